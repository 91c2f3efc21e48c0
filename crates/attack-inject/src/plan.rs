//! Attack plans: the seeded schedule of attack intervals of one flight, and the per-sample
//! attacked GPS fix it implies (paper eq:fdi, `y_k = g(x_k) + v_k + d_k`).
//!
//! An interval is active on the half-open time range `(t0, t1]` (seconds). Offsets `d_k` are in
//! the local ENU frame in metres. A plan is a pure function of time plus the clean GPS history,
//! so the same plan serves batch injection ([`crate::inject()`]) and closed-loop fusion, which
//! injects step by step with [`AttackPlan::apply`].

use nalgebra::Vector3;
use rand::rngs::StdRng;
use rand::{RngExt, SeedableRng};
use rand_distr::StandardNormal;
use serde::{Deserialize, Serialize};
use uav_dynamics::GpsSample;

use crate::config::{AmplitudeConfig, AttackConfig, AttackKind, DirectionMode, ValidAttackConfig};
use crate::error::{AttackError, Result};

/// What an attack interval does to the GPS fixes inside it.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum AttackShape {
    /// Attack I burst: constant offset `d` (metres, ENU) for the whole interval.
    Burst {
        /// The injected offset `d_k`.
        offset: Vector3<f64>,
    },
    /// Attack II constant bias `d` (metres, ENU).
    Bias {
        /// The injected offset `d_k`.
        offset: Vector3<f64>,
    },
    /// Attack II ramp (drift spoofing): `d(t) = offset_end · (t − t0)/(t1 − t0)`, reaching
    /// `offset_end` at `t1`; slope `‖offset_end‖/(t1 − t0)` in m/s.
    Ramp {
        /// Offset at the end of the interval.
        offset_end: Vector3<f64>,
    },
    /// Replay: the fix sent at `t` is the last clean fix at or before `t − delay_s`.
    Replay {
        /// Replay delay in seconds.
        delay_s: f64,
    },
    /// Freeze: the fix sent is the last clean fix at or before `t0`.
    Freeze,
    /// Oscillating offset `d(t) = amplitude · sin(2π · freq_hz · (t − t0))`.
    Oscillating {
        /// Peak offset (metres, ENU).
        amplitude: Vector3<f64>,
        /// Oscillation frequency in Hz.
        freq_hz: f64,
    },
    /// Random noise injection: `d_k ~ N(0, (amplitude_m²/3)·I₃)` (RMS norm `amplitude_m`), drawn
    /// from a generator seeded by `(seed, t_k)` so it is reproducible online.
    Noise {
        /// RMS norm of the offset in metres.
        amplitude_m: f64,
        /// Seed of the per-sample draws.
        seed: u64,
    },
}

/// One attack interval, active on `(t0, t1]` seconds.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AttackInterval {
    /// Start time in seconds (exclusive).
    pub t0: f64,
    /// End time in seconds (inclusive).
    pub t1: f64,
    /// What the attack does.
    pub shape: AttackShape,
}

impl AttackInterval {
    /// Whether `t` lies in `(t0, t1]`.
    #[must_use]
    pub fn contains(&self, t: f64) -> bool {
        t > self.t0 && t <= self.t1
    }

    /// Duration in seconds.
    #[must_use]
    pub fn duration_s(&self) -> f64 {
        self.t1 - self.t0
    }
}

/// The outcome of attacking one GPS sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AttackedSample {
    /// The fix the estimator receives.
    pub gps: GpsSample,
    /// `d_k = gps.p − clean.p` in metres (zero when not attacked).
    pub offset: Vector3<f64>,
    /// Ground-truth label: the sent fix differs from the clean one.
    pub attacked: bool,
}

/// A seeded schedule of non-overlapping attack intervals for one flight, sorted by time.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AttackPlan {
    intervals: Vec<AttackInterval>,
}

/// Attack-plan sampling state: one seeded generator drives every draw, in a fixed order.
struct Sampler<'a> {
    cfg: &'a AttackConfig,
    rng: StdRng,
}

