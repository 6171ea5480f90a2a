"""Other readers of pgser's tables, for tests/interop.rs.

  check_interop.py dump OUT_DIR NAME=PATH...   read each table with polars and with DuckDB and
      dump what each reader sees: a Parquet table as, per reader and column, its values as
      float64 (vectors flattened row-major, NaN where a row is null) in NAME.READER.COLUMN.f64
      and its null rows in NAME.READER.COLUMN.nulls (one byte per row), with the row count and
      column names in NAME.READER.json; a CSV table as its rows in NAME.READER.json (NaN as the
      string "NaN", empty cells as null). The Rust test compares them with pgser's own reading.
  check_interop.py write-traj SRC DEST   polars reads a trajectory table and writes it again
      with its own Parquet writer, carrying over the `pgser` footer: a table pgser did not write.
"""

import json
import math
import sys

import duckdb
import numpy as np
import polars as pl


def as_f64(values):
    """Column values (scalars, lists or None) as flat float64 and a null mask."""
    dim = max((len(v) for v in values if isinstance(v, (list, tuple))), default=1)
    flat, nulls = [], []
    for v in values:
        nulls.append(v is None)
        if v is None:
            flat.extend([math.nan] * dim)
        elif isinstance(v, (list, tuple)):
            flat.extend(float(x) for x in v)
        else:
            flat.append(float(v))
    return np.asarray(flat, dtype="<f8"), np.asarray(nulls, dtype=np.uint8)


def duckdb_columns(rel):
    rows = rel.fetchall()
    return {c: [r[i] for r in rows] for i, c in enumerate(rel.columns)}


def sql_path(path):
    return "'" + path.replace("'", "''") + "'"


def dump_parquet(out, name, path):
    readers = {
        "polars": {c: s.to_list() for c, s in pl.read_parquet(path).to_dict().items()},
        "duckdb": duckdb_columns(duckdb.sql(f"SELECT * FROM read_parquet({sql_path(path)})")),
    }
    for reader, columns in readers.items():
        rows = len(next(iter(columns.values())))
        for c, values in columns.items():
            flat, nulls = as_f64(values)
            flat.tofile(f"{out}/{name}.{reader}.{c}.f64")
            nulls.tofile(f"{out}/{name}.{reader}.{c}.nulls")
        with open(f"{out}/{name}.{reader}.json", "w") as f:
            json.dump({"rows": rows, "columns": list(columns)}, f)


def cell(v):
    return "NaN" if isinstance(v, float) and math.isnan(v) else v


def dump_csv(out, name, path):
    readers = {
        "polars": pl.read_csv(path).to_dict(as_series=False),
        "duckdb": duckdb_columns(duckdb.sql(f"SELECT * FROM read_csv({sql_path(path)})")),
    }
    for reader, columns in readers.items():
        rows = [dict(zip(columns, (cell(v) for v in r))) for r in zip(*columns.values())]
        with open(f"{out}/{name}.{reader}.json", "w") as f:
            json.dump(rows, f)


def main():
    if sys.argv[1] == "dump":
        out = sys.argv[2]
        for arg in sys.argv[3:]:
            name, path = arg.split("=", 1)
            (dump_csv if path.endswith(".csv") else dump_parquet)(out, name, path)
    elif sys.argv[1] == "write-traj":
        src, dest = sys.argv[2], sys.argv[3]
        footer = pl.read_parquet_metadata(src)["pgser"]
        pl.read_parquet(src).write_parquet(dest, metadata={"pgser": footer})
    else:
        sys.exit(f"unknown command {sys.argv[1]}")


if __name__ == "__main__":
    main()
