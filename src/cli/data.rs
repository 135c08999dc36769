//! `drape gen` and `drape data info|show|verify|merge|sensitivity|curve`.

use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicUsize, Ordering};

use clap::{Args, Subcommand};
use dataset::config::{DatasetConfig, Split};
use dataset::generate::{self, Event, GenOptions};
use dataset::inspect;
use dataset::reader::Dataset;

use super::Context;

/// `drape gen`.
#[derive(Debug, Args)]
pub struct GenArgs {
    /// Dataset config: a built-in name (tiny, tiny-heldout, small, cpu-reference, cpu-reference-sweater,
    /// cpu-reference-dress, cpu-reference-jeans, cpu-repro-tshirt, cpu-repro-sweater,
    /// cpu-repro-dress, cpu-repro-jeans, cpu-repro-tshirt-10k, paper-tshirt, paper-sweater,
    /// paper-dress, paper-jeans) or a TOML file.
    pub config: String,
    /// Output folder (created; running again resumes).
    #[arg(short, long, value_name = "DIR")]
    pub output: PathBuf,
    /// Generate only part I of N (0-based), e.g. `--shard 3/16` in a cluster job array;
    /// join the parts with `drape data merge`.
    #[arg(long, value_name = "I/N")]
    pub shard: Option<String>,
    /// Threads (default: all cores).
    #[arg(long)]
    pub threads: Option<usize>,
    /// Accept up to this share of failed drapes before exiting non-zero, instead of the
    /// config's `max_failure_rate` (the data and the config's identity are unchanged; for
    /// accepting a measured rate without regenerating, e.g. `drape reproduce`'s plans).
    #[arg(long, value_name = "SHARE")]
    pub max_failure_rate: Option<f64>,
    /// Resume a folder whose drapes another build of drape made (refused by default: two
    /// builds drape differently by up to 15 mm); its manifest then records no program.
    #[arg(long)]
    pub mixed_builds: bool,
}

/// `drape data`.
#[derive(Debug, Args)]
pub struct DataArgs {
    #[command(subcommand)]
    pub command: DataCommand,
}

