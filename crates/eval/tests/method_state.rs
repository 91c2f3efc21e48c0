//! Save/load round trips of every method of the registry (`eval::methods`) through a model
//! directory (`eval::model_dir`): fitted on a small seeded synthetic case
//! (`baselines::synthetic`), saved, loaded, and compared bit for bit: thresholds, batch and
//! streaming scores, and the online decisions step by step. Also: a version-1 QUADFormer
//! directory still loads; an old model directory that holds copied training data is refused
//! with a message naming the file.

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![allow(clippy::unwrap_used)]

use baselines::synthetic::{SyntheticAttack, SyntheticFlight};
use ekf_residue::LabelledResidues;
use eval::io::Overwrite;
use eval::methods::{Method, MethodConfigs};
use eval::model_dir::{self, Trained};

/// Seeded flights of `n_steps` with a 20 m GPS bias for 5 s every minute.
fn split(seeds: &[u64], n_steps: usize) -> LabelledResidues {
    let attacks: Vec<SyntheticAttack> = (0..n_steps / 600)
        .map(|i| {
            let start_s = 20.0 + 60.0 * i as f64;
            SyntheticAttack { start_s, end_s: start_s + 5.0, bias_m: [20.0, 0.0, 5.0], absorb_tau_s: None }
        })
        .collect();
    let flights = seeds.iter().map(|&seed| SyntheticFlight::new(n_steps, seed).generate(&attacks).unwrap()).collect();
    LabelledResidues::new(flights).unwrap()
}

/// The quick configurations, smaller still: one epoch on few windows.
fn configs() -> MethodConfigs {
    let mut c = MethodConfigs::quick().seeded(3);
    c.quadformer.train.epochs = 1;
    c.quadformer.train.max_windows_per_epoch = Some(64);
    for nn in [&mut c.cnn.0, &mut c.lstm.0] {
        nn.train.epochs = 1;
        nn.train.max_windows_per_epoch = Some(64);
    }
    c.svm.max_train = 200;
    c
}

fn bits(v: &[f64]) -> Vec<u64> {
    v.iter().map(|x| x.to_bits()).collect()
}

fn round_trip(method: Method) {
    let (train, valid, test) = (split(&[1, 2], 1200), split(&[3], 1200), split(&[4], 700));
    let cfgs = configs();
    let (fitted, files) = method.fit_and_save(&cfgs, &train, &valid).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join(method.slug());
    let trained = Trained {
        method,
        channels: train.channels().to_vec(),
        threshold: fitted.threshold(),
        seed: 3,
        configs: cfgs,
        trained_on: vec!["synthetic".into()],
    };
    model_dir::write(&out, Overwrite::Refuse, trained, &files).unwrap();
    let manifest = model_dir::read_manifest(&out).unwrap();
    assert_eq!(manifest.method, method);
    let loaded = model_dir::load(&out, &manifest).unwrap();

    let name = method.name();
    assert_eq!(loaded.name(), fitted.name());
    assert_eq!(loaded.channels(), fitted.channels());
    assert_eq!(loaded.threshold().to_bits(), fitted.threshold().to_bits(), "{name} threshold");
    assert_eq!(loaded.streaming_threshold().to_bits(), fitted.streaming_threshold().to_bits(), "{name}");
    let series = test.flights()[0].series();
    assert_eq!(bits(&loaded.score(series).unwrap()), bits(&fitted.score(series).unwrap()), "{name} score");
    assert_eq!(
        bits(&loaded.score_streaming(series).unwrap()),
        bits(&fitted.score_streaming(series).unwrap()),
        "{name} streaming score"
    );
    let (mut a, mut b) = (fitted.online(), loaded.online());
    for (k, step) in series.steps().enumerate() {
        let (da, db) = (a.update(&step).unwrap(), b.update(&step).unwrap());
        assert_eq!((da.score.to_bits(), da.alarm), (db.score.to_bits(), db.alarm), "{name} online step {k}");
    }
}

