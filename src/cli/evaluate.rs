//! `drape eval`: a trained network and the baselines on a dataset split, as a report folder.

use std::path::PathBuf;

use clap::Args;
use dataset::config::Split;
use dataset::reader::Dataset;
use eval::evaluate::{EvalOptions, METHODS, evaluate, method_title};
use eval::report::write_report;

/// A trained network and a dataset split: what `drape eval` and `drape importance` read.
#[derive(Debug, Args)]
pub struct RunOnSplit {
    /// Run folder of a trained network (`drape train -o`); its best weights are used.
    #[arg(long = "model", value_name = "RUN_DIR")]
    run: PathBuf,
    /// Dataset folder (default: the run config's `data`).
    #[arg(long, value_name = "DIR")]
    data: Option<PathBuf>,
    /// Split to use: train, val or test.
    #[arg(long, default_value = "test")]
    split: String,
    /// Use only the first N samples of the split.
    #[arg(long, value_name = "N")]
    limit: Option<usize>,
}

impl RunOnSplit {
    /// The split, and the dataset opened (the run config's unless `--data`).
    fn open(&self) -> anyhow::Result<(Split, PathBuf, Dataset)> {
        let split = Split::parse(&self.split)?;
        let (config, _) = learn::run::open_run(&self.run)?;
        let dir = self.data.clone().unwrap_or_else(|| config.data.clone());
        let data = Dataset::open(&dir)?;
        if self.limit == Some(0) {
            anyhow::bail!("--limit must be at least 1");
        }
        Ok((split, dir, data))
    }
}

/// `drape eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    #[command(flatten)]
    on: RunOnSplit,
    /// Report folder: report.md, metrics.json, samples.csv, curves (CSV, PNG), renders.
    #[arg(short, long, value_name = "REPORT_DIR")]
    output: PathBuf,
    /// Samples per network batch.
    #[arg(long, default_value_t = 8, value_parser = crate::cli::at_least_one::<usize>)]
    batch: usize,
}

/// Runs `drape eval`.
pub fn run(args: EvalArgs) -> anyhow::Result<()> {
    let (split, dir, data) = args.on.open()?;
    let (run, limit) = (&args.on.run, args.on.limit);
    eprintln!(
        "evaluating {} on {} ({} split, {} samples)",
        run.display(),
        dir.display(),
        split.name(),
        data.count(split).min(limit.unwrap_or(usize::MAX))
    );
    let ev = evaluate(
        run,
        &data,
        &EvalOptions {
            split,
            batch: args.batch,
            limit,
            progress: true,
        },
    )?;
    let sums = write_report(&args.output, run, &data, split, &ev)?;
    println!(
        "{:<20} {:>14} {:>14}",
        "method", "Edist (cm)", "Enorm (deg)"
    );
    for m in METHODS {
        let s = &sums[m];
        println!(
            "{:<20} {:>6.2} ± {:<5.2} {:>6.2} ± {:<5.2}",
            method_title(m, &ev.network),
            s.edist_cm.0,
            s.edist_cm.1,
            s.enorm_deg.0,
            s.enorm_deg.1
        );
    }
    println!(
        "{} samples in {:.1} s -> {}",
        ev.samples.len(),
        ev.seconds,
        args.output.join("report.md").display()
    );
    Ok(())
}

/// `drape compare`.
#[derive(Debug, Args)]
pub struct CompareArgs {
    /// Evaluation A: a report folder of `drape eval`, or a metrics JSON with per-sample rows
    /// (a report's metrics.json, a run record in docs/eval/).
    #[arg(value_name = "A")]
    a: PathBuf,
    /// Evaluation B, the same kinds; may be A itself to compare two of its methods.
    #[arg(value_name = "B")]
    b: PathBuf,
    /// A's method: network, dqs, mean-residual, nearest-neighbour, kernel, linear or
    /// simulator.
    #[arg(long, default_value = "network", value_name = "METHOD")]
    method: String,
    /// B's method (default: A's).
    #[arg(long, value_name = "METHOD")]
    method_b: Option<String>,
    /// Also write the comparison as JSON to this file.
    #[arg(long, value_name = "FILE.json")]
    json: Option<PathBuf>,
    /// A `drape reproduce` record folder (docs/reproduction-record/PLAN): evaluations on
    /// manifests it lists as the same drapes pair, and so do evaluations that record the
    /// drapes sha256 it names (records since session 72) and evaluations on a data folder
    /// made again by the program and config it records (whose manifest differs in timings).
    #[arg(long, value_name = "DIR")]
    record: Option<PathBuf>,
}

/// Runs `drape compare`.
pub fn compare(args: CompareArgs) -> anyhow::Result<()> {
    let mb = args.method_b.as_deref().unwrap_or(&args.method);
    super::check_outputs(&[args.json.as_deref()])?;
    let same = match &args.record {
        Some(dir) => eval::compare::SameDrapes::from_record(dir)?,
        None => eval::compare::SameDrapes::default(),
    };
    eval::compare::check_same_drapes(&args.a, &args.b, &same)?;
    let (a, b) = (
        eval::compare::load(&args.a, &args.method)?,
        eval::compare::load(&args.b, mb)?,
    );
    let c = eval::compare::compare(
        &a,
        &b,
        &format!("{} ({})", args.a.display(), args.method),
        &format!("{} ({mb})", args.b.display()),
    )?;
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&c)? + "\n";
        std::fs::write(path, text)
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
    }
    print!("{}", c.table());
    Ok(())
}

/// `drape importance`.
#[derive(Debug, Args)]
pub struct ImportanceArgs {
    #[command(flatten)]
    on: RunOnSplit,
    /// Drapes per batch; each drape takes the swapped inputs from the next of its batch.
    #[arg(long, default_value_t = 16)]
    batch: usize,
    /// Also write the measurement (per-way means and paired rises) as JSON to this file.
    #[arg(long, value_name = "FILE.json")]
    json: Option<PathBuf>,
}

/// Runs `drape importance`.
pub fn importance(args: ImportanceArgs) -> anyhow::Result<()> {
    use eval::importance::{ImportanceOptions, measure};
    super::check_outputs(&[args.json.as_deref()])?;
    let (split, _, data) = args.on.open()?;
    let report = measure(
        &args.on.run,
        &data,
        &ImportanceOptions {
            split,
            limit: args.on.limit,
            batch: args.batch,
            progress: true,
        },
    )?;
    if let Some(path) = &args.json {
        let text = serde_json::to_string_pretty(&report)? + "\n";
        std::fs::write(path, text)
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
    }
    print!("{}", report.table());
    Ok(())
}
