//! OGBench's PointMaze (`pointmaze-{medium,large,giant,teleport}-v0`, ogbench 1.2.2
//! `locomaze/maze.py` and `point.py`) on MuJoCo 3.17.0, for evaluating agents trained on OGBench's
//! PointMaze datasets (`pgser-etl convert`, docs/ogbench.md).
//!
//! The model is OGBench's `point.xml` (vendored in `assets/ogbench/` with its licence) with the
//! maze composed into it as `update_tree` composes it: one 4 × 4 × 2 box per wall cell in
//! row-major order after the point's body, the floor resized to the maze, a teleport's pads, and
//! the goal marker. The point is two slide joints: a step adds 0.2 · action to its position, sets
//! its velocity to 0 and runs 5 MuJoCo steps, in which only the walls act (soft contacts push the
//! point back out of them). The observation is the position (x, y); the goal is a position; success
//! is a distance of at most 1.
//!
//! OGBench draws a reset's start and goal noise (uniform ±1 around the task's cells) and a random
//! task from numpy's *global* generator, which `env.reset(seed=s)` does not seed; so this
//! environment carries its own [`RandomState`], and `reset(Some(s))` equals Python's
//! `np.random.seed(s); env.reset(seed=s)` (`tests/env_parity.rs` replays episodes, walls and
//! teleports included, against the Python environment bit for bit).

use anyhow::{Result, anyhow, bail};
use mujoco_rs::prelude::*;

use super::{GoalEnv, Obs, Step};
use crate::nprandom::legacy::RandomState;
use crate::task::Task;

/// The environments this module simulates, by OGBench's ids.
pub const TASKS: [&str; 4] =
    ["pointmaze-medium-v0", "pointmaze-large-v0", "pointmaze-giant-v0", "pointmaze-teleport-v0"];

/// The PointMaze an id names: an environment id (`pointmaze-medium-v0`) or an OGBench dataset's
/// name (`pointmaze-medium-navigate-v0`, `pointmaze-large-stitch-v0`), whose environment is the
/// name without its dataset type, as `ogbench.make_env_and_datasets` has it.
pub fn resolve(id: &str) -> Option<&'static str> {
    let words: Vec<&str> = id.split('-').collect();
    let env = match words.as_slice() {
        ["pointmaze", size, version] => format!("pointmaze-{size}-{version}"),
        ["pointmaze", size, "navigate" | "stitch" | "explore", version] => format!("pointmaze-{size}-{version}"),
        _ => return None,
    };
    TASKS.iter().copied().find(|t| *t == env)
}

/// The task of a PointMaze id ([`resolve`]), as its environment has it.
pub fn task(id: &str) -> Option<Task> {
    resolve(id).map(|name| Task::custom(name, EPISODE_STEPS, 2, 2, 2, GOAL_TOL))
}

/// How OGBench's PointMaze datasets were made (`data_gen_scripts/generate_locomaze.py` and the
/// flags in its `commands.sh`), which `pgser-etl collect --policy oracle` follows.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Recipe {
    pub kind: DatasetKind,
    /// Rows (observations) per episode: the generator's `max_episode_steps`.
    pub rows: usize,
    /// Training episodes of the published dataset (its `-val` file holds a tenth as many more).
    pub episodes: usize,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum DatasetKind {
    /// From a random cell to a random junction cell, a new junction each time one is reached,
    /// for the whole episode.
    Navigate,
    /// From a random cell to a cell 4 steps away, staying there: short pieces that only
    /// stitching joins into the evaluation tasks' paths.
    Stitch,
}

/// The recipe of an OGBench PointMaze dataset name (`pointmaze-large-stitch-v0`); None for an
/// environment id or another family.
pub fn recipe(dataset: &str) -> Option<Recipe> {
    resolve(dataset)?;
    let words: Vec<&str> = dataset.split('-').collect();
    let giant = words[1] == "giant";
    match words.get(2) {
        Some(&"navigate") if giant => Some(Recipe { kind: DatasetKind::Navigate, rows: 2001, episodes: 500 }),
        Some(&"navigate") => Some(Recipe { kind: DatasetKind::Navigate, rows: 1001, episodes: 1000 }),
        Some(&"stitch") => Some(Recipe { kind: DatasetKind::Stitch, rows: 201, episodes: 5000 }),
        _ => None,
    }
}

