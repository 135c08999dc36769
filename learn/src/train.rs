//! `drape train`: Adam over batches read shard by shard, validation every epoch, best and
//! last checkpoints, resume after interruption, a CSV log of every loss term.
//!
//! A run folder holds: `config.toml` (the resolved config, seed included), `run.json` (the
//! garment, its vertex count, the dataset it trained on, curvature scales), `last.bpk` and
//! `last-optim.bpk` (model and Adam state), `best.bpk` (lowest validation loss), `state.json`
//! (where training is: epoch, batch, best loss), `log.csv` (per epoch, train and val means)
//! and `steps.csv` (per batch).

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use burn::module::Module;
use burn::optim::{AdamConfig, GradientsAccumulator, GradientsParams};
use burn::tensor::{Device, Tensor};
use dataset::config::Split;
use dataset::reader::Dataset;
use rand::SeedableRng;
use rand::seq::SliceRandom;
use rayon::prelude::{IntoParallelRefIterator, ParallelIterator};
use serde::{Deserialize, Serialize};

use crate::LearnError;
use crate::config::TrainConfig;
use crate::data::{Batch, Prepared, Preprocessor, collate};
use crate::loss::{self, LossTopology};
use crate::model::{GarNet, Graph};
use crate::topology::Topology;

/// The loss terms of one batch (or their mean over many), and Edist.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize, Deserialize)]
pub struct Terms {
    /// Weighted total that was minimised.
    pub total: f64,
    /// L_vert, m^2.
    pub vert: f64,
    /// L_pen, m.
    pub pen: f64,
    /// L_norm.
    pub norm: f64,
    /// L_bend, m.
    pub bend: f64,
    /// L_RQ^8, L_RQ^16, L_RQ^32, m^4 (0 when off).
    pub rq: [f64; 3],
    /// L_MC, 1/m^2 (0 when off).
    pub mc: f64,
    /// L_UMC, m^2 (0 when off).
    pub umc: f64,
    /// Edist, cm (Eq. 17): mean vertex distance.
    pub edist_cm: f64,
}

impl Terms {
    /// Column names of the CSV logs.
    pub const HEADER: &'static str = "total,vert,pen,norm,bend,rq8,rq16,rq32,mc,umc,edist_cm";

    fn csv(&self) -> String {
        format!(
            "{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.6e},{:.5}",
            self.total,
            self.vert,
            self.pen,
            self.norm,
            self.bend,
            self.rq[0],
            self.rq[1],
            self.rq[2],
            self.mc,
            self.umc,
            self.edist_cm
        )
    }

    /// L_p (Eq. 7) with the config's weights, before `physics_scale`.
    pub fn physics(&self, w: &crate::config::LossWeights) -> f64 {
        self.vert * w.vert + self.pen * w.pen + self.norm * w.norm + self.bend * w.bend
    }

    /// Every term divided by `n` (a sum of `n` samples to their mean).
    fn mean_of(self, n: usize) -> Terms {
        let mut m = Terms::default();
        m.add(&self, 1.0 / n as f64);
        m
    }

    fn add(&mut self, o: &Terms, w: f64) {
        self.total += o.total * w;
        self.vert += o.vert * w;
        self.pen += o.pen * w;
        self.norm += o.norm * w;
        self.bend += o.bend * w;
        for k in 0..3 {
            self.rq[k] += o.rq[k] * w;
        }
        self.mc += o.mc * w;
        self.umc += o.umc * w;
        self.edist_cm += o.edist_cm * w;
    }
}

fn scalar(t: &Tensor<1>) -> f64 {
    t.clone().into_scalar::<f32>() as f64
}

/// Everything fixed for one garment and one model config: graph, loss indices, inputs.
#[derive(Debug, Clone)]
pub struct Setup {
    /// The training config.
    pub config: TrainConfig,
    /// The garment's connectivity.
    pub topology: Topology,
    /// Rows to inputs.
    pub pre: Preprocessor,
    /// FeaStNet graph on the device.
    pub graph: Graph,
    /// Loss index tensors on the device.
    pub loss_topology: LossTopology,
    /// Length of the shape-and-pose vector.
    pub params: usize,
    /// Factors on the curvature weights ([`CurvatureScales`]; ones until measured).
    pub scales: CurvatureScales,
    /// The device.
    pub device: Device,
}

/// Factors multiplying the curvature terms' weights, measured at the start of a run
/// (`loss.rescale_curvature`): together the weighted curvature terms then equal the weighted
/// physics term `physics_scale * L_p`, shared among them in proportion to their configured
/// weights (so the paper's 500 : 50 : 10 for L_RQ^8 : L_RQ^16 : L_RQ^32 still holds at the
/// start). Saved in the run's `run.json`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct CurvatureScales {
    /// Of L_RQ^8, L_RQ^16, L_RQ^32.
    pub rq: [f64; 3],
    /// Of L_MC.
    pub mc: f64,
    /// Of L_UMC.
    pub umc: f64,
}

impl Default for CurvatureScales {
    fn default() -> Self {
        Self {
            rq: [1.0; 3],
            mc: 1.0,
            umc: 1.0,
        }
    }
}

