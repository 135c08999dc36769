//! The garment stream's residual FeaStNet blocks at inference, fused on the host.
//!
//! Through burn's operations one block is a concatenation (`[h, xyz]`), the head logits'
//! matrix product, the aggregation ([`super::feast`]) writing `[B, N, M (C + 3)]` sums, the
//! output map's matrix product reading them back, and four element-wise passes (1 / |N_i|,
//! bias, activation, residual sum), each allocating its output. Here a block is two passes
//! over the vertices: the head logits and their factors, then per tile of
//! [`VERTICES_PER_TASK`] vertices the head-weighted sums into a scratch tile that stays in
//! cache, its product with the output map in SIMD registers, and the bias, layer
//! normalisation, activation and residual sum on each output row as it is made
//! (docs/bench.md, "The residual blocks fused").
//!
//! Only where no gradient is wanted ([`super::host::host`]): training takes burn's
//! operations, and a test checks this path against them, with and without layer
//! normalisation.

use pulp::{Simd, WithSimd};
use rayon::prelude::*;

use super::feast::{HEADS_PER_SWEEP, Level, Slots, dot, head_factors, sweep, weights_factored};

/// Vertices per rayon task: the scratch tile of their sums, `64 x M (C + 3)` floats (52 KB
/// at the CPU widths), stays in the core's cache.
const VERTICES_PER_TASK: usize = 64;

/// Rows of the tile product computed together, each in [`COLUMN_VECTORS`] registers.
const ROWS_TOGETHER: usize = 4;

/// Output vectors per row computed together: 4 x 3 accumulators and 3 weight vectors fit
/// AVX2's 16 registers as well as AVX-512's 32.
const COLUMN_VECTORS: usize = 3;

/// One block's parameters on the host.
#[derive(Debug, Clone)]
pub struct HostBlock {
    /// The head logits' map u, `[C_in, M]` (burn's `[input, output]` layout).
    pub u: Vec<f32>,
    /// The head offsets c, `[M]`.
    pub c: Vec<f32>,
    /// The output map W, `[M C_in, O]`, rows ordered head-major as the sums.
    pub w: Vec<f32>,
    /// The output bias b, `[O]`.
    pub bias: Vec<f32>,
    /// Layer normalisation of the output: gamma `[O]`, beta `[O]` (zeros when it has
    /// none) and epsilon.
    pub norm: Option<(Vec<f32>, Vec<f32>, f32)>,
}

/// The residual stack's sizes and constants.
#[derive(Debug, Clone, Copy)]
pub struct StackShape {
    /// Batch B.
    pub batch: usize,
    /// Vertices N.
    pub vertices: usize,
    /// Feature width O (the block's input is O + 3 wide: the features and xyz).
    pub width: usize,
    /// Heads M.
    pub heads: usize,
    /// The leaky ReLU's slope.
    pub slope: f32,
}

/// `h` through the residual blocks: for each block,
/// `h <- h + leaky(norm(W z / |N_i| + b))` with `z` the head-weighted sums of `[h, xyz]`
/// ([`super::FeaStConv::forward`], [`super::ConvStack`]).
///
/// # Shapes
/// `h`: `[B, N, O]`, `xyz`: `[B, N, 3]`, `inv_degree`: `[N]` -> `[B, N, O]`.
pub fn residual_stack(
    h: &[f32],
    xyz: &[f32],
    blocks: &[HostBlock],
    slots: &Slots,
    inv_degree: &[f32],
    shape: StackShape,
) -> Vec<f32> {
    stack_at(Level::Best, h, xyz, blocks, slots, inv_degree, shape)
}

