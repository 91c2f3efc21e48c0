//! Streaming inference of a trained QUADFormer network: the outputs of the newest step of a
//! sliding window (reconstruction, classifier logit and, when asked, the TCD of every step),
//! updated one residue at a time with the work and memory fixed in advance.
//!
//! It computes what [`QuadFormerNet::forward_steps`] with [`Steps::Last`] computes, from the
//! same weights, in plain `f32` buffers ([`nn_toolkit::matmul`], the element-wise kernels of
//! [`nn_toolkit::fused`] and [`crate::js`]), and does less work in seven ways, exact but for rounding:
//!
//! 1. **Layer 1 is linear in each residue.** Its input is `h⁰ᵢ = xᵢ W_e + b_e + PEᵢ` and its
//!    projections `Q¹ᵢ = h⁰ᵢ W_Q + b_Q` (likewise `K¹`, `V¹`), so each splits into a part of
//!    the residue, `xᵢ [W_e | W_e W_Q | W_e W_K | W_e W_V]`, and a part of the position. The
//!    residue part is computed once, when the residue arrives, and kept in a ring of `l`
//!    slots; the position part is computed once, when the engine is built. A new window's
//!    layer-1 input and projections are the ring plus the position part: no matrix product.
//! 2. **The last layer works on the newest row** (as [`Steps::Last`]): one query, one output
//!    row, one feed-forward row. Its value product is reassociated,
//!    `c (H W_V + 1 b_V) = (c H) W_V + b_V` (the attention row `c` sums to 1), so the window's
//!    values are never formed.
//! 3. **With one head, `W_O` is folded into the values**: `C (H W_V + 1 b_V) W_O + b_O =
//!    C (H W_V W_O + 1 (b_V W_O + b_O))`, so the attention output is already in the model
//!    space and the `l × d × d` output product disappears (layer 1's ring holds `V W_O`). With
//!    several heads the folded values would cost a product per head, so they stay apart.
//! 4. **Nothing is allocated** after construction: every intermediate has its buffer.
//! 5. **The TCD takes one logarithm per entry.** `JS(T, C) = ½ (Σ T ln T + Σ C ln C) −
//!    Σ M ln M` with `M = (T + C)/2`: the prior's `Σ T ln T` is frozen with it, and the
//!    attention's comes from its scores, `Σ C ln C = Σ C (s − max s) − ln Σ exp(s − max s)`, as
//!    the softmax forms `C`. Only `ln(M + ε)` is taken per entry, from [`vmath::ln_fast`]
//!    (within 1.4 units in the last place, against 0.7 for [`vmath::ln`], at four fifths of its
//!    cost). The softmax and these terms run over blocks of rows that fill whole vectors
//!    ([`vmath::row_block`]), so no row leaves a remainder to scalar code.
//! 6. **With DCM and one head, no layer after the first forms queries and keys.** Layer `h`
//!    scores its queries against the keys of layer `h − 1`, `Kʰ⁻¹ = H' W'_K + b'_K` with `H'`
//!    that layer's input, so `Q Kʰ⁻¹ᵀ = (H W_Q + b_Q)(W'_K H'ᵀ + b'_Kᵀ)`. Terms constant along a
//!    row leave the softmax unchanged and are dropped, leaving `(H F + f) H'ᵀ` with
//!    `F = W_Q W'_Kᵀ/√d` and `f = b_Q W'_Kᵀ/√d` formed once: one `d × d` product per query
//!    row where the queries and the previous layer's keys took one per query and per key. For
//!    layer 2 the other order is cheaper still: `(H W_Q + b_Q) K¹ᵀ/√d = H κᵀ + 1 βᵀ` with
//!    `[κⱼ | βⱼ] = K¹ⱼ [W_Q | b_Q]ᵀ/√d`, which is affine in each residue and so joins the ring
//!    (point 1): layer 2 takes no product for its scores but the scores themselves.
//! 7. **Layer 1 scores in the residues' rank.** With `Q¹ = X W_e W_Q + P_Q` and
//!    `K¹ = X W_e W_K + P_K` (`X` the window's `l × m` residues, `P` the position parts),
//!    `Q¹K¹ᵀ = [X G + B | X][X | Aᵀ]ᵀ + E` with `G = W_e W_Q (W_e W_K)ᵀ`, `B = P_Q (W_e W_K)ᵀ`,
//!    `A = W_e W_Q P_Kᵀ` and `E = P_Q P_Kᵀ` formed once: an inner dimension of `2m` instead of
//!    `d`. The ring holds `[x G + B | x | Aᵀ]` (residue and position parts, as in point 1). Used
//!    when `2m` is below a head's width (12 against 64 by default).
//!
//! The results equal the candle forward pass up to `f32` rounding: sums are reassociated,
//! logarithms differ in the last place, and the attention's `Σ C ln C` (and a Gaussian
//! prior's) has no guard `ε` where [`crate::js`] takes `Σ C ln(C + ε)`, which moves a step's
//! TCD by at most `l ε` (10⁻⁶ for `l` = 100). The tests bound the difference. The TPC priors are frozen at construction; the
//! Gaussian prior of the "TPC off" ablation depends on the input and is rebuilt per window.
//!
//! Until `l` residues have been seen the window is padded at the front with the first one, as
//! in [`nn_toolkit::window`].

use candle_core::Tensor;

