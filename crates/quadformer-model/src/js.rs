//! Row-wise Jensen–Shannon divergence, the kernel of the Temporal-Contextual Disparity (TCD,
//! sec:attack_detector), as one candle custom op with a hand-written backward.
//!
//! For distributions `p` and `q` over the last axis, with `m = (p + q)/2` and a guard `ε` in
//! every logarithm,
//!
//! `JS(p, q) = ½ Σⱼ [pⱼ (ln(pⱼ+ε) − ln(mⱼ+ε)) + qⱼ (ln(qⱼ+ε) − ln(mⱼ+ε))]`, `0 ≤ JS ≤ ln 2`,
//!
//! `∂JS/∂pⱼ = ½ [ln(pⱼ+ε) − ln(mⱼ+ε) + pⱼ/(pⱼ+ε) − mⱼ/(mⱼ+ε)]` (and symmetrically for `q`).
//!
//! Composed from candle's element-wise ops the divergence and its gradient took about 20 % of
//! a training step: a dozen passes over every `b × heads × l × l` map, each allocating its
//! result and, backwards, a zero-filled gradient. The kernel makes one vectorised pass forward
//! and one backward ([`nn_toolkit::vmath`]). `p` may be shared by the batch (leading axis 1, the
//! TPC prior); its gradient is then summed over the batch. Each input's gradient is passed,
//! stopped or reversed ([`GradFlow`]), which is how the min-max phases split the discrepancy.
//!
//! The kernel runs on the CPU; on another device (a CUDA build of candle) the divergence is
//! composed from candle's ops ([`js_divergence_composed`]), the same function with candle's
//! automatic backward.

use candle_core::{CpuStorage, CustomOp2, D, Layout, Shape, Tensor};

use nn_toolkit::fused::{f32_slice, with_f32};
use nn_toolkit::vmath;

/// How the gradient of a loss term reaches one of its inputs (the min-max split of
/// Anomaly Transformer's association discrepancy).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum GradFlow {
    /// The gradient passes unchanged.
    Pass,
    /// Stop-gradient (`detach`): the input is a constant.
    Stop,
    /// The gradient passes with its sign flipped (a gradient-reversal layer).
    Reverse,
}

/// Additive guard of the logarithms.
pub const JS_EPS: f32 = 1e-8;

/// `JS(p, q)` over the last axis: shape of `q` without its last axis. `p` has the shape of `q`
/// or the same with leading axis 1 (shared by every batch entry). Gradients reach `p` and `q`
/// as `p_flow` and `q_flow` say.
///
/// # Errors
/// candle errors: a dtype other than `f32`, mismatched shapes, a rank below 1.
pub fn js_divergence_with(p: &Tensor, q: &Tensor, p_flow: GradFlow, q_flow: GradFlow) -> candle_core::Result<Tensor> {
    // A stopped input is detached, not merely given no gradient: candle's backward visits
    // every tracked input of a custom op and expects it to receive one.
    let input = |t: &Tensor, flow: GradFlow| match flow {
        GradFlow::Stop => t.detach().contiguous(),
        GradFlow::Pass | GradFlow::Reverse => t.contiguous(),
    };
    if !q.device().is_cpu() {
        return js_divergence_composed(&flow(p, p_flow)?, &flow(q, q_flow)?);
    }
    let (p, q) = (input(p, p_flow)?, input(q, q_flow)?);
    let op = JsDivergence { p_flow, q_flow };
    if !p.track_op() && !q.track_op() {
        return p.apply_op2_no_bwd(&q, &op);
    }
    p.apply_op2(&q, op)
}

/// `t` with its gradient passed, stopped or reversed: for [`GradFlow::Reverse`],
/// `2 sg(t) − t`, whose value is `t` (exactly: `2t` is exact and so is `2t − t`) and whose
/// gradient is `−1`.
fn flow(t: &Tensor, flow: GradFlow) -> candle_core::Result<Tensor> {
    match flow {
        GradFlow::Pass => Ok(t.clone()),
        GradFlow::Stop => Ok(t.detach()),
        GradFlow::Reverse => (t.detach() * 2.0)? - t,
    }
}

