//! A generic, seeded mini-batch training loop over [`Windows`] with AdamW and early stopping.
//!
//! Any model that turns a [`Batch`] into a scalar loss implements [`TrainableModel`]; QUADFormer
//! (min-max, eq:TPC/TCD losses) and the CNN/LSTM baselines (per-step BCE) share this loop.
//!
//! Per epoch: the windows are shuffled with a generator seeded from `(seed, epoch)`, split into
//! mini-batches, and for every batch each of the model's `n_phases()` losses is back-propagated
//! and followed by one AdamW step (one phase = the Anomaly Transformer's single step on the
//! summed min and max losses; two phases = alternating steps). After each epoch the caller's
//! validation closure returns a metric where **lower is better** (e.g. validation loss, or
//! `−F1`); training stops after `patience` epochs without improvement and the variables of the
//! best epoch are restored. Nothing here draws from candle's unseeded generator, so a run is
//! bit-identical for a fixed seed on the CPU.

use std::time::Instant;

use candle_core::{Device, Tensor};
use candle_nn::{AdamW, Optimizer, ParamsAdamW, VarMap};
use indicatif::{ProgressBar, ProgressStyle};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use serde::{Deserialize, Serialize};

use crate::error::{NnError, Result};
use crate::window::{Batch, Mix, WindowConfig, Windows};

/// Budget of the largest activation tensor of a mini-batch, in numbers (1 GiB of `f32`).
pub const MAX_ACTIVATIONS: u64 = 1 << 28;

/// A model trainable by [`train`].
pub trait TrainableModel {
    /// Optimiser steps per mini-batch; phase indices `0..n_phases()` are passed to
    /// [`TrainableModel::loss`] in order. Default 1.
    fn n_phases(&self) -> usize {
        1
    }

    /// The scalar loss of `batch` for `phase`; it must depend on the variables to train.
    ///
    /// # Errors
    /// Any candle error.
    fn loss(&self, batch: &Batch, phase: usize) -> candle_core::Result<Tensor>;
}

/// Hyper-parameters of the training loop.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainConfig {
    /// Maximum number of epochs. Default 10 (Anomaly Transformer `num_epochs`).
    pub epochs: usize,
    /// Windows per mini-batch. Default 32 (sized for a 2-core CPU, the batch of the benches in
    /// docs/performance.md; Anomaly Transformer uses 256 on a GPU).
    pub batch_size: usize,
    /// AdamW learning rate. Default 1e-3 (candle `ParamsAdamW` default).
    pub lr: f64,
    /// AdamW decoupled weight decay. Default 0.01 (candle and PyTorch AdamW default).
    pub weight_decay: f64,
    /// Learning-rate factor applied after every epoch from the second on. Default 0.5
    /// (Anomaly Transformer `adjust_learning_rate`: halve per epoch).
    pub lr_decay: f64,
    /// Epochs without validation improvement before stopping. Default 3 (Anomaly Transformer
    /// `EarlyStopping(patience=3)`).
    pub patience: usize,
    /// At most this many (randomly chosen) windows per epoch; `None` = all. Default `None`.
    pub max_windows_per_epoch: Option<usize>,
    /// Share of each epoch's windows drawn from the windows with labels, when the training set
    /// mixes labelled and unlabelled flights (semi-supervision); labelled windows are repeated
    /// across the epoch if there are too few. `None`: windows are drawn uniformly, so the
    /// labelled share is the labelled fraction of the data. Default `None`.
    #[serde(default)]
    pub labelled_share: Option<f64>,
    /// Mirror each training window with probability ½ (`r_k → −r_k`,
    /// [`Windows::batch_mirrored`]). Default false here; the QUADFormer, CNN and LSTM
    /// configurations turn it on (docs/decisions/044-whitened-inputs.md).
    #[serde(default)]
    pub mirror: bool,
    /// Probability that a labelled training window is mixed with another labelled window
    /// ([`Windows::batch_augmented`]; the windows must come from [`Windows::for_training`]
    /// with whitened features) at a weight `c` drawn uniformly so that both `c` and
    /// `√(1 − c²)` are at least [`MIX_MIN_WEIGHT`]: attacks of every amplitude from the few
    /// labelled flights (docs/decisions/047-mixed-windows.md). Default 0 (none).
    #[serde(default)]
    pub mix: f64,
    /// Seed of the shuffling generator. Default 0.
    pub seed: u64,
    /// Show a progress bar with the loss per epoch on stderr. Default true.
    pub progress: bool,
}

