//! The settings of OGBench's and Horizon Reduction's dataset classes, as an agent's config
//! names them: which code's classes, which class, the goal fractions, the hierarchical classes'
//! subgoal keys, OGBench's pixel keys, and pgser's own (`oracle_reps`, `clip_actions`,
//! `p_swapgoal`); what each class refuses, what a key another class reads is refused as, and
//! what a table must hold for the settings.

use anyhow::{Result, bail};
use serde::{Deserialize, Serialize};

use crate::sampler::view::View;

/// Whose dataset classes a stream follows: the user says which (`layout=`), never guessed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Code {
    /// OGBench's `impls/utils/datasets.py`.
    #[default]
    Ogbench,
    /// Horizon Reduction's `utils/datasets.py`.
    HorizonReduction,
}

impl Code {
    pub fn layout(self) -> &'static str {
        match self {
            Code::Ogbench => "ogbench",
            Code::HorizonReduction => "horizon_reduction",
        }
    }
}

/// `config["dataset_class"]`, as the agents' `main.py` picks it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum DatasetClass {
    #[default]
    GCDataset,
    HGCDataset,
}

/// OGBench's dataset settings, under the names and defaults of its agents' configs (GCIQL's,
/// GCIVL's and HIQL's defaults; CRL's, QRL's and GCBC's differ only in these values), and the
/// hierarchical classes' keys.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct OgbenchConfig {
    /// Whose classes: OGBench's or Horizon Reduction's.
    pub code: Code,
    pub dataset_class: DatasetClass,
    /// The geometric offsets' parameter is 1 − discount.
    pub discount: f64,
    pub value_p_curgoal: f64,
    pub value_p_trajgoal: f64,
    pub value_p_randomgoal: f64,
    /// Geometric (true) or uniform (false) trajectory value goals.
    pub value_geom_sample: bool,
    pub actor_p_curgoal: f64,
    pub actor_p_trajgoal: f64,
    pub actor_p_randomgoal: f64,
    pub actor_geom_sample: bool,
    /// Rewards 0 at the goal and −1 elsewhere (true), or 1 and 0 (false).
    pub gc_negative: bool,
    /// HGCDataset: steps to a subgoal (both classes); Horizon Reduction's takes the value and
    /// actor steps apart where they are given.
    pub subgoal_steps: Option<u64>,
    pub value_subgoal_steps: Option<u64>,
    pub actor_subgoal_steps: Option<u64>,
    /// Horizon Reduction's HGCDataset: the config has a `low_discount` key (even one set to
    /// None), so batches carry low-level value goals.
    pub low_value_goals: bool,
    /// Their geometric offsets' discount; None: `discount` (their `sample_goals` default).
    pub low_discount: Option<f64>,
    /// Goals, high-level actions and `high_value_reps` are the table's achieved goals, OGBench's
    /// oracle representations (Horizon Reduction's classes, on an `-oraclerep` dataset).
    pub oracle_reps: bool,
    /// Actions clipped to ±(1 − clip_actions), as Horizon Reduction's `make_env_and_datasets`
    /// does with 1e-5; None: as stored.
    pub clip_actions: Option<f64>,
    /// PGSER's prioritized swapped rows, a fraction of each batch (needs a scored table).
    pub p_swapgoal: f64,
    /// A swapped row's actor goal is its swapped goal (true) or drawn by the actor's fractions.
    pub swap_actor_goals: bool,
    /// OGBench's image augmentation: the probability that a batch's images are randomly cropped
    /// (`images.rs`); 0 (or None in a config): never.
    pub p_aug: f64,
    /// OGBench's frame stacking: each observation key holds this many frames, oldest first, on
    /// the channel axis (`images.rs`); None: one.
    pub frame_stack: Option<u64>,
}

impl Default for OgbenchConfig {
    fn default() -> Self {
        OgbenchConfig {
            code: Code::Ogbench,
            dataset_class: DatasetClass::GCDataset,
            discount: 0.99,
            value_p_curgoal: 0.2,
            value_p_trajgoal: 0.5,
            value_p_randomgoal: 0.3,
            value_geom_sample: true,
            actor_p_curgoal: 0.0,
            actor_p_trajgoal: 1.0,
            actor_p_randomgoal: 0.0,
            actor_geom_sample: false,
            gc_negative: true,
            subgoal_steps: None,
            value_subgoal_steps: None,
            actor_subgoal_steps: None,
            low_value_goals: false,
            low_discount: None,
            oracle_reps: false,
            clip_actions: None,
            p_swapgoal: 0.0,
            swap_actor_goals: true,
            p_aug: 0.0,
            frame_stack: None,
        }
    }
}

