"""Open Minari datasets with the real `minari` package, for tests/minari.rs.

    check_minari.py same EXPECTED_DIR GOT_DIR
        Both folders are opened with minari.load_dataset (MINARI_DATASETS_PATH set to each
        one's parent, the id being the folder's name). Their episodes must hold equal arrays:
        observations (every Dict key), actions, rewards, terminations and truncations, value for
        value, and bit for bit where the dtypes agree (a float32 array against a float64 one is
        compared after widening, which is exact); and the same infos keys, each with the same
        dtype, shape and bits. Also the counts and the env spec's id.

    check_minari.py table TABLE.parquet DATASET_DIR THRESHOLD
        The dataset opened with minari.load_dataset must hold the trajectory table (read with
        pyarrow): observations = obs / achieved_goal rows, desired_goal = the table's (its last
        row repeating the step before), actions = the non-null action rows, rewards =
        -(|ag[t+1] - g[t]| > THRESHOLD), no terminations, truncation on the last step only; or,
        where the table keeps a Minari dataset's recorded rewards, terminations or truncations
        (passthrough columns of those names), those.

    check_minari.py edit DATASET_DIR EPISODE COLUMN add|remove|string
        Changes one episode of a dataset in place, in either storage (pyarrow or h5py), as
        another tool might have written it: `add` gives it a float32 column COLUMN (`infos/KEY`)
        of zeros, a row per observation, `remove` takes COLUMN away, `string` turns it into
        strings (`rewards`, `infos/KEY`), which no table column keeps.

Prints one JSON line of what was compared; exits non-zero with the first difference.
"""

import json
import os
import sys

import numpy as np


def load(folder):
    folder = os.path.abspath(folder)
    os.environ["MINARI_DATASETS_PATH"] = os.path.dirname(folder)
    import minari

    return minari.load_dataset(os.path.basename(folder))


def same(what, a, b):
    a, b = np.asarray(a), np.asarray(b)
    if a.shape != b.shape:
        sys.exit(f"{what}: shape {a.shape} vs {b.shape}")
    if a.dtype == b.dtype and a.dtype.kind == "f":
        if not np.array_equal(a.view(f"u{a.dtype.itemsize}"), b.view(f"u{b.dtype.itemsize}")):
            sys.exit(f"{what}: bits differ")
    elif not np.array_equal(a.astype(np.float64) if a.dtype.kind == "f" else a,
                            b.astype(np.float64) if b.dtype.kind == "f" else b):
        sys.exit(f"{what}: values differ ({a.dtype} vs {b.dtype})")


def episodes(ds):
    return list(ds.iterate_episodes())


def cmd_same(expected_dir, got_dir):
    want, got = load(expected_dir), load(got_dir)
    for attr in ("total_episodes", "total_steps"):
        if getattr(want, attr) != getattr(got, attr):
            sys.exit(f"{attr}: {getattr(want, attr)} vs {getattr(got, attr)}")
    ids = [d.spec.env_spec.id if d.spec.env_spec else None for d in (want, got)]
    if ids[0] != ids[1]:
        sys.exit(f"env_spec id: {ids[0]} vs {ids[1]}")
    dtypes = {}
    for i, (a, b) in enumerate(zip(episodes(want), episodes(got))):
        if set(a.observations) != set(b.observations):
            sys.exit(f"episode {i}: observation keys {sorted(a.observations)} vs {sorted(b.observations)}")
        for key in a.observations:
            same(f"episode {i} observations/{key}", a.observations[key], b.observations[key])
            dtypes[key] = [str(a.observations[key].dtype), str(b.observations[key].dtype)]
        for key in ("actions", "rewards", "terminations", "truncations"):
            same(f"episode {i} {key}", getattr(a, key), getattr(b, key))
            dtypes[key] = [str(getattr(a, key).dtype), str(getattr(b, key).dtype)]
        ia, ib = a.infos or {}, b.infos or {}
        if sorted(ia) != sorted(ib):
            sys.exit(f"episode {i}: infos keys {sorted(ia)} vs {sorted(ib)}")
        for key in ia:
            x, y = np.asarray(ia[key]), np.asarray(ib[key])
            if x.dtype != y.dtype or x.shape != y.shape or x.tobytes() != y.tobytes():
                sys.exit(f"episode {i} infos/{key}: {y.dtype}{y.shape} differs from {x.dtype}{x.shape}")
            dtypes[f"infos/{key}"] = [str(x.dtype), str(y.dtype)]
    print(json.dumps({"episodes": want.total_episodes, "steps": want.total_steps, "env_id": ids[0], "dtypes": dtypes}))


