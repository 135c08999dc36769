//! Tape-measure girths of a body in its rest pose: chest, waist and hips, the measurements a
//! size chart is read from.
//!
//! A girth is measured the way a tailor's tape lies: the body is cut by a horizontal plane,
//! the closed cross-section loop around the spine is kept (not the arms), and the tape's
//! length is the perimeter of that loop's convex hull (it bridges the hollows, between the
//! breasts or the buttocks). Where the girth is taken follows the tailors' definitions on a
//! vertical profile of the torso, scanned every [`STEP`] metres:
//! - **hips**: the largest girth between the crotch and the lower back's top;
//! - **waist**: the smallest girth between the hips level and the chest band's bottom (the
//!   natural waist);
//! - **chest**: the largest girth between the waist and the armpits (the shoulder joints
//!   lowered by [`ARMPIT_DROP`] of the body's height, or lower where heavy arms already
//!   touch the torso: the first jump of the girth by more than [`ARM_JUMP`]).

use glam::{Vec2, Vec3};
use serde::{Deserialize, Serialize};

use super::{BodyError, ShapedBody};

/// Height step of the torso profile (m).
pub const STEP: f32 = 0.005;

/// How far below the hip joints the profile starts, as a share of the body height (the
/// fullest part of the buttocks lies below the joints; levels through the legs alone are
/// skipped).
pub const HIPS_BELOW: f32 = 0.06;

/// How far below the shoulder joints the chest band ends, as a share of the body height.
pub const ARMPIT_DROP: f32 = 0.045;

/// A girth step between two levels of the profile larger than this (m) means the arms
/// joined the section: the chest band ends below it.
pub const ARM_JUMP: f32 = 0.05;

/// The three girths of a body (m).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Girths {
    /// Chest: fullest girth under the armpits.
    pub chest: f32,
    /// Waist: narrowest girth of the torso.
    pub waist: f32,
    /// Hips: fullest girth around the buttocks.
    pub hips: f32,
}

impl Girths {
    /// The girth named `name` (`chest`, `waist` or `hips`).
    pub fn get(&self, name: &str) -> Option<f32> {
        match name {
            "chest" => Some(self.chest),
            "waist" => Some(self.waist),
            "hips" => Some(self.hips),
            _ => None,
        }
    }
}

/// Closed loops where the plane `y = level` cuts a triangle mesh, as polylines in (x, z).
/// A vertex counts as above the plane when `y >= level`, so every crossing triangle has
/// exactly two crossing edges and the loops of a closed surface close. Open chains (the
/// mesh's holes) are dropped.
pub fn section_loops(vertices: &[Vec3], triangles: &[[u32; 3]], level: f32) -> Vec<Vec<Vec2>> {
    use std::collections::HashMap;
    let above = |i: u32| vertices[i as usize].y >= level;
    let key = |a: u32, b: u32| if a < b { (a, b) } else { (b, a) };
    let point = |a: u32, b: u32| {
        let (p, q) = (vertices[a as usize], vertices[b as usize]);
        let t = (level - p.y) / (q.y - p.y);
        let x = p + (q - p) * t;
        Vec2::new(x.x, x.z)
    };
    // Each crossing edge joins the (at most two) triangles around it.
    let mut links: HashMap<(u32, u32), Vec<(u32, u32)>> = HashMap::new();
    for t in triangles {
        let crossing: Vec<(u32, u32)> = (0..3)
            .map(|k| (t[k], t[(k + 1) % 3]))
            .filter(|&(a, b)| above(a) != above(b))
            .map(|(a, b)| key(a, b))
            .collect();
        if let [e, f] = crossing[..] {
            links.entry(e).or_default().push(f);
            links.entry(f).or_default().push(e);
        }
    }
    let mut edges: Vec<(u32, u32)> = links.keys().copied().collect();
    edges.sort_unstable();
    let mut used = std::collections::HashSet::new();
    let mut loops = Vec::new();
    for &start in &edges {
        if used.contains(&start) {
            continue;
        }
        let mut chain = vec![start];
        used.insert(start);
        let closed;
        let mut current = start;
        loop {
            let next = links[&current].iter().find(|e| !used.contains(*e)).copied();
            match next {
                Some(e) => {
                    used.insert(e);
                    chain.push(e);
                    current = e;
                }
                None => {
                    closed = chain.len() > 2 && links[&current].contains(&start);
                    break;
                }
            }
        }
        if closed {
            loops.push(chain.iter().map(|&(a, b)| point(a, b)).collect());
        }
    }
    loops
}

