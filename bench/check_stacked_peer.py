#!/usr/bin/env python3
"""Correctness check of the many-agent peers: train_peer_stacked.py (and train_peer_jax.py) give
every agent the weights that train_peer.py's single-agent update gives it.

Small problem (default A = 3 agents, hidden 32, batch 16, FetchPush dims, float64 on CPU):

1. A train_peer.Agent's are built (train_peer.HIDDEN set to --hidden), each with its own init and
   normaliser; the stacked peer (each --modes: bmm, vmap) is loaded with exactly their weights,
   targets and normaliser statistics.
2. --updates updates (default 6: three actor updates and Polyak steps) on the same inputs: per
   update one batch [A, B, ...] and one standard-normal draw eps [A, B, act] for the target-policy
   noise; agent i gets slice i (train_peer.Agent.update(batch, eps=...)).
3. Every parameter of every agent (actor, Q1, Q2 and the three targets) is compared; the largest
   absolute difference must be under --tol (default 1e-10 for float64, 5e-5 for float32), and the
   mean losses must agree. "moved" says how far the weights went from their init, so a pass is
   not two frozen copies agreeing.
4. If jax imports in this interpreter: train_peer_jax's vmapped update, from the same init, same
   batches and eps, against the stacked peer (float64 via jax_enable_x64 when --dtype float64).
5. With --device cuda: also the stacked peer replaying CUDA graphs (--cuda-graph) against the same
   peer run eagerly, with fixed noise per batch slot.

Run with both algos (td3bc, td3). Prints one line per comparison and exits 1 on any failure.

Usage:
    check_stacked_peer.py [--device cpu|cuda] [--dtype float64|float32] [--agents 3] [--hidden 32]
                          [--batch-size 16] [--updates 6] [--modes bmm,vmap] [--no-jax] [--tol T]
"""
from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import torch  # noqa: E402

import train_peer  # noqa: E402
import train_peer_stacked as stk  # noqa: E402

OBS, GOAL, ACT = 25, 3, 4
FAILURES = []


def report(name, diff, tol, moved, extra=""):
    ok = diff <= tol and moved > 10 * tol
    if not ok:
        FAILURES.append(name)
    print(f"{'ok  ' if ok else 'FAIL'} {name:58s} max |diff| {diff:.3e} (tol {tol:.0e}); moved {moved:.3e}{extra}",
          flush=True)


def make_inputs(A, B, n, dtype, device, seed):
    gen = torch.Generator().manual_seed(seed)
    batches = stk.make_batches(A, OBS, GOAL, ACT, B, gen, device, dtype, n=n)
    eps = [torch.randn(A, B, ACT, generator=gen, dtype=dtype).to(device) for _ in range(n)]
    return batches, eps


def single_agents(A, algo, device, dtype, seed):
    agents = []
    for i in range(A):
        torch.manual_seed(seed + i)
        ag = train_peer.Agent(OBS, GOAL, ACT, algo, device, torch.Generator().manual_seed(seed + i))
        for net in (ag.actor, ag.q1, ag.q2, ag.actor_t, ag.q1_t, ag.q2_t):
            net.to(dtype)  # keeps the Parameter objects, so the optimisers still hold them
        for nz in (ag.o_norm, ag.g_norm):
            nz.mean, nz.std = nz.mean.to(dtype), nz.std.to(dtype)
        agents.append(ag)
    return agents


def load_stacked(m, agents):
    for i, ag in enumerate(agents):
        m.load_linear(m.actor, i, list(ag.actor.parameters()))
        m.load_linear(m.critic, 2 * i, list(ag.q1.parameters()))
        m.load_linear(m.critic, 2 * i + 1, list(ag.q2.parameters()))
        m.load_linear(m.actor_t, i, list(ag.actor_t.parameters()))
        m.load_linear(m.critic_t, 2 * i, list(ag.q1_t.parameters()))
        m.load_linear(m.critic_t, 2 * i + 1, list(ag.q2_t.parameters()))
        with torch.no_grad():
            m.o_mean[i, 0], m.o_std[i, 0] = ag.o_norm.mean, ag.o_norm.std
            m.g_mean[i, 0], m.g_std[i, 0] = ag.g_norm.mean, ag.g_norm.std