impl OgbenchConfig {
    /// Refuses what OGBench refuses (fractions that do not sum to 1, by `np.isclose`), what its
    /// numpy calls would (a discount outside [0, 1) gives `geometric` a p outside (0, 1]), and a
    /// key the chosen class does not read (a config meant for another class, or another code's,
    /// would otherwise train on batches it did not ask for).
    pub fn validate(&self) -> Result<()> {
        let layout = self.code.layout();
        if !(0.0..1.0).contains(&self.discount) {
            bail!("discount = {}: must be in [0, 1) (geometric goal offsets take p = 1 − discount)", self.discount);
        }
        if !(0.0..=1.0).contains(&self.p_swapgoal) {
            bail!("p_swapgoal = {}: must be in [0, 1]", self.p_swapgoal);
        }
        if !(0.0..=1.0).contains(&self.p_aug) {
            bail!("p_aug = {}: must be in [0, 1] (the probability that a batch's images are cropped)", self.p_aug);
        }
        if self.frame_stack == Some(0) {
            bail!("frame_stack = 0: a stack holds at least one frame (None: no stacking)");
        }
        if self.code == Code::HorizonReduction {
            let pixels = [
                (self.p_aug > 0.0).then(|| format!("p_aug = {}", self.p_aug)),
                self.frame_stack.map(|k| format!("frame_stack = {k}")),
            ];
            if let Some(k) = pixels.into_iter().flatten().next() {
                bail!(
                    "{k}: a key of OGBench's dataset classes, which Horizon Reduction's do not read (they neither crop \
                     nor stack frames): use layout=\"ogbench\", or leave it out"
                );
            }
        }
        for (who, [cur, traj, random]) in [
            ("value", [self.value_p_curgoal, self.value_p_trajgoal, self.value_p_randomgoal]),
            ("actor", [self.actor_p_curgoal, self.actor_p_trajgoal, self.actor_p_randomgoal]),
        ] {
            for (name, p) in [("p_curgoal", cur), ("p_trajgoal", traj), ("p_randomgoal", random)] {
                if !(0.0..=1.0).contains(&p) {
                    bail!("{who}_{name} = {p}: must be in [0, 1]");
                }
            }
            let sum = cur + traj + random;
            // np.isclose(sum, 1.0): |sum − 1| ≤ 1e-8 + 1e-5.
            if (sum - 1.0).abs() > 1e-8 + 1e-5 {
                bail!("{who}_p_curgoal + {who}_p_trajgoal + {who}_p_randomgoal = {sum}: must be 1");
            }
        }
        if let Some(eps) = self.clip_actions
            && !(0.0..1.0).contains(&eps)
        {
            bail!("clip_actions = {eps}: must be in [0, 1) (actions are clipped to ±(1 − clip_actions))");
        }
        if self.oracle_reps && self.code == Code::Ogbench {
            bail!(
                "oracle_reps = True: OGBench's GCDataset and HGCDataset take observations as goals whatever the dataset \
                 holds; Horizon Reduction's read oracle representations: use layout=\"horizon_reduction\""
            );
        }
        let subgoal_keys = [
            ("subgoal_steps", self.subgoal_steps),
            ("value_subgoal_steps", self.value_subgoal_steps),
            ("actor_subgoal_steps", self.actor_subgoal_steps),
        ];
        let low = self
            .low_value_goals
            .then(|| format!("low_discount = {}", self.low_discount.map_or("None".to_string(), |d| d.to_string())));
        let set = subgoal_keys.iter().filter_map(|(k, v)| v.map(|v| format!("{k} = {v}"))).chain(low.clone());
        if self.dataset_class == DatasetClass::GCDataset {
            if let Some(k) = set.into_iter().next() {
                bail!("{k}: a key of HGCDataset, and dataset_class is GCDataset (layout=\"{layout}\")");
            }
            return Ok(());
        }
        if self.code == Code::Ogbench {
            let hr =
                [("value_subgoal_steps", self.value_subgoal_steps), ("actor_subgoal_steps", self.actor_subgoal_steps)];
            if let Some(k) = hr.iter().filter_map(|(k, v)| v.map(|v| format!("{k} = {v}"))).chain(low).next() {
                bail!(
                    "{k}: a key of Horizon Reduction's HGCDataset, which OGBench's does not read (it takes \
                     subgoal_steps alone): use layout=\"horizon_reduction\", or leave it out"
                );
            }
        }
        let (value, actor) = self.subgoal_steps_of()?;
        for (k, v) in [("value subgoal steps", value), ("actor subgoal steps", actor)] {
            if v == 0 {
                bail!("{k} = 0: a subgoal is at least one step ahead");
            }
        }
        if let Some(d) = self.low_discount
            && !(d > 0.0 && d < 1.0)
        {
            bail!("low_discount = {d}: must be in (0, 1)");
        }
        Ok(())
    }

