#!/usr/bin/env python3
"""PGSER end to end with a PyTorch learner: TD3+BC trained from pgser.Sampler's -mem batches,
evaluated in pgser.VectorEnv.

    python examples/td3bc_torch.py --out /tmp/pgser-example            # FetchReach sample data
    python examples/td3bc_torch.py --updates 20000 --expert E.pkl --random R.pkl --task FetchPush

Steps (README, "What PGSER is"):
1. the dataset: WGCSL pickles -> a trajectory table (pgser.convert);
2. the critic that ranks swapped goals, pre-trained with random goal swapping (`pgser-train`);
3. goal-swapped transitions with their Q (pgser.score);
4. TD3+BC in PyTorch, on batches that mix the original data with swapped transitions drawn by
   priority (pgser.Sampler: the batches `pgser-train --data scored.parquet` would draw);
5. evaluation in pgser's environments, several episodes per native call (pgser.VectorEnv).
The last line printed is a JSON summary with the success rate.

TD3+BC (Fujimoto & Gu 2021) as the paper's learner: twin critics with clipped double-Q and target
policy smoothing, a delayed actor whose loss is -lambda * Q / mean|Q| + ||pi(s, g) - a||^2 with
alpha = 2.5, inputs normalized by the data's mean and standard deviation, target Q clipped to the
range of the sparse reward's returns, [-1/(1-gamma), 0].
"""

import argparse
import json
import shutil
import subprocess
import time
from pathlib import Path

import numpy as np
import torch
from torch import nn

import pgser

REPO = Path(__file__).resolve().parents[1]


def mlp(inp, out, hidden, final=None):
    layers = [nn.Linear(inp, hidden), nn.ReLU(), nn.Linear(hidden, hidden), nn.ReLU(), nn.Linear(hidden, hidden),
              nn.ReLU(), nn.Linear(hidden, out)]
    return nn.Sequential(*layers, *([final] if final else []))


class TD3BC:
    def __init__(self, obs_dim, goal_dim, act_dim, norm, hidden=256, lr=1e-3, gamma=0.98, alpha=2.5, tau=0.005,
                 policy_noise=0.2, noise_clip=0.5, policy_freq=2):
        self.mean, self.std = (torch.as_tensor(x, dtype=torch.float32) for x in norm)
        inp = obs_dim + goal_dim
        self.actor = mlp(inp, act_dim, hidden, nn.Tanh())
        self.critics = nn.ModuleList([mlp(inp + act_dim, 1, hidden) for _ in range(2)])
        self.actor_t = mlp(inp, act_dim, hidden, nn.Tanh())
        self.critics_t = nn.ModuleList([mlp(inp + act_dim, 1, hidden) for _ in range(2)])
        self.actor_t.load_state_dict(self.actor.state_dict())
        self.critics_t.load_state_dict(self.critics.state_dict())
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=lr)
        self.critic_opt = torch.optim.Adam(self.critics.parameters(), lr=lr)
        self.gamma, self.alpha, self.tau = gamma, alpha, tau
        self.policy_noise, self.noise_clip, self.policy_freq = policy_noise, noise_clip, policy_freq
        self.updates = 0

    def inputs(self, obs, goal):
        x = torch.cat([obs, goal], dim=-1)
        return ((x - self.mean) / self.std).clamp(-5, 5)

    @staticmethod
    def q(critic, x, a):
        return critic(torch.cat([x, a], dim=-1)).squeeze(-1)

    def update(self, b):
        obs, goal, act, rew, nobs, w = (torch.from_numpy(b[k]) for k in
                                        ("obs", "goal", "action", "reward", "next_obs", "weight"))
        x, nx = self.inputs(obs, goal), self.inputs(nobs, goal)
        with torch.no_grad():
            noise = (torch.randn_like(act) * self.policy_noise).clamp(-self.noise_clip, self.noise_clip)
            na = (self.actor_t(nx) + noise).clamp(-1, 1)
            target_q = torch.min(self.q(self.critics_t[0], nx, na), self.q(self.critics_t[1], nx, na))
            target = (rew + self.gamma * target_q).clamp(-1 / (1 - self.gamma), 0)
        # Importance weights of prioritized rows (all 1 without is_beta) weight the critic loss.
        critic_loss = sum((w * (self.q(c, x, act) - target) ** 2).mean() for c in self.critics)
        self.critic_opt.zero_grad()
        critic_loss.backward()
        self.critic_opt.step()
        self.updates += 1
        if self.updates % self.policy_freq == 0:
            pi = self.actor(x)
            q = self.q(self.critics[0], x, pi)
            lam = self.alpha / q.abs().mean().detach()
            actor_loss = -lam * q.mean() + ((pi - act) ** 2).mean()
            self.actor_opt.zero_grad()
            actor_loss.backward()
            self.actor_opt.step()
            with torch.no_grad():
                for net, tgt in ((self.actor, self.actor_t), (self.critics, self.critics_t)):
                    for p, pt in zip(net.parameters(), tgt.parameters()):
                        pt.mul_(1 - self.tau).add_(self.tau * p)
        return critic_loss.item()

    @torch.no_grad()
    def act(self, obs, goal):
        x = self.inputs(torch.as_tensor(obs, dtype=torch.float32), torch.as_tensor(goal, dtype=torch.float32))
        return self.actor(x).numpy()


