//! What the closed-loop experiment's attacks leave to a detector that knows the true position
//! (Table III, docs/decisions/091-closed-loop.md): per attack family, the per-fix F1 of
//! textbook change tests on the GPS error `z_k = (y_k − p_k) / σ` of the test flights, where
//! `y_k` is the fix the estimator receives, `p_k` the true position and `σ` the GPS noise per
//! axis.
//!
//! An estimator knows `p_k` at best as well as the truth, so `z_k` holds the evidence a fix
//! gives, the GPS noise and the spoofed offset `d_k`, with nothing absorbed by a filter and no
//! dead-reckoning error. The tests are causal and read `z` up to the fix they decide:
//!
//! - `χ² (one fix)`: `‖z_k‖²` ([`baselines::Chi2`]'s statistic, the NIS);
//! - `GLR`: [`baselines::Glr`], the generalised likelihood ratio of an offset that began within
//!   the last `M` fixes, constant or growing linearly from zero, over Huber-clipped errors, with
//!   its end test (docs/baselines.md).
//!
//! Each test's threshold and window `M` (10, 30 or 100 fixes) are chosen per unit on the
//! validation flights of the trained families (sparse, bias, ramp) pooled, as the loop's
//! detectors are, by two rules: the best F1, and the best F1 among settings with at most 0.5
//! alarm events per clean minute (Table III's target; events as decision 060 counts them,
//! including an alarm that outlasts its attack). The table gives the test F1 per family (mean
//! over units), the alarm events per clean minute over every family's test flights, and the
//! share of those events that continue an alarm raised during an attack.
//!
//! ```text
//! cargo run --release -p eval --example glr_reference [-- [--seeds N] [--quick]]
//! ```
//!
//! The units, flights, attacks and seeds are those of `reproduce-tables` (of `--quick` with
//! `--quick`). Only the attack plans are drawn and injected; nothing is flown through a filter
//! or fitted, so it takes seconds.

use anyhow::{Context, Result, bail};
use attack_inject::inject;
use baselines::{GlrConfig, Tuning};
use detection_metrics::Confusion;
use ekf_residue::residues::GPS_CHANNELS;
use ekf_residue::{Detector, Fit, LabelledResidues, LabelledSeries, ResidueSeries};
use eval::closed_loop::{Family, LoopUnit, family_dataset, units};
use eval::dataset::{Split, plan_split};
use eval::reproduce::Options;
use nalgebra::{Matrix3, Vector3};
use rayon::prelude::*;

mod common;

/// The loop's target of alarm events per clean minute.
const EVENT_BUDGET_PER_MIN: f64 = 0.5;

/// The tests, in row order.
#[derive(Clone, Copy)]
enum Test {
    /// `‖u_k‖²`, one fix at a time (the NIS).
    Chi2,
    /// [`baselines::Glr`].
    Glr,
}

impl Test {
    const ALL: [Self; 2] = [Self::Chi2, Self::Glr];

    fn name(self) -> &'static str {
        match self {
            Self::Chi2 => "χ² (one fix)",
            Self::Glr => "GLR (constant or ramping offset)",
        }
    }

    /// The look-back windows the test chooses from on validation: the GLR test's default grid
    /// ([`GlrConfig::window_grid`]); the χ² test has none.
    fn windows(self) -> Vec<Option<usize>> {
        match self {
            Self::Chi2 => vec![None],
            Self::Glr => GlrConfig::default().window_grid.into_iter().map(Some).collect(),
        }
    }

    /// The statistic of every fix of each flight; the GLR test looks back at most `window`
    /// fixes for the onset.
    fn statistics(self, flights: &[Flight], window: Option<usize>) -> Result<Vec<Vec<f64>>> {
        let (Self::Glr, Some(window), Some(first)) = (self, window, flights.first()) else {
            return Ok(flights.iter().map(|f| f.series.nis().to_vec()).collect());
        };
        // The textbook fit only reads the channels; the window is the one asked for.
        let split = LabelledResidues::new(vec![LabelledSeries::new(first.series.clone(), None)?])?;
        let glr = GlrConfig { tuning: Tuning::Textbook, window, ..GlrConfig::default() }.fit(&split, &split)?;
        Ok(flights.iter().map(|f| glr.score(&f.series)).collect::<Result<_, _>>()?)
    }
}

/// One flight's GPS errors against the truth, as a residue series of the GPS channels with
/// `S = diag σ²`, and its labels.
struct Flight {
    family: Family,
    /// Index of `family` in [`Family::ALL`].
    family_idx: usize,
    series: ResidueSeries,
    attacked: Vec<bool>,
    dt_s: f64,
}

