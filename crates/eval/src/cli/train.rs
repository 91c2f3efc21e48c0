//! `quadformer train`: fits one detection method on residue CSV files (docs/data-format.md
//! "Residue file"; residues of paper alg:alg1) and saves a model directory for
//! `quadformer detect`.
//!
//! Every `*.csv` in `--train` and `--valid` (sorted by name) is one flight. Labels are optional
//! in training files (semi-supervision, decision 031) and required in validation files, where the
//! method chooses its alarm threshold (the `Fit` contract: thresholds on validation only). All
//! files must share one channel list (the `r_` columns, in order).
//!
//! Model directory (decision 081), written atomically:
//! - `model.json` ([`ModelManifest`]): format name and version, method, channels, fitted
//!   threshold, seed, the method configurations used, and how the fitted detector is stored
//!   (plain file names inside the directory; for QUADFormer with the SHA-256 of its checkpoint
//!   manifest); [`read_manifest`] validates every field;
//! - QUADFormer: `quadformer.json` + `quadformer.safetensors` (the checkpoint of
//!   `quadformer_model::checkpoint`: manifest with normaliser, scoring mode and threshold,
//!   weights with size and SHA-256);
//! - every other method (cusum, sprt, bht, chi2, px4-gate, svm, cnn, lstm; their fitted types
//!   have no save format): `data/train/*.csv` and `data/valid/*.csv`, a copy of the training
//!   data, from which `detect` re-fits the method with the recorded configuration and seed.

use std::path::{Path, PathBuf};

use ekf_residue::{Detector, Fit, LabelledResidues, LabelledSeries};
use quadformer_model::checkpoint::weights_file_name;
use serde::{Deserialize, Serialize};

use crate::cli::CliError;
use crate::io::{
    CovarianceLayout, Input, IoError, Output, Overwrite, check_dir_output, check_outputs, read_residues,
    write_bytes_atomic, write_dir_atomic, write_residues, write_text_atomic,
};
use crate::methods::{Method, MethodConfigs};
use crate::runner::fit;

/// Name of the model manifest in a model directory.
pub const MODEL_FILE: &str = "model.json";
/// Format name written into every model manifest.
pub const MODEL_FORMAT: &str = "quadformer-model-dir";
/// Current model manifest version.
pub const MODEL_VERSION: u32 = 1;
/// QUADFormer checkpoint manifest in a model directory (weights beside it, `.safetensors`).
pub const CHECKPOINT_FILE: &str = "quadformer.json";
/// Directory of the recorded training data of re-fitted methods.
pub const DATA_DIR: &str = "data";
/// Fewest training residue steps `train` fits on (more for windowed methods: one window).
pub const MIN_TRAIN_STEPS: usize = 10;

/// Checks that the splits can fit `method`: at least [`MIN_TRAIN_STEPS`] training steps and
/// one window of them; validation with both attacked and clean steps, between which the
/// threshold is chosen.
fn check_enough_data(
    args: &Args,
    cfgs: &MethodConfigs,
    train: &LabelledResidues,
    valid: &LabelledResidues,
) -> Result<(), CliError> {
    let window = args.method.window_len(cfgs);
    let need = window.unwrap_or(0).max(MIN_TRAIN_STEPS);
    if train.n_steps() < need {
        let why = match window {
            Some(len) if len >= MIN_TRAIN_STEPS => format!(" (one window of {len})"),
            _ => String::new(),
        };
        return Err(CliError::Input {
            path: args.train.clone(),
            msg: format!("{} residue steps; {} needs at least {need}{why}", train.n_steps(), args.method.name()),
        });
    }
    let (mut attacked, mut clean) = (0usize, 0usize);
    for (_, labels) in valid.labelled() {
        let a = labels.iter().filter(|&&l| l).count();
        attacked += a;
        clean += labels.len() - a;
    }
    if attacked == 0 || clean == 0 {
        return Err(CliError::Input {
            path: args.valid.clone(),
            msg: format!(
                "{attacked} attacked and {clean} clean steps; the alarm threshold is chosen between them, so \
                 validation needs both"
            ),
        });
    }
    Ok(())
}

