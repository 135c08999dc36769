//! Triangle meshes: the one mesh type bodies, garments and drapes share.

pub mod primitives;
pub mod remesh;

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use glam::Vec3;

/// A mesh file could not be read or is not a usable triangle mesh.
#[derive(Debug, thiserror::Error)]
#[error("cannot use mesh {path}: {reason}")]
pub struct MeshError {
    /// The file.
    pub path: PathBuf,
    /// What is wrong.
    pub reason: String,
}

/// An indexed triangle mesh in metres, Y up.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TriMesh {
    /// Vertex positions (m).
    pub vertices: Vec<Vec3>,
    /// Counter-clockwise triangles (outward normals), indices into `vertices`.
    pub triangles: Vec<[u32; 3]>,
}

impl TriMesh {
    /// Every edge of the triangles once, as `[i, j]` with `i < j`, in ascending order.
    pub fn edges(&self) -> Vec<[u32; 2]> {
        let mut edges: Vec<[u32; 2]> = self
            .triangles
            .iter()
            .flat_map(|t| [[t[0], t[1]], [t[1], t[2]], [t[2], t[0]]])
            .map(|[a, b]| [a.min(b), a.max(b)])
            .collect();
        edges.sort_unstable();
        edges.dedup();
        edges
    }

    /// Mean length of the triangles' sides (m; an edge between two triangles counts
    /// twice), at least 0.1 mm: the step that neighbour averaging spreads a value by.
    pub fn mean_side(&self) -> f32 {
        let (mut total, mut count) = (0.0f32, 0usize);
        for t in &self.triangles {
            for k in 0..3 {
                let (a, b) = (t[k] as usize, t[(k + 1) % 3] as usize);
                total += self.vertices[a].distance(self.vertices[b]);
                count += 1;
            }
        }
        (total / count.max(1) as f32).max(1e-4)
    }

    /// Signed enclosed volume (m^3) by the divergence theorem: positive for a closed mesh
    /// whose triangles wind counter-clockwise seen from outside.
    pub fn signed_volume(&self) -> f32 {
        self.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| self.vertices[i as usize]);
                a.dot(b.cross(c)) / 6.0
            })
            .sum()
    }

    /// A mesh from positions and triangles.
    pub fn new(vertices: Vec<Vec3>, triangles: Vec<[u32; 3]>) -> Self {
        Self {
            vertices,
            triangles,
        }
    }

    /// Area-weighted vertex normals (unit length; zero for unused vertices).
    pub fn vertex_normals(&self) -> Vec<Vec3> {
        vertex_normals(&self.vertices, &self.triangles)
    }

    /// Reads a Wavefront OBJ file (all its objects and groups, polygons triangulated; only
    /// positions are kept; vertices are numbered in order of first use by the faces). Rejects files without triangles, with non-finite positions or
    /// with out-of-range indices.
    pub fn read_obj(path: &Path) -> Result<Self, MeshError> {
        let err = |reason: String| MeshError {
            path: path.to_path_buf(),
            reason,
        };
        let opts = tobj::LoadOptions {
            triangulate: true,
            ignore_points: true,
            ignore_lines: true,
            ..Default::default()
        };
        // tobj says only "open file failed": name the system's reason.
        std::fs::File::open(path).map_err(|e| err(e.to_string()))?;
        let (models, _) = tobj::load_obj(path, &opts).map_err(|e| err(e.to_string()))?;
        let mut mesh = TriMesh::default();
        for m in &models {
            let base = mesh.vertices.len() as u32;
            let n = m.mesh.positions.len() / 3;
            mesh.vertices.extend(
                m.mesh
                    .positions
                    .chunks_exact(3)
                    .map(|c| Vec3::new(c[0], c[1], c[2])),
            );
            for t in m.mesh.indices.chunks_exact(3) {
                if t.iter().any(|&i| i as usize >= n) {
                    return Err(err(format!(
                        "face index out of range in object {:?}",
                        m.name
                    )));
                }
                mesh.triangles.push([base + t[0], base + t[1], base + t[2]]);
            }
        }
        if mesh.triangles.is_empty() {
            return Err(err("no faces".into()));
        }
        if mesh.vertices.iter().any(|v| !v.is_finite()) {
            return Err(err("non-finite vertex position".into()));
        }
        Ok(mesh)
    }

    /// The same mesh with vertices numbered in order of first use by the faces, as
    /// [`TriMesh::read_obj`] numbers them; unused vertices are dropped. A mesh already in
    /// that order comes back unchanged.
    pub fn in_first_use_order(&self) -> TriMesh {
        let mut map = vec![u32::MAX; self.vertices.len()];
        let mut vertices = Vec::with_capacity(self.vertices.len());
        let triangles = self
            .triangles
            .iter()
            .map(|t| {
                t.map(|i| {
                    if map[i as usize] == u32::MAX {
                        map[i as usize] = vertices.len() as u32;
                        vertices.push(self.vertices[i as usize]);
                    }
                    map[i as usize]
                })
            })
            .collect();
        TriMesh {
            vertices,
            triangles,
        }
    }

    /// Positions of a state of this mesh read back from an OBJ, in this mesh's vertex
    /// numbering: [`TriMesh::read_obj`] numbers vertices in order of first use by the faces,
    /// which a built-in template's numbering is not. `None` when `read` is not a state of
    /// this mesh: another face count, faces that do not map one to one onto this mesh's in
    /// the same order, or a vertex of this mesh no face uses.
    pub fn positions_in_my_order(&self, read: &TriMesh) -> Option<Vec<Vec3>> {
        if read.triangles.len() != self.triangles.len()
            || read.vertices.len() != self.vertices.len()
        {
            return None;
        }
        let mut from = vec![u32::MAX; self.vertices.len()];
        let mut taken = vec![false; read.vertices.len()];
        for (mine, theirs) in self.triangles.iter().zip(&read.triangles) {
            for (&i, &j) in mine.iter().zip(theirs) {
                let slot = &mut from[i as usize];
                if *slot == u32::MAX {
                    let t = taken.get_mut(j as usize)?;
                    if *t {
                        return None;
                    }
                    (*slot, *t) = (j, true);
                } else if *slot != j {
                    return None;
                }
            }
        }
        from.iter()
            .map(|&j| read.vertices.get(j as usize).copied())
            .collect()
    }

    /// The mesh as Wavefront OBJ text (`v` and `f` records, 1-based indices).
    pub fn to_obj(&self, header: &str) -> String {
        let mut s = String::with_capacity(self.vertices.len() * 40 + self.triangles.len() * 24);
        for line in header.lines() {
            let _ = writeln!(s, "# {line}");
        }
        for v in &self.vertices {
            let _ = writeln!(s, "v {:.6} {:.6} {:.6}", v.x, v.y, v.z);
        }
        for t in &self.triangles {
            let _ = writeln!(s, "f {} {} {}", t[0] + 1, t[1] + 1, t[2] + 1);
        }
        s
    }
}

