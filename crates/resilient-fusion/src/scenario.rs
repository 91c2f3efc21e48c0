//! The paper's closed-loop flight scenarios (fig:simu1 eight-shape, fig:simu2 UST-shape,
//! fig:simu3 four-UAV formation, fig:real1 diagonal, fig:real2 square), each in three cases:
//! no attack, GPS attack without detection, GPS attack with detection (alg:alg3).
//!
//! Every vehicle is a [`ClosedLoopSim`] whose position controller flies on the output of a
//! [`ResilientEstimator`] (Model II by default: GPS + VO + IMU), so a spoofed GPS fix that the
//! filter accepts moves the true vehicle. The attack is a constant GPS bias (`attack-inject`'s
//! [`AttackShape::Bias`]) over a scenario-specific window:
//!
//! | scenario | window |
//! |---|---|
//! | eight | second half of the first loop |
//! | UST | from the completion of the S, 15 s |
//! | formation | UAV 3 (index 2), from a quarter of its leg, half a leg long |
//! | diagonal | from the midpoint, 8 s |
//! | square | the second side |
//!
//! Metrics per vehicle ([`FlightMetrics`]): tracking RMSE and maximum deviation of the truth
//! from the reference, estimate RMSE, time under attack, time GPS was excluded (and how much of
//! it outside the attack), detection delay (attack onset → first alarm) and exclusion delay
//! (onset → GPS excluded, including the decision latency); for the formation the shape error
//! ([`FormationMetrics`]). Traces are sampled at `trace_rate_hz`. Units: metres, seconds.

use attack_inject::{AttackInterval, AttackPlan, AttackShape};
use ekf_residue::detector::OnlineDetector;
use ekf_residue::residues::{FilterConfig, Measurements, ModelKind};
use nalgebra::Vector3;
use serde::{Deserialize, Serialize};
use uav_dynamics::controller::{ClosedLoopSim, ControllerConfig, NavEstimate};
use uav_dynamics::sensors::GpsSample;
use uav_dynamics::sim::SimConfig;
use uav_dynamics::trajectory::{
    self, FORMATION_SIZE, PathTrajectory, SEPTIC_PEAK_SLOPE, ShapeConfig, Trajectory, eight_first_loop,
};

use crate::error::{FusionError, Result};
use crate::estimator::{ResilientConfig, ResilientEstimator};

/// The paper's flight scenarios.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Scenario {
    /// Two loops of an eight from the centre (fig:simu1).
    Eight,
    /// Letters U, S, T from the upper left (fig:simu2).
    Ust,
    /// Four UAVs on a square, each flying to the next vertex counter-clockwise (fig:simu3).
    Formation,
    /// Lower left to upper right (fig:real1).
    Diagonal,
    /// Counter-clockwise square returning home (fig:real2).
    Square,
}

impl Scenario {
    /// All scenarios in the paper's figure order.
    pub const ALL: [Self; 5] = [Self::Eight, Self::Ust, Self::Formation, Self::Diagonal, Self::Square];

    /// Short lowercase name for files and tables.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::Eight => "eight",
            Self::Ust => "ust",
            Self::Formation => "formation",
            Self::Diagonal => "diagonal",
            Self::Square => "square",
        }
    }
}

/// The three cases of every scenario figure.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Case {
    /// Normal operation: no attack, no detector (GPS always fused).
    NoAttack,
    /// GPS attacked, no detector (GPS always fused).
    AttackUndetected,
    /// GPS attacked, detector and alg:alg3 exclusion active.
    AttackDetected,
}

impl Case {
    /// All cases in figure order.
    pub const ALL: [Self; 3] = [Self::NoAttack, Self::AttackUndetected, Self::AttackDetected];

    /// Short lowercase name for files and tables.
    #[must_use]
    pub fn name(self) -> &'static str {
        match self {
            Self::NoAttack => "no_attack",
            Self::AttackUndetected => "attack_undetected",
            Self::AttackDetected => "attack_detected",
        }
    }
}