/// The standard deviation of the action noise in every PointMaze dataset (`--noise=0.5`).
pub const ORACLE_NOISE: f64 = 0.5;

/// Steps per episode (OGBench registers every PointMaze with `max_episode_steps=1000`).
pub const EPISODE_STEPS: usize = 1000;
/// OGBench's `goal_tol` for the point.
pub const GOAL_TOL: f64 = 1.0;
const POINT_XML: &str = include_str!("../../assets/ogbench/point.xml");
const MAZE_UNIT: f64 = 4.0;
const FRAME_SKIP: usize = 5;

/// A maze cell (row i, column j).
pub type Cell = (usize, usize);

struct Maze {
    map: &'static [&'static str],
    /// (start cell, goal cell) of evaluation tasks 1–5.
    tasks: [(Cell, Cell); 5],
    /// Inbound and outbound teleport pads (teleport maze only).
    teleport: Option<(&'static [Cell], &'static [Cell])>,
}

fn maze(name: &str) -> Option<Maze> {
    Some(match name {
        "pointmaze-medium-v0" => Maze {
            map: &["11111111", "10011001", "10010001", "11000111", "10010001", "10100101", "10001001", "11111111"],
            tasks: [((1, 1), (6, 6)), ((6, 1), (1, 6)), ((5, 3), (4, 2)), ((6, 5), (6, 1)), ((2, 6), (1, 1))],
            teleport: None,
        },
        "pointmaze-large-v0" => Maze {
            map: &[
                "111111111111",
                "100001000001",
                "101101010101",
                "100000010001",
                "101111011101",
                "100101000001",
                "110101010111",
                "100100010001",
                "111111111111",
            ],
            tasks: [((1, 1), (7, 10)), ((5, 4), (7, 1)), ((7, 4), (1, 10)), ((3, 8), (5, 4)), ((1, 1), (5, 4))],
            teleport: None,
        },
        "pointmaze-giant-v0" => Maze {
            map: &[
                "1111111111111111",
                "1010000001100001",
                "1010110101001101",
                "1000100100010001",
                "1011101111110101",
                "1000100010000101",
                "1110101001010111",
                "1000100100010001",
                "1010101111110101",
                "1011100010001101",
                "1000001000100001",
                "1111111111111111",
            ],
            tasks: [((1, 1), (10, 14)), ((1, 14), (10, 1)), ((8, 14), (1, 1)), ((8, 3), (5, 12)), ((5, 9), (3, 8))],
            teleport: None,
        },
        "pointmaze-teleport-v0" => Maze {
            map: &[
                "111111111111",
                "100000101001",
                "110100010011",
                "110111000001",
                "100001010101",
                "101101010101",
                "101101010101",
                "100001000101",
                "111111111111",
            ],
            tasks: [((1, 10), (7, 1)), ((1, 1), (7, 10)), ((5, 6), (7, 10)), ((7, 1), (7, 10)), ((5, 6), (7, 1))],
            teleport: Some((&[(4, 6), (5, 1)], &[(1, 7), (6, 1), (6, 10)])),
        },
        _ => return None,
    })
}

/// `ij_to_xy`: cell (i, j) → its centre, column j along x, row i along y; cell (1, 1) is (0, 0).
fn ij_to_xy((i, j): Cell) -> [f64; 2] {
    [j as f64 * MAZE_UNIT - 4.0, i as f64 * MAZE_UNIT - 4.0]
}

/// Python's `str(float)` for the whole numbers and halves the model uses (`-4.0`, `20.0`).
fn py_float(x: f64) -> String {
    format!("{x:?}")
}

