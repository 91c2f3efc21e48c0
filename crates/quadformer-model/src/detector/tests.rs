//! Tests of the fitted detector on small seeded synthetic residue series: Gaussian noise with
//! constant offsets injected in labelled intervals (the shape of a GPS FDI attack's residue).

use std::sync::OnceLock;

use ekf_residue::{LabelledSeries, ResidueError, ResidueStep};
use rand::SeedableRng;
use rand::rngs::StdRng;
use rand_distr::{Distribution, Normal};

use super::*;

const M: usize = 3;
const L: usize = 16;

/// One flight of `n` steps: `N(0, 1)` residues, and `offset` added to all channels inside
/// attack intervals of 12 steps every 60 steps.
fn flight(n: usize, seed: u64, offset: f64, labelled: bool) -> LabelledSeries {
    let mut rng = StdRng::seed_from_u64(seed);
    let normal = Normal::new(0.0, 1.0).unwrap();
    let labels: Vec<bool> = (0..n).map(|k| (k + (seed as usize * 17) % 60) % 60 >= 48).collect();
    let mut r = Vec::with_capacity(n * M);
    for &a in &labels {
        for _ in 0..M {
            r.push(normal.sample(&mut rng) + if a { offset } else { 0.0 });
        }
    }
    let s: Vec<f64> = (0..n).flat_map(|_| [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]).collect();
    let channels = vec!["gps_x".to_string(), "gps_y".into(), "gps_z".into()];
    let series = ResidueSeries::from_flat((0..n).map(|k| k as f64 * 0.1).collect(), channels, r, s).unwrap();
    LabelledSeries::new(series, labelled.then_some(labels)).unwrap()
}

fn split(seeds: &[u64], n: usize, labelled: bool) -> LabelledResidues {
    LabelledResidues::new(seeds.iter().map(|&s| flight(n, s, 4.0, labelled)).collect()).unwrap()
}

fn config() -> QuadFormerConfig {
    let mut c = QuadFormerConfig::tiny(L);
    c.train.epochs = 8;
    c.train.lr = 3e-3;
    c.train.lr_decay = 1.0;
    c.train.patience = 8;
    c.train.seed = 7;
    c
}

fn fitted() -> &'static QuadFormerDetector {
    static DET: OnceLock<QuadFormerDetector> = OnceLock::new();
    DET.get_or_init(|| {
        // Semi-supervised: one of three training flights is labelled.
        let mut flights = split(&[1, 2], 240, false).flights().to_vec();
        flights.push(flight(240, 3, 4.0, true));
        let train = LabelledResidues::new(flights).unwrap();
        config().fit(&train, &split(&[4], 240, true)).unwrap()
    })
}

/// The stitched, unsmoothed batch scores of the detector's streamed mode: what a streaming
/// window's last step is compared with.
fn stitched(det: &QuadFormerDetector, series: &ResidueSeries) -> Vec<f64> {
    det.raw_scores(series).unwrap().mode(det.stream.mode, det.crit_scale)
}

fn f1(det: &QuadFormerDetector, data: &LabelledResidues) -> f64 {
    let mut c = detection_metrics::Confusion::default();
    for (s, l) in data.labelled() {
        c.add(detection_metrics::Confusion::count(&det.detect(s).unwrap(), l));
    }
    c.f1()
}

#[test]
fn learns_to_detect_offsets_and_keeps_every_mode() {
    let det = fitted();
    let report = det.train_report().unwrap();
    assert!(report.history.len() >= 2);
    assert_eq!(det.mode_results().len(), 4);
    assert!(det.mode_results().iter().all(|r| r.threshold.is_finite() && (0.0..=1.0).contains(&r.valid_f1)));
    let test = split(&[5, 6], 240, true);
    let f = f1(det, &test);
    assert!(f > 0.8, "test F1 {f}, chosen {:?}, all {:?}", det.chosen(), det.mode_results());
}

#[test]
fn overfits_a_tiny_labelled_set() {
    let train = LabelledResidues::new(vec![flight(120, 9, 3.0, true)]).unwrap();
    let mut cfg = config();
    cfg.train.epochs = 25;
    cfg.train.patience = 25;
    cfg.score.mode = Some(ScoreMode::Classifier);
    let det = cfg.fit(&train, &train).unwrap();
    let hist = &det.train_report().unwrap().history;
    assert!(hist.last().unwrap().train_loss < hist[0].train_loss);
    assert!(det.chosen().valid_f1 > 0.95, "{:?}", det.chosen());
}