impl Default for TrainConfig {
    fn default() -> Self {
        Self {
            epochs: 10,
            batch_size: 32,
            lr: 1e-3,
            weight_decay: 0.01,
            lr_decay: 0.5,
            patience: 3,
            max_windows_per_epoch: None,
            labelled_share: None,
            mirror: false,
            mix: 0.0,
            seed: 0,
            progress: true,
        }
    }
}

/// Smallest weight of either window of a mix ([`TrainConfig::mix`]): every labelled attack
/// keeps at least a quarter of its amplitude (the smallest attack of the matrix, 1.5 m, becomes
/// 0.375 m, under one GPS σ; docs/decisions/030-attack-model-and-planning.md), so a step
/// labelled attacked carries an offset.
pub const MIX_MIN_WEIGHT: f64 = 0.25;

/// Budget of every mini-batch size (training and scoring): a batch is allocated whole.
pub const MAX_BATCH_SIZE: usize = 65_536;

impl TrainConfig {
    /// [`TrainConfig::check`], and that mixing (`mix > 0`) has the whitened features it mixes
    /// (docs/decisions/047-mixed-windows.md): the check a model configuration runs on its
    /// training loop and windows together.
    ///
    /// # Errors
    /// [`NnError::Config`] naming the field.
    pub fn check_for(&self, window: &WindowConfig) -> Result<()> {
        self.check()?;
        if self.mix > 0.0 && !window.features.is_whitened() {
            return Err(NnError::Config {
                field: "train.mix",
                msg: format!("mixing windows needs whitened features, not window.features = {:?}", window.features),
            });
        }
        Ok(())
    }

    /// Checks that sizes are positive and rates finite and non-negative.
    ///
    /// # Errors
    /// [`NnError::Config`] naming the field.
    pub fn check(&self) -> Result<()> {
        let bad = |field: &'static str, msg: &str| Err(NnError::Config { field, msg: msg.into() });
        if self.epochs == 0 {
            return bad("train.epochs", "must be at least 1");
        }
        if self.batch_size == 0 {
            return bad("train.batch_size", "must be at least 1");
        }
        if self.batch_size > MAX_BATCH_SIZE {
            return Err(NnError::Config {
                field: "train.batch_size",
                msg: format!("{} exceeds the budget of {MAX_BATCH_SIZE}", self.batch_size),
            });
        }
        if !(self.lr.is_finite() && self.lr > 0.0) {
            return bad("train.lr", "must be finite and positive");
        }
        if !(self.weight_decay.is_finite() && self.weight_decay >= 0.0) {
            return bad("train.weight_decay", "must be finite and non-negative");
        }
        if !(self.lr_decay.is_finite() && self.lr_decay > 0.0 && self.lr_decay <= 1.0) {
            return bad("train.lr_decay", "must be in (0, 1]");
        }
        if let Some(share) = self.labelled_share
            && !(0.0..=1.0).contains(&share)
        {
            return bad("train.labelled_share", "must be in [0, 1]");
        }
        if !(0.0..=1.0).contains(&self.mix) {
            return bad("train.mix", "must be in [0, 1]");
        }
        Ok(())
    }
}

/// Statistics of one epoch.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct EpochStats {
    /// Epoch number, from 1.
    pub epoch: usize,
    /// Mean training loss over the epoch's mini-batches (phase 0).
    pub train_loss: f64,
    /// Validation metric after the epoch (lower is better).
    pub valid_metric: f64,
    /// Wall time of the epoch's optimisation (without validation), seconds.
    pub train_seconds: f64,
}

/// What a training run did.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TrainReport {
    /// One entry per epoch run.
    pub history: Vec<EpochStats>,
    /// The epoch whose variables were kept.
    pub best_epoch: usize,
    /// Its validation metric.
    pub best_metric: f64,
    /// Optimiser steps taken (all phases).
    pub steps: usize,
    /// Windows processed (counted once per batch, whatever the number of phases).
    pub windows: usize,
    /// Total optimisation wall time, seconds.
    pub train_seconds: f64,
}

impl TrainReport {
    /// Optimiser steps per second of optimisation time.
    pub fn steps_per_s(&self) -> f64 {
        self.steps as f64 / self.train_seconds.max(1e-9)
    }

