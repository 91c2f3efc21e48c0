//! CSV formats of the sensor streams and the ground truth (docs/data-format.md).
//!
//! Frames and units follow docs/ARCHITECTURE.md, "Frames and units": world ENU (z up), body FLU,
//! metres, radians (ZYX Euler `[roll φ, pitch θ, yaw ψ]`), seconds from the start of the flight.
//! Every file has a header; time stamps must increase strictly; values must be finite and
//! within plausibility bounds ([`MAX_GYRO_RAD_S`], [`MAX_ACCEL_M_S2`], [`MAX_ANGLE_RAD`],
//! [`MAX_POSITION_M`], [`MAX_SPEED_M_S`]) far beyond any quadrotor's sensors.
//!
//! | file | columns |
//! |---|---|
//! | `imu.csv` | `t, gyro_x, gyro_y, gyro_z` (rad/s, body), `accel_x, accel_y, accel_z` (m/s², body) |
//! | `gps.csv` | `t, p_x, p_y, p_z` (m, local ENU), or `t, lat_deg, lon_deg, h_m` (WGS-84, converted to ENU at the first fix) |
//! | `attitude.csv` | `t, roll, pitch, yaw` (rad) |
//! | `vo.csv` | `t, keyframe, p_rel_x, p_rel_y, p_rel_z` (m), `q_rel_roll, q_rel_pitch, q_rel_yaw` (rad) |
//! | `truth.csv` | `t, p_x.., roll.., v_x.., b_g_x.., b_a_x..` (Model I state, eq:model1state) |

use std::path::Path;

use ekf_residue::geodetic::{Geodetic, LocalEnu};
use uav_dynamics::{AttitudeSample, GpsSample, ImuSample, TruthSample, VoSample};

use crate::io::atomic::{Staged, stage_file};
use crate::io::error::{IoError, Result};
use crate::io::table::{ColumnMap, CsvIn, CsvOut, Row};

/// Plausibility bound of angular rates, rad/s (about 5,700 °/s; MEMS gyros of flight
/// controllers saturate at ±2,000 °/s ≈ 35 rad/s). Readers refuse larger values.
pub const MAX_GYRO_RAD_S: f64 = 100.0;
/// Plausibility bound of specific force, m/s² (about 100 g; MEMS accelerometers of flight
/// controllers saturate at ±16 g).
pub const MAX_ACCEL_M_S2: f64 = 1_000.0;
/// Plausibility bound of angles, rad (about 160 turns, so an unwrapped yaw log passes).
pub const MAX_ANGLE_RAD: f64 = 1_000.0;
/// Plausibility bound of positions, m (beyond the Earth's radius).
pub const MAX_POSITION_M: f64 = 1e7;
/// Plausibility bound of velocities, m/s.
pub const MAX_SPEED_M_S: f64 = 1e4;

/// Columns of `imu.csv`.
pub const IMU_COLUMNS: [&str; 7] = ["t", "gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z"];
/// Columns of `gps.csv`.
pub const GPS_COLUMNS: [&str; 4] = ["t", "p_x", "p_y", "p_z"];
/// Columns of `attitude.csv`.
pub const ATTITUDE_COLUMNS: [&str; 4] = ["t", "roll", "pitch", "yaw"];
/// Columns of `vo.csv`.
pub const VO_COLUMNS: [&str; 8] =
    ["t", "keyframe", "p_rel_x", "p_rel_y", "p_rel_z", "q_rel_roll", "q_rel_pitch", "q_rel_yaw"];
/// Columns of `truth.csv`.
pub const TRUTH_COLUMNS: [&str; 16] = [
    "t", "p_x", "p_y", "p_z", "roll", "pitch", "yaw", "v_x", "v_y", "v_z", "b_g_x", "b_g_y", "b_g_z", "b_a_x", "b_a_y",
    "b_a_z",
];

