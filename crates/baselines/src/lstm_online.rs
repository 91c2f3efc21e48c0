//! The streaming LSTM detector ([`OnlineLstm`], what [`crate::Lstm`]'s `online()` returns):
//! each new residue is scored as the last step of the window of the `l` latest ones, as the
//! batch forward pass of [`crate::nn::LstmNet`] scores that window, without candle.
//!
//! The LSTM restarts from a zero state at every window start (module docs of [`crate::nn`]), so
//! each decision runs the recurrence over the whole window again: `l` products
//! `h_{t−1} W_hhᵀ` and cells. What does not depend on the window start is kept: the input
//! projection `x_t W_ihᵀ` of every step is computed once, when the step arrives, and held in
//! a ring of the `l` latest. Until `l` steps have been seen, the window is front-padded with
//! the first step, as [`nn_toolkit::Windows`] pads.
//!
//! Every product goes through the `gemm` kernel with the shapes candle's `matmul` gives it,
//! and the same strides wherever the kernel reads them ([`nn_toolkit::matmul`]); the cell
//! through [`crate::lstm`]'s own forward; the additions in candle's order
//! (`(x W_ihᵀ + h W_hhᵀ) + b`). So a decision is bit for bit the one
//! [`ekf_residue::WindowedOnline`] computes by re-scoring the window with candle
//! (`streaming_lstm_matches_the_windowed_candle_pass`), for the per-step feature maps; for
//! maps with a history (drift, absorbed offset) the two compute the features over different
//! spans of the flight, and agree up to rounding. It does so at a fraction of the cost: candle
//! spends most of a one-row step on creating and dropping tensors. Each new step is checked
//! once, on arrival ([`ekf_residue::checked_step_nis`]).

use ekf_residue::{DetectError, OnlineDecision, OnlineDetector, ResidueStep, checked_step_nis};
use nn_toolkit::matmul::{MatMut, MatRef, matmul};
use nn_toolkit::{FeatureStream, NnError, Normaliser};

use crate::lstm::cell_forward;

/// The weights of a fitted [`crate::nn::LstmNet`] as row-major buffers.
#[derive(Debug, Clone)]
pub(crate) struct LstmWeights {
    /// Input width `m` (the normalised features of a step).
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

impl LstmWeights {
    /// Checks that every buffer has the size `m` and `h` give it, both positive.
    fn check(&self) -> nn_toolkit::Result<()> {
        let (m, h) = (self.m, self.h);
        if m == 0 || h == 0 {
            return Err(NnError::Data { msg: format!("streaming LSTM: input width {m} and hidden size {h}") });
        }
        let sizes = [
            ("W_ih", self.w_ih.len(), 4 * h * m),
            ("W_hh", self.w_hh.len(), 4 * h * h),
            ("b_ih + b_hh", self.bias.len(), 4 * h),
            ("the head's weight", self.head_w.len(), h),
        ];
        for (what, got, expected) in sizes {
            if got != expected {
                return Err(NnError::Data {
                    msg: format!("streaming LSTM: {what} has {got} elements, expected {expected} (m = {m}, h = {h})"),
                });
            }
        }
        Ok(())
    }
}

/// Streaming LSTM (module docs).
pub struct OnlineLstm<'a> {
    norm: &'a Normaliser,
    /// The feature map over the steps seen.
    stream: FeatureStream,
    w: LstmWeights,
    /// Window length `l`.
    l: usize,
    threshold: f64,
    /// `x_t W_ihᵀ` of the `l` latest steps, `l × 4h`; before `l` steps have been seen, row `i`
    /// holds the `i`-th step, after that row `(start + i) mod l` holds the `i`-th oldest.
    proj: Vec<f32>,
    /// Row of `proj` holding the oldest step once the ring is full.
    start: usize,
    /// Steps accepted since the start or the last reset.
    n_seen: usize,
    /// `x W_ihᵀ` of the first step (the front padding).
    first: Vec<f32>,
    /// Time of the newest accepted step, which the next one must follow.
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

impl<'a> OnlineLstm<'a> {
    /// A streaming detector with empty history for windows of `l` (at least 1) steps
    /// normalised by `norm`, alarming when the logit of the newest step exceeds `threshold`.
    ///
    /// # Errors
    /// [`NnError::Data`] if a weight buffer does not have the size the input width and hidden
    /// size give it, or the input width is not `norm`'s.
    pub(crate) fn new(w: LstmWeights, norm: &'a Normaliser, l: usize, threshold: f64) -> nn_toolkit::Result<Self> {
        w.check()?;
        if norm.dim() != w.m {
            return Err(NnError::Data {
                msg: format!("streaming LSTM: input width {} but {} normalised features", w.m, norm.dim()),
            });
        }
        let (l, h, g) = (l.max(1), w.h, 4 * w.h);
        Ok(Self {
            norm,
            stream: norm.stream(),
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
        })
    }

