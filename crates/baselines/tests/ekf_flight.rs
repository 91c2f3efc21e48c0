//! The statistical baselines on residues of the real Model I EKF (`ekf_residue`) over a
//! simulated eight-shape flight (`uav_dynamics`), with a 20 m GPS bias held from 20 s to 40 s
//! and fused by the filter, which then absorbs it: the paper's Fig. 9 (fig:CUSUM_3_plots)
//! setting without the synthetic stand-in.

use baselines::{BhtConfig, Chi2Config, CusumConfig, Px4GateConfig, SprtConfig, Tuning};
use ekf_residue::residues::{FilterConfig, ModelKind, generate_residues};
use ekf_residue::{Detector, Fit, LabelledResidues, LabelledSeries, ResidueSeries};
use uav_dynamics::sim::{SimConfig, simulate};
use uav_dynamics::trajectory::{ShapeConfig, eight};

type TestResult = Result<(), Box<dyn std::error::Error>>;

const ATTACK: (f64, f64) = (20.0, 40.0);

fn residues(seed: u64, bias_m: f64) -> Result<LabelledSeries, Box<dyn std::error::Error>> {
    let sim = SimConfig::default();
    let traj = eight(&ShapeConfig::default())?;
    let mut flight = simulate(&sim, &traj, 60.0, seed)?;
    for g in &mut flight.streams.gps {
        if g.t >= ATTACK.0 && g.t < ATTACK.1 {
            g.p[0] += bias_m;
        }
    }
    let out = generate_residues(&flight.streams, &FilterConfig::for_sim(ModelKind::ModelI, &sim))?;
    let series: ResidueSeries = out.series;
    let labels = series.t().iter().map(|t| bias_m != 0.0 && *t >= ATTACK.0 && *t < ATTACK.1).collect();
    Ok(LabelledSeries::new(series, Some(labels))?)
}

#[test]
fn textbook_detectors_flag_a_fused_20_m_bias_and_cusum_keeps_alarming_after_it() -> TestResult {
    let clean = LabelledResidues::new(vec![residues(1, 0.0)?])?;
    let attacked = residues(2, 20.0)?;
    let series = attacked.series();
    let tb = Tuning::Textbook;
    let dets: Vec<Box<dyn Detector>> = vec![
        Box::new(Chi2Config { tuning: tb, ..Default::default() }.fit(&clean, &clean)?),
        Box::new(CusumConfig { tuning: tb, ..Default::default() }.fit(&clean, &clean)?),
        Box::new(SprtConfig { tuning: tb, ..Default::default() }.fit(&clean, &clean)?),
        Box::new(BhtConfig { tuning: tb, ..Default::default() }.fit(&clean, &clean)?),
        Box::new(Px4GateConfig { tuning: tb, ..Default::default() }.fit(&clean, &clean)?),
    ];
    let in_window = |lo: f64, hi: f64| -> Vec<usize> {
        (0..series.len()).filter(|&k| series.t()[k] >= lo && series.t()[k] < hi).collect()
    };
    let onset = in_window(ATTACK.0, ATTACK.0 + 1.0);
    let after = in_window(ATTACK.1, ATTACK.1 + 3.0);
    for det in &dets {
        let alarms = det.detect(series)?;
        let n_onset = onset.iter().filter(|&&k| alarms[k]).count();
        let n_after = after.iter().filter(|&&k| alarms[k]).count();
        eprintln!(
            "{}: {n_onset}/{} onset alarms, {n_after}/{} alarms in the 3 s after the attack",
            det.name(),
            onset.len(),
            after.len()
        );
        assert!(n_onset * 2 >= onset.len(), "{} misses the onset of a 20 m bias", det.name());
        let clean_alarms = det.detect(clean.flights()[0].series())?;
        let far = clean_alarms.iter().filter(|&&a| a).count() as f64 / clean_alarms.len() as f64;
        eprintln!("{}: false-alarm rate {far:.4} on the clean flight ({} steps)", det.name(), clean_alarms.len());
        // Designed for 1 %; 5 % leaves room for 600 steps and a filter that is not exactly
        // consistent (recorded run: 0 to 1.7 %).
        assert!(far <= 0.05, "{}: false-alarm rate {far} on the clean EKF flight", det.name());
        if det.name().starts_with("CUSUM") {
            // fig:CUSUM_3_plots: the filter absorbed the bias, so the clean steps after the
            // attack carry the opposite offset and CUSUM keeps alarming.
            assert!(n_after * 2 >= after.len(), "CUSUM alarms should persist after the attack ends");
        }
    }
    Ok(())
}
