//! PX4 ULog input (docs/data-format.md "From a PX4 log"; decision 100): a log becomes the
//! sensor streams of a flight, in the project's frames and on one time base, ready for the
//! residue generator of Alg. 1.
//!
//! The log is parsed by the `px4-ulog` crate's streaming parser; only instance 0 of the topics
//! below is kept, and only their numeric fields.
//!
//! | stream | topic | conversion |
//! |---|---|---|
//! | IMU | `sensor_combined` | `gyro_rad`, `accelerometer_m_s2`: FRD → FLU |
//! | GPS | `vehicle_gps_position`, else `sensor_gps` | fixes with `fix_type` ≥ the minimum (3-D by default); WGS-84 → local ENU at the first fix (Alg. 1, `ekf_residue::geodetic`); `eph`/`epv` → R |
//! | attitude | `vehicle_attitude` | `q` (FRD → NED) → ZYX Euler, FLU → ENU; interpolated (slerp) at the GPS fix times |
//! | VO | `vehicle_visual_odometry` | absolute pose → pose relative to a keyframe started every [`VO_KEYFRAME_PERIOD_S`], interpolated at the GPS fix times |
//!
//! Time: `t = (timestamp − t₀)·10⁻⁶ s`, with `t₀` the first IMU sample, so every stream shares the
//! IMU's clock; a topic that logs `timestamp_sample` (when the sample was taken, e.g.
//! `vehicle_attitude`, `vehicle_visual_odometry`, `estimator_innovations`) is timed by it. PX4's
//! GNSS topics log only the publication time, so a receiver's latency (PX4 models it as
//! `EKF2_GPS_DELAY`) stays in the fix times. A sample whose time does not increase is dropped and counted in
//! [`UlogFlight::notes`], as is a measurement outside the IMU's span. The attitude and VO
//! references are resampled at the GPS fix times because Model I and Model II form a residue
//! step where a GPS fix meets a reference sample (docs/decisions/011-residue-channels-and-pairing.md);
//! with no GPS the VO keeps its own times.
//!
//! R: PX4 EKF2 takes a fix's horizontal and vertical σ from the receiver's `eph` and `epv`
//! (PX4 `EKF2_GPS_P_NOISE` is only their floor); [`UlogFlight::gps_sigma_m`] is the median
//! over the fixes used, `[eph, eph, epv]`.
//!
//! Reference topics, kept for checking the conversion (not fused): PX4's own GNSS position
//! innovations (`estimator_innovations`, PX4's sign `prediction − observation` flipped to the
//! project's `observation − prediction`, NED → ENU) and the simulator's ground truth of SITL
//! logs (`vehicle_global_position_groundtruth` in the flight's ENU frame,
//! `vehicle_attitude_groundtruth`).

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::path::Path;

use ekf_residue::geodetic::{Geodetic, LocalEnu};
use nalgebra::{UnitQuaternion, Vector3};
use px4_ulog::full_parser::{Completeness, FlattenedFieldType};
use px4_ulog::stream_parser::model::FlattenedField;
use px4_ulog::stream_parser::{Message, SimpleCallbackResult, read_file_with_simple_callback};
use uav_dynamics::frames::{frd_to_flu, ned_to_enu, px4_quaternion_to_enu_flu};
use uav_dynamics::rotation::euler_from_matrix;
use uav_dynamics::{AttitudeSample, GpsSample, ImuSample, SensorStreams, VoSample};

use crate::io::error::{IoError, Result};
use crate::io::input_file::open_input;
use crate::io::streams::{MAX_ACCEL_M_S2, MAX_GYRO_RAD_S, MAX_POSITION_M};

/// The first bytes of every ULog file ("ULog", then 0x01 0x12 0x35; PX4 ULog file format).
pub const ULOG_MAGIC: [u8; 7] = [0x55, 0x4c, 0x6f, 0x67, 0x01, 0x12, 0x35];
/// Budget of a ULog input: 4 GiB (a day of logging at PX4's default rates).
pub const MAX_ULOG_BYTES: u64 = 4 << 30;
/// Keyframe period of VO converted from absolute poses, seconds (the simulator's default).
pub const VO_KEYFRAME_PERIOD_S: f64 = 1.0;
/// Minimum GNSS `fix_type` kept by default: 3, a 3-D fix (PX4 `EKF2_REQ_*` checks need one).
pub const DEFAULT_MIN_FIX_TYPE: u8 = 3;

