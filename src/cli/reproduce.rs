//! `drape reproduce PLAN.toml`: generates the plan's datasets, trains its networks,
//! evaluates them, times the speed-up and writes the reproduction report. Every stage
//! resumes (generation and training resume by themselves; finished stages are skipped), so
//! running the same command again after an interruption, or in the next session,
//! continues. Each stage runs as a child `drape` process, so its output is what the
//! stage's own command prints.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use clap::Args;
use eval::repro::{Ledger, Plan, Running};

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

/// A child `drape` running `args` with `threads` worker threads (all cores if `None`).
/// `log`: where its output goes (inherited from this process if `None`).
fn spawn(
    ctx: &Context,
    args: &[&std::ffi::OsStr],
    threads: Option<usize>,
    log: Option<&Path>,
) -> anyhow::Result<Child> {
    let exe = std::env::current_exe()?;
    let mut cmd = Command::new(exe);
    cmd.arg("--assets").arg(&ctx.assets);
    if let Some(p) = &ctx.pose_library {
        cmd.arg("--pose-library").arg(p);
    }
    if let Some(t) = threads {
        cmd.env("RAYON_NUM_THREADS", t.to_string());
    }
    if let Some(log) = log {
        let f = std::fs::File::create(log)?;
        cmd.stdout(f.try_clone()?).stderr(f);
    }
    Ok(cmd.args(args).spawn()?)
}

