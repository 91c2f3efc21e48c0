//! Synthetic Model-I-like residue series for tests, benchmarks and examples.
//!
//! Channels are `gps_x, gps_y, gps_z` (m, ENU) and `att_roll, att_pitch, att_yaw` (rad), with a
//! constant diagonal `S_k` (σ_gps = 0.7 m, roughly PX4's 0.5 m GPS floor plus prior position
//! variance; σ_att = 0.02 rad) and i.i.d. residues of a chosen shape scaled to that σ. An attack
//! adds a GPS bias to the residues over `[start_s, end_s)` and labels those steps.
//!
//! The absorbed-bias model (used for the paper's Fig. 9 effect, fig:CUSUM_3_plots) stands in
//! for a filter that fuses the spoofed GPS: during the attack the residue offset decays as
//! `B·e^{−(t−t₀)/τ_a}` because the estimate moves towards the spoofed position, and after the
//! attack ends the estimate is off by `B(1 − e^{−(t₁−t₀)/τ_a})`, so the residue carries the
//! opposite offset, decaying with the same `τ_a`, on steps labelled clean.

use ekf_residue::{LabelledSeries, ResidueError, ResidueSeries};
use rand::{RngExt, SeedableRng};

/// Names of the six synthetic channels.
pub const CHANNELS: [&str; 6] = ["gps_x", "gps_y", "gps_z", "att_roll", "att_pitch", "att_yaw"];

/// Shape of the synthetic residue noise, always scaled to the channel's σ.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoiseShape {
    /// Normal.
    Gaussian,
    /// Laplace with scale `σ/√2`.
    Laplace,
    /// Exponential with rate `1/σ`, centred.
    Exponential,
}

/// A GPS bias injected into the residues.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SyntheticAttack {
    /// Onset in seconds.
    pub start_s: f64,
    /// End (exclusive) in seconds.
    pub end_s: f64,
    /// Bias on `gps_x, gps_y, gps_z` in metres.
    pub bias_m: [f64; 3],
    /// Time constant of bias absorption by the filter in seconds; `None` keeps the full bias in
    /// the residue (a filter that does not fuse the spoofed samples).
    pub absorb_tau_s: Option<f64>,
}

/// A synthetic flight's residues.
#[derive(Debug, Clone, PartialEq)]
pub struct SyntheticFlight {
    /// Number of residue steps.
    pub n_steps: usize,
    /// Step in seconds (10 Hz GPS: 0.1).
    pub dt_s: f64,
    /// GPS residue σ in metres.
    pub sigma_gps_m: f64,
    /// Attitude residue σ in radians.
    pub sigma_att_rad: f64,
    /// Noise shape.
    pub noise: NoiseShape,
    /// Seed of the noise.
    pub seed: u64,
}

impl SyntheticFlight {
    /// A Gaussian flight of `n_steps` at 10 Hz with σ_gps = 0.7 m and σ_att = 0.02 rad.
    pub fn new(n_steps: usize, seed: u64) -> Self {
        Self { n_steps, dt_s: 0.1, sigma_gps_m: 0.7, sigma_att_rad: 0.02, noise: NoiseShape::Gaussian, seed }
    }

    /// Generates the residues with the given attacks and their labels.
    ///
    /// # Errors
    /// [`ResidueError`] if the parameters produce an invalid series (e.g. a zero σ).
    pub fn generate(&self, attacks: &[SyntheticAttack]) -> Result<LabelledSeries, ResidueError> {
        let mut rng = rand::rngs::StdRng::seed_from_u64(self.seed);
        let sigma = [
            self.sigma_gps_m,
            self.sigma_gps_m,
            self.sigma_gps_m,
            self.sigma_att_rad,
            self.sigma_att_rad,
            self.sigma_att_rad,
        ];
        let m = sigma.len();
        let mut t = Vec::with_capacity(self.n_steps);
        let mut r = Vec::with_capacity(self.n_steps * m);
        let mut s = Vec::with_capacity(self.n_steps * m * m);
        let mut labels = Vec::with_capacity(self.n_steps);
        for k in 0..self.n_steps {
            let t_k = k as f64 * self.dt_s;
            t.push(t_k);
            let mut offset = [0.0; 3];
            let mut attacked = false;
            for a in attacks {
                let (gain, active) = attack_gain(a, t_k);
                attacked |= active;
                for (o, b) in offset.iter_mut().zip(a.bias_m) {
                    *o += gain * b;
                }
            }
            labels.push(attacked);
            for (i, sig) in sigma.iter().enumerate() {
                let e = sample(&mut rng, self.noise) * sig;
                r.push(e + if i < 3 { offset[i] } else { 0.0 });
            }
            for (i, sig) in sigma.iter().enumerate() {
                s.extend((0..m).map(|j| if i == j { sig * sig } else { 0.0 }));
            }
        }
        let series = ResidueSeries::from_flat(t, CHANNELS.iter().map(|c| (*c).to_owned()).collect(), r, s)?;
        LabelledSeries::new(series, Some(labels))
    }
}

/// Fraction of the bias present in the residue at `t_s`, and whether the step is attacked.
fn attack_gain(a: &SyntheticAttack, t_s: f64) -> (f64, bool) {
    let active = t_s >= a.start_s && t_s < a.end_s;
    match a.absorb_tau_s {
        None => (if active { 1.0 } else { 0.0 }, active),
        Some(tau) if active => ((-(t_s - a.start_s) / tau).exp(), true),
        Some(tau) if t_s >= a.end_s => {
            let absorbed = 1.0 - (-(a.end_s - a.start_s) / tau).exp();
            (-absorbed * (-(t_s - a.end_s) / tau).exp(), false)
        }
        Some(_) => (0.0, false),
    }
}

/// One unit-variance, zero-mean sample of the shape.
fn sample(rng: &mut rand::rngs::StdRng, shape: NoiseShape) -> f64 {
    let exp1 = |rng: &mut rand::rngs::StdRng| -(1.0 - rng.random::<f64>()).ln();
    match shape {
        NoiseShape::Gaussian => {
            let u1: f64 = 1.0 - rng.random::<f64>();
            let u2: f64 = rng.random();
            (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
        }
        // Laplace(0, 1/√2) = (E1 − E2)/√2 has unit variance.
        NoiseShape::Laplace => (exp1(rng) - exp1(rng)) / std::f64::consts::SQRT_2,
        NoiseShape::Exponential => exp1(rng) - 1.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clean_nis_has_mean_m_and_labels_follow_attack() {
        let f = SyntheticFlight::new(5000, 1)
            .generate(&[SyntheticAttack { start_s: 10.0, end_s: 20.0, bias_m: [20.0, 0.0, 0.0], absorb_tau_s: None }])
            .unwrap();
        let labels = f.labels().unwrap();
        assert_eq!(labels.iter().filter(|&&l| l).count(), 100);
        let clean: Vec<f64> = f.series().nis().iter().zip(labels).filter(|(_, l)| !**l).map(|(z, _)| *z).collect();
        let mean = clean.iter().sum::<f64>() / clean.len() as f64;
        assert!((mean - 6.0).abs() < 0.3, "{mean}");
    }

    #[test]
    fn absorbed_bias_flips_sign_after_the_attack() {
        let a = SyntheticAttack { start_s: 0.0, end_s: 10.0, bias_m: [1.0; 3], absorb_tau_s: Some(2.0) };
        assert!((attack_gain(&a, 0.0).0 - 1.0).abs() < 1e-12);
        let (after, attacked) = attack_gain(&a, 10.0);
        assert!(!attacked && after < -0.99);
    }
}