/// [`residual_stack`] at `level`.
fn stack_at(
    level: Level,
    h: &[f32],
    xyz: &[f32],
    blocks: &[HostBlock],
    slots: &Slots,
    inv_degree: &[f32],
    shape: StackShape,
) -> Vec<f32> {
    let StackShape {
        batch,
        vertices: n,
        width,
        heads: m,
        ..
    } = shape;
    let ci = width + 3;
    let rows = batch * n;
    assert_eq!(h.len(), rows * width, "h is [B, N, O]");
    assert_eq!(xyz.len(), rows * 3, "xyz is [B, N, 3]");
    assert_eq!(inv_degree.len(), n, "one 1 / |N_i| per vertex");
    assert_eq!(slots.vertices, n, "the mesh's vertices");
    // [h, xyz] per row, and a second buffer for the next block's.
    let mut x = vec![0.0f32; rows * ci];
    for ((row, hr), p) in x
        .chunks_exact_mut(ci)
        .zip(h.chunks_exact(width))
        .zip(xyz.chunks_exact(3))
    {
        row[..width].copy_from_slice(hr);
        row[width..].copy_from_slice(p);
    }
    let mut next = x.clone();
    for block in blocks {
        assert_eq!(block.u.len(), ci * m, "u is [C_in, M]");
        assert_eq!(block.c.len(), m, "c is [M]");
        assert_eq!(block.w.len(), m * ci * width, "W is [M C_in, O]");
        assert_eq!(block.bias.len(), width, "b is [O]");
        if let Some((gamma, beta, _)) = &block.norm {
            assert!(
                gamma.len() == width && beta.len() == width,
                "the norm is [O]"
            );
        }
        // The head logits u . x (u's columns as rows), then their factors.
        let ut: Vec<f32> = (0..m)
            .flat_map(|h| (0..ci).map(move |e| block.u[e * m + h]))
            .collect();
        let mut ux = vec![0.0f32; rows * m];
        ux.par_chunks_mut(VERTICES_PER_TASK * m)
            .zip(x.par_chunks(VERTICES_PER_TASK * ci))
            .for_each(|(o, xs)| level.run(Logits { o, xs, ut: &ut, ci }));
        let pq = head_factors(&ux, &block.c, m);
        let (x_in, ux, pq) = (&x, &ux, &pq);
        next.par_chunks_mut(VERTICES_PER_TASK * ci)
            .enumerate()
            .for_each_init(Scratch::default, |scratch, (t, out)| {
                level.run(BlockRows {
                    first: t * VERTICES_PER_TASK,
                    out,
                    scratch,
                    x: x_in,
                    ux,
                    pq,
                    block,
                    slots,
                    inv_degree,
                    shape,
                })
            });
        std::mem::swap(&mut x, &mut next);
    }
    let mut out = Vec::with_capacity(rows * width);
    for row in x.chunks_exact(ci) {
        out.extend_from_slice(&row[..width]);
    }
    out
}

/// The head logits of a task's rows: `o[r, h] = xs[r] . ut[h]`, `ut` `[M, C_in]`. Run
/// at a SIMD [`Level`] as [`BlockRows`].
struct Logits<'a> {
    o: &'a mut [f32],
    xs: &'a [f32],
    ut: &'a [f32],
    ci: usize,
}

impl WithSimd for Logits<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let m = self.ut.len() / self.ci;
        for (oh, xr) in self
            .o
            .chunks_exact_mut(m)
            .zip(self.xs.chunks_exact(self.ci))
        {
            for (v, uh) in oh.iter_mut().zip(self.ut.chunks_exact(self.ci)) {
                *v = dot(simd, xr, uh);
            }
        }
    }
}

/// A worker's buffers for [`BlockRows`], reused across its tasks.
#[derive(Debug, Default)]
struct Scratch {
    /// Head weights of a vertex's used slots, `[K, M rounded up to sweeps]`.
    qs: Vec<f32>,
    /// The tile's head-weighted sums, `[tile, M C_in]`.
    z: Vec<f32>,
    /// The tile's outputs, `[tile, O]`.
    y: Vec<f32>,
}

/// `v` at least `len` long.
fn grow(v: &mut Vec<f32>, len: usize) {
    if v.len() < len {
        v.resize(len, 0.0);
    }
}

/// One task of a block: output rows `first..` (each `[h', xyz]`, `out` holding
/// `out.len() / (O + 3)` of them). Run at a SIMD [`Level`]: the loops compile once per
/// level, and outside tests the CPU's widest runs.
struct BlockRows<'a> {
    first: usize,
    out: &'a mut [f32],
    scratch: &'a mut Scratch,
    x: &'a [f32],
    ux: &'a [f32],
    pq: &'a [f32],
    block: &'a HostBlock,
    slots: &'a Slots,
    inv_degree: &'a [f32],
    shape: StackShape,
}