/// `update_tree`: `point.xml` with the maze's walls, floor, teleport pads and goal marker.
fn compose(m: &Maze) -> Result<String> {
    let (h, w) = (m.map.len(), m.map[0].len());
    let mut geoms = String::new();
    for (i, row) in m.map.iter().enumerate() {
        for (j, c) in row.bytes().enumerate() {
            if c == b'1' {
                let [x, y] = ij_to_xy((i, j));
                geoms += &format!(
                    "<geom name=\"block_{i}_{j}\" pos=\"{} {} 1.0\" size=\"2.0 2.0 1.0\" type=\"box\" contype=\"1\" \
                     conaffinity=\"1\" material=\"wall\"/>\n",
                    py_float(x),
                    py_float(y)
                );
            }
        }
    }
    if let Some((ins, outs)) = m.teleport {
        for (kind, cells) in [("in", ins), ("out", outs)] {
            for (k, &c) in cells.iter().enumerate() {
                let [x, y] = ij_to_xy(c);
                geoms += &format!(
                    "<geom name=\"teleport_{kind}_{k}\" type=\"cylinder\" size=\"1 .05\" pos=\"{} {} .05\" \
                     material=\"teleport_{kind}\" contype=\"0\" conaffinity=\"0\"/>\n",
                    py_float(x),
                    py_float(y)
                );
            }
        }
    }
    geoms += "<geom name=\"target\" type=\"cylinder\" size=\".5 .05\" pos=\"0 0 .05\" material=\"target\" contype=\"0\" conaffinity=\"0\"/>\n";
    let floor = "<geom name=\"floor\" pos=\"0 0 0\" size=\"100 100 .2\"";
    if !POINT_XML.contains(floor) || !POINT_XML.contains("</worldbody>") {
        bail!("assets/ogbench/point.xml is not OGBench 1.2.2's point.xml");
    }
    let resized = format!(
        "<geom name=\"floor\" pos=\"{} {} 0\" size=\"{} {} 0.2\"",
        2 * (w as i64 - 3),
        2 * (h as i64 - 3),
        2 * w,
        2 * h
    );
    Ok(POINT_XML.replace(floor, &resized).replace("</worldbody>", &format!("{geoms}</worldbody>")))
}

/// `xy_to_ij`: the cell a position is in (truncating toward 0, as Python's `int`).
fn xy_to_ij([x, y]: [f64; 2]) -> (i64, i64) {
    (((y + 4.0 + 0.5 * MAZE_UNIT) / MAZE_UNIT) as i64, ((x + 4.0 + 0.5 * MAZE_UNIT) / MAZE_UNIT) as i64)
}

/// OGBench's oracle (`get_oracle_subgoal`, what its data generator and scripted agents steer
/// by): the centre of the neighbouring cell one step closer to `goal`'s cell by breadth-first
/// search (neighbours in the order up, left, down, right; the first of equals wins), or the
/// centre of `xy`'s own cell when none is closer. None for an unknown maze.
pub fn oracle_subgoal(maze_name: &str, xy: [f64; 2], goal: [f64; 2]) -> Option<[f64; 2]> {
    let m = maze(maze_name)?;
    let (dist, _) = m.bfs(xy_to_ij(goal));
    let at = |(i, j): (i64, i64)| dist[i as usize][j as usize];
    let s = xy_to_ij(xy);
    let mut sub = s;
    for (di, dj) in NEIGHBOURS {
        let n = (s.0 + di, s.1 + dj);
        if m.free(n.0, n.1) && at(n) < at(sub) {
            sub = n;
        }
    }
    Some(ij_to_xy((sub.0 as usize, sub.1 as usize)))
}

/// OGBench's neighbour order in its searches: up, left, down, right.
const NEIGHBOURS: [(i64, i64); 4] = [(-1, 0), (0, -1), (1, 0), (0, 1)];

impl Maze {
    fn free(&self, i: i64, j: i64) -> bool {
        i >= 0 && j >= 0 && self.map.get(i as usize).and_then(|row| row.as_bytes().get(j as usize)) == Some(&b'0')
    }

