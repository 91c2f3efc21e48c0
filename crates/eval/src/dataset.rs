//! Labelled residue datasets: simulate flights → inject GPS attacks (eq:fdi) → run the EKF
//! (alg:alg1) → per-step labelled residues, split by flight into train / validation / test,
//! cached on disk (docs/decisions/031-dataset-splits-seeds-and-cache.md; paper Sec. V-B,
//! "Attack Scenario and Training Details": 83,700 training and 18,700 test residue steps, about
//! 12% attacked).
//!
//! One dataset is one cell of the experiment matrix: a model (`FilterConfig::model`), a noise
//! shape (`SimConfig::noise`) and an attack (`AttackConfig::kind`). Every flight flies its own
//! random smooth route ([`RandomRoute`]); routes, sensor noise and attack plans are drawn from
//! seeds derived from `(seed, split, flight index)` only, so all cells of one seed fly the same
//! routes (common random numbers) and the splits never share a route or a seed.
//!
//! Label alignment: the label of a residue step is the label of the GPS fix at the same time
//! (within [`LABEL_TOLERANCE_S`]); a residue step without a GPS fix is clean. Times are seconds,
//! residues and covariances are those of `ekf_residue::residues` (metres, radians).
//!
//! Caching ([`load_or_build`]): the file name and content carry a SHA-256 key of the full
//! configuration (minus the labelled fraction, which is applied after loading), the crate
//! version and [`FORMAT_VERSION`]. The file is `MAGIC ‖ SHA-256(payload) ‖ payload`, the payload
//! bincode 2 of a serialisable mirror; every residue series is rebuilt through
//! `ResidueSeries::from_flat`, so a corrupt, stale or mismatching file is rebuilt, never trusted.
//! Files are written to a temporary file in the cache directory and renamed into place.
//!
//! ```no_run
//! use eval::dataset::{load_or_build, DatasetConfig};
//! use attack_inject::AttackKind;
//! use ekf_residue::residues::ModelKind;
//! use uav_dynamics::noise::NoiseShape;
//! # fn main() -> Result<(), eval::dataset::DatasetError> {
//! let cfg = DatasetConfig::paper(ModelKind::ModelI, NoiseShape::Laplace, AttackKind::Sparse).check()?;
//! let (data, outcome) = load_or_build(&cfg, std::path::Path::new("target/datasets"))?;
//! println!("{outcome:?}: {} training steps", data.train()?.n_steps());
//! # Ok(())
//! # }
//! ```

use std::fmt;
use std::path::{Path, PathBuf};
use std::time::Instant;

use attack_inject::{AttackConfig, AttackError, AttackKind, AttackPlan, inject};
use ekf_residue::residues::{FilterConfig, ModelKind, generate_residues};
use ekf_residue::{FilterError, LabelledResidues, LabelledSeries, ResidueError, ResidueSeries};
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rayon::prelude::*;
use resilient_fusion::estimator::ResilientConfig;
use resilient_fusion::gates::Oracle;
use resilient_fusion::recorded::fly_recorded;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use uav_dynamics::noise::{NoiseConfig, NoiseShape};
use uav_dynamics::sensors::Flight;
use uav_dynamics::sim::{SimConfig, simulate};
use uav_dynamics::trajectory::{RandomRoute, RandomRouteConfig};

/// Version of the cache file layout; bump when the mirror types change.
pub const FORMAT_VERSION: u32 = 1;

/// Two time stamps closer than this (seconds) are the same instant when labels are aligned.
/// The simulator stamps every stream at exact multiples of its period, so any tolerance far
/// below the 0.1 s GPS period works; 1 ms matches `ekf_residue`'s pairing tolerance.
pub const LABEL_TOLERANCE_S: f64 = crate::io::TIME_MATCH_TOL_S;

/// First bytes of a cache file.
const MAGIC: [u8; 8] = *b"QFDSET\x00\x01";

