//! `quadformer fuse`: flies the paper's closed-loop scenarios (fig:simu1–3, fig:real1–2) in the
//! three cases (no attack; GPS attack without detection; GPS attack with detection and the
//! resilient fusion of alg:alg3) and writes `scenarios.md`, `scenarios.csv` (one row per
//! scenario × case × vehicle, metres and seconds; [`crate::scenarios`]) and top-view plots
//! (`plots/*.png|svg`, world ENU east/north, attack window highlighted).
//!
//! With `--in DIR` it flies a user's flight folder instead, as the closed-loop experiment of
//! `reproduce-tables` flies its test flights ([`crate::closed_loop`]): the GPS fixes (with the
//! offsets of `attack.csv` re-applied online) go through the resilient estimator, the detector
//! sees every innovation, and `loop.csv` (one row per fix) and `loop.md` (the Table III
//! metrics) say what it did.
//!
//! Detectors (decision 090): `nis` is resilient-fusion's χ²₃ NIS gate on the GPS innovation
//! (no fitting); `chi2`, `cusum`, `glr` and `quadformer` are fitted by
//! [`crate::scenarios::fit_on_quick_cell`] or loaded from a model directory (`--model`, written
//! by `quadformer train`), whose training channels become the fusion's detector channels. Batch
//! detectors run through [`ekf_residue::Detector::online`]; resilient-fusion stays candle-free.
//! The flying itself is [`crate::scenarios::fly_all`]; this module maps flags to it.

use std::path::{Path, PathBuf};

use ekf_residue::residues::ModelKind;
use ekf_residue::{Confirmed, OnlineDetector, TrailingMean};
use resilient_fusion::estimator::ResilientConfig;
use resilient_fusion::recorded::fly_recorded;
use resilient_fusion::scenario::Scenario;

use crate::cli::CliError;
use crate::cli::residues::{ModelArg, flight_filter};
use crate::closed_loop::{flight_from_dir, loop_metrics};
use crate::io::{Input, Output, check_outputs, write_into_dir_atomic, write_text_atomic};
use crate::methods::Method;
use crate::model_dir;
use crate::scenarios::{FusionDetector, ScenarioRow, fit_on_quick_cell, fly_all, write_tables};

/// Scenario selection of `--scenario`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ScenarioArg {
    /// Eight-shape, two loops (paper Fig. 4).
    Eight,
    /// UST letters (paper Fig. 5).
    Ust,
    /// Four-UAV square formation, UAV 3 attacked (paper Fig. 6).
    Formation,
    /// Diagonal (paper Fig. 7).
    Diagonal,
    /// Square (paper Fig. 8).
    Square,
    /// All five.
    All,
}

impl ScenarioArg {
    /// The value as written on the command line.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::All => "all",
            Self::Eight => "eight",
            Self::Ust => "ust",
            Self::Formation => "formation",
            Self::Diagonal => "diagonal",
            Self::Square => "square",
        }
    }

    /// The scenarios selected.
    #[must_use]
    pub fn scenarios(self) -> Vec<Scenario> {
        match self {
            Self::Eight => vec![Scenario::Eight],
            Self::Ust => vec![Scenario::Ust],
            Self::Formation => vec![Scenario::Formation],
            Self::Diagonal => vec![Scenario::Diagonal],
            Self::Square => vec![Scenario::Square],
            Self::All => Scenario::ALL.to_vec(),
        }
    }
}

/// Detector selection of `--detector`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DetectorArg {
    /// χ²₃ NIS gate at the 0.999 quantile on the GPS innovation (no fitting).
    Nis,
    /// Chi-squared test on the NIS, fitted (or loaded with --model).
    Chi2,
    /// CUSUM on the NIS, fitted (or loaded with --model).
    Cusum,
    /// GLR drift test on the GPS innovation, fitted (or loaded with --model).
    Glr,
    /// QUADFormer, trained on the quick cell (or loaded with --model).
    Quadformer,
}

impl DetectorArg {
    /// Label used in tables and file names.
    #[must_use]
    pub fn label(self) -> &'static str {
        match self {
            Self::Nis => "nis",
            Self::Chi2 => "chi2",
            Self::Cusum => "cusum",
            Self::Glr => "glr",
            Self::Quadformer => "quadformer",
        }
    }

    fn method(self) -> Option<Method> {
        match self {
            Self::Nis => None,
            Self::Chi2 => Some(Method::Chi2),
            Self::Cusum => Some(Method::Cusum),
            Self::Glr => Some(Method::Glr),
            Self::Quadformer => Some(Method::QuadFormer),
        }
    }
}

