//! One frame's histogram counts for one CFA position, in a flat table: every bin's window is
//! the range its [`NoiseHistogram`] covered when the frame began, its counts 32-bit and laid end
//! to end, and every clean level has its bin's window beside the bin ([`LevelWindow`]), so that
//! a sample costs one lookup by its clean level and one increment, with no pointer to follow. A
//! sample outside its bin's window goes straight to the histogram.
//!
//! The histograms end as they would have with every sample added to them in turn: a histogram
//! only grows for a sample outside its range, a range only grows, so the samples inside the
//! frame's first window never make one grow, and those outside it reach the histogram in their
//! own order; [`WindowCounts::flush`] then adds the window's counts (integers: in any order).
//!
//! Every count is kept [`LANES`] times, side by side, and a sample goes to the lane its caller
//! names (the pixel's column): neighbouring pixels of a flat patch hit the same few values, and
//! one counter incremented by consecutive samples makes each increment wait for the one before.
//! [`LaneCounts`] does the same for plain counts over `0 ..= top` (the output codes).

/// Copies of each count; a power of two.
pub(crate) const LANES: usize = 4;

use crate::model::histogram::NoiseHistogram;

/// A bin's window: its histogram's range at the frame's start, and where its counts begin.
#[derive(Debug, Clone, Copy)]
struct Window {
    first: i32,
    len: u32,
    start: u32,
}

/// A clean level's bin and that bin's [`Window`], for [`WindowCounts::add_level`].
#[derive(Debug, Clone, Copy)]
pub(crate) struct LevelWindow {
    first: i32,
    len: u32,
    start: u32,
    bin: u32,
}

/// The counts of one frame, for the bins of one position.
pub(crate) struct WindowCounts {
    windows: Vec<Window>,
    counts: Vec<u32>,
}

impl WindowCounts {
    /// Empty counts over the ranges `hists` cover now. Where a frame's counts could pass 32
    /// bits (`samples`: the most a frame can add), or the windows would not fit one table, the
    /// windows are empty and every sample goes to its histogram.
    pub(crate) fn new(hists: &[NoiseHistogram], samples: usize) -> Self {
        Self::windowed(hists, samples).unwrap_or_else(|| Self {
            windows: hists.iter().map(|h| Window { first: h.first, len: 0, start: 0 }).collect(),
            counts: Vec::new(),
        })
    }

    fn windowed(hists: &[NoiseHistogram], samples: usize) -> Option<Self> {
        if samples >= u32::MAX as usize {
            return None;
        }
        let mut start = 0u32;
        let mut windows = Vec::with_capacity(hists.len());
        for h in hists {
            let len = u32::try_from(h.counts.len()).ok()?;
            windows.push(Window { first: h.first, len, start });
            start = start.checked_add(len)?;
        }
        Some(Self { windows, counts: vec![0; start as usize * LANES] })
    }

    /// Per clean level `0 .. lut.len()`, the window of its bin (`lut`: level → bin), so that a
    /// sample costs one lookup by its clean level ([`WindowCounts::add_level`]).
    pub(crate) fn by_level(&self, lut: &[u16]) -> Vec<LevelWindow> {
        lut.iter()
            .map(|&bin| {
                let w = self.windows.get(bin as usize).copied().unwrap_or(Window { first: 0, len: 0, start: 0 });
                LevelWindow { first: w.first, len: w.len, start: w.start, bin: bin as u32 }
            })
            .collect()
    }

    /// Adds sample `n` in lane `lane` (any number: taken modulo [`LANES`]) to the bin whose
    /// window `lw` is (from [`WindowCounts::by_level`]); its histogram in `hists` takes a sample
    /// outside the window.
    #[inline(always)]
    pub(crate) fn add_level(&mut self, lw: LevelWindow, n: i32, lane: usize, hists: &mut [NoiseHistogram]) {
        let i = n.wrapping_sub(lw.first) as u32;
        if i < lw.len {
            self.counts[(lw.start + i) as usize * LANES + (lane & (LANES - 1))] += 1;
        } else {
            hists[lw.bin as usize].add(n);
        }
    }

    /// Adds the window's counts into the histograms (which may have grown since).
    pub(crate) fn flush(self, hists: &mut [NoiseHistogram]) {
        for (w, h) in self.windows.iter().zip(hists).filter(|(w, _)| w.len > 0) {
            let counts = &self.counts[w.start as usize * LANES..(w.start + w.len) as usize * LANES];
            let offset = (w.first - h.first) as usize;
            for (o, c) in h.counts[offset..offset + w.len as usize].iter_mut().zip(counts.chunks_exact(LANES)) {
                *o += c.iter().map(|&c| c as u64).sum::<u64>();
            }
        }
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
    /// included (samples far outside, below and above, in between samples inside).
    #[test]
    fn same_histograms_as_adding_in_turn() {
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        let mut samples = Vec::new();
        for k in 0..20_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let spread = if k % 97 == 0 { 400 } else { 20 };
            samples.push(((s >> 3) as usize % 3, (s % (2 * spread + 1)) as i32 - spread as i32));
        }
        let mut direct = vec![NoiseHistogram::default(); 3];
        direct[1].add(5);
        let mut windowed = direct.clone();
        for frame in samples.chunks(5000) {
            for &(bin, n) in frame {
                direct[bin].add(n);
            }
            let mut w = WindowCounts::new(&windowed, frame.len());
            // Levels 0..6 in bins of two.
            let levels = w.by_level(&[0, 0, 1, 1, 2, 2]);
            for (lane, &(bin, n)) in frame.iter().enumerate() {
                let level = 2 * bin + lane % 2;
                w.add_level(levels[level], n, lane, &mut windowed);
            }
            w.flush(&mut windowed);
            assert_eq!(direct, windowed);
        }
        // Too many samples for 32-bit counts: every sample straight to its histogram.
        let mut w = WindowCounts::new(&windowed, u32::MAX as usize);
        let levels = w.by_level(&[0, 0, 1, 1, 2, 2]);
        w.add_level(levels[1], 3, 1, &mut windowed);
        direct[0].add(3);
        w.flush(&mut windowed);
        assert_eq!(direct, windowed);
    }
}
