//! `drape reproduce PLAN --status`: where a reproduction stands, read from its working
//! folder without writing to it (safe beside a running `drape reproduce`).
//!
//! Per stage: planned and measured hours (the ledger, `stages.json`), and what it has
//! done: a dataset's drapes, a run's epochs and validation Edist (its `steps.csv` and
//! `log.csv`) with the hours it will take in all at the pace measured so far.

use std::fmt::Write as _;
use std::path::Path;

use super::{Ledger, Plan, fmt};

/// How far a training run has come, from its run folder.
#[derive(Debug, Clone, PartialEq)]
pub struct RunProgress {
    /// Epochs the run trains.
    pub epochs: usize,
    /// Epochs finished (with a line in `log.csv`).
    pub epochs_done: usize,
    /// Optimiser steps so far.
    pub steps: u64,
    /// Steps of one epoch, known once the first epoch is over.
    pub steps_per_epoch: Option<u64>,
    /// Training hours so far (all sessions).
    pub hours: f64,
    /// Validation Edist (cm) of the last finished epoch.
    pub last_val_cm: Option<f64>,
    /// The lowest validation Edist (cm) so far.
    pub best_val_cm: Option<f64>,
    /// All epochs done.
    pub finished: bool,
}

impl RunProgress {
    /// Reads run folder `dir` of a run of `epochs` epochs; None before its first step.
    pub fn read(dir: &Path, epochs: usize) -> Option<Self> {
        let state = learn::train::State::load(dir).ok().flatten();
        let (step, seconds, steps_per_epoch) = match std::fs::read_to_string(dir.join("steps.csv"))
        {
            Ok(steps) => {
                // epoch, batch, step, seconds, ...: lines redone after an interruption
                // repeat an (epoch, batch); the last line is the latest.
                let rows: Vec<(usize, u64, u64, f64)> = steps
                    .lines()
                    .filter_map(|l| {
                        let mut f = l.split(',');
                        Some((
                            f.next()?.parse().ok()?,
                            f.next()?.parse().ok()?,
                            f.next()?.parse().ok()?,
                            f.next()?.parse().ok()?,
                        ))
                    })
                    .collect();
                let &(_, _, step, seconds) = rows.last()?;
                let per_epoch = rows
                    .iter()
                    .any(|r| r.0 > 0)
                    .then(|| rows.iter().filter(|r| r.0 == 0).map(|r| r.1).max())
                    .flatten();
                (step, seconds, per_epoch)
            }
            // A finished run restored from a plan's record keeps its state, not its steps.
            Err(_) => {
                let s = state.as_ref().filter(|s| s.finished)?;
                let per_epoch = (epochs > 0).then(|| s.steps / epochs as u64);
                (s.steps, s.seconds, per_epoch)
            }
        };
        let log = std::fs::read_to_string(dir.join("log.csv")).unwrap_or_default();
        let mut epochs_done = 0;
        let mut vals = Vec::new();
        for l in log.lines() {
            let f: Vec<&str> = l.split(',').collect();
            let Some(epoch) = f.first().and_then(|e| e.parse::<usize>().ok()) else {
                continue;
            };
            epochs_done = epochs_done.max(epoch + 1);
            if f.get(1) == Some(&"val") {
                // The last column is Edist in cm (learn::train::Terms::HEADER).
                if let Some(e) = f.last().and_then(|e| e.parse::<f64>().ok()) {
                    vals.push(e);
                }
            }
        }
        let finished = state.is_some_and(|s| s.finished);
        Some(Self {
            epochs,
            epochs_done,
            steps: step,
            steps_per_epoch,
            hours: seconds / 3600.0,
            last_val_cm: vals.last().copied(),
            best_val_cm: vals.iter().copied().reduce(f64::min),
            finished,
        })
    }

    /// Training hours the whole run takes at the pace so far (None until one epoch is
    /// over, when the steps of an epoch are known).
    pub fn projected_hours(&self) -> Option<f64> {
        if self.finished {
            return Some(self.hours);
        }
        let total = self.steps_per_epoch? * self.epochs as u64;
        (self.steps > 0 && total > 0).then(|| self.hours * total as f64 / self.steps as f64)
    }
}

/// The epochs run `key` trains: the plan's override, else its run folder's resolved
/// config, else the plan's config file.
fn run_epochs(plan_epochs: Option<usize>, dir: &Path, config: &Path) -> Option<usize> {
    plan_epochs.or_else(|| {
        learn::config::TrainConfig::load(&dir.join("config.toml"))
            .or_else(|_| learn::config::TrainConfig::load(config))
            .ok()
            .map(|c| c.epochs)
    })
}

