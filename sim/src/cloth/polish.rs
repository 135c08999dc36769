//! The strain polish: the solver's sag taken out of a drape at rest.
//!
//! A few Gauss-Seidel sweeps per substep leave cloth that hangs `N` edges below its support
//! stretched by about `g h^2 N^2` (docs/sim.md, "Open problems"): the rest state of a drape
//! is the solver's fixed point, not the membrane's, whose compliance (1e-6 m/N) would let
//! it stretch by a fraction of a per mille. Once a drape has come to rest, [`polish`] takes
//! that stretch out where gravity put it, in the manner of strain limiting (Provot 1995):
//!
//! - Particles off the body are moved by sweeps over the stretch constraints in their
//!   colour order: an edge longer than its rest length is projected back to it (zero
//!   compliance, shared by inverse mass; shorter edges are left alone: cloth buckles). In
//!   these sweeps the particles at the body (within `thickness` + [`CONTACT_BAND`]) and
//!   pinned ones do not move. No gravity and no inertia: the shape the drape came to rest
//!   in stays, its hanging parts shorten.
//! - After each sweep the particles at the body, one after the other, slide on it under
//!   Coulomb friction (since session 26; before, they were held where they came to rest).
//!   Each takes the mean of its stretched edges' projections, weighted by their
//!   stiffness (the inverse of the rest length), as its pull. The part of the
//!   pull into the body is what the body takes, the normal force. The particle stays put
//!   while the pull along the body is at most the garment's `friction` times that; beyond
//!   it, it slides by the excess. It never goes below the body's tangent plane where it
//!   started. So tension pressing cloth onto a curved body (an opening pulled over the
//!   hips) is held as friction holds it; the speckle of unequal stretch that the solver's
//!   position-level friction froze in the cloth at the body, which presses nothing onto it,
//!   is not. A rope on a capstan is the test (`tests` below): the tension ratio a wrap
//!   holds stays under `e^(mu theta)`.
//! - The sweeps stop after `max_sweeps`, or when no particle moved more than
//!   [`TOLERANCE`] in a sweep. A particle that came within `thickness` of the body is put
//!   back at `thickness` along the pseudo-normal.
//!
//! Deterministic (one thread, fixed order). Measured on the 10k T-shirt (`drape sim
//! --garment tshirt --pose random:9`) at 100 sweeps: p95 strain 1.82% after it, against
//! 1.91% with the particles at the body held, in 0.120 s against 0.077 s (docs/sim.md,
//! session 26).

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;
use serde::Serialize;

use super::collision::BodyCollider;
use super::constraints::distance::Kind;
use super::model::ClothModel;

