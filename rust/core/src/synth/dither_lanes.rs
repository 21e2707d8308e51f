//! A row's dither stream (xorshift64*, one draw per pair of pixels) drawn in independent lanes:
//! the same draws, in the same order, as the serial stream, without its chain of dependent
//! shifts. xorshift64's step is linear over GF(2), so the state `k` steps on is a 64 × 64 bit
//! matrix `Mᵏ` applied to the state: [`DitherJumps`] holds `M^{L}, M^{2L}, …` for one row length
//! (built once per image), each lane starts `L` draws further on, and the lanes step side by
//! side. Serially, each draw waited on the last one's three shift-and-xor steps (about six
//! cycles per pair of pixels, the bound of the offsets pass); the lanes' steps overlap, and
//! the row's integer offsets are then summed in one loop the compiler vectorises
//! ([`offsets_split`], [`offsets_interleaved`]), compiled for AVX-512 and AVX2 as well as the
//! baseline (`multiversion`).

use multiversion::multiversion;

/// Independent lanes of a row's stream.
const LANES: usize = 8;
/// xorshift64*'s output multiplier.
const MULTIPLIER: u64 = 0x2545_F491_4F6C_DD1D;

/// One step of xorshift64 (12, 25, 27): the state after it.
#[inline(always)]
fn step(mut s: u64) -> u64 {
    s ^= s >> 12;
    s ^= s << 25;
    s ^= s >> 27;
    s
}

/// A 64 × 64 matrix over GF(2), by columns: column `b` is the image of the state `1 << b`.
#[derive(Clone, Copy, Debug, PartialEq)]
struct BitMatrix([u64; 64]);

impl BitMatrix {
    /// The matrix of one step.
    fn step() -> Self {
        Self(std::array::from_fn(|b| step(1u64 << b)))
    }

    fn identity() -> Self {
        Self(std::array::from_fn(|b| 1u64 << b))
    }

    /// The matrix applied to `s` (the xor of the columns of `s`'s set bits).
    #[inline]
    fn apply(&self, s: u64) -> u64 {
        let mut out = 0;
        let mut bits = s;
        while bits != 0 {
            out ^= self.0[bits.trailing_zeros() as usize];
            bits &= bits - 1;
        }
        out
    }

    /// `self` after `other` (`self · other`).
    fn after(&self, other: &Self) -> Self {
        Self(std::array::from_fn(|b| self.apply(other.0[b])))
    }

    /// `Mᵏ` of the step, by squaring.
    fn step_power(mut k: u64) -> Self {
        let (mut out, mut sq) = (Self::identity(), Self::step());
        while k > 0 {
            if k & 1 == 1 {
                out = out.after(&sq);
            }
            sq = sq.after(&sq);
            k >>= 1;
        }
        out
    }
}

/// The jumps that start each lane of a row of `n` draws: lane `c` draws `c·L .. (c + 1)·L`.
#[derive(Clone, Debug)]
pub(crate) struct DitherJumps {
    /// Draws per lane (`⌈n / LANES⌉`).
    per_lane: usize,
    /// `M^{c·L}` for lanes `1 .. LANES`.
    jumps: Vec<BitMatrix>,
}

impl DitherJumps {
    /// For rows of `n` draws.
    pub(crate) fn new(n: usize) -> Self {
        let per_lane = n.div_ceil(LANES).max(1);
        let by_lane = BitMatrix::step_power(per_lane as u64);
        let mut jumps = Vec::with_capacity(LANES - 1);
        let mut m = by_lane;
        for _ in 1..LANES {
            jumps.push(m);
            m = m.after(&by_lane);
        }
        Self { per_lane, jumps }
    }

    /// The first `n` draws (at most the `n` of [`Self::new`]) of the xorshift64* stream from
    /// `state` (not zero) into `out[..n]` (resized; past `n` it holds the stream's next draws
    /// up to whole lanes): draw `j` is the state after `j + 1` steps times the multiplier, as
    /// the serial stream's `j`-th call returns.
    pub(crate) fn fill(&self, state: u64, n: usize, out: &mut Vec<u64>) {
        let l = self.per_lane;
        debug_assert!(n <= l * LANES, "{n} draws, lanes of {l}");
        out.resize(l * LANES, 0);
        let mut s = [state; LANES];
        for (c, j) in self.jumps.iter().enumerate() {
            s[c + 1] = j.apply(state);
        }
        let mut chunks = out.chunks_exact_mut(l);
        let lanes: [&mut [u64]; LANES] = std::array::from_fn(|_| chunks.next().expect("LANES lanes of l draws"));
        step_lanes(s, lanes);
    }
}

