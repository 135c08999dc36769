//! Inference kernels on the CPU: two of the forward pass's slowest tensor operations at
//! batch 1, done as loops over the tensors' data.
//!
//! burn-flex reduces a middle axis (`max_dim(1)` of `[A, K, C]`) one output element at a
//! time, walking the axis with a stride of C: 2.7 ms for GarNet-Local's `[2967, 15, 32]`
//! local max where a sum over the same axis takes 0.23 ms. Here the max walks rows in
//! memory order, and the local max reads each pooled body feature in place instead of
//! gathering them (docs/bench.md, "Inference kernels"). FeaStNet's aggregation, the third
//! such kernel, is an operation with its own backward in [`super::feast`].
//!
//! They are used only where no gradient is wanted: [`host`] is true for tensors off the
//! autodiff device, and only when no GPU backend is compiled in (where reading the data
//! back would cost a device round trip). Training on the CPU backends takes the same max
//! pools as operations with their own backward ([`super::trainops`]), GPU builds burn's
//! operations; the tests below check each kernel against burn's.

use burn::tensor::{Int, Tensor, TensorData};
use pulp::{Simd, WithSimd};
use rayon::prelude::*;

use super::feast::Level;
use super::trainops::PoolRows;

/// Rows per rayon task: the loops below are a few hundred operations per row.
const ROWS_PER_TASK: usize = 256;

/// Whether the forward pass computes `x`'s reductions here: on the CPU backends, without
/// autodiff.
pub fn host<const D: usize>(x: &Tensor<D>) -> bool {
    cpu_build() && !x.is_autodiff()
}

/// Whether this build has only CPU backends (no GPU backend compiled in), where reading a
/// tensor's data costs no device round trip.
pub const fn cpu_build() -> bool {
    cfg!(not(any(feature = "cuda", feature = "wgpu")))
}

/// A tensor's values on the host, flattened.
pub(super) fn floats<const D: usize>(x: Tensor<D>) -> Vec<f32> {
    x.into_data()
        .convert::<f32>()
        .try_into_vec::<f32>()
        .expect("f32 tensor")
}

fn indices(x: &Tensor<1, Int>) -> Vec<usize> {
    x.clone()
        .into_data()
        .convert::<i64>()
        .try_into_vec::<i64>()
        .expect("i64 tensor")
        .into_iter()
        .map(|i| i as usize)
        .collect()
}

/// Running maximum that keeps a NaN once it has seen one (as `max_dim` does); of equal
/// values it keeps the first. Without branches, so that the loop runs on vector lanes
/// (with a branch per element it compared four lanes, then stored them one by one).
#[inline]
fn max_into(acc: &mut [f32], row: &[f32]) {
    for (m, &y) in acc.iter_mut().zip(row) {
        let take = (y > *m) | (y.is_nan() & !m.is_nan());
        *m = if take { y } else { *m };
    }
}

/// `x.max_dim(1)`: the maximum over the middle axis.
///
/// # Shapes
/// `[A, K, C]` -> `[A, 1, C]`.
pub fn max_axis1(x: Tensor<3>) -> Tensor<3> {
    let [a, k, c] = x.dims();
    if !host(&x) {
        if cpu_build() {
            let t = x.reshape([a * k, c]);
            return super::trainops::max_pool(t, PoolRows::Consecutive, k, a).reshape([a, 1, c]);
        }
        return x.max_dim(1);
    }
    let device = x.device();
    let out = row_maxima(&floats(x), [a, k, c]);
    Tensor::from_data(TensorData::new(out, [a, 1, c]), &device)
}

/// [`max_axis1`] on the host: `v` `[A, K, C]` -> `[A, C]`.
pub(super) fn row_maxima(v: &[f32], [a, k, c]: [usize; 3]) -> Vec<f32> {
    assert_eq!(v.len(), a * k * c, "[A, K, C] values");
    let mut out = vec![0.0f32; a * c];
    let reduce = |rows: &[f32], out: &mut [f32]| Level::Best.run(RowsMax { rows, out });
    if a >= rayon::current_num_threads() || k < 2 * ROWS_PER_TASK {
        out.par_chunks_mut(c)
            .zip(v.par_chunks(k * c))
            .with_min_len(ROWS_PER_TASK)
            .for_each(|(o, rows)| reduce(rows, o));
    } else {
        // Few long reductions (a batch's global feature over all its vertices): each
        // reduced in parts on the threads, the parts' maxima then taken in order. The
        // first of equal values and the first NaN win either way, so the bits are the
        // sequential loop's.
        for (o, rows) in out.chunks_exact_mut(c).zip(v.chunks_exact(k * c)) {
            let parts: Vec<Vec<f32>> = rows
                .par_chunks(ROWS_PER_TASK * c)
                .map(|part| {
                    let mut m = vec![0.0f32; c];
                    reduce(part, &mut m);
                    m
                })
                .collect();
            o.copy_from_slice(&parts[0]);
            for p in &parts[1..] {
                max_into(o, p);
            }
        }
    }
    out
}

