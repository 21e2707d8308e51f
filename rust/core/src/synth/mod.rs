//! Noise synthesis on clean raw images (paper Eq. 3): `noisy = clamp(clean + n, 0, white)`, `n`
//! drawn for (ISO, CFA position, bin of the clean level). Seeded and reproducible whatever the
//! thread count: each band of rows has its own ChaCha stream.

mod band_draws;
mod clean_at;
mod dither_lanes;
mod pattern_cache;
mod pattern_lanes;
pub mod phase_tables;
pub mod sampler;
pub mod sampler_up_to;
pub mod saturated;
pub mod structure;

pub use clean_at::CleanAt;
pub use pattern_cache::DEFAULT_PATTERN_CACHE_BYTES;

use std::convert::Infallible;

use ndarray::{Array2, ArrayView2};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::synth::band_draws::next_u64s;
use crate::synth::dither_lanes::{DitherJumps, offsets_interleaved, offsets_split};
use crate::synth::phase_tables::PhaseSet;
use crate::synth::sampler::{BinTable, IsoSampler, fixed};
use crate::synth::structure::ImageOffsets;

/// Rows per RNG stream.
pub const BAND_ROWS: usize = 16;

/// The RNG of one band of rows.
pub fn band_rng(seed: u64, band: usize) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(band as u64);
    rng
}

/// Adds synthetic noise to a clean raw image (levels in DN, black included; CFA phase of the
/// pack's layout at (0, 0)).
pub fn synthesize(sampler: &IsoSampler, clean: ArrayView2<'_, u16>, seed: u64) -> Array2<u16> {
    synthesize_at(sampler, clean, seed, (0, 0))
}

/// As [`synthesize`], for a crop whose pixel (0, 0) sits at `origin = (row, column)` of the full
/// sensor: each pixel gets the noise of its true CFA position (`position(row + y, column + x)`).
/// Only the parity of the origin matters, except to a fixed pattern (which is the sensor's, pixel
/// by pixel); `(0, 0)` is [`synthesize`], byte for byte.
pub fn synthesize_at(
    sampler: &IsoSampler,
    clean: ArrayView2<'_, u16>,
    seed: u64,
    origin: (usize, usize),
) -> Array2<u16> {
    let Ok(out) = synthesize_guarded(sampler, clean, seed, origin, |_| Ok::<(), Infallible>(()));
    out
}

/// [`synthesize_at`], each band drawn only once `guard(band)` lets it: the first refusal is
/// returned (for a sampler that draws only some images, [`SamplerUpTo`](sampler_up_to::SamplerUpTo)).
pub(crate) fn synthesize_guarded<E: Send>(
    sampler: &IsoSampler,
    clean: ArrayView2<'_, u16>,
    seed: u64,
    origin: (usize, usize),
    guard: impl Fn(usize) -> Result<(), E> + Sync,
) -> Result<Array2<u16>, E> {
    let (h, w) = clean.dim();
    let mut out = vec![0u16; h * w];
    if w > 0 {
        let fill = band_filler(sampler, clean, seed, origin);
        out.par_chunks_mut(BAND_ROWS * w).enumerate().try_for_each(|(band, chunk)| {
            guard(band)?;
            fill(band, chunk);
            Ok(())
        })?;
    }
    Ok(Array2::from_shape_vec((h, w), out).expect("h × w samples"))
}

