//! The plan's record: the small outputs of its finished stages, kept in the repository
//! (the plan's `record` folder) so that a fresh checkout on a fresh machine resumes the
//! plan where an earlier session stopped, although the working folder (datasets,
//! checkpoints) did not survive.
//!
//! What is recorded, after every stage:
//! - `stages.json`: the ledger of measured hours;
//! - `data/KEY.json`: a dataset's summary ([`DataSummary`]: sample counts, build, the
//!   manifest's sha256 and, since session 72, the drapes sha256), never its shards;
//! - `runs/KEY/`: a finished run's `config.toml`, `run.json`, `state.json`, `log.csv`, and
//!   its `best.bpk` only while a stage not yet recorded still needs it (its evaluation, a
//!   fine-tune that starts from it, or the speed-up that times it);
//! - `eval/KEY/metrics.json` with each sample's network Edist only, and `speedup/KEY.json`.
//!
//! [`restore`] copies what the working folder lacks back into it, so the stages skip
//! what is recorded; a dataset is generated again only if a stage still to run needs it.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use super::{Ledger, Plan};
use crate::evaluate::EvalError;

/// Files of a finished run kept in the record (besides `best.bpk`); the state, which
/// says it is finished, is written last.
const RUN_FILES: [&str; 4] = ["config.toml", "run.json", "log.csv", "state.json"];

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
    /// The manifests' sha256 of earlier generations of the same drapes
    /// ([`Self::same_drapes_as`]: the same drapes sha256, or, where a summary has none,
    /// the same config made again by the same program, as one binary drapes the same
    /// bytes: docs/datasets.md) after a working folder was lost. Their manifests differ only in the timings they
    /// record, so evaluations on them pair with evaluations on this one.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub same_drapes: Vec<String>,
    /// The drapes' identity (`Manifest::drapes_sha256`: config, bodies and shard bytes,
    /// not the timings), absent in summaries written before session 72. Data made again
    /// by any build with this identity holds the same drapes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub drapes_sha256: Option<String>,
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
            same_drapes: Vec::new(),
            drapes_sha256: Some(m.drapes_sha256()),
        }))
    }

    /// This summary of a dataset made again, given the one recorded before (`earlier`):
    /// if it holds the same drapes ([`Self::same_drapes_as`]), the earlier manifests are
    /// kept in `same_drapes` (the same summary saved again keeps them too).
    pub fn after(mut self, earlier: Option<Self>) -> Self {
        if let Some(e) = earlier
            && self.same_drapes_as(&e)
        {
            for m in e.same_drapes.into_iter().chain([e.manifest_sha256]) {
                if m != self.manifest_sha256 && !self.same_drapes.contains(&m) {
                    self.same_drapes.push(m);
                }
            }
        }
        self
    }

    /// Whether this summary names `drapes` (a drapes sha256, if any) as its drapes.
    pub fn names_drapes(&self, drapes: Option<&str>) -> bool {
        drapes.is_some() && self.drapes_sha256.as_deref() == drapes
    }

    /// Whether this dataset holds the same drapes as `other`: where both record the
    /// drapes' identity, whether it is the same (whichever builds made them); otherwise,
    /// whether they were made from the same config by the same program, recorded in both
    /// (one binary drapes the same bytes).
    pub fn same_drapes_as(&self, other: &Self) -> bool {
        if let (Some(a), Some(b)) = (&self.drapes_sha256, &other.drapes_sha256) {
            return a == b;
        }
        self.config_sha256 == other.config_sha256
            && self.program_sha256.is_some()
            && self.program_sha256 == other.program_sha256
    }

    /// Every dataset summary of the record folder `record` (its `data/*.json`).
    pub fn all_recorded(record: &Path) -> Result<Vec<Self>, EvalError> {
        let data = record.join("data");
        let mut out = Vec::new();
        for entry in std::fs::read_dir(&data).map_err(io(&data))? {
            let path = entry.map_err(io(&data))?.path();
            if path.extension().is_some_and(|x| x == "json") {
                let bytes = std::fs::read(&path).map_err(io(&path))?;
                out.push(serde_json::from_slice(&bytes).map_err(|e| {
                    EvalError::Invalid(format!(
                        "{}: not a dataset summary of a reproduction record: {e}",
                        path.display()
                    ))
                })?);
            }
        }
        Ok(out)
    }

    /// The summary recorded for dataset `key` in the plan's record, if any.
    pub fn recorded(plan: &Plan, key: &str) -> Option<Self> {
        let rec = plan
            .record
            .as_ref()?
            .join("data")
            .join(format!("{key}.json"));
        serde_json::from_slice(&std::fs::read(rec).ok()?).ok()
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
            return Some(s.after(Self::recorded(plan, key)));
        }
        Self::recorded(plan, key)
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

