//! The sampling plan: which body, shape and pose each sample gets, as a pure function of
//! (config, sample id), and which shard it lands in. No thread count, machine or run order
//! enters it.
//!
//! Sample `id` is body `id / poses_per_body`, pose `id % poses_per_body`; bodies are
//! numbered from `bodies.first` (default 0), train first, then val, then test. A body's shape comes from
//! `mix(seed, BODY, body)`, a sample's pose from `mix(seed, POSE, id)`.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};
use sim::body::bvh::Motion as Bvh;
use sim::body::{BodyModel, Pose, PoseLibrary, ShapeParams};

use crate::DatasetError;
use crate::config::{DatasetConfig, PoseSource, Split};
use crate::sampling::{PosePrior, rng};
use rand::Rng;

const BODY: u64 = 0x424f_4459;
const POSE: u64 = 0x504f_5345;

/// splitmix64's finaliser: a fixed bijection that scatters nearby integers.
pub fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// A seed from the dataset seed, a stream tag and an index.
pub fn mix(seed: u64, stream: u64, index: u64) -> u64 {
    splitmix(seed ^ splitmix(stream ^ splitmix(index)))
}

/// Where a sample stands in the dataset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct SamplePlan {
    /// Sample id.
    pub id: u64,
    /// Its split.
    pub split: Split,
    /// Body number.
    pub body: u64,
    /// Pose number of this body.
    pub pose_index: u32,
    /// Seed of the body's shape.
    pub shape_seed: u64,
    /// Seed of the pose.
    pub pose_seed: u64,
}

/// The plan of sample `id`.
pub fn sample_plan(c: &DatasetConfig, id: u64) -> SamplePlan {
    let body = id / c.poses_per_body as u64;
    SamplePlan {
        id,
        split: c.split_of_body(body),
        body,
        pose_index: (id % c.poses_per_body as u64) as u32,
        shape_seed: mix(c.seed, BODY, body),
        pose_seed: mix(c.seed, POSE, id),
    }
}

/// A shard of the plan.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct ShardPlan {
    /// File name, `SPLIT-NNNNN.safetensors`.
    pub file: String,
    /// Split.
    pub split: Split,
    /// Sample ids, ascending.
    pub samples: Vec<u64>,
}

/// Every shard of the dataset, train shards first: shard k of a split holds the split's
/// samples `k * samples_per_shard ..` in id order.
pub fn shards(c: &DatasetConfig) -> Vec<ShardPlan> {
    let mut out = Vec::new();
    for split in Split::ALL {
        let ids: Vec<u64> = c
            .sample_ids()
            .filter(|&id| sample_plan(c, id).split == split)
            .collect();
        for (k, chunk) in ids.chunks(c.samples_per_shard as usize).enumerate() {
            out.push(ShardPlan {
                file: format!("{}-{k:05}.safetensors", split.name()),
                split,
                samples: chunk.to_vec(),
            });
        }
    }
    out
}

/// Part `i` of `n` (0-based): every n-th shard, starting at the i-th.
pub fn part(all: &[ShardPlan], i: u32, n: u32) -> Vec<ShardPlan> {
    all.iter()
        .enumerate()
        .filter(|(k, _)| *k as u32 % n == i)
        .map(|(_, s)| s.clone())
        .collect()
}

/// What a sample drapes on.
#[derive(Debug, Clone)]
pub struct Drawn {
    /// Body shape.
    pub shape: ShapeParams,
    /// Pose.
    pub pose: Pose,
    /// Pose family (`walking`, `dance`, `yoga`, or `bvh` for BVH frames).
    pub family: String,
    /// How the pose was made (key poses and blend, or file and frame).
    pub pose_source: String,
}

/// Draws shapes and poses for plans.
#[derive(Debug)]
pub enum Poser {
    /// The pose prior.
    Prior(PosePrior),
    /// BVH files, sorted by name.
    Bvh(Vec<(PathBuf, Bvh)>),
}

