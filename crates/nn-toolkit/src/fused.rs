//! Element-wise blocks of the QUADFormer layer as single candle custom ops with closed-form
//! backward passes: the bias of a dense layer, the erf GELU of the feed-forward and
//! classification heads, the softmax of the attention `C` (eq:first_layer_attention) and the
//! layer norm of `Norm(·)`.
//!
//! Composed from candle's element-wise ops the last three took about half of a training step
//! (`examples/profile.rs train`, batch 32): the composed GELU backward alone is nine passes over
//! every `b·l × d_ff` activation, each allocating its result, and candle's fused softmax and
//! layer-norm kernels have no backward at all (candle 0.11; for the layer norm see
//! huggingface/candle issues #3011 and #3752). Each op here makes one pass forward and one
//! backward, and works in training and inference alike.
//!
//! Gradients (per row, `g` the incoming gradient):
//! - bias `y = x + b` on every row: `∂/∂x = g`, `∂/∂b = Σ_rows g` (a broadcast's gradient in
//!   candle 0.11 is a strided scalar sum; a rank-1 product, [`crate::layers::repeat_rows`],
//!   costs a matrix product and an addition forward and back);
//! - GELU `y = x Φ(x)`, `Φ(x) = ½(1 + erf(x/√2))`: `∂y/∂x = Φ(x) + x φ(x)`,
//!   `φ(x) = e^{−x²/2}/√(2π)`, with `erf` and `exp` from [`crate::vmath`] (every kernel's loop
//!   runs in [`crate::vmath::vectorized`]; the forward differs from candle's `gelu_erf` by
//!   less than `3·10⁻⁷ |x|`).
//! - softmax `yⱼ = e^{sⱼ}/Σₖ e^{sₖ}`: `∂/∂sⱼ = yⱼ (gⱼ − Σₖ gₖ yₖ)`.
//! - layer norm `yⱼ = x̂ⱼ γⱼ + βⱼ`, `x̂ = (x − μ)/σ`, `σ = √(var + ε)`:
//!   `∂/∂x = (ĝ − mean(ĝ) − x̂ · mean(ĝ ⊙ x̂))/σ` with `ĝ = g ⊙ γ`; `∂/∂γ = Σ_rows g ⊙ x̂`,
//!   `∂/∂β = Σ_rows g`.
//!
//! The backward passes return constants (no second derivatives), which is all training needs.
//! The kernels take `f32` tensors on the CPU and are an error for another type. On another
//! device (a CUDA build of candle) each function runs its definition composed from candle's
//! ops instead ([`composed`]), the same function with candle's automatic backward.

use candle_core::{CpuStorage, CustomOp1, CustomOp2, CustomOp3, Layout, Shape, Storage, Tensor};

use crate::vmath;

pub mod composed;

/// `1/√(2π)`.
const FRAC_1_SQRT_2PI: f32 = 0.398_942_3;

/// The erf GELU `x Φ(x)`, element-wise (candle's `gelu_erf` up to `3·10⁻⁷ |x|`).
///
/// # Errors
/// A dtype other than `f32` on the CPU.
pub fn gelu(x: &Tensor) -> candle_core::Result<Tensor> {
    if !x.device().is_cpu() {
        return composed::gelu(x);
    }
    let x = x.contiguous()?;
    if x.track_op() { x.apply_op1(Gelu) } else { x.apply_op1_no_bwd(&Gelu) }
}

/// Softmax over the last axis.
///
/// # Errors
/// A dtype other than `f32` on the CPU, a rank-0 or empty last axis.
pub fn softmax_last_dim(x: &Tensor) -> candle_core::Result<Tensor> {
    if !x.device().is_cpu() {
        return composed::softmax_last_dim(x);
    }
    let x = x.contiguous()?;
    if x.track_op() { x.apply_op1(Softmax) } else { x.apply_op1_no_bwd(&Softmax) }
}