/// As [`synthesize_at`], handing each band of [`BAND_ROWS`] rows (the last may be shorter) to
/// `sink(first_row, samples)` as soon as it is drawn, on the thread that drew it, instead of
/// returning the image: for callers that write the noisy image out as it is made. The samples
/// are those [`synthesize_at`] returns, byte for byte.
pub fn synthesize_bands<F>(sampler: &IsoSampler, clean: ArrayView2<'_, u16>, seed: u64, origin: (usize, usize), sink: F)
where
    F: Fn(usize, &[u16]) + Sync,
{
    let Ok(()) = synthesize_bands_guarded(sampler, clean, seed, origin, sink, |_| Ok::<(), Infallible>(()));
}

/// [`synthesize_bands`], each band drawn (and sunk) only once `guard(band)` lets it: the first
/// refusal is returned; bands drawn before it may have reached the sink.
pub(crate) fn synthesize_bands_guarded<F, E: Send>(
    sampler: &IsoSampler,
    clean: ArrayView2<'_, u16>,
    seed: u64,
    origin: (usize, usize),
    sink: F,
    guard: impl Fn(usize) -> Result<(), E> + Sync,
) -> Result<(), E>
where
    F: Fn(usize, &[u16]) + Sync,
{
    let (h, w) = clean.dim();
    if w == 0 || h == 0 {
        return Ok(());
    }
    let fill = band_filler(sampler, clean, seed, origin);
    (0..h.div_ceil(BAND_ROWS)).into_par_iter().try_for_each_init(Vec::new, |buf, band| {
        guard(band)?;
        let rows = BAND_ROWS.min(h - band * BAND_ROWS);
        buf.resize(rows * w, 0);
        fill(band, buf);
        sink(band * BAND_ROWS, buf);
        Ok(())
    })
}

/// What draws band `band` of the noisy image into its `chunk` of rows.
type BandFiller<'a> = Box<dyn Fn(usize, &mut [u16]) + Sync + 'a>;

fn band_filler<'a>(
    sampler: &'a IsoSampler,
    clean: ArrayView2<'a, u16>,
    seed: u64,
    origin: (usize, usize),
) -> BandFiller<'a> {
    if sampler.target_tables(0).is_some() {
        return structured_filler::<true>(sampler, sampler.structure(), clean, seed, origin);
    }
    if let Some(st) = sampler.structure() {
        return structured_filler::<false>(sampler, Some(st), clean, seed, origin);
    }
    let w = clean.dim().1;
    let (row0, col0) = (origin.0 & 1, origin.1 & 1);
    {
        Box::new(move |band: usize, chunk: &mut [u16]| {
            let mut rng = band_rng(seed, band);
            // A row's pair draws, taken from the stream at once (`band_draws.rs`).
            let mut us: Vec<u64> = Vec::new();
            for (r, row) in chunk.chunks_mut(w).enumerate() {
                let y = band * BAND_ROWS + r;
                let src = clean_row(&clean, y);
                let parity = ((y + row0) & 1) << 1;
                next_u64s(&mut rng, w / 2, &mut us);
                // The CFA positions of the even and the odd columns of this row.
                let (even, odd) = (parity | col0, parity | (col0 ^ 1));
                let (lut0, tab0) = sampler.position_tables(even);
                let (lut1, tab1) = sampler.position_tables(odd);
                let lattice = sampler.needs_finish(even) || sampler.needs_finish(odd);
                let white = sampler.white as i32;
                // One 64-bit draw feeds an even and an odd pixel: the stream is fixed by the band.
                let Pairs { out: o, src: c, us } = Pairs::of(row, &src, &us);
                if lattice {
                    for i in 0..us.len() {
                        let (u, c) = (us[i], c[i]);
                        let alt = (i + (y >> 1)) & 1 == 1;
                        o[i] = [
                            sampler.finish(even, draw(lut0, tab0, c[0], u as u32), alt),
                            sampler.finish(odd, draw(lut1, tab1, c[1], (u >> 32) as u32), alt),
                        ];
                    }
                } else {
                    for i in 0..us.len() {
                        let (u, c) = (us[i], c[i]);
                        o[i] = [
                            draw(lut0, tab0, c[0], u as u32).clamp(0, white) as u16,
                            draw(lut1, tab1, c[1], (u >> 32) as u32).clamp(0, white) as u16,
                        ];
                    }
                }
                if w % 2 == 1 {
                    let alt = ((w >> 1) + (y >> 1)) & 1 == 1;
                    row[w - 1] = sampler.finish(even, draw(lut0, tab0, src[w - 1], rng.next_u32()), alt);
                }
            }
        })
    }
}

