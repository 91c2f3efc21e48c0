//! What a learning method reads at each residue step: the feature map ([`Features`]) and its
//! step-by-step evaluation over a series ([`FeatureStream`]).
//!
//! - [`Features::Raw`]: `r_k` itself.
//! - [`Features::Whitened`]: the residue whitened by what the filter already knows,
//!   `z_i = r_i / √(S_k)_ii`, plus the Mahalanobis norm `√NIS_k` as one more channel; a
//!   correctly configured change of sensor noise then leaves the input distribution unchanged
//!   (docs/decisions/044-whitened-inputs.md).
//! - [`Features::WhitenedLog`] (the default): the same, each value compressed by
//!   `sign(x)·ln(1 + |x|)`.
//! - [`Features::WhitenedLogDrift`]: [`Features::WhitenedLog`] and one more channel, the GLR
//!   evidence of a constant or growing offset on the GPS channels over the last
//!   [`DRIFT_WINDOW`] steps (`ekf_residue::drift`), as `ln(1 + √g_k)`. A slow spoofed drift
//!   stays within a few σ at every step, where a window of per-step features shows the network
//!   little; the GLR sums gather its evidence over the steps (docs/decisions/094-drift-channel.md).
//!   It reads the GPS entries of the residue decorrelated by its whole covariance,
//!   `u = L⁻¹ r_k`, unit-variance white noise on clean steps. Where the GPS channels come
//!   first (Model I) they are the GPS innovation whitened by its own block, as the GLR drift
//!   test reads it; where they follow the VO channels (Model II) they are the GPS innovation
//!   conditioned on the VO innovation, which a GPS spoof leaves clean.
//! - [`Features::WhitenedLogDriftAbsorbed`]: [`Features::WhitenedLogDrift`] and the
//!   absorbed-offset channels `ln(1 + a_k(H))` for each horizon of [`ABSORBED_HORIZONS`]: the
//!   norm of the sum of the same `u` over the newest `H` steps, divided by `√H`
//!   (`ekf_residue::absorbed`). A filter absorbs a spoofed offset within a few fixes, and in a
//!   window an onset and an end then look alike; the long sums remember the onset until the
//!   end cancels it (docs/decisions/095-absorbed-offset-channels.md).
//!
//! The drift and absorbed-offset channels depend on the steps before, so features are computed by a
//! [`FeatureStream`] fed the steps of one series in order; the other maps are per step. A
//! detector that re-scores a window from its first step (`ekf_residue::WindowedOnline`) gives
//! the window's first [`Features::context`] steps a shorter history than the flight had.

use ekf_residue::ResidueStep;
use ekf_residue::absorbed::AbsorbedSums;
use ekf_residue::drift::{DriftMemory, END_STEPS, LEVEL_STEPS};
use serde::{Deserialize, Serialize};

/// Longest onset of the drift channel, steps (3 s of GPS fixes at 10 Hz, the textbook window
/// of the GLR drift test, docs/decisions/093-glr-drift-test.md).
pub const DRIFT_WINDOW: usize = 30;

/// Horizons of the absorbed-offset channels, steps: 10, 20 and 40 s of GPS fixes at 10 Hz.
/// The longest is as long as the longest Attack II interval (docs/decisions/030), so the end
/// of any shorter attack finds its onset within it; the shorter ones tell a recent onset from
/// an old one.
pub const ABSORBED_HORIZONS: [usize; 3] = [100, 200, 400];

/// Huber's clipping constant of the drift channel, in standard deviations (as the GLR test).
const DRIFT_HUBER_C: f64 = 2.0;

/// Prefix of the channels the drift channel reads (the GPS channels of `ekf_residue`); a series
/// without such channels reads all of them.
const DRIFT_CHANNEL_PREFIX: &str = "gps_";

/// What a learning method reads at each residue step (module docs).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default, Serialize, Deserialize)]
pub enum Features {
    /// The innovation `r_k` as it is (m, rad); the only map before whitened inputs existed, so
    /// a saved normaliser without the field reads as this.
    Raw,
    /// `r_i / √(S_k)_ii` per channel and `√NIS_k`: `m + 1` features, unit scale on clean steps.
    Whitened,
    /// [`Features::Whitened`] with every value compressed by `sign(x)·ln(1 + |x|)`, so that
    /// attacks of tens of σ stay within a few units (the default).
    #[default]
    WhitenedLog,
    /// [`Features::WhitenedLog`] and the drift channel `ln(1 + √g_k)`: `m + 2` features.
    WhitenedLogDrift,
    /// [`Features::WhitenedLogDrift`] and the absorbed-offset channels `ln(1 + a_k(H))`, one
    /// per horizon of [`ABSORBED_HORIZONS`]: `m + 2 + 3` features.
    WhitenedLogDriftAbsorbed,
}