/// How the fitted detector is kept in a model directory.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case", tag = "kind", deny_unknown_fields)]
pub enum Storage {
    /// A QUADFormer checkpoint (`quadformer_model::checkpoint`).
    Checkpoint {
        /// Checkpoint manifest: a plain file name in the model directory.
        manifest: String,
        /// Lower-case hex SHA-256 of the checkpoint manifest (which holds the SHA-256 of the
        /// weights), checked before it is read; absent in directories written before it existed.
        #[serde(default, skip_serializing_if = "Option::is_none")]
        manifest_sha256: Option<String>,
    },
    /// A copy of the training data; `detect` re-fits the method from it.
    Refit {
        /// Training residue files: `data/train/<plain file name>`.
        train: Vec<String>,
        /// Validation residue files: `data/valid/<plain file name>`.
        valid: Vec<String>,
    },
}

/// The `model.json` manifest of a model directory (file format, versioned).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelManifest {
    /// Always [`MODEL_FORMAT`].
    pub format: String,
    /// [`MODEL_VERSION`] when written.
    pub version: u32,
    /// The method.
    pub method: Method,
    /// Residue channels the method was trained on, in order.
    pub channels: Vec<String>,
    /// Alarm threshold chosen on validation (a step alarms when its score exceeds it).
    pub threshold: f64,
    /// Seed of the method's random parts (weights, shuffling, subsampling).
    pub seed: u64,
    /// Every method's configuration as used (already seeded).
    pub configs: MethodConfigs,
    /// Where the fitted detector is.
    pub storage: Storage,
    /// Training and validation flight files the model was fitted on (as given).
    pub trained_on: Vec<String>,
}

/// Arguments of `quadformer train`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Model directory: QUADFormer is saved as a checkpoint (quadformer.json + quadformer.safetensors). \
The other methods (cusum, sprt, bht, chi2, px4-gate, svm, cnn, lstm) have no save format: the model directory keeps \
their configuration and a copy of the training and validation residues, and `quadformer detect` re-fits them from it \
(deterministic for a given seed). See docs/cli.md and decision 081."
)]
pub struct Args {
    /// Method: quadformer, cusum, sprt, bht, chi2, px4-gate, svm, cnn or lstm.
    #[arg(long, value_parser = parse_method)]
    pub method: Method,
    /// Directory of training residue CSVs (every `*.csv`; labels optional).
    #[arg(long, value_name = "DIR")]
    pub train: PathBuf,
    /// Directory of validation residue CSVs (every `*.csv`; labels required): thresholds are
    /// chosen here.
    #[arg(long, value_name = "DIR")]
    pub valid: PathBuf,
    /// Output model directory (must not exist or be empty, unless `--force`).
    #[arg(long, value_name = "MODEL_DIR")]
    pub out: PathBuf,
    /// Method configurations (TOML, one table per method: `quadformer`, `cusum`, `sprt`, `bht`,
    /// `svm`, `cnn`, `lstm`, `chi2`, `px4_gate`; keys left out keep the base values, the
    /// defaults or, with `--quick`, the quick ones).
    #[arg(long, value_name = "FILE.toml")]
    pub config: Option<PathBuf>,
    /// Small networks and few epochs (as `reproduce-tables --quick`): a smoke test.
    #[arg(long)]
    pub quick: bool,
    /// Seed of the method's random parts.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Replace a non-empty output directory.
    #[arg(long)]
    pub force: bool,
}

/// Parses a method name for clap.
fn parse_method(s: &str) -> Result<Method, String> {
    Method::parse(s).map_err(|e| e.to_string())
}

/// Residue files of a directory: every `*.csv`, sorted by name.
///
/// # Errors
/// [`CliError::Io`] if the directory cannot be listed; [`CliError::Input`] if it has no CSV.
pub fn csv_files(dir: &Path) -> Result<Vec<PathBuf>, CliError> {
    let entries = std::fs::read_dir(dir).map_err(|source| IoError::Fs { path: dir.to_owned(), op: "list", source })?;
    let mut files = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|source| IoError::Fs { path: dir.to_owned(), op: "list", source })?;
        let path = entry.path();
        if path.is_file() && path.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv")) {
            files.push(path);
        }
    }
    files.sort();
    if files.is_empty() {
        return Err(CliError::Input { path: dir.to_owned(), msg: "no *.csv residue files".into() });
    }
    Ok(files)
}

