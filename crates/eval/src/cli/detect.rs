//! `quadformer detect`: scores one residue CSV (docs/data-format.md "Residue file"; residues of
//! paper alg:alg1) with a model directory written by `quadformer train`, and writes per-step
//! alarms.
//!
//! Output (written atomically): `t` (s, the residue step's time), `score` (the method's anomaly
//! score, higher = more anomalous; for QUADFormer the scoring mode chosen on validation, paper
//! sec:attack_detector, alg:alg2), `alarm` (`1` when `score > threshold`, the threshold chosen on
//! validation), and `label` when the input has one; then precision, recall and F1 of the alarms
//! (eq:precision, eq:recall, eq:F1; per step, no point adjustment, decision 060) are printed to stderr.
//!
//! With `--streaming` every step is scored as the streaming detector of `quadformer fuse` scores
//! it (from that step and the ones before it only, `Detector::score_streaming`) and alarms at the
//! streaming threshold chosen on validation; without it a step's score may use later steps
//! (QUADFormer averages every window that covers it).
//!
//! QUADFormer is loaded from its checkpoint (size, SHA-256, tensor names and shapes checked);
//! the other methods are re-fitted from the training data recorded in the model directory
//! (decision 081), and a warning is printed if the re-fitted threshold differs from the one
//! recorded at training time.

use std::fmt::Write as _;
use std::path::{Component, Path, PathBuf};

use detection_metrics::Confusion;
use ekf_residue::Detector;
use quadformer_model::{ModelError, QuadFormerDetector};

use crate::cli::CliError;
use crate::cli::train::{ModelManifest, Storage, check_same_channels, read_manifest, read_split, sha256_hex};
use crate::io::{Input, IoError, Output, check_outputs, read_residues, write_text_atomic};
use crate::runner::fit;

/// Relative tolerance between the recorded and the re-fitted threshold before a warning: the
/// statistical methods re-fit bit-identically; networks may differ in the last bits with the
/// thread count.
const THRESHOLD_RTOL: f64 = 1e-9;

/// Arguments of `quadformer detect`.
#[derive(Debug, clap::Args)]
#[command(after_help = "QUADFormer models load from their checkpoint; the other methods are re-fitted from the \
training data recorded in the model directory (see `quadformer train --help`, docs/cli.md).")]
pub struct Args {
    /// Model directory written by `quadformer train`.
    #[arg(long, value_name = "MODEL_DIR")]
    pub model: PathBuf,
    /// Residue CSV to score (its channels must equal the model's training channels).
    #[arg(long = "in", value_name = "FILE.csv")]
    pub input: PathBuf,
    /// Output alarm CSV: t, score, alarm[, label] (written atomically).
    #[arg(long, value_name = "ALARMS.csv")]
    pub out: PathBuf,
    /// Score as the streaming detector does (each step from itself and earlier steps only, at
    /// the streaming threshold), as `quadformer fuse` runs it.
    #[arg(long)]
    pub streaming: bool,
}

/// Runs `quadformer detect`.
///
/// # Errors
/// [`CliError`] naming the file: a missing, malformed or corrupt model manifest or checkpoint,
/// an input CSV with a bad line or column, or channels that differ from the training channels.
pub fn run(args: &Args) -> Result<(), CliError> {
    check_outputs(
        &[Input::new("--model", &args.model), Input::new("--in", &args.input)],
        &[Output::file("--out", &args.out)],
    )?;
    let manifest = read_manifest(&args.model)?;
    let input = read_residues(&args.input)?;
    check_same_channels(&args.input, &manifest.channels, input.series().channels())?;
    let detector = load_detector(&args.model, &manifest)?;
    check_same_channels(&args.input, detector.channels(), input.series().channels())?;
    let scored = if args.streaming { detector.score_streaming(input.series()) } else { detector.score(input.series()) };
    let scores = scored.map_err(|e| CliError::Input {
        path: args.input.clone(),
        msg: format!("{} cannot score it: {e}", manifest.method.name()),
    })?;
    if let Some(len) = manifest.method.window_len(&manifest.configs)
        && input.series().len() < len
    {
        eprintln!(
            "warning: {}: {} residue steps, fewer than {}'s window of {len}; its scores do not come from a \
             full window and are not comparable with those of longer series",
            args.input.display(),
            input.series().len(),
            manifest.method.name()
        );
    }
    if let Some((k, s)) = scores.iter().enumerate().find(|(_, s)| !s.is_finite()) {
        let t = input.series().t().get(k).copied().unwrap_or(f64::NAN);
        return Err(CliError::Input {
            path: args.input.clone(),
            msg: format!(
                "residue step {k} (t = {t} s): {} scores it {s}, not a finite number; are its residues far out of \
                 range?",
                manifest.method.name()
            ),
        });
    }
    let threshold = if args.streaming { detector.streaming_threshold() } else { detector.threshold() };
    let alarms: Vec<bool> = scores.iter().map(|&s| s > threshold).collect();
    let labels = input.labels();
    write_alarms(&args.out, input.series().t(), &scores, &alarms, labels)?;

    let n_alarms = alarms.iter().filter(|&&a| a).count();
    eprintln!(
        "wrote {}: {}{} on {} steps, {n_alarms} alarms (threshold {threshold:.6})",
        args.out.display(),
        manifest.method.name(),
        if args.streaming { " (streaming)" } else { "" },
        scores.len()
    );
    if let Some(labels) = labels {
        let c = Confusion::count(&alarms, labels);
        // A ratio with a zero denominator is undefined, not 0: say so.
        let ratio = |v: f64, defined: bool| if defined { format!("{v:.4}") } else { "undefined".to_owned() };
        eprintln!(
            "precision {}  recall {}  F1 {}  (tp {} fp {} fn {} tn {})",
            ratio(c.precision(), c.tp + c.fp > 0),
            ratio(c.recall(), c.tp + c.fn_ > 0),
            ratio(c.f1(), c.tp + c.fp + c.fn_ > 0),
            c.tp,
            c.fp,
            c.fn_,
            c.tn
        );
        if c.tp + c.fn_ == 0 {
            eprintln!("note: {} has no attacked step, so recall and F1 are undefined", args.input.display());
        }
    }
    Ok(())
}

