//! One frame's histogram counts for one CFA position, in a flat table of 32-bit counts. Each
//! window of counts is the range its bin's [`NoiseHistogram`] covered when the window was made,
//! and every clean level finds its window in one lookup ([`LevelWindow`]), so that a sample
//! costs one lookup and one increment, with no pointer to follow. A sample outside its window
//! goes straight to the histogram.
//!
//! Where the table stays small, every clean level the flat pixels have gets a window of its own
//! (counts by clean level and noise, [`WindowCounts::by_level`]): the output code is the clean
//! level plus the noise, so the same counts also give the output codes, and the one increment
//! per sample serves both ([`WindowCounts::flush`]). Otherwise the levels of a bin share its
//! window, and the output codes are counted apart ([`LaneCounts`]).
//!
//! The histograms end as they would have with every sample added to them in turn: a histogram
//! only grows for a sample outside its range, a range only grows, so the samples inside a window
//! never make one grow, and those outside it reach the histogram in their own order; the counts
//! of the windows are integers, added in any order. So the windows can be flushed and made anew
//! at any point ([`WindowCounts::renew_if_outside`]): when many samples fell outside them (the
//! first frame of a histogram, whose windows are empty, or a patch of new levels), the windows
//! are made again on the ranges the histograms have grown to.
//!
//! Every count is kept [`LANES`] times, side by side, and a sample goes to the lane its caller
//! names (the pixel's column): neighbouring pixels of a flat patch hit the same few values, and
//! one counter incremented by consecutive samples makes each increment wait for the one before.
//! [`LaneCounts`] does the same for plain counts over `0 ..= top` (the output codes).
//!
//! A pixel that is not flat has its own level, [`WindowCounts::not_flat`], whose one-value window
//! at noise 0 takes it and is never read: the caller passes such pixels with noise 0 and needs
//! no branch to skip them.

/// Copies of each count; a power of two.
pub(crate) const LANES: usize = 2;

use crate::model::histogram::NoiseHistogram;

/// A clean level's window: the bin histogram's range when the window was made (`first`, `len`),
/// and `at`, the index in the counts of noise 0 in lane 0 (`(start − first)·LANES`, `start`
/// where its counts begin), so that a sample's count is at `at + n·LANES + lane` with no other
/// arithmetic. Its bin is the level's in the lookup table.
#[derive(Debug, Clone, Copy, Default)]
struct LevelWindow {
    first: i32,
    len: u32,
    at: i64,
}

impl LevelWindow {
    fn new(first: i32, len: u32, start: u32) -> Self {
        Self { first, len, at: (start as i64 - first as i64) * LANES as i64 }
    }

    /// Where the window's counts begin.
    fn start(&self) -> usize {
        (self.at / LANES as i64 + self.first as i64) as usize
    }

    /// The index in the counts of noise `n` in lane 0 (any value when `n` is outside the
    /// window).
    #[inline(always)]
    fn index(&self, n: i32) -> usize {
        self.at.wrapping_add(n as i64 * LANES as i64) as usize
    }
}

/// The counts of one frame, for the clean levels of one position.
pub(crate) struct WindowCounts<'a> {
    /// Per clean level `0 ..= lut.len() − 1`, then the level of the pixels that are not flat.
    levels: Vec<LevelWindow>,
    counts: Vec<u32>,
    /// Level → bin.
    lut: &'a [u16],
    /// The levels the flat pixels have, ascending.
    flat: &'a [u16],
    /// Whether each flat level has a window of its own (else the levels of a bin share one).
    by_level: bool,
    /// Windows by level hold at most this many counts (times [`LANES`]).
    budget: usize,
    /// Whether every sample goes straight to its histogram (32-bit counts could overflow).
    direct: bool,
    /// Samples outside their windows since the windows were made or last checked.
    outside: u64,
}

