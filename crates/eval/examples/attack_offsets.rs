//! How large the spoofed offsets of the closed-loop experiment's test flights are (Table III,
//! docs/decisions/091-closed-loop.md): per attack family, the share of attacked fixes whose
//! offset `‖d_k‖` reaches 0.5, 1, 2 and 3 m, and the per-fix F1 of a detector that alarms on
//! exactly those fixes (precision 1, recall the share). A drift starts at zero offset, so its
//! first fixes are within the GPS noise (σ = 0.5 m horizontally); a detector that cannot tell
//! an offset under a metre from noise is bounded by the F1 printed for 1 m.
//!
//! ```text
//! cargo run --release -p eval --example attack_offsets [-- [--seeds N] [--quick]]
//! ```
//!
//! The shares pool every unit of the matrix (both models and noise shapes, every seed), with
//! the flights, attacks and seeds of `reproduce-tables` (of `--quick` with `--quick`). Only
//! the attack plans are drawn and injected into the clean fixes (`attack_inject::inject`);
//! nothing is flown or fitted, so it takes under a minute.

use anyhow::{Context, Result};
use attack_inject::inject;
use eval::closed_loop::{Family, family_dataset, units};
use eval::dataset::{Split, plan_split};

mod common;

/// Offsets, metres, at which the shares are taken.
const LEVELS_M: [f64; 4] = [0.5, 1.0, 2.0, 3.0];

fn main() -> Result<()> {
    let opts = common::loop_options("attack_offsets")?;
    print!("| family | attacked fixes |");
    for l in LEVELS_M {
        print!(" ≥ {l} m: share / F1 |");
    }
    println!();
    println!("|---|---|{}", "---|".repeat(LEVELS_M.len()));
    let units = units(&opts);
    for family in Family::ALL {
        let mut offsets = Vec::new();
        for &unit in &units {
            let cfg = family_dataset(unit, family, &opts).check().with_context(|| {
                format!("model {} {} seed {} {}", unit.model.roman(), unit.noise.name(), unit.seed, family.name())
            })?;
            for f in plan_split(&cfg, Split::Test)? {
                let sent = inject(&f.flight.streams.gps, &f.plan)?;
                offsets.extend(sent.offset.iter().zip(&sent.labels).filter(|(_, a)| **a).map(|(d, _)| d.norm()));
            }
        }
        print!("| {} | {} |", family.name(), offsets.len());
        for l in LEVELS_M {
            #[allow(clippy::cast_precision_loss)]
            let share = offsets.iter().filter(|&&o| o >= l).count() as f64 / offsets.len().max(1) as f64;
            print!(" {share:.2} / {:.2} |", 2.0 * share / (1.0 + share));
        }
        println!();
    }
    Ok(())
}