/// `JS(p, q)` over the last axis composed from candle's element-wise ops (module docs' formula,
/// with candle's automatic backward): what [`js_divergence_with`] runs off the CPU. `p` has the
/// shape of `q` or leading axis 1.
///
/// # Errors
/// candle errors: shapes that do not broadcast.
pub fn js_divergence_composed(p: &Tensor, q: &Tensor) -> candle_core::Result<Tensor> {
    let eps = f64::from(JS_EPS);
    let p = p.broadcast_as(q.shape())?;
    let ln_m = (((&p + q)? * 0.5)? + eps)?.log()?;
    let kl_pm = (&p * ((&p + eps)?.log()? - &ln_m)?)?.sum(D::Minus1)?;
    let kl_qm = (q * ((q + eps)?.log()? - &ln_m)?)?.sum(D::Minus1)?;
    (kl_pm + kl_qm)? * 0.5
}

/// [`js_divergence_with`] with both gradients passed.
///
/// # Errors
/// As [`js_divergence_with`].
pub fn js_divergence(p: &Tensor, q: &Tensor) -> candle_core::Result<Tensor> {
    js_divergence_with(p, q, GradFlow::Pass, GradFlow::Pass)
}

struct JsDivergence {
    p_flow: GradFlow,
    q_flow: GradFlow,
}

/// Row geometry: `rows` of `q`, row length `len`, and how many rows `p` has (`rows` or
/// `rows / batch` when shared).
struct Geometry {
    len: usize,
    rows: usize,
    p_rows: usize,
}

fn geometry(p: &Shape, q: &Shape) -> candle_core::Result<Geometry> {
    let (pd, qd) = (p.dims(), q.dims());
    let Some(&len) = qd.last() else { candle_core::bail!("js_divergence: rank-0 input") };
    let shared = pd.len() == qd.len() && pd.len() > 1 && pd[0] == 1 && pd[1..] == qd[1..];
    if pd != qd && !shared {
        candle_core::bail!("js_divergence: p {p:?} must have the shape of q {q:?}, or leading axis 1")
    }
    if len == 0 {
        candle_core::bail!("js_divergence: empty last axis")
    }
    Ok(Geometry { len, rows: q.elem_count() / len, p_rows: p.elem_count() / len })
}

/// `JS(p, q)` of one row from `p`, its `ln(p + ε)` and `q`, with `terms` (the row's length)
/// as scratch. Inlined into a loop that runs in [`vmath::vectorized`].
#[inline(always)]
pub(crate) fn js_row(p: &[f32], ln_p: &[f32], q: &[f32], terms: &mut [f32]) -> f32 {
    for (((t, &pj), &lpj), &qj) in terms.iter_mut().zip(p).zip(ln_p).zip(q) {
        let lm = vmath::ln(0.5 * (pj + qj) + JS_EPS);
        *t = pj * (lpj - lm) + qj * (vmath::ln(qj + JS_EPS) - lm);
    }
    0.5 * vmath::sum(terms)
}

/// `mⱼ ln(mⱼ + ε)` of every entry of the mixture `m = (p + q)/2` of two maps, into `terms`,
/// with the logarithm [`vmath::ln_fast`]. With the rows' own `Σ pⱼ ln(pⱼ + ε)` and
/// `Σ qⱼ ln qⱼ` a row's sum gives `JS(p, q) = ½ (Σ p ln p + Σ q ln q) − Σ m ln m`: one
/// logarithm per entry where [`js_row`] takes two. The streaming engine computes the TCD so
/// ([`crate::streaming`]), over whole maps, so that no row leaves a remainder to scalar code.
#[inline(always)]
pub(crate) fn mixture_entropy_terms(p: &[f32], q: &[f32], terms: &mut [f32]) {
    for ((t, &pj), &qj) in terms.iter_mut().zip(p).zip(q) {
        let m = 0.5 * (pj + qj);
        *t = m * vmath::ln_fast(m + JS_EPS);
    }
}

/// `ln(xⱼ + ε)` of every element.
#[inline(always)]
pub(crate) fn ln_eps(x: &[f32]) -> Vec<f32> {
    let mut out = vec![0f32; x.len()];
    for (o, v) in out.iter_mut().zip(x) {
        *o = vmath::ln(v + JS_EPS);
    }
    out
}