impl<'a> WindowCounts<'a> {
    /// Empty counts for the clean levels `0 ..= lut.len() − 1` (`lut`: level → bin of `hists`)
    /// over the ranges `hists` cover now. `flat`: the levels the flat pixels have; a window of
    /// their own when their windows hold at most `budget` counts (times [`LANES`]), else their
    /// bins' windows. Where a frame's counts could pass 32 bits (`samples`: the most a frame can
    /// add), there are no windows and every sample goes to its histogram.
    pub(crate) fn new(
        hists: &[NoiseHistogram],
        lut: &'a [u16],
        flat: &'a [u16],
        samples: usize,
        budget: usize,
    ) -> Self {
        let direct = samples >= u32::MAX as usize;
        let own = flat
            .iter()
            .filter_map(|&l| lut.get(l as usize))
            .try_fold(0usize, |a, &bin| a.checked_add(hists.get(bin as usize).map_or(0, |h| h.counts.len())));
        let by_level = !direct && own.is_some_and(|n| n <= budget);
        let mut w = Self { levels: Vec::new(), counts: Vec::new(), lut, flat, by_level, budget, direct, outside: 0 };
        w.make(hists);
        w
    }

    /// Makes the windows on the ranges of `hists`, their counts zero. By level, the flat levels
    /// in turn while the budget lasts (a level past it has no window: its samples go to the
    /// histogram).
    fn make(&mut self, hists: &[NoiseHistogram]) {
        let range = |bin: u16| hists.get(bin as usize).map_or((0, 0), |h| (h.first, h.counts.len()));
        let top = self.lut.len();
        self.levels.clear();
        self.levels.extend(self.lut.iter().map(|&bin| LevelWindow::new(range(bin).0, 0, 0)));
        let mut start = 0u32;
        if self.direct {
            // No windows: every sample to its histogram.
        } else if self.by_level {
            let mut room = self.budget;
            for &l in self.flat.iter().filter(|&&l| (l as usize) < top) {
                let (first, len) = range(self.lut[l as usize]);
                let Some(end) = u32::try_from(len).ok().and_then(|n| start.checked_add(n)) else { break };
                if len > room || end == u32::MAX {
                    break;
                }
                room -= len;
                self.levels[l as usize] = LevelWindow::new(first, len as u32, start);
                start = end;
            }
        } else {
            let mut bin_start = Vec::with_capacity(hists.len());
            for h in hists {
                let Some(end) = u32::try_from(h.counts.len()).ok().and_then(|n| start.checked_add(n)) else { break };
                if end == u32::MAX {
                    break;
                }
                bin_start.push(start);
                start = end;
            }
            for (w, &bin) in self.levels.iter_mut().zip(self.lut) {
                if let Some(&s) = bin_start.get(bin as usize) {
                    let (first, len) = range(bin);
                    *w = LevelWindow::new(first, len as u32, s);
                }
            }
        }
        self.levels.push(LevelWindow::new(0, 1, start));
        self.counts.clear();
        // A power of two, so that [`count_pairs`] can mask its indices instead of checking them.
        self.counts.resize(((start as usize + 1) * LANES).next_power_of_two(), 0);
    }

    /// Whether each flat level has a window of its own, so that [`WindowCounts::flush`] gives
    /// the output codes.
    pub(crate) fn by_level(&self) -> bool {
        self.by_level
    }

    /// The level that stands for the pixels that are not flat (one past the highest level).
    pub(crate) fn not_flat(&self) -> usize {
        self.levels.len() - 1
    }

    /// Adds sample `n` of clean level `level` (at most [`WindowCounts::not_flat`]) in lane
    /// `lane` (any number: taken modulo [`LANES`]). Returns `false` when the sample is outside
    /// the level's window: the caller adds it to its histogram (bin [`WindowCounts::bin`]) and
    /// says so ([`WindowCounts::note_outside`]).
    #[inline(always)]
    pub(crate) fn add(&mut self, level: usize, n: i32, lane: usize) -> bool {
        let lw = self.levels[level];
        if (n.wrapping_sub(lw.first) as u32) < lw.len {
            self.counts[lw.index(n) + (lane & (LANES - 1))] += 1;
            true
        } else {
            false
        }
    }

    /// The bin of a clean level (0 for the not-flat level, whose window takes every sample).
    pub(crate) fn bin(&self, level: usize) -> usize {
        self.lut.get(level).map_or(0, |&b| b as usize)
    }

    /// Counts a sample that fell outside its window.
    pub(crate) fn note_outside(&mut self) {
        self.outside += 1;
    }

    /// After `samples` more samples: when more than an eighth of them (and more than a few)
    /// fell outside their windows, flushes the counts into `hists` (and `codes`, as
    /// [`WindowCounts::flush`]) and makes the windows anew on the histograms' ranges now.
    pub(crate) fn renew_if_outside(&mut self, samples: u64, hists: &mut [NoiseHistogram], codes: Option<&mut [u64]>) {
        let outside = std::mem::take(&mut self.outside);
        if outside > 64 && outside * 8 > samples && !self.direct {
            self.add_counts(hists, codes);
            self.make(hists);
        }
    }