/// A record type with a CSV layout: a fixed header and a row codec.
pub(crate) trait CsvRecord: Sized {
    /// Header names, time first.
    const COLUMNS: &'static [&'static str];
    /// Parses one row; `cols[i]` is the file's index of `COLUMNS[i]`; `t` is already parsed.
    fn parse(input: &CsvIn, row: &Row, cols: &[usize], t: f64) -> Result<Self>;
    /// Appends one row (all columns in `COLUMNS` order).
    fn emit(&self, out: &mut CsvOut<'_>) -> Result<()>;
}

impl CsvRecord for ImuSample {
    const COLUMNS: &'static [&'static str] = &IMU_COLUMNS;
    fn parse(input: &CsvIn, row: &Row, cols: &[usize], t: f64) -> Result<Self> {
        Ok(Self {
            t,
            gyro: input.bounded_vec3(row, &cols[1..4], MAX_GYRO_RAD_S, "rad/s")?,
            accel: input.bounded_vec3(row, &cols[4..7], MAX_ACCEL_M_S2, "m/s²")?,
        })
    }
    fn emit(&self, out: &mut CsvOut<'_>) -> Result<()> {
        out.f64(self.t)?;
        out.vec3(&self.gyro)?;
        out.vec3(&self.accel)
    }
}

impl CsvRecord for GpsSample {
    const COLUMNS: &'static [&'static str] = &GPS_COLUMNS;
    fn parse(input: &CsvIn, row: &Row, cols: &[usize], t: f64) -> Result<Self> {
        Ok(Self { t, p: input.bounded_vec3(row, &cols[1..4], MAX_POSITION_M, "m")? })
    }
    fn emit(&self, out: &mut CsvOut<'_>) -> Result<()> {
        out.f64(self.t)?;
        out.vec3(&self.p)
    }
}

impl CsvRecord for AttitudeSample {
    const COLUMNS: &'static [&'static str] = &ATTITUDE_COLUMNS;
    fn parse(input: &CsvIn, row: &Row, cols: &[usize], t: f64) -> Result<Self> {
        Ok(Self { t, q: input.bounded_vec3(row, &cols[1..4], MAX_ANGLE_RAD, "rad")? })
    }
    fn emit(&self, out: &mut CsvOut<'_>) -> Result<()> {
        out.f64(self.t)?;
        out.vec3(&self.q)
    }
}

impl CsvRecord for VoSample {
    const COLUMNS: &'static [&'static str] = &VO_COLUMNS;
    fn parse(input: &CsvIn, row: &Row, cols: &[usize], t: f64) -> Result<Self> {
        Ok(Self {
            t,
            keyframe: input.u32(row, cols[1])?,
            p_rel: input.bounded_vec3(row, &cols[2..5], MAX_POSITION_M, "m")?,
            q_rel: input.bounded_vec3(row, &cols[5..8], MAX_ANGLE_RAD, "rad")?,
        })
    }
    fn emit(&self, out: &mut CsvOut<'_>) -> Result<()> {
        out.f64(self.t)?;
        out.u64(u64::from(self.keyframe));
        out.vec3(&self.p_rel)?;
        out.vec3(&self.q_rel)
    }
}

impl CsvRecord for TruthSample {
    const COLUMNS: &'static [&'static str] = &TRUTH_COLUMNS;
    fn parse(input: &CsvIn, row: &Row, cols: &[usize], t: f64) -> Result<Self> {
        Ok(Self {
            t,
            p: input.bounded_vec3(row, &cols[1..4], MAX_POSITION_M, "m")?,
            q: input.bounded_vec3(row, &cols[4..7], MAX_ANGLE_RAD, "rad")?,
            v: input.bounded_vec3(row, &cols[7..10], MAX_SPEED_M_S, "m/s")?,
            b_g: input.bounded_vec3(row, &cols[10..13], MAX_GYRO_RAD_S, "rad/s")?,
            b_a: input.bounded_vec3(row, &cols[13..16], MAX_ACCEL_M_S2, "m/s²")?,
        })
    }
    fn emit(&self, out: &mut CsvOut<'_>) -> Result<()> {
        out.f64(self.t)?;
        for v in [&self.p, &self.q, &self.v, &self.b_g, &self.b_a] {
            out.vec3(v)?;
        }
        Ok(())
    }
}