impl Features {
    /// Number of features for `m` residue channels.
    pub fn dim(self, m: usize) -> usize {
        match self {
            Features::Raw => m,
            Features::Whitened | Features::WhitenedLog => m + 1,
            Features::WhitenedLogDrift => m + 2,
            Features::WhitenedLogDriftAbsorbed => m + 2 + ABSORBED_HORIZONS.len(),
        }
    }

    /// Whether the features of a step are a function of its whitened residue
    /// `z_i = r_i/√(S_k)_ii`, its decorrelated residue `u = L⁻¹ r_k` and `NIS_k` (and, for the
    /// drift channel, those of the steps before), which is what mixing two windows needs
    /// (`Windows::batch_augmented`).
    pub fn is_whitened(self) -> bool {
        self != Features::Raw
    }

    /// Steps before a step whose residues its features read: 0 for the per-step maps; for the
    /// drift channel the drift window and the end test's steps (`ekf_residue::drift`), beyond
    /// which the channel depends on earlier steps only through rare end-test clears; for the
    /// absorbed-offset channels the longest horizon.
    pub fn context(self) -> usize {
        let drift = DRIFT_WINDOW + END_STEPS + LEVEL_STEPS;
        match self {
            Features::WhitenedLogDrift => drift,
            Features::WhitenedLogDriftAbsorbed => drift.max(ABSORBED_HORIZONS.iter().copied().max().unwrap_or(0)),
            _ => 0,
        }
    }

    /// Whether the map has the drift channel (and reads the GPS entries of `u`).
    fn has_drift(self) -> bool {
        matches!(self, Features::WhitenedLogDrift | Features::WhitenedLogDriftAbsorbed)
    }

    /// Whether feature `i` of `m` residue channels changes sign with the residue,
    /// `r_k → −r_k` (the whitened channels), rather than staying as it is (`√NIS`, drift,
    /// absorbed offset: norms).
    pub fn is_odd(self, i: usize, m: usize) -> bool {
        i < m
    }
}

/// The feature map evaluated over the steps of one series, in order: the drift channel's and
/// the absorbed-offset channels' memories, for the maps that have them.
#[derive(Debug, Clone, PartialEq)]
pub struct FeatureStream {
    features: Features,
    /// The drift memory and the channels it reads.
    drift: Option<(DriftMemory, Vec<usize>)>,
    /// The absorbed-offset sums (of the drift channel's channels) and their newest values.
    absorbed: Option<(AbsorbedSums, Vec<f64>)>,
    /// The read channels' values of a step.
    picked: Vec<f64>,
}

impl FeatureStream {
    /// A stream at the start of a series of `channels`.
    pub fn new(features: Features, channels: &[String]) -> Self {
        let drift = features.has_drift().then(|| {
            let mut idx: Vec<usize> = channels
                .iter()
                .enumerate()
                .filter(|(_, c)| c.starts_with(DRIFT_CHANNEL_PREFIX))
                .map(|(i, _)| i)
                .collect();
            if idx.is_empty() {
                idx = (0..channels.len()).collect();
            }
            (DriftMemory::new(DRIFT_WINDOW, idx.len(), DRIFT_HUBER_C), idx)
        });
        let absorbed = match (&drift, features) {
            (Some((_, idx)), Features::WhitenedLogDriftAbsorbed) => {
                Some((AbsorbedSums::new(&ABSORBED_HORIZONS, idx.len()), vec![0.0; ABSORBED_HORIZONS.len()]))
            }
            _ => None,
        };
        Self { features, drift, absorbed, picked: Vec::new() }
    }

    /// Back to the start of a series.
    pub fn reset(&mut self) {
        if let Some((memory, _)) = &mut self.drift {
            memory.clear();
        }
        if let Some((sums, _)) = &mut self.absorbed {
            sums.clear();
        }
    }