/// Per-fix counts of alarms against labels, and alarm events on clean fixes.
#[derive(Default, Clone, Copy)]
struct Counts {
    confusion: Confusion,
    /// Maximal runs of alarmed clean fixes (decision 060).
    events: usize,
    /// Events that continue an alarm raised during an attack (decision 060 counts them too).
    tails: usize,
    clean_s: f64,
}

impl Counts {
    fn add(&mut self, alarms: &[bool], attacked: &[bool], dt_s: f64) {
        self.confusion.add(Confusion::count(alarms, attacked));
        let (mut in_event, mut alarmed_attack) = (false, false);
        for (&a, &y) in alarms.iter().zip(attacked) {
            if !y {
                self.clean_s += dt_s;
                if a && !in_event {
                    self.events += 1;
                    self.tails += usize::from(alarmed_attack);
                }
            }
            in_event = a && !y;
            alarmed_attack = a && y;
        }
    }

    fn f1(&self) -> f64 {
        self.confusion.f1()
    }

    #[allow(clippy::cast_precision_loss)]
    fn events_per_min(&self) -> f64 {
        if self.clean_s > 0.0 { self.events as f64 * 60.0 / self.clean_s } else { 0.0 }
    }

    #[allow(clippy::cast_precision_loss)]
    fn tail_share(&self) -> f64 {
        if self.events > 0 { self.tails as f64 / self.events as f64 } else { 0.0 }
    }
}

/// A test's chosen window and threshold.
#[derive(Clone, Copy)]
struct Setting {
    window: Option<usize>,
    threshold: f64,
}

/// The settings the two rules choose on validation flights: best F1, and best F1 within the
/// event budget (`None` when no candidate keeps it, or the flights have no clean fix).
fn choose(test: Test, valid: &[Flight]) -> Result<[Option<Setting>; 2]> {
    let mut best: Option<(f64, Setting)> = None;
    let mut quiet: Option<(f64, Setting)> = None;
    for window in test.windows() {
        let stats = test.statistics(valid, window)?;
        let mut clean: Vec<f64> = stats
            .iter()
            .zip(valid)
            .flat_map(|(s, f)| s.iter().zip(&f.attacked).filter(|(_, a)| !**a).map(|(v, _)| *v))
            .collect();
        clean.sort_by(f64::total_cmp);
        let Some(&largest) = clean.last() else { continue };
        // Thresholds at clean quantiles from 0.5 up to above the largest clean value.
        let n = clean.len();
        let mut candidates: Vec<f64> = (0..400)
            .map(|i| {
                let q = 1.0 - 0.5 * (1.0 - f64::from(i) / 400.0).powi(4);
                #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss, clippy::cast_precision_loss)]
                clean[((q * n as f64) as usize).min(n - 1)]
            })
            .collect();
        candidates.push(largest * 1.000_001 + f64::EPSILON);
        candidates.dedup();
        for threshold in candidates {
            let mut c = Counts::default();
            for (s, f) in stats.iter().zip(valid) {
                let alarms: Vec<bool> = s.iter().map(|v| *v > threshold).collect();
                c.add(&alarms, &f.attacked, f.dt_s);
            }
            let setting = Setting { window, threshold };
            if best.is_none_or(|(f1, _)| c.f1() > f1) {
                best = Some((c.f1(), setting));
            }
            if c.events_per_min() <= EVENT_BUDGET_PER_MIN && quiet.is_none_or(|(f1, _)| c.f1() > f1) {
                quiet = Some((c.f1(), setting));
            }
        }
    }
    Ok([best, quiet].map(|c| c.map(|(_, s)| s)))
}

