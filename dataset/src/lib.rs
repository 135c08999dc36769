//! `dataset`: what goes into a drape dataset.
//!
//! - [`sampling`]: seeded sampling of body shapes (adult ranges by default) and of poses from
//!   the pose prior (key poses of the walking, dance and yoga families, blended and
//!   perturbed within joint limits); every sampled pose carries its family label.
//! - [`prior_check`]: the share of sampled poses whose body intersects itself.
//!
//! Parallel drape generation, shards and the manifest join this crate later.
#![warn(missing_docs)]

pub mod prior_check;
pub mod sampling;