/// Configuration of a scenario run.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioConfig {
    /// Size, altitude and speed of the shapes. Default [`ShapeConfig::default`].
    #[serde(default)]
    pub shape: ShapeConfig,
    /// Sensors. Default [`SimConfig::default`].
    #[serde(default)]
    pub sim: SimConfig,
    /// Position controller. Default [`ControllerConfig::default`] (PX4 gains).
    #[serde(default)]
    pub controller: ControllerConfig,
    /// Resilient estimator. Default [`ResilientConfig::default`] (1 s latency, 1 s hold).
    #[serde(default)]
    pub resilient: ResilientConfig,
    /// Filter model. Default Model II (GPS + VO + IMU, the sensors alg:alg3 fuses).
    pub model: ModelKind,
    /// GPS bias injected during the attack, metres (ENU). Default `[8, −6, 0]` (10 m
    /// horizontally, twenty GPS σ: an obvious spoof, as in the paper's figures).
    pub attack_offset_m: [f64; 3],
    /// Attack duration override in seconds (`None`: the scenario's window, module doc).
    #[serde(default)]
    pub attack_duration_s: Option<f64>,
    /// Trace sampling rate in Hz; must divide the IMU rate. Default 10.
    pub trace_rate_hz: u32,
    /// Seed of the sensor noise (vehicle `i` uses `seed + i`). Default 1.
    pub seed: u64,
}

impl Default for ScenarioConfig {
    fn default() -> Self {
        Self {
            shape: ShapeConfig::default(),
            sim: SimConfig::default(),
            controller: ControllerConfig::default(),
            resilient: ResilientConfig::default(),
            model: ModelKind::ModelII,
            attack_offset_m: [8.0, -6.0, 0.0],
            attack_duration_s: None,
            trace_rate_hz: 10,
            seed: 1,
        }
    }
}

/// Builds one online detector per vehicle (argument: vehicle index).
pub type DetectorFactory<'d> = dyn Fn(usize) -> Result<Box<dyn OnlineDetector + 'd>> + 'd;

/// Metrics of one vehicle's flight.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FlightMetrics {
    /// RMS of `‖p_true − p_ref‖` over all IMU steps, m.
    pub tracking_rmse_m: f64,
    /// Maximum of `‖p_true − p_ref‖`, m.
    pub tracking_max_m: f64,
    /// RMS of `‖p̂ − p_true‖` over all IMU steps, m.
    pub estimate_rmse_m: f64,
    /// Length of the attack window on this vehicle, s (0 when not attacked).
    pub time_under_attack_s: f64,
    /// Total time GPS was excluded, s.
    pub time_gps_excluded_s: f64,
    /// Time GPS was excluded outside the attack window, s.
    pub excluded_outside_attack_s: f64,
    /// Attack onset → first alarm on a residue inside the window, s.
    pub detection_delay_s: Option<f64>,
    /// Attack onset → GPS excluded (includes the decision latency), s.
    pub exclusion_delay_s: Option<f64>,
}

/// Trajectories of one vehicle's flight, sampled at the trace rate.
#[derive(Debug, Clone, PartialEq)]
pub struct FlightTrace {
    /// Sample times, s.
    pub t: Vec<f64>,
    /// True positions, m.
    pub truth: Vec<Vector3<f64>>,
    /// Estimated positions, m.
    pub estimate: Vec<Vector3<f64>>,
    /// Reference positions, m.
    pub reference: Vec<Vector3<f64>>,
    /// Attack window `(t0, t1]` on this vehicle, if attacked.
    pub attack_interval: Option<(f64, f64)>,
    /// Intervals during which GPS was excluded.
    pub excluded_intervals: Vec<(f64, f64)>,
    /// Residue times of the detector's alarms.
    pub alarm_times: Vec<f64>,
}

/// One vehicle's result.
#[derive(Debug, Clone, PartialEq)]
pub struct VehicleResult {
    /// Metrics.
    pub metrics: FlightMetrics,
    /// Trajectories.
    pub trace: FlightTrace,
}

/// Formation-shape error of a multi-vehicle case: at each trace time, the RMS over vehicles
/// of `‖(p_i − p̄) − (r_i − r̄)‖` (true positions `p`, references `r`, bars = centroids).
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FormationMetrics {
    /// RMS over time of the shape error, m.
    pub shape_rmse_m: f64,
    /// Maximum over time of the shape error, m.
    pub shape_max_m: f64,
}

