//! The max pools and the leaky ReLU as operations with their own backward pass, for
//! training on the CPU backends.
//!
//! Under autodiff burn-flex takes a max pool over the middle axis of `[A, K, C]`
//! (`max_dim_with_indices`) one output element at a time, walking the axis with a stride of
//! C, and GarNet-Local's local max first gathers the `[Q * K, L]` neighbour features
//! (`select`); their backward passes scatter into zero tensors. The leaky ReLU is composed of
//! four element-wise passes each way ([`super::layers::leaky`]). A profile of a training
//! step put 9% of it in the max pools' forward passes and 6.5% in the leaky ReLU's
//! (docs/bench.md, "The max pools and the leaky ReLU as operations"). Here:
//!
//! - a max pool is one pass that keeps each maximum's row (`u32` per output value), in
//!   SIMD registers at the CPU's widest level ([`pulp`]; compiled plainly, the loop was one
//!   scalar comparison per value, 5.6% of a step), and its backward adds each output
//!   gradient to that row;
//! - the leaky ReLU is one pass forward and one backward (the gradient 1 where `x > 0`, the
//!   slope elsewhere, as [`super::layers::leaky`]'s composition gives).
//!
//! The values are bit for bit [`super::host`]'s inference kernels' and burn's `leaky_relu`'s;
//! the tests below compare values and gradients with burn's own operations. Only on the CPU
//! backends ([`super::host::cpu_build`]): GPU builds keep burn's operations.

use std::sync::Arc;

use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Dispatch, TensorMetadata, backend_extension};
use burn::tensor::Tensor;
use pulp::{Simd, WithSimd};
use rayon::prelude::*;

use super::feast::{Level, from_floats, with_floats};
use super::host::nan_takes;

/// Output rows per rayon task (each a few hundred comparisons).
const ROWS_PER_TASK: usize = 256;

/// Which table rows each output row of a max pool reduces: `K` of them per output row.
#[derive(Debug, Clone, PartialEq)]
pub enum PoolRows {
    /// Output row q reduces rows `q K .. (q + 1) K` (a max over the middle axis of
    /// `[A, K, C]` seen as a `[A K, C]` table).
    Consecutive,
    /// Output row q reduces rows `index[q K .. (q + 1) K]`.
    Gathered(Vec<u32>),
}

impl PoolRows {
    fn row(&self, q: usize, j: usize, k: usize) -> usize {
        match self {
            PoolRows::Consecutive => q * k + j,
            PoolRows::Gathered(index) => index[q * k + j] as usize,
        }
    }
}

/// The maxima of a max pool and the table row each came from.
///
/// `table` `[R, L]` -> (`[Q, L]` maxima, `[Q, L]` rows) with Q = the rows' count / K. Of
/// equal values the first row stays, and a NaN once seen stays (as in `max_dim` and the
/// inference kernels of [`super::host`]).
pub fn pool_forward(
    table: &[f32],
    l: usize,
    rows: &PoolRows,
    k: usize,
    q: usize,
) -> (Vec<f32>, Vec<u32>) {
    pool_forward_with(Level::Best, table, l, rows, k, q)
}

/// [`pool_forward`] at `level`.
fn pool_forward_with(
    level: Level,
    table: &[f32],
    l: usize,
    rows: &PoolRows,
    k: usize,
    q: usize,
) -> (Vec<f32>, Vec<u32>) {
    assert!(k > 0 && l > 0, "a max pool over no rows or no features");
    let mut out = vec![0.0f32; q * l];
    let mut arg = vec![0u32; q * l];
    out.par_chunks_mut(ROWS_PER_TASK * l)
        .zip(arg.par_chunks_mut(ROWS_PER_TASK * l))
        .enumerate()
        .for_each(|(t, (out, arg))| {
            level.run(PoolTask {
                first: t * ROWS_PER_TASK,
                out,
                arg,
                table,
                l,
                rows,
                k,
            })
        });
    (out, arg)
}

