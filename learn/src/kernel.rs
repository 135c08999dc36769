//! The kernel map: the linear map of [`crate::linear`] plus an RBF kernel ridge regression
//! of what it leaves, both from a sample's shape and pose to its displacement `G - M`.
//!
//! - Features `x` as the linear map's ([`crate::linear::features`]: the shape and the bones'
//!   rotation matrices), standardised on the training samples (constant ones dropped), `z`.
//! - The linear map is fitted first (its strength picked on the validation split); `R` is its
//!   residual on the training drapes, `[samples, 3 N]`.
//! - Kernel `k(a, b) = exp(-gamma |a - b|^2)`, `gamma = c / (2 d)` for `d` features (`c = 1`
//!   weighs a typical squared distance between two samples, about `2 d`, by `e^-1`).
//! - The map at `x`: `linear(x) + k(z, Z) (K + lambda I)^-1 R`. The width factor `c` and
//!   strength `lambda` are picked on the validation split from [`WIDTHS`] x [`LAMBDAS`] by
//!   the Edist of the whole map.
//!
//! Where the linear map levels off at about 1.1 cm on the T-shirt, this one keeps improving
//! with data (docs/eval.md, "What more data would buy"). Three uses: `drape data curve`
//! (the learning curve), the `kernel` baseline of `drape eval`, and a prior under a network
//! (`model.prior = "kernel"`, [`crate::prior`]).
//!
//! Factorisations and solves are blocked ([`cholesky`], [`cholesky_solve`]: matrix products
//! do the work), so a fit on a few thousand drapes takes seconds, not minutes. For one
//! sample at a time ([`KernelMap`], a network's prior) the residual is reduced to its
//! leading [`RANK`] directions over the garment's coordinates, so a prediction reads
//! megabytes, not the `[samples, 3 N]` dual weights.

use std::path::Path;

use glam::Vec3;
use nalgebra::DMatrix;

use crate::LearnError;
use crate::linear::{Accumulator, Labelled, Linear, f64s, read_matrices};

/// Kernel width factors `c` tried (`gamma = c / (2 d)`).
pub const WIDTHS: [f64; 3] = [0.5, 1.0, 2.0];

/// Kernel ridge strengths tried (the kernel's diagonal is 1).
pub const LAMBDAS: [f64; 4] = [0.01, 0.03, 0.1, 0.3];

/// The picks used without a validation split: `c = 1`, `lambda = 0.1`.
pub const DEFAULT_PICK: (f64, f64) = (1.0, 0.1);

/// A training sample in memory: its body, features and displacement `G - M`.
#[derive(Debug, Clone)]
pub struct Row {
    /// The body's index (cross-fitting folds by body).
    pub body: u64,
    /// [`crate::linear::features`].
    pub x: Vec<f64>,
    /// `G - M`.
    pub d: Vec<Vec3>,
}

/// The strengths and width a map was fitted with.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize)]
pub struct Picks {
    /// The linear map's ridge strength.
    pub linear_lambda: f64,
    /// The kernel's width factor `c`.
    pub width: f64,
    /// The kernel ridge strength.
    pub lambda: f64,
}

/// Standardisation of training features: index, mean and 1 / deviation of each
/// non-constant feature.
#[derive(Debug, Clone)]
pub struct Standard {
    keep: Vec<(usize, f64, f64)>,
}

impl Standard {
    /// From the training features.
    pub fn new(xs: &[&[f64]]) -> Self {
        let n = xs.len().max(1) as f64;
        let width = xs.first().map_or(0, |x| x.len());
        let keep = (0..width)
            .filter_map(|j| {
                let mean = xs.iter().map(|x| x[j]).sum::<f64>() / n;
                let var = xs.iter().map(|x| (x[j] - mean).powi(2)).sum::<f64>() / n;
                (var > 1e-10).then(|| (j, mean, 1.0 / var.sqrt()))
            })
            .collect();
        Self { keep }
    }

    /// The standardised non-constant features of `x`.
    pub fn apply(&self, x: &[f64]) -> Vec<f64> {
        self.keep.iter().map(|&(j, m, s)| (x[j] - m) * s).collect()
    }

    /// Features kept.
    pub fn features(&self) -> usize {
        self.keep.len()
    }
}

/// `|a_i - b_j|^2` for every pair, `[a.len(), b.len()]`, as `|a|^2 + |b|^2 - 2 a b^T` (one
/// matrix product).
pub fn squared_distances(a: &[Vec<f64>], b: &[Vec<f64>]) -> DMatrix<f64> {
    let d = a.first().or(b.first()).map_or(0, |x| x.len());
    let ma = DMatrix::from_fn(a.len(), d, |i, k| a[i][k]);
    let mb = DMatrix::from_fn(b.len(), d, |i, k| b[i][k]);
    let na: Vec<f64> = a.iter().map(|x| x.iter().map(|v| v * v).sum()).collect();
    let nb: Vec<f64> = b.iter().map(|x| x.iter().map(|v| v * v).sum()).collect();
    let mut m = ma * mb.transpose() * -2.0;
    for j in 0..b.len() {
        for i in 0..a.len() {
            m[(i, j)] = (m[(i, j)] + na[i] + nb[j]).max(0.0);
        }
    }
    m
}

