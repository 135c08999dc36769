//! Model and training configurations (`configs/train/*.toml`).
//!
//! Every width the paper does not state is ours; `docs/learn.md` says which are paper facts.

use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::LearnError;

/// Which member of the GarNet family.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Variant {
    /// Point-wise garment features only, no mesh convolutions.
    Naive,
    /// FeaStNet garment stream; the body enters through its global feature.
    Global,
    /// Global plus local body features (15-NN max pooling per garment vertex).
    Local,
    /// Global with the shape and pose parameters in place of the global body feature.
    GlobalParams,
}

impl Variant {
    /// The whole family, in the paper's order.
    pub const ALL: [Variant; 4] = [
        Variant::Naive,
        Variant::Global,
        Variant::Local,
        Variant::GlobalParams,
    ];

    /// Name as in the paper.
    pub fn paper_name(self) -> &'static str {
        match self {
            Variant::Naive => "GarNet-Naive",
            Variant::Global => "GarNet-Global",
            Variant::Local => "GarNet-Local",
            Variant::GlobalParams => "GarNet-Global-Params",
        }
    }

    /// Does the variant use the FeaStNet mesh convolutions?
    pub fn has_mesh_convolutions(self) -> bool {
        !matches!(self, Variant::Naive)
    }
}

/// A set of network widths, to train a config's losses and schedule at other widths
/// (`drape train --widths`, a plan's `widths`): the variant, the neighbourhood sizes, the
/// leaky slope, the length scale, the prior and the optional additions (`fourier_bands`,
/// `zero_init_residuals`, `layer_norm`) stay the config's.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Widths {
    /// [`ModelConfig::default`]: the CPU config.
    Cpu,
    /// [`ModelConfig::paper`]: 6,890 body points, 512-d global body feature, 8 heads.
    Paper,
}

impl Widths {
    /// The name `--widths` takes.
    pub fn name(self) -> &'static str {
        match self {
            Widths::Cpu => "cpu",
            Widths::Paper => "paper",
        }
    }
}

impl std::str::FromStr for Widths {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        [Widths::Cpu, Widths::Paper]
            .into_iter()
            .find(|w| w.name() == s)
            .ok_or_else(|| format!("widths {s:?}: cpu or paper"))
    }
}

