//! Residue series: the EKF innovations `r_k = y_k − g(x̂_{k|k−1})` with their covariances
//! `S_k = H P_{k|k−1} Hᵀ + R` and normalised innovation squared `NIS_k = r_kᵀ S_k⁻¹ r_k`
//! (paper eq:ekf_update, alg:alg1), plus labelled collections of them for training detectors.
//!
//! Shapes: a series of `n` steps over `m` channels stores `r` as `n × m` and `S` as
//! `n × m × m`, both row-major in flat vectors, so that a step is a pair of contiguous slices.

use nalgebra::{DMatrix, DVectorView};

use crate::error::ResidueError;

/// Tolerance for the symmetry check of `S_k`, relative to its largest entry.
const SYMMETRY_RTOL: f64 = 1e-9;

/// A validated residue sequence of one flight.
///
/// Invariants (checked by [`ResidueSeries::new`]): equal lengths, strictly increasing finite
/// time stamps, finite residues, symmetric positive-definite `S_k` (by Cholesky).
#[derive(Debug, Clone, PartialEq)]
pub struct ResidueSeries {
    t: Vec<f64>,
    channels: Vec<String>,
    r: Vec<f64>,
    s: Vec<f64>,
    nis: Vec<f64>,
}

/// One step of a [`ResidueSeries`], borrowed.
#[derive(Debug, Clone, Copy)]
pub struct ResidueStep<'a> {
    /// Time of the measurement in seconds.
    pub t: f64,
    /// Innovation `r_k`, one entry per channel.
    pub r_k: &'a [f64],
    /// Innovation covariance `S_k`, row-major `m × m`.
    pub s_k: &'a [f64],
    /// Normalised innovation squared `r_kᵀ S_k⁻¹ r_k`.
    pub nis: f64,
}

impl ResidueStep<'_> {
    /// Number of channels `m`.
    pub fn dim(&self) -> usize {
        self.r_k.len()
    }

    /// The residue decorrelated by its whole covariance, `u = L⁻¹ r_k` with `S_k = L Lᵀ`
    /// (Cholesky), so that `|u|² = NIS_k` (the per-channel `r_i/√(S_k)_ii` of the detectors'
    /// features ignores the correlations); `None` if `S_k` is not `m × m` positive definite (a
    /// step of a [`ResidueSeries`] always is).
    pub fn decorrelated(&self) -> Option<Vec<f64>> {
        let m = self.dim();
        if self.s_k.len() != m * m {
            return None;
        }
        let chol = DMatrix::from_row_slice(m, m, self.s_k).cholesky()?;
        let u = chol.l().solve_lower_triangular(&DVectorView::from_slice(self.r_k, m).into_owned())?;
        Some(u.iter().copied().collect())
    }
}

impl ResidueSeries {
    /// Builds a series from time stamps, channel names, residues `r_k` and covariances `S_k`;
    /// computes the NIS of every step.
    ///
    /// # Errors
    /// [`ResidueError`] naming the step and field when lengths differ, time stamps are not
    /// strictly increasing, a value is not finite, or an `S_k` is not symmetric positive
    /// definite.
    pub fn new(
        t: Vec<f64>,
        channels: Vec<String>,
        r: Vec<Vec<f64>>,
        s: Vec<DMatrix<f64>>,
    ) -> Result<Self, ResidueError> {
        let m = channels.len();
        if m == 0 {
            return Err(ResidueError::Dim { what: "channels", expected: 1, got: 0 });
        }
        let n = t.len();
        if r.len() != n {
            return Err(ResidueError::Dim { what: "r (steps)", expected: n, got: r.len() });
        }
        if s.len() != n {
            return Err(ResidueError::Dim { what: "S (steps)", expected: n, got: s.len() });
        }
        let mut r_flat = Vec::with_capacity(n * m);
        let mut s_flat = Vec::with_capacity(n * m * m);
        for (step_idx, (r_k, s_k)) in r.iter().zip(&s).enumerate() {
            if r_k.len() != m {
                return Err(ResidueError::StepDim { step_idx, what: "r_k", expected: m, got: r_k.len() });
            }
            if s_k.nrows() != m || s_k.ncols() != m {
                return Err(ResidueError::StepDim {
                    step_idx,
                    what: "S_k",
                    expected: m,
                    got: s_k.nrows().max(s_k.ncols()),
                });
            }
            r_flat.extend_from_slice(r_k);
            // Row-major copy of S_k.
            for i in 0..m {
                for j in 0..m {
                    s_flat.push(s_k[(i, j)]);
                }
            }
        }
        Self::from_flat(t, channels, r_flat, s_flat)
    }

