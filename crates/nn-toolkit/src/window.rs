//! Model-agnostic windowing of labelled residues (paper alg:alg2 input `R ∈ ℝ^{l×m}`).
//!
//! Shared by QUADFormer and the CNN/LSTM baselines so that every learning method sees the same
//! windows, normalisation and stitching.
//!
//! - [`Normaliser`]: the feature map ([`Features`], `crate::features`) and the per-feature mean
//!   and standard deviation, fitted on the training split only and saved with a model.
//! - [`Windows`]: `n_win` windows of `l` steps × the normaliser's features (row-major `f32`), per-step
//!   labels `y ∈ {0, 1}` and a label-known mask (1 where the flight is labelled and the step is
//!   real, 0 for unlabelled flights and padding). Consecutive windows of a flight start `stride`
//!   steps apart; the last window always ends at the last step, so every step is covered.
//!   A flight shorter than `l` is padded at the front by repeating its first step (mask 0).
//! - [`SeriesWindows::stitch`]: per-window per-step scores back to one score per step of the
//!   series, the mean over all windows that cover the step.

use candle_core::{Device, Tensor};
use ekf_residue::{LabelledResidues, ResidueSeries, ResidueStep};
use serde::{Deserialize, Serialize};

use crate::error::{NnError, Result};
use crate::features::whiten_per_channel;
pub use crate::features::{FeatureStream, Features};

/// Smallest standard deviation treated as non-zero; a constant channel is divided by 1.
const STD_FLOOR: f64 = 1e-12;

/// Window length and stride.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WindowConfig {
    /// Window length `l` in residue steps. Default 100 (Anomaly Transformer `win_size`, the
    /// window of alg:alg2; thuml/Anomaly-Transformer `main.py`).
    pub len: usize,
    /// Steps between the starts of consecutive training windows. Default 10
    /// (docs/decisions/041-window-stride.md); QUADFormer, the CNN and the LSTM train at 20
    /// (docs/decisions/044-whitened-inputs.md).
    pub stride: usize,
    /// What each step of a window holds. Default [`Features::WhitenedLog`]
    /// (docs/decisions/044-whitened-inputs.md); a configuration saved without the field was
    /// trained on [`Features::Raw`] and reads back as that.
    #[serde(default = "raw_features")]
    pub features: Features,
}

impl Default for WindowConfig {
    fn default() -> Self {
        Self { len: 100, stride: 10, features: Features::default() }
    }
}

fn raw_features() -> Features {
    Features::Raw
}

/// Longest window accepted, in steps (200 s at 10 Hz). One attention map of a window this long
/// holds 4 million entries per head and layer; anything longer is a configuration error
/// rather than an allocation the machine cannot make.
pub const MAX_WINDOW_LEN: usize = 2_000;

/// Budget of residue channels a model reads (the paper's residues have at most six).
pub const MAX_CHANNELS: usize = 256;

impl WindowConfig {
    /// Checks `2 ≤ len ≤` [`MAX_WINDOW_LEN`] and `1 ≤ stride`.
    ///
    /// # Errors
    /// [`NnError::Config`] naming the field.
    pub fn check(&self) -> Result<()> {
        if !(2..=MAX_WINDOW_LEN).contains(&self.len) {
            return Err(NnError::Config {
                field: "window.len",
                msg: format!("must be between 2 and {MAX_WINDOW_LEN}, got {}", self.len),
            });
        }
        if self.stride == 0 {
            return Err(NnError::Config { field: "window.stride", msg: "must be at least 1".into() });
        }
        Ok(())
    }
}

/// The feature map of a step and the per-feature standardisation `(x − μ) / σ`, fitted on
/// training data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Normaliser {
    /// Residue channel names, in order (what a series must have).
    pub channels: Vec<String>,
    /// The feature map (a saved normaliser without the field used [`Features::Raw`]).
    #[serde(default = "raw_features")]
    pub features: Features,
    /// Mean `μ` per feature.
    pub mean: Vec<f64>,
    /// Standard deviation `σ` per feature (1 for a constant feature).
    pub std: Vec<f64>,
}

impl Normaliser {
    /// Fits mean and standard deviation of every feature over all steps of `train`.
    ///
    /// # Errors
    /// [`NnError::Data`] if `train` has no steps.
    pub fn fit(train: &LabelledResidues, features: Features) -> Result<Self> {
        let m = train.channels().len();
        let n = train.n_steps();
        if n == 0 || m == 0 {
            return Err(NnError::Data { msg: "cannot fit a normaliser on an empty training split".into() });
        }
        let dim = features.dim(m);
        let mut sum = vec![0.0; dim];
        let mut sum_sq = vec![0.0; dim];
        let mut row = vec![0.0; dim];
        for f in train.flights() {
            let mut stream = FeatureStream::new(features, train.channels());
            for step in f.series().steps() {
                stream.compute(&step, &mut row);
                for ((s, q), v) in sum.iter_mut().zip(&mut sum_sq).zip(&row) {
                    *s += v;
                    *q += v * v;
                }
            }
        }
        let nf = n as f64;
        let mean: Vec<f64> = sum.iter().map(|s| s / nf).collect();
        let std = sum_sq
            .iter()
            .zip(&mean)
            .map(|(q, mu)| {
                let var = (q / nf - mu * mu).max(0.0);
                let sd = var.sqrt();
                if sd > STD_FLOOR { sd } else { 1.0 }
            })
            .collect();
        Ok(Self { channels: train.channels().to_vec(), features, mean, std })
    }

    /// Number of features per step (the networks' input width).
    pub fn dim(&self) -> usize {
        self.features.dim(self.channels.len())
    }

    /// A [`FeatureStream`] at the start of a series, for [`Normaliser::apply`].
    pub fn stream(&self) -> FeatureStream {
        FeatureStream::new(self.features, &self.channels)
    }

