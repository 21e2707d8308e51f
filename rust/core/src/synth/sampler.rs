//! Per-bin inverse-CDF sampling with guide tables, built once per pack load.

use std::borrow::Cow;

use multiversion::multiversion;
use rand::Rng;
use rayon::prelude::*;

use crate::derive::fine_levels::{FineLevels, black_bin_one_level, position_fine_levels};
use crate::math::round::floor_i32;
use crate::model::coarse_grid::GRID_STEPS;
use crate::model::codes::Snap;
use crate::model::layout::{Binning, POSITIONS, lut_at_reference_levels, reference_level};
use crate::model::pack::{BinModel, IsoModel, ModelPack};
use crate::model::structure::{Components, IsoStructure};
use crate::synth::CleanAt;
use crate::synth::phase_tables::PhaseSet;
use crate::synth::saturated;
use crate::synth::structure::{FloorReach, StructureSampler};

#[path = "sampler_cells.rs"]
mod cells;
use cells::CoarseCells;
#[path = "sampler_alike.rs"]
mod alike;
#[path = "sampler_shares.rs"]
mod shares;
use shares::ShareBlocks;

const ONE: u64 = 1 << 32;
/// The bytes an ISO's tables are kept within where they fit with the sparse guide: the denser
/// guide ([`Guide::Dense`]) is not allowed to take them past it ([`Guide::for_tables`]).
pub const TABLE_BUDGET: usize = 4_000_000;
/// The most a table put on a coarse grid to keep its ISO within [`TABLE_BUDGET`] may move its
/// draws ([`BinTable::regridded`]): total variation distance to the per-DN table's, in units of
/// 2⁻³².
pub const REGRID_TV: u64 = 1 << 25;
/// Entries past the last of a table (copies of it), so that the walk can read four at a time.
const PAD: usize = 3;
/// The fewest entries a table kept in blocks has ([`BinTable::in_blocks`]): four blocks, about
/// 150 bytes against 300 per DN (a shorter one saves less than the blocks' fixed cost).
const MIN_BLOCKED: usize = 4 * shares::BLOCK;

/// Inverse-CDF table of one bin. The cumulative weights `P(n ≤ first + i)` in units of 2⁻³²
/// (the last exactly 2³²) are kept less one, in 32 bits (`cdf1[i] = cdf[i] − 1`: a draw `u`
/// passes entry `i` when `cdf[i] ≤ u`, that is `cdf1[i] < u`); entries before `lead` have a
/// cumulative weight of 0 and are never drawn (their stored value is not read). `lead +
/// (guide[g] << guide_shift)` is at most the first index whose cdf exceeds `g / G`: the search
/// starts there. 4.5 to 5 bytes per entry with the guide, against 12 to 16 for 64-bit cumulative
/// weights and a 32-bit guide of two cells per entry; every draw maps to the same value.
#[derive(Debug, Clone, PartialEq)]
pub struct BinTable {
    first: i32,
    /// The entries, then [`PAD`] copies of the last (`u32::MAX`): the walk reads four at once.
    cdf1: Box<[u32]>,
    lead: u32,
    guide: Box<[u16]>,
    /// Draw bits dropped to index the guide.
    shift: u32,
    /// Index bits dropped in a guide cell (0 unless the table has more than 2¹⁶ entries).
    guide_shift: u32,
    /// A bin on a coarse grid drawn from its cells ([`Layout::Cells`]): then `cdf1` and `guide`
    /// are empty.
    cells: Option<Box<CoarseCells>>,
    /// A long table kept in blocks ([`BinTable::in_blocks`]): then `cdf1` and `guide` are empty.
    blocks: Option<Box<ShareBlocks>>,
}

/// How a table keeps its cumulative weights; every layout draws every `u` to the same value.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Layout {
    /// One 32-bit entry per DN, with a guide.
    Entries(Guide),
    /// A bin whose weights are a coarse grid's re-expansion (`model::coarse_grid::expand`; its
    /// [`BinModel::grid_step`], as the pack decoder read it) kept as its cells' cumulative masses, 8 bytes per cell of 2 to 128 DN: the weight at each DN
    /// is computed from them (a quadratic inside the cell) when a draw lands in the cell, and
    /// the draw is the per-DN table's. Other bins keep their entries with the guide given.
    Cells(Guide),
}

impl BinTable {
    pub fn new(bin: &BinModel) -> Self {
        Self::with_guide(bin, Guide::Sparse)
    }

    /// The table of `bin` with the guide `guide`.
    pub fn with_guide(bin: &BinModel, guide: Guide) -> Self {
        Self::from_cdf(bin.first, &cdf_of(&bin.counts), guide)
    }

    /// The table of `bin` in the layout `layout`.
    pub fn with_layout(bin: &BinModel, layout: Layout) -> Self {
        match layout {
            Layout::Entries(g) => Self::with_guide(bin, g),
            Layout::Cells(g) => match CoarseCells::at(&bin.counts, bin.grid_step as usize, Guide::Dense) {
                Some(c) => Self::of_cells(bin.first, c),
                None => Self::with_guide(bin, g),
            },
        }
    }

    /// The table of `bin` put on a coarse grid: its weights' masses in cells of the widest step
    /// of [`GRID_STEPS`] up to `widest` whose re-expansion draws within `bound` (total variation,
    /// units of 2⁻³²) of the per-DN table of `bin`, on the grid through `origin`, and like it at
    /// the draws a frame makes ([`alike::draws_alike`]: mean, variance, 0.1 % and 99.9 %
    /// quantiles); `None` where no step does.
    pub(crate) fn regridded(bin: &BinModel, widest: usize, origin: i32, bound: u64) -> Option<Self> {
        let cdf = cdf_of(&bin.counts);
        GRID_STEPS.iter().rev().filter(|&&k| k <= widest).find_map(|&k| {
            let (first, c, tv) = CoarseCells::regridded(bin.first, &bin.counts, &cdf, k, origin)?;
            let t = (tv <= bound).then(|| Self::of_cells(first, c))?;
            alike::draws_alike(bin.first, &cdf, t.first, &t.cdf()).then_some(t)
        })
    }

    /// The table of `bin` kept in blocks of [`shares::BLOCK`] DN, each value's cumulative weight
    /// inside its block on 16 bits ([`ShareBlocks`]), where its drawn distribution stays within
    /// `bound` (total variation, units of 2⁻³²) of the per-DN table's (it is within 1.1·10⁻⁴ by
    /// construction) and like it at the draws a frame makes ([`alike::draws_alike`]), and the
    /// table has at least [`MIN_BLOCKED`] entries (shorter ones save little); `None` otherwise.
    pub(crate) fn in_blocks(bin: &BinModel, bound: u64) -> Option<Self> {
        let cdf = cdf_of(&bin.counts);
        let (t, tv) = Self::of_blocks(bin.first, &cdf)?;
        (tv <= bound && alike::draws_alike(bin.first, &cdf, t.first, &t.cdf())).then_some(t)
    }

    /// The table of cumulative weights `cdf` over `first ..` kept in blocks, and the total
    /// variation (units of 2⁻³²) of its draws from the per-DN table's; `None` for a table shorter
    /// than [`MIN_BLOCKED`].
    fn of_blocks(first: i32, cdf: &[u64]) -> Option<(Self, u64)> {
        if cdf.len() < MIN_BLOCKED {
            return None;
        }
        let (blocks, tv) = ShareBlocks::of_cdf(cdf);
        Some((Self { blocks: Some(Box::new(blocks)), ..Self::without_entries(first) }, tv))
    }

