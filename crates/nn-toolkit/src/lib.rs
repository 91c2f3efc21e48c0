//! A CPU neural-network toolkit on candle, shared by QUADFormer (`quadformer-model`) and the
//! CNN/LSTM baselines so that every learning method sees the same data and loop:
//! - [`features`]: what a network reads per step ([`Features`]: raw, whitened by `S_k`, with
//!   the GLR drift channel (docs/decisions/094) and the absorbed-offset channels
//!   (docs/decisions/095)) and its step-by-step evaluation over a series ([`FeatureStream`]).
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
//! - [`tune_allocator`]: glibc malloc tuning, about 1.6× faster candle training;
//! - [`saved`]: plain file names, SHA-256 and JSON error messages of saved-model files.
//!
//! A per-step classifier trained with these pieces:
//!
//! ```
//! use candle_core::{DType, Device, Module, Tensor};
//! use candle_nn::{VarBuilder, VarMap};
//! use ekf_residue::{LabelledResidues, LabelledSeries, ResidueSeries};
//! use nn_toolkit::{init_vars_seeded, train, Batch, Features, Normaliser, TrainConfig, TrainableModel, WindowConfig, Windows};
//!
//! struct PerStep(candle_nn::Linear);
//! impl TrainableModel for PerStep {
//!     fn loss(&self, batch: &Batch, _phase: usize) -> candle_core::Result<Tensor> {
//!         let logits = self.0.forward(&batch.x)?.squeeze(2)?;
//!         nn_toolkit::loss::masked_bce_with_logits(&logits, &batch.y, &batch.mask, batch.n_labelled, 1.0)
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
//! let report = train(&model, &varmap, &windows, &cfg, &mut |_m| Ok::<f64, nn_toolkit::NnError>(0.0))?;
//! assert_eq!(report.history.len(), 2);
//! # Ok(())
//! # }
//! ```
//! - [`layers`]: the dense layer and layer norm, and [`layers::repeat_rows`], a broadcast whose
//!   gradient is a matrix product (decision 065);
//! - [`fused`]: bias addition, erf GELU, softmax and layer norm as custom ops with closed-form
//!   backward passes; [`vmath`]: their `exp`, `ln` and `erf`, written for the vectoriser, with
//!   run-time dispatch to AVX2 ([`vmath::vectorized`]); [`matmul`]: a bounds-checked wrapper of
//!   the `gemm` kernel into caller-owned buffers;
//! - [`loss`]: the masked, class-weighted BCE every learning method trains its per-step logits with.
//!
//! Layer: between the residues (`ekf-residue`) and the detectors (`quadformer-model`,
//! `baselines`); it knows nothing of any detector.
#![warn(missing_docs)]

pub mod alloc;
pub mod error;
pub mod features;
pub mod fused;
pub mod init;
pub mod layers;
pub mod loss;
pub mod matmul;
pub mod saved;
pub mod train;
pub mod vmath;
pub mod window;

pub use alloc::tune_allocator;
pub use error::{NnError, Result};
pub use features::{FeatureStream, Features};
pub use init::init_vars_seeded;
pub use train::{EpochStats, TrainConfig, TrainReport, TrainableModel, train, train_on};
pub use window::{Batch, Mix, Normaliser, SeriesWindows, WindowConfig, Windows};