const IMU_TOPIC: &str = "sensor_combined";
const GPS_TOPICS: [&str; 2] = ["vehicle_gps_position", "sensor_gps"];
const ATTITUDE_TOPIC: &str = "vehicle_attitude";
const VO_TOPIC: &str = "vehicle_visual_odometry";
const INNOVATION_TOPIC: &str = "estimator_innovations";
const TRUTH_POSITION_TOPIC: &str = "vehicle_global_position_groundtruth";
const TRUTH_ATTITUDE_TOPIC: &str = "vehicle_attitude_groundtruth";
const TOPICS: [&str; 8] = [
    IMU_TOPIC,
    GPS_TOPICS[0],
    GPS_TOPICS[1],
    ATTITUDE_TOPIC,
    VO_TOPIC,
    INNOVATION_TOPIC,
    TRUTH_POSITION_TOPIC,
    TRUTH_ATTITUDE_TOPIC,
];

/// How a log is converted.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UlogOptions {
    /// GNSS fixes with a lower `fix_type` are dropped (0 keeps all; PX4: 2 = 2-D, 3 = 3-D).
    pub min_fix_type: u8,
}

impl Default for UlogOptions {
    fn default() -> Self {
        Self { min_fix_type: DEFAULT_MIN_FIX_TYPE }
    }
}

/// A converted log: the streams, R from the receiver, and the reference topics.
#[derive(Debug, Clone, Default)]
pub struct UlogFlight {
    /// The sensor streams in ENU/FLU on the IMU's clock (see the module doc).
    pub streams: SensorStreams,
    /// GPS σ `[E, N, U]` in metres from the receiver's `eph`/`epv` (median), when it reports them.
    pub gps_sigma_m: Option<[f64; 3]>,
    /// One line per stream: the topic it came from and its sample count.
    pub sources: Vec<String>,
    /// What the conversion dropped or could not use, one line each.
    pub notes: Vec<String>,
    /// Every topic of the log with its number of messages (instance 0).
    pub topics: BTreeMap<String, usize>,
    /// PX4's GNSS position innovations, `observation − prediction` in ENU, at their sample times.
    pub px4_gps_innovations: Vec<(f64, Vector3<f64>)>,
    /// Simulator ground-truth position (SITL logs) in the flight's ENU frame.
    pub truth_position: Vec<(f64, Vector3<f64>)>,
    /// Simulator ground-truth attitude (SITL logs).
    pub truth_attitude: Vec<AttitudeSample>,
    /// `t₀`: the log timestamp (µs since boot) of the first IMU sample, the flight's time 0.
    pub t0_us: u64,
}

/// Whether `path` is a regular file that starts with [`ULOG_MAGIC`].
#[must_use]
pub fn is_ulog(path: &Path) -> bool {
    use std::io::Read as _;
    let Ok(file) = open_input(path, MAX_ULOG_BYTES) else { return false };
    let mut head = [0u8; 7];
    file.take(7).read_exact(&mut head).is_ok() && head == ULOG_MAGIC
}

/// The numeric fields of one topic (instance 0), one column per field, in log order.
#[derive(Debug, Default)]
struct Topic {
    t_us: Vec<u64>,
    cols: BTreeMap<String, Vec<f64>>,
    /// Fields stored as integers in the log (their unit may be scaled, e.g. 1e-7 degrees).
    integer: BTreeSet<String>,
}

impl Topic {
    fn col(&self, path: &Path, topic: &str, name: &str) -> Result<&[f64]> {
        self.cols.get(name).map(Vec::as_slice).ok_or_else(|| IoError::Ulog {
            path: path.to_owned(),
            msg: format!(
                "topic `{topic}` has no field `{name}` (fields: {})",
                self.cols.keys().cloned().collect::<Vec<_>>().join(", ")
            ),
        })
    }

    /// The first of `names` the topic has.
    fn col_any(&self, path: &Path, topic: &str, names: &[&str]) -> Result<(&str, &[f64])> {
        for n in names {
            if let Some((key, c)) = self.cols.get_key_value(*n) {
                return Ok((key.as_str(), c.as_slice()));
            }
        }
        Err(IoError::Ulog {
            path: path.to_owned(),
            msg: format!(
                "topic `{topic}` has none of the fields {} (fields: {})",
                names.join(", "),
                self.cols.keys().cloned().collect::<Vec<_>>().join(", ")
            ),
        })
    }

    fn vec3(&self, path: &Path, topic: &str, base: &str) -> Result<[&[f64]; 3]> {
        Ok([
            self.col(path, topic, &format!("{base}[0]"))?,
            self.col(path, topic, &format!("{base}[1]"))?,
            self.col(path, topic, &format!("{base}[2]"))?,
        ])
    }

    fn quaternion(&self, path: &Path, topic: &str, k: usize) -> Result<Option<[f64; 4]>> {
        let q = [
            self.col(path, topic, "q[0]")?,
            self.col(path, topic, "q[1]")?,
            self.col(path, topic, "q[2]")?,
            self.col(path, topic, "q[3]")?,
        ];
        let v = [q[0][k], q[1][k], q[2][k], q[3][k]];
        Ok(v.iter().all(|x| x.is_finite()).then_some(v))
    }
}