/// [`synthesize_at`] with structured components: per image a frame offset per position, per row
/// and per column an offset, per sensor pixel its fixed pattern ([`structure`](mod@structure)),
/// each pixel adding their sum dithered onto the integers. The pixel draws use the band streams
/// as without components; the dither draws follow them in the same stream.
///
/// `TARGET`: the clean image is at the target ISO's brightness ([`CleanAt::Target`]): each
/// level draws from the bin of its reference level and adds the level's offset that takes the
/// gain shift out, dithered with the structured offsets (`st` may then be `None`: no
/// structured components, only that offset).
fn structured_filler<'a, const TARGET: bool>(
    sampler: &'a IsoSampler,
    st: Option<&structure::StructureSampler>,
    clean: ArrayView2<'a, u16>,
    seed: u64,
    origin: (usize, usize),
) -> BandFiller<'a> {
    let (h, w) = clean.dim();
    let (row0, col0) = (origin.0 & 1, origin.1 & 1);
    let offsets = match st {
        Some(st) => st.draw(seed, h, w, origin),
        None => ImageOffsets { frame: [0.0; crate::POSITIONS], rows: vec![0.0; h], columns: vec![0.0; w] },
    };
    // Per row parity, per column: the column's offset plus its position's frame offset, in
    // 2⁻³² DN (fixed point: a pixel's integer offset is then one add and one shift).
    let columns: [Vec<i64>; 2] = std::array::from_fn(|r| {
        let parity = ((r + row0) & 1) << 1;
        offsets.columns.iter().enumerate().map(|(x, c)| fixed(c + offsets.frame[parity | ((x + col0) & 1)])).collect()
    });
    // The fixed pattern varies from pixel to pixel: each row's offsets are then built anew.
    let pattern = st.filter(|st| st.has_pattern()).cloned();
    // Kept by the sampler when this region was synthesized before; else drawn row by row.
    let kept = pattern.as_ref().and_then(|p| p.kept_pattern(origin, h, w));
    let pattern_columns = pattern.as_ref().filter(|_| kept.is_none()).map(|p| p.pattern_columns(origin.1, w));
    // A row's dither draws: one per pair of pixels and one for the last of an odd width.
    let draws = w.div_ceil(2);
    let jumps = DitherJumps::new(draws);
    // The pattern of a row without a fixed pattern.
    let no_pattern: Vec<i64> = match &pattern {
        Some(_) => Vec::new(),
        None => vec![0; w],
    };
    // Per position, the highest clean level whose table is drawn at the pixel's phase
    // (`phase_tables.rs`), in the map of levels this image takes; `None`: no such level.
    let phase_top: [Option<u16>; crate::POSITIONS] = std::array::from_fn(|p| {
        let sets = sampler.phase_sets(p);
        if sets.iter().all(Option::is_none) {
            return None;
        }
        let lut = match TARGET {
            true => sampler.target_tables(p).expect("a target sampler").0,
            false => sampler.position_tables(p).0,
        };
        lut.iter()
            .rposition(|&t| sets.get(t as usize).is_some_and(Option::is_some))
            .map(|l| l.min(u16::MAX as usize) as u16)
    });
    {
        Box::new(move |band: usize, chunk: &mut [u16]| {
            let mut rng = band_rng(seed, band);
            // A row's pixel draws (one per pair and one for an odd width's last pixel), taken
            // from the stream at once after the row's dither seed (`band_draws.rs`).
            let mut us: Vec<u64> = Vec::new();
            let mut offsets_row: Vec<i32> = vec![0; w];
            let mut dither: Vec<u64> = Vec::new();
            // The fixed pattern's row values, per column parity, reused from row to row.
            let mut scratch: [Vec<i64>; 2] = Default::default();
            // A row's fixed pattern (2⁻³² DN) where some pixel draws at its phase.
            let mut pattern_row: Vec<i64> = Vec::new();
            for (r, row) in chunk.chunks_mut(w).enumerate() {
                let y = band * BAND_ROWS + r;
                let src = clean_row(&clean, y);
                let parity = ((y + row0) & 1) << 1;
                let (even, odd) = (parity | col0, parity | (col0 ^ 1));
                let (lut0, tab0) = sampler.position_tables(even);
                let (lut1, tab1) = sampler.position_tables(odd);
                // At the target brightness: the bins of the reference levels, and the offsets
                // that take the gain shift out (none otherwise).
                let ((lut0, sh0), (lut1, sh1)) = if TARGET {
                    (
                        sampler.target_tables(even).expect("a target sampler"),
                        sampler.target_tables(odd).expect("a target sampler"),
                    )
                } else {
                    ((lut0, &[][..]), (lut1, &[][..]))
                };
                let finish = sampler.needs_finish(even) || sampler.needs_finish(odd);
                let white = sampler.white as i32;
                let ry = fixed(offsets.rows[y]);
                let cols = &columns[y & 1];
                // Dither draws from a xorshift64* stream seeded by the band's stream per row (a
                // 32-bit threshold needs no cryptographic quality).
                let state = rng.next_u64() | 1;
                next_u64s(&mut rng, draws, &mut us);
                // Whether a pixel of this row may draw at its offset's phase (then the row's
                // pattern and dither draws are kept for it, and its pixels drawn in the phased
                // loop): the lowest level of each column parity against its position's top.
                let top = [phase_top[even], phase_top[odd]];
                let phased = top.iter().any(Option::is_some) && {
                    let lowest = parity_minima(&src);
                    (0..2).any(|b| top[b].is_some_and(|t| lowest[b] <= u32::from(t)))
                };
                // Drawn in lanes for the vectorised pass; the target's shift keeps the serial
                // pass (its per-pixel lookups left the lanes no faster), and draws them in lanes
                // only for the phase (the same draws).
                if !TARGET || phased {
                    jumps.fill(state, draws, &mut dither);
                }
                let d: &[u64] = if TARGET { &[] } else { &dither[..draws] };
                if phased {
                    pattern_row.clear();
                    pattern_row.resize(w, 0);
                }
                // The row in passes, each stream drawn in its own order (a pair's pixel draw `u`
                // from the band's stream, its dither `v` from the row's xorshift): first every
                // pixel's integer offset `⌊o⌋ + [v < o − ⌊o⌋]` for its offset `o` and a uniform
                // 32-bit `v`, as `⌊(o·2³² + v) / 2³²⌋`, the fixed pattern added where it is
                // reached (kept, or computed from the pixel's position); then the pixel draws, a
                // loop as short as the pixel-only one, so the table lookups of several pixels
                // overlap.
                let level = |lut: &[u16], c: u16| (c as usize).min(lut.len() - 1);
                let shift = |i: usize, c: u16| -> i64 {
                    match TARGET {
                        true if i & 1 == 0 => sh0[level(lut0, c)],
                        true => sh1[level(lut1, c)],
                        false => 0,
                    }
                };
                let row_offsets = RowOffsets { src: &src, cols, ry, state, dither: d, shift: &shift };
                // Without the target's shift, the pairs' offsets in one vectorised loop.
                match (&kept, &pattern, &pattern_columns) {
                    (Some(k), _, _) => {
                        let k = k.row(y);
                        if phased {
                            pattern_row.copy_from_slice(&k[..w]);
                        }
                        match TARGET {
                            false => row_offsets.fill_pairs(
                                &mut offsets_row,
                                |o| offsets_interleaved(cols, k, ry, d, o),
                                |i| k[i],
                            ),
                            true => row_offsets.fill(&mut offsets_row, |i| (k[i], k[i + 1]), |i| k[i]),
                        }
                    }
                    (None, Some(p), Some(pc)) => {
                        let rp =
                            p.row_pattern_in(pc, origin.0 + y, std::mem::take(&mut scratch)).expect("a fixed pattern");
                        if phased {
                            pattern_row.iter_mut().enumerate().for_each(|(i, v)| *v = rp.at(i));
                        }
                        match (rp.computed(), TARGET) {
                            (Some([c0, c1]), false) => row_offsets.fill_pairs(
                                &mut offsets_row,
                                |o| offsets_split(cols, c0, c1, ry, d, o),
                                |i| c0[i >> 1],
                            ),
                            (Some([c0, c1]), true) => {
                                row_offsets.fill(&mut offsets_row, |i| (c0[i >> 1], c1[i >> 1]), |i| c0[i >> 1])
                            }
                            (None, _) => row_offsets.fill(&mut offsets_row, |i| rp.pair(i), |i| rp.at(i)),
                        }
                        scratch = rp.into_scratch();
                    }
                    _ => match TARGET {
                        false => row_offsets.fill_pairs(
                            &mut offsets_row,
                            |o| offsets_interleaved(cols, &no_pattern, ry, d, o),
                            |_| 0,
                        ),
                        true => row_offsets.fill(&mut offsets_row, |_| (0, 0), |_| 0),
                    },
                }
                if phased {
                    let sets = [sampler.phase_sets(even), sampler.phase_sets(odd)];
                    let phased_row = PhasedRow {
                        sampler,
                        positions: [even, odd],
                        luts: [lut0, lut1],
                        tabs: [tab0, tab1],
                        sets,
                        top,
                        finish,
                        y,
                        src: &src,
                        cols,
                        pattern: &pattern_row,
                        ry,
                        dither: &dither,
                        shift: &shift,
                    };
                    phased_row.draw(&us, row, &offsets_row);
                    continue;
                }
                // Zipped slices here: indexing them as the pixel-only loop does took 2 % more
                // instructions in this loop (callgrind, 12 MP, the structured pack's ISO 1600).
                let pairs = row.chunks_exact_mut(2).zip(src.chunks_exact(2)).zip(offsets_row.chunks_exact(2)).zip(&us);
                if finish {
                    for (i, (((o, c), k), &u)) in pairs.enumerate() {
                        let a = draw(lut0, tab0, c[0], u as u32) + k[0];
                        let b = draw(lut1, tab1, c[1], (u >> 32) as u32) + k[1];
                        let alt = (i + (y >> 1)) & 1 == 1;
                        o[0] = sampler.finish(even, a, alt);
                        o[1] = sampler.finish(odd, b, alt);
                    }
                } else {
                    for (((o, c), k), &u) in pairs {
                        let a = draw(lut0, tab0, c[0], u as u32) + k[0];
                        let b = draw(lut1, tab1, c[1], (u >> 32) as u32) + k[1];
                        o[0] = a.clamp(0, white) as u16;
                        o[1] = b.clamp(0, white) as u16;
                    }
                }
                if w % 2 == 1 {
                    let u = us[w >> 1];
                    let alt = ((w >> 1) + (y >> 1)) & 1 == 1;
                    let a = draw(lut0, tab0, src[w - 1], u as u32) + offsets_row[w - 1];
                    row[w - 1] = sampler.finish(even, a, alt);
                }
            }
        })
    }
}

