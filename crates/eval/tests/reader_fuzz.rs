//! Property tests of every reader under hostile input: flight CSVs, residue CSVs, TOML configs
//! (flight, method and experiment configs), model manifests and the saved states of the
//! statistical methods and the SVM. Inputs are mutations of valid
//! files (fields replaced by absurd values, lines dropped or duplicated, bytes flipped) and
//! random bytes; every read must return `Ok` or an error, never panic. The case counts bound
//! the run time (a few seconds on 2 cores).

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};

use eval::io::{
    FlightConfig, read_attack, read_attitude, read_flight_dir, read_gps, read_imu, read_residues, read_truth, read_vo,
};
use proptest::prelude::*;

/// Values a hostile field may hold.
const FIELDS: &[&str] = &[
    "0",
    "1",
    "-1",
    "0.1",
    "1e308",
    "-1e308",
    "1e-320",
    "NaN",
    "inf",
    "-inf",
    "",
    " ",
    "\"",
    "\"a,b\"",
    "x",
    "99999999999999999999999",
    "-0",
    "1e10",
    "0x10",
    "\u{663}",
    "\u{0}",
    "true",
    "4294967296",
    "-4294967296",
];

/// The fixture flight, a valid starting point for mutations.
fn fixture() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../fixtures/flight-60s")
}

/// One mutation of a CSV text.
#[derive(Debug, Clone)]
enum Mutation {
    /// Replace field `col` of line `line` (indices wrap) with `FIELDS[value]`.
    Field { line: usize, col: usize, value: usize },
    /// Remove line `line`.
    DropLine(usize),
    /// Repeat line `line`.
    DupLine(usize),
    /// Cut the text at byte `at` (rounded down to a character boundary).
    Truncate(usize),
    /// Replace the byte at `at` with `byte`.
    Byte { at: usize, byte: u8 },
}

fn mutation() -> impl Strategy<Value = Mutation> {
    prop_oneof![
        4 => (any::<usize>(), any::<usize>(), 0..FIELDS.len()).prop_map(|(line, col, value)| Mutation::Field { line, col, value }),
        1 => any::<usize>().prop_map(Mutation::DropLine),
        1 => any::<usize>().prop_map(Mutation::DupLine),
        1 => any::<usize>().prop_map(Mutation::Truncate),
        1 => (any::<usize>(), any::<u8>()).prop_map(|(at, byte)| Mutation::Byte { at, byte }),
    ]
}

/// Applies `muts` to `text` (only its first `keep` lines, to keep cases fast).
fn mutate(text: &str, keep: usize, muts: &[Mutation]) -> Vec<u8> {
    let mut lines: Vec<String> = text.lines().take(keep).map(str::to_owned).collect();
    let mut bytes_ops = Vec::new();
    for m in muts {
        let n = lines.len().max(1);
        match m {
            Mutation::Field { line, col, value } => {
                if let Some(l) = lines.get_mut(line % n) {
                    let mut fields: Vec<&str> = l.split(',').collect();
                    let c = col % fields.len().max(1);
                    if let Some(f) = fields.get_mut(c) {
                        *f = FIELDS[*value];
                    }
                    *l = fields.join(",");
                }
            }
            Mutation::DropLine(i) if !lines.is_empty() => {
                lines.remove(i % n);
            }
            Mutation::DupLine(i) if !lines.is_empty() => {
                let l = lines[i % n].clone();
                lines.insert(i % n, l);
            }
            other => bytes_ops.push(other.clone()),
        }
    }
    let mut bytes = (lines.join("\n") + "\n").into_bytes();
    for m in bytes_ops {
        let n = bytes.len().max(1);
        match m {
            Mutation::Truncate(at) => bytes.truncate(at % n),
            Mutation::Byte { at, byte } => {
                if let Some(b) = bytes.get_mut(at % n) {
                    *b = byte;
                }
            }
            _ => {}
        }
    }
    bytes
}

