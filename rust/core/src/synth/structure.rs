//! Structured components at synthesis (method.md, "Structured noise"): per image one offset per
//! CFA position (the frame), per row and per column one offset, drawn from the pack's measured
//! distributions; every pixel gets `frame + row + column` on top of its own noise.
//!
//! Offsets are fractional; a pixel's code is not. A pixel adds `⌊o⌋ + [v < o − ⌊o⌋]` (`v`
//! uniform per pixel): its mean is exactly `o`, so row means carry the row offset, not a
//! rounded one. The pixel PMFs were measured on frames that already held these offsets, so
//! synthesis first takes them out: per position the PMF `K` of the added integer offset is
//! computed from the component distributions, and each bin's PMF `P` is replaced by the `Q ≥ 0`
//! with `Q ∗ K ≈ P` (non-negative deconvolution, [`crate::math::deconv`]). A pixel's
//! marginal stays the measured one and no variance is counted twice.

use std::sync::{Arc, OnceLock};

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::math::deconv::{Problem, SolverLimits, richardson_lucy};
use crate::math::round::{floor_i32, floor_i64, round_half_away, round_half_away_near};
use crate::model::layout::POSITIONS;
use crate::model::layout::position;
use crate::model::pack::BinModel;
use crate::model::pmf::Pmf;
use crate::model::structure::{
    Components, FixedPattern, FrameOffsets, IsoStructure, OffsetDistribution, grid_coord, quantile_at,
};
use crate::synth::pattern_cache::{PatternCache, PatternRegion, Region};
use crate::synth::pattern_lanes::{PATTERN_KEY, ParityColumns, lanes_apply, parity_row};
use crate::synth::phase_tables::{PhaseSet, phase_set, phase_set_less_held};

/// Grid of the offset densities (cells per DN).
const GRID: f64 = 32.0;
/// Below this share of a bin's variance, the offset kernel is taken out by narrowing alone (Eq.
/// 5–6): the shape error is second order in the share (the excess kurtosis of `Q ∗ K` comes out
/// `(1 − share)²` of the measured one), while Richardson–Lucy would cost `n · K` per iteration.
const RESCALE_ONLY: f64 = 0.1;
/// Richardson–Lucy iterations at most, and the work (`iterations · n · K`) per bin at most, `n`
/// the PMF's support less its negligible tails ([`TAIL_MASS`]).
const RL_ITERATIONS: usize = 200;
const RL_WORK: f64 = 4e6;
/// The mass each end of a PMF may hold beyond the support that sets the Richardson–Lucy
/// iteration count and the start's moments: the stored tail reaches out to cells of 2⁻²⁰ of the
/// largest (a cut that moves at most about 10⁻⁶ of the mass) or further, and the iterations and
/// the start, thus the synthesized noise, must not follow how far it reaches.
const TAIL_MASS: f64 = 1e-5;
/// Richardson–Lucy iterations at most for a clipped bin below [`RESCALE_ONLY`].
const CLIPPED_SMALL_SHARE_ITERATIONS: usize = 20;
/// How far (a fraction of the target) Richardson–Lucy's result may miss the variance it must
/// keep before it is rescaled to it ([`variance_kept`]).
const RL_VARIANCE_SLACK: f64 = 0.01;
/// The least mass an end cell of a clipped bin holds to be the clamp's pile (a floor count of
/// 1 is 2⁻³⁰ ≈ 10⁻⁹; a pile this small moves at most 10⁻⁶ of the bin's mass when folded).
const PILE_MIN: f64 = 1e-6;
/// RNG stream of the offsets (the pixel bands use streams `0 ..`, far below).
const STREAM: u64 = 1 << 62;

/// The components synthesis adds at one ISO.
#[derive(Debug, Clone)]
pub struct StructureSampler {
    rows: [Option<OffsetDistribution>; 2],
    columns: [Option<OffsetDistribution>; 2],
    frame: Option<FrameOffsets>,
    fpn: Option<FixedPattern>,
    /// Whether the vectorised loop computes the fixed pattern's rows ([`lanes_apply`]).
    lanes: bool,
    /// The fixed pattern of the image region last synthesized (shared by clones).
    pattern_cache: Arc<PatternCache>,
    /// Per position, [`Self::kernel`] and [`Self::pattern_dither`] once computed: they depend on
    /// the components alone, and a sampler's build asks for them four times per position (the
    /// bins, their phase tables, the fine levels, theirs).
    kernels: [OnceLock<PositionKernels>; POSITIONS],
}

/// A position's kernel ([`StructureSampler::kernel`]) and the fixed pattern's dither beyond it
/// ([`StructureSampler::pattern_dither`]).
#[derive(Debug, Clone)]
struct PositionKernels {
    kernel: (i32, Vec<f64>),
    pattern_dither: f64,
}

/// One image's offsets.
pub(crate) struct ImageOffsets {
    pub(crate) frame: [f64; POSITIONS],
    /// Per row of the image.
    pub(crate) rows: Vec<f64>,
    /// Per column of the image.
    pub(crate) columns: Vec<f64>,
}

impl StructureSampler {
    /// The significant components of `st` that `which` asks for; `None` when that leaves none.
    pub fn new(st: &IsoStructure, which: Components) -> Option<Self> {
        let fpn = st.fixed_pattern().filter(|_| which.fpn).cloned();
        let s = Self {
            rows: std::array::from_fn(|p| st.row(p).filter(|_| which.row).cloned()),
            columns: std::array::from_fn(|p| st.column(p).filter(|_| which.column).cloned()),
            frame: st.frame().filter(|_| which.frame).cloned(),
            lanes: fpn.as_ref().is_some_and(lanes_apply),
            fpn,
            pattern_cache: Arc::default(),
            kernels: Default::default(),
        };
        (s.rows.iter().chain(&s.columns).any(Option::is_some) || s.frame.is_some() || s.fpn.is_some()).then_some(s)
    }

    /// Whether a fixed pattern is added.
    pub fn has_pattern(&self) -> bool {
        self.fpn.is_some()
    }

    /// The most bytes the fixed pattern kept between calls may take ([`PatternCache`]).
    pub fn pattern_cache_bytes(&self) -> usize {
        self.pattern_cache.limit_bytes()
    }

    /// Sets the most bytes the fixed pattern kept between calls may take (0: nothing is kept,
    /// each image computes it row by row); the images are the same whatever the setting.
    pub fn set_pattern_cache_bytes(&self, bytes: usize) {
        self.pattern_cache.set_limit_bytes(bytes);
    }

    /// The fixed pattern at sensor pixel `(y, x)` (DN): its shading plus the residual's quantile
    /// at the pixel's own uniform draw (a hash of its position, the same in every image).
    #[inline]
    pub fn pattern_at(&self, y: usize, x: usize) -> f64 {
        let Some(fp) = &self.fpn else { return 0.0 };
        let p = position(y, x);
        fp.shading_at(p, y, x) + fp.pixels[p].at(pattern_unit(y, x))
    }

    /// Adds the fixed pattern of sensor row `y`, columns `x0 ..`, to `row` (2⁻³² DN): the values
    /// of [`Self::pattern_at`] (tested), the shading's vertical interpolation done once per row
    /// and position.
    #[cfg(test)]
    pub(crate) fn add_pattern_row(&self, y: usize, x0: usize, row: &mut [i64]) {
        self.add_pattern_row_at(&self.pattern_columns(x0, row.len()), y, row);
    }