/// A row in which some pixel draws at its offset's phase ([`structured_filler`]): its pixels'
/// tables, phase tables and offsets. Out of line, so that the loops of the other rows compile
/// as they did without it.
struct PhasedRow<'a, S: Fn(usize, u16) -> i64> {
    sampler: &'a IsoSampler,
    /// The CFA positions of the row's even and odd columns.
    positions: [usize; 2],
    luts: [&'a [u16]; 2],
    tabs: [&'a [BinTable]; 2],
    sets: [&'a [Option<PhaseSet>]; 2],
    /// Per column parity, the highest level drawn at the phase.
    top: [Option<u16>; 2],
    finish: bool,
    y: usize,
    src: &'a [u16],
    cols: &'a [i64],
    /// The row's fixed pattern (2⁻³² DN; zeros without one).
    pattern: &'a [i64],
    ry: i64,
    /// The row's dither draws, one per pair ([`DitherJumps::fill`]).
    dither: &'a [u64],
    shift: &'a S,
}

impl<S: Fn(usize, u16) -> i64> PhasedRow<'_, S> {
    /// The row's noisy pixels into `row`, each pair's pixel draw `u` from `us` (the row's draws
    /// from the band's stream, as the other rows draw them) and its dither draw `v`: a pixel whose table is drawn at
    /// its offset's phase draws its noise and its offset in one rounding (`phase_tables.rs`),
    /// the others add their integer offset from `offsets` to their table's draw.
    #[inline(never)]
    fn draw(&self, us: &[u64], row: &mut [u16], offsets: &[i32]) {
        let (src, w, y) = (self.src, self.src.len(), self.y);
        let white = self.sampler.white as i32;
        let noisy = |b: usize, i: usize, k: i32, u: u32, v: u32| -> i32 {
            let (c, lut) = (src[i], self.luts[b]);
            let t = lut[(c as usize).min(lut.len() - 1)] as usize;
            let set = match self.top[b].is_some_and(|top| c <= top) {
                true => self.sets[b].get(t).and_then(Option::as_ref),
                false => None,
            };
            match set {
                Some(set) => c as i32 + set.draw(self.cols[i] + self.pattern[i] + self.ry + (self.shift)(i, c), v, u),
                None => c as i32 + self.tabs[b][t].sample_u32(u) + k,
            }
        };
        let [even, odd] = self.positions;
        for (j, ((o, k), &u)) in row.chunks_exact_mut(2).zip(offsets.chunks_exact(2)).zip(us).enumerate() {
            let (i, v) = (2 * j, self.dither[j]);
            let a = noisy(0, i, k[0], u as u32, v as u32);
            let b = noisy(1, i + 1, k[1], (u >> 32) as u32, (v >> 32) as u32);
            let alt = (j + (y >> 1)) & 1 == 1;
            (o[0], o[1]) = match self.finish {
                true => (self.sampler.finish(even, a, alt), self.sampler.finish(odd, b, alt)),
                false => (a.clamp(0, white) as u16, b.clamp(0, white) as u16),
            };
        }
        if w % 2 == 1 {
            let u = us[w >> 1];
            let alt = ((w >> 1) + (y >> 1)) & 1 == 1;
            let a = noisy(0, w - 1, offsets[w - 1], u as u32, self.dither[w >> 1] as u32);
            row[w - 1] = self.sampler.finish(even, a, alt);
        }
    }
}

/// What one row's integer offsets are made of ([`structured_filler`]): the clean row, the
/// columns' offsets (with the frame's, 2⁻³² DN), the row's offset, the state of the row's
/// dither stream and, where the pass is vectorised ([`Self::fill_pairs`]), the stream's draws
/// (one per pair, [`DitherJumps::fill`]), and per pixel the target brightness's shift (0
/// otherwise).
struct RowOffsets<'a, S: Fn(usize, u16) -> i64> {
    src: &'a [u16],
    cols: &'a [i64],
    ry: i64,
    state: u64,
    dither: &'a [u64],
    shift: &'a S,
}

