//! How precisely a pack keeps a model (method.md, "Pack format"): a pack file stores each bin's
//! PMF in this form, so the model a calibration finishes with (`ModelPack::compacted`) and a
//! model derived on the fly ([`BinModel::from_pmf`](crate::model::pack::BinModel::from_pmf)) are
//! the ones a file loads back.
//!
//! - **Precision** ([`Precision`]): a weight keeps the significant bits its bin's samples justify.
//!   A cell of probability `p` in a bin of `N` samples is measured to a variance of `p/N`; the
//!   weight keeps just enough bits that its rounding error's variance stays below
//!   2^−[`SAMPLING_SHARE_BITS`] of that (at most [`SAMPLED_MAX_BITS`], at least one). The bits
//!   depend only on the weight's own bit length and the bin's sample count, so a file need not
//!   store them ([`Precision::bits`]).
//! - **Rounding** ([`store_bin`]): error diffusion from the left, each cell rounded to the
//!   nearest value its bits can hold after the rounding error of the cells before it is added
//!   back. The stored CDF then stays within half a step of the exact one at every cell, so the
//!   mean and variance stay (plain rounding half up lowers a decaying tail on average: 3.8 % at
//!   one bit). Integers only, the same on every machine. No kept weight becomes 0.
//! - **Tails** ([`measurable_span`]): each side keeps its cells out to the last one holding at
//!   least 2^−[`TAIL_BITS`] of the bin's largest weight.
//!
//! All three apply to the estimated bins of calibrated models; a plain histogram (a `--plain`
//! pack, or a pack older than the estimator) keeps [`MANTISSA_BITS`] throughout, its sample count
//! not being a scale of its weights. A derived model (interpolated, extrapolated, parametric)
//! keeps every weight to [`DERIVED_BITS`] significant bits, rounded half up, and its tails whole,
//! as derived models always were: an image synthesized at a derived ISO of an unchanged pack
//! keeps its bytes.
//!
//! What it costs is measured in `rust/core/tests/pack_compact.rs` (held-out cross-entropy
//! against the exact pack's, synthesized images' variance and extreme quantiles).

/// Significant bits the largest weight of a bin keeps.
pub const MANTISSA_BITS: u32 = 7;

/// `w` rounded to [`MANTISSA_BITS`] significant bits (half up; down where up would pass
/// `u64::MAX`).
pub fn quantize(w: u64) -> u64 {
    quantize_to(w, MANTISSA_BITS)
}

/// `w` rounded to `keep` (≥ 1) significant bits, as [`quantize`] does.
pub fn quantize_to(w: u64, keep: u32) -> u64 {
    let bits = 64 - w.leading_zeros();
    if bits <= keep {
        return w;
    }
    let e = bits - keep;
    let up = ((w as u128 + (1u128 << (e - 1))) >> e) << e;
    if up > u64::MAX as u128 { (w >> e) << e } else { up as u64 }
}

/// Each side of a bin's PMF keeps its cells out to the last one that holds at least
/// 2^−TAIL_BITS of the bin's largest weight: farther out a tail holds no mass a calibration
/// measures (a decaying tail beyond that point holds about 2^−TAIL_BITS of the bin's mass), and
/// the sampler's tables would carry cells it draws about once in 10⁸ pixels.
pub const TAIL_BITS: u32 = 20;

/// The cells `lo ..= hi` of `w` from the first to the last one of at least 2^−`bits` of the
/// largest (integers only); `None` for all zeros. Cutting there is idempotent: the largest
/// weight stays, so a cut PMF cuts to itself.
pub fn measurable_span(w: &[u64], bits: u32) -> Option<(usize, usize)> {
    let max = *w.iter().max()? as u128;
    if max == 0 {
        return None;
    }
    let holds = |c: &u64| (*c as u128) << bits >= max;
    Some((w.iter().position(holds)?, w.iter().rposition(holds)?))
}

/// Significant bits every weight of a derived (interpolated, extrapolated or parametric) model
/// keeps, its tails whole: derived as they always were, so an image synthesized at a derived ISO
/// of an older pack keeps its bytes.
pub const DERIVED_BITS: u32 = 9;

/// A derived model's weight as a pack keeps it.
pub fn quantize_derived(w: u64) -> u64 {
    quantize_to(w, DERIVED_BITS)
}

/// The rounding error's variance is at most 2^−SAMPLING_SHARE_BITS of a cell's sampling variance
/// (its standard deviation 1/8 of the sampling's): the held-out cross-entropy it adds is about
/// `cells / (2^(SAMPLING_SHARE_BITS+1) · N)` nats per sample.
pub const SAMPLING_SHARE_BITS: i32 = 6;

/// The most significant bits a weight of an estimated bin keeps: what the rule asks of the
/// largest weight of a narrow PMF measured from 10⁷ samples (a bin of 10⁶ asks 12 of a peak near
/// ½; capped at 7, such a bin's variance moved by 0.4 %, three times its sampling noise).
pub const SAMPLED_MAX_BITS: u32 = 13;

