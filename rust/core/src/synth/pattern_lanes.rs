//! The fixed pattern of one sensor row at one column parity, a run of pixels in one loop the
//! compiler vectorises: the same values as the pixel-by-pixel expression
//! ([`super::structure::RowPattern`]), bit for bit, for patterns whose values stay below 2⁵¹
//! in 2⁻³² DN ([`lanes_apply`]; any real pattern, which is a few DN). The loop is compiled for
//! AVX-512 and AVX2 as well as the baseline and the CPU's best is picked at run time
//! (`multiversion`): the per-pixel hash, quantile lookup and rounding were a quarter of a
//! synthesis's CPU time as scalar code, which baseline x86-64 cannot vectorise (no 64-bit
//! multiply or conversions) and which held a saturating conversion per pixel.
//!
//! What differs from the pixel expression, and why each is exact:
//! - the quantile index `x as u32` is `⌊x⌋` found by adding 1.5·2⁵² (round to nearest) and
//!   stepping down where that went up: `x` lies in `[0, n − 1]`, far below 2³² (a saturating
//!   conversion, `x as i32`, was left scalar by the compiler); and `x = u·(n − 1)` is one
//!   product of the hash's bits and `(n − 1)·2⁻⁵³` (the same rounding);
//! - the rounding of the sum is [`crate::math::round::round_half_away_near`]'s without its
//!   branch: the sum is below 2⁵¹ by [`lanes_apply`];
//! - the quantile function is read as pairs of neighbours (`q[i]`, `q[i + 1]` in one 64-bit
//!   load at `q[i]`'s address, [`quantile_pair`]) and the shading line once per run of columns
//!   between the same two cells: one load per pixel instead of four. The loads read the stored
//!   quantile function itself (4 bytes per point: 16 KB for 4096 points, within a core's 32 KB
//!   L1 with the loop's other data), where a table of the pairs took twice that and waited on
//!   L2. They are scalar, in a pass of their own between two vectorised ones
//!   ([`parity_row`]): a 64-bit gather per pixel inside one loop spent more.

use multiversion::multiversion;

use crate::model::layout::POSITIONS;
use crate::model::structure::FixedPattern;

/// The largest magnitude of a quantile or shading value the lanes take (DN): a shaded pixel is
/// then below 2¹⁸ DN, 2⁵⁰ in 2⁻³² DN, where the rounding without a branch is exact.
const BOUND: f64 = 65536.0;
/// 1.5·2⁵²: a sum with it has a unit in the last place of 1.
const SHIFT: f64 = 6755399441055744.0;
/// 0.5 − 2⁻⁵⁴, the largest `f64` below a half.
const HALF_BELOW: f64 = 0.49999999999999994;
/// The fixed pattern's key ([`super::structure`]'s `PATTERN_KEY`).
pub(crate) const PATTERN_KEY: u64 = 0x6E6F_6973_6563_616C;

/// Whether [`parity_row`] gives `fp`'s values: every residual quantile function has two points
/// or more, and every quantile and shading value is finite and within [`BOUND`].
pub(crate) fn lanes_apply(fp: &FixedPattern) -> bool {
    let ok = |v: f32| v.is_finite() && (v as f64).abs() <= BOUND;
    (0..POSITIONS).all(|p| {
        fp.pixels[p].quantiles.len() >= 2
            && fp.pixels[p].quantiles.iter().all(|&v| ok(v))
            && fp.shading[p].iter().all(|&v| ok(v))
    })
}

/// `(q[i], q[i + 1])` from one unaligned 64-bit load at `q[i]` (`i + 1 < q.len()`, else
/// `None`): the form of the read the compiler turns into one 64-bit gather per pixel.
#[inline(always)]
fn quantile_pair(q: &[f32], i: usize) -> Option<(f32, f32)> {
    let two = q.get(i..i + 2)?;
    // SAFETY: `two` holds two `f32`s, 8 bytes; the read takes no alignment.
    let word = unsafe { std::ptr::read_unaligned(two.as_ptr() as *const u64) };
    // The first `f32` sits in the word's low half on a little-endian target, its high half on a
    // big-endian one.
    let (first, second) = match cfg!(target_endian = "little") {
        true => (word as u32, (word >> 32) as u32),
        false => ((word >> 32) as u32, word as u32),
    };
    Some((f32::from_bits(first), f32::from_bits(second)))
}

