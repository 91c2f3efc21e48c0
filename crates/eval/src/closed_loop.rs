//! The closed-loop detection experiment (Table III): every detector protects the estimate it
//! watches. Test flights are flown through the resilient estimator of alg:alg3
//! ([`resilient_fusion::recorded::fly_recorded`]); at every fix the GPS innovation against the
//! prior goes to the detector in streaming mode, an alarm excludes GPS, and clearing re-admits
//! it (hold, covariance inflation and rollback of decision 023). What is scored is the alarm of
//! every fix against its label, and the position error the protected estimate keeps.
//!
//! Protocol (docs/decisions/091-closed-loop.md):
//! - Units: one per (UAV model, noise shape, seed).
//! - Attack families ([`Family`]): `sparse` (Attack I bursts), `bias` (Attack II constant) and
//!   `ramp` (Attack II drift, 0.1–5 m/s) are trained on; `oscillating`, `replay` and `freeze`
//!   are held out, never trained on.
//! - Training and validation data: the trained families' flights flown with GPS excluded
//!   exactly on attacked fixes ([`ResidueProtocol::Protected`]), so residues and labels agree.
//! - Thresholds: each fitted detector first picks its streaming threshold on those validation
//!   residues (inside `fit`); the validation flights are then flown in the loop with the
//!   detector at that threshold and again at each threshold candidate drawn from the scores
//!   of that flight, and the candidate whose own alarms have the best F1 is the one the test
//!   flights use ([`loop_setting`]). In the loop the detector's own exclusions change the
//!   residues (after a false exclusion the estimate has drifted); the second pick sees that,
//!   the first cannot. The same flights choose how many consecutive raw alarms an alarm needs
//!   ([`LoopSetting::confirm`]; candidates 1 and 2 by default), and over how many of its
//!   newest scores the detector's score is averaged ([`LoopSetting::smooth`]; 0 and 2).
//!   `MatrixConfig::loop_f1_tolerance` may instead choose the quietest candidate within a
//!   tolerance of the best F1.
//! - Exclusions by a fitted detector last at most the longest validation attack plus 1 s
//!   ([`exclusion_bound_s`]); then GPS is re-admitted with a position reset, as EKF2 does.
//! - Detectors: the fitted QUADFormer, LSTM, CNN, CUSUM, SPRT and χ² test; the PX4 EKF2 gate
//!   (5σ per axis, reset onto GPS after 7 s of rejection); `None` (GPS always fused) and
//!   `Oracle` (exclusion exactly on attacked fixes). Fitted detectors fly at decision latency
//!   0 s and 1 s; the three reference rows have no decision latency and fly at 0 s.
//!
//! Finished units are cached as JSON under `OUT/runs/closed-loop/`, keyed by a hash of
//! everything that determines them, so an interrupted run resumes.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

use attack_inject::AttackedSample;
use attack_inject::{AttackConfig, AttackInterval, AttackKind};
use detection_metrics::{Confusion, FalseAlarmRate, best_f1_threshold};
use ekf_residue::residues::{FilterConfig, GPS_CHANNELS};
use ekf_residue::{Confirmed, Detector, LabelledResidues, OnlineDetector, TrailingMean};
use rayon::prelude::*;
use resilient_fusion::estimator::ResilientConfig;
use resilient_fusion::gates::{InnovationGate, Oracle};
use resilient_fusion::recorded::{GpsAttack, LoopStep, LoopTrace, fly_recorded};
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use uav_dynamics::sensors::{Flight, GpsSample};

use crate::cell::{AttackModel, Cell, NoiseModel, UavModel};
use crate::dataset::{DatasetConfig, PlannedFlight, ResidueProtocol, Split, SplitSteps, load_or_build, plan_split};
use crate::io::{AttackRecord, FlightDir, TIME_MATCH_TOL_S, write_text_atomic};
use crate::methods::{Method, MethodConfigs};
use crate::metrics::{MeanStd, detection_delays, false_alarms, quantile};
use crate::plot::{ErrorSeries, error_time_plot};
use crate::reproduce::{MatrixConfig, Options, ReproduceError, Result};
use crate::runner::{fit, read_json_cache, write_json_cache};
use crate::table::to_csv;

/// Bumped when the unit's computation changes, so cached units are recomputed.
const UNIT_VERSION: u32 = 9;

/// Seconds after an attack ends over which `max_error_after_m` is taken.
pub const AFTER_WINDOW_S: f64 = 30.0;

/// Spoofed offset a drift must be caught before, metres (`alarmed_before_3m`).
pub const DRIFT_CATCH_M: f64 = 3.0;

/// Decision latencies the fitted detectors fly at, seconds (paper: about 1 s on the edge device).
pub const LATENCIES_S: [f64; 2] = [0.0, 1.0];

/// The fitted detectors of the loop, in table order.
pub const FITTED: [Method; 7] =
    [Method::Cusum, Method::Sprt, Method::Chi2, Method::Glr, Method::Cnn, Method::Lstm, Method::QuadFormer];

/// An attack family of the closed-loop experiment: one column of Table III.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Family {
    /// Attack I: short bursts of a constant offset.
    Sparse,
    /// Attack II: long constant biases.
    Bias,
    /// Attack II drift: a ramp of 0.1–5 m/s from zero offset (PX4/PX4-Autopilot issue #27340
    /// reports 5 m/s).
    Ramp,
    /// Held out: `A·sin(2π f t)`, f in 0.1–0.3 Hz.
    Oscillating,
    /// Held out: fixes recorded 1–5 s earlier, re-sent.
    Replay,
    /// Held out: the last clean fix, repeated.
    Freeze,
}

impl Family {
    /// Every family, in column order.
    pub const ALL: [Self; 6] = [Self::Sparse, Self::Bias, Self::Ramp, Self::Oscillating, Self::Replay, Self::Freeze];

    /// The families the fitted detectors train on.
    pub const TRAINED: [Self; 3] = [Self::Sparse, Self::Bias, Self::Ramp];

    /// Column and file name.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Sparse => "sparse",
            Self::Bias => "bias",
            Self::Ramp => "ramp",
            Self::Oscillating => "oscillating",
            Self::Replay => "replay",
            Self::Freeze => "freeze",
        }
    }

    /// Whether the detectors train on this family.
    #[must_use]
    pub fn trained(self) -> bool {
        Self::TRAINED.contains(&self)
    }

    /// The attack configuration of the family (amplitude unit `gps_sigma_m`).
    #[must_use]
    pub fn attack(self, gps_sigma_m: f64) -> AttackConfig {
        let kind = match self {
            Self::Sparse => AttackKind::Sparse,
            Self::Bias | Self::Ramp => AttackKind::Persistent,
            Self::Oscillating => AttackKind::Oscillating,
            Self::Replay => AttackKind::Replay,
            Self::Freeze => AttackKind::Freeze,
        };
        let mut a = AttackConfig::new(kind);
        a.gps_sigma_m = gps_sigma_m;
        match self {
            Self::Bias => a.ramp_probability = 0.0,
            Self::Ramp => {
                a.ramp_probability = 1.0;
                a.ramp_slope_mps = Some([0.1, 5.0]);
            }
            _ => {}
        }
        a
    }

    fn index(self) -> u64 {
        Self::ALL.iter().position(|f| *f == self).unwrap_or(0) as u64
    }
}

/// A detector of the loop: a fitted method or one of the three reference rows.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LoopMethod {
    /// A method fitted on the protected residues.
    Fitted(Method),
    /// PX4 EKF2's 5σ GNSS gate with its 7 s reset onto GPS.
    Px4Ekf2,
    /// No detector: GPS always fused.
    None,
    /// Exclusion exactly on attacked fixes.
    Oracle,
}

impl LoopMethod {
    /// Table name.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Fitted(m) => m.name(),
            Self::Px4Ekf2 => "PX4 EKF2",
            Self::None => "None",
            Self::Oracle => "Oracle",
        }
    }

    /// Every method in table order: the floor, the gates, the fitted ones, the ceiling.
    fn all() -> Vec<Self> {
        let mut v = vec![Self::None, Self::Px4Ekf2];
        v.extend(FITTED.iter().map(|&m| Self::Fitted(m)));
        v.push(Self::Oracle);
        v
    }
}

/// One row of `closed_loop.csv`: a detector on one family's test flights of one unit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClosedLoopRow {
    /// UAV model.
    pub model: UavModel,
    /// Noise shape.
    pub noise: NoiseModel,
    /// Attack family ([`Family::name`]).
    pub family: String,
    /// Whether the detectors trained on this family.
    pub trained: bool,
    /// Detector ([`LoopMethod::name`]).
    pub method: String,
    /// Decision latency, seconds.
    pub latency_s: f64,
    /// Seed.
    pub seed: u64,
    /// Alarm threshold of the detector's streaming score in the loop (none for the reference
    /// rows, which have their own decision rules).
    pub threshold: Option<f64>,
    /// Rollback look-back of the fitted detectors in the loop, seconds ([`LoopSetting`]).
    pub lookback_s: Option<f64>,
    /// Exclusion bound of the fitted detectors in the loop, seconds ([`exclusion_bound_s`]).
    pub reset_after_s: Option<f64>,
    /// Consecutive raw alarms an alarm of the fitted detectors needs in the loop
    /// ([`LoopSetting::confirm`]).
    pub confirm: Option<u64>,
    /// Earlier scores the fitted detectors' loop score averages with the newest
    /// ([`LoopSetting::smooth`]).
    pub smooth: Option<u64>,
    /// Per-fix F1 of that setting on the trained families' validation flights flown in the
    /// loop, where it was chosen ([`loop_setting`]).
    pub valid_f1: Option<f64>,
    /// Per-fix precision of the alarms.
    pub precision: f64,
    /// Per-fix recall.
    pub recall: f64,
    /// Per-fix F1.
    pub f1: f64,
    /// Median onset → first alarm over detected attack intervals, seconds, at residue time
    /// (the exclusion follows `latency_s` later).
    pub delay_median_s: Option<f64>,
    /// 90th percentile of the same.
    pub delay_p90_s: Option<f64>,
    /// Alarm events (maximal runs of alarmed clean fixes) per minute of clean flight.
    pub alarm_events_per_clean_min: f64,
    /// Of those, the events raised on a clean fix, per minute of clean flight: every event but
    /// an alarm that outlasts the attack it was raised on
    /// ([`detection_metrics::FalseAlarmRate::n_raised_clean`]).
    pub alarms_raised_clean_per_min: f64,
    /// Largest `‖p̂ − p‖` on attacked fixes, metres.
    pub max_error_attack_m: f64,
    /// RMS of `‖p̂ − p‖` on attacked fixes, metres.
    pub rmse_attack_m: f64,
    /// Largest `‖p̂ − p‖` on clean fixes within 30 s after an attack ends, metres.
    pub max_error_after_m: f64,
    /// Clean flight time with GPS excluded, seconds (all test flights of the family).
    pub gps_lost_clean_s: f64,
    /// Ramps only: share of the intervals whose spoofed offset passed 3 m that alarmed before
    /// (the alarm on the residue; at latency 1 s GPS is excluded 1 s later).
    pub alarmed_before_3m: Option<f64>,
    /// Attack intervals on the test flights.
    pub n_intervals: u64,
    /// Clean flight time of the test flights, minutes.
    pub clean_min: f64,
}

