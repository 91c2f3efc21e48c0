//! The streaming QUADFormer detector ([`OnlineQuadFormer`]): every new residue is scored as the
//! newest step of the window of the `l` latest ones (its last position; a causal network's
//! first `l − 1` steps open the window instead), by the streaming engine
//! ([`crate::streaming::StreamingNet`]) or, for a network the engine cannot represent, by the
//! candle forward pass on the same window ([`QuadFormerNet::forward_steps`]). Both compute the
//! same function; the differential tests of the engine bound their difference to rounding.

use candle_core::Tensor;
use ekf_residue::{DetectError, OnlineDecision, OnlineDetector, ResidueError, ResidueSeries, ResidueStep};
use nn_toolkit::FeatureStream;

use super::{QuadFormerDetector, RawScores, ScoreMode, combine};
use crate::error::{ModelError, Result};
use crate::model::{GradFlow, QuadFormerNet, Steps};
use crate::streaming::{StepOutput, StreamingNet};

/// Streaming QUADFormer: scores each new step as the last position of the window of the `l`
/// latest normalised residues (causal; a batch [`ekf_residue::Detector::score`] averages over
/// all windows covering a step, so the two differ slightly). Until `l` steps have been seen
/// the window is padded at the front with the first step, as in [`nn_toolkit::window`]; a
/// causal network ([`crate::NetConfig::causal`]) needs no padding and scores the steps seen
/// so far as the opening positions of a window, as its batch score of a flight's start does. The
/// network runs in a [`StreamingNet`], which reuses the previous windows' work on layer 1 and
/// allocates nothing, and computes the TCD of the window only for the modes that read it;
/// where the engine cannot represent the network, in the candle forward pass (module docs).
pub struct OnlineQuadFormer<'a> {
    det: &'a QuadFormerDetector,
    scorer: Scorer,
    /// The feature map over the steps seen.
    stream: FeatureStream,
    /// The newest normalised residue.
    x: Vec<f32>,
}

/// What computes the newest step's outputs.
enum Scorer {
    /// The streaming engine.
    Engine(Box<StreamingNet>),
    /// The candle forward pass on the sliding window.
    Candle(CandleWindow),
}

impl Scorer {
    fn n_seen(&self) -> usize {
        match self {
            Scorer::Engine(engine) => engine.n_seen(),
            Scorer::Candle(window) => window.n_seen,
        }
    }
}

/// The window of the `l` latest residues for the candle forward pass: a ring of `l × m`
/// values, front-padded with the first residue like the engine's (a causal network reads the
/// steps seen as the window's opening positions instead, [`CandleWindow::push`]).
struct CandleWindow {
    l: usize,
    m: usize,
    /// Residues, `l` rows; row `start` holds the oldest step.
    ring: Vec<f32>,
    start: usize,
    n_seen: usize,
    /// TCD of every step of the latest window.
    tcd: Vec<f32>,
}

impl CandleWindow {
    fn new(l: usize, m: usize) -> Self {
        Self { l, m, ring: vec![0.0; l * m], start: 0, n_seen: 0, tcd: Vec::with_capacity(l) }
    }

    /// Slides the window to end at `x` and computes its newest step's outputs with `net`, as
    /// [`StreamingNet::push`] does.
    fn push(&mut self, net: &QuadFormerNet, x: &[f32], with_tcd: bool) -> Result<StepOutput<'_>> {
        let (l, m) = (self.l, self.m);
        if x.len() != m {
            return Err(ModelError::Data { msg: format!("residue of {} values, network reads {m}", x.len()) });
        }
        if self.n_seen == 0 {
            for row in self.ring.chunks_exact_mut(m) {
                row.copy_from_slice(x);
            }
            self.start = 0;
        } else {
            self.ring[self.start * m..(self.start + 1) * m].copy_from_slice(x);
            self.start = (self.start + 1) % l;
        }
        self.n_seen += 1;
        let n = self.n_seen;
        // The ring in time order: the `n` steps seen at its end while `n < l`.
        let mut window: Vec<f32> =
            (0..l).flat_map(|i| self.ring[(self.start + i) % l * m..][..m].iter().copied()).collect();
        // A causal network needs no padding: the steps seen open the window (the rest repeats
        // the newest, which no earlier position reads), and position `n − 1` is the newest
        // step, as in the batch score of a flight's first window; its TCD covers those steps.
        let (steps, row, seen) = if net.config().causal && n < l {
            window.drain(..(l - n) * m);
            for _ in n..l {
                window.extend_from_slice(x);
            }
            (Steps::All, n - 1, n)
        } else {
            (Steps::Last { with_tcd }, 0, l)
        };
        let out = net.forward_steps(&Tensor::from_vec(window, (1, l, m), net.device())?, steps)?;
        let logit = out.logits.narrow(1, row, 1)?.flatten_all()?.to_vec1::<f32>()?;
        let logit = *logit.first().ok_or_else(|| ModelError::Data { msg: "the network gave no logit".into() })?;
        let r_hat = out.r_hat.narrow(1, row, 1)?.flatten_all()?.to_vec1::<f32>()?;
        let recon_err = r_hat.iter().zip(x).map(|(r, v)| (r - v) * (r - v)).sum::<f32>() / m as f32;
        if with_tcd {
            let tcd = QuadFormerNet::tcd(&out, GradFlow::Stop, GradFlow::Stop)?;
            self.tcd = tcd.narrow(1, 0, seen)?.flatten_all()?.to_vec1::<f32>()?;
        }
        Ok(StepOutput { recon_err, logit, tcd: with_tcd.then_some(&self.tcd[..]) })
    }
}

