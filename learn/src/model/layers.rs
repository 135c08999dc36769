//! Building blocks: point-wise MLPs and the FeaStNet convolution.

use burn::module::{Module, Param};
use burn::nn::{Initializer, LayerNorm, LayerNormConfig, Linear, LinearConfig};
use burn::tensor::activation::{leaky_relu, relu, softmax};
use burn::tensor::{Device, Int, Tensor, TensorData};

use std::sync::Arc;

use super::feast::{self, Slots};
use super::fused::{HostBlock, HostDense};
use super::host;
use crate::topology::Topology;

/// He initialisation (uniform, fan in): keeps the activations' scale through leaky-ReLU
/// layers; burn's default (a bound of 1/sqrt(fan_in)) shrinks it by about 2.4x per layer.
pub fn he() -> Initializer {
    Initializer::KaimingUniform {
        gain: std::f64::consts::SQRT_2,
        fan_out_only: false,
    }
}

/// A layer normalisation over the last axis (features) of `width`, or none: the
/// normalisation of [`crate::config::ModelConfig::layer_norm`].
pub fn maybe_norm(on: bool, width: usize, device: &Device) -> Option<LayerNorm> {
    on.then(|| {
        LayerNormConfig::new(width)
            .with_epsilon(NORM_EPSILON)
            .init(device)
    })
}

/// A layer normalisation's gamma, beta (zeros when it has none) and epsilon on the host.
pub(super) fn host_norm(n: &LayerNorm) -> (Vec<f32>, Vec<f32>, f32) {
    let gamma = host::floats(n.gamma.val());
    let beta = match &n.beta {
        Some(b) => host::floats(b.val()),
        None => vec![0.0; gamma.len()],
    };
    (gamma, beta, NORM_EPSILON as f32)
}

/// A linear layer (and the normalisation and activation after it) on the host.
pub(super) fn host_dense(l: &Linear, norm: Option<&LayerNorm>, leaky: bool) -> HostDense {
    let w = host::floats(l.weight.val());
    let out = l.weight.val().dims()[1];
    HostDense {
        w,
        b: l.bias
            .as_ref()
            .map_or_else(|| vec![0.0; out], |b| host::floats(b.val())),
        norm: norm.map(host_norm),
        leaky,
    }
}

/// The layer normalisations' epsilon (burn's default; not saved with the weights, so the
/// host path of [`super::fused`] reads it here).
pub const NORM_EPSILON: f64 = 1e-5;

/// The leaky ReLU, `max(x, slope x)` for `slope` < 1.
///
/// Under autodiff burn composes `leaky_relu` from a comparison, a scaled copy and a
/// `mask_where`, whose backward fills two zero tensors and runs two more `mask_where`s, all
/// scalar loops on burn-flex. Written as `slope x + (1 - slope) relu(x)` it is four vectorised
/// passes forward and backward (relu has its own backward op): the same values to a rounding
/// of the positive side, the same gradient except at exactly 0 (the slope here, 1 in burn's),
/// and a faster training step (docs/bench.md, "The leaky ReLU"). On the CPU backends
/// (since session 63) it is one operation with its own backward instead, one pass each way
/// with that composition's gradient ([`super::trainops::leaky`]); GPU builds keep the
/// composition. Without autodiff burn's own `leaky_relu` is one pass and stays.
pub fn leaky<const D: usize>(x: Tensor<D>, slope: f64) -> Tensor<D> {
    if x.is_autodiff() && host::cpu_build() {
        super::trainops::leaky(x, slope)
    } else if x.is_autodiff() {
        x.clone() * slope + relu(x) * (1.0 - slope)
    } else {
        leaky_relu(x, slope)
    }
}

/// Whether linear layers run as one operation with their own backward
/// ([`super::dense`]): under autodiff, in a build with only CPU backends and burn-flex.
#[cfg(feature = "flex")]
fn dense_path<const D: usize>(x: &Tensor<D>) -> bool {
    host::cpu_build() && x.is_autodiff()
}