/// `x + b` with the bias `b` (`d` elements) added to every row of `x` (last axis `d`).
///
/// # Errors
/// Shapes that do not fit, a dtype other than `f32` on the CPU.
pub fn add_bias(x: &Tensor, bias: &Tensor) -> candle_core::Result<Tensor> {
    if !x.device().is_cpu() {
        return composed::add_bias(x, bias);
    }
    let (x, bias) = (x.contiguous()?, bias.contiguous()?);
    if x.track_op() || bias.track_op() { x.apply_op2(&bias, AddBias) } else { x.apply_op2_no_bwd(&bias, &AddBias) }
}

/// Layer norm of the rows of `x` (`n × d`) with gain `γ` and bias `β` (both `d`), variance
/// guard `eps`.
///
/// # Errors
/// Shapes that do not fit, a dtype other than `f32` on the CPU.
pub fn layer_norm(x: &Tensor, gain: &Tensor, bias: &Tensor, eps: f32) -> candle_core::Result<Tensor> {
    if !x.device().is_cpu() {
        return composed::layer_norm(x, gain, bias, eps);
    }
    let (x, gain, bias) = (x.contiguous()?, gain.contiguous()?, bias.contiguous()?);
    let op = LayerNorm { eps };
    if x.track_op() || gain.track_op() || bias.track_op() {
        x.apply_op3(&gain, &bias, op)
    } else {
        x.apply_op3_no_bwd(&gain, &bias, &op)
    }
}

/// The erf GELU of one value. Like every kernel below it is inlined into its caller, which
/// runs it inside [`vmath::vectorized`]; the streaming engine (`quadformer_model::streaming`) calls
/// the same kernels, so both paths compute the same element-wise values.
#[inline(always)]
pub fn gelu_value(v: f32) -> f32 {
    (vmath::erf(v * std::f32::consts::FRAC_1_SQRT_2) + 1.0) * 0.5 * v
}

/// `row + bias`, in place.
#[inline(always)]
pub fn add_bias_row(row: &mut [f32], bias: &[f32]) {
    for (yj, bj) in row.iter_mut().zip(bias) {
        *yj += bj;
    }
}

/// Softmax of every row (`len` values) of `map`, in place: `cⱼ = exp(sⱼ − max s) / Σ`, with
/// the exponentials taken over [`vmath::row_block`] rows at a time, so that no row leaves a
/// remainder to scalar code. With `entropy`, `(ent, shifted)`, also writes each row's
/// `Σⱼ cⱼ ln cⱼ = Σⱼ cⱼ (sⱼ − max s) − ln Σⱼ exp(sⱼ − max s)` to `ent`, without a logarithm per
/// entry; `shifted` (a block's size) is scratch.
#[inline(always)]
pub fn softmax_rows(map: &mut [f32], len: usize, mut entropy: Option<(&mut [f32], &mut [f32])>) {
    let rows = vmath::row_block(len);
    for (b, block) in map.chunks_mut(rows * len).enumerate() {
        for row in block.chunks_exact_mut(len) {
            let max = vmath::max(row);
            for y in row.iter_mut() {
                *y -= max;
            }
        }
        if let Some((_, shifted)) = entropy.as_mut() {
            shifted[..block.len()].copy_from_slice(block);
        }
        for y in block.iter_mut() {
            *y = vmath::exp(*y);
        }
        for (r, row) in block.chunks_exact_mut(len).enumerate() {
            let sum = vmath::sum(row);
            for y in row.iter_mut() {
                *y /= sum;
            }
            if let Some((ent, shifted)) = entropy.as_mut() {
                ent[b * rows + r] = vmath::dot(row, &shifted[r * len..(r + 1) * len]) - vmath::ln(sum);
            }
        }
    }
}

/// Replaces a row by `x − μ` and returns `1/σ`, `σ = √(var + eps)`.
#[inline(always)]
fn centre_row(row: &mut [f32], eps: f32) -> f32 {
    let n = row.len() as f32;
    let mu = vmath::sum(row) / n;
    for x in row.iter_mut() {
        *x -= mu;
    }
    1.0 / (vmath::dot(row, row) / n + eps).sqrt()
}

