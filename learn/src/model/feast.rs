//! FeaStNet's head-weighted neighbourhood sums as one operation with its own backward pass,
//! on the CPU backends.
//!
//! `z_i,m = sum_{j in N_i} q_m(i, j) x_j`, `q_m` = softmax over the M heads of
//! `u_m . x_j - u_m . x_i + c_m`, summed over the used slots of vertex i's padded
//! neighbourhood (the output map W, the 1 / |N_i| and the bias follow in
//! [`super::FeaStConv::forward`]).
//!
//! Written with burn's tensor operations this is a gather of `[B, N, K, C]` neighbour
//! features, a softmax over `[B, N, K, M]` and one `[M, K] x [K, C]` matrix product per vertex:
//! on burn-flex each of those B x N products (and the two per vertex in the backward pass) is
//! a separate `gemm` call whose fixed cost outweighs its 2,000 multiply-adds, 30% of a
//! GarNet-Local training step (docs/bench.md, "FeaStNet's aggregation as one operation").
//! Here forward and backward are loops over each vertex's neighbours in place, and the
//! backward pass recomputes q instead of keeping `[B, N, K, M]`.
//!
//! The operation is a burn backend extension ([`FeastOps`]): the CPU backends run the loops
//! on the tensors' data; under autodiff [`FeastOps for Autodiff`](FeastOps) records
//! [`feast_backward`] as the operation's backward. GPU builds keep the tensor formulation.

use std::sync::Arc;

use burn::backend::autodiff::Autodiff;
use burn::backend::autodiff::checkpoint::base::Checkpointer;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::autodiff::grads::Gradients;
use burn::backend::autodiff::ops::{Backward, Ops, OpsKind};
use burn::backend::tensor::FloatTensor;
use burn::backend::{Backend, Dispatch, TensorMetadata, backend_extension};
use burn::tensor::{Tensor, TensorData};
use pulp::{Arch, Simd, WithSimd};
use rayon::prelude::*;

/// Vertices per rayon task in the forward pass (each is a few thousand multiply-adds).
const VERTICES_PER_TASK: usize = 64;

/// A mesh's padded neighbourhoods on the host: slot `s` of vertex `i` at `i * k + s`.
#[derive(Debug, Clone, PartialEq)]
pub struct Slots {
    /// Vertices N.
    pub vertices: usize,
    /// Slots per vertex K.
    pub k: usize,
    /// Neighbour of each slot, `[N * K]` (padding slots name some vertex; their `used` is
    /// false).
    pub index: Vec<u32>,
    /// Whether each slot is a neighbour (true) or padding, `[N * K]`.
    pub used: Vec<bool>,
}

/// The sizes of one aggregation, `[B, N, C, M]` (batch, vertices, features, heads), from
/// `x`'s `[B, N, C]` and `ux`'s `[B, N, M]`, checked against each other and the mesh.
fn sizes(x: &[usize], ux: &[usize], slots: &Slots) -> [usize; 4] {
    assert_eq!(x.len(), 3, "x is [B, N, C]");
    assert_eq!(ux.len(), 3, "ux is [B, N, M]");
    assert_eq!(
        (x[0], x[1]),
        (ux[0], ux[1]),
        "x and ux disagree on batch or vertices"
    );
    assert_eq!(x[1], slots.vertices, "x's vertices are not the mesh's");
    [x[0], x[1], x[2], ux[2]]
}

/// q over the heads for one slot: softmax of `uj - ui + c`, into `q`.
#[inline]
fn weights(ui: &[f32], uj: &[f32], c: &[f32], q: &mut [f32]) {
    let mut top = f32::NEG_INFINITY;
    for h in 0..q.len() {
        q[h] = uj[h] - ui[h] + c[h];
        top = top.max(q[h]);
    }
    let mut sum = 0.0;
    for qh in q.iter_mut() {
        *qh = (*qh - top).exp();
        sum += *qh;
    }
    for qh in q.iter_mut() {
        *qh /= sum;
    }
}

/// The two factors of every vertex's head weights, `[B * N, 2 M]`: with `a_h = u_h . x`,
/// `P_h = exp(a_h - max a)` and `Q_h = exp(c_h - a_h - max(c - a))`. The softmax of slot
/// (i, j) over the heads is then `P_j,h Q_i,h / sum_h' P_j,h' Q_i,h'`: the same numbers as
/// exponentiating `u_h . x_j - u_h . x_i + c_h` per slot, with an exponential per vertex and
/// head instead of per used slot and head (about 2/7 of them on a triangle mesh, whose
/// slots are the vertex and its one-ring; docs/bench.md, "FeaStNet's head weights
/// factored").
pub(super) fn head_factors(ux: &[f32], c: &[f32], m: usize) -> Vec<f32> {
    let mut pq = vec![0.0f32; ux.len() * 2];
    pq.par_chunks_mut(VERTICES_PER_TASK * 4 * 2 * m)
        .zip(ux.par_chunks(VERTICES_PER_TASK * 4 * m))
        .for_each(|(o, a)| {
            // The exponents, all <= 0, then their exponentials in one vectorised pass.
            for (o, a) in o.chunks_exact_mut(2 * m).zip(a.chunks_exact(m)) {
                let (p, q) = o.split_at_mut(m);
                let top = a.iter().fold(f32::NEG_INFINITY, |t, &v| t.max(v));
                let top_q = a
                    .iter()
                    .zip(c)
                    .fold(f32::NEG_INFINITY, |t, (&v, &ch)| t.max(ch - v));
                for h in 0..m {
                    p[h] = a[h] - top;
                    q[h] = c[h] - a[h] - top_q;
                }
            }
            Arch::new().dispatch(|| {
                for v in o.iter_mut() {
                    *v = exp_nonpositive(*v);
                }
            });
        });
    pq
}