/// Rows per block of [`cholesky_solve`].
const BLOCK: usize = 128;

/// `X` with `L L^T X = B`, for a lower-triangular `L`: forward then back substitution in
/// blocks of [`BLOCK`] rows, each block's update one matrix product, its diagonal block a
/// small triangular solve.
pub fn cholesky_solve(l: &DMatrix<f64>, b: &DMatrix<f64>) -> DMatrix<f64> {
    let n = l.nrows();
    assert_eq!(b.nrows(), n, "right-hand side rows");
    let mut y = b.clone();
    let solve_block = |y: &mut DMatrix<f64>, s: usize, e: usize, transposed: bool| {
        let diag = l.view((s, s), (e - s, e - s)).clone_owned();
        let mut block = y.rows(s, e - s).clone_owned();
        // A factor from [`cholesky`] has a positive diagonal, so these cannot fail.
        let solved = if transposed {
            diag.tr_solve_lower_triangular_mut(&mut block)
        } else {
            diag.solve_lower_triangular_mut(&mut block)
        };
        debug_assert!(solved, "a zero on the factor's diagonal");
        y.rows_mut(s, e - s).copy_from(&block);
    };
    // L Y = B.
    let mut s = 0;
    while s < n {
        let e = (s + BLOCK).min(n);
        if s > 0 {
            let update = l.view((s, 0), (e - s, s)) * y.rows(0, s);
            let mut rows = y.rows_mut(s, e - s);
            rows -= update;
        }
        solve_block(&mut y, s, e, false);
        s = e;
    }
    // L^T X = Y.
    let mut e = n;
    while e > 0 {
        let s = e.saturating_sub(BLOCK);
        if e < n {
            let below = l.view((e, s), (n - e, e - s)).transpose();
            let update = below * y.rows(e, n - e);
            let mut rows = y.rows_mut(s, e - s);
            rows -= update;
        }
        solve_block(&mut y, s, e, true);
        e = s;
    }
    y
}

/// The lower Cholesky factor `L` of a symmetric positive definite `a` (`L L^T = a`; only
/// the lower triangle of `a` is read), left-looking in blocks of [`BLOCK`] columns: each
/// block's update is a matrix product, its diagonal block a small factorisation. `None` if
/// `a` is not positive definite.
pub fn cholesky(mut a: DMatrix<f64>) -> Option<DMatrix<f64>> {
    let n = a.nrows();
    assert_eq!(a.ncols(), n, "square");
    let mut k = 0;
    while k < n {
        let e = (k + BLOCK).min(n);
        let w = e - k;
        if k > 0 {
            // The block column below and at the diagonal, minus the factored columns.
            let left_t = a.view((k, 0), (w, k)).transpose(); // [k, w]
            let update = a.view((k, 0), (n - k, k)) * left_t; // [n - k, w]
            let mut col = a.view_mut((k, k), (n - k, w));
            col -= update;
        }
        let diag = a.view((k, k), (w, w)).clone_owned().cholesky()?.unpack();
        if e < n {
            // L21 = A21 L11^-T, as L11 L21^T = A21^T.
            let mut below_t = a.view((e, k), (n - e, w)).transpose(); // [w, n - e]
            if !diag.solve_lower_triangular_mut(&mut below_t) {
                return None;
            }
            a.view_mut((e, k), (n - e, w))
                .copy_from(&below_t.transpose());
        }
        a.view_mut((k, k), (w, w)).copy_from(&diag);
        k = e;
    }
    // Zero the upper triangle.
    for j in 1..n {
        for i in 0..j {
            a[(i, j)] = 0.0;
        }
    }
    Some(a)
}

/// RBF kernel ridge regression on standardised features: the prediction at `q` is
/// `k(q, Z) (K + lambda I)^-1 R` for training features `Z` and targets `R`.
#[derive(Debug, Clone)]
pub struct KernelRidge {
    gamma: f64,
    /// The Cholesky factor of `K + lambda I`.
    l: DMatrix<f64>,
    /// The width factor `c` (`gamma = c / (2 d)`).
    pub width: f64,
    /// The ridge strength.
    pub lambda: f64,
}

