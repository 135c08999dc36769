//! The training losses of the GarNet++ paper, one function each, on root-relative metres.
//!
//! `pred` is G^P = M + T^P and `target` is G^G, both `[B, N, 3]`. Every loss is a mean
//! over the batch, so batch size does not change its scale.

use burn::tensor::activation::relu;
use burn::tensor::{Device, IndexingUpdateOp, Int, Tensor, TensorData};
use glam::Vec3;

use crate::data::{Prepared, knn, nearest};
use crate::topology::Topology;

/// Small number keeping square roots differentiable at zero (squared lengths, m^2).
const EPS: f32 = 1e-12;
/// The same for face normals: squared doubled areas of centimetre triangles are ~1e-8 m^4,
/// so this must be far smaller than `EPS` not to bias them.
const EPS_NORMAL: f32 = 1e-24;

/// Index tensors of a garment's faces, edges and bending pairs, on a device.
#[derive(Debug, Clone)]
pub struct LossTopology {
    faces: [Tensor<1, Int>; 3],
    bend: [Tensor<1, Int>; 2],
    /// Padded neighbourhoods (slot 0 the vertex, then its one-ring), `[N * K]`.
    padded: Tensor<1, Int>,
    /// 1 for used slots, `[1, N, K, 1]`.
    padded_mask: Tensor<4>,
    /// 1 / |one-ring| (1 for an isolated vertex), `[1, N, 1]`.
    inv_ring: Tensor<3>,
    slots: usize,
}

fn column(v: impl Iterator<Item = u32>, device: &Device) -> Tensor<1, Int> {
    let v: Vec<i64> = v.map(i64::from).collect();
    let n = v.len();
    Tensor::from_data(TensorData::new(v, [n]), device)
}

impl LossTopology {
    /// Puts the index lists of `t` on `device`.
    pub fn new(t: &Topology, device: &Device) -> Self {
        let faces = [0, 1, 2].map(|k| column(t.triangles.iter().map(|f| f[k]), device));
        let bend = [0, 1].map(|k| column(t.bend_pairs.iter().map(|p| p[k]), device));
        let inv: Vec<f32> = t
            .rings
            .iter()
            .map(|r| 1.0 / r.len().max(1) as f32)
            .collect();
        let (n, k) = (t.vertices, t.slots);
        Self {
            faces,
            bend,
            padded: Tensor::from_data(TensorData::new(t.padded.clone(), [n * k]), device),
            padded_mask: Tensor::from_data(
                TensorData::new(t.padded_mask.clone(), [1, n, k, 1]),
                device,
            ),
            inv_ring: Tensor::from_data(TensorData::new(inv, [1, n, 1]), device),
            slots: k,
        }
    }
}

/// Squared length along the last axis: `[B, X, 3]` -> `[B, X, 1]`.
fn sq_norm(v: Tensor<3>) -> Tensor<3> {
    (v.clone() * v).sum_dim(2)
}

/// Cross product along the last axis of `[B, X, 3]` tensors.
fn cross(a: Tensor<3>, b: Tensor<3>) -> Tensor<3> {
    let [bs, x, _] = a.dims();
    let c = |t: &Tensor<3>, k: usize| t.clone().slice([0..bs, 0..x, k..k + 1]);
    Tensor::cat(
        vec![
            c(&a, 1) * c(&b, 2) - c(&a, 2) * c(&b, 1),
            c(&a, 2) * c(&b, 0) - c(&a, 0) * c(&b, 2),
            c(&a, 0) * c(&b, 1) - c(&a, 1) * c(&b, 0),
        ],
        2,
    )
}

/// Unit face normals, `[B, F, 3]`.
pub fn face_normals(x: Tensor<3>, topo: &LossTopology) -> Tensor<3> {
    let [a, b, c] = topo.faces.clone().map(|f| x.clone().select(1, f));
    let n = cross(b - a.clone(), c - a);
    n.clone() / (sq_norm(n) + EPS_NORMAL).sqrt()
}

