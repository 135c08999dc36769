//! `eval`: looking at and measuring what drape makes.
//!
//! - [`render`]: a small software renderer (shaded front and side views, several meshes in
//!   different colours, PNG output) used across the project to look at bodies, garments
//!   and drapes.
//!
//! Metrics (Edist, Enorm), the paper's tables and timing reports join this crate later.
#![warn(missing_docs)]

pub mod render;
