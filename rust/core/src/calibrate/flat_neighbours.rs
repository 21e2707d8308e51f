//! The flat test's neighbour comparison on the burst's integer sums ([`super::flat`]).
//!
//! Two same-position neighbours of means `a = Sa / m` and `b = Sb / m` (f64 quotients of their
//! sums over an `m`-frame burst) differ beyond the threshold `t` when
//! `(a − b).abs() as f32 > t`. That depends on `D = |Sa − Sb|` alone except within a hair of
//! the threshold: `|a − b|` computed is `D / m` to within `3 · 2¹⁶ · 2⁻⁵³ < 10⁻¹⁰` DN (means at
//! most 65 535), and its conversion to f32 exceeds `t` exactly when it lies above the midpoint
//! between `t` and the next f32 (at the midpoint, where ties go). So per threshold two integers
//! decide almost every pair: `D` below the first passes, `D` from the second on fails, and the
//! rare `D` between (its quotient within 10⁻⁶ DN of the midpoint) takes the float expression.

/// Where `D = |Sa − Sb|` decides the comparison with one threshold by itself.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct NeighbourLimit {
    /// `D` below this passes (`|a − b| as f32 ≤ t`).
    pass_below: u64,
    /// `D` from this on fails (`|a − b| as f32 > t`).
    fail_from: u64,
}

/// How far (DN) from the midpoint the quotient `D / m` must lie for `D` to decide: far beyond
/// the error of the computed difference (< 10⁻¹⁰ DN) and of the products below (< 10⁻¹¹ DN).
const MARGIN: f64 = 1e-6;

impl NeighbourLimit {
    /// The integer bounds for threshold `t` and an `m`-frame burst (`m ≥ 1`); a threshold that
    /// is negative, NaN or infinite leaves every `D` to the float expression.
    pub(crate) fn new(t: f32, m: u32) -> Self {
        let undecided = Self { pass_below: 0, fail_from: u64::MAX };
        if !t.is_finite() || t < 0.0 || m == 0 {
            return undecided;
        }
        let up = t.next_up();
        if !up.is_finite() {
            return undecided;
        }
        // Exact: both are f32, their sum has at most 25 significant bits.
        let mid = (t as f64 + up as f64) / 2.0;
        let m = m as f64;
        let lo = (mid - MARGIN) * m;
        let hi = (mid + MARGIN) * m;
        // D < ⌈lo⌉ is D < lo; D ≥ ⌊hi⌋ + 1 is D > hi.
        let pass_below = if lo > 0.0 { lo.ceil() as u64 } else { 0 };
        let fail_from = if hi < 1.8e19 { hi.floor() as u64 + 1 } else { u64::MAX };
        Self { pass_below, fail_from }
    }

    /// Whether sums `sa`, `sb` of an `m`-frame burst differ beyond threshold `t` (the one this
    /// limit was made for): `(sa / m − sb / m).abs() as f32 > t` in f64, decided on the integers
    /// where they can.
    #[inline(always)]
    pub(crate) fn beyond(&self, sa: u32, sb: u32, m: f64, t: f32) -> bool {
        let d = sa.abs_diff(sb) as u64;
        if d < self.pass_below {
            false
        } else if d >= self.fail_from {
            true
        } else {
            (sa as f64 / m - sb as f64 / m).abs() as f32 > t
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn float(sa: u32, sb: u32, m: u32, t: f32) -> bool {
        let m = m as f64;
        (sa as f64 / m - sb as f64 / m).abs() as f32 > t
    }

    /// The integer decision is the float expression on random sums of bursts of 1 to 60 000
    /// frames of 16-bit values, against thresholds from a tenth of a DN to thousands, and on the
    /// sums that lie right at each threshold (D = ⌊t·m⌋ − 2 ..= ⌈t·m⌉ + 2, where a bound off by
    /// one, or a decision on `D / m > t` without the f32 rounding, goes wrong). It counts how
    /// many pairs the float expression decided: few.
    #[test]
    fn decides_as_the_float_expression() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let (mut checked, mut undecided) = (0u64, 0u64);
        let mut check = |sa: u32, sb: u32, m: u32, t: f32, lim: &NeighbourLimit| {
            let d = sa.abs_diff(sb) as u64;
            if d >= lim.pass_below && d < lim.fail_from {
                undecided += 1;
            }
            assert_eq!(lim.beyond(sa, sb, m as f64, t), float(sa, sb, m, t), "sa {sa} sb {sb} m {m} t {t}");
            checked += 1;
        };
        for _ in 0..2_000 {
            let m = match rng.random_range(0..4) {
                0 => rng.random_range(1..=4),
                1 => rng.random_range(5..=64),
                2 => rng.random_range(65..=2_000),
                _ => rng.random_range(2_001..=60_000),
            };
            let t = match rng.random_range(0..3) {
                0 => rng.random_range(0.1f32..4.0),
                1 => rng.random_range(4.0f32..300.0),
                _ => (rng.random_range(1u32..2_000) as f32) * 0.5 + 0.5,
            };
            let lim = NeighbourLimit::new(t, m);
            let top = m as u64 * 65_535;
            for _ in 0..50 {
                let sa = rng.random_range(0..=top) as u32;
                let sb = rng.random_range(0..=top) as u32;
                check(sa, sb, m, t, &lim);
            }
            // Around the threshold, both signs, low and high levels.
            let at = (t as f64 * m as f64).round() as i64;
            for base in [0i64, top as i64 / 2, top as i64 - at - 3] {
                for d in at - 2..=at + 2 {
                    let (sa, sb) = (base.max(0), base.max(0) + d);
                    if !(0..=top as i64).contains(&sb) {
                        continue;
                    }
                    check(sa as u32, sb as u32, m, t, &lim);
                    check(sb as u32, sa as u32, m, t, &lim);
                }
            }
        }
        assert!(checked > 100_000, "{checked}");
        // Half-integer thresholds over even bursts put D / m on the midpoint's neighbourhood
        // only when m·mid is within 10⁻⁶·m of an integer: a few pairs in a thousand at most.
        assert!(undecided * 100 < checked, "{undecided} of {checked} left to the float expression");
    }

    /// Thresholds that cannot be decided on integers leave every pair to the float expression,
    /// which is then what `beyond` gives (NaN never exceeds, infinity neither, a negative
    /// threshold always).
    #[test]
    fn odd_thresholds_take_the_float_expression() {
        for t in [f32::NAN, f32::INFINITY, -1.0, f32::MAX] {
            let lim = NeighbourLimit::new(t, 8);
            for (sa, sb) in [(0, 0), (100, 900), (8 * 65_535, 0)] {
                assert_eq!(lim.beyond(sa, sb, 8.0, t), float(sa, sb, 8, t));
            }
        }
        assert!(!NeighbourLimit::new(f32::NAN, 8).beyond(0, 8 * 65_535, 8.0, f32::NAN));
        assert!(NeighbourLimit::new(-1.0, 8).beyond(5, 5, 8.0, -1.0));
    }
}
