//! How the closed-form maps improve with training data (`drape data curve`): would more
//! drapes buy a lower Edist, and how many?
//!
//! For each share of the training bodies (the first bodies by index, all their drapes) two
//! maps from the sample's shape and pose to the displacement `G - M` are fitted and
//! measured on the test split (the validation split picks their strengths):
//!
//! - the linear map of `drape eval` ([`learn::linear`]: ridge regression on the shape and
//!   the bones' rotation matrices, its strength picked on the validation split);
//! - the same plus an RBF kernel ridge regression of what the linear map leaves (the
//!   linear fit's training residual), on the standardised features: a smooth nonlinear map
//!   whose error keeps falling with data where the linear map's levels off. Its kernel
//!   width and strength are picked on the validation split from [`KERNEL_WIDTHS`] x
//!   [`KERNEL_LAMBDAS`].
//!
//! Training Edist beside held-out Edist tells a map that has stopped improving (the two
//! meet) from one that more data would still help.

use std::collections::BTreeSet;

use dataset::config::Split;
use dataset::reader::Dataset;
use glam::Vec3;
use learn::linear::{Accumulator, Labelled, Linear, features, read_split};
use nalgebra::DMatrix;
use serde::Serialize;

use crate::evaluate::EvalError;
use crate::metrics::{edist_cm, mean};

/// Kernel widths tried: `gamma = c / (2 d)` for these `c` (`d` the number of non-constant
/// features; `c = 1` weighs a typical squared distance between two samples' standardised
/// features, about `2 d`, by `e^-1`).
pub const KERNEL_WIDTHS: [f64; 3] = [0.5, 1.0, 2.0];

/// Kernel ridge strengths tried (the kernel's diagonal is 1).
pub const KERNEL_LAMBDAS: [f64; 4] = [0.01, 0.03, 0.1, 0.3];

/// One point of the curve.
#[derive(Debug, Clone, Serialize)]
pub struct CurvePoint {
    /// Share of the training bodies asked for.
    pub share: f64,
    /// Training bodies used.
    pub bodies: usize,
    /// Their drapes.
    pub drapes: usize,
    /// The linear map's ridge strength (picked on validation).
    pub linear_lambda: f64,
    /// The linear map's Edist on its own training drapes (cm).
    pub linear_train_cm: f64,
    /// The linear map's Edist on the held-out split (cm).
    pub linear_cm: f64,
    /// The kernel's width factor `c` and strength (picked on validation).
    pub kernel_width: f64,
    /// See `kernel_width`.
    pub kernel_lambda: f64,
    /// Linear plus kernel, Edist on the held-out split (cm).
    pub kernel_cm: f64,
}

/// The whole curve.
#[derive(Debug, Clone, Serialize)]
pub struct Curve {
    /// Dataset name and manifest checksum.
    pub dataset: String,
    /// See `dataset`.
    pub manifest_sha256: String,
    /// The split measured (test).
    pub split: String,
    /// Its drapes.
    pub held_out: usize,
    /// The DQS warp's Edist on it (cm).
    pub dqs_cm: f64,
    /// One point per share, in the order asked.
    pub points: Vec<CurvePoint>,
}

/// A training sample in memory: its body, features and displacement `G - M`.
struct Train {
    body: u64,
    x: Vec<f64>,
    d: Vec<Vec3>,
}

/// Standardisation of the training features: mean and 1 / deviation of each
/// non-constant feature.
struct Standard {
    keep: Vec<(usize, f64, f64)>,
}

impl Standard {
    fn new(xs: &[&[f64]]) -> Self {
        let n = xs.len() as f64;
        let width = xs[0].len();
        let keep = (0..width)
            .filter_map(|j| {
                let mean = xs.iter().map(|x| x[j]).sum::<f64>() / n;
                let var = xs.iter().map(|x| (x[j] - mean).powi(2)).sum::<f64>() / n;
                (var > 1e-10).then(|| (j, mean, 1.0 / var.sqrt()))
            })
            .collect();
        Self { keep }
    }