/// Errors of dataset building and caching.
#[derive(Debug, thiserror::Error)]
#[non_exhaustive]
pub enum DatasetError {
    /// A configuration field is out of range.
    #[error("invalid dataset config field `{field}`: {msg}")]
    Config {
        /// Dotted field path.
        field: &'static str,
        /// What is wrong.
        msg: String,
    },
    /// The attack configuration is invalid.
    #[error("invalid attack config: {0}")]
    AttackConfig(#[source] AttackError),
    /// Simulating one flight failed.
    #[error("{split} flight {index}: simulation failed: {source}")]
    Sim {
        /// Split of the flight.
        split: Split,
        /// Index of the flight in its split.
        index: usize,
        /// The simulator's error.
        #[source]
        source: uav_dynamics::Error,
    },
    /// Planning or injecting the attacks of one flight failed.
    #[error("{split} flight {index}: attack injection failed: {source}")]
    Attack {
        /// Split of the flight.
        split: Split,
        /// Index of the flight in its split.
        index: usize,
        /// The attack error.
        #[source]
        source: AttackError,
    },
    /// The EKF failed on one flight.
    #[error("{split} flight {index}: residue generation failed: {source}")]
    Filter {
        /// Split of the flight.
        split: Split,
        /// Index of the flight in its split.
        index: usize,
        /// The filter error.
        #[source]
        source: FilterError,
    },
    /// A residue series or label set failed validation.
    #[error("{split} flight {index}: invalid residues: {source}")]
    Residue {
        /// Split of the flight.
        split: Split,
        /// Index of the flight in its split.
        index: usize,
        /// The validation error.
        #[source]
        source: ResidueError,
    },
    /// Reading or writing a cache file failed.
    #[error("cache file {}: {source}", path.display())]
    Io {
        /// The file or directory.
        path: PathBuf,
        /// The I/O error.
        #[source]
        source: std::io::Error,
    },
    /// Flying one flight through the protected estimator failed.
    #[error("{split} flight {index}: protected estimator failed: {source}")]
    Fusion {
        /// Split of the flight.
        split: Split,
        /// Index of the flight in its split.
        index: usize,
        /// The estimator's error.
        #[source]
        source: resilient_fusion::FusionError,
    },
    /// Writing a cache file failed (`crate::io::write_bytes_atomic`).
    #[error(transparent)]
    Write(#[from] crate::io::IoError),
    /// Encoding the dataset failed.
    #[error("encoding dataset: {0}")]
    Encode(String),
}

/// Result alias of this module.
pub type Result<T, E = DatasetError> = std::result::Result<T, E>;

/// One of the three splits; flights never cross splits.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Split {
    /// Training flights (labels known for a fraction of them).
    Train,
    /// Validation flights (fully labelled; thresholds and early stopping only).
    Valid,
    /// Test flights (fully labelled; scoring only).
    Test,
}

impl Split {
    /// All splits in order.
    pub const ALL: [Self; 3] = [Self::Train, Self::Valid, Self::Test];

    /// Lowercase name.
    #[must_use]
    pub const fn name(self) -> &'static str {
        match self {
            Self::Train => "train",
            Self::Valid => "valid",
            Self::Test => "test",
        }
    }

    const fn tag(self) -> u64 {
        match self {
            Self::Train => 1,
            Self::Valid => 2,
            Self::Test => 3,
        }
    }
}

impl fmt::Display for Split {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// Target number of residue steps per split.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SplitSteps {
    /// Training steps. Paper: 83,700.
    pub train: usize,
    /// Validation steps. Default 18,700 (same size as the test split; thresholds and early
    /// stopping need a validation split, the paper has none; decision 001).
    pub valid: usize,
    /// Test steps. Paper: 18,700.
    pub test: usize,
}

impl SplitSteps {
    /// Paper scale: 83,700 / 18,700 / 18,700 (paper Sec. "Attack Scenario and Training Details").
    pub const PAPER: Self = Self { train: 83_700, valid: 18_700, test: 18_700 };
    /// CI scale: 3,000 / 1,000 / 1,000.
    pub const QUICK: Self = Self { train: 3_000, valid: 1_000, test: 1_000 };

    /// Target steps of `split`.
    #[must_use]
    pub const fn of(&self, split: Split) -> usize {
        match split {
            Split::Train => self.train,
            Split::Valid => self.valid,
            Split::Test => self.test,
        }
    }
}

/// Which estimator produces a dataset's residues.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ResidueProtocol {
    /// The EKF fuses every fix, attacked or not (Tables I and II, the paper's protocol).
    #[default]
    OpenLoop,
    /// The resilient estimator (alg:alg3) with GPS excluded exactly on attacked fixes (an
    /// oracle detector at latency 0, hold 0): the residues a detector sees in the closed loop
    /// when it protects the estimate, with labels that agree with them
    /// (docs/decisions/091-closed-loop.md).
    Protected,
}

impl ResidueProtocol {
    const fn is_open_loop(&self) -> bool {
        matches!(self, Self::OpenLoop)
    }
}

/// Everything that defines one dataset (one matrix cell at one seed).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DatasetConfig {
    /// Simulator (rates, sensor σ, noise shape in `sim.noise.shape`).
    pub sim: SimConfig,
    /// Residue generator (model in `filter.model`).
    pub filter: FilterConfig,
    /// GPS attack (kind in `attack.kind`, attacked fraction about 12%).
    pub attack: AttackConfig,
    /// Random route parameters (its `duration_s` is replaced by the planned flight length).
    pub route: RandomRouteConfig,
    /// Target residue steps per split.
    pub steps: SplitSteps,
    /// Longest flight in seconds; each split is cut into equal flights no longer than this.
    /// Default 150 s: 56 training flights at paper scale, so the 10% labelled subset is six
    /// whole flights and the 1% ablation one flight (decision 031).
    pub flight_duration_s: f64,
    /// Fraction of training flights whose labels are kept (others `None`). Default 0.1
    /// (decision 031). At least one flight when non-zero. Not part of the
    /// cache key: labels are hidden after loading.
    pub labelled_fraction: f64,
    /// Seed of the whole dataset.
    pub seed: u64,
    /// Estimator of the residues. Default [`ResidueProtocol::OpenLoop`] (left out of the cache
    /// key then, so open-loop datasets keep their keys).
    #[serde(default, skip_serializing_if = "ResidueProtocol::is_open_loop")]
    pub protocol: ResidueProtocol,
}

/// Budget of one flight of a dataset, seconds (the paper's flights are 150 s).
pub const MAX_FLIGHT_DURATION_S: f64 = 3_600.0;
/// Budget of residue steps per split (the paper's training split has 83,700).
pub const MAX_SPLIT_STEPS: usize = 10_000_000;

