//! Poses: per-bone local rotations plus a root translation, Blender Euler I/O, and the
//! pose library (named key poses, joint limits, motion families) read from
//! `configs/poses/library.toml`.

use std::collections::BTreeMap;
use std::path::Path;

use glam::{EulerRot, Quat, Vec3};
use serde::Deserialize;

use super::BodyError;
use super::skeleton::Skeleton;

/// A pose of the skeleton.
#[derive(Debug, Clone, PartialEq)]
pub struct Pose {
    /// Local rotation of each bone relative to its rest frame, in skeleton order.
    pub rotations: Vec<Quat>,
    /// Translation of the root (m, world axes).
    pub root_translation: Vec3,
}

/// Blender's XYZ Euler rotation (radians): `Rz * Ry * Rx`, X applied first.
pub fn euler_xyz(x: f32, y: f32, z: f32) -> Quat {
    Quat::from_rotation_z(z) * Quat::from_rotation_y(y) * Quat::from_rotation_x(x)
}

/// Inverse of [`euler_xyz`]: `(x, y, z)` in radians.
pub fn to_euler_xyz(q: Quat) -> [f32; 3] {
    let (z, y, x) = q.to_euler(EulerRot::ZYX);
    [x, y, z]
}

impl Pose {
    /// The rest pose (the asset's A-pose) of a skeleton with `bones` bones.
    pub fn rest(bones: usize) -> Self {
        Self {
            rotations: vec![Quat::IDENTITY; bones],
            root_translation: Vec3::ZERO,
        }
    }

    /// A pose from Blender XYZ Euler angles (radians) per bone name; bones not named keep
    /// their rest rotation.
    pub fn from_euler_map(
        skeleton: &Skeleton,
        angles: &BTreeMap<String, [f32; 3]>,
    ) -> Result<Self, BodyError> {
        let mut pose = Self::rest(skeleton.len());
        for (name, &[x, y, z]) in angles {
            let i = skeleton
                .index(name)
                .ok_or_else(|| BodyError::UnknownBone(name.clone()))?;
            pose.rotations[i] = euler_xyz(x, y, z);
        }
        Ok(pose)
    }

    /// Reads an MPFB pose file (`{"bone_rotations": {bone: [x, y, z]}, ...}`, Blender XYZ
    /// Euler radians), such as the T-pose `poses/cmu_mb_fk/t-pose.json`.
    pub fn from_mpfb_json(
        skeleton: &Skeleton,
        text: &str,
        origin: &Path,
    ) -> Result<Self, BodyError> {
        #[derive(Deserialize)]
        struct MpfbPose {
            bone_rotations: BTreeMap<String, serde_json::Value>,
            #[serde(default)]
            bone_translations: BTreeMap<String, serde_json::Value>,
            #[serde(default)]
            bone_rotation_modes: BTreeMap<String, String>,
        }
        let bad = |reason: String| BodyError::BadPoseFile {
            path: origin.to_path_buf(),
            reason,
        };
        let parsed: MpfbPose =
            serde_json::from_str(text).map_err(|e| bad(format!("not an MPFB pose file: {e}")))?;
        // Bone translations live in each bone's rest frame; drape's poses carry only the
        // root's world translation, so files that move bones are refused, not misread.
        if let Some(bone) = parsed.bone_translations.keys().next() {
            return Err(bad(format!(
                "bone translations (of {bone}) are not supported"
            )));
        }
        let mut angles = BTreeMap::new();
        for (bone, value) in &parsed.bone_rotations {
            let mode = parsed
                .bone_rotation_modes
                .get(bone)
                .map_or("XYZ", String::as_str);
            if mode != "XYZ" {
                return Err(bad(format!(
                    "{bone}: rotation mode {mode}; only XYZ Euler angles are supported"
                )));
            }
            let xyz: [f32; 3] = serde_json::from_value(value.clone()).map_err(|_| {
                bad(format!(
                    "{bone}: expected three Euler angles, found {value}"
                ))
            })?;
            if xyz.iter().any(|a| !a.is_finite()) {
                return Err(bad(format!("{bone}: non-finite angle")));
            }
            angles.insert(bone.clone(), xyz);
        }
        Self::from_euler_map(skeleton, &angles).map_err(|e| bad(e.to_string()))
    }

