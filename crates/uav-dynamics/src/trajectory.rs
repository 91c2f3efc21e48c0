//! Reference trajectories for the paper's flight scenarios (sec. "Simulation Experiment" and
//! "Real-world Experiment": eight-shape, UST-shape, four-UAV square formation, diagonal,
//! square) and long random smooth routes for training data (sec. "Attack Scenario and
//! Training Details").
//!
//! A [`Trajectory`] gives the flat outputs of a quadrotor at time `t` (seconds): position,
//! velocity, acceleration and jerk in the ENU world frame (m, m/s, m/s², m/s³) plus yaw (rad)
//! and yaw rate (rad/s). Position is at least three times continuously differentiable, which is
//! what differential flatness needs (thrust direction from acceleration, body rates from jerk;
//! see `sim`).
//!
//! Construction: scenario shapes are chains of pieces, each a geometric curve `c(s)` (line,
//! circular arc, Gerono lemniscate) flown with a time warp `s(t)`:
//!
//! ```text
//! p = c(s),  v = c′ṡ,  a = c″ṡ² + c′s̈,  j = c‴ṡ³ + 3c″ṡs̈ + c′s⃛
//! ```
//!
//! Lines and arcs use the septic rest-to-rest warp (velocity, acceleration and jerk zero at both
//! ends, peak speed `35/16·L/T`), so the vehicle stops briefly at every corner, as waypoint
//! missions do. The eight uses a constant phase rate with septic ramps at both ends. Random
//! routes are sums of sinusoids per axis (analytic, C∞). Before `t = 0` a trajectory holds its
//! start; after [`Trajectory::duration_s`] it holds its end.

use nalgebra::Vector3;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use serde::{Deserialize, Serialize};
use std::f64::consts::PI;

use crate::error::{Error, Result};

/// Flat outputs of the quadrotor at one instant (differential flatness, Mellinger & Kumar 2011).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FlatOutput {
    /// Position in metres (ENU).
    pub p: Vector3<f64>,
    /// Velocity in m/s.
    pub v: Vector3<f64>,
    /// Acceleration in m/s².
    pub a: Vector3<f64>,
    /// Jerk in m/s³.
    pub j: Vector3<f64>,
    /// Yaw `ψ` in radians (not wrapped; the simulator wraps Euler angles).
    pub yaw: f64,
    /// Yaw rate `ψ̇` in rad/s.
    pub yaw_rate: f64,
}

impl FlatOutput {
    /// Hovering at `p` with yaw `yaw`.
    #[must_use]
    pub fn hover(p: Vector3<f64>, yaw: f64) -> Self {
        Self { p, v: Vector3::zeros(), a: Vector3::zeros(), j: Vector3::zeros(), yaw, yaw_rate: 0.0 }
    }
}

/// A reference trajectory: flat outputs as a smooth function of time.
pub trait Trajectory: Send + Sync {
    /// Flat outputs at time `t_s` (seconds from the start). Defined for every `t_s`: before 0
    /// the start is held, after [`Self::duration_s`] the end.
    fn flat_output(&self, t_s: f64) -> FlatOutput;
    /// Nominal flight time in seconds.
    fn duration_s(&self) -> f64;
}

/// A geometric curve `c(s)` with its first three derivatives in `s`.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Curve {
    /// Stay at a point.
    Hold { p: Vector3<f64> },
    /// Straight line `a + s(b − a)`, `s ∈ [0, 1]`.
    Line { a: Vector3<f64>, b: Vector3<f64> },
    /// Horizontal circular arc (optionally climbing by `dz`), `θ = θ₀ + sΔθ`, `s ∈ [0, 1]`.
    Arc { centre: Vector3<f64>, radius: f64, theta0: f64, dtheta: f64, dz: f64 },
    /// Gerono lemniscate `centre + [A sin s, B sin 2s, 0]`, `s` = phase in radians.
    Lemniscate { centre: Vector3<f64>, half_width: f64, half_height: f64 },
}

