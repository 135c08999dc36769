//! Drape protocols and the quality report.
//!
//! **Morph and settle** (the paper's PBS): the garment starts as its template on the
//! canonical body in the rest pose; the body morphs to the target shape and pose over
//! `morph_frames` frames, or more where a body vertex would otherwise move faster than
//! `max_morph_speed` on average (the two shaped bodies blended linearly, bones slerped
//! from rest);
//! then the body holds still and the cloth runs, at `settle_substeps` substeps a frame
//! (finer than the morph's: less sag in the rest state), until it is at rest (the largest per-frame
//! displacement below `rest_displacement` for `rest_frames` consecutive frames, at most
//! `max_frames` frames); a final pass pushes out particles left inside the body and
//! measures what remains.
//!
//! **Warm start** (the paper's PBS-dagger timing): the same with a static body already in
//! the target pose and a given starting state, e.g. the DQS warp of the template.

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;

use super::collision::{BodyCollider, Hit};
use super::model::ClothModel;
use super::polish::{self, PolishStats};
use super::solver::{Solver, StageTimes};
use super::thin::ThinParts;
use super::{SimConfig, SimError};
use crate::body::{BodyError, BodyModel, Pose, ShapeParams, ShapedBody};

/// How the body moves during a drape.
pub trait BodyMotion {
    /// Frames of motion (0 for a static body).
    fn frames(&self) -> u32;
    /// Body vertices after `k` of those frames (`k = 0` is the start).
    fn at(&self, k: u32) -> Vec<Vec3>;
    /// Body triangles (fixed topology).
    fn triangles(&self) -> &[[u32; 3]];
}

/// A body that does not move.
#[derive(Debug, Clone)]
pub struct StaticBody {
    /// Vertices (m).
    pub vertices: Vec<Vec3>,
    /// Triangles.
    pub triangles: Vec<[u32; 3]>,
}

impl BodyMotion for StaticBody {
    fn frames(&self) -> u32 {
        0
    }
    fn at(&self, _: u32) -> Vec<Vec3> {
        self.vertices.clone()
    }
    fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
}

/// Any motion given by a function of the frame.
pub struct FnMotion<F: Fn(u32) -> Vec<Vec3>> {
    /// Frames of motion.
    pub frames: u32,
    /// Vertices at frame k.
    pub at: F,
    /// Triangles.
    pub triangles: Vec<[u32; 3]>,
}

impl<F: Fn(u32) -> Vec<Vec3>> std::fmt::Debug for FnMotion<F> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FnMotion")
            .field("frames", &self.frames)
            .finish()
    }
}

impl<F: Fn(u32) -> Vec<Vec3>> BodyMotion for FnMotion<F> {
    fn frames(&self) -> u32 {
        self.frames
    }
    fn at(&self, k: u32) -> Vec<Vec3> {
        (self.at)(k)
    }
    fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }
}

/// The MakeHuman body morphing from one shape in the rest pose to another shape in a pose:
/// the two shaped bodies' vertices and joints blended linearly, every bone slerped from
/// rest to its target rotation.
#[derive(Debug, Clone)]
pub struct BodyMorph<'a> {
    /// The body model.
    pub model: &'a BodyModel,
    /// Target pose.
    pub pose: Pose,
    /// Frames of the morph ([`BodyMorph::new`] paces it).
    pub frames: u32,
    /// The starting shape (the canonical body, or a size's reference) and the target
    /// shape in the rest pose, made once.
    shaped: [ShapedBody<'a>; 2],
}

impl BodyMorph<'_> {
    /// Checks and makes both shapes once, so [`BodyMotion::at`] cannot fail and blends
    /// instead of reshaping every frame, and paces the morph: `config.morph_frames`
    /// frames, or more if a body vertex would otherwise travel faster than
    /// `config.max_morph_speed` on average (its straight distance from the start to the
    /// end of the morph over the morph's duration).
    ///
    /// Why: a hand rising at 2.5 m/s (an arm raised from the A-pose in the 60-frame
    /// morph's one second, smoothstep's peak) drags a sleeve's cuff faster than the
    /// constraint sweeps pass the pull up the sleeve; the cuff's edges stretch several
    /// times over and the hand slips between its particles, leaving the sleeve caught
    /// across the forearm. Measured on the sweater (docs/garments.md): edges through the
    /// body in 22% of 50 sampled drapes at 60 frames, none with the morph paced at 0.6 m/s.
    pub fn new<'m>(
        model: &'m BodyModel,
        from: ShapeParams,
        to: ShapeParams,
        pose: Pose,
        config: &SimConfig,
    ) -> Result<BodyMorph<'m>, BodyError> {
        let shaped = [model.shape(&from)?, model.shape(&to)?];
        let mut morph = BodyMorph {
            model,
            pose,
            frames: 1,
            shaped,
        };
        let (start, end) = (morph.at(0), morph.at(1));
        let distance = start
            .iter()
            .zip(&end)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0f32, f32::max);
        let paced = (distance * config.fps / config.max_morph_speed).ceil();
        morph.frames = config.morph_frames.max(paced.min(u32::MAX as f32) as u32);
        Ok(morph)
    }
}

