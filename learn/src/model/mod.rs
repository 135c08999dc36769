//! The GarNet family (GarNet++ paper, section 3): **the forward pass** is
//! [`GarNet::forward`].
//!
//! Body stream (PointNet with a spatial transformer) -> global body feature (and point-wise
//! body features for GarNet-Local); garment stream (point-wise MLP, the global body feature
//! repeated per vertex, residual FeaStNet blocks with xyz concatenated at each block);
//! fusion (point-wise MLP to 3 outputs, the per-vertex translation T^P). Prediction
//! G^P = M + T^P.

#[cfg(feature = "flex")]
pub mod dense;
pub mod feast;
pub mod fused;
pub mod host;
mod layers;
pub mod trainops;

pub use layers::{Aggregation, FeaStConv, Graph, Mlp, SplitLinear, linear_act};

use layers::{maybe_norm, norm_act};

use burn::module::Module;
use burn::nn::{Initializer, LayerNorm, Linear, LinearConfig};
use burn::tensor::{Device, Int, Tensor, TensorData};

use crate::config::{ModelConfig, Variant};

/// What the network reads for one batch (coordinates relative to the body's root joint).
#[derive(Debug, Clone)]
pub struct Input {
    /// Body points with normals, `[B, P, 6]` (xyz, normal).
    pub body: Tensor<3>,
    /// Shape and pose parameters, `[B, S]` (GarNet-Global-Params only).
    pub params: Tensor<2>,
    /// The DQS-warped garment M, `[B, N, 3]`.
    pub warped: Tensor<3>,
    /// For each downsampled body point, its `local_pool_k` nearest body points, as rows of
    /// the flattened `[B * P]` body features, `[B * P' * K_pool]` (GarNet-Local).
    pub pool_index: Tensor<1, Int>,
    /// For each garment vertex, its `local_k` nearest downsampled body points, as rows of
    /// the flattened `[B * P']`, `[B * N * K]` (GarNet-Local).
    pub local_index: Tensor<1, Int>,
    /// Each garment vertex's geometry relative to the closest body vertex, `[B, N, 7]`
    /// (`model.body_offsets`; [`crate::data::body_offsets`]).
    pub offsets: Option<Tensor<3>>,
}

/// PointNet's spatial transformer on the body points: a 3 x 3 matrix per sample, identity
/// at initialisation.
#[derive(Module, Debug)]
pub struct SpatialTransformer {
    mlp: Mlp,
    head: Mlp,
    out: Linear,
}

impl SpatialTransformer {
    fn new(c: &ModelConfig, device: &Device) -> Self {
        let mlp = Mlp::new(6, &c.stn_mlp, c.leaky_slope, c.layer_norm, device);
        let head = Mlp::new(
            *c.stn_mlp.last().unwrap(),
            &c.stn_head,
            c.leaky_slope,
            c.layer_norm,
            device,
        );
        let out = LinearConfig::new(*c.stn_head.last().unwrap(), 9)
            .with_initializer(Initializer::Zeros)
            .init(device);
        Self { mlp, head, out }
    }

    /// # Shapes
    /// `[B, P, 6]` -> `[B, 3, 3]`.
    fn forward(&self, x: Tensor<3>) -> Tensor<3> {
        let [b, _, _] = x.dims();
        let h = self.mlp.forward(x); // [B, P, C]
        let c = h.dims()[2];
        let g = host::max_axis1(h).reshape([b, c]); // [B, C]
        let t = linear_act(&self.out, self.head.forward(g), None).reshape([b, 3, 3]); // [B, 3, 3]
        let eye = Tensor::<2>::eye(3, &t.device()).unsqueeze_dim::<3>(0);
        t + eye
    }
}

/// The body stream: spatial transformer, MLP block 1, skip connection of the transformed
/// points to the input of MLP block 2, max pool.
#[derive(Module, Debug)]
pub struct BodyStream {
    stn: SpatialTransformer,
    mlp1: Mlp,
    /// Block 2 up to its last layer: its output is the point-wise body feature.
    mlp2_point: Mlp,
    /// Block 2's last layer: max-pooled into the global body feature.
    mlp2_global: Mlp,
}

