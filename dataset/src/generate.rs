//! `drape gen`: drapes every sample of a dataset (or of one part of it) in parallel and
//! writes the shards, resumably.
//!
//! Files in the output folder (every one written atomically: a temporary file, then a
//! rename):
//!
//! - `static.safetensors`: template, faces, canonical body (`shard.rs`);
//! - `partial/SAMPLE.safetensors`: one finished drape, until its shard is assembled;
//! - `records/SHARD.json`: the samples of a finished shard with the simulator's reports and
//!   timings, and the shard's sha256;
//! - `SPLIT-NNNNN.safetensors`: the shards;
//! - `manifest.json` (or `manifest.part-I-of-N.json` for `--shard I/N`, joined by
//!   `drape data merge`);
//! - `.gen.lock` and `.gen.part-I-of-N.lock`: empty files that the running generation
//!   holds locks on, so that two runs never write one folder ([`lock_folder`]).
//!
//! Killing the program at any moment leaves only whole files; running it again skips the
//! shards and drapes already done, and ends with shards byte-identical to an uninterrupted
//! run's: a shard's bytes depend only on the config (each drape runs on one thread and the
//! solver is deterministic).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use sim::body::{BodyModel, PoseLibrary, ShapeParams};
use sim::cloth::drape::{self, BodyMorph};
use sim::garment::template::Template;

use crate::wardrobe::Wardrobe;

use crate::DatasetError;
use crate::config::{DatasetConfig, hex};
use crate::manifest::{Manifest, SampleRecord, ShardRecord};
use crate::plan::{Poser, ShardPlan, part, sample_plan, shards};
use crate::shard::{
    Reader, Row, STATIC_FILE, Static, encode_shard, read_rows, row_tensors, serialize,
};

/// Options of one generation run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GenOptions {
    /// This part (0-based) of `parts`.
    pub part: u32,
    /// Parts the dataset is split into (1: the whole dataset).
    pub parts: u32,
    /// Resume drapes made by another build of drape (refused by default: two builds drape
    /// differently); the manifest then records no program.
    pub mixed_builds: bool,
}

impl Default for GenOptions {
    fn default() -> Self {
        Self {
            part: 0,
            parts: 1,
            mixed_builds: false,
        }
    }
}

/// What a dataset folder was started with (`config.json`): the resolved config and its
/// sha256, the garment's own friction, friction below its band, substeps and crease
/// contacts (for a garment that has them) and the program's sha256 (absent in folders
/// started before they were recorded).
#[derive(Debug, Serialize, Deserialize)]
struct Stamp {
    config_sha256: String,
    config: serde_json::Value,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    garment_friction: Option<f32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    garment_substeps: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    garment_below_band: Option<sim::garment::def::BelowBand>,
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    garment_crease_contacts: bool,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    program_sha256: Option<String>,
}

/// Progress of a run, for a progress bar.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Event {
    /// Work found: `todo` drapes to run, `done` already finished (resumed).
    Start {
        /// Drapes to run now.
        todo: usize,
        /// Drapes found finished.
        done: usize,
    },
    /// One drape finished.
    Drape {
        /// Whether it converged.
        ok: bool,
    },
}

/// What a run did.
#[derive(Debug, Clone, PartialEq)]
pub struct GenSummary {
    /// The manifest written (whole dataset or this part).
    pub manifest_path: PathBuf,
    /// The manifest.
    pub manifest: Manifest,
    /// Drapes run by this invocation.
    pub draped_now: usize,
    /// Wall time of this invocation (s).
    pub seconds: f64,
}

/// Writes `bytes` to `path` through a temporary file and a rename.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), DatasetError> {
    sim::io::write_all_or_nothing(&[(path, bytes)]).map_err(|e| DatasetError::Io {
        path: path.to_path_buf(),
        source: e.source,
    })
}

/// sha256 of bytes, hex.
pub fn sha256(bytes: &[u8]) -> String {
    hex(&Sha256::digest(bytes))
}

/// The part manifest's file name.
pub fn manifest_name(o: GenOptions) -> String {
    if o.parts == 1 {
        "manifest.json".into()
    } else {
        format!("manifest.part-{}-of-{}.json", o.part, o.parts)
    }
}