/// The result of one case of a scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct CaseResult {
    /// Which scenario.
    pub scenario: Scenario,
    /// Which case.
    pub case: Case,
    /// Index of the attacked vehicle.
    pub attacked_vehicle: usize,
    /// One result per vehicle.
    pub vehicles: Vec<VehicleResult>,
    /// Formation-shape error (formation scenario only).
    pub formation: Option<FormationMetrics>,
}

impl CaseResult {
    /// The attacked vehicle's result.
    #[must_use]
    pub fn attacked(&self) -> Option<&VehicleResult> {
        self.vehicles.get(self.attacked_vehicle)
    }
}

/// Trajectories, attacked vehicle and attack window of a scenario.
#[derive(Debug, Clone, PartialEq)]
pub struct ScenarioSetup {
    /// One reference per vehicle.
    pub trajectories: Vec<PathTrajectory>,
    /// Index of the attacked vehicle.
    pub attacked_vehicle: usize,
    /// Attack window `(t0, t1]`, seconds.
    pub attack_window: (f64, f64),
}

/// Duration of a rest-to-rest line of length `len_m` at peak speed `speed_mps`.
fn leg_time(len_m: f64, speed_mps: f64) -> f64 {
    SEPTIC_PEAK_SLOPE * len_m / speed_mps
}

/// Build the references and attack window of `scenario` (module doc).
///
/// # Errors
/// [`FusionError::Sim`] for an invalid shape; [`FusionError::Config`] for a non-positive
/// attack duration.
pub fn setup(scenario: Scenario, cfg: &ScenarioConfig) -> Result<ScenarioSetup> {
    let sh = &cfg.shape;
    if let Some(d) = cfg.attack_duration_s
        && !(d.is_finite() && d > 0.0)
    {
        return Err(FusionError::Config { field: "attack_duration_s", msg: format!("must be positive, got {d}") });
    }
    let dur = |default: f64| cfg.attack_duration_s.unwrap_or(default);
    let (trajectories, attacked_vehicle, attack_window) = match scenario {
        Scenario::Eight => {
            let tr = trajectory::eight(sh)?;
            let (l0, l1) = eight_first_loop(&tr);
            let mid = 0.5 * (l0 + l1);
            (vec![tr], 0, (mid, mid + dur(l1 - mid)))
        }
        Scenario::Ust => {
            let (tr, s_done) = trajectory::ust(sh)?;
            (vec![tr], 0, (s_done, s_done + dur(15.0)))
        }
        Scenario::Formation => {
            let trs =
                (0..FORMATION_SIZE).map(|i| trajectory::formation_square(sh, i)).collect::<Result<Vec<_>, _>>()?;
            let leg = leg_time(sh.size_m, sh.speed_mps);
            let t0 = sh.hover_s + 0.25 * leg;
            (trs, 2, (t0, t0 + dur(0.5 * leg)))
        }
        Scenario::Diagonal => {
            let tr = trajectory::diagonal(sh)?;
            let leg = leg_time(sh.size_m * std::f64::consts::SQRT_2, sh.speed_mps);
            let mid = sh.hover_s + 0.5 * leg;
            (vec![tr], 0, (mid, mid + dur(8.0)))
        }
        Scenario::Square => {
            let tr = trajectory::square(sh)?;
            let leg = leg_time(sh.size_m, sh.speed_mps);
            let t0 = sh.hover_s + leg;
            (vec![tr], 0, (t0, t0 + dur(leg)))
        }
    };
    Ok(ScenarioSetup { trajectories, attacked_vehicle, attack_window })
}

