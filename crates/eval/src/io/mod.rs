//! File formats of QUADFormer-rs (docs/data-format.md): CSV sensor streams, ground truth,
//! attack offsets/labels and residue series (paper alg:alg1 outputs), flight directories, and
//! atomic output with the checks of docs/cli.md "Safety rules" (`atomic`, `output_check`).
//!
//! Every CSV file has a header; time stamps are seconds and increase strictly; frames are ENU
//! (world) and FLU (body); angles are radians (ZYX Euler). Readers find columns by name and
//! report bad input with file, line and column ([`IoError`]); writers print `f64` in shortest
//! round-trip form, so write → read is bit-exact, and write to a temporary file (or directory)
//! that is renamed into place only when complete.
//!
//! ```
//! use eval::io::{read_gps, write_gps};
//! use uav_dynamics::GpsSample;
//! use nalgebra::Vector3;
//! # fn main() -> Result<(), Box<dyn std::error::Error>> {
//! let dir = std::env::temp_dir().join(format!("qf-io-doc-{}", std::process::id()));
//! std::fs::create_dir_all(&dir)?;
//! let gps = vec![GpsSample { t: 0.1, p: Vector3::new(1.0, 2.0, 0.1 + 0.2) }];
//! write_gps(&dir.join("gps.csv"), &gps)?;
//! assert_eq!(read_gps(&dir.join("gps.csv"))?, gps);
//! # std::fs::remove_dir_all(&dir)?;
//! # Ok(())
//! # }
//! ```

mod atomic;
mod attack;
mod error;
mod flight_config;
mod flight_dir;
mod input_file;
mod output_check;
mod residues;
mod streams;
mod table;
mod toml_merge;
mod ulog;

pub use atomic::{
    OutputKind, Overwrite, Staged, TEMP_PREFIX, check_dir_output, check_replaceable, commit_all, remove_stale_temps,
    stage_bytes, stage_file, write_bytes_atomic, write_dir_atomic, write_file_atomic, write_into_dir_atomic,
    write_path_atomic, write_text_atomic,
};
pub use attack::{ATTACK_COLUMNS, AttackRecord, TIME_MATCH_TOL_S, align_labels, labels_at, read_attack, write_attack};
pub use error::{IoError, Result};
pub use flight_config::{FlightConfig, MAX_SEED, SeedStream, TrajectoryConfig, TrajectoryKind};
pub use flight_dir::{
    ATTACK_FILE, ATTITUDE_FILE, CONFIG_FILE, FILTER_FILE, FlightDir, GPS_FILE, IMU_FILE, LoadedFlight, TRUTH_FILE,
    VO_FILE, read_flight, read_flight_dir, read_flight_dir_mapped, write_flight_dir,
};
pub use input_file::{MAX_CSV_BYTES, MAX_TEXT_BYTES, open_input, read_text};
pub use output_check::{Input, Output, check_outputs};
pub use residues::{CovarianceLayout, r_column, read_residues, s_column, stage_residues, write_residues};
pub use streams::{
    ATTITUDE_COLUMNS, GPS_COLUMNS, GPS_GEODETIC_COLUMNS, IMU_COLUMNS, MAX_ACCEL_M_S2, MAX_ANGLE_RAD, MAX_GYRO_RAD_S,
    MAX_POSITION_M, MAX_SPEED_M_S, TRUTH_COLUMNS, VO_COLUMNS, read_attitude, read_gps, read_imu, read_truth, read_vo,
    stage_truth, write_attitude, write_gps, write_imu, write_truth, write_vo,
};
pub use table::ColumnMap;
pub use toml_merge::merge_over;
pub use ulog::{
    DEFAULT_MIN_FIX_TYPE, MAX_ULOG_BYTES, ULOG_MAGIC, UlogFlight, UlogOptions, VO_KEYFRAME_PERIOD_S, is_ulog, read_ulog,
};
