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


def pointmaze_cmd(args):
    """OGBench's PointMaze: per maze and seed, `np.random.seed(seed)` then `reset(seed=seed)` with
    task (seed % 5) + 1, and a second episode continuing the global generator with no task (a
    random one); each `steps` steps of float32 actions toward the goal in a straight line plus
    N(0, 0.6) noise from `default_rng(1000 + seed)`, so the point runs into walls (and, in the
    teleport maze, onto pads). `terminate_at_goal=False` keeps an episode going past success."""
    import warnings

    import gymnasium

    warnings.filterwarnings("ignore")
    import ogbench.locomaze  # noqa: F401  (registers the ids)

    out = {}
    for maze in args.mazes:
        env = gymnasium.make(maze, terminate_at_goal=False).unwrapped
        runs = {}
        for seed in args.seeds:
            np.random.seed(seed)
            rng = np.random.default_rng(1000 + seed)
            episodes = []
            for k, options in enumerate([dict(task_id=seed % 5 + 1), None]):
                ob, info = env.reset(seed=seed, options=options) if k == 0 else env.reset(options=options)
                ep = {"task_id": env.cur_task_id, "reset": bits(ob), "goal": bits(info["goal"]), "steps": []}
                for _ in range(args.steps):
                    d = info["goal"] - ob
                    a = np.clip(d / (np.linalg.norm(d) + 1e-6) + rng.normal(0, 0.6, 2), -1, 1).astype(np.float32)
                    ob, r, term, trunc, step_info = env.step(a)
                    ep["steps"].append({"action": bits(a.astype(np.float64)), "obs": bits(ob), "success": bool(step_info["success"])})
                episodes.append(ep)
            runs[str(seed)] = episodes
        out[maze] = runs
        env.close()
    with open(args.out, "w") as f:
        json.dump(out, f)


def pointmaze_eval_cmd(args):
    """OGBench's evaluation of its oracle agent, as pgser's evaluation runs it: per seed,
    `np.random.seed(seed)` and `reset(options=dict(task_id=seed % 5 + 1))` in the env as OGBench
    registers it (ending at success), then up to 1000 steps of the BFS oracle's direction,
    computed from the observation and goal rounded to float32 (what a pgser policy sees), with
    N(0, 1) noise from `default_rng(seed)` so that it sometimes fails. Per episode: success and steps."""
    import warnings

    import gymnasium

    warnings.filterwarnings("ignore")
    import ogbench.locomaze  # noqa: F401

    env = gymnasium.make(args.maze).unwrapped
    out = []
    for seed in args.seeds:
        np.random.seed(seed)
        ob, info = env.reset(options=dict(task_id=seed % 5 + 1))
        goal = info["goal"].astype(np.float32).astype(np.float64)
        noise = np.random.default_rng(seed)
        success, steps = False, 0
        for steps in range(1, 1001):
            xy = ob.astype(np.float32).astype(np.float64)
            sub, _ = env.get_oracle_subgoal(xy, goal)
            d = sub - xy
            a = d / (np.sqrt(d[0] * d[0] + d[1] * d[1]) + 1e-6) + noise.standard_normal(2)
            a = np.clip(a, -1, 1).astype(np.float32)
            ob, _, terminated, _, step_info = env.step(a)
            if terminated:
                success = True
                break
        out.append({"seed": seed, "task_id": seed % 5 + 1, "success": success, "steps": steps})
    json.dump(out, sys.stdout)


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
    pm = sub.add_parser("pointmaze")
    pm.add_argument("--mazes", type=lambda s: s.split(","), required=True)
    pm.add_argument("--seeds", type=ints, required=True)
    pm.add_argument("--steps", type=int, default=200)
    pm.add_argument("--out", required=True)
    pe = sub.add_parser("pointmaze-eval")
    pe.add_argument("--maze", required=True)
    pe.add_argument("--seeds", type=ints, required=True)
    args = p.parse_args()
    cmds = {"pointmaze-eval": pointmaze_eval_cmd, "rng": rng_cmd, "env": env_cmd, "hand": hand_cmd, "random-success": random_success_cmd, "pointmaze": pointmaze_cmd}
    cmds[args.cmd](args)


if __name__ == "__main__":
    main()