    /// What the fixed pattern of an image's rows needs of its columns, `x0 .. x0 + w`, computed
    /// once per image instead of once per pixel: each column's shading cells.
    pub(crate) fn pattern_columns(&self, x0: usize, w: usize) -> PatternColumns {
        let (cells, line_len) = match &self.fpn {
            Some(fp) => {
                let gw = fp.grid[1] as usize;
                let cells = (x0..x0 + w)
                    .map(|x| {
                        let (c0, c1, f) = grid_coord(x, fp.size[1], gw);
                        (c0 as u32, c1 as u32, f)
                    })
                    .collect();
                (cells, gw.max(1))
            }
            None => (Vec::new(), 1),
        };
        let parity = std::array::from_fn(|p| match self.lanes {
            true => ParityColumns::new(cells.iter().skip(p).step_by(2).copied()),
            false => ParityColumns::default(),
        });
        PatternColumns { x0, cells, line_len, parity }
    }

    /// The fixed pattern of sensor row `y` over an image's columns ([`Self::pattern_columns`]),
    /// pixel by pixel as the synthesis pass reaches it ([`RowPattern::pair`]): the values of
    /// [`Self::add_pattern_row_at`], bit for bit (tested), without a row of them written first
    /// and read back. `None` without a fixed pattern.
    pub(crate) fn row_pattern<'a>(&'a self, columns: &'a PatternColumns, y: usize) -> Option<RowPattern<'a>> {
        self.row_pattern_in(columns, y, Default::default())
    }

    /// [`Self::row_pattern`], the row's values computed into `scratch` (one vector per column
    /// parity, of any length: resized, every value written), which [`RowPattern::into_scratch`]
    /// hands back for the next row: a band's rows then allocate and zero no buffer of their own.
    pub(crate) fn row_pattern_in<'a>(
        &'a self,
        columns: &'a PatternColumns,
        y: usize,
        mut scratch: [Vec<i64>; 2],
    ) -> Option<RowPattern<'a>> {
        let fp = self.fpn.as_ref()?;
        let parity = std::array::from_fn(|px| {
            let pos = position(y, columns.x0 + px);
            // A position without shading adds `0.0 + quantile`: a line of zeros gives the same
            // sum (`0·(1 − f) + 0·f` is +0 for the cells' `f` in [0, 1]).
            let line = fp.shading_line(pos, y).unwrap_or_else(|| vec![0.0; columns.line_len]);
            ParityPattern { line, q: fp.pixels[pos].quantiles.as_slice() }
        });
        // The whole row at once where the vectorised loop applies, per parity.
        let computed = self.lanes.then(|| {
            for (px, out) in scratch.iter_mut().enumerate() {
                let cols = &columns.parity[px];
                // Every value is written: the lanes apply, so the quantile function has two
                // points or more ([`lanes_apply`]).
                out.resize(cols.len(), 0);
                parity_row(y as u64, (columns.x0 + px) as u64, cols, &parity[px].line, parity[px].q, out);
            }
            scratch
        });
        Some(RowPattern { y, columns, parity, computed })
    }

    /// [`Self::add_pattern_row`] with the columns' shading cells computed beforehand
    /// ([`Self::pattern_columns`], for the same `x0` and width): the same values, bit for bit
    /// (the same expressions, only hoisted out of the rows).
    #[cfg(test)]
    pub(crate) fn add_pattern_row_at(&self, columns: &PatternColumns, y: usize, row: &mut [i64]) {
        let Some(fp) = &self.fpn else { return };
        let x0 = columns.x0;
        // Per column parity, the shading grid interpolated to this row, and the residual's
        // quantile function.
        for px in 0..2 {
            let x_first = x0 + px;
            let pos = position(y, x_first);
            let line = fp.shading_line(pos, y);
            let q = fp.pixels[pos].quantiles.as_slice();
            // The columns of this parity: `i` runs over `(x_first − x0) % 2 ..` in steps of two.
            let start = px;
            if start >= row.len() {
                continue;
            }
            let values = row[start..].iter_mut().step_by(2);
            let cells = columns.cells.get(start..).unwrap_or(&[]).iter().step_by(2);
            match &line {
                Some(l) => {
                    for (k, (v, &(c0, c1, f))) in values.zip(cells).enumerate() {
                        let x = x_first + 2 * k;
                        let shade = l[c0 as usize] * (1.0 - f) + l[c1 as usize] * f;
                        *v += round_half_away((shade + quantile_at(q, pattern_unit(y, x))) * 4294967296.0);
                    }
                }
                None => {
                    for (k, v) in values.enumerate() {
                        let x = x_first + 2 * k;
                        *v += round_half_away((0.0 + quantile_at(q, pattern_unit(y, x))) * 4294967296.0);
                    }
                }
            }
        }
    }

    /// The fixed pattern of an image at `origin`, `height × width`, when the sampler keeps it
    /// ([`PatternCache`]); `None`: computed pixel by pixel in the synthesis pass
    /// ([`Self::row_pattern`]).
    pub(crate) fn kept_pattern(
        &self,
        origin: (usize, usize),
        height: usize,
        width: usize,
    ) -> Option<Arc<PatternRegion>> {
        self.fpn.as_ref()?;
        self.pattern_cache.get(Region { origin, height, width }, || {
            let columns = self.pattern_columns(origin.1, width);
            move |y: usize, row: &mut [i64]| {
                if let Some(p) = self.row_pattern(&columns, y) {
                    row.iter_mut().enumerate().for_each(|(i, v)| *v += p.at(i));
                }
            }
        })
    }

    /// Draws an image's offsets (`origin`: the sensor row and column of its pixel (0, 0); only
    /// parities matter). Deterministic in the seed, whatever the thread count.
    pub(crate) fn draw(&self, seed: u64, h: usize, w: usize, origin: (usize, usize)) -> ImageOffsets {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(STREAM);
        let frame = match &self.frame {
            Some(f) => {
                let pick = rng.next_u64();
                let gauss = std::array::from_fn(|_| gaussian(&mut rng));
                f.draw(pick, gauss)
            }
            None => [0.0; POSITIONS],
        };
        let mut line = |n: usize, first: usize, d: &[Option<OffsetDistribution>; 2]| -> Vec<f64> {
            (0..n)
                .map(|i| match &d[(first + i) & 1] {
                    Some(d) => d.at(unit(rng.next_u64())),
                    None => 0.0,
                })
                .collect()
        };
        let rows = line(h, origin.0, &self.rows);
        let columns = line(w, origin.1, &self.columns);
        ImageOffsets { frame, rows, columns }
    }

    /// The PMF of the integer offset a pixel at `pos` gets: `⌊o⌋ + Bernoulli(o − ⌊o⌋)` with `o`
    /// the sum of its frame, row and column offsets. Returns `(first, pmf)`.
    pub fn kernel(&self, pos: usize) -> (i32, Vec<f64>) {
        self.kernels(pos).kernel.clone()
    }

    /// A position's kernel and pattern dither, computed on first use.
    fn kernels(&self, pos: usize) -> &PositionKernels {
        self.kernels[pos].get_or_init(|| PositionKernels {
            kernel: self.compute_kernel(pos),
            pattern_dither: self.compute_pattern_dither(pos),
        })
    }

    /// [`Self::kernel`], computed.
    fn compute_kernel(&self, pos: usize) -> (i32, Vec<f64>) {
        let mut dens = self.others_density(pos);
        // Of the fixed pattern, the pixel PMFs hold its change from the reference ISO's.
        if let Some(fp) = &self.fpn {
            dens = convolve(&dens, &quantile_density(&fp.in_pixel_noise[pos]));
        }
        dithered(dens)
    }

    /// The phase tables of black's bin `bin` at `pos` where that bin holds one level, black's
    /// code, and so the fixed pattern (`derive/fine_levels.rs`, [`black_bin_one_level`]; method.md,
    /// *Fixed pattern*, "Black's bin holds the pattern"): its samples (dark frames, the dimmest
    /// lit steps) sit at black's fraction `black − round(black)` plus each pixel's pattern, and
    /// are measured about their clean level rounded, which a pattern under a code does not move,
    /// so the PMF holds the pattern wrapped into black's code. It is drawn at the pixel's phase
    /// with that held pattern taken out of `Y` ([`phase_set_less_held`]) and the row, column and
    /// frame offsets out of the PMF (their kernel, not the pattern's change from the reference,
    /// which the whole pattern holds). `None` without a fixed pattern, for a clipped or empty
    /// bin: it is then drawn as before.
    ///
    /// [`black_bin_one_level`]: crate::derive::fine_levels::black_bin_one_level
    pub fn black_phase_set(&self, pos: usize, bin: &BinModel, black: f64) -> Option<PhaseSet> {
        let fp = self.fpn.as_ref()?;
        if bin.clipped || bin.counts.is_empty() || !black.is_finite() {
            return None;
        }
        let (k0, others) = dithered(self.others_density(pos));
        let q0 = match others.len() > 1 {
            true => deconvolve_bin_within(bin, k0, &others, RL_ITERATIONS, false, None).pmf(),
            false => bin.pmf(),
        };
        let f0 = black - round_half_away(black) as f64;
        let (c0, whole) = convolve(&quantile_density(&fp.pixels[pos]), &shading_density(fp, pos));
        // Each pattern value `o` as black's samples hold it: `f0 + o` wrapped into black's code.
        let held: Vec<(f64, f64)> = whole
            .iter()
            .enumerate()
            .filter(|(_, w)| **w > 0.0)
            .map(|(i, &w)| {
                let o = (c0 + i as i64) as f64 / GRID;
                let g = f0 + o;
                (g - floor_i64(g + 0.5) as f64 - f0, w)
            })
            .collect();
        phase_set_less_held(q0.first, &q0.p, &held)
    }
}

