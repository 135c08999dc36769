//! The plan's record: the small outputs of its finished stages, kept in the repository
//! (the plan's `record` folder) so that a fresh checkout on a fresh machine resumes the
//! plan where an earlier session stopped, although the working folder (datasets,
//! checkpoints) did not survive.
//!
//! What is recorded, after every stage:
//! - `stages.json`: the ledger of measured hours;
//! - `data/KEY.json`: a dataset's summary ([`DataSummary`]: sample counts, build, the
//!   manifest's sha256), never its shards;
//! - `runs/KEY/`: a finished run's `config.toml`, `run.json`, `state.json`, `log.csv`, and
//!   its `best.bpk` only while a stage not yet recorded still needs it (a fine-tune starts
//!   from it, or the speed-up times it);
//! - `eval/KEY/metrics.json` and `speedup/KEY.json`.
//!
//! [`restore`] copies what the working folder lacks back into it, so the stages skip
//! what is recorded; a dataset is generated again only if a stage still to run needs it.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{Ledger, Plan};
use crate::evaluate::EvalError;

/// Files of a finished run kept in the record (besides `best.bpk`).
const RUN_FILES: [&str; 4] = ["config.toml", "run.json", "state.json", "log.csv"];

/// What the report says about a dataset, kept when its shards are not.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct DataSummary {
    /// Dataset config it was generated from.
    pub config: String,
    /// sha256 of its manifest.
    pub manifest_sha256: String,
    /// sha256 of the resolved config.
    pub config_sha256: String,
    /// sha256 of the program that draped it, if recorded.
    pub program_sha256: Option<String>,
    /// drape's version.
    pub program_version: String,
    /// Git revision of the program.
    pub git_revision: String,
    /// Converged samples: train, val, test.
    pub converged: [usize; 3],
    /// Failed drapes.
    pub failed: usize,
    /// The simulator's stepping, as the report prints it.
    pub stepping: String,
}

impl DataSummary {
    /// The summary of the dataset whose manifest is at `path` (None if there is none).
    pub fn read(config: &str, path: &Path) -> Result<Option<Self>, EvalError> {
        let Ok(bytes) = std::fs::read(path) else {
            return Ok(None);
        };
        let m = dataset::manifest::Manifest::parse(path, &bytes)?;
        let t = m.tally_by_split();
        use dataset::config::Split;
        let ok = |s: Split| t.get(&s).map_or(0, |x| x.samples - x.failed);
        Ok(Some(Self {
            config: config.to_string(),
            manifest_sha256: sha256(&bytes),
            config_sha256: m.config_sha256.clone(),
            program_sha256: m.program_sha256.clone(),
            program_version: m.program_version.clone(),
            git_revision: m.git_revision.clone(),
            converged: [ok(Split::Train), ok(Split::Val), ok(Split::Test)],
            failed: t.values().map(|x| x.failed).sum(),
            stepping: m.dataset_config().map_or("–".into(), |c| c.sim.stepping()),
        }))
    }

    /// Dataset `key`'s summary: from its manifest in the working folder `out`, else
    /// from the record.
    pub fn find(plan: &Plan, out: &Path, key: &str) -> Option<Self> {
        let config = plan
            .datasets
            .iter()
            .find(|d| d.key == key)
            .map_or("", |d| d.config.as_str());
        let live = out.join("data").join(key).join("manifest.json");
        if let Ok(Some(s)) = Self::read(config, &live) {
            return Some(s);
        }
        let rec = plan
            .record
            .as_ref()?
            .join("data")
            .join(format!("{key}.json"));
        serde_json::from_slice(&std::fs::read(rec).ok()?).ok()
    }
}

fn sha256(bytes: &[u8]) -> String {
    use sha2::{Digest, Sha256};
    dataset::config::hex(&Sha256::digest(bytes))
}

fn io(path: &Path) -> impl Fn(std::io::Error) -> EvalError + '_ {
    move |e| EvalError::Io {
        path: path.to_path_buf(),
        source: e,
    }
}

/// Copies `from` to `to` (creating its folder) unless `to` already has the same bytes.
/// Returns whether it wrote.
fn copy(from: &Path, to: &Path) -> Result<bool, EvalError> {
    let bytes = std::fs::read(from).map_err(io(from))?;
    if std::fs::read(to).is_ok_and(|b| b == bytes) {
        return Ok(false);
    }
    if let Some(p) = to.parent() {
        std::fs::create_dir_all(p).map_err(io(p))?;
    }
    dataset::generate::write_atomic(to, &bytes)?;
    Ok(true)
}

fn finished(run: &Path) -> bool {
    learn::train::State::load(run).is_ok_and(|s| s.is_some_and(|s| s.finished))
}

/// Whether run `key`'s weights are still needed by a stage that the working folder `out`
/// has not finished: a fine-tune from it not yet trained, its own evaluation or speed-up
/// not yet made.
fn weights_needed(plan: &Plan, out: &Path, key: &str) -> bool {
    let evaluated = |k: &str| out.join("eval").join(k).join("metrics.json").exists();
    !evaluated(key)
        || plan
            .runs
            .iter()
            .any(|r| r.init.as_deref() == Some(key) && !finished(&out.join("runs").join(&r.key)))
        || (plan.speedup.runs.iter().any(|k| k == key)
            && !out.join("speedup").join(format!("{key}.json")).exists())
}