impl BodyStream {
    fn new(c: &ModelConfig, device: &Device) -> Self {
        let c1 = *c.body_mlp1.last().unwrap();
        let (point, global) = c.body_mlp2.split_at(c.body_mlp2.len() - 1);
        Self {
            stn: SpatialTransformer::new(c, device),
            mlp1: Mlp::new(6, &c.body_mlp1, c.leaky_slope, c.layer_norm, device),
            mlp2_point: Mlp::new(c1 + 6, point, c.leaky_slope, c.layer_norm, device),
            mlp2_global: Mlp::new(
                *point.last().unwrap(),
                global,
                c.leaky_slope,
                c.layer_norm,
                device,
            ),
        }
    }

    /// # Shapes
    /// `[B, P, 6]` -> (point-wise `[B, P, C_p]`, global `[B, G]`).
    pub fn forward(&self, x: Tensor<3>) -> (Tensor<3>, Tensor<2>) {
        if host::host(&x) && x.dims()[0] * x.dims()[1] > 0 {
            return self.forward_host(x);
        }
        let [b, p, _] = x.dims();
        let t = self.stn.forward(x.clone()); // [B, 3, 3]
        let xyz = x.clone().slice([0..b, 0..p, 0..3]).matmul(t.clone()); // [B, P, 3]
        let nrm = x.slice([0..b, 0..p, 3..6]).matmul(t); // [B, P, 3]
        let xt = Tensor::cat(vec![xyz, nrm], 2); // [B, P, 6]
        let f1 = self.mlp1.forward(xt.clone()); // [B, P, C1]
        let point = self.mlp2_point.forward(Tensor::cat(vec![f1, xt], 2)); // [B, P, Cp]
        let g = self.mlp2_global.forward(point.clone()); // [B, P, G]
        let gd = g.dims()[2];
        (point, host::max_axis1(g).reshape([b, gd]))
    }

    /// [`BodyStream::forward`] without autodiff on the CPU backends: each MLP in
    /// [`fused::pointwise_head`], the maxima and the transform on the host (at batch 1 burn's
    /// operations took 2.0 ms for the stream's 0.35 GFLOPs over 2,000 points; docs/bench.md,
    /// "The local search as a scan").
    fn forward_host(&self, x: Tensor<3>) -> (Tensor<3>, Tensor<2>) {
        let [b, p, _] = x.dims();
        let device = x.device();
        let x = host::floats(x);
        // The spatial transformer: its point-wise MLP, max-pooled, then its small head on
        // burn.
        let h = mlp_host(&self.stn.mlp, &[(&x, 6)], (b, p));
        let c = h.len() / (b * p);
        let g = host::row_maxima(&h, [b, p, c]);
        let g = Tensor::<2>::from_data(TensorData::new(g, [b, c]), &device);
        let t = host::floats(self.stn.out.forward(self.stn.head.forward(g))); // [B, 9]
        // The points and normals through T + I.
        let mut xt = vec![0.0f32; b * p * 6];
        for (s, (xs, ts)) in x
            .chunks_exact(p * 6)
            .zip(xt.chunks_exact_mut(p * 6))
            .enumerate()
        {
            let m = &t[s * 9..(s + 1) * 9];
            let e = |i: usize, j: usize| m[i * 3 + j] + if i == j { 1.0 } else { 0.0 };
            for (xr, tr) in xs.chunks_exact(3).zip(ts.chunks_exact_mut(3)) {
                for (j, o) in tr.iter_mut().enumerate() {
                    *o = xr[0] * e(0, j) + xr[1] * e(1, j) + xr[2] * e(2, j);
                }
            }
        }
        let f1 = mlp_host(&self.mlp1, &[(&xt, 6)], (b, p));
        let c1 = f1.len() / (b * p);
        let point = mlp_host(&self.mlp2_point, &[(&f1, c1), (&xt, 6)], (b, p));
        let cp = point.len() / (b * p);
        let g = mlp_host(&self.mlp2_global, &[(&point, cp)], (b, p));
        let gd = g.len() / (b * p);
        let global = host::row_maxima(&g, [b, p, gd]);
        (
            Tensor::from_data(TensorData::new(point, [b, p, cp]), &device),
            Tensor::from_data(TensorData::new(global, [b, gd]), &device),
        )
    }
}