/// A field's value in a data message, or `None` for a character or a short message.
fn decode(data: &[u8], field: &FlattenedField) -> Option<f64> {
    let o = usize::from(field.offset);
    let bytes = |n: usize| data.get(o..o + n);
    #[allow(clippy::cast_precision_loss)] // 64-bit integers above 2^53 are not sensor values
    let v = match field.field_type {
        FlattenedFieldType::Int8 => f64::from(i8::from_le_bytes(bytes(1)?.try_into().ok()?)),
        FlattenedFieldType::UInt8 => f64::from(bytes(1)?[0]),
        FlattenedFieldType::Bool => f64::from(u8::from(bytes(1)?[0] != 0)),
        FlattenedFieldType::Int16 => f64::from(i16::from_le_bytes(bytes(2)?.try_into().ok()?)),
        FlattenedFieldType::UInt16 => f64::from(u16::from_le_bytes(bytes(2)?.try_into().ok()?)),
        FlattenedFieldType::Int32 => f64::from(i32::from_le_bytes(bytes(4)?.try_into().ok()?)),
        FlattenedFieldType::UInt32 => f64::from(u32::from_le_bytes(bytes(4)?.try_into().ok()?)),
        FlattenedFieldType::Int64 => i64::from_le_bytes(bytes(8)?.try_into().ok()?) as f64,
        FlattenedFieldType::UInt64 => u64::from_le_bytes(bytes(8)?.try_into().ok()?) as f64,
        FlattenedFieldType::Float => f64::from(f32::from_le_bytes(bytes(4)?.try_into().ok()?)),
        FlattenedFieldType::Double => f64::from_le_bytes(bytes(8)?.try_into().ok()?),
        FlattenedFieldType::Char => return None,
    };
    Some(v)
}

fn is_integer(t: &FlattenedFieldType) -> bool {
    !matches!(t, FlattenedFieldType::Float | FlattenedFieldType::Double | FlattenedFieldType::Char)
}

/// What [`parse`] keeps: the wanted topics by name, the message count of every topic, and how
/// the log ended.
type Parsed = (BTreeMap<String, Topic>, BTreeMap<String, usize>, Completeness);

/// Parses the log, keeping the topics of [`TOPICS`] (instance 0) and counting every topic.
fn parse(path: &Path) -> Result<Parsed> {
    let err = |msg: String| IoError::Ulog { path: path.to_owned(), msg };
    // Regular file within its budget, and a ULog at all, before the parser sees it.
    if !is_ulog(path) {
        open_input(path, MAX_ULOG_BYTES)?;
        return Err(err("not a PX4 ULog file (it does not start with the ULog magic bytes)".into()));
    }
    let path_str = path.to_str().ok_or_else(|| err("the ULog reader needs a UTF-8 path".into()))?;
    let mut plans: HashMap<u16, Plan> = HashMap::new();
    let mut kept: Vec<Kept> = Vec::new();
    let mut counts: Vec<(String, usize)> = Vec::new();
    let mut callback = |msg: &Message| {
        let Message::Data(d) = msg else { return SimpleCallbackResult::KeepReading };
        let plan = plans.entry(d.msg_id).or_insert_with(|| Plan::new(d, &mut kept, &mut counts));
        if let Some(c) = plan.count {
            counts[c].1 += 1;
        }
        if let Some((k, ts)) = plan.topic
            && let Some(t) = u64_at(d.data, ts)
        {
            let Kept { topic, cols, .. } = &mut kept[k];
            let n = topic.t_us.len();
            // 0: `timestamp_sample` not set (the simulator's ground-truth topics).
            let sampled = plan.sample.and_then(|o| u64_at(d.data, o)).filter(|&ts| ts > 0);
            topic.t_us.push(sampled.unwrap_or(t));
            for (ci, f) in &plan.fields {
                // Every message of a subscription has every field; padding keeps a column
                // aligned with `t_us` should two subscriptions of one topic differ.
                cols[*ci].resize(n, f64::NAN);
                cols[*ci].push(decode(d.data, f).unwrap_or(f64::NAN));
            }
        }
        SimpleCallbackResult::KeepReading
    };
    // The parser is third-party code reading untrusted bytes: a panic inside it becomes an
    // error naming the file rather than the end of the process.
    let outcome = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        read_file_with_simple_callback(path_str, &mut callback)
    }));
    let completeness = match outcome {
        Ok(Ok(c)) => c,
        Ok(Err(e)) => return Err(err(format!("cannot parse the log: {e}"))),
        Err(_) => return Err(err("the ULog parser failed on this file (a malformed log)".into())),
    };
    let topics = kept
        .into_iter()
        .map(|Kept { name, mut topic, names, cols }| {
            let n = topic.t_us.len();
            topic.cols = names
                .into_iter()
                .zip(cols)
                .map(|(c, mut v)| {
                    v.resize(n, f64::NAN);
                    (c, v)
                })
                .collect();
            (name, topic)
        })
        .collect();
    Ok((topics, counts.into_iter().collect(), completeness))
}

