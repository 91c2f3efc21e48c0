//! A one-layer LSTM over a window, `b × l × m → b × l × h`, for the LSTM baseline.
//!
//! The cell is PyTorch's (and `candle_nn::LSTM`'s): gates `[i, f, g, o] = x_t W_ihᵀ + h_{t−1}
//! W_hhᵀ + b_ih + b_hh`, `c_t = σ(f)·c_{t−1} + σ(i)·tanh(g)`, `h_t = σ(o)·tanh(c_t)`, with the
//! same variable names (`weight_ih_l0`, `weight_hh_l0`, `bias_ih_l0`, `bias_hh_l0`) and shapes,
//! so checkpoints and the seeded initialisation are those of `candle_nn::LSTM`.
//!
//! It differs from `candle_nn::LSTM` only in how the biases enter: their sum is repeated over
//! the batch once per window by a rank-1 product ([`repeat_rows`]) instead of being broadcast
//! twice at every step. candle back-propagates a broadcast by a strided scalar sum, which took
//! about 12 % of an LSTM fit (perf on `fit_cell lstm`); the rank-1 product's gradient is a
//! matrix product, accumulated over the steps before it is taken (decision 065).
//!
//! The cell's element-wise part is one candle custom op ([`lstm_cell`]) with a closed-form
//! backward, instead of a dozen candle ops (three sigmoids, two `tanh`, products and sums) per
//! step forward and twice as many backward. With `a` the gates before activation,
//! `i = σ(a_i)`, `f = σ(a_f)`, `g = tanh(a_g)`, `o = σ(a_o)`, `c = f c₋ + i g`, `h = o tanh c`,
//! and incoming gradients `∂h`, `∂c`:
//! `∂c* = ∂c + ∂h · o (1 − tanh² c)`, `∂a_i = ∂c* g i(1 − i)`, `∂a_f = ∂c* c₋ f(1 − f)`,
//! `∂a_g = ∂c* i (1 − g²)`, `∂a_o = ∂h tanh c · o(1 − o)`, `∂c₋ = ∂c* f`.
//! `σ` and `tanh` are computed from `nn_toolkit::vmath::exp`, the loops vectorised with
//! AVX2 where the processor has it (`nn_toolkit::vmath::vectorized`).

use candle_core::{CpuStorage, CustomOp2, IndexOp, Layout, Shape, Tensor};
use candle_nn::{VarBuilder, init};
use nn_toolkit::fused::{f32_slice, with_f32};
use nn_toolkit::layers::repeat_rows;
use nn_toolkit::vmath;

/// A one-layer, forward LSTM.
#[derive(Debug, Clone)]
pub struct LstmLayer {
    w_ih: Tensor,
    w_hh: Tensor,
    b_ih: Tensor,
    b_hh: Tensor,
    hidden: usize,
}

impl LstmLayer {
    /// Creates the variables under `vb` for inputs of `in_dim` channels and `hidden` units;
    /// their values are set by `nn_toolkit::init_vars_seeded`.
    ///
    /// # Errors
    /// candle errors.
    pub fn new(in_dim: usize, hidden: usize, vb: VarBuilder) -> candle_core::Result<Self> {
        let gates = 4 * hidden;
        Ok(Self {
            w_ih: vb.get_with_hints((gates, in_dim), "weight_ih_l0", init::DEFAULT_KAIMING_UNIFORM)?,
            w_hh: vb.get_with_hints((gates, hidden), "weight_hh_l0", init::DEFAULT_KAIMING_UNIFORM)?,
            b_ih: vb.get_with_hints(gates, "bias_ih_l0", init::ZERO)?,
            b_hh: vb.get_with_hints(gates, "bias_hh_l0", init::ZERO)?,
            hidden,
        })
    }

    /// Input width `m` and hidden size `h`.
    pub fn dims(&self) -> (usize, usize) {
        (self.w_ih.dims().get(1).copied().unwrap_or(0), self.hidden)
    }

    /// The weights as row-major `f32` buffers: `W_ih` (`4h × m`), `W_hh` (`4h × h`) and
    /// `b_ih + b_hh` (`4h`, summed as [`LstmLayer::forward`] sums them).
    ///
    /// # Errors
    /// candle errors.
    pub(crate) fn weights(&self) -> candle_core::Result<(Vec<f32>, Vec<f32>, Vec<f32>)> {
        let flat = |t: &Tensor| t.flatten_all()?.to_vec1::<f32>();
        Ok((flat(&self.w_ih)?, flat(&self.w_hh)?, (&self.b_ih + &self.b_hh)?.to_vec1::<f32>()?))
    }