    /// Windows per second of optimisation time.
    pub fn windows_per_s(&self) -> f64 {
        self.windows as f64 / self.train_seconds.max(1e-9)
    }
}

/// Copies of all variables of `varmap`, by name.
fn snapshot(varmap: &VarMap) -> Result<Vec<(String, Tensor)>> {
    let data = varmap.data().lock().map_err(|_| NnError::Data { msg: "variable map lock poisoned".into() })?;
    data.iter().map(|(k, v)| Ok((k.clone(), v.as_tensor().copy()?))).collect()
}

fn restore(varmap: &VarMap, snap: &[(String, Tensor)]) -> Result<()> {
    let data = varmap.data().lock().map_err(|_| NnError::Data { msg: "variable map lock poisoned".into() })?;
    for (name, t) in snap {
        if let Some(var) = data.get(name) {
            var.set(t)?;
        }
    }
    Ok(())
}

/// Seeded Fisher–Yates shuffle.
fn shuffle(idx: &mut [usize], rng: &mut StdRng) {
    for i in (1..idx.len()).rev() {
        let j = rng.random_range(0..=i);
        idx.swap(i, j);
    }
}

/// The `per_epoch` windows of one epoch, in training order: a uniform sample without
/// replacement, or, with a labelled share `ρ` and both kinds of window present, `⌈ρ·n⌉`
/// labelled windows (each used once before any repeats) and the rest unlabelled ones.
fn epoch_windows(windows: &Windows, per_epoch: usize, share: Option<f64>, rng: &mut StdRng) -> Vec<usize> {
    let mut all: Vec<usize> = (0..windows.len()).collect();
    if let Some(share) = share {
        let (mut lab, mut unlab): (Vec<usize>, Vec<usize>) = all.iter().partition(|&&w| windows.is_labelled(w));
        if !lab.is_empty() && !unlab.is_empty() {
            let n_lab = ((share * per_epoch as f64).ceil() as usize).min(per_epoch);
            let n_unlab = (per_epoch - n_lab).min(unlab.len());
            let mut idx = Vec::with_capacity(n_lab + n_unlab);
            while idx.len() < n_lab {
                shuffle(&mut lab, rng);
                idx.extend(lab.iter().take(n_lab - idx.len()));
            }
            shuffle(&mut unlab, rng);
            idx.extend(&unlab[..n_unlab]);
            shuffle(&mut idx, rng);
            return idx;
        }
    }
    shuffle(&mut all, rng);
    all.truncate(per_epoch);
    all
}

/// Which windows of `chunk` are mixed, and with what ([`TrainConfig::mix`]): each labelled
/// one (a member of `labelled`, ascending) with probability `p`, with another labelled window
/// drawn uniformly, at a weight uniform in `[w₀, √(1 − w₀²)]` (`w₀` = [`MIX_MIN_WEIGHT`]).
/// Draws nothing when `p` is 0, so a run without mixing is unchanged.
fn mixes_of(chunk: &[usize], labelled: &[usize], p: f64, rng: &mut StdRng) -> Vec<Option<Mix>> {
    if p <= 0.0 || labelled.len() < 2 {
        return Vec::new();
    }
    let top = (1.0 - MIX_MIN_WEIGHT * MIX_MIN_WEIGHT).sqrt();
    chunk
        .iter()
        .map(|w| {
            let own = labelled.binary_search(w).ok()?;
            if !rng.random_bool(p) {
                return None;
            }
            // Uniform over the other labelled windows.
            let j = rng.random_range(0..labelled.len() - 1);
            let with = labelled[j + usize::from(j >= own)];
            let weight = rng.random_range(MIX_MIN_WEIGHT..=top) as f32;
            Some(Mix { with, weight })
        })
        .collect()
}

/// Trains the variables of `varmap` through `model` on `windows` (module docs for the loop),
/// calling `valid(model)` after every epoch; lower validation metric is better. The batches are
/// built on the CPU: [`train_on`] with [`Device::Cpu`].
///
/// # Errors
/// [`NnError::Config`] for a bad config, [`NnError::Data`] for no windows,
/// [`NnError::Numerical`] naming epoch and step for a non-finite loss, and any error of
/// `valid` or candle.
pub fn train<M: TrainableModel + ?Sized, E: From<NnError>>(
    model: &M,
    varmap: &VarMap,
    windows: &Windows,
    cfg: &TrainConfig,
    valid: &mut dyn FnMut(&M) -> std::result::Result<f64, E>,
) -> std::result::Result<TrainReport, E> {
    train_on(model, varmap, windows, cfg, &Device::Cpu, valid)
}

