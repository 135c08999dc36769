//! Reading a dataset: `Dataset::open(dir)`, then `samples(split)` iterates one shard at a
//! time (only one shard is in memory).

use std::path::{Path, PathBuf};

use crate::DatasetError;
use crate::config::Split;
use crate::generate::sha256;
use crate::manifest::{Manifest, SampleRecord};
use crate::shard::{Row, STATIC_FILE, Static, decode_shard};

/// An opened dataset.
#[derive(Debug, Clone)]
pub struct Dataset {
    /// Its folder.
    pub dir: PathBuf,
    /// The manifest.
    pub manifest: Manifest,
    /// Template, faces and canonical body.
    pub statics: Static,
}

/// One sample: its row and its manifest record.
#[derive(Debug, Clone)]
pub struct Sample {
    /// Arrays.
    pub row: Row,
    /// Seeds, split, report.
    pub record: SampleRecord,
}

impl Dataset {
    /// Opens `dir/manifest.json` and `dir/static.safetensors`. A dataset generated in parts
    /// must be merged first (`drape data merge`).
    pub fn open(dir: &Path) -> Result<Self, DatasetError> {
        let mp = dir.join("manifest.json");
        let text = std::fs::read(&mp).map_err(|e| {
            let part = std::fs::read_dir(dir).is_ok_and(|entries| {
                entries.flatten().any(|e| {
                    e.file_name()
                        .to_string_lossy()
                        .starts_with("manifest.part-")
                })
            });
            let hint = if part {
                " (a dataset generated with --shard needs `drape data merge` first)"
            } else if dir.join("config.json").is_file() {
                " (its generation has not finished: the same `drape gen` command resumes it)"
            } else if !dir.exists() {
                " (there is no such folder: give a dataset folder, one `drape gen` wrote)"
            } else if dir.join("config.toml").is_file() && dir.join("run.json").is_file() {
                " (that is a training run's folder, not a dataset's)"
            } else {
                ""
            };
            DatasetError::Invalid(format!("cannot read {}: {e}{hint}", mp.display()))
        })?;
        let manifest = Manifest::parse(&mp, &text)?;
        let sp = dir.join(STATIC_FILE);
        let bytes = std::fs::read(&sp).map_err(|e| DatasetError::Io {
            path: sp.clone(),
            source: e,
        })?;
        if sha256(&bytes) != manifest.static_sha256 {
            return Err(DatasetError::Corrupt {
                path: sp,
                reason: "sha256 differs from the manifest's".into(),
            });
        }
        let statics = Static::decode(&sp, &bytes)?;
        Ok(Self {
            dir: dir.to_path_buf(),
            manifest,
            statics,
        })
    }

    /// Reads and checks one shard (sha256 against the manifest, shapes, finite values).
    pub fn read_shard(&self, file: &str) -> Result<Vec<Row>, DatasetError> {
        let rec = self
            .manifest
            .shards
            .iter()
            .find(|s| s.file == file)
            .ok_or_else(|| DatasetError::Invalid(format!("no shard {file} in the manifest")))?;
        let path = self.dir.join(file);
        let bytes = std::fs::read(&path).map_err(|e| DatasetError::Io {
            path: path.clone(),
            source: e,
        })?;
        if bytes.len() as u64 != rec.bytes || sha256(&bytes) != rec.sha256 {
            return Err(DatasetError::Corrupt {
                path,
                reason: format!(
                    "{} bytes, sha256 {}; the manifest says {} bytes, sha256 {} (truncated or altered)",
                    bytes.len(),
                    &sha256(&bytes)[..12],
                    rec.bytes,
                    &rec.sha256[..12.min(rec.sha256.len())]
                ),
            });
        }
        let s = &self.statics;
        let (meta, rows) = decode_shard(
            &path,
            &bytes,
            s.canonical_body.len(),
            s.garment_vertices.len(),
            s.bones,
        )?;
        let expect: Vec<u64> = rec
            .samples
            .iter()
            .filter(|r| r.ok)
            .map(|r| r.plan.id)
            .collect();
        if meta.ids != expect || meta.split != rec.split.name() {
            return Err(DatasetError::Corrupt {
                path,
                reason: "its samples disagree with the manifest".into(),
            });
        }
        Ok(rows)
    }

    /// The converged samples of a split, one shard in memory at a time.
    pub fn samples(&self, split: Split) -> impl Iterator<Item = Result<Sample, DatasetError>> + '_ {
        self.manifest
            .shards
            .iter()
            .filter(move |s| s.split == split)
            .flat_map(move |s| {
                let rows = self.read_shard(&s.file);
                let records: Vec<SampleRecord> =
                    s.samples.iter().filter(|r| r.ok).cloned().collect();
                let out: Vec<Result<Sample, DatasetError>> = match rows {
                    Err(e) => vec![Err(e)],
                    Ok(rows) => rows
                        .into_iter()
                        .zip(records)
                        .map(|(row, record)| Ok(Sample { row, record }))
                        .collect(),
                };
                out.into_iter()
            })
    }

    /// Converged samples of a split (from the manifest, without reading shards).
    pub fn count(&self, split: Split) -> usize {
        self.manifest
            .samples()
            .filter(|s| s.plan.split == split && s.ok)
            .count()
    }
}
