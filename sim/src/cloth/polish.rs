//! The strain polish: the solver's sag taken out of a drape at rest.
//!
//! A few Gauss-Seidel sweeps per substep leave cloth that hangs `N` edges below its support
//! stretched by about `g h^2 N^2` (docs/sim.md, "Open problems"): the rest state of a drape
//! is the solver's fixed point, not the membrane's, whose compliance (1e-6 m/N) would let
//! it stretch by a fraction of a per mille. Once a drape has come to rest, [`polish`] takes
//! that stretch out where gravity put it, in the manner of strain limiting (Provot 1995):
//!
//! - Particles within `thickness` + [`CONTACT_BAND`] of the body are held: friction holds
//!   them where they came to rest, and the fit's tension over the body (an opening pulled
//!   over the hips) is the garment's, not the solver's. So is a pinned particle.
//! - Every other particle is moved by sweeps over the stretch constraints in their colour
//!   order: an edge longer than its rest length is projected back to it (zero compliance,
//!   shared by inverse mass; shorter edges are left alone: cloth buckles). No gravity and
//!   no inertia: the shape the drape came to rest in stays, its hanging parts shorten.
//! - The sweeps stop after `max_sweeps`, or when no particle moved more than
//!   [`TOLERANCE`] in a sweep. A particle that came within `thickness` of the body is put
//!   back at `thickness` along the pseudo-normal.
//!
//! Deterministic (one thread, fixed order). Measured on the 10k T-shirt (`drape bench sim`,
//! random:9 to 11) at 100 sweeps: p95 strain 3.03%, 2.29%, 1.21% before, 1.91%, 1.21%, 1.00%
//! after, particles moved 0.1 to 0.3 mm on average and at most 4.5 mm (docs/sim.md).

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;

use super::collision::BodyCollider;
use super::constraints::distance::Kind;
use super::model::ClothModel;

/// Particles closer to the body than `thickness` plus this are held (m).
pub const CONTACT_BAND: f32 = 0.002;

/// A sweep that moves no particle by more than this ends the polish (m).
pub const TOLERANCE: f32 = 1e-6;

/// Clearance searched around a particle that may move (m): a particle that moves less than
/// its clearance minus `thickness` cannot have come within `thickness` of the body.
const CLEARANCE_RADIUS: f32 = 0.05;

/// What the polish did.
#[derive(Debug, Clone, Copy, PartialEq, Default, Serialize)]
pub struct PolishStats {
    /// Sweeps run.
    pub sweeps: u32,
    /// Particles held (near the body or pinned).
    pub held: usize,
    /// p95 edge strain before the polish.
    pub strain_p95_before: f32,
    /// Mean distance a particle moved (m; over all particles).
    pub mean_move: f32,
    /// Largest distance a particle moved (m).
    pub max_move: f32,
    /// Particles put back at `thickness` from the body after the sweeps.
    pub pushed_out: usize,
    /// Wall time (s).
    pub time: f64,
}

