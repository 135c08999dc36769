//! A garment template: the mesh on the canonical body in its rest pose, its skinning weights
//! and body bindings, stored as safetensors (readable from Python with
//! `safetensors.numpy.load_file`).
//!
//! Tensors: `vertices` f32 [V, 3] (m, Y up), `triangles` u32 [F, 3], `skin_bones` u8 [V, 4],
//! `skin_weights` f32 [V, 4], `bind_triangle` u32 [V] (canonical body triangle),
//! `bind_bary` f32 [V, 3]. Metadata key `drape`: JSON [`TemplateMeta`].

use std::path::Path;
use std::sync::OnceLock;

use glam::Vec3;
use rayon::prelude::*;
use safetensors::tensor::{Dtype, SafeTensors};
use serde::{Deserialize, Serialize};

use super::GarmentError;
use super::skin::Binding;
use crate::body::skinning::{self, SkinWeights};
use crate::body::{BodyModel, PosedBody, ShapeParams, ShapedBody};
use crate::cloth::{ClothModel, SimConfig, SimError};
use crate::mesh::TriMesh;

/// Reach of the smoothing of the shape moves in [`Template::reshape`] (m): neighbour
/// averaging spreads a value over about `edge * sqrt(rounds)`, so the rounds are
/// `(RESHAPE_SMOOTHING_REACH / mean edge)^2` (99 for the 3k T-shirt, 327 for the 10k one).
pub const RESHAPE_SMOOTHING_REACH: f32 = 0.15;

/// Format tag of the template files.
pub const FORMAT: &str = "drape-garment-template/1";

/// What a template is and how it was made.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TemplateMeta {
    /// Format tag, [`FORMAT`].
    pub format: String,
    /// Garment name.
    pub name: String,
    /// `built-in` (from `configs/garments`) or `imported` (from a user's OBJ).
    pub origin: String,
    /// Requested vertex count (built-in) or 0 (imported).
    pub resolution: usize,
    /// sha256 of the definition text and the build code version it was built from (built-in).
    pub key: String,
    /// Free-form build figures (edge length, angles, relaxation, seconds).
    pub build: serde_json::Value,
    /// The size this template is, for a graded garment's other sizes: its name and the
    /// reference body it is made for (`None`: made for the canonical body).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<SizeMeta>,
    /// The garment's own friction against the body (its definition's `[material]`; `None`:
    /// the simulator config's). [`Template::cloth`] cooks it into the cloth.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub friction: Option<f32>,
    /// The garment's friction below a band along its top opening (its definition's
    /// `[material] below_band`; `None`: `friction` everywhere). [`Template::cloth`] cooks it
    /// into the cloth.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub below_band: Option<super::def::BelowBand>,
    /// Substeps a frame the garment needs throughout a drape, at least (its
    /// definition's `[simulation]`; `None`: the simulator config's). [`Template::cloth`]
    /// cooks it into the cloth.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub substeps: Option<u32>,
    /// Whether the garment takes crease contacts when the simulator config leaves them
    /// unset (its definition's `[simulation]`; false: not). [`Template::cloth`] cooks it into
    /// the cloth.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub crease_contacts: bool,
}

/// A graded template's size.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SizeMeta {
    /// Size name.
    pub name: String,
    /// Shape of the reference body the template is made for.
    pub reference: ShapeParams,
}

/// A garment template.
#[derive(Debug, Clone)]
pub struct Template {
    /// Metadata.
    pub meta: TemplateMeta,
    /// The mesh on the canonical body in its rest pose (its rest shape).
    pub mesh: TriMesh,
    /// Skinning weights transferred from the body.
    pub skin: SkinWeights,
    /// Closest canonical body point of each vertex.
    pub bindings: Vec<Binding>,
    /// Each body shape target's move of the template, made on first use by
    /// [`Self::reshape`]. It assumes `mesh` and `bindings` are not edited after that.
    pub(crate) shape_moves: ShapeMoves,
}

/// The template's move under each of the body model's shape targets, for
/// [`Template::reshape`]: one slot per target, filled the first time a body needs it.
/// No lock: two warps that need the same missing targets at once (the first drapes of
/// `drape gen`'s workers) both make them and the first to finish fills the slot. A lock
/// held across the smoothing's parallel jobs could deadlock: a thread waiting for a stolen
/// job may run another drape's warp, which would wait for the lock it holds.
#[derive(Debug, Clone, Default)]
pub(crate) struct ShapeMoves(OnceLock<Vec<OnceLock<TargetMove>>>);

