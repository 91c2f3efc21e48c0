//! Model-agnostic windowing of labelled residues (paper alg:alg2 input `R ∈ ℝ^{l×m}`).
//!
//! Shared by QUADFormer and the CNN/LSTM baselines so that every learning method sees the same
//! windows, normalisation and stitching.
//!
//! - [`Normaliser`]: per-channel mean and standard deviation of `r_k`, fitted on the training
//!   split only and saved with a model (residue units, e.g. m and rad, become dimensionless).
//! - [`Windows`]: `n_win` windows of `l` steps × `m` channels (row-major `f32`), per-step
//!   labels `y ∈ {0, 1}` and a label-known mask (1 where the flight is labelled and the step is
//!   real, 0 for unlabelled flights and padding). Consecutive windows of a flight start `stride`
//!   steps apart; the last window always ends at the last step, so every step is covered.
//!   A flight shorter than `l` is padded at the front by repeating its first step (mask 0).
//! - [`SeriesWindows::stitch`]: per-window per-step scores back to one score per step of the
//!   series, the mean over all windows that cover the step.

use candle_core::{Device, Tensor};
use ekf_residue::{LabelledResidues, ResidueSeries};
use serde::{Deserialize, Serialize};

use crate::error::{ModelError, Result};

/// Smallest standard deviation treated as non-zero; a constant channel is divided by 1.
const STD_FLOOR: f64 = 1e-12;

/// Window length and stride.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WindowConfig {
    /// Window length `l` in residue steps. Default 100 (Anomaly Transformer `win_size`, the
    /// window of alg:alg2; shared/reference/anomaly-transformer-and-peers.md §2).
    pub len: usize,
    /// Steps between the starts of consecutive training windows. Default 10: chosen on
    /// validation F1 per minute of training (docs/decisions/041-window-stride.md).
    pub stride: usize,
}

impl Default for WindowConfig {
    fn default() -> Self {
        Self { len: 100, stride: 10 }
    }
}

impl WindowConfig {
    /// Checks `len ≥ 2` and `1 ≤ stride`.
    ///
    /// # Errors
    /// [`ModelError::Config`] naming the field.
    pub fn check(&self) -> Result<()> {
        if self.len < 2 {
            return Err(ModelError::Config {
                field: "window.len",
                msg: format!("must be at least 2, got {}", self.len),
            });
        }
        if self.stride == 0 {
            return Err(ModelError::Config { field: "window.stride", msg: "must be at least 1".into() });
        }
        Ok(())
    }
}

/// Per-channel standardisation `(r − μ) / σ`, fitted on training data.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Normaliser {
    /// Channel names, in order.
    pub channels: Vec<String>,
    /// Mean `μ` per channel, residue units.
    pub mean: Vec<f64>,
    /// Standard deviation `σ` per channel, residue units (1 for a constant channel).
    pub std: Vec<f64>,
}