/// What [`save`] did.
#[derive(Debug, Default)]
pub struct Saved {
    /// Files written or removed.
    pub changed: Vec<PathBuf>,
    /// What it could not record (each item is tried on its own).
    pub warnings: Vec<String>,
}

/// Brings the record up to date with the working folder `out`: everything is copied
/// first, and only then are weights no stage needs any more removed, so an interrupted
/// save never leaves a run without the weights a stage not yet recorded needs.
pub fn save(plan: &Plan, out: &Path, ledger: &Ledger) -> Saved {
    let mut saved = Saved::default();
    let Some(rec) = &plan.record else {
        return saved;
    };
    let ledger_bytes = serde_json::to_vec_pretty(ledger).expect("ledger serialises");
    saved.note(put_bytes(&ledger_bytes, rec.join("stages.json")));
    for d in &plan.datasets {
        let mp = out.join("data").join(&d.key).join("manifest.json");
        match DataSummary::read(&d.config, &mp) {
            Ok(Some(s)) => {
                let s = s.after(DataSummary::recorded(plan, &d.key));
                let bytes = serde_json::to_vec_pretty(&s).expect("summary serialises");
                saved.note(put_bytes(
                    &bytes,
                    rec.join("data").join(format!("{}.json", d.key)),
                ));
            }
            Ok(None) => {}
            Err(e) => saved.warnings.push(format!("dataset {}: {e}", d.key)),
        }
    }
    let mut drop = Vec::new();
    for r in &plan.runs {
        let run = out.join("runs").join(&r.key);
        let to = rec.join("runs").join(&r.key);
        if finished(&run) {
            let best = to.join("best.bpk");
            if weights_needed(plan, out, &r.key) {
                if run.join("best.bpk").exists() {
                    saved.put(&run.join("best.bpk"), best);
                } else if !best.exists() {
                    saved.warnings.push(format!(
                        "run {} is finished but has no best.bpk, which a stage still to run needs",
                        r.key
                    ));
                }
            } else {
                drop.push(best);
            }
            // In RUN_FILES' order: the state last, so a recorded finished state always has
            // its files beside it.
            for f in RUN_FILES {
                saved.put(&run.join(f), to.join(f));
            }
        }
        let m = out.join("eval").join(&r.key).join("metrics.json");
        if m.exists() {
            let to = rec.join("eval").join(&r.key).join("metrics.json");
            saved.note(summary_metrics(&m).and_then(|b| put_bytes(&b, to)));
        }
        let s = out.join("speedup").join(format!("{}.json", r.key));
        if s.exists() {
            saved.put(&s, rec.join("speedup").join(format!("{}.json", r.key)));
        }
    }
    if saved.warnings.is_empty() {
        for best in drop.into_iter().filter(|b| b.exists()) {
            match std::fs::remove_file(&best) {
                Ok(()) => saved.changed.push(best),
                Err(e) => saved.warnings.push(format!("{}: {e}", best.display())),
            }
        }
    }
    saved
}

impl Saved {
    /// Notes one item's outcome.
    fn note(&mut self, r: Result<Option<PathBuf>, EvalError>) {
        match r {
            Ok(Some(p)) => self.changed.push(p),
            Ok(None) => {}
            Err(e) => self.warnings.push(e.to_string()),
        }
    }

    /// Copies `from` to `to` and notes it.
    fn put(&mut self, from: &Path, to: PathBuf) {
        let r = copy(from, &to).map(|w| w.then_some(to));
        self.note(r);
    }
}