/// A kept topic while the log is read: its columns by index, named by `names`.
struct Kept {
    name: String,
    topic: Topic,
    names: Vec<String>,
    cols: Vec<Vec<f64>>,
}

/// The little-endian `u64` at byte `offset` of a message, if the message is long enough.
fn u64_at(data: &[u8], offset: usize) -> Option<u64> {
    data.get(offset..offset + 8).and_then(|b| <[u8; 8]>::try_from(b).ok()).map(u64::from_le_bytes)
}

/// How the data messages of one subscription are stored, decided at its first message so that
/// later messages cost one decode per kept field.
struct Plan {
    /// Index of the topic's message count (instance 0 only).
    count: Option<usize>,
    /// Index of the kept topic and offset of its `timestamp`, for the topics of [`TOPICS`].
    topic: Option<(usize, usize)>,
    /// Offset of a `uint64 timestamp_sample` field.
    sample: Option<usize>,
    /// The stored fields and the index of each one's column in the topic.
    fields: Vec<(usize, FlattenedField)>,
}

impl Plan {
    fn new(
        d: &px4_ulog::stream_parser::DataMessage<'_>,
        kept: &mut Vec<Kept>,
        counts: &mut Vec<(String, usize)>,
    ) -> Self {
        let mut plan = Self { count: None, topic: None, sample: None, fields: Vec::new() };
        if d.multi_id.value() != 0 {
            return plan;
        }
        let format = d.flattened_format;
        let name = format.message_name();
        let index = |list: &mut Vec<String>, name: &str| match list.iter().position(|n| n == name) {
            Some(i) => i,
            None => {
                list.push(name.to_owned());
                list.len() - 1
            }
        };
        plan.count = Some(counts.iter().position(|(n, _)| n == name).unwrap_or_else(|| {
            counts.push((name.to_owned(), 0));
            counts.len() - 1
        }));
        let Some(ts) = format.timestamp_field.as_ref().filter(|_| TOPICS.contains(&name)) else { return plan };
        let k = kept.iter().position(|t| t.name == name).unwrap_or_else(|| {
            kept.push(Kept { name: name.to_owned(), topic: Topic::default(), names: Vec::new(), cols: Vec::new() });
            kept.len() - 1
        });
        plan.topic = Some((k, usize::from(ts.offset)));
        let Kept { topic, names, cols, .. } = &mut kept[k];
        for f in format.field_iter() {
            let field = f.flattened_field_name.as_str();
            if field == "timestamp_sample" && f.field_type == FlattenedFieldType::UInt64 {
                plan.sample = Some(usize::from(f.offset));
            }
            if field == "timestamp" || f.field_type == FlattenedFieldType::Char {
                continue;
            }
            let ci = index(names, field);
            if ci == cols.len() {
                cols.push(Vec::new());
            }
            if is_integer(&f.field_type) {
                topic.integer.insert(field.to_owned());
            }
            plan.fields.push((ci, f.clone()));
        }
        plan
    }
}