/// `exp(x)` for `x <= 0`, within 2.6e-7 relative of the exact value (3 units in the last
/// place), written so that a loop of it runs on vector lanes (the C library's `expf` is a
/// call per element): `x = n ln 2 + r` with `|r| <= ln 2 / 2`, `exp(r)` by its Taylor
/// polynomial to degree 6 (remainder below 1.6e-7 relative), times `2^n` built in the
/// exponent bits. Below -87 it returns `exp(-87)` (1.6e-38: a head weight that should be
/// smaller stays below 1.6e-8 of its slot's sum, and a slot whose heads all fall there
/// takes the exact per-slot formula, [`weights_factored`]); a NaN stays NaN. Not for
/// `x > 0` (checked in debug builds).
#[inline(always)]
pub(super) fn exp_nonpositive(x: f32) -> f32 {
    const LN2_HI: f32 = 0.693_359_4; // 355 / 512, 9 bits: n * LN2_HI is exact for |n| < 128
    const LN2_LO: f32 = -2.121_944_4e-4; // ln 2 - 355 / 512
    debug_assert!(x.is_nan() || x <= 0.0, "exp_nonpositive({x})");
    let x = if x < -87.0 { -87.0 } else { x };
    let n = (x * std::f32::consts::LOG2_E + 0.5).floor();
    let r = x - n * LN2_HI - n * LN2_LO;
    let p = 1.0
        + r * (1.0
            + r * (1.0 / 2.0
                + r * (1.0 / 6.0 + r * (1.0 / 24.0 + r * (1.0 / 120.0 + r * (1.0 / 720.0))))));
    p * f32::from_bits(((n as i32 + 127) as u32) << 23)
}

/// q over the heads for one slot from the factors of [`head_factors`] (`pj` of the
/// neighbour, `qi` of the vertex), into `q`. Where the products' sum falls below 1e-30
/// (logits spread over about 69 between the two ends' maxima, which trained networks do
/// not reach) it falls back to [`weights`].
#[inline(always)]
pub(super) fn weights_factored(
    pj: &[f32],
    qi: &[f32],
    (ui, uj, c): (&[f32], &[f32], &[f32]),
    scale: f32,
    q: &mut [f32],
) {
    let mut sum = 0.0;
    for ((o, &p), &f) in q.iter_mut().zip(pj).zip(qi) {
        *o = p * f;
        sum += *o;
    }
    if sum < 1e-30 || !sum.is_finite() {
        weights(ui, uj, c, q);
        for qh in q.iter_mut() {
            *qh *= scale;
        }
        return;
    }
    let inv = scale / sum;
    for qh in q.iter_mut() {
        *qh *= inv;
    }
}

/// One used slot's share of the backward pass, `m = q.len()` heads of `ch = xj.len()`
/// features: `g[h] = gz_h . xj` for each head's output gradient `gz_h` (row `h` of `gzi`,
/// `[M, C]`), and `gxj += sum_h q[h] gz_h`. For each group of [`HEADS_PER_SWEEP`] heads,
/// one sweep over the features loads each of their gradients' vectors once for both: the
/// dot products' sums stay in registers, and so does each vector of `gxj` while the group's
/// heads are added to it. Each element sees the same operations in the same order as
/// [`dot`] per head and then `gxj += q[h] gz_h` per head (the loop before session 70, which
/// loaded `gxj` and `gz_h` once per head and pass), so the bits are the same.
#[inline(always)]
fn slot_backward<S: Simd>(
    simd: S,
    gzi: &[f32],
    xj: &[f32],
    q: &[f32],
    gxj: &mut [f32],
    g: &mut [f32],
) {
    let (m, ch) = (q.len(), xj.len());
    debug_assert_eq!(gzi.len(), m * ch);
    for h0 in (0..m).step_by(HEADS_PER_SWEEP) {
        let count = (m - h0).min(HEADS_PER_SWEEP);
        let heads = &gzi[h0 * ch..(h0 + count) * ch];
        let (q, g) = (&q[h0..], &mut g[h0..]);
        match count {
            1 => slot_group::<S, 1>(simd, heads, xj, q, gxj, g),
            2 => slot_group::<S, 2>(simd, heads, xj, q, gxj, g),
            3 => slot_group::<S, 3>(simd, heads, xj, q, gxj, g),
            _ => slot_group::<S, HEADS_PER_SWEEP>(simd, heads, xj, q, gxj, g),
        }
    }
}

/// [`slot_backward`] for `H` heads: `gz` holds their `H` rows of `xj.len()` features, `q`
/// and `g` start at the first of them.
#[inline(always)]
fn slot_group<S: Simd, const H: usize>(
    simd: S,
    gz: &[f32],
    xj: &[f32],
    q: &[f32],
    gxj: &mut [f32],
    g: &mut [f32],
) {
    let ch = xj.len();
    let zero = simd.splat_f32s(0.0);
    let rows: [&[f32]; H] = std::array::from_fn(|h| &gz[h * ch..(h + 1) * ch]);
    let qv: [S::f32s; H] = std::array::from_fn(|h| simd.splat_f32s(q[h]));
    let mut dots = [zero; H];
    let (xh, xt) = S::as_simd_f32s(xj);
    let (gh, gt) = S::as_mut_simd_f32s(gxj);
    for (v, (o, &xv)) in gh.iter_mut().zip(xh).enumerate() {
        let mut acc = *o;
        for h in 0..H {
            let gv = S::as_simd_f32s(rows[h]).0[v];
            dots[h] = simd.mul_add_e_f32s(gv, xv, dots[h]);
            acc = simd.mul_add_e_f32s(qv[h], gv, acc);
        }
        *o = acc;
    }
    if !gt.is_empty() {
        let xv = simd.partial_load_f32s(xt);
        let mut acc = simd.partial_load_f32s(gt);
        for h in 0..H {
            let gv = simd.partial_load_f32s(S::as_simd_f32s(rows[h]).1);
            dots[h] = simd.mul_add_e_f32s(gv, xv, dots[h]);
            acc = simd.mul_add_e_f32s(qv[h], gv, acc);
        }
        simd.partial_store_f32s(gt, acc);
    }
    for h in 0..H {
        g[h] = simd.reduce_sum_f32s(dots[h]);
    }
}

