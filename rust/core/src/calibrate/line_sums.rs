//! One row of a target frame, as the target fold reads it (method.md, "Calibration" 4–6): the
//! noise `v − c` of every pixel, and its sums over the line pixels per column and per cell, for
//! the structured components ([`crate::calibrate::structure`]). Branch-free integer passes that
//! the compiler vectorises, some compiled for AVX-512 and AVX2 as well as the baseline.

use multiversion::multiversion;

use crate::calibrate::flat::NOT_FLAT;
use crate::calibrate::line_base::in_lines;
use crate::calibrate::structure::CELLS;

/// Adds one row's noise over its line pixels (flat, clean level at most `line_top`) into its
/// columns' sums `cols`, and returns its sums per cell (`x & 3`). One branch-free pass over the
/// row's quads, so that the compiler vectorises it (integer sums: any order gives the same).
#[inline]
pub(super) fn line_sums(noise: &[i32], crow: &[u16], line_top: u16, cols: &mut [i64]) -> [i64; CELLS] {
    let n = noise.len().min(crow.len()).min(cols.len());
    let (noise, crow, cols) = (&noise[..n], &crow[..n], &mut cols[..n]);
    let mut cells = [0i64; CELLS];
    let masked = |n: i32, c: u16| (n & (in_lines(c, line_top) as i32).wrapping_neg()) as i64;
    let quads = noise.chunks_exact(CELLS).zip(crow.chunks_exact(CELLS)).zip(cols.chunks_exact_mut(CELLS));
    for ((qn, qc), qcols) in quads {
        for k in 0..CELLS {
            let m = masked(qn[k], qc[k]);
            qcols[k] += m;
            cells[k] += m;
        }
    }
    let done = n / CELLS * CELLS;
    for (k, ((&v, &c), col)) in noise[done..].iter().zip(&crow[done..]).zip(&mut cols[done..]).enumerate() {
        let m = masked(v, c);
        *col += m;
        cells[k] += m;
    }
    cells
}

/// Rows of one half whose noise [`line_sums_narrow`] sums into 32-bit columns before they are
/// added into the 64-bit ones: `NARROW_ROWS · 2¹⁶ < 2³¹`.
pub(super) const NARROW_ROWS: usize = 1 << 14;

/// Pixels of a row whose cell sums [`line_sums_narrow`] forms in 32 bits at a time (a lane
/// holds an eighth of them: `2¹¹ · 2¹⁶ < 2³¹`).
pub(super) const NARROW_RUN: usize = 1 << 14;

/// Adds `narrow` into `wide` and clears it.
pub(super) fn widen_into(narrow: &mut [i32], wide: &mut [i64]) {
    for (n, w) in narrow.iter_mut().zip(wide) {
        *w += std::mem::take(n) as i64;
    }
}

/// [`line_sums`] of a row whose noise is below 2¹⁶ in magnitude (a still frame: a difference of
/// two u16), into 32-bit column sums `cols` (the caller adds them into its 64-bit ones before
/// [`NARROW_ROWS`] rows could overflow them). The same integer sums, so the same values; in
/// half the width, so twice the pixels per vector instruction.
#[inline]
pub(super) fn line_sums_narrow(noise: &[i32], crow: &[u16], line_top: u16, cols: &mut [i32]) -> [i64; CELLS] {
    let n = noise.len().min(crow.len()).min(cols.len());
    let mut cells = [0i64; CELLS];
    let runs = noise[..n].chunks(NARROW_RUN).zip(crow[..n].chunks(NARROW_RUN)).zip(cols[..n].chunks_mut(NARROW_RUN));
    for ((noise, crow), cols) in runs {
        // A run starts at a multiple of CELLS: its lane `k` is cell `k mod CELLS`.
        let lanes = narrow_run(noise, crow, line_top, cols);
        for (k, l) in lanes.iter().enumerate() {
            cells[k % CELLS] += *l as i64;
        }
    }
    cells
}

/// The noise `v − c` of every pixel of a row (`row` raw values, `crow` clean levels) into
/// `noise`, 0 where the pixel is not flat; returns the flat pixels. Branch-free, compiled for
/// AVX-512 and AVX2 as well as the baseline, the CPU's best picked at run time.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512dq+avx512vl+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3",
    "x86_64+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3"
))]
pub(super) fn noise_row(row: &[u16], crow: &[u16], noise: &mut [i32]) -> u32 {
    let mut flat_pixels = 0u32;
    for ((n, &v), &c) in noise.iter_mut().zip(row).zip(crow) {
        let is_flat = c != NOT_FLAT;
        *n = (v as i32 - c as i32) & (is_flat as i32).wrapping_neg();
        flat_pixels += is_flat as u32;
    }
    flat_pixels
}

