//! Collision against a moving body mesh.
//!
//! The body's triangles live in an obvhs BVH built once and refitted every frame: each
//! leaf box covers its triangles at the start and at the end of the frame (a swept box),
//! inflated by the contact margin. Queries find the closest point on the body to a
//! particle within a radius; the sign of a distance comes from the angle-weighted
//! pseudo-normal of the closest feature (face, edge or vertex), which tells inside from
//! outside even for deep penetrations. Contacts cache the triangle, the barycentric
//! coordinates and the feature, so each substep can enforce them against the body
//! interpolated in time at no search cost.

use std::collections::HashMap;

use glam::{Vec3, Vec3A};
use obvhs::aabb::Aabb;
use obvhs::bvh2::Bvh2;
use rayon::prelude::*;

/// Which part of a triangle a closest point lies on.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Feature {
    /// Corner k.
    Vertex(u8),
    /// Edge from corner k to corner (k + 1) % 3.
    Edge(u8),
    /// The inside of the face.
    Face,
}

/// Closest point on a triangle: barycentric coordinates and the feature it lies on
/// (Voronoi regions of the triangle, as in Ericson, "Real-Time Collision Detection" 5.1.5).
pub fn closest_on_triangle(p: Vec3, a: Vec3, b: Vec3, c: Vec3) -> ([f32; 3], Feature) {
    let ab = b - a;
    let ac = c - a;
    let ap = p - a;
    let d1 = ab.dot(ap);
    let d2 = ac.dot(ap);
    if d1 <= 0.0 && d2 <= 0.0 {
        return ([1.0, 0.0, 0.0], Feature::Vertex(0));
    }
    let bp = p - b;
    let d3 = ab.dot(bp);
    let d4 = ac.dot(bp);
    if d3 >= 0.0 && d4 <= d3 {
        return ([0.0, 1.0, 0.0], Feature::Vertex(1));
    }
    let vc = d1 * d4 - d3 * d2;
    if vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0 {
        // d1 - d3 = |ab|^2 > 0 here unless a and b coincide.
        let v = if d1 - d3 > 0.0 { d1 / (d1 - d3) } else { 0.0 };
        return ([1.0 - v, v, 0.0], Feature::Edge(0));
    }
    let cp = p - c;
    let d5 = ab.dot(cp);
    let d6 = ac.dot(cp);
    if d6 >= 0.0 && d5 <= d6 {
        return ([0.0, 0.0, 1.0], Feature::Vertex(2));
    }
    let vb = d5 * d2 - d1 * d6;
    if vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0 {
        let w = if d2 - d6 > 0.0 { d2 / (d2 - d6) } else { 0.0 };
        return ([1.0 - w, 0.0, w], Feature::Edge(2));
    }
    let va = d3 * d6 - d5 * d4;
    if va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0 {
        let s = (d4 - d3) + (d5 - d6);
        let w = if s > 0.0 { (d4 - d3) / s } else { 0.0 };
        return ([0.0, 1.0 - w, w], Feature::Edge(1));
    }
    let sum = va + vb + vc;
    if sum <= 0.0 {
        // A degenerate triangle: its first corner stands in for it.
        return ([1.0, 0.0, 0.0], Feature::Vertex(0));
    }
    let v = vb / sum;
    let w = vc / sum;
    ([1.0 - v - w, v, w], Feature::Face)
}

/// Angle-weighted pseudo-normals of a closed triangle mesh (Baerentzen and Aanaes 2005).
#[derive(Debug, Clone, Default)]
struct PseudoNormals {
    face: Vec<Vec3>,
    edge: Vec<Vec3>,
    vertex: Vec<Vec3>,
}

/// How far (m) each surface of a crease must rise above the other's tangent plane at its
/// closest point ([`BodyCollider::crease`]): a fold, not two faces of one smooth, slightly
/// concave patch within rounding.
pub const CREASE_RISE: f32 = 0.0005;

/// The two sides of a crease face at least 60 degrees apart: the cosine between their
/// normals is below this ([`BodyCollider::crease`]). Nearly parallel surfaces one above
/// the other (the back of a hand and its knuckles) are a step, not a fold.
pub const CREASE_MAX_COS: f32 = 0.5;

/// Whether a candidate at squared distance `d2` on triangle `f` is nearer than `best`
/// (squared distance, triangle): ties (a shared edge or vertex) go to the lower triangle
/// index, so the answer does not depend on the order of the search.
#[inline]
fn nearer(d2: f32, f: u32, best: Option<(f32, u32)>) -> bool {
    best.is_none_or(|(bd, bf)| d2 < bd || (d2 == bd && f < bf))
}