impl CurvatureScales {
    /// The factors for the mean terms `t` of the first batches: weighted term k becomes
    /// `physics_scale * L_p * w_k / sum(w)`. Terms that are off or zero keep 1.
    pub fn measure(t: &Terms, w: &crate::config::LossWeights) -> Self {
        let budget = w.physics_scale * t.physics(w);
        let sum_w: f64 = w.rq.iter().sum::<f64>() + w.mc + w.umc;
        let f = |weight: f64, value: f64| {
            if weight > 0.0 && value > 0.0 {
                budget / (sum_w * value)
            } else {
                1.0
            }
        };
        Self {
            rq: [0, 1, 2].map(|k| f(w.rq[k], t.rq[k])),
            mc: f(w.mc, t.mc),
            umc: f(w.umc, t.umc),
        }
    }
}

/// The largest L_RQ neighbourhood a config's weights use (None: L_RQ off).
pub fn rq_kmax(w: &crate::config::LossWeights) -> Option<usize> {
    (0..3)
        .rev()
        .find(|&k| w.rq[k] > 0.0)
        .map(|k| loss::RQ_SIZES[k])
}

impl Setup {
    /// Builds the fixed parts for a dataset's garment.
    pub fn new(config: &TrainConfig, data: &Dataset, device: &Device) -> Self {
        let st = &data.statics;
        let topology = Topology::new(st.garment_vertices.len(), &st.garment_triangles);
        Self {
            config: config.clone(),
            pre: Preprocessor::new(
                st,
                &config.model,
                config.loss.pen_push_out,
                rq_kmax(&config.loss).unwrap_or(0),
            ),
            graph: Graph::new(&topology, device),
            loss_topology: LossTopology::new(&topology, device),
            params: crate::data::param_count(st.bones),
            scales: CurvatureScales::default(),
            topology,
            device: device.clone(),
        }
    }

    /// Forward pass and losses of one batch. Returns the differentiable total.
    pub fn losses(&self, model: &GarNet, samples: &[&Prepared]) -> (Tensor<1>, Terms) {
        let Batch { input, target } = collate(samples, &self.config.model, &self.device);
        let target = target.expect("training samples carry their target");
        let pred = input.warped.clone() + model.forward(&input, &self.graph); // [B, N, 3]
        let w = &self.config.loss;
        let lt = &self.loss_topology;
        let vert = loss::vertex_loss(pred.clone(), target.clone());
        let (bp, bn) = loss::penetration_targets(&pred, samples, &self.device);
        let pen =
            loss::penetration_loss(pred.clone(), target.clone(), bp, bn, w.pen_tolerance as f32);
        let norm = loss::normal_loss(pred.clone(), target.clone(), lt);
        let bend = loss::bending_loss(pred.clone(), target.clone(), lt);
        let mut total = (vert.clone() * w.vert
            + pen.clone() * w.pen
            + norm.clone() * w.norm
            + bend.clone() * w.bend)
            * w.physics_scale;
        let mut terms = Terms::default();
        let sc = &self.scales;
        // L_RQ^K on the ground truth's K nearest neighbours (the first K of the largest set,
        // found once per sample by the preprocessor).
        if let Some(kmax) = rq_kmax(w) {
            let lists: Vec<&[u32]> = samples.iter().map(|s| s.rq.as_slice()).collect();
            let n = pred.dims()[1];
            let rows = loss::rq_rows(&lists, n, kmax, &self.device);
            let on = w.rq.map(|x| x > 0.0);
            let losses = loss::rayleigh_losses(pred.clone(), target.clone(), rows, kmax, on);
            for (k, l) in losses.into_iter().enumerate() {
                if let Some(l) = l {
                    terms.rq[k] = scalar(&l);
                    total = total + l * (w.rq[k] * sc.rq[k]);
                }
            }
        }
        if w.mc > 0.0 {
            let l = loss::mean_curvature_loss(pred.clone(), target.clone(), lt);
            terms.mc = scalar(&l);
            total = total + l * (w.mc * sc.mc);
        }
        if w.umc > 0.0 {
            let l = loss::uniform_curvature_loss(pred.clone(), target.clone(), lt);
            terms.umc = scalar(&l);
            total = total + l * (w.umc * sc.umc);
        }
        let dist = (pred - target).powi_scalar(2).sum_dim(2).sqrt().mean();
        let terms = Terms {
            total: scalar(&total),
            vert: scalar(&vert),
            pen: scalar(&pen),
            norm: scalar(&norm),
            bend: scalar(&bend),
            edist_cm: scalar(&dist) * 100.0,
            ..terms
        };
        (total, terms)
    }
}

/// The threads that compute a training step's gradients (data parallelism inside one
/// process). With one worker the step runs as it always has: the inputs on rayon's pool,
/// then one forward and one backward pass of the whole batch, whose kernels use the pool's
/// threads where burn-flex parallelises them. With more, the batch is cut into one part per
/// worker; each part's inputs, forward and backward pass run on the worker's own thread (a
/// one-thread rayon pool, so burn-flex's kernels stay on it), each part's loss weighted by
/// its share of the batch, and the parts' gradients are summed. Every loss term is a mean
/// over the batch's samples, so the sum is the whole batch's gradient up to rounding
/// (`tests/train.rs`, with L_RQ^8 and L_UMC on, and with L_MC, whose gradients reach ~1e4
/// so that its rounding is ~1e-3 wherever it lands: 1.4e-4 of the largest gradient at most,
/// in the output bias, where L_MC's share is zero in exact arithmetic; docs/bench.md).
/// Two one-thread training processes side by side run 1.68 times the samples of one
/// two-thread process with one worker (docs/bench.md); two workers bring that to one run.
pub struct Workers {
    pools: Vec<rayon::ThreadPool>,
}