impl BodyMotion for BodyMorph<'_> {
    fn frames(&self) -> u32 {
        self.frames
    }
    fn at(&self, k: u32) -> Vec<Vec3> {
        let t = if self.frames == 0 {
            1.0
        } else {
            (k as f32 / self.frames as f32).min(1.0)
        };
        // Smooth start and stop: the body accelerates and decelerates.
        let s = t * t * (3.0 - 2.0 * t);
        // `a (1 - s) + b s`: exactly the start at s = 0 and the target at s = 1.
        let [a, b] = &self.shaped;
        let mix = |p: &[Vec3], q: &[Vec3]| -> Vec<Vec3> {
            p.iter()
                .zip(q)
                .map(|(p, q)| *p * (1.0 - s) + *q * s)
                .collect()
        };
        let joints = mix(&a.joints, &b.joints);
        let body = ShapedBody {
            model: self.model,
            params: if s < 1.0 { a.params } else { b.params },
            vertices: mix(&a.vertices, &b.vertices),
            rest_frames: self.model.skeleton.rest_frames(&joints),
            joints,
        };
        let rest = Pose::rest(self.model.skeleton.len());
        body.pose(&rest.slerp(&self.pose, s)).vertices
    }
    fn triangles(&self) -> &[[u32; 3]] {
        &self.model.triangles
    }
}

/// Why a drape failed.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
#[serde(tag = "reason", rename_all = "snake_case")]
pub enum Failure {
    /// A position became NaN or infinite.
    NonFinite {
        /// Frame where it happened.
        frame: u32,
    },
    /// Particles moved absurdly far: faster than twice the speed limit for
    /// [`EXPLOSION_FRAMES`] frames in a row, or more than [`EXPLOSION_JUMP`] in one frame.
    Explosion {
        /// Frame where it happened.
        frame: u32,
        /// The largest displacement in that frame (m).
        displacement: f32,
    },
    /// The cloth did not come to rest within `max_frames`.
    NoConvergence {
        /// Largest displacement in the last frame (m).
        last_displacement: f32,
    },
    /// Too many particles were inside the body before the final push-out.
    PushedOut {
        /// How many.
        count: usize,
        /// Deepest (m).
        max_depth: f32,
    },
    /// Particles remained inside the body after the push-out.
    PenetrationsLeft {
        /// How many.
        count: usize,
        /// Deepest (m).
        max_depth: f32,
    },
    /// Edges pass through the body deeper than `max_edge_penetration` and than a quarter
    /// of their length inside it, with both ends outside it: the cloth is caught across a limb (a
    /// hand slipped between its particles), which the particle checks do not see.
    CaughtOnBody {
        /// Edges caught so.
        count: usize,
        /// Deepest point along one of them (m).
        max_depth: f32,
    },
    /// The garment slid down the body: its top opening (a neckline, a waistband) came to
    /// rest more than [`MAX_TOP_DROP`] below where the DQS warp puts it (judged by callers
    /// that have the warp, [`DrapeReport::judge_top_drop`]).
    SlidDown {
        /// How far below the warp's (m, mean over the opening's vertices).
        drop: f32,
    },
}

/// How far a garment's top opening may come to rest below the DQS warp's before the drape
/// counts as slid down (m). 10k jeans hanging from the hips end 4 to 16 cm below the warp's
/// waistband, fallen ones 38 cm or more (docs/garments.md, "Sliding").
pub const MAX_TOP_DROP: f32 = 0.25;

impl std::fmt::Display for Failure {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Failure::NonFinite { frame } => write!(f, "non-finite positions at frame {frame}"),
            Failure::Explosion {
                frame,
                displacement,
            } => {
                write!(
                    f,
                    "explosion at frame {frame} (a particle moved {displacement:.2} m)"
                )
            }
            Failure::NoConvergence { last_displacement } => {
                write!(
                    f,
                    "no convergence (last frame moved {:.2} mm)",
                    last_displacement * 1e3
                )
            }
            Failure::PushedOut { count, max_depth } => write!(
                f,
                "{count} particles were inside the body before the final push-out (deepest {:.2} mm)",
                max_depth * 1e3
            ),
            Failure::PenetrationsLeft { count, max_depth } => write!(
                f,
                "{count} particles left inside the body (deepest {:.2} mm)",
                max_depth * 1e3
            ),
            Failure::CaughtOnBody { count, max_depth } => write!(
                f,
                "caught on the body ({count} edges through a part of it with both ends outside, deepest {:.1} mm)",
                max_depth * 1e3
            ),
            Failure::SlidDown { drop } => write!(
                f,
                "slid down the body (the top opening came to rest {:.1} cm below the DQS warp's)",
                drop * 1e2
            ),
        }
    }
}