/// `l(x)`, then the leaky ReLU of `slope` when there is one. In training on the CPU
/// backends one operation ([`super::dense`]: the product, the bias and the activation
/// written once, with its own backward); elsewhere burn's `Linear` and [`leaky`].
pub fn linear_act<const D: usize>(l: &Linear, x: Tensor<D>, slope: Option<f64>) -> Tensor<D> {
    #[cfg(feature = "flex")]
    if dense_path(&x) {
        let o = l.weight.dims()[1];
        let add = match &l.bias {
            Some(b) => b.val().reshape([1, 1, o]),
            None => Tensor::zeros([1, 1, o], &x.device()),
        };
        return super::dense::dense(x, l.weight.val(), add, slope, None);
    }
    maybe_leaky(l.forward(x), slope)
}

/// `y`, through the leaky ReLU of `slope` when there is one.
fn maybe_leaky<const D: usize>(y: Tensor<D>, slope: Option<f64>) -> Tensor<D> {
    match slope {
        Some(s) => leaky(y, s),
        None => y,
    }
}

/// `leaky(norm(layer(None)))`, or `layer(Some(slope))` without `norm`: a layer that can
/// take the activation into its own operation ([`linear_act`], [`SplitLinear::forward_act`])
/// takes it unless a normalisation sits between.
pub fn norm_act<const D: usize>(
    norm: Option<&LayerNorm>,
    slope: f64,
    layer: impl FnOnce(Option<f64>) -> Tensor<D>,
) -> Tensor<D> {
    match norm {
        None => layer(Some(slope)),
        Some(n) => leaky(n.forward(layer(None)), slope),
    }
}

/// A point-wise MLP: linear layers, each followed by a leaky ReLU (with `norm`, by a layer
/// normalisation and then the leaky ReLU).
#[derive(Module, Debug)]
pub struct Mlp {
    layers: Vec<Linear>,
    /// One per layer with `norm`, empty without (no parameters, so weights saved without
    /// normalisation load unchanged).
    norms: Vec<LayerNorm>,
    #[module(skip)]
    slope: f64,
}

impl Mlp {
    /// `input` features to `widths` (one layer per width), with a layer normalisation
    /// before each activation when `norm` is set.
    pub fn new(input: usize, widths: &[usize], slope: f64, norm: bool, device: &Device) -> Self {
        let mut layers = Vec::with_capacity(widths.len());
        let mut norms = Vec::new();
        let mut d = input;
        for &w in widths {
            layers.push(LinearConfig::new(d, w).with_initializer(he()).init(device));
            norms.extend(maybe_norm(norm, w, device));
            d = w;
        }
        Self {
            layers,
            norms,
            slope,
        }
    }

    /// The leaky ReLU's negative slope.
    pub(super) fn slope(&self) -> f64 {
        self.slope
    }

    /// The layers on the host ([`super::fused::pointwise_head`]).
    pub(super) fn host_layers(&self) -> Vec<HostDense> {
        self.layers
            .iter()
            .enumerate()
            .map(|(i, l)| host_dense(l, self.norms.get(i), true))
            .collect()
    }

    /// # Shapes
    /// `[.., input]` -> `[.., widths.last()]`.
    pub fn forward<const D: usize>(&self, mut x: Tensor<D>) -> Tensor<D> {
        for (i, l) in self.layers.iter().enumerate() {
            x = norm_act(self.norms.get(i), self.slope, |act| linear_act(l, x, act));
        }
        x
    }
}

/// A linear layer on the concatenation of several inputs, computed as a sum of one linear
/// map per input: `W [a, b, c] = W_a a + W_b b + W_c c`. Inputs may broadcast, so a
/// per-sample feature `[B, 1, C]` joins per-vertex features `[B, N, C']` without being
/// repeated N times (the repeat would cost N times the memory and the multiply-adds).
#[derive(Module, Debug)]
pub struct SplitLinear {
    parts: Vec<Linear>,
}

impl SplitLinear {
    /// One map per input width; the bias lives in the first.
    pub fn new(inputs: &[usize], output: usize, device: &Device) -> Self {
        let fan_in: usize = inputs.iter().sum();
        let bound = (6.0 / fan_in as f64).sqrt();
        let parts = inputs
            .iter()
            .enumerate()
            .map(|(i, &d)| {
                LinearConfig::new(d, output)
                    .with_bias(i == 0)
                    .with_initializer(Initializer::Uniform {
                        min: -bound,
                        max: bound,
                    })
                    .init(device)
            })
            .collect();
        Self { parts }
    }