impl Normaliser {
    /// Fits mean and standard deviation of every channel over all steps of `train`.
    ///
    /// # Errors
    /// [`ModelError::Data`] if `train` has no steps.
    pub fn fit(train: &LabelledResidues) -> Result<Self> {
        let m = train.channels().len();
        let n = train.n_steps();
        if n == 0 || m == 0 {
            return Err(ModelError::Data { msg: "cannot fit a normaliser on an empty training split".into() });
        }
        let mut sum = vec![0.0; m];
        let mut sum_sq = vec![0.0; m];
        for f in train.flights() {
            for row in f.series().r().chunks_exact(m) {
                for ((s, q), v) in sum.iter_mut().zip(&mut sum_sq).zip(row) {
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
        Ok(Self { channels: train.channels().to_vec(), mean, std })
    }

    /// Number of channels `m`.
    pub fn dim(&self) -> usize {
        self.channels.len()
    }

    /// Writes the normalised `r_k` into `out` (both of length `m`).
    pub fn apply(&self, r_k: &[f64], out: &mut [f32]) {
        for (((o, v), mu), sd) in out.iter_mut().zip(r_k).zip(&self.mean).zip(&self.std) {
            *o = ((v - mu) / sd) as f32;
        }
    }

    /// Checks that the series has the fitted channels.
    ///
    /// # Errors
    /// [`ModelError::Detect`] with a channel mismatch.
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

    /// Per-step scores of the series: the mean over the covering windows of the
    /// per-window-step scores `window_scores` (`starts.len() × l`, row-major).
    ///
    /// # Errors
    /// [`ModelError::Data`] if `window_scores` has the wrong length.
    pub fn stitch(&self, window_scores: &[f32]) -> Result<Vec<f64>> {
        let l = self.len;
        if window_scores.len() != self.starts.len() * l {
            return Err(ModelError::Data {
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
    x: Vec<f32>,
    y: Vec<f32>,
    mask: Vec<f32>,
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

    /// All training windows of a split, `cfg.stride` apart within each flight.
    ///
    /// # Errors
    /// [`ModelError::Config`] for a bad `cfg`; channel mismatch with `norm`.
    pub fn from_split(data: &LabelledResidues, norm: &Normaliser, cfg: &WindowConfig) -> Result<Self> {
        cfg.check()?;
        let mut out = Self::empty(cfg.len, norm.dim());
        for f in data.flights() {
            out.push_series(f.series(), f.labels(), norm, cfg.stride)?;
        }
        Ok(out)
    }

    /// Appends the windows of one series (labels optional) and returns where they start.
    ///
    /// # Errors
    /// Channel mismatch with `norm`; [`ModelError::Data`] if the labels have the wrong length.
    pub fn push_series(
        &mut self,
        series: &ResidueSeries,
        labels: Option<&[bool]>,
        norm: &Normaliser,
        stride: usize,
    ) -> Result<SeriesWindows> {
        norm.check_series(series)?;
        if norm.dim() != self.dim {
            return Err(ModelError::Data {
                msg: format!("windows have {} channels, normaliser {}", self.dim, norm.dim()),
            });
        }
        if let Some(l) = labels
            && l.len() != series.len()
        {
            return Err(ModelError::Data { msg: format!("{} labels for {} steps", l.len(), series.len()) });
        }
        let (l, m) = (self.len, self.dim);
        let sw = SeriesWindows::new(series.len(), l, stride);
        if sw.starts.is_empty() {
            return Ok(sw);
        }
        // Normalise the (front-padded) series once, then copy windows out of it.
        let n_pad = series.len() + sw.pad;
        let mut xs = vec![0.0f32; n_pad * m];
        let mut ys = vec![0.0f32; n_pad];
        let mut ms = vec![0.0f32; n_pad];
        for k in 0..n_pad {
            let src = k.saturating_sub(sw.pad);
            let r_k = &series.r()[src * m..(src + 1) * m];
            norm.apply(r_k, &mut xs[k * m..(k + 1) * m]);
            if k >= sw.pad
                && let Some(lab) = labels
            {
                ys[k] = if lab[src] { 1.0 } else { 0.0 };
                ms[k] = 1.0;
            }
        }
        for &s0 in &sw.starts {
            self.x.extend_from_slice(&xs[s0 * m..(s0 + l) * m]);
            self.y.extend_from_slice(&ys[s0..s0 + l]);
            self.mask.extend_from_slice(&ms[s0..s0 + l]);
        }
        Ok(sw)
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
    /// [`ModelError::Data`] for an index past the end; [`ModelError::Candle`].
    pub fn batch(&self, idx: &[usize], device: &Device) -> Result<Batch> {
        let (l, m, n) = (self.len, self.dim, self.len());
        let b = idx.len();
        let mut x = Vec::with_capacity(b * l * m);
        let mut y = Vec::with_capacity(b * l);
        let mut mask = Vec::with_capacity(b * l);
        for &w in idx {
            if w >= n {
                return Err(ModelError::Data { msg: format!("window index {w} out of range ({n} windows)") });
            }
            x.extend_from_slice(&self.x[w * l * m..(w + 1) * l * m]);
            y.extend_from_slice(&self.y[w * l..(w + 1) * l]);
            mask.extend_from_slice(&self.mask[w * l..(w + 1) * l]);
        }
        let n_labelled = mask.iter().filter(|&&v| v > 0.0).count();
        Ok(Batch {
            x: Tensor::from_vec(x, (b, l, m), device)?,
            y: Tensor::from_vec(y, (b, l), device)?,
            mask: Tensor::from_vec(mask, (b, l), device)?,
            n_labelled,
        })
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
        let norm = Normaliser::fit(&split).unwrap();
        assert!((norm.mean[0] - 5.5).abs() < 1e-12);
        let w = Windows::from_split(&split, &norm, &WindowConfig { len: 5, stride: 5 }).unwrap();
        // Starts 0, 5, 7 per flight.
        assert_eq!(w.len(), 6);
        assert_eq!(w.n_labelled(), 15);
        assert_eq!(&w.y()[5..10], &[0.0, 1.0, 1.0, 1.0, 1.0]);
        let b = w.batch(&[0, 3], &Device::Cpu).unwrap();
        assert_eq!(b.x.dims(), &[2, 5, 2]);
        assert_eq!(b.n_labelled, 5);
        assert!(w.batch(&[6], &Device::Cpu).is_err());
    }

    proptest! {
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
    }
}