    /// Whether the table is kept in blocks ([`Self::in_blocks`]).
    pub fn is_blocks(&self) -> bool {
        self.blocks.is_some()
    }

    /// A table drawn from cells with the cells' guide `guide` ([`CoarseCells::with_guide`]: the
    /// same draws); any other table as it is.
    fn with_cell_guide(mut self, guide: Guide) -> Self {
        self.cells = self.cells.map(|c| Box::new(c.with_guide(guide)));
        self
    }

    /// [`Self::heap_bytes`] with the cells' guide `guide` ([`Self::with_cell_guide`]).
    fn bytes_with_cell_guide(&self, guide: Guide) -> usize {
        match &self.cells {
            Some(c) => std::mem::size_of::<CoarseCells>() + c.heap_bytes_with(guide),
            None => self.heap_bytes(),
        }
    }

    fn of_cells(first: i32, cells: CoarseCells) -> Self {
        Self { cells: Some(Box::new(cells)), ..Self::without_entries(first) }
    }

    /// A table from `first` with no per-DN entries and no guide, for the cells or the blocks to fill.
    fn without_entries(first: i32) -> Self {
        Self {
            first,
            cdf1: Box::new([]),
            lead: 0,
            guide: Box::new([]),
            shift: 0,
            guide_shift: 0,
            cells: None,
            blocks: None,
        }
    }

    /// Whether the table draws from a coarse grid's cells ([`Layout::Cells`]).
    pub fn is_cells(&self) -> bool {
        self.cells.is_some()
    }

    pub fn from_weights(first: i32, w: &[u64]) -> Self {
        Self::from_cdf(first, &cdf_of(w), Guide::Sparse)
    }

    /// The table of cumulative weights `cdf` (units of 2⁻³², non-decreasing, the last 2³²).
    fn from_cdf(first: i32, cdf: &[u64], guide: Guide) -> Self {
        let lead = cdf.iter().take_while(|&&c| c == 0).count();
        let cdf1: Box<[u32]> =
            cdf.iter().map(|&c| c.wrapping_sub(1) as u32).chain(std::iter::repeat_n(u32::MAX, PAD)).collect();
        let bits = guide.bits(cdf.len());
        let g = 1usize << bits;
        let guide_shift = (usize::BITS - (cdf.len() - 1).leading_zeros()).saturating_sub(16);
        let mut guide = vec![0u16; g];
        let mut i = lead;
        for (k, cell) in guide.iter_mut().enumerate() {
            let threshold = (k as u64) << (32 - bits);
            while cdf[i] <= threshold {
                i += 1;
            }
            *cell = ((i - lead) >> guide_shift) as u16;
        }
        Self {
            first,
            cdf1,
            lead: lead as u32,
            guide: guide.into(),
            shift: 32 - bits,
            guide_shift,
            cells: None,
            blocks: None,
        }
    }

    /// Maps a uniform 32-bit draw to a noise value.
    #[inline(always)]
    pub fn sample_u32(&self, u: u32) -> i32 {
        if let Some(c) = &self.cells {
            return self.first + c.sample_u32(u) as i32;
        }
        if let Some(b) = &self.blocks {
            return self.first + b.sample_u32(u) as i32;
        }
        let mut i = self.lead as usize + ((self.guide[(u >> self.shift) as usize] as usize) << self.guide_shift);
        // Four entries at a time, without a branch inside: the cumulative weights rise, so the
        // count of those below the draw is the number of steps taken among them (the walk from
        // the guide's cell is 0 to 3 steps for most draws, and four independent loads and
        // compares cost less than a chain of dependent ones or a mispredicted exit). The last
        // entry (2³² − 1) and its padding stop every walk.
        loop {
            let four = &self.cdf1[i..i + PAD + 1];
            let steps = four.iter().map(|&c| (c < u) as usize).sum::<usize>();
            i += steps;
            if steps <= PAD {
                break;
            }
        }
        self.first + i as i32
    }

    #[inline]
    pub fn sample<R: Rng + ?Sized>(&self, rng: &mut R) -> i32 {
        self.sample_u32(rng.next_u32())
    }

    pub fn first(&self) -> i32 {
        self.first
    }

    /// Entries of the table (values `first .. first + len`).
    pub fn len(&self) -> usize {
        match (&self.cells, &self.blocks) {
            (Some(c), _) => c.len(),
            (None, Some(b)) => b.len(),
            (None, None) => self.cdf1.len() - PAD,
        }
    }

    /// Whether the table has no entry (never: a table draws at least one value).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The cumulative weight of entry `i`, in units of 2⁻³².
    #[inline]
    fn cdf_at(&self, i: usize) -> u64 {
        if let Some(c) = &self.cells {
            return c.cdf_at(i);
        }
        if let Some(b) = &self.blocks {
            return b.cdf_at(i);
        }
        if i < self.lead as usize { 0 } else { self.cdf1[i] as u64 + 1 }
    }

    /// The cumulative weights over `first ..`, in units of 2⁻³² (the last is 2³²): a draw `u`
    /// maps to `first + i` for the first `i` with `cdf[i] > u`, which is what exported tables
    /// (`searchsorted(cdf, u, right=True)`) reproduce.
    pub fn cdf(&self) -> Vec<u64> {
        (0..self.len()).map(|i| self.cdf_at(i)).collect()
    }

    /// Bytes the table holds (its entries and its guide).
    pub fn heap_bytes(&self) -> usize {
        std::mem::size_of_val(&*self.cdf1)
            + std::mem::size_of_val(&*self.guide)
            + self.cells.as_ref().map_or(0, |c| std::mem::size_of::<CoarseCells>() + c.heap_bytes())
            + self.blocks.as_ref().map_or(0, |b| std::mem::size_of::<ShareBlocks>() + b.heap_bytes())
    }

    /// Probability of value `n` as the table encodes it.
    pub fn prob(&self, n: i32) -> f64 {
        let i = n - self.first;
        if i < 0 || i as usize >= self.len() {
            return 0.0;
        }
        let i = i as usize;
        let lo = if i == 0 { 0 } else { self.cdf_at(i - 1) };
        (self.cdf_at(i) - lo) as f64 / ONE as f64
    }
}