/// `(∂JS/∂p, ∂JS/∂q)` times the incoming gradient `g` (one value per row), each scaled by its
/// sign (`None`: no gradient).
#[inline(always)]
fn gradients(
    geo: &Geometry,
    pv: &[f32],
    qv: &[f32],
    gv: &[f32],
    p_sign: Option<f32>,
    q_sign: Option<f32>,
) -> (Option<Vec<f32>>, Option<Vec<f32>>) {
    // ln(x + ε) is needed only for x's own gradient.
    let ln_p = if p_sign.is_some() { ln_eps(pv) } else { Vec::new() };
    let ln_q = if q_sign.is_some() { ln_eps(qv) } else { Vec::new() };
    let mut dp = p_sign.map(|_| vec![0f32; pv.len()]);
    let mut dq = q_sign.map(|_| vec![0f32; qv.len()]);
    // Per row, shared by both gradients: ln(m + ε) and m/(m + ε).
    let (mut ln_m, mut ratio_m) = (vec![0f32; geo.len], vec![0f32; geo.len]);
    for (r, (q_row, &g_row)) in qv.chunks_exact(geo.len).zip(gv).enumerate() {
        let (off, row) = ((r % geo.p_rows) * geo.len, r * geo.len);
        let p_row = &pv[off..off + geo.len];
        for (((lm, rm), &pj), &qj) in ln_m.iter_mut().zip(ratio_m.iter_mut()).zip(p_row).zip(q_row) {
            let m = 0.5 * (pj + qj);
            *lm = vmath::ln(m + JS_EPS);
            *rm = m / (m + JS_EPS);
        }
        let half_g = 0.5 * g_row;
        if let (Some(d), Some(s)) = (dp.as_mut(), p_sign) {
            accumulate_row(&mut d[off..off + geo.len], p_row, &ln_p[off..off + geo.len], &ln_m, &ratio_m, s * half_g);
        }
        if let (Some(d), Some(s)) = (dq.as_mut(), q_sign) {
            accumulate_row(&mut d[row..row + geo.len], q_row, &ln_q[row..row + geo.len], &ln_m, &ratio_m, s * half_g);
        }
    }
    (dp, dq)
}

/// One input's gradient row, `dⱼ += k·(ln(xⱼ + ε) − ln(mⱼ + ε) + xⱼ/(xⱼ + ε) − mⱼ/(mⱼ + ε))`
/// with `k = ±½g` (accumulated: a `p` shared by the batch sums over it).
#[inline(always)]
fn accumulate_row(d: &mut [f32], x: &[f32], ln_x: &[f32], ln_m: &[f32], ratio_m: &[f32], k: f32) {
    for ((((dj, &xj), &lx), &lm), &rm) in d.iter_mut().zip(x).zip(ln_x).zip(ln_m).zip(ratio_m) {
        *dj += k * (lx - lm + xj / (xj + JS_EPS) - rm);
    }
}

impl CustomOp2 for JsDivergence {
    fn name(&self) -> &'static str {
        "js-divergence"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let g = geometry(l1.shape(), l2.shape())?;
        let (p, q) = (f32_slice(self.name(), s1, l1)?, f32_slice(self.name(), s2, l2)?);
        let out = vmath::vectorized(
            #[inline(always)]
            || {
                // ln(p + ε) once per row of p (once per batch when p is shared).
                let ln_p = ln_eps(p);
                let mut terms = vec![0f32; g.len];
                let mut out = Vec::with_capacity(g.rows);
                for (r, q_row) in q.chunks_exact(g.len).enumerate() {
                    let off = (r % g.p_rows) * g.len;
                    out.push(js_row(&p[off..off + g.len], &ln_p[off..off + g.len], q_row, &mut terms));
                }
                out
            },
        );
        let mut dims = l2.shape().dims().to_vec();
        dims.pop();
        Ok((CpuStorage::F32(out), Shape::from(dims)))
    }

    fn bwd(
        &self,
        p: &Tensor,
        q: &Tensor,
        _res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
        // No gradient for an input that does not track one (a constant or a stopped input).
        let sign = |flow: GradFlow, t: &Tensor| match flow {
            _ if !t.track_op() => None,
            GradFlow::Pass => Some(1f32),
            GradFlow::Stop => None,
            GradFlow::Reverse => Some(-1f32),
        };
        let (p_sign, q_sign) = (sign(self.p_flow, p), sign(self.q_flow, q));
        if p_sign.is_none() && q_sign.is_none() {
            return Ok((None, None));
        }
        let geo = geometry(p.shape(), q.shape())?;
        let name = self.name();
        let (dp, dq) = with_f32(name, p, |pv| {
            with_f32(name, q, |qv| {
                with_f32(name, grad, |gv| {
                    Ok(vmath::vectorized(
                        #[inline(always)]
                        || gradients(&geo, pv, qv, gv, p_sign, q_sign),
                    ))
                })
            })
        })?;
        let wrap = |v: Option<Vec<f32>>, like: &Tensor| -> candle_core::Result<Option<Tensor>> {
            v.map(|v| Tensor::from_vec(v, like.shape(), like.device())).transpose()
        };
        Ok((wrap(dp, p)?, wrap(dq, q)?))
    }
}

