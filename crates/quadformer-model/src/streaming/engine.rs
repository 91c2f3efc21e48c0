//! The streaming engine's state and its decision: the ring of layer 1's residue parts, the
//! buffers allocated once, and the forward pass of the newest window (module docs of
//! [`crate::streaming`] have the algebra; [`super::build`] prepares the weights).

use super::dense::{LayerNormW, Linear};
use super::layout::RingLayout;
use crate::error::{ModelError, Result};
use crate::js::mixture_entropy_terms;
use crate::model::{CAUSAL_MASK_FLOOR, ClassInput, PRIOR_EXP_FLOOR};
use nn_toolkit::fused::{add_bias_row, gelu_value, softmax_rows};
use nn_toolkit::matmul::{MatMut, MatRef, matmul};
use nn_toolkit::vmath;

/// The prior association `T` of one layer.
#[derive(Clone)]
pub(super) enum LayerPrior {
    /// Frozen TPC maps `heads × l × l` and the `Σⱼ Tᵢⱼ ln(Tᵢⱼ + ε)` of their rows.
    Tpc { t: Vec<f32>, ent: Vec<f32> },
    /// Anomaly Transformer's Gaussian kernel; its width is a projection of the layer input.
    Gaussian { sigma: Linear },
}

/// How a layer forms its attention scores `S = Q Kᵀ/√d_h` (module docs, points 6 and 7).
#[derive(Clone)]
pub(super) enum Scores {
    /// From the projected queries and keys: this layer's own keys, or with DCM the previous
    /// layer's. Layer 1 reads its projections from the ring.
    Projected,
    /// Layer 2 with DCM and one head: `S = H κᵀ + 1 βᵀ`, where `[κⱼ | βⱼ] = K¹ⱼ [W_Q | b_Q]ᵀ/√d`
    /// is affine in residue `j` and so held in the ring.
    RingKeys,
    /// Layer 1 in the rank of the residues: `S = [X G + B | X][X | Aᵀ]ᵀ + E` per head, with
    /// `G = W_e W_Q (W_e W_K)ᵀ/√d`, `B = P_Q (W_e W_K)ᵀ/√d`, `A = W_e W_Q P_Kᵀ/√d`,
    /// `E = P_Q P_Kᵀ/√d` (`P_Q`, `P_K` the position parts of `Q¹`, `K¹`). The ring holds a block
    /// `[x G + B | x | Aᵀ]` per head ([`RingLayout::low_rank_block`]); `E` is `heads × l × l`.
    LowRank { e: Vec<f32> },
    /// A later layer with DCM and one head: `S ≅ (H F + f) H'ᵀ` with `H'` the previous
    /// layer's input, `F = W_Q W'_Kᵀ/√d` and `f = b_Q W'_Kᵀ/√d` (this linear map); the
    /// previous layer's keys are never formed.
    Folded(Linear),
}

/// One UAV Attack Attention layer's weights.
#[derive(Clone)]
pub(super) struct LayerW {
    pub(super) scores: Scores,
    pub(super) w_q: Linear,
    pub(super) w_k: Linear,
    /// The value projection; with one head, `W_V W_O` and `b_V W_O + b_O` (module docs).
    pub(super) w_v: Linear,
    /// The output projection; `None` with one head, where it is folded into `w_v`.
    pub(super) w_o: Option<Linear>,
    pub(super) norm1: LayerNormW,
    pub(super) ff1: Linear,
    pub(super) ff2: Linear,
    pub(super) norm2: LayerNormW,
    pub(super) prior: LayerPrior,
}

/// The newest step's outputs ([`StreamingNet::push`]).
#[derive(Debug, Clone, Copy)]
pub struct StepOutput<'a> {
    /// Mean over channels of `(R̂ − x)²` at the newest step.
    pub recon_err: f32,
    /// Classifier logit at the newest step.
    pub logit: f32,
    /// TCD of every step of the window (oldest first), when asked for; with a causal network
    /// that has seen fewer than `l` residues, of the steps seen.
    pub tcd: Option<&'a [f32]>,
}