/// `a . b`, in the widest SIMD the CPU offers (the tail shorter than a vector with a masked
/// load).
#[inline(always)]
pub(super) fn dot<S: Simd>(simd: S, a: &[f32], b: &[f32]) -> f32 {
    debug_assert_eq!(a.len(), b.len());
    let (ah, at) = S::as_simd_f32s(a);
    let (bh, bt) = S::as_simd_f32s(b);
    let mut acc = simd.splat_f32s(0.0);
    for (&u, &v) in ah.iter().zip(bh) {
        acc = simd.mul_add_e_f32s(u, v, acc);
    }
    if !at.is_empty() {
        let (u, v) = (simd.partial_load_f32s(at), simd.partial_load_f32s(bt));
        acc = simd.mul_add_e_f32s(u, v, acc);
    }
    simd.reduce_sum_f32s(acc)
}

/// The operands of both passes, on the host.
#[derive(Clone, Copy)]
struct Operands<'a> {
    x: &'a [f32],
    ux: &'a [f32],
    c: &'a [f32],
    /// [`head_factors`] of `ux` and `c`.
    pq: &'a [f32],
    slots: &'a Slots,
    /// `[B, N, C, M]`.
    sizes: [usize; 4],
}

/// Heads whose sums one sweep over a vertex's neighbours accumulates, each in a SIMD
/// register ([`ForwardRows`]); in the backward pass, heads whose dot products and
/// contributions to a neighbour's gradient one sweep over its features takes
/// ([`slot_backward`]).
pub(super) const HEADS_PER_SWEEP: usize = 4;

/// One rayon task of the forward pass: the output rows from `first` on, `z` holding
/// `z.len() / (M C)` of them. Run at a SIMD [`Level`], so the loops compile once per
/// SIMD level (AVX-512, AVX2, none) and the CPU's widest runs.
///
/// Per vertex, the head weights of its used slots first; then for each vector-wide column
/// block of the features and each group of [`HEADS_PER_SWEEP`] heads, one sweep over the
/// neighbours keeps the group's sums in registers and stores them once: a neighbour's block
/// is loaded once per group instead of each head's output read and written per neighbour
/// (docs/bench.md, "FeaStNet's aggregation in SIMD registers").
struct ForwardRows<'a> {
    first: usize,
    z: &'a mut [f32],
    ops: Operands<'a>,
}

impl WithSimd for ForwardRows<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let Operands {
            x,
            ux,
            c,
            pq,
            slots,
            sizes: [_, n, ch, m],
        } = self.ops;
        let k = slots.k;
        // Heads rounded up to whole sweeps; the padding heads' weights stay zero.
        let mp = m.div_ceil(HEADS_PER_SWEEP) * HEADS_PER_SWEEP;
        let mut neighbours: Vec<&[f32]> = Vec::with_capacity(k);
        let mut qs = vec![0.0f32; k * mp];
        for (r, zi) in self.z.chunks_exact_mut(m * ch).enumerate() {
            let row = self.first + r;
            let (s, i) = (row / n, row % n);
            let base = s * n;
            let ui = &ux[row * m..(row + 1) * m];
            let qi = &pq[row * 2 * m + m..(row + 1) * 2 * m];
            neighbours.clear();
            for slot in i * k..(i + 1) * k {
                if !slots.used[slot] {
                    continue;
                }
                let j = base + slots.index[slot] as usize;
                let uj = &ux[j * m..(j + 1) * m];
                let u = neighbours.len();
                let q = &mut qs[u * mp..u * mp + m];
                weights_factored(&pq[j * 2 * m..j * 2 * m + m], qi, (ui, uj, c), 1.0, q);
                neighbours.push(&x[j * ch..(j + 1) * ch]);
            }
            sweep(simd, &neighbours, &qs, mp, m, zi);
        }
    }
}

/// One vertex's head-weighted sums into `zi`, `[M, C]`: `zi[h] = sum_u qs[u mp + h]
/// neighbours[u]` over its used neighbours' features (`C` each). For each vector block of
/// the features and each group of [`HEADS_PER_SWEEP`] heads one sweep over the neighbours
/// keeps the group's sums in registers (`qs` holds `mp` weights per neighbour, `mp` the
/// heads rounded up to whole groups, the padding weights zero); the features past the last
/// whole vector with masked loads and stores. Every element of `zi` is written.
#[inline(always)]
pub(super) fn sweep<S: Simd>(
    simd: S,
    neighbours: &[&[f32]],
    qs: &[f32],
    mp: usize,
    m: usize,
    zi: &mut [f32],
) {
    let zero = simd.splat_f32s(0.0);
    let ch = zi.len() / m;
    let blocks = ch / S::F32_LANES;
    let tail = ch % S::F32_LANES;
    for g in 0..mp / HEADS_PER_SWEEP {
        let h0 = g * HEADS_PER_SWEEP;
        let heads = HEADS_PER_SWEEP.min(m - h0);
        for v in 0..blocks {
            let mut acc = [zero; HEADS_PER_SWEEP];
            for (u, xj) in neighbours.iter().enumerate() {
                let xv = S::as_simd_f32s(xj).0[v];
                let q = &qs[u * mp + h0..u * mp + h0 + HEADS_PER_SWEEP];
                for h in 0..HEADS_PER_SWEEP {
                    acc[h] = simd.mul_add_e_f32s(simd.splat_f32s(q[h]), xv, acc[h]);
                }
            }
            for h in 0..heads {
                let out = &mut zi[(h0 + h) * ch..(h0 + h + 1) * ch];
                S::as_mut_simd_f32s(out).0[v] = acc[h];
            }
        }
        if tail > 0 {
            let mut acc = [zero; HEADS_PER_SWEEP];
            for (u, xj) in neighbours.iter().enumerate() {
                let xv = simd.partial_load_f32s(S::as_simd_f32s(xj).1);
                let q = &qs[u * mp + h0..u * mp + h0 + HEADS_PER_SWEEP];
                for h in 0..HEADS_PER_SWEEP {
                    acc[h] = simd.mul_add_e_f32s(simd.splat_f32s(q[h]), xv, acc[h]);
                }
            }
            for h in 0..heads {
                let out = &mut zi[(h0 + h) * ch..(h0 + h + 1) * ch];
                simd.partial_store_f32s(S::as_mut_simd_f32s(out).1, acc[h]);
            }
        }
    }
}

