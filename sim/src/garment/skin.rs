//! Skinning a garment from the body: each garment vertex is bound to its closest point on the
//! canonical body (triangle and barycentrics); the body's weights at that point, smoothed over
//! the garment, become the garment's weights; the point's motion under a shape change carries
//! the vertex to a new body shape (see [`super::warp`]).

use glam::Vec3;

use crate::body::skinning::SkinWeights;
use crate::cloth::collision::BodyCollider;
use crate::mesh::TriMesh;

/// Where a garment vertex is attached to the canonical body.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Binding {
    /// Body triangle.
    pub triangle: u32,
    /// Barycentric coordinates of the closest point in it.
    pub bary: [f32; 3],
}

/// Rounds of neighbour averaging of the transferred weights: enough to blur the seams of the
/// body's weight map over a few garment edges, not enough to move a sleeve's weights to the
/// torso.
pub const SMOOTHING_ROUNDS: usize = 8;

/// Rounds of neighbour averaging on `garment` that spread a value over about `reach` (m):
/// `(reach / mean edge length)^2`, at least [`SMOOTHING_ROUNDS`]. `r` rounds spread a value
/// over about `sqrt(r)` edges, so a reach gives the same blur at every resolution: 0.18 m
/// is 88 rounds on the 3k jeans (mean edge 19.3 mm) and about 290 on the 10k ones (10.6
/// mm). At most 10,000.
pub fn smoothing_rounds(garment: &TriMesh, reach: f32) -> usize {
    let rounds = (f64::from(reach) / f64::from(garment.mean_side()))
        .powi(2)
        .ceil() as usize;
    rounds.clamp(SMOOTHING_ROUNDS, 10_000)
}

/// Binds every vertex to its closest point on the body.
pub fn bind(points: &[Vec3], body: &BodyCollider) -> Vec<Binding> {
    points
        .iter()
        .map(|&p| {
            // Search wider and wider: a flared skirt's hem can be 30 cm from the legs.
            let hit = [0.05, 0.2, 1.0, 5.0]
                .iter()
                .find_map(|&r| body.closest(p, r))
                .expect("the body is within 5 m of every garment vertex");
            Binding {
                triangle: hit.contact.tri,
                bary: hit.contact.bary,
            }
        })
        .collect()
}

/// Transfers the body's skinning weights to the garment.
///
/// `only[v]`, when not empty, lists the only bones vertex `v` may follow (a skirt follows the
/// hips, never one leg): its weights are replaced by those bones' share of the transferred
/// weights, or by equal shares when the body point has none of them. The weights are then
/// averaged with the mesh neighbours' [`SMOOTHING_ROUNDS`] times (each round: half its own,
/// half the neighbours' mean). With `split = ([a, b], rounds)` the division between bones
/// `a` and `b` is then taken from their transferred weights averaged `rounds` times
/// instead ([`smoothing_rounds`]), their sum kept, except in vertices restricted by `only`.
/// Last, the four largest weights are kept and renormalised.
pub fn transfer_weights(
    garment: &TriMesh,
    bindings: &[Binding],
    body_triangles: &[[u32; 3]],
    body_skin: &SkinWeights,
    bones: usize,
    only: &[Vec<u16>],
    split: Option<([u16; 2], usize)>,
) -> SkinWeights {
    let n = garment.vertices.len();
    let mut dense = vec![0.0f32; n * bones];
    for (v, b) in bindings.iter().enumerate() {
        let row = &mut dense[v * bones..(v + 1) * bones];
        let tri = body_triangles[b.triangle as usize];
        for (k, &bv) in tri.iter().enumerate() {
            let (ib, w) = (
                &body_skin.bones[bv as usize],
                &body_skin.weights[bv as usize],
            );
            for s in 0..4 {
                row[ib[s] as usize] += b.bary[k] * w[s];
            }
        }
        if let Some(allowed) = only.get(v).filter(|a| !a.is_empty()) {
            let kept: f32 = allowed.iter().map(|&a| row[a as usize]).sum();
            let restricted: Vec<f32> = allowed
                .iter()
                .map(|&a| {
                    if kept > 1e-6 {
                        row[a as usize] / kept
                    } else {
                        1.0 / allowed.len() as f32
                    }
                })
                .collect();
            row.fill(0.0);
            for (&a, w) in allowed.iter().zip(restricted) {
                row[a as usize] = w;
            }
        }
    }

    let neighbours = neighbours(garment);
    // The split bones' transferred weights, before the averaging below.
    let pair: Option<Vec<f32>> = split.map(|([a, b], _)| {
        (0..n)
            .flat_map(|v| [dense[v * bones + a as usize], dense[v * bones + b as usize]])
            .collect()
    });
    let mut dense = average(dense, bones, &neighbours, SMOOTHING_ROUNDS);
    if let (Some(([a, b], wide_rounds)), Some(pair)) = (split, pair) {
        let (a, b) = (a as usize, b as usize);
        // The two bones' split, averaged over `wide_rounds`; their sum as above.
        let pair = average(pair, 2, &neighbours, wide_rounds);
        for v in 0..n {
            // A part restricted to some bones keeps its own weights.
            if only.get(v).is_some_and(|o| !o.is_empty()) {
                continue;
            }
            let total = dense[v * bones + a] + dense[v * bones + b];
            let (pa, pb) = (pair[2 * v], pair[2 * v + 1]);
            let both = pa + pb;
            if both > 1e-6 {
                dense[v * bones + a] = total * pa / both;
                dense[v * bones + b] = total * pb / both;
            }
        }
    }

    let mut skin = SkinWeights::default();
    for v in 0..n {
        let row = &dense[v * bones..(v + 1) * bones];
        let mut order: Vec<usize> = (0..bones).collect();
        order.sort_by(|&a, &b| row[b].total_cmp(&row[a]).then(a.cmp(&b)));
        let top = &order[..4.min(bones)];
        let sum: f32 = top.iter().map(|&j| row[j]).sum();
        let mut b = [top[0] as u16; 4];
        let mut w = [0.0; 4];
        for (k, &j) in top.iter().enumerate() {
            b[k] = j as u16;
            w[k] = if sum > 0.0 { row[j] / sum } else { 0.25 };
        }
        skin.bones.push(b);
        skin.weights.push(w);
    }
    skin
}

