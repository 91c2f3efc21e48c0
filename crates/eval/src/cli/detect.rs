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
//! streaming threshold chosen on validation (QUADFormer: in the mode chosen on the streaming
//! scores, which may differ from the offline one); without it a step's score may use later
//! steps (QUADFormer averages every window that covers it).
//!
//! Every method loads its saved fitted state from the model directory ([`crate::model_dir`],
//! each file's SHA-256 checked against `model.json`); `detect` never fits.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use detection_metrics::Confusion;

use crate::cli::CliError;
use crate::cli::train::check_same_channels;
use crate::io::{Input, IoError, Output, check_outputs, read_residues, write_text_atomic};
use crate::model_dir;

/// Arguments of `quadformer detect`.
#[derive(Debug, clap::Args)]
#[command(after_help = "Every method loads the fitted state saved in the model directory; nothing is re-fitted \
(see `quadformer train --help`, docs/cli.md).")]
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
    let manifest = model_dir::read_manifest(&args.model)?;
    let input = read_residues(&args.input)?;
    check_same_channels(&args.input, &manifest.channels, input.series().channels())?;
    let detector = model_dir::load(&args.model, &manifest)?;
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
