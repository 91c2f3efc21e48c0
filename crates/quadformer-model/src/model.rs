//! The QUADFormer network (paper sec:attack_detector): UAV Attack Attention with Temporal
//! Proximity Concentration (eq:TPC) and Dynamic Context Mapping (eq:first_layer_attention,
//! eq:cross_layer_attention), the reconstruction and classification heads, the
//! Temporal-Contextual Disparity (TCD, Jensen–Shannon) and the min-max losses.
//!
//! Shapes: input `x` is `b × l × m` (normalised residues, [`nn_toolkit::window`]); hidden states are
//! kept flat as `(b·l) × d_model`; attention maps `T` and `C` are `b × heads × l × l`; TCD,
//! logits and per-step scores are `b × l`.
//!
//! Layer `h` (post-norm, as the paper's `Z^{h+1} = Norm(Attn(R^h) + R^h)`,
//! `R^{h+1} = Norm(FF(Z^{h+1}) + Z^{h+1})`):
//! `Q = R W_Q`, `K = R W_K`, `V = R W_V`; `C¹ = softmax(Q¹K¹ᵀ/√d)`, `Cʰ = softmax(QʰKʰ⁻¹ᵀ/√d)`
//! for `h > 1` (DCM; switchable off = own keys); `T_{ij} = exp(−γ_i |j−i|^p) / Σ_k …` with a
//! learnable width `γ` per layer, head and position (TPC; switchable off = the Anomaly
//! Transformer's Gaussian prior with an input-dependent width). The layer norm, softmax and GELU
//! are the kernels of [`nn_toolkit::fused`], which have backward passes (candle 0.11's fused
//! `LayerNorm` and `softmax_last_dim` have none; for the layer norm see huggingface/candle issues
//! #3011 and #3752). The exponent of the prior is clamped at [`PRIOR_EXP_FLOOR`] so that
//! far-apart steps never produce subnormal results (slow on this CPU) while their weight stays
//! negligible.
//!
//! Min-max with stop-gradient (Anomaly Transformer `solver.py`): the min phase uses
//! `TCD(T, sg(C))`, so its discrepancy term only moves the prior (`γ`); the max phase uses
//! `TCD(sg(T), C)`, so its discrepancy term only moves the attention (`W_Q`, `W_K`, embeddings).

use candle_core::{D, DType, Device, Tensor};
use candle_nn::{VarBuilder, VarMap};
use serde::{Deserialize, Serialize};

use crate::error::{ModelError, Result};
pub use crate::js::GradFlow;
use crate::js::js_divergence_with;
pub use crate::weights::log_gamma_name;
use crate::weights::{PriorWeights, QuadFormerWeights};
use nn_toolkit::fused::{gelu, softmax_last_dim};
use nn_toolkit::layers::Dense;
use nn_toolkit::loss::masked_bce_with_logits;
use nn_toolkit::window::Batch;

/// Lower clamp of the prior's exponent: `exp(−50) ≈ 2e−22` is still a normal `f32`.
pub const PRIOR_EXP_FLOOR: f64 = -50.0;

/// Which prior association the attention is compared with.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum Prior {
    /// Temporal Proximity Concentration, eq:TPC (the paper).
    Tpc,
    /// Anomaly Transformer's Gaussian kernel with width from `Linear(d_model, heads)` of the
    /// layer input (ablation "TPC off").
    Gaussian,
}

/// What the classification head reads at every step.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum ClassInput {
    /// The reconstruction `R̂` (`m` values per step), as the paper writes it (sec:attack_detector:
    /// `Ŷ` is obtained by passing `R̂` through the classification head).
    #[default]
    Reconstruction,
    /// The last layer's hidden state (`d_model` values per step), the representation `R̂` is
    /// read from (docs/decisions/043-classification-head-input.md).
    Hidden,
}