/// `mlp` on the concatenation of `parts` (each `[B, N, d_k]`, in the order of the first
/// layer's input) in [`fused::pointwise_head`]: all its layers per tile of vertices.
///
/// # Shapes
/// -> `[B, N, output]` (flattened).
fn mlp_host(mlp: &Mlp, parts: &[(&[f32], usize)], (b, n): (usize, usize)) -> Vec<f32> {
    let mut layers = mlp.host_layers();
    let mut first = layers.remove(0);
    // The first layer's bias is the same for every drape: it is pointwise_head's constant.
    let constant: Vec<f32> = (0..b).flat_map(|_| first.b.iter().copied()).collect();
    first.b = Vec::new();
    fused::pointwise_head(
        parts,
        &constant,
        &first,
        &layers,
        (b, n),
        mlp.slope() as f32,
    )
}

/// The garment stream's mesh convolutions: `blocks` residual FeaStNet blocks, the input xyz
/// concatenated to the input of each.
#[derive(Module, Debug)]
pub struct ConvStack {
    blocks: Vec<FeaStConv>,
    /// One layer normalisation per block on its convolution's output, before the activation
    /// ([`ModelConfig::layer_norm`]); empty without.
    norms: Vec<LayerNorm>,
    #[module(skip)]
    slope: f64,
}

impl ConvStack {
    fn new(c: &ModelConfig, device: &Device) -> Self {
        let blocks = (0..c.conv_blocks)
            .map(|_| {
                FeaStConv::new(
                    c.conv_width + 3,
                    c.conv_width,
                    c.conv_heads,
                    c.zero_init_residuals,
                    device,
                )
            })
            .collect();
        let norms = (0..c.conv_blocks)
            .flat_map(|_| maybe_norm(c.layer_norm, c.conv_width, device))
            .collect();
        Self {
            blocks,
            norms,
            slope: c.leaky_slope,
        }
    }

    /// # Shapes
    /// `h`: `[B, N, C]`, `xyz`: `[B, N, 3]` -> `[B, N, C]`.
    fn forward(&self, mut h: Tensor<3>, xyz: Tensor<3>, g: &Graph) -> Tensor<3> {
        if host::host(&h) {
            return self.forward_host(h, xyz, g);
        }
        let how = g.aggregation(h.dims()[0], &h.device());
        for (i, conv) in self.blocks.iter().enumerate() {
            let x = Tensor::cat(vec![h.clone(), xyz.clone()], 2);
            let y = norm_act(self.norms.get(i), self.slope, |act| {
                conv.forward_act(x, g, &how, act)
            }); // [B, N, C]
            h = h + y;
        }
        h
    }

    /// [`ConvStack::forward`] without autodiff on the CPU backends: all blocks in
    /// [`fused::residual_stack`].
    fn forward_host(&self, h: Tensor<3>, xyz: Tensor<3>, g: &Graph) -> Tensor<3> {
        let [b, n, width] = h.dims();
        let device = h.device();
        let blocks: Vec<fused::HostBlock> = self
            .blocks
            .iter()
            .enumerate()
            .map(|(i, conv)| conv.host_block(self.norms.get(i)))
            .collect();
        let out = fused::residual_stack(
            &host::floats(h),
            &host::floats(xyz),
            &blocks,
            &g.host_slots,
            &g.host_inv_degree,
            fused::StackShape {
                batch: b,
                vertices: n,
                width,
                heads: self.blocks.first().map_or(1, |c| c.heads()),
                slope: self.slope as f32,
            },
        );
        Tensor::from_data(TensorData::new(out, [b, n, width]), &device)
    }
}