/// The share of the machine's hours a training run under way takes: all of them if it
/// last started on every one of the `cores` (the lone run; "all" is the header of a child
/// given no thread count), read from the last header `drape reproduce` wrote to its log
/// `log`; else one slot's, `1 / parallel_runs` (also when the log does not say).
fn core_share(log: &Path, parallel_runs: usize, cores: usize) -> f64 {
    let text = std::fs::read(log).unwrap_or_default();
    let text = String::from_utf8_lossy(&text);
    let threads = text.lines().rev().find_map(|l| {
        l.strip_prefix("== drape train ")?
            .strip_suffix(" threads, started by drape reproduce)")?
            .rsplit_once(" (")
            .map(|(_, n)| n.to_string())
    });
    let every_core = match threads.as_deref() {
        Some("all") => true,
        Some(n) => n.parse::<usize>().is_ok_and(|n| n >= cores),
        None => false,
    };
    if every_core {
        1.0
    } else {
        1.0 / parallel_runs.max(1) as f64
    }
}

/// The status of plan `plan` (loaded from `plan_path`) in working folder `out` on a
/// machine of `cores` cores, as text: a table of the stages and an estimate of the
/// machine hours left.
pub fn status(plan: &Plan, plan_path: &Path, out: &Path, ledger: &Ledger, cores: usize) -> String {
    let mut w = String::new();
    let done = |name: &str| ledger.done.get(name).copied().unwrap_or(false);
    // The evaluations made as runs finish ("eval KEY") count in the eval stage.
    let measured = |name: &str| {
        ledger
            .seconds
            .iter()
            .filter(|(k, _)| *k == name || (name == "eval" && k.starts_with("eval ")))
            .map(|(_, s)| s / 3600.0)
            .reduce(|a, b| a + b)
    };
    writeln!(
        w,
        "plan {} ({}), working folder {}\nmachine hours measured: {:.2} of a budget of {} (planned in all: {:.2})\n",
        plan.name,
        plan_path.display(),
        out.display(),
        ledger.hours(),
        plan.budget_hours,
        plan.planned_machine_hours()
    )
    .unwrap();
    writeln!(
        w,
        "| stage | planned h | measured h | state |\n|---|---|---|---|"
    )
    .unwrap();
    // Machine hours left: stages not begun at their planned hours, runs under way at
    // their measured pace. Planned training hours are a slot's (one of `parallel_runs`
    // training at once), so they are shared among the slots; a run under way counts its
    // hours left at its pace times the share of the cores it trains on (`core_share`):
    // the whole of them for a lone run on every core.
    let (mut left, mut left_training) = (0.0f64, 0.0f64);
    for d in &plan.datasets {
        let name = format!("gen {}", d.key);
        let mp = out.join("data").join(&d.key).join("manifest.json");
        let state = if done(&name) {
            std::fs::read(&mp)
                .ok()
                .and_then(|b| dataset::manifest::Manifest::parse(&mp, &b).ok())
                .map_or("done".into(), |m| {
                    let t = m.tally_by_split();
                    let n: usize = t.values().map(|x| x.samples).sum();
                    let failed: usize = t.values().map(|x| x.failed).sum();
                    format!("done: {n} drapes, {failed} failed")
                })
        } else if let Some(hours) = measured(&name) {
            let dir = out.join("data").join(&d.key);
            let made = dataset::config::DatasetConfig::load(&d.config)
                .and_then(|c| dataset::generate::drapes_done(&c, &dir));
            // The hours of the drapes on disk: a lost machine's are not in the pace.
            let hours = hours - ledger.lost.get(&name).map_or(0.0, |s| s / 3600.0);
            match made {
                // Drapes left at the pace so far: the hours over the drapes made (on all
                // threads or one beside training).
                Ok((n, total)) if n > 0 && hours > 0.0 => {
                    let rest = hours * (total - n.min(total)) as f64 / n as f64;
                    left += rest;
                    format!(
                        "under way: {n} of {total} drapes, about {rest:.2} h left at this pace (resumes)"
                    )
                }
                Ok((n, total)) => {
                    left += d.planned_hours;
                    format!("under way: {n} of {total} drapes (resumes)")
                }
                Err(e) => {
                    left += d.planned_hours;
                    format!("under way ({e})")
                }
            }
        } else {
            left += d.planned_hours;
            "not started".into()
        };
        writeln!(
            w,
            "| {name} | {:.2} | {} | {state} |",
            d.planned_hours,
            fmt(measured(&name), 2)
        )
        .unwrap();
    }
    for r in &plan.runs {
        let name = format!("train {}", r.key);
        let dir = out.join("runs").join(&r.key);
        let epochs = run_epochs(r.epochs, &dir, &r.config);
        let progress = epochs.and_then(|e| RunProgress::read(&dir, e));
        let state = match &progress {
            Some(p) if p.finished => {
                let evaluated = out.join("eval").join(&r.key).join("metrics.json").exists();
                format!(
                    "done: {} epochs, {:.2} h of training, validation Edist {} cm (best {}){}",
                    p.epochs,
                    p.hours,
                    fmt(p.last_val_cm, 2),
                    fmt(p.best_val_cm, 2),
                    if evaluated { "; evaluated" } else { "" }
                )
            }
            Some(p) => {
                let projected = p.projected_hours();
                match projected {
                    Some(t) => {
                        let log = out.join("logs").join(format!("train-{}.log", r.key));
                        left +=
                            (t - p.hours).max(0.0) * core_share(&log, plan.parallel_runs, cores);
                    }
                    None => left_training += (r.planned_hours - p.hours).max(0.0),
                }
                let mut s = format!(
                    "epoch {} of {} under way, step {}",
                    (p.epochs_done + 1).min(p.epochs),
                    p.epochs,
                    p.steps
                );
                if let Some(spe) = p.steps_per_epoch {
                    write!(s, " of {}", spe * p.epochs as u64).unwrap();
                }
                write!(s, ", {:.2} h of training", p.hours).unwrap();
                if p.last_val_cm.is_some() {
                    write!(
                        s,
                        ", validation Edist {} cm (best {})",
                        fmt(p.last_val_cm, 2),
                        fmt(p.best_val_cm, 2)
                    )
                    .unwrap();
                }
                if let Some(t) = projected {
                    write!(s, "; {t:.2} h in all at this pace").unwrap();
                }
                s
            }
            None => {
                left_training += r.planned_hours;
                match &r.init {
                    Some(i) => format!("not started (fine-tunes {i})"),
                    None => "not started".into(),
                }
            }
        };
        writeln!(
            w,
            "| {name} | {:.2} | {} | {state} |",
            r.planned_hours,
            fmt(measured(&name), 2)
        )
        .unwrap();
    }
    let evaluated = done("eval");
    if !evaluated {
        left += plan.eval_planned_hours;
    }
    writeln!(
        w,
        "| eval | {:.2} | {} | {} |",
        plan.eval_planned_hours,
        fmt(measured("eval"), 2),
        if evaluated { "done" } else { "not finished" }
    )
    .unwrap();
    left += left_training / plan.parallel_runs as f64;
    writeln!(
        w,
        "\nabout {left:.1} machine hours left: the plan's hours for stages not begun ({} training run(s) at once), the pace so far for runs under way (each at the share of the cores it trains on).",
        plan.parallel_runs
    )
    .unwrap();
    if ledger.hours() + left > plan.budget_hours {
        writeln!(
            w,
            "that is more than the budget allows ({:.2} h left of {}): the plan stops before the stage that would start over it.",
            (plan.budget_hours - ledger.hours()).max(0.0),
            plan.budget_hours
        )
        .unwrap();
    }
    w
}