/// One rayon task of [`pool_forward`]: the output rows from `first` on, `out` and `arg`
/// holding `out.len() / L` of them. Run at the CPU's widest SIMD ([`pulp`]): per output row
/// and vector block of the features, the running maxima and their rows stay in registers
/// while the row's K table rows are compared in turn (the plain loop compiled to one
/// scalar comparison per value).
struct PoolTask<'a> {
    first: usize,
    out: &'a mut [f32],
    arg: &'a mut [u32],
    table: &'a [f32],
    l: usize,
    rows: &'a PoolRows,
    k: usize,
}

impl WithSimd for PoolTask<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let PoolTask {
            first,
            out,
            arg,
            table,
            l,
            rows,
            k,
        } = self;
        for (i, (mo, ao)) in out
            .chunks_exact_mut(l)
            .zip(arg.chunks_exact_mut(l))
            .enumerate()
        {
            let row = |j: usize| rows.row(first + i, j, k);
            let (mh, mt) = S::as_mut_simd_f32s(mo);
            let (ah, at) = S::as_mut_simd_u32s(ao);
            for (v, (mv, av)) in mh.iter_mut().zip(ah.iter_mut()).enumerate() {
                (*mv, *av) = max_and_row(simd, k, row, l, table, |y| S::as_simd_f32s(y).0[v]);
            }
            if !mt.is_empty() {
                let tail = |y: &[f32]| simd.partial_load_f32s(S::as_simd_f32s(y).1);
                let (m, a) = max_and_row(simd, k, row, l, table, tail);
                simd.partial_store_f32s(mt, m);
                simd.partial_store_u32s(at, a);
            }
        }
    }
}

/// The maximum over the `k` table rows `row(0..k)` (each `l` long) of one vector block of
/// the features (`load` reads it from a row), and the row each lane's maximum came from.
/// A row takes over where [`nan_takes`] says, as at inference: the first of equal values
/// stays, and so does a NaN once seen.
#[inline(always)]
fn max_and_row<S: Simd>(
    simd: S,
    k: usize,
    row: impl Fn(usize) -> usize,
    l: usize,
    table: &[f32],
    load: impl Fn(&[f32]) -> S::f32s,
) -> (S::f32s, S::u32s) {
    let r0 = row(0);
    let (mut m, mut a) = (
        load(&table[r0 * l..(r0 + 1) * l]),
        simd.splat_u32s(r0 as u32),
    );
    for j in 1..k {
        let r = row(j);
        let y = load(&table[r * l..(r + 1) * l]);
        let take = nan_takes(simd, m, y);
        m = simd.select_f32s(take, y, m);
        a = simd.select_u32s(take, simd.splat_u32s(r as u32), a);
    }
    (m, a)
}

/// The max pool's backward pass: each output gradient added to its maximum's table row.
///
/// `g` `[Q, L]`, `arg` `[Q, L]` -> `[R, L]`.
pub fn pool_backward(g: &[f32], arg: &[u32], l: usize, r: usize) -> Vec<f32> {
    let mut gt = vec![0.0f32; r * l];
    for (gq, aq) in g.chunks_exact(l).zip(arg.chunks_exact(l)) {
        for c in 0..l {
            gt[aq[c] as usize * l + c] += gq[c];
        }
    }
    gt
}

/// Values per rayon task of the leaky ReLU's passes.
const VALUES_PER_TASK: usize = 1 << 14;

/// The leaky ReLU's values, `x` where `x > 0`, `slope x` elsewhere.
fn leaky_forward(x: &[f32], slope: f32) -> Vec<f32> {
    let mut y = vec![0.0f32; x.len()];
    y.par_chunks_mut(VALUES_PER_TASK)
        .zip(x.par_chunks(VALUES_PER_TASK))
        .for_each(|(y, x)| {
            for (y, &v) in y.iter_mut().zip(x) {
                *y = if v > 0.0 { v } else { slope * v };
            }
        });
    y
}