/// Dataset tools.
#[derive(Debug, Subcommand)]
pub enum DataCommand {
    /// Counts per split, failure rates, disk size, simulator report statistics, and how far
    /// test poses are from training poses.
    Info {
        /// Dataset folder.
        dir: PathBuf,
        /// Print JSON instead of text.
        #[arg(long)]
        json: bool,
    },
    /// Check every shard: checksum, tensor shapes, finite values. Exits non-zero naming the
    /// bad files.
    Verify {
        /// Dataset folder.
        dir: PathBuf,
    },
    /// Join the parts made with `drape gen --shard I/N` (one or several folders) into one
    /// dataset with a single manifest.json.
    Merge {
        /// Folders holding the parts.
        #[arg(required = true)]
        dirs: Vec<PathBuf>,
        /// Output folder (may be the parts' folder itself).
        #[arg(short, long, value_name = "DIR")]
        output: PathBuf,
        /// Join parts draped by different builds of drape (refused by default: two builds
        /// drape differently by up to 15 mm); the merged manifest then records no program.
        #[arg(long)]
        mixed_builds: bool,
    },
    /// Look at samples: each row renders the simulator's drape G on its body (left) beside
    /// the DQS warp M (right) coloured by its distance to G (the network's input and the
    /// displacement it must learn), and prints the sample's body, pose, size and report.
    Show {
        /// Dataset folder.
        dir: PathBuf,
        /// Split to take samples from: train, val or test.
        #[arg(long, default_value = "test")]
        split: String,
        /// Positions within the split's converged samples (comma-separated, from 0).
        #[arg(long, value_delimiter = ',', default_value = "0,1,2")]
        samples: Vec<usize>,
        /// The PNG to write (rows stacked, one per sample).
        #[arg(short, long, value_name = "FILE.png")]
        output: PathBuf,
    },
    /// What more training data would buy: fit the linear map (and a kernel map of what it
    /// leaves) on the first 1/8, 1/4, 1/2 and all of the training bodies, their strengths
    /// picked on the validation split, and print their Edist on the test drapes beside the
    /// DQS warp's (docs/eval.md)
    Curve {
        /// Dataset folder.
        dir: PathBuf,
        /// Shares of the training bodies (comma-separated, each in (0, 1]).
        #[arg(long, value_delimiter = ',', default_value = "0.125,0.25,0.5,1")]
        shares: Vec<f64>,
        /// Also write the figures as JSON.
        #[arg(long, value_name = "FILE.json")]
        json: Option<PathBuf>,
        /// Also draw the curve (Edist against log2 of the training drapes) to this PNG.
        #[arg(long, value_name = "FILE.png")]
        png: Option<PathBuf>,
    },
    /// How much of a drape no input determines: redrape samples with the starting template
    /// moved by micrometres and measure Edist to the dataset's drape (the floor under a
    /// network's Edist); `--model` measures a network on the same samples.
    Sensitivity {
        /// Dataset folder.
        dir: PathBuf,
        /// Split to take samples from: train, val or test.
        #[arg(long, default_value = "test")]
        split: String,
        /// Samples redraped (the first ones of the split).
        #[arg(long, default_value_t = 20, value_parser = crate::cli::at_least_one::<usize>)]
        samples: usize,
        /// Largest offset of a starting vertex per coordinate (m); a comma-separated list
        /// redrapes each sample once per value.
        #[arg(long, value_delimiter = ',', default_value = "1e-6,1e-4")]
        amplitude: Vec<f32>,
        /// Seed of the offsets.
        #[arg(long, default_value_t = 1)]
        seed: u64,
        /// Run folder of a trained network to measure on the same samples.
        #[arg(long = "model", value_name = "RUN_DIR")]
        run: Option<PathBuf>,
        /// Also write the figures as JSON.
        #[arg(long, value_name = "FILE.json")]
        json: Option<PathBuf>,
        /// Write a render of the sample that moved most at the first amplitude (dataset's
        /// drape beside the redrape coloured by their distance) to this PNG.
        #[arg(long, value_name = "FILE.png")]
        render: Option<PathBuf>,
    },
}

fn parse_part(s: &str) -> anyhow::Result<(u32, u32)> {
    let bad = || anyhow::anyhow!("--shard {s:?}: expected I/N with 0 <= I < N, e.g. 0/4");
    let (i, n) = s.split_once('/').ok_or_else(bad)?;
    let (i, n): (u32, u32) = (
        i.trim().parse().map_err(|_| bad())?,
        n.trim().parse().map_err(|_| bad())?,
    );
    if n == 0 || i >= n {
        return Err(bad());
    }
    Ok((i, n))
}

