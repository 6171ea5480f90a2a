#!/usr/bin/env python3
"""JAX peer of A independent goal-conditioned TD3+BC (or TD3) agents updated at once: a peer for
"many agents per process" (issue 12).

Per agent the arithmetic of train_peer.py / train_peer_stacked.py (check_stacked_peer.py checks
it against the stacked PyTorch peer):

    actor   [obs+goal] -> H -> H -> H -> act, ReLU, tanh                     (H = --hidden, 256)
    critics twin [obs+goal+act] -> H -> H -> H -> 1, ReLU, as an ensemble of 2 (weights [2, in, out],
            jax.vmap over the 2), one Adam for both
    inputs  (x - mean) / std clipped to [-5, 5] for obs and goal, own statistics per agent
    target  r + 0.98 * min(Q1', Q2')(s', g, clip(pi'(s', g) + clip(0.2 N, +-0.5), +-1)),
            clamped to [-1 / (1 - 0.98), 0]
    critic  mse(Q1, target) + mse(Q2, target)
    actor   td3bc: -lambda * Q1(s, g, pi).mean() + mse(pi, a), lambda = 2.5 / |Q1|.mean()
            (stop_gradient; over the agent's own batch); td3: -Q1(s, g, pi).mean();
            every 2nd update, then Polyak tp = 0.005 p + 0.995 tp on actor and both critics
    Adam    hand-written to match torch.optim.Adam: lr 3e-4 (td3bc) / 1e-3 (td3), betas
            (0.9, 0.999), eps 1e-8, p -= lr/(1-b1^t) * m / (sqrt(v)/sqrt(1-b2^t) + eps)

The per-agent update is a pure function (params, target params, Adam state, batch, noise) ->
new state; `jax.vmap` maps it over the agent axis (A = 1 is a vmap of size 1) and `jax.jit`
compiles a two-update cycle, critic-only update then critic + actor + targets, per call. (Chosen
over a lax.cond on the step parity without measuring the latter: the cycle is one straight-line
program with half the dispatches, while a cond on GPU decides at run time between branches.) The state is donated to the call, so it is updated in place. Noise:
one key per call, split into a standard-normal draw [A, B, act] per update, so every agent and
update gets its own. The actor loss is differentiated for the actor's parameters only (XLA then
does not compute Q1's weight gradients, which train_peer.py computes and discards).

FLOPs per agent-update (matmuls only; train_flops.py says how they are counted): FetchPush dims
(obs 25, goal 3, act 4), H 256, batch 512, policy delay 2:
    critic update  F_a + 2 F_c + 6 F_c = 1,285,554,176
    actor update   3 F_a + 2 F_c       =   713,555,968 (every 2nd)
    per update     1,642,332,160 ≈ 1.64 GFLOP   (F_a = 142,606,336, F_c = 142,868,480)

Batches are random arrays [A, B, ...] made on the device before timing (8, cycled by pairs).
Timing: jax.block_until_ready around the loop of jitted calls; compile time is in the warm-up.

Device and threads: --device cpu|gpu (cuda is an alias of gpu) sets JAX_PLATFORMS before jax is
imported. --threads N on CPU sets XLA_FLAGS="--xla_cpu_multi_thread_eigen=true
intra_op_parallelism_threads=N" (the usual recipe, appended to any XLA_FLAGS already set) -- but
XLA's CPU backend sizes its thread pools from the CPUs the process may run on, not from a flag,
so N is NOT a strict limit; --pin additionally restricts the process's CPU affinity to N CPUs
before jax starts, which XLA does respect. On the 2-core build machine with N = 2 the question
does not arise. Float32 matmuls on GPU use full float32 (jax_default_matmul_precision "highest",
as PyTorch's default) unless --tf32. On GPU the first call compiles for ~40 s (XLA autotunes its
Triton GEMMs; not timed): XLA_FLAGS=--xla_gpu_enable_triton_gemm=false cuts that to ~2 s at
about the same speed (H100, A = 10: 13.2k vs 13.5k agent-updates/s); --xla_gpu_autotune_level=0
compiles in ~5 s but ran 3.5x slower.

Prints one line; with --json one JSON object:
    {"peer": "jax", "jax": ..., "device": ..., "agents": A, "threads": ..., "batch_size": ...,
     "updates": ..., "seconds": ..., "agent_updates_per_sec": ..., "updates_per_sec": (per agent),
     "flops_per_update": ..., "gflops_per_sec": ..., ...}

Usage:
    train_peer_jax.py [--agents 10] [--obs 25] [--goal 3] [--act 4] [--hidden 256]
                      [--batch-size 512] [--updates 100 | --seconds S] [--warmup 4] [--threads 2]
                      [--pin] [--seed 0] [--algo td3bc|td3] [--device cpu|gpu] [--tf32]
                      [--dtype float32|float64] [--json]
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

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
BETA1, BETA2, ADAM_EPS = 0.9, 0.999, 1e-8
N_LAYERS = 4


# ---- the per-agent update (pure functions; jax imported lazily so this module imports without it) ----

def mlp(params, x):
    """params: [(W [in, out], b [out]), ...]; ReLU between layers."""
    for i, (w, b) in enumerate(params):
        x = x @ w + b
        if i < len(params) - 1:
            x = _jnp().maximum(x, 0)
    return x


def critics(params, x):
    """Twin critics as an ensemble: params [(W [2, in, out], b [2, out]), ...] -> [2, B, 1]."""
    import jax
    return jax.vmap(mlp, in_axes=(0, None))(params, x)


def q1_params(params):
    import jax
    return jax.tree_util.tree_map(lambda p: p[0], params)


def _jnp():
    import jax.numpy as jnp
    return jnp


def adam_init(params):
    import jax
    jnp = _jnp()
    z = jax.tree_util.tree_map(jnp.zeros_like, params)
    return {"m": z, "v": jax.tree_util.tree_map(jnp.zeros_like, params), "t": jnp.zeros((), jnp.int32)}


def adam_step(params, grads, opt, lr):
    """torch.optim.Adam's arithmetic (single-tensor path), betas (0.9, 0.999), eps 1e-8."""
    import jax
    jnp = _jnp()
    t = opt["t"] + 1
    m = jax.tree_util.tree_map(lambda m, g: m + (g - m) * (1 - BETA1), opt["m"], grads)  # lerp, as torch
    v = jax.tree_util.tree_map(lambda v, g: v * BETA2 + (1 - BETA2) * g * g, opt["v"], grads)
    tf = t.astype(jnp.float32) if jax.tree_util.tree_leaves(params)[0].dtype == jnp.float32 else t.astype(jnp.float64)
    bc1 = 1 - BETA1 ** tf
    bc2_sqrt = jnp.sqrt(1 - BETA2 ** tf)
    step = lr / bc1
    new = jax.tree_util.tree_map(lambda p, m, v: p - step * (m / (jnp.sqrt(v) / bc2_sqrt + ADAM_EPS)),
                                 params, m, v)
    return new, {"m": m, "v": v, "t": t}