/// [`noise_row`] and then [`line_sums_narrow`] of its noise, in one pass over the row: the noise
/// `v − c` of every pixel into `noise` (0 where not flat), its line pixels' noise into the
/// 32-bit column sums `cols`; returns the flat pixels and the row's sums per cell (`x & 3`).
/// The same integers as the two in turn, with the row and its clean levels read once.
#[inline]
pub(super) fn noise_and_line_sums(
    row: &[u16],
    crow: &[u16],
    line_top: u16,
    noise: &mut [i32],
    cols: &mut [i32],
) -> (u32, [i64; CELLS]) {
    let n = row.len().min(crow.len()).min(noise.len()).min(cols.len());
    let mut cells = [0i64; CELLS];
    let mut flat = 0u32;
    let runs = row[..n]
        .chunks(NARROW_RUN)
        .zip(crow[..n].chunks(NARROW_RUN))
        .zip(noise[..n].chunks_mut(NARROW_RUN))
        .zip(cols[..n].chunks_mut(NARROW_RUN));
    for (((row, crow), noise), cols) in runs {
        // A run starts at a multiple of CELLS: its lane `k` is cell `k mod CELLS`.
        let (f, lanes) = noise_lines_run(row, crow, line_top, noise, cols);
        flat += f;
        for (k, l) in lanes.iter().enumerate() {
            cells[k % CELLS] += *l as i64;
        }
    }
    (flat, cells)
}

/// One run of [`noise_and_line_sums`] (at most [`NARROW_RUN`] pixels): returns its flat pixels
/// and its line sums per lane `x mod 16` (a vector of 32-bit lanes under AVX-512). Branch-free,
/// compiled for AVX-512 and AVX2 as well as the baseline, the CPU's best picked at run time.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512dq+avx512vl+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3",
    "x86_64+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3"
))]
fn noise_lines_run(row: &[u16], crow: &[u16], line_top: u16, noise: &mut [i32], cols: &mut [i32]) -> (u32, [i32; 16]) {
    const LANES: usize = 16;
    let n = row.len().min(crow.len()).min(noise.len()).min(cols.len());
    let (row, crow, noise, cols) = (&row[..n], &crow[..n], &mut noise[..n], &mut cols[..n]);
    let mut lanes = [0i32; LANES];
    let mut flat = [0u32; LANES];
    // The noise is 0 where not flat, so the line mask needs only the line top.
    #[inline(always)]
    fn one(v: u16, c: u16, line_top: u16, noise: &mut i32, col: &mut i32, lane: &mut i32, flat: &mut u32) {
        let is_flat = c != NOT_FLAT;
        let d = (v as i32 - c as i32) & (is_flat as i32).wrapping_neg();
        *noise = d;
        let m = d & ((c <= line_top) as i32).wrapping_neg();
        *col += m;
        *lane += m;
        *flat += is_flat as u32;
    }
    let steps = row
        .chunks_exact(LANES)
        .zip(crow.chunks_exact(LANES))
        .zip(noise.chunks_exact_mut(LANES))
        .zip(cols.chunks_exact_mut(LANES));
    for (((qv, qc), qn), qcols) in steps {
        for k in 0..LANES {
            one(qv[k], qc[k], line_top, &mut qn[k], &mut qcols[k], &mut lanes[k], &mut flat[k]);
        }
    }
    let done = n / LANES * LANES;
    for k in 0..n - done {
        let x = done + k;
        one(row[x], crow[x], line_top, &mut noise[x], &mut cols[x], &mut lanes[k], &mut flat[k]);
    }
    (flat.iter().sum(), lanes)
}

