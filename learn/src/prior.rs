//! A prior under a network (`model.prior`): the network reads `M + prior` instead of the
//! DQS warp `M` and predicts what is left.
//!
//! - `linear`: the ridge map of [`crate::linear`] from the shape and the bones' rotation
//!   matrices to the displacement `G - M`;
//! - `kernel`: that map plus an RBF kernel ridge regression of what it leaves
//!   ([`crate::kernel`]).
//!
//! Both are fitted on the training split when a run starts, their strengths (and the
//! kernel's width) picked on the validation split. The training samples' prior is
//! cross-fitted ([`FOLDS`] folds by body: each sample's displacement comes from a fit
//! without its body, with the same picks), so the network trains on priors as wrong as the
//! ones it meets on new bodies; the run keeps the fit on all training samples in
//! `prior.safetensors` for inference.

use std::collections::{HashMap, HashSet};
use std::path::Path;

use dataset::config::Split;
use dataset::reader::Dataset;
use glam::{Quat, Vec3};

use crate::LearnError;
use crate::config::PriorKind;
use crate::kernel::{Fit, KernelMap, Row, cross_fit};
use crate::linear::{Accumulator, Linear, features, features_from_params, read_split};

/// Cross-fitting folds of [`Prior::fit`].
pub const FOLDS: u64 = 5;

/// A fitted prior map.
#[derive(Debug, Clone)]
pub enum PriorMap {
    /// The linear map.
    Linear(Linear),
    /// The linear map plus the kernel map of its residual.
    Kernel(KernelMap),
}

impl PriorMap {
    /// The predicted displacement of a sample with features `x`.
    pub fn displacement(&self, x: &[f64]) -> Vec<Vec3> {
        match self {
            PriorMap::Linear(m) => m.displacement(x),
            PriorMap::Kernel(m) => m.displacement(x),
        }
    }

    /// Garment vertices it predicts for.
    pub fn vertices(&self) -> usize {
        match self {
            PriorMap::Linear(m) => m.vertices(),
            PriorMap::Kernel(m) => m.vertices(),
        }
    }

    /// Features it takes ([`features`]: the shape and 9 per bone).
    pub fn features(&self) -> usize {
        match self {
            PriorMap::Linear(m) => m.weights().nrows() - 1,
            PriorMap::Kernel(m) => m.features(),
        }
    }

    /// The file's bytes.
    pub fn encode(&self) -> Vec<u8> {
        match self {
            PriorMap::Linear(m) => m.encode(),
            PriorMap::Kernel(m) => m.encode(),
        }
    }

    /// Reads a prior of `kind` (not `none`) from `path`.
    pub fn load(path: &Path, kind: PriorKind) -> Result<Self, LearnError> {
        Ok(match kind {
            PriorKind::Kernel => PriorMap::Kernel(KernelMap::load(path)?),
            _ => PriorMap::Linear(Linear::load(path)?),
        })
    }

    /// What it was fitted with, for logs.
    pub fn describe(&self) -> String {
        match self {
            PriorMap::Linear(m) => format!("strength {}", m.lambda),
            PriorMap::Kernel(m) => format!(
                "linear strength {}, kernel width {} and strength {}, {} training drapes, \
                 residual basis of rank {} keeping {:.2}% of its energy",
                m.linear.lambda,
                m.width,
                m.lambda,
                m.samples(),
                m.rank(),
                100.0 * m.kept
            ),
        }
    }
}

/// The prior of a run: the fit on all training samples, and for each training sample
/// the displacement of the fit without its body's fold.
#[derive(Debug, Clone)]
pub struct Prior {
    /// Fitted on every training sample (inference, validation).
    pub model: PriorMap,
    /// Training sample id to its cross-fitted displacement.
    pub held_out: HashMap<u64, Vec<Vec3>>,
    /// Validation Edist (cm) per choice tried, described.
    pub tried: Vec<(String, f64)>,
}

impl Prior {
    /// An inference-only prior (no training samples).
    pub fn of(model: PriorMap) -> Self {
        Self {
            model,
            held_out: HashMap::new(),
            tried: Vec::new(),
        }
    }

    /// Adds a sample's displacement to `garment`: its cross-fitted one if `id` is a
    /// training sample of the fit, else the full model's on `params`
    /// ([`features_from_params`]).
    pub fn add_to(&self, id: u64, params: &[f32], garment: &mut [Vec3]) {
        let full;
        let d = match self.held_out.get(&id) {
            Some(d) => d,
            None => {
                full = self.model.displacement(&features_from_params(params));
                &full
            }
        };
        for (m, d) in garment.iter_mut().zip(d) {
            *m += *d;
        }
    }