def agent_update(state, consts, batch, eps, *, do_actor, algo):
    """One critic update of one agent (+ actor and targets when do_actor). state: dict with
    actor, critic, actor_t, critic_t, actor_opt, critic_opt, losses; consts: normaliser
    statistics (o_mean, o_std, g_mean, g_std); batch: (o, g, a, o2, r) [B, ...]; eps [B, act]."""
    import jax
    jnp = _jnp()
    lr = LR[algo]
    o_raw, g_raw, a, o2_raw, r = batch
    o_mean, o_std, g_mean, g_std = consts
    o = jnp.clip((o_raw - o_mean) / o_std, -CLIP_OBS, CLIP_OBS)
    g = jnp.clip((g_raw - g_mean) / g_std, -CLIP_OBS, CLIP_OBS)
    o2 = jnp.clip((o2_raw - o_mean) / o_std, -CLIP_OBS, CLIP_OBS)

    noise = jnp.clip(eps * POLICY_NOISE, -NOISE_CLIP, NOISE_CLIP)
    a2 = jnp.clip(jnp.tanh(mlp(state["actor_t"], jnp.concatenate([o2, g], 1))) + noise, -1.0, 1.0)
    tq = critics(state["critic_t"], jnp.concatenate([o2, g, a2], 1)).min(axis=0)  # [B, 1]
    target = jax.lax.stop_gradient(jnp.clip(r + GAMMA * tq, -1.0 / (1.0 - GAMMA), 0.0))

    x = jnp.concatenate([o, g, a], 1)

    def critic_loss(cp):
        q = critics(cp, x)  # [2, B, 1]
        return jnp.square(q - target[None]).mean(axis=(1, 2)).sum()

    closs, grads = jax.value_and_grad(critic_loss)(state["critic"])
    critic, critic_opt = adam_step(state["critic"], grads, state["critic_opt"], lr)
    new = dict(state, critic=critic, critic_opt=critic_opt)
    new["losses"] = state["losses"].at[0].set(closs)
    if not do_actor:
        return new

    xa = jnp.concatenate([o, g], 1)
    cq1 = q1_params(critic)

    def actor_loss(ap):
        pi = jnp.tanh(mlp(ap, xa))
        q = mlp(cq1, jnp.concatenate([o, g, pi], 1))
        if algo == "td3bc":
            lmbda = ALPHA / jax.lax.stop_gradient(jnp.abs(q).mean())
            return -lmbda * q.mean() + jnp.square(pi - a).mean()
        return -q.mean()

    aloss, agrads = jax.value_and_grad(actor_loss)(state["actor"])
    actor, actor_opt = adam_step(state["actor"], agrads, state["actor_opt"], lr)
    polyak = lambda p, tp: TAU * p + (1 - TAU) * tp  # noqa: E731  (sfujim's form, as train_peer.py)
    new.update(actor=actor, actor_opt=actor_opt,
               actor_t=jax.tree_util.tree_map(polyak, actor, state["actor_t"]),
               critic_t=jax.tree_util.tree_map(polyak, critic, state["critic_t"]))
    new["losses"] = new["losses"].at[1].set(aloss)
    return new