/// [`train`] with the mini-batches built on `device`, the device of the model's variables
/// (the CPU, or a CUDA device in a build with candle's `cuda` feature). The shuffling and
/// mirroring draws do not depend on the device.
///
/// # Errors
/// As [`train`].
pub fn train_on<M: TrainableModel + ?Sized, E: From<NnError>>(
    model: &M,
    varmap: &VarMap,
    windows: &Windows,
    cfg: &TrainConfig,
    device: &Device,
    valid: &mut dyn FnMut(&M) -> std::result::Result<f64, E>,
) -> std::result::Result<TrainReport, E> {
    train_loop(model, varmap, windows, cfg, device, valid).map_err(|e| match e {
        Failure::Toolkit(e) => E::from(e),
        Failure::Valid(e) => e,
    })
}

/// Why [`train_loop`] stopped: the toolkit failed, or the caller's validation metric did.
enum Failure<E> {
    Toolkit(NnError),
    Valid(E),
}

impl<E> From<NnError> for Failure<E> {
    fn from(e: NnError) -> Self {
        Self::Toolkit(e)
    }
}

impl<E> From<candle_core::Error> for Failure<E> {
    fn from(e: candle_core::Error) -> Self {
        Self::Toolkit(NnError::Candle(e))
    }
}

/// [`train`]'s loop, with the caller's error kept apart.
fn train_loop<M: TrainableModel + ?Sized, E>(
    model: &M,
    varmap: &VarMap,
    windows: &Windows,
    cfg: &TrainConfig,
    device: &Device,
    valid: &mut dyn FnMut(&M) -> std::result::Result<f64, E>,
) -> std::result::Result<TrainReport, Failure<E>> {
    cfg.check()?;
    if windows.is_empty() {
        return Err(NnError::Data { msg: "no training windows".into() }.into());
    }
    let labelled: Vec<usize> = if cfg.mix > 0.0 {
        if !windows.can_mix() {
            return Err(NnError::Config {
                field: "train.mix",
                msg: "mixing windows needs training windows (Windows::for_training) of whitened features \
                      (window.features)"
                    .into(),
            }
            .into());
        }
        (0..windows.len()).filter(|&w| windows.is_labelled(w)).collect()
    } else {
        Vec::new()
    };
    let params = ParamsAdamW { lr: cfg.lr, weight_decay: cfg.weight_decay, ..ParamsAdamW::default() };
    let mut opt = AdamW::new(varmap.all_vars(), params)?;
    let per_epoch = cfg.max_windows_per_epoch.unwrap_or(usize::MAX).min(windows.len());
    let batches_per_epoch = per_epoch.div_ceil(cfg.batch_size);
    let pb = if cfg.progress {
        let pb = ProgressBar::new((cfg.epochs * batches_per_epoch) as u64);
        if let Ok(style) =
            ProgressStyle::with_template("{prefix} [{elapsed_precise}] {wide_bar} {pos}/{len} batches {msg}")
        {
            pb.set_style(style);
        }
        pb.set_prefix("training");
        pb
    } else {
        ProgressBar::hidden()
    };
    let mut report = TrainReport {
        history: Vec::new(),
        best_epoch: 0,
        best_metric: f64::INFINITY,
        steps: 0,
        windows: 0,
        train_seconds: 0.0,
    };
    let mut best: Option<Vec<(String, Tensor)>> = None;
    let mut since_best = 0;
    let mut lr = cfg.lr;
    for epoch in 1..=cfg.epochs {
        let mut rng = StdRng::seed_from_u64(cfg.seed.wrapping_mul(0x9E37_79B9_7F4A_7C15).wrapping_add(epoch as u64));
        let idx = epoch_windows(windows, per_epoch, cfg.labelled_share, &mut rng);
        let t0 = Instant::now();
        let mut loss_sum = 0.0;
        for (b, chunk) in idx.chunks(cfg.batch_size).enumerate() {
            let mirrored: Vec<bool> =
                if cfg.mirror { chunk.iter().map(|_| rng.random_bool(0.5)).collect() } else { Vec::new() };
            let mixes = mixes_of(chunk, &labelled, cfg.mix, &mut rng);
            let batch = windows.batch_augmented(chunk, &mirrored, &mixes, device)?;
            for phase in 0..model.n_phases() {
                let loss = model.loss(&batch, phase)?;
                let v = f64::from(loss.to_scalar::<f32>()?);
                if !v.is_finite() {
                    return Err(NnError::Numerical {
                        what: format!("loss {v} at epoch {epoch}, batch {b}, phase {phase}"),
                    }
                    .into());
                }
                if phase == 0 {
                    loss_sum += v;
                }
                opt.backward_step(&loss)?;
                report.steps += 1;
            }
            report.windows += chunk.len();
            pb.inc(1);
        }
        let train_seconds = t0.elapsed().as_secs_f64();
        report.train_seconds += train_seconds;
        let valid_metric = valid(model).map_err(Failure::Valid)?;
        let stats =
            EpochStats { epoch, train_loss: loss_sum / batches_per_epoch.max(1) as f64, valid_metric, train_seconds };
        let line = format!("epoch {epoch}: train loss {:.5}, valid metric {:.5}", stats.train_loss, stats.valid_metric);
        pb.set_message(line.clone());
        if cfg.progress {
            pb.println(line);
        }
        report.history.push(stats);
        if valid_metric < report.best_metric || best.is_none() {
            report.best_metric = valid_metric;
            report.best_epoch = epoch;
            best = Some(snapshot(varmap)?);
            since_best = 0;
        } else {
            since_best += 1;
            if since_best >= cfg.patience.max(1) {
                break;
            }
        }
        if epoch >= 2 {
            lr *= cfg.lr_decay;
            opt.set_learning_rate(lr);
        }
    }
    pb.finish_and_clear();
    if let Some(snap) = best {
        restore(varmap, &snap)?;
    }
    Ok(report)
}