/// A (model, noise, seed) unit of the experiment.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct LoopUnit {
    /// UAV model.
    pub model: UavModel,
    /// Noise shape.
    pub noise: NoiseModel,
    /// Seed.
    pub seed: u64,
}

impl LoopUnit {
    fn slug(self) -> String {
        format!("{}-{}-s{}", self.model.slug(), self.noise.name(), self.seed)
    }
}

/// Position error over time of every detector on one drift flight (the figure).
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
pub struct DriftTrace {
    /// Attack intervals `(t0, t1]` of the flight, seconds.
    pub attacks: Vec<(f64, f64)>,
    /// `(detector, [(t, error m)])` at latency 0.
    pub errors: Vec<(String, Vec<(f64, f64)>)>,
}

/// The cached outcome of one unit.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct UnitRecord {
    key: String,
    rows: Vec<ClosedLoopRow>,
    drift: DriftTrace,
}

/// The dataset configuration of `family` in `unit`: the cell's simulator and filter, the
/// family's attacks, protected residues, a third of the matrix's steps per split (the three
/// trained families together match one cell) but at least one whole flight, so a persistent
/// attack fits, and a seed of its own per family.
#[must_use]
pub fn family_dataset(unit: LoopUnit, family: Family, opts: &Options) -> DatasetConfig {
    let cell = Cell { model: unit.model, noise: unit.noise, attack: AttackModel::I };
    let base = crate::reproduce::dataset_config(cell, unit.seed, &opts.config, opts.quick);
    let s = base.steps;
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let flight = (base.flight_duration_s * f64::from(base.sim.gps_rate_hz)).floor() as usize;
    let third = |n: usize| (n / 3).max(flight).max(1);
    DatasetConfig {
        attack: family.attack(base.sim.gps_sigma_m[0]),
        steps: SplitSteps { train: third(s.train), valid: third(s.valid), test: third(s.test) },
        protocol: ResidueProtocol::Protected,
        seed: 1000 + 16 * unit.seed + family.index(),
        ..base
    }
}

/// The units of the options: the distinct (model, noise) pairs of `opts.cells`, every seed.
#[must_use]
pub fn units(opts: &Options) -> Vec<LoopUnit> {
    let mut pairs: Vec<(UavModel, NoiseModel)> = opts.cells.iter().map(|c| (c.model, c.noise)).collect();
    pairs.sort();
    pairs.dedup();
    (0..opts.seeds).flat_map(|seed| pairs.iter().map(move |&(model, noise)| LoopUnit { model, noise, seed })).collect()
}

fn dataset_err(unit: LoopUnit, family: Family) -> impl Fn(crate::dataset::DatasetError) -> ReproduceError {
    move |source| ReproduceError::Dataset { cell: format!("closed loop {} {}", unit.slug(), family.name()), source }
}

/// The method configurations of a unit's fits: the matrix's, seeded, with QUADFormer's
/// attention causal when `MatrixConfig::loop_causal` says so and the networks' features those
/// of `MatrixConfig::loop_features`.
fn loop_method_configs(opts: &Options, seed: u64) -> MethodConfigs {
    let mut cfgs = opts.config.methods.seeded(seed);
    cfgs.quadformer.net.causal = opts.config.loop_causal;
    let features = opts.config.loop_features;
    cfgs.quadformer.window.features = features.quadformer;
    cfgs.cnn.0.window.features = features.cnn;
    cfgs.lstm.0.window.features = features.lstm;
    cfgs
}

/// Merge the flights of several splits of one channel set.
fn merge(splits: Vec<LabelledResidues>) -> Result<LabelledResidues> {
    let flights = splits.into_iter().flat_map(|s| s.flights().to_vec()).collect();
    LabelledResidues::new(flights).map_err(|e| ReproduceError::Config(format!("closed-loop training data: {e}")))
}

/// Where a computed unit's time went, seconds of wall time.
#[derive(Debug, Clone, Copy, Default)]
struct UnitTimes {
    /// Building or loading the trained families' datasets and planning their validation flights.
    data_s: f64,
    /// Fitting the detectors on the protected training residues.
    fit_s: f64,
    /// Flying the validation flights to choose each fitted detector's loop setting.
    setting_s: f64,
    /// Flying the test flights with every detector.
    test_s: f64,
}

impl std::fmt::Display for UnitTimes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "datasets {:.0} s, fits {:.0} s, loop settings on validation flights {:.0} s, test flights {:.0} s",
            self.data_s, self.fit_s, self.setting_s, self.test_s
        )
    }
}

/// Runs one unit (or loads it from the cache), with where its time went when it was computed.
///
/// # Errors
/// Any stage's error, naming the unit.
fn run_unit(unit: LoopUnit, opts: &Options, methods: &[LoopMethod]) -> Result<(UnitRecord, Option<UnitTimes>)> {
    let test_cfgs: Vec<_> = Family::ALL
        .iter()
        .map(|&f| family_dataset(unit, f, opts).check().map_err(dataset_err(unit, f)).map(|c| (f, c)))
        .collect::<Result<_>>()?;
    let trained_cfgs: Vec<_> = test_cfgs.iter().filter(|(f, _)| f.trained()).collect();
    let key = unit_key(unit, opts, methods, &test_cfgs)?;
    let path = opts.out.join("runs").join("closed-loop").join(format!("{}.json", unit.slug()));
    if let Some(rec) = read_json_cache::<UnitRecord>(&path)
        && rec.key == key
    {
        return Ok((rec, None));
    }

    // Training and validation data: the trained families' protected flights.
    let t0 = Instant::now();
    let (mut train, mut valid) = (Vec::new(), Vec::new());
    for &(f, cfg) in &trained_cfgs {
        let f = *f;
        let (data, _) = load_or_build(cfg, &opts.out.join("datasets")).map_err(dataset_err(unit, f))?;
        train.push(data.train().map_err(dataset_err(unit, f))?);
        valid.push(data.valid().map_err(dataset_err(unit, f))?);
    }
    let (train, valid) = (merge(train)?, merge(valid)?);
    let cfgs = loop_method_configs(opts, unit.seed);
    // Every family of a unit shares the cell's simulator and filter.
    let Some((_, first)) = test_cfgs.first() else {
        return Err(ReproduceError::Config("closed loop: no attack family".into()));
    };
    let filter = first.get().filter;
    let valid_flights: Vec<PlannedFlight> = trained_cfgs
        .iter()
        .map(|&(f, c)| plan_split(c, Split::Valid).map_err(dataset_err(unit, *f)))
        .collect::<Result<Vec<_>>>()?
        .into_iter()
        .flatten()
        .collect();
    let mut fitted: Vec<(Method, Box<dyn Detector>, Flown)> = Vec::new();
    let mut times = UnitTimes { data_s: t0.elapsed().as_secs_f64(), ..UnitTimes::default() };
    for m in methods {
        if let LoopMethod::Fitted(method) = *m {
            let t0 = Instant::now();
            let det = fit(method, &cfgs, &train, &valid)?.detector;
            times.fit_s += t0.elapsed().as_secs_f64();
            let t0 = Instant::now();
            let candidates = LoopCandidates {
                confirm: &opts.config.loop_confirm,
                smooth: &opts.config.loop_smooth,
                f1_tolerance: opts.config.loop_f1_tolerance,
            };
            let chosen = loop_setting(det.as_ref(), &valid_flights, &filter, candidates)
                .map_err(|e| ReproduceError::Config(format!("closed loop {}: {e}", unit.slug())))?;
            times.setting_s += t0.elapsed().as_secs_f64();
            fitted.push((method, det, chosen));
        }
    }

    let t0 = Instant::now();
    let mut rows = Vec::new();
    let mut drift = DriftTrace::default();
    for (family, cfg) in &test_cfgs {
        let flights = plan_split(cfg, Split::Test).map_err(dataset_err(unit, *family))?;
        for &method in methods {
            let latencies: &[f64] = if matches!(method, LoopMethod::Fitted(_)) { &LATENCIES_S } else { &[0.0] };
            for &latency_s in latencies {
                let (pilot, chosen) = match method {
                    LoopMethod::Fitted(m) => match fitted.iter().find(|(f, _, _)| *f == m) {
                        Some((_, d, chosen)) => (Pilot::Fitted(d.as_ref(), chosen.setting), Some(*chosen)),
                        None => return Err(ReproduceError::Config(format!("{} was not fitted", m.name()))),
                    },
                    LoopMethod::Px4Ekf2 => (Pilot::Px4Ekf2, None),
                    LoopMethod::None => (Pilot::None, None),
                    LoopMethod::Oracle => (Pilot::Oracle, None),
                };
                let traces = fly_family(&flights, &filter, pilot, latency_s).map_err(|e| {
                    ReproduceError::Config(format!("closed loop {} {}: {e}", unit.slug(), family.name()))
                })?;
                if *family == Family::Ramp && latency_s == 0.0 && unit.seed == 0 {
                    record_drift(&mut drift, &flights, &traces, method.name());
                }
                let steps: Vec<&[LoopStep]> = traces.iter().map(|t| t.steps.as_slice()).collect();
                rows.push(row(unit, *family, method.name(), latency_s, chosen, &steps));
            }
        }
    }
    times.test_s = t0.elapsed().as_secs_f64();
    let rec = UnitRecord { key, rows, drift };
    write_json_cache(&path, &rec)?;
    Ok((rec, Some(times)))
}