impl Curve {
    /// `[c, c′, c″, c‴]` at parameter `s`.
    fn eval(&self, s: f64) -> [Vector3<f64>; 4] {
        let z = Vector3::zeros();
        match *self {
            Self::Hold { p } => [p, z, z, z],
            Self::Line { a, b } => [a + (b - a) * s, b - a, z, z],
            Self::Arc { centre, radius, theta0, dtheta, dz } => {
                let (sn, cs) = (theta0 + s * dtheta).sin_cos();
                let (r, d) = (radius, dtheta);
                [
                    centre + Vector3::new(r * cs, r * sn, s * dz),
                    Vector3::new(-r * d * sn, r * d * cs, dz),
                    Vector3::new(-r * d * d * cs, -r * d * d * sn, 0.0),
                    Vector3::new(r * d * d * d * sn, -r * d * d * d * cs, 0.0),
                ]
            }
            Self::Lemniscate { centre, half_width: a, half_height: b } => {
                let (s1, c1) = s.sin_cos();
                let (s2, c2) = (2.0 * s).sin_cos();
                [
                    centre + Vector3::new(a * s1, b * s2, 0.0),
                    Vector3::new(a * c1, 2.0 * b * c2, 0.0),
                    Vector3::new(-a * s1, -4.0 * b * s2, 0.0),
                    Vector3::new(-a * c1, -8.0 * b * c2, 0.0),
                ]
            }
        }
    }
}

/// Septic smooth step `S(x) = 35x⁴ − 84x⁵ + 70x⁶ − 20x⁷` and its first three derivatives;
/// `S(0) = 0`, `S(1) = 1`, first to third derivatives zero at both ends.
fn septic(x: f64) -> [f64; 4] {
    let x = x.clamp(0.0, 1.0);
    let x2 = x * x;
    let x3 = x2 * x;
    let x4 = x3 * x;
    [
        x4 * (35.0 - 84.0 * x + 70.0 * x2 - 20.0 * x3),
        x3 * (140.0 - 420.0 * x + 420.0 * x2 - 140.0 * x3),
        x2 * (420.0 - 1680.0 * x + 2100.0 * x2 - 840.0 * x3),
        x * (840.0 - 5040.0 * x + 8400.0 * x2 - 4200.0 * x3),
    ]
}

/// Integral of [`septic`] from 0 to `x`: `7x⁵ − 14x⁶ + 10x⁷ − 2.5x⁸` (equals ½ at 1).
fn septic_integral(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    let x5 = x.powi(5);
    x5 * (7.0 - 14.0 * x + 10.0 * x * x - 2.5 * x * x * x)
}

/// Peak of the septic step's slope, `S′(½) = 35/16`.
pub const SEPTIC_PEAK_SLOPE: f64 = 35.0 / 16.0;

/// Time warp `s(τ)` of one piece with its first three time derivatives.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Warp {
    /// Rest-to-rest septic warp from `s = 0` to `s = 1` over `duration`.
    Septic { duration: f64 },
    /// Phase `s = ω·H(τ)` with `H′ = h`, `h` ramping 0 → 1 over `ramp` (septic), 1 in the middle,
    /// 1 → 0 over the last `ramp`; total phase `ω (duration − ramp)`.
    Ramp { rate: f64, ramp: f64, duration: f64 },
}

impl Warp {
    fn duration(&self) -> f64 {
        match *self {
            Self::Septic { duration } | Self::Ramp { duration, .. } => duration,
        }
    }

    fn eval(&self, tau: f64) -> [f64; 4] {
        match *self {
            Self::Septic { duration } => {
                if duration <= 0.0 {
                    return [1.0, 0.0, 0.0, 0.0];
                }
                let [s, d1, d2, d3] = septic(tau / duration);
                [s, d1 / duration, d2 / (duration * duration), d3 / (duration * duration * duration)]
            }
            Self::Ramp { rate, ramp, duration } => {
                let tau = tau.clamp(0.0, duration);
                let h_total = duration - ramp;
                if tau < ramp {
                    let x = tau / ramp;
                    let [h, h1, h2, _] = septic(x);
                    [rate * ramp * septic_integral(x), rate * h, rate * h1 / ramp, rate * h2 / (ramp * ramp)]
                } else if tau <= duration - ramp {
                    [rate * (0.5 * ramp + (tau - ramp)), rate, 0.0, 0.0]
                } else {
                    let x = (duration - tau) / ramp;
                    let [h, h1, h2, _] = septic(x);
                    [
                        rate * (h_total - ramp * septic_integral(x)),
                        rate * h,
                        -rate * h1 / ramp,
                        rate * h2 / (ramp * ramp),
                    ]
                }
            }
        }
    }
}

/// One piece of a [`PathTrajectory`].
#[derive(Debug, Clone, Copy, PartialEq)]
struct Piece {
    t0: f64,
    curve: Curve,
    warp: Warp,
}

/// A chain of curve pieces flown one after another at constant yaw.
#[derive(Debug, Clone, PartialEq)]
pub struct PathTrajectory {
    pieces: Vec<Piece>,
    yaw: f64,
    duration: f64,
}