#[cfg(test)]
mod tests {
    use candle_core::{DType, Device, Var};
    use proptest::prelude::*;

    use super::*;

    fn composed(p: &Tensor, q: &Tensor) -> Tensor {
        js_divergence_composed(p, q).unwrap()
    }

    /// Rows of a softmax of `raw`, shape `dims`.
    fn distributions(raw: &[f32], dims: &[usize]) -> Tensor {
        let t = Tensor::from_slice(raw, dims, &Device::Cpu).unwrap();
        candle_nn::ops::softmax(&(t * 3.0).unwrap(), D::Minus1).unwrap()
    }

    fn max_diff(a: &Tensor, b: &Tensor) -> f32 {
        (a - b).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap()
    }

    /// Values and gradients (with a weighting `w` of the rows) of the kernel and the composed
    /// definition, for `p` of shape `p_dims` and `q` of shape `q_dims`.
    fn compare(raw_p: &[f32], raw_q: &[f32], p_dims: &[usize], q_dims: &[usize]) -> (f32, f32, f32) {
        let p = Var::from_tensor(&distributions(raw_p, p_dims)).unwrap();
        let q = Var::from_tensor(&distributions(raw_q, q_dims)).unwrap();
        let rows = q.elem_count() / q_dims[q_dims.len() - 1];
        let w = Tensor::from_vec((0..rows).map(|i| 1.0 + i as f32 * 0.25).collect(), rows, &Device::Cpu).unwrap();
        let ours = js_divergence(&p, &q).unwrap();
        let theirs = composed(&p, &q);
        let loss = |t: &Tensor| (t.flatten_all().unwrap() * &w).unwrap().sum_all().unwrap();
        let (go, gt) = (loss(&ours).backward().unwrap(), loss(&theirs).backward().unwrap());
        (
            max_diff(&ours, &theirs),
            max_diff(go.get(&p).unwrap(), gt.get(&p).unwrap()),
            max_diff(go.get(&q).unwrap(), gt.get(&q).unwrap()),
        )
    }

    #[test]
    fn shared_prior_matches_the_composed_definition() {
        let raw_p: Vec<f32> = (0..2 * 5 * 5).map(|i| ((i * 13) % 7) as f32 / 7.0).collect();
        let raw_q: Vec<f32> = (0..3 * 2 * 5 * 5).map(|i| ((i * 29) % 11) as f32 / 11.0).collect();
        let (v, gp, gq) = compare(&raw_p, &raw_q, &[1, 2, 5, 5], &[3, 2, 5, 5]);
        assert!(v < 1e-6 && gp < 1e-4 && gq < 1e-4, "value {v}, grad p {gp}, grad q {gq}");
    }

    #[test]
    fn flows_stop_and_reverse_the_gradients() {
        let p = Var::from_tensor(&distributions(&[0.1, 0.9, 0.3, 0.2, 0.5, 0.0], &[2, 3])).unwrap();
        let q = Var::from_tensor(&distributions(&[0.7, 0.1, 0.4, 0.9, 0.2, 0.3], &[2, 3])).unwrap();
        let pass = js_divergence(&p, &q).unwrap().sum_all().unwrap().backward().unwrap();
        let mixed = js_divergence_with(&p, &q, GradFlow::Stop, GradFlow::Reverse).unwrap();
        assert_eq!(mixed.to_vec1::<f32>().unwrap(), js_divergence(&p, &q).unwrap().to_vec1::<f32>().unwrap());
        let mixed = mixed.sum_all().unwrap().backward().unwrap();
        assert!(mixed.get(&p).is_none());
        let flipped = mixed.get(&q).unwrap().neg().unwrap();
        assert_eq!(max_diff(&flipped, pass.get(&q).unwrap()), 0.0);
        let none = js_divergence_with(&p, &q, GradFlow::Stop, GradFlow::Stop).unwrap();
        assert!(none.sum_all().unwrap().backward().unwrap().get(&q).is_none());
    }