/// The columns of one parity of an image's row, as the lanes read them: per column the
/// fraction between its two shading cells ([`crate::model::structure::grid_coord`]), and the
/// runs of columns between the same two cells.
#[derive(Debug, Default)]
pub(crate) struct ParityColumns {
    /// Per run, its end (exclusive, in columns of this parity) and its two cells.
    runs: Vec<(usize, u32, u32)>,
    f: Vec<f64>,
}

impl ParityColumns {
    /// From each column's cells and fraction, in order.
    pub(crate) fn new(cells: impl Iterator<Item = (u32, u32, f64)>) -> Self {
        let mut out = Self::default();
        for (k, (c0, c1, f)) in cells.enumerate() {
            match out.runs.last_mut() {
                Some((end, a, b)) if (*a, *b) == (c0, c1) => *end = k + 1,
                _ => out.runs.push((k + 1, c0, c1)),
            }
            out.f.push(f);
        }
        out
    }

    /// Columns of this parity.
    pub(crate) fn len(&self) -> usize {
        self.f.len()
    }
}

/// Pixels per block of [`parity_row`]'s three passes (their scratch stays in L1).
const BLOCK: usize = 256;

/// The pattern (2⁻³² DN) of sensor row `y` at the columns `x_first, x_first + 2, …` into `out`
/// (one per column of `cols`): `line` is the row's shading line of this parity (zeros without
/// shading; it holds every cell `cols` names), `q` the residual's quantile function (two points
/// or more, checked by [`lanes_apply`]). A sensor pixel's uniform draw is splitmix64 of its
/// position.
///
/// In blocks of [`BLOCK`] pixels, three passes: the hashes' quantile positions (vectorised),
/// the quantile pairs they fall between read by scalar loads ([`quantile_pairs`]), then the
/// interpolation and rounding (vectorised). One loop with a 64-bit gather per pixel spent a
/// quarter of its time waiting on the gather on this machine's AMD EPYC (AVX-512); the values
/// are the same, operation for operation.
pub(crate) fn parity_row(y: u64, x_first: u64, cols: &ParityColumns, line: &[f64], q: &[f32], out: &mut [i64]) {
    let Some(last) = q.len().checked_sub(2) else { return };
    let mut idx = [0u32; BLOCK];
    let mut fracs = [0f64; BLOCK];
    let mut pairs = [0u64; BLOCK];
    let mut start = 0;
    for &(end, c0, c1) in &cols.runs {
        let (a, b) = (line[c0 as usize], line[c1 as usize]);
        let mut s = start;
        while s < end {
            let e = (s + BLOCK).min(end);
            let n = e - s;
            positions(y, x_first + 2 * s as u64, q.len(), last, &mut fracs[..n], &mut idx[..n]);
            quantile_pairs(q, &idx[..n], &mut pairs[..n]);
            interpolated(a, b, &cols.f[s..e], &fracs[..n], &pairs[..n], &mut out[s..e]);
            s = e;
        }
        start = end;
    }
}

/// Per pixel at columns `x_first, x_first + 2, …` of row `y` (one per slot of `fracs`): its
/// draw's position `x = u·(n − 1)` in the quantile function of `n` points, the index `i = ⌊x⌋`
/// at most `last` into `idx`, and the fraction `x − i` into `fracs`. `i` is found as a float
/// (`x` lies in `[0, n − 1]`, far below 2³², so it and the fraction are exact) and stored
/// through the 1.5·2⁵² shift: no float-to-integer conversion, which AVX2 lacks for 64 bits.
/// Where the target has SSE4.1's rounding instruction, `⌊x⌋` is one `trunc` (`x ≥ 0`).
#[multiversion(targets(
    "x86_64+avx512f+avx512dq+avx512vl+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3",
    "x86_64+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3"
))]
fn positions(y: u64, x_first: u64, n: usize, last: usize, fracs: &mut [f64], idx: &mut [u32]) {
    // `u·(n − 1)` in one product: `u` is the hash's 53 bits times 2⁻⁵³, both products exact
    // but the last, so `bits·((n − 1)·2⁻⁵³)` rounds the same real number the same way.
    let scale = (n - 1) as f64 * (1.0 / (1u64 << 53) as f64);
    let last = last as f64;
    for (j, (fo, io)) in fracs.iter_mut().zip(idx.iter_mut()).enumerate() {
        let mut z = PATTERN_KEY ^ (y << 32 | (x_first + 2 * j as u64));
        z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        let x = (((z ^ (z >> 31)) >> 11) as i64) as f64 * scale;
        let floor = match multiversion::target::target_cfg_f!(target_feature = "sse4.1") {
            true => x.trunc(),
            // ⌊x⌋ for x in [0, n − 1]: the nearest integer, one less where it lies above x.
            false => {
                let nearest = (x + SHIFT) - SHIFT;
                nearest - if nearest > x { 1.0 } else { 0.0 }
            }
        };
        let i = if floor < last { floor } else { last };
        *fo = x - i;
        *io = ((i + SHIFT).to_bits() - SHIFT.to_bits()) as u32;
    }
}

