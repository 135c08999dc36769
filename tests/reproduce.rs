//! `drape reproduce` end to end on a tiny plan: it generates, trains a network and a
//! fine-tune from it, evaluates both, times the speed-up and writes the report with our
//! numbers beside the paper's; a second run resumes without redoing anything; a plan's
//! record lets a fresh working folder resume without the data; a spent budget stops it
//! with a clear message; a slot the runs leave free makes the next dataset; `--only` works
//! on some datasets and leaves the rest for later.

mod common;

use std::path::Path;

use common::{drape, run};

#[test]
fn reproduce_runs_a_tiny_plan_resumes_and_keeps_to_its_budget() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    // The configs keep tiny's 150 epochs: the plan shortens each run to 3 (`epochs`).
    let tiny = tiny_configs(dir);
    assert!(tiny.contains("epochs = 150"));
    std::fs::write(
        dir.join("rq.toml"),
        format!("{tiny}\n[loss]\nvert = 1.0\nphysics_scale = 0.1\nrq = [500.0, 50.0, 10.0]\n"),
    )
    .unwrap();
    let plan = |budget: f64| {
        format!(
            r#"name = "tiny"
budget_hours = {budget}
eval_planned_hours = 0.01
parallel_runs = 2

[[datasets]]
key = "tshirt"
config = "tiny"
planned_hours = 0.01

[[runs]]
key = "tshirt-local"
config = "{0}/local.toml"
data = "tshirt"
planned_hours = 0.01
epochs = 3

[[runs]]
key = "tshirt-naive"
config = "{0}/naive.toml"
data = "tshirt"
planned_hours = 0.01
epochs = 3

[[runs]]
key = "tshirt-local-rq"
config = "{0}/rq.toml"
data = "tshirt"
init = "tshirt-local"
planned_hours = 0.01

[speedup]
runs = ["tshirt-local"]
samples = 1
"#,
            dir.display()
        )
    };
    std::fs::write(dir.join("plan.toml"), plan(1.0)).unwrap();
    let (out, docs) = (dir.join("out"), dir.join("docs"));
    let reproduce = |plan: &str| {
        run(drape()
            .arg("reproduce")
            .arg(dir.join(plan))
            .arg("-o")
            .arg(&out)
            .arg("--docs")
            .arg(&docs))
    };
    let (ok, text) = reproduce("plan.toml");
    assert!(ok, "{text}");
    // Two runs at once, each logging to its file; the fine-tune starts only once the run
    // it starts from has finished.
    for f in ["logs/train-tshirt-local.log", "logs/train-tshirt-naive.log"] {
        assert!(out.join(f).exists(), "{f} missing: {text}");
    }
    let at = |s: &str| {
        text.find(s)
            .unwrap_or_else(|| panic!("{s:?} missing: {text}"))
    };
    assert!(
        at("== train tshirt-local: finished") < at("== train tshirt-local-rq on"),
        "{text}"
    );
    assert!(
        at("== train tshirt-naive on") < at("== train tshirt-local: finished"),
        "{text}"
    );
    for f in [
        "data/tshirt/manifest.json",
        "runs/tshirt-local/best.bpk",
        "runs/tshirt-local-rq/run.json",
        "eval/tshirt-local/metrics.json",
        "eval/tshirt-local-rq/report.md",
        "speedup/tshirt-local.json",
        "stages.json",
    ] {
        assert!(out.join(f).exists(), "{f} missing: {text}");
    }
    // The plan's epochs reached the run's resolved config, and the report says so.
    let resolved = std::fs::read_to_string(out.join("runs/tshirt-local/config.toml")).unwrap();
    assert!(resolved.contains("epochs = 3"), "{resolved}");
    let md = std::fs::read_to_string(docs.join("reproduction.md")).unwrap();
    assert!(md.contains("`tshirt-local` (3 epochs)"), "{md}");
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(docs.join("reproduction.json")).unwrap()).unwrap();
    // Table 1's T-shirt GarNet-Local cell carries our Edist and the paper's 0.56; the
    // number in the JSON equals the evaluation's and names its provenance.
    let metrics: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("eval/tshirt-local/metrics.json")).unwrap())
            .unwrap();
    let edist = metrics["summaries"]["network"]["edist_cm"][0]
        .as_f64()
        .unwrap();
    assert!(
        md.contains(&format!(
            "| GarNet-Local | – / – (0.41 / 5.10) | {edist:.2} /"
        )),
        "{md}"
    );
    let cell = json["numbers"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| {
            n["table"] == 1
                && n["row"] == "GarNet-Local"
                && n["column"] == "T-shirt"
                && n["metric"] == "Edist"
        })
        .unwrap();
    assert!((cell["ours"].as_f64().unwrap() - edist).abs() < 1e-12);
    assert_eq!(cell["paper"].as_f64().unwrap(), 0.56);
    assert_eq!(
        cell["manifest_sha256"],
        metrics["provenance"]["manifest_sha256"]
    );
    assert!(cell["run_config_sha256"].as_str().unwrap().len() == 64);
    // The speed-up section: the batch-1 speed-up over the full drape is the bench's PBS
    // mean over its network time, in the table and in the JSON.
    let speed: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("speedup/tshirt-local.json")).unwrap())
            .unwrap();
    let sample = &speed["samples"][0];
    let net = ["warp", "inputs", "network"]
        .iter()
        .map(|k| sample[k].as_f64().unwrap())
        .sum::<f64>();
    let ratio = sample["pbs"].as_f64().unwrap() / net;
    assert!(md.contains("## Speed-up over the simulator"), "{md}");
    assert!(md.contains(&format!(" | {ratio:.1}x / ")), "{ratio} {md}");
    let number = |row: &str, column: &str, metric: &str| {
        json["numbers"]
            .as_array()
            .unwrap()
            .iter()
            .find(|n| n["row"] == row && n["column"] == column && n["metric"] == metric)
            .unwrap_or_else(|| panic!("{row} {column} {metric} missing"))["ours"]
            .as_f64()
            .unwrap()
    };
    let x = number("tshirt-local", "speed-up", "speed-up over PBS at batch 1");
    assert!((x - ratio).abs() < 1e-9 * ratio, "{x} {ratio}");
    // The baselines of the T-shirt come from GarNet-Local's evaluation.
    let dqs = metrics["summaries"]["dqs"]["edist_cm"][0].as_f64().unwrap();
    assert!(md.contains(&format!("| DQS | {dqs:.2} /")), "{md}");
    assert!((number("DQS", "baselines T-shirt", "Edist") - dqs).abs() < 1e-12);
    // What no run of the plan feeds is named, not shown as a table of dashes.
    assert!(
        md.contains("## Outside this plan") && md.contains("the loss ablation"),
        "{md}"
    );
    assert!(!md.contains("## Loss ablation"), "{md}");
    // Table 2 has our simulator time; the budget table lists every stage as done.
    assert!(
        md.contains("| gen tshirt | 0.01 |") && md.contains("| train tshirt-local-rq |"),
        "{md}"
    );
    let ledger: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("stages.json")).unwrap()).unwrap();
    assert!(
        ledger["done"]
            .as_object()
            .unwrap()
            .values()
            .all(|v| v == true),
        "{ledger}"
    );

    // The machine's hours count overlapping runs once.
    let stage_sum: f64 = ledger["seconds"]
        .as_object()
        .unwrap()
        .values()
        .map(|v| v.as_f64().unwrap())
        .sum();
    let machine = ledger["machine_seconds"].as_f64().unwrap();
    let secs = |k: &str| ledger["seconds"][k].as_f64().unwrap();
    // gen, local, its fine-tune and eval ran one after another; naive beside local.
    let chain = secs("gen tshirt")
        + secs("train tshirt-local")
        + secs("train tshirt-local-rq")
        + secs("eval");
    assert!(machine + 2.0 >= chain && machine < stage_sum, "{ledger}");

    // Again: every stage is done, nothing runs, the ledger's hours stay.
    let (ok, text) = reproduce("plan.toml");
    assert!(ok && !text.contains("== "), "{text}");
    let again: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("stages.json")).unwrap()).unwrap();
    assert_eq!(again["seconds"], ledger["seconds"]);
    assert_eq!(again["machine_seconds"], ledger["machine_seconds"]);

    // With a record, the finished stages go to it; a fresh working folder (a fresh machine)
    // restores them and runs nothing, not even the dataset, and reports the same numbers.
    let record = dir.join("record");
    std::fs::write(
        dir.join("recorded.toml"),
        plan(1.0).replace(
            "parallel_runs = 2",
            &format!("parallel_runs = 2\nrecord = \"{}\"", record.display()),
        ),
    )
    .unwrap();
    let reproduce_in = |plan: &str, out: &Path, docs: &Path| {
        run(drape()
            .arg("reproduce")
            .arg(dir.join(plan))
            .arg("-o")
            .arg(out)
            .arg("--docs")
            .arg(docs))
    };
    let (ok, text) = reproduce_in("recorded.toml", &out, &dir.join("docs-recorded"));
    assert!(ok && text.contains("file(s) updated"), "{text}");
    for f in [
        "stages.json",
        "data/tshirt.json",
        "runs/tshirt-local/state.json",
        "runs/tshirt-local-rq/log.csv",
        "eval/tshirt-naive/metrics.json",
        "speedup/tshirt-local.json",
    ] {
        assert!(record.join(f).exists(), "{f} not recorded: {text}");
    }
    // No stage needs weights any more, and checkpoints are never recorded.
    for r in ["tshirt-local", "tshirt-naive", "tshirt-local-rq"] {
        for f in ["best.bpk", "last.bpk", "last-optim.bpk"] {
            assert!(!record.join("runs").join(r).join(f).exists(), "{r}/{f}");
        }
    }
    let fresh = dir.join("fresh");
    let (ok, text) = reproduce_in("recorded.toml", &fresh, &dir.join("docs-fresh"));
    assert!(ok && !text.contains("== "), "{text}");
    assert!(text.contains("restored from the record: run tshirt-local-rq (finished)"));
    assert!(!fresh.join("data").exists(), "{text}");
    let numbers = |docs: &str| {
        let j: serde_json::Value = serde_json::from_slice(
            &std::fs::read(dir.join(docs).join("reproduction.json")).unwrap(),
        )
        .unwrap();
        j["numbers"].clone()
    };
    assert_eq!(numbers("docs-fresh"), numbers("docs-recorded"));
    assert!(
        numbers("docs-fresh")
            .as_array()
            .is_some_and(|n| !n.is_empty())
    );
    let md = std::fs::read_to_string(dir.join("docs-fresh/reproduction.md")).unwrap();
    assert!(!md.contains("| tshirt | `tiny` | – |"), "{md}");
    // The paired differences read the record's per-sample Edist (rounded to 1e-4 cm) as
    // they read the working folder's.
    let paired = |md: &str, name: &str| -> (f64, f64) {
        let row = md
            .lines()
            .find(|l| l.starts_with(&format!("| {name} | ")))
            .unwrap_or_else(|| panic!("no {name} row: {md}"));
        let cell: Vec<f64> = row
            .split('|')
            .nth(2)
            .unwrap()
            .split('±')
            .map(|x| x.trim().parse().unwrap())
            .collect();
        let n: usize = row.split('|').nth(3).unwrap().trim().parse().unwrap();
        assert!(n >= 2, "{row}");
        (cell[0], cell[1])
    };
    let recorded = std::fs::read_to_string(dir.join("docs-recorded/reproduction.md")).unwrap();
    for name in ["Local - Naive", "Local-RQ - Local"] {
        let (a, b) = (paired(&md, name), paired(&recorded, name));
        assert!(
            (a.0 - b.0).abs() <= 1.5e-3 && (a.1 - b.1).abs() <= 1.5e-3,
            "{name}: {a:?} {b:?}"
        );
    }
    // --status on a machine without the working folder reads the record.
    let (ok, status) = run(drape()
        .arg("reproduce")
        .arg(dir.join("recorded.toml"))
        .arg("-o")
        .arg(dir.join("lost"))
        .arg("--status"));
    assert!(
        ok && status.contains("this is the plan's record"),
        "{status}"
    );
    assert!(
        row_in(&status, "train tshirt-local").contains("| done: 3 epochs, ")
            && row_in(&status, "train tshirt-local-rq").ends_with("; evaluated |"),
        "{status}"
    );
    assert!(!dir.join("lost").exists());

    // The recorded drapes made again by the same binary from the same config: another
    // manifest (it records timings), the same drapes. `drape compare` pairs an evaluation on
    // them with the recorded one on their drapes sha256; an evaluation made before that
    // was recorded (session 71) pairs only given the record, which names the drapes
    // sha256 (since session 72; before, the program and config, with the data folder).
    let again = dir.join("again");
    let (ok, text) = run(drape().arg("gen").arg("tiny").arg("-o").arg(&again));
    assert!(ok, "{text}");
    let manifest = |d: &Path| std::fs::read(d.join("manifest.json")).unwrap();
    assert_ne!(manifest(&again), manifest(&out.join("data/tshirt")));
    let eval_again = dir.join("eval-again");
    let (ok, text) = run(drape()
        .arg("eval")
        .arg("--model")
        .arg(out.join("runs/tshirt-local"))
        .arg("--data")
        .arg(&again)
        .arg("-o")
        .arg(&eval_again));
    assert!(ok, "{text}");
    let recorded_eval = record.join("eval/tshirt-local/metrics.json");
    let (ok, text) = run(drape().arg("compare").arg(&eval_again).arg(&recorded_eval));
    assert!(ok, "{text}");
    // The recorded evaluation as one made before session 71: no drapes sha256.
    let mut old: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&recorded_eval).unwrap()).unwrap();
    assert!(old["provenance"]["drapes_sha256"].is_string());
    old["provenance"]
        .as_object_mut()
        .unwrap()
        .remove("drapes_sha256");
    let recorded_eval = dir.join("recorded-eval-before-71.json");
    std::fs::write(&recorded_eval, old.to_string()).unwrap();
    // The record as one written before session 72: its summaries name no drapes
    // sha256, so only the data folder an evaluation names can tie it to them.
    let record_before_72 = dir.join("record-before-72");
    std::fs::create_dir_all(record_before_72.join("data")).unwrap();
    for entry in std::fs::read_dir(record.join("data")).unwrap() {
        let path = entry.unwrap().path();
        let mut s: serde_json::Value =
            serde_json::from_slice(&std::fs::read(&path).unwrap()).unwrap();
        assert!(s["drapes_sha256"].is_string(), "{s}");
        s.as_object_mut().unwrap().remove("drapes_sha256");
        let to = record_before_72
            .join("data")
            .join(path.file_name().unwrap());
        std::fs::write(to, s.to_string()).unwrap();
    }
    let compare_with = |record: Option<&Path>| {
        let mut c = drape();
        c.arg("compare").arg(&eval_again).arg(&recorded_eval);
        if let Some(r) = record {
            c.arg("--record").arg(r);
        }
        run(&mut c)
    };
    let compare = |with_record: bool| compare_with(with_record.then_some(&record_before_72));
    let (ok, text) = compare(false);
    assert!(!ok && text.contains("these are different drapes"), "{text}");
    let (ok, text) = compare(true);
    assert!(ok, "{text}");
    // The record as written now names the drapes sha256 the new evaluation records.
    let (ok, text) = compare_with(Some(&record));
    assert!(ok, "{text}");
    // The same network on the same drapes: no difference beyond the record's rounding.
    let edist = text
        .lines()
        .find(|l| l.starts_with("| Edist (cm) | "))
        .unwrap_or_else(|| panic!("no Edist row: {text}"));
    let mean_difference: f64 = edist.split('|').nth(5).unwrap().trim().parse().unwrap();
    assert!(mean_difference.abs() < 1e-4, "{edist}");
    // The data folder must still hold the manifest evaluated...
    let again_manifest = again.join("manifest.json");
    let kept = std::fs::read(&again_manifest).unwrap();
    std::fs::write(&again_manifest, [kept.as_slice(), b"\n"].concat()).unwrap();
    let (ok, text) = compare(true);
    assert!(
        !ok && text.contains("is no longer the manifest evaluated"),
        "{text}"
    );
    // (A record that names the drapes sha256 needs no data folder.)
    let (ok, text) = compare_with(Some(&record));
    assert!(ok, "{text}");
    std::fs::write(&again_manifest, &kept).unwrap();
    // ...made from the recorded config: the same manifest with another config's sha256,
    // evaluated (its provenance) on a folder of its own, is other drapes.
    let other = dir.join("other-data");
    std::fs::create_dir_all(&other).unwrap();
    let mut m: serde_json::Value = serde_json::from_slice(&kept).unwrap();
    m["config_sha256"] = serde_json::json!("0".repeat(64));
    std::fs::write(other.join("manifest.json"), serde_json::to_vec(&m).unwrap()).unwrap();
    let mut e: serde_json::Value =
        serde_json::from_slice(&std::fs::read(eval_again.join("metrics.json")).unwrap()).unwrap();
    let other_summary = eval::repro::record::DataSummary::read("", &other.join("manifest.json"))
        .unwrap()
        .unwrap();
    e["provenance"]["manifest_sha256"] = serde_json::json!(other_summary.manifest_sha256);
    e["provenance"]["drapes_sha256"] = serde_json::json!(other_summary.drapes_sha256);
    e["provenance"]["data"] = serde_json::json!(other.to_str().unwrap());
    let other_eval = dir.join("other-eval.json");
    std::fs::write(&other_eval, serde_json::to_vec(&e).unwrap()).unwrap();
    let compare_other = |record: &Path| {
        run(drape()
            .arg("compare")
            .arg(&other_eval)
            .arg(&recorded_eval)
            .arg("--record")
            .arg(record))
    };
    let (ok, text) = compare_other(&record_before_72);
    assert!(
        !ok && text.contains("records no program and config the record does"),
        "{text}"
    );
    // With the record as written now, its drapes sha256 decides, and the message names
    // both.
    let (ok, text) = compare_other(&record);
    assert!(!ok && text.contains("the record names"), "{text}");
    // A folder that is no record is refused.
    let (ok, text) = run(drape()
        .arg("compare")
        .arg(&eval_again)
        .arg(&recorded_eval)
        .arg("--record")
        .arg(dir.join("no-record")));
    assert!(!ok && text.contains("not a record folder"), "{text}");

    // --status reads the folder and writes nothing: every stage done, the runs' epochs
    // and validation Edist, no hours left.
    let before = std::fs::read(out.join("stages.json")).unwrap();
    let (ok, status) = run(drape()
        .arg("reproduce")
        .arg(dir.join("plan.toml"))
        .arg("-o")
        .arg(&out)
        .arg("--status"));
    assert!(ok, "{status}");
    assert_eq!(std::fs::read(out.join("stages.json")).unwrap(), before);
    let row = |stage: &str| row_in(&status, stage);
    assert!(row("gen tshirt").contains("| done: "), "{status}");
    for r in ["tshirt-local", "tshirt-naive"] {
        assert!(
            row(&format!("train {r}")).contains("| done: 3 epochs, "),
            "{status}"
        );
    }
    assert!(row("eval").ends_with("| done |"), "{status}");
    assert!(status.contains("about 0.0 machine hours left"), "{status}");
    // A folder where nothing has run says so.
    let (ok, status) = run(drape()
        .arg("reproduce")
        .arg(dir.join("plan.toml"))
        .arg("-o")
        .arg(dir.join("nothing"))
        .arg("--status"));
    assert!(ok && status.contains("nothing has run yet"), "{status}");
    assert!(
        row_in(&status, "train tshirt-local-rq").contains("not started (fine-tunes tshirt-local)")
    );
    assert!(!dir.join("nothing").exists());

    // A plan may name its report's folder; --docs overrides it.
    std::fs::write(
        dir.join("own.toml"),
        plan(1.0).replace(
            "parallel_runs = 2",
            &format!(
                "parallel_runs = 2\ndocs = \"{}\"",
                dir.join("own").display()
            ),
        ),
    )
    .unwrap();
    let (ok, text) = run(drape()
        .arg("reproduce")
        .arg(dir.join("own.toml"))
        .arg("-o")
        .arg(&out)
        .arg("--report-only"));
    assert!(ok && !text.contains("== "), "{text}");
    let own = std::fs::read_to_string(dir.join("own/reproduction.md")).unwrap();
    // The same report as the one written from this working folder (docs-recorded) but
    // for the plan's name in its first lines. (Not docs-fresh's: it reads the record's
    // per-sample Edist, rounded to 1e-4 cm, so its paired differences' last digit can
    // differ; they are compared with a tolerance above.)
    let body = |m: &str| {
        m.lines()
            .filter(|l| !l.starts_with("Made by"))
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert_eq!(body(&own), body(&recorded));

    // A spent budget stops a plan before its next stage.
    std::fs::write(
        dir.join("tight.toml"),
        plan(1e-6).replace("samples = 1", "samples = 2"),
    )
    .unwrap();
    std::fs::remove_file(out.join("speedup/tshirt-local.json")).unwrap();
    let (ok, text) = reproduce("tight.toml");
    assert!(!ok && text.contains("budget"), "{text}");
    // A plan whose fine-tune starts from an unknown run is refused.
    std::fs::write(
        dir.join("bad.toml"),
        plan(1.0).replace("init = \"tshirt-local\"", "init = \"nothing\""),
    )
    .unwrap();
    let (ok, text) = reproduce("bad.toml");
    assert!(!ok && text.contains("nothing"), "{text}");
    // So is a failure gate outside [0, 1].
    std::fs::write(
        dir.join("gate.toml"),
        plan(1.0).replacen(
            "planned_hours = 0.01",
            "planned_hours = 0.01\nmax_failure_rate = 2.0",
            1,
        ),
    )
    .unwrap();
    let (ok, text) = reproduce("gate.toml");
    assert!(!ok && text.contains("max_failure_rate"), "{text}");
    // So is a run of no epochs.
    std::fs::write(
        dir.join("zero.toml"),
        plan(1.0).replacen("epochs = 3", "epochs = 0", 1),
    )
    .unwrap();
    let (ok, text) = reproduce("zero.toml");
    assert!(!ok && text.contains("epochs must be at least 1"), "{text}");
    // A plan whose dataset config changed after its data were made is refused, not run on
    // the old data.
    let tiny_data = std::fs::read_to_string("configs/datasets/tiny.toml").unwrap();
    assert!(tiny_data.contains("seed = 1\n"));
    let other = dir.join("tiny-seed-2.toml");
    std::fs::write(&other, tiny_data.replace("seed = 1\n", "seed = 2\n")).unwrap();
    std::fs::write(
        dir.join("other-data.toml"),
        plan(1.0).replace(
            "config = \"tiny\"",
            &format!("config = \"{}\"", other.display()),
        ),
    )
    .unwrap();
    let (ok, text) = reproduce("other-data.toml");
    assert!(
        !ok && text.contains("holds dataset \"tiny\"") && text.contains("another working folder"),
        "{text}"
    );
}