/// Network widths and neighbourhood sizes. Defaults: the CPU config.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ModelConfig {
    /// Network variant (default `local`).
    pub variant: Variant,
    /// Body points fed to the body stream, a fixed farthest-point subset of the body's
    /// vertices (paper: 6,890, SMPL's count; CPU default 2,000).
    pub body_points: usize,
    /// Widths of the body stream's first point-wise MLP block (default [64, 64]).
    pub body_mlp1: Vec<usize>,
    /// Widths of the body stream's second block; the last is the global body feature
    /// (paper: 512; default [128, 256]).
    pub body_mlp2: Vec<usize>,
    /// Widths of the spatial transformer's point-wise MLP and of its head (default
    /// [64, 128, 256] and [128, 64]).
    pub stn_mlp: Vec<usize>,
    /// Spatial transformer head widths.
    pub stn_head: Vec<usize>,
    /// Garment point-wise MLP widths (default [32, 64]).
    pub garment_mlp: Vec<usize>,
    /// Width of the FeaStNet blocks (default 48).
    pub conv_width: usize,
    /// FeaStNet attention heads M (default 4; FeaStNet's paper used 8 to 32).
    pub conv_heads: usize,
    /// Residual FeaStNet blocks (paper: 6).
    pub conv_blocks: usize,
    /// Fusion MLP widths before the 3 outputs (paper: 4 blocks; default [128, 64, 32]).
    pub fusion: Vec<usize>,
    /// Body downsampling factor for local features (paper: 10).
    pub local_downsample: usize,
    /// Neighbours averaged per downsampled body point (paper: 16).
    pub local_pool_k: usize,
    /// Downsampled body points max-pooled per garment vertex (paper: 15).
    pub local_k: usize,
    /// Leaky ReLU slope (paper: 0.1).
    pub leaky_slope: f64,
    /// Coordinates enter the network divided by this length, m (default 0.1: a body spans
    /// about +-10 units). The paper feeds metres; in metres this network fits about a third
    /// more slowly (docs/learn.md).
    pub length_scale: f64,
    /// Frequency bands of a positional encoding of the garment coordinates (default 0: the
    /// paper's plain xyz). With `n` bands the garment point-wise MLP also takes sin and cos
    /// of `2^k` times the coordinates (in `length_scale` units) for k = 0 to n - 1: an MLP
    /// of plain coordinates learns detail of a few centimetres slowly (docs/learn.md).
    /// Left out of the saved config when 0.
    #[serde(skip_serializing_if = "is_zero")]
    pub fourier_bands: usize,
    /// Start every residual FeaStNet block at zero (its output layer's weights zero, as
    /// Fixup and SkipInit do), so the stack starts as the identity and the blocks grow in
    /// as they learn (default false: He initialisation). Left out of the saved config when
    /// false.
    #[serde(skip_serializing_if = "is_false")]
    pub zero_init_residuals: bool,
    /// A layer normalisation (over the features of each point, learnt scale and shift)
    /// after every hidden linear layer, before its leaky ReLU: in the body stream and its
    /// spatial transformer, the garment MLP, the FeaStNet blocks and the fusion; not in the
    /// 32-channel reduction of the local body features (`local_in`) nor on the output
    /// layers (default false: the paper states none). It does not depend on the batch, so
    /// a drape predicts the same alone or in a batch. Not with `zero_init_residuals`: a
    /// normalised block's output is not zero. Left out of the saved config when false.
    #[serde(skip_serializing_if = "is_false")]
    pub layer_norm: bool,
    /// The garment the network starts from (default `none`: the DQS warp M, as the paper).
    /// `linear`: M plus the linear (ridge) map from shape and bone rotations to the
    /// displacement, fitted on the training split when the run starts (cross-fitted for the
    /// training samples, `learn::prior::Prior`) and kept in the run's `prior.safetensors`;
    /// the network predicts what is left (docs/learn.md, session 28). `kernel`: the same
    /// with the linear map plus an RBF kernel ridge regression of its residual
    /// (`learn::kernel`, session 30). Left out of the saved config when `none`.
    #[serde(skip_serializing_if = "PriorKind::is_none")]
    pub prior: PriorKind,
    /// Give every garment vertex its own geometry relative to the body (default false: the
    /// paper's inputs): the offset from the vertex to the closest posed body vertex (in
    /// `length_scale` units), that body vertex's unit normal, and the vertex's signed
    /// distance along it, 7 numbers appended to the garment point-wise MLP's input, so
    /// the FeaStNet stack and the fusion see them too. Any variant with a body stream.
    /// Asks whether GarNet-Local's local body features, which the trained network hardly
    /// uses (`drape importance`, docs/learn.md session 43), lack relative geometry. Left out
    /// of the saved config when false.
    #[serde(skip_serializing_if = "is_false")]
    pub body_offsets: bool,
}

/// What the network's input garment is ([`ModelConfig::prior`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum PriorKind {
    /// The DQS warp M (the paper).
    #[default]
    None,
    /// M plus the linear prior's displacement.
    Linear,
    /// M plus the kernel prior's displacement (the linear map and a kernel ridge
    /// regression of what it leaves).
    Kernel,
}

impl PriorKind {
    /// As written in configs.
    pub fn name(self) -> &'static str {
        match self {
            PriorKind::None => "none",
            PriorKind::Linear => "linear",
            PriorKind::Kernel => "kernel",
        }
    }

    /// The paper's input.
    pub fn is_none(&self) -> bool {
        *self == PriorKind::None
    }
}

fn is_zero(n: &usize) -> bool {
    *n == 0
}

fn is_false(b: &bool) -> bool {
    !*b
}

impl Default for ModelConfig {
    fn default() -> Self {
        Self {
            variant: Variant::Local,
            body_points: 2000,
            body_mlp1: vec![64, 64],
            body_mlp2: vec![128, 256],
            stn_mlp: vec![64, 128, 256],
            stn_head: vec![128, 64],
            garment_mlp: vec![32, 64],
            conv_width: 48,
            conv_heads: 4,
            conv_blocks: 6,
            fusion: vec![128, 64, 32],
            local_downsample: 10,
            local_pool_k: 16,
            local_k: 15,
            leaky_slope: 0.1,
            length_scale: 0.1,
            fourier_bands: 0,
            zero_init_residuals: false,
            layer_norm: false,
            prior: PriorKind::None,
            body_offsets: false,
        }
    }
}