/// A bin with fewer samples of its own (a filled bin has none) is kept as precisely as one with
/// this many: its PMF comes from its neighbours, and synthesis at its levels draws from it.
pub const MIN_SAMPLES: u64 = 1 << 12;

/// An estimated bin's weights are probabilities × 2^SCALE_BITS
/// ([`BinModel::estimated`](crate::model::pack::BinModel::estimated)).
pub const SCALE_BITS: i32 = 30;

/// The significant bits a bin's weights keep, as a function of each weight's bit length `L`:
/// `clamp(⌈(L + shift)/2⌉, 1, cap)`. A fixed precision keeps `cap` bits at every length.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Precision {
    shift: i32,
    cap: u32,
}

impl Precision {
    /// Every weight to `bits` significant bits.
    pub const fn fixed(bits: u32) -> Self {
        Self { shift: 128, cap: bits }
    }

    /// An estimated bin of `samples` samples of its own. A weight `w` of bit length `L` is about
    /// `p·2^SCALE_BITS` with `p ≥ 2^(L−1−SCALE_BITS)`; rounded to `k` bits its error's variance is at
    /// most `2^(2(L−k))/12`, and its sampling variance is `w·2^SCALE_BITS/N`. Keeping the first
    /// below 2^−SAMPLING_SHARE_BITS of the second needs `2k ≥ L + 1 + lg N + SAMPLING_SHARE_BITS −
    /// lg 12 − SCALE_BITS`; `lg N` is rounded up and `lg 12` down to 3, so the bound holds.
    pub fn for_samples(samples: u64) -> Self {
        let n = samples.max(MIN_SAMPLES);
        let lg_n_up = 64 - (n - 1).leading_zeros() as i32;
        Self { shift: 1 + lg_n_up + SAMPLING_SHARE_BITS - 3 - SCALE_BITS, cap: SAMPLED_MAX_BITS }
    }

    /// Significant bits a weight of bit length `len` keeps.
    pub fn bits(&self, len: u32) -> u32 {
        let k = (len as i32).saturating_add(self.shift).saturating_add(1).div_euclid(2);
        k.clamp(1, self.cap as i32) as u32
    }

    /// The nearest value at or above 1 these bits hold to `t` (half up; down where up would pass
    /// `u64::MAX`).
    pub fn round(&self, t: u64) -> u64 {
        let t = t.max(1);
        quantize_to(t, self.bits(64 - t.leading_zeros()))
    }

    /// The values these bits hold next to `w ≥ 1`: the largest at or below it and the smallest at
    /// or above it (the same when `w` is held; below only where above would pass `u64::MAX`).
    pub fn bracket(&self, w: u64) -> (u64, u64) {
        let w = w.max(1);
        let len = 64 - w.leading_zeros();
        let drop = len - self.bits(len).min(len);
        let down = (w >> drop) << drop;
        let up = (((w as u128) + (1u128 << drop) - 1) >> drop) << drop;
        (down, if up > u64::MAX as u128 { down } else { up as u64 })
    }

    /// Whether `w` is a value these bits hold (0 included).
    pub fn holds(&self, w: u64) -> bool {
        w == 0 || self.round(w) == w
    }
}

/// The precision a calibrated model's bin keeps: by its samples when the estimator made it
/// (`estimated`), else [`MANTISSA_BITS`] throughout.
pub fn bin_precision(estimated: bool, samples: u64) -> Precision {
    if estimated { Precision::for_samples(samples) } else { Precision::fixed(MANTISSA_BITS) }
}

/// Rounds `cells` in order by error diffusion and returns the error left over (exact − stored,
/// summed): each cell takes whichever of the two values next to its own weight that `precision`
/// holds ([`Precision::bracket`]) lies nearer its weight plus the error carried so far (half up),
/// so no cell moves by more than its own step (a weight next to a much larger one is not zeroed
/// by that one's error) and the error carried stays below the largest step passed.
fn diffuse<'a>(cells: impl Iterator<Item = &'a mut u64>, precision: Precision) -> i128 {
    let mut carry: i128 = 0;
    for w in cells.filter(|w| **w != 0) {
        let (down, up) = precision.bracket(*w);
        let t = *w as i128 + carry;
        let q = if t - (down as i128) < (up as i128) - t { down } else { up };
        carry = t - q as i128;
        *w = q;
    }
    carry
}

/// Puts one bin's weights in their stored form: rounded by error diffusion to the bits `precision`
/// gives each, from either end in towards the bin's largest weight, which takes what is left
/// over (the error flows from small weights to larger ones, so no tail cell takes more than its
/// own step); then the tails cut to [`measurable_span`] at [`TAIL_BITS`]. The stored CDF stays
/// within half a step of the exact one left of the peak, and the stored survival function right
/// of it. Idempotent: weights already held by their bits round to themselves with nothing
/// carried, the largest stays the largest (the first of equals), and the cut keeps it.
pub fn store_bin(first: &mut i32, counts: &mut Vec<u64>, precision: Precision) {
    round_by_diffusion(counts, precision);
    cut_tails(first, counts);
}

