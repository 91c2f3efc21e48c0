//! End-to-end check of `reproduce-tables` on a micro configuration: every output is written,
//! Tables I and II have the paper's shape, every rate is finite and in [0, 1], and the same seed
//! gives a byte-identical `results.csv` (docs/decisions/061-results-files.md).
#![allow(clippy::unwrap_used)]

use std::path::Path;

use eval::cell::Cell;
use eval::closed_loop::{ClosedLoopRow, Family};
use eval::dataset::SplitSteps;
use eval::methods::Method;
use eval::reproduce::{MatrixConfig, Options, Stages, reproduce};
use eval::table::read_results_csv;

fn micro_options(out: &Path) -> Options {
    let mut config = MatrixConfig::quick();
    config.steps = SplitSteps { train: 1_800, valid: 600, test: 600 };
    config.methods.quadformer.train.max_windows_per_epoch = Some(32);
    config.methods.quadformer.train.epochs = 1;
    for nn in [&mut config.methods.cnn.0, &mut config.methods.lstm.0] {
        nn.train.max_windows_per_epoch = Some(32);
        nn.train.epochs = 1;
    }
    config.methods.svm.max_train = 200;
    config.sweep_sigma = vec![5.0];
    config.ablation_fractions = vec![0.1, 1.0];
    Options {
        config,
        quick: true,
        seeds: 1,
        cells: vec![Cell::parse("m1-exponential-a1").unwrap(), Cell::parse("m1-exponential-a2").unwrap()],
        methods: Method::ALL.to_vec(),
        out: out.to_owned(),
        progress: false,
        stages: Stages::Tables,
    }
}

#[test]
fn quick_matrix_writes_every_output_with_valid_numbers_deterministically() {
    let dir_a = tempfile::tempdir().unwrap();
    let dir_b = tempfile::tempdir().unwrap();
    reproduce(&micro_options(dir_a.path())).unwrap();

    for name in
        ["table1.md", "table1.tex", "table2.md", "table2.tex", "metrics.md", "results.csv", "results.json", "report.md"]
    {
        let len = std::fs::metadata(dir_a.path().join(name)).map(|m| m.len()).unwrap_or(0);
        assert!(len > 0, "{name} missing or empty");
    }
    for fig in ["roc-m1-exponential-a1.png", "cusum-post-attack.svg", "f1-vs-amplitude.png"] {
        assert!(dir_a.path().join("figures").join(fig).exists(), "{fig} missing");
    }

    let rows = read_results_csv(&dir_a.path().join("results.csv")).unwrap();
    assert_eq!(rows.len(), 2 * Method::ALL.len(), "one row per cell and method");
    for r in &rows {
        for (what, v) in [("P", r.precision), ("R", r.recall), ("F1", r.f1), ("AUC", r.roc_auc), ("AP", r.pr_auc)] {
            assert!(v.is_finite() && (0.0..=1.0).contains(&v), "{} {what} = {v}", r.method);
        }
    }
    // Table I: a header, an alignment row and one row per method of the cells run.
    let table1 = std::fs::read_to_string(dir_a.path().join("table1.md")).unwrap();
    let header = table1.lines().find(|l| l.starts_with("| Group")).unwrap();
    assert_eq!(header.matches('|').count(), 2 + 12 + 1, "group, method and 12 P/R/F1 columns");
    for m in Method::ALL {
        assert!(table1.contains(&format!("| {} |", m.name())), "Table I lacks {}", m.name());
    }

    // QUADFormer's cached runs carry every score mode; the chosen one is the run's own result.
    let qf_runs: Vec<_> = std::fs::read_dir(dir_a.path().join("runs").join("m1-exponential-a1"))
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.file_name().unwrap().to_string_lossy().starts_with("quadformer-seed0"))
        .collect();
    assert!(!qf_runs.is_empty());
    for path in qf_runs {
        let rec: eval::runner::RunRecord = serde_json::from_str(&std::fs::read_to_string(&path).unwrap()).unwrap();
        assert_eq!(rec.modes.len(), 4, "{}", path.display());
        let chosen: Vec<_> = rec.modes.iter().filter(|m| m.chosen).collect();
        assert_eq!(chosen.len(), 1);
        assert_eq!(chosen[0].test_f1, rec.result.f1, "{}", path.display());
        assert_eq!(chosen[0].test_auc, rec.result.roc_auc);
    }
    // The ablations take the matrix's study-unit rows: 10% (the matrix's fraction) and 100%.
    let report = std::fs::read_to_string(dir_a.path().join("report.md")).unwrap();
    assert!(report.contains("| QUADFormer | 10% |") && report.contains("| QUADFormer | 100% |"), "{report}");
    assert!(report.contains("| full |") && report.contains("| no TPC |") && report.contains("| no DCM |"));
    assert!(report.contains("score modes over every cell and seed (2 runs)"), "{report}");

    reproduce(&micro_options(dir_b.path())).unwrap();
    let a = std::fs::read(dir_a.path().join("results.csv")).unwrap();
    let b = std::fs::read(dir_b.path().join("results.csv")).unwrap();
    assert_eq!(a, b, "same seed, same results.csv");
}

/// The closed loop (Table III) on one micro unit with two fitted detectors: every family ×
/// detector (fitted ones at two latencies) has a row, every rate is in [0, 1], the oracle
/// excludes exactly the attacked fixes, and the same seed gives the same `closed_loop.csv`.
#[test]
fn quick_closed_loop_writes_table3_deterministically() {
    let run = |dir: &Path| {
        let mut opts = micro_options(dir);
        opts.cells.truncate(1);
        opts.methods = vec![Method::Chi2, Method::Cusum];
        opts.stages = Stages::ClosedLoop;
        reproduce(&opts).unwrap();
    };
    let (dir_a, dir_b) = (tempfile::tempdir().unwrap(), tempfile::tempdir().unwrap());
    run(dir_a.path());
    let rows: Vec<ClosedLoopRow> = csv::Reader::from_path(dir_a.path().join("closed_loop.csv"))
        .unwrap()
        .deserialize()
        .collect::<Result<_, _>>()
        .unwrap();
    assert_eq!(rows.len(), Family::ALL.len() * (3 + 2 * 2), "families × (3 reference + 2 fitted × 2 latencies)");
    for r in &rows {
        for v in [r.precision, r.recall, r.f1] {
            assert!(v.is_finite() && (0.0..=1.0).contains(&v), "{} {}: {v}", r.method, r.family);
        }
        if r.method == "Oracle" && r.n_intervals > 0 {
            assert_eq!((r.f1, r.gps_lost_clean_s), (1.0, 0.0), "{r:?}");
        }
        if r.method == "None" {
            assert_eq!(r.f1, 0.0, "no detector, no alarm: {r:?}");
        }
        assert_eq!(r.threshold.is_some(), r.method == "Chi2" || r.method == "CUSUM", "{r:?}");
        assert!(
            r.alarmed_before_3m.is_none_or(|v| (0.0..=1.0).contains(&v))
                && (r.family == "ramp" || r.alarmed_before_3m.is_none())
        );
    }
    let table3 = std::fs::read_to_string(dir_a.path().join("table3.md")).unwrap();
    assert!(table3.contains("| Chi2 |") && table3.contains("| PX4 EKF2 |"), "{table3}");
    assert!(dir_a.path().join("figures").join("closed-loop-drift.png").exists());
    run(dir_b.path());
    let a = std::fs::read(dir_a.path().join("closed_loop.csv")).unwrap();
    let b = std::fs::read(dir_b.path().join("closed_loop.csv")).unwrap();
    assert_eq!(a, b, "same seed, same closed_loop.csv");
}