/// A slot that the runs of a dataset leave free, with nothing left to train or evaluate
/// beside the last run, makes the next dataset meanwhile, timed as its own stage.
#[test]
fn reproduce_makes_the_next_dataset_on_a_slot_the_runs_leave_free() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    tiny_configs(dir);
    // The naive run (1 epoch) and its evaluation end long before the local one (60
    // epochs): its slot then makes dataset b.
    std::fs::write(
        dir.join("plan.toml"),
        plan_on_a_and_b(
            "fill",
            &format!(
                r#"[[runs]]
key = "a-local"
config = "{0}/local.toml"
data = "a"
planned_hours = 0.01
epochs = 60

[[runs]]
key = "a-naive"
config = "{0}/naive.toml"
data = "a"
planned_hours = 0.01
epochs = 1

[[runs]]
key = "b-naive"
config = "{0}/naive.toml"
data = "b"
planned_hours = 0.01
epochs = 1

[speedup]
runs = []
samples = 1
"#,
                dir.display()
            ),
        ),
    )
    .unwrap();
    let out = dir.join("out");
    let (ok, text) = run(drape()
        .arg("reproduce")
        .arg(dir.join("plan.toml"))
        .arg("-o")
        .arg(&out)
        .arg("--docs")
        .arg(dir.join("docs")));
    assert!(ok, "{text}");
    let at = |s: &str| {
        text.find(s)
            .unwrap_or_else(|| panic!("{s:?} missing: {text}"))
    };
    // Started beside a-local, after a-naive's evaluation, on that slot's one thread.
    let fill = at("== gen b on 1 thread(s) beside the training, log ");
    assert!(at("== eval a-naive: done") < fill, "{text}");
    assert!(fill < at("== train a-local: finished"), "{text}");
    assert!(out.join("logs/gen-b.log").exists());
    // Either it finished there (and its own stage had nothing left to do) or it was
    // stopped when a-local ended and its own stage resumed it.
    if text.contains("== gen b: finished beside the training") {
        assert!(!text.contains("== gen b ("), "{text}");
    } else {
        assert!(
            text.contains("== gen b beside the training: stopped") && text.contains("== gen b ("),
            "{text}"
        );
    }
    assert!(out.join("data/b/manifest.json").exists());
    let ledger: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("stages.json")).unwrap()).unwrap();
    assert!(
        ledger["done"]
            .as_object()
            .unwrap()
            .values()
            .all(|v| v == true),
        "{ledger}"
    );
    // Its time is its stage's; made beside a-local, the machine counts it once.
    let secs = |k: &str| ledger["seconds"][k].as_f64().unwrap();
    let stages: f64 = ledger["seconds"]
        .as_object()
        .unwrap()
        .values()
        .map(|v| v.as_f64().unwrap())
        .sum();
    let machine = ledger["machine_seconds"].as_f64().unwrap();
    assert!(secs("gen b") > 0.0, "{ledger}");
    if text.contains("== gen b: finished beside the training") {
        assert!(machine <= stages - secs("gen b") + 0.5, "{ledger}");
    }
    assert!(
        machine + 2.0 >= secs("gen a") + secs("train a-local") + secs("train b-naive"),
        "{ledger}"
    );
}

