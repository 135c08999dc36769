//! k nearest neighbours for GarNet's inputs: a k-d tree (kiddo) for large point sets, a scan
//! in SIMD registers for small ones.
//!
//! GarNet-Local asks, for every garment vertex, for its 15 nearest of the 200 downsampled
//! body points. That search was most of a 10k drape's inputs at batch 1 (docs/bench.md,
//! "The local search as a scan"). Over so few points a scan wins over the tree when it is
//! bounded: neighbouring queries (consecutive garment vertices) have nearly the same
//! neighbours, so the previous query's k neighbours give an upper bound on this query's
//! k-th distance; one pass over the points in vector registers keeps the few within the
//! bound, and only those are sorted. The result is exact whatever the bound's quality: a
//! loose bound only keeps more candidates.

use std::num::NonZero;

use glam::Vec3;
use kiddo::{ImmutableKdTree, SquaredEuclidean};
use pulp::{Simd, WithSimd};
use rayon::prelude::*;

use crate::model::feast::Level;

/// Queries per rayon task of the scan, at least (each is well under a microsecond).
const QUERIES_PER_TASK: usize = 256;

/// Queries per rayon task of the k-d tree, at least (each is a microsecond or two over
/// GarNet-Local's 2,000 body points: the 200 downsampled points' search in four tasks).
const TREE_QUERIES_PER_TASK: usize = 64;

/// Point sets up to this size are scanned, larger ones go to the k-d tree. At 200 points
/// and 15 neighbours the scan along a Z-order curve takes about a third of the tree's
/// time, at 2,000 points and 16 neighbours the tree is faster (docs/bench.md, "The local
/// search as a scan"); this size sits between the two measured.
pub const SCAN_POINTS: usize = 512;

/// For each query, the indices of its `k` nearest points (nearest first; all points when
/// there are fewer than `k`). The queries run in parallel, tens to hundreds to a task; the
/// result does not depend on the thread count. Up to [`SCAN_POINTS`] points are scanned
/// ([`knn_scan`]), more searched in a k-d tree ([`knn_tree`]). The scan's squared distances
/// are glam's (`(dx dx + dy dy) + dz dz`, unfused); the tree's may round differently, so
/// the two can differ where two points are at the same distance to within a rounding.
/// Points with a NaN coordinate are never found but to fill k.
pub fn knn(points: &[Vec3], queries: &[Vec3], k: usize) -> Vec<u32> {
    if points.len() <= SCAN_POINTS {
        knn_scan(points, queries, k)
    } else {
        knn_tree(points, queries, k)
    }
}

/// For each query, the index of its nearest point.
pub fn nearest(points: &[Vec3], queries: &[Vec3]) -> Vec<u32> {
    knn(points, queries, 1)
}

/// [`knn`] with kiddo's k-d tree.
pub fn knn_tree(points: &[Vec3], queries: &[Vec3], k: usize) -> Vec<u32> {
    let entries: Vec<[f32; 3]> = points.iter().map(|p| p.to_array()).collect();
    let tree = ImmutableKdTree::new_from_slice(&entries).expect("a non-empty point set");
    let k = NonZero::new(k.min(points.len())).expect("k >= 1");
    let mut out = vec![0u32; queries.len() * k.get()];
    out.par_chunks_mut(k.get())
        .zip(queries.par_iter())
        .with_min_len(TREE_QUERIES_PER_TASK)
        .for_each(|(o, q)| {
            let found = tree
                .query(&q.to_array())
                .nearest_n::<SquaredEuclidean<f32>>(k)
                .execute();
            for (slot, r) in o.iter_mut().zip(found.iter()) {
                *slot = r.item;
            }
        });
    out
}

/// [`knn`] by a bounded scan over all points (the module's documentation), the queries
/// visited in their own order.
pub fn knn_scan(points: &[Vec3], queries: &[Vec3], k: usize) -> Vec<u32> {
    knn_scan_with(Level::Best, points, queries, None, k)
}

/// [`knn`] with the queries visited in `order` (a permutation of their indices; the
/// results stay at each query's own place): a [`spatial_order`] of the queries keeps
/// consecutive ones close, which keeps the scan's bounds tight. The k-d tree ignores it.
pub fn knn_along(points: &[Vec3], queries: &[Vec3], order: &[u32], k: usize) -> Vec<u32> {
    if points.len() <= SCAN_POINTS {
        knn_scan_with(Level::Best, points, queries, Some(order), k)
    } else {
        knn_tree(points, queries, k)
    }
}

