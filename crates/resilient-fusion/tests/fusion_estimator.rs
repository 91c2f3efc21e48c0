//! Tests of the resilient estimator's state machine (`estimator::ResilientEstimator`) with a
//! scripted detector on an open-loop simulated flight: exclusion starts after the decision
//! latency, GPS is re-admitted after the hold time, a rollback into an earlier exclusion
//! reopens it, a reset takes the velocity the unfused fixes reveal, and configs are `Send +
//! Sync`.

use ekf_residue::detector::{OnlineDecision, OnlineDetector};
use ekf_residue::error::DetectError;
use ekf_residue::residues::{FilterConfig, Measurements, ModelKind};
use ekf_residue::series::ResidueStep;
use nalgebra::Vector3;
use resilient_fusion::estimator::{ResilientConfig, ResilientEstimator, Rollback};
use resilient_fusion::scenario::ScenarioConfig;
use resilient_fusion::{FusionError, Result};
use uav_dynamics::sim::{SimConfig, simulate};
use uav_dynamics::trajectory::{ShapeConfig, square};

/// Alarms on every residue step with `t0 < t ≤ t1` for one of its windows `(t0, t1)`.
struct Scripted {
    windows: Vec<(f64, f64)>,
}

impl OnlineDetector for Scripted {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        let alarm = self.windows.iter().any(|&(t0, t1)| step.t > t0 && step.t <= t1);
        Ok(OnlineDecision { score: f64::from(u8::from(alarm)), alarm })
    }

    fn reset(&mut self) {}
}

/// What the estimator did over a flight.
struct Outcome {
    excluded: Vec<(f64, f64)>,
    n_rollbacks: usize,
    n_resets: usize,
    /// `(t, ‖p̂ − p‖, ‖v̂ − v‖)` at every step with a measurement.
    errors: Vec<(f64, f64, f64)>,
}

/// A GPS spoof: `offset + rate·(t − t0)` added to every fix with `t0 < t ≤ t1`.
struct Spoof {
    t0: f64,
    t1: f64,
    offset: Vector3<f64>,
    rate: Vector3<f64>,
}

/// Run the estimator over a 30 s square flight with a detector alarming in `windows`; with the
/// Model II filter it must end within 2 m of the truth.
fn excluded(cfg: &ResilientConfig, windows: &[(f64, f64)]) -> Result<Outcome> {
    let out = fly(ModelKind::ModelII, cfg, windows, &[])?;
    let err = out.errors.last().map_or(f64::INFINITY, |e| e.1);
    if err > 2.0 {
        return Err(FusionError::Config { field: "estimate", msg: format!("final error {err} m") });
    }
    Ok(out)
}

/// Run the estimator of `model` over a 30 s square flight with a detector alarming in
/// `windows` and the fixes spoofed by `spoof`.
fn fly(model: ModelKind, cfg: &ResilientConfig, windows: &[(f64, f64)], spoofs: &[Spoof]) -> Result<Outcome> {
    let sim = SimConfig::default();
    let flight = simulate(&sim, &square(&ShapeConfig::default())?, 30.0, 4)?;
    let fc = FilterConfig::for_sim(model, &sim);
    let mut est = ResilientEstimator::new(&fc, cfg, Some(Box::new(Scripted { windows: windows.to_vec() })))?;
    let s = &flight.streams;
    let (mut g, mut a, mut v) = (0, 0, 0);
    let mut errors = Vec::new();
    for imu in &s.imu {
        let t = imu.t;
        let take_gps = s.gps.get(g).filter(|x| x.t == t).map(|x| {
            let spoofed = spoofs.iter().filter(|sp| t > sp.t0 && t <= sp.t1);
            x.p + spoofed.map(|sp| sp.offset + sp.rate * (t - sp.t0)).sum::<Vector3<f64>>()
        });
        g += usize::from(take_gps.is_some());
        let take_att = s.attitude.get(a).filter(|x| x.t == t).map(|x| x.q);
        a += usize::from(take_att.is_some());
        let take_vo = s.vo.get(v).filter(|x| x.t == t).copied();
        v += usize::from(take_vo.is_some());
        let step = est.process(imu, &Measurements { t, gps: take_gps, attitude: take_att, vo: take_vo })?;
        if let (Some(_), Some(e)) = (step, est.estimate()) {
            let k = flight.truth.partition_point(|x| x.t < t - 1e-9).min(flight.truth.len() - 1);
            errors.push((t, (e.p - flight.truth[k].p).norm(), (e.v - flight.truth[k].v).norm()));
        }
    }
    Ok(Outcome {
        excluded: est.excluded_intervals(30.0),
        n_rollbacks: est.n_rollbacks(),
        n_resets: est.n_resets(),
        errors,
    })
}

#[test]
fn exclusion_follows_latency_and_hold() -> Result<()> {
    let cfg = ResilientConfig { latency_s: 0.5, hold_s: 2.0, ..ResilientConfig::default() };
    let Outcome { excluded: iv, n_rollbacks, .. } = excluded(&cfg, &[(10.0, 15.0)])?;
    // First alarm on the residue at 10.1 s, usable at 10.6 s; last alarm at 15.0 s, usable at
    // 15.5 s; re-admitted 2 s later.
    assert_eq!(iv.len(), 1, "{iv:?}");
    assert!((iv[0].0 - 10.6).abs() < 1e-6 && (iv[0].1 - 17.5).abs() < 1e-6, "{iv:?}");
    assert_eq!(n_rollbacks, 1);
    let off = ResilientConfig { rollback: Rollback::Off, ..cfg };
    let Outcome { excluded: iv_off, n_rollbacks: n_off, .. } = excluded(&off, &[(10.0, 15.0)])?;
    assert_eq!(iv_off, iv);
    assert_eq!(n_off, 0);
    Ok(())
}

