//! Helpers shared by the integration tests that run the `drape` program.

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
