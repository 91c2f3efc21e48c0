//! The QUADFormer attack detector (paper sec:attack_detector, alg:alg2) in candle, on the CPU.
//!
//! Layer: this crate owns the QUADFormer network, its losses and min-max trainer, windowing,
//! checkpoints and streaming inference. It reads `ekf_residue::{ResidueSeries,
//! LabelledResidues}` and implements `ekf_residue::{Fit, Detector}`; it knows nothing about the
//! baselines or the evaluation.
//!
//! The detector:
//! - [`model`]: the network — UAV Attack Attention with TPC (eq:TPC) and DCM
//!   (eq:first_layer_attention, eq:cross_layer_attention), reconstruction and classification
//!   heads, TCD (Jensen–Shannon, [`js::js_divergence`], one fused kernel) and the min-max losses with the
//!   Anomaly Transformer's stop-gradient split ([`model::LossTerms`], [`model::MinMaxTrainer`]);
//!   its dense and norm layers are in [`layers`], and its GELU, softmax and layer norm are
//!   single kernels with closed-form backward passes ([`fused`]);
//! - [`detector`]: [`QuadFormerConfig`] implements `ekf_residue::Fit`; the fitted
//!   [`QuadFormerDetector`] implements `Detector` with four scoring modes ([`ScoreMode`]:
//!   alg:alg2's `softmax(−TCD)`, the Anomaly Transformer criterion, the classifier probability,
//!   a combination) whose thresholds are chosen on the validation split, and a streaming
//!   [`OnlineQuadFormer`];
//! - [`streaming`]: [`streaming::StreamingNet`], the frozen network outside candle that the
//!   streaming detector runs (layer 1 reused across windows, the last layer on the newest step,
//!   attention scores refactored to fewer multiply-adds, the TCD with one logarithm per entry,
//!   products through the bounds-checked [`matmul`] into buffers allocated once);
//! - [`checkpoint`]: safetensors weights + versioned JSON manifest with integrity checks.
//!
//! Usage and training guide: `docs/quadformer.md`.
//!
//! Model-agnostic building blocks, shared with the CNN/LSTM baselines so that every learning
//! method sees the same data and loop:
//! - [`window`]: [`Normaliser`] (per-channel standardisation fitted on training data, saved
//!   with a model), [`Windows`] (windows of `l` steps × `m` channels with per-step labels and a
//!   label-known mask, configurable stride, [`Windows::batch`] → [`Batch`] tensors) and
//!   [`SeriesWindows::stitch`] (per-window scores back to one score per step);
//! - [`train`](mod@train): [`train()`] — a seeded mini-batch loop with AdamW, per-epoch
//!   learning-rate decay, early stopping on a caller-supplied validation metric (lower is
//!   better, best variables restored) and a progress bar, generic over [`TrainableModel`]
//!   (`fn loss(&self, batch: &Batch, phase: usize) -> candle_core::Result<Tensor>`);
//! - [`init_vars_seeded`]: seeded initialisation of every variable of a `VarMap` (candle's own
//!   generator cannot be seeded);
//! - [`tune_allocator`]: glibc malloc tuning, about 1.6× faster candle training.
//!
//! A per-step classifier trained with these pieces:
//!
//! ```
//! use candle_core::{DType, Device, Module, Tensor};
//! use candle_nn::{VarBuilder, VarMap};
//! use ekf_residue::{LabelledResidues, LabelledSeries, ResidueSeries};
//! use quadformer_model::{init_vars_seeded, train, Batch, Features, Normaliser, TrainConfig, TrainableModel, WindowConfig, Windows};
//!
//! struct PerStep(candle_nn::Linear);
//! impl TrainableModel for PerStep {
//!     fn loss(&self, batch: &Batch, _phase: usize) -> candle_core::Result<Tensor> {
//!         let logits = self.0.forward(&batch.x)?.squeeze(2)?;
//!         quadformer_model::model::masked_bce_with_logits(&logits, &batch.y, &batch.mask, batch.n_labelled, 1.0)
//!     }
//! }
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let n = 200;
//! let labels: Vec<bool> = (0..n).map(|k| (50..70).contains(&k)).collect();
//! let r = labels.iter().map(|&a| if a { 4.0 } else { 0.1 }).collect();
//! let series = ResidueSeries::from_flat((0..n).map(|k| k as f64 * 0.1).collect(), vec!["gps_x".into()], r, vec![1.0; n])?;
//! let split = LabelledResidues::new(vec![LabelledSeries::new(series, Some(labels))?])?;
//! let norm = Normaliser::fit(&split, Features::Raw)?;
//! let windows = Windows::from_split(&split, &norm, &WindowConfig { len: 20, stride: 10, features: Features::Raw })?;
//! let varmap = VarMap::new();
//! let model = PerStep(candle_nn::linear(1, 1, VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu))?);
//! init_vars_seeded(&varmap, 42)?;
//! let cfg = TrainConfig { epochs: 2, progress: false, ..TrainConfig::default() };
//! let report = train(&model, &varmap, &windows, &cfg, &mut |_m| Ok(0.0))?;
//! assert_eq!(report.history.len(), 2);
//! # Ok(())
//! # }
//! ```
#![warn(missing_docs)]

pub mod alloc;
pub mod checkpoint;
pub mod detector;
pub mod error;
pub mod fused;
pub mod init;
pub mod js;
pub mod layers;
pub mod matmul;
pub mod model;
pub mod streaming;
pub mod train;
pub mod vmath;
pub mod window;

pub use alloc::tune_allocator;
pub use detector::{
    ModeResult, OnlineQuadFormer, QuadFormerConfig, QuadFormerDetector, RawScores, ScoreConfig, ScoreMode,
};
pub use error::{ModelError, Result};
pub use init::init_vars_seeded;
pub use model::{ClassInput, GradFlow, LossConfig, MinMax, NetConfig, Prior, QuadFormerNet, Steps};
pub use train::{EpochStats, TrainConfig, TrainReport, TrainableModel, train};
pub use window::{Batch, Features, Normaliser, SeriesWindows, WindowConfig, Windows};
