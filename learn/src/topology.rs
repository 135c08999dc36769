//! Fixed mesh structure shared by every sample of a garment: the FeaStNet neighbourhoods,
//! the bending pairs, the faces; and two helpers for bodies (farthest-point subsets, mean
//! edge length).

use std::collections::BTreeSet;

use glam::Vec3;

/// A garment template's connectivity, precomputed once per model.
#[derive(Debug, Clone)]
pub struct Topology {
    /// Vertex count N.
    pub vertices: usize,
    /// Triangles [F][3].
    pub triangles: Vec<[u32; 3]>,
    /// One-ring neighbours of each vertex, ascending, without the vertex.
    pub rings: Vec<Vec<u32>>,
    /// Padded neighbourhoods for FeaStNet and the Laplacian: `K = max |N_i|` slots per
    /// vertex, `[N * K]`, slot 0 the vertex itself, then its one-ring, unused slots
    /// repeating the vertex.
    pub padded: Vec<i64>,
    /// 1 for a used slot, 0 for padding, `[N * K]`.
    pub padded_mask: Vec<f32>,
    /// Slots per vertex K.
    pub slots: usize,
    /// Mesh edges (i < j), once each.
    pub edges: Vec<[u32; 2]>,
    /// Vertex pairs exactly two edges apart (i < k), for L_bend.
    pub bend_pairs: Vec<[u32; 2]>,
}

impl Topology {
    /// Builds the structure of a triangle mesh with `vertices` vertices.
    pub fn new(vertices: usize, triangles: &[[u32; 3]]) -> Self {
        let mut ring: Vec<BTreeSet<u32>> = vec![BTreeSet::new(); vertices];
        for t in triangles {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                ring[a as usize].insert(b);
                ring[b as usize].insert(a);
            }
        }
        let mut edges = Vec::new();
        let mut bend = BTreeSet::new();
        for (i, r) in ring.iter().enumerate() {
            for &j in r {
                if (i as u32) < j {
                    edges.push([i as u32, j]);
                }
                for &k in &ring[j as usize] {
                    if k as usize != i && !r.contains(&k) {
                        let (a, b) = if (i as u32) < k {
                            (i as u32, k)
                        } else {
                            (k, i as u32)
                        };
                        bend.insert([a, b]);
                    }
                }
            }
        }
        let rings: Vec<Vec<u32>> = ring.into_iter().map(|r| r.into_iter().collect()).collect();
        let slots = rings.iter().map(|r| r.len() + 1).max().unwrap_or(1);
        let mut padded = Vec::with_capacity(vertices * slots);
        let mut padded_mask = Vec::with_capacity(vertices * slots);
        for (i, r) in rings.iter().enumerate() {
            padded.push(i as i64);
            padded.extend(r.iter().map(|&j| j as i64));
            padded_mask.extend(std::iter::repeat_n(1.0, r.len() + 1));
            padded.extend(std::iter::repeat_n(i as i64, slots - r.len() - 1));
            padded_mask.extend(std::iter::repeat_n(0.0, slots - r.len() - 1));
        }
        Self {
            vertices,
            triangles: triangles.to_vec(),
            rings,
            padded,
            padded_mask,
            slots,
            edges,
            bend_pairs: bend.into_iter().collect(),
        }
    }

    /// 1 / |N_i| per vertex, N_i the one-ring plus the vertex itself (FeaStNet's mean).
    pub fn inv_degree(&self) -> Vec<f32> {
        self.rings
            .iter()
            .map(|r| 1.0 / (r.len() + 1) as f32)
            .collect()
    }
}

/// `count` indices of `points` chosen by farthest-point sampling from index 0: a fixed,
/// deterministic, roughly even subset.
pub fn farthest_point_subset(points: &[Vec3], count: usize) -> Vec<u32> {
    let count = count.min(points.len());
    if count == 0 {
        return Vec::new();
    }
    let mut chosen = Vec::with_capacity(count);
    let mut dist = vec![f32::INFINITY; points.len()];
    let mut next = 0usize;
    for _ in 0..count {
        chosen.push(next as u32);
        let p = points[next];
        let mut best = (0usize, -1.0f32);
        for (i, q) in points.iter().enumerate() {
            let d = dist[i].min(q.distance_squared(p));
            dist[i] = d;
            if d > best.1 {
                best = (i, d);
            }
        }
        next = best.0;
    }
    chosen
}

/// Mean edge length of a triangle mesh (each triangle's three edges; shared edges count
/// twice, which does not change the mean of a closed or nearly closed mesh much).
pub fn mean_edge_length(points: &[Vec3], triangles: &[[u32; 3]]) -> f32 {
    let mut sum = 0.0f64;
    for t in triangles {
        for k in 0..3 {
            sum += points[t[k] as usize].distance(points[t[(k + 1) % 3] as usize]) as f64;
        }
    }
    (sum / (3 * triangles.len().max(1)) as f64) as f32
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two triangles sharing an edge: a quad 0-1-2-3.
    fn quad() -> Topology {
        Topology::new(4, &[[0, 1, 2], [0, 2, 3]])
    }

    #[test]
    fn rings_pairs_and_degrees_of_a_quad() {
        let t = quad();
        assert_eq!(t.edges, vec![[0, 1], [0, 2], [0, 3], [1, 2], [2, 3]]);
        // 1 and 3 are the only pair two edges apart.
        assert_eq!(t.bend_pairs, vec![[1, 3]]);
        // Vertex 0 has neighbours 1, 2, 3 plus itself.
        assert_eq!(t.inv_degree()[0], 0.25);
        assert_eq!(t.inv_degree()[1], 1.0 / 3.0);
        // FeaStNet neighbourhoods: 4 self-loops and both directions of the 5 edges.
        assert_eq!(
            t.vertices + t.rings.iter().map(Vec::len).sum::<usize>(),
            4 + 2 * 5
        );
        assert_eq!(t.rings[1], vec![0, 2]);
        assert_eq!(t.slots, 4);
        assert_eq!(&t.padded[4..8], &[1, 0, 2, 1]);
        assert_eq!(&t.padded_mask[4..8], &[1.0, 1.0, 1.0, 0.0]);
    }

    #[test]
    fn farthest_points_spread_out() {
        let pts: Vec<Vec3> = (0..11).map(|i| Vec3::new(i as f32, 0.0, 0.0)).collect();
        assert_eq!(farthest_point_subset(&pts, 3), vec![0, 10, 5]);
    }

    #[test]
    fn mean_edge_length_of_a_quad() {
        let pts = [Vec3::ZERO, Vec3::X, Vec3::new(1.0, 0.0, -1.0), Vec3::NEG_Z];
        assert!(
            (mean_edge_length(&pts, &quad().triangles) - (4.0 + 2.0 * 2f32.sqrt()) / 6.0).abs()
                < 1e-6
        );
    }
}