/// Cumulative weights in units of 2⁻³², `⌊acc·2³²/total⌋` (the last exactly 2³²; one entry of
/// 2³² for no weight).
fn cdf_of(w: &[u64]) -> Vec<u64> {
    let total: u128 = w.iter().map(|&c| c as u128).sum();
    let mut cdf = Vec::with_capacity(w.len().max(1));
    if total > 0 && total <= u32::MAX as u128 {
        // The same quotients in 64 bits (acc · 2³² < 2⁶⁴): a 128-bit division per entry was
        // most of the sampler build. The running sums first, then their quotients by a product
        // and a correction ([`Quotients`]): no division, and a loop the compiler vectorises.
        let (total, mut acc) = (total as u64, 0u64);
        cdf.extend(w.iter().map(|&c| {
            acc += c;
            acc << 32
        }));
        Quotients::new(total).floor_all(&mut cdf);
    } else if total > 0 && total < 1 << 48 {
        // The same quotients by long division in base 2¹⁶ (each remainder times 2¹⁶ stays below
        // 2⁶⁴): three 64-bit divisions per entry instead of a call to the 128-bit one.
        let (total, mut acc) = (total as u64, 0u64);
        for &c in w {
            acc += c;
            let (q0, r) = (acc / total, acc % total);
            let (q1, r) = ((r << 16) / total, (r << 16) % total);
            let q2 = (r << 16) / total;
            cdf.push(q0 << 32 | q1 << 16 | q2);
        }
    } else {
        let mut acc: u128 = 0;
        for &c in w {
            acc += c as u128;
            let v = (acc * ONE as u128).checked_div(total).unwrap_or(ONE as u128);
            cdf.push(v as u64);
        }
    }
    if cdf.is_empty() {
        cdf.push(ONE);
    }
    if let Some(last) = cdf.last_mut() {
        *last = ONE;
    }
    cdf
}

/// `⌊n / d⌋` for many `n < 2⁶⁴` over one divisor `0 < d < 2³²` whose quotients stay within
/// `2³²` (a cumulative weight over the total, [`cdf_of`]), without a division: the product
/// `n · (1/d)` in `f64` is within `2³² · 2⁻⁵¹` of `n / d` (three roundings of at most 2⁻⁵³
/// each), so its truncation is the quotient or one off, and the remainder `n − q·d` (which
/// then lies in `[−d, 2d)`, exact in 64-bit wrapping arithmetic) says which.
struct Quotients {
    d: u64,
    inv: f64,
}

impl Quotients {
    fn new(d: u64) -> Self {
        debug_assert!(d > 0 && d <= u32::MAX as u64);
        Self { d, inv: 1.0 / d as f64 }
    }

    /// Replaces each `n` of `values` (each `n / d` at most `2³²`) by `⌊n / d⌋`.
    fn floor_all(&self, values: &mut [u64]) {
        floor_quotients(self.d, self.inv, values);
    }
}

#[multiversion(targets(
    "x86_64+avx512f+avx512dq+avx512vl+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3",
    "x86_64+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3"
))]
fn floor_quotients(d: u64, inv: f64, values: &mut [u64]) {
    for v in values.iter_mut() {
        let n = *v;
        let q = (n as f64 * inv) as u64;
        let r = n.wrapping_sub(q.wrapping_mul(d)) as i64;
        *v = q.wrapping_sub((r < 0) as u64).wrapping_add((r >= d as i64) as u64);
    }
}

/// How many guide cells a table has (8 … 4096 cells, 16 bits each): an inverse CDF maps a draw
/// to the same value whatever the guide size, so the guide is sized for speed and memory. The
/// search walks from the cell's start, within a cache line, four 32-bit entries at a time.
/// Measured on 12 MP frames: with the tables of 240 bins out of cache (demo ISO 3200), a quarter
/// cell per entry drew as fast as one or two cells per entry; within cache (one bin of phone14
/// ISO 1600) a cell per two entries drew about 15 % faster, at half a byte more per entry.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Guide {
    /// A cell per four entries (4.5 to 5 bytes per entry with the entries).
    Sparse,
    /// A cell per two entries (5 to 6 bytes per entry).
    Dense,
}

impl Guide {
    /// The guide of an ISO's tables of `lens` entries (one per table): the dense one unless it
    /// is what would take them past `budget` bytes ([`BinTable::heap_bytes`]), that is the
    /// sparse one only where the tables fit within it with the sparse guide and not with the
    /// dense one. Tables past it either way (a 14-bit sensor's high ISOs) take the dense guide:
    /// half a byte more per entry, the draws within cache about 15 % faster.
    pub fn for_tables(budget: usize, lens: impl IntoIterator<Item = usize>) -> Self {
        let (sparse, dense) = lens
            .into_iter()
            .fold((0, 0), |(s, d), n| (s + Guide::Sparse.table_bytes(n), d + Guide::Dense.table_bytes(n)));
        if sparse <= budget && dense > budget { Guide::Sparse } else { Guide::Dense }
    }

    /// [`BinTable::heap_bytes`] of a table of `len` entries (at least one) with this guide.
    pub fn table_bytes(self, len: usize) -> usize {
        let len = len.max(1);
        4 * (len + PAD) + 2 * (1usize << self.bits(len))
    }

    /// Guide bits (`log₂` of the cells) of a table of `len` entries.
    fn bits(self, len: usize) -> u32 {
        let extra = match self {
            Guide::Sparse => -2,
            Guide::Dense => -1,
        };
        (len.next_power_of_two().trailing_zeros() as i32 + extra).clamp(3, 12) as u32
    }
}

/// Samplers of every (position, bin) of one ISO, and the level → bin maps.
#[derive(Debug, Clone)]
pub struct IsoSampler {
    pub iso: u32,
    pub white: u16,
    pub binning: Binning,
    luts: [Vec<u16>; POSITIONS],
    tables: [Vec<BinTable>; POSITIONS],
    /// Per position, the move onto the codes the sensor writes (when it skips codes).
    snaps: [Option<Snap>; POSITIONS],
    /// Per position, the codes the sensor writes `[floor, ceiling]`.
    range: [[i32; 2]; POSITIONS],
    /// The row, column and frame offsets added on top (when the pack has significant ones and
    /// they were asked for); the tables then hold the PMFs with them taken out.
    structure: Option<StructureSampler>,
    /// Per position and table (as `tables`; missing at the end: none), the tables drawn at the
    /// phase of the pixel's structured offset where the table's PMF sits at the lattice's floor
    /// ([`StructureSampler::phase_sets`]).
    phases: [Vec<Option<PhaseSet>>; POSITIONS],
    /// For clean images at the target ISO's brightness ([`CleanAt::Target`]): per position and
    /// clean level, the bin of its reference level and the offset that takes the PMF's gain
    /// shift back out. `None`: the clean image is at the reference brightness, as the pack's
    /// bins are.
    target: Option<Box<TargetMap>>,
}

/// What a sampler for clean images at the target ISO's brightness adds to the bin lookup.
#[derive(Debug, Clone)]
struct TargetMap {
    /// Per position, clean level → bin of the reference level `black + (level − black)/g`.
    luts: [Vec<u16>; POSITIONS],
    /// Per position, clean level → offset in 2⁻³² DN added to the draw (dithered onto the
    /// integers with the structured components' offsets).
    shifts: [Vec<i64>; POSITIONS],
    gains: [f64; POSITIONS],
}

/// The noise value at or below which a sample of bin `i` at position `pos` lies at or past the
/// sensor's floor (`floor`, the lowest code it writes) for the bin's lowest clean level:
/// `floor − level`. Bin 0 holds every level below black too; its lowest is taken as black's
/// whole part (a clean level below black is a dark pixel's averaging error, a DN or two).
/// The pile is not known (`pile_known` false) for a bin wider than a quarter of its noise SD:
/// the cells of its pile range also hold the unclipped noise of its higher levels, in
/// proportion to the bin's width against the noise, and all of them would go to the floor. On
/// the demo at ISO 3200 (4 DN bins, SD 28 DN) that overshot the real pile by 7 %; on random
/// sensor 11 (16 DN bins, black 1–5 DN above the floor, SD of a few DN) it made the pack's
/// marginal JSD 0.00062 → 0.00065.
fn floor_noise(binning: &Binning, pos: usize, floor: u16, i: usize, bin: &BinModel) -> FloorReach {
    let (_, var) = bin.pmf().moments();
    let w = f64::from(binning.bin_width);
    let black = f64::from(binning.black[pos]);
    let lowest = match i {
        0 => floor_i32(black),
        _ => -floor_i32(-(black + (i as f64) * f64::from(binning.bin_width))),
    };
    FloorReach { noise: i32::from(floor) - lowest, pile_known: 16.0 * w * w <= var }
}

