//! Body self-intersection: do limbs pass through the torso, the head or each other?
//!
//! Each body vertex belongs to a segment (torso, head, upper arm, forearm with hand,
//! thigh, shin with foot; left and right) through its skinning weights. Only *core*
//! triangles are tested: those whose three vertices have at least [`CORE_WEIGHT`] of their
//! weight in one segment. That leaves out the blended skin around the joints, which LBS
//! folds by design (armpits, groin, the inside of a bent knee), and keeps everything a limb
//! could push through another part. Two core triangles of different segments that intersect
//! are a self-intersection. A uniform grid finds candidate pairs; a separating-axis test
//! decides.

use std::collections::HashMap;

use glam::Vec3;

use super::BodyModel;

/// Share of a vertex's skinning weight that must lie in one segment for it to be core.
pub const CORE_WEIGHT: f32 = 0.99;

/// Grid cell edge (m): about two body triangles.
const CELL: f32 = 0.03;

/// Body segments.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Segment {
    /// Pelvis, spine, clavicles.
    Torso,
    /// Neck and head.
    Head,
    /// Left upper arm.
    LeftUpperArm,
    /// Left forearm and hand.
    LeftForearm,
    /// Right upper arm.
    RightUpperArm,
    /// Right forearm and hand.
    RightForearm,
    /// Left thigh.
    LeftThigh,
    /// Left shin and foot.
    LeftShin,
    /// Right thigh.
    RightThigh,
    /// Right shin and foot.
    RightShin,
}

impl Segment {
    /// The segment a `cmu_mb` bone belongs to.
    pub fn of_bone(name: &str) -> Segment {
        match name {
            "Neck" | "Neck1" | "Head" => Segment::Head,
            "LeftArm" => Segment::LeftUpperArm,
            "LeftForeArm" | "LeftHand" | "LeftFingerBase" | "LeftHandFinger1" | "LThumb" => {
                Segment::LeftForearm
            }
            "RightArm" => Segment::RightUpperArm,
            "RightForeArm" | "RightHand" | "RightFingerBase" | "RightHandFinger1" | "RThumb" => {
                Segment::RightForearm
            }
            "LeftUpLeg" => Segment::LeftThigh,
            "LeftLeg" | "LeftFoot" | "LeftToeBase" => Segment::LeftShin,
            "RightUpLeg" => Segment::RightThigh,
            "RightLeg" | "RightFoot" | "RightToeBase" => Segment::RightShin,
            _ => Segment::Torso,
        }
    }
}

/// Pairs of segments that are not tested: neighbours across a hinge whose joint limits
/// already keep them apart, and where LBS's own folding inside the bend is expected.
fn exempt(a: Segment, b: Segment) -> bool {
    use Segment::*;
    let pair = if a <= b { (a, b) } else { (b, a) };
    matches!(
        pair,
        (Torso, Head)
            | (LeftUpperArm, LeftForearm)
            | (RightUpperArm, RightForearm)
            | (LeftThigh, LeftShin)
            | (RightThigh, RightShin)
    )
}

/// The core triangles of the body and their segments, computed once per model.
#[derive(Debug, Clone)]
pub struct SelfIntersection {
    triangles: Vec<([u32; 3], Segment)>,
}

/// One intersecting pair found.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contact {
    /// Segments of the two triangles.
    pub segments: (Segment, Segment),
    /// Their triangle indices in the body mesh.
    pub triangles: (u32, u32),
}

impl SelfIntersection {
    /// Classifies the model's triangles.
    pub fn new(model: &BodyModel) -> Self {
        let seg_of_bone: Vec<Segment> = model
            .skeleton
            .bones
            .iter()
            .map(|b| Segment::of_bone(&b.name))
            .collect();
        let core: Vec<Option<Segment>> = model
            .skin
            .bones
            .iter()
            .zip(&model.skin.weights)
            .map(|(b, w)| {
                let mut acc: Vec<(Segment, f32)> = Vec::with_capacity(4);
                for k in 0..4 {
                    let s = seg_of_bone[b[k] as usize];
                    match acc.iter_mut().find(|(x, _)| *x == s) {
                        Some(e) => e.1 += w[k],
                        None => acc.push((s, w[k])),
                    }
                }
                acc.into_iter()
                    .find(|(_, w)| *w >= CORE_WEIGHT)
                    .map(|(s, _)| s)
            })
            .collect();
        let triangles = model
            .triangles
            .iter()
            .filter_map(|t| {
                let s = core[t[0] as usize]?;
                (core[t[1] as usize] == Some(s) && core[t[2] as usize] == Some(s))
                    .then_some((*t, s))
            })
            .collect();
        Self { triangles }
    }

    /// Number of core triangles tested.
    pub fn core_triangles(&self) -> usize {
        self.triangles.len()
    }