    /// Writes the normalised features of `step`, the next step of the series `stream` follows,
    /// into `out` (length [`Normaliser::dim`]).
    pub fn apply(&self, stream: &mut FeatureStream, step: &ResidueStep<'_>, out: &mut [f32]) {
        // A stack row for the usual widths keeps streaming decisions free of allocations.
        let mut stack = [0.0f64; 32];
        let mut heap = Vec::new();
        let row: &mut [f64] = if self.dim() <= stack.len() {
            &mut stack[..self.dim()]
        } else {
            heap.resize(self.dim(), 0.0);
            &mut heap
        };
        stream.compute(step, row);
        self.standardise(row, out);
    }

    /// `(x − μ) / σ` of the features `row` of one step into `out`.
    fn standardise(&self, row: &[f64], out: &mut [f32]) {
        for (((o, v), mu), sd) in out.iter_mut().zip(row).zip(&self.mean).zip(&self.std) {
            *o = ((v - mu) / sd) as f32;
        }
    }

    /// Where each normalised feature is mirrored by a sign flip of the residue, `r_k → −r_k`:
    /// `Some(c)` for a feature odd in `r_k` (mirrored value `2c − x`, with `c = −μ/σ` the image
    /// of a zero residue), `None` for an even one (`√NIS`, drift; unchanged).
    pub fn mirror_centres(&self) -> Vec<Option<f32>> {
        let m = self.channels.len();
        (0..self.dim()).map(|i| self.features.is_odd(i, m).then(|| (-self.mean[i] / self.std[i]) as f32)).collect()
    }

    /// Checks that the fitted statistics match the feature map: one finite mean and one
    /// finite positive standard deviation per feature.
    ///
    /// # Errors
    /// [`NnError::Data`] naming what is wrong.
    pub fn check(&self) -> Result<()> {
        if self.channels.len() > MAX_CHANNELS {
            return Err(NnError::Data {
                msg: format!("normaliser: {} channels exceed the budget of {MAX_CHANNELS}", self.channels.len()),
            });
        }
        let dim = self.dim();
        if self.mean.len() != dim || self.std.len() != dim {
            return Err(NnError::Data {
                msg: format!(
                    "normaliser: {:?} features of {} channels need {dim} means and standard deviations, got {} and {}",
                    self.features,
                    self.channels.len(),
                    self.mean.len(),
                    self.std.len()
                ),
            });
        }
        if self.mean.iter().any(|v| !v.is_finite()) || self.std.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
            return Err(NnError::Data {
                msg: "normaliser: means must be finite and standard deviations finite and positive".into(),
            });
        }
        Ok(())
    }

    /// Checks that the series has the fitted channels.
    ///
    /// # Errors
    /// [`NnError::Detect`] with a channel mismatch.
    pub fn check_series(&self, series: &ResidueSeries) -> Result<()> {
        Ok(ekf_residue::check_channels(&self.channels, series)?)
    }
}

/// Where the windows of one series start, to stitch window scores back to steps.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SeriesWindows {
    /// Start of each window in the padded series.
    pub starts: Vec<usize>,
    /// Number of real steps `n` of the series.
    pub n_steps: usize,
    /// Front padding steps (`l − n` when `n < l`, else 0).
    pub pad: usize,
    /// Window length `l`.
    pub len: usize,
}

impl SeriesWindows {
    /// Window starts over a series of `n_steps` steps: every `stride` steps, plus a last window
    /// that ends at the last step. A stride above `len` is treated as `len`, so that every step
    /// is covered (subsample training windows with `TrainConfig::max_windows_per_epoch`).
    pub fn new(n_steps: usize, len: usize, stride: usize) -> Self {
        let stride = stride.clamp(1, len.max(1));
        let pad = len.saturating_sub(n_steps);
        let n_pad = n_steps + pad;
        let last = n_pad - len;
        let mut starts: Vec<usize> = (0..=last).step_by(stride).collect();
        if starts.last() != Some(&last) {
            starts.push(last);
        }
        if n_steps == 0 {
            starts.clear();
        }
        Self { starts, n_steps, pad, len }
    }

    /// The one window that ends at the last of `n_steps` steps (front-padded when
    /// `n_steps < len`): the only window covering that step, so its score there is the
    /// step's stitched score. No window for an empty series.
    pub fn newest(n_steps: usize, len: usize) -> Self {
        let pad = len.saturating_sub(n_steps);
        let starts = if n_steps == 0 { Vec::new() } else { vec![n_steps + pad - len] };
        Self { starts, n_steps, pad, len }
    }

    /// Per-step scores of the series: the mean over the covering windows of the
    /// per-window-step scores `window_scores` (`starts.len() × l`, row-major).
    ///
    /// # Errors
    /// [`NnError::Data`] if `window_scores` has the wrong length.
    pub fn stitch(&self, window_scores: &[f32]) -> Result<Vec<f64>> {
        let l = self.len;
        if window_scores.len() != self.starts.len() * l {
            return Err(NnError::Data {
                msg: format!("stitch: expected {} window scores, got {}", self.starts.len() * l, window_scores.len()),
            });
        }
        let n_pad = self.n_steps + self.pad;
        let mut sum = vec![0.0f64; n_pad];
        let mut count = vec![0u32; n_pad];
        for (w, &s0) in self.starts.iter().enumerate() {
            for (i, &v) in window_scores[w * l..(w + 1) * l].iter().enumerate() {
                sum[s0 + i] += f64::from(v);
                count[s0 + i] += 1;
            }
        }
        Ok(sum[self.pad..].iter().zip(&count[self.pad..]).map(|(s, &c)| s / f64::from(c.max(1))).collect())
    }
}

