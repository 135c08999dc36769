//! Linear layers as one operation with its own backward pass, for training on burn-flex:
//! `act(s (x W) + a)`, where the addend `a` is the bias, a per-sample term (a split layer's
//! global inputs, [`super::SplitLinear`]) or another per-row term, `s` a constant scale per
//! row of a sample or none (FeaStNet's `1 / |N_i|`, [`super::FeaStConv`]), and `act` the
//! leaky ReLU or none.
//!
//! burn runs a linear layer under autodiff as a matrix product and a bias addition, each
//! with its own output, and the leaky ReLU after it as another pass
//! ([`super::trainops::leaky`]). A profile of a training step (docs/bench.md, "Linear
//! layers as one operation") put 10% of it in burn-flex's two-dimensional products' memory
//! traffic (each output allocated zeroed, then copied into an aligned buffer), 11% in the
//! leaky ReLU's two passes and 5% in the bias's addition and its gradient's sum. Here the
//! output is written once, in blocks of [`ROWS`] rows: the addend, then the product added
//! to it (`gemm`; with a scale, the product first and then `s` times it plus the addend),
//! then the activation, while the block is in cache. The backward pass walks the same
//! blocks: the activation's gradient `dz` (1 where the output is positive, the slope
//! elsewhere: the leaky ReLU keeps the sign for a slope of 0 or more), the input's gradient
//! `dp W^T` with `dp = s dz` (`dz` without a scale), and `x^T dp` and the addend's sums of
//! `dz` into the weight's and addend's gradients. Those sums run over at most [`GROUPS`] fixed ranges of whole blocks, each
//! summed in order and then added in order, so they do not depend on how rayon schedules the ranges: the same
//! inputs give the same gradients bit for bit.
//!
//! The tests compare values and gradients with burn's `matmul`, addition and `leaky_relu`
//! (within rounding: the sums run in another order), and [`super::SplitLinear`]'s with its
//! burn composition.

use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Dispatch, TensorMetadata, backend_extension};
use burn::tensor::Tensor;
use rayon::prelude::*;
use std::sync::Arc;

use super::feast::{from_floats, with_floats};

/// Rows per block (per `gemm` call): the block's outputs and gradients stay in cache.
pub const ROWS: usize = 256;

/// Fixed ranges of rows whose weight and addend gradients are summed apart, then in order.
pub const GROUPS: usize = 8;

/// The largest offset of a `[rows, cols]` matrix with strides `[rs, cs]`, plus one.
fn extent([rows, cols]: [usize; 2], [rs, cs]: [usize; 2]) -> usize {
    if rows == 0 || cols == 0 {
        0
    } else {
        (rows - 1) * rs + (cols - 1) * cs + 1
    }
}

/// `dst[m, n] (+)= lhs[m, k] rhs[k, n]` on one thread (`gemm`), strides in elements as
/// (row, column). Panics if a matrix reaches past its slice.
#[allow(unsafe_code, clippy::too_many_arguments)]
fn product(
    [m, n, k]: [usize; 3],
    dst: &mut [f32],
    dst_strides: [usize; 2],
    accumulate: bool,
    lhs: &[f32],
    lhs_strides: [usize; 2],
    rhs: &[f32],
    rhs_strides: [usize; 2],
) {
    if m == 0 || n == 0 {
        return;
    }
    assert!(
        extent([m, n], dst_strides) <= dst.len(),
        "dst [{m}, {n}] out of bounds"
    );
    assert!(
        extent([m, k], lhs_strides) <= lhs.len(),
        "lhs [{m}, {k}] out of bounds"
    );
    assert!(
        extent([k, n], rhs_strides) <= rhs.len(),
        "rhs [{k}, {n}] out of bounds"
    );
    let [dst_rs, dst_cs] = dst_strides.map(|v| v as isize);
    let [lhs_rs, lhs_cs] = lhs_strides.map(|v| v as isize);
    let [rhs_rs, rhs_cs] = rhs_strides.map(|v| v as isize);
    // SAFETY: each matrix lies inside its slice (checked above), and dst, borrowed
    // mutably, overlaps neither of the others. gemm computes dst = alpha dst + beta lhs
    // rhs (here alpha = beta = 1) and does not read dst when read_dst is false.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            dst.as_mut_ptr(),
            dst_cs,
            dst_rs,
            accumulate,
            lhs.as_ptr(),
            lhs_cs,
            lhs_rs,
            rhs.as_ptr(),
            rhs_cs,
            rhs_rs,
            1.0f32,
            1.0f32,
            false,
            false,
            false,
            gemm::Parallelism::None,
        );
    }
}