impl KernelRidge {
    /// Factorises `K + lambda I` from the training features' squared distances `sq`
    /// ([`squared_distances`]) for `d` features; `None` if it cannot be (no samples, or not
    /// positive definite).
    pub fn fit(sq: &DMatrix<f64>, d: usize, width: f64, lambda: f64) -> Option<Self> {
        if sq.nrows() == 0 {
            return None;
        }
        let gamma = width / (2.0 * d.max(1) as f64);
        let mut a = sq.map(|v| (-gamma * v).exp());
        for i in 0..a.nrows() {
            a[(i, i)] += lambda;
        }
        let l = cholesky(a)?;
        Some(Self {
            gamma,
            l,
            width,
            lambda,
        })
    }

    /// `(K + lambda I)^-1 targets`: the dual weights, `[training samples, outputs]`.
    pub fn dual(&self, targets: &DMatrix<f64>) -> DMatrix<f64> {
        cholesky_solve(&self.l, targets)
    }

    /// Predictions at the queries whose squared distances to the training features are
    /// `sq` (`[training samples, queries]`), for training targets `targets` (`[training
    /// samples, outputs]`): `[queries, outputs]`. Solved with one right-hand side per query,
    /// not per output.
    pub fn predict(&self, sq: &DMatrix<f64>, targets: &DMatrix<f64>) -> DMatrix<f64> {
        let k = sq.map(|v| (-self.gamma * v).exp());
        cholesky_solve(&self.l, &k).transpose() * targets
    }
}

/// Row `i` of `[rows, 3 N]` as vertices.
fn unstack(m: &DMatrix<f64>, i: usize) -> Vec<Vec3> {
    (0..m.ncols() / 3)
        .map(|v| {
            Vec3::new(
                m[(i, 3 * v)] as f32,
                m[(i, 3 * v + 1)] as f32,
                m[(i, 3 * v + 2)] as f32,
            )
        })
        .collect()
}

/// Mean Edist (cm) of `M + displacement` against `G` over `samples`.
fn edist(samples: &[Labelled], displacement: impl Fn(usize) -> Vec<Vec3>) -> f64 {
    let per: f64 = samples
        .iter()
        .enumerate()
        .map(|(i, (_, m, g))| {
            let d = displacement(i);
            m.iter()
                .zip(&d)
                .zip(g)
                .map(|((m, d), g)| (*m + *d).distance(*g) as f64)
                .sum::<f64>()
                / g.len() as f64
        })
        .sum();
    per / samples.len().max(1) as f64 * 100.0
}

/// A fit in memory: the linear map, the standardised training features, the residual
/// and the factorised kernel system. [`Fit::map`] turns it into a [`KernelMap`].
#[derive(Debug)]
pub struct Fit {
    /// The linear map.
    pub linear: Linear,
    /// The linear map's Edist on its own training drapes (cm).
    pub linear_train_cm: f64,
    /// The kernel ridge regression of the residual.
    pub ridge: KernelRidge,
    /// Validation Edist (cm) of the whole map per (width factor, strength) tried.
    pub tried: Vec<(f64, f64, f64)>,
    standard: Standard,
    z: Vec<Vec<f64>>,
    residual: DMatrix<f64>,
}

impl Fit {
    /// Fits on `rows`. Without `picks` the linear strength, then the kernel's width and
    /// strength are picked on `validation` (features, M, G; the defaults if it is empty);
    /// with them nothing is picked and `validation` is not read. `None` if a system cannot
    /// be solved. `progress` gets a line per kernel tried.
    pub fn new(
        rows: &[&Row],
        validation: &[Labelled],
        picks: Option<Picks>,
        progress: &mut dyn FnMut(&str),
    ) -> Option<Self> {
        let first = rows.first()?;
        let n = first.d.len();
        let mut sums = Accumulator::new(first.x.len(), n);
        for r in rows {
            sums.add(&r.x, &r.d);
        }
        let linear = match picks {
            Some(p) => sums.solve(p.linear_lambda)?,
            None => crate::linear::fit(&sums, validation)?.0,
        };
        // Residual of the linear fit on its own training drapes.
        let mut residual = DMatrix::<f64>::zeros(rows.len(), 3 * n);
        let mut train_cm = 0.0;
        for (i, r) in rows.iter().enumerate() {
            let mut err = 0.0;
            for (v, (p, d)) in linear.displacement(&r.x).iter().zip(&r.d).enumerate() {
                let e = *d - *p;
                err += e.length() as f64;
                for k in 0..3 {
                    residual[(i, 3 * v + k)] = e[k] as f64;
                }
            }
            train_cm += err / n as f64 * 100.0;
        }
        let xs: Vec<&[f64]> = rows.iter().map(|r| r.x.as_slice()).collect();
        let standard = Standard::new(&xs);
        let z: Vec<Vec<f64>> = xs.iter().map(|x| standard.apply(x)).collect();
        let d = standard.features();
        let sq = squared_distances(&z, &z);
        let mut tried = Vec::new();
        let ridge = match (picks, validation.is_empty()) {
            (Some(p), _) => KernelRidge::fit(&sq, d, p.width, p.lambda)?,
            (None, true) => KernelRidge::fit(&sq, d, DEFAULT_PICK.0, DEFAULT_PICK.1)?,
            (None, false) => {
                let zv: Vec<Vec<f64>> = validation
                    .iter()
                    .map(|(x, _, _)| standard.apply(x))
                    .collect();
                let sqv = squared_distances(&z, &zv);
                let base: Vec<Vec<Vec3>> = validation
                    .iter()
                    .map(|(x, _, _)| linear.displacement(x))
                    .collect();
                let mut best: Option<(f64, KernelRidge)> = None;
                for &c in &WIDTHS {
                    for &l in &LAMBDAS {
                        progress(&format!("kernel width {c}, strength {l}"));
                        let Some(k) = KernelRidge::fit(&sq, d, c, l) else {
                            continue;
                        };
                        let p = k.predict(&sqv, &residual);
                        let cm = edist(validation, |i| {
                            base[i]
                                .iter()
                                .zip(unstack(&p, i))
                                .map(|(a, b)| *a + b)
                                .collect()
                        });
                        tried.push((c, l, cm));
                        if best.as_ref().is_none_or(|(b, _)| cm < *b) {
                            best = Some((cm, k));
                        }
                    }
                }
                best?.1
            }
        };
        Some(Self {
            linear,
            linear_train_cm: train_cm / rows.len() as f64,
            ridge,
            tried,
            standard,
            z,
            residual,
        })
    }

