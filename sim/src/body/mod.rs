//! The CC0 MakeHuman body model.
//!
//! Pipeline: [`BodyModel`] (the decoded asset) -> [`BodyModel::shape`] applies the macro
//! targets and recomputes the joints -> [`ShapedBody::pose`] runs forward kinematics and
//! linear blend skinning. All positions are metres, Y up, face towards +Z, the character's
//! left towards +X.

pub mod asset;
pub mod bvh;
pub mod import;
pub mod intersect;
pub mod measure;
pub mod pose;
pub mod shape;
pub mod skeleton;
pub mod skinning;

use std::path::PathBuf;

use glam::Vec3;

use crate::mesh::TriMesh;
pub use asset::{BodyModel, Target};
pub use measure::Girths;
pub use pose::{Family, Pose, PoseLibrary};
pub use shape::ShapeParams;
pub use skeleton::Skeleton;
pub use skinning::{Rigid, SkinWeights};

/// Number of vertices of the body surface (the `body` group of base.obj).
pub const BODY_VERTICES: usize = 13_380;

/// Errors of the body model: bad input, unreadable or corrupt files.
#[derive(Debug, thiserror::Error)]
pub enum BodyError {
    /// A file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// What the operating system said.
        #[source]
        source: std::io::Error,
    },
    /// A file exists but its content is not what it should be.
    #[error("{path} is corrupt or not a drape body asset: {reason}")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A pose file (MPFB's JSON) that cannot be read as a pose.
    #[error("{path} is not a pose file drape can read: {reason}")]
    BadPoseFile {
        /// The file.
        path: PathBuf,
        /// What is wrong with it.
        reason: String,
    },
    /// A shape parameter is out of range.
    #[error("shape parameter {name} = {value} is invalid: {reason}")]
    BadParameter {
        /// Parameter name.
        name: String,
        /// The value given.
        value: f32,
        /// Why it is rejected.
        reason: String,
    },
    /// A pose names a bone the rig does not have.
    #[error("unknown bone {0:?}: the cmu_mb rig has no such bone")]
    UnknownBone(String),
    /// A pose name that is neither a key pose nor a known pose source.
    #[error("unknown pose {name:?}; known poses: {}, or random:SEED, FILE.bvh:FRAME, FILE.json", known.join(", "))]
    UnknownPose {
        /// The name given.
        name: String,
        /// Names that would have worked.
        known: Vec<String>,
    },
    /// The pose library is inconsistent.
    #[error("pose library: {0}")]
    PoseLibrary(String),
    /// A BVH motion file could not be used.
    #[error("BVH file {path}: {reason}")]
    Bvh {
        /// The file.
        path: PathBuf,
        /// What is wrong (with the line number where there is one).
        reason: String,
    },
    /// A body could not be measured.
    #[error("cannot measure the body: {0}")]
    Measure(String),
    /// The MakeHuman data given to the importer is incomplete or unexpected.
    #[error("import from {path}: {reason}")]
    Import {
        /// The file or folder.
        path: PathBuf,
        /// What is wrong.
        reason: String,
    },
}

/// A body with its shape applied, in the rest (A-) pose.
#[derive(Debug, Clone)]
pub struct ShapedBody<'m> {
    /// The model it was made from.
    pub model: &'m BodyModel,
    /// Its shape parameters.
    pub params: ShapeParams,
    /// Rest-pose vertices (m).
    pub vertices: Vec<Vec3>,
    /// Joint points (m), indexed like [`BodyModel::joint_labels`].
    pub joints: Vec<Vec3>,
    /// World rest frames of the bones.
    pub rest_frames: Vec<Rigid>,
}

/// A shaped body in a pose.
#[derive(Debug, Clone)]
pub struct PosedBody {
    /// Posed vertices (m).
    pub vertices: Vec<Vec3>,
    /// Posed world frames of the bones.
    pub frames: Vec<Rigid>,
    /// Skinning transforms (rest world to posed world), one per bone.
    pub skinning: Vec<Rigid>,
}

impl BodyModel {
    /// Applies shape parameters: `v = base + sum_t w_t(params) delta_t`, and the same for
    /// the joint points, then builds the bone rest frames.
    pub fn shape(&self, params: &ShapeParams) -> Result<ShapedBody<'_>, BodyError> {
        params.validate()?;
        let mut vertices = self.base_vertices.clone();
        let mut joints = self.joint_base.clone();
        for (t, w) in self.targets.iter().zip(self.target_weights(params)) {
            if w == 0.0 {
                continue;
            }
            for (&i, &d) in t.indices.iter().zip(&t.deltas) {
                vertices[i as usize] += w * d;
            }
            for (j, &d) in joints.iter_mut().zip(&t.joint_deltas) {
                *j += w * d;
            }
        }
        let rest_frames = self.skeleton.rest_frames(&joints);
        Ok(ShapedBody {
            model: self,
            params: *params,
            vertices,
            joints,
            rest_frames,
        })
    }

    /// The weight `w_t(params)` of each shape target in [`Self::shape`]: the sum over the
    /// target's files of the product of their axis factors.
    pub fn target_weights(&self, params: &ShapeParams) -> Vec<f32> {
        self.targets
            .iter()
            .map(|t| t.factors.iter().map(|f| params.target_weight(f)).sum())
            .collect()
    }
}

impl ShapedBody<'_> {
    /// Forward kinematics and linear blend skinning (top-4 weights).
    pub fn pose(&self, pose: &Pose) -> PosedBody {
        let skeleton = &self.model.skeleton;
        let frames = skeleton.posed_frames(&self.rest_frames, pose);
        let skinning = skeleton.skinning_transforms(&self.rest_frames, &frames);
        let vertices = skinning::lbs(&self.vertices, &self.model.skin, &skinning);
        PosedBody {
            vertices,
            frames,
            skinning,
        }
    }

    /// Standing height: top of the head to the soles in the rest pose (m).
    pub fn height(&self) -> f32 {
        let (lo, hi) = crate::mesh::bounds(&self.vertices).unwrap_or((Vec3::ZERO, Vec3::ZERO));
        hi.y - lo.y
    }

    /// Rest-pose head and tail of the bone named `name` (m).
    pub fn rest_bone_ends(&self, name: &str) -> Result<(Vec3, Vec3), BodyError> {
        let skeleton = &self.model.skeleton;
        let b = skeleton
            .index(name)
            .ok_or_else(|| BodyError::UnknownBone(name.to_string()))?;
        let bone = &skeleton.bones[b];
        Ok((self.joints[bone.head], self.joints[bone.tail]))
    }

    /// Posed head and tail of a bone (m).
    pub fn bone_ends(&self, posed: &PosedBody, bone: usize) -> (Vec3, Vec3) {
        let b = &self.model.skeleton.bones[bone];
        let s = &posed.skinning[bone];
        (s.apply(self.joints[b.head]), s.apply(self.joints[b.tail]))
    }
}

impl PosedBody {
    /// The posed mesh.
    pub fn mesh(&self, model: &BodyModel) -> TriMesh {
        TriMesh::new(self.vertices.clone(), model.triangles.clone())
    }
}
