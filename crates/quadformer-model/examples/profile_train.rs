//! Rough timing of one training step and its parts (development aid; criterion benches give
//! the reported figures).
//!
//! `CANDLE_NUM_THREADS=1 RAYON_NUM_THREADS=1 cargo run --release -p quadformer-model --example profile_train`

use std::time::Instant;

use candle_core::{Device, Tensor};
use quadformer_model::model::masked_bce_with_logits;
use quadformer_model::{Batch, GradFlow, LossConfig, NetConfig, QuadFormerNet, tune_allocator};

fn time<T>(label: &str, n: usize, mut f: impl FnMut() -> candle_core::Result<T>) -> candle_core::Result<()> {
    f()?;
    let mut v = Vec::with_capacity(n);
    for _ in 0..n {
        let t0 = Instant::now();
        f()?;
        v.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    v.sort_by(f64::total_cmp);
    println!("{label:<48} median {:.1} ms", v[n / 2]);
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    tune_allocator();
    let net = QuadFormerNet::new(&NetConfig::default(), 100, 6, 0)?;
    let (b, l, m) = (32, 100, 6);
    let x: Vec<f32> = (0..b * l * m).map(|i| ((i * 7919) % 1000) as f32 / 500.0 - 1.0).collect();
    let y: Vec<f32> = (0..b * l).map(|i| if i % 9 == 0 { 1.0 } else { 0.0 }).collect();
    let batch = Batch {
        x: Tensor::from_vec(x, (b, l, m), &Device::Cpu)?,
        y: Tensor::from_vec(y, (b, l), &Device::Cpu)?,
        mask: Tensor::ones((b, l), candle_core::DType::F32, &Device::Cpu)?,
        n_labelled: b * l,
    };
    let cfg = LossConfig::default();
    let n = 40;
    time("forward b=32", n, || net.forward(&batch.x))?;
    let out = net.forward(&batch.x)?;
    time("tcd (Pass, Reverse) b=32", n, || QuadFormerNet::tcd(&out, GradFlow::Pass, GradFlow::Reverse))?;
    time("summed loss (forward)", n, || net.summed_min_max_loss(&batch, &cfg))?;
    time("summed loss + backward", n, || net.summed_min_max_loss(&batch, &cfg)?.backward())?;
    time("recon + class loss + backward (no TCD)", n, || {
        let out = net.forward(&batch.x)?;
        let recon = (&out.r_hat - &batch.x)?.sqr()?.mean_all()?;
        let class = masked_bce_with_logits(&out.logits, &batch.y, &batch.mask, batch.n_labelled)?;
        (recon + class)?.backward()
    })?;
    Ok(())
}