impl Poser {
    /// The poser of a config; `library` is the built-in pose library, used unless the
    /// config names another.
    pub fn new(
        c: &DatasetConfig,
        model: &BodyModel,
        library: PoseLibrary,
    ) -> Result<Self, DatasetError> {
        match &c.poses {
            PoseSource::Prior { library: None } => Ok(Poser::Prior(PosePrior::new(library))),
            PoseSource::Prior { library: Some(p) } => {
                let bad = |e: &dyn std::fmt::Display| {
                    DatasetError::Invalid(format!(
                        "the config's [poses] library {}: {e}",
                        p.display()
                    ))
                };
                let text = std::fs::read_to_string(p).map_err(|e| bad(&e))?;
                let lib = PoseLibrary::from_toml(&model.skeleton, &text, &model.t_pose)
                    .map_err(|e| bad(&e))?;
                Ok(Poser::Prior(PosePrior::new(lib)))
            }
            PoseSource::Bvh { dir } => {
                let mut files: Vec<PathBuf> = std::fs::read_dir(dir)
                    .map_err(|e| {
                        DatasetError::Invalid(format!(
                            "the config's [poses] dir {}: {e}",
                            dir.display()
                        ))
                    })?
                    .filter_map(|e| e.ok().map(|e| e.path()))
                    .filter(|p| p.extension().is_some_and(|x| x.eq_ignore_ascii_case("bvh")))
                    .collect();
                files.sort();
                if files.is_empty() {
                    return Err(DatasetError::Invalid(format!(
                        "no .bvh files in {}",
                        dir.display()
                    )));
                }
                let mut out = Vec::new();
                for f in files {
                    let b = Bvh::load(&f)?;
                    if b.is_empty() {
                        return Err(DatasetError::Invalid(format!(
                            "{} has no frames",
                            f.display()
                        )));
                    }
                    out.push((f, b));
                }
                Ok(Poser::Bvh(out))
            }
        }
    }