    /// Hidden states of every step of `x` (`b × l × m`), starting from zero state: `b × l × h`.
    ///
    /// # Errors
    /// candle errors, e.g. a wrong input width.
    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        let (b, l, _) = x.dims3()?;
        let hd = self.hidden;
        let bias = repeat_rows(&(&self.b_ih + &self.b_hh)?, b)?;
        let (w_ih, w_hh) = (self.w_ih.t()?, self.w_hh.t()?);
        let mut h = Tensor::zeros((b, hd), x.dtype(), x.device())?;
        let mut c = h.clone();
        let mut states = Vec::with_capacity(l);
        for t in 0..l {
            let x_t = x.i((.., t, ..))?.contiguous()?;
            let gates = ((x_t.matmul(&w_ih)? + h.matmul(&w_hh)?)? + &bias)?;
            let hc = lstm_cell(&gates, &c)?;
            h = hc.narrow(1, 0, hd)?.contiguous()?;
            c = hc.narrow(1, hd, hd)?;
            states.push(h.clone());
        }
        Tensor::stack(&states, 1)
    }
}

/// The LSTM cell's element-wise part (module docs): gates `a` (`b × 4h`, order `i, f, g, o`)
/// and the previous cell state `c₋` (`b × h`) give `[h | c]`, `b × 2h`.
///
/// # Errors
/// Shapes that do not fit, a dtype other than `f32`, a device other than the CPU.
pub fn lstm_cell(gates: &Tensor, c_prev: &Tensor) -> candle_core::Result<Tensor> {
    let (gates, c_prev) = (gates.contiguous()?, c_prev.contiguous()?);
    if gates.track_op() || c_prev.track_op() {
        gates.apply_op2(&c_prev, LstmCell)
    } else {
        gates.apply_op2_no_bwd(&c_prev, &LstmCell)
    }
}

struct LstmCell;

impl LstmCell {
    /// `(b, h)` from the shapes of the gates and the previous state.
    fn dims(&self, gates: &Shape, c_prev: &Shape) -> candle_core::Result<(usize, usize)> {
        let (b, h4) = gates.dims2()?;
        let (bc, h) = c_prev.dims2()?;
        if bc != b || h4 != 4 * h || h == 0 {
            candle_core::bail!("lstm-cell: gates {gates:?} must be b × 4h for a state {c_prev:?} of b × h")
        }
        Ok((b, h))
    }
}

/// `σ(x)` of every element, in place.
#[inline(always)]
fn sigmoid_in_place(x: &mut [f32]) {
    x.iter_mut().for_each(|v| *v = 1.0 / (1.0 + vmath::exp(-*v)));
}

/// `tanh x` of every element, in place, as `1 − 2/(e^{2x} + 1)`.
#[inline(always)]
fn tanh_in_place(x: &mut [f32]) {
    x.iter_mut().for_each(|v| *v = 1.0 - 2.0 / (vmath::exp(2.0 * *v) + 1.0));
}

/// Activated gates of one row: `[i, f, g, o]` in place.
#[inline(always)]
fn activate(row: &mut [f32], h: usize) {
    let (ifg, o) = row.split_at_mut(3 * h);
    let (i_f, g) = ifg.split_at_mut(2 * h);
    sigmoid_in_place(i_f);
    tanh_in_place(g);
    sigmoid_in_place(o);
}

/// The cell's forward pass on `b` rows: `act` holds the gates before activation (`b × 4h`,
/// activated in place), `c_prev` the previous cell states (`b × h`), and `out` receives
/// `[h_t | c_t]` (`b × 2h`). The custom op and the streaming LSTM ([`crate::lstm_online`]) both
/// compute the cell here, so they agree bit for bit.
pub(crate) fn cell_forward(act: &mut [f32], c_prev: &[f32], out: &mut [f32], h: usize) {
    vmath::vectorized(
        #[inline(always)]
        || {
            for ((a, cp), o) in act.chunks_exact_mut(4 * h).zip(c_prev.chunks_exact(h)).zip(out.chunks_exact_mut(2 * h))
            {
                activate(a, h);
                let (ho, co) = o.split_at_mut(h);
                for j in 0..h {
                    co[j] = a[h + j] * cp[j] + a[j] * a[2 * h + j];
                    ho[j] = co[j];
                }
                tanh_in_place(ho);
                for j in 0..h {
                    ho[j] *= a[3 * h + j];
                }
            }
        },
    );
}