/// The offline score is the chosen mode's stitched score under the centred moving mean chosen
/// on validation; with `score.smoothing` off, no mode is smoothed.
#[test]
fn offline_scores_are_smoothed_as_chosen_on_validation() {
    let det = fitted();
    let widths = detection_metrics::smoothing::half_widths(L);
    assert!(det.mode_results().iter().all(|r| widths.contains(&r.smooth)), "{:?}", det.mode_results());
    let s = flight(200, 22, 4.0, false);
    assert_eq!(det.score(s.series()).unwrap(), centred_mean(&stitched(det, s.series()), det.chosen().smooth));
    for (r, scores) in det.scores_by_mode(s.series()).unwrap() {
        let raw = det.raw_scores(s.series()).unwrap().mode(r.mode, det.crit_scale);
        assert_eq!(scores, centred_mean(&raw, r.smooth), "{:?}", r.mode);
    }
    let mut cfg = config();
    cfg.train.epochs = 1;
    cfg.score.smoothing = false;
    let plain = cfg.fit(&split(&[13], 160, true), &split(&[14], 160, true)).unwrap();
    assert!(plain.mode_results().iter().all(|r| r.smooth == 0), "{:?}", plain.mode_results());
}

#[test]
fn same_seed_same_detector() {
    let train = split(&[11], 160, true);
    let valid = split(&[12], 160, true);
    let mut cfg = config();
    cfg.train.epochs = 2;
    let a = cfg.fit(&train, &valid).unwrap();
    let b = cfg.fit(&train, &valid).unwrap();
    let s = valid.flights()[0].series();
    assert_eq!(a.raw_scores(s).unwrap(), b.raw_scores(s).unwrap());
    assert_eq!(a.chosen(), b.chosen());
}

/// Writes `det`'s checkpoint as `path` and its weights beside it.
fn save(det: &QuadFormerDetector, path: &std::path::Path) {
    let name = path.file_name().unwrap().to_str().unwrap();
    let files = det.encode(&crate::checkpoint::weights_file_name(name)).unwrap();
    std::fs::write(path.with_extension("safetensors"), files.weights).unwrap();
    std::fs::write(path, files.manifest).unwrap();
}

#[test]
fn checkpoint_round_trip_gives_identical_scores() {
    let det = fitted();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("qf.json");
    save(det, &path);
    let back = QuadFormerDetector::load(&path).unwrap();
    let s = flight(100, 21, 4.0, false);
    assert_eq!(det.score(s.series()).unwrap(), back.score(s.series()).unwrap());
    assert_eq!(det.chosen(), back.chosen());
    assert_eq!(det.mode_results(), back.mode_results());
}

