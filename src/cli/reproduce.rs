//! `drape reproduce PLAN.toml`: generates the plan's datasets, trains its networks,
//! evaluates them, times the speed-up and writes the reproduction report. Every stage
//! resumes (generation and training resume by themselves; finished stages are skipped), so
//! running the same command again after an interruption, or in the next session,
//! continues. Each stage runs as a child `drape` process, so its output is what the
//! stage's own command prints.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command};
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use clap::Args;
use eval::repro::{Clock, Ledger, Plan, PlanRun, Running};

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
    /// Where the report goes: reproduction.md and reproduction.json (default: the plan's
    /// `docs`, else docs/).
    #[arg(long, value_name = "DIR")]
    docs: Option<PathBuf>,
    /// Only write the report from what is finished, and bring the plan's record
    /// (`record`, a path from the repository's root, where `drape reproduce` runs) up to
    /// date; generate, train and evaluate nothing.
    #[arg(long, conflicts_with = "status")]
    report_only: bool,
    /// Print where the plan stands (stages, hours, epochs, validation Edist, hours left)
    /// and exit; writes nothing, so it can run beside a running `drape reproduce`.
    #[arg(long)]
    status: bool,
    /// Let `drape gen` resume a dataset that another build of drape began (as `drape gen
    /// --mixed-builds`: two builds drape differently by up to 15 mm; its manifest then
    /// records no program), and make again, with this build, a dataset the record says
    /// another build draped and evaluations were made on (runs on the new drapes then do
    /// not pair with those, unless the record names their drapes sha256 and the new
    /// drapes have it). Without it either stops the plan with an error that names
    /// the build (and, for a dataset to be made again, how to make the same drapes).
    #[arg(long)]
    mixed_builds: bool,
    /// Work on these datasets only (keys of the plan's `[[datasets]]`, comma-separated):
    /// make them and train and evaluate the runs on them, with their speed-ups; the other
    /// stages wait for a later invocation. For sessions shorter than the whole plan: pick
    /// the stages that finish within one (a machine that is lost keeps only finished
    /// stages, through the record).
    #[arg(
        long,
        value_name = "KEY,...",
        value_delimiter = ',',
        conflicts_with_all = ["status", "report_only"]
    )]
    only: Vec<String>,
}

/// A child `drape` running `args` with `threads` worker threads (all cores if `None`).
/// `log`: a file its output is appended to (inherited from this process if `None`).
fn spawn(
    ctx: &Context,
    args: &[&std::ffi::OsStr],
    threads: Option<usize>,
    log: Option<&Path>,
) -> anyhow::Result<Child> {
    let exe = std::env::current_exe()?;
    let mut cmd = Command::new(exe);
    cmd.arg("--assets").arg(&ctx.assets);
    // The child stops if this process dies (src/main.rs).
    cmd.env("DRAPE_WATCH_PARENT", std::process::id().to_string());
    if let Some(p) = &ctx.pose_library {
        cmd.arg("--pose-library").arg(p);
    }
    if let Some(t) = threads {
        cmd.env("RAYON_NUM_THREADS", t.to_string());
    }
    if let Some(log) = log {
        let mut f = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(log)?;
        writeln!(
            f,
            "\n== drape {} ({} threads, started by drape reproduce)",
            args.iter()
                .map(|a| a.to_string_lossy())
                .collect::<Vec<_>>()
                .join(" "),
            threads.map_or("all".into(), |t| t.to_string())
        )?;
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
    learn::train::State::load(run).is_ok_and(|s| s.is_some_and(|s| s.finished))
}

/// Where a run under way stands, for the status lines: "epoch E of N, step S" and the
/// last validation Edist (read as `--status` reads it).
fn last_step(run: &Path) -> String {
    let epochs = learn::config::TrainConfig::load(&run.join("config.toml")).map_or(0, |c| c.epochs);
    eval::repro::status::RunProgress::read(run, epochs).map_or_else(
        || "starting".into(),
        |p| {
            format!(
                "epoch {} of {}, step {}{}",
                (p.epochs_done + 1).min(p.epochs.max(1)),
                p.epochs,
                p.steps,
                p.last_val_cm
                    .map_or(String::new(), |v| format!(", validation Edist {v:.2} cm"))
            )
        },
    )
}

/// The last `n` lines of a file (for a failed child's log).
fn tail(path: &Path, n: usize) -> String {
    let t = std::fs::read_to_string(path).unwrap_or_default();
    let lines: Vec<&str> = t.lines().collect();
    lines[lines.len().saturating_sub(n)..].join("\n")
}

/// Sets the flag when dropped, also on an early return or a panic.
struct SetOnDrop<'a>(&'a AtomicBool);