/// Runs `drape gen`.
pub fn gen_run(args: GenArgs, ctx: &Context) -> anyhow::Result<()> {
    let config = DatasetConfig::load(&args.config)?;
    if let Some(r) = args.max_failure_rate
        && !(0.0..=1.0).contains(&r)
    {
        anyhow::bail!("--max-failure-rate {r}: a share from 0 to 1");
    }
    let (part, parts) = match &args.shard {
        Some(s) => parse_part(s)?,
        None => (0, 1),
    };
    let threads = args.threads.unwrap_or(0);
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()?;
    println!(
        "{}: {} on {} bodies (train/val/test {}/{}/{}{}) x {} poses = {} drapes{}, {} threads -> {}",
        config.name,
        config.garment,
        config.total_bodies(),
        config.bodies.train,
        config.bodies.val,
        config.bodies.test,
        if config.bodies.first > 0 {
            format!(", numbered from {}", config.bodies.first)
        } else {
            String::new()
        },
        config.poses_per_body,
        config.total_samples(),
        if parts > 1 {
            format!(", part {part} of {parts}")
        } else {
            String::new()
        },
        pool.current_num_threads(),
        args.output.display()
    );
    let bar = indicatif::ProgressBar::new(0).with_style(
        indicatif::ProgressStyle::with_template(
            "{prefix} [{bar:30}] {pos}/{len} drapes, {msg}, {per_sec}, {elapsed} (eta {eta})",
        )?
        .progress_chars("=> "),
    );
    // Drawn from the start event on, once it knows how many drapes there are to do.
    let stderr_bar = !bar.is_hidden();
    bar.set_draw_target(indicatif::ProgressDrawTarget::hidden());
    bar.set_prefix("gen");
    // Without a terminal (a log file), a line a minute instead of the bar.
    let lines = learn::run::LogLines::when(
        !stderr_bar,
        "gen",
        "drapes",
        std::time::Duration::from_secs(60),
    );
    let failed = AtomicUsize::new(0);
    let progress = |e: Event| match e {
        Event::Start { todo, done } => {
            bar.set_length(todo as u64);
            bar.set_message("0 failed");
            if stderr_bar {
                bar.set_draw_target(indicatif::ProgressDrawTarget::stderr());
            }
            lines.restart();
            if done > 0 {
                let note = format!("resuming: {done} drapes already done, {todo} to go");
                if stderr_bar {
                    bar.println(note);
                } else {
                    eprintln!("{note}");
                }
            }
        }
        Event::Drape { ok } => {
            if !ok {
                failed.fetch_add(1, Ordering::Relaxed);
            }
            bar.set_message(format!("{} failed", failed.load(Ordering::Relaxed)));
            bar.inc(1);
            lines.tick(&bar);
        }
    };
    let opts = GenOptions {
        part,
        parts,
        mixed_builds: args.mixed_builds,
    };
    let summary = pool.install(|| {
        generate::generate(
            &config,
            &args.output,
            &ctx.assets,
            opts,
            &mut |msg| println!("{msg}"),
            &progress,
        )
    })?;
    bar.finish();
    learn::run::end_bar_line(&bar);
    lines.finish(&bar);
    let m = &summary.manifest;
    let t = m.tally();
    println!(
        "{} drapes this run in {:.1} s ({:.0} drapes per hour); manifest: {}",
        summary.draped_now,
        summary.seconds,
        if summary.seconds > 0.0 {
            summary.draped_now as f64 * 3600.0 / summary.seconds
        } else {
            0.0
        },
        summary.manifest_path.display()
    );
    println!(
        "failed: {} of {} ({:.1}%)",
        t.failed,
        t.samples,
        100.0 * t.rate()
    );
    for (s, t) in m.tally_by_split() {
        println!(
            "  {:<8} {:>4} of {:>5} ({:.1}%)",
            s.name(),
            t.failed,
            t.samples,
            100.0 * t.rate()
        );
    }
    for (f, t) in m.tally_by_family() {
        println!(
            "  {:<8} {:>4} of {:>5} ({:.1}%)",
            f,
            t.failed,
            t.samples,
            100.0 * t.rate()
        );
    }
    for (r, k) in m.failure_reasons() {
        println!("  reason: {r}: {k}");
    }
    let (gate, whose) = match args.max_failure_rate {
        Some(r) => (r, "--max-failure-rate"),
        None => (config.max_failure_rate, "the config's max_failure_rate"),
    };
    if t.rate() > gate {
        anyhow::bail!(
            "{:.1}% of drapes failed, above {whose} of {:.1}%",
            100.0 * t.rate(),
            100.0 * gate
        );
    }
    Ok(())
}

fn mb(b: u64) -> String {
    format!("{:.1} MB", b as f64 / 1e6)
}