/// A SIMD level to run the host kernels at: the CPU's widest, or one picked (tests).
#[derive(Debug, Clone, Copy)]
pub(crate) enum Level {
    Best,
    #[cfg(test)]
    Scalar,
    #[cfg(all(test, target_arch = "x86_64"))]
    Avx2(pulp::x86::V3),
    #[cfg(all(test, target_arch = "x86_64"))]
    Avx512(pulp::x86::V4),
}

impl Level {
    pub(crate) fn run<Op: WithSimd>(self, op: Op) -> Op::Output {
        match self {
            Level::Best => Arch::new().dispatch(op),
            #[cfg(test)]
            Level::Scalar => Simd::vectorize(pulp::Scalar::new(), op),
            #[cfg(all(test, target_arch = "x86_64"))]
            Level::Avx2(s) => Simd::vectorize(s, op),
            #[cfg(all(test, target_arch = "x86_64"))]
            Level::Avx512(s) => Simd::vectorize(s, op),
        }
    }

    /// Every level this CPU has, the scalar one first (tests).
    #[cfg(test)]
    pub(crate) fn all() -> Vec<Level> {
        let mut levels = vec![Level::Scalar, Level::Best];
        #[cfg(target_arch = "x86_64")]
        {
            levels.extend(pulp::x86::V3::try_new().map(Level::Avx2));
            levels.extend(pulp::x86::V4::try_new().map(Level::Avx512));
        }
        levels
    }
}

/// The forward pass on the host.
///
/// # Shapes
/// `x`: `[B, N, C]`, `ux`: `[B, N, M]`, `c`: `[M]` -> `[B, N, M * C]` (flattened).
pub fn feast_forward(
    x: &[f32],
    ux: &[f32],
    c: &[f32],
    slots: &Slots,
    sizes: [usize; 4],
) -> Vec<f32> {
    forward_with(Level::Best, x, ux, c, slots, sizes)
}

/// [`feast_forward`] at `level`.
fn forward_with(
    level: Level,
    x: &[f32],
    ux: &[f32],
    c: &[f32],
    slots: &Slots,
    [b, n, ch, m]: [usize; 4],
) -> Vec<f32> {
    let pq = head_factors(ux, c, m);
    let ops = Operands {
        x,
        ux,
        c,
        pq: &pq,
        slots,
        sizes: [b, n, ch, m],
    };
    let mut z = vec![0.0f32; b * n * m * ch];
    z.par_chunks_mut(VERTICES_PER_TASK * m * ch)
        .enumerate()
        .for_each(|(t, z)| {
            let first = t * VERTICES_PER_TASK;
            level.run(ForwardRows { first, z, ops });
        });
    z
}

/// The gradients of the forward pass's inputs from the output's gradient `gz`.
///
/// With `g_m = gz_i,m . x_j` per used slot, the softmax's backward gives
/// `dl_m = q_m (g_m - sum_h q_h g_h)` for the logit `u_m . x_j - u_m . x_i + c_m`, so
/// `d ux_j += dl`, `d ux_i -= dl`, `d c += dl`, and `d x_j += sum_m q_m gz_i,m`. The
/// contributions land on the neighbours j: the batch items run in parallel, each item's
/// vertices in turn.
///
/// # Shapes
/// As [`feast_forward`]; `gz`: `[B, N, M * C]` -> (`[B, N, C]`, `[B, N, M]`, `[M]`).
pub fn feast_backward(
    x: &[f32],
    ux: &[f32],
    c: &[f32],
    gz: &[f32],
    slots: &Slots,
    sizes: [usize; 4],
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    backward_with(Level::Best, x, ux, c, gz, slots, sizes)
}

/// [`feast_backward`] at `level`.
fn backward_with(
    level: Level,
    x: &[f32],
    ux: &[f32],
    c: &[f32],
    gz: &[f32],
    slots: &Slots,
    [b, n, ch, m]: [usize; 4],
) -> (Vec<f32>, Vec<f32>, Vec<f32>) {
    let pq = head_factors(ux, c, m);
    let ops = Operands {
        x,
        ux,
        c,
        pq: &pq,
        slots,
        sizes: [b, n, ch, m],
    };
    let mut gx = vec![0.0f32; b * n * ch];
    let mut gux = vec![0.0f32; b * n * m];
    let gc_parts: Vec<Vec<f32>> = gx
        .par_chunks_mut(n * ch)
        .zip(gux.par_chunks_mut(n * m))
        .enumerate()
        .map(|(item, (gx, gux))| {
            level.run(BackwardItem {
                item,
                gz,
                gx,
                gux,
                ops,
            })
        })
        .collect();
    let mut gc = vec![0.0f32; m];
    for part in gc_parts {
        for (o, v) in gc.iter_mut().zip(part) {
            *o += v;
        }
    }
    (gx, gux, gc)
}