impl WithSimd for BlockRows<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let StackShape {
            vertices: n,
            width,
            heads: m,
            slope,
            ..
        } = self.shape;
        let (x, ux, pq, slots, block) = (self.x, self.ux, self.pq, self.slots, self.block);
        let ci = width + 3;
        let kdim = m * ci;
        let tile = self.out.len() / ci;
        let k = slots.k;
        let mp = m.div_ceil(HEADS_PER_SWEEP) * HEADS_PER_SWEEP;
        let mut neighbours: Vec<&[f32]> = Vec::with_capacity(k);
        let Scratch { qs, z, y } = self.scratch;
        // Grown once per worker; the sums and products are not cleared, as they write
        // every element read back; the weights are, so that the padding heads' are zero.
        grow(qs, k * mp);
        grow(z, tile * kdim);
        grow(y, tile * width);
        qs.fill(0.0);
        let (z, y) = (&mut z[..tile * kdim], &mut y[..tile * width]);
        // The head-weighted sums of the tile's vertices, divided by |N_i|.
        for (r, zi) in z.chunks_exact_mut(kdim).enumerate() {
            let row = self.first + r;
            let (s, i) = (row / n, row % n);
            let ui = &ux[row * m..(row + 1) * m];
            let qi = &pq[row * 2 * m + m..(row + 1) * 2 * m];
            let scale = self.inv_degree[i];
            neighbours.clear();
            for slot in i * k..(i + 1) * k {
                if !slots.used[slot] {
                    continue;
                }
                let j = s * n + slots.index[slot] as usize;
                let u = neighbours.len();
                let q = &mut qs[u * mp..u * mp + m];
                weights_factored(
                    &pq[j * 2 * m..j * 2 * m + m],
                    qi,
                    (ui, &ux[j * m..(j + 1) * m], &block.c),
                    scale,
                    q,
                );
                neighbours.push(&x[j * ci..(j + 1) * ci]);
            }
            sweep(simd, &neighbours, qs, mp, m, zi);
        }
        // The tile's outputs W z, then bias, normalisation, activation and residual.
        tile_product(simd, z, kdim, &block.w, width, y);
        for (r, (o, yr)) in self
            .out
            .chunks_exact_mut(ci)
            .zip(y.chunks_exact_mut(width))
            .enumerate()
        {
            let xr = &x[(self.first + r) * ci..(self.first + r + 1) * ci];
            for (v, &b) in yr.iter_mut().zip(&block.bias) {
                *v += b;
            }
            if let Some((gamma, beta, eps)) = &block.norm {
                layer_norm_row(yr, gamma, beta, *eps);
            }
            for ((o, &v), &h) in o[..width].iter_mut().zip(yr.iter()).zip(&xr[..width]) {
                *o = h + if v >= 0.0 { v } else { v * slope };
            }
            o[width..].copy_from_slice(&xr[width..]);
        }
    }
}

/// `y = z w` for a tile: `z` `[R, K]`, `w` `[K, O]`, `y` `[R, O]`, every element of `y`
/// written (it may hold anything before).
/// Blocks of [`ROWS_TOGETHER`] rows and [`COLUMN_VECTORS`] output vectors accumulate in
/// registers over K; the rows and vectors left over take smaller blocks, and the columns
/// past the last whole vector a scalar loop.
#[inline(always)]
fn tile_product<S: Simd>(simd: S, z: &[f32], kdim: usize, w: &[f32], o: usize, y: &mut [f32]) {
    let rows = z.len() / kdim;
    let vectors = o / S::F32_LANES;
    let mut r0 = 0;
    while r0 < rows {
        let rr = if rows - r0 >= ROWS_TOGETHER {
            ROWS_TOGETHER
        } else {
            1
        };
        let mut v0 = 0;
        while v0 < vectors {
            let nv = COLUMN_VECTORS.min(vectors - v0);
            match (rr, nv) {
                (ROWS_TOGETHER, COLUMN_VECTORS) => {
                    block_product::<S, ROWS_TOGETHER, COLUMN_VECTORS>(
                        simd, z, kdim, w, o, y, r0, v0,
                    )
                }
                (ROWS_TOGETHER, 2) => {
                    block_product::<S, ROWS_TOGETHER, 2>(simd, z, kdim, w, o, y, r0, v0)
                }
                (ROWS_TOGETHER, _) => {
                    block_product::<S, ROWS_TOGETHER, 1>(simd, z, kdim, w, o, y, r0, v0)
                }
                (_, COLUMN_VECTORS) => {
                    block_product::<S, 1, COLUMN_VECTORS>(simd, z, kdim, w, o, y, r0, v0)
                }
                (_, 2) => block_product::<S, 1, 2>(simd, z, kdim, w, o, y, r0, v0),
                _ => block_product::<S, 1, 1>(simd, z, kdim, w, o, y, r0, v0),
            }
            v0 += nv;
        }
        // Columns past the last whole vector.
        for r in r0..r0 + rr {
            let zr = &z[r * kdim..(r + 1) * kdim];
            for col in vectors * S::F32_LANES..o {
                y[r * o + col] = zr
                    .iter()
                    .enumerate()
                    .map(|(kk, &a)| a * w[kk * o + col])
                    .sum();
            }
        }
        r0 += rr;
    }
}

