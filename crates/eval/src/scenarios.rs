//! The paper's closed-loop flight scenarios (fig:simu1 eight, fig:simu2 UST, fig:simu3
//! formation, fig:real1 diagonal, fig:real2 square; alg:alg3) flown with detectors, and their
//! tables and top-view plots.
//!
//! [`fly_all`] flies every scenario in its three cases through
//! [`resilient_fusion::scenario::run_case`], the detected case once per [`FusionDetector`] and
//! decision latency. A detector is resilient-fusion's NIS gate or a batch detector run online:
//! loaded from a model directory, or fitted by [`fit_on_quick_cell`] on the quick dataset cell
//! `m2-gaussian-a2` restricted to the GPS channels (decision 090).
//!
//! One [`ScenarioRow`] per scenario × case × vehicle (× detector × decision latency), written as
//! CSV ([`write_csv`]) and as a Markdown table of the attacked vehicles with the tracking RMSE
//! relative to the no-attack case ([`markdown`]). Units: metres and seconds, positions in the
//! world ENU frame; the plots are top views (east x, north y).

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use attack_inject::AttackKind;
use ekf_residue::Detector;
use ekf_residue::detector::OnlineDetector;
use ekf_residue::residues::{GPS_CHANNELS, ModelKind};
use resilient_fusion::estimator::NisGate;
use resilient_fusion::scenario::{Case, CaseResult, Scenario, ScenarioConfig, run_case};
use uav_dynamics::noise::NoiseShape;

use crate::dataset::{DatasetConfig, load_or_build};
use crate::io::{IoError, write_text_atomic};
use crate::methods::{Method, MethodConfigs};
use crate::plot::{PlotError, TopView, top_view_plot};
use crate::runner::fit;

/// Errors of flying the scenarios.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    /// A flight failed.
    #[error("{scenario} {case}: {source}")]
    Flight {
        /// The scenario.
        scenario: &'static str,
        /// The case.
        case: &'static str,
        /// The fusion's error.
        source: resilient_fusion::FusionError,
    },
    /// A plot of a flight failed.
    #[error("{scenario} {case}: {source}")]
    Plot {
        /// The scenario.
        scenario: &'static str,
        /// The case.
        case: &'static str,
        /// The plot error.
        source: Box<PlotError>,
    },
    /// Building the quick cell or fitting the detector on it failed.
    #[error("dataset {cell}, GPS channels: {msg}")]
    Fit {
        /// The dataset cell.
        cell: String,
        /// What failed.
        msg: String,
    },
}

/// A detector ready for the scenarios: the NIS gate, or a fitted / loaded batch detector.
pub enum FusionDetector {
    /// resilient-fusion's χ²₃ NIS gate at the 0.999 quantile.
    Nis,
    /// A batch detector run online.
    Batch(Box<dyn Detector>),
}

impl std::fmt::Debug for FusionDetector {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Self::Nis => f.write_str("Nis"),
            Self::Batch(d) => write!(f, "Batch({})", d.name()),
        }
    }
}

impl FusionDetector {
    /// Channels the detector reads (the fusion's `detector_channels`).
    #[must_use]
    pub fn channels(&self) -> Vec<String> {
        match self {
            Self::Nis => GPS_CHANNELS.iter().map(|s| (*s).to_owned()).collect(),
            Self::Batch(d) => d.channels().to_vec(),
        }
    }

    /// The threshold its online detector alarms above: the NIS gate's χ²₃ quantile, or a
    /// fitted detector's streaming threshold.
    #[must_use]
    pub fn threshold(&self) -> f64 {
        match self {
            Self::Nis => NisGate::CHI2_3_999,
            Self::Batch(d) => d.streaming_threshold(),
        }
    }

    /// A fresh online detector for one flight.
    ///
    /// # Errors
    /// The gate's error when its threshold is invalid.
    pub fn online(&self) -> resilient_fusion::Result<Box<dyn OnlineDetector + '_>> {
        match self {
            Self::Nis => Ok(Box::new(NisGate::new(NisGate::CHI2_3_999)?)),
            Self::Batch(d) => Ok(d.online()),
        }
    }
}