impl std::fmt::Debug for Workers {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Workers")
            .field("count", &self.count())
            .finish()
    }
}

impl Workers {
    /// `n` workers (0: [`Workers::auto`] for batches of `batch_size`).
    pub fn new(n: usize, batch_size: usize) -> Self {
        let n = if n == 0 { Self::auto(batch_size) } else { n };
        let pools = if n <= 1 {
            Vec::new()
        } else {
            (0..n)
                .map(|k| {
                    rayon::ThreadPoolBuilder::new()
                        .num_threads(1)
                        .thread_name(move |_| format!("gradients-{k}"))
                        .build()
                        .expect("a one-thread pool")
                })
                .collect()
        };
        Self { pools }
    }

    /// The default: one worker per thread of rayon's pool (`RAYON_NUM_THREADS`), at most
    /// one per sample of a batch.
    pub fn auto(batch_size: usize) -> usize {
        rayon::current_num_threads().min(batch_size).max(1)
    }

    /// How many there are.
    pub fn count(&self) -> usize {
        self.pools.len().max(1)
    }

    /// `items` cut into one contiguous part per worker (the first parts one longer when
    /// they do not divide evenly), `f` run on each part on its worker's thread, the
    /// results in the parts' order. With one worker, `f(items)` on the calling thread.
    pub fn share<T: Sync, R: Send>(&self, items: &[T], f: impl Fn(&[T]) -> R + Sync) -> Vec<R> {
        if self.pools.is_empty() || items.is_empty() {
            return vec![f(items)];
        }
        // Part k holds n / p items, one more for the first n % p parts.
        let (n, p) = (items.len(), self.pools.len().min(items.len()));
        let mut parts: Vec<&[T]> = Vec::with_capacity(p);
        let mut start = 0;
        for k in 0..p {
            let len = n / p + usize::from(k < n % p);
            parts.push(&items[start..start + len]);
            start += len;
        }
        let f = &f;
        std::thread::scope(|s| {
            let handles: Vec<_> = parts
                .iter()
                .zip(&self.pools)
                .map(|(&part, pool)| s.spawn(move || pool.install(|| f(part))))
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().unwrap_or_else(|e| std::panic::resume_unwind(e)))
                .collect()
        })
    }
}

impl Setup {
    /// The gradients of the mean loss over `rows` and its terms: inputs, forward and
    /// backward pass, on `workers`.
    pub fn gradients(
        &self,
        model: &GarNet,
        rows: &[dataset::shard::Row],
        workers: &Workers,
    ) -> (GradientsParams, Terms) {
        if workers.pools.is_empty() || rows.len() < 2 {
            let prepared: Vec<Prepared> =
                rows.par_iter().map(|r| self.pre.prepare_row(r)).collect();
            let refs: Vec<&Prepared> = prepared.iter().collect();
            let (total, terms) = self.losses(model, &refs);
            return (GradientsParams::from_grads(total.backward(), model), terms);
        }
        let n = rows.len();
        // burn creates parameters when first used, drawing from the device's seeded
        // generator. On a fresh model a forward pass on this thread creates them in the
        // order one worker's pass does, so the starting weights do not depend on the
        // worker count (concurrent forks would create them in declaration order).
        if !initialised(model) {
            let first: Vec<Prepared> = rows[..1].iter().map(|r| self.pre.prepare_row(r)).collect();
            let refs: Vec<&Prepared> = first.iter().collect();
            drop(self.losses(model, &refs));
        }
        let results: Vec<(GradientsParams, Terms, usize)> = workers.share(rows, |part| {
            // A fork has its own autodiff graph and the same parameter ids.
            let local = model.clone().fork(&self.device);
            let prepared: Vec<Prepared> = part.iter().map(|r| self.pre.prepare_row(r)).collect();
            let refs: Vec<&Prepared> = prepared.iter().collect();
            let (total, terms) = self.losses(&local, &refs);
            let share = part.len() as f64 / n as f64;
            let grads = GradientsParams::from_grads((total * share).backward(), &local);
            (grads, terms, part.len())
        });
        let mut acc = GradientsAccumulator::<GarNet>::new();
        let mut sum = Terms::default();
        for (grads, terms, k) in results {
            acc.accumulate(model, grads);
            sum.add(&terms, k as f64);
        }
        (acc.grads(), sum.mean_of(n))
    }
}

/// Whether every parameter of `model` has been created (burn creates them lazily).
fn initialised(model: &GarNet) -> bool {
    struct Check(bool);
    impl burn::module::ModuleVisitor for Check {
        fn visit_float<const D: usize>(&mut self, p: &burn::module::Param<Tensor<D>>) {
            self.0 &= p.is_initialized();
        }
    }
    let mut c = Check(true);
    model.visit(&mut c);
    c.0
}

