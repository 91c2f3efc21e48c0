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
//! - `χ² (one fix)`: `‖z_k‖²`;
//! - `GLR bias + ramp`: the generalised likelihood ratio of an offset that began within the
//!   last `M` fixes, constant or growing linearly from zero (Willsky & Jones, IEEE TAC 21(1),
//!   1976; Basseville & Nikiforov, *Detection of Abrupt Changes*, 1993, §2.4), set to 0 once
//!   the newest fixes fall back from the trend of the fixes before them towards zero (the
//!   attack has ended);
//! - `GLR bias + ramp, Huber-clipped`: the same sums over `z` clipped to ±2σ per axis, so one
//!   sample of the heavy-tailed noise moves them little (the end test reads `z` unclipped).
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
use eval::cell::Cell;
use eval::closed_loop::{Family, LoopUnit, family_dataset, units};
use eval::dataset::{Split, plan_split};
use eval::reproduce::{MatrixConfig, Options, Stages};
use nalgebra::Vector3;
use rayon::prelude::*;

/// Longest onsets the GLR tests look back to, fixes; each test chooses one on validation.
const WINDOWS: [usize; 3] = [10, 30, 100];

/// The loop's target of alarm events per clean minute.
const EVENT_BUDGET_PER_MIN: f64 = 0.5;

/// Huber's clipping constant `c` of [`Test::GlrHuber`], in σ: each axis of `z` is clipped to
/// `[−c, c]` before it enters the sums (Huber, *Robust Statistics*, 1981, ψ of §4.5).
const HUBER_C: f64 = 2.0;

/// The tests, in row order.
#[derive(Clone, Copy)]
enum Test {
    /// `‖z_k‖²`, one fix at a time.
    Chi2,
    /// The larger of the constant-offset and ramp GLR statistics.
    Glr,
    /// [`Test::Glr`] over Huber-clipped errors: a heavy-tailed noise sample moves the sums
    /// by at most `c` per axis.
    GlrHuber,
}

impl Test {
    const ALL: [Self; 3] = [Self::Chi2, Self::Glr, Self::GlrHuber];

    fn name(self) -> &'static str {
        match self {
            Self::Chi2 => "χ² (one fix)",
            Self::Glr => "GLR bias + ramp",
            Self::GlrHuber => "GLR bias + ramp, Huber-clipped",
        }
    }

    fn windows(self) -> &'static [usize] {
        match self {
            Self::Chi2 => &WINDOWS[..1],
            Self::Glr | Self::GlrHuber => &WINDOWS,
        }
    }

    /// The statistic of every fix of a flight's whitened GPS errors `z`; the GLR tests look
    /// back at most `window` fixes for the onset.
    fn statistic(self, z: &[Vector3<f64>], window: usize) -> Vec<f64> {
        match self {
            Self::Chi2 => z.iter().map(Vector3::norm_squared).collect(),
            Self::Glr => glr(z, z, window),
            Self::GlrHuber => {
                let clipped: Vec<Vector3<f64>> = z.iter().map(|v| v.map(|x| x.clamp(-HUBER_C, HUBER_C))).collect();
                glr(&clipped, z, window)
            }
        }
    }
}

/// The GLR statistic of every fix: the larger of a constant offset's,
/// `max_m ‖Σ_{i<m} e_{k−i}‖² / m`, and a ramp's from zero, `max_m ‖Σ_{i<m} (m − i) e_{k−i}‖² /
/// Σ_{j≤m} j²`, over onsets `m ≤ window` fixes back, of the errors `e` (`z` or its clipped
/// form). 0 where the offset has ended at the newest fixes of `z` ([`ended`]), so an attack's
/// alarm does not outlast it by the window.
fn glr(e: &[Vector3<f64>], z: &[Vector3<f64>], window: usize) -> Vec<f64> {
    (0..e.len())
        .map(|k| {
            if ended(z, k) {
                return 0.0;
            }
            // `sum` = Σ e over the `m` newest fixes; `weighted` = Σ (m − i) e_{k−i}, which
            // grows by `sum` when the onset moves one fix earlier.
            let (mut best, mut sum, mut weighted, mut sq) = (0.0_f64, Vector3::zeros(), Vector3::zeros(), 0.0);
            for m in 1..=window.min(k + 1) {
                sum += e[k + 1 - m];
                weighted += sum;
                #[allow(clippy::cast_precision_loss)]
                let mf = m as f64;
                sq += mf * mf;
                best = best.max(sum.norm_squared() / mf).max(weighted.norm_squared() / sq);
            }
            best
        })
        .collect()
}

