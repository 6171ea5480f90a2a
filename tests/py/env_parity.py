"""Reference runs of the Python Fetch v4 and hand v1 environments and of numpy's generator,
for tests/env_parity.rs.

    env_parity.py rng --seeds 0,1,42 --n 1000          # JSON to stdout
    env_parity.py env --tasks FetchPush --seeds 0,1,7 --steps 50 --out runs.json
    env_parity.py hand --tasks HandManipulateEggRotate --seeds 0,3 --episodes 3 --steps 40 --out runs.json
    env_parity.py random-success --task HandManipulateEggRotate --seed 1000 --episodes 100

Every float is written as the u64 of its IEEE bits, so the comparison in Rust sees exactly the
values Python had (a decimal round trip through a JSON parser need not be exact).

`env`: per task and seed, `reset(seed=seed)`, then `steps` steps of a closed-loop scripted
policy (reach over the object, descend, close, carry to the goal; Reach: go to the goal) plus
noise from `default_rng(1000 + seed)`, so the gripper touches and moves objects and some actions
fall outside [-1, 1]. Actions are float32, the action space's dtype, and are dumped so Rust
replays exactly them rather than recomputing the policy.
"""

import argparse
import json
import sys
import types

import mujoco
import numpy as np
from gymnasium_robotics.utils import mujoco_utils

# --- workaround, no numbers change: with mujoco 3.17 the pybind enum `mjtJoint` no longer
# compares equal to the np.int32 in `model.jnt_type`, so mujoco_utils' joint-type asserts fail.
# Give mujoco_utils a view of the mujoco module whose mjtJoint members are plain ints (the same
# values); everything else is the real module.
_mj = types.ModuleType("mujoco")
_mj.__dict__.update(mujoco.__dict__)
_mj.mjtJoint = types.SimpleNamespace(**{k: int(v) for k, v in mujoco.mjtJoint.__members__.items()})
mujoco_utils.mujoco = _mj
# ---------------------------------------------------------------------------------------------

import gymnasium as gym  # noqa: E402
import gymnasium_robotics  # noqa: E402

gym.register_envs(gymnasium_robotics)


def bits(x):
    return np.ascontiguousarray(x, dtype=np.float64).ravel().view(np.uint64).tolist()


def rng_cmd(args):
    out = {}
    for s in args.seeds:
        make = lambda: np.random.Generator(np.random.PCG64(np.random.SeedSequence(s)))  # noqa: E731
        g = make()
        u = make()
        out[str(s)] = {
            "random": bits(g.random(args.n)),
            # one call with size=n, then scalar calls: both must follow the same stream
            "uniform": bits(np.concatenate([u.uniform(-0.3, 0.7, size=args.n), [u.uniform(0, 0.45)]])),
            # the ziggurat (Generator.normal), as the hand tasks' resets draw it
            "normal": bits(make().normal(size=args.n, scale=0.005)),
        }
    json.dump(out, sys.stdout)


def policy(task, obs, t, noise):
    o = obs["observation"]
    grip = o[:3]
    if task == "FetchReach":
        target, fingers = obs["desired_goal"], 0.0
    else:
        obj = o[3:6]
        if t < 12:
            target, fingers = obj + np.array([0.0, 0.0, 0.06]), 1.0
        elif t < 22:
            target, fingers = obj, 1.0
        elif t < 27:
            target, fingers = obj, -1.0
        else:
            target, fingers = obs["desired_goal"], -1.0
    a = np.concatenate([np.clip((target - grip) / 0.05, -1.0, 1.0), [fingers]]) + 0.3 * noise[t]
    return a.astype(np.float32)


def env_cmd(args):
    runs = {}
    for task in args.tasks:
        env = gym.make(f"{task}-v4")
        u = env.unwrapped
        per_seed = {}
        for s in args.seeds:
            noise = np.random.default_rng(1000 + s).uniform(-1.0, 1.0, (args.steps, 4))
            obs, _ = u.reset(seed=s)
            rec = {
                "initial_gripper_xpos": bits(u.initial_gripper_xpos),
                "height_offset": bits(getattr(u, "height_offset", 0.0)),
                "reset": {k: bits(v) for k, v in obs.items()},
                "steps": [],
            }
            for t in range(args.steps):
                a = policy(task, obs, t, noise)
                obs, r, _, _, info = u.step(a)
                step = {k: bits(v) for k, v in obs.items()}
                step.update(action=bits(a), reward=float(r), success=bool(info["is_success"]),
                            time=bits(u.data.time))
                rec["steps"].append(step)
            per_seed[str(s)] = rec
        runs[task] = per_seed
        env.close()
    with open(args.out, "w") as f:
        json.dump(runs, f)


