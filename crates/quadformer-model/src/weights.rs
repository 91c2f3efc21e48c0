//! The QUADFormer network's weights as one typed structure: the input embedding, every UAV
//! Attack Attention layer's projections (eq:first_layer_attention, eq:cross_layer_attention),
//! prior (eq:TPC, or the Gaussian of the "TPC off" ablation), norms and feed-forward block,
//! and the reconstruction and classification heads.
//!
//! This module is the one place that names the network's variables. The names are those of
//! the safetensors checkpoints ([`crate::checkpoint`]) and of the seeded initialisation
//! (`nn_toolkit::init`, which visits the variables in name order), so they do not change:
//!
//! | part | variables |
//! |---|---|
//! | embedding `W_e`, `b_e` | `embed.{weight,bias}` |
//! | layer `h` projections | `layers.{h}.attn.{w_q,w_k,w_v,w_o}.{weight,bias}` |
//! | layer `h` TPC width `ln γ` | `layers.{h}.attn.log_gamma` |
//! | layer `h` Gaussian width | `layers.{h}.attn.sigma.{weight,bias}` |
//! | layer `h` norms | `layers.{h}.norm1.{weight,bias}`, `layers.{h}.norm2.{weight,bias}` |
//! | layer `h` feed-forward | `layers.{h}.ff1.{weight,bias}`, `layers.{h}.ff2.{weight,bias}` |
//! | heads | `recon.{weight,bias}`, `class1.{weight,bias}`, `class2.{weight,bias}` |
//!
//! The candle network ([`crate::model::QuadFormerNet`]) is built from a [`QuadFormerWeights`]
//! and the streaming engine ([`crate::streaming`]) reads the same structure, so neither looks a
//! weight up by name.

use candle_core::{Device, Tensor};
use candle_nn::{Init, VarBuilder, VarMap};

use crate::error::Result;
use crate::model::{ClassInput, NetConfig, Prior};
use nn_toolkit::init::init_vars_seeded;
use nn_toolkit::layers::{Dense, Norm};

/// The prior association's weights of one layer.
pub enum PriorWeights {
    /// TPC (eq:TPC): `ln γ`, `heads × l`.
    Tpc {
        /// `ln γ` per head and window position.
        log_gamma: Tensor,
    },
    /// The Anomaly Transformer's Gaussian prior: its width is `Linear(d_model, heads)` of the
    /// layer input.
    Gaussian {
        /// The width projection.
        sigma: Dense,
    },
}

/// One UAV Attack Attention layer (post-norm, [`crate::model`] docs).
pub struct EncoderLayerWeights {
    /// Query projection `W_Q`, `b_Q`.
    pub w_q: Dense,
    /// Key projection `W_K`, `b_K`.
    pub w_k: Dense,
    /// Value projection `W_V`, `b_V`.
    pub w_v: Dense,
    /// Output projection `W_O`, `b_O`.
    pub w_o: Dense,
    /// The prior `T`.
    pub prior: PriorWeights,
    /// The norm after the attention and its residual.
    pub norm1: Norm,
    /// Feed-forward, `d_model → d_ff`.
    pub ff1: Dense,
    /// Feed-forward, `d_ff → d_model`.
    pub ff2: Dense,
    /// The norm after the feed-forward block and its residual.
    pub norm2: Norm,
}

/// Every weight of a QUADFormer network (module docs).
pub struct QuadFormerWeights {
    /// Input embedding `Linear(m, d_model)`.
    pub embed: Dense,
    /// The layers, first to last.
    pub layers: Vec<EncoderLayerWeights>,
    /// Reconstruction head `Linear(d_model, m)`.
    pub recon: Dense,
    /// Classification head, first layer (`Linear(m or d_model, d_class)`, [`ClassInput`]).
    pub class1: Dense,
    /// Classification head, second layer `Linear(d_class, 1)`.
    pub class2: Dense,
}

/// The variable prefix of layer `h`.
fn layer_prefix(h: usize) -> String {
    format!("layers.{h}")
}

/// Name of the TPC width variable of layer `h` (for tests and inspection).
pub fn log_gamma_name(h: usize) -> String {
    format!("{}.attn.log_gamma", layer_prefix(h))
}

impl QuadFormerWeights {
    /// Creates every variable of a network `cfg` for windows of `len` steps × `dim` channels
    /// under `vb` (names in the module docs), with constant initial values; the random ones are
    /// set by [`QuadFormerWeights::init_seeded`].
    ///
    /// # Errors
    /// candle errors.
    pub fn new(cfg: &NetConfig, len: usize, dim: usize, vb: &VarBuilder) -> candle_core::Result<Self> {
        let d = cfg.d_model;
        let embed = Dense::new(dim, d, vb.pp("embed"))?;
        let mut layers = Vec::with_capacity(cfg.n_layers);
        for h in 0..cfg.n_layers {
            let vl = vb.pp(layer_prefix(h));
            let va = vl.pp("attn");
            let prior = match cfg.prior {
                Prior::Tpc => PriorWeights::Tpc {
                    log_gamma: va.get_with_hints((cfg.n_heads, len), "log_gamma", Init::Const(cfg.gamma_init.ln()))?,
                },
                Prior::Gaussian => PriorWeights::Gaussian { sigma: Dense::new(d, cfg.n_heads, va.pp("sigma"))? },
            };
            layers.push(EncoderLayerWeights {
                w_q: Dense::new(d, d, va.pp("w_q"))?,
                w_k: Dense::new(d, d, va.pp("w_k"))?,
                w_v: Dense::new(d, d, va.pp("w_v"))?,
                w_o: Dense::new(d, d, va.pp("w_o"))?,
                prior,
                norm1: Norm::new(d, vl.pp("norm1"))?,
                ff1: Dense::new(d, cfg.d_ff, vl.pp("ff1"))?,
                ff2: Dense::new(cfg.d_ff, d, vl.pp("ff2"))?,
                norm2: Norm::new(d, vl.pp("norm2"))?,
            });
        }
        let recon = Dense::new(d, dim, vb.pp("recon"))?;
        let class_in = match cfg.class_input {
            ClassInput::Reconstruction => dim,
            ClassInput::Hidden => d,
        };
        let class1 = Dense::new(class_in, cfg.d_class, vb.pp("class1"))?;
        let class2 = Dense::new(cfg.d_class, 1, vb.pp("class2"))?;
        Ok(Self { embed, layers, recon, class1, class2 })
    }

    /// Sets every variable of `varmap` (holding the weights of a network `cfg` for windows of
    /// `len` steps, on `device`) from `seed` ([`init_vars_seeded`]), then `ln γ` back to
    /// `ln gamma_init`: it is rank 2, so the generic rule overwrote it.
    ///
    /// # Errors
    /// candle errors.
    pub fn init_seeded(varmap: &VarMap, cfg: &NetConfig, len: usize, seed: u64, device: &Device) -> Result<()> {
        init_vars_seeded(varmap, seed)?;
        if cfg.prior == Prior::Tpc {
            for h in 0..cfg.n_layers {
                let t = Tensor::full(cfg.gamma_init.ln() as f32, (cfg.n_heads, len), device)?;
                let mut vm = varmap.clone();
                vm.set_one(log_gamma_name(h), t)?;
            }
        }
        Ok(())
    }
}
