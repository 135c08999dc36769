//! The run folder: resolved config, run info, checkpoints, logs.

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::Path;

use burn::optim::ModuleOptimizer;
use indicatif::{ProgressBar, ProgressStyle};
use serde::Serialize;
use serde::de::DeserializeOwned;

use crate::LearnError;
use crate::config::TrainConfig;
use crate::model::GarNet;
use crate::train::{RunInfo, State, ck, model_bytes};

fn io(path: &Path) -> impl Fn(std::io::Error) -> LearnError + '_ {
    move |e| LearnError::Io {
        path: path.to_path_buf(),
        source: e,
    }
}

/// Reads a JSON file, `None` if it does not exist.
pub fn read_json<T: DeserializeOwned>(path: &Path) -> Result<Option<T>, LearnError> {
    match std::fs::read(path) {
        Ok(b) => serde_json::from_slice(&b)
            .map(Some)
            .map_err(|e| LearnError::Checkpoint {
                path: path.to_path_buf(),
                reason: e.to_string(),
            }),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
        Err(e) => Err(io(path)(e)),
    }
}

/// Writes all files or none (`sim::io::write_all_or_nothing`), renamed in the given order.
pub fn write_files(files: &[(&Path, &[u8])]) -> Result<(), LearnError> {
    sim::io::write_all_or_nothing(files).map_err(|e| LearnError::Io {
        path: e.path,
        source: e.source,
    })
}

pub(crate) fn json(value: &impl Serialize) -> Vec<u8> {
    serde_json::to_vec_pretty(value).expect("serialisable")
}

/// sha256 of a dataset's manifest file, hex.
pub fn manifest_sha256(data: &Path) -> Result<String, LearnError> {
    let p = data.join("manifest.json");
    let bytes = std::fs::read(&p).map_err(io(&p))?;
    Ok(dataset::generate::sha256(&bytes))
}

/// sha256 of a garment's triangles (their vertex indices as little-endian u32s): two
/// meshes with the same vertex count but other faces give a network other convolution
/// neighbourhoods, and its predictions would be meaningless.
pub fn faces_sha256(triangles: &[[u32; 3]]) -> String {
    let bytes: Vec<u8> = triangles
        .iter()
        .flatten()
        .flat_map(|i| i.to_le_bytes())
        .collect();
    dataset::generate::sha256(&bytes)
}

/// Refuses a garment whose triangles (their [`faces_sha256`], `faces`) are not those `run`
/// was trained on, when its `run.json` records them: an imported template replaced by
/// another mesh with as many vertices, or a built-in one whose definition changed since.
pub fn check_faces(run: &Path, info: &RunInfo, faces: &str) -> Result<(), LearnError> {
    match &info.faces_sha256 {
        Some(trained) if trained != faces => Err(LearnError::Mismatch(format!(
            "{} was trained on a {} mesh with other triangles (faces sha256 {}..., this garment's {}...): \
             the template was replaced or its definition changed since; use data or a template \
             with the run's mesh",
            run.display(),
            info.garment,
            dataset::manifest::short_hex(trained),
            dataset::manifest::short_hex(faces),
        ))),
        _ => Ok(()),
    }
}

/// The lock file a training process holds in its run folder ([`prepare_folder`]).
pub const LOCK_FILE: &str = ".train.lock";

