//! The `cmu_mb` skeleton: bone frames as Blender computes them, and forward kinematics.
//!
//! A bone's rest frame has its Y axis along `tail - head` and is rolled about that axis by
//! the bone's `roll`. Blender defines the zero-roll frame as the shortest-arc rotation of
//! its world Y axis onto the bone direction *in Blender's axes* (Z up), so frames are built
//! there and then turned into drape's Y-up world with `C = RotX(-90 deg)`, which maps
//! Blender `(x, y, z)` to drape `(x, z, -y)`.
//!
//! Forward kinematics, with `L_b` the bone's local rotation:
//! `Pose_b = Pose_parent * Rest_parent^-1 * Rest_b * L_b` (the root also gets the pose's
//! translation); the skinning transform is `Pose_b * Rest_b^-1`.

use glam::{Quat, Vec3};
use serde::{Deserialize, Serialize};

use super::pose::Pose;
use super::skinning::Rigid;

/// One bone of the rig.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Bone {
    /// Bone name (CMU naming).
    pub name: String,
    /// Index of the parent bone, `None` for the root. Parents come before children.
    pub parent: Option<usize>,
    /// Roll about the bone axis (rad), Blender convention.
    pub roll: f32,
    /// Index of the joint point at the bone's head.
    pub head: usize,
    /// Index of the joint point at the bone's tail.
    pub tail: usize,
}

/// The bones of a rig, parents before children.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Skeleton {
    /// Bones in topological order.
    pub bones: Vec<Bone>,
}

/// Blender's axes to drape's: `(x, y, z) -> (x, z, -y)`.
pub fn blender_to_yup() -> Quat {
    Quat::from_rotation_x(-std::f32::consts::FRAC_PI_2)
}

/// Blender's zero-roll bone rotation: the shortest arc taking +Y onto `dir` (unit, in
/// Blender axes), with a half turn about Z when `dir` points straight down -Y (Blender's
/// own cut-off: x^2 + z^2 at most 2.5e-4 squared).
fn zero_roll_rotation(dir: Vec3) -> Quat {
    if dir.y < 0.0 && dir.x * dir.x + dir.z * dir.z <= 6.25e-8 {
        Quat::from_rotation_z(std::f32::consts::PI)
    } else {
        Quat::from_rotation_arc(Vec3::Y, dir)
    }
}

impl Skeleton {
    /// Number of bones.
    pub fn len(&self) -> usize {
        self.bones.len()
    }

    /// True if the skeleton has no bones.
    pub fn is_empty(&self) -> bool {
        self.bones.is_empty()
    }

    /// Index of a bone by name.
    pub fn index(&self, name: &str) -> Option<usize> {
        self.bones.iter().position(|b| b.name == name)
    }

    /// World rest frames (Y up) of every bone from the joint points of a shaped body.
    pub fn rest_frames(&self, joints: &[Vec3]) -> Vec<Rigid> {
        let c = blender_to_yup();
        let c_inv = c.conjugate();
        self.bones
            .iter()
            .map(|b| {
                let head = joints[b.head];
                let dir_blender = (c_inv * (joints[b.tail] - head)).normalize();
                let r_blender = zero_roll_rotation(dir_blender) * Quat::from_rotation_y(b.roll);
                Rigid::new((c * r_blender).normalize(), head)
            })
            .collect()
    }

    /// Posed world frames of every bone.
    pub fn posed_frames(&self, rest: &[Rigid], pose: &Pose) -> Vec<Rigid> {
        let mut out: Vec<Rigid> = Vec::with_capacity(self.bones.len());
        for (i, b) in self.bones.iter().enumerate() {
            let local = Rigid::new(pose.rotations[i], Vec3::ZERO);
            let frame = match b.parent {
                Some(p) => out[p] * rest[p].inverse() * rest[i] * local,
                None => Rigid::new(Quat::IDENTITY, pose.root_translation) * rest[i] * local,
            };
            out.push(frame);
        }
        out
    }

