//! The clean image's own error sorts pixels into bins (method.md, "Selection by the clean
//! image").
//!
//! A sample is `n = noisy − round(Î)` where the clean estimate `Î = I + e` carries the error of a
//! mean of `M` reference frames, `e ~ (0, σ_e²)`, `σ_e² = σ_ref²(l)/M`. Its bin is chosen by `Î`,
//! so a pixel whose estimate came out high lands in a higher bin, with a noise `n = n_true − e`
//! whose mean is negative there. By Tweedie's formula the mean shift at a clean estimate `c` is
//!
//! `E[n | Î = c] − E[n_true] = −E[e | Î = c] = σ_e²(c) · (log f)′(c)`,
//!
//! `f` being the density of clean estimates over the flat pixels of the step. On a chart with
//! many patches and a long reference burst the shift is a fraction of a DN; on a flat field with
//! a 4-frame reference at the target's own gain it swings by ±30 DN across a bin cluster (real
//! flat-field bursts of an IMX541, measured): the per-bin means then describe the calibration
//! scene, not the sensor, and mislead every level the scene did not cover. The session sums the
//! shift per bin over the samples it adds ([`bin_sums`]); the estimator removes each bin's
//! mean shift before building its PMF and gives it back the spread the error lost
//! (`Var(e | Î) = σ_e² − a`, see [`Selection`]), so a bin holds `n_true − e` with `e` independent
//! of the bin: the sensor's noise plus the clean image's error, as the paper's samples are
//! meant to be, whatever the calibration scene.
//!
//! `f` is a Gaussian kernel estimate of the clean-level histogram with bandwidth `σ_e(c)/4` (at
//! least half a DN, widened up to `σ_e` where few pixels are near): narrow enough to keep the
//! density's shape (`f` is itself smooth on the scale `σ_e`; a bandwidth `h` shrinks the shift of
//! a Gaussian scene by `σ_f²/(σ_f² + h²)`, 6 % at most here), wide enough to differentiate a
//! histogram.

/// Levels within this many bandwidths contribute to the kernel estimate.
const KERNEL_REACH: f64 = 4.0;
/// The bandwidth widens (from σ_e/4 up to σ_e) until ±2 bandwidths hold this many pixels.
const MIN_KERNEL_PIXELS: u64 = 200;

/// What selection does to the samples of one clean level: their mean shift
/// `δ = σ_e²·(log f)′` and the variance the error of the clean image loses, `a = −σ_e⁴·(log f)″`
/// (`Var(e | Î = c) = σ_e² − a`: on a narrow cluster of levels the estimate all but fixes the
/// error, which then shows as the shift instead of as spread).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Selection {
    pub shift: f64,
    pub lost_variance: f64,
}

/// [`Selection`] at every clean level `c` that occurs in `hist` (`hist[c]` = flat pixels whose
/// clean level is `c`); zero elsewhere. `var_e(c)` is the variance of the clean estimate's error
/// at level `c`.
pub fn selection(hist: &[u64], var_e: impl Fn(f64) -> f64) -> Vec<Selection> {
    let mut out = vec![Selection::default(); hist.len()];
    for c in (0..hist.len()).filter(|&c| hist[c] > 0) {
        let v = var_e(c as f64).max(0.0);
        if v < 1e-6 {
            continue;
        }
        let sd = v.sqrt();
        // The narrowest bandwidth from σ_e/4 up that sees enough pixels.
        let mut h = (0.25 * sd).max(0.5);
        while h < sd {
            let r = (2.0 * h).ceil() as usize;
            let seen: u64 = hist[c.saturating_sub(r)..=(c + r).min(hist.len() - 1)].iter().sum();
            if seen >= MIN_KERNEL_PIXELS {
                break;
            }
            h *= 1.5;
        }
        let reach = (KERNEL_REACH * h).ceil() as usize + 1;
        let lo = c.saturating_sub(reach);
        let hi = (c + reach).min(hist.len() - 1);
        let (mut f, mut d1, mut d2) = (0.0f64, 0.0f64, 0.0f64);
        for (k, &count) in hist.iter().enumerate().take(hi + 1).skip(lo) {
            if count == 0 {
                continue;
            }
            let z = (c as f64 - k as f64) / h;
            let g = count as f64 * (-0.5 * z * z).exp();
            f += g;
            d1 += g * (-z / h);
            d2 += g * (z * z - 1.0) / (h * h);
        }
        if f > 0.0 {
            let l1 = d1 / f;
            let l2 = d2 / f - l1 * l1;
            // Var(e | c) = σ_e² − a lies in [0, σ_e²] where the density is log-concave; a
            // kernel estimate's tails are not, so `a` is kept in that range.
            out[c] = Selection { shift: v * l1, lost_variance: (-v * v * l2).clamp(0.0, v) };
        }
    }
    out
}

