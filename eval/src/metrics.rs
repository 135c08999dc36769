//! Accuracy and physics metrics of a predicted garment against the simulator's.
//!
//! - [`edist_cm`]: the GarNet++ paper's Eq. 17, the mean vertex-to-vertex distance (cm).
//! - [`enorm_deg`]: Eq. 18, the mean angle between predicted and true face normals
//!   (degrees).
//! - [`Curve`]: average-precision curves (the paper's Fig. 9): the share of vertices (faces)
//!   whose error lies below each threshold.
//! - [`Physics`]: the energies DrapeNet reports (StVK membrane strain, dihedral bending,
//!   gravity) with SNUG's fabric, and [`interpenetration`], the share of garment vertices
//!   inside the body.
//!
//! Positions are metres; every function takes vertices and triangles as stored in a
//! dataset's shards and static file.

use glam::{DMat2, DVec3, Vec3};
use sim::cloth::collision::BodyCollider;

/// Per-vertex distances `|pred_i - gt_i|` (m).
pub fn vertex_errors(pred: &[Vec3], gt: &[Vec3]) -> Vec<f32> {
    assert_eq!(pred.len(), gt.len(), "meshes of different sizes");
    pred.iter().zip(gt).map(|(p, g)| p.distance(*g)).collect()
}

/// Eq. 17: mean vertex-to-vertex distance, in centimetres.
pub fn edist_cm(pred: &[Vec3], gt: &[Vec3]) -> f64 {
    mean(vertex_errors(pred, gt).iter().map(|&e| e as f64)) * 100.0
}

/// Unit face normals (zero for a degenerate face, NaN for a face with a non-finite
/// vertex).
pub fn face_normals(x: &[Vec3], triangles: &[[u32; 3]]) -> Vec<Vec3> {
    triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| x[i as usize]);
            let n = (b - a).cross(c - a);
            if n.is_finite() {
                n.normalize_or_zero()
            } else {
                Vec3::NAN
            }
        })
        .collect()
}

/// Angle between predicted and true normals per face (degrees). A face degenerate in
/// either mesh counts as 90 degrees: its normal is undefined, which is an error. A face
/// with a non-finite vertex gives NaN, so a diverged prediction shows in Enorm too.
pub fn face_angles(pred: &[Vec3], gt: &[Vec3], triangles: &[[u32; 3]]) -> Vec<f32> {
    let (np, ng) = (face_normals(pred, triangles), face_normals(gt, triangles));
    np.iter()
        .zip(&ng)
        .map(|(p, g)| {
            if p.is_nan() || g.is_nan() {
                f32::NAN
            } else if *p == Vec3::ZERO || *g == Vec3::ZERO {
                90.0
            } else {
                p.dot(*g).clamp(-1.0, 1.0).acos().to_degrees()
            }
        })
        .collect()
}

/// Eq. 18: mean angle between predicted and true face normals, in degrees.
pub fn enorm_deg(pred: &[Vec3], gt: &[Vec3], triangles: &[[u32; 3]]) -> f64 {
    mean(face_angles(pred, gt, triangles).iter().map(|&e| e as f64))
}

/// Mean of the values (NaN for none).
pub fn mean(v: impl IntoIterator<Item = f64>) -> f64 {
    let (s, n) = v
        .into_iter()
        .fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    if n == 0 { f64::NAN } else { s / n as f64 }
}

/// Median of the values (the upper one of an even count; NaN for none).
pub fn median(mut v: Vec<f64>) -> f64 {
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Median of the values, the mean of the middle pair for an even count (None for none).
pub fn median_of(mut v: Vec<f64>) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    Some(if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    })
}

/// The key of the largest value and that value's share of the sum (percent); None when
/// there is none or the sum is not positive.
pub fn largest_share<K: Copy>(v: impl IntoIterator<Item = (K, f64)>) -> Option<(K, f64)> {
    let (mut total, mut top) = (0.0, None::<(K, f64)>);
    for (k, x) in v {
        total += x;
        if top.is_none_or(|(_, t)| x > t) {
            top = Some((k, x));
        }
    }
    top.filter(|_| total > 0.0)
        .map(|(k, x)| (k, 100.0 * x / total))
}

/// Mean and (population) standard deviation.
pub fn mean_std(v: &[f64]) -> (f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN);
    }
    let m = v.iter().sum::<f64>() / v.len() as f64;
    let var = v.iter().map(|x| (x - m) * (x - m)).sum::<f64>() / v.len() as f64;
    (m, var.sqrt())
}

/// An average-precision curve: the share of values at or below each threshold,
/// accumulated over many samples.
#[derive(Debug, Clone, PartialEq)]
pub struct Curve {
    /// Thresholds, increasing (cm for distances, degrees for angles).
    pub thresholds: Vec<f64>,
    /// Values at or below each threshold.
    pub counts: Vec<u64>,
    /// All values seen.
    pub total: u64,
}