impl PathTrajectory {
    /// Start positions of every piece, with their start times (useful to locate scenario events
    /// such as "the second side of the square").
    #[must_use]
    pub fn piece_starts(&self) -> Vec<(f64, Vector3<f64>)> {
        self.pieces.iter().map(|pc| (pc.t0, pc.curve.eval(pc.warp.eval(0.0)[0])[0])).collect()
    }
}

impl Trajectory for PathTrajectory {
    fn flat_output(&self, t_s: f64) -> FlatOutput {
        let t = if t_s.is_nan() { 0.0 } else { t_s.clamp(0.0, self.duration) };
        let idx = self.pieces.partition_point(|pc| pc.t0 <= t).saturating_sub(1);
        let Some(pc) = self.pieces.get(idx) else {
            return FlatOutput::hover(Vector3::zeros(), self.yaw);
        };
        let [s, s1, s2, s3] = pc.warp.eval(t - pc.t0);
        let [c, c1, c2, c3] = pc.curve.eval(s);
        FlatOutput {
            p: c,
            v: c1 * s1,
            a: c2 * (s1 * s1) + c1 * s2,
            j: c3 * (s1 * s1 * s1) + c2 * (3.0 * s1 * s2) + c1 * s3,
            yaw: self.yaw,
            yaw_rate: 0.0,
        }
    }

    fn duration_s(&self) -> f64 {
        self.duration
    }
}

/// Builds a [`PathTrajectory`] piece by piece, flying every line and arc rest-to-rest with a
/// given peak speed.
#[derive(Debug, Clone, PartialEq)]
pub struct PathBuilder {
    pieces: Vec<Piece>,
    pos: Vector3<f64>,
    t: f64,
    speed_mps: f64,
    yaw: f64,
}

impl PathBuilder {
    /// Start at `start` with peak speed `speed_mps` on each piece and constant yaw `yaw`.
    ///
    /// # Errors
    /// [`Error::Config`] if the speed is not positive and finite or `start`/`yaw` is non-finite.
    pub fn new(start: Vector3<f64>, speed_mps: f64, yaw: f64) -> Result<Self> {
        if !(speed_mps.is_finite() && speed_mps > 0.0) {
            return Err(Error::Config { field: "speed_mps", msg: format!("must be positive, got {speed_mps}") });
        }
        if !start.iter().all(|x| x.is_finite()) || !yaw.is_finite() {
            return Err(Error::NonFinite { what: "path start or yaw" });
        }
        Ok(Self { pieces: Vec::new(), pos: start, t: 0.0, speed_mps, yaw })
    }

    /// Current end of the path.
    #[must_use]
    pub fn position(&self) -> Vector3<f64> {
        self.pos
    }

    /// Current end time of the path in seconds.
    #[must_use]
    pub fn time_s(&self) -> f64 {
        self.t
    }

    fn push(&mut self, curve: Curve, warp: Warp) {
        self.pieces.push(Piece { t0: self.t, curve, warp });
        self.t += warp.duration();
    }

    /// Rest-to-rest duration for a piece of length `len_m` at the peak speed.
    fn septic_duration(&self, len_m: f64) -> f64 {
        (SEPTIC_PEAK_SLOPE * len_m / self.speed_mps).max(1e-3)
    }

    /// Hover at the current position for `secs` seconds.
    #[must_use]
    pub fn hold(mut self, secs: f64) -> Self {
        if secs > 0.0 {
            self.push(Curve::Hold { p: self.pos }, Warp::Septic { duration: secs });
        }
        self
    }

    /// Fly a straight line to `to`, starting and ending at rest.
    #[must_use]
    pub fn line_to(mut self, to: Vector3<f64>) -> Self {
        let len = (to - self.pos).norm();
        if len > 0.0 {
            let d = self.septic_duration(len);
            self.push(Curve::Line { a: self.pos, b: to }, Warp::Septic { duration: d });
            self.pos = to;
        }
        self
    }

    /// Fly a horizontal circular arc about `centre_xy` (at the current altitude) through the
    /// signed angle `dtheta` (radians, positive = counter-clockwise seen from above).
    #[must_use]
    pub fn arc(mut self, centre_x: f64, centre_y: f64, dtheta: f64) -> Self {
        let rel = Vector3::new(self.pos.x - centre_x, self.pos.y - centre_y, 0.0);
        let radius = rel.norm();
        if radius > 0.0 && dtheta != 0.0 {
            let centre = Vector3::new(centre_x, centre_y, self.pos.z);
            let theta0 = rel.y.atan2(rel.x);
            let d = self.septic_duration(radius * dtheta.abs());
            let curve = Curve::Arc { centre, radius, theta0, dtheta, dz: 0.0 };
            self.push(curve, Warp::Septic { duration: d });
            self.pos = curve.eval(1.0)[0];
        }
        self
    }

