#!/usr/bin/env python3
"""A goal-conditioned IQL agent (OGBench's GCIQL) in plain JAX, trained on pgser's OGBench batches.

    python examples/gciql_jax.py TABLE [--steps 300] [--batch-size 256] [--memory-budget 2GB]

TABLE is a pgser trajectory table or table folder made from OGBench data (`pgser-etl convert
pointmaze-medium-navigate-v0.npz -o pm.parquet`, or a folder of Horizon Reduction's shards:
`pgser-etl convert shards/ -o table/`). The batches come from

    dataset = pgser.Sampler(TABLE, layout="ogbench", config=CONFIG)

where OGBench's trainer has `dataset = GCDataset(Dataset.create(**train_dataset), config)`: the
one object a JAX agent replaces. `train()` takes either, or anything with `.sample(batch_size)`
returning OGBench's dict (observations, next_observations, actions, rewards, masks,
value_goals, actor_goals), and CONFIG is an OGBench agent config, passed to pgser unchanged.

The agent is OGBench's GCIQL (impls/agents/gciql.py) written with jax.numpy alone, no flax or
optax: a value network V(s, g) fitted by expectile regression (0.9) to the target critics'
min Q; two critics Q(s, g, a) fitted to r + discount · mask · V(s', g); a Gaussian actor of
constant standard deviation trained by DDPG+BC (-Q / mean|Q| - alpha · log pi(a | s, g));
MLPs with GELU and layer norm; one Adam over all three (each loss reaches only its own network,
as in OGBench's `params=grad_params` selections); target critics by Polyak averaging.

Every `--log-every` steps a line with the losses; the last line is a JSON summary, with the mean
V(s, g) of an evaluation batch's rows whose goal is the state itself (`v_reached`) and whose goal
is a random state (`v_random`): a trained value tells them apart (tests/python/
test_gciql_example.py asserts it, and that the critic's loss falls).
"""

import argparse
import json
import time

import jax
import jax.numpy as jnp
import numpy as np

# OGBench's GCIQL defaults (impls/agents/gciql.py, get_config), smaller networks.
CONFIG = dict(
    agent_name="gciql",
    lr=3e-4,
    batch_size=256,
    actor_hidden_dims=(256, 256),
    value_hidden_dims=(256, 256),
    layer_norm=True,
    discount=0.99,
    tau=0.005,
    expectile=0.9,
    actor_loss="ddpgbc",
    alpha=0.3,
    const_std=True,
    discrete=False,
    encoder=None,
    dataset_class="GCDataset",
    value_p_curgoal=0.2,
    value_p_trajgoal=0.5,
    value_p_randomgoal=0.3,
    value_geom_sample=True,
    actor_p_curgoal=0.0,
    actor_p_trajgoal=1.0,
    actor_p_randomgoal=0.0,
    actor_geom_sample=False,
    gc_negative=True,
    p_aug=0.0,
    frame_stack=None,
)

KEYS = ("observations", "next_observations", "actions", "rewards", "masks", "value_goals", "actor_goals")


def mlp_init(key, sizes):
    """Weights of an MLP: OGBench's default init (variance scaling, fan_avg, uniform), zero biases,
    layer-norm scales of one."""
    layers = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        key, k = jax.random.split(key)
        limit = np.sqrt(3.0 / ((a + b) / 2.0))
        layer = {"w": jax.random.uniform(k, (a, b), jnp.float32, -limit, limit), "b": jnp.zeros(b)}
        if i + 2 < len(sizes):
            layer["scale"], layer["bias"] = jnp.ones(b), jnp.zeros(b)
        layers.append(layer)
    return layers


def mlp(layers, x, layer_norm=True):
    """OGBench's MLP: Dense, then GELU and layer norm on every hidden layer."""
    for layer in layers[:-1]:
        x = jax.nn.gelu(x @ layer["w"] + layer["b"])
        if layer_norm:
            mean, var = x.mean(-1, keepdims=True), x.var(-1, keepdims=True)
            x = (x - mean) / jnp.sqrt(var + 1e-6) * layer["scale"] + layer["bias"]
    last = layers[-1]
    return x @ last["w"] + last["b"]


