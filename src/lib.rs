//! pgser: Prioritized Offline Goal-Swapping Experience Replay as batch jobs over Parquet.
//!
//! Data flows one way: files → record batches → tensors. Each pipeline stage is one module:
//! [`pickle`] reads WGCSL buffers without executing them (and writes them), [`minari`] reads
//! and writes Minari datasets, [`convert`] picks one of those readers for an input, [`trajectory`]
//! writes and reads the trajectory table, [`collect`] simulates episodes in [`env`](mod@env) and writes
//! them as either, [`inspect`] summarises any pgser table, [`query`] runs SQL over tables.
//! [`table`] and [`output`] hold what every writer shares (parallel row-group encoding, the
//! footer, atomic files); [`nprandom`] is numpy's generator, which every stage draws from;
//! [`dtype`] is numpy's element types, which every format reader and writer converts to.
//!
//! Imports run down these layers, never up or across (`tests/layers.rs` checks it):
//!
//! | layer | modules |
//! |---:|---|
//! | 9 | [`pipeline`] |
//! | 8 | [`report`] |
//! | 7 | [`train`] |
//! | 6 | [`sampler`], [`inspect`] |
//! | 5 | [`collect`], [`score`], [`convert`] |
//! | 4 | [`eval`], [`swap`], [`minari`], [`ogbench`], [`query`], [`verify`] |
//! | 3 | [`agent`], [`trajectory`] |
//! | 2 | [`env`](mod@env), [`table`] |
//! | 1 | [`pickle`], [`nprandom`], [`output`], [`task`], [`cli`], [`progress`] |
//! | 0 | [`dtype`], [`install`] |

pub mod agent;
pub mod cli;
pub mod collect;
pub mod convert;
pub mod dtype;
pub mod env;
pub mod eval;
pub mod inspect;
pub mod install;
pub mod minari;
pub mod nprandom;
pub mod ogbench;
pub mod output;
pub mod pickle;
pub mod pipeline;
pub mod progress;
pub mod query;
pub mod report;
pub mod sampler;
pub mod score;
pub mod swap;
pub mod table;
pub mod task;
pub mod train;
pub mod trajectory;
pub mod verify;