    /// Fly `loops` loops of a Gerono lemniscate (figure eight) centred at the current position
    /// with half extents `half_width` (x) and `half_height` (y), at a constant phase rate that
    /// gives peak speed `speed_mps` at the crossing, with septic ramps of `ramp_s` seconds.
    #[must_use]
    pub fn eight(mut self, half_width: f64, half_height: f64, loops: f64, ramp_s: f64) -> Self {
        let peak = half_width.hypot(2.0 * half_height);
        if peak > 0.0 && loops > 0.0 {
            let rate = self.speed_mps / peak;
            let phase = 2.0 * PI * loops;
            let duration = phase / rate + ramp_s.max(1e-3);
            let curve = Curve::Lemniscate { centre: self.pos, half_width, half_height };
            let warp = Warp::Ramp { rate, ramp: ramp_s.max(1e-3), duration };
            self.push(curve, warp);
            self.pos = curve.eval(warp.eval(duration)[0])[0];
        }
        self
    }

    /// Finish the path.
    #[must_use]
    pub fn build(self) -> PathTrajectory {
        let mut pieces = self.pieces;
        if pieces.is_empty() {
            pieces.push(Piece { t0: 0.0, curve: Curve::Hold { p: self.pos }, warp: Warp::Septic { duration: 0.0 } });
        }
        PathTrajectory { pieces, yaw: self.yaw, duration: self.t }
    }
}

/// Size, altitude and speed of a scenario shape.
///
/// Defaults are a scenario choice (docs/decisions/021-trajectories.md): a 20 m pattern at
/// 10 m altitude flown at 3 m/s peak, the scale of the paper's campus flights.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ShapeConfig {
    /// Characteristic size in metres (square side, eight width, letter height). Default 20.
    pub size_m: f64,
    /// Flight altitude in metres (ENU z). Default 10.
    pub altitude_m: f64,
    /// Peak speed on each piece in m/s. Default 3.
    pub speed_mps: f64,
    /// Hover time before and after the pattern in seconds (lets the estimator settle). Default 3.
    pub hover_s: f64,
}

impl Default for ShapeConfig {
    fn default() -> Self {
        Self { size_m: 20.0, altitude_m: 10.0, speed_mps: 3.0, hover_s: 3.0 }
    }
}

impl ShapeConfig {
    fn check(&self) -> Result<()> {
        for (field, v) in [("size_m", self.size_m), ("speed_mps", self.speed_mps)] {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::Config { field, msg: format!("must be positive, got {v}") });
            }
        }
        for (field, v) in [("altitude_m", self.altitude_m), ("hover_s", self.hover_s)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::Config { field, msg: format!("must be non-negative, got {v}") });
            }
        }
        Ok(())
    }

    fn at(&self, x: f64, y: f64) -> Vector3<f64> {
        Vector3::new(x, y, self.altitude_m)
    }
}

/// Eight-shape (fig:simu1): two loops of a lemniscate `size` wide and `size/2` tall, starting
/// and ending at the centre, where the vehicle takes off.
///
/// # Errors
/// [`Error::Config`] on a non-positive size or speed.
pub fn eight(cfg: &ShapeConfig) -> Result<PathTrajectory> {
    cfg.check()?;
    let s = cfg.size_m;
    Ok(PathBuilder::new(cfg.at(0.0, 0.0), cfg.speed_mps, 0.0)?
        .hold(cfg.hover_s)
        .eight(0.5 * s, 0.25 * s, 2.0, 3.0)
        .hold(cfg.hover_s)
        .build())
}

/// Times `(start, end)` of the first lemniscate loop of [`eight`] (for placing the attack in its
/// second half).
#[must_use]
pub fn eight_first_loop(traj: &PathTrajectory) -> (f64, f64) {
    match traj.pieces.iter().find(|pc| matches!(pc.curve, Curve::Lemniscate { .. })) {
        Some(pc) => {
            if let Warp::Ramp { rate, ramp, .. } = pc.warp {
                // Phase 2π is reached at ramp/2 + 2π/rate after the piece start.
                (pc.t0, pc.t0 + 0.5 * ramp + 2.0 * PI / rate)
            } else {
                (pc.t0, pc.t0 + pc.warp.duration())
            }
        }
        None => (0.0, traj.duration),
    }
}