#[test]
fn corrupt_truncated_and_mismatched_checkpoints_are_clear_errors() {
    let det = fitted();
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("qf.json");
    save(det, &path);
    let weights = path.with_extension("safetensors");
    let good_w = std::fs::read(&weights).unwrap();
    let good_j = std::fs::read_to_string(&path).unwrap();
    let expect_err = |needle: &str| {
        let e = QuadFormerDetector::load(&path).unwrap_err();
        assert!(e.to_string().contains(needle), "expected `{needle}` in: {e}");
    };
    std::fs::write(&weights, &good_w[..good_w.len() / 2]).unwrap();
    expect_err("truncated");
    let mut flipped = good_w.clone();
    let last = flipped.len() - 3;
    flipped[last] ^= 0x40;
    std::fs::write(&weights, &flipped).unwrap();
    expect_err("corrupted");
    std::fs::write(&weights, &good_w).unwrap();
    std::fs::write(&path, good_j.replace("\"d_model\": 16", "\"d_model\": 32")).unwrap();
    expect_err("does not match the config");
    std::fs::write(&path, good_j.replace("\"version\": 1", "\"version\": 99")).unwrap();
    expect_err("version 99");
    std::fs::write(&path, good_j.replacen('{', "{\"surprise\": 1,", 1)).unwrap();
    expect_err("unknown field");
    std::fs::write(&path, &good_j[..good_j.len() / 3]).unwrap();
    expect_err("malformed manifest");
    for outside in ["../qf.safetensors", "/etc/passwd", "..", "sub/qf.safetensors"] {
        std::fs::write(
            &path,
            good_j.replace("\"weights_file\": \"qf.safetensors\"", &format!("\"weights_file\": {outside:?}")),
        )
        .unwrap();
        expect_err("weights_file must be a file name");
    }
    std::fs::write(&path, good_j.replace("\"len\": 16", "\"len\": 1000000000")).unwrap();
    expect_err("window.len");
    std::fs::write(&path, good_j.replace("\"d_model\": 16", "\"d_model\": 1000000000")).unwrap();
    expect_err("net.d_model");
    let mut json: serde_json::Value = serde_json::from_str(&good_j).unwrap();
    json["chosen"]["valid_f1"] = serde_json::json!(2.0);
    std::fs::write(&path, json.to_string()).unwrap();
    expect_err("chosen.valid_f1 must be in [0, 1]");
    let mut json: serde_json::Value = serde_json::from_str(&good_j).unwrap();
    json["stream_f1"] = serde_json::json!(-0.5);
    std::fs::write(&path, json.to_string()).unwrap();
    expect_err("stream_f1 must be in [0, 1]");
    let negative_std = good_j.replacen("\"std\": [\n      ", "\"std\": [\n      -", 1);
    assert_ne!(negative_std, good_j, "the manifest layout changed");
    std::fs::write(&path, negative_std).unwrap();
    expect_err("standard deviations finite and positive");
    std::fs::remove_file(&weights).unwrap();
    std::fs::write(&path, &good_j).unwrap();
    assert!(matches!(QuadFormerDetector::load(&path), Err(ModelError::Io { .. })));
}

#[test]
fn online_matches_batch_on_one_window_and_checks_input() {
    let det = fitted();
    let f = flight(L, 31, 4.0, false);
    let batch = stitched(det, f.series());
    let mut online = det.online();
    let mut last = None;
    for step in f.series().steps() {
        last = Some(online.update(&step).unwrap());
    }
    let last = last.unwrap();
    assert!((last.score - batch[L - 1]).abs() < 1e-6, "{} vs {}", last.score, batch[L - 1]);
    assert_eq!(last.alarm, last.score > det.streaming_threshold());
    let bad = ResidueStep { t: 0.0, r_k: &[1.0, 2.0], s_k: &[1.0, 0.0, 0.0, 1.0], nis: 5.0 };
    assert!(matches!(online.update(&bad), Err(DetectError::Residue(_))));
    let short_s = ResidueStep { t: 0.0, r_k: &[1.0, 2.0, 3.0], s_k: &[1.0, 0.0, 0.0, 1.0], nis: 5.0 };
    assert!(matches!(online.update(&short_s), Err(DetectError::Residue(ResidueError::StepDim { what: "S_k", .. }))));
    let eye = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0];
    let nan_nis = ResidueStep { t: 0.0, r_k: &[1.0, 2.0, 3.0], s_k: &eye, nis: f64::NAN };
    assert!(matches!(online.update(&nan_nis), Err(DetectError::Residue(ResidueError::NonFinite { what: "nis", .. }))));
    online.reset();
}

#[test]
fn online_matches_batch_in_every_mode() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("qf.json");
    save(fitted(), &path);
    let f = flight(L, 32, 4.0, false);
    for r in fitted().mode_results() {
        let mut det = QuadFormerDetector::load(&path).unwrap();
        det.stream = *r;
        let batch = stitched(&det, f.series());
        let mut online = det.online();
        let last = f.series().steps().map(|s| online.update(&s).unwrap()).last().unwrap();
        assert!((last.score - batch[L - 1]).abs() < 1e-6, "{:?}: {} vs {}", r.mode, last.score, batch[L - 1]);
    }
}

