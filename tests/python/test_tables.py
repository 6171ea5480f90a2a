"""pgser.read_table / read_footer / convert / score: the CLI's tables through Python, and every
bad input raising a Python exception with pgser's one-line message and leaving no file."""

import pickle

import numpy as np
import pyarrow.parquet as pq
import pytest

import pgser
from conftest import BIN, REPO, footer, run


def test_read_table_round_trips_with_pyarrow(tables):
    traj, _, scored = tables
    for path in (traj, scored):
        ours, theirs = pgser.read_table(path), pq.read_table(path)
        assert ours.schema.equals(theirs.schema, check_metadata=False)
        assert ours.equals(theirs), path
        assert pgser.read_footer(path) == footer(path)
    sub = pgser.read_table(scored, columns=["episode", "q"])
    assert sub.column_names == ["episode", "q"]
    assert sub.column("q").equals(pq.read_table(scored, columns=["q"]).column("q"))


def test_a_flipped_bit_raises_what_verify_says(tables, tmp_path):
    """One flipped bit in a page's data, a page's header or the footer: `pgser.read_table`,
    `pgser.read_footer` (for the footer) and `pgser-etl query` refuse the file with the line
    `pgser-etl verify` prints, never returning other values."""
    import subprocess

    traj, _, _ = tables
    raw = traj.read_bytes()
    chunk = pq.ParquetFile(traj).metadata.row_group(0).column(0)
    start = chunk.dictionary_page_offset or chunk.data_page_offset
    where = {
        "page header": start + 1,
        "page data": start + chunk.total_compressed_size // 2,
        "footer": raw.rindex(b'"kind"') + 2,
    }
    for what, at in where.items():
        bad = tmp_path / f"{what.replace(' ', '_')}.parquet"
        flipped = bytearray(raw)
        flipped[at] ^= 0x04
        bad.write_bytes(bytes(flipped))
        v = subprocess.run([BIN / "pgser-etl", "verify", bad], capture_output=True, text=True)
        assert v.returncode == 1 and v.stdout.startswith("CORRUPT "), (what, v.stdout, v.stderr)
        line = v.stdout.strip().removeprefix("CORRUPT ")
        assert "\n" not in line and str(bad) in line, line
        with pytest.raises(ValueError) as e:
            pgser.read_table(bad)
        assert str(e.value) == line, what
        if what == "footer":
            with pytest.raises(ValueError) as e:
                pgser.read_footer(bad)
            assert str(e.value) == line
        q = subprocess.run([BIN / "pgser-etl", "query", "SELECT count(*) AS n FROM t", f"t={bad}"],
                           capture_output=True, text=True)
        assert q.returncode == 1 and q.stderr.strip() == f"pgser-etl: error: {line}", (what, q.stderr)


def test_convert_equals_the_cli(tables, tmp_path):
    traj, _, _ = tables
    cli = tmp_path / "cli.parquet"
    data = REPO / "data"
    run(BIN / "pgser-etl", "convert", data / "fetch_reach_expert_50.pkl", data / "fetch_reach_random_200.pkl", "-o", cli)
    assert pgser.read_table(traj).equals(pgser.read_table(cli))
    a, b = footer(traj), footer(cli)
    a.pop("command"), b.pop("command")
    # Same column chunks, byte for byte; the footer's own checksum covers the command line.
    assert a.pop("checksums")["column_chunks"] == b.pop("checksums")["column_chunks"]
    for s in a["sources"] + b["sources"]:
        s.pop("path")
    assert a == b
    s = pgser.convert([data / "fetch_reach_expert_50.pkl"], tmp_path / "e.parquet", episodes=[10], float32=True)
    assert (s["episodes"], s["float_type"], s["task"]) == (10, "float32", "FetchReach")


def test_score_summary_and_table(tables):
    _, _, scored = tables
    f = pgser.read_footer(scored)
    assert f["kind"] == "transition" and f["swaps"] == 2 and f["include_original"] is True
    q = pgser.read_table(scored, columns=["q"]).column("q").to_numpy()
    assert np.isclose(q.mean(), f["q"]["mean"], rtol=1e-5)


