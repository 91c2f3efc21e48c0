//! End-to-end tests of `quadformer dataset | train | detect` on the quick cell
//! `m1-exponential-a1` (UAV Model I, exponential GPS noise, Attack I): the round trip finds
//! the attacks better than chance for QUADFormer (checkpoint) and CUSUM (saved parameters),
//! both loaded without fitting; a corrupt checkpoint, a channel mismatch and a bad CSV line give
//! errors naming the file; no partial output is left behind.

// Helpers outside `#[test]` functions unwrap too: a failure there is a test failure.
#![allow(clippy::unwrap_used)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use eval::io::read_residues;

fn quadformer(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_quadformer")).args(args).output().unwrap()
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn ok(args: &[&str]) -> String {
    let out = quadformer(args);
    assert!(out.status.success(), "quadformer {args:?} failed: {}", stderr(&out));
    stderr(&out)
}

fn fails(args: &[&str]) -> String {
    let out = quadformer(args);
    assert!(!out.status.success(), "quadformer {args:?} should fail");
    assert_eq!(out.status.code(), Some(1));
    stderr(&out)
}

fn s(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// A one-epoch QUADFormer on few windows: the smallest model that still learns something.
const TINY: &str = "[quadformer.train]\nepochs = 1\nmax_windows_per_epoch = 128\n";

/// Writes the quick dataset cell into `dir/ds` and returns its path.
fn dataset(dir: &Path) -> PathBuf {
    let ds = dir.join("ds");
    ok(&["dataset", "--cell", "m1-exponential-a1", "--quick", "--seed", "3", "--out", s(&ds)]);
    ds
}

/// Trains `method` on the dataset in `ds` into `dir/<method>` and returns the model directory.
fn train(dir: &Path, ds: &Path, method: &str) -> PathBuf {
    let cfg = dir.join("tiny.toml");
    std::fs::write(&cfg, TINY).unwrap();
    let model = dir.join(method);
    let (tr, va) = (ds.join("train"), ds.join("valid"));
    ok(&[
        "train",
        "--method",
        method,
        "--train",
        s(&tr),
        "--valid",
        s(&va),
        "--out",
        s(&model),
        "--quick",
        "--config",
        s(&cfg),
    ]);
    model
}

fn files(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir).unwrap().map(|e| e.unwrap().path()).collect();
    v.sort();
    v
}

/// Pooled outcome of one detector over the test flights.
#[derive(Debug, PartialEq)]
struct Pooled {
    tp: usize,
    fp: usize,
    /// Scores of attacked steps.
    pos: Vec<f64>,
    /// Scores of clean steps.
    neg: Vec<f64>,
}

/// Runs `detect` on every test flight, checking that each alarm file lines up with its input.
fn detect_all(dir: &Path, ds: &Path, model: &Path) -> Pooled {
    let mut p = Pooled { tp: 0, fp: 0, pos: Vec::new(), neg: Vec::new() };
    for (i, input) in files(&ds.join("test")).iter().enumerate() {
        let out = dir.join(format!("alarms-{i}.csv"));
        let log = ok(&["detect", "--model", s(model), "--in", s(input), "--out", s(&out)]);
        assert!(log.contains("precision") && log.contains("F1"), "{log}");
        let series = read_residues(input).unwrap();
        let text = std::fs::read_to_string(&out).unwrap();
        let mut lines = text.lines();
        assert_eq!(lines.next(), Some("t,score,alarm,label"));
        let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
        assert_eq!(rows.len(), series.series().len());
        for (k, row) in rows.iter().enumerate() {
            assert_eq!(row[0].parse::<f64>().unwrap(), series.series().t()[k]);
            assert!(row[1].parse::<f64>().unwrap().is_finite());
            let score = row[1].parse::<f64>().unwrap();
            let alarm = row[2] == "1";
            let label = row[3] == "1";
            assert_eq!(label, series.labels().unwrap()[k]);
            p.tp += usize::from(alarm && label);
            p.fp += usize::from(alarm && !label);
            if label { p.pos.push(score) } else { p.neg.push(score) }
        }
    }
    p
}

/// Better than chance, both ways: the alarms' precision beats the attacked fraction (what
/// random alarms achieve), and the scores' ROC AUC (Mann–Whitney) beats 0.5 by a margin. The
/// margins are loose because the quick models are tiny (quick QUADFormer on this cell: precision
/// about 1.6× the attacked fraction, AUC about 0.67).
#[allow(clippy::cast_precision_loss)]
fn assert_better_than_chance(p: &Pooled) {
    let (n_pos, n_neg) = (p.pos.len() as f64, p.neg.len() as f64);
    assert!(p.tp > 0, "no attacked step found of {n_pos}");
    let precision = p.tp as f64 / (p.tp + p.fp) as f64;
    let prevalence = n_pos / (n_pos + n_neg);
    assert!(precision > 1.2 * prevalence, "precision {precision} vs attacked fraction {prevalence}");
    let wins: f64 = p
        .pos
        .iter()
        .flat_map(|a| {
            p.neg.iter().map(move |b| {
                if a > b {
                    1.0
                } else if a == b {
                    0.5
                } else {
                    0.0
                }
            })
        })
        .sum();
    let auc = wins / (n_pos * n_neg);
    assert!(auc > 0.55, "ROC AUC {auc}");
}

#[test]
fn dataset_layout_labels_only_the_labelled_training_flights() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = dataset(tmp.path());
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(ds.join("dataset.json")).unwrap()).unwrap();
    assert_eq!(summary["cell"], "m1-exponential-a1");
    let labelled: Vec<u64> =
        summary["labelled_train_flights"].as_array().unwrap().iter().map(|v| v.as_u64().unwrap()).collect();
    let train = files(&ds.join("train"));
    assert!(train.len() >= 2 && !labelled.is_empty() && labelled.len() < train.len());
    for (i, f) in train.iter().enumerate() {
        assert_eq!(f.file_name().unwrap().to_str().unwrap(), format!("flight-{i:03}.csv"));
        let has = read_residues(f).unwrap().labels().is_some();
        assert_eq!(has, labelled.contains(&(i as u64)), "{}", f.display());
    }
    for split in ["valid", "test"] {
        for f in files(&ds.join(split)) {
            assert!(read_residues(&f).unwrap().labels().is_some(), "{}", f.display());
        }
    }
    // An existing dataset is not overwritten without --force.
    let err = fails(&["dataset", "--cell", "m1-exponential-a1", "--quick", "--out", s(&ds)]);
    assert!(err.contains("not empty"), "{err}");
    let err = fails(&["dataset", "--cell", "m3-exponential-a1", "--quick", "--out", s(&tmp.path().join("x"))]);
    assert!(err.contains("unknown cell"), "{err}");
}

