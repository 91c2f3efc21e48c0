//! The streaming LSTM detector ([`LstmOnline`]): each new residue is scored as the last step of
//! the window of the `l` latest ones, exactly as the batch forward pass of
//! [`crate::nn::LstmNet`] scores that window, without candle.
//!
//! The LSTM restarts from a zero state at every window start (module docs of [`crate::nn`]), so
//! each decision runs the recurrence over the whole window again: `l` products
//! `h_{t−1} W_hhᵀ` and cells. What does not depend on the window start is kept: the input
//! projection `x_t W_ihᵀ` of every step is computed once, when the step arrives, and held in
//! a ring of the `l` latest. Until `l` steps have been seen, the window is front-padded with
//! the first step, as [`nn_toolkit::Windows`] pads.
//!
//! Every product goes through the `gemm` kernel with the shapes and strides candle's `matmul`
//! gives it ([`nn_toolkit::matmul`]), the cell through [`crate::lstm`]'s own forward, and the
//! additions in candle's order (`(x W_ihᵀ + h W_hhᵀ) + b`), so a decision is bit for bit the
//! one [`ekf_residue::WindowedOnline`] computes by re-scoring the window with candle
//! (`streaming_lstm_matches_the_windowed_candle_pass`) at a fraction of its cost: candle
//! spends most of a one-row step on creating and dropping tensors.

use ekf_residue::{DetectError, OnlineDecision, OnlineDetector, ResidueError, ResidueSeries, ResidueStep};
use nn_toolkit::Normaliser;
use nn_toolkit::matmul::{MatMut, MatRef, matmul};

use crate::lstm::cell_forward;

/// The weights of a fitted [`crate::nn::LstmNet`] as row-major buffers.
#[derive(Debug, Clone)]
pub(crate) struct LstmWeights {
    /// Input width `m`.
    pub(crate) m: usize,
    /// Hidden size `h`.
    pub(crate) h: usize,
    /// `W_ih`, `4h × m`.
    pub(crate) w_ih: Vec<f32>,
    /// `W_hh`, `4h × h`.
    pub(crate) w_hh: Vec<f32>,
    /// `b_ih + b_hh`, `4h`.
    pub(crate) bias: Vec<f32>,
    /// The head's weight, `1 × h`.
    pub(crate) head_w: Vec<f32>,
    /// The head's bias.
    pub(crate) head_b: f32,
}

/// Streaming LSTM (module docs).
pub struct LstmOnline<'a> {
    norm: &'a Normaliser,
    w: LstmWeights,
    /// Window length `l`.
    l: usize,
    threshold: f64,
    /// `x_t W_ihᵀ` of the `l` latest steps, `l × 4h`; row `(start + i) mod l` is the `i`-th
    /// oldest once `l` steps have been seen, row `i` before.
    proj: Vec<f32>,
    start: usize,
    n_seen: usize,
    /// `x W_ihᵀ` of the first step (the front padding).
    first: Vec<f32>,
    t_last: Option<f64>,
    /// Normalised features of the newest step.
    x: Vec<f32>,
    /// Hidden states of the window, `l × h`.
    states: Vec<f32>,
    /// The zero state `h₀` the recurrence starts from.
    h0: Vec<f32>,
    /// Scratch: `h W_hhᵀ`, the gates, `[h | c]`, the cell state and the head's outputs.
    hw: Vec<f32>,
    gates: Vec<f32>,
    hc: Vec<f32>,
    c: Vec<f32>,
    logits: Vec<f32>,
}

impl<'a> LstmOnline<'a> {
    /// A streaming detector with empty history for windows of `l` steps normalised by `norm`,
    /// alarming when the logit of the newest step exceeds `threshold`.
    pub(crate) fn new(w: LstmWeights, norm: &'a Normaliser, l: usize, threshold: f64) -> Self {
        let (l, h, g) = (l.max(1), w.h, 4 * w.h);
        Self {
            norm,
            l,
            threshold,
            proj: vec![0.0; l * g],
            start: 0,
            n_seen: 0,
            first: vec![0.0; g],
            t_last: None,
            x: vec![0.0; w.m],
            states: vec![0.0; l * h],
            h0: vec![0.0; h],
            hw: vec![0.0; g],
            gates: vec![0.0; g],
            hc: vec![0.0; 2 * h],
            c: vec![0.0; h],
            logits: vec![0.0; l],
            w,
        }
    }

    /// Checks `step` as a window holding it would be checked ([`ResidueSeries::from_flat`]:
    /// finite values, a symmetric positive definite `S_k`, time after the previous step's) and
    /// writes its normalised features into `self.x`.
    fn features(&mut self, step: &ResidueStep<'_>) -> Result<(), DetectError> {
        let series =
            ResidueSeries::from_flat(vec![step.t], self.norm.channels.clone(), step.r_k.to_vec(), step.s_k.to_vec())?;
        if let Some(t_prev) = self.t_last
            && step.t <= t_prev
        {
            let step_idx = self.n_seen.min(self.l - 1);
            return Err(ResidueError::Unordered { step_idx, t_prev, t: step.t }.into());
        }
        let newest = series.step(0).ok_or_else(|| DetectError::Numerical { what: "empty residue step".into() })?;
        self.norm.apply(&newest, &mut self.x);
        Ok(())
    }