    /// Adds the window's counts into the histograms (which may have grown since), and with
    /// windows by level, the output codes (`level + n`, at most `codes.len() − 1`) into `codes`.
    pub(crate) fn flush(self, hists: &mut [NoiseHistogram], codes: Option<&mut [u64]>) {
        self.add_counts(hists, codes);
    }

    fn add_counts(&self, hists: &mut [NoiseHistogram], codes: Option<&mut [u64]>) {
        let top = self.not_flat();
        let sum = |start: usize, len: u32| {
            self.counts[start * LANES..(start + len as usize) * LANES]
                .chunks_exact(LANES)
                .map(|c| c.iter().map(|&c| c as u64).sum::<u64>())
        };
        if self.by_level {
            let mut codes = codes;
            for (level, w) in self.levels[..top].iter().enumerate().filter(|(_, w)| w.len > 0) {
                let h = &mut hists[self.lut[level] as usize];
                let offset = (w.first - h.first) as usize;
                let window = h.counts[offset..offset + w.len as usize].iter_mut().zip(sum(w.start(), w.len));
                for (i, (o, c)) in window.enumerate().filter(|(_, (_, c))| *c > 0) {
                    *o += c;
                    if let Some(codes) = codes.as_deref_mut() {
                        let code = (level as i64 + w.first as i64 + i as i64).clamp(0, codes.len() as i64 - 1);
                        codes[code as usize] += c;
                    }
                }
            }
        } else {
            // Every level of a bin has the bin's window: one flush per bin.
            let mut done = vec![false; hists.len()];
            for (w, &bin) in self.levels[..top].iter().zip(self.lut).filter(|(w, _)| w.len > 0) {
                if std::mem::replace(&mut done[bin as usize], true) {
                    continue;
                }
                let h = &mut hists[bin as usize];
                let offset = (w.first - h.first) as usize;
                for (o, c) in h.counts[offset..offset + w.len as usize].iter_mut().zip(sum(w.start(), w.len)) {
                    *o += c;
                }
            }
        }
    }
}

/// A row's samples outside their windows, for one position: `(level, noise)` in column order.
pub(crate) type Outside = Vec<(u32, i32)>;

/// Counts one row of two positions, `even` taking the even columns and `odd` the odd ones, as
/// [`WindowCounts::add`] of every pixel in turn (clean level `crow[x]`, at most the window's
/// [`WindowCounts::not_flat`]; noise `noise[x]`; lane the column pair) would, except that the
/// samples outside their windows are not added anywhere but listed in `outside` (even, odd), in
/// column order, for the caller to add to the histograms.
///
/// The one loop of the target accumulation that runs per sample: one pass over the row per
/// position, so that a pass holds one position's tables in registers (both at once spilled
/// them to the stack, a reload per sample); its tables are local slices whose lengths the
/// indexing can be checked against once (the levels end at the not-flat level, the counts are a
/// power of two long), so a sample costs a load of its level's window, a compare and an
/// increment. The positions' counts are apart, so the order of the passes changes nothing.
pub(crate) fn count_pairs(
    even: &mut WindowCounts<'_>,
    odd: &mut WindowCounts<'_>,
    crow: &[u16],
    noise: &[i32],
    outside: [&mut Outside; 2],
) {
    let [out0, out1] = outside;
    let n = crow.len().min(noise.len());
    count_position::<0>(even, &crow[..n], &noise[..n], out0);
    count_position::<1>(odd, &crow[..n], &noise[..n], out1);
}

