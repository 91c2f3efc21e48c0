//! A flight directory: the sensor streams of one flight as CSV files, plus optional ground
//! truth, attack offsets/labels and the config that produced it (docs/data-format.md).
//!
//! ```text
//! DIR/imu.csv       required  IMU samples (inputs of eq:model1f)
//! DIR/gps.csv       optional  GPS fixes in local ENU, as received (attacked if attack.csv says so)
//! DIR/attitude.csv  optional  attitude reference (Model I measures it, eq:model1g)
//! DIR/vo.csv        optional  visual-odometry relative poses (Model II, eq:model2g)
//! DIR/truth.csv     optional  true state per IMU step
//! DIR/attack.csv    optional  injected GPS offsets and labels, one row per GPS fix
//! DIR/config.toml   optional  the configuration `quadformer simulate` used
//! DIR/filter.toml   optional  filter settings for this flight's sensors (FilterConfig keys)
//! ```
//!
//! [`read_flight`] reads either such a directory or a PX4 ULog (`crate::io::read_ulog`), so
//! every command that takes a flight takes both.
//!
//! Which streams a model needs is checked by the consumer (the `residues` command), so that a
//! user's own log with only the files one model needs is accepted.

use std::path::Path;

use uav_dynamics::{SensorStreams, TruthSample};

use crate::io::atomic::{Overwrite, write_dir_atomic, write_text_atomic};
use crate::io::attack::{AttackRecord, TIME_MATCH_TOL_S, read_attack_mapped, write_attack};
use crate::io::error::{IoError, Result};
use crate::io::input_file::read_text;
use crate::io::streams::{
    read_gps_mapped, read_records, require_file, write_attitude, write_gps, write_imu, write_truth, write_vo,
};
use crate::io::table::ColumnMap;
use crate::io::ulog::{UlogOptions, is_ulog, read_ulog};

/// File name of the IMU stream.
pub const IMU_FILE: &str = "imu.csv";
/// File name of the GPS stream.
pub const GPS_FILE: &str = "gps.csv";
/// File name of the attitude stream.
pub const ATTITUDE_FILE: &str = "attitude.csv";
/// File name of the visual-odometry stream.
pub const VO_FILE: &str = "vo.csv";
/// File name of the ground truth.
pub const TRUTH_FILE: &str = "truth.csv";
/// File name of the attack offsets and labels.
pub const ATTACK_FILE: &str = "attack.csv";
/// File name of the configuration a simulated flight was made with.
pub const CONFIG_FILE: &str = "config.toml";
/// File name of the filter settings that suit a flight's sensors (e.g. R from a receiver's
/// reported accuracy): `ekf_residue::residues::FilterConfig` keys, merged over the base filter.
pub const FILTER_FILE: &str = "filter.toml";

/// The contents of a flight directory.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct FlightDir {
    /// Sensor streams; a stream whose file is absent is empty.
    pub streams: SensorStreams,
    /// Ground truth, if `truth.csv` exists.
    pub truth: Option<Vec<TruthSample>>,
    /// Attack offsets and labels, if `attack.csv` exists (one per GPS fix).
    pub attack: Option<Vec<AttackRecord>>,
    /// Text of `config.toml`, if it exists.
    pub config_toml: Option<String>,
    /// Text of `filter.toml`, if it exists.
    pub filter_toml: Option<String>,
}

/// A flight read by [`read_flight`], with what its conversion reported.
#[derive(Debug, Clone, Default)]
pub struct LoadedFlight {
    /// The flight, as a directory would hold it.
    pub flight: FlightDir,
    /// For a ULog: where each stream came from and what was dropped, one line each.
    pub notes: Vec<String>,
}

/// Reads a flight from a flight directory (its CSV headers renamed by `columns`) or a PX4 ULog
/// file (recognised by its magic bytes).
///
/// A ULog gives the streams of [`crate::io::read_ulog`] and, when the receiver reports its
/// accuracy, a `filter.toml` that sets the GPS σ from it; it has no truth and no attack file.
///
/// # Errors
/// As [`read_flight_dir`] or [`crate::io::read_ulog`]; [`IoError::MissingFile`] for a path
/// that is neither a directory nor a ULog.
pub fn read_flight(path: &Path, ulog: &UlogOptions, columns: &ColumnMap) -> Result<LoadedFlight> {
    if path.is_dir() {
        return Ok(LoadedFlight { flight: read_flight_dir_mapped(path, columns)?, notes: Vec::new() });
    }
    if !is_ulog(path) {
        return Err(IoError::MissingFile {
            path: path.to_owned(),
            why: "a flight directory or a PX4 ULog (.ulg) file is required".into(),
        });
    }
    let log = read_ulog(path, ulog)?;
    let filter_toml = log.gps_sigma_m.map(|s| {
        format!(
            "# Filter settings of a flight converted from the PX4 log {}:\n\
             # GPS σ from the receiver's reported accuracy (median eph, eph, epv over the fixes used).\n\
             [meas]\ngps_sigma_m = [{:?}, {:?}, {:?}]\n",
            // A file name is free text; in a TOML comment a line break would start a new line.
            path.file_name().map_or_else(String::new, |n| n.to_string_lossy().replace(char::is_control, "?")),
            s[0],
            s[1],
            s[2]
        )
    });
    let mut notes = log.sources;
    notes.extend(log.notes);
    Ok(LoadedFlight { flight: FlightDir { streams: log.streams, filter_toml, ..FlightDir::default() }, notes })
}

