//! `drape data sensitivity`: how far a dataset's drapes move when the simulation is
//! disturbed by a detail no network input carries.
//!
//! For each sample the simulator redrapes it exactly as the dataset did (the same body
//! morph, simulator config and garment model) except that the starting template
//! positions are moved by independent uniform offsets of at most `amplitude` metres per
//! coordinate (a micrometre by default, far below anything visible or any input of a
//! network). Cloth buckling is a bifurcation: where a fold could form left or right, such
//! a disturbance can pick the other branch. Edist between the disturbed drape and the
//! dataset's then measures the part of the target that the network's inputs (body shape,
//! pose, template) do not determine.
//!
//! How to read it: if the disturbed drape and the dataset's were two independent draws of
//! the same spread, a network predicting their mean would be off by about Edist / sqrt(2)
//! (exact for a Gaussian spread); a network trained with L_vert on such targets cannot do
//! better on average. With `--model` the network's own Edist on the same samples is
//! measured beside it.

use dataset::config::Split;
use dataset::reader::Dataset;
use dataset::shard::Row;
use dataset::wardrobe::Wardrobe;
use glam::Vec3;
use learn::predict::Predictor;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use sim::body::BodyModel;
use sim::cloth::drape;

use crate::evaluate::EvalError;
use crate::metrics::{edist_cm, enorm_deg, mean, mean_std, median, vertex_errors};
use crate::speed::Redraper;

/// Options of the measurement.
#[derive(Debug, Clone)]
pub struct SensitivityOptions {
    /// Samples redraped (the first converged ones of the split).
    pub samples: usize,
    /// Split to take samples from.
    pub split: Split,
    /// Largest offset of a starting position per coordinate (m), one redrape per value.
    pub amplitudes: Vec<f32>,
    /// Seed of the offsets (sample `id` and amplitude index are mixed in).
    pub seed: u64,
}

impl SensitivityOptions {
    /// Fails on no samples, an empty amplitude list or an amplitude outside (0, 1 cm].
    pub fn validate(&self) -> Result<(), EvalError> {
        if self.samples == 0 {
            return Err(EvalError::Invalid("samples = 0: redrape at least 1".into()));
        }
        if self.amplitudes.is_empty() {
            return Err(EvalError::Invalid("give at least one amplitude".into()));
        }
        if let Some(a) = self
            .amplitudes
            .iter()
            .find(|a| !(a.is_finite() && **a > 0.0 && **a <= 0.01))
        {
            return Err(EvalError::Invalid(format!(
                "amplitude {a} m: give values above 0 and at most 0.01 m"
            )));
        }
        Ok(())
    }
}

/// One redrape of one sample.
#[derive(Debug, Clone, Serialize)]
pub struct Redrape {
    /// Largest starting offset per coordinate (m).
    pub amplitude: f32,
    /// Edist between the redrape and the dataset's drape (cm).
    pub edist_cm: f64,
    /// Enorm between them (degrees).
    pub enorm_deg: f64,
    /// The largest vertex distance between them (cm).
    pub max_cm: f64,
    /// Share of vertices more than 1 cm from the dataset's drape.
    pub over_1cm: f64,
    /// Why the redrape failed (it is left out of the summary), if it did.
    pub failure: Option<String>,
    /// Wall time of the redrape (s).
    pub seconds: f64,
}

/// One sample.
#[derive(Debug, Clone, Serialize)]
pub struct SampleSensitivity {
    /// Sample id.
    pub id: u64,
    /// Edist of the DQS warp (no physics) to the dataset's drape (cm), for scale.
    pub dqs_cm: f64,
    /// Edist of the network to the dataset's drape (cm), with `--model`.
    pub network_cm: Option<f64>,
    /// One per amplitude, in the options' order.
    pub redrapes: Vec<Redrape>,
}

/// Summary of one amplitude over the samples whose redrape converged.
#[derive(Debug, Clone, Serialize)]
pub struct AmplitudeSummary {
    /// Largest starting offset per coordinate (m).
    pub amplitude: f32,
    /// Redrapes that converged (counted below) and all of them.
    pub converged: usize,
    /// Redrapes made.
    pub redrapes: usize,
    /// Edist to the dataset's drape (cm): mean, standard deviation, median, largest.
    pub edist_cm: (f64, f64),
    /// Median Edist (cm).
    pub edist_median_cm: f64,
    /// Largest Edist (cm).
    pub edist_max_cm: f64,
    /// Mean Enorm (degrees) and its standard deviation.
    pub enorm_deg: (f64, f64),
    /// Mean share of vertices more than 1 cm away.
    pub over_1cm: f64,
    /// Pearson correlation over samples between this Edist and the network's, with
    /// `--model` and at least three samples.
    pub correlation_with_network: Option<f64>,
}