/// [`count_pairs`] of one position: the columns `x ≡ P (mod 2)` of the row, lane `⌊x/2⌋`.
#[inline(never)]
fn count_position<const P: usize>(w: &mut WindowCounts<'_>, crow: &[u16], noise: &[i32], out: &mut Outside) {
    let nf = w.not_flat();
    let levels = &w.levels[..=nf];
    let mask = w.counts.len() - 1;
    let counts = &mut w.counts[..=mask];
    let n = crow.len().min(noise.len());
    let (crow, noise) = (&crow[..n], &noise[..n]);
    #[inline(always)]
    fn one(
        levels: &[LevelWindow],
        counts: &mut [u32],
        mask: usize,
        nf: usize,
        c: u16,
        n: i32,
        lane: usize,
        out: &mut Outside,
    ) {
        let level = (c as usize).min(nf);
        let lw = levels[level];
        if (n.wrapping_sub(lw.first) as u32) < lw.len {
            counts[(lw.index(n) + lane) & mask] += 1;
        } else {
            out.push((level as u32, n));
        }
    }
    // A column pair per lane, the lanes in turn: each lane is a constant within the loop's body.
    let (whole, pairs) = (n - n % (2 * LANES), 2 * LANES);
    for (c, v) in crow[..whole].chunks_exact(pairs).zip(noise[..whole].chunks_exact(pairs)) {
        for lane in 0..LANES {
            one(levels, counts, mask, nf, c[2 * lane + P], v[2 * lane + P], lane, out);
        }
    }
    for x in (whole..n).filter(|x| x % 2 == P) {
        one(levels, counts, mask, nf, crow[x], noise[x], (x >> 1) & (LANES - 1), out);
    }
}

/// Counts of the values `0 ..= top`, [`LANES`] copies of each, added into `u64` counts at the
/// end. The caller keeps each lane's counts below 2³² (a frame's samples).
pub(crate) struct LaneCounts {
    counts: Vec<u32>,
}

impl LaneCounts {
    pub(crate) fn new(top: usize) -> Self {
        Self { counts: vec![0; (top + 1) * LANES] }
    }

    /// Counts `value` (at most `top`) in lane `lane` (taken modulo [`LANES`]).
    #[inline(always)]
    pub(crate) fn add(&mut self, value: usize, lane: usize) {
        self.counts[value * LANES + (lane & (LANES - 1))] += 1;
    }

