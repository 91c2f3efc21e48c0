//! The blocks of [`crate::fused`] composed from candle's own tensor ops, for tensors on a device
//! the custom ops have no kernel for (they have CPU kernels only; a CUDA build of candle runs
//! these). Each computes the same function as its kernel, with candle's automatic backward; on
//! the CPU the kernels are used, and the tests hold the two together (values and gradients,
//! within `f32` rounding).

use candle_core::{D, Tensor};

/// `x + b` with `b` (`d` elements) added to every row of `x`, as [`crate::fused::add_bias`].
///
/// # Errors
/// Shapes that do not fit; candle errors.
pub fn add_bias(x: &Tensor, bias: &Tensor) -> candle_core::Result<Tensor> {
    x.broadcast_add(&bias.flatten_all()?)
}

/// The erf GELU `x Φ(x)`, as [`crate::fused::gelu`].
///
/// # Errors
/// candle errors.
pub fn gelu(x: &Tensor) -> candle_core::Result<Tensor> {
    x.gelu_erf()
}

/// Softmax over the last axis, `exp(s − max s) / Σ exp(s − max s)`, as
/// [`crate::fused::softmax_last_dim`].
///
/// # Errors
/// candle errors.
pub fn softmax_last_dim(x: &Tensor) -> candle_core::Result<Tensor> {
    let shifted = x.broadcast_sub(&x.max_keepdim(D::Minus1)?)?;
    let e = shifted.exp()?;
    e.broadcast_div(&e.sum_keepdim(D::Minus1)?)
}

/// Layer norm of the rows of `x`, `(x − μ)/√(var + eps) · γ + β`, as
/// [`crate::fused::layer_norm`].
///
/// # Errors
/// candle errors.
pub fn layer_norm(x: &Tensor, gain: &Tensor, bias: &Tensor, eps: f32) -> candle_core::Result<Tensor> {
    let centred = x.broadcast_sub(&x.mean_keepdim(D::Minus1)?)?;
    let var = centred.sqr()?.mean_keepdim(D::Minus1)?;
    let normed = centred.broadcast_div(&(var + f64::from(eps))?.sqrt()?)?;
    normed.broadcast_mul(&gain.flatten_all()?)?.broadcast_add(&bias.flatten_all()?)
}
