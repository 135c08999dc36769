//! Simulator parameters: one struct, every field with its unit and default, read from
//! `configs/sim/default.toml` (the built-in defaults) or a user file.

use std::path::Path;

use glam::Vec3;
use serde::{Deserialize, Serialize};

use super::SimError;

fn is_one(n: &u32) -> bool {
    *n == 1
}

fn is_zero(n: &u32) -> bool {
    *n == 0
}

fn is_zero_f32(x: &f32) -> bool {
    *x == 0.0
}

/// The built-in configuration file.
pub const DEFAULT_TOML: &str = include_str!("../../../configs/sim/default.toml");

/// Parameters of the cloth simulator and of the drape protocol.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SimConfig {
    /// Simulation frames per second (1/s, default 60).
    pub fps: f32,
    /// Substeps per frame, one constraint sweep each (default 10).
    pub substeps: u32,
    /// Substeps per frame in which the shear and bending constraints are solved, a divisor
    /// of `substeps` (default: unset, every substep). Stretch, collision and integration
    /// run at `substeps`; the shear and bending constraints, prepared for the longer step,
    /// every `substeps / shear_bend_substeps`-th substep. More substeps cut the stretch that
    /// one Gauss-Seidel sweep per substep leaves under gravity (about `g h^2 N^2` over `N`
    /// edges) while shear and bending, about half the constraints, cost what they cost at
    /// this rate. Left out of the serialised config when unset, so configs from before the
    /// field keep their hashes.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shear_bend_substeps: Option<u32>,
    /// Stretch sweeps per substep (default 5): the ones after the first solve the stretch
    /// constraints alone again, each the same projection, so the stretch ends stiffer than
    /// its compliance says (the intent: a stiff membrane whose sag one sweep per substep
    /// cannot remove). Unlike more substeps, every substep stays the same, so a resting
    /// cloth keeps a fixed point. Left out of the serialised config at 1, so a config
    /// pinned to 1 keeps the hash it had before the field; a manifest without it (all
    /// written before the field) reads as 1 (`Manifest::dataset_config`).
    #[serde(skip_serializing_if = "is_one")]
    pub stretch_iterations: u32,
    /// Substeps per frame once the body holds still: the settling after the morph, and the
    /// whole of a warm start (default 20). The morph's motion needs `substeps`; the state a
    /// drape comes to rest in is the solver's fixed point, whose sag (the stretch that the
    /// sweeps leave under gravity, about `g h^2` per substep to carry) falls with the
    /// square of the substep: p95 strain of the 10k T-shirt in the rest pose 3.7% at 10,
    /// 1.0% at 20, 0.3% at 40 (docs/sim.md, session 16). A manifest without the field
    /// (written before it) reads as its `substeps` (`Manifest::dataset_config`). Not tied
    /// to `substeps`: a config raising `substeps` above it settles coarser than it morphs.
    pub settle_substeps: u32,
    /// The push-out out of the body also gives the particle the push over `h` as outward
    /// speed, as before session 16 (default false: inelastic, the particle leaves with the
    /// body's normal speed). The garment builder's relaxation keeps it: at its 30 substeps
    /// and 6/s damping the inelastic push left the 10k jeans moving 0.5 to 0.6 mm a frame
    /// for 1,500 frames. Left out of the serialised config when false.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub elastic_pushout: bool,
    /// Sweeps of the strain polish once a drape is at rest (default 100; 0: none): the
    /// stretch the solver's sweeps leave in the hanging cloth projected out, the particles
    /// near the body held (`polish.rs`, docs/sim.md). Left out of the serialised config at 0,
    /// so a config pinned to 0 keeps the hash it had before the field; a manifest without
    /// it (all written before the field) reads as 0 (`Manifest::dataset_config`).
    #[serde(skip_serializing_if = "is_zero")]
    pub polish_sweeps: u32,
    /// Edge contacts against the body's parts thinner than this (m, default 0.03; 0:
    /// none; else above `thickness`, at most 0.2): fingers, thumbs, toes, ears. Each mesh
    /// edge's midpoint is kept `thickness` away from them, so a coarse cloth's edge does not
    /// pass through a finger with both ends outside while it is shorter than about twice
    /// the finger's width (`thin.rs`, docs/sim.md). Left out of the serialised config at 0, so a
    /// config pinned to 0 keeps the hash it had before the field; a manifest without it
    /// reads as 0.
    #[serde(skip_serializing_if = "is_zero_f32")]
    pub thin_part_thickness: f32,
    /// A particle in a fold of the body (a raised thigh against the belly) also keeps the
    /// fold's other side as a contact, so a push out of one surface cannot land it inside
    /// the other (`BodyCollider::crease`, docs/sim.md "Creases"). Without it such particles
    /// can be pushed back and forth between the two surfaces (the 3k jeans on check sample
    /// 15 never came to rest). Unset (the default): each garment's own choice, its
    /// definition's `[simulation] crease_contacts` (the jeans: on; the others: off; a plain
    /// mesh: off; [`ClothModel::drape_config`](super::ClothModel::drape_config) resolves it).
    /// `true` or `false` sets it for every garment. Not on for every garment: on 50 sampled
    /// drapes it took the 3k jeans from 48 to 49 converged but the 3k sweater from 50 to 48
    /// (cuffs caught on the hands in two drapes it changed). Left out of the serialised
    /// config when unset, so configs keep the hashes they had before the field.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub crease_contacts: Option<bool>,
    /// Gravity (m/s^2, default (0, -9.81, 0)).
    pub gravity: [f32; 3],
    /// Velocity damping (1/s, default 2): velocities decay as exp(-damping t).
    pub damping: f32,
    /// Speed limit of a particle (m/s, default 5).
    pub max_velocity: f32,
    /// Mass per area of the cloth (kg/m^2, default 0.15).
    pub density: f32,
    /// Compliance of stretch (edge) constraints (m/N, default 1e-6), scaled per edge by
    /// l^2 / A with A the area of the triangles beside the edge, so a resolution change
    /// keeps the membrane's stiffness.
    pub stretch_compliance: f32,
    /// Compliance of shear constraints (m/N, default 1e-5), scaled like stretch.
    pub shear_compliance: f32,
    /// Compliance of distance bending constraints (m/N, default 2e-2), scaled like stretch.
    pub bend_compliance: f32,
    /// Largest relative stretch of an edge, enforced as a hard limit (default 0.05).
    pub stretch_limit: f32,
    /// Largest relative compression of an edge, enforced as a hard limit (default 0.2).
    pub compression_limit: f32,
    /// Add dihedral-angle bending constraints (default false).
    pub dihedral_bending: bool,
    /// Compliance of dihedral bending (1/(N m), default 1).
    pub dihedral_compliance: f32,
    /// Distance kept between cloth and body (m, default 0.003).
    pub thickness: f32,
    /// Extra contact search radius beyond thickness and a particle's travel (m, default 0.01).
    pub margin: f32,
    /// Coulomb friction coefficient between cloth and body (default 0.3); a garment with its
    /// own (`[material] friction` in its definition) uses that instead.
    pub friction: f32,
    /// Particle-particle self-collision (default false).
    pub self_collision: bool,
    /// Smallest distance between cloth particles with self-collision (m, default 0.004).
    pub self_distance: f32,
    /// Frames over which the body morphs from canonical to target, at least (default 60).
    pub morph_frames: u32,
    /// Average speed (the straight distance over the morph's duration) that no body vertex
    /// exceeds in the morph: a morph that `morph_frames` would make faster gets more frames
    /// (m/s, default 0.6).
    pub max_morph_speed: f32,
    /// Largest per-frame displacement counted as at rest (m, default 0.0005).
    pub rest_displacement: f32,
    /// Consecutive frames at rest that end a drape (default 10).
    pub rest_frames: u32,
    /// Settling frames at most, after the morph (default 600).
    pub max_frames: u32,
    /// A drape still moving after this many settling frames settles on with twice the
    /// stretch sweeps per substep (default 300; 0: never). Some drapes fall into a limit
    /// cycle of the solve itself: five free particles of the 3k jeans behind a calf (check
    /// sample 2) swung 0.4 to 0.9 mm in a seven-frame period for all 600 frames, with
    /// every edge within 0.3% of its length; four times the damping did not stop them, a
    /// different sweep count did within 132 frames (docs/sim.md, "A limit cycle of the
    /// solve"). Drapes at rest before it are unchanged bit for bit. Left out of the
    /// serialised config at 0, so a config pinned to 0 keeps the hash it had before the
    /// field; a manifest without it (all written before the field) reads as 0.
    #[serde(skip_serializing_if = "is_zero")]
    pub stall_frames: u32,
    /// Vertices deeper than this inside the body after the final push-out fail the drape
    /// (m, default 0.001).
    pub max_penetration: f32,
    /// An edge through the body (both ends outside it, a point along it inside) deeper
    /// than this and than a quarter of its length inside the body fails the drape: the
    /// cloth is caught across a limb (m, default 0.005).
    pub max_edge_penetration: f32,
    /// Largest share of particles the final push-out may move out of the body (deeper than
    /// `max_penetration`) before the drape counts as failed (default 0.01).
    pub max_pushout_share: f32,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            fps: 60.0,
            substeps: 10,
            shear_bend_substeps: None,
            stretch_iterations: 5,
            settle_substeps: 20,
            elastic_pushout: false,
            polish_sweeps: 100,
            thin_part_thickness: 0.03,
            crease_contacts: None,
            gravity: [0.0, -9.81, 0.0],
            damping: 2.0,
            max_velocity: 5.0,
            density: 0.15,
            stretch_compliance: 1e-6,
            shear_compliance: 1e-5,
            bend_compliance: 2e-2,
            stretch_limit: 0.05,
            compression_limit: 0.2,
            dihedral_bending: false,
            dihedral_compliance: 1.0,
            thickness: 0.003,
            margin: 0.01,
            friction: 0.3,
            self_collision: false,
            self_distance: 0.004,
            morph_frames: 60,
            max_morph_speed: 0.6,
            rest_displacement: 0.0005,
            rest_frames: 10,
            max_frames: 600,
            stall_frames: 300,
            max_penetration: 0.001,
            max_edge_penetration: 0.005,
            max_pushout_share: 0.01,
        }
    }
}

