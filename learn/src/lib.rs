//! `learn`: the GarNet family of networks (GarNet++ paper) in burn: models, losses,
//! training with checkpoints, inference.
//!
//! - [`model`]: **the GarNet forward pass** ([`model::GarNet::forward`]) and its blocks.
//! - [`loss`]: L_vert, L_pen, L_norm, L_bend, the curvature losses.
//! - [`linear`]: the linear (ridge) map from shape and pose to the displacement: a baseline
//!   of `drape eval` and the optional prior under a network (`model.prior`).
//! - [`kernel`]: that map plus an RBF kernel ridge regression of what it leaves: a baseline,
//!   the learning curve's map, and a prior.
//! - [`prior`]: the prior under a network, cross-fitted by body for the training samples.
//! - [`data`]: dataset rows to network inputs.
//! - [`nearest`]: the k-NN searches of those inputs (a k-d tree, a SIMD scan).
//! - [`topology`]: the garment's mesh graph.
//! - [`config`]: model and training configs (`configs/train/*.toml`).
#![warn(missing_docs)]

pub mod bench;
pub mod config;
pub mod data;
pub mod kernel;
pub mod linear;
pub mod loss;
pub mod model;
pub mod nearest;
pub mod predict;
pub mod prior;
pub mod run;
pub mod topology;
pub mod train;

use std::path::PathBuf;

/// Errors of training and inference.
#[derive(Debug, thiserror::Error)]
pub enum LearnError {
    /// A file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// A config with unknown fields or values out of range.
    #[error("bad config: {0}")]
    Config(String),
    /// A run folder that does not fit what it is used with.
    #[error("{0}")]
    Mismatch(String),
    /// The dataset could not be read.
    #[error(transparent)]
    Dataset(#[from] dataset::DatasetError),
    /// A checkpoint could not be saved or loaded.
    #[error("{path}: {reason}")]
    Checkpoint {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
}