/// Architecture of the network.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NetConfig {
    /// Hidden size `d_model`. Default 64 (docs/decisions/040-quadformer-architecture.md; the
    /// paper gives no value).
    pub d_model: usize,
    /// Attention heads. Default 1: the paper's equations are single-head with `√d_model`
    /// scaling (eq:first_layer_attention).
    pub n_heads: usize,
    /// Number of layers `H`. Default 3 (Anomaly Transformer `e_layers`).
    pub n_layers: usize,
    /// Feed-forward width. Default 128 (2 × `d_model`; decision 040).
    pub d_ff: usize,
    /// Hidden width of the classification head. Default 32 (decision 040).
    pub d_class: usize,
    /// TPC distance exponent `p` (eq:TPC). Default 2, a Gaussian-shaped kernel like the Anomaly
    /// Transformer's prior (decision 040).
    pub p: f64,
    /// Initial TPC width `γ`. Default 0.1: with `p = 2` a Gaussian of about 2.2 steps standard
    /// deviation, the order of the Anomaly Transformer's initial width (decision 040).
    pub gamma_init: f64,
    /// The prior association; [`Prior::Gaussian`] is the "TPC off" ablation. Default TPC.
    pub prior: Prior,
    /// Dynamic Context Mapping (cross-layer keys, eq:cross_layer_attention); `false` = every
    /// layer uses its own keys (ablation "DCM off"). Default true.
    pub dcm: bool,
    /// Input of the classification head. Default [`ClassInput::Hidden`]: chosen on validation
    /// (docs/decisions/043-classification-head-input.md); a checkpoint without the field reads
    /// as [`ClassInput::Reconstruction`], the only head of earlier versions.
    #[serde(default)]
    pub class_input: ClassInput,
    /// Causal attention: every step attends to itself and earlier steps only, and its prior
    /// is the TPC (or Gaussian) kernel restricted to them and renormalised, so every step's
    /// outputs are a function of its past, as the newest step's are when streaming. Each
    /// position of a training window is then a streaming decision. Default `false`, the
    /// paper's attention over the whole window (docs/decisions/092-causal-loop-quadformer.md);
    /// a checkpoint without the field reads as `false`.
    #[serde(default)]
    pub causal: bool,
}

impl Default for NetConfig {
    fn default() -> Self {
        Self {
            d_model: 64,
            n_heads: 1,
            n_layers: 3,
            d_ff: 128,
            d_class: 32,
            p: 2.0,
            gamma_init: 0.1,
            prior: Prior::Tpc,
            dcm: true,
            class_input: ClassInput::Hidden,
            causal: false,
        }
    }
}

/// Budget of `d_model`, `d_ff` and `d_class` (each): ten times the paper-scale sizes, so a
/// configuration or checkpoint cannot make the network allocate without bound.
pub const MAX_WIDTH: usize = 8_192;
/// Budget of `n_heads` and `n_layers` (each).
pub const MAX_DEPTH: usize = 64;
/// Budget of the network's weights, counted as [`NetConfig::approx_params`]: 50 M (200 MB of
/// `f32`; the paper-scale network has about 0.1 M).
pub const MAX_PARAMS: u64 = 50_000_000;

impl NetConfig {
    /// The weights of the layers' attention projections and feed-forward blocks,
    /// `n_layers·(4·d_model² + 2·d_model·d_ff)`, the bulk of the network (the budget's measure).
    #[must_use]
    pub fn approx_params(&self) -> u64 {
        let (d, ff, l) = (self.d_model as u64, self.d_ff as u64, self.n_layers as u64);
        l.saturating_mul(
            4u64.saturating_mul(d).saturating_mul(d).saturating_add(2u64.saturating_mul(d).saturating_mul(ff)),
        )
    }

