//! The flat test's spread check on the burst's integers: a pixel whose own variance over the
//! burst exceeds its level's limit did not hold still ([`crate::calibrate::flat`]). The variance
//! is a floating-point expression with two divisions per pixel ([`burst_variance`]); every
//! pixel of a 12 MP clean image is checked, so [`SpreadLimit::beyond`] decides on the exact
//! integer numerator where that is far from the limit, and leaves the rare pixels close to it to
//! the expression itself: the same answer at every pixel, without the divisions.

/// A pixel's variance over an `m`-frame burst (`m ≥ 2`) from the burst's per-pixel sum, first
/// frame and `Σ(frame − first)²` (saturating: `u32::MAX` reads as infinite), as the flat test
/// defines it: `(sq − (Σd)² / m) / (m − 1)` with `Σd = sum − m · first`, in `f64`.
#[inline]
pub(crate) fn burst_variance(sum: u32, first: u16, sq: u32, m: u32) -> f64 {
    let mf = m as i64;
    let sum_d = sum as i64 - mf * first as i64;
    if sq == u32::MAX {
        return f64::INFINITY;
    }
    (sq as f64 - (sum_d as f64).powi(2) / mf as f64) / (mf - 1) as f64
}

/// How far (relative to the numerator's scale `sq · m`) the exact numerator must lie from the
/// limit to decide: far beyond the expression's rounding (a few units in the last place of
/// `sq`, over the cancellation of its subtraction) and the products' below.
const MARGIN: f64 = 1e-9;

/// One level's spread limit for an `m`-frame burst, ready for [`SpreadLimit::beyond`].
#[derive(Debug, Clone, Copy)]
pub(crate) struct SpreadLimit {
    /// The limit (variance, DN²), as the flat test compares it.
    limit: f32,
    /// `limit · m · (m − 1)`: the limit on the numerator `sq · m − (Σd)²`.
    scaled: f64,
}

impl SpreadLimit {
    /// The limit `limit` for an `m`-frame burst (`m ≥ 2`; a smaller `m` leaves every pixel to
    /// [`burst_variance`]).
    pub(crate) fn new(limit: f32, m: u32) -> Self {
        let scaled = if m >= 2 { limit as f64 * (m as f64 * (m - 1) as f64) } else { f64::NAN };
        Self { limit, scaled }
    }

    /// Whether `burst_variance(sum, first, sq, m) > limit` (`m`: this limit's burst length).
    /// The numerator `sq · m − (Σd)²` is an exact integer (below 2⁴⁸ and 2⁶² in its terms); the
    /// expression differs from it over `m · (m − 1)` by far less than [`MARGIN`] of
    /// `sq · m`, so a numerator further than that from the scaled limit decides as the
    /// expression would. Otherwise (near the limit, a saturated square, a sum far off its
    /// first frame, an infinite or NaN limit) the expression decides.
    #[inline(always)]
    pub(crate) fn beyond(&self, sum: u32, first: u16, sq: u32, m: u32) -> bool {
        let mf = m as i64;
        let sum_d = sum as i64 - mf * first as i64;
        if sq != u32::MAX && sum_d.unsigned_abs() < 1 << 31 {
            let sqm = sq as i64 * mf;
            let num = (sqm - sum_d * sum_d) as f64;
            let margin = MARGIN * (sqm as f64 + self.scaled.abs() + 1.0);
            // NaN and infinite limits fail both tests.
            if num > self.scaled + margin {
                return true;
            }
            if num < self.scaled - margin {
                return false;
            }
        }
        burst_variance(sum, first, sq, m) > self.limit as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A burst's (sum, first, squares) from its frames' values.
    fn burst(values: &[u16]) -> (u32, u16, u32) {
        let first = values[0];
        let sum = values.iter().map(|&v| v as u32).sum();
        let sq = values.iter().fold(0u32, |q, &v| {
            let d = v.abs_diff(first) as u32;
            q.saturating_add(d * d)
        });
        (sum, first, sq)
    }

    /// `beyond` answers as the expression does on every pixel: random bursts of 2–64 frames
    /// (noise of 0.5–2 000 DN over the 16-bit range), each against limits spread around its own
    /// variance, among them the variance itself rounded to f32 and its f32 neighbours (the
    /// ties the margin leaves to the expression); bursts whose squares saturate, whose sums lie
    /// far from their first frame; NaN and infinite limits. A version that decides ties on the
    /// integers (`≥`, or no margin), or that drops the division by `m`, fails on the ties.
    #[test]
    fn beyond_is_the_expression() {
        let mut rng = ChaCha8Rng::seed_from_u64(26);
        let (mut checked, mut ties, mut fast) = (0u64, 0u64, 0u64);
        for _ in 0..40_000 {
            let m = rng.random_range(2..=64u32);
            let level = rng.random_range(0..=u16::MAX) as f64;
            let sd = [0.5, 3.0, 40.0, 2000.0][rng.random_range(0..4)];
            let values: Vec<u16> = (0..m)
                .map(|_| (level + sd * (rng.random::<f64>() * 2.0 - 1.0) * 1.7).clamp(0.0, 65535.0) as u16)
                .collect();
            let (sum, first, sq) = burst(&values);
            let var = burst_variance(sum, first, sq, m);
            let at = var as f32;
            let mut limits = vec![at, at.next_up(), at.next_down(), 0.0, f32::NAN, f32::INFINITY];
            limits.extend((0..6).map(|_| (var * rng.random_range(0.0..3.0)) as f32));
            for l in limits {
                let want = burst_variance(sum, first, sq, m) > l as f64;
                let lim = SpreadLimit::new(l, m);
                assert_eq!(lim.beyond(sum, first, sq, m), want, "sum {sum} first {first} sq {sq} m {m} limit {l}");
                checked += 1;
                ties += (var == l as f64) as u64;
                let sqm = sq as i64 * m as i64;
                let num = (sqm - (sum as i64 - m as i64 * first as i64).pow(2)) as f64;
                fast += ((num - lim.scaled).abs() > MARGIN * (sqm as f64 + lim.scaled.abs() + 1.0)) as u64;
            }
        }
        // Saturated squares and the largest sums: the expression's own answers.
        for (sum, first, sq, m) in
            [(u32::MAX, 0, u32::MAX, 65_537), (4_000_000_000, 0, 100, 61_000), (10, 5, u32::MAX, 2)]
        {
            for l in [0.0f32, 1.0, 1e30, f32::INFINITY, f32::NAN] {
                let want = burst_variance(sum, first, sq, m) > l as f64;
                assert_eq!(SpreadLimit::new(l, m).beyond(sum, first, sq, m), want);
                checked += 1;
            }
        }
        assert!(checked > 400_000, "{checked}");
        // Ties occur (the integer variances of small noise), and most pixels take the fast path.
        assert!(ties > 2_000, "{ties} ties");
        assert!(fast * 10 > checked * 8, "{fast} of {checked} decided on the integers");
    }
}