    /// Builds a series from flat row-major buffers: `r` is `n × m`, `s` is `n × m × m`.
    ///
    /// # Errors
    /// As [`ResidueSeries::new`].
    pub fn from_flat(t: Vec<f64>, channels: Vec<String>, r: Vec<f64>, s: Vec<f64>) -> Result<Self, ResidueError> {
        let m = channels.len();
        if m == 0 {
            return Err(ResidueError::Dim { what: "channels", expected: 1, got: 0 });
        }
        let n = t.len();
        if r.len() != n * m {
            return Err(ResidueError::Dim { what: "r (flat)", expected: n * m, got: r.len() });
        }
        if s.len() != n * m * m {
            return Err(ResidueError::Dim { what: "S (flat)", expected: n * m * m, got: s.len() });
        }
        let mut nis = Vec::with_capacity(n);
        for step_idx in 0..n {
            let t_prev = step_idx.checked_sub(1).map(|i| t[i]);
            let (r_k, s_k) = (&r[step_idx * m..(step_idx + 1) * m], &s[step_idx * m * m..(step_idx + 1) * m * m]);
            nis.push(checked_step_nis(step_idx, m, t_prev, t[step_idx], r_k, s_k)?);
        }
        Ok(Self { t, channels, r, s, nis })
    }

    /// A series of steps each already checked by [`checked_step_nis`] in this order, with
    /// their NIS: what a streaming window holds. Lengths must agree (`debug_assert`ed).
    pub(crate) fn from_checked(t: Vec<f64>, channels: Vec<String>, r: Vec<f64>, s: Vec<f64>, nis: Vec<f64>) -> Self {
        let (n, m) = (t.len(), channels.len());
        debug_assert!(r.len() == n * m && s.len() == n * m * m && nis.len() == n);
        Self { t, channels, r, s, nis }
    }

    /// Number of steps `n`.
    pub fn len(&self) -> usize {
        self.t.len()
    }