/// Polishes the rest state `x` of `model` on `body` (see the module documentation): at
/// most `max_sweeps` sweeps, the queries on rayon's threads when `parallel`.
pub fn polish(
    model: &ClothModel,
    body: &BodyCollider,
    x: &mut [Vec3],
    thickness: f32,
    max_sweeps: u32,
    parallel: bool,
) -> PolishStats {
    let t = Instant::now();
    let strain_p95_before = super::drape::strain(model, x).p95;
    let reach = thickness + CONTACT_BAND;
    // Signed distance to the body within the clearance radius (None: farther).
    let distance = |p: &Vec3| body.closest(*p, CLEARANCE_RADIUS).map(|h| h.distance);
    let clearance: Vec<Option<f32>> = if parallel {
        x.par_iter().map(distance).collect()
    } else {
        x.iter().map(distance).collect()
    };
    let w: Vec<f32> = model
        .inv_mass
        .iter()
        .zip(&clearance)
        .map(|(&w, c)| match c {
            Some(d) if *d < reach => 0.0,
            _ => w,
        })
        .collect();
    let held = w.iter().filter(|&&w| w == 0.0).count();
    // The stretch constraints with a particle free to move, in colour order.
    let edges: Vec<(usize, usize, f32)> = model
        .distance
        .iter()
        .zip(&model.distance_kind)
        .filter(|(c, k)| **k == Kind::Stretch && w[c.i as usize] + w[c.j as usize] > 0.0)
        .map(|(c, _)| (c.i as usize, c.j as usize, c.rest))
        .collect();
    let x0 = x.to_vec();
    let mut sweeps = 0;
    while sweeps < max_sweeps {
        sweeps += 1;
        let mut largest = 0.0f32;
        for &(i, j, rest) in &edges {
            let d = x[i] - x[j];
            let len = d.length();
            if len <= rest {
                continue;
            }
            let (wi, wj) = (w[i], w[j]);
            let corr = d * ((len - rest) / (len * (wi + wj)));
            x[i] -= corr * wi;
            x[j] += corr * wj;
            largest = largest.max((len - rest) * wi.max(wj) / (wi + wj));
        }
        if largest < TOLERANCE {
            break;
        }
    }
    // Back out of the thickness where a particle moved towards the body.
    let mut pushed_out = 0;
    for ((p, p0), c) in x.iter_mut().zip(&x0).zip(&clearance) {
        let moved = p.distance(*p0);
        if moved == 0.0 || moved < c.unwrap_or(CLEARANCE_RADIUS) - thickness {
            continue;
        }
        if let Some(h) = body.closest(*p, CLEARANCE_RADIUS) {
            if h.distance < thickness {
                *p = h.point + h.normal * thickness;
                pushed_out += 1;
            }
        }
    }
    let moves = x.iter().zip(&x0).map(|(a, b)| a.distance(*b));
    let (sum, max_move) = moves.fold((0.0f32, 0.0f32), |(s, m), d| (s + d, m.max(d)));
    PolishStats {
        sweeps,
        held,
        strain_p95_before,
        mean_move: sum / x.len().max(1) as f32,
        max_move,
        pushed_out,
        time: t.elapsed().as_secs_f64(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cloth::SimConfig;
    use crate::mesh::primitives;

    /// A 0.4 x 0.4 m cloth of 20 x 20 cells hanging in the x-y plane, its top row pinned
    /// (grid row 20), every particle moved down so that each row is `stretch` longer.
    fn hanging(stretch: f32) -> (ClothModel, Vec<Vec3>, Vec<u32>) {
        let mesh = primitives::grid(
            Vec3::new(0.0, -0.4, 0.0),
            Vec3::X * 0.4,
            Vec3::Y * 0.4,
            20,
            20,
        );
        let top: Vec<u32> = (0..=20).map(|i| 20 * 21 + i).collect();
        let model = ClothModel::new(&mesh, &SimConfig::default(), &top).unwrap();
        let x = mesh
            .vertices
            .iter()
            .map(|p| Vec3::new(p.x, p.y * (1.0 + stretch), p.z))
            .collect();
        (model, x, top)
    }

    #[test]
    fn a_stretched_hanging_cloth_is_brought_back_to_its_rest_lengths() {
        let (model, mut x, top) = hanging(0.03);
        let before = x.clone();
        // A body far away: nothing is held but the pinned row.
        let ball = primitives::uv_sphere(Vec3::new(3.0, 0.0, 0.0), 0.1, 16, 8);
        let body = BodyCollider::new(&ball.vertices, &ball.triangles, 0.01);
        let s = polish(&model, &body, &mut x, 0.003, 5000, false);
        assert_eq!(s.held, top.len());
        assert!((s.strain_p95_before - 0.03).abs() < 1e-3, "{s:?}");
        let after = super::super::drape::strain(&model, &x);
        assert!(after.max < 1e-4, "{after:?} after {} sweeps", s.sweeps);
        assert!(s.sweeps < 5000, "stopped at the tolerance: {s:?}");
        for &i in &top {
            assert_eq!(x[i as usize], before[i as usize]);
        }
        // Rows shorten towards the pinned top: the bottom row rises by the 3% of 0.4 m.
        let bottom = x[0].y - before[0].y;
        assert!((bottom - 0.012).abs() < 5e-4, "bottom rose {bottom}");
        assert!(
            (s.max_move - bottom).abs() < 5e-4 && s.mean_move > 0.0,
            "{s:?}"
        );
        assert_eq!(s.pushed_out, 0);
    }

    #[test]
    fn particles_at_the_body_are_held_and_none_is_moved_into_it() {
        // A ball touching the cloth's lower left corner from behind (1 mm gap) and a second
        // one behind the middle of its lower rows hold the particles near them.
        let (model, mut x, top) = hanging(0.03);
        let before = x.clone();
        let r = 0.05;
        let mut balls = primitives::uv_sphere(Vec3::new(0.0, -0.412, -r - 0.004), r, 32, 16);
        let second = primitives::uv_sphere(Vec3::new(0.2, -0.39, -r - 0.001), r, 32, 16);
        let n = balls.vertices.len() as u32;
        balls.vertices.extend(&second.vertices);
        balls
            .triangles
            .extend(second.triangles.iter().map(|t| t.map(|i| i + n)));
        let body = BodyCollider::new(&balls.vertices, &balls.triangles, 0.01);
        let thickness = 0.003;
        let held: Vec<usize> = (0..x.len())
            .filter(|&i| {
                body.closest(x[i], 0.05)
                    .is_some_and(|h| h.distance < thickness + CONTACT_BAND)
            })
            .collect();
        assert!(held.contains(&0), "the corner touches the first ball");
        let s = polish(&model, &body, &mut x, thickness, 5000, true);
        assert_eq!(s.held, top.len() + held.len());
        for &i in &held {
            assert_eq!(x[i], before[i], "particle {i} is held");
        }
        // The moved ones end at least `thickness` from the body.
        for (i, p) in x.iter().enumerate().filter(|(i, _)| !held.contains(i)) {
            let d = body.closest(*p, 0.05).map_or(1.0, |h| h.distance);
            assert!(d >= thickness - 1e-5, "particle {i} at {d} from the body");
        }
        // The same on one thread.
        let mut y = before.clone();
        let t = polish(&model, &body, &mut y, thickness, 5000, false);
        assert_eq!(x, y);
        assert_eq!((s.sweeps, s.pushed_out), (t.sweeps, t.pushed_out));
    }
}
