//! Rough timing of the streaming forward pass and its parts (development aid; criterion
//! benches give the reported figures).
//!
//! `cargo run --release -p quadformer-model --example profile_forward`

use std::time::Instant;

use candle_core::{D, Device, Tensor};
use quadformer_model::{GradFlow, NetConfig, QuadFormerNet, tune_allocator};

fn time<T>(label: &str, n: usize, mut f: impl FnMut() -> candle_core::Result<T>) -> candle_core::Result<()> {
    for _ in 0..n / 10 {
        f()?;
    }
    let mut v = Vec::with_capacity(n);
    for _ in 0..n {
        let t0 = Instant::now();
        f()?;
        v.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    v.sort_by(f64::total_cmp);
    println!("{label:<40} median {:.3} ms", v[n / 2]);
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    tune_allocator();
    let mut net = QuadFormerNet::new(&NetConfig::default(), 100, 6, 0)?;
    net.freeze()?;
    println!("parameters: {}", net.n_params());
    let x = Tensor::zeros((1, 100, 6), candle_core::DType::F32, &Device::Cpu)?;
    time("forward b=1", 300, || net.forward(&x))?;
    let out = net.forward(&x)?;
    time("tcd b=1", 300, || QuadFormerNet::tcd(&out, GradFlow::Pass, GradFlow::Pass))?;
    let a = out.attn[0].clone();
    time("softmax 100x100", 300, || candle_nn::ops::softmax(&a, D::Minus1))?;
    time("log 100x100", 300, || a.log())?;
    time("exp 100x100", 300, || a.exp())?;
    time("matmul 100x100x64", 300, || {
        a.squeeze(0)?.squeeze(0)?.matmul(&Tensor::zeros((100, 64), candle_core::DType::F32, &Device::Cpu)?)
    })?;
    let h = Tensor::zeros((100, 64), candle_core::DType::F32, &Device::Cpu)?;
    let w = Tensor::zeros((64, 64), candle_core::DType::F32, &Device::Cpu)?;
    time("matmul 100x64 · 64x64ᵀ", 300, || h.matmul(&w.t()?))?;
    time("add 100x64", 300, || &h + &h)?;
    time("gelu_erf 100x128", 300, || Tensor::zeros((100, 128), candle_core::DType::F32, &Device::Cpu)?.gelu_erf())?;
    let xb = Tensor::zeros((32, 100, 6), candle_core::DType::F32, &Device::Cpu)?;
    time("forward b=32", 20, || net.forward(&xb))?;
    Ok(())
}