/// A residue file of the fixture flight, computed once.
fn residue_text() -> &'static str {
    static TEXT: std::sync::OnceLock<String> = std::sync::OnceLock::new();
    TEXT.get_or_init(|| {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("r.csv");
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_quadformer"))
            .args(["residues", "--model", "II", "--in", fixture().to_str().unwrap(), "--out", out.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        std::fs::read_to_string(out).unwrap()
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 96, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn flight_csv_readers_never_panic(file in 0usize..6, muts in prop::collection::vec(mutation(), 0..6)) {
        let names = ["imu.csv", "gps.csv", "attitude.csv", "vo.csv", "attack.csv", "config.toml"];
        let src = fixture();
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("flight");
        std::fs::create_dir(&dir).unwrap();
        for name in names {
            let text = std::fs::read_to_string(src.join(name)).unwrap();
            // Short streams at matching times, so the consistency checks are reached too.
            let keep = match name {
                "imu.csv" => 402,
                "config.toml" => usize::MAX,
                _ => 22,
            };
            let bytes = if name == names[file] { mutate(&text, keep, &muts) } else { mutate(&text, keep, &[]) };
            std::fs::write(dir.join(name), bytes).unwrap();
        }
        let p = |n: &str| dir.join(n);
        let _ = read_imu(&p("imu.csv"));
        let _ = read_gps(&p("gps.csv"));
        let _ = read_attitude(&p("attitude.csv"));
        let _ = read_vo(&p("vo.csv"));
        let _ = read_attack(&p("attack.csv"));
        let _ = read_truth(&p("imu.csv"));
        let _ = read_flight_dir(&dir);
        // The whole command on it: an error or a result, never a crash.
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_quadformer"))
            .args(["residues", "--model", "I", "--in", dir.to_str().unwrap(), "--out", tmp.path().join("r.csv").to_str().unwrap()])
            .output()
            .unwrap();
        prop_assert!(matches!(o.status.code(), Some(0 | 1)), "{}", String::from_utf8_lossy(&o.stderr));
    }

    #[test]
    fn residue_reader_never_panics(muts in prop::collection::vec(mutation(), 0..8)) {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("r.csv");
        std::fs::write(&path, mutate(residue_text(), 40, &muts)).unwrap();
        let _ = read_residues(&path);
    }

    #[test]
    fn csv_readers_take_random_bytes(bytes in prop::collection::vec(any::<u8>(), 0..300), header in 0usize..3) {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("f.csv");
        let head = ["", "t,gyro_x,gyro_y,gyro_z,accel_x,accel_y,accel_z\n", "t,lat_deg,lon_deg,h_m\n"][header];
        let mut all = head.as_bytes().to_vec();
        all.extend_from_slice(&bytes);
        std::fs::write(&path, &all).unwrap();
        let _ = read_imu(&path);
        let _ = read_gps(&path);
        let _ = read_residues(&path);
    }
}

/// Keys and values of hostile TOML.
const TOML_KEYS: &[&str] = &[
    "seed",
    "duration_s",
    "[trajectory]",
    "kind",
    "[sim]",
    "imu_rate_hz",
    "gps_rate_hz",
    "[sim.noise]",
    "shape",
    "[[attacks]]",
    "attacked_fraction",
    "[trajectory.shape]",
    "size_m",
    "[quadformer.window]",
    "len",
    "[quadformer.net]",
    "d_model",
    "[svm]",
    "max_train",
    "[cnn]",
    "hidden",
    "[methods.quadformer.train]",
    "epochs",
    "labelled_fraction",
    "[x",
    "=",
    "\"",
];
const TOML_VALUES: &[&str] = &[
    "0",
    "-1",
    "1e9",
    "1e308",
    "nan",
    "inf",
    "-inf",
    "18446744073709551615",
    "9223372036854775807",
    "\"eight\"",
    "\"random\"",
    "\"Laplace\"",
    "\"sparse\"",
    "[]",
    "{}",
    "true",
    "0.5",
    "1000000000",
    "\"\"",
    "[1, 2]",
];

fn toml_text() -> impl Strategy<Value = String> {
    prop::collection::vec((0..TOML_KEYS.len(), 0..TOML_VALUES.len()), 0..10).prop_map(|items| {
        items
            .into_iter()
            .map(|(k, v)| {
                let key = TOML_KEYS[k];
                if key.starts_with('[') { format!("{key}\n") } else { format!("{key} = {}\n", TOML_VALUES[v]) }
            })
            .collect()
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn toml_readers_never_panic(text in toml_text()) {
        let tmp = tempfile::tempdir().unwrap();
        let path = tmp.path().join("c.toml");
        std::fs::write(&path, &text).unwrap();
        if let Ok(cfg) = FlightConfig::from_toml(&path, &text) {
            // What parses must also write back, or fail to write with an error.
            let _ = cfg.to_toml(&path);
            let _ = eval::cli::simulate::simulate_flight(&path, &FlightConfig { duration_s: Some(1.0), ..cfg });
        }
        let _ = eval::cli::train::method_configs(Some(&path), true, 0);
        let _ = eval::reproduce::MatrixConfig::from_toml_file(&path, &eval::reproduce::MatrixConfig::quick());
    }
}

/// JSON values a hostile manifest field may hold.
fn json_value() -> impl Strategy<Value = serde_json::Value> {
    use serde_json::json;
    prop_oneof![
        Just(json!(null)),
        Just(json!(-1)),
        Just(json!(0)),
        Just(json!(1e300)),
        Just(json!(u64::MAX)),
        Just(json!("../../etc/passwd")),
        Just(json!("/etc/passwd")),
        Just(json!("")),
        Just(json!([])),
        Just(json!({})),
        Just(json!(["a", "a"])),
        Just(json!(1_000_000_000)),
    ]
}

/// Every JSON pointer of `v`'s leaves and containers.
fn pointers(v: &serde_json::Value, here: String, out: &mut Vec<String>) {
    match v {
        serde_json::Value::Object(m) => {
            for (k, c) in m {
                pointers(c, format!("{here}/{k}"), out);
            }
        }
        serde_json::Value::Array(a) => {
            for (i, c) in a.iter().enumerate() {
                pointers(c, format!("{here}/{i}"), out);
            }
        }
        _ => {}
    }
    out.push(here);
}

/// The JSON of `path` with the node `which` picks (any leaf or container, or the whole
/// document) replaced by `value`.
fn replaced_at(path: &Path, which: prop::sample::Index, value: serde_json::Value) -> serde_json::Value {
    let good: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let mut all = Vec::new();
    pointers(&good, String::new(), &mut all);
    let pointer = which.get(&all);
    let mut bad = good;
    if pointer.is_empty() {
        return value;
    }
    if let Some(v) = bad.pointer_mut(pointer) {
        *v = value;
    }
    bad
}

/// A model directory of a statistical method (CUSUM), trained once.
fn model_dir() -> &'static Path {
    static DIR: std::sync::OnceLock<(tempfile::TempDir, PathBuf)> = std::sync::OnceLock::new();
    &DIR.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap();
        let ds = tmp.path().join("ds");
        std::fs::create_dir(&ds).unwrap();
        std::fs::write(ds.join("a.csv"), residue_text()).unwrap();
        let model = tmp.path().join("model");
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_quadformer"))
            .args(["train", "--method", "cusum", "--train", ds.to_str().unwrap(), "--valid", ds.to_str().unwrap()])
            .args(["--out", model.to_str().unwrap()])
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        (tmp, model)
    })
    .1
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 192, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn manifest_reader_never_panics(which in any::<prop::sample::Index>(), value in json_value()) {
        let model = model_dir();
        let bad = replaced_at(&model.join("model.json"), which, value);
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("model");
        std::fs::create_dir(&dir).unwrap();
        std::fs::write(dir.join("model.json"), bad.to_string()).unwrap();
        if let Ok(m) = eval::model_dir::read_manifest(&dir) {
            // Whatever validates only names files inside the model directory, which has none:
            // loading reports them missing.
            let _ = eval::model_dir::load(&dir, &m);
        }
    }
}

/// A short valid flight directory (the fixture's first 2 s), written once.
fn short_flight() -> &'static Path {
    static DIR: std::sync::OnceLock<(tempfile::TempDir, PathBuf)> = std::sync::OnceLock::new();
    &DIR.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("flight");
        std::fs::create_dir(&dir).unwrap();
        for name in ["imu.csv", "gps.csv", "attitude.csv", "vo.csv", "attack.csv", "config.toml"] {
            let text = std::fs::read_to_string(fixture().join(name)).unwrap();
            let keep = match name {
                "imu.csv" => 402,
                "config.toml" => usize::MAX,
                _ => 22,
            };
            std::fs::write(dir.join(name), mutate(&text, keep, &[])).unwrap();
        }
        (tmp, dir)
    })
    .1
}