/// Brings the record up to date with the working folder `out`. Returns the files written
/// or removed.
pub fn save(plan: &Plan, out: &Path, ledger: &Ledger) -> Result<Vec<PathBuf>, EvalError> {
    let Some(rec) = &plan.record else {
        return Ok(Vec::new());
    };
    let mut changed = Vec::new();
    std::fs::create_dir_all(rec).map_err(io(rec))?;
    let lp = rec.join("stages.json");
    let before = std::fs::read(&lp).ok();
    ledger.save(&lp)?;
    if std::fs::read(&lp).ok() != before {
        changed.push(lp);
    }
    for d in &plan.datasets {
        let mp = out.join("data").join(&d.key).join("manifest.json");
        if let Some(s) = DataSummary::read(&d.config, &mp)? {
            let p = rec.join("data").join(format!("{}.json", d.key));
            let bytes = serde_json::to_vec_pretty(&s).expect("summary serialises");
            if std::fs::read(&p).ok().as_deref() != Some(&bytes[..]) {
                std::fs::create_dir_all(rec.join("data")).map_err(io(rec))?;
                dataset::generate::write_atomic(&p, &bytes)?;
                changed.push(p);
            }
        }
    }
    for r in &plan.runs {
        let run = out.join("runs").join(&r.key);
        let to = rec.join("runs").join(&r.key);
        if finished(&run) {
            for f in RUN_FILES {
                if copy(&run.join(f), &to.join(f))? {
                    changed.push(to.join(f));
                }
            }
            let best = to.join("best.bpk");
            if weights_needed(plan, out, &r.key) {
                if copy(&run.join("best.bpk"), &best)? {
                    changed.push(best);
                }
            } else if best.exists() {
                std::fs::remove_file(&best).map_err(io(&best))?;
                changed.push(best);
            }
        }
        let m = out.join("eval").join(&r.key).join("metrics.json");
        if m.exists() && copy(&m, &rec.join("eval").join(&r.key).join("metrics.json"))? {
            changed.push(rec.join("eval").join(&r.key).join("metrics.json"));
        }
        let s = out.join("speedup").join(format!("{}.json", r.key));
        let st = rec.join("speedup").join(format!("{}.json", r.key));
        if s.exists() && copy(&s, &st)? {
            changed.push(st);
        }
    }
    Ok(changed)
}

/// Copies into the working folder `out` what the record holds and `out` lacks: finished
/// runs, evaluations, speed-ups, and the ledger if `out` has none. Returns what it
/// restored, one line each.
pub fn restore(plan: &Plan, out: &Path) -> Result<Vec<String>, EvalError> {
    let Some(rec) = &plan.record else {
        return Ok(Vec::new());
    };
    let mut done = Vec::new();
    let lp = out.join("stages.json");
    if !lp.exists() && rec.join("stages.json").exists() {
        copy(&rec.join("stages.json"), &lp)?;
        done.push("the ledger of measured hours".to_string());
    }
    for r in &plan.runs {
        let from = rec.join("runs").join(&r.key);
        let run = out.join("runs").join(&r.key);
        if finished(&from) && !finished(&run) {
            // A half-trained run of this folder is replaced by the recorded finished one.
            for f in RUN_FILES {
                copy(&from.join(f), &run.join(f))?;
            }
            if from.join("best.bpk").exists() {
                copy(&from.join("best.bpk"), &run.join("best.bpk"))?;
            }
            done.push(format!("run {} (finished)", r.key));
        }
        let m = rec.join("eval").join(&r.key).join("metrics.json");
        let mo = out.join("eval").join(&r.key).join("metrics.json");
        if m.exists() && !mo.exists() {
            copy(&m, &mo)?;
            done.push(format!("evaluation of {}", r.key));
        }
        let s = rec.join("speedup").join(format!("{}.json", r.key));
        let so = out.join("speedup").join(format!("{}.json", r.key));
        if s.exists() && !so.exists() {
            copy(&s, &so)?;
            done.push(format!("speed-up of {}", r.key));
        }
    }
    Ok(done)
}