/// Layer norm of one row with gain `γ` and bias `β`, in place.
#[inline(always)]
pub fn layer_norm_row(row: &mut [f32], gain: &[f32], bias: &[f32], eps: f32) {
    let inv_sigma = centre_row(row, eps);
    for ((yj, &gj), &bj) in row.iter_mut().zip(gain).zip(bias) {
        *yj = *yj * inv_sigma * gj + bj;
    }
}

/// The contiguous `f32` elements of a storage (for a custom op's `cpu_fwd`).
///
/// # Errors
/// Another dtype, a non-contiguous layout; the message names `op`.
pub fn f32_slice<'a>(op: &str, s: &'a CpuStorage, l: &Layout) -> candle_core::Result<&'a [f32]> {
    let CpuStorage::F32(v) = s else { candle_core::bail!("{op}: only f32 is supported") };
    let Some((start, end)) = l.contiguous_offsets() else { candle_core::bail!("{op}: non-contiguous input") };
    Ok(&v[start..end])
}

/// Calls `f` with the `f32` elements of `t` in row-major order (copied only when `t` is not
/// contiguous, e.g. a broadcast gradient), for a custom op's backward.
///
/// # Errors
/// Another dtype or device (the message names `op`), and `f`'s errors.
pub fn with_f32<R>(op: &str, t: &Tensor, f: impl FnOnce(&[f32]) -> candle_core::Result<R>) -> candle_core::Result<R> {
    let t = t.contiguous()?;
    let (storage, layout) = t.storage_and_layout();
    let Storage::Cpu(cpu) = &*storage else { candle_core::bail!("{op}: only the CPU is supported") };
    f(f32_slice(op, cpu, layout)?)
}

/// Length of the last axis, which must be non-empty.
fn last_dim(op: &str, shape: &Shape) -> candle_core::Result<usize> {
    match shape.dims().last() {
        Some(&d) if d > 0 => Ok(d),
        _ => candle_core::bail!("{op}: needs a non-empty last axis, got shape {shape:?}"),
    }
}

struct AddBias;

impl AddBias {
    fn check(&self, x: &Shape, bias: &Shape) -> candle_core::Result<usize> {
        let d = last_dim(self.name(), x)?;
        if bias.elem_count() != d {
            candle_core::bail!("{}: rows of width {d}, bias {bias:?}", self.name())
        }
        Ok(d)
    }
}

impl CustomOp2 for AddBias {
    fn name(&self) -> &'static str {
        "fused-add-bias"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let d = self.check(l1.shape(), l2.shape())?;
        let (x, bias) = (f32_slice(self.name(), s1, l1)?, f32_slice(self.name(), s2, l2)?);
        let mut y = x.to_vec();
        vmath::vectorized(
            #[inline(always)]
            || {
                for row in y.chunks_exact_mut(d) {
                    add_bias_row(row, bias);
                }
            },
        );
        Ok((CpuStorage::F32(y), l1.shape().clone()))
    }

    fn bwd(
        &self,
        x: &Tensor,
        bias: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
        let d = self.check(x.shape(), bias.shape())?;
        let db = with_f32(self.name(), grad, |g| {
            let mut db = vec![0f32; d];
            vmath::vectorized(
                #[inline(always)]
                || {
                    for row in g.chunks_exact(d) {
                        for (s, gj) in db.iter_mut().zip(row) {
                            *s += gj;
                        }
                    }
                },
            );
            Ok(db)
        })?;
        Ok((Some(grad.clone()), Some(Tensor::from_vec(db, bias.shape(), bias.device())?)))
    }
}

struct Gelu;