/// The points' indices along a Z-order (Morton) curve over their bounding box, 1,024 cells
/// to an axis: points close in space are mostly close in the sequence. Deterministic; ties
/// (points in one cell) in index order.
pub fn spatial_order(points: &[Vec3]) -> Vec<u32> {
    let lo = points.iter().fold(Vec3::splat(f32::MAX), |a, &p| a.min(p));
    let hi = points.iter().fold(Vec3::splat(f32::MIN), |a, &p| a.max(p));
    let cells = 1023.0 / (hi - lo).max(Vec3::splat(f32::MIN_POSITIVE));
    // The 10 bits of v spread to every third bit.
    let spread = |v: u32| -> u32 {
        let mut v = v & 0x3ff;
        v = (v | (v << 16)) & 0x0300_00ff;
        v = (v | (v << 8)) & 0x0300_f00f;
        v = (v | (v << 4)) & 0x030c_30c3;
        (v | (v << 2)) & 0x0924_9249
    };
    let mut keyed: Vec<(u32, u32)> = points
        .iter()
        .enumerate()
        .map(|(i, &p)| {
            let c = ((p - lo) * cells).round().as_uvec3();
            (spread(c.x) | spread(c.y) << 1 | spread(c.z) << 2, i as u32)
        })
        .collect();
    keyed.sort_unstable();
    keyed.into_iter().map(|(_, i)| i).collect()
}

/// [`knn_scan`] at a given SIMD level, the queries visited in `order` if one is given.
pub(crate) fn knn_scan_with(
    level: Level,
    points: &[Vec3],
    queries: &[Vec3],
    order: Option<&[u32]>,
    k: usize,
) -> Vec<u32> {
    assert!(!points.is_empty(), "a non-empty point set");
    assert!(k >= 1, "k >= 1");
    let k = k.min(points.len());
    let identity: Vec<u32>;
    let visit = match order {
        Some(order) => {
            assert_eq!(order.len(), queries.len(), "an order of every query");
            let mut seen = vec![false; queries.len()];
            for &q in order {
                assert!(
                    !std::mem::replace(&mut seen[q as usize], true),
                    "query {q} twice in the order"
                );
            }
            order
        }
        None => {
            identity = (0..queries.len() as u32).collect();
            &identity
        }
    };
    let coords = Coords::new(points);
    // The results in visiting order.
    let mut visited = vec![0u32; queries.len() * k];
    let tasks = queries.len().div_ceil(QUERIES_PER_TASK).max(1);
    let per_task = queries.len().div_ceil(tasks).max(1);
    visited
        .par_chunks_mut(per_task * k)
        .zip(visit.par_chunks(per_task))
        .for_each(|(out, visit)| {
            level.run(Scan {
                coords: &coords,
                queries,
                visit,
                k,
                out,
            })
        });
    if order.is_none() {
        return visited;
    }
    let mut out = vec![0u32; queries.len() * k];
    for (&q, found) in visit.iter().zip(visited.chunks_exact(k)) {
        out[q as usize * k..(q as usize + 1) * k].copy_from_slice(found);
    }
    out
}

/// The points' coordinates in three arrays, padded to a whole number of the widest vectors
/// with points at infinity: never within a finite bound, and behind every real point at an
/// infinite one (ties go to the lower index).
struct Coords {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
}

/// Widest vector in f32 lanes the scan pads for (AVX-512).
const PAD_LANES: usize = 16;

impl Coords {
    fn new(points: &[Vec3]) -> Self {
        let len = points.len().div_ceil(PAD_LANES) * PAD_LANES;
        let axis = |f: fn(&Vec3) -> f32| -> Vec<f32> {
            let mut v: Vec<f32> = points.iter().map(f).collect();
            v.resize(len, f32::INFINITY);
            v
        };
        Self {
            x: axis(|p| p.x),
            y: axis(|p| p.y),
            z: axis(|p| p.z),
        }
    }