/// A finished drape kept until its shard is assembled.
#[derive(Debug, Clone, Serialize, Deserialize)]
struct PartialMeta {
    record: SampleRecord,
}

/// Everything a drape needs, shared by the threads.
struct Job<'a> {
    config: &'a DatasetConfig,
    model: &'a BodyModel,
    wardrobe: &'a Wardrobe,
    poser: Poser,
    canonical: sim::body::ShapedBody<'a>,
}

impl<'a> Job<'a> {
    /// The poser and the canonical body for the garment in `wardrobe`.
    fn new(
        config: &'a DatasetConfig,
        model: &'a BodyModel,
        wardrobe: &'a Wardrobe,
        library: PoseLibrary,
    ) -> Result<Self, DatasetError> {
        Ok(Self {
            config,
            model,
            wardrobe,
            poser: Poser::new(config, model, library)?,
            canonical: model.shape(&ShapeParams::default())?,
        })
    }

    /// Drapes sample `id`: a row (None if the drape failed) and its record.
    fn run(&self, id: u64) -> Result<(Option<Row>, SampleRecord), DatasetError> {
        let t0 = Instant::now();
        let c = self.config;
        let plan = sample_plan(c, id);
        let drawn = self.poser.draw(c, self.model, &plan)?;
        let shaped = self.model.shape(&drawn.shape)?;
        let posed = shaped.pose(&drawn.pose);
        let warped = self.wardrobe.base.warp(&self.canonical, &shaped, &posed);
        let warp_seconds = t0.elapsed().as_secs_f64();
        // The drape starts from the body's size on that size's reference body.
        let start = self.wardrobe.start(&shaped)?;
        let motion = BodyMorph::new(
            self.model,
            start.reference,
            drawn.shape,
            drawn.pose.clone(),
            &c.sim,
        )?;
        // One thread per drape: threads go across drapes, and the bits do not depend on it.
        let mut d = drape::drape(
            start.cloth,
            &start.template.mesh.vertices,
            &motion,
            &c.sim,
            false,
            &mut |_| {},
        );
        // A drape that came to rest off the body (trousers at the feet) is a failure too.
        d.judge_slide(self.wardrobe.top_opening(), &warped);
        let ok = d.report.converged;
        let record = SampleRecord {
            plan,
            family: drawn.family.clone(),
            pose_source: drawn.pose_source.clone(),
            shape: drawn.shape.values(),
            size: start.size.map(String::from),
            ok,
            failure: d.report.failure.map(|f| f.to_string()),
            report: serde_json::to_value(&d.report).expect("reports serialise"),
            warp_seconds,
            seconds: t0.elapsed().as_secs_f64(),
        };
        let row = ok.then(|| Row {
            id,
            body: posed.vertices.clone(),
            warped,
            draped: d.positions,
            shape: record.shape,
            pose: drawn.pose.rotations.clone(),
            root: drawn.pose.root_translation,
        });
        Ok((row, record))
    }
}

/// Body vertices, garment vertices, bones: the sizes every row has.
type Dims = (usize, usize, usize);

fn partial_path(dir: &Path, id: u64) -> PathBuf {
    dir.join("partial").join(format!("{id:08}.safetensors"))
}

fn record_path(dir: &Path, shard: &str) -> PathBuf {
    dir.join("records")
        .join(shard.replace(".safetensors", ".json"))
}

/// A finished drape: its row (none if it failed) as the shard tensors, its record as
/// metadata.
fn encode_partial(row: Option<Row>, record: &SampleRecord, dims: Dims) -> Vec<u8> {
    let (nb, n, bones) = dims;
    serialize(
        &row_tensors(row.as_slice(), nb, n, bones),
        &PartialMeta {
            record: record.clone(),
        },
    )
}

fn decode_partial(
    path: &Path,
    bytes: &[u8],
    dims: Dims,
) -> Result<(Option<Row>, SampleRecord), DatasetError> {
    let (nb, n, bones) = dims;
    let meta: PartialMeta = Reader::meta(bytes, path)?;
    let ids: &[u64] = if meta.record.ok {
        &[meta.record.plan.id]
    } else {
        &[]
    };
    let mut rows = read_rows(&Reader::new(path, bytes)?, ids, nb, n, bones)?;
    Ok((rows.pop(), meta.record))
}