/// Whether a stage still to run needs dataset `key` on disk: a run on it not finished or
/// not evaluated, or a speed-up on it not made.
pub fn data_needed(plan: &Plan, out: &Path, key: &str) -> bool {
    plan.runs.iter().filter(|r| r.data == key).any(|r| {
        !finished(&out.join("runs").join(&r.key))
            || !out.join("eval").join(&r.key).join("metrics.json").exists()
            || (plan.speedup.runs.contains(&r.key)
                && !out.join("speedup").join(format!("{}.json", r.key)).exists())
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plan(record: &Path) -> Plan {
        let text = format!(
            r#"
name = "t"
budget_hours = 1.0
eval_planned_hours = 0.1
record = "{}"
[[datasets]]
key = "shirt"
config = "tiny"
planned_hours = 0.1
[[runs]]
key = "base"
config = "configs/train/tshirt-local.toml"
data = "shirt"
planned_hours = 0.1
[[runs]]
key = "tune"
config = "configs/train/tshirt-local.toml"
data = "shirt"
init = "base"
planned_hours = 0.1
[speedup]
runs = ["base"]
samples = 2
"#,
            record.display()
        );
        let p: Plan = toml::from_str(&text).unwrap();
        p.validate().unwrap();
        p
    }

    /// A finished run as `drape train` leaves it (the files' contents are placeholders,
    /// except the state, which says finished).
    fn finish(out: &Path, key: &str) {
        let d = out.join("runs").join(key);
        std::fs::create_dir_all(&d).unwrap();
        for f in ["config.toml", "run.json", "log.csv", "last.bpk"] {
            std::fs::write(d.join(f), format!("{key} {f}")).unwrap();
        }
        std::fs::write(d.join("best.bpk"), format!("{key} weights")).unwrap();
        let state = learn::train::State {
            epoch: 3,
            finished: true,
            ..Default::default()
        };
        std::fs::write(d.join("state.json"), serde_json::to_vec(&state).unwrap()).unwrap();
    }

    fn evaluate(out: &Path, key: &str) {
        let d = out.join("eval").join(key);
        std::fs::create_dir_all(&d).unwrap();
        std::fs::write(d.join("metrics.json"), format!("{{\"run\": \"{key}\"}}")).unwrap();
    }

    #[test]
    fn the_record_keeps_finished_stages_and_weights_only_while_needed_and_a_fresh_folder_resumes_from_it()
     {
        let root = tempfile::tempdir().unwrap();
        let (out, rec) = (root.path().join("out"), root.path().join("record"));
        let p = plan(&rec);
        let mut ledger = Ledger::default();
        ledger.machine_seconds = 3600.0;
        ledger.seconds.insert("train base".into(), 3600.0);
        ledger.done.insert("train base".into(), true);

        // Nothing finished: only the ledger is recorded; the data are needed.
        std::fs::create_dir_all(out.join("runs").join("base")).unwrap();
        save(&p, &out, &ledger).unwrap();
        assert!(rec.join("stages.json").exists());
        assert!(!rec.join("runs").exists());
        assert!(data_needed(&p, &out, "shirt"));

        // The base run finished: its small files and its weights (its evaluation, the
        // fine-tune and the speed-up need them), never its checkpoint.
        finish(&out, "base");
        save(&p, &out, &ledger).unwrap();
        let rb = rec.join("runs").join("base");
        for f in RUN_FILES {
            assert_eq!(
                std::fs::read(rb.join(f)).unwrap(),
                std::fs::read(out.join("runs/base").join(f)).unwrap()
            );
        }
        assert!(rb.join("best.bpk").exists() && !rb.join("last.bpk").exists());

        // Evaluated: the weights stay while the fine-tune and the speed-up wait for them.
        evaluate(&out, "base");
        save(&p, &out, &ledger).unwrap();
        assert!(rec.join("eval/base/metrics.json").exists());
        assert!(rb.join("best.bpk").exists());

        // A fresh machine resumes from the record: the base run is finished there and
        // can start the fine-tune; the data are needed again (the fine-tune trains on them).
        let fresh = root.path().join("fresh");
        let restored = restore(&p, &fresh).unwrap();
        assert_eq!(restored.len(), 3, "{restored:?}");
        assert!(finished(&fresh.join("runs/base")));
        assert_eq!(
            std::fs::read(fresh.join("runs/base/best.bpk")).unwrap(),
            b"base weights"
        );
        assert_eq!(Ledger::load(&fresh.join("stages.json")).unwrap(), ledger);
        assert!(data_needed(&p, &fresh, "shirt"));
        // Restoring again changes nothing.
        assert!(restore(&p, &fresh).unwrap().is_empty());

        // All done: no stage needs the base weights, and the record drops them; the
        // fine-tune's were never needed after its evaluation.
        finish(&out, "tune");
        evaluate(&out, "tune");
        std::fs::create_dir_all(out.join("speedup")).unwrap();
        std::fs::write(out.join("speedup/base.json"), "{}").unwrap();
        let changed = save(&p, &out, &ledger).unwrap();
        assert!(changed.contains(&rb.join("best.bpk")));
        assert!(!rb.join("best.bpk").exists());
        assert!(!rec.join("runs/tune/best.bpk").exists());
        assert!(rec.join("runs/tune/state.json").exists());
        assert!(rec.join("speedup/base.json").exists());
        // Saving again writes nothing.
        assert!(save(&p, &out, &ledger).unwrap().is_empty());

        // Another fresh machine has nothing left to do that needs the data.
        let last = root.path().join("last");
        restore(&p, &last).unwrap();
        assert!(!data_needed(&p, &last, "shirt"));
        assert!(last.join("speedup/base.json").exists());
    }
}