/// One shape target's unit move of the template: its bound points' deltas, and those
/// smoothed as [`Template::reshape`] smooths.
#[derive(Debug, Clone)]
struct TargetMove {
    bound: Vec<Vec3>,
    smoothed: Vec<Vec3>,
}

/// How far (m) a body may be from its shape parameters' body, at the template's bound
/// points, before [`Template::reshape`] smooths the difference itself: below it, the
/// difference (float rounding) moves no vertex by more than this, since averaging never
/// makes a field larger.
const RESHAPE_RESIDUAL: f32 = 1e-6;

/// Template vertices per task of the shape targets' sum in [`Template::reshape`].
const RESHAPE_CHUNK: usize = 2048;

fn f32s(v: impl IntoIterator<Item = f32>) -> Vec<u8> {
    v.into_iter().flat_map(f32::to_le_bytes).collect()
}

fn u32s(v: impl IntoIterator<Item = u32>) -> Vec<u8> {
    v.into_iter().flat_map(u32::to_le_bytes).collect()
}

impl Template {
    /// The template cooked for the simulator with `config`, its fabric's friction
    /// (`meta.friction`) in place of the config's when the garment has its own, below its
    /// band (`meta.below_band`) if it has one, its own substeps (`meta.substeps`),
    /// checked against `config`, and its own crease contacts (`meta.crease_contacts`).
    pub fn cloth(&self, config: &SimConfig) -> Result<ClothModel, SimError> {
        let mut cloth = ClothModel::new(&self.mesh, config, &[])?;
        cloth.friction = self.friction(config);
        cloth.substeps = self.meta.substeps;
        cloth.crease_contacts = self.meta.crease_contacts;
        if let Some(b) = self.meta.below_band {
            cloth.friction_map =
                b.friction_map(&self.mesh.vertices, &self.top_opening(), cloth.friction);
        }
        cloth
            .drape_config(config)
            .map_err(|reason| SimError::Config {
                path: format!("(garment {})", self.meta.name).into(),
                reason,
            })?;
        Ok(cloth)
    }

    /// How `config` steps, for a summary line, with the garment's own substeps and crease
    /// contacts if it has them ([`SimConfig::stepping`]).
    pub fn stepping(&self, config: &SimConfig) -> String {
        let mut s = config.stepping();
        if let Some(n) = self.meta.substeps {
            s += &format!("; the garment's own: at least {n} substeps throughout");
        }
        if config.crease_contacts.is_none() && self.meta.crease_contacts {
            s += "; the garment's own crease contacts";
        }
        s
    }

    /// The friction this garment drapes with under `config`: its own, else the config's.
    pub fn friction(&self, config: &SimConfig) -> f32 {
        self.meta.friction.unwrap_or(config.friction)
    }

    /// The top opening: the boundary loop highest on the template (a top's neckline,
    /// trousers' waistband); empty for a closed mesh.
    pub fn top_opening(&self) -> Vec<u32> {
        let mean_y = |l: &Vec<u32>| {
            l.iter()
                .map(|&v| self.mesh.vertices[v as usize].y)
                .sum::<f32>()
                / l.len() as f32
        };
        crate::mesh::remesh::boundary_loops(&self.mesh)
            .into_iter()
            .max_by(|a, b| mean_y(a).total_cmp(&mean_y(b)))
            .unwrap_or_default()
    }

    /// Shape of the body the template is made for, in its rest pose: the canonical body
    /// unless it is a graded size. Drapes start there and warps reshape from there.
    pub fn reference(&self) -> ShapeParams {
        self.meta
            .size
            .as_ref()
            .map_or_else(ShapeParams::default, |s| s.reference)
    }

    /// Number of vertices.
    pub fn len(&self) -> usize {
        self.mesh.vertices.len()
    }

    /// True for an empty mesh.
    pub fn is_empty(&self) -> bool {
        self.mesh.vertices.is_empty()
    }

