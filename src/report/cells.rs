//! The data of Table 2, below everything that compares or renders it: the paper's six tasks and
//! six rows, and a cell pgser measured. [`super::paper`] holds the paper's own cells in the same
//! terms, [`super::measured`] reads results.csv files into cells, [`super::agree`] compares the
//! two, [`super::chosen`] assembles a chosen setting's rows and [`super::table2`] renders them all,
//! so imports run one way: cells, then the paper's values and the reading, then the comparison,
//! then the chosen rows, then the table.

/// One side of Welch's test: (mean, sample std, n).
pub(super) type Side = (f64, f64, usize);

/// The paper's columns: pgser's task name, and the paper's short header.
pub const TASKS: [(&str, &str); 6] = [
    ("FetchReach", "FetchReach"),
    ("FetchPush", "FetchPush"),
    ("FetchPickAndPlace", "FetchPick"),
    ("FetchSlide", "FetchSlide"),
    ("HandManipulateBlockRotateZ", "HandBlock-Z"),
    ("HandManipulateEggRotate", "HandEgg-Rotate"),
];

/// The paper's rows in its order: (algo, variant, the paper's name).
pub const AGENTS: [(&str, &str, &str); 6] = [
    ("td3bc", "mem", "TD3BC-mem"),
    ("td3bc", "swap", "TD3BC-swap"),
    ("td3bc", "baseline", "TD3BC"),
    ("td3", "mem", "TD3-mem"),
    ("td3", "swap", "TD3-swap"),
    ("td3", "baseline", "TD3"),
];

/// A measured cell as read, before the table is assembled.
pub(super) struct Measured {
    pub task: &'static str,
    pub agent: usize,
    pub seeds: usize,
    pub mean: f64,
    pub std: f64,
    /// (episodes, mean, sample std) of all episodes pooled.
    pub pooled: Option<(usize, f64, f64)>,
    pub source: String,
}

impl Measured {
    pub(super) fn seeds_side(&self) -> Side {
        (self.mean, self.std, self.seeds)
    }
    pub(super) fn episodes_side(&self) -> Option<Side> {
        self.pooled.map(|(n, m, s)| (m, s, n))
    }
}

/// Where a results.csv row goes in Table 2: a row of the paper's table ([`AGENTS`]' index), a row
/// to leave out (another arm of a chosen-setting pipeline), or one the table cannot have.
pub(super) enum RowOf {
    Agent(usize),
    Skip,
    Unknown,
}

/// A measured cell as the tables print it: `mean ± std` (the mean alone with one seed) and its marks.
pub(super) fn fmt_cell(mean: f64, std: f64, marks: &str) -> String {
    let cell = if std.is_finite() { format!("{mean:.2} ± {std:.2}") } else { format!("{mean:.2}") };
    if marks.is_empty() { cell } else { format!("{cell} {marks}") }
}
