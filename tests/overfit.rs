//! Every GarNet variant overfits a handful of samples: `drape train` on the two lowest-id
//! training samples of the `handful` dataset (a 1k-vertex T-shirt, DQS 7.0 cm), L_vert only,
//! 2,000 Adam steps with a cosine-decayed learning rate, and the training Edist must end
//! below the 3 mm.
//!
//! The network is the tiny config's with a wider garment MLP and fusion, a positional
//! encoding of the garment coordinates (`fourier_bands = 8`) and residual blocks that start
//! at zero (`zero_init_residuals`): without the last two, 2,000 steps end at 5.3 to 5.5 mm
//! (docs/learn.md, "Overfitting").

mod common;

use common::{drape, run};
use std::path::Path;

/// Mean DQS Edist (cm) of the `n` lowest-id training samples.
fn dqs_edist(data: &Path, n: usize) -> f64 {
    let d = dataset::reader::Dataset::open(data).unwrap();
    let mut rows = Vec::new();
    for s in &d.manifest.shards {
        if s.split == dataset::config::Split::Train {
            rows.extend(d.read_shard(&s.file).unwrap());
        }
    }
    rows.sort_by_key(|r| r.id);
    rows.truncate(n);
    eval::metrics::mean(
        rows.iter()
            .map(|r| eval::metrics::edist_cm(&r.warped, &r.draped)),
    )
}

#[test]
fn every_variant_fits_a_handful_of_samples() {
    let tmp = tempfile::tempdir().unwrap();
    let data = tmp.path().join("data");
    let (ok, text) = run(drape()
        .args(["gen", "configs/datasets/handful.toml", "-o"])
        .arg(&data));
    assert!(ok, "{text}");
    let dqs = dqs_edist(&data, 2);
    assert!(
        dqs > 3.0,
        "the DQS warp is {dqs:.2} cm from the drapes: too easy a test"
    );
    let base = std::fs::read_to_string("configs/train/tiny.toml").unwrap();
    // The four trainings run at once, one thread each (a run keeps about one core busy):
    // the same results as one after another, in half the time on two cores.
    let variants = ["naive", "global", "local", "global-params"];
    let results: Vec<(String, Result<f64, String>)> = std::thread::scope(|scope| {
        let handles: Vec<_> = variants
            .iter()
            .map(|&variant| {
                let (base, tmp, data) = (&base, tmp.path(), &data);
                scope.spawn(move || (variant.to_string(), overfit(base, tmp, data, variant)))
            })
            .collect();
        handles.into_iter().map(|h| h.join().unwrap()).collect()
    });
    for (variant, r) in results {
        let last = r.unwrap_or_else(|e| panic!("{variant}: {e}"));
        eprintln!("{variant}: training Edist {last:.3} cm (DQS {dqs:.3} cm)");
        assert!(
            last < 0.3,
            "{variant}: training Edist {last:.3} cm, not below 3 mm (DQS {dqs:.3} cm)"
        );
    }
}

/// Trains `variant` on the two samples with the test's config; its last training Edist (cm).
fn overfit(base: &str, tmp: &Path, data: &Path, variant: &str) -> Result<f64, String> {
    let text = base
        .replace(
            "epochs = 150",
            "epochs = 2000\nmax_train_samples = 2\nlearning_rate_end = 1e-5\nadam_epsilon = 1e-8",
        )
        .replace("variant = \"local\"", &format!("variant = \"{variant}\""))
        .replace("garment_mlp = [32, 32]", "garment_mlp = [128, 128]")
        .replace("fusion = [64, 32, 32]", "fusion = [256, 128, 64]")
        + "\nfourier_bands = 8\nzero_init_residuals = true\n\n[loss]\npen = 0.0\nnorm = 0.0\nbend = 0.0\n";
    assert!(text.contains("epochs = 2000") && text.contains("[128, 128]"));
    let cfg = tmp.join(format!("{variant}.toml"));
    std::fs::write(&cfg, text).unwrap();
    let run_dir = tmp.join(variant);
    let (ok, out) = run(drape()
        .env("RAYON_NUM_THREADS", "1")
        .arg("train")
        .arg(&cfg)
        .arg("--data")
        .arg(data)
        .arg("-o")
        .arg(&run_dir));
    if !ok {
        return Err(out);
    }
    let log = std::fs::read_to_string(run_dir.join("log.csv")).unwrap();
    log.lines()
        .rfind(|l| l.contains(",train,"))
        .and_then(|l| l.rsplit(',').next())
        .and_then(|v| v.parse().ok())
        .ok_or_else(|| format!("no train row in {log}"))
}