def init_state(key, A, obs, goal, act, hidden, dtype):
    """A agents' state with a leading agent axis; nn.Linear-style init U(+-1/sqrt(in))."""
    import jax
    jnp = _jnp()
    sizes_a = [obs + goal, hidden, hidden, hidden, act]
    sizes_c = [obs + goal + act, hidden, hidden, hidden, 1]

    def layers(key, lead, sizes):
        ps = []
        for i in range(N_LAYERS):
            key, kw, kb = jax.random.split(key, 3)
            bound = 1.0 / math.sqrt(sizes[i])
            w = jax.random.uniform(kw, (*lead, sizes[i], sizes[i + 1]), dtype, -bound, bound)
            b = jax.random.uniform(kb, (*lead, sizes[i + 1]), dtype, -bound, bound)
            ps.append((w, b))
        return key, ps

    key, actor = layers(key, (A,), sizes_a)
    key, critic = layers(key, (A, 2), sizes_c)
    return key, make_state(actor, critic)


def make_state(actor, critic, actor_t=None, critic_t=None):
    """State from stacked parameters (leading agent axis); targets default to copies."""
    import jax
    jnp = _jnp()
    cp = lambda t: jax.tree_util.tree_map(jnp.array, t)  # noqa: E731
    A = actor[0][0].shape[0]
    vadam = jax.vmap(adam_init)
    return {"actor": actor, "critic": critic,
            "actor_t": cp(actor if actor_t is None else actor_t),
            "critic_t": cp(critic if critic_t is None else critic_t),
            "actor_opt": vadam(actor), "critic_opt": vadam(critic),
            "losses": jnp.zeros((A, 2), actor[0][0].dtype)}


def make_step(algo):
    """jitted (state, consts, batch, eps, do_actor) -> state over all agents, with eps given
    (for check_stacked_peer.py). do_actor is static."""
    import jax
    from functools import partial

    def step(state, consts, batch, eps, do_actor):
        f = partial(agent_update, do_actor=do_actor, algo=algo)
        return jax.vmap(f)(state, consts, batch, eps)

    return jax.jit(step, static_argnums=(4,))


