//! Metrics of `eval::metrics` against hand-computed cases (per-step P/R/F1, ROC AUC with ties,
//! average precision, detection delay, false alarms per minute, mean ± sample std) and
//! property tests of the ROC identities.

use eval::metrics::{
    FlightOutcome, MeanStd, MetricsError, RocCurve, average_precision, confusion, detection_delays, evaluate,
    false_alarms, roc_auc,
};
use proptest::prelude::*;

const EPS: f64 = 1e-12;

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() < EPS
}

#[test]
fn per_step_prf_without_point_adjustment() {
    // One attack interval of 4 steps, the detector hits 1 of them and raises 1 false alarm.
    // With point adjustment recall would be 1; per step it is 1/4.
    let labels = [false, true, true, true, true, false];
    let alarms = [false, false, true, false, false, true];
    let c = confusion(&alarms, &labels).unwrap();
    assert_eq!((c.tp, c.fp, c.fn_, c.tn), (1, 1, 3, 1));
    assert!(close(c.precision(), 0.5));
    assert!(close(c.recall(), 0.25));
    assert!(close(c.f1(), 2.0 * 0.5 * 0.25 / 0.75));
    assert!(matches!(confusion(&alarms[..3], &labels), Err(MetricsError::Length { what: "alarms", .. })));
}

#[test]
fn roc_auc_by_hand_without_ties() {
    // Positives 0.9, 0.4; negatives 0.8, 0.3, 0.1.
    // Pairs ranked correctly: (0.9 > all 3) + (0.4 > 0.3, 0.1) = 5 of 6.
    let scores = [0.9, 0.8, 0.4, 0.3, 0.1];
    let labels = [true, false, true, false, false];
    assert!(close(roc_auc(&scores, &labels).unwrap(), 5.0 / 6.0));
    // AP: thresholds 0.9 (R 1/2, P 1), 0.4 (R 1, P 2/3): 0.5 * 1 + 0.5 * 2/3.
    assert!(close(average_precision(&scores, &labels).unwrap(), 0.5 + 1.0 / 3.0));
}

#[test]
fn roc_ties_get_half_credit() {
    // All scores equal: every positive/negative pair is a tie, AUC = 0.5 exactly, and the
    // curve is the single diagonal segment (0,0) → (1,1).
    let scores = [1.0; 4];
    let labels = [true, false, true, false];
    let roc = RocCurve::new([(&scores[..], &labels[..])]).unwrap();
    assert_eq!(roc.points().len(), 2);
    assert!(close(roc.auc(), 0.5));
    // AP with one tie group: recall 0 → 1 at precision 1/2.
    assert!(close(roc.average_precision(), 0.5));

    // Mixed: positive 0.7 tied with negative 0.7, plus positive 0.9 and negative 0.1.
    // Pairs: (0.9 vs 0.7, 0.1) = 2, (0.7 vs 0.7) = 0.5, (0.7 vs 0.1) = 1 → 3.5 / 4.
    let scores = [0.9, 0.7, 0.7, 0.1];
    let labels = [true, true, false, false];
    assert!(close(roc_auc(&scores, &labels).unwrap(), 3.5 / 4.0));
}

#[test]
fn roc_rejects_nan_and_single_class() {
    assert!(matches!(
        roc_auc(&[0.1, f64::NAN], &[true, false]),
        Err(MetricsError::NonFinite { step_idx: 1, what: "score", .. })
    ));
    assert!(matches!(
        roc_auc(&[0.1, 0.2], &[false, false]),
        Err(MetricsError::MissingClass { n_attacked: 0, n_clean: 2, .. })
    ));
    // Infinite scores are legitimate (a gate may saturate).
    assert!(close(roc_auc(&[f64::INFINITY, 0.0], &[true, false]).unwrap(), 1.0));
}

#[test]
fn detection_delay_per_interval() {
    // 10 Hz; intervals [1, 4) detected at step 3 (0.2 s), [6, 8) missed, [9, 10) detected at once.
    let t: Vec<f64> = (0..10).map(|k| k as f64 * 0.1).collect();
    let labels = [false, true, true, true, false, false, true, true, false, true];
    let alarms = [true, false, false, true, true, false, false, false, false, true];
    let d = detection_delays(&t, &alarms, &labels).unwrap();
    assert_eq!(d.n_intervals, 3);
    assert_eq!(d.n_missed, 1);
    assert_eq!(d.delays_s.len(), 2);
    assert!((d.delays_s[0] - 0.2).abs() < 1e-9);
    assert!(d.delays_s[1].abs() < 1e-12);
    // Median of {0.2, 0}: 0.1; p90: 0 + 0.9 * 0.2 = 0.18.
    assert!((d.median_s().unwrap() - 0.1).abs() < 1e-9);
    assert!((d.p90_s().unwrap() - 0.18).abs() < 1e-9);
}

#[test]
fn false_alarm_events_over_clean_time() {
    // 1 s steps. Clean steps: 0, 1, 2, 5, 6, 7 (6 s). Alarm runs on clean steps: {1, 2} and {5}
    // (the alarm that starts inside the attack at step 4 and goes on at step 5 is a false
    // alarm event once the attack is over, as CUSUM's post-attack alarms in Fig. 9), and {7}.
    let t: Vec<f64> = (0..8).map(f64::from).collect();
    let labels = [false, false, false, true, true, false, false, false];
    let alarms = [false, true, true, false, true, true, false, true];
    let fa = false_alarms(&t, &alarms, &labels).unwrap();
    assert_eq!(fa.n_events, 3);
    assert!(close(fa.clean_time_s, 6.0));
    assert!(close(fa.per_minute(), 30.0));
    // {5} continues the alarm of attacked step 4: raised on a clean step are {1, 2} and {7}.
    assert_eq!(fa.n_raised_clean, 2);
    assert!(close(fa.raised_clean_per_minute(), 20.0));
}