impl CustomOp1 for Gelu {
    fn name(&self) -> &'static str {
        "fused-gelu"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let x = f32_slice(self.name(), s, l)?;
        let mut y = vec![0f32; x.len()];
        vmath::vectorized(
            #[inline(always)]
            || {
                for (yj, &v) in y.iter_mut().zip(x) {
                    *yj = gelu_value(v);
                }
            },
        );
        Ok((CpuStorage::F32(y), l.shape().clone()))
    }

    fn bwd(&self, arg: &Tensor, res: &Tensor, grad: &Tensor) -> candle_core::Result<Option<Tensor>> {
        let dx = with_f32(self.name(), arg, |x| {
            with_f32(self.name(), res, |y| {
                with_f32(self.name(), grad, |g| {
                    let mut dx = vec![0f32; x.len()];
                    vmath::vectorized(
                        #[inline(always)]
                        || {
                            for (((d, &x), &y), &g) in dx.iter_mut().zip(x).zip(y).zip(g) {
                                // Φ(x) = y/x reuses the forward's erf; Φ(0) = ½.
                                let cdf = if x == 0.0 { 0.5 } else { y / x };
                                *d = g * (cdf + x * FRAC_1_SQRT_2PI * vmath::exp(-0.5 * x * x));
                            }
                        },
                    );
                    Ok(dx)
                })
            })
        })?;
        Ok(Some(Tensor::from_vec(dx, arg.shape(), arg.device())?))
    }
}

struct Softmax;

impl CustomOp1 for Softmax {
    fn name(&self) -> &'static str {
        "fused-softmax"
    }

    fn cpu_fwd(&self, s: &CpuStorage, l: &Layout) -> candle_core::Result<(CpuStorage, Shape)> {
        let len = last_dim(self.name(), l.shape())?;
        let x = f32_slice(self.name(), s, l)?;
        let mut y = x.to_vec();
        vmath::vectorized(
            #[inline(always)]
            || {
                softmax_rows(&mut y, len, None);
            },
        );
        Ok((CpuStorage::F32(y), l.shape().clone()))
    }

    fn bwd(&self, arg: &Tensor, res: &Tensor, grad: &Tensor) -> candle_core::Result<Option<Tensor>> {
        let len = last_dim(self.name(), res.shape())?;
        let dx = with_f32(self.name(), res, |y| {
            with_f32(self.name(), grad, |g| {
                let mut dx = vec![0f32; y.len()];
                vmath::vectorized(
                    #[inline(always)]
                    || {
                        for ((yr, gr), dr) in y.chunks_exact(len).zip(g.chunks_exact(len)).zip(dx.chunks_exact_mut(len))
                        {
                            let dot = vmath::dot(yr, gr);
                            for ((d, &yj), &gj) in dr.iter_mut().zip(yr).zip(gr) {
                                *d = yj * (gj - dot);
                            }
                        }
                    },
                );
                Ok(dx)
            })
        })?;
        Ok(Some(Tensor::from_vec(dx, arg.shape(), arg.device())?))
    }
}

struct LayerNorm {
    eps: f32,
}

impl LayerNorm {
    fn check(&self, x: &Shape, gain: &Shape, bias: &Shape) -> candle_core::Result<usize> {
        let d = last_dim(self.name(), x)?;
        if gain.elem_count() != d || bias.elem_count() != d {
            candle_core::bail!("{}: rows of width {d}, gain {gain:?}, bias {bias:?}", self.name())
        }
        Ok(d)
    }
}

