//! Cutting a triangle mesh with a plane, and bridging two boundary loops.
//!
//! A cut removes the part of a mesh that lies beyond a plane *and* is connected to a seed
//! point without crossing the plane: cutting a sleeve with a plane across the upper arm takes
//! the forearm and the hand, not the bit of torso that happens to lie on the same side of
//! the plane further down.

use std::collections::BTreeMap;

use glam::Vec3;

use crate::mesh::TriMesh;

/// Vertices closer to the plane than this are moved onto it first, so the cut makes no
/// sliver triangles (m).
const SNAP: f32 = 0.002;

/// An oriented plane: points with `(x - point) . normal > 0` are beyond it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// A point on the plane (m).
    pub point: Vec3,
    /// Unit normal, pointing at the side a cut removes.
    pub normal: Vec3,
}

impl Plane {
    /// Signed distance of `p` (m), positive beyond the plane.
    pub fn distance(&self, p: Vec3) -> f32 {
        (p - self.point).dot(self.normal)
    }
}

/// What a cut removes: the points beyond a plane, optionally only those within `radius` of
/// an axis (a sleeve cut near the shoulder must not take the side of the torso that also
/// lies beyond its plane).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Region {
    /// The plane.
    pub plane: Plane,
    /// Axis line (a point and a unit direction) and radius (m).
    pub within: Option<(Vec3, Vec3, f32)>,
}

impl Region {
    /// Positive inside the region; for the plane part, the signed distance (m).
    pub fn value(&self, p: Vec3) -> f32 {
        let d = self.plane.distance(p);
        match self.within {
            None => d,
            Some((o, dir, r)) => {
                let v = p - o;
                d.min(r - (v - dir * v.dot(dir)).length())
            }
        }
    }
}

/// Edge-adjacent triangles of each triangle (`u32::MAX` on a boundary edge).
fn triangle_neighbours(triangles: &[[u32; 3]]) -> Vec<[u32; 3]> {
    let mut by_edge: BTreeMap<(u32, u32), Vec<u32>> = BTreeMap::new();
    for (t, tri) in triangles.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            by_edge
                .entry((a.min(b), a.max(b)))
                .or_default()
                .push(t as u32);
        }
    }
    triangles
        .iter()
        .enumerate()
        .map(|(t, tri)| {
            let mut n = [u32::MAX; 3];
            for k in 0..3 {
                let (a, b) = (tri[k], tri[(k + 1) % 3]);
                if let Some(list) = by_edge.get(&(a.min(b), a.max(b)))
                    && let Some(&o) = list.iter().find(|&&o| o != t as u32)
                {
                    n[k] = o;
                }
            }
            n
        })
        .collect()
}

/// Removes the part of `mesh` inside `region` that is connected to the vertex nearest to
/// `seed` (among the vertices inside) through triangles reaching inside it. Triangles
/// crossing the region's border are clipped to it (exactly on the plane, linearly on the
/// cylinder), so the cut leaves a clean opening. Returns the mesh unchanged when nothing
/// lies inside.
pub fn cut(mesh: &TriMesh, region: Region, seed: Vec3) -> TriMesh {
    let plane = region.plane;
    let mut x = mesh.vertices.clone();
    let mut d: Vec<f32> = x.iter().map(|&p| region.value(p)).collect();
    for (p, di) in x.iter_mut().zip(d.iter_mut()) {
        // Snap to the plane only where the plane is the border.
        let on_plane = (plane.distance(*p) - *di).abs() < 1e-7;
        if di.abs() < SNAP && on_plane {
            *p -= plane.normal * *di;
            *di = 0.0;
        }
    }
    // The seed triangle: one using the vertex beyond the plane nearest to the seed.
    let Some(start) = (0..x.len()).filter(|&i| d[i] > 0.0).min_by(|&a, &b| {
        x[a].distance_squared(seed)
            .total_cmp(&x[b].distance_squared(seed))
    }) else {
        return TriMesh::new(x, mesh.triangles.clone());
    };
    let reaches = |t: &[u32; 3]| t.iter().any(|&i| d[i as usize] > 0.0);
    let neighbours = triangle_neighbours(&mesh.triangles);
    let mut in_region = vec![false; mesh.triangles.len()];
    let mut stack: Vec<u32> = mesh
        .triangles
        .iter()
        .enumerate()
        .filter(|(_, t)| t.contains(&(start as u32)))
        .map(|(i, _)| i as u32)
        .collect();
    while let Some(t) = stack.pop() {
        let t = t as usize;
        if in_region[t] || !reaches(&mesh.triangles[t]) {
            continue;
        }
        in_region[t] = true;
        stack.extend(neighbours[t].iter().filter(|&&n| n != u32::MAX));
    }

    // Keep what is outside the region; clip what crosses the plane inside it.
    let mut splits: BTreeMap<(u32, u32), u32> = BTreeMap::new();
    let mut triangles = Vec::with_capacity(mesh.triangles.len());
    for (t, tri) in mesh.triangles.iter().enumerate() {
        if !in_region[t] {
            triangles.push(*tri);
            continue;
        }
        // Sutherland-Hodgman against d <= 0, keeping the triangle's winding.
        let mut poly: Vec<u32> = Vec::with_capacity(4);
        for k in 0..3 {
            let (a, b) = (tri[k], tri[(k + 1) % 3]);
            let (da, db) = (d[a as usize], d[b as usize]);
            if da <= 0.0 {
                poly.push(a);
            }
            if (da < 0.0 && db > 0.0) || (da > 0.0 && db < 0.0) {
                let key = (a.min(b), a.max(b));
                let v = *splits.entry(key).or_insert_with(|| {
                    let (pa, pb) = (x[a as usize], x[b as usize]);
                    let s = da / (da - db);
                    x.push(pa + (pb - pa) * s);
                    d.push(0.0);
                    x.len() as u32 - 1
                });
                poly.push(v);
            }
        }
        for k in 1..poly.len().saturating_sub(1) {
            triangles.push([poly[0], poly[k], poly[k + 1]]);
        }
    }
    compact(&x, &triangles)
}

