//! `drape train` end to end on the tiny dataset: a run folder with its config, logs and
//! checkpoints; validation loss below the DQS warp's; resume of a finished run; fine-tuning
//! checks; bad configs refused.

use std::path::Path;
use std::process::Command;

fn drape() -> Command {
    Command::new(env!("CARGO_BIN_EXE_drape"))
}

fn run(cmd: &mut Command) -> (bool, String) {
    let out = cmd.output().expect("drape runs");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

/// The tiny training config with a few epochs and another variant.
fn config(dir: &Path, epochs: usize, variant: &str, extra: &str) -> std::path::PathBuf {
    let base = std::fs::read_to_string("configs/train/tiny.toml").unwrap();
    let text = base
        .replace("epochs = 150", &format!("epochs = {epochs}"))
        .replace(
            "variant = \"local\"",
            &format!("variant = \"{variant}\"{extra}"),
        );
    let p = dir.join(format!("{variant}-{epochs}.toml"));
    std::fs::write(&p, text).unwrap();
    p
}

/// `drape train CONFIG --data DATA -o RUN [extra...]`.
fn train(config: &Path, data: &Path, run_dir: &Path, extra: &[&std::ffi::OsStr]) -> (bool, String) {
    run(drape()
        .arg("train")
        .arg(config)
        .arg("--data")
        .arg(data)
        .arg("-o")
        .arg(run_dir)
        .args(extra))
}

#[test]
fn train_writes_a_run_learns_resumes_and_refuses_bad_input() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let (ok, text) = run(drape().args(["gen", "tiny", "-o"]).arg(&data));
    assert!(ok, "{text}");

    let run_dir = tmp.path().join("run");
    let cfg = config(tmp.path(), 8, "local", "");
    let (ok, text) = train(&cfg, &data, &run_dir, &[]);
    assert!(ok, "{text}");
    for f in [
        "config.toml",
        "run.json",
        "state.json",
        "last.bpk",
        "last-optim.bpk",
        "best.bpk",
        "log.csv",
        "steps.csv",
    ] {
        assert!(run_dir.join(f).exists(), "{f} missing: {text}");
    }
    // log.csv: a train and a val row per epoch; validation Edist falls below epoch 0's,
    // which is one Adam step away from the DQS warp (the untrained network returns M).
    let log = std::fs::read_to_string(run_dir.join("log.csv")).unwrap();
    let val: Vec<f64> = log
        .lines()
        .filter(|l| l.split(',').nth(1) == Some("val"))
        .map(|l| l.rsplit(',').next().unwrap().parse().unwrap())
        .collect();
    assert_eq!(val.len(), 8, "{log}");
    assert!(
        val.iter().all(|v| v.is_finite() && *v > 0.0 && *v < 30.0),
        "{val:?}"
    );
    let best = val.iter().cloned().fold(f64::MAX, f64::min);
    assert!(best < val[0], "validation Edist never improved: {val:?}");

    // A finished run: the same command does nothing more.
    let steps_before = std::fs::read_to_string(run_dir.join("steps.csv")).unwrap();
    let (ok, text) = train(&cfg, &data, &run_dir, &[]);
    assert!(ok, "{text}");
    assert_eq!(
        steps_before,
        std::fs::read_to_string(run_dir.join("steps.csv")).unwrap()
    );

    // Another config into the same folder is refused.
    let other = config(tmp.path(), 9, "local", "");
    let (ok, text) = train(&other, &data, &run_dir, &[]);
    assert!(!ok && text.contains("another config"), "{text}");

    // Fine-tuning a Global network from a Local run is refused with both names.
    let global = config(tmp.path(), 1, "global", "");
    let ft = tmp.path().join("ft");
    let (ok, text) = train(
        &global,
        &data,
        &ft,
        &["--init".as_ref(), run_dir.as_os_str()],
    );
    assert!(
        !ok && text.contains("GarNet-Local") && text.contains("GarNet-Global"),
        "{text}"
    );

    // Unknown fields and out-of-range values are named.
    let bad = config(tmp.path(), 2, "local", "\nwidth = 3");
    let (ok, text) = train(&bad, &data, &tmp.path().join("bad"), &[]);
    assert!(!ok && text.contains("width"), "{text}");
    let bad = config(tmp.path(), 0, "local", "");
    let (ok, text) = train(&bad, &data, &tmp.path().join("bad"), &[]);
    assert!(!ok && text.contains("epochs"), "{text}");
}
