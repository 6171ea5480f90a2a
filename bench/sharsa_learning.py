#!/usr/bin/env python3
"""Does the whole dataset, and PGSER, help the agent that scales? Horizon Reduction's SHARSA (their
code, from a local checkout given on the command line; never committed, never needed by
`make test`) trained from `pgser.Sampler` on a table folder in their layout, and evaluated on
OGBench's five evaluation tasks in OGBench's own environment (`-oraclerep`, as their runs are).

One run is one arm, one goal scheme and one seed:
- `--arm whole`: every batch from the whole folder within `--memory-budget`;
  `--arm window`: one shard at a time, the next every `--window` batches (their
  `dataset_replace_interval`), every goal from the held shard (`shard_window=`).
- `--goals her`: their HGCDataset's own goals; `--goals pgser`: from a scored folder
  (`pgser-etl score`), a fraction `--p-swapgoal` of rows are PGSER's prioritized swapped rows,
  whose goals are the high-level goals (docs/ogbench.md, "Hierarchical batches").

Their training loop as their `main.py` has it (the dataset line replaced), at a CPU budget set
here and printed in the output: `--steps` updates of `--batch-size`, hidden layers of
`--hidden` (two), evaluation every `--eval-every` updates with `--eval-episodes` per task.
The run checkpoints (their `save_agent`) and its log after every evaluation; run again with the
same `--out` to resume (the sampler is brought to the same batch by drawing the batches before
it, so a resumed run draws what an uninterrupted one does).

Usage:
    sharsa_learning.py --hr-src HR --table FOLDER [--scored SCORED] --arm whole --goals her --seed 0
                       --env-name pointmaze-medium-navigate-oraclerep-v0 --out OUT_DIR
                       [--steps 20000] [--eval-every 5000] [--eval-episodes 10] [--memory-budget 64MB]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--hr-src", required=True)
    p.add_argument("--table", required=True)
    p.add_argument("--scored")
    p.add_argument("--arm", choices=["whole", "window"], required=True)
    p.add_argument("--goals", choices=["her", "pgser"], required=True)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--env-name", default="pointmaze-medium-navigate-oraclerep-v0")
    p.add_argument("--out", required=True)
    p.add_argument("--steps", type=int, default=20000)
    p.add_argument("--eval-every", type=int, default=5000)
    p.add_argument("--eval-episodes", type=int, default=10)
    p.add_argument("--batch-size", type=int, default=256)
    p.add_argument("--hidden", type=int, default=256)
    p.add_argument("--subgoal-steps", type=int, default=25)
    p.add_argument("--memory-budget", default="64MB")
    p.add_argument("--window", type=int, default=1000)
    p.add_argument("--p-swapgoal", type=float, default=0.25)
    a = p.parse_args()
    sys.path.insert(0, a.hr_src)
    import numpy as np
    import ogbench

    import pgser
    from agents import agents  # theirs
    from agents.sharsa import get_config
    from utils.evaluation import evaluate
    from utils.flax_utils import restore_agent, save_agent

    os.makedirs(a.out, exist_ok=True)
    log_path = os.path.join(a.out, "log.json")
    log = json.load(open(log_path)) if os.path.exists(log_path) else {"evals": []}
    done = log["evals"][-1]["step"] if log["evals"] else 0

    config = get_config()
    config["batch_size"] = a.batch_size
    config["actor_hidden_dims"] = config["value_hidden_dims"] = (a.hidden, a.hidden)
    config["subgoal_steps"] = a.subgoal_steps
    kw = dict(layout="horizon_reduction", config=config, seed=a.seed, env_name=a.env_name, clip_actions=1e-5)
    if a.arm == "whole":
        kw["memory_budget"] = a.memory_budget
    else:
        kw["shard_window"] = a.window
    source = a.table
    if a.goals == "pgser":
        if not a.scored:
            sys.exit("--goals pgser draws swapped goals from a scored folder: give --scored")
        source, kw["p_swapgoal"], kw["priority"] = a.scored, a.p_swapgoal, "rank"
    env = ogbench.make_env_and_datasets(a.env_name, env_only=True)

    # --- their main.py from here, the dataset line replaced ---
    np.random.seed(a.seed)
    train_dataset = pgser.Sampler(source, **kw)
    example_batch = train_dataset.sample(1)
    agent = agents[config["agent_name"]].create(a.seed, example_batch, config)
    if done:
        agent = restore_agent(agent, a.out, done)
        for _ in range(done):  # the same batches as an uninterrupted run from here on
            train_dataset.sample(config["batch_size"])
    t0 = time.perf_counter()
    for i in range(done + 1, a.steps + 1):
        batch = train_dataset.sample(config["batch_size"])
        agent, update_info = agent.update(batch)
        if i % a.eval_every == 0 or i == a.steps:
            task_infos = env.unwrapped.task_infos
            successes = []
            for task_id in range(1, len(task_infos) + 1):
                info, _, _ = evaluate(agent=agent, env=env, env_name=a.env_name, goal_conditioned=True, task_id=task_id,
                                      config=config, num_eval_episodes=a.eval_episodes, num_video_episodes=0)
                successes.append(float(info["success"]))
            log["evals"].append(dict(step=i, task_success=successes, success=float(np.mean(successes)),
                                     seconds=time.perf_counter() - t0,
                                     losses={k: float(v) for k, v in update_info.items() if np.ndim(v) == 0}))
            save_agent(agent, a.out, i)
            log.update(arm=a.arm, goals=a.goals, seed=a.seed, env_name=a.env_name, steps=a.steps, eval_episodes=a.eval_episodes,
                       batch_size=a.batch_size, hidden=[a.hidden, a.hidden], subgoal_steps=a.subgoal_steps,
                       memory_budget=a.memory_budget if a.arm == "whole" else None,
                       window=a.window if a.arm == "window" else None,
                       p_swapgoal=a.p_swapgoal if a.goals == "pgser" else 0.0, pool=train_dataset.pool_stats())
            with open(log_path + ".tmp", "w") as f:
                json.dump(log, f)
            os.replace(log_path + ".tmp", log_path)
            print(json.dumps(log["evals"][-1]), flush=True)


if __name__ == "__main__":
    main()
