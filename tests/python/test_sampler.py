"""pgser.Sampler yields the batches pgser-train trains on: checked against `pgser-train batches`,
the table the trainer's own sampler writes, for each kind of batch (original data with HER,
random swapping, the prioritized -mem mix with importance weights, from disk and from memory)."""

import numpy as np
import pytest

import pgser
from conftest import BIN, run

KEYS = ("obs", "goal", "action", "reward", "next_obs", "weight", "episode", "step", "scored_row")


def dumped(data, out, count, flags):
    run(BIN / "pgser-train", "batches", "--data", data, "-o", out, "--count", count, *flags)
    t = pgser.read_table(out)
    cols = {}
    for k in KEYS:
        c = t.column(k).combine_chunks()
        cols[k] = np.stack(c.to_numpy(zero_copy_only=False)) if k in ("obs", "goal", "action", "next_obs") else c.to_numpy()
    batch = t.column("batch").to_numpy()
    return [{k: v[batch == b] for k, v in cols.items()} for b in range(count)]


CASES = [
    # (table, pgser-train flags, Sampler keywords)
    ("traj", ["--batch-size", "64", "--seed", "3"], dict(batch_size=64, seed=3)),
    ("traj", ["--batch-size", "50", "--swap", "random", "--swap-ratio", "0.3", "--her-ratio", "0.8"],
     dict(batch_size=50, swap="random", swap_ratio=0.3, her=0.8)),
    ("scored", ["--batch-size", "64", "--aug-ratio", "0.25", "--is-beta", "0.4", "--seed", "5"],
     dict(batch_size=64, aug_ratio=0.25, is_beta=0.4, seed=5)),
    # the paper's reading, no longer the default: both sides must still agree on it
    ("scored", ["--batch-size", "64", "--priority", "q", "--seed", "2"], dict(batch_size=64, priority="q", seed=2)),
    ("scored", ["--batch-size", "32", "--priority", "rank", "--priority-alpha", "0.7", "--aug-in-memory"],
     dict(batch_size=32, priority="rank", alpha=0.7, in_memory=True)),
]


@pytest.mark.parametrize("table,flags,kwargs", CASES)
def test_batches_equal_pgser_train(tables, tmp_path, table, flags, kwargs):
    traj, _, scored = tables
    data = traj if table == "traj" else scored
    want = dumped(data, tmp_path / "b.parquet", 6, flags)
    got = list(pgser.Sampler(data, num_batches=6, **kwargs))
    assert len(got) == 6
    for b, (g, w) in enumerate(zip(got, want)):
        for k in KEYS:
            assert g[k].shape == w[k].shape, (b, k)
            assert np.array_equal(g[k], w[k]), (b, k)
    n = kwargs["batch_size"]
    g = got[0]
    assert g["obs"].dtype == np.float32 and g["obs"].shape == (n, 10) and g["goal"].shape == (n, 3)
    assert g["action"].shape == (n, 4) and g["reward"].shape == (n,) and g["episode"].dtype == np.int64
    if table == "scored":
        k = round(n * kwargs["aug_ratio"]) if "aug_ratio" in kwargs else n // 2
        assert (g["scored_row"][-k:] >= 0).all() and (g["scored_row"][:-k] == -1).all()


def test_endless_by_default_and_closable(tables):
    traj, _, _ = tables
    s = pgser.Sampler(traj, batch_size=8)
    first = [next(s) for _ in range(50)]
    assert len(first) == 50 and s.task == "FetchReach" and not s.scored
    s.close()
    with pytest.raises(ValueError, match="closed"):
        next(s)
    with pgser.Sampler(traj, batch_size=8, num_batches=2) as s2:
        assert len(list(s2)) == 2


def test_bad_settings_raise_with_pgser_message(tables, tmp_path):
    traj, _, scored = tables
    with pytest.raises(FileNotFoundError, match="nope.parquet"):
        pgser.Sampler(tmp_path / "nope.parquet")
    with pytest.raises(ValueError, match="swap random with a scored table"):
        pgser.Sampler(scored, swap="random")
    with pytest.raises(ValueError, match="swap="):
        pgser.Sampler(traj, swap="sometimes")
    with pytest.raises(ValueError, match="priority="):
        pgser.Sampler(scored, priority="best")
    with pytest.raises(ValueError, match="is-beta"):
        pgser.Sampler(scored, is_beta=2.0)
    with pytest.raises(ValueError, match="her=1.5"):
        pgser.Sampler(traj, her=1.5)
    with pytest.raises(ValueError, match="batch-size"):
        pgser.Sampler(traj, batch_size=0)
    with pytest.raises(ValueError, match="aug-ratio"):
        pgser.Sampler(scored, aug_ratio=-0.1)