/// Runs `drape data curve`.
fn curve_run(
    dir: &Path,
    shares: &[f64],
    json: Option<&Path>,
    png: Option<&Path>,
) -> anyhow::Result<()> {
    super::check_outputs(&[json, png])?;
    let data = Dataset::open(dir)?;
    let t0 = std::time::Instant::now();
    let curve = eval::curve::measure(&data, shares, &mut |m| {
        eprintln!("[{:>5.0} s] {m}", t0.elapsed().as_secs_f64())
    })?;
    println!(
        "{}: Edist on {} {} drapes (DQS warp {:.2} cm); the maps trained on the first bodies of the training split",
        curve.dataset, curve.held_out, curve.split, curve.dqs_cm
    );
    println!(
        "{:>7} {:>7} {:>10} {:>15} {:>11} {:>19} {:>14}",
        "bodies", "drapes", "lambda", "linear, train", "linear", "linear + kernel", "kernel c, l"
    );
    for p in &curve.points {
        println!(
            "{:>7} {:>7} {:>10} {:>12.3} cm {:>8.3} cm {:>16.3} cm {:>14}",
            p.bodies,
            p.drapes,
            p.linear_lambda,
            p.linear_train_cm,
            p.linear_cm,
            p.kernel_cm,
            format!("{}, {}", p.kernel_width, p.kernel_lambda)
        );
    }
    println!("({:.0} s)", t0.elapsed().as_secs_f64());
    if let Some(path) = json {
        std::fs::write(path, serde_json::to_string_pretty(&curve)? + "\n")
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
    }
    if let Some(path) = png {
        let img = eval::plot::line_chart(&eval::curve::chart(&curve), 760, 480);
        std::fs::write(path, eval::render::encode_png(&img)?)
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
    }
    Ok(())
}

