//! The compact body asset: `assets/body/body.safetensors.gz`.
//!
//! A gzip-compressed safetensors file (readable from Python:
//! `safetensors.numpy.load(gzip.open(path).read())`). Tensors, all little-endian:
//!
//! | name            | dtype | shape     | content                                          |
//! |-----------------|-------|-----------|--------------------------------------------------|
//! | `base_vertices` | F32   | [V, 3]    | base.obj body vertices, metres, Y up             |
//! | `triangles`     | U32   | [F, 3]    | body quads split along their shorter diagonal    |
//! | `target_offsets`| U32   | [T + 1]   | start of each target in the two arrays below     |
//! | `target_indices`| U16   | [N]       | vertex of each sparse delta                      |
//! | `target_deltas` | F16   | [3, N]    | deltas (m), x row then y row then z row          |
//! | `joint_base`    | F32   | [J, 3]    | joint points of base.obj (cube means)            |
//! | `joint_deltas`  | F32   | [T, J, 3] | each target's exact effect on the joint points   |
//! | `skin_bones`    | U8    | [V, 4]    | top-4 bone influences                            |
//! | `skin_weights`  | F32   | [V, 4]    | their weights, renormalised to sum to one        |
//!
//! The safetensors metadata key `drape` holds JSON ([`AssetMeta`]): format version, bones,
//! joint point labels, the target file names behind each stored target, the T-pose, the
//! rig's reference joint positions and the provenance of the data.

use std::collections::{BTreeMap, HashMap};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

use flate2::Compression;
use flate2::read::GzDecoder;
use flate2::write::GzEncoder;
use glam::Vec3;
use half::f16;
use safetensors::tensor::{Dtype, SafeTensors, TensorView};
use serde::{Deserialize, Serialize};

use super::BodyError;
use super::pose::Pose;
use super::shape::{Factor, parse_target_name};
use super::skeleton::{Bone, Skeleton};
use super::skinning::SkinWeights;

/// Format tag written into every asset; bumped on incompatible changes.
pub const FORMAT: &str = "drape-body/1";

/// File name of the asset inside the assets folder.
pub const ASSET_FILE: &str = "body/body.safetensors.gz";

/// The assets folder of this source tree (what the `drape` program uses by default).
pub fn default_assets_dir() -> PathBuf {
    let sim_crate = Path::new(env!("CARGO_MANIFEST_DIR"));
    sim_crate.parent().unwrap_or(sim_crate).join("assets")
}

/// One stored shape target: the sum of one or more identical MakeHuman target files.
#[derive(Debug, Clone, PartialEq)]
pub struct Target {
    /// The target files (below `targets/macrodetails/`) that have exactly this content.
    pub names: Vec<String>,
    /// The axis values of each of those files; the target's weight is the sum over files.
    pub factors: Vec<Vec<Factor>>,
    /// Vertex indices of the sparse deltas.
    pub indices: Vec<u16>,
    /// Vertex deltas (m).
    pub deltas: Vec<Vec3>,
    /// Effect on every joint point (m).
    pub joint_deltas: Vec<Vec3>,
}

/// Where the body data came from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Provenance {
    /// Python package that ships the data.
    pub package: String,
    /// Its version.
    pub version: String,
    /// sha256 of the wheel file, as checked by `scripts/import-body.sh`.
    pub wheel_sha256: String,
    /// Licence of the data.
    pub license: String,
    /// sha256 of every source file read, by path inside the wheel.
    pub files: BTreeMap<String, String>,
}

/// JSON stored in the safetensors metadata under the key `drape`.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AssetMeta {
    /// Always [`FORMAT`].
    pub format: String,
    /// The rig.
    pub bones: Vec<Bone>,
    /// Label of each joint point (`joint-...` cube names, or `mean:a,b` for vertex means).
    pub joint_points: Vec<String>,
    /// Target file names behind each stored target.
    pub targets: Vec<Vec<String>>,
    /// The T-pose: Blender XYZ Euler angles (rad) per bone, from `poses/cmu_mb_fk/t-pose.json`.
    pub t_pose: BTreeMap<String, [f32; 3]>,
    /// The rig file's `default_position` of each bone's head and tail, drape axes (m).
    pub reference_joints: Vec<[[f32; 3]; 2]>,
    /// Data provenance.
    pub provenance: Provenance,
}