/// One batch item's backward pass (see [`feast_backward`]), its vertices in turn; returns
/// the item's share of c's gradient. Run at a [`Level`] as [`ForwardRows`].
struct BackwardItem<'a> {
    item: usize,
    gz: &'a [f32],
    gx: &'a mut [f32],
    gux: &'a mut [f32],
    ops: Operands<'a>,
}

impl WithSimd for BackwardItem<'_> {
    type Output = Vec<f32>;

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) -> Vec<f32> {
        let Operands {
            x,
            ux,
            c,
            pq,
            slots,
            sizes: [_, n, ch, m],
        } = self.ops;
        let (s, k) = (self.item, slots.k);
        let (gxs, guxs) = (self.gx, self.gux);
        let xs = &x[s * n * ch..(s + 1) * n * ch];
        let uxs = &ux[s * n * m..(s + 1) * n * m];
        let gzs = &self.gz[s * n * m * ch..(s + 1) * n * m * ch];
        let pqs = &pq[s * n * 2 * m..(s + 1) * n * 2 * m];
        let mut gc = vec![0.0f32; m];
        let (mut q, mut g) = (vec![0.0f32; m], vec![0.0f32; m]);
        for i in 0..n {
            let ui = &uxs[i * m..(i + 1) * m];
            let qi = &pqs[i * 2 * m + m..(i + 1) * 2 * m];
            let gzi = &gzs[i * m * ch..(i + 1) * m * ch];
            for slot in i * k..(i + 1) * k {
                if !slots.used[slot] {
                    continue;
                }
                let j = slots.index[slot] as usize;
                let pj = &pqs[j * 2 * m..j * 2 * m + m];
                weights_factored(pj, qi, (ui, &uxs[j * m..(j + 1) * m], c), 1.0, &mut q);
                let xj = &xs[j * ch..(j + 1) * ch];
                let gxj = &mut gxs[j * ch..(j + 1) * ch];
                slot_backward(simd, gzi, xj, &q, gxj, &mut g);
                let mut total = 0.0;
                for h in 0..m {
                    total += q[h] * g[h];
                }
                for h in 0..m {
                    let dl = q[h] * (g[h] - total);
                    guxs[j * m + h] += dl;
                    guxs[i * m + h] -= dl;
                    gc[h] += dl;
                }
            }
        }
        gc
    }
}

/// Runs a backend future that is ready at once (the CPU backends' data reads).
fn ready<T>(f: impl Future<Output = T>) -> T {
    let mut f = std::pin::pin!(f);
    let mut cx = std::task::Context::from_waker(std::task::Waker::noop());
    match f.as_mut().poll(&mut cx) {
        std::task::Poll::Ready(v) => v,
        std::task::Poll::Pending => panic!("a CPU backend's tensor read was not ready"),
    }
}

pub(super) fn host_floats<B: Backend>(t: FloatTensor<B>) -> Vec<f32> {
    ready(B::float_into_data(t))
        .expect("reading a tensor on the CPU")
        .convert::<f32>()
        .try_into_vec::<f32>()
        .expect("f32 data")
}

pub(super) fn to_backend<B: Backend>(
    v: Vec<f32>,
    shape: Vec<usize>,
    device: &B::Device,
) -> FloatTensor<B> {
    B::float_from_data(TensorData::new(v, shape), device)
}

/// Runs `f` on a float tensor's values: on burn-flex in place when the tensor is contiguous,
/// elsewhere on a copy ([`host_floats`]). Reading through `TensorData` copies a tensor that
/// autodiff also keeps (twice on burn-flex: once out of the shared buffer, once more to
/// align it).
pub(super) fn with_floats<B: Backend, R>(t: &FloatTensor<B>, f: impl FnOnce(&[f32]) -> R) -> R {
    #[cfg(feature = "flex")]
    if let Some(flex) = (t as &dyn std::any::Any).downcast_ref::<burn_flex::FlexTensor>()
        && let Some(values) = flex.as_slice::<f32>()
    {
        return f(values);
    }
    f(&host_floats::<B>(t.clone()))
}

/// A float tensor of `shape` holding `v`: on burn-flex without a copy, elsewhere through
/// [`to_backend`].
pub(super) fn from_floats<B: Backend>(
    v: Vec<f32>,
    shape: Vec<usize>,
    device: &B::Device,
) -> FloatTensor<B> {
    #[cfg(feature = "flex")]
    if std::any::TypeId::of::<FloatTensor<B>>() == std::any::TypeId::of::<burn_flex::FlexTensor>() {
        let flex = burn_flex::FlexTensor::new(
            burn_std::Bytes::from_elems(v),
            burn_flex::Layout::contiguous(burn_std::Shape::from(shape)),
            burn::tensor::DType::F32,
        );
        let boxed: Box<dyn std::any::Any> = Box::new(flex);
        return *boxed
            .downcast::<FloatTensor<B>>()
            .expect("the types are equal");
    }
    to_backend::<B>(v, shape, device)
}

/// FeaStNet's aggregation as a backend operation (see the module's documentation).
#[backend_extension(
    Flex: cfg(feature = "flex"),
    NdArray: cfg(feature = "ndarray"),
    Autodiff
)]
pub trait FeastOps: Backend {
    /// [`feast_forward`] on the backend's tensors: `x` `[B, N, C]`, `ux` `[B, N, M]`, `c`
    /// `[M]` -> `[B, N, M * C]`.
    fn feast_aggregate(
        x: FloatTensor<Self>,
        ux: FloatTensor<Self>,
        c: FloatTensor<Self>,
        slots: Arc<Slots>,
    ) -> FloatTensor<Self> {
        let [b, n, ch, m] = sizes(&x.shape(), &ux.shape(), &slots);
        let device = x.device();
        let z = with_floats::<Self, _>(&x, |x| {
            with_floats::<Self, _>(&ux, |ux| {
                with_floats::<Self, _>(&c, |c| feast_forward(x, ux, c, &slots, [b, n, ch, m]))
            })
        });
        from_floats::<Self>(z, vec![b, n, m * ch], &device)
    }