/// Quantiles of the clean validation scores flown at the fitted threshold that are candidates
/// of the loop threshold, with the fitted threshold and the F1-best threshold of those scores.
pub const LOOP_THRESHOLD_QUANTILES: [f64; 6] = [0.9, 0.95, 0.98, 0.99, 0.995, 0.999];

/// Longest rollback look-back, seconds.
pub const MAX_LOOKBACK_S: f64 = 5.0;

/// Margin over the longest validation attack before an exclusion counts as stuck, seconds.
pub const EXCLUSION_MARGIN_S: f64 = 1.0;

/// The exclusion bound of the fitted detectors ([`LoopSetting::reset_after_s`]): the longest
/// attack interval among the validation flights plus [`EXCLUSION_MARGIN_S`]. An alarm held
/// longer than any attack the detector was validated on is taken to be stuck, and GPS is
/// re-admitted with a position reset, as PX4 EKF2 does after 7 s of rejected fusion
/// (`reset_timeout_max` in `EKF/common.h`). Without a bound, one false alarm that the
/// detector keeps raising on the drift it causes leaves the estimate dead-reckoning for the
/// rest of the flight. `None` when no validation flight is attacked.
pub fn exclusion_bound_s(valid: &[PlannedFlight]) -> Option<f64> {
    valid
        .iter()
        .flat_map(|f| f.plan.intervals().iter().map(AttackInterval::duration_s))
        .reduce(f64::max)
        .map(|d| d + EXCLUSION_MARGIN_S)
}

/// How a fitted detector flies in the loop, chosen on validation flights ([`loop_setting`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct LoopSetting {
    /// Alarm threshold of its streaming score.
    pub threshold: f64,
    /// How far before an alarmed fix the estimator rewinds
    /// ([`ResilientConfig::rollback_lookback_s`]), seconds.
    pub lookback_s: f64,
    /// Exclusion time after which GPS is re-admitted with a position reset
    /// ([`ResilientConfig::reset_after_s`]), seconds: [`exclusion_bound_s`].
    pub reset_after_s: Option<f64>,
    /// Consecutive raw alarms (score above `threshold`) before the alarm stands
    /// ([`ekf_residue::Confirmed`]); 1 alarms on every raw alarm.
    pub confirm: usize,
    /// Earlier steps whose scores the loop score averages with the newest one's
    /// ([`ekf_residue::TrailingMean`]); 0 is the detector's streaming score.
    #[serde(default)]
    pub smooth: usize,
}

/// The candidates [`loop_setting`] flies besides the thresholds, and how it chooses.
#[derive(Debug, Clone, Copy)]
pub struct LoopCandidates<'a> {
    /// Of [`LoopSetting::confirm`] (`MatrixConfig::loop_confirm`).
    pub confirm: &'a [usize],
    /// Of [`LoopSetting::smooth`] (`MatrixConfig::loop_smooth`).
    pub smooth: &'a [usize],
    /// How far below the best validation F1 a candidate may fall and still be chosen for
    /// raising fewer alarm events per clean minute (`MatrixConfig::loop_f1_tolerance`);
    /// `None` chooses the best F1.
    pub f1_tolerance: Option<f64>,
}

/// One candidate setting flown on the validation flights.
#[derive(Debug, Clone, Copy)]
pub struct Flown {
    /// The setting.
    pub setting: LoopSetting,
    /// Index of its (confirm, smooth) pair in `confirm` × `smooth`, smoothing varying fastest.
    pub pair: usize,
    /// Per-fix F1 of its alarms on the validation flights.
    pub f1: f64,
    /// Alarm events per clean minute of those flights.
    pub alarm_events_per_clean_min: f64,
}

/// Step 4 of [`loop_setting`]: the chosen candidate.
fn choose(flown: &[Flown], f1_tolerance: Option<f64>) -> Option<Flown> {
    // Higher F1, then the earlier pair, then the higher threshold.
    let by_f1 = |a: &Flown, b: &Flown| {
        a.f1.total_cmp(&b.f1).then(b.pair.cmp(&a.pair)).then(a.setting.threshold.total_cmp(&b.setting.threshold))
    };
    let best = flown.iter().max_by(|a, b| by_f1(a, b))?;
    let Some(tol) = f1_tolerance else { return Some(*best) };
    flown
        .iter()
        .filter(|c| c.f1 >= best.f1 - tol)
        .max_by(|a, b| b.alarm_events_per_clean_min.total_cmp(&a.alarm_events_per_clean_min).then(by_f1(a, b)))
        .copied()
}

/// The loop setting of a fitted detector (module doc), from the trained families' validation
/// flights alone, flown at latency 0:
///
/// 1. Fly them with the detector at its streaming threshold. The look-back is the 90th
///    percentile of its detection delays there (at most [`MAX_LOOKBACK_S`]), so an alarm
///    also undoes the spoofed fixes fused before it in nine attacks out of ten.
/// 2. Candidates: that threshold, the F1-maximising threshold of the scores it gave there and
///    [`LOOP_THRESHOLD_QUANTILES`] of its scores on clean fixes.
/// 3. Fly them again at each candidate with that look-back. A candidate stops flying as soon
///    as its F1 could no longer be chosen even if every attacked fix of the flights left
///    alarmed and no clean one did. Leaving it out changes no choice; the candidates are
///    flown best-first by the F1 their thresholds give the scores of step 1, and each one's
///    flights with the most attacked fixes first, so that the bound tightens early.
/// 4. Steps 1–3 are taken for each pair of candidates of the score's trailing mean
///    ([`LoopSetting::smooth`]; `MatrixConfig::loop_smooth`) and of the confirmation (an
///    alarm stands after that many consecutive raw alarms, [`LoopSetting::confirm`];
///    `MatrixConfig::loop_confirm`). Of every candidate flown, the one whose own alarms have
///    the highest per-fix F1 wins (ties: the earlier pair, smoothing varying fastest, then
///    the higher threshold). With an F1 tolerance (`MatrixConfig::loop_f1_tolerance`), the
///    candidate with the fewest alarm events per clean minute among those within it of the
///    best F1 wins instead (ties as before).
///
/// Every flight, from step 1 on, bounds an exclusion by [`exclusion_bound_s`].
///
/// Each candidate is judged by the flight it produces, so a threshold whose false alarm starts
/// a drift the detector then keeps alarming on (lock-out) loses to one that does not.
///
/// # Errors
/// A flight's error (of step 1, or of a candidate still in reach), no attacked fix among
/// the validation flights, a `confirm` candidate of 0, an F1 tolerance that is not a finite
/// non-negative number, or no candidate.
pub fn loop_setting(
    det: &dyn Detector,
    valid: &[PlannedFlight],
    filter: &FilterConfig,
    candidates: LoopCandidates<'_>,
) -> std::result::Result<Flown, String> {
    if let Some(tol) = candidates.f1_tolerance.filter(|t| !(t.is_finite() && *t >= 0.0)) {
        return Err(format!("loop_f1_tolerance: must be finite and at least 0, got {tol}"));
    }
    let pairs: Vec<(usize, usize)> =
        candidates.confirm.iter().flat_map(|&c| candidates.smooth.iter().map(move |&w| (c, w))).collect();
    if pairs.iter().any(|&(confirm, _)| confirm == 0) {
        return Err("loop_confirm: a confirmation needs at least 1 raw alarm, got 0".into());
    }
    let planned: Vec<(Vec<Planned>, Vec<u64>)> = pairs
        .par_iter()
        .enumerate()
        .map(|(pair, &(confirm, smooth))| plan_candidates(det, valid, filter, confirm, smooth, pair))
        .collect::<std::result::Result<_, String>>()?;
    // Which fixes are attacked depends on the flight alone, not on the pilot: every pair's
    // step 1 counts the same.
    let attacked = planned.first().map(|(_, a)| a.clone()).unwrap_or_default();
    let mut order: Vec<Planned> = planned.into_iter().flat_map(|(p, _)| p).collect();
    // The likeliest winners first (ties as `choose` breaks them), so that the others fall out
    // of reach sooner; `par_bridge` hands them to the threads in this order.
    order.sort_by(|a, b| {
        (b.step1_f1.total_cmp(&a.step1_f1))
            .then(a.pair.cmp(&b.pair))
            .then(b.setting.threshold.total_cmp(&a.setting.threshold))
    });
    let best = BestSoFar::new(candidates.f1_tolerance);
    let flown: Vec<Option<Flown>> = order
        .into_iter()
        .par_bridge()
        .map(|p| {
            let m = fly_within_reach(valid, filter, Pilot::Fitted(det, p.setting), &attacked, &best)?;
            Ok(m.map(|m| {
                best.record(m.f1);
                Flown {
                    setting: p.setting,
                    pair: p.pair,
                    f1: m.f1,
                    alarm_events_per_clean_min: m.alarm_events_per_clean_min,
                }
            }))
        })
        .collect::<std::result::Result<_, String>>()?;
    let flown: Vec<Flown> = flown.into_iter().flatten().collect();
    choose(&flown, candidates.f1_tolerance).ok_or_else(|| "loop_confirm, loop_smooth: no candidate".to_owned())
}

/// A threshold candidate of [`loop_setting`], before it is flown.
struct Planned {
    setting: LoopSetting,
    /// Index of its (confirm, smooth) pair.
    pair: usize,
    /// The F1 of its threshold on the scores of step 1, which ranks the candidates.
    step1_f1: f64,
}