/// Fits `method` (with the `--quick` configurations, seeded by `seed`) on the quick dataset
/// cell `m2-gaussian-a2` restricted to `gps_x gps_y gps_z`, its threshold chosen on the cell's
/// validation split; the dataset is cached under `cache`.
///
/// # Errors
/// [`ScenarioError::Fit`] naming the cell when the dataset or the fit fails.
pub fn fit_on_quick_cell(method: Method, seed: u64, cache: &Path) -> Result<Box<dyn Detector>, ScenarioError> {
    let cfg = DatasetConfig {
        seed,
        ..DatasetConfig::quick(ModelKind::ModelII, NoiseShape::Gaussian, AttackKind::Persistent)
    };
    let cell = cfg.cell_name();
    let err = |msg: String| ScenarioError::Fit { cell: cell.clone(), msg };
    let valid_cfg = cfg.check().map_err(|e| err(e.to_string()))?;
    let (data, outcome) = load_or_build(&valid_cfg, cache).map_err(|e| err(e.to_string()))?;
    eprintln!("dataset {cell}: {outcome:?}");
    let (train, valid) = (data.train().map_err(|e| err(e.to_string()))?, data.valid().map_err(|e| err(e.to_string()))?);
    let (train, valid) = (
        train.select_channels(&GPS_CHANNELS).map_err(|e| err(e.to_string()))?,
        valid.select_channels(&GPS_CHANNELS).map_err(|e| err(e.to_string()))?,
    );
    let fitted = fit(method, &MethodConfigs::quick().seeded(seed), &train, &valid).map_err(|e| err(e.to_string()))?;
    eprintln!(
        "fitted {} on {cell} (gps_x gps_y gps_z) in {:.1} s, streaming threshold {:.4}",
        method.name(),
        fitted.train_s,
        fitted.detector.streaming_threshold()
    );
    Ok(fitted.detector)
}

/// Flies `scenarios` with every `(label, detector)` at every latency; the no-attack and
/// undetected cases once per scenario. Plots go to `plot_dir`.
///
/// # Errors
/// [`ScenarioError`] naming the scenario and case when a flight or its plot fails.
pub fn fly_all(
    scenarios: &[Scenario],
    detectors: &[(&str, &FusionDetector)],
    latencies: &[f64],
    seed: u64,
    plot_dir: &Path,
) -> Result<Vec<ScenarioRow>, ScenarioError> {
    let mut all = Vec::new();
    for &sc in scenarios {
        let flight =
            |case: Case| move |source| ScenarioError::Flight { scenario: sc.name(), case: case.name(), source };
        let plot = |case: Case| {
            move |source| ScenarioError::Plot { scenario: sc.name(), case: case.name(), source: Box::new(source) }
        };
        let base = ScenarioConfig { seed, ..ScenarioConfig::default() };
        for case in [Case::NoAttack, Case::AttackUndetected] {
            let r = run_case(sc, case, &base, None).map_err(flight(case))?;
            all.extend(rows(&r, "none", base.resilient.latency_s));
            plot_case(plot_dir, &r, "none", base.resilient.latency_s).map_err(plot(case))?;
        }
        for &(label, det) in detectors {
            for &latency_s in latencies {
                let mut cfg = base.clone();
                cfg.resilient.latency_s = latency_s;
                cfg.resilient.detector_channels = det.channels();
                let case = Case::AttackDetected;
                let make = |_: usize| det.online();
                let r = run_case(sc, case, &cfg, Some(&make)).map_err(flight(case))?;
                eprintln!("{} {} ({label}, latency {latency_s} s) done", sc.name(), case.name());
                all.extend(rows(&r, label, latency_s));
                plot_case(plot_dir, &r, label, latency_s).map_err(plot(case))?;
            }
        }
    }
    Ok(all)
}

/// Writes `scenarios.csv` and `scenarios.md` (with `heading` above the table) into `out`.
///
/// # Errors
/// [`IoError`] naming the file.
pub fn write_tables(out: &Path, heading: &str, all: &[ScenarioRow]) -> Result<(), IoError> {
    write_csv(&out.join("scenarios.csv"), all)?;
    let md = format!(
        "{heading}\n\nAttacked vehicle of every case (all vehicles in scenarios.csv); \"× no attack\" is the \
         tracking RMSE over the no-attack case's. Plots: plots/.\n\n{}",
        markdown(all)
    );
    write_text_atomic(&out.join("scenarios.md"), &md)
}

/// One vehicle of one case of one scenario, with the detector and latency it ran with.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenarioRow {
    /// Scenario.
    pub scenario: Scenario,
    /// Case.
    pub case: Case,
    /// Detector label (`none` for the cases without detection).
    pub detector: String,
    /// Decision latency of the resilient estimator, s.
    pub latency_s: f64,
    /// Vehicle index (0-based).
    pub vehicle: usize,
    /// Whether this vehicle's GPS is spoofed in this case.
    pub attacked: bool,
    /// Metrics of the vehicle.
    pub metrics: resilient_fusion::scenario::FlightMetrics,
    /// Formation-shape RMSE and maximum, m (formation scenario only).
    pub formation: Option<resilient_fusion::scenario::FormationMetrics>,
}

