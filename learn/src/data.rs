//! From dataset rows to network inputs: root-relative coordinates, the body point subset
//! with normals, the k-NN indices of GarNet-Local ([`crate::nearest`]), and the pushed-out body points
//! that L_pen compares against.

use burn::tensor::{Device, Int, Tensor, TensorData};
use dataset::shard::{Row, Static};
use glam::Vec3;

use crate::config::{ModelConfig, Variant};
use crate::model::Input;
pub use crate::nearest::{knn, nearest};
use crate::nearest::{knn_along, spatial_order};
use sim::mesh::vertex_normals;

use crate::topology::{farthest_point_subset, mean_edge_length};

/// One sample made ready for the network, on the CPU.
#[derive(Debug, Clone)]
pub struct Prepared {
    /// Sample id in its dataset.
    pub id: u64,
    /// The body's root joint (world), subtracted from every coordinate below.
    pub root: Vec3,
    /// Body subset points and normals, `P * 6`.
    pub body: Vec<f32>,
    /// Shape and pose parameters.
    pub params: Vec<f32>,
    /// The network's input garment, root-relative: the warped garment M, plus the linear
    /// prior's displacement with `model.prior`.
    pub warped: Vec<Vec3>,
    /// Simulated garment G, root-relative (absent at inference).
    pub target: Option<Vec<Vec3>>,
    /// GarNet-Local pooling neighbours (rows of this sample's P points), `P' * K_pool`.
    pub pool: Vec<u32>,
    /// GarNet-Local neighbours of each garment vertex (rows of P'), `N * K`.
    pub local: Vec<u32>,
    /// With `model.body_offsets`, per garment vertex: the offset to the closest posed body
    /// vertex (in `length_scale` units), its unit normal, and the signed distance along it
    /// (length units; negative inside), `N * 7` ([`body_offsets`]); empty without.
    pub offsets: Vec<f32>,
    /// Full body vertices, root-relative, pushed out along their normals (for L_pen).
    pub pen_points: Vec<Vec3>,
    /// Their unit normals.
    pub pen_normals: Vec<Vec3>,
    /// L_RQ neighbourhoods on the target: each vertex's `rq_k` nearest target vertices
    /// (itself first), `N * rq_k` (empty without a target or without L_RQ).
    pub rq: Vec<u32>,
}

/// Turns rows into [`Prepared`] samples for one model config and one garment.
#[derive(Debug, Clone)]
pub struct Preprocessor {
    config: ModelConfig,
    body_triangles: Vec<[u32; 3]>,
    /// Body vertex indices fed to the body stream (fixed farthest-point subset).
    pub body_subset: Vec<u32>,
    /// Positions within `body_subset` of the downsampled points (GarNet-Local).
    pub local_subset: Vec<u32>,
    /// The order the k-NN searches visit the downsampled points and the garment vertices in
    /// ([`crate::nearest::spatial_order`] of the canonical body's and the template's).
    local_order: Vec<u32>,
    garment_order: Vec<u32>,
    push_out: f32,
    /// L_RQ neighbourhood size found on each target (0: none).
    rq_k: usize,
    /// The prior added to M (`model.prior`).
    prior: Option<std::sync::Arc<crate::prior::Prior>>,
}

impl Preprocessor {
    /// The subsets are computed once from the canonical body, deterministically.
    /// `rq_k`: neighbourhood size of the L_RQ terms to find on each target (0: none).
    pub fn new(statics: &Static, config: &ModelConfig, push_out_share: f64, rq_k: usize) -> Self {
        let canon = &statics.canonical_body;
        let body_subset = farthest_point_subset(canon, config.body_points);
        let sub: Vec<Vec3> = body_subset.iter().map(|&i| canon[i as usize]).collect();
        let local_subset = farthest_point_subset(&sub, config.local_points());
        let down: Vec<Vec3> = local_subset.iter().map(|&i| sub[i as usize]).collect();
        let push_out = push_out_share as f32 * mean_edge_length(canon, &statics.body_triangles);
        Self {
            config: config.clone(),
            body_triangles: statics.body_triangles.clone(),
            body_subset,
            local_subset,
            local_order: spatial_order(&down),
            garment_order: spatial_order(&statics.garment_vertices),
            push_out,
            rq_k,
            prior: None,
        }
    }