    /// Each input's map `[C_k, output]` and bias (the first's) on the host.
    pub(super) fn host_maps(&self) -> Vec<(Vec<f32>, Option<Vec<f32>>)> {
        self.parts
            .iter()
            .map(|l| {
                (
                    host::floats(l.weight.val()),
                    l.bias.as_ref().map(|b| host::floats(b.val())),
                )
            })
            .collect()
    }

    /// [`SplitLinear::forward`], then the leaky ReLU of `slope` when there is one. In
    /// training on the CPU backends the per-sample inputs' maps and the bias make one
    /// addend `[B, 1, output]`, and each per-vertex input's map is one operation
    /// ([`super::dense`]) that adds it to the sum so far, the last with the activation.
    ///
    /// # Shapes
    /// As [`SplitLinear::forward`].
    pub fn forward_act(&self, inputs: Vec<Tensor<3>>, slope: Option<f64>) -> Tensor<3> {
        #[cfg(feature = "flex")]
        if inputs.iter().any(dense_path) && inputs.iter().all(|x| x.dims().iter().all(|&d| d > 0)) {
            let n = inputs.iter().map(|x| x.dims()[1]).max().unwrap_or(0);
            let o = self.parts[0].weight.dims()[1];
            let mut add: Option<Tensor<3>> = None;
            let mut per_vertex = Vec::new();
            for (l, x) in self.parts.iter().zip(inputs) {
                let term = if x.dims()[1] == n {
                    per_vertex.push((l, x));
                    l.bias.as_ref().map(|b| b.val().reshape([1, 1, o]))
                } else {
                    Some(l.forward(x))
                };
                add = match (add, term) {
                    (Some(a), Some(t)) => Some(a + t),
                    (a, t) => a.or(t),
                };
            }
            let last = per_vertex.len() - 1;
            let mut sum =
                add.unwrap_or_else(|| Tensor::zeros([1, 1, o], &per_vertex[0].1.device()));
            for (j, (l, x)) in per_vertex.into_iter().enumerate() {
                let act = if j == last { slope } else { None };
                sum = super::dense::dense(x, l.weight.val(), sum, act, None);
            }
            return sum;
        }
        maybe_leaky(self.forward(inputs), slope)
    }

    /// # Shapes
    /// Inputs `[B, N or 1, C_k]` -> `[B, N, output]`.
    pub fn forward(&self, inputs: Vec<Tensor<3>>) -> Tensor<3> {
        let mut sum: Option<Tensor<3>> = None;
        for (l, x) in self.parts.iter().zip(inputs) {
            let y = l.forward(x);
            sum = Some(match sum {
                None => y,
                Some(s) => s + y,
            });
        }
        sum.expect("at least one input")
    }
}

/// The mesh graph of a garment on a device: padded neighbourhoods (see
/// [`Topology::padded`]).
#[derive(Debug, Clone)]
pub struct Graph {
    /// 1 / |N_i|, `[1, N, 1]`.
    pub inv_degree: Tensor<3>,
    /// The same on the host, `[N]`.
    pub(super) host_inv_degree: Arc<Vec<f32>>,
    /// N.
    pub vertices: usize,
    /// Padded neighbourhood slots per vertex K.
    pub slots: usize,
    /// Padded neighbourhoods on the host, for [`feast::aggregate`] and [`Graph::rows`].
    pub(super) host_slots: Arc<Slots>,
    /// 1 for used slots, 0 for padding, `[1, N, K, 1]`.
    pub mask: Tensor<4>,
}

impl Graph {
    /// Puts a topology's neighbourhoods on `device`.
    pub fn new(t: &Topology, device: &Device) -> Self {
        Self {
            inv_degree: Tensor::from_data(
                TensorData::new(t.inv_degree(), [1, t.vertices, 1]),
                device,
            ),
            host_inv_degree: Arc::new(t.inv_degree()),
            vertices: t.vertices,
            slots: t.slots,
            host_slots: Arc::new(Slots {
                vertices: t.vertices,
                k: t.slots,
                index: t.padded.iter().map(|&j| j as u32).collect(),
                used: t.padded_mask.iter().map(|&w| w != 0.0).collect(),
            }),
            mask: Tensor::from_data(
                TensorData::new(t.padded_mask.clone(), [1, t.vertices, t.slots, 1]),
                device,
            ),
        }
    }