/// Run one case of a scenario. `detectors` builds each vehicle's detector for
/// [`Case::AttackDetected`] (ignored otherwise).
///
/// # Errors
/// [`FusionError::Config`] for an invalid trace rate or a missing detector factory in the
/// detected case; otherwise any error of the simulator, filter, detector or attack plan.
pub fn run_case(
    scenario: Scenario,
    case: Case,
    cfg: &ScenarioConfig,
    detectors: Option<&DetectorFactory<'_>>,
) -> Result<CaseResult> {
    let su = setup(scenario, cfg)?;
    if cfg.trace_rate_hz == 0 || !cfg.sim.imu_rate_hz.is_multiple_of(cfg.trace_rate_hz) {
        return Err(FusionError::Config {
            field: "trace_rate_hz",
            msg: format!("{} Hz must be positive and divide the IMU rate {}", cfg.trace_rate_hz, cfg.sim.imu_rate_hz),
        });
    }
    if case == Case::AttackDetected && detectors.is_none() {
        return Err(FusionError::Config {
            field: "detectors",
            msg: "the detected case needs a detector factory".into(),
        });
    }
    let (a0, a1) = su.attack_window;
    let offset = Vector3::from(cfg.attack_offset_m);
    let plan =
        AttackPlan::from_intervals(vec![AttackInterval { t0: a0, t1: a1, shape: AttackShape::Bias { offset } }])?;
    let mut vehicles = Vec::with_capacity(su.trajectories.len());
    for (i, traj) in su.trajectories.iter().enumerate() {
        let attacked = case != Case::NoAttack && i == su.attacked_vehicle;
        let detector = match (case, detectors) {
            (Case::AttackDetected, Some(f)) => Some(f(i)?),
            _ => None,
        };
        let seed = cfg.seed.wrapping_add(i as u64);
        vehicles.push(fly(traj, cfg, attacked.then_some(&plan), detector, seed)?);
    }
    let formation = (vehicles.len() > 1).then(|| formation_metrics(&vehicles));
    Ok(CaseResult { scenario, case, attacked_vehicle: su.attacked_vehicle, vehicles, formation })
}

/// Run the three cases of a scenario.
///
/// # Errors
/// As [`run_case`].
pub fn run_scenario(
    scenario: Scenario,
    cfg: &ScenarioConfig,
    detectors: &DetectorFactory<'_>,
) -> Result<Vec<CaseResult>> {
    Case::ALL.iter().map(|&case| run_case(scenario, case, cfg, Some(detectors))).collect()
}

/// Fly one vehicle in closed loop on the resilient estimate.
fn fly(
    traj: &dyn Trajectory,
    cfg: &ScenarioConfig,
    plan: Option<&AttackPlan>,
    detector: Option<Box<dyn OnlineDetector + '_>>,
    seed: u64,
) -> Result<VehicleResult> {
    let mut sim = ClosedLoopSim::new(&cfg.sim, cfg.controller, traj, seed)?;
    let filter_cfg = FilterConfig::for_sim(cfg.model, &cfg.sim);
    let mut res = ResilientEstimator::new(&filter_cfg, &cfg.resilient, detector)?;
    let dt = sim.dt_s();
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let n_steps = (traj.duration_s() / dt).round().max(1.0) as u64 + 1;
    let trace_every = u64::from(cfg.sim.imu_rate_hz / cfg.trace_rate_hz);
    let mut nav = sim.initial_estimate();
    let mut history: Vec<GpsSample> = Vec::new();
    let cap = usize::try_from(n_steps / trace_every + 1).unwrap_or(0);
    let mut trace = FlightTrace {
        t: Vec::with_capacity(cap),
        truth: Vec::with_capacity(cap),
        estimate: Vec::with_capacity(cap),
        reference: Vec::with_capacity(cap),
        attack_interval: plan.and_then(|p| p.intervals().first().map(|iv| (iv.t0, iv.t1))),
        excluded_intervals: Vec::new(),
        alarm_times: Vec::new(),
    };
    let (mut sum_track, mut max_track, mut sum_est) = (0.0, 0.0_f64, 0.0);
    let mut t_last = 0.0;
    for k in 0..n_steps {
        let out = sim.step(&nav)?;
        let s = out.sensors;
        let t = s.imu.t;
        t_last = t;
        let gps = match (s.gps, plan) {
            (Some(clean), Some(plan)) => {
                let sent = plan.apply(&clean, &history);
                history.push(clean);
                Some(sent.gps.p)
            }
            (g, None) => g.map(|g| g.p),
            (None, Some(_)) => None,
        };
        let meas = Measurements { t, gps, attitude: s.attitude.map(|a| a.q), vo: s.vo };
        res.process(&s.imu, &meas)?;
        let est = res.estimate();
        let p_hat = est.map_or(s.truth.p, |e| e.p);
        let track = (s.truth.p - out.reference.p).norm();
        sum_track += track * track;
        max_track = max_track.max(track);
        sum_est += (p_hat - s.truth.p).norm_squared();
        if k % trace_every == 0 {
            trace.t.push(t);
            trace.truth.push(s.truth.p);
            trace.estimate.push(p_hat);
            trace.reference.push(out.reference.p);
        }
        // The controller's next input: the estimate propagated to the next step's time.
        if let Some(e) = est {
            nav = NavEstimate { p: e.p + e.v * dt, v: e.v };
        }
    }
    #[allow(clippy::cast_precision_loss)]
    let n = n_steps as f64;
    trace.excluded_intervals = res.excluded_intervals(t_last);
    trace.alarm_times = res.alarm_times().to_vec();
    let metrics =
        flight_metrics(&trace, cfg.resilient.latency_s, (sum_track / n).sqrt(), max_track, (sum_est / n).sqrt());
    Ok(VehicleResult { metrics, trace })
}

