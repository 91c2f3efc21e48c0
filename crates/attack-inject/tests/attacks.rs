//! Public-boundary tests of attack-inject: attack shapes, attacked fraction, determinism,
//! label alignment and the bit-identity of samples outside attacks (eq:fdi).

use approx::assert_relative_eq;
use attack_inject::{
    AmplitudeConfig, AttackConfig, AttackError, AttackInterval, AttackKind, AttackPlan, AttackShape, DirectionMode,
    inject,
};
use nalgebra::Vector3;
use proptest::prelude::*;
use uav_dynamics::GpsSample;

/// A 10 Hz stream of a vehicle flying a circle of radius 50 m with a little deterministic jitter.
fn stream(n: usize) -> Vec<GpsSample> {
    (0..n)
        .map(|k| {
            #[allow(clippy::cast_precision_loss)]
            let t = k as f64 * 0.1;
            let jitter = (t * 12.9898).sin() * 0.3;
            GpsSample { t, p: Vector3::new(50.0 * (0.05 * t).cos() + jitter, 50.0 * (0.05 * t).sin(), 20.0 - jitter) }
        })
        .collect()
}

#[allow(clippy::unwrap_used)] // Test helper: default configs are valid.
fn plan(kind: AttackKind, n: usize, seed: u64) -> AttackPlan {
    let cfg = AttackConfig::new(kind).check().unwrap();
    #[allow(clippy::cast_precision_loss)]
    let t_end = (n - 1) as f64 * 0.1;
    AttackPlan::sample(&cfg, 0.0, t_end, seed).unwrap()
}

#[test]
fn attacked_fraction_near_target_for_every_kind() {
    for kind in AttackKind::ALL {
        for seed in 0..5 {
            let gps = stream(6000);
            let a = inject(&gps, &plan(kind, gps.len(), seed)).unwrap();
            let f = a.attacked_fraction();
            // 600 s flight, 12% target; one truncated interval of at most half a minimum duration
            // (5 s for persistent) and sample quantisation keep it within 0.02.
            assert!((f - 0.12).abs() < 0.02, "{kind:?} seed {seed}: fraction {f}");
        }
    }
}

#[test]
fn burst_and_persistent_durations_in_range() {
    let cfg = AttackConfig::new(AttackKind::Sparse);
    let p = plan(AttackKind::Sparse, 6000, 3);
    assert!(p.intervals().len() > 10);
    for iv in p.intervals() {
        let [lo, hi] = cfg.durations.sparse_s;
        assert!(iv.duration_s() <= hi + 1e-12, "{iv:?}");
        // The last interval may be shortened to hit the target, never below half the minimum.
        assert!(iv.duration_s() >= 0.5 * lo - 1e-12 || iv.duration_s() >= lo, "{iv:?}");
        assert!(matches!(iv.shape, AttackShape::Burst { .. }));
    }
    let p = plan(AttackKind::Persistent, 6000, 3);
    let [lo, hi] = cfg.durations.persistent_s;
    for (i, iv) in p.intervals().iter().enumerate() {
        assert!(iv.duration_s() <= hi + 1e-12);
        if i + 1 < p.intervals().len() {
            assert!(iv.duration_s() >= lo);
        }
        assert!(matches!(iv.shape, AttackShape::Bias { .. } | AttackShape::Ramp { .. }));
    }
}

#[test]
fn intervals_sorted_disjoint_with_gap_and_warmup() {
    for kind in AttackKind::ALL {
        let cfg = AttackConfig::new(kind);
        let p = plan(kind, 3000, 11);
        let first = p.intervals().first().unwrap();
        assert!(first.t0 >= cfg.warmup_s);
        for w in p.intervals().windows(2) {
            assert!(w[1].t0 >= w[0].t1 + cfg.min_gap_s - 1e-9, "{kind:?}: {w:?}");
        }
        assert!(p.intervals().last().unwrap().t1 <= 299.9 + 1e-9);
    }
}

#[test]
fn amplitudes_within_range_and_fixed_sweep() {
    let p = plan(AttackKind::Sparse, 6000, 5);
    for iv in p.intervals() {
        let AttackShape::Burst { offset } = iv.shape else { panic!("not a burst") };
        assert!(offset.norm() >= 1.5 - 1e-9 && offset.norm() <= 30.0 + 1e-9, "{}", offset.norm());
    }
    let mut cfg = AttackConfig::new(AttackKind::Persistent);
    cfg.amplitude = AmplitudeConfig::Fixed { sigma_multiple: 0.5 };
    cfg.gps_sigma_m = 1.5;
    cfg.direction = DirectionMode::Horizontal;
    let p = AttackPlan::sample(&cfg.check().unwrap(), 0.0, 600.0, 1).unwrap();
    for iv in p.intervals() {
        let d = match iv.shape {
            AttackShape::Bias { offset } => offset,
            AttackShape::Ramp { offset_end } => offset_end,
            other => panic!("unexpected {other:?}"),
        };
        assert_relative_eq!(d.norm(), 0.75, max_relative = 1e-12);
        assert_eq!(d.z, 0.0);
    }
}

