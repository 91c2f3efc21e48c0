//! `quadformer residues`: flight directory or PX4 ULog → residue CSV (paper Alg. 1;
//! docs/data-format.md "Residue file" and "From a PX4 log").
//!
//! The EKF (`ekf_residue::residues::generate_residues`) runs on the streams of the flight.
//! Its noise model is built up in layers, each overriding the keys it sets:
//! 1. the simulator settings of the directory's `config.toml` when it was made by
//!    `quadformer simulate` (`FilterConfig::for_sim`, a consistent filter; a `config.toml`
//!    that does not parse is an error, not a silent fall-back), else the documented defaults
//!    (`FilterConfig::new`);
//! 2. the flight's own `filter.toml` (a ULog's: GPS σ from the receiver's eph/epv);
//! 3. the `--filter-config` file;
//! 4. with `--estimate-noise`, the measurement σ estimated from the first clean stretch
//!    (`ekf_residue::noise_check`).
//!
//! The filter used is written beside the output (`OUT.filter.toml`, every key), and a warning
//! is printed when a channel's NIS on the first clean stretch is far from what a consistent
//! filter gives. Labels come from `attack.csv` when present: a residue step is attacked when
//! the GPS fix at its time is (`eval::io::labels_at`).

use std::path::{Path, PathBuf};

use ekf_residue::noise_check::{NIS_FACTOR, estimate_measurement_noise, nis_check};
use ekf_residue::residues::{FilterConfig, ModelKind, generate_residues};
use uav_dynamics::TruthSample;

use crate::cli::CliError;
use crate::io::{
    ATTITUDE_FILE, CONFIG_FILE, CovarianceLayout, FILTER_FILE, FlightConfig, FlightDir, GPS_FILE, Input, IoError,
    Output, VO_FILE, check_outputs, commit_all, labels_at, merge_over, stage_bytes, stage_residues, stage_truth,
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
    /// Flight directory (imu.csv plus the streams the model needs: I: gps.csv and
    /// attitude.csv; II: vo.csv, with gps.csv and attitude.csv used when present; truth.csv,
    /// attack.csv and filter.toml are optional), or a PX4 ULog file (.ulg).
    #[arg(long = "in", value_name = "DIR|LOG.ulg")]
    pub input: PathBuf,
    /// Output residue CSV (written atomically); the filter used goes beside it, as
    /// FILE.filter.toml.
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
    /// Estimate the measurement σ from the flight's first clean stretch (covariance matching)
    /// and use them; the figures used are printed and written to FILE.filter.toml.
    #[arg(long)]
    pub estimate_noise: bool,
    /// How a recorded flight is read.
    #[command(flatten)]
    pub read: crate::cli::FlightReadArgs,
}

/// Where the filter record of a residue file goes: `FILE.csv` → `FILE.filter.toml`.
#[must_use]
pub fn filter_record_path(out: &Path) -> PathBuf {
    out.with_extension("filter.toml")
}

/// Runs `quadformer residues`.
///
/// # Errors
/// [`CliError`] naming the file, line and column of bad input, a stream the model needs that
/// is missing, or the filter time at which the EKF failed.
pub fn run(args: &Args) -> Result<(), CliError> {
    let record = filter_record_path(&args.out);
    let mut inputs = vec![Input::new("--in", &args.input)];
    inputs.extend(args.filter_config.as_deref().map(|p| Input::new("--filter-config", p)));
    let mut outputs = vec![Output::file("--out", &args.out), Output::file("the filter record", &record)];
    outputs.extend(args.estimates.as_deref().map(|p| Output::file("--estimates", p)));
    check_outputs(&inputs, &outputs)?;
    let flight = args.read.read(&args.input)?;
    let model = ModelKind::from(args.model);
    check_streams(&args.input, &flight, model)?;
    let (mut cfg, mut sources) = filter_config(args, &flight, model)?;
    // The attack labels decide the clean stretch whether or not they are written.
    let label_fn = |t: &[f64]| match &flight.attack {
        Some(attack) => labels_at(t, attack),
        None => vec![false; t.len()],
    };
    if args.estimate_noise {
        let est = estimate_measurement_noise(&flight.streams, &cfg, &label_fn)
            .map_err(|e| CliError::Filter { path: args.input.clone(), msg: format!("--estimate-noise: {e}") })?;
        eprintln!(
            "--estimate-noise: {} clean residue steps, t {:.2}–{:.2} s, {} rounds of covariance matching:",
            est.steps, est.t_span.0, est.t_span.1, est.rounds
        );
        for c in &est.sigmas {
            eprintln!("  {:<10} σ {:.6} → {:.6}", c.channel, c.before, c.after);
        }
        sources.push(format!(
            "measurement σ estimated from the clean residue steps at t {:.2}–{:.2} s (--estimate-noise)",
            est.t_span.0, est.t_span.1
        ));
        cfg = est.config;
    }
    let out = generate_residues(&flight.streams, &cfg)
        .map_err(|e| CliError::Filter { path: args.input.clone(), msg: e.to_string() })?;
    let attack_labels = flight.attack.as_ref().map(|a| labels_at(out.series.t(), a));
    let labels = attack_labels.as_deref().filter(|_| !args.no_labels);
    // The outputs are staged and committed together: a failure writing any leaves none.
    let mut staged = vec![stage_residues(&args.out, &out.series, labels, args.covariance.into())?];
    if let Some(path) = &args.estimates {
        let rows: Vec<TruthSample> = out
            .estimates
            .iter()
            .map(|e| TruthSample { t: e.t, p: e.p, q: e.q, v: e.v, b_g: e.b_g, b_a: e.b_a })
            .collect();
        staged.push(stage_truth(path, &rows)?);
    }
    let text =
        filter_record(&cfg, &sources).map_err(|msg| CliError::Io(IoError::Toml { path: record.clone(), msg }))?;
    staged.push(stage_bytes(&record, text.as_bytes())?);
    commit_all(staged)?;
    let n = out.series.len();
    #[allow(clippy::cast_precision_loss)] // step counts are far below 2^52
    let mean_nis = out.series.nis().iter().sum::<f64>() / n.max(1) as f64;
    let attacked =
        labels.map_or_else(|| "unlabelled".to_owned(), |l| format!("{} attacked", l.iter().filter(|&&x| x).count()));
    eprintln!(
        "wrote {}: {n} residue steps ({attacked}), channels {}, mean NIS {mean_nis:.3}; filter used: {}",
        args.out.display(),
        out.series.channels().join(" "),
        record.display()
    );
    warn_if_inconsistent(&args.input, &out.series, attack_labels.as_deref(), args.estimate_noise);
    Ok(())
}