#[test]
fn evaluate_pools_flights_without_joining_intervals() {
    // Flight A ends attacked, flight B starts attacked: two intervals, not one.
    let ta = [0.0, 1.0, 2.0];
    let tb = [10.0, 11.0, 12.0];
    let la = [false, false, true];
    let lb = [true, false, false];
    let sa = [0.1, 0.2, 0.9];
    let sb = [0.3, 0.4, 0.0];
    let aa = [false, false, true];
    let ab = [false, false, false];
    let flights = [
        FlightOutcome { t: &ta, scores: &sa, alarms: &aa, labels: &la },
        FlightOutcome { t: &tb, scores: &sb, alarms: &ab, labels: &lb },
    ];
    let e = evaluate(&flights).unwrap();
    assert_eq!(e.delays.n_intervals, 2);
    assert_eq!(e.delays.n_missed, 1);
    assert!(close(e.precision(), 1.0));
    assert!(close(e.recall(), 0.5));
    // Positives 0.9, 0.3; negatives 0.1, 0.2, 0.4, 0.0: 4 + 3 = 7 of 8 pairs.
    assert!(close(e.roc.auc(), 7.0 / 8.0));
    assert_eq!(e.false_alarms.n_events, 0);
    assert!(close(e.false_alarms.clean_time_s, 4.0));

    let bad_t = [0.0, 0.0, 1.0];
    let flights = [FlightOutcome { t: &bad_t, scores: &sa, alarms: &aa, labels: &la }];
    assert!(matches!(evaluate(&flights), Err(MetricsError::Unordered { flight_idx: 0, step_idx: 1, .. })));
}

#[test]
fn mean_and_sample_std() {
    // Values 0.90, 0.92, 0.94: mean 0.92, sample std sqrt((0.0004 + 0 + 0.0004) / 2) = 0.02.
    let m = MeanStd::new("f1", &[0.90, 0.92, 0.94]).unwrap();
    assert!((m.mean - 0.92).abs() < 1e-12);
    assert!((m.std.unwrap() - 0.02).abs() < 1e-12);
    assert_eq!(m.to_string(), "0.92 ± 0.02");
    assert_eq!(format!("{m:.3}"), "0.920 ± 0.020");
    let one = MeanStd::new("f1", &[0.5]).unwrap();
    assert_eq!(one.std, None);
    assert_eq!(one.to_string(), "0.50");
    assert!(matches!(MeanStd::new("f1", &[]), Err(MetricsError::Summary { .. })));
}

/// Mann–Whitney AUC by counting pairs, the definition the trapezoidal ROC area must equal.
fn pairwise_auc(scores: &[f64], labels: &[bool]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (i, &si) in scores.iter().enumerate() {
        for (j, &sj) in scores.iter().enumerate() {
            if labels[i] && !labels[j] {
                den += 1.0;
                num += if si > sj {
                    1.0
                } else if si == sj {
                    0.5
                } else {
                    0.0
                };
            }
        }
    }
    num / den
}

proptest! {
    #[test]
    fn roc_auc_equals_pairwise_count(
        data in proptest::collection::vec((0u8..6, any::<bool>()), 2..40)
    ) {
        // Small integer scores make ties frequent.
        let scores: Vec<f64> = data.iter().map(|(s, _)| f64::from(*s)).collect();
        let labels: Vec<bool> = data.iter().map(|(_, l)| *l).collect();
        prop_assume!(labels.iter().any(|l| *l) && labels.iter().any(|l| !*l));
        let roc = RocCurve::new([(&scores[..], &labels[..])]).unwrap();
        prop_assert!((roc.auc() - pairwise_auc(&scores, &labels)).abs() < 1e-12);
        prop_assert!((0.0..=1.0).contains(&roc.average_precision()));
        // The curve is monotone from (0, 0) to (1, 1).
        let p = roc.points();
        prop_assert_eq!((p[0].fpr, p[0].tpr), (0.0, 0.0));
        prop_assert!((p[p.len() - 1].fpr - 1.0).abs() < EPS && (p[p.len() - 1].tpr - 1.0).abs() < EPS);
        prop_assert!(p.windows(2).all(|w| w[1].fpr >= w[0].fpr && w[1].tpr >= w[0].tpr));
    }

    #[test]
    fn reversing_scores_mirrors_auc(
        data in proptest::collection::vec((0u8..6, any::<bool>()), 2..40)
    ) {
        let scores: Vec<f64> = data.iter().map(|(s, _)| f64::from(*s)).collect();
        let neg: Vec<f64> = scores.iter().map(|s| -s).collect();
        let labels: Vec<bool> = data.iter().map(|(_, l)| *l).collect();
        prop_assume!(labels.iter().any(|l| *l) && labels.iter().any(|l| !*l));
        let a = roc_auc(&scores, &labels).unwrap();
        let b = roc_auc(&neg, &labels).unwrap();
        prop_assert!((a + b - 1.0).abs() < 1e-12);
    }
}

#[test]
fn result_types_are_send_and_sync() {
    fn assert_send_sync<T: Send + Sync>() {}
    assert_send_sync::<RocCurve>();
    assert_send_sync::<MeanStd>();
    assert_send_sync::<MetricsError>();
    assert_send_sync::<eval::metrics::Evaluation>();
    assert_send_sync::<eval::table::ResultRow>();
    assert_send_sync::<eval::table::TableError>();
    assert_send_sync::<eval::plot::PlotError>();
}