/// The whole measurement.
#[derive(Debug, Clone, Serialize)]
pub struct SensitivityReport {
    /// Dataset name.
    pub dataset: String,
    /// Garment vertices.
    pub vertices: usize,
    /// Split measured.
    pub split: String,
    /// Seed of the offsets.
    pub seed: u64,
    /// Per sample.
    pub samples: Vec<SampleSensitivity>,
    /// Per amplitude.
    pub summaries: Vec<AmplitudeSummary>,
    /// Mean DQS Edist over the samples (cm).
    pub dqs_cm: f64,
    /// Mean network Edist over the samples (cm), with `--model`.
    pub network_cm: Option<f64>,
    /// The sample whose redrape at the first amplitude moved most, and that redrape's
    /// positions (for a render; not written to JSON).
    #[serde(skip)]
    pub most_moved: Option<(Row, Vec<Vec3>)>,
}

/// The starting positions moved by independent uniform offsets in `[-a, a]` per coordinate.
pub fn jitter(start: &[Vec3], amplitude: f32, seed: u64) -> Vec<Vec3> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    start
        .iter()
        .map(|p| {
            *p + Vec3::new(
                rng.random_range(-amplitude..=amplitude),
                rng.random_range(-amplitude..=amplitude),
                rng.random_range(-amplitude..=amplitude),
            )
        })
        .collect()
}

fn pearson(a: &[f64], b: &[f64]) -> Option<f64> {
    if a.len() < 3 || a.len() != b.len() {
        return None;
    }
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
    let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
    (va > 0.0 && vb > 0.0).then(|| cov / (va * vb).sqrt())
}

/// The seed of sample `id`'s offsets at amplitude index `k`.
fn offset_seed(seed: u64, id: u64, k: usize) -> u64 {
    seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(id.wrapping_mul(1_000_003))
        .wrapping_add(k as u64)
}

/// `row` draped as the dataset did, from the template moved by the offsets of amplitude
/// index `k`.
fn redrape(
    redraper: &Redraper<'_>,
    model: &BodyModel,
    row: &Row,
    opts: &SensitivityOptions,
    k: usize,
) -> Result<drape::DrapeResult, EvalError> {
    let start = redraper.start(row)?;
    let motion = redraper.morph(model, row, &start)?;
    let x0 = jitter(
        &start.template.mesh.vertices,
        opts.amplitudes[k],
        offset_seed(opts.seed, row.id, k),
    );
    let sim = &redraper.config.sim;
    let mut d = drape::drape(start.cloth, &x0, &motion, sim, true, &mut |_| {});
    redraper.judge(&mut d, row);
    Ok(d)
}

