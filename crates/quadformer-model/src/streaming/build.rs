//! Preparing a network for streaming: host copies of the typed weights
//! ([`crate::weights::QuadFormerWeights`]), the score form of each layer, the products formed
//! once in `f64` (module docs of [`crate::streaming`], points 1, 3, 6 and 7) and the ring's
//! residue and position parts in the slots of its [`RingLayout`].

use super::dense::{LayerNormW, Linear, to_f64};
use super::engine::{LayerPrior, LayerW, Scores, Scratch, StreamingNet};
use super::layout::RingLayout;
use crate::error::{ModelError, Result};
use crate::model::{Prior, QuadFormerNet};
use crate::weights::PriorWeights;
use nn_toolkit::vmath;

impl StreamingNet {
    /// Why the engine cannot represent `net`, if it cannot: then the detector scores its
    /// streaming decisions with the candle forward pass instead
    /// ([`crate::detector::OnlineQuadFormer`]). Every [`crate::NetConfig`] is represented;
    /// the engine reads `f32` weights only.
    pub fn unsupported(net: &QuadFormerNet) -> Option<String> {
        let dtypes: Vec<_> = net.varmap().all_vars().iter().map(|v| v.dtype()).collect();
        dtypes
            .iter()
            .find(|&&t| t != candle_core::DType::F32)
            .map(|t| format!("weights of type {t:?} (it computes in f32)"))
    }