/// The decoded body model.
#[derive(Debug, Clone)]
pub struct BodyModel {
    /// Vertices of base.obj's body group (m, Y up). Not the default person: the race
    /// targets always apply.
    pub base_vertices: Vec<Vec3>,
    /// Triangles of the body surface.
    pub triangles: Vec<[u32; 3]>,
    /// Shape targets.
    pub targets: Vec<Target>,
    /// Joint points of base.obj.
    pub joint_base: Vec<Vec3>,
    /// What each joint point is.
    pub joint_labels: Vec<String>,
    /// The `cmu_mb` rig.
    pub skeleton: Skeleton,
    /// Top-4 skinning weights of the body vertices.
    pub skin: SkinWeights,
    /// The shipped T-pose.
    pub t_pose: Pose,
    /// The rig's `default_position` of each bone's head and tail (m, drape axes).
    pub reference_joints: Vec<[Vec3; 2]>,
    /// Where the data came from.
    pub provenance: Provenance,
}

fn corrupt(path: &Path, reason: impl Into<String>) -> BodyError {
    BodyError::Corrupt {
        path: path.to_path_buf(),
        reason: reason.into(),
    }
}

fn f32s(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn u32s(v: &[u32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn u16s(v: &[u16]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

fn vec3s(v: &[Vec3]) -> Vec<f32> {
    v.iter().flat_map(|p| p.to_array()).collect()
}

impl BodyModel {
    /// Loads the asset from an assets folder (`<dir>/body/body.safetensors.gz`).
    pub fn load_from_dir(dir: &Path) -> Result<Self, BodyError> {
        Self::load(&dir.join(ASSET_FILE))
    }

    /// Loads the asset of this source tree.
    pub fn load_default() -> Result<Self, BodyError> {
        Self::load_from_dir(&default_assets_dir())
    }

    /// Loads and validates a body asset file.
    pub fn load(path: &Path) -> Result<Self, BodyError> {
        let compressed = std::fs::read(path).map_err(|source| BodyError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let mut bytes = Vec::with_capacity(compressed.len() * 3);
        GzDecoder::new(compressed.as_slice())
            .read_to_end(&mut bytes)
            .map_err(|e| corrupt(path, format!("gzip: {e}")))?;
        Self::decode(&bytes, path)
    }

    /// Decodes uncompressed safetensors bytes; `path` only names the source in errors.
    pub fn decode(bytes: &[u8], path: &Path) -> Result<Self, BodyError> {
        let (_, header) = SafeTensors::read_metadata(bytes)
            .map_err(|e| corrupt(path, format!("safetensors header: {e}")))?;
        let meta_json = header
            .metadata()
            .as_ref()
            .and_then(|m| m.get("drape"))
            .ok_or_else(|| corrupt(path, "no `drape` metadata"))?;
        let meta: AssetMeta =
            serde_json::from_str(meta_json).map_err(|e| corrupt(path, format!("metadata: {e}")))?;
        if meta.format != FORMAT {
            return Err(corrupt(
                path,
                format!("format {:?}, expected {FORMAT:?}", meta.format),
            ));
        }
        let st = SafeTensors::deserialize(bytes)
            .map_err(|e| corrupt(path, format!("safetensors: {e}")))?;
        let get = |name: &str, dtype: Dtype, rank: usize| -> Result<TensorView<'_>, BodyError> {
            let t = st
                .tensor(name)
                .map_err(|_| corrupt(path, format!("tensor {name} missing")))?;
            if t.dtype() != dtype || t.shape().len() != rank {
                return Err(corrupt(
                    path,
                    format!(
                        "tensor {name} is {:?} {:?}, expected {dtype:?} of rank {rank}",
                        t.dtype(),
                        t.shape()
                    ),
                ));
            }
            Ok(t)
        };
        let read_f32 = |t: &TensorView<'_>| -> Vec<f32> {
            t.data()
                .chunks_exact(4)
                .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        };
        let read_u32 = |t: &TensorView<'_>| -> Vec<u32> {
            t.data()
                .chunks_exact(4)
                .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
                .collect()
        };
        let to_vec3 =
            |v: Vec<f32>| -> Vec<Vec3> { v.chunks_exact(3).map(Vec3::from_slice).collect() };

        let columns = |t: &TensorView<'_>, name: &str, n: usize| -> Result<(), BodyError> {
            match t.shape().last() {
                Some(&c) if c == n => Ok(()),
                _ => Err(corrupt(
                    path,
                    format!(
                        "tensor {name} has shape {:?}, expected {n} columns",
                        t.shape()
                    ),
                )),
            }
        };
        let base = get("base_vertices", Dtype::F32, 2)?;
        columns(&base, "base_vertices", 3)?;
        let base_vertices = to_vec3(read_f32(&base));
        let n_v = base_vertices.len();
        let tris_t = get("triangles", Dtype::U32, 2)?;
        columns(&tris_t, "triangles", 3)?;
        let tris = read_u32(&tris_t);
        if tris.iter().any(|&i| i as usize >= n_v) {
            return Err(corrupt(path, "triangle index out of range"));
        }
        let triangles: Vec<[u32; 3]> = tris.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect();

        let offsets = read_u32(&get("target_offsets", Dtype::U32, 1)?);
        let idx_t = get("target_indices", Dtype::U16, 1)?;
        let indices: Vec<u16> = idx_t
            .data()
            .chunks_exact(2)
            .map(|c| u16::from_le_bytes([c[0], c[1]]))
            .collect();
        let del_t = get("target_deltas", Dtype::F16, 2)?;
        let n = indices.len();
        if del_t.shape() != [3, n] {
            return Err(corrupt(path, "target_deltas does not match target_indices"));
        }
        let comps: Vec<f32> = del_t
            .data()
            .chunks_exact(2)
            .map(|c| f16::from_le_bytes([c[0], c[1]]).to_f32())
            .collect();
        let joint_t = get("joint_base", Dtype::F32, 2)?;
        columns(&joint_t, "joint_base", 3)?;
        let joint_base = to_vec3(read_f32(&joint_t));
        let n_j = joint_base.len();
        let jd_t = get("joint_deltas", Dtype::F32, 3)?;
        let n_t = meta.targets.len();
        if offsets.len() != n_t + 1
            || jd_t.shape() != [n_t, n_j, 3]
            || meta.joint_points.len() != n_j
        {
            return Err(corrupt(
                path,
                "target or joint tables disagree with the metadata",
            ));
        }
        if offsets.windows(2).any(|w| w[0] > w[1]) {
            return Err(corrupt(path, "target offsets are not increasing"));
        }
        if offsets[n_t] as usize != n {
            return Err(corrupt(
                path,
                "target offsets do not end at the number of deltas",
            ));
        }
        if indices.iter().any(|&i| i as usize >= n_v) {
            return Err(corrupt(path, "target vertex index out of range"));
        }
        let joint_deltas = to_vec3(read_f32(&jd_t));
        let finite = base_vertices
            .iter()
            .chain(&joint_base)
            .chain(&joint_deltas)
            .all(|v| v.is_finite())
            && comps.iter().all(|c| c.is_finite());
        if !finite {
            return Err(corrupt(path, "non-finite positions or deltas"));
        }
        let mut targets = Vec::with_capacity(n_t);
        for (t, names) in meta.targets.iter().enumerate() {
            let (a, b) = (offsets[t] as usize, offsets[t + 1] as usize);
            let factors = names
                .iter()
                .map(|name| {
                    parse_target_name(name)
                        .ok_or_else(|| corrupt(path, format!("unknown target name {name:?}")))
                })
                .collect::<Result<Vec<_>, _>>()?;
            targets.push(Target {
                names: names.clone(),
                factors,
                indices: indices[a..b].to_vec(),
                deltas: (a..b)
                    .map(|k| Vec3::new(comps[k], comps[n + k], comps[2 * n + k]))
                    .collect(),
                joint_deltas: joint_deltas[t * n_j..(t + 1) * n_j].to_vec(),
            });
        }

        let sb = get("skin_bones", Dtype::U8, 2)?;
        let sw_t = get("skin_weights", Dtype::F32, 2)?;
        if sb.shape() != [n_v, 4] || sw_t.shape() != [n_v, 4] {
            return Err(corrupt(path, "skinning tables do not match the vertices"));
        }
        let sw = read_f32(&sw_t);
        let bad_weights = sw.chunks_exact(4).any(|w| {
            w.iter().any(|x| !x.is_finite() || *x < 0.0)
                || (w.iter().sum::<f32>() - 1.0).abs() > 1e-3
        });
        if bad_weights {
            return Err(corrupt(
                path,
                "skinning weights are negative, non-finite or do not sum to one",
            ));
        }
        let n_b = meta.bones.len();
        let skin = SkinWeights {
            bones: sb
                .data()
                .chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]].map(u16::from))
                .collect(),
            weights: sw
                .chunks_exact(4)
                .map(|c| [c[0], c[1], c[2], c[3]])
                .collect(),
        };
        if skin.bones.iter().flatten().any(|&b| b as usize >= n_b) {
            return Err(corrupt(path, "skinning bone index out of range"));
        }
        for (i, b) in meta.bones.iter().enumerate() {
            if b.head >= n_j || b.tail >= n_j || b.parent.is_some_and(|p| p >= i) {
                return Err(corrupt(path, format!("bone {} is inconsistent", b.name)));
            }
        }
        if meta.reference_joints.len() != n_b {
            return Err(corrupt(path, "reference joints do not match the bones"));
        }
        let skeleton = Skeleton {
            bones: meta.bones.clone(),
        };
        let t_pose = Pose::from_euler_map(&skeleton, &meta.t_pose)
            .map_err(|e| corrupt(path, format!("T-pose: {e}")))?;
        Ok(Self {
            base_vertices,
            triangles,
            targets,
            joint_base,
            joint_labels: meta.joint_points.clone(),
            skeleton,
            skin,
            t_pose,
            reference_joints: meta
                .reference_joints
                .iter()
                .map(|[h, t]| [Vec3::from_array(*h), Vec3::from_array(*t)])
                .collect(),
            provenance: meta.provenance,
        })
    }

    /// Encodes the model as uncompressed safetensors bytes (deltas rounded to f16).
    pub fn encode(&self) -> Vec<u8> {
        let meta = AssetMeta {
            format: FORMAT.to_string(),
            bones: self.skeleton.bones.clone(),
            joint_points: self.joint_labels.clone(),
            targets: self.targets.iter().map(|t| t.names.clone()).collect(),
            t_pose: self
                .skeleton
                .bones
                .iter()
                .zip(&self.t_pose.rotations)
                .filter(|(_, q)| q.angle_between(glam::Quat::IDENTITY) > 1e-7)
                .map(|(b, q)| (b.name.clone(), super::pose::to_euler_xyz(*q)))
                .collect(),
            reference_joints: self
                .reference_joints
                .iter()
                .map(|[h, t]| [h.to_array(), t.to_array()])
                .collect(),
            provenance: self.provenance.clone(),
        };
        let n_v = self.base_vertices.len();
        let mut offsets = vec![0u32];
        let mut indices = Vec::new();
        let mut comps: [Vec<u16>; 3] = Default::default();
        let mut joint_deltas = Vec::new();
        for t in &self.targets {
            indices.extend_from_slice(&t.indices);
            for d in &t.deltas {
                for (k, c) in comps.iter_mut().enumerate() {
                    c.push(f16::from_f32(d[k]).to_bits());
                }
            }
            offsets.push(indices.len() as u32);
            joint_deltas.extend(vec3s(&t.joint_deltas));
        }
        let n = indices.len();
        let deltas: Vec<u16> = comps.concat();
        let tris: Vec<u32> = self.triangles.iter().flatten().copied().collect();
        let bones: Vec<u8> = self.skin.bones.iter().flatten().map(|&b| b as u8).collect();
        let weights: Vec<f32> = self.skin.weights.iter().flatten().copied().collect();
        let buffers: Vec<(&str, Dtype, Vec<usize>, Vec<u8>)> = vec![
            (
                "base_vertices",
                Dtype::F32,
                vec![n_v, 3],
                f32s(&vec3s(&self.base_vertices)),
            ),
            (
                "triangles",
                Dtype::U32,
                vec![self.triangles.len(), 3],
                u32s(&tris),
            ),
            (
                "target_offsets",
                Dtype::U32,
                vec![offsets.len()],
                u32s(&offsets),
            ),
            ("target_indices", Dtype::U16, vec![n], u16s(&indices)),
            ("target_deltas", Dtype::F16, vec![3, n], u16s(&deltas)),
            (
                "joint_base",
                Dtype::F32,
                vec![self.joint_base.len(), 3],
                f32s(&vec3s(&self.joint_base)),
            ),
            (
                "joint_deltas",
                Dtype::F32,
                vec![self.targets.len(), self.joint_base.len(), 3],
                f32s(&joint_deltas),
            ),
            ("skin_bones", Dtype::U8, vec![n_v, 4], bones),
            ("skin_weights", Dtype::F32, vec![n_v, 4], f32s(&weights)),
        ];
        let views: Vec<(&str, TensorView<'_>)> = buffers
            .iter()
            .map(|(name, dtype, shape, data)| {
                (*name, TensorView::new(*dtype, shape.clone(), data).unwrap())
            })
            .collect();
        let mut info = HashMap::new();
        info.insert("drape".to_string(), serde_json::to_string(&meta).unwrap());
        safetensors::tensor::serialize(views, Some(info)).unwrap()
    }

    /// The asset file's bytes: [`Self::encode`] compressed with [`compress`].
    pub fn to_compressed_bytes(&self) -> Vec<u8> {
        compress(&self.encode())
    }
}

/// Gzip at level 9, as the asset file is stored. The gzip header carries no time stamp, so
/// the same model always gives the same bytes.
pub fn compress(raw: &[u8]) -> Vec<u8> {
    let mut enc = GzEncoder::new(Vec::new(), Compression::best());
    enc.write_all(raw).expect("writing to memory");
    enc.finish().expect("writing to memory")
}