    /// Breadth-first search over the free cells from `from`, as OGBench's oracle and stitch data
    /// search: each cell's distance in moves (−1 where unreached), and the cells other than `from`
    /// in the order the search reached them.
    fn bfs(&self, from: (i64, i64)) -> (Vec<Vec<i64>>, Vec<(i64, i64)>) {
        let mut dist = vec![vec![-1i64; self.map[0].len()]; self.map.len()];
        dist[from.0 as usize][from.1 as usize] = 0;
        let mut queue = std::collections::VecDeque::from([from]);
        let mut reached = Vec::new();
        while let Some((i, j)) = queue.pop_front() {
            for (di, dj) in NEIGHBOURS {
                let (ni, nj) = (i + di, j + dj);
                if self.free(ni, nj) && dist[ni as usize][nj as usize] == -1 {
                    dist[ni as usize][nj as usize] = dist[i as usize][j as usize] + 1;
                    queue.push_back((ni, nj));
                    reached.push((ni, nj));
                }
            }
        }
        (dist, reached)
    }
}

/// One PointMaze: the MuJoCo model and data, the current goal, and numpy's global generator.
pub struct PointMazeEnv {
    task: Task,
    maze: Maze,
    data: MjData<Box<MjModel>>,
    rng: RandomState,
    goal: [f64; 2],
    /// The evaluation task (1–5) of the current episode.
    task_id: usize,
}

impl PointMazeEnv {
    /// The PointMaze of an id or an OGBench dataset's name ([`resolve`]).
    pub fn new(id: &str) -> Result<PointMazeEnv> {
        let Some((name, maze)) = resolve(id).and_then(|n| Some((n, maze(n)?))) else {
            bail!("{id}: no such PointMaze (pgser simulates {})", TASKS.join(", "));
        };
        let xml = compose(&maze)?;
        let model = MjModel::from_xml_string(&xml).map_err(|e| anyhow!("{name}: the composed maze model: {e:?}"))?;
        let (nq, nv) = (model.ffi().nq, model.ffi().nv);
        if (nq, nv) != (2, 2) {
            bail!("{name}: the point model has nq = {nq}, nv = {nv}; OGBench's has 2 and 2");
        }
        let data = MjData::new(Box::new(model));
        // Evaluation steps an episode T times (as the Fetch tasks, T = 50 steps): 1000 here.
        let task = task(name).expect("a resolved id");
        Ok(PointMazeEnv { task, maze, data, rng: RandomState::new(0), goal: [0.0; 2], task_id: 1 })
    }

    /// Starts an episode of evaluation task `task_id` (1–5), or of a random one (numpy's
    /// `randint(1, 6)`) as `env.reset()` without options does, continuing the generator.
    pub fn reset_task(&mut self, task_id: Option<usize>) -> Obs {
        let id = match task_id {
            Some(k) => {
                assert!((1..=5).contains(&k), "task_id {k}: PointMaze has tasks 1 to 5");
                k
            }
            None => 1 + self.rng.randint(5) as usize,
        };
        let (start, goal) = self.maze.tasks[id - 1];
        self.task_id = id;
        self.reset_cells(start, goal)
    }

    /// `env.reset(options=dict(task_info=dict(init_ij=start, goal_ij=goal)))`: start and goal
    /// noise drawn around the two cells' centres, start first.
    pub fn reset_cells(&mut self, start: Cell, goal: Cell) -> Obs {
        let init = self.noisy(ij_to_xy(start));
        self.goal = self.noisy(ij_to_xy(goal));
        // The warm-up steps and the goal observation OGBench takes in between leave nothing
        // behind but the position: mj_resetData, then the start set (velocity is zeroed by the
        // next step before it can act).
        self.data.reset();
        self.data.qpos_mut().copy_from_slice(&init);
        self.data.qvel_mut().fill(0.0);
        self.data.forward();
        self.obs()
    }

    /// `set_goal(goal_ij)`: a new goal mid-episode, with noise, as the navigate data switch goals.
    pub fn set_goal_cell(&mut self, goal: Cell) {
        self.goal = self.noisy(ij_to_xy(goal));
    }

