//! `drape bench`: scene benchmarks that print the figures users care about.

use clap::{Args, Subcommand};
use sim::body::ShapeParams;
use sim::cloth::SimConfig;
use sim::cloth::drape::{self, BodyMorph, DrapeReport};

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
        #[arg(long, value_name = "N", value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(100..=200_000))]
        resolution: Option<usize>,
        /// Number of poses (random:SEED onwards).
        #[arg(long, default_value_t = 3, value_parser = crate::cli::at_least_one::<u64>)]
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
        #[arg(long, default_value_t = 5, value_parser = crate::cli::at_least_one::<usize>)]
        batches: usize,
        /// Override the config's batch size.
        #[arg(long)]
        batch_size: Option<usize>,
        /// Override the variant: naive, global, local, global-params.
        #[arg(long)]
        variant: Option<String>,
        /// Gradient workers per step, as `drape train --workers` (default: one per
        /// thread of RAYON_NUM_THREADS, at most the batch size).
        #[arg(long, default_value_t = 0, hide_default_value = true)]
        workers: usize,
    },
    /// Inference time of GarNet networks: per drape, the DQS warp, the inputs (normals,
    /// k-NN searches) and both streams, at batch 1 and 16, for each variant and garment
    /// size, with each variant's forward GFLOPs per drape and the rate the network ran
    /// them at. Freshly initialised weights of the config's widths (the time does not
    /// depend on the weights).
    Predict {
        /// Training config giving the widths (configs/train/*.toml).
        #[arg(value_name = "CONFIG.toml")]
        config: std::path::PathBuf,
        /// Garment.
        #[arg(long, default_value = "tshirt")]
        garment: String,
        /// Template sizes, comma-separated.
        #[arg(long, default_value = "3000,10000", value_delimiter = ',', value_parser = clap::builder::RangedU64ValueParser::<usize>::new().range(100..=200_000))]
        resolution: Vec<usize>,
        /// Batch sizes, comma-separated.
        #[arg(long, default_value = "1,16", value_delimiter = ',', value_parser = crate::cli::at_least_one::<usize>)]
        batch: Vec<usize>,
        /// Variants, comma-separated (default: all four).
        #[arg(
            long,
            default_value = "naive,global,local,global-params",
            value_delimiter = ','
        )]
        variant: Vec<String>,
        /// Timed repeats per measurement (after one warm-up); the median is printed.
        #[arg(long, default_value_t = 5, value_parser = crate::cli::at_least_one::<usize>)]
        repeats: usize,
        /// Threads a batch's drapes are shared among, one drape per pass (default: one
        /// per thread of RAYON_NUM_THREADS; 1: the whole batch in one pass).
        #[arg(long, default_value_t = 0, hide_default_value = true)]
        workers: usize,
    },
    /// The speed-up of a trained network over the simulator on the same test samples, in
    /// one run: the full drape (PBS) and PBS-dagger (from the DQS warp, body in the target
    /// pose) with the dataset's simulator config against the network (DQS warp, inputs,
    /// both streams) at batch 1 and 16; GFLOPs of every variant.
    Speedup {
        /// Run folder of a trained network.
        #[arg(long = "model", value_name = "RUN_DIR")]
        run: std::path::PathBuf,
        /// Dataset folder (default: the run config's `data`).
        #[arg(long, value_name = "DIR")]
        data: Option<std::path::PathBuf>,
        /// Test samples timed.
        #[arg(long, default_value_t = 10, value_parser = crate::cli::at_least_one::<usize>)]
        samples: usize,
        /// Batch size of the batched measurement.
        #[arg(long, default_value_t = 16, value_parser = crate::cli::at_least_one::<usize>)]
        batch: usize,
        /// Timed repeats of each network measurement (median; after a warm-up).
        #[arg(long, default_value_t = 5, value_parser = crate::cli::at_least_one::<usize>)]
        repeats: usize,
        /// Also write the figures as JSON.
        #[arg(long, value_name = "FILE.json")]
        json: Option<std::path::PathBuf>,
        /// Threads the batched measurement's drapes are shared among, one drape per pass
        /// (default: one per thread of RAYON_NUM_THREADS; 1: the whole batch in one pass).
        #[arg(long, default_value_t = 0, hide_default_value = true)]
        workers: usize,
    },
}

