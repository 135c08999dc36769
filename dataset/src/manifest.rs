//! The manifest (`manifest.json`): the resolved config, program version and git revision,
//! every sample with its seed, split and simulator report, every shard with its sha256.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::config::{DatasetConfig, Split};
use crate::generate::GenOptions;
use crate::plan::SamplePlan;

/// Format tag of manifests.
pub const MANIFEST_FORMAT: &str = "drape-dataset/1";

/// The git revision the program was built from ("unknown" outside a checkout).
pub const GIT_REVISION: &str = env!("DRAPE_GIT_REVISION");

/// A git revision shortened to 12 hex digits, keeping a `-dirty` mark.
pub fn short_revision(rev: &str) -> String {
    let commit = rev.trim_end_matches("-dirty");
    let short = commit.get(..12).unwrap_or(commit);
    if commit.len() < rev.len() {
        format!("{short}-dirty")
    } else {
        short.to_string()
    }
}

/// The first 12 hex digits of a sha256, or `not recorded`.
pub fn short_sha(sha: &Option<String>) -> String {
    sha.as_deref()
        .map_or("not recorded".to_string(), |s| short_hex(s).to_string())
}

/// The first 12 hex digits of a sha256 (all of a shorter string).
pub fn short_hex(sha: &str) -> &str {
    &sha[..sha.len().min(12)]
}

/// One sample.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SampleRecord {
    /// Id, split, body, pose number and seeds (flattened into the record's JSON).
    #[serde(flatten)]
    pub plan: SamplePlan,
    /// Pose family.
    pub family: String,
    /// How the pose was made.
    pub pose_source: String,
    /// Shape parameters (`shard::SHAPE_FIELDS` order).
    pub shape: [f32; 9],
    /// The garment size the body wore (datasets with `sizes = true`; absent otherwise).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub size: Option<String>,
    /// Whether the drape converged (failed drapes are left out of the shards).
    pub ok: bool,
    /// Why it failed.
    pub failure: Option<String>,
    /// The simulator's report (`sim::cloth::DrapeReport` as JSON).
    pub report: serde_json::Value,
    /// Time of the DQS warp (s).
    pub warp_seconds: f64,
    /// Time of the whole sample: warp and drape (s, one thread).
    pub seconds: f64,
}

/// One shard.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShardRecord {
    /// File name.
    pub file: String,
    /// Split.
    pub split: Split,
    /// Rows (converged samples).
    pub rows: usize,
    /// Size (bytes).
    pub bytes: u64,
    /// sha256 of the file.
    pub sha256: String,
    /// Every sample planned into the shard, failed ones included.
    pub samples: Vec<SampleRecord>,
}

/// The manifest of a dataset or of one part of it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Manifest {
    /// [`MANIFEST_FORMAT`].
    pub format: String,
    /// Dataset name.
    pub name: String,
    /// drape's version.
    pub program_version: String,
    /// Git revision of the program.
    pub git_revision: String,
    /// sha256 of the resolved config's JSON.
    pub config_sha256: String,
    /// The resolved config.
    pub config: serde_json::Value,
    /// Part (0-based) of `parts`; a merged or whole dataset is part 0 of 1.
    pub part: u32,
    /// Parts.
    pub parts: u32,
    /// sha256 of `static.safetensors`.
    pub static_sha256: String,
    /// With `sizes`: each size's sha256 of its template's vertex positions (f32
    /// little-endian), so a redrape can check it grades the same sizes (absent otherwise).
    #[serde(default, skip_serializing_if = "BTreeMap::is_empty")]
    pub size_templates: BTreeMap<String, String>,
    /// Friction between the garment and the body the drapes ran with: the garment's own
    /// (its definition's `[material]`) or the simulator config's (absent in manifests
    /// written before it was recorded: the config's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub friction: Option<f32>,
    /// The garment's friction below a band along its top opening (its definition's
    /// `[material] below_band`), absent when `friction` held everywhere.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub below_band: Option<sim::garment::def::BelowBand>,
    /// The garment's own substeps a frame the drapes ran with (its definition's
    /// `[simulation]`), absent when they ran at the simulator config's.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub garment_substeps: Option<u32>,
    /// Whether the garment's own `[simulation] crease_contacts` was on (it counts where the
    /// simulator config leaves them unset); absent when off, and in manifests written
    /// before it existed (session 46), when no garment had it.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub garment_crease_contacts: bool,
    /// sha256 of the program that draped (`drape`'s executable; absent in manifests
    /// written before it was recorded). Two builds of the same source drape differently
    /// (by up to 15 mm: docs/datasets.md), so `drape data merge` joins only parts of one.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub program_sha256: Option<String>,
    /// Shards, in plan order.
    pub shards: Vec<ShardRecord>,
}

