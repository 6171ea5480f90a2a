#!/usr/bin/env python3
"""PyTorch peer of one goal-conditioned TD3+BC (or TD3) update, for bench_train.py.

This is the update as it is usually written in Python: sfujim/TD3_BC (Fujimoto & Gu 2021)
with the goal-conditioned changes GoFAR/WGCSL-style code makes (goal concatenated to the
observation, no done mask, target clipped to the return range of rewards in {-1, 0}). It is
meant to do the same arithmetic per update as `pgser-train bench`, so that the two
updates/s figures can be compared:

    actor   [obs+goal] -> 256 -> 256 -> 256 -> act, ReLU, tanh (max_action 1)
    critics two separate [obs+goal+act] -> 256 -> 256 -> 256 -> 1, ReLU, one Adam for both
    targets deepcopies, soft update tau 0.005 after each actor update (policy delay 2)
    inputs  (x - mean) / std clipped to [-5, 5] for obs and goal, done inside the update
    target  r + 0.98 * min(Q1', Q2')(s', g, clip(pi'(s', g) + clip(0.2 N, +-0.5), +-1)),
            clamped to [-1 / (1 - gamma), 0]
    actor   td3bc: -lambda * Q1(s, g, pi).mean() + mse(pi, a), lambda = 2.5 / |Q1|.mean()
            td3:   -Q1(s, g, pi).mean()
    lr      3e-4 (td3bc) or 1e-3 (td3), both optimisers

With --algo ddpg it is instead MRN's DDPG update (Cranial-XIX/metric-residual-network,
src/agent/ddpg.py, as `main.py --agent her --negative-reward` trains the hand experts), the
update `pgser-train online` makes (docs/online.md):

    critic  one [obs+goal+act] -> 256 -> 256 -> 256 -> 1 (MRN feeds [s, a, g]: same cost)
    target  r + 0.98 * Q'(s', g, pi'(s', g)), clamped to [-1 / (1 - gamma), 0]; no noise
    actor   -Q(s, g, pi).mean() + 1.0 * pi.pow(2).mean(), every update, on the critic before
            its step; both losses scaled by MRN's loss_scale 20 before backward
    targets polyak 0.9 once per cycle of 40 updates
    lr      1e-3, both optimisers

Batches are random tensors generated before timing (8 of them, cycled), so only the update
is timed. `--updates` counts critic updates; the actor and targets move on every 2nd one.

Prints one line; with --json:
    {"peer": "pytorch", "torch": ..., "threads": ..., "batch_size": ..., "updates": ...,
     "seconds": ..., "updates_per_sec": ..., "device": "cpu", ...}

Usage:
    train_peer.py [--obs 25] [--goal 3] [--act 4] [--batch-size 512] [--updates 300]
                  [--warmup 20] [--threads 2] [--seed 0] [--algo td3bc|td3|ddpg]
                  [--device cpu|cuda] [--json]
"""
from __future__ import annotations

import argparse
import copy
import json
import platform
import sys
import time

import torch
import torch.nn as nn
import torch.nn.functional as F

HIDDEN = 256
GAMMA = 0.98
TAU = 0.005
POLICY_NOISE = 0.2
NOISE_CLIP = 0.5
POLICY_FREQ = 2
ALPHA = 2.5  # TD3+BC's lambda numerator
CLIP_OBS = 5.0  # normaliser clip range, as in HER/WGCSL/GoFAR
N_BATCHES = 8
LR = {"td3bc": 3e-4, "td3": 1e-3, "ddpg": 1e-3}
# MRN's DDPG (--algo ddpg): src/args.py defaults.
ACTION_L2 = 1.0
LOSS_SCALE = 20.0
POLYAK = 0.9
N_BATCHES_PER_CYCLE = 40


def mlp(inp: int, out: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Linear(inp, HIDDEN), nn.ReLU(),
        nn.Linear(HIDDEN, HIDDEN), nn.ReLU(),
        nn.Linear(HIDDEN, HIDDEN), nn.ReLU(),
        nn.Linear(HIDDEN, out),
    )


class Actor(nn.Module):
    def __init__(self, obs: int, goal: int, act: int):
        super().__init__()
        self.net = mlp(obs + goal, act)

    def forward(self, o, g):
        return torch.tanh(self.net(torch.cat([o, g], dim=1)))  # max_action = 1


class Critic(nn.Module):
    def __init__(self, obs: int, goal: int, act: int):
        super().__init__()
        self.net = mlp(obs + goal + act, 1)

    def forward(self, o, g, a):
        return self.net(torch.cat([o, g, a], dim=1))


