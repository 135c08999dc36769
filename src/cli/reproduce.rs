//! `drape reproduce PLAN.toml`: generates the plan's datasets, trains its networks,
//! evaluates them, times the speed-up and writes the reproduction report. Every stage
//! resumes (generation and training resume by themselves; finished stages are skipped), so
//! running the same command again after an interruption, or in the next session,
//! continues. Each stage runs as a child `drape` process, so its output is what the
//! stage's own command prints.

use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Instant;

use clap::Args;
use eval::repro::{Ledger, Plan};

use super::Context;

/// `drape reproduce`.
#[derive(Debug, Args)]
pub struct ReproduceArgs {
    /// Reproduction plan (configs/repro/*.toml).
    #[arg(value_name = "PLAN.toml")]
    plan: PathBuf,
    /// Working folder: data/, runs/, eval/, speedup/, stages.json (default runs/repro-NAME).
    #[arg(short, long, value_name = "DIR")]
    output: Option<PathBuf>,
    /// Where the report goes: reproduction.md and reproduction.json (default docs/).
    #[arg(long, value_name = "DIR", default_value = "docs")]
    docs: PathBuf,
    /// Only write the report from what is finished; run nothing.
    #[arg(long)]
    report_only: bool,
}

/// Runs a child `drape` with `args`; fails with the stage's name if it fails.
fn child(ctx: &Context, stage: &str, args: &[&std::ffi::OsStr]) -> anyhow::Result<()> {
    let exe = std::env::current_exe()?;
    let mut cmd = Command::new(exe);
    cmd.arg("--assets").arg(&ctx.assets);
    if let Some(p) = &ctx.pose_library {
        cmd.arg("--pose-library").arg(p);
    }
    let status = cmd.args(args).status()?;
    if !status.success() {
        anyhow::bail!(
            "stage {stage} failed ({status}); fix the cause and run the same command again to resume"
        );
    }
    Ok(())
}

fn finished_run(run: &Path) -> bool {
    std::fs::read(run.join("state.json"))
        .ok()
        .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
        .and_then(|v| v["finished"].as_bool())
        .unwrap_or(false)
}