    /// Fits a prior of `kind` (not `none`) on `data`'s training split (only `subset` if
    /// given), its picks made on the validation split. The training samples are read once
    /// (one shard at a time) and kept in memory.
    pub fn fit(
        data: &Dataset,
        subset: Option<&HashSet<u64>>,
        kind: PriorKind,
        progress: bool,
    ) -> Result<Self, LearnError> {
        let bar = crate::run::progress(progress, data.count(Split::Train) as u64);
        bar.set_message(format!("{} prior: reading the training split", kind.name()));
        let mut ids = Vec::new();
        let mut rows = Vec::new();
        for s in data.samples(Split::Train) {
            let s = s?;
            bar.inc(1);
            if subset.is_none_or(|k| k.contains(&s.row.id)) {
                ids.push(s.row.id);
                rows.push(Row {
                    body: s.record.plan.body,
                    x: features(&s.row.shape, &s.row.pose),
                    d: s.row.displacement(),
                });
            }
        }
        bar.finish_and_clear();
        if rows.is_empty() {
            return Err(LearnError::Mismatch(format!(
                "{} has no training samples to fit the {} prior on",
                data.dir.display(),
                kind.name()
            )));
        }
        let validation = read_split(data, Split::Val)?;
        let unsolvable = || {
            LearnError::Mismatch(format!(
                "the {} prior's equations cannot be solved",
                kind.name()
            ))
        };
        let (model, held, tried) = if kind == PriorKind::Kernel {
            let say = |m: &str| {
                if progress {
                    eprintln!("kernel prior: {m}");
                }
            };
            let refs: Vec<&Row> = rows.iter().collect();
            let fit = Fit::new(&refs, &validation, None, &mut |m| say(m)).ok_or_else(unsolvable)?;
            let tried = fit
                .tried
                .iter()
                .map(|(c, l, e)| (format!("width {c}, strength {l}"), *e))
                .collect();
            let picks = fit.picks();
            say("the map at rank 256 for one drape at a time");
            let map = fit.map(crate::kernel::RANK);
            drop(fit);
            let held = cross_fit(&rows, picks, FOLDS, &mut |m| say(m))
                .map_err(|e| LearnError::Mismatch(format!("the kernel prior: {e}")))?;
            (PriorMap::Kernel(map), held, tried)
        } else {
            let n = data.statics.garment_vertices.len();
            let width = features(&[0.0; 9], &vec![Quat::IDENTITY; data.statics.bones]).len();
            let mut total = Accumulator::new(width, n);
            let mut folds: Vec<Accumulator> =
                (0..FOLDS).map(|_| Accumulator::new(width, n)).collect();
            for r in &rows {
                total.add(&r.x, &r.d);
                folds[(r.body % FOLDS) as usize].add(&r.x, &r.d);
            }
            let (model, tried) = crate::linear::fit(&total, &validation).ok_or_else(unsolvable)?;
            // A fold holding every sample has nothing to fit without it (an in-sample
            // prior would be far better on the training drapes than on new bodies).
            if let Some(f) = folds.iter().position(|f| f.samples() == total.samples()) {
                return Err(LearnError::Mismatch(format!(
                    "the linear prior: all {} training drapes come from bodies of one fold \
                     (body index % {FOLDS} = {f}): cross-fitting needs bodies in two folds",
                    total.samples()
                )));
            }
            let fold_models: Vec<Option<Linear>> = folds
                .iter()
                .map(|f| (f.samples() > 0).then(|| total.without(f).solve(model.lambda)))
                .map(|m| m.map(|m| m.ok_or_else(unsolvable)).transpose())
                .collect::<Result<_, _>>()?;
            let held = rows
                .iter()
                .map(|r| {
                    fold_models[(r.body % FOLDS) as usize]
                        .as_ref()
                        .expect("the fold of a row has rows")
                        .displacement(&r.x)
                })
                .collect();
            let tried = tried
                .iter()
                .map(|(l, e)| (format!("strength {l}"), *e))
                .collect();
            (PriorMap::Linear(model), held, tried)
        };
        Ok(Self {
            model,
            held_out: ids.into_iter().zip(held).collect(),
            tried,
        })
    }
}
