//! `quadformer residues`: flight directory → residue CSV (paper alg:alg1, eq:ekf_update;
//! docs/data-format.md "Residue file").
//!
//! The EKF (`ekf_residue::residues::generate_residues`) runs on the streams of the directory.
//! Its noise model is, in order of precedence: the `--filter-config` file (keys left out keep
//! the base values), else the simulator settings of the directory's `config.toml` when it was
//! made by `quadformer simulate` (`FilterConfig::for_sim`, a consistent filter; a
//! `config.toml` that does not parse is an error, not a silent fall-back), else the
//! documented defaults (`FilterConfig::new`). Labels come from `attack.csv` when present: a
//! residue step is attacked when the GPS fix at its time is (`eval::io::labels_at`).

use std::path::{Path, PathBuf};

use ekf_residue::residues::{FilterConfig, ModelKind, generate_residues};
use uav_dynamics::TruthSample;

use crate::cli::CliError;
use crate::io::{
    ATTITUDE_FILE, CONFIG_FILE, CovarianceLayout, FlightConfig, FlightDir, GPS_FILE, Input, IoError, Output, VO_FILE,
    check_outputs, commit_all, labels_at, merge_over, read_flight_dir, stage_residues, stage_truth,
};

/// Which EKF model to run (paper Sec. IV-A and V-A).
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ModelArg {
    /// Model I: 15 states, GPS position + attitude measurement (paper Eqs. (28)–(29)).
    #[value(name = "I", alias = "1", alias = "i")]
    One,
    /// Model II: 21 states with a keyframe clone, VO relative pose (+ GPS) (paper Eqs. (31)–(32)).
    #[value(name = "II", alias = "2", alias = "ii")]
    Two,
}

impl From<ModelArg> for ModelKind {
    fn from(m: ModelArg) -> Self {
        match m {
            ModelArg::One => Self::ModelI,
            ModelArg::Two => Self::ModelII,
        }
    }
}

/// Storage of S_k in the residue file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum LayoutArg {
    /// Upper triangle, m(m+1)/2 columns.
    #[default]
    Upper,
    /// All m² entries.
    Full,
}

impl From<LayoutArg> for CovarianceLayout {
    fn from(l: LayoutArg) -> Self {
        match l {
            LayoutArg::Upper => Self::Upper,
            LayoutArg::Full => Self::Full,
        }
    }
}

/// Arguments of `quadformer residues`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// EKF model: I (GPS + attitude) or II (VO + GPS, keyframe cloning).
    #[arg(long, value_enum)]
    pub model: ModelArg,
    /// Flight directory: imu.csv plus the streams the model needs (I: gps.csv and
    /// attitude.csv; II: vo.csv, with gps.csv and attitude.csv used when present); truth.csv
    /// and attack.csv are optional.
    #[arg(long = "in", value_name = "DIR")]
    pub input: PathBuf,
    /// Output residue CSV (written atomically).
    #[arg(long, value_name = "FILE.csv")]
    pub out: PathBuf,
    /// How to store S_k.
    #[arg(long, value_enum, default_value_t = LayoutArg::Upper)]
    pub covariance: LayoutArg,
    /// Filter settings (TOML, `ekf_residue::residues::FilterConfig` fields: imu, meas, init,
    /// cov_update, guard, pair_tolerance_s); keys left out keep the base values.
    #[arg(long, value_name = "FILE.toml")]
    pub filter_config: Option<PathBuf>,
    /// Also write the posterior state estimate after each residue step (truth.csv columns).
    #[arg(long, value_name = "FILE.csv")]
    pub estimates: Option<PathBuf>,
    /// Do not write a label column even if attack.csv exists.
    #[arg(long)]
    pub no_labels: bool,
}