    /// Skinning transforms `Pose_b * Rest_b^-1` (rest world space to posed world space).
    pub fn skinning_transforms(&self, rest: &[Rigid], posed: &[Rigid]) -> Vec<Rigid> {
        rest.iter()
            .zip(posed)
            .map(|(r, p)| *p * r.inverse())
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chain() -> (Skeleton, Vec<Vec3>) {
        let s = Skeleton {
            bones: vec![
                Bone {
                    name: "root".into(),
                    parent: None,
                    roll: 0.0,
                    head: 0,
                    tail: 1,
                },
                Bone {
                    name: "arm".into(),
                    parent: Some(0),
                    roll: 0.4,
                    head: 1,
                    tail: 2,
                },
            ],
        };
        (
            s,
            vec![
                Vec3::ZERO,
                Vec3::new(0.0, 1.0, 0.0),
                Vec3::new(1.0, 1.0, 0.0),
            ],
        )
    }

    #[test]
    fn rest_frames_point_along_bones() {
        let (s, j) = chain();
        let rest = s.rest_frames(&j);
        for (b, f) in s.bones.iter().zip(&rest) {
            let d = (j[b.tail] - j[b.head]).normalize();
            assert!((f.rot * Vec3::Y - d).length() < 1e-6);
            assert!((f.trans - j[b.head]).length() < 1e-6);
        }
    }

    #[test]
    fn roll_turns_the_frame_about_the_bone_as_blender_does() {
        // A bone along drape's -Z is Blender's +Y: with roll 0 its frame is Blender's world
        // frame, so local X = +X and local Z = Blender +Z = drape +Y. Roll +90 degrees turns
        // local X onto -(local Z at roll 0) = drape -Y.
        let joints = [Vec3::ZERO, Vec3::new(0.0, 0.0, -1.0)];
        for (roll, x_axis, z_axis) in [
            (0.0, Vec3::X, Vec3::Y),
            (std::f32::consts::FRAC_PI_2, -Vec3::Y, Vec3::X),
        ] {
            let s = Skeleton {
                bones: vec![Bone {
                    name: "b".into(),
                    parent: None,
                    roll,
                    head: 0,
                    tail: 1,
                }],
            };
            let f = s.rest_frames(&joints)[0];
            assert!(
                (f.rot * Vec3::X - x_axis).length() < 1e-6,
                "roll {roll}: x {}",
                f.rot * Vec3::X
            );
            assert!(
                (f.rot * Vec3::Z - z_axis).length() < 1e-6,
                "roll {roll}: z {}",
                f.rot * Vec3::Z
            );
        }
        // A bone straight up (Blender +Z): the shortest arc is a quarter turn about X, so
        // local X stays +X.
        let s = Skeleton {
            bones: vec![Bone {
                name: "b".into(),
                parent: None,
                roll: 0.0,
                head: 0,
                tail: 1,
            }],
        };
        let f = s.rest_frames(&[Vec3::ZERO, Vec3::Y])[0];
        assert!((f.rot * Vec3::X - Vec3::X).length() < 1e-6);
        assert!((f.rot * Vec3::Z - Vec3::Z).length() < 1e-6);
    }

    #[test]
    fn rest_pose_is_identity_and_rotation_moves_children() {
        let (s, j) = chain();
        let rest = s.rest_frames(&j);
        let posed = s.posed_frames(&rest, &Pose::rest(s.len()));
        for t in s.skinning_transforms(&rest, &posed) {
            assert!(t.rot.angle_between(Quat::IDENTITY) < 1e-5 && t.trans.length() < 1e-6);
        }
        // Rotate the root a quarter turn about its own Y (the world Y here): the arm's tail
        // at (1, 1, 0) goes to (0, 1, -1).
        let mut pose = Pose::rest(s.len());
        pose.rotations[0] = Quat::from_rotation_y(std::f32::consts::FRAC_PI_2);
        let posed = s.posed_frames(&rest, &pose);
        let skin = s.skinning_transforms(&rest, &posed);
        let p = skin[1].apply(Vec3::new(1.0, 1.0, 0.0));
        assert!((p - Vec3::new(0.0, 1.0, -1.0)).length() < 1e-5, "{p}");
    }
}