impl Drop for SetOnDrop<'_> {
    fn drop(&mut self) {
        self.0.store(true, Ordering::Relaxed);
    }
}

/// Training children; any still running when this is dropped (an error in this process)
/// are killed, so none trains on unsupervised.
struct Children<'p>(Vec<(&'p PlanRun, Job, Child)>);

/// What a child of the training stages does.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Job {
    /// `drape train`.
    Train,
    /// `drape eval` of a run that has just finished, so that its figures reach the record
    /// in the session that trained it.
    Eval,
}

impl Drop for Children<'_> {
    fn drop(&mut self) {
        for (_, _, c) in &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

/// The `drape gen` arguments that make dataset `d` in `dir`, with the plan's failure gate.
fn gen_args(
    d: &eval::repro::PlanDataset,
    dir: &Path,
    mixed_builds: bool,
) -> Vec<std::ffi::OsString> {
    let mut a: Vec<std::ffi::OsString> = vec![
        "gen".into(),
        d.config.clone().into(),
        "-o".into(),
        dir.into(),
    ];
    if let Some(r) = d.max_failure_rate {
        a.push("--max-failure-rate".into());
        a.push(r.to_string().into());
    }
    if mixed_builds {
        a.push("--mixed-builds".into());
    }
    a
}

/// The next dataset's `drape gen`, started on a training slot that no run will take
/// (`train_runs`): its dataset and process; killed if this is dropped.
struct Filler<'p>(Option<(&'p eval::repro::PlanDataset, Child)>);

impl<'p> Filler<'p> {
    /// Starts `drape gen` of dataset `d` on `threads` threads as stage `gen KEY`, its
    /// output to OUT/logs/gen-KEY.log. A child that cannot start is reported and left to
    /// the dataset's own stage.
    fn start(
        &mut self,
        ctx: &Context,
        d: &'p eval::repro::PlanDataset,
        threads: usize,
        out: &Path,
        clock: &Mutex<Clock>,
        mixed_builds: bool,
    ) -> anyhow::Result<()> {
        let name = format!("gen {}", d.key);
        let mut a = gen_args(d, &data_dir(out, &d.key), mixed_builds);
        a.push("--threads".into());
        a.push(threads.to_string().into());
        let a: Vec<&std::ffi::OsStr> = a.iter().map(|x| x.as_os_str()).collect();
        let log = out.join("logs").join(format!("gen-{}.log", d.key));
        std::fs::create_dir_all(out.join("logs"))?;
        match spawn(ctx, &a, Some(threads), Some(&log)) {
            Ok(c) => {
                println!(
                    "== {name} on {threads} thread(s) beside the training, log {}",
                    log.display()
                );
                lock(clock).start(&name)?;
                self.0 = Some((d, c));
            }
            Err(e) => println!(
                "== {name} did not start beside the training ({e}); its own stage makes it"
            ),
        }
        Ok(())
    }

    /// Ends the stage once the child has exited: done if it succeeded and left a manifest
    /// (a failure is the dataset's own stage's to report: it runs `drape gen` again).
    fn poll(&mut self, plan: &Plan, out: &Path, clock: &Mutex<Clock>) -> anyhow::Result<()> {
        let exited = match &mut self.0 {
            Some((_, c)) => c.try_wait().map(|s| s.map(|s| s.success())),
            None => return Ok(()),
        };
        let ok = match exited {
            Ok(None) => return Ok(()),
            Ok(Some(ok)) => ok,
            Err(_) => false,
        };
        self.end(ok, "exited with an error", plan, out, clock)
    }