/// `--only b` makes dataset b and trains and evaluates its run alone (on every thread: nothing
/// is beside it), leaving dataset a, its run and its speed-up for a later invocation; the
/// plan's evaluations are then not done, and no report is written. A key the plan lacks is
/// refused, naming its keys, and so is a fine-tune still to train whose base run trains on
/// a dataset left out.
#[test]
fn reproduce_only_works_on_the_datasets_named() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path();
    tiny_configs(dir);
    std::fs::write(
        dir.join("plan.toml"),
        plan_on_a_and_b(
            "only",
            &format!(
                r#"[[runs]]
key = "a-naive"
config = "{0}/naive.toml"
data = "a"
planned_hours = 0.01
epochs = 1

[[runs]]
key = "b-naive"
config = "{0}/naive.toml"
data = "b"
planned_hours = 0.01
epochs = 1

[speedup]
runs = ["a-naive"]
samples = 1
"#,
                dir.display()
            ),
        ),
    )
    .unwrap();
    let out = dir.join("out");
    // `drape reproduce --only ONLY` of the plan into working folder `into`.
    let reproduce_into = |into: &Path, only: &str| {
        run(drape()
            .arg("reproduce")
            .arg(dir.join("plan.toml"))
            .arg("-o")
            .arg(into)
            .arg("--docs")
            .arg(dir.join("docs"))
            .arg("--only")
            .arg(only))
    };
    let reproduce = |only: &str| reproduce_into(&out, only);
    let (ok, text) = reproduce("zz");
    assert!(
        !ok && text.contains("has no dataset \"zz\" (its datasets: a, b)"),
        "{text}"
    );
    assert!(!out.exists(), "nothing is made for a refused key");

    let (ok, text) = reproduce("b");
    assert!(ok, "{text}");
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    assert!(
        text.contains(&format!("== train b-naive on {cores} thread(s)")),
        "the lone run takes every core: {text}"
    );
    assert!(out.join("data/b/manifest.json").exists());
    assert!(out.join("eval/b-naive/metrics.json").exists());
    assert!(!out.join("data/a").exists(), "{text}");
    assert!(!out.join("runs/a-naive").exists(), "{text}");
    assert!(!out.join("speedup/a-naive.json").exists(), "{text}");
    let ledger = |k: &str| {
        let l: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("stages.json")).unwrap()).unwrap();
        l[k].clone()
    };
    assert_eq!(ledger("done")["gen b"], true);
    assert_eq!(ledger("done")["train b-naive"], true);
    assert_eq!(
        ledger("done")["eval"],
        false,
        "a-naive is not evaluated yet"
    );
    assert!(ledger("seconds").get("gen a").is_none());
    assert!(
        text.contains("report not written: stages of datasets left out of --only are unfinished"),
        "{text}"
    );
    assert!(
        !dir.join("docs/reproduction.md").exists(),
        "part of the plan writes no report"
    );

    // The rest, later: b and its run are not made again, a and its run and speed-up are.
    let (ok, text) = reproduce("a,b");
    assert!(ok, "{text}");
    assert!(
        !text.contains("== gen b") && !text.contains("== train b-naive"),
        "{text}"
    );
    assert!(text.contains("== train a-naive"), "{text}");
    assert!(out.join("eval/a-naive/metrics.json").exists());
    assert!(out.join("speedup/a-naive.json").exists());
    assert_eq!(ledger("done")["eval"], true);
    assert!(
        dir.join("docs/reproduction.md").exists(),
        "all of the plan done: the report is written: {text}"
    );

    // A fine-tune on b whose base trains on a, unfinished and left out, is refused before
    // anything is made.
    let plan = std::fs::read_to_string(dir.join("plan.toml")).unwrap();
    let plan = plan.replace(
        "[speedup]",
        &format!(
            "[[runs]]\nkey = \"b-tune\"\nconfig = \"{}/naive.toml\"\ndata = \"b\"\ninit = \"a-naive\"\nplanned_hours = 0.01\n\n[speedup]",
            dir.display()
        ),
    );
    std::fs::write(dir.join("plan.toml"), plan).unwrap();
    let report = std::fs::read(dir.join("docs/reproduction.md")).unwrap();
    let fresh = dir.join("fresh");
    let (ok, text) = reproduce_into(&fresh, "b");
    assert!(
        !ok && text.contains(
            "run b-tune starts from a-naive, which trains on dataset a and is not finished: add a to --only"
        ),
        "{text}"
    );
    assert!(!fresh.join("data/b").exists(), "{text}");
    // The same fine-tune already trained needs nothing of its base: it is not refused.
    // (b-naive's finished run stands in for it.)
    let tune = fresh.join("runs/b-tune");
    std::fs::create_dir_all(&tune).unwrap();
    for f in std::fs::read_dir(out.join("runs/b-naive")).unwrap() {
        let f = f.unwrap();
        if f.file_type().unwrap().is_file() {
            std::fs::copy(f.path(), tune.join(f.file_name())).unwrap();
        }
    }
    let (ok, text) = reproduce_into(&fresh, "b");
    assert!(ok, "{text}");
    assert!(!text.contains("starts from a-naive"), "{text}");
    assert!(!text.contains("== train b-tune"), "finished: {text}");
    assert!(fresh.join("eval/b-naive/metrics.json").exists(), "{text}");
    assert!(fresh.join("eval/b-tune/metrics.json").exists(), "{text}");
    assert_eq!(
        std::fs::read(dir.join("docs/reproduction.md")).unwrap(),
        report,
        "the whole plan's report stays: {text}"
    );
}

