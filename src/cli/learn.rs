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
    /// Dataset folder (default: the config's `data`).
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
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
    #[arg(long, value_name = "N", default_value_t = 0)]
    workers: usize,
}

/// Runs `drape train`.
pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let mut config = TrainConfig::load(&args.config)?;
    if let Some(e) = args.epochs {
        config.epochs = e;
    }
    if let Some(m) = args.wall_clock_minutes {
        config.wall_clock_minutes = m;
    }
    if let Some(w) = args.widths {
        config.model = config.model.with_widths(w);
    }
    config.validate()?;
    let data = args.data.unwrap_or_else(|| config.data.clone());
    let run = args
        .output
        .unwrap_or_else(|| PathBuf::from("runs").join(&config.name));
    eprintln!(
        "{} ({}) on {} -> {}",
        config.name,
        config.model.variant.paper_name(),
        data.display(),
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
pub struct PredictArgs {
    /// Run folder of a trained network (`drape train -o`); its best weights are used.
    #[arg(long = "model", value_name = "RUN_DIR")]
    run: PathBuf,
    #[command(flatten)]
    target: BodyOutputArgs,
}

/// Runs `drape predict`: `G^P = M + T^P` with `M = dqs(M0, body)`.
pub fn predict(args: PredictArgs, ctx: &Context) -> anyhow::Result<()> {
    let t0 = std::time::Instant::now();
    let (_, info) = learn::run::open_run(&args.run)?;
    let params = args.target.shape.params()?;
    let (model, library) = load(ctx)?;
    let canonical = model.shape(&ShapeParams::default())?;
    let target = model.shape(&params)?;
    let resolved = pose_spec::resolve(&args.target.pose, &target, &library)?;
    let t = template(ctx, &info.garment, Some(info.resolution), &model)?;
    let statics = dataset::shard::Static::new(&t.mesh, &model, &canonical.vertices);
    let net = Predictor::open(&args.run, &statics)?;
    let loaded = t0.elapsed().as_secs_f64();
    let t1 = std::time::Instant::now();
    let posed = target.pose(&resolved.pose);
    let warped = t.warp(&canonical, &target, &posed);
    let p = body_params(&params.values(), &resolved.pose.rotations);
    let x = net.prepare(&posed.vertices, resolved.pose.root_translation, p, &warped);
    let pred = net.predict(&[&x]).pop().expect("one prediction");
    let seconds = t1.elapsed().as_secs_f64();
    let mesh = TriMesh::new(pred, t.mesh.triangles.clone());
    let image = match &args.target.png {
        Some(p) => Some((p.as_path(), render(&posed.vertices, &model, &mesh)?)),
        None => None,
    };
    let header = format!(
        "drape predict: {} ({}) from {}, pose {}",
        info.garment,
        net.config.model.variant.paper_name(),
        args.run.display(),
        resolved.description
    );
    write_outputs(&mesh, &header, Some(&args.target.output), image)?;
    println!(
        "{} ({}, {} vertices): pose {}; warp + network {:.3} s (loading {:.2} s) -> {}",
        info.garment,
        net.config.model.variant.paper_name(),
        mesh.vertices.len(),
        resolved.description,
        seconds,
        loaded,
        args.target.output.display()
    );
    Ok(())
}