/// Each lane's draws from its state, the lanes stepped side by side (one vector of states where
/// the target has 64-bit lanes and multiplies: AVX-512).
#[multiversion(targets(
    "x86_64+avx512f+avx512dq+avx512vl+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3",
    "x86_64+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3"
))]
fn step_lanes(mut s: [u64; LANES], mut lanes: [&mut [u64]; LANES]) {
    let l = lanes.iter().map(|lane| lane.len()).min().unwrap_or(0);
    for t in 0..l {
        for x in s.iter_mut() {
            *x = step(*x);
        }
        for (lane, x) in lanes.iter_mut().zip(&s) {
            lane[t] = x.wrapping_mul(MULTIPLIER);
        }
    }
}

/// One pair's integer offsets: `⌊(o·2³² + v) / 2³²⌋` for each pixel's offset `o` (2⁻³² DN: its
/// column's with the frame's `col`, its fixed pattern `pat`, and the row's `ry`) and the
/// pair's dither draw `v`, its low half for the even pixel.
#[inline(always)]
fn pair_offsets(col: [i64; 2], pat: [i64; 2], ry: i64, v: u64) -> [i32; 2] {
    [
        ((col[0] + pat[0] + ry + (v as u32) as i64) >> 32) as i32,
        ((col[1] + pat[1] + ry + (v >> 32) as i64) >> 32) as i32,
    ]
}

/// A row's integer offsets into `out` (pairs of pixels; an odd width's last pixel is the
/// caller's): the columns' offsets `cols`, the fixed pattern per column parity (`p0[j]`, `p1[j]`
/// for pair `j`), the row's offset `ry` and the pair's dither draw `dither[j]`.
#[multiversion(targets(
    "x86_64+avx512f+avx512dq+avx512vl+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3",
    "x86_64+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3"
))]
pub(crate) fn offsets_split(cols: &[i64], p0: &[i64], p1: &[i64], ry: i64, dither: &[u64], out: &mut [i32]) {
    let pairs = out.chunks_exact_mut(2).zip(cols.chunks_exact(2)).zip(p0.iter().zip(p1)).zip(dither);
    for (((o, k), (&a, &b)), &v) in pairs {
        let [x, y] = pair_offsets([k[0], k[1]], [a, b], ry, v);
        o[0] = x;
        o[1] = y;
    }
}