    /// The free cells in row-major order (OGBench's data generator's `all_cells`).
    pub fn free_cells(&self) -> Vec<Cell> {
        let m = self.maze.map;
        (0..m.len()).flat_map(|i| (0..m[0].len()).map(move |j| (i, j))).filter(|&(i, j)| self.free(i, j)).collect()
    }

    /// The free cells that are not straight corridor cells (free above and below with walls left
    /// and right, or the reverse): the generator's `vertex_cells`, its navigate goals.
    pub fn vertex_cells(&self) -> Vec<Cell> {
        let f = |i: usize, j: usize| self.free(i, j);
        self.free_cells()
            .into_iter()
            .filter(|&(i, j)| {
                let vertical = f(i - 1, j) && f(i + 1, j) && !f(i, j - 1) && !f(i, j + 1);
                let horizontal = f(i, j - 1) && f(i, j + 1) && !f(i - 1, j) && !f(i + 1, j);
                !vertical && !horizontal
            })
            .collect()
    }

    /// The cells exactly `steps` moves from `from`, in breadth-first order (neighbours up, left,
    /// down, right): the stitch data's candidate goals.
    pub fn cells_at_distance(&self, from: Cell, steps: usize) -> Vec<Cell> {
        let (dist, reached) = self.maze.bfs((from.0 as i64, from.1 as i64));
        reached
            .into_iter()
            .filter(|&(i, j)| dist[i as usize][j as usize] == steps as i64)
            .map(|(i, j)| (i as usize, j as usize))
            .collect()
    }

    fn free(&self, i: usize, j: usize) -> bool {
        self.maze.free(i as i64, j as i64)
    }

    /// numpy's global generator, which OGBench's data generator also draws its cells and action
    /// noise from.
    pub fn rng(&mut self) -> &mut RandomState {
        &mut self.rng
    }

    /// The point's velocity (what OGBench records as `qvel`).
    pub fn qvel(&self) -> [f64; 2] {
        let v = self.data.qvel();
        [v[0], v[1]]
    }

    /// `add_noise`: U(−1, 1) · unit / 4 on each coordinate, x first.
    fn noisy(&mut self, [x, y]: [f64; 2]) -> [f64; 2] {
        let dx = self.rng.uniform(-1.0, 1.0) * MAZE_UNIT / 4.0;
        let dy = self.rng.uniform(-1.0, 1.0) * MAZE_UNIT / 4.0;
        [x + dx, y + dy]
    }

    /// Re-seeds numpy's global generator, as `np.random.seed(seed)`.
    pub fn seed(&mut self, seed: u64) {
        self.rng = RandomState::new(seed as u32);
    }

    pub fn goal(&self) -> [f64; 2] {
        self.goal
    }

    /// The evaluation task (1–5) of the current episode.
    pub fn task_id(&self) -> usize {
        self.task_id
    }

    /// The point's position (x, y).
    pub fn xy(&self) -> [f64; 2] {
        let q = self.data.qpos();
        [q[0], q[1]]
    }

    fn obs(&self) -> Obs {
        let xy = self.xy().to_vec();
        Obs { observation: xy.clone(), achieved_goal: xy, desired_goal: self.goal.to_vec() }
    }
}

impl GoalEnv for PointMazeEnv {
    fn task(&self) -> &Task {
        &self.task
    }

    /// `np.random.seed(seed)` (with `Some`), then `env.reset()`: a random evaluation task.
    fn reset(&mut self, seed: Option<u64>) -> Obs {
        if let Some(s) = seed {
            self.seed(s);
        }
        self.reset_task(None)
    }

    /// An evaluation episode: task `seed % 5 + 1` with the noise of `np.random.seed(seed)`, so
    /// that consecutive seeds cycle through OGBench's five tasks (its protocol evaluates each task
    /// on the same number of episodes; give evaluations a multiple of 5).
    fn restart(&mut self, seed: u64) -> Obs {
        self.seed(seed);
        self.reset_task(Some((seed % 5) as usize + 1))
    }

    fn ends_at_success(&self) -> bool {
        true
    }