/// A GarNet network. Which parts exist depends on the variant.
#[derive(Module, Debug)]
pub struct GarNet {
    /// PointNet body stream (absent in GarNet-Global-Params).
    body: Option<BodyStream>,
    /// Reduces point-wise body features before local pooling (GarNet-Local).
    local_in: Option<Linear>,
    /// Garment point-wise MLP.
    garment_mlp: Mlp,
    /// Point-wise garment features + global body feature -> conv width.
    conv_in: SplitLinear,
    /// Layer normalisation after `conv_in` ([`ModelConfig::layer_norm`]).
    conv_in_norm: Option<LayerNorm>,
    /// Residual FeaStNet blocks (absent in GarNet-Naive).
    convs: Option<ConvStack>,
    /// First fusion layer, on [point-wise, patch-wise, global garment, global body
    /// (, local body)] features.
    fusion_in: SplitLinear,
    /// Layer normalisation after `fusion_in` ([`ModelConfig::layer_norm`]).
    fusion_in_norm: Option<LayerNorm>,
    /// The other fusion layers.
    fusion: Mlp,
    /// Last fusion layer: 3 outputs, zero at initialisation (the network starts at M).
    out: Linear,
    #[module(skip)]
    variant: Variant,
    #[module(skip)]
    slope: f64,
    #[module(skip)]
    local_pool_k: usize,
    #[module(skip)]
    local_k: usize,
    #[module(skip)]
    local_points: usize,
    #[module(skip)]
    length_scale: f64,
    #[module(skip)]
    fourier_bands: usize,
}

/// Inputs of the garment point-wise MLP: xyz and, with `fourier_bands`, their encoding;
/// with `body_offsets`, the 7 numbers of the vertex's geometry relative to the body.
fn garment_inputs(c: &ModelConfig) -> usize {
    3 + 6 * c.fourier_bands + if c.body_offsets { 7 } else { 0 }
}

/// The positional encoding of [`ModelConfig::fourier_bands`]: `[x, sin(x), cos(x),
/// sin(2x), cos(2x), ...]` to `2^(bands-1) x`, per coordinate.
///
/// # Shapes
/// `[B, N, 3]` -> `[B, N, 3 + 6 bands]`.
pub fn positional_encoding(x: Tensor<3>, bands: usize) -> Tensor<3> {
    if bands == 0 {
        return x; // the default: no copy in the forward pass
    }
    let mut parts = vec![x.clone()];
    for k in 0..bands {
        let scaled = x.clone() * (1u64 << k) as f64;
        parts.push(scaled.clone().sin());
        parts.push(scaled.cos());
    }
    Tensor::cat(parts, 2)
}

/// Body features a forward pass takes from another drape of its batch
/// ([`GarNet::forward_swapped`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Swap {
    /// The global body feature (GarNet-Global-Params: the shape-and-pose vector), which
    /// enters the garment stream and the fusion.
    pub global: bool,
    /// GarNet-Local's local body features of each garment vertex.
    pub local: bool,
    /// Each vertex's geometry relative to the body (`model.body_offsets`).
    pub offsets: bool,
}

impl Swap {
    /// Every input the drape's own.
    pub const NONE: Self = Self {
        global: false,
        local: false,
        offsets: false,
    };
}

/// `x` with its batch (first) axis rotated by one: row `b` holds row `(b + 1) mod B`.
fn next_in_batch<const D: usize>(x: Tensor<D>) -> Tensor<D> {
    let b = x.dims()[0];
    if b < 2 {
        return x;
    }
    Tensor::cat(vec![x.clone().narrow(0, 1, b - 1), x.narrow(0, 0, 1)], 0)
}

/// Width of the local body feature after its reduction layer (our choice).
pub const LOCAL_WIDTH: usize = 32;