/// Loads the body model, the pose library and the garment template for a config.
pub fn load_inputs(
    config: &DatasetConfig,
    assets: &Path,
    built: &mut dyn FnMut(&str),
) -> Result<(BodyModel, PoseLibrary, Template), DatasetError> {
    let model = BodyModel::load_from_dir(assets)?;
    let library = PoseLibrary::from_toml(
        &model.skeleton,
        sim::body::pose::LIBRARY_TOML,
        &model.t_pose,
    )?;
    let lib = sim::garment::Library::new(assets);
    let template = lib.get(&config.garment, config.resolution, &model, built)?;
    Ok((model, library, template))
}

/// Drapes samples `ids` of `config` again, exactly as `drape gen` did (the same plan,
/// body, pose, template and simulator config; one drape per thread), without writing
/// anything: rows (`None` for a failed drape) and records, in the order of `ids`.
pub fn redrape(
    config: &DatasetConfig,
    assets: &Path,
    ids: &[u64],
) -> Result<Vec<(Option<Row>, SampleRecord)>, DatasetError> {
    use rayon::prelude::*;
    let range = config.sample_ids();
    if let Some(bad) = ids.iter().find(|&&id| !range.contains(&id)) {
        return Err(DatasetError::Invalid(format!(
            "sample {bad} does not exist: {}'s samples are {} to {}",
            config.name,
            range.start,
            range.end - 1
        )));
    }
    let (model, library, template) = load_inputs(config, assets, &mut |_| {})?;
    let wardrobe = Wardrobe::new(template, config, &model, assets, &mut |_| {})?;
    let job = Job::new(config, &model, &wardrobe, library)?;
    ids.par_iter().map(|&id| job.run(id)).collect()
}

/// Assembles a shard whose samples are all finished: writes the shard, then its record,
/// then removes the partial files.
fn assemble(dir: &Path, shard: &ShardPlan, dims: Dims) -> Result<ShardRecord, DatasetError> {
    let mut rows = Vec::new();
    let mut samples = Vec::new();
    for &id in &shard.samples {
        let p = partial_path(dir, id);
        let bytes = std::fs::read(&p).map_err(|e| DatasetError::Io {
            path: p.clone(),
            source: e,
        })?;
        let (row, record) = decode_partial(&p, &bytes, dims)?;
        rows.extend(row);
        samples.push(record);
    }
    let (nb, n, bones) = dims;
    let bytes = encode_shard(shard.split.name(), &rows, nb, n, bones);
    write_atomic(&dir.join(&shard.file), &bytes)?;
    let record = ShardRecord {
        file: shard.file.clone(),
        split: shard.split,
        rows: rows.len(),
        bytes: bytes.len() as u64,
        sha256: sha256(&bytes),
        samples,
    };
    write_atomic(
        &record_path(dir, &shard.file),
        &serde_json::to_vec_pretty(&record).expect("json"),
    )?;
    for &id in &shard.samples {
        let _ = std::fs::remove_file(partial_path(dir, id));
    }
    Ok(record)
}

/// The lock file of a whole run; a part's run holds it shared.
const LOCK_FILE: &str = ".gen.lock";