/// A set of windows with per-step labels and label-known mask, ready for batching.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Windows {
    len: usize,
    dim: usize,
    /// [`Normaliser::mirror_centres`] of the normaliser the windows were made with.
    mirror: Vec<Option<f32>>,
    /// The normaliser the windows were made with (for features of mixed windows).
    norm: Option<Normaliser>,
    x: Vec<f32>,
    y: Vec<f32>,
    mask: Vec<f32>,
    /// Per step, the whitened residue `z_i = r_i/√(S_k)_ii` and `u = L⁻¹ r_k` (`|u|² = NIS_k`),
    /// `2m` values, for training windows ([`Windows::for_training`]) of a whitened feature map
    /// ([`Features::is_whitened`]); empty otherwise. Each window holds `ctx + l` rows: the
    /// [`Features::context`] steps before it, then its own; rows before the flight's first
    /// step and front padding are `NaN`.
    whitened: Vec<f32>,
    /// Whether [`Windows::push_series`] keeps `whitened` ([`Windows::for_training`]).
    mixable: bool,
}

/// The mixing of one window of a batch with another ([`Windows::batch_augmented`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Mix {
    /// The other window.
    pub with: usize,
    /// Weight `c ∈ (0, 1)` of the window itself; the other gets `√(1 − c²)`.
    pub weight: f32,
}

/// One mini-batch: inputs `x` (`b × l × m`), labels `y` and mask (`b × l`), all `f32`.
#[derive(Debug, Clone)]
pub struct Batch {
    /// Normalised residues, `b × l × m`.
    pub x: Tensor,
    /// Labels (1 = attacked), `b × l`; 0 where unknown.
    pub y: Tensor,
    /// 1 where the label is known, `b × l`.
    pub mask: Tensor,
    /// Number of steps with a known label.
    pub n_labelled: usize,
}

impl Windows {
    /// An empty set for windows of `len` steps × `dim` channels.
    pub fn empty(len: usize, dim: usize) -> Self {
        Self { len, dim, ..Self::default() }
    }

    /// All windows of a split, `cfg.stride` apart within each flight.
    ///
    /// # Errors
    /// [`NnError::Config`] for a bad `cfg`; channel mismatch with `norm`.
    pub fn from_split(data: &LabelledResidues, norm: &Normaliser, cfg: &WindowConfig) -> Result<Self> {
        Self::split_windows(Self::empty(cfg.len, norm.dim()), data, norm, cfg)
    }

    /// The training windows of a split: [`Windows::from_split`] with what mixing them needs
    /// ([`Windows::can_mix`]; per window step the `2m` values of [`Windows::batch_augmented`],
    /// for a whitened feature map).
    ///
    /// # Errors
    /// As [`Windows::from_split`].
    pub fn for_training(data: &LabelledResidues, norm: &Normaliser, cfg: &WindowConfig) -> Result<Self> {
        Self::split_windows(Self { mixable: true, ..Self::empty(cfg.len, norm.dim()) }, data, norm, cfg)
    }

    fn split_windows(mut out: Self, data: &LabelledResidues, norm: &Normaliser, cfg: &WindowConfig) -> Result<Self> {
        cfg.check()?;
        for f in data.flights() {
            out.push_series(f.series(), f.labels(), norm, cfg.stride)?;
        }
        Ok(out)
    }

    /// Appends the windows of one series (labels optional) and returns where they start.
    ///
    /// # Errors
    /// Channel mismatch with `norm`; [`NnError::Data`] if the labels have the wrong length.
    pub fn push_series(
        &mut self,
        series: &ResidueSeries,
        labels: Option<&[bool]>,
        norm: &Normaliser,
        stride: usize,
    ) -> Result<SeriesWindows> {
        self.push_windows(series, labels, norm, SeriesWindows::new(series.len(), self.len, stride))
    }

    /// Appends the window that ends at the last step of `series` ([`SeriesWindows::newest`]),
    /// its features computed over the whole series, as [`Windows::push_series`] computes
    /// them: what a streaming decision on that step reads.
    ///
    /// # Errors
    /// As [`Windows::push_series`].
    pub fn push_newest(&mut self, series: &ResidueSeries, norm: &Normaliser) -> Result<SeriesWindows> {
        self.push_windows(series, None, norm, SeriesWindows::newest(series.len(), self.len))
    }

    /// Appends the windows `sw` of one series.
    fn push_windows(
        &mut self,
        series: &ResidueSeries,
        labels: Option<&[bool]>,
        norm: &Normaliser,
        sw: SeriesWindows,
    ) -> Result<SeriesWindows> {
        norm.check_series(series)?;
        if norm.dim() != self.dim {
            return Err(NnError::Data {
                msg: format!("windows have {} channels, normaliser {}", self.dim, norm.dim()),
            });
        }
        if let Some(l) = labels
            && l.len() != series.len()
        {
            return Err(NnError::Data { msg: format!("{} labels for {} steps", l.len(), series.len()) });
        }
        match &self.norm {
            Some(own) if own != norm => {
                return Err(NnError::Data { msg: "windows of one set need one normaliser".into() });
            }
            Some(_) => {}
            None => {
                self.mirror = norm.mirror_centres();
                self.norm = Some(norm.clone());
            }
        }
        let (l, m) = (self.len, self.dim);
        if sw.starts.is_empty() {
            return Ok(sw);
        }
        // Normalise the (front-padded) series once, then copy windows out of it. Padding
        // repeats the features of the first step.
        let n_pad = series.len() + sw.pad;
        let mut xs = vec![0.0f32; n_pad * m];
        let mut ys = vec![0.0f32; n_pad];
        let mut ms = vec![0.0f32; n_pad];
        let mut stream = norm.stream();
        for (step, row) in series.steps().zip(xs[sw.pad * m..].chunks_exact_mut(m)) {
            norm.apply(&mut stream, &step, row);
        }
        let (pad_rows, first) = xs.split_at_mut(sw.pad * m);
        for row in pad_rows.chunks_exact_mut(m) {
            row.copy_from_slice(&first[..m]);
        }
        if let Some(lab) = labels {
            for (k, &a) in lab.iter().enumerate() {
                ys[sw.pad + k] = if a { 1.0 } else { 0.0 };
                ms[sw.pad + k] = 1.0;
            }
        }
        for &s0 in &sw.starts {
            self.x.extend_from_slice(&xs[s0 * m..(s0 + l) * m]);
            self.y.extend_from_slice(&ys[s0..s0 + l]);
            self.mask.extend_from_slice(&ms[s0..s0 + l]);
        }
        if self.mixable && norm.features.is_whitened() {
            // `ctx` rows of NaN, the padding as NaN, then the steps.
            let (w, ctx) = (2 * series.dim(), norm.features.context());
            let mut zu = vec![f32::NAN; (ctx + n_pad) * w];
            for (step, row) in series.steps().zip(zu[(ctx + sw.pad) * w..].chunks_exact_mut(w)) {
                whitened_row(&step, row);
            }
            for &s0 in &sw.starts {
                self.whitened.extend_from_slice(&zu[s0 * w..(s0 + ctx + l) * w]);
            }
        }
        Ok(sw)
    }