/// Edge strain `l / l0 - 1` over the mesh edges.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct StrainStats {
    /// Mean.
    pub mean: f32,
    /// 95th percentile.
    pub p95: f32,
    /// Largest.
    pub max: f32,
    /// Share of edges stretched more than 1%.
    pub over_1pct: f32,
    /// Share of edges stretched more than 5%.
    pub over_5pct: f32,
    /// Edges at twice their rest length or more (strain 100% and over).
    pub doubled: usize,
}

/// Particles inside the body.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct PenetrationStats {
    /// Particles with a negative signed distance to the body.
    pub count: usize,
    /// Deepest (m).
    pub max_depth: f32,
    /// Mean depth of those particles (m).
    pub mean_depth: f32,
}

/// Everything measured about one drape.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct DrapeReport {
    /// True if the cloth came to rest and no particle is left inside the body (and, where
    /// judged, it did not slide down the body: [`Self::judge_top_drop`]).
    pub converged: bool,
    /// Why not, when not.
    pub failure: Option<Failure>,
    /// Particles of the cloth.
    pub particles: usize,
    /// Constraints: stretch, shear, bend, dihedral.
    pub constraints: [usize; 4],
    /// Colours of the distance constraints.
    pub colours: usize,
    /// Frames of body motion.
    pub morph_frames: u32,
    /// Frames after the motion until at rest (or the cap).
    pub settle_frames: u32,
    /// Substeps run in total.
    pub substeps: u64,
    /// Half-sweeps solved by the second thread (0 on one thread): how much of the sweeps
    /// ran on both cores.
    pub helper_half_sweeps: u64,
    /// Wall time of the whole drape (s).
    pub wall_time: f64,
    /// Wall time per stage (s).
    pub stage_times: StageTimes,
    /// Wall time of the final push-out and verification (s).
    pub verify_time: f64,
    /// Residual edge strain.
    pub strain: StrainStats,
    /// Particles inside the body before the final push-out.
    pub penetration_before_pushout: PenetrationStats,
    /// Particles inside the body after it.
    pub penetration: PenetrationStats,
    /// Edges through the body after it: a point along them deeper than `max_penetration`
    /// inside, both ends possibly outside ([`edges_through_body`]).
    pub edges_through_body: PenetrationStats,
    /// Kinetic energy at the end (J).
    pub kinetic_energy: f32,
    /// Largest displacement in the last frame (m).
    pub last_displacement: f32,
    /// How far the garment's top opening came to rest below the DQS warp's (m; None when
    /// the caller did not judge it: `drape sim` does not). `drape gen` compares with the
    /// base template's warp (the network's M), `garment check` and `gallery` with the
    /// worn size's.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub top_drop: Option<f32>,
    /// What the strain polish did (None when it did not run: `polish_sweeps` = 0, or the
    /// drape failed before it). `strain` is measured after it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub polish: Option<PolishStats>,
    /// The edge contacts on the body's thin parts (None when off: `thin_part_thickness` =
    /// 0, or the body has none).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub thin_parts: Option<ThinStats>,
    /// Whether the drape was still moving after `stall_frames` settling frames and settled
    /// on with twice the stretch sweeps (`SimConfig::stall_frames`).
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub stalled: bool,
}

/// What the edge contacts on the body's thin parts did in one drape (`thin.rs`).
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct ThinStats {
    /// Body triangles under which the body is thinner than `thin_part_thickness`.
    pub triangles: usize,
    /// Edge midpoints pushed out of them (one per edge and substep).
    pub edge_pushes: u64,
}

impl DrapeReport {
    /// Records how far the top opening came to rest below the DQS warp's (see
    /// [`top_drop`]); beyond [`MAX_TOP_DROP`] a drape that had not failed otherwise
    /// fails as slid down: it came to rest, but not on the body.
    pub fn judge_top_drop(&mut self, drop: f32) {
        self.top_drop = Some(drop);
        if self.failure.is_none() && (drop.is_nan() || drop > MAX_TOP_DROP) {
            self.failure = Some(Failure::SlidDown { drop });
            self.converged = false;
        }
    }
}

/// How far the top opening `top` (`Template::top_opening`) of a drape came to rest below
/// the DQS warp's (m; mean over its vertices of the height difference). The warp carries
/// the opening to where the body holds it, so a large drop means the garment slid down.
pub fn top_drop(top: &[u32], warp: &[Vec3], drape: &[Vec3]) -> f32 {
    top.iter()
        .map(|&v| warp[v as usize].y - drape[v as usize].y)
        .sum::<f32>()
        / top.len().max(1) as f32
}

/// Final positions and the report.
#[derive(Debug, Clone)]
pub struct DrapeResult {
    /// Particle positions (m).
    pub positions: Vec<Vec3>,
    /// Quality and timing.
    pub report: DrapeReport,
    /// The edges through the body that the verification found (the report counts them),
    /// each with its depth and body triangle.
    pub edges_through_body: Vec<EdgeThrough>,
}