/// The leaky ReLU's backward pass: `g` where `x > 0`, `slope g` elsewhere.
fn leaky_backward(x: &[f32], g: &[f32], slope: f32) -> Vec<f32> {
    assert_eq!(x.len(), g.len(), "the gradient's shape is the input's");
    let mut gx = vec![0.0f32; x.len()];
    gx.par_chunks_mut(VALUES_PER_TASK)
        .zip(
            x.par_chunks(VALUES_PER_TASK)
                .zip(g.par_chunks(VALUES_PER_TASK)),
        )
        .for_each(|(gx, (x, g))| {
            for ((gx, &v), &gv) in gx.iter_mut().zip(x).zip(g) {
                *gx = if v > 0.0 { gv } else { slope * gv };
            }
        });
    gx
}

/// The max pools and the leaky ReLU as backend operations (see the module's documentation).
#[backend_extension(
    Flex: cfg(feature = "flex"),
    NdArray: cfg(feature = "ndarray"),
    Autodiff
)]
pub trait TrainOps: Backend {
    /// [`pool_forward`]'s maxima on the backend's tensors: `table` `[R, L]` -> `[Q, L]`.
    fn train_max_pool(
        table: FloatTensor<Self>,
        rows: Arc<PoolRows>,
        k: usize,
        q: usize,
    ) -> FloatTensor<Self> {
        let l = table.shape()[1];
        let device = table.device();
        let (out, _) = with_floats::<Self, _>(&table, |t| pool_forward(t, l, &rows, k, q));
        from_floats::<Self>(out, vec![q, l], &device)
    }

    /// [`leaky_forward`] on the backend's tensors, any shape.
    fn train_leaky(x: FloatTensor<Self>, slope: f32) -> FloatTensor<Self> {
        let shape = x.shape().to_vec();
        let device = x.device();
        let y = with_floats::<Self, _>(&x, |x| leaky_forward(x, slope));
        from_floats::<Self>(y, shape, &device)
    }
}

#[cfg(feature = "flex")]
impl TrainOps for burn::backend::Flex {}
#[cfg(feature = "ndarray")]
impl TrainOps for burn::backend::NdArray {}

/// The backward step recorded for [`TrainOps::train_max_pool`] under autodiff.
#[derive(Debug)]
struct MaxPool;

impl<B: Backend + TrainOps> Backward<B, 1> for MaxPool {
    /// Each maximum's table row, `[Q, L]`, and the table's shape `[R, L]`.
    type State = (Arc<Vec<u32>>, [usize; 2]);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let (arg, [r, l]) = ops.state;
        let g = grads.consume::<B>(&ops.node);
        let device = g.device();
        let gt = with_floats::<B, _>(&g, |g| pool_backward(g, &arg, l, r));
        if let [Some(node)] = ops.parents {
            grads.register::<B>(node.id, from_floats::<B>(gt, vec![r, l], &device));
        }
    }
}

/// The backward step recorded for [`TrainOps::train_leaky`] under autodiff.
#[derive(Debug)]
struct Leaky;

impl<B: Backend + TrainOps> Backward<B, 1> for Leaky {
    /// The input and the slope.
    type State = (FloatTensor<B>, f32);

    fn backward(self, ops: Ops<Self::State, 1>, grads: &mut Gradients, _: &mut Checkpointer) {
        let (x, slope) = ops.state;
        let g = grads.consume::<B>(&ops.node);
        let shape = g.shape().to_vec();
        let device = g.device();
        let gx = with_floats::<B, _>(&x, |x| {
            with_floats::<B, _>(&g, |g| leaky_backward(x, g, slope))
        });
        if let [Some(node)] = ops.parents {
            grads.register::<B>(node.id, from_floats::<B>(gx, shape, &device));
        }
    }
}