impl GarNet {
    /// A freshly initialised network. `params` is the length of the shape-and-pose vector
    /// (used by GarNet-Global-Params).
    pub fn new(c: &ModelConfig, params: usize, device: &Device) -> Self {
        let global = match c.variant {
            Variant::GlobalParams => params,
            _ => *c.body_mlp2.last().unwrap(),
        };
        let body_point = c.body_mlp2[c.body_mlp2.len() - 2];
        let cg = *c.garment_mlp.last().unwrap();
        let local = matches!(c.variant, Variant::Local);
        let mut fusion_in = vec![cg, c.conv_width, c.conv_width, global];
        if local {
            fusion_in.push(LOCAL_WIDTH);
        }
        Self {
            body: (c.variant != Variant::GlobalParams).then(|| BodyStream::new(c, device)),
            local_in: local.then(|| LinearConfig::new(body_point, LOCAL_WIDTH).init(device)),
            garment_mlp: Mlp::new(
                garment_inputs(c),
                &c.garment_mlp,
                c.leaky_slope,
                c.layer_norm,
                device,
            ),
            conv_in: SplitLinear::new(&[cg, global], c.conv_width, device),
            conv_in_norm: maybe_norm(c.layer_norm, c.conv_width, device),
            convs: c
                .variant
                .has_mesh_convolutions()
                .then(|| ConvStack::new(c, device)),
            fusion_in: SplitLinear::new(&fusion_in, c.fusion[0], device),
            fusion_in_norm: maybe_norm(c.layer_norm, c.fusion[0], device),
            fusion: Mlp::new(
                c.fusion[0],
                &c.fusion[1..],
                c.leaky_slope,
                c.layer_norm,
                device,
            ),
            out: LinearConfig::new(*c.fusion.last().unwrap(), 3)
                .with_initializer(Initializer::Zeros)
                .init(device),
            variant: c.variant,
            slope: c.leaky_slope,
            local_pool_k: c.local_pool_k,
            local_k: c.local_k,
            local_points: c.local_points(),
            length_scale: c.length_scale,
            fourier_bands: c.fourier_bands,
        }
    }

    /// The variant this network was built as.
    pub fn variant(&self) -> Variant {
        self.variant
    }

    /// Per-vertex translations T^P; the prediction is `input.warped + T^P`.
    ///
    /// # Shapes
    /// `input` as documented on [`Input`] -> `[B, N, 3]`.
    pub fn forward(&self, input: &Input, g: &Graph) -> Tensor<3> {
        self.forward_swapped(input, g, Swap::NONE)
    }

    /// [`GarNet::forward`] with the body features that `swap` names taken from the next
    /// drape of the batch (drape `b` reads drape `(b + 1) mod B`'s), everything else from
    /// the drape's own inputs: how much a trained network relies on each (permutation
    /// importance, `drape importance`). A batch of one drape swaps nothing.
    ///
    /// # Shapes
    /// As [`GarNet::forward`].
    pub fn forward_swapped(&self, input: &Input, g: &Graph, swap: Swap) -> Tensor<3> {
        let [b, n, _] = input.warped.dims();
        // Body stream.
        let inv = 1.0 / self.length_scale;
        let (body_point, body_global) = match &self.body {
            Some(body) => {
                let [_, p, _] = input.body.dims();
                let x = input.body.clone();
                let x = Tensor::cat(
                    vec![
                        x.clone().slice([0..b, 0..p, 0..3]) * inv,
                        x.slice([0..b, 0..p, 3..6]),
                    ],
                    2,
                ); // [B, P, 6], scaled xyz and unit normals
                let (p, g) = body.forward(x); // [B, P, Cp], [B, G]
                (Some(p), g)
            }
            None => (None, input.params.clone()), // [B, S]
        };
        let body_global = if swap.global {
            next_in_batch(body_global)
        } else {
            body_global
        };
        let global = body_global.unsqueeze_dim::<3>(1); // [B, 1, G]
        // Garment stream.
        let xyz = input.warped.clone() * inv; // [B, N, 3]
        let encoded = positional_encoding(xyz.clone(), self.fourier_bands);
        let encoded = match &input.offsets {
            Some(o) if swap.offsets => Tensor::cat(vec![encoded, next_in_batch(o.clone())], 2),
            Some(o) => Tensor::cat(vec![encoded, o.clone()], 2), // [B, N, 3 + ... + 7]
            None => encoded,
        };
        let (point, h0) = if host::host(&encoded) && b * n > 0 {
            self.garment_in_host(encoded, global.clone())
        } else {
            let point = self.garment_mlp.forward(encoded); // [B, N, Cg]
            let h0 = norm_act(self.conv_in_norm.as_ref(), self.slope, |act| {
                let inputs = vec![point.clone(), global.clone()];
                self.conv_in.forward_act(inputs, act)
            }); // [B, N, C]
            (point, h0)
        };
        let patch = match &self.convs {
            Some(convs) => convs.forward(h0, xyz, g), // [B, N, C]
            None => h0,
        };
        let garment_global = host::max_axis1(patch.clone()); // [B, 1, C]
        let mut fused = vec![point, patch, garment_global, global];
        // Local body features.
        if let (Some(local_in), Some(body_point)) = (&self.local_in, body_point) {
            let [_, p, _] = body_point.dims();
            let f = linear_act(local_in, body_point, Some(self.slope)); // [B, P, L]
            let l = LOCAL_WIDTH;
            let (pd, kp, k) = (self.local_points, self.local_pool_k, self.local_k);
            let pooled = f
                .reshape([b * p, l])
                .select(0, input.pool_index.clone()) // [B * P' * Kp, L]
                .reshape([b * pd, kp, l])
                .mean_dim(1)
                .reshape([b * pd, l]); // [B * P', L]
            let local = host::gather_max(pooled, &input.local_index, k) // [B * N, L]
                .reshape([b, n, l]); // [B, N, L]
            fused.push(if swap.local {
                next_in_batch(local)
            } else {
                local
            });
        }
        if host::host(&fused[0]) {
            return self.head_host(fused);
        }
        let f = norm_act(self.fusion_in_norm.as_ref(), self.slope, |act| {
            self.fusion_in.forward_act(fused, act)
        }); // [B, N, F0]
        linear_act(&self.out, self.fusion.forward(f), None) // [B, N, 3]
    }

