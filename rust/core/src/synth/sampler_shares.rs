//! A long per-DN table kept in blocks of [`BLOCK`] DN, where an ISO's tables still pass their
//! budget after the exact layouts and the re-grid (issue 26 item 3): each block's cumulative
//! weight exactly as the per-DN table holds it (32 bits), and inside the block each value's
//! cumulative share of the block's mass on 16 bits. About 2.2 bytes per DN against 4.5 to 6.
//!
//! The drawn distribution is the per-DN table's with each value's cumulative weight inside its
//! block rounded to 1/65 535 of the block's mass: every value moves by at most that mass over
//! 65 535 (the rounding of its two ends), so the total variation distance to the per-DN table is
//! at most `(BLOCK − 1) / (2 · 65 535)` ≈ 1.1·10⁻⁴ whatever the PMF's shape (combs, piles,
//! steep edges), and a value the per-DN table never draws (no weight) is never drawn. The
//! blocks' ends are the per-DN table's own, so no mass crosses a block's edge.
//!
//! A draw `u` finds its block among the ends (the per-DN table's guide and walk, on blocks),
//! then the value whose cumulative weight `lo + ⌊m·S/65 535⌋` (`lo` the block's start, `m` its
//! mass, `S` the value's share) first exceeds `u`: the count of shares with `m·S < (u − lo +
//! 1)·65 535`, in integers.

use super::{BinTable, Guide};

/// Values per block.
pub(crate) const BLOCK: usize = 16;
/// A block's mass in share units.
const FULL: u64 = u16::MAX as u64;

/// A per-DN table kept as blocks of [`BLOCK`] values (module docs).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct ShareBlocks {
    /// The per-DN table's cumulative weight at each block's end, as a table over the blocks
    /// (block `b` is its value `b`).
    blocks: BinTable,
    /// Per block, the cumulative share of its mass (units of 1/65 535) at the end of each of its
    /// first `BLOCK − 1` values (65 535 past the table's last value).
    shares: Box<[u16]>,
    /// Values the table covers.
    len: usize,
}

impl ShareBlocks {
    /// The blocks of the per-DN table whose cumulative weights are `cdf` (units of 2⁻³², the last
    /// 2³²), and the total variation distance (units of 2⁻³²) between what they draw and what
    /// the per-DN table draws.
    pub(crate) fn of_cdf(cdf: &[u64]) -> (Self, u64) {
        let len = cdf.len();
        let ends: Vec<u64> = cdf.chunks(BLOCK).map(|c| c[c.len() - 1]).collect();
        let mut shares = Vec::with_capacity(ends.len() * (BLOCK - 1));
        let mut lo = 0u64;
        for (b, &hi) in ends.iter().enumerate() {
            let m = hi - lo;
            for j in 0..BLOCK - 1 {
                let s = match cdf.get(b * BLOCK + j) {
                    // Rounded to the nearest share: `m > 0` wherever a value of the block has
                    // weight; an empty block's shares are never read by a draw.
                    Some(&c) if m > 0 => ((2 * (c - lo) * FULL + m) / (2 * m)).min(FULL),
                    _ => FULL,
                };
                shares.push(s as u16);
            }
            lo = hi;
        }
        let blocks = BinTable::from_cdf(0, &ends, Guide::Dense);
        let out = Self { blocks, shares: shares.into(), len };
        let mut below = (0u64, 0u64);
        let twice: u64 = cdf
            .iter()
            .enumerate()
            .map(|(i, &c)| {
                let (e, s) = (c - below.0, out.cdf_at(i) - below.1);
                below = (c, out.cdf_at(i));
                e.abs_diff(s)
            })
            .sum();
        (out, twice.div_ceil(2))
    }

    /// Values the blocks cover.
    pub(crate) fn len(&self) -> usize {
        self.len
    }

    /// Bytes held (the blocks' table and the shares).
    pub(crate) fn heap_bytes(&self) -> usize {
        self.blocks.heap_bytes() + std::mem::size_of_val(&*self.shares)
    }

    /// Block `b`'s start and mass, units of 2⁻³².
    #[inline(always)]
    fn block(&self, b: usize) -> (u64, u64) {
        let lo = if b == 0 { 0 } else { self.blocks.cdf_at(b - 1) };
        (lo, self.blocks.cdf_at(b) - lo)
    }

    /// Cumulative weight up to value `i` (from the first), units of 2⁻³².
    pub(crate) fn cdf_at(&self, i: usize) -> u64 {
        let (b, j) = (i / BLOCK, i % BLOCK);
        if j == BLOCK - 1 {
            return self.blocks.cdf_at(b);
        }
        let (lo, m) = self.block(b);
        lo + m * u64::from(self.shares[b * (BLOCK - 1) + j]) / FULL
    }

    /// The value (from the first) a uniform 32-bit draw maps to.
    #[inline]
    pub(crate) fn sample_u32(&self, u: u32) -> usize {
        let b = (self.blocks.sample_u32(u) - self.blocks.first()) as usize;
        let (lo, m) = self.block(b);
        let t = (u64::from(u) - lo + 1) * FULL;
        let s = &self.shares[b * (BLOCK - 1)..(b + 1) * (BLOCK - 1)];
        b * BLOCK + s.iter().map(|&x| usize::from(m * u64::from(x) < t)).sum::<usize>()
    }
}
