//! The training losses of the GarNet++ paper, one function each, on root-relative metres.
//!
//! `pred` is G^P = M + T^P and `target` is G^G, both `[B, N, 3]`. Every loss is a mean
//! over the batch, so batch size does not change its scale.

use burn::tensor::activation::relu;
use burn::tensor::{Device, Int, Tensor, TensorData};
use glam::Vec3;

use crate::data::{Prepared, nearest};
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
