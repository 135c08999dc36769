//! The linear baseline: a ridge regression from a sample's shape and pose to its whole
//! displacement `G - M`, fitted in closed form on the training split.
//!
//! Features `x`: the 9 shape parameters and, per bone, the 9 entries of its local rotation
//! matrix (rotation matrices, not quaternions: they are smooth in the rotation and have no
//! sign ambiguity), then a constant 1. Outputs: the `3 N` coordinates of `G - M`. The
//! weights solve
//!
//! `W = argmin sum_i |d_i - W^T x_i|^2 + lambda sum_j s_j^2 |W_j|^2`,
//!
//! with `s_j` the training standard deviation of feature `j` (the bias unpenalised): ridge
//! regression on standardised features, written on the raw ones, so one pass over the
//! training split accumulates `X^T X` and `X^T D` and nothing is read twice. A feature that
//! never varies gets weight 0. `lambda` is picked from [`LAMBDAS`] by the validation split's
//! Edist (not the split being evaluated).
//!
//! Two uses:
//! - **a baseline** in `drape eval` (`eval::evaluate`): it has per-vertex parameters (the
//!   network must find a vertex from its warped coordinates) and no notion of the body's
//!   surface, so it says how much of the drape is a smooth function of the shape and pose
//!   parameters alone;
//! - **a prior** under a network (`model.prior = "linear"`, [`crate::prior`]): the network
//!   reads `M + linear` instead of the DQS warp `M` and predicts what is left.

use std::path::Path;

use dataset::config::Split;
use dataset::reader::Dataset;
use glam::{Mat3, Quat, Vec3};
use nalgebra::{DMatrix, DVector};

use crate::LearnError;

/// Ridge strengths tried on the validation split.
pub const LAMBDAS: [f64; 7] = [0.3, 1.0, 3.0, 10.0, 30.0, 100.0, 300.0];

/// The strength used when there is no validation sample to choose with.
pub const DEFAULT_LAMBDA: f64 = 10.0;

/// The feature vector of a shape and pose, without the constant.
pub fn features(shape: &[f32], pose: &[Quat]) -> Vec<f64> {
    let mut x: Vec<f64> = shape.iter().map(|&v| v as f64).collect();
    for q in pose {
        let m = Mat3::from_quat(q.normalize());
        x.extend(m.to_cols_array().iter().map(|&v| v as f64));
    }
    x
}

/// [`features`] of a network's shape-and-pose vector ([`crate::data::body_params`]: the
/// shape parameters, then x, y, z, w per bone).
pub fn features_from_params(params: &[f32]) -> Vec<f64> {
    let shape = dataset::shard::SHAPE_FIELDS.len();
    let pose: Vec<Quat> = params[shape..]
        .chunks_exact(4)
        .map(|q| Quat::from_xyzw(q[0], q[1], q[2], q[3]))
        .collect();
    features(&params[..shape], &pose)
}

/// Sums over the training split: `X^T X`, `X^T D`, and the features' first two moments.
#[derive(Debug, Clone)]
pub struct Accumulator {
    /// Features plus the constant.
    width: usize,
    /// `3 N`.
    outputs: usize,
    xtx: Vec<f64>,
    xty: Vec<f64>,
    samples: usize,
}

impl Accumulator {
    /// Empty sums for `features` features and garments of `vertices` vertices.
    pub fn new(features: usize, vertices: usize) -> Self {
        let width = features + 1;
        Self {
            width,
            outputs: 3 * vertices,
            xtx: vec![0.0; width * width],
            xty: vec![0.0; width * 3 * vertices],
            samples: 0,
        }
    }

