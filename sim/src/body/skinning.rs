//! Rigid transforms and skinning: linear blend skinning (LBS) for the body and dual
//! quaternion skinning (DQS) for any mesh bound to the skeleton (the garment warp).

use glam::{Mat3, Quat, Vec3};
use rayon::prelude::*;

/// A rotation followed by a translation: `p -> rot * p + trans`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Rigid {
    /// Unit rotation.
    pub rot: Quat,
    /// Translation (m).
    pub trans: Vec3,
}

impl Rigid {
    /// The identity transform.
    pub const IDENTITY: Self = Self {
        rot: Quat::IDENTITY,
        trans: Vec3::ZERO,
    };

    /// A transform from its parts.
    pub fn new(rot: Quat, trans: Vec3) -> Self {
        Self { rot, trans }
    }

    /// Applies the transform to a point.
    #[inline]
    pub fn apply(&self, p: Vec3) -> Vec3 {
        self.rot * p + self.trans
    }

    /// The inverse transform.
    pub fn inverse(&self) -> Self {
        let rot = self.rot.conjugate();
        Self {
            rot,
            trans: -(rot * self.trans),
        }
    }
}

impl std::ops::Mul for Rigid {
    type Output = Rigid;
    /// `(a * b).apply(p) == a.apply(b.apply(p))`.
    fn mul(self, b: Rigid) -> Rigid {
        Rigid {
            rot: (self.rot * b.rot).normalize(),
            trans: self.rot * b.trans + self.trans,
        }
    }
}

/// Up to four bone influences per vertex, weights summing to one (unused slots weight 0).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SkinWeights {
    /// Bone indices per vertex.
    pub bones: Vec<[u16; 4]>,
    /// Weights per vertex, same order as `bones`.
    pub weights: Vec<[f32; 4]>,
}

impl SkinWeights {
    /// Number of vertices.
    pub fn len(&self) -> usize {
        self.bones.len()
    }

    /// True when there are no vertices.
    pub fn is_empty(&self) -> bool {
        self.bones.is_empty()
    }
}

/// Linear blend skinning: `v' = sum_i w_i S_i v` with the skinning transforms `S_i`
/// (rest world space to posed world space, one per bone).
pub fn lbs(points: &[Vec3], skin: &SkinWeights, transforms: &[Rigid]) -> Vec<Vec3> {
    assert_eq!(
        points.len(),
        skin.len(),
        "one set of skinning weights per point"
    );
    let mats: Vec<(Mat3, Vec3)> = transforms
        .iter()
        .map(|t| (Mat3::from_quat(t.rot), t.trans))
        .collect();
    points
        .par_iter()
        .zip(skin.bones.par_iter().zip(&skin.weights))
        .with_min_len(SKIN_POINTS_PER_TASK)
        .map(|(&p, (b, w))| {
            let mut m = Mat3::ZERO;
            let mut t = Vec3::ZERO;
            for k in 0..4 {
                if w[k] != 0.0 {
                    let (mk, tk) = &mats[b[k] as usize];
                    m += *mk * w[k];
                    t += *tk * w[k];
                }
            }
            m * p + t
        })
        .collect()
}

/// A unit dual quaternion `real + eps dual` encoding a rigid transform.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DualQuat {
    /// Rotation part.
    pub real: Quat,
    /// `0.5 * t * real`, with `t` the translation as a pure quaternion.
    pub dual: Quat,
}

impl DualQuat {
    /// The dual quaternion of a rigid transform.
    pub fn from_rigid(r: &Rigid) -> Self {
        let t = Quat::from_xyzw(r.trans.x, r.trans.y, r.trans.z, 0.0);
        Self {
            real: r.rot,
            dual: (t * r.rot) * 0.5,
        }
    }

    /// The rigid transform of a (not necessarily unit) dual quaternion, normalising it.
    pub fn to_rigid(&self) -> Rigid {
        let n = self.real.length();
        let real = self.real * (1.0 / n);
        let dual = self.dual * (1.0 / n);
        // t = 2 dual real^*, after removing the part of dual parallel to real.
        let dual = dual - real * real.dot(dual);
        let t = (dual * real.conjugate()) * 2.0;
        Rigid {
            rot: real,
            trans: Vec3::new(t.x, t.y, t.z),
        }
    }
}

/// Points per task of [`lbs`] and [`dqs`] (each a few hundred operations; the same bits as
/// one thread, as each point is its own).
const SKIN_POINTS_PER_TASK: usize = 2048;