#[test]
fn quadformer_round_trip_finds_attacks_and_rejects_a_corrupt_checkpoint() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = dataset(tmp.path());
    let model = train(tmp.path(), &ds, "quadformer");
    for f in ["model.json", "quadformer.json", "quadformer.safetensors"] {
        assert!(model.join(f).is_file(), "{f}");
    }
    assert_better_than_chance(&detect_all(tmp.path(), &ds, &model));
    // `--streaming` scores every step from the past alone, at the streaming threshold saved in
    // the checkpoint, as `fuse` runs the model: same rows, other scores.
    let input = &files(&ds.join("test"))[0];
    let (batch_out, stream_out) = (tmp.path().join("batch.csv"), tmp.path().join("stream.csv"));
    ok(&["detect", "--model", s(&model), "--in", s(input), "--out", s(&batch_out)]);
    let log = ok(&["detect", "--model", s(&model), "--in", s(input), "--out", s(&stream_out), "--streaming"]);
    assert!(log.contains("QUADFormer (streaming)"), "{log}");
    let checkpoint: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(model.join("quadformer.json")).unwrap()).unwrap();
    let stream_threshold = checkpoint["stream_threshold"].as_f64().unwrap();
    assert!(log.contains(&format!("threshold {stream_threshold:.6}")), "{log}");
    let (batch, stream) = (std::fs::read_to_string(&batch_out).unwrap(), std::fs::read_to_string(&stream_out).unwrap());
    assert_eq!(batch.lines().count(), stream.lines().count());
    assert_ne!(batch, stream);

    // Flip one byte of the weights: the checkpoint's SHA-256 check names the file.
    let input = files(&ds.join("test"))[0].clone();
    let out = tmp.path().join("corrupt.csv");
    let weights = model.join("quadformer.safetensors");
    let mut bytes = std::fs::read(&weights).unwrap();
    let mid = bytes.len() / 2;
    bytes[mid] ^= 0x55;
    std::fs::write(&weights, &bytes).unwrap();
    let err = fails(&["detect", "--model", s(&model), "--in", s(&input), "--out", s(&out)]);
    assert!(err.contains("quadformer.safetensors") && err.contains("corrupted"), "{err}");
    // A truncated weights file: the SHA-256 recorded in model.json no longer matches.
    std::fs::write(&weights, &bytes[..mid]).unwrap();
    let err = fails(&["detect", "--model", s(&model), "--in", s(&input), "--out", s(&out)]);
    assert!(err.contains("quadformer.safetensors") && err.contains("corrupted"), "{err}");
    // A damaged model manifest.
    let manifest = model.join("model.json");
    let text = std::fs::read_to_string(&manifest).unwrap();
    std::fs::write(&manifest, &text[..text.len() / 2]).unwrap();
    let err = fails(&["detect", "--model", s(&model), "--in", s(&input), "--out", s(&out)]);
    assert!(err.contains("model.json") && err.contains("malformed"), "{err}");
    assert!(!out.exists(), "no alarm file after an error");
}