def cmd_table(table, dataset_dir, threshold):
    import pyarrow.parquet as pq

    t = pq.read_table(table)
    footer = json.loads(pq.read_metadata(table).metadata[b"pgser"])
    n, T = footer["episodes"], footer["T"]

    def column(name, dim):
        col = t.column(name).combine_chunks()
        values = np.asarray(col.flatten() if col.null_count == 0 else col.values, dtype=np.float64)
        return values.reshape(n, T, dim)

    obs = column("obs", footer["obs_dim"])
    ag = column("achieved_goal", footer["goal_dim"])
    g = column("desired_goal", footer["goal_dim"])[:, : T - 1]
    u = column("action", footer["act_dim"])[:, : T - 1]
    ds = load(dataset_dir)
    if ds.total_episodes != n or ds.total_steps != n * (T - 1):
        sys.exit(f"counts: {ds.total_episodes} episodes, {ds.total_steps} steps for a table of {n} x T={T}")
    for i, ep in enumerate(episodes(ds)):
        same(f"episode {i} observation", ep.observations["observation"], obs[i])
        same(f"episode {i} achieved_goal", ep.observations["achieved_goal"], ag[i])
        same(f"episode {i} desired_goal", ep.observations["desired_goal"], np.concatenate([g[i], g[i][-1:]]))
        same(f"episode {i} actions", ep.actions, u[i])
        d = np.linalg.norm(ag[i][1:] - g[i], axis=-1)
        want = {"rewards": -(d > threshold).astype(np.float32), "terminations": np.zeros(T - 1, bool),
                "truncations": np.arange(T - 1) == T - 2}
        for key, default in want.items():
            if key in t.column_names:
                kept = t.column(key).combine_chunks().to_numpy(zero_copy_only=False).reshape(n, T)[i, : T - 1]
                default = kept.astype(default.dtype)
            same(f"episode {i} {key}", getattr(ep, key), default)
    env_id = ds.spec.env_spec.id if ds.spec.env_spec else None
    print(json.dumps({"episodes": n, "T": T, "env_id": env_id, "obs_dtype": str(ep.observations["observation"].dtype)}))


def cmd_edit(dataset_dir, episode, column, action):
    data = os.path.join(dataset_dir, "data")
    with open(os.path.join(data, "metadata.json")) as f:
        storage = json.load(f)["data_format"]
    group, _, key = column.rpartition("/")
    if storage == "hdf5":
        import h5py

        with h5py.File(os.path.join(data, "main_data.hdf5"), "r+") as f:
            ep = f[f"episode_{episode}"]
            where = ep.require_group(group) if group else ep
            rows = ep["actions"].shape[0] + (1 if group == "infos" else 0)
            if action == "add":
                where.create_dataset(key, data=np.zeros(rows, np.float32))
            elif action == "remove":
                del where[key]
            else:
                values = [str(v).encode() for v in where[key][()]]
                del where[key]
                where.create_dataset(key, data=np.array(values, dtype="S16"))
    else:
        import pyarrow as pa
        import pyarrow.ipc as ipc

        path = os.path.join(data, str(episode), "part-0.arrow")
        with ipc.open_file(path) as r:
            t = r.read_all()
        if group:
            s = t.column(group).combine_chunks()
            fields, arrays = list(s.type), [s.field(i) for i in range(s.type.num_fields)]
            names = [f.name for f in fields]
            if action == "add":
                fields.append(pa.field(key, pa.float32()))
                arrays.append(pa.array(np.zeros(len(s), np.float32)))
            else:
                i = names.index(key)
                if action == "remove":
                    del fields[i], arrays[i]
                else:
                    fields[i] = pa.field(key, pa.string())
                    arrays[i] = pa.array([str(v) for v in arrays[i].to_pylist()])
            new = pa.StructArray.from_arrays(arrays, fields=fields)
            t = t.set_column(t.schema.get_field_index(group), pa.field(group, new.type), new)
        else:
            i = t.schema.get_field_index(key)
            assert action == "string", action
            t = t.set_column(i, pa.field(key, pa.string()), pa.array([str(v) for v in t.column(key).to_pylist()]))
        with ipc.new_file(path, t.schema) as w:
            w.write_table(t)
    print(json.dumps({"edited": [dataset_dir, episode, column, action, storage]}))


if __name__ == "__main__":
    if len(sys.argv) == 4 and sys.argv[1] == "same":
        cmd_same(sys.argv[2], sys.argv[3])
    elif len(sys.argv) == 5 and sys.argv[1] == "table":
        cmd_table(sys.argv[2], sys.argv[3], float(sys.argv[4]))
    elif len(sys.argv) == 6 and sys.argv[1] == "edit":
        cmd_edit(sys.argv[2], int(sys.argv[3]), sys.argv[4], sys.argv[5])
    else:
        sys.exit(__doc__)