/// Drops unused vertices, renumbering in first-use order.
pub fn compact(vertices: &[Vec3], triangles: &[[u32; 3]]) -> TriMesh {
    let mut map = vec![u32::MAX; vertices.len()];
    let mut out = Vec::new();
    let tris = triangles
        .iter()
        .map(|t| {
            t.map(|i| {
                if map[i as usize] == u32::MAX {
                    map[i as usize] = out.len() as u32;
                    out.push(vertices[i as usize]);
                }
                map[i as usize]
            })
        })
        .collect();
    TriMesh::new(out, tris)
}

/// Keeps the largest edge-connected piece of the mesh (a cut can leave crumbs).
pub fn largest_piece(mesh: &TriMesh) -> TriMesh {
    let neighbours = triangle_neighbours(&mesh.triangles);
    let mut piece = vec![u32::MAX; mesh.triangles.len()];
    let mut sizes = Vec::new();
    for s in 0..mesh.triangles.len() {
        if piece[s] != u32::MAX {
            continue;
        }
        let id = sizes.len() as u32;
        let mut size = 0usize;
        let mut stack = vec![s as u32];
        while let Some(t) = stack.pop() {
            if piece[t as usize] != u32::MAX {
                continue;
            }
            piece[t as usize] = id;
            size += 1;
            stack.extend(neighbours[t as usize].iter().filter(|&&n| n != u32::MAX));
        }
        sizes.push(size);
    }
    let Some(best) = (0..sizes.len()).max_by_key(|&i| (sizes[i], usize::MAX - i)) else {
        return mesh.clone();
    };
    let tris: Vec<[u32; 3]> = mesh
        .triangles
        .iter()
        .zip(&piece)
        .filter(|(_, p)| **p == best as u32)
        .map(|(t, _)| *t)
        .collect();
    compact(&mesh.vertices, &tris)
}

/// Boundary loops following the triangles' winding: for each boundary edge `a -> b` of a
/// triangle, `b` follows `a`. Loops start at their smallest vertex, in order of it.
pub fn directed_boundary_loops(mesh: &TriMesh) -> Vec<Vec<u32>> {
    let mut count: BTreeMap<(u32, u32), u32> = BTreeMap::new();
    for t in &mesh.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            *count.entry((a.min(b), a.max(b))).or_default() += 1;
        }
    }
    let mut next: BTreeMap<u32, u32> = BTreeMap::new();
    for t in &mesh.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if count[&(a.min(b), a.max(b))] == 1 {
                next.insert(a, b);
            }
        }
    }
    let mut loops = Vec::new();
    let mut used: BTreeMap<u32, bool> = BTreeMap::new();
    for &s in next.keys() {
        if used.contains_key(&s) {
            continue;
        }
        let mut l = vec![s];
        used.insert(s, true);
        let mut v = next[&s];
        while v != s {
            if used.contains_key(&v) {
                break;
            }
            used.insert(v, true);
            l.push(v);
            match next.get(&v) {
                Some(&n) => v = n,
                None => break,
            }
        }
        loops.push(l);
    }
    loops
}