    /// True when the series has no steps.
    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }

    /// Number of channels `m`.
    pub fn dim(&self) -> usize {
        self.channels.len()
    }

    /// Time stamps in seconds.
    pub fn t(&self) -> &[f64] {
        &self.t
    }

    /// Channel names, e.g. `["gps_x", "gps_y", "gps_z", "att_roll", "att_pitch", "att_yaw"]`.
    pub fn channels(&self) -> &[String] {
        &self.channels
    }

    /// All residues, row-major `n × m`.
    pub fn r(&self) -> &[f64] {
        &self.r
    }

    /// All covariances, row-major `n × m × m`.
    pub fn s(&self) -> &[f64] {
        &self.s
    }

    /// NIS of every step.
    pub fn nis(&self) -> &[f64] {
        &self.nis
    }

    /// Residue `r_k` of step `k`, or `None` past the end.
    pub fn r_k(&self, k: usize) -> Option<&[f64]> {
        let m = self.dim();
        self.r.get(k * m..(k + 1) * m)
    }

    /// Covariance `S_k` of step `k` as an `m × m` matrix, or `None` past the end.
    pub fn s_k(&self, k: usize) -> Option<DMatrix<f64>> {
        let m = self.dim();
        self.s.get(k * m * m..(k + 1) * m * m).map(|s| DMatrix::from_row_slice(m, m, s))
    }

    /// Borrowed view of step `k`, or `None` past the end.
    pub fn step(&self, k: usize) -> Option<ResidueStep<'_>> {
        let m = self.dim();
        Some(ResidueStep {
            t: *self.t.get(k)?,
            r_k: self.r.get(k * m..(k + 1) * m)?,
            s_k: self.s.get(k * m * m..(k + 1) * m * m)?,
            nis: self.nis[k],
        })
    }

    /// Iterates over all steps in time order.
    pub fn steps(&self) -> impl Iterator<Item = ResidueStep<'_>> {
        (0..self.len()).filter_map(|k| self.step(k))
    }

    /// A new series restricted to the named channels, in the given order: the sub-vector of
    /// every `r_k` and the matching sub-block of every `S_k` (the NIS is recomputed).
    ///
    /// # Errors
    /// [`ResidueError::UnknownChannel`] if a name is not a channel of this series.
    pub fn select_channels(&self, names: &[&str]) -> Result<Self, ResidueError> {
        let idx = names
            .iter()
            .map(|name| {
                self.channels.iter().position(|c| c == name).ok_or_else(|| ResidueError::UnknownChannel {
                    name: (*name).to_owned(),
                    available: self.channels.clone(),
                })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let (m, m_new, n) = (self.dim(), idx.len(), self.len());
        let mut r = Vec::with_capacity(n * m_new);
        let mut s = Vec::with_capacity(n * m_new * m_new);
        for k in 0..n {
            for &i in &idx {
                r.push(self.r[k * m + i]);
            }
            for &i in &idx {
                for &j in &idx {
                    s.push(self.s[k * m * m + i * m + j]);
                }
            }
        }
        let channels = names.iter().map(|s| (*s).to_owned()).collect();
        Self::from_flat(self.t.clone(), channels, r, s)
    }

    /// The steps `range` of this series as a new series.
    ///
    /// # Errors
    /// [`ResidueError::Dim`] if the range reaches past the end.
    pub fn slice(&self, range: std::ops::Range<usize>) -> Result<Self, ResidueError> {
        if range.end > self.len() || range.start > range.end {
            return Err(ResidueError::Dim { what: "slice end", expected: self.len(), got: range.end });
        }
        let m = self.dim();
        Ok(Self {
            t: self.t[range.clone()].to_vec(),
            channels: self.channels.clone(),
            r: self.r[range.start * m..range.end * m].to_vec(),
            s: self.s[range.start * m * m..range.end * m * m].to_vec(),
            nis: self.nis[range].to_vec(),
        })
    }
}

/// Checks one step as [`ResidueSeries::from_flat`] checks its step `step_idx` of `m` channels
/// when the step before is at `t_prev`, and returns its NIS `r_kᵀ S_k⁻¹ r_k`. In this order:
/// at least one channel, a finite time `t` after `t_prev`, `m` finite residues `r_k`, and a
/// finite, symmetric, positive definite `m × m` covariance `s_k` (row-major). A streaming detector checks each
/// new step once with it, and so never checks its window again.
///
/// # Errors
/// The first failed check, as a [`ResidueError`] naming `step_idx` and the field.
pub fn checked_step_nis(
    step_idx: usize,
    m: usize,
    t_prev: Option<f64>,
    t: f64,
    r_k: &[f64],
    s_k: &[f64],
) -> Result<f64, ResidueError> {
    if m == 0 {
        return Err(ResidueError::Dim { what: "channels", expected: 1, got: 0 });
    }
    if !t.is_finite() {
        return Err(ResidueError::NonFinite { step_idx, what: "t" });
    }
    if let Some(t_prev) = t_prev
        && t <= t_prev
    {
        return Err(ResidueError::Unordered { step_idx, t_prev, t });
    }
    if r_k.len() != m {
        return Err(ResidueError::StepDim { step_idx, what: "r_k", expected: m, got: r_k.len() });
    }
    if s_k.len() != m * m {
        return Err(ResidueError::StepDim { step_idx, what: "S_k (flat)", expected: m * m, got: s_k.len() });
    }
    if r_k.iter().any(|v| !v.is_finite()) {
        return Err(ResidueError::NonFinite { step_idx, what: "r_k" });
    }
    checked_nis(step_idx, r_k, DMatrix::from_row_slice(m, m, s_k))
}

/// Checks that `S_k` is finite, symmetric and positive definite, and returns `r_kᵀ S_k⁻¹ r_k`.
fn checked_nis(step_idx: usize, r_k: &[f64], s_k: DMatrix<f64>) -> Result<f64, ResidueError> {
    if s_k.iter().any(|v| !v.is_finite()) {
        return Err(ResidueError::NonFinite { step_idx, what: "S_k" });
    }
    let scale = s_k.amax().max(f64::MIN_POSITIVE);
    if (&s_k - s_k.transpose()).amax() > SYMMETRY_RTOL * scale {
        return Err(ResidueError::NotSymmetric { step_idx });
    }
    let chol = s_k.cholesky().ok_or(ResidueError::NotPositiveDefinite { step_idx })?;
    let r = DVectorView::from_slice(r_k, r_k.len());
    let x = chol.solve(&r.into_owned());
    Ok(r.dot(&x))
}

/// One flight's residues with optional per-step attack labels (`None` for an unlabelled
/// flight, as in semi-supervised training).
#[derive(Debug, Clone, PartialEq)]
pub struct LabelledSeries {
    series: ResidueSeries,
    labels: Option<Vec<bool>>,
}

impl LabelledSeries {
    /// Pairs a series with its labels.
    ///
    /// # Errors
    /// [`ResidueError::Dim`] if there is not one label per step.
    pub fn new(series: ResidueSeries, labels: Option<Vec<bool>>) -> Result<Self, ResidueError> {
        if let Some(l) = &labels
            && l.len() != series.len()
        {
            return Err(ResidueError::Dim { what: "labels", expected: series.len(), got: l.len() });
        }
        Ok(Self { series, labels })
    }

    /// The residues.
    pub fn series(&self) -> &ResidueSeries {
        &self.series
    }

    /// Per-step labels (`true` = attacked), if known.
    pub fn labels(&self) -> Option<&[bool]> {
        self.labels.as_deref()
    }

    /// The same flight with its labels hidden.
    pub fn unlabelled(&self) -> Self {
        Self { series: self.series.clone(), labels: None }
    }
}

/// A split (train, validation or test) of labelled flights sharing one channel set.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct LabelledResidues {
    flights: Vec<LabelledSeries>,
}