/// Reads residue files that must share `channels` (the first file's when `None`).
///
/// # Errors
/// [`CliError::Io`] naming file, line and column of bad input; [`CliError::Input`] naming the
/// file whose channels differ, or that has no labels when `need_labels`.
pub fn read_split(
    files: &[PathBuf],
    channels: Option<&[String]>,
    need_labels: bool,
) -> Result<LabelledResidues, CliError> {
    let mut flights: Vec<LabelledSeries> = Vec::with_capacity(files.len());
    let mut expected: Option<Vec<String>> = channels.map(<[String]>::to_vec);
    for path in files {
        let f = read_residues(path)?;
        let got = f.series().channels();
        match &expected {
            Some(want) => check_same_channels(path, want, got)?,
            None => expected = Some(got.to_vec()),
        }
        if need_labels && f.labels().is_none() {
            return Err(CliError::Input {
                path: path.clone(),
                msg: "no `label` column; validation files need labels (thresholds are chosen on them)".into(),
            });
        }
        flights.push(f);
    }
    let first = files.first().cloned().unwrap_or_default();
    LabelledResidues::new(flights).map_err(|e| CliError::Input { path: first, msg: e.to_string() })
}

/// Checks that a file's channels equal the expected ones, naming both lists.
///
/// # Errors
/// [`CliError::Input`] naming `path`.
pub fn check_same_channels(path: &Path, want: &[String], got: &[String]) -> Result<(), CliError> {
    if want == got {
        return Ok(());
    }
    Err(CliError::Input {
        path: path.to_owned(),
        msg: format!(
            "channel mismatch: file has [{}], the model's training channels are [{}]",
            got.join(", "),
            want.join(", ")
        ),
    })
}

/// The method configurations: the base (defaults, or quick ones) with the keys of `path`
/// over it, seeded.
///
/// # Errors
/// [`CliError::Io`] if the file cannot be read or parsed; [`CliError::Config`] naming an unknown
/// or ill-typed field.
pub fn method_configs(path: Option<&Path>, quick: bool, seed: u64) -> Result<MethodConfigs, CliError> {
    let base = if quick { MethodConfigs::quick() } else { MethodConfigs::full() };
    let Some(path) = path else {
        return Ok(base.seeded(seed));
    };
    let text = crate::io::read_text(path)?;
    let config_err = |msg: String| CliError::Config { path: path.to_owned(), msg };
    let user: toml::Table = text.parse().map_err(|e: toml::de::Error| config_err(e.to_string()))?;
    let mut merged = toml::Table::try_from(&base).map_err(|e| config_err(e.to_string()))?;
    crate::io::merge_over(&mut merged, user);
    let cfgs: MethodConfigs =
        merged.try_into().map_err(|e: toml::de::Error| config_err(e.message().trim().to_owned()))?;
    // Sizes are checked against their budgets here, before any data is read.
    for &m in Method::ALL {
        m.check(&cfgs).map_err(|e| config_err(format!("[{}]: {e}", m.config_key())))?;
    }
    Ok(cfgs.seeded(seed))
}