/// Dithers each grid point of an offset density onto the integers: the PMF `(first, pmf)` of
/// `⌊o⌋ + Bernoulli(o − ⌊o⌋)`.
fn dithered(dens: (i64, Vec<f64>)) -> (i32, Vec<f64>) {
    {
        let (first_cell, w) = dens;
        let lo = floor_i32((first_cell as f64) / GRID);
        let hi = floor_i32(((first_cell + w.len() as i64) as f64) / GRID) + 1;
        let mut out = vec![0.0; (hi - lo + 1) as usize];
        for (i, &p) in w.iter().enumerate() {
            let o = (first_cell + i as i64) as f64 / GRID;
            let fi = floor_i32(o);
            let f = fi as f64;
            let k = (fi - lo) as usize;
            out[k] += p * (1.0 - (o - f));
            out[k + 1] += p * (o - f);
        }
        let first = out.iter().position(|&p| p > 1e-12).unwrap_or(0);
        let last = out.iter().rposition(|&p| p > 1e-12).unwrap_or(first);
        let p: Vec<f64> = out[first..=last].to_vec();
        let t: f64 = p.iter().sum();
        (lo + first as i32, p.into_iter().map(|x| x / t).collect())
    }
}

impl StructureSampler {
    /// The dither variance (DN²) that adding the whole fixed pattern brings beyond what
    /// [`Self::kernel`] holds: `E[f(1 − f)]` of the whole added offset (pattern, rows, columns,
    /// frame) less that of the offset the kernel holds (the pattern's change from the reference
    /// and the other components), `f` the offset's fraction. 0 without a fixed pattern, and where
    /// the difference is negative (an offset density whose fractions crowd at ½ more than the
    /// whole one's; the kernel cannot be widened by a negative variance).
    ///
    /// The pixel PMFs hold the sensor's one rounding of signal, pattern and noise together;
    /// synthesis adds the pattern to whole codes by a dither, a second rounding the sensor never
    /// made. Of that second rounding the kernel counted only its own part's.
    pub fn pattern_dither(&self, pos: usize) -> f64 {
        self.kernels(pos).pattern_dither
    }

    /// [`Self::pattern_dither`], computed.
    fn compute_pattern_dither(&self, pos: usize) -> f64 {
        let Some(fp) = &self.fpn else { return 0.0 };
        let others = self.others_density(pos);
        let held = convolve(&others, &quantile_density(&fp.in_pixel_noise[pos]));
        let whole = convolve(&convolve(&others, &quantile_density(&fp.pixels[pos])), &shading_density(fp, pos));
        (dither_variance(&whole) - dither_variance(&held)).max(0.0)
    }

    /// The density of the row, column and frame offsets a pixel at `pos` gets (grid cells).
    fn others_density(&self, pos: usize) -> (i64, Vec<f64>) {
        let mut dens = (0i64, vec![1.0]);
        if let Some(d) = &self.rows[pos >> 1] {
            dens = convolve(&dens, &quantile_density(d));
        }
        if let Some(d) = &self.columns[pos & 1] {
            dens = convolve(&dens, &quantile_density(d));
        }
        if let Some(f) = &self.frame {
            dens = convolve(&dens, &frame_density(f, pos));
        }
        dens
    }

    /// The kernel the pixel PMFs are deconvolved by: [`Self::kernel`], and where a fixed pattern
    /// is added, convolved with `{−1: Δ/2, 0: 1 − Δ, +1: Δ/2}`, `Δ` the dither the whole pattern
    /// adds beyond it ([`Self::pattern_dither`]): a zero-mean integer noise of that variance, as
    /// the dither is (its error `⌊o⌋ + [v < f] − o` has mean 0 and variance `f(1 − f)`, within
    /// ±1). Without a fixed pattern it is [`Self::kernel`], bit for bit.
    pub fn narrowing_kernel(&self, pos: usize) -> (i32, Vec<f64>) {
        let (k0, kernel) = self.kernel(pos);
        let d = self.pattern_dither(pos);
        if d <= 0.0 {
            return (k0, kernel);
        }
        let three = [0.5 * d, 1.0 - d, 0.5 * d];
        let mut out = vec![0.0; kernel.len() + 2];
        crate::math::deconv::convolve_wide(&kernel, &three, &mut out);
        (k0 - 1, out)
    }

