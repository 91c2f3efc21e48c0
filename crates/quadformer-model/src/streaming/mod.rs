//! Streaming inference of a trained QUADFormer network: the outputs of the newest step of a
//! sliding window (reconstruction, classifier logit and, when asked, the TCD of every step),
//! updated one residue at a time with the work and memory fixed in advance.
//!
//! It computes what [`crate::model::QuadFormerNet::forward_steps`] with [`crate::model::Steps::Last`] computes (for a
//! causal network's first `l − 1` steps, row `n − 1` of [`crate::model::Steps::All`] on a window
//! opening with the `n` steps seen), from the same weights, in plain `f32` buffers ([`nn_toolkit::matmul`], the element-wise kernels of
//! [`nn_toolkit::fused`] and [`crate::js`]), and does less work in seven ways, exact but for rounding:
//!
//! 1. **Layer 1 is linear in each residue.** Its input is `h⁰ᵢ = xᵢ W_e + b_e + PEᵢ` and its
//!    projections `Q¹ᵢ = h⁰ᵢ W_Q + b_Q` (likewise `K¹`, `V¹`), so each splits into a part of
//!    the residue, `xᵢ [W_e | W_e W_Q | W_e W_K | W_e W_V]`, and a part of the position. The
//!    residue part is computed once, when the residue arrives, and kept in a ring of `l`
//!    slots; the position part is computed once, when the engine is built. A new window's
//!    layer-1 input and projections are the ring plus the position part: no matrix product.
//! 2. **The last layer works on the newest row** (as [`crate::model::Steps::Last`]): one query, one output
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
//!    the softmax forms `C`. Only `ln(M + ε)` is taken per entry, from [`nn_toolkit::vmath::ln_fast`]
//!    (within 1.4 units in the last place, against 0.7 for [`nn_toolkit::vmath::ln`], at four fifths of its
//!    cost). The softmax and these terms run over blocks of rows that fill whole vectors
//!    ([`nn_toolkit::vmath::row_block`]), so no row leaves a remainder to scalar code.
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
//!
//! A causal network ([`crate::NetConfig::causal`]) gets the candle pass's masks: each score row
//! adds [`crate::model::CAUSAL_MASK_FLOOR`] after its diagonal before the softmax, and its TPC
//! prior is the network's own, restricted to the past and renormalised (the Gaussian prior is
//! restricted the same way). It needs no padding: until `l` residues have been seen they fill
//! the window's first positions and the newest is scored where it stands, as the batch score
//! of a flight's first window does.
//!
//! The engine reads the network's typed weights ([`crate::weights::QuadFormerWeights`]) and
//! nothing by name: `build` prepares them (host copies in `dense`, the products formed once, the
//! score form of each layer), `layout` names the slots of a ring row, and `engine` holds the
//! ring and the buffers and makes the decision. [`StreamingNet::unsupported`] names a network it
//! cannot represent; the streaming detector then runs the candle forward pass instead
//! ([`crate::detector::OnlineQuadFormer`]).

mod build;
mod dense;
mod engine;
mod layout;

pub use engine::{StepOutput, StreamingNet};

#[cfg(test)]
mod tests;