/// Dual quaternion skinning (Kavan et al. 2007): blends the bones' dual quaternions with
/// the vertex weights (flipping each to the hemisphere of the vertex's first bone), then
/// applies the normalised blend. Keeps volume at twisting joints where LBS collapses.
pub fn dqs(points: &[Vec3], skin: &SkinWeights, transforms: &[Rigid]) -> Vec<Vec3> {
    assert_eq!(
        points.len(),
        skin.len(),
        "one set of skinning weights per point"
    );
    let dqs: Vec<DualQuat> = transforms.iter().map(DualQuat::from_rigid).collect();
    points
        .par_iter()
        .zip(skin.bones.par_iter().zip(&skin.weights))
        .with_min_len(SKIN_POINTS_PER_TASK)
        .map(|(&p, (b, w))| {
            let pivot = dqs[b[0] as usize].real;
            let mut real = Quat::from_xyzw(0.0, 0.0, 0.0, 0.0);
            let mut dual = real;
            for k in 0..4 {
                if w[k] != 0.0 {
                    let d = dqs[b[k] as usize];
                    let s = if d.real.dot(pivot) < 0.0 { -w[k] } else { w[k] };
                    real += d.real * s;
                    dual += d.dual * s;
                }
            }
            DualQuat { real, dual }.to_rigid().apply(p)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rigid(axis: Vec3, angle: f32, t: Vec3) -> Rigid {
        Rigid::new(Quat::from_axis_angle(axis.normalize(), angle), t)
    }

    #[test]
    fn rigid_algebra() {
        let a = rigid(Vec3::new(1.0, 2.0, 3.0), 0.7, Vec3::new(0.1, -0.2, 0.3));
        let b = rigid(Vec3::new(-1.0, 0.5, 0.2), -1.3, Vec3::new(1.0, 0.0, -2.0));
        let p = Vec3::new(0.3, 0.4, -0.5);
        assert!(((a * b).apply(p) - a.apply(b.apply(p))).length() < 1e-5);
        assert!((a.inverse().apply(a.apply(p)) - p).length() < 1e-5);
    }

    #[test]
    fn dual_quaternion_round_trip() {
        let a = rigid(Vec3::new(0.2, 1.0, -0.4), 2.1, Vec3::new(0.5, 1.5, -0.25));
        let back = DualQuat::from_rigid(&a).to_rigid();
        let p = Vec3::new(-0.3, 0.2, 0.9);
        assert!((back.apply(p) - a.apply(p)).length() < 1e-5);
    }

    #[test]
    fn dqs_ignores_the_sign_of_a_bone_quaternion() {
        // q and -q are the same rotation: flipping one bone's quaternion must not change
        // the result (the blend flips it back to the first bone's hemisphere).
        let a = rigid(Vec3::new(0.1, 1.0, 0.3), 0.8, Vec3::new(0.1, 0.2, -0.1));
        let b = rigid(Vec3::new(1.0, 0.2, -0.5), -1.1, Vec3::new(-0.3, 0.0, 0.4));
        let flipped = Rigid::new(-b.rot, b.trans);
        let skin = SkinWeights {
            bones: vec![[0, 1, 0, 0]],
            weights: vec![[0.3, 0.7, 0.0, 0.0]],
        };
        let p = [Vec3::new(0.2, -0.4, 0.6)];
        let x = dqs(&p, &skin, &[a, b])[0];
        let y = dqs(&p, &skin, &[a, flipped])[0];
        assert!(x.distance(y) < 1e-5, "{x} vs {y}");
    }

    #[test]
    fn dqs_blends_translations_linearly_when_rotations_agree() {
        // Same rotation, different translations: the blend moves by the weighted mean
        // translation (this exercises the normalisation of the blended dual part).
        let q = Quat::from_axis_angle(Vec3::new(0.3, -1.0, 0.5).normalize(), 0.9);
        let (ta, tb) = (Vec3::new(0.5, 0.0, -0.2), Vec3::new(-0.1, 0.3, 0.6));
        let skin = SkinWeights {
            bones: vec![[0, 1, 0, 0]],
            weights: vec![[0.25, 0.75, 0.0, 0.0]],
        };
        let p = [Vec3::new(0.4, 0.1, -0.3)];
        let out = dqs(&p, &skin, &[Rigid::new(q, ta), Rigid::new(q, tb)])[0];
        let expected = q * p[0] + 0.25 * ta + 0.75 * tb;
        assert!(out.distance(expected) < 1e-5, "{out} vs {expected}");
    }

    #[test]
    fn dqs_keeps_length_where_lbs_shrinks() {
        // A point bound half and half to the identity and a 180 degree twist about its own
        // axis: LBS collapses it onto the axis, DQS keeps its distance from the axis.
        let transforms = [
            Rigid::IDENTITY,
            rigid(Vec3::Y, std::f32::consts::PI * 0.999, Vec3::ZERO),
        ];
        let skin = SkinWeights {
            bones: vec![[0, 1, 0, 0]],
            weights: vec![[0.5, 0.5, 0.0, 0.0]],
        };
        let p = [Vec3::new(0.1, 0.5, 0.0)];
        let l = lbs(&p, &skin, &transforms)[0];
        let d = dqs(&p, &skin, &transforms)[0];
        assert!(Vec3::new(l.x, 0.0, l.z).length() < 0.01);
        assert!((Vec3::new(d.x, 0.0, d.z).length() - 0.1).abs() < 1e-4);
        assert!((d.y - 0.5).abs() < 1e-5);
    }
}