/// Dotted paths of every leaf of `t`.
fn leaves(t: &toml::Table, here: &str, out: &mut Vec<String>) {
    for (k, v) in t {
        let path = if here.is_empty() { k.clone() } else { format!("{here}.{k}") };
        match v {
            toml::Value::Table(sub) => leaves(sub, &path, out),
            _ => out.push(path),
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 48, failure_persistence: None, ..ProptestConfig::default() })]

    /// `residues --filter-config` with one field of the documented filter settings replaced by
    /// a hostile value: an error naming the file or a result, never a crash.
    #[test]
    fn filter_configs_never_crash_residues(which in any::<prop::sample::Index>(), value in 0..TOML_VALUES.len()) {
        let base = ekf_residue::residues::FilterConfig::new(ekf_residue::residues::ModelKind::ModelI);
        let table = toml::Table::try_from(base).unwrap();
        let mut all = Vec::new();
        leaves(&table, "", &mut all);
        let key = which.get(&all);
        let (section, field) = key.rsplit_once('.').map_or((None, key.as_str()), |(s, f)| (Some(s), f));
        let text = match section {
            Some(s) => format!("[{s}]\n{field} = {}\n", TOML_VALUES[value]),
            None => format!("{field} = {}\n", TOML_VALUES[value]),
        };
        let tmp = tempfile::tempdir().unwrap();
        let cfg = tmp.path().join("filter.toml");
        std::fs::write(&cfg, &text).unwrap();
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_quadformer"))
            .args(["residues", "--model", "I", "--in", short_flight().to_str().unwrap()])
            .args(["--out", tmp.path().join("r.csv").to_str().unwrap(), "--filter-config", cfg.to_str().unwrap()])
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        prop_assert!(matches!(o.status.code(), Some(0 | 1)), "{text}: {err}");
        if o.status.code() == Some(1) {
            prop_assert!(err.contains("filter.toml") || err.contains("EKF failed"), "{text}: {err}");
        }
    }
}