/// Takes the folder's locks for this run, so that two runs never write the same files:
///
/// - a whole run holds [`LOCK_FILE`] alone;
/// - a part's run (`--shard I/N`) holds it shared with the other parts (a cluster job's
///   parts may write into one folder at once), its own `.gen.part-I-of-N.lock` alone and
///   `.gen.parts-N.lock` shared; it then refuses the folder if a part of another split
///   (another N, whose shards overlap this one's) holds its `.gen.parts-M.lock`. Of two
///   such runs starting at once, at least one is refused.
///
/// Operating-system locks on open files: they end with the process, however it ends, so
/// no stale lock is ever left to remove. On a file system that cannot lock (some network
/// mounts) the run goes on without the guard and `log` says so. Creates `dir` if it is
/// missing.
pub fn lock_folder(
    dir: &Path,
    opts: GenOptions,
    log: &mut dyn FnMut(&str),
) -> Result<Vec<std::fs::File>, DatasetError> {
    let io = |path: PathBuf| move |source| DatasetError::Io { path, source };
    std::fs::create_dir_all(dir).map_err(io(dir.to_path_buf()))?;
    let open = |name: &str| {
        let path = dir.join(name);
        std::fs::File::options()
            .create(true)
            .truncate(false)
            .write(true)
            .open(&path)
            .map_err(io(path))
    };
    let busy = |what: &str| {
        DatasetError::Invalid(format!(
            "another drape gen is writing {what} into {}; wait for it to finish or stop it \
             (its lock ends with its process)",
            dir.display()
        ))
    };
    let mut unguarded = None;
    // Ok(true): locked; Ok(false): another process holds it.
    let mut take = |name: &str, shared: bool| -> Result<(std::fs::File, bool), DatasetError> {
        let file = open(name)?;
        let taken = if shared {
            file.try_lock_shared()
        } else {
            file.try_lock()
        };
        match taken {
            Ok(()) => Ok((file, true)),
            Err(std::fs::TryLockError::WouldBlock) => Ok((file, false)),
            Err(std::fs::TryLockError::Error(e)) => {
                unguarded.get_or_insert(format!("{}: {e}", dir.join(name).display()));
                Ok((file, true))
            }
        }
    };
    let mut held = Vec::new();
    let (whole, ok) = take(LOCK_FILE, opts.parts > 1)?;
    if !ok {
        return Err(busy(if opts.parts == 1 {
            "this dataset or one of its parts"
        } else {
            "the whole dataset"
        }));
    }
    held.push(whole);
    if opts.parts > 1 {
        let (mine, ok) = take(
            &format!(".gen.part-{}-of-{}.lock", opts.part, opts.parts),
            false,
        )?;
        if !ok {
            return Err(busy(&format!("part {}/{}", opts.part, opts.parts)));
        }
        held.push(mine);
        let split = format!(".gen.parts-{}.lock", opts.parts);
        let (ours, _) = take(&split, true)?;
        held.push(ours);
        let others: Vec<String> = std::fs::read_dir(dir)
            .map_err(io(dir.to_path_buf()))?
            .flatten()
            .map(|e| e.file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with(".gen.parts-") && n.ends_with(".lock") && *n != split)
            .collect();
        for name in others {
            // Free unless a part of that split is running; the probe's lock ends with
            // its file, at the end of this iteration.
            let (_probe, ok) = take(&name, false)?;
            if !ok {
                let m = name
                    .trim_start_matches(".gen.parts-")
                    .trim_end_matches(".lock");
                return Err(busy(&format!(
                    "parts of another split (--shard I/{m}, whose shards overlap part {}/{})",
                    opts.part, opts.parts
                )));
            }
        }
    }
    if let Some(why) = unguarded {
        log(&format!(
            "warning: cannot lock the folder ({why}); running without the guard against a second drape gen writing into it"
        ));
    }
    Ok(held)
}

/// Whether `dir` holds anything but what a start of `drape gen` stopped before its
/// config.json leaves: empty `partial/` and `records/` folders, temporary files and the
/// lock files.
fn holds_other_files(dir: &Path) -> bool {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return false;
    };
    entries.flatten().any(|e| {
        let name = e.file_name().to_string_lossy().into_owned();
        let empty_dir =
            || std::fs::read_dir(e.path()).is_ok_and(|mut inner| inner.next().is_none());
        let ours = ((name == "partial" || name == "records") && empty_dir())
            || (name.starts_with('.') && (name.ends_with(".tmp") || name.ends_with(".lock")));
        !ours
    })
}

/// Whether `dir` holds finished drapes: partial drapes or shard records.
fn holds_drapes(dir: &Path) -> bool {
    ["partial", "records"].iter().any(|sub| {
        std::fs::read_dir(dir.join(sub)).is_ok_and(|mut entries| entries.next().is_some())
    })
}