impl CustomOp3 for LayerNorm {
    fn name(&self) -> &'static str {
        "fused-layer-norm"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
        s3: &CpuStorage,
        l3: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let d = self.check(l1.shape(), l2.shape(), l3.shape())?;
        let (x, gain, bias) =
            (f32_slice(self.name(), s1, l1)?, f32_slice(self.name(), s2, l2)?, f32_slice(self.name(), s3, l3)?);
        let mut y = x.to_vec();
        vmath::vectorized(
            #[inline(always)]
            || {
                for row in y.chunks_exact_mut(d) {
                    layer_norm_row(row, gain, bias, self.eps);
                }
            },
        );
        Ok((CpuStorage::F32(y), l1.shape().clone()))
    }

    fn bwd(
        &self,
        x: &Tensor,
        gain: &Tensor,
        bias: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>, Option<Tensor>)> {
        let d = self.check(x.shape(), gain.shape(), bias.shape())?;
        let (dx, dgain, dbias) = with_f32(self.name(), x, |xv| {
            with_f32(self.name(), gain, |gamma| {
                with_f32(self.name(), grad, |g| {
                    vmath::vectorized(
                        #[inline(always)]
                        || {
                            let mut dx = vec![0f32; xv.len()];
                            let (mut dgain, mut dbias) = (vec![0f32; d], vec![0f32; d]);
                            let mut xhat = vec![0f32; d];
                            let mut ghat = vec![0f32; d];
                            for ((xr, gr), dr) in xv.chunks_exact(d).zip(g.chunks_exact(d)).zip(dx.chunks_exact_mut(d))
                            {
                                xhat.copy_from_slice(xr);
                                let inv_sigma = centre_row(&mut xhat, self.eps);
                                for j in 0..d {
                                    xhat[j] *= inv_sigma;
                                    ghat[j] = gr[j] * gamma[j];
                                    dgain[j] += gr[j] * xhat[j];
                                    dbias[j] += gr[j];
                                }
                                let mean_g = vmath::sum(&ghat) / d as f32;
                                let mean_gx = vmath::dot(&ghat, &xhat) / d as f32;
                                for j in 0..d {
                                    dr[j] = (ghat[j] - mean_g - xhat[j] * mean_gx) * inv_sigma;
                                }
                            }
                            Ok((dx, dgain, dbias))
                        },
                    )
                })
            })
        })?;
        Ok((
            Some(Tensor::from_vec(dx, x.shape(), x.device())?),
            Some(Tensor::from_vec(dgain, gain.shape(), gain.device())?),
            Some(Tensor::from_vec(dbias, bias.shape(), bias.device())?),
        ))
    }
}

#[cfg(test)]
mod tests {
    use candle_core::{D, Device, Var};
    use proptest::prelude::*;

    use super::*;

    /// `max |a − b| / (1 + max |b|)`.
    fn max_diff(a: &Tensor, b: &Tensor) -> f32 {
        let max_abs = |t: &Tensor| t.abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap();
        max_abs(&(a - b).unwrap()) / (1.0 + max_abs(b))
    }

    fn var(v: &[f32], dims: &[usize]) -> Var {
        Var::from_slice(v, dims, &Device::Cpu).unwrap()
    }

    /// A weighting of the outputs, so that gradients differ per element.
    fn weighted_sum(t: &Tensor) -> Tensor {
        let n = t.elem_count();
        let w =
            Tensor::from_vec((0..n).map(|i| 0.5 + (i % 7) as f32 * 0.3).collect(), t.shape(), &Device::Cpu).unwrap();
        (t * w).unwrap().sum_all().unwrap()
    }

    /// Value and gradient differences between `ours` and `theirs` applied to one variable.
    fn compare1(x: &Var, ours: impl Fn(&Tensor) -> Tensor, theirs: impl Fn(&Tensor) -> Tensor) -> (f32, f32) {
        let (a, b) = (ours(x.as_tensor()), theirs(x.as_tensor()));
        let (ga, gb) = (weighted_sum(&a).backward().unwrap(), weighted_sum(&b).backward().unwrap());
        (max_diff(&a, &b), max_diff(ga.get(x).unwrap(), gb.get(x).unwrap()))
    }

    /// Softmax by blocks of rows gives the bits of the softmax of each row on its own, also for
    /// a last block of fewer rows, and each row's `Σ c ln c`.
    #[test]
    fn softmax_by_blocks_matches_the_row_kernel() {
        let (len, rows) = (12, 5);
        let scores: Vec<f32> = (0..len * rows).map(|i| ((i * 37) % 23) as f32 * 1.7 - 20.0).collect();
        let mut by_rows = scores.clone();
        for row in by_rows.chunks_exact_mut(len) {
            let max = vmath::max(row);
            for y in row.iter_mut() {
                *y = vmath::exp(*y - max);
            }
            let sum = vmath::sum(row);
            for y in row.iter_mut() {
                *y /= sum;
            }
        }
        let (mut by_blocks, mut ent, mut shifted) = (scores, vec![0f32; rows], vec![0f32; 2 * len]);
        softmax_rows(&mut by_blocks, len, Some((&mut ent, &mut shifted)));
        assert_eq!(by_blocks, by_rows);
        for (row, e) in by_rows.chunks_exact(len).zip(&ent) {
            let direct: f32 = row.iter().filter(|&&c| c > 0.0).map(|&c| c * c.ln()).sum();
            assert!((e - direct).abs() < 1e-5, "{e} vs {direct}");
        }
    }