use crate::error::{ModelError, Result};
use crate::js::mixture_entropy_terms;
use crate::model::{ClassInput, PRIOR_EXP_FLOOR, Prior, QuadFormerNet};
use nn_toolkit::fused::{add_bias_row, gelu_value, layer_norm_row, softmax_rows};
use nn_toolkit::layers::LN_EPS;
use nn_toolkit::matmul::{MatMut, MatRef, matmul};
use nn_toolkit::vmath;

/// A dense layer `y = x W + b` with `W` stored `in × out` (the transpose of the checkpoint's
/// `weight`).
#[derive(Clone)]
struct Linear {
    w: Vec<f32>,
    b: Vec<f32>,
    n_in: usize,
    n_out: usize,
}

impl Linear {
    /// Reads `{name}.weight` (`out × in`) and `{name}.bias` from the network's variables.
    fn load(net: &QuadFormerNet, name: &str) -> Result<Self> {
        let weight = var(net, &format!("{name}.weight"))?;
        let (n_out, n_in) = weight.dims2()?;
        let w = weight.t()?.contiguous()?.flatten_all()?.to_vec1::<f32>()?;
        let b = var(net, &format!("{name}.bias"))?.flatten_all()?.to_vec1::<f32>()?;
        if b.len() != n_out {
            return Err(ModelError::Data { msg: format!("{name}.bias has {} values, expected {n_out}", b.len()) });
        }
        Ok(Self { w, b, n_in, n_out })
    }

    /// `u W + bias·b` of one row `u`, in `f64` (for weights formed once).
    fn apply_f64(&self, u: &[f64], bias: f64) -> Vec<f64> {
        (0..self.n_out)
            .map(|j| {
                let acc: f64 = u.iter().enumerate().map(|(k, uk)| uk * f64::from(self.w[k * self.n_out + j])).sum();
                acc + bias * f64::from(self.b[j])
            })
            .collect()
    }

    /// The composition `x ↦ (x W + b) W' + b'` of this layer and `next`, as one layer
    /// (accumulated in `f64`).
    fn then(&self, next: &Linear) -> Self {
        let w = self.w.chunks_exact(self.n_out).flat_map(|row| to_f32(&next.apply_f64(&to_f64(row), 0.0))).collect();
        Self { w, b: to_f32(&next.apply_f64(&to_f64(&self.b), 1.0)), n_in: self.n_in, n_out: next.n_out }
    }

    /// `x ↦ c x Wᵀ`, without bias.
    fn transposed(&self, c: f32) -> Self {
        let w = (0..self.n_in * self.n_out).map(|k| c * self.w[(k % self.n_in) * self.n_out + k / self.n_in]).collect();
        Self { w, b: vec![0.0; self.n_in], n_in: self.n_out, n_out: self.n_in }
    }

    /// `k ↦ c [k W_Qᵀ | k·b_Q]` of this query projection, without bias: what layer 2's folded
    /// scores read of a key `k` of layer 1 ([`Scores::RingKeys`]).
    fn key_map(&self, c: f32) -> Self {
        let mut w = Vec::with_capacity(self.n_out * (self.n_in + 1));
        for j in 0..self.n_out {
            w.extend((0..self.n_in).map(|a| c * self.w[a * self.n_out + j]));
            w.push(c * self.b[j]);
        }
        Self { w, b: vec![0.0; self.n_in + 1], n_in: self.n_out, n_out: self.n_in + 1 }
    }

    /// `dst ← x W + b` for the `rows` rows of `x`.
    #[inline(always)]
    fn forward(&self, x: MatRef<'_>, dst: &mut [f32], rows: usize) -> Result<()> {
        matmul(MatMut::rows(dst, rows, self.n_out)?, x, MatRef::rows(&self.w, self.n_in, self.n_out)?, 1.0, false)?;
        for row in dst[..rows * self.n_out].chunks_exact_mut(self.n_out) {
            add_bias_row(row, &self.b);
        }
        Ok(())
    }
}

/// Gain and bias of a layer norm.
#[derive(Clone)]
struct LayerNormW {
    gain: Vec<f32>,
    bias: Vec<f32>,
}

impl LayerNormW {
    fn load(net: &QuadFormerNet, name: &str) -> Result<Self> {
        Ok(Self {
            gain: var(net, &format!("{name}.weight"))?.to_vec1::<f32>()?,
            bias: var(net, &format!("{name}.bias"))?.to_vec1::<f32>()?,
        })
    }

    #[inline(always)]
    fn apply(&self, rows: &mut [f32]) {
        for row in rows.chunks_exact_mut(self.gain.len()) {
            layer_norm_row(row, &self.gain, &self.bias, LN_EPS);
        }
    }
}

fn to_f64(xs: &[f32]) -> Vec<f64> {
    xs.iter().map(|&v| f64::from(v)).collect()
}

fn to_f32(xs: &[f64]) -> Vec<f32> {
    xs.iter().map(|&v| v as f32).collect()
}

/// The value of the variable `name`.
fn var(net: &QuadFormerNet, name: &str) -> Result<Tensor> {
    let data = net.varmap().data().lock().map_err(|_| ModelError::Data { msg: "variable map poisoned".into() })?;
    data.get(name)
        .map(|v| v.as_tensor().detach())
        .ok_or_else(|| ModelError::Data { msg: format!("the network has no variable `{name}`") })
}

