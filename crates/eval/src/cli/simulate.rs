//! `quadformer simulate`: flight config (TOML) → flight directory (docs/data-format.md).
//!
//! Pipeline: build the reference trajectory, simulate truth and sensor streams
//! (`uav_dynamics::sim::simulate`), plan each configured attack in its share of the flight and
//! inject it into the GPS stream (paper eq:fdi, `attack_inject`), then write the flight
//! directory atomically with the fully explicit config it was made from.

use std::path::{Path, PathBuf};

use attack_inject::{AttackPlan, inject};
use uav_dynamics::Flight;

use crate::cli::CliError;
use crate::io::{
    AttackRecord, CONFIG_FILE, FlightConfig, FlightDir, Input, Output, Overwrite, SeedStream, check_dir_output,
    check_outputs, write_flight_dir,
};

/// Arguments of `quadformer simulate`.
#[derive(Debug, clap::Args)]
pub struct Args {
    /// Flight config (TOML; docs/data-format.md "Flight config"). Keys left out keep their
    /// defaults; an empty file is a clean eight-shape flight.
    #[arg(long, value_name = "FILE.toml", required_unless_present = "print_default_config")]
    pub config: Option<PathBuf>,
    /// Output flight directory (created atomically; must not exist or be empty unless --force).
    #[arg(long, value_name = "DIR", required_unless_present = "print_default_config")]
    pub out: Option<PathBuf>,
    /// Override the config's master seed (at most 2^63 − 1: the seed is written to config.toml,
    /// whose integers are signed 64-bit).
    #[arg(long, value_parser = clap::value_parser!(u64).range(..=crate::io::MAX_SEED))]
    pub seed: Option<u64>,
    /// Replace DIR if it exists (the old directory is removed only after the new one is complete).
    #[arg(long)]
    pub force: bool,
    /// Do not write truth.csv (e.g. to keep a committed fixture small).
    #[arg(long)]
    pub no_truth: bool,
    /// Print the default config with every field explicit, and exit.
    #[arg(long)]
    pub print_default_config: bool,
}

/// Runs `quadformer simulate`.
///
/// # Errors
/// [`CliError`] naming the config field or file concerned.
pub fn run(args: &Args) -> Result<(), CliError> {
    if args.print_default_config {
        print!("{}", FlightConfig::default().to_toml(Path::new("<default>"))?);
        return Ok(());
    }
    let (Some(config), Some(out)) = (&args.config, &args.out) else {
        return Err(CliError::Input { path: PathBuf::from("."), msg: "--config and --out are required".into() });
    };
    let overwrite = if args.force { Overwrite::Replace } else { Overwrite::Refuse };
    check_outputs(&[Input::new("--config", config)], &[Output::dir("--out", out)])?;
    check_dir_output(out, overwrite)?;
    let mut cfg = FlightConfig::load(config)?;
    if let Some(seed) = args.seed {
        cfg.seed = seed;
    }
    let mut flight = simulate_flight(config, &cfg)?;
    if args.no_truth {
        flight.truth = None;
    }
    write_flight_dir(out, &flight, overwrite)?;
    let n_attacked = flight.attack.as_ref().map_or(0, |a| a.iter().filter(|r| r.label).count());
    eprintln!(
        "wrote {}: {} IMU, {} GPS ({} attacked), {} attitude, {} VO samples",
        out.display(),
        flight.streams.imu.len(),
        flight.streams.gps.len(),
        n_attacked,
        flight.streams.attitude.len(),
        flight.streams.vo.len()
    );
    Ok(())
}

/// Simulates one flight from a config: truth, sensor streams with the attacked GPS, attack
/// records (one per GPS fix, always present so that labels are explicit) and the config with
/// its resolved duration. `config_path` is only used in error messages.
///
/// # Errors
/// [`CliError::Config`] for an invalid trajectory, simulator or attack setting (naming the
/// field); [`CliError::Attack`] if an attack plan does not fit its share of the flight.
pub fn simulate_flight(config_path: &Path, cfg: &FlightConfig) -> Result<FlightDir, CliError> {
    let config_err = |section: &str, e: &dyn std::fmt::Display| CliError::Config {
        path: config_path.to_owned(),
        msg: format!("[{section}]: {e}"),
    };
    if let Some(d) = cfg.duration_s
        && !(d.is_finite() && d > 0.0)
    {
        return Err(config_err("top level", &format!("duration_s must be positive, got {d}")));
    }
    let traj = cfg
        .trajectory
        .build(cfg.duration_s, cfg.sub_seed(SeedStream::Route))
        .map_err(|e| config_err("trajectory", &e))?;
    let duration_s = cfg.duration_s.unwrap_or_else(|| traj.duration_s());
    let Flight { mut streams, truth } =
        uav_dynamics::sim::simulate(&cfg.sim, traj.as_ref(), duration_s, cfg.sub_seed(SeedStream::Sim))
            .map_err(|e| config_err("sim", &e))?;

    let mut intervals = Vec::new();
    if let (Some(first), Some(last)) = (streams.gps.first(), streams.gps.last()) {
        let n = cfg.attacks.len();
        #[allow(clippy::cast_precision_loss)] // a handful of attacks
        let share = (last.t - first.t) / n.max(1) as f64;
        for (i, attack) in cfg.attacks.iter().enumerate() {
            let valid = attack.check().map_err(|e| config_err(&format!("attacks {}", i + 1), &e))?;
            #[allow(clippy::cast_precision_loss)]
            let t0 = first.t + share * i as f64;
            let seed = cfg.sub_seed(SeedStream::Attack(u32::try_from(i).unwrap_or(u32::MAX)));
            let plan = AttackPlan::sample(&valid, t0, t0 + share, seed)
                .map_err(|e| config_err(&format!("attacks {}", i + 1), &e))?;
            if plan.intervals().is_empty() && attack.attacked_fraction > 0.0 {
                let [d_min, _] = attack.durations.of(attack.kind);
                return Err(config_err(
                    &format!("attacks {}", i + 1),
                    &format!(
                        "no {} interval fits: {:.3} s attacked of a {share:.3} s share is less than half the \
                         minimum duration {d_min} s; raise attacked_fraction or duration_s, or shorten durations",
                        attack.kind.name(),
                        attack.attacked_fraction * share
                    ),
                ));
            }
            intervals.extend_from_slice(plan.intervals());
        }
    }
    let plan = AttackPlan::from_intervals(intervals)?;
    let attacked = inject(&streams.gps, &plan)?;
    let attack = attacked
        .gps
        .iter()
        .zip(&attacked.offset)
        .zip(&attacked.labels)
        .map(|((g, d), &label)| AttackRecord { t: g.t, label, d: *d })
        .collect();
    streams.gps = attacked.gps;

    let used = FlightConfig { duration_s: Some(duration_s), ..cfg.clone() };
    let config_toml = used.to_toml(&config_path.with_file_name(CONFIG_FILE))?;
    Ok(FlightDir {
        streams,
        truth: Some(truth),
        attack: Some(attack),
        config_toml: Some(config_toml),
        filter_toml: None,
    })
}