/// `rounds` rounds of neighbour averaging of `field`, `width` values per vertex: each
/// value becomes half its own and half its neighbours' mean (a vertex without neighbours
/// keeps its values).
fn average(mut field: Vec<f32>, width: usize, neighbours: &[Vec<u32>], rounds: usize) -> Vec<f32> {
    for _ in 0..rounds {
        let mut next = field.clone();
        for (v, nb) in neighbours.iter().enumerate() {
            if nb.is_empty() {
                continue;
            }
            let inv = 1.0 / nb.len() as f32;
            for j in 0..width {
                let mean: f32 = nb
                    .iter()
                    .map(|&u| field[u as usize * width + j])
                    .sum::<f32>()
                    * inv;
                next[v * width + j] = 0.5 * field[v * width + j] + 0.5 * mean;
            }
        }
        field = next;
    }
    field
}

/// Mesh neighbours of every vertex, sorted.
pub fn neighbours(mesh: &TriMesh) -> Vec<Vec<u32>> {
    let mut nb: Vec<Vec<u32>> = vec![Vec::new(); mesh.vertices.len()];
    for t in &mesh.triangles {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            nb[a as usize].push(b);
            nb[b as usize].push(a);
        }
    }
    for l in &mut nb {
        l.sort_unstable();
        l.dedup();
    }
    nb
}

/// [`neighbours`] flattened for the smoothing rounds: vertex `v`'s neighbours are
/// `flat[start[v]..start[v + 1]]`.
fn flat_neighbours(mesh: &TriMesh) -> (Vec<usize>, Vec<u32>) {
    let nb = neighbours(mesh);
    let mut start = Vec::with_capacity(nb.len() + 1);
    start.push(0usize);
    for l in &nb {
        start.push(start.last().unwrap() + l.len());
    }
    (start, nb.into_iter().flatten().collect())
}

/// Meshes from this many vertices run [`smooth`]'s rounds in parallel; below it a round is
/// cheaper than handing it to the thread pool.
const SMOOTH_PARALLEL_FROM: usize = 4_096;

/// `rounds` rounds of neighbour averaging of a per-vertex vector field: each round a vertex
/// keeps half its value and takes half its neighbours' mean.
///
/// The neighbour lists are flattened once and each round runs over the vertices in parallel
/// into a second buffer; every vertex sums its neighbours in the same order as one thread
/// would, so the result does not depend on the thread count. The DQS warp's reshape runs
/// hundreds of rounds at 10k vertices (`Template::reshape`).
pub fn smooth(mesh: &TriMesh, field: Vec<Vec3>, rounds: usize) -> Vec<Vec3> {
    use rayon::prelude::*;
    let (start, flat) = flat_neighbours(mesh);
    let mut field = field;
    let mut next = vec![Vec3::ZERO; field.len()];
    for _ in 0..rounds {
        let round = |(v, out): (usize, &mut Vec3)| {
            let n = &flat[start[v]..start[v + 1]];
            *out = if n.is_empty() {
                field[v]
            } else {
                let mean = n.iter().map(|&u| field[u as usize]).sum::<Vec3>() / n.len() as f32;
                0.5 * field[v] + 0.5 * mean
            };
        };
        if field.len() >= SMOOTH_PARALLEL_FROM {
            next.par_iter_mut()
                .enumerate()
                .with_min_len(1_024)
                .for_each(round);
        } else {
            next.iter_mut().enumerate().for_each(round);
        }
        std::mem::swap(&mut field, &mut next);
    }
    field
}