/// Runs `drape data sensitivity`.
#[allow(clippy::too_many_arguments)]
fn sensitivity_run(
    ctx: &Context,
    dir: &Path,
    split: &str,
    samples: usize,
    amplitudes: Vec<f32>,
    seed: u64,
    run: Option<&Path>,
    json: Option<&Path>,
    render: Option<&Path>,
) -> anyhow::Result<()> {
    use eval::sensitivity::{SensitivityOptions, measure};
    super::check_outputs(&[json, render])?;
    let split = Split::parse(split)?;
    let opts = SensitivityOptions {
        samples,
        split,
        amplitudes,
        seed,
    };
    opts.validate()?;
    let amplitudes = &opts.amplitudes;
    let data = Dataset::open(dir)?;
    let dc = data.manifest.dataset_config()?;
    let (model, _, template) =
        generate::load_inputs(&dc, &ctx.assets, &mut |g| eprintln!("building {g}"))?;
    let wardrobe =
        dataset::wardrobe::Wardrobe::new(template, &dc, &model, &ctx.assets, &mut |g| {
            eprintln!("{g}")
        })?;
    let template = &wardrobe.base;
    let n = samples.min(data.count(split));
    println!(
        "{} ({}, {} vertices): {n} {} samples redraped {} time(s) each with the dataset's simulator config ({}), starting offsets up to {} m; seed {seed}",
        dc.name,
        dc.garment,
        template.mesh.vertices.len(),
        split.name(),
        amplitudes.len(),
        template.stepping(&dc.sim),
        amplitudes
            .iter()
            .map(|a| format!("{a:e}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    print!("{:>8} {:>8}", "sample", "DQS cm");
    if run.is_some() {
        print!(" {:>10}", "network cm");
    }
    for a in amplitudes {
        print!(" {:>16}", format!("Edist@{a:e} cm"));
    }
    println!();
    let report = measure(&data, &model, &wardrobe, run, &opts, &mut |s| {
        print!("{:>8} {:>8.2}", s.id, s.dqs_cm);
        if let Some(n) = s.network_cm {
            print!(" {n:>10.2}");
        }
        for r in &s.redrapes {
            match &r.failure {
                None => print!(" {:>16.2}", r.edist_cm),
                Some(_) => print!(" {:>16}", format!("{:.2} failed", r.edist_cm)),
            }
        }
        println!();
    })?;
    println!(
        "mean DQS Edist {:.2} cm{}",
        report.dqs_cm,
        report
            .network_cm
            .map(|n| format!(", network Edist {n:.2} cm"))
            .unwrap_or_default()
    );
    for s in &report.summaries {
        println!(
            "offsets up to {:e} m: {} of {} redrapes converged; Edist to the dataset's drape {:.2} ± {:.2} cm (median {:.2}, largest {:.2}), Enorm {:.1} ± {:.1} deg, {:.1}% of vertices over 1 cm away{}",
            s.amplitude,
            s.converged,
            s.redrapes,
            s.edist_cm.0,
            s.edist_cm.1,
            s.edist_median_cm,
            s.edist_max_cm,
            s.enorm_deg.0,
            s.enorm_deg.1,
            100.0 * s.over_1cm,
            s.correlation_with_network
                .map(|r| format!("; correlation with the network's Edist {r:.2}"))
                .unwrap_or_default()
        );
    }
    if let Some(path) = json {
        std::fs::write(path, serde_json::to_string_pretty(&report)?)
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
    }
    if let (Some(path), Some((row, redrape))) = (render, &report.most_moved) {
        let (img, _) = eval::report::sample_render(
            &row.body,
            &data.statics.body_triangles,
            &data.statics.garment_triangles,
            &row.draped,
            redrape,
            "distance (cm) of the redrape (right) to the drape (left)",
        )?;
        std::fs::write(path, eval::render::encode_png(&img)?)
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
        println!(
            "render of sample {} (dataset's drape, left; redrape from offsets up to {:e} m, right) -> {}",
            row.id,
            opts.amplitudes[0],
            path.display()
        );
    }
    Ok(())
}

/// `drape data show`: renders and describes the chosen samples of a split.
fn show_run(dir: &Path, split: &str, picks: &[usize], output: &Path) -> anyhow::Result<()> {
    if !output
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("png"))
    {
        anyhow::bail!("-o {}: expected a .png file", output.display());
    }
    let split = Split::parse(split)?;
    let data = Dataset::open(dir)?;
    let n = data.count(split);
    if picks.is_empty() {
        anyhow::bail!("--samples: name at least one sample");
    }
    if n == 0 {
        anyhow::bail!(
            "the {} split of {} has no converged samples",
            split.name(),
            dir.display()
        );
    }
    if let Some(bad) = picks.iter().find(|&&i| i >= n) {
        anyhow::bail!(
            "--samples {bad}: the {} split of {} has {n} converged samples (0 to {})",
            split.name(),
            dir.display(),
            n.saturating_sub(1)
        );
    }
    let last = *picks.iter().max().unwrap();
    let mut found: Vec<Option<dataset::reader::Sample>> = vec![None; last + 1];
    // Every sample up to the last pick is read, so that a shard that cannot be read stops
    // here instead of shifting the positions after it.
    for (i, sample) in data.samples(split).take(last + 1).enumerate() {
        let sample = sample?;
        if picks.contains(&i) {
            found[i] = Some(sample);
        }
    }
    let mut rows = Vec::with_capacity(picks.len());
    for &i in picks {
        let s = found[i].as_ref().ok_or_else(|| {
            anyhow::anyhow!(
                "sample #{i} of the {} split could not be read",
                split.name()
            )
        })?;
        let (row, rec) = (&s.row, &s.record);
        let dqs_cm = eval::metrics::edist_cm(&row.warped, &row.draped);
        let figure = |path: &str| rec.report.pointer(path).and_then(|v| v.as_f64());
        println!(
            "{} #{i}: sample {} ({} pose, size {}), DQS warp to drape {:.2} cm; {} frames, p95 strain {}, {:.2} s",
            split.name(),
            row.id,
            rec.family,
            rec.size.as_deref().unwrap_or("one size"),
            dqs_cm,
            match (figure("/morph_frames"), figure("/settle_frames")) {
                (Some(m), Some(r)) => format!("{m:.0}+{r:.0}"),
                _ => "?".into(),
            },
            figure("/strain/p95").map_or("?".into(), |p| format!("{:.2}%", 100.0 * p)),
            rec.seconds
        );
        let (img, _) = eval::report::sample_render(
            &row.body,
            &data.statics.body_triangles,
            &data.statics.garment_triangles,
            &row.draped,
            &row.warped,
            &format!(
                "sample {}: drape (left); warp M (right), distance to the drape (cm), mean {dqs_cm:.2}",
                row.id
            ),
        )?;
        rows.push(img);
    }
    let img = eval::render::stack(&rows, [255, 255, 255]);
    std::fs::write(output, eval::render::encode_png(&img)?)
        .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", output.display()))?;
    let n = picks.len();
    let plural = if n == 1 { "" } else { "s" };
    println!("{n} sample{plural} -> {}", output.display());
    Ok(())
}

/// Runs `drape data`.
pub fn data_run(args: DataArgs, ctx: &Context) -> anyhow::Result<()> {
    match args.command {
        DataCommand::Curve {
            dir,
            shares,
            json,
            png,
        } => curve_run(&dir, &shares, json.as_deref(), png.as_deref()),
        DataCommand::Sensitivity {
            dir,
            split,
            samples,
            amplitude,
            seed,
            run,
            json,
            render,
        } => sensitivity_run(
            ctx,
            &dir,
            &split,
            samples,
            amplitude,
            seed,
            run.as_deref(),
            json.as_deref(),
            render.as_deref(),
        ),
        DataCommand::Show {
            dir,
            split,
            samples,
            output,
        } => show_run(&dir, &split, &samples, &output),
        DataCommand::Info { dir, json } => {
            let ds = Dataset::open(&dir)?;
            let i = inspect::info(&ds)?;
            if json {
                println!("{}", serde_json::to_string_pretty(&i)?);
                return Ok(());
            }
            let m = &ds.manifest;
            println!(
                "{} ({}, {} vertices): program {} at {} (build sha256 {}), config sha256 {}, drapes sha256 {}",
                i.name,
                i.garment,
                i.vertices,
                m.program_version,
                dataset::manifest::short_revision(&m.git_revision),
                dataset::manifest::short_sha(&m.program_sha256),
                &m.config_sha256[..12],
                &i.drapes_sha256[..12]
            );
            if let Ok(c) = m.dataset_config()
                && c.bodies.first > 0
            {
                println!(
                    "  bodies numbered from {} (sample ids {} to {})",
                    c.bodies.first,
                    c.sample_ids().start,
                    c.sample_ids().end - 1
                );
            }
            for s in Split::ALL {
                let t = i.failures_by_split.get(&s).copied().unwrap_or_default();
                println!(
                    "  {:<6} {:>6} samples, {} failed ({:.1}%)",
                    s.name(),
                    i.samples[&s],
                    t.failed,
                    100.0 * t.rate()
                );
            }
            for (f, t) in &i.failures_by_family {
                println!(
                    "  family {f:<8} {} of {} failed ({:.1}%)",
                    t.failed,
                    t.samples,
                    100.0 * t.rate()
                );
            }
            for (z, t) in &i.failures_by_size {
                println!(
                    "  size {z:<14} {} drapes, {} failed ({:.1}%)",
                    t.samples,
                    t.failed,
                    100.0 * t.rate()
                );
            }
            for (r, k) in &i.failure_reasons {
                println!("  failure: {r}: {k}");
            }
            println!("  on disk: {}", mb(i.bytes));
            match m.friction {
                Some(mu) => println!(
                    "  friction garment-body: {mu}{}",
                    m.below_band
                        .map_or_else(String::new, |b| format!(", {}", b.describe()))
                ),
                None => println!(
                    "  friction garment-body: the config's (not recorded: made before garments had their own)"
                ),
            }
            let st = |name: &str, s: &inspect::Stats, scale: f64, unit: &str| {
                println!(
                    "  {name:<28} mean {:.2}{unit}, p95 {:.2}{unit}, max {:.2}{unit}",
                    s.mean * scale,
                    s.p95 * scale,
                    s.max * scale
                )
            };
            st("strain p95 per drape", &i.strain_p95, 100.0, "%");
            st("strain max per drape", &i.strain_max, 100.0, "%");
            match &i.polish {
                Some(p) => {
                    println!("  strain polish ({} drapes):", p.drapes);
                    st("  p95 strain before it", &p.strain_p95_before, 100.0, "%");
                    st("  mean particle move", &p.mean_move, 1000.0, " mm");
                    st("  largest particle move", &p.max_move, 1000.0, " mm");
                }
                None => println!(
                    "  strain polish: none recorded (polish_sweeps = 0, or made before it)"
                ),
            }
            st(
                "deepest penetration",
                &i.penetration_max_depth,
                1000.0,
                " mm",
            );
            let converged: usize = i.samples.values().sum();
            match &i.top_drop {
                Some((d, n)) => {
                    st("top opening below the warp's", d, 100.0, " cm");
                    if *n < converged {
                        println!(
                            "    (recorded by {n} of the {converged} converged drapes; the others were made before the slide check)"
                        );
                    }
                }
                None if converged > 0 => println!(
                    "  top opening below the warp's: not recorded (made before the slide check)"
                ),
                None => {}
            }
            st("time per drape (1 thread)", &i.seconds, 1.0, " s");
            if ds.count(Split::Test) > 0 && ds.count(Split::Train) > 0 {
                st(
                    "test pose to nearest train",
                    &i.test_to_train_pose_deg,
                    1.0,
                    " deg",
                );
            } else {
                println!(
                    "  test pose to nearest train  not measured: no test or no training drapes"
                );
            }
            for (split, d) in &i.dqs_edist_cm {
                st(
                    &format!("DQS warp to drape, {}", split.name()),
                    d,
                    1.0,
                    " cm",
                );
            }
            let t = &i.thin;
            if t.drapes > 0 {
                let below: Vec<String> = t
                    .drapes_below
                    .iter()
                    .map(|(deg, n)| {
                        format!(
                            "under {deg}° in {n} ({:.1}%)",
                            100.0 * *n as f64 / t.drapes as f64
                        )
                    })
                    .collect();
                println!(
                    "  thin triangles (a drape's smallest triangle angle; the template's {:.1}°): {} of {} drapes; smallest {:.2}°, at most {} under {}° in one drape",
                    t.template_min_deg,
                    below.join(", "),
                    t.drapes,
                    t.min_deg,
                    t.most_in_a_drape,
                    inspect::THIN_DEG[inspect::THIN_DEG.len() - 1]
                );
            }
            Ok(())
        }
        DataCommand::Verify { dir } => {
            let (rows, problems) = inspect::verify(&dir)?;
            if problems.is_empty() {
                println!("{}: every shard is intact ({rows} samples)", dir.display());
                Ok(())
            } else {
                for p in &problems {
                    eprintln!("{p}");
                }
                anyhow::bail!("{} bad shard(s) in {}", problems.len(), dir.display())
            }
        }
        DataCommand::Merge {
            dirs,
            output,
            mixed_builds,
        } => {
            let m = inspect::merge(&dirs, &output, mixed_builds)?;
            let t = m.tally();
            println!(
                "merged {} shards ({} samples, {} failed) into {}",
                m.shards.len(),
                t.samples,
                t.failed,
                output.join("manifest.json").display()
            );
            Ok(())
        }
    }
}
