//! `drape`: the command-line program. One subcommand per job; `drape --help` lists them.

mod cli;

use clap::Parser;

/// Set by `drape reproduce` on its children to its own process id: a child whose parent
/// is gone (killed, even by SIGKILL, which runs no clean-up) stops within a second
/// instead of training on unsupervised, where a rerun of `drape reproduce` would start a
/// second process on the same run folder. Training resumes from its last checkpoint.
const WATCH_PARENT: &str = "DRAPE_WATCH_PARENT";

/// Starts the parent watch if `DRAPE_WATCH_PARENT` names a process id.
fn watch_parent() {
    let Some(pid) = std::env::var(WATCH_PARENT)
        .ok()
        .and_then(|v| v.parse::<u32>().ok())
    else {
        return;
    };
    let check = move || {
        // An orphan is re-parented (to init or a subreaper), so its parent id changes.
        if std::os::unix::process::parent_id() != pid {
            eprintln!(
                "error: the drape reproduce that started this process (pid {pid}) is gone; stopping (the same reproduce command resumes)"
            );
            std::process::exit(3);
        }
    };
    check();
    std::thread::spawn(move || {
        loop {
            std::thread::sleep(std::time::Duration::from_millis(500));
            check();
        }
    });
}

fn main() -> std::process::ExitCode {
    watch_parent();
    let args = cli::Cli::parse();
    match cli::run(args) {
        Ok(()) => std::process::ExitCode::SUCCESS,
        Err(e) => {
            // Error types here name their cause in their own message; add only causes
            // not yet said.
            let mut msg = e.to_string();
            for cause in e.chain().skip(1) {
                let c = cause.to_string();
                if !msg.contains(&c) {
                    msg = format!("{msg}: {c}");
                }
            }
            eprintln!("error: {msg}");
            std::process::ExitCode::FAILURE
        }
    }
}