/// Axis-aligned bounds of points; `None` if there are none.
pub fn bounds(points: &[Vec3]) -> Option<(Vec3, Vec3)> {
    let first = *points.first()?;
    Some(
        points
            .iter()
            .fold((first, first), |(lo, hi), &p| (lo.min(p), hi.max(p))),
    )
}

/// Area-weighted vertex normals of a triangle soup over `vertices`.
pub fn vertex_normals(vertices: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    let mut n = vec![Vec3::ZERO; vertices.len()];
    for t in triangles {
        let [a, b, c] = t.map(|i| vertices[i as usize]);
        // The cross product's length is twice the area: area weighting for free.
        let fnormal = (b - a).cross(c - a);
        for &i in t {
            n[i as usize] += fnormal;
        }
    }
    for v in &mut n {
        *v = v.normalize_or_zero();
    }
    n
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn obj_round_trip_and_bad_files() {
        let m = TriMesh::new(
            vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
            vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        );
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("t.obj");
        std::fs::write(&p, m.to_obj("tetrahedron")).unwrap();
        let back = TriMesh::read_obj(&p).unwrap();
        // Same triangles corner by corner (tobj numbers vertices in order of first use).
        assert_eq!(back.triangles.len(), m.triangles.len());
        for (a, b) in back.triangles.iter().zip(&m.triangles) {
            for k in 0..3 {
                let d = back.vertices[a[k] as usize].distance(m.vertices[b[k] as usize]);
                assert!(d < 1e-6);
            }
        }
        // A mesh in first-use order survives the round trip index for index.
        let ordered = m.in_first_use_order();
        std::fs::write(&p, ordered.to_obj("ordered")).unwrap();
        let back = TriMesh::read_obj(&p).unwrap();
        assert_eq!(back.triangles, ordered.triangles);
        assert_eq!(ordered.in_first_use_order(), ordered);
        // A state of a mesh not in first-use order maps back onto its numbering.
        let mut moved = m.clone();
        for v in &mut moved.vertices {
            *v += Vec3::new(0.5, -1.0, 2.0);
        }
        std::fs::write(&p, moved.to_obj("moved")).unwrap();
        let back = TriMesh::read_obj(&p).unwrap();
        assert_ne!(
            back.triangles, m.triangles,
            "the test mesh must not be in first-use order"
        );
        assert_eq!(m.positions_in_my_order(&back).unwrap(), moved.vertices);
        assert_eq!(m.positions_in_my_order(&m).unwrap(), m.vertices);
        // Faces of another mesh, or in another order, are not a state of it.
        let mut swapped = back.clone();
        swapped.triangles.swap(0, 1);
        assert!(m.positions_in_my_order(&swapped).is_none());
        let mut fewer = back.clone();
        fewer.triangles.pop();
        assert!(m.positions_in_my_order(&fewer).is_none());
        std::fs::write(&p, "v 0 0 0\nv 1 0 0\n").unwrap();
        assert!(
            TriMesh::read_obj(&p)
                .unwrap_err()
                .to_string()
                .contains("no faces")
        );
        assert!(TriMesh::read_obj(&dir.path().join("missing.obj")).is_err());
    }

    #[test]
    fn tetrahedron_normals_point_outwards() {
        let m = TriMesh::new(
            vec![Vec3::ZERO, Vec3::X, Vec3::Y, Vec3::Z],
            vec![[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]],
        );
        let centre = Vec3::splat(0.25);
        for (v, n) in m.vertices.iter().zip(m.vertex_normals()) {
            assert!((*v - centre).dot(n) > 0.0);
            assert!((n.length() - 1.0).abs() < 1e-6);
        }
        let obj = m.to_obj("test");
        assert_eq!(obj.lines().filter(|l| l.starts_with("v ")).count(), 4);
        assert!(obj.contains("f 2 3 4"));
    }
}