    /// Checks `step` as a window holding it as its newest step would be checked, and writes
    /// its normalised features into `self.x`.
    fn features(&mut self, step: &ResidueStep<'_>) -> Result<(), DetectError> {
        let step_idx = self.n_seen.min(self.l - 1);
        let m = self.norm.channels.len();
        let nis = checked_step_nis(step_idx, m, self.t_last, step.t, step.r_k, step.s_k)?;
        self.norm.apply(&mut self.stream, &ResidueStep { nis, ..*step }, &mut self.x);
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

impl OnlineDetector for OnlineLstm<'_> {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        self.features(step)?;
        self.t_last = Some(step.t);
        let score = f64::from(self.newest_logit()?);
        Ok(OnlineDecision { score, alarm: score > self.threshold })
    }

    fn reset(&mut self) {
        (self.start, self.n_seen, self.t_last) = (0, 0, None);
        self.stream.reset();
    }
}

#[cfg(test)]
mod tests {
    use std::sync::OnceLock;

    use candle_core::{DType, Device, Tensor};
    use candle_nn::{VarBuilder, VarMap};
    use ekf_residue::{DetectError, Detector, Fit, LabelledResidues, OnlineDetector, ResidueError, WindowedOnline};
    use nn_toolkit::{Features, Normaliser, TrainConfig, WindowConfig, init_vars_seeded};

    use super::OnlineLstm;
    use crate::nn::{LstmConfig, LstmNet, PerStepNet, Stitched};
    use crate::synthetic::{SyntheticAttack, SyntheticFlight};

    fn split(seeds: &[u64]) -> LabelledResidues {
        let attack = [SyntheticAttack { start_s: 30.0, end_s: 35.0, bias_m: [20.0, 0.0, 5.0], absorb_tau_s: None }];
        let flights = seeds.iter().map(|&s| SyntheticFlight::new(600, s).generate(&attack).unwrap()).collect();
        LabelledResidues::new(flights).unwrap()
    }

    /// A small LSTM fitted once on two synthetic flights with a GPS bias (20-step windows, the
    /// default hidden size, so that the products have the width of the full run's).
    fn small_lstm() -> &'static crate::Lstm {
        static LSTM: OnceLock<crate::Lstm> = OnceLock::new();
        LSTM.get_or_init(|| {
            let mut cfg = LstmConfig::default();
            cfg.0.window = WindowConfig { len: 20, stride: 5, ..WindowConfig::default() };
            cfg.0.score_stride = 10;
            cfg.0.train = TrainConfig { epochs: 2, progress: false, ..TrainConfig::default() };
            cfg.fit(&split(&[11, 12]), &split(&[13])).unwrap()
        })
    }