/// The prior association `T` of one layer.
#[derive(Clone)]
enum LayerPrior {
    /// Frozen TPC maps `heads × l × l` and the `Σⱼ Tᵢⱼ ln(Tᵢⱼ + ε)` of their rows.
    Tpc { t: Vec<f32>, ent: Vec<f32> },
    /// Anomaly Transformer's Gaussian kernel; its width is a projection of the layer input.
    Gaussian { sigma: Linear },
}

/// How a layer forms its attention scores `S = Q Kᵀ/√d_h` (module docs, points 6 and 7).
#[derive(Clone)]
enum Scores {
    /// From the projected queries and keys: this layer's own keys, or with DCM the previous
    /// layer's. Layer 1 reads its projections from the ring.
    Projected,
    /// Layer 2 with DCM and one head: `S = H κᵀ + 1 βᵀ`, where `[κⱼ | βⱼ] = K¹ⱼ [W_Q | b_Q]ᵀ/√d`
    /// is affine in residue `j` and so held in the ring.
    RingKeys,
    /// Layer 1 in the rank of the residues: `S = [X G + B | X][X | Aᵀ]ᵀ + E` per head, with
    /// `G = W_e W_Q (W_e W_K)ᵀ/√d`, `B = P_Q (W_e W_K)ᵀ/√d`, `A = W_e W_Q P_Kᵀ/√d`,
    /// `E = P_Q P_Kᵀ/√d` (`P_Q`, `P_K` the position parts of `Q¹`, `K¹`). The ring holds a block
    /// `[x G + B | x | Aᵀ]` per head from column `col`; `E` is `heads × l × l`.
    LowRank { col: usize, e: Vec<f32> },
    /// A later layer with DCM and one head: `S ≅ (H F + f) H'ᵀ` with `H'` the previous
    /// layer's input, `F = W_Q W'_Kᵀ/√d` and `f = b_Q W'_Kᵀ/√d` (this linear map); the
    /// previous layer's keys are never formed.
    Folded(Linear),
}

/// One UAV Attack Attention layer's weights.
#[derive(Clone)]
struct LayerW {
    scores: Scores,
    w_q: Linear,
    w_k: Linear,
    /// The value projection; with one head, `W_V W_O` and `b_V W_O + b_O` (module docs).
    w_v: Linear,
    /// The output projection; `None` with one head, where it is folded into `w_v`.
    w_o: Option<Linear>,
    norm1: LayerNormW,
    ff1: Linear,
    ff2: Linear,
    norm2: LayerNormW,
    prior: LayerPrior,
}

/// The newest step's outputs ([`StreamingNet::push`]).
#[derive(Debug, Clone, Copy)]
pub struct StepOutput<'a> {
    /// Mean over channels of `(R̂ − x)²` at the newest step.
    pub recon_err: f32,
    /// Classifier logit at the newest step.
    pub logit: f32,
    /// TCD of every step of the window (oldest first), when asked for.
    pub tcd: Option<&'a [f32]>,
}

/// Per-window intermediates, allocated once.
#[derive(Clone)]
struct Scratch {
    /// Layer-1 input and projections `[h⁰ | Q¹ | K¹ | V¹]` (and `[κ | β]` of
    /// [`Scores::RingKeys`]), `l × w_ring`.
    x0: Vec<f32>,
    /// A layer's input `H` (`l × d`, layers after the first), then its output; and the
    /// previous layer's input.
    h: Vec<f32>,
    h_prev: Vec<f32>,
    q: Vec<f32>,
    /// This layer's keys, and the previous layer's (DCM).
    k: Vec<f32>,
    k_prev: Vec<f32>,
    /// `β` of [`Scores::RingKeys`], `l` values.
    beta: Vec<f32>,
    v: Vec<f32>,
    /// Attention output (before `W_O`, or after it when folded).
    att: Vec<f32>,
    /// `Z`: the attention output after `W_O`, the residual and the norm.
    z: Vec<f32>,
    /// `c H` of every head (last layer).
    ctx: Vec<f32>,
    ff: Vec<f32>,
    /// Every layer's attention `C` (`heads × rows × l`) and Gaussian prior `T` (`heads × l × l`),
    /// and the `Σⱼ xᵢⱼ ln xᵢⱼ` of their rows (only for the TCD).
    attn: Vec<Vec<f32>>,
    ent_attn: Vec<Vec<f32>>,
    prior: Vec<Vec<f32>>,
    ent_prior: Vec<Vec<f32>>,
    /// Gaussian widths of every step and head, `l × heads`.
    sigma: Vec<f32>,
    r_hat: Vec<f32>,
    class: Vec<f32>,
    logit: Vec<f32>,
    tcd: Vec<f32>,
    /// Scratch of a block of rows of a map ([`vmath::row_block`]).
    terms: Vec<f32>,
}