impl Sampler<'_> {
    fn uniform(&mut self, r: [f64; 2]) -> f64 {
        if r[1] > r[0] { self.rng.random_range(r[0]..=r[1]) } else { r[0] }
    }

    /// Amplitude `‖d‖` in metres.
    fn amplitude_m(&mut self) -> f64 {
        let sigma = self.cfg.gps_sigma_m;
        match self.cfg.amplitude {
            AmplitudeConfig::Range { min_sigma, max_m } => {
                // Log-uniform: each decade of amplitude equally likely (decision 030).
                let lo = (min_sigma * sigma).ln();
                let hi = max_m.ln();
                self.uniform([lo, hi]).exp()
            }
            AmplitudeConfig::Fixed { sigma_multiple } => sigma_multiple * sigma,
        }
    }

    fn direction(&mut self) -> Vector3<f64> {
        match self.cfg.direction {
            DirectionMode::Sphere => {
                // Uniform on S²: z = cos(polar) uniform in [−1, 1], azimuth uniform.
                let z: f64 = self.rng.random_range(-1.0..=1.0);
                let az: f64 = self.rng.random_range(0.0..std::f64::consts::TAU);
                let rho = (1.0 - z * z).max(0.0).sqrt();
                Vector3::new(rho * az.cos(), rho * az.sin(), z)
            }
            DirectionMode::Horizontal => {
                let az: f64 = self.rng.random_range(0.0..std::f64::consts::TAU);
                Vector3::new(az.cos(), az.sin(), 0.0)
            }
        }
    }

    /// The shape of an interval of `duration_s` seconds.
    fn shape(&mut self, duration_s: f64) -> AttackShape {
        match self.cfg.kind {
            AttackKind::Sparse => AttackShape::Burst { offset: self.amplitude_m() * self.direction() },
            AttackKind::Persistent => {
                let ramp = self.rng.random::<f64>() < self.cfg.ramp_probability;
                let offset = self.amplitude_m() * self.direction();
                match (ramp, self.cfg.ramp_slope_mps) {
                    (false, _) => AttackShape::Bias { offset },
                    (true, None) => AttackShape::Ramp { offset_end: offset },
                    (true, Some([lo, hi])) => {
                        // Log-uniform slope; the direction is the drawn offset's.
                        let slope = self.uniform([lo.ln(), hi.ln()]).exp();
                        let dir = offset.try_normalize(0.0).unwrap_or_else(Vector3::x);
                        AttackShape::Ramp { offset_end: dir * (slope * duration_s) }
                    }
                }
            }
            AttackKind::Oscillating => {
                let amplitude = self.amplitude_m() * self.direction();
                AttackShape::Oscillating { amplitude, freq_hz: self.uniform(self.cfg.oscillation_hz) }
            }
            AttackKind::Replay => AttackShape::Replay { delay_s: self.uniform(self.cfg.replay_delay_s) },
            AttackKind::Freeze => AttackShape::Freeze,
            AttackKind::Noise => AttackShape::Noise { amplitude_m: self.amplitude_m(), seed: self.rng.random() },
        }
    }
}

impl AttackPlan {
    /// A plan without attacks.
    #[must_use]
    pub const fn empty() -> Self {
        Self { intervals: Vec::new() }
    }