/// sha256 of the running executable, hex (`None` if it cannot be read); computed once, at
/// the first call (`drape gen` calls it before it drapes).
pub fn program_sha256() -> Option<String> {
    static SHA: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();
    SHA.get_or_init(|| {
        use sha2::{Digest, Sha256};
        // /proc/self/exe opens the running file even after a rebuild replaced it.
        let mut file = std::fs::File::open("/proc/self/exe")
            .or_else(|_| std::fs::File::open(std::env::current_exe()?))
            .ok()?;
        let mut h = Sha256::new();
        std::io::copy(&mut file, &mut h).ok()?;
        Some(crate::config::hex(&h.finalize()))
    })
    .clone()
}

/// Failure counts of a group of samples.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Tally {
    /// Samples.
    pub samples: usize,
    /// Failed drapes.
    pub failed: usize,
}

impl Tally {
    /// Share failed.
    pub fn rate(&self) -> f64 {
        if self.samples == 0 {
            0.0
        } else {
            self.failed as f64 / self.samples as f64
        }
    }
}

impl Manifest {
    /// Parses a manifest file's bytes; a broken file or another format is named.
    pub fn parse(path: &std::path::Path, bytes: &[u8]) -> Result<Self, crate::DatasetError> {
        let corrupt = |reason: String| crate::DatasetError::Corrupt {
            path: path.to_path_buf(),
            reason,
        };
        let m: Manifest = serde_json::from_slice(bytes).map_err(|e| corrupt(e.to_string()))?;
        if m.format != MANIFEST_FORMAT {
            return Err(corrupt(format!(
                "format {:?}, expected {MANIFEST_FORMAT:?}",
                m.format
            )));
        }
        Ok(m)
    }

    /// A manifest of finished shards.
    pub fn new(
        config: &DatasetConfig,
        opts: GenOptions,
        static_sha256: String,
        shards: Vec<ShardRecord>,
    ) -> Self {
        Self {
            format: MANIFEST_FORMAT.into(),
            name: config.name.clone(),
            program_version: env!("CARGO_PKG_VERSION").into(),
            git_revision: GIT_REVISION.into(),
            config_sha256: config.hash(),
            config: config.resolved_json(),
            part: opts.part,
            parts: opts.parts,
            static_sha256,
            size_templates: BTreeMap::new(),
            friction: None,
            below_band: None,
            garment_substeps: None,
            garment_crease_contacts: false,
            program_sha256: None,
            shards,
        }
    }

    /// sha256 of what a network trains on, hex: the config's hash, `static.safetensors`'s
    /// and every shard's file, split, rows and sha256, in plan order. Two makings of one
    /// config by one build give the same drapes, byte for byte, and so the same value, where
    /// the manifest files differ (each records its git revision, its program's sha256 and
    /// its drapes' stage times). A run resumes on data with this value
    /// (`learn::run::prepare_folder`), so a dataset made again on a fresh machine serves.
    pub fn drapes_sha256(&self) -> String {
        let mut text = format!(
            "drapes of config {}, static {}\n",
            self.config_sha256, self.static_sha256
        );
        for s in &self.shards {
            text.push_str(&format!(
                "{} {} {} {}\n",
                s.file,
                s.split.name(),
                s.rows,
                s.sha256
            ));
        }
        crate::generate::sha256(text.as_bytes())
    }

