//! How often does the pose prior make the body intersect itself?
//!
//! Sample `i` draws the pose `random:{seed + i}` from the [`PosePrior`] (the same pose
//! `drape body --pose random:{seed + i}` gives) and a body from the default adult
//! [`ShapeRanges`] with [`shape_seed`]`(seed.wrapping_add(i))`, poses the body and runs the
//! self-intersection test of `sim::body::intersect`.

use std::collections::BTreeMap;

use rayon::prelude::*;
use sim::body::intersect::SelfIntersection;
use sim::body::{BodyError, BodyModel, Family, PoseLibrary, ShapeParams};

use crate::sampling::{PosePrior, ShapeRanges, rng, shape_seed};

/// Result of a prior check.
#[derive(Debug, Clone)]
pub struct PriorReport {
    /// Seed of sample 0.
    pub seed: u64,
    /// Per family: (poses sampled, poses with self-intersection).
    pub per_family: BTreeMap<Family, (usize, usize)>,
    /// Number of core triangles the test looks at (of the body's 26,756).
    pub core_triangles: usize,
    /// Poses with self-intersection: pose seed, the body's shape, the segments that met.
    pub failures: Vec<(u64, ShapeParams, String)>,
}

impl PriorReport {
    /// Poses sampled.
    pub fn samples(&self) -> usize {
        self.per_family.values().map(|v| v.0).sum()
    }

    /// Poses with self-intersection.
    pub fn intersecting(&self) -> usize {
        self.per_family.values().map(|v| v.1).sum()
    }

    /// Share of poses with self-intersection.
    pub fn share(&self) -> f64 {
        self.intersecting() as f64 / self.samples().max(1) as f64
    }

    /// A plain-text table.
    pub fn table(&self) -> String {
        let mut s = format!(
            "self-intersection test on {} core triangles\nfamily    poses  self-intersecting  share\n",
            self.core_triangles
        );
        for (f, (n, k)) in &self.per_family {
            s.push_str(&format!(
                "{:<9} {:>5}  {:>17}  {:>5.2}%\n",
                f.name(),
                n,
                k,
                100.0 * *k as f64 / (*n).max(1) as f64
            ));
        }
        s.push_str(&format!(
            "{:<9} {:>5}  {:>17}  {:>5.2}%",
            "all",
            self.samples(),
            self.intersecting(),
            100.0 * self.share()
        ));
        if !self.failures.is_empty() {
            let list: Vec<String> = self
                .failures
                .iter()
                .take(10)
                .map(|(s, _, w)| format!("random:{s} ({w})"))
                .collect();
            s.push_str(&format!("\nintersecting poses: {}", list.join(", ")));
        }
        s
    }

    /// The report as JSON.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "seed": self.seed,
            "core_triangles": self.core_triangles,
            "samples": self.samples(),
            "intersecting": self.intersecting(),
            "share": self.share(),
            "per_family": self.per_family.iter().map(|(f, (n, k))| (f.name().to_string(), serde_json::json!({"samples": n, "intersecting": k}))).collect::<serde_json::Map<_, _>>(),
            "failures": self.failures.iter().map(|(s, p, w)| serde_json::json!({"pose": format!("random:{s}"), "shape": p.named().iter().map(|(n, v)| (n.to_string(), serde_json::json!(v))).collect::<serde_json::Map<_, _>>(), "segments": w})).collect::<Vec<_>>(),
        })
    }
}

/// Samples `n` bodies and poses from seed `seed` on and counts self-intersections;
/// `progress` is called once per pose (from any thread).
pub fn check(
    model: &BodyModel,
    library: &PoseLibrary,
    n: usize,
    seed: u64,
    progress: impl Fn() + Sync,
) -> Result<PriorReport, BodyError> {
    let prior = PosePrior::new(library.clone());
    let test = SelfIntersection::new(model);
    let ranges = ShapeRanges::default();
    let results: Vec<(Family, ShapeParams, Option<String>)> = (0..n as u64)
        .into_par_iter()
        .map(|i| {
            let sampled = prior.sample_seeded(seed.wrapping_add(i));
            let shape = ranges.sample(&mut rng(shape_seed(seed.wrapping_add(i))));
            let body = model.shape(&shape)?;
            let posed = body.pose(&sampled.pose);
            let hit = test
                .find(&posed.vertices, 1)
                .first()
                .map(|c| format!("{:?}/{:?}", c.segments.0, c.segments.1));
            progress();
            Ok((sampled.family, shape, hit))
        })
        .collect::<Result<_, BodyError>>()?;
    let mut per_family: BTreeMap<Family, (usize, usize)> = BTreeMap::new();
    let mut failures = Vec::new();
    for (i, (f, shape, hit)) in results.into_iter().enumerate() {
        let e = per_family.entry(f).or_default();
        e.0 += 1;
        if let Some(w) = hit {
            e.1 += 1;
            failures.push((seed.wrapping_add(i as u64), shape, w));
        }
    }
    Ok(PriorReport {
        seed,
        core_triangles: test.core_triangles(),
        per_family,
        failures,
    })
}