    /// Whether windows can be mixed ([`Windows::batch_augmented`]): training windows
    /// ([`Windows::for_training`]) of a whitened feature map.
    pub fn can_mix(&self) -> bool {
        let (m2, ctx) = self.norm.as_ref().map_or((0, 0), |n| (2 * n.channels.len(), n.features.context()));
        m2 > 0 && self.whitened.len() == self.len() * (ctx + self.len) * m2
    }

    /// Number of windows.
    pub fn len(&self) -> usize {
        self.y.len() / self.len.max(1)
    }

    /// True when there are no windows.
    pub fn is_empty(&self) -> bool {
        self.y.is_empty()
    }

    /// Window length `l`.
    pub fn window_len(&self) -> usize {
        self.len
    }

    /// Number of channels `m`.
    pub fn dim(&self) -> usize {
        self.dim
    }

    /// Inputs, row-major `n_win × l × m`.
    pub fn x(&self) -> &[f32] {
        &self.x
    }

    /// Labels, row-major `n_win × l`.
    pub fn y(&self) -> &[f32] {
        &self.y
    }

    /// Label-known mask, row-major `n_win × l`.
    pub fn mask(&self) -> &[f32] {
        &self.mask
    }

    /// Whether window `w` has at least one step with a known label.
    pub fn is_labelled(&self, w: usize) -> bool {
        let l = self.len;
        self.mask.get(w * l..(w + 1) * l).is_some_and(|m| m.iter().any(|&v| v > 0.0))
    }

    /// Number of window steps with a known label.
    pub fn n_labelled(&self) -> usize {
        self.mask.iter().filter(|&&v| v > 0.0).count()
    }

    /// The windows `idx` as a [`Batch`] on `device`.
    ///
    /// # Errors
    /// [`NnError::Data`] for an index past the end; [`NnError::Candle`].
    pub fn batch(&self, idx: &[usize], device: &Device) -> Result<Batch> {
        self.batch_mirrored(idx, &[], device)
    }

    /// The windows `idx` as a [`Batch`], window `idx[i]` mirrored (`r_k → −r_k` at every step,
    /// [`Normaliser::mirror_centres`]) where `mirrored[i]` is true; a short `mirrored` leaves
    /// the rest as they are. A sign-flipped attack is an attack of the opposite offset as far
    /// as the linearised filter goes, so this doubles the labelled examples (training
    /// augmentation); under skewed noise (exponential) a mirrored clean window is slightly off
    /// its distribution (docs/decisions/044-whitened-inputs.md).
    ///
    /// # Errors
    /// As [`Windows::batch`].
    pub fn batch_mirrored(&self, idx: &[usize], mirrored: &[bool], device: &Device) -> Result<Batch> {
        self.batch_augmented(idx, mirrored, &[], device)
    }