/// Reads a PX4 ULog as a flight (see the module doc).
///
/// # Errors
/// [`IoError::Ulog`] naming the file: not a ULog, unparsable, no `sensor_combined` or no GNSS
/// topic (listing the topics the log has), a field missing from a topic, an IMU value that is
/// not finite or out of range; [`IoError::Unsafe`] for a non-regular or oversized file.
pub fn read_ulog(path: &Path, opts: &UlogOptions) -> Result<UlogFlight> {
    let (topics, counts, completeness) = parse(path)?;
    let err = |msg: String| IoError::Ulog { path: path.to_owned(), msg };
    let missing = |what: &str, wanted: &[&str]| {
        err(format!(
            "no {what} topic ({}); the log has: {}",
            wanted.join(" or "),
            if counts.is_empty() {
                "no data at all".to_owned()
            } else {
                counts.keys().cloned().collect::<Vec<_>>().join(", ")
            }
        ))
    };
    let mut out = UlogFlight { topics: counts.clone(), ..UlogFlight::default() };
    if completeness.is_incomplete() {
        out.notes.push(format!("the log ends early ({completeness:?}); its complete prefix is used"));
    }

    let imu_topic = topics.get(IMU_TOPIC).filter(|t| !t.t_us.is_empty()).ok_or_else(|| missing("IMU", &[IMU_TOPIC]))?;
    let t0 = imu_topic.t_us[0];
    out.t0_us = t0;
    out.streams.imu = convert_imu(path, imu_topic, t0, &mut out.notes)?;
    let t_end = out.streams.imu.last().map_or(0.0, |s| s.t);
    out.sources.push(format!("imu: {IMU_TOPIC} ({} samples)", out.streams.imu.len()));

    let (gps_name, gps_topic) = GPS_TOPICS
        .iter()
        .find_map(|n| topics.get(*n).filter(|t| !t.t_us.is_empty()).map(|t| (*n, t)))
        .ok_or_else(|| missing("GNSS", &GPS_TOPICS))?;
    let (gps, frame, sigma) = convert_gps(path, gps_name, gps_topic, t0, t_end, opts, &mut out.notes)?;
    out.streams.gps = gps;
    out.gps_sigma_m = sigma;
    out.sources.push(format!("gps: {gps_name} ({} fixes)", out.streams.gps.len()));
    let clock: Vec<f64> = out.streams.gps.iter().map(|g| g.t).collect();

    if let Some(att) = topics.get(ATTITUDE_TOPIC) {
        let poses = poses(path, ATTITUDE_TOPIC, att, t0, None)?;
        out.streams.attitude = resample(&poses, &clock)
            .into_iter()
            .map(|(t, _, r)| AttitudeSample { t, q: euler_from_matrix(&r) })
            .collect();
        out.sources.push(format!(
            "attitude: {ATTITUDE_TOPIC} ({} samples, interpolated at the {} fix times)",
            out.streams.attitude.len(),
            clock.len()
        ));
    }
    if let Some(vo) = topics.get(VO_TOPIC) {
        let poses = poses(path, VO_TOPIC, vo, t0, Some(&["position", "x"]))?;
        let poses: Vec<Pose> = poses.into_iter().filter(|p| p.0 <= t_end).collect();
        let at = if clock.is_empty() { poses.clone() } else { resample(&poses, &clock) };
        out.streams.vo = keyframe_relative(&at, VO_KEYFRAME_PERIOD_S);
        out.sources.push(format!("vo: {VO_TOPIC} ({} samples)", out.streams.vo.len()));
    }

    if let Some(inn) = topics.get(INNOVATION_TOPIC) {
        out.px4_gps_innovations = px4_innovations(path, inn, t0)?;
    }
    if let (Some(frame), Some(tp)) = (frame, topics.get(TRUTH_POSITION_TOPIC)) {
        out.truth_position = geodetic_track(path, TRUTH_POSITION_TOPIC, tp, t0, &frame)?;
    }
    if let Some(ta) = topics.get(TRUTH_ATTITUDE_TOPIC) {
        out.truth_attitude = poses(path, TRUTH_ATTITUDE_TOPIC, ta, t0, None)?
            .into_iter()
            .map(|(t, _, r)| AttitudeSample { t, q: euler_from_matrix(&r) })
            .collect();
    }
    Ok(out)
}

/// Seconds of a log timestamp on the flight's clock.
#[allow(clippy::cast_precision_loss)] // microsecond offsets stay far below 2^52
fn seconds(t_us: u64, t0: u64) -> f64 {
    if t_us >= t0 { (t_us - t0) as f64 * 1e-6 } else { -((t0 - t_us) as f64 * 1e-6) }
}

/// Row indices whose time is at or after `t0` and strictly after the previous kept row's.
fn increasing_rows(t_us: &[u64], t0: u64) -> (Vec<usize>, usize) {
    let mut rows = Vec::with_capacity(t_us.len());
    let mut prev: Option<u64> = None;
    for (k, &t) in t_us.iter().enumerate() {
        if t >= t0 && prev.is_none_or(|p| t > p) {
            rows.push(k);
            prev = Some(t);
        }
    }
    let dropped = t_us.len() - rows.len();
    (rows, dropped)
}