/// With the drift channel (`Features::WhitenedLogDrift`, computed over each flight's history)
/// the detector learns, and its streaming decision on a flight's last step is the batch score
/// of the window ending there, whose drift channel saw the steps before the window too.
#[test]
fn a_drift_channel_detector_learns_and_streams_what_it_scores() {
    let mut cfg = config();
    cfg.window.features = Features::WhitenedLogDrift;
    let mut flights = split(&[1, 2], 240, false).flights().to_vec();
    flights.push(flight(240, 3, 4.0, true));
    let mut det = cfg.fit(&LabelledResidues::new(flights).unwrap(), &split(&[4], 240, true)).unwrap();
    assert_eq!(det.normaliser().dim(), M + 2);
    let f = f1(&det, &split(&[5, 6], 240, true));
    assert!(f > 0.8, "test F1 {f}, chosen {:?}", det.chosen());
    let long = flight(3 * L, 37, 4.0, false);
    for r in det.mode_results().to_vec() {
        det.stream = r;
        let batch = stitched(&det, long.series());
        let mut online = det.online();
        let last = long.series().steps().map(|s| online.update(&s).unwrap()).last().unwrap();
        let want = batch[3 * L - 1];
        assert!((last.score - want).abs() < 1e-6, "{:?}: {} vs {want}", r.mode, last.score);
    }
}

/// A detector whose network the streaming engine does not represent streams through the candle
/// forward pass on the sliding window: the same decisions as the engine, step by step through
/// the padding and the sliding, and the batch score of a window's last step, in every mode.
#[test]
fn without_the_engine_the_online_detector_streams_through_candle() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("qf.json");
    save(fitted(), &path);
    let long = flight(3 * L, 34, 4.0, false);
    let one_window = flight(L, 35, 4.0, false);
    for r in fitted().mode_results() {
        let mut engine = QuadFormerDetector::load(&path).unwrap();
        engine.stream = *r;
        let mut candle = QuadFormerDetector::load(&path).unwrap();
        candle.stream = *r;
        // Forced: the fallback a network the engine cannot represent gets.
        candle.streaming = None;
        assert!(engine.streams_with_engine() && !candle.streams_with_engine());
        let (mut a, mut b) = (engine.online(), candle.online());
        for (k, step) in long.series().steps().enumerate() {
            let (da, db) = (a.update(&step).unwrap(), b.update(&step).unwrap());
            assert!((da.score - db.score).abs() < 1e-6, "{:?}, step {k}: {} vs {}", r.mode, da.score, db.score);
            assert_eq!(da.alarm, db.alarm, "{:?}, step {k}", r.mode);
        }
        b.reset();
        let batch = stitched(&candle, one_window.series());
        let last = one_window.series().steps().map(|s| b.update(&s).unwrap()).last().unwrap();
        assert!((last.score - batch[L - 1]).abs() < 1e-6, "{:?}: {} vs {}", r.mode, last.score, batch[L - 1]);
    }
}

/// A causal network (`net.causal`) trains and streams in the engine, which gives the candle
/// pass's decisions on the window from the first step. With no padding at the start, every
/// streaming score of a one-window flight is the batch score of its step, and the last one is
/// in every mode.
#[test]
fn a_causal_detector_learns_and_streams_without_padding() {
    let mut cfg = config();
    cfg.net.causal = true;
    let mut flights = split(&[1, 2], 240, false).flights().to_vec();
    flights.push(flight(240, 3, 4.0, true));
    let mut det = cfg.fit(&LabelledResidues::new(flights).unwrap(), &split(&[4], 240, true)).unwrap();
    assert!(det.streams_with_engine());
    let f = f1(&det, &split(&[5, 6], 240, true));
    assert!(f > 0.8, "test F1 {f}, chosen {:?}", det.chosen());
    let one_window = flight(L, 35, 4.0, false);
    let long = flight(3 * L, 36, 4.0, false);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("causal.json");
    save(&det, &path);
    let saved_stream = det.stream;
    for r in det.mode_results().to_vec() {
        det.stream = r;
        let batch = stitched(&det, one_window.series());
        let mut online = det.online();
        let streamed: Vec<f64> = one_window.series().steps().map(|s| online.update(&s).unwrap().score).collect();
        let steps = if r.mode == ScoreMode::Classifier { 0..L } else { L - 1..L };
        for k in steps {
            assert!((streamed[k] - batch[k]).abs() < 1e-6, "{:?}, step {k}: {} vs {}", r.mode, streamed[k], batch[k]);
        }
        // The candle fallback decides the same, warm-up included.
        let mut candle = QuadFormerDetector::load(&path).unwrap();
        (candle.stream, candle.streaming) = (r, None);
        let (mut a, mut b) = (det.online(), candle.online());
        for (k, step) in long.series().steps().enumerate() {
            let (da, db) = (a.update(&step).unwrap(), b.update(&step).unwrap());
            assert!((da.score - db.score).abs() < 1e-6, "{:?}, step {k}: {} vs {}", r.mode, da.score, db.score);
        }
    }
    // A checkpoint keeps the causal network: the same scores, batch and streaming.
    det.stream = saved_stream;
    let back = QuadFormerDetector::load(&path).unwrap();
    assert!(back.config.net.causal && back.streams_with_engine());
    assert_eq!(back.score(long.series()).unwrap(), det.score(long.series()).unwrap());
    assert_eq!(back.score_streaming(long.series()).unwrap(), det.score_streaming(long.series()).unwrap());
}