    /// The logit of the newest step: the recurrence over the window from a zero state, then
    /// the head on every state, as the batch forward pass computes it.
    fn newest_logit(&mut self) -> nn_toolkit::Result<f32> {
        let (l, h, g, m) = (self.l, self.w.h, 4 * self.w.h, self.w.m);
        // The new step's input projection goes into the ring.
        let row = if self.n_seen < l { self.n_seen } else { self.start };
        let slot = &mut self.proj[row * g..(row + 1) * g];
        let w_ih = MatRef::rows(&self.w.w_ih, g, m)?.t();
        matmul(MatMut::rows(slot, 1, g)?, MatRef::rows(&self.x, 1, m)?, w_ih, 1.0, false)?;
        if self.n_seen == 0 {
            self.first.copy_from_slice(slot);
        }
        if self.n_seen >= l {
            self.start = (self.start + 1) % l;
        }
        self.n_seen += 1;
        let (seen, pad) = (self.n_seen.min(l), l - self.n_seen.min(l));

        let w_hh = MatRef::rows(&self.w.w_hh, g, h)?.t();
        self.c.fill(0.0);
        for t in 0..l {
            let p = if t < pad {
                &self.first[..]
            } else {
                let i = t - pad;
                let r = if seen < l { i } else { (self.start + i) % l };
                &self.proj[r * g..(r + 1) * g]
            };
            let h_prev: &[f32] = if t == 0 { &self.h0 } else { &self.states[(t - 1) * h..t * h] };
            matmul(MatMut::rows(&mut self.hw, 1, g)?, MatRef::rows(h_prev, 1, h)?, w_hh, 1.0, false)?;
            for ((a, (&pj, &hj)), &bj) in self.gates.iter_mut().zip(p.iter().zip(&self.hw)).zip(&self.w.bias) {
                *a = (pj + hj) + bj;
            }
            cell_forward(&mut self.gates, &self.c, &mut self.hc, h);
            self.states[t * h..(t + 1) * h].copy_from_slice(&self.hc[..h]);
            self.c.copy_from_slice(&self.hc[h..]);
        }
        let head = MatRef::rows(&self.w.head_w, 1, h)?.t();
        matmul(MatMut::rows(&mut self.logits, l, 1)?, MatRef::rows(&self.states, l, h)?, head, 1.0, false)?;
        Ok(self.logits[l - 1] + self.w.head_b)
    }
}

impl OnlineDetector for LstmOnline<'_> {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        self.features(step)?;
        self.t_last = Some(step.t);
        let score = f64::from(self.newest_logit()?);
        Ok(OnlineDecision { score, alarm: score > self.threshold })
    }

    fn reset(&mut self) {
        (self.start, self.n_seen, self.t_last) = (0, 0, None);
    }
}

#[cfg(test)]
mod tests {
    use ekf_residue::{Detector, Fit, LabelledResidues, OnlineDetector, WindowedOnline};
    use nn_toolkit::{TrainConfig, WindowConfig};

    use crate::nn::{LstmConfig, Stitched};
    use crate::synthetic::{SyntheticAttack, SyntheticFlight};

    /// A small LSTM fitted on two synthetic flights with a GPS bias (20-step windows, the
    /// default hidden size, so that the products have the width of the full run's).
    fn small_lstm() -> crate::Lstm {
        let attack = [SyntheticAttack { start_s: 30.0, end_s: 35.0, bias_m: [20.0, 0.0, 5.0], absorb_tau_s: None }];
        let split = |seeds: &[u64]| {
            let flights = seeds.iter().map(|&s| SyntheticFlight::new(600, s).generate(&attack).unwrap()).collect();
            LabelledResidues::new(flights).unwrap()
        };
        let mut cfg = LstmConfig::default();
        cfg.0.window = WindowConfig { len: 20, stride: 5, ..WindowConfig::default() };
        cfg.0.score_stride = 10;
        cfg.0.train = TrainConfig { epochs: 2, progress: false, ..TrainConfig::default() };
        cfg.fit(&split(&[11, 12]), &split(&[13])).unwrap()
    }

    #[test]
    fn streaming_lstm_matches_the_windowed_candle_pass() {
        let lstm = small_lstm();
        let flight = SyntheticFlight::new(600, 14)
            .generate(&[SyntheticAttack { start_s: 20.0, end_s: 28.0, bias_m: [15.0, 5.0, 0.0], absorb_tau_s: None }])
            .unwrap();
        let mut ours = lstm.online();
        let mut candle = WindowedOnline::new(Stitched(&lstm), lstm.online_window());
        // Twice, with a reset between: the padded opening, the ring's wrap, and a fresh start.
        for pass in 0..2 {
            for (k, step) in flight.series().steps().enumerate() {
                let (a, b) = (ours.update(&step).unwrap(), candle.update(&step).unwrap());
                assert_eq!(a.score.to_bits(), b.score.to_bits(), "pass {pass} step {k}: {} vs {}", a.score, b.score);
                assert_eq!(a.alarm, b.alarm, "pass {pass} step {k}");
            }
            ours.reset();
            candle.reset();
        }
    }

    #[test]
    fn a_bad_step_is_refused_and_leaves_the_window_as_it_was() {
        let lstm = small_lstm();
        let flight = SyntheticFlight::new(60, 15).generate(&[]).unwrap();
        let steps: Vec<_> = flight.series().steps().collect();
        let (mut ours, mut reference) = (lstm.online(), lstm.online());
        for s in &steps[..30] {
            ours.update(s).unwrap();
            reference.update(s).unwrap();
        }
        // A repeated time stamp and a non-finite residue are refused by name.
        let repeated = ours.update(&steps[29]).unwrap_err().to_string();
        assert!(repeated.contains("t"), "{repeated}");
        let r: Vec<f64> = steps[30].r_k.iter().map(|_| f64::NAN).collect();
        let nan = ekf_residue::ResidueStep { r_k: &r, ..steps[30] };
        let err = ours.update(&nan).unwrap_err().to_string();
        assert!(err.contains("r_k"), "{err}");
        for s in &steps[30..] {
            assert_eq!(ours.update(s).unwrap().score.to_bits(), reference.update(s).unwrap().score.to_bits());
        }
    }
}