def make_cycle(algo, A, B, act, dtype):
    """jitted (state, key, consts, batch0, batch1) -> (state, key): a critic-only update on batch0
    then a critic + actor + targets update on batch1 for all agents; state donated."""
    import jax
    from functools import partial
    upd0 = jax.vmap(partial(agent_update, do_actor=False, algo=algo))
    upd1 = jax.vmap(partial(agent_update, do_actor=True, algo=algo))

    def cycle(state, key, consts, b0, b1):
        key, k0, k1 = jax.random.split(key, 3)
        state = upd0(state, consts, b0, jax.random.normal(k0, (A, B, act), dtype))
        state = upd1(state, consts, b1, jax.random.normal(k1, (A, B, act), dtype))
        return state, key

    return jax.jit(cycle, donate_argnums=(0,))


def make_consts(key, A, obs, goal, dtype):
    import jax
    k1, k2, k3, k4 = jax.random.split(key, 4)
    return (jax.random.normal(k1, (A, 1, obs), dtype) * 0.5, jax.random.uniform(k2, (A, 1, obs), dtype) + 0.5,
            jax.random.normal(k3, (A, 1, goal), dtype) * 0.5, jax.random.uniform(k4, (A, 1, goal), dtype) + 0.5)


def make_batches(key, A, obs, goal, act, bs, dtype, n=N_BATCHES):
    """Random stand-ins [A, B, ...], distributed as train_peer.make_batches."""
    import jax
    jnp = _jnp()
    out = []
    for _ in range(n):
        key, *k = jax.random.split(key, 6)
        o = jax.random.normal(k[0], (A, bs, obs), dtype)
        g = jax.random.normal(k[1], (A, bs, goal), dtype)
        a = jax.random.uniform(k[2], (A, bs, act), dtype) * 2 - 1
        o2 = o + 0.05 * jax.random.normal(k[3], (A, bs, obs), dtype)
        r = -(jax.random.uniform(k[4], (A, bs, 1), dtype) < 0.7).astype(dtype)
        out.append(tuple(jnp.asarray(t) for t in (o, g, a, o2, r)))
    return key, out


