//! The inverse CDF of a bin kept on a coarse grid, drawn from its cells instead of one entry per
//! DN: the same draw for every `u`, in 8 bytes per cell of `k` DN.
//!
//! A bin a pack keeps on a coarse grid ([`crate::model::coarse_grid`]) has the weights of
//! [`expand`](crate::model::coarse_grid::expand) of its cell masses: inside cell `j` (mass `m`,
//! `k` DN) the weight up to its `n`-th DN is `⌊m · cum(n) / ((a + b)·k²)⌋` with `cum(n) = a·(2kn −
//! n²) + b·n²`, `a` and `b` the shape's densities at the cell's edges (sums of neighbouring masses
//! to 40 significant bits; `a = b = 1` where both are 0, the even split). So the cumulative weight
//! at every DN follows from the cells' cumulative masses alone. The per-DN table
//! ([`super::BinTable`]) draws `u` to the first DN whose cumulative weight `acc` has `⌊acc ·
//! 2³² / T⌋ > u` (`T` the total), that is `acc ≥ ⌈(u + 1) · T / 2³²⌉`: here that threshold is
//! found among the cells' ends (a guide, then a walk), then within the cell by the quadratic's
//! root and an exact integer check of its neighbours.

use super::Guide;
use crate::model::coarse_grid::{cell_masses_at, expand, is_expansion};

/// Cells of a bin on a coarse grid of `k` DN, as [`super::BinTable`] draws them.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct CoarseCells {
    /// DN per cell.
    k: u32,
    /// Mass bits dropped to read the shape ([`crate::model::coarse_grid::expand`]'s).
    shift: u32,
    /// Total weight `T`.
    total: u64,
    /// Cumulative weight at each cell's end (the last is `T`).
    ends: Box<[u64]>,
    /// Per range of draws `g << guide_bits_dropped ..`, the first cell that can hold one.
    guide: Box<[u16]>,
    /// Draw bits dropped to index the guide.
    guide_shift: u32,
}

impl CoarseCells {
    /// The cells of weights `w` that are the re-expansion of their cells of `k > 1` DN (a bin's
    /// [`BinModel::grid_step`](crate::model::pack::BinModel::grid_step), which the pack decoder
    /// knows: not looked for here), with a total below 2⁶⁴ and at most 2¹⁶ cells, and the guide
    /// `guide` ([`Self::with_guide`]); `None` otherwise (`k` of 1 or less, a length not a multiple
    /// of `k`).
    pub(crate) fn at(w: &[u64], k: usize, guide: Guide) -> Option<Self> {
        if k <= 1 || !w.len().is_multiple_of(k) {
            return None;
        }
        debug_assert!(is_expansion(w, k), "weights said to be on a grid of {k} DN are not its re-expansion");
        let mut ends = Vec::with_capacity(w.len() / k);
        let mut acc = 0u64;
        for c in w.chunks(k) {
            for &x in c {
                acc = acc.checked_add(x)?;
            }
            ends.push(acc);
        }
        Self::from_ends(ends, k, guide)
    }

    /// The cells of `k` DN holding the masses of weights `w` over `first ..` on the grid whose
    /// edges lie at `origin + j·k` ([`cell_masses_at`]), the first DN of their first cell, and
    /// the total variation distance, in units of 2⁻³², between what they draw (the per-DN table
    /// of the masses' re-expansion, [`expand`]) and what the per-DN table of `w` draws (`cdf`, its
    /// cumulative weights). `None` where cells cannot hold them (more than 2¹⁶ cells, a total
    /// past 2⁶⁴, no mass).
    pub(crate) fn regridded(first: i32, w: &[u64], cdf: &[u64], k: usize, origin: i32) -> Option<(i32, Self, u64)> {
        let (start, masses) = cell_masses_at(first, w, k, origin);
        let mut acc = 0u64;
        let ends = masses
            .iter()
            .map(|&m| {
                acc = acc.checked_add(m)?;
                Some(acc)
            })
            .collect::<Option<Vec<u64>>>()?;
        if acc != w.iter().try_fold(0u64, |a, &x| a.checked_add(x))? {
            return None;
        }
        let cells = Self::from_ends(ends, k, Guide::Dense)?;
        let grid = super::cdf_of(&expand(&masses, k));
        let lead = (first - start) as usize;
        let exact = |i: usize| match i.checked_sub(lead) {
            Some(0) => cdf[0],
            Some(j) if j < cdf.len() => cdf[j] - cdf[j - 1],
            _ => 0,
        };
        let mut below = 0u64;
        let twice: u64 =
            grid.iter().enumerate().map(|(i, &c)| exact(i).abs_diff(c - std::mem::replace(&mut below, c))).sum();
        Some((start, cells, twice.div_ceil(2)))
    }

    /// The cells whose cumulative masses are `ends` (`k` DN each): they draw what the per-DN table
    /// of `expand(masses, k)` draws. `None` for no mass or more than 2¹⁶ cells.
    fn from_ends(ends: Vec<u64>, k: usize, guide: Guide) -> Option<Self> {
        let acc = ends.last().copied().unwrap_or(0);
        if acc == 0 || ends.len() > 1 << 16 {
            return None;
        }
        let top = ends.iter().scan(0u64, |s, &e| Some(e - std::mem::replace(s, e))).max().unwrap_or(0);
        let shift = (64 - top.leading_zeros()).saturating_sub(40);
        let cells = Self { k: k as u32, shift, total: acc, ends: ends.into(), guide: Box::new([]), guide_shift: 32 };
        Some(cells.with_guide(guide))
    }

