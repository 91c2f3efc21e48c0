//! `quadformer inject`: one GPS attack on a recorded flight (a PX4 ULog or a flight directory)
//! → a labelled flight directory that `residues`, `detect` and `fuse` read.
//!
//! The attack is one interval `(start, start + duration]` of the project's attack models
//! (`attack_inject::AttackShape`, paper Eq. of the false data injection `ỹ_k = y_k + d_k`):
//!
//! | `--attack` | offset `d_k` |
//! |---|---|
//! | `bias` | constant `amplitude · u` (Attack II) |
//! | `sparse` | one burst of a constant `amplitude · u` (Attack I) |
//! | `ramp` | `slope · (t − start) · u`; without `--slope`, reaching `amplitude · u` at the end |
//! | `oscillating` | `amplitude · u · sin(2π f (t − start))`, `f` from `--freq-hz` |
//! | `replay` | the fix of `--delay-s` earlier |
//! | `freeze` | the last fix before `start` |
//!
//! `u` is `--direction` normalised, or a horizontal direction drawn from `--seed`. The output
//! holds the attacked `gps.csv`, `attack.csv` (offset and label per fix) and every other
//! stream and file of the input; a ULog's receiver accuracy goes to `filter.toml`.

use std::path::PathBuf;

use attack_inject::{AttackInterval, AttackPlan, AttackShape, inject};
use nalgebra::Vector3;
use rand::{RngExt as _, SeedableRng as _, rngs::StdRng};

use crate::cli::CliError;
use crate::io::{AttackRecord, Input, Output, Overwrite, check_dir_output, check_outputs, write_flight_dir};

/// The attack models `inject` applies.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum AttackArg {
    /// Constant offset for the whole interval (Attack II bias).
    Bias,
    /// One burst of a constant offset (Attack I).
    Sparse,
    /// Offset growing linearly (drift spoofing).
    Ramp,
    /// Sinusoidal offset.
    Oscillating,
    /// Re-send the fixes of `--delay-s` earlier.
    Replay,
    /// Repeat the last fix before the interval.
    Freeze,
}

/// Arguments of `quadformer inject`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// The recorded flight: a PX4 ULog file or a flight directory (without attacks).
    #[arg(long = "in", value_name = "LOG.ulg|DIR")]
    pub input: PathBuf,
    /// Attack model.
    #[arg(long, value_enum)]
    pub attack: AttackArg,
    /// Start of the attack, seconds on the flight's clock (a ULog's first IMU sample is 0).
    #[arg(long, value_name = "S")]
    pub start: f64,
    /// Duration of the attack, seconds.
    #[arg(long, value_name = "D")]
    pub duration: f64,
    /// Offset size, metres: the bias and burst offset, the oscillation's peak, the ramp's end
    /// offset when --slope is not given (not used by replay and freeze).
    #[arg(long, value_name = "M", default_value_t = 10.0)]
    pub amplitude: f64,
    /// Ramp slope, metres per second (overrides --amplitude for ramps).
    #[arg(long, value_name = "M_PER_S")]
    pub slope: Option<f64>,
    /// Oscillation frequency, Hz.
    #[arg(long, value_name = "HZ", default_value_t = 0.2)]
    pub freq_hz: f64,
    /// Replay delay, seconds.
    #[arg(long, value_name = "S", default_value_t = 5.0)]
    pub delay_s: f64,
    /// Offset direction in ENU as `E,N,U` (normalised); default: horizontal, drawn from --seed.
    #[arg(long, value_name = "E,N,U", value_delimiter = ',', allow_hyphen_values = true)]
    pub direction: Option<Vec<f64>>,
    /// Seed of the drawn direction.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// How a recorded flight is read.
    #[command(flatten)]
    pub read: crate::cli::FlightReadArgs,
    /// Output flight directory (created atomically; must not exist or be empty unless --force).
    #[arg(long, value_name = "DIR")]
    pub out: PathBuf,
    /// Replace DIR if it exists.
    #[arg(long)]
    pub force: bool,
}