/// Steps 1 and 2 of [`loop_setting`] for one pair: alarms confirmed over `confirm` steps,
/// scores averaged over `smooth` earlier ones, every threshold candidate tagged with `pair`,
/// the index of the pair; and the number of attacked fixes of each validation flight, in the
/// order of `valid`.
fn plan_candidates(
    det: &dyn Detector,
    valid: &[PlannedFlight],
    filter: &FilterConfig,
    confirm: usize,
    smooth: usize,
    pair: usize,
) -> std::result::Result<(Vec<Planned>, Vec<u64>), String> {
    let reset_after_s = exclusion_bound_s(valid);
    let fitted = LoopSetting { threshold: det.streaming_threshold(), lookback_s: 0.0, reset_after_s, confirm, smooth };
    let traces = fly_family(valid, filter, Pilot::Fitted(det, fitted), 0.0)?;
    let steps: Vec<&[LoopStep]> = traces.iter().map(|t| t.steps.as_slice()).collect();
    let lookback_s = loop_metrics(&steps, false).delay_p90_s.unwrap_or(0.0).clamp(0.0, MAX_LOOKBACK_S);
    let scored: Vec<(Vec<f64>, Vec<bool>)> = traces
        .iter()
        .map(|tr| (tr.steps.iter().map(|s| s.score).collect(), tr.steps.iter().map(|s| s.attacked).collect()))
        .collect();
    let (one_step, _) = best_f1_threshold(scored.iter().map(|(s, l)| (s.as_slice(), l.as_slice())))
        .map_err(|e| format!("{} loop threshold: {e}", det.name()))?;
    let clean: Vec<f64> =
        traces.iter().flat_map(|tr| tr.steps.iter().filter(|s| !s.attacked).map(|s| s.score)).collect();
    let mut thresholds = vec![fitted.threshold, one_step];
    thresholds.extend(LOOP_THRESHOLD_QUANTILES.iter().filter_map(|&q| quantile(&clean, q)));
    thresholds.retain(|t| t.is_finite());
    thresholds.sort_by(f64::total_cmp);
    thresholds.dedup();
    if thresholds.is_empty() {
        return Err(format!("{} loop threshold: no candidate", det.name()));
    }
    let attacked: Vec<u64> = scored.iter().map(|(_, l)| l.iter().map(|&a| u64::from(a)).sum()).collect();
    let step1_f1 = |t: f64| {
        let mut conf = Confusion::default();
        for (s, l) in &scored {
            conf.add(Confusion::count(&s.iter().map(|&x| x > t).collect::<Vec<_>>(), l));
        }
        conf.f1()
    };
    let planned = thresholds
        .into_iter()
        .map(|threshold| Planned {
            setting: LoopSetting { threshold, lookback_s, reset_after_s, confirm, smooth },
            pair,
            step1_f1: step1_f1(threshold),
        })
        .collect();
    Ok((planned, attacked))
}

/// The best validation F1 flown so far for one detector, shared by the candidates
/// [`loop_setting`] flies in parallel, and the F1 tolerance of its choice.
struct BestSoFar {
    /// `f64` bits of the best F1; F1 is never negative, and the bits of non-negative floats
    /// order as the floats do.
    f1_bits: AtomicU64,
    tolerance: f64,
}

impl BestSoFar {
    fn new(f1_tolerance: Option<f64>) -> Self {
        Self { f1_bits: AtomicU64::new(0.0_f64.to_bits()), tolerance: f1_tolerance.unwrap_or(0.0) }
    }

    /// Records the F1 of a candidate flown to the end. `Relaxed` suffices: a thread that reads
    /// an older best only stops a candidate later.
    fn record(&self, f1: f64) {
        self.f1_bits.fetch_max(f1.to_bits(), Ordering::Relaxed);
    }

    /// Whether a candidate whose F1 can reach at most `f1_bound` can no longer be chosen: the
    /// choice takes the best F1, or one within the tolerance of it ([`choose`]).
    fn out_of_reach(&self, f1_bound: f64) -> bool {
        f1_bound < f64::from_bits(self.f1_bits.load(Ordering::Relaxed)) - self.tolerance
    }
}

/// The metrics of `flights` flown with `pilot`, or `None` as soon as the F1 of its alarms can
/// no longer be chosen ([`BestSoFar::out_of_reach`] of [`f1_bound`]). `attacked` holds the
/// attacked fixes of each flight; the flights with the most fly first, so that the bound
/// tightens early (the metrics used here are sums over flights, whatever their order).
///
/// # Errors
/// A flight's error, or a flight whose attacked fixes are not `attacked` (the bound would not
/// hold).
fn fly_within_reach(
    flights: &[PlannedFlight],
    filter: &FilterConfig,
    pilot: Pilot<'_>,
    attacked: &[u64],
    best: &BestSoFar,
) -> std::result::Result<Option<LoopMetrics>, String> {
    if attacked.len() != flights.len() {
        return Err(format!("{}: attacked fixes of {} flights for {}", pilot.name(), attacked.len(), flights.len()));
    }
    let mut order: Vec<usize> = (0..flights.len()).collect();
    order.sort_by_key(|&i| std::cmp::Reverse(attacked[i]));
    let mut still_to_fly: u64 = attacked.iter().sum();
    let mut conf = Confusion::default();
    let mut flown: Vec<Vec<LoopStep>> = Vec::with_capacity(flights.len());
    for i in order {
        let steps = fly(&flights[i], filter, pilot, 0.0)?.steps;
        let alarms: Vec<bool> = steps.iter().map(|s| s.alarm).collect();
        let labels: Vec<bool> = steps.iter().map(|s| s.attacked).collect();
        let c = Confusion::count(&alarms, &labels);
        if c.tp + c.fn_ != attacked[i] {
            return Err(format!(
                "{} flight {}: {} attacked fixes, {} when the candidates were planned",
                pilot.name(),
                flights[i].index,
                c.tp + c.fn_,
                attacked[i]
            ));
        }
        conf.add(c);
        flown.push(steps);
        still_to_fly -= attacked[i];
        if best.out_of_reach(f1_bound(conf, still_to_fly)) {
            return Ok(None);
        }
    }
    let steps: Vec<&[LoopStep]> = flown.iter().map(Vec::as_slice).collect();
    Ok(Some(loop_metrics(&steps, false)))
}

/// The highest per-fix F1 alarms can still reach after the flights counted in `so_far`, with
/// `still_to_fly` attacked fixes left: every one of them alarms and no clean fix does.
fn f1_bound(so_far: Confusion, still_to_fly: u64) -> f64 {
    Confusion { tp: so_far.tp + still_to_fly, ..so_far }.f1()
}

/// What decides the exclusions of a flight.
#[derive(Clone, Copy)]
enum Pilot<'d> {
    /// A fitted detector at its loop setting.
    Fitted(&'d dyn Detector, LoopSetting),
    /// PX4 EKF2's gate.
    Px4Ekf2,
    /// No detector.
    None,
    /// The oracle.
    Oracle,
}

impl Pilot<'_> {
    fn name(&self) -> &str {
        match self {
            Self::Fitted(d, _) => d.name(),
            Self::Px4Ekf2 => LoopMethod::Px4Ekf2.name(),
            Self::None => LoopMethod::None.name(),
            Self::Oracle => LoopMethod::Oracle.name(),
        }
    }
}

/// Fly every flight of a family with one pilot.
fn fly_family(
    flights: &[PlannedFlight],
    filter: &FilterConfig,
    pilot: Pilot<'_>,
    latency_s: f64,
) -> std::result::Result<Vec<LoopTrace>, String> {
    flights.iter().map(|f| fly(f, filter, pilot, latency_s)).collect()
}

/// Fly one flight with one pilot.
fn fly(
    f: &PlannedFlight,
    filter: &FilterConfig,
    pilot: Pilot<'_>,
    latency_s: f64,
) -> std::result::Result<LoopTrace, String> {
    let mut cfg = ResilientConfig { latency_s, ..ResilientConfig::default() };
    let online: Option<Box<dyn OnlineDetector + '_>> = match pilot {
        Pilot::Fitted(d, setting) => {
            cfg.detector_channels = d.channels().to_vec();
            cfg.readmit_nis = Some(ResilientConfig::CHI2_3_99);
            cfg.rollback_lookback_s = setting.lookback_s;
            cfg.rollback_onset_s = MAX_LOOKBACK_S;
            cfg.reset_after_s = setting.reset_after_s;
            let scored = TrailingMean::new(d.online_at(setting.threshold), setting.smooth, setting.threshold);
            Some(Box::new(Confirmed::new(Box::new(scored), setting.confirm)))
        }
        Pilot::Px4Ekf2 => {
            cfg.hold_s = 0.0;
            cfg.reset_after_s = Some(7.0);
            cfg.detector_channels = GPS_CHANNELS.iter().map(|c| (*c).to_owned()).collect();
            Some(Box::new(InnovationGate::new(InnovationGate::PX4_GAMMA).map_err(|e| e.to_string())?))
        }
        Pilot::None => None,
        Pilot::Oracle => {
            cfg.hold_s = 0.0;
            Some(Box::new(Oracle::new(f.plan.clone())))
        }
    };
    fly_recorded(&f.flight, &f.plan, filter, &cfg, online)
        .map_err(|e| format!("{} flight {}: {e}", pilot.name(), f.index))
}

/// Keep the position error of the ramp test flight with the most attacked fixes.
fn record_drift(drift: &mut DriftTrace, flights: &[PlannedFlight], traces: &[LoopTrace], name: &str) {
    let Some((i, tr)) = traces.iter().enumerate().max_by_key(|(_, tr)| tr.steps.iter().filter(|s| s.attacked).count())
    else {
        return;
    };
    if drift.attacks.is_empty() {
        drift.attacks = flights[i].plan.intervals().iter().map(|iv| (iv.t0, iv.t1)).collect();
    }
    drift.errors.push((name.to_owned(), tr.steps.iter().map(|s| (s.t, s.error_m)).collect()));
}