/// Runs `quadformer residues`.
///
/// # Errors
/// [`CliError`] naming the file, line and column of bad input, a stream the model needs that
/// is missing, or the filter time at which the EKF failed.
pub fn run(args: &Args) -> Result<(), CliError> {
    let mut inputs = vec![Input::new("--in", &args.input)];
    inputs.extend(args.filter_config.as_deref().map(|p| Input::new("--filter-config", p)));
    let mut outputs = vec![Output::file("--out", &args.out)];
    outputs.extend(args.estimates.as_deref().map(|p| Output::file("--estimates", p)));
    check_outputs(&inputs, &outputs)?;
    let flight = read_flight_dir(&args.input)?;
    let model = ModelKind::from(args.model);
    check_streams(&args.input, &flight, model)?;
    let cfg = filter_config(args, &flight, model)?;
    let out = generate_residues(&flight.streams, &cfg)
        .map_err(|e| CliError::Filter { path: args.input.clone(), msg: e.to_string() })?;
    let labels = match (&flight.attack, args.no_labels) {
        (Some(attack), false) => Some(labels_at(out.series.t(), attack)),
        _ => None,
    };
    // Both outputs are staged and committed together: a failure writing either leaves neither.
    let mut staged = vec![stage_residues(&args.out, &out.series, labels.as_deref(), args.covariance.into())?];
    if let Some(path) = &args.estimates {
        let rows: Vec<TruthSample> = out
            .estimates
            .iter()
            .map(|e| TruthSample { t: e.t, p: e.p, q: e.q, v: e.v, b_g: e.b_g, b_a: e.b_a })
            .collect();
        staged.push(stage_truth(path, &rows)?);
    }
    commit_all(staged)?;
    let n = out.series.len();
    #[allow(clippy::cast_precision_loss)] // step counts are far below 2^52
    let mean_nis = out.series.nis().iter().sum::<f64>() / n.max(1) as f64;
    let attacked = labels
        .as_ref()
        .map_or_else(|| "unlabelled".to_owned(), |l| format!("{} attacked", l.iter().filter(|&&x| x).count()));
    eprintln!(
        "wrote {}: {n} residue steps ({attacked}), channels {}, mean NIS {mean_nis:.3}",
        args.out.display(),
        out.series.channels().join(" ")
    );
    Ok(())
}

/// Checks that the directory has the streams `model` needs, naming the missing file.
fn check_streams(dir: &Path, flight: &FlightDir, model: ModelKind) -> Result<(), CliError> {
    let s = &flight.streams;
    let needed: &[(&str, bool)] = match model {
        ModelKind::ModelI => &[(GPS_FILE, s.gps.is_empty()), (ATTITUDE_FILE, s.attitude.is_empty())],
        ModelKind::ModelII => &[(VO_FILE, s.vo.is_empty())],
    };
    for &(file, missing) in needed {
        if missing {
            let model_name = if model == ModelKind::ModelI { "Model I" } else { "Model II" };
            return Err(CliError::Input {
                path: dir.join(file),
                msg: format!("missing or empty; {model_name} needs it"),
            });
        }
    }
    Ok(())
}

/// The filter a flight folder `dir` asks for: the sensor σ of its `config.toml`, or the
/// documented defaults without one. A `config.toml` that does not parse is an error, since it
/// would silently change the noise model.
///
/// # Errors
/// [`CliError::Input`] naming `config.toml` and the field.
pub(crate) fn flight_filter(dir: &Path, flight: &FlightDir, model: ModelKind) -> Result<FilterConfig, CliError> {
    let Some(text) = &flight.config_toml else {
        return Ok(FilterConfig::new(model));
    };
    let path = dir.join(CONFIG_FILE);
    let cfg = FlightConfig::from_toml(&path, text).map_err(|e| CliError::Input {
        path: path.clone(),
        msg: format!(
            "{}\n(the filter's noise model is taken from this file; fix it, or remove it to use the \
             documented default filter settings)",
            match e {
                IoError::Toml { msg, .. } => msg,
                other => other.to_string(),
            }
        ),
    })?;
    Ok(FilterConfig::for_sim(model, &cfg.sim))
}

/// The filter configuration (see the module doc for the precedence).
fn filter_config(args: &Args, flight: &FlightDir, model: ModelKind) -> Result<FilterConfig, CliError> {
    let base = flight_filter(&args.input, flight, model)?;
    let Some(path) = &args.filter_config else {
        return Ok(base);
    };
    let text = crate::io::read_text(path)?;
    let toml_err = |msg: String| CliError::Io(IoError::Toml { path: path.clone(), msg });
    let mut user: toml::Table = text.parse().map_err(|e: toml::de::Error| toml_err(e.to_string()))?;
    let mut merged = toml::Table::try_from(base).map_err(|e| toml_err(e.to_string()))?;
    user.remove("model"); // --model decides
    merge_over(&mut merged, user);
    let mut cfg: FilterConfig =
        merged.try_into().map_err(|e: toml::de::Error| toml_err(e.message().trim().to_owned()))?;
    cfg.model = model;
    cfg.check().map_err(|e| CliError::Config { path: path.clone(), msg: e.to_string() })?;
    Ok(cfg)
}