#[test]
fn saved_statistical_method_round_trip_is_deterministic_and_finds_attacks() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = dataset(tmp.path());
    let model = train(tmp.path(), &ds, "cusum");
    let names: Vec<String> =
        files(&model).iter().map(|p| p.file_name().unwrap().to_string_lossy().into_owned()).collect();
    assert_eq!(names, ["detector.json", "model.json"], "the fitted state, no copy of the training data");
    let first = detect_all(tmp.path(), &ds, &model);
    let alarms = std::fs::read(tmp.path().join("alarms-0.csv")).unwrap();
    assert_eq!(detect_all(tmp.path(), &ds, &model), first);
    assert_eq!(std::fs::read(tmp.path().join("alarms-0.csv")).unwrap(), alarms, "loading is bit-identical");
    // A corrupt state file is named.
    let state = model.join("detector.json");
    let text = std::fs::read_to_string(&state).unwrap();
    std::fs::write(&state, text.replacen('1', "2", 1)).unwrap();
    let err = fails(&[
        "detect",
        "--model",
        s(&model),
        "--in",
        s(&files(&ds.join("test"))[0]),
        "--out",
        s(&tmp.path().join("x.csv")),
    ]);
    assert!(err.contains("detector.json") && err.contains("corrupted"), "{err}");
    std::fs::write(&state, text).unwrap();
    assert_better_than_chance(&first);
    let log = ok(&[
        "detect",
        "--model",
        s(&model),
        "--in",
        s(&files(&ds.join("test"))[0]),
        "--out",
        s(&tmp.path().join("again.csv")),
    ]);
    assert!(!log.contains("warning"), "{log}");
}