/// What a detector did in the loop over a set of flights (the metric columns of
/// [`ClosedLoopRow`]).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct LoopMetrics {
    /// Per-fix precision of the alarms.
    pub precision: f64,
    /// Per-fix recall.
    pub recall: f64,
    /// Per-fix F1.
    pub f1: f64,
    /// Median onset → first alarm over detected attack intervals, seconds.
    pub delay_median_s: Option<f64>,
    /// 90th percentile of the same.
    pub delay_p90_s: Option<f64>,
    /// Alarm events per minute of clean flight.
    pub alarm_events_per_clean_min: f64,
    /// Of those, the events raised on a clean fix (not an alarm outlasting its attack).
    pub alarms_raised_clean_per_min: f64,
    /// Largest `‖p̂ − p‖` on attacked fixes, metres.
    pub max_error_attack_m: f64,
    /// RMS of `‖p̂ − p‖` on attacked fixes, metres.
    pub rmse_attack_m: f64,
    /// Largest `‖p̂ − p‖` on clean fixes within 30 s after an attack ends, metres.
    pub max_error_after_m: f64,
    /// Clean flight time with GPS excluded, seconds.
    pub gps_lost_clean_s: f64,
    /// Share of the attack intervals whose offset passed 3 m that alarmed before (drifts).
    pub alarmed_before_3m: Option<f64>,
    /// Attack intervals.
    pub n_intervals: u64,
    /// Clean flight time, minutes.
    pub clean_min: f64,
}

/// The metrics of one detector on one family's flights.
fn row(
    unit: LoopUnit,
    family: Family,
    method: &str,
    latency_s: f64,
    chosen: Option<Flown>,
    flights: &[&[LoopStep]],
) -> ClosedLoopRow {
    let setting = chosen.map(|c| c.setting);
    let m = loop_metrics(flights, family == Family::Ramp);
    ClosedLoopRow {
        model: unit.model,
        noise: unit.noise,
        family: family.name().to_owned(),
        trained: family.trained(),
        method: method.to_owned(),
        latency_s,
        seed: unit.seed,
        threshold: setting.map(|s| s.threshold),
        lookback_s: setting.map(|s| s.lookback_s),
        reset_after_s: setting.and_then(|s| s.reset_after_s),
        confirm: setting.map(|s| s.confirm as u64),
        smooth: setting.map(|s| s.smooth as u64),
        valid_f1: chosen.map(|c| c.f1),
        precision: m.precision,
        recall: m.recall,
        f1: m.f1,
        delay_median_s: m.delay_median_s,
        delay_p90_s: m.delay_p90_s,
        alarm_events_per_clean_min: m.alarm_events_per_clean_min,
        alarms_raised_clean_per_min: m.alarms_raised_clean_per_min,
        max_error_attack_m: m.max_error_attack_m,
        rmse_attack_m: m.rmse_attack_m,
        max_error_after_m: m.max_error_after_m,
        gps_lost_clean_s: m.gps_lost_clean_s,
        alarmed_before_3m: m.alarmed_before_3m,
        n_intervals: m.n_intervals,
        clean_min: m.clean_min,
    }
}

/// The metrics of the steps of `flights` (one slice per flight); `drift` computes
/// `alarmed_before_3m` over the attack intervals whose offset passes 3 m. Errors are NaN for
/// flights without ground truth.
#[must_use]
pub fn loop_metrics(flights: &[&[LoopStep]], drift: bool) -> LoopMetrics {
    let mut conf = Confusion::default();
    let mut delays = Vec::new();
    let (mut n_intervals, mut fa) = (0u64, FalseAlarmRate::default());
    let (mut max_att, mut sum_sq_att, mut n_att, mut max_after, mut lost) = (0.0_f64, 0.0, 0usize, 0.0_f64, 0.0);
    let (mut drifts, mut caught) = (0usize, 0usize);
    for &steps in flights {
        let t: Vec<f64> = steps.iter().map(|s| s.t).collect();
        let alarms: Vec<bool> = steps.iter().map(|s| s.alarm).collect();
        let labels: Vec<bool> = steps.iter().map(|s| s.attacked).collect();
        conf.add(Confusion::count(&alarms, &labels));
        if let Ok(d) = detection_delays(&t, &alarms, &labels) {
            delays.extend(d.delays_s);
            n_intervals += d.n_intervals as u64;
        }
        if let Ok(f) = false_alarms(&t, &alarms, &labels) {
            fa.n_events += f.n_events;
            fa.n_raised_clean += f.n_raised_clean;
            fa.clean_time_s += f.clean_time_s;
        }
        let dt = match t.as_slice() {
            [a, b, ..] => b - a,
            _ => 0.0,
        };
        let mut last_end = f64::NEG_INFINITY;
        for (k, s) in steps.iter().enumerate() {
            if s.attacked {
                max_att = max_att.max(s.error_m);
                sum_sq_att += s.error_m * s.error_m;
                n_att += 1;
            } else {
                if k > 0 && steps[k - 1].attacked {
                    last_end = s.t;
                }
                if s.t - last_end <= AFTER_WINDOW_S {
                    max_after = max_after.max(s.error_m);
                }
                if s.gps_excluded {
                    lost += dt;
                }
            }
        }
        if drift {
            for iv in crate::metrics::attack_intervals(&labels) {
                let run = &steps[iv.start..iv.end];
                // Only intervals that start below 3 m can be caught before it (drifts; a bias
                // or burst is past 3 m at its first fix).
                if let Some(k3) = run.iter().position(|s| s.offset_m >= DRIFT_CATCH_M)
                    && k3 > 0
                {
                    drifts += 1;
                    caught += usize::from(run[..k3].iter().any(|s| s.alarm));
                }
            }
        }
    }
    #[allow(clippy::cast_precision_loss)]
    let rmse = if n_att > 0 { (sum_sq_att / n_att as f64).sqrt() } else { 0.0 };
    #[allow(clippy::cast_precision_loss)]
    let alarmed_before_3m = (drift && drifts > 0).then(|| caught as f64 / drifts as f64);
    if flights.iter().any(|f| f.iter().any(|s| s.error_m.is_nan())) {
        (max_att, max_after) = (f64::NAN, f64::NAN);
    }
    let rmse = if max_att.is_nan() { f64::NAN } else { rmse };
    LoopMetrics {
        precision: conf.precision(),
        recall: conf.recall(),
        f1: conf.f1(),
        delay_median_s: quantile(&delays, 0.5),
        delay_p90_s: quantile(&delays, 0.9),
        alarm_events_per_clean_min: fa.per_minute(),
        alarms_raised_clean_per_min: fa.raised_clean_per_minute(),
        max_error_attack_m: max_att,
        rmse_attack_m: rmse,
        max_error_after_m: max_after,
        gps_lost_clean_s: lost,
        alarmed_before_3m,
        n_intervals,
        clean_min: fa.clean_time_s / 60.0,
    }
}

/// The attack recorded with a flight folder (`attack.csv`): the fix at `t` was sent as the
/// clean fix plus `d`, so a folder's received GPS minus `d` is its clean GPS.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordedAttack {
    records: Vec<AttackRecord>,
}

impl GpsAttack for RecordedAttack {
    fn apply(&self, clean: &GpsSample, _history: &[GpsSample]) -> AttackedSample {
        let i = self.records.partition_point(|r| r.t < clean.t - TIME_MATCH_TOL_S);
        match self.records.get(i) {
            Some(r) if r.label && (r.t - clean.t).abs() <= TIME_MATCH_TOL_S => {
                AttackedSample { gps: GpsSample { t: clean.t, p: clean.p + r.d }, offset: r.d, attacked: true }
            }
            _ => AttackedSample { gps: *clean, offset: nalgebra::Vector3::zeros(), attacked: false },
        }
    }
}

/// A user's flight folder as the loop flies it: the clean flight (received GPS minus the
/// recorded offsets; the truth if the folder has one) and the recorded attack (none without
/// `attack.csv`, so every fix is clean).
#[must_use]
pub fn flight_from_dir(dir: &FlightDir) -> (Flight, RecordedAttack) {
    let records = dir.attack.clone().unwrap_or_default();
    let mut streams = dir.streams.clone();
    for g in &mut streams.gps {
        let i = records.partition_point(|r| r.t < g.t - TIME_MATCH_TOL_S);
        if let Some(r) = records.get(i)
            && r.label
            && (r.t - g.t).abs() <= TIME_MATCH_TOL_S
        {
            g.p -= r.d;
        }
    }
    (Flight { streams, truth: dir.truth.clone().unwrap_or_default() }, RecordedAttack { records })
}

/// Hash of everything that determines a unit.
fn unit_key(
    unit: LoopUnit,
    opts: &Options,
    methods: &[LoopMethod],
    cfgs: &[(Family, crate::dataset::ValidDatasetConfig)],
) -> Result<String> {
    let mut h = Sha256::new();
    h.update(format!("quadformer-rs closed loop v{UNIT_VERSION} {}\n", env!("CARGO_PKG_VERSION")).as_bytes());
    let (confirm, smooth) = (&opts.config.loop_confirm, &opts.config.loop_smooth);
    h.update(format!("{unit:?} {methods:?} {LATENCIES_S:?} {confirm:?} {smooth:?}\n").as_bytes());
    if let Some(tol) = opts.config.loop_f1_tolerance {
        // + 0.0 makes a tolerance of -0.0 the key of 0.0.
        h.update(format!("f1 tolerance {:?}\n", tol + 0.0).as_bytes());
    }
    for (f, c) in cfgs {
        let key = c.get().cache_key().map_err(dataset_err(unit, *f))?;
        h.update(key.as_bytes());
    }
    let m = serde_json::to_string(&loop_method_configs(opts, unit.seed))
        .map_err(|e| ReproduceError::Config(format!("closed-loop key: {e}")))?;
    h.update(m.as_bytes());
    Ok(crate::dataset::hex(&h.finalize()))
}

