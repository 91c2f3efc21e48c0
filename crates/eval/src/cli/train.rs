//! `quadformer train`: fits one detection method on residue CSV files (docs/data-format.md
//! "Residue file"; residues of paper alg:alg1) and saves a model directory for
//! `quadformer detect`.
//!
//! Every `*.csv` in `--train` and `--valid` (sorted by name) is one flight. Labels are optional
//! in training files (semi-supervision, decision 031) and required in validation files, where the
//! method chooses its alarm threshold (the `Fit` contract: thresholds on validation only). All
//! files must share one channel list (the `r_` columns, in order).
//!
//! The model directory (decision 081, amended by decision 110; [`crate::model_dir`]) holds
//! `model.json` and the method's saved fitted state, so `quadformer detect` never fits.

use std::path::{Path, PathBuf};

use ekf_residue::{LabelledResidues, LabelledSeries};

use crate::cli::CliError;
use crate::io::{Input, IoError, Output, Overwrite, check_dir_output, check_outputs, read_residues};
use crate::methods::{Method, MethodConfigs};
use crate::model_dir::{self, Trained};

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

/// Arguments of `quadformer train`.
#[derive(Debug, clap::Args)]
#[command(
    after_help = "Model directory: model.json and the fitted state, which `quadformer detect` loads without fitting: \
detector.json (the fitted parameters of cusum, sprt, bht, chi2, px4-gate, glr and svm; the manifest of cnn and lstm, with \
detector.safetensors for their weights) or quadformer.json + quadformer.safetensors (the QUADFormer checkpoint). See \
docs/cli.md and decisions 081 and 110."
)]
pub struct Args {
    /// Method: quadformer, cusum, sprt, bht, chi2, px4-gate, glr, svm, cnn or lstm.
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

    let (det, files) =
        method.fit_and_save(&cfgs, &train, &valid).map_err(|e| fit_err(format!("{}: {e}", method.name())))?;
    let threshold = finite(det.threshold())?;
    let trained = Trained { method, channels: channels.clone(), threshold, seed: args.seed, configs: cfgs, trained_on };
    model_dir::write(&args.out, overwrite, trained, &files)?;
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
