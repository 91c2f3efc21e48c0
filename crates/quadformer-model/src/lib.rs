//! The QUADFormer attack detector (paper sec:attack_detector, alg:alg2) in candle, on the CPU or a
//! device its caller passes ([`QuadFormerConfig::fit_on`]).
//!
//! Layer: this crate owns the QUADFormer network, its losses and min-max trainer, checkpoints and
//! streaming inference. It trains with the CPU toolkit of `nn-toolkit` (windowing, the training
//! loop, initialisation, layers and kernels), reads `ekf_residue::{ResidueSeries,
//! LabelledResidues}` and implements `ekf_residue::{Fit, Detector}`; it knows nothing about the
//! baselines or the evaluation.
//!
//! The detector:
//! - [`weights`]: [`QuadFormerWeights`], every weight of the network as one typed structure,
//!   and the only place that names the variables (the checkpoints' names);
//! - [`model`]: the network — UAV Attack Attention with TPC (eq:TPC) and DCM
//!   (eq:first_layer_attention, eq:cross_layer_attention), reconstruction and classification
//!   heads, TCD (Jensen–Shannon, [`js::js_divergence`], one fused kernel) and the min-max losses with the
//!   Anomaly Transformer's stop-gradient split ([`model::LossTerms`], [`model::MinMaxTrainer`]);
//!   its dense and norm layers, and its GELU, softmax and layer norm kernels with closed-form
//!   backward passes, come from `nn-toolkit` (`nn_toolkit::layers`, `nn_toolkit::fused`);
//! - [`detector`]: [`QuadFormerConfig`] implements `ekf_residue::Fit`; the fitted
//!   [`QuadFormerDetector`] implements `Detector` with four scoring modes ([`ScoreMode`]:
//!   alg:alg2's `softmax(−TCD)`, the Anomaly Transformer criterion, the classifier probability,
//!   a combination) whose thresholds are chosen on the validation split, and a streaming
//!   [`OnlineQuadFormer`] that runs the streaming engine, or the candle forward pass on its
//!   window for a network the engine cannot represent;
//! - [`streaming`]: [`streaming::StreamingNet`], the frozen network outside candle that the
//!   streaming detector runs (layer 1 reused across windows, the last layer on the newest step,
//!   attention scores refactored to fewer multiply-adds, the TCD with one logarithm per entry,
//!   products through the bounds-checked `nn_toolkit::matmul` into buffers allocated once), read
//!   from [`QuadFormerWeights`] into a ring whose slots are named;
//! - [`checkpoint`]: safetensors weights + versioned JSON manifest with integrity checks.
//!
//! Usage and training guide: `docs/quadformer.md`.
//!
//!
//! The types of the toolkit that appear in this crate's configuration and API ([`TrainConfig`],
//! [`WindowConfig`], [`Features`], [`Normaliser`], ...) are re-exported here.
#![warn(missing_docs)]

pub mod checkpoint;
pub mod detector;
pub mod error;
pub mod js;
pub mod model;
pub mod streaming;
pub mod weights;

pub use detector::{
    ModeResult, OnlineQuadFormer, QuadFormerConfig, QuadFormerDetector, RawScores, ScoreConfig, ScoreMode,
};
pub use error::{ModelError, Result};
pub use model::{ClassInput, GradFlow, LossConfig, MinMax, NetConfig, Prior, QuadFormerNet, Steps};
pub use nn_toolkit::{
    Batch, EpochStats, Features, Normaliser, SeriesWindows, TrainConfig, TrainReport, TrainableModel, WindowConfig,
    Windows,
};
pub use weights::{EncoderLayerWeights, PriorWeights, QuadFormerWeights};