impl DatasetConfig {
    /// The paper-scale cell `(model, noise, attack)` with every other value at its default.
    ///
    /// The attack amplitude unit `attack.gps_sigma_m` is set to the simulator's horizontal GPS σ.
    #[must_use]
    pub fn paper(model: ModelKind, noise: NoiseShape, attack: AttackKind) -> Self {
        let sim = SimConfig { noise: NoiseConfig::with_shape(noise), ..SimConfig::default() };
        let mut attack = AttackConfig::new(attack);
        attack.gps_sigma_m = sim.gps_sigma_m[0];
        Self {
            sim,
            filter: FilterConfig::new(model),
            attack,
            route: RandomRouteConfig::default(),
            steps: SplitSteps::PAPER,
            flight_duration_s: 150.0,
            labelled_fraction: 0.1,
            seed: 0,
            protocol: ResidueProtocol::OpenLoop,
        }
    }

    /// The CI-sized cell: [`SplitSteps::QUICK`] and 60 s flights (so the 10% labelled subset
    /// still holds a flight).
    #[must_use]
    pub fn quick(model: ModelKind, noise: NoiseShape, attack: AttackKind) -> Self {
        Self { steps: SplitSteps::QUICK, flight_duration_s: 60.0, ..Self::paper(model, noise, attack) }
    }

    /// Stable cell name in the one naming scheme of [`crate::cell::Cell::slug`], e.g.
    /// `m1-laplace-a1` ([`crate::cell::Cell::name_of_parts`]).
    #[must_use]
    pub fn cell_name(&self) -> String {
        crate::cell::Cell::name_of_parts(self.filter.model, self.sim.noise.shape, self.attack.kind)
    }

    /// Residue steps per second of flight: one per GPS fix (Model I) or VO sample (Model II).
    fn residue_rate_hz(&self) -> f64 {
        f64::from(match self.filter.model {
            ModelKind::ModelI => self.sim.gps_rate_hz,
            ModelKind::ModelII => self.sim.vo_rate_hz,
        })
    }

    /// Validate the dataset fields and the nested attack configuration (simulator and filter
    /// configurations are validated by their own crates when the first flight runs).
    ///
    /// # Errors
    /// [`DatasetError::Config`] or [`DatasetError::AttackConfig`] naming the field.
    pub fn check(&self) -> Result<ValidDatasetConfig> {
        let bad = |field, msg: String| Err(DatasetError::Config { field, msg });
        if !(self.flight_duration_s.is_finite() && (10.0..=MAX_FLIGHT_DURATION_S).contains(&self.flight_duration_s)) {
            return bad(
                "flight_duration_s",
                format!("must be between 10 and {MAX_FLIGHT_DURATION_S} s, got {}", self.flight_duration_s),
            );
        }
        let f = self.labelled_fraction;
        if !(f.is_finite() && (0.0..=1.0).contains(&f)) {
            return bad("labelled_fraction", format!("must be in [0, 1], got {f}"));
        }
        for split in Split::ALL {
            if self.steps.of(split) == 0 {
                return bad("steps", format!("{split} needs at least one step"));
            }
            if self.steps.of(split) > MAX_SPLIT_STEPS {
                return bad(
                    "steps",
                    format!("{split}: {} steps exceed the budget of {MAX_SPLIT_STEPS}", self.steps.of(split)),
                );
            }
        }
        if self.residue_rate_hz() <= 0.0 {
            return bad("sim", "the residue stream (GPS or VO) rate must be positive".to_owned());
        }
        self.attack.check().map_err(DatasetError::AttackConfig)?;
        Ok(ValidDatasetConfig(self.clone()))
    }

    /// The flights of every split: equal flights per split, each at most `flight_duration_s`.
    fn flight_specs(&self) -> Vec<FlightSpec> {
        let rate = self.residue_rate_hz();
        let mut specs = Vec::new();
        for split in Split::ALL {
            let steps = self.steps.of(split);
            #[allow(clippy::cast_precision_loss, clippy::cast_possible_truncation, clippy::cast_sign_loss)]
            let (n_flights, duration_s) = {
                let per_flight = (self.flight_duration_s * rate).floor().max(1.0);
                let n = (steps as f64 / per_flight).ceil().max(1.0) as usize;
                (n, steps as f64 / (n as f64 * rate))
            };
            for index in 0..n_flights {
                let idx = index as u64;
                specs.push(FlightSpec {
                    split,
                    index,
                    duration_s,
                    route_seed: derive_seed(self.seed, split, idx, Stream::Route),
                    sim_seed: derive_seed(self.seed, split, idx, Stream::Sim),
                    attack_seed: derive_seed(self.seed, split, idx, Stream::Attack),
                });
            }
        }
        specs
    }

    /// SHA-256 key of everything that changes the cached data (hex, 64 characters).
    ///
    /// # Errors
    /// [`DatasetError::Encode`] if the configuration cannot be serialised.
    pub fn cache_key(&self) -> Result<String> {
        let json = config_json(self)?;
        let mut h = Sha256::new();
        h.update(b"quadformer-rs dataset\n");
        h.update(FORMAT_VERSION.to_le_bytes());
        h.update(env!("CARGO_PKG_VERSION").as_bytes());
        h.update(b"\n");
        h.update(json.as_bytes());
        Ok(hex(&h.finalize()))
    }
}

