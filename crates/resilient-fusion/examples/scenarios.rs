//! Runs every scenario's three cases with a NIS-gate detector and prints the metrics
//! (`cargo run --release -p resilient-fusion --example scenarios [latency_s]`).

use ekf_residue::detector::OnlineDetector;
use resilient_fusion::estimator::NisGate;
use resilient_fusion::scenario::{Scenario, ScenarioConfig, run_scenario};

fn main() -> Result<(), resilient_fusion::FusionError> {
    let mut cfg = ScenarioConfig::default();
    if let Some(l) = std::env::args().nth(1).and_then(|s| s.parse().ok()) {
        cfg.resilient.latency_s = l;
    }
    let gate = |_: usize| -> resilient_fusion::Result<Box<dyn OnlineDetector>> {
        Ok(Box::new(NisGate::new(NisGate::CHI2_3_999)?))
    };
    println!("latency {} s, hold {} s", cfg.resilient.latency_s, cfg.resilient.hold_s);
    println!(
        "| scenario | case | RMSE m | max dev m | est RMSE m | attack s | excluded s | excl. outside s | det. delay s | excl. delay s | formation RMSE m |"
    );
    println!("|---|---|---|---|---|---|---|---|---|---|---|");
    for sc in Scenario::ALL {
        for r in run_scenario(sc, &cfg, &gate)? {
            let Some(v) = r.attacked() else { continue };
            let m = v.metrics;
            let f = |x: Option<f64>| x.map_or("-".to_string(), |x| format!("{x:.2}"));
            println!(
                "| {} | {} | {:.2} | {:.2} | {:.2} | {:.1} | {:.1} | {:.1} | {} | {} | {} |",
                sc.name(),
                r.case.name(),
                m.tracking_rmse_m,
                m.tracking_max_m,
                m.estimate_rmse_m,
                m.time_under_attack_s,
                m.time_gps_excluded_s,
                m.excluded_outside_attack_s,
                f(m.detection_delay_s),
                f(m.exclusion_delay_s),
                f(r.formation.map(|x| x.shape_rmse_m)),
            );
        }
    }
    Ok(())
}