    /// Adds one training sample: its features and its displacement `G - M`.
    pub fn add(&mut self, x: &[f64], displacement: &[Vec3]) {
        assert_eq!(x.len() + 1, self.width, "feature count");
        assert_eq!(3 * displacement.len(), self.outputs, "vertex count");
        let mut a = x.to_vec();
        a.push(1.0);
        let d: Vec<f64> = displacement
            .iter()
            .flat_map(|v| [v.x as f64, v.y as f64, v.z as f64])
            .collect();
        for (j, &aj) in a.iter().enumerate() {
            for (k, &ak) in a.iter().enumerate() {
                self.xtx[j * self.width + k] += aj * ak;
            }
            let row = &mut self.xty[j * self.outputs..(j + 1) * self.outputs];
            for (r, &dk) in row.iter_mut().zip(&d) {
                *r += aj * dk;
            }
        }
        self.samples += 1;
    }

    /// Training samples added.
    pub fn samples(&self) -> usize {
        self.samples
    }

    /// The sums of the samples in `self` but not in `part` (a subset of them).
    pub fn without(&self, part: &Accumulator) -> Accumulator {
        let minus = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(x, y)| x - y).collect();
        Accumulator {
            width: self.width,
            outputs: self.outputs,
            xtx: minus(&self.xtx, &part.xtx),
            xty: minus(&self.xty, &part.xty),
            samples: self.samples - part.samples,
        }
    }

    /// The weights for one `lambda`; `None` if the system cannot be solved.
    pub fn solve(&self, lambda: f64) -> Option<Linear> {
        let (w, n) = (self.width, self.samples as f64);
        if self.samples == 0 {
            return None;
        }
        let mut a = DMatrix::from_row_slice(w, w, &self.xtx);
        // Feature variances from the sums (the last row holds the plain sums).
        for j in 0..w - 1 {
            let mean = self.xtx[j * w + w - 1] / n;
            let var = (self.xtx[j * w + j] / n - mean * mean).max(0.0);
            let penalty = if var > 1e-10 { lambda * var } else { 1e6 * n };
            a[(j, j)] += penalty;
        }
        let chol = a.cholesky()?;
        let b = DMatrix::from_row_slice(w, self.outputs, &self.xty);
        let weights = chol.solve(&b);
        Some(Linear {
            width: w,
            outputs: self.outputs,
            weights,
            lambda,
        })
    }
}

/// A fitted linear baseline.
#[derive(Debug, Clone)]
pub struct Linear {
    width: usize,
    outputs: usize,
    /// `[features + 1, 3 N]`.
    weights: DMatrix<f64>,
    /// The ridge strength it was fitted with.
    pub lambda: f64,
}

impl Linear {
    /// The predicted displacement of a sample with features `x`.
    pub fn displacement(&self, x: &[f64]) -> Vec<Vec3> {
        assert_eq!(x.len() + 1, self.width, "feature count");
        let mut a = x.to_vec();
        a.push(1.0);
        let y = self.weights.tr_mul(&DVector::from_vec(a));
        (0..self.outputs / 3)
            .map(|i| Vec3::new(y[3 * i] as f32, y[3 * i + 1] as f32, y[3 * i + 2] as f32))
            .collect()
    }

    /// The predicted garment: `M` plus the predicted displacement.
    pub fn predict(&self, x: &[f64], warped: &[Vec3]) -> Vec<Vec3> {
        warped
            .iter()
            .zip(self.displacement(x))
            .map(|(m, d)| *m + d)
            .collect()
    }
}

impl Linear {
    /// Safetensors bytes: `weights` (F64 `[features + 1, 3 N]`) and the strength.
    pub fn encode(&self) -> Vec<u8> {
        let mut bytes = Vec::with_capacity(self.width * self.outputs * 8);
        for j in 0..self.width {
            for k in 0..self.outputs {
                bytes.extend_from_slice(&self.weights[(j, k)].to_le_bytes());
            }
        }
        sim::io::safetensors_bytes(
            &[(
                "weights",
                safetensors::Dtype::F64,
                vec![self.width, self.outputs],
                bytes,
            )],
            &serde_json::json!({"format": "drape-linear/1", "lambda": self.lambda}),
        )
    }

