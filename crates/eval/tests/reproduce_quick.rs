//! End-to-end check of `reproduce-tables` on a micro configuration: every output is written,
//! Tables I and II have the paper's shape, every rate is finite and in [0, 1], and the same seed
//! gives a byte-identical `results.csv` (issue 6, "Checks").
#![allow(clippy::unwrap_used)]

use std::path::Path;

use eval::dataset::SplitSteps;
use eval::reproduce::{MatrixConfig, Options, parse_cell, reproduce};
use eval::runner::Method;
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
    config.ablation_fractions = vec![1.0];
    Options {
        config,
        quick: true,
        seeds: 1,
        cells: vec![parse_cell("m1-exponential-a1").unwrap(), parse_cell("m1-exponential-a2").unwrap()],
        methods: Method::ALL.to_vec(),
        out: out.to_owned(),
        progress: false,
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

    reproduce(&micro_options(dir_b.path())).unwrap();
    let a = std::fs::read(dir_a.path().join("results.csv")).unwrap();
    let b = std::fs::read(dir_b.path().join("results.csv")).unwrap();
    assert_eq!(a, b, "same seed, same results.csv");
}