/// A plan named `name` on two tiny datasets, `a` then `b`, followed by `rest` (its runs and
/// speed-up).
fn plan_on_a_and_b(name: &str, rest: &str) -> String {
    format!(
        "name = \"{name}\"\nbudget_hours = 1.0\neval_planned_hours = 0.01\nparallel_runs = 2\n\n[[datasets]]\nkey = \"a\"\nconfig = \"tiny\"\nplanned_hours = 0.01\n\n[[datasets]]\nkey = \"b\"\nconfig = \"tiny\"\nplanned_hours = 0.01\n\n{rest}"
    )
}

/// Writes the tiny training config as DIR/local.toml and its Naive twin as DIR/naive.toml;
/// returns the config's text.
fn tiny_configs(dir: &Path) -> String {
    let tiny = std::fs::read_to_string("configs/train/tiny.toml").unwrap();
    std::fs::write(dir.join("local.toml"), &tiny).unwrap();
    std::fs::write(
        dir.join("naive.toml"),
        tiny.replace("variant = \"local\"", "variant = \"naive\""),
    )
    .unwrap();
    tiny
}

/// The table row of `stage` in `drape reproduce --status` output.
fn row_in(status: &str, stage: &str) -> String {
    status
        .lines()
        .find(|l| l.starts_with(&format!("| {stage} |")))
        .unwrap_or_else(|| panic!("{stage} missing: {status}"))
        .to_string()
}