    /// Writes the features of the next step of the series into `out` (length
    /// [`Features::dim`]). A non-positive variance counts as 1; where `S_k` is not positive
    /// definite the drift channel reads `z` for `u`.
    pub fn compute(&mut self, step: &ResidueStep<'_>, out: &mut [f64]) {
        let m = step.dim();
        if self.features == Features::Raw {
            for (o, r) in out.iter_mut().zip(step.r_k) {
                *o = *r;
            }
            return;
        }
        whiten_per_channel(step, out);
        let drift = if self.drift.is_some() {
            let u = step.decorrelated().unwrap_or_else(|| out.iter().take(m).copied().collect());
            self.drift_of(&u)
        } else {
            0.0
        };
        self.finish_whitened(m, step.nis, drift, out);
    }

    /// Writes the features of the next step from its whitened residue `z`, decorrelated
    /// residue `u` (`m` values each) and `NIS_k` into `out` (length [`Features::dim`]); the
    /// same as [`FeatureStream::compute`] for a step with those values. Leaves `out` untouched
    /// for [`Features::Raw`], which is not a function of them.
    pub fn from_whitened(&mut self, z: &[f64], u: &[f64], nis: f64, out: &mut [f64]) {
        if !self.features.is_whitened() {
            return;
        }
        for (o, v) in out.iter_mut().zip(z) {
            *o = *v;
        }
        let drift = if self.drift.is_some() { self.drift_of(u) } else { 0.0 };
        self.finish_whitened(z.len(), nis, drift, out);
    }

    /// Adds the step's decorrelated residue `u` to the drift memory and returns `g_k`; a
    /// non-finite `u` is not kept and reads 0. Adds it to the absorbed-offset sums too, whose
    /// newest values `a_k(H)` [`FeatureStream::finish_whitened`] reads.
    fn drift_of(&mut self, u: &[f64]) -> f64 {
        let Some((memory, idx)) = &mut self.drift else { return 0.0 };
        self.picked.clear();
        self.picked.extend(idx.iter().map(|&i| u.get(i).copied().unwrap_or(0.0)));
        if let Some((sums, newest)) = &mut self.absorbed {
            sums.push(&self.picked, newest);
        }
        if self.picked.iter().all(|v| v.is_finite()) { memory.push(&self.picked) } else { 0.0 }
    }

    /// `√NIS_k`, `√g_k` and the `a_k(H)` after the `m` whitened channels, then the compression
    /// of [`Features::WhitenedLog`].
    fn finish_whitened(&self, m: usize, nis: f64, drift: f64, out: &mut [f64]) {
        if let Some(slot) = out.get_mut(m) {
            *slot = nis.max(0.0).sqrt();
        }
        if self.features.has_drift()
            && let Some(slot) = out.get_mut(m + 1)
        {
            *slot = drift.max(0.0).sqrt();
        }
        if let Some((_, newest)) = &self.absorbed {
            for (slot, a) in out.iter_mut().skip(m + 2).zip(newest) {
                *slot = *a;
            }
        }
        if self.features != Features::Whitened {
            for o in out.iter_mut() {
                *o = o.signum() * o.abs().ln_1p();
            }
        }
    }
}

/// `z_i = r_i / √(S_k)_ii` of each channel of `step` into `out` (as many as both hold); a
/// non-positive variance counts as 1.
pub(crate) fn whiten_per_channel(step: &ResidueStep<'_>, out: &mut [f64]) {
    let m = step.dim();
    for (i, (o, r)) in out.iter_mut().zip(step.r_k).enumerate() {
        let var = step.s_k.get(i * m + i).copied().unwrap_or(1.0);
        *o = if var > 0.0 { r / var.sqrt() } else { *r };
    }
}

#[cfg(test)]
mod tests {
    use ekf_residue::ResidueSeries;

    use super::*;

    /// A series of `n` steps on channels `gps_x, gps_y, baro` with unit covariance and a drift
    /// of 0.2 σ per step on `gps_x` from step `onset`.
    fn drifting(n: usize, onset: usize) -> ResidueSeries {
        let t = (0..n).map(|k| k as f64 * 0.1).collect();
        let r = (0..n).flat_map(|k| [0.2 * k.saturating_sub(onset) as f64, 0.0, 0.0]).collect();
        let s = (0..n).flat_map(|_| [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]).collect();
        let channels = vec!["gps_x".into(), "gps_y".into(), "baro".into()];
        ResidueSeries::from_flat(t, channels, r, s).unwrap()
    }

