//! Distance constraints: stretch on edges, shear and bend between particles two edges
//! apart (the NvCloth cooker's classification), with hard stretch and compression limits.

use glam::{Vec3, Vec3A};

use super::xpbd_delta;

/// What a distance constraint models.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// A mesh edge.
    Stretch,
    /// Two edges apart around a corner (a quad's other diagonal).
    Shear,
    /// Two edges apart along a nearly straight path.
    Bend,
}

/// One distance constraint `C = |x_i - x_j| - rest`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Distance {
    /// First particle.
    pub i: u32,
    /// Second particle.
    pub j: u32,
    /// Rest length (m).
    pub rest: f32,
    /// Compliance (m/N).
    pub compliance: f32,
    /// Shortest allowed length (m), enforced hard.
    pub min: f32,
    /// Longest allowed length (m), enforced hard.
    pub max: f32,
}

/// A distance constraint prepared for a fixed substep length and fixed masses: the XPBD
/// update of a constraint solved once per substep is `len' = len - k (len - rest)` with
/// `k = w / (w + alpha / h^2)`, `w = w_i + w_j`, clamped to `[min, max]`; particle i takes
/// the share `w_i / w` of the change and j the rest.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Prepared {
    /// First particle.
    pub i: u32,
    /// Second particle.
    pub j: u32,
    /// Rest length (m).
    pub rest: f32,
    /// Stiffness factor `w / (w + alpha / h^2)` in [0, 1].
    pub k: f32,
    /// Shortest allowed length (m).
    pub min: f32,
    /// Longest allowed length (m).
    pub max: f32,
    /// Share of particle i, `w_i / w` (0 if both particles are pinned).
    pub share_i: f32,
    /// Share of particle j.
    pub share_j: f32,
}

impl Prepared {
    /// Prepares `c` for inverse masses `wi`, `wj` and `1 / h^2 = inv_h2`.
    pub fn new(c: &Distance, wi: f32, wj: f32, inv_h2: f32) -> Self {
        let w = wi + wj;
        let (k, share_i, share_j) = if w == 0.0 {
            (0.0, 0.0, 0.0)
        } else {
            (w / (w + c.compliance * inv_h2), wi / w, wj / w)
        };
        Self {
            i: c.i,
            j: c.j,
            rest: c.rest,
            k,
            min: c.min,
            max: c.max,
            share_i,
            share_j,
        }
    }

    /// Corrections `(dx_i, dx_j)` at positions `xi`, `xj` (SIMD vectors: the solver's hot
    /// loop); the same as [`solve`].
    #[inline]
    pub fn solve(&self, xi: Vec3A, xj: Vec3A) -> (Vec3A, Vec3A) {
        let d = xi - xj;
        let len2 = d.length_squared();
        if len2 < 1e-24 {
            return (Vec3A::ZERO, Vec3A::ZERO);
        }
        let len = len2.sqrt();
        let target = (len - self.k * (len - self.rest)).clamp(self.min, self.max);
        let n = d * ((target - len) / len);
        (n * self.share_i, n * -self.share_j)
    }
}

/// Corrections `(dx_i, dx_j)` of one distance constraint at positions `xi`, `xj`.
#[inline]
pub fn solve(c: &Distance, xi: Vec3, xj: Vec3, wi: f32, wj: f32, inv_h2: f32) -> (Vec3, Vec3) {
    let w = wi + wj;
    if w == 0.0 {
        return (Vec3::ZERO, Vec3::ZERO);
    }
    let d = xi - xj;
    let len = d.length();
    if len < 1e-12 {
        return (Vec3::ZERO, Vec3::ZERO);
    }
    let n = d / len;
    // Soft part, then the hard limits on the softly corrected length.
    let dl = xpbd_delta(len - c.rest, w, c.compliance * inv_h2);
    let soft = len + w * dl;
    let target = soft.clamp(c.min, c.max);
    let total = (target - len) / w;
    (n * (wi * total), n * (-wj * total))
}