/// Creates the run folder with `config.toml` and `run.json`, or checks that an existing
/// one was made by the same config on the same dataset (resume). Returns the folder's lock
/// ([`LOCK_FILE`], held until the returned file is dropped): a second `drape train` into a
/// folder that another process trains in is refused, as the two would write the same
/// checkpoints and logs. An operating-system lock ends with its process, however it ends,
/// so none is ever left stale; on a file system that cannot lock, training goes on without
/// the guard and says so.
pub fn prepare_folder(
    run: &Path,
    config: &TrainConfig,
    info: &RunInfo,
) -> Result<File, LearnError> {
    if run.join("manifest.json").exists() {
        return Err(LearnError::Mismatch(format!(
            "{} is a dataset folder; give the run a folder of its own (-o)",
            run.display()
        )));
    }
    std::fs::create_dir_all(run).map_err(io(run))?;
    let lp = run.join(LOCK_FILE);
    let lock = File::options()
        .create(true)
        .truncate(false)
        .write(true)
        .open(&lp)
        .map_err(io(&lp))?;
    match lock.try_lock() {
        Ok(()) => {}
        Err(std::fs::TryLockError::WouldBlock) => {
            return Err(LearnError::Mismatch(format!(
                "another drape train is writing {}; wait for it to finish or stop it (its lock ends with its process)",
                run.display()
            )));
        }
        Err(std::fs::TryLockError::Error(e)) => eprintln!(
            "note: {} cannot be locked ({e}): nothing stops a second drape train from writing this run at once",
            lp.display()
        ),
    }
    let cp = run.join("config.toml");
    let text = toml::to_string(config).expect("serialisable config");
    match std::fs::read_to_string(&cp) {
        Ok(old) => {
            let mut old: TrainConfig = toml::from_str(&old)
                .map_err(|e| LearnError::Config(format!("{}: {e}", cp.display())))?;
            // The wall-clock cap is per invocation: a resumed run may have another.
            old.wall_clock_minutes = config.wall_clock_minutes;
            // An option given on the command line that differs from the run's: name it.
            let refuse = |was: String, asks: String, flag: &str, value: u64| {
                LearnError::Mismatch(format!(
                    "{} is a run of {was}, this invocation asks for {asks}; resume with --{flag} {value} (or use another -o folder)",
                    run.display()
                ))
            };
            if old.epochs != config.epochs {
                let (was, asks) = (format!("{} epochs", old.epochs), config.epochs.to_string());
                return Err(refuse(was, asks, "epochs", old.epochs as u64));
            }
            if old.seed != config.seed {
                let (was, asks) = (
                    format!("seed {}", old.seed),
                    format!("seed {}", config.seed),
                );
                return Err(refuse(was, asks, "seed", old.seed));
            }
            if &old != config {
                // Only [model] differs: likely a resume without the run's `--widths`.
                let same_but_model = TrainConfig {
                    model: config.model.clone(),
                    ..old.clone()
                } == *config;
                let hint = if same_but_model {
                    " (only its [model] differs: resume with the --widths the run started with, if any)"
                } else {
                    ""
                };
                return Err(LearnError::Mismatch(format!(
                    "{} holds a run of another config ({} records it){hint}; use another -o folder, or delete it",
                    run.display(),
                    cp.display()
                )));
            }
        }
        Err(_) => write_files(&[(&cp, text.as_bytes())])?,
    }
    let ip = run.join("run.json");
    let old = read_json::<RunInfo>(&ip)?;
    // Checked before the main dataset's identity, whose same-drapes case resumes at once.
    if let Some(old) = &old
        && old
            .more_data
            .iter()
            .map(|m| &m.drapes_sha256)
            .ne(info.more_data.iter().map(|m| &m.drapes_sha256))
    {
        let names = |m: &[crate::train::MoreData]| {
            if m.is_empty() {
                "none".to_string()
            } else {
                m.iter()
                    .map(|d| {
                        format!(
                            "{} (drapes sha256 {}...)",
                            d.dataset,
                            dataset::manifest::short_hex(&d.drapes_sha256)
                        )
                    })
                    .collect::<Vec<_>>()
                    .join(", ")
            }
        };
        return Err(LearnError::Mismatch(format!(
            "{} was trained with --more-data {}, not {}: resume it with the data it started on, or use another -o folder",
            run.display(),
            names(&old.more_data),
            names(&info.more_data)
        )));
    }
    match old {
        Some(old) if old.garment != info.garment || old.vertices != info.vertices => {
            Err(LearnError::Mismatch(format!(
                "{} was trained on {} ({} vertices), not {} ({} vertices)",
                run.display(),
                old.garment,
                old.vertices,
                info.garment,
                info.vertices
            )))
        }
        Some(old) if old.manifest_sha256 != info.manifest_sha256 => {
            // Another manifest: the same drapes made again serve (their identity matches).
            match (&old.drapes_sha256, &info.drapes_sha256) {
                (Some(a), Some(b)) if a == b => {
                    println!(
                        "resuming on the same drapes made again (drapes sha256 {}...; manifest {}... where the run started on {}...)",
                        dataset::manifest::short_hex(a),
                        dataset::manifest::short_hex(&info.manifest_sha256),
                        dataset::manifest::short_hex(&old.manifest_sha256),
                    );
                    Ok(())
                }
                (old_drapes, _) => Err(LearnError::Mismatch(format!(
                    "{} was trained on dataset {} with manifest sha256 {}..., not on this data ({}, manifest {}...){}: resume it with the data it started on, or use another -o folder",
                    run.display(),
                    old.dataset,
                    dataset::manifest::short_hex(&old.manifest_sha256),
                    info.dataset,
                    dataset::manifest::short_hex(&info.manifest_sha256),
                    match old_drapes {
                        Some(_) => ", and these are other drapes",
                        None =>
                            " (the run predates drapes sha256, so data made again cannot be matched to it)",
                    },
                ))),
            }
        }
        // A run made before the drapes' identity: recorded now that its data is verified
        // by the manifest, so that it can resume on the same drapes made again later.
        Some(old) if old.drapes_sha256.is_none() && info.drapes_sha256.is_some() => {
            let upgraded = RunInfo {
                drapes_sha256: info.drapes_sha256.clone(),
                ..old
            };
            write_files(&[(&ip, &json(&upgraded))])
        }
        Some(_) => Ok(()),
        None => write_files(&[(&ip, &json(info))]),
    }?;
    Ok(lock)
}

