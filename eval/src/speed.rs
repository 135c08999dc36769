//! `drape bench speedup`: simulator time over network time per drape, measured in one run
//! on the same test samples, at the same vertex count, with the simulator config that made
//! the dataset.
//!
//! - Simulator, full drape (the paper's PBS): from the template on the canonical body (or,
//!   for a dataset in sizes, the sample's size on its reference body), morphing to the
//!   sample's shape and pose, then settling (the dataset's protocol).
//! - Simulator, PBS-dagger: from the DQS-warped garment M with the body already in the
//!   target pose, settling only.
//! - Network: the DQS warp, the inputs (body normals, the k-NN searches of GarNet-Local)
//!   and both streams, at batch 1 (per sample) and batch 16 (per sample of a batch).
//!
//! The simulator runs one drape at a time on all of rayon's threads (constraint colours in
//! parallel), the network on the same threads.

use rayon::prelude::{IntoParallelRefIterator, ParallelIterator};
use std::time::Instant;

use dataset::config::Split;
use dataset::reader::Dataset;
use dataset::shard::Row;
use dataset::wardrobe::{Start, Wardrobe};
use glam::Vec3;
use learn::config::{ModelConfig, Variant};
use learn::predict::Predictor;
use serde::{Deserialize, Serialize};
use sim::body::pose::Pose;
use sim::body::{BodyModel, PosedBody, ShapeParams, ShapedBody};
use sim::cloth::drape::{self, BodyMorph};
use sim::garment::Template;

use crate::evaluate::EvalError;
use crate::metrics::{edist_cm, mean, median};

/// Options of the measurement.
#[derive(Debug, Clone)]
pub struct SpeedOptions {
    /// Test samples timed (the first ones of the split).
    pub samples: usize,
    /// The batched measurement's batch size.
    pub batch: usize,
    /// Timed repeats of each network measurement (after one warm-up); the median counts.
    pub repeats: usize,
    /// Split to take samples from.
    pub split: Split,
    /// Threads the batched measurement's drapes are shared among
    /// (`learn::predict::Predictor::with_workers`; 0: one per rayon thread).
    pub workers: usize,
}

/// Times of one sample (s).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SampleSpeed {
    /// Sample id.
    pub id: u64,
    /// Full simulator drape (morph and settle), wall time.
    pub pbs: f64,
    /// Frames of that drape (morph + settle).
    pub pbs_frames: u32,
    /// PBS-dagger: settle from the warped garment, wall time.
    pub pbs_dagger: f64,
    /// Frames of that drape.
    pub pbs_dagger_frames: u32,
    /// Why the full drape failed, if it did.
    pub pbs_failure: Option<String>,
    /// Why PBS-dagger failed, if it did (e.g. a warped garment starting inside the body).
    pub pbs_dagger_failure: Option<String>,
    /// Edist between this run's full drape and the dataset's (cm; 0 when the simulator is
    /// deterministic across thread counts, as it is designed to be).
    pub pbs_vs_dataset_cm: f64,
    /// Edist of PBS-dagger's drape to the dataset's (cm).
    pub dagger_vs_dataset_cm: f64,
    /// DQS warp (s).
    pub warp: f64,
    /// Inputs at batch 1 (s).
    pub inputs: f64,
    /// Both streams at batch 1 (s).
    pub network: f64,
}

fn one() -> usize {
    1
}

/// The whole measurement.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct SpeedReport {
    /// Network variant.
    pub network: String,
    /// Garment vertices.
    pub vertices: usize,
    /// Threads used.
    pub threads: usize,
    /// Threads the batched measurement's drapes were shared among (1: one pass over the
    /// batch, as every report before session 35).
    #[serde(default = "one")]
    pub workers: usize,
    /// Per sample.
    pub samples: Vec<SampleSpeed>,
    /// Batch of the batched measurement.
    pub batch: usize,
    /// Per drape at that batch: warp, inputs and network (s).
    pub batched_per_drape: f64,
    /// Network forward FLOPs per drape.
    pub flops: f64,
    /// Forward FLOPs per drape of every variant at the run's widths, by paper name.
    pub flops_by_variant: Vec<(String, f64)>,
    /// Parameters of the network.
    pub parameters: usize,
    /// Time (s) to make the template's move under each of the body model's shape targets,
    /// once per template before any drape is timed (the DQS warp's reshape sums them;
    /// 0 in reports from before session 48, whose warps smoothed each body's moves).
    #[serde(default)]
    pub shape_moves: f64,
    /// How many shape targets that was.
    #[serde(default)]
    pub shape_targets: usize,
}