impl LabelledResidues {
    /// Collects flights into a split.
    ///
    /// # Errors
    /// [`ResidueError::ChannelMismatch`] if the flights do not all have the same channels.
    pub fn new(flights: Vec<LabelledSeries>) -> Result<Self, ResidueError> {
        if let Some(first) = flights.first() {
            for f in &flights[1..] {
                if f.series.channels() != first.series.channels() {
                    return Err(ResidueError::ChannelMismatch {
                        expected: first.series.channels().to_vec(),
                        got: f.series.channels().to_vec(),
                    });
                }
            }
        }
        Ok(Self { flights })
    }

    /// The flights of this split.
    pub fn flights(&self) -> &[LabelledSeries] {
        &self.flights
    }

    /// The common channel names (empty for an empty split).
    pub fn channels(&self) -> &[String] {
        self.flights.first().map(|f| f.series.channels()).unwrap_or(&[])
    }

    /// Total number of residue steps over all flights.
    pub fn n_steps(&self) -> usize {
        self.flights.iter().map(|f| f.series.len()).sum()
    }

    /// Flights whose labels are known.
    pub fn labelled(&self) -> impl Iterator<Item = (&ResidueSeries, &[bool])> {
        self.flights.iter().filter_map(|f| f.labels().map(|l| (&f.series, l)))
    }

