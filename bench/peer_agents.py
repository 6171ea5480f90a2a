#!/usr/bin/env python3
"""OGBench's and Horizon Reduction's own agents trained from `pgser.Sampler`, run from local
checkouts of their code (never committed, never needed by `make test`), for a few hundred
updates from a table folder within a memory budget, printing their losses.

Each agent runs its code's `main.py` training loop as written there, with one line changed: the
one that built the dataset object,
    train_dataset = dataset_class(Dataset.create(**train_dataset), config)
becomes
    train_dataset = pgser.Sampler(folder, layout=CODE, config=config, memory_budget=BUDGET, ...)
and the same for the validation dataset from the folder's `val/` (when it has one). Nothing else
of theirs changes: `get_config()`, `agent_class.create(...)` as each `main.py` calls it,
`agent.update(batch)`, `agent.total_loss(val_batch, grad_params=None)`. Sizes are set the way
their command line sets them (`--agent.batch_size=256`, smaller hidden layers), so it runs on a
CPU.

Each agent runs in a child process (both codes name their packages `agents` and `utils`).

Usage:
    peer_agents.py --ogbench-src DIR --hr-src DIR --table FOLDER [--steps 300] [--log-every 100]
                   [--memory-budget 64MB] [--batch-size 256] [--hidden 128] [--env-name NAME]
                   [--agents ogbench:gciql,...] [--encoder impala_small --p-aug 0.5 [--frame-stack 3]]
(a visual dataset's table with --encoder: their pixel agents, as hyperparameters.sh runs them)
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import os
import subprocess
import sys
import time

AGENTS = {
    "ogbench": ["gciql", "crl", "hiql"],
    "horizon_reduction": ["sharsa", "dsharsa", "ngcsacbc", "hgcfbc", "hiql", "crl", "gcsacbc"],
}


def worker(a: argparse.Namespace) -> None:
    code, name = a.worker.split(":")
    root = os.path.join(a.src, "impls") if code == "ogbench" else a.src
    sys.path.insert(0, root)
    import numpy as np

    import pgser
    from agents import agents  # theirs

    spec = importlib.util.spec_from_file_location(f"agent_{name}", os.path.join(root, "agents", f"{name}.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    config = mod.get_config()
    # What their command line would set (`--agent.batch_size=...`): sizes for a CPU.
    config["batch_size"] = a.batch_size
    # A visual dataset's command line (OGBench's hyperparameters.sh): `--agent.encoder=impala_small
    # --agent.p_aug=0.5`, and `--agent.frame_stack=K` where it stacks.
    if a.encoder:
        config["encoder"] = a.encoder
    if a.p_aug is not None:
        config["p_aug"] = a.p_aug
    if a.frame_stack:
        config["frame_stack"] = a.frame_stack
    for k in ("actor_hidden_dims", "value_hidden_dims"):
        if k in config:
            config[k] = (a.hidden, a.hidden)
    kw = dict(memory_budget=a.memory_budget)
    if code == "horizon_reduction":
        kw.update(env_name=a.env_name, clip_actions=1e-5)
    val = os.path.join(a.table, "val")

    # --- their main.py from here, the dataset lines replaced ---
    np.random.seed(a.seed)
    train_dataset = pgser.Sampler(a.table, layout=code, config=config, seed=a.seed, **kw)
    val_dataset = pgser.Sampler(val, layout=code, config=config, seed=a.seed + 1) if os.path.isdir(val) else None
    example_batch = train_dataset.sample(1)
    agent_class = agents[config["agent_name"]]
    if code == "ogbench":
        agent = agent_class.create(a.seed, example_batch["observations"], example_batch["actions"], config)
    else:
        agent = agent_class.create(a.seed, example_batch, config)
    t0 = time.perf_counter()
    log = []
    for i in range(1, a.steps + 1):
        batch = train_dataset.sample(config["batch_size"])
        agent, update_info = agent.update(batch)
        if i % a.log_every == 0:
            row = {f"training/{k}": float(v) for k, v in update_info.items() if np.ndim(v) == 0}
            if val_dataset is not None:
                val_batch = val_dataset.sample(config["batch_size"])
                _, val_info = agent.total_loss(val_batch, grad_params=None)
                row.update({f"validation/{k}": float(v) for k, v in val_info.items() if np.ndim(v) == 0})
            row["step"] = i
            row["seconds"] = time.perf_counter() - t0
            log.append(row)
    json.dump(dict(agent=name, code=code, dataset_class=config["dataset_class"], log=log,
                   pool=train_dataset.pool_stats()), sys.stdout)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--ogbench-src")
    p.add_argument("--hr-src")
    p.add_argument("--table", required=True)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--log-every", type=int, default=100)
    p.add_argument("--memory-budget", default="64MB")
    p.add_argument("--batch-size", type=int, default=256)
    p.add_argument("--hidden", type=int, default=128)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--env-name", default="pointmaze-medium-navigate-oraclerep-v0")
    p.add_argument("--agents", help="comma-separated CODE:NAME to run (default: all)")
    p.add_argument("--encoder", help="a visual encoder of theirs (impala_small): a visual dataset's table")
    p.add_argument("--p-aug", type=float, help="their p_aug (0.5 on visual datasets)")
    p.add_argument("--frame-stack", type=int, help="their frame_stack")
    p.add_argument("--json")
    p.add_argument("--worker", help=argparse.SUPPRESS)
    p.add_argument("--src", help=argparse.SUPPRESS)
    a = p.parse_args()
    if a.worker:
        worker(a)
        return
    runs = [(c, n) for c, src in (("ogbench", a.ogbench_src), ("horizon_reduction", a.hr_src)) if src
            for n in AGENTS[c]]
    if a.agents:
        runs = [r for r in runs if f"{r[0]}:{r[1]}" in a.agents.split(",")]
    results = []
    for code, name in runs:
        src = a.ogbench_src if code == "ogbench" else a.hr_src
        cmd = [sys.executable, __file__, "--worker", f"{code}:{name}", "--src", src, "--table", a.table,
               "--steps", str(a.steps), "--log-every", str(a.log_every), "--memory-budget", a.memory_budget,
               "--batch-size", str(a.batch_size), "--hidden", str(a.hidden), "--seed", str(a.seed),
               "--env-name", a.env_name]
        cmd += ["--encoder", a.encoder] if a.encoder else []
        cmd += ["--p-aug", str(a.p_aug)] if a.p_aug is not None else []
        cmd += ["--frame-stack", str(a.frame_stack)] if a.frame_stack else []
        r = subprocess.run(cmd, capture_output=True, text=True)
        if r.returncode != 0:
            print(f"{code} {name}: FAILED\n{r.stderr[-3000:]}")
            results.append(dict(agent=name, code=code, failed=r.stderr[-3000:]))
            continue
        out = json.loads(r.stdout)
        results.append(out)
        print(f"\n{code} {name} ({out['dataset_class']}), pool: {out['pool']}")
        for row in out["log"]:
            losses = {k.split("/", 1)[1]: v for k, v in row.items() if "loss" in k and k.startswith("training/")}
            vals = {k.split("/", 1)[1]: v for k, v in row.items() if "loss" in k and k.startswith("validation/")}
            print(f"  step {row['step']:5d} ({row['seconds']:6.1f} s)  "
                  + "  ".join(f"{k} {v:.4g}" for k, v in sorted(losses.items()))
                  + ("   val " + "  ".join(f"{k} {v:.4g}" for k, v in sorted(vals.items())) if vals else ""))
    if a.json:
        with open(a.json, "w") as f:
            json.dump(results, f)
    failed = [f"{r['code']}:{r['agent']}" for r in results if "failed" in r]
    if failed:
        sys.exit(f"failed: {', '.join(failed)}")


if __name__ == "__main__":
    main()
