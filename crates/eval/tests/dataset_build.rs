//! Dataset builder at its public boundary: label alignment, split by flight, semi-supervised
//! label hiding, determinism (byte-identical, independent of the thread count) and the cache
//! (hit, corrupt, truncated, stale files rebuilt).

use attack_inject::AttackKind;
use ekf_residue::residues::ModelKind;
use eval::dataset::{
    CacheOutcome, Dataset, DatasetConfig, Split, SplitSteps, StaleReason, ValidDatasetConfig, build, build_split,
    cache_path, load_or_build,
};
use uav_dynamics::noise::NoiseShape;

type TestResult = Result<(), Box<dyn std::error::Error>>;

/// A small cell: 20 s flights, 2,000 / 400 / 400 steps (10 / 2 / 2 flights at 10 Hz).
fn tiny(model: ModelKind, attack: AttackKind, seed: u64) -> Result<ValidDatasetConfig, eval::dataset::DatasetError> {
    let mut cfg = DatasetConfig::quick(model, NoiseShape::Laplace, attack);
    cfg.steps = SplitSteps { train: 2_000, valid: 400, test: 400 };
    cfg.flight_duration_s = 20.0;
    cfg.seed = seed;
    cfg.check()
}

#[test]
fn labels_are_the_attack_intervals_and_fraction_near_target() -> TestResult {
    let data = build(&tiny(ModelKind::ModelI, AttackKind::Sparse, 1)?)?;
    let (mut steps, mut attacked) = (0, 0);
    for split in Split::ALL {
        for f in data.flights(split) {
            let t = f.series().t();
            assert_eq!(f.labels().len(), t.len());
            for (k, &tk) in t.iter().enumerate() {
                // Model I has one residue step per GPS fix; sparse bursts are additive, so a step
                // is attacked exactly when its time lies in an attack interval.
                assert_eq!(f.labels()[k], f.meta.plan.active_at(tk).is_some(), "{split} {} t={tk}", f.meta.index);
            }
            steps += t.len();
            attacked += f.n_attacked();
        }
    }
    #[allow(clippy::cast_precision_loss)]
    let frac = attacked as f64 / steps as f64;
    assert!((frac - 0.12).abs() < 0.03, "attacked fraction {frac}");
    let total = SplitSteps { train: 2_000, valid: 400, test: 400 };
    #[allow(clippy::cast_precision_loss)]
    let rel = (steps as f64 - (total.train + total.valid + total.test) as f64).abs() / 2_800.0;
    assert!(rel < 0.02, "{steps} steps");
    Ok(())
}

#[test]
fn one_split_alone_is_the_same_as_in_the_whole_dataset() -> TestResult {
    let cfg = tiny(ModelKind::ModelII, AttackKind::Persistent, 4)?;
    let whole = build(&cfg)?;
    let test = build_split(&cfg, Split::Test)?;
    let expected = whole.test()?;
    assert_eq!(test.flights().len(), expected.flights().len());
    for (a, b) in test.flights().iter().zip(expected.flights()) {
        assert_eq!(a.series().t(), b.series().t());
        assert_eq!(a.series().r(), b.series().r());
        assert_eq!(a.labels(), b.labels());
    }
    Ok(())
}

#[test]
fn split_by_flight_with_hidden_training_labels() -> TestResult {
    let data = build(&tiny(ModelKind::ModelI, AttackKind::Sparse, 2)?)?;
    let mut seeds = std::collections::HashSet::new();
    for split in Split::ALL {
        for f in data.flights(split) {
            assert_eq!(f.meta.split, split);
            assert!(seeds.insert(f.meta.route_seed), "route seed shared across flights");
        }
    }
    let train = data.train()?;
    assert_eq!(train.flights().len(), 10);
    // 10% of 10 flights: one labelled.
    assert_eq!(train.labelled().count(), 1);
    assert_eq!(data.summary(Split::Train).labelled_flights, 1);
    assert!(data.valid()?.flights().iter().all(|f| f.labels().is_some()));
    assert!(data.test()?.flights().iter().all(|f| f.labels().is_some()));
    // Nested subsets: 1% (at least one flight) ⊂ 10% ⊂ 50% ⊂ 100%.
    let one = data.labelled_train_indices(0.01);
    let ten = data.labelled_train_indices(0.1);
    let half = data.labelled_train_indices(0.5);
    assert_eq!((one.len(), ten.len(), half.len()), (1, 1, 5));
    assert!(ten.iter().all(|i| half.contains(i)));
    assert_eq!(data.labelled_train_indices(1.0).len(), 10);
    assert!(data.labelled_train_indices(0.0).is_empty());
    assert_eq!(data.train_with_labelled_fraction(1.0)?.labelled().count(), 10);
    Ok(())
}

