//! Rounding to the nearest integer, halves away from zero, as `f64::round` does but without the
//! call to libm's `round` that it compiles to on x86-64 without SSE4.1: for loops that round
//! once per pixel (the fixed pattern at synthesis, the clean image's levels at calibration).

/// `v.round() as i64` (halves away from zero, saturating, NaN to 0), without the call to libm's
/// `round` that `f64::round` is on x86-64 without SSE4.1, and without a branch, so that loops
/// of it need no call at all: below 2⁵² the fraction `v − trunc(v)` is exact and says which way
/// to go; from 2⁵² on every `f64` is an integer (the fraction is 0), and beyond `i64` the
/// truncation saturates as `round` does.
#[inline(always)]
pub fn round_half_away(v: f64) -> i64 {
    let t = v as i64;
    let r = v - t as f64;
    t.saturating_add((r >= 0.5) as i64).saturating_sub((r <= -0.5) as i64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The rounding is `f64::round` exactly: at halves (both signs), next to them, at zero, at
    /// NaN, past 2⁵², and on random values of a pattern's and a level's scale.
    #[test]
    fn round_half_away_is_round() {
        let two52 = 4503599627370496.0f64;
        let two63 = 9223372036854775808.0f64;
        let mut vals = vec![0.0, -0.0, 0.5, -0.5, 1.5, -1.5, 2.5, -2.5, f64::NAN, 1e17, -1e17, 4.0e15, -4.0e15];
        vals.extend([f64::INFINITY, f64::NEG_INFINITY, 1e300, -1e300, two63, -two63, f64::MAX, f64::MIN]);
        for b in [two52, two63, 4.0e15] {
            for x in [b, -b] {
                vals.extend([x.next_down(), x.next_up(), x - 0.5, x + 0.5, x - 1.5]);
            }
        }
        for h in [0.5f64, 1.5, 12345.5, -0.5, -7.5] {
            vals.extend([h.next_down(), h.next_up()]);
        }
        vals.push(0.49999999999999994);
        vals.push(-0.49999999999999994);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let unit = |u: u64| (u >> 11) as f64 / (1u64 << 53) as f64;
        vals.extend((0..100_000).map(|_| (unit(rng.next_u64()) - 0.5) * 200.0 * 4294967296.0));
        vals.extend((0..100_000).map(|_| unit(rng.next_u64()) * 20000.0));
        for v in vals {
            assert_eq!(round_half_away(v), v.round() as i64, "{v:e}");
        }
    }
}