    /// The garment stream's point-wise layers without autodiff on the CPU backends: the
    /// garment MLP and `conv_in` on its output and the global body feature, each in
    /// [`fused::pointwise_head`] (at batch 1 and 10k vertices burn's operations took 0.9
    /// ms for their 0.1 GFLOPs; docs/bench.md, "The local search as a scan").
    ///
    /// # Shapes
    /// `encoded`: `[B, N, D]`, `global`: `[B, 1, G]` -> (`[B, N, Cg]`, `[B, N, C]`).
    fn garment_in_host(&self, encoded: Tensor<3>, global: Tensor<3>) -> (Tensor<3>, Tensor<3>) {
        let [b, n, d] = encoded.dims();
        let device = encoded.device();
        let slope = self.slope as f32;
        let point = mlp_host(&self.garment_mlp, &[(&host::floats(encoded), d)], (b, n));
        let cg = point.len() / (b * n);
        let point = Tensor::from_data(TensorData::new(point, [b, n, cg]), &device);
        let (parts, stacked, constant) =
            split_inputs(vec![point.clone(), global], self.conv_in.host_maps(), b, n);
        let conv_in = fused::HostDense {
            w: stacked,
            b: Vec::new(),
            norm: self.conv_in_norm.as_ref().map(layers::host_norm),
            leaky: true,
        };
        let part_refs: Vec<(&[f32], usize)> =
            parts.iter().map(|(v, d)| (v.as_slice(), *d)).collect();
        let h0 = fused::pointwise_head(&part_refs, &constant, &conv_in, &[], (b, n), slope);
        let c = h0.len() / (b * n);
        (
            point,
            Tensor::from_data(TensorData::new(h0, [b, n, c]), &device),
        )
    }

    /// The fusion head without autodiff on the CPU backends
    /// ([`fused::pointwise_head`]): the per-drape inputs' products (the global garment and
    /// body features) and the bias made once per drape, the per-vertex inputs through all
    /// layers per tile.
    ///
    /// # Shapes
    /// `fused`: `[B, N or 1, C_k]` each -> `[B, N, 3]`.
    fn head_host(&self, fused: Vec<Tensor<3>>) -> Tensor<3> {
        let [b, n, _] = fused[0].dims();
        let device = fused[0].device();
        let maps = self.fusion_in.host_maps();
        let (parts, stacked, constant) = split_inputs(fused, maps, b, n);
        let first = fused::HostDense {
            w: stacked,
            b: Vec::new(), // the per-drape `constant` is its bias
            norm: self.fusion_in_norm.as_ref().map(layers::host_norm),
            leaky: true,
        };
        let mut rest = self.fusion.host_layers();
        rest.push(layers::host_dense(&self.out, None, false));
        let part_refs: Vec<(&[f32], usize)> =
            parts.iter().map(|(v, d)| (v.as_slice(), *d)).collect();
        let out = fused::pointwise_head(
            &part_refs,
            &constant,
            &first,
            &rest,
            (b, n),
            self.slope as f32,
        );
        Tensor::from_data(TensorData::new(out, [b, n, 3]), &device)
    }
}