    /// A position's bins with the structured offsets, and the dither the fixed pattern brings,
    /// taken out of their PMFs (see the module docs; [`Self::narrowing_kernel`]). Clipped bins
    /// too narrow to deconvolve keep their shape (the pile moved past the clip); unclipped ones
    /// are narrowed by the kernel's variance where they hold more, else kept as they are.
    pub fn deconvolved(&self, pos: usize, bins: &[BinModel]) -> Vec<BinModel> {
        self.deconvolved_at_floor(pos, bins, |_| None)
    }

    /// [`Self::deconvolved`] where the sensor's output stops at a floor (its clamp near black):
    /// `floor_noise(i)` says where the floor lies for bin `i` ([`FloorReach`]; `None` where not
    /// known). Where its pile is known, the cells at or below the floor for the bin's lowest level
    /// are the clamp's pile, spread over as many cells as the bin pools levels; they are moved
    /// past the clip by the kernel's reach (`floor_pile_start`). Everywhere it is known, a PMF of
    /// a few cells whose low end lies above it has no pile there ([`clamp_end`]).
    pub fn deconvolved_at_floor(
        &self,
        pos: usize,
        bins: &[BinModel],
        floor_noise: impl Fn(usize) -> Option<FloorReach> + Sync,
    ) -> Vec<BinModel> {
        self.deconvolved_at_floor_in(pos, bins, floor_noise, 0..bins.len())
    }

    /// [`Self::deconvolved_at_floor`] for the bins of `range` alone; the others are returned as
    /// they are (for a sampler whose images hold no level of theirs: the work is skipped, the
    /// deconvolved bins of `range` are the same).
    pub(crate) fn deconvolved_at_floor_in(
        &self,
        pos: usize,
        bins: &[BinModel],
        floor_noise: impl Fn(usize) -> Option<FloorReach> + Sync,
        range: std::ops::Range<usize>,
    ) -> Vec<BinModel> {
        let (k0, kernel) = self.narrowing_kernel(pos);
        if kernel.len() <= 1 {
            return bins.to_vec();
        }
        let half = bins.len() / 2;
        bins.par_iter()
            .enumerate()
            .map(|(i, b)| {
                if !range.contains(&i) {
                    return b.clone();
                }
                let floor = if i < half { floor_noise(i) } else { None };
                deconvolve_bin_within(b, k0, &kernel, RL_ITERATIONS, i >= half, floor)
            })
            .collect()
    }

    /// Tables drawn instead of a bin's PMF at some of its levels (the fine levels near black,
    /// `derive/fine_levels.rs`, made from the model's own bins) deconvolved as that bin is
    /// ([`Self::deconvolved_at_floor_in`]): `source(t)` the bin table `t` was made from, of
    /// `bins` bins. So the default components draw what pixel-only draws there with the offsets
    /// taken out, as at every other level; made from the deconvolved bins instead, the fine
    /// levels' law was anchored at the dark frames' variance less what the first bin read lost
    /// to its deconvolution, then held at 1/6 DN² (EMVA set 002 at black: 0.135 DN² drawn
    /// where the bin deconvolved to 0.014, against pixel-only's 0.097).
    pub(crate) fn deconvolved_tables(
        &self,
        pos: usize,
        tables: &[BinModel],
        bins: usize,
        source: impl Fn(usize) -> usize + Sync,
        floor_noise: impl Fn(usize) -> Option<FloorReach> + Sync,
    ) -> Vec<BinModel> {
        let (k0, kernel) = self.narrowing_kernel(pos);
        if kernel.len() <= 1 {
            return tables.to_vec();
        }
        let half = bins / 2;
        tables
            .par_iter()
            .enumerate()
            .map(|(t, b)| {
                let i = source(t);
                let floor = if i < half { floor_noise(i) } else { None };
                deconvolve_bin_within(b, k0, &kernel, RL_ITERATIONS, i >= half, floor)
            })
            .collect()
    }
}

impl StructureSampler {
    /// Per table of `originals` (a position's bins, or its fine levels' tables made from them),
    /// the tables drawn at the phase of the pixel's offset ([`crate::synth::phase_tables`]) where
    /// the narrowing could not take the fixed pattern's dither out: `deconvolved[t]` (what
    /// [`Self::deconvolved_at_floor_in`] or [`Self::deconvolved_tables`] made of `originals[t]`)
    /// holds more than [`PHASE_GATE`] of the dither `Δ` ([`Self::pattern_dither`]) above its
    /// target, the measured variance less the narrowing kernel's. There the PMF sits at the
    /// lattice's floor `f(1 − f)`, and the dither would be drawn on top of it. The phase tables
    /// are made from the table deconvolved by the other components' kernel alone
    /// ([`Self::kernel`]), not the dither, which they draw by the pixel's own rounding. `None`
    /// everywhere else (a clipped table, none without a fixed pattern): those pixels draw as before,
    /// byte for byte. `range`: the tables to look at (the others get `None`).
    pub(crate) fn phase_sets(
        &self,
        pos: usize,
        originals: &[BinModel],
        deconvolved: &[BinModel],
        range: std::ops::Range<usize>,
    ) -> Vec<Option<PhaseSet>> {
        let delta = self.pattern_dither(pos);
        if delta <= 0.0 {
            return vec![None; originals.len()];
        }
        // The narrowing kernel is the held kernel convolved with the dither's three taps: their
        // variances add ([`Self::narrowing_kernel`]).
        let (h0, held) = self.kernel(pos);
        let kv = kernel_moments(h0, &held).1 + delta;
        originals
            .par_iter()
            .zip(deconvolved)
            .enumerate()
            .map(|(t, (b, d))| {
                if !range.contains(&t) || b.clipped || b.counts.is_empty() || d.counts.is_empty() {
                    return None;
                }
                let (_, pv) = b.pmf().moments();
                let (_, dv) = d.pmf().moments();
                if dv - (pv - kv) <= PHASE_GATE * delta {
                    return None;
                }
                let q0 = match held.len() > 1 {
                    true => deconvolve_bin_within(b, h0, &held, RL_ITERATIONS, false, None).pmf(),
                    false => b.pmf(),
                };
                phase_set(q0.first, &q0.p)
            })
            .collect()
    }
}

/// The share of the fixed pattern's dither a deconvolved table may hold above its target before
/// its pixels draw at their offset's phase instead ([`StructureSampler::phase_sets`]). Where the
/// narrowing works the excess is within the deconvolution's 1 % variance slack, far below.
const PHASE_GATE: f64 = 0.25;

/// Where the sensor's floor lies for one bin ([`StructureSampler::deconvolved_at_floor`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct FloorReach {
    /// The noise value at or below which the bin's cells lie at or past the floor for its
    /// lowest clean level (`floor − lowest level`); for its higher levels the floor lies lower.
    pub noise: i32,
    /// Whether the cells at or below `noise` are the clamp's pile alone: a bin narrow against
    /// its noise, whose cells there hold no unclipped noise of its higher levels.
    pub pile_known: bool,
}

/// `Q` with `Q ∗ K ≈ P` for one bin: `P`'s shape narrowed by `K`'s variance (Eq. 5–6 of the
/// paper, [`Pmf::rescaled_exact`]) as the start, then Richardson–Lucy. In a clipped bin the sensor's
/// clamp piled mass at one end of `P`; synthesis clamps after adding the offsets, so `Q ∗ K` is
/// folded onto that end the same way before it is compared with `P`.
#[cfg(test)]
fn deconvolve_bin(b: &BinModel, k0: i32, kernel: &[f64], upper: bool) -> BinModel {
    deconvolve_bin_within(b, k0, kernel, RL_ITERATIONS, upper, None)
}