/// UST-shape (fig:simu2): the letters U, S and T drawn left to right, starting at the top left
/// of the U. Letter height `size`, width `size/2`, gap `size/4`.
///
/// Returns the trajectory and the time at which the S is complete.
///
/// # Errors
/// [`Error::Config`] on a non-positive size or speed.
pub fn ust(cfg: &ShapeConfig) -> Result<(PathTrajectory, f64)> {
    cfg.check()?;
    let h = cfg.size_m;
    let w = 0.5 * h;
    let gap = 0.25 * h;
    let r = 0.25 * h; // S bowl radius; S width = 2r = w
    // U: down the left stroke, half circle through the bottom, up the right stroke.
    let b = PathBuilder::new(cfg.at(0.0, h), cfg.speed_mps, 0.0)?
        .hold(cfg.hover_s)
        .line_to(cfg.at(0.0, 0.5 * w))
        .arc(0.5 * w, 0.5 * w, PI)
        .line_to(cfg.at(w, h));
    // S: start at the right of the upper bowl, counter-clockwise over the top to the middle,
    // then clockwise around the lower bowl to its left side.
    let xs = w + gap + r; // S centre line
    let b = b.line_to(cfg.at(xs + r, 0.75 * h)).arc(xs, 0.75 * h, 1.5 * PI).arc(xs, 0.25 * h, -1.5 * PI);
    let s_done = b.time_s();
    // T: the top bar left to right, back to its middle, down the stem.
    let xt = w + gap + 2.0 * r + gap;
    let b = b
        .line_to(cfg.at(xt, h))
        .line_to(cfg.at(xt + w, h))
        .line_to(cfg.at(xt + 0.5 * w, h))
        .line_to(cfg.at(xt + 0.5 * w, 0.0))
        .hold(cfg.hover_s);
    Ok((b.build(), s_done))
}

/// Diagonal flight (fig:real1): from the lower-left corner `(0, 0)` to the upper-right corner
/// `(size, size)`.
///
/// # Errors
/// [`Error::Config`] on a non-positive size or speed.
pub fn diagonal(cfg: &ShapeConfig) -> Result<PathTrajectory> {
    cfg.check()?;
    let s = cfg.size_m;
    Ok(PathBuilder::new(cfg.at(0.0, 0.0), cfg.speed_mps, 0.0)?
        .hold(cfg.hover_s)
        .line_to(cfg.at(s, s))
        .hold(cfg.hover_s)
        .build())
}

/// Square flight (fig:real2): from the lower-left corner counter-clockwise around a square of
/// side `size`, returning to the start. Side `i` (1-based) is piece `i` of
/// [`PathTrajectory::piece_starts`] (piece 0 is the initial hover).
///
/// # Errors
/// [`Error::Config`] on a non-positive size or speed.
pub fn square(cfg: &ShapeConfig) -> Result<PathTrajectory> {
    cfg.check()?;
    let s = cfg.size_m;
    Ok(PathBuilder::new(cfg.at(0.0, 0.0), cfg.speed_mps, 0.0)?
        .hold(cfg.hover_s)
        .line_to(cfg.at(s, 0.0))
        .line_to(cfg.at(s, s))
        .line_to(cfg.at(0.0, s))
        .line_to(cfg.at(0.0, 0.0))
        .hold(cfg.hover_s)
        .build())
}

/// Number of vehicles in the formation scenario (fig:simu3).
pub const FORMATION_SIZE: usize = 4;

/// Vertex `i` (0-based, counter-clockwise from the lower left) of the formation square of side
/// `size` centred on the origin.
#[must_use]
pub fn formation_vertex(cfg: &ShapeConfig, i: usize) -> Vector3<f64> {
    let h = 0.5 * cfg.size_m;
    match i % FORMATION_SIZE {
        0 => cfg.at(-h, -h),
        1 => cfg.at(h, -h),
        2 => cfg.at(h, h),
        _ => cfg.at(-h, h),
    }
}

/// Four-UAV square formation (fig:simu3): vehicle `idx` (0-based; the paper's "UAV 3" is index
/// 2) starts at vertex `idx` and flies counter-clockwise to the next vertex.
///
/// # Errors
/// [`Error::Config`] on a non-positive size or speed, or `idx ≥ 4`.
pub fn formation_square(cfg: &ShapeConfig, idx: usize) -> Result<PathTrajectory> {
    cfg.check()?;
    if idx >= FORMATION_SIZE {
        return Err(Error::Config { field: "idx", msg: format!("vehicle index {idx} not in 0..{FORMATION_SIZE}") });
    }
    Ok(PathBuilder::new(formation_vertex(cfg, idx), cfg.speed_mps, 0.0)?
        .hold(cfg.hover_s)
        .line_to(formation_vertex(cfg, idx + 1))
        .hold(cfg.hover_s)
        .build())
}