/// Newest fixes an ended attack is judged on.
const END_FIXES: usize = 3;

/// Fixes before them whose linear trend predicts them.
const TREND_FIXES: usize = 10;

/// χ²₃ quantile 0.999: the newest fixes' mean departure from the trend beyond it (scaled by
/// the prediction's own variance) means the offset has ended.
const END_CHI2: f64 = 16.27;

/// Whether an offset ended at the newest fixes up to `k`: their sum departs from the linear
/// trend of the `TREND_FIXES` fixes before them by more than `END_CHI2` allows, towards zero
/// (they are nearer the origin than the trend predicts). An onset moves away from zero and
/// does not count.
fn ended(z: &[Vector3<f64>], k: usize) -> bool {
    if k + 1 < END_FIXES + TREND_FIXES {
        return false;
    }
    // Least-squares line through the trend fixes, at ages t = 0..TREND_FIXES (0 oldest).
    let first = k + 1 - END_FIXES - TREND_FIXES;
    #[allow(clippy::cast_precision_loss)]
    let n = TREND_FIXES as f64;
    let t_mean = (n - 1.0) / 2.0;
    let z_mean: Vector3<f64> = (0..TREND_FIXES).map(|i| z[first + i]).sum::<Vector3<f64>>() / n;
    let (mut cov, mut var) = (Vector3::zeros(), 0.0);
    for i in 0..TREND_FIXES {
        #[allow(clippy::cast_precision_loss)]
        let dt = i as f64 - t_mean;
        cov += (z[first + i] - z_mean) * dt;
        var += dt * dt;
    }
    let slope = cov / var;
    let (mut departure, mut pred_sum, mut new_sum, mut pred_var) =
        (Vector3::zeros(), Vector3::zeros(), Vector3::zeros(), 0.0);
    for j in 0..END_FIXES {
        #[allow(clippy::cast_precision_loss)]
        let t = (TREND_FIXES + j) as f64;
        let pred = z_mean + slope * (t - t_mean);
        departure += z[first + TREND_FIXES + j] - pred;
        pred_sum += pred;
        new_sum += z[first + TREND_FIXES + j];
        pred_var += 1.0 / n + (t - t_mean).powi(2) / var;
    }
    #[allow(clippy::cast_precision_loss)]
    let r = END_FIXES as f64;
    // Variance of the summed departure per axis: r fixes of unit noise plus the prediction's.
    let stat = departure.norm_squared() / (r + pred_var * r);
    stat > END_CHI2 && new_sum.norm() < pred_sum.norm()
}

/// One flight's whitened GPS errors and labels.
struct Flight {
    family: Family,
    z: Vec<Vector3<f64>>,
    attacked: Vec<bool>,
    dt_s: f64,
}

/// Per-fix counts of alarms against labels, and alarm events on clean fixes.
#[derive(Default, Clone, Copy)]
struct Counts {
    tp: usize,
    fp: usize,
    fn_: usize,
    events: usize,
    /// Events that continue an alarm raised during an attack (decision 060 counts them).
    tails: usize,
    clean_s: f64,
}