/// [`deconvolve_bin`] with at most `max_iterations` Richardson–Lucy iterations.
/// `upper`: the bin lies in the upper half of the levels, so a clip it reached is white's.
/// `floor_noise`: the noise value at or below which the bin's cells lie at or past the sensor's
/// floor for its lowest clean level ([`StructureSampler::deconvolved_at_floor`]).
fn deconvolve_bin_within(
    b: &BinModel,
    k0: i32,
    kernel: &[f64],
    max_iterations: usize,
    upper: bool,
    floor_noise: Option<FloorReach>,
) -> BinModel {
    let pmf = b.pmf();
    let (km, kv) = kernel_moments(k0, kernel);
    // A clipped bin that reaches the floor: its pile is known by where the floor lies, not read
    // from its end cells, which a pile pooled over the bin's levels (each level piles at its own
    // `floor − level`) need not show ([`floor_pile_start`]).
    if b.clipped
        && let Some(f) = floor_noise.filter(|f| f.pile_known)
        && let Some(start) = floor_pile_start(&pmf, f.noise, k0, kernel.len(), km, kv)
    {
        return from_weights(b, start.first, &start.p);
    }
    // Which end holds the clamp's pile, if any ([`clamp_end`]): `Some(true)` the low end.
    let pile_end = clamp_end(b, &pmf, upper, floor_noise.map(|f| f.noise));
    // Too narrow to deconvolve (support within the kernel's length, or variance within its
    // variance): nothing to narrow, but a clamp's pile kept where it is would be smeared onto its
    // neighbour by the offsets. The demo at ISO 100 (bins of saturated pixels, 0.9995–1 of their
    // mass at white, row offsets of ±1 DN at 5.5 % each) put 5.6 % of them 1 DN below white. So
    // the pile still moves past the clip by the kernel's reach, as in a wider clipped bin.
    let kept = |pmf: &Pmf| match pile_end {
        Some(low) => {
            let start = clipped_start(pmf, low, k0, kernel.len(), km, kv);
            from_weights(b, start.first, &start.p)
        }
        None => b.clone(),
    };
    let (lo, hi) = core_span(&pmf.p);
    let core = hi - lo + 1;
    // The moments of the support less its negligible tails: a tail of 10⁻⁶ of the mass far out
    // would move the variance, thus the start, by as much as the iterations then fail to undo.
    let core_pmf = Pmf::from_weights(pmf.first + lo as i32, pmf.p[lo..=hi].iter().copied());
    let (pm, pv) = core_pmf.as_ref().map_or_else(|| pmf.moments(), |c| c.moments());
    let n = pmf.p.len();
    if core < kernel.len() + 2 || pv <= kv + 1.0 / 12.0 {
        // Too narrow for Richardson–Lucy, but an unclipped bin that holds more variance than
        // the kernel is still narrowed by it (Eq. 5–6): kept whole, it came out with `pv + kv`
        // (an 8-bit sensor at black, 0.16 DN² measured and 0.08 of the pattern's dither added).
        if pile_end.is_none() && pv > kv {
            let start = narrowed(&pmf, core_pmf.as_ref().unwrap_or(&pmf), pm - km, pv - kv);
            return from_weights(b, start.first, &start.p);
        }
        return kept(&pmf);
    }
    let start_only = kv < RESCALE_ONLY * pv;
    // Richardson–Lucy costs `n · K` per iteration: bounded per bin, so a wide bin with a long
    // kernel cannot stall the sampler build (the start is already close there). The bound counts
    // the support less its negligible tails, so the tails' reach does not set the iterations.
    // A clipped bin where the kernel is a small share of the variance starts close (the pile
    // past the clip, the rest narrowed) and needs few iterations to fit the cells next to the
    // clip: 20 leave a JSD near 10⁻⁵ on clipped Gaussians, far below a bin's sampling floor.
    let cap = if start_only { max_iterations.min(CLIPPED_SMALL_SHARE_ITERATIONS) } else { max_iterations };
    let iterations = (RL_WORK / (core * kernel.len()) as f64).min(cap as f64) as usize;
    // A bin whose samples reached a clip can have no pile at either end of its PMF (pooled
    // neighbours, whose clips sit elsewhere, leave floor-count tails past its own): such a bin
    // is deconvolved as an unclipped one, since there is nothing at an end to fold.
    let (low, high) = (pile_end == Some(true), pile_end == Some(false));
    // A clipped bin whose pile is spread over a few cells (its pixels' clean levels a few DN apart
    // below the clip) with pooled tails past it can have a tail's floor count read as a pile at
    // the other end, while most of its mass lies within the kernel's reach of this one; the
    // sensor's clamp holds that pile in place whatever offsets came before it
    // ([`spread_pile_start`]). Also applied to bins with no end pile at all, it moved the floor
    // piles of short PMFs near black the wrong way (random sensors 16 and 21: pack / plain 1.25
    // and 1.97), so only this misreading is taken.
    let taps = kernel.len().min(n);
    let total: f64 = pmf.p.iter().sum();
    let low_mass = pmf.p[..taps].iter().sum::<f64>() / total;
    let high_mass = pmf.p[n - taps..].iter().sum::<f64>() / total;
    let misread = (low && high_mass >= 0.5 && low_mass < 0.5) || (high && low_mass >= 0.5 && high_mass < 0.5);
    if b.clipped
        && misread
        && let Some(start) = spread_pile_start(&pmf, k0, kernel.len(), km, kv)
    {
        return from_weights(b, start.first, &start.p);
    }
    let clipped = low || high;
    let start = match clipped {
        false => narrowed(&pmf, core_pmf.as_ref().unwrap_or(&pmf), pm - km, pv - kv),
        true => clipped_start(&pmf, low, k0, kernel.len(), km, kv),
    };
    if (start_only && !clipped) || iterations < 10 {
        return from_weights(b, start.first, &start.p);
    }
    let ext = kernel.len();
    let (ext_lo, ext_hi) = (if low { ext } else { 0 }, if high { ext } else { 0 });
    let m = n - kernel.len() + 1 + ext_lo + ext_hi;
    let q_first = pmf.first - k0 - ext_lo as i32;
    let mut q: Vec<f64> = (0..m).map(|j| start.at(q_first + j as i32) + 1e-9).collect();
    let s: f64 = q.iter().sum();
    q.iter_mut().for_each(|x| *x /= s);
    let mut target = vec![0.0; ext_lo];
    target.extend_from_slice(&pmf.p);
    target.resize(ext_lo + n + ext_hi, 0.0);
    let problem = Problem { a: kernel.to_vec(), b: target, clip_lo: ext_lo, clip_hi: ext_lo + n - 1 };
    richardson_lucy(&problem, &mut q, &SolverLimits { max_iterations: iterations, tolerance: 1e-5 });
    if !clipped && let Some(kept) = variance_kept(&q, q_first, pmf.moments().1 - kv) {
        return from_weights(b, kept.first, &kept.p);
    }
    from_weights(b, q_first, &q)
}

