//! Time-stamp alignment of multi-rate sensor streams (paper alg:alg1, TimeStampAlignment).
//!
//! [`align`] validates every stream of a [`SensorStreams`] (finite values, strictly increasing
//! time stamps, non-decreasing VO keyframe index) and merges them into one time-ordered list of
//! [`AlignedEvent`]s: IMU samples, and groups of simultaneous measurements. Measurements of
//! different streams whose times lie within `tolerance_s` of the earliest member of a group form
//! one [`MeasurementGroup`] (at most one sample per stream; the group time is its earliest
//! member's time). At equal times the order is fixed: IMU first, then the measurement group.
//! The filter propagates with the held IMU sample up to each event time, splitting the last IMU
//! interval exactly at a measurement time (see `residues::Estimator`).
//!
//! Times are in seconds. Errors name the stream (`"imu"`, `"gps"`, `"attitude"`, `"vo"`), the
//! index within it and the time.

use uav_dynamics::sensors::SensorStreams;

use crate::error::FilterError;

/// Default grouping tolerance, seconds: a fifth of the 200 Hz IMU period (docs/decisions/020),
/// far below the 0.1 s spacing of the 10 Hz measurement streams.
pub const DEFAULT_TOLERANCE_S: f64 = 1e-3;

/// Indices of the samples, one per stream at most, that form one measurement time.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasurementGroup {
    /// Group time (earliest member), seconds.
    pub t: f64,
    /// Index into `streams.gps`.
    pub gps: Option<usize>,
    /// Index into `streams.attitude`.
    pub attitude: Option<usize>,
    /// Index into `streams.vo`.
    pub vo: Option<usize>,
}

/// One event of the merged, time-ordered stream.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum AlignedEvent {
    /// IMU sample `streams.imu[idx]`.
    Imu(usize),
    /// Simultaneous measurements.
    Measurements(MeasurementGroup),
}

impl AlignedEvent {
    /// Event time in seconds.
    #[must_use]
    pub fn t(&self, streams: &SensorStreams) -> f64 {
        match self {
            Self::Imu(i) => streams.imu.get(*i).map_or(f64::NAN, |s| s.t),
            Self::Measurements(g) => g.t,
        }
    }
}

fn check_times(stream: &'static str, times: impl Iterator<Item = f64>) -> Result<(), FilterError> {
    let mut t_prev = f64::NEG_INFINITY;
    for (idx, t) in times.enumerate() {
        if !t.is_finite() {
            return Err(FilterError::NonFiniteInput { stream, idx, t, field: "t" });
        }
        if t <= t_prev {
            return Err(FilterError::Unordered { stream, idx, t_prev, t });
        }
        t_prev = t;
    }
    Ok(())
}

fn check_finite(stream: &'static str, idx: usize, t: f64, field: &'static str, v: &[f64]) -> Result<(), FilterError> {
    if v.iter().all(|x| x.is_finite()) { Ok(()) } else { Err(FilterError::NonFiniteInput { stream, idx, t, field }) }
}