#[test]
fn channel_mismatch_and_bad_lines_name_the_file() {
    let tmp = tempfile::tempdir().unwrap();
    let ds = dataset(tmp.path());
    let model = train(tmp.path(), &ds, "chi2");
    let out = tmp.path().join("alarms.csv");

    // A residue file with GPS channels only (Model I was trained on GPS + attitude).
    let gps_only = tmp.path().join("gps-only.csv");
    std::fs::write(&gps_only, "t,r_gps_x,s_gps_x_gps_x\n0.1,0.5,2.0\n0.2,-0.1,2.0\n").unwrap();
    let err = fails(&["detect", "--model", s(&model), "--in", s(&gps_only), "--out", s(&out)]);
    assert!(err.contains("gps-only.csv") && err.contains("channel mismatch"), "{err}");
    assert!(err.contains("att_roll"), "lists the training channels: {err}");

    // The same file among validation data is refused at training time.
    let valid = tmp.path().join("valid-mixed");
    std::fs::create_dir(&valid).unwrap();
    std::fs::copy(files(&ds.join("valid"))[0].clone(), valid.join("a.csv")).unwrap();
    std::fs::copy(&gps_only, valid.join("b.csv")).unwrap();
    let (tr, m2) = (ds.join("train"), tmp.path().join("m2"));
    let err = fails(&["train", "--method", "chi2", "--train", s(&tr), "--valid", s(&valid), "--out", s(&m2)]);
    assert!(err.contains("b.csv") && err.contains("channel mismatch"), "{err}");
    assert!(!m2.exists(), "no model directory after an error");

    // Validation data without any attacked step: no threshold can be chosen.
    let clean = tmp.path().join("valid-clean");
    std::fs::create_dir(&clean).unwrap();
    let text = std::fs::read_to_string(&files(&ds.join("valid"))[0]).unwrap();
    let clean_text: String =
        text.lines().map(|l| l.strip_suffix(",1").map_or(l.to_owned(), |x| format!("{x},0")) + "\n").collect();
    std::fs::write(clean.join("a.csv"), clean_text).unwrap();
    let err = fails(&["train", "--method", "chi2", "--train", s(&tr), "--valid", s(&clean), "--out", s(&m2)]);
    assert!(err.contains("valid-clean: 0 attacked and 500 clean steps"), "{err}");
    assert!(!m2.exists(), "no model directory after an error");

    // A value that is not a number, on line 5, column 2.
    let input = files(&ds.join("test"))[0].clone();
    let text = std::fs::read_to_string(&input).unwrap();
    let mut lines: Vec<String> = text.lines().map(str::to_owned).collect();
    let mut fields: Vec<&str> = lines[4].split(',').collect();
    fields[1] = "oops";
    lines[4] = fields.join(",");
    let bad = tmp.path().join("bad.csv");
    std::fs::write(&bad, lines.join("\n") + "\n").unwrap();
    let err = fails(&["detect", "--model", s(&model), "--in", s(&bad), "--out", s(&out)]);
    assert!(err.contains("bad.csv") && err.contains("line 5"), "{err}");
    assert!(!out.exists(), "no alarm file after an error");
}

#[test]
fn help_says_how_each_method_is_stored() {
    let out = quadformer(&["train", "--help"]);
    let text = String::from_utf8(out.stdout).unwrap();
    assert!(text.contains("quadformer.safetensors") && text.contains("detector.json"), "{text}");
    let out = quadformer(&["--help"]);
    let text = String::from_utf8(out.stdout).unwrap();
    for cmd in ["dataset", "train", "detect"] {
        assert!(text.lines().any(|l| l.trim_start().starts_with(cmd)), "{text}");
    }
}

fn check_help(args: &[&str], expect: expect_test::Expect) {
    let o = Command::new(env!("CARGO_BIN_EXE_quadformer")).args(args).env("COLUMNS", "100").output().unwrap();
    assert!(o.status.success());
    expect.assert_eq(&String::from_utf8(o.stdout).unwrap());
}

