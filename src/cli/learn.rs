//! `drape train`: train a GarNet network on a drape dataset.

use std::path::PathBuf;

use clap::Args;
use learn::config::TrainConfig;
use learn::data::body_params;
use learn::predict::Predictor;
use learn::train::{TrainOptions, train};
use sim::body::ShapeParams;
use sim::mesh::TriMesh;

use super::body::load;
use super::garment::{BodyOutputArgs, render, template, write_outputs};
use super::{Context, pose_spec};

/// `drape train`.
#[derive(Debug, Args)]
pub struct TrainArgs {
    /// Training config (configs/train/*.toml).
    #[arg(value_name = "CONFIG.toml")]
    config: PathBuf,
    /// Dataset folder (default: the config's `data`): its training drapes train, its
    /// validation drapes pick the best weights.
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
    /// Train on this dataset's training drapes too (repeatable): drapes of the same garment
    /// template on other bodies, with other sample ids (a dataset config with `[bodies]
    /// first` past the other's bodies, e.g. configs/datasets/cpu-repro-tshirt-more.toml).
    /// Its validation and test drapes are not used. A resumed run needs the same list.
    #[arg(long = "more-data", value_name = "DIR")]
    more_data: Vec<PathBuf>,
    /// Run folder (default: runs/NAME). Running again with the same folder resumes.
    #[arg(short, long, value_name = "DIR")]
    output: Option<PathBuf>,
    /// Start from this run's best weights (fine-tuning, e.g. -RQ from a GarNet-Local run).
    #[arg(long, value_name = "RUN_DIR")]
    init: Option<PathBuf>,
    /// Train this many epochs instead of the config's `epochs` (the learning-rate schedule
    /// follows; the run's config.toml records the value used).
    #[arg(long, value_name = "N")]
    epochs: Option<usize>,
    /// Seed of the initialisation and the shuffling instead of the config's `seed`: another
    /// seed of the same run without a copy of its config. The run folder then defaults to
    /// runs/NAME-seedN; the run's config.toml records the seed used.
    #[arg(long, value_name = "N")]
    seed: Option<u64>,
    /// Wall-clock cap of this invocation instead of the config's `wall_clock_minutes`
    /// (0: no cap).
    #[arg(long, value_name = "MINUTES")]
    wall_clock_minutes: Option<f64>,
    /// Train at these network widths instead of the config's: `cpu` or `paper` (6,890
    /// body points, 512-d global body feature, FeaStNet width 128 with 8 heads; meant for
    /// a GPU). The losses, schedule and variant stay the config's; the run's config.toml
    /// records the widths used.
    #[arg(long, value_name = "WIDTHS")]
    widths: Option<learn::config::Widths>,
    /// Gradient workers per step: the batch is cut into this many parts whose forward and
    /// backward passes run side by side, one thread each, and their gradients are summed
    /// (the same gradient up to rounding). Default: one per thread of RAYON_NUM_THREADS
    /// (all cores), at most the batch size; 1 runs the whole batch at once.
    #[arg(long, value_name = "N", default_value_t = 0, hide_default_value = true)]
    workers: usize,
}

/// Runs `drape train`.
pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let mut config = TrainConfig::load(&args.config)?;
    if let Some(e) = args.epochs {
        config.epochs = e;
    }
    if let Some(s) = args.seed {
        config.seed = s;
    }
    if let Some(m) = args.wall_clock_minutes {
        config.wall_clock_minutes = m;
    }
    if let Some(w) = args.widths {
        config.model = config.model.with_widths(w);
    }
    config.validate()?;
    let data = args.data.unwrap_or_else(|| config.data.clone());
    let run = args.output.unwrap_or_else(|| {
        PathBuf::from("runs").join(match args.seed {
            Some(s) => format!("{}-seed{s}", config.name),
            None => config.name.clone(),
        })
    });
    eprintln!(
        "{} ({}) on {}{} -> {}",
        config.name,
        config.model.variant.paper_name(),
        data.display(),
        args.more_data
            .iter()
            .map(|d| format!(" + {}", d.display()))
            .collect::<String>(),
        run.display()
    );
    let state = train(
        &config,
        &TrainOptions {
            data,
            run: run.clone(),
            init: args.init,
            progress: true,
            workers: args.workers,
            more_data: args.more_data,
        },
    )?;
    if state.finished {
        println!(
            "{}: {} epochs, {} steps, {:.0} s; best validation loss {}; weights in {}",
            config.name,
            state.epoch,
            state.steps,
            state.seconds,
            state.best_val.map_or("-".into(), |v| format!("{v:.4e}")),
            run.display()
        );
    } else {
        println!(
            "{}: stopped in epoch {} after {} steps ({:.0} s); run the same command to resume",
            config.name,
            state.epoch + 1,
            state.steps,
            state.seconds
        );
    }
    Ok(())
}

