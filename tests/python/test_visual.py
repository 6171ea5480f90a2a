"""OGBench's visual datasets in Python: a table converted from a file rendered by ogbench's own
visual environment (tests/fixtures/ogbench/visual) holds each image as one fixed-size binary
value a row, which pyarrow reads back as the file's uint8 images; the samplers, which draw float
observations, refuse it by name."""
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


@pytest.mark.parametrize("layout", ["pgser", "ogbench"])
@pytest.mark.parametrize("budget", [None, "50M"])
def test_the_samplers_refuse_an_image_table_by_name(table, layout, budget):
    with pytest.raises(ValueError, match=r"vcube.parquet: observations are 64×64×3 uint8 images"):
        pgser.Sampler(table, layout=layout, memory_budget=budget)