/// A contact: a particle near a body triangle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Contact {
    /// Body triangle.
    pub tri: u32,
    /// Barycentric coordinates of the closest point.
    pub bary: [f32; 3],
    /// Feature of the closest point (for its pseudo-normal).
    pub feature: Feature,
}

/// Result of a closest-point query.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Hit {
    /// The contact (triangle, barycentrics, feature).
    pub contact: Contact,
    /// Closest point on the body (m).
    pub point: Vec3,
    /// Pseudo-normal at that point.
    pub normal: Vec3,
    /// Signed distance: negative inside the body (m).
    pub distance: f32,
}

/// The moving body: triangles, positions at the start and end of the current frame, the
/// BVH over their swept boxes and the pseudo-normals at both ends.
#[derive(Clone)]
pub struct BodyCollider {
    triangles: Vec<[u32; 3]>,
    tri_edges: Vec<[u32; 3]>,
    edge_faces: Vec<[u32; 2]>,
    start: Vec<Vec3>,
    end: Vec<Vec3>,
    normals_start: PseudoNormals,
    normals_end: PseudoNormals,
    bvh: Bvh2,
    /// Each triangle's swept box, inflated by the margin.
    boxes: Vec<Aabb>,
    /// The corners around each vertex, as `3 * triangle + corner` in triangle order:
    /// vertex `v`'s are `corners[corner_start[v]..corner_start[v + 1]]`.
    corners: Vec<u32>,
    corner_start: Vec<u32>,
    margin: f32,
    travel: f32,
    /// Move the body (pseudo-normals, swept boxes) on rayon's threads.
    parallel: bool,
}

/// `out[i] = f(i)` for every `i`, on rayon's threads or on this one. Each item is computed
/// alone, so the bits are the same either way.
fn fill<T: Send>(parallel: bool, out: &mut [T], f: impl Fn(usize) -> T + Sync) {
    if parallel {
        out.par_iter_mut().enumerate().for_each(|(i, o)| *o = f(i));
    } else {
        out.iter_mut().enumerate().for_each(|(i, o)| *o = f(i));
    }
}

impl std::fmt::Debug for BodyCollider {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("BodyCollider")
            .field("triangles", &self.triangles.len())
            .field("vertices", &self.end.len())
            .field("bvh_nodes", &self.bvh.nodes.len())
            .finish()
    }
}

fn to_a(v: Vec3) -> Vec3A {
    Vec3A::from(v)
}