#[cfg(test)]
mod tests {
    use super::*;

    const HEADER: &str =
        "epoch,batch,step,seconds,total,vert,pen,norm,bend,rq8,rq16,rq32,mc,umc,edist_cm";

    fn terms(edist: f64) -> String {
        format!("1e-2,1e-3,1e-4,1e-2,1e-3,0,0,0,0,0,{edist}")
    }

    /// A run's steps.csv and log.csv: two epochs of 4 steps done at 900 s each, then 2
    /// steps of the third; the second epoch's last step was redone after an interruption.
    fn two_epochs_and_two_steps(dir: &Path) {
        let mut steps = String::from(HEADER) + "\n";
        let mut step = 0;
        for (epoch, batches) in [(0, 4), (1, 4)] {
            for b in 1..=batches {
                step += 1;
                let s = step as f64 * 225.0;
                steps += &format!("{epoch},{b},{step},{s},{}\n", terms(3.0));
            }
        }
        steps += &format!("1,4,8,1800,{}\n", terms(3.0));
        steps += &format!("2,1,9,2025,{}\n2,2,10,2250,{}\n", terms(3.0), terms(3.0));
        std::fs::write(dir.join("steps.csv"), steps).unwrap();
        let log = format!(
            "epoch,split,samples,{}\n0,train,32,900,{}\n0,val,8,900,{}\n1,train,32,1800,{}\n1,val,8,1800,{}\n",
            &HEADER[17..],
            terms(3.1),
            terms(2.9),
            terms(2.8),
            terms(3.0)
        );
        std::fs::write(dir.join("log.csv"), log).unwrap();
    }

