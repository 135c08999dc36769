//! Garment definitions: `configs/garments/*.toml`.
//!
//! A garment is one or two *parts*, each cut from a MakeHuman helper mesh by planes placed
//! on the canonical body's skeleton, given ease (an offset along the surface normal), and,
//! for two parts, stitched along a shared plane. See `configs/garments/tshirt.toml` for a
//! commented example.

use serde::{Deserialize, Serialize};

use crate::body::ShapeParams;

/// A garment definition.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GarmentDef {
    /// Name used on the command line (`tshirt`).
    pub name: String,
    /// One line for humans.
    pub description: String,
    /// Number of vertices of the default resolution (about; the remesher aims at it).
    #[serde(default = "default_vertices")]
    pub vertices: usize,
    /// The parts, stitched together in order.
    pub parts: Vec<PartDef>,
    /// Where two parts are stitched: each part must have an opening on this plane.
    #[serde(default)]
    pub join: Option<PlaneDef>,
    /// Clearance kept from the canonical body before relaxing (m, default 0.006).
    #[serde(default = "default_clearance")]
    pub clearance: f32,
    /// Sizes: the garment graded for other bodies (none: one size, the canonical body's).
    #[serde(default)]
    pub grading: Option<GradingDef>,
    /// The fabric's contact with the body (none: the simulator config's).
    #[serde(default)]
    pub material: Option<MaterialDef>,
    /// Simulator settings the garment needs (none: the simulator config's).
    #[serde(default)]
    pub simulation: Option<SimulationDef>,
    /// How the body's skinning weights are carried to the garment (none: the default).
    #[serde(default)]
    pub skinning: Option<SkinningDef>,
}

/// How the garment's skinning weights are made from the body's.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SkinningDef {
    /// Two bones whose share of the weights is divided between them over a wider reach
    /// than the other weights are averaged over (trousers: the two thighs). None: every
    /// weight is averaged over [`crate::garment::skin::SMOOTHING_ROUNDS`] rounds.
    pub split: Option<SplitDef>,
}

/// Two bones that share the cloth between them over a distance: where a vertex follows
/// both, the split between them is averaged over `reach` of cloth while their sum, and
/// every other weight, is averaged as without it. Trousers: across the crotch the two thighs
/// carry the cloth apart in a wide stance, and the wider the band in which the cloth
/// follows both, the fewer edges of the DQS warp stretch; the band stays between the legs,
/// so the hips are not blurred into the thighs (which sinks the warp into the body).
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SplitDef {
    /// The two bones, by name.
    pub bones: [String; 2],
    /// The distance over the garment (m) the split is averaged over: `(reach / mean
    /// edge)^2` rounds of neighbour averaging, at least
    /// [`crate::garment::skin::SMOOTHING_ROUNDS`] and at most 10,000 (from 0.005 to 0.5).
    pub reach: f32,
}

/// What a garment needs of the simulator.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SimulationDef {
    /// Substeps a frame, at least, throughout the drape (from 1 to 1000): a garment that
    /// hangs by friction sags at the config's 10 and slides down while the body moves.
    pub substeps: Option<u32>,
    /// Whether the garment's particles take crease contacts (the other side of a fold of
    /// the body as a second contact) when the simulator config leaves them unset: trousers,
    /// whose cloth lies in the fold between a raised thigh and the belly.
    pub crease_contacts: Option<bool>,
}

/// What a garment's fabric brings to the simulation besides its shape.
#[derive(Debug, Clone, Copy, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialDef {
    /// Coulomb friction coefficient between this garment and the body, in place of the
    /// simulator config's `friction` (from 0 to 2).
    pub friction: Option<f32>,
    /// Where the cloth slides more freely: below a band along the top opening (trousers'
    /// waistband) the cloth's friction is this band's, in drapes (the template is made and
    /// graded at `friction`).
    pub below_band: Option<BelowBand>,
}

/// The friction of a garment below a band along its top opening: a waistband grips the
/// body, the legs slide on it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BelowBand {
    /// Width of the band (m): cloth closer than this to the top opening (straight-line
    /// distance to its nearest vertex on the template) keeps the garment's `friction`.
    pub width: f32,
    /// Coulomb friction coefficient of the cloth beyond the band (from 0 to 2).
    pub friction: f32,
}

impl BelowBand {
    /// For summaries: `0.1 beyond 8 cm of the top opening`.
    pub fn describe(&self) -> String {
        format!(
            "{} beyond {} cm of the top opening",
            self.friction,
            (self.width * 1000.0).round() / 10.0
        )
    }

    /// Each vertex's friction on a mesh whose top opening is `top`: `band` within
    /// `width` of one of the opening's vertices, the band's `friction` beyond.
    pub fn friction_map(&self, vertices: &[glam::Vec3], top: &[u32], band: f32) -> Vec<f32> {
        let top: Vec<glam::Vec3> = top.iter().map(|&i| vertices[i as usize]).collect();
        let w2 = self.width * self.width;
        vertices
            .iter()
            .map(|p| {
                if top.iter().any(|q| q.distance_squared(*p) <= w2) {
                    band
                } else {
                    self.friction
                }
            })
            .collect()
    }
}