/// The unit direction `u` of the offset.
fn direction(args: &Args) -> Result<Vector3<f64>, CliError> {
    let bad = |msg: String| CliError::Input { path: PathBuf::from("--direction"), msg };
    match &args.direction {
        Some(v) => {
            let [e, n, up] = v.as_slice() else {
                return Err(bad(format!("{v:?}: three components E,N,U are required")));
            };
            let u = Vector3::new(*e, *n, *up);
            let n = u.norm();
            if !(n.is_finite() && n > 0.0) {
                return Err(bad(format!("{v:?} is not a direction (finite, not zero)")));
            }
            Ok(u / n)
        }
        None => {
            let a = StdRng::seed_from_u64(args.seed).random_range(0.0..std::f64::consts::TAU);
            Ok(Vector3::new(a.cos(), a.sin(), 0.0))
        }
    }
}

/// The attack interval the arguments describe.
fn interval(args: &Args) -> Result<AttackInterval, CliError> {
    let bad = |flag: &str, msg: String| CliError::Input { path: PathBuf::from(flag), msg };
    let finite_pos = |flag: &str, v: f64| {
        if v.is_finite() && v > 0.0 { Ok(v) } else { Err(bad(flag, format!("must be finite and > 0, got {v}"))) }
    };
    if !(args.start.is_finite() && args.start >= 0.0) {
        return Err(bad("--start", format!("must be finite and ≥ 0, got {}", args.start)));
    }
    let duration = finite_pos("--duration", args.duration)?;
    let u = direction(args)?;
    let amplitude = || finite_pos("--amplitude", args.amplitude);
    let shape = match args.attack {
        AttackArg::Bias => AttackShape::Bias { offset: u * amplitude()? },
        AttackArg::Sparse => AttackShape::Burst { offset: u * amplitude()? },
        AttackArg::Ramp => {
            let end = match args.slope {
                Some(s) => finite_pos("--slope", s)? * duration,
                None => amplitude()?,
            };
            AttackShape::Ramp { offset_end: u * end }
        }
        AttackArg::Oscillating => {
            AttackShape::Oscillating { amplitude: u * amplitude()?, freq_hz: finite_pos("--freq-hz", args.freq_hz)? }
        }
        AttackArg::Replay => AttackShape::Replay { delay_s: finite_pos("--delay-s", args.delay_s)? },
        AttackArg::Freeze => AttackShape::Freeze,
    };
    Ok(AttackInterval { t0: args.start, t1: args.start + duration, shape })
}

/// Runs `quadformer inject`.
///
/// # Errors
/// [`CliError`] naming the flag, the input (a ULog without the needed topics lists the topics
/// it has; a flight that is already attacked) or the output.
pub fn run(args: &Args) -> Result<(), CliError> {
    let overwrite = if args.force { Overwrite::Replace } else { Overwrite::Refuse };
    check_outputs(&[Input::new("--in", &args.input)], &[Output::dir("--out", &args.out)])?;
    check_dir_output(&args.out, overwrite)?;
    let iv = interval(args)?;
    let mut flight = args.read.read(&args.input)?;
    if flight.attack.as_ref().is_some_and(|a| a.iter().any(|r| r.label)) {
        return Err(CliError::Input {
            path: args.input.clone(),
            msg: "already has attacked fixes in attack.csv; inject into a clean flight".into(),
        });
    }
    let gps = &flight.streams.gps;
    let (t_first, t_last) = match (gps.first(), gps.last()) {
        (Some(a), Some(b)) => (a.t, b.t),
        _ => return Err(CliError::Input { path: args.input.clone(), msg: "has no GPS fixes to attack".into() }),
    };
    if iv.t0 >= t_last || iv.t1 <= t_first {
        return Err(CliError::Input {
            path: PathBuf::from("--start"),
            msg: format!(
                "the attack ({}–{} s) misses the GPS fixes, which span {t_first:.3}–{t_last:.3} s",
                iv.t0, iv.t1
            ),
        });
    }
    let plan = AttackPlan::from_intervals(vec![iv])?;
    let attacked = inject(gps, &plan)?;
    let records: Vec<AttackRecord> = attacked
        .gps
        .iter()
        .zip(&attacked.offset)
        .zip(&attacked.labels)
        .map(|((g, d), &label)| AttackRecord { t: g.t, label, d: *d })
        .collect();
    let n_attacked = attacked.labels.iter().filter(|&&l| l).count();
    flight.streams.gps = attacked.gps;
    flight.attack = Some(records);
    write_flight_dir(&args.out, &flight, overwrite)?;
    eprintln!(
        "wrote {}: {} GPS fixes, {n_attacked} attacked ({:?} on {}–{} s)",
        args.out.display(),
        flight.streams.gps.len(),
        args.attack,
        iv.t0,
        iv.t1
    );
    Ok(())
}