    /// A plan from hand-written intervals (e.g. a scripted closed-loop scenario).
    ///
    /// # Errors
    /// [`AttackError::InvalidInterval`] if an interval is empty or non-finite, intervals overlap
    /// or are unsorted, or a shape parameter is non-finite (or a replay delay is not positive).
    pub fn from_intervals(intervals: Vec<AttackInterval>) -> Result<Self> {
        let mut prev_t1 = f64::NEG_INFINITY;
        for (interval_idx, iv) in intervals.iter().enumerate() {
            let bad = |reason| AttackError::InvalidInterval { interval_idx, reason };
            if !(iv.t0.is_finite() && iv.t1.is_finite() && iv.t1 > iv.t0) {
                return Err(bad("times must be finite with t1 > t0"));
            }
            if iv.t0 < prev_t1 {
                return Err(bad("intervals must be sorted and non-overlapping"));
            }
            let shape_ok = match iv.shape {
                AttackShape::Burst { offset } | AttackShape::Bias { offset } => offset.iter().all(|v| v.is_finite()),
                AttackShape::Ramp { offset_end } => offset_end.iter().all(|v| v.is_finite()),
                AttackShape::Replay { delay_s } => delay_s.is_finite() && delay_s > 0.0,
                AttackShape::Freeze => true,
                AttackShape::Noise { amplitude_m, .. } => amplitude_m.is_finite() && amplitude_m >= 0.0,
                AttackShape::Oscillating { amplitude, freq_hz } => {
                    amplitude.iter().all(|v| v.is_finite()) && freq_hz.is_finite() && freq_hz > 0.0
                }
            };
            if !shape_ok {
                return Err(bad("shape parameters must be finite (replay delay and frequency > 0)"));
            }
            prev_t1 = iv.t1;
        }
        Ok(Self { intervals })
    }

    /// Draw a plan for a flight whose GPS fixes span `[t_start, t_end]` seconds.
    ///
    /// Interval durations are drawn from the kind's range until their total reaches
    /// `attacked_fraction · (t_end − t_start)`: the last one is shortened to hit the target (or
    /// dropped when less than half its minimum duration is missing). The intervals are then
    /// placed in random order with random clean gaps (at least `min_gap_s`) after the warm-up
    /// (plus the longest replay delay, so a replay always has recorded fixes to send).
    /// Every draw comes from one `StdRng` seeded with `seed`, so the plan is deterministic.
    ///
    /// # Errors
    /// [`AttackError::InvalidWindow`] for a non-finite or empty window,
    /// [`AttackError::PlanDoesNotFit`] if the attacked time plus gaps exceed the window.
    pub fn sample(cfg: &ValidAttackConfig, t_start: f64, t_end: f64, seed: u64) -> Result<Self> {
        let cfg = cfg.get();
        if !(t_start.is_finite() && t_end.is_finite() && t_end > t_start) {
            return Err(AttackError::InvalidWindow { t_start, t_end });
        }
        let mut s = Sampler { cfg, rng: StdRng::seed_from_u64(seed) };
        let target_s = cfg.attacked_fraction * (t_end - t_start);
        let [d_min, d_max] = cfg.durations.of(cfg.kind);

        // Durations until the attacked-time budget is spent.
        let mut durations = Vec::new();
        let mut total = 0.0;
        loop {
            let remaining = target_s - total;
            if remaining <= 0.0 {
                break;
            }
            let mut d = s.uniform([d_min, d_max]);
            if d > remaining {
                if remaining >= d_min {
                    d = remaining;
                } else if remaining >= 0.5 * d_min {
                    d = d_min;
                } else {
                    break;
                }
            }
            durations.push(d);
            total += d;
        }
        if durations.is_empty() {
            return Ok(Self::empty());
        }

        let lead_s = cfg.warmup_s + if cfg.kind == AttackKind::Replay { cfg.replay_delay_s[1] } else { 0.0 };
        let first = t_start + lead_s;
        let available_s = t_end - first;
        let n = durations.len();
        #[allow(clippy::cast_precision_loss)] // n is a small count.
        let needed_s = total + cfg.min_gap_s * (n as f64 - 1.0).max(0.0);
        if needed_s > available_s {
            return Err(AttackError::PlanDoesNotFit { needed_s, available_s });
        }
        // Free time split into n + 1 gaps by sorted uniform cut points (a uniform point on the
        // simplex), then the fixed minimum gaps are added between intervals.
        let free_s = available_s - needed_s;
        let mut cuts: Vec<f64> = (0..n).map(|_| s.rng.random::<f64>() * free_s).collect();
        cuts.sort_by(f64::total_cmp);
        let mut intervals = Vec::with_capacity(n);
        let mut prev_cut = 0.0;
        let mut cursor = first;
        for (i, (&d, &cut)) in durations.iter().zip(&cuts).enumerate() {
            cursor += cut - prev_cut + if i > 0 { cfg.min_gap_s } else { 0.0 };
            prev_cut = cut;
            let shape = s.shape(d);
            intervals.push(AttackInterval { t0: cursor, t1: cursor + d, shape });
            cursor += d;
        }
        Ok(Self { intervals })
    }