#[test]
fn dataset_help() {
    check_help(
        &["dataset", "-h"],
        expect_test::expect![[r#"
        Build (or load from a cache) one labelled dataset cell and write its train, valid and test flights as residue CSV files

        Usage: quadformer dataset [OPTIONS] --cell <CELL> --out <DIR>

        Options:
              --cell <CELL>            Cell of the experiment matrix: m1|m2 - gaussian|exponential|laplace - a1|a2, e.g. `m1-exponential-a1` (UAV Model I, exponential GPS noise, Attack I)
              --quick                  CI-sized cell (3,000 / 1,000 / 1,000 residue steps, 60 s flights) instead of the paper's (83,700 / 18,700 / 18,700 steps, 150 s flights)
              --seed <SEED>            Dataset seed (routes, sensor noise, attacks and the labelled subset derive from it) [default: 0]
              --labelled-fraction <F>  Fraction of training flights whose labels are written (the rest have no label column) [default: 0.1]
              --cache <DIR>            Cache directory: the cell is loaded from it when a valid cache file exists, else built and cached there (the same cache `reproduce-tables` keeps under `OUT/datasets`)
              --out <DIR>              Output directory (must not exist or be empty, unless `--force`)
              --force                  Replace a non-empty output directory
          -h, --help                   Print help
          -V, --version                Print version
    "#]],
    );
}

#[test]
fn train_help() {
    check_help(
        &["train", "-h"],
        expect_test::expect![[r#"
            Fit a detection method on residue CSV files (thresholds chosen on the validation files) and save a model directory

            Usage: quadformer train [OPTIONS] --method <METHOD> --train <DIR> --valid <DIR> --out <MODEL_DIR>

            Options:
                  --method <METHOD>     Method: quadformer, cusum, sprt, bht, chi2, px4-gate, glr, svm, cnn or lstm
                  --train <DIR>         Directory of training residue CSVs (every `*.csv`; labels optional)
                  --valid <DIR>         Directory of validation residue CSVs (every `*.csv`; labels required): thresholds are chosen here
                  --out <MODEL_DIR>     Output model directory (must not exist or be empty, unless `--force`)
                  --config <FILE.toml>  Method configurations (TOML, one table per method: `quadformer`, `cusum`, `sprt`, `bht`, `svm`, `cnn`, `lstm`, `chi2`, `px4_gate`; keys left out keep the base values, the defaults or, with `--quick`, the quick ones)
                  --quick               Small networks and few epochs (as `reproduce-tables --quick`): a smoke test
                  --seed <SEED>         Seed of the method's random parts [default: 0]
                  --force               Replace a non-empty output directory
              -h, --help                Print help
              -V, --version             Print version

            Model directory: model.json and the fitted state, which `quadformer detect` loads without fitting: detector.json (the fitted parameters of cusum, sprt, bht, chi2, px4-gate, glr and svm; the manifest of cnn and lstm, with detector.safetensors for their weights) or quadformer.json + quadformer.safetensors (the QUADFormer checkpoint). See docs/cli.md and decisions 081 and 110.
        "#]],
    );
}

#[test]
fn detect_help() {
    check_help(
        &["detect", "-h"],
        expect_test::expect![[r#"
            Score a residue CSV with a trained model directory and write per-step scores and alarms

            Usage: quadformer detect [OPTIONS] --model <MODEL_DIR> --in <FILE.csv> --out <ALARMS.csv>

            Options:
                  --model <MODEL_DIR>  Model directory written by `quadformer train`
                  --in <FILE.csv>      Residue CSV to score (its channels must equal the model's training channels)
                  --out <ALARMS.csv>   Output alarm CSV: t, score, alarm[, label] (written atomically)
                  --streaming          Score as the streaming detector does (each step from itself and earlier steps only, at the streaming threshold), as `quadformer fuse` runs it
              -h, --help               Print help
              -V, --version            Print version

            Every method loads the fitted state saved in the model directory; nothing is re-fitted (see `quadformer train --help`, docs/cli.md).
        "#]],
    );
}