/// Whether `p` lies inside the closed polygon `poly` (even-odd rule).
pub fn contains(poly: &[Vec2], p: Vec2) -> bool {
    let mut inside = false;
    let n = poly.len();
    for i in 0..n {
        let (a, b) = (poly[i], poly[(i + 1) % n]);
        if (a.y > p.y) != (b.y > p.y) {
            let x = a.x + (p.y - a.y) / (b.y - a.y) * (b.x - a.x);
            if x > p.x {
                inside = !inside;
            }
        }
    }
    inside
}

/// Perimeter of the convex hull of points (monotone chain).
pub fn hull_perimeter(points: &[Vec2]) -> f32 {
    let mut p: Vec<Vec2> = points.to_vec();
    p.sort_by(|a, b| a.x.total_cmp(&b.x).then(a.y.total_cmp(&b.y)));
    p.dedup();
    if p.len() < 2 {
        return 0.0;
    }
    let cross = |o: Vec2, a: Vec2, b: Vec2| (a - o).perp_dot(b - o);
    let mut hull: Vec<Vec2> = Vec::with_capacity(2 * p.len());
    for pass in 0..2 {
        let start = hull.len();
        let iter: Box<dyn Iterator<Item = &Vec2>> = if pass == 0 {
            Box::new(p.iter())
        } else {
            Box::new(p.iter().rev())
        };
        for &q in iter {
            while hull.len() >= start + 2
                && cross(hull[hull.len() - 2], hull[hull.len() - 1], q) <= 0.0
            {
                hull.pop();
            }
            hull.push(q);
        }
        hull.pop();
    }
    (0..hull.len())
        .map(|i| hull[i].distance(hull[(i + 1) % hull.len()]))
        .sum()
}

/// Tape girth at height `level`: the hull perimeter of the cross-section loop that encloses
/// `centre` (x, z), or `None` when no loop does (the plane passes between the legs).
pub fn girth_at(
    vertices: &[Vec3],
    triangles: &[[u32; 3]],
    level: f32,
    centre: Vec2,
) -> Option<f32> {
    section_loops(vertices, triangles, level)
        .into_iter()
        .filter(|l| contains(l, centre))
        .map(|l| hull_perimeter(&l))
        .reduce(f32::max)
}

/// One point of the torso profile: height (m) and girth (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProfilePoint {
    /// Height of the plane (m).
    pub y: f32,
    /// Tape girth there (m).
    pub girth: f32,
}