/// A trained QUADFormer network prepared for streaming (module docs).
#[derive(Clone)]
pub struct StreamingNet {
    l: usize,
    m: usize,
    d: usize,
    heads: usize,
    dcm: bool,
    class_input: ClassInput,
    /// Residue part of a ring row per residue channel, `m × w_ring` ([`layer_one_parts`]:
    /// `[W_e | W_e W_Q¹ | W_e W_K¹ | W_e W_V¹]` with `W_V¹` as held by its layer, then the
    /// parts of [`Scores::RingKeys`] and [`Scores::LowRank`] when used).
    w_in: Vec<f32>,
    /// Position part of a ring row per step, `l × w_ring`.
    p_in: Vec<f32>,
    /// Width of a row of the ring, `w_in`, `p_in` and `x0`.
    w_ring: usize,
    layers: Vec<LayerW>,
    recon: Linear,
    class1: Linear,
    class2: Linear,
    /// Residue parts of the window, `l` slots of `w_ring`; slot `start` holds the oldest step.
    ring: Vec<f32>,
    start: usize,
    n_seen: usize,
    s: Scratch,
}

impl StreamingNet {
    /// Prepares `net` (its current variables; TPC priors from [`QuadFormerNet::freeze`]'s
    /// cache when frozen).
    ///
    /// # Errors
    /// Missing variables; candle errors.
    pub fn new(net: &QuadFormerNet) -> Result<Self> {
        let cfg = net.config();
        let (l, m, d, heads, n_layers) = (net.window_len(), net.dim(), cfg.d_model, cfg.n_heads, cfg.n_layers);
        let embed = Linear::load(net, "embed")?;
        let pos = net.positional_encoding().flatten_all()?.to_vec1::<f32>()?;
        let mut tpc = net.tpc_priors()?.into_iter();
        // The attention's scale `1/√d_h`, folded into the weights of the refactored scores.
        let scale = 1.0 / ((d / heads) as f32).sqrt();
        let mut layers: Vec<LayerW> = Vec::with_capacity(n_layers);
        for h in 0..n_layers {
            let name = |part: &str| format!("layers.{h}.{part}");
            let prior = match cfg.prior {
                Prior::Tpc => {
                    let t = tpc
                        .next()
                        .ok_or_else(|| ModelError::Data { msg: format!("layer {h} has no TPC prior") })?
                        .flatten_all()?
                        .to_vec1::<f32>()?;
                    let ln_t = vmath::vectorized(
                        #[inline(always)]
                        || crate::js::ln_eps(&t),
                    );
                    let ent =
                        t.chunks_exact(l).zip(ln_t.chunks_exact(l)).map(|(t, ln_t)| vmath::dot(t, ln_t)).collect();
                    LayerPrior::Tpc { t, ent }
                }
                Prior::Gaussian => LayerPrior::Gaussian { sigma: Linear::load(net, &name("attn.sigma"))? },
            };
            let (w_v, w_o) = (Linear::load(net, &name("attn.w_v"))?, Linear::load(net, &name("attn.w_o"))?);
            let (w_v, w_o) = if heads == 1 { (w_v.then(&w_o), None) } else { (w_v, Some(w_o)) };
            let w_q = Linear::load(net, &name("attn.w_q"))?;
            let scores = match (layers.last(), h) {
                (Some(_), 1) if cfg.dcm && heads == 1 => Scores::RingKeys,
                (Some(prev), _) if cfg.dcm && heads == 1 => Scores::Folded(w_q.then(&prev.w_k.transposed(scale))),
                _ => Scores::Projected,
            };
            layers.push(LayerW {
                scores,
                w_q,
                w_k: Linear::load(net, &name("attn.w_k"))?,
                w_v,
                w_o,
                norm1: LayerNormW::load(net, &name("norm1"))?,
                ff1: Linear::load(net, &name("ff1"))?,
                ff2: Linear::load(net, &name("ff2"))?,
                norm2: LayerNormW::load(net, &name("norm2"))?,
                prior,
            });
        }
        let first = layers.first().ok_or_else(|| ModelError::Data { msg: "the network has no layers".into() })?;
        let key_map = match layers.get(1) {
            Some(LayerW { scores: Scores::RingKeys, w_q, .. }) => Some(w_q.key_map(scale)),
            _ => None,
        };
        // Layer 1's scores in the residues' rank when that is below a head's width (point 7).
        let low_rank_heads = (2 * m < d / heads).then_some(heads);
        let LayerOne { w_in, p_in, low_rank } =
            layer_one_parts(&embed, &pos, first, key_map.as_ref(), low_rank_heads, l)?;
        if let (Some(scores), Some(first)) = (low_rank, layers.first_mut()) {
            first.scores = scores;
        }
        let w_ring = p_in.len() / l;
        let d_ff = cfg.d_ff;
        let zeros = |n: usize| vec![0f32; n];
        let s = Scratch {
            x0: zeros(l * w_ring),
            h: zeros(l * d),
            h_prev: zeros(l * d),
            q: zeros(l * d),
            k: zeros(l * d),
            k_prev: zeros(l * d),
            beta: zeros(l),
            v: zeros(l * d),
            att: zeros(l * d),
            z: zeros(l * d),
            ctx: zeros(heads * d),
            ff: zeros(l * d_ff),
            attn: (0..n_layers).map(|_| zeros(heads * l * l)).collect(),
            ent_attn: (0..n_layers).map(|_| zeros(heads * l)).collect(),
            prior: (0..n_layers)
                .map(|_| if cfg.prior == Prior::Gaussian { zeros(heads * l * l) } else { Vec::new() })
                .collect(),
            ent_prior: (0..n_layers)
                .map(|_| if cfg.prior == Prior::Gaussian { zeros(heads * l) } else { Vec::new() })
                .collect(),
            sigma: zeros(l * heads),
            r_hat: zeros(m),
            class: zeros(cfg.d_class),
            logit: zeros(1),
            tcd: zeros(l),
            terms: zeros(vmath::row_block(l) * l),
        };
        Ok(Self {
            l,
            m,
            d,
            heads,
            dcm: cfg.dcm,
            class_input: cfg.class_input,
            w_in,
            p_in,
            w_ring,
            layers,
            recon: Linear::load(net, "recon")?,
            class1: Linear::load(net, "class1")?,
            class2: Linear::load(net, "class2")?,
            ring: zeros(l * w_ring),
            start: 0,
            n_seen: 0,
            s,
        })
    }

