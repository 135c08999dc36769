//! Dataset configs (`configs/datasets/*.toml`): what to drape, on which bodies and poses,
//! how to split and shard it, and the simulator parameters.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use sim::cloth::SimConfig;

use crate::DatasetError;
use crate::sampling::ShapeRanges;

/// The built-in dataset configs, by name.
pub const BUILT_IN: [(&str, &str); 16] = [
    ("tiny", include_str!("../../configs/datasets/tiny.toml")),
    (
        "tiny-heldout",
        include_str!("../../configs/datasets/tiny-heldout.toml"),
    ),
    ("small", include_str!("../../configs/datasets/small.toml")),
    (
        "cpu-reference",
        include_str!("../../configs/datasets/cpu-reference.toml"),
    ),
    (
        "cpu-reference-sweater",
        include_str!("../../configs/datasets/cpu-reference-sweater.toml"),
    ),
    (
        "cpu-reference-dress",
        include_str!("../../configs/datasets/cpu-reference-dress.toml"),
    ),
    (
        "cpu-reference-jeans",
        include_str!("../../configs/datasets/cpu-reference-jeans.toml"),
    ),
    (
        "cpu-repro-tshirt",
        include_str!("../../configs/datasets/cpu-repro-tshirt.toml"),
    ),
    (
        "cpu-repro-sweater",
        include_str!("../../configs/datasets/cpu-repro-sweater.toml"),
    ),
    (
        "cpu-repro-dress",
        include_str!("../../configs/datasets/cpu-repro-dress.toml"),
    ),
    (
        "cpu-repro-jeans",
        include_str!("../../configs/datasets/cpu-repro-jeans.toml"),
    ),
    (
        "cpu-repro-tshirt-10k",
        include_str!("../../configs/datasets/cpu-repro-tshirt-10k.toml"),
    ),
    (
        "paper-tshirt",
        include_str!("../../configs/datasets/paper-tshirt.toml"),
    ),
    (
        "paper-sweater",
        include_str!("../../configs/datasets/paper-sweater.toml"),
    ),
    (
        "paper-dress",
        include_str!("../../configs/datasets/paper-dress.toml"),
    ),
    (
        "paper-jeans",
        include_str!("../../configs/datasets/paper-jeans.toml"),
    ),
];

/// Bodies per split. Splits are by body, as in the paper: a test body is never seen in
/// training, in any pose.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Bodies {
    /// Training bodies.
    pub train: u32,
    /// Validation bodies.
    pub val: u32,
    /// Test bodies.
    pub test: u32,
    /// Number of the first body (default 0). Body `first + b` gets the shape seed
    /// `mix(seed, BODY, first + b)` and its samples the ids `(first + b) * poses_per_body
    /// ..`, so a dataset with the same seed and `first` past another's last body holds
    /// other bodies and other sample ids: more training drapes for that one (`drape train
    /// --more-data`), its validation and test bodies untouched. Left out of the resolved
    /// config when 0, so configs without it keep their hash.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub first: u32,
}

fn is_zero(n: &u32) -> bool {
    *n == 0
}

/// Where poses come from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "source", rename_all = "lowercase", deny_unknown_fields)]
pub enum PoseSource {
    /// The pose prior (`sampling::PosePrior`) over a pose library: the built-in
    /// `configs/poses/library.toml` unless `library` names another TOML file.
    Prior {
        /// A pose library TOML replacing the built-in one (relative to the config file).
        #[serde(default)]
        library: Option<PathBuf>,
    },
    /// Frames of BVH files in a folder (every `*.bvh`, sorted by name), retargeted to each
    /// body: a sample picks a file and a frame uniformly.
    Bvh {
        /// The folder (relative to the config file).
        dir: PathBuf,
    },
}

impl Default for PoseSource {
    fn default() -> Self {
        PoseSource::Prior { library: None }
    }
}