/// Where a run is; saved with every checkpoint.
#[derive(Debug, Clone, Default, Serialize, Deserialize)]
pub struct State {
    /// Epoch in progress (0-based).
    pub epoch: usize,
    /// Batches of that epoch already trained.
    pub batch: usize,
    /// Optimiser steps so far.
    pub steps: u64,
    /// Lowest validation loss so far.
    pub best_val: Option<f64>,
    /// Seconds of training so far (all sessions).
    pub seconds: f64,
    /// Set when all epochs are done.
    pub finished: bool,
}

impl State {
    /// The state saved in run folder `run` (None before its first checkpoint).
    pub fn load(run: &Path) -> Result<Option<Self>, LearnError> {
        crate::run::read_json(&run.join("state.json"))
    }
}

/// What the run folder records about its data and garment.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct RunInfo {
    /// Garment name.
    pub garment: String,
    /// Garment vertex count.
    pub vertices: usize,
    /// Template resolution of the dataset.
    pub resolution: usize,
    /// Dataset name.
    pub dataset: String,
    /// sha256 of the dataset's manifest file.
    pub manifest_sha256: String,
    /// The dataset's [`dataset::manifest::Manifest::drapes_sha256`]: its drapes' identity,
    /// the same for the same drapes made again. Absent in runs made before session 71.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drapes_sha256: Option<String>,
    /// Run this one was initialised from (fine-tuning).
    pub init: Option<PathBuf>,
    /// Curvature weight factors measured at the start of the run (`loss.rescale_curvature`).
    #[serde(default)]
    pub curvature_scales: Option<CurvatureScales>,
    /// sha256 of the garment's triangles ([`crate::run::faces_sha256`]): the mesh the
    /// network's convolutions were trained on. Absent in runs made before session 50.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub faces_sha256: Option<String>,
    /// Datasets whose training drapes were trained on too (`drape train --more-data`), in
    /// the order given; their validation and test drapes are not used.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub more_data: Vec<MoreData>,
}

/// A dataset whose training drapes a run trained on besides its own (`RunInfo::more_data`).
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
pub struct MoreData {
    /// Dataset name.
    pub dataset: String,
    /// sha256 of its manifest file.
    pub manifest_sha256: String,
    /// Its drapes' identity ([`dataset::manifest::Manifest::drapes_sha256`]).
    pub drapes_sha256: String,
    /// Its converged training drapes.
    pub train_drapes: usize,
}

impl RunInfo {
    /// Whether the run was trained on the dataset with manifest sha256 `manifest` and
    /// drapes sha256 `drapes`: the same manifest, or the same drapes made again.
    pub fn trained_on(&self, manifest: &str, drapes: &str) -> bool {
        self.manifest_sha256 == manifest || self.drapes_sha256.as_deref() == Some(drapes)
    }
}

pub(crate) fn ck(path: &Path) -> impl Fn(burn::store::RecordError) -> LearnError + '_ {
    move |e| LearnError::Checkpoint {
        path: path.to_path_buf(),
        reason: e.to_string(),
    }
}

/// A model's parameters as burnpack bytes.
pub(crate) fn model_bytes(model: &GarNet, path: &Path) -> Result<Vec<u8>, LearnError> {
    Ok(model
        .clone()
        .into_record()
        .into_bytes()
        .map_err(ck(path))?
        .to_vec())
}

/// Saves a model's parameters (burnpack) atomically.
pub fn save_model(model: &GarNet, path: &Path) -> Result<(), LearnError> {
    crate::run::write_files(&[(path, &model_bytes(model, path)?)])
}

/// Loads parameters into a model built from the same config.
pub fn load_model(model: GarNet, path: &Path) -> Result<GarNet, LearnError> {
    model.try_load_file(path).map_err(ck(path))
}

/// Options of one `drape train` call.
#[derive(Debug, Clone)]
pub struct TrainOptions {
    /// The dataset (overrides the config's).
    pub data: PathBuf,
    /// The run folder.
    pub run: PathBuf,
    /// Initialise from this run's best checkpoint (fine-tuning).
    pub init: Option<PathBuf>,
    /// Show a progress bar (with a line per epoch above it); without a terminal, plain
    /// lines instead ([`crate::run::LogLines`]).
    pub progress: bool,
    /// Gradient workers per step ([`Workers`]; 0: one per rayon thread).
    pub workers: usize,
    /// Datasets whose training drapes are trained on too ([`open_more_data`]).
    pub more_data: Vec<PathBuf>,
}

/// Shards read together in one epoch (index into the training datasets, file), and how
/// many of their rows train (converged, and in `max_train_samples`' subset if there is one),
/// as the manifests list them.
struct Group {
    shards: Vec<(usize, String)>,
    rows: usize,
}