/// Arguments of `quadformer fuse`.
#[derive(Debug, clap::Args)]
#[command(after_help = "Fitted detectors (chi2, cusum, glr, quadformer without --model) are fitted on the quick \
dataset cell m2-gaussian-a2 restricted to gps_x gps_y gps_z (cached under --cache); see \
docs/decisions/090-fuse-detectors.md and docs/scenarios.md.")]
pub struct Args {
    /// Which scenario to fly.
    #[arg(long, value_enum, required_unless_present = "input", conflicts_with = "input")]
    pub scenario: Option<ScenarioArg>,
    /// A flight folder to fly instead of a scenario (imu.csv and the streams the EKF needs;
    /// attack.csv gives the labels, truth.csv the position errors), or a PX4 ULog file.
    #[arg(long = "in", value_name = "DIR|LOG.ulg")]
    pub input: Option<PathBuf>,
    /// How a recorded flight is read.
    #[command(flatten)]
    pub read: crate::cli::FlightReadArgs,
    /// EKF of a flight folder: I (GPS + attitude) or II (VO + GPS).
    #[arg(long, value_enum, default_value = "II", requires = "input")]
    pub ekf: ModelArg,
    /// Detector of the detected case.
    #[arg(long, value_enum, default_value = "nis")]
    pub detector: DetectorArg,
    /// Model directory written by `quadformer train` (chi2, cusum, glr or quadformer; its method must
    /// match --detector).
    #[arg(long, value_name = "MODEL_DIR")]
    pub model: Option<PathBuf>,
    /// Decision latency of the detector, seconds (paper: about 1 s on the edge device).
    #[arg(long, default_value_t = 1.0)]
    pub latency_s: f64,
    /// With --in: NIS gate of the GPS innovation under which fixes that agree with the
    /// prediction end an exclusion although the detector alarms (`ResilientConfig::readmit_nis`;
    /// default the χ²₃ 0.99 quantile, as in Table III); 0 never re-admits so.
    #[arg(long, default_value_t = ResilientConfig::CHI2_3_99, requires = "input")]
    pub readmit_nis: f64,
    /// With --in: how far before an alarmed fix the estimator rewinds, seconds
    /// (`ResilientConfig::rollback_lookback_s`; Table III uses the detector's 90th-percentile
    /// validation detection delay).
    #[arg(long, default_value_t = 0.0, requires = "input")]
    pub lookback_s: f64,
    /// With --in: how far before an alarmed fix the estimator looks for the onset of a spoof it
    /// fused, seconds, and rewinds to it when that lies beyond --lookback-s
    /// (`ResilientConfig::rollback_onset_s`; Table III uses 5 s); 0 does not look.
    #[arg(long, default_value_t = 0.0, requires = "input")]
    pub onset_s: f64,
    /// With --in: longest exclusion, seconds, after which GPS is re-admitted with a position
    /// reset onto the fix (`ResilientConfig::reset_after_s`; Table III uses the longest
    /// validation attack plus 1 s, PX4 EKF2 7 s); 0 never resets.
    #[arg(long, default_value_t = 0.0, requires = "input")]
    pub reset_after_s: f64,
    /// With --in: window of unfused fixes, seconds, whose innovation trend gives the velocity a
    /// reset takes (`ResilientConfig::reset_velocity_window_s`); 0 forgets the velocity at a reset.
    #[arg(long, default_value_t = 2.0, requires = "input")]
    pub reset_velocity_window_s: f64,
    /// With --in: consecutive raw alarms before an alarm stands (`ekf_residue::Confirmed`;
    /// Table III chooses 1–3 per detector on validation flights); 1 alarms on every raw alarm.
    #[arg(long, default_value_t = 1, value_parser = clap::value_parser!(u64).range(1..), requires = "input")]
    pub confirm: u64,
    /// With --in: earlier scores the detector's score is averaged with before it is compared
    /// with its threshold (`ekf_residue::TrailingMean`; Table III can choose it per detector on
    /// validation flights, `loop_smooth`); 0 scores each fix alone.
    #[arg(long, default_value_t = 0, requires = "input")]
    pub smooth: u64,
    /// Seed of the sensor noise (vehicle i uses seed + i) and of the detector fit.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Dataset cache for fitted detectors (default OUT/datasets).
    #[arg(long, value_name = "DIR")]
    pub cache: Option<PathBuf>,
    /// Output directory.
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
}