    /// Checks sizes and ranges, and the budgets [`MAX_WIDTH`] and [`MAX_DEPTH`].
    ///
    /// # Errors
    /// [`ModelError::Config`] naming the field.
    pub fn check(&self) -> Result<()> {
        let bad = |field: &'static str, msg: String| Err(ModelError::Config { field, msg });
        if self.d_model == 0 || self.n_heads == 0 || !self.d_model.is_multiple_of(self.n_heads) {
            return bad(
                "net.d_model",
                format!("{} must be a positive multiple of n_heads {}", self.d_model, self.n_heads),
            );
        }
        if self.n_layers == 0 || self.d_ff == 0 || self.d_class == 0 {
            return bad("net.n_layers", "n_layers, d_ff and d_class must be positive".into());
        }
        for (field, v, max) in [
            ("net.d_model", self.d_model, MAX_WIDTH),
            ("net.d_ff", self.d_ff, MAX_WIDTH),
            ("net.d_class", self.d_class, MAX_WIDTH),
            ("net.n_heads", self.n_heads, MAX_DEPTH),
            ("net.n_layers", self.n_layers, MAX_DEPTH),
        ] {
            if v > max {
                return bad(field, format!("{v} exceeds the budget of {max}"));
            }
        }
        let params = self.approx_params();
        if params > MAX_PARAMS {
            return bad(
                "net.d_model",
                format!(
                    "d_model {}, d_ff {}, n_layers {} make about {params} weights, more than the budget of {MAX_PARAMS}",
                    self.d_model, self.d_ff, self.n_layers
                ),
            );
        }
        if !(self.p.is_finite() && self.p > 0.0) {
            return bad("net.p", format!("must be finite and positive, got {}", self.p));
        }
        if !(self.gamma_init.is_finite() && self.gamma_init > 0.0) {
            return bad("net.gamma_init", format!("must be finite and positive, got {}", self.gamma_init));
        }
        Ok(())
    }
}

/// Weights of the loss terms.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LossConfig {
    /// `λ` of `L_dis = λ‖TCD‖₁`. Default 3 (Anomaly Transformer `k`).
    pub lambda: f64,
    /// `α₁`, classification weight in the min phase. Default 1 (decision 042).
    pub alpha1: f64,
    /// `α₂`, classification weight in the max phase. Default 1 (decision 042).
    pub alpha2: f64,
    /// How the two phases are stepped. Default [`MinMax::Summed`] (Anomaly Transformer code).
    pub min_max: MinMax,
    /// Weight of attacked steps in `L_class` (class imbalance: about one step in eight is
    /// attacked). Default 1.
    #[serde(default = "one")]
    pub pos_weight: f64,
}

fn one() -> f64 {
    1.0
}

impl Default for LossConfig {
    fn default() -> Self {
        Self { lambda: 3.0, alpha1: 1.0, alpha2: 1.0, min_max: MinMax::Summed, pos_weight: 1.0 }
    }
}

/// Scheduling of the min and max phases.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum MinMax {
    /// One AdamW step on the sum of both phase losses (Anomaly Transformer's
    /// `loss1.backward(); loss2.backward(); step()`).
    Summed,
    /// A max-phase step, then a min-phase step on a fresh forward pass
    /// (<https://github.com/thuml/Anomaly-Transformer/issues/70>).
    Alternating,
}

/// The per-batch loss terms (all scalars), for training and tests.
#[derive(Debug, Clone)]
pub struct LossTerms {
    /// `L_recon`: mean squared reconstruction error (`‖R̂ − R‖²_F / (b·l·m)`).
    pub recon: Tensor,
    /// `λ · mean TCD(T, sg(C))`: the min phase's discrepancy (gradient only to the prior).
    pub dis_min: Tensor,
    /// `λ · mean TCD(sg(T), C)`: the max phase's discrepancy (gradient only to the attention).
    pub dis_max: Tensor,
    /// `L_class`: BCE over the labelled steps (mean; 0 without labelled steps).
    pub class: Tensor,
}

impl LossTerms {
    /// Min phase: `L_recon + L_dis + α₁ L_class`.
    ///
    /// # Errors
    /// candle errors.
    pub fn min_phase(&self, cfg: &LossConfig) -> candle_core::Result<Tensor> {
        (&self.recon + &self.dis_min)? + self.class.affine(cfg.alpha1, 0.0)?
    }

    /// Max phase: `L_recon − L_dis + α₂ L_class`.
    ///
    /// # Errors
    /// candle errors.
    pub fn max_phase(&self, cfg: &LossConfig) -> candle_core::Result<Tensor> {
        (&self.recon - &self.dis_max)? + self.class.affine(cfg.alpha2, 0.0)?
    }
}