/// The rounding of [`store_bin`] alone (no cut): each weight to the bits `precision` gives it,
/// by error diffusion from either end in towards the largest weight, which takes what is left.
/// Also rounds the cell masses of a coarse grid ([`crate::model::coarse_grid`]), a mass being
/// measured to the same variance `p/N` as a weight.
pub fn round_by_diffusion(counts: &mut [u64], precision: Precision) {
    let Some(peak) = counts
        .iter()
        .enumerate()
        .filter(|&(_, &w)| w > 0)
        .max_by_key(|&(i, &w)| (w, std::cmp::Reverse(i)))
        .map(|(i, _)| i)
    else {
        return;
    };
    let (left, rest) = counts.split_at_mut(peak);
    let (top, right) = rest.split_first_mut().expect("the peak");
    let carry = diffuse(left.iter_mut(), precision) + diffuse(right.iter_mut().rev(), precision);
    // The largest weight takes what is left, to the nearest value held (it stays the largest:
    // the error is below the largest step passed, which is at most its own).
    *top = precision.round((*top as i128 + carry).clamp(1, u64::MAX as i128) as u64);
}

/// Cuts both tails of `counts` to [`measurable_span`] at [`TAIL_BITS`], moving `first` with the
/// left cut.
pub fn cut_tails(first: &mut i32, counts: &mut Vec<u64>) {
    if let Some((lo, hi)) = measurable_span(counts, TAIL_BITS)
        && (lo > 0 || hi + 1 < counts.len())
    {
        counts.truncate(hi + 1);
        counts.drain(..lo);
        *first += lo as i32;
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Weights that probe rounding: every small one, the edges of 9 and 10 bits, large and extreme
    /// ones, and 20 000 spread over every magnitude (a fixed LCG).
    pub(crate) fn rounding_probe_weights() -> Vec<u64> {
        let mut ws: Vec<u64> = (0..5000).collect();
        ws.extend([511, 512, 513, 1023, 1024, 1025, 1 << 30, (1 << 30) + 12345, 987_654_321]);
        ws.extend([u64::MAX, u64::MAX - 1, 1 << 63]);
        let mut state = 7u64;
        for _ in 0..20000 {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ws.push(state >> (state % 60));
        }
        ws
    }

    /// `quantize_to(·, bits)` is idempotent, exact below `2^bits` and within `2^−bits` relative
    /// error everywhere, over [`rounding_probe_weights`]; gives the rounded weights.
    pub(crate) fn assert_rounds_to_bits(bits: u32) -> Vec<(u64, u64)> {
        let mut out = Vec::new();
        for w in rounding_probe_weights() {
            let q = quantize_to(w, bits);
            assert_eq!(quantize_to(q, bits), q, "idempotent at {w} ({bits} bits)");
            if w < 1 << bits {
                assert_eq!(q, w);
            }
            let err = (q as f64 - w as f64).abs() / (w.max(1) as f64);
            assert!(err <= 1.0 / (1u64 << bits) as f64 + 1e-15, "{w} → {q} ({bits} bits)");
            out.push((w, q));
        }
        out
    }

    #[test]
    fn weights_round_to_their_significant_bits() {
        assert_rounds_to_bits(MANTISSA_BITS);
        assert_rounds_to_bits(DERIVED_BITS);
        for w in rounding_probe_weights() {
            assert_eq!(quantize(w), quantize_to(w, MANTISSA_BITS));
        }
    }

    /// The bits a sample count asks for hold the rounding error's variance (step²/12) below
    /// 2^−SAMPLING_SHARE_BITS of the cell's sampling variance (w·2^SCALE_BITS/N), and are not
    /// more than two bits above the fewest that do (the rule rounds `lg N` up, `lg 12` down and
    /// takes each weight at the bottom of its bit length).
    #[test]
    fn bits_follow_the_sampling_variance() {
        let share = (1u64 << SAMPLING_SHARE_BITS) as f64;
        let mut state = 11u64;
        for _ in 0..50_000 {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            let w = (state >> 34).max(1) >> (state % 29);
            let n = 1u64 << ((state >> 8) % 26);
            let p = Precision::for_samples(n);
            let w = w.max(1);
            let len = 64 - w.leading_zeros();
            let k = p.bits(len);
            let step = |k: u32| 2f64.powi(len as i32 - k.min(len) as i32);
            let sampling = w as f64 * (1u64 << SCALE_BITS) as f64 / n.max(MIN_SAMPLES) as f64;
            if k < SAMPLED_MAX_BITS {
                assert!(step(k).powi(2) / 12.0 <= sampling / share, "w {w} N {n}: {k} bits");
            }
            if k > 3 && k < len {
                assert!(step(k - 3).powi(2) / 12.0 > sampling / share, "w {w} N {n}: {k} bits, fewer would do");
            }
        }
    }
}