#[test]
fn constant_bias_and_ramp_slope() {
    let gps = stream(400);
    let bias = Vector3::new(3.0, -4.0, 0.0);
    let ramp = Vector3::new(0.0, 0.0, 10.0);
    let plan = AttackPlan::from_intervals(vec![
        AttackInterval { t0: 5.0, t1: 15.0, shape: AttackShape::Bias { offset: bias } },
        AttackInterval { t0: 20.0, t1: 30.0, shape: AttackShape::Ramp { offset_end: ramp } },
    ])
    .unwrap();
    let a = inject(&gps, &plan).unwrap();
    for (k, g) in gps.iter().enumerate() {
        if g.t > 5.0 && g.t <= 15.0 {
            assert_relative_eq!(a.offset[k], bias, epsilon = 1e-9);
            assert!(a.labels[k]);
        } else if g.t > 20.0 && g.t <= 30.0 {
            // Slope ‖offset_end‖ / duration = 1 m/s along z.
            assert_relative_eq!(a.offset[k].z, g.t - 20.0, epsilon = 1e-9);
            assert!(a.labels[k]);
        } else {
            assert!(!a.labels[k]);
            assert_eq!(a.offset[k], Vector3::zeros());
        }
    }
}

#[test]
fn replay_and_freeze_send_recorded_fixes() {
    let gps = stream(400);
    let plan = AttackPlan::from_intervals(vec![
        AttackInterval { t0: 10.05, t1: 15.05, shape: AttackShape::Replay { delay_s: 2.0 } },
        AttackInterval { t0: 20.05, t1: 25.05, shape: AttackShape::Freeze },
    ])
    .unwrap();
    let a = inject(&gps, &plan).unwrap();
    for (k, g) in gps.iter().enumerate() {
        if g.t > 10.05 && g.t <= 15.05 {
            // 2 s at 10 Hz is 20 samples back (time stamps are k·0.1, so allow the rounding).
            let back = gps.iter().rev().find(|h| h.t <= g.t - 2.0).unwrap();
            assert_eq!(a.gps[k].p, back.p);
            assert_eq!(a.gps[k].t, g.t);
            assert!(a.labels[k]);
        } else if g.t > 20.05 && g.t <= 25.05 {
            assert_eq!(a.gps[k].p, gps[200].p);
            assert!(a.labels[k]);
        }
    }
}

#[test]
fn noise_injection_has_requested_rms_and_is_online_reproducible() {
    let gps = stream(3000);
    let plan = AttackPlan::from_intervals(vec![AttackInterval {
        t0: 0.0,
        t1: 299.9,
        shape: AttackShape::Noise { amplitude_m: 6.0, seed: 9 },
    }])
    .unwrap();
    let a = inject(&gps, &plan).unwrap();
    let ms: f64 = a.offset.iter().skip(1).map(|d| d.norm_squared()).sum::<f64>() / 2999.0;
    assert!((ms.sqrt() - 6.0).abs() < 0.3, "rms {}", ms.sqrt());
    // Online, sample by sample with no history, gives the same offsets.
    for (k, g) in gps.iter().enumerate().step_by(97) {
        assert_eq!(plan.apply(g, &[]).offset, a.offset[k]);
    }
}

#[test]
fn same_seed_same_plan_other_seed_other_plan() {
    for kind in AttackKind::ALL {
        assert_eq!(plan(kind, 3000, 77), plan(kind, 3000, 77));
        assert_ne!(plan(kind, 3000, 77), plan(kind, 3000, 78));
    }
}

#[test]
fn errors_are_named() {
    let cfg = AttackConfig::new(AttackKind::Sparse).check().unwrap();
    assert!(matches!(AttackPlan::sample(&cfg, 5.0, 5.0, 0), Err(AttackError::InvalidWindow { .. })));
    assert!(matches!(AttackPlan::sample(&cfg, 0.0, f64::NAN, 0), Err(AttackError::InvalidWindow { .. })));
    let mut big = AttackConfig::new(AttackKind::Persistent);
    big.attacked_fraction = 0.9;
    big.warmup_s = 50.0;
    assert!(matches!(
        AttackPlan::sample(&big.check().unwrap(), 0.0, 100.0, 0),
        Err(AttackError::PlanDoesNotFit { .. })
    ));
    let mut gps = stream(10);
    gps[4].t = gps[3].t;
    assert!(matches!(inject(&gps, &AttackPlan::empty()), Err(AttackError::UnorderedGps { step_idx: 4, .. })));
    gps = stream(10);
    gps[2].p.y = f64::NAN;
    assert!(matches!(inject(&gps, &AttackPlan::empty()), Err(AttackError::NonFiniteGps { step_idx: 2, what: "p" })));
    let overlap = vec![
        AttackInterval { t0: 0.0, t1: 2.0, shape: AttackShape::Freeze },
        AttackInterval { t0: 1.0, t1: 3.0, shape: AttackShape::Freeze },
    ];
    assert!(matches!(AttackPlan::from_intervals(overlap), Err(AttackError::InvalidInterval { interval_idx: 1, .. })));
}

