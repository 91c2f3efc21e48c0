//! Prints the textbook thresholds of the statistical baselines for 3 (GPS) and 6 (Model I)
//! channels, and the settings the validation-F1 fit chooses on a synthetic split, as the
//! Markdown tables of docs/baselines.md.
//!
//! `cargo run -p baselines --example textbook_thresholds`

use baselines::sprt::wald_thresholds;
use baselines::stats::{chi2_cdf, chi2_quantile, cusum_tau_for_far};
use baselines::synthetic::{SyntheticAttack, SyntheticFlight};
use baselines::{BhtConfig, Chi2Config, CusumConfig, Px4GateConfig, SprtConfig};
use detection_metrics::Confusion;
use ekf_residue::{Detector, Fit, LabelledResidues};

fn split(seeds: &[u64], bias_m: f64) -> Result<LabelledResidues, Box<dyn std::error::Error>> {
    let attacks: Vec<SyntheticAttack> = (0..10)
        .map(|i| {
            let start_s = 30.0 + 60.0 * f64::from(i);
            SyntheticAttack { start_s, end_s: start_s + 5.0, bias_m: [bias_m, 0.0, 0.0], absorb_tau_s: None }
        })
        .collect();
    let flights =
        seeds.iter().map(|&s| SyntheticFlight::new(6000, s).generate(&attacks)).collect::<Result<Vec<_>, _>>()?;
    Ok(LabelledResidues::new(flights)?)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    println!(
        "| m | chi2 alpha (1% FAR) | CUSUM b = 1.5m | CUSUM tau (1% FAR) | SPRT A, B (a = b = 1%) | BHT gamma (N = 1, 1% FAR) |"
    );
    println!("|---|---|---|---|---|---|");
    for m in [3.0, 6.0] {
        let b = 1.5 * m;
        let tau = cusum_tau_for_far(&|x| chi2_cdf(m, x), b, 0.01, 150)?;
        let (a_up, b_low) = wald_thresholds(0.01, 0.01);
        let alpha = chi2_quantile(m, 0.99)?;
        println!("| {m} | {alpha:.3} | {b:.1} | {tau:.3} | {a_up:.3}, {b_low:.3} | {alpha:.3} |");
    }
    println!();
    println!("Validation-F1 settings on synthetic flights (6 channels, sigma_gps 0.7 m, 5 s bursts of a gps_x bias):");
    println!();
    println!("| bias | detector | chosen setting | test P | test R | test F1 |");
    println!("|---|---|---|---|---|---|");
    for bias in [2.1, 20.0] {
        let (train, valid, test) = (split(&[1], bias)?, split(&[2], bias)?, split(&[3], bias)?);
        let f1 = |d: &dyn Detector| -> Result<Confusion, Box<dyn std::error::Error>> {
            let mut c = Confusion::default();
            for f in test.flights() {
                c.add(Confusion::count(&d.detect(f.series())?, f.labels().ok_or("labels")?));
            }
            Ok(c)
        };
        let chi2 = Chi2Config::default().fit(&train, &valid)?;
        let cusum = CusumConfig::default().fit(&train, &valid)?;
        let sprt = SprtConfig::default().fit(&train, &valid)?;
        let bht = BhtConfig::default().fit(&train, &valid)?;
        let px4 = Px4GateConfig::default().fit(&train, &valid)?;
        let rows: Vec<(&dyn Detector, String)> = vec![
            (&chi2, format!("alpha = {:.2}", chi2.alpha())),
            (&cusum, format!("b = {:.2}, tau = {:.2}", cusum.b(), cusum.tau())),
            (&sprt, format!("delta = {}, (a, b) = {:?}", sprt.delta(), sprt.alpha_beta())),
            (&bht, format!("N = {}, gamma = {:.2}", bht.n_samples(), bht.threshold())),
            (&px4, format!("gamma = {}", px4.gamma())),
        ];
        for (d, setting) in rows {
            let c = f1(d)?;
            println!(
                "| {bias} m | {} | {setting} | {:.3} | {:.3} | {:.3} |",
                d.name(),
                c.precision(),
                c.recall(),
                c.f1()
            );
        }
    }
    Ok(())
}