    /// The intervals, sorted by time.
    #[must_use]
    pub fn intervals(&self) -> &[AttackInterval] {
        &self.intervals
    }

    /// Total attacked time in seconds.
    #[must_use]
    pub fn attacked_time_s(&self) -> f64 {
        self.intervals.iter().map(AttackInterval::duration_s).sum()
    }

    /// The interval active at `t`, if any.
    #[must_use]
    pub fn active_at(&self, t: f64) -> Option<&AttackInterval> {
        // Intervals are sorted and disjoint: the candidate is the last one with t0 < t.
        let idx = self.intervals.partition_point(|iv| iv.t0 < t);
        idx.checked_sub(1).and_then(|i| self.intervals.get(i)).filter(|iv| iv.contains(t))
    }

    /// Attack one clean GPS fix, online: `history` holds the clean fixes received before
    /// `clean` (sorted by time; only replay and freeze read it, and only its tail matters).
    ///
    /// Additive shapes send `clean.p + d_k` (eq:fdi); replay and freeze send a recorded fix's
    /// position with the current time stamp. When the recorded fix a replay or freeze needs is
    /// not in `history`, the sample passes through clean.
    #[must_use]
    pub fn apply(&self, clean: &GpsSample, history: &[GpsSample]) -> AttackedSample {
        let passthrough = AttackedSample { gps: *clean, offset: Vector3::zeros(), attacked: false };
        let Some(iv) = self.active_at(clean.t) else {
            return passthrough;
        };
        let recorded_at = |t_rec: f64| -> Option<Vector3<f64>> {
            let idx = history.partition_point(|g| g.t <= t_rec);
            idx.checked_sub(1).and_then(|i| history.get(i)).map(|g| g.p)
        };
        // eq:fdi: y_k = g(x_k) + v_k + d_k.
        let p = match iv.shape {
            AttackShape::Burst { offset } | AttackShape::Bias { offset } => clean.p + offset,
            AttackShape::Ramp { offset_end } => clean.p + offset_end * ((clean.t - iv.t0) / iv.duration_s()),
            AttackShape::Oscillating { amplitude, freq_hz } => {
                clean.p + amplitude * (std::f64::consts::TAU * freq_hz * (clean.t - iv.t0)).sin()
            }
            AttackShape::Replay { delay_s } => match recorded_at(clean.t - delay_s) {
                Some(p) => p,
                None => return passthrough,
            },
            AttackShape::Freeze => match recorded_at(iv.t0) {
                Some(p) => p,
                None => return passthrough,
            },
            AttackShape::Noise { amplitude_m, seed } => {
                let mut rng = StdRng::seed_from_u64(mix(seed, clean.t.to_bits()));
                let sd = amplitude_m / 3f64.sqrt();
                let n = Vector3::from_fn(|_, _| rng.sample::<f64, _>(StandardNormal));
                clean.p + sd * n
            }
        };
        let attacked = p != clean.p;
        AttackedSample { gps: GpsSample { t: clean.t, p }, offset: p - clean.p, attacked }
    }
}

/// SplitMix64 finaliser of `a ⊕ rot(b)`: a well-spread per-sample seed from two words.
fn mix(a: u64, b: u64) -> u64 {
    let mut z = a ^ b.rotate_left(29) ^ 0x9E37_79B9_7F4A_7C15;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}
