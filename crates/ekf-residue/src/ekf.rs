//! Generic extended Kalman filter over nalgebra static matrices: prediction (paper
//! eq:ekf_predict) and update (eq:ekf_update) with a Joseph-form or standard covariance update.
//!
//! Shapes: state `x ∈ ℝᴺ`, covariance `P ∈ ℝᴺˣᴺ`, measurement `y ∈ ℝᴹ` with Jacobian
//! `H = ∇ₓg ∈ ℝᴹˣᴺ` and noise covariance `R ∈ ℝᴹˣᴹ`. The model-specific parts (the state
//! propagation `f`, the innovation `r_k = y_k − g(x̂_{k|k−1})` with its angle wrapping, and the
//! Jacobians) live in the Model I and Model II filters; this type owns `x̂`, `P`, the numerics
//! and the failure checks:
//!
//! - the innovation covariance `S_k` is factorised by Cholesky; failure is
//!   [`FilterError::NotPositiveDefinite`];
//! - non-finite state or covariance is [`FilterError::NonFiniteState`];
//! - divergence ([`DivergenceGuard`]) is [`FilterError::Diverged`]: `trace(P)` above
//!   `max_trace_p`, or `max_absurd_updates` consecutive updates with NIS above `nis_absurd`.

use nalgebra::{Cholesky, DMatrix, DVector, SMatrix, SVector};
use serde::{Deserialize, Serialize};

use crate::error::FilterError;

/// Covariance update form of eq:ekf_update.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
pub enum CovarianceUpdate {
    /// Joseph form `P = (I − K H) P (I − K H)ᵀ + K R Kᵀ`: symmetric PSD by construction,
    /// valid for any gain (Bar-Shalom et al. 2001, eq. 5.2.3-18). Default.
    #[default]
    Joseph,
    /// Standard form `P = P − K H P` as printed in eq:ekf_update (cheaper, loses symmetry and
    /// definiteness through rounding).
    Standard,
}

/// Divergence criteria of the EKF (documented defaults; a diverging filter is an error).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DivergenceGuard {
    /// Largest admissible `trace(P)` (mixed units m², rad², (m/s)², ...). Default `1e8`: a
    /// position standard deviation of 10 km, far beyond any flight this workspace simulates.
    pub max_trace_p: f64,
    /// NIS above which an update counts as absurd. Default `1e4` (a 100-σ innovation; the 99.9%
    /// χ² quantile of dimension 9 is 27.9).
    pub nis_absurd: f64,
    /// Number of consecutive absurd updates that declares divergence. Default 50 (5 s of
    /// 10 Hz measurements: a sustained, not a transient, inconsistency such as a spoofed GPS).
    pub max_absurd_updates: usize,
}

impl Default for DivergenceGuard {
    fn default() -> Self {
        Self { max_trace_p: 1e8, nis_absurd: 1e4, max_absurd_updates: 50 }
    }
}

/// The innovation of one update: `r_k`, `S_k` and the normalised innovation squared.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Innovation<const M: usize> {
    /// `r_k = y_k − g(x̂_{k|k−1})` (angle parts already wrapped by the caller).
    pub r_k: SVector<f64, M>,
    /// `S_k = H P_{k|k−1} Hᵀ + R_k`.
    pub s_k: SMatrix<f64, M, M>,
    /// `r_kᵀ S_k⁻¹ r_k`.
    pub nis: f64,
}

/// Extended Kalman filter with `N` states (static size).
#[derive(Debug, Clone, PartialEq)]
pub struct Ekf<const N: usize> {
    x: SVector<f64, N>,
    p: SMatrix<f64, N, N>,
    cov_update: CovarianceUpdate,
    guard: DivergenceGuard,
    n_absurd: usize,
}

/// `(A + Aᵀ)/2`.
fn symmetrise<const N: usize>(a: &mut SMatrix<f64, N, N>) {
    for i in 0..N {
        for j in (i + 1)..N {
            let m = 0.5 * (a[(i, j)] + a[(j, i)]);
            a[(i, j)] = m;
            a[(j, i)] = m;
        }
    }
}