    /// The config back. A simulator config written before `stretch_iterations` existed
    /// ran one stretch sweep per substep, so a manifest without the field reads as 1, not
    /// as today's default. One written before session 15 had no paced morph and no check
    /// for cloth caught on the body: without `max_morph_speed` and `max_edge_penetration`
    /// both read as off (1e9). Its morph then keeps `morph_frames`, but blends the two
    /// shaped bodies where the old one blended shape parameters: a redrape of such a
    /// dataset ([`Self::before_paced_morph`]) is today's protocol on its samples. One
    /// written before session 16 settled at its `substeps` with the elastic push-out:
    /// without `settle_substeps` it reads as those, and `elastic_pushout` as true, so its
    /// redrapes settle as it did. One written before the strain polish (session 24) has no
    /// `polish_sweeps`: it reads as 0, no polish; one written before the edge contacts on
    /// thin parts (session 25) has no `thin_part_thickness`: 0, none. One in sizes written
    /// before session 26 picked sizes by the first rule: without `size_pick` it reads as 1.
    pub fn dataset_config(&self) -> Result<DatasetConfig, crate::DatasetError> {
        let mut config = self.config.clone();
        if let Some(c) = config.as_object_mut()
            && c.get("sizes").and_then(|s| s.as_bool()) == Some(true)
        {
            c.entry("size_pick")
                .or_insert(serde_json::Value::from(sim::garment::PickRule::V1.number()));
        }
        if let Some(sim) = config.get_mut("sim").and_then(|s| s.as_object_mut()) {
            sim.entry("stretch_iterations")
                .or_insert(serde_json::Value::from(1));
            // Made before the strain polish (session 24).
            sim.entry("polish_sweeps")
                .or_insert(serde_json::Value::from(0));
            // Made before the edge contacts on thin parts (session 25).
            sim.entry("thin_part_thickness")
                .or_insert(serde_json::Value::from(0.0));
            // Made before a stalled drape's sweeps were doubled (session 46).
            sim.entry("stall_frames")
                .or_insert(serde_json::Value::from(0));
            for off in ["max_morph_speed", "max_edge_penetration"] {
                sim.entry(off).or_insert(serde_json::Value::from(1e9));
            }
            if let Some(substeps) = sim.get("substeps").cloned()
                && !sim.contains_key("settle_substeps")
            {
                // Made before session 16: settling at its substeps, elastic push-outs.
                sim.insert("settle_substeps".into(), substeps);
                sim.entry("elastic_pushout")
                    .or_insert(serde_json::Value::from(true));
            }
        }
        serde_json::from_value(config)
            .map_err(|e| crate::DatasetError::Invalid(format!("manifest config: {e}")))
    }

    /// True for a dataset made before the paced morph of session 15 (its simulator config
    /// has no `max_morph_speed`).
    pub fn before_paced_morph(&self) -> bool {
        self.config
            .get("sim")
            .is_some_and(|s| s.get("max_morph_speed").is_none())
    }

    /// Every sample, in shard order.
    pub fn samples(&self) -> impl Iterator<Item = &SampleRecord> {
        self.shards.iter().flat_map(|s| s.samples.iter())
    }

    /// All samples.
    pub fn tally(&self) -> Tally {
        let mut t = Tally::default();
        for s in self.samples() {
            t.samples += 1;
            t.failed += usize::from(!s.ok);
        }
        t
    }

    /// Per split.
    pub fn tally_by_split(&self) -> BTreeMap<Split, Tally> {
        let mut m: BTreeMap<Split, Tally> = BTreeMap::new();
        for s in self.samples() {
            let t = m.entry(s.plan.split).or_default();
            t.samples += 1;
            t.failed += usize::from(!s.ok);
        }
        m
    }

    /// Per pose family.
    pub fn tally_by_family(&self) -> BTreeMap<String, Tally> {
        let mut m: BTreeMap<String, Tally> = BTreeMap::new();
        for s in self.samples() {
            let t = m.entry(s.family.clone()).or_default();
            t.samples += 1;
            t.failed += usize::from(!s.ok);
        }
        m
    }

    /// Samples and failures per garment size (empty for a dataset without sizes).
    pub fn tally_by_size(&self) -> BTreeMap<String, Tally> {
        let mut m: BTreeMap<String, Tally> = BTreeMap::new();
        for s in self.samples() {
            if let Some(size) = &s.size {
                let t = m.entry(size.clone()).or_default();
                t.samples += 1;
                t.failed += usize::from(!s.ok);
            }
        }
        m
    }