/// Reads a CSV file of records `R`: columns found by name (any order, extra columns ignored),
/// every value finite, time stamps strictly increasing; for `vo.csv` keyframe indices must not
/// decrease.
///
/// # Errors
/// [`IoError`] naming the file, and the line and column where it applies: missing file or
/// column, wrong number of fields, a value that is not a number or not finite, a time stamp
/// not after the previous one, a decreasing keyframe index.
pub(crate) fn read_records<R: CsvRecord>(path: &Path, map: &ColumnMap) -> Result<Vec<R>> {
    let mut input = CsvIn::open_mapped(path, map)?;
    let cols = input.columns(R::COLUMNS)?;
    let keyframe_col = input.optional_column("keyframe").filter(|_| R::COLUMNS.contains(&"keyframe"));
    let mut out: Vec<R> = Vec::new();
    let mut prev_t = None;
    let mut prev_keyframe: Option<u32> = None;
    while let Some(row) = input.next_row()? {
        let t = input.time(&row, cols[0], prev_t)?;
        if let Some(kc) = keyframe_col {
            let k = input.u32(&row, kc)?;
            if let Some(k_prev) = prev_keyframe
                && k < k_prev
            {
                return Err(input.field_error(
                    &row,
                    kc,
                    format!("keyframe index must not decrease: {k} after {k_prev}"),
                ));
            }
            prev_keyframe = Some(k);
        }
        out.push(R::parse(&input, &row, &cols, t)?);
        prev_t = Some(t);
    }
    Ok(out)
}

/// Writes records `R` to `path` atomically (header, one row per record, `f64` in shortest
/// round-trip form).
///
/// # Errors
/// [`IoError::Unwritable`] for a non-finite value (nothing is written); [`IoError::Fs`] on
/// file-system failure.
pub(crate) fn write_records<R: CsvRecord>(path: &Path, records: &[R]) -> Result<()> {
    stage_records(path, records)?.commit()
}

/// Writes records `R` as [`write_records`] does into the file's temporary, to be committed
/// with the other outputs of a command.
pub(crate) fn stage_records<R: CsvRecord>(path: &Path, records: &[R]) -> Result<Staged> {
    stage_file(path, |file| {
        let mut out = CsvOut::new(path, file, R::COLUMNS.iter().map(|s| (*s).to_owned()).collect())?;
        for r in records {
            r.emit(&mut out)?;
            out.end_row()?;
        }
        out.finish()
    })
}

/// [`IoError::MissingFile`] unless `path` is a file.
pub(crate) fn require_file(path: &Path, why: &str) -> Result<()> {
    if path.is_file() { Ok(()) } else { Err(IoError::MissingFile { path: path.to_owned(), why: why.to_owned() }) }
}

macro_rules! stream_io {
    ($read:ident, $write:ident, $ty:ty, $file:literal) => {
        #[doc = concat!("Reads `", $file, "` (see the module table for its columns).")]
        ///
        /// # Errors
        /// [`IoError`] naming the file, line and column of the first bad value, missing column,
        /// wrong field count or non-increasing time stamp.
        pub fn $read(path: &Path) -> Result<Vec<$ty>> {
            read_records(path, &ColumnMap::default())
        }

        #[doc = concat!("Writes `", $file, "` atomically (temporary file, then rename).")]
        ///
        /// # Errors
        /// [`IoError::Unwritable`] for a non-finite value, [`IoError::Fs`] on file-system failure;
        /// nothing is left at `path` on error.
        pub fn $write(path: &Path, samples: &[$ty]) -> Result<()> {
            write_records(path, samples)
        }
    };
}