/// Methods whose saved state is a `detector.json` of their fitted parameters.
const JSON_STATE_METHODS: [&str; 7] = ["cusum", "sprt", "bht", "chi2", "px4-gate", "glr", "svm"];

/// One model directory per method of [`JSON_STATE_METHODS`], trained once on the fixture's
/// residues (in the directory `residues/`).
fn state_dirs() -> &'static Path {
    static DIR: std::sync::OnceLock<tempfile::TempDir> = std::sync::OnceLock::new();
    DIR.get_or_init(|| {
        let tmp = tempfile::tempdir().unwrap();
        let ds = tmp.path().join("residues");
        std::fs::create_dir(&ds).unwrap();
        std::fs::write(ds.join("a.csv"), residue_text()).unwrap();
        for m in JSON_STATE_METHODS {
            let o = std::process::Command::new(env!("CARGO_BIN_EXE_quadformer"))
                .args([
                    "train",
                    "--method",
                    m,
                    "--quick",
                    "--train",
                    ds.to_str().unwrap(),
                    "--valid",
                    ds.to_str().unwrap(),
                ])
                .args(["--out", tmp.path().join(m).to_str().unwrap()])
                .output()
                .unwrap();
            assert!(o.status.success(), "{m}: {}", String::from_utf8_lossy(&o.stderr));
        }
        tmp
    })
    .path()
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 192, failure_persistence: None, ..ProptestConfig::default() })]

    /// A hand-edited `detector.json` (its SHA-256 updated in `model.json`, so the decoder sees
    /// it) loads or is an error; what loads scores the residues or returns an error.
    #[test]
    fn saved_state_reader_never_panics(
        method in prop::sample::select(JSON_STATE_METHODS.to_vec()),
        which in any::<prop::sample::Index>(),
        value in json_value(),
    ) {
        let src = state_dirs().join(method);
        let bad = replaced_at(&src.join("detector.json"), which, value).to_string();
        let mut manifest: serde_json::Value =
            serde_json::from_str(&std::fs::read_to_string(src.join("model.json")).unwrap()).unwrap();
        manifest["state"][0]["sha256"] = serde_json::json!(eval::model_dir::sha256_hex(bad.as_bytes()));
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("model");
        std::fs::create_dir(&dir).unwrap();
        std::fs::write(dir.join("detector.json"), &bad).unwrap();
        std::fs::write(dir.join("model.json"), manifest.to_string()).unwrap();
        let m = eval::model_dir::read_manifest(&dir).unwrap();
        if let Ok(det) = eval::model_dir::load(&dir, &m) {
            let series = read_residues(&state_dirs().join("residues/a.csv")).unwrap();
            let _ = det.score(series.series());
            let _ = det.score_streaming(series.series());
            let mut online = det.online();
            for step in series.series().steps().take(200) {
                let _ = online.update(&step);
            }
        }
    }
}