/// JSON of `cfg` with the labelled fraction normalised to 0 (it is applied after loading).
fn config_json(cfg: &DatasetConfig) -> Result<String> {
    let normalised = DatasetConfig { labelled_fraction: 0.0, ..cfg.clone() };
    serde_json::to_string(&normalised).map_err(|e| DatasetError::Encode(e.to_string()))
}

/// A [`DatasetConfig`] that passed [`DatasetConfig::check`].
#[derive(Debug, Clone, PartialEq)]
pub struct ValidDatasetConfig(DatasetConfig);

impl ValidDatasetConfig {
    /// The checked configuration.
    #[must_use]
    pub const fn get(&self) -> &DatasetConfig {
        &self.0
    }
}

/// Independent random streams of one flight.
#[derive(Clone, Copy)]
enum Stream {
    Route = 1,
    Sim = 2,
    Attack = 3,
    Labels = 4,
}

/// SplitMix64 step.
fn splitmix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// Seed of one random stream of one flight: a SplitMix64 chain over `(seed, split, index, stream)`.
fn derive_seed(seed: u64, split: Split, index: u64, stream: Stream) -> u64 {
    let mut z = splitmix(seed);
    for word in [split.tag(), index, stream as u64] {
        z = splitmix(z ^ word);
    }
    z
}

/// Lowercase hexadecimal of `bytes` (cache keys).
pub(crate) fn hex(bytes: &[u8]) -> String {
    use std::fmt::Write as _;
    bytes.iter().fold(String::with_capacity(bytes.len() * 2), |mut s, b| {
        let _ = write!(s, "{b:02x}");
        s
    })
}

/// Where and how one flight is generated.
#[derive(Debug, Clone, Copy, PartialEq)]
struct FlightSpec {
    split: Split,
    index: usize,
    duration_s: f64,
    route_seed: u64,
    sim_seed: u64,
    attack_seed: u64,
}

/// Provenance of one dataset flight.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlightMeta {
    /// Split of the flight.
    pub split: Split,
    /// Index within the split.
    pub index: usize,
    /// Flight length in seconds.
    pub duration_s: f64,
    /// Seed of the random route.
    pub route_seed: u64,
    /// Seed of the sensor noise.
    pub sim_seed: u64,
    /// Seed of the attack plan.
    pub attack_seed: u64,
    /// RMS horizontal speed of the route, m/s.
    pub speed_mps: f64,
    /// Mean altitude of the route, m.
    pub altitude_m: f64,
    /// The attacks injected into this flight's GPS stream.
    pub plan: AttackPlan,
    /// GPS fixes in the flight.
    pub n_gps: usize,
    /// GPS fixes labelled attacked.
    pub n_gps_attacked: usize,
}

/// One flight of a dataset: residues with the true label of every step.
#[derive(Debug, Clone, PartialEq)]
pub struct DatasetFlight {
    /// Where the flight came from.
    pub meta: FlightMeta,
    series: ResidueSeries,
    labels: Vec<bool>,
}

impl DatasetFlight {
    /// The residue series.
    #[must_use]
    pub const fn series(&self) -> &ResidueSeries {
        &self.series
    }

    /// The true label of every residue step.
    #[must_use]
    pub fn labels(&self) -> &[bool] {
        &self.labels
    }

    /// Number of attacked residue steps.
    #[must_use]
    pub fn n_attacked(&self) -> usize {
        self.labels.iter().filter(|&&l| l).count()
    }
}

/// Per-split counts of a dataset.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct SplitSummary {
    /// Number of flights.
    pub flights: usize,
    /// Number of residue steps.
    pub steps: usize,
    /// Number of attacked residue steps.
    pub attacked: usize,
    /// Number of flights whose labels are exposed (train: the labelled subset).
    pub labelled_flights: usize,
}

/// A built (or loaded) dataset: every flight of every split with its true labels.
#[derive(Debug, Clone, PartialEq)]
pub struct Dataset {
    config: DatasetConfig,
    key: String,
    train: Vec<DatasetFlight>,
    valid: Vec<DatasetFlight>,
    test: Vec<DatasetFlight>,
}

impl Dataset {
    /// The configuration it was built from.
    #[must_use]
    pub const fn config(&self) -> &DatasetConfig {
        &self.config
    }

    /// The cache key ([`DatasetConfig::cache_key`]).
    #[must_use]
    pub fn key(&self) -> &str {
        &self.key
    }

    /// The flights of `split`, with their true labels.
    #[must_use]
    pub fn flights(&self, split: Split) -> &[DatasetFlight] {
        match split {
            Split::Train => &self.train,
            Split::Valid => &self.valid,
            Split::Test => &self.test,
        }
    }