/// Checks that the run `init` can start a run of network `want` on data `info`: the same
/// variant, widths and garment. Called before the new run's folder is written, so that a
/// refused fine-tune leaves nothing behind.
pub fn check_init(
    want: &crate::config::ModelConfig,
    init: &Path,
    info: &RunInfo,
) -> Result<(), LearnError> {
    let (config, old) = open_run(init)?;
    if config.model.variant != want.variant {
        return Err(LearnError::Mismatch(format!(
            "{} is a {} run; this config trains {}",
            init.display(),
            config.model.variant.paper_name(),
            want.variant.paper_name()
        )));
    }
    if &config.model != want {
        return Err(LearnError::Mismatch(format!(
            "{} was trained with other network widths or sizes than this config's [model] \
             (theirs: {} body points, global feature {}, FeaStNet width {} with {} heads; \
             this config's: {}, {}, {} with {}): fine-tune with the same widths (`--widths`)",
            init.display(),
            config.model.body_points,
            config.model.body_mlp2.last().copied().unwrap_or(0),
            config.model.conv_width,
            config.model.conv_heads,
            want.body_points,
            want.body_mlp2.last().copied().unwrap_or(0),
            want.conv_width,
            want.conv_heads
        )));
    }
    if old.garment != info.garment || old.vertices != info.vertices {
        return Err(LearnError::Mismatch(format!(
            "{} was trained on {} ({} vertices), this data is {} ({} vertices)",
            init.display(),
            old.garment,
            old.vertices,
            info.garment,
            info.vertices
        )));
    }
    if let Some(faces) = &info.faces_sha256 {
        check_faces(init, &old, faces)?;
    }
    Ok(())
}

/// Reads a run folder's config and info.
pub fn open_run(run: &Path) -> Result<(TrainConfig, RunInfo), LearnError> {
    let cp = run.join("config.toml");
    if !cp.exists() {
        return Err(LearnError::Mismatch(format!(
            "{} is not a run folder (no config.toml)",
            run.display()
        )));
    }
    let config = TrainConfig::load(&cp)?;
    let info = read_json::<RunInfo>(&run.join("run.json"))?
        .ok_or_else(|| LearnError::Mismatch(format!("{} has no run.json", run.display())))?;
    Ok((config, info))
}

