//! The per-step classification loss every learning method trains with.

use candle_core::Tensor;

/// BCE with logits and positive-class weight `w`, `(1 − y)·softplus(z) + w·y·softplus(−z)`
/// (PyTorch's `BCEWithLogitsLoss(pos_weight)`), averaged over the masked steps; `w = 1` is the
/// plain BCE `relu(z) − z·y + ln(1 + e^{−|z|})`.
///
/// # Errors
/// candle errors.
pub fn masked_bce_with_logits(
    z: &Tensor,
    y: &Tensor,
    mask: &Tensor,
    n_labelled: usize,
    pos_weight: f64,
) -> candle_core::Result<Tensor> {
    let softplus = (z.relu()? + (z.abs()?.neg()?.exp()? + 1.0)?.log()?)?;
    let bce = if pos_weight == 1.0 {
        (softplus - (z * y)?)?
    } else {
        ((softplus * y.affine(pos_weight - 1.0, 1.0)?)? - (z * y)?.affine(pos_weight, 0.0)?)?
    };
    (bce * mask)?.sum_all()? / n_labelled.max(1) as f64
}