/// Network outputs for one batch (`r` = `l` steps, or 1 for [`Steps::Last`]).
#[derive(Debug, Clone)]
pub struct Output {
    /// Reconstruction `R̂`, `b × r × m`.
    pub r_hat: Tensor,
    /// Classification logits (sigmoid → attack probability), `b × r`.
    pub logits: Tensor,
    /// Prior `Tʰ` per layer, `b × heads × l × l` or `1 × heads × l × l` (TPC).
    pub prior: Vec<Tensor>,
    /// Attention `Cʰ` per layer, `b × heads × l × l`.
    pub attn: Vec<Tensor>,
}

/// Which steps of a window the forward pass produces outputs for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Steps {
    /// Every step (training and batch scoring).
    All,
    /// Only the last step (streaming). `with_tcd` keeps every layer's full prior and attention
    /// in the output so that the TCD of every step can be formed; without it `prior` and
    /// `attn` are empty and the last layer's queries are the last step's alone.
    Last {
        /// Keep the full maps for the TCD.
        with_tcd: bool,
    },
}

/// The QUADFormer network with its own variables.
pub struct QuadFormerNet {
    cfg: NetConfig,
    len: usize,
    dim: usize,
    varmap: VarMap,
    /// Every weight, typed (the variables of `varmap`).
    weights: QuadFormerWeights,
    /// Sinusoidal positional encoding, `1 × l × d_model`.
    pos: Tensor,
    /// `|j − i|^p`, `1 × l × l`, built once (TPC).
    dist_p: Tensor,
    /// `|j − i|²`, `1 × 1 × l × l`, built once (Gaussian prior).
    dist_sq: Tensor,
    /// For a causal network ([`NetConfig::causal`]): the additive mask of the attention scores
    /// (0 where `j ≤ i`, [`CAUSAL_MASK_FLOOR`] after) and the multiplicative one of the priors
    /// (1 where `j ≤ i`, 0 after), `1 × 1 × l × l` each.
    causal: Option<(Tensor, Tensor)>,
    /// Frozen TPC priors per layer for inference (`None` while training; empty for the
    /// Gaussian prior).
    prior_cache: Option<Vec<Tensor>>,
}

impl QuadFormerNet {
    /// Builds the network on the CPU for windows of `len` steps × `dim` channels and
    /// initialises every variable from `seed` ([`QuadFormerWeights::init_seeded`]); as
    /// [`QuadFormerNet::new_on`] with [`Device::Cpu`].
    ///
    /// # Errors
    /// [`ModelError::Config`] for a bad config; candle errors.
    pub fn new(cfg: &NetConfig, len: usize, dim: usize, seed: u64) -> Result<Self> {
        Self::new_on(cfg, len, dim, seed, &Device::Cpu)
    }

    /// Builds the network with its variables and constants on `device` (the CPU, or a CUDA
    /// device in a build with candle's `cuda` feature). The initial values are drawn on the
    /// CPU from `seed` whatever the device, so they do not depend on it.
    ///
    /// # Errors
    /// [`ModelError::Config`] for a bad config; candle errors.
    pub fn new_on(cfg: &NetConfig, len: usize, dim: usize, seed: u64, device: &Device) -> Result<Self> {
        cfg.check()?;
        if len < 2 || dim == 0 {
            return Err(ModelError::Config {
                field: "window.len",
                msg: format!("need l ≥ 2 and m ≥ 1, got l={len}, m={dim}"),
            });
        }
        let dev = device.clone();
        let varmap = VarMap::new();
        let vb = VarBuilder::from_varmap(&varmap, DType::F32, &dev);
        let weights = QuadFormerWeights::new(cfg, len, dim, &vb)?;
        QuadFormerWeights::init_seeded(&varmap, cfg, len, seed, &dev)?;
        let (dist_p, dist_sq) = distance_matrices(len, cfg.p, &dev)?;
        let causal = if cfg.causal { Some(causal_masks(len, &dev)?) } else { None };
        Ok(Self {
            cfg: cfg.clone(),
            len,
            dim,
            varmap,
            weights,
            pos: positional_encoding(len, cfg.d_model, &dev)?,
            dist_p,
            dist_sq,
            causal,
            prior_cache: None,
        })
    }

    /// The network's variables (for the optimiser and checkpoints).
    pub fn varmap(&self) -> &VarMap {
        &self.varmap
    }

