//! The motion probe's anchors (flat pixels of the sampled rows) as one bit per pixel of a band
//! of rows, thinned to the few registration reads without listing them first. Every flat pixel
//! of every fourth row pair is an anchor (3 M at 12 MP) and about a thousand are kept: as a list
//! of (pixel, noise SD) they were 24 MB of fresh pages per reference burst, a sixth of
//! `noisecal calibrate`'s page faults; as bits 1.5 MB.

/// One band's anchors: bit `i − first_pixel` set for each anchor pixel `i` (row-major indices).
#[derive(Debug)]
pub(super) struct AnchorBits {
    /// The band's first pixel (its first row's first column).
    first_pixel: usize,
    bits: Vec<u64>,
}

impl AnchorBits {
    /// No anchor yet in a band of `pixels` pixels from `first_pixel` on.
    pub(super) fn new(first_pixel: usize, pixels: usize) -> Self {
        Self { first_pixel, bits: vec![0; pixels.div_ceil(64)] }
    }

    /// Marks pixel `i` (in the band, each at most once) an anchor.
    #[inline(always)]
    pub(super) fn set(&mut self, i: usize) {
        let b = i - self.first_pixel;
        self.bits[b / 64] |= 1 << (b % 64);
    }

    /// Anchors set: the bits counted (once per band, at thinning; a counter in [`AnchorBits::set`]
    /// was an increment per flat pixel of the sampled rows). The words of the rows not sampled
    /// (three row pairs in four) are zero and skipped: without the CPU's `popcnt` (the baseline
    /// x86-64 build) a count is a dozen instructions.
    fn count(&self) -> usize {
        self.bits.iter().filter(|&&w| w != 0).map(|w| w.count_ones() as usize).sum()
    }
}

/// Every k-th anchor of the bands in pixel order (counted across the bands, from the first), so
/// that at most `max` remain: the thinning of the joined list of anchors.
pub(super) fn thin_anchors(bands: &[AnchorBits], max: usize) -> Vec<u32> {
    let total: usize = bands.iter().map(AnchorBits::count).sum();
    let k = if total <= max { 1 } else { total.div_ceil(max) };
    let mut out = Vec::with_capacity(total.div_ceil(k));
    // The global index of the next anchor.
    let mut g = 0usize;
    for band in bands {
        for (wi, &word) in band.bits.iter().enumerate() {
            if word == 0 {
                continue;
            }
            let n = word.count_ones() as usize;
            // No multiple of k among this word's anchors: skip it whole.
            if g.next_multiple_of(k) >= g + n {
                g += n;
                continue;
            }
            let mut word = word;
            while word != 0 {
                if g.is_multiple_of(k) {
                    out.push((band.first_pixel + wi * 64 + word.trailing_zeros() as usize) as u32);
                }
                g += 1;
                word &= word - 1;
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// Every k-th of `v` so that at most `max` remain: what `thin_anchors` stands for.
    fn thin(v: &[u32], max: usize) -> Vec<u32> {
        let k = if v.len() <= max { 1 } else { v.len().div_ceil(max) };
        v.iter().step_by(k).copied().collect()
    }

    /// The kept anchors are exactly every k-th of the joined list of anchor pixels, for bands
    /// of any length (empty ones, lengths not multiples of 64, dense and sparse anchors) and
    /// any `max`: a thinning that restarted its count at each band or word, skipped a word
    /// holding a kept anchor, or misplaced a bit differs.
    #[test]
    fn thinning_bits_is_thinning_the_list() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut thinned = 0;
        for _ in 0..2000 {
            let mut start = rng.random_range(0..100);
            let mut list = Vec::new();
            let bands: Vec<AnchorBits> = (0..rng.random_range(0..8))
                .map(|_| {
                    let pixels = if rng.random_bool(0.2) { 0 } else { rng.random_range(1..700) };
                    let density = rng.random_range(0.0..1.0);
                    let mut b = AnchorBits::new(start, pixels);
                    for i in start..start + pixels {
                        if rng.random_bool(density) {
                            b.set(i);
                            list.push(i as u32);
                        }
                    }
                    start += pixels;
                    b
                })
                .collect();
            let max = rng.random_range(1..300);
            assert_eq!(thin_anchors(&bands, max), thin(&list, max), "{} anchors, max {max}", list.len());
            thinned += usize::from(list.len() > max);
        }
        assert!(thinned > 500, "{thinned}");
    }
}