/// Runs `quadformer train`.
///
/// # Errors
/// [`CliError`] naming the file of bad input (line and column for CSV errors, field for
/// config errors), [`CliError::Run`] when fitting fails.
pub fn run(args: &Args) -> Result<(), CliError> {
    let overwrite = if args.force { Overwrite::Replace } else { Overwrite::Refuse };
    let mut inputs = vec![Input::new("--train", &args.train), Input::new("--valid", &args.valid)];
    inputs.extend(args.config.as_deref().map(|p| Input::new("--config", p)));
    check_outputs(&inputs, &[Output::dir("--out", &args.out)])?;
    check_dir_output(&args.out, overwrite)?;
    let cfgs = method_configs(args.config.as_deref(), args.quick, args.seed)?;
    let train_files = csv_files(&args.train)?;
    let valid_files = csv_files(&args.valid)?;
    let train = read_split(&train_files, None, false)?;
    let channels = train.channels().to_vec();
    let valid = read_split(&valid_files, Some(&channels), true)?;
    check_enough_data(args, &cfgs, &train, &valid)?;
    let method = args.method;
    let fit_err = |msg: String| {
        CliError::Run(format!("--train {}, --valid {}: {msg}", args.train.display(), args.valid.display()))
    };
    // A threshold that is not finite cannot be stored in JSON and alarms never or always.
    let finite = |threshold: f64| {
        if threshold.is_finite() {
            Ok(threshold)
        } else {
            Err(CliError::Input {
                path: args.valid.clone(),
                msg: format!(
                    "{} chose threshold {threshold} on these files; do they contain attacked steps?",
                    method.name()
                ),
            })
        }
    };
    let trained_on: Vec<String> = train_files.iter().chain(&valid_files).map(|p| p.display().to_string()).collect();

    let threshold = if method == Method::QuadFormer {
        let det =
            cfgs.quadformer.fit(&train, &valid).map_err(|e| fit_err(format!("{}: fit failed: {e}", method.name())))?;
        let threshold = finite(det.threshold())?;
        let files = det
            .encode(&weights_file_name(CHECKPOINT_FILE))
            .map_err(|e| CliError::Run(format!("{}: {e}", args.out.display())))?;
        let manifest = manifest(
            method,
            &channels,
            threshold,
            args.seed,
            &cfgs,
            trained_on,
            Storage::Checkpoint {
                manifest: CHECKPOINT_FILE.into(),
                manifest_sha256: Some(sha256_hex(files.manifest.as_bytes())),
            },
        );
        write_dir_atomic(&args.out, overwrite, |dir| {
            write_bytes_atomic(&dir.join(weights_file_name(CHECKPOINT_FILE)), &files.weights)?;
            write_text_atomic(&dir.join(CHECKPOINT_FILE), &files.manifest)?;
            write_manifest(dir, &manifest)
        })?;
        threshold
    } else {
        let fitted = fit(method, &cfgs, &train, &valid).map_err(|e| fit_err(e.to_string()))?;
        let threshold = finite(fitted.detector.threshold())?;
        let rel = |split: &str, files: &[PathBuf]| -> Vec<String> {
            files.iter().enumerate().map(|(i, p)| recorded_name(split, i, p)).collect()
        };
        let storage = Storage::Refit { train: rel("train", &train_files), valid: rel("valid", &valid_files) };
        let manifest = manifest(method, &channels, threshold, args.seed, &cfgs, trained_on, storage.clone());
        write_dir_atomic(&args.out, overwrite, |dir| {
            if let Storage::Refit { train: tn, valid: vn } = &storage {
                for (names, split) in [(tn, &train), (vn, &valid)] {
                    for (name, f) in names.iter().zip(split.flights()) {
                        write_residues(&dir.join(name), f.series(), f.labels(), CovarianceLayout::Upper)?;
                    }
                }
            }
            write_manifest(dir, &manifest)
        })?;
        threshold
    };
    eprintln!(
        "wrote {}: {} on {} training + {} validation flights ({} + {} steps), channels {}, threshold {threshold:.6}",
        args.out.display(),
        method.name(),
        train.flights().len(),
        valid.flights().len(),
        train.n_steps(),
        valid.n_steps(),
        channels.join(" ")
    );
    Ok(())
}

/// Relative path of the recorded copy of input file `i` of `split`: the original file name,
/// prefixed with its index so names from different directories cannot collide.
fn recorded_name(split: &str, i: usize, original: &Path) -> String {
    let name = original.file_name().map_or_else(|| "flight.csv".into(), |n| n.to_string_lossy().into_owned());
    format!("{DATA_DIR}/{split}/{i:04}-{name}")
}

fn manifest(
    method: Method,
    channels: &[String],
    threshold: f64,
    seed: u64,
    cfgs: &MethodConfigs,
    trained_on: Vec<String>,
    storage: Storage,
) -> ModelManifest {
    ModelManifest {
        format: MODEL_FORMAT.into(),
        version: MODEL_VERSION,
        method,
        channels: channels.to_vec(),
        threshold,
        seed,
        configs: cfgs.clone(),
        storage,
        trained_on,
    }
}

fn write_manifest(dir: &Path, m: &ModelManifest) -> crate::io::Result<()> {
    let path = dir.join(MODEL_FILE);
    let json = serde_json::to_string_pretty(m)
        .map_err(|e| IoError::Inconsistent { path: path.clone(), msg: format!("cannot serialise: {e}") })?;
    write_text_atomic(&path, &json)
}

/// Most files a model manifest may list (training plus validation flights).
pub const MAX_MANIFEST_FILES: usize = 100_000;

