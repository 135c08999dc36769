//! `drape quickstart` with the committed weights (assets/quickstart/tshirt-local): it
//! writes its meshes and render and prints its figures; and the weights reproduce their
//! recorded Edist (reference.json) on test samples 0-9 of their dataset config, redraped
//! here by the simulator, within 10%.

mod common;

use common::{drape, run};

/// The number after `key` in `text`.
fn figure(text: &str, key: &str) -> f64 {
    let at = text
        .find(key)
        .unwrap_or_else(|| panic!("no {key:?} in {text}"))
        + key.len();
    text[at..]
        .trim_start()
        .split(|c: char| !(c.is_ascii_digit() || c == '.'))
        .next()
        .unwrap()
        .parse()
        .unwrap_or_else(|_| panic!("no number after {key:?} in {text}"))
}

#[test]
fn quickstart_drapes_with_both_and_the_weights_reproduce_their_reference() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("qs");
    let (ok, text) = run(drape().arg("quickstart").arg("-o").arg(&out));
    assert!(ok, "{text}");
    for f in [
        "body.obj",
        "simulator.obj",
        "network.obj",
        "dqs.obj",
        "quickstart.png",
    ] {
        assert!(out.join(f).exists(), "{f} missing: {text}");
    }
    let (edist, dqs) = (figure(&text, "Edist"), figure(&text, "alone:"));
    assert!(
        edist > 0.0 && edist < dqs,
        "network {edist} cm, DQS {dqs} cm: {text}"
    );
    // The speed-up is the two printed times' ratio (their speed is the benchmarks' business,
    // not a test's), within the rounding of the three printed figures.
    let (sim_s, net_ms, speedup) = (
        figure(&text, "simulator:"),
        figure(&text, "network:"),
        figure(&text, "speed-up:"),
    );
    assert!(sim_s > 0.0 && net_ms > 0.0, "{text}");
    let ratio = sim_s / (net_ms * 1e-3);
    assert!(
        (speedup - ratio).abs() <= 0.5 + 0.03 * ratio,
        "speed-up {speedup}x against {ratio:.1}x from the times: {text}"
    );

    let reference = tmp.path().join("reference.json");
    let (ok, text) = run(drape().args(["quickstart", "--reference"]).arg(&reference));
    assert!(ok, "{text}");
    let read = |p: &std::path::Path| -> serde_json::Value {
        serde_json::from_slice(&std::fs::read(p).unwrap()).unwrap()
    };
    let now = read(&reference);
    let committed = read(std::path::Path::new(
        "assets/quickstart/tshirt-local/reference.json",
    ));
    assert_eq!(now["config_sha256"], committed["config_sha256"]);
    let (a, b) = (
        now["samples"].as_array().unwrap(),
        committed["samples"].as_array().unwrap(),
    );
    assert_eq!(a.len(), b.len(), "{text}");
    assert!(a.len() >= 9, "{text}");
    for (x, y) in a.iter().zip(b) {
        assert_eq!(x[0], y[0]);
        let (e, r) = (x[1].as_f64().unwrap(), y[1].as_f64().unwrap());
        assert!(
            (e - r).abs() <= 0.1 * r,
            "sample {}: Edist {e} cm, recorded {r} cm",
            x[0]
        );
    }
}
