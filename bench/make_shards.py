#!/usr/bin/env python3
"""A folder of `.npz` shards in Horizon Reduction's layout, of a chosen shape, for benchmarks
of sharded datasets (issue 65). Never for tests: they use small folders made in the test.

Each shard `NAME-i.npz` (and one `NAME-val.npz`) holds E episodes of M rows each:
`observations` [E*M, obs] float32, `actions` [E*M, act] float32 in [-1, 1], `terminals`
[E*M] float32 (1 on each episode's last row), and `qpos` / `qvel` float32 (obs/2 each, rounded),
as OGBench's locomotion generators save them. The observations are random walks whose first two
values are an x, y position, so goal maps and distances behave like a maze's, not like noise.

`--no-state` leaves `qpos` and `qvel` out (the 1B-row folder of PointMaze's width, issue 75,
whose disk they would not fit beside its table).

`--visual H` makes the observations uint8 images [E*M, H, H, 3], as OGBench's visual datasets
hold them (64 for theirs), and `qpos` (15 values, the first two the walk's x, y) and `qvel`
(14) an ant's widths, so that `visual-antmaze-*` names convert (the goal is qpos[0:2]). Each
image is a smooth colour field moved by the walk's position plus a little noise: not a
rendering, but neither constant (which zstd would shrink to nothing) nor noise (which it could
not shrink at all). `--image-noise P` puts the bit of noise on a share P of the pixels only:
P = 0.01 makes images that zstd-1 shrinks to about 2.4 kB, near OGBench's own renders (1,774
bytes an image), where the default (every byte) leaves them 8.7 kB.

humanoidmaze-giant's shape is obs 69, act 21, M = 4001, 1000 episodes a shard in the 1B set;
`--episodes` picks a smaller shard. Shards are written with np.savez (uncompressed, the default)
or np.savez_compressed (`--compressed`, as OGBench's files are); each is written beside its
name and renamed, so a killed run leaves no partial shard, and shards already present are kept.

Usage:
    make_shards.py OUT_DIR [--name humanoidmaze-giant-navigate-v0] [--shards 4]
                   [--episodes 100] [--rows 4001] [--obs 69] [--act 21] [--compressed] [--no-state]
                   [--visual 64] [--seed 0]
"""
from __future__ import annotations

import argparse
import os

import numpy as np


def shard(rng: np.random.Generator, episodes: int, rows: int, obs: int, act: int, state: bool = True) -> dict[str, np.ndarray]:
    n = episodes * rows
    actions = rng.uniform(-1.0, 1.0, (n, act)).astype(np.float32)
    steps = rng.normal(0.0, 0.05, (episodes, rows, obs)).astype(np.float32)
    steps[:, 0, :] = rng.uniform(-1.0, 1.0, (episodes, obs))
    steps[:, 0, :2] = rng.uniform(0.0, 40.0, (episodes, 2))
    observations = np.cumsum(steps, axis=1, dtype=np.float32).reshape(n, obs)
    terminals = np.zeros(n, np.float32)
    terminals[rows - 1 :: rows] = 1.0
    half = max(obs // 2, 1)
    if not state:
        return {"observations": observations, "actions": actions, "terminals": terminals}
    return {
        "observations": observations,
        "actions": actions,
        "terminals": terminals,
        "qpos": observations[:, :half].copy(),
        "qvel": observations[:, half : 2 * half].copy(),
    }


def visual_shard(rng: np.random.Generator, episodes: int, rows: int, act: int, side: int, noise: float = 1.0) -> dict[str, np.ndarray]:
    walk = shard(rng, episodes, rows, 29, act, state=False)
    xy = walk["observations"][:, :2]
    n = len(xy)
    u = np.linspace(0.0, 2 * np.pi, side, dtype=np.float32)
    images = np.empty((n, side, side, 3), np.uint8)
    for start in range(0, n, 4096):
        p = xy[start : start + 4096]
        k = len(p)
        fx = np.sin(u[None, :, None] + p[:, 0, None, None] * 0.3)  # (k, side, 1)
        fy = np.cos(u[None, None, :] + p[:, 1, None, None] * 0.3)  # (k, 1, side)
        base = (fx * fy)[..., None] * np.array([60.0, 45.0, 30.0], np.float32) + 128.0
        bits = rng.integers(0, 2, (k, side, side, 3), dtype=np.uint8)
        if noise < 1.0:
            bits &= rng.random((k, side, side, 1)) < noise
        images[start : start + k] = np.clip(base, 0, 254).astype(np.uint8) + bits
    qpos = np.zeros((n, 15), np.float32)
    qpos[:, :2] = xy
    return {
        "observations": images,
        "actions": walk["actions"],
        "terminals": walk["terminals"],
        "qpos": qpos,
        "qvel": rng.normal(0.0, 0.1, (n, 14)).astype(np.float32),
    }


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("out")
    p.add_argument("--name", default="humanoidmaze-giant-navigate-v0")
    p.add_argument("--shards", type=int, default=4)
    p.add_argument("--episodes", type=int, default=100)
    p.add_argument("--rows", type=int, default=4001)
    p.add_argument("--obs", type=int, default=69)
    p.add_argument("--act", type=int, default=21)
    p.add_argument("--compressed", action="store_true")
    p.add_argument("--no-state", action="store_true", help="no qpos, qvel")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--visual", type=int, default=0, metavar="H", help="uint8 images H x H x 3 as observations")
    p.add_argument("--image-noise", type=float, default=1.0, metavar="P",
                   help="the share of pixels given a bit of noise (1: every byte; 0.01 compresses about as OGBench's renders)")
    a = p.parse_args()
    os.makedirs(a.out, exist_ok=True)
    save = np.savez_compressed if a.compressed else np.savez
    names = [f"{a.name}-{i}.npz" for i in range(a.shards)] + [f"{a.name}-val.npz"]
    for i, name in enumerate(names):
        path = os.path.join(a.out, name)
        if os.path.exists(path):
            continue
        rng = np.random.default_rng([a.seed, i])
        episodes = a.episodes if not name.endswith("-val.npz") else max(a.episodes // 10, 1)
        tmp = path + ".part.npz"
        if a.visual:
            arrays = visual_shard(rng, episodes, a.rows, a.act, a.visual, a.image_noise)
        else:
            arrays = shard(rng, episodes, a.rows, a.obs, a.act, not a.no_state)
        save(tmp, **arrays)
        os.replace(tmp, path)
        print(path, flush=True)


if __name__ == "__main__":
    main()