    #[test]
    fn a_run_under_way_is_projected_from_its_pace() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        two_epochs_and_two_steps(dir);
        let p = RunProgress::read(dir, 6).unwrap();
        assert_eq!(p.epochs_done, 2);
        assert_eq!(p.steps, 10);
        assert_eq!(p.steps_per_epoch, Some(4));
        assert!((p.hours - 0.625).abs() < 1e-12);
        assert_eq!(p.last_val_cm, Some(3.0));
        assert_eq!(p.best_val_cm, Some(2.9));
        assert!(!p.finished);
        // 24 steps in all at 225 s each.
        assert!((p.projected_hours().unwrap() - 1.5).abs() < 1e-12);

        // Restored from a plan's record: no steps.csv, a finished state; the log stays.
        std::fs::remove_file(dir.join("steps.csv")).unwrap();
        assert!(
            RunProgress::read(dir, 6).is_none(),
            "an unfinished run needs its steps"
        );
        let state = learn::train::State {
            epoch: 6,
            steps: 24,
            seconds: 5400.0,
            finished: true,
            ..Default::default()
        };
        std::fs::write(dir.join("state.json"), serde_json::to_vec(&state).unwrap()).unwrap();
        let p = RunProgress::read(dir, 6).unwrap();
        assert!(p.finished);
        assert_eq!((p.steps, p.steps_per_epoch), (24, Some(4)));
        assert_eq!(p.projected_hours(), Some(1.5));
        assert_eq!(p.best_val_cm, Some(2.9));
    }

    #[test]
    fn a_run_in_its_first_epoch_has_no_projection_and_a_missing_one_no_progress() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        assert!(RunProgress::read(dir, 3).is_none());
        std::fs::write(
            dir.join("steps.csv"),
            format!("{HEADER}\n0,1,1,10.5,{}\n", terms(4.0)),
        )
        .unwrap();
        let p = RunProgress::read(dir, 3).unwrap();
        assert_eq!((p.steps, p.steps_per_epoch, p.epochs_done), (1, None, 0));
        assert_eq!(p.projected_hours(), None);
        assert_eq!(p.last_val_cm, None);
    }

    #[test]
    fn a_dataset_under_way_shows_its_drapes_and_the_hours_left_at_its_pace() {
        let plan: Plan = toml::from_str(
            r#"name = "t"
budget_hours = 1.0
eval_planned_hours = 0.1
runs = []
[[datasets]]
key = "tshirt"
config = "tiny"
planned_hours = 0.5
[[datasets]]
key = "sweater"
config = "tiny"
planned_hours = 0.25
[speedup]
runs = []
samples = 1
"#,
        )
        .unwrap();
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path();
        let c = dataset::config::DatasetConfig::load("tiny").unwrap();
        let shards = dataset::plan::shards(&c);
        // Two of tiny's 8 drapes made in 0.1 h.
        let partial = out.join("data/tshirt/partial");
        std::fs::create_dir_all(&partial).unwrap();
        for id in &shards[0].samples[..2] {
            std::fs::write(partial.join(format!("{id:08}.safetensors")), b"").unwrap();
        }
        let mut ledger = Ledger::default();
        ledger.seconds.insert("gen tshirt".into(), 360.0);
        let text = status(&plan, Path::new("t.toml"), out, &ledger, 2);
        assert!(
            text.contains(
                "| gen tshirt | 0.50 | 0.10 | under way: 2 of 8 drapes, about 0.30 h left at this pace (resumes) |"
            ),
            "{text}"
        );
        assert!(
            text.contains("| gen sweater | 0.25 | – | not started |"),
            "{text}"
        );
        // Left: 0.3 h at the pace, the sweater's 0.25 planned, the evaluation's 0.1.
        assert!(text.contains("\nabout 0.7 machine hours left"), "{text}");
        // Under way with nothing made yet: the planned hours count.
        std::fs::remove_dir_all(&partial).unwrap();
        let text = status(&plan, Path::new("t.toml"), out, &ledger, 2);
        assert!(
            text.contains("| under way: 0 of 8 drapes (resumes) |"),
            "{text}"
        );
        assert!(text.contains("\nabout 0.8 machine hours left"), "{text}");
        // A machine lost after 0.1 h of it took its drapes along; two drapes made since in
        // 0.05 h: the pace is this folder's (0.15 h left), the budget counts all 0.15 h.
        std::fs::create_dir_all(&partial).unwrap();
        for id in &shards[0].samples[..2] {
            std::fs::write(partial.join(format!("{id:08}.safetensors")), b"").unwrap();
        }
        ledger.seconds.insert("gen tshirt".into(), 540.0);
        ledger.lost.insert("gen tshirt".into(), 360.0);
        let text = status(&plan, Path::new("t.toml"), out, &ledger, 2);
        assert!(
            text.contains(
                "| gen tshirt | 0.50 | 0.15 | under way: 2 of 8 drapes, about 0.15 h left at this pace (resumes) |"
            ),
            "{text}"
        );
        // Drapes made but no hours since the loss yet: the planned hours count.
        ledger.seconds.insert("gen tshirt".into(), 360.0);
        let text = status(&plan, Path::new("t.toml"), out, &ledger, 2);
        assert!(
            text.contains("| gen tshirt | 0.50 | 0.10 | under way: 2 of 8 drapes (resumes) |"),
            "{text}"
        );
    }

    #[test]
    fn a_run_under_way_counts_its_hours_at_the_share_of_the_cores_it_trains_on() {
        let plan: Plan = toml::from_str(
            r#"name = "t"
budget_hours = 10.0
eval_planned_hours = 0.1
parallel_runs = 2
datasets = []
[[runs]]
key = "a"
config = "tiny.toml"
data = "tshirt"
planned_hours = 1.0
epochs = 6
[[runs]]
key = "b"
config = "tiny.toml"
data = "tshirt"
planned_hours = 1.0
epochs = 6
[[runs]]
key = "c"
config = "tiny.toml"
data = "tshirt"
planned_hours = 0.8
epochs = 6
[speedup]
runs = []
samples = 1
"#,
        )
        .unwrap();
        let tmp = tempfile::tempdir().unwrap();
        let out = tmp.path();
        let a = out.join("runs/a");
        std::fs::create_dir_all(&a).unwrap();
        two_epochs_and_two_steps(&a);
        let ledger = Ledger::default();
        let logs = out.join("logs");
        std::fs::create_dir_all(&logs).unwrap();
        let header = |key: &str, threads: &str| {
            format!(
                "\n== drape train c.toml --data d -o runs/{key} ({threads} threads, started by drape reproduce)\nepoch 1\n"
            )
        };
        // a: 1.5 h in all at its pace, 0.625 h done, 0.875 h left; b and c not begun:
        // (1.0 + 0.8) / 2 h; the evaluation's 0.1 h. With no log, a is taken to train in
        // one of the 2 slots, its hours shared with the other slot's.
        let text = status(&plan, Path::new("t.toml"), out, &ledger, 2);
        assert!(text.contains("; 1.50 h in all at this pace |"), "{text}");
        assert!(text.contains("\nabout 1.4 machine hours left"), "{text}");
        // a started on 1 thread, then resumed alone on both cores: its 0.875 h count in full.
        let a_log = logs.join("train-a.log");
        std::fs::write(&a_log, header("a", "1") + &header("a", "2")).unwrap();
        let text = status(&plan, Path::new("t.toml"), out, &ledger, 2);
        assert!(text.contains("\nabout 1.9 machine hours left"), "{text}");
        // On a machine of 4 cores those 2 threads are one of the 2 slots.
        let text = status(&plan, Path::new("t.toml"), out, &ledger, 4);
        assert!(text.contains("\nabout 1.4 machine hours left"), "{text}");
        // b under way beside a at the same pace, one thread each: 1.75 h shared by the two.
        std::fs::write(&a_log, header("a", "2") + &header("a", "1")).unwrap();
        let b = out.join("runs/b");
        std::fs::create_dir_all(&b).unwrap();
        two_epochs_and_two_steps(&b);
        std::fs::write(logs.join("train-b.log"), header("b", "1")).unwrap();
        let text = status(&plan, Path::new("t.toml"), out, &ledger, 2);
        assert!(text.contains("\nabout 1.4 machine hours left"), "{text}");
        // A child given no thread count has every core ("all"); a log without a header,
        // or one with bytes that are not UTF-8 before it, is read as far as it can be.
        std::fs::write(&a_log, header("a", "all")).unwrap();
        assert_eq!(core_share(&a_log, 2, 2), 1.0);
        std::fs::write(&a_log, "no header\n").unwrap();
        assert_eq!(core_share(&a_log, 4, 2), 0.25);
        let mut bytes = b"progress \xff\xfe\n".to_vec();
        bytes.extend(header("a", "3").into_bytes());
        std::fs::write(&a_log, bytes).unwrap();
        assert_eq!(core_share(&a_log, 3, 3), 1.0);
        assert_eq!(core_share(&a_log, 3, 4), 1.0 / 3.0);
    }
}