    /// The windows `idx` as a [`Batch`], window `idx[i]` mixed with another where `mixes[i]`
    /// is `Some`, then mirrored where `mirrored[i]` is true (short slices leave the rest as
    /// they are).
    ///
    /// Mixing window `a` with window `b` at weight `c` makes, at every step, the whitened
    /// residue `c·z_a + √(1 − c²)·z_b` (and `u` alike, so `NIS = |u|²`), and its features.
    /// For a linearised filter the innovation of an attacked flight is the clean innovation
    /// plus a response linear in the offset, and clean innovations of equal covariance keep
    /// their covariance under these weights; so the mix is a flight whose attacks are those
    /// of `a` scaled by `c` and those of `b` by `√(1 − c²)`. A step is attacked if it is in
    /// either and its label is known if it is known in both (0 where unknown). It exists to
    /// give the few labelled flights attacks of every amplitude
    /// (docs/decisions/047-mixed-windows.md).
    ///
    /// # Errors
    /// As [`Windows::batch`]; [`NnError::Data`] for a mix of windows that cannot be mixed
    /// ([`Windows::can_mix`]) or a weight outside `(0, 1)`.
    pub fn batch_augmented(
        &self,
        idx: &[usize],
        mirrored: &[bool],
        mixes: &[Option<Mix>],
        device: &Device,
    ) -> Result<Batch> {
        let (l, m, n) = (self.len, self.dim, self.len());
        let b = idx.len();
        let mut x = Vec::with_capacity(b * l * m);
        let mut y = Vec::with_capacity(b * l);
        let mut mask = Vec::with_capacity(b * l);
        for (i, &w) in idx.iter().enumerate() {
            let mix = mixes.get(i).copied().flatten();
            for v in std::iter::once(w).chain(mix.map(|mx| mx.with)) {
                if v >= n {
                    return Err(NnError::Data { msg: format!("window index {v} out of range ({n} windows)") });
                }
            }
            let start = x.len();
            match mix {
                None => {
                    x.extend_from_slice(&self.x[w * l * m..(w + 1) * l * m]);
                    y.extend_from_slice(&self.y[w * l..(w + 1) * l]);
                    mask.extend_from_slice(&self.mask[w * l..(w + 1) * l]);
                }
                Some(mx) => {
                    x.resize(start + l * m, 0.0);
                    self.mix_into(w, mx, &mut x[start..])?;
                    let (ya, yb) = (&self.y[w * l..(w + 1) * l], &self.y[mx.with * l..(mx.with + 1) * l]);
                    let (ma, mb) = (&self.mask[w * l..(w + 1) * l], &self.mask[mx.with * l..(mx.with + 1) * l]);
                    for (((ya, yb), ma), mb) in ya.iter().zip(yb).zip(ma).zip(mb) {
                        let known = ma.min(*mb);
                        y.push(ya.max(*yb) * known);
                        mask.push(known);
                    }
                }
            }
            if mirrored.get(i).copied().unwrap_or(false) {
                for row in x[start..].chunks_exact_mut(m) {
                    for (v, c) in row.iter_mut().zip(&self.mirror) {
                        if let Some(c) = c {
                            *v = 2.0 * c - *v;
                        }
                    }
                }
            }
        }
        let n_labelled = mask.iter().filter(|&&v| v > 0.0).count();
        Ok(Batch {
            x: Tensor::from_vec(x, (b, l, m), device)?,
            y: Tensor::from_vec(y, (b, l), device)?,
            mask: Tensor::from_vec(mask, (b, l), device)?,
            n_labelled,
        })
    }

    /// The normalised features of window `a` mixed with `mix.with` ([`Windows::batch_augmented`])
    /// into `out` (`l × dim`).
    fn mix_into(&self, a: usize, mix: Mix, out: &mut [f32]) -> Result<()> {
        let norm = match &self.norm {
            Some(norm) if self.can_mix() => norm,
            _ => return Err(NnError::Data { msg: "these windows cannot be mixed (no whitened features)".into() }),
        };
        if !(mix.weight > 0.0 && mix.weight < 1.0) {
            return Err(NnError::Data { msg: format!("mixing weight {} outside (0, 1)", mix.weight) });
        }
        let (l, ch, ctx) = (self.len, norm.channels.len(), norm.features.context());
        let (w, rows) = (2 * ch, ctx + l);
        let (c, s) = (f64::from(mix.weight), (1.0 - f64::from(mix.weight).powi(2)).sqrt());
        let (za, zb) = (
            &self.whitened[a * rows * w..(a + 1) * rows * w],
            &self.whitened[mix.with * rows * w..(mix.with + 1) * rows * w],
        );
        let mut stream = norm.stream();
        let (mut z, mut u) = (vec![0.0f64; ch], vec![0.0f64; ch]);
        let mut row = vec![0.0f64; self.dim];
        // Rows of the window before the flight's first step (front padding), to be filled
        // with the features of the first.
        let mut padding = 0;
        for (k, (ra, rb)) in za.chunks_exact(w).zip(zb.chunks_exact(w)).enumerate() {
            // A row absent from either window (before a flight or padding) is skipped.
            if ra[0].is_nan() || rb[0].is_nan() {
                padding += usize::from(k >= ctx && padding == k - ctx);
                continue;
            }
            let mut nis = 0.0;
            for i in 0..ch {
                z[i] = c * f64::from(ra[i]) + s * f64::from(rb[i]);
                u[i] = c * f64::from(ra[ch + i]) + s * f64::from(rb[ch + i]);
                nis += u[i] * u[i];
            }
            stream.from_whitened(&z, &u, nis, &mut row);
            if let Some(o) = k.checked_sub(ctx) {
                norm.standardise(&row, &mut out[o * self.dim..(o + 1) * self.dim]);
            }
        }
        let (pad_rows, first) = out.split_at_mut(padding * self.dim);
        if let Some(first) = first.get(..self.dim) {
            for o in pad_rows.chunks_exact_mut(self.dim) {
                o.copy_from_slice(first);
            }
        }
        Ok(())
    }
}

/// `z_i = r_i/√(S_k)_ii` (a non-positive variance counts as 1) and `u = L⁻¹ r_k`
/// ([`ResidueStep::decorrelated`]) of one step into `row` (`2m` values); `u = z` where `S_k`
/// is not positive definite.
fn whitened_row(step: &ResidueStep<'_>, row: &mut [f32]) {
    let m = step.dim();
    let mut z = vec![0.0; m];
    whiten_per_channel(step, &mut z);
    let u = step.decorrelated().unwrap_or_else(|| z.clone());
    for (o, v) in row.iter_mut().zip(z.iter().chain(&u)) {
        *o = *v as f32;
    }
}

#[cfg(test)]
mod tests {
    use ekf_residue::LabelledSeries;
    use proptest::prelude::*;

    use super::*;

    fn series(n: usize) -> ResidueSeries {
        let t = (0..n).map(|k| k as f64 * 0.1).collect();
        let r = (0..n).flat_map(|k| [k as f64, -(k as f64)]).collect();
        let s = (0..n).flat_map(|_| [1.0, 0.0, 0.0, 1.0]).collect();
        ResidueSeries::from_flat(t, vec!["a".into(), "b".into()], r, s).unwrap()
    }