    /// Indices of the training flights whose labels are kept at `fraction`: a seeded
    /// permutation of the flights, cut at `max(1, round(fraction · n))` (0 for fraction 0), so
    /// the subsets are nested (1% ⊂ 10% ⊂ 100%).
    #[must_use]
    pub fn labelled_train_indices(&self, fraction: f64) -> Vec<usize> {
        let n = self.train.len();
        if fraction.is_nan() || fraction <= 0.0 || n == 0 {
            return Vec::new();
        }
        #[allow(clippy::cast_precision_loss, clippy::cast_possible_truncation, clippy::cast_sign_loss)]
        let k = ((fraction.min(1.0) * n as f64).round() as usize).clamp(1, n);
        let mut idx: Vec<usize> = (0..n).collect();
        let mut rng = StdRng::seed_from_u64(derive_seed(self.config.seed, Split::Train, u64::MAX, Stream::Labels));
        // Fisher–Yates with the crate's seeded generator.
        for i in (1..n).rev() {
            let j = rng.random_range(0..=i);
            idx.swap(i, j);
        }
        idx.truncate(k);
        idx.sort_unstable();
        idx
    }

    fn split_residues(flights: &[DatasetFlight], keep: impl Fn(usize) -> bool) -> Result<LabelledResidues> {
        let series = flights
            .iter()
            .enumerate()
            .map(|(i, f)| {
                let labels = keep(i).then(|| f.labels.clone());
                LabelledSeries::new(f.series.clone(), labels).map_err(|source| DatasetError::Residue {
                    split: f.meta.split,
                    index: f.meta.index,
                    source,
                })
            })
            .collect::<Result<Vec<_>>>()?;
        let split = flights.first().map_or(Split::Train, |f| f.meta.split);
        LabelledResidues::new(series).map_err(|source| DatasetError::Residue { split, index: 0, source })
    }

    /// The training split with labels kept for the configured `labelled_fraction` of flights.
    ///
    /// # Errors
    /// [`DatasetError::Residue`] if the flights do not share one channel set.
    pub fn train(&self) -> Result<LabelledResidues> {
        self.train_with_labelled_fraction(self.config.labelled_fraction)
    }

    /// The training split with labels kept for `fraction` of the flights (the 1/10/100%
    /// ablation reuses one cached dataset).
    ///
    /// # Errors
    /// As [`Dataset::train`].
    pub fn train_with_labelled_fraction(&self, fraction: f64) -> Result<LabelledResidues> {
        let keep = self.labelled_train_indices(fraction);
        Self::split_residues(&self.train, |i| keep.binary_search(&i).is_ok())
    }

    /// The fully labelled validation split (for thresholds and early stopping only).
    ///
    /// # Errors
    /// As [`Dataset::train`].
    pub fn valid(&self) -> Result<LabelledResidues> {
        Self::split_residues(&self.valid, |_| true)
    }

    /// The fully labelled test split.
    ///
    /// # Errors
    /// As [`Dataset::train`].
    pub fn test(&self) -> Result<LabelledResidues> {
        Self::split_residues(&self.test, |_| true)
    }

    /// Counts per split (train's `labelled_flights` at the configured fraction).
    #[must_use]
    pub fn summary(&self, split: Split) -> SplitSummary {
        let flights = self.flights(split);
        SplitSummary {
            flights: flights.len(),
            steps: flights.iter().map(|f| f.series.len()).sum(),
            attacked: flights.iter().map(DatasetFlight::n_attacked).sum(),
            labelled_flights: match split {
                Split::Train => self.labelled_train_indices(self.config.labelled_fraction).len(),
                Split::Valid | Split::Test => flights.len(),
            },
        }
    }

    /// The exact bytes of the cache file (deterministic: same config and seed, same bytes).
    ///
    /// # Errors
    /// [`DatasetError::Encode`] if encoding fails.
    pub fn to_bytes(&self) -> Result<Vec<u8>> {
        let file = DatasetFile {
            format_version: FORMAT_VERSION,
            crate_version: env!("CARGO_PKG_VERSION").to_owned(),
            key: self.key.clone(),
            config_json: config_json(&self.config)?,
            flights: Split::ALL
                .iter()
                .flat_map(|&s| self.flights(s))
                .map(|f| FlightFile {
                    meta: f.meta.clone(),
                    t: f.series.t().to_vec(),
                    channels: f.series.channels().to_vec(),
                    r: f.series.r().to_vec(),
                    s: f.series.s().to_vec(),
                    labels: f.labels.clone(),
                })
                .collect(),
        };
        let payload = bincode::serde::encode_to_vec(&file, bincode::config::standard())
            .map_err(|e| DatasetError::Encode(e.to_string()))?;
        let mut out = Vec::with_capacity(MAGIC.len() + 32 + payload.len());
        out.extend_from_slice(&MAGIC);
        out.extend_from_slice(&Sha256::digest(&payload));
        out.extend_from_slice(&payload);
        Ok(out)
    }