/// The sizes of one dense operation: `rows` rows of `input` features to `output` features,
/// the rows in `batch` equal runs (the samples) for a per-sample addend.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Sizes {
    rows: usize,
    input: usize,
    output: usize,
    batch: usize,
}

impl Sizes {
    /// The sizes of `x` `[rows, input]`, `w` `[input, output]` and an addend of `add`
    /// values, which must be `[batch, output]` (one row per sample) or `[rows, output]`.
    fn of(x: usize, w: usize, add: usize, input: usize, output: usize, batch: usize) -> Self {
        assert!(input > 0 && output > 0, "a dense layer without features");
        assert_eq!(x % input, 0, "x's values are rows of {input}");
        assert_eq!(w, input * output, "w is [{input}, {output}]");
        let rows = x / input;
        assert!(
            batch > 0 && rows.is_multiple_of(batch),
            "{rows} rows in {batch} samples"
        );
        assert!(
            add == batch * output || add == rows * output,
            "an addend of {add} values for {batch} samples and {rows} rows of {output}"
        );
        Sizes {
            rows,
            input,
            output,
            batch,
        }
    }

    /// Panics unless `scale` is none or one value per row of a sample: its length divides
    /// the rows (the samples' count need not be the addend's `batch`, which is 1 for a
    /// bias).
    fn check_scale(&self, scale: Option<&[f32]>) {
        if let Some(sc) = scale {
            assert!(
                !sc.is_empty() && self.rows.is_multiple_of(sc.len()),
                "a scale of {} values for {} rows: one per row of a sample",
                sc.len(),
                self.rows
            );
        }
    }

    /// The addend's row for row `i`.
    fn add_row(&self, add_len: usize, i: usize) -> usize {
        if add_len == self.rows * self.output {
            i
        } else {
            i / (self.rows / self.batch)
        }
    }

    /// Rows per group of [`dense_backward`]: whole blocks, at most [`GROUPS`] groups.
    fn group_rows(&self) -> usize {
        self.rows.div_ceil(GROUPS).div_ceil(ROWS).max(1) * ROWS
    }
}

/// `act(s (x W) + a)` for `x` `[rows, input]`, `w` `[input, output]`, `add` `[batch,
/// output]` or `[rows, output]`, `scale` (`s`) one value per row of a sample (row `i`
/// takes `scale[i % scale.len()]`) or none, with the leaky ReLU of `slope` when there is
/// one.
pub fn dense_forward(
    x: &[f32],
    w: &[f32],
    add: &[f32],
    [input, output, batch]: [usize; 3],
    slope: Option<f32>,
    scale: Option<&[f32]>,
) -> Vec<f32> {
    let s = Sizes::of(x.len(), w.len(), add.len(), input, output, batch);
    s.check_scale(scale);
    let mut y = vec![0.0f32; s.rows * output];
    y.par_chunks_mut(ROWS * output)
        .enumerate()
        .for_each(|(t, block)| {
            let first = t * ROWS;
            let rows = block.len() / output;
            if scale.is_none() {
                for (i, row) in block.chunks_exact_mut(output).enumerate() {
                    let a = s.add_row(add.len(), first + i) * output;
                    row.copy_from_slice(&add[a..a + output]);
                }
            }
            product(
                [rows, output, input],
                block,
                [output, 1],
                scale.is_none(),
                &x[first * input..],
                [input, 1],
                w,
                [output, 1],
            );
            if let Some(sc) = scale {
                for (i, row) in block.chunks_exact_mut(output).enumerate() {
                    let a = s.add_row(add.len(), first + i) * output;
                    let f = sc[(first + i) % sc.len()];
                    for (v, &b) in row.iter_mut().zip(&add[a..a + output]) {
                        *v = f * *v + b;
                    }
                }
            }
            if let Some(slope) = slope {
                for v in block.iter_mut() {
                    *v = if *v > 0.0 { *v } else { slope * *v };
                }
            }
        });
    y
}