/// Richardson–Lucy's `Q` (first cell `first`) rescaled to variance `var` (Eq. 5–6,
/// [`Pmf::rescaled_exact`]), its shape and mean kept, where its variance misses `var` by more
/// than [`RL_VARIANCE_SLACK`]; `None` where it is within. `var` is the measured PMF's less the
/// kernel's, so `Q ∗ K` keeps the measured variance. Richardson–Lucy fits the shape, not the
/// moments: on a PMF a few cells wide whose outer cells are empty it spreads `Q` so that `Q ∗ K`
/// puts mass where `P` has none (EMVA set 002 at 1–12 DN above black, sub-DN noise and a 3-tap
/// kernel: `Q ∗ K` 0.012–0.023 DN² above the measured variance).
fn variance_kept(q: &[f64], first: i32, var: f64) -> Option<Pmf> {
    let q = Pmf::from_weights(first, q.iter().copied())?;
    let (qm, qv) = q.moments();
    (var > 0.0 && (qv - var).abs() > RL_VARIANCE_SLACK * var).then(|| q.rescaled_exact(qm, var))
}

/// The mean and variance of the offset kernel whose first offset is `k0`.
fn kernel_moments(k0: i32, kernel: &[f64]) -> (f64, f64) {
    let km: f64 = kernel.iter().enumerate().map(|(i, p)| (k0 + i as i32) as f64 * p).sum();
    let kv: f64 = kernel.iter().enumerate().map(|(i, p)| ((k0 + i as i32) as f64 - km).powi(2) * p).sum();
    (km, kv)
}

/// Which end of a clipped bin's PMF holds the clamp's pile: `Some(true)` the low end,
/// `Some(false)` the high end, `None` for an unclipped bin or one with no pile at an end. The
/// pile is the heavier end cell that [`is_pile`] finds. A PMF of fewer than four cells has no
/// trend to judge by (only a bin too narrow to deconvolve has one): there the heaviest cell is
/// the pile if it is an end cell, and a single cell lies at the clip of the half of the levels
/// its bin lies in (`upper`: white's), except at a low end above `floor` (the noise value at or
/// below which the bin's cells reach the floor, where known): no level of the bin can pile
/// there. An 8-bit sensor whose noise at black rounds to nothing (`tests/bench/sim_tiles.py`:
/// black 2.87 DN, 0.1 DN of noise, the floor at 0) has bin 0 all at noise 0, 2 DN above the
/// floor; taken for a pile, it was moved to −1 and every black pixel came out 0.75 DN dark.
fn clamp_end(b: &BinModel, pmf: &Pmf, upper: bool, floor: Option<i32>) -> Option<bool> {
    let n = pmf.p.len();
    if !b.clipped || n == 0 {
        return None;
    }
    if n >= 4 {
        let pile_lo = is_pile([pmf.p[0], pmf.p[1], pmf.p[2], pmf.p[3]]);
        let pile_hi = is_pile([pmf.p[n - 1], pmf.p[n - 2], pmf.p[n - 3], pmf.p[n - 4]]);
        return match (pile_lo, pile_hi) {
            (false, false) => None,
            (true, true) => Some(pmf.p[0] >= pmf.p[n - 1]),
            (lo, _) => Some(lo),
        };
    }
    let heaviest = pmf.p.iter().enumerate().fold(0, |m, (i, &x)| if x > pmf.p[m] { i } else { m });
    let end = match (heaviest == 0, heaviest == n - 1) {
        (true, true) => Some(!upper),
        (true, false) => Some(true),
        (false, true) => Some(false),
        (false, false) => None,
    };
    match (end, floor) {
        (Some(true), Some(t)) if pmf.first > t => None,
        _ => end,
    }
}

/// Whether the end cell of `run` (the end cell first, then its three neighbours inward) is the
/// clamp's pile: it holds at least [`PILE_MIN`] and stands above the log-quadratic run of its
/// three neighbours (by a fifth), as the mass a clamp piled from the whole tail beyond does. The
/// end of a decaying tail does not, wherever the stored tail was cut: a Gaussian's sits on that
/// run, a Student-t's falls below it. With the end cell's mass alone counted, a tail cut at
/// 2⁻²⁰ of the peak could end in a cell of a few 10⁻⁶ and be folded as a pile at a clip the
/// sensor does not have.
fn is_pile(run: [f64; 4]) -> bool {
    let [end, a, b, c] = run;
    // log end > 3 log a − 3 log b + log c + log 1.2, without the logarithms.
    end >= PILE_MIN && a > 0.0 && c > 0.0 && end * b.powi(3) > 1.2 * a.powi(3) * c
}

/// `pmf`'s shape narrowed about its core ([`core_span`]; `core`, the PMF less its negligible
/// tails): the affine map under which the core comes out at mean `mu` and variance `var` exactly
/// ([`Pmf::exact_map`], Eq. 5–6 on a smooth reading of the cells), applied to the whole PMF, so
/// far tails of 10⁻⁶ of the mass set neither the centre nor the factor. The piecewise-uniform
/// re-binning ([`Pmf::rescaled`]) missed the variance on PMFs a few cells wide (near black at
/// the demo's ISO 100, 1.2 DN² narrowed by 0.11: 0.968 of the measured variance in `Q ∗ K`).
fn narrowed(pmf: &Pmf, core: &Pmf, mu: f64, var: f64) -> Pmf {
    pmf.mapped(&core.exact_map(mu, var))
}

/// The index span of `p`'s support less its negligible tails: without the cells at each end
/// that together hold at most [`TAIL_MASS`] of the total.
fn core_span(p: &[f64]) -> (usize, usize) {
    let bound = TAIL_MASS * p.iter().sum::<f64>();
    let outer = |cells: &mut dyn Iterator<Item = &f64>| {
        let mut cum = 0.0;
        cells
            .take_while(|&&x| {
                cum += x;
                cum <= bound
            })
            .count()
    };
    let lo = outer(&mut p.iter()).min(p.len() - 1);
    let hi = (p.len() - 1 - outer(&mut p.iter().rev())).max(lo);
    (lo, hi)
}

/// The start (and, below [`RESCALE_ONLY`], the result) for a clipped bin: the clamp's pile is
/// the mass the sensor pushed past its clip, so it is set beyond the clip by the kernel's reach
/// (every offset added then clamps it back onto the clip), and the rest, the unclipped part, is
/// narrowed by the kernel's variance (Eq. 5–6) as an unclipped bin is. Narrowing the whole PMF
/// instead would carry the pile inward, and keeping it would let the offsets smear the pile onto
/// its neighbour.
/// `k0`, `taps`: the kernel's first offset and length; `km`, `kv`: its mean and variance.
fn clipped_start(pmf: &Pmf, low: bool, k0: i32, taps: usize, km: f64, kv: f64) -> Pmf {
    let n = pmf.p.len();
    let (pile, rest, rest_first) = match low {
        true => (pmf.p[0], &pmf.p[1..], pmf.first + 1),
        false => (pmf.p[n - 1], &pmf.p[..n - 1], pmf.first),
    };
    let k_last = k0 + taps as i32 - 1;
    // The pile's new place: past the clip by the kernel's reach.
    let at = match low {
        true => pmf.first - k_last,
        false => pmf.last() - k0,
    };
    let Some(inner) = Pmf::from_weights(rest_first, rest.iter().copied()) else {
        return Pmf { first: at, p: vec![1.0] };
    };
    let (im, iv) = inner.moments();
    let narrowed = if iv > kv + 1.0 / 12.0 { inner.rescaled_exact(im - km, iv - kv) } else { inner };
    let first = narrowed.first.min(at);
    let last = narrowed.last().max(at);
    let mut p: Vec<f64> = (first..=last).map(|v| narrowed.at(v) * (1.0 - pile)).collect();
    p[(at - first) as usize] += pile;
    Pmf { first, p }
}

