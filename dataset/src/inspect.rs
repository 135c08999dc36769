//! `drape data info`, `verify` and `merge`.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use glam::Quat;
use serde::Serialize;

use crate::DatasetError;
use crate::config::Split;
use crate::generate::{sha256, write_atomic};
use crate::manifest::{Manifest, Tally};
use crate::reader::Dataset;
use crate::shard::STATIC_FILE;
use sim::mesh::remesh::min_angles_deg;

/// mean, p95 and max of a list.
#[derive(Debug, Clone, Copy, Default, PartialEq, Serialize)]
pub struct Stats {
    /// Mean.
    pub mean: f64,
    /// 95th percentile.
    pub p95: f64,
    /// Largest.
    pub max: f64,
}

impl Stats {
    /// Of `v` (zeros when empty).
    pub fn of(mut v: Vec<f64>) -> Self {
        if v.is_empty() {
            return Self::default();
        }
        v.sort_by(f64::total_cmp);
        let k = ((v.len() as f64 * 0.95).ceil() as usize).clamp(1, v.len()) - 1;
        Self {
            mean: v.iter().sum::<f64>() / v.len() as f64,
            p95: v[k],
            max: v[v.len() - 1],
        }
    }
}

/// What `drape data info` prints.
#[derive(Debug, Clone, Serialize)]
pub struct Info {
    /// Dataset name.
    pub name: String,
    /// Its drapes' identity ([`crate::manifest::Manifest::drapes_sha256`]): the same for
    /// the same drapes made again.
    pub drapes_sha256: String,
    /// Garment and vertex count.
    pub garment: String,
    /// Garment vertices.
    pub vertices: usize,
    /// Converged samples per split.
    pub samples: BTreeMap<Split, usize>,
    /// Failures per split.
    pub failures_by_split: BTreeMap<Split, Tally>,
    /// Failures per pose family.
    pub failures_by_family: BTreeMap<String, Tally>,
    /// Samples and failures per garment size (empty without sizes).
    pub failures_by_size: BTreeMap<String, Tally>,
    /// Failure reasons.
    pub failure_reasons: BTreeMap<String, usize>,
    /// Bytes on disk (shards and static file).
    pub bytes: u64,
    /// p95 edge strain of converged drapes.
    pub strain_p95: Stats,
    /// Largest edge strain of converged drapes.
    pub strain_max: Stats,
    /// Deepest penetration after the push-out (m).
    pub penetration_max_depth: Stats,
    /// How far the top opening came to rest below the DQS warp's (m), over the converged
    /// drapes that record it (`None` if none does: made before the slide check), and how
    /// many record it (a dataset resumed across the change has both kinds).
    pub top_drop: Option<(Stats, usize)>,
    /// The strain polish, over the converged drapes that record it (`None` if none does:
    /// made before the polish, or with `polish_sweeps = 0`): p95 edge strain before it, and
    /// the mean and largest distance it moved a particle (m).
    pub polish: Option<PolishInfo>,
    /// Time per sample, one thread (s).
    pub seconds: Stats,
    /// Each converged test pose's distance to the nearest converged training pose: mean
    /// over bones of the rotation angle between them (degrees).
    pub test_to_train_pose_deg: Stats,
    /// Edist between the DQS warp M and the drape G (cm), per sample, of the training and
    /// the test split: the DQS baseline, and how far a network has to move M.
    pub dqs_edist_cm: BTreeMap<Split, Stats>,
    /// Triangles the drapes crush thin (every split).
    pub thin: ThinInfo,
}

/// The angles at which `drape data info` counts a draped triangle as crushed thin.
pub const THIN_DEG: [f64; 3] = [1.0, 2.0, 5.0];

/// Triangles crushed thin in the drapes: a fold the simulator could not resolve at the
/// mesh's edge length, where the mean-curvature normal (L_MC) becomes very large.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct ThinInfo {
    /// Drapes read.
    pub drapes: usize,
    /// The template's smallest triangle angle (degrees).
    pub template_min_deg: f64,
    /// The smallest triangle angle over all drapes (degrees; 180 when none was read).
    pub min_deg: f64,
    /// Per angle of [`THIN_DEG`]: the drapes with a triangle whose smallest angle is below it.
    pub drapes_below: Vec<(f64, usize)>,
    /// The most triangles under the largest angle of [`THIN_DEG`] in one drape.
    pub most_in_a_drape: usize,
}