/// Runs a child `drape` with `args`; fails with the stage's name if it fails.
fn child(ctx: &Context, stage: &str, args: &[&std::ffi::OsStr]) -> anyhow::Result<()> {
    let status = spawn(ctx, args, None, None)?.wait()?;
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

/// The last line of a run's `steps.csv` as "epoch E, step S" (for the status lines).
fn last_step(run: &Path) -> String {
    std::fs::read_to_string(run.join("steps.csv"))
        .ok()
        .and_then(|t| {
            let f: Vec<String> = t.lines().last()?.split(',').map(String::from).collect();
            (f.len() > 2 && f[0] != "epoch").then(|| format!("epoch {}, step {}", f[0], f[2]))
        })
        .unwrap_or_else(|| "starting".into())
}

/// What is running now, for the heartbeat.
#[derive(Default)]
struct Now {
    phase: Option<Instant>,
    stages: BTreeMap<String, Instant>,
}

impl Now {
    fn running(&self) -> Running {
        Running {
            machine: self.phase.map_or(0.0, |t| t.elapsed().as_secs_f64()),
            stages: self
                .stages
                .iter()
                .map(|(k, t)| (k.clone(), t.elapsed().as_secs_f64()))
                .collect(),
        }
    }
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
    // Stages that a killed session left running: their time so far, kept by a heartbeat.
    let running_path = out.join("stages.running.json");
    if let Ok(b) = std::fs::read(&running_path) {
        // (An older heartbeat held one stage as [name, seconds].)
        let r = serde_json::from_slice::<Running>(&b).ok().or_else(|| {
            serde_json::from_slice::<(String, f64)>(&b)
                .ok()
                .map(|(name, s)| Running {
                    machine: s,
                    stages: [(name, s)].into(),
                })
        });
        if let Some(r) = r {
            ledger.absorb(&r);
            ledger.save(&ledger_path)?;
        }
        std::fs::remove_file(&running_path)?;
    }
    let now = Mutex::new(Now::default());
    let stop = AtomicBool::new(false);
    let r = std::thread::scope(|s| {
        // Heartbeat: what runs and for how long, to stages.running.json every 30 s.
        s.spawn(|| {
            while !stop.load(Ordering::Relaxed) {
                let r = now.lock().expect("heartbeat").running();
                if r.machine > 0.0 {
                    let beat = serde_json::to_vec(&r).expect("json");
                    let _ = dataset::generate::write_atomic(&running_path, &beat);
                }
                for _ in 0..30 {
                    if stop.load(Ordering::Relaxed) {
                        break;
                    }
                    std::thread::sleep(std::time::Duration::from_secs(1));
                }
            }
        });
        let r = stages(&args, ctx, &plan, &out, &mut ledger, &now);
        stop.store(true, Ordering::Relaxed);
        r
    });
    let _ = std::fs::remove_file(&running_path);
    r?;
    let written = eval::repro::write_report(&plan, &args.plan, &out, &ledger, &args.docs)?;
    for f in written {
        println!("wrote {}", f.display());
    }
    Ok(())
}

/// Runs the plan's unfinished stages: generation, training (`parallel_runs` at once),
/// evaluation.
fn stages(
    args: &ReproduceArgs,
    ctx: &Context,
    plan: &Plan,
    out: &Path,
    ledger: &mut Ledger,
    now: &Mutex<Now>,
) -> anyhow::Result<()> {
    if args.report_only {
        return Ok(());
    }
    let ledger_path = out.join("stages.json");
    let data_dir = |key: &str| out.join("data").join(key);
    let run_dir = |key: &str| out.join("runs").join(key);
    let eval_dir = |key: &str| out.join("eval").join(key);
    let speed_file = |key: &str| out.join("speedup").join(format!("{key}.json"));
    let over_budget = |ledger: &Ledger, extra: f64, name: &str| -> anyhow::Result<()> {
        let spent = ledger.hours() + extra / 3600.0;
        if spent >= plan.budget_hours {
            anyhow::bail!(
                "the plan's budget of {} machine hours is spent ({spent:.2} h measured); stage {name} not run",
                plan.budget_hours
            );
        }
        Ok(())
    };

    // One stage on its own: skip if done, stop if over budget, time it into the ledger.
    let stage = |ledger: &mut Ledger,
                 name: &str,
                 done: &dyn Fn() -> bool,
                 work: &mut dyn FnMut() -> anyhow::Result<()>|
     -> anyhow::Result<()> {
        if done() {
            ledger.done.insert(name.to_string(), true);
            return Ok(());
        }
        over_budget(ledger, 0.0, name)?;
        println!(
            "== {name} ({:.2} of {} hours spent)",
            ledger.hours(),
            plan.budget_hours
        );
        let t0 = Instant::now();
        {
            let mut n = now.lock().expect("heartbeat");
            n.phase = Some(t0);
            n.stages.insert(name.to_string(), t0);
        }
        let r = work();
        *now.lock().expect("heartbeat") = Now::default();
        let s = t0.elapsed().as_secs_f64();
        *ledger.seconds.entry(name.to_string()).or_default() += s;
        ledger.machine_seconds += s;
        ledger.done.insert(name.to_string(), r.is_ok() && done());
        ledger.save(&ledger_path)?;
        r
    };

    for d in &plan.datasets {
        let dir = data_dir(&d.key);
        stage(
            ledger,
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

    // Training: up to `parallel_runs` children at once, a fine-tune once its start is
    // finished. With more than one at once, each child's output goes to OUT/logs/.
    let parallel = plan.parallel_runs;
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let threads = (parallel > 1).then(|| (cores / parallel).max(1));
    let mut pending: Vec<&eval::repro::PlanRun> = Vec::new();
    for r in &plan.runs {
        let name = format!("train {}", r.key);
        if finished_run(&run_dir(&r.key)) {
            ledger.done.insert(name, true);
        } else {
            pending.push(r);
        }
    }
    if !pending.is_empty() {
        std::fs::create_dir_all(out.join("logs"))?;
        let phase = Instant::now();
        now.lock().expect("heartbeat").phase = Some(phase);
        let mut running: Vec<(&eval::repro::PlanRun, Child, Instant)> = Vec::new();
        let mut failure: Option<anyhow::Error> = None;
        let mut status_at = Instant::now();
        loop {
            while failure.is_none() && running.len() < parallel {
                let ready = pending
                    .iter()
                    .position(|r| r.init.as_ref().is_none_or(|i| finished_run(&run_dir(i))));
                let Some(k) = ready else { break };
                let r = pending.remove(k);
                let name = format!("train {}", r.key);
                if let Err(e) = over_budget(ledger, phase.elapsed().as_secs_f64(), &name) {
                    failure = Some(e);
                    break;
                }
                let (data, dir) = (data_dir(&r.data), run_dir(&r.key));
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
                let log = out.join("logs").join(format!("train-{}.log", r.key));
                let spent = ledger.hours() + phase.elapsed().as_secs_f64() / 3600.0;
                match threads {
                    Some(t) => println!(
                        "== {name} on {t} thread(s), log {} ({spent:.2} of {} hours spent)",
                        log.display(),
                        plan.budget_hours
                    ),
                    None => println!(
                        "== {name} ({spent:.2} of {} hours spent)",
                        plan.budget_hours
                    ),
                }
                let log = threads.is_some().then_some(log.as_path());
                match spawn(ctx, &a, threads, log) {
                    Ok(c) => {
                        let t = Instant::now();
                        now.lock().expect("heartbeat").stages.insert(name, t);
                        running.push((r, c, t));
                    }
                    Err(e) => failure = Some(e),
                }
            }
            if running.is_empty() {
                break;
            }
            std::thread::sleep(std::time::Duration::from_secs(1));
            let mut k = 0;
            while k < running.len() {
                let Some(status) = running[k].1.try_wait()? else {
                    k += 1;
                    continue;
                };
                let (r, _, t) = running.remove(k);
                let name = format!("train {}", r.key);
                now.lock().expect("heartbeat").stages.remove(&name);
                let s = t.elapsed().as_secs_f64();
                *ledger.seconds.entry(name.clone()).or_default() += s;
                let done = finished_run(&run_dir(&r.key));
                ledger.done.insert(name.clone(), done);
                ledger.save(&ledger_path)?;
                println!(
                    "== {name}: {} after {:.2} h",
                    if done { "finished" } else { "stopped" },
                    s / 3600.0
                );
                if failure.is_none() && !status.success() {
                    failure = Some(anyhow::anyhow!(
                        "stage {name} failed ({status}; log in {}); fix the cause and run the same command again to resume",
                        out.join("logs").display()
                    ));
                } else if failure.is_none() && !done {
                    failure = Some(anyhow::anyhow!(
                        "{name} stopped at its wall-clock cap before its last epoch; run the same command again to continue it"
                    ));
                }
            }
            if threads.is_some() && status_at.elapsed().as_secs() >= 600 {
                status_at = Instant::now();
                for (r, _, t) in &running {
                    println!(
                        "   train {}: {:.2} h, {}",
                        r.key,
                        t.elapsed().as_secs_f64() / 3600.0,
                        last_step(&run_dir(&r.key))
                    );
                }
            }
        }
        ledger.machine_seconds += phase.elapsed().as_secs_f64();
        *now.lock().expect("heartbeat") = Now::default();
        ledger.save(&ledger_path)?;
        if let Some(e) = failure {
            return Err(e);
        }
    }

    stage(
        ledger,
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
    Ok(())
}
