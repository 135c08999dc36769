//! Inference: a run folder's best weights turned into drapes. The batch API
//! ([`Predictor::predict`]) is what `drape predict` and the evaluation call.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use burn::tensor::Device;
use dataset::shard::{Row, Static};
use glam::Vec3;

use crate::LearnError;
use crate::config::TrainConfig;
use crate::data::{Prepared, Preprocessor, collate, row_params};
use crate::linear::Linear;
use crate::model::{GarNet, Graph, Swap};
use crate::prior::{Prior, PriorMap};
use crate::run::open_run;
use crate::topology::Topology;
use crate::train::{RunInfo, Workers, load_model};

/// A trained network ready to drape its garment, on the plain (no autodiff) device.
#[derive(Debug)]
pub struct Predictor {
    /// The run's training config (model widths included).
    pub config: TrainConfig,
    /// The run's garment and dataset.
    pub info: RunInfo,
    model: GarNet,
    pre: Preprocessor,
    graph: Graph,
    /// Length of the shape-and-pose vector ([`crate::data::param_count`]).
    params: usize,
    device: Device,
    /// Threads a batch's drapes are shared among ([`Predictor::with_workers`]).
    workers: Workers,
}

/// Where the time of one [`Predictor::predict`] call went, s.
#[derive(Debug, Clone, Copy, Default)]
pub struct Timing {
    /// Inputs: root-relative coordinates, body normals, k-NN searches (GarNet-Local).
    pub inputs: f64,
    /// Both streams and the fusion, read back to the CPU.
    pub network: f64,
}

impl Predictor {
    /// Loads `run`'s best weights (and its prior, `prior.safetensors`, if the model
    /// has one) for the garment and body described by `statics` (the dataset's static
    /// file, or the template and body model). Refuses a garment whose vertex count or,
    /// for runs that record them, triangles are not the run's.
    pub fn open(run: &Path, statics: &Static) -> Result<Self, LearnError> {
        let (config, info) = open_run(run)?;
        let n = statics.garment_vertices.len();
        if n != info.vertices {
            return Err(LearnError::Mismatch(format!(
                "{} was trained on {} with {} vertices; this garment has {n}",
                run.display(),
                info.garment,
                info.vertices
            )));
        }
        crate::run::check_faces(
            run,
            &info,
            &crate::run::faces_sha256(&statics.garment_triangles),
        )?;
        let best = run.join("best.bpk");
        if !best.exists() {
            return Err(LearnError::Mismatch(format!(
                "{} has no best.bpk yet: train at least one epoch",
                run.display()
            )));
        }
        let mut p = Self::untrained(&config, statics);
        p.model = load_model(p.model, &best)?;
        if !config.model.prior.is_none() {
            let path = run.join("prior.safetensors");
            let prior = PriorMap::load(&path, config.model.prior)?;
            if prior.vertices() != n {
                return Err(LearnError::Mismatch(format!(
                    "{}: a {} prior for {} vertices; the garment has {n}",
                    path.display(),
                    config.model.prior.name(),
                    prior.vertices()
                )));
            }
            let features =
                crate::linear::features_from_params(&vec![
                    0.0;
                    crate::data::param_count(statics.bones)
                ])
                .len();
            if prior.features() != features {
                return Err(LearnError::Mismatch(format!(
                    "{}: a {} prior of {} shape and pose features; this body has {features} \
                     ({} bones)",
                    path.display(),
                    config.model.prior.name(),
                    prior.features(),
                    statics.bones
                )));
            }
            p.pre = p.pre.with_prior(Arc::new(Prior::of(prior)));
        }
        p.info = info;
        Ok(p)
    }

    /// A freshly initialised network of `config` for `statics`' garment (for timing: the
    /// cost of a forward pass does not depend on the weights).
    pub fn untrained(config: &TrainConfig, statics: &Static) -> Self {
        let device = Device::default();
        device.seed(config.seed);
        let params = crate::data::param_count(statics.bones);
        let n = statics.garment_vertices.len();
        let topology = Topology::new(n, &statics.garment_triangles);
        let mut pre = Preprocessor::new(statics, &config.model, config.loss.pen_push_out, 0);
        if !config.model.prior.is_none() {
            // The linear map's cost; a kernel prior's (one pass over its training drapes)
            // needs them, so an untrained network times the linear one.
            let features = crate::linear::features_from_params(&vec![0.0; params]).len();
            pre = pre.with_prior(Arc::new(Prior::of(PriorMap::Linear(Linear::zeros(
                features, n,
            )))));
        }
        Self {
            pre,
            graph: Graph::new(&topology, &device),
            model: GarNet::new(&config.model, params, &device),
            params,
            config: config.clone(),
            info: RunInfo {
                garment: String::new(),
                vertices: n,
                resolution: 0,
                dataset: String::new(),
                manifest_sha256: String::new(),
                drapes_sha256: None,
                init: None,
                curvature_scales: None,
                faces_sha256: None,
                more_data: Vec::new(),
            },
            device,
            workers: Workers::new(0, usize::MAX),
        }
    }