    /// The same, adding `prior`'s displacement to every warped garment.
    pub fn with_prior(mut self, prior: std::sync::Arc<crate::prior::Prior>) -> Self {
        self.prior = Some(prior);
        self
    }

    /// The L_pen push-out distance, m.
    pub fn push_out(&self) -> f32 {
        self.push_out
    }

    /// Prepares one sample from its posed body, warped garment and (for training) the
    /// simulated garment.
    pub fn prepare(
        &self,
        id: u64,
        body: &[Vec3],
        root: Vec3,
        params: Vec<f32>,
        warped: &[Vec3],
        target: Option<&[Vec3]>,
    ) -> Prepared {
        let rel = |v: &[Vec3]| v.iter().map(|&p| p - root).collect::<Vec<_>>();
        let body_rel = rel(body);
        let normals = vertex_normals(&body_rel, &self.body_triangles);
        let mut pts = Vec::with_capacity(self.body_subset.len() * 6);
        let sub: Vec<Vec3> = self
            .body_subset
            .iter()
            .map(|&i| {
                let (p, n) = (body_rel[i as usize], normals[i as usize]);
                pts.extend_from_slice(&[p.x, p.y, p.z, n.x, n.y, n.z]);
                p
            })
            .collect();
        let mut warped = rel(warped);
        if let Some(prior) = &self.prior {
            prior.add_to(id, &params, &mut warped);
        }
        let (pool, local) = if self.config.variant == Variant::Local {
            let down: Vec<Vec3> = self.local_subset.iter().map(|&i| sub[i as usize]).collect();
            let pool = knn_along(&sub, &down, &self.local_order, self.config.local_pool_k);
            let local = if warped.len() == self.garment_order.len() {
                knn_along(&down, &warped, &self.garment_order, self.config.local_k)
            } else {
                knn(&down, &warped, self.config.local_k)
            };
            (pool, local)
        } else {
            (Vec::new(), Vec::new())
        };
        let offsets = if self.config.body_offsets {
            body_offsets(
                &body_rel,
                &normals,
                &warped,
                self.config.length_scale as f32,
            )
        } else {
            Vec::new()
        };
        let pen_points = body_rel
            .iter()
            .zip(&normals)
            .map(|(&p, &n)| p + n * self.push_out)
            .collect();
        let target = target.map(rel);
        // Found here, once per sample and in parallel across a batch, not in the loss.
        let rq = match &target {
            Some(g) if self.rq_k > 0 => knn(g, g, self.rq_k),
            _ => Vec::new(),
        };
        Prepared {
            id,
            root,
            body: pts,
            params,
            warped,
            target,
            rq,
            pool,
            local,
            offsets,
            pen_points,
            pen_normals: normals,
        }
    }

    /// Prepares a dataset row.
    pub fn prepare_row(&self, row: &Row) -> Prepared {
        self.prepare(
            row.id,
            &row.body,
            row.root,
            row_params(row),
            &row.warped,
            Some(&row.draped),
        )
    }
}

/// Shape parameters then pose quaternions (x, y, z, w per bone): GarNet-Global-Params'
/// body description.
pub fn body_params(shape: &[f32], pose: &[glam::Quat]) -> Vec<f32> {
    let mut p = shape.to_vec();
    for q in pose {
        p.extend_from_slice(&q.to_array());
    }
    p
}

/// Length of [`body_params`] for a skeleton of `bones` bones.
pub fn param_count(bones: usize) -> usize {
    dataset::shard::SHAPE_FIELDS.len() + 4 * bones
}

/// [`body_params`] of a dataset row.
pub fn row_params(row: &Row) -> Vec<f32> {
    body_params(&row.shape, &row.pose)
}