/// Which gradients [`dense_backward`] computes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Wanted {
    /// The input's gradient.
    pub x: bool,
    /// The weight's.
    pub w: bool,
    /// The addend's.
    pub add: bool,
}

/// The gradients of [`dense_forward`]: `x`'s `[rows, input]`, `w`'s `[input, output]`, the
/// addend's (its shape), each when wanted.
#[derive(Debug, Default)]
pub struct DenseGrads {
    /// The input's gradient, `[rows, input]`.
    pub x: Option<Vec<f32>>,
    /// The weight's, `[input, output]`.
    pub w: Option<Vec<f32>>,
    /// The addend's, its shape. None for a per-row addend without the activation, whose
    /// gradient is the output's `g` itself (the caller passes it on, not a copy).
    pub add: Option<Vec<f32>>,
}

/// One group's share of the sums: the weight's gradient and the per-sample addend's.
struct Partial {
    w: Vec<f32>,
    add: Vec<f32>,
}

/// The backward pass of [`dense_forward`] for the output gradient `g` `[rows, output]`:
/// `y` is the forward pass's output (read for the activation's gradient; unused without
/// `slope`), `add_len` the addend's length, `scale` the forward pass's.
#[allow(clippy::too_many_arguments)]
pub fn dense_backward(
    x: &[f32],
    w: &[f32],
    y: &[f32],
    g: &[f32],
    add_len: usize,
    [input, output, batch]: [usize; 3],
    slope: Option<f32>,
    scale: Option<&[f32]>,
    want: Wanted,
) -> DenseGrads {
    let s = Sizes::of(x.len(), w.len(), add_len, input, output, batch);
    s.check_scale(scale);
    assert_eq!(
        g.len(),
        s.rows * output,
        "the gradient is the output's shape"
    );
    if let Some(slope) = slope {
        assert!(
            slope >= 0.0,
            "the output's sign is the input's for slopes of 0 or more"
        );
        assert_eq!(y.len(), g.len(), "the output is the gradient's shape");
    }
    let per_row = add_len == s.rows * output && s.rows != batch;
    let want = Wanted {
        add: want.add && !(per_row && slope.is_none()),
        ..want
    };
    let group = s.group_rows();
    let groups = s.rows.div_ceil(group).max(1);
    // Outputs written group by group: x's gradient and a per-row addend's (which is dz).
    let mut gx = vec![0.0f32; if want.x { s.rows * input } else { 0 }];
    let mut gadd = vec![0.0f32; if want.add && per_row { add_len } else { 0 }];
    let mut gx_parts = gx.chunks_mut(group * input);
    let mut gadd_parts = gadd.chunks_mut(group * output);
    let work: Vec<_> = (0..groups)
        .map(|k| (k, gx_parts.next(), gadd_parts.next()))
        .collect();
    let partials: Vec<Partial> = work
        .into_par_iter()
        .map(|(k, mut gx_part, mut gadd_part)| {
            let mut part = Partial {
                w: vec![0.0; if want.w { input * output } else { 0 }],
                add: vec![
                    0.0;
                    if want.add && !per_row {
                        batch * output
                    } else {
                        0
                    }
                ],
            };
            let mut scratch: Vec<f32> = Vec::new();
            let mut scaled: Vec<f32> = Vec::new();
            let start = k * group;
            let end = (start + group).min(s.rows);
            for first in (start..end).step_by(ROWS) {
                let rows = ROWS.min(end - first);
                let local = first - start;
                let gb = &g[first * output..(first + rows) * output];
                // dz: the output gradient through the activation, into the per-row
                // addend's gradient when it is wanted, else into scratch.
                let dz: &[f32] = match (slope, gadd_part.as_deref_mut()) {
                    (None, _) => gb,
                    (Some(slope), Some(part)) => {
                        let yb = &y[first * output..(first + rows) * output];
                        let d = &mut part[local * output..(local + rows) * output];
                        for ((d, &gv), &yv) in d.iter_mut().zip(gb).zip(yb) {
                            *d = if yv > 0.0 { gv } else { slope * gv };
                        }
                        d
                    }
                    (Some(slope), None) => {
                        let yb = &y[first * output..(first + rows) * output];
                        scratch.clear();
                        scratch.extend(
                            gb.iter()
                                .zip(yb)
                                .map(|(&gv, &yv)| if yv > 0.0 { gv } else { slope * gv }),
                        );
                        &scratch
                    }
                };
                // The product's gradient: dz, times the row's scale when there is one
                // (the addend's gradient is dz).
                let dp: &[f32] = match scale {
                    None => dz,
                    Some(sc) => {
                        scaled.resize(dz.len(), 0.0);
                        let rows = scaled.chunks_exact_mut(output).zip(dz.chunks_exact(output));
                        for (i, (d, row)) in rows.enumerate() {
                            let f = sc[(first + i) % sc.len()];
                            for (d, &v) in d.iter_mut().zip(row) {
                                *d = f * v;
                            }
                        }
                        &scaled
                    }
                };
                if let Some(part) = gx_part.as_deref_mut() {
                    // dp [rows, output] times W^T [output, input] (w [input, output] read
                    // with swapped strides) into the block of x's gradient.
                    product(
                        [rows, input, output],
                        &mut part[local * input..(local + rows) * input],
                        [input, 1],
                        false,
                        dp,
                        [output, 1],
                        w,
                        [1, output],
                    );
                }
                if want.w {
                    // x^T [input, rows] (x's block read with swapped strides) times dp
                    // [rows, output], added to the group's sum [input, output].
                    product(
                        [input, output, rows],
                        &mut part.w,
                        [output, 1],
                        true,
                        &x[first * input..(first + rows) * input],
                        [1, input],
                        dp,
                        [output, 1],
                    );
                }
                if !part.add.is_empty() {
                    for (i, row) in dz.chunks_exact(output).enumerate() {
                        let a = s.add_row(add_len, first + i) * output;
                        for (d, &v) in part.add[a..a + output].iter_mut().zip(row) {
                            *d += v;
                        }
                    }
                }
            }
            part
        })
        .collect();
    let mut grads = DenseGrads::default();
    if want.x {
        grads.x = Some(gx);
    }
    if want.w {
        let mut gw = vec![0.0f32; input * output];
        for p in &partials {
            for (d, v) in gw.iter_mut().zip(&p.w) {
                *d += v;
            }
        }
        grads.w = Some(gw);
    }
    if want.add {
        if per_row {
            grads.add = Some(gadd);
        } else {
            let mut ga = vec![0.0f32; batch * output];
            for p in &partials {
                for (d, v) in ga.iter_mut().zip(&p.add) {
                    *d += v;
                }
            }
            grads.add = Some(ga);
        }
    }
    grads
}

