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

/// Keeps freed memory in the process instead of returning it to the system at once.
/// Training allocates and frees tensors of tens of megabytes every step; with glibc's
/// defaults each comes back from the kernel as fresh zeroed pages (page faults, memset),
/// about a quarter of a training step's time. Measured (docs/bench.md): GarNet-Local training
/// at 1 thread, 4.2-4.7 samples/s with the defaults, 6.1-6.3 with these settings. Any
/// `MALLOC_*_` variable in the environment (glibc's own tuning) turns this off.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[allow(unsafe_code)]
fn tune_allocator() {
    if std::env::vars_os().any(|(k, _)| {
        let k = k.to_string_lossy();
        k.starts_with("MALLOC_") && k.ends_with('_')
    }) {
        return;
    }
    // SAFETY: mallopt only sets allocator parameters; it is called before any other
    // thread exists.
    unsafe {
        // Blocks up to 32 MB (glibc's largest) come from the heap, not from mmap.
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        // Free memory at the top of the heap is kept up to 1 GB ...
        libc::mallopt(libc::M_TRIM_THRESHOLD, 1 << 30);
        // ... and the heap grows 256 MB at a time.
        libc::mallopt(libc::M_TOP_PAD, 256 << 20);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn tune_allocator() {}

/// Output piped into a program that stops reading (`drape data info DIR | head`) ends the
/// process quietly, as with other command-line tools, instead of a panic on the next write.
#[cfg(all(target_os = "linux", target_env = "gnu"))]
#[allow(unsafe_code)]
fn default_sigpipe() {
    // SAFETY: restores the signal's default action; called before any other thread exists.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
}

#[cfg(not(all(target_os = "linux", target_env = "gnu")))]
fn default_sigpipe() {}

fn main() -> std::process::ExitCode {
    default_sigpipe();
    tune_allocator();
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
