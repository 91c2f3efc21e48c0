//! Hostile input to the `quadformer` binary: every case that once gave a wrong result with
//! exit status 0, reached outside a model directory or grew without bound is an error (or a
//! clear warning) naming the file, line or field, and the budget where one applies.

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn quadformer(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_quadformer")).args(args).output().unwrap()
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

/// Runs a command that must fail with `code` and returns its stderr.
fn fails_with(code: i32, args: &[&str]) -> String {
    let o = quadformer(args);
    assert_eq!(o.status.code(), Some(code), "{args:?}: {}", stderr(&o));
    stderr(&o)
}

fn fails(args: &[&str]) -> String {
    fails_with(1, args)
}

fn ok(args: &[&str]) -> String {
    let o = quadformer(args);
    assert!(o.status.success(), "{args:?}: {}", stderr(&o));
    stderr(&o)
}

const CONFIG: &str = r#"
seed = 3
duration_s = 20.0
[[attacks]]
kind = "persistent"
attacked_fraction = 0.5
warmup_s = 1.0
durations.persistent_s = [4.0, 5.0]
"#;

fn flight(dir: &Path, name: &str) -> PathBuf {
    let cfg = dir.join("flight.toml");
    std::fs::write(&cfg, CONFIG).unwrap();
    let out = dir.join(name);
    ok(&["simulate", "--config", s(&cfg), "--out", s(&out)]);
    out
}

/// Replaces line `line` (1-based) of `path` with `text`.
fn replace_line(path: &Path, line: usize, text: &str) {
    let body = std::fs::read_to_string(path).unwrap();
    let mut lines: Vec<&str> = body.lines().collect();
    lines[line - 1] = text;
    std::fs::write(path, lines.join("\n") + "\n").unwrap();
}

#[test]
fn silent_wrong_flight_results_are_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let out = tmp.path().join("r.csv");
    // An IMU log that stops 1.5 s before the GPS log.
    let fl = flight(tmp.path(), "short-imu");
    let imu = fl.join("imu.csv");
    let body = std::fs::read_to_string(&imu).unwrap();
    let kept: Vec<&str> = body.lines().take(3701).collect();
    std::fs::write(&imu, kept.join("\n") + "\n").unwrap();
    let err = fails(&["residues", "--model", "I", "--in", s(&fl), "--out", s(&out)]);
    assert!(err.contains("come after the last IMU sample"), "{err}");
    assert!(!out.exists());

    // One absurd gyro sample, one absurd attitude.
    let fl = flight(tmp.path(), "gyro");
    replace_line(&fl.join("imu.csv"), 5, "0.015,1e308,0,0,0,0,9.81");
    let err = fails(&["residues", "--model", "I", "--in", s(&fl), "--out", s(&out)]);
    assert!(err.contains("imu.csv: line 5, column 2 (`gyro_x`): 1e308 rad/s is outside the plausible range"), "{err}");
    let fl = flight(tmp.path(), "attitude");
    replace_line(&fl.join("attitude.csv"), 3, "0.1,1e10,0,0");
    let err = fails(&["residues", "--model", "I", "--in", s(&fl), "--out", s(&out)]);
    assert!(err.contains("attitude.csv: line 3, column 2 (`roll`)"), "{err}");

    // A config.toml that does not parse is not replaced by the default filter silently.
    let fl = flight(tmp.path(), "bad-config");
    std::fs::write(fl.join("config.toml"), "seed = 18446744073709551615\n").unwrap();
    let err = fails(&["residues", "--model", "I", "--in", s(&fl), "--out", s(&out)]);
    assert!(err.contains("config.toml") && err.contains("fix it, or remove it"), "{err}");
    assert_eq!(err.matches("config.toml").count(), 1, "the file is named once: {err}");

    // A seed a config.toml cannot hold is refused before simulating.
    let cfg = tmp.path().join("flight.toml");
    let err = fails_with(
        2,
        &["simulate", "--config", s(&cfg), "--out", s(&tmp.path().join("x")), "--seed", "18446744073709551615"],
    );
    assert!(err.contains("--seed"), "{err}");
    assert!(!tmp.path().join("x").exists());
}