fn convert_imu(path: &Path, topic: &Topic, t0: u64, notes: &mut Vec<String>) -> Result<Vec<ImuSample>> {
    let gyro = topic.vec3(path, IMU_TOPIC, "gyro_rad")?;
    let accel = topic.vec3(path, IMU_TOPIC, "accelerometer_m_s2")?;
    let (rows, dropped) = increasing_rows(&topic.t_us, t0);
    if dropped > 0 {
        notes.push(format!("{IMU_TOPIC}: {dropped} samples dropped (time stamp not after the previous one)"));
    }
    let mut out = Vec::with_capacity(rows.len());
    for k in rows {
        let g = Vector3::new(gyro[0][k], gyro[1][k], gyro[2][k]);
        let a = Vector3::new(accel[0][k], accel[1][k], accel[2][k]);
        let t = seconds(topic.t_us[k], t0);
        let bad = |what: &str, v: &Vector3<f64>, max: f64, unit: &str| IoError::Ulog {
            path: path.to_owned(),
            msg: format!(
                "{IMU_TOPIC} message {k} (t = {t} s): {what} {v:?} is not finite or beyond ±{max} {unit}",
                v = v.as_slice()
            ),
        };
        if !g.iter().all(|x| x.is_finite() && x.abs() <= MAX_GYRO_RAD_S) {
            return Err(bad("gyro_rad", &g, MAX_GYRO_RAD_S, "rad/s"));
        }
        if !a.iter().all(|x| x.is_finite() && x.abs() <= MAX_ACCEL_M_S2) {
            return Err(bad("accelerometer_m_s2", &a, MAX_ACCEL_M_S2, "m/s²"));
        }
        out.push(ImuSample { t, gyro: frd_to_flu(&g), accel: frd_to_flu(&a) });
    }
    Ok(out)
}

/// Latitude and longitude in degrees and altitude in metres of row `k`, whichever field names
/// and units the PX4 version logs (`lat` in 1e-7° as an integer or in degrees as a float,
/// `latitude_deg`; `alt` in mm as an integer or in m as a float, `altitude_msl_m`).
fn geodetic_at(topic: &Topic, cols: &GeoCols<'_>, k: usize) -> Geodetic {
    let scale = |name: &str, int_scale: f64| if topic.integer.contains(name) { int_scale } else { 1.0 };
    Geodetic {
        lat_deg: cols.lat.1[k] * scale(cols.lat.0, 1e-7),
        lon_deg: cols.lon.1[k] * scale(cols.lon.0, 1e-7),
        h_m: cols.alt.1[k] * scale(cols.alt.0, 1e-3),
    }
}

struct GeoCols<'a> {
    lat: (&'a str, &'a [f64]),
    lon: (&'a str, &'a [f64]),
    alt: (&'a str, &'a [f64]),
}

impl<'a> GeoCols<'a> {
    fn of(path: &Path, name: &str, topic: &'a Topic) -> Result<Self> {
        Ok(Self {
            lat: topic.col_any(path, name, &["latitude_deg", "lat"])?,
            lon: topic.col_any(path, name, &["longitude_deg", "lon"])?,
            alt: topic.col_any(path, name, &["altitude_msl_m", "alt"])?,
        })
    }
}

type GpsConversion = (Vec<GpsSample>, Option<LocalEnu>, Option<[f64; 3]>);

fn convert_gps(
    path: &Path,
    name: &str,
    topic: &Topic,
    t0: u64,
    t_end: f64,
    opts: &UlogOptions,
    notes: &mut Vec<String>,
) -> Result<GpsConversion> {
    let geo = GeoCols::of(path, name, topic)?;
    let fix = topic.cols.get("fix_type");
    let (eph, epv) = (topic.cols.get("eph"), topic.cols.get("epv"));
    let (rows, dropped) = increasing_rows(&topic.t_us, t0);
    let mut counts = [dropped, 0, 0, 0]; // not increasing, low fix, beyond IMU, invalid
    let mut frame: Option<LocalEnu> = None;
    let (mut out, mut h_acc, mut v_acc) = (Vec::new(), Vec::new(), Vec::new());
    for k in rows {
        // A NaN fix type counts as no fix.
        if fix.is_some_and(|f| f[k].is_nan() || f[k] < f64::from(opts.min_fix_type)) {
            counts[1] += 1;
            continue;
        }
        let t = seconds(topic.t_us[k], t0);
        if t > t_end {
            counts[2] += 1;
            continue;
        }
        let g = geodetic_at(topic, &geo, k);
        let f = match frame {
            Some(f) => f,
            None => match LocalEnu::new(&g) {
                Ok(f) => *frame.insert(f),
                Err(_) => {
                    counts[3] += 1;
                    continue;
                }
            },
        };
        match f.to_enu(&g) {
            Ok(p) if p.iter().all(|x| x.abs() <= MAX_POSITION_M) => out.push(GpsSample { t, p }),
            _ => {
                counts[3] += 1;
                continue;
            }
        }
        if let (Some(h), Some(v)) = (eph, epv)
            && h[k].is_finite()
            && v[k].is_finite()
            && h[k] > 0.0
            && v[k] > 0.0
        {
            h_acc.push(h[k]);
            v_acc.push(v[k]);
        }
    }
    for (n, why) in counts.iter().zip([
        "time stamp not after the previous one".to_owned(),
        format!("fix_type below {}", opts.min_fix_type),
        "after the last IMU sample".to_owned(),
        "position not a valid WGS-84 point".to_owned(),
    ]) {
        if *n > 0 {
            notes.push(format!("{name}: {n} fixes dropped ({why})"));
        }
    }
    if out.is_empty() {
        return Err(IoError::Ulog {
            path: path.to_owned(),
            msg: format!(
                "`{name}` has {} messages but no usable fix (fix_type ≥ {} within the IMU's span); \
                 a receiver without a 3-D fix can be accepted with a lower minimum fix type",
                topic.t_us.len(),
                opts.min_fix_type
            ),
        });
    }
    let sigma = (!h_acc.is_empty()).then(|| {
        let (h, v) = (median(&mut h_acc), median(&mut v_acc));
        [h, h, v]
    });
    Ok((out, frame, sigma))
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 { v[n / 2] } else { 0.5 * (v[n / 2 - 1] + v[n / 2]) }
}