/// The dense operation on the backend's tensors (see the module's documentation).
#[backend_extension(
    Flex: cfg(feature = "flex"),
    NdArray: cfg(feature = "ndarray"),
    Autodiff
)]
pub trait DenseOps: Backend {
    /// [`dense_forward`]: `x` `[rows, input]`, `w` `[input, output]`, `add` `[batch,
    /// output]` or `[rows, output]`, `scale` one value per row of a sample or none -> `[rows,
    /// output]`.
    fn train_dense(
        x: FloatTensor<Self>,
        w: FloatTensor<Self>,
        add: FloatTensor<Self>,
        batch: usize,
        slope: Option<f32>,
        scale: Option<Arc<Vec<f32>>>,
    ) -> FloatTensor<Self> {
        let [input, output] = [w.shape()[0], w.shape()[1]];
        let rows = x.shape()[0];
        let device = x.device();
        let y = with_floats::<Self, _>(&x, |x| {
            with_floats::<Self, _>(&w, |w| {
                with_floats::<Self, _>(&add, |a| {
                    dense_forward(
                        x,
                        w,
                        a,
                        [input, output, batch],
                        slope,
                        scale.as_deref().map(|v| &v[..]),
                    )
                })
            })
        });
        from_floats::<Self>(y, vec![rows, output], &device)
    }
}