impl<B: Backend + TrainOps, C: CheckpointStrategy> TrainOps for Autodiff<B, C> {
    fn train_max_pool(
        table: FloatTensor<Self>,
        rows: Arc<PoolRows>,
        k: usize,
        q: usize,
    ) -> FloatTensor<Self> {
        let (table, node) = table.into_parts();
        let [r, l] = [table.shape()[0], table.shape()[1]];
        let device = table.device();
        let (out, arg) = with_floats::<B, _>(&table, |t| pool_forward(t, l, &rows, k, q));
        let out = from_floats::<B>(out, vec![q, l], &device);
        match MaxPool.prepare::<C>([node]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => prep.finish((Arc::new(arg), [r, l]), out),
            OpsKind::UnTracked(prep) => prep.finish(out),
        }
    }

    fn train_leaky(x: FloatTensor<Self>, slope: f32) -> FloatTensor<Self> {
        let (x, node) = x.into_parts();
        let y = B::train_leaky(x.clone(), slope);
        match Leaky.prepare::<C>([node]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => prep.finish((x, slope), y),
            OpsKind::UnTracked(prep) => prep.finish(y),
        }
    }
}

/// [`TrainOps::train_max_pool`] on high-level tensors.
///
/// # Shapes
/// `table`: `[R, L]` -> `[Q, L]`.
pub fn max_pool(table: Tensor<2>, rows: PoolRows, k: usize, q: usize) -> Tensor<2> {
    Tensor::from_dispatch(<Dispatch as TrainOps>::train_max_pool(
        table.into_dispatch(),
        Arc::new(rows),
        k,
        q,
    ))
}

/// [`TrainOps::train_leaky`] on high-level tensors, any shape.
pub fn leaky<const D: usize>(x: Tensor<D>, slope: f64) -> Tensor<D> {
    Tensor::from_dispatch(<Dispatch as TrainOps>::train_leaky(
        x.into_dispatch(),
        slope as f32,
    ))
}

// On the default device, which is a GPU one in builds with a GPU backend, where these
// operations do not exist (the model takes burn's there).
#[cfg(all(test, not(any(feature = "cuda", feature = "wgpu"))))]
pub(crate) mod tests {
    use burn::tensor::activation::leaky_relu;
    use burn::tensor::{Device, Distribution, Int, Tensor, TensorData};

    use super::{Level, PoolRows, leaky, max_pool};
    use crate::model::host::{floats, gather_max, max_axis1};

    /// Two leaves on the autodiff device with the same normal random values.
    fn twins<const D: usize>(dims: [usize; D], seed: u64) -> (Tensor<D>, Tensor<D>) {
        let plain = Device::default();
        plain.seed(seed);
        let data = Tensor::<D>::random(dims, Distribution::Normal(0.0, 1.0), &plain).into_data();
        let ad = plain.autodiff();
        (
            Tensor::<D>::from_data(data.clone(), &ad).require_grad(),
            Tensor::<D>::from_data(data, &ad).require_grad(),
        )
    }

