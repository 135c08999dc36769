//! The body's thin parts (fingers, toes, ears) for edge contacts.
//!
//! The collision stage keeps the particles out of the body, but an edge whose two ends are
//! outside can still pass through a part thinner than the edge is long: a coarse cuff's
//! 2.5 cm edges across a 1.5 cm finger or thumb. The drape then ends "caught on the body"
//! (`drape.rs`) and fails. So the parts where the body is thinner than
//! `thin_part_thickness` (`SimConfig`) are found once per drape, on its first frame: the
//! triangles whose inward ray leaves the body that soon
//! ([`BodyCollider::local_thickness`]; on the MakeHuman body at 3 cm: the hands, the feet
//! and the face's features, about 12,500 of its 26,756 triangles). Each frame every cloth
//! edge whose midpoint comes near one (within the boxes around the groups of them: the
//! hands, the feet, the head) looks for its nearest body triangle and keeps it as a
//! contact if that triangle is thin; in each substep a midpoint closer than the thickness
//! is pushed out along that contact's normal, each end by its share of the inverse masses
//! ([`super::solver::Solver::frame_with`]). That holds an edge off a part while the edge is
//! shorter than about twice the part's width. Fingertips and toe tips are not thin: their
//! inward ray runs along the digit.

use glam::Vec3;

use super::collision::BodyCollider;

/// Thin parts whose boxes come within this distance of each other are grouped (the
/// fingers of a hand, the features of a face): a handful of boxes to test each edge
/// against (m).
const GROUPING: f32 = 0.05;

/// The thin parts of a body: which of its triangles are thin, and boxes around groups of
/// them (a hand, a foot, the head), moved with the body, to tell quickly which edges come
/// near one.
#[derive(Debug, Clone)]
pub struct ThinParts {
    /// Per body triangle: thin or not.
    thin: Vec<bool>,
    /// Number of thin triangles.
    count: usize,
    /// The body vertices of each group.
    groups: Vec<Vec<u32>>,
    /// Each group's box at the end of the frame (min, max).
    end: Vec<(Vec3, Vec3)>,
    /// Each group's box swept over the frame (start and end), and the box around them all.
    swept: Vec<(Vec3, Vec3)>,
    all: (Vec3, Vec3),
}

