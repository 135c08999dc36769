//! The shard format: safetensors files of a fixed layout.
//!
//! A shard `SPLIT-NNNNN.safetensors` holds the drapes of consecutive samples of one split
//! (failed drapes left out), `n` rows:
//!
//! | tensor | dtype | shape | what |
//! |---|---|---|---|
//! | `id` | I64 | [n] | sample id (its index in the dataset's sampling order) |
//! | `body` | F32 | [n, Nb, 3] | posed body vertices (m) |
//! | `warped` | F32 | [n, N, 3] | the DQS-warped garment `M` (m) |
//! | `draped` | F32 | [n, N, 3] | the simulated garment `G` (m) |
//! | `shape` | F32 | [n, 9] | shape parameters, in [`SHAPE_FIELDS`] order |
//! | `pose` | F32 | [n, B, 4] | local bone rotations, quaternions (x, y, z, w) |
//! | `root` | F32 | [n, 3] | root translation (m) |
//!
//! and the metadata key `drape`: JSON `{"format": "drape-shard/1", "split": ..., "ids": [...]}`.
//! Shards hold no timings, so they are byte-identical across runs, threads and resumes.
//!
//! `static.safetensors` holds what all samples share: `garment_vertices` (F32 [N, 3], the
//! template on the canonical body), `garment_triangles` (U32 [F, 3]), `body_triangles` (U32
//! [Fb, 3]) and `canonical_body` (F32 [Nb, 3]).

use std::path::Path;

use glam::{Quat, Vec3};
use safetensors::tensor::{Dtype, SafeTensors};
use serde::{Deserialize, Serialize};

use crate::DatasetError;

/// Format tag of shard files.
pub const SHARD_FORMAT: &str = "drape-shard/1";
/// Format tag of the static file.
pub const STATIC_FORMAT: &str = "drape-static/1";
/// Name of the static file.
pub const STATIC_FILE: &str = "static.safetensors";
/// Order of the `shape` columns.
pub const SHAPE_FIELDS: [&str; 9] = [
    "gender",
    "age",
    "muscle",
    "weight",
    "height",
    "proportions",
    "african",
    "asian",
    "caucasian",
];

/// One drape as stored in a shard.
#[derive(Debug, Clone, PartialEq)]
pub struct Row {
    /// Sample id.
    pub id: u64,
    /// Posed body vertices (m).
    pub body: Vec<Vec3>,
    /// DQS-warped garment M (m).
    pub warped: Vec<Vec3>,
    /// Simulated garment G (m).
    pub draped: Vec<Vec3>,
    /// Shape parameters in [`SHAPE_FIELDS`] order.
    pub shape: [f32; 9],
    /// Local bone rotations.
    pub pose: Vec<Quat>,
    /// Root translation (m).
    pub root: Vec3,
}

impl Row {
    /// The simulator's departure from the warp, `G - M` per vertex (m).
    pub fn displacement(&self) -> Vec<Vec3> {
        self.draped
            .iter()
            .zip(&self.warped)
            .map(|(g, m)| *g - *m)
            .collect()
    }
}

/// Shard metadata.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ShardMeta {
    /// [`SHARD_FORMAT`].
    pub format: String,
    /// Split name.
    pub split: String,
    /// Sample ids of the rows, in order.
    pub ids: Vec<u64>,
}

fn f32s(it: impl Iterator<Item = f32>) -> Vec<u8> {
    it.flat_map(f32::to_le_bytes).collect()
}

fn vecs(v: &[Vec3]) -> impl Iterator<Item = f32> + '_ {
    v.iter().flat_map(|p| p.to_array())
}

fn vec3s(d: &[f32]) -> Vec<Vec3> {
    d.chunks_exact(3).map(Vec3::from_slice).collect()
}