/// A variant name as in the configs.
fn parse_variant(v: &str) -> anyhow::Result<learn::config::Variant> {
    serde_json::from_value(serde_json::Value::String(v.to_string()))
        .map_err(|_| anyhow::anyhow!("unknown variant {v:?}: naive, global, local, global-params"))
}

use eval::metrics::median;

/// `drape bench predict`.
#[allow(clippy::too_many_arguments)]
fn bench_predict(
    ctx: &Context,
    config: &std::path::Path,
    garment: &str,
    resolutions: &[usize],
    batches: &[usize],
    variants: &[String],
    repeats: usize,
    workers: usize,
) -> anyhow::Result<()> {
    let base = learn::config::TrainConfig::load(config)?;
    let variants: Vec<_> = variants
        .iter()
        .map(|v| parse_variant(v))
        .collect::<anyhow::Result<_>>()?;
    let repeats = repeats.max(1);
    let most = batches.iter().copied().max().unwrap_or(1).max(1);
    let (model, library) = load(ctx)?;
    let canonical = model.shape(&ShapeParams::default())?;
    let threads = rayon::current_num_threads();
    let shared = if workers == 0 {
        learn::train::Workers::auto(usize::MAX)
    } else {
        workers
    };
    println!(
        "{garment}, bodies of the default shape ranges and poses random:1..={most}; {threads} threads; a batch's drapes shared among {shared} worker{}; median of {repeats} runs after a warm-up",
        if shared == 1 { "" } else { "s" }
    );
    println!(
        "{:<22} {:>8} {:>6} {:>11} {:>11} {:>13} {:>13} {:>10} {:>8} {:>9}",
        "variant",
        "vertices",
        "batch",
        "warp ms/s",
        "inputs ms/s",
        "network ms/b",
        "network ms/s",
        "ms/drape",
        "GFLOPs",
        "GFLOP/s"
    );
    for &res in resolutions {
        let t = super::garment::template(ctx, garment, Some(res), &model)?;
        // Made once per template, as `bench speedup` does, so that no timed warp makes them.
        let t0 = std::time::Instant::now();
        let targets = t.make_shape_moves(&model);
        println!(
            "{} vertices: the template's moves under the body's {targets} shape targets, made once: {:.0} ms",
            t.mesh.vertices.len(),
            t0.elapsed().as_secs_f64() * 1e3
        );
        let mut samples = Vec::with_capacity(most);
        let mut warp = Vec::with_capacity(most);
        for i in 1..=most {
            use dataset::sampling::{ShapeRanges, rng, shape_seed};
            let shape = ShapeRanges::default().sample(&mut rng(shape_seed(i as u64)));
            let shaped = model.shape(&shape)?;
            let resolved = super::pose_spec::resolve(&format!("random:{i}"), &canonical, &library)?;
            let posed = shaped.pose(&resolved.pose);
            let t0 = std::time::Instant::now();
            let warped = t.warp(&canonical, &shaped, &posed);
            warp.push(t0.elapsed().as_secs_f64());
            let p = learn::data::body_params(&shape.values(), &resolved.pose.rotations);
            samples.push((posed.vertices, resolved.pose.root_translation, p, warped));
        }
        let warp = median(warp);
        let statics = dataset::shard::Static::new(&t.mesh, &model, &canonical.vertices);
        for &variant in &variants {
            let mut c = base.clone();
            c.model.variant = variant;
            c.validate()?;
            let net = learn::predict::Predictor::untrained(&c, &statics).with_workers(workers);
            for &b in batches {
                let b = b.max(1);
                let (mut inputs, mut network) = (Vec::new(), Vec::new());
                for r in 0..=repeats {
                    let t0 = std::time::Instant::now();
                    let prepared: Vec<learn::data::Prepared> = samples[..b]
                        .iter()
                        .map(|(body, root, p, w)| net.prepare(body, *root, p.clone(), w))
                        .collect();
                    let t1 = std::time::Instant::now();
                    let refs: Vec<&learn::data::Prepared> = prepared.iter().collect();
                    let out = net.predict(&refs);
                    let t2 = std::time::Instant::now();
                    assert_eq!(out.len(), b);
                    if r > 0 {
                        inputs.push((t1 - t0).as_secs_f64() / b as f64);
                        network.push((t2 - t1).as_secs_f64());
                    }
                }
                let (inputs, network) = (median(inputs), median(network));
                // Forward FLOPs of one drape, and the rate the network ran them at.
                let flops = net.forward_flops(&c.model);
                println!(
                    "{:<22} {:>8} {:>6} {:>11.2} {:>11.2} {:>13.1} {:>13.1} {:>10.1} {:>8.3} {:>9.1}",
                    variant.paper_name(),
                    t.mesh.vertices.len(),
                    b,
                    warp * 1e3,
                    inputs * 1e3,
                    network * 1e3,
                    network * 1e3 / b as f64,
                    (warp + inputs + network / b as f64) * 1e3,
                    flops / 1e9,
                    flops * b as f64 / network / 1e9
                );
            }
        }
        if variants.contains(&learn::config::Variant::Local) {
            local_search(&base.model, &statics, &samples[0].0, &samples[0].3, repeats);
        }
    }
    if let Some(mb) = peak_memory_mb() {
        println!("peak memory: {mb:.0} MB");
    }
    Ok(())
}