impl Curve {
    /// `steps + 1` evenly spaced thresholds from 0 to `max`.
    pub fn new(max: f64, steps: usize) -> Self {
        let steps = steps.max(1);
        Self {
            thresholds: (0..=steps).map(|k| max * k as f64 / steps as f64).collect(),
            counts: vec![0; steps + 1],
            total: 0,
        }
    }

    /// The paper's Fig. 9 distance axis: 0 to 3 cm.
    pub fn distances() -> Self {
        Self::new(3.0, 60)
    }

    /// The paper's Fig. 9 angle axis: 0 to 45 degrees.
    pub fn angles() -> Self {
        Self::new(45.0, 45)
    }

    /// Adds values (in the thresholds' unit).
    pub fn add(&mut self, values: impl IntoIterator<Item = f64>) {
        let top = *self.thresholds.last().expect("a curve has thresholds");
        let step = top / (self.thresholds.len() - 1) as f64;
        for v in values {
            self.total += 1;
            if v.is_nan() || v > top {
                continue;
            }
            // First threshold at or above v, then every later one counts it too.
            let mut k = (v / step).ceil().max(0.0) as usize;
            while k > 0 && self.thresholds[k - 1] >= v {
                k -= 1;
            }
            while k < self.thresholds.len() && self.thresholds[k] < v {
                k += 1;
            }
            if k < self.counts.len() {
                self.counts[k] += 1;
            }
        }
    }

    /// Share of values at or below each threshold (0 to 1).
    pub fn shares(&self) -> Vec<f64> {
        let mut acc = 0u64;
        self.counts
            .iter()
            .map(|&c| {
                acc += c;
                if self.total == 0 {
                    0.0
                } else {
                    acc as f64 / self.total as f64
                }
            })
            .collect()
    }

    /// Share at or below `t` (the nearest threshold at or below it).
    pub fn share_at(&self, t: f64) -> f64 {
        let k = self
            .thresholds
            .iter()
            .rposition(|&x| x <= t + 1e-9)
            .unwrap_or(0);
        self.shares()[k]
    }
}

/// Fabric of the physics metrics: SNUG's material (the corrected values DrapeNet uses).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Fabric {
    /// Lame's first parameter (Pa).
    pub lambda: f64,
    /// Shear modulus (Pa).
    pub mu: f64,
    /// Thickness (m).
    pub thickness: f64,
    /// Areal density (kg/m^2).
    pub density: f64,
    /// Bending stiffness (N m).
    pub bending: f64,
    /// Gravity (m/s^2).
    pub gravity: f64,
}

impl Default for Fabric {
    fn default() -> Self {
        Self {
            lambda: 4.44e4,
            mu: 2.36e4,
            thickness: 4.7e-4,
            density: 0.20022,
            bending: 3.96e-5,
            gravity: 9.81,
        }
    }
}

/// An interior edge and its two opposite vertices.
#[derive(Debug, Clone, Copy)]
struct Hinge {
    edge: [u32; 2],
    opposite: [u32; 2],
    /// `k_b l0^2 / (4 (A0 + A1))` at rest.
    weight: f64,
}

/// The rest state of a garment (its template) cooked for the energies.
#[derive(Debug, Clone)]
pub struct Physics {
    triangles: Vec<[u32; 3]>,
    /// Inverse of the rest edge matrix in the triangle's own plane.
    dm_inv: Vec<DMat2>,
    rest_area: Vec<f64>,
    hinges: Vec<Hinge>,
    mass: Vec<f64>,
    fabric: Fabric,
}

/// Energies of one garment state (J).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Energies {
    /// StVK membrane strain energy.
    pub strain: f64,
    /// Bending energy of the dihedral angles (flat rest angle, as SNUG and DrapeNet).
    pub bending: f64,
    /// Potential energy `sum m_i g h_i`, heights above the body's lowest vertex.
    pub gravity: f64,
}

fn d(v: Vec3) -> DVec3 {
    v.as_dvec3()
}