/// A split layer's inputs on the host ([`SplitLinear::host_maps`] `maps`, one per input):
/// the per-vertex inputs (`[B, N, d_k]`) with their maps stacked `[sum d_k, F]`, and one row
/// per drape (`[B, F]`) of the bias plus the broadcast inputs' (`[B, 1, d_k]`) products.
#[allow(clippy::type_complexity)]
fn split_inputs(
    inputs: Vec<Tensor<3>>,
    maps: Vec<(Vec<f32>, Option<Vec<f32>>)>,
    b: usize,
    n: usize,
) -> (Vec<(Vec<f32>, usize)>, Vec<f32>, Vec<f32>) {
    let f0 = maps[0].0.len() / inputs[0].dims()[2];
    let mut constant = vec![0.0f32; b * f0];
    let (mut parts, mut stacked) = (Vec::new(), Vec::new());
    for (t, (w, bias)) in inputs.into_iter().zip(maps) {
        let [_, rows, d] = t.dims();
        let v = host::floats(t);
        if let Some(bias) = bias {
            for row in constant.chunks_exact_mut(f0) {
                for (o, c) in row.iter_mut().zip(&bias) {
                    *o += c;
                }
            }
        }
        if rows == n {
            parts.push((v, d));
            stacked.extend(w);
        } else {
            for (s, row) in constant.chunks_exact_mut(f0).enumerate() {
                for (e, &x) in v[s * d..(s + 1) * d].iter().enumerate() {
                    for (o, &wv) in row.iter_mut().zip(&w[e * f0..(e + 1) * f0]) {
                        *o += x * wv;
                    }
                }
            }
        }
    }
    (parts, stacked, constant)
}

/// Floating-point operations of one forward pass for one sample (a multiply-add counts
/// 2): the dense layers, the spatial transformer's 3x3 products and FeaStNet's padded
/// aggregation `[M, K] x [K, C]` as executed (`slots` = K, the padded neighbourhood size),
/// for `vertices` garment vertices and `params` shape-and-pose inputs (Global-Params).
/// Activations, layer normalisations, softmax, pooling and gathers are left out: they are
/// a few operations per element against the dense layers' hundreds.
pub fn forward_flops(c: &ModelConfig, params: usize, vertices: usize, slots: usize) -> f64 {
    let n = vertices as f64;
    let p = c.body_points as f64;
    let dense = |rows: f64, i: usize, o: usize| 2.0 * rows * i as f64 * o as f64;
    let mlp = |rows: f64, input: usize, widths: &[usize]| {
        let mut i = input;
        let mut f = 0.0;
        for &w in widths {
            f += dense(rows, i, w);
            i = w;
        }
        f
    };
    let mut f = 0.0;
    let global = match c.variant {
        Variant::GlobalParams => params,
        _ => *c.body_mlp2.last().unwrap(),
    };
    if c.variant != Variant::GlobalParams {
        // Spatial transformer, the two 3x3 products, then the body MLPs.
        f += mlp(p, 6, &c.stn_mlp);
        f += mlp(1.0, *c.stn_mlp.last().unwrap(), &c.stn_head);
        f += dense(1.0, *c.stn_head.last().unwrap(), 9);
        f += 2.0 * dense(p, 3, 3);
        f += mlp(p, 6, &c.body_mlp1);
        let (point, last) = c.body_mlp2.split_at(c.body_mlp2.len() - 1);
        f += mlp(p, c.body_mlp1.last().unwrap() + 6, point);
        f += mlp(p, *point.last().unwrap(), last);
    }
    let cg = *c.garment_mlp.last().unwrap();
    f += mlp(n, garment_inputs(c), &c.garment_mlp);
    f += dense(n, cg, c.conv_width) + dense(1.0, global, c.conv_width);
    if c.variant.has_mesh_convolutions() {
        let (ci, m, k) = (c.conv_width + 3, c.conv_heads, slots);
        let block =
            dense(n, ci, m) + 2.0 * n * (m * k * ci) as f64 + dense(n, m * ci, c.conv_width);
        f += c.conv_blocks as f64 * block;
    }
    let mut fusion_in = cg + 2 * c.conv_width;
    if c.variant == Variant::Local {
        f += dense(p, c.body_mlp2[c.body_mlp2.len() - 2], LOCAL_WIDTH);
        fusion_in += LOCAL_WIDTH;
    }
    f += dense(n, fusion_in, c.fusion[0]) + dense(1.0, global, c.fusion[0]);
    f += mlp(n, c.fusion[0], &c.fusion[1..]);
    f += dense(n, *c.fusion.last().unwrap(), 3);
    f
}