impl<'a> OnlineQuadFormer<'a> {
    /// A streaming detector with empty history.
    pub fn new(det: &'a QuadFormerDetector) -> Self {
        let m = det.net.dim();
        let scorer = match &det.streaming {
            Some(engine) => Scorer::Engine(Box::new(engine.clone())),
            None => Scorer::Candle(CandleWindow::new(det.net.window_len(), m)),
        };
        Self { det, scorer, stream: det.norm.stream(), x: vec![0.0; m] }
    }

    /// The raw scores of the newest step, with the window slid to end at `x`; the two TCD
    /// scores are `NaN` unless `with_tcd`.
    fn raw_newest(&mut self, with_tcd: bool) -> Result<StepRaw> {
        let out = match &mut self.scorer {
            Scorer::Engine(engine) => engine.push(&self.x, with_tcd)?,
            Scorer::Candle(window) => window.push(&self.det.net, &self.x, with_tcd)?,
        };
        let tcd = out.tcd.unwrap_or_default();
        Ok(StepRaw {
            alg2: last_of_softmax(tcd, -1.0),
            at: last_of_softmax(tcd, -self.det.config.score.temperature) * f64::from(out.recon_err),
            class: 1.0 / (1.0 + (-f64::from(out.logit)).exp()),
        })
    }

    /// Checks `step` against the detector's channels, slides the window to end at it and
    /// gives its raw scores (the two TCD scores `NaN` unless `with_tcd`).
    fn push(&mut self, step: &ResidueStep<'_>, with_tcd: bool) -> Result<StepRaw, DetectError> {
        let (m, k) = (self.det.norm.channels.len(), self.scorer.n_seen());
        if step.dim() != m {
            return Err(ResidueError::StepDim { step_idx: k, what: "r_k", expected: m, got: step.dim() }.into());
        }
        if step.s_k.len() != m * m {
            return Err(ResidueError::StepDim { step_idx: k, what: "S_k", expected: m * m, got: step.s_k.len() }.into());
        }
        for (what, finite) in [
            ("r_k", step.r_k.iter().all(|v| v.is_finite())),
            ("S_k", step.s_k.iter().all(|v| v.is_finite())),
            ("nis", step.nis.is_finite()),
        ] {
            if !finite {
                return Err(ResidueError::NonFinite { step_idx: k, what }.into());
            }
        }
        self.det.norm.apply(&mut self.stream, step, &mut self.x);
        Ok(self.raw_newest(with_tcd)?)
    }

    /// The raw streaming scores of every step of `series` in every mode, each step the newest
    /// of its window: what the streamed mode is chosen from at `fit`.
    pub(crate) fn raw_scores(mut self, series: &ResidueSeries) -> Result<RawScores, DetectError> {
        let mut raw = RawScores::default();
        for step in series.steps() {
            let s = self.push(&step, true)?;
            raw.alg2.push(s.alg2);
            raw.at.push(s.at);
            raw.class.push(s.class);
        }
        Ok(raw)
    }
}

/// The raw scores of one streamed step.
struct StepRaw {
    alg2: f64,
    at: f64,
    class: f64,
}

impl StepRaw {
    fn mode(&self, mode: ScoreMode, crit_scale: f64) -> f64 {
        match mode {
            ScoreMode::Alg2 => self.alg2,
            ScoreMode::AnomalyTransformer => self.at,
            ScoreMode::Classifier => self.class,
            ScoreMode::Combined => combine(self.class, self.at, crit_scale),
        }
    }
}

/// The last entry of `softmax(k·v)`, `NaN` for an empty `v`.
fn last_of_softmax(v: &[f32], k: f64) -> f64 {
    let Some(&last) = v.last() else { return f64::NAN };
    let max = v.iter().map(|&x| k * f64::from(x)).fold(f64::NEG_INFINITY, f64::max);
    let sum: f64 = v.iter().map(|&x| (k * f64::from(x) - max).exp()).sum();
    (k * f64::from(last) - max).exp() / sum
}

impl OnlineDetector for OnlineQuadFormer<'_> {
    fn update(&mut self, step: &ResidueStep<'_>) -> Result<OnlineDecision, DetectError> {
        let k = self.scorer.n_seen();
        let mode = self.det.stream.mode;
        let score = self.push(step, mode.reads_tcd())?.mode(mode, self.det.crit_scale);
        if !score.is_finite() {
            return Err(DetectError::Numerical { what: format!("non-finite QUADFormer score at step {k}") });
        }
        Ok(OnlineDecision { score, alarm: score > self.det.stream.threshold })
    }

    fn reset(&mut self) {
        self.stream.reset();
        match &mut self.scorer {
            Scorer::Engine(engine) => engine.reset(),
            Scorer::Candle(window) => window.n_seen = 0,
        }
    }
}