    /// What was used.
    pub fn picks(&self) -> Picks {
        Picks {
            linear_lambda: self.linear.lambda,
            width: self.ridge.width,
            lambda: self.ridge.lambda,
        }
    }

    /// The map's displacements at many feature vectors at once (one solve for all).
    pub fn displacements(&self, xs: &[&[f64]]) -> Vec<Vec<Vec3>> {
        if xs.is_empty() {
            return Vec::new();
        }
        let zq: Vec<Vec<f64>> = xs.iter().map(|x| self.standard.apply(x)).collect();
        let p = self
            .ridge
            .predict(&squared_distances(&self.z, &zq), &self.residual);
        xs.iter()
            .enumerate()
            .map(|(i, x)| {
                self.linear
                    .displacement(x)
                    .iter()
                    .zip(unstack(&p, i))
                    .map(|(a, b)| *a + b)
                    .collect()
            })
            .collect()
    }

    /// The map for one sample at a time, with the residual reduced to its first `rank`
    /// principal directions over the garment's coordinates ([`RANK`] by default; exact when
    /// `rank` reaches the samples or the coordinates): `R ~ R V V^T` with `V` an orthonormal
    /// `[3 N, rank]` basis from a randomised range finder with two power iterations, so the
    /// map keeps `A = (K + lambda I)^-1 R V` (`[samples, rank]`) and `V`, and a prediction
    /// costs `(samples + 3 N) rank` multiply-adds instead of `samples 3 N`.
    pub fn map(&self, rank: usize) -> KernelMap {
        let r = &self.residual;
        let basis = row_basis(r, rank);
        let projected = r * &basis; // [samples, k]
        let kept = projected.norm_squared() / r.norm_squared().max(f64::MIN_POSITIVE);
        let a = self.ridge.dual(&projected);
        let row_major = |m: &DMatrix<f64>| -> Vec<f32> {
            (0..m.nrows())
                .flat_map(|i| (0..m.ncols()).map(move |j| m[(i, j)] as f32))
                .collect()
        };
        KernelMap {
            gamma: self.ridge.gamma,
            width: self.ridge.width,
            lambda: self.ridge.lambda,
            linear: self.linear.clone(),
            standard: self.standard.clone(),
            z: self.z.clone(),
            rank: basis.ncols(),
            a: row_major(&a),
            basis: row_major(&basis),
            outputs: r.ncols(),
            kept,
        }
    }
}

/// Rank of [`Fit::map`]'s residual basis. On `cpu-curve` (5,855 training drapes of the 3k
/// T-shirt, 8,901 coordinates) rank 256 keeps 98.1% of the residual's energy; the 98
/// validation drapes' Edist is 0.980 cm against 0.982 for the exact map (the largest
/// vertex difference 6.2 mm), and a prediction takes 4.7 ms against 27 ms (docs/learn.md).
pub const RANK: usize = 256;

/// An orthonormal basis `[cols, k]` (`k = min(rank, rows, cols)`) of the leading right
/// singular directions of `r`: a randomised range finder (a fixed pseudo-random start) with
/// two power iterations.
fn row_basis(r: &DMatrix<f64>, rank: usize) -> DMatrix<f64> {
    use rand::{Rng, SeedableRng};
    let k = rank.min(r.nrows()).min(r.ncols());
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0x6b65726e);
    let start = DMatrix::from_fn(r.nrows(), k, |_, _| rng.random::<f64>() - 0.5);
    let rt = r.transpose();
    let mut y = (&rt * start).qr().q();
    for _ in 0..2 {
        y = (&rt * (r * &y)).qr().q();
    }
    y
}