    /// The network's weights, typed (the same tensors as [`QuadFormerNet::varmap`]).
    pub fn weights(&self) -> &QuadFormerWeights {
        &self.weights
    }

    /// The device of the variables and of every tensor the forward pass makes.
    pub fn device(&self) -> &Device {
        self.pos.device()
    }

    /// The architecture.
    pub fn config(&self) -> &NetConfig {
        &self.cfg
    }

    /// Window length `l`.
    pub fn window_len(&self) -> usize {
        self.len
    }

    /// Number of channels `m`.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Number of trainable scalars.
    pub fn n_params(&self) -> usize {
        self.varmap.all_vars().iter().map(|v| v.elem_count()).sum()
    }

    /// Switches to inference: precomputes the TPC priors (they depend only on `γ`).
    /// Call after the last change of the variables; [`QuadFormerNet::thaw`] switches back.
    ///
    /// # Errors
    /// candle errors.
    pub fn freeze(&mut self) -> Result<()> {
        self.prior_cache = None;
        let mut cache = Vec::with_capacity(self.weights.layers.len());
        for layer in &self.weights.layers {
            if let PriorWeights::Tpc { log_gamma } = &layer.prior {
                cache.push(self.tpc(log_gamma)?.detach());
            }
        }
        // Empty for the Gaussian prior, which depends on the input.
        self.prior_cache = Some(cache);
        Ok(())
    }

    /// The sinusoidal positional encoding, `1 × l × d_model`.
    pub(crate) fn positional_encoding(&self) -> &Tensor {
        &self.pos
    }

    /// Every layer's TPC prior, `1 × heads × l × l` each (the frozen ones after
    /// [`QuadFormerNet::freeze`]); empty for the Gaussian prior.
    ///
    /// # Errors
    /// candle errors.
    pub(crate) fn tpc_priors(&self) -> candle_core::Result<Vec<Tensor>> {
        if let Some(cache) = &self.prior_cache {
            return Ok(cache.clone());
        }
        self.weights
            .layers
            .iter()
            .filter_map(|layer| match &layer.prior {
                PriorWeights::Tpc { log_gamma } => Some(self.tpc(log_gamma)),
                PriorWeights::Gaussian { .. } => None,
            })
            .collect()
    }

    /// Drops the inference cache (before training again).
    pub fn thaw(&mut self) {
        self.prior_cache = None;
    }

    /// TPC prior `T` of one layer from `ln γ` (`heads × l`): `1 × heads × l × l`, rows sum to 1.
    fn tpc(&self, log_gamma: &Tensor) -> candle_core::Result<Tensor> {
        let (heads, l) = log_gamma.dims2()?;
        let gamma = log_gamma.exp()?.reshape((heads, l, 1))?;
        // eq:TPC: T = Rescale(exp(−γ·|j−i|^p)), exponent clamped (module docs).
        let arg = gamma.broadcast_mul(&self.dist_p)?.neg()?.clamp(PRIOR_EXP_FLOOR, 0.0)?;
        let k = self.restrict_to_past(&arg.exp()?.unsqueeze(0)?)?;
        k.broadcast_div(&k.sum_keepdim(D::Minus1)?)
    }

    /// A prior kernel (`… × l × l`) with the weights of later steps zeroed when the network is
    /// causal; unchanged otherwise. The diagonal stays, so every row keeps a positive sum.
    fn restrict_to_past(&self, k: &Tensor) -> candle_core::Result<Tensor> {
        match &self.causal {
            Some((_, keep)) => k.broadcast_mul(keep),
            None => Ok(k.clone()),
        }
    }

