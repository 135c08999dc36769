//! `eval`: looking at and measuring what drape makes.
//!
//! - [`render`]: a small software renderer (shaded front and side views, several meshes in
//!   different colours, PNG output) used across the project to look at bodies, garments
//!   and drapes.
//! - [`metrics`]: Edist, Enorm, average-precision curves, physics energies and the
//!   interpenetration ratio.
//! - [`evaluate`]: a trained network and the DQS, mean-residual, nearest-neighbour and linear
//!   baselines measured on a dataset split (`drape eval`); [`report`] writes the report
//!   folder; [`exr`] the float error images; [`linear`] the linear (ridge) baseline.
//! - [`compare`]: two evaluations of the same drapes paired by sample (`drape compare`).
//! - [`importance`]: how much a trained network relies on each body input, by taking
//!   that input from another drape (`drape importance`).
//! - [`speed`]: the speed-up of a network over the simulator (`drape bench speedup`).
//! - [`sensitivity`]: how far drapes move under a micrometre disturbance of the
//!   simulation (`drape data sensitivity`), the part of a target no input determines.
//! - [`curve`]: how the linear map and a kernel map beside it improve with more training
//!   drapes (`drape data curve`): what more data would buy.
//! - [`repro`]: the reproduction plan, its stage ledger and `docs/reproduction.md`.
//! - [`plot`]: line charts (the average-precision curves) and colour bars as images.
#![warn(missing_docs)]

pub mod compare;
pub mod curve;
pub mod evaluate;
pub mod exr;
pub mod importance;
pub use learn::linear;
pub mod metrics;
pub mod plot;
pub mod render;
pub mod report;
pub mod repro;
pub mod sensitivity;
pub mod speed;