impl DrapeResult {
    /// Judges whether the garment slid down the body: its top opening `top` against the
    /// DQS warp `warp` of the same body and pose ([`top_drop`],
    /// [`DrapeReport::judge_top_drop`]).
    pub fn judge_slide(&mut self, top: &[u32], warp: &[Vec3]) {
        self.report
            .judge_top_drop(top_drop(top, warp, &self.positions));
    }
}

/// What the progress callback sees after each frame.
#[derive(Debug, Clone, Copy)]
pub struct Progress {
    /// Frames done (motion and settling).
    pub frame: u32,
    /// True during the body motion.
    pub morphing: bool,
    /// Largest displacement of this frame (m).
    pub max_displacement: f32,
    /// Kinetic energy (J).
    pub kinetic_energy: f32,
}

/// Each mesh edge's particles and its strain `l / l0 - 1` at positions `x`.
fn edge_strains<'a>(
    model: &'a ClothModel,
    x: &'a [Vec3],
) -> impl Iterator<Item = ([usize; 2], f32)> + 'a {
    model.edges.iter().map(|&[a, b]| {
        let (a, b) = (a as usize, b as usize);
        (
            [a, b],
            x[a].distance(x[b]) / model.rest[a].distance(model.rest[b]) - 1.0,
        )
    })
}

/// Every mesh edge's strain `l / l0 - 1` at positions `x`, in the model's edge order.
pub fn edge_strain_values(model: &ClothModel, x: &[Vec3]) -> Vec<f32> {
    edge_strains(model, x).map(|(_, e)| e).collect()
}

/// Edge strain statistics of positions `x`.
pub fn strain(model: &ClothModel, x: &[Vec3]) -> StrainStats {
    strain_stats(edge_strain_values(model, x))
}

/// Statistics of edge strains `s` (any edges: one drape's, or several drapes' pooled).
pub fn strain_stats(mut s: Vec<f32>) -> StrainStats {
    if s.is_empty() {
        return StrainStats::default();
    }
    s.sort_by(f32::total_cmp);
    let n = s.len() as f32;
    StrainStats {
        mean: s.iter().sum::<f32>() / n,
        p95: s[((0.95 * n) as usize).min(s.len() - 1)],
        max: s[s.len() - 1],
        over_1pct: s.iter().filter(|&&e| e > 0.01).count() as f32 / n,
        over_5pct: s.iter().filter(|&&e| e > 0.05).count() as f32 / n,
        doubled: s.iter().filter(|&&e| e >= 1.0).count(),
    }
}

/// Per particle, the largest strain `l / l0 - 1` of the edges that meet it (0 for a
/// particle on no edge): what a strain map colours.
pub fn vertex_strain(model: &ClothModel, x: &[Vec3]) -> Vec<f32> {
    let mut s = vec![f32::NEG_INFINITY; model.rest.len()];
    for ([a, b], e) in edge_strains(model, x) {
        s[a] = s[a].max(e);
        s[b] = s[b].max(e);
    }
    for v in &mut s {
        if *v == f32::NEG_INFINITY {
            *v = 0.0;
        }
    }
    s
}

/// Consecutive frames in which a particle outruns twice the speed limit that count as an
/// explosion.
pub const EXPLOSION_FRAMES: u32 = 3;

/// A displacement in one frame that counts as an explosion at once (m).
pub const EXPLOSION_JUMP: f32 = 1.0;

/// Radius within which the final pass looks for the body surface (m).
const VERIFY_RADIUS: f32 = 0.05;

/// Particles inside the body, at any depth: inside by ray parity, depth from the nearest
/// surface point within 5 cm (deeper ones count with a depth of at least 5 cm).
pub fn penetration(body: &BodyCollider, x: &[Vec3]) -> PenetrationStats {
    penetration_stats(
        x.iter()
            .filter_map(|p| depth(body, *p, body.closest(*p, VERIFY_RADIUS).as_ref())),
    )
}

/// An edge of the cloth that passes through the body (see [`edges_through_body`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct EdgeThrough {
    /// Index into the edge list.
    pub edge: usize,
    /// Depth of its deepest sample point inside the body (m).
    pub depth: f32,
    /// Body triangle nearest to that point (`None` when it is deeper than the 5 cm search
    /// and found by ray parity).
    pub tri: Option<u32>,
}