class Normalizer:
    """Fixed statistics: the benchmark times applying a normaliser, not fitting one."""

    def __init__(self, dim: int, gen: torch.Generator, device):
        self.mean = (torch.randn(dim, generator=gen) * 0.5).to(device)
        self.std = (torch.rand(dim, generator=gen) + 0.5).to(device)  # in [0.5, 1.5): no div by ~0

    def __call__(self, x):
        return ((x - self.mean) / self.std).clamp(-CLIP_OBS, CLIP_OBS)


class Agent:
    def __init__(self, obs: int, goal: int, act: int, algo: str, device, gen: torch.Generator):
        self.algo = algo
        self.actor = Actor(obs, goal, act).to(device)
        self.q1 = Critic(obs, goal, act).to(device)
        self.q2 = Critic(obs, goal, act).to(device)
        self.actor_t = copy.deepcopy(self.actor)
        self.q1_t = copy.deepcopy(self.q1)
        self.q2_t = copy.deepcopy(self.q2)
        for net in (self.actor_t, self.q1_t, self.q2_t):
            net.requires_grad_(False)
        lr = LR[algo]
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=lr)
        critics = [self.q1] if algo == "ddpg" else [self.q1, self.q2]  # DDPG: one critic
        self.critic_opt = torch.optim.Adam([p for q in critics for p in q.parameters()], lr=lr)
        self.o_norm = Normalizer(obs, gen, device)
        self.g_norm = Normalizer(goal, gen, device)
        self.q_min, self.q_max = -1.0 / (1.0 - GAMMA), 0.0
        self.it = 0
        self.last = {}

    def update_ddpg(self, batch):
        """MRN's `DDPG._update`, plus its once-per-cycle `_soft_update` every 40th call."""
        self.it += 1
        o_raw, g_raw, a, o2_raw, r = batch
        o, g, o2 = self.o_norm(o_raw), self.g_norm(g_raw), self.o_norm(o2_raw)
        with torch.no_grad():
            tq = self.q1_t(o2, g, self.actor_t(o2, g))
            target = (r + GAMMA * tq).clamp(self.q_min, self.q_max)
        critic_loss = (self.q1(o, g, a) - target).pow(2).mean()
        pi = self.actor(o, g)
        actor_loss = -self.q1(o, g, pi).mean() + ACTION_L2 * pi.pow(2).mean()
        self.actor_opt.zero_grad()
        (actor_loss * LOSS_SCALE).backward()
        self.actor_opt.step()
        self.critic_opt.zero_grad()
        (critic_loss * LOSS_SCALE).backward()
        self.critic_opt.step()
        self.last["critic_loss"], self.last["actor_loss"] = critic_loss, actor_loss
        if self.it % N_BATCHES_PER_CYCLE == 0:
            with torch.no_grad():
                for net, tgt in ((self.q1, self.q1_t), (self.actor, self.actor_t)):
                    for p, tp in zip(net.parameters(), tgt.parameters()):
                        tp.data.copy_((1 - POLYAK) * p.data + POLYAK * tp.data)  # MRN's form

    def update(self, batch, eps=None):
        """One critic update (+ actor and targets every POLICY_FREQ-th). `eps`: the standard-normal
        draw behind the target-policy noise, shape of the batch's actions; None (the benchmark)
        draws it here. check_stacked_peer.py passes its own so other peers can be fed the same."""
        if self.algo == "ddpg":
            return self.update_ddpg(batch)
        self.it += 1
        o_raw, g_raw, a, o2_raw, r = batch
        # Normalising the raw batch is part of the update, as in pgser's trainer.
        o, g, o2 = self.o_norm(o_raw), self.g_norm(g_raw), self.o_norm(o2_raw)

        with torch.no_grad():
            if eps is None:
                eps = torch.randn_like(a)
            noise = (eps * POLICY_NOISE).clamp(-NOISE_CLIP, NOISE_CLIP)
            a2 = (self.actor_t(o2, g) + noise).clamp(-1.0, 1.0)
            tq = torch.min(self.q1_t(o2, g, a2), self.q2_t(o2, g, a2))
            # Goal-conditioned, infinite horizon: no done mask; clip to the reachable returns.
            target = (r + GAMMA * tq).clamp(self.q_min, self.q_max)

        critic_loss = F.mse_loss(self.q1(o, g, a), target) + F.mse_loss(self.q2(o, g, a), target)
        self.critic_opt.zero_grad()
        critic_loss.backward()
        self.critic_opt.step()
        self.last["critic_loss"] = critic_loss

        if self.it % POLICY_FREQ == 0:
            pi = self.actor(o, g)
            q = self.q1(o, g, pi)
            if self.algo == "td3bc":
                lmbda = ALPHA / q.abs().mean().detach()
                actor_loss = -lmbda * q.mean() + F.mse_loss(pi, a)
            else:
                actor_loss = -q.mean()
            # As in sfujim/TD3_BC the critics are not frozen here: backward also fills Q1's
            # grads, which critic_opt.zero_grad() discards before the next critic step.
            self.actor_opt.zero_grad()
            actor_loss.backward()
            self.actor_opt.step()
            self.last["actor_loss"] = actor_loss

            with torch.no_grad():
                for net, tgt in ((self.q1, self.q1_t), (self.q2, self.q2_t), (self.actor, self.actor_t)):
                    for p, tp in zip(net.parameters(), tgt.parameters()):
                        tp.data.copy_(TAU * p.data + (1 - TAU) * tp.data)  # sfujim's form