/// The rows of one case result.
#[must_use]
pub fn rows(result: &CaseResult, detector: &str, latency_s: f64) -> Vec<ScenarioRow> {
    let detector = if result.case == Case::AttackDetected { detector } else { "none" };
    result
        .vehicles
        .iter()
        .enumerate()
        .map(|(i, v)| ScenarioRow {
            scenario: result.scenario,
            case: result.case,
            detector: detector.to_owned(),
            latency_s,
            vehicle: i,
            attacked: result.case != Case::NoAttack && i == result.attacked_vehicle,
            metrics: v.metrics,
            formation: result.formation,
        })
        .collect()
}

/// CSV header of [`write_csv`].
pub const CSV_HEADER: &str = "scenario,case,detector,latency_s,vehicle,attacked,tracking_rmse_m,tracking_max_m,\
estimate_rmse_m,time_under_attack_s,time_gps_excluded_s,excluded_outside_attack_s,detection_delay_s,\
exclusion_delay_s,formation_shape_rmse_m,formation_shape_max_m";

fn opt(x: Option<f64>) -> String {
    x.map_or_else(String::new, |x| format!("{x:.6}"))
}

/// The rows as CSV text ([`CSV_HEADER`]; empty fields for absent delays and formation errors).
#[must_use]
pub fn csv(rows: &[ScenarioRow]) -> String {
    let mut s = String::from(CSV_HEADER);
    s.push('\n');
    for r in rows {
        let m = &r.metrics;
        let _ = writeln!(
            s,
            "{},{},{},{},{},{},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6},{},{},{},{}",
            r.scenario.name(),
            r.case.name(),
            r.detector,
            r.latency_s,
            r.vehicle,
            u8::from(r.attacked),
            m.tracking_rmse_m,
            m.tracking_max_m,
            m.estimate_rmse_m,
            m.time_under_attack_s,
            m.time_gps_excluded_s,
            m.excluded_outside_attack_s,
            opt(m.detection_delay_s),
            opt(m.exclusion_delay_s),
            opt(r.formation.map(|f| f.shape_rmse_m)),
            opt(r.formation.map(|f| f.shape_max_m)),
        );
    }
    s
}

/// Writes [`csv()`] atomically to `path`.
///
/// # Errors
/// [`IoError`] naming the file.
pub fn write_csv(path: &Path, rows: &[ScenarioRow]) -> Result<(), IoError> {
    write_text_atomic(path, &csv(rows))
}

/// Tracking RMSE of the no-attack case of the same scenario and vehicle (the reference of the
/// ratio column), if present in `rows`.
fn no_attack_rmse(rows: &[ScenarioRow], row: &ScenarioRow) -> Option<f64> {
    rows.iter()
        .find(|r| r.scenario == row.scenario && r.case == Case::NoAttack && r.vehicle == row.vehicle)
        .map(|r| r.metrics.tracking_rmse_m)
}

/// Markdown table of the attacked vehicle of every case (all vehicles of the formation are in
/// the CSV): tracking RMSE and its ratio to the no-attack case, maximum deviation, estimate
/// RMSE, time under attack, time GPS excluded (and outside the attack), detection and exclusion
/// delays, formation-shape RMSE. The latency is shown for the detected case only (it does not
/// affect the others).
#[must_use]
pub fn markdown(rows: &[ScenarioRow]) -> String {
    let mut s = String::from(
        "| scenario | case | detector | latency s | RMSE m | × no attack | max dev m | est. RMSE m | attack s | \
         GPS excluded s | excl. outside s | det. delay s | excl. delay s | formation RMSE m |\n\
         |---|---|---|---|---|---|---|---|---|---|---|---|---|---|\n",
    );
    let f2 = |x: Option<f64>| x.map_or_else(|| "–".to_owned(), |x| format!("{x:.2}"));
    let mut attacked_idx: Vec<usize> = Vec::new();
    for (i, r) in rows.iter().enumerate() {
        // The attacked vehicle (in the no-attack case: the vehicle that is attacked in the others).
        let target = rows.iter().find(|o| o.scenario == r.scenario && o.attacked).map_or(0, |o| o.vehicle);
        if r.vehicle == target {
            attacked_idx.push(i);
        }
    }
    for &i in &attacked_idx {
        let r = &rows[i];
        let m = &r.metrics;
        let ratio = no_attack_rmse(rows, r).filter(|&b| b > 0.0).map(|b| m.tracking_rmse_m / b);
        let _ = writeln!(
            s,
            "| {} | {} | {} | {} | {:.2} | {} | {:.2} | {:.2} | {:.1} | {:.1} | {:.1} | {} | {} | {} |",
            r.scenario.name(),
            r.case.name(),
            r.detector,
            if r.case == Case::AttackDetected { r.latency_s.to_string() } else { "–".to_owned() },
            m.tracking_rmse_m,
            ratio.map_or_else(|| "–".to_owned(), |x| format!("{x:.1}")),
            m.tracking_max_m,
            m.estimate_rmse_m,
            m.time_under_attack_s,
            m.time_gps_excluded_s,
            m.excluded_outside_attack_s,
            f2(m.detection_delay_s),
            f2(m.exclusion_delay_s),
            f2(r.formation.map(|f| f.shape_rmse_m)),
        );
    }
    s
}

