#!/usr/bin/env python3
"""Make small OGBench dataset files in OGBench's own on-disk format, with the real `ogbench` package.

The episodes are rolled out in ogbench's real PointMaze env exactly as OGBench's
`data_gen_scripts/generate_locomaze.py` does for PointMaze (its BFS oracle: the action is the unit
direction to the oracle subgoal cell plus N(0, noise) noise, clipped to [-1, 1]; for 'navigate' a new
goal is sampled when the current one is reached), only with fewer and shorter episodes and a fixed seed.
Nothing is downloaded (the dataset servers are not needed). Run it in a scratch venv:

  python3 -m venv /tmp/ogvenv
  /tmp/ogvenv/bin/pip install ogbench==1.2.2 mujoco==3.17.0
  /tmp/ogvenv/bin/python tests/py/make_ogbench_fixtures.py OUT_DIR [--check] [--dump-loaded]
      [--dataset-type navigate|stitch|explore] [--maze medium|large|giant|teleport]
      [--train-episodes 4] [--val-episodes 2] [--steps 101] [--seed 0] [--seed-per-episode]

Writes OUT_DIR/pointmaze-<maze>-<type>-v0.npz and OUT_DIR/pointmaze-<maze>-<type>-v0-val.npz with
`np.savez_compressed` (a zip of DEFLATE-compressed .npy members written with zip64 extra fields),
keys in this order: observations <f4 [N,2], actions <f4 [N,2], terminals |b1 [N], qpos <f4 [N,2],
qvel <f4 [N,2], as generate_locomaze.py writes them. Each episode is `--steps` rows (the script's
`max_episode_steps`; the real PointMaze navigate data use 1001, stitch 201, giant navigate 2001);
terminals is True only on an episode's last row. There is no separate "compact" file: OGBench ships
one layout and `compact_dataset=True` is only a load-time transform.

Differences from generate_locomaze.py, none of which changes the format:
- it seeds: `np.random.seed(seed)` (the script never seeds numpy's global RNG, which drives the cell
  sampling, the goal/start noise and the action noise), `env.reset(seed=seed)` on the first episode
  only (the env's own RNG draws the reset qvel, which lands in qvel's first row of each episode) and
  `env.action_space.seed(seed)` (the 5 random warm-up steps inside reset; they change nothing stored);
- train and val episodes are counted separately (the script takes num_episodes // 10 for val).

--seed-per-episode seeds numpy's global generator with seed + i before episode i (train episodes
first, then val), and never seeds env.reset: what `pgser-etl collect --policy oracle --seed S`
does, so that its files can be compared with these array for array (tests/ogbench.rs).

--check loads the files back with `ogbench.make_env_and_datasets(..., dataset_path=...)` for
compact_dataset False and True (and add_info True) and prints every array's shape and dtype.
--dump-loaded also writes what the loader returned (with add_info=True, so qpos/qvel are kept) as
uncompressed `np.savez` files next to the data, for a reader parity test without Python:
  <name>.loaded-regular.npz      observations, actions, terminals <f4, qpos, qvel, next_observations
  <name>.loaded-compact.npz      observations, actions, terminals <f4, qpos, qvel, valids <f4
  <name>-val.loaded-regular.npz, <name>-val.loaded-compact.npz   the same for the val file.

Every `gymnasium.make` of a maze env leaves a temp XML (/tmp/tmpXXXX.xml) behind: ogbench writes the
composed maze model with tempfile.mkstemp and never deletes it.
"""
import argparse
import os
import warnings

import gymnasium
import numpy as np

import ogbench  # noqa: F401  (registers the envs)
import ogbench.locomaze  # noqa: F401

warnings.filterwarnings('ignore')


def cells(maze_map):
    """All empty cells and 'vertex' cells (empty cells that are not straight hallway cells)."""
    all_cells, vertex_cells = [], []
    for i in range(maze_map.shape[0]):
        for j in range(maze_map.shape[1]):
            if maze_map[i, j] != 0:
                continue
            all_cells.append((i, j))
            if maze_map[i - 1, j] == 0 and maze_map[i + 1, j] == 0 and maze_map[i, j - 1] == 1 and maze_map[i, j + 1] == 1:
                continue
            if maze_map[i, j - 1] == 0 and maze_map[i, j + 1] == 0 and maze_map[i - 1, j] == 1 and maze_map[i + 1, j] == 1:
                continue
            vertex_cells.append((i, j))
    return all_cells, vertex_cells


def stitch_goal(maze_map, init_ij, adj_steps=4):
    """Cells exactly `adj_steps` BFS steps from init_ij, in BFS discovery order (as the script)."""
    bfs_map = np.full(maze_map.shape, -1, dtype=maze_map.dtype)
    bfs_map[init_ij] = 0
    queue, adj = [init_ij], []
    while queue:
        i, j = queue.pop(0)
        for di, dj in [(-1, 0), (0, -1), (1, 0), (0, 1)]:
            ni, nj = i + di, j + dj
            if 0 <= ni < maze_map.shape[0] and 0 <= nj < maze_map.shape[1] and maze_map[ni, nj] == 0 and bfs_map[ni, nj] == -1:
                bfs_map[ni, nj] = bfs_map[i, j] + 1
                queue.append((ni, nj))
                if bfs_map[ni, nj] == adj_steps:
                    adj.append((ni, nj))
    return adj[np.random.randint(len(adj))] if adj else init_ij