/// The streaming detector's mode and threshold are the best of every mode's best-F1 threshold
/// on the validation split's streaming scores, whatever mode the offline score uses; a
/// checkpoint keeps them, and one written before them streams the offline mode and threshold.
#[test]
fn the_streamed_mode_and_threshold_are_chosen_on_validation_streaming_scores_and_saved() {
    let det = fitted();
    let valid = split(&[4], 240, true);
    let raw: Vec<(RawScores, &[bool])> =
        valid.labelled().map(|(s, l)| (det.online_quadformer().raw_scores(s).unwrap(), l)).collect();
    let best = |mode: ScoreMode| {
        let scores: Vec<Vec<f64>> = raw.iter().map(|(r, _)| r.mode(mode, det.crit_scale)).collect();
        best_f1_threshold(scores.iter().zip(&raw).map(|(s, (_, l))| (s.as_slice(), *l))).unwrap()
    };
    let stream = det.stream();
    assert_eq!((det.streaming_threshold(), stream.valid_f1), best(stream.mode));
    assert!(ScoreMode::ALL.iter().all(|&m| best(m).1 <= stream.valid_f1), "{stream:?}");
    // The streaming scores are the online detector's, in the streamed mode.
    let streamed: Vec<(Vec<f64>, &[bool])> =
        valid.labelled().map(|(s, l)| (det.score_streaming(s).unwrap(), l)).collect();
    assert_eq!(best_f1_threshold(streamed.iter().map(|(s, l)| (s.as_slice(), *l))).unwrap(), best(stream.mode));
    let f = flight(3 * L, 33, 4.0, false);
    let mut online = det.online();
    for (step, s) in f.series().steps().zip(det.score_streaming(f.series()).unwrap()) {
        let d = online.update(&step).unwrap();
        assert!((d.score - s).abs() < 1e-9, "{} vs {s}", d.score);
    }
    // A forced mode is streamed too.
    let mut forced = config();
    forced.score.mode = Some(ScoreMode::AnomalyTransformer);
    forced.train.epochs = 1;
    let forced = forced.fit(&split(&[1], 240, true), &valid).unwrap();
    assert_eq!(
        (forced.chosen().mode, forced.stream().mode),
        (ScoreMode::AnomalyTransformer, ScoreMode::AnomalyTransformer)
    );

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("qf.json");
    save(det, &path);
    assert_eq!(QuadFormerDetector::load(&path).unwrap().stream(), stream);
    // A manifest written before streaming thresholds existed streams the batch mode at the
    // batch threshold.
    let text = std::fs::read_to_string(&path).unwrap();
    let mut json: serde_json::Value = serde_json::from_str(&text).unwrap();
    for key in ["stream_threshold", "stream_mode", "stream_f1"] {
        json.as_object_mut().unwrap().remove(key);
    }
    std::fs::write(&path, serde_json::to_string(&json).unwrap()).unwrap();
    let old = QuadFormerDetector::load(&path).unwrap();
    assert_eq!((old.stream().mode, old.streaming_threshold()), (det.chosen().mode, det.threshold()));
}

#[test]
fn wrong_channels_and_unlabelled_validation_are_errors() {
    let det = fitted();
    let other = flight(50, 1, 0.0, false).series().select_channels(&["gps_x", "gps_y"]).unwrap();
    assert!(matches!(det.score(&other), Err(DetectError::ChannelMismatch { .. })));
    let e = config().fit(&split(&[1], 100, true), &split(&[2], 100, false)).unwrap_err();
    assert!(e.to_string().contains("validation split needs labelled"), "{e}");
    let mut bad = config();
    bad.net.d_model = 15;
    bad.net.n_heads = 2;
    assert!(matches!(bad.check(), Err(ModelError::Config { field: "net.d_model", .. })));
}