    /// Prepares `net` (its current weights; TPC priors from [`QuadFormerNet::freeze`]'s
    /// cache when frozen).
    ///
    /// # Errors
    /// [`ModelError::StreamingUnsupported`] for a network of [`StreamingNet::unsupported`];
    /// candle errors.
    pub fn new(net: &QuadFormerNet) -> Result<Self> {
        if let Some(what) = Self::unsupported(net) {
            return Err(ModelError::StreamingUnsupported { what });
        }
        let cfg = net.config();
        let weights = net.weights();
        let (l, m, d, heads, n_layers) = (net.window_len(), net.dim(), cfg.d_model, cfg.n_heads, cfg.n_layers);
        let embed = Linear::of(&weights.embed)?;
        let pos = net.positional_encoding().flatten_all()?.to_vec1::<f32>()?;
        let mut tpc = net.tpc_priors()?.into_iter();
        // The attention's scale `1/√d_h`, folded into the weights of the refactored scores.
        let scale = 1.0 / ((d / heads) as f32).sqrt();
        let mut layers: Vec<LayerW> = Vec::with_capacity(n_layers);
        for (h, lw) in weights.layers.iter().enumerate() {
            let prior = match &lw.prior {
                PriorWeights::Tpc { .. } => {
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
                PriorWeights::Gaussian { sigma } => LayerPrior::Gaussian { sigma: Linear::of(sigma)? },
            };
            let (w_v, w_o) = (Linear::of(&lw.w_v)?, Linear::of(&lw.w_o)?);
            let (w_v, w_o) = if heads == 1 { (w_v.then(&w_o), None) } else { (w_v, Some(w_o)) };
            let w_q = Linear::of(&lw.w_q)?;
            let scores = match (layers.last(), h) {
                (Some(_), 1) if cfg.dcm && heads == 1 => Scores::RingKeys,
                (Some(prev), _) if cfg.dcm && heads == 1 => Scores::Folded(w_q.then(&prev.w_k.transposed(scale))),
                _ => Scores::Projected,
            };
            layers.push(LayerW {
                scores,
                w_q,
                w_k: Linear::of(&lw.w_k)?,
                w_v,
                w_o,
                norm1: LayerNormW::of(&lw.norm1)?,
                ff1: Linear::of(&lw.ff1)?,
                ff2: Linear::of(&lw.ff2)?,
                norm2: LayerNormW::of(&lw.norm2)?,
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
        let layout = RingLayout::new(d, m, key_map.is_some(), low_rank_heads);
        let LayerOne { w_in, p_in, low_rank } =
            layer_one_parts(&embed, &pos, first, key_map.as_ref(), low_rank_heads, l, &layout)?;
        if let (Some(scores), Some(first)) = (low_rank, layers.first_mut()) {
            first.scores = scores;
        }
        let w_ring = layout.width();
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
            causal: cfg.causal,
            class_input: cfg.class_input,
            layout,
            w_in,
            p_in,
            layers,
            recon: Linear::of(&weights.recon)?,
            class1: Linear::of(&weights.class1)?,
            class2: Linear::of(&weights.class2)?,
            ring: zeros(l * w_ring),
            start: 0,
            n_seen: 0,
            s,
        })
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

/// Layer 1's residue and position parts, accumulated in `f64`, in the slots of `layout`:
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
    layout: &RingLayout,
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
    // A ring row with `[h⁰ | Q¹ | K¹ | V¹ | κ | β]` in their slots and zeros elsewhere.
    let slots =
        [layout.h0.clone(), layout.q.clone(), layout.k.clone(), layout.v.clone(), layout.kappa.start..layout.beta.end];
    let row_of = |parts: &[Vec<f64>; 5]| -> Result<Vec<f64>> {
        let mut row = vec![0.0; layout.width()];
        for (slot, part) in slots.iter().zip(parts) {
            row.get_mut(slot.clone())
                .filter(|dst| dst.len() == part.len())
                .map(|dst| dst.copy_from_slice(part))
                .ok_or_else(|| ModelError::Data {
                    msg: format!("ring slot {slot:?} cannot hold {} values", part.len()),
                })?;
        }
        Ok(row)
    };
    let mut w_rows: Vec<Vec<f64>> = res.iter().map(row_of).collect::<Result<_>>()?;
    let mut p_rows: Vec<Vec<f64>> = posn.iter().map(row_of).collect::<Result<_>>()?;
    let low_rank = low_rank_heads.map(|heads| {
        let dh = d / heads;
        let scale = 1.0 / (dh as f64).sqrt();
        let dot = |a: &[f64], b: &[f64], hd: usize| -> f64 {
            a[hd * dh..(hd + 1) * dh].iter().zip(&b[hd * dh..(hd + 1) * dh]).map(|(x, y)| x * y).sum::<f64>() * scale
        };
        let mut e = Vec::with_capacity(heads * l * l);
        for hd in 0..heads {
            // `[x G + B | x | Aᵀ]`: residue part `[x G | x | 0]`, position part `[B | 0 | Aᵀ]`.
            let block = layout.low_rank_block(hd);
            for (r, row) in w_rows.iter_mut().enumerate() {
                let dst = &mut row[block.clone()];
                let (xg, rest) = dst.split_at_mut(m);
                let (x, _) = rest.split_at_mut(m);
                for (v, other) in xg.iter_mut().zip(&res) {
                    *v = dot(&res[r][Q], &other[K], hd);
                }
                x[r] = 1.0;
            }
            for (pi, row) in posn.iter().zip(&mut p_rows) {
                let dst = &mut row[block.clone()];
                let (b, rest) = dst.split_at_mut(m);
                let (_, a_t) = rest.split_at_mut(m);
                for (v, other) in b.iter_mut().zip(&res) {
                    *v = dot(&pi[Q], &other[K], hd);
                }
                for (v, other) in a_t.iter_mut().zip(&res) {
                    *v = dot(&pi[K], &other[Q], hd);
                }
            }
            e.extend(posn.iter().flat_map(|pi| posn.iter().map(move |pj| dot(&pi[Q], &pj[K], hd) as f32)));
        }
        Scores::LowRank { e }
    });
    let flat = |rows: Vec<Vec<f64>>| -> Vec<f32> { rows.concat().iter().map(|&v| v as f32).collect() };
    Ok(LayerOne { w_in: flat(w_rows), p_in: flat(p_rows), low_rank })
}
