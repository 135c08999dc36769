//! `sim`: geometry and physics of drape.
//!
//! - [`mesh`]: triangle meshes, normals, OBJ output.
//! - [`body`]: the CC0 MakeHuman body model: asset import and loading, shape, skeleton,
//!   poses (key poses, CMU BVH), skinning (LBS for the body, DQS for other meshes) and a
//!   self-intersection check.
//! - [`io`]: all-or-nothing file output shared by every command.
//!
//! The cloth solver joins this crate in a later stage.
#![warn(missing_docs)]

pub mod body;
pub mod cloth;
pub mod garment;
pub mod io;
pub mod mesh;