#[cfg(feature = "flex")]
impl DenseOps for burn::backend::Flex {}
#[cfg(feature = "ndarray")]
impl DenseOps for burn::backend::NdArray {}

/// The backward step recorded for [`DenseOps::train_dense`] under autodiff.
#[derive(Debug)]
struct Dense;

/// What [`Dense`]'s backward step keeps: the input, the weight, the output (with an
/// activation), the addend's shape, the samples, the slope and the scale.
#[derive(Debug, Clone)]
struct DenseState<B: Backend> {
    x: FloatTensor<B>,
    w: FloatTensor<B>,
    y: Option<FloatTensor<B>>,
    add_shape: Vec<usize>,
    batch: usize,
    slope: Option<f32>,
    scale: Option<Arc<Vec<f32>>>,
}

impl<B: Backend + DenseOps> Backward<B, 3> for Dense {
    type State = DenseState<B>;

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let st = ops.state;
        let g = grads.consume::<B>(&ops.node);
        let [px, pw, pa] = ops.parents;
        let want = Wanted {
            x: px.is_some(),
            w: pw.is_some(),
            add: pa.is_some(),
        };
        let device = g.device();
        let [input, output] = [st.w.shape()[0], st.w.shape()[1]];
        let rows = st.x.shape()[0];
        let add_len: usize = st.add_shape.iter().product();
        let sizes = [input, output, st.batch];
        // A per-row addend without the activation: its gradient is g, passed on as it is.
        let pass_on = st.slope.is_none() && add_len == rows * output && rows != st.batch;
        if let (true, Some(node)) = (pass_on, &pa) {
            grads.register::<B>(node.id, g.clone());
        }
        let scale = st.scale.as_deref().map(|v| &v[..]);
        let d = with_floats::<B, _>(&st.x, |x| {
            with_floats::<B, _>(&st.w, |w| {
                with_floats::<B, _>(&g, |g| match &st.y {
                    Some(y) => with_floats::<B, _>(y, |y| {
                        dense_backward(x, w, y, g, add_len, sizes, st.slope, scale, want)
                    }),
                    None => dense_backward(x, w, &[], g, add_len, sizes, None, scale, want),
                })
            })
        });
        if let (Some(node), Some(v)) = (px, d.x) {
            grads.register::<B>(node.id, from_floats::<B>(v, vec![rows, input], &device));
        }
        if let (Some(node), Some(v)) = (pw, d.w) {
            grads.register::<B>(node.id, from_floats::<B>(v, vec![input, output], &device));
        }
        if let (Some(node), Some(v)) = (pa, d.add) {
            grads.register::<B>(node.id, from_floats::<B>(v, st.add_shape, &device));
        }
    }
}

impl<B: Backend + DenseOps, C: CheckpointStrategy> DenseOps for Autodiff<B, C> {
    fn train_dense(
        x: FloatTensor<Self>,
        w: FloatTensor<Self>,
        add: FloatTensor<Self>,
        batch: usize,
        slope: Option<f32>,
        scale: Option<Arc<Vec<f32>>>,
    ) -> FloatTensor<Self> {
        let (x, nx) = x.into_parts();
        let (w, nw) = w.into_parts();
        let (add, na) = add.into_parts();
        let add_shape = add.shape().to_vec();
        let y = B::train_dense(x.clone(), w.clone(), add, batch, slope, scale.clone());
        match Dense.prepare::<C>([nx, nw, na]).compute_bound().stateful() {
            OpsKind::Tracked(prep) => {
                let state = DenseState {
                    x,
                    w,
                    y: slope.map(|_| y.clone()),
                    add_shape,
                    batch,
                    slope,
                    scale,
                };
                prep.finish(state, y)
            }
            OpsKind::UnTracked(prep) => prep.finish(y),
        }
    }
}