/// L_vert (Eq. 3): mean over vertices of ||G^G_i - G^P_i||^2.
pub fn vertex_loss(pred: Tensor<3>, target: Tensor<3>) -> Tensor<1> {
    sq_norm(pred - target).mean()
}

/// L_norm (Eq. 5): mean over faces of (1 - F^G . F^P)^2 with unit face normals.
pub fn normal_loss(pred: Tensor<3>, target: Tensor<3>, topo: &LossTopology) -> Tensor<1> {
    let (fp, fg) = (face_normals(pred, topo), face_normals(target, topo));
    let d = (fp * fg).sum_dim(2);
    let one_minus = d.neg() + 1.0;
    (one_minus.clone() * one_minus).mean()
}

/// L_bend (Eq. 6): mean over vertex pairs two edges apart of
/// | |G^P_i - G^P_k| - |G^G_i - G^G_k| |.
pub fn bending_loss(pred: Tensor<3>, target: Tensor<3>, topo: &LossTopology) -> Tensor<1> {
    let len = |x: Tensor<3>| {
        let [i, k] = topo.bend.clone().map(|c| x.clone().select(1, c));
        (sq_norm(i - k) + EPS).sqrt()
    };
    (len(pred) - len(target)).abs().mean()
}

/// The nearest pushed-out body point and its normal for every predicted vertex, searched
/// on the prediction's current values (the paper searches at every iteration).
pub fn penetration_targets(
    pred: &Tensor<3>,
    samples: &[&Prepared],
    device: &Device,
) -> (Tensor<3>, Tensor<3>) {
    let [b, n, _] = pred.dims();
    let values = pred
        .to_data()
        .try_into_vec::<f32>()
        .expect("f32 predictions");
    let mut pts = Vec::with_capacity(b * n * 3);
    let mut nrm = Vec::with_capacity(b * n * 3);
    for (s, sample) in samples.iter().enumerate() {
        let q: Vec<Vec3> = values[s * n * 3..(s + 1) * n * 3]
            .chunks_exact(3)
            .map(Vec3::from_slice)
            .collect();
        for i in nearest(&sample.pen_points, &q) {
            pts.extend_from_slice(&sample.pen_points[i as usize].to_array());
            nrm.extend_from_slice(&sample.pen_normals[i as usize].to_array());
        }
    }
    (
        Tensor::from_data(TensorData::new(pts, [b, n, 3]), device),
        Tensor::from_data(TensorData::new(nrm, [b, n, 3]), device),
    )
}

/// L_pen (Eq. 4): for each predicted vertex j and its nearest pushed-out body point B_i
/// with normal N_i, 1{||G^P_j - G^G_j|| < d_tol} ReLU(-N_i . (G^P_j - B_i)), summed over
/// vertices and divided by their number.
pub fn penetration_loss(
    pred: Tensor<3>,
    target: Tensor<3>,
    body_points: Tensor<3>,
    body_normals: Tensor<3>,
    tolerance: f32,
) -> Tensor<1> {
    let close = sq_norm(pred.clone() - target)
        .detach()
        .lower_elem(tolerance * tolerance)
        .float(); // [B, N, 1]
    let depth = relu((body_normals * (pred - body_points)).sum_dim(2).neg()); // [B, N, 1]
    (close * depth).mean()
}

/// Uniform Laplacian: mean of the one-ring neighbours minus the vertex, `[B, N, 3]`.
pub fn uniform_laplacian(x: Tensor<3>, topo: &LossTopology) -> Tensor<3> {
    let [b, n, _] = x.dims();
    let nb = x
        .clone()
        .select(1, topo.padded.clone())
        .reshape([b, n, topo.slots, 3]); // [B, N, K, 3]
    // Slot 0 is the vertex itself: take it out of the masked sum.
    let ring = (nb * topo.padded_mask.clone())
        .sum_dim(2)
        .reshape([b, n, 3])
        - x.clone(); // [B, N, 3]
    ring * topo.inv_ring.clone() - x
}