/// The box around some vertices.
fn bounds(x: &[Vec3], vertices: &[u32]) -> (Vec3, Vec3) {
    vertices.iter().fold(
        (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
        |(lo, hi), &i| (lo.min(x[i as usize]), hi.max(x[i as usize])),
    )
}

impl ThinParts {
    /// The triangles of `body` (at the end of its frame) under which it is thinner than
    /// `max_thickness` (m); `None` if there are none.
    pub fn new(body: &BodyCollider, max_thickness: f32) -> Option<Self> {
        // Rays through boxes without the contact margin visit far fewer of them.
        let mut bare = BodyCollider::new(body.positions(), body.triangles(), 0.0);
        bare.set_parallel(body.is_parallel());
        let thickness = bare.local_thickness(max_thickness);
        let thin: Vec<bool> = thickness.iter().map(|d| *d <= max_thickness).collect();
        let count = thin.iter().filter(|t| **t).count();
        if count == 0 {
            return None;
        }
        // Connected groups of thin triangles (sharing a vertex), then groups whose boxes
        // come within GROUPING of each other merged.
        let x = body.positions();
        let mut parent: Vec<u32> = (0..x.len() as u32).collect();
        fn root(parent: &mut [u32], mut i: u32) -> u32 {
            while parent[i as usize] != i {
                parent[i as usize] = parent[parent[i as usize] as usize];
                i = parent[i as usize];
            }
            i
        }
        let mut used = vec![false; x.len()];
        for (t, _) in body.triangles().iter().zip(&thin).filter(|(_, t)| **t) {
            for k in 0..3 {
                used[t[k] as usize] = true;
                let (a, b) = (root(&mut parent, t[k]), root(&mut parent, t[(k + 1) % 3]));
                parent[a.max(b) as usize] = a.min(b);
            }
        }
        let mut by_root: std::collections::BTreeMap<u32, Vec<u32>> = Default::default();
        for v in 0..x.len() as u32 {
            if used[v as usize] {
                let r = root(&mut parent, v);
                by_root.entry(r).or_default().push(v);
            }
        }
        let mut groups: Vec<Vec<u32>> = by_root.into_values().collect();
        let mut end: Vec<(Vec3, Vec3)> = groups.iter().map(|g| bounds(x, g)).collect();
        let near = |a: (Vec3, Vec3), b: (Vec3, Vec3)| {
            (a.0 - GROUPING).cmple(b.1).all() && (b.0 - GROUPING).cmple(a.1).all()
        };
        while let Some((i, j)) = (0..groups.len()).find_map(|i| {
            (i + 1..groups.len())
                .find(|&j| near(end[i], end[j]))
                .map(|j| (i, j))
        }) {
            let (moved, b) = (groups.swap_remove(j), end.swap_remove(j));
            groups[i].extend(moved);
            end[i] = (end[i].0.min(b.0), end[i].1.max(b.1));
        }
        let mut me = Self {
            thin,
            count,
            groups,
            swept: end.clone(),
            end,
            all: (Vec3::ZERO, Vec3::ZERO),
        };
        me.sweep(None);
        Some(me)
    }

    /// The swept boxes from the boxes at the frame's start (None: the body stands still)
    /// and at its end.
    fn sweep(&mut self, start: Option<&[(Vec3, Vec3)]>) {
        let start = start.unwrap_or(&self.end);
        for ((s, a), b) in self.swept.iter_mut().zip(start).zip(&self.end) {
            *s = (a.0.min(b.0), a.1.max(b.1));
        }
        self.all = self.swept.iter().fold(
            (Vec3::splat(f32::INFINITY), Vec3::splat(f32::NEG_INFINITY)),
            |(lo, hi), b| (lo.min(b.0), hi.max(b.1)),
        );
    }

    /// Number of thin triangles.
    pub fn len(&self) -> usize {
        self.count
    }

    /// True if there are no thin triangles (never, for a value from [`ThinParts::new`]).
    pub fn is_empty(&self) -> bool {
        self.count == 0
    }

    /// Number of groups (a hand, a foot, the head).
    pub fn groups(&self) -> usize {
        self.groups.len()
    }

    /// True if the body's triangle `tri` is thin.
    pub fn is_thin(&self, tri: u32) -> bool {
        self.thin[tri as usize]
    }

    /// True if `p` lies within `radius` of a group's box swept over the frame: a thin
    /// triangle may be that close.
    #[inline]
    pub fn near(&self, p: Vec3, radius: f32) -> bool {
        let within =
            |b: &(Vec3, Vec3)| (p + radius).cmpge(b.0).all() && (p - radius).cmple(b.1).all();
        within(&self.all) && self.swept.iter().any(within)
    }

    /// Starts a frame in which the body moves to `body` (all its vertices).
    pub fn advance(&mut self, body: &[Vec3]) {
        let start = self.end.clone();
        for (b, g) in self.end.iter_mut().zip(&self.groups) {
            *b = bounds(body, g);
        }
        self.sweep(Some(&start));
    }

    /// Starts a frame in which the body does not move.
    pub fn hold(&mut self) {
        self.sweep(None);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives;

    #[test]
    fn a_thin_rod_beside_a_thick_one_is_found_alone() {
        // A 1.5 cm rod (a finger) and a 10 cm rod (an arm), apart.
        let thin = primitives::cylinder(Vec3::ZERO, 0.0075, 0.2, 16, 8);
        let thick = primitives::cylinder(Vec3::ZERO, 0.05, 0.2, 32, 8);
        let mut vertices: Vec<Vec3> = thin.vertices.clone();
        let mut triangles = thin.triangles.clone();
        let offset = vertices.len() as u32;
        vertices.extend(thick.vertices.iter().map(|p| *p + Vec3::new(0.3, 0.0, 0.0)));
        triangles.extend(thick.triangles.iter().map(|t| t.map(|i| i + offset)));
        let body = BodyCollider::new(&vertices, &triangles, 0.01);
        let d = body.local_thickness(0.5);
        // The side walls' rays cross the rod: its diameter, to within the polygon's sag.
        let (thin_d, thick_d) = d.split_at(thin.triangles.len());
        let sides = |d: &[f32], lo: f32, hi: f32| d.iter().filter(|&&x| x > lo && x < hi).count();
        assert!(
            sides(thin_d, 0.0140, 0.0151) > thin.triangles.len() / 2,
            "{thin_d:?}"
        );
        assert!(sides(thick_d, 0.095, 0.101) > thick.triangles.len() / 2);
        let parts = ThinParts::new(&body, 0.03).expect("the thin rod");
        // The thin rod's side walls (16 x 8 quads) and nothing of the thick one; neither
        // rod's caps, whose rays run 0.2 m along the axis.
        assert_eq!(parts.len(), 2 * 16 * 8);
        assert_eq!(parts.groups(), 1);
        assert!(parts.is_thin(0) && !parts.is_thin(thin.triangles.len() as u32));
        // Its box: near the thin rod, not near the thick one.
        assert!(parts.near(Vec3::new(0.0, 0.1, 0.0), 0.001));
        assert!(parts.near(Vec3::new(0.012, 0.1, 0.0), 0.005));
        assert!(!parts.near(Vec3::new(0.3, 0.1, 0.0), 0.005));
        // It moves with the body.
        let mut parts = parts;
        let moved: Vec<Vec3> = vertices.iter().map(|p| *p + Vec3::X * 0.05).collect();
        parts.advance(&moved);
        assert!(
            parts.near(Vec3::new(0.03, 0.1, 0.0), 0.001),
            "swept over the frame"
        );
        parts.hold();
        assert!(!parts.near(Vec3::new(0.03, 0.1, 0.0), 0.001));
        assert!(parts.near(Vec3::new(0.05, 0.1, 0.0), 0.001));
    }
}