/// Opens the datasets of `drape train --more-data` and checks that their training drapes
/// can join `data`'s: the same static file (garment template, faces, canonical body), the
/// same size templates, at least one converged training drape each, and sample ids that no
/// other of the datasets holds (a config with `[bodies] first` past the other's bodies makes
/// such a dataset).
pub fn open_more_data(data: &Dataset, dirs: &[PathBuf]) -> Result<Vec<Dataset>, LearnError> {
    let mut seen: std::collections::HashMap<u64, PathBuf> = data
        .manifest
        .samples()
        .map(|s| (s.plan.id, data.dir.clone()))
        .collect();
    // Bodies by their shape seed: the same seed and body number give the same body, even
    // under other sample ids (another `poses_per_body`).
    let mut bodies: std::collections::HashMap<u64, PathBuf> = data
        .manifest
        .samples()
        .map(|s| (s.plan.shape_seed, data.dir.clone()))
        .collect();
    let mut out = Vec::new();
    for dir in dirs {
        let more = Dataset::open(dir)?;
        let refuse = |what: String| {
            LearnError::Mismatch(format!(
                "--more-data {} cannot train beside {}: {what}",
                dir.display(),
                data.dir.display()
            ))
        };
        if more.manifest.static_sha256 != data.manifest.static_sha256 {
            return Err(refuse(format!(
                "its static.safetensors (garment template, faces and body) differs, sha256 {}... against {}...",
                dataset::manifest::short_hex(&more.manifest.static_sha256),
                dataset::manifest::short_hex(&data.manifest.static_sha256)
            )));
        }
        if more.manifest.size_templates != data.manifest.size_templates {
            return Err(refuse("its garment's size templates differ".into()));
        }
        if more.count(Split::Train) == 0 {
            return Err(refuse("it has no converged training drapes".into()));
        }
        let mut own = std::collections::HashSet::new();
        for s in more.manifest.samples() {
            if let Some(other) = seen.insert(s.plan.id, dir.clone()) {
                return Err(refuse(format!(
                    "both it and {} hold sample id {} (give its config a `[bodies] first` past the other's bodies)",
                    other.display(),
                    s.plan.id
                )));
            }
            if own.insert(s.plan.shape_seed)
                && let Some(other) = bodies.insert(s.plan.shape_seed, dir.clone())
            {
                return Err(refuse(format!(
                    "its body {} is one of {}'s (the same shape seed; give its config the other's `poses_per_body` and a `[bodies] first` past the other's bodies)",
                    s.plan.body,
                    other.display()
                )));
            }
        }
        out.push(more);
    }
    Ok(out)
}

/// The epoch's groups: the training shards shuffled and read `shuffle_shards` at a time.
/// Each group is shuffled and cut into batches on its own, so its last batch may be
/// partial: the epoch has `sum(ceil(rows / batch_size))` batches. The training loop checks
/// each group's rows against `rows`, so the schedule's length cannot drift from the loop.
fn epoch_groups(
    sources: &[&Dataset],
    config: &TrainConfig,
    subset: Option<&std::collections::HashSet<u64>>,
    epoch: usize,
) -> Vec<Group> {
    let mut shards: Vec<(usize, &dataset::manifest::ShardRecord)> = sources
        .iter()
        .enumerate()
        .flat_map(|(i, d)| {
            d.manifest
                .shards
                .iter()
                .filter(|s| s.split == Split::Train)
                .map(move |s| (i, s))
        })
        .collect();
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(config.seed ^ (epoch as u64) << 32);
    shards.shuffle(&mut rng);
    shards
        .chunks(config.shuffle_shards)
        .map(|c| Group {
            rows: c
                .iter()
                .flat_map(|(_, s)| s.samples.iter())
                .filter(|r| r.ok && subset.is_none_or(|k| k.contains(&r.plan.id)))
                .count(),
            shards: c.iter().map(|(i, s)| (*i, s.file.clone())).collect(),
        })
        .collect()
}

/// Fits the prior of `model.prior` (linear or kernel) on the training samples (`subset` of
/// them if given) and keeps the fit on all of them in `run/prior.safetensors`. The fit is
/// deterministic, so a resumed run makes it again and finds the file it wrote.
fn fit_prior(
    data: &Dataset,
    subset: Option<&std::collections::HashSet<u64>>,
    kind: crate::config::PriorKind,
    run: &Path,
    progress: bool,
) -> Result<std::sync::Arc<crate::prior::Prior>, LearnError> {
    let prior = crate::prior::Prior::fit(data, subset, kind, progress)?;
    let tried: Vec<String> = prior
        .tried
        .iter()
        .map(|(what, e)| format!("{what}: {e:.2} cm"))
        .collect();
    eprintln!(
        "{} prior: {} training samples, {} (validation Edist {})",
        kind.name(),
        prior.held_out.len(),
        prior.model.describe(),
        tried.join(", ")
    );
    // A resumed run finds its file: it must be this fit, or inference would use another
    // prior than training did.
    let path = run.join("prior.safetensors");
    let bytes = prior.model.encode();
    if path.exists() {
        let kept = std::fs::read(&path).map_err(|source| LearnError::Io {
            path: path.clone(),
            source,
        })?;
        if kept != bytes {
            return Err(LearnError::Mismatch(format!(
                "{} differs from the {} prior fitted again from the data: the data or the \
                 program changed since the run started",
                path.display(),
                kind.name()
            )));
        }
    } else {
        sim::io::write_all_or_nothing(&[(&path, &bytes)]).map_err(|e| LearnError::Io {
            path: e.path.clone(),
            source: e.source,
        })?;
    }
    Ok(std::sync::Arc::new(prior))
}