impl<const N: usize> Ekf<N> {
    /// A filter at `x̂_{0|0} = x0`, `P_{0|0} = p0`.
    ///
    /// # Errors
    /// [`FilterError::NonFiniteState`] for non-finite input; [`FilterError::NotPositiveDefinite`]
    /// if `p0` is not symmetric positive semi-definite (Cholesky of `p0 + εI`).
    pub fn new(
        x0: SVector<f64, N>,
        p0: SMatrix<f64, N, N>,
        cov_update: CovarianceUpdate,
        guard: DivergenceGuard,
    ) -> Result<Self, FilterError> {
        if !x0.iter().all(|v| v.is_finite()) {
            return Err(FilterError::NonFiniteState { t: 0.0, what: "initial state" });
        }
        if !p0.iter().all(|v| v.is_finite()) {
            return Err(FilterError::NonFiniteState { t: 0.0, what: "initial covariance" });
        }
        let asym = (p0 - p0.transpose()).abs().max();
        // Positive semi-definite is enough (a cloned keyframe makes P singular): test P0 + εI.
        let eps = 1e-12 * (1.0 + p0.abs().max());
        if asym > 1e-9 * (1.0 + p0.abs().max()) || Cholesky::new(p0 + SMatrix::<f64, N, N>::identity() * eps).is_none()
        {
            return Err(FilterError::NotPositiveDefinite { t: 0.0, what: "initial covariance P0" });
        }
        Ok(Self { x: x0, p: p0, cov_update, guard, n_absurd: 0 })
    }

    /// Current estimate `x̂`.
    #[must_use]
    pub fn x(&self) -> &SVector<f64, N> {
        &self.x
    }

    /// Current covariance `P`.
    #[must_use]
    pub fn p(&self) -> &SMatrix<f64, N, N> {
        &self.p
    }

    /// The covariance update form in use.
    #[must_use]
    pub fn cov_update(&self) -> CovarianceUpdate {
        self.cov_update
    }

    /// Dense prediction, eq:ekf_predict: `x̂ ← x_prior`, `P ← F P Fᵀ + Q`.
    ///
    /// `x_prior = f(x̂, u)` is computed by the caller (the discretised model), `f_jac = ∇ₓf`.
    ///
    /// # Errors
    /// [`FilterError::NonFiniteState`] or [`FilterError::Diverged`] (trace bound) at time `t`.
    pub fn predict(
        &mut self,
        x_prior: SVector<f64, N>,
        f_jac: &SMatrix<f64, N, N>,
        q: &SMatrix<f64, N, N>,
        t: f64,
    ) -> Result<(), FilterError> {
        // eq:ekf_predict: P_{k|k−1} = ∇f P ∇fᵀ + Q
        let p_prior = f_jac * self.p * f_jac.transpose() + q;
        self.set_prior(x_prior, p_prior, t)
    }

    /// Install a prior `(x̂_{k|k−1}, P_{k|k−1})` computed elsewhere (e.g. by a sparse,
    /// model-specific covariance propagation), with the same checks as [`Ekf::predict`].
    ///
    /// # Errors
    /// As [`Ekf::predict`].
    pub fn set_prior(
        &mut self,
        x_prior: SVector<f64, N>,
        p_prior: SMatrix<f64, N, N>,
        t: f64,
    ) -> Result<(), FilterError> {
        if !x_prior.iter().all(|v| v.is_finite()) {
            return Err(FilterError::NonFiniteState { t, what: "predicted state" });
        }
        let trace = p_prior.trace();
        if !trace.is_finite() {
            return Err(FilterError::NonFiniteState { t, what: "predicted covariance" });
        }
        if trace > self.guard.max_trace_p {
            return Err(FilterError::Diverged {
                t,
                reason: format!("trace(P) = {trace:.3e} above {:.3e}", self.guard.max_trace_p),
            });
        }
        self.x = x_prior;
        self.p = p_prior;
        Ok(())
    }

    /// Apply a linear map to the state and covariance: `x̂ ← M x̂`, `P ← M P Mᵀ` (used for
    /// stochastic keyframe cloning in Model II).
    pub fn apply_linear_map(&mut self, m: &SMatrix<f64, N, N>) {
        self.x = m * self.x;
        self.p = m * self.p * m.transpose();
        symmetrise(&mut self.p);
    }

