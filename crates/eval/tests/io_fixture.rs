//! The committed fixture flight `fixtures/flight-60s` (fixtures/README.md has the command that
//! regenerated it): it reads, both EKF models run on it (paper alg:alg1), and residue labels
//! align with the attacked GPS fixes.

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![allow(clippy::unwrap_used)]

use std::path::PathBuf;
use std::process::Command;

use ekf_residue::residues::{FilterConfig, ModelKind, generate_residues};
use eval::io::{FlightConfig, FlightDir, labels_at, read_flight_dir, read_residues};

fn fixture_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/flight-60s")
}

fn fixture() -> (FlightDir, FlightConfig) {
    let dir = fixture_dir();
    let flight = read_flight_dir(&dir).unwrap();
    let cfg = FlightConfig::from_toml(&dir.join("config.toml"), flight.config_toml.as_deref().unwrap()).unwrap();
    (flight, cfg)
}

#[test]
fn fixture_reads_with_one_attack_of_each_kind() {
    let (flight, cfg) = fixture();
    let s = &flight.streams;
    assert_eq!((s.imu.len(), s.gps.len(), s.attitude.len(), s.vo.len()), (12001, 601, 601, 601));
    let mut kinds: Vec<_> = cfg.attacks.iter().map(|a| a.kind.name()).collect();
    kinds.sort_unstable();
    assert_eq!(kinds, ["freeze", "noise", "persistent", "replay", "sparse"]);
    let attack = flight.attack.as_ref().unwrap();
    let n_attacked = attack.iter().filter(|a| a.label).count();
    assert!((100..250).contains(&n_attacked), "{n_attacked} attacked fixes");
    // Offsets are zero exactly outside attacks (labels come from the injected offset or the
    // replayed/frozen fix differing from the clean one).
    assert!(attack.iter().filter(|a| !a.label).all(|a| a.d == nalgebra::Vector3::zeros()));
}

#[test]
fn both_models_run_and_labels_align() {
    let (flight, cfg) = fixture();
    let attack = flight.attack.as_ref().unwrap();
    for (model, dim) in [(ModelKind::ModelI, 6), (ModelKind::ModelII, 9)] {
        let out = generate_residues(&flight.streams, &FilterConfig::for_sim(model, &cfg.sim)).unwrap();
        let series = &out.series;
        assert_eq!(series.dim(), dim, "{model:?}");
        assert_eq!(series.len(), 600, "{model:?}: one step per fix after the initialising one");
        let labels = labels_at(series.t(), attack);
        for (k, &t_k) in series.t().iter().enumerate() {
            let fix = attack.iter().find(|a| (a.t - t_k).abs() < 1e-9).unwrap();
            assert_eq!(labels[k], fix.label, "{model:?} step {k} at {t_k} s");
        }
        // Before the first attack the filter is consistent (mean NIS near the dimension; about
        // 60 steps, so a loose band), and attacked steps stand out against that. Clean steps
        // after an attack are not used: the filter absorbs part of an attack and stays off for
        // a while (the paper's Fig. 9 effect).
        let first = labels.iter().position(|&l| l).unwrap();
        let mean = |z: &[f64]| z.iter().sum::<f64>() / z.len() as f64;
        let clean = mean(&series.nis()[..first]);
        let attacked: Vec<f64> = series.nis().iter().zip(&labels).filter(|(_, l)| **l).map(|(z, _)| *z).collect();
        let dim = dim as f64;
        assert!((0.3 * dim..3.0 * dim).contains(&clean), "{model:?}: clean mean NIS {clean}");
        assert!(mean(&attacked) > 2.0 * clean, "{model:?}: attacked {} vs clean {clean}", mean(&attacked));
    }
}

#[test]
fn residues_command_on_the_fixture() {
    let tmp = tempfile::tempdir().unwrap();
    let (flight, _) = fixture();
    for model in ["I", "II"] {
        let out = tmp.path().join(format!("r{model}.csv"));
        let o = Command::new(env!("CARGO_BIN_EXE_quadformer"))
            .args(["residues", "--model", model, "--in"])
            .arg(fixture_dir())
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let res = read_residues(&out).unwrap();
        let n_attacked = res.labels().unwrap().iter().filter(|&&l| l).count();
        let n_fix_attacked = flight.attack.as_ref().unwrap().iter().skip(1).filter(|a| a.label).count();
        assert_eq!(n_attacked, n_fix_attacked, "every attacked fix after the first has a labelled residue step");
    }
}
