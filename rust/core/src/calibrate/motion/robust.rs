//! The robust weighting a frame's registration fits with: per-row robust offsets, Huber and
//! Tukey weights, Tukey's loss, taking each row's mean out, and the median they all rest on.

/// Tukey's biweight constant (95 % efficiency on Gaussian noise).
pub(super) const TUKEY_C: f64 = 4.685;

/// One sample of a fit: its row, weight, Jacobian row and residual.
pub(super) type Row<const N: usize> = (usize, f64, [f64; N], f64);

/// The median of the finite values of `v` (reordered in place; NaN when there are none): the
/// value [`crate::math::stats::median`] gives, bit for bit, by selection instead of a sort.
pub(super) fn median_in_place(v: &mut Vec<f64>) -> f64 {
    v.retain(|x| x.is_finite());
    let n = v.len();
    if n == 0 {
        return f64::NAN;
    }
    let (low, mid, _) = v.select_nth_unstable_by(n / 2, f64::total_cmp);
    let mid = *mid;
    if n % 2 == 1 { mid } else { 0.5 * (low.iter().copied().max_by(f64::total_cmp).unwrap_or(mid) + mid) }
}

/// Sets each sample's weight (`.1`) from its residual (`.3`) less its row's median residual
/// (the row offset, estimated robustly: a glitch of a hundred SD moves a row's mean by several
/// SD of the noise, and every residual of the row with it), at the sample's own scale
/// `hypot(scale, slack)` (`slack`: the model's slack times its gradient): Huber's at 3 scales
/// or, when `redescend`, Tukey's biweight at [`TUKEY_C`]. An infinite `scale` (a first fit) is
/// taken from the deviations' own MAD.
pub(super) fn robust_weights<const N: usize>(rows: &mut [Row<N>], slack: &[f64], scale: f64, redescend: bool) {
    let mut dev = Vec::with_capacity(rows.len());
    let mut scratch = Vec::new();
    for group in rows.chunk_by(|a, b| a.0 == b.0) {
        scratch.clear();
        scratch.extend(group.iter().map(|r| r.3));
        let centre = median_in_place(&mut scratch);
        dev.extend(group.iter().map(|r| r.3 - centre));
    }
    let scale = if scale.is_finite() {
        scale
    } else {
        scratch.clear();
        scratch.extend(dev.iter().map(|d| d.abs()));
        (1.4826 * median_in_place(&mut scratch)).max(0.25)
    };
    for ((r, d), sl) in rows.iter_mut().zip(&dev).zip(slack) {
        let z = (d / scale.hypot(*sl)).abs();
        r.1 = if redescend {
            if z < TUKEY_C { (1.0 - (z / TUKEY_C).powi(2)).powi(2) } else { 0.0 }
        } else if z <= 3.0 {
            1.0
        } else {
            3.0 / z
        };
    }
}

/// Tukey's biweight loss of a residual at `scale` (bounded: a glitch costs what any outlier does).
#[inline]
pub(super) fn tukey(r: f64, scale: f64) -> f64 {
    let z = (r / scale).abs();
    let c2 = TUKEY_C * TUKEY_C;
    scale * scale * if z < TUKEY_C { c2 / 6.0 * (1.0 - (1.0 - z * z / c2).powi(3)) } else { c2 / 6.0 }
}

/// Takes each row's mean (weights `.1`) out of the Jacobian rows `.2` and residuals `.3` of its
/// samples (`.0`: the row; samples of a row are contiguous, as the probe lists them).
pub(super) fn demean_rows<const N: usize>(rows: &mut [Row<N>]) {
    for group in rows.chunk_by_mut(|a, b| a.0 == b.0) {
        let wsum: f64 = group.iter().map(|r| r.1).sum();
        if wsum > 0.0 {
            let mut mj = [0.0f64; N];
            let mut mr = 0.0;
            for r in group.iter() {
                for k in 0..N {
                    mj[k] += r.1 * r.2[k];
                }
                mr += r.1 * r.3;
            }
            for r in group.iter_mut() {
                for k in 0..N {
                    r.2[k] -= mj[k] / wsum;
                }
                r.3 -= mr / wsum;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::stats::median;

    /// Selection gives the sorted median bit for bit: odd and even counts, ties, signed zeros,
    /// non-finite values left out.
    #[test]
    fn the_selected_median_is_the_sorted_one() {
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        for n in 0..200usize {
            let v: Vec<f64> = (0..n)
                .map(|i| {
                    s ^= s << 13;
                    s ^= s >> 7;
                    s ^= s << 17;
                    match i % 11 {
                        0 => 0.0,
                        1 => -0.0,
                        2 => f64::NAN,
                        3 => 1.5,
                        _ => (s % 1000) as f64 / 7.0 - 70.0,
                    }
                })
                .collect();
            let want = median(&v);
            let got = median_in_place(&mut v.clone());
            assert!(want.to_bits() == got.to_bits() || (want.is_nan() && got.is_nan()), "n {n}: {got} vs {want}");
        }
    }
}