/// How far the generation of `config` into `dir` has come, without locking the folder (a
/// running `drape gen` may hold it): the drapes finished (those of shards with a record
/// and those waiting in `partial/`, converged or not) and the dataset's total. Counts
/// files only. An error if the folder was started with another config (its `config.json`
/// names another hash), whose drapes `drape gen` would refuse to resume.
pub fn drapes_done(config: &DatasetConfig, dir: &Path) -> Result<(usize, usize), DatasetError> {
    let stamp_path = dir.join("config.json");
    if let Ok(bytes) = std::fs::read(&stamp_path) {
        let stamp: Stamp = serde_json::from_slice(&bytes)
            .map_err(|e| DatasetError::Invalid(format!("{}: {e}", stamp_path.display())))?;
        if stamp.config_sha256 != config.hash() {
            return Err(DatasetError::Invalid(format!(
                "{} holds drapes of another config (sha256 {}, not {})",
                dir.display(),
                &stamp.config_sha256[..12.min(stamp.config_sha256.len())],
                &config.hash()[..12]
            )));
        }
    }
    let all = shards(config);
    let total = all.iter().map(|s| s.samples.len()).sum();
    let done = all
        .iter()
        .map(|s| {
            if record_path(dir, &s.file).is_file() && dir.join(&s.file).is_file() {
                s.samples.len()
            } else {
                s.samples
                    .iter()
                    .filter(|&&id| partial_path(dir, id).is_file())
                    .count()
            }
        })
        .sum();
    Ok((done, total))
}

