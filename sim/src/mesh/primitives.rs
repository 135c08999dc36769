//! Procedural meshes for tests and scenes: a cloth grid, a sphere, a box, a cylinder and
//! an open tube. Closed ones have outward (counter-clockwise) triangles.

use glam::Vec3;

use super::TriMesh;

/// A flat rectangular cloth of `nu x nv` quads spanning `u` and `v` from `origin`, each
/// quad split along alternating diagonals (no preferred shear direction).
pub fn grid(origin: Vec3, u: Vec3, v: Vec3, nu: u32, nv: u32) -> TriMesh {
    let mut vertices = Vec::with_capacity(((nu + 1) * (nv + 1)) as usize);
    for j in 0..=nv {
        for i in 0..=nu {
            vertices.push(origin + u * (i as f32 / nu as f32) + v * (j as f32 / nv as f32));
        }
    }
    let id = |i: u32, j: u32| j * (nu + 1) + i;
    let mut triangles = Vec::with_capacity((2 * nu * nv) as usize);
    for j in 0..nv {
        for i in 0..nu {
            let (a, b, c, d) = (id(i, j), id(i + 1, j), id(i + 1, j + 1), id(i, j + 1));
            if (i + j) % 2 == 0 {
                triangles.extend([[a, b, c], [a, c, d]]);
            } else {
                triangles.extend([[a, b, d], [b, c, d]]);
            }
        }
    }
    TriMesh::new(vertices, triangles)
}

/// A UV sphere with `nu` segments around and `nv` rings.
pub fn uv_sphere(centre: Vec3, radius: f32, nu: u32, nv: u32) -> TriMesh {
    let mut vertices = vec![centre + Vec3::Y * radius];
    for j in 1..nv {
        let theta = std::f32::consts::PI * j as f32 / nv as f32;
        for i in 0..nu {
            let phi = std::f32::consts::TAU * i as f32 / nu as f32;
            let dir = Vec3::new(
                theta.sin() * phi.cos(),
                theta.cos(),
                -theta.sin() * phi.sin(),
            );
            vertices.push(centre + dir * radius);
        }
    }
    vertices.push(centre - Vec3::Y * radius);
    let bottom = vertices.len() as u32 - 1;
    let ring = |j: u32, i: u32| 1 + (j - 1) * nu + (i % nu);
    let mut triangles = Vec::new();
    for i in 0..nu {
        triangles.push([0, ring(1, i), ring(1, i + 1)]);
        triangles.push([bottom, ring(nv - 1, i + 1), ring(nv - 1, i)]);
    }
    for j in 1..nv - 1 {
        for i in 0..nu {
            let (a, b, c, d) = (
                ring(j, i),
                ring(j + 1, i),
                ring(j + 1, i + 1),
                ring(j, i + 1),
            );
            triangles.extend([[a, b, c], [a, c, d]]);
        }
    }
    TriMesh::new(vertices, triangles)
}

/// An axis-aligned box, each face split into `n x n` quads.
pub fn cuboid(centre: Vec3, half: Vec3, n: u32) -> TriMesh {
    let mut mesh = TriMesh::default();
    let faces = [
        (Vec3::X, Vec3::Y, Vec3::Z),
        (-Vec3::X, Vec3::Z, Vec3::Y),
        (Vec3::Y, Vec3::Z, Vec3::X),
        (-Vec3::Y, Vec3::X, Vec3::Z),
        (Vec3::Z, Vec3::X, Vec3::Y),
        (-Vec3::Z, Vec3::Y, Vec3::X),
    ];
    for (normal, u, v) in faces {
        let origin = centre + (normal - u - v) * half;
        let face = grid(origin, 2.0 * u * half, 2.0 * v * half, n, n);
        append_welded(&mut mesh, &face);
    }
    mesh
}

