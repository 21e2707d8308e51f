//! Small non-negative least-squares fits of polynomials in one variable, used for noise
//! variance and mean curves (never negative where the physics says so).

/// Weighted least squares `y ≈ Σ c_k x^k` (k over `degree + 1` terms) with `c ≥ 0`, solved by
/// trying every active set (degree ≤ 3, so at most 16 small systems). Returns the coefficients.
pub fn nn_poly_fit(x: &[f64], y: &[f64], w: &[f64], degree: usize) -> Vec<f64> {
    let k = degree + 1;
    let mut best: Option<(f64, Vec<f64>)> = None;
    for mask in 1u32..(1 << k) {
        let terms: Vec<usize> = (0..k).filter(|t| mask & (1 << t) != 0).collect();
        let Some(c) = wls(x, y, w, &terms) else {
            continue;
        };
        if c.iter().any(|&v| v < 0.0) {
            continue;
        }
        let mut full = vec![0.0; k];
        for (t, &v) in terms.iter().zip(&c) {
            full[*t] = v;
        }
        let err = sse(x, y, w, &full);
        if best.as_ref().is_none_or(|(e, _)| err < *e) {
            best = Some((err, full));
        }
    }
    best.map(|b| b.1).unwrap_or_else(|| {
        // Nothing feasible: a constant at the weighted mean, clamped at 0.
        let sw: f64 = w.iter().sum();
        let m = if sw > 0.0 { x.iter().zip(y).zip(w).map(|((_, y), w)| y * w).sum::<f64>() / sw } else { 0.0 };
        let mut c = vec![0.0; k];
        c[0] = m.max(0.0);
        c
    })
}

/// Unconstrained weighted least squares over the given powers.
pub fn wls(x: &[f64], y: &[f64], w: &[f64], terms: &[usize]) -> Option<Vec<f64>> {
    let n = terms.len();
    let mut a = vec![vec![0.0f64; n + 1]; n];
    for i in 0..x.len() {
        let row: Vec<f64> = terms.iter().map(|&t| x[i].powi(t as i32)).collect();
        for r in 0..n {
            for c in 0..n {
                a[r][c] += w[i] * row[r] * row[c];
            }
            a[r][n] += w[i] * row[r] * y[i];
        }
    }
    solve(a)
}

/// Evaluates `Σ c_k x^k`.
pub fn poly_eval(c: &[f64], x: f64) -> f64 {
    c.iter().rev().fold(0.0, |acc, &k| acc * x + k)
}

fn sse(x: &[f64], y: &[f64], w: &[f64], c: &[f64]) -> f64 {
    x.iter().zip(y).zip(w).map(|((&x, &y), &w)| w * (poly_eval(c, x) - y).powi(2)).sum()
}

/// Solves the augmented system `a = [A | b]` (n rows of n + 1) by Gauss–Jordan elimination with
/// partial pivoting; `None` when `A` is singular.
pub(crate) fn solve(mut a: Vec<Vec<f64>>) -> Option<Vec<f64>> {
    let n = a.len();
    for col in 0..n {
        let piv = (col..n).max_by(|&i, &j| a[i][col].abs().total_cmp(&a[j][col].abs()))?;
        let scale = a.iter().map(|r| r[col].abs()).fold(0.0, f64::max).max(1e-300);
        if a[piv][col].abs() < 1e-12 * scale {
            return None;
        }
        a.swap(col, piv);
        for r in 0..n {
            if r != col {
                let f = a[r][col] / a[col][col];
                for c in col..=n {
                    a[r][c] -= f * a[col][c];
                }
            }
        }
    }
    Some((0..n).map(|i| a[i][n] / a[i][i]).collect())
}

/// The inverse of a small square matrix (`None` when singular).
pub(crate) fn invert(a: &[Vec<f64>]) -> Option<Vec<Vec<f64>>> {
    let n = a.len();
    let cols: Option<Vec<Vec<f64>>> = (0..n)
        .map(|k| {
            let aug: Vec<Vec<f64>> = a
                .iter()
                .enumerate()
                .map(|(r, row)| {
                    let mut v = row.clone();
                    v.push(if r == k { 1.0 } else { 0.0 });
                    v
                })
                .collect();
            solve(aug)
        })
        .collect();
    let cols = cols?;
    Some((0..n).map(|r| (0..n).map(|c| cols[c][r]).collect()).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recovers_nonnegative_quadratic() {
        let x: Vec<f64> = (0..50).map(|i| i as f64 * 20.0).collect();
        let y: Vec<f64> = x.iter().map(|&x| 3.0 + 0.5 * x + 0.001 * x * x).collect();
        let w = vec![1.0; x.len()];
        let c = nn_poly_fit(&x, &y, &w, 2);
        assert!((c[0] - 3.0).abs() < 1e-6 && (c[1] - 0.5).abs() < 1e-8 && (c[2] - 0.001).abs() < 1e-10, "{c:?}");
    }

    #[test]
    fn never_negative() {
        // Data that an unconstrained fit would give a negative intercept.
        let x = [10.0, 20.0, 30.0, 40.0];
        let y = [1.0, 12.0, 23.0, 34.0];
        let c = nn_poly_fit(&x, &y, &[1.0; 4], 1);
        assert!(c.iter().all(|&v| v >= 0.0));
        assert!(poly_eval(&c, 0.0) >= 0.0);
    }
}