/// `table.select(0, index).reshape([Q, K, L]).max_dim(1)`: for each of Q queries the
/// feature-wise maximum over the K rows `index` names, without materialising the `[Q * K,
/// L]` gather.
///
/// # Shapes
/// `table`: `[R, L]`, `index`: `[Q * K]` -> `[Q, L]`.
pub fn gather_max(table: Tensor<2>, index: &Tensor<1, Int>, k: usize) -> Tensor<2> {
    let [_, l] = table.dims();
    let q = index.dims()[0] / k;
    if !host(&table) {
        if cpu_build() {
            let rows = indices(index).into_iter().map(|i| i as u32).collect();
            return super::trainops::max_pool(table, PoolRows::Gathered(rows), k, q);
        }
        return table
            .select(0, index.clone())
            .reshape([q, k, l])
            .max_dim(1)
            .reshape([q, l]);
    }
    let device = table.device();
    let out = gathered_maxima(Level::Best, &floats(table), &indices(index), k, l);
    Tensor::from_data(TensorData::new(out, [q, l]), &device)
}

/// [`gather_max`] on the host at a SIMD level: `table` `[R, L]`, `rows` `[Q * K]` -> `[Q, L]`.
fn gathered_maxima(level: Level, table: &[f32], rows: &[usize], k: usize, l: usize) -> Vec<f32> {
    let mut out = vec![0.0f32; rows.len() / k * l];
    out.par_chunks_mut(ROWS_PER_TASK * l)
        .zip(rows.par_chunks(ROWS_PER_TASK * k))
        .for_each(|(out, rows)| {
            level.run(GatherMax {
                table,
                rows,
                k,
                out,
            })
        });
    out
}

/// The lanes where y takes over the running maximum m: y > m, or y is NaN and m is not (so
/// the first of equal values stays, and a NaN once seen stays; also the training pools',
/// [`super::trainops`]).
#[inline(always)]
pub(super) fn nan_takes<S: Simd>(simd: S, m: S::f32s, y: S::f32s) -> S::m32s {
    simd.or_m32s(
        simd.greater_than_f32s(y, m),
        simd.and_m32s(simd.not_m32s(simd.equal_f32s(y, y)), simd.equal_f32s(m, m)),
    )
}

/// [`max_into`] on vector lanes: y where it takes over m ([`nan_takes`]), else m.
#[inline(always)]
fn nan_max<S: Simd>(simd: S, m: S::f32s, y: S::f32s) -> S::f32s {
    simd.select_f32s(nan_takes(simd, m, y), y, m)
}

/// The maximum over `count` rows (`row(i)`, each as long as `out`) into `out`, per
/// vector-wide block of the columns, as [`max_into`] takes it; the columns past the last
/// whole vector with partial loads. (Written as loops: through iterator adapters the
/// vectors left the registers and the 10k drape took 4 ms more.)
#[inline(always)]
fn max_of_rows<'r, S: Simd>(
    simd: S,
    count: usize,
    row: impl Fn(usize) -> &'r [f32],
    out: &mut [f32],
) {
    let c = out.len();
    let (blocks, tail) = S::as_mut_simd_f32s(out);
    for (v, ov) in blocks.iter_mut().enumerate() {
        let mut m = S::as_simd_f32s(row(0)).0[v];
        for i in 1..count {
            m = nan_max(simd, m, S::as_simd_f32s(row(i)).0[v]);
        }
        *ov = m;
    }
    if !tail.is_empty() {
        let start = c - tail.len();
        let mut m = simd.partial_load_f32s(&row(0)[start..]);
        for i in 1..count {
            m = nan_max(simd, m, simd.partial_load_f32s(&row(i)[start..]));
        }
        simd.partial_store_f32s(tail, m);
    }
}

/// [`max_axis1`]'s reduction of consecutive rows (`[K, C]`) into `out` (`[C]`) in vector
/// registers.
struct RowsMax<'a> {
    rows: &'a [f32],
    out: &'a mut [f32],
}

impl WithSimd for RowsMax<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let (rows, c) = (self.rows, self.out.len());
        max_of_rows(
            simd,
            rows.len() / c,
            |i| &rows[i * c..(i + 1) * c],
            self.out,
        );
    }
}

/// [`gather_max`]'s loop for some queries in vector registers: per query the maximum over
/// its `k` rows (with the baseline x86-64 target `max_into` ran four lanes at a time, and
/// its loop's set-up per 32-float row cost more than the row).
struct GatherMax<'a> {
    table: &'a [f32],
    /// `k` table rows per query.
    rows: &'a [usize],
    k: usize,
    /// `[queries, L]`.
    out: &'a mut [f32],
}

impl WithSimd for GatherMax<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let GatherMax {
            table,
            rows,
            k,
            out,
        } = self;
        let l = out.len() / (rows.len() / k);
        for (o, rows) in out.chunks_exact_mut(l).zip(rows.chunks_exact(k)) {
            max_of_rows(simd, k, |i| &table[rows[i] * l..(rows[i] + 1) * l], o);
        }
    }
}

#[cfg(test)]
mod tests {
    use burn::tensor::{Device, Distribution, Int, Tensor, TensorData};

    use super::*;