/// Parameters of a random smooth training route.
///
/// Defaults are a choice (docs/decisions/021-trajectories.md) spanning the envelope of small
/// quadrotors: PX4's default horizontal cruise limit is 12 m/s (MPC_XY_VEL_MAX) and its
/// default maximum ascent speed is 3 m/s (MPC_Z_VEL_MAX_UP).
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RandomRouteConfig {
    /// Flight time in seconds. Default 600.
    pub duration_s: f64,
    /// Lowest route RMS horizontal speed in m/s. Default 0.5.
    pub speed_min_mps: f64,
    /// Highest route RMS horizontal speed in m/s. Default 12 (PX4 MPC_XY_VEL_MAX).
    pub speed_max_mps: f64,
    /// Lowest mean altitude in m. Default 5.
    pub altitude_min_m: f64,
    /// Highest mean altitude in m. Default 100.
    pub altitude_max_m: f64,
    /// Highest RMS vertical speed in m/s. Default 1.5 (half of PX4 MPC_Z_VEL_MAX_UP).
    pub climb_max_mps: f64,
    /// Lowest angular frequency of the sinusoids in rad/s. Default 0.03.
    pub omega_min: f64,
    /// Highest angular frequency of the sinusoids in rad/s. Default 0.3 (keeps tilt below
    /// about 35° at the top speed).
    pub omega_max: f64,
    /// Highest RMS yaw rate in rad/s. Default 0.3.
    pub yaw_rate_max: f64,
}

impl Default for RandomRouteConfig {
    fn default() -> Self {
        Self {
            duration_s: 600.0,
            speed_min_mps: 0.5,
            speed_max_mps: 12.0,
            altitude_min_m: 5.0,
            altitude_max_m: 100.0,
            climb_max_mps: 1.5,
            omega_min: 0.03,
            omega_max: 0.3,
            yaw_rate_max: 0.3,
        }
    }
}

/// Sinusoids per axis of a [`RandomRoute`].
const HARMONICS: usize = 3;

/// One axis: `offset + Σ Aᵢ (sin(ωᵢ t + φᵢ) − sin φᵢ)`.
#[derive(Debug, Clone, Copy, PartialEq)]
struct SineAxis {
    offset: f64,
    amp: [f64; HARMONICS],
    omega: [f64; HARMONICS],
    phase: [f64; HARMONICS],
}

impl SineAxis {
    /// Random axis with RMS rate `rms_rate` (value units per second).
    fn random(rng: &mut StdRng, offset: f64, rms_rate: f64, omega: (f64, f64)) -> Self {
        let mut w = [0.0; HARMONICS];
        let mut om = [0.0; HARMONICS];
        let mut ph = [0.0; HARMONICS];
        for i in 0..HARMONICS {
            w[i] = rng.random_range(0.2..1.0);
            om[i] = if omega.1 > omega.0 { rng.random_range(omega.0..omega.1) } else { omega.0 };
            ph[i] = rng.random_range(0.0..2.0 * PI);
        }
        // Rate amplitude Aᵢωᵢ = c·wᵢ; RMS rate = c·√(Σwᵢ²/2) = rms_rate.
        let norm = (w.iter().map(|x| x * x).sum::<f64>() / 2.0).sqrt();
        let c = rms_rate / norm;
        let mut amp = [0.0; HARMONICS];
        for i in 0..HARMONICS {
            amp[i] = c * w[i] / om[i];
        }
        Self { offset, amp, omega: om, phase: ph }
    }

    fn scale(&mut self, k: f64) {
        for a in &mut self.amp {
            *a *= k;
        }
    }

    fn eval(&self, t: f64) -> [f64; 4] {
        let mut out = [self.offset, 0.0, 0.0, 0.0];
        for i in 0..HARMONICS {
            let (a, w) = (self.amp[i], self.omega[i]);
            let (s, c) = (w * t + self.phase[i]).sin_cos();
            out[0] += a * (s - self.phase[i].sin());
            out[1] += a * w * c;
            out[2] -= a * w * w * s;
            out[3] -= a * w * w * w * c;
        }
        out
    }
}

/// A long random smooth route for training flights: per axis a sum of three sinusoids with
/// random frequencies and phases, scaled to a random RMS speed and mean altitude drawn from
/// [`RandomRouteConfig`]. Starts at `(0, 0, h₀)`; the altitude stays within `[h₀/2, 3h₀/2]`.
#[derive(Debug, Clone, PartialEq)]
pub struct RandomRoute {
    axes: [SineAxis; 3],
    yaw: SineAxis,
    duration: f64,
    speed_mps: f64,
    altitude_m: f64,
}

