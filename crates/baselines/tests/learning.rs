//! Public-boundary tests of the learning baselines (SVM, CNN, LSTM) on synthetic Model-I-like
//! residues (`baselines::synthetic`), small and seeded so that they run in seconds.
//!
//! Documented bounds (docs/baselines.md, "Tests"): on a 20 m GPS bias held for 5 s the
//! detectors reach recall ≥ 0.9, and on a clean Gaussian flight their false-alarm rate is
//! at most 1 %.

use baselines::synthetic::{CHANNELS, SyntheticAttack, SyntheticFlight};
use baselines::{CnnConfig, LstmConfig, NeuralConfig, SvmConfig};
use detection_metrics::Confusion;
use ekf_residue::{DetectError, Detector, Fit, LabelledResidues};
use nn_toolkit::{TrainConfig, WindowConfig};

type TestResult = Result<(), Box<dyn std::error::Error>>;

fn split(seeds: &[u64], n_steps: usize) -> Result<LabelledResidues, Box<dyn std::error::Error>> {
    let attacks: Vec<SyntheticAttack> = (0..n_steps / 600)
        .map(|i| {
            let start_s = 30.0 + 60.0 * i as f64;
            SyntheticAttack { start_s, end_s: start_s + 5.0, bias_m: [20.0, 0.0, 5.0], absorb_tau_s: None }
        })
        .collect();
    let flights = seeds
        .iter()
        .map(|&seed| SyntheticFlight::new(n_steps, seed).generate(&attacks))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(LabelledResidues::new(flights)?)
}

fn check_detector(det: &dyn Detector, exact_online: bool) -> TestResult {
    let test = split(&[104], 2400)?;
    let f = &test.flights()[0];
    let c = Confusion::count(&det.detect(f.series())?, f.labels().ok_or("labels")?);
    assert!(c.recall() >= 0.9, "{} recall {} ({c:?})", det.name(), c.recall());
    let clean = SyntheticFlight::new(6000, 105).generate(&[])?;
    let alarms = det.detect(clean.series())?;
    let far = alarms.iter().filter(|&&a| a).count() as f64 / alarms.len() as f64;
    assert!(far <= 0.01, "{}: false-alarm rate {far}", det.name());
    // Channel check.
    let gps_only = test.select_channels(&CHANNELS[..3])?;
    let err = det.score(gps_only.flights()[0].series()).err().ok_or("expected a channel mismatch")?;
    assert!(matches!(err, DetectError::ChannelMismatch { .. }), "{err}");
    // Streaming: exact for the SVM (its features use only the last w steps); for the
    // networks the online score sees one causal window while the batch score averages the
    // covering windows, so only the alarms (each at its own threshold) are compared, on at
    // least 95 % of the steps.
    let batch = det.score(f.series())?;
    // `score_streaming` is what the online detector gives, computed in batches.
    let streamed = det.score_streaming(f.series())?;
    assert_eq!(streamed.len(), batch.len());
    let mut online = det.online();
    let mut agree = 0usize;
    let n = 1000;
    for (k, step) in f.series().steps().take(n).enumerate() {
        let d = online.update(&step)?;
        assert!(
            (d.score - streamed[k]).abs() <= 1e-4 * (1.0 + streamed[k].abs()),
            "{} step {k}: online {} vs score_streaming {}",
            det.name(),
            d.score,
            streamed[k]
        );
        if (streamed[k] - det.streaming_threshold()).abs() > 1e-4 {
            assert_eq!(d.alarm, streamed[k] > det.streaming_threshold(), "{} step {k}", det.name());
        }
        if exact_online {
            assert!(
                (d.score - batch[k]).abs() <= 1e-9 * (1.0 + batch[k].abs()),
                "{} step {k}: {} vs {}",
                det.name(),
                d.score,
                batch[k]
            );
        }
        agree += usize::from((streamed[k] > det.streaming_threshold()) == (batch[k] > det.threshold()));
    }
    assert!(agree as f64 >= 0.95 * n as f64, "{}: online and batch alarms agree on {agree} of {n} steps", det.name());
    Ok(())
}