/// Redrapes the first `opts.samples` samples of `data`'s split once per amplitude.
/// `wardrobe` must hold the template the dataset was made with; `run`, if given, is a trained
/// network measured on the same samples. `progress` is called per finished sample.
pub fn measure(
    data: &Dataset,
    model: &BodyModel,
    wardrobe: &Wardrobe,
    run: Option<&std::path::Path>,
    opts: &SensitivityOptions,
    progress: &mut dyn FnMut(&SampleSensitivity),
) -> Result<SensitivityReport, EvalError> {
    opts.validate()?;
    let redraper = Redraper::new(data, wardrobe)?;
    let net = run.map(|r| Predictor::open(r, &data.statics)).transpose()?;
    let rows = crate::evaluate::first_rows(data, opts.split, opts.samples)?;
    let tris = &data.statics.garment_triangles;
    let mut samples = Vec::with_capacity(rows.len());
    let mut most_moved: Option<(Row, Vec<Vec3>)> = None;
    for row in &rows {
        let mut redrapes = Vec::with_capacity(opts.amplitudes.len());
        for k in 0..opts.amplitudes.len() {
            let out = redrape(&redraper, model, row, opts, k)?;
            let d = vertex_errors(&out.positions, &row.draped);
            let r = Redrape {
                amplitude: opts.amplitudes[k],
                edist_cm: mean(d.iter().map(|&e| e as f64)) * 100.0,
                enorm_deg: enorm_deg(&out.positions, &row.draped, tris),
                max_cm: d.iter().fold(0.0f32, |m, &e| m.max(e)) as f64 * 100.0,
                over_1cm: d.iter().filter(|&&e| e > 0.01).count() as f64 / d.len() as f64,
                failure: out.report.failure.as_ref().map(|f| f.to_string()),
                seconds: out.report.wall_time,
            };
            let moved_most = k == 0
                && samples
                    .iter()
                    .all(|s: &SampleSensitivity| s.redrapes[0].edist_cm <= r.edist_cm);
            if moved_most {
                most_moved = Some((row.clone(), out.positions));
            }
            redrapes.push(r);
        }
        let network_cm = net.as_ref().map(|n| {
            let (pred, _) = n.predict_rows(std::slice::from_ref(row));
            edist_cm(&pred[0], &row.draped)
        });
        let s = SampleSensitivity {
            id: row.id,
            dqs_cm: edist_cm(&row.warped, &row.draped),
            network_cm,
            redrapes,
        };
        progress(&s);
        samples.push(s);
    }
    let summaries = opts
        .amplitudes
        .iter()
        .enumerate()
        .map(|(k, &a)| {
            let ok: Vec<&SampleSensitivity> = samples
                .iter()
                .filter(|s| s.redrapes[k].failure.is_none())
                .collect();
            let e: Vec<f64> = ok.iter().map(|s| s.redrapes[k].edist_cm).collect();
            let n: Vec<f64> = ok.iter().map(|s| s.redrapes[k].enorm_deg).collect();
            let net: Vec<f64> = ok.iter().filter_map(|s| s.network_cm).collect();
            AmplitudeSummary {
                amplitude: a,
                converged: ok.len(),
                redrapes: samples.len(),
                edist_cm: mean_std(&e),
                edist_median_cm: median(e.clone()),
                edist_max_cm: e.iter().fold(f64::NAN, |m, &x| m.max(x)),
                enorm_deg: mean_std(&n),
                over_1cm: mean(ok.iter().map(|s| s.redrapes[k].over_1cm)),
                correlation_with_network: pearson(&e, &net),
            }
        })
        .collect();
    let nets: Vec<f64> = samples.iter().filter_map(|s| s.network_cm).collect();
    Ok(SensitivityReport {
        dataset: data.manifest.name.clone(),
        vertices: data.statics.garment_vertices.len(),
        split: opts.split.name().to_string(),
        seed: opts.seed,
        summaries,
        dqs_cm: mean(samples.iter().map(|s| s.dqs_cm)),
        network_cm: (!nets.is_empty()).then(|| mean(nets)),
        samples,
        most_moved,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jitter_stays_within_the_amplitude_and_is_seeded() {
        let start: Vec<Vec3> = (0..500).map(|i| Vec3::splat(i as f32 * 0.001)).collect();
        let a = jitter(&start, 1e-4, 7);
        let b = jitter(&start, 1e-4, 7);
        let c = jitter(&start, 1e-4, 8);
        assert_eq!(a, b);
        assert_ne!(a, c);
        let mut largest = 0.0f32;
        for (p, q) in a.iter().zip(&start) {
            let d = (*p - *q).abs().max_element();
            // Within the bound up to the rounding of positions below 0.5 m (6e-8 m).
            assert!(d <= 1e-4 + 1e-7, "offset {d}");
            largest = largest.max(d);
        }
        // 1,500 uniform draws: the largest is within 1% of the bound.
        assert!(largest > 0.99e-4, "largest offset {largest}");
    }

    #[test]
    fn pearson_of_known_series() {
        let a = [1.0, 2.0, 3.0, 4.0];
        let r = pearson(&a, &[2.0, 4.0, 6.0, 8.0]).unwrap();
        assert!((r - 1.0).abs() < 1e-12);
        let r = pearson(&a, &[4.0, 3.0, 2.0, 1.0]).unwrap();
        assert!((r + 1.0).abs() < 1e-12);
        let r = pearson(&a, &[1.0, -1.0, -1.0, 1.0]).unwrap();
        assert!(r.abs() < 1e-12);
        assert!(pearson(&a[..2], &[1.0, 2.0]).is_none());
        assert!(pearson(&a, &[1.0, 1.0, 1.0, 1.0]).is_none());
    }
}