/// Per-window intermediates, allocated once.
#[derive(Clone)]
pub(super) struct Scratch {
    /// Ring rows of the window, oldest first ([`RingLayout`]: layer 1's input and
    /// projections, and the parts of the refactored scores), `l × width`.
    pub(super) x0: Vec<f32>,
    /// A layer's input `H` (`l × d`, layers after the first), then its output; and the
    /// previous layer's input.
    pub(super) h: Vec<f32>,
    pub(super) h_prev: Vec<f32>,
    pub(super) q: Vec<f32>,
    /// This layer's keys, and the previous layer's (DCM).
    pub(super) k: Vec<f32>,
    pub(super) k_prev: Vec<f32>,
    /// `β` of [`Scores::RingKeys`], `l` values.
    pub(super) beta: Vec<f32>,
    pub(super) v: Vec<f32>,
    /// Attention output (before `W_O`, or after it when folded).
    pub(super) att: Vec<f32>,
    /// `Z`: the attention output after `W_O`, the residual and the norm.
    pub(super) z: Vec<f32>,
    /// `c H` of every head (last layer).
    pub(super) ctx: Vec<f32>,
    pub(super) ff: Vec<f32>,
    /// Every layer's attention `C` (`heads × rows × l`) and Gaussian prior `T` (`heads × l × l`),
    /// and the `Σⱼ xᵢⱼ ln xᵢⱼ` of their rows (only for the TCD).
    pub(super) attn: Vec<Vec<f32>>,
    pub(super) ent_attn: Vec<Vec<f32>>,
    pub(super) prior: Vec<Vec<f32>>,
    pub(super) ent_prior: Vec<Vec<f32>>,
    /// Gaussian widths of every step and head, `l × heads`.
    pub(super) sigma: Vec<f32>,
    pub(super) r_hat: Vec<f32>,
    pub(super) class: Vec<f32>,
    pub(super) logit: Vec<f32>,
    pub(super) tcd: Vec<f32>,
    /// Scratch of a block of rows of a map ([`vmath::row_block`]).
    pub(super) terms: Vec<f32>,
}

/// A trained QUADFormer network prepared for streaming (module docs).
#[derive(Clone)]
pub struct StreamingNet {
    pub(super) l: usize,
    pub(super) m: usize,
    pub(super) d: usize,
    pub(super) heads: usize,
    pub(super) dcm: bool,
    /// Every step attends to itself and earlier steps only ([`crate::NetConfig::causal`]).
    pub(super) causal: bool,
    pub(super) class_input: ClassInput,
    /// The slots of a row of the ring, `w_in`, `p_in` and `x0`.
    pub(super) layout: RingLayout,
    /// Residue part of a ring row per residue channel, `m × width` (`build::layer_one_parts`:
    /// `[W_e | W_e W_Q¹ | W_e W_K¹ | W_e W_V¹]` with `W_V¹` as held by its layer, then the
    /// parts of [`Scores::RingKeys`] and [`Scores::LowRank`] when used).
    pub(super) w_in: Vec<f32>,
    /// Position part of a ring row per step, `l × width`.
    pub(super) p_in: Vec<f32>,
    pub(super) layers: Vec<LayerW>,
    pub(super) recon: Linear,
    pub(super) class1: Linear,
    pub(super) class2: Linear,
    /// Residue parts of the window, `l` rows; row `start` holds the oldest step.
    pub(super) ring: Vec<f32>,
    pub(super) start: usize,
    pub(super) n_seen: usize,
    pub(super) s: Scratch,
}