    /// Anomaly Transformer's Gaussian prior from the layer input `h` (`(b·l) × d`).
    fn gaussian_prior(&self, sigma_proj: &Dense, h: &Tensor, b: usize) -> candle_core::Result<Tensor> {
        let heads = self.cfg.n_heads;
        let s = sigma_proj.forward(h)?.reshape((b, self.len, heads))?.transpose(1, 2)?.contiguous()?;
        // σ = 3^(sigmoid(5s) + 1e−5) − 1 (Anomaly Transformer attn.py).
        let s = (candle_nn::ops::sigmoid(&(s * 5.0)?)? + 1e-5)?;
        let sigma = ((s * 3f64.ln())?.exp()? - 1.0)?.unsqueeze(D::Minus1)?;
        let two_var = (sigma.sqr()? * 2.0)?;
        let arg = self.dist_sq.broadcast_div(&two_var)?.neg()?.clamp(PRIOR_EXP_FLOOR, 0.0)?;
        let k = self.restrict_to_past(&arg.exp()?)?;
        k.broadcast_div(&k.sum_keepdim(D::Minus1)?)
    }

    /// Forward pass of `x` (`b × l × m`).
    ///
    /// # Errors
    /// candle errors, e.g. a wrong input shape.
    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Output> {
        self.forward_steps(x, Steps::All)
    }

    /// Forward pass of `x` (`b × l × m`) with outputs for the `steps` asked ([`Steps`]). With
    /// [`Steps::Last`], `r_hat` is `b × 1 × m` and `logits` `b × 1`, equal to the last step of
    /// [`QuadFormerNet::forward`]: what a streaming decision needs, with the last layer working
    /// on one row instead of `l`.
    ///
    /// # Errors
    /// candle errors, e.g. a wrong input shape.
    pub fn forward_steps(&self, x: &Tensor, steps: Steps) -> candle_core::Result<Output> {
        let (b, l, m) = x.dims3()?;
        if l != self.len || m != self.dim {
            candle_core::bail!("input window {l} × {m}, network built for {} × {}", self.len, self.dim)
        }
        let (d, heads) = (self.cfg.d_model, self.cfg.n_heads);
        let dh = d / heads;
        let scale = 1.0 / (dh as f64).sqrt();
        let w = &self.weights;
        let mut h = w
            .embed
            .forward(&x.reshape((b * l, m))?)?
            .reshape((b, l, d))?
            .broadcast_add(&self.pos)?
            .reshape((b * l, d))?;
        // `rows` rows per window of `(b·rows) × d` → `b × heads × rows × dh`.
        let split = |t: Tensor, rows: usize| -> candle_core::Result<Tensor> {
            t.reshape((b, rows, heads, dh))?.transpose(1, 2)?.contiguous()
        };
        let last_row =
            |t: &Tensor| -> candle_core::Result<Tensor> { t.reshape((b, l, d))?.narrow(1, l - 1, 1)?.reshape((b, d)) };
        let mut k_prev: Option<Tensor> = None;
        let mut prior = Vec::with_capacity(w.layers.len());
        let mut attn = Vec::with_capacity(w.layers.len());
        let n_layers = w.layers.len();
        // Rows the last layer and the heads produce, and whether every layer's attention is
        // kept for the TCD.
        let (rows, keep_attn) = match steps {
            Steps::All => (l, true),
            Steps::Last { with_tcd } => (1, with_tcd),
        };
        for (idx, layer) in w.layers.iter().enumerate() {
            let last_layer = idx + 1 == n_layers;
            let out_rows = if last_layer { rows } else { l };
            // Queries of every step only when the attention is kept.
            let q_rows = if keep_attn { l } else { out_rows };
            // The residual's rows; the queries' rows are the same ones or all `l`.
            let h_res = if out_rows == l { h.clone() } else { last_row(&h)? };
            let q = split(layer.w_q.forward(if q_rows == l { &h } else { &h_res })?, q_rows)?;
            // With DCM a layer's keys serve the next layer, so the last layer's are never used.
            let k = if self.cfg.dcm && idx > 0 && last_layer { None } else { Some(split(layer.w_k.forward(&h)?, l)?) };
            let v = split(layer.w_v.forward(&h)?, l)?;
            // eq:first_layer_attention (h = 1 or DCM off) / eq:cross_layer_attention (h > 1).
            let keys = match (self.cfg.dcm, &k_prev, &k) {
                (true, Some(kp), _) => kp,
                (_, _, Some(own)) => own,
                _ => candle_core::bail!("layer {idx} has no keys"),
            };
            let mut scores = (q.matmul(&keys.t()?)? * scale)?;
            // The last step's row attends to every step, causal or not.
            if let (Some((mask, _)), true) = (&self.causal, q_rows == l) {
                scores = scores.broadcast_add(mask)?;
            }
            let c = softmax_last_dim(&scores)?;
            let c_out = if q_rows == out_rows { c.clone() } else { c.narrow(2, l - 1, 1)? };
            if keep_attn {
                prior.push(match (&layer.prior, &self.prior_cache) {
                    (PriorWeights::Tpc { .. }, Some(cache)) if idx < cache.len() => cache[idx].clone(),
                    (PriorWeights::Tpc { log_gamma }, _) => self.tpc(log_gamma)?,
                    (PriorWeights::Gaussian { sigma }, _) => self.gaussian_prior(sigma, &h, b)?,
                });
                attn.push(c);
            }
            let out = c_out.matmul(&v)?.transpose(1, 2)?.reshape((b * out_rows, d))?;
            let z = layer.norm1.forward(&(layer.w_o.forward(&out)? + h_res)?)?;
            let f = layer.ff2.forward(&gelu(&layer.ff1.forward(&z)?)?)?;
            h = layer.norm2.forward(&(f + &z)?)?;
            k_prev = k;
        }
        let r_hat = w.recon.forward(&h)?;
        let class_in = match self.cfg.class_input {
            ClassInput::Reconstruction => &r_hat,
            ClassInput::Hidden => &h,
        };
        let logits = w.class2.forward(&gelu(&w.class1.forward(class_in)?)?)?.reshape((b, rows))?;
        Ok(Output { r_hat: r_hat.reshape((b, rows, m))?, logits, prior, attn })
    }