/// Lower-case hex SHA-256 of `bytes`.
#[must_use]
pub fn sha256_hex(bytes: &[u8]) -> String {
    use sha2::Digest as _;
    sha2::Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

/// Whether `name` is a plain file name: one normal component, no separator.
#[must_use]
pub fn is_plain_name(name: &str) -> bool {
    !name.contains(['/', '\\']) && Path::new(name).file_name().is_some_and(|n| n == name)
}

/// A JSON error's message without the ` at line L column C` serde_json appends (the caller
/// reports the position once, itself).
fn json_message(e: &serde_json::Error) -> String {
    let msg = e.to_string();
    match msg.rsplit_once(" at line ") {
        Some((head, _)) if e.line() > 0 => head.to_owned(),
        _ => msg,
    }
}

/// Checks every field of a parsed manifest (see [`read_manifest`]); the message names the field.
fn check_fields(m: &ModelManifest) -> Result<(), String> {
    if m.channels.is_empty() {
        return Err("channels: empty".into());
    }
    if m.channels.len() > nn_toolkit::window::MAX_CHANNELS {
        return Err(format!(
            "channels: {} exceed the budget of {}",
            m.channels.len(),
            nn_toolkit::window::MAX_CHANNELS
        ));
    }
    for (i, c) in m.channels.iter().enumerate() {
        if c.is_empty() || c.chars().any(|ch| ch.is_control() || ch == ',') {
            return Err(format!("channels[{i}]: {c:?} is not a channel name (empty, a control character or `,`)"));
        }
        if m.channels[..i].contains(c) {
            return Err(format!("channels[{i}]: `{c}` is listed twice"));
        }
    }
    if !m.threshold.is_finite() {
        return Err(format!("threshold: must be finite, got {}", m.threshold));
    }
    if m.trained_on.len() > MAX_MANIFEST_FILES {
        return Err(format!("trained_on: {} entries exceed the budget of {MAX_MANIFEST_FILES}", m.trained_on.len()));
    }
    match &m.storage {
        Storage::Checkpoint { manifest, manifest_sha256 } => {
            if !is_plain_name(manifest) {
                return Err(format!("storage.manifest: `{manifest}` must be a plain file name in the model directory"));
            }
            if let Some(h) = manifest_sha256
                && !(h.len() == 64 && h.chars().all(|c| c.is_ascii_digit() || ('a'..='f').contains(&c)))
            {
                return Err(format!("storage.manifest_sha256: `{h}` is not a lower-case hex SHA-256"));
            }
        }
        Storage::Refit { train, valid } => {
            for (split, names) in [("train", train), ("valid", valid)] {
                if names.is_empty() {
                    return Err(format!("storage.{split}: no files"));
                }
                if names.len() > MAX_MANIFEST_FILES {
                    return Err(format!(
                        "storage.{split}: {} files exceed the budget of {MAX_MANIFEST_FILES}",
                        names.len()
                    ));
                }
                let prefix = format!("{DATA_DIR}/{split}/");
                for (i, n) in names.iter().enumerate() {
                    let plain = n.strip_prefix(&prefix).is_some_and(is_plain_name);
                    if !plain {
                        return Err(format!("storage.{split}[{i}]: `{n}` must be `{prefix}<plain file name>`"));
                    }
                    if names[..i].contains(n) {
                        return Err(format!("storage.{split}[{i}]: `{n}` is listed twice"));
                    }
                }
            }
        }
    }
    Ok(())
}

/// Reads and checks the `model.json` of a model directory.
///
/// # Errors
/// [`CliError::Io`] if it cannot be read; [`CliError::Input`] naming the file when it is
/// malformed (line and column), of another format or version, or inconsistent, or a field is
/// invalid (named): no channels or a duplicate, a threshold that is not finite, a file name
/// that is not a plain name inside the model directory, a list over its budget.
pub fn read_manifest(model_dir: &Path) -> Result<ModelManifest, CliError> {
    let path = model_dir.join(MODEL_FILE);
    let bad = |msg: String| CliError::Input { path: path.clone(), msg };
    let text = crate::io::read_text(&path)?;
    let m: ModelManifest = serde_json::from_str(&text).map_err(|e| {
        bad(format!("malformed model manifest at line {}, column {}: {}", e.line(), e.column(), json_message(&e)))
    })?;
    if m.format != MODEL_FORMAT {
        return Err(bad(format!("format is `{}`, expected `{MODEL_FORMAT}`", m.format)));
    }
    if m.version != MODEL_VERSION {
        return Err(bad(format!("version {} is not supported (this build reads {MODEL_VERSION})", m.version)));
    }
    check_fields(&m).map_err(bad)?;
    let storage_ok =
        matches!((&m.storage, m.method), (Storage::Checkpoint { .. }, Method::QuadFormer) | (Storage::Refit { .. }, _));
    if !storage_ok {
        return Err(bad(format!("{} cannot be stored as {:?}", m.method.name(), m.storage)));
    }
    Ok(m)
}
