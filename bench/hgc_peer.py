#!/usr/bin/env python3
"""The hierarchical agents' batches drawn as their own code draws them, re-implemented here in
numpy from OGBench's `impls/utils/datasets.py` and Horizon Reduction's `utils/datasets.py`
(nothing of theirs is imported, so this needs only numpy): the peer pgser's
`layout="ogbench"` / `layout="horizon_reduction"` with `dataset_class="HGCDataset"` is tested
and timed against.

A dataset is one `.npz` file or a folder of shards (`-val.npz` skipped), loaded as the code
loads it:
- `ogbench`: OGBench's default regular layout (`load_dataset`): each episode's last row
  dropped, its observation kept as the row before's `next_observations`.
- `horizon_reduction`: the compact layout (`compact_dataset=True`): every row kept, `valids` 0
  on each episode's last row, `terminals` on its last two; next observations are the next row;
  with `--oracle-reps`, `oracle_reps` = `qpos[:, :2]` (a maze's, `add_oracle_reps`).

`sample(B)` returns the class's dict and the flat indices behind it (`idx`, and each goal's),
so a test can compare distributions of steps with pgser's provenance columns.

Usage (timing one shard in RAM, batches of 1024):
    hgc_peer.py FILE_OR_DIR --code ogbench|horizon_reduction [--subgoal-steps 25]
                [--batches 2000] [--batch-size 1024] [--seed 0] [--oracle-reps] [--json OUT]
"""
from __future__ import annotations

import argparse
import glob
import json
import os
import resource
import time

import numpy as np


def files(path: str) -> list[str]:
    if os.path.isdir(path):
        return [f for f in sorted(glob.glob(os.path.join(path, "*.npz"))) if not f.endswith("-val.npz")]
    return [path]


def load(paths: list[str], code: str, oracle_reps: bool = False) -> dict[str, np.ndarray]:
    """The shards concatenated, in `code`'s layout (the module doc)."""
    parts = []
    for p in paths:
        with np.load(p) as f:
            d = {k: f[k][...].astype(np.float32, copy=False) for k in ("observations", "actions", "terminals")}
            qpos = f["qpos"][...] if "qpos" in f.files else None
        if code == "horizon_reduction":
            d["valids"] = 1.0 - d["terminals"]
            shifted = np.concatenate([d["terminals"][1:], [1.0]])
            d["terminals"] = np.minimum(d["terminals"] + shifted, 1.0).astype(np.float32)
            if oracle_reps:
                d["oracle_reps"] = qpos[:, :2].astype(np.float32)
        else:
            keep = (1.0 - d["terminals"]).astype(bool)
            next_keep = np.concatenate([[False], keep[:-1]])
            d["next_observations"] = d["observations"][next_keep]
            d["observations"] = d["observations"][keep]
            d["actions"] = d["actions"][keep]
            d["terminals"] = np.concatenate([d["terminals"][1:], [1.0]])[keep].astype(np.float32)
        parts.append(d)
    return {k: np.concatenate([p[k] for p in parts]) for k in parts[0]}


class GCDataset:
    """`GCDataset`'s `__post_init__`, `sample_goals` and the Dataset's index draws."""

    def __init__(self, data: dict, config: dict, rng: np.random.Generator):
        self.d, self.config, self.rng = data, config, rng
        self.size = len(data["observations"])
        (self.terminal_locs,) = np.nonzero(data["terminals"] > 0)
        if "valids" in data:
            (self.valid_idxs,) = np.nonzero(data["valids"] > 0)

    def random_idxs(self, n):
        if "valids" in self.d:
            return self.valid_idxs[self.rng.integers(len(self.valid_idxs), size=n)]
        return self.rng.integers(self.size, size=n)

    def observations(self, idxs):
        return self.d["observations"][idxs]

    def traj_goals(self, idxs, final_state_idxs, geom_sample, discount):
        """A later state of each row's trajectory, as both classes draw one (their code writes it
        out in `sample_goals` and again in OGBench's `HGCDataset.sample`)."""
        n = len(idxs)
        if geom_sample:
            offsets = self.rng.geometric(p=1 - discount, size=n)
            return np.minimum(idxs + offsets, final_state_idxs)
        distances = self.rng.random(n)
        return np.round(
            np.minimum(idxs + 1, final_state_idxs) * distances + final_state_idxs * (1 - distances)
        ).astype(int)

    def sample_goals(self, idxs, p_curgoal, p_trajgoal, geom_sample, discount=None):
        n = len(idxs)
        if discount is None:
            discount = self.config["discount"]
        random_goal_idxs = self.random_idxs(n)
        final_state_idxs = self.terminal_locs[np.searchsorted(self.terminal_locs, idxs)]
        traj_goal_idxs = self.traj_goals(idxs, final_state_idxs, geom_sample, discount)
        if p_curgoal == 1.0:
            return idxs
        goal_idxs = np.where(self.rng.random(n) < p_trajgoal / (1.0 - p_curgoal), traj_goal_idxs, random_goal_idxs)
        return np.where(self.rng.random(n) < p_curgoal, idxs, goal_idxs)

    def batch_of(self, idxs):
        b = {k: v[idxs] for k, v in self.d.items()}
        if "next_observations" not in self.d:
            b["next_observations"] = self.d["observations"][np.minimum(idxs + 1, self.size - 1)]
        return b