/// Serialises named tensors with the `drape` metadata (see `sim::io::safetensors_bytes`).
pub fn serialize(tensors: &[sim::io::NamedTensor<'_>], meta: &impl Serialize) -> Vec<u8> {
    sim::io::safetensors_bytes(tensors, meta)
}

/// The tensors of the table above for `rows` (all with the same vertex counts): a shard's,
/// and a single finished drape's while its shard is not yet assembled.
pub(crate) fn row_tensors(
    rows: &[Row],
    nb: usize,
    n: usize,
    bones: usize,
) -> Vec<sim::io::NamedTensor<'static>> {
    let k = rows.len();
    vec![
        (
            "id",
            Dtype::I64,
            vec![k],
            rows.iter()
                .flat_map(|r| (r.id as i64).to_le_bytes())
                .collect(),
        ),
        (
            "body",
            Dtype::F32,
            vec![k, nb, 3],
            f32s(rows.iter().flat_map(|r| vecs(&r.body))),
        ),
        (
            "warped",
            Dtype::F32,
            vec![k, n, 3],
            f32s(rows.iter().flat_map(|r| vecs(&r.warped))),
        ),
        (
            "draped",
            Dtype::F32,
            vec![k, n, 3],
            f32s(rows.iter().flat_map(|r| vecs(&r.draped))),
        ),
        (
            "shape",
            Dtype::F32,
            vec![k, 9],
            f32s(rows.iter().flat_map(|r| r.shape)),
        ),
        (
            "pose",
            Dtype::F32,
            vec![k, bones, 4],
            f32s(
                rows.iter()
                    .flat_map(|r| r.pose.iter().flat_map(|q| q.to_array())),
            ),
        ),
        (
            "root",
            Dtype::F32,
            vec![k, 3],
            f32s(rows.iter().flat_map(|r| r.root.to_array())),
        ),
    ]
}

/// Encodes rows of one split (all with the same vertex counts) into shard bytes.
pub fn encode_shard(split: &str, rows: &[Row], nb: usize, n: usize, bones: usize) -> Vec<u8> {
    let meta = ShardMeta {
        format: SHARD_FORMAT.into(),
        split: split.into(),
        ids: rows.iter().map(|r| r.id).collect(),
    };
    serialize(&row_tensors(rows, nb, n, bones), &meta)
}

/// Reads the rows written by [`row_tensors`], checking that they are `ids`, in order.
pub(crate) fn read_rows(
    r: &Reader<'_>,
    ids: &[u64],
    nb: usize,
    n: usize,
    bones: usize,
) -> Result<Vec<Row>, DatasetError> {
    let k = ids.len();
    let (_, idb) = r.raw("id", Dtype::I64, &[Some(k)])?;
    let stored: Vec<u64> = idb
        .chunks_exact(8)
        .map(|c| i64::from_le_bytes(c.try_into().expect("8 bytes")) as u64)
        .collect();
    if stored != ids {
        return Err(r.bad("tensor `id` disagrees with the metadata's ids".into()));
    }
    let body = r.f32s("body", &[Some(k), Some(nb), Some(3)])?;
    let warped = r.f32s("warped", &[Some(k), Some(n), Some(3)])?;
    let draped = r.f32s("draped", &[Some(k), Some(n), Some(3)])?;
    let shape = r.f32s("shape", &[Some(k), Some(9)])?;
    let pose = r.f32s("pose", &[Some(k), Some(bones), Some(4)])?;
    let root = r.f32s("root", &[Some(k), Some(3)])?;
    Ok((0..k)
        .map(|i| Row {
            id: ids[i],
            body: vec3s(&body[i * nb * 3..(i + 1) * nb * 3]),
            warped: vec3s(&warped[i * n * 3..(i + 1) * n * 3]),
            draped: vec3s(&draped[i * n * 3..(i + 1) * n * 3]),
            shape: shape[i * 9..(i + 1) * 9].try_into().expect("9"),
            pose: pose[i * bones * 4..(i + 1) * bones * 4]
                .chunks_exact(4)
                .map(Quat::from_slice)
                .collect(),
            root: Vec3::from_slice(&root[i * 3..i * 3 + 3]),
        })
        .collect())
}

/// Reads tensors of a safetensors file with shape checks, naming the file in every error.
pub struct Reader<'a> {
    path: &'a Path,
    st: SafeTensors<'a>,
}

impl std::fmt::Debug for Reader<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Reader").field("path", &self.path).finish()
    }
}

impl<'a> Reader<'a> {
    /// Parses `bytes` read from `path`.
    pub fn new(path: &'a Path, bytes: &'a [u8]) -> Result<Self, DatasetError> {
        let st = SafeTensors::deserialize(bytes).map_err(|e| DatasetError::Corrupt {
            path: path.to_path_buf(),
            reason: format!("not a readable safetensors file: {e}"),
        })?;
        Ok(Self { path, st })
    }

    /// An error about this file.
    pub fn bad(&self, reason: String) -> DatasetError {
        DatasetError::Corrupt {
            path: self.path.to_path_buf(),
            reason,
        }
    }

