//! Criterion benchmarks of QUADFormer at the default size (`l` = 100, `d_model` 64, 3 layers,
//! one head, `m` = 6 residue channels): streaming decision latency (one new residue) and
//! training throughput (one min-max AdamW step on a batch of 32 windows); and the two logarithms
//! of `vmath` the Jensen–Shannon terms use.
//!
//! Run with `cargo bench -p quadformer-model`; figures go to docs/performance.md.

// A benchmark harness aborts on setup failure; unwrapping is the clearest way to say so.
#![allow(clippy::unwrap_used)]

use candle_core::{Device, Tensor};
use candle_nn::{AdamW, Optimizer, ParamsAdamW};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ekf_residue::{Fit, LabelledResidues, LabelledSeries, ResidueSeries};
use nn_toolkit::tune_allocator;
use nn_toolkit::vmath;
use quadformer_model::model::MinMaxTrainer;
use quadformer_model::{Batch, LossConfig, NetConfig, QuadFormerConfig, QuadFormerNet, ScoreMode, TrainableModel};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

const M: usize = 6;
const L: usize = 100;

fn flight(n: usize, seed: u64) -> LabelledSeries {
    let mut rng = StdRng::seed_from_u64(seed);
    let labels: Vec<bool> = (0..n).map(|k| k % 200 >= 170).collect();
    let r: Vec<f64> = labels
        .iter()
        .flat_map(|&a| (0..M).map(|_| rng.random_range(-1.0..1.0) + if a { 3.0 } else { 0.0 }).collect::<Vec<_>>())
        .collect();
    let s: Vec<f64> = (0..n).flat_map(|_| (0..M * M).map(|i| if i % (M + 1) == 0 { 1.0 } else { 0.0 })).collect();
    let channels = (0..M).map(|c| format!("r{c}")).collect();
    let series = ResidueSeries::from_flat((0..n).map(|k| k as f64 * 0.1).collect(), channels, r, s).unwrap();
    LabelledSeries::new(series, Some(labels)).unwrap()
}

fn streaming(c: &mut Criterion) {
    tune_allocator();
    let split = LabelledResidues::new(vec![flight(600, 1)]).unwrap();
    let f = flight(400, 2);
    let steps: Vec<_> = f.series().steps().collect();
    // The default network, the smaller one a deployment can choose (docs/performance.md) and
    // the causal one of the closed loop (docs/decisions/092-causal-loop-quadformer.md).
    let nets = [(64, 128, false), (32, 64, false), (64, 128, true)];
    for (mode, (d_model, d_ff, causal)) in
        nets.iter().flat_map(|&s| [(ScoreMode::Combined, s), (ScoreMode::Classifier, s)])
    {
        let mut cfg = QuadFormerConfig::default();
        cfg.net.d_model = d_model;
        cfg.net.d_ff = d_ff;
        cfg.net.causal = causal;
        cfg.train.epochs = 1;
        cfg.train.max_windows_per_epoch = Some(32);
        cfg.train.progress = false;
        cfg.score.mode = Some(mode);
        let det = cfg.fit(&split, &split).unwrap();
        let mut online = det.online_quadformer();
        for s in &steps[..L] {
            ekf_residue::OnlineDetector::update(&mut online, s).unwrap();
        }
        let mut k = L;
        c.bench_function(
            &format!(
                "streaming decision, {} mode (l=100, d_model={d_model}, 3 layers, m=6{})",
                mode.name(),
                if causal { ", causal" } else { "" }
            ),
            |b| {
                b.iter(|| {
                    k = if k + 1 >= steps.len() { L } else { k + 1 };
                    ekf_residue::OnlineDetector::update(&mut online, &steps[k]).unwrap()
                })
            },
        );
    }
}

fn training(c: &mut Criterion) {
    tune_allocator();
    let net = QuadFormerNet::new(&NetConfig::default(), L, M, 0).unwrap();
    let trainer = MinMaxTrainer { net: &net, loss: LossConfig::default() };
    let mut opt = AdamW::new(net.varmap().all_vars(), ParamsAdamW::default()).unwrap();
    let b = 32;
    let mut rng = StdRng::seed_from_u64(3);
    let x: Vec<f32> = (0..b * L * M).map(|_| rng.random_range(-1.0f32..1.0)).collect();
    let y: Vec<f32> = (0..b * L).map(|i| if i % 9 == 0 { 1.0 } else { 0.0 }).collect();
    let batch = Batch {
        x: Tensor::from_vec(x, (b, L, M), &Device::Cpu).unwrap(),
        y: Tensor::from_vec(y, (b, L), &Device::Cpu).unwrap(),
        mask: Tensor::ones((b, L), candle_core::DType::F32, &Device::Cpu).unwrap(),
        n_labelled: b * L,
    };
    let mut group = c.benchmark_group("training");
    group.sample_size(20);
    group.throughput(Throughput::Elements(b as u64));
    group.bench_function("min-max AdamW step, batch 32 windows (elements = windows)", |bch| {
        bch.iter(|| {
            let loss = trainer.loss(&batch, 0).unwrap();
            opt.backward_step(&loss).unwrap();
        })
    });
    group.bench_function("forward only, batch 32 windows (elements = windows)", |bch| {
        bch.iter(|| net.forward(&batch.x).unwrap())
    });
    group.finish();
}

/// The two logarithms of `vmath` over 30,000 values (the Jensen–Shannon terms of a streaming
/// decision in the combined mode take 60,000).
fn logarithms(c: &mut Criterion) {
    let x: Vec<f32> = (0..30_000).map(|i| (i as f32 + 1.0) / 30_000.0 + 1e-8).collect();
    let mut group = c.benchmark_group("vmath");
    group.throughput(Throughput::Elements(x.len() as u64));
    // Generic so that each logarithm is inlined into its vectorised loop.
    fn run(
        group: &mut criterion::BenchmarkGroup<'_, criterion::measurement::WallTime>,
        name: &str,
        x: &[f32],
        f: impl Fn(f32) -> f32 + Copy,
    ) {
        let mut y = vec![0f32; x.len()];
        group.bench_function(format!("{name}, 30k values"), |b| {
            b.iter(|| {
                vmath::vectorized(
                    #[inline(always)]
                    || {
                        for (o, &v) in y.iter_mut().zip(x) {
                            *o = f(v);
                        }
                    },
                )
            })
        });
    }
    run(&mut group, "ln (Cephes)", &x, vmath::ln);
    run(&mut group, "ln_fast (atanh)", &x, vmath::ln_fast);
    group.finish();
}

criterion_group!(benches, streaming, training, logarithms);
criterion_main!(benches);