class OgbenchHGCDataset(GCDataset):
    """OGBench's `HGCDataset.sample` (p_aug and frame_stack None)."""

    def sample(self, n):
        c = self.config
        idxs = self.random_idxs(n)
        batch = self.batch_of(idxs)
        value_goal_idxs = self.sample_goals(idxs, c["value_p_curgoal"], c["value_p_trajgoal"], c["value_geom_sample"])
        batch["value_goals"] = self.observations(value_goal_idxs)
        successes = (idxs == value_goal_idxs).astype(float)
        batch["masks"] = 1.0 - successes
        batch["rewards"] = successes - (1.0 if c["gc_negative"] else 0.0)
        final_state_idxs = self.terminal_locs[np.searchsorted(self.terminal_locs, idxs)]
        low_goal_idxs = np.minimum(idxs + c["subgoal_steps"], final_state_idxs)
        batch["low_actor_goals"] = self.observations(low_goal_idxs)
        high_traj_goal_idxs = self.traj_goals(idxs, final_state_idxs, c["actor_geom_sample"], c["discount"])
        high_traj_target_idxs = np.minimum(idxs + c["subgoal_steps"], high_traj_goal_idxs)
        high_random_goal_idxs = self.random_idxs(n)
        high_random_target_idxs = np.minimum(idxs + c["subgoal_steps"], final_state_idxs)
        pick_random = self.rng.random(n) < c["actor_p_randomgoal"]
        high_goal_idxs = np.where(pick_random, high_random_goal_idxs, high_traj_goal_idxs)
        high_target_idxs = np.where(pick_random, high_random_target_idxs, high_traj_target_idxs)
        batch["high_actor_goals"] = self.observations(high_goal_idxs)
        batch["high_actor_targets"] = self.observations(high_target_idxs)
        index = dict(idx=idxs, value_goal=value_goal_idxs, low_actor_goal=low_goal_idxs,
                     high_actor_goal=high_goal_idxs, high_actor_target=high_target_idxs, high_random=pick_random)
        return batch, index