/// `act(scale (x W) + add)` on high-level tensors: `x` `[.., input]` (all leading axes are
/// rows), `w` `[input, output]`, `add` `[batch, 1, output]` (one row per sample, the rows in
/// `batch` equal runs) or `[batch, rows / batch, output]`, `scale` a constant per row of a
/// sample (row `i` of `x` takes `scale[i % scale.len()]`) or none; the leaky ReLU of
/// `slope` when there is one.
pub fn dense<const D: usize>(
    x: Tensor<D>,
    w: Tensor<2>,
    add: Tensor<3>,
    slope: Option<f64>,
    scale: Option<&Arc<Vec<f32>>>,
) -> Tensor<D> {
    let dims = x.dims();
    let input = dims[D - 1];
    let rows: usize = dims[..D - 1].iter().product();
    let [batch, per, output] = add.dims();
    assert!(
        batch == 1 || (D > 1 && dims[0] == batch),
        "an addend of {batch} samples for x {dims:?}"
    );
    assert!(
        slope.is_none_or(|s| s >= 0.0),
        "a leaky ReLU's slope of 0 or more (its gradient is read from the output's sign)"
    );
    let add = add.reshape([batch * per, output]);
    let y = Tensor::<2>::from_dispatch(<Dispatch as DenseOps>::train_dense(
        x.reshape([rows, input]).into_dispatch(),
        w.into_dispatch(),
        add.into_dispatch(),
        batch,
        slope.map(|s| s as f32),
        scale.cloned(),
    ));
    let mut out = dims;
    out[D - 1] = output;
    y.reshape(out)
}

// On the default device, which is a GPU one in builds with a GPU backend.
#[cfg(all(test, not(any(feature = "cuda", feature = "wgpu"))))]
mod tests {
    use burn::tensor::activation::leaky_relu;
    use burn::tensor::{Device, Distribution, Tensor, TensorData};
    use std::sync::Arc;

    use super::{Wanted, dense, dense_backward, dense_forward};
    use crate::model::host::floats;
    use crate::model::trainops::tests::rel;

    /// A leaf on the autodiff device with normal random values.
    fn leaf<const D: usize>(dims: [usize; D], seed: u64) -> Tensor<D> {
        let plain = Device::default();
        plain.seed(seed);
        let data = Tensor::<D>::random(dims, Distribution::Normal(0.0, 1.0), &plain).into_data();
        Tensor::<D>::from_data(data, &plain.autodiff()).require_grad()
    }

    /// A copy of `t` as a new leaf.
    fn twin<const D: usize>(t: &Tensor<D>) -> Tensor<D> {
        Tensor::<D>::from_data(t.to_data(), &t.device()).require_grad()
    }

    /// The operation against burn's `x W + add` (and `leaky_relu`) on `[b, n, input]`, with
    /// a per-sample addend (`per` 1), a per-row one (`per` n) or one for all samples (`per`
    /// 0: `[1, 1, output]`, a bias), and with `scaled` the
    /// product times a constant per row of a sample first (`s (x W) + add`, as FeaStNet's
    /// `1 / |N_i|`): values and the gradients of x, W and the addend within 1e-5 of their
    /// largest.
    fn against_burn(
        b: usize,
        n: usize,
        input: usize,
        output: usize,
        per: usize,
        slope: Option<f64>,
        scaled: bool,
    ) {
        let seed = (b * 1000 + n + input * 7 + output * 13 + per) as u64;
        let (x, w, a) = (
            leaf([b, n, input], seed),
            leaf([input, output], seed + 1),
            if per == 0 {
                leaf([1, 1, output], seed + 2)
            } else {
                leaf([b, per, output], seed + 2)
            },
        );
        let (x2, w2, a2) = (twin(&x), twin(&w), twin(&a));
        // 1, 1/2, .. 1/7 over the rows of a sample, as the inverse degrees of a mesh.
        let scale = Arc::new((0..n).map(|i| 1.0 / (1 + i % 7) as f32).collect::<Vec<_>>());
        let got = dense(
            x.clone(),
            w.clone(),
            a.clone(),
            slope,
            scaled.then_some(&scale),
        );
        let mut z = x2.clone().matmul(w2.clone().unsqueeze::<3>());
        if scaled {
            let device = z.device();
            z = z * Tensor::<3>::from_data(TensorData::new(scale.to_vec(), [1, n, 1]), &device);
        }
        let z = z + a2.clone();
        let want = match slope {
            Some(s) => leaky_relu(z, s),
            None => z,
        };
        let what = format!(
            "[{b}, {n}, {input}] -> {output}, addend per {per}, {slope:?}, scaled {scaled}"
        );
        let err = rel(&floats(got.clone().inner()), &floats(want.clone().inner()));
        assert!(err < 1e-5, "values differ by {err}: {what}");
        let r = Tensor::<3>::random(got.dims(), Distribution::Normal(0.0, 1.0), &got.device());
        let g1 = (got * r.clone()).sum().backward();
        let g2 = (want * r).sum().backward();
        for (name, ga, gb) in [
            ("x", x.grad(&g1).map(floats), x2.grad(&g2).map(floats)),
            ("w", w.grad(&g1).map(floats), w2.grad(&g2).map(floats)),
            ("add", a.grad(&g1).map(floats), a2.grad(&g2).map(floats)),
        ] {
            let (ga, gb) = (ga.expect("a gradient"), gb.expect("a gradient"));
            assert!(
                gb.iter().any(|v| *v != 0.0),
                "the test reaches {name}'s gradient"
            );
            let err = rel(&ga, &gb);
            assert!(err < 1e-5, "{name}'s gradient differs by {err}: {what}");
        }
    }