#[test]
fn silent_wrong_training_and_detection_results_are_errors_or_warnings() {
    let tmp = tempfile::tempdir().unwrap();
    let fl = flight(tmp.path(), "flight");
    let r = tmp.path().join("r.csv");
    ok(&["residues", "--model", "I", "--in", s(&fl), "--out", s(&r)]);
    let body = std::fs::read_to_string(&r).unwrap();
    let (one, two) = (tmp.path().join("one"), tmp.path().join("two"));
    for d in [&one, &two] {
        std::fs::create_dir_all(d).unwrap();
    }
    std::fs::write(one.join("a.csv"), body.lines().take(2).collect::<Vec<_>>().join("\n") + "\n").unwrap();
    std::fs::copy(&r, two.join("a.csv")).unwrap();
    let model = tmp.path().join("model");
    let err = fails(&["train", "--method", "cusum", "--train", s(&one), "--valid", s(&two), "--out", s(&model)]);
    assert!(err.contains("1 residue steps; CUSUM needs at least 10"), "{err}");
    let err = fails(&["train", "--method", "cusum", "--train", s(&two), "--valid", s(&one), "--out", s(&model)]);
    assert!(err.contains("validation needs both"), "{err}");
    assert!(!model.exists());

    // A series shorter than the window is scored with a warning, and undefined ratios say so.
    ok(&["train", "--method", "svm", "--quick", "--train", s(&two), "--valid", s(&two), "--out", s(&model)]);
    let short = tmp.path().join("short.csv");
    std::fs::write(&short, body.lines().take(5).collect::<Vec<_>>().join("\n") + "\n").unwrap();
    let log = ok(&["detect", "--model", s(&model), "--in", s(&short), "--out", s(&tmp.path().join("a.csv"))]);
    assert!(log.contains("fewer than SVM's window of 10"), "{log}");
    assert!(log.contains("recall undefined"), "{log}");
}

#[test]
fn model_directories_are_closed_and_checked() {
    let tmp = tempfile::tempdir().unwrap();
    let fl = flight(tmp.path(), "flight");
    let ds = tmp.path().join("ds");
    std::fs::create_dir_all(&ds).unwrap();
    ok(&["residues", "--model", "I", "--in", s(&fl), "--out", s(&ds.join("a.csv"))]);
    let model = tmp.path().join("model");
    ok(&["train", "--method", "cusum", "--train", s(&ds), "--valid", s(&ds), "--out", s(&model)]);
    let manifest = model.join("model.json");
    let good = std::fs::read_to_string(&manifest).unwrap();
    let input = ds.join("a.csv");
    let out = tmp.path().join("alarms.csv");
    let detect = || fails(&["detect", "--model", s(&model), "--in", s(&input), "--out", s(&out)]);
    let json: serde_json::Value = serde_json::from_str(&good).unwrap();
    let cases: [(&str, serde_json::Value, &str); 5] = [
        ("/state/0/file", serde_json::json!("../../etc/passwd"), "state[0].file"),
        ("/state/0/file", serde_json::json!("/etc/passwd"), "state[0].file"),
        ("/state", serde_json::json!([]), "state: no files"),
        ("/channels/1", serde_json::json!("gps_x"), "channels[1]: `gps_x` is listed twice"),
        ("/channels", serde_json::json!([]), "channels: empty"),
    ];
    for (pointer, value, needle) in cases {
        let mut bad = json.clone();
        *bad.pointer_mut(pointer).unwrap() = value;
        std::fs::write(&manifest, bad.to_string()).unwrap();
        let err = detect();
        assert!(err.contains(needle), "{pointer}: {err}");
    }
    assert!(!out.exists());
}

