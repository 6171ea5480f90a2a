//! Goal swapping (PGSER Alg. 1): give a transition a goal taken from elsewhere in the dataset
//! and recompute its reward for that goal, r = R(φ(s'), g_rand).
//!
//! The goal pool is every achieved goal of every episode: those are states the data shows to be
//! reachable from somewhere, which is what makes a swapped goal plausible as a target.

use crate::env::rng::NpRandom;
use crate::trajectory::Episodes;

/// A random goal's source: (episode, step) of an achieved goal, uniform over the whole table.
pub fn random_goal(data: &Episodes, rng: &mut NpRandom) -> (usize, usize) {
    let k = rng.below(data.n * data.t);
    (k / data.t, k % data.t)
}