#[test]
fn svm_flags_a_gross_gps_bias() -> TestResult {
    let train = split(&[101, 102], 2400)?;
    let valid = split(&[103], 2400)?;
    let svm = SvmConfig { max_train: 400, ..Default::default() }.fit(&train, &valid)?;
    assert!(svm.n_support() > 0);
    check_detector(&svm, true)
}

/// A small, fast network configuration for tests: 20-step windows, 8 epochs.
fn small(mut cfg: NeuralConfig) -> NeuralConfig {
    cfg.window = WindowConfig { len: 20, stride: 5, ..WindowConfig::default() };
    cfg.score_stride = 10;
    cfg.train = TrainConfig { epochs: 8, lr: 3e-3, lr_decay: 1.0, progress: false, ..TrainConfig::default() };
    cfg.hidden = 16;
    cfg
}

#[test]
fn cnn_flags_a_gross_gps_bias() -> TestResult {
    let train = split(&[101, 102], 2400)?;
    let valid = split(&[103], 2400)?;
    let cnn = CnnConfig(small(CnnConfig::default().0)).fit(&train, &valid)?;
    assert!(cnn.train_report().history.len() >= 2);
    check_detector(&cnn, false)
}

/// With the absorbed-offset channels, whose sums reach 400 steps back, the CNN's online
/// detector keeps that history before its window: it gives what `score_streaming` computes
/// over the whole flight (`check_detector` compares 1,000 steps).
#[test]
fn cnn_with_the_absorbed_channels_streams_what_it_scores() -> TestResult {
    let train = split(&[101, 102], 2400)?;
    let valid = split(&[103], 2400)?;
    let mut cfg = small(CnnConfig::default().0);
    cfg.window.features = nn_toolkit::Features::WhitenedLogDriftAbsorbed;
    let cnn = CnnConfig(cfg).fit(&train, &valid)?;
    assert_eq!(cnn.online_window(), 20 + nn_toolkit::Features::WhitenedLogDriftAbsorbed.context());
    check_detector(&cnn, false)
}

#[test]
fn lstm_flags_a_gross_gps_bias() -> TestResult {
    let train = split(&[101, 102], 2400)?;
    let valid = split(&[103], 2400)?;
    let lstm = LstmConfig(small(LstmConfig::default().0)).fit(&train, &valid)?;
    check_detector(&lstm, false)
}

#[test]
fn learning_detectors_are_send_and_sync() {
    fn check<T: Send + Sync>() {}
    check::<baselines::Svm>();
    check::<SvmConfig>();
    check::<baselines::Cnn>();
    check::<baselines::Lstm>();
    check::<CnnConfig>();
    check::<LstmConfig>();
}

#[test]
fn sizes_beyond_their_budgets_are_refused_by_name() {
    let e = |r: baselines::Result<()>| r.unwrap_err().to_string();
    let wide = NeuralConfig { hidden: 1_000_000_000, ..CnnConfig::default().0 };
    assert!(e(wide.check()).contains("`hidden`: 1000000000 exceeds the budget of 4096"));
    let mut heavy = CnnConfig::default().0;
    heavy.hidden = 4_096;
    heavy.window.len = 2_000;
    heavy.train.batch_size = 65_536;
    assert!(e(heavy.check()).contains("more than the budget of 268435456"));
    let svm = SvmConfig { max_train: 1_000_000_000, ..SvmConfig::default() };
    assert!(e(svm.check()).contains("`max_train`: 1000000000 exceeds the budget of 10000"));
    CnnConfig::default().0.check().unwrap();
    LstmConfig::default().0.check().unwrap();
    SvmConfig::default().check().unwrap();
    let mut raw = LstmConfig::default().0;
    raw.window.features = nn_toolkit::Features::Raw;
    assert!(e(raw.check()).contains("train.mix"));
}