impl SimConfig {
    /// Parses TOML (fields left out keep their defaults) and validates it.
    pub fn from_toml(text: &str, origin: &Path) -> Result<Self, SimError> {
        let c: SimConfig = toml::from_str(text).map_err(|e| SimError::Config {
            path: origin.to_path_buf(),
            reason: e.to_string(),
        })?;
        c.validate().map_err(|reason| SimError::Config {
            path: origin.to_path_buf(),
            reason,
        })?;
        Ok(c)
    }

    /// Reads and validates a configuration file.
    pub fn load(path: &Path) -> Result<Self, SimError> {
        let text = std::fs::read_to_string(path).map_err(|source| SimError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Self::from_toml(&text, path)
    }

    /// Gravity as a vector.
    pub fn gravity(&self) -> Vec3 {
        Vec3::from_array(self.gravity)
    }

    /// Length of a frame (s).
    pub fn frame_dt(&self) -> f32 {
        1.0 / self.fps
    }

    /// Length of a substep (s).
    pub fn substep_dt(&self) -> f32 {
        1.0 / (self.fps * self.substeps as f32)
    }

    /// The time stepping in words, for headers: "10 substeps at 60 fps (20 while
    /// settling), 5 stretch sweeps each" (and the shear and bending rate and crease
    /// contacts when set).
    pub fn stepping(&self) -> String {
        let settling = if self.settle_substeps == self.substeps {
            String::new()
        } else {
            format!(" ({} while settling)", self.settle_substeps)
        };
        let mut s = format!(
            "{} substeps at {} fps{settling}, {} stretch sweep{} each",
            self.substeps,
            self.fps,
            self.stretch_iterations,
            if self.stretch_iterations == 1 {
                ""
            } else {
                "s"
            }
        );
        if self.shear_bend_interval() > 1 {
            s += &format!(
                ", shear and bending every {} substeps",
                self.shear_bend_interval()
            );
        }
        if self.crease_contacts == Some(true) {
            s += ", crease contacts";
        }
        s
    }

    /// Substeps from one shear and bending solve to the next (1 unless
    /// `shear_bend_substeps` is set below `substeps`).
    pub fn shear_bend_interval(&self) -> u32 {
        match self.shear_bend_substeps {
            Some(n) if n > 0 => (self.substeps / n).max(1),
            _ => 1,
        }
    }

    /// Checks every value's range; the message names the field.
    pub fn validate(&self) -> Result<(), String> {
        let positive = [
            ("fps", self.fps),
            ("max_velocity", self.max_velocity),
            ("max_morph_speed", self.max_morph_speed),
            ("density", self.density),
            ("thickness", self.thickness),
            ("rest_displacement", self.rest_displacement),
            ("max_penetration", self.max_penetration),
            ("max_edge_penetration", self.max_edge_penetration),
            ("self_distance", self.self_distance),
        ];
        for (name, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("{name} = {v} must be a positive number"));
            }
        }
        let non_negative = [
            ("damping", self.damping),
            ("stretch_compliance", self.stretch_compliance),
            ("shear_compliance", self.shear_compliance),
            ("bend_compliance", self.bend_compliance),
            ("dihedral_compliance", self.dihedral_compliance),
            ("margin", self.margin),
            ("friction", self.friction),
            ("max_pushout_share", self.max_pushout_share),
            ("stretch_limit", self.stretch_limit),
        ];
        if self.max_morph_speed < 0.05 {
            return Err(format!(
                "max_morph_speed = {} must be 0.05 m/s or more (slower morphs take thousands of frames)",
                self.max_morph_speed
            ));
        }
        for (name, v) in non_negative {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("{name} = {v} must be zero or positive"));
            }
        }
        if !(self.compression_limit.is_finite() && (0.0..1.0).contains(&self.compression_limit)) {
            return Err(format!(
                "compression_limit = {} must lie in [0, 1)",
                self.compression_limit
            ));
        }
        if self.gravity.iter().any(|g| !g.is_finite()) {
            return Err("gravity must be finite".into());
        }
        for (name, n) in [
            ("substeps", self.substeps),
            ("settle_substeps", self.settle_substeps),
        ] {
            if !(1..=1000).contains(&n) {
                return Err(format!("{name} = {n} must lie in 1 to 1000"));
            }
            if let Some(m) = self.shear_bend_substeps
                && (m == 0 || n % m != 0)
            {
                return Err(format!(
                    "shear_bend_substeps = {m} must divide {name} = {n}"
                ));
            }
            if self.fps * n as f32 > 1e5 {
                return Err(format!("fps * {name} above 100,000 steps per second"));
            }
        }
        if !(1..=16).contains(&self.stretch_iterations) {
            return Err(format!(
                "stretch_iterations = {} must lie in 1 to 16",
                self.stretch_iterations
            ));
        }
        if !(self.thin_part_thickness == 0.0
            || (self.thin_part_thickness > self.thickness && self.thin_part_thickness <= 0.2))
        {
            return Err(format!(
                "thin_part_thickness = {} m must be 0 (no edge contacts) or lie above thickness ({} m) and at most 0.2",
                self.thin_part_thickness, self.thickness
            ));
        }
        if self.polish_sweeps > 100_000 {
            return Err(format!(
                "polish_sweeps = {} must lie in 0 to 100,000",
                self.polish_sweeps
            ));
        }
        if self.rest_frames == 0 || self.max_frames == 0 {
            return Err("rest_frames and max_frames must be at least 1".into());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_file_spells_out_the_defaults() {
        let c = SimConfig::from_toml(DEFAULT_TOML, Path::new("default.toml")).unwrap();
        assert_eq!(c, SimConfig::default());
    }

    #[test]
    fn bad_values_name_the_field() {
        let e = SimConfig::from_toml("substeps = 0", Path::new("x.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("substeps") && e.contains("x.toml"), "{e}");
        let e = SimConfig::from_toml("thickness = -1.0", Path::new("x.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("thickness"), "{e}");
        let e = SimConfig::from_toml("thicknes = 0.1", Path::new("x.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("thicknes"), "{e}");
        let e = SimConfig::from_toml(
            "substeps = 15\nshear_bend_substeps = 10",
            Path::new("x.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("shear_bend_substeps") && e.contains("15"), "{e}");
        let e = SimConfig::from_toml(
            "settle_substeps = 15\nshear_bend_substeps = 10",
            Path::new("x.toml"),
        )
        .unwrap_err()
        .to_string();
        assert!(e.contains("settle_substeps = 15"), "{e}");
        let e = SimConfig::from_toml("settle_substeps = 0", Path::new("x.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("settle_substeps"), "{e}");
        let e = SimConfig::from_toml("friction = nan", Path::new("x.toml"))
            .unwrap_err()
            .to_string();
        assert!(e.contains("friction"), "{e}");
        // Thin parts: 0, or above the thickness.
        for bad in ["0.002", "-0.01", "0.5", "nan"] {
            let e =
                SimConfig::from_toml(&format!("thin_part_thickness = {bad}"), Path::new("x.toml"))
                    .unwrap_err()
                    .to_string();
            assert!(e.contains("thin_part_thickness"), "{e}");
        }
        assert!(SimConfig::from_toml("thin_part_thickness = 0.0", Path::new("x.toml")).is_ok());
    }
}