impl ModelConfig {
    /// The variant's paper name, with its prior if it has one ("GarNet-Local over the
    /// kernel prior").
    pub fn display_name(&self) -> String {
        let name = match self.prior {
            PriorKind::None => self.variant.paper_name().to_string(),
            p => format!("{} over the {} prior", self.variant.paper_name(), p.name()),
        };
        let with: Vec<&str> = [
            (self.layer_norm, "layer normalisation"),
            (self.body_offsets, "body offsets"),
        ]
        .into_iter()
        .filter_map(|(on, what)| on.then_some(what))
        .collect();
        if with.is_empty() {
            name
        } else {
            format!("{name} with {}", with.join(" and "))
        }
    }

    /// The paper-width config: 6,890 body points, 512-d global body feature, 8 heads.
    pub fn paper(variant: Variant) -> Self {
        Self {
            variant,
            body_points: 6890,
            body_mlp2: vec![128, 512],
            stn_mlp: vec![64, 128, 1024],
            stn_head: vec![512, 256],
            garment_mlp: vec![64, 128],
            conv_width: 128,
            conv_heads: 8,
            fusion: vec![256, 128, 64],
            ..Self::default()
        }
    }

    /// This config at the widths of `w`: the layer widths, body points, FeaStNet width and
    /// heads and residual blocks of the preset, everything else (variant, neighbourhoods,
    /// leaky slope, length scale, prior, the optional additions) this config's.
    pub fn with_widths(&self, w: Widths) -> Self {
        let preset = match w {
            Widths::Cpu => Self::default(),
            Widths::Paper => Self::paper(self.variant),
        };
        Self {
            variant: self.variant,
            local_downsample: self.local_downsample,
            local_pool_k: self.local_pool_k,
            local_k: self.local_k,
            leaky_slope: self.leaky_slope,
            length_scale: self.length_scale,
            fourier_bands: self.fourier_bands,
            zero_init_residuals: self.zero_init_residuals,
            layer_norm: self.layer_norm,
            prior: self.prior,
            body_offsets: self.body_offsets,
            ..preset
        }
    }

    /// Refuses widths and sizes that cannot make a network.
    pub fn validate(&self) -> Result<(), LearnError> {
        let bad = |m: String| Err(LearnError::Config(m));
        if self.body_points < 32 {
            return bad(format!(
                "model.body_points = {} (at least 32)",
                self.body_points
            ));
        }
        for (name, v) in [
            ("body_mlp1", &self.body_mlp1),
            ("body_mlp2", &self.body_mlp2),
            ("stn_mlp", &self.stn_mlp),
            ("stn_head", &self.stn_head),
            ("garment_mlp", &self.garment_mlp),
            ("fusion", &self.fusion),
        ] {
            if v.is_empty() || v.iter().any(|&w| w == 0 || w > 8192) {
                return bad(format!(
                    "model.{name} = {v:?}: 1 to 8192 per layer, not empty"
                ));
            }
        }
        if self.conv_width == 0 || self.conv_heads == 0 || self.conv_heads > 64 {
            return bad("model.conv_width > 0 and model.conv_heads in 1..=64".into());
        }
        if self.variant.has_mesh_convolutions() && self.conv_blocks == 0 {
            return bad("model.conv_blocks must be at least 1 for this variant".into());
        }
        if self.local_downsample < 1 || self.local_pool_k < 1 || self.local_k < 1 {
            return bad("model.local_downsample, local_pool_k and local_k must be >= 1".into());
        }
        if self.body_points / self.local_downsample < self.local_k {
            return bad(format!(
                "model.body_points / local_downsample = {} < local_k = {}",
                self.body_points / self.local_downsample,
                self.local_k
            ));
        }
        if !(self.length_scale > 0.0 && self.length_scale.is_finite()) {
            return bad(format!(
                "model.length_scale = {} (a positive length, m)",
                self.length_scale
            ));
        }
        if self.fourier_bands > 16 {
            return bad(format!(
                "model.fourier_bands = {} (0 to 16)",
                self.fourier_bands
            ));
        }
        if self.layer_norm && self.zero_init_residuals {
            return bad(
                "model.layer_norm and model.zero_init_residuals together: the normalisation \
                 would scale a block that starts at zero back to unit size (use one)"
                    .into(),
            );
        }
        if self.body_offsets && self.variant == Variant::GlobalParams {
            return bad(
                "model.body_offsets needs the posed body; GarNet-Global-Params reads only the \
                 shape and pose parameters"
                    .into(),
            );
        }
        if !(0.0..1.0).contains(&self.leaky_slope) {
            return bad(format!("model.leaky_slope = {} (0 to 1)", self.leaky_slope));
        }
        Ok(())
    }