    /// The same cells with a guide of one cell per cell ([`Guide::Dense`]: 2 to 4 bytes per cell
    /// of 8 bytes) or one per four cells ([`Guide::Sparse`]: a quarter of that, the walk from the
    /// guide's cell up to four cells longer). Every draw is the same.
    pub(crate) fn with_guide(mut self, guide: Guide) -> Self {
        let less = match guide {
            Guide::Dense => 0,
            Guide::Sparse => 2,
        };
        let bits = (self.ends.len().next_power_of_two().trailing_zeros().saturating_sub(less)).clamp(3, 12);
        self.guide_shift = 32 - bits;
        let mut j = 0usize;
        let guide: Box<[u16]> = (0..1u64 << bits)
            .map(|g| {
                let t = self.threshold((g << self.guide_shift) as u32);
                while self.ends[j] < t {
                    j += 1;
                }
                j as u16
            })
            .collect();
        self.guide = guide;
        self
    }

    /// [`Self::heap_bytes`] with the guide `guide` ([`Self::with_guide`]).
    pub(crate) fn heap_bytes_with(&self, guide: Guide) -> usize {
        std::mem::size_of_val(&*self.ends) + self.guide_bytes(guide)
    }

    /// Bytes the guide `guide` would take ([`Self::with_guide`]).
    fn guide_bytes(&self, guide: Guide) -> usize {
        let less = match guide {
            Guide::Dense => 0,
            Guide::Sparse => 2,
        };
        2 << (self.ends.len().next_power_of_two().trailing_zeros().saturating_sub(less)).clamp(3, 12)
    }

    /// Entries (DN) the cells cover.
    pub(crate) fn len(&self) -> usize {
        self.ends.len() * self.k as usize
    }

    /// Bytes held (cell ends and guide).
    pub(crate) fn heap_bytes(&self) -> usize {
        std::mem::size_of_val(&*self.ends) + std::mem::size_of_val(&*self.guide)
    }

    /// The least cumulative weight a draw `u` reaches: `⌈(u + 1) · T / 2³²⌉`.
    #[inline(always)]
    fn threshold(&self, u: u32) -> u64 {
        ((((u as u128) + 1) * self.total as u128 + (u32::MAX as u128)) >> 32) as u64
    }

    #[inline(always)]
    fn start(&self, j: usize) -> u64 {
        if j == 0 { 0 } else { self.ends[j - 1] }
    }

    /// Mass of cell `j` (0 beyond the ends), to the shape's bits.
    #[inline(always)]
    fn shape_mass(&self, j: isize) -> u64 {
        if j < 0 || j as usize >= self.ends.len() {
            return 0;
        }
        let j = j as usize;
        (self.ends[j] - self.start(j)) >> self.shift
    }

    /// Cell `j`'s mass `m`, edge densities `a`, `b` and `whole = (a + b)·k²`.
    #[inline(always)]
    fn cell(&self, j: usize) -> (u64, u64, u64, u64) {
        let m = self.ends[j] - self.start(j);
        let at = self.shape_mass(j as isize);
        let (mut a, mut b) = (self.shape_mass(j as isize - 1) + at, at + self.shape_mass(j as isize + 1));
        if a == 0 && b == 0 {
            (a, b) = (1, 1);
        }
        let k = self.k as u64;
        (m, a, b, (a + b) * k * k)
    }

    /// `cum(n) = a·(2kn − n²) + b·n²` (below 2⁵⁶: `a + b < 2⁴²`, `k ≤ 128`).
    #[inline(always)]
    fn cum(&self, a: u64, b: u64, n: u64) -> u64 {
        let k = self.k as u64;
        a * (2 * k * n - n * n) + b * n * n
    }

    /// Cumulative weight up to DN `i` (from the first), as the per-DN table's.
    pub(crate) fn acc_at(&self, i: usize) -> u64 {
        let (j, n) = (i / self.k as usize, (i % self.k as usize) as u64 + 1);
        let (m, a, b, whole) = self.cell(j);
        self.start(j) + ((m as u128 * self.cum(a, b, n) as u128) / whole as u128) as u64
    }

    /// Cumulative weight up to DN `i` in units of 2⁻³², `⌊acc · 2³² / T⌋`.
    pub(crate) fn cdf_at(&self, i: usize) -> u64 {
        (((self.acc_at(i) as u128) << 32) / self.total as u128) as u64
    }

    /// The DN (from the first) a uniform 32-bit draw maps to.
    #[inline]
    pub(crate) fn sample_u32(&self, u: u32) -> usize {
        let t = self.threshold(u);
        let mut j = self.guide[(u >> self.guide_shift) as usize] as usize;
        while self.ends[j] < t {
            j += 1;
        }
        // Within cell j: the least n in 1..=k with ⌊m·cum(n)/whole⌋ ≥ r, i.e. m·cum(n) ≥ r·whole.
        let r = t - self.start(j);
        let (m, a, b, whole) = self.cell(j);
        let k = self.k as u64;
        let reaches = |n: u64| m as u128 * self.cum(a, b, n) as u128 >= r as u128 * whole as u128;
        // The root of (b − a)x² + 2a·x = (a + b)·ρ (x = n/k, ρ = r/m), in its stable form.
        let (af, bf) = (a as f64, b as f64);
        let rho = r as f64 / m as f64;
        let x = (af + bf) * rho / (af + (af * af + (bf * bf - af * af) * rho).max(0.0).sqrt());
        let mut n = ((x * k as f64).ceil() as u64).clamp(1, k);
        while n > 1 && reaches(n - 1) {
            n -= 1;
        }
        while !reaches(n) {
            n += 1;
        }
        j * self.k as usize + n as usize - 1
    }
}