impl<S: Fn(usize, u16) -> i64> RowOffsets<'_, S> {
    /// Writes every pixel's integer offset into `out` (the row's length), pixel `i`'s fixed pattern from
    /// `pair(i)` (for `i` and `i + 1`, `i` even) or `one(i)` (the last pixel of an odd width).
    /// One dither draw per pair from the serial stream, its low half for the even pixel.
    #[inline(always)]
    fn fill(&self, out: &mut [i32], pair: impl Fn(usize) -> (i64, i64), one: impl Fn(usize) -> i64) {
        let mut state = self.state;
        let mut dither = || {
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            state.wrapping_mul(0x2545_F491_4F6C_DD1D)
        };
        let (src, cols, ry) = (self.src, self.cols, self.ry);
        let w = src.len();
        let pairs = src.chunks_exact(2).zip(cols.chunks_exact(2)).zip(out[..w].chunks_exact_mut(2));
        for (j, ((c, k), o)) in pairs.enumerate() {
            let i = 2 * j;
            let v = dither();
            let (p0, p1) = pair(i);
            let k0 = k[0] + p0 + (self.shift)(i, c[0]);
            let k1 = k[1] + p1 + (self.shift)(i + 1, c[1]);
            o[0] = ((k0 + ry + (v as u32) as i64) >> 32) as i32;
            o[1] = ((k1 + ry + (v >> 32) as i64) >> 32) as i32;
        }
        if w % 2 == 1 {
            self.fill_last(out, one, dither());
        }
    }

    /// [`Self::fill`] where the target brightness adds no shift: the pairs' offsets written by
    /// `pairs` (given `out` less an odd width's last pixel) with the lanes' draws (the serial
    /// stream's), that pixel's as [`Self::fill`]'s.
    #[inline(always)]
    fn fill_pairs(&self, out: &mut [i32], pairs: impl FnOnce(&mut [i32]), one: impl Fn(usize) -> i64) {
        let w = self.src.len();
        pairs(&mut out[..w - w % 2]);
        if w % 2 == 1 {
            self.fill_last(out, one, self.dither[w / 2]);
        }
    }

    /// The last pixel of an odd width, its fixed pattern from `one`, its dither draw `v`.
    #[inline(always)]
    fn fill_last(&self, out: &mut [i32], one: impl Fn(usize) -> i64, v: u64) {
        let (src, cols, ry) = (self.src, self.cols, self.ry);
        let w = src.len();
        let k = cols[w - 1] + one(w - 1) + (self.shift)(w - 1, src[w - 1]);
        out[w - 1] = ((k + ry + (v as u32) as i64) >> 32) as i32;
    }
}

