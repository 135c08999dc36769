//! Command-line definitions and dispatch.

mod bench;
mod body;
mod data;
mod evaluate;
mod garment;
mod learn;
mod pose_spec;
mod quickstart;
mod reproduce;
mod simulate;

use std::path::PathBuf;

use clap::{Parser, Subcommand};

/// drape: cloth physics to training data to fast draping networks.
#[derive(Debug, Parser)]
#[command(name = "drape", version, about, long_about = None)]
pub struct Cli {
    /// Folder of the shipped assets (default: the `assets/` folder of this source tree).
    #[arg(long, global = true, value_name = "DIR")]
    pub assets: Option<PathBuf>,
    /// Pose library TOML to use instead of the built-in configs/poses/library.toml.
    #[arg(long, global = true, value_name = "FILE.toml")]
    pub pose_library: Option<PathBuf>,
    #[command(subcommand)]
    pub command: Command,
}

/// The jobs.
#[derive(Debug, Subcommand)]
pub enum Command {
    /// The quick start: drape the T-shirt on one body with the simulator and with the
    /// committed GarNet-Local weights; print both times, the speed-up, Edist and Enorm;
    /// write OBJs and a side-by-side render.
    Quickstart(quickstart::QuickstartArgs),
    /// Build a shaped, posed MakeHuman body: OBJ and PNG; import the body asset; check the
    /// pose prior.
    Body(body::BodyArgs),
    /// Drape a garment on a shaped, posed body with the cloth simulator: OBJ, PNG and a
    /// quality report.
    Sim(Box<simulate::SimArgs>),
    /// Garment templates: build the built-in ones, import your own, list them, render them
    /// on sampled bodies and check their drapes against the quality bars.
    Garment(garment::GarmentArgs),
    /// Warp a garment template to a shaped, posed body with dual quaternion skinning (the
    /// network's input and the DQS baseline): OBJ and PNG.
    Warp(Box<garment::WarpArgs>),
    /// Scene benchmarks that print timings and quality figures.
    Bench(bench::BenchArgs),
    /// Generate a drape dataset (shards of bodies, DQS warps and simulated drapes) from a
    /// config, in parallel and resumably; `--shard I/N` makes one part of a cluster job.
    Gen(data::GenArgs),
    /// Inspect, verify, show and merge datasets made by `drape gen`; measure the
    /// simulator's scatter (sensitivity) and what more data would buy (curve).
    Data(data::DataArgs),
    /// Train a GarNet network (Naive, Global, Local, Global-Params) on a dataset; resumes;
    /// `--init` fine-tunes from another run.
    Train(learn::TrainArgs),
    /// Drape a garment with a trained network: the DQS warp onto a shaped, posed body, then
    /// the network (the run folder knows its garment).
    Predict(Box<learn::PredictArgs>),
    /// Evaluate a trained network and the DQS, mean-residual, nearest-neighbour, linear and
    /// kernel baselines on a dataset split: Edist, Enorm, curvature, physics, curves and renders
    /// in a report folder.
    Eval(evaluate::EvalArgs),
    /// Compare two evaluations of the same drapes sample by sample (two networks, or a
    /// network and a baseline): per figure the mean difference, its standard error, and
    /// on how many drapes each is lower.
    Compare(evaluate::CompareArgs),
    /// How much a trained network relies on each body input (permutation importance): the
    /// test drapes once as they are and once per input with that input taken from another
    /// drape of the batch; Edist and Enorm, and their paired rise.
    Importance(evaluate::ImportanceArgs),
    /// Reproduce the paper's tables on our data: generate the plan's datasets, train its
    /// networks and fine-tunes, evaluate them, time the speed-up, write
    /// docs/reproduction.md and .json. Resumable.
    Reproduce(reproduce::ReproduceArgs),
}

/// Options every command shares.
#[derive(Debug)]
pub struct Context {
    /// The assets folder.
    pub assets: PathBuf,
    /// A pose library replacing the built-in one.
    pub pose_library: Option<PathBuf>,
}

/// Runs a parsed command line.
pub fn run(cli: Cli) -> anyhow::Result<()> {
    let ctx = Context {
        assets: cli
            .assets
            .unwrap_or_else(sim::body::asset::default_assets_dir),
        pose_library: cli.pose_library,
    };
    match cli.command {
        Command::Body(args) => body::run(args, &ctx),
        Command::Sim(args) => simulate::run(*args, &ctx),
        Command::Garment(args) => garment::run(args, &ctx),
        Command::Warp(args) => garment::warp(*args, &ctx),
        Command::Bench(args) => bench::run(args, &ctx),
        Command::Gen(args) => data::gen_run(args, &ctx),
        Command::Data(args) => data::data_run(args, &ctx),
        Command::Train(args) => learn::run(args),
        Command::Predict(args) => learn::predict(*args, &ctx),
        Command::Eval(args) => evaluate::run(args),
        Command::Compare(args) => evaluate::compare(args),
        Command::Importance(args) => evaluate::importance(args),
        Command::Quickstart(args) => quickstart::run(args, &ctx),
        Command::Reproduce(args) => reproduce::run(args, &ctx),
    }
}

/// Checks, before any work, that each given output file can be written: its folder exists
/// and takes a new file. A long command with a mistyped output path then stops at once
/// instead of after its work.
pub(crate) fn check_outputs(paths: &[Option<&std::path::Path>]) -> anyhow::Result<()> {
    for path in paths.iter().flatten() {
        if path.is_dir() {
            anyhow::bail!("cannot write {}: it is a folder", path.display());
        }
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => std::path::Path::new("."),
        };
        if !dir.is_dir() {
            anyhow::bail!(
                "cannot write {}: no folder {}",
                path.display(),
                dir.display()
            );
        }
        let probe = dir.join(format!(".drape-write-check-{}", std::process::id()));
        std::fs::File::create(&probe)
            .map_err(|e| anyhow::anyhow!("cannot write {}: {e}", path.display()))?;
        let _ = std::fs::remove_file(&probe);
    }
    Ok(())
}

/// A count given on the command line that must be at least 1 (`--samples`, `--batch`...).
pub(crate) fn at_least_one<T>(s: &str) -> Result<T, String>
where
    T: std::str::FromStr + PartialOrd + From<u8>,
{
    match s.parse::<T>() {
        Ok(n) if n >= T::from(1) => Ok(n),
        Ok(_) => Err("must be at least 1".to_string()),
        Err(_) => Err(format!("{s:?} is not a whole number")),
    }
}