impl SpeedReport {
    /// Mean full-drape time over the converged full drapes (s; NaN if none converged).
    pub fn pbs(&self) -> f64 {
        mean(
            self.samples
                .iter()
                .filter(|s| s.pbs_failure.is_none())
                .map(|s| s.pbs),
        )
    }

    /// Mean PBS-dagger time over the converged PBS-dagger drapes (s; NaN if none): a
    /// drape that fails in its first frame would make the simulator look fast.
    pub fn pbs_dagger(&self) -> f64 {
        mean(
            self.samples
                .iter()
                .filter(|s| s.pbs_dagger_failure.is_none())
                .map(|s| s.pbs_dagger),
        )
    }

    /// Mean network time per drape at batch 1 (warp, inputs, network) (s).
    pub fn network_batch1(&self) -> f64 {
        mean(self.samples.iter().map(|s| s.warp + s.inputs + s.network))
    }
}

/// One drape by the network, timed: medians over `repeats` runs after a warm-up.
#[derive(Debug, Clone)]
pub struct NetworkDrape {
    /// The DQS warp M.
    pub warped: Vec<Vec3>,
    /// The prediction G^P = M + T^P (world coordinates).
    pub prediction: Vec<Vec3>,
    /// DQS warp (s).
    pub warp: f64,
    /// Inputs: normals, k-NN searches (s).
    pub inputs: f64,
    /// Both streams (s).
    pub network: f64,
}

impl NetworkDrape {
    /// Warp, inputs and network (s).
    pub fn seconds(&self) -> f64 {
        self.warp + self.inputs + self.network
    }
}

/// Drapes `template` on `posed` (the shaped body `shaped` in a pose with root `root`,
/// shape-and-pose vector `params`) with `net`, timing each stage.
#[allow(clippy::too_many_arguments)]
pub fn network_drape(
    net: &Predictor,
    template: &Template,
    canonical: &ShapedBody<'_>,
    shaped: &ShapedBody<'_>,
    posed: &PosedBody,
    root: Vec3,
    params: &[f32],
    repeats: usize,
) -> NetworkDrape {
    let (mut w, mut i, mut n) = (Vec::new(), Vec::new(), Vec::new());
    let mut last = None;
    for r in 0..=repeats.max(1) {
        let t0 = Instant::now();
        let warped = template.warp(canonical, shaped, posed);
        let t1 = Instant::now();
        let x = net.prepare(&posed.vertices, root, params.to_vec(), &warped);
        let t2 = Instant::now();
        let prediction = net.predict(&[&x]).pop().expect("one prediction");
        let t3 = Instant::now();
        if r > 0 {
            w.push((t1 - t0).as_secs_f64());
            i.push((t2 - t1).as_secs_f64());
            n.push((t3 - t2).as_secs_f64());
        }
        last = Some((warped, prediction));
    }
    let (warped, prediction) = last.expect("ran");
    NetworkDrape {
        warped,
        prediction,
        warp: median(w),
        inputs: median(i),
        network: median(n),
    }
}

/// The sample's shape and pose, as its row stores them.
fn row_body(row: &Row) -> (ShapeParams, Pose) {
    (
        ShapeParams::from_named(row.shape),
        Pose {
            rotations: row.pose.clone(),
            root_translation: row.root,
        },
    )
}

/// Redraping stored samples as the dataset did: the dataset's config, its garment's
/// wardrobe (checked against the template the dataset was made with) and the size each
/// sample wore.
pub(crate) struct Redraper<'w> {
    /// The dataset's config.
    pub config: dataset::config::DatasetConfig,
    /// The garment: base template and sizes.
    pub wardrobe: &'w Wardrobe,
    sizes: std::collections::HashMap<u64, Option<String>>,
}