    /// The raw bytes of tensor `name`, checked to be `dtype` with `shape` (`None` = any
    /// length on that axis); returns the shape.
    pub fn raw(
        &self,
        name: &str,
        dtype: Dtype,
        shape: &[Option<usize>],
    ) -> Result<(Vec<usize>, &'a [u8]), DatasetError> {
        let t = self
            .st
            .tensor(name)
            .map_err(|_| self.bad(format!("tensor `{name}` is missing")))?;
        let s = t.shape().to_vec();
        let ok = t.dtype() == dtype
            && s.len() == shape.len()
            && s.iter().zip(shape).all(|(a, b)| b.is_none_or(|b| b == *a));
        if !ok {
            return Err(self.bad(format!(
                "tensor `{name}` is {:?} {s:?}, expected {dtype:?} {shape:?}",
                t.dtype()
            )));
        }
        Ok((s, t.data()))
    }

    /// An F32 tensor as numbers, every one checked finite.
    pub fn f32s(&self, name: &str, shape: &[Option<usize>]) -> Result<Vec<f32>, DatasetError> {
        let (_, d) = self.raw(name, Dtype::F32, shape)?;
        let v: Vec<f32> = d
            .chunks_exact(4)
            .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect();
        if let Some(k) = v.iter().position(|x| !x.is_finite()) {
            return Err(self.bad(format!("tensor `{name}` has a non-finite value at {k}")));
        }
        Ok(v)
    }

    /// A U32 tensor.
    pub fn u32s(&self, name: &str, shape: &[Option<usize>]) -> Result<Vec<u32>, DatasetError> {
        let (_, d) = self.raw(name, Dtype::U32, shape)?;
        Ok(d.chunks_exact(4)
            .map(|c| u32::from_le_bytes([c[0], c[1], c[2], c[3]]))
            .collect())
    }

    /// The `drape` metadata JSON.
    pub fn meta<T: for<'de> Deserialize<'de>>(
        bytes: &[u8],
        path: &Path,
    ) -> Result<T, DatasetError> {
        let bad = |reason: String| DatasetError::Corrupt {
            path: path.to_path_buf(),
            reason,
        };
        let (_, header) = SafeTensors::read_metadata(bytes)
            .map_err(|e| bad(format!("not a readable safetensors file: {e}")))?;
        let text = header
            .metadata()
            .as_ref()
            .and_then(|m| m.get("drape"))
            .ok_or_else(|| bad("no `drape` metadata".into()))?;
        serde_json::from_str(text).map_err(|e| bad(format!("metadata: {e}")))
    }
}

/// Decodes and checks a whole shard: `nb` body vertices, `n` garment vertices, `bones`.
pub fn decode_shard(
    path: &Path,
    bytes: &[u8],
    nb: usize,
    n: usize,
    bones: usize,
) -> Result<(ShardMeta, Vec<Row>), DatasetError> {
    let meta: ShardMeta = Reader::meta(bytes, path)?;
    let r = Reader::new(path, bytes)?;
    if meta.format != SHARD_FORMAT {
        return Err(r.bad(format!(
            "format {:?}, expected {SHARD_FORMAT:?}",
            meta.format
        )));
    }
    let rows = read_rows(&r, &meta.ids, nb, n, bones)?;
    Ok((meta, rows))
}

/// What all samples share.
#[derive(Debug, Clone, PartialEq)]
pub struct Static {
    /// The garment template on the canonical body (m).
    pub garment_vertices: Vec<Vec3>,
    /// Garment triangles.
    pub garment_triangles: Vec<[u32; 3]>,
    /// Body triangles.
    pub body_triangles: Vec<[u32; 3]>,
    /// The canonical body's vertices (m).
    pub canonical_body: Vec<Vec3>,
    /// Bones of the skeleton (the `pose` tensor's second axis).
    pub bones: usize,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct StaticMeta {
    format: String,
    bones: usize,
}

impl Static {
    /// What a dataset of `garment` (its template mesh) on `model` stores once: the
    /// template, its faces, the body's faces, the canonical body (`canonical`, the model
    /// at the default shape in its rest pose) and the skeleton's bone count.
    pub fn new(
        garment: &sim::mesh::TriMesh,
        model: &sim::body::BodyModel,
        canonical: &[Vec3],
    ) -> Self {
        Self {
            garment_vertices: garment.vertices.clone(),
            garment_triangles: garment.triangles.clone(),
            body_triangles: model.triangles.clone(),
            canonical_body: canonical.to_vec(),
            bones: model.skeleton.len(),
        }
    }