    fn eval_task(&self) -> Option<usize> {
        Some(self.task_id)
    }

    fn step(&mut self, action: &[f64]) -> Step {
        assert_eq!(action.len(), 2, "PointMaze takes 2 action values");
        // `0.2 * action` on the float32 action is float32 (numpy's weak Python scalar), then
        // added to the float64 position.
        let a = |k: usize| f64::from(0.2f32 * super::applied_action(action[k]));
        self.advance([a(0), a(1)])
    }
}

impl PointMazeEnv {
    /// A step with a float64 action, as OGBench's data generator takes them (`0.2 * action` in
    /// float64; the action is not clipped here, the generator clips it).
    pub fn step_f64(&mut self, action: [f64; 2]) -> Step {
        self.advance(action.map(|a| 0.2 * a))
    }

    /// Moves the point by `delta`, resolves walls, then checks success and the teleport pads.
    fn advance(&mut self, delta: [f64; 2]) -> Step {
        for (q, d) in self.data.qpos_mut().iter_mut().zip(delta) {
            *q += d;
        }
        self.data.qvel_mut().fill(0.0);
        for _ in 0..FRAME_SKIP {
            self.data.step();
        }
        // The observation and success are those before a teleport moves the point: OGBench
        // returns the step's observation and checks the pads after it, so a teleport shows in the
        // next step's observation.
        let obs = self.obs();
        let step = Step::of(&self.task, obs);
        if let Some((ins, outs)) = self.maze.teleport {
            let [x, y] = self.xy();
            for &c in ins {
                let [tx, ty] = ij_to_xy(c);
                if ((x - tx) * (x - tx) + (y - ty) * (y - ty)).sqrt() <= 1.5 {
                    let out = ij_to_xy(outs[self.rng.randint(outs.len() as u32) as usize]);
                    self.data.qpos_mut().copy_from_slice(&out);
                    self.data.forward();
                    break;
                }
            }
        }
        step
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_maze_composes_as_ogbench_composes_it() {
        let xml = compose(&maze("pointmaze-medium-v0").unwrap()).unwrap();
        assert!(xml.contains("<geom name=\"floor\" pos=\"10 10 0\" size=\"16 16 0.2\""));
        assert!(xml.contains("<geom name=\"block_0_0\" pos=\"-4.0 -4.0 1.0\" size=\"2.0 2.0 1.0\""));
        assert_eq!(xml.matches("name=\"block_").count(), 38);
        let env = PointMazeEnv::new("pointmaze-medium-v0").unwrap();
        assert_eq!(env.data.model().ffi().ngeom, 41, "floor, 38 walls, target, the point");
        let tele = compose(&maze("pointmaze-teleport-v0").unwrap()).unwrap();
        assert_eq!(resolve("pointmaze-large-stitch-v0"), Some("pointmaze-large-v0"));
        assert_eq!(resolve("pointmaze-giant-navigate-v0"), Some("pointmaze-giant-v0"));
        assert_eq!((resolve("pointmaze-huge-v0"), resolve("antmaze-medium-v0")), (None, None));
        assert!(tele.contains("<geom name=\"teleport_out_2\" type=\"cylinder\" size=\"1 .05\" pos=\"36.0 20.0 .05\""));
    }

    /// In free space a step moves the point by exactly 0.2 · the float32 action (OGBench's notes:
    /// seed 0, task 1, one step of [0.3, −0.7] ends at x = 0.1576270102388353).
    #[test]
    fn a_free_step_moves_by_a_fifth_of_the_action() {
        let mut env = PointMazeEnv::new("pointmaze-medium-v0").unwrap();
        env.seed(0);
        let o = env.reset_task(Some(1));
        assert_eq!(o.observation, [0.0976270078546495, 0.43037873274483895]);
        assert_eq!(env.goal(), [20.20552675214329, 20.089766365993793]);
        let s = env.step(&[0.3, -0.7]);
        assert_eq!(s.obs.observation, [0.1576270102388353, 0.2903787321487925]);
        assert!(!s.success && s.reward == -1.0);
    }
}