impl RandomRoute {
    /// Draw a route from `cfg` with `seed`.
    ///
    /// # Errors
    /// [`Error::Config`] when a range is empty, reversed or not finite.
    pub fn new(cfg: &RandomRouteConfig, seed: u64) -> Result<Self> {
        let positive = [
            ("duration_s", cfg.duration_s),
            ("speed_min_mps", cfg.speed_min_mps),
            ("altitude_min_m", cfg.altitude_min_m),
            ("omega_min", cfg.omega_min),
        ];
        for (field, v) in positive {
            if !(v.is_finite() && v > 0.0) {
                return Err(Error::Config { field, msg: format!("must be positive, got {v}") });
            }
        }
        let ranges = [
            ("speed_max_mps", cfg.speed_min_mps, cfg.speed_max_mps),
            ("altitude_max_m", cfg.altitude_min_m, cfg.altitude_max_m),
            ("omega_max", cfg.omega_min, cfg.omega_max),
        ];
        for (field, lo, hi) in ranges {
            if !(hi.is_finite() && hi >= lo) {
                return Err(Error::Config { field, msg: format!("must be finite and >= {lo}, got {hi}") });
            }
        }
        for (field, v) in [("climb_max_mps", cfg.climb_max_mps), ("yaw_rate_max", cfg.yaw_rate_max)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::Config { field, msg: format!("must be non-negative, got {v}") });
            }
        }
        let mut rng = StdRng::seed_from_u64(seed);
        let draw = |rng: &mut StdRng, lo: f64, hi: f64| if hi > lo { rng.random_range(lo..hi) } else { lo };
        let speed = draw(&mut rng, cfg.speed_min_mps, cfg.speed_max_mps);
        let altitude = draw(&mut rng, cfg.altitude_min_m, cfg.altitude_max_m);
        let climb = draw(&mut rng, 0.0, cfg.climb_max_mps);
        let yaw_rate = draw(&mut rng, 0.0, cfg.yaw_rate_max);
        let omega = (cfg.omega_min, cfg.omega_max);
        let per_axis = speed / std::f64::consts::SQRT_2;
        let x = SineAxis::random(&mut rng, 0.0, per_axis, omega);
        let y = SineAxis::random(&mut rng, 0.0, per_axis, omega);
        let mut z = SineAxis::random(&mut rng, altitude, climb, omega);
        // Keep the altitude within [h₀/2, 3h₀/2]: the offset from h₀ is at most 2·Σ|Aᵢ|.
        let reach = 2.0 * z.amp.iter().map(|a| a.abs()).sum::<f64>();
        if reach > 0.5 * altitude {
            z.scale(0.5 * altitude / reach);
        }
        let yaw0 = rng.random_range(-PI..PI);
        let yaw = SineAxis::random(&mut rng, yaw0, yaw_rate, omega);
        Ok(Self { axes: [x, y, z], yaw, duration: cfg.duration_s, speed_mps: speed, altitude_m: altitude })
    }

    /// The route's RMS horizontal speed in m/s.
    #[must_use]
    pub fn speed_mps(&self) -> f64 {
        self.speed_mps
    }

    /// The route's mean altitude `h₀` in metres.
    #[must_use]
    pub fn altitude_m(&self) -> f64 {
        self.altitude_m
    }
}

impl Trajectory for RandomRoute {
    fn flat_output(&self, t_s: f64) -> FlatOutput {
        let t = if t_s.is_nan() { 0.0 } else { t_s };
        let [x, y, z] = [self.axes[0].eval(t), self.axes[1].eval(t), self.axes[2].eval(t)];
        let yaw = self.yaw.eval(t);
        FlatOutput {
            p: Vector3::new(x[0], y[0], z[0]),
            v: Vector3::new(x[1], y[1], z[1]),
            a: Vector3::new(x[2], y[2], z[2]),
            j: Vector3::new(x[3], y[3], z[3]),
            yaw: yaw[0],
            yaw_rate: yaw[1],
        }
    }