/// Builds the detector of `which`: the NIS gate, a model directory, or a fit on the quick cell.
///
/// # Errors
/// [`CliError`] when the model directory is unreadable or of another method, or the dataset or
/// fit fails.
pub fn make_detector(
    which: DetectorArg,
    model: Option<&Path>,
    seed: u64,
    cache: &Path,
) -> Result<FusionDetector, CliError> {
    let Some(method) = which.method() else {
        if let Some(m) = model {
            return Err(CliError::Input { path: m.to_owned(), msg: "--model is not used by --detector nis".into() });
        }
        return Ok(FusionDetector::Nis);
    };
    if let Some(dir) = model {
        let manifest = model_dir::read_manifest(dir)?;
        if manifest.method != method {
            return Err(CliError::Input {
                path: dir.to_owned(),
                msg: format!("the model is {}, but --detector is {}", manifest.method.name(), which.label()),
            });
        }
        return Ok(FusionDetector::Batch(model_dir::load(dir, &manifest)?));
    }
    Ok(FusionDetector::Batch(fit_on_quick_cell(method, seed, cache)?))
}

/// Checks `--latency-s`.
fn check_latency(latency_s: f64) -> Result<(), CliError> {
    if latency_s.is_finite() && latency_s >= 0.0 {
        Ok(())
    } else {
        Err(CliError::Run(format!("--latency-s must be finite and non-negative, got {latency_s}")))
    }
}

