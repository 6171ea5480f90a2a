"""Cross-check a transition table from `pgser-etl score` against its trajectory table with
pyarrow and numpy alone (no pgser code): columns, goal sources, rewards and the footer.

Usage: check_scored.py SCORED.parquet TRAJ.parquet
Checks, for every row: (episode, step) and the order of rows; obs, action, next_obs and
next_achieved_goal equal the source rows (as float32); goal equals achieved_goal at
(goal_episode, goal_step), or desired_goal[episode, step] where goal_step == -1; the reward is
-(distance > threshold) recomputed with numpy; the footer's counts, source path and sha256.
"""
import hashlib
import json
import os
import sys

import numpy as np
import pyarrow.parquet as pq


def vectors(table, name):
    col = table.column(name).combine_chunks()
    assert col.null_count == 0, f"{name} has nulls"
    dim = col.type.list_size
    return col.flatten().to_numpy(zero_copy_only=False).reshape(-1, dim)


def scalars(table, name):
    return table.column(name).to_numpy()


def distance(metric, a, b):
    if metric == "euclidean":
        d = a.astype(np.float64) - b.astype(np.float64)
        return np.sqrt((d * d).sum(axis=1))
    if metric == "each_object":
        d = (a.astype(np.float64) - b.astype(np.float64)).reshape(len(a), -1, 3)
        return np.sqrt((d * d).sum(axis=2)).max(axis=1)
    if metric == "each_value":
        return np.abs(a.astype(np.float64) - b.astype(np.float64)).max(axis=1)
    if metric == "scene":
        # cubes' (x, y, z), 2 buttons, drawer, window; each part over its own tolerance.
        d = a.astype(np.float64) - b.astype(np.float64)
        cubes = (d.shape[1] - 4) // 3
        c = np.sqrt((d[:, : 3 * cubes].reshape(len(d), cubes, 3) ** 2).sum(axis=2)) / 0.4
        rest = np.abs(d[:, 3 * cubes :]) / np.array([0.5, 0.5, 0.72, 0.6])
        return np.concatenate([c, rest], axis=1).max(axis=1)
    assert metric == "quat_angle", metric
    # gymnasium-robotics' rotation distance on components 3..7.
    dot = (a[:, 3:7].astype(np.float64) * b[:, 3:7].astype(np.float64)).sum(axis=1)
    return 2.0 * np.arccos(np.clip(dot, -1.0, 1.0))


def main():
    scored_path, traj_path = sys.argv[1], sys.argv[2]
    meta = pq.read_metadata(scored_path).metadata
    f = json.loads(meta[b"pgser"])
    assert f["kind"] == "transition", f["kind"]
    traj = pq.read_table(traj_path)
    tf = json.loads(pq.read_metadata(traj_path).metadata[b"pgser"])
    n, T = tf["episodes"], tf["T"]
    obs = vectors(traj, "obs").astype(np.float32).reshape(n, T, -1)
    ag = vectors(traj, "achieved_goal").astype(np.float32).reshape(n, T, -1)
    # desired_goal and action are null on step T-1: fill those rows with NaN to keep [n, T, d].
    def padded(name):
        col = traj.column(name).combine_chunks()
        dim = col.type.list_size
        out = np.full((n * T, dim), np.nan, dtype=np.float32)
        valid = col.is_valid().to_numpy(zero_copy_only=False)
        out[valid] = col.drop_null().flatten().to_numpy(zero_copy_only=False).reshape(-1, dim)
        return out.reshape(n, T, dim)
    dg, u = padded("desired_goal"), padded("action")

    s = pq.read_table(scored_path)
    per = f["swaps"] + int(f["include_original"])
    transitions = n * (T - 1)
    assert s.num_rows == f["rows"] == transitions * per, (s.num_rows, f["rows"], transitions, per)
    assert f["transitions"] == transitions and f["episodes"] == n
    ep, st = scalars(s, "episode"), scalars(s, "step")
    ge, gs = scalars(s, "goal_episode"), scalars(s, "goal_step")
    k = np.arange(s.num_rows) // per
    assert (ep == k // (T - 1)).all() and (st == k % (T - 1)).all(), "rows are not in table order"
    assert (vectors(s, "obs") == obs[ep, st]).all()
    assert (vectors(s, "action") == u[ep, st]).all()
    assert (vectors(s, "next_obs") == obs[ep, st + 1]).all()
    next_ag = vectors(s, "next_achieved_goal")
    assert (next_ag == ag[ep, st + 1]).all()
    goal = vectors(s, "goal")
    original = gs == -1
    if f["include_original"]:
        assert (original == (np.arange(s.num_rows) % per == 0)).all(), "originals come first"
        assert (ge[original] == ep[original]).all()
        assert (goal[original] == dg[ep[original], st[original]]).all()
    else:
        assert not original.any()
    sw = ~original
    assert ((ge[sw] >= 0) & (ge[sw] < n) & (gs[sw] >= 0) & (gs[sw] < T)).all(), "goal source out of range"
    assert (goal[sw] == ag[ge[sw], gs[sw]]).all(), "goal != achieved goal at its source"
    d = distance(tf["goal_metric"], next_ag, goal)
    want = -(d > tf["success_threshold"]).astype(np.float32)
    reward = scalars(s, "reward")
    assert (reward == want).all(), f"{(reward != want).sum()} rewards differ"
    q = scalars(s, "q")
    assert np.isfinite(q).all()
    assert f["q"]["min"] == float(q.min()) and f["q"]["max"] == float(q.max())
    assert abs(f["q"]["mean"] - q.astype(np.float64).mean()) < 1e-9 * max(1.0, abs(f["q"]["mean"]))
    h = f["q"]["histogram"]
    counts, _ = np.histogram(q[(q >= h["edges"][0]) & (q <= h["edges"][-1])], bins=np.array(h["edges"]))
    assert sum(h["counts"]) + h["below"] + h["above"] == s.num_rows
    assert np.abs(counts - np.array(h["counts"])).sum() <= 2, "histogram differs beyond edge rounding"
    source = os.path.join(os.path.dirname(os.path.abspath(scored_path)), f["source"]["path"])
    assert os.path.samefile(source, traj_path), (source, traj_path)
    assert f["source"]["sha256"] == hashlib.sha256(open(traj_path, "rb").read()).hexdigest()
    print(f"ok: {s.num_rows} rows, {int((reward == 0).sum())} reached")


if __name__ == "__main__":
    main()