def evaluate(agent, task, episodes, envs=25, seed=1_000_000):
    """Success rate over `episodes` episodes, `envs` at a time in one pgser.VectorEnv."""
    venv = pgser.VectorEnv(task, envs)
    steps = venv.spec.max_episode_steps
    successes = []
    for start in range(0, episodes, envs):
        obs, _ = venv.reset(seed=seed + start)
        for _ in range(steps):
            obs, _, _, truncated, info = venv.step(agent.act(obs["observation"], obs["desired_goal"]))
        assert truncated.all()
        successes.extend(info["is_success"][: episodes - start])
    return float(np.mean(successes))


def data_norm(table):
    """Mean and standard deviation of [obs, goal] over the table; goals from achieved and desired
    goals both, as pgser's normalizer (swapped goals are achieved goals)."""
    t = pgser.read_table(table, columns=["obs", "achieved_goal", "desired_goal"])
    vec = lambda name: np.stack(t.column(name).drop_null().to_numpy(zero_copy_only=False))  # noqa: E731
    obs, goals = vec("obs"), np.concatenate([vec("achieved_goal"), vec("desired_goal")])
    mean = np.concatenate([obs.mean(0), goals.mean(0)]).astype(np.float32)
    std = np.concatenate([obs.std(0), goals.std(0)]).clip(1e-2, None).astype(np.float32)
    return mean, std


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", type=Path, default=Path("out/example"))
    ap.add_argument("--task", default="FetchReach")
    ap.add_argument("--expert", type=Path, default=REPO / "data/fetch_reach_expert_50.pkl")
    ap.add_argument("--random", type=Path, default=REPO / "data/fetch_reach_random_200.pkl")
    ap.add_argument("--pretrain-updates", type=int, default=2000)
    ap.add_argument("--updates", type=int, default=3000)
    ap.add_argument("--batch-size", type=int, default=256)
    ap.add_argument("--eval-episodes", type=int, default=100)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--pgser-train", default=shutil.which("pgser-train") or str(REPO / "target/release/pgser-train"))
    args = ap.parse_args()
    torch.manual_seed(args.seed)
    torch.set_num_threads(max(1, torch.get_num_threads()))
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()

    traj, q, scored = args.out / "traj.parquet", args.out / "q.ckpt", args.out / "scored.parquet"
    pgser.convert([args.expert, args.random], traj, task=args.task)
    subprocess.run([args.pgser_train, "--data", str(traj), "--swap", "random", "--updates", str(args.pretrain_updates),
                    "--batch-size", str(args.batch_size), "--eval-episodes", "0", "--seed", str(args.seed),
                    "-o", str(q)], check=True)
    pgser.score(q, traj, scored, swaps=4, seed=args.seed)

    info = pgser.task_info(args.task)
    agent = TD3BC(info["obs_dim"], info["goal_dim"], info["act_dim"], data_norm(traj))
    # priority="rank" is pgser's default (docs/domain.md); "q" is the paper's reading
    sampler = pgser.Sampler(scored, batch_size=args.batch_size, aug_ratio=0.5, priority="rank", seed=args.seed,
                            num_batches=args.updates)
    for i, batch in enumerate(sampler, 1):
        loss = agent.update(batch)
        if i % 1000 == 0:
            print(f"update {i}: critic loss {loss:.4f}", flush=True)
    success = evaluate(agent, f"{args.task}-v4" if args.task.startswith("Fetch") else f"{args.task}-v1",
                       args.eval_episodes)
    print(json.dumps({"task": args.task, "updates": args.updates, "success": success,
                      "seconds": round(time.time() - t0, 1)}))


if __name__ == "__main__":
    main()