impl CustomOp2 for LstmCell {
    fn name(&self) -> &'static str {
        "lstm-cell"
    }

    fn cpu_fwd(
        &self,
        s1: &CpuStorage,
        l1: &Layout,
        s2: &CpuStorage,
        l2: &Layout,
    ) -> candle_core::Result<(CpuStorage, Shape)> {
        let (b, h) = self.dims(l1.shape(), l2.shape())?;
        let (gates, c_prev) = (f32_slice(self.name(), s1, l1)?, f32_slice(self.name(), s2, l2)?);
        let mut act = gates.to_vec();
        let mut out = vec![0f32; b * 2 * h];
        cell_forward(&mut act, c_prev, &mut out, h);
        Ok((CpuStorage::F32(out), Shape::from((b, 2 * h))))
    }

    fn bwd(
        &self,
        gates: &Tensor,
        c_prev: &Tensor,
        res: &Tensor,
        grad: &Tensor,
    ) -> candle_core::Result<(Option<Tensor>, Option<Tensor>)> {
        let (b, h) = self.dims(gates.shape(), c_prev.shape())?;
        let (d_gates, d_c_prev) = with_f32(self.name(), gates, |a_all| {
            with_f32(self.name(), c_prev, |cp_all| {
                with_f32(self.name(), res, |hc_all| {
                    with_f32(self.name(), grad, |g_all| {
                        vmath::vectorized(
                            #[inline(always)]
                            || {
                                let mut act = a_all.to_vec();
                                let mut d_gates = vec![0f32; b * 4 * h];
                                let mut d_c_prev = vec![0f32; b * h];
                                let mut tanh_c = vec![0f32; h];
                                for r in 0..b {
                                    let a = &mut act[r * 4 * h..(r + 1) * 4 * h];
                                    activate(a, h);
                                    let cp = &cp_all[r * h..(r + 1) * h];
                                    let c = &hc_all[r * 2 * h + h..(r + 1) * 2 * h];
                                    let (dh, dc) = grad_row(g_all, r, h);
                                    tanh_c.copy_from_slice(c);
                                    tanh_in_place(&mut tanh_c);
                                    let da = &mut d_gates[r * 4 * h..(r + 1) * 4 * h];
                                    for j in 0..h {
                                        let (i, f, g, o) = (a[j], a[h + j], a[2 * h + j], a[3 * h + j]);
                                        let tc = tanh_c[j];
                                        let dc_total = dc[j] + dh[j] * o * (1.0 - tc * tc);
                                        da[j] = dc_total * g * i * (1.0 - i);
                                        da[h + j] = dc_total * cp[j] * f * (1.0 - f);
                                        da[2 * h + j] = dc_total * i * (1.0 - g * g);
                                        da[3 * h + j] = dh[j] * tc * o * (1.0 - o);
                                        d_c_prev[r * h + j] = dc_total * f;
                                    }
                                }
                                Ok((d_gates, d_c_prev))
                            },
                        )
                    })
                })
            })
        })?;
        Ok((
            Some(Tensor::from_vec(d_gates, gates.shape(), gates.device())?),
            Some(Tensor::from_vec(d_c_prev, c_prev.shape(), c_prev.device())?),
        ))
    }
}

/// The incoming gradients `(∂h, ∂c)` of row `r` of a `b × 2h` gradient.
fn grad_row(g: &[f32], r: usize, h: usize) -> (&[f32], &[f32]) {
    g[r * 2 * h..(r + 1) * 2 * h].split_at(h)
}

#[cfg(test)]
mod tests {
    use candle_core::{DType, Device, Var};
    use candle_nn::VarMap;
    use candle_nn::rnn::{LSTMConfig, RNN};

    use super::*;

    /// The cell composed from candle's ops, as `candle_nn::LSTM` computes it.
    fn composed_cell(gates: &Tensor, c_prev: &Tensor, h: usize) -> Tensor {
        let sig = |k: usize| candle_nn::ops::sigmoid(&gates.narrow(1, k * h, h).unwrap()).unwrap();
        let g = gates.narrow(1, 2 * h, h).unwrap().tanh().unwrap();
        let c = ((sig(1) * c_prev).unwrap() + (sig(0) * g).unwrap()).unwrap();
        let h_new = (sig(3) * c.tanh().unwrap()).unwrap();
        Tensor::cat(&[&h_new, &c], 1).unwrap()
    }