    /// TCD per step (eq. TCD of sec:attack_detector): mean over layers (and heads) of
    /// `JS(Tʰ_{i,:} ‖ Cʰ_{i,:})`, `b × l`, with the gradient to the prior and to the attention
    /// each passed, stopped or reversed ([`GradFlow`]).
    ///
    /// # Errors
    /// candle errors.
    pub fn tcd(out: &Output, prior: GradFlow, attn: GradFlow) -> candle_core::Result<Tensor> {
        let mut acc: Option<Tensor> = None;
        for (t, c) in out.prior.iter().zip(&out.attn) {
            let js = js_divergence_with(t, c, prior, attn)?.mean(1)?;
            acc = Some(match acc {
                Some(a) => (a + js)?,
                None => js,
            });
        }
        match acc {
            Some(a) => a / out.prior.len() as f64,
            None => candle_core::bail!("network has no layers"),
        }
    }

    /// All loss terms of a batch (see [`LossTerms`]).
    ///
    /// # Errors
    /// candle errors.
    pub fn loss_terms(&self, batch: &Batch, cfg: &LossConfig) -> candle_core::Result<LossTerms> {
        let out = self.forward(&batch.x)?;
        let recon = (&out.r_hat - &batch.x)?.sqr()?.mean_all()?;
        let dis_min = (Self::tcd(&out, GradFlow::Pass, GradFlow::Stop)?.mean_all()? * cfg.lambda)?;
        let dis_max = (Self::tcd(&out, GradFlow::Stop, GradFlow::Pass)?.mean_all()? * cfg.lambda)?;
        let class = masked_bce_with_logits(&out.logits, &batch.y, &batch.mask, batch.n_labelled, cfg.pos_weight)?;
        Ok(LossTerms { recon, dis_min, dis_max, class })
    }

    /// The sum of both phases, `max_phase + min_phase` of [`LossTerms`], from one discrepancy
    /// instead of two: `λ·TCD(T, C)` with the attention's gradient reversed has the gradient
    /// of `dis_min − dis_max` (prior pulled towards the attention, attention pushed away), and
    /// subtracting its detached value keeps the loss value `2·L_recon + (α₁ + α₂)·L_class`
    /// that the two phases sum to. It skips the forward pass of the second discrepancy that
    /// [`QuadFormerNet::loss_terms`] builds.
    ///
    /// # Errors
    /// candle errors.
    pub fn summed_min_max_loss(&self, batch: &Batch, cfg: &LossConfig) -> candle_core::Result<Tensor> {
        let out = self.forward(&batch.x)?;
        let recon = (&out.r_hat - &batch.x)?.sqr()?.mean_all()?;
        let dis = Self::tcd(&out, GradFlow::Pass, GradFlow::Reverse)?.mean_all()?;
        let dis = ((&dis - dis.detach())? * cfg.lambda)?;
        let class = masked_bce_with_logits(&out.logits, &batch.y, &batch.mask, batch.n_labelled, cfg.pos_weight)?;
        (recon.affine(2.0, 0.0)? + dis)? + class.affine(cfg.alpha1 + cfg.alpha2, 0.0)?
    }
}