/// A pose on the flight's clock: time, ENU position (zero for attitude-only topics) and the
/// FLU → ENU rotation.
type Pose = (f64, Vector3<f64>, nalgebra::Matrix3<f64>);

/// The poses of an attitude (or odometry, with `position` field names) topic, in time order,
/// rows with a degenerate quaternion or non-finite position skipped.
fn poses(path: &Path, name: &str, topic: &Topic, t0: u64, position: Option<&[&str]>) -> Result<Vec<Pose>> {
    let pos = match position {
        Some(names) => {
            let base = topic.col_any(path, name, &[&format!("{}[0]", names[0]), names[1]])?.0;
            Some(if base.ends_with(']') {
                topic.vec3(path, name, names[0])?
            } else {
                [topic.col(path, name, "x")?, topic.col(path, name, "y")?, topic.col(path, name, "z")?]
            })
        }
        None => None,
    };
    let (rows, _) = increasing_rows(&topic.t_us, t0);
    let mut out = Vec::with_capacity(rows.len());
    for k in rows {
        let Some(q) = topic.quaternion(path, name, k)? else { continue };
        let Some(r) = px4_quaternion_to_enu_flu(q) else { continue };
        let p = match &pos {
            Some(c) => ned_to_enu(&Vector3::new(c[0][k], c[1][k], c[2][k])),
            None => Vector3::zeros(),
        };
        if p.iter().all(|x| x.is_finite()) {
            out.push((seconds(topic.t_us[k], t0), p, r));
        }
    }
    Ok(out)
}

/// Interpolation does not bridge a gap between samples longer than this many of the topic's
/// median periods (a logging dropout).
const MAX_GAP_PERIODS: f64 = 3.0;

/// The median time between consecutive poses (infinite with fewer than two).
fn median_period(poses: &[Pose]) -> f64 {
    let mut dt: Vec<f64> = poses.windows(2).map(|w| w[1].0 - w[0].0).collect();
    if dt.is_empty() { f64::INFINITY } else { median(&mut dt) }
}

/// The poses interpolated at the `clock` times inside their span (position linearly, rotation
/// by slerp); clock times outside the span, or inside a dropout of more than
/// [`MAX_GAP_PERIODS`] median periods, are skipped.
fn resample(poses: &[Pose], clock: &[f64]) -> Vec<Pose> {
    let max_gap = MAX_GAP_PERIODS * median_period(poses);
    let mut out = Vec::with_capacity(clock.len());
    for &t in clock {
        let i = poses.partition_point(|p| p.0 < t);
        let (a, b) = match (i.checked_sub(1).and_then(|j| poses.get(j)), poses.get(i)) {
            (_, Some(b)) if b.0 == t => (b, b),
            (Some(a), Some(b)) if b.0 - a.0 <= max_gap => (a, b),
            _ => continue,
        };
        let w = if b.0 > a.0 { (t - a.0) / (b.0 - a.0) } else { 0.0 };
        let qa = UnitQuaternion::from_matrix(&a.2);
        let mut qb = UnitQuaternion::from_matrix(&b.2);
        if qa.coords.dot(&qb.coords) < 0.0 {
            qb = UnitQuaternion::new_unchecked(-qb.into_inner());
        }
        let q = qa.try_slerp(&qb, w, 1e-12).unwrap_or(qa);
        out.push((t, a.1 + (b.1 - a.1) * w, q.to_rotation_matrix().into_inner()));
    }
    out
}