#[test]
fn detectors_and_configs_are_send_sync() {
    fn check<T: Send + Sync>() {}
    check::<QuadFormerDetector>();
    check::<QuadFormerConfig>();
    check::<nn_toolkit::window::Windows>();
}

/// Every JSON pointer of `v`'s leaves and containers.
fn json_pointers(v: &serde_json::Value, here: String, out: &mut Vec<String>) {
    match v {
        serde_json::Value::Object(m) => {
            for (k, c) in m {
                json_pointers(c, format!("{here}/{k}"), out);
            }
        }
        serde_json::Value::Array(a) => {
            for (i, c) in a.iter().enumerate() {
                json_pointers(c, format!("{here}/{i}"), out);
            }
        }
        _ => {}
    }
    out.push(here);
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig {
        cases: 256,
        failure_persistence: None,
        ..proptest::prelude::ProptestConfig::default()
    })]

    /// A checkpoint whose manifest has any one field replaced by a hostile value, or whose
    /// weights have a byte changed, loads or fails with an error: never a panic, an abort or an
    /// allocation beyond the budgets.
    #[test]
    fn hostile_checkpoints_never_panic(
        which in proptest::prelude::any::<proptest::sample::Index>(),
        value in proptest::prop_oneof![
            proptest::strategy::Just(serde_json::json!(null)),
            proptest::strategy::Just(serde_json::json!(-1)),
            proptest::strategy::Just(serde_json::json!(0)),
            proptest::strategy::Just(serde_json::json!(1e300)),
            proptest::strategy::Just(serde_json::json!(u64::MAX)),
            proptest::strategy::Just(serde_json::json!(1_000_000_000)),
            proptest::strategy::Just(serde_json::json!("../qf.safetensors")),
            proptest::strategy::Just(serde_json::json!("")),
            proptest::strategy::Just(serde_json::json!([])),
            proptest::strategy::Just(serde_json::json!({})),
        ],
        flip in proptest::prelude::any::<Option<(proptest::sample::Index, u8)>>(),
    ) {
        static GOOD: OnceLock<(String, Vec<u8>)> = OnceLock::new();
        let (json, weights) = GOOD.get_or_init(|| {
            let f = fitted().encode("qf.safetensors").unwrap();
            (f.manifest, f.weights)
        });
        let good: serde_json::Value = serde_json::from_str(json).unwrap();
        let mut all = Vec::new();
        json_pointers(&good, String::new(), &mut all);
        let mut bad = good.clone();
        let pointer: &String = which.get(&all);
        if let Some(v) = bad.pointer_mut(pointer) {
            *v = value;
        }
        let mut w = weights.clone();
        if let Some((at, byte)) = flip {
            let i = at.index(w.len());
            w[i] = byte;
        }
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("qf.json");
        std::fs::write(&path, bad.to_string()).unwrap();
        std::fs::write(dir.path().join("qf.safetensors"), &w).unwrap();
        let _ = QuadFormerDetector::load(&path);
    }
}

#[test]
fn configurations_beyond_the_weight_and_activation_budgets_are_refused() {
    let mut big = config();
    big.net.d_model = 8_192;
    big.net.d_ff = 8_192;
    big.net.n_layers = 64;
    let e = big.check().unwrap_err().to_string();
    assert!(e.contains("more than the budget of 50000000"), "{e}");
    let mut wide = config();
    wide.window.len = 2_000;
    wide.train.batch_size = 65_536;
    let e = wide.check().unwrap_err().to_string();
    assert!(e.contains("`train.batch_size`") && e.contains("more than the budget of 268435456"), "{e}");
    QuadFormerConfig::default().check().unwrap();
    // Mixed windows need whitened features.
    let mut raw = QuadFormerConfig::default();
    raw.window.features = nn_toolkit::Features::Raw;
    assert!(matches!(raw.check(), Err(ModelError::Config { field: "train.mix", .. })));
    raw.train.mix = 0.0;
    raw.check().unwrap();
}