macro_rules! round_trips {
    ($($test:ident: $method:ident),* $(,)?) => {
        $( #[test] fn $test() { round_trip(Method::$method); } )*

        #[test]
        fn every_method_has_a_round_trip_test() {
            assert_eq!([$(Method::$method),*].len(), Method::ALL.len());
        }
    };
}

round_trips! {
    cusum_round_trip: Cusum,
    sprt_round_trip: Sprt,
    bht_round_trip: Bht,
    svm_round_trip: Svm,
    cnn_round_trip: Cnn,
    lstm_round_trip: Lstm,
    quadformer_round_trip: QuadFormer,
    chi2_round_trip: Chi2,
    px4_gate_round_trip: Px4Gate,
    glr_round_trip: Glr,
}

#[test]
fn a_directory_of_copied_training_data_says_to_retrain() {
    let dir = tempfile::tempdir().unwrap();
    let manifest = serde_json::json!({
        "format": "quadformer-model-dir",
        "version": 1,
        "method": "cusum",
        "channels": ["gps_x", "gps_y", "gps_z"],
        "threshold": 1.5,
        "seed": 0,
        "configs": {},
        "storage": {"kind": "refit", "train": ["data/train/0000-a.csv"], "valid": ["data/valid/0000-b.csv"]},
        "trained_on": ["a.csv", "b.csv"]
    });
    std::fs::write(dir.path().join("model.json"), manifest.to_string()).unwrap();
    let err = model_dir::read_manifest(dir.path()).unwrap_err().to_string();
    assert!(err.contains("model.json") && err.contains("re-run `quadformer train`"), "{err}");
}

#[test]
fn a_state_file_of_another_method_is_refused_by_name() {
    let (train, valid) = (split(&[1], 1200), split(&[3], 1200));
    let cfgs = configs();
    let (fitted, files) = Method::Chi2.fit_and_save(&cfgs, &train, &valid).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("m");
    let trained = Trained {
        method: Method::Chi2,
        channels: train.channels().to_vec(),
        threshold: fitted.threshold(),
        seed: 0,
        configs: cfgs,
        trained_on: Vec::new(),
    };
    model_dir::write(&out, Overwrite::Refuse, trained, &files).unwrap();
    let mut manifest = model_dir::read_manifest(&out).unwrap();
    manifest.method = Method::Cusum;
    let Err(err) = model_dir::load(&out, &manifest) else { panic!("a CUSUM loaded from a chi-squared state") };
    let err = err.to_string();
    assert!(err.contains("detector.json"), "{err}");
}

#[test]
fn a_version_1_quadformer_directory_still_loads() {
    let (train, valid, test) = (split(&[1, 2], 1200), split(&[3], 1200), split(&[4], 700));
    let cfgs = configs();
    let (fitted, files) = Method::QuadFormer.fit_and_save(&cfgs, &train, &valid).unwrap();
    let dir = tempfile::tempdir().unwrap();
    for f in &files {
        std::fs::write(dir.path().join(&f.name), &f.bytes).unwrap();
    }
    let checkpoint = files.iter().find(|f| f.name == "quadformer.json").unwrap();
    // As version 1 wrote it: the method as `quad-former`, the checkpoint as `storage`.
    let manifest = serde_json::json!({
        "format": "quadformer-model-dir",
        "version": 1,
        "method": "quad-former",
        "channels": train.channels(),
        "threshold": fitted.threshold(),
        "seed": 3,
        "configs": serde_json::to_value(&cfgs).unwrap(),
        "storage": {
            "kind": "checkpoint",
            "manifest": "quadformer.json",
            "manifest_sha256": model_dir::sha256_hex(&checkpoint.bytes)
        },
        "trained_on": ["synthetic"]
    });
    std::fs::write(dir.path().join("model.json"), manifest.to_string()).unwrap();
    let m = model_dir::read_manifest(dir.path()).unwrap();
    assert_eq!(m.method, Method::QuadFormer);
    let loaded = model_dir::load(dir.path(), &m).unwrap();
    let series = test.flights()[0].series();
    assert_eq!(bits(&loaded.score(series).unwrap()), bits(&fitted.score(series).unwrap()));
}