/// Prints a warning when a channel's NIS on the first clean stretch says its σ is mis-set.
fn warn_if_inconsistent(input: &Path, series: &ekf_residue::ResidueSeries, labels: Option<&[bool]>, estimated: bool) {
    let Some(check) = nis_check(series, labels) else {
        eprintln!(
            "note: {}: the first clean stretch is too short to check the filter's noise settings",
            input.display()
        );
        return;
    };
    let far = check.far_channels();
    if far.is_empty() {
        return;
    }
    let list: Vec<String> = far.iter().map(|(c, r)| format!("{c} {r:.3}")).collect();
    eprintln!(
        "warning: {}: on the first clean stretch (t {:.2}–{:.2} s, {} steps) the mean of r²/S per channel should \
         be 1, but is {} (mean NIS {:.3} for {} channels): the filter's σ of {} look mis-set (off by more than \
         {NIS_FACTOR}× in variance). {}",
        input.display(),
        check.t_span.0,
        check.t_span.1,
        check.steps,
        list.join(", "),
        check.mean_nis,
        check.channels,
        if far.iter().all(|(_, r)| *r < 1.0) { "these channels (too large)" } else { "these channels" },
        if estimated {
            "The estimate did not settle them; check the stretch for manoeuvres the model misses."
        } else {
            "Re-run with --estimate-noise, or set them with --filter-config."
        }
    );
}

/// The filter record: where each layer came from, then every key of the filter used.
fn filter_record(cfg: &FilterConfig, sources: &[String]) -> Result<String, String> {
    let body = toml::to_string(cfg).map_err(|e| e.to_string())?;
    let mut text = String::from("# The filter `quadformer residues` ran with (pass it back with --filter-config).\n");
    for s in sources {
        text.push_str("# - ");
        text.push_str(&s.replace(['\n', '\r'], " "));
        text.push('\n');
    }
    text.push_str(&body);
    Ok(text)
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

/// The filter a flight asks for: the sensor σ of its `config.toml` (or the documented defaults
/// without one), with its `filter.toml` merged over them; and one line per layer saying where
/// it came from. A `config.toml` that does not parse is an error, since it would silently
/// change the noise model.
///
/// # Errors
/// [`CliError::Input`] naming `config.toml` and the field; [`CliError::Config`] for a bad
/// `filter.toml`.
pub(crate) fn flight_filter(
    dir: &Path,
    flight: &FlightDir,
    model: ModelKind,
) -> Result<(FilterConfig, Vec<String>), CliError> {
    let mut sources = Vec::new();
    let base = match &flight.config_toml {
        None => {
            sources.push("base: the documented default filter settings".to_owned());
            FilterConfig::new(model)
        }
        Some(text) => {
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
            sources.push(format!("base: the simulated sensors of {}", path.display()));
            FilterConfig::for_sim(model, &cfg.sim)
        }
    };
    let Some(text) = &flight.filter_toml else { return Ok((base, sources)) };
    let path = if dir.is_dir() { dir.join(FILTER_FILE) } else { dir.to_owned() };
    let cfg = merge_filter(base, text, &path, model)?;
    sources.push(format!("the flight's filter settings ({})", path.display()));
    for line in text.lines().filter(|l| l.starts_with("# ")) {
        sources.push(format!("  {}", &line[2..]));
    }
    Ok((cfg, sources))
}

/// `base` with the TOML `text` (FilterConfig keys; `model` ignored) merged over it.
fn merge_filter(base: FilterConfig, text: &str, path: &Path, model: ModelKind) -> Result<FilterConfig, CliError> {
    let toml_err = |msg: String| CliError::Io(IoError::Toml { path: path.to_owned(), msg });
    let mut user: toml::Table = text.parse().map_err(|e: toml::de::Error| toml_err(e.to_string()))?;
    let mut merged = toml::Table::try_from(base).map_err(|e| toml_err(e.to_string()))?;
    user.remove("model"); // --model decides
    merge_over(&mut merged, user);
    let mut cfg: FilterConfig =
        merged.try_into().map_err(|e: toml::de::Error| toml_err(e.message().trim().to_owned()))?;
    cfg.model = model;
    cfg.check().map_err(|e| CliError::Config { path: path.to_owned(), msg: e.to_string() })?;
    Ok(cfg)
}

/// The filter configuration and its provenance (see the module doc for the layers).
fn filter_config(args: &Args, flight: &FlightDir, model: ModelKind) -> Result<(FilterConfig, Vec<String>), CliError> {
    let (base, mut sources) = flight_filter(&args.input, flight, model)?;
    let Some(path) = &args.filter_config else {
        return Ok((base, sources));
    };
    let text = crate::io::read_text(path)?;
    let cfg = merge_filter(base, &text, path, model)?;
    sources.push(format!("--filter-config {}", path.display()));
    Ok((cfg, sources))
}