/// Top views of one case, one figure per vehicle: `<dir>/<scenario>-<case>[-<detector>]
/// [-uav<i>].{png,svg}` (the vehicle suffix only for multi-vehicle scenarios, the detector
/// suffix only in the detected case). The estimate is drawn thick red inside the attack window.
///
/// # Errors
/// [`PlotError`] when drawing or writing fails.
pub fn plot_case(dir: &Path, result: &CaseResult, detector: &str, latency_s: f64) -> Result<Vec<PathBuf>, PlotError> {
    let mut out = Vec::new();
    let multi = result.vehicles.len() > 1;
    for (i, v) in result.vehicles.iter().enumerate() {
        let tr = &v.trace;
        let xy = |p: &[nalgebra::Vector3<f64>]| p.iter().map(|p| (p.x, p.y)).collect::<Vec<_>>();
        let (reference, truth, estimate) = (xy(&tr.reference), xy(&tr.truth), xy(&tr.estimate));
        let attacked: Vec<bool> =
            tr.t.iter().map(|&t| tr.attack_interval.is_some_and(|(a0, a1)| t > a0 && t <= a1)).collect();
        let mut stem = format!("{}-{}", result.scenario.name(), result.case.name());
        let mut title = format!("{}: {}", result.scenario.name(), result.case.name().replace('_', " "));
        if result.case == Case::AttackDetected {
            let _ = write!(stem, "-{detector}-lat{latency_s}");
            let _ = write!(title, " ({detector}, latency {latency_s} s)");
        }
        if multi {
            let _ = write!(stem, "-uav{}", i + 1);
            let _ = write!(title, ", UAV {}", i + 1);
        }
        let view = TopView { reference: &reference, truth: &truth, estimate: &estimate, attacked: &attacked };
        out.extend(top_view_plot(&dir.join(stem), &title, view)?);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use resilient_fusion::scenario::FlightMetrics;

    use super::*;

    fn row(case: Case, rmse: f64, attacked: bool) -> ScenarioRow {
        ScenarioRow {
            scenario: Scenario::Square,
            case,
            detector: if case == Case::AttackDetected { "nis" } else { "none" }.to_owned(),
            latency_s: 1.0,
            vehicle: 0,
            attacked,
            metrics: FlightMetrics {
                tracking_rmse_m: rmse,
                tracking_max_m: 2.0 * rmse,
                estimate_rmse_m: rmse,
                time_under_attack_s: if attacked { 10.0 } else { 0.0 },
                time_gps_excluded_s: 0.0,
                excluded_outside_attack_s: 0.0,
                detection_delay_s: attacked.then_some(0.1),
                exclusion_delay_s: None,
            },
            formation: None,
        }
    }

    #[test]
    fn csv_has_one_field_per_header_column() {
        let rows = [row(Case::NoAttack, 0.5, false), row(Case::AttackDetected, 1.0, true)];
        let text = csv(&rows);
        let n = CSV_HEADER.split(',').count();
        assert_eq!(text.lines().count(), 3);
        for line in text.lines() {
            assert_eq!(line.split(',').count(), n, "{line}");
        }
        assert!(text.lines().nth(2).is_some_and(|l| l.starts_with("square,attack_detected,nis,1,0,1,1.000000")));
    }

    #[test]
    fn markdown_ratio_is_relative_to_no_attack() {
        let rows = [
            row(Case::NoAttack, 0.5, false),
            row(Case::AttackUndetected, 5.0, true),
            row(Case::AttackDetected, 1.0, true),
        ];
        let md = markdown(&rows);
        assert!(md.contains("| square | no_attack | none | – | 0.50 | 1.0 |"), "{md}");
        assert!(md.contains("| square | attack_undetected | none | – | 5.00 | 10.0 |"), "{md}");
        assert!(md.contains("| square | attack_detected | nis | 1 | 1.00 | 2.0 |"), "{md}");
    }
}