    /// Squared distance from point `j` to `q`, as the scan's vectors compute it (and glam),
    /// a NaN taken as infinity so that such a point is the first to leave the list.
    #[inline(always)]
    fn distance_squared(&self, j: usize, q: Vec3) -> f32 {
        let (dx, dy, dz) = (self.x[j] - q.x, self.y[j] - q.y, self.z[j] - q.z);
        let d = (dx * dx + dy * dy) + dz * dz;
        if d.is_nan() { f32::INFINITY } else { d }
    }
}

/// One task's queries, in visiting order, each bounded by the previous one's neighbours.
struct Scan<'a> {
    coords: &'a Coords,
    queries: &'a [Vec3],
    /// The queries this task visits, in order.
    visit: &'a [u32],
    k: usize,
    out: &'a mut [u32],
}

impl WithSimd for Scan<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let Scan {
            coords,
            queries,
            visit,
            k,
            out,
        } = self;
        let lanes = S::F32_LANES;
        let (xs, _) = S::as_simd_f32s(&coords.x);
        let (ys, _) = S::as_simd_f32s(&coords.y);
        let (zs, _) = S::as_simd_f32s(&coords.z);
        // The k nearest so far, nearest first, as (squared distance, point); which points
        // they are, one bit each.
        let mut top: Vec<(f32, u32)> = Vec::with_capacity(k);
        let mut member = vec![0u64; coords.x.len().div_ceil(64)];
        let mut block = vec![0.0f32; lanes];
        // The first query starts from the first k points.
        let mut previous: Vec<u32> = (0..k as u32).collect();
        for (&i, found) in visit.iter().zip(out.chunks_exact_mut(k)) {
            let q = &queries[i as usize];
            top.clear();
            for &j in &previous {
                top.push((coords.distance_squared(j as usize, *q), j));
                member[j as usize / 64] |= 1 << (j % 64);
            }
            top.sort_unstable_by(by_distance);
            let (qx, qy, qz) = (
                simd.splat_f32s(q.x),
                simd.splat_f32s(q.y),
                simd.splat_f32s(q.z),
            );
            let mut bound = simd.splat_f32s(top[k - 1].0);
            for (b, ((&x, &y), &z)) in xs.iter().zip(ys).zip(zs).enumerate() {
                let (dx, dy, dz) = (
                    simd.sub_f32s(x, qx),
                    simd.sub_f32s(y, qy),
                    simd.sub_f32s(z, qz),
                );
                // Unfused, as glam and `Coords::distance_squared`: the same bits at every
                // SIMD level. A NaN fails the comparison below.
                let d = simd.add_f32s(
                    simd.add_f32s(simd.mul_f32s(dx, dx), simd.mul_f32s(dy, dy)),
                    simd.mul_f32s(dz, dz),
                );
                let mut bits = mask_bits::<S>(simd.less_than_or_equal_f32s(d, bound));
                if bits == 0 {
                    continue;
                }
                // Points already kept are not candidates again.
                let first = b * lanes;
                bits &= !(member[first / 64] >> (first % 64)) as u32;
                if bits == 0 {
                    continue;
                }
                S::as_mut_simd_f32s(&mut block).0[0] = d;
                while bits != 0 {
                    let lane = bits.trailing_zeros() as usize;
                    bits &= bits - 1;
                    let candidate = (block[lane], (first + lane) as u32);
                    if by_distance(&candidate, &top[k - 1]).is_ge() {
                        continue;
                    }
                    let (_, out) = top[k - 1];
                    member[out as usize / 64] &= !(1 << (out % 64));
                    member[candidate.1 as usize / 64] |= 1 << (candidate.1 % 64);
                    let mut at = k - 1;
                    while at > 0 && by_distance(&candidate, &top[at - 1]).is_lt() {
                        top[at] = top[at - 1];
                        at -= 1;
                    }
                    top[at] = candidate;
                }
                bound = simd.splat_f32s(top[k - 1].0);
            }
            for ((slot, kept), &(_, j)) in found.iter_mut().zip(previous.iter_mut()).zip(&top) {
                *slot = j;
                *kept = j;
                member[j as usize / 64] &= !(1 << (j % 64));
            }
        }
    }
}