    /// Downsampled body points for local features.
    pub fn local_points(&self) -> usize {
        self.body_points / self.local_downsample
    }
}

/// Loss weights (paper Eq. 7 and the fine-tuning totals of section 4).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct LossWeights {
    /// Weight of L_vert (paper 1.0; 0.1 when fine-tuning with curvature).
    pub vert: f64,
    /// Weight of L_pen relative to L_vert (paper 1.0).
    pub pen: f64,
    /// Weight of L_norm (paper 0.3).
    pub norm: f64,
    /// Weight of L_bend (paper 0.5).
    pub bend: f64,
    /// Scale applied to the whole L_p (paper 1.0; 0.1 in the fine-tunes).
    pub physics_scale: f64,
    /// Weights of L_RQ^8, L_RQ^16, L_RQ^32 (paper 500, 50, 10 in the -RQ fine-tune; 0 off).
    pub rq: [f64; 3],
    /// Weight of L_MC (paper 10 in the -MC fine-tune; 0 off).
    pub mc: f64,
    /// Weight of L_UMC (0 off).
    pub umc: f64,
    /// Rescale the curvature terms at the start of the run (default true): the paper's
    /// weights were tuned for 10k-vertex SMPL garments in its units. The weighted curvature
    /// terms then sum to `physics_scale * L_p` on the first batches, each its configured
    /// weight's share (`train::CurvatureScales`); the factors go to `run.json`.
    pub rescale_curvature: bool,
    /// Distance tolerance d_tol of L_pen, m (paper 0.05).
    pub pen_tolerance: f64,
    /// Push-out of body points along their normals, as a share of the body mesh's mean
    /// edge length (paper 0.2).
    pub pen_push_out: f64,
}

impl Default for LossWeights {
    fn default() -> Self {
        Self {
            vert: 1.0,
            pen: 1.0,
            norm: 0.3,
            bend: 0.5,
            physics_scale: 1.0,
            rq: [0.0; 3],
            mc: 0.0,
            umc: 0.0,
            rescale_curvature: true,
            pen_tolerance: 0.05,
            pen_push_out: 0.2,
        }
    }
}

impl LossWeights {
    /// Any curvature term on?
    pub fn has_curvature(&self) -> bool {
        self.rq.iter().any(|&w| w > 0.0) || self.mc > 0.0 || self.umc > 0.0
    }
}

/// A training run's configuration (`configs/train/*.toml`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    /// Run name.
    pub name: String,
    /// Dataset folder (relative to the working directory; `--data` overrides it).
    pub data: PathBuf,
    /// Seed of initialisation and shuffling (default 1).
    #[serde(default = "default_seed")]
    pub seed: u64,
    /// Epochs (passes over the training split).
    pub epochs: usize,
    /// Samples per batch (paper: 16 at timing).
    #[serde(default = "default_batch")]
    pub batch_size: usize,
    /// Adam learning rate (paper 1e-3).
    #[serde(default = "default_lr")]
    pub learning_rate: f64,
    /// If set, the learning rate decays from `learning_rate` to this value over the run
    /// along a half cosine (default: constant, as in the paper).
    #[serde(default)]
    pub learning_rate_end: Option<f64>,
    /// Adam's epsilon, added to the root of the second moment (default 1e-5, burn's; the
    /// paper used PyTorch's Adam, whose default is 1e-8). With losses in square metres
    /// many gradients are below 1e-5, where it shrinks the steps: see docs/learn.md. Left
    /// out of the saved config when it is the default.
    #[serde(
        default = "default_epsilon",
        skip_serializing_if = "is_default_epsilon"
    )]
    pub adam_epsilon: f64,
    /// Train on only this many samples, the same every epoch: the lowest ids of the
    /// training split (0: all); for overfitting tests.
    #[serde(default)]
    pub max_train_samples: usize,
    /// Stop after this many minutes of training, with checkpoints saved (0: no cap).
    #[serde(default)]
    pub wall_clock_minutes: f64,
    /// Shards shuffled together in memory when reading the training split (default 2).
    #[serde(default = "default_buffer")]
    pub shuffle_shards: usize,
    /// The network.
    #[serde(default)]
    pub model: ModelConfig,
    /// The losses.
    #[serde(default)]
    pub loss: LossWeights,
}

fn default_seed() -> u64 {
    1
}
fn default_batch() -> usize {
    8
}
fn default_lr() -> f64 {
    1e-3
}
fn default_buffer() -> usize {
    2
}
fn default_epsilon() -> f64 {
    1e-5
}
fn is_default_epsilon(e: &f64) -> bool {
    *e == default_epsilon()
}

