//! The flight config of `quadformer simulate` (TOML, docs/data-format.md "Flight config"): it
//! composes the configs the lower crates define, each a serde type with
//! `deny_unknown_fields`, so a misspelt key is an error naming it.
//!
//! ```toml
//! seed = 7              # every random draw of the flight derives from it
//! duration_s = 60.0     # optional; default: the trajectory's own duration
//!
//! [trajectory]
//! kind = "eight"        # eight | ust | diagonal | square | formation | random
//!
//! [sim.noise]
//! shape = "Laplace"     # Gaussian | Exponential | Laplace (uav_dynamics::noise::NoiseConfig)
//!
//! [[attacks]]           # zero or more; attack i is planned in the i-th equal share of the flight
//! kind = "sparse"       # attack_inject::AttackConfig
//! ```

use std::path::Path;

use attack_inject::AttackConfig;
use serde::{Deserialize, Serialize};
use uav_dynamics::sim::SimConfig;
use uav_dynamics::trajectory::{self, RandomRouteConfig, ShapeConfig, Trajectory};

use crate::io::atomic::write_text_atomic;
use crate::io::error::{IoError, Result};
use crate::io::toml_merge::merge_over;

/// Which reference trajectory to fly (paper sec. "Simulation Experiment" and "Real-world
/// Experiment"; random routes are the training flights of sec. "Attack Scenario and Training
/// Details").
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrajectoryKind {
    /// Eight-shape, two loops (fig:simu1).
    Eight,
    /// The letters U, S, T (fig:simu2).
    Ust,
    /// Corner to corner (fig:real1).
    Diagonal,
    /// Counter-clockwise square returning home.
    Square,
    /// One vehicle of the four-UAV square formation (fig:simu3), see
    /// [`TrajectoryConfig::formation_index`].
    Formation,
    /// A long random smooth route (seeded), as used for training flights.
    Random,
}

/// The trajectory section of a [`FlightConfig`].
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrajectoryConfig {
    /// Which trajectory. Default `eight` (the paper's first simulated scenario, fig:simu1).
    pub kind: TrajectoryKind,
    /// Size, altitude, speed and hover time of the scenario shapes (all but `random`).
    /// Default `uav_dynamics::trajectory::ShapeConfig::default()` (20 m, 10 m altitude, 3 m/s,
    /// 3 s hover; docs/decisions/021-trajectories.md). Keys left out keep their defaults.
    #[serde(default)]
    pub shape: ShapeConfig,
    /// Vehicle of the formation, 0..=3 counter-clockwise from the lower left. Default 2 (the
    /// paper's "UAV 3", the attacked one in fig:simu3).
    #[serde(default = "default_formation_index")]
    pub formation_index: usize,
    /// Parameters of `random` routes. Default `RandomRouteConfig::default()`
    /// (docs/decisions/021-trajectories.md); its `duration_s` is replaced by the flight's.
    /// Give the whole table or none.
    #[serde(default)]
    pub random: RandomRouteConfig,
}

const fn default_formation_index() -> usize {
    2
}

impl Default for TrajectoryConfig {
    fn default() -> Self {
        Self {
            kind: TrajectoryKind::Eight,
            shape: ShapeConfig::default(),
            formation_index: default_formation_index(),
            random: RandomRouteConfig::default(),
        }
    }
}

impl TrajectoryConfig {
    /// Builds the trajectory; `duration_s` is needed by random routes only (their length),
    /// `seed` by random routes only.
    ///
    /// # Errors
    /// [`uav_dynamics::Error::Config`] naming the field out of range.
    pub fn build(&self, duration_s: Option<f64>, seed: u64) -> uav_dynamics::Result<Box<dyn Trajectory>> {
        Ok(match self.kind {
            TrajectoryKind::Eight => Box::new(trajectory::eight(&self.shape)?),
            TrajectoryKind::Ust => Box::new(trajectory::ust(&self.shape)?.0),
            TrajectoryKind::Diagonal => Box::new(trajectory::diagonal(&self.shape)?),
            TrajectoryKind::Square => Box::new(trajectory::square(&self.shape)?),
            TrajectoryKind::Formation => Box::new(trajectory::formation_square(&self.shape, self.formation_index)?),
            TrajectoryKind::Random => {
                let cfg = RandomRouteConfig { duration_s: duration_s.unwrap_or(self.random.duration_s), ..self.random };
                Box::new(trajectory::RandomRoute::new(&cfg, seed)?)
            }
        })
    }
}