    /// Stops the child if it still runs (the training it filled in for has ended): its
    /// stage ends unfinished and resumes as the dataset's own stage, on all threads.
    fn stop(&mut self, plan: &Plan, out: &Path, clock: &Mutex<Clock>) -> anyhow::Result<()> {
        let Some((_, c)) = &mut self.0 else {
            return Ok(());
        };
        let ok = match c.try_wait() {
            Ok(Some(s)) => s.success(),
            _ => {
                let _ = c.kill();
                let _ = c.wait();
                false
            }
        };
        self.end(ok, "stopped: the training ended first", plan, out, clock)
    }

    /// Ends the stage; `why`: what happened if it did not finish.
    fn end(
        &mut self,
        ok: bool,
        why: &str,
        plan: &Plan,
        out: &Path,
        clock: &Mutex<Clock>,
    ) -> anyhow::Result<()> {
        let Some((d, _)) = self.0.take() else {
            return Ok(());
        };
        let name = format!("gen {}", d.key);
        let done = ok && data_dir(out, &d.key).join("manifest.json").exists();
        lock(clock).end(&name, done)?;
        let hours = lock(clock).stage_hours(&name);
        if done {
            println!("== {name}: finished beside the training ({hours:.2} h)");
            let ledger = lock(clock).ledger.clone();
            save_record(plan, out, &ledger);
        } else {
            println!(
                "== {name} beside the training: {why} ({hours:.2} h); its own stage resumes it"
            );
        }
        Ok(())
    }
}

impl Drop for Filler<'_> {
    fn drop(&mut self) {
        if let Some((_, c)) = &mut self.0 {
            let _ = c.kill();
            let _ = c.wait();
        }
    }
}

fn lock(clock: &Mutex<Clock>) -> std::sync::MutexGuard<'_, Clock> {
    clock.lock().unwrap_or_else(|e| e.into_inner())
}