/// Joins two meshes and stitches boundary loop `a` of `top` to boundary loop `b` of
/// `bottom` with a strip of triangles (the shorter diagonal first, as one zips two
/// polygons), keeping the winding consistent.
pub fn bridge(top: &TriMesh, a: &[u32], bottom: &TriMesh, b: &[u32]) -> TriMesh {
    let offset = top.vertices.len() as u32;
    let mut vertices = top.vertices.clone();
    vertices.extend_from_slice(&bottom.vertices);
    let mut triangles = top.triangles.clone();
    triangles.extend(bottom.triangles.iter().map(|t| t.map(|i| i + offset)));
    // Both loops follow their own surface's winding, so facing each other they run in
    // opposite directions: walk `a` backwards.
    let la: Vec<u32> = a.iter().rev().copied().collect();
    let lb: Vec<u32> = b.iter().map(|&i| i + offset).collect();
    let p = |i: u32| vertices[i as usize];
    // Start at the closest pair.
    let mut best = (0, 0, f32::MAX);
    for (i, &u) in la.iter().enumerate() {
        for (j, &v) in lb.iter().enumerate() {
            let d = p(u).distance_squared(p(v));
            if d < best.2 {
                best = (i, j, d);
            }
        }
    }
    let (n, m) = (la.len(), lb.len());
    let at_a = |k: usize| la[(best.0 + k) % n];
    let at_b = |k: usize| lb[(best.1 + k) % m];
    let (mut i, mut j) = (0, 0);
    let mut strip = Vec::with_capacity(n + m);
    while i < n || j < m {
        let advance_a = if i == n {
            false
        } else if j == m {
            true
        } else {
            p(at_a(i + 1)).distance_squared(p(at_b(j)))
                <= p(at_a(i)).distance_squared(p(at_b(j + 1)))
        };
        if advance_a {
            strip.push([at_a(i), at_a(i + 1), at_b(j)]);
            i += 1;
        } else {
            strip.push([at_a(i), at_b(j + 1), at_b(j)]);
            j += 1;
        }
    }
    // Winding: the strip must use each loop edge against the direction its own triangle
    // uses it. Check one loop edge and flip the whole strip if needed.
    let (u, w) = (a[0], a[1]);
    let same = strip
        .iter()
        .any(|t| (0..3).any(|k| t[k] == u && t[(k + 1) % 3] == w));
    if same {
        for t in &mut strip {
            t.swap(1, 2);
        }
    }
    triangles.extend(strip);
    TriMesh::new(vertices, triangles)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives;

    #[test]
    fn a_cut_takes_only_the_connected_part_beyond_the_plane() {
        // A tube along y from 0 to 1; cut at y = 0.5, seeded at the top.
        let tube = primitives::tube(Vec3::ZERO, 0.1, 1.0, 24, 20);
        let plane = Plane {
            point: Vec3::new(0.0, 0.52, 0.0),
            normal: Vec3::Y,
        };
        let region = Region {
            plane,
            within: None,
        };
        let cut = cut(&tube, region, Vec3::new(0.0, 1.0, 0.0));
        let top = cut.vertices.iter().map(|p| p.y).fold(f32::MIN, f32::max);
        assert!((top - 0.52).abs() < 1e-5, "top at {top}");
        let loops = directed_boundary_loops(&cut);
        assert_eq!(loops.len(), 2);
        // The new opening lies in the plane.
        let in_plane = loops
            .iter()
            .filter(|l| {
                l.iter()
                    .all(|&i| (cut.vertices[i as usize].y - 0.52).abs() < 1e-5)
            })
            .count();
        assert_eq!(in_plane, 1);
        // A seed far from anything beyond the plane changes nothing else: a plane that
        // misses the mesh keeps it whole.
        let miss = Plane {
            point: Vec3::new(0.0, 2.0, 0.0),
            normal: Vec3::Y,
        };
        let region = Region {
            plane: miss,
            within: None,
        };
        assert_eq!(
            super::cut(&tube, region, Vec3::Y * 3.0).triangles.len(),
            tube.triangles.len()
        );
    }

    #[test]
    fn bridging_two_tubes_makes_one_manifold_tube() {
        let upper = primitives::tube(Vec3::new(0.0, 0.5, 0.0), 0.1, 0.5, 24, 5);
        let lower = primitives::tube(Vec3::new(0.0, -0.55, 0.0), 0.12, 0.5, 17, 5);
        let la = directed_boundary_loops(&upper);
        let lb = directed_boundary_loops(&lower);
        let a = la
            .iter()
            .find(|l| upper.vertices[l[0] as usize].y < 0.6)
            .unwrap();
        let b = lb
            .iter()
            .find(|l| lower.vertices[l[0] as usize].y > -0.1)
            .unwrap();
        let joined = bridge(&upper, a, &lower, b);
        assert_eq!(directed_boundary_loops(&joined).len(), 2);
        // Every interior edge is used once in each direction.
        let mut dir: BTreeMap<(u32, u32), i32> = BTreeMap::new();
        for t in &joined.triangles {
            for k in 0..3 {
                *dir.entry((t[k], t[(k + 1) % 3])).or_default() += 1;
            }
        }
        assert!(
            dir.values().all(|&c| c == 1),
            "an edge is used twice the same way"
        );
        assert_eq!(
            joined.triangles.len(),
            upper.triangles.len() + lower.triangles.len() + 24 + 17
        );
    }
}