/// [`bin_sums`]: per position and bin `[Σδ, Σδ², Σa]`, per position and level `[δ, a]`.
pub type SelectionSums = ([Vec<[f64; 3]>; 4], [Vec<[f64; 2]>; 4]);

/// Per bin, `[Σδ, Σδ², Σa]` over the flat pixels of one frame ([`Selection`]): `clean` holds
/// clean levels (or `not_flat`), row-major with CFA position `(y % 2)·2 + x % 2`; `var_e(pos,
/// level)` is the variance of the clean image's error; `bin_of[pos][level]` maps a level to its
/// bin. Returns `[pos][bin]`, and `[pos][level]` the `[δ, a]` of one pixel at each level (what a
/// sample left out of a frame takes back out of the sums).
pub fn bin_sums(
    clean: &[u16],
    width: usize,
    not_flat: u16,
    var_e: impl Fn(usize, f64) -> f64,
    bin_of: &[Vec<u16>; 4],
) -> SelectionSums {
    let levels = bin_of[0].len();
    let mut hists = [vec![0u64; levels], vec![0u64; levels], vec![0u64; levels], vec![0u64; levels]];
    for (i, &c) in clean.iter().enumerate() {
        if c == not_flat {
            continue;
        }
        let (y, x) = (i / width, i % width);
        let pos = ((y & 1) << 1) | (x & 1);
        hists[pos][(c as usize).min(levels - 1)] += 1;
    }
    let sel: [Vec<Selection>; 4] = std::array::from_fn(|pos| selection(&hists[pos], |c| var_e(pos, c)));
    let sums = std::array::from_fn(|pos| {
        let bins = bin_of[pos].iter().map(|&b| b as usize).max().map_or(0, |b| b + 1);
        let mut sums = vec![[0.0f64; 3]; bins];
        for (c, (&n, s)) in hists[pos].iter().zip(&sel[pos]).enumerate() {
            if n > 0 {
                let e = &mut sums[bin_of[pos][c] as usize];
                let n = n as f64;
                e[0] += n * s.shift;
                e[1] += n * s.shift * s.shift;
                e[2] += n * s.lost_variance;
            }
        }
        sums
    });
    let per_level = std::array::from_fn(|pos| sel[pos].iter().map(|s| [s.shift, s.lost_variance]).collect());
    (sums, per_level)
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// The selection shift alone at every level (see [`selection`]).
    fn selection_shift(hist: &[u64], var_e: impl Fn(f64) -> f64) -> Vec<f32> {
        selection(hist, var_e).iter().map(|s| s.shift as f32).collect()
    }

    /// A flat field: true levels spread by 2 DN around 1000, clean estimates with σ_e = 8 DN.
    /// The noise mean of pixels binned by their estimate follows Tweedie's formula.
    #[test]
    fn the_shift_matches_the_selection_it_explains() {
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let truth = Normal::new(1000.0, 2.0).expect("normal");
        let err = Normal::new(0.0, 8.0).expect("normal");
        let n = 2_000_000;
        let mut hist = vec![0u64; 1200];
        // Per estimated level: Σ(−e) and count, i.e. the mean of n − n_true.
        let mut sum = vec![0.0f64; 1200];
        for _ in 0..n {
            let i: f64 = truth.sample(&mut rng);
            let e: f64 = err.sample(&mut rng);
            let c = (i + e).round() as usize;
            hist[c] += 1;
            sum[c] += -e;
        }
        let shift = selection_shift(&hist, |_| 64.0);
        let mut checked = 0;
        for c in 975..1025 {
            if hist[c] < 20_000 {
                continue;
            }
            let observed = sum[c] / hist[c] as f64;
            // Exact for a Gaussian scene: −E[e|c] = −σ_e²/(σ_e² + σ_I²)·(c − μ) … with the sign
            // of n = n_true − e: E[n − n_true | c] = −(64/68)(c − 1000).
            let exact = -(64.0 / 68.0) * (c as f64 - 1000.0);
            assert!((observed - exact).abs() < 0.3, "simulation at {c}: {observed} vs {exact}");
            // The kernel estimate (bandwidth σ_e/4) recovers nearly all of it.
            assert!(
                (shift[c] as f64 - exact).abs() < 0.08 * exact.abs() + 0.3,
                "level {c}: shift {} vs {exact}",
                shift[c]
            );
            checked += 1;
        }
        assert!(checked > 20);
        // The variance the error loses: Var(e | c) = σ_e²σ_I²/(σ_e² + σ_I²) for a Gaussian scene,
        // so a = σ_e⁴/(σ_e² + σ_I²) = 64²/68 ≈ 60.2.
        let sel = selection(&hist, |_| 64.0);
        let a = sel[1000].lost_variance;
        assert!((a / (64.0 * 64.0 / 68.0) - 1.0).abs() < 0.12, "lost variance {a}");
        // No error, no shift.
        assert!(selection_shift(&hist, |_| 0.0).iter().all(|&s| s == 0.0));
    }
}