/// For a clipped bin whose end pile was read at the wrong end: where most of its mass lies within the
/// kernel's reach of one end, that part is the clamp's pile spread over a few cells; it is moved
/// past the clip by the kernel's reach (every offset added then leaves it at or beyond where it
/// was, so the clamp takes it back onto the clip) and the rest is narrowed as in
/// [`clipped_start`]. Narrowed with the rest instead, the pile moved inward toward the mean its
/// pooled tails set, below the clip: on a 14-bit random sensor at ISO 2000 (row offsets of
/// 17 DN², the saturated pixels' bin holding 0.3 of a DN² of spread besides its tails) the
/// saturated pixels came out 24 DN below white, and the group's JSD went from 0.05 to 0.68.
/// `None` when neither end holds most of the mass.
fn spread_pile_start(pmf: &Pmf, k0: i32, taps: usize, km: f64, kv: f64) -> Option<Pmf> {
    let n = pmf.p.len();
    if taps >= n {
        return None;
    }
    let total: f64 = pmf.p.iter().sum();
    let low_mass: f64 = pmf.p[..taps].iter().sum::<f64>() / total;
    let high_mass: f64 = pmf.p[n - taps..].iter().sum::<f64>() / total;
    let (pile, rest, shift) = if high_mass >= 0.5 && high_mass >= low_mass {
        (n - taps..n, 0..n - taps, -k0)
    } else if low_mass >= 0.5 {
        (0..taps, taps..n, -(k0 + taps as i32 - 1))
    } else {
        return None;
    };
    let pile_mass: f64 = pmf.p[pile.clone()].iter().sum::<f64>() / total;
    let moved = Pmf::from_weights(pmf.first + pile.start as i32 + shift, pmf.p[pile].iter().copied())?;
    let narrowed = Pmf::from_weights(pmf.first + rest.start as i32, pmf.p[rest].iter().copied()).map(|inner| {
        let (im, iv) = inner.moments();
        if iv > kv + 1.0 / 12.0 { inner.rescaled_exact(im - km, iv - kv) } else { inner }
    });
    let (first, last) = match &narrowed {
        Some(r) => (r.first.min(moved.first), r.last().max(moved.last())),
        None => (moved.first, moved.last()),
    };
    let p: Vec<f64> = (first..=last)
        .map(|v| moved.at(v) * pile_mass + narrowed.as_ref().map_or(0.0, |r| r.at(v) * (1.0 - pile_mass)))
        .collect();
    Some(Pmf { first, p })
}

/// The start, and result, for a clipped bin whose cells at or below `t` lie at or past the
/// sensor's floor for the bin's lowest clean level: those cells are the clamp's pile, pooled
/// from the bin's levels (each piles at `floor − level`, so the pile covers as many cells as the
/// bin has levels, on a digital-gain lattice every other one, with pooled tails beyond); they
/// are moved past the clip by the kernel's reach, so every offset added leaves them at or past
/// the floor and the clamp takes them back onto it, and the rest is narrowed by the kernel's
/// variance (Eq. 5–6). Read from the end cells instead ([`clamp_end`]), a pile whose first
/// cell holds less than its neighbours (its bin's lowest level has few pixels) was taken for
/// none and kept in place, and the offsets spread it over the codes above the floor; with a
/// floor-count tail at the other end read as the pile, Richardson–Lucy, which cannot put
/// mass below `first − k0` there, piled it `|k0|` DN inward: the demo's ISO 3200, R, clean
/// levels 84–87 DN, put 1.2 % of its mass 7–10 DN above black's clamp. `None` when no cell
/// holds mass at or below `t`, or nothing is left above it.
fn floor_pile_start(pmf: &Pmf, t: i32, k0: i32, taps: usize, km: f64, kv: f64) -> Option<Pmf> {
    if pmf.first > t || t >= pmf.last() {
        return None;
    }
    let split = (t - pmf.first + 1) as usize;
    let total: f64 = pmf.p.iter().sum();
    let pile_mass = pmf.p[..split].iter().sum::<f64>() / total;
    if pile_mass < PILE_MIN {
        return None;
    }
    let reach = k0 + taps as i32 - 1;
    let moved = Pmf::from_weights(pmf.first - reach.max(0), pmf.p[..split].iter().copied())?;
    let rest = Pmf::from_weights(pmf.first + split as i32, pmf.p[split..].iter().copied())?;
    let (im, iv) = rest.moments();
    let narrowed = if iv > kv + 1.0 / 12.0 { rest.rescaled_exact(im - km, iv - kv) } else { rest };
    let (first, last) = (narrowed.first.min(moved.first), narrowed.last().max(moved.last()));
    let p = (first..=last).map(|v| moved.at(v) * pile_mass + narrowed.at(v) * (1.0 - pile_mass)).collect();
    Some(Pmf { first, p })
}

/// `b` with its PMF replaced by the weights `q` over `first, first + 1, …`.
fn from_weights(b: &BinModel, first: i32, q: &[f64]) -> BinModel {
    const SCALE: f64 = (1u64 << 30) as f64;
    // `(x·SCALE).round() as u64` (0 below zero and at NaN), without libm's `round`.
    let count = |x: f64| round_half_away(x * SCALE).max(0) as u64;
    let lo = q.iter().position(|&x| count(x) > 0);
    let hi = q.iter().rposition(|&x| count(x) > 0);
    let (Some(lo), Some(hi)) = (lo, hi) else {
        return b.clone();
    };
    // The counts of the cells kept, and `b`'s other fields (`..b.clone()` copied its counts
    // only to drop them).
    let counts = q[lo..=hi].iter().map(|&x| count(x)).collect();
    BinModel {
        first: first + lo as i32,
        counts,
        samples: b.samples,
        source: b.source,
        measured: b.measured,
        clipped: b.clipped,
        grid_step: 0,
    }
}

/// `E[f(1 − f)]` over a density on the grid, `f` each grid point's fraction of a DN: the
/// variance dithering such offsets onto the integers adds (the kernel's dither splits each grid
/// point the same way).
fn dither_variance(d: &(i64, Vec<f64>)) -> f64 {
    let total: f64 = d.1.iter().sum();
    if total <= 0.0 {
        return 0.0;
    }
    let acc: f64 =
        d.1.iter()
            .enumerate()
            .map(|(i, &w)| {
                let o = (d.0 + i as i64) as f64 / GRID;
                let f = o - floor_i64(o) as f64;
                w * f * (1.0 - f)
            })
            .sum();
    acc / total
}