impl Physics {
    /// Cooks the rest state `rest` (the garment template) with `fabric`.
    pub fn new(rest: &[Vec3], triangles: &[[u32; 3]], fabric: Fabric) -> Self {
        let mut dm_inv = Vec::with_capacity(triangles.len());
        let mut rest_area = Vec::with_capacity(triangles.len());
        let mut mass = vec![0.0; rest.len()];
        for t in triangles {
            let [a, b, c] = t.map(|i| d(rest[i as usize]));
            let (e1, e2) = (b - a, c - a);
            let area = 0.5 * e1.cross(e2).length();
            // Orthonormal frame of the triangle's plane: u along e1.
            let u = e1.normalize_or_zero();
            let v = (e2 - u * e2.dot(u)).normalize_or_zero();
            let dm = DMat2::from_cols(
                glam::DVec2::new(e1.dot(u), 0.0),
                glam::DVec2::new(e2.dot(u), e2.dot(v)),
            );
            let ok = dm.determinant().abs() > 1e-14;
            dm_inv.push(if ok { dm.inverse() } else { DMat2::ZERO });
            rest_area.push(if ok { area } else { 0.0 });
            for &i in t {
                mass[i as usize] += fabric.density * area / 3.0;
            }
        }
        // Interior edges: the two faces sharing an edge, each with its opposite vertex.
        let mut edges: std::collections::HashMap<(u32, u32), Vec<(u32, usize)>> =
            std::collections::HashMap::new();
        for (f, t) in triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b, o) = (t[k], t[(k + 1) % 3], t[(k + 2) % 3]);
                edges.entry((a.min(b), a.max(b))).or_default().push((o, f));
            }
        }
        let mut hinges: Vec<Hinge> = edges
            .into_iter()
            .filter(|(_, v)| v.len() == 2)
            .map(|((a, b), v)| {
                let l0 = rest[a as usize].distance(rest[b as usize]) as f64;
                let areas = rest_area[v[0].1] + rest_area[v[1].1];
                Hinge {
                    edge: [a, b],
                    opposite: [v[0].0, v[1].0],
                    weight: if areas > 0.0 {
                        fabric.bending * l0 * l0 / (4.0 * areas)
                    } else {
                        0.0
                    },
                }
            })
            .collect();
        hinges.sort_by_key(|h| h.edge);
        Self {
            triangles: triangles.to_vec(),
            dm_inv,
            rest_area,
            hinges,
            mass,
            fabric,
        }
    }

    /// Energies of positions `x`; gravity heights are measured from `floor` (m, Y up).
    pub fn energies(&self, x: &[Vec3], floor: f32) -> Energies {
        let f = &self.fabric;
        let mut strain = 0.0;
        for ((t, dm_inv), &area) in self.triangles.iter().zip(&self.dm_inv).zip(&self.rest_area) {
            if area == 0.0 {
                continue;
            }
            let [a, b, c] = t.map(|i| d(x[i as usize]));
            // F = Ds Dm^-1 (3x2), as two columns.
            let (e1, e2) = (b - a, c - a);
            let f0 = e1 * dm_inv.x_axis.x + e2 * dm_inv.x_axis.y;
            let f1 = e1 * dm_inv.y_axis.x + e2 * dm_inv.y_axis.y;
            // Green strain G = (F^T F - I) / 2.
            let g00 = 0.5 * (f0.dot(f0) - 1.0);
            let g11 = 0.5 * (f1.dot(f1) - 1.0);
            let g01 = 0.5 * f0.dot(f1);
            let tr = g00 + g11;
            let psi = f.mu * (g00 * g00 + g11 * g11 + 2.0 * g01 * g01) + 0.5 * f.lambda * tr * tr;
            strain += area * f.thickness * psi;
        }
        let mut bending = 0.0;
        for h in &self.hinges {
            let [a, b] = h.edge.map(|i| d(x[i as usize]));
            let [o0, o1] = h.opposite.map(|i| d(x[i as usize]));
            let e = b - a;
            let n0 = e.cross(o0 - a).normalize_or_zero();
            let n1 = (o1 - a).cross(e).normalize_or_zero();
            let theta = n0.cross(n1).dot(e.normalize_or_zero()).atan2(n0.dot(n1));
            bending += h.weight * theta * theta / 2.0;
        }
        let gravity = self
            .mass
            .iter()
            .zip(x)
            .map(|(m, p)| m * f.gravity * (p.y - floor) as f64)
            .sum();
        Energies {
            strain,
            bending,
            gravity,
        }
    }

    /// Garment mass (kg).
    pub fn mass(&self) -> f64 {
        self.mass.iter().sum()
    }
}