/// Everything `quadformer simulate` needs to make one flight.
#[derive(Debug, Clone, PartialEq, Default, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlightConfig {
    /// Master seed; the route, the sensor noise and each attack plan use seeds derived from it
    /// ([`FlightConfig::sub_seed`]). Default 0.
    #[serde(default)]
    pub seed: u64,
    /// Flight time in seconds. Default: the trajectory's nominal duration for the shapes,
    /// `trajectory.random.duration_s` for random routes.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub duration_s: Option<f64>,
    /// The reference trajectory. Default: the eight-shape.
    #[serde(default)]
    pub trajectory: TrajectoryConfig,
    /// Sensor rates, noise figures and noise shape (`uav_dynamics::sim::SimConfig`). Default
    /// `SimConfig::default()`: every value cites its source there and in docs/sensors.md.
    /// Keys left out keep their defaults (e.g. `[sim.noise]` alone sets the noise shape).
    #[serde(default)]
    pub sim: SimConfig,
    /// Attacks on the GPS stream (`attack_inject::AttackConfig`, one `[[attacks]]` table
    /// each). Attack `i` of `n` is planned inside the `i`-th of `n` equal consecutive shares
    /// of the GPS time span, so kinds never overlap; its `attacked_fraction` is relative to
    /// that share. Default: none (a clean flight).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub attacks: Vec<AttackConfig>,
}

/// Largest seed a flight config can hold (TOML integers are signed 64-bit).
#[allow(clippy::cast_sign_loss)] // i64::MAX is positive
pub const MAX_SEED: u64 = i64::MAX as u64;

/// Purposes of derived seeds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SeedStream {
    /// The random route.
    Route,
    /// The simulator's sensor noise and biases.
    Sim,
    /// Attack plan `i`.
    Attack(u32),
}

impl FlightConfig {
    /// Parses a flight config from TOML text; `path` is only used in error messages.
    ///
    /// # Errors
    /// [`IoError::Toml`] with the parser's line, column and field (unknown keys included).
    pub fn from_toml(path: &Path, text: &str) -> Result<Self> {
        let toml_err = |msg: String| IoError::Toml { path: path.to_owned(), msg };
        let mut user: toml::Table = text.parse().map_err(|e: toml::de::Error| toml_err(e.to_string()))?;
        // The lower crates' configs require every field; fill the keys a user left out from
        // their documented defaults, so `[sim.noise]` alone is a complete config.
        let defaults = Self::default();
        let sections: [(&[&str], Option<toml::Table>); 3] = [
            (&["sim"], toml::Table::try_from(&defaults.sim).ok()),
            (&["trajectory", "shape"], toml::Table::try_from(defaults.trajectory.shape).ok()),
            (&["trajectory", "random"], toml::Table::try_from(defaults.trajectory.random).ok()),
        ];
        for (keys, default) in sections {
            if let Some(default) = default {
                fill_defaults(&mut user, keys, default);
            }
        }
        match user.try_into::<Self>() {
            Ok(cfg) => Ok(cfg),
            // The merged table has no source positions: parse the user's text again to report
            // the error with its line and column, unless that only complains about a key the
            // merge supplied.
            Err(merged) => match toml::from_str::<Self>(text) {
                Err(strict) if !strict.message().contains("missing field") => Err(toml_err(strict.to_string())),
                _ => Err(toml_err(merged.message().trim().to_owned())),
            },
        }
    }

    /// Reads and parses a flight config file.
    ///
    /// # Errors
    /// [`IoError::Fs`] if unreadable; as [`FlightConfig::from_toml`].
    pub fn load(path: &Path) -> Result<Self> {
        let text = crate::io::input_file::read_text(path)?;
        Self::from_toml(path, &text)
    }

    /// The config as TOML text (every field explicit), checked to read back as `self`.
    ///
    /// # Errors
    /// [`IoError::Toml`] if a value cannot be encoded (e.g. a non-finite float, or a `seed`
    /// above [`MAX_SEED`]: TOML integers are signed 64-bit) or the text would not read back
    /// as the same config.
    pub fn to_toml(&self, path: &Path) -> Result<String> {
        let toml_err = |msg: String| IoError::Toml { path: path.to_owned(), msg };
        if self.seed > MAX_SEED {
            return Err(toml_err(format!(
                "seed {} cannot be written: TOML integers are signed 64-bit, so a seed is at most {MAX_SEED}",
                self.seed
            )));
        }
        let text = toml::to_string(self).map_err(|e| toml_err(e.to_string()))?;
        match Self::from_toml(path, &text) {
            Ok(back) if back == *self => Ok(text),
            Ok(_) => Err(toml_err("the config does not read back as written".into())),
            Err(e) => Err(toml_err(format!("the config would not read back: {e}"))),
        }
    }