    /// Adds the counts into `out` (one per value).
    pub(crate) fn flush(self, out: &mut [u64]) {
        for (o, c) in out.iter_mut().zip(self.counts.chunks_exact(LANES)) {
            *o += c.iter().map(|&c| c as u64).sum::<u64>();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Window counts leave the histograms exactly as adding every sample in turn does, growth
    /// included (samples far outside, below and above, in between samples inside), with windows
    /// by clean level and by bin, made anew within a frame; by clean level they also give the
    /// output codes exactly, and the pixels that are not flat reach neither.
    #[test]
    fn same_histograms_and_codes_as_adding_in_turn() {
        // Levels 0 ..= 39 in bins of four; the flat pixels have some of them.
        let lut: Vec<u16> = (0..40).map(|l| l / 4).collect();
        let flat: Vec<u16> = vec![3, 4, 5, 9, 10, 20, 21, 22, 23, 37];
        let top = 60usize;
        let code = |level: usize, n: i32| (level as i64 + n as i64).clamp(0, top as i64) as usize;
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        let mut samples = Vec::new();
        for k in 0..20_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let spread = if k % 97 == 0 { 400 } else { 20 };
            let level = flat[(s >> 40) as usize % flat.len()] as usize;
            samples.push((level, (s % (2 * spread + 1)) as i32 - spread as i32));
        }
        for (budget, by_level) in [(usize::MAX, true), (0, false)] {
            let mut direct = vec![NoiseHistogram::default(); 10];
            direct[1].add(5);
            let mut windowed = direct.clone();
            let (mut codes_direct, mut codes) = (vec![0u64; top + 1], vec![0u64; top + 1]);
            let mut renewed = 0;
            for frame in samples.chunks(5000) {
                for &(level, n) in frame {
                    direct[lut[level] as usize].add(n);
                    codes_direct[code(level, n)] += 1;
                }
                let mut w = WindowCounts::new(&windowed, &lut, &flat, frame.len(), budget);
                assert_eq!(w.by_level(), by_level);
                for (k, &(level, n)) in frame.iter().enumerate() {
                    assert!(w.add(w.not_flat(), 0, k), "a pixel that is not flat has its window");
                    if !w.add(level, n, k) {
                        windowed[w.bin(level)].add(n);
                        w.note_outside();
                        if by_level {
                            codes[code(level, n)] += 1;
                        }
                    }
                    if !by_level {
                        codes[code(level, n)] += 1;
                    }
                    if k % 100 == 99 {
                        renewed += (w.outside > 64 && w.outside * 8 > 100) as u32;
                        w.renew_if_outside(100, &mut windowed, by_level.then_some(&mut codes[..]));
                    }
                }
                w.flush(&mut windowed, by_level.then_some(&mut codes[..]));
                assert_eq!(direct, windowed);
                assert_eq!(codes_direct, codes);
            }
            assert!(windowed.iter().any(|h| h.counts.len() > 400), "samples outside made a histogram grow");
            assert!(renewed > 0, "the windows were made anew in the first frame");
        }
        // A budget smaller than the flat levels' windows: windows by bin.
        let hists = vec![NoiseHistogram { first: -10, counts: vec![0; 21] }; 10];
        let windows = 21 * flat.len();
        assert!(WindowCounts::new(&hists, &lut, &flat, 100, windows).by_level());
        assert!(!WindowCounts::new(&hists, &lut, &flat, 100, windows - 1).by_level());
        // Too many samples for 32-bit counts: every flat sample straight to its histogram.
        let mut w = WindowCounts::new(&hists, &lut, &flat, u32::MAX as usize, usize::MAX);
        assert!(!w.by_level());
        assert!(!w.add(5, 3, 1));
        assert!(w.add(w.not_flat(), 0, 1));
    }

    /// A row counted by [`count_pairs`] leaves both positions' windows as adding each pixel in
    /// turn does, and lists exactly the samples outside, in column order: rows of odd and even
    /// width, pixels not flat, levels without a window, noise far outside.
    #[test]
    fn count_pairs_is_adding_in_turn() {
        let lut: Vec<u16> = (0..40).map(|l| l / 4).collect();
        let flat: Vec<u16> = vec![3, 4, 5, 9, 10, 20, 21, 22, 23, 37];
        let hists = vec![NoiseHistogram { first: -6, counts: vec![1; 13] }; 10];
        let mut s = 0x2545_F491_4F6C_DD1Du64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        for (width, budget) in [(101usize, usize::MAX), (64, usize::MAX), (98, usize::MAX), (103, 0), (77, 0)] {
            let (mut even, mut odd) = (
                WindowCounts::new(&hists, &lut, &flat, 1000, budget),
                WindowCounts::new(&hists, &lut, &flat, 1000, budget),
            );
            let (mut even_turn, mut odd_turn) = (
                WindowCounts::new(&hists, &lut, &flat, 1000, budget),
                WindowCounts::new(&hists, &lut, &flat, 1000, budget),
            );
            let (mut out, mut out_turn) = ([Vec::new(), Vec::new()], [Vec::new(), Vec::new()]);
            for _row in 0..20 {
                let mut crow = Vec::with_capacity(width);
                let mut noise = Vec::with_capacity(width);
                for _ in 0..width {
                    let r = next();
                    let (c, n) = match r % 10 {
                        // Not flat: the not-flat level, noise 0.
                        0 => (u16::MAX, 0),
                        // A level no flat pixel has (no window by level).
                        1 => (30, (r >> 8) as i32 % 5),
                        // Far outside.
                        2 => (flat[(r >> 8) as usize % flat.len()], 50 + (r >> 20) as i32 % 50),
                        _ => (flat[(r >> 8) as usize % flat.len()], ((r >> 20) % 13) as i32 - 6),
                    };
                    crow.push(c);
                    noise.push(n);
                }
                let [o0, o1] = &mut out;
                o0.clear();
                o1.clear();
                count_pairs(&mut even, &mut odd, &crow, &noise, [o0, o1]);
                out_turn[0].clear();
                out_turn[1].clear();
                for (x, (&c, &n)) in crow.iter().zip(&noise).enumerate() {
                    let w = if x % 2 == 0 { &mut even_turn } else { &mut odd_turn };
                    let level = (c as usize).min(w.not_flat());
                    if !w.add(level, n, x >> 1) {
                        out_turn[x % 2].push((level as u32, n));
                    }
                }
                assert_eq!(out, out_turn, "width {width}");
                assert_eq!(even.counts, even_turn.counts);
                assert_eq!(odd.counts, odd_turn.counts);
            }
            assert!(out_turn.iter().all(|o| !o.is_empty()), "samples fell outside");
            assert!(even.counts.iter().any(|&c| c > 0) && odd.counts.iter().any(|&c| c > 0));
        }
    }
}
