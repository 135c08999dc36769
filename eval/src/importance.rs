//! `drape importance`: how much a trained network relies on each of its body inputs
//! (permutation importance).
//!
//! The test drapes are read in batches. Each batch is draped by the network once as it
//! is, and once more per body input, with that input taken from the next drape of the
//! batch (another body shape and pose; the last drape reads the first's) while everything
//! else, the DQS-warped garment above all, stays the drape's own
//! ([`learn::model::GarNet::forward_swapped`]). The inputs: the global body feature (the
//! PointNet stream's max-pooled feature; the shape-and-pose vector of
//! GarNet-Global-Params), GarNet-Local's local body features of each garment vertex, the
//! per-vertex body offsets (`model.body_offsets`), and all of them. If Edist hardly
//! rises when an input belongs to another body, the network has learned little from it;
//! the rise against the drape's own inputs is paired per drape.

use std::path::Path;

use dataset::config::Split;
use dataset::reader::Dataset;
use dataset::shard::Row;
use learn::config::{ModelConfig, Variant};
use learn::model::Swap;
use learn::predict::Predictor;
use serde::Serialize;

use crate::compare::{Paired, paired};
use crate::evaluate::EvalError;
use crate::metrics::{edist_cm, enorm_deg, mean_std};

/// Options of the measurement.
#[derive(Debug, Clone)]
pub struct ImportanceOptions {
    /// Split to take drapes from.
    pub split: Split,
    /// At most this many drapes (the split's first), all of them by default.
    pub limit: Option<usize>,
    /// Drapes per batch, among which the swapped inputs rotate (at least 2).
    pub batch: usize,
    /// Show a progress bar.
    pub progress: bool,
}

impl ImportanceOptions {
    /// Fails on a batch below 2 (a drape cannot take an input from itself) or a limit of
    /// fewer than 2 drapes.
    pub fn validate(&self) -> Result<(), EvalError> {
        if self.batch < 2 {
            return Err(EvalError::Invalid(format!(
                "batch = {}: inputs are swapped among the drapes of a batch, give at least 2",
                self.batch
            )));
        }
        if self.limit.is_some_and(|n| n < 2) {
            return Err(EvalError::Invalid(
                "limit: swapping inputs needs at least 2 drapes".into(),
            ));
        }
        Ok(())
    }
}

/// The inputs a network of `model` can have swapped, with their names: none (the
/// reference), then one entry per body input, then all of them together when there are
/// two or more.
pub fn swaps(model: &ModelConfig) -> Vec<(&'static str, Swap)> {
    let mut out = vec![("none", Swap::NONE)];
    out.push((
        if model.variant == Variant::GlobalParams {
            "shape and pose parameters"
        } else {
            "global body feature"
        },
        Swap {
            global: true,
            ..Swap::NONE
        },
    ));
    if model.variant == Variant::Local {
        let one = Swap {
            local: true,
            ..Swap::NONE
        };
        out.push(("local body features", one));
    }
    if model.body_offsets {
        let one = Swap {
            offsets: true,
            ..Swap::NONE
        };
        out.push(("body offsets", one));
    }
    if out.len() > 2 {
        let all = Swap {
            global: true,
            local: model.variant == Variant::Local,
            offsets: model.body_offsets,
        };
        out.push(("all body inputs", all));
    }
    out
}

/// One way of draping the test set: which inputs came from another drape, and how far
/// the network landed from the simulator.
#[derive(Debug, Clone, Serialize)]
pub struct Entry {
    /// The inputs taken from another drape ("none" for the network as it is).
    pub swapped: String,
    /// Edist (cm): mean and standard deviation over drapes.
    pub edist_cm: (f64, f64),
    /// Enorm (degrees): mean and standard deviation.
    pub enorm_deg: (f64, f64),
    /// Edist against "none", paired per drape (this entry is A, "none" B); absent for
    /// "none" itself.
    pub edist_rise: Option<Paired>,
    /// Enorm against "none", paired per drape.
    pub enorm_rise: Option<Paired>,
}

/// The whole measurement.
#[derive(Debug, Clone, Serialize)]
pub struct ImportanceReport {
    /// The run folder.
    pub run: String,
    /// Its variant's name.
    pub variant: String,
    /// Dataset name.
    pub dataset: String,
    /// Split measured.
    pub split: String,
    /// Drapes measured.
    pub drapes: usize,
    /// Drapes per batch.
    pub batch: usize,
    /// One per way of draping, "none" first.
    pub entries: Vec<Entry>,
}

/// Batches of `n` drapes of at most `batch` each, none of a single drape: the sizes.
pub fn batch_sizes(n: usize, batch: usize) -> Vec<usize> {
    let mut sizes = vec![batch; n / batch];
    match n % batch {
        0 => {}
        1 if !sizes.is_empty() => *sizes.last_mut().unwrap() += 1,
        r => sizes.push(r),
    }
    sizes
}

