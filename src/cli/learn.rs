//! `drape train`: train a GarNet network on a drape dataset.

use std::path::PathBuf;

use clap::Args;
use learn::config::TrainConfig;
use learn::train::{TrainOptions, train};

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
}

/// Runs `drape train`.
pub fn run(args: TrainArgs) -> anyhow::Result<()> {
    let config = TrainConfig::load(&args.config)?;
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
