//! `drape bench`: scene benchmarks that print the figures users care about.

use clap::{Args, Subcommand};
use sim::body::ShapeParams;
use sim::cloth::drape::{self, BodyMorph, DrapeReport};
use sim::cloth::{ClothModel, SimConfig};

use super::Context;
use super::body::load;

/// `drape bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {
    #[command(subcommand)]
    command: BenchCommand,
}

#[derive(Debug, Subcommand)]
enum BenchCommand {
    /// Drape a garment (default: the garment-like tube, 10,112 particles) on the default
    /// body morphing to poses of the prior, on one thread and on all cores; prints time per
    /// drape and per stage, peak memory and the quality figures of each drape.
    Sim {
        /// Garment: tube, tshirt, sweater, dress, jeans, an imported name or an OBJ.
        #[arg(long, default_value = "tube", value_name = "NAME")]
        garment: String,
        /// About this many vertices for a built-in garment (default 10000).
        #[arg(long, value_name = "N")]
        resolution: Option<usize>,
        /// Number of poses (random:SEED onwards).
        #[arg(long, default_value_t = 3)]
        poses: u64,
        /// Seed of the first pose.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Simulator configuration TOML (default: configs/sim/default.toml).
        #[arg(long, value_name = "FILE.toml")]
        config: Option<std::path::PathBuf>,
    },
    /// Training throughput of a GarNet config: samples per second of whole training steps
    /// and seconds per stage (inputs, forward and losses, backward, Adam), peak memory.
    Train {
        /// Training config (configs/train/*.toml).
        #[arg(value_name = "CONFIG.toml")]
        config: std::path::PathBuf,
        /// Dataset folder (default: the config's `data`).
        #[arg(long, value_name = "DIR")]
        data: Option<std::path::PathBuf>,
        /// Timed batches after one warm-up batch.
        #[arg(long, default_value_t = 5)]
        batches: usize,
        /// Override the config's batch size.
        #[arg(long)]
        batch_size: Option<usize>,
        /// Override the variant: naive, global, local, global-params.
        #[arg(long)]
        variant: Option<String>,
    },
}

/// Peak resident memory of this process (MB), from /proc where there is one.
fn peak_memory_mb() -> Option<f64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// Runs `drape bench`.
pub fn run(args: BenchArgs, ctx: &Context) -> anyhow::Result<()> {
    let (garment, resolution, poses, seed, config) = match args.command {
        BenchCommand::Sim {
            garment,
            resolution,
            poses,
            seed,
            config,
        } => (garment, resolution, poses, seed, config),
        BenchCommand::Train {
            config,
            data,
            batches,
            batch_size,
            variant,
        } => return bench_train(config, data, batches, batch_size, variant),
    };
    let config = match &config {
        Some(p) => SimConfig::load(p)?,
        None => SimConfig::default(),
    };
    let (model, library) = load(ctx)?;
    let body = model.shape(&ShapeParams::default())?;
    let tube = super::simulate::garment(&garment, resolution, ctx, &body)?;
    let cloth = ClothModel::new(&tube, &config, &[])?;
    let prior = dataset::sampling::PosePrior::new(library);
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    println!(
        "{garment}: {} particles, {} triangles, constraints stretch/shear/bend {}/{}/{}, {} colours; {} substeps at {} fps, morph {} frames",
        cloth.len(),
        tube.triangles.len(),
        cloth.kind_counts[0],
        cloth.kind_counts[1],
        cloth.kind_counts[2],
        cloth.distance_colours.len(),
        config.substeps,
        config.fps,
        config.morph_frames
    );
    println!(
        "pose                 family    frames  1 thread  {cores} threads  converged  strain p95  max    inside before/after push-out"
    );
    let mut reports: Vec<DrapeReport> = Vec::new();
    for k in 0..poses {
        let s = seed.wrapping_add(k);
        let sampled = prior.sample_seeded(s);
        let motion = BodyMorph::new(
            &model,
            ShapeParams::default(),
            ShapeParams::default(),
            sampled.pose.clone(),
            config.morph_frames,
        )?;
        let mut time = [0.0f64; 2];
        let mut last = None;
        for (slot, threads) in [(0, 1usize), (1, cores)] {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()?;
            let d = pool.install(|| {
                drape::drape(
                    &cloth,
                    &tube.vertices,
                    &motion,
                    &config,
                    threads > 1,
                    &mut |_| {},
                )
            });
            time[slot] = d.report.wall_time;
            last = Some(d.report);
        }
        let r = last.expect("ran");
        let label = format!("random:{s}");
        let converged = match &r.failure {
            None => "yes".to_string(),
            Some(f) => format!("NO ({f})"),
        };
        let inside = format!(
            "{}/{}",
            r.penetration_before_pushout.count, r.penetration.count
        );
        println!(
            "{label:<20} {:<9} {:>3}+{:<3} {:>7.2} s {:>9.2} s  {converged:<9}  {:>9.2}%  {:>5.1}%  {inside}",
            sampled.family.name(),
            r.morph_frames,
            r.settle_frames,
            time[0],
            time[1],
            r.strain.p95 * 100.0,
            r.strain.max * 100.0,
        );
        reports.push(r);
    }
    let n = reports.len().max(1) as f64;
    let mean = |f: &dyn Fn(&DrapeReport) -> f64| reports.iter().map(f).sum::<f64>() / n;
    println!(
        "time per stage on {cores} threads (mean, s): body {:.3}, detect {:.3}, predict {:.3}, solve {:.3}, collide {:.3}, velocities {:.3}, verify {:.3}",
        mean(&|r| r.stage_times.body),
        mean(&|r| r.stage_times.detect),
        mean(&|r| r.stage_times.predict),
        mean(&|r| r.stage_times.solve),
        mean(&|r| r.stage_times.collide),
        mean(&|r| r.stage_times.velocities),
        mean(&|r| r.verify_time),
    );
    if let Some(mb) = peak_memory_mb() {
        println!("peak memory of this process: {mb:.0} MB");
    }
    Ok(())
}

/// `drape bench train`.
fn bench_train(
    config: std::path::PathBuf,
    data: Option<std::path::PathBuf>,
    batches: usize,
    batch_size: Option<usize>,
    variant: Option<String>,
) -> anyhow::Result<()> {
    let mut c = learn::config::TrainConfig::load(&config)?;
    if let Some(b) = batch_size {
        c.batch_size = b;
    }
    if let Some(v) = variant {
        c.model.variant =
            serde_json::from_value(serde_json::Value::String(v.clone())).map_err(|_| {
                anyhow::anyhow!("unknown variant {v:?}: naive, global, local, global-params")
            })?;
    }
    c.validate()?;
    let data = data.unwrap_or_else(|| c.data.clone());
    let r = learn::bench::train_rate(&c, &data, batches)?;
    println!(
        "{} on {} vertices, {} body points, {} parameters, batch {}, {} timed batches",
        r.variant, r.vertices, r.body_points, r.parameters, r.batch_size, r.batches
    );
    println!("  training rate: {:.2} samples/s", r.samples_per_second);
    println!(
        "  per batch: inputs {:.3} s, forward+losses {:.3} s, backward {:.3} s, Adam {:.3} s",
        r.prepare, r.forward, r.backward, r.step
    );
    if let Some(mb) = peak_memory_mb() {
        println!("  peak memory: {mb:.0} MB");
    }
    Ok(())
}