    proptest::proptest! {
        #[test]
        fn cell_matches_the_composed_ops(
            a in proptest::collection::vec(-8f32..8.0, 2 * 4 * 3),
            c in proptest::collection::vec(-3f32..3.0, 2 * 3),
        ) {
            let gates = Var::from_vec(a, (2, 12), &Device::Cpu).unwrap();
            let c_prev = Var::from_vec(c, (2, 3), &Device::Cpu).unwrap();
            let ours = lstm_cell(&gates, &c_prev).unwrap();
            let theirs = composed_cell(&gates, &c_prev, 3);
            let w = Tensor::from_vec((0..12).map(|k| (k % 5) as f32 - 2.0).collect::<Vec<f32>>(), (2, 6), &Device::Cpu).unwrap();
            let diff = |p: &Tensor, q: &Tensor| {
                (p - q).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap()
            };
            proptest::prop_assert!(diff(&ours, &theirs) < 1e-6);
            let ga = (ours * &w).unwrap().sum_all().unwrap().backward().unwrap();
            let gb = (theirs * &w).unwrap().sum_all().unwrap().backward().unwrap();
            for v in [&gates, &c_prev] {
                let d = diff(ga.get(v).unwrap(), gb.get(v).unwrap());
                proptest::prop_assert!(d < 1e-5, "gradient differs by {}", d);
            }
        }
    }

    #[test]
    fn cell_rejects_mismatched_shapes() {
        let gates = Tensor::zeros((2, 8), DType::F32, &Device::Cpu).unwrap();
        assert!(lstm_cell(&gates, &Tensor::zeros((2, 3), DType::F32, &Device::Cpu).unwrap()).is_err());
        assert!(lstm_cell(&gates, &Tensor::zeros((3, 2), DType::F32, &Device::Cpu).unwrap()).is_err());
        assert!(lstm_cell(&gates, &Tensor::zeros((2, 2), DType::F32, &Device::Cpu).unwrap()).is_ok());
    }

    /// Values and gradients agree with `candle_nn::LSTM` on the same variables.
    #[test]
    fn matches_candle_nn_lstm() {
        let vm = VarMap::new();
        let vb = VarBuilder::from_varmap(&vm, DType::F32, &Device::Cpu);
        let ours = LstmLayer::new(3, 5, vb.pp("lstm")).unwrap();
        let theirs = candle_nn::lstm(3, 5, LSTMConfig::default(), vb.pp("lstm")).unwrap();
        nn_toolkit::init_vars_seeded(&vm, 4).unwrap();
        // Non-zero biases, so that their path is exercised.
        let data = vm.data().lock().unwrap();
        let bias: Vec<f32> = (0..20).map(|k| (k as f32 - 10.0) / 25.0).collect();
        data["lstm.bias_ih_l0"].set(&Tensor::new(bias.as_slice(), &Device::Cpu).unwrap()).unwrap();
        let vars: Vec<(String, Var)> = data.iter().map(|(k, v)| (k.clone(), v.clone())).collect();
        drop(data);
        let x: Vec<f32> = (0..2 * 7 * 3).map(|k| ((k * 17) % 11) as f32 / 5.0 - 1.0).collect();
        let x = Tensor::from_vec(x, (2, 7, 3), &Device::Cpu).unwrap();
        let a = ours.forward(&x).unwrap();
        let b = theirs.states_to_tensor(&theirs.seq(&x).unwrap()).unwrap();
        let diff = |p: &Tensor, q: &Tensor| {
            (p - q).unwrap().abs().unwrap().flatten_all().unwrap().max(0).unwrap().to_scalar::<f32>().unwrap()
        };
        assert!(diff(&a, &b) < 1e-6);
        let w: Vec<f32> = (0..2 * 7 * 5).map(|k| (k % 4) as f32 - 1.5).collect();
        let w = Tensor::from_vec(w, (2, 7, 5), &Device::Cpu).unwrap();
        let ga = (a * &w).unwrap().sum_all().unwrap().backward().unwrap();
        let gb = (b * &w).unwrap().sum_all().unwrap().backward().unwrap();
        for (name, var) in &vars {
            let (p, q) = (ga.get(var).unwrap(), gb.get(var).unwrap());
            assert!(diff(p, q) < 1e-5, "{name}: {p} vs {q}");
        }
    }
}