/// Trains (or resumes) a run. Returns the final state.
pub fn train(config: &TrainConfig, opts: &TrainOptions) -> Result<State, LearnError> {
    let data = Dataset::open(&opts.data)?;
    let more = open_more_data(&data, &opts.more_data)?;
    if !more.is_empty() && !config.model.prior.is_none() {
        return Err(LearnError::Config(format!(
            "model.prior = \"{}\" is fitted on one dataset's training drapes: it cannot train with --more-data",
            config.model.prior.name()
        )));
    }
    let sources: Vec<&Dataset> = std::iter::once(&data).chain(&more).collect();
    let train_drapes = data.count(Split::Train);
    let body = data.statics.canonical_body.len();
    if config.model.body_points > body {
        return Err(LearnError::Config(format!(
            "model.body_points = {} is more than the body's {body} vertices",
            config.model.body_points
        )));
    }
    if train_drapes == 0 {
        return Err(LearnError::Config(format!(
            "{} has no drapes in its training split to train on (`drape data info {}` lists its splits)",
            opts.data.display(),
            opts.data.display()
        )));
    }
    let device = Device::default().autodiff();
    let setup = Setup::new(config, &data, &device);
    let info = RunInfo {
        garment: data.manifest.config["garment"]
            .as_str()
            .unwrap_or("?")
            .to_string(),
        vertices: setup.topology.vertices,
        resolution: data.manifest.config["resolution"].as_u64().unwrap_or(0) as usize,
        dataset: data.manifest.name.clone(),
        manifest_sha256: crate::run::manifest_sha256(&opts.data)?,
        drapes_sha256: Some(data.manifest.drapes_sha256()),
        init: opts.init.clone(),
        curvature_scales: None,
        faces_sha256: Some(crate::run::faces_sha256(&data.statics.garment_triangles)),
        more_data: more
            .iter()
            .map(|d| {
                Ok(MoreData {
                    dataset: d.manifest.name.clone(),
                    manifest_sha256: crate::run::manifest_sha256(&d.dir)?,
                    drapes_sha256: d.manifest.drapes_sha256(),
                    train_drapes: d.count(Split::Train),
                })
            })
            .collect::<Result<_, LearnError>>()?,
    };
    // A fresh fine-tune: `init` is checked before the run's folder is written, so that a
    // refused one leaves nothing behind; its weights are loaded below.
    let last = opts.run.join("last.bpk");
    let init = opts.init.as_ref().filter(|_| !last.exists());
    if let Some(init) = init {
        crate::run::check_init(&config.model, init, &info)?;
    }
    let _lock = crate::run::prepare_folder(&opts.run, config, &info)?;
    let mut state = State::load(&opts.run)?.unwrap_or_default();
    if state.finished {
        return Ok(state);
    }
    // Model and optimiser: resume, or initialise (from scratch or from --init).
    device.seed(config.seed);
    let mut model = GarNet::new(&config.model, setup.params, &device);
    let mut optim = AdamConfig::new()
        .with_epsilon(config.adam_epsilon as f32)
        .init();
    if last.exists() {
        model = load_model(model, &last)?;
        let op = opts.run.join("last-optim.bpk");
        optim = optim.load(&op).map_err(ck(&op))?;
    } else if let Some(init) = init {
        model = load_model(model, &init.join("best.bpk"))?;
    }
    // max_train_samples: the same samples every epoch, the lowest ids of the split.
    let subset: Option<std::collections::HashSet<u64>> =
        (config.max_train_samples > 0).then(|| {
            let mut ids: Vec<u64> = sources
                .iter()
                .flat_map(|d| d.manifest.samples())
                .filter(|s| s.plan.split == Split::Train && s.ok)
                .map(|s| s.plan.id)
                .collect();
            ids.sort_unstable();
            ids.truncate(config.max_train_samples);
            ids.into_iter().collect()
        });
    let mut setup = setup;
    if !config.model.prior.is_none() {
        setup.pre = setup.pre.with_prior(fit_prior(
            &data,
            subset.as_ref(),
            config.model.prior,
            &opts.run,
            opts.progress,
        )?);
    }
    if config.loss.has_curvature() && config.loss.rescale_curvature {
        setup.scales = curvature_scales(&setup, &model, &data, &opts.run)?;
    }
    // Every epoch's groups; steps of the whole run (the learning-rate schedule's length)
    // and before each epoch.
    let groups: Vec<Vec<Group>> = (0..config.epochs)
        .map(|e| epoch_groups(&sources, config, subset.as_ref(), e))
        .collect();
    let per_epoch: Vec<usize> = groups
        .iter()
        .map(|epoch| {
            epoch
                .iter()
                .map(|g| g.rows.div_ceil(config.batch_size))
                .sum()
        })
        .collect();
    let total_steps: usize = per_epoch.iter().sum();
    let bar = crate::run::progress(opts.progress, total_steps as u64);
    bar.set_position(
        (per_epoch[..state.epoch.min(config.epochs)]
            .iter()
            .sum::<usize>()
            + state.batch) as u64,
    );
    // Without a terminal (a log file, `nohup`), a line a minute and one per epoch instead.
    let lines = crate::run::LogLines::new(opts.progress, &bar, "train", "batches")
        .starting_at(bar.position());
    let workers = Workers::new(opts.workers, config.batch_size);
    let started = Instant::now();
    let seconds_before = state.seconds;
    let cap = config.wall_clock_minutes * 60.0;
    let mut last_save = Instant::now();
    // Rows past the checkpoint (a process stopped before its next save) are dropped:
    // those steps and epochs run again from here.
    let field = |l: &str, i: usize| l.split(',').nth(i).and_then(|f| f.parse::<u64>().ok());
    let (done_steps, done_epochs) = (state.steps, state.epoch as u64);
    let mut steps_log = crate::run::append_after(
        &opts.run.join("steps.csv"),
        &format!("epoch,batch,step,seconds,{}", Terms::HEADER),
        |l| field(l, 2).is_some_and(|s| s <= done_steps),
    )?;
    let mut log = crate::run::append_after(
        &opts.run.join("log.csv"),
        &format!("epoch,split,samples,seconds,{}", Terms::HEADER),
        |l| field(l, 0).is_some_and(|e| e < done_epochs),
    )?;
    while state.epoch < config.epochs {
        let mut sum = Terms::default();
        let mut seen = 0usize;
        let mut batch_index = 0usize;
        // Batches of this epoch run before a resume (their terms are not in `sum`).
        let resumed_after = state.batch;
        for group in &groups[state.epoch] {
            let mut rows = Vec::new();
            for (i, f) in &group.shards {
                rows.extend(sources[*i].read_shard(f)?);
            }
            if let Some(keep) = &subset {
                rows.retain(|r| keep.contains(&r.id));
            }
            if rows.len() != group.rows {
                let names: Vec<String> = group
                    .shards
                    .iter()
                    .map(|(i, f)| sources[*i].dir.join(f).display().to_string())
                    .collect();
                return Err(LearnError::Mismatch(format!(
                    "shards {} hold {} training rows; the manifests list {}",
                    names.join(", "),
                    rows.len(),
                    group.rows
                )));
            }
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(
                config
                    .seed
                    .wrapping_mul(31)
                    .wrapping_add(state.epoch as u64),
            );
            rows.sort_by_key(|r| r.id);
            rows.shuffle(&mut rng);
            for chunk in rows.chunks(config.batch_size) {
                batch_index += 1;
                if batch_index <= state.batch {
                    continue; // done before an interruption
                }
                let (grads, terms) = setup.gradients(&model, chunk, &workers);
                let lr = config.rate_at(state.steps, total_steps as u64);
                model = optim.step(lr, model, grads);
                state.batch = batch_index;
                state.steps += 1;
                state.seconds = seconds_before + started.elapsed().as_secs_f64();
                sum.add(&terms, chunk.len() as f64);
                seen += chunk.len();
                writeln!(
                    steps_log,
                    "{},{},{},{:.2},{}",
                    state.epoch,
                    batch_index,
                    state.steps,
                    state.seconds,
                    terms.csv()
                )
                .ok();
                bar.inc(1);
                bar.set_message(format!(
                    "epoch {} loss {:.3e} vert {:.2e} pen {:.2e} norm {:.3} bend {:.2e} Edist {:.2} cm",
                    state.epoch + 1, terms.total, terms.vert, terms.pen, terms.norm, terms.bend, terms.edist_cm
                ));
                lines.tick(&bar);
                let out_of_time = cap > 0.0 && state.seconds - seconds_before >= cap;
                if out_of_time || last_save.elapsed().as_secs_f64() > 600.0 {
                    crate::run::checkpoint(&opts.run, &model, &optim, &state)?;
                    last_save = Instant::now();
                }
                if out_of_time {
                    let why = format!(
                        "wall-clock cap of {} min reached; run again to continue",
                        config.wall_clock_minutes
                    );
                    if lines.is_on() {
                        lines.finish(&bar);
                        eprintln!("train: {why}");
                    }
                    bar.abandon_with_message(why);
                    crate::run::end_bar_line(&bar);
                    return Ok(state);
                }
            }
        }
        let mut summary = format!("epoch {}/{}", state.epoch + 1, config.epochs);
        if seen > 0 {
            let sum = sum.mean_of(seen);
            summary.push_str(&format!(
                ": training loss {:.3e}, Edist {:.2} cm",
                sum.total, sum.edist_cm
            ));
            if resumed_after > 0 {
                summary.push_str(&format!(
                    " (its last {seen} samples, resumed after batch {resumed_after})"
                ));
            }
            writeln!(
                log,
                "{},train,{},{:.2},{}",
                state.epoch,
                seen,
                state.seconds,
                sum.csv()
            )
            .ok();
        }
        if seen == 0 {
            summary.push_str(": its training batches all ran before the resume");
        }
        let val = evaluate(&setup, &model.valid(), &data, Split::Val)?;
        if let Some((v, n)) = val {
            writeln!(
                log,
                "{},val,{},{:.2},{}",
                state.epoch,
                n,
                state.seconds,
                v.csv()
            )
            .ok();
            let best = state.best_val.is_none_or(|b| v.total < b);
            summary.push_str(&format!(
                "; validation loss {:.3e}, Edist {:.2} cm{}",
                v.total,
                v.edist_cm,
                if best { " (best so far)" } else { "" }
            ));
            if best {
                state.best_val = Some(v.total);
                save_model(&model, &opts.run.join("best.bpk"))?;
            }
        } else if state.epoch + 1 == config.epochs {
            save_model(&model, &opts.run.join("best.bpk"))?;
        }
        state.epoch += 1;
        state.batch = 0;
        state.finished = state.epoch >= config.epochs;
        crate::run::checkpoint(&opts.run, &model, &optim, &state)?;
        last_save = Instant::now();
        lines.note(&bar, &summary);
    }
    bar.finish();
    crate::run::end_bar_line(&bar);
    lines.finish(&bar);
    Ok(state)
}