    #[test]
    fn the_drift_channel_grows_with_a_drift_and_reads_zero_without() {
        let series = drifting(50, 20);
        let mut stream = FeatureStream::new(Features::WhitenedLogDrift, series.channels());
        let mut out = vec![0.0; Features::WhitenedLogDrift.dim(3)];
        let drift: Vec<f64> = series
            .steps()
            .map(|step| {
                stream.compute(&step, &mut out);
                out[4]
            })
            .collect();
        assert!(drift[..=20].iter().all(|&d| d == 0.0), "{drift:?}");
        assert!(drift[21..].windows(2).all(|w| w[1] > w[0]), "{drift:?}");
        // The per-step features are those of WhitenedLog.
        let mut log = vec![0.0; 4];
        let mut plain = FeatureStream::new(Features::WhitenedLog, series.channels());
        plain.compute(&series.step(49).unwrap(), &mut log);
        assert_eq!(&out[..4], &log[..]);
        // A reset stream computes the series again from its start.
        stream.reset();
        stream.compute(&series.step(0).unwrap(), &mut out);
        assert_eq!(out[4], 0.0);
    }

    /// The absorbed-offset channels follow the drift map's channels and read `ln(1 + a_k(H))`
    /// of the GPS channels; a jump in the GPS residue is remembered by them.
    #[test]
    fn the_absorbed_channels_extend_the_drift_map() {
        let series = drifting(50, 20);
        let features = Features::WhitenedLogDriftAbsorbed;
        assert_eq!(features.dim(3), 3 + 2 + ABSORBED_HORIZONS.len());
        assert!(!features.is_odd(5, 3));
        let (mut stream, mut drift) = (
            FeatureStream::new(features, series.channels()),
            FeatureStream::new(Features::WhitenedLogDrift, series.channels()),
        );
        let (mut out, mut prefix) = (vec![0.0; features.dim(3)], vec![0.0; 5]);
        let mut sums = AbsorbedSums::new(&ABSORBED_HORIZONS, 2);
        let mut a = vec![0.0; ABSORBED_HORIZONS.len()];
        for step in series.steps() {
            stream.compute(&step, &mut out);
            drift.compute(&step, &mut prefix);
            assert_eq!(&out[..5], &prefix[..]);
            sums.push(&step.r_k[..2], &mut a);
            for (o, a) in out[5..].iter().zip(&a) {
                assert!((o - a.ln_1p()).abs() < 1e-12, "{out:?}");
            }
        }
        assert!(out[5] > 1.0, "{out:?}");
        // A reset stream starts the sums again.
        stream.reset();
        let mut fresh = FeatureStream::new(features, series.channels());
        let mut first = vec![0.0; features.dim(3)];
        stream.compute(&series.step(30).unwrap(), &mut out);
        fresh.compute(&series.step(30).unwrap(), &mut first);
        assert_eq!(out, first);
    }

    #[test]
    fn from_whitened_equals_compute_step_by_step() {
        let series = drifting(50, 5);
        for features in [Features::WhitenedLogDrift, Features::WhitenedLogDriftAbsorbed] {
            let (mut a, mut b) =
                (FeatureStream::new(features, series.channels()), FeatureStream::new(features, series.channels()));
            let (mut x, mut y) = (vec![0.0; features.dim(3)], vec![0.0; features.dim(3)]);
            for step in series.steps() {
                a.compute(&step, &mut x);
                let u = step.decorrelated().unwrap();
                b.from_whitened(&u, &u, step.nis, &mut y);
                assert_eq!(x, y);
            }
        }
    }

    /// A step of more channels than the output holds, with a covariance that is not positive
    /// definite or not finite, gives finite features and no panic.
    #[test]
    fn a_malformed_step_does_not_panic() {
        let channels: Vec<String> = vec!["gps_x".into(), "gps_y".into()];
        let mut stream = FeatureStream::new(Features::WhitenedLogDriftAbsorbed, &channels);
        for s_k in [[0.0; 9], [f64::NAN; 9]] {
            let step = ResidueStep { t: 0.0, r_k: &[1.0, 2.0, 3.0], s_k: &s_k, nis: 1.0 };
            let mut out = [0.0; 2];
            stream.compute(&step, &mut out);
            let mut short = [0.0; 1];
            stream.from_whitened(&[1.0, 2.0, 3.0], &[f64::NAN], 1.0, &mut short);
        }
    }
}