    /// Forgets every residue seen.
    pub fn reset(&mut self) {
        self.start = 0;
        self.n_seen = 0;
    }

    /// Residues seen since construction or [`StreamingNet::reset`].
    pub fn n_seen(&self) -> usize {
        self.n_seen
    }

    /// Slides the window to end at the normalised residue `x` (`m` values) and computes its
    /// newest step's outputs, with the TCD of every step when `with_tcd`.
    ///
    /// # Errors
    /// [`ModelError::Data`] for a residue of the wrong length or with a non-finite value.
    pub fn push(&mut self, x: &[f32], with_tcd: bool) -> Result<StepOutput<'_>> {
        if x.len() != self.m {
            return Err(ModelError::Data { msg: format!("residue of {} values, network reads {}", x.len(), self.m) });
        }
        if let Some(j) = x.iter().position(|v| !v.is_finite()) {
            return Err(ModelError::Data { msg: format!("non-finite residue value in channel {j}") });
        }
        self.push_residue(x)?;
        vmath::vectorized(
            #[inline(always)]
            || self.forward(with_tcd),
        )?;
        let s = &self.s;
        let recon_err = s.r_hat.iter().zip(x).map(|(r, v)| (r - v) * (r - v)).sum::<f32>() / self.m as f32;
        Ok(StepOutput { recon_err, logit: s.logit[0], tcd: with_tcd.then_some(&s.tcd[..]) })
    }

    /// Stores the residue part of layer 1's input and projections in the ring (every slot for
    /// the first residue: front padding).
    fn push_residue(&mut self, x: &[f32]) -> Result<()> {
        let w = self.w_ring;
        let slot = if self.n_seen == 0 { 0 } else { self.start };
        let row = &mut self.ring[slot * w..(slot + 1) * w];
        matmul(
            MatMut::rows(row, 1, w)?,
            MatRef::rows(x, 1, self.m)?,
            MatRef::rows(&self.w_in, self.m, w)?,
            1.0,
            false,
        )?;
        if self.n_seen == 0 {
            let (first, rest) = self.ring.split_at_mut(w);
            for r in rest.chunks_exact_mut(w) {
                r.copy_from_slice(first);
            }
            self.start = 0;
        } else {
            // The slot that held the oldest step now holds the newest: the next one is oldest.
            self.start = (self.start + 1) % self.l;
        }
        self.n_seen += 1;
        Ok(())
    }

    /// The forward pass of the current window. Inlined into [`vmath::vectorized`], like every
    /// function it calls with element-wise loops.
    #[inline(always)]
    fn forward(&mut self, with_tcd: bool) -> Result<()> {
        let (l, d, heads) = (self.l, self.d, self.heads);
        let dh = d / heads;
        let scale = 1.0 / (dh as f32).sqrt();
        let w_ring = self.w_ring;
        let s = &mut self.s;
        // Layer 1's input and projections: ring (oldest first) plus the position part.
        for i in 0..l {
            let slot = (self.start + i) % l;
            let (dst, ring, pos) = (
                &mut s.x0[i * w_ring..(i + 1) * w_ring],
                &self.ring[slot * w_ring..(slot + 1) * w_ring],
                &self.p_in[i * w_ring..(i + 1) * w_ring],
            );
            for ((o, a), b) in dst.iter_mut().zip(ring).zip(pos) {
                *o = a + b;
            }
        }
        let n_layers = self.layers.len();
        for (idx, layer) in self.layers.iter().enumerate() {
            let last = idx + 1 == n_layers;
            let out_rows = if last { 1 } else { l };
            let q_rows = if with_tcd || !last { l } else { 1 };
            let first_q = l - q_rows;
            // Input `H`, queries, own keys and values as views (row stride), layer 1 from `x0`.
            let (h_in, h_rs): (&[f32], usize) = if idx == 0 { (&s.x0, w_ring) } else { (&s.h, d) };
            // Keys this layer projects for the next one (DCM, several heads).
            let keys_for_next =
                self.dcm && self.layers.get(idx + 1).is_some_and(|next| matches!(next.scores, Scores::Projected));
            if idx > 0 && out_rows == l {
                layer.w_v.forward(MatRef::new(h_in, l, d, h_rs, 1)?, &mut s.v, l)?;
            }
            if keys_for_next && idx == 0 {
                for (dst, src) in s.k.chunks_exact_mut(d).zip(s.x0.chunks_exact(w_ring)) {
                    dst.copy_from_slice(&src[2 * d..3 * d]);
                }
            } else if keys_for_next {
                layer.w_k.forward(MatRef::new(h_in, l, d, h_rs, 1)?, &mut s.k, l)?;
            }
            // Scores `Q Kᵀ/√d` per head (eq:first_layer_attention, eq:cross_layer_attention), in
            // the layer's form (`Scores`; `κ` and `β` are columns `4d..5d` and `5d` of the ring).
            let attn = &mut s.attn[idx];
            let h_q = MatRef::new(&h_in[first_q * h_rs..], q_rows, d, h_rs, 1)?;
            match &layer.scores {
                Scores::Projected => {
                    if idx > 0 {
                        layer.w_q.forward(h_q, &mut s.q, q_rows)?;
                        if !self.dcm {
                            layer.w_k.forward(MatRef::new(h_in, l, d, h_rs, 1)?, &mut s.k, l)?;
                        }
                    }
                    let (q, q_rs, q_off) =
                        if idx == 0 { (&s.x0[..], w_ring, first_q * w_ring + d) } else { (&s.q[..], d, 0) };
                    let (keys, k_rs, k_off) = match (idx, self.dcm) {
                        (0, _) => (&s.x0[..], w_ring, 2 * d),
                        (_, true) => (&s.k_prev[..], d, 0),
                        (_, false) => (&s.k[..], d, 0),
                    };
                    for hd in 0..heads {
                        matmul(
                            MatMut::rows(&mut attn[hd * q_rows * l..(hd + 1) * q_rows * l], q_rows, l)?,
                            MatRef::new(&q[q_off + hd * dh..], q_rows, dh, q_rs, 1)?,
                            MatRef::new(&keys[k_off + hd * dh..], l, dh, k_rs, 1)?.t(),
                            scale,
                            false,
                        )?;
                    }
                }
                Scores::LowRank { col, e } => {
                    let m = self.m;
                    for hd in 0..heads {
                        let c = &mut attn[hd * q_rows * l..(hd + 1) * q_rows * l];
                        c.copy_from_slice(&e[(hd * l + first_q) * l..(hd + 1) * l * l]);
                        let block = col + hd * 3 * m;
                        matmul(
                            MatMut::rows(c, q_rows, l)?,
                            MatRef::new(&s.x0[first_q * w_ring + block..], q_rows, 2 * m, w_ring, 1)?,
                            MatRef::new(&s.x0[block + m..], l, 2 * m, w_ring, 1)?.t(),
                            1.0,
                            true,
                        )?;
                    }
                }
                Scores::RingKeys => {
                    let kappa = MatRef::new(&s.x0[4 * d..], l, d, w_ring, 1)?;
                    matmul(MatMut::rows(attn, q_rows, l)?, h_q, kappa.t(), 1.0, false)?;
                    for (b, row) in s.beta.iter_mut().zip(s.x0.chunks_exact(w_ring)) {
                        *b = row[5 * d];
                    }
                    for row in attn[..q_rows * l].chunks_exact_mut(l) {
                        add_bias_row(row, &s.beta);
                    }
                }
                Scores::Folded(fold) => {
                    fold.forward(h_q, &mut s.q, q_rows)?;
                    matmul(
                        MatMut::rows(attn, q_rows, l)?,
                        MatRef::rows(&s.q, q_rows, d)?,
                        MatRef::rows(&s.h_prev, l, d)?.t(),
                        1.0,
                        false,
                    )?;
                }
            }
            // Attention `C = softmax(S)`, with `Σ C ln C` of every row for the TCD.
            let entropy = with_tcd.then_some((&mut s.ent_attn[idx][..], &mut s.terms[..]));
            softmax_rows(&mut attn[..heads * q_rows * l], l, entropy);
            // Attention output of the `out_rows` newest rows, heads side by side.
            let c_out = |hd: usize| -> Result<MatRef<'_>> {
                Ok(MatRef::rows(&attn[(hd * q_rows + q_rows - out_rows) * l..(hd + 1) * q_rows * l], out_rows, l)?)
            };
            if idx == 0 || out_rows == l {
                let (v, v_rs, v_off) = if idx == 0 { (&s.x0[..], w_ring, 3 * d) } else { (&s.v[..], d, 0) };
                for hd in 0..heads {
                    matmul(
                        MatMut::new(&mut s.att[hd * dh..], out_rows, dh, d, 1)?,
                        c_out(hd)?,
                        MatRef::new(&v[v_off + hd * dh..], l, dh, v_rs, 1)?,
                        1.0,
                        false,
                    )?;
                }
            } else {
                // One row: `c (H W_V + b_V) = (c H) W_V + b_V` per head.
                let w_v = &layer.w_v;
                for hd in 0..heads {
                    let ctx = &mut s.ctx[hd * d..(hd + 1) * d];
                    matmul(MatMut::rows(ctx, 1, d)?, c_out(hd)?, MatRef::new(h_in, l, d, h_rs, 1)?, 1.0, false)?;
                    let out = &mut s.att[hd * dh..(hd + 1) * dh];
                    matmul(
                        MatMut::rows(out, 1, dh)?,
                        MatRef::rows(ctx, 1, d)?,
                        MatRef::new(&w_v.w[hd * dh..], d, dh, d, 1)?,
                        1.0,
                        false,
                    )?;
                    add_bias_row(out, &w_v.b[hd * dh..(hd + 1) * dh]);
                }
            }
            // Gaussian prior from this layer's input (only for the TCD).
            if with_tcd && let LayerPrior::Gaussian { sigma } = &layer.prior {
                sigma.forward(MatRef::new(h_in, l, d, h_rs, 1)?, &mut s.sigma, l)?;
                gaussian_prior(&s.sigma, heads, l, &mut s.prior[idx], &mut s.ent_prior[idx], &mut s.terms);
            }
            // `Z = Norm(C V W_O + b_O + H)` on the newest `out_rows` rows.
            let rows = out_rows * d;
            for (i, z_row) in s.z[..rows].chunks_exact_mut(d).enumerate() {
                let src = (l - out_rows + i) * h_rs;
                z_row.copy_from_slice(&h_in[src..src + d]);
                match &layer.w_o {
                    Some(w_o) => add_bias_row(z_row, &w_o.b),
                    // One head: the attention output is already `C V W_O + b_O`.
                    None => add_bias_row(z_row, &s.att[i * d..(i + 1) * d]),
                }
            }
            if let Some(w_o) = &layer.w_o {
                matmul(
                    MatMut::rows(&mut s.z, out_rows, d)?,
                    MatRef::rows(&s.att, out_rows, d)?,
                    MatRef::rows(&w_o.w, d, d)?,
                    1.0,
                    true,
                )?;
            }
            layer.norm1.apply(&mut s.z[..rows]);
            // `H' = Norm(FF(Z) + Z)`.
            layer.ff1.forward(MatRef::rows(&s.z, out_rows, d)?, &mut s.ff, out_rows)?;
            for v in &mut s.ff[..out_rows * layer.ff1.n_out] {
                *v = gelu_value(*v);
            }
            // The input `H` stays as the next layer's `H'` ([`Scores::Folded`]).
            std::mem::swap(&mut s.h, &mut s.h_prev);
            for (h_row, z_row) in s.h[..rows].chunks_exact_mut(d).zip(s.z.chunks_exact(d)) {
                h_row.copy_from_slice(z_row);
                add_bias_row(h_row, &layer.ff2.b);
            }
            matmul(
                MatMut::rows(&mut s.h, out_rows, d)?,
                MatRef::rows(&s.ff, out_rows, layer.ff1.n_out)?,
                MatRef::rows(&layer.ff2.w, layer.ff2.n_in, d)?,
                1.0,
                true,
            )?;
            layer.norm2.apply(&mut s.h[..rows]);
            if keys_for_next {
                std::mem::swap(&mut s.k, &mut s.k_prev);
            }
        }
        // Heads on the newest row.
        self.recon.forward(MatRef::rows(&s.h, 1, d)?, &mut s.r_hat, 1)?;
        let class_in = match self.class_input {
            ClassInput::Reconstruction => MatRef::rows(&s.r_hat, 1, self.m)?,
            ClassInput::Hidden => MatRef::rows(&s.h, 1, d)?,
        };
        self.class1.forward(class_in, &mut s.class, 1)?;
        for v in &mut s.class {
            *v = gelu_value(*v);
        }
        self.class2.forward(MatRef::rows(&s.class, 1, s.class.len())?, &mut s.logit, 1)?;
        if with_tcd {
            self.tcd();
        }
        Ok(())
    }

    /// TCD of every step: mean over layers and heads of
    /// `JS(Tᵢ ‖ Cᵢ) = ½ (Σ T ln T + Σ C ln C) − Σ M ln M` (module docs).
    #[inline(always)]
    fn tcd(&mut self) {
        let (l, heads) = (self.l, self.heads);
        let s = &mut self.s;
        s.tcd.fill(0.0);
        for (idx, layer) in self.layers.iter().enumerate() {
            let (t, ent_t) = match &layer.prior {
                LayerPrior::Tpc { t, ent } => (&t[..], &ent[..]),
                LayerPrior::Gaussian { .. } => (&s.prior[idx][..], &s.ent_prior[idx][..]),
            };
            // Rows `hd·l + i`, a block at a time (vmath::row_block).
            let (n, block) = (heads * l * l, vmath::row_block(l) * l);
            let blocks = t[..n].chunks(block).zip(s.attn[idx][..n].chunks(block));
            for (b, (t_block, c_block)) in blocks.enumerate() {
                let terms = &mut s.terms[..t_block.len()];
                mixture_entropy_terms(t_block, c_block, terms);
                for (r, row_terms) in terms.chunks_exact(l).enumerate() {
                    let row = b * block / l + r;
                    let js = 0.5 * (ent_t[row] + s.ent_attn[idx][row]) - vmath::sum(row_terms);
                    s.tcd[row % l] += js / heads as f32;
                }
            }
        }
        let n = self.layers.len() as f32;
        for v in &mut s.tcd {
            *v /= n;
        }
    }
}

