//! Training throughput: samples per second of full training steps (inputs, forward pass
//! and losses, backward pass, Adam step), with the time of each stage.

use std::path::Path;
use std::time::Instant;

use burn::optim::{AdamConfig, GradientsParams};
use burn::tensor::Device;
use dataset::config::Split;
use dataset::reader::Dataset;
use rayon::prelude::{IntoParallelRefIterator, ParallelIterator};

use crate::LearnError;
use crate::config::TrainConfig;
use crate::data::Prepared;
use crate::model::GarNet;
use crate::train::{Setup, Workers};

/// Measured training throughput.
#[derive(Debug, Clone, serde::Serialize)]
pub struct TrainRate {
    /// Variant name.
    pub variant: String,
    /// Garment vertices.
    pub vertices: usize,
    /// Body points.
    pub body_points: usize,
    /// Trainable parameters.
    pub parameters: usize,
    /// Samples per batch.
    pub batch_size: usize,
    /// Timed batches (after one warm-up batch).
    pub batches: usize,
    /// Training samples per second, whole steps.
    pub samples_per_second: f64,
    /// Gradient workers ([`crate::train::Workers`]).
    pub workers: usize,
    /// Seconds per batch: inputs, forward pass, losses and backward pass.
    pub gradients: f64,
    /// Seconds per batch of the gradients' stages, with one worker (with several they
    /// overlap): inputs (k-NN, normals, collation), forward pass and losses, backward pass.
    pub stages: Option<[f64; 3]>,
    /// Seconds per batch: Adam step.
    pub step: f64,
}

/// Times `batches` training steps (after one warm-up) on the training split of `data`, the
/// gradients on `workers` ([`Workers::new`]; 0: one per rayon thread).
pub fn train_rate(
    config: &TrainConfig,
    data: &Path,
    batches: usize,
    workers: usize,
) -> Result<TrainRate, LearnError> {
    let workers = Workers::new(workers, config.batch_size);
    let data = Dataset::open(data)?;
    let device = Device::default().autodiff();
    device.seed(config.seed);
    let setup = Setup::new(config, &data, &device);
    let mut model = GarNet::new(&config.model, setup.params, &device);
    let parameters = burn::module::Module::num_params(&model);
    let mut optim = AdamConfig::new()
        .with_epsilon(config.adam_epsilon as f32)
        .init();
    let mut rows = Vec::new();
    let need = (batches + 1) * config.batch_size;
    for s in data
        .manifest
        .shards
        .iter()
        .filter(|s| s.split == Split::Train)
    {
        rows.extend(data.read_shard(&s.file)?);
        if rows.len() >= need {
            break;
        }
    }
    if rows.len() < config.batch_size {
        return Err(LearnError::Mismatch(format!(
            "{}: {} training samples, fewer than one batch of {}",
            data.dir.display(),
            rows.len(),
            config.batch_size
        )));
    }
    let (mut prepare, mut forward, mut backward, mut step) = (0.0, 0.0, 0.0, 0.0);
    let mut gradients = 0.0;
    let mut samples = 0usize;
    let mut timed = 0usize;
    for b in 0..=batches {
        let start = (b * config.batch_size) % (rows.len() - config.batch_size + 1);
        let chunk = &rows[start..start + config.batch_size];
        let t0 = Instant::now();
        let grads = if workers.count() > 1 {
            setup.gradients(&model, chunk, &workers).0
        } else {
            // One worker: the same work as `Setup::gradients`, timed stage by stage.
            let prepared: Vec<Prepared> =
                chunk.par_iter().map(|r| setup.pre.prepare_row(r)).collect();
            let refs: Vec<&Prepared> = prepared.iter().collect();
            let t1 = Instant::now();
            let (total, _) = setup.losses(&model, &refs);
            let t2 = Instant::now();
            let grads = GradientsParams::from_grads(total.backward(), &model);
            if b > 0 {
                prepare += (t1 - t0).as_secs_f64();
                forward += (t2 - t1).as_secs_f64();
                backward += t2.elapsed().as_secs_f64();
            }
            grads
        };
        let t3 = Instant::now();
        model = optim.step(config.learning_rate, model, grads);
        let t4 = Instant::now();
        if b > 0 {
            gradients += (t3 - t0).as_secs_f64();
            step += (t4 - t3).as_secs_f64();
            samples += chunk.len();
            timed += 1;
        }
    }
    let n = timed.max(1) as f64;
    Ok(TrainRate {
        variant: config.model.variant.paper_name().to_string(),
        vertices: setup.topology.vertices,
        body_points: config.model.body_points,
        parameters,
        batch_size: config.batch_size,
        batches: timed,
        samples_per_second: samples as f64 / (gradients + step),
        workers: workers.count(),
        gradients: gradients / n,
        stages: (workers.count() == 1).then(|| [prepare / n, forward / n, backward / n]),
        step: step / n,
    })
}
