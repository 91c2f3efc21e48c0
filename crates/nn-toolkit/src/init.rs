//! Seeded initialisation of every variable of a [`VarMap`].
//!
//! candle's CPU random generator cannot be seeded (in candle 0.11 `Device::Cpu.set_seed` returns
//! an error, and `Tensor::randn` and the `Init` initialisers draw from `rand::rng()`), so a
//! model is built with any initialiser and then every variable is overwritten here from a
//! seeded [`StdRng`]. Variables are visited in sorted name order, so the result depends only on
//! the names, shapes and seed.
//!
//! Rule (PyTorch's `nn.Linear`/`nn.Conv1d` default bound):
//! - a variable of rank ≥ 2 is drawn from `U(−1/√fan_in, 1/√fan_in)` with `fan_in` the product
//!   of all dimensions after the first (candle stores `Linear` weights as `out × in`);
//! - a variable whose last name segment contains `bias` is set to zero;
//! - any other rank-0/1 variable (norm gains, learnable scalars) is left as constructed, so it
//!   must be built with a constant initialiser (`Init::Const`).
//!
//! Variables that need another rule (QUADFormer's TPC width `γ`) are set by their owner after
//! calling [`init_vars_seeded`].

use candle_core::{Device, Tensor};
use candle_nn::VarMap;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

use crate::error::{NnError, Result};

/// Overwrites every variable of `varmap` from a generator seeded with `seed` (rule in the
/// module docs).
///
/// # Errors
/// [`NnError::Candle`] if a variable cannot be set, [`NnError::Data`] if the map's lock
/// is poisoned.
pub fn init_vars_seeded(varmap: &VarMap, seed: u64) -> Result<()> {
    let data = varmap.data().lock().map_err(|_| NnError::Data { msg: "variable map lock poisoned".into() })?;
    let mut names: Vec<&String> = data.keys().collect();
    names.sort();
    let mut rng = StdRng::seed_from_u64(seed);
    for name in names {
        let Some(var) = data.get(name) else { continue };
        let dims = var.dims().to_vec();
        let n: usize = dims.iter().product();
        let last = name.rsplit('.').next().unwrap_or(name);
        let values: Vec<f32> = if last.contains("bias") {
            vec![0.0; n]
        } else if dims.len() >= 2 {
            let fan_in: usize = dims[1..].iter().product();
            let bound = 1.0 / (fan_in.max(1) as f32).sqrt();
            (0..n).map(|_| rng.random_range(-bound..bound)).collect()
        } else {
            continue;
        };
        // Drawn on the CPU whatever the variable's device, so the values do not depend on it.
        let t =
            Tensor::from_vec(values, dims.as_slice(), &Device::Cpu)?.to_dtype(var.dtype())?.to_device(var.device())?;
        var.set(&t)?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use candle_core::DType;
    use candle_nn::{Init, VarBuilder};

    use super::*;

    fn build(seed: u64) -> Vec<f32> {
        let vm = VarMap::new();
        let vb = VarBuilder::from_varmap(&vm, DType::F32, &Device::Cpu);
        let _l = candle_nn::linear(4, 3, vb.pp("lin")).unwrap();
        let _g = vb.get_with_hints(3, "gain", Init::Const(1.0)).unwrap();
        init_vars_seeded(&vm, seed).unwrap();
        let data = vm.data().lock().unwrap();
        let mut out = data["lin.weight"].flatten_all().unwrap().to_vec1::<f32>().unwrap();
        out.extend(data["lin.bias"].to_vec1::<f32>().unwrap());
        out.extend(data["gain"].to_vec1::<f32>().unwrap());
        out
    }

    #[test]
    fn same_seed_same_values_and_rule() {
        let a = build(7);
        assert_eq!(a, build(7));
        assert_ne!(a, build(8));
        assert!(a[..12].iter().all(|v| v.abs() <= 0.5));
        assert_eq!(&a[12..15], &[0.0; 3]);
        assert_eq!(&a[15..], &[1.0; 3]);
    }
}