/// Runs `drape reproduce`.
pub fn run(args: ReproduceArgs, ctx: &Context) -> anyhow::Result<()> {
    let plan = Plan::load(&args.plan)?;
    let out = args
        .output
        .clone()
        .unwrap_or_else(|| PathBuf::from("runs").join(format!("repro-{}", plan.name)));
    std::fs::create_dir_all(&out)?;
    let ledger_path = out.join("stages.json");
    let mut ledger = Ledger::load(&ledger_path)?;
    // A stage that a killed session left running: its time so far, kept by a heartbeat.
    let running_path = out.join("stages.running.json");
    if let Ok(b) = std::fs::read(&running_path) {
        if let Ok((name, seconds)) = serde_json::from_slice::<(String, f64)>(&b) {
            *ledger.seconds.entry(name).or_default() += seconds;
            ledger.save(&ledger_path)?;
        }
        std::fs::remove_file(&running_path)?;
    }
    let data_dir = |key: &str| out.join("data").join(key);
    let run_dir = |key: &str| out.join("runs").join(key);
    let eval_dir = |key: &str| out.join("eval").join(key);
    let speed_file = |key: &str| out.join("speedup").join(format!("{key}.json"));

    // One stage: skip if done, stop if over budget, time it into the ledger.
    let mut stage = |name: &str,
                     done: &dyn Fn() -> bool,
                     work: &mut dyn FnMut() -> anyhow::Result<()>|
     -> anyhow::Result<()> {
        if done() {
            ledger.done.insert(name.to_string(), true);
            return Ok(());
        }
        if ledger.hours() >= plan.budget_hours {
            anyhow::bail!(
                "the plan's budget of {} machine hours is spent ({:.2} h measured); stage {name} not run",
                plan.budget_hours,
                ledger.hours()
            );
        }
        println!(
            "== {name} ({:.2} of {} hours spent)",
            ledger.hours(),
            plan.budget_hours
        );
        let t0 = Instant::now();
        // Heartbeat: the elapsed time goes to stages.running.json every 30 s, so a session
        // that ends abruptly still counts its hours on the next run.
        let stop = std::sync::atomic::AtomicBool::new(false);
        let r = std::thread::scope(|s| {
            s.spawn(|| {
                while !stop.load(std::sync::atomic::Ordering::Relaxed) {
                    let beat =
                        serde_json::to_vec(&(name, t0.elapsed().as_secs_f64())).expect("json");
                    let _ = dataset::generate::write_atomic(&running_path, &beat);
                    for _ in 0..30 {
                        if stop.load(std::sync::atomic::Ordering::Relaxed) {
                            break;
                        }
                        std::thread::sleep(std::time::Duration::from_secs(1));
                    }
                }
            });
            let r = work();
            stop.store(true, std::sync::atomic::Ordering::Relaxed);
            r
        });
        let _ = std::fs::remove_file(&running_path);
        *ledger.seconds.entry(name.to_string()).or_default() += t0.elapsed().as_secs_f64();
        ledger.done.insert(name.to_string(), r.is_ok() && done());
        ledger.save(&ledger_path)?;
        r
    };

    if !args.report_only {
        for d in &plan.datasets {
            let dir = data_dir(&d.key);
            stage(
                &format!("gen {}", d.key),
                &|| dir.join("manifest.json").exists(),
                &mut || {
                    child(
                        ctx,
                        &format!("gen {}", d.key),
                        &[
                            "gen".as_ref(),
                            d.config.as_ref(),
                            "-o".as_ref(),
                            dir.as_os_str(),
                        ],
                    )
                },
            )?;
        }
        for r in &plan.runs {
            let dir = run_dir(&r.key);
            stage(
                &format!("train {}", r.key),
                &|| finished_run(&dir),
                &mut || {
                    let data = data_dir(&r.data);
                    let mut a: Vec<&std::ffi::OsStr> = vec![
                        "train".as_ref(),
                        r.config.as_os_str(),
                        "--data".as_ref(),
                        data.as_os_str(),
                        "-o".as_ref(),
                        dir.as_os_str(),
                    ];
                    let init = r.init.as_ref().map(|k| run_dir(k));
                    if let Some(i) = &init {
                        a.push("--init".as_ref());
                        a.push(i.as_os_str());
                    }
                    child(ctx, &format!("train {}", r.key), &a)?;
                    if !finished_run(&dir) {
                        anyhow::bail!(
                            "train {} stopped at its wall-clock cap before its last epoch; run the same command again to continue it",
                            r.key
                        );
                    }
                    Ok(())
                },
            )?;
        }
        stage(
            "eval",
            &|| {
                plan.runs
                    .iter()
                    .all(|r| eval_dir(&r.key).join("metrics.json").exists())
                    && plan.speedup.runs.iter().all(|k| speed_file(k).exists())
            },
            &mut || {
                for r in &plan.runs {
                    let e = eval_dir(&r.key);
                    if e.join("metrics.json").exists() {
                        continue;
                    }
                    let (rd, dd) = (run_dir(&r.key), data_dir(&r.data));
                    child(
                        ctx,
                        &format!("eval {}", r.key),
                        &[
                            "eval".as_ref(),
                            "--model".as_ref(),
                            rd.as_os_str(),
                            "--data".as_ref(),
                            dd.as_os_str(),
                            "-o".as_ref(),
                            e.as_os_str(),
                        ],
                    )?;
                }
                std::fs::create_dir_all(out.join("speedup"))?;
                for k in &plan.speedup.runs {
                    let f = speed_file(k);
                    if f.exists() {
                        continue;
                    }
                    let r = plan.runs.iter().find(|r| &r.key == k).expect("validated");
                    let (rd, dd) = (run_dir(k), data_dir(&r.data));
                    let samples = plan.speedup.samples.to_string();
                    child(
                        ctx,
                        &format!("speedup {k}"),
                        &[
                            "bench".as_ref(),
                            "speedup".as_ref(),
                            "--model".as_ref(),
                            rd.as_os_str(),
                            "--data".as_ref(),
                            dd.as_os_str(),
                            "--samples".as_ref(),
                            samples.as_ref(),
                            "--json".as_ref(),
                            f.as_os_str(),
                        ],
                    )?;
                }
                Ok(())
            },
        )?;
    }
    let written = eval::repro::write_report(&plan, &args.plan, &out, &ledger, &args.docs)?;
    for f in written {
        println!("wrote {}", f.display());
    }
    Ok(())
}