/// Edges of the cloth that pass through the body: a point at a quarter, half or three
/// quarters along lies deeper than `tolerance` inside it, while the ends may both be
/// outside (cloth caught on both sides of a limb, which the particle checks do not see).
/// In edge order, each with its deepest point's depth and body triangle; `parallel` uses
/// rayon's threads (the same result).
pub fn edges_through_body(
    body: &BodyCollider,
    edges: &[[u32; 2]],
    x: &[Vec3],
    tolerance: f32,
    parallel: bool,
) -> Vec<EdgeThrough> {
    let through = |(edge, [a, b]): (usize, &[u32; 2])| {
        let (p, q) = (x[*a as usize], x[*b as usize]);
        [0.25f32, 0.5, 0.75]
            .iter()
            .filter_map(|t| {
                let m = p.lerp(q, *t);
                let hit = body.closest(m, VERIFY_RADIUS);
                depth(body, m, hit.as_ref()).map(|depth| EdgeThrough {
                    edge,
                    depth,
                    tri: hit.map(|h| h.contact.tri),
                })
            })
            .filter(|e| e.depth > tolerance)
            .max_by(|a, b| a.depth.total_cmp(&b.depth))
    };
    if parallel {
        edges.par_iter().enumerate().filter_map(through).collect()
    } else {
        edges.iter().enumerate().filter_map(through).collect()
    }
}

/// Length of the segment from `p` to `q` inside the body, from 64 points along it.
fn length_inside(body: &BodyCollider, p: Vec3, q: Vec3) -> f32 {
    const N: usize = 64;
    let inside = (0..N)
        .filter(|&k| {
            let m = p.lerp(q, (k as f32 + 0.5) / N as f32);
            depth(body, m, body.closest(m, VERIFY_RADIUS).as_ref()).is_some()
        })
        .count();
    p.distance(q) * inside as f32 / N as f32
}

/// How deep `p` is inside the body (`None` outside), given its nearest surface point within
/// [`VERIFY_RADIUS`] (`hit`, if any): as [`penetration`] counts it.
fn depth(body: &BodyCollider, p: Vec3, hit: Option<&Hit>) -> Option<f32> {
    match hit.map(|h| h.distance) {
        Some(d) if d < 0.0 => Some(-d),
        Some(_) => None,
        None => body.inside(p).then_some(VERIFY_RADIUS),
    }
}

/// Count, largest and mean of `depths` (summed in the order given).
fn penetration_stats(depths: impl Iterator<Item = f32>) -> PenetrationStats {
    let depths: Vec<f32> = depths.collect();
    PenetrationStats {
        count: depths.len(),
        max_depth: depths.iter().copied().fold(0.0, f32::max),
        mean_depth: if depths.is_empty() {
            0.0
        } else {
            depths.iter().sum::<f32>() / depths.len() as f32
        },
    }
}

/// The final pass: pushes particles found inside the body out to `thickness` along the
/// nearest surface point's pseudo-normal; returns the penetrations before and after. Each
/// particle's nearest surface point is searched once (on rayon's threads if `parallel`),
/// and again after the push only for the particles pushed.
fn push_out(
    body: &BodyCollider,
    x: &mut [Vec3],
    thickness: f32,
    parallel: bool,
) -> (PenetrationStats, PenetrationStats) {
    let hits: Vec<Option<Hit>> = if parallel {
        x.par_iter()
            .map(|p| body.closest(*p, VERIFY_RADIUS))
            .collect()
    } else {
        x.iter().map(|p| body.closest(*p, VERIFY_RADIUS)).collect()
    };
    let before: Vec<Option<f32>> = x
        .iter()
        .zip(&hits)
        .map(|(p, h)| depth(body, *p, h.as_ref()))
        .collect();
    let mut after = before.clone();
    for ((p, hit), after) in x.iter_mut().zip(&hits).zip(after.iter_mut()) {
        if let Some(hit) = hit
            && hit.distance < 0.0
        {
            *p = hit.point + hit.normal * thickness;
            *after = depth(body, *p, body.closest(*p, VERIFY_RADIUS).as_ref());
        }
    }
    (
        penetration_stats(before.into_iter().flatten()),
        penetration_stats(after.into_iter().flatten()),
    )
}

/// Checks that a garment is placed around a body: at least 30% of its particles within
/// 10 cm of the body, at most 5% inside it.
pub fn check_placement(body: &BodyCollider, x: &[Vec3]) -> Result<(), SimError> {
    let near: Vec<f32> = x
        .iter()
        .filter_map(|p| body.signed_distance(*p, 0.1))
        .collect();
    let share_near = near.len() as f32 / x.len().max(1) as f32;
    if share_near < 0.3 {
        return Err(SimError::Placement(format!(
            "only {:.0}% of the garment lies within 10 cm of the body; it must be placed around the body in its rest pose",
            share_near * 100.0
        )));
    }
    let inside = near.iter().filter(|d| **d < 0.0).count() as f32 / x.len() as f32;
    if inside > 0.05 {
        return Err(SimError::Placement(format!(
            "{:.0}% of the garment starts inside the body (at most 5% allowed)",
            inside * 100.0
        )));
    }
    Ok(())
}