    /// Per-bone spherical interpolation between two poses (`t` = 0 gives `self`).
    pub fn slerp(&self, other: &Pose, t: f32) -> Pose {
        Pose {
            rotations: self
                .rotations
                .iter()
                .zip(&other.rotations)
                .map(|(a, b)| a.slerp(*b, t).normalize())
                .collect(),
            root_translation: self.root_translation.lerp(other.root_translation, t),
        }
    }
}

/// A motion family of the pose prior (the families of the paper's CMU motions).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Family {
    /// Walking: phases of a gait cycle.
    Walking,
    /// Dance: arm and leg gestures.
    Dance,
    /// Yoga: wide stances, balances, stretches.
    Yoga,
}

impl Family {
    /// Every family, in a fixed order.
    pub const ALL: [Family; 3] = [Family::Walking, Family::Dance, Family::Yoga];

    /// The family's name as written in configs and metadata.
    pub fn name(self) -> &'static str {
        match self {
            Family::Walking => "walking",
            Family::Dance => "dance",
            Family::Yoga => "yoga",
        }
    }
}

/// How a family blends its key poses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BlendMode {
    /// Blend neighbours of a cyclic sequence (gait phases).
    Cycle,
    /// Blend any two key poses of the family.
    Any,
}

/// One family's definition in the library.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FamilySpec {
    /// Relative probability of the family when sampling.
    pub weight: f32,
    /// How key poses are paired for blending.
    pub blend: BlendMode,
    /// Key poses of the family (names from `[keyposes]`, or `rest` / `t-pose`).
    pub keyposes: Vec<String>,
}

/// Per-bone limits of Blender XYZ Euler angles (degrees), `[min, max]` per axis.
#[derive(Debug, Clone, Copy, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JointLimit {
    /// Range of the X angle (deg).
    pub x: [f32; 2],
    /// Range of the Y angle (deg).
    pub y: [f32; 2],
    /// Range of the Z angle (deg).
    pub z: [f32; 2],
    /// Standard deviation of the random perturbation of this bone (deg).
    #[serde(default)]
    pub jitter: f32,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct LibraryFile {
    limits: BTreeMap<String, JointLimit>,
    families: BTreeMap<Family, FamilySpec>,
    keyposes: BTreeMap<String, BTreeMap<String, [f32; 3]>>,
}

/// The built-in pose library: `configs/poses/library.toml`.
pub const LIBRARY_TOML: &str = include_str!("../../../configs/poses/library.toml");

/// Named key poses, joint limits and motion families (see `configs/poses/library.toml`).
#[derive(Debug, Clone)]
pub struct PoseLibrary {
    /// Key poses by name, including `rest` and `t-pose`.
    pub keyposes: BTreeMap<String, Pose>,
    /// Joint limits by bone index (`None`: the bone stays at rest in sampled poses).
    pub limits: Vec<Option<JointLimit>>,
    /// Families by name.
    pub families: BTreeMap<Family, FamilySpec>,
}

