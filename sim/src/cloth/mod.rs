//! The cloth simulator: NvCloth-style position-based dynamics with XPBD compliance, small
//! steps, and collision against a moving body through a BVH.
//!
//! - [`config`]: every parameter, with units and defaults (`configs/sim/default.toml`).
//! - [`model`]: a garment mesh cooked into particles and coloured constraints.
//! - [`constraints`]: distance (stretch, shear, bend) and dihedral constraints.
//! - [`collision`]: the body in a BVH, closest points, pseudo-normals, contacts.
//! - [`solver`]: the time step, stage by stage.
//! - [`drape`]: the drape protocols and the quality report.
//! - [`polish`]: the strain polish of a drape at rest.
//! - [`thin`]: the body's thin parts (fingers, toes), for the cloth's edge contacts.

pub mod collision;
pub mod coloring;
pub mod config;
pub mod constraints;
pub mod drape;
pub mod model;
pub mod polish;
pub mod scene;
pub mod self_collision;
pub mod solver;
pub mod thin;

use std::path::PathBuf;

pub use collision::BodyCollider;
pub use config::SimConfig;
pub use drape::{DrapeReport, DrapeResult, Failure};
pub use model::ClothModel;
pub use solver::Solver;

/// Errors of the simulator's inputs.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// A file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },
    /// A configuration file or value is invalid.
    #[error("simulator config {path}: {reason}")]
    Config {
        /// Where the configuration came from.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
    /// The garment mesh cannot be simulated.
    #[error("garment mesh: {0}")]
    BadMesh(String),
    /// The garment and the body do not fit together.
    #[error("garment and body: {0}")]
    Placement(String),
}
