//! `--pose SPEC`: rest | t-pose | a key pose name | random:SEED | FILE.bvh:FRAME | FILE.json.

use std::path::Path;

use anyhow::Context;
use sim::body::{BodyError, Pose, PoseLibrary, ShapedBody};

/// A resolved pose and a one-line description of where it came from.
pub struct ResolvedPose {
    /// The pose.
    pub pose: Pose,
    /// Where it came from, for messages and OBJ headers.
    pub description: String,
}

/// Resolves a `--pose` argument for a shaped body (BVH retargeting depends on its
/// proportions) and a pose library.
pub fn resolve(
    spec: &str,
    body: &ShapedBody<'_>,
    library: &PoseLibrary,
) -> anyhow::Result<ResolvedPose> {
    let model = body.model;
    if let Some(seed) = spec.strip_prefix("random:") {
        let seed: u64 = seed.parse().with_context(|| {
            format!("--pose {spec}: the seed after random: must be a whole number")
        })?;
        let prior = dataset::sampling::PosePrior::new(library.clone());
        let sampled = prior.sample_seeded(seed);
        let description = format!("random:{seed} ({})", sampled.describe());
        return Ok(ResolvedPose {
            pose: sampled.pose,
            description,
        });
    }
    if let Some((file, frame)) = spec.rsplit_once(':')
        && file.to_ascii_lowercase().ends_with(".bvh")
    {
        let frame: usize = frame.parse().with_context(|| {
            format!(
                "--pose {spec}: the frame after the file name must be a whole number (a range of frames, FILE.bvh:FIRST-LAST, is for drape predict)"
            )
        })?;
        let motion = sim::body::bvh::Motion::load(Path::new(file))?;
        let pose = motion.retarget(body, frame)?;
        return Ok(ResolvedPose {
            pose,
            description: format!("{file} frame {frame}"),
        });
    }
    if spec.to_ascii_lowercase().ends_with(".bvh") {
        anyhow::bail!("--pose {spec}: say which frame, as FILE.bvh:FRAME (frames count from 0)");
    }
    if spec.to_ascii_lowercase().ends_with(".json") {
        let path = Path::new(spec);
        let text = std::fs::read_to_string(path).map_err(|source| BodyError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let pose = Pose::from_mpfb_json(&model.skeleton, &text, path)?;
        return Ok(ResolvedPose {
            pose,
            description: format!("pose file {spec}"),
        });
    }
    let pose = library.get(spec)?.clone();
    Ok(ResolvedPose {
        pose,
        description: format!("key pose {spec}"),
    })
}

/// Resolves `--pose` for `drape predict`, which also takes a range of BVH frames,
/// `FILE.bvh:FIRST-LAST` (both included; frames count from 0): one pose per frame, in
/// order, with its frame number (`Some`). Any other spec gives its one pose (`None`).
pub fn resolve_frames(
    spec: &str,
    body: &ShapedBody<'_>,
    library: &PoseLibrary,
) -> anyhow::Result<Vec<(Option<usize>, ResolvedPose)>> {
    if let Some((file, range)) = spec.rsplit_once(':')
        && file.to_ascii_lowercase().ends_with(".bvh")
        && let Some((first, last)) = range.split_once('-')
    {
        let frame = |s: &str| {
            s.parse::<usize>().with_context(|| {
                format!("--pose {spec}: a range of frames is FIRST-LAST, whole numbers from 0")
            })
        };
        let (first, last) = (frame(first)?, frame(last)?);
        if first > last {
            anyhow::bail!("--pose {spec}: the first frame comes after the last");
        }
        let motion = sim::body::bvh::Motion::load(Path::new(file))?;
        if last >= motion.len() {
            anyhow::bail!(
                "--pose {spec}: {file} has {} frames (0 to {})",
                motion.len(),
                motion.len().saturating_sub(1)
            );
        }
        return (first..=last)
            .map(|f| {
                let pose = ResolvedPose {
                    pose: motion.retarget(body, f)?,
                    description: format!("{file} frame {f}"),
                };
                Ok((Some(f), pose))
            })
            .collect();
    }
    Ok(vec![(None, resolve(spec, body, library)?)])
}