    /// Reads [`Linear::encode`]'s file.
    pub fn load(path: &Path) -> Result<Self, LearnError> {
        let (meta, mut t) = read_matrices(
            path,
            "drape-linear/1",
            &[("weights", safetensors::Dtype::F64)],
        )?;
        let (shape, bytes) = t.remove(0);
        Ok(Self {
            width: shape[0],
            outputs: shape[1],
            weights: DMatrix::from_row_slice(shape[0], shape[1], &f64s(&bytes)),
            lambda: meta["lambda"].as_f64().unwrap_or(f64::NAN),
        })
    }

    /// A model of the right size whose every weight is zero (for timing an untrained
    /// network's inputs: the cost does not depend on the weights).
    pub fn zeros(features: usize, vertices: usize) -> Self {
        Self {
            width: features + 1,
            outputs: 3 * vertices,
            weights: DMatrix::zeros(features + 1, 3 * vertices),
            lambda: 0.0,
        }
    }

    /// Garment vertices it predicts for.
    pub fn vertices(&self) -> usize {
        self.outputs / 3
    }

    /// The weights, `[features + 1, 3 N]`.
    pub fn weights(&self) -> &DMatrix<f64> {
        &self.weights
    }

    /// A model of these weights (`[features + 1, 3 N]`) fitted with strength `lambda`.
    pub fn from_weights(weights: DMatrix<f64>, lambda: f64) -> Self {
        Self {
            width: weights.nrows(),
            outputs: weights.ncols(),
            weights,
            lambda,
        }
    }
}

/// A matrix file's tensors: its drape metadata (which must name `format`) and, per wanted
/// name and type, a 2-d tensor's shape and little-endian bytes; a clear error otherwise.
pub(crate) type Matrices = (serde_json::Value, Vec<(Vec<usize>, Vec<u8>)>);