/// The curvature factors of a run: read from its `run.json`, or measured on the first
/// batches of training data (at most 4) with the model as it starts, then saved there.
fn curvature_scales(
    setup: &Setup,
    model: &GarNet,
    data: &Dataset,
    run: &Path,
) -> Result<CurvatureScales, LearnError> {
    let ip = run.join("run.json");
    let mut info: RunInfo = crate::run::read_json(&ip)?
        .ok_or_else(|| LearnError::Mismatch(format!("{} is missing", ip.display())))?;
    if let Some(s) = info.curvature_scales {
        return Ok(s);
    }
    let first = data
        .manifest
        .shards
        .iter()
        .find(|s| s.split == Split::Train)
        .ok_or_else(|| LearnError::Config("the dataset has no training samples".into()))?;
    let mut rows = data.read_shard(&first.file)?;
    rows.truncate(4 * setup.config.batch_size);
    let (sum, n) = mean_terms(&plain(setup), &model.valid(), &rows);
    let t = sum.mean_of(n);
    let scales = CurvatureScales::measure(&t, &setup.config.loss);
    info.curvature_scales = Some(scales);
    crate::run::write_files(&[(&ip, &crate::run::json(&info))])?;
    Ok(scales)
}

/// The same setup on the plain (non-autodiff) device.
fn plain(setup: &Setup) -> Setup {
    let device = setup.device.clone().inner();
    Setup {
        graph: Graph::new(&setup.topology, &device),
        loss_topology: LossTopology::new(&setup.topology, &device),
        device,
        ..setup.clone()
    }
}