    /// Safetensors bytes.
    pub fn encode(&self) -> Vec<u8> {
        let u32s = |t: &[[u32; 3]]| -> Vec<u8> {
            t.iter().flatten().flat_map(|i| i.to_le_bytes()).collect()
        };
        let tensors = vec![
            (
                "garment_vertices",
                Dtype::F32,
                vec![self.garment_vertices.len(), 3],
                f32s(vecs(&self.garment_vertices)),
            ),
            (
                "garment_triangles",
                Dtype::U32,
                vec![self.garment_triangles.len(), 3],
                u32s(&self.garment_triangles),
            ),
            (
                "body_triangles",
                Dtype::U32,
                vec![self.body_triangles.len(), 3],
                u32s(&self.body_triangles),
            ),
            (
                "canonical_body",
                Dtype::F32,
                vec![self.canonical_body.len(), 3],
                f32s(vecs(&self.canonical_body)),
            ),
        ];
        serialize(
            &tensors,
            &StaticMeta {
                format: STATIC_FORMAT.into(),
                bones: self.bones,
            },
        )
    }

    /// Decodes and checks a static file.
    pub fn decode(path: &Path, bytes: &[u8]) -> Result<Self, DatasetError> {
        let meta: StaticMeta = Reader::meta(bytes, path)?;
        let r = Reader::new(path, bytes)?;
        if meta.format != STATIC_FORMAT {
            return Err(r.bad(format!(
                "format {:?}, expected {STATIC_FORMAT:?}",
                meta.format
            )));
        }
        let t3 = |d: Vec<u32>| {
            d.chunks_exact(3)
                .map(|c| [c[0], c[1], c[2]])
                .collect::<Vec<_>>()
        };
        let garment_vertices = vec3s(&r.f32s("garment_vertices", &[None, Some(3)])?);
        let canonical_body = vec3s(&r.f32s("canonical_body", &[None, Some(3)])?);
        let garment_triangles = t3(r.u32s("garment_triangles", &[None, Some(3)])?);
        let body_triangles = t3(r.u32s("body_triangles", &[None, Some(3)])?);
        if garment_triangles
            .iter()
            .flatten()
            .any(|&i| i as usize >= garment_vertices.len())
            || body_triangles
                .iter()
                .flatten()
                .any(|&i| i as usize >= canonical_body.len())
        {
            return Err(r.bad("a triangle indexes beyond its vertices".into()));
        }
        Ok(Self {
            garment_vertices,
            garment_triangles,
            body_triangles,
            canonical_body,
            bones: meta.bones,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn row(id: u64, nb: usize, n: usize, bones: usize) -> Row {
        let f = id as f32;
        Row {
            id,
            body: (0..nb).map(|i| Vec3::splat(f + i as f32)).collect(),
            warped: (0..n).map(|i| Vec3::new(f, i as f32, 1.0)).collect(),
            draped: (0..n).map(|i| Vec3::new(f, i as f32, 2.0)).collect(),
            shape: [0.5; 9],
            pose: vec![Quat::from_rotation_y(f); bones],
            root: Vec3::new(0.0, f, 0.0),
        }
    }

    #[test]
    fn shards_round_trip_and_bad_bytes_are_named() {
        let rows = vec![row(3, 5, 4, 2), row(7, 5, 4, 2)];
        let bytes = encode_shard("train", &rows, 5, 4, 2);
        let p = Path::new("train-00000.safetensors");
        let (meta, back) = decode_shard(p, &bytes, 5, 4, 2).unwrap();
        assert_eq!(meta.ids, vec![3, 7]);
        assert_eq!(back, rows);
        // Deterministic bytes.
        assert_eq!(bytes, encode_shard("train", &rows, 5, 4, 2));
        // Truncated and wrong-shaped files are refused with the file's name.
        let e = decode_shard(p, &bytes[..bytes.len() - 10], 5, 4, 2).unwrap_err();
        assert!(e.to_string().contains("train-00000"), "{e}");
        let e = decode_shard(p, &bytes, 6, 4, 2).unwrap_err();
        assert!(e.to_string().contains("body"), "{e}");
        // An empty shard (every drape failed) is valid.
        let empty = encode_shard("val", &[], 5, 4, 2);
        assert!(decode_shard(p, &empty, 5, 4, 2).unwrap().1.is_empty());
    }
}