#[test]
fn sizes_that_drive_allocations_are_budgeted_before_allocating() {
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tmp.path().join("long.toml");
    std::fs::write(&cfg, "duration_s = 1e9\n").unwrap();
    let err = fails(&["simulate", "--config", s(&cfg), "--out", s(&tmp.path().join("x"))]);
    assert!(err.contains("`duration_s`") && err.contains("more than the 10000000 one flight may hold"), "{err}");
    let err = fails(&["reproduce-tables", "--seeds", "4294967296", "--out", s(&tmp.path().join("res"))]);
    assert!(err.contains("--seeds must be between 1 and 100"), "{err}");

    // Endless inputs are refused before reading, not read until memory runs out.
    let err = fails(&["simulate", "--config", "/dev/zero", "--out", s(&tmp.path().join("x"))]);
    assert!(err.contains("/dev/zero: is not a regular file"), "{err}");

    let fl = flight(tmp.path(), "flight");
    let ds = tmp.path().join("ds");
    std::fs::create_dir_all(&ds).unwrap();
    ok(&["residues", "--model", "I", "--in", s(&fl), "--out", s(&ds.join("a.csv"))]);
    let model = tmp.path().join("cusum");
    ok(&["train", "--method", "cusum", "--train", s(&ds), "--valid", s(&ds), "--out", s(&model)]);
    let err = fails(&["detect", "--model", s(&model), "--in", "/dev/zero", "--out", s(&tmp.path().join("z.csv"))]);
    assert!(err.contains("/dev/zero: is not a regular file"), "{err}");
    let cases = [
        ("svm", "[svm]\nmax_train = 1000000000\n", "`max_train`: 1000000000 exceeds the budget of 10000"),
        ("cnn", "[cnn]\nhidden = 1000000000\n", "`hidden`: 1000000000 exceeds the budget of 4096"),
        ("quadformer", "[quadformer.net]\nd_model = 1000000000\n", "`net.d_model`: 1000000000 exceeds the budget"),
        ("quadformer", "[quadformer.window]\nlen = 1000000000\n", "window.len"),
        (
            "quadformer",
            "[quadformer.net]\nd_model = 8192\nd_ff = 8192\nn_layers = 64\n",
            "weights, more than the budget",
        ),
    ];
    for (method, toml, needle) in cases {
        std::fs::write(&cfg, toml).unwrap();
        let out = tmp.path().join("model");
        let err = fails(&[
            "train",
            "--method",
            method,
            "--quick",
            "--config",
            s(&cfg),
            "--train",
            s(&ds),
            "--valid",
            s(&ds),
            "--out",
            s(&out),
        ]);
        assert!(err.contains(needle), "{method}: {err}");
    }
}

#[test]
fn messages_name_each_file_once() {
    let tmp = tempfile::tempdir().unwrap();
    let (cfg, out) = (tmp.path().join("cfg"), tmp.path().join("out"));
    std::fs::create_dir(&cfg).unwrap();
    let err = fails(&["simulate", "--config", s(&cfg), "--out", s(&out)]);
    assert_eq!(err.matches("is a directory").count(), 1, "{err}");
    // An operating-system error is printed once, not once per cause.
    let afile = tmp.path().join("afile");
    std::fs::write(&afile, "x").unwrap();
    let err = fails(&["simulate", "--config", s(&afile.join("c.toml")), "--out", s(&out)]);
    assert_eq!(err.matches("os error 20").count(), 1, "{err}");
    std::fs::write(cfg.join("m.json"), "{").unwrap();
    let model = tmp.path().join("model");
    std::fs::create_dir(&model).unwrap();
    std::fs::write(model.join("model.json"), "{\"format\": 1}").unwrap();
    let err = fails(&["detect", "--model", s(&model), "--in", s(&cfg.join("m.json")), "--out", s(&out)]);
    assert_eq!(err.matches("line 1").count(), 1, "{err}");
}
