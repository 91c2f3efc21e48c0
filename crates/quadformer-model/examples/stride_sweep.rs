//! Window-stride sweep on seeded synthetic residues: for each training stride, fit QUADFormer
//! with the default configuration and report training time, validation and test F1, and test
//! F1 per minute of training (docs/decisions/041-window-stride.md).
//!
//! Data: 6 channels of `N(0, 1)` residues; Attack I bursts (5–30 steps, 3–6 σ on the three GPS
//! channels) and Attack II intervals (100–250 steps, ramp to 2–4 σ), about 12% attacked steps;
//! 10% of training flights labelled. This stands in for the EKF residues until the dataset
//! builder of `eval` is wired in.
//!
//! `cargo run --release -p quadformer-model --example stride_sweep -- [n_train_flights] [epochs] [strides...]`

use std::time::Instant;

use detection_metrics::Confusion;
use ekf_residue::{Detector, Fit, LabelledResidues, LabelledSeries, ResidueSeries};
use nn_toolkit::tune_allocator;
use quadformer_model::QuadFormerConfig;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};

const M: usize = 6;
const N: usize = 500;

fn normal(rng: &mut StdRng) -> f64 {
    // Box–Muller.
    let u1: f64 = rng.random_range(f64::EPSILON..1.0);
    let u2: f64 = rng.random_range(0.0..1.0);
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

fn flight(seed: u64, labelled: bool) -> Result<LabelledSeries, Box<dyn std::error::Error>> {
    let mut rng = StdRng::seed_from_u64(seed);
    let mut offset = vec![0.0f64; N];
    let mut k = rng.random_range(20..80);
    while k < N {
        if rng.random_range(0.0..1.0) < 0.7 {
            let len = rng.random_range(5..30);
            let amp = rng.random_range(3.0..6.0);
            for o in offset.iter_mut().skip(k).take(len) {
                *o = amp;
            }
            k += len + rng.random_range(100..250);
        } else {
            let len = rng.random_range(100..250);
            let amp = rng.random_range(2.0..4.0);
            for (i, o) in offset.iter_mut().skip(k).take(len).enumerate() {
                *o = amp * (i as f64 / 30.0).min(1.0);
            }
            k += len + rng.random_range(400..900);
        }
    }
    let labels: Vec<bool> = offset.iter().map(|&o| o != 0.0).collect();
    let mut r = Vec::with_capacity(N * M);
    for &o in &offset {
        for c in 0..M {
            r.push(normal(&mut rng) + if c < 3 { o } else { 0.0 });
        }
    }
    let s: Vec<f64> = (0..N).flat_map(|_| (0..M * M).map(|i| if i % (M + 1) == 0 { 1.0 } else { 0.0 })).collect();
    let channels = ["gps_x", "gps_y", "gps_z", "att_roll", "att_pitch", "att_yaw"].map(String::from).to_vec();
    let series = ResidueSeries::from_flat((0..N).map(|k| k as f64 * 0.1).collect(), channels, r, s)?;
    Ok(LabelledSeries::new(series, labelled.then_some(labels))?)
}

fn split(first_seed: u64, n: usize, labelled_every: usize) -> Result<LabelledResidues, Box<dyn std::error::Error>> {
    let flights =
        (0..n).map(|i| flight(first_seed + i as u64, i % labelled_every == 0)).collect::<Result<Vec<_>, _>>()?;
    Ok(LabelledResidues::new(flights)?)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    tune_allocator();
    let args: Vec<String> = std::env::args().skip(1).collect();
    let n_train: usize = args.first().map_or(Ok(24), |s| s.parse())?;
    let epochs: usize = args.get(1).map_or(Ok(4), |s| s.parse())?;
    let strides: Vec<usize> = if args.len() > 2 {
        args[2..].iter().map(|s| s.parse()).collect::<Result<_, _>>()?
    } else {
        vec![50, 25, 10, 5, 2]
    };
    let train = split(1000, n_train, 10)?;
    let valid = split(2000, 6, 1)?;
    let test = split(3000, 10, 1)?;
    let attacked: usize = test.labelled().map(|(_, l)| l.iter().filter(|&&a| a).count()).sum();
    println!(
        "train {} steps ({} flights, 10% labelled), valid {} steps, test {} steps ({:.1}% attacked), epochs ≤ {epochs}",
        train.n_steps(),
        n_train,
        valid.n_steps(),
        test.n_steps(),
        100.0 * attacked as f64 / test.n_steps() as f64
    );
    println!(
        "| stride | windows/epoch | epochs run | train+valid time (s) | train windows/s | valid F1 | test F1 | mode | test F1 per min |"
    );
    println!("|---|---|---|---|---|---|---|---|---|");
    for stride in strides {
        let mut cfg = QuadFormerConfig::default();
        cfg.window.stride = stride;
        cfg.train.epochs = epochs;
        cfg.train.progress = false;
        let t0 = Instant::now();
        let det = cfg.fit(&train, &valid)?;
        let secs = t0.elapsed().as_secs_f64();
        let mut c = Confusion::default();
        for (s, l) in test.labelled() {
            c.add(Confusion::count(&det.detect(s)?, l));
        }
        let rep = det.train_report().ok_or("no report")?;
        let n_win = quadformer_model::Windows::from_split(&train, det.normaliser(), &cfg.window)?.len();
        println!(
            "| {stride} | {n_win} | {} | {secs:.1} | {:.0} | {:.3} | {:.3} | {} | {:.3} |",
            rep.history.len(),
            rep.windows_per_s(),
            det.chosen().valid_f1,
            c.f1(),
            det.chosen().mode.name(),
            c.f1() / (secs / 60.0)
        );
    }
    Ok(())
}
