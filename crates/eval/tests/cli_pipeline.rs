//! End-to-end tests of the `quadformer` binary: `simulate` then `residues` on a temp dir give
//! readable CSVs with aligned labels; bad input exits non-zero with a message naming the file,
//! line and column; nothing partial is left behind.

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![allow(clippy::unwrap_used)]

use std::path::Path;
use std::process::{Command, Output};

use eval::io::{read_attack, read_flight_dir, read_residues};

fn quadformer(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_quadformer")).args(args).output().unwrap()
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

/// A 20 s square flight with one sparse and one persistent attack (persistent durations
/// shortened so it fits its 10 s share).
const CONFIG: &str = r#"
seed = 11
duration_s = 20.0

[trajectory]
kind = "square"

[[attacks]]
kind = "sparse"
attacked_fraction = 0.2
warmup_s = 2.0

[[attacks]]
kind = "persistent"
attacked_fraction = 0.5
warmup_s = 1.0
durations.persistent_s = [4.0, 5.0]
"#;

fn simulate(dir: &Path, name: &str) -> std::path::PathBuf {
    let cfg = dir.join("flight.toml");
    std::fs::write(&cfg, CONFIG).unwrap();
    let out = dir.join(name);
    let o = quadformer(&["simulate", "--config", cfg.to_str().unwrap(), "--out", out.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));
    out
}

#[test]
fn simulate_then_residues_gives_labelled_csvs() {
    let tmp = tempfile::tempdir().unwrap();
    let flight = simulate(tmp.path(), "flight");
    let dir = read_flight_dir(&flight).unwrap();
    assert_eq!(dir.streams.imu.len(), 4001);
    assert_eq!(dir.streams.gps.len(), 201);
    let attack = dir.attack.as_ref().unwrap();
    let n_attacked = attack.iter().filter(|a| a.label).count();
    assert!(n_attacked > 20, "both attacks present: {n_attacked} attacked fixes");
    // The attacked GPS is the clean fix plus d; truth is at IMU rate.
    assert!(dir.truth.as_ref().unwrap().len() == 4001);

    for model in ["I", "II"] {
        let csv = tmp.path().join(format!("residues-{model}.csv"));
        let o = quadformer(&[
            "residues",
            "--model",
            model,
            "--in",
            flight.to_str().unwrap(),
            "--out",
            csv.to_str().unwrap(),
        ]);
        assert!(o.status.success(), "{}", stderr(&o));
        let res = read_residues(&csv).unwrap();
        let labels = res.labels().unwrap();
        let t = res.series().t();
        assert_eq!(t.len(), 200, "one residue step per GPS fix after the initialising one");
        // Labels align: each residue step carries the label of the GPS fix at its time.
        for (k, &t_k) in t.iter().enumerate() {
            let fix = attack.iter().find(|a| (a.t - t_k).abs() < 1e-9).unwrap();
            assert_eq!(labels[k], fix.label, "step {k} at {t_k} s");
        }
        let expected_channels = if model == "I" { 6 } else { 9 };
        assert_eq!(res.series().dim(), expected_channels);
    }
}

#[test]
fn simulate_is_deterministic_and_refuses_to_overwrite() {
    let tmp = tempfile::tempdir().unwrap();
    let a = simulate(tmp.path(), "a");
    let b = simulate(tmp.path(), "b");
    for file in ["imu.csv", "gps.csv", "attitude.csv", "vo.csv", "truth.csv", "attack.csv", "config.toml"] {
        assert_eq!(std::fs::read(a.join(file)).unwrap(), std::fs::read(b.join(file)).unwrap(), "{file}");
    }
    // The written config reproduces the flight.
    let again = tmp.path().join("again");
    let o = quadformer(&[
        "simulate",
        "--config",
        a.join("config.toml").to_str().unwrap(),
        "--out",
        again.to_str().unwrap(),
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(read_attack(&again.join("attack.csv")).unwrap(), read_attack(&a.join("attack.csv")).unwrap());
    assert_eq!(std::fs::read(again.join("imu.csv")).unwrap(), std::fs::read(a.join("imu.csv")).unwrap());

    let o = quadformer(&[
        "simulate",
        "--config",
        tmp.path().join("flight.toml").to_str().unwrap(),
        "--out",
        a.to_str().unwrap(),
    ]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("exists and is not empty"), "{}", stderr(&o));
}

#[test]
fn bad_stream_file_names_file_line_and_column() {
    let tmp = tempfile::tempdir().unwrap();
    let flight = simulate(tmp.path(), "flight");
    // Corrupt one GPS value on line 5.
    let gps_path = flight.join("gps.csv");
    let text = std::fs::read_to_string(&gps_path).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    let mut fields: Vec<&str> = lines[4].split(',').collect();
    fields[2] = "NaN";
    lines[4] = fields.join(",");
    std::fs::write(&gps_path, lines.join("\n") + "\n").unwrap();

    let csv = tmp.path().join("r.csv");
    let o = quadformer(&["residues", "--model", "I", "--in", flight.to_str().unwrap(), "--out", csv.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(1));
    let msg = stderr(&o);
    assert!(msg.contains("gps.csv: line 5, column 3 (`p_y`): value `NaN` is not finite"), "{msg}");
    assert!(!csv.exists(), "no output on failure");
    assert_eq!(std::fs::read_dir(tmp.path()).unwrap().count(), 2, "only flight.toml and the flight dir remain");
}

#[test]
fn missing_stream_and_bad_config_are_named() {
    let tmp = tempfile::tempdir().unwrap();
    let flight = simulate(tmp.path(), "flight");
    std::fs::remove_file(flight.join("attitude.csv")).unwrap();
    let csv = tmp.path().join("r.csv");
    let o = quadformer(&["residues", "--model", "I", "--in", flight.to_str().unwrap(), "--out", csv.to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("attitude.csv: missing or empty; Model I needs it"), "{}", stderr(&o));
    // Model II runs without the attitude stream.
    let o =
        quadformer(&["residues", "--model", "II", "--in", flight.to_str().unwrap(), "--out", csv.to_str().unwrap()]);
    assert!(o.status.success(), "{}", stderr(&o));

    let cfg = tmp.path().join("bad.toml");
    std::fs::write(&cfg, "seed = 1\n[trajectory]\nkind = \"circle\"\n").unwrap();
    let o =
        quadformer(&["simulate", "--config", cfg.to_str().unwrap(), "--out", tmp.path().join("x").to_str().unwrap()]);
    assert!(!o.status.success());
    let msg = stderr(&o);
    assert!(msg.contains("bad.toml") && msg.contains("line 3") && msg.contains("circle"), "{msg}");
    assert!(!tmp.path().join("x").exists());

    // A requested attack that cannot fit is an error, not a silently clean flight.
    std::fs::write(&cfg, "duration_s = 30.0\n[[attacks]]\nkind = \"sparse\"\n[[attacks]]\nkind = \"persistent\"\n")
        .unwrap();
    let o =
        quadformer(&["simulate", "--config", cfg.to_str().unwrap(), "--out", tmp.path().join("x").to_str().unwrap()]);
    assert!(!o.status.success());
    assert!(stderr(&o).contains("[attacks 2]: no persistent interval fits"), "{}", stderr(&o));
    assert!(!tmp.path().join("x").exists());
}

#[test]
fn help_is_available_everywhere() {
    for args in [&["--help"][..], &["simulate", "--help"], &["residues", "--help"]] {
        let o = quadformer(args);
        assert!(o.status.success());
        assert!(String::from_utf8_lossy(&o.stdout).contains("Usage: quadformer"));
    }
    let o = quadformer(&["residues", "--model", "III", "--in", "x", "--out", "y"]);
    assert_eq!(o.status.code(), Some(2), "usage errors exit with 2");
}

#[test]
fn own_log_without_config_truth_or_attack_works() {
    let tmp = tempfile::tempdir().unwrap();
    let flight = simulate(tmp.path(), "flight");
    // A user's log: only the streams Model I needs, columns reordered, an extra column, a
    // comment line; no config.toml (default filter), no attack.csv (no labels).
    let own = tmp.path().join("own");
    std::fs::create_dir(&own).unwrap();
    std::fs::copy(flight.join("imu.csv"), own.join("imu.csv")).unwrap();
    std::fs::copy(flight.join("attitude.csv"), own.join("attitude.csv")).unwrap();
    let gps = std::fs::read_to_string(flight.join("gps.csv")).unwrap();
    let mut text = String::from("# exported from a flight log\nsats,p_z,p_y,p_x,t\n");
    for line in gps.lines().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        text.push_str(&format!("12,{},{},{},{}\n", f[3], f[2], f[1], f[0]));
    }
    std::fs::write(own.join("gps.csv"), text).unwrap();

    let csv = tmp.path().join("r.csv");
    let est = tmp.path().join("est.csv");
    let o = quadformer(&[
        "residues",
        "--model",
        "I",
        "--in",
        own.to_str().unwrap(),
        "--out",
        csv.to_str().unwrap(),
        "--estimates",
        est.to_str().unwrap(),
        "--covariance",
        "full",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(stderr(&o).contains("unlabelled"), "{}", stderr(&o));
    let res = read_residues(&csv).unwrap();
    assert_eq!(res.labels(), None);
    assert_eq!(res.series().len(), 200);
    let estimates = eval::io::read_truth(&est).unwrap();
    assert_eq!(estimates.len(), res.series().len());
    assert_eq!(estimates[0].t, res.series().t()[0]);
}