    /// Replace entries of the state without touching `P` (e.g. re-wrapping Euler angles, which
    /// changes `x̂` by multiples of 2π only).
    pub fn map_state(&mut self, fun: impl FnOnce(&mut SVector<f64, N>)) {
        fun(&mut self.x);
    }

    /// Forget what is known about the `B` states from `idx` on: their variances become `var`
    /// and their correlations with every other state 0, as at initialisation (a state reset,
    /// e.g. PX4 EKF2's velocity reset after GNSS fusion timed out). Zeroing a block's rows and
    /// columns keeps `P` positive semi-definite (the rest is a principal submatrix of `P`).
    ///
    /// # Errors
    /// [`FilterError::Config`] for a negative or non-finite `var` or a block past the state.
    pub fn reset_block<const B: usize>(&mut self, idx: usize, var: f64) -> Result<(), FilterError> {
        if !(var.is_finite() && var >= 0.0) {
            return Err(FilterError::Config { field: "var", msg: format!("must be finite and ≥ 0, got {var}") });
        }
        if idx + B > N {
            return Err(FilterError::Config {
                field: "idx",
                msg: format!("block {idx}..{} past the {N} states", idx + B),
            });
        }
        self.p.rows_mut(idx, B).fill(0.0);
        self.p.columns_mut(idx, B).fill(0.0);
        for i in idx..idx + B {
            self.p[(i, i)] = var;
        }
        Ok(())
    }

    /// Add `ΔP` to the covariance (e.g. inflation when a sensor is re-admitted).
    ///
    /// # Errors
    /// [`FilterError::NonFiniteState`] if the result is not finite.
    pub fn add_covariance(&mut self, dp: &SMatrix<f64, N, N>, t: f64) -> Result<(), FilterError> {
        let p = self.p + dp;
        if !p.iter().all(|v| v.is_finite()) {
            return Err(FilterError::NonFiniteState { t, what: "inflated covariance" });
        }
        self.p = p;
        symmetrise(&mut self.p);
        Ok(())
    }

    /// Innovation covariance `S = H P Hᵀ + R` and its Cholesky factor, without updating.
    ///
    /// # Errors
    /// [`FilterError::NotPositiveDefinite`] if `S` is not positive definite.
    pub fn innovation<const M: usize>(
        &self,
        r_k: &SVector<f64, M>,
        h: &SMatrix<f64, M, N>,
        r_cov: &SMatrix<f64, M, M>,
        t: f64,
    ) -> Result<Innovation<M>, FilterError> {
        let (s_k, _, nis) = factor_innovation(r_k, h, &(self.p * h.transpose()), r_cov, t)?;
        if !nis.is_finite() || !r_k.iter().all(|v| v.is_finite()) {
            return Err(FilterError::NonFiniteState { t, what: "innovation" });
        }
        Ok(Innovation { r_k: *r_k, s_k, nis })
    }

    /// Measurement update, eq:ekf_update, for an innovation `r_k = y_k − g(x̂_{k|k−1})` computed
    /// by the caller, `h = ∇ₓg(x̂_{k|k−1})` and measurement noise covariance `r_cov = R_k`.
    ///
    /// # Errors
    /// [`FilterError::NotPositiveDefinite`] if `S_k` is not positive definite,
    /// [`FilterError::NonFiniteState`] for non-finite results, [`FilterError::Diverged`] by the
    /// [`DivergenceGuard`].
    pub fn update<const M: usize>(
        &mut self,
        r_k: &SVector<f64, M>,
        h: &SMatrix<f64, M, N>,
        r_cov: &SMatrix<f64, M, M>,
        t: f64,
    ) -> Result<Innovation<M>, FilterError> {
        let ph_t = self.p * h.transpose();
        let (s_k, chol, nis) = factor_innovation(r_k, h, &ph_t, r_cov, t)?;
        // eq:ekf_update: K_k = P Hᵀ S_k⁻¹, computed as (S_k⁻¹ H P)ᵀ with P and S_k symmetric.
        let k_gain: SMatrix<f64, N, M> = chol.solve(&ph_t.transpose()).transpose();
        // eq:ekf_update: x̂_{k|k} = x̂_{k|k−1} + K_k r_k
        let x_post = self.x + k_gain * r_k;
        let p_post = match self.cov_update {
            CovarianceUpdate::Joseph => {
                let i_kh = SMatrix::<f64, N, N>::identity() - k_gain * h;
                i_kh * self.p * i_kh.transpose() + k_gain * r_cov * k_gain.transpose()
            }
            // eq:ekf_update: P_{k|k} = P_{k|k−1} − K_k H P_{k|k−1}
            CovarianceUpdate::Standard => self.p - k_gain * ph_t.transpose(),
        };
        if !nis.is_finite() || !x_post.iter().all(|v| v.is_finite()) || !p_post.iter().all(|v| v.is_finite()) {
            return Err(FilterError::NonFiniteState { t, what: "updated state or covariance" });
        }
        self.x = x_post;
        self.p = p_post;
        symmetrise(&mut self.p);
        if nis > self.guard.nis_absurd {
            self.n_absurd += 1;
            if self.n_absurd >= self.guard.max_absurd_updates {
                return Err(FilterError::Diverged {
                    t,
                    reason: format!(
                        "{} consecutive updates with NIS above {:.3e} (last {nis:.3e})",
                        self.n_absurd, self.guard.nis_absurd
                    ),
                });
            }
        } else {
            self.n_absurd = 0;
        }
        let trace = self.p.trace();
        if trace > self.guard.max_trace_p {
            return Err(FilterError::Diverged {
                t,
                reason: format!("trace(P) = {trace:.3e} above {:.3e}", self.guard.max_trace_p),
            });
        }
        Ok(Innovation { r_k: *r_k, s_k, nis })
    }
}

