//! Rough timing of QUADFormer's parts at the default size (development aid; the criterion
//! benches give the reported figures): `forward` times the inference forward pass and single
//! candle ops, `train` one summed min-max training step and its parts, `stream tcd|plain`
//! [`STREAM_DECISIONS`] decisions of the streaming engine with or without the TCD.
//!
//! `RAYON_NUM_THREADS=1 CANDLE_NUM_THREADS=1 cargo run --release -p quadformer-model --example profile -- forward|train`
//!
//! The streaming decisions' instructions, repeatable on a noisy machine:
//! `valgrind --tool=callgrind --toggle-collect='*StreamingNet*push*' target/release/examples/profile stream tcd`,
//! then divide the count by [`STREAM_DECISIONS`].

use std::time::Instant;

use candle_core::{D, Device, Tensor};
use nn_toolkit::fused;
use nn_toolkit::loss::masked_bce_with_logits;
use nn_toolkit::tune_allocator;
use quadformer_model::streaming::StreamingNet;
use quadformer_model::{Batch, GradFlow, LossConfig, NetConfig, QuadFormerNet};

/// Prints the median of `n` timed calls of `f`, after a tenth as many untimed ones.
fn time<T>(label: &str, n: usize, mut f: impl FnMut() -> candle_core::Result<T>) -> candle_core::Result<()> {
    for _ in 0..n.div_ceil(10) {
        f()?;
    }
    let mut v = Vec::with_capacity(n);
    for _ in 0..n {
        let t0 = Instant::now();
        f()?;
        v.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    v.sort_by(f64::total_cmp);
    println!("{label:<48} median {:.3} ms", v[n / 2]);
    Ok(())
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    tune_allocator();
    match std::env::args().nth(1).as_deref() {
        Some("forward") => forward(),
        Some("train") => train(),
        Some("stream") => stream(std::env::args().nth(2).as_deref() == Some("tcd")),
        _ => Err("usage: profile forward|train|stream [tcd|plain]".into()),
    }
}

/// Decisions `profile stream` makes.
const STREAM_DECISIONS: usize = 400;

/// Median and fastest time of the streaming engine's decisions after the first 100, on
/// seeded residues, at the default size.
fn stream(with_tcd: bool) -> Result<(), Box<dyn std::error::Error>> {
    let mut net = QuadFormerNet::new(&NetConfig::default(), 100, 6, 0)?;
    net.freeze()?;
    let mut engine = StreamingNet::new(&net)?;
    let mut state = 0x9e37_79b9_u32;
    let mut times = Vec::with_capacity(STREAM_DECISIONS);
    for k in 0..STREAM_DECISIONS {
        let x: Vec<f32> = (0..6)
            .map(|_| {
                state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                (state >> 8) as f32 / (1u32 << 23) as f32 - 1.0
            })
            .collect();
        let t0 = Instant::now();
        engine.push(&x, with_tcd)?;
        if k >= 100 {
            times.push(t0.elapsed().as_secs_f64() * 1e3);
        }
    }
    times.sort_by(f64::total_cmp);
    println!(
        "streaming decision ({}): median {:.3} ms, fastest {:.3} ms over {} decisions",
        if with_tcd { "with the TCD" } else { "without the TCD" },
        times[times.len() / 2],
        times[0],
        times.len()
    );
    Ok(())
}

fn forward() -> Result<(), Box<dyn std::error::Error>> {
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

fn train() -> Result<(), Box<dyn std::error::Error>> {
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
        let class = masked_bce_with_logits(&out.logits, &batch.y, &batch.mask, batch.n_labelled, 1.0)?;
        (recon + class)?.backward()
    })?;
    // The element-wise blocks of one step, forward and backward, at their training sizes.
    let var = |dims: &[usize]| -> candle_core::Result<candle_core::Var> {
        let n: usize = dims.iter().product();
        let v: Vec<f32> = (0..n).map(|i| ((i * 7919) % 1000) as f32 / 300.0 - 1.5).collect();
        candle_core::Var::from_vec(v, dims, &Device::Cpu)
    };
    let ff = var(&[b * l, 128])?;
    time("gelu 3200x128 + backward (candle)", n, || ff.gelu_erf()?.sum_all()?.backward())?;
    time("gelu 3200x128 + backward (fused)", n, || fused::gelu(&ff)?.sum_all()?.backward())?;
    let sc = var(&[b, 1, l, l])?;
    time("softmax 32x100x100 + backward (candle)", n, || {
        candle_nn::ops::softmax(&sc, D::Minus1)?.sum_all()?.backward()
    })?;
    time("softmax 32x100x100 + backward (fused)", n, || fused::softmax_last_dim(&sc)?.sum_all()?.backward())?;
    let hid = var(&[b * l, 64])?;
    let norm_vm = candle_nn::VarMap::new();
    let norm = nn_toolkit::layers::Norm::new(
        64,
        candle_nn::VarBuilder::from_varmap(&norm_vm, candle_core::DType::F32, &Device::Cpu),
    )?;
    time("norm 3200x64 + backward (fused)", n, || norm.forward(&hid)?.sqr()?.sum_all()?.backward())?;
    Ok(())
}