    fn apply(&self, x: &[f64]) -> Vec<f64> {
        self.keep.iter().map(|&(j, m, s)| (x[j] - m) * s).collect()
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

/// RBF kernel ridge regression on standardised features: the prediction at `q` is
/// `k(q, Z) (K + lambda I)^-1 R` for training features `Z` and targets `R`, with
/// `k(a, b) = exp(-gamma |a - b|^2)` and `gamma = width / (2 d)`.
#[derive(Debug)]
pub struct KernelRidge {
    gamma: f64,
    chol: nalgebra::Cholesky<f64, nalgebra::Dyn>,
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
        let chol = a.cholesky()?;
        Some(Self {
            gamma,
            chol,
            width,
            lambda,
        })
    }

    /// Predictions at the queries whose squared distances to the training features are
    /// `sq` (`[training samples, queries]`), for training targets `targets` (`[training
    /// samples, outputs]`): `[queries, outputs]`. Solved as `((K + lambda I)^-1 k(Z,
    /// q))^T R`: one right-hand side per query, not per output.
    pub fn predict(&self, sq: &DMatrix<f64>, targets: &DMatrix<f64>) -> DMatrix<f64> {
        let k = sq.map(|v| (-self.gamma * v).exp());
        self.chol.solve(&k).transpose() * targets
    }
}

/// Mean Edist (cm) of `base + correction rows` against the samples' drapes.
fn edist_with(samples: &[Labelled], base: &[Vec<Vec3>], correction: &DMatrix<f64>) -> f64 {
    mean(samples.iter().enumerate().map(|(i, (_, _, g))| {
        let p: Vec<Vec3> = base[i]
            .iter()
            .enumerate()
            .map(|(v, b)| {
                *b + Vec3::new(
                    correction[(i, 3 * v)] as f32,
                    correction[(i, 3 * v + 1)] as f32,
                    correction[(i, 3 * v + 2)] as f32,
                )
            })
            .collect();
        edist_cm(&p, g)
    }))
}

/// Measures the curve on `data`: training on the first `shares` of its training bodies,
/// picking on its validation split, measuring on its test split. `progress` gets a line per
/// step.
pub fn measure(
    data: &Dataset,
    shares: &[f64],
    progress: &mut dyn FnMut(&str),
) -> Result<Curve, EvalError> {
    let bad = |m: String| Err(EvalError::Invalid(m));
    if shares.is_empty() || shares.iter().any(|s| !(*s > 0.0 && *s <= 1.0)) {
        return bad(format!("shares must lie in (0, 1]: {shares:?}"));
    }
    let split = Split::Test;
    progress("reading the training split");
    let train: Vec<Train> = data
        .samples(Split::Train)
        .map(|s| {
            let s = s?;
            Ok(Train {
                body: s.record.plan.body,
                x: features(&s.row.shape, &s.row.pose),
                d: s.row.displacement(),
            })
        })
        .collect::<Result<_, EvalError>>()?;
    let validation = read_split(data, Split::Val)?;
    let held = read_split(data, split)?;
    if train.is_empty() || validation.is_empty() || held.is_empty() {
        return bad(format!(
            "{} needs training, validation and {} drapes (it has {}, {} and {})",
            data.dir.display(),
            split.name(),
            train.len(),
            validation.len(),
            held.len()
        ));
    }
    let bodies: Vec<u64> = train
        .iter()
        .map(|t| t.body)
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    let n = data.statics.garment_vertices.len();
    let dqs_cm = mean(held.iter().map(|(_, m, g)| edist_cm(m, g)));
    let mut points = Vec::new();
    for &share in shares {
        let count = ((bodies.len() as f64 * share).round() as usize).clamp(1, bodies.len());
        let kept: BTreeSet<u64> = bodies[..count].iter().copied().collect();
        let used: Vec<&Train> = train.iter().filter(|t| kept.contains(&t.body)).collect();
        progress(&format!(
            "{count} bodies ({} drapes): linear map",
            used.len()
        ));
        let mut sums = Accumulator::new(used[0].x.len(), n);
        for t in &used {
            sums.add(&t.x, &t.d);
        }
        let Some((linear, _)) = learn::linear::fit(&sums, &validation) else {
            return bad("the linear map's normal equations cannot be solved".into());
        };
        // Residual of the linear fit on its own training drapes, [drapes, 3N].
        let mut residual = DMatrix::<f64>::zeros(used.len(), 3 * n);
        let mut train_cm = 0.0;
        for (i, t) in used.iter().enumerate() {
            let p = linear.displacement(&t.x);
            let mut err = 0.0;
            for (v, (pv, dv)) in p.iter().zip(&t.d).enumerate() {
                let r = *dv - *pv;
                err += r.length() as f64;
                residual[(i, 3 * v)] = r.x as f64;
                residual[(i, 3 * v + 1)] = r.y as f64;
                residual[(i, 3 * v + 2)] = r.z as f64;
            }
            train_cm += err / n as f64 * 100.0;
        }
        train_cm /= used.len() as f64;
        let base = |h: &[Labelled], m: &Linear| -> Vec<Vec<Vec3>> {
            h.iter().map(|(x, w, _)| m.predict(x, w)).collect()
        };
        let (val_base, held_base) = (base(&validation, &linear), base(&held, &linear));
        let linear_cm = mean(
            held.iter()
                .zip(&held_base)
                .map(|((_, _, g), p)| edist_cm(p, g)),
        );
        // The kernel on the standardised features.
        let xs: Vec<&[f64]> = used.iter().map(|t| t.x.as_slice()).collect();
        let st = Standard::new(&xs);
        let z: Vec<Vec<f64>> = xs.iter().map(|x| st.apply(x)).collect();
        let zv: Vec<Vec<f64>> = validation.iter().map(|(x, _, _)| st.apply(x)).collect();
        let zh: Vec<Vec<f64>> = held.iter().map(|(x, _, _)| st.apply(x)).collect();
        let d = st.keep.len();
        let (sq, sqv, sqh) = (
            squared_distances(&z, &z),
            squared_distances(&z, &zv),
            squared_distances(&z, &zh),
        );
        let mut best: Option<(f64, KernelRidge)> = None; // validation cm
        for &c in &KERNEL_WIDTHS {
            for &lk in &KERNEL_LAMBDAS {
                progress(&format!("{count} bodies: kernel width {c}, strength {lk}"));
                let Some(k) = KernelRidge::fit(&sq, d, c, lk) else {
                    continue;
                };
                let cm = edist_with(&validation, &val_base, &k.predict(&sqv, &residual));
                if best.as_ref().is_none_or(|(b, _)| cm < *b) {
                    best = Some((cm, k));
                }
            }
        }
        let Some((_, k)) = best else {
            return bad("the kernel system cannot be solved".into());
        };
        let kernel_cm = edist_with(&held, &held_base, &k.predict(&sqh, &residual));
        points.push(CurvePoint {
            share,
            bodies: count,
            drapes: used.len(),
            linear_lambda: linear.lambda,
            linear_train_cm: train_cm,
            linear_cm,
            kernel_width: k.width,
            kernel_lambda: k.lambda,
            kernel_cm,
        });
    }
    Ok(Curve {
        dataset: data.manifest.name.clone(),
        manifest_sha256: learn::run::manifest_sha256(&data.dir)?,
        split: split.name().to_string(),
        held_out: held.len(),
        dqs_cm,
        points,
    })
}

/// The curve as a chart: Edist against log2 of the training drapes, the linear map on its
/// training drapes and held out, the kernel map held out, and the 1 cm line.
pub fn chart(c: &Curve) -> crate::plot::Chart {
    use crate::plot::{Chart, PALETTE, Series};
    let x = |p: &CurvePoint| (p.drapes.max(1) as f64).log2();
    let line = |label: &str, k: usize, f: &dyn Fn(&CurvePoint) -> f64| Series {
        label: label.to_string(),
        points: c.points.iter().map(|p| (x(p), f(p))).collect(),
        colour: PALETTE[k],
    };
    let xs: Vec<f64> = c.points.iter().map(x).collect();
    let (x0, x1) = (
        xs.iter().cloned().fold(f64::MAX, f64::min).floor(),
        xs.iter().cloned().fold(f64::MIN, f64::max).ceil(),
    );
    let x1 = if x1 > x0 { x1 } else { x0 + 1.0 };
    let ys = c
        .points
        .iter()
        .flat_map(|p| [p.linear_train_cm, p.linear_cm, p.kernel_cm]);
    let (lo, hi) = ys.fold((1.0f64, 1.0f64), |(a, b), y| (a.min(y), b.max(y)));
    Chart {
        title: format!("{}: Edist on {} {} drapes", c.dataset, c.held_out, c.split),
        x_label: "log2 of the training drapes (10 = 1,024; 12 = 4,096)".into(),
        y_label: "Edist (cm)".into(),
        x_range: (x0, x1),
        y_range: ((lo * 10.0).floor() / 10.0, (hi * 10.0).ceil() / 10.0),
        series: vec![
            line("linear, held out", 0, &|p| p.linear_cm),
            line("linear, its training drapes", 2, &|p| p.linear_train_cm),
            line("linear + kernel, held out", 1, &|p| p.kernel_cm),
            Series {
                label: "1 cm".into(),
                points: vec![(x0, 1.0), (x1, 1.0)],
                colour: [150, 150, 150],
            },
        ],
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
}