/// Checks that no measurement comes after the IMU log ends, beyond one IMU interval (the
/// last one) plus [`DEFAULT_TOLERANCE_S`]: the filter predicts with IMU samples and could only
/// hold its state frozen there. A flight without IMU samples is left to the caller.
fn check_imu_covers(streams: &SensorStreams) -> Result<(), FilterError> {
    let n = streams.imu.len();
    let (Some(last), Some(prev)) = (streams.imu.last(), n.checked_sub(2).and_then(|i| streams.imu.get(i))) else {
        return Ok(());
    };
    let limit = last.t + (last.t - prev.t) + DEFAULT_TOLERANCE_S;
    let streams_t: [(&'static str, Vec<f64>); 3] = [
        ("gps", streams.gps.iter().map(|s| s.t).collect()),
        ("attitude", streams.attitude.iter().map(|s| s.t).collect()),
        ("vo", streams.vo.iter().map(|s| s.t).collect()),
    ];
    for (stream, times) in streams_t {
        if let Some(idx) = times.iter().position(|&t| t > limit) {
            return Err(FilterError::BeyondImu {
                stream,
                idx,
                t: times[idx],
                n_after: times.len() - idx - 1,
                t_imu: last.t,
            });
        }
    }
    Ok(())
}

/// Validate all streams: finite values, strictly increasing times, VO keyframes non-decreasing,
/// no measurement after the IMU log ends.
///
/// # Errors
/// [`FilterError::NonFiniteInput`] or [`FilterError::Unordered`] naming stream, index and time;
/// [`FilterError::BeyondImu`] naming the first measurement after the IMU log.
pub fn validate(streams: &SensorStreams) -> Result<(), FilterError> {
    check_times("imu", streams.imu.iter().map(|s| s.t))?;
    check_times("gps", streams.gps.iter().map(|s| s.t))?;
    check_times("attitude", streams.attitude.iter().map(|s| s.t))?;
    check_times("vo", streams.vo.iter().map(|s| s.t))?;
    for (i, s) in streams.imu.iter().enumerate() {
        check_finite("imu", i, s.t, "gyro", s.gyro.as_slice())?;
        check_finite("imu", i, s.t, "accel", s.accel.as_slice())?;
    }
    for (i, s) in streams.gps.iter().enumerate() {
        check_finite("gps", i, s.t, "p", s.p.as_slice())?;
    }
    for (i, s) in streams.attitude.iter().enumerate() {
        check_finite("attitude", i, s.t, "q", s.q.as_slice())?;
    }
    check_imu_covers(streams)?;
    let mut kf_prev = 0;
    for (i, s) in streams.vo.iter().enumerate() {
        check_finite("vo", i, s.t, "p_rel", s.p_rel.as_slice())?;
        check_finite("vo", i, s.t, "q_rel", s.q_rel.as_slice())?;
        if i > 0 && s.keyframe < kf_prev {
            return Err(FilterError::Unordered {
                stream: "vo",
                idx: i,
                t_prev: f64::from(kf_prev),
                t: f64::from(s.keyframe),
            });
        }
        kf_prev = s.keyframe;
    }
    Ok(())
}

/// Validate and merge the streams into time order with measurement grouping (module doc).
///
/// # Errors
/// As [`validate`]; [`FilterError::Config`] for a negative or non-finite `tolerance_s`.
pub fn align(streams: &SensorStreams, tolerance_s: f64) -> Result<Vec<AlignedEvent>, FilterError> {
    if !(tolerance_s.is_finite() && tolerance_s >= 0.0) {
        return Err(FilterError::Config {
            field: "pair_tolerance_s",
            msg: format!("must be finite and ≥ 0, got {tolerance_s}"),
        });
    }
    validate(streams)?;
    // Measurement samples as (t, stream id, idx), stably sorted by time then stream order.
    let mut meas: Vec<(f64, u8, usize)> =
        Vec::with_capacity(streams.gps.len() + streams.attitude.len() + streams.vo.len());
    meas.extend(streams.gps.iter().enumerate().map(|(i, s)| (s.t, 0u8, i)));
    meas.extend(streams.attitude.iter().enumerate().map(|(i, s)| (s.t, 1u8, i)));
    meas.extend(streams.vo.iter().enumerate().map(|(i, s)| (s.t, 2u8, i)));
    meas.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    let mut groups: Vec<MeasurementGroup> = Vec::new();
    for (t, id, idx) in meas {
        let fits = groups.last().is_some_and(|g| {
            t - g.t <= tolerance_s
                && match id {
                    0 => g.gps.is_none(),
                    1 => g.attitude.is_none(),
                    _ => g.vo.is_none(),
                }
        });
        if !fits {
            groups.push(MeasurementGroup { t, gps: None, attitude: None, vo: None });
        }
        if let Some(g) = groups.last_mut() {
            match id {
                0 => g.gps = Some(idx),
                1 => g.attitude = Some(idx),
                _ => g.vo = Some(idx),
            }
        }
    }
    // Merge: IMU first at equal times.
    let mut events = Vec::with_capacity(streams.imu.len() + groups.len());
    let mut gi = 0;
    for (i, s) in streams.imu.iter().enumerate() {
        while gi < groups.len() && groups[gi].t < s.t {
            events.push(AlignedEvent::Measurements(groups[gi]));
            gi += 1;
        }
        events.push(AlignedEvent::Imu(i));
    }
    events.extend(groups[gi..].iter().copied().map(AlignedEvent::Measurements));
    Ok(events)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;
    use uav_dynamics::sensors::{AttitudeSample, GpsSample, ImuSample};

    #[test]
    fn groups_and_orders() {
        let imu = (0..5)
            .map(|k| ImuSample { t: 0.05 * f64::from(k), gyro: Vector3::zeros(), accel: Vector3::zeros() })
            .collect();
        let streams = SensorStreams {
            imu,
            gps: vec![GpsSample { t: 0.1, p: Vector3::zeros() }],
            attitude: vec![
                AttitudeSample { t: 0.1005, q: Vector3::zeros() },
                AttitudeSample { t: 0.12, q: Vector3::zeros() },
            ],
            vo: vec![],
        };
        let ev = align(&streams, DEFAULT_TOLERANCE_S).unwrap();
        let kinds: Vec<String> = ev
            .iter()
            .map(|e| match e {
                AlignedEvent::Imu(i) => format!("i{i}"),
                AlignedEvent::Measurements(g) => format!("m{:?}{:?}", g.gps, g.attitude),
            })
            .collect();
        assert_eq!(kinds, ["i0", "i1", "i2", "mSome(0)Some(0)", "mNoneSome(1)", "i3", "i4"]);
    }

    #[test]
    fn measurements_after_the_imu_log_are_an_error() {
        let imu: Vec<ImuSample> = (0..5)
            .map(|k| ImuSample { t: 0.05 * f64::from(k), gyro: Vector3::zeros(), accel: Vector3::zeros() })
            .collect();
        let gps = |ts: &[f64]| ts.iter().map(|&t| GpsSample { t, p: Vector3::zeros() }).collect();
        // One IMU interval past the last sample is still held; beyond that is not.
        let held = SensorStreams { imu: imu.clone(), gps: gps(&[0.1, 0.25]), ..SensorStreams::default() };
        assert!(align(&held, DEFAULT_TOLERANCE_S).is_ok());
        let beyond = SensorStreams { imu, gps: gps(&[0.1, 0.2, 0.3, 0.4]), ..SensorStreams::default() };
        let e = align(&beyond, DEFAULT_TOLERANCE_S).unwrap_err().to_string();
        assert!(e.starts_with("gps sample 2 (t = 0.3 s) and 1 more come after the last IMU sample (t = 0.2 s)"), "{e}");
    }
}
