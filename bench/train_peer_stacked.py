#!/usr/bin/env python3
"""PyTorch peer of A independent goal-conditioned TD3+BC (or TD3) agents updated at once, with an
agent dimension on every tensor: a peer for "many agents per process" (issue 12).

Per agent this is the arithmetic of train_peer.py (see there; sfujim/TD3_BC with the
goal-conditioned changes), and check_stacked_peer.py checks that agent by agent:

    actor   [obs+goal] -> H -> H -> H -> act, ReLU, tanh                     (H = --hidden, 256)
    critics twin [obs+goal+act] -> H -> H -> H -> 1, ReLU, one Adam for both
    inputs  (x - mean) / std clipped to [-5, 5] for obs and goal, per agent (own statistics)
    target  r + 0.98 * min(Q1', Q2')(s', g, clip(pi'(s', g) + clip(0.2 N, +-0.5), +-1)),
            clamped to [-1 / (1 - 0.98), 0]
    critic  mse(Q1, target) + mse(Q2, target)          (means over the agent's own batch)
    actor   td3bc: -lambda * Q1(s, g, pi).mean() + mse(pi, a), lambda = 2.5 / |Q1|.mean() over
            the agent's own batch (one lambda per agent); td3: -Q1(s, g, pi).mean()
            every 2nd update, then Polyak tau 0.005 on actor and both critics
    Adam    lr 3e-4 (td3bc) / 1e-3 (td3), betas (0.9, 0.999), eps 1e-8

Every agent has its own weights, targets, Adam moments, normaliser statistics, batch and noise.
The losses are summed over agents (not averaged), so each agent's gradient is exactly its own;
Adam and Polyak are elementwise, so one Adam over the stacked tensors and one
torch._foreach_lerp_ over them are exactly A separate ones.

Layout (--mode bmm, CORL's VectorizedLinear style): each linear layer of the actor is a weight
[A, in, out] and a bias [A, 1, out], applied to activations [A, B, in] with one torch.baddbmm for
all agents. The twin critics are an ensemble of 2 inside each agent: weights [A*2, in, out]
(agent-major: row 2a is agent a's Q1, 2a+1 its Q2), input [A, B, in] expanded to [A*2, B, in];
the actor step uses Q1 alone through the strided view W[0::2].
--mode vmap: the same update, but the nets are nn.Linear modules (on the meta device) run with
torch.func.functional_call under torch.func.vmap over parameters stacked with
torch.func.stack_module_state (weights [A, out, in] / [A*2, out, in]); gradients by ordinary
autograd through the vmapped forward.

The actor loss is differentiated for the actor's parameters only (backward(inputs=...)), so Q1's
weight gradients, which train_peer.py computes and throws away, are not computed: same result.

FLOPs per agent-update (matmuls only; see train_flops.py for how they are counted): for
FetchPush dims (obs 25, goal 3, act 4), H 256, batch 512, policy delay 2:
    critic update: target actor + 2 target critics + 2 critics forward and backward
                   = F_a + 2 F_c + 6 F_c = 1,285,554,176
    actor update:  actor forward and backward + Q1 forward and input gradient
                   = 3 F_a + 2 F_c = 713,555,968, every 2nd update
    per update     1,642,332,160 ≈ 1.64 GFLOP   (F_a = 142,606,336, F_c = 142,868,480)

Batches are random tensors [A, B, ...] made before timing (8 of them, cycled); the noise is
drawn inside the update (torch.randn, its own per agent). --updates counts critic updates of all
agents at once; agent-updates/s = A x updates/s.

--cuda-graph (with --device cuda): after the eager warm-up, the two-update cycle (critic-only
update, then critic + actor + targets) is captured once per pair of the 8 batches (4 graphs
reading the batches in place, Adam(capturable=True)), and replayed; --updates is then rounded up
to an even number. The RNG inside the graphs advances on each replay (PyTorch registers the
generator with the graph), so every update still gets fresh noise.

Prints one line; with --json one JSON object:
    {"peer": "pytorch-stacked-bmm", "torch": ..., "device": ..., "agents": A, "threads": ...,
     "batch_size": ..., "updates": ..., "seconds": ..., "agent_updates_per_sec": ...,
     "updates_per_sec": (per agent), "flops_per_update": (per agent-update), "gflops_per_sec": ..., ...}

Usage:
    train_peer_stacked.py [--agents 10] [--mode bmm|vmap] [--obs 25] [--goal 3] [--act 4]
                          [--hidden 256] [--batch-size 512] [--updates 100 | --seconds S]
                          [--warmup 4] [--threads 2] [--seed 0] [--algo td3bc|td3]
                          [--device cpu|cuda] [--cuda-graph] [--tf32] [--dtype float32|float64] [--json]
"""
from __future__ import annotations