/// `(q[i], q[i + 1])` of each `i` of `idx` (each below `q.len() − 1`) as the 64-bit word at
/// `q[i]` ([`quantile_pair`]): scalar loads, compiled for the baseline (no gather instruction).
#[inline(never)]
fn quantile_pairs(q: &[f32], idx: &[u32], pairs: &mut [u64]) {
    for (p, &i) in pairs.iter_mut().zip(idx) {
        *p = quantile_pair(q, i as usize).map_or(0, |(a, b)| {
            let (a, b) = (a.to_bits() as u64, b.to_bits() as u64);
            a | b << 32
        });
    }
}

/// The shaded, interpolated and rounded pattern of each pixel (2⁻³² DN) into `out`: its shading
/// between the cells `a` and `b` at fraction `fs`, plus the residual between the quantile pair
/// (`pairs`, [`quantile_pairs`]) at fraction `fracs` ([`positions`]).
///
/// The rounding, half away from zero, is `trunc(v + copysign(0.5 − 2⁻⁵⁴, v))` where the target
/// has SSE4.1's rounding instruction (the lowering compilers give `round` itself, exact for every
/// `f64`: the sum rounds up past the next integer only from a half or more), then read out
/// through the 1.5·2⁵² shift; elsewhere the shift's nearest integer, moved one away from zero on
/// a tie. Both are [`crate::math::round::round_half_away_near`]'s value.
#[multiversion(targets(
    "x86_64+avx512f+avx512dq+avx512vl+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3",
    "x86_64+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3"
))]
fn interpolated(a: f64, b: f64, fs: &[f64], fracs: &[f64], pairs: &[u64], out: &mut [i64]) {
    let n = out.len();
    let (fs, fracs, pairs) = (&fs[..n], &fracs[..n], &pairs[..n]);
    for j in 0..n {
        let f = fs[j];
        let shade = a * (1.0 - f) + b * f;
        let f = fracs[j];
        let word = pairs[j];
        let (q0, q1) = (f32::from_bits(word as u32) as f64, f32::from_bits((word >> 32) as u32) as f64);
        let residual = q0 * (1.0 - f) + q1 * f;
        // Rounded half away from zero ([`crate::math::round::round_half_away_near`]).
        let v = (shade + residual) * 4294967296.0;
        out[j] = match multiversion::target::target_cfg_f!(target_feature = "sse4.1") {
            true => {
                let r = (v + HALF_BELOW.copysign(v)).trunc();
                (r + SHIFT).to_bits() as i64 - SHIFT.to_bits() as i64
            }
            false => {
                let m = v + SHIFT;
                let nearest = m.to_bits() as i64 - SHIFT.to_bits() as i64;
                let d = v - (m - SHIFT);
                nearest + ((d >= 0.5) & (v > 0.0)) as i64 - ((d <= -0.5) & (v < 0.0)) as i64
            }
        };
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::round::round_half_away;
    use crate::model::structure::quantile_at;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// The pixel expression the lanes stand for: shading plus the residual's quantile at the
    /// pixel's hashed draw, rounded half away from zero (2⁻³² DN).
    fn reference(y: u64, x: u64, shade: f64, q: &[f32]) -> i64 {
        let mut z = PATTERN_KEY ^ (y << 32 | x);
        z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        let u = (((z ^ (z >> 31)) >> 11) as i64) as f64 * (1.0 / (1u64 << 53) as f64);
        round_half_away((shade + quantile_at(q, u)) * 4294967296.0)
    }

    /// Bit for bit the pixel expression on random quantile functions (2 to 1000 points, both
    /// signs, up to the bound), random shading lines and cells, rows and origins; and on
    /// constant quantile functions at odd multiples of 2⁻³³ DN without shading, whose values
    /// land on halves of 2⁻³² DN, where the rounding's tie rule decides.
    #[test]
    fn lanes_are_the_pixel_expression_bit_for_bit() {
        let mut rng = ChaCha8Rng::seed_from_u64(8);
        let mut checked = 0usize;
        let mut ties = 0usize;
        for case in 0..120 {
            let n = [2usize, 3, 17, 256, 1000][case % 5];
            let scale = [0.01f64, 1.0, 40.0, BOUND / 2.0][case % 4];
            let mut q: Vec<f32> = (0..n).map(|_| ((rng.random::<f64>() - 0.5) * 2.0 * scale) as f32).collect();
            let tie = case % 6 == 5;
            if tie {
                let j = rng.random_range(-5000i64..5000);
                q = vec![((2 * j + 1) as f64 / 8589934592.0) as f32; n];
            }
            q.sort_by(f32::total_cmp);
            let gw = 1 + case % 9;
            let line: Vec<f64> = match tie {
                true => vec![0.0; gw],
                false => (0..gw).map(|_| (rng.random::<f64>() - 0.5) * scale).collect(),
            };
            let w = rng.random_range(0..700usize);
            // Columns in runs between the same cells, as an image's are, or changing at random.
            let mut c0 = 0u32;
            let cells: Vec<(u32, u32, f64)> = (0..w)
                .map(|_| {
                    if rng.random::<f64>() < [0.01, 0.5][case % 2] {
                        c0 = rng.random_range(0..gw as u32);
                    }
                    (c0, (c0 + 1).min(gw as u32 - 1), if case % 3 == 0 { 0.0 } else { rng.random::<f64>() })
                })
                .collect();
            let cols = ParityColumns::new(cells.iter().copied());
            assert_eq!(cols.len(), w);
            let (y, x_first) = (rng.random_range(0..100_000u64), rng.random_range(0..100_000u64));
            let mut out = vec![7i64; w];
            parity_row(y, x_first, &cols, &line, &q, &mut out);
            for (k, &v) in out.iter().enumerate() {
                let (c0, c1, f) = (cells[k].0 as usize, cells[k].1 as usize, cells[k].2);
                let shade = line[c0] * (1.0 - f) + line[c1] * f;
                let x = x_first + 2 * k as u64;
                let want = reference(y, x, shade, &q);
                assert_eq!(v, want, "case {case}, row {y}, column {x}");
                let exact = (shade + quantile_at(&q, 0.5)) * 4294967296.0;
                ties += (tie && exact.fract().abs() == 0.5) as usize;
                checked += 1;
            }
        }
        assert!(checked > 30_000, "{checked} pixels");
        assert!(ties > 1000, "{ties} pixels on a tie");
    }

    /// The rounding's constant is the largest `f64` below a half: one more ulp and 0.5 − 2⁻⁵⁴
    /// itself would round up (the tie case in the test above catches a wrong constant too).
    #[test]
    fn half_below_is_the_float_below_a_half() {
        assert_eq!(HALF_BELOW, f64::from_bits(0.5f64.to_bits() - 1));
        assert_eq!((HALF_BELOW + HALF_BELOW.copysign(HALF_BELOW)).trunc(), 0.0);
        assert_eq!((0.5 + HALF_BELOW).trunc(), 1.0);
    }

    /// The lanes apply to a pattern of finite values within the bound whose quantile functions
    /// have two points or more, and to no other.
    #[test]
    fn lanes_apply_only_within_the_bound() {
        let st = crate::model::structure::OffsetDistribution {
            quantiles: vec![-1.0, 0.0, 2.0],
            count: 10,
            measured_var: 1.0,
            sampling_var: 0.0,
            significant: true,
        };
        let fp = |q: Vec<f32>, shade: f32| FixedPattern {
            pixels: std::array::from_fn(|_| crate::model::structure::OffsetDistribution {
                quantiles: q.clone(),
                ..st.clone()
            }),
            shading: std::array::from_fn(|_| vec![shade; 4]),
            grid: [2, 2],
            size: [8, 8],
            frames: 4,
            temporal_var: [1.0; POSITIONS],
            in_pixel_noise: std::array::from_fn(|_| st.clone()),
            significant: true,
        };
        assert!(lanes_apply(&fp(vec![-1.0, 0.0, 2.0], 3.0)));
        assert!(lanes_apply(&fp(vec![-BOUND as f32, BOUND as f32], -BOUND as f32)));
        assert!(!lanes_apply(&fp(vec![0.5], 0.0)), "one point");
        assert!(!lanes_apply(&fp(vec![], 0.0)), "no point");
        assert!(!lanes_apply(&fp(vec![0.0, 1e6], 0.0)), "past the bound");
        assert!(!lanes_apply(&fp(vec![0.0, 1.0], f32::NAN)), "NaN shading");
        assert!(!lanes_apply(&fp(vec![0.0, f32::INFINITY], 0.0)), "infinite quantile");
    }
}