    /// Writes the config to `path` atomically.
    ///
    /// # Errors
    /// As [`FlightConfig::to_toml`] and [`write_text_atomic`].
    pub fn save(&self, path: &Path) -> Result<()> {
        write_text_atomic(path, &self.to_toml(path)?)
    }

    /// The seed of one random stream: SplitMix64 of the master seed mixed with the stream's
    /// index, so streams are independent and adding an attack does not change the noise.
    #[must_use]
    pub fn sub_seed(&self, stream: SeedStream) -> u64 {
        let idx: u64 = match stream {
            SeedStream::Route => 1,
            SeedStream::Sim => 2,
            SeedStream::Attack(i) => 16 + u64::from(i),
        };
        splitmix64(self.seed ^ idx.wrapping_mul(0x9E37_79B9_7F4A_7C15))
    }
}

/// One step of SplitMix64 (Steele, Lea & Flood 2014), a standard seed scrambler.
fn splitmix64(x: u64) -> u64 {
    let mut z = x.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Inserts the keys of `default` that the table at `keys` inside `root` lacks (recursively
/// for sub-tables); a section absent from `root` is left absent (serde's `default` applies).
fn fill_defaults(root: &mut toml::Table, keys: &[&str], default: toml::Table) {
    let mut table = root;
    for key in keys {
        match table.get_mut(*key) {
            Some(toml::Value::Table(t)) => table = t,
            _ => return,
        }
    }
    // The user's keys over the defaults: the one TOML merge (`crate::io::merge_over`).
    let mut merged = default;
    merge_over(&mut merged, std::mem::take(table));
    *table = merged;
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse(text: &str) -> Result<FlightConfig> {
        FlightConfig::from_toml(Path::new("f.toml"), text)
    }

    #[test]
    fn empty_config_is_the_default_and_round_trips() {
        let cfg = parse("").unwrap();
        assert_eq!(cfg, FlightConfig::default());
        let text = cfg.to_toml(Path::new("f.toml")).unwrap();
        assert_eq!(parse(&text).unwrap(), cfg);
    }

    #[test]
    fn partial_sections_keep_defaults() {
        let cfg = parse("seed = 3\n[sim.noise]\nshape = \"Laplace\"\n[trajectory]\nkind = \"square\"\n[trajectory.shape]\nsize_m = 5.0\n[[attacks]]\nkind = \"sparse\"\n").unwrap();
        assert_eq!(cfg.sim.noise.shape, uav_dynamics::noise::NoiseShape::Laplace);
        assert_eq!(cfg.sim.imu_rate_hz, SimConfig::default().imu_rate_hz);
        assert_eq!(cfg.trajectory.shape.size_m, 5.0);
        assert_eq!(cfg.trajectory.shape.altitude_m, ShapeConfig::default().altitude_m);
        assert_eq!(cfg.attacks.len(), 1);
    }

    #[test]
    fn unknown_keys_are_named() {
        let e = parse("[sim]\nimu_rate = 100\n").unwrap_err().to_string();
        assert!(e.starts_with("f.toml: TOML parse error at line 2, column 1"), "{e}");
        assert!(e.contains("unknown field `imu_rate`"), "{e}");
        let e = parse("sed = 1\n").unwrap_err().to_string();
        assert!(e.contains("line 1") && e.contains("unknown field `sed`"), "{e}");
        let e = parse("seed = \"x\"\n").unwrap_err().to_string();
        assert!(e.contains("line 1, column 8"), "{e}");
        let e = parse("seed = \n").unwrap_err().to_string();
        assert!(e.contains("line 1"), "{e}");
    }

    #[test]
    fn a_config_that_cannot_read_back_is_not_written() {
        let cfg = FlightConfig { seed: u64::MAX, ..FlightConfig::default() };
        let e = cfg.to_toml(Path::new("c.toml")).unwrap_err().to_string();
        assert!(e.contains("seed 18446744073709551615 cannot be written"), "{e}");
        let cfg = FlightConfig { seed: MAX_SEED, ..FlightConfig::default() };
        assert_eq!(parse(&cfg.to_toml(Path::new("c.toml")).unwrap()).unwrap(), cfg);
    }

    #[test]
    fn sub_seeds_differ_and_are_stable() {
        let cfg = FlightConfig { seed: 1, ..FlightConfig::default() };
        let seeds =
            [SeedStream::Route, SeedStream::Sim, SeedStream::Attack(0), SeedStream::Attack(1)].map(|s| cfg.sub_seed(s));
        for i in 0..seeds.len() {
            for j in 0..i {
                assert_ne!(seeds[i], seeds[j]);
            }
        }
        assert_eq!(
            cfg.sub_seed(SeedStream::Sim),
            FlightConfig { seed: 1, ..FlightConfig::default() }.sub_seed(SeedStream::Sim)
        );
    }
}