    /// Intersecting core triangle pairs of posed vertices; stops after `limit` pairs.
    pub fn find(&self, vertices: &[Vec3], limit: usize) -> Vec<Contact> {
        let cell_of = |p: Vec3| (p / CELL).floor().as_ivec3();
        let mut grid: HashMap<glam::IVec3, Vec<u32>> =
            HashMap::with_capacity(self.triangles.len() * 2);
        let mut boxes = Vec::with_capacity(self.triangles.len());
        for (k, (t, _)) in self.triangles.iter().enumerate() {
            let [a, b, c] = t.map(|i| vertices[i as usize]);
            let (lo, hi) = (a.min(b).min(c), a.max(b).max(c));
            boxes.push((lo, hi));
            let (l, h) = (cell_of(lo), cell_of(hi));
            for x in l.x..=h.x {
                for y in l.y..=h.y {
                    for z in l.z..=h.z {
                        grid.entry(glam::IVec3::new(x, y, z))
                            .or_default()
                            .push(k as u32);
                    }
                }
            }
        }
        let mut out = Vec::new();
        let mut cells: Vec<_> = grid.iter().collect();
        cells.sort_unstable_by_key(|(c, _)| (c.x, c.y, c.z));
        for (cell, list) in cells {
            for (i, &p) in list.iter().enumerate() {
                let (tp, sp) = self.triangles[p as usize];
                for &q in &list[i + 1..] {
                    let (tq, sq) = self.triangles[q as usize];
                    if sp == sq || exempt(sp, sq) {
                        continue;
                    }
                    let (lp, hp) = boxes[p as usize];
                    let (lq, hq) = boxes[q as usize];
                    if lp.cmpgt(hq).any() || lq.cmpgt(hp).any() {
                        continue;
                    }
                    // Test each pair once: in the cell holding the corner of their overlap.
                    if cell_of(lp.max(lq)) != *cell {
                        continue;
                    }
                    if triangles_intersect(
                        tp.map(|i| vertices[i as usize]),
                        tq.map(|i| vertices[i as usize]),
                    ) {
                        out.push(Contact {
                            segments: (sp, sq),
                            triangles: (p, q),
                        });
                        if out.len() >= limit {
                            return out;
                        }
                    }
                }
            }
        }
        out
    }

    /// True if any two core triangles of different (non-exempt) segments intersect.
    pub fn any(&self, vertices: &[Vec3]) -> bool {
        !self.find(vertices, 1).is_empty()
    }
}

/// Separating-axis test of two triangles (face normals, edge-edge cross products, and
/// in-plane edge normals for the coplanar case). Touching counts as intersecting.
pub fn triangles_intersect(a: [Vec3; 3], b: [Vec3; 3]) -> bool {
    let ea = [a[1] - a[0], a[2] - a[1], a[0] - a[2]];
    let eb = [b[1] - b[0], b[2] - b[1], b[0] - b[2]];
    let na = ea[0].cross(ea[1]);
    let nb = eb[0].cross(eb[1]);
    let separated = |axis: Vec3| {
        if axis.length_squared() < 1e-20 {
            return false;
        }
        let pa = a.map(|p| p.dot(axis));
        let pb = b.map(|p| p.dot(axis));
        let (amin, amax) = (pa[0].min(pa[1]).min(pa[2]), pa[0].max(pa[1]).max(pa[2]));
        let (bmin, bmax) = (pb[0].min(pb[1]).min(pb[2]), pb[0].max(pb[1]).max(pb[2]));
        amax < bmin || bmax < amin
    };
    if separated(na) || separated(nb) {
        return false;
    }
    for x in &ea {
        for y in &eb {
            if separated(x.cross(*y)) {
                return false;
            }
        }
    }
    for e in &ea {
        if separated(na.cross(*e)) {
            return false;
        }
    }
    for e in &eb {
        if separated(nb.cross(*e)) {
            return false;
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crossing_and_apart_triangles() {
        let a = [
            Vec3::new(-1.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(0.0, 1.0, 0.0),
        ];
        // Pierces a's plane inside a.
        let b = [
            Vec3::new(0.0, 0.3, -1.0),
            Vec3::new(0.0, 0.3, 1.0),
            Vec3::new(0.1, 0.5, 0.0),
        ];
        assert!(triangles_intersect(a, b));
        // Same, moved beyond a's apex.
        let c = b.map(|p| p + Vec3::new(0.0, 2.0, 0.0));
        assert!(!triangles_intersect(a, c));
        // Parallel planes.
        let d = a.map(|p| p + Vec3::new(0.0, 0.0, 0.01));
        assert!(!triangles_intersect(a, d));
        // Coplanar overlap.
        let e = a.map(|p| p * 0.5 + Vec3::new(0.1, 0.1, 0.0));
        assert!(triangles_intersect(a, e));
    }
}