    /// Shape and pose of a sample.
    pub fn draw(
        &self,
        c: &DatasetConfig,
        model: &BodyModel,
        p: &SamplePlan,
    ) -> Result<Drawn, DatasetError> {
        let shape = c.shapes.sample(&mut rng(p.shape_seed));
        match self {
            Poser::Prior(prior) => {
                let s = prior.sample_seeded(p.pose_seed);
                Ok(Drawn {
                    shape,
                    pose: s.pose.clone(),
                    family: s.family.name().to_string(),
                    pose_source: s.describe(),
                })
            }
            Poser::Bvh(files) => {
                let mut r = rng(p.pose_seed);
                let k = r.random_range(0..files.len());
                let (path, bvh) = &files[k];
                let frame = r.random_range(0..bvh.len());
                let body = model.shape(&shape)?;
                let pose = bvh.retarget(&body, frame)?;
                Ok(Drawn {
                    shape,
                    pose,
                    family: "bvh".into(),
                    pose_source: format!(
                        "{} frame {frame}",
                        path.file_name().unwrap_or_default().to_string_lossy()
                    ),
                })
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_plan_is_a_pure_function_of_seed_and_id() {
        let c = DatasetConfig::load("tiny").unwrap();
        let a: Vec<_> = (0..c.total_samples()).map(|i| sample_plan(&c, i)).collect();
        let b: Vec<_> = (0..c.total_samples())
            .rev()
            .map(|i| sample_plan(&c, i))
            .collect();
        assert_eq!(a, b.into_iter().rev().collect::<Vec<_>>());
        // Poses of one body share its shape seed; different samples differ in pose seed.
        assert_eq!(a[0].shape_seed, a[1].shape_seed);
        assert_ne!(a[0].pose_seed, a[1].pose_seed);
        assert_ne!(a[0].shape_seed, a[2].shape_seed);
        // Another seed, other samples.
        let mut d = c.clone();
        d.seed += 1;
        assert_ne!(sample_plan(&d, 0).pose_seed, a[0].pose_seed);
    }

    #[test]
    fn bodies_from_first_are_other_bodies_with_other_ids() {
        let c = DatasetConfig::load("small").unwrap();
        let ppb = c.poses_per_body as u64;
        let mut more = c.clone();
        more.bodies = crate::config::Bodies {
            first: c.total_bodies() as u32,
            train: 3,
            val: 0,
            test: 0,
        };
        // The config without `first` keeps its resolved form (and so its hash).
        assert!(c.resolved_json()["bodies"].get("first").is_none());
        assert_eq!(more.resolved_json()["bodies"]["first"], c.total_bodies());
        let ids = more.sample_ids();
        assert_eq!(ids.start, c.sample_ids().end);
        assert_eq!(ids.end - ids.start, 3 * ppb);
        let plans: Vec<SamplePlan> = ids.clone().map(|i| sample_plan(&more, i)).collect();
        assert!(plans.iter().all(|p| p.split == Split::Train));
        assert_eq!(plans[0].body, c.total_bodies());
        assert_eq!(plans[0].pose_index, 0);
        // Body b's seeds are those a bigger dataset of the same seed gives body b.
        let mut big = c.clone();
        big.bodies.train = c.total_bodies() as u32 + 3;
        for p in &plans {
            let q = sample_plan(&big, p.id);
            assert_eq!((q.shape_seed, q.pose_seed), (p.shape_seed, p.pose_seed));
        }
        let original: std::collections::HashSet<u64> = (0..c.total_samples())
            .map(|i| sample_plan(&c, i).shape_seed)
            .collect();
        assert!(plans.iter().all(|p| !original.contains(&p.shape_seed)));
        // The shards hold exactly those ids, train shards numbered from 0.
        let all = shards(&more);
        assert_eq!(all[0].file, "train-00000.safetensors");
        let held: Vec<u64> = all.iter().flat_map(|s| s.samples.clone()).collect();
        assert_eq!(held, ids.collect::<Vec<_>>());
    }

    #[test]
    fn splits_count_bodies_from_first() {
        let mut c = DatasetConfig::load("tiny").unwrap();
        c.bodies = crate::config::Bodies {
            first: 5,
            train: 2,
            val: 1,
            test: 1,
        };
        let ppb = c.poses_per_body as u64;
        assert_eq!(c.sample_ids(), 5 * ppb..9 * ppb);
        let split = |body: u64| sample_plan(&c, body * ppb).split;
        assert_eq!(
            [split(5), split(6), split(7), split(8)],
            [Split::Train, Split::Train, Split::Val, Split::Test]
        );
    }

    #[test]
    fn the_more_drapes_config_is_the_reproductions_but_its_bodies() {
        let repro = DatasetConfig::load("cpu-repro-tshirt").unwrap();
        let more = DatasetConfig::load(
            &std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
                .join("../configs/datasets/cpu-repro-tshirt-more.toml")
                .display()
                .to_string(),
        )
        .unwrap();
        assert_eq!(more.bodies.first as u64, repro.total_bodies());
        assert_eq!((more.bodies.val, more.bodies.test), (0, 0));
        let strip = |c: &DatasetConfig| {
            let mut v = c.resolved_json();
            let o = v.as_object_mut().unwrap();
            o.remove("name");
            o.remove("bodies");
            v
        };
        assert_eq!(strip(&more), strip(&repro));
    }

    #[test]
    fn shards_cover_every_sample_once_and_parts_split_them() {
        let mut c = DatasetConfig::load("small").unwrap();
        c.samples_per_shard = 7;
        let all = shards(&c);
        let mut ids: Vec<u64> = all.iter().flat_map(|s| s.samples.clone()).collect();
        ids.sort();
        assert_eq!(ids, (0..c.total_samples()).collect::<Vec<_>>());
        for s in &all {
            assert!(
                s.samples
                    .iter()
                    .all(|&i| sample_plan(&c, i).split == s.split)
            );
            assert!(s.samples.len() <= 7);
        }
        let mut joined: Vec<String> = (0..3)
            .flat_map(|i| part(&all, i, 3).into_iter().map(|s| s.file))
            .collect();
        joined.sort();
        let mut files: Vec<String> = all.iter().map(|s| s.file.clone()).collect();
        files.sort();
        assert_eq!(joined, files);
    }
}