/// `S_k = H P Hᵀ + R` from `ph_t = P Hᵀ` (shared with the gain), its Cholesky factor and the
/// NIS `r_kᵀ S_k⁻¹ r_k`, as used by both [`Ekf::innovation`] and [`Ekf::update`].
#[allow(clippy::type_complexity)]
fn factor_innovation<const N: usize, const M: usize>(
    r_k: &SVector<f64, M>,
    h: &SMatrix<f64, M, N>,
    ph_t: &SMatrix<f64, N, M>,
    r_cov: &SMatrix<f64, M, M>,
    t: f64,
) -> Result<(SMatrix<f64, M, M>, Cholesky<f64, nalgebra::Const<M>>, f64), FilterError> {
    let mut s_k = h * ph_t + r_cov;
    symmetrise(&mut s_k);
    let chol = Cholesky::new(s_k).ok_or(FilterError::NotPositiveDefinite { t, what: "innovation covariance S_k" })?;
    let nis = r_k.dot(&chol.solve(r_k));
    Ok((s_k, chol, nis))
}

/// The innovation of a runtime-sized update ([`Ekf::update_dyn`]).
#[derive(Debug, Clone, PartialEq)]
pub struct DynInnovation {
    /// `r_k`.
    pub r_k: DVector<f64>,
    /// `S_k`.
    pub s_k: DMatrix<f64>,
    /// `r_kᵀ S_k⁻¹ r_k`.
    pub nis: f64,
}

impl<const N: usize> Ekf<N> {
    /// Measurement update (eq:ekf_update) for a measurement whose size is known only at run
    /// time (e.g. a user's own sensor): `r_k` (M), `h` (M×N), `r_cov` (M×M). Always Joseph form.
    ///
    /// # Errors
    /// [`FilterError::Dim`] when the sizes disagree; otherwise as [`Ekf::update`].
    pub fn update_dyn(
        &mut self,
        r_k: &DVector<f64>,
        h: &DMatrix<f64>,
        r_cov: &DMatrix<f64>,
        t: f64,
    ) -> Result<DynInnovation, FilterError> {
        let m = r_k.len();
        if h.nrows() != m {
            return Err(FilterError::Dim { what: "rows of H (= length of r_k)", expected: m, got: h.nrows() });
        }
        if h.ncols() != N {
            return Err(FilterError::Dim { what: "columns of H (= state dimension)", expected: N, got: h.ncols() });
        }
        if r_cov.nrows() != m || r_cov.ncols() != m {
            return Err(FilterError::Dim {
                what: "size of R (= length of r_k)",
                expected: m,
                got: r_cov.nrows().max(r_cov.ncols()),
            });
        }
        let p = DMatrix::from_column_slice(N, N, self.p.as_slice());
        let mut s_k = h * &p * h.transpose() + r_cov;
        s_k = (&s_k + s_k.transpose()) * 0.5;
        let chol =
            s_k.clone().cholesky().ok_or(FilterError::NotPositiveDefinite { t, what: "innovation covariance S_k" })?;
        let ph_t = &p * h.transpose();
        let k_gain = chol.solve(&ph_t.transpose()).transpose();
        let nis = r_k.dot(&chol.solve(r_k));
        let x_post = DVector::from_column_slice(self.x.as_slice()) + &k_gain * r_k;
        let i_kh = DMatrix::<f64>::identity(N, N) - &k_gain * h;
        let p_post = &i_kh * &p * i_kh.transpose() + &k_gain * r_cov * k_gain.transpose();
        if !nis.is_finite() || !x_post.iter().all(|v| v.is_finite()) || !p_post.iter().all(|v| v.is_finite()) {
            return Err(FilterError::NonFiniteState { t, what: "updated state or covariance" });
        }
        self.x = SVector::<f64, N>::from_column_slice(x_post.as_slice());
        self.p = SMatrix::<f64, N, N>::from_column_slice(p_post.as_slice());
        symmetrise(&mut self.p);
        Ok(DynInnovation { r_k: r_k.clone(), s_k, nis })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix1, Matrix2, Vector1, Vector2};