/// One dataset.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetConfig {
    /// Name, written into the manifest.
    pub name: String,
    /// Garment: a built-in name or an imported one.
    pub garment: String,
    /// Template resolution of a built-in garment (about this many vertices).
    pub resolution: usize,
    /// Seed of all sampling.
    pub seed: u64,
    /// Bodies per split.
    pub bodies: Bodies,
    /// Poses per body.
    pub poses_per_body: u32,
    /// Samples per shard file (default 64).
    #[serde(default = "default_shard_samples")]
    pub samples_per_shard: u32,
    /// Largest share of failed drapes before `drape gen` exits non-zero (default 0.03).
    #[serde(default = "default_max_failure_rate")]
    pub max_failure_rate: f64,
    /// Shape ranges, sampled uniformly (default: the adult ranges of `ShapeRanges`).
    #[serde(default)]
    pub shapes: ShapeRanges,
    /// Pose source (default: the built-in pose prior).
    #[serde(default)]
    pub poses: PoseSource,
    /// Simulator parameters (fields left out keep the defaults of `configs/sim/default.toml`).
    #[serde(default)]
    pub sim: SimConfig,
    /// Drape each body in the size its measurements pick from the garment's size chart
    /// (a graded garment only; default false: every body wears the base template). The
    /// size is recorded per sample; the network's input stays the base template's warp.
    /// Left out of the resolved config when false, so older configs keep their hash.
    #[serde(default, skip_serializing_if = "is_false")]
    pub sizes: bool,
    /// With `sizes`: the rule that picks a body's size (`sim::garment::PickRule`): 2 (the
    /// default, since session 26) counts a girth too small 10 times one too large and a
    /// height too small 4 times; 1 (before) counted any measurement too small 4 times.
    /// A manifest in sizes without the field was made with 1, and a config that sets 1
    /// keeps the hash it had (1 is left out of the resolved config). Without sizes the
    /// field is not recorded.
    #[serde(
        default = "default_size_pick",
        skip_serializing_if = "is_first_size_pick"
    )]
    pub size_pick: u32,
}

fn default_size_pick() -> u32 {
    sim::garment::PickRule::V2.number()
}

fn is_first_size_pick(n: &u32) -> bool {
    *n == sim::garment::PickRule::V1.number()
}

fn is_false(b: &bool) -> bool {
    !*b
}

fn default_shard_samples() -> u32 {
    64
}

fn default_max_failure_rate() -> f64 {
    0.03
}

/// A split of a dataset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    /// Training.
    Train,
    /// Validation.
    Val,
    /// Test.
    Test,
}

impl Split {
    /// All splits in order.
    pub const ALL: [Split; 3] = [Split::Train, Split::Val, Split::Test];

    /// Its name.
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Test => "test",
        }
    }

    /// Parses a name.
    pub fn parse(s: &str) -> Result<Split, DatasetError> {
        Split::ALL
            .into_iter()
            .find(|x| x.name() == s)
            .ok_or_else(|| {
                DatasetError::Invalid(format!("no split named {s:?} (train, val, test)"))
            })
    }
}

impl DatasetConfig {
    /// Parses and validates a config; `origin` names it in errors and anchors relative paths.
    pub fn from_toml(text: &str, origin: &Path) -> Result<Self, DatasetError> {
        let bad = |reason: String| DatasetError::Config {
            path: origin.to_path_buf(),
            reason,
        };
        let mut c: DatasetConfig = toml::from_str(text).map_err(|e| bad(e.to_string()))?;
        c.validate().map_err(bad)?;
        let base = origin.parent().unwrap_or(Path::new("."));
        match &mut c.poses {
            PoseSource::Prior { library: Some(p) } if p.is_relative() => *p = base.join(&*p),
            PoseSource::Bvh { dir } if dir.is_relative() => *dir = base.join(&*dir),
            _ => {}
        }
        Ok(c)
    }

    /// A built-in config by name, or a TOML file.
    pub fn load(name_or_path: &str) -> Result<Self, DatasetError> {
        if let Some((n, text)) = BUILT_IN.iter().find(|(n, _)| *n == name_or_path) {
            return Self::from_toml(text, &PathBuf::from(format!("configs/datasets/{n}.toml")));
        }
        let path = PathBuf::from(name_or_path);
        let text = std::fs::read_to_string(&path).map_err(|e| DatasetError::Config {
            path: path.clone(),
            reason: format!(
                "{e} (built-in configs: {})",
                BUILT_IN.map(|(n, _)| n).join(", ")
            ),
        })?;
        Self::from_toml(&text, &path)
    }