/// An evaluation's `metrics.json` with its per-sample rows cut to what the report reads:
/// each sample's id, the network's Edist (to 1e-4 cm) for the paired differences between
/// runs, and its L_MC and L_RQ terms (to 5 significant digits) for the per-drape curvature
/// ratios under Table 7. The full rows (0.6 MB for 396 T-shirt test samples) stay in the
/// working folder and its `samples.csv`.
fn summary_metrics(path: &Path) -> Result<Vec<u8>, EvalError> {
    let bytes = std::fs::read(path).map_err(io(path))?;
    let mut v: serde_json::Value = serde_json::from_slice(&bytes)
        .map_err(|e| EvalError::Invalid(format!("{}: {e}", path.display())))?;
    let significant = |x: f64| -> f64 { format!("{x:.4e}").parse().unwrap_or(x) };
    if let Some(rows) = v.get_mut("samples").and_then(|s| s.as_array_mut()) {
        for row in rows.iter_mut() {
            let net = &row["methods"]["network"];
            let mut kept = serde_json::Map::new();
            kept.insert(
                "edist_cm".into(),
                net["edist_cm"]
                    .as_f64()
                    .map(|e| (e * 1e4).round() / 1e4)
                    .into(),
            );
            if let Some(mc) = net["l_mc"].as_f64() {
                kept.insert("l_mc".into(), significant(mc).into());
            }
            if let Some(rq) = net["l_rq"].as_array() {
                let rq: Option<Vec<f64>> = rq.iter().map(|x| x.as_f64().map(significant)).collect();
                if let Some(rq) = rq {
                    kept.insert("l_rq".into(), rq.into());
                }
            }
            *row = serde_json::json!({
                "id": row["id"],
                "methods": {"network": kept},
            });
        }
    }
    Ok(serde_json::to_vec_pretty(&v).expect("JSON serialises"))
}

/// Writes `bytes` to `to` (creating its folder) unless it holds them already; returns
/// `to` if it wrote.
fn put_bytes(bytes: &[u8], to: PathBuf) -> Result<Option<PathBuf>, EvalError> {
    if std::fs::read(&to).is_ok_and(|b| b == bytes) {
        return Ok(None);
    }
    if let Some(p) = to.parent() {
        std::fs::create_dir_all(p).map_err(io(p))?;
    }
    dataset::generate::write_atomic(&to, bytes)?;
    Ok(Some(to))
}