    #[test]
    fn scalar_update_matches_closed_form() {
        let mut ekf =
            Ekf::<1>::new(Vector1::new(0.0), Matrix1::new(4.0), CovarianceUpdate::Joseph, DivergenceGuard::default())
                .unwrap();
        let inn = ekf.update(&Vector1::new(2.0), &Matrix1::new(1.0), &Matrix1::new(1.0), 0.0).unwrap();
        // K = 4/5, x = 1.6, P = 4 − 16/5 = 0.8, NIS = 4/5.
        assert!((ekf.x()[0] - 1.6).abs() < 1e-12);
        assert!((ekf.p()[(0, 0)] - 0.8).abs() < 1e-12);
        assert!((inn.nis - 0.8).abs() < 1e-12);
    }

    #[test]
    fn joseph_equals_standard_for_optimal_gain() {
        let p0 = Matrix2::new(2.0, 0.3, 0.3, 1.0);
        let h = SMatrix::<f64, 1, 2>::new(1.0, 0.5);
        let mut a = Ekf::<2>::new(Vector2::zeros(), p0, CovarianceUpdate::Joseph, DivergenceGuard::default()).unwrap();
        let mut b =
            Ekf::<2>::new(Vector2::zeros(), p0, CovarianceUpdate::Standard, DivergenceGuard::default()).unwrap();
        a.update(&Vector1::new(1.0), &h, &Matrix1::new(0.5), 0.0).unwrap();
        b.update(&Vector1::new(1.0), &h, &Matrix1::new(0.5), 0.0).unwrap();
        assert!((a.p() - b.p()).norm() < 1e-12);
        assert!((a.x() - b.x()).norm() < 1e-12);
    }

    #[test]
    fn a_block_reset_rejects_a_block_past_the_state_and_a_bad_variance() {
        let mut ekf =
            Ekf::<2>::new(Vector2::zeros(), Matrix2::identity(), CovarianceUpdate::Joseph, DivergenceGuard::default())
                .unwrap();
        assert!(matches!(ekf.reset_block::<2>(1, 1.0), Err(FilterError::Config { field: "idx", .. })));
        for bad in [-1.0, f64::NAN, f64::INFINITY] {
            assert!(matches!(ekf.reset_block::<1>(0, bad), Err(FilterError::Config { field: "var", .. })));
        }
        assert_eq!(ekf.p(), &Matrix2::identity(), "a rejected reset leaves P alone");
    }

    #[test]
    fn singular_innovation_covariance_is_an_error() {
        let mut ekf =
            Ekf::<1>::new(Vector1::new(0.0), Matrix1::new(1.0), CovarianceUpdate::Joseph, DivergenceGuard::default())
                .unwrap();
        let err = ekf.update(&Vector1::new(1.0), &Matrix1::new(0.0), &Matrix1::new(0.0), 3.0).unwrap_err();
        assert!(matches!(err, FilterError::NotPositiveDefinite { t, .. } if t == 3.0));
    }
}