/// Checks, before any work, the outputs of a scenario run into `out` (`scenarios.csv`,
/// `scenarios.md`, `plots/`) against `inputs` (model directory, dataset cache).
///
/// # Errors
/// [`CliError::Io`] when an output would touch an input or is not replaceable.
pub(crate) fn check_scenario_outputs(out: &Path, inputs: &[Input<'_>]) -> Result<(), CliError> {
    let (csv, md, plots) = (out.join("scenarios.csv"), out.join("scenarios.md"), out.join("plots"));
    check_outputs(inputs, &[Output::file("--out", &csv), Output::file("--out", &md), Output::dir("--out", &plots)])?;
    Ok(())
}

/// Flies `scenarios` as [`fly_all`] does, then adds the tables and plots to `out` only when
/// every flight succeeded (nothing is written on failure).
///
/// # Errors
/// As [`fly_all`] and [`write_tables`].
pub(crate) fn fly_and_write(
    out: &Path,
    heading: impl FnOnce() -> String,
    scenarios: &[Scenario],
    detectors: &[(&str, &FusionDetector)],
    latencies: &[f64],
    seed: u64,
) -> Result<Vec<ScenarioRow>, CliError> {
    let mut all = Vec::new();
    write_into_dir_atomic(out, |tmp| -> Result<(), CliError> {
        all = fly_all(scenarios, detectors, latencies, seed, &tmp.join("plots"))?;
        Ok(write_tables(tmp, &heading(), &all)?)
    })?;
    Ok(all)
}

/// Runs `quadformer fuse`.
///
/// # Errors
/// [`CliError`] for a bad latency, an unusable model directory, a failed fit or flight, or an
/// output that cannot be written.
pub fn run(args: &Args) -> Result<(), CliError> {
    check_latency(args.latency_s)?;
    if let (DetectorArg::Nis, Some(m)) = (args.detector, &args.model) {
        return Err(CliError::Input { path: m.clone(), msg: "--model is not used by --detector nis".into() });
    }
    let cache = args.cache.clone().unwrap_or_else(|| args.out.join("datasets"));
    let mut inputs = vec![Input::new("--cache", &cache)];
    inputs.extend(args.model.as_deref().map(|m| Input::new("--model", m)));
    if let Some(dir) = &args.input {
        inputs.push(Input::new("--in", dir));
        let (csv, md) = (args.out.join("loop.csv"), args.out.join("loop.md"));
        check_outputs(&inputs, &[Output::file("--out", &csv), Output::file("--out", &md)])?;
    } else {
        check_scenario_outputs(&args.out, &inputs)?;
    }
    let det = make_detector(args.detector, args.model.as_deref(), args.seed, &cache)?;
    let label = args.detector.label();
    let scenario = match (&args.input, args.scenario) {
        (Some(dir), _) => return fly_folder(args, dir, &det),
        (None, Some(s)) => s,
        (None, None) => return Err(CliError::Run("give --scenario or --in".into())),
    };
    let heading = || {
        format!(
            "# Flight scenarios: detector {label}, latency {} s, seed {}\n\nGenerated by `quadformer fuse --scenario \
         {} --detector {label} --latency-s {} --seed {}`.",
            args.latency_s,
            args.seed,
            scenario.name(),
            args.latency_s,
            args.seed
        )
    };
    let all = fly_and_write(&args.out, heading, &scenario.scenarios(), &[(label, &det)], &[args.latency_s], args.seed)?;
    eprintln!("wrote {} ({} rows)", args.out.join("scenarios.csv").display(), all.len());
    Ok(())
}

/// One fix of `loop.csv`.
#[derive(Debug, serde::Serialize)]
struct LoopRow {
    t: f64,
    attacked: u8,
    offset_m: f64,
    score: f64,
    alarm: u8,
    gps_excluded: u8,
    reset: u8,
    error_m: f64,
}

/// `fuse --in DIR`: fly a flight folder through the resilient estimator with the detector.
fn fly_folder(args: &Args, dir: &Path, det: &FusionDetector) -> Result<(), CliError> {
    let folder = args.read.read(dir)?;
    let model = ModelKind::from(args.ekf);
    let (filter, _) = flight_filter(dir, &folder, model)?;
    let (flight, attack) = flight_from_dir(&folder);
    let mut cfg = ResilientConfig {
        latency_s: args.latency_s,
        readmit_nis: (args.readmit_nis != 0.0).then_some(args.readmit_nis),
        rollback_lookback_s: args.lookback_s,
        rollback_onset_s: args.onset_s,
        reset_after_s: (args.reset_after_s != 0.0).then_some(args.reset_after_s),
        reset_velocity_window_s: args.reset_velocity_window_s,
        ..ResilientConfig::default()
    };
    cfg.detector_channels = det.channels();
    cfg.check().map_err(|e| {
        CliError::Run(format!(
            "--readmit-nis / --lookback-s / --onset-s / --reset-after-s / --reset-velocity-window-s: {e}"
        ))
    })?;
    let online = det.online().map_err(|e| CliError::Run(e.to_string()))?;
    let confirm = usize::try_from(args.confirm).unwrap_or(usize::MAX);
    let smooth = usize::try_from(args.smooth).unwrap_or(usize::MAX);
    let online = Box::new(TrailingMean::new(online, smooth, det.threshold()));
    let online: Box<dyn OnlineDetector + '_> = Box::new(Confirmed::new(online, confirm));
    let trace = fly_recorded(&flight, &attack, &filter, &cfg, Some(online))
        .map_err(|e| CliError::Filter { path: dir.to_owned(), msg: e.to_string() })?;
    let rows: Vec<LoopRow> = trace
        .steps
        .iter()
        .map(|s| LoopRow {
            t: s.t,
            attacked: u8::from(s.attacked),
            offset_m: s.offset_m,
            score: s.score,
            alarm: u8::from(s.alarm),
            gps_excluded: u8::from(s.gps_excluded),
            reset: u8::from(s.reset),
            error_m: s.error_m,
        })
        .collect();
    let csv = crate::table::to_csv(&rows).map_err(|e| CliError::Run(e.to_string()))?;
    let m = loop_metrics(&[trace.steps.as_slice()], true);
    let opt = |v: Option<f64>| v.map_or_else(|| "–".to_owned(), |v| format!("{v:.2}"));
    let md = format!(
        "# {} in the loop on {}\n\nGenerated by `quadformer fuse --in {} --ekf {} --detector {} --latency-s {} --readmit-nis {} \
         --lookback-s {} --onset-s {} --reset-after-s {} --reset-velocity-window-s {} --confirm {} --smooth {}`. Per fix: loop.csv. Errors are NaN without truth.csv; precision, recall and F1 need attack.csv.\n\n\
         | metric | value |\n|---|---|\n\
         | precision / recall / F1 | {:.3} / {:.3} / {:.3} |\n\
         | detection delay median / p90 (s) | {} / {} |\n\
         | alarm events per clean minute / of which raised on a clean fix | {:.2} / {:.2} |\n\
         | max / RMS position error on attacked fixes (m) | {:.2} / {:.2} |\n\
         | max position error within 30 s after an attack (m) | {:.2} |\n\
         | GPS excluded on clean fixes (s) | {:.1} |\n\
         | attack intervals / drifts caught before 3 m | {} / {} |\n",
        args.detector.label(),
        dir.display(),
        dir.display(),
        match args.ekf {
            ModelArg::One => "I",
            ModelArg::Two => "II",
        },
        args.detector.label(),
        args.latency_s,
        args.readmit_nis,
        args.lookback_s,
        args.onset_s,
        args.reset_after_s,
        args.reset_velocity_window_s,
        args.confirm,
        args.smooth,
        m.precision,
        m.recall,
        m.f1,
        opt(m.delay_median_s),
        opt(m.delay_p90_s),
        m.alarm_events_per_clean_min,
        m.alarms_raised_clean_per_min,
        m.max_error_attack_m,
        m.rmse_attack_m,
        m.max_error_after_m,
        m.gps_lost_clean_s,
        m.n_intervals,
        opt(m.alarmed_before_3m),
    );
    write_into_dir_atomic(&args.out, |tmp| -> Result<(), CliError> {
        write_text_atomic(&tmp.join("loop.csv"), &csv)?;
        write_text_atomic(&tmp.join("loop.md"), &md)?;
        Ok(())
    })?;
    eprintln!("wrote {} ({} fixes) and loop.md: F1 {:.3}", args.out.join("loop.csv").display(), rows.len(), m.f1);
    Ok(())
}
