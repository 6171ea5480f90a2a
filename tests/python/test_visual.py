"""OGBench's visual datasets in Python: a table converted from a file rendered by ogbench's own
visual environment (tests/fixtures/ogbench/visual) holds each image as one fixed-size binary
value a row, which pyarrow reads back as the file's uint8 images; OGBench's layout of
`pgser.Sampler` gives uint8 batches stacked and cropped as OGBench's `GCDataset` does (checked
here against its own numpy code, re-implemented on the file), and the pgser layout, which draws
float observations, refuses the table by name."""
import numpy as np
import pyarrow.parquet as pq
import pytest

import pgser
from conftest import REPO

FIXTURE = REPO / "tests/fixtures/ogbench/visual/visual-cube-single-play-v0.npz"


@pytest.fixture(scope="module")
def table(tmp_path_factory):
    out = tmp_path_factory.mktemp("visual") / "vcube.parquet"
    pgser.convert([FIXTURE], out)
    return out


def test_images_read_back_with_pyarrow_as_the_files(table):
    want = np.load(FIXTURE)["observations"]
    assert want.dtype == np.uint8 and want.shape[1:] == (64, 64, 3)
    t = pq.read_table(table)
    assert str(t.schema.field("obs").type) == "fixed_size_binary[12288]"
    got = np.frombuffer(b"".join(t.column("obs").to_pylist()), np.uint8).reshape(-1, 64, 64, 3)
    np.testing.assert_array_equal(got, want)
    assert pgser.read_footer(table)["image_shape"] == [64, 64, 3]


@pytest.mark.parametrize("budget", [None, "50M"])
def test_the_pgser_layout_refuses_an_image_table_by_name(table, budget):
    with pytest.raises(ValueError, match=r"vcube.parquet: observations are 64×64×3 uint8 images"):
        pgser.Sampler(table, layout="pgser", memory_budget=budget)


def ogbench_stacks(observations, terminals, idxs, frame_stack):
    """OGBench's `get_stacked_observations` on its compact dataset (`load_dataset(...,
    compact_dataset=True)`: `terminals` set on each trajectory's last two steps)."""
    compact = np.minimum(terminals + np.concatenate([terminals[1:], [1.0]]), 1.0)
    (terminal_locs,) = np.nonzero(compact > 0)
    initial_locs = np.concatenate([[0], terminal_locs[:-1] + 1])
    initial = initial_locs[np.searchsorted(initial_locs, idxs, side="right") - 1]
    frames = [observations[np.maximum(idxs - i, initial)] for i in reversed(range(frame_stack))]
    return np.concatenate(frames, axis=-1)


def ogbench_crop(images, crop_froms, padding=3):
    """OGBench's `batched_random_crop`: edge padding, then a cut at each row's offsets."""
    padded = np.pad(images, ((0, 0), (padding, padding), (padding, padding), (0, 0)), mode="edge")
    h, w = images.shape[1:3]
    return np.stack([p[y : y + h, x : x + w] for p, (y, x) in zip(padded, crop_froms)])


@pytest.mark.parametrize("budget", [None, "50M"])
@pytest.mark.parametrize("frame_stack", [None, 3])
def test_ogbench_batches_are_the_files_images_stacked_and_cropped(table, budget, frame_stack):
    src = np.load(FIXTURE)
    observations, terminals = src["observations"], src["terminals"].astype(np.float32)
    t = int(np.nonzero(terminals)[0][0]) + 1
    config = dict(batch_size=64, p_aug=1.0, frame_stack=frame_stack, discount=0.99)
    s = pgser.Sampler(table, layout="ogbench", config=config, memory_budget=budget)
    k = frame_stack or 1
    for evaluation in [False, True]:
        b = s.sample(64, evaluation=evaluation)
        cropped = b["crop_y"][0] >= 0
        assert cropped != evaluation, "p_aug = 1 crops every training batch and no evaluation batch"
        for key, (ep, st), nxt in [
            ("observations", ("episode", "step"), 0),
            ("next_observations", ("episode", "step"), 1),
            ("value_goals", ("value_goal_episode", "value_goal_step"), 0),
            ("actor_goals", ("actor_goal_episode", "actor_goal_step"), 0),
        ]:
            got = b[key]
            assert got.dtype == np.uint8 and got.shape == (64, 64, 64, 3 * k), key
            idxs = b[ep] * t + b[st] + nxt
            want = ogbench_stacks(observations, terminals, idxs, k)
            if cropped:
                want = ogbench_crop(want, np.stack([b["crop_y"], b["crop_x"]], axis=1))
            np.testing.assert_array_equal(got, want, err_msg=key)
    s.close()


def test_bad_pixel_settings_are_refused_by_name(table):
    with pytest.raises(ValueError, match=r"p_aug = 2: must be in \[0, 1\]"):
        pgser.Sampler(table, layout="ogbench", config=dict(p_aug=2.0))
    with pytest.raises(ValueError, match=r"frame_stack = 50: longer than this table's episodes"):
        pgser.Sampler(table, layout="ogbench", config=dict(frame_stack=50))
    with pytest.raises(ValueError, match=r"p_aug = 0.5: a key of OGBench's dataset classes"):
        pgser.Sampler(table, layout="horizon_reduction", p_aug=0.5)