    /// Shapes of the training step's layers: one sample and several, rows that fill several
    /// blocks and groups and end in a partial block, a single row per sample, per-sample and
    /// per-row addends, with and without the leaky ReLU, with and without a scale per row
    /// (the residual blocks' convolutions: several samples of rows over several blocks).
    #[test]
    fn dense_is_burns_linear_and_leaky_relu_with_their_gradients() {
        against_burn(1, 5, 3, 4, 1, Some(0.1), false);
        against_burn(4, 2967, 64, 48, 1, Some(0.1), false);
        against_burn(3, 1000, 70, 128, 1000, Some(0.2), false);
        against_burn(2, 700, 32, 3, 1, None, false);
        against_burn(2, 700, 48, 48, 700, None, false);
        against_burn(5, 1, 256, 64, 1, Some(0.1), false);
        against_burn(1, 5, 3, 4, 1, Some(0.1), true);
        against_burn(3, 1000, 264, 48, 1, Some(0.1), true);
        against_burn(2, 700, 48, 48, 700, None, true);
        against_burn(2, 700, 32, 16, 1, None, true);
        // The residual blocks' convolutions: a bias shared by four samples, the scale, the
        // activation; and a per-row addend with both.
        against_burn(4, 600, 48, 32, 0, Some(0.1), true);
        against_burn(2, 700, 24, 16, 700, Some(0.2), true);
    }

    /// Rows without batch axes (the spatial transformer's output layer), and inputs or
    /// addends that want no gradient (the network's inputs, a layer without a bias): the
    /// others' gradients as burn's, none for them.
    #[test]
    fn dense_on_rows_and_without_some_gradients() {
        let (x, w) = (leaf([6, 64], 41), leaf([64, 9], 42));
        let a = leaf([1, 1, 9], 43);
        let (x2, w2, a2) = (twin(&x), twin(&w), twin(&a));
        let got = dense(x.clone(), w.clone(), a.clone(), None, None);
        let want = x2.clone().matmul(w2.clone()) + a2.clone().reshape([1, 9]);
        let r = Tensor::<2>::random([6, 9], Distribution::Normal(0.0, 1.0), &got.device());
        let (g1, g2) = (
            (got.clone() * r.clone()).sum().backward(),
            (want.clone() * r).sum().backward(),
        );
        assert!(rel(&floats(got.inner()), &floats(want.inner())) < 1e-5);
        for (ga, gb) in [(x.grad(&g1), x2.grad(&g2)), (w.grad(&g1), w2.grad(&g2))] {
            assert!(rel(&floats(ga.unwrap()), &floats(gb.unwrap())) < 1e-5);
        }
        let (ga, gb) = (a.grad(&g1).unwrap(), a2.grad(&g2).unwrap());
        assert!(
            rel(&floats(ga), &floats(gb)) < 1e-5,
            "the addend's gradient"
        );
        // x and the addend as constants, with the activation: only W's gradient.
        let ad = Device::default().autodiff();
        let xc = Tensor::<3>::from_data(leaf([2, 300, 16], 44).to_data(), &ad);
        let ac = Tensor::<3>::zeros([1, 1, 8], &ad);
        let w = leaf([16, 8], 45);
        let w2 = twin(&w);
        let got = dense(xc.clone(), w.clone(), ac, Some(0.1), None);
        let want = leaky_relu(xc.clone().matmul(w2.clone().unsqueeze::<3>()), 0.1);
        let r = Tensor::<3>::random([2, 300, 8], Distribution::Normal(0.0, 1.0), &ad);
        let g1 = (got.clone() * r.clone()).sum().backward();
        let g2 = (want.clone() * r).sum().backward();
        assert!(rel(&floats(got.inner()), &floats(want.inner())) < 1e-5);
        let (gw, gw2) = (floats(w.grad(&g1).unwrap()), floats(w2.grad(&g2).unwrap()));
        assert!(gw2.iter().any(|v| *v != 0.0));
        assert!(rel(&gw, &gw2) < 1e-5, "W's gradient");
        assert!(xc.grad(&g1).is_none(), "no gradient for a constant input");
    }