    /// The largest difference relative to `want`'s largest magnitude (also for the tests
    /// of [`crate::model::dense`] and [`crate::model::SplitLinear`]).
    pub(crate) fn rel(got: &[f32], want: &[f32]) -> f32 {
        assert_eq!(got.len(), want.len());
        let scale = want.iter().fold(1e-12f32, |s, v| s.max(v.abs()));
        got.iter()
            .zip(want)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f32::max)
            / scale
    }

    /// Values bit for bit, and `x`'s gradient of `sum(w * y)` within rounding, for the
    /// operation `got` and burn's formulation `want` of the same function.
    fn same_values_and_gradients<const D: usize, const E: usize>(
        dims: [usize; D],
        seed: u64,
        got: impl Fn(Tensor<D>) -> Tensor<E>,
        want: impl Fn(Tensor<D>) -> Tensor<E>,
    ) {
        let (a, b) = twins(dims, seed);
        let (ya, yb) = (got(a.clone()), want(b.clone()));
        assert_eq!(ya.dims(), yb.dims());
        let bits = |v: Vec<f32>| v.into_iter().map(f32::to_bits).collect::<Vec<_>>();
        assert_eq!(
            bits(floats(ya.clone().inner())),
            bits(floats(yb.clone().inner())),
            "values, {dims:?}"
        );
        let w = Tensor::<E>::random(ya.dims(), Distribution::Normal(0.0, 1.0), &ya.device());
        let ga = a
            .grad(&(ya * w.clone()).sum().backward())
            .expect("a gradient");
        let gb = b.grad(&(yb * w).sum().backward()).expect("a gradient");
        let (ga, gb) = (floats(ga), floats(gb));
        assert!(gb.iter().any(|g| *g != 0.0), "the test reaches gradients");
        let err = rel(&ga, &gb);
        assert!(
            err < 1e-6,
            "gradients differ by {err} of the largest, {dims:?}"
        );
    }

    /// The local max under autodiff: gathered rows (some named more than once, so their
    /// gradients add up) against `select` then `max_dim`.
    #[test]
    fn gathered_max_pool_is_select_then_max_dim_with_its_gradient() {
        let (rows, l, q, k) = (200, 37, 500, 15);
        let idx: Vec<i64> = (0..q * k).map(|i| ((i * 7919) % rows) as i64).collect();
        let ad = Device::default().autodiff();
        let index = Tensor::<1, Int>::from_data(TensorData::new(idx.clone(), [q * k]), &ad);
        let want = |t: Tensor<2>| {
            t.select(0, index.clone())
                .reshape([q, k, l])
                .max_dim(1)
                .reshape([q, l])
        };
        same_values_and_gradients([rows, l], 11, |t| gather_max(t, &index, k), want);
        let rows_u32: Vec<u32> = idx.iter().map(|&i| i as u32).collect();
        same_values_and_gradients(
            [rows, l],
            12,
            |t| max_pool(t, PoolRows::Gathered(rows_u32.clone()), k, q),
            want,
        );
    }

    /// Of equal values the first row stays and takes the gradient; a NaN once seen stays
    /// (as `max_dim` and the inference kernels of [`crate::model::host`]).
    #[test]
    fn pool_keeps_the_first_of_equal_values_and_a_nan() {
        // Rows 0..4 of width 2: column 0 ties at 1.0 in rows 1 and 3, column 1 has a NaN in
        // row 2 and a larger value after it.
        let table = [0.0, 0.0, 1.0, 0.5, -1.0, f32::NAN, 1.0, 9.0];
        let rows = PoolRows::Gathered(vec![0, 1, 2, 3, 3, 1, 0, 2]);
        let (out, arg) = super::pool_forward(&table, 2, &rows, 4, 2);
        assert_eq!((out[0], arg[0]), (1.0, 1));
        assert!(out[1].is_nan() && arg[1] == 2, "{out:?} {arg:?}");
        assert_eq!((out[2], arg[2]), (1.0, 3));
        assert!(out[3].is_nan() && arg[3] == 2, "{out:?} {arg:?}");
        // Both outputs' gradients land in their rows, added where rows coincide.
        let g = super::pool_backward(&[1.0, 2.0, 10.0, 20.0], &arg, 2, 4);
        assert_eq!(g, vec![0.0, 0.0, 1.0, 0.0, 0.0, 22.0, 10.0, 0.0]);
        let (out, arg) = super::pool_forward(&table, 2, &PoolRows::Consecutive, 2, 2);
        assert_eq!((&out[..3], arg), (&[1.0, 0.5, 1.0][..], vec![1, 1, 3, 2]));
        assert!(
            out[3].is_nan(),
            "the NaN of row 2 stays before row 3's 9: {out:?}"
        );
    }

    /// Every SIMD level's pool is the plain loop's, bit for bit and row for row: 37
    /// features (whole vectors and a tail at every vector width), values with many ties,
    /// scattered NaNs, and a column of NaNs of three bit patterns in every third row (so a
    /// pool meets several NaNs, and only the first may stay), gathered and consecutive rows.
    #[test]
    fn every_simd_level_pools_as_the_plain_loop() {
        let (r, l, k, q) = (60, 37, 7, 90);
        let nans = [f32::NAN, -f32::NAN, f32::from_bits(f32::NAN.to_bits() | 1)];
        let table: Vec<f32> = (0..r * l)
            .map(|i| match ((i * 2_654_435_761usize) % 97, i / l, i % l) {
                (_, row, 35) if row % 3 == 0 => nans[(row / 3) % 3],
                (0, _, _) => f32::NAN,
                (v, _, _) => (v % 9) as f32 - 4.0,
            })
            .collect();
        // The loop before session 70, one value at a time.
        let plain = |table: &[f32], rows: &PoolRows| {
            let (mut out, mut arg) = (vec![0.0f32; q * l], vec![0u32; q * l]);
            for qi in 0..q {
                for c in 0..l {
                    let first = rows.row(qi, 0, k);
                    let (mut m, mut a) = (table[first * l + c], first as u32);
                    for j in 1..k {
                        let row = rows.row(qi, j, k);
                        let y = table[row * l + c];
                        if y > m || (y.is_nan() && !m.is_nan()) {
                            (m, a) = (y, row as u32);
                        }
                    }
                    (out[qi * l + c], arg[qi * l + c]) = (m, a);
                }
            }
            (out, arg)
        };
        let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
        let gathered = PoolRows::Gathered((0..q * k).map(|i| ((i * 31) % r) as u32).collect());
        // Consecutive rows read q k table rows.
        let long: Vec<f32> = (0..q * k * l).map(|i| table[i % (r * l)]).collect();
        for (t, rows) in [(&table, &gathered), (&long, &PoolRows::Consecutive)] {
            let (want, want_arg) = plain(t, rows);
            assert!(want.iter().any(|v| v.is_nan()), "the test reaches a NaN");
            for level in Level::all() {
                let (out, arg) = super::pool_forward_with(level, t, l, rows, k, q);
                assert_eq!(bits(&out), bits(&want), "{level:?}, {rows:?}");
                assert_eq!(arg, want_arg, "{level:?}, {rows:?}");
            }
        }
    }

    /// The max over the middle axis under autodiff against `max_dim(1)`, at the forward
    /// pass's shapes (a body feature, a garment feature, many small groups).
    #[test]
    fn middle_axis_max_pool_is_max_dim_with_its_gradient() {
        for (i, dims) in [[1, 2000, 64], [2, 300, 48], [700, 15, 32]]
            .into_iter()
            .enumerate()
        {
            same_values_and_gradients(dims, 20 + i as u64, max_axis1, |x| x.max_dim(1));
        }
    }

    /// The leaky ReLU under autodiff: burn's `leaky_relu` values bit for bit, and the
    /// gradient of `slope x + (1 - slope) relu(x)` (1 where x > 0, the slope elsewhere, also
    /// at exactly 0).
    #[test]
    fn leaky_is_burns_leaky_relu_with_the_composed_gradient() {
        let slope = 0.2;
        same_values_and_gradients(
            [3, 40_000],
            31,
            |x| leaky(x, slope),
            |x| leaky_relu(x, slope),
        );
        let ad = Device::default().autodiff();
        let v = vec![-1.5f32, -0.0, 0.0, 0.5, 2.0];
        let x = Tensor::<1>::from_data(TensorData::new(v, [5]), &ad).require_grad();
        let g = floats(x.grad(&leaky(x.clone(), slope).sum().backward()).unwrap());
        let s = slope as f32;
        assert_eq!(g, vec![s, s, s, 1.0, 1.0]);
    }
}