/// Share of the garment's vertices inside the body (0 to 1), by ray parity, at any depth:
/// the interpenetration ratio DrapeNet reports. `body` is the posed body's collider
/// (`BodyCollider::new(vertices, triangles, 0.0)`), built once for all garments on it.
pub fn interpenetration(body: &BodyCollider, x: &[Vec3]) -> f64 {
    if x.is_empty() {
        return 0.0;
    }
    let inside = x.iter().filter(|p| body.inside(**p)).count();
    inside as f64 / x.len() as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square() -> (Vec<Vec3>, Vec<[u32; 3]>) {
        // A 1 m square in the XZ plane, two triangles.
        let v = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 1.0),
            Vec3::new(0.0, 0.0, 1.0),
        ];
        (v, vec![[0, 2, 1], [0, 3, 2]])
    }

    #[test]
    fn median_of_takes_the_middle_or_the_middle_pairs_mean() {
        assert_eq!(median_of(vec![3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median_of(vec![4.0, 1.0, 3.0, 2.0]), Some(2.5));
        assert_eq!(median_of(vec![]), None);
    }

    #[test]
    fn edist_and_enorm_of_a_shift_and_a_fold() {
        let (v, t) = square();
        let shifted: Vec<Vec3> = v.iter().map(|p| *p + Vec3::new(0.0, 0.03, 0.04)).collect();
        assert!((edist_cm(&shifted, &v) - 5.0).abs() < 1e-5);
        assert_eq!(enorm_deg(&shifted, &v, &t), 0.0);
        // Lift vertex 3 so the second face tilts by 45 degrees about the diagonal 0-2...
        let mut folded = v.clone();
        folded[3].y = std::f32::consts::FRAC_1_SQRT_2;
        let a = face_angles(&folded, &v, &t);
        assert!(a[0].abs() < 1e-4);
        // ... by atan(h / (distance of vertex 3 to the diagonal)) = atan(1) = 45 degrees.
        assert!((a[1] - 45.0).abs() < 1e-3, "{}", a[1]);
        assert!((enorm_deg(&folded, &v, &t) - 22.5).abs() < 1e-3);
    }

    #[test]
    fn curve_counts_values_at_or_below_each_threshold() {
        let mut c = Curve::new(2.0, 4); // 0, 0.5, 1, 1.5, 2
        c.add([0.0, 0.5, 0.7, 1.0, 1.9, 5.0, f64::NAN, 0.25]);
        assert_eq!(c.total, 8);
        let s = c.shares();
        assert_eq!(s.len(), 5);
        let expect = [1.0, 3.0, 5.0, 5.0, 6.0].map(|k| k / 8.0);
        for (a, b) in s.iter().zip(expect) {
            assert!((a - b).abs() < 1e-12, "{s:?}");
        }
        assert!((c.share_at(1.2) - 5.0 / 8.0).abs() < 1e-12);
    }

    #[test]
    fn energies_of_rest_stretch_fold_and_height() {
        let (v, t) = square();
        let p = Physics::new(&v, &t, Fabric::default());
        let f = Fabric::default();
        assert!((p.mass() - f.density).abs() < 1e-9);
        let e = p.energies(&v, 0.0);
        assert!(e.strain.abs() < 1e-12 && e.bending.abs() < 1e-12 && e.gravity.abs() < 1e-12);
        // Uniform stretch by s along x: G = diag((s^2 - 1) / 2, 0);
        // psi = (mu + lambda / 2) g^2; E = A t psi.
        let s = 1.01f32;
        let stretched: Vec<Vec3> = v.iter().map(|q| Vec3::new(q.x * s, q.y, q.z)).collect();
        let g = (s as f64 * s as f64 - 1.0) / 2.0;
        let expect = 1.0 * f.thickness * (f.mu + f.lambda / 2.0) * g * g;
        let e = p.energies(&stretched, 0.0);
        assert!(
            (e.strain - expect).abs() < 1e-6 * expect,
            "{} vs {expect}",
            e.strain
        );
        // Lifted by 2 m: m g h.
        let up: Vec<Vec3> = v.iter().map(|q| *q + Vec3::Y * 2.0).collect();
        let e = p.energies(&up, 0.0);
        assert!((e.gravity - f.density * f.gravity * 2.0).abs() < 1e-6);
        // Folded along the diagonal by 90 degrees: theta = pi / 2 on the one hinge, whose
        // rest length is sqrt(2) and areas 1/2 each: E = k_b 2 / 4 (pi/2)^2 / 2.
        let folded = vec![
            v[0],
            v[1],
            v[2],
            Vec3::new(0.5, std::f32::consts::FRAC_1_SQRT_2, 0.5),
        ];
        let e = p.energies(&folded, 0.0);
        let expect = f.bending * 2.0 / 4.0 * (std::f64::consts::FRAC_PI_2).powi(2) / 2.0;
        assert!(
            (e.bending - expect).abs() < 1e-4 * expect,
            "{} vs {expect}",
            e.bending
        );
    }

    #[test]
    fn interpenetration_counts_vertices_inside_a_closed_body() {
        let body = sim::mesh::primitives::uv_sphere(Vec3::ZERO, 0.2, 24, 16);
        let x = vec![
            Vec3::ZERO,
            Vec3::new(0.1, 0.0, 0.0),
            Vec3::new(0.3, 0.0, 0.0),
            Vec3::new(0.0, 0.5, 0.0),
        ];
        let collider = BodyCollider::new(&body.vertices, &body.triangles, 0.0);
        let r = interpenetration(&collider, &x);
        assert!((r - 0.5).abs() < 1e-12, "{r}");
    }
}