impl ThinInfo {
    /// From each drape's smallest triangle angles, beside the template's.
    pub fn of(template_min_deg: f64, drapes: &[Vec<f32>]) -> Self {
        let smallest: Vec<f64> = drapes
            .iter()
            .map(|a| a.iter().map(|&m| f64::from(m)).fold(180.0, f64::min))
            .collect();
        let top = THIN_DEG[THIN_DEG.len() - 1];
        Self {
            drapes: drapes.len(),
            template_min_deg,
            min_deg: smallest.iter().copied().fold(180.0, f64::min),
            drapes_below: THIN_DEG
                .iter()
                .map(|&d| (d, smallest.iter().filter(|m| **m < d).count()))
                .collect(),
            most_in_a_drape: drapes
                .iter()
                .map(|a| a.iter().filter(|m| f64::from(**m) < top).count())
                .max()
                .unwrap_or(0),
        }
    }
}

/// Mean rotation angle (degrees) between two poses, over bones.
pub fn pose_distance(a: &[Quat], b: &[Quat]) -> f64 {
    let sum: f64 = a
        .iter()
        .zip(b)
        .map(|(p, q)| p.angle_between(*q).to_degrees() as f64)
        .sum();
    sum / a.len().max(1) as f64
}

/// Summarises a dataset (reads the shards of train and test for the pose distances).
pub fn info(ds: &Dataset) -> Result<Info, DatasetError> {
    let m = &ds.manifest;
    let c = m.dataset_config()?;
    let ok: Vec<_> = m.samples().filter(|s| s.ok).collect();
    let get = |s: &crate::manifest::SampleRecord, path: &[&str]| -> f64 {
        let mut v = &s.report;
        for k in path {
            v = &v[*k];
        }
        v.as_f64().unwrap_or(f64::NAN)
    };
    let stat = |path: &[&str]| Stats::of(ok.iter().map(|s| get(s, path)).collect());
    // Each sample's pose, DQS Edist (cm) and triangles' smallest angles, one shard in
    // memory at a time.
    let triangles = &ds.statics.garment_triangles;
    let mut angles: Vec<Vec<f32>> = Vec::new();
    let mut read = |split: Split| -> Result<(Vec<Vec<Quat>>, Vec<f64>), DatasetError> {
        let mut poses = Vec::new();
        let mut dqs = Vec::new();
        for s in ds.samples(split) {
            let row = s?.row;
            angles.push(min_angles_deg(&row.draped, triangles));
            let sum: f64 = row
                .warped
                .iter()
                .zip(&row.draped)
                .map(|(m, g)| m.distance(*g) as f64)
                .sum();
            dqs.push(100.0 * sum / row.warped.len().max(1) as f64);
            poses.push(row.pose);
        }
        Ok((poses, dqs))
    };
    let ((train, train_dqs), (test, test_dqs)) = (read(Split::Train)?, read(Split::Test)?);
    read(Split::Val)?;
    let thin = ThinInfo::of(
        min_angles_deg(&ds.statics.garment_vertices, triangles)
            .into_iter()
            .map(f64::from)
            .fold(180.0, f64::min),
        &angles,
    );
    let nearest: Vec<f64> = test
        .iter()
        .filter_map(|t| {
            train
                .iter()
                .map(|r| pose_distance(t, r))
                .min_by(f64::total_cmp)
        })
        .collect();
    let mut bytes = std::fs::metadata(ds.dir.join(STATIC_FILE))
        .map(|md| md.len())
        .unwrap_or(0);
    bytes += m.shards.iter().map(|s| s.bytes).sum::<u64>();
    Ok(Info {
        name: m.name.clone(),
        drapes_sha256: m.drapes_sha256(),
        garment: c.garment.clone(),
        vertices: ds.statics.garment_vertices.len(),
        samples: Split::ALL.iter().map(|&s| (s, ds.count(s))).collect(),
        failures_by_split: m.tally_by_split(),
        failures_by_family: m.tally_by_family(),
        failures_by_size: m.tally_by_size(),
        failure_reasons: m.failure_reasons(),
        bytes,
        strain_p95: stat(&["strain", "p95"]),
        strain_max: stat(&["strain", "max"]),
        penetration_max_depth: stat(&["penetration", "max_depth"]),
        top_drop: {
            let v: Vec<f64> = ok
                .iter()
                .filter_map(|s| s.report["top_drop"].as_f64())
                .collect();
            let n = v.len();
            (n > 0).then(|| (Stats::of(v), n))
        },
        polish: {
            let polished: Vec<&serde_json::Value> = ok
                .iter()
                .map(|s| &s.report["polish"])
                .filter(|p| p.is_object())
                .collect();
            let field = |k: &str| -> Stats {
                Stats::of(polished.iter().filter_map(|p| p[k].as_f64()).collect())
            };
            (!polished.is_empty()).then(|| PolishInfo {
                drapes: polished.len(),
                strain_p95_before: field("strain_p95_before"),
                mean_move: field("mean_move"),
                max_move: field("max_move"),
            })
        },
        seconds: Stats::of(ok.iter().map(|s| s.seconds).collect()),
        test_to_train_pose_deg: Stats::of(nearest),
        dqs_edist_cm: [(Split::Train, train_dqs), (Split::Test, test_dqs)]
            .into_iter()
            .filter(|(_, v)| !v.is_empty())
            .map(|(s, v)| (s, Stats::of(v)))
            .collect(),
        thin,
    })
}