impl<'w> Redraper<'w> {
    /// Fails if `wardrobe`'s base template (built here) is not the one `data` was made
    /// with, or if it has sizes and the dataset does not (or the other way round).
    pub fn new(data: &Dataset, wardrobe: &'w Wardrobe) -> Result<Self, EvalError> {
        let config = data.manifest.dataset_config()?;
        if data.manifest.before_paced_morph() {
            eprintln!(
                "note: {} was made before the paced morph (session 15); its drapes are redraped with today's morph over its {} frames, which blends the shaped bodies instead of their shape parameters",
                data.dir.display(),
                config.sim.morph_frames
            );
        }
        let ours = &wardrobe.base.mesh.vertices;
        let theirs = &data.statics.garment_vertices;
        let drift = ours
            .iter()
            .zip(theirs)
            .map(|(a, b)| a.distance(*b))
            .fold(0.0f32, f32::max);
        if ours.len() != theirs.len() || drift > 1e-5 {
            return Err(EvalError::Invalid(format!(
                "the {} template built here differs from the one {} was made with (vertices {} and {}, largest offset {drift} m): rebuild the dataset or the template",
                config.garment,
                data.dir.display(),
                ours.len(),
                theirs.len()
            )));
        }
        // The sizes graded here must be the ones the dataset was draped in.
        let ours = wardrobe.size_fingerprints();
        let theirs = &data.manifest.size_templates;
        if &ours != theirs {
            let differ: std::collections::BTreeSet<&str> = ours
                .keys()
                .chain(theirs.keys())
                .filter(|k| ours.get(*k) != theirs.get(*k))
                .map(String::as_str)
                .collect();
            return Err(EvalError::Invalid(format!(
                "the {} sizes graded here differ from the ones {} was draped in (sizes {}): regrade them with the program that made the dataset, or regenerate it",
                config.garment,
                data.dir.display(),
                differ.into_iter().collect::<Vec<_>>().join(", ")
            )));
        }
        // The garment's friction must be the one it was draped with (a manifest written
        // before it was recorded: the config's).
        let theirs = data.manifest.friction.unwrap_or(config.sim.friction);
        let ours = wardrobe.friction();
        if ours != theirs {
            return Err(EvalError::Invalid(format!(
                "{} was draped with friction {theirs} between the {} and the body; it is {ours} here (the garment's own friction changed): regenerate the dataset",
                data.dir.display(),
                config.garment
            )));
        }
        // And its friction below its band (none in a manifest written before it existed).
        if data.manifest.below_band != wardrobe.below_band() {
            let say = |b: Option<sim::garment::def::BelowBand>| {
                b.map_or_else(|| "none".to_string(), |b| b.describe())
            };
            return Err(EvalError::Invalid(format!(
                "{} was draped with the {}'s friction below its band {}; it is {} here (the garment's `[material] below_band` changed): regenerate the dataset",
                data.dir.display(),
                config.garment,
                say(data.manifest.below_band),
                say(wardrobe.below_band())
            )));
        }
        // And its own substeps (none in a manifest written before they existed).
        if data.manifest.garment_substeps != wardrobe.substeps() {
            return Err(EvalError::Invalid(format!(
                "{} was draped with the {}'s own substeps {:?}; they are {:?} here (the garment's `[simulation]` changed): regenerate the dataset",
                data.dir.display(),
                config.garment,
                data.manifest.garment_substeps,
                wardrobe.substeps()
            )));
        }
        // And its own crease contacts (off in a manifest written before they existed).
        let on_off = |on: bool| if on { "on" } else { "off" };
        if data.manifest.garment_crease_contacts != wardrobe.crease_contacts() {
            return Err(EvalError::Invalid(format!(
                "{} was draped with the {}'s own crease contacts {}; they are {} here (the garment's `[simulation]` changed): regenerate the dataset",
                data.dir.display(),
                config.garment,
                on_off(data.manifest.garment_crease_contacts),
                on_off(wardrobe.crease_contacts()),
            )));
        }
        let sizes = data
            .manifest
            .samples()
            .map(|r| (r.plan.id, r.size.clone()))
            .collect();
        Ok(Self {
            config,
            wardrobe,
            sizes,
        })
    }

    /// Judges a redrape of `row` as `drape gen` judged the dataset's: slid down the body if
    /// its top opening came to rest too far below the row's warp M.
    pub fn judge(&self, d: &mut drape::DrapeResult, row: &Row) {
        d.judge_slide(self.wardrobe.top_opening(), &row.warped);
    }

    /// Where the dataset's drape of `row` started: its size's template and reference body.
    pub fn start(&self, row: &Row) -> Result<Start<'w>, EvalError> {
        let size = self.sizes.get(&row.id).ok_or_else(|| {
            EvalError::Invalid(format!("sample {} is not in the manifest", row.id))
        })?;
        self.wardrobe
            .start_of(size.as_deref())
            .map_err(|e| EvalError::Invalid(format!("sample {}: {e}", row.id)))
    }

    /// The body motion of the dataset's drape protocol for `row`: from the start's
    /// reference body in its rest pose to the row's shape and pose.
    pub fn morph<'m>(
        &self,
        model: &'m BodyModel,
        row: &Row,
        start: &Start<'_>,
    ) -> Result<BodyMorph<'m>, EvalError> {
        let (shape, pose) = row_body(row);
        BodyMorph::new(model, start.reference, shape, pose, &self.config.sim)
            .map_err(|e| EvalError::Invalid(format!("sample {}: {e}", row.id)))
    }
}