/// Runs the experiment for the options' units and writes `closed_loop.csv`, `table3.md`,
/// `table3.tex` and the drift figure; returns the rows and the files written.
///
/// # Errors
/// Any unit's error; [`ReproduceError::Io`] and plot errors for the outputs.
pub fn closed_loop(opts: &Options) -> Result<(Vec<ClosedLoopRow>, Vec<PathBuf>)> {
    let methods: Vec<LoopMethod> = LoopMethod::all()
        .into_iter()
        .filter(|m| match m {
            LoopMethod::Fitted(f) => opts.methods.contains(f),
            _ => true,
        })
        .collect();
    let units = units(opts);
    let progress = crate::progress::Progress::new(units.len() as u64, opts.progress, "closed-loop units");
    let records = units
        .par_iter()
        .map(|&u| {
            let t0 = Instant::now();
            progress.set_message(format!("closed loop {}", u.slug()));
            let r = run_unit(u, opts, &methods);
            let how = match &r {
                Ok((_, Some(times))) => format!("done in {:.0} s: {times}", t0.elapsed().as_secs_f64()),
                Ok((_, None)) => "read from the cache".to_owned(),
                Err(_) => format!("failed after {:.0} s", t0.elapsed().as_secs_f64()),
            };
            progress.finish_unit(&format!("closed loop {} {how}", u.slug()));
            r.map(|(rec, _)| rec)
        })
        .collect::<Result<Vec<_>>>()?;
    progress.finish();
    let mut rows: Vec<ClosedLoopRow> = records.iter().flat_map(|r| r.rows.iter().cloned()).collect();
    let rank = |r: &ClosedLoopRow| {
        (
            r.model,
            r.noise,
            Family::ALL.iter().position(|f| f.name() == r.family),
            methods.iter().position(|m| m.name() == r.method),
            r.latency_s.to_bits(),
            r.seed,
        )
    };
    rows.sort_by_key(rank);
    let mut files = Vec::new();
    let csv = to_csv(&rows)?;
    let p = opts.out.join("closed_loop.csv");
    write_text_atomic(&p, &csv)?;
    files.push(p);
    let md = table3_markdown(&rows, &methods, &opts.config);
    for (name, text) in [("table3.md", md), ("table3.tex", table3_latex(&rows, &methods))] {
        let p = opts.out.join(name);
        write_text_atomic(&p, &text)?;
        files.push(p);
    }
    // The figure shows Model II when it ran (its estimate survives GPS exclusion on VO), else
    // the first unit with a drift flight; seed 0 either way.
    let drawn = units
        .iter()
        .zip(&records)
        .filter(|(_, r)| !r.drift.errors.is_empty())
        .max_by_key(|(u, _)| (u.model == UavModel::II, std::cmp::Reverse(**u)));
    if let Some((u, rec)) = drawn {
        let series: Vec<ErrorSeries<'_>> =
            rec.drift.errors.iter().map(|(l, p)| ErrorSeries { label: l, points: p }).collect();
        let title = format!(
            "Position error on a drift flight ({}, {} noise, seed 0, latency 0)",
            model_name(u.model),
            u.noise.name()
        );
        let stem = opts.out.join("figures").join("closed-loop-drift");
        files.extend(error_time_plot(&stem, &title, &series, &rec.drift.attacks, 30.0)?);
    }
    Ok((rows, files))
}

fn model_name(m: UavModel) -> &'static str {
    match m {
        UavModel::I => "Model I",
        UavModel::II => "Model II",
    }
}

/// Mean ± std over seeds of `value` for the rows of one (model, noise, family, method,
/// latency) group; `None` when the group is empty or no row has the value.
fn group_stat(
    rows: &[ClosedLoopRow],
    key: (UavModel, NoiseModel, &str, &str, f64),
    value: impl Fn(&ClosedLoopRow) -> Option<f64>,
) -> Option<MeanStd> {
    let (model, noise, family, method, latency) = key;
    let vals: Vec<f64> = rows
        .iter()
        .filter(|r| {
            r.model == model && r.noise == noise && r.family == family && r.method == method && r.latency_s == latency
        })
        .filter_map(&value)
        .collect();
    MeanStd::new("closed loop", &vals).ok()
}

/// Distinct (model, noise) pairs of the rows, in order.
fn pairs(rows: &[ClosedLoopRow]) -> Vec<(UavModel, NoiseModel)> {
    let mut v: Vec<(UavModel, NoiseModel)> = rows.iter().map(|r| (r.model, r.noise)).collect();
    v.dedup();
    v
}

/// The latency a method's rows carry at the table's `latency`.
fn latency_of(method: LoopMethod, latency: f64) -> f64 {
    if matches!(method, LoopMethod::Fitted(_)) { latency } else { 0.0 }
}

fn fmt_ms(m: Option<MeanStd>, digits: usize) -> String {
    match m {
        Some(m) => match m.std {
            Some(sd) => format!("{:.digits$} ± {sd:.digits$}", m.mean),
            None => format!("{:.digits$}", m.mean),
        },
        None => "–".to_owned(),
    }
}

/// Table III in Markdown: per (model, noise) and latency, F1 and the maximum position error
/// during attacks of every detector on every family, then how the fitted detectors' loop
/// settings were chosen under `cfg` ([`choice_rule_markdown`]).
#[must_use]
pub fn table3_markdown(rows: &[ClosedLoopRow], methods: &[LoopMethod], cfg: &MatrixConfig) -> String {
    let mut s = String::new();
    let seeds = {
        let mut v: Vec<u64> = rows.iter().map(|r| r.seed).collect();
        v.sort_unstable();
        v.dedup();
        v.len()
    };
    let _ = writeln!(s, "# Table III: detectors in the loop\n");
    let _ = writeln!(
        s,
        "Every test flight flown through the resilient estimator (Alg. 3): an alarm excludes GPS, clearing re-admits \
         it. Per-fix F1 of the alarms and the largest position error ‖p̂ − p‖ on attacked fixes, mean ± std over {seeds} \
         seed(s). Families marked † were never trained on. PX4 EKF2, None and Oracle have no decision latency. \
         All columns: closed_loop.csv.\n"
    );
    for (model, noise) in pairs(rows) {
        for &latency in &LATENCIES_S {
            let _ = writeln!(s, "## {}, {} noise, decision latency {latency} s\n", model_name(model), noise.name());
            let _ = write!(s, "| detector |");
            for f in Family::ALL {
                let mark = if f.trained() { "" } else { " †" };
                let _ = write!(s, " {}{mark} F1 | max err (m) |", f.name());
            }
            let _ = writeln!(
                s,
                " ramp caught < 3 m | alarm events / clean min (all families) | of which raised on a clean fix |"
            );
            let _ = writeln!(s, "|---|{}---|---|---|", "---|---|".repeat(Family::ALL.len()));
            for &m in methods {
                let lat = latency_of(m, latency);
                let _ = write!(s, "| {} |", m.name());
                for f in Family::ALL {
                    let key = (model, noise, f.name(), m.name(), lat);
                    let f1 = group_stat(rows, key, |r| Some(r.f1));
                    let err = group_stat(rows, key, |r| Some(r.max_error_attack_m));
                    let _ = write!(s, " {} | {} |", fmt_ms(f1, 2), fmt_ms(err, 1));
                }
                let caught = group_stat(rows, (model, noise, "ramp", m.name(), lat), |r| r.alarmed_before_3m);
                let over_families = |stat: fn(&ClosedLoopRow) -> f64| {
                    let vals: Vec<f64> = rows
                        .iter()
                        .filter(|r| r.model == model && r.noise == noise && r.method == m.name() && r.latency_s == lat)
                        .map(stat)
                        .collect();
                    MeanStd::new("alarms", &vals).ok()
                };
                let fa = over_families(|r| r.alarm_events_per_clean_min);
                let raised = over_families(|r| r.alarms_raised_clean_per_min);
                let _ = writeln!(s, " {} | {} | {} |", fmt_ms(caught, 2), fmt_ms(fa, 2), fmt_ms(raised, 2));
            }
            let _ = writeln!(s);
        }
    }
    s.push_str(&choice_rule_markdown(rows, cfg));
    s
}

/// Units per (confirmation, smoothing) pair of a detector's loop settings.
type PairCounts = BTreeMap<(u64, u64), usize>;

/// The section of `table3.md` that says how each fitted detector's loop setting was chosen:
/// the candidates and rule of `cfg` ([`loop_setting`]), whether QUADFormer attends causally
/// (when it flew), and per detector how many units chose each (confirmation, smoothing) pair.
/// Empty when no fitted detector flew.
#[must_use]
pub fn choice_rule_markdown(rows: &[ClosedLoopRow], cfg: &MatrixConfig) -> String {
    // Per fitted detector, units per (confirmation, smoothing): one row per unit, since the
    // setting is the unit's, the same for every family and latency.
    let chosen: Vec<(Method, PairCounts)> = FITTED
        .iter()
        .map(|&m| {
            let counts = rows
                .iter()
                .filter(|r| r.method == m.name() && r.latency_s == 0.0 && r.family == Family::Sparse.name())
                .filter_map(|r| r.confirm.zip(r.smooth))
                .fold(BTreeMap::new(), |mut acc, pair| {
                    *acc.entry(pair).or_insert(0) += 1;
                    acc
                });
            (m, counts)
        })
        .filter(|(_, counts)| !counts.is_empty())
        .collect();
    if chosen.is_empty() {
        return String::new();
    }
    let rule = match cfg.loop_f1_tolerance {
        Some(tol) => {
            format!("the quietest candidate (fewest alarm events per clean minute) within {tol} of the best F1")
        }
        None => "the candidate with the best F1".to_owned(),
    };
    let attention = if !chosen.iter().any(|(m, _)| *m == Method::QuadFormer) {
        ""
    } else if cfg.loop_causal {
        " QUADFormer attends causally (decision 092)."
    } else {
        " QUADFormer attends over the whole window."
    };
    let mut s = String::from("## How the fitted detectors' alarms were chosen\n\n");
    let _ = writeln!(
        s,
        "On the trained families' validation flights flown in the loop at latency 0, each fitted detector tried its \
         threshold candidates at every alarm confirmation in {:?} (raw alarms in a row) and score smoothing in {:?} \
         (earlier scores averaged with the newest) and kept {rule} (decision 091).{attention} Per detector, the \
         units that chose each pair (confirmation k, smoothing w); thresholds, look-backs and exclusion bounds are \
         in closed_loop.csv.\n",
        cfg.loop_confirm, cfg.loop_smooth,
    );
    let _ = writeln!(s, "| detector | units per (k, w) |\n|---|---|");
    for (m, counts) in &chosen {
        let cells: Vec<String> = counts.iter().map(|((k, w), n)| format!("({k}, {w}): {n}")).collect();
        let _ = writeln!(s, "| {} | {} |", m.name(), cells.join(", "));
    }
    s
}