    #[test]
    fn add_bias_matches_a_broadcast() {
        let x = var(&(0..12).map(|i| i as f32 * 0.5 - 2.0).collect::<Vec<_>>(), &[4, 3]);
        let b = var(&[0.5, -1.0, 2.0], &[3]);
        let ours = add_bias(&x, &b).unwrap();
        let theirs = x.broadcast_add(&b).unwrap();
        assert_eq!(max_diff(&ours, &theirs), 0.0);
        let (ga, gb) = (weighted_sum(&ours).backward().unwrap(), weighted_sum(&theirs).backward().unwrap());
        assert_eq!(max_diff(ga.get(&x).unwrap(), gb.get(&x).unwrap()), 0.0);
        assert!(max_diff(ga.get(&b).unwrap(), gb.get(&b).unwrap()) < 1e-6);
        assert!(add_bias(&x, &var(&[1.0, 2.0], &[2])).is_err());
    }

    #[test]
    fn gelu_matches_candle_values_and_gradient() {
        let v: Vec<f32> = (0..61).map(|i| (i as f32 - 30.0) * 0.25).chain([0.0, -0.0, 1e-30, -12.0]).collect();
        let x = var(&v, &[v.len()]);
        let (dv, dg) = compare1(&x, |t| gelu(t).unwrap(), |t| t.gelu_erf().unwrap());
        assert!(dv < 1e-6 && dg < 1e-5, "value {dv}, gradient {dg}");
    }

    #[test]
    fn softmax_matches_the_composed_definition() {
        let v: Vec<f32> = (0..2 * 3 * 5).map(|i| ((i * 17) % 13) as f32 * 0.7 - 4.0).collect();
        let x = var(&v, &[2, 3, 5]);
        let (dv, dg) =
            compare1(&x, |t| softmax_last_dim(t).unwrap(), |t| candle_nn::ops::softmax(t, D::Minus1).unwrap());
        assert!(dv < 1e-6 && dg < 1e-5, "value {dv}, gradient {dg}");
        let rows = softmax_last_dim(x.as_tensor()).unwrap().sum(D::Minus1).unwrap().flatten_all().unwrap();
        assert!(rows.to_vec1::<f32>().unwrap().iter().all(|s| (s - 1.0).abs() < 1e-6));
    }

    #[test]
    fn layer_norm_matches_the_composed_definition() {
        let xv: Vec<f32> = (0..4 * 6).map(|i| ((i * 29) % 11) as f32 * 0.9 - 3.0).collect();
        let (x, gain, bias) = (
            var(&xv, &[4, 6]),
            var(&[1.5, 0.5, -1.0, 2.0, 1.0, 0.1], &[6]),
            var(&[0.0, 1.0, 2.0, -1.0, 0.3, 0.0], &[6]),
        );
        let ours = layer_norm(&x, &gain, &bias, 1e-5).unwrap();
        let theirs = composed::layer_norm(&x, &gain, &bias, 1e-5).unwrap();
        assert!(max_diff(&ours, &theirs) < 1e-5);
        let (ga, gb) = (weighted_sum(&ours).backward().unwrap(), weighted_sum(&theirs).backward().unwrap());
        for v in [&x, &gain, &bias] {
            let d = max_diff(ga.get(v).unwrap(), gb.get(v).unwrap());
            assert!(d < 1e-4, "gradient differs by {d}");
        }
    }

    #[test]
    fn constants_build_no_graph_and_bad_inputs_are_errors() {
        let x = Tensor::new(&[[1f32, 2.0], [3.0, -1.0]], &Device::Cpu).unwrap();
        assert!(!gelu(&x).unwrap().track_op());
        assert!(!softmax_last_dim(&x).unwrap().track_op());
        let f64s = x.to_dtype(candle_core::DType::F64).unwrap();
        assert!(gelu(&f64s).is_err());
        assert!(softmax_last_dim(&f64s).is_err());
        let short = Tensor::new(&[1f32], &Device::Cpu).unwrap();
        assert!(layer_norm(&x, &short, &short, 1e-5).is_err());
        let empty = Tensor::zeros((2, 0), candle_core::DType::F32, &Device::Cpu).unwrap();
        assert!(softmax_last_dim(&empty).is_err());
    }

