//! Building blocks of the QUADFormer network: a dense layer and a layer norm, each made of one
//! matrix product at most and the kernels of [`crate::fused`], and [`repeat_rows`], a
//! broadcast whose gradient is a matrix product.
//!
//! candle 0.11 back-propagates a broadcast by summing the gradient over the broadcast axis, and
//! for any axis but the last that sum is a scalar loop with an integer division per element.
//! Repeating a row vector `v` as the rank-1 product `1ₙ v` gives the same values, and its
//! gradient `1ₙᵀ g` is one vectorised matrix product (decision 065).
//!
//! Variable names (`weight`, `bias`) and shapes are those of `candle_nn::Linear` and the
//! PyTorch layer norm, so checkpoints and the seeded initialisation ([`crate::init`]) are
//! unchanged.

use candle_core::Tensor;
use candle_nn::{Init, VarBuilder};

/// Layer-norm variance guard (PyTorch default).
pub const LN_EPS: f32 = 1e-5;

/// `v` (any shape, `d` elements) repeated over `n` rows: `n × d`, equal to
/// `v.reshape((1, d)).broadcast_as((n, d))`, with a gradient computed as a matrix product
/// (module docs).
///
/// # Errors
/// candle errors.
pub fn repeat_rows(v: &Tensor, n: usize) -> candle_core::Result<Tensor> {
    let ones = Tensor::ones((n, 1), v.dtype(), v.device())?;
    ones.matmul(&v.reshape((1, v.elem_count()))?)
}

/// A dense layer `y = x Wᵀ + b` on rows `x` (`n × in`), `W` stored `out × in`.
pub struct Dense {
    weight: Tensor,
    bias: Tensor,
}

impl Dense {
    /// Creates `weight` (`out × in`) and `bias` (`out`) under `vb`; their values are set by
    /// [`crate::init::init_vars_seeded`].
    ///
    /// # Errors
    /// candle errors.
    pub fn new(in_dim: usize, out_dim: usize, vb: VarBuilder) -> candle_core::Result<Self> {
        Ok(Self {
            weight: vb.get_with_hints((out_dim, in_dim), "weight", candle_nn::init::DEFAULT_KAIMING_NORMAL)?,
            bias: vb.get_with_hints(out_dim, "bias", Init::Const(0.0))?,
        })
    }

    /// `x Wᵀ + b` for `x` of shape `n × in` (the bias by [`crate::fused::add_bias`]).
    ///
    /// # Errors
    /// candle errors, e.g. a wrong input width.
    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        crate::fused::add_bias(&x.matmul(&self.weight.t()?)?, &self.bias)
    }

    /// The weight `W`, `out × in`.
    pub fn weight(&self) -> &Tensor {
        &self.weight
    }

    /// The bias `b`, `out` values.
    pub fn bias(&self) -> &Tensor {
        &self.bias
    }
}

/// Layer norm over the last axis of rows `x` (`n × d`) with a learnable gain and bias.
pub struct Norm {
    gain: Tensor,
    bias: Tensor,
}

impl Norm {
    /// Creates `weight` (gain, 1) and `bias` (0) of width `d` under `vb`.
    ///
    /// # Errors
    /// candle errors.
    pub fn new(d: usize, vb: VarBuilder) -> candle_core::Result<Self> {
        Ok(Self {
            gain: vb.get_with_hints(d, "weight", Init::Const(1.0))?,
            bias: vb.get_with_hints(d, "bias", Init::Const(0.0))?,
        })
    }

    /// The normalised rows ([`crate::fused::layer_norm`], one kernel forward and backward, in
    /// training and inference alike).
    ///
    /// # Errors
    /// candle errors.
    pub fn forward(&self, x: &Tensor) -> candle_core::Result<Tensor> {
        crate::fused::layer_norm(x, &self.gain, &self.bias, LN_EPS)
    }

    /// The gain `γ`, `d` values (variable `weight`).
    pub fn gain(&self) -> &Tensor {
        &self.gain
    }

    /// The bias `β`, `d` values.
    pub fn bias(&self) -> &Tensor {
        &self.bias
    }
}

#[cfg(test)]
mod tests {
    use candle_core::{DType, Device, Var};
    use candle_nn::VarMap;

    use super::*;

    fn close(a: &Tensor, b: &Tensor) -> f32 {
        (a - b).unwrap().abs().unwrap().max_all().unwrap().to_scalar::<f32>().unwrap()
    }

    fn input(n: usize, d: usize) -> Tensor {
        let v: Vec<f32> = (0..n * d).map(|i| ((i * 37) % 23) as f32 / 7.0 - 1.5).collect();
        Tensor::from_vec(v, (n, d), &Device::Cpu).unwrap()
    }

    #[test]
    fn repeat_rows_has_the_values_and_gradient_of_a_broadcast() {
        let v = Var::from_vec(vec![1f32, -2.0, 0.5], 3, &Device::Cpu).unwrap();
        let g = input(4, 3);
        let ours = repeat_rows(v.as_tensor(), 4).unwrap();
        let theirs = v.as_tensor().reshape((1, 3)).unwrap().broadcast_as((4, 3)).unwrap();
        assert_eq!(close(&ours, &theirs), 0.0);
        let grad_ours = (ours * &g).unwrap().sum_all().unwrap().backward().unwrap();
        let grad_theirs = (theirs * &g).unwrap().sum_all().unwrap().backward().unwrap();
        let (a, b) = (grad_ours.get(&v).unwrap(), grad_theirs.get(&v).unwrap());
        assert!(close(a, b) < 1e-6, "{a} vs {b}");
    }

    #[test]
    fn dense_and_norm_match_candle_nn() {
        let vm = VarMap::new();
        let vb = VarBuilder::from_varmap(&vm, DType::F32, &Device::Cpu);
        let dense = Dense::new(5, 3, vb.pp("d")).unwrap();
        let norm = Norm::new(3, vb.pp("n")).unwrap();
        crate::init::init_vars_seeded(&vm, 3).unwrap();
        let data = vm.data().lock().unwrap();
        data["d.bias"].set(&Tensor::new(&[0.1f32, -0.2, 0.3], &Device::Cpu).unwrap()).unwrap();
        data["n.weight"].set(&Tensor::new(&[1.5f32, 0.5, -1.0], &Device::Cpu).unwrap()).unwrap();
        data["n.bias"].set(&Tensor::new(&[0.0f32, 1.0, 2.0], &Device::Cpu).unwrap()).unwrap();
        let linear =
            candle_nn::Linear::new(data["d.weight"].as_tensor().clone(), Some(data["d.bias"].as_tensor().clone()));
        let x = input(6, 5);
        let y = dense.forward(&x).unwrap();
        assert!(close(&y, &candle_core::Module::forward(&linear, &x).unwrap()) < 1e-6);
        let candle = candle_nn::ops::layer_norm(&y, data["n.weight"].as_tensor(), data["n.bias"].as_tensor(), LN_EPS);
        assert!(close(&norm.forward(&y).unwrap(), &candle.unwrap()) < 1e-5);
    }
}