/// A row's whole pairs of pixels as arrays of two, every slice cut to the pairs' count (the
/// length of `us`), so that a pixel loop indexing them by pair needs no bounds check.
struct Pairs<'a, 'b> {
    out: &'a mut [[u16; 2]],
    src: &'b [[u16; 2]],
    /// One draw per pair.
    us: &'b [u64],
}

impl<'a, 'b> Pairs<'a, 'b> {
    /// The pairs of `row` and `src` (of one length) and the first draws of `us` (at least one
    /// per pair).
    #[inline(always)]
    fn of(row: &'a mut [u16], src: &'b [u16], us: &'b [u64]) -> Self {
        let n = row.len() / 2;
        Self { out: &mut row.as_chunks_mut::<2>().0[..n], src: &src.as_chunks::<2>().0[..n], us: &us[..n] }
    }
}

/// The lowest level of a row's even and of its odd columns (`u32::MAX` for a parity without a
/// column): one pass the compiler vectorises.
fn parity_minima(src: &[u16]) -> [u32; 2] {
    let (mut m0, mut m1) = (u16::MAX, u16::MAX);
    for c in src.chunks_exact(2) {
        m0 = m0.min(c[0]);
        m1 = m1.min(c[1]);
    }
    if src.len() % 2 == 1 {
        m0 = m0.min(src[src.len() - 1]);
    }
    let seen = |m: u16, n: usize| if n > 0 { u32::from(m) } else { u32::MAX };
    [seen(m0, src.len().div_ceil(2)), seen(m1, src.len() / 2)]
}