/// GarNet-Local's local k-NN search on one drape (each garment vertex's `local_k` nearest
/// downsampled body points) three ways, medians of `repeats` after a warm-up: kiddo's k-d
/// tree, the scan with the vertices in their stored order, and the scan along the
/// template's Z-order curve as the inputs run it (docs/bench.md, "The local search as a
/// scan").
fn local_search(
    model: &learn::config::ModelConfig,
    statics: &dataset::shard::Static,
    body: &[glam::Vec3],
    warped: &[glam::Vec3],
    repeats: usize,
) {
    use learn::nearest::{knn_along, knn_scan, knn_tree, spatial_order};
    let pre = learn::data::Preprocessor::new(statics, model, 0.0, 0);
    let down: Vec<glam::Vec3> = pre
        .local_subset
        .iter()
        .map(|&i| body[pre.body_subset[i as usize] as usize])
        .collect();
    let order = spatial_order(&statics.garment_vertices);
    let k = model.local_k;
    let time = |f: &dyn Fn() -> Vec<u32>| {
        let runs: Vec<f64> = (0..=repeats)
            .map(|_| {
                let t0 = std::time::Instant::now();
                std::hint::black_box(f());
                t0.elapsed().as_secs_f64()
            })
            .skip(1)
            .collect();
        median(runs) * 1e3
    };
    let tree = time(&|| knn_tree(&down, warped, k));
    let stored = time(&|| knn_scan(&down, warped, k));
    let along = time(&|| knn_along(&down, warped, &order, k));
    println!(
        "{} vertices: GarNet-Local's local search (each vertex's {k} nearest of {} body points, one drape): k-d tree {tree:.2} ms, scan in stored order {stored:.2} ms, scan along the template's Z-order curve {along:.2} ms",
        warped.len(),
        down.len()
    );
}