def make_batches(obs, goal, act, bs, gen, device):
    """Random stand-ins for replay samples: the update's cost does not depend on the values."""
    out = []
    for _ in range(N_BATCHES):
        o = torch.randn(bs, obs, generator=gen)
        g = torch.randn(bs, goal, generator=gen)
        a = torch.rand(bs, act, generator=gen) * 2 - 1
        o2 = o + 0.05 * torch.randn(bs, obs, generator=gen)
        r = -(torch.rand(bs, 1, generator=gen) < 0.7).float()  # sparse reward in {0, -1}
        out.append(tuple(t.to(device) for t in (o, g, a, o2, r)))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--obs", type=int, default=25, help="observation dim (FetchPush: 25)")
    ap.add_argument("--goal", type=int, default=3, help="goal dim (Fetch: 3)")
    ap.add_argument("--act", type=int, default=4, help="action dim (Fetch: 4)")
    ap.add_argument("--batch-size", type=int, default=512)
    ap.add_argument("--updates", type=int, default=300, help="timed critic updates (default 300)")
    ap.add_argument("--warmup", type=int, default=20, help="untimed updates first (default 20)")
    ap.add_argument("--threads", type=int, default=2, help="torch.set_num_threads (default 2)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--algo", choices=sorted(LR), default="td3bc")
    ap.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    ap.add_argument("--json", action="store_true", help="print one JSON line")
    a = ap.parse_args(argv)
    if a.updates < 1 or a.warmup < 0 or a.threads < 1:
        ap.error("--updates and --threads must be >= 1, --warmup >= 0")
    if a.device == "cuda" and not torch.cuda.is_available():
        sys.exit("--device cuda: torch.cuda.is_available() is False")

    # Intra-op threads are what matter for a single stream of GEMMs; bench_train.py also sets
    # OMP_NUM_THREADS/MKL_NUM_THREADS so the backend's pools are sized before torch starts.
    torch.set_num_threads(a.threads)
    torch.manual_seed(a.seed)
    gen = torch.Generator().manual_seed(a.seed)
    device = torch.device(a.device)

    agent = Agent(a.obs, a.goal, a.act, a.algo, device, gen)
    batches = make_batches(a.obs, a.goal, a.act, a.batch_size, gen, device)

    def sync():
        if device.type == "cuda":
            torch.cuda.synchronize()

    # Warm-up: allocator, oneDNN/MKL kernel selection, Adam state creation. An even count keeps
    # the timed window starting on a critic-only update, so it holds updates//2 actor updates.
    tw = time.perf_counter()
    for i in range(a.warmup):
        agent.update(batches[i % N_BATCHES])
    sync()
    t0 = time.perf_counter()
    warm_secs = t0 - tw
    for i in range(a.updates):
        agent.update(batches[i % N_BATCHES])
    sync()
    secs = time.perf_counter() - t0

    # Read the losses only after timing (.item() would force a sync inside the loop on cuda);
    # a NaN here would mean the peer is not doing what it claims.
    losses = {k: float(v.item()) for k, v in agent.last.items()}
    res = {
        "peer": "pytorch", "torch": torch.__version__, "threads": torch.get_num_threads(),
        "batch_size": a.batch_size, "updates": a.updates, "seconds": secs,
        "updates_per_sec": a.updates / secs, "device": a.device,
        "algo": a.algo, "warmup": a.warmup, "warmup_seconds": warm_secs, "dims": [a.obs, a.goal, a.act],
        "actor_updates": a.updates if a.algo == "ddpg"
        else a.updates // POLICY_FREQ + (a.updates % POLICY_FREQ if a.warmup % 2 else 0),
        "python": platform.python_version(), **losses,
    }
    if device.type == "cuda":
        res["gpu"] = torch.cuda.get_device_name(device)
    if a.json:
        print(json.dumps(res), flush=True)
    else:
        print(f"pytorch {torch.__version__} {a.algo} on {a.device} ({res['threads']} threads): "
              f"{a.updates} updates of batch {a.batch_size} in {secs:.3f} s = "
              f"{res['updates_per_sec']:.1f} updates/s ({1e3 * secs / a.updates:.2f} ms/update); "
              f"last critic loss {losses['critic_loss']:.4g}", flush=True)


if __name__ == "__main__":
    main()