/// [`offsets_split`] with the fixed pattern per column, `pat[i]` (zeros without one).
#[multiversion(targets(
    "x86_64+avx512f+avx512dq+avx512vl+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3",
    "x86_64+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3"
))]
pub(crate) fn offsets_interleaved(cols: &[i64], pat: &[i64], ry: i64, dither: &[u64], out: &mut [i32]) {
    let pairs = out.chunks_exact_mut(2).zip(cols.chunks_exact(2)).zip(pat.chunks_exact(2)).zip(dither);
    for (((o, k), p), &v) in pairs {
        let [x, y] = pair_offsets([k[0], k[1]], [p[0], p[1]], ry, v);
        o[0] = x;
        o[1] = y;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The serial stream the lanes stand for.
    fn serial(state: u64, n: usize) -> Vec<u64> {
        let mut s = state;
        (0..n)
            .map(|_| {
                s = step(s);
                s.wrapping_mul(MULTIPLIER)
            })
            .collect()
    }

    /// Bit for bit the serial stream, for row lengths around multiples of the lane count and
    /// image widths, and random states; a lane started one step off (a wrong jump) differs in
    /// every draw of that lane.
    #[test]
    fn lanes_are_the_serial_stream() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        for n in [1usize, 2, 7, 8, 9, 15, 16, 17, 63, 64, 65, 100, 1000, 1001, 2000, 2001, 3000] {
            let jumps = DitherJumps::new(n);
            for _ in 0..5 {
                state = step(state).wrapping_mul(MULTIPLIER) | 1;
                let mut out = Vec::new();
                jumps.fill(state, n, &mut out);
                assert_eq!(out[..n], serial(state, n), "n {n}, state {state:#x}");
            }
        }
        // The jump is exact, not near: one step more is another stream.
        let (n, state) = (2000, 0x1234_5678_9ABC_DEF1u64);
        let mut wrong = DitherJumps::new(n);
        wrong.jumps[0] = wrong.jumps[0].after(&BitMatrix::step());
        let mut out = Vec::new();
        wrong.fill(state, n, &mut out);
        let want = serial(state, n);
        let l = n.div_ceil(LANES);
        assert_eq!(out[..l], want[..l]);
        assert!(out[l..2 * l].iter().zip(&want[l..2 * l]).all(|(a, b)| a != b));
    }

    /// The offsets kernels with the lanes' draws are the pair-by-pair expression with the
    /// serial stream (as the offsets pass drew it before the lanes): random columns, patterns,
    /// row offsets and states, widths around multiples of the lanes. With the draw's halves
    /// swapped (a kernel giving each pixel the other's draw) about a third of the pixels differ
    /// (`E|U − U'|` of two uniforms: the dither picks between two integers by the draw).
    #[test]
    fn offsets_are_the_serial_expression() {
        let mut z = 0x0123_4567_89AB_CDEFu64;
        let mut next = || {
            z = step(z);
            z.wrapping_mul(MULTIPLIER)
        };
        let mut differ = 0usize;
        for w in [2usize, 3, 16, 17, 30, 258, 1001, 4000] {
            let draws = w.div_ceil(2);
            let jumps = DitherJumps::new(draws);
            for _ in 0..3 {
                // Offsets of a few DN either way, 2⁻³² DN.
                let mut small = || (next() >> 29) as i64 - (1 << 34);
                let cols: Vec<i64> = (0..w).map(|_| small()).collect();
                let pat: Vec<i64> = (0..w).map(|_| small()).collect();
                let ry = small();
                let state = next() | 1;
                let mut d = Vec::new();
                jumps.fill(state, draws, &mut d);
                let mut serial_state = state;
                let want: Vec<i32> = (0..w / 2)
                    .flat_map(|j| {
                        serial_state = step(serial_state);
                        let v = serial_state.wrapping_mul(MULTIPLIER);
                        let lo = (cols[2 * j] + pat[2 * j] + ry + (v as u32) as i64) >> 32;
                        let hi = (cols[2 * j + 1] + pat[2 * j + 1] + ry + (v >> 32) as i64) >> 32;
                        [lo as i32, hi as i32]
                    })
                    .collect();
                let pairs = w - w % 2;
                let mut got = vec![i32::MIN; pairs];
                offsets_interleaved(&cols, &pat, ry, &d[..draws], &mut got);
                assert_eq!(got, want, "interleaved, width {w}");
                let p0: Vec<i64> = pat.iter().step_by(2).copied().collect();
                let p1: Vec<i64> = pat.iter().skip(1).step_by(2).copied().collect();
                let mut got = vec![i32::MIN; pairs];
                offsets_split(&cols, &p0, &p1, ry, &d[..draws], &mut got);
                assert_eq!(got, want, "split, width {w}");
                // The halves swapped: what a wrong kernel scores.
                let swapped: Vec<u64> = d[..draws].iter().map(|v| v.rotate_left(32)).collect();
                offsets_split(&cols, &p0, &p1, ry, &swapped, &mut got);
                differ += got.iter().zip(&want).filter(|(a, b)| a != b).count();
            }
        }
        assert!(differ > 3000, "{differ} of about 16 000 pixels differ with the halves swapped");
    }

    /// `Mᵏ` by squaring is `k` steps, and the identity at `k = 0`.
    #[test]
    fn step_power_is_k_steps() {
        let s = 0xDEAD_BEEF_0123_4567u64;
        for k in [0u64, 1, 2, 3, 250, 251, 1 << 20] {
            let mut want = s;
            for _ in 0..k {
                want = step(want);
            }
            assert_eq!(BitMatrix::step_power(k).apply(s), want, "k {k}");
        }
    }
}