    #[test]
    fn starts_cover_the_end_and_pad_short_series() {
        let sw = SeriesWindows::new(25, 10, 7);
        assert_eq!(sw.starts, vec![0, 7, 14, 15]);
        assert_eq!(SeriesWindows::new(25, 10, 30).starts, vec![0, 10, 15]);
        let short = SeriesWindows::new(4, 10, 3);
        assert_eq!((short.pad, short.starts.clone()), (6, vec![0]));
    }

    #[test]
    fn windows_labels_mask_and_normalisation() {
        let s = series(12);
        let labels: Vec<bool> = (0..12).map(|k| k >= 6).collect();
        let split = LabelledResidues::new(vec![
            LabelledSeries::new(s.clone(), Some(labels)).unwrap(),
            LabelledSeries::new(s, None).unwrap(),
        ])
        .unwrap();
        let norm = Normaliser::fit(&split, Features::Raw).unwrap();
        assert!((norm.mean[0] - 5.5).abs() < 1e-12);
        let w =
            Windows::from_split(&split, &norm, &WindowConfig { len: 5, stride: 5, features: Features::Raw }).unwrap();
        // Starts 0, 5, 7 per flight.
        assert_eq!(w.len(), 6);
        assert_eq!(w.n_labelled(), 15);
        assert_eq!(&w.y()[5..10], &[0.0, 1.0, 1.0, 1.0, 1.0]);
        let b = w.batch(&[0, 3], &Device::Cpu).unwrap();
        assert_eq!(b.x.dims(), &[2, 5, 2]);
        assert_eq!(b.n_labelled, 5);
        assert!(w.batch(&[6], &Device::Cpu).is_err());
    }

    /// A one-flight split of `series`, unlabelled.
    fn split_of(series: ResidueSeries) -> LabelledResidues {
        LabelledResidues::new(vec![LabelledSeries::new(series, None).unwrap()]).unwrap()
    }

    /// A two-channel series with correlated `S_k` that varies per step.
    fn series_with_cov(r: &[(f64, f64)], scale: f64) -> ResidueSeries {
        let n = r.len();
        let t = (0..n).map(|k| k as f64 * 0.1).collect();
        let flat = r.iter().flat_map(|&(a, b)| [a * scale, b * scale]).collect();
        let s = (0..n)
            .flat_map(|k| {
                let (a, b) = (1.0 + 0.1 * k as f64, 2.0 + 0.05 * k as f64);
                [a * scale * scale, 0.3 * scale * scale, 0.3 * scale * scale, b * scale * scale]
            })
            .collect();
        ResidueSeries::from_flat(t, vec!["a".into(), "b".into()], flat, s).unwrap()
    }

    #[test]
    fn whitened_features_divide_by_the_innovation_sigma_and_add_sqrt_nis() {
        let s = series_with_cov(&[(2.0, -4.0)], 1.0);
        let step = s.step(0).unwrap();
        let mut out = [0.0f64; 3];
        FeatureStream::new(Features::Whitened, s.channels()).compute(&step, &mut out);
        assert!((out[0] - 2.0).abs() < 1e-12 && (out[1] + 4.0 / 2f64.sqrt()).abs() < 1e-12, "{out:?}");
        assert!((out[2] - step.nis.sqrt()).abs() < 1e-12);
        let mut log = [0.0f64; 3];
        FeatureStream::new(Features::WhitenedLog, s.channels()).compute(&step, &mut log);
        for (l, w) in log.iter().zip(&out) {
            assert!((l - w.signum() * w.abs().ln_1p()).abs() < 1e-12);
        }
    }