/// Saves model, optimiser and state, all or none; the state is renamed last, so a state
/// file never points past the weights beside it.
pub fn checkpoint(
    run: &Path,
    model: &GarNet,
    optim: &ModuleOptimizer,
    state: &State,
) -> Result<(), LearnError> {
    let (mp, op, sp) = (
        run.join("last.bpk"),
        run.join("last-optim.bpk"),
        run.join("state.json"),
    );
    let model = model_bytes(model, &mp)?;
    let optim = optim.into_bytes().map_err(ck(&op))?;
    write_files(&[(&mp, &model), (&op, &optim), (&sp, &json(state))])
}

/// Opens a CSV log for appending, writing its header if it is new, after dropping the
/// rows for which `keep` is false. A run
/// resumes from its last checkpoint: rows a stopped process wrote after that checkpoint
/// would be written again, so `drape train` keeps only those the checkpoint covers.
pub fn append_after(
    path: &Path,
    header: &str,
    keep: impl Fn(&str) -> bool,
) -> Result<File, LearnError> {
    if path.exists() {
        let text = std::fs::read_to_string(path).map_err(io(path))?;
        let mut lines = text.lines();
        let first = lines.next();
        let rows: Vec<&str> = lines.filter(|l| !l.is_empty()).collect();
        let kept: Vec<&str> = rows.iter().copied().filter(|l| keep(l)).collect();
        if kept.len() < rows.len() {
            let mut out = String::new();
            for l in first.into_iter().chain(kept) {
                out.push_str(l);
                out.push('\n');
            }
            write_files(&[(path, out.as_bytes())])?;
        }
    }
    let new = !path.exists();
    let mut f = OpenOptions::new()
        .create(true)
        .append(true)
        .open(path)
        .map_err(io(path))?;
    if new {
        writeln!(f, "{header}").map_err(io(path))?;
    }
    Ok(f)
}

/// Ends the line of a finished bar that stays on the terminal, so that what is printed
/// next starts on a line of its own (indicatif leaves the cursor after the bar).
pub fn end_bar_line(bar: &ProgressBar) {
    if !bar.is_hidden() {
        eprintln!();
    }
}

/// A progress bar (hidden when `show` is false).
pub fn progress(show: bool, len: u64) -> ProgressBar {
    if !show {
        return ProgressBar::hidden();
    }
    let bar = ProgressBar::new(len);
    bar.set_style(
        ProgressStyle::with_template(
            "{elapsed_precise} [{bar:30}] {pos}/{len} batches, {per_sec}, ETA {eta} | {msg}",
        )
        .expect("valid template")
        .progress_chars("=> "),
    );
    bar
}

/// A bar's state as plain lines, for logs. indicatif draws nothing when standard error is
/// not a terminal (a log file, `nohup`, CI), so a long job would show nothing until it ends;
/// then `tick` writes the bar's position, message, rate and remaining time to standard
/// error at most once every `every`, and `finish` writes a last line.
#[derive(Debug)]
pub struct LogLines {
    what: String,
    unit: String,
    every: std::time::Duration,
    /// When the work started and when the last line was written.
    clock: std::sync::Mutex<(std::time::Instant, std::time::Instant)>,
    /// The bar's position when the work started (a resumed run's earlier steps), left out
    /// of the rate.
    from: std::sync::atomic::AtomicU64,
    on: bool,
}

impl LogLines {
    /// A line a minute for a bar meant to be `shown` that draws nothing (standard error is
    /// not a terminal); none when the bar was not meant to be shown. `what` names the work
    /// ("gen"), `unit` counts it ("drapes").
    pub fn new(shown: bool, bar: &ProgressBar, what: &str, unit: &str) -> Self {
        Self::when(
            shown && bar.is_hidden(),
            what,
            unit,
            std::time::Duration::from_secs(60),
        )
    }

    /// Lines if `on`, whatever the bar does (for bars drawn to a hidden target at first).
    pub fn when(on: bool, what: &str, unit: &str, every: std::time::Duration) -> Self {
        let now = std::time::Instant::now();
        Self {
            what: what.to_string(),
            unit: unit.to_string(),
            every,
            clock: std::sync::Mutex::new((now, now)),
            from: std::sync::atomic::AtomicU64::new(0),
            on,
        }
    }

    /// Whether lines are written (as made: [`LogLines::new`] for a bar meant to be shown
    /// that draws nothing, or `when` with `on`).
    pub fn is_on(&self) -> bool {
        self.on
    }