/// Rows `r0..r0 + R` and output vectors `v0..v0 + V` of [`tile_product`], in `R x V`
/// registers.
#[inline(always)]
fn block_product<S: Simd, const R: usize, const V: usize>(
    simd: S,
    z: &[f32],
    kdim: usize,
    w: &[f32],
    o: usize,
    y: &mut [f32],
    r0: usize,
    v0: usize,
) {
    let zero = simd.splat_f32s(0.0);
    let mut acc = [[zero; V]; R];
    let zs: [&[f32]; R] = std::array::from_fn(|r| &z[(r0 + r) * kdim..(r0 + r + 1) * kdim]);
    for kk in 0..kdim {
        let wv = &S::as_simd_f32s(&w[kk * o..(kk + 1) * o]).0[v0..v0 + V];
        for r in 0..R {
            let a = simd.splat_f32s(zs[r][kk]);
            for v in 0..V {
                acc[r][v] = simd.mul_add_e_f32s(a, wv[v], acc[r][v]);
            }
        }
    }
    for r in 0..R {
        let out = &mut S::as_mut_simd_f32s(&mut y[(r0 + r) * o..(r0 + r + 1) * o]).0[v0..v0 + V];
        out.copy_from_slice(&acc[r]);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};

    /// Every SIMD level this CPU has gives the scalar level's stack, for widths whose
    /// outputs fill whole vector blocks, leave a part vector, or fill none, head counts in
    /// and out of whole sweeps, with and without layer normalisation, and a vertex count
    /// whose last tile is not a whole number of row blocks.
    #[test]
    fn every_simd_level_gives_the_scalar_stack() {
        // A strip of 2 x 49 vertices, two triangles per cell.
        let w = 49u32;
        let tris: Vec<[u32; 3]> = (0..w - 1)
            .flat_map(|x| [[x, x + 1, x + w], [x + 1, x + w + 1, x + w]])
            .collect();
        let topo = crate::topology::Topology::new(2 * w as usize, &tris);
        let n = topo.vertices;
        let slots = Slots {
            vertices: n,
            k: topo.slots,
            index: topo.padded.iter().map(|&j| j as u32).collect(),
            used: topo.padded_mask.iter().map(|&u| u != 0.0).collect(),
        };
        let inv_degree = topo.inv_degree();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut checked = 0;
        for (width, heads, norm) in [
            (48, 4, false),
            (13, 3, true),
            (61, 8, true),
            (16, 1, false),
            (5, 2, true),
        ] {
            let ci = width + 3;
            let mut draw = |len: usize, s: f32| -> Vec<f32> {
                (0..len).map(|_| rng.random_range(-s..s)).collect()
            };
            let blocks: Vec<HostBlock> = (0..2)
                .map(|_| HostBlock {
                    u: draw(ci * heads, 0.5),
                    c: draw(heads, 0.3),
                    w: draw(heads * ci * width, 0.2),
                    bias: draw(width, 0.1),
                    norm: norm.then(|| (draw(width, 1.5), draw(width, 0.2), 1e-5)),
                })
                .collect();
            // 3 x 98 rows: tiles of 64, the last of 38, not a whole number of 4-row blocks.
            let b = 3;
            let (h, xyz) = (draw(b * n * width, 1.0), draw(b * n * 3, 1.0));
            let shape = StackShape {
                batch: b,
                vertices: n,
                width,
                heads,
                slope: 0.1,
            };
            let run = |level| stack_at(level, &h, &xyz, &blocks, &slots, &inv_degree, shape);
            let want = run(Level::Scalar);
            assert_eq!(want.len(), b * n * width);
            for level in Level::all() {
                let (err, scale) = largest_difference(&run(level), &want);
                assert!(
                    err / scale < 1e-5,
                    "width {width}, heads {heads}, {level:?}: {err} of {scale}"
                );
                checked += 1;
            }
        }
        assert!(checked >= 5, "{checked}");
    }

    /// The same for the fusion head: two per-vertex parts whose widths fill no vector, a
    /// per-drape constant, layers with and without normalisation and activation, down to
    /// 3 outputs, on 3 x 98 rows.
    #[test]
    fn every_simd_level_gives_the_scalar_head() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(8);
        let mut draw = |len: usize, s: f32| -> Vec<f32> {
            (0..len).map(|_| rng.random_range(-s..s)).collect()
        };
        let (b, n) = (3, 98);
        let (p1, p2) = (draw(b * n * 7, 1.0), draw(b * n * 5, 1.0));
        let mut dense = |i: usize, o: usize, norm: bool, leaky: bool| HostDense {
            w: draw(i * o, 0.4),
            b: draw(o, 0.1),
            norm: norm.then(|| (draw(o, 1.5), draw(o, 0.2), 1e-5)),
            leaky,
        };
        let first = dense(12, 20, true, true);
        let rest = [
            dense(20, 13, false, true),
            dense(13, 9, true, true),
            dense(9, 3, false, false),
        ];
        let constant = draw(b * 20, 0.5);
        let parts = [(p1.as_slice(), 7), (p2.as_slice(), 5)];
        let run = |level| head_at(level, &parts, &constant, &first, &rest, (b, n), 0.1);
        let want = run(Level::Scalar);
        assert_eq!(want.len(), b * n * 3);
        // The first row by hand.
        let mut x: Vec<f32> = p1[..7].iter().chain(&p2[..5]).copied().collect();
        for (k, layer) in std::iter::once(&first).chain(&rest).enumerate() {
            let o = layer.w.len() / x.len();
            let bias = if k == 0 {
                &constant[..20]
            } else {
                &layer.b[..]
            };
            let mut y: Vec<f32> = (0..o)
                .map(|c| {
                    x.iter()
                        .enumerate()
                        .map(|(e, v)| v * layer.w[e * o + c])
                        .sum::<f32>()
                        + bias[c]
                })
                .collect();
            if let Some((g, bt, eps)) = &layer.norm {
                layer_norm_row(&mut y, g, bt, *eps);
            }
            if layer.leaky {
                y.iter_mut()
                    .for_each(|v| *v = if *v >= 0.0 { *v } else { 0.1 * *v });
            }
            x = y;
        }
        for (a, e) in want[..3].iter().zip(&x) {
            assert!((a - e).abs() <= 1e-5 * (1.0 + e.abs()), "{a} against {e}");
        }
        for level in Level::all() {
            let (err, scale) = largest_difference(&run(level), &want);
            assert!(err / scale < 1e-5, "{level:?}: {err} of {scale}");
        }
    }
}

