//! Dataset-builder speed: simulate → attack → EKF → labelled residues.
//!
//! - Criterion: building the `--quick` cell (5,000 residue steps) for Model I and Model II on one
//!   thread, and loading the Model II one from its cache bytes.
//! - One-shot: with `QF_DATASET_PAPER=1`, every paper-scale cell listed below (121,100 residue
//!   steps, about 12,110 s of flight, 2.4 M IMU steps) is built once on a one-thread rayon pool
//!   and once on the default pool, and the wall times are printed as Markdown table rows
//!   (`QF_DATASET_ALL=1` times all 30 cells instead of one per model and noise shape).
//!
//! Run: `QF_DATASET_PAPER=1 cargo bench -p eval --bench dataset`; figures go to
//! docs/performance.md, section "Datasets".

use std::hint::black_box;
use std::time::Instant;

use attack_inject::AttackKind;
use criterion::{Criterion, criterion_group};
use ekf_residue::residues::ModelKind;
use eval::dataset::{Dataset, DatasetConfig, Split, build};
use uav_dynamics::noise::NoiseShape;

fn one_thread() -> rayon::ThreadPool {
    match rayon::ThreadPoolBuilder::new().num_threads(1).build() {
        Ok(pool) => pool,
        Err(e) => {
            eprintln!("cannot build a one-thread pool: {e}");
            std::process::exit(1);
        }
    }
}

fn quick_cells(c: &mut Criterion) {
    let pool = one_thread();
    let mut group = c.benchmark_group("dataset_quick_1thread");
    group.sample_size(10);
    for model in [ModelKind::ModelI, ModelKind::ModelII] {
        let Ok(cfg) = DatasetConfig::quick(model, NoiseShape::Laplace, AttackKind::Sparse).check() else {
            continue;
        };
        group.bench_function(cfg.get().cell_name(), |b| {
            b.iter(|| pool.install(|| black_box(build(&cfg).map(|d| d.summary(Split::Train).steps))));
        });
    }
    group.finish();

    // Loading a cached cell: checksum, decode and re-validation of every series.
    let mut group = c.benchmark_group("dataset_quick_load");
    group.sample_size(10);
    if let Ok(cfg) = DatasetConfig::quick(ModelKind::ModelII, NoiseShape::Laplace, AttackKind::Sparse).check()
        && let Ok(bytes) = build(&cfg).and_then(|d| d.to_bytes())
    {
        group.bench_function(format!("{} ({} bytes)", cfg.get().cell_name(), bytes.len()), |b| {
            b.iter(|| black_box(Dataset::from_bytes(&bytes, &cfg).is_ok()));
        });
    }
    group.finish();
}

fn paper_scale() {
    if std::env::var_os("QF_DATASET_PAPER").is_none() {
        return;
    }
    let all = std::env::var_os("QF_DATASET_ALL").is_some();
    let pool = one_thread();
    println!(
        "| cell | residue steps (train/valid/test) | attacked | 1 thread (s) | {} threads (s) |",
        rayon::current_num_threads()
    );
    println!("|---|---|---|---|---|");
    for model in [ModelKind::ModelI, ModelKind::ModelII] {
        for noise in NoiseShape::ALL {
            let kinds: &[AttackKind] = if all { &AttackKind::ALL } else { &[AttackKind::Sparse] };
            for &kind in kinds {
                let cfg = match DatasetConfig::paper(model, noise, kind).check() {
                    Ok(cfg) => cfg,
                    Err(e) => {
                        eprintln!("{e}");
                        continue;
                    }
                };
                let start = Instant::now();
                let one = pool.install(|| build(&cfg));
                let t_one = start.elapsed().as_secs_f64();
                let start = Instant::now();
                let many = build(&cfg);
                let t_many = start.elapsed().as_secs_f64();
                match (one, many) {
                    (Ok(a), Ok(b)) => {
                        let s = Split::ALL.map(|sp| a.summary(sp));
                        let steps: usize = s.iter().map(|x| x.steps).sum();
                        let attacked: usize = s.iter().map(|x| x.attacked).sum();
                        #[allow(clippy::cast_precision_loss)]
                        let frac = attacked as f64 / steps as f64;
                        let same = a.to_bytes().ok() == b.to_bytes().ok();
                        println!(
                            "| {} | {}/{}/{} | {:.1}% | {t_one:.1} | {t_many:.1}{} |",
                            cfg.get().cell_name(),
                            s[0].steps,
                            s[1].steps,
                            s[2].steps,
                            100.0 * frac,
                            if same { "" } else { " (NOT byte-identical)" }
                        );
                    }
                    (Err(e), _) | (_, Err(e)) => eprintln!("{}: {e}", cfg.get().cell_name()),
                }
            }
        }
    }
}

// Plots off: criterion's plotters backend needs system fonts that CI machines may lack.
criterion_group! {
    name = benches;
    config = Criterion::default().without_plots();
    targets = quick_cells
}

fn main() {
    paper_scale();
    benches();
    Criterion::default().without_plots().configure_from_args().final_summary();
}