/// `drape predict`.
#[derive(Debug, Args)]
#[command(mut_arg("pose", |a| a.help(
    "Target pose (as for `drape body --pose`), or a range of BVH frames, \
     FILE.bvh:FIRST-LAST, which writes one numbered file per frame"
)))]
pub struct PredictArgs {
    /// Run folder of a trained network (`drape train -o`); its best weights are used.
    #[arg(long = "model", value_name = "RUN_DIR")]
    run: PathBuf,
    #[command(flatten)]
    target: BodyOutputArgs,
}

/// Runs `drape predict`: `G^P = M + T^P` with `M = dqs(M0, body)`. A range of BVH frames
/// (`--pose FILE.bvh:FIRST-LAST`) drapes each frame, in batches of [`FRAMES_PER_BATCH`],
/// to numbered files.
pub fn predict(args: PredictArgs, ctx: &Context) -> anyhow::Result<()> {
    let t0 = std::time::Instant::now();
    let (_, info) = learn::run::open_run(&args.run)?;
    let params = args.target.shape.params()?;
    let (model, library) = load(ctx)?;
    let canonical = model.shape(&ShapeParams::default())?;
    let target = model.shape(&params)?;
    let poses = pose_spec::resolve_frames(&args.target.pose, &target, &library)?;
    // A range of frames (even of one) writes numbered files.
    let many = poses[0].0.is_some();
    let outputs: Vec<(PathBuf, Option<PathBuf>)> = poses
        .iter()
        .map(|&(frame, _)| {
            let png = args.target.png.as_deref();
            match frame {
                Some(k) => (
                    numbered(&args.target.output, k),
                    png.map(|p| numbered(p, k)),
                ),
                None => (args.target.output.clone(), png.map(PathBuf::from)),
            }
        })
        .collect();
    super::check_outputs(&[Some(&outputs[0].0), outputs[0].1.as_deref()])?;
    let t = template(ctx, &info.garment, Some(info.resolution), &model)?;
    let statics = dataset::shard::Static::new(&t.mesh, &model, &canonical.vertices);
    let net = Predictor::open(&args.run, &statics)?;
    let loaded = t0.elapsed().as_secs_f64();
    let mut seconds = 0.0;
    for (chunk, files) in poses
        .chunks(FRAMES_PER_BATCH)
        .zip(outputs.chunks(FRAMES_PER_BATCH))
    {
        let t1 = std::time::Instant::now();
        let posed: Vec<_> = chunk.iter().map(|(_, r)| target.pose(&r.pose)).collect();
        let inputs: Vec<_> = chunk
            .iter()
            .zip(&posed)
            .map(|((_, r), posed)| {
                let warped = t.warp(&canonical, &target, posed);
                let p = body_params(&params.values(), &r.pose.rotations);
                net.prepare(&posed.vertices, r.pose.root_translation, p, &warped)
            })
            .collect();
        let preds = net.predict(&inputs.iter().collect::<Vec<_>>());
        seconds += t1.elapsed().as_secs_f64();
        for ((((_, r), posed), pred), (obj, png)) in chunk.iter().zip(&posed).zip(preds).zip(files)
        {
            let mesh = TriMesh::new(pred, t.mesh.triangles.clone());
            let image = match png {
                Some(p) => Some((p.as_path(), render(&posed.vertices, &model, &mesh)?)),
                None => None,
            };
            let header = format!(
                "drape predict: {} ({}) from {}, pose {}",
                info.garment,
                net.config.model.variant.paper_name(),
                args.run.display(),
                r.description
            );
            write_outputs(&mesh, &header, Some(obj), image)?;
        }
    }
    let what = format!(
        "{} ({}, {} vertices)",
        info.garment,
        net.config.model.variant.paper_name(),
        t.mesh.vertices.len()
    );
    if many {
        println!(
            "{what}: {} frames, {} to {}; warp + network {:.2} s, {:.1} ms per frame in batches of up to {FRAMES_PER_BATCH} (loading {:.2} s) -> {} to {}",
            poses.len(),
            poses[0].1.description,
            poses[poses.len() - 1].1.description,
            seconds,
            1e3 * seconds / poses.len() as f64,
            loaded,
            outputs[0].0.display(),
            outputs[outputs.len() - 1].0.display()
        );
    } else {
        println!(
            "{what}: pose {}; warp + network {:.3} s (loading {:.2} s) -> {}",
            poses[0].1.description,
            seconds,
            loaded,
            args.target.output.display()
        );
    }
    Ok(())
}

/// Frames of a BVH range draped together by `drape predict` (one batch of the network,
/// its drapes shared among the workers).
const FRAMES_PER_BATCH: usize = 16;

/// `dir/name.ext` as `dir/name-0007.ext` for frame 7 of a range.
fn numbered(path: &std::path::Path, k: usize) -> PathBuf {
    let stem = path
        .file_stem()
        .map_or_else(String::new, |s| s.to_string_lossy().into_owned());
    let name = match path.extension() {
        Some(ext) => format!("{stem}-{k:04}.{}", ext.to_string_lossy()),
        None => format!("{stem}-{k:04}"),
    };
    path.with_file_name(name)
}
