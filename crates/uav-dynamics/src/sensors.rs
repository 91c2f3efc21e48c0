//! Sensor samples and flight records: the data that crosses from the simulator (or a user's
//! flight log) into the estimator.
//!
//! Frames and units (docs/ARCHITECTURE.md, "Frames and units"): world frame ENU with z up, body
//! frame FLU, positions in metres, angles in radians as ZYX Euler `[roll φ, pitch θ, yaw ψ]`, time in
//! seconds from the start of the flight.

use nalgebra::Vector3;

/// One IMU sample: body-frame angular rate `ω_m` (rad/s) and specific force `a_m` (m/s²).
///
/// These are the inputs `u` of Model I and Model II (paper eq:model1f, eq:model2f).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuSample {
    /// Sample time in seconds.
    pub t: f64,
    /// Measured body angular rate `ω_m` in rad/s.
    pub gyro: Vector3<f64>,
    /// Measured specific force `a_m` in m/s² (reads `+9.81` on z at rest, level).
    pub accel: Vector3<f64>,
}

/// One GPS position fix in the local ENU frame, in metres (after the coordinate
/// transformation of alg:alg1).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct GpsSample {
    /// Sample time in seconds.
    pub t: f64,
    /// Position `p` in the local ENU frame, metres.
    pub p: Vector3<f64>,
}

/// One attitude reference sample (e.g. an AHRS output): ZYX Euler angles in radians.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AttitudeSample {
    /// Sample time in seconds.
    pub t: f64,
    /// Orientation `q = [φ, θ, ψ]` in radians.
    pub q: Vector3<f64>,
}

/// One visual-odometry sample: pose of the current body frame relative to the body frame of
/// the current keyframe (paper eq:model2g).
///
/// `keyframe` increases by one whenever the VO front end starts a new keyframe; the first
/// sample of a keyframe is taken at the keyframe's own time, so its relative pose is zero
/// up to noise.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoSample {
    /// Sample time in seconds.
    pub t: f64,
    /// Keyframe index, non-decreasing along a flight.
    pub keyframe: u32,
    /// Relative position `R(q_F)ᵀ(p − p_F)` in metres.
    pub p_rel: Vector3<f64>,
    /// Relative orientation `Euler(R(q_F)ᵀR(q))` in radians.
    pub q_rel: Vector3<f64>,
}

/// The true vehicle state at one instant (the simulator's ground truth).
///
/// Layout follows Model I's state `[p, q, v, b_g, b_a]` (paper eq:model1state).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TruthSample {
    /// Time in seconds.
    pub t: f64,
    /// Position in metres (ENU).
    pub p: Vector3<f64>,
    /// Orientation as ZYX Euler angles in radians.
    pub q: Vector3<f64>,
    /// Velocity in m/s (ENU).
    pub v: Vector3<f64>,
    /// Gyroscope bias in rad/s.
    pub b_g: Vector3<f64>,
    /// Accelerometer bias in m/s².
    pub b_a: Vector3<f64>,
}

/// The multi-rate sensor streams of one flight, each sorted by time.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct SensorStreams {
    /// IMU samples (default 200 Hz).
    pub imu: Vec<ImuSample>,
    /// GPS position fixes (default 10 Hz).
    pub gps: Vec<GpsSample>,
    /// Attitude reference samples (default 10 Hz).
    pub attitude: Vec<AttitudeSample>,
    /// Visual-odometry relative poses (default 10 Hz).
    pub vo: Vec<VoSample>,
}

/// A simulated flight: sensor streams plus the true state at every IMU step.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Flight {
    /// What the sensors reported.
    pub streams: SensorStreams,
    /// The true state, one sample per IMU step.
    pub truth: Vec<TruthSample>,
}