    /// Decode cache-file bytes and check them against `cfg`; every series is re-validated.
    ///
    /// # Errors
    /// A [`StaleReason`] saying why the bytes cannot be trusted.
    pub fn from_bytes(bytes: &[u8], cfg: &ValidDatasetConfig) -> Result<Self, StaleReason> {
        let cfg = cfg.get();
        let (magic, rest) = bytes.split_at_checked(MAGIC.len()).ok_or(StaleReason::Truncated)?;
        if magic != MAGIC {
            return Err(StaleReason::BadMagic);
        }
        let (digest, payload) = rest.split_at_checked(32).ok_or(StaleReason::Truncated)?;
        if Sha256::digest(payload).as_slice() != digest {
            return Err(StaleReason::Checksum);
        }
        let (file, used): (DatasetFile, usize) =
            bincode::serde::decode_from_slice(payload, bincode::config::standard())
                .map_err(|e| StaleReason::Decode(e.to_string()))?;
        if used != payload.len() {
            return Err(StaleReason::Decode(format!("{} trailing bytes", payload.len() - used)));
        }
        if file.format_version != FORMAT_VERSION || file.crate_version != env!("CARGO_PKG_VERSION") {
            return Err(StaleReason::Version { format: file.format_version, crate_version: file.crate_version });
        }
        let key = cfg.cache_key().map_err(|e| StaleReason::Decode(e.to_string()))?;
        let expected_json = config_json(cfg).map_err(|e| StaleReason::Decode(e.to_string()))?;
        if file.key != key || file.config_json != expected_json {
            return Err(StaleReason::ConfigMismatch);
        }
        let mut data = Self { config: cfg.clone(), key, train: Vec::new(), valid: Vec::new(), test: Vec::new() };
        for f in file.flights {
            let series = ResidueSeries::from_flat(f.t, f.channels, f.r, f.s).map_err(|source| {
                StaleReason::Invalid { split: f.meta.split, index: f.meta.index, msg: source.to_string() }
            })?;
            if f.labels.len() != series.len() {
                return Err(StaleReason::Invalid {
                    split: f.meta.split,
                    index: f.meta.index,
                    msg: format!("{} labels for {} steps", f.labels.len(), series.len()),
                });
            }
            let split = f.meta.split;
            let flight = DatasetFlight { meta: f.meta, series, labels: f.labels };
            match split {
                Split::Train => data.train.push(flight),
                Split::Valid => data.valid.push(flight),
                Split::Test => data.test.push(flight),
            }
        }
        let expected = cfg.flight_specs();
        let got: Vec<(Split, usize)> =
            Split::ALL.iter().flat_map(|&s| data.flights(s)).map(|f| (f.meta.split, f.meta.index)).collect();
        if got != expected.iter().map(|s| (s.split, s.index)).collect::<Vec<_>>() {
            return Err(StaleReason::ConfigMismatch);
        }
        Ok(data)
    }
}

/// Why a cache file was not used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum StaleReason {
    /// The file does not exist.
    #[error("no cache file")]
    Missing,
    /// Shorter than its header.
    #[error("truncated file")]
    Truncated,
    /// Not a dataset cache file.
    #[error("bad magic bytes")]
    BadMagic,
    /// The payload does not match its SHA-256.
    #[error("checksum mismatch")]
    Checksum,
    /// The payload does not decode.
    #[error("undecodable payload: {0}")]
    Decode(String),
    /// Written by another format or crate version.
    #[error("written by format {format}, crate {crate_version}")]
    Version {
        /// Stored format version.
        format: u32,
        /// Stored crate version.
        crate_version: String,
    },
    /// Built from another configuration.
    #[error("built from another configuration")]
    ConfigMismatch,
    /// A stored series fails validation.
    #[error("{split} flight {index}: {msg}")]
    Invalid {
        /// Split of the flight.
        split: Split,
        /// Index of the flight.
        index: usize,
        /// The validation message.
        msg: String,
    },
}

/// What [`load_or_build`] did.
#[derive(Debug, Clone, PartialEq)]
pub enum CacheOutcome {
    /// Loaded a valid cache file.
    Hit {
        /// The file.
        path: PathBuf,
    },
    /// Built the dataset and wrote the cache (the old file, if any, was not usable).
    Built {
        /// The file written.
        path: PathBuf,
        /// Why no cached data was used.
        reason: StaleReason,
        /// Build time in seconds (simulation, attacks and EKF of every flight).
        build_s: f64,
    },
}

/// Serialisable mirror of a [`Dataset`] (the cache file payload).
#[derive(Serialize, Deserialize)]
struct DatasetFile {
    format_version: u32,
    crate_version: String,
    key: String,
    /// The configuration as JSON (serde_json supports every serde attribute; bincode does not
    /// support self-describing ones), compared as a string on load.
    config_json: String,
    flights: Vec<FlightFile>,
}

/// Serialisable mirror of one [`DatasetFlight`]; `ResidueSeries` is rebuilt on load.
#[derive(Serialize, Deserialize)]
struct FlightFile {
    meta: FlightMeta,
    t: Vec<f64>,
    channels: Vec<String>,
    r: Vec<f64>,
    s: Vec<f64>,
    labels: Vec<bool>,
}

pub use crate::io::align_labels;

/// One simulated flight before filtering: the clean sensor streams with the true state, and
/// the attack plan drawn for it.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedFlight {
    /// Split of the flight.
    pub split: Split,
    /// Index within the split.
    pub index: usize,
    /// The clean flight (GPS not yet attacked).
    pub flight: Flight,
    /// The attacks drawn for its GPS stream.
    pub plan: AttackPlan,
}