#[cfg(test)]
mod tests {
    use candle_core::{DType, Module};
    use candle_nn::VarBuilder;

    use super::*;
    use crate::init::init_vars_seeded;

    /// A per-step logistic classifier: the smallest user of the loop.
    struct PerStep {
        lin: candle_nn::Linear,
    }

    impl TrainableModel for PerStep {
        fn loss(&self, batch: &Batch, _phase: usize) -> candle_core::Result<Tensor> {
            let logits = self.lin.forward(&batch.x)?.squeeze(2)?;
            candle_nn::loss::binary_cross_entropy_with_logit(&logits, &batch.y)
        }
    }

    fn toy(n_win: usize) -> Windows {
        use ekf_residue::{LabelledResidues, LabelledSeries, ResidueSeries};
        let n = n_win * 10;
        let labels: Vec<bool> = (0..n).map(|k| k % 7 == 0).collect();
        let r: Vec<f64> = labels.iter().map(|&a| if a { 3.0 } else { -1.0 }).collect();
        let s =
            ResidueSeries::from_flat((0..n).map(|k| k as f64).collect(), vec!["a".into()], r, vec![1.0; n]).unwrap();
        let split = LabelledResidues::new(vec![LabelledSeries::new(s, Some(labels)).unwrap()]).unwrap();
        let norm = crate::window::Normaliser::fit(&split, crate::window::Features::Raw).unwrap();
        Windows::from_split(
            &split,
            &norm,
            &crate::window::WindowConfig { len: 10, stride: 10, features: crate::window::Features::Raw },
        )
        .unwrap()
    }

    fn run(seed: u64) -> (TrainReport, Vec<f32>) {
        let vm = VarMap::new();
        let vb = VarBuilder::from_varmap(&vm, DType::F32, &Device::Cpu);
        let model = PerStep { lin: candle_nn::linear(1, 1, vb).unwrap() };
        init_vars_seeded(&vm, seed).unwrap();
        let w = toy(8);
        let cfg =
            TrainConfig { epochs: 4, batch_size: 3, lr: 0.1, lr_decay: 1.0, progress: false, ..Default::default() };
        let wv = w.clone();
        let mut valid = |m: &PerStep| -> Result<f64> {
            let b = wv.batch(&(0..wv.len()).collect::<Vec<_>>(), &Device::Cpu)?;
            Ok(f64::from(m.loss(&b, 0)?.to_scalar::<f32>()?))
        };
        let report = train(&model, &vm, &w, &cfg, &mut valid).unwrap();
        (report, model.lin.weight().flatten_all().unwrap().to_vec1().unwrap())
    }