def init(key, obs_dim, act_dim, cfg):
    kv, kq1, kq2, ka = jax.random.split(key, 4)
    vh, ah = list(cfg["value_hidden_dims"]), list(cfg["actor_hidden_dims"])
    critic = [mlp_init(k, [2 * obs_dim + act_dim, *vh, 1]) for k in (kq1, kq2)]
    params = {
        "value": mlp_init(kv, [2 * obs_dim, *vh, 1]),
        "critic": critic,
        "actor": mlp_init(ka, [2 * obs_dim, *ah, act_dim]),
    }
    target = jax.tree_util.tree_map(lambda x: x, params["critic"])
    return params, target


def value(p, s, g, ln):
    return mlp(p, jnp.concatenate([s, g], -1), ln)[..., 0]


def critics(ps, s, g, a, ln):
    x = jnp.concatenate([s, g, a], -1)
    return tuple(mlp(p, x, ln)[..., 0] for p in ps)


def losses(params, target, batch, cfg):
    """GCIQL's three losses (OGBench's value_loss, critic_loss, actor_loss with 'ddpgbc')."""
    ln, sg = cfg["layer_norm"], jax.lax.stop_gradient
    s, s2, a = batch["observations"], batch["next_observations"], batch["actions"]
    vg, ag = batch["value_goals"], batch["actor_goals"]
    # Value: expectile regression of V(s, g) to the target critics' min Q.
    q = jnp.minimum(*critics(target, s, vg, a, ln))
    v = value(params["value"], s, vg, ln)
    adv = q - v
    value_loss = (jnp.where(adv >= 0, cfg["expectile"], 1 - cfg["expectile"]) * adv**2).mean()
    # Critics: to r + discount * mask * V(s', g), V held fixed.
    next_v = value(sg(params["value"]), s2, vg, ln)
    target_q = batch["rewards"] + cfg["discount"] * batch["masks"] * next_v
    q1, q2 = critics(params["critic"], s, vg, a, ln)
    critic_loss = ((q1 - target_q) ** 2 + (q2 - target_q) ** 2).mean()
    # Actor: DDPG+BC with a constant-std (1) Gaussian, the critics held fixed.
    mean = mlp(params["actor"], jnp.concatenate([s, ag], -1), ln)
    qa = jnp.minimum(*critics(sg(params["critic"]), s, ag, jnp.clip(mean, -1, 1), ln))
    q_loss = -qa.mean() / sg(jnp.abs(qa).mean() + 1e-6)
    log_prob = (-0.5 * (a - mean) ** 2 - 0.5 * jnp.log(2 * jnp.pi)).sum(-1)
    bc_loss = -(cfg["alpha"] * log_prob).mean()
    actor_loss = q_loss + bc_loss
    info = {"value_loss": value_loss, "critic_loss": critic_loss, "actor_loss": actor_loss, "v_mean": v.mean(),
            "q_mean": target_q.mean()}
    return value_loss + critic_loss + actor_loss, info


def make_update(cfg):
    lr, tau, b1, b2, eps = cfg["lr"], cfg["tau"], 0.9, 0.999, 1e-8
    cfg = {k: cfg[k] for k in ("layer_norm", "expectile", "discount", "alpha")}

    @jax.jit
    def update(state, batch):
        params, target, m, v, t = state
        grads, info = jax.grad(losses, has_aux=True)(params, target, batch, cfg)
        t = t + 1
        m = jax.tree_util.tree_map(lambda m, g: b1 * m + (1 - b1) * g, m, grads)
        v = jax.tree_util.tree_map(lambda v, g: b2 * v + (1 - b2) * g * g, v, grads)
        step = lr * jnp.sqrt(1 - b2**t) / (1 - b1**t)
        params = jax.tree_util.tree_map(lambda p, m, v: p - step * m / (jnp.sqrt(v) + eps), params, m, v)
        target = jax.tree_util.tree_map(lambda p, tp: tau * p + (1 - tau) * tp, params["critic"], target)
        return (params, target, m, v, t), info

    return update