/// A unit's flights of one split, every family.
fn flights(unit: LoopUnit, split: Split, opts: &Options) -> Result<Vec<Flight>> {
    let mut out = Vec::new();
    for (family_idx, family) in Family::ALL.into_iter().enumerate() {
        let cfg = family_dataset(unit, family, opts).check().with_context(|| {
            format!("model {} {} seed {} {}", unit.model.roman(), unit.noise.name(), unit.seed, family.name())
        })?;
        let sigma = Vector3::from(cfg.get().sim.gps_sigma_m);
        let dt_s = 1.0 / f64::from(cfg.get().sim.gps_rate_hz);
        for f in plan_split(&cfg, split)? {
            let sent = inject(&f.flight.streams.gps, &f.plan)?;
            let truth = &f.flight.truth;
            if truth.is_empty() {
                bail!(
                    "model {} {} seed {} {}: a flight without truth",
                    unit.model.roman(),
                    unit.noise.name(),
                    unit.seed,
                    family.name()
                );
            }
            let (mut t, mut r) = (Vec::with_capacity(sent.gps.len()), Vec::with_capacity(3 * sent.gps.len()));
            for fix in &sent.gps {
                let i = truth.partition_point(|s| s.t < fix.t).min(truth.len().saturating_sub(1));
                let i = if i > 0 && (truth[i - 1].t - fix.t).abs() < (truth[i].t - fix.t).abs() { i - 1 } else { i };
                t.push(fix.t);
                r.extend((fix.p - truth[i].p).iter());
            }
            let s_k = Matrix3::from_diagonal(&sigma.component_mul(&sigma));
            let s = std::iter::repeat_n(s_k.iter().copied().collect::<Vec<f64>>(), t.len()).flatten().collect();
            let channels = GPS_CHANNELS.iter().map(|c| (*c).to_owned()).collect();
            let series = ResidueSeries::from_flat(t, channels, r, s)?;
            out.push(Flight { family, family_idx, series, attacked: sent.labels, dt_s });
        }
    }
    Ok(out)
}

/// Per test and rule (best F1, within the budget), a unit's test counts per family and over
/// every family (last), at the setting chosen on its validation flights.
fn unit_counts(unit: LoopUnit, opts: &Options) -> Result<Vec<[Option<Vec<Counts>>; 2]>> {
    let valid: Vec<Flight> =
        flights(unit, Split::Valid, opts)?.into_iter().filter(|f| Family::TRAINED.contains(&f.family)).collect();
    let test = flights(unit, Split::Test, opts)?;
    let mut out = Vec::new();
    for t in Test::ALL {
        let mut rules = [None, None];
        // The test flights' statistics per window, computed once for both rules.
        let mut stats: Vec<(Option<usize>, Vec<Vec<f64>>)> = Vec::new();
        for (rule, setting) in rules.iter_mut().zip(choose(t, &valid)?) {
            let Some(s) = setting else { continue };
            let at = match stats.iter().position(|(w, _)| *w == s.window) {
                Some(i) => i,
                None => {
                    stats.push((s.window, t.statistics(&test, s.window)?));
                    stats.len() - 1
                }
            };
            let mut counts = vec![Counts::default(); Family::ALL.len() + 1];
            for (f, stat) in test.iter().zip(&stats[at].1) {
                let alarms: Vec<bool> = stat.iter().map(|v| *v > s.threshold).collect();
                for c in [f.family_idx, Family::ALL.len()] {
                    counts[c].add(&alarms, &f.attacked, f.dt_s);
                }
            }
            *rule = Some(counts);
        }
        out.push(rules);
    }
    Ok(out)
}

fn main() -> Result<()> {
    let opts = common::loop_options("glr_reference")?;
    let units = units(&opts);
    // Per unit, per test, per rule: test counts per family and over every family.
    let per_unit: Vec<Vec<[Option<Vec<Counts>>; 2]>> =
        units.par_iter().map(|&unit| unit_counts(unit, &opts)).collect::<Result<_>>()?;

    print!("| test | rule |");
    for family in Family::ALL {
        print!(" {} F1 |", family.name());
    }
    println!(" alarm events / clean min | share after an attack | units |");
    println!("|---|---|{}---|---|---|", "---|".repeat(Family::ALL.len()));
    for (ti, t) in Test::ALL.iter().enumerate() {
        for (ri, rule) in ["best F1", "≤ 0.5 events / min"].iter().enumerate() {
            let rows: Vec<&Vec<Counts>> = per_unit.iter().filter_map(|u| u[ti][ri].as_ref()).collect();
            #[allow(clippy::cast_precision_loss)]
            let mean =
                |f: &dyn Fn(&Vec<Counts>) -> f64| rows.iter().map(|c| f(c)).sum::<f64>() / rows.len().max(1) as f64;
            print!("| {} | {rule} |", t.name());
            for fi in 0..Family::ALL.len() {
                print!(" {:.2} |", mean(&|c| c[fi].f1()));
            }
            let all = |c: &Vec<Counts>| c[Family::ALL.len()];
            println!(
                " {:.2} | {:.2} | {} |",
                mean(&|c| all(c).events_per_min()),
                mean(&|c| all(c).tail_share()),
                rows.len()
            );
        }
    }
    Ok(())
}