    /// Checks the numbers.
    pub fn validate(&self) -> Result<(), String> {
        if self.garment.is_empty() {
            return Err("garment is empty".into());
        }
        if !(100..=200_000).contains(&self.resolution) {
            return Err(format!(
                "resolution {} is not in 100..=200000",
                self.resolution
            ));
        }
        if self.bodies.train + self.bodies.val + self.bodies.test == 0 {
            return Err("no bodies in any split".into());
        }
        if self.sizes && sim::garment::built_in(&self.garment).is_none_or(|d| d.grading.is_none()) {
            let graded: Vec<&str> = sim::garment::def::BUILT_IN
                .iter()
                .map(|(n, _)| *n)
                .filter(|n| sim::garment::built_in(n).is_some_and(|d| d.grading.is_some()))
                .collect();
            return Err(format!(
                "sizes = true, but garment {} is not graded (graded: {})",
                self.garment,
                graded.join(", ")
            ));
        }
        if sim::garment::PickRule::from_number(self.size_pick).is_none() {
            return Err(format!(
                "size_pick = {} must be 1 (the rule before session 26) or 2",
                self.size_pick
            ));
        }
        if self.poses_per_body == 0 {
            return Err("poses_per_body must be at least 1".into());
        }
        if self.samples_per_shard == 0 {
            return Err("samples_per_shard must be at least 1".into());
        }
        if !(0.0..=1.0).contains(&self.max_failure_rate) {
            return Err("max_failure_rate must be in [0, 1]".into());
        }
        for (name, r) in [
            ("gender", self.shapes.gender),
            ("age", self.shapes.age),
            ("muscle", self.shapes.muscle),
            ("weight", self.shapes.weight),
            ("height", self.shapes.height),
            ("proportions", self.shapes.proportions),
        ] {
            if !(0.0 <= r[0] && r[0] <= r[1] && r[1] <= 1.0) {
                return Err(format!(
                    "shapes.{name} = {r:?} is not a range within [0, 1]"
                ));
            }
        }
        self.sim.validate()
    }

    /// Total bodies.
    pub fn total_bodies(&self) -> u64 {
        (self.bodies.train + self.bodies.val + self.bodies.test) as u64
    }

    /// Total samples (bodies x poses).
    pub fn total_samples(&self) -> u64 {
        self.total_bodies() * self.poses_per_body as u64
    }

    /// The sample ids: `total_samples()` of them from the first body's first pose.
    pub fn sample_ids(&self) -> std::ops::Range<u64> {
        let first = self.bodies.first as u64 * self.poses_per_body as u64;
        first..first + self.total_samples()
    }

    /// The split of body `b` (bodies are numbered from `bodies.first`, train first, then
    /// val, then test).
    pub fn split_of_body(&self, b: u64) -> Split {
        let b = b
            .checked_sub(self.bodies.first as u64)
            .expect("a body below the config's [bodies] first");
        let (t, v) = (self.bodies.train as u64, self.bodies.val as u64);
        if b < t {
            Split::Train
        } else if b < t + v {
            Split::Val
        } else {
            Split::Test
        }
    }

    /// The resolved config as canonical JSON (what the manifest stores and hashes).
    pub fn resolved_json(&self) -> serde_json::Value {
        let mut v = serde_json::to_value(self).expect("configs serialise");
        if !self.sizes
            && let Some(o) = v.as_object_mut()
        {
            o.remove("size_pick");
        }
        v
    }

    /// sha256 of the resolved config's JSON: parts of one dataset must agree on it.
    pub fn hash(&self) -> String {
        let text = serde_json::to_string(&self.resolved_json()).expect("json");
        hex(&Sha256::digest(text.as_bytes()))
    }
}