/// Table III in LaTeX: F1 of every detector on every family at latency 0, one block per
/// (model, noise).
#[must_use]
pub fn table3_latex(rows: &[ClosedLoopRow], methods: &[LoopMethod]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "% Generated by reproduce-tables from closed_loop.csv. Mean over seeds; latency 0 s.");
    let _ = writeln!(s, "\\begin{{table}}[t]\n\\centering");
    let _ = writeln!(
        s,
        "\\caption{{Detectors in the loop (Alg.~3): per-fix F1 of the alarms, mean over seeds, decision latency 0~s. \
         $\\dagger$: never trained on.}}"
    );
    let _ = writeln!(s, "\\label{{tab:closed_loop}}");
    let _ = writeln!(s, "\\begin{{tabular}}{{l{}}}\n\\hline", "c".repeat(Family::ALL.len()));
    let _ = write!(s, "Detector");
    for f in Family::ALL {
        let mark = if f.trained() { "" } else { "$^\\dagger$" };
        let _ = write!(s, " & {}{mark}", f.name());
    }
    let _ = writeln!(s, " \\\\\n\\hline");
    for (model, noise) in pairs(rows) {
        let _ = writeln!(
            s,
            "\\multicolumn{{{}}}{{l}}{{\\textit{{{}, {} noise}}}} \\\\",
            Family::ALL.len() + 1,
            model_name(model),
            noise.name()
        );
        for &m in methods {
            let _ = write!(s, "{}", m.name());
            for f in Family::ALL {
                let f1 = group_stat(rows, (model, noise, f.name(), m.name(), 0.0), |r| Some(r.f1));
                let _ = write!(s, " & {}", f1.map_or_else(|| "--".to_owned(), |m| format!("{:.2}", m.mean)));
            }
            let _ = writeln!(s, " \\\\");
        }
        let _ = writeln!(s, "\\hline");
    }
    let _ = writeln!(s, "\\end{{tabular}}\n\\end{{table}}");
    s
}