/// Measures `run`'s reliance on its body inputs on `data`'s split.
pub fn measure(
    run: &Path,
    data: &Dataset,
    opts: &ImportanceOptions,
) -> Result<ImportanceReport, EvalError> {
    opts.validate()?;
    let net = Predictor::open(run, &data.statics)?;
    let variant = net.config.model.variant;
    let n = data.count(opts.split).min(opts.limit.unwrap_or(usize::MAX));
    if n < 2 {
        return Err(EvalError::Invalid(format!(
            "{} has {n} converged {} samples; swapping inputs needs at least 2",
            data.dir.display(),
            opts.split.name()
        )));
    }
    let ways = swaps(&net.config.model);
    let triangles = &data.statics.garment_triangles;
    // Per way, per drape: (Edist, Enorm).
    let mut figures: Vec<Vec<(f64, f64)>> = vec![Vec::with_capacity(n); ways.len()];
    let bar = learn::run::progress(opts.progress, n as u64);
    bar.set_message(format!("{}: swapping body inputs", variant.paper_name()));
    let mut samples = data.samples(opts.split).take(n);
    for size in batch_sizes(n, opts.batch) {
        let rows: Vec<Row> = samples
            .by_ref()
            .take(size)
            .map(|s| s.map(|s| s.row))
            .collect::<Result<_, _>>()?;
        let prepared: Vec<_> = rows.iter().map(|r| net.prepare_row(r)).collect();
        let refs: Vec<_> = prepared.iter().collect();
        for (w, (_, swap)) in ways.iter().enumerate() {
            let out = net.predict_swapped(&refs, *swap);
            for (pred, row) in out.iter().zip(&rows) {
                figures[w].push((
                    edist_cm(pred, &row.draped),
                    enorm_deg(pred, &row.draped, triangles),
                ));
            }
        }
        bar.inc(size as u64);
    }
    bar.finish_and_clear();
    let base = &figures[0];
    let entries = ways
        .iter()
        .zip(&figures)
        .enumerate()
        .map(|(w, ((name, _), f))| {
            let edist: Vec<f64> = f.iter().map(|x| x.0).collect();
            let enorm: Vec<f64> = f.iter().map(|x| x.1).collect();
            let rise = |pick: fn(&(f64, f64)) -> f64, figure: &str| {
                (w > 0)
                    .then(|| {
                        let pairs: Vec<(f64, f64)> = f
                            .iter()
                            .zip(base)
                            .map(|(a, b)| (pick(a), pick(b)))
                            .collect();
                        paired(figure, &pairs)
                    })
                    .flatten()
            };
            Entry {
                swapped: name.to_string(),
                edist_cm: mean_std(&edist),
                enorm_deg: mean_std(&enorm),
                edist_rise: rise(|x| x.0, "edist_cm"),
                enorm_rise: rise(|x| x.1, "enorm_deg"),
            }
        })
        .collect();
    Ok(ImportanceReport {
        run: run.display().to_string(),
        variant: variant.paper_name().to_string(),
        dataset: data.manifest.name.clone(),
        split: opts.split.name().to_string(),
        drapes: n,
        batch: opts.batch,
        entries,
    })
}

impl ImportanceReport {
    /// The report as a Markdown table.
    pub fn table(&self) -> String {
        let mut s = format!(
            "{} ({}) on {} drapes of {}'s {} split, inputs swapped within batches of {}\n\n\
             | inputs from another drape | Edist cm | Enorm deg | Edist rise cm (paired) | \
             drapes worse | Enorm rise deg |\n|---|---|---|---|---|---|\n",
            self.run, self.variant, self.drapes, self.dataset, self.split, self.batch
        );
        for e in &self.entries {
            let rise = |p: &Option<Paired>| match p {
                Some(p) => format!("{:+.3} ± {:.3}", p.mean_difference, p.standard_error),
                None => "-".to_string(),
            };
            let worse = e.edist_rise.as_ref().map_or("-".to_string(), |p| {
                format!("{} of {}", p.b_lower, p.samples)
            });
            s.push_str(&format!(
                "| {} | {:.3} ± {:.2} | {:.2} ± {:.2} | {} | {} | {} |\n",
                e.swapped,
                e.edist_cm.0,
                e.edist_cm.1,
                e.enorm_deg.0,
                e.enorm_deg.1,
                rise(&e.edist_rise),
                worse,
                rise(&e.enorm_rise),
            ));
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn batches_never_hold_a_single_drape() {
        assert_eq!(batch_sizes(32, 16), vec![16, 16]);
        assert_eq!(batch_sizes(33, 16), vec![16, 17]);
        assert_eq!(batch_sizes(34, 16), vec![16, 16, 2]);
        assert_eq!(batch_sizes(5, 16), vec![5]);
        assert_eq!(batch_sizes(2, 2), vec![2]);
        assert_eq!(batch_sizes(3, 2), vec![3]);
        for n in 2..60 {
            for b in 2..9 {
                let s = batch_sizes(n, b);
                assert_eq!(s.iter().sum::<usize>(), n, "{n} {b}");
                assert!(s.iter().all(|&k| k >= 2 && k <= b + 1), "{n} {b}: {s:?}");
            }
        }
    }

    #[test]
    fn each_body_input_has_its_way() {
        let names = |variant, body_offsets| {
            let c = ModelConfig {
                variant,
                body_offsets,
                ..ModelConfig::default()
            };
            swaps(&c).iter().map(|x| x.0).collect::<Vec<_>>()
        };
        assert_eq!(
            names(Variant::Local, false),
            [
                "none",
                "global body feature",
                "local body features",
                "all body inputs"
            ]
        );
        assert_eq!(
            names(Variant::Local, true),
            [
                "none",
                "global body feature",
                "local body features",
                "body offsets",
                "all body inputs"
            ]
        );
        assert_eq!(
            names(Variant::Global, false),
            ["none", "global body feature"]
        );
        assert_eq!(
            names(Variant::GlobalParams, false),
            ["none", "shape and pose parameters"]
        );
        let c = ModelConfig {
            variant: Variant::Global,
            body_offsets: true,
            ..ModelConfig::default()
        };
        let all = swaps(&c).last().unwrap().1;
        assert!(all.global && all.offsets && !all.local);
        assert_eq!(swaps(&c)[0].1, Swap::NONE);
    }

    #[test]
    fn a_batch_below_two_is_refused() {
        let o = ImportanceOptions {
            split: Split::Test,
            limit: None,
            batch: 1,
            progress: false,
        };
        assert!(o.validate().unwrap_err().to_string().contains("at least 2"));
    }
}
