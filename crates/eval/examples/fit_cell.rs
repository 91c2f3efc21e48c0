//! Fits one method on one cell of the experiment matrix and prints what model selection saw:
//! the training history (learning methods), the validation F1 at the chosen threshold, the
//! ROC AUC on the validation and test splits, and the F1 of the streaming scores on both.
//! This is the tool behind the measured choices in docs/decisions/043 and 053.
//!
//! ```text
//! cargo run --release -p eval --example fit_cell -- <method> <cell> [--seed N] [--config FILE.toml] [--out DIR]
//! cargo run --release -p eval --example fit_cell -- quadformer m1-exponential-a1 --config qf.toml
//! ```
//!
//! The configuration is the paper-scale `reproduce-tables` configuration with the file's keys
//! merged over it (docs/cli.md); datasets are read from, or built into, `DIR/datasets`
//! (default `results/`), the cache `reproduce-tables` uses.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};
use ekf_residue::{Detector, Fit, LabelledResidues};
use eval::cell::Cell;
use eval::methods::Method;
use eval::metrics::{confusion, roc_auc};
use eval::reproduce::{MatrixConfig, Options, load_cell};
use eval::runner::fit;
use quadformer_model::TrainReport;

fn main() -> Result<()> {
    // SAFETY: first thing in `main`, before any other thread exists.
    #[allow(unsafe_code)]
    unsafe {
        eval::runtime::init_cpu_runtime();
    }
    let mut args = std::env::args().skip(1);
    let (Some(method), Some(cell)) = (args.next(), args.next()) else {
        bail!("usage: fit_cell <method> <cell> [--seed N] [--config FILE.toml] [--out DIR]");
    };
    let (method, cell) = (Method::parse(&method)?, Cell::parse(&cell)?);
    let (mut seed, mut config, mut out) = (0u64, MatrixConfig::default(), PathBuf::from("results"));
    while let Some(flag) = args.next() {
        let value = args.next().with_context(|| format!("{flag} needs a value"))?;
        match flag.as_str() {
            "--seed" => seed = value.parse().with_context(|| format!("--seed {value}"))?,
            "--config" => config = MatrixConfig::from_toml_file(value.as_ref(), &config)?,
            "--out" => out = value.into(),
            other => bail!("unknown option {other}"),
        }
    }
    let opts = Options {
        config,
        quick: false,
        seeds: 1,
        cells: vec![cell],
        methods: vec![method],
        out,
        progress: false,
        stages: eval::reproduce::Stages::Tables,
    };
    let data = load_cell(cell, seed, &opts)?;
    let train = data.train_with_labelled_fraction(opts.config.labelled_fraction)?;
    let (valid, test) = (data.valid()?, data.test()?);
    let cfgs = opts.config.methods.seeded(seed);

    let start = std::time::Instant::now();
    let (detector, report): (Box<dyn Detector>, Option<TrainReport>) = match method {
        Method::QuadFormer => {
            let qf = cfgs.quadformer.fit(&train, &valid)?;
            for m in qf.mode_results() {
                println!("mode {:<14} valid F1 {:.3}", m.mode.name(), m.valid_f1);
            }
            let report = qf.train_report().cloned();
            (Box::new(qf), report)
        }
        Method::Cnn => {
            let d = cfgs.cnn.fit(&train, &valid)?;
            let report = Some(d.train_report().clone());
            (Box::new(d), report)
        }
        Method::Lstm => {
            let d = cfgs.lstm.fit(&train, &valid)?;
            let report = Some(d.train_report().clone());
            (Box::new(d), report)
        }
        other => (fit(other, &cfgs, &train, &valid)?.detector, None),
    };
    let fit_s = start.elapsed().as_secs_f64();
    if let Some(r) = &report {
        for e in &r.history {
            println!(
                "epoch {:>2}: train loss {:.4}, valid metric {:.4}, {:.1} s",
                e.epoch, e.train_loss, e.valid_metric, e.train_seconds
            );
        }
        println!("best epoch {}, {:.0} windows/s", r.best_epoch, r.windows_per_s());
    }
    let (valid_f1, valid_auc) = f1_and_auc(detector.as_ref(), &valid)?;
    let (test_f1, test_auc) = f1_and_auc(detector.as_ref(), &test)?;
    println!("{} on {} seed {seed}: fit {fit_s:.1} s", method.name(), cell.slug());
    println!("valid F1 {valid_f1:.3}, valid ROC AUC {valid_auc:.3}; test F1 {test_f1:.3}, test ROC AUC {test_auc:.3}");
    let (valid_f1, test_f1) = (streaming_f1(detector.as_ref(), &valid)?, streaming_f1(detector.as_ref(), &test)?);
    println!("streaming: valid F1 {valid_f1:.3}, test F1 {test_f1:.3}");
    Ok(())
}

/// F1 of the streaming scores at the detector's streaming threshold over a split's labelled
/// flights.
fn streaming_f1(det: &dyn Detector, split: &LabelledResidues) -> Result<f64> {
    let (mut alarms, mut labels) = (Vec::new(), Vec::new());
    for (series, l) in split.labelled() {
        alarms.extend(det.score_streaming(series)?.into_iter().map(|s| s > det.streaming_threshold()));
        labels.extend_from_slice(l);
    }
    Ok(confusion(&alarms, &labels)?.f1())
}

/// F1 at the detector's threshold and ROC AUC of its scores over a split's labelled flights.
fn f1_and_auc(det: &dyn Detector, split: &LabelledResidues) -> Result<(f64, f64)> {
    let (mut scores, mut labels) = (Vec::new(), Vec::new());
    for (series, l) in split.labelled() {
        scores.extend(det.score(series)?);
        labels.extend_from_slice(l);
    }
    let alarms: Vec<bool> = scores.iter().map(|&s| s > det.threshold()).collect();
    Ok((confusion(&alarms, &labels)?.f1(), roc_auc(&scores, &labels)?))
}
