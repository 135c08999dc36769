//! `dataset`: drape datasets, from sampling to shards.
//!
//! - [`sampling`]: seeded sampling of body shapes (adult ranges by default) and of poses from
//!   the pose prior; every sampled pose carries its family label.
//! - [`prior_check`]: the share of sampled poses whose body intersects itself.
//! - [`config`]: dataset configs (`configs/datasets/*.toml`).
//! - [`plan`]: which body and pose each sample gets and which shard it lands in, a pure
//!   function of (seed, sample id).
//! - [`shard`]: **the shard format** (safetensors; tensors and metadata documented there).
//! - [`generate`]: `drape gen`: parallel, resumable generation, one part of a cluster job.
//! - [`manifest`]: the JSON manifest: config, versions, per-sample reports, shard checksums.
//! - [`reader`]: iterate the samples of a split one shard at a time.
//! - [`inspect`]: `drape data info`, `verify`, `merge`.
//! - [`wardrobe`]: the garment a dataset drapes: its base template and, with `sizes`, the
//!   size each body wears.
#![warn(missing_docs)]

use std::path::PathBuf;

pub mod config;
pub mod generate;
pub mod inspect;
pub mod manifest;
pub mod plan;
pub mod prior_check;
pub mod reader;
pub mod sampling;
pub mod shard;
pub mod wardrobe;

/// Errors of dataset configs, generation and reading.
#[derive(Debug, thiserror::Error)]
pub enum DatasetError {
    /// A config file that cannot be used.
    #[error("dataset config {path}: {reason}")]
    Config {
        /// The file.
        path: PathBuf,
        /// Why.
        reason: String,
    },
    /// A file that cannot be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        #[source]
        source: std::io::Error,
    },
    /// A file that is not what it should be: truncated, altered, of another format.
    #[error("{path} is corrupt: {reason}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// Anything else that makes the request impossible.
    #[error("{0}")]
    Invalid(String),
    /// The body model.
    #[error(transparent)]
    Body(#[from] sim::body::BodyError),
    /// The garment.
    #[error(transparent)]
    Garment(#[from] sim::garment::GarmentError),
    /// The simulator.
    #[error(transparent)]
    Sim(#[from] sim::cloth::SimError),
}