/// Loads (QUADFormer) or re-fits (other methods) the detector of a model directory.
///
/// # Errors
/// [`CliError::Input`] naming the checkpoint or recorded data file that is missing, corrupt or
/// inconsistent; [`CliError::Run`] if re-fitting fails.
pub fn load_detector(model_dir: &Path, m: &ModelManifest) -> Result<Box<dyn Detector>, CliError> {
    match &m.storage {
        Storage::Checkpoint { manifest, manifest_sha256 } => {
            let path = inside(model_dir, manifest)?;
            if let Some(want) = manifest_sha256 {
                let bytes = std::fs::read(&path)
                    .map_err(|source| CliError::Io(IoError::Fs { path: path.clone(), op: "read", source }))?;
                if sha256_hex(&bytes) != *want {
                    return Err(CliError::Input {
                        path: path.clone(),
                        msg: format!("corrupted: SHA-256 differs from the one in {}", crate::cli::train::MODEL_FILE),
                    });
                }
            }
            // Name each file once: checkpoint errors carry their own file.
            let det = QuadFormerDetector::load(&path).map_err(|e| match e {
                ModelError::Checkpoint { path, msg } => CliError::Input { path, msg },
                ModelError::Io { path, source } => CliError::Io(IoError::Fs { path, op: "read", source }),
                other => CliError::Input {
                    path: path.clone(),
                    msg: format!("cannot load the QUADFormer checkpoint: {other}"),
                },
            })?;
            Ok(Box::new(det))
        }
        Storage::Refit { train, valid } => {
            let files = |names: &[String]| names.iter().map(|n| inside(model_dir, n)).collect::<Result<Vec<_>, _>>();
            let train = read_split(&files(train)?, Some(&m.channels), false)?;
            let valid = read_split(&files(valid)?, Some(&m.channels), true)?;
            let fitted = fit(m.method, &m.configs, &train, &valid).map_err(|e| CliError::Run(e.to_string()))?;
            let t = fitted.detector.threshold();
            if (t - m.threshold).abs() > THRESHOLD_RTOL * m.threshold.abs().max(1.0) {
                eprintln!(
                    "warning: {}: re-fitted threshold {t} differs from the recorded {}",
                    model_dir.display(),
                    m.threshold
                );
            }
            Ok(fitted.detector)
        }
    }
}

/// `rel` resolved in `dir`, refusing absolute paths and `..` (a manifest must not point outside
/// its model directory).
fn inside(dir: &Path, rel: &str) -> Result<PathBuf, CliError> {
    let p = Path::new(rel);
    if p.components().all(|c| matches!(c, Component::Normal(_))) {
        Ok(dir.join(p))
    } else {
        Err(CliError::Input {
            path: dir.join(crate::cli::train::MODEL_FILE),
            msg: format!("file `{rel}` is not inside the model directory"),
        })
    }
}

/// Writes the alarm CSV atomically.
fn write_alarms(
    path: &Path,
    t: &[f64],
    scores: &[f64],
    alarms: &[bool],
    labels: Option<&[bool]>,
) -> Result<(), CliError> {
    if scores.len() != t.len() {
        return Err(CliError::Input {
            path: path.to_owned(),
            msg: format!("{} scores for {} residue steps", scores.len(), t.len()),
        });
    }
    let mut text = String::with_capacity(32 * t.len() + 32);
    text.push_str(if labels.is_some() { "t,score,alarm,label\n" } else { "t,score,alarm\n" });
    for (k, (&t_k, &s_k)) in t.iter().zip(scores).enumerate() {
        if !s_k.is_finite() {
            return Err(CliError::Io(IoError::Unwritable {
                path: path.to_owned(),
                row: k,
                field: "score".into(),
                msg: format!("non-finite score {s_k} at t = {t_k}"),
            }));
        }
        // `{:?}` prints the shortest representation that parses back to the same f64.
        let _ = write!(text, "{t_k:?},{s_k:?},{}", u8::from(alarms.get(k).copied().unwrap_or(false)));
        if let Some(l) = labels {
            let _ = write!(text, ",{}", u8::from(l.get(k).copied().unwrap_or(false)));
        }
        text.push('\n');
    }
    write_text_atomic(path, &text).map_err(CliError::Io)
}