    /// A new split restricted to the named channels.
    ///
    /// # Errors
    /// As [`ResidueSeries::select_channels`].
    pub fn select_channels(&self, names: &[&str]) -> Result<Self, ResidueError> {
        let flights = self
            .flights
            .iter()
            .map(|f| Ok(LabelledSeries { series: f.series.select_channels(names)?, labels: f.labels.clone() }))
            .collect::<Result<Vec<_>, ResidueError>>()?;
        Ok(Self { flights })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn series(t: Vec<f64>, r: Vec<Vec<f64>>) -> Result<ResidueSeries, ResidueError> {
        let n = r.len();
        ResidueSeries::new(t, vec!["a".into(), "b".into()], r, vec![DMatrix::from_diagonal_element(2, 2, 4.0); n])
    }

    #[test]
    fn decorrelated_residue_has_the_nis_as_squared_norm() {
        let s = ResidueSeries::from_flat(
            vec![0.0],
            vec!["a".into(), "b".into()],
            vec![1.5, -0.5],
            vec![2.0, 0.6, 0.6, 1.0],
        )
        .unwrap();
        let step = s.step(0).unwrap();
        let u = step.decorrelated().unwrap();
        assert!((u.iter().map(|v| v * v).sum::<f64>() - step.nis).abs() < 1e-12);
        // L is lower triangular: the first entry is r₀/√S₀₀.
        assert!((u[0] - 1.5 / 2f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn nis_is_mahalanobis() {
        let s = series(vec![0.0, 0.1], vec![vec![2.0, 0.0], vec![2.0, 2.0]]).unwrap();
        assert_eq!(s.nis(), &[1.0, 2.0]);
        assert_eq!(s.r_k(1), Some(&[2.0, 2.0][..]));
    }

    #[test]
    fn bad_input_is_named() {
        let e = series(vec![0.0, 0.0], vec![vec![0.0, 0.0], vec![0.0, 0.0]]).unwrap_err();
        assert!(matches!(e, ResidueError::Unordered { step_idx: 1, .. }), "{e}");
        let e = series(vec![0.0, 0.1], vec![vec![0.0, f64::NAN], vec![0.0, 0.0]]).unwrap_err();
        assert!(matches!(e, ResidueError::NonFinite { step_idx: 0, what: "r_k" }), "{e}");
        let e = series(vec![0.0], vec![vec![0.0]]).unwrap_err();
        assert!(matches!(e, ResidueError::StepDim { step_idx: 0, what: "r_k", .. }), "{e}");
        let bad_s = DMatrix::from_row_slice(2, 2, &[1.0, 2.0, 2.0, 1.0]);
        let e =
            ResidueSeries::new(vec![0.0], vec!["a".into(), "b".into()], vec![vec![0.0, 0.0]], vec![bad_s]).unwrap_err();
        assert!(matches!(e, ResidueError::NotPositiveDefinite { step_idx: 0 }), "{e}");
    }

    #[test]
    fn select_channels_takes_sub_block() {
        let s_k = DMatrix::from_row_slice(2, 2, &[4.0, 1.0, 1.0, 9.0]);
        let s = ResidueSeries::new(vec![0.0], vec!["a".into(), "b".into()], vec![vec![1.0, 3.0]], vec![s_k]).unwrap();
        let b = s.select_channels(&["b"]).unwrap();
        assert_eq!(b.r(), &[3.0]);
        assert_eq!(b.s(), &[9.0]);
        assert_eq!(b.nis(), &[1.0]);
        assert!(matches!(s.select_channels(&["c"]), Err(ResidueError::UnknownChannel { .. })));
    }
}