/// A drape from a state of the cloth with the body already in its target shape and pose
/// (`body` vertices over `triangles`, standing still): the paper's PBS-dagger when `start`
/// is the DQS warp. As [`drape`] otherwise, with no progress reports.
pub fn drape_from_state(
    model: &ClothModel,
    start: &[Vec3],
    body: &[Vec3],
    triangles: &[[u32; 3]],
    config: &SimConfig,
    parallel: bool,
) -> DrapeResult {
    let still = StaticBody {
        vertices: body.to_vec(),
        triangles: triangles.to_vec(),
    };
    drape(model, start, &still, config, parallel, &mut |_| {})
}

/// Runs a drape: `start` positions, the body's motion, then settling, push-out and the
/// report. `parallel` lets a frame use rayon's threads; the result is the same either way.
///
/// # Panics
/// If `config` is not valid, or the cloth's own substeps do not fit it
/// ([`ClothModel::drape_config`]; a cloth from `Template::cloth` was checked against the
/// config it was made with).
pub fn drape(
    model: &ClothModel,
    start: &[Vec3],
    motion: &dyn BodyMotion,
    config: &SimConfig,
    parallel: bool,
    progress: &mut dyn FnMut(&Progress),
) -> DrapeResult {
    debug_assert!(
        config.validate().is_ok(),
        "drape() needs a validated SimConfig"
    );
    // A garment's own substeps (`ClothModel::substeps`), checked against the same config
    // by `Template::cloth`.
    let own = model
        .drape_config(config)
        .expect("the garment's own substeps fit the config (Template::cloth checks it)");
    let config = &own;
    let t_all = Instant::now();
    let t = Instant::now();
    let mut body = BodyCollider::new(&motion.at(0), motion.triangles(), config.margin);
    body.set_parallel(parallel && rayon::current_num_threads() > 1);
    // The body's thin parts, for the edges' contacts (`thin.rs`), found on the first frame.
    let mut thin = (config.thin_part_thickness > 0.0)
        .then(|| ThinParts::new(&body, config.thin_part_thickness))
        .flatten();
    let mut solver = Solver::new(model, config, start.to_vec());
    solver.parallel = parallel;
    solver.times.body += t.elapsed().as_secs_f64();

    // One frame: step, report progress, catch non-finite values and explosions: a particle
    // moving twice as far in a frame as the speed limit allows, for EXPLOSION_FRAMES frames
    // in a row, or EXPLOSION_JUMP in one. The grace frames let the constraints repair a
    // distorted start: a DQS warp stretches armpit edges up to 16 times their rest length,
    // and pulling them back moves particles 0.2-0.25 m in the first frame and under the
    // speed limit's bound from the second on (measured on cpu-reference test samples).
    let explosion = 2.0 * config.max_velocity * config.frame_dt();
    let mut frame = 0u32;
    let mut fast = 0u32;
    let mut step =
        |solver: &mut Solver<'_>, body: &BodyCollider, thin: Option<&ThinParts>, morphing: bool| {
            let stats = solver.frame_with(body, thin);
            frame += 1;
            fast = if stats.max_displacement > explosion {
                fast + 1
            } else {
                0
            };
            progress(&Progress {
                frame,
                morphing,
                max_displacement: stats.max_displacement,
                kinetic_energy: stats.kinetic_energy,
            });
            if !stats.finite {
                Err(Failure::NonFinite { frame })
            } else if fast >= EXPLOSION_FRAMES || stats.max_displacement > EXPLOSION_JUMP {
                Err(Failure::Explosion {
                    frame,
                    displacement: stats.max_displacement,
                })
            } else {
                Ok(stats)
            }
        };
    let mut failure = None;
    let mut last = (f32::MAX, 0.0f32);
    for k in 1..=motion.frames() {
        let t = Instant::now();
        body.advance(&motion.at(k));
        if let Some(thin) = &mut thin {
            thin.advance(body.positions());
        }
        solver.times.body += t.elapsed().as_secs_f64();
        match step(&mut solver, &body, thin.as_ref(), true) {
            Ok(stats) => last = (stats.max_displacement, stats.kinetic_energy),
            Err(f) => {
                failure = Some(f);
                break;
            }
        }
    }
    let mut settle = 0u32;
    let mut stalled = false;
    if failure.is_none() {
        body.hold();
        if let Some(thin) = &mut thin {
            thin.hold();
        }
        // The body stands still from here on: the rest state's sag falls with the substep.
        solver.set_substeps(config.settle_substeps);
        let mut calm = 0u32;
        while settle < config.max_frames && calm < config.rest_frames {
            if config.stall_frames > 0 && settle == config.stall_frames {
                // Still moving: a limit cycle of the solve is likely; a different sweep
                // count breaks it (`SimConfig::stall_frames`).
                solver.set_stretch_iterations(2 * config.stretch_iterations);
                stalled = true;
            }
            settle += 1;
            match step(&mut solver, &body, thin.as_ref(), false) {
                Ok(stats) => {
                    last = (stats.max_displacement, stats.kinetic_energy);
                    calm = if stats.max_displacement < config.rest_displacement {
                        calm + 1
                    } else {
                        0
                    };
                }
                Err(f) => {
                    failure = Some(f);
                    break;
                }
            }
        }
        if failure.is_none() && calm < config.rest_frames {
            failure = Some(Failure::NoConvergence {
                last_displacement: last.0,
            });
        }
    }

    let mut x = solver.positions();
    let finite = x.iter().all(|p| p.is_finite());
    // The strain polish of a drape at rest.
    let polished = (failure.is_none() && finite && config.polish_sweeps > 0).then(|| {
        polish::polish(
            model,
            &body,
            &mut x,
            config.thickness,
            config.polish_sweeps,
            parallel,
        )
    });

    // Push-out and verification.
    let t = Instant::now();
    let (before, after) = if finite {
        push_out(&body, &mut x, config.thickness, parallel)
    } else {
        Default::default()
    };
    let through = if finite {
        edges_through_body(&body, &model.edges, &x, config.max_penetration, parallel)
    } else {
        Vec::new()
    };
    // Caught across a part of the body: deeper than `max_edge_penetration` and than a
    // quarter of the edge's length inside the body. A chord at depth d through a round
    // part of radius R is 2 sqrt(2Rd - d^2) long inside it: d exceeds a quarter of that
    // only for d > 0.4 R, an edge through the part's core. Shallower dips are tight cloth
    // over a curve (a coarse mesh's 4 cm edges over a 4 cm arm: 5 mm deep, 2.8 cm inside).
    let caught: Vec<f32> = through
        .iter()
        .filter(|e| {
            let [a, b] = model.edges[e.edge];
            e.depth > config.max_edge_penetration
                && e.depth > 0.25 * length_inside(&body, x[a as usize], x[b as usize])
        })
        .map(|e| e.depth)
        .collect();
    let through_stats = penetration_stats(through.iter().map(|e| e.depth));
    let verify_time = t.elapsed().as_secs_f64();
    if failure.is_none() && after.count > 0 && after.max_depth > config.max_penetration {
        failure = Some(Failure::PenetrationsLeft {
            count: after.count,
            max_depth: after.max_depth,
        });
    }
    // The push-out repairs a few particles; a drape that needed it for many was not
    // penetration-free and is not ground truth.
    let allowed = (config.max_pushout_share * model.len() as f32).floor() as usize;
    if failure.is_none() && before.count > allowed && before.max_depth > config.max_penetration {
        failure = Some(Failure::PushedOut {
            count: before.count,
            max_depth: before.max_depth,
        });
    }
    if failure.is_none() && !caught.is_empty() {
        failure = Some(Failure::CaughtOnBody {
            count: caught.len(),
            max_depth: caught.iter().copied().fold(0.0, f32::max),
        });
    }
    let report = DrapeReport {
        converged: failure.is_none(),
        failure,
        particles: model.len(),
        constraints: {
            let [stretch, shear, bend] = model.kind_counts();
            [stretch, shear, bend, model.dihedral.len()]
        },
        colours: model.distance_colours.len(),
        morph_frames: motion.frames(),
        settle_frames: settle,
        substeps: solver.substeps_run,
        helper_half_sweeps: solver.helper_half_sweeps,
        wall_time: t_all.elapsed().as_secs_f64(),
        stage_times: solver.times,
        verify_time,
        strain: strain(model, &x),
        penetration_before_pushout: before,
        penetration: after,
        edges_through_body: through_stats,
        kinetic_energy: last.1,
        last_displacement: last.0,
        top_drop: None,
        polish: polished,
        thin_parts: thin.as_ref().map(|t| ThinStats {
            triangles: t.len(),
            edge_pushes: solver.edge_pushes,
        }),
        stalled,
    };
    DrapeResult {
        positions: x,
        report,
        edges_through_body: through,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives;

    fn report(failure: Option<Failure>) -> DrapeReport {
        DrapeReport {
            converged: failure.is_none(),
            failure,
            particles: 0,
            constraints: [0; 4],
            colours: 0,
            morph_frames: 0,
            settle_frames: 0,
            substeps: 0,
            helper_half_sweeps: 0,
            wall_time: 0.0,
            stage_times: Default::default(),
            verify_time: 0.0,
            strain: Default::default(),
            penetration_before_pushout: Default::default(),
            penetration: Default::default(),
            edges_through_body: Default::default(),
            kinetic_energy: 0.0,
            last_displacement: 0.0,
            top_drop: None,
            polish: None,
            thin_parts: None,
            stalled: false,
        }
    }

    #[test]
    fn a_drape_fails_as_slid_down_beyond_the_top_drop_limit_only() {
        // Up to the limit (and a neckline risen above the warp's) it stays converged.
        for drop in [-0.05, 0.0, 0.1, MAX_TOP_DROP] {
            let mut r = report(None);
            r.judge_top_drop(drop);
            assert!(r.converged && r.failure.is_none(), "{drop}");
            assert_eq!(r.top_drop, Some(drop));
        }
        // Beyond it, or unmeasurable, it fails and says by how much.
        for drop in [MAX_TOP_DROP + 0.01, 1.6, f32::NAN] {
            let mut r = report(None);
            r.judge_top_drop(drop);
            assert!(!r.converged, "{drop}");
            let text = r.failure.unwrap().to_string();
            assert!(text.starts_with("slid down the body"), "{text}");
        }
        let mut r = report(None);
        r.judge_top_drop(1.606);
        assert!(r.failure.unwrap().to_string().contains("160.6 cm below"));
        // An earlier failure is the one reported.
        let mut r = report(Some(Failure::NoConvergence {
            last_displacement: 0.002,
        }));
        r.judge_top_drop(1.0);
        assert!(matches!(r.failure, Some(Failure::NoConvergence { .. })));
        assert_eq!(r.top_drop, Some(1.0));
        // It serialises with its reason; an unjudged report has no top_drop.
        let mut r = report(None);
        assert!(serde_json::to_value(&r).unwrap().get("top_drop").is_none());
        r.judge_top_drop(0.5);
        let v = serde_json::to_value(&r).unwrap();
        assert_eq!(v["failure"]["reason"], "slid_down");
        assert!((v["top_drop"].as_f64().unwrap() - 0.5).abs() < 1e-6);
    }

    #[test]
    fn an_edge_through_a_limb_is_found_where_its_ends_are_outside() {
        // A 4 cm thick limb (a sphere here); particles 5 mm outside it.
        let sphere = primitives::uv_sphere(Vec3::ZERO, 0.02, 48, 24);
        let body = BodyCollider::new(&sphere.vertices, &sphere.triangles, 0.01);
        let x = vec![
            Vec3::new(-0.025, 0.0, 0.0),
            Vec3::new(0.025, 0.0, 0.0),
            Vec3::new(-0.025, 0.03, 0.0),
            Vec3::new(0.025, 0.03, 0.0),
            Vec3::new(0.0, 0.025, 0.0),
        ];
        assert!(
            x.iter()
                .all(|p| body.closest(*p, 0.05).unwrap().distance > 0.004)
        );
        // Across the limb: through it. Above it, and from the top down to touching: not.
        let edges = [[0, 1], [2, 3], [4, 2]];
        assert_eq!(
            edges_through_body(&body, &edges[..1], &x, 0.001, false).len(),
            1
        );
        assert_eq!(
            edges_through_body(&body, &edges[1..], &x, 0.001, true).len(),
            0
        );
        let through = edges_through_body(&body, &edges, &x, 0.001, false);
        assert_eq!(through, edges_through_body(&body, &edges, &x, 0.001, true));
        assert_eq!(through.len(), 1);
        // Its deepest point is the middle: the sphere's centre, 2 cm deep.
        assert_eq!(through[0].edge, 0);
        assert!((through[0].depth - 0.02).abs() < 1e-3, "{:?}", through[0]);
        assert!(through[0].tri.is_some());
        // A tolerance deeper than the limb's half thickness finds nothing.
        assert_eq!(edges_through_body(&body, &edges, &x, 0.03, true).len(), 0);
    }

    #[test]
    fn push_out_reuses_searches_and_counts_as_penetration_does() {
        let sphere = primitives::uv_sphere(Vec3::ZERO, 0.3, 48, 24);
        let body = BodyCollider::new(&sphere.vertices, &sphere.triangles, 0.01);
        // Points on rays from the centre at depths from 8 cm inside to 8 cm outside: some
        // beyond the 5 cm search (deep inside: found by ray parity; far outside: none).
        let x0: Vec<Vec3> = (0..200)
            .map(|k| {
                let t = k as f32;
                let dir =
                    Vec3::new((t * 0.37).sin(), (t * 0.91).cos(), (t * 0.53).sin()).normalize();
                dir * (0.3 + 0.08 * ((t * 0.61).sin()))
            })
            .collect();
        for parallel in [false, true] {
            let mut x = x0.clone();
            let (before, after) = push_out(&body, &mut x, 0.003, parallel);
            assert_eq!(before, penetration(&body, &x0));
            assert_eq!(after, penetration(&body, &x));
            assert!(
                before.count > 40 && before.max_depth == VERIFY_RADIUS,
                "{before:?}"
            );
            // Pushed: those within 5 cm inside, to 3 mm outside; deeper ones stay inside.
            let deep = x0
                .iter()
                .filter(|p| p.length() < 0.3 - VERIFY_RADIUS)
                .count();
            assert!(deep > 0);
            assert_eq!(after.count, deep, "{after:?}");
            for (p, q) in x0.iter().zip(&x) {
                if p != q {
                    assert!((q.length() - 0.303).abs() < 2e-3, "{p} -> {q}");
                }
            }
        }
    }
}