def agent_tensors(ag):
    return [p.detach() for net in (ag.actor, ag.q1, ag.q2, ag.actor_t, ag.q1_t, ag.q2_t) for p in net.parameters()]


def stacked_agent_tensors(m, i):
    return [t.detach() for t in (m.linear_layout(m.actor, i) + m.linear_layout(m.critic, 2 * i)
                                 + m.linear_layout(m.critic, 2 * i + 1) + m.linear_layout(m.actor_t, i)
                                 + m.linear_layout(m.critic_t, 2 * i) + m.linear_layout(m.critic_t, 2 * i + 1))]


def max_diff(xs, ys):
    return max(float((x - y).abs().max()) for x, y in zip(xs, ys))


def check_vs_single(args, algo, mode, dtype, tol):
    A, B, dev = args.agents, args.batch_size, torch.device(args.device)
    agents = single_agents(A, algo, dev, dtype, args.seed)
    m = stk.StackedTD3(A, OBS, GOAL, ACT, args.hidden, algo, dev, dtype, mode, fused=False)
    load_stacked(m, agents)
    init = [[t.clone() for t in agent_tensors(ag)] for ag in agents]  # detach() shares storage
    batches, eps = make_inputs(A, B, args.updates, dtype, dev, args.seed + 100)
    for k in range(args.updates):
        for i, ag in enumerate(agents):
            ag.update(tuple(t[i] for t in batches[k]), eps=eps[k][i])
        m.update(batches[k], eps[k])
    diff = max(max_diff(agent_tensors(ag), stacked_agent_tensors(m, i)) for i, ag in enumerate(agents))
    moved = max(max_diff(agent_tensors(ag), init[i]) for i, ag in enumerate(agents))
    cl = sum(float(ag.last["critic_loss"].detach()) for ag in agents) / A
    al = sum(float(ag.last["actor_loss"].detach()) for ag in agents) / A
    sl = m.loss_buf.tolist()
    ldiff = max(abs(cl - sl[0]), abs(al - sl[1]))
    if ldiff > max(tol, 1e-6) * 10:
        FAILURES.append(f"losses {algo} {mode}")
    report(f"stacked {mode} vs {A} x train_peer.py [{algo}, {args.device}, {args.dtype}]", diff, tol, moved,
           f"; losses {sl[0]:.5g}/{sl[1]:.5g} vs {cl:.5g}/{al:.5g}")