/// Particles closer to the body than `thickness` plus this are at the body: the sweeps do
/// not move them, they slide on it under friction (m).
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
    /// Particles the sweeps did not move (at the body or pinned).
    pub held: usize,
    /// p95 edge strain before the polish.
    pub strain_p95_before: f32,
    /// Mean distance a particle moved (m; over all particles).
    pub mean_move: f32,
    /// Largest distance a particle moved (m).
    pub max_move: f32,
    /// Particles put back at `thickness` from the body after the sweeps.
    pub pushed_out: usize,
    /// Particles at the body that slid on it (their stretched edges' net pull beat
    /// friction).
    pub slid: usize,
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
    // Signed distance to the body and the contact's normal within the clearance radius
    // (None: farther).
    let hit = |p: &Vec3| {
        body.closest(*p, CLEARANCE_RADIUS)
            .map(|h| (h.distance, h.normal))
    };
    let contact: Vec<Option<(f32, Vec3)>> = if parallel {
        x.par_iter().map(hit).collect()
    } else {
        x.iter().map(hit).collect()
    };
    // Inverse masses of the sweeps: particles at the body (and pinned ones) are 0 there.
    let w: Vec<f32> = model
        .inv_mass
        .iter()
        .zip(&contact)
        .map(|(&w, c)| match c {
            Some((d, _)) if *d < reach => 0.0,
            _ => w,
        })
        .collect();
    let held = w.iter().filter(|&&w| w == 0.0).count();
    // The stretch constraints with a particle free to move, in colour order.
    let stretch = || {
        model
            .distance
            .iter()
            .zip(&model.distance_kind)
            .filter(|(_, k)| **k == Kind::Stretch)
            .map(|(c, _)| (c.i as usize, c.j as usize, c.rest))
    };
    let edges: Vec<(usize, usize, f32)> =
        stretch().filter(|&(i, j, _)| w[i] + w[j] > 0.0).collect();
    // The particles at the body that may slide on it (not pinned), with their contact
    // normals, and the stretch constraints of each (the other end, its rest length).
    let mut sliders: Vec<Slider> = Vec::new();
    let mut slot = vec![usize::MAX; x.len()];
    for (i, c) in contact.iter().enumerate() {
        if let Some((d, n)) = c
            && *d < reach
            && model.inv_mass[i] > 0.0
        {
            slot[i] = sliders.len();
            sliders.push(Slider {
                i,
                normal: *n,
                start: x[i],
                edges: Vec::new(),
            });
        }
    }
    for (i, j, rest) in stretch() {
        if slot[i] != usize::MAX {
            sliders[slot[i]].edges.push((j, rest));
        }
        if slot[j] != usize::MAX {
            sliders[slot[j]].edges.push((i, rest));
        }
    }
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
        // The particles at the body, in index order: each moves by the mean of its
        // stretched edges' pulls after Coulomb friction on that net pull.
        for s in &sliders {
            let m = s.pull(x, &model.inv_mass, model.friction_of(s.i));
            if m == Vec3::ZERO {
                continue;
            }
            let p = x[s.i] + m;
            // Never into the body: not below the contact's tangent plane at the start.
            let below = (p - s.start).dot(s.normal).min(0.0);
            let p = p - s.normal * below;
            largest = largest.max(p.distance(x[s.i]));
            x[s.i] = p;
        }
        if largest < TOLERANCE {
            break;
        }
    }
    let slid = sliders.iter().filter(|s| x[s.i] != x0[s.i]).count();
    // Back out of the thickness where a particle moved towards the body.
    let mut pushed_out = 0;
    for ((p, p0), c) in x.iter_mut().zip(&x0).zip(&contact) {
        let moved = p.distance(*p0);
        let clearance = c.map_or(CLEARANCE_RADIUS, |(d, _)| d);
        if moved == 0.0 || moved < clearance - thickness {
            continue;
        }
        if let Some(h) = body.closest(*p, CLEARANCE_RADIUS)
            && h.distance < thickness
        {
            *p = h.point + h.normal * thickness;
            pushed_out += 1;
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
        slid,
        time: t.elapsed().as_secs_f64(),
    }
}

/// A particle at the body during the polish.
struct Slider {
    i: usize,
    /// The contact's pseudo-normal (out of the body) where the polish started.
    normal: Vec3,
    /// Its position where the polish started.
    start: Vec3,
    /// Its stretch constraints: the other particle and the rest length.
    edges: Vec<(usize, f32)>,
}