/// How a garment is graded in sizes, as shops do: each size is the garment made for a
/// reference body (the template carried to that body's shape with the same ease and relaxed
/// there), and a body wears the size whose reference body measures closest to its own.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GradingDef {
    /// Measurements that choose the size: `chest`, `waist`, `hips` (tape girths) and
    /// `height`; the size whose reference body differs least in relative terms is worn
    /// (`SizeChart::pick`: a size too small counts more than one too large).
    pub by: Vec<String>,
    /// The sizes besides the base one (the canonical body's, named `base`).
    pub sizes: Vec<SizeDef>,
    /// Name of the base size (default `M`).
    #[serde(default = "default_base_size")]
    pub base: String,
}

/// Name of the base size unless a grading names it otherwise, and the one size of a garment
/// that is not graded.
pub const DEFAULT_BASE_SIZE: &str = "M";

fn default_base_size() -> String {
    DEFAULT_BASE_SIZE.into()
}

/// One size: a name and the shape of its reference body.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SizeDef {
    /// Size name (letters, digits, `-`).
    pub name: String,
    /// Shape parameters of the reference body (unset ones are the average person's).
    pub shape: ShapeParams,
}

/// Measurements a size can be chosen by.
pub const SIZE_MEASUREMENTS: [&str; 4] = ["chest", "waist", "hips", "height"];

fn default_vertices() -> usize {
    10_000
}

fn default_clearance() -> f32 {
    0.006
}

/// One part of a garment.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PartDef {
    /// The helper mesh it is cut from (`helper-tights` or `helper-skirt`).
    pub source: String,
    /// Offset along the surface normal, the garment's looseness (m).
    pub ease: f32,
    /// Cuts, applied in order.
    #[serde(default)]
    pub cuts: Vec<CutDef>,
    /// Skinning: `None` transfers weights from the nearest body point; a list of bones
    /// binds the part to those bones only (a skirt follows the hips, not either leg).
    #[serde(default)]
    pub bones: Option<Vec<String>>,
    /// Flare (m of extra radius per m below the part's top, default 0): each vertex moves
    /// away from the vertical axis through the Hips joint by this times its depth below
    /// the part's highest vertex, after the ease, so a skirt widens towards its hem.
    #[serde(default)]
    pub flare: f32,
}

/// A plane placed on the skeleton of the canonical body.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlaneDef {
    /// Bone the plane goes through.
    pub bone: String,
    /// Where along the bone: 0 at its head, 1 at its tail.
    pub at: f32,
    /// Which way the plane's normal points.
    pub normal: Direction,
    /// Moves the plane along its normal (m).
    #[serde(default)]
    pub offset: f32,
}

/// A plane's normal.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Direction {
    /// Along the bone, head to tail.
    Bone,
    /// World up (+Y).
    Up,
    /// World down (-Y).
    Down,
}

/// A cut removes what lies beyond a plane and is connected to the seed.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CutDef {
    /// Bone the plane goes through.
    pub bone: String,
    /// Where along the bone: 0 at its head, 1 at its tail.
    pub at: f32,
    /// Which way the plane's normal points: at the removed side.
    pub normal: Direction,
    /// Moves the plane along its normal (m).
    #[serde(default)]
    pub offset: f32,
    /// The removed piece is the one around this bone's head.
    pub seed: String,
    /// Cut only within this distance of the bone's axis line (m): a sleeve cut near the
    /// shoulder then leaves the torso alone.
    #[serde(default)]
    pub radius: Option<f32>,
}

impl CutDef {
    /// The cut's plane.
    pub fn plane(&self) -> PlaneDef {
        PlaneDef {
            bone: self.bone.clone(),
            at: self.at,
            normal: self.normal,
            offset: self.offset,
        }
    }
}

/// Checks a garment's own friction: from 0 to 2 (the error says so).
pub fn check_friction(mu: f32) -> Result<(), String> {
    if (0.0..=2.0).contains(&mu) {
        Ok(())
    } else {
        Err(format!("friction must be from 0 to 2 (got {mu})"))
    }
}

impl GarmentDef {
    /// The garment's own substeps a frame, at least (`[simulation] substeps`), if any.
    pub fn substeps(&self) -> Option<u32> {
        self.simulation.and_then(|s| s.substeps)
    }

    /// Whether the garment takes crease contacts when the simulator config leaves them unset
    /// (`[simulation] crease_contacts`; false without it).
    pub fn crease_contacts(&self) -> bool {
        self.simulation
            .and_then(|s| s.crease_contacts)
            .unwrap_or(false)
    }