    /// The composed path (what runs off the CPU) gives the kernel's values and gradients with
    /// every flow of the gradients, also with a prior shared by the batch.
    #[test]
    fn composed_path_matches_the_kernel_with_every_flow() {
        let raw_p: Vec<f32> = (0..2 * 4 * 4).map(|i| ((i * 13) % 7) as f32 / 7.0).collect();
        let raw_q: Vec<f32> = (0..3 * 2 * 4 * 4).map(|i| ((i * 29) % 11) as f32 / 11.0).collect();
        let p = Var::from_tensor(&distributions(&raw_p, &[1, 2, 4, 4])).unwrap();
        let q = Var::from_tensor(&distributions(&raw_q, &[3, 2, 4, 4])).unwrap();
        let flows = [GradFlow::Pass, GradFlow::Stop, GradFlow::Reverse];
        for (p_flow, q_flow) in flows.iter().flat_map(|&a| flows.iter().map(move |&b| (a, b))) {
            let kernel = js_divergence_with(&p, &q, p_flow, q_flow).unwrap();
            let comp = js_divergence_composed(&flow(&p, p_flow).unwrap(), &flow(&q, q_flow).unwrap()).unwrap();
            assert!(max_diff(&kernel, &comp) < 1e-6, "{p_flow:?} {q_flow:?}: values");
            let (gk, gc) = (kernel.sum_all().unwrap().backward().unwrap(), comp.sum_all().unwrap().backward().unwrap());
            for (name, v, f) in [("p", &p, p_flow), ("q", &q, q_flow)] {
                match (gk.get(v), gc.get(v)) {
                    (Some(a), Some(b)) => assert!(max_diff(a, b) < 1e-4, "{p_flow:?} {q_flow:?}: gradient of {name}"),
                    (a, b) => {
                        // A stopped input gets no gradient from the kernel, a zero one at most
                        // from the composed ops.
                        assert_eq!(f, GradFlow::Stop, "{name}");
                        assert!(a.is_none());
                        assert!(b.is_none_or(|g| max_diff(g, &g.zeros_like().unwrap()) == 0.0));
                    }
                }
            }
        }
    }

    #[test]
    fn bad_inputs_are_errors() {
        let a = Tensor::zeros((2, 3), DType::F32, &Device::Cpu).unwrap();
        let b = Tensor::zeros((2, 4), DType::F32, &Device::Cpu).unwrap();
        assert!(js_divergence(&a, &b).is_err());
        assert!(js_divergence(&a.to_dtype(DType::F64).unwrap(), &a.to_dtype(DType::F64).unwrap()).is_err());
    }

    proptest! {
        /// The streaming engine's form `½ (Σ p ln p + Σ q ln q) − Σ m ln m`, with `Σ q ln q`
        /// from the scores of `q`, against [`js_row`]: they differ by rounding and by at most
        /// `len · ε` (the unguarded `Σ q ln q`), also where scores 60 apart underflow `q`.
        #[test]
        fn entropy_form_matches_the_row_kernel(
            raw_p in proptest::collection::vec(-2f32..2.0, 40),
            scores in proptest::collection::vec(-30f32..30.0, 40),
        ) {
            let p = distributions(&raw_p, &[40]).to_vec1::<f32>().unwrap();
            let (mut q, mut scratch, mut ent_q) = (scores.clone(), vec![0f32; 40], [0f32]);
            nn_toolkit::fused::softmax_rows(&mut q, 40, Some((&mut ent_q, &mut scratch)));
            let ln_p = ln_eps(&p);
            let ent_p = vmath::dot(&p, &ln_p);
            mixture_entropy_terms(&p, &q, &mut scratch);
            let entropy_form = 0.5 * (ent_p + ent_q[0]) - vmath::sum(&scratch);
            let direct = js_row(&p, &ln_p, &q, &mut scratch);
            prop_assert!((entropy_form - direct).abs() < 40.0 * JS_EPS + 2e-6, "{entropy_form} vs {direct}");
            prop_assert!((-1e-6..=std::f32::consts::LN_2 + 1e-6).contains(&entropy_form));
        }

        #[test]
        fn kernel_matches_the_composed_definition(
            raw_p in proptest::collection::vec(-2f32..2.0, 24),
            raw_q in proptest::collection::vec(-2f32..2.0, 24),
        ) {
            let (v, gp, gq) = compare(&raw_p, &raw_q, &[2, 3, 4], &[2, 3, 4]);
            prop_assert!(v < 1e-6 && gp < 1e-4 && gq < 1e-4, "value {v}, grad p {gp}, grad q {gq}");
        }
    }
}