impl Slider {
    /// The move of this particle in one sweep: the mean over its stretched edges of each
    /// edge's projection (shared by the two ends' inverse masses), each weighted by its
    /// stiffness, the inverse of its rest length (an edge's force goes with its strain: a
    /// short edge stretched by a millimetre pulls harder than a long one), then Coulomb
    /// friction on that net pull. The part of the pull into the body is what the body
    /// takes (the normal force); the particle stays put while the tangential part is at
    /// most `mu` times it (static friction), and otherwise slides by the excess (kinetic).
    /// A pull away from the body lifts the particle off it.
    fn pull(&self, x: &[Vec3], inv_mass: &[f32], mu: f32) -> Vec3 {
        let wi = inv_mass[self.i];
        let mut sum = Vec3::ZERO;
        let mut stiffness = 0.0;
        for &(j, rest) in &self.edges {
            let d = x[self.i] - x[j];
            let len = d.length();
            if len <= rest {
                continue;
            }
            let k = 1.0 / rest;
            sum -= d * ((len - rest) / len * wi / (wi + inv_mass[j]) * k);
            stiffness += k;
        }
        if stiffness == 0.0 {
            return Vec3::ZERO;
        }
        let pull = sum / stiffness;
        let into = -pull.dot(self.normal);
        if into <= 0.0 {
            return pull;
        }
        let tangential = pull + self.normal * into;
        let t = tangential.length();
        let budget = mu * into;
        if t <= budget {
            Vec3::ZERO
        } else {
            tangential * (1.0 - budget / t)
        }
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

    /// Mean strain of the edges between consecutive particles `i`, `i + 1` of a grid, both in
    /// `cols` (vertex indices within one row).
    fn row_strain(model: &ClothModel, x: &[Vec3], cols: std::ops::Range<usize>) -> f32 {
        let mut sum = 0.0;
        let mut n = 0;
        for c in &model.distance {
            let (i, j) = (c.i as usize, c.j as usize);
            if i.max(j) - i.min(j) == 1 && cols.contains(&i) && cols.contains(&j) {
                sum += x[i].distance(x[j]) / c.rest - 1.0;
                n += 1;
            }
        }
        sum / n as f32
    }

    #[test]
    fn a_stretched_cloth_lying_on_the_body_slides_back_to_its_rest_lengths() {
        // A 0.2 x 0.2 m cloth lying 1 mm above a box's top face (y = 0) with its left half
        // stretched 5% along x and nothing pinned: every particle is at the body, and the
        // pulls lie in the face, so nothing presses the cloth on it and friction holds
        // nothing.
        let mesh = primitives::grid(Vec3::ZERO, Vec3::X * 0.2, Vec3::Z * 0.2, 20, 20);
        let config = SimConfig {
            friction: 0.8,
            ..SimConfig::default()
        };
        let model = ClothModel::new(&mesh, &config, &[]).unwrap();
        let thickness = 0.003;
        let lift = thickness + 0.001;
        let mut x: Vec<Vec3> = mesh
            .vertices
            .iter()
            .map(|p| {
                let stretched = p.x.min(0.1) * 1.05 + (p.x - 0.1).max(0.0);
                Vec3::new(stretched, lift, p.z)
            })
            .collect();
        let box_ = primitives::cuboid(Vec3::new(0.1, -0.5, 0.1), Vec3::splat(0.5), 4);
        let body = BodyCollider::new(&box_.vertices, &box_.triangles, 0.01);
        let before = super::super::drape::strain(&model, &x);
        assert!(before.max > 0.049, "{before:?}");
        let s = polish(&model, &body, &mut x, thickness, 5000, false);
        assert_eq!(s.held, x.len(), "{s:?}");
        assert!(s.slid > 0, "{s:?}");
        let after = super::super::drape::strain(&model, &x);
        assert!(after.max < 0.004, "{after:?} after {} sweeps", s.sweeps);
        // In the face: never into the box, never lifted off it.
        for p in &x {
            assert!((p.y - lift).abs() < 1e-6, "{p}");
        }
    }

    /// A strip 3 particles wide (1 cm apart, 1 cm edges) wrapped about a quarter round a
    /// vertical cylinder of radius 0.1 m, `thickness` + 1 mm off it, its straight tails
    /// pinned. Along the wrap the strain falls from 6% at tail A to 3% at tail B as a rope's
    /// tension on a capstan does, `T(theta) = T_A e^(-k theta)`, k = ln 2 / (the wrap's
    /// angle) = 0.42; each tail is stretched as its end of the wrap. Returns the model, the
    /// positions, the cylinder, the wrap's first and last column and the wrap's angle.
    fn capstan(
        friction: f32,
        thickness: f32,
    ) -> (ClothModel, Vec<Vec3>, BodyCollider, (usize, usize), f32) {
        // The wrap's columns are returned as indices of the middle row.
        let (r, h, rows) = (0.1f32, 0.01f32, 2u32);
        let (tail, wrap) = (5usize, 16usize); // columns
        let nu = (2 * tail + wrap) as u32;
        let (ea, eb) = (0.06f32, 0.03f32);
        let rc = r + thickness + 0.001;
        let mesh = primitives::grid(
            Vec3::ZERO,
            Vec3::X * h * nu as f32,
            Vec3::Y * h * rows as f32,
            nu,
            rows,
        );
        // The angle of each wrap column: edge k of the wrap at strain ea (eb/ea)^(k/(wrap-1)).
        let mut theta = vec![0.0f32; wrap + 1];
        for k in 0..wrap {
            let e = ea * (eb / ea).powf(k as f32 / (wrap - 1) as f32);
            theta[k + 1] = theta[k] + h * (1.0 + e) / rc;
        }
        let span = theta[wrap];
        let start = -span / 2.0;
        let on = |t: f32| Vec3::new(rc * (start + t).sin(), 0.0, rc * (start + t).cos());
        let tangent = |t: f32| Vec3::new((start + t).cos(), 0.0, -(start + t).sin());
        let column = |c: usize| -> Vec3 {
            if c < tail {
                on(0.0) - tangent(0.0) * ((tail - c) as f32 * h * (1.0 + ea))
            } else if c <= tail + wrap {
                on(theta[c - tail])
            } else {
                on(span) + tangent(span) * ((c - tail - wrap) as f32 * h * (1.0 + eb))
            }
        };
        let x: Vec<Vec3> = (0..=rows)
            .flat_map(|j| (0..=nu as usize).map(move |c| (j, c)))
            .map(|(j, c)| column(c) + Vec3::Y * (j as f32 * h))
            .collect();
        let pinned: Vec<u32> = (0..=rows)
            .flat_map(|j| {
                (0..=nu)
                    .filter(|&c| c < tail as u32 || c > (tail + wrap) as u32)
                    .map(move |c| j * (nu + 1) + c)
            })
            .collect();
        let config = SimConfig {
            friction,
            ..SimConfig::default()
        };
        let model = ClothModel::new(&mesh, &config, &pinned).unwrap();
        let cyl = primitives::cylinder(Vec3::new(0.0, -0.1, 0.0), r, 0.2, 512, 4);
        let body = BodyCollider::new(&cyl.vertices, &cyl.triangles, 0.01);
        let middle = nu as usize + 1;
        (model, x, body, (middle + tail, middle + tail + wrap), span)
    }

    #[test]
    fn friction_on_a_wrapped_strip_holds_a_tension_difference_as_a_capstan_does() {
        // A rope on a capstan holds tensions T_A > T_B while T_A / T_B <= e^(mu theta)
        // (Euler-Eytelwein): here 2 over about 1.6 rad, which friction 0.3 cannot hold
        // (e^(0.3 theta) = 1.62) and 0.8 could (3.61).
        let thickness = 0.003;
        let run = |mu: f32| {
            let (model, mut x, body, (a, b), span) = capstan(mu, thickness);
            let ends = |x: &[Vec3]| {
                (
                    row_strain(&model, x, a - 1..a + 3),
                    row_strain(&model, x, b - 2..b + 2),
                )
            };
            let (a0, b0) = ends(&x);
            assert!(
                (a0 - 0.059).abs() < 2e-3 && (b0 - 0.0305).abs() < 2e-3,
                "{a0} {b0}"
            );
            let before = x.clone();
            let s = polish(&model, &body, &mut x, thickness, 20000, false);
            assert_eq!(s.held, x.len(), "{s:?}");
            for (i, p) in x.iter().enumerate() {
                let d = body.closest(*p, 0.05).map_or(1.0, |h| h.distance);
                assert!(d >= thickness - 1e-5, "particle {i} at {d} from the body");
            }
            let moved = x
                .iter()
                .zip(&before)
                .map(|(p, q)| p.distance(*q))
                .fold(0.0f32, f32::max);
            let (a1, b1) = ends(&x);
            eprintln!(
                "friction {mu}: strain at the wrap's ends {a1:.4} / {b1:.4} = {:.2} (e^(mu theta) = {:.2}), moved at most {moved:.5} m, {} sweeps, {} slid",
                a1 / b1,
                (mu * span).exp(),
                s.sweeps,
                s.slid
            );
            (a1 / b1, moved, span)
        };
        // Without friction the strip slides round until it pulls nearly alike everywhere
        // (the sweeps stop at the polish's tolerance, 1 um a sweep, before it is exact).
        let (free, _, _) = run(0.0);
        assert!(free < 1.15, "{free}");
        // With friction the strip slides until the ratio is one friction can hold: never
        // more than the capstan's bound, and more with more friction. (At 0.8 the strip
        // still slides a little: the outer rows' diagonals pull them in towards the middle
        // one, a pull in the surface that friction does not hold, and that moves the rows.)
        let (low, moved_low, span) = run(0.3);
        assert!(low > 1.4 && low < (0.3 * span).exp() * 1.02, "{low}");
        let (high, moved_high, _) = run(0.8);
        assert!(
            high > low + 0.15 && high < (0.8 * span).exp(),
            "{high} against {low}"
        );
        assert!(moved_high < moved_low, "{moved_high} {moved_low}");
    }

    #[test]
    fn the_polish_gives_the_same_bits_on_one_thread_and_two() {
        let thickness = 0.003;
        let (model, x, body, _, _) = capstan(0.3, thickness);
        let (mut y, mut z) = (x.clone(), x);
        let s = polish(&model, &body, &mut y, thickness, 300, true);
        let t = polish(&model, &body, &mut z, thickness, 300, false);
        assert_eq!(y, z);
        assert_eq!(
            (s.sweeps, s.slid, s.pushed_out),
            (t.sweeps, t.slid, t.pushed_out)
        );
    }
}