#[test]
fn plan_serde_round_trip() {
    let p = plan(AttackKind::Persistent, 3000, 4);
    let json = serde_json::to_string(&p).unwrap();
    let back: AttackPlan = serde_json::from_str(&json).unwrap();
    assert_eq!(p, back);
}

fn kind_strategy() -> impl Strategy<Value = AttackKind> {
    prop::sample::select(AttackKind::ALL.to_vec())
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    /// Samples outside every attack interval are bit-identical to the clean stream, and a
    /// sample is labelled exactly when its sent fix differs from the clean one.
    #[test]
    fn outside_attacks_bit_identical(kind in kind_strategy(), seed in any::<u64>(), n in 200usize..1500,
                                     fraction in 0.0f64..0.3) {
        let gps = stream(n);
        let mut cfg = AttackConfig::new(kind);
        cfg.attacked_fraction = fraction;
        cfg.durations.persistent_s = [2.0, 8.0];
        #[allow(clippy::cast_precision_loss)]
        let t_end = (n - 1) as f64 * 0.1;
        let Ok(plan) = AttackPlan::sample(&cfg.check().unwrap(), 0.0, t_end, seed) else {
            return Ok(());
        };
        let a = inject(&gps, &plan).unwrap();
        prop_assert_eq!(a.gps.len(), gps.len());
        for (k, clean) in gps.iter().enumerate() {
            prop_assert_eq!(a.gps[k].t.to_bits(), clean.t.to_bits());
            if plan.active_at(clean.t).is_none() {
                for i in 0..3 {
                    prop_assert_eq!(a.gps[k].p[i].to_bits(), clean.p[i].to_bits());
                }
                prop_assert!(!a.labels[k]);
                prop_assert_eq!(a.offset[k], Vector3::zeros());
            }
            prop_assert_eq!(a.labels[k], a.gps[k].p != clean.p);
        }
    }
}

#[test]
fn ramp_slopes_stay_in_the_configured_range() {
    let mut cfg = AttackConfig::new(AttackKind::Persistent);
    cfg.ramp_probability = 1.0;
    cfg.ramp_slope_mps = Some([0.1, 5.0]);
    cfg.attacked_fraction = 0.5;
    for seed in 0..20 {
        let p = AttackPlan::sample(&cfg.check().unwrap(), 0.0, 600.0, seed).unwrap();
        assert!(!p.intervals().is_empty());
        for iv in p.intervals() {
            let AttackShape::Ramp { offset_end } = iv.shape else { panic!("not a ramp: {:?}", iv.shape) };
            let slope = offset_end.norm() / iv.duration_s();
            assert!((0.1 - 1e-9..=5.0 + 1e-9).contains(&slope), "slope {slope}");
        }
    }
    cfg.ramp_slope_mps = Some([0.0, 1.0]);
    assert!(cfg.check().is_err(), "a zero slope bound is refused");
}

#[test]
fn oscillating_offset_is_a_sine_from_the_interval_start() {
    let gps = stream(400);
    let amplitude = Vector3::new(6.0, 0.0, -2.0);
    let plan = AttackPlan::from_intervals(vec![AttackInterval {
        t0: 10.0,
        t1: 30.0,
        shape: AttackShape::Oscillating { amplitude, freq_hz: 0.25 },
    }])
    .unwrap();
    let a = inject(&gps, &plan).unwrap();
    for (k, g) in gps.iter().enumerate() {
        let expected = if g.t > 10.0 && g.t <= 30.0 {
            amplitude * (std::f64::consts::TAU * 0.25 * (g.t - 10.0)).sin()
        } else {
            Vector3::zeros()
        };
        assert_relative_eq!(a.offset[k], expected, epsilon = 1e-9);
    }
    // Sampled plans draw the frequency from its range.
    let cfg = AttackConfig::new(AttackKind::Oscillating);
    let p = AttackPlan::sample(&cfg.check().unwrap(), 0.0, 600.0, 3).unwrap();
    for iv in p.intervals() {
        let AttackShape::Oscillating { freq_hz, .. } = iv.shape else { panic!("not oscillating") };
        assert!((0.1..=0.3).contains(&freq_hz));
    }
}

#[test]
fn default_configs_serialise_without_the_newer_fields() {
    // Dataset cache keys hash this JSON: a configuration at its defaults must read as it did
    // before the oscillating attack and the ramp slopes existed.
    for kind in [AttackKind::Sparse, AttackKind::Persistent, AttackKind::Replay] {
        let json = serde_json::to_string(&AttackConfig::new(kind)).unwrap();
        for field in ["oscillating_s", "oscillation_hz", "ramp_slope_mps"] {
            assert!(!json.contains(field), "{field} in {json}");
        }
    }
    let mut cfg = AttackConfig::new(AttackKind::Oscillating);
    cfg.oscillation_hz = [0.2, 0.2];
    let back: AttackConfig = serde_json::from_str(&serde_json::to_string(&cfg).unwrap()).unwrap();
    assert_eq!(back, cfg);
}