/// Simulate one flight and draw its attack plan.
fn plan_flight(cfg: &DatasetConfig, spec: &FlightSpec) -> Result<(PlannedFlight, RandomRoute)> {
    let (split, index) = (spec.split, spec.index);
    let sim_err = |source| DatasetError::Sim { split, index, source };
    let attack_err = |source| DatasetError::Attack { split, index, source };
    let route_cfg = RandomRouteConfig { duration_s: spec.duration_s, ..cfg.route };
    let route = RandomRoute::new(&route_cfg, spec.route_seed).map_err(sim_err)?;
    let flight = simulate(&cfg.sim, &route, spec.duration_s, spec.sim_seed).map_err(sim_err)?;
    let gps = &flight.streams.gps;
    let (t_start, t_end) = match (gps.first(), gps.last()) {
        (Some(a), Some(b)) if b.t > a.t => (a.t, b.t),
        _ => (0.0, spec.duration_s),
    };
    let attack_cfg = cfg.attack.check().map_err(attack_err)?;
    let plan = AttackPlan::sample(&attack_cfg, t_start, t_end, spec.attack_seed).map_err(attack_err)?;
    Ok((PlannedFlight { split, index, flight, plan }, route))
}

/// Simulate, attack and filter one flight.
fn run_flight(cfg: &DatasetConfig, spec: &FlightSpec) -> Result<DatasetFlight> {
    let (split, index) = (spec.split, spec.index);
    let (planned, route) = plan_flight(cfg, spec)?;
    let PlannedFlight { mut flight, plan, .. } = planned;
    let (series, labels, n_gps, n_gps_attacked) = match cfg.protocol {
        ResidueProtocol::OpenLoop => {
            let attacked =
                inject(&flight.streams.gps, &plan).map_err(|source| DatasetError::Attack { split, index, source })?;
            let gps_t: Vec<f64> = attacked.gps.iter().map(|g| g.t).collect();
            let n_gps_attacked = attacked.labels.iter().filter(|&&l| l).count();
            flight.streams.gps = attacked.gps;
            let out = generate_residues(&flight.streams, &cfg.filter).map_err(|source| DatasetError::Filter {
                split,
                index,
                source,
            })?;
            let labels = align_labels(out.series.t(), &gps_t, &attacked.labels);
            (out.series, labels, gps_t.len(), n_gps_attacked)
        }
        ResidueProtocol::Protected => {
            let resilient = ResilientConfig { latency_s: 0.0, hold_s: 0.0, ..ResilientConfig::default() };
            let oracle = Box::new(Oracle::new(plan.clone()));
            let trace = fly_recorded(&flight, &plan, &cfg.filter, &resilient, Some(oracle))
                .map_err(|source| DatasetError::Fusion { split, index, source })?;
            let n_gps_attacked = trace.steps.iter().filter(|s| s.attacked).count();
            (trace.residues, trace.labels, trace.steps.len(), n_gps_attacked)
        }
    };
    Ok(DatasetFlight {
        meta: FlightMeta {
            split,
            index,
            duration_s: spec.duration_s,
            route_seed: spec.route_seed,
            sim_seed: spec.sim_seed,
            attack_seed: spec.attack_seed,
            speed_mps: route.speed_mps(),
            altitude_m: route.altitude_m(),
            plan,
            n_gps,
            n_gps_attacked,
        },
        series,
        labels,
    })
}

/// The flights of one split, simulated with their attack plans but not filtered: what a
/// closed-loop experiment flies through its own estimator. They are the flights [`build`]
/// makes for that split (the same seeds), in index order.
///
/// # Errors
/// As [`build`].
pub fn plan_split(cfg: &ValidDatasetConfig, split: Split) -> Result<Vec<PlannedFlight>> {
    let cfg = cfg.get();
    let specs: Vec<FlightSpec> = cfg.flight_specs().into_iter().filter(|s| s.split == split).collect();
    specs.par_iter().map(|spec| plan_flight(cfg, spec).map(|(p, _)| p)).collect()
}

/// Build a dataset without touching the disk: every flight in parallel on the rayon pool, each
/// from its own derived seeds, so the result does not depend on the thread count.
///
/// # Errors
/// The first failing flight's error (by split and index).
pub fn build(cfg: &ValidDatasetConfig) -> Result<Dataset> {
    let cfg = cfg.get();
    let specs = cfg.flight_specs();
    let flights = specs.par_iter().map(|spec| run_flight(cfg, spec)).collect::<Result<Vec<_>>>()?;
    let mut data =
        Dataset { config: cfg.clone(), key: cfg.cache_key()?, train: Vec::new(), valid: Vec::new(), test: Vec::new() };
    for f in flights {
        match f.meta.split {
            Split::Train => data.train.push(f),
            Split::Valid => data.valid.push(f),
            Split::Test => data.test.push(f),
        }
    }
    Ok(data)
}

/// The flights of one split alone, fully labelled, without building the other splits or
/// touching the cache. They are the flights [`build`] makes for that split, because every
/// flight's seeds derive from `(seed, split, index)` only; the amplitude sweep uses this to
/// score test splits at fixed amplitudes without simulating training data it never uses.
///
/// # Errors
/// As [`build`].
pub fn build_split(cfg: &ValidDatasetConfig, split: Split) -> Result<LabelledResidues> {
    let cfg = cfg.get();
    let specs: Vec<FlightSpec> = cfg.flight_specs().into_iter().filter(|s| s.split == split).collect();
    let flights = specs.par_iter().map(|spec| run_flight(cfg, spec)).collect::<Result<Vec<_>>>()?;
    Dataset::split_residues(&flights, |_| true)
}