    #[test]
    fn loop_learns_and_is_deterministic() {
        let (a, wa) = run(3);
        let (b, wb) = run(3);
        assert_eq!(wa, wb);
        assert_eq!(
            a.history,
            b.history
                .iter()
                .map(|h| EpochStats { train_seconds: a.history[h.epoch - 1].train_seconds, ..h.clone() })
                .collect::<Vec<_>>()
        );
        assert!(a.history.last().unwrap().valid_metric < a.history[0].train_loss);
        assert_eq!(a.steps, 4 * 3);
    }

    #[test]
    fn labelled_share_sets_the_mix_of_each_epoch() {
        use ekf_residue::{LabelledResidues, LabelledSeries, ResidueSeries};
        // Two flights of 10 windows each, the first labelled, the second not.
        let flight = |labelled: bool| {
            let n = 100;
            let s = ResidueSeries::from_flat(
                (0..n).map(|k| k as f64).collect(),
                vec!["a".into()],
                vec![0.5; n],
                vec![1.0; n],
            )
            .unwrap();
            LabelledSeries::new(s, labelled.then(|| vec![false; n])).unwrap()
        };
        let split = LabelledResidues::new(vec![flight(true), flight(false)]).unwrap();
        let norm = crate::window::Normaliser::fit(&split, crate::window::Features::Raw).unwrap();
        let w = Windows::from_split(
            &split,
            &norm,
            &crate::window::WindowConfig { len: 10, stride: 10, features: crate::window::Features::Raw },
        )
        .unwrap();
        assert_eq!((0..w.len()).filter(|&i| w.is_labelled(i)).count(), 10);
        let mut rng = StdRng::seed_from_u64(1);
        // 80% of 16 windows = 13 labelled: all 10 once, then 3 repeats; 3 unlabelled.
        let idx = epoch_windows(&w, 16, Some(0.8), &mut rng);
        assert_eq!(idx.len(), 16);
        let n_lab = idx.iter().filter(|&&i| w.is_labelled(i)).count();
        assert_eq!(n_lab, 13);
        let mut lab: Vec<usize> = idx.iter().copied().filter(|&i| w.is_labelled(i)).collect();
        lab.sort_unstable();
        lab.dedup();
        assert_eq!(lab.len(), 10, "every labelled window is used before any repeats");
        // Without a share the epoch is a plain sample without replacement.
        let mut plain = epoch_windows(&w, 20, None, &mut rng);
        plain.sort_unstable();
        assert_eq!(plain, (0..20).collect::<Vec<_>>());
        assert!(TrainConfig { labelled_share: Some(1.5), ..Default::default() }.check().is_err());
    }

    #[test]
    fn bad_config_is_named() {
        let e = TrainConfig { batch_size: 0, ..Default::default() }.check().unwrap_err();
        assert!(e.to_string().contains("batch_size"), "{e}");
    }

    #[test]
    fn mixes_pair_labelled_windows_with_another_at_bounded_weights_and_draw_nothing_at_zero() {
        let labelled = [1usize, 4, 5, 9];
        let chunk = [0usize, 1, 4, 5, 7, 9, 1, 4];
        let mut rng = StdRng::seed_from_u64(3);
        let before = StdRng::seed_from_u64(3).random::<u64>();
        assert!(mixes_of(&chunk, &labelled, 0.0, &mut rng).is_empty());
        assert_eq!(rng.random::<u64>(), before, "no draw without mixing");
        let top = (1.0 - MIX_MIN_WEIGHT * MIX_MIN_WEIGHT).sqrt() as f32;
        let mut partners = std::collections::BTreeSet::new();
        for seed in 0..200 {
            let mixes = mixes_of(&chunk, &labelled, 1.0, &mut StdRng::seed_from_u64(seed));
            for (w, mix) in chunk.iter().zip(&mixes) {
                match mix {
                    None => assert!(!labelled.contains(w), "labelled window {w} not mixed at p = 1"),
                    Some(mx) => {
                        assert!(labelled.contains(w) && labelled.contains(&mx.with) && mx.with != *w);
                        assert!((MIX_MIN_WEIGHT as f32..=top).contains(&mx.weight), "{}", mx.weight);
                        partners.insert((*w, mx.with));
                    }
                }
            }
        }
        // Every other labelled window is drawn as a partner.
        assert_eq!(partners.len(), labelled.len() * (labelled.len() - 1));
        assert!(TrainConfig { mix: 1.5, ..TrainConfig::default() }.check().is_err());
    }
}