/// Lower-case hex of bytes.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_in_configs_parse_and_sizes_are_as_documented() {
        for (name, _) in BUILT_IN {
            let c = DatasetConfig::load(name).unwrap();
            assert_eq!(c.name, name);
        }
        let c = DatasetConfig::load("tiny-heldout").unwrap();
        assert_eq!((c.bodies.train, c.bodies.val, c.bodies.test), (100, 10, 10));
        assert_eq!(
            (c.garment.as_str(), c.resolution, c.poses_per_body),
            ("tshirt", 3000, 2)
        );
        let c = DatasetConfig::load("cpu-reference").unwrap();
        assert_eq!((c.bodies.train, c.bodies.val, c.bodies.test), (200, 10, 40));
        // Its hash is pinned: the data the first quick-start weights were trained on (before
        // session 54) and the reproduction's first pass stay reproducible only while the
        // resolved config, and so the simulator it pins, is unchanged.
        assert_eq!(
            c.hash(),
            "98a76105adedc77f8d24e8a575410c131789d70ba84e495a08fe6909b2c809c9"
        );
        assert_eq!(
            (c.garment.as_str(), c.resolution, c.poses_per_body),
            ("tshirt", 3000, 10)
        );
        // The paper's sizes (its section 4.2), at 10k vertices, in sizes.
        for (g, poses) in [
            ("tshirt", 40),
            ("sweater", 23),
            ("dress", 26),
            ("jeans", 31),
        ] {
            let p = DatasetConfig::load(&format!("paper-{g}")).unwrap();
            assert_eq!((p.bodies.train, p.bodies.val, p.bodies.test), (500, 20, 80));
            assert_eq!((p.garment.as_str(), p.resolution), (g, 10000));
            assert_eq!((p.poses_per_body, p.sizes), (poses, true));
        }
    }

    #[test]
    fn the_size_pick_is_hashed_only_with_sizes_and_legacy_manifests_read_1() {
        let plain = DatasetConfig::load("tiny").unwrap();
        assert_eq!(plain.size_pick, 2);
        // Without sizes the rule is not part of the config: the hash stays.
        let mut first = plain.clone();
        first.size_pick = 1;
        assert_eq!(first.hash(), plain.hash());
        assert!(plain.resolved_json().get("size_pick").is_none());
        // With sizes the default (2) is recorded; 1, the rule before session 26, is left
        // out, so configs that pin it keep the hash they had.
        let mut sized = plain.clone();
        sized.sizes = true;
        assert_eq!(sized.resolved_json()["size_pick"], 2);
        let mut legacy = sized.clone();
        legacy.size_pick = 1;
        assert!(legacy.resolved_json().get("size_pick").is_none());
        assert_ne!(legacy.hash(), sized.hash());
        // The reproduction's configs pinned 1 until session 53; its rerun takes the default.
        for name in ["tshirt", "sweater", "dress", "jeans", "tshirt-10k"] {
            let c = DatasetConfig::load(&format!("cpu-repro-{name}")).unwrap();
            assert_eq!((c.sizes, c.size_pick), (true, 2));
        }
        // A manifest in sizes without the field was made with 1; one with it keeps it.
        let manifest = |c: &DatasetConfig| {
            crate::manifest::Manifest::new(c, Default::default(), String::new(), Vec::new())
        };
        assert_eq!(manifest(&legacy).dataset_config().unwrap().size_pick, 1);
        assert_eq!(manifest(&sized).dataset_config().unwrap().size_pick, 2);
        // No such rule: refused by name.
        for bad in [0, 3] {
            let mut c = sized.clone();
            c.size_pick = bad;
            let e = c.validate().unwrap_err();
            assert!(e.contains("size_pick"), "{e}");
        }
    }

    #[test]
    fn bad_configs_are_refused_with_the_field() {
        let text = BUILT_IN[0].1;
        let err = |t: &str| {
            DatasetConfig::from_toml(t, Path::new("x.toml"))
                .unwrap_err()
                .to_string()
        };
        assert!(
            err(&text.replace("poses_per_body = 2", "poses_per_body = 0"))
                .contains("poses_per_body")
        );
        assert!(err(&text.replace("seed = 1", "seed = 1\nbogus = 1")).contains("bogus"));
        assert!(err(&text.replace("resolution = 3000", "resolution = 5")).contains("resolution"));
    }

    #[test]
    fn splits_are_by_body() {
        let c = DatasetConfig::load("tiny").unwrap();
        let t = c.bodies.train as u64;
        assert_eq!(c.split_of_body(0), Split::Train);
        assert_eq!(c.split_of_body(t), Split::Val);
        assert_eq!(c.split_of_body(c.total_bodies() - 1), Split::Test);
    }
}