    /// The work starts at `pos` (steps done before a resume): the rate counts from there.
    pub fn starting_at(self, pos: u64) -> Self {
        self.from.store(pos, std::sync::atomic::Ordering::Relaxed);
        self
    }

    /// A line worth keeping (an epoch's figures, say): on standard error when lines are
    /// on, else above the bar (which prints nothing for a hidden bar).
    pub fn note(&self, bar: &ProgressBar, text: &str) {
        if self.on {
            eprintln!("{text}");
        } else {
            bar.println(text);
        }
    }

    /// Starts the clock again: the work itself begins now (after loading, say), so the
    /// rate and the time to go leave out what came before.
    pub fn restart(&self) {
        let now = std::time::Instant::now();
        *self.clock.lock().unwrap_or_else(|e| e.into_inner()) = (now, now);
    }

    /// Whether a line is due (and, if so, counts it as written): for callers that write
    /// their own line (a stage's message rather than the bar's count).
    pub fn due(&self) -> bool {
        if !self.on {
            return false;
        }
        let now = std::time::Instant::now();
        let mut clock = self.clock.lock().unwrap_or_else(|e| e.into_inner());
        if now.duration_since(clock.1) >= self.every {
            clock.1 = now;
            true
        } else {
            false
        }
    }

    /// After the bar moved: a line if one is due.
    pub fn tick(&self, bar: &ProgressBar) {
        if self.due() {
            eprintln!("{}", self.line(bar));
        }
    }

    /// A last line, whether due or not.
    pub fn finish(&self, bar: &ProgressBar) {
        if self.on {
            eprintln!("{}", self.line(bar));
        }
    }

    fn line(&self, bar: &ProgressBar) -> String {
        let start = self.clock.lock().unwrap_or_else(|e| e.into_inner()).0;
        log_line(
            &self.what,
            &self.unit,
            self.from.load(std::sync::atomic::Ordering::Relaxed),
            bar.position(),
            bar.length().unwrap_or(0),
            &bar.message(),
            start.elapsed().as_secs_f64(),
        )
    }
}

/// `gen: 500/2483 drapes (20%), 0 failed, 10m 0s, 1.2 s each, about 39m 40s to go`; below
/// one a second the rate is given as seconds each.  The share is rounded down, so 100% means
/// done. The rate counts from position `from` (where a resumed run started) at 0 seconds.
pub fn log_line(
    what: &str,
    unit: &str,
    from: u64,
    pos: u64,
    len: u64,
    msg: &str,
    seconds: f64,
) -> String {
    let mut s = format!("{what}: {pos}/{len} {unit}");
    if let Some(share) = (100 * pos).checked_div(len) {
        s.push_str(&format!(" ({share}%)"));
    }
    if !msg.is_empty() {
        s.push_str(&format!(", {msg}"));
    }
    s.push_str(&format!(", {}", clock(seconds)));
    let done = pos.saturating_sub(from);
    if done > 0 && seconds > 0.0 {
        let rate = done as f64 / seconds;
        if rate >= 1.0 {
            s.push_str(&format!(", {rate:.1} {unit}/s"));
        } else {
            s.push_str(&format!(", {:.1} s each", 1.0 / rate));
        }
        if pos < len {
            s.push_str(&format!(
                ", about {} to go",
                clock((len - pos) as f64 / rate)
            ));
        }
    }
    s
}