/// A cylinder along Y from `base` up by `height`, `segments` around, `rings` along, closed
/// with flat caps.
pub fn cylinder(base: Vec3, radius: f32, height: f32, segments: u32, rings: u32) -> TriMesh {
    let mut mesh = tube(base, radius, height, segments, rings);
    for (y, up) in [(0.0f32, false), (height, true)] {
        let centre = mesh.vertices.len() as u32;
        mesh.vertices.push(base + Vec3::Y * y);
        let ring0 = if up { rings * segments } else { 0 };
        for i in 0..segments {
            let (a, b) = (ring0 + i, ring0 + (i + 1) % segments);
            mesh.triangles
                .push(if up { [centre, a, b] } else { [centre, b, a] });
        }
    }
    mesh
}

/// An open tube (no caps) along Y from `base` up by `height`, outward triangles.
pub fn tube(base: Vec3, radius: f32, height: f32, segments: u32, rings: u32) -> TriMesh {
    let mut vertices = Vec::new();
    for j in 0..=rings {
        let y = height * j as f32 / rings as f32;
        for i in 0..segments {
            let phi = std::f32::consts::TAU * i as f32 / segments as f32;
            vertices.push(base + Vec3::new(radius * phi.cos(), y, -radius * phi.sin()));
        }
    }
    TriMesh::new(vertices, ring_triangles(segments, rings))
}

/// Triangles of `rings` bands of a closed ring of `segments` vertices per ring (vertex
/// `j * segments + i` is vertex i of ring j), quads split along alternating diagonals.
pub fn ring_triangles(segments: u32, rings: u32) -> Vec<[u32; 3]> {
    let id = |j: u32, i: u32| j * segments + (i % segments);
    let mut triangles = Vec::with_capacity((2 * segments * rings) as usize);
    for j in 0..rings {
        for i in 0..segments {
            let (a, b, c, d) = (id(j, i), id(j, i + 1), id(j + 1, i + 1), id(j + 1, i));
            if (i + j) % 2 == 0 {
                triangles.extend([[a, b, c], [a, c, d]]);
            } else {
                triangles.extend([[a, b, d], [b, c, d]]);
            }
        }
    }
    triangles
}

/// Appends `part` to `mesh`, merging vertices that coincide (within 1e-6).
fn append_welded(mesh: &mut TriMesh, part: &TriMesh) {
    let map: Vec<u32> = part
        .vertices
        .iter()
        .map(|p| {
            match mesh
                .vertices
                .iter()
                .position(|q| q.distance_squared(*p) < 1e-12)
            {
                Some(i) => i as u32,
                None => {
                    mesh.vertices.push(*p);
                    mesh.vertices.len() as u32 - 1
                }
            }
        })
        .collect();
    mesh.triangles
        .extend(part.triangles.iter().map(|t| t.map(|i| map[i as usize])));
}

#[cfg(test)]
mod tests {
    use super::*;

    fn closed(m: &TriMesh) -> bool {
        let mut edges = std::collections::HashMap::new();
        for t in &m.triangles {
            for k in 0..3 {
                *edges.entry((t[k], t[(k + 1) % 3])).or_insert(0) += 1;
            }
        }
        edges
            .iter()
            .all(|(&(a, b), &n)| n == 1 && edges.get(&(b, a)) == Some(&1))
    }

    #[test]
    fn closed_primitives_enclose_their_volume() {
        let s = uv_sphere(Vec3::ZERO, 1.0, 64, 32);
        assert!(closed(&s));
        assert!((s.signed_volume() - 4.0 / 3.0 * std::f32::consts::PI).abs() < 0.02);
        let b = cuboid(Vec3::new(1.0, 2.0, 3.0), Vec3::new(0.5, 1.0, 1.5), 3);
        assert!(closed(&b));
        assert!((b.signed_volume() - 6.0).abs() < 1e-4);
        let c = cylinder(Vec3::ZERO, 1.0, 2.0, 64, 4);
        assert!(closed(&c));
        assert!((c.signed_volume() - 2.0 * std::f32::consts::PI).abs() < 0.02);
    }
}