#[cfg(test)]
mod tests {
    use burn::module::Param;
    use burn::tensor::{Device, Distribution, Tensor};

    use super::*;
    use crate::topology::Topology;

    fn floats(x: Tensor<3>) -> Vec<f32> {
        x.into_data()
            .convert::<f32>()
            .try_into_vec::<f32>()
            .unwrap()
    }

    /// The residual blocks fused on the host (off the autodiff device) give the training
    /// operations' values (on it: burn's and this crate's, [`super::dense`] and others),
    /// with and without layer normalisation, the normalisations' gains and offsets drawn
    /// away from 1 and 0.
    #[test]
    fn fused_residual_blocks_are_burns_operations() {
        let ad = Device::default().autodiff();
        ad.seed(9);
        let (w, rows) = (13u32, 7u32);
        let mut tris = Vec::new();
        for y in 0..rows - 1 {
            for x in 0..w - 1 {
                let v = y * w + x;
                tris.push([v, v + 1, v + w]);
                tris.push([v + 1, v + w + 1, v + w]);
            }
        }
        let topo = Topology::new((w * rows) as usize, &tris);
        let n = topo.vertices;
        for (width, heads, layer_norm) in [(48, 4, false), (20, 3, true)] {
            let c = ModelConfig {
                conv_width: width,
                conv_heads: heads,
                conv_blocks: 3,
                layer_norm,
                ..ModelConfig::default()
            };
            let mut stack = ConvStack::new(&c, &ad);
            for norm in stack.norms.iter_mut() {
                let draw = |lo: f64, hi: f64| {
                    Param::from_tensor(Tensor::<1>::random(
                        [width],
                        Distribution::Uniform(lo, hi),
                        &ad,
                    ))
                };
                norm.gamma = draw(0.5, 1.5);
                norm.beta = Some(draw(-0.3, 0.3));
            }
            for conv in stack.blocks.iter_mut() {
                conv.bias = Param::from_tensor(Tensor::<1>::random(
                    [width],
                    Distribution::Uniform(-0.2, 0.2),
                    &ad,
                ));
            }
            let b = 2;
            let h = Tensor::<3>::random([b, n, width], Distribution::Normal(0.0, 1.0), &ad);
            let xyz = Tensor::<3>::random([b, n, 3], Distribution::Normal(0.0, 1.0), &ad);
            let want = stack.forward(h.clone(), xyz.clone(), &Graph::new(&topo, &ad));
            let plain = ad.clone().inner();
            let stack = stack.valid();
            let (h, xyz) = (h.inner(), xyz.inner());
            assert!(host::host(&h));
            let got = stack.forward(h, xyz, &Graph::new(&topo, &plain));
            let (err, scale) = fused::largest_difference(&floats(got), &floats(want.inner()));
            assert!(
                err / scale < 1e-5,
                "width {width}, heads {heads}, layer norm {layer_norm}: {err} of {scale}"
            );
        }
    }
}
