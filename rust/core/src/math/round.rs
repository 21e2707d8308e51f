//! Rounding to integers as `f64::round` and `f64::floor` do, but without the calls to libm's
//! `round` and `floor` that they compile to on x86-64 without SSE4.1: for loops that round once
//! per pixel (the fixed pattern at synthesis, the clean image's levels at calibration) or once
//! per PMF cell (the sampler build's rescaled starts and grid densities).

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

/// [`round_half_away`], faster on values below 2⁵¹ in magnitude (a pattern's 2⁻³² DN): there,
/// adding 1.5·2⁵² rounds to the nearest integer, ties to even, and leaves that integer in the
/// sum's low bits; a tie (`v` half an integer from it) that went toward zero is moved one away.
/// Float adds, compares and an integer subtraction, where the conversion of `round_half_away`
/// checks for overflow and NaN twice. Other values (and NaN) take `round_half_away` itself, a
/// branch that a loop over values of one scale predicts alike every time.
#[inline(always)]
pub fn round_half_away_near(v: f64) -> i64 {
    const SHIFT: f64 = 6755399441055744.0; // 1.5·2⁵²: the sum's unit in the last place is 1.
    if v.abs() < 2251799813685248.0 {
        let m = v + SHIFT;
        let nearest = m.to_bits() as i64 - SHIFT.to_bits() as i64;
        let d = v - (m - SHIFT);
        nearest + ((d >= 0.5) & (v > 0.0)) as i64 - ((d <= -0.5) & (v < 0.0)) as i64
    } else {
        round_half_away(v)
    }
}

/// `v.floor() as i32` (saturating, NaN to 0), without the call to libm's `floor`: the
/// truncation toward zero is one below the floor exactly where it lies above `v` (a negative
/// non-integer), and saturates where the floor's conversion does.
#[inline(always)]
pub fn floor_i32(v: f64) -> i32 {
    let t = v as i32;
    t.saturating_sub((t as f64 > v) as i32)
}

/// `v.floor() as i64` (saturating, NaN to 0), as [`floor_i32`].
#[inline(always)]
pub fn floor_i64(v: f64) -> i64 {
    let t = v as i64;
    t.saturating_sub((t as f64 > v) as i64)
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

    /// Both roundings are `f64::round` exactly: at halves (both signs), next to them, at zero,
    /// at NaN, at and past 2⁵¹ and 2⁵², and on random values of a pattern's and a level's scale.
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
        let two51 = 2251799813685248.0f64;
        for x in [two51, -two51, two51 - 0.5, -two51 + 0.5, two51 - 1.5, two51 * 1.5] {
            vals.extend([x, x.next_down(), x.next_up()]);
        }
        for k in -2000..2000 {
            let h = k as f64 + 0.5;
            vals.extend([h, h.next_down(), h.next_up(), h * 4294967296.0 + 0.5]);
        }
        vals.push(0.49999999999999994);
        vals.push(-0.49999999999999994);
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let unit = |u: u64| (u >> 11) as f64 / (1u64 << 53) as f64;
        vals.extend((0..100_000).map(|_| (unit(rng.next_u64()) - 0.5) * 200.0 * 4294967296.0));
        vals.extend((0..100_000).map(|_| unit(rng.next_u64()) * 20000.0));
        for v in vals {
            assert_eq!(round_half_away(v), v.round() as i64, "{v:e}");
            assert_eq!(round_half_away_near(v), v.round() as i64, "{v:e}");
        }
    }

    /// The floors are `f64::floor`'s, converted: at and next to integers of both signs, at the
    /// ends of both integer types (where the conversion saturates), at NaN and infinities, and
    /// on random values of a PMF support's and a density grid's scale.
    #[test]
    fn floors_are_floor() {
        let mut vals = vec![0.0, -0.0, 0.5, -0.5, 1.0, -1.0, 2.5, -2.5, f64::NAN, f64::INFINITY, f64::NEG_INFINITY];
        vals.extend([f64::MAX, f64::MIN, 1e300, -1e300, 4503599627370496.0, -4503599627370496.0]);
        for b in [i32::MIN as f64, i32::MAX as f64, i64::MIN as f64, i64::MAX as f64, 1.0, -1.0, 7.0, -7.0] {
            vals.extend([b, b.next_down(), b.next_up(), b - 0.5, b + 0.5, b - 1.0, b + 1.0]);
        }
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        let unit = |u: u64| (u >> 11) as f64 / (1u64 << 53) as f64;
        vals.extend((0..100_000).map(|_| (unit(rng.next_u64()) - 0.5) * 2000.0));
        vals.extend((0..100_000).map(|_| (unit(rng.next_u64()) - 0.5) * 1e12));
        vals.extend((0..1000).map(|i| i as f64 * 0.25 - 125.0));
        for v in vals {
            assert_eq!(floor_i32(v), v.floor() as i32, "{v:e}");
            assert_eq!(floor_i64(v), v.floor() as i64, "{v:e}");
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