def check_graph(args, algo, dtype, tol):
    A, B, dev = args.agents, args.batch_size, torch.device("cuda")
    n = stk.N_BATCHES
    batches, eps = make_inputs(A, B, n, dtype, dev, args.seed + 200)
    ms = [stk.StackedTD3(A, OBS, GOAL, ACT, args.hidden, algo, dev, dtype, "bmm",
                         torch.Generator().manual_seed(args.seed), cuda_graph=True) for _ in range(2)]
    eager, graphed = ms
    init = [p.detach().clone() for p in eager.actor + eager.critic]
    # Both: 2 eager warm-up updates (graphed one on a side stream), then 2 cycles of 8 updates.
    for i in range(2):
        eager.update(batches[i], eps[i])
    s = torch.cuda.Stream()
    s.wait_stream(torch.cuda.current_stream())
    with torch.cuda.stream(s):
        for i in range(2):
            graphed.update(batches[i], eps[i])
    torch.cuda.current_stream().wait_stream(s)
    graphed.capture(batches, eps)
    for r in range(2):
        for j in range(n):
            eager.update(batches[j], eps[j])
        for c in range(n // 2):
            graphed.replay(c)
    torch.cuda.synchronize()
    pe = [p.detach() for p in eager.actor + eager.critic + eager.actor_t + eager.critic_t]
    pg = [p.detach() for p in graphed.actor + graphed.critic + graphed.actor_t + graphed.critic_t]
    report(f"stacked bmm CUDA graphs vs eager [{algo}, {args.dtype}]", max_diff(pe, pg), tol,
           max_diff(pe[:len(init)], init))


def check_jax(args, algo, dtype, tol):
    os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")  # share the GPU with torch
    import train_peer_jax as tpj
    jax = tpj.configure("cpu" if args.device == "cpu" else "gpu", None, False, False, args.dtype == "float64")
    import jax.numpy as jnp
    import numpy as np

    A, B, dev = args.agents, args.batch_size, torch.device(args.device)
    m = stk.StackedTD3(A, OBS, GOAL, ACT, args.hidden, algo, dev, dtype, "bmm",
                       torch.Generator().manual_seed(args.seed), fused=False)
    J = lambda t: jnp.asarray(np.asarray(t.detach().cpu()))  # noqa: E731

    def to_jax(ps, critic):
        out = []
        for i in range(0, len(ps), 2):
            w, b = ps[i], ps[i + 1]  # [E, in, out], [E, 1, out]
            if critic:
                out.append((J(w).reshape(A, 2, *w.shape[1:]), J(b).reshape(A, 2, b.shape[-1])))
            else:
                out.append((J(w), J(b).reshape(A, b.shape[-1])))
        return out

    state = tpj.make_state(to_jax(m.actor, False), to_jax(m.critic, True),
                           to_jax(m.actor_t, False), to_jax(m.critic_t, True))
    consts = (J(m.o_mean), J(m.o_std), J(m.g_mean), J(m.g_std))
    init = [p.detach().clone() for p in m.actor + m.critic]
    batches, eps = make_inputs(A, B, args.updates, dtype, dev, args.seed + 300)
    step = tpj.make_step(algo)
    for k in range(args.updates):
        m.update(batches[k], eps[k])
        state = step(state, consts, tuple(J(t) for t in batches[k]), J(eps[k]), (k + 1) % 2 == 0)
    got = [x for w, b in state["actor"] + state["critic"] + state["actor_t"] + state["critic_t"] for x in (w, b)]
    want = [J(p) for p in m.actor + m.critic + m.actor_t + m.critic_t]
    diff = max(float(jnp.abs(g.reshape(w.shape) - w).max()) for g, w in zip(got, want))
    moved = max_diff([p.detach() for p in m.actor + m.critic], init)
    jl = np.asarray(state["losses"]).mean(axis=0)
    sl = m.loss_buf.tolist()
    if max(abs(jl[0] - sl[0]), abs(jl[1] - sl[1])) > max(tol, 1e-6) * 10:
        FAILURES.append(f"jax losses {algo}")
    report(f"jax {jax.__version__} vs stacked bmm [{algo}, {args.device}, {args.dtype}]", diff, tol, moved,
           f"; losses {jl[0]:.5g}/{jl[1]:.5g} vs {sl[0]:.5g}/{sl[1]:.5g}")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--device", choices=("cpu", "cuda"), default="cpu")
    ap.add_argument("--dtype", choices=("float64", "float32"), default="float64")
    ap.add_argument("--agents", type=int, default=3)
    ap.add_argument("--hidden", type=int, default=32)
    ap.add_argument("--batch-size", type=int, default=16)
    ap.add_argument("--updates", type=int, default=6)
    ap.add_argument("--modes", default="bmm,vmap")
    ap.add_argument("--algos", default="td3bc,td3")
    ap.add_argument("--no-jax", action="store_true")
    ap.add_argument("--tol", type=float, default=None)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.device == "cuda" and not torch.cuda.is_available():
        sys.exit("--device cuda: no CUDA")
    dtype = getattr(torch, args.dtype)
    tol = args.tol if args.tol is not None else (1e-10 if args.dtype == "float64" else 5e-5)
    torch.set_num_threads(1)
    torch.backends.cuda.matmul.allow_tf32 = False
    train_peer.HIDDEN = args.hidden  # train_peer.mlp reads it when the nets are built

    algos = args.algos.split(",")
    for algo in algos:
        for mode in args.modes.split(","):
            check_vs_single(args, algo, mode, dtype, tol)
        if args.device == "cuda":
            check_graph(args, algo, dtype, tol)
    if not args.no_jax:
        import importlib.util
        have_jax = importlib.util.find_spec("jax") is not None  # no import yet: JAX_PLATFORMS first
        if not have_jax:
            print("skip jax: not importable in this interpreter")
        else:
            for algo in algos:
                check_jax(args, algo, dtype, tol)
    print(f"{'FAILED: ' + ', '.join(FAILURES) if FAILURES else 'all passed'}")
    sys.exit(1 if FAILURES else 0)


if __name__ == "__main__":
    main()