    /// [`feast_backward`] on the backend's tensors: the gradients of `x`, `ux` and `c`.
    fn feast_aggregate_backward(
        x: FloatTensor<Self>,
        ux: FloatTensor<Self>,
        c: FloatTensor<Self>,
        gz: FloatTensor<Self>,
        slots: Arc<Slots>,
    ) -> (FloatTensor<Self>, FloatTensor<Self>, FloatTensor<Self>) {
        let [b, n, ch, m] = sizes(&x.shape(), &ux.shape(), &slots);
        let device = x.device();
        let (gx, gux, gc) = with_floats::<Self, _>(&x, |x| {
            with_floats::<Self, _>(&ux, |ux| {
                with_floats::<Self, _>(&c, |c| {
                    with_floats::<Self, _>(&gz, |gz| {
                        feast_backward(x, ux, c, gz, &slots, [b, n, ch, m])
                    })
                })
            })
        });
        (
            from_floats::<Self>(gx, vec![b, n, ch], &device),
            from_floats::<Self>(gux, vec![b, n, m], &device),
            from_floats::<Self>(gc, vec![m], &device),
        )
    }
}

#[cfg(feature = "flex")]
impl FeastOps for burn::backend::Flex {}
#[cfg(feature = "ndarray")]
impl FeastOps for burn::backend::NdArray {}

/// The backward step recorded for [`FeastOps::feast_aggregate`] under autodiff.
#[derive(Debug)]
struct Aggregate;

impl<B: Backend + FeastOps> Backward<B, 3> for Aggregate {
    /// The inputs (q is recomputed from them) and the neighbourhoods.
    type State = (FloatTensor<B>, FloatTensor<B>, FloatTensor<B>, Arc<Slots>);

    fn backward(self, ops: Ops<Self::State, 3>, grads: &mut Gradients, _: &mut Checkpointer) {
        let (x, ux, c, slots) = ops.state;
        let gz = grads.consume::<B>(&ops.node);
        let (gx, gux, gc) = B::feast_aggregate_backward(x, ux, c, gz, slots);
        let [px, pux, pc] = ops.parents;
        for (parent, grad) in [(px, gx), (pux, gux), (pc, gc)] {
            if let Some(node) = parent {
                grads.register::<B>(node.id, grad);
            }
        }
    }
}

impl<B: Backend + FeastOps, C: CheckpointStrategy> FeastOps for Autodiff<B, C> {
    fn feast_aggregate(
        x: FloatTensor<Self>,
        ux: FloatTensor<Self>,
        c: FloatTensor<Self>,
        slots: Arc<Slots>,
    ) -> FloatTensor<Self> {
        let (x, x_node) = x.into_parts();
        let (ux, ux_node) = ux.into_parts();
        let (c, c_node) = c.into_parts();
        let z = B::feast_aggregate(x.clone(), ux.clone(), c.clone(), slots.clone());
        match Aggregate
            .prepare::<C>([x_node, ux_node, c_node])
            .compute_bound()
            .stateful()
        {
            OpsKind::Tracked(prep) => prep.finish((x, ux, c, slots), z),
            OpsKind::UnTracked(prep) => prep.finish(z),
        }
    }
}

/// [`FeastOps::feast_aggregate`] on high-level tensors.
///
/// # Shapes
/// `x`: `[B, N, C]`, `ux`: `[B, N, M]`, `c`: `[M]` -> `[B, N, M * C]`.
pub fn aggregate(x: Tensor<3>, ux: Tensor<3>, c: Tensor<1>, slots: &Arc<Slots>) -> Tensor<3> {
    Tensor::from_dispatch(<Dispatch as FeastOps>::feast_aggregate(
        x.into_dispatch(),
        ux.into_dispatch(),
        c.into_dispatch(),
        slots.clone(),
    ))
}

#[cfg(test)]
mod tests {
    use burn::module::{Module, Param};
    use burn::tensor::{Device, Distribution, Tensor};

    use crate::model::{Aggregation, FeaStConv, Graph};
    use crate::topology::Topology;

    fn floats<const D: usize>(x: Tensor<D>) -> Vec<f32> {
        x.into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .unwrap()
    }

