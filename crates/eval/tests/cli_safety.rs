//! Output safety of the `quadformer` binary (docs/cli.md "Safety rules"): no output replaces a
//! device, FIFO or symbolic link, an input, a model's own file or the data being read; a
//! failing command leaves nothing partial; temporaries of a killed run are removed; long
//! output names work.

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

/// Runs a command that must fail with exit 1 and returns its stderr.
fn fails(args: &[&str]) -> String {
    let o = quadformer(args);
    let err = String::from_utf8_lossy(&o.stderr).into_owned();
    assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
    err
}

fn ok(args: &[&str]) {
    let o = quadformer(args);
    assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
}

/// A 20 s flight with a persistent attack.
const CONFIG: &str = r#"
seed = 3
duration_s = 20.0
[[attacks]]
kind = "persistent"
attacked_fraction = 0.5
warmup_s = 1.0
durations.persistent_s = [4.0, 5.0]
"#;

/// Simulates a flight into `dir/flight` and returns it with its config file.
fn flight(dir: &Path) -> (PathBuf, PathBuf) {
    let cfg = dir.join("flight.toml");
    std::fs::write(&cfg, CONFIG).unwrap();
    let out = dir.join("flight");
    ok(&["simulate", "--config", s(&cfg), "--out", s(&out)]);
    (out, cfg)
}

/// A dataset directory `dir/ds/{train,valid}` of one residue file each and a CUSUM model
/// `dir/model` trained on it.
fn model(dir: &Path) -> (PathBuf, PathBuf) {
    let (fl, _) = flight(dir);
    let r = dir.join("r.csv");
    ok(&["residues", "--model", "I", "--in", s(&fl), "--out", s(&r)]);
    let ds = dir.join("ds");
    for split in ["train", "valid"] {
        std::fs::create_dir_all(ds.join(split)).unwrap();
        std::fs::copy(&r, ds.join(split).join("f.csv")).unwrap();
    }
    let model = dir.join("model");
    let (train, valid) = (ds.join("train"), ds.join("valid"));
    ok(&["train", "--method", "cusum", "--train", s(&train), "--valid", s(&valid), "--out", s(&model)]);
    (ds, model)
}

#[cfg(unix)]
#[test]
fn special_files_and_links_are_never_replaced() {
    let tmp = tempfile::tempdir().unwrap();
    let (fl, _) = flight(tmp.path());
    let err = fails(&["residues", "--model", "I", "--in", s(&fl), "--out", "/dev/null"]);
    assert!(err.contains("/dev/null: is a device; only regular files are replaced"), "{err}");
    let fifo = tmp.path().join("fifo");
    assert!(Command::new("mkfifo").arg(&fifo).status().unwrap().success());
    let err = fails(&["residues", "--model", "I", "--in", s(&fl), "--out", s(&fifo)]);
    assert!(err.contains("is a FIFO"), "{err}");
    assert!(std::fs::symlink_metadata(&fifo).unwrap().file_type().is_fifo_like());
    let target = tmp.path().join("precious.csv");
    std::fs::write(&target, "keep").unwrap();
    let link = tmp.path().join("link.csv");
    std::os::unix::fs::symlink(&target, &link).unwrap();
    let err = fails(&["residues", "--model", "I", "--in", s(&fl), "--out", s(&link)]);
    assert!(err.contains("is a symbolic link"), "{err}");
    assert_eq!(std::fs::read_to_string(&target).unwrap(), "keep");
    assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
}

/// `FileType::is_fifo` through a small extension, so the assertion reads plainly.
trait FifoLike {
    fn is_fifo_like(&self) -> bool;
}

#[cfg(unix)]
impl FifoLike for std::fs::FileType {
    fn is_fifo_like(&self) -> bool {
        use std::os::unix::fs::FileTypeExt as _;
        self.is_fifo()
    }
}

#[test]
fn inputs_models_and_datasets_are_not_outputs() {
    let tmp = tempfile::tempdir().unwrap();
    let (ds, model) = model(tmp.path());
    let input = ds.join("valid/f.csv");
    let before = std::fs::read(&input).unwrap();
    let err = fails(&["detect", "--model", s(&model), "--in", s(&input), "--out", s(&input)]);
    assert!(err.contains("--out is also the input --in"), "{err}");
    assert_eq!(std::fs::read(&input).unwrap(), before);
    let own = model.join("model.json");
    let err = fails(&["detect", "--model", s(&model), "--in", s(&input), "--out", s(&own)]);
    assert!(err.contains("--out lies inside --model"), "{err}");
    let (train, valid) = (ds.join("train"), ds.join("valid"));
    let err =
        fails(&["train", "--method", "cusum", "--train", s(&train), "--valid", s(&valid), "--out", s(&ds), "--force"]);
    assert!(err.contains("--out contains the input --train"), "{err}");
    assert!(input.is_file());
    let (fl, _) = (tmp.path().join("flight"), ());
    let r = tmp.path().join("r.csv");
    let r_before = std::fs::read(&r).unwrap();
    let err = fails(&["residues", "--model", "I", "--in", s(&fl), "--out", s(&r), "--estimates", s(&r)]);
    assert!(err.contains("--estimates and --out"), "{err}");
    assert_eq!(std::fs::read(&r).unwrap(), r_before);
    let inside = fl.join("r.csv");
    let err = fails(&["residues", "--model", "I", "--in", s(&fl), "--out", s(&inside)]);
    assert!(err.contains("--out lies inside --in"), "{err}");
}

#[test]
fn a_failing_command_leaves_nothing() {
    let tmp = tempfile::tempdir().unwrap();
    let (fl, _) = flight(tmp.path());
    let afile = tmp.path().join("afile");
    std::fs::write(&afile, "x").unwrap();
    let r = tmp.path().join("new.csv");
    let est = afile.join("e.csv");
    let err = fails(&["residues", "--model", "I", "--in", s(&fl), "--out", s(&r), "--estimates", s(&est)]);
    assert!(err.contains("afile: is a regular file, not a directory"), "{err}");
    assert!(!r.exists());
}

#[test]
fn a_failing_fuse_leaves_no_plots() {
    let tmp = tempfile::tempdir().unwrap();
    // A CUSUM model of Model I channels: the closed loop (Model II) cannot feed it, so the
    // detected case fails after the other cases have drawn their plots.
    let (_, model) = model(tmp.path());
    let out = tmp.path().join("fused");
    let err = fails(&["fuse", "--scenario", "diagonal", "--detector", "cusum", "--model", s(&model), "--out", s(&out)]);
    assert!(err.contains("detector channel `att_roll` not in the innovation"), "{err}");
    assert!(!out.exists(), "nothing under --out after a failed fuse");
}

#[test]
fn temporaries_of_a_killed_run_are_removed_and_long_names_work() {
    let tmp = tempfile::tempdir().unwrap();
    // What a killed `simulate` leaves: a temporary directory of a process that is gone (PID 0
    // is never a user process).
    let stale = tmp.path().join(format!("{}0-abcdef", eval::io::TEMP_PREFIX));
    std::fs::create_dir(&stale).unwrap();
    std::fs::write(stale.join("imu.csv"), "t\n").unwrap();
    let (fl, _) = flight(tmp.path());
    assert!(!stale.exists());
    let long = tmp.path().join(format!("{}.csv", "r".repeat(240)));
    ok(&["residues", "--model", "I", "--in", s(&fl), "--out", s(&long)]);
    assert!(long.is_file());
    let names: Vec<String> =
        std::fs::read_dir(tmp.path()).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    assert!(names.iter().all(|n| !n.starts_with(eval::io::TEMP_PREFIX)), "{names:?}");
}