    /// How this build's convolutions aggregate a batch of `b` on `device`: fused in builds
    /// with only CPU backends (no index tensor), else burn's tensor operations with
    /// [`Graph::rows`]. Made once per forward pass and shared by all convolutions.
    pub fn aggregation(&self, b: usize, device: &Device) -> Aggregation {
        if host::cpu_build() {
            Aggregation::Fused
        } else {
            Aggregation::Tensors(self.rows(b, device))
        }
    }

    /// Neighbour rows of the flattened `[B * N, C]` features for batch size `b`,
    /// `[B * N * K]`: the index of [`Aggregation::Tensors`].
    pub fn rows(&self, b: usize, device: &Device) -> Tensor<1, Int> {
        let n = self.vertices as i64;
        let idx: Vec<i64> = (0..b as i64)
            .flat_map(|s| {
                self.host_slots
                    .index
                    .iter()
                    .map(move |&j| s * n + i64::from(j))
            })
            .collect();
        let len = idx.len();
        Tensor::from_data(TensorData::new(idx, [len]), device)
    }
}

/// How [`FeaStConv::forward`] computes its head-weighted neighbourhood sums.
// One value per forward pass, so the size of the `Tensors` variant costs nothing.
#[allow(clippy::large_enum_variant)]
#[derive(Debug, Clone)]
pub enum Aggregation {
    /// One operation with its own backward, loops over each vertex's neighbours in place
    /// ([`feast::aggregate`]); only for tensors on a CPU backend (burn-flex or
    /// burn-ndarray), else it panics.
    Fused,
    /// burn's tensor operations on any backend, gathering by [`Graph::rows`] for the batch.
    Tensors(Tensor<1, Int>),
}

/// FeaStNet graph convolution (Verma et al. 2018), the translation-invariant variant:
///
/// y_i = b + (1/|N_i|) sum_{j in N_i} sum_m q_m(x_i, x_j) W_m x_j,
/// q_m = softmax over the M heads of (u_m . (x_j - x_i) + c_m),
///
/// where N_i is the one-ring of vertex i plus i itself.
#[derive(Module, Debug)]
pub struct FeaStConv {
    /// W: the M per-head maps stacked, heads x input -> output, no bias.
    pub(super) lin: Linear,
    /// u: input -> heads, no bias.
    pub(super) u: Linear,
    /// c, `[heads]`.
    pub(super) c: Param<Tensor<1>>,
    /// b, `[output]`.
    pub(super) bias: Param<Tensor<1>>,
    #[module(skip)]
    heads: usize,
    #[module(skip)]
    output: usize,
}

impl FeaStConv {
    /// A convolution from `input` to `output` features with `heads` attention heads; with
    /// `zero` its output weights start at zero (a residual block that starts as the identity).
    pub fn new(input: usize, output: usize, heads: usize, zero: bool, device: &Device) -> Self {
        let lin = LinearConfig::new(heads * input, output)
            .with_bias(false)
            .with_initializer(if zero { Initializer::Zeros } else { he() })
            .init(device);
        let u = LinearConfig::new(input, heads)
            .with_bias(false)
            .init(device);
        let c = Initializer::Normal {
            mean: 0.0,
            std: 0.1,
        }
        .init([heads], device);
        let bias = Initializer::Zeros.init([output], device);
        Self {
            lin,
            u,
            c,
            bias,
            heads,
            output,
        }
    }

    /// This convolution's parameters (and `norm`'s, the layer normalisation after it) on
    /// the host, for [`super::fused::residual_stack`].
    pub(super) fn host_block(&self, norm: Option<&LayerNorm>) -> HostBlock {
        HostBlock {
            u: host::floats(self.u.weight.val()),
            c: host::floats(self.c.val()),
            w: host::floats(self.lin.weight.val()),
            bias: host::floats(self.bias.val()),
            norm: norm.map(host_norm),
        }
    }