def test_bad_inputs_raise_with_one_line_and_leave_no_file(tables, tmp_path):
    traj, ckpt, _ = tables
    out = tmp_path / "out.parquet"
    missing = tmp_path / "missing.parquet"
    with pytest.raises(FileNotFoundError, match="missing.parquet"):
        pgser.read_table(missing)
    with pytest.raises(FileNotFoundError, match="missing.parquet"):
        pgser.read_footer(missing)
    not_parquet = tmp_path / "x.parquet"
    not_parquet.write_bytes(b"not a parquet file at all")
    with pytest.raises(ValueError, match="x.parquet: not a readable Parquet file"):
        pgser.read_table(not_parquet)
    with pytest.raises(ValueError, match="no column nope"):
        pgser.read_table(traj, columns=["nope"])
    with pytest.raises(FileNotFoundError, match="missing.parquet"):
        pgser.convert([missing], out)
    # A pickle that is not a WGCSL buffer: refused by the reader, which never executes it.
    bad = tmp_path / "bad.pkl"
    bad.write_bytes(pickle.dumps({"o": np.zeros((2, 3, 4)), "u": [1, 2]}))
    with pytest.raises(ValueError, match="bad.pkl") as e:
        pgser.convert([bad], out)
    assert "\n" not in str(e.value)
    with pytest.raises(ValueError, match="task 'FetchFly' is not built in"):
        pgser.convert([REPO / "data" / "fetch_reach_expert_50.pkl"], out, task="FetchFly")
    with pytest.raises(FileNotFoundError, match="missing.ckpt"):
        pgser.score(tmp_path / "missing.ckpt", traj, out)
    with pytest.raises(ValueError, match="swaps"):
        pgser.score(ckpt, traj, out, swaps=0)
    with pytest.raises(TypeError):
        pgser.convert([traj], out, no_such_option=1)
    assert not out.exists()
    assert not any(p.name.startswith(".") for p in tmp_path.iterdir()), "a temporary file was left"


def test_ctrl_c_interrupts_a_long_score_and_leaves_no_file(tables, tmp_path):
    """SIGINT during pgser.score (6.3M rows, about 4 s of work on 2 cores): KeyboardInterrupt within a fraction
    of a second, and no output or temporary file."""
    import subprocess
    import sys
    import textwrap

    traj, ckpt, _ = tables
    out = tmp_path / "big" / "scored.parquet"
    out.parent.mkdir()
    script = textwrap.dedent(f"""
        import os, signal, threading, time, pgser
        # Ctrl-C's handler, whatever this process inherited: a shell's background job (`make
        # test &`) starts with SIGINT ignored, and Python then leaves it ignored.
        signal.signal(signal.SIGINT, signal.default_int_handler)
        threading.Timer(0.5, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
        t0 = time.time()
        try:
            pgser.score({str(ckpt)!r}, {str(traj)!r}, {str(out)!r}, swaps=512)
            print("finished", time.time() - t0)
        except KeyboardInterrupt:
            print("interrupted", time.time() - t0)
    """)
    p = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert p.returncode == 0, p.stderr
    word, seconds = p.stdout.split()
    assert word == "interrupted" and float(seconds) < 3.0, p.stdout
    assert list(out.parent.iterdir()) == []


def test_passthrough_columns_are_columns_like_any_other(tmp_path):
    """A WGCSL buffer's extra arrays (here WGCSL's info_is_success and an int per step) are
    columns of the table: `pgser.read_table`, `pgser-etl query` and pyarrow see them with the
    buffer's values, and `pgser.convert(drop=...)` leaves one out by name."""
    import subprocess

    src = REPO / "tests" / "fixtures" / "passthrough" / "wgcsl_info.pkl"
    with open(src, "rb") as f:
        d = pickle.load(f)
    out = tmp_path / "t.parquet"
    s = pgser.convert([src], out, task="FetchReach")
    assert s["kept"][0].startswith("info_is_success (<f8 [1] per transition)"), s
    t = pgser.read_table(out)
    assert t.column_names[6:] == ["info_is_success", "phase"]
    n, T = d["o"].shape[:2]
    steps = np.array(t.column("step"))
    info = t.column("info_is_success").combine_chunks()
    assert np.array_equal(np.asarray(info.is_null()), steps == T - 1)
    kept = info.filter(steps < T - 1).flatten().to_numpy()
    assert np.array_equal(kept, d["info_is_success"].reshape(-1))
    assert np.array_equal(t.column("phase").to_numpy(), d["phase"].reshape(-1))
    assert t.equals(pq.read_table(out))
    q = subprocess.run([BIN / "pgser-etl", "query", "SELECT sum(phase) AS s FROM t", f"t={out}", "--json"],
                       capture_output=True, text=True)
    assert q.returncode == 0, q.stderr
    assert f'"s":{int(d["phase"].sum())}' in q.stdout.replace(" ", ""), q.stdout
    footer = pgser.read_footer(out)
    assert [p["column"] for p in footer["passthrough"]] == ["info_is_success", "phase"]
    dropped = tmp_path / "d.parquet"
    s = pgser.convert([src], dropped, task="FetchReach", drop=["phase"])
    assert pgser.read_table(dropped).column_names[6:] == ["info_is_success"]
    assert any("phase" in note for note in s["notes"]), s