/// Seconds as `1h 2m`, `3m 4s` or `5s`.
fn clock(seconds: f64) -> String {
    let t = seconds.max(0.0).round() as u64;
    if t >= 3600 {
        format!("{}h {}m", t / 3600, t % 3600 / 60)
    } else if t >= 60 {
        format!("{}m {}s", t / 60, t % 60)
    } else {
        format!("{t}s")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The log line states position, share, message, elapsed time, rate and what is left,
    /// and leaves out the rate and the rest where they cannot be known; a resumed run's
    /// rate counts only what this process did.
    #[test]
    fn log_lines_read_as_the_bar() {
        let cases = [
            (
                ("gen", 0, 500, 2000, "3 failed", 600.0),
                "gen: 500/2000 drapes (25%), 3 failed, 10m 0s, 1.2 s each, about 30m 0s to go",
            ),
            (
                ("gen", 0, 1990, 2000, "", 100.0),
                "gen: 1990/2000 drapes (99%), 1m 40s, 19.9 drapes/s, about 1s to go",
            ),
            (("check", 0, 0, 50, "", 2.4), "check: 0/50 drapes (0%), 2s"),
            (
                ("gen", 0, 40, 40, "", 7300.0),
                "gen: 40/40 drapes (100%), 2h 1m, 182.5 s each",
            ),
            (
                ("gen", 1500, 1600, 2000, "", 120.0),
                "gen: 1600/2000 drapes (80%), 2m 0s, 1.2 s each, about 8m 0s to go",
            ),
            (
                ("gen", 1500, 1500, 2000, "", 5.0),
                "gen: 1500/2000 drapes (75%), 5s",
            ),
        ];
        for ((what, from, pos, len, msg, seconds), want) in cases {
            assert_eq!(log_line(what, "drapes", from, pos, len, msg, seconds), want);
        }
    }

    /// Lines are written only when asked for, and no more often than `every`.
    #[test]
    fn log_lines_are_rationed() {
        let off = LogLines::when(false, "gen", "drapes", std::time::Duration::ZERO);
        assert!(!off.due());
        let always = LogLines::when(true, "gen", "drapes", std::time::Duration::ZERO);
        assert!(always.due() && always.due());
        let hourly = LogLines::when(true, "gen", "drapes", std::time::Duration::from_secs(3600));
        assert!(
            !hourly.due(),
            "the first line is due an hour after the start"
        );
        // A bar meant to be shown but drawn nowhere (as on a log file) asks for lines, a
        // minute apart; a bar not meant to be shown asks for none.
        let bar = ProgressBar::hidden();
        let logged = LogLines::new(true, &bar, "gen", "drapes");
        assert!(logged.is_on() && !logged.due());
        assert!(!LogLines::new(false, &bar, "gen", "drapes").is_on());
        // A restart counts as a line written: the next is due `every` later.
        let minutely = LogLines::when(true, "gen", "drapes", std::time::Duration::from_secs(60));
        minutely.restart();
        assert!(!minutely.due());
        // A resumed bar's earlier steps are left out of the rate.
        let bar = ProgressBar::hidden();
        bar.set_length(100);
        bar.set_position(90);
        let resumed =
            LogLines::when(true, "train", "batches", std::time::Duration::ZERO).starting_at(90);
        assert!(resumed.is_on());
        assert!(
            resumed
                .line(&bar)
                .starts_with("train: 90/100 batches (90%), ")
        );
        assert!(
            !resumed.line(&bar).contains("to go"),
            "nothing done yet: no rate"
        );
    }

    /// A log with rows past the checkpoint: they are dropped before appending, the rest
    /// and the header stay; a log with nothing to drop is left as it is.
    #[test]
    fn append_after_drops_the_rows_past_the_checkpoint() {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        let p = dir.join("log.csv");
        std::fs::write(&p, "epoch,x\n0,a\n1,b\n2,c\n").unwrap();
        let epoch = |l: &str| l.split(',').next().unwrap().parse::<u32>().unwrap();
        let mut f = append_after(&p, "epoch,x", |l| epoch(l) < 2).unwrap();
        writeln!(f, "2,d").unwrap();
        drop(f);
        assert_eq!(
            std::fs::read_to_string(&p).unwrap(),
            "epoch,x\n0,a\n1,b\n2,d\n"
        );
        let f = append_after(&p, "epoch,x", |_| true).unwrap();
        drop(f);
        assert_eq!(
            std::fs::read_to_string(&p).unwrap(),
            "epoch,x\n0,a\n1,b\n2,d\n"
        );
        let q = dir.join("new.csv");
        drop(append_after(&q, "epoch,x", |_| false).unwrap());
        assert_eq!(std::fs::read_to_string(&q).unwrap(), "epoch,x\n");
    }
}