/// Layer 1's residue and position parts (module docs, points 1, 6 and 7).
struct LayerOne {
    /// Residue part of a ring row per residue channel, `m × width`.
    w_in: Vec<f32>,
    /// Position part of a ring row per step, `l × width`.
    p_in: Vec<f32>,
    /// [`Scores::LowRank`], when asked for.
    low_rank: Option<Scores>,
}

/// Layer 1's residue and position parts, accumulated in `f64`. A ring row is
/// `[h⁰ | Q¹ | K¹ | V¹]`, then `[κ | β]` with `key_map` ([`Scores::RingKeys`]), then with
/// `low_rank_heads` one block `[x G + B | x | Aᵀ]` per head ([`Scores::LowRank`]). The residue
/// part of `[h⁰ | Q¹ | K¹ | V¹]` is `x [W_e | W_e W_Q | W_e W_K | W_e W_V]`, its position part
/// `(b_e + PEᵢ)[I | W_Q | W_K | W_V] + [0 | b_Q | b_K | b_V]`.
fn layer_one_parts(
    embed: &Linear,
    pos: &[f32],
    layer: &LayerW,
    key_map: Option<&Linear>,
    low_rank_heads: Option<usize>,
    l: usize,
) -> Result<LayerOne> {
    let (m, d) = (embed.n_in, embed.n_out);
    if pos.len() != l * d {
        return Err(ModelError::Data {
            msg: format!("positional encoding of {} values, expected {l} × {d}", pos.len()),
        });
    }
    // Row `u` (`d` values) through the identity and the three projections (`bias` times their
    // biases), and its key through `key_map`.
    const Q: usize = 1;
    const K: usize = 2;
    let through = |u: &[f64], bias: f64| -> [Vec<f64>; 5] {
        let key = layer.w_k.apply_f64(u, bias);
        let folded_key = key_map.map(|map| map.apply_f64(&key, 0.0)).unwrap_or_default();
        [u.to_vec(), layer.w_q.apply_f64(u, bias), key, layer.w_v.apply_f64(u, bias), folded_key]
    };
    let res: Vec<_> = embed.w.chunks_exact(d).map(|row| through(&to_f64(row), 0.0)).collect();
    let posn: Vec<_> = pos
        .chunks_exact(d)
        .map(|pe| {
            through(&pe.iter().zip(&embed.b).map(|(&p, &b)| f64::from(b) + f64::from(p)).collect::<Vec<_>>(), 1.0)
        })
        .collect();
    let mut w_rows: Vec<Vec<f64>> = res.iter().map(|parts| parts.concat()).collect();
    let mut p_rows: Vec<Vec<f64>> = posn.iter().map(|parts| parts.concat()).collect();
    let col = 4 * d + key_map.map_or(0, |map| map.n_out);
    let low_rank = low_rank_heads.map(|heads| {
        let dh = d / heads;
        let scale = 1.0 / (dh as f64).sqrt();
        let dot = |a: &[f64], b: &[f64], hd: usize| -> f64 {
            a[hd * dh..(hd + 1) * dh].iter().zip(&b[hd * dh..(hd + 1) * dh]).map(|(x, y)| x * y).sum::<f64>() * scale
        };
        let mut e = Vec::with_capacity(heads * l * l);
        for hd in 0..heads {
            for (r, row) in w_rows.iter_mut().enumerate() {
                row.extend(res.iter().map(|other| dot(&res[r][Q], &other[K], hd)));
                row.extend((0..m).map(|c| if c == r { 1.0 } else { 0.0 }));
                row.extend(std::iter::repeat_n(0.0, m));
            }
            for (pi, row) in posn.iter().zip(&mut p_rows) {
                row.extend(res.iter().map(|other| dot(&pi[Q], &other[K], hd)));
                row.extend(std::iter::repeat_n(0.0, m));
                row.extend(res.iter().map(|other| dot(&pi[K], &other[Q], hd)));
            }
            e.extend(posn.iter().flat_map(|pi| posn.iter().map(move |pj| dot(&pi[Q], &pj[K], hd) as f32)));
        }
        Scores::LowRank { col, e }
    });
    let flat = |rows: Vec<Vec<f64>>| -> Vec<f32> { rows.concat().iter().map(|&v| v as f32).collect() };
    Ok(LayerOne { w_in: flat(w_rows), p_in: flat(p_rows), low_rank })
}