/// Runs `drape reproduce`.
pub fn run(args: ReproduceArgs, ctx: &Context) -> anyhow::Result<()> {
    let plan = Plan::load(&args.plan)?;
    plan.check_seed_configs(Path::new(""))
        .map_err(|e| anyhow::anyhow!("{}: {e}", args.plan.display()))?;
    for k in &args.only {
        if !plan.datasets.iter().any(|d| &d.key == k) {
            let keys: Vec<&str> = plan.datasets.iter().map(|d| d.key.as_str()).collect();
            anyhow::bail!(
                "--only {k}: {} has no dataset {k:?} (its datasets: {})",
                args.plan.display(),
                keys.join(", ")
            );
        }
    }
    let out = args
        .output
        .clone()
        .unwrap_or_else(|| PathBuf::from("runs").join(format!("repro-{}", plan.name)));
    let ledger_path = out.join("stages.json");
    if args.status {
        // A fresh machine: what the plan's record holds (`drape reproduce` restores it).
        let recorded = plan
            .record
            .as_ref()
            .filter(|r| !ledger_path.exists() && r.join("stages.json").exists());
        let (folder, ledger) = match recorded {
            Some(r) => {
                println!(
                    "no working folder {} here: this is the plan's record {} (the next `drape reproduce` restores it)",
                    out.display(),
                    r.display()
                );
                (r.clone(), Ledger::load(&r.join("stages.json"))?)
            }
            None => {
                if !out.is_dir() {
                    println!("nothing has run yet: no working folder {}", out.display());
                }
                (out.clone(), Ledger::load(&ledger_path)?)
            }
        };
        print!(
            "{}",
            eval::repro::status::status(
                &plan,
                &args.plan,
                &folder,
                &ledger,
                std::thread::available_parallelism().map_or(1, |n| n.get()),
            )
        );
        return Ok(());
    }
    std::fs::create_dir_all(&out)
        .map_err(|e| anyhow::anyhow!("cannot make the working folder {}: {e}", out.display()))?;
    // What earlier sessions recorded in the repository (the plan's `record`) and this
    // working folder lacks: a fresh machine resumes where they stopped.
    for what in eval::repro::record::restore(&plan, &out)? {
        println!("restored from the record: {what}");
    }
    let mut ledger = Ledger::load(&ledger_path)?;
    // An earlier version kept running stages' time in a heartbeat file: fold it in once.
    let running_path = out.join("stages.running.json");
    if let Ok(b) = std::fs::read(&running_path) {
        if let Some(r) = Running::parse(&b) {
            ledger.absorb(&r);
            ledger.save(&ledger_path)?;
        }
        std::fs::remove_file(&running_path)?;
    }
    let clock = Mutex::new(Clock::new(ledger, &ledger_path));
    let stop = AtomicBool::new(false);
    let r = std::thread::scope(|s| {
        // Heartbeat: every 30 s the running stages' time goes into stages.json.
        s.spawn(|| {
            let mut warned = false;
            loop {
                for _ in 0..30 {
                    if stop.load(Ordering::Relaxed) {
                        return;
                    }
                    std::thread::sleep(std::time::Duration::from_secs(1));
                }
                let mut c = lock(&clock);
                // The record's ledger too: hours of runs still training count even if this
                // machine is lost before they finish.
                let mut r = c.credit();
                if let (Ok(()), Some(rec)) = (&r, &plan.record)
                    && rec.is_dir()
                {
                    r = c.ledger.save(&rec.join("stages.json"));
                }
                drop(c);
                if let Err(e) = r
                    && !warned
                {
                    eprintln!("warning: cannot save the ledger: {e}");
                    warned = true;
                }
            }
        });
        let _stop = SetOnDrop(&stop);
        if args.report_only {
            Ok(())
        } else {
            stages(ctx, &plan, &out, &clock, args.mixed_builds, &args.only)
        }
    });
    let ledger = clock.into_inner().unwrap_or_else(|e| e.into_inner()).ledger;
    ledger.save(&ledger_path)?;
    save_record(&plan, &out, &ledger);
    r?;
    let docs = args
        .docs
        .clone()
        .or_else(|| plan.docs.clone())
        .unwrap_or_else(|| PathBuf::from("docs"));
    // Part of a plan does not overwrite the plan's report (the last one written, perhaps
    // of a finished pass) with one of partial data.
    if !args.only.is_empty() && !ledger.done.get("eval").copied().unwrap_or(false) {
        println!(
            "report not written: stages of datasets left out of --only are unfinished (the same command with --report-only in place of --only writes the report of what is done)"
        );
        return Ok(());
    }
    let written = eval::repro::write_report(&plan, &args.plan, &out, &ledger, &docs)?;
    for f in written {
        println!("wrote {}", f.display());
    }
    Ok(())
}

