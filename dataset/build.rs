//! Records the git revision for the dataset manifests (`DRAPE_GIT_REVISION`): the commit,
//! with `-dirty` appended when the source differs from it (uncommitted changes to tracked
//! files), so that a dataset made by a build of uncommitted code does not name a commit
//! that would not make it.
use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    Command::new("git")
        .args(args)
        .output()
        .ok()
        .filter(|o| o.status.success())
        .and_then(|o| String::from_utf8(o.stdout).ok())
}

fn main() {
    let rev = git(&["rev-parse", "HEAD"])
        .map(|s| s.trim().to_string())
        .filter(|s| !s.is_empty());
    let rev = match rev {
        None => "unknown".to_string(),
        Some(rev) => {
            let dirty = git(&["status", "--porcelain", "--untracked-files=no"])
                .is_some_and(|s| !s.trim().is_empty());
            if dirty { format!("{rev}-dirty") } else { rev }
        }
    };
    println!("cargo:rustc-env=DRAPE_GIT_REVISION={rev}");
    // Re-run on a commit and on any change to the workspace's sources and configs.
    for p in [
        "../.git/HEAD",
        "../.git/refs/heads",
        "../.git/packed-refs",
        "../.git/index",
        "../src",
        "../sim/src",
        "../dataset/src",
        "../learn/src",
        "../eval/src",
        "../configs",
        "../Cargo.toml",
        "../Cargo.lock",
    ] {
        println!("cargo:rerun-if-changed={p}");
    }
}