/// The cache file of `cfg` in `cache_dir`: `<cell>-<first 16 hex digits of the key>.qfds`.
///
/// # Errors
/// [`DatasetError::Encode`] if the key cannot be computed.
pub fn cache_path(cfg: &ValidDatasetConfig, cache_dir: &Path) -> Result<PathBuf> {
    let key = cfg.get().cache_key()?;
    Ok(cache_dir.join(format!("{}-{}.qfds", cfg.get().cell_name(), key.get(..16).unwrap_or(&key))))
}

/// Load the dataset of `cfg` from `cache_dir`, or build it and write the cache atomically.
///
/// # Errors
/// Build errors as [`build`]; [`DatasetError::Io`] if the cache cannot be written (a file
/// that cannot be read is treated as stale and rebuilt).
pub fn load_or_build(cfg: &ValidDatasetConfig, cache_dir: &Path) -> Result<(Dataset, CacheOutcome)> {
    let path = cache_path(cfg, cache_dir)?;
    let reason = match std::fs::read(&path) {
        Ok(bytes) => match Dataset::from_bytes(&bytes, cfg) {
            Ok(data) => return Ok((data, CacheOutcome::Hit { path })),
            Err(reason) => reason,
        },
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => StaleReason::Missing,
        Err(e) => StaleReason::Decode(e.to_string()),
    };
    let start = Instant::now();
    let data = build(cfg)?;
    let build_s = start.elapsed().as_secs_f64();
    crate::io::write_bytes_atomic(&path, &data.to_bytes()?)?;
    Ok((data, CacheOutcome::Built { path, reason, build_s }))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sizes_beyond_their_budget_are_refused_by_name() {
        let base = DatasetConfig::quick(ModelKind::ModelI, NoiseShape::Gaussian, AttackKind::Sparse);
        let long = DatasetConfig { flight_duration_s: 1e9, ..base.clone() };
        let e = long.check().unwrap_err().to_string();
        assert!(e.contains("`flight_duration_s`: must be between 10 and 3600 s"), "{e}");
        let mut many = base;
        many.steps.train = MAX_SPLIT_STEPS + 1;
        let e = many.check().unwrap_err().to_string();
        assert!(e.contains("exceed the budget of 10000000"), "{e}");
    }

    #[test]
    fn labels_follow_gps_fixes_and_default_to_clean() {
        let gps_t = [0.1, 0.2, 0.3, 0.5];
        let gps_l = [false, true, true, true];
        // 0.4 has no fix (clean); 0.2000001 matches 0.2 within the tolerance; 0.6 is past the end.
        let res_t = [0.1, 0.2000001, 0.3, 0.4, 0.5, 0.6];
        assert_eq!(align_labels(&res_t, &gps_t, &gps_l), vec![false, true, true, false, true, false]);
    }

    #[test]
    fn derived_seeds_differ_by_split_index_and_stream() {
        let a = derive_seed(7, Split::Train, 0, Stream::Route);
        assert_ne!(a, derive_seed(7, Split::Test, 0, Stream::Route));
        assert_ne!(a, derive_seed(7, Split::Train, 1, Stream::Route));
        assert_ne!(a, derive_seed(7, Split::Train, 0, Stream::Sim));
        assert_ne!(a, derive_seed(8, Split::Train, 0, Stream::Route));
        assert_eq!(a, derive_seed(7, Split::Train, 0, Stream::Route));
    }

    #[test]
    fn paper_scale_flight_plan() {
        let cfg = DatasetConfig::paper(ModelKind::ModelI, NoiseShape::Laplace, AttackKind::Sparse);
        let specs = cfg.flight_specs();
        let count = |s| specs.iter().filter(|f| f.split == s).count();
        assert_eq!((count(Split::Train), count(Split::Valid), count(Split::Test)), (56, 13, 13));
        for s in &specs {
            assert!(s.duration_s <= 150.0);
        }
        let train_s: f64 = specs.iter().filter(|f| f.split == Split::Train).map(|f| f.duration_s).sum();
        assert!((train_s * 10.0 - 83_700.0).abs() < 1e-6);
    }

    #[test]
    fn invalid_config_names_field() {
        let mut cfg = DatasetConfig::quick(ModelKind::ModelI, NoiseShape::Gaussian, AttackKind::Sparse);
        cfg.labelled_fraction = 1.5;
        assert!(matches!(cfg.check(), Err(DatasetError::Config { field: "labelled_fraction", .. })));
        cfg.labelled_fraction = 0.1;
        cfg.flight_duration_s = f64::NAN;
        assert!(matches!(cfg.check(), Err(DatasetError::Config { field: "flight_duration_s", .. })));
        cfg.flight_duration_s = 60.0;
        cfg.attack.attacked_fraction = -0.1;
        assert!(matches!(cfg.check(), Err(DatasetError::AttackConfig(_))));
    }

    #[test]
    fn cache_key_ignores_labelled_fraction_only() {
        let a = DatasetConfig::quick(ModelKind::ModelI, NoiseShape::Gaussian, AttackKind::Sparse);
        let b = DatasetConfig { labelled_fraction: 1.0, ..a.clone() };
        let c = DatasetConfig { seed: 1, ..a.clone() };
        assert_eq!(a.cache_key().unwrap(), b.cache_key().unwrap());
        assert_ne!(a.cache_key().unwrap(), c.cache_key().unwrap());
        assert_eq!(a.cache_key().unwrap().len(), 64);
    }
}