/// L_UMC (Eq. 19): mean over vertices of ||delta^P_i - delta^G_i||^2 with the uniform
/// Laplacian delta.
pub fn uniform_curvature_loss(
    pred: Tensor<3>,
    target: Tensor<3>,
    topo: &LossTopology,
) -> Tensor<1> {
    sq_norm(uniform_laplacian(pred, topo) - uniform_laplacian(target, topo)).mean()
}

/// Neighbourhood sizes of L_RQ^8, L_RQ^16, L_RQ^32.
pub const RQ_SIZES: [usize; 3] = [8, 16, 32];

/// For every vertex of each ground truth in `targets`, its `k` nearest vertices of that
/// ground truth (itself first), as rows of the flattened `[B * N]`, `[B * N * k]`. The
/// L_RQ neighbourhoods: found on G^G and shared by prediction and ground truth.
pub fn rq_neighbourhoods(targets: &[&[Vec3]], k: usize, device: &Device) -> Tensor<1, Int> {
    let lists: Vec<Vec<u32>> = targets.iter().map(|g| knn(g, g, k)).collect();
    let refs: Vec<&[u32]> = lists.iter().map(|l| l.as_slice()).collect();
    let n = targets.first().map_or(0, |g| g.len());
    rq_rows(&refs, n, k, device)
}

/// Per-sample neighbour lists (indices within each sample, `n * k` each, as
/// `Prepared::rq`) as rows of the flattened `[B * n]`, `[B * n * k]`.
///
/// # Panics
/// If a list is not `n * k` long (a sample without its ground truth's neighbourhoods).
pub fn rq_rows(lists: &[&[u32]], n: usize, k: usize, device: &Device) -> Tensor<1, Int> {
    let mut rows = Vec::new();
    for (s, l) in lists.iter().enumerate() {
        assert_eq!(
            l.len(),
            n * k,
            "sample {s} of the batch carries no L_RQ neighbourhoods of its ground truth"
        );
        let base = (s * n) as i64;
        rows.extend(l.iter().map(|&j| base + i64::from(j)));
    }
    let len = rows.len();
    Tensor::from_data(TensorData::new(rows, [len]), device)
}

/// Smallest and largest Rayleigh quotient of every vertex's neighbourhood (Eq. 10-12),
/// `[B, N, 1]` each, m^2.
///
/// The neighbourhood's centred points g_j = G_j - mean give the covariance
/// Sigma = (1/K) sum_j g_j g_j^T (one batched `[3, K] x [K, 3]` product per vertex), and
/// RQ_j = g_j^T Sigma g_j / (g_j^T g_j); the bounds are the min and max over j. No
/// eigendecomposition. A point at the neighbourhood's mean has no direction: the
/// denominator carries 1e-3 tr(Sigma), so its quotient tends to 0 with a bounded gradient,
/// and flat or collapsed neighbourhoods stay finite.
pub fn rayleigh_bounds(x: Tensor<3>, rows: Tensor<1, Int>, k: usize) -> (Tensor<3>, Tensor<3>) {
    let [b, n, _] = x.dims();
    let p = x.reshape([b * n, 3]).select(0, rows).reshape([b * n, k, 3]); // [BN, K, 3]
    let g = p.clone() - p.mean_dim(1); // [BN, K, 3]
    let sigma = g.clone().swap_dims(1, 2).matmul(g.clone()) / k as f32; // [BN, 3, 3]
    let trace = (g.clone() * g.clone()).sum_dim(2).mean_dim(1); // [BN, 1, 1]
    let num = (g.clone().matmul(sigma) * g.clone()).sum_dim(2); // [BN, K, 1]
    let den = (g.clone() * g).sum_dim(2) + trace * 1e-3 + EPS; // [BN, K, 1]
    let rq = num / den;
    (
        rq.clone().min_dim(1).reshape([b, n, 1]),
        rq.max_dim(1).reshape([b, n, 1]),
    )
}