    /// Largest difference relative to the larger tensor's largest magnitude.
    fn rel(a: Vec<f32>, b: Vec<f32>) -> f32 {
        assert_eq!(a.len(), b.len());
        let scale = b.iter().fold(1e-12f32, |s, v| s.max(v.abs()));
        a.iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max)
            / scale
    }

    /// A 12 x 9 grid of vertices, two triangles per cell: boundary vertices have fewer
    /// neighbours, so some slots are padding.
    fn grid() -> Topology {
        let (w, h) = (12u32, 9u32);
        let mut tris = Vec::new();
        for y in 0..h - 1 {
            for x in 0..w - 1 {
                let v = y * w + x;
                tris.push([v, v + 1, v + w]);
                tris.push([v + 1, v + w + 1, v + w]);
            }
        }
        let topo = Topology::new((w * h) as usize, &tris);
        assert!(topo.padded_mask.contains(&0.0), "some slots are padding");
        topo
    }

    /// The factored head weights of the forward and backward passes are the per-slot
    /// softmax: on ordinary logits, and where the factors' products underflow (logits of
    /// one vertex spread over 200) and the per-slot formula takes over. The reference
    /// aggregates with [`super::weights`] slot by slot.
    #[test]
    fn factored_head_weights_are_the_per_slot_softmax() {
        use super::{Slots, feast_backward, feast_forward, weights};
        let topo = grid();
        let (n, k, ch, m) = (topo.vertices, topo.slots, 3, 4);
        let slots = Slots {
            vertices: n,
            k,
            index: topo.padded.iter().map(|&j| j as u32).collect(),
            used: topo.padded_mask.iter().map(|&u| u > 0.5).collect(),
        };
        let x: Vec<f32> = (0..n * ch)
            .map(|i| ((i * 37 % 101) as f32 / 50.0) - 1.0)
            .collect();
        let c = [0.1f32, -0.2, 0.05, 0.3];
        for spread in [1.0f32, 200.0] {
            // Vertex i's logits alternate between +spread and -spread by head and parity,
            // so that neighbours' maxima sit on other heads.
            let ux: Vec<f32> = (0..n * m)
                .map(|e| {
                    let (i, h) = (e / m, e % m);
                    let sign = if (i + h) % 2 == 0 { 1.0 } else { -1.0 };
                    sign * spread * (0.5 + (e % 7) as f32 / 14.0)
                })
                .collect();
            let z = feast_forward(&x, &ux, &c, &slots, [1, n, ch, m]);
            let mut want = vec![0.0f32; n * m * ch];
            let mut q = vec![0.0f32; m];
            for i in 0..n {
                for slot in i * k..(i + 1) * k {
                    if !slots.used[slot] {
                        continue;
                    }
                    let j = slots.index[slot] as usize;
                    weights(&ux[i * m..(i + 1) * m], &ux[j * m..(j + 1) * m], &c, &mut q);
                    for h in 0..m {
                        for f in 0..ch {
                            want[(i * m + h) * ch + f] += q[h] * x[j * ch + f];
                        }
                    }
                }
            }
            assert!(z.iter().all(|v| v.is_finite()), "spread {spread}");
            let err = rel(z, want);
            assert!(err < 1e-5, "spread {spread}: forward differs by {err}");
            // The backward pass's weights: finite gradients that agree with the forward
            // pass's through a finite difference in x.
            let gz: Vec<f32> = (0..n * m * ch)
                .map(|e| ((e * 13 % 17) as f32 - 8.0) / 8.0)
                .collect();
            let (gx, gux, gc) = feast_backward(&x, &ux, &c, &gz, &slots, [1, n, ch, m]);
            assert!(gx.iter().chain(&gux).chain(&gc).all(|v| v.is_finite()));
            let loss = |x: &[f32]| -> f64 {
                feast_forward(x, &ux, &c, &slots, [1, n, ch, m])
                    .iter()
                    .zip(&gz)
                    .map(|(a, b)| (*a as f64) * (*b as f64))
                    .sum()
            };
            let (e, eps) = (5 * ch + 1, 1e-2f32);
            let (mut up, mut down) = (x.clone(), x.clone());
            up[e] += eps;
            down[e] -= eps;
            let numeric = (loss(&up) - loss(&down)) / (2.0 * eps as f64);
            assert!(
                (numeric - gx[e] as f64).abs() < 1e-3 * (1.0 + numeric.abs()),
                "spread {spread}: d/dx {numeric} against {}",
                gx[e]
            );
        }
    }

    /// The fused operation against burn's tensor formulation, on the autodiff device: the
    /// convolution's output, and the gradients of its input and of all its parameters
    /// (u and c are reached only through the aggregation's backward).
    #[test]
    fn fused_aggregation_and_its_backward_are_the_tensor_formulation() {
        let ad = Device::default().autodiff();
        ad.seed(5);
        let topo = grid();
        let (c, o, heads, b) = (19, 16, 4, 2);
        let mut conv = FeaStConv::new(c, o, heads, false, &ad);
        // Larger head biases than the initialisation's, so the softmax is far from uniform.
        let c_big = conv.c.val().inner() * 20.0;
        conv.c = Param::from_tensor(Tensor::from_inner(c_big).require_grad());
        let n = topo.vertices;
        let g = Graph::new(&topo, &ad);
        let rows = Aggregation::Tensors(g.rows(b, &ad));
        let x = Tensor::<3>::random([b, n, c], Distribution::Normal(0.0, 1.0), &ad).require_grad();
        let w = Tensor::<3>::random([b, n, o], Distribution::Normal(0.0, 1.0), &ad);

        let fused = conv.forward(x.clone(), &g, &Aggregation::Fused);
        let tensors = conv.forward(x.clone(), &g, &rows);
        assert_eq!(fused.dims(), [b, n, o]);
        let err = rel(
            floats(fused.clone().inner()),
            floats(tensors.clone().inner()),
        );
        assert!(err < 1e-5, "outputs differ by {err}");

        let g_fused = (fused * w.clone()).sum().backward();
        let g_tensors = (tensors * w).sum().backward();
        let grad = |t: Option<Vec<f32>>, name: &str| t.unwrap_or_else(|| panic!("{name}"));
        let pairs = [
            (
                "x",
                x.grad(&g_fused).map(floats),
                x.grad(&g_tensors).map(floats),
            ),
            (
                "u",
                conv.u.weight.grad(&g_fused).map(floats),
                conv.u.weight.grad(&g_tensors).map(floats),
            ),
            (
                "c",
                conv.c.grad(&g_fused).map(floats),
                conv.c.grad(&g_tensors).map(floats),
            ),
            (
                "W",
                conv.lin.weight.grad(&g_fused).map(floats),
                conv.lin.weight.grad(&g_tensors).map(floats),
            ),
        ];
        for (name, a, b) in pairs {
            let err = rel(grad(a, name), grad(b, name));
            assert!(err < 1e-4, "{name}'s gradients differ by {err}");
        }
    }

    /// The forward and backward passes at each SIMD level this CPU has (none, AVX2,
    /// AVX-512) against the per-slot formula written out, for feature widths with and
    /// without a part-vector tail, narrower than a vector, and head counts that do and do
    /// not fill whole sweeps of [`super::HEADS_PER_SWEEP`].
    #[test]
    fn every_simd_level_gives_the_per_slot_sums_and_their_gradients() {
        use super::{Level, Slots, backward_with, forward_with, weights};
        use rand::{Rng, SeedableRng};

        let topo = grid();
        let g = Graph::new(&topo, &Device::default());
        let slots: &Slots = &g.host_slots;
        let (n, k) = (slots.vertices, slots.k);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut levels = 0;
        for (ch, m) in [(19, 4), (51, 4), (32, 8), (5, 3), (131, 6), (16, 1)] {
            let b = 2;
            let mut draw = |len: usize| -> Vec<f32> {
                (0..len).map(|_| rng.random_range(-1.5f32..1.5)).collect()
            };
            let (x, ux, c, gz) = (
                draw(b * n * ch),
                draw(b * n * m),
                draw(m),
                draw(b * n * m * ch),
            );
            // The formula, slot by slot: z and, for the loss sum(gz * z), its gradients.
            let mut z = vec![0.0f64; b * n * m * ch];
            let mut gx = vec![0.0f64; b * n * ch];
            let mut gux = vec![0.0f64; b * n * m];
            let mut q = vec![0.0f32; m];
            for s in 0..b {
                for i in 0..n {
                    let row = s * n + i;
                    for slot in i * k..(i + 1) * k {
                        if !slots.used[slot] {
                            continue;
                        }
                        let j = s * n + slots.index[slot] as usize;
                        weights(&ux[row * m..][..m], &ux[j * m..][..m], &c, &mut q);
                        let mut g = vec![0.0f64; m];
                        for h in 0..m {
                            for e in 0..ch {
                                let (xv, gv) =
                                    (x[j * ch + e] as f64, gz[(row * m + h) * ch + e] as f64);
                                z[(row * m + h) * ch + e] += q[h] as f64 * xv;
                                gx[j * ch + e] += q[h] as f64 * gv;
                                g[h] += gv * xv;
                            }
                        }
                        let total: f64 = (0..m).map(|h| q[h] as f64 * g[h]).sum();
                        for h in 0..m {
                            let dl = q[h] as f64 * (g[h] - total);
                            gux[j * m + h] += dl;
                            gux[row * m + h] -= dl;
                        }
                    }
                }
            }
            let close = |what: &str, got: &[f32], want: &[f64]| {
                let scale = want.iter().fold(1e-12f64, |s, v| s.max(v.abs()));
                let err = got
                    .iter()
                    .zip(want)
                    .map(|(a, b)| (*a as f64 - b).abs())
                    .fold(0.0, f64::max);
                assert!(
                    err / scale < 1e-5,
                    "C {ch}, M {m}, {what}: off by {err} of {scale}"
                );
            };
            let sizes = [b, n, ch, m];
            let mut check =
                |forward: &dyn Fn() -> Vec<f32>,
                 backward: &dyn Fn() -> (Vec<f32>, Vec<f32>, Vec<f32>)| {
                    close("z", &forward(), &z);
                    let (bx, bux, _) = backward();
                    close("d x", &bx, &gx);
                    close("d ux", &bux, &gux);
                    levels += 1;
                };
            for level in Level::all() {
                check(&|| forward_with(level, &x, &ux, &c, slots, sizes), &|| {
                    backward_with(level, &x, &ux, &c, &gz, slots, sizes)
                });
            }
        }
        assert!(
            levels >= 6,
            "at least the scalar level for every size: {levels}"
        );
    }

    /// The vectorisable exponential is within 2.6e-7 relative of the exact value over the
    /// range the head factors take (the largest found by sampling 2e7 points is 2.53e-7),
    /// clamps below -87 and keeps NaN.
    #[test]
    fn vectorised_exponential_is_the_librarys() {
        use super::exp_nonpositive;
        let mut worst = 0.0f64;
        let mut x = 0.0f32;
        while x > -87.0 {
            let (got, want) = (exp_nonpositive(x) as f64, (x as f64).exp());
            worst = worst.max(((got - want) / want).abs());
            x -= 0.000_731;
        }
        assert!(worst < 2.6e-7, "largest relative error {worst}");
        assert_eq!(exp_nonpositive(0.0), 1.0);
        assert_eq!(exp_nonpositive(-200.0), exp_nonpositive(-87.0));
        assert!(exp_nonpositive(-87.0) < 2e-38 && exp_nonpositive(-87.0) > 0.0);
        assert!(exp_nonpositive(f32::NAN).is_nan());
    }

    /// Off the autodiff device the same operation gives the autodiff device's values.
    #[test]
    fn fused_aggregation_without_autodiff_is_the_tensor_formulation() {
        let ad = Device::default().autodiff();
        ad.seed(7);
        let topo = grid();
        let (c, o, heads, b) = (19, 16, 4, 2);
        let conv = FeaStConv::new(c, o, heads, false, &ad);
        let n = topo.vertices;
        let x = Tensor::<3>::random([b, n, c], Distribution::Normal(0.0, 1.0), &ad);
        let g_ad = Graph::new(&topo, &ad);
        let rows = Aggregation::Tensors(g_ad.rows(b, &ad));
        let want = conv.forward(x.clone(), &g_ad, &rows);

        let plain = ad.clone().inner();
        let (conv, x) = (conv.valid(), x.inner());
        let g = Graph::new(&topo, &plain);
        let got = conv.forward(x, &g, &Aggregation::Fused);
        let err = rel(floats(got), floats(want.inner()));
        assert!(err < 1e-5, "largest difference {err}");
    }
}
