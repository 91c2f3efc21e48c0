//! The streaming engine's copies of the typed weights ([`crate::weights`]) in plain `f32`
//! buffers: a dense layer with `W` stored `in × out`, a layer norm's gain and bias, and the
//! compositions of dense layers the engine forms once, accumulated in `f64`.

use candle_core::Tensor;

use crate::error::{ModelError, Result};
use nn_toolkit::fused::{add_bias_row, layer_norm_row};
use nn_toolkit::layers::{Dense, LN_EPS, Norm};
use nn_toolkit::matmul::{MatMut, MatRef, matmul};

/// A dense layer `y = x W + b` with `W` stored `in × out` (the transpose of the checkpoint's
/// `weight`).
#[derive(Clone)]
pub(super) struct Linear {
    pub(super) w: Vec<f32>,
    pub(super) b: Vec<f32>,
    pub(super) n_in: usize,
    pub(super) n_out: usize,
}

/// The values of `t` on the host, row-major.
fn host(t: &Tensor) -> Result<Vec<f32>> {
    Ok(t.detach().flatten_all()?.to_vec1::<f32>()?)
}

impl Linear {
    /// A host copy of `dense` (`weight` is `out × in`).
    pub(super) fn of(dense: &Dense) -> Result<Self> {
        let (n_out, n_in) = dense.weight().dims2()?;
        let w = host(&dense.weight().t()?.contiguous()?)?;
        let b = host(dense.bias())?;
        if b.len() != n_out {
            return Err(ModelError::Data { msg: format!("a bias has {} values, expected {n_out}", b.len()) });
        }
        Ok(Self { w, b, n_in, n_out })
    }

    /// `u W + bias·b` of one row `u`, in `f64` (for weights formed once).
    pub(super) fn apply_f64(&self, u: &[f64], bias: f64) -> Vec<f64> {
        (0..self.n_out)
            .map(|j| {
                let acc: f64 = u.iter().enumerate().map(|(k, uk)| uk * f64::from(self.w[k * self.n_out + j])).sum();
                acc + bias * f64::from(self.b[j])
            })
            .collect()
    }

    /// The composition `x ↦ (x W + b) W' + b'` of this layer and `next`, as one layer
    /// (accumulated in `f64`).
    pub(super) fn then(&self, next: &Linear) -> Self {
        let w = self.w.chunks_exact(self.n_out).flat_map(|row| to_f32(&next.apply_f64(&to_f64(row), 0.0))).collect();
        Self { w, b: to_f32(&next.apply_f64(&to_f64(&self.b), 1.0)), n_in: self.n_in, n_out: next.n_out }
    }

    /// `x ↦ c x Wᵀ`, without bias.
    pub(super) fn transposed(&self, c: f32) -> Self {
        let w = (0..self.n_in * self.n_out).map(|k| c * self.w[(k % self.n_in) * self.n_out + k / self.n_in]).collect();
        Self { w, b: vec![0.0; self.n_in], n_in: self.n_out, n_out: self.n_in }
    }

    /// `k ↦ c [k W_Qᵀ | k·b_Q]` of this query projection, without bias: what layer 2's folded
    /// scores read of a key `k` of layer 1 (`Scores::RingKeys`).
    pub(super) fn key_map(&self, c: f32) -> Self {
        let mut w = Vec::with_capacity(self.n_out * (self.n_in + 1));
        for j in 0..self.n_out {
            w.extend((0..self.n_in).map(|a| c * self.w[a * self.n_out + j]));
            w.push(c * self.b[j]);
        }
        Self { w, b: vec![0.0; self.n_in + 1], n_in: self.n_out, n_out: self.n_in + 1 }
    }

    /// `dst ← x W + b` for the `rows` rows of `x`.
    #[inline(always)]
    pub(super) fn forward(&self, x: MatRef<'_>, dst: &mut [f32], rows: usize) -> Result<()> {
        matmul(MatMut::rows(dst, rows, self.n_out)?, x, MatRef::rows(&self.w, self.n_in, self.n_out)?, 1.0, false)?;
        for row in dst[..rows * self.n_out].chunks_exact_mut(self.n_out) {
            add_bias_row(row, &self.b);
        }
        Ok(())
    }
}

/// Gain and bias of a layer norm.
#[derive(Clone)]
pub(super) struct LayerNormW {
    gain: Vec<f32>,
    bias: Vec<f32>,
}

impl LayerNormW {
    /// A host copy of `norm`.
    pub(super) fn of(norm: &Norm) -> Result<Self> {
        Ok(Self { gain: host(norm.gain())?, bias: host(norm.bias())? })
    }

    /// The norm of every row of `rows`, in place.
    #[inline(always)]
    pub(super) fn apply(&self, rows: &mut [f32]) {
        for row in rows.chunks_exact_mut(self.gain.len()) {
            layer_norm_row(row, &self.gain, &self.bias, LN_EPS);
        }
    }
}

/// `f32` values widened to `f64`.
pub(super) fn to_f64(xs: &[f32]) -> Vec<f64> {
    xs.iter().map(|&v| f64::from(v)).collect()
}

/// `f64` values rounded to `f32`.
pub(super) fn to_f32(xs: &[f64]) -> Vec<f32> {
    xs.iter().map(|&v| v as f32).collect()
}