    fn duration_s(&self) -> f64 {
        self.duration
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Central differences of p, v, a must match v, a, j (step 1e-4 s; error O(h²·snap) ≲ 1e-6
    /// for these speeds, far below the 1e-4 tolerance).
    fn check_derivatives(traj: &dyn Trajectory) {
        let h = 1e-4;
        let n = 400;
        for i in 1..n {
            let t = traj.duration_s() * i as f64 / n as f64;
            let (m, c, p) = (traj.flat_output(t - h), traj.flat_output(t), traj.flat_output(t + h));
            let dv = (p.p - m.p) / (2.0 * h);
            let da = (p.v - m.v) / (2.0 * h);
            let dj = (p.a - m.a) / (2.0 * h);
            assert!((dv - c.v).norm() < 1e-4 * (1.0 + c.v.norm()), "v at {t}: {dv} vs {}", c.v);
            assert!((da - c.a).norm() < 1e-4 * (1.0 + c.a.norm()), "a at {t}: {da} vs {}", c.a);
            assert!((dj - c.j).norm() < 1e-3 * (1.0 + c.j.norm()), "j at {t}: {dj} vs {}", c.j);
            let dyaw = (p.yaw - m.yaw) / (2.0 * h);
            assert!((dyaw - c.yaw_rate).abs() < 1e-6 * (1.0 + c.yaw_rate.abs()));
        }
    }

    #[test]
    fn scenario_shapes_are_smooth() {
        let cfg = ShapeConfig::default();
        check_derivatives(&eight(&cfg).unwrap());
        check_derivatives(&ust(&cfg).unwrap().0);
        check_derivatives(&diagonal(&cfg).unwrap());
        check_derivatives(&square(&cfg).unwrap());
        for i in 0..FORMATION_SIZE {
            check_derivatives(&formation_square(&cfg, i).unwrap());
        }
        check_derivatives(
            &RandomRoute::new(&RandomRouteConfig { duration_s: 120.0, ..Default::default() }, 5).unwrap(),
        );
    }

    #[test]
    fn square_returns_home_counter_clockwise() {
        let cfg = ShapeConfig::default();
        let sq = square(&cfg).unwrap();
        let start = sq.flat_output(0.0).p;
        let end = sq.flat_output(sq.duration_s()).p;
        assert!((start - end).norm() < 1e-9);
        let starts = sq.piece_starts();
        // Side 1 goes east, side 2 north: counter-clockwise seen from above.
        assert!((starts[2].1 - cfg.at(cfg.size_m, 0.0)).norm() < 1e-9);
        assert!((starts[3].1 - cfg.at(cfg.size_m, cfg.size_m)).norm() < 1e-9);
    }

    #[test]
    fn eight_flies_two_loops_through_the_centre() {
        let cfg = ShapeConfig::default();
        let e = eight(&cfg).unwrap();
        let (t0, t1) = eight_first_loop(&e);
        assert!((e.flat_output(t0).p - e.flat_output(t1).p).norm() < 1e-6);
        assert!((e.flat_output(e.duration_s()).p - e.flat_output(0.0).p).norm() < 1e-6);
        let max_speed =
            (0..1000).map(|i| e.flat_output(e.duration_s() * i as f64 / 1000.0).v.norm()).fold(0.0, f64::max);
        assert!((max_speed - cfg.speed_mps).abs() < 0.05 * cfg.speed_mps, "{max_speed}");
    }

    #[test]
    fn formation_vehicles_move_to_next_vertex() {
        let cfg = ShapeConfig::default();
        for i in 0..FORMATION_SIZE {
            let tr = formation_square(&cfg, i).unwrap();
            assert!((tr.flat_output(tr.duration_s()).p - formation_vertex(&cfg, i + 1)).norm() < 1e-9);
        }
        assert!(formation_square(&cfg, 4).is_err());
    }

    #[test]
    fn random_routes_are_seeded_and_stay_in_the_envelope() {
        let cfg = RandomRouteConfig::default();
        let a = RandomRoute::new(&cfg, 1).unwrap();
        assert_eq!(a, RandomRoute::new(&cfg, 1).unwrap());
        assert_ne!(a, RandomRoute::new(&cfg, 2).unwrap());
        for seed in 0..20 {
            let r = RandomRoute::new(&cfg, seed).unwrap();
            for i in 0..600 {
                let f = r.flat_output(i as f64);
                assert!(f.p.z >= 0.5 * r.altitude_m() - 1e-9 && f.p.z <= 1.5 * r.altitude_m() + 1e-9);
                // Tilt below 60°: horizontal acceleration below g·tan 60°.
                assert!(f.a.xy().norm() < 9.81 * 3f64.sqrt(), "seed {seed} t {i}: {}", f.a);
            }
        }
        let bad = RandomRouteConfig { speed_max_mps: 0.1, ..cfg };
        assert!(matches!(RandomRoute::new(&bad, 0), Err(Error::Config { field: "speed_max_mps", .. })));
    }
}