/// Reads a [`Matrices`] file (the linear and kernel maps' `prior.safetensors`).
pub(crate) fn read_matrices(
    path: &Path,
    format: &str,
    wanted: &[(&str, safetensors::Dtype)],
) -> Result<Matrices, LearnError> {
    let bad = |reason: String| LearnError::Checkpoint {
        path: path.to_path_buf(),
        reason,
    };
    let bytes = std::fs::read(path).map_err(|source| LearnError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let st = safetensors::SafeTensors::deserialize(&bytes).map_err(|e| bad(e.to_string()))?;
    let (_, header) =
        safetensors::SafeTensors::read_metadata(&bytes).map_err(|e| bad(e.to_string()))?;
    let meta: serde_json::Value = header
        .metadata()
        .as_ref()
        .and_then(|m| m.get("drape"))
        .and_then(|j| serde_json::from_str(j).ok())
        .ok_or_else(|| bad("no drape metadata".into()))?;
    if meta["format"] != format {
        return Err(bad(format!("format {}, expected {format}", meta["format"])));
    }
    let tensors = wanted
        .iter()
        .map(|&(name, dtype)| {
            let t = st.tensor(name).map_err(|e| bad(e.to_string()))?;
            if t.dtype() != dtype || t.shape().len() != 2 {
                return Err(bad(format!("{name}: expected a 2-d {dtype:?} tensor")));
            }
            Ok((t.shape().to_vec(), t.data().to_vec()))
        })
        .collect::<Result<_, _>>()?;
    Ok((meta, tensors))
}

/// Little-endian F64 bytes as numbers.
pub(crate) fn f64s(bytes: &[u8]) -> Vec<f64> {
    bytes
        .chunks_exact(8)
        .map(|b| f64::from_le_bytes(b.try_into().expect("8 bytes")))
        .collect()
}

/// A fitted model and, per strength tried, its validation Edist (cm).
pub type Fitted = (Linear, Vec<(f64, f64)>);

/// A sample as the fits measure it: its features, warped garment M and simulated G.
pub type Labelled = (Vec<f64>, Vec<Vec3>, Vec<Vec3>);

/// Every sample of `split` as [`Labelled`] (read one shard at a time).
pub fn read_split(data: &Dataset, split: Split) -> Result<Vec<Labelled>, dataset::DatasetError> {
    data.samples(split)
        .map(|s| {
            s.map(|s| {
                let r = s.row;
                (features(&r.shape, &r.pose), r.warped, r.draped)
            })
        })
        .collect()
}

/// [`fit`] with `data`'s validation split.
pub fn fit_on_validation(
    sums: &Accumulator,
    data: &Dataset,
) -> Result<Option<Fitted>, dataset::DatasetError> {
    Ok(fit(sums, &read_split(data, Split::Val)?))
}

/// Fits for every strength of [`LAMBDAS`] and keeps the one with the lowest mean Edist on
/// `validation` (features, warped, simulated); [`DEFAULT_LAMBDA`] without validation
/// samples. Returns the model and, per strength tried, its validation Edist (cm).
pub fn fit(sums: &Accumulator, validation: &[Labelled]) -> Option<Fitted> {
    if validation.is_empty() {
        return sums.solve(DEFAULT_LAMBDA).map(|m| (m, Vec::new()));
    }
    let mut tried = Vec::new();
    let mut best: Option<(f64, Linear)> = None;
    for &lambda in &LAMBDAS {
        let Some(model) = sums.solve(lambda) else {
            continue;
        };
        let edist = validation
            .iter()
            .map(|(x, m, g)| {
                let p = model.predict(x, m);
                p.iter()
                    .zip(g)
                    .map(|(a, b)| a.distance(*b) as f64)
                    .sum::<f64>()
                    / g.len() as f64
            })
            .sum::<f64>()
            / validation.len() as f64
            * 100.0;
        tried.push((lambda, edist));
        if best.as_ref().is_none_or(|(e, _)| edist < *e) {
            best = Some((edist, model));
        }
    }
    best.map(|(_, m)| (m, tried))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(angle: f32) -> Vec<Quat> {
        vec![
            Quat::from_rotation_x(angle),
            Quat::from_rotation_y(0.5 * angle),
        ]
    }

    /// Displacements that are an exact linear function of the features are recovered
    /// (a weak ridge), on samples not used for the fit.
    #[test]
    fn recovers_a_linear_map() {
        let n = 4;
        let truth = |x: &[f64]| -> Vec<Vec3> {
            (0..n)
                .map(|i| {
                    let i = i as f64;
                    Vec3::new(
                        (0.01 * x[0] + 0.002 * i * x[13] - 0.003) as f32,
                        (0.02 * x[1] * (i + 1.0) + 0.01 * x[14]) as f32,
                        (-0.01 * x[2] + 0.004 * x[18] - 0.002 * x[20]) as f32,
                    )
                })
                .collect()
        };
        let sample = |k: usize| {
            let s: Vec<f32> = (0..9)
                .map(|j| ((k * 7 + j * 3) % 11) as f32 / 10.0)
                .collect();
            features(&s, &pose(0.1 * k as f32 - 0.8))
        };
        let mut acc = Accumulator::new(sample(0).len(), n);
        for k in 0..40 {
            let x = sample(k);
            acc.add(&x, &truth(&x));
        }
        let model = acc.solve(1e-6).expect("solvable");
        for k in [3, 41, 45] {
            let x = sample(k);
            for (p, t) in model.displacement(&x).iter().zip(truth(&x)) {
                assert!(p.distance(t) < 1e-5, "{p} against {t}");
            }
        }
    }

    /// A strong ridge shrinks towards the training mean displacement (the mean-residual
    /// baseline); a constant feature gets no weight.
    #[test]
    fn strong_ridge_gives_the_mean() {
        let mut acc = Accumulator::new(features(&[0.5; 9], &pose(0.0)).len(), 1);
        let mut mean = Vec3::ZERO;
        for k in 0..10 {
            let x = features(&[0.1 * k as f32; 9], &pose(0.05 * k as f32));
            let d = Vec3::new(0.01 * k as f32, -0.02, 0.003 * (k * k) as f32);
            mean += d / 10.0;
            acc.add(&x, &[d]);
        }
        let model = acc.solve(1e9).expect("solvable");
        let p = model.displacement(&features(&[0.9; 9], &pose(0.7)))[0];
        assert!(p.distance(mean) < 1e-4, "{p} against the mean {mean}");
    }

    /// The network's parameter vector gives the same features; the file keeps the weights.
    #[test]
    fn params_features_and_file() {
        let shape = [0.1f32, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9];
        let p = pose(0.4);
        let params = crate::data::body_params(&shape, &p);
        assert_eq!(features_from_params(&params), features(&shape, &p));
        let mut acc = Accumulator::new(features(&shape, &p).len(), 2);
        for k in 0..5 {
            let x = features(&shape, &pose(0.1 * k as f32));
            acc.add(
                &x,
                &[Vec3::splat(0.01 * k as f32), Vec3::new(0.0, -0.02, 0.003)],
            );
        }
        let model = acc.solve(3.0).expect("solvable");
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("prior.safetensors");
        std::fs::write(&path, model.encode()).unwrap();
        let back = Linear::load(&path).unwrap();
        assert_eq!(back.lambda, 3.0);
        let x = features(&shape, &pose(0.25));
        assert_eq!(back.displacement(&x), model.displacement(&x));
        std::fs::write(&path, b"not a safetensors file").unwrap();
        assert!(Linear::load(&path).is_err());
    }

    /// Removing a part's sums leaves the sums of the rest.
    #[test]
    fn without_removes_a_part() {
        let x = |k: usize| features(&[0.1 * k as f32; 9], &pose(0.1 * k as f32));
        let d = |k: usize| vec![Vec3::new(0.01 * k as f32, 0.0, 0.002)];
        let (mut all, mut part, mut rest) = (
            Accumulator::new(x(0).len(), 1),
            Accumulator::new(x(0).len(), 1),
            Accumulator::new(x(0).len(), 1),
        );
        for k in 0..8 {
            all.add(&x(k), &d(k));
            if k % 3 == 0 {
                part.add(&x(k), &d(k))
            } else {
                rest.add(&x(k), &d(k))
            }
        }
        let a = all.without(&part).solve(1.0).unwrap();
        let b = rest.solve(1.0).unwrap();
        let p = (a.displacement(&x(9))[0], b.displacement(&x(9))[0]);
        assert!(p.0.distance(p.1) < 1e-6, "{p:?}");
    }

    /// The validation split picks the strength: with noise-free data the weakest ridge.
    #[test]
    fn validation_picks_lambda() {
        let mut acc = Accumulator::new(features(&[0.5; 9], &pose(0.0)).len(), 1);
        let f = |k: usize| features(&[0.1 * (k % 10) as f32; 9], &pose(0.03 * k as f32));
        let d = |x: &[f64]| vec![Vec3::new((0.05 * x[0]) as f32, (0.1 * x[13]) as f32, 0.0)];
        for k in 0..30 {
            let x = f(k);
            acc.add(&x, &d(&x));
        }
        let val: Vec<_> = (30..34)
            .map(|k| {
                let x = f(k);
                (x.clone(), vec![Vec3::ZERO], d(&x))
            })
            .collect();
        let (model, tried) = fit(&acc, &val).expect("fitted");
        assert_eq!(tried.len(), LAMBDAS.len());
        assert_eq!(model.lambda, LAMBDAS[0]);
        assert!(
            tried.windows(2).all(|w| w[0].1 <= w[1].1 + 1e-9),
            "{tried:?}"
        );
    }
}