    fn close(a: Tensor<3>, b: Tensor<3>) -> f32 {
        let (a, b) = (floats(a), floats(b));
        assert_eq!(a.len(), b.len());
        a.iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs() / (1.0 + y.abs()))
            .fold(0.0, f32::max)
    }

    #[test]
    fn max_over_the_middle_axis_is_burns() {
        let device = Device::default();
        device.seed(3);
        // The forward pass's shapes: a body feature, a garment feature, many small groups.
        for dims in [[1, 2000, 256], [2, 300, 48], [700, 15, 32]] {
            let x = Tensor::<3>::random(dims, Distribution::Normal(0.0, 1.0), &device);
            assert!(host(&x));
            let got = max_axis1(x.clone());
            assert_eq!(got.dims(), [dims[0], 1, dims[2]]);
            assert_eq!(close(got, x.max_dim(1)), 0.0, "{dims:?}");
        }
        // A NaN anywhere in a column stays in its maximum, as in max_dim.
        let mut v = vec![0.5f32; 2 * 3 * 2];
        v[2] = f32::NAN; // sample 0, row 1, column 0
        let x = Tensor::<3>::from_data(TensorData::new(v, [2, 3, 2]), &device);
        let got = floats(max_axis1(x));
        assert!(got[0].is_nan());
        assert_eq!(&got[1..], &[0.5, 0.5, 0.5]);
        // So it does in one long reduction cut into parts on the threads: a NaN deep in
        // column 1 (after the first part) and the largest value late in column 2.
        let (k, c) = (3000, 3);
        let mut v: Vec<f32> = (0..k * c)
            .map(|e| ((e * 7919) % 1000) as f32 / 1000.0)
            .collect();
        v[2100 * c + 1] = f32::NAN;
        v[2999 * c + 2] = 5.0;
        let x = Tensor::<3>::from_data(TensorData::new(v.clone(), [1, k, c]), &device);
        let got = floats(max_axis1(x));
        let col0 = v
            .iter()
            .step_by(c)
            .fold(f32::NEG_INFINITY, |m, &y| m.max(y));
        assert_eq!(got[0], col0);
        assert!(got[1].is_nan(), "{got:?}");
        assert_eq!(got[2], 5.0);
    }

    #[test]
    fn gathered_maximum_is_select_then_max_dim() {
        let device = Device::default();
        device.seed(4);
        let (rows, l, q, k) = (200, 32, 500, 15);
        let table = Tensor::<2>::random([rows, l], Distribution::Normal(0.0, 1.0), &device);
        let idx: Vec<i64> = (0..q * k).map(|i| ((i * 7919) % rows) as i64).collect();
        let index = Tensor::<1, Int>::from_data(TensorData::new(idx, [q * k]), &device);
        let got = gather_max(table.clone(), &index, k);
        let want = table.select(0, index).reshape([q, k, l]).max_dim(1);
        assert_eq!(close(got.reshape([q, 1, l]), want), 0.0);
    }

    /// At every SIMD level, for a width that is no whole number of vectors, the gathered
    /// maxima and the maxima over consecutive rows are [`max_into`]'s, bit for bit, NaNs
    /// kept.
    #[test]
    fn gathered_maxima_are_the_scalar_loops_at_every_simd_level() {
        let (rows, k, q) = (50, 7, 600);
        for l in [32, 37, 5] {
            let mut table: Vec<f32> = (0..rows * l)
                .map(|e| ((e * 7919) % 997) as f32 / 97.0 - 5.0)
                .collect();
            // Two NaN payloads in one column (the first seen stays) and both zeros in
            // another (of equal values the first stays).
            table[3 * l + 1] = f32::from_bits(0x7fc0_0001);
            table[4 * l + 1] = f32::from_bits(0xffc0_0002);
            table[10 * l + l - 1] = f32::NAN;
            for r in 0..rows {
                table[r * l + 2] = if r % 2 == 0 { -0.0 } else { 0.0 };
            }
            let idx: Vec<usize> = (0..q * k).map(|i| (i * 31 + i / 7) % rows).collect();
            let mut want = vec![0.0f32; q * l];
            for (o, r) in want.chunks_exact_mut(l).zip(idx.chunks_exact(k)) {
                o.copy_from_slice(&table[r[0] * l..(r[0] + 1) * l]);
                for &j in &r[1..] {
                    max_into(o, &table[j * l..(j + 1) * l]);
                }
            }
            assert!(want.iter().any(|v| v.is_nan()), "the test reaches a NaN");
            let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
            for level in Level::all() {
                let got = gathered_maxima(level, &table, &idx, k, l);
                assert_eq!(bits(&got), bits(&want), "width {l}, {level:?}");
            }
            // So are the maxima over consecutive rows (max_axis1's).
            let mut want = table[..l].to_vec();
            for r in table[l..].chunks_exact(l) {
                max_into(&mut want, r);
            }
            assert!(want.iter().any(|v| v.is_nan()));
            for level in Level::all() {
                let mut got = vec![0.0f32; l];
                level.run(RowsMax {
                    rows: &table,
                    out: &mut got,
                });
                assert_eq!(bits(&got), bits(&want), "width {l}, {level:?}");
            }
        }
    }
}