/// Classifies the pair `(a, c)` reached from `a` through `b`: the NvCloth cooker's ratio
/// `|(a - b) x (c - b)| / |c - a|^2` is 0 on a straight path and 0.5 at a right angle.
/// Bend below 0.1; shear from 0.35 to 0.6 (around a quad's right-angled corner, where
/// NvCloth's shear score peaks at 0.45); otherwise neither (NvCloth also sums its scores over
/// all paths between a pair; here the first path that classifies decides).
pub fn classify(a: Vec3, b: Vec3, c: Vec3) -> Option<Kind> {
    let ac = (c - a).length_squared();
    if ac < 1e-20 {
        return None;
    }
    let ratio = (a - b).cross(c - b).length() / ac;
    if ratio < 0.1 {
        Some(Kind::Bend)
    } else if (0.35..=0.6).contains(&ratio) {
        Some(Kind::Shear)
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stiff_constraint_restores_length_and_keeps_the_centre_of_mass() {
        let c = Distance {
            i: 0,
            j: 1,
            rest: 1.0,
            compliance: 0.0,
            min: 0.0,
            max: f32::MAX,
        };
        let (xi, xj) = (Vec3::ZERO, Vec3::new(1.5, 0.0, 0.0));
        let (di, dj) = solve(&c, xi, xj, 1.0, 3.0, 1e4);
        assert!(((xi + di).distance(xj + dj) - 1.0).abs() < 1e-6);
        assert!(
            (di * 1.0 + dj * (1.0 / 3.0)).length() < 1e-6,
            "momentum kept with masses 1 and 1/3"
        );
    }

    #[test]
    fn soft_constraint_yields_and_limits_hold() {
        let soft = Distance {
            i: 0,
            j: 1,
            rest: 1.0,
            compliance: 1.0,
            min: 0.0,
            max: f32::MAX,
        };
        let (di, dj) = solve(&soft, Vec3::ZERO, Vec3::X * 2.0, 1.0, 1.0, 1.0);
        let len = (Vec3::X * 2.0 + dj - di).length();
        // w = 2, alpha~ = 1: the length moves 2/3 of the way, to 2 - 2/3.
        assert!((len - (2.0 - 2.0 / 3.0)).abs() < 1e-5, "{len}");
        let limited = Distance { max: 1.1, ..soft };
        let (di, dj) = solve(&limited, Vec3::ZERO, Vec3::X * 2.0, 1.0, 1.0, 1.0);
        assert!(((Vec3::X * 2.0 + dj - di).length() - 1.1).abs() < 1e-5);
    }

    #[test]
    fn prepared_form_matches_the_direct_update() {
        let c = Distance {
            i: 0,
            j: 1,
            rest: 1.0,
            compliance: 0.3,
            min: 0.8,
            max: 1.05,
        };
        let cases = [
            (Vec3::new(1.3, 0.2, 0.0), 1.0, 2.0),
            (Vec3::new(0.5, 0.0, 0.1), 0.0, 1.0),
            (Vec3::new(1.02, 0.0, 0.0), 3.0, 0.5),
        ];
        for (xj, wi, wj) in cases {
            let (a, b) = solve(&c, Vec3::ZERO, xj, wi, wj, 10.0);
            let (p, q) = Prepared::new(&c, wi, wj, 10.0).solve(Vec3A::ZERO, xj.into());
            let (p, q) = (Vec3::from(p), Vec3::from(q));
            assert!(
                a.distance(p) < 1e-6 && b.distance(q) < 1e-6,
                "{a} {p} / {b} {q}"
            );
        }
    }

    #[test]
    fn classification_follows_the_path_shape() {
        let b = Vec3::ZERO;
        assert_eq!(classify(-Vec3::X, b, Vec3::X), Some(Kind::Bend));
        assert_eq!(classify(-Vec3::X, b, Vec3::Y), Some(Kind::Shear));
        // Equilateral corner (120 degrees): neither.
        let c = Vec3::new(0.5, 3f32.sqrt() / 2.0, 0.0);
        assert_eq!(classify(-Vec3::X, b, c), None);
        // A sharp corner (60 degrees, ratio 0.87): neither.
        let sharp = Vec3::new(-0.5, 3f32.sqrt() / 2.0, 0.0);
        assert_eq!(classify(-Vec3::X, b, sharp), None);
    }
}