    #[test]
    fn streaming_lstm_matches_the_windowed_candle_pass() {
        let lstm = small_lstm();
        let flight = SyntheticFlight::new(600, 14)
            .generate(&[SyntheticAttack { start_s: 20.0, end_s: 28.0, bias_m: [15.0, 5.0, 0.0], absorb_tau_s: None }])
            .unwrap();
        let (l, threshold) = (lstm.window.len, lstm.streaming_threshold());
        let mut ours = lstm.net.online(&lstm.norm, l, threshold).expect("the LSTM streams through OnlineLstm");
        let mut candle = WindowedOnline::new(Stitched(lstm), lstm.online_window());
        // The padded opening, the ring's wraps, a reset mid-ring (537 is no multiple of the
        // window) and a fresh start.
        let steps: Vec<_> = flight.series().steps().collect();
        for (pass, run) in [&steps[..537], &steps[..]].into_iter().enumerate() {
            for (k, step) in run.iter().enumerate() {
                let (a, b) = (ours.update(step).unwrap(), candle.update(step).unwrap());
                assert_eq!(a.score.to_bits(), b.score.to_bits(), "pass {pass} step {k}: {} vs {}", a.score, b.score);
                assert_eq!(a.alarm, b.alarm, "pass {pass} step {k}");
            }
            ours.reset();
            candle.reset();
        }
    }

    /// Untrained seeded networks of hidden sizes on both sides of the kernel's switch from a
    /// row-vector product to a full one (`4h` ≤ 256 and > 256): the newest logit of every
    /// window is the one candle's forward pass gives the same window.
    #[test]
    fn streaming_logits_are_candle_logits_for_any_hidden_size() {
        let data = split(&[21]);
        let flight = SyntheticFlight::new(120, 22).generate(&[]).unwrap();
        for (features, h) in [
            (Features::default(), 8),
            (Features::default(), 64),
            (Features::WhitenedLogDrift, 65),
            (Features::WhitenedLogDriftAbsorbed, 16),
        ] {
            let norm = Normaliser::fit(&data, features).unwrap();
            let (m, l) = (norm.dim(), 12);
            let varmap = VarMap::new();
            let vb = VarBuilder::from_varmap(&varmap, DType::F32, &Device::Cpu);
            let net = LstmNet::new(m, h, vb).unwrap();
            init_vars_seeded(&varmap, 7).unwrap();
            let mut ours = OnlineLstm::new(net.weights().unwrap(), &norm, l, 0.0).unwrap();
            let mut window: Vec<f32> = Vec::new();
            let mut stream = norm.stream();
            for (k, step) in flight.series().steps().enumerate() {
                let score = ours.update(&step).unwrap().score;
                let mut x = vec![0.0; m];
                norm.apply(&mut stream, &step, &mut x);
                if window.is_empty() {
                    window = x.repeat(l);
                } else {
                    window.drain(..m);
                    window.extend_from_slice(&x);
                }
                let logits = net.logits(&Tensor::from_slice(&window, (1, l, m), &Device::Cpu).unwrap()).unwrap();
                let expected = logits.flatten_all().unwrap().to_vec1::<f32>().unwrap()[l - 1];
                assert_eq!(score.to_bits(), f64::from(expected).to_bits(), "h {h} step {k}: {score} vs {expected}");
            }
        }
    }

    #[test]
    fn weights_of_the_wrong_size_are_refused() {
        let lstm = small_lstm();
        let weights = lstm.net.weights().unwrap();
        let mut short = weights.clone();
        short.w_hh.pop();
        let err = OnlineLstm::new(short, &lstm.norm, 20, 0.0).err().unwrap().to_string();
        assert!(err.contains("W_hh"), "{err}");
        let wide = super::LstmWeights { m: weights.m + 1, ..weights };
        assert!(OnlineLstm::new(wide, &lstm.norm, 20, 0.0).is_err());
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
        // A repeated time stamp and a non-finite residue are refused by name, at the newest
        // index of the full window.
        let err = ours.update(&steps[29]).unwrap_err();
        assert!(matches!(err, DetectError::Residue(ResidueError::Unordered { step_idx: 19, .. })), "{err}");
        let r: Vec<f64> = steps[30].r_k.iter().map(|_| f64::NAN).collect();
        let nan = ekf_residue::ResidueStep { r_k: &r, ..steps[30] };
        let err = ours.update(&nan).unwrap_err();
        assert!(matches!(err, DetectError::Residue(ResidueError::NonFinite { step_idx: 19, what: "r_k" })), "{err}");
        for s in &steps[30..] {
            assert_eq!(ours.update(s).unwrap().score.to_bits(), reference.update(s).unwrap().score.to_bits());
        }
    }
}