/// Measures the speed-up of the network of `run` on the first samples of `data`'s split.
/// `progress` is called with a line per finished sample.
pub fn measure(
    run: &std::path::Path,
    data: &Dataset,
    model: &BodyModel,
    wardrobe: &Wardrobe,
    opts: &SpeedOptions,
    progress: &mut dyn FnMut(&SampleSpeed),
) -> Result<SpeedReport, EvalError> {
    let redraper = Redraper::new(data, wardrobe)?;
    let config = &redraper.config;
    let template = &wardrobe.base;
    let net = Predictor::open(run, &data.statics)?.with_workers(opts.workers);
    let canonical = model
        .shape(&ShapeParams::default())
        .map_err(|e| EvalError::Invalid(e.to_string()))?;
    let rows = crate::evaluate::first_rows(data, opts.split, opts.samples)?;
    let t0 = Instant::now();
    let shape_targets = template.make_shape_moves(model);
    let shape_moves = t0.elapsed().as_secs_f64();
    let mut samples = Vec::new();
    let mut bodies_of_rows = Vec::with_capacity(rows.len());
    for row in &rows {
        let (shape, pose) = row_body(row);
        let shaped = model
            .shape(&shape)
            .map_err(|e| EvalError::Invalid(format!("sample {}: {e}", row.id)))?;
        let posed = shaped.pose(&pose);
        let start = redraper.start(row)?;
        let motion = redraper.morph(model, row, &start)?;
        let mut full = drape::drape(
            start.cloth,
            &start.template.mesh.vertices,
            &motion,
            &config.sim,
            true,
            &mut |_| {},
        );
        redraper.judge(&mut full, row);
        // PBS-dagger starts from the warp M (the network's input, the base template's
        // warp) with the cloth the dataset draped: the size's rest lengths.
        let mut dagger = drape::drape_from_state(
            start.cloth,
            &row.warped,
            &posed.vertices,
            &model.triangles,
            &config.sim,
            true,
        );
        redraper.judge(&mut dagger, row);
        let t = network_drape(
            &net,
            template,
            &canonical,
            &shaped,
            &posed,
            row.root,
            &learn::data::row_params(row),
            opts.repeats,
        );
        let s = SampleSpeed {
            id: row.id,
            pbs: full.report.wall_time,
            pbs_frames: full.report.morph_frames + full.report.settle_frames,
            pbs_dagger: dagger.report.wall_time,
            pbs_dagger_frames: dagger.report.morph_frames + dagger.report.settle_frames,
            pbs_failure: full.report.failure.as_ref().map(|f| f.to_string()),
            pbs_dagger_failure: dagger.report.failure.as_ref().map(|f| f.to_string()),
            pbs_vs_dataset_cm: edist_cm(&full.positions, &row.draped),
            dagger_vs_dataset_cm: edist_cm(&dagger.positions, &row.draped),
            warp: t.warp,
            inputs: t.inputs,
            network: t.network,
        };
        progress(&s);
        samples.push(s);
        bodies_of_rows.push((shaped, posed));
    }
    // Batched: `batch` samples (the timed ones, repeated if fewer), warp and inputs
    // included, per drape. The batch's warps and inputs run on rayon's threads, one drape
    // each, and the network shares the drapes among its workers.
    let b = opts.batch.max(1);
    let jobs: Vec<_> = rows.iter().zip(&bodies_of_rows).cycle().take(b).collect();
    let mut per = Vec::new();
    for r in 0..=opts.repeats.max(1) {
        let t0 = Instant::now();
        let prepared: Vec<learn::data::Prepared> = jobs
            .par_iter()
            .map(|(row, (shaped, posed))| {
                let warped = template.warp(&canonical, shaped, posed);
                net.prepare(
                    &posed.vertices,
                    row.root,
                    learn::data::row_params(row),
                    &warped,
                )
            })
            .collect();
        let refs: Vec<&learn::data::Prepared> = prepared.iter().collect();
        let out = net.predict(&refs);
        assert_eq!(out.len(), b);
        if r > 0 {
            per.push(t0.elapsed().as_secs_f64() / b as f64);
        }
    }
    let flops_by_variant = Variant::ALL
        .into_iter()
        .map(|v| {
            let c = ModelConfig {
                variant: v,
                ..net.config.model.clone()
            };
            (v.paper_name().to_string(), net.forward_flops(&c))
        })
        .collect();
    Ok(SpeedReport {
        network: net.config.model.display_name(),
        vertices: data.statics.garment_vertices.len(),
        threads: rayon::current_num_threads(),
        workers: net.workers(),
        samples,
        batch: b,
        batched_per_drape: median(per),
        flops: net.forward_flops(&net.config.model),
        flops_by_variant,
        parameters: net.parameters(),
        shape_moves,
        shape_targets,
    })
}