def configure(device: str, threads: int | None, pin: bool, tf32: bool, float64: bool):
    """Environment for jax; call before importing it."""
    os.environ["JAX_PLATFORMS"] = "cpu" if device == "cpu" else "cuda"
    if device == "cpu" and threads:
        flags = f"--xla_cpu_multi_thread_eigen=true intra_op_parallelism_threads={threads}"
        os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + flags).strip()
        if pin and hasattr(os, "sched_setaffinity"):
            cpus = sorted(os.sched_getaffinity(0))[:threads]
            os.sched_setaffinity(0, cpus)
    import jax
    if float64:
        jax.config.update("jax_enable_x64", True)
    jax.config.update("jax_default_matmul_precision", "default" if tf32 else "highest")
    return jax


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--agents", type=int, default=10)
    ap.add_argument("--obs", type=int, default=25)
    ap.add_argument("--goal", type=int, default=3)
    ap.add_argument("--act", type=int, default=4)
    ap.add_argument("--hidden", type=int, default=256)
    ap.add_argument("--batch-size", type=int, default=512, help="per agent")
    ap.add_argument("--updates", type=int, default=100, help="timed critic updates, rounded up to even")
    ap.add_argument("--seconds", type=float, default=None,
                    help="instead of --updates: time about this long (updates chosen from a short calibration)")
    ap.add_argument("--warmup", type=int, default=4, help="untimed updates first, compile included (even, >= 2)")
    ap.add_argument("--threads", type=int, default=2, help="CPU: XLA_FLAGS thread recipe (not a strict limit)")
    ap.add_argument("--pin", action="store_true", help="CPU: restrict affinity to --threads CPUs before jax starts")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--algo", choices=sorted(LR), default="td3bc")
    ap.add_argument("--device", choices=("cpu", "gpu", "cuda"), default="cpu")
    ap.add_argument("--tf32", action="store_true", help="GPU: default matmul precision (TF32) instead of highest")
    ap.add_argument("--dtype", choices=("float32", "float64"), default="float32")
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    if a.agents < 1 or a.updates < 1 or a.warmup < 0 or a.threads < 1:
        ap.error("--agents, --updates and --threads must be >= 1, --warmup >= 0")
    device = "cpu" if a.device == "cpu" else "gpu"
    jax = configure(device, a.threads, a.pin, a.tf32, a.dtype == "float64")
    import jax.numpy as jnp

    dev = jax.devices()[0]
    dtype = jnp.float64 if a.dtype == "float64" else jnp.float32
    key = jax.random.PRNGKey(a.seed)
    key, k_init, k_norm, k_batch = jax.random.split(key, 4)
    _, state = init_state(k_init, a.agents, a.obs, a.goal, a.act, a.hidden, dtype)
    consts = make_consts(k_norm, a.agents, a.obs, a.goal, dtype)
    _, batches = make_batches(k_batch, a.agents, a.obs, a.goal, a.act, a.batch_size, dtype)
    cycle = make_cycle(a.algo, a.agents, a.batch_size, a.act, dtype)
    jax.block_until_ready((state, consts, batches))

    def run(n_cycles, start):
        nonlocal state, key
        for c in range(n_cycles):
            k = 2 * ((start + c) % (N_BATCHES // 2))
            state, key = cycle(state, key, consts, batches[k], batches[k + 1])

    tw = time.perf_counter()
    warm_cycles = max(1, (a.warmup + 1) // 2)
    run(warm_cycles, 0)
    jax.block_until_ready(state)
    warm_secs = time.perf_counter() - tw
    done = warm_cycles

    cycles = (a.updates + 1) // 2
    if a.seconds is not None:
        n = 1
        while True:
            t0 = time.perf_counter()
            run(n, done)
            jax.block_until_ready(state)
            t = time.perf_counter() - t0
            done += n
            if t >= min(0.15, a.seconds / 10) or n >= 1 << 15:
                break
            n *= 2
        cycles = max(1, int(round(a.seconds * n / t)))

    jax.block_until_ready(state)
    t0 = time.perf_counter()
    run(cycles, done)
    jax.block_until_ready(state)
    secs = time.perf_counter() - t0

    updates = 2 * cycles
    losses = state["losses"].mean(axis=0)
    closs, aloss = float(losses[0]), float(losses[1])
    flops = flops_per_update(a.obs, a.goal, a.act, a.hidden, a.batch_size, POLICY_FREQ)
    ups = updates / secs
    res = {
        "peer": "jax", "jax": jax.__version__, "device": device, "agents": a.agents,
        "threads": a.threads if device == "cpu" else None, "batch_size": a.batch_size, "updates": updates,
        "seconds": secs, "agent_updates_per_sec": a.agents * ups, "updates_per_sec": ups,
        "flops_per_update": flops, "gflops_per_sec": a.agents * ups * flops / 1e9,
        "algo": a.algo, "hidden": a.hidden, "dims": [a.obs, a.goal, a.act], "dtype": a.dtype,
        "tf32": a.tf32 if device == "gpu" else False, "warmup": 2 * done, "warmup_seconds": warm_secs,
        "xla_flags": os.environ.get("XLA_FLAGS", ""), "pinned": a.pin, "jax_device": str(dev),
        "critic_loss": closs, "actor_loss": aloss, "python": platform.python_version(),
    }
    if device == "gpu":
        res["gpu"] = getattr(dev, "device_kind", str(dev))
    if not (math.isfinite(closs) and math.isfinite(aloss)):
        print(f"warning: non-finite loss (critic {closs}, actor {aloss})", file=sys.stderr)
    if a.json:
        print(json.dumps(res), flush=True)
    else:
        print(f"jax {jax.__version__} {a.algo} on {dev} ({res['threads']} threads): {a.agents} agents x {updates} "
              f"updates of batch {a.batch_size} in {secs:.3f} s = {res['agent_updates_per_sec']:.1f} agent-updates/s "
              f"({ups:.2f} updates/s per agent, {res['gflops_per_sec']:.1f} GFLOP/s); mean critic loss {closs:.4g}",
              flush=True)


if __name__ == "__main__":
    main()