    /// Attention heads M.
    pub fn heads(&self) -> usize {
        self.heads
    }

    /// # Shapes
    /// `x`: `[B, N, input]` -> `[B, N, output]`.
    ///
    /// The head-weighted neighbourhood sums as `how` says ([`Graph::aggregation`] picks
    /// the build's: fused where only CPU backends are compiled in, burn's tensor
    /// operations where a GPU backend is; tests and benchmarks pick either), then one
    /// linear map from `M * input` to `output`.
    pub fn forward(&self, x: Tensor<3>, g: &Graph, how: &Aggregation) -> Tensor<3> {
        self.forward_act(x, g, how, None)
    }

    /// [`FeaStConv::forward`], then the leaky ReLU of `slope` when there is one. In
    /// training on the CPU backends the output map, the `1 / |N_i|` scale, the bias and
    /// the activation are one operation ([`super::dense`]).
    pub fn forward_act(
        &self,
        x: Tensor<3>,
        g: &Graph,
        how: &Aggregation,
        slope: Option<f64>,
    ) -> Tensor<3> {
        let ux = linear_act(&self.u, x.clone(), None); // [B, N, M]
        let z = match how {
            Aggregation::Fused => feast::aggregate(x, ux, self.c.val(), &g.host_slots),
            Aggregation::Tensors(rows) => self.aggregate_tensors(x, ux, g, rows),
        }; // [B, N, M * C]
        let bias = self.bias.val().reshape([1, 1, self.output]);
        #[cfg(feature = "flex")]
        if dense_path(&z) {
            let w = self.lin.weight.val();
            return super::dense::dense(z, w, bias, slope, Some(&g.host_inv_degree));
        }
        let y = linear_act(&self.lin, z, None); // [B, N, O]
        maybe_leaky(y * g.inv_degree.clone() + bias, slope)
    }

    /// The head-weighted sums with burn's tensor operations, on padded neighbourhoods (K
    /// slots per vertex): one gather of the inputs, `[B, N, K, input]`, then per vertex a
    /// small batched matrix product, `[M, K] x [K, input]`. No scatter in the forward pass,
    /// and the gathered tensor is M times smaller than gathering `W_m x_j`.
    ///
    /// # Shapes
    /// `x`: `[B, N, C]`, `ux`: `[B, N, M]` -> `[B, N, M * C]`.
    fn aggregate_tensors(
        &self,
        x: Tensor<3>,
        ux: Tensor<3>,
        g: &Graph,
        rows: &Tensor<1, Int>,
    ) -> Tensor<3> {
        let [b, n, c] = x.dims();
        let (m, k) = (self.heads, g.slots);
        let uj = ux
            .clone()
            .reshape([b * n, m])
            .select(0, rows.clone())
            .reshape([b, n, k, m]);
        let logits = uj - ux.unsqueeze_dim::<4>(2) + self.c.val().reshape([1, 1, 1, m]); // [B, N, K, M]
        let q = softmax(logits, 3) * g.mask.clone(); // [B, N, K, M], padding zeroed
        let xj = x
            .reshape([b * n, c])
            .select(0, rows.clone())
            .reshape([b * n, k, c]); // [B*N, K, C]
        q.reshape([b * n, k, m])
            .swap_dims(1, 2)
            .matmul(xj) // [B*N, M, C]
            .reshape([b, n, m * c])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use burn::tensor::Distribution;

    /// The autodiff form of [`leaky`] gives burn's `leaky_relu` values, and its gradient is 1
    /// on the positive side and the slope on the negative side.
    #[test]
    fn leaky_under_autodiff_is_burns_leaky_relu_with_its_gradient() {
        let ad = Device::default().autodiff();
        ad.seed(6);
        let slope = 0.1;
        let x = Tensor::<2>::random([64, 37], Distribution::Normal(0.0, 1.0), &ad).require_grad();
        let y = leaky(x.clone(), slope);
        let want = leaky_relu(x.clone().inner(), slope);
        let (got_v, want_v, x_v) = (
            y.clone().inner().into_data().try_to_vec::<f32>().unwrap(),
            want.into_data().try_to_vec::<f32>().unwrap(),
            x.clone().inner().into_data().try_to_vec::<f32>().unwrap(),
        );
        let err = got_v
            .iter()
            .zip(&want_v)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0f32, f32::max);
        assert!(err < 1e-6, "largest difference {err}");
        // d/dx of sum(w * leaky(x)) is w times the local slope.
        let w = Tensor::<2>::random([64, 37], Distribution::Normal(0.0, 1.0), &ad);
        let w_v = w.clone().inner().into_data().try_to_vec::<f32>().unwrap();
        let grads = (y * w).sum().backward();
        let gx = x.grad(&grads).expect("x's gradient");
        let gx_v = gx.into_data().try_to_vec::<f32>().unwrap();
        let (mut pos, mut neg) = (0, 0);
        for ((g, xv), wv) in gx_v.iter().zip(&x_v).zip(&w_v) {
            let d = if *xv > 0.0 {
                pos += 1;
                1.0
            } else {
                neg += 1;
                slope as f32
            };
            assert!(
                (g - d * wv).abs() < 1e-6,
                "x {xv}: gradient {g}, want {}",
                d * wv
            );
        }
        assert!(pos > 100 && neg > 100, "both sides sampled: {pos}, {neg}");
    }