/// Each row's displacement from a fit without its fold of bodies (`body % folds`), with
/// fixed `picks`. An error if one fold holds every row (there is nothing to fit without
/// it: an in-sample prior would be far better on the training drapes than on new bodies)
/// or a system cannot be solved.
pub fn cross_fit(
    rows: &[Row],
    picks: Picks,
    folds: u64,
    progress: &mut dyn FnMut(&str),
) -> Result<Vec<Vec<Vec3>>, String> {
    let mut out: Vec<Option<Vec<Vec3>>> = vec![None; rows.len()];
    for f in 0..folds {
        let (inside, rest): (Vec<usize>, Vec<usize>) =
            (0..rows.len()).partition(|&i| rows[i].body % folds == f);
        if inside.is_empty() {
            continue;
        }
        if rest.is_empty() {
            return Err(format!(
                "all {} training drapes come from bodies of one fold (body index % {folds} = \
                 {f}): cross-fitting needs bodies in two folds",
                rows.len()
            ));
        }
        progress(&format!(
            "fold {} of {folds}: {} drapes held out",
            f + 1,
            inside.len()
        ));
        let train: Vec<&Row> = rest.iter().map(|&i| &rows[i]).collect();
        let fit = Fit::new(&train, &[], Some(picks), &mut |_| {})
            .ok_or_else(|| format!("the fit without fold {f} cannot be solved"))?;
        let xs: Vec<&[f64]> = inside.iter().map(|&i| rows[i].x.as_slice()).collect();
        for (i, d) in inside.iter().zip(fit.displacements(&xs)) {
            out[*i] = Some(d);
        }
    }
    Ok(out
        .into_iter()
        .map(|d| d.expect("every row in a fold"))
        .collect())
}

/// A fitted kernel map that predicts one sample at a time ([`Fit::map`]).
#[derive(Debug, Clone)]
pub struct KernelMap {
    /// The linear part.
    pub linear: Linear,
    standard: Standard,
    /// Standardised training features.
    z: Vec<Vec<f64>>,
    /// Columns of the residual basis.
    rank: usize,
    /// `(K + lambda I)^-1 R V`, row-major `[training samples, rank]`.
    a: Vec<f32>,
    /// The residual basis `V`, row-major `[3 N, rank]`.
    basis: Vec<f32>,
    outputs: usize,
    gamma: f64,
    /// The width factor `c`.
    pub width: f64,
    /// The kernel ridge strength.
    pub lambda: f64,
    /// Share of the training residual's energy the basis keeps.
    pub kept: f64,
}

impl KernelMap {
    /// The predicted displacement of a sample with features `x`.
    pub fn displacement(&self, x: &[f64]) -> Vec<Vec3> {
        let q = self.standard.apply(x);
        let r = self.rank;
        // Coefficients on the basis: sum over training samples of k(x, z_i) A_i.
        let mut c = vec![0.0f32; r];
        for (i, z) in self.z.iter().enumerate() {
            let sq: f64 = z.iter().zip(&q).map(|(a, b)| (a - b) * (a - b)).sum();
            let k = (-self.gamma * sq).exp() as f32;
            if k < 1e-12 {
                continue;
            }
            for (c, &a) in c.iter_mut().zip(&self.a[i * r..(i + 1) * r]) {
                *c += k * a;
            }
        }
        let out = |o: usize| -> f32 {
            self.basis[o * r..(o + 1) * r]
                .iter()
                .zip(&c)
                .map(|(v, c)| v * c)
                .sum()
        };
        self.linear
            .displacement(x)
            .iter()
            .enumerate()
            .map(|(v, l)| *l + Vec3::new(out(3 * v), out(3 * v + 1), out(3 * v + 2)))
            .collect()
    }

    /// Garment vertices it predicts for.
    pub fn vertices(&self) -> usize {
        self.outputs / 3
    }

    /// Features it takes ([`crate::linear::features`]).
    pub fn features(&self) -> usize {
        self.linear.weights().nrows() - 1
    }

    /// Columns of its residual basis.
    pub fn rank(&self) -> usize {
        self.rank
    }

    /// Training samples it keeps.
    pub fn samples(&self) -> usize {
        self.z.len()
    }

    /// What it was fitted with.
    pub fn picks(&self) -> Picks {
        Picks {
            linear_lambda: self.linear.lambda,
            width: self.width,
            lambda: self.lambda,
        }
    }