stream_io!(read_imu, write_imu, ImuSample, "imu.csv");
stream_io!(read_attitude, write_attitude, AttitudeSample, "attitude.csv");
stream_io!(read_vo, write_vo, VoSample, "vo.csv");
stream_io!(read_truth, write_truth, TruthSample, "truth.csv");

/// Writes `truth.csv` as [`write_truth`] does into its temporary, to be committed with the
/// other outputs of a command (`crate::io::commit_all`).
///
/// # Errors
/// As [`write_truth`].
pub fn stage_truth(path: &Path, samples: &[TruthSample]) -> Result<Staged> {
    stage_records(path, samples)
}

/// Geodetic columns accepted in `gps.csv` instead of `p_x, p_y, p_z`.
pub const GPS_GEODETIC_COLUMNS: [&str; 4] = ["t", "lat_deg", "lon_deg", "h_m"];

/// Reads `gps.csv`: local ENU positions (`p_x, p_y, p_z`), or, when those columns are absent
/// and `lat_deg, lon_deg, h_m` are present, WGS-84 geodetic fixes converted to the local ENU
/// frame anchored at the first fix (paper alg:alg1, CoordinateTransformation;
/// `ekf_residue::geodetic`).
///
/// # Errors
/// [`IoError`] naming the file, line and column of the first bad value, missing column,
/// wrong field count, non-increasing time stamp, or latitude outside [−90°, 90°].
pub fn read_gps(path: &Path) -> Result<Vec<GpsSample>> {
    read_gps_mapped(path, &ColumnMap::default())
}

/// [`read_gps`] with another tool's column names renamed by `map`.
///
/// # Errors
/// As [`read_gps`].
pub(crate) fn read_gps_mapped(path: &Path, map: &ColumnMap) -> Result<Vec<GpsSample>> {
    let probe = CsvIn::open_mapped(path, map)?;
    let geodetic = probe.optional_column("p_x").is_none() && probe.optional_column("lat_deg").is_some();
    drop(probe);
    if !geodetic {
        return read_records(path, map);
    }
    let mut input = CsvIn::open_mapped(path, map)?;
    let cols = input.columns(&GPS_GEODETIC_COLUMNS)?;
    let mut out = Vec::new();
    let mut enu: Option<LocalEnu> = None;
    let mut prev_t = None;
    while let Some(row) = input.next_row()? {
        let t = input.time(&row, cols[0], prev_t)?;
        let g = Geodetic {
            lat_deg: input.f64(&row, cols[1])?,
            lon_deg: input.f64(&row, cols[2])?,
            h_m: input.f64(&row, cols[3])?,
        };
        if g.h_m.abs() > MAX_POSITION_M {
            return Err(input.field_error(
                &row,
                cols[3],
                format!("{:?} m is outside the plausible range ±{MAX_POSITION_M} m", g.h_m),
            ));
        }
        if g.lat_deg.abs() > 90.0 {
            return Err(input.field_error(
                &row,
                cols[1],
                format!("latitude {} is outside [-90, 90] degrees", g.lat_deg),
            ));
        }
        let frame = match enu {
            Some(f) => f,
            None => {
                let f = LocalEnu::new(&g).map_err(|e| input.field_error(&row, cols[1], e.to_string()))?;
                enu = Some(f);
                f
            }
        };
        let p = frame.to_enu(&g).map_err(|e| input.field_error(&row, cols[1], e.to_string()))?;
        out.push(GpsSample { t, p });
        prev_t = Some(t);
    }
    Ok(out)
}

/// Writes `gps.csv` (local ENU columns) atomically (temporary file, then rename).
///
/// # Errors
/// [`IoError::Unwritable`] for a non-finite value, [`IoError::Fs`] on file-system failure;
/// nothing is left at `path` on error.
pub fn write_gps(path: &Path, samples: &[GpsSample]) -> Result<()> {
    write_records(path, samples)
}