    /// A split layer in training (per-vertex and per-sample inputs, two per-vertex ones
    /// chained, several samples) gives `leaky(forward(inputs))`'s values and the gradients
    /// of its inputs and of every map's weight and the bias.
    #[cfg(all(feature = "flex", not(any(feature = "cuda", feature = "wgpu"))))]
    #[test]
    fn split_layer_as_one_operation_is_its_composition() {
        use crate::model::trainops::tests::rel;
        let ad = Device::default().autodiff();
        ad.seed(9);
        let (b, n, o) = (3, 400, 24);
        let dims = [[b, n, 20], [b, 1, 12], [b, n, 7], [b, 1, 5]];
        let data: Vec<TensorData> = dims
            .iter()
            .map(|&d| Tensor::<3>::random(d, Distribution::Normal(0.0, 1.0), &ad).into_data())
            .collect();
        let layer = SplitLinear::new(&[20, 12, 7, 5], o, &ad);
        let leaves = || -> Vec<Tensor<3>> {
            data.iter()
                .map(|d| Tensor::<3>::from_data(d.clone(), &ad).require_grad())
                .collect()
        };
        let (xa, xb) = (leaves(), leaves());
        let got = layer.forward_act(xa.clone(), Some(0.1));
        let want = leaky_relu(layer.forward(xb.clone()), 0.1);
        let to = |t: Tensor<3>| t.inner().into_data().try_to_vec::<f32>().unwrap();
        assert!(rel(&to(got.clone()), &to(want.clone())) < 1e-5, "values");
        let r = Tensor::<3>::random([b, n, o], Distribution::Normal(0.0, 1.0), &ad);
        let g1 = (got * r.clone()).sum().backward();
        let g2 = (want * r).sum().backward();
        let v = |t: Tensor<3>| t.into_data().try_to_vec::<f32>().unwrap();
        for (i, (a, c)) in xa.iter().zip(&xb).enumerate() {
            let (ga, gc) = (v(a.grad(&g1).unwrap()), v(c.grad(&g2).unwrap()));
            assert!(rel(&ga, &gc) < 1e-5, "input {i}'s gradient");
        }
        // The two passes share the layer's parameters: each gradient from each graph.
        let w = |g: &burn::tensor::Gradients, i: usize| -> Vec<f32> {
            let t = layer.parts[i]
                .weight
                .val()
                .grad(g)
                .expect("a weight's gradient");
            t.into_data().try_to_vec::<f32>().unwrap()
        };
        for i in 0..4 {
            assert!(rel(&w(&g1, i), &w(&g2, i)) < 1e-5, "map {i}'s gradient");
        }
        let bias = |g: &burn::tensor::Gradients| -> Vec<f32> {
            let t = layer.parts[0].bias.as_ref().unwrap().val().grad(g).unwrap();
            t.into_data().try_to_vec::<f32>().unwrap()
        };
        assert!(rel(&bias(&g1), &bias(&g2)) < 1e-5, "the bias's gradient");
    }
}