/// `c + n`, `n` drawn with the 32-bit uniform `u` from the table of clean level `c`'s bin
/// (levels past the map take its last bin). A function rather than a closure in each row loop:
/// the compiler left the closure out of line, a call per pixel.
#[inline(always)]
fn draw(lut: &[u16], tab: &[BinTable], c: u16, u: u32) -> i32 {
    let l = (c as usize).min(lut.len() - 1);
    c as i32 + tab[lut[l] as usize].sample_u32(u)
}

/// Row `y` of the clean image as a slice (borrowed when the view is contiguous).
pub(crate) fn clean_row<'a>(clean: &'a ArrayView2<'_, u16>, y: usize) -> std::borrow::Cow<'a, [u16]> {
    let view = clean.row(y);
    match view.to_slice() {
        Some(s) => std::borrow::Cow::Borrowed(s),
        None => std::borrow::Cow::Owned(view.to_vec()),
    }
}

/// As [`synthesize`], for a clean image with fractional levels (e.g. rendered from HDR data):
/// the bin and the base level are `round(clean)`.
pub fn synthesize_f32(sampler: &IsoSampler, clean: ArrayView2<'_, f32>, seed: u64) -> Array2<u16> {
    let rounded = clean.mapv(|v| v.round().clamp(0.0, sampler.white as f32) as u16);
    synthesize(sampler, rounded.view(), seed)
}