impl StreamingNet {
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
        let rows = self.newest() + 1;
        Ok(StepOutput { recon_err, logit: s.logit[0], tcd: with_tcd.then_some(&s.tcd[..rows]) })
    }

    /// Where the window's steps start in the padded ring order (oldest first) and the
    /// position of the newest step. A full-window network reads the padded window, newest
    /// step last. A causal network that has seen `n < l` residues reads them as the window's
    /// first `n` positions, as its batch score of a flight's first window does: no padding,
    /// the newest step at position `n − 1`; the positions after it hold padding copies,
    /// which no position up to it reads.
    fn placement(&self) -> (usize, usize) {
        let n = self.n_seen.min(self.l);
        if self.causal && n < self.l { (self.l - n, n - 1) } else { (0, self.l - 1) }
    }

    /// The position of the newest step in the window ([`StreamingNet::placement`]).
    fn newest(&self) -> usize {
        self.placement().1
    }

    /// Stores the residue part of layer 1's input and projections in the ring (every slot for
    /// the first residue: front padding).
    fn push_residue(&mut self, x: &[f32]) -> Result<()> {
        let w = self.layout.width();
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
        let (shift, newest) = self.placement();
        let causal = self.causal;
        let layout = &self.layout;
        let w_ring = layout.width();
        let s = &mut self.s;
        // Layer 1's input and projections: ring (oldest first) plus the position part.
        for i in 0..l {
            let slot = (self.start + shift + i) % l;
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
            // The rows this layer outputs (from `out_first`) and the rows it forms queries of
            // (from `first_q`): every row, or with the last layer the newest one.
            let out_rows = if last { 1 } else { l };
            let out_first = if last { newest } else { 0 };
            let q_rows = if with_tcd || !last { l } else { 1 };
            let first_q = if q_rows == l { 0 } else { newest };
            // Input `H`, queries, own keys and values as views (row stride), layer 1 from `x0`.
            let (h_in, h_rs): (&[f32], usize) = if idx == 0 { (&s.x0[layout.h0.start..], w_ring) } else { (&s.h, d) };
            // Keys this layer projects for the next one (DCM, several heads).
            let keys_for_next =
                self.dcm && self.layers.get(idx + 1).is_some_and(|next| matches!(next.scores, Scores::Projected));
            if idx > 0 && out_rows == l {
                layer.w_v.forward(MatRef::new(h_in, l, d, h_rs, 1)?, &mut s.v, l)?;
            }
            if keys_for_next && idx == 0 {
                for (dst, src) in s.k.chunks_exact_mut(d).zip(s.x0.chunks_exact(w_ring)) {
                    dst.copy_from_slice(&src[layout.k.clone()]);
                }
            } else if keys_for_next {
                layer.w_k.forward(MatRef::new(h_in, l, d, h_rs, 1)?, &mut s.k, l)?;
            }
            // Scores `Q Kᵀ/√d` per head (eq:first_layer_attention, eq:cross_layer_attention), in
            // the layer's form (`Scores`; their parts in the ring by `RingLayout`).
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
                    let (q, q_rs, q_off) = if idx == 0 {
                        (&s.x0[..], w_ring, first_q * w_ring + layout.q.start)
                    } else {
                        (&s.q[..], d, 0)
                    };
                    let (keys, k_rs, k_off) = match (idx, self.dcm) {
                        (0, _) => (&s.x0[..], w_ring, layout.k.start),
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
                Scores::LowRank { e } => {
                    for hd in 0..heads {
                        let c = &mut attn[hd * q_rows * l..(hd + 1) * q_rows * l];
                        c.copy_from_slice(&e[(hd * l + first_q) * l..][..q_rows * l]);
                        let (query, key) = (layout.low_rank_query(hd), layout.low_rank_key(hd));
                        matmul(
                            MatMut::rows(c, q_rows, l)?,
                            MatRef::new(&s.x0[first_q * w_ring + query.start..], q_rows, query.len(), w_ring, 1)?,
                            MatRef::new(&s.x0[key.start..], l, key.len(), w_ring, 1)?.t(),
                            1.0,
                            true,
                        )?;
                    }
                }
                Scores::RingKeys => {
                    let kappa = MatRef::new(&s.x0[layout.kappa.start..], l, layout.kappa.len(), w_ring, 1)?;
                    matmul(MatMut::rows(attn, q_rows, l)?, h_q, kappa.t(), 1.0, false)?;
                    for (b, row) in s.beta.iter_mut().zip(s.x0.chunks_exact(w_ring)) {
                        *b = row[layout.beta.start];
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
            if causal {
                mask_future(&mut attn[..heads * q_rows * l], l, q_rows, first_q);
            }
            // Attention `C = softmax(S)`, with `Σ C ln C` of every row for the TCD.
            let entropy = with_tcd.then_some((&mut s.ent_attn[idx][..], &mut s.terms[..]));
            softmax_rows(&mut attn[..heads * q_rows * l], l, entropy);
            // Attention output of the `out_rows` newest rows, heads side by side.
            let c_out = |hd: usize| -> Result<MatRef<'_>> {
                Ok(MatRef::rows(&attn[(hd * q_rows + out_first - first_q) * l..][..out_rows * l], out_rows, l)?)
            };
            if idx == 0 || out_rows == l {
                let (v, v_rs, v_off) = if idx == 0 { (&s.x0[..], w_ring, layout.v.start) } else { (&s.v[..], d, 0) };
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
                gaussian_prior(&s.sigma, heads, l, causal, &mut s.prior[idx], &mut s.ent_prior[idx], &mut s.terms);
            }
            // `Z = Norm(C V W_O + b_O + H)` on the newest `out_rows` rows.
            let rows = out_rows * d;
            for (i, z_row) in s.z[..rows].chunks_exact_mut(d).enumerate() {
                let src = (out_first + i) * h_rs;
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

/// Adds the causal mask to a block of score rows (`heads × rows × l`, the rows of positions
/// `first..first + rows` of each head): [`CAUSAL_MASK_FLOOR`] after the diagonal, as
/// [`crate::model::QuadFormerNet`] does, so the softmax gives those steps no weight.
#[inline(always)]
fn mask_future(scores: &mut [f32], l: usize, rows: usize, first: usize) {
    for (r, row) in scores.chunks_exact_mut(l).enumerate() {
        let position = first + r % rows;
        for v in &mut row[position + 1..] {
            *v += CAUSAL_MASK_FLOOR;
        }
    }
}

/// Anomaly Transformer's Gaussian prior from the width projections `s` (`l × heads`):
/// `σ = 3^(sigmoid(5s) + 10⁻⁵) − 1`, `Tᵢⱼ ∝ exp(−|j − i|²/(2σᵢ²))` (exponent clamped at
/// [`PRIOR_EXP_FLOOR`]), as [`crate::model::QuadFormerNet`] builds it: the softmax of the exponents, whose
/// maximum is 0; with `causal`, restricted to `j ≤ i` and renormalised. `t` is `heads × l × l`,
/// `ent` (`heads × l`) the `Σⱼ Tᵢⱼ ln Tᵢⱼ` of its rows; `shifted` (a block of rows,
/// [`vmath::row_block`]) is scratch.
#[inline(always)]
pub(super) fn gaussian_prior(
    s: &[f32],
    heads: usize,
    l: usize,
    causal: bool,
    t: &mut [f32],
    ent: &mut [f32],
    shifted: &mut [f32],
) {
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
            if causal {
                row[i + 1..].fill(CAUSAL_MASK_FLOOR);
            }
        }
    }
    softmax_rows(&mut t[..heads * l * l], l, Some((ent, shifted)));
}
