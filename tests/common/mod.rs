//! Helpers shared by the integration tests that run the `drape` program.
// Each test binary compiles this module and uses a part of it.
#![allow(dead_code)]

use std::process::Command;

/// The `drape` binary of this build.
pub fn drape() -> Command {
    Command::new(env!("CARGO_BIN_EXE_drape"))
}

/// Runs a command: success, and stdout then stderr as text.
pub fn run(cmd: &mut Command) -> (bool, String) {
    let out = cmd.output().expect("drape runs");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    (out.status.success(), text)
}

/// A private assets folder (the body model and the helper meshes, nothing built): what a
/// test builds, grades or imports there stays out of the source tree's `assets/`.
#[allow(dead_code)]
pub fn private_assets() -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("assets");
    for rel in [
        "body/body.safetensors.gz",
        "garments/source/makehuman-helpers.obj",
    ] {
        let to = dir.path().join(rel);
        std::fs::create_dir_all(to.parent().unwrap()).unwrap();
        std::fs::copy(src.join(rel), &to).unwrap();
    }
    dir
}