impl BodyCollider {
    /// A static body. `margin` inflates the BVH boxes (m). The mesh should be closed and
    /// consistently oriented (outward normals) for the inside/outside test.
    pub fn new(vertices: &[Vec3], triangles: &[[u32; 3]], margin: f32) -> Self {
        let mut edge_id: HashMap<(u32, u32), u32> = HashMap::new();
        let mut edge_faces: Vec<[u32; 2]> = Vec::new();
        let mut tri_edges = Vec::with_capacity(triangles.len());
        for (f, t) in triangles.iter().enumerate() {
            let mut ids = [0u32; 3];
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let key = (a.min(b), a.max(b));
                let id = *edge_id.entry(key).or_insert_with(|| {
                    edge_faces.push([f as u32, f as u32]);
                    edge_faces.len() as u32 - 1
                });
                edge_faces[id as usize][1] = f as u32;
                ids[k] = id;
            }
            tri_edges.push(ids);
        }
        let boxes: Vec<Aabb> = triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| to_a(vertices[i as usize]));
                Aabb::new(a.min(b).min(c), a.max(b).max(c))
            })
            .collect();
        let mut build_time = std::time::Duration::ZERO;
        let bvh = obvhs::bvh2::builder::build_bvh2(
            &boxes,
            obvhs::BvhBuildParams::fast_build(),
            &mut build_time,
        );
        // Corners grouped by vertex, each group in triangle order (a counting sort).
        let mut corner_start = vec![0u32; vertices.len() + 1];
        for t in triangles {
            for &i in t {
                corner_start[i as usize + 1] += 1;
            }
        }
        for v in 0..vertices.len() {
            corner_start[v + 1] += corner_start[v];
        }
        let mut next = corner_start.clone();
        let mut corners = vec![0u32; 3 * triangles.len()];
        for (f, t) in triangles.iter().enumerate() {
            for (k, &i) in t.iter().enumerate() {
                corners[next[i as usize] as usize] = 3 * f as u32 + k as u32;
                next[i as usize] += 1;
            }
        }
        let mut me = Self {
            triangles: triangles.to_vec(),
            tri_edges,
            edge_faces,
            start: vertices.to_vec(),
            end: vertices.to_vec(),
            normals_start: PseudoNormals::default(),
            normals_end: PseudoNormals::default(),
            bvh,
            boxes: vec![Aabb::INVALID; triangles.len()],
            corners,
            corner_start,
            margin,
            travel: 0.0,
            parallel: false,
        };
        let mut normals = PseudoNormals::default();
        me.pseudo_normals(&me.end, &mut normals);
        me.normals_start = normals.clone();
        me.normals_end = normals;
        me.refit();
        me
    }

    /// Moves the body on rayon's threads (`true`) or on the calling one (the default). The
    /// positions, normals and boxes are the same to the bit either way.
    pub fn set_parallel(&mut self, parallel: bool) {
        self.parallel = parallel;
    }

    /// True if the body moves on rayon's threads ([`BodyCollider::set_parallel`]).
    pub fn is_parallel(&self) -> bool {
        self.parallel
    }

    /// Body positions at the end of the frame.
    pub fn positions(&self) -> &[Vec3] {
        &self.end
    }

    /// Starts a new frame in which the body moves from its current positions to `next`;
    /// refits the BVH to the swept boxes.
    pub fn advance(&mut self, next: &[Vec3]) {
        assert_eq!(next.len(), self.end.len(), "the body keeps its topology");
        std::mem::swap(&mut self.start, &mut self.end);
        self.end.copy_from_slice(next);
        std::mem::swap(&mut self.normals_start, &mut self.normals_end);
        let mut normals = std::mem::take(&mut self.normals_end);
        self.pseudo_normals(&self.end, &mut normals);
        self.normals_end = normals;
        self.travel = self
            .start
            .iter()
            .zip(&self.end)
            .map(|(a, b)| a.distance_squared(*b))
            .fold(0.0, f32::max)
            .sqrt();
        self.refit();
    }

    /// Largest distance a body vertex moves in the current frame (m).
    pub fn travel(&self) -> f32 {
        self.travel
    }

    /// Starts a new frame in which the body does not move.
    pub fn hold(&mut self) {
        if self.start != self.end {
            self.start.copy_from_slice(&self.end);
            self.normals_start = self.normals_end.clone();
            self.travel = 0.0;
            self.refit();
        }
    }

    fn refit(&mut self) {
        let m = Vec3A::splat(self.margin);
        let (triangles, start, end) = (&self.triangles, &self.start, &self.end);
        fill(self.parallel, &mut self.boxes, |f| {
            let mut bb = Aabb::INVALID;
            for &i in &triangles[f] {
                bb.extend(to_a(start[i as usize]));
                bb.extend(to_a(end[i as usize]));
            }
            Aabb::new(bb.min - m, bb.max + m)
        });
        let boxes = &self.boxes;
        let Bvh2 {
            nodes,
            primitive_indices,
            ..
        } = &mut self.bvh;
        let leaf = |node: &mut obvhs::bvh2::node::Bvh2Node| {
            if node.is_leaf() {
                let mut bb = Aabb::INVALID;
                for k in node.first_index..node.first_index + node.prim_count {
                    bb = bb.union(&boxes[primitive_indices[k as usize] as usize]);
                }
                node.set_aabb(bb);
            }
        };
        if self.parallel {
            nodes.par_iter_mut().for_each(leaf);
        } else {
            nodes.iter_mut().for_each(leaf);
        }
        self.bvh.refit_all();
    }

    /// Angle-weighted pseudo-normals of the body at positions `x`, into `out`. Each
    /// vertex sums its corners' angle-weighted face normals in triangle order, so the
    /// bits do not depend on the thread count.
    fn pseudo_normals(&self, x: &[Vec3], out: &mut PseudoNormals) {
        let par = self.parallel;
        let tris = &self.triangles;
        out.face.resize(tris.len(), Vec3::ZERO);
        fill(par, &mut out.face, |f| {
            let [a, b, c] = tris[f].map(|i| x[i as usize]);
            (b - a).cross(c - a).normalize_or_zero()
        });
        let face = &out.face;
        out.edge.resize(self.edge_faces.len(), Vec3::ZERO);
        fill(par, &mut out.edge, |e| {
            let [f, g] = self.edge_faces[e];
            (face[f as usize] + face[g as usize]).normalize_or_zero()
        });
        out.vertex.resize(x.len(), Vec3::ZERO);
        let (corners, corner_start) = (&self.corners, &self.corner_start);
        fill(par, &mut out.vertex, |v| {
            let mut sum = Vec3::ZERO;
            let range = corner_start[v] as usize..corner_start[v + 1] as usize;
            for &c in &corners[range] {
                let (f, k) = (c as usize / 3, c as usize % 3);
                let t = tris[f];
                let p = x[t[k] as usize];
                let e1 = (x[t[(k + 1) % 3] as usize] - p).normalize_or_zero();
                let e2 = (x[t[(k + 2) % 3] as usize] - p).normalize_or_zero();
                sum += face[f] * e1.dot(e2).clamp(-1.0, 1.0).acos();
            }
            sum.normalize_or_zero()
        });
    }

    /// Position of a contact's point on the body at time `t` in [0, 1] of the frame.
    #[inline]
    pub fn point_at(&self, c: &Contact, t: f32) -> Vec3 {
        let tri = self.triangles[c.tri as usize];
        let mut q = Vec3::ZERO;
        for k in 0..3 {
            let i = tri[k] as usize;
            q += c.bary[k] * self.start[i].lerp(self.end[i], t);
        }
        q
    }

    fn feature_normal(&self, normals: &PseudoNormals, c: &Contact) -> Vec3 {
        match c.feature {
            Feature::Face => normals.face[c.tri as usize],
            Feature::Edge(k) => normals.edge[self.tri_edges[c.tri as usize][k as usize] as usize],
            Feature::Vertex(k) => {
                normals.vertex[self.triangles[c.tri as usize][k as usize] as usize]
            }
        }
    }

    /// Pseudo-normal of a contact's feature at time `t` of the frame.
    #[inline]
    pub fn normal_at(&self, c: &Contact, t: f32) -> Vec3 {
        let a = self.feature_normal(&self.normals_start, c);
        let b = self.feature_normal(&self.normals_end, c);
        a.lerp(b, t).normalize_or_zero()
    }

    /// The triangle closest to `p` at the end of the frame among those whose swept,
    /// margin-inflated boxes come within `radius` of `p`: squared distance, triangle,
    /// barycentrics and feature.
    fn nearest_candidate(&self, p: Vec3, radius: f32) -> Option<(f32, u32, [f32; 3], Feature)> {
        self.nearest_where(p, radius, |_, _, _| true)
    }

    /// Calls `visit(squared distance, triangle, barycentrics, feature, closest point)` for
    /// every triangle whose swept, margin-inflated box comes within `radius` of `p`, with
    /// its point closest to `p` at the end of the frame.
    #[inline]
    fn candidates(
        &self,
        p: Vec3,
        radius: f32,
        mut visit: impl FnMut(f32, u32, [f32; 3], Feature, Vec3),
    ) {
        let r = Vec3A::splat(radius);
        let query = Aabb::new(to_a(p) - r, to_a(p) + r);
        self.bvh.aabb_traverse(query, |bvh, node_index| {
            let node = &bvh.nodes[node_index as usize];
            for k in node.first_index..node.first_index + node.prim_count {
                let f = bvh.primitive_indices[k as usize];
                // Each triangle's own swept box: the candidates do not depend on how the
                // tree grouped triangles into leaves.
                if !self.boxes[f as usize].intersect_aabb(&query) {
                    continue;
                }
                let [a, b, c] = self.triangles[f as usize].map(|i| self.end[i as usize]);
                let (bary, feature) = closest_on_triangle(p, a, b, c);
                let q = a * bary[0] + b * bary[1] + c * bary[2];
                let d2 = p.distance_squared(q);
                if d2.is_finite() {
                    visit(d2, f, bary, feature, q);
                }
            }
            true
        });
    }

    /// [`Self::nearest_candidate`] among the triangles that `accept` (triangle, closest
    /// point, contact) lets through.
    #[inline]
    fn nearest_where(
        &self,
        p: Vec3,
        radius: f32,
        accept: impl Fn(u32, Vec3, &Contact) -> bool,
    ) -> Option<(f32, u32, [f32; 3], Feature)> {
        let mut best: Option<(f32, u32, [f32; 3], Feature)> = None;
        self.candidates(p, radius, |d2, f, bary, feature, q| {
            if nearer(d2, f, best.map(|b| (b.0, b.1)))
                && accept(
                    f,
                    q,
                    &Contact {
                        tri: f,
                        bary,
                        feature,
                    },
                )
            {
                best = Some((d2, f, bary, feature));
            }
        });
        best
    }

    /// The contact a particle at `p` may meet this frame: the body triangle nearest at the
    /// end of the frame among those whose swept boxes (inflated by the margin) come within
    /// `reach` of `p`. No distance cut: a far contact only constrains a particle that gets
    /// closer than the thickness.
    pub fn contact(&self, p: Vec3, reach: f32) -> Option<Contact> {
        self.nearest_candidate(p, reach)
            .map(|(_, tri, bary, feature)| Contact { tri, bary, feature })
    }

    /// The other side of a crease at a particle at `p` whose [`Self::contact`] is `first`:
    /// the nearest candidate triangle (as for `contact`, within `reach`) that faces at
    /// least 60 degrees away from `first` ([`CREASE_MAX_COS`]), rises above `first`'s
    /// tangent plane while `first` lies above its own, both by more than [`CREASE_RISE`],
    /// and has `p` on its outer side. Where the body folds on itself (a raised thigh
    /// against the belly, two legs pressed together) the free space is the wedge outside
    /// both surfaces, and a particle pushed out of one surface alone can land inside the
    /// other; on a convex part (a finger, a shoulder) every other triangle falls away
    /// below the first's plane and none is returned, as there a second plane would push
    /// the particle off a surface it is not near. A particle behind the other side's plane is not in the
    /// fold's free space (the body may intersect itself there, a forearm sunk into the hip)
    /// and gets none: that plane would carry it through the body.
    pub fn crease(&self, p: Vec3, reach: f32, first: &Contact) -> Option<Contact> {
        let is_other_side = self.other_side(p, first);
        self.nearest_where(p, reach, |f, q, c| is_other_side(f, q, c))
            .map(|(_, tri, bary, feature)| Contact { tri, bary, feature })
    }

    /// Whether a triangle, its point `q` closest to `p` and contact `c` make the other side
    /// of a crease at `p` whose contact is `first` ([`Self::crease`]).
    fn other_side(&self, p: Vec3, first: &Contact) -> impl Fn(u32, Vec3, &Contact) -> bool {
        let q1 = self.point_at(first, 1.0);
        let n1 = self.feature_normal(&self.normals_end, first);
        let tri = first.tri;
        move |f, q, c| {
            if f == tri || (q - q1).dot(n1) <= CREASE_RISE {
                return false;
            }
            let n = self.feature_normal(&self.normals_end, c);
            n.dot(n1) < CREASE_MAX_COS && (q1 - q).dot(n) > CREASE_RISE && (p - q).dot(n) >= 0.0
        }
    }

    /// [`Self::contact`] and, if there is one, [`Self::crease`] from one search of the
    /// candidates, with the same answers as the two calls: two searches made a 10k T-shirt
    /// drape 22% slower in CPU time than the nearest surface alone, one 4.6% (docs/sim.md,
    /// "Creases").
    pub fn contact_and_crease(&self, p: Vec3, reach: f32) -> (Option<Contact>, Option<Contact>) {
        /// Candidates kept for the crease (more: a second search).
        const KEPT: usize = 48;
        let mut kept = [(0.0f32, 0u32, [0.0f32; 3], Feature::Face, Vec3::ZERO); KEPT];
        let (mut n, mut overflow) = (0usize, false);
        let mut best: Option<(f32, u32, [f32; 3], Feature)> = None;
        self.candidates(p, reach, |d2, f, bary, feature, q| {
            if nearer(d2, f, best.map(|b| (b.0, b.1))) {
                best = Some((d2, f, bary, feature));
            }
            if n < KEPT {
                kept[n] = (d2, f, bary, feature, q);
                n += 1;
            } else {
                overflow = true;
            }
        });
        let Some((_, tri, bary, feature)) = best else {
            return (None, None);
        };
        let first = Contact { tri, bary, feature };
        if overflow {
            return (Some(first), self.crease(p, reach, &first));
        }
        let is_other_side = self.other_side(p, &first);
        let mut other: Option<(f32, u32, [f32; 3], Feature)> = None;
        for &(d2, f, bary, feature, q) in &kept[..n] {
            if nearer(d2, f, other.map(|b| (b.0, b.1)))
                && is_other_side(
                    f,
                    q,
                    &Contact {
                        tri: f,
                        bary,
                        feature,
                    },
                )
            {
                other = Some((d2, f, bary, feature));
            }
        }
        (
            Some(first),
            other.map(|(_, tri, bary, feature)| Contact { tri, bary, feature }),
        )
    }

    /// Margin the BVH boxes are inflated by (m).
    pub fn margin(&self) -> f32 {
        self.margin
    }

    /// The closest point on the body (at the end of the frame) to `p`, if it lies within
    /// `radius`.
    pub fn closest(&self, p: Vec3, radius: f32) -> Option<Hit> {
        // A narrow search first: a triangle found at a distance d within the narrow radius
        // is also the nearest of the wide search (its box meets every query box of half-size
        // d or more, and ties go to the same lower index), so the wide search, which visits
        // many more triangles, runs only when nothing is that close.
        let narrow = (radius > NARROW_RADIUS)
            .then(|| self.nearest_candidate(p, NARROW_RADIUS))
            .flatten()
            .filter(|c| c.0 <= NARROW_RADIUS * NARROW_RADIUS);
        let (d2, tri, bary, feature) = match narrow {
            Some(c) => c,
            None => self.nearest_candidate(p, radius)?,
        };
        if d2 > radius * radius {
            return None;
        }
        let contact = Contact { tri, bary, feature };
        let point = self.point_at(&contact, 1.0);
        let normal = self.feature_normal(&self.normals_end, &contact);
        let dist = d2.sqrt();
        let sign = if (p - point).dot(normal) < 0.0 {
            -1.0
        } else {
            1.0
        };
        Some(Hit {
            contact,
            point,
            normal,
            distance: sign * dist,
        })
    }

    /// True if `p` is inside the (closed) body at the end of the frame: a ray from `p`
    /// crosses the body an odd number of times. Works at any depth, unlike distances. A ray
    /// through a shared edge or vertex can be miscounted, so three rays in unrelated
    /// directions vote.
    pub fn inside(&self, p: Vec3) -> bool {
        const DIRS: [[f32; 3]; 3] = [
            [0.5773, 0.5774, 0.5773],
            [-0.6712, 0.2331, 0.7036],
            [0.1289, -0.8911, -0.4352],
        ];
        let votes = DIRS
            .iter()
            .filter(|d| {
                let dir = Vec3::from_array(**d).normalize();
                let ray = obvhs::ray::Ray::new_inf(to_a(p), to_a(dir));
                let mut crossings = 0u32;
                self.bvh.ray_traverse_anyhit(ray, |_, k| {
                    let f = self.bvh.primitive_indices[k];
                    let [a, b, c] = self.triangles[f as usize].map(|i| self.end[i as usize]);
                    if ray_hits_triangle(p, dir, a, b, c) {
                        crossings += 1;
                    }
                });
                crossings % 2 == 1
            })
            .count();
        votes >= 2
    }

    /// Triangles of the body.
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// How thick the body is under each triangle (at the end of the frame): the distance
    /// from the triangle's centroid along its inward face normal to the next triangle the
    /// ray crosses, or infinity if none lies within `max` (m). About a finger's width on a
    /// finger, a torso's depth on the torso.
    pub fn local_thickness(&self, max: f32) -> Vec<f32> {
        let mut out = vec![f32::INFINITY; self.triangles.len()];
        let x = &self.end;
        fill(self.parallel, &mut out, |f| {
            let [a, b, c] = self.triangles[f].map(|i| x[i as usize]);
            let n = (b - a).cross(c - a).normalize_or_zero();
            if n == Vec3::ZERO {
                return f32::INFINITY;
            }
            let (origin, dir) = ((a + b + c) / 3.0, -n);
            let ray = obvhs::ray::Ray::new(to_a(origin), to_a(dir), 0.0, max);
            let mut nearest = f32::INFINITY;
            self.bvh.ray_traverse_anyhit(ray, |_, k| {
                let g = self.bvh.primitive_indices[k];
                if g as usize == f {
                    return;
                }
                let [p, q, r] = self.triangles[g as usize].map(|i| x[i as usize]);
                if let Some(t) = ray_triangle(origin, dir, p, q, r, 1e-4) {
                    // Hits in the first tenth of a millimetre are the triangle's own
                    // neighbours at its corners.
                    if t > 1e-4 && t <= max {
                        nearest = nearest.min(t);
                    }
                }
            });
            nearest
        });
        out
    }

    /// Signed distance of `p` to the body within `radius` (positive outside), if any part of
    /// the body is that close.
    pub fn signed_distance(&self, p: Vec3, radius: f32) -> Option<f32> {
        self.closest(p, radius).map(|h| h.distance)
    }
}