    /// Safetensors bytes: `linear` (F64 `[features + 1, 3 N]`), `standard` (F64 `[d, 3]`:
    /// feature index, mean, 1 / deviation), `z` (F64 `[samples, d]`), `a` (F32 `[samples,
    /// rank]`), `basis` (F32 `[3 N, rank]`), and the picks, `gamma` and the energy kept as
    /// metadata.
    pub fn encode(&self) -> Vec<u8> {
        let f64s = |v: &mut dyn Iterator<Item = f64>| -> Vec<u8> {
            v.flat_map(|x| x.to_le_bytes()).collect()
        };
        let f32s = |v: &[f32]| -> Vec<u8> { v.iter().flat_map(|x| x.to_le_bytes()).collect() };
        let w = self.linear.weights();
        let linear = f64s(&mut (0..w.nrows()).flat_map(|j| (0..w.ncols()).map(move |k| w[(j, k)])));
        let standard = f64s(
            &mut self
                .standard
                .keep
                .iter()
                .flat_map(|&(j, m, s)| [j as f64, m, s]),
        );
        let z = f64s(&mut self.z.iter().flatten().copied());
        let d = self.standard.features();
        use safetensors::Dtype::{F32, F64};
        sim::io::safetensors_bytes(
            &[
                ("linear", F64, vec![w.nrows(), w.ncols()], linear),
                ("standard", F64, vec![d, 3], standard),
                ("z", F64, vec![self.z.len(), d], z),
                ("a", F32, vec![self.z.len(), self.rank], f32s(&self.a)),
                (
                    "basis",
                    F32,
                    vec![self.outputs, self.rank],
                    f32s(&self.basis),
                ),
            ],
            &serde_json::json!({
                "format": "drape-kernel/2",
                "gamma": self.gamma,
                "width": self.width,
                "lambda": self.lambda,
                "linear_lambda": self.linear.lambda,
                "kept": self.kept,
            }),
        )
    }