#[test]
fn model2_residues_carry_vo_and_gps_channels() -> TestResult {
    let data = build(&tiny(ModelKind::ModelII, AttackKind::Sparse, 3)?)?;
    let test = data.test()?;
    assert_eq!(test.channels(), ["vo_x", "vo_y", "vo_z", "vo_roll", "vo_pitch", "vo_yaw", "gps_x", "gps_y", "gps_z"]);
    assert!(data.summary(Split::Test).attacked > 0);
    Ok(())
}

#[test]
fn byte_identical_across_runs_and_thread_counts() -> TestResult {
    let cfg = tiny(ModelKind::ModelI, AttackKind::Replay, 4)?;
    let a = build(&cfg)?.to_bytes()?;
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build()?;
    let b = pool.install(|| build(&cfg))?.to_bytes()?;
    assert!(a == b, "same config and seed must give identical bytes");
    let other = build(&tiny(ModelKind::ModelI, AttackKind::Replay, 5)?)?.to_bytes()?;
    assert!(a != other);
    Ok(())
}

#[test]
fn cache_hit_and_corrupt_truncated_or_stale_files_rebuilt() -> TestResult {
    let dir = tempfile::tempdir()?;
    let cfg = tiny(ModelKind::ModelI, AttackKind::Noise, 6)?;
    let (built, outcome) = load_or_build(&cfg, dir.path())?;
    assert!(matches!(outcome, CacheOutcome::Built { reason: StaleReason::Missing, .. }), "{outcome:?}");
    let path = cache_path(&cfg, dir.path())?;
    let (hit, outcome) = load_or_build(&cfg, dir.path())?;
    assert_eq!(outcome, CacheOutcome::Hit { path: path.clone() });
    assert_eq!(hit, built);
    // Only the cache file is left in the directory (no temporary files).
    assert_eq!(std::fs::read_dir(dir.path())?.count(), 1);

    // A flipped byte in the payload fails the checksum and is rebuilt.
    let mut bytes = std::fs::read(&path)?;
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x55;
    std::fs::write(&path, &bytes)?;
    let (again, outcome) = load_or_build(&cfg, dir.path())?;
    assert!(matches!(outcome, CacheOutcome::Built { reason: StaleReason::Checksum, .. }), "{outcome:?}");
    assert_eq!(again, built);

    // Truncated and foreign files.
    std::fs::write(&path, b"QFD")?;
    let (_, outcome) = load_or_build(&cfg, dir.path())?;
    assert!(matches!(outcome, CacheOutcome::Built { reason: StaleReason::Truncated, .. }), "{outcome:?}");
    std::fs::write(&path, vec![0u8; 100])?;
    let (_, outcome) = load_or_build(&cfg, dir.path())?;
    assert!(matches!(outcome, CacheOutcome::Built { reason: StaleReason::BadMagic, .. }), "{outcome:?}");

    // A valid file of another configuration at this path is stale.
    let other = tiny(ModelKind::ModelI, AttackKind::Noise, 7)?;
    std::fs::write(&path, build(&other)?.to_bytes()?)?;
    assert_eq!(Dataset::from_bytes(&std::fs::read(&path)?, &cfg), Err(StaleReason::ConfigMismatch));
    let (_, outcome) = load_or_build(&cfg, dir.path())?;
    assert!(matches!(outcome, CacheOutcome::Built { reason: StaleReason::ConfigMismatch, .. }), "{outcome:?}");

    // The labelled fraction is applied after loading: another fraction hits the same file.
    let mut more_labels = cfg.get().clone();
    more_labels.labelled_fraction = 1.0;
    let (data, outcome) = load_or_build(&more_labels.check()?, dir.path())?;
    assert!(matches!(outcome, CacheOutcome::Hit { .. }), "{outcome:?}");
    assert_eq!(data.train()?.labelled().count(), 10);
    Ok(())
}