impl Counts {
    fn add(&mut self, alarms: impl Iterator<Item = bool>, attacked: &[bool], dt_s: f64) {
        let (mut in_event, mut alarmed_attack) = (false, false);
        for (a, &y) in alarms.zip(attacked) {
            match (a, y) {
                (true, true) => self.tp += 1,
                (true, false) => self.fp += 1,
                (false, true) => self.fn_ += 1,
                (false, false) => {}
            }
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

    #[allow(clippy::cast_precision_loss)]
    fn f1(&self) -> f64 {
        let denom = 2 * self.tp + self.fp + self.fn_;
        if denom == 0 { 0.0 } else { 2.0 * self.tp as f64 / denom as f64 }
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
    window: usize,
    threshold: f64,
}

/// The settings the two rules choose on validation flights: best F1, and best F1 within the
/// event budget (`None` when no candidate keeps it, or the flights have no clean fix).
fn choose(test: Test, valid: &[Flight]) -> [Option<Setting>; 2] {
    let mut best: Option<(f64, Setting)> = None;
    let mut quiet: Option<(f64, Setting)> = None;
    for &window in test.windows() {
        let stats: Vec<Vec<f64>> = valid.iter().map(|f| test.statistic(&f.z, window)).collect();
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
                c.add(s.iter().map(|v| *v > threshold), &f.attacked, f.dt_s);
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
    [best, quiet].map(|c| c.map(|(_, s)| s))
}

/// A unit's flights of one split, every family.
fn flights(unit: LoopUnit, split: Split, opts: &Options) -> Result<Vec<Flight>> {
    let mut out = Vec::new();
    for family in Family::ALL {
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
            let z = sent
                .gps
                .iter()
                .map(|fix| {
                    let i = truth.partition_point(|s| s.t < fix.t).min(truth.len().saturating_sub(1));
                    let i =
                        if i > 0 && (truth[i - 1].t - fix.t).abs() < (truth[i].t - fix.t).abs() { i - 1 } else { i };
                    (fix.p - truth[i].p).component_div(&sigma)
                })
                .collect();
            out.push(Flight { family, z, attacked: sent.labels, dt_s });
        }
    }
    Ok(out)
}

fn main() -> Result<()> {
    let (mut seeds, mut quick) = (3u64, false);
    let mut args = std::env::args().skip(1);
    while let Some(flag) = args.next() {
        match flag.as_str() {
            "--seeds" => {
                let v = args.next().context("--seeds needs a value")?;
                seeds = v.parse().with_context(|| format!("--seeds {v}"))?;
            }
            "--quick" => quick = true,
            other => bail!("unknown option {other}; usage: glr_reference [--seeds N] [--quick]"),
        }
    }
    let opts = Options {
        config: if quick { MatrixConfig::quick() } else { MatrixConfig::default() },
        quick,
        seeds,
        cells: Cell::table_cells(),
        methods: vec![],
        out: "results".into(),
        progress: false,
        stages: Stages::ClosedLoop,
    };
    let units = units(&opts);
    // Per unit, per test, per rule: test counts per family and over every family.
    let per_unit: Vec<Vec<[Option<Vec<Counts>>; 2]>> = units
        .par_iter()
        .map(|&unit| -> Result<_> {
            let valid: Vec<Flight> = flights(unit, Split::Valid, &opts)?
                .into_iter()
                .filter(|f| Family::TRAINED.contains(&f.family))
                .collect();
            let test = flights(unit, Split::Test, &opts)?;
            Ok(Test::ALL
                .iter()
                .map(|&t| {
                    choose(t, &valid).map(|s| {
                        s.map(|s| {
                            let mut counts = vec![Counts::default(); Family::ALL.len() + 1];
                            for f in &test {
                                let alarms = t.statistic(&f.z, s.window);
                                let family = Family::ALL.iter().position(|x| *x == f.family).unwrap_or(0);
                                for c in [family, Family::ALL.len()] {
                                    counts[c].add(alarms.iter().map(|v| *v > s.threshold), &f.attacked, f.dt_s);
                                }
                            }
                            counts
                        })
                    })
                })
                .collect())
        })
        .collect::<Result<_>>()?;

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