    /// Reads [`KernelMap::encode`]'s file.
    pub fn load(path: &Path) -> Result<Self, LearnError> {
        use safetensors::Dtype::{F32, F64};
        let bad = |reason: String| LearnError::Checkpoint {
            path: path.to_path_buf(),
            reason,
        };
        let (meta, t) = read_matrices(
            path,
            "drape-kernel/2",
            &[
                ("linear", F64),
                ("standard", F64),
                ("z", F64),
                ("a", F32),
                ("basis", F32),
            ],
        )?;
        let [(ls, lb), (ss, sb), (zs, zb), (as_, ab), (bs, bb)] =
            <[_; 5]>::try_from(t).expect("five tensors asked for");
        let number = |k: &str| meta[k].as_f64().ok_or_else(|| bad(format!("no {k}")));
        if ss[1] != 3 || zs[1] != ss[0] || as_[0] != zs[0] || bs[0] != ls[1] || bs[1] != as_[1] {
            return Err(bad(format!(
                "inconsistent shapes: linear {ls:?}, standard {ss:?}, z {zs:?}, a {as_:?}, basis {bs:?}"
            )));
        }
        let keep: Vec<(usize, f64, f64)> = f64s(&sb)
            .chunks_exact(3)
            .map(|c| (c[0] as usize, c[1], c[2]))
            .collect();
        if ls[1] % 3 != 0 || ls[0] == 0 || keep.iter().any(|&(j, _, _)| j + 1 >= ls[0]) {
            return Err(bad(format!(
                "linear {ls:?}: not 3 N outputs, or a standardised feature beyond its {} \
                 features",
                ls[0].saturating_sub(1)
            )));
        }
        let z = if zs[1] == 0 {
            vec![Vec::new(); zs[0]]
        } else {
            f64s(&zb).chunks_exact(zs[1]).map(|c| c.to_vec()).collect()
        };
        let f32s = |b: &[u8]| -> Vec<f32> {
            b.chunks_exact(4)
                .map(|c| f32::from_le_bytes(c.try_into().expect("4 bytes")))
                .collect()
        };
        Ok(Self {
            linear: Linear::from_weights(
                DMatrix::from_row_slice(ls[0], ls[1], &f64s(&lb)),
                number("linear_lambda")?,
            ),
            standard: Standard { keep },
            z,
            rank: as_[1],
            a: f32s(&ab),
            basis: f32s(&bb),
            outputs: bs[0],
            gamma: number("gamma")?,
            width: number("width")?,
            lambda: number("lambda")?,
            kept: number("kept")?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A smooth nonlinear function of two standardised features.
    fn f(z: &[f64]) -> f64 {
        (1.5 * z[0]).sin() + 0.5 * z[0] * z[1]
    }

    /// Points on a grid in [-1.5, 1.5]^2 (offset for the held-out ones).
    fn grid(n: usize, offset: f64) -> Vec<Vec<f64>> {
        let at = |i: usize| -1.5 + 3.0 * (i as f64 + offset) / n as f64;
        (0..n)
            .flat_map(|i| (0..n).map(move |j| vec![at(i), at(j)]))
            .collect()
    }

    #[test]
    fn kernel_ridge_learns_a_smooth_function_off_its_samples() {
        let z = grid(15, 0.0);
        let targets = DMatrix::from_fn(z.len(), 2, |i, o| f(&z[i]) * (1.0 + o as f64));
        let held = grid(10, 0.5);
        let k = KernelRidge::fit(&squared_distances(&z, &z), 2, 2.0, 1e-3).unwrap();
        let p = k.predict(&squared_distances(&z, &held), &targets);
        assert_eq!((p.nrows(), p.ncols()), (100, 2));
        // Function values span about +-2.1; the interpolation is within 0.05 of them on
        // held-out points inside the grid (the border extrapolates).
        let mut worst: f64 = 0.0;
        for (i, q) in held.iter().enumerate() {
            if q.iter().all(|x| x.abs() < 1.3) {
                worst = worst.max((p[(i, 0)] - f(q)).abs());
                assert!((p[(i, 1)] - 2.0 * p[(i, 0)]).abs() < 1e-9);
            }
        }
        assert!(worst < 0.05, "worst error {worst}");
    }

    #[test]
    fn a_strong_kernel_ridge_predicts_zero() {
        let z = grid(5, 0.0);
        let targets = DMatrix::from_fn(z.len(), 1, |i, _| f(&z[i]));
        let k = KernelRidge::fit(&squared_distances(&z, &z), 2, 1.0, 1e9).unwrap();
        let p = k.predict(&squared_distances(&z, &grid(3, 0.5)), &targets);
        assert!(p.iter().all(|v| v.abs() < 1e-6), "{p}");
        assert!(KernelRidge::fit(&DMatrix::zeros(0, 0), 2, 1.0, 0.1).is_none());
    }

    #[test]
    fn squared_distances_are_those_of_the_pairs() {
        let a = vec![vec![0.0, 0.0], vec![1.0, 2.0]];
        let b = vec![vec![3.0, 4.0], vec![1.0, 2.0], vec![-1.0, 0.5]];
        let m = squared_distances(&a, &b);
        assert_eq!((m.nrows(), m.ncols()), (2, 3));
        for (i, p) in a.iter().enumerate() {
            for (j, q) in b.iter().enumerate() {
                let want: f64 = p.iter().zip(q).map(|(x, y)| (x - y).powi(2)).sum();
                assert!(
                    (m[(i, j)] - want).abs() < 1e-12,
                    "{i} {j}: {} {want}",
                    m[(i, j)]
                );
            }
        }
    }

    #[test]
    fn standardisation_drops_constant_features() {
        let xs: Vec<Vec<f64>> = vec![vec![1.0, 5.0, 2.0], vec![3.0, 5.0, 4.0]];
        let refs: Vec<&[f64]> = xs.iter().map(|x| x.as_slice()).collect();
        let st = Standard::new(&refs);
        assert_eq!(st.apply(&xs[0]), vec![-1.0, -1.0]);
        assert_eq!(st.apply(&xs[1]), vec![1.0, 1.0]);
    }

    /// The blocked factorisation and solve agree with nalgebra's on a system of several
    /// blocks; a matrix that is not positive definite has no factor.
    #[test]
    fn blocked_cholesky_solve_matches_the_plain_one() {
        let n = 2 * BLOCK + 37;
        let z: Vec<Vec<f64>> = (0..n)
            .map(|i| {
                vec![
                    (i as f64 * 0.37).sin(),
                    (i as f64 * 0.11).cos(),
                    i as f64 / n as f64,
                ]
            })
            .collect();
        let mut a = squared_distances(&z, &z).map(|v| (-v).exp());
        for i in 0..n {
            a[(i, i)] += 0.05;
        }
        let b = DMatrix::from_fn(n, 5, |i, j| ((i * 7 + j * 3) % 11) as f64 - 5.0);
        let chol = a.clone().cholesky().unwrap();
        let want = chol.solve(&b);
        let l = cholesky(a.clone()).unwrap();
        assert!((&l - chol.l()).abs().max() < 1e-10);
        let got = cholesky_solve(&l, &b);
        let err = (&got - &want).abs().max();
        assert!(err < 1e-8 * want.abs().max(), "{err}");
        assert!((&a * &got - &b).abs().max() < 1e-8);
        let mut indefinite = a.clone();
        indefinite[(BLOCK + 5, BLOCK + 5)] = -1.0;
        assert!(cholesky(indefinite).is_none());
    }

    /// Rows whose displacement is a linear function plus a smooth bump in the first
    /// feature: the kernel map recovers the bump the linear map cannot; its one-at-a-time
    /// map equals the batched fit, survives a file round trip, and cross-fitting gives
    /// every row a prediction from a fit without its body.
    #[test]
    fn the_kernel_map_learns_what_the_linear_map_leaves() {
        let truth = |x: &[f64]| -> Vec<Vec3> {
            let bump = (-(x[0] * x[0]) * 4.0).exp();
            vec![
                Vec3::new((0.02 * x[1]) as f32, (0.05 * bump) as f32, 0.0),
                Vec3::new((0.01 * x[0]) as f32, 0.0, (-0.03 * bump) as f32),
            ]
        };
        let x = |k: usize| {
            let t = k as f64 / 199.0 * 2.0 - 1.0;
            vec![t, (k as f64 * 0.7).sin(), 0.5]
        };
        let rows: Vec<Row> = (0..200)
            .map(|k| Row {
                body: k as u64 % 10,
                x: x(k),
                d: truth(&x(k)),
            })
            .collect();
        let val: Vec<Labelled> = (0..20)
            .map(|k| {
                let xv = vec![k as f64 / 19.0 * 1.8 - 0.9, (k as f64 * 1.3).cos(), 0.5];
                let g = truth(&xv);
                (xv, vec![Vec3::ZERO; 2], g)
            })
            .collect();
        let refs: Vec<&Row> = rows.iter().collect();
        let fit = Fit::new(&refs, &val, None, &mut |_| {}).unwrap();
        assert_eq!(fit.tried.len(), WIDTHS.len() * LAMBDAS.len());
        let xs: Vec<&[f64]> = val.iter().map(|(x, _, _)| x.as_slice()).collect();
        let batched = fit.displacements(&xs);
        let linear_cm = edist(&val, |i| fit.linear.displacement(&val[i].0));
        let kernel_cm = edist(&val, |i| batched[i].clone());
        assert!(linear_cm > 0.8, "the bump is not linear: {linear_cm} cm");
        assert!(
            kernel_cm < 0.25 * linear_cm,
            "{kernel_cm} against {linear_cm} cm"
        );
        let picks = fit.picks();
        let map = fit.map(RANK);
        assert!(
            (map.kept - 1.0).abs() < 1e-9,
            "rank 6 of 6 keeps everything"
        );
        for (xv, b) in xs.iter().zip(&batched) {
            for (p, q) in map.displacement(xv).iter().zip(b) {
                assert!(p.distance(*q) < 1e-5, "{p} {q}");
            }
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("kernel.safetensors");
        std::fs::write(&path, map.encode()).unwrap();
        let back = KernelMap::load(&path).unwrap();
        assert_eq!(back.picks(), picks);
        assert_eq!(back.samples(), 200);
        assert_eq!(back.displacement(xs[3]), map.displacement(xs[3]));
        std::fs::write(&path, b"no").unwrap();
        // The residual here is one pattern over the coordinates: rank 1 keeps it.
        let one = Fit::new(&refs, &val, Some(picks), &mut |_| {})
            .unwrap()
            .map(1);
        assert_eq!(one.rank(), 1);
        assert!(one.kept > 0.99 && one.kept < 1.0 + 1e-9, "{}", one.kept);
        for (xv, b) in xs.iter().zip(&batched) {
            for (p, q) in one.displacement(xv).iter().zip(b) {
                assert!(p.distance(*q) < 2e-3, "{p} {q}");
            }
        }
        assert!(KernelMap::load(&path).is_err());

        let held = cross_fit(&rows, picks, 5, &mut |_| {}).unwrap();
        // A fold's predictions do not depend on its own drapes: change them all and its
        // held-out predictions stay bit for bit; the other folds' change.
        let mut changed = rows.clone();
        for r in changed.iter_mut().filter(|r| r.body % 5 == 0) {
            r.d = vec![Vec3::splat(0.3); 2];
        }
        let again = cross_fit(&changed, picks, 5, &mut |_| {}).unwrap();
        for (i, r) in rows.iter().enumerate() {
            assert_eq!(
                held[i] == again[i],
                r.body % 5 == 0,
                "row {i}, body {}",
                r.body
            );
        }
        // One fold only: refused.
        let one_body: Vec<Row> = rows.iter().filter(|r| r.body == 3).cloned().collect();
        let e = cross_fit(&one_body, picks, 5, &mut |_| {}).unwrap_err();
        assert!(e.contains("one fold"), "{e}");
        assert_eq!(held.len(), rows.len());
        let own: Vec<Vec3> = map.displacement(&rows[0].x);
        assert!(held[0].iter().zip(&own).any(|(a, b)| a.distance(*b) > 1e-6));
        let cross_cm: f64 = rows
            .iter()
            .zip(&held)
            .map(|(r, h)| {
                r.d.iter()
                    .zip(h)
                    .map(|(a, b)| a.distance(*b) as f64)
                    .sum::<f64>()
                    / 2.0
            })
            .sum::<f64>()
            / rows.len() as f64
            * 100.0;
        assert!(cross_cm < 0.3 * linear_cm, "held-out folds {cross_cm} cm");
    }
}
