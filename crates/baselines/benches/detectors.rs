//! Criterion benchmarks of the baselines (docs/performance.md, "Baselines"):
//! - statistical detectors: batch scoring throughput in residue steps per second (target
//!   ≥ 10 M steps/s) and the CUSUM online update;
//! - learning detectors: training time (one SVM fit at fixed `(C, γ)`; one CNN/LSTM epoch) and
//!   per-step inference, batch and streaming (`online()`, one step at a time).
//!
//! Data: synthetic Model-I-like residues (`baselines::synthetic`, 6 channels, 10 Hz).
// A benchmark is not library code: a failed fit should stop it loudly.
#![allow(clippy::expect_used)]

use baselines::synthetic::{SyntheticAttack, SyntheticFlight};
use baselines::{
    BhtConfig, Chi2Config, CnnConfig, CusumConfig, LstmConfig, Px4GateConfig, SprtConfig, SvmConfig, Tuning,
};
use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ekf_residue::{Detector, Fit, LabelledResidues};
use nn_toolkit::TrainConfig;
use std::hint::black_box;

fn split(seeds: &[u64], n_steps: usize) -> LabelledResidues {
    let attacks: Vec<SyntheticAttack> = (0..n_steps / 600)
        .map(|i| {
            let start_s = 30.0 + 60.0 * i as f64;
            SyntheticAttack { start_s, end_s: start_s + 5.0, bias_m: [3.0, 0.0, 1.0], absorb_tau_s: None }
        })
        .collect();
    let flights =
        seeds.iter().map(|&s| SyntheticFlight::new(n_steps, s).generate(&attacks).expect("synthetic flight")).collect();
    LabelledResidues::new(flights).expect("split")
}

fn statistical(c: &mut Criterion) {
    let train = split(&[1], 6000);
    let series = split(&[2], 100_000).flights()[0].series().clone();
    let tb = Tuning::Textbook;
    let dets: Vec<Box<dyn Detector>> = vec![
        Box::new(Chi2Config { tuning: tb, ..Default::default() }.fit(&train, &train).expect("fit")),
        Box::new(CusumConfig { tuning: tb, ..Default::default() }.fit(&train, &train).expect("fit")),
        Box::new(SprtConfig { tuning: tb, ..Default::default() }.fit(&train, &train).expect("fit")),
        Box::new(BhtConfig { tuning: tb, ..Default::default() }.fit(&train, &train).expect("fit")),
        Box::new(Px4GateConfig { tuning: tb, ..Default::default() }.fit(&train, &train).expect("fit")),
    ];
    let mut g = c.benchmark_group("statistical_score");
    g.throughput(Throughput::Elements(series.len() as u64));
    for det in &dets {
        g.bench_function(det.name(), |b| b.iter(|| black_box(det.score(black_box(&series)).expect("score"))));
    }
    g.finish();
    let mut g = c.benchmark_group("statistical_online");
    g.throughput(Throughput::Elements(series.len() as u64));
    for det in &dets {
        g.bench_function(det.name(), |b| {
            b.iter(|| {
                let mut online = det.online();
                let mut n = 0usize;
                for step in series.steps() {
                    n += usize::from(online.update(&step).expect("update").alarm);
                }
                black_box(n)
            })
        });
    }
    g.finish();
}

fn learning(c: &mut Criterion) {
    nn_toolkit::tune_allocator();
    let train = split(&[11, 12], 5000);
    let valid = split(&[13], 3000);
    let test = split(&[14], 10_000).flights()[0].series().clone();

    let svm_cfg = SvmConfig { c_grid: vec![1.0], gamma_grid: vec![1.0], ..Default::default() };
    let mut g = c.benchmark_group("learning_train");
    g.sample_size(10);
    g.bench_function("SVM fit (2000 samples, one C, gamma)", |b| {
        b.iter(|| black_box(svm_cfg.fit(&train, &valid).expect("fit")))
    });
    let one_epoch = TrainConfig { epochs: 1, progress: false, ..TrainConfig::default() };
    let cnn_cfg = CnnConfig(baselines::NeuralConfig { train: one_epoch.clone(), ..CnnConfig::default().0 });
    let lstm_cfg = LstmConfig(baselines::NeuralConfig { train: one_epoch, ..LstmConfig::default().0 });
    g.bench_function("CNN one epoch (10k steps, l=100, stride 10)", |b| {
        b.iter(|| black_box(cnn_cfg.fit(&train, &valid).expect("fit")))
    });
    g.bench_function("LSTM one epoch (10k steps, l=100, stride 10)", |b| {
        b.iter(|| black_box(lstm_cfg.fit(&train, &valid).expect("fit")))
    });
    g.finish();

    let svm = svm_cfg.fit(&train, &valid).expect("fit");
    let cnn = cnn_cfg.fit(&train, &valid).expect("fit");
    let lstm = lstm_cfg.fit(&train, &valid).expect("fit");
    let mut g = c.benchmark_group("learning_score");
    g.sample_size(10);
    g.throughput(Throughput::Elements(test.len() as u64));
    for det in [&svm as &dyn Detector, &cnn, &lstm] {
        g.bench_function(det.name(), |b| b.iter(|| black_box(det.score(black_box(&test)).expect("score"))));
    }
    g.finish();

    // The streaming decision of the closed loop: one `online()` update, the newest step the
    // last of its window (CNN: candle on the window; LSTM: `baselines::lstm_online`).
    let stream: Vec<_> = test.steps().take(1_000).collect();
    let mut g = c.benchmark_group("learning_online");
    g.sample_size(10);
    g.throughput(Throughput::Elements(stream.len() as u64));
    for det in [&cnn as &dyn Detector, &lstm] {
        g.bench_function(det.name(), |b| {
            b.iter(|| {
                let mut online = det.online();
                let mut n = 0usize;
                for step in &stream {
                    n += usize::from(online.update(step).expect("update").alarm);
                }
                black_box(n)
            })
        });
    }
    g.finish();
}

criterion_group!(benches, statistical, learning);
criterion_main!(benches);