    /// Shares a batch's drapes among `n` threads (0: one per thread of rayon's pool, the
    /// default), each drape's forward pass on one thread: on this CPU a batch runs
    /// faster per drape as single drapes side by side than as one `[B, N, ...]` pass,
    /// whose intermediates fall out of cache (docs/bench.md). 1: the whole batch in one
    /// pass on rayon's pool. A single drape always runs on rayon's pool.
    pub fn with_workers(mut self, n: usize) -> Self {
        self.workers = Workers::new(n, usize::MAX);
        self
    }

    /// How many threads a batch's drapes are shared among.
    pub fn workers(&self) -> usize {
        self.workers.count()
    }

    /// Forward FLOPs per drape of a network of widths `model` on this garment (the run's
    /// own with `&self.config.model`), [`crate::model::forward_flops`].
    pub fn forward_flops(&self, model: &crate::config::ModelConfig) -> f64 {
        crate::model::forward_flops(model, self.params, self.graph.vertices, self.graph.slots)
    }

    /// Trainable parameters of the network.
    pub fn parameters(&self) -> usize {
        burn::module::Module::num_params(&self.model)
    }

    /// Prepares one body and its DQS-warped garment (world coordinates; `root` is the
    /// body's root joint; `params` the shape parameters then the pose quaternions).
    pub fn prepare(
        &self,
        body: &[Vec3],
        root: Vec3,
        params: Vec<f32>,
        warped: &[Vec3],
    ) -> Prepared {
        self.pre.prepare(0, body, root, params, warped, None)
    }

    /// Prepares a dataset row (its simulated garment is ignored).
    pub fn prepare_row(&self, row: &Row) -> Prepared {
        self.pre.prepare(
            row.id,
            &row.body,
            row.root,
            row_params(row),
            &row.warped,
            None,
        )
    }

    /// G^P = M + T^P for every sample, in world coordinates: one pass over the batch, or
    /// with several workers ([`Predictor::with_workers`]) the drapes shared among them,
    /// one drape per pass (the same predictions up to rounding).
    pub fn predict(&self, samples: &[&Prepared]) -> Vec<Vec<Vec3>> {
        if self.workers.count() < 2 || samples.len() < 2 {
            return self.predict_batch(samples);
        }
        let parts: Vec<Vec<Vec<Vec3>>> = self.workers.share(samples, |part| {
            part.iter()
                .flat_map(|x| self.predict_batch(std::slice::from_ref(x)))
                .collect()
        });
        parts.into_iter().flatten().collect()
    }

    /// G^P = M + T^P for every sample, as one batch on the calling thread's pool.
    fn predict_batch(&self, samples: &[&Prepared]) -> Vec<Vec<Vec3>> {
        self.predict_swapped(samples, Swap::NONE)
    }

    /// G^P = M + T^P for every sample, as one batch, each drape reading the body features
    /// that `swap` names from the next drape of `samples` (the last from the first):
    /// [`GarNet::forward_swapped`].
    pub fn predict_swapped(&self, samples: &[&Prepared], swap: Swap) -> Vec<Vec<Vec3>> {
        let batch = collate(samples, &self.config.model, &self.device);
        let t = self.model.forward_swapped(&batch.input, &self.graph, swap); // [B, N, 3]
        let v = t
            .into_data()
            .try_into_vec::<f32>()
            .expect("f32 predictions");
        let n = samples[0].warped.len();
        samples
            .iter()
            .enumerate()
            .map(|(s, x)| {
                x.warped
                    .iter()
                    .zip(v[s * n * 3..(s + 1) * n * 3].chunks_exact(3))
                    .map(|(m, d)| *m + Vec3::from_slice(d) + x.root)
                    .collect()
            })
            .collect()
    }

    /// [`Predictor::predict`] from rows, timed: inputs (k-NN included) and network.
    pub fn predict_rows(&self, rows: &[Row]) -> (Vec<Vec<Vec3>>, Timing) {
        let t0 = Instant::now();
        let prepared: Vec<Prepared> = rows.iter().map(|r| self.prepare_row(r)).collect();
        let inputs = t0.elapsed().as_secs_f64();
        let refs: Vec<&Prepared> = prepared.iter().collect();
        let t1 = Instant::now();
        let out = self.predict(&refs);
        let network = t1.elapsed().as_secs_f64();
        (out, Timing { inputs, network })
    }
}