    /// HGCDataset's value and actor subgoal steps: `value_subgoal_steps` / `actor_subgoal_steps`
    /// where Horizon Reduction's class reads them and they are set, `subgoal_steps` otherwise.
    pub fn subgoal_steps_of(&self) -> Result<(u64, u64)> {
        let need = |own: Option<u64>, which: &str| -> Result<u64> {
            own.or(self.subgoal_steps).ok_or_else(|| match self.code {
                Code::Ogbench => anyhow::anyhow!("HGCDataset needs subgoal_steps; the config has none"),
                Code::HorizonReduction => {
                    anyhow::anyhow!("HGCDataset needs subgoal_steps (or {which}_subgoal_steps); the config has neither")
                }
            })
        };
        Ok((need(self.value_subgoal_steps, "value")?, need(self.actor_subgoal_steps, "actor")?))
    }
}

/// A goal source's fractions: (p_curgoal, p_trajgoal, geom_sample, discount).
pub(super) type Fractions = (f64, f64, bool, f64);

impl OgbenchConfig {
    pub(super) fn value(&self) -> Fractions {
        (self.value_p_curgoal, self.value_p_trajgoal, self.value_geom_sample, self.discount)
    }
    pub(super) fn actor(&self) -> Fractions {
        (self.actor_p_curgoal, self.actor_p_trajgoal, self.actor_geom_sample, self.discount)
    }
}

impl OgbenchConfig {
    /// What a table must hold for these settings: a transition per episode, subgoals and frame
    /// stacks that fit an episode, achieved goals that are oracle representations where
    /// `oracle_reps` reads them, and images where `p_aug` or `frame_stack` asks for them.
    pub(super) fn check_table(&self, view: &dyn View) -> Result<()> {
        let cfg = self;
        cfg.validate()?;
        let t = view.t();
        if t < 2 {
            bail!("episodes of {t} step(s) hold no transition");
        }
        if cfg.dataset_class == DatasetClass::HGCDataset {
            let (value, actor) = cfg.subgoal_steps_of()?;
            for (k, v) in [("value subgoal steps", value), ("actor subgoal steps", actor)] {
                if v >= t as u64 {
                    bail!("{k} = {v}: longer than this table's episodes ({} transitions each)", t - 1);
                }
            }
        }
        if cfg.oracle_reps {
            oracle_reps_of(view.task())?;
        }
        let images = view.image_shape();
        if images.is_empty() {
            let pixels = [
                (cfg.p_aug > 0.0).then(|| format!("p_aug = {}: random crops are of images", cfg.p_aug)),
                cfg.frame_stack.map(|k| format!("frame_stack = {k}: frames stacked are images")),
            ];
            if let Some(k) = pixels.into_iter().flatten().next() {
                bail!(
                    "{k}, and this table's observations are states ({} floats; a visual dataset's are images)",
                    view.task().obs_dim
                );
            }
        } else if images.len() != 3 {
            bail!("images of shape {}: OGBench's are [H, W, C]", crate::trajectory::shape_text(images));
        }
        if let Some(k) = cfg.frame_stack
            && k > t as u64
        {
            bail!("frame_stack = {k}: longer than this table's episodes ({t} observations each)");
        }
        Ok(())
    }
}

/// The families whose table goals are OGBench's oracle representations (`add_oracle_reps`):
/// a maze's x, y (`qpos[:2]`, which its observations start with), and each cube's position
/// centred on (0.425, 0, 0) and scaled by 10 (the goal map's cube values, OGBench's
/// `compute_oracle_observation`, which tests/ogbench.rs checks row for row), and a puzzle's
/// button states (its `button_states`, as floats), and a scene's cube, buttons, drawer and window
/// (`compute_oracle_observation`'s values, from the observation). A table converted with
/// `--full-goal` has whole observations as goals.
fn oracle_reps_of(task: &crate::task::Task) -> Result<()> {
    // A visual dataset's family is its state twin's (its goal is read from the file's state).
    let family = task.name.strip_prefix("visual-").unwrap_or(&task.name).split('-').next().unwrap_or_default();
    let full = task.goal_dim == task.obs_dim && task.obs_dim > 2;
    // Every family OGBench's goal map maps has its oracle representation as its goal.
    if !crate::ogbench::goal::FAMILIES.contains(&family) || full {
        bail!(
            "oracle_reps = True: {}'s table goals are not OGBench's oracle representations ({}); pgser has them for \
             tables of {} datasets converted without --full-goal",
            task.name,
            if full { "they are whole observations (--full-goal)" } else { "no oracle representation is mapped" },
            crate::ogbench::goal::FAMILIES.join(", ")
        );
    }
    Ok(())
}