/// The report's section on the closed loop: links and the QUADFormer headline per unit pair.
pub fn write_report_section(s: &mut String, rows: &[ClosedLoopRow]) {
    let _ = writeln!(s, "\n## Closed loop: detectors that protect the estimate (Table III)\n");
    let _ = writeln!(
        s,
        "- [Table III](table3.md), [LaTeX](table3.tex), raw: [closed_loop.csv](closed_loop.csv)\n\n\
         ![drift](figures/closed-loop-drift.png)\n"
    );
    let _ = writeln!(s, "| model | noise | detector | sparse F1 | bias F1 | ramp F1 | max err sparse/bias/ramp (m) |");
    let _ = writeln!(s, "|---|---|---|---|---|---|---|");
    for (model, noise) in pairs(rows) {
        for m in ["QUADFormer", "Chi2", "PX4 EKF2"] {
            let stat =
                |f: &str, v: fn(&ClosedLoopRow) -> f64| group_stat(rows, (model, noise, f, m, 0.0), |r| Some(v(r)));
            if stat("sparse", |r| r.f1).is_none() {
                continue;
            }
            let _ = writeln!(
                s,
                "| {} | {} | {m} | {} | {} | {} | {} / {} / {} |",
                model_name(model),
                noise.name(),
                fmt_ms(stat("sparse", |r| r.f1), 2),
                fmt_ms(stat("bias", |r| r.f1), 2),
                fmt_ms(stat("ramp", |r| r.f1), 2),
                fmt_ms(stat("sparse", |r| r.max_error_attack_m), 1),
                fmt_ms(stat("bias", |r| r.max_error_attack_m), 1),
                fmt_ms(stat("ramp", |r| r.max_error_attack_m), 1),
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use attack_inject::{AttackPlan, AttackShape};

    /// A 10 Hz flight of `n` fixes; `attacked(k)` and `alarm(k)` script the labels and alarms,
    /// the offset grows 1 m per attacked fix and the error is 0.1 m clean, 2 m attacked.
    fn steps(n: usize, attacked: impl Fn(usize) -> bool, alarm: impl Fn(usize) -> bool) -> Vec<LoopStep> {
        let mut offset = 0.0;
        (0..n)
            .map(|k| {
                let a = attacked(k);
                offset = if a { offset + 1.0 } else { 0.0 };
                #[allow(clippy::cast_precision_loss)]
                let t = 0.1 * k as f64;
                LoopStep {
                    t,
                    attacked: a,
                    offset_m: offset,
                    score: 0.0,
                    alarm: alarm(k),
                    gps_excluded: alarm(k),
                    reset: false,
                    error_m: if a { 2.0 } else { 0.1 },
                }
            })
            .collect()
    }

    const UNIT: LoopUnit = LoopUnit { model: UavModel::I, noise: NoiseModel::Exponential, seed: 0 };

    #[test]
    fn the_loop_networks_are_configured_by_the_loop_settings() {
        let mut opts = Options {
            config: crate::reproduce::MatrixConfig::default(),
            quick: false,
            seeds: 1,
            cells: Vec::new(),
            methods: Vec::new(),
            out: PathBuf::new(),
            progress: false,
            stages: crate::reproduce::Stages::ClosedLoop,
        };
        let cfgs = loop_method_configs(&opts, 3);
        assert!(cfgs.quadformer.net.causal);
        assert!(!opts.config.methods.quadformer.net.causal, "Tables I and II keep the full window");
        assert_eq!(cfgs.quadformer.train.seed, opts.config.methods.seeded(3).quadformer.train.seed);
        opts.config.loop_causal = false;
        assert!(!loop_method_configs(&opts, 3).quadformer.net.causal);
        // The networks read the loop's features (decisions 094 and 095), not the tables'.
        use nn_toolkit::Features;
        assert_eq!(opts.config.methods.quadformer.window.features, Features::WhitenedLogDriftAbsorbed);
        assert_eq!(opts.config.methods.cnn.0.window.features, Features::WhitenedLogDriftAbsorbed);
        let window =
            |c: &MethodConfigs| (c.quadformer.window.features, c.cnn.0.window.features, c.lstm.0.window.features);
        assert_eq!(
            window(&cfgs),
            (Features::WhitenedLogDriftAbsorbed, Features::WhitenedLog, Features::WhitenedLogDriftAbsorbed)
        );
        let quick = crate::reproduce::MatrixConfig::quick().loop_features;
        assert_eq!(
            (quick.quadformer, quick.cnn, quick.lstm),
            (Features::WhitenedLog, Features::WhitenedLog, Features::WhitenedLog)
        );
        opts.config.loop_features.cnn = Features::WhitenedLogDriftAbsorbed;
        assert_eq!(loop_method_configs(&opts, 3).cnn.0.window.features, Features::WhitenedLogDriftAbsorbed);
    }

    #[test]
    fn row_counts_alarms_delays_false_alarm_events_and_errors() {
        // Attack on fixes 100..110; alarms on 103..110 (delay 0.3 s) and a clean false alarm
        // event on 200..205 (5 fixes excluded, 0.5 s of GPS lost).
        let f = steps(600, |k| (100..110).contains(&k), |k| (103..110).contains(&k) || (200..205).contains(&k));
        let r = row(
            UNIT,
            Family::Ramp,
            "X",
            0.0,
            Some(Flown {
                setting: LoopSetting { threshold: 1.0, lookback_s: 0.5, reset_after_s: None, confirm: 2, smooth: 0 },
                pair: 0,
                f1: 0.8,
                alarm_events_per_clean_min: 0.0,
            }),
            &[f.as_slice()],
        );
        assert_eq!((r.confirm, r.valid_f1), (Some(2), Some(0.8)));
        assert_eq!((r.precision, r.recall), (7.0 / 12.0, 0.7));
        assert!((r.delay_median_s.unwrap() - 0.3).abs() < 1e-9);
        assert_eq!(r.n_intervals, 1);
        assert!((r.gps_lost_clean_s - 0.5).abs() < 1e-9);
        assert!((r.clean_min - 59.0 / 60.0).abs() < 1e-6, "{}", r.clean_min);
        assert!((r.alarm_events_per_clean_min - 60.0 / 59.0).abs() < 1e-6);
        assert!((r.alarms_raised_clean_per_min - 60.0 / 59.0).abs() < 1e-6);
        assert_eq!((r.max_error_attack_m, r.rmse_attack_m, r.max_error_after_m), (2.0, 2.0, 0.1));
        // The offset passes 3 m at the third attacked fix, before the first alarm: not caught.
        assert_eq!(r.alarmed_before_3m, Some(0.0));
        // An alarm that outlasts its attack by two fixes is an alarm event on clean fixes, but
        // not one raised on a clean fix.
        let late = steps(600, |k| (100..110).contains(&k), |k| (103..112).contains(&k));
        let r = row(UNIT, Family::Sparse, "X", 0.0, None, &[late.as_slice()]);
        assert!((r.alarm_events_per_clean_min - 60.0 / 59.0).abs() < 1e-6);
        assert_eq!(r.alarms_raised_clean_per_min, 0.0);
        let early = steps(600, |k| (100..110).contains(&k), |k| (101..110).contains(&k));
        let r = row(UNIT, Family::Ramp, "X", 0.0, None, &[early.as_slice(), f.as_slice()]);
        assert_eq!(r.alarmed_before_3m, Some(0.5), "one of the two drifts caught before 3 m");
        assert_eq!(row(UNIT, Family::Bias, "X", 0.0, None, &[f.as_slice()]).alarmed_before_3m, None);
    }

    #[test]
    fn the_setting_is_the_best_f1_or_the_quietest_within_the_tolerance() {
        let c = |pair, threshold, f1, alarm_events_per_clean_min| Flown {
            setting: LoopSetting { threshold, lookback_s: 0.0, reset_after_s: None, confirm: 1 + pair, smooth: 0 },
            pair,
            f1,
            alarm_events_per_clean_min,
        };
        let flown = [c(0, 0.1, 0.90, 3.0), c(0, 0.2, 0.89, 1.0), c(0, 0.3, 0.80, 0.0), c(1, 0.1, 0.90, 2.0)];
        let chosen = |tol| choose(&flown, tol).map(|c| (c.setting.confirm, c.setting.threshold));
        assert_eq!(chosen(None), Some((1, 0.1)), "best F1; ties: the earlier pair");
        let tied = [c(0, 0.1, 0.90, 3.0), c(1, 0.5, 0.90, 3.0)];
        assert_eq!(
            choose(&tied, None).map(|c| c.setting.confirm),
            Some(1),
            "the earlier pair before the higher threshold"
        );
        assert_eq!(chosen(Some(0.0)), Some((2, 0.1)), "equal F1: the quieter");
        assert_eq!(chosen(Some(0.02)), Some((1, 0.2)), "within 0.02 of the best: the quietest");
        assert_eq!(chosen(Some(0.5)), Some((1, 0.3)));
        assert_eq!(choose(&[], None).map(|c| c.setting.threshold), None);
        // Equal F1 within one pair: the higher threshold.
        assert_eq!(
            choose(&[c(0, 0.1, 0.5, 1.0), c(0, 0.2, 0.5, 1.0)], Some(0.0)).map(|c| c.setting.threshold),
            Some(0.2)
        );
    }

    #[test]
    fn a_candidate_is_out_of_reach_only_when_its_bound_could_not_be_chosen() {
        let best = BestSoFar::new(None);
        assert!(!best.out_of_reach(0.0), "nothing flown yet: every candidate is in reach");
        best.record(0.8);
        best.record(0.6);
        assert!(best.out_of_reach(0.79));
        assert!(!best.out_of_reach(0.8), "a tie may still win on the pair or the threshold");
        let tolerant = BestSoFar::new(Some(0.05));
        tolerant.record(0.8);
        assert!(!tolerant.out_of_reach(0.8 - 0.05), "at the tolerance: the quieter may win");
        assert!(tolerant.out_of_reach(0.74));
        // Any outcome of the flights still to fly stays under the bound.
        let so_far = Confusion { tp: 3, fp: 2, fn_: 5, tn: 90 };
        assert!((f1_bound(so_far, 10) - 26.0 / 33.0).abs() < 1e-15);
        for tp in 0..=10 {
            for fp in 0..5 {
                let mut all = so_far;
                all.add(Confusion { tp, fp, fn_: 10 - tp, tn: 0 });
                assert!(all.f1() <= f1_bound(so_far, 10), "tp {tp}, fp {fp}");
            }
        }
    }

    #[test]
    fn the_pruned_search_chooses_what_the_full_search_chooses() {
        use rand::{RngExt as _, SeedableRng as _};
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let mut pruned_any = false;
        for case in 0..2_000 {
            let tolerance = [None, Some(0.0), Some(0.05)][case % 3];
            let attacked: Vec<u64> = (0..rng.random_range(1..5)).map(|_| rng.random_range(0..12)).collect();
            // Candidates as the per-flight confusions their flights would give; few fixes, so
            // that F1 ties are common.
            let mut candidates: Vec<(Flown, Vec<Confusion>)> = (0..rng.random_range(1..10))
                .map(|k| {
                    let per_flight: Vec<Confusion> = attacked
                        .iter()
                        .map(|&a| {
                            let tp = rng.random_range(0..=a);
                            Confusion { tp, fp: rng.random_range(0..6), fn_: a - tp, tn: 50 }
                        })
                        .collect();
                    let mut total = Confusion::default();
                    per_flight.iter().for_each(|c| total.add(*c));
                    #[allow(clippy::cast_precision_loss)]
                    let setting = LoopSetting {
                        threshold: k as f64,
                        lookback_s: 0.0,
                        reset_after_s: None,
                        confirm: 1,
                        smooth: 0,
                    };
                    let flown = Flown {
                        setting,
                        pair: rng.random_range(0..2),
                        f1: total.f1(),
                        alarm_events_per_clean_min: f64::from(rng.random_range(0..4_u8)),
                    };
                    (flown, per_flight)
                })
                .collect();
            let all: Vec<Flown> = candidates.iter().map(|(f, _)| *f).collect();
            let full = choose(&all, tolerance).map(|c| (c.pair, c.setting.threshold));
            // Flown in a random order, each as `fly_within_reach` flies it.
            for i in (1..candidates.len()).rev() {
                candidates.swap(i, rng.random_range(0..=i));
            }
            let best = BestSoFar::new(tolerance);
            let mut kept = Vec::new();
            for (flown, per_flight) in &candidates {
                let (mut so_far, mut still_to_fly) = (Confusion::default(), attacked.iter().sum::<u64>());
                let out = per_flight.iter().zip(&attacked).any(|(c, a)| {
                    so_far.add(*c);
                    still_to_fly -= a;
                    best.out_of_reach(f1_bound(so_far, still_to_fly))
                });
                if out {
                    pruned_any = true;
                } else {
                    best.record(flown.f1);
                    kept.push(*flown);
                }
            }
            let pruned = choose(&kept, tolerance).map(|c| (c.pair, c.setting.threshold));
            assert_eq!(pruned, full, "case {case}, tolerance {tolerance:?}");
        }
        assert!(pruned_any, "the cases exercise the pruning");
    }

    #[test]
    fn a_bad_f1_tolerance_or_confirmation_is_refused_before_anything_is_flown() {
        let data = |seed| {
            let flight = baselines::synthetic::SyntheticFlight::new(2_000, seed).generate(&[]).unwrap();
            LabelledResidues::new(vec![flight]).unwrap()
        };
        let textbook = baselines::Chi2Config { tuning: baselines::Tuning::Textbook, ..Default::default() };
        let det = ekf_residue::Fit::fit(&textbook, &data(1), &data(2)).unwrap();
        let filter = FilterConfig::new(ekf_residue::residues::ModelKind::ModelI);
        for tol in [-0.1, f64::NAN, f64::INFINITY] {
            let candidates = LoopCandidates { confirm: &[1], smooth: &[0], f1_tolerance: Some(tol) };
            let err = loop_setting(&det, &[], &filter, candidates).unwrap_err();
            assert!(err.contains("loop_f1_tolerance"), "{err}");
        }
        let candidates = LoopCandidates { confirm: &[1, 0], smooth: &[0], f1_tolerance: None };
        let err = loop_setting(&det, &[], &filter, candidates).unwrap_err();
        assert!(err.contains("loop_confirm"), "{err}");
    }

    #[test]
    fn the_exclusion_bound_is_the_longest_validation_attack_plus_the_margin() {
        let planned = |spans: &[(f64, f64)]| PlannedFlight {
            split: Split::Valid,
            index: 0,
            flight: Flight::default(),
            plan: AttackPlan::from_intervals(
                spans.iter().map(|&(t0, t1)| AttackInterval { t0, t1, shape: AttackShape::Freeze }).collect(),
            )
            .unwrap(),
        };
        assert_eq!(exclusion_bound_s(&[planned(&[])]), None);
        let valid = [planned(&[(10.0, 14.0), (30.0, 32.0)]), planned(&[(5.0, 25.0)]), planned(&[])];
        assert!((exclusion_bound_s(&valid).unwrap() - (20.0 + EXCLUSION_MARGIN_S)).abs() < 1e-12);
    }

    #[test]
    fn the_choice_section_counts_each_units_setting_once_and_states_the_rule() {
        let flight = steps(20, |k| (5..10).contains(&k), |k| (6..10).contains(&k));
        let setting = |confirm, smooth| Flown {
            setting: LoopSetting { threshold: 0.5, lookback_s: 0.0, reset_after_s: None, confirm, smooth },
            pair: 0,
            f1: 0.5,
            alarm_events_per_clean_min: 0.0,
        };
        let mut rows = Vec::new();
        for (seed, (k, w)) in [(0, (2, 0)), (1, (1, 2)), (2, (2, 0))] {
            let unit = LoopUnit { seed, ..UNIT };
            for family in [Family::Sparse, Family::Bias] {
                for latency in LATENCIES_S {
                    rows.push(row(unit, family, "QUADFormer", latency, Some(setting(k, w)), &[&flight]));
                }
            }
            rows.push(row(unit, Family::Sparse, "Oracle", 0.0, None, &[&flight]));
        }
        let md = choice_rule_markdown(&rows, &MatrixConfig::default());
        assert!(md.contains("| QUADFormer | (1, 2): 1, (2, 0): 2 |"), "{md}");
        assert!(
            md.contains("[1, 2]") && md.contains("[0, 2]") && md.contains("kept the candidate with the best F1"),
            "{md}"
        );
        assert!(md.contains("attends causally"), "{md}");
        assert!(!md.contains("| Oracle") && !md.contains("| LSTM"), "{md}");
        let quiet = MatrixConfig { loop_f1_tolerance: Some(0.02), loop_causal: false, ..MatrixConfig::default() };
        let md = choice_rule_markdown(&rows, &quiet);
        assert!(md.contains("within 0.02 of the best F1") && md.contains("over the whole window"), "{md}");
        let reference_only: Vec<ClosedLoopRow> = rows.into_iter().filter(|r| r.method == "Oracle").collect();
        assert_eq!(choice_rule_markdown(&reference_only, &quiet), "");
    }

    #[test]
    fn families_configure_their_attacks() {
        for f in Family::ALL {
            assert!(f.attack(0.5).check().is_ok(), "{}", f.name());
        }
        assert_eq!(Family::Bias.attack(0.5).ramp_probability, 0.0);
        let ramp = Family::Ramp.attack(0.5);
        assert_eq!((ramp.ramp_probability, ramp.ramp_slope_mps), (1.0, Some([0.1, 5.0])));
        assert_eq!(Family::TRAINED.iter().filter(|f| f.trained()).count(), 3);
        assert!(!Family::Replay.trained());
    }
}