    /// The gradient at an output of exactly 0 (or -0) is the slope's, as
    /// [`crate::model::trainops::leaky`]'s; the sums do not depend on the threads.
    #[test]
    fn dense_gradient_at_zero_is_the_slope_and_the_sums_repeat() {
        // x W + a = [0, 0, 2, -1] with w = 1 and a = 0 (-0 * 1 + 0 is +0).
        let x = [0.0f32, -0.0, 2.0, -1.0];
        let y = dense_forward(&x, &[1.0], &[0.0], [1, 1, 1], Some(0.5), None);
        assert_eq!(y, vec![0.0, 0.0, 2.0, -0.5]);
        let all = Wanted {
            x: true,
            w: true,
            add: true,
        };
        // The backward pass reads the output's sign: an output of -0 takes the slope too.
        for y in [y, vec![0.0, -0.0, 2.0, -0.5]] {
            let g = dense_backward(
                &x,
                &[1.0],
                &y,
                &[1.0; 4],
                1,
                [1, 1, 1],
                Some(0.5),
                None,
                all,
            );
            assert_eq!(g.x.unwrap(), vec![0.5, 0.5, 1.0, 0.5]);
            // dW = sum of x * dz = 0 * 0.5 + (-0) * 0.5 + 2 * 1 + (-1) * 0.5.
            assert_eq!(g.w.unwrap(), vec![1.5]);
            assert_eq!(g.add.unwrap(), vec![2.5]);
        }
        // Many rows on a pool of one thread and of four: the same bits.
        // With a scale per row of a sample too (two samples of 2,500 rows).
        let (rows, input, output) = (5000, 17, 9);
        let v = |n: usize, k: usize| -> Vec<f32> {
            (0..n)
                .map(|i| (((i * k) % 97) as f32 - 48.0) / 31.0)
                .collect()
        };
        let (x, w, a, g) = (
            v(rows * input, 7),
            v(input * output, 5),
            v(output, 3),
            v(rows * output, 11),
        );
        let scale: Vec<f32> = (0..rows / 2).map(|i| 1.0 / (1 + i % 5) as f32).collect();
        let run = |threads: usize, scale: Option<&[f32]>| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| {
                let y = dense_forward(&x, &w, &a, [input, output, 1], Some(0.1), scale);
                let sizes = [input, output, 1];
                let d = dense_backward(&x, &w, &y, &g, output, sizes, Some(0.1), scale, all);
                (y, d.x.unwrap(), d.w.unwrap(), d.add.unwrap())
            })
        };
        let bits = |r: (Vec<f32>, Vec<f32>, Vec<f32>, Vec<f32>)| {
            [r.0, r.1, r.2, r.3].map(|v| v.into_iter().map(f32::to_bits).collect::<Vec<_>>())
        };
        for scale in [None, Some(&scale[..])] {
            assert!(
                bits(run(1, scale)) == bits(run(4, scale)),
                "the same values and gradients on 1 and 4 threads (scaled: {})",
                scale.is_some()
            );
        }
    }
}