/// Which optional files of a flight directory are present.
fn present(dir: &Path, name: &str) -> Option<std::path::PathBuf> {
    let p = dir.join(name);
    p.is_file().then_some(p)
}

/// Reads a flight directory: `imu.csv` is required, every other file is optional.
///
/// # Errors
/// [`IoError::MissingFile`] if `dir` has no `imu.csv`; any CSV error of the files present
/// (naming file, line and column); [`IoError::Inconsistent`] if `attack.csv` does not have
/// exactly one row per GPS fix at the same times.
pub fn read_flight_dir(dir: &Path) -> Result<FlightDir> {
    read_flight_dir_mapped(dir, &ColumnMap::default())
}

/// [`read_flight_dir`] with every CSV header renamed by `map` (another tool's column names).
///
/// # Errors
/// As [`read_flight_dir`]; a missing column error names every column a file lacks.
pub fn read_flight_dir_mapped(dir: &Path, map: &ColumnMap) -> Result<FlightDir> {
    if !dir.is_dir() {
        return Err(IoError::MissingFile { path: dir.to_owned(), why: "a flight directory is required".into() });
    }
    let imu_path = dir.join(IMU_FILE);
    require_file(&imu_path, "every flight directory needs its IMU stream")?;
    let mut streams = SensorStreams { imu: read_records(&imu_path, map)?, ..SensorStreams::default() };
    if let Some(p) = present(dir, GPS_FILE) {
        streams.gps = read_gps_mapped(&p, map)?;
    }
    if let Some(p) = present(dir, ATTITUDE_FILE) {
        streams.attitude = read_records(&p, map)?;
    }
    if let Some(p) = present(dir, VO_FILE) {
        streams.vo = read_records(&p, map)?;
    }
    let truth = present(dir, TRUTH_FILE).map(|p| read_records(&p, map)).transpose()?;
    let attack = match present(dir, ATTACK_FILE) {
        Some(p) => {
            let records = read_attack_mapped(&p, map)?;
            check_attack_matches_gps(&p, &records, &streams)?;
            Some(records)
        }
        None => None,
    };
    let config_toml = present(dir, CONFIG_FILE).map(|p| read_text(&p)).transpose()?;
    let filter_toml = present(dir, FILTER_FILE).map(|p| read_text(&p)).transpose()?;
    Ok(FlightDir { streams, truth, attack, config_toml, filter_toml })
}

fn check_attack_matches_gps(path: &Path, attack: &[AttackRecord], streams: &SensorStreams) -> Result<()> {
    if attack.len() != streams.gps.len() {
        return Err(IoError::Inconsistent {
            path: path.to_owned(),
            msg: format!(
                "{} rows, but {GPS_FILE} has {} fixes (one row per fix is required)",
                attack.len(),
                streams.gps.len()
            ),
        });
    }
    for (k, (a, g)) in attack.iter().zip(&streams.gps).enumerate() {
        if (a.t - g.t).abs() > TIME_MATCH_TOL_S {
            return Err(IoError::Inconsistent {
                path: path.to_owned(),
                msg: format!(
                    "line {}: time {:?} s does not match {GPS_FILE} line {} time {:?} s",
                    k + 2,
                    a.t,
                    k + 2,
                    g.t
                ),
            });
        }
    }
    Ok(())
}

/// Writes a flight directory atomically: all files go to a temporary sibling directory, which
/// is renamed to `dir` at the end. Empty streams are not written; truth, attack and config
/// only when present.
///
/// # Errors
/// [`IoError::Inconsistent`] if `dir` exists, is not empty and `overwrite` is
/// [`Overwrite::Refuse`]; any write error. On error `dir` is unchanged.
pub fn write_flight_dir(dir: &Path, flight: &FlightDir, overwrite: Overwrite) -> Result<()> {
    write_dir_atomic(dir, overwrite, |tmp| {
        let s = &flight.streams;
        write_imu(&tmp.join(IMU_FILE), &s.imu)?;
        if !s.gps.is_empty() {
            write_gps(&tmp.join(GPS_FILE), &s.gps)?;
        }
        if !s.attitude.is_empty() {
            write_attitude(&tmp.join(ATTITUDE_FILE), &s.attitude)?;
        }
        if !s.vo.is_empty() {
            write_vo(&tmp.join(VO_FILE), &s.vo)?;
        }
        if let Some(truth) = &flight.truth {
            write_truth(&tmp.join(TRUTH_FILE), truth)?;
        }
        if let Some(attack) = &flight.attack {
            write_attack(&tmp.join(ATTACK_FILE), attack)?;
        }
        if let Some(cfg) = &flight.config_toml {
            write_text_atomic(&tmp.join(CONFIG_FILE), cfg)?;
        }
        if let Some(cfg) = &flight.filter_toml {
            write_text_atomic(&tmp.join(FILTER_FILE), cfg)?;
        }
        Ok(())
    })
}