/// The largest absolute difference of `got` from `want`, and `want`'s largest magnitude
/// (for tests).
#[cfg(test)]
pub(super) fn largest_difference(got: &[f32], want: &[f32]) -> (f32, f32) {
    assert_eq!(got.len(), want.len());
    let scale = want.iter().fold(1e-12f32, |s, v| s.max(v.abs()));
    let err = got
        .iter()
        .zip(want)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f32::max);
    (err, scale)
}

/// A point-wise dense layer on the host: `y = act(norm(x w + b))`.
#[derive(Debug, Clone)]
pub struct HostDense {
    /// `[input, output]` (burn's layout).
    pub w: Vec<f32>,
    /// `[output]`.
    pub b: Vec<f32>,
    /// Layer normalisation: gamma, beta, epsilon.
    pub norm: Option<(Vec<f32>, Vec<f32>, f32)>,
    /// Whether the leaky ReLU follows.
    pub leaky: bool,
}

/// The fusion head at inference: per vertex, the first layer on the concatenation of
/// `parts` (each `[B, N, d_k]`, their maps stacked in `first.w`) plus a per-drape row of
/// `constant` (`[B, F0]`: the broadcast features' products and the bias; `first.b` is
/// ignored), then `rest`, all per tile of [`VERTICES_PER_TASK`] vertices in cache, with no
/// tensor between the layers.
///
/// # Shapes
/// -> `[B, N, rest.last().b.len()]`.
pub fn pointwise_head(
    parts: &[(&[f32], usize)],
    constant: &[f32],
    first: &HostDense,
    rest: &[HostDense],
    (batch, n): (usize, usize),
    slope: f32,
) -> Vec<f32> {
    head_at(Level::Best, parts, constant, first, rest, (batch, n), slope)
}