/// Radius of [`BodyCollider::closest`]'s first, narrow search (m).
const NARROW_RADIUS: f32 = 0.01;

/// Moeller-Trumbore: does the ray `origin + t dir`, t > 0, cross the triangle?
fn ray_hits_triangle(origin: Vec3, dir: Vec3, a: Vec3, b: Vec3, c: Vec3) -> bool {
    ray_triangle(origin, dir, a, b, c, 0.0).is_some()
}

/// Moeller-Trumbore: the `t > 0` at which the ray `origin + t dir` crosses the triangle,
/// the triangle widened by `slack` in barycentric terms (a ray through a shared edge
/// then hits both triangles, where without slack rounding can miss both).
fn ray_triangle(origin: Vec3, dir: Vec3, a: Vec3, b: Vec3, c: Vec3, slack: f32) -> Option<f32> {
    let e1 = b - a;
    let e2 = c - a;
    let p = dir.cross(e2);
    let det = e1.dot(p);
    if det.abs() < 1e-12 {
        return None;
    }
    let inv = 1.0 / det;
    let s = origin - a;
    let u = s.dot(p) * inv;
    if !(-slack..=1.0 + slack).contains(&u) {
        return None;
    }
    let q = s.cross(e1);
    let v = dir.dot(q) * inv;
    if v < -slack || u + v > 1.0 + slack {
        return None;
    }
    let t = e2.dot(q) * inv;
    (t > 0.0).then_some(t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives;

    #[test]
    fn closest_point_regions() {
        let (a, b, c) = (Vec3::ZERO, Vec3::X, Vec3::Y);
        assert_eq!(
            closest_on_triangle(Vec3::new(-1.0, -1.0, 0.3), a, b, c).1,
            Feature::Vertex(0)
        );
        assert_eq!(
            closest_on_triangle(Vec3::new(0.5, -1.0, 0.0), a, b, c).1,
            Feature::Edge(0)
        );
        assert_eq!(
            closest_on_triangle(Vec3::new(1.0, 1.0, 0.0), a, b, c).1,
            Feature::Edge(1)
        );
        assert_eq!(
            closest_on_triangle(Vec3::new(-1.0, 0.5, 0.0), a, b, c).1,
            Feature::Edge(2)
        );
        let (bary, f) = closest_on_triangle(Vec3::new(0.2, 0.3, 5.0), a, b, c);
        assert_eq!(f, Feature::Face);
        assert!((bary[1] - 0.2).abs() < 1e-6 && (bary[2] - 0.3).abs() < 1e-6);
    }

    #[test]
    fn signed_distance_to_a_sphere() {
        let s = primitives::uv_sphere(Vec3::ZERO, 0.5, 48, 24);
        let body = BodyCollider::new(&s.vertices, &s.triangles, 0.01);
        for &(p, expect) in &[
            (Vec3::new(0.0, 0.0, 0.6), 0.1),
            (Vec3::new(0.45, 0.0, 0.0), -0.05),
            (Vec3::new(0.3, 0.3, 0.3), 0.27f32.sqrt() - 0.5),
            (Vec3::new(0.0, -0.7, 0.0), 0.2),
        ] {
            let d = body.signed_distance(p, 0.5).unwrap();
            assert!((d - expect).abs() < 0.01, "{p}: {d} vs {expect}");
        }
        assert!(
            body.signed_distance(Vec3::new(0.0, 2.0, 0.0), 0.1)
                .is_none()
        );
        // Inside at any depth; outside far away.
        assert!(body.inside(Vec3::ZERO));
        assert!(body.inside(Vec3::new(0.1, -0.2, 0.05)));
        assert!(!body.inside(Vec3::new(0.0, 0.0, 0.7)));
        assert!(!body.inside(Vec3::new(3.0, 1.0, -2.0)));
    }

    #[test]
    fn a_crease_is_found_between_two_surfaces_and_not_on_a_convex_part() {
        // Two spheres 6 mm apart along X: the gap between them is a crease.
        let mut two = primitives::uv_sphere(Vec3::new(-0.103, 0.0, 0.0), 0.1, 48, 24);
        let b = primitives::uv_sphere(Vec3::new(0.103, 0.0, 0.0), 0.1, 48, 24);
        let base = two.vertices.len() as u32;
        two.vertices.extend(&b.vertices);
        two.triangles
            .extend(b.triangles.iter().map(|t| t.map(|i| i + base)));
        let body = BodyCollider::new(&two.vertices, &two.triangles, 0.01);
        // In the gap, a little nearer the left sphere: its contact on the left sphere's
        // right side, the crease's other side on the right sphere's left side.
        let p = Vec3::new(-0.001, 0.004, 0.0);
        let first = body.contact(p, 0.01).unwrap();
        assert!(body.normal_at(&first, 1.0).x > 0.9);
        let other = body
            .crease(p, 0.01, &first)
            .expect("a crease between the spheres");
        // One search gives both.
        assert_eq!(body.contact_and_crease(p, 0.01), (Some(first), Some(other)));
        let n = body.normal_at(&other, 1.0);
        assert!(n.x < -0.9, "{n}");
        assert!((body.point_at(&other, 1.0).x - 0.003).abs() < 0.001);
        // Over the outer side of a sphere, and over a box's edge and corner: none.
        let far = Vec3::new(-0.205, 0.0, 0.0);
        assert!(
            body.crease(far, 0.01, &body.contact(far, 0.01).unwrap())
                .is_none()
        );
        let cube = primitives::cuboid(Vec3::ZERO, Vec3::splat(0.1), 6);
        let body = BodyCollider::new(&cube.vertices, &cube.triangles, 0.01);
        for p in [
            Vec3::new(0.09, 0.103, 0.0),
            Vec3::new(0.102, 0.102, 0.0),
            Vec3::new(0.102, 0.102, 0.102),
            Vec3::new(0.0, 0.103, 0.0),
        ] {
            let first = body.contact(p, 0.01).unwrap();
            assert!(body.crease(p, 0.01, &first).is_none(), "{p}");
            assert_eq!(body.contact_and_crease(p, 0.01), (Some(first), None));
        }
    }

    #[test]
    fn degenerate_triangles_give_finite_answers() {
        let (a, b) = (Vec3::ZERO, Vec3::X);
        for p in [
            Vec3::new(0.5, 1.0, 0.0),
            Vec3::new(-1.0, 0.0, 0.0),
            Vec3::new(0.0, 0.0, 2.0),
        ] {
            for (x, y, z) in [(a, a, b), (a, b, b), (a, b, a), (a, a, a)] {
                let (bary, _) = closest_on_triangle(p, x, y, z);
                assert!(
                    bary.iter().all(|w| w.is_finite()),
                    "{p} {x} {y} {z}: {bary:?}"
                );
            }
        }
    }

    #[test]
    fn moving_body_interpolates_contacts() {
        let s = primitives::uv_sphere(Vec3::ZERO, 0.5, 24, 12);
        let mut body = BodyCollider::new(&s.vertices, &s.triangles, 0.01);
        let moved: Vec<Vec3> = s.vertices.iter().map(|v| *v + Vec3::X * 0.2).collect();
        body.advance(&moved);
        // A point 0.55 to the right of the new centre is found by the swept boxes.
        let hit = body.closest(Vec3::new(0.75, 0.0, 0.0), 0.1).unwrap();
        assert!((hit.distance - 0.05).abs() < 0.01, "{}", hit.distance);
        let half = body.point_at(&hit.contact, 0.5);
        assert!((half.x - 0.6).abs() < 0.01, "{half}");
    }

    #[test]
    fn moving_the_body_on_two_threads_gives_the_same_bits() {
        // A lumpy sphere (so the vertices differ in valence and angles) moved and deformed;
        // the body moved on two threads against one, and the vertex pseudo-normals against
        // a plain scatter over the triangles, the order a sum over triangles takes.
        let s = primitives::uv_sphere(Vec3::ZERO, 0.5, 48, 24);
        let lumpy = |t: f32| -> Vec<Vec3> {
            s.vertices
                .iter()
                .map(|v| *v * (1.0 + 0.2 * (7.0 * v.x + 3.0 * t).sin() * v.y) + Vec3::X * t)
                .collect()
        };
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let mut one = BodyCollider::new(&lumpy(0.0), &s.triangles, 0.01);
        let mut two = one.clone();
        two.set_parallel(true);
        for k in 1..4 {
            let next = lumpy(0.1 * k as f32);
            one.advance(&next);
            pool.install(|| two.advance(&next));
        }
        pool.install(|| two.hold());
        one.hold();
        let bits = |v: &[Vec3]| {
            v.iter()
                .map(|p| p.to_array().map(f32::to_bits))
                .collect::<Vec<_>>()
        };
        for (a, b) in [
            (&one.normals_end, &two.normals_end),
            (&one.normals_start, &two.normals_start),
        ] {
            assert_eq!(bits(&a.face), bits(&b.face));
            assert_eq!(bits(&a.edge), bits(&b.edge));
            assert_eq!(bits(&a.vertex), bits(&b.vertex));
        }
        let boxes = |c: &BodyCollider| {
            c.bvh
                .nodes
                .iter()
                .map(|n| [n.aabb().min, n.aabb().max].map(|v| v.to_array().map(f32::to_bits)))
                .collect::<Vec<_>>()
        };
        assert_eq!(boxes(&one), boxes(&two));
        let x = one.positions();
        let mut scatter = vec![Vec3::ZERO; x.len()];
        for (t, n) in one.triangles.iter().zip(&one.normals_end.face) {
            for k in 0..3 {
                let p = x[t[k] as usize];
                let e1 = (x[t[(k + 1) % 3] as usize] - p).normalize_or_zero();
                let e2 = (x[t[(k + 2) % 3] as usize] - p).normalize_or_zero();
                scatter[t[k] as usize] += *n * e1.dot(e2).clamp(-1.0, 1.0).acos();
            }
        }
        let scatter: Vec<Vec3> = scatter.iter().map(|v| v.normalize_or_zero()).collect();
        assert_eq!(bits(&scatter), bits(&one.normals_end.vertex));
        // And they point outwards on the sphere's lumps, as a pseudo-normal must.
        let c = x.iter().copied().sum::<Vec3>() / x.len() as f32;
        assert!(x.iter().zip(&scatter).all(|(p, n)| n.dot(*p - c) > 0.0));
    }
}