/// One run of [`line_sums_narrow`] (at most [`NARROW_RUN`] pixels): the masked noise into its
/// columns' sums, and its sums per lane `x mod 8`. Branch-free, so that the compiler vectorises
/// it; compiled for AVX-512 and AVX2 as well as the baseline, the CPU's best picked at run time.
#[multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512dq+avx512vl+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3",
    "x86_64+avx2+avx+fma+bmi1+bmi2+lzcnt+popcnt+sse4.1+sse4.2+ssse3"
))]
fn narrow_run(noise: &[i32], crow: &[u16], line_top: u16, cols: &mut [i32]) -> [i32; 8] {
    const LANES: usize = 8;
    let n = noise.len().min(crow.len()).min(cols.len());
    let (noise, crow, cols) = (&noise[..n], &crow[..n], &mut cols[..n]);
    let mut lanes = [0i32; LANES];
    let masked = |n: i32, c: u16| n & (in_lines(c, line_top) as i32).wrapping_neg();
    let steps = noise.chunks_exact(LANES).zip(crow.chunks_exact(LANES)).zip(cols.chunks_exact_mut(LANES));
    for ((qn, qc), qcols) in steps {
        for k in 0..LANES {
            let m = masked(qn[k], qc[k]);
            qcols[k] += m;
            lanes[k] += m;
        }
    }
    let done = n / LANES * LANES;
    for (k, ((&v, &c), col)) in noise[done..].iter().zip(&crow[done..]).zip(&mut cols[done..]).enumerate() {
        let m = masked(v, c);
        *col += m;
        lanes[k] += m;
    }
    lanes
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The narrow line sums are the 64-bit ones exactly: noise up to ±65535, pixels not flat or
    /// above the line top among them, rows shorter than the lanes, and a row of many runs with
    /// a tail past the lanes whose cell sums pass 2³¹ (so a version that summed a whole row in
    /// 32 bits fails, as does one that put a run's lane into the wrong cell or dropped the
    /// tail), columns already holding sums.
    #[test]
    fn narrow_line_sums_are_the_wide_ones() {
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let line_top = 60_000u16;
        for w in [7usize, 37, NARROW_RUN * 18 + 13] {
            let mut wide_cols: Vec<i64> = (0..w).map(|_| (next() % 1000) as i64 - 500).collect();
            let mut narrow_cols = vec![0i32; w];
            let start = wide_cols.clone();
            for _row in 0..3 {
                let crow: Vec<u16> = (0..w)
                    .map(|_| match next() % 8 {
                        0 => NOT_FLAT,
                        1 => 60_001 + (next() % 5000) as u16,
                        _ => (next() % 60_001) as u16,
                    })
                    .collect();
                // Mostly the top, so that the sums are large.
                let noise: Vec<i32> = crow
                    .iter()
                    .map(|&c| match (c == NOT_FLAT, next() % 4) {
                        (true, _) => 0,
                        (false, 0) => (next() % 131_071) as i32 - 65_535,
                        _ => 65_535,
                    })
                    .collect();
                let wide = line_sums(&noise, &crow, line_top, &mut wide_cols);
                let narrow = line_sums_narrow(&noise, &crow, line_top, &mut narrow_cols);
                assert_eq!(wide, narrow, "width {w}");
                if w > NARROW_RUN {
                    assert!(narrow.iter().any(|c| c.abs() > i32::MAX as i64), "sums past 32 bits");
                }
            }
            let mut from_narrow = start.clone();
            widen_into(&mut narrow_cols, &mut from_narrow);
            assert_eq!(from_narrow, wide_cols, "width {w}");
            assert!(narrow_cols.iter().all(|&c| c == 0), "the narrow sums were cleared");
        }
    }

    /// The one-pass noise and line sums are [`noise_row`] then [`line_sums_narrow`] exactly: the
    /// same noise, column sums, cell sums and flat count, on rows with pixels not flat and above
    /// the line top, raw values far from their clean levels (noise up to ±65535), widths below
    /// the lanes, off the lanes and over many runs with a tail, columns already holding sums. A
    /// version that put lane `k` into cell `k mod 8`'s place, dropped the tail, or kept the noise
    /// of a pixel that is not flat differs in the cell sums, the columns or the noise.
    #[test]
    fn noise_and_line_sums_are_noise_then_line_sums() {
        let mut s = 0x2545_F491_4F6C_DD1Du64;
        let mut next = move || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            s
        };
        let line_top = 60_000u16;
        for w in [3usize, 16, 37, NARROW_RUN * 3 + 21] {
            let start: Vec<i32> = (0..w).map(|_| (next() % 1000) as i32 - 500).collect();
            let (mut two_cols, mut one_cols) = (start.clone(), start.clone());
            for _row in 0..3 {
                let crow: Vec<u16> = (0..w)
                    .map(|_| match next() % 8 {
                        0 => NOT_FLAT,
                        1 => 60_001 + (next() % 5000) as u16,
                        _ => (next() % 60_001) as u16,
                    })
                    .collect();
                let row: Vec<u16> = crow
                    .iter()
                    .map(|&c| match next() % 4 {
                        0 => (next() % 65_536) as u16,
                        _ => c.saturating_add((next() % 25) as u16).saturating_sub(12),
                    })
                    .collect();
                let (mut two_noise, mut one_noise) = (vec![7i32; w], vec![-7i32; w]);
                let flat = noise_row(&row, &crow, &mut two_noise);
                let cells = line_sums_narrow(&two_noise, &crow, line_top, &mut two_cols);
                let (one_flat, one_cells) = noise_and_line_sums(&row, &crow, line_top, &mut one_noise, &mut one_cols);
                assert_eq!(one_noise, two_noise, "width {w}");
                assert_eq!((one_flat, one_cells), (flat, cells), "width {w}");
                assert_eq!(one_cols, two_cols, "width {w}");
                assert!(cells.iter().any(|&c| c != 0), "width {w}: line sums that say something");
            }
        }
    }
}