def as_jax(batch):
    """The batch's training keys as float32 device arrays (pgser's provenance columns stay on the host)."""
    return {k: jnp.asarray(batch[k], jnp.float32) for k in KEYS}


def init_state(dataset, cfg, seed):
    """Networks, target critics and Adam's moments, shaped by a batch of one row."""
    first = dataset.sample(1)
    obs_dim, act_dim = first["observations"].shape[1], first["actions"].shape[1]
    params, target = init(jax.random.PRNGKey(seed), obs_dim, act_dim, cfg)
    zeros = jax.tree_util.tree_map(jnp.zeros_like, params)
    return params, target, zeros, zeros, jnp.zeros((), jnp.int32)


def train(dataset, cfg=CONFIG, steps=300, seed=0, log_every=50, log=print):
    """Trains GCIQL for `steps` updates on `dataset.sample(cfg["batch_size"])` batches; returns the
    state and the per-step losses."""
    state = init_state(dataset, cfg, seed)
    update = make_update(cfg)
    history = []
    for i in range(steps):
        batch = as_jax(dataset.sample(cfg["batch_size"]))
        state, info = update(state, batch)
        history.append({k: float(x) for k, x in info.items()})
        if log and (i % log_every == 0 or i + 1 == steps):
            log(f"step {i:5d}  " + "  ".join(f"{k} {x:9.4f}" for k, x in history[-1].items()))
    return state, history


def evaluate(state, batch, cfg=CONFIG):
    """Mean value V(s, g) and critic min Q(s, g, a) over an evaluation batch's rows, with the goal
    the state itself (reached: reward 0, nothing to come) and with the goal another row's state
    (most far away: reward -1 a step until reached)."""
    params, ln = state[0], cfg["layer_norm"]
    s = jnp.asarray(batch["observations"], jnp.float32)
    a = jnp.asarray(batch["actions"], jnp.float32)
    other = s[np.random.default_rng(0).permutation(len(s))]
    out = {}
    for name, g in (("reached", s), ("random", other)):
        out[f"v_{name}"] = float(value(params["value"], s, g, ln).mean())
        out[f"q_{name}"] = float(jnp.minimum(*critics(params["critic"], s, g, a, ln)).mean())
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("table", help="a pgser trajectory table or table folder of OGBench data")
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--batch-size", type=int, default=CONFIG["batch_size"])
    p.add_argument("--hidden", type=int, default=256, help="width of the two hidden layers")
    p.add_argument("--lr", type=float, default=CONFIG["lr"])
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--memory-budget", default=None, help="e.g. 2GB: an out-of-core pool for a larger table")
    p.add_argument("--log-every", type=int, default=50)
    a = p.parse_args()

    import pgser

    cfg = dict(CONFIG, lr=a.lr, batch_size=a.batch_size, value_hidden_dims=(a.hidden,) * 2, actor_hidden_dims=(a.hidden,) * 2)
    # The one object OGBench's trainer builds as GCDataset(Dataset.create(**train_dataset), config).
    dataset = pgser.Sampler(a.table, layout="ogbench", config=cfg, seed=a.seed, memory_budget=a.memory_budget)
    t0 = time.perf_counter()
    state, history = train(dataset, cfg, a.steps, a.seed, a.log_every)
    seconds = time.perf_counter() - t0
    before = evaluate(init_state(dataset, cfg, a.seed), dataset.sample(1024), cfg)
    after = evaluate(state, dataset.sample(1024), cfg)
    dataset.close()
    window = max(1, min(20, a.steps // 5))
    mean = lambda rows, k: float(np.mean([r[k] for r in rows]))  # noqa: E731
    print(json.dumps({
        "task": dataset.task,
        "steps": a.steps,
        "seconds": round(seconds, 2),
        "critic_loss_first": mean(history[:window], "critic_loss"),
        "critic_loss_last": mean(history[-window:], "critic_loss"),
        "value_loss_first": mean(history[:window], "value_loss"),
        "value_loss_last": mean(history[-window:], "value_loss"),
        "before": before,
        "after": after,
    }))


if __name__ == "__main__":
    main()