/// Fine levels `fine` of position `p` made from `model`'s own bins (pixel-only's tables), for a
/// sampler adding the structured components `st`: each table deconvolved as the bin it was made
/// from is ([`StructureSampler::deconvolved_tables`]), that bin read from `lut`, the sampler's
/// map of clean levels to bins before the fine levels are added (the reference levels' own, or
/// the target's at the target brightness), at the table's first level.
fn deconvolved_fine_levels(
    st: &StructureSampler,
    binning: &Binning,
    model: &IsoModel,
    p: usize,
    lut: &[u16],
    mut fine: FineLevels,
) -> (FineLevels, Vec<Option<PhaseSet>>) {
    let own = &model.positions[p].bins;
    let floor = |i: usize| Some(floor_noise(binning, p, model.range[p][0], i, &own[i]));
    let first = |t: usize| fine.lut.iter().position(|&k| k as usize == own.len() + t);
    let source: Vec<usize> =
        (0..fine.extra.len()).map(|t| first(t).and_then(|l| lut.get(l)).map_or(0, |&b| b as usize)).collect();
    let deconvolved = st.deconvolved_tables(p, &fine.extra, own.len(), |t| source[t], floor);
    let phases = st.phase_sets(p, &fine.extra, &deconvolved, 0..deconvolved.len());
    fine.extra = deconvolved;
    (fine, phases)
}