/// Fields [`smooth_many`] smooths together: a vertex's values of this many fields lie side
/// by side, so a round loads each neighbour index once for all of them and sums 12 floats
/// in a row; two buffers of 10k vertices stay about the size of a core's L2 cache.
const SMOOTH_TOGETHER: usize = 4;

/// [`smooth`] of several fields on the same mesh, equal to smoothing each alone bit for bit:
/// every float sees the same additions in the same order. Groups of [`SMOOTH_TOGETHER`]
/// fields run side by side on the thread pool, each group's rounds on one thread. The DQS
/// warp's shape moves smooth one field per body shape target (`Template::reshape`), and
/// one at a time, their loads of the neighbour lists and of single vectors were the cost
/// (docs/bench.md).
pub fn smooth_many(mesh: &TriMesh, fields: &[Vec<Vec3>], rounds: usize) -> Vec<Vec<Vec3>> {
    use rayon::prelude::*;
    const W: usize = 3 * SMOOTH_TOGETHER;
    let n = mesh.vertices.len();
    assert!(
        fields.iter().all(|f| f.len() == n),
        "every field has one vector per vertex"
    );
    let (start, flat) = flat_neighbours(mesh);
    let groups: Vec<&[Vec<Vec3>]> = fields.chunks(SMOOTH_TOGETHER).collect();
    let smoothed: Vec<Vec<Vec<Vec3>>> = groups
        .par_iter()
        .map(|group| {
            // Vertex-major: vertex v's fields at [v * W, (v + 1) * W); a short last group
            // is padded with zeros, which touch no other field's sums.
            let mut field = vec![0.0f32; n * W];
            for (k, f) in group.iter().enumerate() {
                for (v, p) in f.iter().enumerate() {
                    field[v * W + 3 * k..v * W + 3 * k + 3].copy_from_slice(&p.to_array());
                }
            }
            let mut next = vec![0.0f32; n * W];
            for _ in 0..rounds {
                for v in 0..n {
                    let own: [f32; W] = field[v * W..(v + 1) * W].try_into().unwrap();
                    let out = &mut next[v * W..(v + 1) * W];
                    let nv = &flat[start[v]..start[v + 1]];
                    if nv.is_empty() {
                        out.copy_from_slice(&own);
                        continue;
                    }
                    // As `smooth`: the neighbours summed from zero in list order, divided
                    // by their count, then half own value plus half mean.
                    let mut sum = [0.0f32; W];
                    for &u in nv {
                        let x = &field[u as usize * W..(u as usize + 1) * W];
                        for j in 0..W {
                            sum[j] += x[j];
                        }
                    }
                    let count = nv.len() as f32;
                    for j in 0..W {
                        out[j] = 0.5 * own[j] + 0.5 * (sum[j] / count);
                    }
                }
                std::mem::swap(&mut field, &mut next);
            }
            (0..group.len())
                .map(|k| {
                    (0..n)
                        .map(|v| Vec3::from_slice(&field[v * W + 3 * k..v * W + 3 * k + 3]))
                        .collect()
                })
                .collect()
        })
        .collect();
    smoothed.into_iter().flatten().collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::mesh::primitives::grid;

    /// The plain one-thread rounds `smooth` must reproduce exactly (the code it replaced).
    fn smooth_serial(mesh: &TriMesh, mut field: Vec<Vec3>, rounds: usize) -> Vec<Vec3> {
        let nb = neighbours(mesh);
        for _ in 0..rounds {
            field = (0..field.len())
                .map(|v| {
                    let n = &nb[v];
                    if n.is_empty() {
                        return field[v];
                    }
                    let mean = n.iter().map(|&u| field[u as usize]).sum::<Vec3>() / n.len() as f32;
                    0.5 * field[v] + 0.5 * mean
                })
                .collect();
        }
        field
    }

    fn pseudo_random_field(n: usize) -> Vec<Vec3> {
        (0..n)
            .map(|i| {
                let x = (i as f32 * 0.618_034).fract();
                Vec3::new(x, (x * 7.3).fract(), -x)
            })
            .collect()
    }

    #[test]
    fn smoothing_fields_together_equals_smoothing_each_alone() {
        // Six fields: a full group and a short one; a vertex no face uses keeps its values.
        let grid = grid(Vec3::ZERO, Vec3::X * 0.01, Vec3::Z * 0.01, 30, 30);
        let mut vertices = grid.vertices.clone();
        vertices.push(Vec3::splat(1.0));
        let mesh = TriMesh::new(vertices, grid.triangles.clone());
        let n = mesh.vertices.len();
        let fields: Vec<Vec<Vec3>> = (0..6)
            .map(|k| {
                pseudo_random_field(n + k)
                    .into_iter()
                    .skip(k)
                    .map(|p| p * (k as f32 - 2.5))
                    .collect()
            })
            .collect();
        for rounds in [0, 1, 23] {
            let together = smooth_many(&mesh, &fields, rounds);
            assert_eq!(together.len(), fields.len());
            for (k, f) in fields.iter().enumerate() {
                assert_eq!(
                    together[k],
                    smooth_serial(&mesh, f.clone(), rounds),
                    "field {k}, {rounds} rounds: must equal smoothing it alone bit for bit"
                );
            }
            assert_eq!(together[5][n - 1], fields[5][n - 1]);
        }
        assert!(smooth_many(&mesh, &[], 3).is_empty());
    }

    #[test]
    fn a_reach_gives_the_same_blur_at_every_resolution() {
        // Right triangles of 1 cm legs: mean edge (1 + 1 + sqrt 2) / 3 cm = 11.381 mm.
        let coarse = grid(Vec3::ZERO, Vec3::X * 0.2, Vec3::Z * 0.2, 20, 20);
        // Half the spacing: four times the rounds for the same reach.
        let fine = grid(Vec3::ZERO, Vec3::X * 0.2, Vec3::Z * 0.2, 40, 40);
        // (0.1 / 0.011381)^2 = 77.2 and (0.1 / 0.0056904)^2 = 308.8, rounded up.
        assert_eq!(smoothing_rounds(&coarse, 0.1), 78);
        assert_eq!(smoothing_rounds(&fine, 0.1), 309);
        // A reach shorter than the default's blur keeps the default.
        assert_eq!(smoothing_rounds(&coarse, 0.02), SMOOTHING_ROUNDS);
    }

    #[test]
    fn smoothing_is_exact_in_parallel_and_spreads_a_spike() {
        // 81 x 81 = 6,561 vertices runs its rounds in parallel, 11 x 11 on one thread; the
        // small one gets a vertex no face uses, which keeps its value.
        let mesh = grid(Vec3::ZERO, Vec3::X * 0.01, Vec3::Z * 0.01, 80, 80);
        assert!(mesh.vertices.len() >= SMOOTH_PARALLEL_FROM);
        let small = grid(Vec3::ZERO, Vec3::X * 0.01, Vec3::Z * 0.01, 10, 10);
        let mut lone = small.vertices.clone();
        lone.push(Vec3::splat(1.0));
        let small = TriMesh::new(lone, small.triangles.clone());
        for m in [&mesh, &small] {
            for rounds in [0, 1, 2, 37] {
                let field = pseudo_random_field(m.vertices.len());
                let fast = smooth(m, field.clone(), rounds);
                let slow = smooth_serial(m, field.clone(), rounds);
                assert_eq!(
                    fast,
                    slow,
                    "{} vertices, {rounds} rounds: must equal one-thread rounds bit for bit",
                    m.vertices.len()
                );
                if rounds == 0 {
                    assert_eq!(fast, field);
                }
            }
        }
        let lone = small.vertices.len() - 1;
        let field = pseudo_random_field(small.vertices.len());
        assert_eq!(smooth(&small, field.clone(), 5)[lone], field[lone]);

        // A unit spike in the middle spreads: it falls, its neighbours rise, nothing goes
        // negative, and a constant field is left alone.
        let centre = 40 * 81 + 40;
        let mut spike = vec![Vec3::ZERO; mesh.vertices.len()];
        spike[centre] = Vec3::ONE;
        let out = smooth(&mesh, spike, 10);
        assert!(
            out[centre].x < 0.2 && out[centre].x > 0.0,
            "{}",
            out[centre].x
        );
        assert!(out[centre + 1].x > 0.01);
        assert!(out.iter().all(|v| v.x >= 0.0));
        let constant = smooth(&mesh, vec![Vec3::splat(2.5); mesh.vertices.len()], 10);
        assert!(
            constant
                .iter()
                .all(|v| (*v - Vec3::splat(2.5)).abs().max_element() < 1e-5)
        );
    }
}