/// Nearer first; the lower index first at the same distance.
#[inline(always)]
fn by_distance(a: &(f32, u32), b: &(f32, u32)) -> std::cmp::Ordering {
    a.0.total_cmp(&b.0).then(a.1.cmp(&b.1))
}

/// The lanes of a comparison's mask as bits, lane 0 the lowest: AVX-512 masks are bits
/// already (`b16`, moved to a register as they are), the scalar level's a `bool`, other
/// levels' vectors of all-ones or zero lanes.
#[inline(always)]
fn mask_bits<S: Simd>(mask: S::m32s) -> u32 {
    match size_of::<S::m32s>() {
        1 => u32::from(bytemuck::cast::<S::m32s, u8>(mask)),
        2 => u32::from(bytemuck::cast::<S::m32s, u16>(mask)),
        _ => bytemuck::bytes_of(&mask)
            .chunks_exact(4)
            .enumerate()
            .fold(0, |bits, (lane, b)| bits | (u32::from(b[0] != 0) << lane)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cloud(seed: u64, count: usize) -> Vec<Vec3> {
        let mut state = seed;
        let mut next = move || {
            state = state
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (state >> 40) as f32 / (1u64 << 24) as f32
        };
        (0..count)
            .map(|_| Vec3::new(next(), next(), next()))
            .collect()
    }

    /// The k nearest of a brute force over every point, as sets, with the k-th distance.
    fn check(points: &[Vec3], queries: &[Vec3], k: usize, got: &[u32]) {
        let k = k.min(points.len());
        assert_eq!(got.len(), queries.len() * k);
        for (q, found) in queries.iter().zip(got.chunks_exact(k)) {
            let mut d: Vec<(f32, u32)> = points
                .iter()
                .enumerate()
                .map(|(i, p)| (p.distance_squared(*q), i as u32))
                .collect();
            d.sort_by(|a, b| a.0.total_cmp(&b.0));
            let dist = |i: u32| points[i as usize].distance_squared(*q);
            // Nearest first (to a rounding of the distance), and the k-th distance is the
            // brute force's k-th.
            assert!(
                found
                    .windows(2)
                    .all(|w| dist(w[0]) <= dist(w[1]) * (1.0 + 1e-6))
            );
            assert!((dist(found[k - 1]) - d[k - 1].0).abs() <= 1e-6 * d[k - 1].0);
            let mut a: Vec<u32> = found.to_vec();
            let mut b: Vec<u32> = d[..k].iter().map(|x| x.1).collect();
            a.sort_unstable();
            b.sort_unstable();
            assert_eq!(a, b);
        }
    }

    /// The k-d tree's k nearest, searched in parallel, are a brute force's: the same sets,
    /// nearest first, for more queries than one task takes.
    #[test]
    fn the_tree_finds_the_brute_forces_neighbours() {
        let (points, queries) = (cloud(12345, 700), cloud(777, 1500));
        check(&points, &queries, 15, &knn_tree(&points, &queries, 15));
        // More neighbours asked than points: all of them.
        check(
            &points[..5],
            &queries[..3],
            8,
            &knn_tree(&points[..5], &queries[..3], 8),
        );
    }

    /// The scan, at every SIMD level this CPU has, finds the brute force's neighbours:
    /// for queries in random order (loose bounds), in a sweep along a line (tight ones), for
    /// point counts that are not whole vectors, and for fewer points than asked.
    #[test]
    fn the_scan_finds_the_brute_forces_neighbours_at_every_simd_level() {
        let sweep: Vec<Vec3> = (0..900)
            .map(|i| Vec3::new(i as f32 / 900.0, 0.5, 0.3 + 0.1 * (i as f32 * 0.05).sin()))
            .collect();
        for level in Level::all() {
            for (count, seed) in [(200, 1), (37, 2), (1, 3), (513, 4)] {
                let points = cloud(seed, count);
                for queries in [cloud(seed + 100, 1500), sweep.clone()] {
                    for k in [1, 15, 16] {
                        check(
                            &points,
                            &queries,
                            k,
                            &knn_scan_with(level, &points, &queries, None, k),
                        );
                    }
                }
            }
        }
    }

    /// Duplicated points (equal distances) still give k distinct indices, nearest first,
    /// and the same as the tree's sets where no distances tie.
    #[test]
    fn the_scan_keeps_k_distinct_points_among_duplicates() {
        let mut points = cloud(9, 40);
        points.extend(points.clone());
        let queries = cloud(10, 300);
        for level in Level::all() {
            let got = knn_scan_with(level, &points, &queries, None, 6);
            for found in got.chunks_exact(6) {
                let mut s = found.to_vec();
                s.sort_unstable();
                s.dedup();
                assert_eq!(s.len(), 6, "{found:?}");
            }
            check(&points, &queries, 6, &got);
        }
    }

    /// Visited along a Z-order curve, each query's neighbours land in its own place: the
    /// same lists as visiting the queries in their order, at every SIMD level.
    #[test]
    fn knn_along_puts_each_querys_neighbours_in_its_place() {
        let points = cloud(21, 200);
        let queries = cloud(22, 3000);
        let order = spatial_order(&queries);
        let mut sorted = order.clone();
        sorted.sort_unstable();
        assert_eq!(sorted, (0..3000).collect::<Vec<u32>>(), "a permutation");
        // Consecutive queries along the curve are closer than in storage order.
        let gap = |o: &[u32]| -> f32 {
            o.windows(2)
                .map(|w| queries[w[0] as usize].distance(queries[w[1] as usize]))
                .sum()
        };
        let stored: Vec<u32> = (0..3000).collect();
        assert!(gap(&order) < 0.2 * gap(&stored));
        for level in Level::all() {
            let plain = knn_scan_with(level, &points, &queries, None, 15);
            let along = knn_scan_with(level, &points, &queries, Some(&order), 15);
            assert_eq!(plain, along, "{level:?}");
            check(&points, &queries, 15, &along);
        }
        assert_eq!(
            knn_along(&points, &queries, &order, 15),
            knn_scan(&points, &queries, 15)
        );
        // Fewer than k queries, and none.
        assert_eq!(knn_along(&points, &queries[..2], &[1, 0], 15).len(), 30);
        assert!(knn_along(&points, &[], &[], 15).is_empty());
    }

    #[test]
    #[should_panic(expected = "twice in the order")]
    fn an_order_that_repeats_a_query_is_refused() {
        let points = cloud(23, 20);
        let queries = cloud(24, 3);
        knn_along(&points, &queries, &[0, 0, 2], 4);
    }

    /// Points with a NaN coordinate (of either sign) are never among the neighbours while
    /// there are enough others, wherever they stand (as the first k, which seed the first
    /// query's list), and fill the list last when there are not.
    #[test]
    fn points_with_nan_are_found_only_to_fill_k() {
        let mut points = cloud(25, 60);
        points[0].x = f32::NAN;
        points[3].y = -f32::NAN;
        points[40].z = f32::NAN;
        let finite: Vec<u32> = (0..60).filter(|i| ![0, 3, 40].contains(i)).collect();
        let queries = cloud(26, 400);
        for level in Level::all() {
            let got = knn_scan_with(level, &points, &queries, None, 15);
            for (q, found) in queries.iter().zip(got.chunks_exact(15)) {
                let mut want: Vec<(f32, u32)> = finite
                    .iter()
                    .map(|&i| (points[i as usize].distance_squared(*q), i))
                    .collect();
                want.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
                let want: Vec<u32> = want[..15].iter().map(|x| x.1).collect();
                assert_eq!(found, &want[..], "{level:?}");
            }
            let all = knn_scan_with(level, &points, &queries[..5], None, 60);
            for found in all.chunks_exact(60) {
                let mut tail = found[57..].to_vec();
                tail.sort_unstable();
                assert_eq!(tail, [0, 3, 40], "{level:?}");
            }
        }
    }

    /// [`knn`] picks the scan or the tree by the point count and both agree.
    #[test]
    fn scan_and_tree_agree() {
        let points = cloud(5, 200);
        let queries = cloud(6, 2000);
        let mut a = knn_scan(&points, &queries, 15);
        let mut b = knn_tree(&points, &queries, 15);
        for chunk in a.chunks_exact_mut(15).chain(b.chunks_exact_mut(15)) {
            chunk.sort_unstable();
        }
        assert_eq!(a, b);
        assert_eq!(knn(&points, &queries, 15).len(), 2000 * 15);
    }
}