/// Runs the plan's unfinished stages: the datasets in turn, each followed by the training
/// of the runs on the datasets made so far in multiples of `parallel_runs` (the rest waits
/// for the next dataset; [`eval::repro::split_group`]), `parallel_runs` at once, each
/// evaluated as it finishes, and the next dataset made on a slot those runs leave free;
/// then the evaluations left and the speed-ups.
fn stages(
    ctx: &Context,
    plan: &Plan,
    out: &Path,
    clock: &Mutex<Clock>,
    mixed_builds: bool,
    only: &[String],
) -> anyhow::Result<()> {
    let data_dir = |key: &str| data_dir(out, key);
    let run_dir = |key: &str| run_dir(out, key);
    // The datasets this invocation works on (all without --only), and the runs on them.
    let chosen = |key: &str| only.is_empty() || only.iter().any(|k| k == key);
    let datasets: Vec<&eval::repro::PlanDataset> =
        plan.datasets.iter().filter(|d| chosen(&d.key)).collect();
    let runs: Vec<&PlanRun> = plan.runs.iter().filter(|r| chosen(&r.data)).collect();
    let speedups: Vec<&String> = plan
        .speedup
        .runs
        .iter()
        .filter(|k| runs.iter().any(|r| &&r.key == k))
        .collect();
    // A fine-tune still to train whose base run is on a dataset left out would never start.
    for r in &runs {
        if let Some(i) = &r.init
            && !runs.iter().any(|b| &b.key == i)
            && !finished_run(&run_dir(i))
            && !finished_run(&run_dir(&r.key))
        {
            let base = plan.runs.iter().find(|b| &b.key == i).expect("validated");
            anyhow::bail!(
                "--only: run {} starts from {}, which trains on dataset {} and is not finished: add {} to --only",
                r.key,
                i,
                base.data,
                base.data
            );
        }
    }
    let eval_dir = |key: &str| out.join("eval").join(key);
    let speed_file = |key: &str| out.join("speedup").join(format!("{key}.json"));
    // One stage on its own: skip it if `skip` says it is done (then it is done in the
    // ledger if `done_if_skipped` says so), stop if over budget, time it into the ledger;
    // it is done if `work` succeeds and `finished` finds its output.
    let stage = |name: &str,
                 skip: &dyn Fn() -> bool,
                 done_if_skipped: &dyn Fn() -> bool,
                 finished: &dyn Fn() -> bool,
                 work: &mut dyn FnMut() -> anyhow::Result<()>|
     -> anyhow::Result<()> {
        if skip() {
            let done = done_if_skipped();
            lock(clock).ledger.done.insert(name.to_string(), done);
            return Ok(());
        }
        over_budget(plan, clock, name)?;
        println!(
            "== {name} ({:.2} of {} hours spent)",
            lock(clock).hours(),
            plan.budget_hours
        );
        lock(clock).start(name)?;
        let r = work();
        let done = r.is_ok() && finished();
        lock(clock).end(name, done)?;
        r
    };

    // A dataset to be made again whose recorded drapes have evaluations: only the build
    // that draped them makes the same drapes (the message says how to get it).
    // With --mixed-builds it is made by this build, and said so.
    let program = dataset::manifest::program_sha256();
    for d in &datasets {
        if eval::repro::record::data_needed(plan, out, &d.key)
            && let Some(why) =
                eval::repro::record::remake_differs(plan, out, &d.key, program.as_deref())
        {
            if !mixed_builds {
                anyhow::bail!(why);
            }
            println!(
                "warning (--mixed-builds: made with this build, its runs pair with the recorded evaluations only if it drapes the same bytes): {why}"
            );
        }
    }
    let mut group: Vec<&PlanRun> = Vec::new();
    for (k, d) in datasets.iter().enumerate() {
        let dir = data_dir(&d.key);
        // Done once `drape gen` has exited successfully (recorded in the ledger): a
        // manifest alone may belong to a dataset above its failure gate. Running gen on a
        // finished dataset only checks it again.
        let name = format!("gen {}", d.key);
        let manifest = || dir.join("manifest.json").exists();
        // A finished dataset of another config (a plan edited after its data were made)
        // is never used in its place.
        if manifest() {
            let want = dataset::config::DatasetConfig::load(&d.config)?.hash();
            let path = dir.join("manifest.json");
            let bytes = std::fs::read(&path)
                .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", path.display()))?;
            let m = dataset::manifest::Manifest::parse(&path, &bytes)?;
            if m.config_sha256 != want {
                anyhow::bail!(
                    "{} holds dataset {:?} (config sha256 {}), but the plan's {:?} for {} resolves to config sha256 {}: use another working folder (-o) or remove that dataset",
                    dir.display(),
                    m.name,
                    &m.config_sha256[..12],
                    d.config,
                    d.key,
                    &want[..12]
                );
            }
        }
        // Skipped when generated here already, or when no stage still to run needs it
        // (its runs are recorded: a fresh machine does not make it again for nothing).
        let passed = || {
            (lock(clock).ledger.done.get(&name) == Some(&true) && manifest())
                || !eval::repro::record::data_needed(plan, out, &d.key)
        };
        stage(&name, &passed, &|| true, &manifest, &mut || {
            let a = gen_args(d, &dir, mixed_builds);
            let a: Vec<&std::ffi::OsStr> = a.iter().map(|x| x.as_os_str()).collect();
            child(ctx, &name, &a)
        })?;
        let ledger = lock(clock).ledger.clone();
        save_record(plan, out, &ledger);
        // The runs on the datasets made so far train before the next dataset is made, so
        // that a session spends its hours on finished runs rather than on data a later
        // session may have to make again; but in multiples of `parallel_runs`, so that no
        // slot idles beside a lone run: the rest waits for the next dataset's runs (all
        // train after the last dataset).
        group.extend(runs.iter().copied().filter(|r| r.data == d.key));
        let (now, later) = eval::repro::split_group(
            &group,
            |r| !finished_run(&run_dir(&r.key)),
            plan.parallel_runs,
            k + 1 == datasets.len(),
        );
        if !now.is_empty() {
            // The next dataset, if it still has to be made: a slot that no run of `now`
            // will take makes it meanwhile.
            let fill = datasets.get(k + 1).copied().filter(|n| {
                !data_dir(&n.key).join("manifest.json").exists()
                    && eval::repro::record::data_needed(plan, out, &n.key)
            });
            train_runs(ctx, plan, &now, fill, out, clock, mixed_builds)?;
        }
        group = later;
    }

    // Whether these runs are evaluated and these speed-ups timed: the ones this invocation
    // works on, and (with --only, for the ledger's `eval`) all of the plan's.
    let evaluated_of = |runs: &[&PlanRun], speedups: &[&String]| {
        runs.iter()
            .all(|r| eval_dir(&r.key).join("metrics.json").exists())
            && speedups.iter().all(|k| speed_file(k).exists())
    };
    let (all_runs, all_speedups): (Vec<&PlanRun>, Vec<&String>) = (
        plan.runs.iter().collect(),
        plan.speedup.runs.iter().collect(),
    );
    let evaluated = || evaluated_of(&runs, &speedups);
    let all_evaluated = || evaluated_of(&all_runs, &all_speedups);
    stage(
        "eval",
        &evaluated,
        &all_evaluated,
        &all_evaluated,
        &mut || {
            for r in &runs {
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
            for &k in &speedups {
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

/// Brings the plan's record up to date (a warning if it cannot: the working folder still
/// holds everything).
fn save_record(plan: &Plan, out: &Path, ledger: &Ledger) {
    let saved = eval::repro::record::save(plan, out, ledger);
    if let (Some(r), false) = (&plan.record, saved.changed.is_empty()) {
        println!(
            "   record {}: {} file(s) updated; commit it to keep them",
            r.display(),
            saved.changed.len()
        );
    }
    for w in &saved.warnings {
        eprintln!("warning: the plan's record: {w}");
    }
}

/// The folder of dataset `key` in the working folder `out`.
fn data_dir(out: &Path, key: &str) -> PathBuf {
    out.join("data").join(key)
}

/// The folder of training run `key` in the working folder `out`.
fn run_dir(out: &Path, key: &str) -> PathBuf {
    out.join("runs").join(key)
}

/// Fails, naming the stage, once the plan's machine hours are spent.
fn over_budget(plan: &Plan, clock: &Mutex<Clock>, name: &str) -> anyhow::Result<()> {
    let spent = lock(clock).hours();
    if spent >= plan.budget_hours {
        anyhow::bail!(
            "the plan's budget of {} machine hours is spent ({spent:.2} h measured); stage {name} not run",
            plan.budget_hours
        );
    }
    Ok(())
}

/// The training stages of `runs`: up to `parallel_runs` children at once, a fine-tune
/// once the run it starts from has finished, and each finished run's evaluation (started
/// before any training waiting for a slot; then the record is brought up to date). With
/// more than one at once, each child's output goes to OUT/logs/. Returns once every run has
/// finished and its evaluation ended (a failed evaluation is left to the eval stage), or
/// fails naming the runs that did not finish (the others are left to finish first).
///
/// `fill`: the next dataset to make. Once a slot frees that no run here will take (nothing
/// waits to train or to be evaluated, and a run still trains: the last of a group rarely
/// ends with the others), `drape gen` makes it on that slot's threads, as its own stage
/// `gen KEY` timed beside the runs. If the runs end first it is stopped (generation
/// resumes) and its stage goes on later on all threads.
fn train_runs(
    ctx: &Context,
    plan: &Plan,
    runs: &[&PlanRun],
    fill: Option<&eval::repro::PlanDataset>,
    out: &Path,
    clock: &Mutex<Clock>,
    mixed_builds: bool,
) -> anyhow::Result<()> {
    let data_dir = |key: &str| data_dir(out, key);
    let run_dir = |key: &str| run_dir(out, key);
    let parallel = plan.parallel_runs;
    let threads = plan.run_threads();
    let log_of = |key: &str| out.join("logs").join(format!("train-{key}.log"));
    let evaluated = |key: &str| out.join("eval").join(key).join("metrics.json").exists();
    let mut pending: Vec<&PlanRun> = Vec::new();
    // Finished runs not yet evaluated, evaluated before any new training starts.
    let mut to_eval: Vec<&PlanRun> = Vec::new();
    for &r in runs {
        if finished_run(&run_dir(&r.key)) {
            lock(clock)
                .ledger
                .done
                .insert(format!("train {}", r.key), true);
            if !evaluated(&r.key) {
                to_eval.push(r);
            }
        } else {
            pending.push(r);
        }
    }
    if threads.is_some() && !pending.is_empty() {
        std::fs::create_dir_all(out.join("logs"))?;
    }
    let mut running = Children(Vec::new());
    let mut fill = fill;
    let mut filler = Filler(None);
    let mut failures: Vec<String> = Vec::new();
    let mut status_at = Instant::now();
    loop {
        // Evaluations go first and also after a failure: a run that trained is evaluated
        // in the session that trained it.
        while running.0.len() < parallel && !to_eval.is_empty() {
            let r = to_eval.remove(0);
            let name = format!("eval {}", r.key);
            let (data, dir, e) = (
                data_dir(&r.data),
                run_dir(&r.key),
                out.join("eval").join(&r.key),
            );
            let a: Vec<&std::ffi::OsStr> = vec![
                "eval".as_ref(),
                "--model".as_ref(),
                dir.as_os_str(),
                "--data".as_ref(),
                data.as_os_str(),
                "-o".as_ref(),
                e.as_os_str(),
            ];
            let log = out.join("logs").join(format!("eval-{}.log", r.key));
            println!("== {name}, log {}", log.display());
            std::fs::create_dir_all(out.join("logs"))?;
            match spawn(ctx, &a, threads, Some(&log)) {
                Ok(c) => {
                    running.0.push((r, Job::Eval, c));
                    lock(clock).start(&name)?;
                }
                Err(e) => failures.push(format!("{name} did not start: {e}")),
            }
        }
        while failures.is_empty() && running.0.len() < parallel {
            // A fine-tune waits until the run it starts from is finished on disk and its
            // process has been reaped (its last files may be written just before it exits).
            let ready = pending.iter().position(|r| {
                r.init.as_ref().is_none_or(|i| {
                    finished_run(&run_dir(i)) && !running.0.iter().any(|(x, _, _)| &x.key == i)
                })
            });
            let Some(k) = ready else { break };
            let r = pending.remove(k);
            let name = format!("train {}", r.key);
            if let Err(e) = over_budget(plan, clock, &name) {
                failures.push(e.to_string());
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
            let epochs = r.epochs.map(|e| e.to_string());
            if let Some(e) = &epochs {
                a.push("--epochs".as_ref());
                a.push(e.as_ref());
            }
            let minutes = r.wall_clock_minutes.map(|m| m.to_string());
            if let Some(m) = &minutes {
                a.push("--wall-clock-minutes".as_ref());
                a.push(m.as_ref());
            }
            if let Some(w) = plan.widths {
                a.push("--widths".as_ref());
                a.push(w.name().as_ref());
            }
            // The last run, with nothing beside it to train, evaluate or make, takes every
            // core.
            let threads = if running.0.is_empty()
                && pending.is_empty()
                && to_eval.is_empty()
                && fill.is_none()
            {
                threads.map(|_| std::thread::available_parallelism().map_or(1, |n| n.get()))
            } else {
                threads
            };
            let spent = lock(clock).hours();
            let log = log_of(&r.key);
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
            match spawn(ctx, &a, threads, threads.map(|_| log.as_path())) {
                Ok(c) => {
                    running.0.push((r, Job::Train, c));
                    lock(clock).start(&name)?;
                }
                Err(e) => failures.push(format!("{name} did not start: {e}")),
            }
        }
        if failures.is_empty()
            && pending.is_empty()
            && to_eval.is_empty()
            && !running.0.is_empty()
            && running.0.len() < parallel
            && let Some(d) = fill.take()
        {
            let t = threads.unwrap_or(1) * (parallel - running.0.len());
            filler.start(ctx, d, t, out, clock, mixed_builds)?;
        }
        if running.0.is_empty() {
            filler.stop(plan, out, clock)?;
            break;
        }
        std::thread::sleep(std::time::Duration::from_secs(1));
        filler.poll(plan, out, clock)?;
        let mut k = 0;
        while k < running.0.len() {
            let status = match running.0[k].2.try_wait() {
                Ok(None) => {
                    k += 1;
                    continue;
                }
                Ok(Some(status)) => Ok(status),
                Err(e) => Err(e),
            };
            let (r, job, _) = running.0.remove(k);
            if job == Job::Eval {
                let name = format!("eval {}", r.key);
                let done = evaluated(&r.key);
                lock(clock).end(&name, done)?;
                match status {
                    Ok(s) if s.success() && done => {
                        println!("== {name}: done");
                        let ledger = lock(clock).ledger.clone();
                        save_record(plan, out, &ledger);
                    }
                    // Not a reason to stop training: the eval stage tries it again and
                    // fails there if it fails again.
                    Ok(s) => {
                        let log = out.join("logs").join(format!("eval-{}.log", r.key));
                        println!(
                            "== {name} failed ({s}); the eval stage tries it again; end of {}:\n{}",
                            log.display(),
                            tail(&log, 10)
                        );
                    }
                    Err(e) => println!("== {name}: cannot wait for its process: {e}"),
                }
                continue;
            }
            let name = format!("train {}", r.key);
            let done = finished_run(&run_dir(&r.key));
            lock(clock).end(&name, done)?;
            let hours = lock(clock).stage_hours(&name);
            let failure = match status {
                Ok(s) if s.success() && done => None,
                Ok(s) if s.success() => Some(format!(
                    "{name} stopped at its wall-clock cap before its last epoch; run the same command again to continue it"
                )),
                Ok(s) => Some(format!(
                    "{name} failed ({s}); fix the cause and run the same command again to resume"
                )),
                Err(e) => Some(format!("{name}: cannot wait for its process: {e}")),
            };
            match failure {
                None => {
                    println!("== {name}: finished ({hours:.2} h in all)");
                    to_eval.push(r);
                    let ledger = lock(clock).ledger.clone();
                    save_record(plan, out, &ledger);
                }
                Some(f) => {
                    println!("== {f}");
                    if threads.is_some() {
                        let log = log_of(&r.key);
                        println!("   end of {}:\n{}", log.display(), tail(&log, 10));
                    }
                    if !running.0.is_empty() {
                        println!(
                            "   waiting for the {} run(s) still training",
                            running.0.len()
                        );
                    }
                    failures.push(f);
                }
            }
        }
        if threads.is_some() && status_at.elapsed().as_secs() >= 600 {
            status_at = Instant::now();
            for (r, _, _) in running.0.iter().filter(|(_, j, _)| *j == Job::Train) {
                println!(
                    "   train {}: {:.2} h, {}",
                    r.key,
                    lock(clock).stage_hours(&format!("train {}", r.key)),
                    last_step(&run_dir(&r.key))
                );
            }
        }
    }
    if !failures.is_empty() {
        anyhow::bail!("{}", failures.join("\n"));
    }
    if let Some(r) = pending.first() {
        anyhow::bail!("train {} never became ready to start", r.key);
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gen_children_get_the_datasets_gate_and_mixed_builds_only_when_asked() {
        let d = eval::repro::PlanDataset {
            key: "sweater".into(),
            config: "cpu-repro-sweater".into(),
            planned_hours: 0.4,
            max_failure_rate: Some(0.08),
        };
        let args = |mixed| {
            gen_args(&d, Path::new("w/data/sweater"), mixed)
                .iter()
                .map(|a| a.to_string_lossy().into_owned())
                .collect::<Vec<_>>()
                .join(" ")
        };
        assert_eq!(
            args(false),
            "gen cpu-repro-sweater -o w/data/sweater --max-failure-rate 0.08"
        );
        assert_eq!(
            args(true),
            "gen cpu-repro-sweater -o w/data/sweater --max-failure-rate 0.08 --mixed-builds"
        );
    }
}