    /// Safetensors bytes.
    pub fn encode(&self) -> Vec<u8> {
        let (v, f) = (self.mesh.vertices.len(), self.mesh.triangles.len());
        let buffers: Vec<crate::io::NamedTensor<'_>> = vec![
            (
                "vertices",
                Dtype::F32,
                vec![v, 3],
                f32s(self.mesh.vertices.iter().flat_map(|p| p.to_array())),
            ),
            (
                "triangles",
                Dtype::U32,
                vec![f, 3],
                u32s(self.mesh.triangles.iter().flatten().copied()),
            ),
            (
                "skin_bones",
                Dtype::U8,
                vec![v, 4],
                self.skin.bones.iter().flatten().map(|&b| b as u8).collect(),
            ),
            (
                "skin_weights",
                Dtype::F32,
                vec![v, 4],
                f32s(self.skin.weights.iter().flatten().copied()),
            ),
            (
                "bind_triangle",
                Dtype::U32,
                vec![v],
                u32s(self.bindings.iter().map(|b| b.triangle)),
            ),
            (
                "bind_bary",
                Dtype::F32,
                vec![v, 3],
                f32s(self.bindings.iter().flat_map(|b| b.bary)),
            ),
        ];
        crate::io::safetensors_bytes(&buffers, &self.meta)
    }

    /// Reads a template file, checking every tensor's type and shape and every index.
    pub fn load(path: &Path, body_triangles: usize, bones: usize) -> Result<Self, GarmentError> {
        let bytes = std::fs::read(path).map_err(|source| GarmentError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let bad = |reason: String| GarmentError::Corrupt {
            path: path.to_path_buf(),
            reason,
        };
        let (_, header) =
            SafeTensors::read_metadata(&bytes).map_err(|e| bad(format!("safetensors: {e}")))?;
        let meta: TemplateMeta = header
            .metadata()
            .as_ref()
            .and_then(|m| m.get("drape"))
            .ok_or_else(|| bad("no `drape` metadata".into()))
            .and_then(|j| serde_json::from_str(j).map_err(|e| bad(format!("metadata: {e}"))))?;
        if meta.format != FORMAT {
            return Err(bad(format!(
                "format {:?}, expected {FORMAT:?}",
                meta.format
            )));
        }
        let st = SafeTensors::deserialize(&bytes).map_err(|e| bad(format!("safetensors: {e}")))?;
        let get = |name: &str, dtype: Dtype, shape_tail: &[usize]| {
            let t = st
                .tensor(name)
                .map_err(|_| bad(format!("tensor {name} missing")))?;
            let s = t.shape();
            if t.dtype() != dtype || s.len() != 1 + shape_tail.len() || &s[1..] != shape_tail {
                return Err(bad(format!(
                    "tensor {name} is {:?} {s:?}, expected {dtype:?} [n, {shape_tail:?}]",
                    t.dtype()
                )));
            }
            Ok((s[0], t.data().to_vec()))
        };
        let as_f32 = |d: &[u8]| -> Vec<f32> {
            d.chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        };
        let as_u32 = |d: &[u8]| -> Vec<u32> {
            d.chunks_exact(4)
                .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        };
        let (nv, vd) = get("vertices", Dtype::F32, &[3])?;
        let (nf, fd) = get("triangles", Dtype::U32, &[3])?;
        let (nb, bd) = get("skin_bones", Dtype::U8, &[4])?;
        let (nw, wd) = get("skin_weights", Dtype::F32, &[4])?;
        let (nt, td) = get("bind_triangle", Dtype::U32, &[])?;
        let (nc, cd) = get("bind_bary", Dtype::F32, &[3])?;
        if [nb, nw, nt, nc].iter().any(|&n| n != nv) {
            return Err(bad("per-vertex tensors differ in length".into()));
        }
        let vertices: Vec<Vec3> = as_f32(&vd).chunks_exact(3).map(Vec3::from_slice).collect();
        if vertices.iter().any(|p| !p.is_finite()) {
            return Err(bad("non-finite vertex".into()));
        }
        let flat = as_u32(&fd);
        if flat.iter().any(|&i| i as usize >= nv) {
            return Err(bad("a triangle indexes beyond the vertices".into()));
        }
        let triangles: Vec<[u32; 3]> = flat.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();
        debug_assert_eq!(triangles.len(), nf);
        if bd.iter().any(|&b| b as usize >= bones) {
            return Err(bad("a skinning bone is not in the rig".into()));
        }
        let skin = SkinWeights {
            bones: bd
                .chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]].map(u16::from))
                .collect(),
            weights: as_f32(&wd)
                .chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect(),
        };
        let tri = as_u32(&td);
        if tri.iter().any(|&t| t as usize >= body_triangles) {
            return Err(bad(
                "a binding names a triangle the body does not have".into()
            ));
        }
        let bindings = tri
            .iter()
            .zip(as_f32(&cd).chunks_exact(3))
            .map(|(&triangle, c)| Binding {
                triangle,
                bary: [c[0], c[1], c[2]],
            })
            .collect();
        Ok(Self {
            meta,
            mesh: TriMesh::new(vertices, triangles),
            skin,
            bindings,
            shape_moves: ShapeMoves::default(),
        })
    }

    /// The template carried to a new body shape: each vertex moves as its bound point of the
    /// body does between the `canonical` (the template's [`Self::reference`] body) and the
    /// `shaped` body (rest pose), the moves smoothed
    /// over the garment (neighbour averaging reaching about [`RESHAPE_SMOOTHING_REACH`]), so that
    /// neighbours bound to different limbs (a skirt's front between the legs) move together.
    pub fn reshape(&self, canonical: &ShapedBody<'_>, shaped: &ShapedBody<'_>) -> Vec<Vec3> {
        // The moves are linear in the bodies' difference, which is a weighted sum of the
        // model's shape targets, and so is their smoothing: each target's smoothed move is
        // made once and a body's moves are the sum of those, weighted by how much more of
        // each target it has than the canonical body. The rounds, not the sum, were the
        // warp's cost (docs/bench.md).
        let model = canonical.model;
        let (a, b) = (&canonical.vertices, &shaped.vertices);
        let mut residual = self.bound(model, |i| b[i] - a[i]);
        let mut moves = vec![Vec3::ZERO; residual.len()];
        let slots = self.shape_slots(model);
        if slots.len() == model.targets.len() {
            let (wa, wb) = (
                model.target_weights(&canonical.params),
                model.target_weights(&shaped.params),
            );
            let active: Vec<(usize, f32)> = wa
                .iter()
                .zip(&wb)
                .map(|(a, b)| b - a)
                .enumerate()
                .filter(|&(_, d)| d != 0.0)
                .collect();
            let needed: Vec<usize> = active.iter().map(|&(t, _)| t).collect();
            self.make_target_moves(model, &needed);
            let made: Vec<(&TargetMove, f32)> = active
                .iter()
                .map(|&(t, d)| (slots[t].get().expect("made above"), d))
                .collect();
            // In parallel over the vertices, each summing the targets in order (the same
            // bits as one thread): the sum reads two vectors per vertex and target, and on
            // one thread was most of a 10k warp (docs/bench.md, "The local search as a scan").
            moves
                .par_chunks_mut(RESHAPE_CHUNK)
                .zip(residual.par_chunks_mut(RESHAPE_CHUNK))
                .enumerate()
                .for_each(|(c, (moves, residual))| {
                    let first = c * RESHAPE_CHUNK;
                    for &(m, d) in &made {
                        let range = first..first + moves.len();
                        for ((s, r), (&ms, &mb)) in moves
                            .iter_mut()
                            .zip(residual.iter_mut())
                            .zip(m.smoothed[range.clone()].iter().zip(&m.bound[range]))
                        {
                            *s += d * ms;
                            *r -= d * mb;
                        }
                    }
                });
        }
        // What the targets do not explain (a body not made by `BodyModel::shape`) is
        // smoothed as it is.
        if residual
            .iter()
            .any(|r| r.abs().max_element() > RESHAPE_RESIDUAL)
        {
            let rest = super::skin::smooth(&self.mesh, residual, self.reshape_rounds());
            for (m, r) in moves.iter_mut().zip(rest) {
                *m += r;
            }
        }
        self.moved(moves)
    }

    /// [`Self::reshape`] as its definition reads: the body's moves at the bound points,
    /// smoothed. The same to within float rounding (2.4e-7 m on the built-in garments), at
    /// the cost of the full smoothing for every body. Grading a size uses it, so that the
    /// sized templates, which are relaxed from it and cached, keep the bits they had
    /// before `reshape` summed shape targets (session 48): drapes are chaotic, and a
    /// rounding-level change in a template changes which drapes cycle.
    pub fn reshape_by_smoothing(
        &self,
        canonical: &ShapedBody<'_>,
        shaped: &ShapedBody<'_>,
    ) -> Vec<Vec3> {
        let (a, b) = (&canonical.vertices, &shaped.vertices);
        let moves = self.bound(canonical.model, |i| b[i] - a[i]);
        self.moved(super::skin::smooth(
            &self.mesh,
            moves,
            self.reshape_rounds(),
        ))
    }

    /// The template's vertices plus `moves`.
    fn moved(&self, moves: Vec<Vec3>) -> Vec<Vec3> {
        self.mesh
            .vertices
            .iter()
            .zip(moves)
            .map(|(&p, m)| p + m)
            .collect()
    }

    /// Makes the moves of all the model's shape targets now, instead of as bodies need them
    /// in [`Self::reshape`] (each about one reshape's smoothing), so that no later warp
    /// includes them. Returns how many targets there are.
    pub fn make_shape_moves(&self, model: &BodyModel) -> usize {
        let all: Vec<usize> = (0..model.targets.len()).collect();
        self.make_target_moves(model, &all);
        all.len()
    }

    /// One slot per shape target of `model` (made empty on first use).
    fn shape_slots(&self, model: &BodyModel) -> &[OnceLock<TargetMove>] {
        self.shape_moves
            .0
            .get_or_init(|| model.targets.iter().map(|_| OnceLock::new()).collect())
    }

    /// Fills the slots of `targets` not yet made, their smoothing done together
    /// ([`super::skin::smooth_many`]).
    fn make_target_moves(&self, model: &BodyModel, targets: &[usize]) {
        let slots = self.shape_slots(model);
        if slots.len() != model.targets.len() {
            return;
        }
        let missing: Vec<usize> = targets
            .iter()
            .copied()
            .filter(|&t| slots[t].get().is_none())
            .collect();
        if missing.is_empty() {
            return;
        }
        let bound: Vec<Vec<Vec3>> = missing
            .iter()
            .map(|&t| self.target_bound(model, t))
            .collect();
        let smoothed = super::skin::smooth_many(&self.mesh, &bound, self.reshape_rounds());
        for ((t, bound), smoothed) in missing.into_iter().zip(bound).zip(smoothed) {
            // Another warp may have filled it meanwhile, with the same bits.
            let _ = slots[t].set(TargetMove { bound, smoothed });
        }
    }

    /// The rounds of [`Self::reshape`]'s smoothing: reaching about
    /// [`RESHAPE_SMOOTHING_REACH`] over the template's mean edge.
    fn reshape_rounds(&self) -> usize {
        let edge = self.mesh.mean_side();
        ((RESHAPE_SMOOTHING_REACH / edge).powi(2).ceil() as usize).min(2_000)
    }

    /// A body field (per body vertex) at each template vertex's bound point.
    fn bound(&self, model: &BodyModel, field: impl Fn(usize) -> Vec3) -> Vec<Vec3> {
        let tris = &model.triangles;
        self.bindings
            .iter()
            .map(|b| {
                let t = tris[b.triangle as usize];
                (0..3).map(|k| field(t[k] as usize) * b.bary[k]).sum()
            })
            .collect()
    }

    /// Shape target `t`'s unit move at the template's bound points (before smoothing).
    fn target_bound(&self, model: &BodyModel, t: usize) -> Vec<Vec3> {
        let target = &model.targets[t];
        let mut delta = vec![Vec3::ZERO; model.base_vertices.len()];
        for (&i, &d) in target.indices.iter().zip(&target.deltas) {
            delta[i as usize] += d;
        }
        self.bound(model, |i| delta[i])
    }

    /// The DQS warp `M = dqs(M0, body)` of the paper: the template reshaped to the body
    /// ([`Self::reshape`]) and posed with dual quaternion skinning by its weights and the
    /// posed body's skinning transforms.
    pub fn warp(
        &self,
        canonical: &ShapedBody<'_>,
        shaped: &ShapedBody<'_>,
        posed: &PosedBody,
    ) -> Vec<Vec3> {
        skinning::dqs(
            &self.reshape(canonical, shaped),
            &self.skin,
            &posed.skinning,
        )
    }
}