impl TrainConfig {
    /// Reads and validates a TOML config.
    pub fn load(path: &Path) -> Result<Self, LearnError> {
        let text = std::fs::read_to_string(path).map_err(|e| LearnError::Io {
            path: path.to_path_buf(),
            source: e,
        })?;
        let c: Self = toml::from_str(&text)
            .map_err(|e| LearnError::Config(format!("{}: {e}", path.display())))?;
        c.validate()?;
        Ok(c)
    }

    /// The learning rate after `step` of `total` optimiser steps.
    pub fn rate_at(&self, step: u64, total: u64) -> f64 {
        match self.learning_rate_end {
            None => self.learning_rate,
            Some(end) => {
                let t = (step as f64 / total.max(1) as f64).min(1.0);
                end + (self.learning_rate - end) * 0.5 * (1.0 + (std::f64::consts::PI * t).cos())
            }
        }
    }

    /// Refuses values out of range.
    pub fn validate(&self) -> Result<(), LearnError> {
        let bad = |m: String| Err(LearnError::Config(m));
        if self.epochs == 0 || self.epochs > 100_000 {
            return bad(format!("epochs = {} (1 to 100000)", self.epochs));
        }
        if self.batch_size == 0 || self.batch_size > 1024 {
            return bad(format!("batch_size = {} (1 to 1024)", self.batch_size));
        }
        if !(self.learning_rate > 0.0 && self.learning_rate < 1.0) {
            return bad(format!("learning_rate = {} (0 to 1)", self.learning_rate));
        }
        if !(self.adam_epsilon > 0.0 && self.adam_epsilon <= 1e-2) {
            return bad(format!(
                "adam_epsilon = {} (above 0, at most 0.01)",
                self.adam_epsilon
            ));
        }
        if let Some(end) = self.learning_rate_end
            && !(end > 0.0 && end <= self.learning_rate)
        {
            return bad(format!(
                "learning_rate_end = {end} (above 0, at most learning_rate)"
            ));
        }
        if self.shuffle_shards == 0 {
            return bad("shuffle_shards must be at least 1".into());
        }
        if self.wall_clock_minutes < 0.0 || !self.wall_clock_minutes.is_finite() {
            return bad(format!("wall_clock_minutes = {}", self.wall_clock_minutes));
        }
        let l = &self.loss;
        for (n, w) in [
            ("vert", l.vert),
            ("pen", l.pen),
            ("norm", l.norm),
            ("bend", l.bend),
            ("physics_scale", l.physics_scale),
            ("mc", l.mc),
            ("umc", l.umc),
            ("rq[0]", l.rq[0]),
            ("rq[1]", l.rq[1]),
            ("rq[2]", l.rq[2]),
        ] {
            if !(w >= 0.0 && w.is_finite()) {
                return bad(format!("loss.{n} = {w} (a finite weight >= 0)"));
            }
        }
        if !(l.pen_tolerance > 0.0 && l.pen_tolerance < 1.0) {
            return bad(format!(
                "loss.pen_tolerance = {} m (0 to 1)",
                l.pen_tolerance
            ));
        }
        self.model.validate()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(extra: &str) -> Result<TrainConfig, LearnError> {
        let c: TrainConfig =
            toml::from_str(&format!("name = \"t\"\ndata = \"d\"\nepochs = 1\n{extra}"))
                .map_err(|e| LearnError::Config(e.to_string()))?;
        c.validate()?;
        Ok(c)
    }

    #[test]
    fn a_widths_preset_replaces_the_widths_and_keeps_the_rest() {
        let c = parse("[model]\nvariant = \"global\"\nlocal_k = 9\nlength_scale = 0.2\n")
            .unwrap()
            .model;
        let p = c.with_widths(Widths::Paper);
        assert_eq!(p.variant, Variant::Global);
        assert_eq!((p.local_k, p.length_scale), (9, 0.2));
        assert_eq!((p.body_points, p.conv_width, p.conv_heads), (6890, 128, 8));
        assert_eq!(p.body_mlp2.last(), Some(&512));
        assert_eq!(p.fusion, [256, 128, 64]);
        p.validate().unwrap();
        // Back to the CPU widths: the config as it was.
        assert_eq!(p.with_widths(Widths::Cpu), c);
        assert_eq!("paper".parse::<Widths>(), Ok(Widths::Paper));
        assert!(
            "wide"
                .parse::<Widths>()
                .unwrap_err()
                .contains("cpu or paper")
        );
    }

    #[test]
    fn body_offsets_are_off_by_default_kept_by_widths_named_and_need_a_body() {
        let c = parse("").unwrap();
        assert!(!c.model.body_offsets);
        assert!(!toml::to_string(&c).unwrap().contains("body_offsets"));
        let c = parse("[model]\nlayer_norm = true\nbody_offsets = true").unwrap();
        c.model.validate().unwrap();
        let saved = toml::to_string(&c).unwrap();
        assert!(saved.contains("body_offsets = true"), "{saved}");
        assert_eq!(toml::from_str::<TrainConfig>(&saved).unwrap(), c);
        assert!(c.model.with_widths(Widths::Paper).body_offsets);
        assert_eq!(
            c.model.display_name(),
            "GarNet-Local with layer normalisation and body offsets"
        );
        let params = ModelConfig {
            variant: Variant::GlobalParams,
            ..c.model.clone()
        };
        let e = params.validate().unwrap_err().to_string();
        assert!(e.contains("body_offsets"), "{e}");
    }

    #[test]
    fn layer_norm_is_off_by_default_kept_by_widths_and_named() {
        let c = parse("").unwrap();
        assert!(!c.model.layer_norm);
        let saved = toml::to_string(&c).unwrap();
        assert!(!saved.contains("layer_norm"), "{saved}");
        assert_eq!(c.model.display_name(), "GarNet-Local");
        let c = parse("[model]\nlayer_norm = true\nprior = \"kernel\"").unwrap();
        c.model.validate().unwrap();
        let saved = toml::to_string(&c).unwrap();
        assert!(saved.contains("layer_norm = true"), "{saved}");
        assert_eq!(toml::from_str::<TrainConfig>(&saved).unwrap(), c);
        assert!(c.model.with_widths(Widths::Paper).layer_norm);
        assert_eq!(
            c.model.display_name(),
            "GarNet-Local over the kernel prior with layer normalisation"
        );
        let both = ModelConfig {
            zero_init_residuals: true,
            ..c.model.clone()
        };
        let e = both.validate().unwrap_err().to_string();
        assert!(
            e.contains("layer_norm") && e.contains("zero_init_residuals"),
            "{e}"
        );
    }

    #[test]
    fn prior_defaults_to_none_and_is_left_out_of_saved_configs() {
        let c = parse("").unwrap();
        assert_eq!(c.model.prior, PriorKind::None);
        let saved = toml::to_string(&c).unwrap();
        assert!(!saved.contains("prior"), "{saved}");
        let c = parse("[model]\nprior = \"linear\"").unwrap();
        assert_eq!(c.model.prior, PriorKind::Linear);
        let saved = toml::to_string(&c).unwrap();
        assert!(saved.contains("prior = \"linear\""), "{saved}");
        assert_eq!(toml::from_str::<TrainConfig>(&saved).unwrap(), c);
        assert_eq!(c.model.with_widths(Widths::Paper).prior, PriorKind::Linear);
        let e = parse("[model]\nprior = \"quadratic\"")
            .unwrap_err()
            .to_string();
        assert!(e.contains("quadratic") && e.contains("linear"), "{e}");
    }

    /// Every committed training config parses and validates.
    #[test]
    fn committed_configs_load() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../configs/train");
        let mut n = 0;
        for entry in std::fs::read_dir(&dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                TrainConfig::load(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
                n += 1;
            }
        }
        assert!(n >= 20, "{n} configs in {}", dir.display());
    }

    #[test]
    fn adam_epsilon_defaults_to_burns_and_is_left_out_of_saved_configs() {
        let c = parse("").unwrap();
        assert_eq!(c.adam_epsilon, 1e-5);
        let saved = toml::to_string(&c).unwrap();
        assert!(!saved.contains("adam_epsilon"), "{saved}");
        let c = parse("adam_epsilon = 1e-8").unwrap();
        assert_eq!(c.adam_epsilon, 1e-8);
        let saved = toml::to_string(&c).unwrap();
        assert!(saved.contains("adam_epsilon = "), "{saved}");
        assert_eq!(toml::from_str::<TrainConfig>(&saved).unwrap(), c);
        for bad in [
            "adam_epsilon = 0.0",
            "adam_epsilon = -1e-8",
            "adam_epsilon = 0.5",
        ] {
            let e = parse(bad).unwrap_err().to_string();
            assert!(e.contains("adam_epsilon"), "{bad}: {e}");
        }
    }
}