impl ShapedBody<'_> {
    /// The spine's (x, z) at height `y`: interpolated along the chain of spine joints.
    fn spine_at(&self, chain: &[Vec3], y: f32) -> Vec2 {
        let flat = |p: Vec3| Vec2::new(p.x, p.z);
        for w in chain.windows(2) {
            let (a, b) = (w[0], w[1]);
            if (a.y..=b.y).contains(&y) && b.y > a.y {
                let t = (y - a.y) / (b.y - a.y);
                return flat(a.lerp(b, t));
            }
        }
        if y < chain[0].y {
            flat(chain[0])
        } else {
            flat(chain[chain.len() - 1])
        }
    }

    /// The torso's girth profile from below the hip joints ([`HIPS_BELOW`]) to the armpits,
    /// every [`STEP`] m (levels where the plane passes between the legs are left out).
    pub fn torso_profile(&self) -> Result<Vec<ProfilePoint>, BodyError> {
        let chain = [
            self.rest_bone_ends("Hips")?.0,
            self.rest_bone_ends("LowerBack")?.0,
            self.rest_bone_ends("Spine")?.0,
            self.rest_bone_ends("Spine1")?.0,
            self.rest_bone_ends("Neck")?.0,
        ];
        // The spine joints lie near the back; the section centre is moved forward to the
        // middle of the torso by the hips' depth (the hip joints sit mid-depth).
        let hip = self.rest_bone_ends("LeftUpLeg")?.0;
        let shoulder = self.rest_bone_ends("LeftArm")?.0;
        let forward = Vec2::new(0.0, (hip.z - chain[0].z).max(0.0));
        let bottom = hip.y - HIPS_BELOW * self.height();
        let top = shoulder.y - ARMPIT_DROP * self.height();
        let steps = ((top - bottom) / STEP).floor().max(0.0) as usize;
        Ok((0..=steps)
            .filter_map(|k| {
                let y = bottom + k as f32 * STEP;
                let centre = self.spine_at(&chain, y) + forward;
                girth_at(&self.vertices, &self.model.triangles, y, centre)
                    .map(|girth| ProfilePoint { y, girth })
            })
            .collect())
    }

    /// Chest, waist and hip girths (see the module documentation).
    pub fn girths(&self) -> Result<Girths, BodyError> {
        let profile = self.torso_profile()?;
        let lower_back_top = self.rest_bone_ends("LowerBack")?.1.y;
        let spine1 = self.rest_bone_ends("Spine1")?.0.y;
        let bad = |what: &str| {
            BodyError::Measure(format!(
                "the torso profile has no {what} level (shape {:?})",
                self.params
            ))
        };
        let band = |lo: f32, hi: f32| profile.iter().filter(move |p| p.y >= lo && p.y <= hi);
        let max_in = |lo: f32, hi: f32| {
            band(lo, hi)
                .max_by(|a, b| a.girth.total_cmp(&b.girth))
                .copied()
        };
        let min_in = |lo: f32, hi: f32| {
            band(lo, hi)
                .min_by(|a, b| a.girth.total_cmp(&b.girth))
                .copied()
        };
        let hips = max_in(f32::MIN, lower_back_top).ok_or_else(|| bad("hips"))?;
        let waist = min_in(hips.y, spine1).ok_or_else(|| bad("waist"))?;
        // Heavy arms touch the torso below the band's nominal top: the loop then takes them
        // in and the girth jumps; the band ends below the first such jump.
        let armpit = profile
            .windows(2)
            .find(|w| w[0].y >= waist.y && w[1].girth - w[0].girth > ARM_JUMP)
            .map_or(f32::MAX, |w| w[0].y);
        let chest = max_in(waist.y, armpit).ok_or_else(|| bad("chest"))?;
        Ok(Girths {
            chest: chest.girth,
            waist: waist.girth,
            hips: hips.girth,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A closed prism of `n` sides around the Y axis from y=0 to y=1, radius `r(k)`.
    fn prism(n: usize, r: impl Fn(usize) -> f32) -> (Vec<Vec3>, Vec<[u32; 3]>) {
        let mut v = Vec::new();
        for y in [0.0, 1.0] {
            for k in 0..n {
                let a = std::f32::consts::TAU * k as f32 / n as f32;
                v.push(Vec3::new(r(k) * a.cos(), y, r(k) * a.sin()));
            }
        }
        v.push(Vec3::new(0.0, 0.0, 0.0));
        v.push(Vec3::new(0.0, 1.0, 0.0));
        let (bc, tc) = (2 * n as u32, 2 * n as u32 + 1);
        let mut t = Vec::new();
        for k in 0..n as u32 {
            let j = (k + 1) % n as u32;
            let nn = n as u32;
            t.push([k, j, nn + j]);
            t.push([k, nn + j, nn + k]);
            t.push([bc, j, k]);
            t.push([tc, nn + k, nn + j]);
        }
        (v, t)
    }

    #[test]
    fn the_girth_of_a_cylinder_is_its_circumference() {
        let (v, t) = prism(256, |_| 0.15);
        let g = girth_at(&v, &t, 0.5, Vec2::ZERO).unwrap();
        let exact = std::f32::consts::TAU * 0.15;
        assert!((g - exact).abs() < 1e-3 * exact, "{g} vs {exact}");
        // A plane beside the prism, or a centre outside it, finds nothing.
        assert!(girth_at(&v, &t, 1.5, Vec2::ZERO).is_none());
        assert!(girth_at(&v, &t, 0.5, Vec2::new(0.5, 0.0)).is_none());
    }

    #[test]
    fn the_tape_bridges_hollows() {
        // A star of 8 points, radius alternating 0.2 and 0.1: the tape lies on the four
        // outer points only, a square of side 0.2 * sqrt(2).
        let (v, t) = prism(8, |k| if k % 2 == 0 { 0.2 } else { 0.1 });
        let g = girth_at(&v, &t, 0.3, Vec2::ZERO).unwrap();
        let exact = 4.0 * 0.2 * 2f32.sqrt();
        assert!((g - exact).abs() < 1e-4, "{g} vs {exact}");
    }

    #[test]
    fn two_legs_give_two_loops_and_the_centre_picks_one() {
        let (mut v, mut t) = prism(64, |_| 0.1);
        let (v2, t2) = prism(64, |_| 0.05);
        let off = v.len() as u32;
        v.extend(v2.iter().map(|p| *p + Vec3::new(0.4, 0.0, 0.0)));
        t.extend(t2.iter().map(|f| [f[0] + off, f[1] + off, f[2] + off]));
        assert_eq!(section_loops(&v, &t, 0.5).len(), 2);
        let small = girth_at(&v, &t, 0.5, Vec2::new(0.4, 0.0)).unwrap();
        assert!((small - std::f32::consts::TAU * 0.05).abs() < 1e-3);
    }
}
