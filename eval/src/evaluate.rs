//! `drape eval`: a trained network and five baselines measured on a dataset split.
//!
//! Methods, each a garment per test sample:
//! - the network (`G^P = M + T^P`, [`learn::predict::Predictor`]);
//! - **DQS**: the warped template `M` itself (the paper's Table 1 baseline);
//! - **mean residual**: `M` plus the training split's mean displacement `mean(G - M)`;
//! - **nearest neighbour**: `M` plus the displacement `G_j - M_j` of the training sample
//!   `j` with the closest shape and pose ([`pose_shape_distance`]);
//! - **linear**: `M` plus a ridge regression of the displacement on the shape and the bone
//!   rotation matrices, fitted on the training split, its strength picked on the validation
//!   split ([`crate::linear`]; on the training split itself it is an in-sample fit).
//! - **kernel**: the linear baseline plus an RBF kernel ridge regression of what it leaves,
//!   on the standardised shape and pose features, its width and strength picked on the
//!   validation split ([`learn::kernel`]; in-sample on the training split too).
//!
//! Per sample and method: Edist, Enorm, L_MC and L_RQ^K, the physics energies and the
//! interpenetration ratio; the simulator's own energies and interpenetration for reference;
//! average-precision curves per method.

use std::collections::{BTreeMap, HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::time::Instant;

use dataset::config::Split;
use dataset::reader::{Dataset, Sample};
use dataset::shard::Row;
use glam::{Quat, Vec3};
use learn::kernel::{Fit, Row as KernelRow};
use learn::loss::CurvatureErrors;
use learn::predict::Predictor;
use rayon::prelude::*;
use serde::Serialize;

use crate::linear;
use crate::metrics::{self, Curve, Energies, Fabric, Physics};

/// Evaluation failed.
#[derive(Debug, thiserror::Error)]
pub enum EvalError {
    /// Reading the dataset failed.
    #[error(transparent)]
    Data(#[from] dataset::DatasetError),
    /// Loading the network failed.
    #[error(transparent)]
    Learn(#[from] learn::LearnError),
    /// Nothing to evaluate, or inputs that do not fit together.
    #[error("{0}")]
    Invalid(String),
    /// Reading an input file failed.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// Writing the report failed.
    #[error("cannot write {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// Why.
        source: std::io::Error,
    },
    /// Rendering failed.
    #[error(transparent)]
    Render(#[from] crate::render::RenderError),
}

/// What to evaluate.
#[derive(Debug, Clone)]
pub struct EvalOptions {
    /// The split (test by default in the command).
    pub split: Split,
    /// Samples per network batch.
    pub batch: usize,
    /// Only the first `limit` samples of the split (all if `None`).
    pub limit: Option<usize>,
    /// Show progress bars; without a terminal, plain lines instead
    /// ([`learn::run::LogLines`]).
    pub progress: bool,
}

/// The methods, in report order.
pub const METHODS: [&str; 6] = [
    "network",
    "dqs",
    "mean-residual",
    "nearest-neighbour",
    "linear",
    "kernel",
];

/// Display names of [`METHODS`] (the network's is its variant's).
pub fn method_title(method: &str, network: &str) -> String {
    match method {
        "network" => network.to_string(),
        "dqs" => "DQS".into(),
        "mean-residual" => "Mean residual".into(),
        "nearest-neighbour" => "Nearest neighbour".into(),
        "linear" => "Linear (ridge)".into(),
        "kernel" => "Kernel (linear + RBF)".into(),
        "simulator" => "Simulator".into(),
        m => m.into(),
    }
}

/// The figures of one garment against the simulator's.
#[derive(Debug, Clone, Copy, Default, Serialize)]
pub struct Figures {
    /// Eq. 17 (cm).
    pub edist_cm: f64,
    /// Eq. 18 (degrees).
    pub enorm_deg: f64,
    /// L_MC (m^-2).
    pub l_mc: f64,
    /// L_RQ^8, L_RQ^16, L_RQ^32 (m^4).
    pub l_rq: [f64; 3],
    /// Membrane, bending and gravity energies (J).
    pub strain_j: f64,
    /// Bending energy (J).
    pub bending_j: f64,
    /// Gravitational potential energy above the body's lowest vertex (J).
    pub gravity_j: f64,
    /// Share of vertices inside the body.
    pub interpenetration: f64,
}

/// One evaluated sample.
#[derive(Debug, Clone, Serialize)]
pub struct SampleEval {
    /// Sample id.
    pub id: u64,
    /// Pose family.
    pub family: String,
    /// Simulator time of this drape when the dataset was made (s, one thread).
    pub sim_seconds: f64,
    /// Figures per method ([`METHODS`]).
    pub methods: BTreeMap<String, Figures>,
    /// The simulator's own energies and interpenetration (Edist and friends are zero).
    pub simulator: Figures,
    /// Training sample used by the nearest-neighbour baseline.
    pub neighbour: u64,
}

/// Everything measured.
#[derive(Debug, Clone)]
pub struct Evaluation {
    /// Per sample, in split order.
    pub samples: Vec<SampleEval>,
    /// Vertex-distance curves (cm) per method.
    pub distance_curves: BTreeMap<String, Curve>,
    /// Face-angle curves (degrees) per method.
    pub angle_curves: BTreeMap<String, Curve>,
    /// Training samples the baselines saw.
    pub train_samples: usize,
    /// Wall time of the network's batches (inputs and both streams) per drape (s).
    pub network_seconds_per_drape: f64,
    /// Batch size of those batches.
    pub batch: usize,
    /// Threads a batch's drapes were shared among (`Predictor::workers`).
    pub workers: usize,
    /// The network's paper name.
    pub network: String,
    /// Wall time of the whole evaluation (s).
    pub seconds: f64,
    /// The linear baseline (its strength is `linear.lambda`).
    pub linear: linear::Linear,
    /// Per ridge strength tried, the linear baseline's validation Edist (cm; empty without
    /// validation samples).
    pub linear_validation: Vec<(f64, f64)>,
    /// The kernel baseline's strengths and width.
    pub kernel: learn::kernel::Picks,
    /// Per (width factor, strength) tried, the kernel baseline's validation Edist (cm;
    /// empty without validation samples).
    pub kernel_validation: Vec<(f64, f64, f64)>,
}

/// Distance between two training keys: mean bone rotation angle (radians) plus the
/// Euclidean distance of the shape parameters (each in 0 to 1), so one radian of pose
/// weighs as much as the whole range of one shape parameter.
pub fn pose_shape_distance(a: &Key, b: &Key) -> f64 {
    let pose = dataset::inspect::pose_distance(&a.pose, &b.pose).to_radians();
    let shape: f64 = a
        .shape
        .iter()
        .zip(&b.shape)
        .map(|(x, y)| ((x - y) as f64).powi(2))
        .sum::<f64>()
        .sqrt();
    pose + shape
}

/// Shape and pose of a sample.
#[derive(Debug, Clone)]
pub struct Key {
    /// Sample id.
    pub id: u64,
    /// Shape parameters.
    pub shape: [f32; 9],
    /// Bone rotations.
    pub pose: Vec<Quat>,
}

impl Key {
    fn of(row: &Row) -> Self {
        Self {
            id: row.id,
            shape: row.shape,
            pose: row.pose.clone(),
        }
    }
}

fn progress(show: bool, len: usize, what: &str) -> indicatif::ProgressBar {
    let bar = learn::run::progress(show, len as u64);
    bar.set_message(what.to_string());
    bar
}

/// The training split's mean displacement, the keys of its samples, the linear baseline's
/// sums and the samples for the kernel baseline (one pass).
type Summary = (Vec<Vec3>, Vec<Key>, linear::Accumulator, Vec<KernelRow>);

fn training_summary(data: &Dataset, show: bool) -> Result<Summary, EvalError> {
    let n = data.statics.garment_vertices.len();
    let mut sum = vec![glam::DVec3::ZERO; n];
    let mut keys = Vec::new();
    let mut sums: Option<linear::Accumulator> = None;
    let mut rows = Vec::new();
    let bar = progress(
        show,
        data.count(Split::Train),
        "training split: mean, keys, linear",
    );
    let lines = learn::run::LogLines::new(show, &bar, "eval", "samples");
    for s in data.samples(Split::Train) {
        let s = s?;
        let disp = s.row.displacement();
        for (acc, d) in sum.iter_mut().zip(&disp) {
            *acc += d.as_dvec3();
        }
        let x = linear::features(&s.row.shape, &s.row.pose);
        sums.get_or_insert_with(|| linear::Accumulator::new(x.len(), n))
            .add(&x, &disp);
        keys.push(Key::of(&s.row));
        rows.push(KernelRow {
            body: s.record.plan.body,
            x,
            d: disp,
        });
        bar.inc(1);
        lines.tick(&bar);
    }
    bar.finish_and_clear();
    lines.finish(&bar);
    if keys.is_empty() {
        return Err(EvalError::Invalid(format!(
            "{} has no training samples: the baselines need them",
            data.dir.display()
        )));
    }
    let k = keys.len() as f64;
    let sums = sums.expect("at least one training sample");
    Ok((
        sum.iter().map(|s| (*s / k).as_vec3()).collect(),
        keys,
        sums,
        rows,
    ))
}

/// The evaluated samples of `split` (at most `limit`).
fn split_samples(
    data: &Dataset,
    split: Split,
    limit: Option<usize>,
) -> impl Iterator<Item = Result<Sample, dataset::DatasetError>> + '_ {
    data.samples(split).take(limit.unwrap_or(usize::MAX))
}

/// Evaluates the network of `run` and the baselines on `data`'s split.
pub fn evaluate(run: &Path, data: &Dataset, opts: &EvalOptions) -> Result<Evaluation, EvalError> {
    let t0 = Instant::now();
    let st = &data.statics;
    let net = Predictor::open(run, st)?;
    let manifest = learn::run::manifest_sha256(&data.dir)?;
    if !net
        .info
        .trained_on(&manifest, &data.manifest.drapes_sha256())
    {
        eprintln!(
            "note: {} was trained on dataset {:?}; evaluating on {} ({})",
            run.display(),
            net.info.dataset,
            data.manifest.name,
            data.dir.display()
        );
    }
    for m in &net.info.more_data {
        eprintln!(
            "note: {} trained on {}'s {} training drapes too; the baselines fit on {}'s only",
            run.display(),
            m.dataset,
            m.train_drapes,
            data.manifest.name
        );
    }
    let count = data.count(opts.split).min(opts.limit.unwrap_or(usize::MAX));
    if count == 0 {
        return Err(EvalError::Invalid(format!(
            "{} has no converged {} samples",
            data.dir.display(),
            opts.split.name()
        )));
    }
    // Baselines: the mean displacement and, per evaluated sample, the nearest training key.
    let (mean_disp, keys, sums, kernel_rows) = training_summary(data, opts.progress)?;
    let validation = linear::read_split(data, Split::Val)?;
    let (linear, linear_validation) = linear::fit(&sums, &validation).ok_or_else(|| {
        EvalError::Invalid("the linear baseline's normal equations cannot be solved".into())
    })?;
    let mut neighbour_of: HashMap<u64, u64> = HashMap::new();
    let mut evaluated: Vec<(u64, Vec<f64>)> = Vec::new();
    for s in split_samples(data, opts.split, opts.limit) {
        let s = s?;
        evaluated.push((s.row.id, linear::features(&s.row.shape, &s.row.pose)));
        let key = Key::of(&s.row);
        // On the training split a sample must not be its own neighbour.
        let best = keys
            .par_iter()
            .filter(|k| k.id != key.id)
            .map(|k| (pose_shape_distance(&key, k), k.id))
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .ok_or_else(|| {
                EvalError::Invalid(
                    "the nearest-neighbour baseline needs a second training sample".into(),
                )
            })?;
        neighbour_of.insert(s.row.id, best.1);
    }
    // The kernel baseline's displacements of the evaluated samples, solved together.
    let (kernel_of, kernel, kernel_validation) = {
        let bar = progress(opts.progress, 1, "kernel baseline: fitting");
        let lines = learn::run::LogLines::new(opts.progress, &bar, "eval", "samples");
        if lines.is_on() {
            eprintln!("eval: fitting the kernel baseline");
        }
        let refs: Vec<&KernelRow> = kernel_rows.iter().collect();
        let fit = Fit::new(&refs, &validation, None, &mut |m| {
            if lines.due() {
                eprintln!("eval: kernel baseline: {m}");
            }
            bar.set_message(format!("kernel baseline: {m}"))
        })
        .ok_or_else(|| {
            EvalError::Invalid("the kernel baseline's system cannot be solved".into())
        })?;
        let xs: Vec<&[f64]> = evaluated.iter().map(|(_, x)| x.as_slice()).collect();
        let of: HashMap<u64, Vec<Vec3>> = evaluated
            .iter()
            .map(|(id, _)| *id)
            .zip(fit.displacements(&xs))
            .collect();
        bar.finish_and_clear();
        (of, fit.picks(), fit.tried.clone())
    };
    drop(kernel_rows);
    let wanted: HashSet<u64> = neighbour_of.values().copied().collect();
    let mut displacement: HashMap<u64, Vec<Vec3>> = HashMap::new();
    for s in data.samples(Split::Train) {
        let s = s?;
        if wanted.contains(&s.row.id) {
            displacement.insert(s.row.id, s.row.displacement());
        }
    }

    // The mean residual; on the training split without the sample's own displacement.
    let n_train = keys.len() as f32;
    let train_ids: HashSet<u64> = keys.iter().map(|k| k.id).collect();
    let mean_residual = |row: &Row| -> Vec<Vec3> {
        let own = train_ids.contains(&row.id) && n_train > 1.0;
        row.warped
            .iter()
            .zip(&row.draped)
            .zip(&mean_disp)
            .map(|((m, g), d)| {
                if own {
                    *m + (*d * n_train - (*g - *m)) / (n_train - 1.0)
                } else {
                    *m + *d
                }
            })
            .collect()
    };
    let physics = Physics::new(
        &st.garment_vertices,
        &st.garment_triangles,
        Fabric::default(),
    );
    let curvature = CurvatureErrors::new(st.garment_vertices.len(), &st.garment_triangles);
    let mut distance_curves: BTreeMap<String, Curve> = METHODS
        .iter()
        .map(|m| (m.to_string(), Curve::distances()))
        .collect();
    let mut angle_curves: BTreeMap<String, Curve> = METHODS
        .iter()
        .map(|m| (m.to_string(), Curve::angles()))
        .collect();
    let mut samples = Vec::with_capacity(count);
    let mut network_seconds = 0.0;
    let bar = progress(opts.progress, count, "evaluating");
    let lines = learn::run::LogLines::new(opts.progress, &bar, "eval", "samples");
    let mut batch: Vec<Sample> = Vec::new();
    let mut flush = |batch: &mut Vec<Sample>,
                     samples: &mut Vec<SampleEval>|
     -> Result<(), EvalError> {
        if batch.is_empty() {
            return Ok(());
        }
        let rows: Vec<Row> = batch.iter().map(|s| s.row.clone()).collect();
        let (preds, timing) = net.predict_rows(&rows);
        network_seconds += timing.inputs + timing.network;
        // Each sample's garments per method, then the figures in parallel.
        // Per sample: its figures, and per method the vertex distances and face angles.
        type Errors = Vec<(String, Vec<f32>, Vec<f32>)>;
        let per: Vec<(SampleEval, Errors)> = batch
            .par_iter()
            .zip(preds)
            .map(|(s, pred)| {
                let row = &s.row;
                let nn = &displacement[&neighbour_of[&row.id]];
                let garments: [(&str, Vec<Vec3>); 6] = [
                    ("network", pred),
                    ("dqs", row.warped.clone()),
                    ("mean-residual", mean_residual(row)),
                    (
                        "nearest-neighbour",
                        row.warped.iter().zip(nn).map(|(m, d)| *m + *d).collect(),
                    ),
                    (
                        "linear",
                        linear.predict(&linear::features(&row.shape, &row.pose), &row.warped),
                    ),
                    (
                        "kernel",
                        row.warped
                            .iter()
                            .zip(&kernel_of[&row.id])
                            .map(|(m, d)| *m + *d)
                            .collect(),
                    ),
                ];
                let floor = row.body.iter().map(|p| p.y).fold(f32::MAX, f32::min);
                let collider = sim::cloth::BodyCollider::new(&row.body, &st.body_triangles, 0.0);
                let with_energies = |f: Figures, e: Energies, x: &[Vec3]| Figures {
                    strain_j: e.strain,
                    bending_j: e.bending,
                    gravity_j: e.gravity,
                    interpenetration: metrics::interpenetration(&collider, x),
                    ..f
                };
                let mut methods = BTreeMap::new();
                let mut errors = Vec::new();
                for (name, x) in &garments {
                    let dist = metrics::vertex_errors(x, &row.draped);
                    let ang = metrics::face_angles(x, &row.draped, &st.garment_triangles);
                    let c = curvature.of(x, &row.draped);
                    let f = Figures {
                        edist_cm: metrics::mean(dist.iter().map(|&e| e as f64)) * 100.0,
                        enorm_deg: metrics::mean(ang.iter().map(|&e| e as f64)),
                        l_mc: c[0],
                        l_rq: [c[1], c[2], c[3]],
                        ..Figures::default()
                    };
                    methods.insert(
                        name.to_string(),
                        with_energies(f, physics.energies(x, floor), x),
                    );
                    errors.push((name.to_string(), dist, ang));
                }
                let simulator = with_energies(
                    Figures::default(),
                    physics.energies(&row.draped, floor),
                    &row.draped,
                );
                let eval = SampleEval {
                    id: row.id,
                    family: s.record.family.clone(),
                    sim_seconds: s.record.seconds - s.record.warp_seconds,
                    methods,
                    simulator,
                    neighbour: neighbour_of[&row.id],
                };
                (eval, errors)
            })
            .collect();
        for (eval, errors) in per {
            for (name, dist, ang) in errors {
                distance_curves
                    .get_mut(&name)
                    .expect("curve")
                    .add(dist.iter().map(|&e| e as f64 * 100.0));
                angle_curves
                    .get_mut(&name)
                    .expect("curve")
                    .add(ang.iter().map(|&e| e as f64));
            }
            samples.push(eval);
            bar.inc(1);
            lines.tick(&bar);
        }
        batch.clear();
        Ok(())
    };
    for s in split_samples(data, opts.split, opts.limit) {
        batch.push(s?);
        if batch.len() == opts.batch.max(1) {
            flush(&mut batch, &mut samples)?;
        }
    }
    flush(&mut batch, &mut samples)?;
    bar.finish_and_clear();
    lines.finish(&bar);
    let n = samples.len();
    Ok(Evaluation {
        samples,
        distance_curves,
        angle_curves,
        train_samples: keys.len(),
        network_seconds_per_drape: network_seconds / n as f64,
        batch: opts.batch.max(1),
        workers: net.workers(),
        network: net.config.model.display_name(),
        seconds: t0.elapsed().as_secs_f64(),
        linear,
        linear_validation,
        kernel,
        kernel_validation,
    })
}

/// The first `n` (at least one) rows of `split`; an error if the split has none.
pub fn first_rows(data: &Dataset, split: Split, n: usize) -> Result<Vec<Row>, EvalError> {
    let rows: Vec<Row> = data
        .samples(split)
        .take(n.max(1))
        .map(|s| s.map(|s| s.row))
        .collect::<Result<_, _>>()?;
    if rows.is_empty() {
        return Err(EvalError::Invalid(format!(
            "{} has no converged {} samples",
            data.dir.display(),
            split.name()
        )));
    }
    Ok(rows)
}

/// The rows of `ids` from `split` (for the renders), in the order of `ids`.
pub fn rows_of(data: &Dataset, split: Split, ids: &[u64]) -> Result<Vec<Row>, EvalError> {
    let want: HashSet<u64> = ids.iter().copied().collect();
    let mut found: HashMap<u64, Row> = HashMap::new();
    for s in data.samples(split) {
        let s = s?;
        if want.contains(&s.row.id) {
            found.insert(s.row.id, s.row);
        }
    }
    ids.iter()
        .map(|id| {
            found
                .get(id)
                .cloned()
                .ok_or_else(|| EvalError::Invalid(format!("sample {id} is not in the split")))
        })
        .collect()
}