#[cfg(test)]
mod thin_tests {
    use super::*;
    use glam::Vec3;

    #[test]
    fn thin_triangles_are_counted_by_their_smallest_angle() {
        // A right isosceles triangle (45°), one squashed to a 1.5° sliver, one degenerate.
        let x = [
            Vec3::ZERO,
            Vec3::X,
            Vec3::Y,
            Vec3::new(0.5, 0.013, 0.0),
            Vec3::new(2.0, 0.0, 0.0),
        ];
        let a: Vec<f64> = min_angles_deg(&x, &[[0, 1, 2], [0, 1, 3], [0, 1, 4]])
            .into_iter()
            .map(f64::from)
            .collect();
        assert!((a[0] - 45.0).abs() < 1e-9, "{a:?}");
        assert!(
            (a[1] - 0.013f64.atan2(0.5).to_degrees()).abs() < 1e-4,
            "{a:?}"
        );
        assert!(a[1] > 1.0 && a[1] < 2.0, "{a:?}");
        assert_eq!(a[2], 0.0);
        // Three drapes: one clean, one with the sliver, one with two triangles under 5°.
        let t = ThinInfo::of(14.2, &[vec![45.0, 30.0], vec![45.0, 1.5], vec![4.0, 0.5]]);
        assert_eq!(t.drapes, 3);
        assert_eq!(t.min_deg, 0.5);
        assert_eq!(t.drapes_below, vec![(1.0, 1), (2.0, 2), (5.0, 2)]);
        assert_eq!(t.most_in_a_drape, 2);
        assert_eq!(ThinInfo::of(14.2, &[]).min_deg, 180.0);
    }
}

/// The strain polish's figures over a dataset's converged drapes.
#[derive(Debug, Clone, Serialize)]
pub struct PolishInfo {
    /// Drapes that record it.
    pub drapes: usize,
    /// p95 edge strain before the polish.
    pub strain_p95_before: Stats,
    /// Mean distance the polish moved a particle, per drape (m).
    pub mean_move: Stats,
    /// Largest distance the polish moved a particle, per drape (m).
    pub max_move: Stats,
}

/// Checks every shard: size and sha256 against the manifest, tensor shapes, finite values,
/// ids. Returns the problems, each naming its file (empty: all good).
pub fn verify(dir: &Path) -> Result<(usize, Vec<String>), DatasetError> {
    let ds = Dataset::open(dir)?;
    let mut problems = Vec::new();
    let mut rows = 0usize;
    for s in &ds.manifest.shards {
        match ds.read_shard(&s.file) {
            Ok(r) => rows += r.len(),
            Err(e) => problems.push(e.to_string()),
        }
    }
    Ok((rows, problems))
}

