//! How precisely a pack keeps a model (method.md, "Pack format"): a pack file stores each bin's
//! PMF in this form, so the model a calibration finishes with (`ModelPack::compacted`) and a
//! model derived on the fly ([`BinModel::from_pmf`](crate::model::pack::BinModel::from_pmf)) are
//! the ones a file loads back.
//!
//! - **Rounding** ([`store_bin`]): the bin's largest weight keeps [`MANTISSA_BITS`] significant
//!   bits, every other weight one bit less per [`FADE_BITS`] binary orders below it, down to
//!   [`MIN_BITS`] ([`kept_bits`]; round half up in integers, no floating point, so the same on every
//!   machine). No weight becomes 0, so no value of the kept support loses its probability; a
//!   weight kept to `k` bits moves by at most 2^−k of itself.
//! - **Tails** ([`measurable_span`]): each side keeps its cells out to the last one holding at
//!   least 2^−[`TAIL_BITS`] of the bin's largest weight.
//!
//! Both apply to calibrated models. A derived model (interpolated, extrapolated, parametric)
//! keeps every weight to [`DERIVED_BITS`] significant bits and its tails whole, as derived models
//! always were: an image synthesized at a derived ISO of an unchanged pack keeps its bytes.
//!
//! What it costs is measured: on independent held-out sessions the cross-entropy moves by
//! −4·10⁻⁴ … −1·10⁻⁵ of itself (the budget is 1 %), and images
//! synthesized from a stored pack match those of the exact one within the noise of the fidelity
//! figures (`rust/core/tests/pack_compact.rs`).

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

/// A weight keeps one significant bit less for every `FADE_BITS` binary orders it lies below its
/// bin's largest (down to one bit): the relative error a cell's probability is measured with
/// grows as `1/√(N·p)`, so a cell far below the peak is known to fewer bits than the peak is.
pub const FADE_BITS: u32 = 2;

/// The fewest significant bits a weight keeps (now every weight: [`MANTISSA_BITS`]). Fewer bits
/// below the peak were tried and left out: rounding half up in linear terms lowers weights spread
/// evenly in log terms (a decaying tail) on average, by 3.8 % at one bit, 1.1 % at two, 0.28 % at
/// three, and 6 bits at the peak fading to 1 or 3 moved a bin's variance by 0.7 % (the session
/// tests' flicker check, `tests/e2e/tests/session.rs`, failed), though it halved the file.
pub const MIN_BITS: u32 = 7;

/// The significant bits a weight `w` keeps in a bin whose largest weight has `top` bits.
pub fn kept_bits(w: u64, top: u32) -> u32 {
    let below = top.saturating_sub(64 - w.leading_zeros());
    MANTISSA_BITS.saturating_sub(below / FADE_BITS).max(MIN_BITS)
}

/// Puts one bin's weights in their stored form: each rounded to the bits [`kept_bits`] gives it
/// (the bin's largest to [`MANTISSA_BITS`]), then the tails cut to [`measurable_span`] at
/// [`TAIL_BITS`]. Idempotent: the largest weight keeps its bit length through the rounding, a
/// rounded weight only gains bits to keep, and the cut keeps the largest.
pub fn store_bin(first: &mut i32, counts: &mut Vec<u64>) {
    let top = counts.iter().max().map_or(0, |&m| 64 - quantize(m).leading_zeros());
    for w in counts.iter_mut() {
        *w = quantize_to(*w, kept_bits(*w, top));
    }
    if let Some((lo, hi)) = measurable_span(counts, TAIL_BITS)
        && (lo > 0 || hi + 1 < counts.len())
    {
        counts.truncate(hi + 1);
        counts.drain(..lo);
        *first += lo as i32;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_round_to_their_significant_bits() {
        let mut ws: Vec<u64> = (0..5000).collect();
        ws.extend([511, 512, 513, 1023, 1024, 1025, 1 << 30, (1 << 30) + 12345, 987_654_321, u64::MAX, 1 << 63]);
        let mut state = 7u64;
        for _ in 0..20000 {
            state = state.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            ws.push(state >> (state % 60));
        }
        for &w in &ws {
            let q = quantize(w);
            assert_eq!(quantize(q), q, "idempotent at {w}");
            if w < 1 << MANTISSA_BITS {
                assert_eq!(q, w);
            }
            let err = (q as f64 - w as f64).abs() / (w.max(1) as f64);
            assert!(err <= 1.0 / (1u64 << MANTISSA_BITS) as f64 + 1e-15, "{w} → {q}");
        }
    }
}