def hand_cmd(args):
    """Per task and seed: `reset(seed=seed)`, then further `reset()`s on the same environment
    (controls and warm starts carry over between episodes, as in gymnasium), each episode
    stepped with float32 actions from `default_rng(1000 + seed)`, some outside [-1, 1]."""
    runs = {}
    for task in args.tasks:
        per_seed = {}
        for s in args.seeds:
            u = gym.make(f"{task}-v1").unwrapped
            actions = np.random.default_rng(1000 + s).uniform(-1.2, 1.2, (args.episodes, args.steps, 20))
            episodes = []
            for e in range(args.episodes):
                obs, _ = u.reset(seed=s) if e == 0 else u.reset()
                rec = {"reset": {k: bits(v) for k, v in obs.items()}, "time": bits(u.data.time), "steps": []}
                for t in range(args.steps):
                    a = actions[e, t].astype(np.float32)
                    obs, r, _, _, info = u.step(a)
                    step = {k: bits(v) for k, v in obs.items()}
                    step.update(action=bits(a), reward=float(r), success=bool(info["is_success"]),
                                time=bits(u.data.time))
                    rec["steps"].append(step)
                episodes.append(rec)
            per_seed[str(s)] = episodes
            u.close()
        runs[task] = per_seed
    with open(args.out, "w") as f:
        json.dump(runs, f)


def random_success_cmd(args):
    """What `pgser-etl collect --policy random` does, in gymnasium: episode i is a newly made
    environment reset with seed S+i, stepped T-1 times with `default_rng(SeedSequence(S,
    spawn_key=(i,))).uniform(-1, 1, 20)` as float32. Prints the final-step successes and returns."""
    T = {"HandManipulateBlockRotateZ": 100, "HandManipulateEggRotate": 100}.get(args.task, 50)
    version = "v1" if args.task.startswith("Hand") else "v4"
    success, returns = [], []
    for i in range(args.episodes):
        env = gym.make(f"{args.task}-{version}").unwrapped
        env.reset(seed=args.seed + i)
        rng = np.random.default_rng(np.random.SeedSequence(args.seed, spawn_key=(i,)))
        ret, ok = 0.0, False
        for _ in range(T - 1):
            a = rng.uniform(-1.0, 1.0, size=env.action_space.shape[0]).astype(np.float32)
            _, r, _, _, info = env.step(a)
            ret += float(r)
            ok = bool(info["is_success"])
        success.append(ok)
        returns.append(ret)
        env.close()
    json.dump({"success": success, "returns": returns}, sys.stdout)


def main():
    p = argparse.ArgumentParser()
    sub = p.add_subparsers(dest="cmd", required=True)
    ints = lambda s: [int(x) for x in s.split(",")]  # noqa: E731
    r = sub.add_parser("rng")
    r.add_argument("--seeds", type=ints, required=True)
    r.add_argument("--n", type=int, default=1000)
    e = sub.add_parser("env")
    e.add_argument("--tasks", type=lambda s: s.split(","), required=True)
    e.add_argument("--seeds", type=ints, required=True)
    e.add_argument("--steps", type=int, default=50)
    e.add_argument("--out", required=True)
    h = sub.add_parser("hand")
    h.add_argument("--tasks", type=lambda s: s.split(","), required=True)
    h.add_argument("--seeds", type=ints, required=True)
    h.add_argument("--episodes", type=int, default=3)
    h.add_argument("--steps", type=int, default=40)
    h.add_argument("--out", required=True)
    rs = sub.add_parser("random-success")
    rs.add_argument("--task", required=True)
    rs.add_argument("--seed", type=int, default=0)
    rs.add_argument("--episodes", type=int, default=100)
    args = p.parse_args()
    {"rng": rng_cmd, "env": env_cmd, "hand": hand_cmd, "random-success": random_success_cmd}[args.cmd](args)


if __name__ == "__main__":
    main()