/// Joins the part manifests found in `dirs` (all parts of one dataset, each shard in one of
/// the folders) into `out/manifest.json`, copying shards into `out` when they are elsewhere.
/// Every shard's sha256 is checked on the way.
pub fn merge(dirs: &[PathBuf], out: &Path, mixed_builds: bool) -> Result<Manifest, DatasetError> {
    let mut parts: BTreeMap<u32, (PathBuf, Manifest)> = BTreeMap::new();
    let mut total: Option<u32> = None;
    for d in dirs {
        let entries = std::fs::read_dir(d).map_err(|e| DatasetError::Io {
            path: d.clone(),
            source: e,
        })?;
        for e in entries.filter_map(Result::ok) {
            let name = e.file_name().to_string_lossy().to_string();
            if !(name.starts_with("manifest.part-") && name.ends_with(".json")) {
                continue;
            }
            let text = std::fs::read(e.path()).map_err(|err| DatasetError::Io {
                path: e.path(),
                source: err,
            })?;
            let m = Manifest::parse(&e.path(), &text)?;
            if *total.get_or_insert(m.parts) != m.parts {
                return Err(DatasetError::Invalid(format!(
                    "{} is part of {} parts, others of {}",
                    e.path().display(),
                    m.parts,
                    total.unwrap_or(0)
                )));
            }
            if let Some((other, _)) = parts.get(&m.part)
                && other != d
            {
                return Err(DatasetError::Invalid(format!(
                    "part {} found twice: in {} and {}",
                    m.part,
                    other.display(),
                    d.display()
                )));
            }
            parts.insert(m.part, (d.clone(), m));
        }
    }
    let n = total.ok_or_else(|| {
        DatasetError::Invalid("no manifest.part-*.json in the folders given".into())
    })?;
    let missing: Vec<u32> = (0..n).filter(|i| !parts.contains_key(i)).collect();
    if !missing.is_empty() {
        return Err(DatasetError::Invalid(format!(
            "parts {missing:?} of {n} are missing (run `drape gen CONFIG --shard I/{n}` for them)"
        )));
    }
    let first = &parts[&0].1;
    // A manifest written before the friction was recorded draped with its config's.
    let friction = |m: &Manifest| -> Result<f32, DatasetError> {
        Ok(match m.friction {
            Some(mu) => mu,
            None => m.dataset_config()?.sim.friction,
        })
    };
    for (i, (d, m)) in &parts {
        if m.config_sha256 != first.config_sha256
            || m.static_sha256 != first.static_sha256
            || m.size_templates != first.size_templates
            || friction(m)? != friction(first)?
            || m.garment_substeps != first.garment_substeps
            || m.garment_crease_contacts != first.garment_crease_contacts
            || m.below_band != first.below_band
        {
            return Err(DatasetError::Invalid(format!(
                "part {i} in {} was made from another config or template",
                d.display()
            )));
        }
        if m.program_sha256 != first.program_sha256 && !mixed_builds {
            return Err(DatasetError::Invalid(format!(
                "part {i} in {} was draped by another build of drape than part 0 (program sha256 {} against {}); two builds drape differently by up to 15 mm (docs/datasets.md): regenerate it with part 0's binary, or pass --mixed-builds to join them anyway",
                d.display(),
                crate::manifest::short_sha(&m.program_sha256),
                crate::manifest::short_sha(&first.program_sha256)
            )));
        }
    }
    // No drape gen may write into the folder while the merge writes its manifest.
    let _lock =
        crate::generate::lock_folder(out, crate::generate::GenOptions::default(), &mut |m| {
            eprintln!("{m}")
        })?;
    let copy = |from: &Path, name: &str, sha: &str| -> Result<(), DatasetError> {
        let src = from.join(name);
        let bytes = std::fs::read(&src).map_err(|e| DatasetError::Io {
            path: src.clone(),
            source: e,
        })?;
        if sha256(&bytes) != sha {
            return Err(DatasetError::Corrupt {
                path: src,
                reason: "sha256 differs from its part manifest's".into(),
            });
        }
        let dst = out.join(name);
        if std::fs::canonicalize(&src).ok() != std::fs::canonicalize(&dst).ok() {
            write_atomic(&dst, &bytes)?;
        }
        Ok(())
    };
    copy(&parts[&0].0, STATIC_FILE, &first.static_sha256)?;
    // Shards in plan order: part k holds plan shards k, k + n, ...
    let mut shards = Vec::new();
    let longest = parts
        .values()
        .map(|(_, m)| m.shards.len())
        .max()
        .unwrap_or(0);
    for j in 0..longest {
        for i in 0..n {
            let (d, m) = &parts[&i];
            if let Some(s) = m.shards.get(j) {
                copy(d, &s.file, &s.sha256)?;
                shards.push(s.clone());
            }
        }
    }
    let one_build = parts
        .values()
        .all(|(_, m)| m.program_sha256 == first.program_sha256);
    let merged = Manifest {
        part: 0,
        parts: 1,
        shards,
        program_sha256: first.program_sha256.clone().filter(|_| one_build),
        ..first.clone()
    };
    write_atomic(
        &out.join("manifest.json"),
        &serde_json::to_vec_pretty(&merged).expect("json"),
    )?;
    Ok(merged)
}
