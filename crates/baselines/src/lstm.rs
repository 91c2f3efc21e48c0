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

use candle_core::{IndexOp, Tensor};
use candle_nn::{VarBuilder, init};
use quadformer_model::layers::repeat_rows;

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
    /// their values are set by `quadformer_model::init_vars_seeded`.
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
            let sig = |k: usize| candle_nn::ops::sigmoid(&gates.narrow(1, k * hd, hd)?);
            let (i, f, o) = (sig(0)?, sig(1)?, sig(3)?);
            let g = gates.narrow(1, 2 * hd, hd)?.tanh()?;
            c = ((f * &c)? + (i * g)?)?;
            h = (o * c.tanh()?)?;
            states.push(h.clone());
        }
        Tensor::stack(&states, 1)
    }
}

#[cfg(test)]
mod tests {
    use candle_core::{DType, Device, Var};
    use candle_nn::VarMap;
    use candle_nn::rnn::{LSTMConfig, RNN};

    use super::*;

    /// Values and gradients agree with `candle_nn::LSTM` on the same variables.
    #[test]
    fn matches_candle_nn_lstm() {
        let vm = VarMap::new();
        let vb = VarBuilder::from_varmap(&vm, DType::F32, &Device::Cpu);
        let ours = LstmLayer::new(3, 5, vb.pp("lstm")).unwrap();
        let theirs = candle_nn::lstm(3, 5, LSTMConfig::default(), vb.pp("lstm")).unwrap();
        quadformer_model::init_vars_seeded(&vm, 4).unwrap();
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