/// L_RQ^K (Eq. 13): mean over vertices of (RQmin^P - RQmin^G)^2 + (RQmax^P - RQmax^G)^2 on
/// the neighbourhoods `rows` of size `k` ([`rq_neighbourhoods`]), m^4.
pub fn rayleigh_loss(
    pred: Tensor<3>,
    target: Tensor<3>,
    rows: Tensor<1, Int>,
    k: usize,
) -> Tensor<1> {
    let (pmin, pmax) = rayleigh_bounds(pred, rows.clone(), k);
    let (gmin, gmax) = rayleigh_bounds(target, rows, k);
    let (dmin, dmax) = (pmin - gmin, pmax - gmax);
    (dmin.clone() * dmin + dmax.clone() * dmax).mean()
}

/// L_RQ^8, L_RQ^16, L_RQ^32 for the sizes whose `on` is set, from neighbourhoods `rows`
/// found at `kmax` (the largest size on; [`rq_rows`]): each size uses the first K of
/// every neighbourhood (nearest first).
pub fn rayleigh_losses(
    pred: Tensor<3>,
    target: Tensor<3>,
    rows: Tensor<1, Int>,
    kmax: usize,
    on: [bool; 3],
) -> [Option<Tensor<1>>; 3] {
    let [b, n, _] = pred.dims();
    [0, 1, 2].map(|s| {
        let k = RQ_SIZES[s];
        (on[s] && k <= kmax).then(|| {
            let r = rows
                .clone()
                .reshape([b * n, kmax])
                .slice([0..b * n, 0..k])
                .reshape([b * n * k]);
            rayleigh_loss(pred.clone(), target.clone(), r, k)
        })
    })
}

/// Cotangents are clamped to this magnitude (angles below 5.7 degrees or above 174.3): the
/// guard of L_MC against sliver and flat triangles.
pub const COT_MAX: f32 = 10.0;
/// Smallest vertex area in the mean-curvature normal, m^2 (a 0.1 mm square).
const AREA_MIN: f32 = 1e-8;

/// Cotangent mean-curvature normal of every vertex (Meyer et al. 2003; the paper's Eq. 9),
/// `[B, N, 3]`, 1/m:
///
/// kappa_i = 1 / (2 A_i) sum_{j in N_i} (cot alpha_ij + cot beta_ij) (G_j - G_i),
///
/// with A_i the mixed (Voronoi, or for obtuse triangles a half or a quarter of the area)
/// area of vertex i. Per triangle, the cotangent at each corner weighs the opposite edge;
/// contributions are scattered to the vertices. Cotangents are clamped to +-[`COT_MAX`] and
/// areas floored at 1e-8 m^2, so sliver and obtuse triangles give bounded values and
/// gradients.
pub fn mean_curvature_normal(x: Tensor<3>, topo: &LossTopology) -> Tensor<3> {
    let [b, n, _] = x.dims();
    let [ia, ib, ic] = topo.faces.clone();
    let [pa, pb, pc] = [&ia, &ib, &ic].map(|f| x.clone().select(1, f.clone())); // [B, F, 3]
    let dot = |u: Tensor<3>, v: Tensor<3>| (u * v).sum_dim(2); // [B, F, 1]
    let (ab, ac, bc) = (
        pb.clone() - pa.clone(),
        pc.clone() - pa.clone(),
        pc - pb.clone(),
    );
    let dbl = (sq_norm(cross(ab.clone(), ac.clone())) + EPS_NORMAL).sqrt(); // 2 area
    let (da, db, dc) = (
        dot(ab.clone(), ac.clone()),
        dot(ab.clone().neg(), bc.clone()),
        dot(ac.clone(), bc.clone()),
    ); // dot products at the corners a, b, c
    let cot = |d: Tensor<3>| (d / dbl.clone()).clamp(-COT_MAX, COT_MAX);
    let (cot_a, cot_b, cot_c) = (cot(da.clone()), cot(db.clone()), cot(dc.clone()));
    // Corner a: cot_c weighs edge ab, cot_b weighs edge ac; likewise b and c.
    let ka = ab.clone() * cot_c.clone() + ac.clone() * cot_b.clone();
    let kb = ab.clone().neg() * cot_c.clone() + bc.clone() * cot_a.clone();
    let kc = ac.clone().neg() * cot_b.clone() - bc.clone() * cot_a.clone();
    // Mixed areas: Voronoi in a non-obtuse triangle; else half the area at the obtuse
    // corner and a quarter at the others.
    let area = dbl / 2.0;
    let (lab, lac, lbc) = (sq_norm(ab), sq_norm(ac), sq_norm(bc));
    let obtuse = |d: &Tensor<3>| d.clone().detach().lower_elem(0.0).float(); // [B, F, 1]
    let (oa, ob, oc) = (obtuse(&da), obtuse(&db), obtuse(&dc));
    let any = (oa.clone() + ob.clone() + oc.clone()).clamp_max(1.0);
    let mixed = |voronoi: Tensor<3>, own: Tensor<3>| {
        let share = own.clone() * 0.5 + (own.neg() + 1.0) * 0.25;
        voronoi * (any.clone().neg() + 1.0) + any.clone() * share * area.clone()
    };
    let area_a = mixed(
        (lab.clone() * cot_c.clone() + lac.clone() * cot_b.clone()) / 8.0,
        oa,
    );
    let area_b = mixed((lab * cot_c + lbc.clone() * cot_a.clone()) / 8.0, ob);
    let area_c = mixed((lac * cot_b + lbc * cot_a) / 8.0, oc);
    let add = IndexingUpdateOp::Add;
    let sum = Tensor::<3>::zeros([b, n, 3], &x.device())
        .select_assign(1, ia.clone(), ka, add)
        .select_assign(1, ib.clone(), kb, add)
        .select_assign(1, ic.clone(), kc, add);
    let areas = Tensor::<3>::zeros([b, n, 1], &x.device())
        .select_assign(1, ia, area_a, add)
        .select_assign(1, ib, area_b, add)
        .select_assign(1, ic, area_c, add)
        .clamp_min(AREA_MIN);
    sum / (areas * 2.0)
}