    /// The composed path of every block (what runs on a device without the kernels) gives the
    /// kernels' values and gradients, within `f32` rounding.
    #[test]
    fn composed_paths_match_the_kernels() {
        let xv: Vec<f32> = (0..5 * 7).map(|i| ((i * 31) % 17) as f32 * 0.6 - 4.5).chain([0.0, -0.0, 30.0]).collect();
        let n = xv.len() / 2 * 2;
        let x = var(&xv[..n], &[n / 2, 2]);
        let (dv, dg) = compare1(&x, |t| gelu(t).unwrap(), |t| composed::gelu(t).unwrap());
        assert!(dv < 1e-6 && dg < 1e-5, "gelu: value {dv}, gradient {dg}");
        let x = var(&xv[..35], &[5, 7]);
        let (dv, dg) = compare1(&x, |t| softmax_last_dim(t).unwrap(), |t| composed::softmax_last_dim(t).unwrap());
        assert!(dv < 1e-6 && dg < 1e-5, "softmax: value {dv}, gradient {dg}");
        let (gain, bias) =
            (var(&[1.5, 0.5, -1.0, 2.0, 1.0, 0.1, 0.7], &[7]), var(&[0.0, 1.0, 2.0, -1.0, 0.3, 0.0, -0.2], &[7]));
        let pairs = [
            (layer_norm(&x, &gain, &bias, 1e-5).unwrap(), composed::layer_norm(&x, &gain, &bias, 1e-5).unwrap()),
            (add_bias(&x, &bias).unwrap(), composed::add_bias(&x, &bias).unwrap()),
        ];
        for (name, (ours, theirs)) in ["layer norm", "bias"].iter().zip(pairs) {
            assert!(max_diff(&ours, &theirs) < 1e-5, "{name}: value");
            let (ga, gb) = (weighted_sum(&ours).backward().unwrap(), weighted_sum(&theirs).backward().unwrap());
            for v in [&x, &gain, &bias] {
                if let (Some(a), Some(b)) = (ga.get(v), gb.get(v)) {
                    let d = max_diff(a, b);
                    assert!(d < 1e-4, "{name}: gradient differs by {d}");
                } else {
                    assert_eq!(ga.get(v).is_some(), gb.get(v).is_some(), "{name}: the same variables get a gradient");
                }
            }
        }
    }

    proptest! {
        #[test]
        fn kernels_match_their_composed_definitions(v in proptest::collection::vec(-6f32..6.0, 24)) {
            let x = var(&v, &[4, 6]);
            let (dv, dg) = compare1(&x, |t| gelu(t).unwrap(), |t| t.gelu_erf().unwrap());
            prop_assert!(dv < 1e-6 && dg < 1e-5, "gelu: value {dv}, gradient {dg}");
            let (dv, dg) =
                compare1(&x, |t| softmax_last_dim(t).unwrap(), |t| candle_nn::ops::softmax(t, D::Minus1).unwrap());
            prop_assert!(dv < 1e-6 && dg < 1e-5, "softmax: value {dv}, gradient {dg}");
            let gain = Tensor::new(&[1.0f32, -0.5, 2.0, 0.7, 1.1, 0.2], &Device::Cpu).unwrap();
            let bias = Tensor::new(&[0.1f32, 0.0, -0.3, 0.5, 0.0, 1.0], &Device::Cpu).unwrap();
            let (dv, dg) = compare1(
                &x,
                |t| layer_norm(t, &gain, &bias, 1e-5).unwrap(),
                |t| composed::layer_norm(t, &gain, &bias, 1e-5).unwrap(),
            );
            prop_assert!(dv < 1e-5 && dg < 1e-3, "layer norm: value {dv}, gradient {dg}");
        }
    }
}