    /// Failure reasons and their counts.
    pub fn failure_reasons(&self) -> BTreeMap<String, usize> {
        let mut m = BTreeMap::new();
        for s in self.samples().filter(|s| !s.ok) {
            let r = s.failure.clone().unwrap_or_else(|| "unknown".into());
            let key = r.split(" (").next().unwrap_or(&r).to_string();
            *m.entry(key).or_default() += 1;
        }
        m
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_manifest_from_before_stretch_iterations_reads_as_one_sweep() {
        let config = DatasetConfig::from_toml(
            "name = \"t\"\ngarment = \"tshirt\"\nresolution = 3000\nseed = 1\nposes_per_body = 1\n\
             [bodies]\ntrain = 1\nval = 1\ntest = 1\n[sim]\nstretch_iterations = 3\n\
             crease_contacts = true\n",
            std::path::Path::new("t.toml"),
        )
        .unwrap();
        let mut m = Manifest::new(&config, GenOptions::default(), String::new(), Vec::new());
        assert_eq!(m.dataset_config().unwrap().sim.stretch_iterations, 3);
        assert!(!m.before_paced_morph());
        assert_eq!(m.dataset_config().unwrap().sim.max_morph_speed, 0.6);
        assert_eq!(m.dataset_config().unwrap().sim.settle_substeps, 20);
        assert!(!m.dataset_config().unwrap().sim.elastic_pushout);
        assert_eq!(m.dataset_config().unwrap().sim.crease_contacts, Some(true));
        // As written by earlier versions: no such fields.
        let sim = m.config["sim"].as_object_mut().unwrap();
        for old in [
            "stall_frames",
            "crease_contacts",
            "stretch_iterations",
            "max_morph_speed",
            "max_edge_penetration",
            "settle_substeps",
        ] {
            sim.remove(old);
        }
        let back = m.dataset_config().unwrap();
        assert_eq!(back.sim.stretch_iterations, 1);
        // Nor the paced morph and the check for cloth caught on the body: both read as off.
        assert!(m.before_paced_morph());
        assert_eq!(back.sim.max_morph_speed, 1e9);
        assert_eq!(back.sim.max_edge_penetration, 1e9);
        assert_eq!(back.sim.substeps, config.sim.substeps);
        // It settled at its substeps, with the elastic push-out.
        assert_eq!(back.sim.settle_substeps, config.sim.substeps);
        assert!(back.sim.elastic_pushout);
        // Crease contacts unset: each garment's own, and no garment had them before the
        // field (the manifest's `garment_crease_contacts` reads false).
        assert_eq!(back.sim.crease_contacts, None);
        assert!(!m.garment_crease_contacts);
        // Nor the doubled sweeps of a stalled drape.
        assert_eq!(back.sim.stall_frames, 0);
    }

    #[test]
    fn the_drapes_identity_ignores_the_build_and_the_times_but_not_the_shards() {
        let config = DatasetConfig::from_toml(
            "name = \"t\"\ngarment = \"tshirt\"\nresolution = 3000\nseed = 1\nposes_per_body = 1\n\
             [bodies]\ntrain = 1\nval = 1\ntest = 1\n",
            std::path::Path::new("t.toml"),
        )
        .unwrap();
        let sample = SampleRecord {
            plan: crate::plan::sample_plan(&config, 0),
            family: "walking".into(),
            pose_source: "walking".into(),
            shape: [0.5; 9],
            size: None,
            ok: true,
            failure: None,
            report: serde_json::json!({"stage_times": {"solve": 0.5}, "settle_frames": 90}),
            warp_seconds: 0.001,
            seconds: 1.0,
        };
        let shard = ShardRecord {
            file: "train-00000.safetensors".into(),
            split: Split::Train,
            rows: 1,
            bytes: 100,
            sha256: "a".repeat(64),
            samples: vec![sample],
        };
        let m = Manifest::new(&config, GenOptions::default(), "s".repeat(64), vec![shard]);
        let id = m.drapes_sha256();
        assert_eq!(id.len(), 64);
        // Made again by another build, or with other stage times: the same drapes.
        let mut again = m.clone();
        again.git_revision = "another".into();
        again.program_sha256 = Some("b".repeat(64));
        again.shards[0].samples[0].seconds = 1.2;
        again.shards[0].samples[0].warp_seconds = 0.002;
        again.shards[0].samples[0].report["stage_times"]["solve"] = serde_json::json!(0.6);
        assert_ne!(again, m);
        assert_eq!(again.drapes_sha256(), id);
        // Another shard, static file, config or split: other drapes.
        let changes: [fn(&mut Manifest); 5] = [
            |m| m.shards[0].sha256 = "c".repeat(64),
            |m| m.static_sha256 = "d".repeat(64),
            |m| m.config_sha256 = "e".repeat(64),
            |m| m.shards[0].split = Split::Val,
            |m| m.shards[0].rows = 2,
        ];
        for change in changes {
            let mut other = m.clone();
            change(&mut other);
            assert_ne!(other.drapes_sha256(), id);
        }
    }

    #[test]
    fn a_short_revision_keeps_the_dirty_mark() {
        let rev = "0123456789abcdef0123456789abcdef01234567";
        assert_eq!(short_revision(rev), "0123456789ab");
        assert_eq!(
            short_revision(&format!("{rev}-dirty")),
            "0123456789ab-dirty"
        );
        assert_eq!(short_revision("unknown"), "unknown");
    }
}