/// Runs (or resumes) the generation of `config` into `dir`.
pub fn generate(
    config: &DatasetConfig,
    dir: &Path,
    assets: &Path,
    opts: GenOptions,
    log: &mut dyn FnMut(&str),
    progress: &(dyn Fn(Event) + Sync),
) -> Result<GenSummary, DatasetError> {
    let t0 = Instant::now();
    if opts.parts == 0 || opts.part >= opts.parts {
        return Err(DatasetError::Invalid(format!(
            "part {} of {} does not exist (parts are 0 to {})",
            opts.part,
            opts.parts,
            opts.parts.saturating_sub(1)
        )));
    }
    // A folder holds one dataset: refuse another config (before any work), another
    // garment material or drapes of another build. A folder of other files is refused
    // before its lock file is written into it, and again once locked.
    let stamp_path = dir.join("config.json");
    let foreign = || !stamp_path.exists() && holds_other_files(dir);
    let _locks = if foreign() {
        Vec::new()
    } else {
        lock_folder(dir, opts, log)?
    };
    if foreign() {
        return Err(DatasetError::Invalid(
            if dir.join("manifest.json").exists() {
                format!(
                    "{} holds a dataset not made here by drape gen (a manifest.json, no config.json: merged by drape data merge?); use a new or empty folder",
                    dir.display()
                )
            } else {
                format!(
                    "{} is not empty and holds no dataset (no config.json); use a new or empty folder",
                    dir.display()
                )
            },
        ));
    }
    let old: Option<Stamp> = match std::fs::read(&stamp_path) {
        Ok(bytes) => Some(
            serde_json::from_slice(&bytes)
                .map_err(|e| DatasetError::Invalid(format!("{}: {e}", stamp_path.display())))?,
        ),
        Err(_) => None,
    };
    let refuse = |what: &str| {
        DatasetError::Invalid(format!(
            "{} holds a dataset of another {what} ({}); use a new folder",
            dir.display(),
            stamp_path.display()
        ))
    };
    let stamp = Stamp {
        config_sha256: config.hash(),
        config: config.resolved_json(),
        garment_friction: None,
        garment_substeps: None,
        garment_below_band: None,
        garment_crease_contacts: false,
        program_sha256: crate::manifest::program_sha256(),
    };
    // The stored config compared as read back from text: serde_json's parser does not
    // always give back the exact f64 it printed (an f32 0.03 printed as
    // 0.029999999329447746 read back one ulp off), so this config goes through the same
    // printing and parsing.
    let as_read: serde_json::Value =
        serde_json::from_str(&serde_json::to_string(&stamp.config).expect("configs serialise"))
            .expect("printed JSON parses");
    // A folder that holds no drapes yet (a start that failed before its first drape, on a
    // bad pose folder say) is taken over by this config.
    let old = old.filter(|_| holds_drapes(dir));
    if old
        .as_ref()
        .is_some_and(|o| o.config_sha256 != stamp.config_sha256 || o.config != as_read)
    {
        return Err(refuse("config"));
    }
    let (model, library, template) = load_inputs(config, assets, log)?;
    let stamp = Stamp {
        garment_friction: template.meta.friction,
        garment_substeps: template.meta.substeps,
        garment_below_band: template.meta.below_band,
        garment_crease_contacts: template.meta.crease_contacts,
        ..stamp
    };
    // Whether the drapes of this folder all come from this program.
    let mut one_build = true;
    if let Some(o) = &old {
        if o.garment_friction != stamp.garment_friction
            || o.garment_below_band != stamp.garment_below_band
        {
            return Err(refuse("garment material (its own friction or its band)"));
        }
        if o.garment_substeps != stamp.garment_substeps {
            return Err(refuse("garment's own substeps (its `[simulation]`)"));
        }
        if o.garment_crease_contacts != stamp.garment_crease_contacts {
            return Err(refuse("garment's own crease contacts (its `[simulation]`)"));
        }
        if o.program_sha256 != stamp.program_sha256 && holds_drapes(dir) {
            if o.program_sha256.is_some() && !opts.mixed_builds {
                return Err(DatasetError::Invalid(format!(
                    "{} holds drapes made by another build of drape (program sha256 {} in {}, this one {}); two builds drape differently by up to 15 mm (docs/datasets.md): resume with that binary, use a new folder, or pass --mixed-builds",
                    dir.display(),
                    crate::manifest::short_sha(&o.program_sha256),
                    stamp_path.display(),
                    crate::manifest::short_sha(&stamp.program_sha256)
                )));
            }
            one_build = false;
        }
    }
    for sub in ["", "partial", "records"] {
        let d = dir.join(sub);
        std::fs::create_dir_all(&d).map_err(|e| DatasetError::Io { path: d, source: e })?;
    }
    if old.is_none() {
        write_atomic(
            &stamp_path,
            &serde_json::to_vec_pretty(&stamp).expect("json"),
        )?;
    }
    let wardrobe = Wardrobe::new(template, config, &model, assets, log)?;
    let template = &wardrobe.base;
    let job = Job::new(config, &model, &wardrobe, library)?;
    let dims: Dims = (
        job.canonical.vertices.len(),
        template.mesh.vertices.len(),
        model.skeleton.len(),
    );
    let st = Static::new(&template.mesh, &model, &job.canonical.vertices);
    let static_bytes = st.encode();
    let static_path = dir.join(STATIC_FILE);
    let old_static = std::fs::read(&static_path).ok();
    if old_static.as_ref().is_some_and(|b| *b != static_bytes) && holds_drapes(dir) {
        return Err(DatasetError::Invalid(format!(
            "{} holds drapes of another {} template ({} differs from the one built now: the definition or the build code changed); use a new folder",
            dir.display(),
            config.garment,
            static_path.display()
        )));
    }
    if old_static.as_deref() != Some(&static_bytes[..]) {
        write_atomic(&static_path, &static_bytes)?;
    }

    let all = shards(config);
    let mine = part(&all, opts.part, opts.parts);
    // What is finished already.
    let mut records: BTreeMap<String, ShardRecord> = BTreeMap::new();
    let mut todo: Vec<u64> = Vec::new();
    let mut resumed = 0usize;
    for s in &mine {
        let rp = record_path(dir, &s.file);
        if let (Ok(text), true) = (std::fs::read(&rp), dir.join(&s.file).exists())
            && let Ok(r) = serde_json::from_slice::<ShardRecord>(&text)
        {
            resumed += s.samples.len();
            records.insert(s.file.clone(), r);
            continue;
        }
        for &id in &s.samples {
            let p = partial_path(dir, id);
            let good = std::fs::read(&p)
                .ok()
                .is_some_and(|b| decode_partial(&p, &b, dims).is_ok());
            if good {
                resumed += 1;
            } else {
                todo.push(id);
            }
        }
    }
    progress(Event::Start {
        todo: todo.len(),
        done: resumed,
    });

    // Shards still missing samples, with the count missing.
    let shard_of: BTreeMap<u64, usize> = mine
        .iter()
        .enumerate()
        .flat_map(|(k, s)| s.samples.iter().map(move |&id| (id, k)))
        .collect();
    let missing: Vec<AtomicUsize> = mine.iter().map(|_| AtomicUsize::new(0)).collect();
    for id in &todo {
        missing[shard_of[id]].fetch_add(1, Ordering::Relaxed);
    }
    let done_records = Mutex::new(records);
    let assemble_if_done = |k: usize| -> Result<(), DatasetError> {
        let s = &mine[k];
        if done_records.lock().expect("lock").contains_key(&s.file) {
            return Ok(());
        }
        let r = assemble(dir, s, dims)?;
        done_records.lock().expect("lock").insert(s.file.clone(), r);
        Ok(())
    };

    use rayon::prelude::*;
    let draped_now = todo.len();
    todo.par_iter()
        .try_for_each(|&id| -> Result<(), DatasetError> {
            let (row, record) = job.run(id)?;
            progress(Event::Drape { ok: record.ok });
            write_atomic(&partial_path(dir, id), &encode_partial(row, &record, dims))?;
            let k = shard_of[&id];
            if missing[k].fetch_sub(1, Ordering::AcqRel) == 1 {
                assemble_if_done(k)?;
            }
            Ok(())
        })?;
    // Shards whose drapes were all finished before this run.
    for k in 0..mine.len() {
        assemble_if_done(k)?;
    }

    let records = done_records.into_inner().expect("lock");
    let mut manifest = Manifest::new(
        config,
        opts,
        sha256(&static_bytes),
        mine.iter().map(|s| records[&s.file].clone()).collect(),
    );
    manifest.size_templates = wardrobe.size_fingerprints();
    manifest.friction = Some(wardrobe.friction());
    manifest.below_band = wardrobe.below_band();
    manifest.garment_substeps = wardrobe.substeps();
    manifest.garment_crease_contacts = wardrobe.crease_contacts();
    manifest.program_sha256 = stamp.program_sha256.clone().filter(|_| one_build);
    let manifest_path = dir.join(manifest_name(opts));
    write_atomic(
        &manifest_path,
        &serde_json::to_vec_pretty(&manifest).expect("json"),
    )?;
    if opts.parts == 1 {
        let _ = std::fs::remove_dir(dir.join("partial"));
    }
    Ok(GenSummary {
        manifest_path,
        manifest,
        draped_now,
        seconds: t0.elapsed().as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn drapes_done_counts_recorded_shards_and_partial_drapes() {
        let c = DatasetConfig::load("tiny").unwrap();
        let all = shards(&c);
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path();
        // 4 bodies x 2 poses; an empty folder or none at all: nothing done.
        assert_eq!(drapes_done(&c, dir).unwrap(), (0, 8));
        assert_eq!(drapes_done(&c, &dir.join("none")).unwrap(), (0, 8));
        std::fs::create_dir_all(dir.join("partial")).unwrap();
        std::fs::create_dir_all(dir.join("records")).unwrap();
        // The first train shard finished (its record and its file), one drape of the
        // second waiting in partial/.
        let (first, second) = (&all[0], &all[1]);
        assert_eq!(first.samples.len(), 3);
        std::fs::write(dir.join(&first.file), b"").unwrap();
        std::fs::write(record_path(dir, &first.file), b"{}").unwrap();
        std::fs::write(partial_path(dir, second.samples[0]), b"").unwrap();
        assert_eq!(drapes_done(&c, dir).unwrap(), (4, 8));
        // A record without its shard is not a finished shard; its drapes are not in
        // partial/ any more, so they count as not done.
        std::fs::remove_file(dir.join(&first.file)).unwrap();
        assert_eq!(drapes_done(&c, dir).unwrap(), (1, 8));
        // Started with this config: counted; with another: an error naming it.
        let stamp = |hash: String| {
            serde_json::to_vec(&Stamp {
                config_sha256: hash,
                config: c.resolved_json(),
                garment_friction: None,
                garment_substeps: None,
                garment_below_band: None,
                garment_crease_contacts: false,
                program_sha256: None,
            })
            .unwrap()
        };
        std::fs::write(dir.join("config.json"), stamp(c.hash())).unwrap();
        assert_eq!(drapes_done(&c, dir).unwrap(), (1, 8));
        std::fs::write(dir.join("config.json"), stamp("ab".repeat(32))).unwrap();
        let e = drapes_done(&c, dir).unwrap_err().to_string();
        assert!(
            e.contains("holds drapes of another config (sha256 abababababab"),
            "{e}"
        );
    }
}