/// The fixed pattern's shading at `pos` as a density on the grid: its grid cells, equally
/// weighted (a point mass at 0 without shading).
fn shading_density(fp: &FixedPattern, pos: usize) -> (i64, Vec<f64>) {
    let g = &fp.shading[pos];
    // Synthesis adds no shading where the grid does not match its cells ([`FixedPattern::shading_line`]).
    if g.is_empty() || g.len() != (fp.grid[0] * fp.grid[1]) as usize {
        return (0, vec![1.0]);
    }
    let w = 1.0 / g.len() as f64;
    on_grid(&g.iter().map(|&v| (v as f64, w)).collect::<Vec<_>>())
}

/// A quantile function as a density on the grid.
fn quantile_density(d: &OffsetDistribution) -> (i64, Vec<f64>) {
    let q = &d.quantiles;
    let n = q.len();
    let pts: Vec<(f64, f64)> =
        (0..n.saturating_sub(1)).map(|i| (0.5 * (q[i] as f64 + q[i + 1] as f64), 1.0 / (n - 1) as f64)).collect();
    on_grid(&pts)
}

/// The density of one position's frame offsets as [`FrameOffsets::draw`] makes them: the
/// measured offsets, shrunk, each with its Gaussian kernel.
fn frame_density(f: &FrameOffsets, pos: usize) -> (i64, Vec<f64>) {
    let Some(b) = f.bootstrap(pos) else {
        return (0, vec![1.0]);
    };
    // The kernel at 33 points over ±4 sd.
    let ws: Vec<f64> = (-16..=16).map(|j| (-0.5 * (j as f64 / 4.0).powi(2)).exp()).collect();
    let t = ws.iter().sum::<f64>() * f.offsets.len() as f64;
    let mut pts = Vec::with_capacity(f.offsets.len() * ws.len());
    for o in &f.offsets {
        let c = (o[pos] as f64 - b.mean) * b.shrink;
        pts.extend((-16..=16).zip(&ws).map(|(j, w)| (c + b.kernel_sd * j as f64 / 4.0, w / t)));
    }
    on_grid(&pts)
}

/// Weighted points onto the grid (linear split between the two nearest cells).
fn on_grid(pts: &[(f64, f64)]) -> (i64, Vec<f64>) {
    if pts.is_empty() {
        return (0, vec![1.0]);
    }
    let lo = pts.iter().map(|p| floor_i64(p.0 * GRID)).min().unwrap_or(0);
    let hi = pts.iter().map(|p| floor_i64(p.0 * GRID) + 1).max().unwrap_or(0);
    let mut out = vec![0.0; (hi - lo + 1) as usize];
    for &(x, w) in pts {
        let g = x * GRID;
        let fi = floor_i64(g);
        let f = fi as f64;
        let k = (fi - lo) as usize;
        out[k] += w * (1.0 - (g - f));
        out[k + 1] += w * (g - f);
    }
    (lo, out)
}

fn convolve(a: &(i64, Vec<f64>), b: &(i64, Vec<f64>)) -> (i64, Vec<f64>) {
    let mut out = vec![0.0; a.1.len() + b.1.len() - 1];
    crate::math::deconv::convolve_wide(&a.1, &b.1, &mut out);
    (a.0 + b.0, out)
}

/// An image's columns as the fixed pattern's rows need them ([`StructureSampler::pattern_columns`]).
pub(crate) struct PatternColumns {
    x0: usize,
    /// Per column, its shading cells and the fraction between them ([`grid_coord`]).
    cells: Vec<(u32, u32, f64)>,
    /// Cells of a shading line (the length of the zero line of a position without shading).
    line_len: usize,
    /// Per column parity, the cells as the vectorised loop reads them (empty where it does not
    /// apply).
    parity: [ParityColumns; 2],
}

/// The fixed pattern of one sensor row ([`StructureSampler::row_pattern`]), computed where the
/// synthesis pass adds it. Per column parity (of the image's index): the shading interpolated to
/// the row and the residual's quantile function.
pub(crate) struct RowPattern<'a> {
    y: usize,
    columns: &'a PatternColumns,
    parity: [ParityPattern<'a>; 2],
    /// Per column parity, the row's values computed at once ([`parity_row`]), where it applies.
    computed: Option<[Vec<i64>; 2]>,
}

struct ParityPattern<'a> {
    line: Vec<f64>,
    q: &'a [f32],
}

impl RowPattern<'_> {
    /// The row's values computed at once, per column parity (column `i` at `[i & 1][i >> 1]`),
    /// where the vectorised loop applies; else [`Self::pair`] computes them pixel by pixel.
    pub(crate) fn computed(&self) -> Option<&[Vec<i64>; 2]> {
        self.computed.as_ref()
    }

    /// The buffers the row was computed into, for the next row's
    /// ([`StructureSampler::row_pattern_in`]; empty where the row was not computed at once).
    pub(crate) fn into_scratch(self) -> [Vec<i64>; 2] {
        self.computed.unwrap_or_default()
    }

    /// The pattern (2⁻³² DN) of the image's columns `i` and `i + 1`, `i` even and `i + 1` within
    /// the row.
    #[inline(always)]
    pub(crate) fn pair(&self, i: usize) -> (i64, i64) {
        (self.value(&self.parity[0], i), self.value(&self.parity[1], i + 1))
    }

    /// The pattern (2⁻³² DN) of the image's column `i`.
    #[inline]
    pub(crate) fn at(&self, i: usize) -> i64 {
        match &self.computed {
            Some(c) => c[i & 1][i >> 1],
            None => self.value(&self.parity[i & 1], i),
        }
    }

    /// [`StructureSampler::add_pattern_row_at`]'s expression for one pixel, with the same
    /// floating-point operations in the same order. [`quantile_at`] is inlined for the uniform
    /// draw's range `[0, 1)`, where its clamp changes nothing, with its index converted through
    /// `u32` (the same integer for the indices of any stored quantile function).
    #[inline(always)]
    fn value(&self, p: &ParityPattern<'_>, i: usize) -> i64 {
        let (c0, c1, f) = self.columns.cells[i];
        let shade = p.line[c0 as usize] * (1.0 - f) + p.line[c1 as usize] * f;
        let u = pattern_unit(self.y, self.columns.x0 + i);
        let q = p.q;
        let residual = match q.len() {
            0 | 1 => quantile_at(q, u),
            n => {
                let x = u * (n - 1) as f64;
                let k = (x as u32 as usize).min(n - 2);
                let f = x - k as u32 as f64;
                q[k] as f64 * (1.0 - f) + q[k + 1] as f64 * f
            }
        };
        round_half_away_near((shade + residual) * 4294967296.0)
    }
}

/// A sensor pixel's uniform draw of the fixed pattern (splitmix64 of its position).
#[inline]
fn pattern_unit(y: usize, x: usize) -> f64 {
    let mut z = PATTERN_KEY ^ ((y as u64) << 32 | x as u64);
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    unit(z ^ (z >> 31))
}

/// A uniform draw in `[0, 1)` from 53 bits.
#[inline]
fn unit(u: u64) -> f64 {
    // Through i64: the same value (it is below 2⁵³), a single conversion instruction.
    ((u >> 11) as i64) as f64 * (1.0 / (1u64 << 53) as f64)
}

/// A standard normal draw (Box–Muller).
fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
    let u1 = 1.0 - unit(rng.next_u64());
    let u2 = unit(rng.next_u64());
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

#[cfg(test)]
#[path = "tests_structure.rs"]
mod tests;