    #[test]
    fn a_saved_normaliser_without_features_reads_as_raw() {
        let old = r#"{"channels":["a"],"mean":[0.5],"std":[2.0]}"#;
        let n: Normaliser = serde_json::from_str(old).unwrap();
        assert_eq!((n.features, n.dim()), (Features::Raw, 1));
        n.check().unwrap();
        let bad = Normaliser { std: vec![-1.0], ..n };
        assert!(bad.check().is_err());
        // So does a window configuration saved before the field existed; a new one is whitened.
        let cfg: WindowConfig = serde_json::from_str(r#"{"len":100,"stride":10}"#).unwrap();
        assert_eq!(cfg.features, Features::Raw);
        assert_eq!(WindowConfig::default().features, Features::WhitenedLog);
    }

    #[test]
    fn a_mirrored_window_is_the_window_of_the_negated_residues() {
        let r: Vec<(f64, f64)> =
            (0..12).map(|k| ((k as f64 * 0.7).sin() + 0.3, (k as f64 * 0.3).cos() - 0.2)).collect();
        let neg: Vec<(f64, f64)> = r.iter().map(|&(a, b)| (-a, -b)).collect();
        for features in [
            Features::Raw,
            Features::Whitened,
            Features::WhitenedLog,
            Features::WhitenedLogDrift,
            Features::WhitenedLogDriftAbsorbed,
        ] {
            let norm = Normaliser::fit(&split_of(series_with_cov(&r, 1.0)), features).unwrap();
            let cfg = WindowConfig { len: 4, stride: 4, features };
            let w = Windows::from_split(&split_of(series_with_cov(&r, 1.0)), &norm, &cfg).unwrap();
            let w_neg = Windows::from_split(&split_of(series_with_cov(&neg, 1.0)), &norm, &cfg).unwrap();
            let idx: Vec<usize> = (0..w.len()).collect();
            let mirrored = w.batch_mirrored(&idx, &vec![true; idx.len()], &Device::Cpu).unwrap();
            let a = mirrored.x.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            let b = w_neg.batch(&idx, &Device::Cpu).unwrap().x.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            assert!(a.iter().zip(&b).all(|(u, v)| (u - v).abs() < 1e-5), "{features:?}: {a:?} vs {b:?}");
            let plain = w.batch(&idx, &Device::Cpu).unwrap().x.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            let none =
                w.batch_mirrored(&idx, &[], &Device::Cpu).unwrap().x.flatten_all().unwrap().to_vec1::<f32>().unwrap();
            assert_eq!(plain, none);
        }
    }

    #[test]
    fn a_mixed_window_is_the_window_of_the_weighted_residues() {
        let r: Vec<(f64, f64)> = (0..12).map(|k| ((k as f64 * 0.7).sin() * 3.0, (k as f64 * 0.3).cos())).collect();
        let q: Vec<(f64, f64)> = (0..12).map(|k| ((k as f64 * 0.2).cos(), -(k as f64 * 0.5).sin() * 2.0)).collect();
        let (a, b) = (series_with_cov(&r, 1.0), series_with_cov(&q, 1.0));
        let labels = |from: usize| Some((0..12).map(|k| k >= from).collect::<Vec<bool>>());
        let split = LabelledResidues::new(vec![
            LabelledSeries::new(a, labels(8)).unwrap(),
            LabelledSeries::new(b, labels(3)).unwrap(),
            LabelledSeries::new(series_with_cov(&r, 1.0), None).unwrap(),
        ])
        .unwrap();
        let cfg = WindowConfig { len: 12, stride: 12, features: Features::WhitenedLog };
        let norm = Normaliser::fit(&split, Features::WhitenedLog).unwrap();
        let w = Windows::for_training(&split, &norm, &cfg).unwrap();
        assert!(w.can_mix());
        let flat = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        // A weight near 1 is the window itself, with the other's attacks labelled.
        let one = w.batch_augmented(&[0], &[], &[Some(Mix { with: 1, weight: 0.999_999 })], &Device::Cpu).unwrap();
        let plain = w.batch(&[0], &Device::Cpu).unwrap();
        assert!(flat(&one.x).iter().zip(flat(&plain.x)).all(|(u, v)| (u - v).abs() < 1e-2));
        // Weight c: the features of the series of c·r_a + √(1 − c²)·r_b (same S_k), labels of
        // either, known where both are.
        let c = 0.6f64;
        let s = (1.0 - c * c).sqrt();
        let mixed_r: Vec<(f64, f64)> = r.iter().zip(&q).map(|(x, y)| (c * x.0 + s * y.0, c * x.1 + s * y.1)).collect();
        let want = Windows::from_split(&split_of(series_with_cov(&mixed_r, 1.0)), &norm, &cfg).unwrap();
        let got = w.batch_augmented(&[0], &[], &[Some(Mix { with: 1, weight: c as f32 })], &Device::Cpu).unwrap();
        let (g, e) = (flat(&got.x), flat(&want.batch(&[0], &Device::Cpu).unwrap().x));
        assert!(g.iter().zip(&e).all(|(u, v)| (u - v).abs() < 1e-4), "{g:?} vs {e:?}");
        assert_eq!(flat(&got.y), (0..12).map(|k| if k >= 3 { 1.0 } else { 0.0 }).collect::<Vec<f32>>());
        assert_eq!(got.n_labelled, 12);
        // With an unlabelled window the labels are unknown.
        let half = w.batch_augmented(&[0], &[], &[Some(Mix { with: 2, weight: 0.5 })], &Device::Cpu).unwrap();
        assert_eq!(half.n_labelled, 0);
        assert!(flat(&half.y).iter().all(|&v| v == 0.0), "labels are 0 where unknown");
        // Weights outside (0, 1), raw features and windows not made for training are refused.
        for weight in [0.0, 1.0, f32::NAN] {
            assert!(w.batch_augmented(&[0], &[], &[Some(Mix { with: 1, weight })], &Device::Cpu).is_err());
        }
        let scoring = Windows::from_split(&split, &norm, &cfg).unwrap();
        assert!(!scoring.can_mix());
        let raw_norm = Normaliser::fit(&split, Features::Raw).unwrap();
        let raw = Windows::for_training(&split, &raw_norm, &WindowConfig { features: Features::Raw, ..cfg }).unwrap();
        assert!(!raw.can_mix());
        assert!(raw.batch_augmented(&[0], &[], &[Some(Mix { with: 1, weight: 0.5 })], &Device::Cpu).is_err());
        // A short flight's front padding repeats its first step in the mixed features too, with
        // the labels unknown there.
        let short = |r: &[(f64, f64)]| {
            LabelledSeries::new(series_with_cov(&r[..7], 1.0), labels(8).map(|l| l[..7].to_vec())).unwrap()
        };
        let short_split = LabelledResidues::new(vec![short(&r), short(&q)]).unwrap();
        let sw = Windows::for_training(&short_split, &norm, &cfg).unwrap();
        let mixed = sw.batch_augmented(&[0], &[], &[Some(Mix { with: 1, weight: 0.6 })], &Device::Cpu).unwrap();
        let x = flat(&mixed.x);
        let dim = norm.dim();
        for k in 0..5 {
            assert_eq!(x[k * dim..(k + 1) * dim], x[5 * dim..6 * dim], "padding row {k}");
        }
        assert_eq!(flat(&mixed.mask), (0..12).map(|k| if k >= 5 { 1.0 } else { 0.0 }).collect::<Vec<f32>>());
    }

    /// The drift channel of a mixed window reads the mixed residues of the steps before the
    /// window too: mid-flight, the mix is the window of the mixed flight.
    #[test]
    fn a_mixed_window_carries_the_drift_of_the_steps_before_it() {
        for features in [Features::WhitenedLogDrift, Features::WhitenedLogDriftAbsorbed] {
            // The flights' last windows have more than `Features::context` steps before them.
            let n = features.context() + 50;
            let r: Vec<(f64, f64)> =
                (0..n).map(|k| (0.05 * k as f64 + (k as f64 * 0.7).sin(), (k as f64 * 0.3).cos())).collect();
            let q: Vec<(f64, f64)> = (0..n).map(|k| ((k as f64 * 0.2).cos(), -0.04 * k as f64)).collect();
            mixed_window_is_the_window_of_the_mixed_flight(&r, &q, features);
        }
    }

    fn mixed_window_is_the_window_of_the_mixed_flight(r: &[(f64, f64)], q: &[(f64, f64)], features: Features) {
        let split = LabelledResidues::new(vec![
            LabelledSeries::new(series_with_cov(r, 1.0), None).unwrap(),
            LabelledSeries::new(series_with_cov(q, 1.0), None).unwrap(),
        ])
        .unwrap();
        let cfg = WindowConfig { len: 12, stride: 12, features };
        let norm = Normaliser::fit(&split, features).unwrap();
        let w = Windows::for_training(&split, &norm, &cfg).unwrap();
        assert!(w.can_mix());
        // The flights are as long: window `per − 1` is the first flight's last, window
        // `2·per − 1` the second's, both ending at the flight's last step.
        let per = w.len() / 2;
        let c = 0.6f64;
        let s = (1.0 - c * c).sqrt();
        let mixed_r: Vec<(f64, f64)> = r.iter().zip(q).map(|(x, y)| (c * x.0 + s * y.0, c * x.1 + s * y.1)).collect();
        let want = Windows::from_split(&split_of(series_with_cov(&mixed_r, 1.0)), &norm, &cfg).unwrap();
        let mix = Mix { with: 2 * per - 1, weight: c as f32 };
        let got = w.batch_augmented(&[per - 1], &[], &[Some(mix)], &Device::Cpu).unwrap();
        let flat = |t: &Tensor| t.flatten_all().unwrap().to_vec1::<f32>().unwrap();
        let (g, e) = (flat(&got.x), flat(&want.batch(&[per - 1], &Device::Cpu).unwrap().x));
        assert!(g.iter().zip(&e).all(|(u, v)| (u - v).abs() < 1e-4), "{features:?}: {g:?} vs {e:?}");
        // The last channel (drift or longest sum) is not constant there: the test reads it.
        let dim = norm.dim();
        assert!(e.chunks_exact(dim).any(|row| row[dim - 1] != e[dim - 1]), "{features:?}");
    }

    proptest! {
        /// A consistent filter whose sensors are `c` times noisier reports `c·r` with `c²·S`:
        /// the whitened features, and so every learning method's input, do not change.
        #[test]
        fn whitened_features_ignore_the_noise_level(
            r in proptest::collection::vec((-50.0f64..50.0, -50.0f64..50.0), 1..20),
            c in 0.01f64..100.0,
        ) {
            let (base, scaled) = (series_with_cov(&r, 1.0), series_with_cov(&r, c));
            for features in [
                Features::Whitened,
                Features::WhitenedLog,
                Features::WhitenedLogDrift,
                Features::WhitenedLogDriftAbsorbed,
            ] {
                let (mut sa, mut sb) =
                    (FeatureStream::new(features, base.channels()), FeatureStream::new(features, base.channels()));
                for (a, b) in base.steps().zip(scaled.steps()) {
                    let (mut fa, mut fb) = (vec![0.0f64; features.dim(2)], vec![0.0f64; features.dim(2)]);
                    sa.compute(&a, &mut fa);
                    sb.compute(&b, &mut fb);
                    for (x, y) in fa.iter().zip(&fb) {
                        prop_assert!((x - y).abs() <= 1e-9 * (1.0 + x.abs()), "{:?} vs {:?}", fa, fb);
                    }
                }
            }
        }

        #[test]
        fn stitch_of_step_index_is_identity(n in 1usize..60, l in 2usize..20, stride in 1usize..25) {
            let sw = SeriesWindows::new(n, l, stride);
            let scores: Vec<f32> = sw.starts.iter().flat_map(|&s0| (0..l).map(move |i| (s0 + i) as f32)).collect();
            let out = sw.stitch(&scores).unwrap();
            prop_assert_eq!(out.len(), n);
            for (k, v) in out.iter().enumerate() {
                prop_assert!((v - (k + sw.pad) as f64).abs() < 1e-9);
            }
        }

        /// The newest window is the last of every stride's windows and the only one covering
        /// the last step, so its score there is the stitched score; `push_newest` copies the
        /// rows `push_series` gives that window.
        #[test]
        fn the_newest_window_alone_covers_the_last_step(n in 1usize..60, l in 2usize..20, stride in 1usize..25) {
            let (all, newest) = (SeriesWindows::new(n, l, stride), SeriesWindows::newest(n, l));
            prop_assert_eq!((newest.n_steps, newest.pad, newest.len), (all.n_steps, all.pad, all.len));
            prop_assert_eq!(newest.starts.as_slice(), &all.starts[all.starts.len() - 1..]);
            let last = n + all.pad - 1;
            prop_assert_eq!(all.starts.iter().filter(|&&s0| s0 <= last && last < s0 + l).count(), 1);

            let s = series(n);
            let norm = Normaliser::fit(&split_of(series(80)), Features::WhitenedLog).unwrap();
            let (mut w_all, mut w_new) = (Windows::empty(l, norm.dim()), Windows::empty(l, norm.dim()));
            w_all.push_series(&s, None, &norm, stride).unwrap();
            w_new.push_newest(&s, &norm).unwrap();
            prop_assert_eq!(w_new.len(), 1);
            let rows = l * norm.dim();
            prop_assert_eq!(&w_new.x[..], &w_all.x[w_all.x.len() - rows..]);
        }
    }
}