/// Absolute poses → VO samples relative to a keyframe started at the first pose and then at
/// the first pose at least `period_s` after the current keyframe (paper Eq. of Model II's VO
/// measurement: `p_rel = R_Fᵀ(p − p_F)`, `q_rel = Euler(R_Fᵀ R)`).
fn keyframe_relative(poses: &[Pose], period_s: f64) -> Vec<VoSample> {
    let mut out = Vec::with_capacity(poses.len());
    let mut key: Option<(u32, &Pose)> = None;
    for pose in poses {
        let (index, f) = match key {
            Some((i, f)) if pose.0 - f.0 < period_s => (i, f),
            Some((i, _)) => (i + 1, pose),
            None => (0, pose),
        };
        key = Some((index, f));
        let r_f_t = f.2.transpose();
        out.push(VoSample {
            t: pose.0,
            keyframe: index,
            p_rel: r_f_t * (pose.1 - f.1),
            q_rel: euler_from_matrix(&(r_f_t * pose.2)),
        });
    }
    out
}

fn px4_innovations(path: &Path, topic: &Topic, t0: u64) -> Result<Vec<(f64, Vector3<f64>)>> {
    let h0 = topic.col(path, INNOVATION_TOPIC, "gps_hpos[0]")?;
    let h1 = topic.col(path, INNOVATION_TOPIC, "gps_hpos[1]")?;
    let v = topic.col(path, INNOVATION_TOPIC, "gps_vpos")?;
    let mut out = Vec::with_capacity(h0.len());
    for k in 0..h0.len() {
        let t_us = topic.t_us[k];
        let innov_ned = Vector3::new(h0[k], h1[k], v[k]);
        if innov_ned.iter().all(|x| x.is_finite()) {
            out.push((seconds(t_us, t0), -ned_to_enu(&innov_ned)));
        }
    }
    Ok(out)
}

fn geodetic_track(
    path: &Path,
    name: &str,
    topic: &Topic,
    t0: u64,
    frame: &LocalEnu,
) -> Result<Vec<(f64, Vector3<f64>)>> {
    let geo = GeoCols::of(path, name, topic)?;
    let (rows, _) = increasing_rows(&topic.t_us, t0);
    Ok(rows
        .into_iter()
        .filter_map(|k| frame.to_enu(&geodetic_at(topic, &geo, k)).ok().map(|p| (seconds(topic.t_us[k], t0), p)))
        .collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Matrix3;
    use uav_dynamics::rotation::rotation_matrix;

    #[test]
    fn keyframe_relative_poses_restart_every_period() {
        let poses: Vec<Pose> = (0..25)
            .map(|k| {
                let t = f64::from(k) * 0.1;
                (t, Vector3::new(t, 0.0, 0.0), rotation_matrix(&Vector3::new(0.0, 0.0, 0.1 * t)))
            })
            .collect();
        let vo = keyframe_relative(&poses, 1.0);
        assert_eq!(vo.iter().map(|s| s.keyframe).collect::<Vec<_>>()[8..13], [0, 0, 1, 1, 1]);
        assert!(vo[10].p_rel.norm() < 1e-12 && vo[10].q_rel.norm() < 1e-12);
        // 0.5 s into keyframe 1 the body moved 0.5 m east and turned 0.05 rad: seen from the
        // keyframe, that is 0.5 m along its rotated x axis.
        let expected = rotation_matrix(&Vector3::new(0.0, 0.0, 0.1)).transpose() * Vector3::new(0.5, 0.0, 0.0);
        assert!((vo[15].p_rel - expected).norm() < 1e-9);
        assert!((vo[15].q_rel[2] - 0.05).abs() < 1e-9);
    }

    #[test]
    fn resampling_interpolates_inside_the_span_only() {
        let r0 = Matrix3::identity();
        let r1 = rotation_matrix(&Vector3::new(0.0, 0.0, 0.2));
        let poses: Vec<Pose> = vec![(1.0, Vector3::zeros(), r0), (2.0, Vector3::new(2.0, 0.0, 0.0), r1)];
        let out = resample(&poses, &[0.5, 1.0, 1.5, 2.0, 2.5]);
        assert_eq!(out.iter().map(|p| p.0).collect::<Vec<_>>(), [1.0, 1.5, 2.0]);
        assert!((out[1].1 - Vector3::new(1.0, 0.0, 0.0)).norm() < 1e-12);
        assert!((euler_from_matrix(&out[1].2)[2] - 0.1).abs() < 1e-9);
    }

    #[test]
    fn non_increasing_and_early_rows_are_dropped() {
        assert_eq!(increasing_rows(&[5, 10, 10, 9, 20], 6), (vec![1, 4], 3));
        assert!((seconds(1_500_000, 500_000) - 1.0).abs() < 1e-12);
    }

    #[test]
    fn a_file_that_is_not_a_ulog_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("x.ulg");
        std::fs::write(&p, b"t,gyro_x\n").unwrap();
        assert!(!is_ulog(&p));
        let e = read_ulog(&p, &UlogOptions::default()).unwrap_err().to_string();
        assert!(e.contains("x.ulg: not a PX4 ULog file"), "{e}");
    }
}