/// Overlap of `(a0, a1)` and `(b0, b1)`.
fn overlap(a: (f64, f64), b: (f64, f64)) -> f64 {
    (a.1.min(b.1) - a.0.max(b.0)).max(0.0)
}

fn flight_metrics(trace: &FlightTrace, latency_s: f64, rmse: f64, max: f64, est_rmse: f64) -> FlightMetrics {
    // `+ 0.0` turns the empty sum (−0.0) into +0.0.
    let excluded: f64 = trace.excluded_intervals.iter().map(|iv| iv.1 - iv.0).sum::<f64>() + 0.0;
    let (under, outside, det, excl) = match trace.attack_interval {
        Some((a0, a1)) => {
            let inside: f64 = trace.excluded_intervals.iter().map(|iv| overlap(*iv, (a0, a1))).sum();
            let det = trace.alarm_times.iter().find(|&&t| t > a0 && t <= a1).map(|t| t - a0);
            // An exclusion that starts within the window (or up to the latency after it).
            let excl = trace
                .excluded_intervals
                .iter()
                .find(|iv| iv.0 > a0 && iv.0 <= a1 + latency_s + 1e-9)
                .map(|iv| iv.0 - a0);
            (a1 - a0, (excluded - inside).max(0.0), det, excl)
        }
        None => (0.0, excluded, None, None),
    };
    FlightMetrics {
        tracking_rmse_m: rmse,
        tracking_max_m: max,
        estimate_rmse_m: est_rmse,
        time_under_attack_s: under,
        time_gps_excluded_s: excluded,
        excluded_outside_attack_s: outside,
        detection_delay_s: det,
        exclusion_delay_s: excl,
    }
}

fn formation_metrics(vehicles: &[VehicleResult]) -> FormationMetrics {
    let n_t = vehicles.iter().map(|v| v.trace.t.len()).min().unwrap_or(0);
    #[allow(clippy::cast_precision_loss)]
    let n_v = vehicles.len() as f64;
    let (mut sum, mut max) = (0.0, 0.0_f64);
    for k in 0..n_t {
        let c_p: Vector3<f64> = vehicles.iter().map(|v| v.trace.truth[k]).sum::<Vector3<f64>>() / n_v;
        let c_r: Vector3<f64> = vehicles.iter().map(|v| v.trace.reference[k]).sum::<Vector3<f64>>() / n_v;
        let e2 = vehicles
            .iter()
            .map(|v| ((v.trace.truth[k] - c_p) - (v.trace.reference[k] - c_r)).norm_squared())
            .sum::<f64>()
            / n_v;
        sum += e2;
        max = max.max(e2.sqrt());
    }
    #[allow(clippy::cast_precision_loss)]
    let rmse = if n_t > 0 { (sum / n_t as f64).sqrt() } else { 0.0 };
    FormationMetrics { shape_rmse_m: rmse, shape_max_m: max }
}