#[test]
fn zero_latency_gates_the_alarmed_fix_itself() -> Result<()> {
    let cfg = ResilientConfig { latency_s: 0.0, hold_s: 1.0, ..ResilientConfig::default() };
    let Outcome { excluded: iv, n_rollbacks, .. } = excluded(&cfg, &[(20.0, 22.0)])?;
    assert_eq!(iv.len(), 1, "{iv:?}");
    assert!((iv[0].0 - 20.1).abs() < 1e-6 && (iv[0].1 - 23.0).abs() < 1e-6, "{iv:?}");
    assert_eq!(n_rollbacks, 0);
    Ok(())
}

#[test]
fn a_rollback_into_an_earlier_exclusion_reopens_it_and_its_reset_clock() -> Result<()> {
    // Latency 1 s, hold 1 s, look-back 0.4 s. Each window alarms for 0.3 s; GPS is re-admitted
    // 2 s after a window's last alarmed residue, and the next window's first alarm, 0.3 s
    // later, rewinds 0.4 s: to before that re-admission, undoing every fix fused since.
    let cfg = ResilientConfig {
        latency_s: 1.0,
        hold_s: 1.0,
        rollback_lookback_s: 0.4,
        reset_after_s: Some(5.0),
        ..ResilientConfig::default()
    };
    let windows: Vec<(f64, f64)> = (0..5).map(|i| 10.0 + 2.5 * f64::from(i)).map(|a| (a, a + 0.3)).collect();
    let out = excluded(&cfg, &windows)?;
    // The first three windows make one exclusion, from the first alarm (residue 10.1 s, usable
    // at 11.1 s) to the reset 5 s later. The fourth starts a new one (its rollback stops at the
    // reset), which the fifth reopens.
    assert_eq!(out.n_resets, 1);
    assert_eq!(out.n_rollbacks, windows.len());
    assert_eq!(out.excluded.len(), 2, "{:?}", out.excluded);
    assert!((out.excluded[0].0 - 11.1).abs() < 1e-6 && (out.excluded[0].1 - 16.1).abs() < 1e-6, "{:?}", out.excluded);
    assert!((out.excluded[1].0 - 18.6).abs() < 1e-6 && (out.excluded[1].1 - 22.3).abs() < 1e-6, "{:?}", out.excluded);
    // Without the look-back each rollback lands after the re-admission before it: the
    // exclusions stay apart and none lasts 5 s.
    let apart = excluded(&ResilientConfig { rollback_lookback_s: 0.0, ..cfg }, &windows)?;
    assert_eq!(apart.n_resets, 0);
    assert_eq!(apart.excluded.len(), windows.len(), "{:?}", apart.excluded);
    Ok(())
}

#[test]
fn a_reset_takes_the_velocity_the_unfused_fixes_reveal() -> Result<()> {
    // Model I fuses a 1 m/s drift from 4 s to 10 s, which the velocity takes. The detector
    // alarms from 10 s to 28 s: the estimate dead-reckons with the velocity error, and GPS is
    // reset onto the fix 6 s later (16.1 s), the detector's alarms unheeded since. A 15 m burst
    // 0.5 s after the reset is fused whole.
    let cfg = ResilientConfig { latency_s: 0.0, reset_after_s: Some(6.0), ..ResilientConfig::default() };
    let spoofs = [
        Spoof { t0: 4.0, t1: 10.0, offset: Vector3::zeros(), rate: Vector3::new(1.0, 0.0, 0.0) },
        Spoof { t0: 16.6, t1: 18.6, offset: Vector3::new(15.0, -10.0, 0.0), rate: Vector3::zeros() },
    ];
    let alarms = [(10.0, 28.0)];
    let trend = fly(ModelKind::ModelI, &cfg, &alarms, &spoofs)?;
    let forget = fly(ModelKind::ModelI, &ResilientConfig { reset_velocity_window_s: 0.0, ..cfg }, &alarms, &spoofs)?;
    assert_eq!((trend.n_resets, forget.n_resets), (1, 1));
    let worst = |o: &Outcome, from: f64, to: f64| {
        o.errors.iter().filter(|e| e.0 > from && e.0 <= to).map(|e| e.2).fold(0.0, f64::max)
    };
    // The reset removes most of the velocity error the dead reckoning carried; forgotten, the
    // velocity takes the noise of the next fixes.
    let before = worst(&trend, 15.5, 16.0);
    let (after, after_forget) = (worst(&trend, 16.0, 16.6), worst(&forget, 16.0, 16.6));
    assert!(before > 0.7, "velocity error before the reset {before} m/s");
    assert!(after < 0.5 * before, "velocity error after the reset {after} m/s, before it {before} m/s");
    assert!(after < after_forget, "after the reset: trend {after}, forgotten {after_forget} m/s");
    // During the burst the velocity holds far better than a forgotten one, which takes it.
    let (burst, burst_forget) = (worst(&trend, 16.6, 22.0), worst(&forget, 16.6, 22.0));
    assert!(burst < 0.5 * burst_forget, "during the burst: trend {burst}, forgotten {burst_forget} m/s");
    Ok(())
}

#[test]
fn configs_and_estimator_are_thread_safe() {
    fn send_sync<T: Send + Sync>() {}
    fn send<T: Send>() {}
    send_sync::<ResilientConfig>();
    send_sync::<ScenarioConfig>();
    send_sync::<FusionError>();
    send::<ResilientEstimator<'static>>();
}