/// The tables of an ISO's bins (per position, `sources`' bins then its extra tables), kept
/// within `budget` bytes where they can be, each step taken only where the ones before it leave
/// the tables past the budget:
/// 1. one entry per DN with the denser guide unless it takes them past the budget
///    ([`Guide::for_tables`]);
/// 2. the bins on a coarse grid drawn from their cells ([`Layout::Cells`]: the same draws), the
///    cells' guide a cell per cell, else a cell per four cells ([`CoarseCells::with_guide`]: the
///    same draws);
/// 3. every table with a grid in `grids` (per position and table, as `sources`; missing: none)
///    put on that grid, or a finer one, where its draws move by at most [`REGRID_TV`]
///    ([`BinTable::regridded`]);
/// 4. the tables still per DN kept in blocks ([`BinTable::in_blocks`], within [`REGRID_TV`] too,
///    by construction within 1.1·10⁻⁴);
///
/// the cells' guide the denser one where the tables fit with it, and the per-DN tables' guide
/// chosen within what the others leave.
fn tables_within(
    budget: usize,
    sources: &[(Cow<'_, [BinModel]>, Vec<BinModel>); POSITIONS],
    grids: &[Vec<Option<(usize, i32)>>; POSITIONS],
) -> [Vec<BinTable>; POSITIONS] {
    let all = || sources.iter().flat_map(|(bins, extra)| bins.iter().chain(extra));
    let entries: usize = all().map(|b| Guide::Sparse.table_bytes(b.counts.len())).sum();
    if entries <= budget {
        let guide = Guide::for_tables(budget, all().map(|b| b.counts.len()));
        return std::array::from_fn(|p| {
            let (bins, extra) = &sources[p];
            bins.par_iter().chain(extra.par_iter()).map(|b| BinTable::with_guide(b, guide)).collect()
        });
    }
    let mut cells: [Vec<Option<BinTable>>; POSITIONS] = std::array::from_fn(|p| {
        let (bins, extra) = &sources[p];
        bins.par_iter()
            .chain(extra.par_iter())
            .map(|b| Some(BinTable::with_layout(b, Layout::Cells(Guide::Dense))).filter(BinTable::is_cells))
            .collect()
    });
    // Whether the tables pass the budget with the cells' guide `g` and the others per DN with
    // the sparse guide.
    let over = |cells: &[Vec<Option<BinTable>>; POSITIONS], g: Guide| -> bool {
        let held: usize = cells.iter().flatten().flatten().map(|t| t.bytes_with_cell_guide(g)).sum();
        let rest: usize = all()
            .zip(cells.iter().flatten())
            .filter(|(_, c)| c.is_none())
            .map(|(b, _)| Guide::Sparse.table_bytes(b.counts.len()))
            .sum();
        held + rest > budget
    };
    // Step `make` for the tables still per DN (per position, the table's index and its source).
    let fill = |cells: &mut [Vec<Option<BinTable>>; POSITIONS],
                make: &(dyn Fn(usize, usize, &BinModel) -> Option<BinTable> + Sync)| {
        for (p, c) in cells.iter_mut().enumerate() {
            let (bins, extra) = &sources[p];
            let done = std::mem::take(c);
            *c = bins
                .par_iter()
                .chain(extra.par_iter())
                .zip(done.into_par_iter())
                .enumerate()
                .map(|(t, (b, c))| c.or_else(|| make(p, t, b)))
                .collect();
        }
    };
    if over(&cells, Guide::Sparse) {
        fill(&mut cells, &|p, t, b| {
            let (k, origin) = grids[p].get(t).copied().flatten()?;
            BinTable::regridded(b, k, origin, REGRID_TV)
        });
        if over(&cells, Guide::Sparse) {
            fill(&mut cells, &|_, _, b| BinTable::in_blocks(b, REGRID_TV));
        }
    }
    let cell_guide = if over(&cells, Guide::Dense) { Guide::Sparse } else { Guide::Dense };
    let held: usize = cells.iter().flatten().flatten().map(|t| t.bytes_with_cell_guide(cell_guide)).sum();
    let rest: Vec<usize> =
        all().zip(cells.iter().flatten()).filter(|(_, c)| c.is_none()).map(|(b, _)| b.counts.len()).collect();
    let guide = Guide::for_tables(budget.saturating_sub(held), rest);
    std::array::from_fn(|p| {
        let (bins, extra) = &sources[p];
        let done = std::mem::take(&mut cells[p]);
        bins.par_iter()
            .chain(extra.par_iter())
            .zip(done.into_par_iter())
            .map(|(b, c)| match c {
                Some(t) if cell_guide == Guide::Dense => t,
                Some(t) => t.with_cell_guide(cell_guide),
                None => BinTable::with_guide(b, guide),
            })
            .collect()
    })
}

/// One past the highest bin `lut` maps a level up to `top` to.
fn bins_up_to(lut: &[u16], top: u16) -> usize {
    lut.iter().take(top as usize + 1).map(|&b| b as usize + 1).max().unwrap_or(0)
}

impl IsoSampler {
    /// The sampler of a model with the structured components `structure` of its ISO handed in
    /// (the caller derives them: a pack's own, or derived from its calibrated ISOs, as
    /// the resolution step's `IsoSampler::with_components` does), of which `which` asks for those
    /// it adds; `None`, or `which` asking for none: the pixel-independent model alone.
    pub fn with_structure(
        pack: &ModelPack,
        model: &IsoModel,
        structure: Option<&IsoStructure>,
        which: Components,
    ) -> Self {
        Self::build(pack, model, structure, which, None, TABLE_BUDGET)
    }

    /// [`Self::with_structure`] with the ISO's tables kept within `budget` bytes instead of
    /// [`TABLE_BUDGET`] (`usize::MAX`: one entry per DN for every table, the exact draws): for
    /// measuring what the budget's layouts change.
    pub fn with_structure_within(
        pack: &ModelPack,
        model: &IsoModel,
        structure: Option<&IsoStructure>,
        which: Components,
        budget: usize,
    ) -> Self {
        Self::build(pack, model, structure, which, None, budget)
    }

    /// [`Self::with_structure`] for clean images whose levels are all at most `top` (a single
    /// image's, as `noisecal synth` of one file reads it before the build): the bins that hold
    /// no level up to `top` are not deconvolved, and their tables draw from the model's own
    /// bins. An image within `top` gets the same bytes as from [`Self::with_structure`]; a level
    /// above it would draw its noise with the structured offsets counted twice, so this is
    /// built only inside the type that refuses such images
    /// ([`crate::synth::sampler_up_to::SamplerUpTo`]).
    pub(crate) fn built_up_to(
        pack: &ModelPack,
        model: &IsoModel,
        structure: Option<&IsoStructure>,
        which: Components,
        top: u16,
    ) -> Self {
        Self::build(pack, model, structure, which, Some(top), TABLE_BUDGET)
    }

    /// [`Self::with_structure`], or [`Self::built_up_to`] with `top`.
    fn build(
        pack: &ModelPack,
        model: &IsoModel,
        structure: Option<&IsoStructure>,
        which: Components,
        top: Option<u16>,
        budget: usize,
    ) -> Self {
        let structure = structure.filter(|_| which.structured()).and_then(|st| StructureSampler::new(st, which));
        let binning = pack.binning();
        let mut luts: [Vec<u16>; POSITIONS] = std::array::from_fn(|p| binning.lut(p));
        let mut phases: [Vec<Option<PhaseSet>>; POSITIONS] = Default::default();
        let sources: [(Cow<'_, [BinModel]>, Vec<BinModel>); POSITIONS] = std::array::from_fn(|p| {
            let own = &model.positions[p].bins;
            // An estimated model's levels near black whose bin is too wide for the noise there
            // draw from the bin's PMF at the law's variance for their level (tables after the
            // bins'); plain histograms and parametric models keep one PMF per bin.
            let (bins, fine) = match &structure {
                Some(st) => {
                    let floor = |i: usize| Some(floor_noise(&binning, p, model.range[p][0], i, &own[i]));
                    // The bins that hold a level up to `top` (all of them without it).
                    let used = top.map_or(own.len(), |t| bins_up_to(&luts[p], t).min(own.len()));
                    let bins = st.deconvolved_at_floor_in(p, own, floor, 0..used);
                    // Black's bin, where it holds black's level alone, holds the fixed pattern too:
                    // its phase set is the one without the pattern, the shared one only where
                    // that has none (bin 0 is not drawn twice).
                    let black_alone = used > 0 && black_bin_one_level(&binning, p);
                    phases[p] = st.phase_sets(p, own, &bins, usize::from(black_alone)..used);
                    if black_alone {
                        phases[p][0] = st
                            .black_phase_set(p, &own[0], f64::from(binning.black[p]))
                            .or_else(|| st.phase_sets(p, own, &bins, 0..1).swap_remove(0));
                    }
                    // The fine levels of the model's own bins (pixel-only's tables), each table
                    // then deconvolved as the bin it was made from.
                    let fine = position_fine_levels(pack, model, p, own).map(|f| {
                        let (f, extra_phases) = deconvolved_fine_levels(st, &binning, model, p, &luts[p], f);
                        phases[p].extend(extra_phases);
                        f
                    });
                    (Cow::Owned(bins), fine)
                }
                None => (Cow::Borrowed(&own[..]), position_fine_levels(pack, model, p, own)),
            };
            let extra = fine.map_or_else(Vec::new, |f| {
                luts[p] = f.lut;
                f.extra
            });
            (bins, extra)
        });
        // A bin deconvolved from one the pack keeps on a coarse grid may be put back on it.
        let grids: [Vec<Option<(usize, i32)>>; POSITIONS] = std::array::from_fn(|p| {
            let own = &model.positions[p].bins;
            own.iter()
                .zip(sources[p].0.iter())
                .map(|(o, b)| (o.grid_step > 1 && b.grid_step <= 1).then_some((o.grid_step as usize, o.first)))
                .collect()
        });
        let mut tables = tables_within(budget, &sources, &grids);
        let white = pack.layout.white;
        // Clean levels at the reference's ceiling are saturated pixels: they read the ceiling.
        for (p, (lut, tabs)) in luts.iter_mut().zip(tables.iter_mut()).enumerate() {
            let k = tabs.len();
            if k > u16::MAX as usize {
                continue;
            }
            tabs.push(BinTable::new(&saturated::at_the_ceiling(white)));
            for l in lut.iter_mut().skip(saturated::saturated_from(pack, p) as usize) {
                *l = k as u16;
            }
        }
        let snaps = std::array::from_fn(|p| model.lattice[p].as_ref().map(|l| Snap::new(l, white)));
        let range = std::array::from_fn(|p| {
            let [f, c] = model.range[p];
            let c = c.min(white);
            [f.min(c) as i32, c as i32]
        });
        Self { iso: model.iso, white, binning, luts, tables, snaps, range, structure, phases, target: None }
    }

    /// The same sampler for clean images at the brightness `clean_at` says
    /// ([`CleanAt`]; method.md, *Synthesis*). [`CleanAt::Reference`] returns it unchanged (the
    /// pack's own convention, byte for byte). [`CleanAt::Target`]: a clean level `c` at position
    /// `p` stands for the reference level `x = black + (c − black)/g[p]` (clamped to
    /// `[0, white]`); the noise is drawn from the bin of `round(x)` and, when the tables carry
    /// the gain shift `(g − 1)·(x − black)` in their means (the calibrated and interpolated
    /// models; the parametric baselines are zero-mean), that shift is taken back out, dithered
    /// onto the integers: `noisy = c + n − (g − 1)·(x − black)`, which is
    /// `x + n` inside the range. `black` is the pack's, `gains` the ISO's gain ratios
    /// ([`IsoModel::gain_ratio`]; an interpolated ISO's are interpolated in log ISO) that pick
    /// the bin; `carried` the gain ratios the tables' means carry ([`carried_gain_ratio`]), whose
    /// shift `(carried − 1)·(x − black)` is taken out, or `None` for zero-mean tables.
    pub fn clean_at(
        mut self,
        clean_at: CleanAt,
        black: [f32; POSITIONS],
        gains: [f64; POSITIONS],
        carried: Option<[f64; POSITIONS]>,
    ) -> Result<Self, String> {
        if clean_at == CleanAt::Reference {
            self.target = None;
            return Ok(self);
        }
        let all = gains.iter().chain(carried.iter().flatten());
        if let Some((p, g)) = all.enumerate().find(|(_, g)| !(g.is_finite() && **g > 0.0)) {
            let p = p % POSITIONS;
            return Err(format!(
                "clean-at target: the gain ratio of ISO {} at CFA position {p} is {g}, not a positive number: \
                 recalibrate, or give the clean image at the reference brightness (clean-at reference)",
                self.iso
            ));
        }
        let luts = std::array::from_fn(|p| lut_at_reference_levels(&self.luts[p], black[p] as f64, gains[p]));
        let shifts = std::array::from_fn(|p| {
            let n = self.luts[p].len();
            let top = (n - 1) as f64;
            let (b, g) = (black[p] as f64, gains[p]);
            (0..n)
                .map(|c| {
                    let x = reference_level(c, b, g, top);
                    carried.map_or(0, |k| fixed(-(k[p] - 1.0) * (x - b)))
                })
                .collect()
        });
        self.target = Some(Box::new(TargetMap { luts, shifts, gains }));
        Ok(self)
    }

    /// For clean images at the target brightness: the levels near black whose bin is too wide
    /// draw from the tables `fine` holds per position for them, each at the variance of its own
    /// reference level rather than of that level rounded (`derive::fine_levels::target_fine_levels`
    /// of `model`'s own bins; its `lut` is indexed by the target's levels, its tables after the
    /// bins). With structured components each table is deconvolved as the bin it was made from,
    /// as at the reference brightness. Unchanged for a sampler at the reference brightness, and
    /// at a position whose tables would pass 16-bit indices.
    pub fn with_target_fine_levels(self, model: &IsoModel, fine: [Option<FineLevels>; POSITIONS]) -> Self {
        let Some(target) = self.target.as_ref() else {
            return self;
        };
        let mut phases: [Vec<Option<PhaseSet>>; POSITIONS] = Default::default();
        let fine = match &self.structure {
            Some(st) => {
                let mut fine = fine;
                for (p, f) in fine.iter_mut().enumerate() {
                    *f = f.take().map(|f| {
                        let (f, ph) = deconvolved_fine_levels(st, &self.binning, model, p, &target.luts[p], f);
                        phases[p] = ph;
                        f
                    });
                }
                fine
            }
            None => fine,
        };
        self.with_phased_level_tables(fine, phases)
    }

    /// The levels `fine` maps to tables of their own (indices at or past the position's bins)
    /// draw from those tables: added after the position's tables, in the map of the clean
    /// levels this sampler takes (the target's when it takes them at the target brightness, its
    /// `lut` then indexed by the target's levels). Used for the fine levels near black and for
    /// a parametric baseline's law at each level (`derive::baselines::Baseline::level_tables`).
    /// A position whose tables would pass 16-bit indices, or whose map has another length, is
    /// left as it is.
    pub fn with_level_tables(self, fine: [Option<FineLevels>; POSITIONS]) -> Self {
        self.with_phased_level_tables(fine, Default::default())
    }

    /// [`Self::with_level_tables`], the tables of `fine` drawn at the pixel's phase where
    /// `phases` (per position, per table of `fine`) has tables for them.
    fn with_phased_level_tables(
        mut self,
        fine: [Option<FineLevels>; POSITIONS],
        phases: [Vec<Option<PhaseSet>>; POSITIONS],
    ) -> Self {
        for (p, (f, ph)) in fine.into_iter().zip(phases).enumerate() {
            let Some(f) = f else { continue };
            let (bins, base) = (self.binning.bins(p), self.tables[p].len());
            let luts = match self.target.as_mut() {
                Some(t) => &mut t.luts[p],
                None => &mut self.luts[p],
            };
            if base + f.extra.len() > u16::MAX as usize + 1 || f.lut.len() != luts.len() {
                continue;
            }
            for (to, &k) in luts.iter_mut().zip(&f.lut) {
                if k as usize >= bins {
                    *to = (base + k as usize - bins) as u16;
                }
            }
            self.tables[p].extend(f.extra.iter().map(BinTable::new));
            if ph.iter().any(Option::is_some) {
                self.phases[p].resize(base, None);
                self.phases[p].extend(ph);
            }
        }
        self
    }

    /// Per table of a position (missing at the end: none), the tables drawn at the phase of the
    /// pixel's structured offset ([`StructureSampler::phase_sets`]).
    #[inline]
    pub fn phase_sets(&self, pos: usize) -> &[Option<PhaseSet>] {
        &self.phases[pos]
    }

    /// Which brightness this sampler takes clean images at.
    pub fn clean_at_mode(&self) -> CleanAt {
        if self.target.is_some() { CleanAt::Target } else { CleanAt::Reference }
    }

    /// The gain ratios a [`CleanAt::Target`] sampler divides clean levels by.
    pub fn target_gains(&self) -> Option<[f64; POSITIONS]> {
        self.target.as_ref().map(|t| t.gains)
    }

    /// Level → bin map and per-level offset (2⁻³² DN) of a position for clean images at the
    /// target brightness (`None` for a [`CleanAt::Reference`] sampler).
    #[inline]
    pub fn target_tables(&self, pos: usize) -> Option<(&[u16], &[i64])> {
        self.target.as_ref().map(|t| (t.luts[pos].as_slice(), t.shifts[pos].as_slice()))
    }

    /// The structured components this sampler adds, if any.
    pub fn structure(&self) -> Option<&StructureSampler> {
        self.structure.as_ref()
    }

    /// Sets the most bytes this sampler keeps of a fixed pattern between calls
    /// ([`StructureSampler::set_pattern_cache_bytes`]; 0: none, each image computes it row by
    /// row). Only time and memory change: the images are the same whatever the setting. Nothing
    /// to set when the sampler adds no fixed pattern.
    pub fn set_pattern_cache_bytes(&self, bytes: usize) {
        if let Some(st) = &self.structure {
            st.set_pattern_cache_bytes(bytes);
        }
    }

    /// Builder form of [`Self::set_pattern_cache_bytes`].
    pub fn with_pattern_cache_bytes(self, bytes: usize) -> Self {
        self.set_pattern_cache_bytes(bytes);
        self
    }

    /// The same sampler writing every code (no lattice).
    pub fn without_lattice(mut self) -> Self {
        self.snaps = std::array::from_fn(|_| None);
        self
    }

    /// Clamps a synthesized value to the codes the sensor writes at this position (its output
    /// range, `[0, white]` unless it piles up earlier) and moves it onto its lattice;
    /// `alternate` (alternating between neighbouring pixels of one colour) breaks ties between
    /// two codes.
    #[inline(always)]
    pub fn finish(&self, pos: usize, value: i32, alternate: bool) -> u16 {
        let [lo, hi] = self.range[pos];
        if value >= hi {
            return hi as u16;
        }
        if value <= lo {
            return lo as u16;
        }
        match &self.snaps[pos] {
            Some(s) => (s.apply(value as u16, alternate) as i32).clamp(lo, hi) as u16,
            None => value as u16,
        }
    }

    /// Whether synthesis at a position needs more than a clamp to `[0, white]`.
    pub fn needs_finish(&self, pos: usize) -> bool {
        self.snaps[pos].is_some() || self.range[pos] != [0, self.white as i32]
    }

    /// The codes the sensor writes at a position, `[floor, ceiling]`: synthesis clamps to it.
    pub fn range(&self, pos: usize) -> [i32; 2] {
        self.range[pos]
    }

    /// Whether a position snaps onto a lattice.
    pub fn has_lattice(&self, pos: usize) -> bool {
        self.snaps[pos].is_some()
    }

    /// The table for a clean level at a position.
    #[inline(always)]
    pub fn table(&self, pos: usize, level: u16) -> &BinTable {
        let l = (level as usize).min(self.luts[pos].len() - 1);
        &self.tables[pos][self.luts[pos][l] as usize]
    }

    /// Tables of a position: one per bin, then those of the levels near black whose bin is too
    /// wide for the noise there ([`crate::derive::fine_levels`]).
    pub fn tables(&self, pos: usize) -> &[BinTable] {
        &self.tables[pos]
    }

    /// Level → table map and tables of a position, for row loops.
    #[inline]
    pub fn position_tables(&self, pos: usize) -> (&[u16], &[BinTable]) {
        (&self.luts[pos], &self.tables[pos])
    }

    /// `clamp(level + n, 0, white)` with `n` drawn for (position, bin of level), moved onto the
    /// sensor's codes ([`Self::finish`]).
    #[inline(always)]
    pub fn noisy(&self, pos: usize, level: u16, u: u32, alternate: bool) -> u16 {
        let n = self.table(pos, level).sample_u32(u);
        self.finish(pos, level as i32 + n, alternate)
    }
}

/// The gain ratio per position that a model's PMF means carry, `mean ≈ (g − 1)·(level −
/// black)`: a calibrated model's measured [`IsoModel::gain_ratio`]; for a derived model, the
/// weighted (samples/σ²) regression through black of its bins' means on their levels, over the
/// filled bins whose noise stays clear (4 σ) of the output range. An interpolated ISO's means
/// take their gain part at its stated gain ratio ([`crate::derive::interp`]), so the two agree
/// within the means' own error (0.822–0.825 carried against 0.820–0.822 stated at ISO 400 on the
/// sensor of `tests/interp_gain.rs`); it is the carried one that a clean image at the target
/// brightness must have taken out.
pub fn carried_gain_ratio(pack: &ModelPack, model: &IsoModel) -> [f64; POSITIONS] {
    if model.is_calibrated() {
        return model.gain_ratio;
    }
    let binning = pack.binning();
    std::array::from_fn(|p| {
        let black = pack.layout.black[p] as f64;
        let [lo, hi] = model.range[p].map(|v| v as f64);
        let (mut num, mut den) = (0.0, 0.0);
        for (b, bin) in model.positions[p].bins.iter().enumerate() {
            let l = binning.center(p, b) as f64 - black;
            if !bin.filled() || l <= 0.0 {
                continue;
            }
            let (m, v) = bin.moments();
            let sd = v.max(0.0).sqrt();
            let out = black + l + m;
            if !(m.is_finite() && v.is_finite()) || out - 4.0 * sd <= lo || out + 4.0 * sd >= hi {
                continue;
            }
            let w = bin.samples.max(1) as f64 / v.max(1e-3);
            num += w * m * l;
            den += w * l * l;
        }
        if den > 0.0 { 1.0 + num / den } else { model.gain_ratio[p] }
    })
}

/// An offset in DN as a fixed-point number of 2⁻³² DN.
pub(crate) fn fixed(o: f64) -> i64 {
    (o * 4294967296.0).round() as i64
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// Each of `cdf_of`'s three ways (64-bit quotients, base-2¹⁶ long division, 128-bit
    /// division) gives `⌊acc·2³²/total⌋`, computed here in 128 bits, on weights whose totals
    /// fall in each range and at its edges.
    #[test]
    fn cdf_of_is_the_exact_quotient() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(4);
        let reference = |w: &[u64]| -> Vec<u64> {
            let total: u128 = w.iter().map(|&c| c as u128).sum();
            let mut acc = 0u128;
            let mut v: Vec<u64> = w
                .iter()
                .map(|&c| {
                    acc += c as u128;
                    (acc << 32).checked_div(total).unwrap_or(ONE as u128) as u64
                })
                .collect();
            *v.last_mut().unwrap() = ONE;
            v
        };
        let mut cases: Vec<Vec<u64>> = Vec::new();
        for bits in [20u32, 31, 32, 33, 40, 47, 48, 49, 60] {
            for len in [1usize, 2, 7, 300, 5000] {
                // Random weights whose total is near 2^bits.
                let each = ((1u128 << bits) / len as u128).max(1) as u64;
                cases.push((0..len).map(|_| rng.next_u64() % (2 * each)).collect());
            }
        }
        for total in [u32::MAX as u64, 1 << 32, (1 << 32) + 1, (1 << 48) - 1, 1 << 48] {
            let a = rng.next_u64() % total;
            cases.push(vec![a, 0, total - a]);
            cases.push(vec![1, total - 2, 1]);
        }
        for w in cases.iter().filter(|w| w.iter().any(|&c| c > 0)) {
            assert_eq!(cdf_of(w), reference(w), "weights totalling {}", w.iter().map(|&c| c as u128).sum::<u128>());
        }
    }

    /// The quotients by product and correction are `⌊n / d⌋` exactly: at every multiple of
    /// the divisor and one either side (where a truncated product one off would show), for
    /// divisors from 1 to `2³² − 1` and numerators up to `(2³² − 1)·2³²`, and on random ones.
    /// A bare truncated product (no correction) misses thousands of these.
    #[test]
    fn quotients_are_exact() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        let mut checked = 0usize;
        let divisors = [1u64, 2, 3, 7, 1000, 65_537, 1 << 30, (1 << 30) + 12_345, u32::MAX as u64 - 1, u32::MAX as u64];
        for &d in divisors.iter().chain(&(0..40).map(|_| 1 + rng.next_u64() % u32::MAX as u64).collect::<Vec<_>>()) {
            let mut ns: Vec<u64> = Vec::new();
            for _ in 0..300 {
                // A quotient up to 2³² (the cumulative weight at the total), n near q·d.
                let q = rng.next_u64() % ((1u64 << 32) + 1);
                let m = q as u128 * d as u128;
                for n in [m.wrapping_sub(1), m, m + 1, m + d as u128 - 1] {
                    if n < (1u128 << 64) && n / d as u128 <= 1 << 32 {
                        ns.push(n as u64);
                    }
                }
                ns.push((rng.next_u64() >> 1) % (d << 32).max(1));
            }
            let mut got = ns.clone();
            Quotients::new(d).floor_all(&mut got);
            for (n, g) in ns.iter().zip(&got) {
                assert_eq!(*g, n / d, "{n} / {d}");
                checked += 1;
            }
        }
        assert!(checked > 50_000, "{checked} quotients");
    }

    #[test]
    fn empirical_pmf_matches_table() {
        // A skewed, gappy PMF with a zero in the middle and a tiny tail.
        let w: Vec<u64> = vec![1, 0, 30, 500, 2000, 900, 0, 0, 60, 7, 1];
        let t = BinTable::from_weights(-4, &w);
        let total: u64 = w.iter().sum();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let n = 2_000_000usize;
        let mut counts = vec![0u64; w.len()];
        for _ in 0..n {
            let v = t.sample(&mut rng);
            counts[(v + 4) as usize] += 1;
        }
        // Chi-square against the PMF: 10 dof, p = 1e-4 critical value ≈ 35.6.
        let mut chi2 = 0.0;
        for (i, &c) in counts.iter().enumerate() {
            let e = w[i] as f64 / total as f64 * n as f64;
            if e > 0.0 {
                chi2 += (c as f64 - e).powi(2) / e;
            } else {
                assert_eq!(c, 0, "value {} has zero probability but was drawn", i as i32 - 4);
            }
        }
        assert!(chi2 < 35.6, "chi2 {chi2}");
        // An off-by-one table would shift the mean by 1: check the mean tightly.
        let mean: f64 = counts.iter().enumerate().map(|(i, &c)| (i as f64 - 4.0) * c as f64).sum::<f64>() / n as f64;
        let want: f64 = w.iter().enumerate().map(|(i, &c)| (i as f64 - 4.0) * c as f64).sum::<f64>() / total as f64;
        assert!((mean - want).abs() < 0.01, "{mean} vs {want}");
        assert!((t.prob(0) - 2000.0 / total as f64).abs() < 1e-9);
    }

    /// The compact table draws, for every 32-bit draw, the value of the plain inverse CDF
    /// (the first entry whose 2⁻³²-unit cumulative weight exceeds the draw): checked at every
    /// entry's boundary (±1) and on random draws, for PMFs with zero weights at the start, the end
    /// and inside, totals beyond 2³² and tables longer than a 16-bit guide can index.
    #[test]
    fn compact_table_draws_what_the_inverse_cdf_draws() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        let mut cases: Vec<Vec<u64>> = vec![
            vec![0, 0, 0, 5, 0, 3, 0, 0],
            vec![1],
            vec![0, 7],
            vec![u64::MAX / 4, 1, 0, u64::MAX / 4],
            (0..70_000).map(|i| (i % 7) as u64 * (i as u64 % 5)).collect(),
            (0..200_000).map(|i| if i < 150_000 { 0 } else { 1 + (i % 3) as u64 }).collect(),
        ];
        for len in [2usize, 9, 100, 1000, 5000] {
            // Gaussian-like bodies with long tails of tiny weights, as calibrated PMFs.
            let sd = len as f64 / 10.0;
            cases.push(
                (0..len)
                    .map(|i| {
                        let x = (i as f64 - len as f64 / 2.0) / sd;
                        (1e7 * (-0.5 * x * x).exp()) as u64 + rng.next_u32() as u64 % 3
                    })
                    .collect(),
            );
        }
        for w in &cases {
            let cdf = cdf_of(w);
            let t = BinTable::from_weights(-3, w);
            assert_eq!(t.cdf(), cdf, "stored cumulative weights");
            let reference = |u: u32| -3 + cdf.partition_point(|&c| c <= u as u64) as i32;
            let mut draws: Vec<u32> = vec![0, 1, u32::MAX, u32::MAX - 1];
            for &c in &cdf {
                for d in [c.wrapping_sub(1), c, c + 1] {
                    if d <= u32::MAX as u64 {
                        draws.push(d as u32);
                    }
                }
            }
            draws.extend((0..20_000).map(|_| rng.next_u32()));
            for u in draws {
                assert_eq!(t.sample_u32(u), reference(u), "draw {u} of a table of {} entries", w.len());
            }
        }
    }

    /// A table costs 4 bytes per entry plus its guide, half a byte to one byte per entry (16
    /// bytes for the smallest guide of 8 cells), and the walk's padding of 12 bytes: the layout
    /// that keeps the demo's ISO 3200 under 4 MB (the 64-bit layout took 16 bytes per entry).
    #[test]
    fn tables_take_at_most_five_bytes_per_entry() {
        for len in [1usize, 5, 33, 1000, 1514, 4096, 9000, 16000] {
            let w: Vec<u64> = (0..len).map(|i| 1 + (i % 13) as u64).collect();
            let t = BinTable::from_weights(0, &w);
            assert_eq!(t.len(), len);
            let budget = 5 * len + 16 + 4 * PAD;
            assert!(t.heap_bytes() <= budget, "{len} entries: {} bytes > {budget}", t.heap_bytes());
        }
    }

    /// The dense guide draws what the sparse one draws, for every boundary draw and random
    /// ones; [`Guide::table_bytes`] is what a table takes; the budget picks the sparse guide exactly
    /// where the tables fit within it with the sparse guide and not with the dense one.
    #[test]
    fn guides_draw_alike_and_the_budget_picks_one() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        let mut total = [0usize; 2];
        for len in [1usize, 2, 5, 33, 1000, 1514, 4096, 9000, 16000, 70_000] {
            let sd = len as f64 / 8.0;
            let counts: Vec<u64> = (0..len)
                .map(|i| {
                    let x = (i as f64 - len as f64 / 2.0) / sd;
                    (1e7 * (-0.5 * x * x).exp()) as u64 + u64::from(i % 5 == 0)
                })
                .collect();
            let source = crate::model::pack::BinSource::Measured;
            let bin = BinModel {
                first: -7,
                counts: counts.clone(),
                samples: 10,
                source,
                measured: None,
                clipped: false,
                grid_step: 0,
            };
            let (sparse, dense) = (BinTable::with_guide(&bin, Guide::Sparse), BinTable::with_guide(&bin, Guide::Dense));
            assert_eq!(sparse.heap_bytes(), Guide::Sparse.table_bytes(len), "{len} entries");
            assert_eq!(dense.heap_bytes(), Guide::Dense.table_bytes(len), "{len} entries");
            assert_eq!(sparse, BinTable::from_weights(-7, &counts));
            let mut draws: Vec<u32> = vec![0, 1, u32::MAX];
            for c in sparse.cdf() {
                draws.extend([c.wrapping_sub(1), c].iter().filter(|&&d| d <= u32::MAX as u64).map(|&d| d as u32));
            }
            draws.extend((0..20_000).map(|_| rng.next_u32()));
            for u in draws {
                assert_eq!(dense.sample_u32(u), sparse.sample_u32(u), "draw {u}, {len} entries");
            }
            total[0] += sparse.heap_bytes();
            total[1] += dense.heap_bytes();
        }
        assert!(total[1] > total[0], "the dense guide takes more bytes");
        let lens = [1usize, 2, 5, 33, 1000, 1514, 4096, 9000, 16000, 70_000];
        assert_eq!(Guide::for_tables(total[1], lens), Guide::Dense);
        assert_eq!(Guide::for_tables(total[1] - 1, lens), Guide::Sparse);
        assert_eq!(Guide::for_tables(total[0], lens), Guide::Sparse);
        assert_eq!(Guide::for_tables(total[0] - 1, lens), Guide::Dense, "past the budget either way");
    }

    #[test]
    fn extreme_draws_stay_in_support() {
        let t = BinTable::from_weights(10, &[3, 0, 5]);
        assert_eq!(t.sample_u32(0), 10);
        assert_eq!(t.sample_u32(u32::MAX), 12);
        let single = BinTable::from_weights(-2, &[9]);
        assert_eq!(single.sample_u32(u32::MAX), -2);
        assert_eq!(single.sample_u32(0), -2);
    }
}

#[cfg(test)]
#[path = "tests_sampler_cells.rs"]
mod tests_cells;

#[cfg(test)]
#[path = "tests_sampler_shares.rs"]
mod tests_shares;
