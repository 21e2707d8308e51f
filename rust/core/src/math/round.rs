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

/// `round(s / m)` with halves up, for many `u32` sums `s` over one divisor `m ≥ 1` (a burst's
/// per-pixel mean): a product gives the quotient to within one, an integer comparison makes it
/// exact, so no value takes a division. Up to `m = 2¹⁶` this is `round_half_away(s as f64 / m)`
/// to the bit (a quotient that is not a half-integer lies at least `1/(2m)` from one, far beyond
/// the division's rounding); beyond that divisor, and for `m = 0`, it is that expression.
#[derive(Debug, Clone, Copy)]
pub struct RoundedQuotient {
    m: u64,
    inv: f64,
}

impl RoundedQuotient {
    pub fn new(m: u32) -> Self {
        Self { m: m as u64, inv: 1.0 / m as f64 }
    }

    #[inline(always)]
    pub fn of(&self, s: u32) -> i64 {
        if self.m == 0 || self.m > 1 << 16 {
            return round_half_away(s as f64 / self.m as f64);
        }
        // ⌊(2s + m) / 2m⌋: `k` is within one of it (the product is within 10⁻⁶ of s / m), and
        // `k · 2m` stays below 2⁵¹.
        let (n, d) = (2 * s as u64 + self.m, 2 * self.m);
        let k = (s as f64 * self.inv + 0.5) as u64;
        let k = k - (k * d > n) as u64;
        (k + ((k + 1) * d <= n) as u64) as i64
    }
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

    /// `RoundedQuotient` is `round_half_away(s as f64 / m)`: for every divisor up to 64 on
    /// every sum up to 64·4096 (all the halves), for burst lengths up to 60 000 and the divisors
    /// past 2¹⁶ on random sums and sums next to halves and to `u32::MAX`.
    #[test]
    fn rounded_quotient_is_the_division() {
        let float = |s: u32, m: u32| round_half_away(s as f64 / m as f64);
        for m in 1..=64u32 {
            let r = RoundedQuotient::new(m);
            for s in 0..=64 * 4096u32 {
                assert_eq!(r.of(s), float(s, m), "{s} / {m}");
            }
        }
        let mut rng = ChaCha8Rng::seed_from_u64(26);
        let mut halves = 0;
        for m in [65u32, 100, 255, 1000, 4097, 60_000, 65_535, 65_536, 65_537, 1 << 20, u32::MAX, 0] {
            let r = RoundedQuotient::new(m);
            let mut sums: Vec<u32> = (0..50_000).map(|_| rng.next_u32()).collect();
            for k in [0u64, 1, 7, 1000, 65_534, 65_535] {
                let half = k * 2 * m as u64 + m as u64; // 2s = (2k + 1)·m
                if half.is_multiple_of(2) && half / 2 <= u32::MAX as u64 {
                    let s = (half / 2) as u32;
                    sums.extend([s.saturating_sub(1), s, s.saturating_add(1)]);
                    halves += 1;
                }
            }
            sums.extend([0, 1, u32::MAX - 1, u32::MAX]);
            for s in sums {
                assert_eq!(r.of(s), float(s, m), "{s} / {m}");
            }
        }
        assert!(halves >= 20, "{halves} exact halves");
    }
}