/// Additive mask of a causal attention's scores after the diagonal: `exp` of it underflows to
/// 0 in `f32` whatever the scores, and it stays finite, so no `∞ − ∞` reaches a gradient.
pub const CAUSAL_MASK_FLOOR: f32 = -1e9;

/// The causal masks of [`QuadFormerNet`]: additive on the scores (0 / [`CAUSAL_MASK_FLOOR`])
/// and multiplicative on the priors (1 / 0), `1 × 1 × l × l` each.
fn causal_masks(len: usize, dev: &Device) -> candle_core::Result<(Tensor, Tensor)> {
    let past = |i: usize, j: usize| j <= i;
    let add: Vec<f32> =
        (0..len).flat_map(|i| (0..len).map(move |j| if past(i, j) { 0.0 } else { CAUSAL_MASK_FLOOR })).collect();
    let keep: Vec<f32> = (0..len).flat_map(|i| (0..len).map(move |j| if past(i, j) { 1.0 } else { 0.0 })).collect();
    Ok((Tensor::from_vec(add, (1, 1, len, len), dev)?, Tensor::from_vec(keep, (1, 1, len, len), dev)?))
}

/// `|j − i|^p` (`1 × l × l`) and `|j − i|²` (`1 × 1 × l × l`).
fn distance_matrices(len: usize, p: f64, dev: &Device) -> candle_core::Result<(Tensor, Tensor)> {
    let mut dp = Vec::with_capacity(len * len);
    let mut d2 = Vec::with_capacity(len * len);
    for i in 0..len {
        for j in 0..len {
            let a = (j as f64 - i as f64).abs();
            dp.push(a.powf(p) as f32);
            d2.push((a * a) as f32);
        }
    }
    Ok((Tensor::from_vec(dp, (1, len, len), dev)?, Tensor::from_vec(d2, (1, 1, len, len), dev)?))
}

/// Fixed sinusoidal positional encoding (Vaswani et al.), `1 × l × d`.
fn positional_encoding(len: usize, d: usize, dev: &Device) -> candle_core::Result<Tensor> {
    let mut pe = vec![0f32; len * d];
    for pos in 0..len {
        for i in 0..d {
            let k = (i / 2 * 2) as f64;
            let angle = pos as f64 / 10000f64.powf(k / d as f64);
            pe[pos * d + i] = if i % 2 == 0 { angle.sin() } else { angle.cos() } as f32;
        }
    }
    Tensor::from_vec(pe, (1, len, d), dev)
}

/// The network paired with its loss weights, as trained by [`nn_toolkit::train::train`].
pub struct MinMaxTrainer<'a> {
    /// The network.
    pub net: &'a QuadFormerNet,
    /// Loss weights and phase schedule.
    pub loss: LossConfig,
}

impl nn_toolkit::train::TrainableModel for MinMaxTrainer<'_> {
    fn n_phases(&self) -> usize {
        match self.loss.min_max {
            MinMax::Summed => 1,
            MinMax::Alternating => 2,
        }
    }

    fn loss(&self, batch: &Batch, phase: usize) -> candle_core::Result<Tensor> {
        // Anomaly Transformer: loss1 (max) and loss2 (min) back-propagated into one step.
        if self.loss.min_max == MinMax::Summed {
            return self.net.summed_min_max_loss(batch, &self.loss);
        }
        let terms = self.net.loss_terms(batch, &self.loss)?;
        if phase == 0 { terms.max_phase(&self.loss) } else { terms.min_phase(&self.loss) }
    }
}

#[cfg(test)]
mod tests;