/// `drape bench speedup`.
fn bench_speedup(
    ctx: &Context,
    run: &std::path::Path,
    data: Option<std::path::PathBuf>,
    samples: usize,
    batch: usize,
    repeats: usize,
    json: Option<std::path::PathBuf>,
    workers: usize,
) -> anyhow::Result<()> {
    super::check_outputs(&[json.as_deref()])?;
    let (config, _) = learn::run::open_run(run)?;
    let dir = data.unwrap_or_else(|| config.data.clone());
    let data = dataset::reader::Dataset::open(&dir)?;
    let dc = data.manifest.dataset_config()?;
    let (model, _, template) =
        dataset::generate::load_inputs(&dc, &ctx.assets, &mut |g| eprintln!("building {g}"))?;
    let wardrobe =
        dataset::wardrobe::Wardrobe::new(template, &dc, &model, &ctx.assets, &mut |g| {
            eprintln!("{g}")
        })?;
    let template = &wardrobe.base;
    let threads = rayon::current_num_threads();
    println!(
        "{} ({} vertices) from {}; {} test samples of {}; simulator config of the dataset ({}); {threads} threads",
        dc.garment,
        template.mesh.vertices.len(),
        run.display(),
        samples.max(1).min(data.count(dataset::config::Split::Test)),
        dc.name,
        template.stepping(&dc.sim)
    );
    println!(
        "{:>8} {:>9} {:>7} {:>10} {:>7} {:>9} {:>10} {:>11} {:>10}",
        "sample",
        "PBS s",
        "frames",
        "PBS-dag s",
        "frames",
        "warp ms",
        "inputs ms",
        "network ms",
        "speed-up"
    );
    let r = eval::speed::measure(
        run,
        &data,
        &model,
        &wardrobe,
        &eval::speed::SpeedOptions {
            samples,
            batch,
            repeats,
            split: dataset::config::Split::Test,
            workers,
        },
        &mut |s| {
            let net = s.warp + s.inputs + s.network;
            println!(
                "{:>8} {:>9.2} {:>7} {:>10.2} {:>7} {:>9.2} {:>10.2} {:>11.2} {:>9.0}x{}",
                s.id,
                s.pbs,
                s.pbs_frames,
                s.pbs_dagger,
                s.pbs_dagger_frames,
                s.warp * 1e3,
                s.inputs * 1e3,
                s.network * 1e3,
                s.pbs / net,
                match (&s.pbs_failure, &s.pbs_dagger_failure) {
                    (None, None) => String::new(),
                    (Some(f), _) => format!("  (full drape failed: {f})"),
                    (None, Some(f)) => format!("  (PBS-dagger failed: {f}; left out of its mean)"),
                }
            );
        },
    )?;
    let (pbs, dagger, one, many) = (
        r.pbs(),
        r.pbs_dagger(),
        r.network_batch1(),
        r.batched_per_drape,
    );
    println!(
        "\nper drape, mean over samples ({} vertices, {} threads):",
        r.vertices, r.threads
    );
    let converged =
        |f: &dyn Fn(&eval::speed::SampleSpeed) -> bool| r.samples.iter().filter(|s| f(s)).count();
    println!(
        "  simulator, full drape (PBS)        {:>9.3} s   ({} of {} drapes converged; the mean is theirs)",
        pbs,
        converged(&|s| s.pbs_failure.is_none()),
        r.samples.len()
    );
    println!(
        "  simulator, from the warp (PBS-dag) {:>9.3} s   ({} of {} drapes converged; the mean is theirs)",
        dagger,
        converged(&|s| s.pbs_dagger_failure.is_none()),
        r.samples.len()
    );
    println!(
        "  made once per template, before any of the above: its moves under the body's {} shape targets, {:.0} ms",
        r.shape_targets,
        r.shape_moves * 1e3
    );
    println!(
        "  {} batch 1                {:>9.1} ms   speed-up {:>6.1}x over PBS, {:>5.1}x over PBS-dagger",
        r.network,
        one * 1e3,
        pbs / one,
        dagger / one
    );
    println!(
        "  {} batch {:<2} (per drape)   {:>9.1} ms   speed-up {:>6.1}x over PBS, {:>5.1}x over PBS-dagger",
        r.network,
        r.batch,
        many * 1e3,
        pbs / many,
        dagger / many
    );
    let agree = r
        .samples
        .iter()
        .map(|s| s.pbs_vs_dataset_cm)
        .fold(0.0, f64::max);
    println!("  this run's full drapes vs the dataset's: largest Edist {agree:.2e} cm");
    println!(
        "  {}: {} parameters, {:.3} GFLOPs per forward pass",
        r.network,
        r.parameters,
        r.flops / 1e9
    );
    println!(
        "GFLOPs per forward pass of each variant at this run's widths and {} vertices:",
        r.vertices
    );
    for (name, flops) in &r.flops_by_variant {
        println!("  {name:<20} {:.3}", flops / 1e9);
    }
    if let Some(p) = json {
        std::fs::write(&p, serde_json::to_vec_pretty(&r)?)
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", p.display()))?;
        println!("figures -> {}", p.display());
    }
    Ok(())
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
            workers,
        } => return bench_train(config, data, batches, batch_size, variant, workers),
        BenchCommand::Speedup {
            run,
            data,
            samples,
            batch,
            repeats,
            json,
            workers,
        } => return bench_speedup(ctx, &run, data, samples, batch, repeats, json, workers),
        BenchCommand::Predict {
            config,
            garment,
            resolution,
            batch,
            variant,
            repeats,
            workers,
        } => {
            return bench_predict(
                ctx,
                &config,
                &garment,
                &resolution,
                &batch,
                &variant,
                repeats,
                workers,
            );
        }
    };
    let config = match &config {
        Some(p) => SimConfig::load(p)?,
        None => SimConfig::default(),
    };
    let (model, library) = load(ctx)?;
    let body = model.shape(&ShapeParams::default())?;
    let (tube, cloth) = super::simulate::garment(&garment, resolution, ctx, &body, &config)?;
    let prior = dataset::sampling::PosePrior::new(library);
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let [stretch, shear, bend] = cloth.kind_counts();
    println!(
        "{garment}: {} particles, {} triangles, constraints stretch/shear/bend {stretch}/{shear}/{bend}, {} colours; {}, morph {} frames or more (body vertices at {} m/s at most)",
        cloth.len(),
        tube.triangles.len(),
        cloth.distance_colours.len(),
        cloth
            .drape_config(&config)
            .map_err(anyhow::Error::msg)?
            .stepping(),
        config.morph_frames,
        config.max_morph_speed
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
            &config,
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
        "time per stage on {cores} threads (mean, s): body {:.3}, detect {:.3}, predict {:.3}, solve {:.3}, collide {:.3}, velocities {:.3}, polish {:.3}, verify {:.3}",
        mean(&|r| r.stage_times.body),
        mean(&|r| r.stage_times.detect),
        mean(&|r| r.stage_times.predict),
        mean(&|r| r.stage_times.solve),
        mean(&|r| r.stage_times.collide),
        mean(&|r| r.stage_times.velocities),
        mean(&|r| r.polish.map_or(0.0, |p| p.time)),
        mean(&|r| r.verify_time),
    );
    let polished: Vec<_> = reports.iter().filter_map(|r| r.polish).collect();
    if !polished.is_empty() {
        let m = polished.len() as f64;
        let avg = |f: &dyn Fn(&sim::cloth::polish::PolishStats) -> f64| {
            polished.iter().map(f).sum::<f64>() / m
        };
        println!(
            "strain polish (mean of {} drapes): {:.0} sweeps, p95 strain {:.2}% before, particles moved {:.2} mm on average, {:.2} mm at most",
            polished.len(),
            avg(&|p| p.sweeps as f64),
            avg(&|p| p.strain_p95_before as f64 * 100.0),
            avg(&|p| p.mean_move as f64 * 1e3),
            polished.iter().map(|p| p.max_move).fold(0.0f32, f32::max) * 1e3,
        );
    }
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
    workers: usize,
) -> anyhow::Result<()> {
    let mut c = learn::config::TrainConfig::load(&config)?;
    if let Some(b) = batch_size {
        c.batch_size = b;
    }
    if let Some(v) = variant {
        c.model.variant = parse_variant(&v)?;
    }
    c.validate()?;
    let data = data.unwrap_or_else(|| c.data.clone());
    let r = learn::bench::train_rate(&c, &data, batches, workers)?;
    println!(
        "{} on {} vertices, {} body points, {} parameters, batch {}, {} timed batches, {} gradient worker{}",
        r.variant,
        r.vertices,
        r.body_points,
        r.parameters,
        r.batch_size,
        r.batches,
        r.workers,
        if r.workers == 1 { "" } else { "s" }
    );
    println!("  training rate: {:.2} samples/s", r.samples_per_second);
    match r.stages {
        Some([inputs, forward, backward]) => println!(
            "  per batch: inputs {inputs:.3} s, forward+losses {forward:.3} s, backward {backward:.3} s, Adam {:.3} s",
            r.step
        ),
        None => println!(
            "  per batch: inputs, forward+losses and backward on {} threads {:.3} s, Adam {:.3} s",
            r.workers, r.gradients, r.step
        ),
    }
    if let Some(mb) = peak_memory_mb() {
        println!("  peak memory: {mb:.0} MB");
    }
    Ok(())
}