/// Copies into the working folder `out` what the record holds and `out` lacks: finished
/// runs, evaluations, speed-ups, and the ledger if `out` has none or one with fewer
/// machine hours (another machine went on from the record). Returns what it restored,
/// one line each.
pub fn restore(plan: &Plan, out: &Path) -> Result<Vec<String>, EvalError> {
    let Some(rec) = &plan.record else {
        return Ok(Vec::new());
    };
    let mut done = Vec::new();
    let (lp, rl) = (out.join("stages.json"), rec.join("stages.json"));
    if rl.exists() {
        let ahead =
            !lp.exists() || Ledger::load(&rl)?.machine_seconds > Ledger::load(&lp)?.machine_seconds;
        if ahead {
            // The drapes of unfinished datasets that this folder lacks were lost with the
            // machine that made them: their hours stay in the budget, not in the pace.
            let mut ledger = Ledger::load(&rl)?;
            for d in &plan.datasets {
                let name = format!("gen {}", d.key);
                let s = ledger.seconds.get(&name).copied().unwrap_or(0.0);
                if ledger.done.get(&name) != Some(&true)
                    && s > 0.0
                    && !out.join("data").join(&d.key).exists()
                {
                    ledger.lost.insert(name, s);
                }
            }
            if let Some(p) = lp.parent() {
                std::fs::create_dir_all(p).map_err(io(p))?;
            }
            ledger.save(&lp)?;
            done.push("the ledger of measured hours".to_string());
        }
    }
    for r in &plan.runs {
        let from = rec.join("runs").join(&r.key);
        let run = out.join("runs").join(&r.key);
        if finished(&from) && !finished(&run) {
            // A half-trained run of this folder is replaced by the recorded finished one:
            // its checkpoint and steps go; the weights come first, the state last, so an
            // interrupted restore never leaves a finished state without them.
            for f in ["last.bpk", "last-optim.bpk", "steps.csv", "best.bpk"] {
                if run.join(f).exists() {
                    std::fs::remove_file(run.join(f)).map_err(io(&run))?;
                }
            }
            if from.join("best.bpk").exists() {
                copy(&from.join("best.bpk"), &run.join("best.bpk"))?;
            }
            for f in RUN_FILES.iter().filter(|f| **f != "state.json") {
                copy(&from.join(f), &run.join(f))?;
            }
            copy(&from.join("state.json"), &run.join("state.json"))?;
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
/// not evaluated, or a speed-up on it not made. (A dataset no run uses is never needed.)
pub fn data_needed(plan: &Plan, out: &Path, key: &str) -> bool {
    plan.runs.iter().filter(|r| r.data == key).any(|r| {
        !finished(&out.join("runs").join(&r.key))
            || !out.join("eval").join(&r.key).join("metrics.json").exists()
            || (plan.speedup.runs.contains(&r.key)
                && !out.join("speedup").join(format!("{}.json", r.key)).exists())
    })
}

/// Why this build should not make dataset `key` again, if it should not: the working
/// folder `out` lacks it, the record names the build that made it (`program_sha256`),
/// this build (`program`) is another, and an evaluation restored into `out` was made on
/// the recorded drapes (its manifest's sha256). Two builds drape differently by up to
/// 15 mm (docs/datasets.md), so runs on the new drapes would not pair with the recorded
/// ones. The message says how to make the same drapes again: a release build of the
/// recorded revision at the same path with the same toolchain is the same binary.
pub fn remake_differs(plan: &Plan, out: &Path, key: &str, program: Option<&str>) -> Option<String> {
    let dir = out.join("data").join(key);
    if dir.join("manifest.json").exists() {
        return None;
    }
    let rec = plan
        .record
        .as_ref()?
        .join("data")
        .join(format!("{key}.json"));
    let s = DataSummary::recorded(plan, key)?;
    let made_by = s.program_sha256.as_deref()?;
    if program == Some(made_by) {
        return None;
    }
    // The recorded drapes, under their present manifest or an earlier one.
    let drapes: Vec<&str> = std::iter::once(s.manifest_sha256.as_str())
        .chain(s.same_drapes.iter().map(String::as_str))
        .collect();
    let on_it: Vec<&str> = plan
        .runs
        .iter()
        .filter(|r| r.data == key)
        .filter(|r| {
            let m = out.join("eval").join(&r.key).join("metrics.json");
            std::fs::read(m)
                .ok()
                .and_then(|b| serde_json::from_slice::<serde_json::Value>(&b).ok())
                .is_some_and(|v| {
                    let p = &v["provenance"];
                    p["manifest_sha256"]
                        .as_str()
                        .is_some_and(|m| drapes.contains(&m))
                        || s.names_drapes(p["drapes_sha256"].as_str())
                })
        })
        .map(|r| r.key.as_str())
        .collect();
    if on_it.is_empty() {
        return None;
    }
    let short = |x: &str| x.chars().take(12).collect::<String>();
    let rate = plan
        .datasets
        .iter()
        .find(|d| d.key == key)
        .and_then(|d| d.max_failure_rate)
        .map_or(String::new(), |r| format!(" --max-failure-rate {r}"));
    let to = std::path::absolute(&dir).unwrap_or(dir);
    // Builds that drape the same bytes make the same drapes; the record says which they
    // are if it names their identity.
    let same = s.drapes_sha256.as_deref().map_or(String::new(), |d| {
        format!(
            " (if it drapes the same bytes, its drapes sha256, which `drape data info` prints, is the recorded {}, and runs on them pair with the recorded ones)",
            short(d)
        )
    });
    Some(format!(
        "dataset {key} is to be made again, but the record's summary of it ({}) says another build of drape draped it (program sha256 {}, git {}; this one {}), and the evaluations of {} were made on those drapes (manifest sha256 {}): two builds drape differently by up to 15 mm, so runs on new drapes would not pair with them. To make the same drapes, check out git {} and build it with `cargo build --release` at the path and with the Rust toolchain that built it (neither is recorded; with both the same, the build is the same binary: check that its sha256 is {}), run its `drape gen {} -o {}{rate}`, then this command again; or pass --mixed-builds to make the dataset with this build{same}",
        rec.display(),
        short(made_by),
        short(&s.git_revision),
        program.map_or("unknown".into(), short),
        on_it.join(", "),
        drapes
            .iter()
            .map(|m| short(m))
            .collect::<Vec<_>>()
            .join(" = "),
        short(&s.git_revision),
        short(made_by),
        s.config,
        to.display()
    ))
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

    /// A dataset summary whose manifest, program and config sha256 repeat one character
    /// each (`program` None: no program recorded).
    fn summary(manifest: &str, program: Option<&str>, config: &str) -> DataSummary {
        DataSummary {
            config: "tiny".into(),
            manifest_sha256: manifest.repeat(64),
            config_sha256: config.repeat(64),
            program_sha256: program.map(|p| p.repeat(64)),
            program_version: "0.1.0".into(),
            git_revision: "0123456789abcdef".into(),
            converged: [8, 0, 0],
            failed: 0,
            stepping: "10 substeps".into(),
            same_drapes: Vec::new(),
            drapes_sha256: None,
        }
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
        std::fs::write(
            d.join("metrics.json"),
            format!(
                "{{\"run\": \"{key}\", \"samples\": [{{\"id\": 7, \"family\": \"dance\", \"methods\": {{\"dqs\": {{\"edist_cm\": 5.0}}, \"network\": {{\"edist_cm\": 2.123456, \"enorm_deg\": 18.0, \"l_mc\": 1234.5678, \"l_rq\": [1.234567e-9, 2.0, 3.0]}}}}}}]}}"
            ),
        )
        .unwrap();
    }

    #[test]
    fn the_record_keeps_finished_stages_and_weights_only_while_needed_and_a_fresh_folder_resumes_from_it()
     {
        let root = tempfile::tempdir().unwrap();
        let (out, rec) = (root.path().join("out"), root.path().join("record"));
        let p = plan(&rec);
        let mut ledger = Ledger {
            machine_seconds: 3600.0,
            ..Default::default()
        };
        ledger.seconds.insert("train base".into(), 3600.0);
        ledger.done.insert("train base".into(), true);

        // Nothing finished: only the ledger is recorded; the data are needed.
        std::fs::create_dir_all(out.join("runs").join("base")).unwrap();
        assert!(save(&p, &out, &ledger).warnings.is_empty());
        assert!(rec.join("stages.json").exists());
        assert!(!rec.join("runs").exists());
        assert!(data_needed(&p, &out, "shirt"));

        // The base run finished: its small files and its weights (its evaluation, the
        // fine-tune and the speed-up need them), never its checkpoint.
        finish(&out, "base");
        assert!(save(&p, &out, &ledger).warnings.is_empty());
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
        assert!(save(&p, &out, &ledger).warnings.is_empty());
        // The evaluation with each sample's id and network Edist, L_MC and L_RQ only.
        let m: serde_json::Value =
            serde_json::from_slice(&std::fs::read(rec.join("eval/base/metrics.json")).unwrap())
                .unwrap();
        assert_eq!(
            m,
            serde_json::json!({"run": "base", "samples": [
                {"id": 7, "methods": {"network": {"edist_cm": 2.1235, "l_mc": 1234.6, "l_rq": [1.2346e-9, 2.0, 3.0]}}}
            ]})
        );
        assert!(rb.join("best.bpk").exists());

        // A fresh machine resumes from the record: the base run is finished there and
        // can start the fine-tune; the data are needed again (the fine-tune trains on them).
        let fresh = root.path().join("fresh");
        // It had begun the base run before it was lost: that half-trained run is replaced.
        let half = fresh.join("runs/base");
        std::fs::create_dir_all(&half).unwrap();
        for f in ["last.bpk", "last-optim.bpk", "steps.csv", "best.bpk"] {
            std::fs::write(half.join(f), "half").unwrap();
        }
        let restored = restore(&p, &fresh).unwrap();
        for f in ["last.bpk", "last-optim.bpk", "steps.csv"] {
            assert!(!half.join(f).exists(), "{f}");
        }
        assert_eq!(restored.len(), 3, "{restored:?}");
        assert!(finished(&fresh.join("runs/base")));
        assert_eq!(
            std::fs::read(fresh.join("runs/base/best.bpk")).unwrap(),
            b"base weights"
        );
        // The ledger comes along; the dataset stage was not finished, so its hours went
        // with the lost drapes (none here: it had not begun).
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
        let saved = save(&p, &out, &ledger);
        assert!(saved.warnings.is_empty(), "{:?}", saved.warnings);
        let changed = saved.changed;
        assert!(changed.contains(&rb.join("best.bpk")));
        assert!(!rb.join("best.bpk").exists());
        assert!(!rec.join("runs/tune/best.bpk").exists());
        assert!(rec.join("runs/tune/state.json").exists());
        assert!(rec.join("speedup/base.json").exists());
        // Saving again writes nothing.
        assert!(save(&p, &out, &ledger).changed.is_empty());

        // Another fresh machine has nothing left to do that needs the data.
        let last = root.path().join("last");
        restore(&p, &last).unwrap();
        assert!(!data_needed(&p, &last, "shirt"));
        assert!(last.join("speedup/base.json").exists());
    }

    #[test]
    fn a_dataset_the_record_pairs_evaluations_with_is_not_made_again_by_another_build() {
        let root = tempfile::tempdir().unwrap();
        let (out, rec) = (root.path().join("out"), root.path().join("record"));
        let p = plan(&rec);
        let (made_by, manifest) = ("a".repeat(64), "b".repeat(64));
        let write_summary = |s: &DataSummary| {
            std::fs::create_dir_all(rec.join("data")).unwrap();
            std::fs::write(rec.join("data/shirt.json"), serde_json::to_vec(s).unwrap()).unwrap();
        };
        let evaluated_on = |sha: &str| {
            let d = out.join("eval/base");
            std::fs::create_dir_all(&d).unwrap();
            let m = serde_json::json!({"provenance": {"manifest_sha256": sha, "split": "test"}});
            std::fs::write(d.join("metrics.json"), m.to_string()).unwrap();
        };
        let other = "d".repeat(64);
        // No record of the data yet: nothing to keep.
        assert_eq!(remake_differs(&p, &out, "shirt", Some(&other)), None);
        write_summary(&summary("b", Some("a"), "c"));
        // Recorded, but nothing was evaluated on it: any build may make it.
        assert_eq!(remake_differs(&p, &out, "shirt", Some(&other)), None);
        // An evaluation on those drapes: another build is refused, with the way to make
        // the same drapes; the build that made them is not.
        evaluated_on(&manifest);
        let e = remake_differs(&p, &out, "shirt", Some(&other)).unwrap();
        for part in [
            "program sha256 aaaaaaaaaaaa, git 0123456789ab; this one dddddddddddd",
            "evaluations of base were made on those drapes (manifest sha256 bbbbbbbbbbbb)",
            "check that its sha256 is aaaaaaaaaaaa",
            "check out git 0123456789ab and build it",
            "`drape gen tiny -o ",
            "--mixed-builds",
        ] {
            assert!(e.contains(part), "{part:?} not in {e}");
        }
        assert!(remake_differs(&p, &out, "shirt", None).is_some());
        assert_eq!(remake_differs(&p, &out, "shirt", Some(&made_by)), None);
        // The drapes made again by the same binary (a new manifest; the record keeps the
        // earlier one): the evaluations on the earlier manifest still count.
        let mut again = summary("b", Some("a"), "c");
        again.manifest_sha256 = "e".repeat(64);
        again.same_drapes = vec![manifest.clone()];
        write_summary(&again);
        let e = remake_differs(&p, &out, "shirt", Some(&other)).unwrap();
        assert!(
            e.contains("(manifest sha256 eeeeeeeeeeee = bbbbbbbbbbbb)"),
            "{e}"
        );
        // A record that names the drapes' sha256: an evaluation that records it counts,
        // under any manifest, and the message says which sha256 the same drapes have.
        let mut named = summary("b", Some("a"), "c");
        named.drapes_sha256 = Some("f".repeat(64));
        write_summary(&named);
        let m = serde_json::json!({"provenance": {"manifest_sha256": "9".repeat(64),
            "split": "test", "drapes_sha256": "f".repeat(64)}});
        std::fs::write(out.join("eval/base/metrics.json"), m.to_string()).unwrap();
        let e = remake_differs(&p, &out, "shirt", Some(&other)).unwrap();
        assert!(e.contains("is the recorded ffffffffffff"), "{e}");
        // ...and one that records other drapes does not.
        let m = serde_json::json!({"provenance": {"manifest_sha256": "9".repeat(64),
            "split": "test", "drapes_sha256": "7".repeat(64)}});
        std::fs::write(out.join("eval/base/metrics.json"), m.to_string()).unwrap();
        assert_eq!(remake_differs(&p, &out, "shirt", Some(&other)), None);
        evaluated_on(&manifest);
        write_summary(&summary("b", Some("a"), "c"));
        // Evaluated on other drapes, or a record that names no build, or the data there
        // already: nothing to keep.
        evaluated_on(&other);
        assert_eq!(remake_differs(&p, &out, "shirt", Some(&other)), None);
        evaluated_on(&manifest);
        write_summary(&summary("b", None, "c"));
        assert_eq!(remake_differs(&p, &out, "shirt", Some(&other)), None);
        write_summary(&summary("b", Some("a"), "c"));
        std::fs::create_dir_all(out.join("data/shirt")).unwrap();
        std::fs::write(out.join("data/shirt/manifest.json"), "{}").unwrap();
        assert_eq!(remake_differs(&p, &out, "shirt", Some(&other)), None);
    }

    #[test]
    fn a_dataset_made_again_by_the_same_program_keeps_the_earlier_manifests() {
        let first = summary("1", Some("p"), "c");
        // The same program and config: the first manifest is kept, and a third
        // generation keeps both earlier ones.
        let second = summary("2", Some("p"), "c").after(Some(first.clone()));
        assert_eq!(second.same_drapes, vec!["1".repeat(64)]);
        let third = summary("3", Some("p"), "c").after(Some(second.clone()));
        assert_eq!(third.same_drapes, vec!["1".repeat(64), "2".repeat(64)]);
        // The same manifest again (its summary saved twice): the earlier ones stay.
        assert_eq!(
            summary("1", Some("p"), "c").after(Some(first.clone())),
            first
        );
        assert_eq!(
            summary("2", Some("p"), "c").after(Some(second.clone())),
            second
        );
        assert_eq!(
            summary("3", Some("p"), "c").after(Some(third.clone())),
            third
        );
        // Another program, no program recorded, or another config: other drapes.
        for other in [
            summary("2", Some("q"), "c"),
            summary("2", None, "c"),
            summary("2", Some("p"), "e"),
        ] {
            assert!(other.after(Some(first.clone())).same_drapes.is_empty());
        }
        assert!(
            summary("2", Some("p"), "c")
                .after(Some(summary("1", None, "c")))
                .same_drapes
                .is_empty()
        );
        // A summary that names the drapes sha256 after one written before it did (none):
        // the program and config decide, as before.
        let named = |manifest: &str, program: &str, drapes: &str| {
            let mut s = summary(manifest, Some(program), "c");
            s.drapes_sha256 = Some(drapes.repeat(64));
            s
        };
        let linked = named("2", "p", "d").after(Some(first.clone()));
        assert_eq!(linked.same_drapes, vec!["1".repeat(64)]);
        assert!(
            named("2", "q", "d")
                .after(Some(first.clone()))
                .same_drapes
                .is_empty()
        );
        // Where both name it, it decides, whatever the programs: the links carry over to
        // another build's making of the same bytes, and not to the same build's other bytes.
        let third = named("3", "q", "d").after(Some(linked.clone()));
        assert_eq!(third.same_drapes, vec!["1".repeat(64), "2".repeat(64)]);
        assert!(
            named("3", "p", "e")
                .after(Some(linked))
                .same_drapes
                .is_empty()
        );
    }

    #[test]
    fn a_fresh_folder_counts_an_unfinished_datasets_hours_as_lost() {
        let root = tempfile::tempdir().unwrap();
        let (out, rec) = (root.path().join("out"), root.path().join("record"));
        let p = plan(&rec);
        let mut ledger = Ledger {
            machine_seconds: 900.0,
            ..Default::default()
        };
        ledger.seconds.insert("gen shirt".into(), 900.0);
        std::fs::create_dir_all(&rec).unwrap();
        ledger.save(&rec.join("stages.json")).unwrap();
        // A fresh folder: the drapes of those 900 s are gone.
        restore(&p, &out).unwrap();
        let got = Ledger::load(&out.join("stages.json")).unwrap();
        assert_eq!(got.lost.get("gen shirt"), Some(&900.0));
        assert_eq!(got.seconds, ledger.seconds);
        assert_eq!(got.machine_seconds, 900.0);
        // A folder that holds the dataset keeps its drapes' hours in the pace; a finished
        // dataset has no pace.
        let kept = root.path().join("kept");
        std::fs::create_dir_all(kept.join("data/shirt")).unwrap();
        restore(&p, &kept).unwrap();
        assert!(
            Ledger::load(&kept.join("stages.json"))
                .unwrap()
                .lost
                .is_empty()
        );
        ledger.done.insert("gen shirt".into(), true);
        ledger.save(&rec.join("stages.json")).unwrap();
        let done = root.path().join("done");
        restore(&p, &done).unwrap();
        assert!(
            Ledger::load(&done.join("stages.json"))
                .unwrap()
                .lost
                .is_empty()
        );
    }

    #[test]
    fn the_record_keeps_the_earlier_drapes_across_saves_of_a_dataset_made_again() {
        let root = tempfile::tempdir().unwrap();
        let (out, rec) = (root.path().join("out"), root.path().join("record"));
        let p = plan(&rec);
        let c = dataset::config::DatasetConfig::load("tiny").unwrap();
        // A manifest by `program` with one shard whose bytes' sha256 repeats `drapes`;
        // `made` stands for the timings that tell two generations of the same drapes
        // apart.
        let make = |program: &str, made: &str, drapes: &str| {
            let shard = dataset::manifest::ShardRecord {
                file: "train-00000.safetensors".into(),
                split: dataset::config::Split::Train,
                rows: 8,
                bytes: 1000,
                sha256: drapes.repeat(64),
                samples: vec![],
            };
            let mut m = dataset::manifest::Manifest::new(
                &c,
                Default::default(),
                "s".repeat(64),
                vec![shard],
            );
            m.program_sha256 = Some(program.repeat(64));
            m.size_templates.insert("made".into(), made.into());
            let dir = out.join("data/shirt");
            std::fs::create_dir_all(&dir).unwrap();
            let bytes = serde_json::to_vec(&m).unwrap();
            std::fs::write(dir.join("manifest.json"), &bytes).unwrap();
            (sha256(&bytes), m.drapes_sha256())
        };
        let ledger = Ledger::default();
        let recorded = || DataSummary::recorded(&p, "shirt").unwrap();
        let (first, drapes) = make("p", "first", "a");
        save(&p, &out, &ledger);
        assert_eq!(recorded().manifest_sha256, first);
        assert_eq!(recorded().drapes_sha256.as_ref(), Some(&drapes));
        assert!(recorded().same_drapes.is_empty());
        // Made again by the same program: the record links the two, and keeps the link
        // through later saves; the report finds it.
        let (second, _) = make("p", "second", "a");
        for _ in 0..2 {
            save(&p, &out, &ledger);
            assert_eq!(recorded().manifest_sha256, second);
            assert_eq!(recorded().same_drapes, vec![first.clone()]);
        }
        let found = DataSummary::find(&p, &out, "shirt").unwrap();
        assert_eq!(found.same_drapes, vec![first.clone()]);
        // Made again by another program that draped other bytes: other drapes, no link.
        let (third, _) = make("q", "third", "b");
        save(&p, &out, &ledger);
        assert_eq!(recorded().manifest_sha256, third);
        assert!(recorded().same_drapes.is_empty());
        // Made again by a third program that draped the same bytes: the same drapes.
        let (fourth, _) = make("r", "fourth", "b");
        save(&p, &out, &ledger);
        assert_eq!(recorded().manifest_sha256, fourth);
        assert_eq!(recorded().same_drapes, vec![third.clone()]);
        // Made again by that program, but with other bytes: the identity decides, not
        // the program.
        make("r", "fifth", "c");
        save(&p, &out, &ledger);
        assert!(recorded().same_drapes.is_empty());
    }
}