/// [`Prepared::offsets`]: for each garment vertex x, its closest body vertex p (normal n),
/// `[(p - x) / scale, n, n . (x - p) / scale]`.
pub fn body_offsets(body: &[Vec3], normals: &[Vec3], garment: &[Vec3], scale: f32) -> Vec<f32> {
    let inv = 1.0 / scale;
    nearest(body, garment)
        .iter()
        .zip(garment)
        .flat_map(|(&i, &x)| {
            let (p, n) = (body[i as usize], normals[i as usize]);
            let d = (p - x) * inv;
            [d.x, d.y, d.z, n.x, n.y, n.z, -n.dot(d)]
        })
        .collect()
}

/// A batch on a device: the network input and, for training, the target.
#[derive(Debug, Clone)]
pub struct Batch {
    /// The network input.
    pub input: Input,
    /// G^G, `[B, N, 3]`, root-relative.
    pub target: Option<Tensor<3>>,
}

/// Stacks prepared samples into a batch on `device`.
pub fn collate(samples: &[&Prepared], config: &ModelConfig, device: &Device) -> Batch {
    let b = samples.len();
    let p = samples[0].body.len() / 6;
    let n = samples[0].warped.len();
    let s = samples[0].params.len();
    let pd = config.local_points();
    let floats = |f: &dyn Fn(&Prepared) -> &[f32]| -> Vec<f32> {
        samples.iter().flat_map(|x| f(x).iter().copied()).collect()
    };
    let points = |f: &dyn Fn(&Prepared) -> &[Vec3]| -> Vec<f32> {
        samples
            .iter()
            .flat_map(|x| f(x).iter().flat_map(|p| p.to_array()))
            .collect()
    };
    let body = Tensor::<3>::from_data(TensorData::new(floats(&|x| &x.body), [b, p, 6]), device);
    let params = Tensor::<2>::from_data(TensorData::new(floats(&|x| &x.params), [b, s]), device);
    let warped = Tensor::<3>::from_data(TensorData::new(points(&|x| &x.warped), [b, n, 3]), device);
    let target = samples[0].target.is_some().then(|| {
        Tensor::<3>::from_data(
            TensorData::new(points(&|x| x.target.as_deref().unwrap()), [b, n, 3]),
            device,
        )
    });
    let offset = |field: &dyn Fn(&Prepared) -> &Vec<u32>, rows: usize| -> Tensor<1, Int> {
        let v: Vec<i64> = samples
            .iter()
            .enumerate()
            .flat_map(|(i, x)| field(x).iter().map(move |&j| (i * rows) as i64 + j as i64))
            .collect();
        let len = v.len();
        Tensor::from_data(TensorData::new(v, [len]), device)
    };
    let pool_index = offset(&|x| &x.pool, p);
    let local_index = offset(&|x| &x.local, pd);
    let offsets = config.body_offsets.then(|| {
        Tensor::<3>::from_data(TensorData::new(floats(&|x| &x.offsets), [b, n, 7]), device)
    });
    Batch {
        input: Input {
            body,
            params,
            warped,
            pool_index,
            local_index,
            offsets,
        },
        target,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn body_offsets_point_to_the_closest_body_vertex_and_sign_the_side() {
        // A floor of body vertices at y = 0 facing +y; one vertex far off at (5, 0, 0).
        let body = vec![
            Vec3::new(0.0, 0.0, 0.0),
            Vec3::new(1.0, 0.0, 0.0),
            Vec3::new(5.0, 0.0, 0.0),
        ];
        let normals = vec![Vec3::Y; 3];
        let garment = vec![Vec3::new(0.9, 0.2, 0.0), Vec3::new(0.1, -0.3, 0.0)];
        let o = body_offsets(&body, &normals, &garment, 0.1);
        assert_eq!(o.len(), 14);
        let close = |a: &[f32], b: &[f32]| a.iter().zip(b).all(|(x, y)| (x - y).abs() < 1e-5);
        // Above the floor, closest to (1, 0, 0): offset (0.1, -0.2, 0) / 0.1, distance +2.
        assert!(
            close(&o[..7], &[1.0, -2.0, 0.0, 0.0, 1.0, 0.0, 2.0]),
            "{o:?}"
        );
        // Below it (inside), closest to the origin: distance -3.
        assert!(
            close(&o[7..], &[-1.0, 3.0, 0.0, 0.0, 1.0, 0.0, -3.0]),
            "{o:?}"
        );
    }
}
