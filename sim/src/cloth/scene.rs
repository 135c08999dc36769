//! A garment-like test object: a tube fitted around the torso of a shaped body in its rest
//! pose, from the hip joints to below the armpits, with a given ease. It stands in for a
//! garment in tests and benchmarks until the built-in garments exist; it is a real open
//! surface with two openings that rests on the hips and chest.

use glam::Vec3;

use crate::body::ShapedBody;
use crate::body::intersect::Segment;
use crate::mesh::TriMesh;

/// A tube of `segments` around and `rings` along, `ease` metres away from the torso.
pub fn torso_tube(body: &ShapedBody<'_>, segments: u32, rings: u32, ease: f32) -> TriMesh {
    let model = body.model;
    let sk = &model.skeleton;
    let joint = |bone: &str| body.joints[sk.bones[sk.index(bone).expect("cmu_mb bone")].head];
    let bottom = joint("LeftUpLeg").y.min(joint("RightUpLeg").y);
    let top = joint("LeftArm").y.min(joint("RightArm").y) - 0.09;
    // Torso and thigh vertices only: the arms hang outside the tube.
    let keep: Vec<usize> = (0..body.vertices.len())
        .filter(|&i| {
            let b = model.skin.bones[i][0] as usize;
            matches!(
                Segment::of_bone(&sk.bones[b].name),
                Segment::Torso | Segment::LeftThigh | Segment::RightThigh
            )
        })
        .collect();
    let centre_z = {
        let zs: Vec<f32> = keep.iter().map(|&i| body.vertices[i].z).collect();
        0.5 * (zs.iter().cloned().fold(f32::MAX, f32::min)
            + zs.iter().cloned().fold(f32::MIN, f32::max))
    };
    // Largest torso radius on a coarse (ring, sector) grid that the body's vertices fill,
    // each vertex counting in its bin's neighbours too; then bilinear interpolation.
    const CS: usize = 48;
    const CR: usize = 24;
    let cdy = (top - bottom) / CR as f32;
    let mut coarse = vec![0.0f32; (CR + 1) * CS];
    for &i in &keep {
        let p = body.vertices[i];
        if p.y < bottom - cdy || p.y > top + cdy {
            continue;
        }
        let (x, z) = (p.x, p.z - centre_z);
        let theta = (-z).atan2(x).rem_euclid(std::f32::consts::TAU);
        let rad = (x * x + z * z).sqrt();
        let ring = ((p.y - bottom) / cdy).round().clamp(0.0, CR as f32) as usize;
        let sector = (theta / std::f32::consts::TAU * CS as f32).round() as usize % CS;
        for rr in ring.saturating_sub(1)..=(ring + 1).min(CR) {
            for ds in [CS - 1, 0, 1] {
                let k = rr * CS + (sector + ds) % CS;
                coarse[k] = coarse[k].max(rad);
            }
        }
    }
    // Smooth outwards only (a taut tube bridges hollows).
    for _ in 0..4 {
        let old = coarse.clone();
        for j in 0..=CR {
            for i in 0..CS {
                let at = |jj: usize, ii: usize| old[jj * CS + ii % CS];
                let mean = (at(j, i + CS - 1)
                    + at(j, i + 1)
                    + at(j.saturating_sub(1), i)
                    + at((j + 1).min(CR), i))
                    / 4.0;
                coarse[j * CS + i] = old[j * CS + i].max(mean);
            }
        }
    }
    let radius_at = |u: f32, v: f32| {
        // u in [0, 1) around, v in [0, 1] up.
        let (fu, fv) = (u * CS as f32, v * CR as f32);
        let (i0, j0) = (fu.floor() as usize % CS, (fv.floor() as usize).min(CR));
        let (i1, j1) = ((i0 + 1) % CS, (j0 + 1).min(CR));
        let (a, b) = (fu.fract(), fv - fv.floor());
        let c = |j: usize, i: usize| coarse[j * CS + i];
        (c(j0, i0) * (1.0 - a) + c(j0, i1) * a) * (1.0 - b)
            + (c(j1, i0) * (1.0 - a) + c(j1, i1) * a) * b
    };
    let (s, r) = (segments as usize, rings as usize);
    let mut vertices = Vec::with_capacity((r + 1) * s);
    for j in 0..=r {
        let v = j as f32 / r as f32;
        let y = bottom + (top - bottom) * v;
        for i in 0..s {
            let u = i as f32 / s as f32;
            let theta = std::f32::consts::TAU * u;
            let rad = radius_at(u, v) + ease;
            vertices.push(Vec3::new(
                rad * theta.cos(),
                y,
                centre_z - rad * theta.sin(),
            ));
        }
    }
    TriMesh::new(
        vertices,
        crate::mesh::primitives::ring_triangles(segments, rings),
    )
}