def rollout(env, num_episodes, dataset_type, noise, seed, first, seed_from=None):
    u = env.unwrapped
    all_cells, vertex_cells = cells(u.maze_map)
    data = {k: [] for k in ['observations', 'actions', 'terminals', 'qpos', 'qvel']}
    for ep in range(num_episodes):
        if seed_from is not None:
            np.random.seed(seed_from + ep)
            first = False
        if dataset_type in ['path', 'navigate', 'explore']:
            init_ij = all_cells[np.random.randint(len(all_cells))]
            goal_ij = vertex_cells[np.random.randint(len(vertex_cells))]
        else:
            init_ij = all_cells[np.random.randint(len(all_cells))]
            goal_ij = stitch_goal(u.maze_map, init_ij)
        kw = dict(seed=seed) if (first and ep == 0) else {}
        ob, _ = env.reset(options=dict(task_info=dict(init_ij=init_ij, goal_ij=goal_ij)), **kw)
        done, step, cur_dir = False, 0, None
        while not done:
            if dataset_type == 'explore':
                if step % 10 == 0:
                    cur_dir = np.random.randn(2)
                    cur_dir = cur_dir / (np.linalg.norm(cur_dir) + 1e-6)
                subgoal_dir = cur_dir
            else:
                subgoal_xy, _ = u.get_oracle_subgoal(u.get_xy(), u.cur_goal_xy)
                subgoal_dir = subgoal_xy - u.get_xy()
                subgoal_dir = subgoal_dir / (np.linalg.norm(subgoal_dir) + 1e-6)
            agent_ob = np.concatenate([u.get_ob(ob_type='states')[2:], subgoal_dir])
            action = agent_ob[-2:]  # The PointMaze "actor": the subgoal direction itself.
            action = action + np.random.normal(0, noise, action.shape)
            action = np.clip(action, -1, 1)  # float64, as in the script
            next_ob, _, terminated, truncated, info = env.step(action)
            done = terminated or truncated
            if info['success'] and dataset_type == 'navigate':
                goal_ij = vertex_cells[np.random.randint(len(vertex_cells))]
                u.set_goal(goal_ij)
            data['observations'].append(ob)
            data['actions'].append(action)
            data['terminals'].append(done)
            data['qpos'].append(info['prev_qpos'])
            data['qvel'].append(info['prev_qvel'])
            ob = next_ob
            step += 1
    out = {}
    for k, v in data.items():
        dtype = bool if k == 'terminals' else np.float32
        out[k] = np.array(v, dtype=dtype)
    return out


def main():
    p = argparse.ArgumentParser()
    p.add_argument('out_dir')
    p.add_argument('--maze', default='medium', choices=['medium', 'large', 'giant', 'teleport'])
    p.add_argument('--dataset-type', default='navigate', choices=['navigate', 'stitch', 'explore'])
    p.add_argument('--train-episodes', type=int, default=4)
    p.add_argument('--val-episodes', type=int, default=2)
    p.add_argument('--steps', type=int, default=101, help='rows per episode (max_episode_steps)')
    p.add_argument('--noise', type=float, default=0.5)
    p.add_argument('--seed', type=int, default=0)
    p.add_argument('--check', action='store_true')
    p.add_argument('--dump-loaded', action='store_true')
    p.add_argument('--seed-per-episode', action='store_true')
    a = p.parse_args()

    env_id = f'pointmaze-{a.maze}-v0'
    name = f'pointmaze-{a.maze}-{a.dataset_type}-v0'
    os.makedirs(a.out_dir, exist_ok=True)
    np.random.seed(a.seed)
    env = gymnasium.make(env_id, terminate_at_goal=False, max_episode_steps=a.steps)
    env.action_space.seed(a.seed)
    per = a.seed_per_episode
    train = rollout(env, a.train_episodes, a.dataset_type, a.noise, a.seed, first=True,
                    seed_from=a.seed if per else None)
    val = rollout(env, a.val_episodes, a.dataset_type, a.noise, a.seed, first=False,
                  seed_from=a.seed + a.train_episodes if per else None)
    train_path = os.path.join(a.out_dir, f'{name}.npz')
    val_path = train_path.replace('.npz', '-val.npz')
    for path, d in [(train_path, train), (val_path, val)]:
        np.savez_compressed(path, **d)
        print(f'wrote {path} ({os.path.getsize(path)} bytes):',
              ', '.join(f'{k} {v.dtype.str}{list(v.shape)}' for k, v in d.items()))

    if a.check or a.dump_loaded:
        import ogbench as og
        for compact in [False, True]:
            for add_info in [False, True]:
                _, tr, va = og.make_env_and_datasets(name, dataset_path=train_path, compact_dataset=compact,
                                                     add_info=add_info)
                for split, d in [('train', tr), ('val', va)]:
                    print(f'loaded compact={compact} add_info={add_info} {split}:',
                          ', '.join(f'{k} {v.dtype.str}{list(v.shape)}' for k, v in d.items()),
                          f'sum(terminals)={d["terminals"].sum()}')
                if a.dump_loaded and add_info:
                    tag = 'compact' if compact else 'regular'
                    for base, d in [(train_path, tr), (val_path, va)]:
                        np.savez(base.replace('.npz', f'.loaded-{tag}.npz'), **d)


if __name__ == '__main__':
    main()