/// Sum of the loss terms of `rows` (weighted by samples) and their count, no gradients.
fn mean_terms(plain: &Setup, model: &GarNet, rows: &[dataset::shard::Row]) -> (Terms, usize) {
    let mut sum = Terms::default();
    let mut n = 0;
    for chunk in rows.chunks(plain.config.batch_size) {
        let prepared: Vec<Prepared> = chunk.par_iter().map(|r| plain.pre.prepare_row(r)).collect();
        let refs: Vec<&Prepared> = prepared.iter().collect();
        let (_, t) = plain.losses(model, &refs);
        sum.add(&t, refs.len() as f64);
        n += refs.len();
    }
    (sum, n)
}

/// Mean loss terms of a split (`None` if it is empty), without gradients.
pub fn evaluate(
    setup: &Setup,
    model: &GarNet,
    data: &Dataset,
    split: Split,
) -> Result<Option<(Terms, usize)>, LearnError> {
    let plain = plain(setup);
    let mut sum = Terms::default();
    let mut n = 0usize;
    let files: Vec<String> = data
        .manifest
        .shards
        .iter()
        .filter(|s| s.split == split)
        .map(|s| s.file.clone())
        .collect();
    for f in files {
        let (s, k) = mean_terms(&plain, model, &data.read_shard(&f)?);
        sum.add(&s, 1.0);
        n += k;
    }
    if n == 0 {
        return Ok(None);
    }
    Ok(Some((sum.mean_of(n), n)))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The measured factors make the weighted curvature terms add up to the weighted
    /// physics term times `physics_scale`, shared in the ratio of their configured weights
    /// (the paper's 500 : 50 : 10 for L_RQ); a term that is off, or zero, keeps 1.
    #[test]
    fn curvature_scales_share_the_physics_budget_by_weight() {
        let w = crate::config::LossWeights {
            physics_scale: 0.5,
            rq: [500.0, 50.0, 10.0],
            mc: 0.0,
            umc: 2.0,
            ..Default::default()
        };
        let t = Terms {
            vert: 4e-4,
            pen: 1e-4,
            norm: 3e-2,
            bend: 2e-3,
            rq: [1e-9, 4e-9, 2e-8],
            mc: 7.0,
            umc: 3e-6,
            ..Default::default()
        };
        let s = CurvatureScales::measure(&t, &w);
        let budget = 0.5 * t.physics(&w);
        assert!(budget > 0.0);
        let weighted = [
            s.rq[0] * w.rq[0] * t.rq[0],
            s.rq[1] * w.rq[1] * t.rq[1],
            s.rq[2] * w.rq[2] * t.rq[2],
            s.umc * w.umc * t.umc,
        ];
        let sum: f64 = weighted.iter().sum();
        assert!((sum - budget).abs() < 1e-9 * budget, "{sum} vs {budget}");
        for (k, share) in [500.0, 50.0, 10.0, 2.0].iter().enumerate() {
            let want = budget * share / 562.0;
            assert!(
                (weighted[k] - want).abs() < 1e-9 * want,
                "term {k}: {} vs {want}",
                weighted[k]
            );
        }
        assert_eq!(s.mc, 1.0, "L_MC is off");
        let none = CurvatureScales::measure(
            &Terms {
                rq: [0.0; 3],
                umc: 0.0,
                ..t
            },
            &w,
        );
        assert_eq!(none, CurvatureScales::default());
    }
}
