//! Dihedral bending (optional): the angle between two triangles that share an edge is kept
//! near its rest value. The formulation of Mueller et al., "Position Based Dynamics"
//! (2007, appendix A), solved with XPBD compliance.
//!
//! For triangles `(p1, p2, p3)` and `(p1, p2, p4)` sharing the edge `p1 p2`, with `p1` moved
//! to the origin: `n1 = p2 x p3 / |p2 x p3|`, `n2 = p2 x p4 / |p2 x p4|`, `d = n1 . n2`,
//! `C = acos(d) - phi0`. With `s = sqrt(1 - d^2)` and the PBD vectors `q_k`, the gradient
//! is `grad_k C = q_k / s` (with the `q_k` as written below), so one XPBD step moves
//! particle k by `-w_k q_k C s / (sum_j w_j |q_j|^2 + alpha~ s^2)`.

use glam::Vec3;

use super::xpbd_delta;

/// One dihedral constraint.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dihedral {
    /// The shared edge's particles, then the two opposite particles.
    pub p: [u32; 4],
    /// Rest angle (rad) between the normals as defined above.
    pub rest: f32,
    /// Compliance (1/(N m)).
    pub compliance: f32,
}

/// The angle `acos(n1 . n2)` of four positions, and the PBD vectors `q`.
fn angle_and_q(x: [Vec3; 4]) -> Option<(f32, f32, [Vec3; 4])> {
    let (p2, p3, p4) = (x[1] - x[0], x[2] - x[0], x[3] - x[0]);
    let c23 = p2.cross(p3);
    let c24 = p2.cross(p4);
    let (l23, l24) = (c23.length(), c24.length());
    if l23 < 1e-12 || l24 < 1e-12 {
        return None;
    }
    let n1 = c23 / l23;
    let n2 = c24 / l24;
    let d = n1.dot(n2).clamp(-1.0, 1.0);
    let q3 = (p2.cross(n2) + n1.cross(p2) * d) / l23;
    let q4 = (p2.cross(n1) + n2.cross(p2) * d) / l24;
    let q2 = -(p3.cross(n2) + n1.cross(p3) * d) / l23 - (p4.cross(n1) + n2.cross(p4) * d) / l24;
    let q1 = -q2 - q3 - q4;
    Some((d.acos(), d, [q1, q2, q3, q4]))
}

/// The rest angle of four rest positions (pi for a flat pair).
pub fn rest_angle(x: [Vec3; 4]) -> Option<f32> {
    angle_and_q(x).map(|(a, _, _)| a)
}

/// Corrections of the four particles.
pub fn solve(c: &Dihedral, x: [Vec3; 4], w: [f32; 4], inv_h2: f32) -> [Vec3; 4] {
    let Some((angle, d, q)) = angle_and_q(x) else {
        return [Vec3::ZERO; 4];
    };
    // The gradient q / s is undefined for (nearly) flat or fully folded pairs.
    let s = (1.0 - d * d).max(0.0).sqrt();
    if s < 1e-6 {
        return [Vec3::ZERO; 4];
    }
    let grad = q.map(|g| g / s);
    let sum: f32 = (0..4).map(|k| w[k] * grad[k].length_squared()).sum();
    let dl = xpbd_delta(angle - c.rest, sum, c.compliance * inv_h2);
    [0, 1, 2, 3].map(|k| grad[k] * (w[k] * dl))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_folded_flap_opens_towards_its_rest_angle() {
        // Flat pair: edge along x, p3 on +y, p4 on -y.
        let flat = [
            Vec3::ZERO,
            Vec3::X,
            Vec3::new(0.5, 1.0, 0.0),
            Vec3::new(0.5, -1.0, 0.0),
        ];
        let rest = rest_angle(flat).unwrap();
        assert!((rest - std::f32::consts::PI).abs() < 1e-4);
        // Fold p4 up by 60 degrees.
        let a = 60f32.to_radians();
        let mut x = flat;
        x[3] = Vec3::new(0.5, -a.cos(), a.sin());
        let c = Dihedral {
            p: [0, 1, 2, 3],
            rest,
            compliance: 0.0,
        };
        let before = rest_angle(x).unwrap();
        for _ in 0..20 {
            let dx = solve(&c, x, [1.0; 4], 1.0);
            for k in 0..4 {
                x[k] += dx[k];
            }
        }
        let after = rest_angle(x).unwrap();
        assert!(
            (after - rest).abs() < 0.2 * (before - rest).abs(),
            "{before} -> {after}"
        );
    }
}