    /// The two bones whose split is averaged over a reach (`[skinning] split`), if any.
    pub fn split(&self) -> Option<&SplitDef> {
        self.skinning.as_ref().and_then(|s| s.split.as_ref())
    }

    /// The garment's own friction against the body (`[material] friction`), if it has one.
    pub fn friction(&self) -> Option<f32> {
        self.material.and_then(|m| m.friction)
    }

    /// The garment's friction below a band along its top opening (`[material]
    /// below_band`), if it has one.
    pub fn below_band(&self) -> Option<BelowBand> {
        self.material.and_then(|m| m.below_band)
    }

    /// Parses and checks a definition; `origin` names it in errors.
    pub fn from_toml(text: &str, origin: &str) -> Result<Self, String> {
        let def: GarmentDef = toml::from_str(text).map_err(|e| format!("{origin}: {e}"))?;
        if def.parts.is_empty() || def.parts.len() > 2 {
            return Err(format!("{origin}: a garment has one or two parts"));
        }
        if (def.parts.len() == 2) != def.join.is_some() {
            return Err(format!(
                "{origin}: two parts need a `join` plane, one part must not have one"
            ));
        }
        if !(100..=200_000).contains(&def.vertices) {
            return Err(format!("{origin}: vertices must be from 100 to 200000"));
        }
        for p in &def.parts {
            if !(0.0..=0.2).contains(&p.ease) {
                return Err(format!("{origin}: ease must be from 0 to 0.2 m"));
            }
        }
        if let Some(mu) = def.friction() {
            check_friction(mu).map_err(|e| format!("{origin}: material {e}"))?;
        }
        if let Some(b) = def.below_band() {
            check_friction(b.friction).map_err(|e| format!("{origin}: material below_band {e}"))?;
            if !(b.width > 0.0 && b.width <= 1.0) {
                return Err(format!(
                    "{origin}: material below_band width must be over 0 and at most 1 m (got {})",
                    b.width
                ));
            }
            if def.friction().is_none() {
                return Err(format!(
                    "{origin}: material below_band needs the band's own `friction`"
                ));
            }
        }
        if let Some(split) = def.split() {
            if !(0.005..=0.5).contains(&split.reach) {
                return Err(format!(
                    "{origin}: skinning split reach must be from 0.005 to 0.5 m (got {})",
                    split.reach
                ));
            }
            if split.bones[0] == split.bones[1] {
                return Err(format!(
                    "{origin}: skinning split needs two different bones"
                ));
            }
        }
        if let Some(n) = def.substeps()
            && !(1..=1000).contains(&n)
        {
            return Err(format!(
                "{origin}: simulation substeps must be from 1 to 1000 (got {n})"
            ));
        }
        if let Some(g) = &def.grading {
            if g.by.is_empty() || g.sizes.is_empty() {
                return Err(format!(
                    "{origin}: grading needs at least one measurement (`by`) and one size"
                ));
            }
            if let Some(m) =
                g.by.iter()
                    .find(|m| !SIZE_MEASUREMENTS.contains(&m.as_str()))
            {
                return Err(format!(
                    "{origin}: grading by {m:?}: measurements are {}",
                    SIZE_MEASUREMENTS.join(", ")
                ));
            }
            let mut names = vec![g.base.as_str()];
            for s in &g.sizes {
                let ok = !s.name.is_empty()
                    && s.name
                        .chars()
                        .all(|c| c.is_ascii_alphanumeric() || c == '-');
                if !ok || names.contains(&s.name.as_str()) {
                    return Err(format!(
                        "{origin}: size name {:?} is empty, repeated or has characters other than letters, digits and -",
                        s.name
                    ));
                }
                names.push(&s.name);
                s.shape
                    .validate()
                    .map_err(|e| format!("{origin}: size {}: {e}", s.name))?;
            }
        }
        Ok(def)
    }

    /// Name of the base size (the garment on the canonical body).
    pub fn base_size(&self) -> &str {
        self.grading
            .as_ref()
            .map_or(DEFAULT_BASE_SIZE, |g| g.base.as_str())
    }

    /// The size names, the base size first (just the base when the garment is not graded).
    pub fn size_names(&self) -> Vec<String> {
        match &self.grading {
            None => vec![default_base_size()],
            Some(g) => std::iter::once(g.base.clone())
                .chain(g.sizes.iter().map(|s| s.name.clone()))
                .collect(),
        }
    }
}

/// The built-in garments, in the paper's order: name and definition text.
pub const BUILT_IN: [(&str, &str); 4] = [
    (
        "tshirt",
        include_str!("../../../configs/garments/tshirt.toml"),
    ),
    (
        "sweater",
        include_str!("../../../configs/garments/sweater.toml"),
    ),
    (
        "dress",
        include_str!("../../../configs/garments/dress.toml"),
    ),
    (
        "jeans",
        include_str!("../../../configs/garments/jeans.toml"),
    ),
];