/// L_MC (Eq. 14): mean over vertices of ||kappa^P_i - kappa^G_i||^2 with the cotangent
/// mean-curvature normal of [`mean_curvature_normal`], 1/m^2.
pub fn mean_curvature_loss(pred: Tensor<3>, target: Tensor<3>, topo: &LossTopology) -> Tensor<1> {
    sq_norm(mean_curvature_normal(pred, topo) - mean_curvature_normal(target, topo)).mean()
}

/// The curvature losses as evaluation metrics (the paper's Table 7): per sample L_MC and
/// L_RQ^8, L_RQ^16, L_RQ^32 of a prediction against its ground truth, without gradients.
#[derive(Debug, Clone)]
pub struct CurvatureErrors {
    topology: LossTopology,
    device: Device,
}

impl CurvatureErrors {
    /// For the garment with `vertices` vertices and `triangles`, on the default device.
    pub fn new(vertices: usize, triangles: &[[u32; 3]]) -> Self {
        let device = Device::default();
        Self {
            topology: LossTopology::new(&Topology::new(vertices, triangles), &device),
            device,
        }
    }

    /// `[L_MC, L_RQ^8, L_RQ^16, L_RQ^32]` of `pred` against `target` (metres).
    pub fn of(&self, pred: &[Vec3], target: &[Vec3]) -> [f64; 4] {
        let n = target.len();
        let tensor = |x: &[Vec3]| {
            let v: Vec<f32> = x.iter().flat_map(|p| p.to_array()).collect();
            Tensor::<3>::from_data(TensorData::new(v, [1, n, 3]), &self.device)
        };
        let (p, g) = (tensor(pred), tensor(target));
        let value = |t: Tensor<1>| t.into_data().try_into_vec::<f32>().expect("f32")[0] as f64;
        let mc = value(mean_curvature_loss(p.clone(), g.clone(), &self.topology));
        let kmax = RQ_SIZES[2];
        let rows = rq_neighbourhoods(&[target], kmax, &self.device);
        let rq = rayleigh_losses(p, g, rows, kmax, [true; 3]).map(|l| value(l.expect("on")));
        [mc, rq[0], rq[1], rq[2]]
    }
}
