//! Building blocks: point-wise MLPs and the FeaStNet convolution.

use burn::module::{Module, Param};
use burn::nn::{Initializer, Linear, LinearConfig};
use burn::tensor::activation::{leaky_relu, softmax};
use burn::tensor::{Device, IndexingUpdateOp, Int, Tensor, TensorData};

use crate::topology::Topology;

/// A point-wise MLP: linear layers, each followed by a leaky ReLU.
#[derive(Module, Debug)]
pub struct Mlp {
    layers: Vec<Linear>,
    #[module(skip)]
    slope: f64,
}

impl Mlp {
    /// `input` features to `widths` (one layer per width).
    pub fn new(input: usize, widths: &[usize], slope: f64, device: &Device) -> Self {
        let mut layers = Vec::with_capacity(widths.len());
        let mut d = input;
        for &w in widths {
            layers.push(LinearConfig::new(d, w).init(device));
            d = w;
        }
        Self { layers, slope }
    }

    /// # Shapes
    /// `[.., input]` -> `[.., widths.last()]`.
    pub fn forward<const D: usize>(&self, mut x: Tensor<D>) -> Tensor<D> {
        for l in &self.layers {
            x = leaky_relu(l.forward(x), self.slope);
        }
        x
    }
}

/// The mesh graph of a garment as index tensors on a device.
#[derive(Debug, Clone)]
pub struct Graph {
    /// Source vertex j of each edge (self-loops included), `[E]`.
    pub src: Tensor<1, Int>,
    /// Destination vertex i of each edge, `[E]`.
    pub dst: Tensor<1, Int>,
    /// 1 / |N_i|, `[1, N, 1]`.
    pub inv_degree: Tensor<3>,
    /// N.
    pub vertices: usize,
}

impl Graph {
    /// Puts a topology's FeaStNet edges on `device`.
    pub fn new(t: &Topology, device: &Device) -> Self {
        let e = t.conv_src.len();
        Self {
            src: Tensor::from_data(TensorData::new(t.conv_src.clone(), [e]), device),
            dst: Tensor::from_data(TensorData::new(t.conv_dst.clone(), [e]), device),
            inv_degree: Tensor::from_data(
                TensorData::new(t.inv_degree.clone(), [1, t.vertices, 1]),
                device,
            ),
            vertices: t.vertices,
        }
    }
}

/// FeaStNet graph convolution (Verma et al. 2018), the translation-invariant variant:
///
/// y_i = b + (1/|N_i|) sum_{j in N_i} sum_m q_m(x_i, x_j) W_m x_j,
/// q_m = softmax over the M heads of (u_m . (x_j - x_i) + c_m),
///
/// where N_i is the one-ring of vertex i plus i itself.
#[derive(Module, Debug)]
pub struct FeaStConv {
    /// W: input -> heads x output, no bias.
    lin: Linear,
    /// u: input -> heads, no bias.
    u: Linear,
    /// c, `[heads]`.
    c: Param<Tensor<1>>,
    /// b, `[output]`.
    bias: Param<Tensor<1>>,
    #[module(skip)]
    heads: usize,
    #[module(skip)]
    output: usize,
}

impl FeaStConv {
    /// A convolution from `input` to `output` features with `heads` attention heads.
    pub fn new(input: usize, output: usize, heads: usize, device: &Device) -> Self {
        let lin = LinearConfig::new(input, heads * output)
            .with_bias(false)
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

    /// # Shapes
    /// `x`: `[B, N, input]` -> `[B, N, output]`.
    pub fn forward(&self, x: Tensor<3>, g: &Graph) -> Tensor<3> {
        let [b, n, _] = x.dims();
        let e = g.src.dims()[0];
        let (m, o) = (self.heads, self.output);
        let ux = self.u.forward(x.clone()); // [B, N, M]
        let logits = ux.clone().select(1, g.src.clone()) - ux.select(1, g.dst.clone())
            + self.c.val().reshape([1, 1, m]); // [B, E, M]
        let q = softmax(logits, 2); // [B, E, M]
        let wx = self.lin.forward(x).select(1, g.src.clone()); // [B, E, M * O]
        let msg = (wx.reshape([b, e, m, o]) * q.unsqueeze_dim::<4>(3))
            .sum_dim(2)
            .reshape([b, e, o]); // [B, E, O]
        let agg = Tensor::<3>::zeros([b, n, o], &msg.device()).select_assign(
            1,
            g.dst.clone(),
            msg,
            IndexingUpdateOp::Add,
        ); // [B, N, O]
        agg * g.inv_degree.clone() + self.bias.val().reshape([1, 1, o])
    }
}
