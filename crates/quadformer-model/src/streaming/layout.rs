//! The named slots of a row of the streaming engine's per-residue ring (module docs of
//! [`crate::streaming`], points 1, 6 and 7): what layer 1 and the refactored scores of layers 1
//! and 2 keep of each residue, side by side in one row so that a residue costs one product.
//!
//! A row is `[h⁰ | Q¹ | K¹ | V¹ | κ | β | low-rank blocks]`: layer 1's input and projections
//! (`d` each; `V¹` as its layer holds it, with `W_O` folded in for one head), then `κ` (`d`) and
//! `β` (1) of `Scores::RingKeys` when layer 2 uses them, then one block `[x G + B | x | Aᵀ]`
//! (`3m`) per head of `Scores::LowRank` when layer 1 uses it. Unused slots are empty ranges.

use std::ops::Range;

/// The slots of a ring row (module docs).
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct RingLayout {
    /// Layer 1's input `h⁰ = x W_e + b_e + PE`.
    pub(crate) h0: Range<usize>,
    /// Layer 1's queries `Q¹`.
    pub(crate) q: Range<usize>,
    /// Layer 1's keys `K¹`.
    pub(crate) k: Range<usize>,
    /// Layer 1's values `V¹` (times `W_O` with one head).
    pub(crate) v: Range<usize>,
    /// `κ = K¹ W_Qᵀ/√d` of layer 2's queries (`Scores::RingKeys`), or empty.
    pub(crate) kappa: Range<usize>,
    /// `β = K¹ b_Qᵀ/√d` (one column, `Scores::RingKeys`), or empty.
    pub(crate) beta: Range<usize>,
    /// The blocks of `Scores::LowRank`, one per head, or empty.
    pub(crate) low_rank: Range<usize>,
    /// Residue channels `m`: a low-rank block is `3m` wide.
    m: usize,
}

impl RingLayout {
    /// The layout for `d_model` = `d`, `m` channels, with `[κ | β]` when `ring_keys` and
    /// `low_rank_heads` low-rank blocks.
    pub(crate) fn new(d: usize, m: usize, ring_keys: bool, low_rank_heads: Option<usize>) -> Self {
        let mut end = 0;
        let mut slot = |width: usize| {
            let r = end..end + width;
            end += width;
            r
        };
        let (h0, q, k, v) = (slot(d), slot(d), slot(d), slot(d));
        let kappa = slot(if ring_keys { d } else { 0 });
        let beta = slot(usize::from(ring_keys));
        let low_rank = slot(low_rank_heads.map_or(0, |heads| heads * 3 * m));
        Self { h0, q, k, v, kappa, beta, low_rank, m }
    }

    /// Width of a row.
    pub(crate) fn width(&self) -> usize {
        self.low_rank.end
    }

    /// Head `hd`'s low-rank block `[x G + B | x | Aᵀ]`, `3m` wide.
    pub(crate) fn low_rank_block(&self, hd: usize) -> Range<usize> {
        let start = self.low_rank.start + hd * 3 * self.m;
        start..start + 3 * self.m
    }

    /// The query side `[x G + B | x]` of head `hd`'s block, `2m` wide.
    pub(crate) fn low_rank_query(&self, hd: usize) -> Range<usize> {
        let b = self.low_rank_block(hd);
        b.start..b.start + 2 * self.m
    }

    /// The key side `[x | Aᵀ]` of head `hd`'s block, `2m` wide.
    pub(crate) fn low_rank_key(&self, hd: usize) -> Range<usize> {
        let b = self.low_rank_block(hd);
        b.start + self.m..b.end
    }

    /// Every slot with its name, in row order.
    #[cfg(test)]
    pub(crate) fn slots(&self) -> [(&'static str, Range<usize>); 7] {
        [
            ("h0", self.h0.clone()),
            ("q", self.q.clone()),
            ("k", self.k.clone()),
            ("v", self.v.clone()),
            ("kappa", self.kappa.clone()),
            ("beta", self.beta.clone()),
            ("low_rank", self.low_rank.clone()),
        ]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Consecutive ranges from 0 to `width`, with no gap or overlap.
    fn tiles(ranges: impl IntoIterator<Item = Range<usize>>, from: usize, to: usize) -> bool {
        let mut at = from;
        for r in ranges {
            if r.start != at || r.end < r.start {
                return false;
            }
            at = r.end;
        }
        at == to
    }

    #[test]
    fn the_slots_tile_the_row() {
        for (d, m, ring_keys, heads) in [
            (64, 6, true, Some(1)),
            (64, 6, false, Some(2)),
            (16, 3, true, None),
            (16, 3, false, None),
            (8, 1, false, Some(4)),
        ] {
            let layout = RingLayout::new(d, m, ring_keys, heads);
            let case = format!("d {d}, m {m}, ring keys {ring_keys}, low-rank heads {heads:?}");
            assert!(tiles(layout.slots().map(|(_, r)| r), 0, layout.width()), "{case}: {layout:?}");
            for (name, r) in [("h0", &layout.h0), ("q", &layout.q), ("k", &layout.k), ("v", &layout.v)] {
                assert_eq!(r.len(), d, "{case}: {name}");
            }
            assert_eq!(layout.kappa.len(), if ring_keys { d } else { 0 }, "{case}");
            assert_eq!(layout.beta.len(), usize::from(ring_keys), "{case}");
            let n = heads.unwrap_or(0);
            assert!(tiles((0..n).map(|hd| layout.low_rank_block(hd)), layout.low_rank.start, layout.low_rank.end));
            for hd in 0..n {
                let (block, q, k) = (layout.low_rank_block(hd), layout.low_rank_query(hd), layout.low_rank_key(hd));
                assert_eq!((q.start, q.len(), k.end, k.len()), (block.start, 2 * m, block.end, 2 * m), "{case}");
            }
        }
    }
}