import argparse
import json
import math
import platform
import sys
import time
from pathlib import Path

import torch
import torch.nn as nn

sys.path.insert(0, str(Path(__file__).resolve().parent))
from train_flops import flops_per_update  # noqa: E402

GAMMA = 0.98
TAU = 0.005
POLICY_NOISE = 0.2
NOISE_CLIP = 0.5
POLICY_FREQ = 2
ALPHA = 2.5
CLIP_OBS = 5.0
N_BATCHES = 8
LR = {"td3bc": 3e-4, "td3": 1e-3}
N_LAYERS = 4


def linear_init(n: int, inp: int, out: int, gen, dtype):
    """n independent nn.Linear-style inits (weight and bias ~ U(+-1/sqrt(in)), what
    kaiming_uniform_(a=sqrt(5)) gives), in nn.Linear's layout: weight [n, out, in], bias [n, out]."""
    bound = 1.0 / math.sqrt(inp)
    w = (torch.rand(n, out, inp, generator=gen, dtype=dtype) * 2 - 1) * bound
    b = (torch.rand(n, out, generator=gen, dtype=dtype) * 2 - 1) * bound
    return w, b


class StackedTD3:
    """A agents' TD3+BC/TD3 state with a leading agent dimension; `update` trains all at once.

    Parameters are lists of leaf tensors, [W0, b0, W1, b1, W2, b2, W3, b3]: actor ones lead with A,
    critic ones with A*2 (agent-major twins). `linear_layout(net, agent)` / `load_linear` convert
    to and from nn.Linear's per-agent layout, for check_stacked_peer.py."""

    def __init__(self, agents, obs, goal, act, hidden=256, algo="td3bc", device="cpu",
                 dtype=torch.float32, mode="bmm", gen=None, cuda_graph=False, fused=None):
        if mode not in ("bmm", "vmap"):
            raise ValueError(f"mode {mode!r}")
        self.A, self.obs, self.goal, self.act, self.hidden = agents, obs, goal, act, hidden
        self.algo, self.mode, self.dtype = algo, mode, dtype
        self.device = torch.device(device)
        gen = gen if gen is not None else torch.Generator().manual_seed(0)
        A = agents
        sizes_a = [obs + goal, hidden, hidden, hidden, act]
        sizes_c = [obs + goal + act, hidden, hidden, hidden, 1]

        def build(n, sizes):
            ps = []
            for i in range(N_LAYERS):
                w, b = linear_init(n, sizes[i], sizes[i + 1], gen, dtype)
                ps += [self._from_linear(w), self._from_linear_bias(b)]
            return [p.to(self.device).requires_grad_(True) for p in ps]

        self.actor = build(A, sizes_a)
        self.critic = build(2 * A, sizes_c)
        self.actor_t = [p.detach().clone() for p in self.actor]
        self.critic_t = [p.detach().clone() for p in self.critic]
        # Normaliser statistics, one set per agent, as train_peer.Normalizer draws them.
        self.o_mean = (torch.randn(A, 1, obs, generator=gen, dtype=dtype) * 0.5).to(self.device)
        self.o_std = (torch.rand(A, 1, obs, generator=gen, dtype=dtype) + 0.5).to(self.device)
        self.g_mean = (torch.randn(A, 1, goal, generator=gen, dtype=dtype) * 0.5).to(self.device)
        self.g_std = (torch.rand(A, 1, goal, generator=gen, dtype=dtype) + 0.5).to(self.device)
        self.q_min, self.q_max = -1.0 / (1.0 - GAMMA), 0.0

        lr = LR[algo]
        kw = {}
        if self.device.type == "cuda":
            if fused is None or fused:
                kw["fused"] = True
            if cuda_graph:
                kw["capturable"] = True
        elif fused:
            kw["fused"] = True
        self.actor_opt = torch.optim.Adam(self.actor, lr=lr, **kw)
        self.critic_opt = torch.optim.Adam(self.critic, lr=lr, **kw)
        self.opt_kwargs = kw
        self.it = 0
        # Losses go to a static buffer (mean over agents), so they survive CUDA graph replays.
        self.loss_buf = torch.zeros(2, dtype=dtype, device=self.device)
        self.graphs = None

        if mode == "vmap":
            from torch.func import functional_call, vmap

            def base(sizes):
                layers = []
                for i in range(N_LAYERS):
                    layers.append(nn.Linear(sizes[i], sizes[i + 1], device="meta", dtype=dtype))
                    if i < N_LAYERS - 1:
                        layers.append(nn.ReLU())
                return nn.Sequential(*layers)

            self._base_a, self._base_c = base(sizes_a), base(sizes_c)
            self._names = [n for n, _ in self._base_a.named_parameters()]  # 0.weight, 0.bias, 2.weight...
            self._functional_call, self._vmap = functional_call, vmap

    # ---- layout -------------------------------------------------------------------------------
    def _from_linear(self, w):  # [n, out, in] -> this mode's weight layout
        return w.transpose(1, 2).contiguous() if self.mode == "bmm" else w.contiguous()

    def _from_linear_bias(self, b):  # [n, out] -> this mode's bias layout
        return b.unsqueeze(1).contiguous() if self.mode == "bmm" else b.contiguous()

    def linear_layout(self, params, index):
        """Entry `index` of stacked `params` as nn.Linear tensors [weight [out, in], bias [out], ...]."""
        out = []
        for i in range(0, len(params), 2):
            w, b = params[i][index], params[i + 1][index]
            out += [w.t(), b.squeeze(0)] if self.mode == "bmm" else [w, b]
        return out

    @torch.no_grad()
    def load_linear(self, params, index, tensors):
        """Set entry `index` of stacked `params` from nn.Linear tensors [weight, bias, ...]."""
        for i in range(0, len(params), 2):
            w, b = tensors[i], tensors[i + 1]
            params[i][index].copy_(w.t() if self.mode == "bmm" else w)
            params[i + 1][index].copy_(b.unsqueeze(0) if self.mode == "bmm" else b)

    # ---- nets ---------------------------------------------------------------------------------
    def _mlp_bmm(self, params, x):
        for i in range(N_LAYERS):
            x = torch.baddbmm(params[2 * i + 1], x, params[2 * i])
            if i < N_LAYERS - 1:
                x = torch.relu(x)
        return x

    def _mlp_vmap(self, base, params, x):
        d = dict(zip(self._names, params))
        return self._vmap(lambda p, xx: self._functional_call(base, p, (xx,)))(d, x)

    def actor_fwd(self, params, x):  # x [A, B, obs+goal] -> [A, B, act]
        if self.mode == "bmm":
            return torch.tanh(self._mlp_bmm(params, x))
        return torch.tanh(self._mlp_vmap(self._base_a, params, x))

    def critic_fwd(self, params, x):  # x [A, B, in] -> [A, 2, B, 1]
        A, B, n = x.shape
        x2 = x.unsqueeze(1).expand(A, 2, B, n).reshape(2 * A, B, n)
        y = self._mlp_bmm(params, x2) if self.mode == "bmm" else self._mlp_vmap(self._base_c, params, x2)
        return y.view(A, 2, B, 1)

    def q1_fwd(self, params, x):  # x [A, B, in] -> [A, B, 1], agent a's Q1 = ensemble row 2a
        p1 = [p[0::2] for p in params]
        return self._mlp_bmm(p1, x) if self.mode == "bmm" else self._mlp_vmap(self._base_c, p1, x)

    # ---- the update ---------------------------------------------------------------------------
    def update(self, batch, eps=None):
        """One critic update of every agent (+ actor and targets every POLICY_FREQ-th). `batch`:
        (o, g, a, o2, r) each [A, B, ...]; `eps`: standard-normal draw [A, B, act] for the target
        policy noise, or None to draw it here."""
        self.it += 1
        o_raw, g_raw, a, o2_raw, r = batch
        o = ((o_raw - self.o_mean) / self.o_std).clamp(-CLIP_OBS, CLIP_OBS)
        g = ((g_raw - self.g_mean) / self.g_std).clamp(-CLIP_OBS, CLIP_OBS)
        o2 = ((o2_raw - self.o_mean) / self.o_std).clamp(-CLIP_OBS, CLIP_OBS)

        with torch.no_grad():
            if eps is None:
                eps = torch.randn_like(a)
            noise = (eps * POLICY_NOISE).clamp(-NOISE_CLIP, NOISE_CLIP)
            a2 = (self.actor_fwd(self.actor_t, torch.cat([o2, g], 2)) + noise).clamp(-1.0, 1.0)
            tq = self.critic_fwd(self.critic_t, torch.cat([o2, g, a2], 2)).amin(dim=1)  # [A, B, 1]
            target = (r + GAMMA * tq).clamp(self.q_min, self.q_max)

        q = self.critic_fwd(self.critic, torch.cat([o, g, a], 2))  # [A, 2, B, 1]
        per_agent = (q - target.unsqueeze(1)).square().mean(dim=(2, 3)).sum(dim=1)  # [A]
        critic_loss = per_agent.sum()
        self.critic_opt.zero_grad(set_to_none=True)
        critic_loss.backward(inputs=self.critic)
        self.critic_opt.step()
        with torch.no_grad():
            self.loss_buf[0].copy_(critic_loss.detach() / self.A)

        if self.it % POLICY_FREQ == 0:
            x = torch.cat([o, g], 2)
            pi = self.actor_fwd(self.actor, x)
            q1 = self.q1_fwd(self.critic, torch.cat([o, g, pi], 2))  # [A, B, 1]
            if self.algo == "td3bc":
                lmbda = ALPHA / q1.detach().abs().mean(dim=(1, 2))  # [A], each agent its own
                per_agent = -lmbda * q1.mean(dim=(1, 2)) + (pi - a).square().mean(dim=(1, 2))
            else:
                per_agent = -q1.mean(dim=(1, 2))
            actor_loss = per_agent.sum()
            self.actor_opt.zero_grad(set_to_none=True)
            actor_loss.backward(inputs=self.actor)
            self.actor_opt.step()
            with torch.no_grad():
                self.loss_buf[1].copy_(actor_loss.detach() / self.A)
                torch._foreach_lerp_(self.actor_t + self.critic_t, self.actor + self.critic, TAU)

    # ---- CUDA graphs --------------------------------------------------------------------------
    def capture(self, batches, eps_list=None):
        """Capture the two-update cycle once per pair of batches (batches[2k], batches[2k+1]);
        call after an eager warm-up of >= 2 updates (Adam state must exist) with self.it even.
        eps_list: fixed noise per batch slot (for checks), else drawn inside the graphs."""
        assert self.it % POLICY_FREQ == 0 and self.actor_opt.state, "warm up an even number >= 2 first"
        torch.cuda.synchronize()
        self.graphs = []
        for k in range(len(batches) // 2):
            gph = torch.cuda.CUDAGraph()
            with torch.cuda.graph(gph):
                for j in (2 * k, 2 * k + 1):
                    self.update(batches[j], None if eps_list is None else eps_list[j])
            self.graphs.append(gph)
        self.it -= 2 * len(self.graphs)  # nothing ran while capturing
        torch.cuda.synchronize()

    def replay(self, cycle):
        """Two updates: graph `cycle % n_graphs` (i.e. batches 2k, 2k+1)."""
        self.graphs[cycle % len(self.graphs)].replay()
        self.it += 2


def make_batches(A, obs, goal, act, bs, gen, device, dtype=torch.float32, n=N_BATCHES):
    """Random stand-ins for replay samples, [A, B, ...], distributed as train_peer.make_batches."""
    out = []
    for _ in range(n):
        o = torch.randn(A, bs, obs, generator=gen, dtype=dtype)
        g = torch.randn(A, bs, goal, generator=gen, dtype=dtype)
        a = torch.rand(A, bs, act, generator=gen, dtype=dtype) * 2 - 1
        o2 = o + 0.05 * torch.randn(A, bs, obs, generator=gen, dtype=dtype)
        r = -(torch.rand(A, bs, 1, generator=gen, dtype=dtype) < 0.7).to(dtype)
        out.append(tuple(t.to(device) for t in (o, g, a, o2, r)))
    return out


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agents", type=int, default=10, help="independent agents trained at once (default 10)")
    ap.add_argument("--mode", choices=("bmm", "vmap"), default="bmm")
    ap.add_argument("--obs", type=int, default=25)
    ap.add_argument("--goal", type=int, default=3)
    ap.add_argument("--act", type=int, default=4)
    ap.add_argument("--hidden", type=int, default=256)
    ap.add_argument("--batch-size", type=int, default=512, help="per agent")
    ap.add_argument("--updates", type=int, default=100, help="timed critic updates (of all agents at once)")
    ap.add_argument("--seconds", type=float, default=None,
                    help="instead of --updates: time about this long (updates chosen from a short calibration)")
    ap.add_argument("--warmup", type=int, default=4, help="untimed updates first (default 4; even)")
    ap.add_argument("--threads", type=int, default=2, help="torch.set_num_threads (default 2)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--algo", choices=sorted(LR), default="td3bc")
    ap.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    ap.add_argument("--cuda-graph", action="store_true", help="replay the update cycle as CUDA graphs")
    ap.add_argument("--tf32", action="store_true", help="allow TF32 float32 matmuls on GPU (default: full float32)")
    ap.add_argument("--dtype", choices=("float32", "float64"), default="float32")
    ap.add_argument("--json", action="store_true", help="print one JSON line")
    a = ap.parse_args(argv)
    if a.agents < 1 or a.updates < 1 or a.warmup < 0 or a.threads < 1:
        ap.error("--agents, --updates and --threads must be >= 1, --warmup >= 0")
    if a.device == "cuda" and not torch.cuda.is_available():
        sys.exit("--device cuda: torch.cuda.is_available() is False")
    if a.cuda_graph and a.device != "cuda":
        ap.error("--cuda-graph needs --device cuda")
    warmup = a.warmup + (a.warmup % 2)  # even: the timed window starts on a critic-only update
    if a.cuda_graph:
        warmup = max(warmup, 2)

    torch.set_num_threads(a.threads)
    torch.manual_seed(a.seed)
    if a.device == "cuda":
        torch.backends.cuda.matmul.allow_tf32 = a.tf32
    dtype = getattr(torch, a.dtype)
    gen = torch.Generator().manual_seed(a.seed)
    device = torch.device(a.device)
    m = StackedTD3(a.agents, a.obs, a.goal, a.act, a.hidden, a.algo, device, dtype, a.mode, gen,
                   cuda_graph=a.cuda_graph)
    batches = make_batches(a.agents, a.obs, a.goal, a.act, a.batch_size, gen, device, dtype)

    def sync():
        if device.type == "cuda":
            torch.cuda.synchronize()

    tw = time.perf_counter()
    if a.cuda_graph:
        # Warm up on a side stream, as torch.cuda.graphs asks before capturing autograd + optimizer.
        s = torch.cuda.Stream()
        s.wait_stream(torch.cuda.current_stream())
        with torch.cuda.stream(s):
            for i in range(warmup):
                m.update(batches[i % N_BATCHES])
        torch.cuda.current_stream().wait_stream(s)
        m.capture(batches)
        m.replay(0)  # first replay uploads the graph
        m.replay(1)
        warmup += 4

        def run(n, start):  # n even; start = updates done so far in this loop's numbering
            for c in range(n // 2):
                m.replay(start // 2 + c)
    else:
        for i in range(warmup):
            m.update(batches[i % N_BATCHES])

        def run(n, start):
            for i in range(n):
                m.update(batches[(start + i) % N_BATCHES])
    sync()
    warm_secs = time.perf_counter() - tw

    done = warmup
    updates = a.updates
    if a.seconds is not None:
        # Calibrate: 2, 4, 8, ... updates until one round takes >= 0.15 s (or seconds/10).
        n, t = 2, 0.0
        while True:
            t0 = time.perf_counter()
            run(n, done)
            sync()
            t = time.perf_counter() - t0
            done += n
            if t >= min(0.15, a.seconds / 10) or n >= 1 << 16:
                break
            n *= 2
        updates = max(2, int(round(a.seconds * n / t / 2)) * 2)
    if a.cuda_graph:
        updates += updates % 2

    sync()
    t0 = time.perf_counter()
    run(updates, done)
    sync()
    secs = time.perf_counter() - t0

    closs, aloss = (float(x) for x in m.loss_buf.tolist())
    flops = flops_per_update(a.obs, a.goal, a.act, a.hidden, a.batch_size, POLICY_FREQ)
    ups = updates / secs
    res = {
        "peer": f"pytorch-stacked-{a.mode}" + ("-graph" if a.cuda_graph else ""), "torch": torch.__version__,
        "device": a.device, "agents": a.agents, "threads": torch.get_num_threads(),
        "batch_size": a.batch_size, "updates": updates, "seconds": secs,
        "agent_updates_per_sec": a.agents * ups, "updates_per_sec": ups,
        "flops_per_update": flops, "gflops_per_sec": a.agents * ups * flops / 1e9,
        "mode": a.mode, "cuda_graph": a.cuda_graph, "algo": a.algo, "hidden": a.hidden,
        "dims": [a.obs, a.goal, a.act], "dtype": a.dtype, "tf32": a.tf32 if a.device == "cuda" else False,
        "warmup": done, "warmup_seconds": warm_secs, "adam": m.opt_kwargs,
        "critic_loss": closs, "actor_loss": aloss, "python": platform.python_version(),
    }
    if device.type == "cuda":
        res["gpu"] = torch.cuda.get_device_name(device)
    if not (math.isfinite(closs) and math.isfinite(aloss)):
        print(f"warning: non-finite loss (critic {closs}, actor {aloss})", file=sys.stderr)
    if a.json:
        print(json.dumps(res), flush=True)
    else:
        print(f"{res['peer']} torch {torch.__version__} {a.algo} on {a.device} ({res['threads']} threads): "
              f"{a.agents} agents x {updates} updates of batch {a.batch_size} in {secs:.3f} s = "
              f"{res['agent_updates_per_sec']:.1f} agent-updates/s ({ups:.2f} updates/s per agent, "
              f"{res['gflops_per_sec']:.1f} GFLOP/s); mean critic loss {closs:.4g}", flush=True)


if __name__ == "__main__":
    main()