class HorizonReductionHGCDataset(GCDataset):
    """Horizon Reduction's `HGCDataset.sample`."""

    def reps(self, idxs):
        return self.d["oracle_reps"][idxs] if "oracle_reps" in self.d else self.observations(idxs)

    def high_next(self, idxs, final_state_idxs, high_goal_idxs, subgoal_steps):
        steps = np.full(len(idxs), subgoal_steps)
        steps = np.minimum(steps, final_state_idxs - idxs)
        diff = high_goal_idxs - idxs
        steps = np.where((0 <= diff) & (diff < steps), diff, steps)
        return idxs + steps, steps

    def sample(self, n):
        c = self.config
        idxs = self.random_idxs(n)
        batch = self.batch_of(idxs)
        final_state_idxs = self.terminal_locs[np.searchsorted(self.terminal_locs, idxs)]
        hv = self.sample_goals(idxs, c["value_p_curgoal"], c["value_p_trajgoal"], c["value_geom_sample"])
        vss = c["subgoal_steps"] if c.get("value_subgoal_steps") is None else c["value_subgoal_steps"]
        hv_next, hv_steps = self.high_next(idxs, final_state_idxs, hv, vss)
        batch["high_value_reps"] = self.reps(idxs)
        batch["high_value_goals"] = self.reps(hv)
        batch["high_value_actions"] = self.reps(hv_next)
        batch["high_value_next_observations"] = self.observations(hv_next)
        batch["high_value_offsets"] = hv - idxs
        reached = (hv_steps < vss).astype(float)
        batch["high_value_subgoal_steps"] = hv_steps
        batch["high_value_masks"] = 1.0 - reached
        if c["gc_negative"]:
            batch["high_value_rewards"] = -(1 - c["discount"] ** hv_steps) / (1 - c["discount"])
        else:
            batch["high_value_rewards"] = (c["discount"] ** hv_steps) * reached
        index = dict(idx=idxs, high_value_goal=hv, high_value_action=hv_next)
        if "low_discount" in c:
            lv = self.sample_goals(idxs, c["value_p_curgoal"], c["value_p_trajgoal"], True, discount=c["low_discount"])
            batch["low_value_goals"] = self.reps(lv)
            s = (idxs == lv).astype(float)
            batch["low_value_masks"] = 1.0 - s
            batch["low_value_rewards"] = s - (1.0 if c["gc_negative"] else 0.0)
            index["low_value_goal"] = lv
        s = (idxs == hv).astype(float)
        batch["masks"] = 1.0 - s
        batch["rewards"] = s - (1.0 if c["gc_negative"] else 0.0)
        ha = self.sample_goals(idxs, c["actor_p_curgoal"], c["actor_p_trajgoal"], c["actor_geom_sample"])
        ass = c["subgoal_steps"] if c.get("actor_subgoal_steps") is None else c["actor_subgoal_steps"]
        ha_next, _ = self.high_next(idxs, final_state_idxs, ha, ass)
        batch["high_actor_goals"] = self.reps(ha)
        batch["high_actor_actions"] = self.reps(ha_next)
        batch["high_actor_next_observations"] = self.observations(ha_next)
        low = np.minimum(idxs + ass, final_state_idxs)
        batch["low_actor_goals"] = self.reps(low)
        index.update(high_actor_goal=ha, high_actor_action=ha_next, low_actor_goal=low)
        return batch, index


CLASSES = {"ogbench": OgbenchHGCDataset, "horizon_reduction": HorizonReductionHGCDataset}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("path")
    p.add_argument("--code", choices=sorted(CLASSES), required=True)
    p.add_argument("--subgoal-steps", type=int, default=25)
    p.add_argument("--batches", type=int, default=2000)
    p.add_argument("--warmup", type=int, default=20)
    p.add_argument("--batch-size", type=int, default=1024)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--oracle-reps", action="store_true")
    p.add_argument("--json")
    a = p.parse_args()
    # HIQL's (OGBench) and SHARSA's (Horizon Reduction) sampling settings.
    config = dict(discount=0.99, value_p_curgoal=0.2, value_p_trajgoal=0.5, value_p_randomgoal=0.3,
                  value_geom_sample=True, actor_p_curgoal=0.0, actor_p_trajgoal=1.0, actor_p_randomgoal=0.0,
                  actor_geom_sample=False, gc_negative=True, subgoal_steps=a.subgoal_steps)
    if a.code == "horizon_reduction":
        config.update(discount=0.999, value_geom_sample=False, actor_p_trajgoal=0.5, actor_p_randomgoal=0.5,
                      actor_geom_sample=True, gc_negative=False)
    t0 = time.perf_counter()
    data = load(files(a.path)[:1], a.code, a.oracle_reps)
    load_seconds = time.perf_counter() - t0
    ds = CLASSES[a.code](data, config, np.random.default_rng(a.seed))
    for _ in range(a.warmup):
        ds.sample(a.batch_size)
    times = np.empty(a.batches)
    start = time.perf_counter()
    for i in range(a.batches):
        t = time.perf_counter()
        ds.sample(a.batch_size)
        times[i] = time.perf_counter() - t
    seconds = time.perf_counter() - start
    ms = times * 1e3
    out = {
        "peer": f"hgc-{a.code}-numpy-ram", "numpy": np.__version__, "batches": a.batches, "batch_size": a.batch_size,
        "seconds": seconds, "batches_per_sec": a.batches / seconds, "median_ms": float(np.median(ms)),
        "p999_ms": float(np.quantile(ms, 0.999)), "max_ms": float(ms.max()), "load_seconds": load_seconds,
        "peak_rss_bytes": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024, "rows_loaded": ds.size,
    }
    line = json.dumps(out)
    if a.json:
        with open(a.json, "w") as f:
            f.write(line + "\n")
    print(line)


if __name__ == "__main__":
    main()