/// Anomaly Transformer's Gaussian prior from the width projections `s` (`l × heads`):
/// `σ = 3^(sigmoid(5s) + 10⁻⁵) − 1`, `Tᵢⱼ ∝ exp(−|j − i|²/(2σᵢ²))` (exponent clamped at
/// [`PRIOR_EXP_FLOOR`]), as [`QuadFormerNet`] builds it: the softmax of the exponents, whose
/// maximum is 0. `t` is `heads × l × l`, `ent` (`heads × l`) the `Σⱼ Tᵢⱼ ln Tᵢⱼ` of its rows;
/// `shifted` (a block of rows, [`vmath::row_block`]) is scratch.
#[inline(always)]
fn gaussian_prior(s: &[f32], heads: usize, l: usize, t: &mut [f32], ent: &mut [f32], shifted: &mut [f32]) {
    let floor = PRIOR_EXP_FLOOR as f32;
    for hd in 0..heads {
        for i in 0..l {
            let u = 1.0 / (1.0 + vmath::exp(-5.0 * s[i * heads + hd])) + 1e-5;
            let sigma = vmath::exp(u * 3f32.ln()) - 1.0;
            let two_var = 2.0 * sigma * sigma;
            let row = &mut t[(hd * l + i) * l..(hd * l + i + 1) * l];
            for (j, v) in row.iter_mut().enumerate() {
                let dist = j as f32 - i as f32;
                *v = (-(dist * dist) / two_var).clamp(floor, 0.0);
            }
        }
    }
    softmax_rows(&mut t[..heads * l * l], l, Some((ent, shifted)));
}

#[cfg(test)]
mod tests;