impl PoseLibrary {
    /// Parses a library from TOML text; `t_pose` is the asset's T-pose.
    pub fn from_toml(skeleton: &Skeleton, text: &str, t_pose: &Pose) -> Result<Self, BodyError> {
        let file: LibraryFile =
            toml::from_str(text).map_err(|e| BodyError::PoseLibrary(e.to_string()))?;
        let mut keyposes = BTreeMap::new();
        keyposes.insert("rest".to_string(), Pose::rest(skeleton.len()));
        keyposes.insert("t-pose".to_string(), t_pose.clone());
        for (name, angles) in &file.keyposes {
            let radians = angles
                .iter()
                .map(|(b, a)| (b.clone(), a.map(f32::to_radians)))
                .collect::<BTreeMap<_, _>>();
            keyposes.insert(name.clone(), Pose::from_euler_map(skeleton, &radians)?);
        }
        let mut limits = vec![None; skeleton.len()];
        for (bone, lim) in &file.limits {
            let i = skeleton
                .index(bone)
                .ok_or_else(|| BodyError::UnknownBone(bone.clone()))?;
            let ranges_ok = [lim.x, lim.y, lim.z]
                .iter()
                .all(|[lo, hi]| lo.is_finite() && hi.is_finite() && lo <= hi);
            if !ranges_ok || !lim.jitter.is_finite() || lim.jitter < 0.0 {
                return Err(BodyError::PoseLibrary(format!(
                    "limits of {bone}: every range must be [min, max] with min <= max, jitter >= 0"
                )));
            }
            limits[i] = Some(*lim);
        }
        let total: f32 = file.families.values().map(|f| f.weight).sum();
        let weights_ok = file
            .families
            .values()
            .all(|f| f.weight.is_finite() && f.weight >= 0.0);
        if file.families.is_empty() || !weights_ok || total <= 0.0 {
            return Err(BodyError::PoseLibrary(
                "at least one family, with weights >= 0 that do not all vanish".into(),
            ));
        }
        for (family, spec) in &file.families {
            for k in &spec.keyposes {
                if !keyposes.contains_key(k) {
                    return Err(BodyError::PoseLibrary(format!(
                        "family {} names key pose {k:?}, which is not defined",
                        family.name()
                    )));
                }
            }
            if spec.keyposes.len() < 2 {
                return Err(BodyError::PoseLibrary(format!(
                    "family {} needs at least two key poses",
                    family.name()
                )));
            }
        }
        let lib = Self {
            keyposes,
            limits,
            families: file.families,
        };
        // Key poses must respect the limits they will be clamped to.
        for (name, pose) in &lib.keyposes {
            if name == "t-pose" {
                continue;
            }
            let clamped = lib.clamp(pose);
            for (i, (a, b)) in pose.rotations.iter().zip(&clamped.rotations).enumerate() {
                if a.angle_between(*b) > 1e-3 {
                    let why = if lib.limits[i].is_some() {
                        "breaks the joint limits of"
                    } else {
                        "rotates a bone without limits,"
                    };
                    return Err(BodyError::PoseLibrary(format!(
                        "key pose {name:?} {why} {}",
                        skeleton.bones[i].name
                    )));
                }
            }
        }
        Ok(lib)
    }

    /// A key pose by name.
    pub fn get(&self, name: &str) -> Result<&Pose, BodyError> {
        self.keyposes
            .get(name)
            .ok_or_else(|| BodyError::UnknownPose {
                name: name.to_string(),
                known: self.keyposes.keys().cloned().collect(),
            })
    }

    /// The pose with every limited bone's Euler angles clamped to its limits and every
    /// unlimited bone at rest.
    pub fn clamp(&self, pose: &Pose) -> Pose {
        let rotations = pose
            .rotations
            .iter()
            .zip(&self.limits)
            .map(|(q, lim)| match lim {
                None => Quat::IDENTITY,
                Some(l) => {
                    let [x, y, z] = to_euler_xyz(*q);
                    let c = |v: f32, r: [f32; 2]| v.clamp(r[0].to_radians(), r[1].to_radians());
                    euler_xyz(c(x, l.x), c(y, l.y), c(z, l.z))
                }
            })
            .collect();
        Pose {
            rotations,
            root_translation: pose.root_translation,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn euler_round_trip() {
        for &(x, y, z) in &[
            (0.1f32, -0.4f32, 0.9f32),
            (-1.2, 0.3, -2.0),
            (0.0, 0.0, 0.0),
        ] {
            let [a, b, c] = to_euler_xyz(euler_xyz(x, y, z));
            assert!((a - x).abs() < 1e-5 && (b - y).abs() < 1e-5 && (c - z).abs() < 1e-5);
        }
        // X applied first: a quarter turn about X then about Z takes +Y to +Z then keeps it.
        let q = euler_xyz(
            std::f32::consts::FRAC_PI_2,
            0.0,
            std::f32::consts::FRAC_PI_2,
        );
        assert!((q * Vec3::Y - Vec3::Z).length() < 1e-6);
    }
}