/// [`pointwise_head`] at `level`.
fn head_at(
    level: Level,
    parts: &[(&[f32], usize)],
    constant: &[f32],
    first: &HostDense,
    rest: &[HostDense],
    (batch, n): (usize, usize),
    slope: f32,
) -> Vec<f32> {
    let rows = batch * n;
    let din: usize = parts.iter().map(|p| p.1).sum();
    let f0 = first.w.len() / din.max(1);
    assert_eq!(
        first.w.len(),
        din * f0,
        "the first layer's maps are [sum d_k, F0]"
    );
    assert_eq!(
        constant.len(),
        batch * f0,
        "one row of the constant per drape"
    );
    for (p, d) in parts {
        assert_eq!(p.len(), rows * d, "each part is [B, N, d_k]");
    }
    let out_width = rest.last().map_or(f0, |l| l.b.len());
    let mut out = vec![0.0f32; rows * out_width];
    out.par_chunks_mut(VERTICES_PER_TASK * out_width)
        .enumerate()
        .for_each(|(t, out)| {
            level.run(HeadRows {
                first_row: t * VERTICES_PER_TASK,
                out,
                parts,
                constant,
                first,
                rest,
                n,
                slope,
            })
        });
    out
}

/// One task of [`pointwise_head`].
struct HeadRows<'a> {
    first_row: usize,
    out: &'a mut [f32],
    parts: &'a [(&'a [f32], usize)],
    constant: &'a [f32],
    first: &'a HostDense,
    rest: &'a [HostDense],
    n: usize,
    slope: f32,
}

impl WithSimd for HeadRows<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: Simd>(self, simd: S) {
        let din: usize = self.parts.iter().map(|p| p.1).sum();
        let f0 = self.first.w.len() / din;
        let out_width = self.rest.last().map_or(f0, |l| l.b.len());
        let tile = self.out.len() / out_width;
        // The tile's inputs side by side.
        let mut x = Vec::with_capacity(tile * din);
        for r in 0..tile {
            let row = self.first_row + r;
            for (p, d) in self.parts {
                x.extend_from_slice(&p[row * d..(row + 1) * d]);
            }
        }
        let mut y = vec![0.0f32; tile * f0];
        tile_product(simd, &x, din, &self.first.w, f0, &mut y);
        for (r, yr) in y.chunks_exact_mut(f0).enumerate() {
            let s = (self.first_row + r) / self.n;
            let c = &self.constant[s * f0..(s + 1) * f0];
            finish_row(
                yr,
                c,
                self.first.norm.as_ref(),
                self.first.leaky,
                self.slope,
            );
        }
        let (mut x, mut width) = (y, f0);
        for layer in self.rest {
            let o = layer.b.len();
            let mut y = vec![0.0f32; tile * o];
            tile_product(simd, &x, width, &layer.w, o, &mut y);
            for yr in y.chunks_exact_mut(o) {
                finish_row(yr, &layer.b, layer.norm.as_ref(), layer.leaky, self.slope);
            }
            (x, width) = (y, o);
        }
        self.out.copy_from_slice(&x);
    }
}

/// `y <- act(norm(y + b))` for one row.
#[inline(always)]
fn finish_row(
    y: &mut [f32],
    b: &[f32],
    norm: Option<&(Vec<f32>, Vec<f32>, f32)>,
    act: bool,
    slope: f32,
) {
    for (v, &c) in y.iter_mut().zip(b) {
        *v += c;
    }
    if let Some((gamma, beta, eps)) = norm {
        layer_norm_row(y, gamma, beta, *eps);
    }
    if act {
        for v in y.iter_mut() {
            *v = if *v >= 0.0 { *v } else { *v * slope };
        }
    }
}

/// burn's layer normalisation of one row: `(y - mean) / sqrt(var + eps) gamma + beta`, the
/// variance biased.
#[inline(always)]
fn layer_norm_row(y: &mut [f32], gamma: &[f32], beta: &[f32], eps: f32) {
    let w = y.len() as f32;
    let mean = y.iter().sum::<f32>() / w;
    let var = y.iter().map(|v| (v - mean) * (v - mean)).sum::<f32>() / w;
    let inv = 1.0 / (var + eps).sqrt();
    for ((v, &g), &b) in y.iter_mut().zip(gamma).zip(beta) {
        *v = (*v - mean) * inv * g + b;
    }
}
