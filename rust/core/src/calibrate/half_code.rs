//! Flat pixels whose clean code is wrong at sub-DN noise, at the codes where they would bias the
//! code's noise (method.md, "Selection by the clean image", issue 21).
//!
//! The clean code is `round(mean)` of an M-frame burst, whose error has the SD `σ_e`. Where the
//! noise is sub-DN, `σ_e` is a tenth of a DN or two, and a pixel whose mean lies near a half
//! code may be rounded to the other code: it lands there with the sample `noisy − code` of a
//! clean level `x` beyond the code's range. The selection correction cannot see a rounding (its
//! kernel is at least 0.5 DN wide over whole codes). Where the clean levels fill the codes
//! evenly this is harmless: a pixel crosses a half code in each direction about as often, and
//! one that crossed has a clean level just beyond the code's edge, a sample like the code's
//! own. Where the levels cluster (a flat patch 0.37 DN into a code), the code next to the
//! cluster receives pixels whose clean level lies far beyond its edge, and on a ladder of flat
//! steps the codes between the steps hold little else.
//!
//! So, per position, the clean levels' density `g` is estimated from the burst's sums by
//! deconvolution (the EM iteration of the nonparametric maximum likelihood, on the lattice of
//! the sums; the kernel of a level `x` is the sum of M rounded frames `round(x + n)`, a Gaussian
//! with that sum's mean and variance at `x`'s phase in its code), and each flat pixel's clean
//! level gets its posterior given its sum. Per code `c` the rule reads the expected shift of
//! the code's mean by the clean levels beyond its range,
//! `shift(c) = mean over the code's pixels of E[d − clamp(d, −½, ½) | sum]`, `d = x − c`: zero
//! where every pixel's clean level rounds to `c`, about −0.3 … −0.5 `σ_e` at the code just
//! above a step 0.37 DN into its code (two thirds of its pixels crossed, from just below the
//! half code), and 0.8 … 1.3 `σ_e` at a code that only a step's tail reaches. Where
//! `|shift(c)|` exceeds [`WRONG_SHIFT_SES`] `σ_e`, the code's pixels whose clean level most
//! likely rounds to another code (posterior probability above ½) leave the flat set; elsewhere
//! nothing changes. The rule applies where the per-frame noise variance is below
//! [`SUB_DN_VARIANCE`] and `σ_e` at most [`MAX_MEAN_SD`]: where the mean's error is a sizeable
//! part of a code, codes are not wrong by a rounding near the half codes only.

use crate::math::special::normal_mass;
use crate::model::layout::{POSITIONS, position};

/// The per-frame noise variance (DN²) from which on a level's codes are left as they are: the
/// rule is for sub-DN noise only.
pub(crate) const SUB_DN_VARIANCE: f64 = 1.0;

/// The largest SD of the clean image's error (DN) at which the rule applies.
pub(crate) const MAX_MEAN_SD: f64 = 0.2;

/// The expected shift of a code's mean by its pixels' clean levels beyond the code's range, in
/// SDs `σ_e` of the mean's error, from which on the code's pixels that most likely belong to
/// another code leave the flat set. Pixels that cross a half code from a cluster of levels just
/// beyond it (the code above a step 0.37 DN into its code) lie within about `σ_e` of the code's
/// edge and shift it by 0.27–0.48 `σ_e`; pixels that arrive from a cluster two or more `σ_e`
/// away (a code only a step's tail reaches) by 0.8–1.3 `σ_e` (estimated as here, on
/// sim_tiles.py's ladder at `σ_e` 0.13–0.19 DN and this module's test; method.md).
pub(crate) const WRONG_SHIFT_SES: f64 = 0.6;

/// The posterior probability that a pixel's clean level rounds to another code above which it
/// leaves a code where the rule fires.
const WRONG_PROBABILITY: f64 = 0.5;

/// EM iterations of the deconvolution.
const ITERATIONS: usize = 200;

/// The half-width of the mean's error kernel, in its SDs.
const KERNEL_SDS: f64 = 4.0;

/// The SD of the clean image's error (DN) at a level whose error has the variance
/// `mean_variance` (of an `frames`-frame burst) where the rule applies (sub-DN per-frame noise,
/// the SD at most [`MAX_MEAN_SD`]), else 0.
pub(crate) fn mean_sd(mean_variance: f64, frames: u32) -> f64 {
    let per_frame = mean_variance * frames as f64;
    let applies =
        frames >= 2 && per_frame < SUB_DN_VARIANCE && mean_variance > 0.0 && mean_variance <= MAX_MEAN_SD * MAX_MEAN_SD;
    if applies { mean_variance.sqrt() } else { 0.0 }
}

/// The clean level of a sum: `round(sum / frames)` with halves up, clamped to `white`.
fn level_of(sum: u64, frames: u64, white: u16) -> u16 {
    ((2 * sum + frames) / (2 * frames)).min(white as u64) as u16
}

/// One position's sums of flat pixels at the levels where the rule applies.
struct Sums {
    /// The lowest sum counted.
    lo: u64,
    /// Pixels per sum from `lo`.
    count: Vec<u64>,
}

/// What the deconvolution says per sum of one position.
struct Verdict {
    /// The codes (levels) at which the rule fires.
    fires: Vec<bool>,
    /// Per sum from `lo`: its pixels' clean level most likely rounds to another code.
    wrong: Vec<bool>,
}

/// The SD of the mean's error per level, gaps (levels where the rule does not apply) filled from
/// the nearest level below (else above) where it does; `None` where it applies nowhere.
fn filled(sds: &[f64]) -> Option<Vec<f64>> {
    let first = sds.iter().copied().find(|&s| s > 0.0)?;
    let mut last = first;
    Some(
        sds.iter()
            .map(|&s| {
                if s > 0.0 {
                    last = s;
                }
                last
            })
            .collect(),
    )
}

/// The deconvolution of one position's sums, and the codes where the rule fires.
fn judge(sums: &Sums, sds: &[f64], frames: u64, white: u16) -> Option<Verdict> {
    let total: u64 = sums.count.iter().sum();
    if total == 0 {
        return None;
    }
    let sd = filled(sds)?;
    let m = frames as f64;
    // Per level, the per-frame noise SD before the frames' rounding: the mean's error is that
    // of rounded frames, `(σ² + 1/12)/M` spread evenly over the phases (at least a quarter of
    // the rounded frames' variance).
    let noise: Vec<f64> = sd
        .iter()
        .map(|&e| {
            let v = e * e * m;
            (v - 1.0 / 12.0).max(0.25 * v).sqrt()
        })
        .collect();
    // The kernel of a clean level `x`: the sum of M frames `round(x + n)`, a Gaussian on the
    // sums' lattice with that sum's mean and variance at `x`'s own phase (near a half code the
    // rounding spreads a sum most, at a code's centre least; one SD for all phases put atoms of
    // `g` at the half codes and read a step's tail in the empty code next to it as that code's
    // own: the codes no step reaches read +0.04 DN where the truth is +0.16).
    let frame_moments = |x: f64, sigma: f64| -> (f64, f64) {
        let r = (6.0 * sigma).ceil() + 1.0;
        let (mut p0, mut p1, mut p2) = (0.0, 0.0, 0.0);
        let mut k = x.floor() - r;
        while k <= x.ceil() + r {
            let p = normal_mass((k - 0.5 - x) / sigma, (k + 0.5 - x) / sigma);
            p0 += p;
            p1 += p * k;
            p2 += p * k * k;
            k += 1.0;
        }
        let mu = p1 / p0;
        (mu, (p2 / p0 - mu * mu).max(1e-4))
    };
    let level_at = |x: f64| (x.round().max(0.0) as usize).min(sd.len() - 1);
    let widest = noise.iter().map(|&s| s * s + 0.25).fold(0.0f64, f64::max);
    let reach = ((KERNEL_SDS * (widest * m).sqrt()).ceil() + (m / 2.0).ceil() + 1.0) as usize;
    let n = sums.count.len();
    let grid = n + 2 * reach;
    let width = 2 * reach + 1;
    // kernel[j * width + t]: P(sum = lo + j + t − 2·reach | x = (lo + j − reach) / M), the
    // grid of clean levels on the sums' lattice, `reach` beyond the counted sums on each side.
    let mut kernel = vec![0.0f64; grid * width];
    for j in 0..grid {
        let x = (sums.lo as f64 + j as f64 - reach as f64) / m;
        let (mu, v) = frame_moments(x, noise[level_at(x)]);
        let (centre, var) = (m * (mu - x), m * v);
        let row = &mut kernel[j * width..(j + 1) * width];
        let mut norm = 0.0;
        for (t, k) in row.iter_mut().enumerate() {
            let u = t as f64 - reach as f64 - centre;
            *k = (-0.5 * u * u / var).exp();
            norm += *k;
        }
        row.iter_mut().for_each(|k| *k /= norm);
    }
    // EM for the mixing density g over the grid.
    let mut g = vec![1.0 / grid as f64; grid];
    let mut f = vec![0.0f64; n];
    let mut ratio = vec![0.0f64; n];
    let observed = |j: usize, t: usize| (j + t).checked_sub(2 * reach).filter(|&i| i < n);
    for _ in 0..ITERATIONS {
        f.iter_mut().for_each(|v| *v = 0.0);
        for j in 0..grid {
            if g[j] == 0.0 {
                continue;
            }
            for t in 0..width {
                if let Some(i) = observed(j, t) {
                    f[i] += g[j] * kernel[j * width + t];
                }
            }
        }
        for i in 0..n {
            ratio[i] = if sums.count[i] > 0 && f[i] > 0.0 { sums.count[i] as f64 / f[i] } else { 0.0 };
        }
        for j in 0..grid {
            if g[j] == 0.0 {
                continue;
            }
            let mut acc = 0.0;
            for t in 0..width {
                if let Some(i) = observed(j, t) {
                    acc += kernel[j * width + t] * ratio[i];
                }
            }
            g[j] *= acc / total as f64;
        }
    }
    // Per counted sum: the posterior over the grid, the shift of its code's mean by the clean
    // levels beyond the code, and whether it most likely belongs to another code.
    let mut shift = vec![0.0f64; white as usize + 1];
    let mut pixels = vec![0u64; white as usize + 1];
    let mut wrong = vec![false; n];
    for i in 0..n {
        if sums.count[i] == 0 {
            continue;
        }
        let code = level_of(sums.lo + i as u64, frames, white);
        let (mut p, mut beyond, mut other) = (0.0, 0.0, 0.0);
        // Grid point j = i + 2·reach − t sees sum i through kernel entry t.
        for t in 0..width {
            let Some(j) = (i + 2 * reach).checked_sub(t).filter(|&j| j < grid) else { continue };
            let w = g[j] * kernel[j * width + t];
            if w == 0.0 {
                continue;
            }
            let d = (sums.lo as f64 + j as f64 - reach as f64) / m - code as f64;
            // The floor and the ceiling hold every level beyond them.
            let d = if code == 0 { d.max(-0.5) } else { d };
            let d = if code == white { d.min(0.5) } else { d };
            p += w;
            beyond += w * (d - d.clamp(-0.5, 0.5));
            other += w * if d.abs() > 0.5 {
                1.0
            } else if d.abs() == 0.5 {
                0.5
            } else {
                0.0
            };
        }
        if p <= 0.0 {
            continue;
        }
        let c = sums.count[i];
        shift[code as usize] += c as f64 * beyond / p;
        pixels[code as usize] += c;
        wrong[i] = other / p > WRONG_PROBABILITY;
    }
    let fires = shift
        .iter()
        .zip(&pixels)
        .zip(&sd)
        .map(|((&s, &n), &e)| n > 0 && (s / n as f64).abs() > WRONG_SHIFT_SES * e)
        .collect();
    Some(Verdict { fires, wrong })
}

/// Leaves out of `clean` (row-major, `width` wide, `not_flat` where not flat) the flat pixels
/// whose clean code the rule finds most likely wrong at a code where the wrong ones would shift
/// its mean beyond [`WRONG_SHIFT_SES`] (module doc). `sds[pos][level]` is the SD of the clean
/// image's error where the rule applies at the level ([`mean_sd`]), 0 elsewhere. Returns the
/// pixels left out per position.
pub(crate) fn leave_out(
    clean: &mut [u16],
    sum: &[u32],
    width: usize,
    frames: u32,
    white: u16,
    not_flat: u16,
    sds: &[Vec<f64>; POSITIONS],
) -> [u64; POSITIONS] {
    let mut left = [0u64; POSITIONS];
    if frames < 2 || width == 0 || sds.iter().all(|b| b.iter().all(|&x| x <= 0.0)) {
        return left;
    }
    let m = frames as u64;
    let applies = |pos: usize, c: u16| sds[pos].get(c as usize).is_some_and(|&s| s > 0.0);
    // The sums' range per position: the levels where the rule applies.
    let mut sums: [Sums; POSITIONS] = std::array::from_fn(|pos| {
        let levels: Vec<usize> = (0..sds[pos].len()).filter(|&l| sds[pos][l] > 0.0).collect();
        match (levels.first(), levels.last()) {
            (Some(&a), Some(&b)) => {
                let lo = (2 * a as u64 * m).saturating_sub(m) / 2;
                let hi = (2 * b as u64 + 1) * m / 2;
                Sums { lo, count: vec![0; (hi - lo + 1) as usize] }
            }
            _ => Sums { lo: 0, count: Vec::new() },
        }
    });
    for (i, (&c, &s)) in clean.iter().zip(sum).enumerate() {
        if c == not_flat {
            continue;
        }
        let pos = position(i / width, i % width);
        if !applies(pos, c) {
            continue;
        }
        let k = &mut sums[pos];
        if let Some(n) = (s as u64).checked_sub(k.lo).and_then(|i| k.count.get_mut(i as usize)) {
            *n += 1;
        }
    }
    let verdicts: [Option<Verdict>; POSITIONS] =
        std::array::from_fn(|pos| judge(&sums[pos], &sds[pos], m, white).filter(|v| v.fires.iter().any(|&f| f)));
    if verdicts.iter().all(Option::is_none) {
        return left;
    }
    for (i, (c, &s)) in clean.iter_mut().zip(sum).enumerate() {
        if *c == not_flat {
            continue;
        }
        let pos = position(i / width, i % width);
        let Some(v) = &verdicts[pos] else { continue };
        if !applies(pos, *c) || !v.fires[*c as usize] {
            continue;
        }
        let k = &sums[pos];
        let wrong = (s as u64).checked_sub(k.lo).and_then(|i| v.wrong.get(i as usize)).copied().unwrap_or(false);
        if wrong {
            *c = not_flat;
            left[pos] += 1;
        }
    }
    left
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn gaussian(rng: &mut ChaCha8Rng) -> f64 {
        let (u, v): (f64, f64) = (rng.random::<f64>().max(1e-300), rng.random());
        (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
    }

    /// The SD is zero where the noise is 1 DN or more (nothing changes there), where the mean's
    /// error passes [`MAX_MEAN_SD`], and for a one-frame burst; the mean's SD elsewhere.
    #[test]
    fn applies_only_at_sub_dn_noise() {
        assert_eq!(mean_sd(1.0 / 8.0, 8), 0.0);
        assert_eq!(mean_sd(4.0 / 16.0, 16), 0.0);
        assert_eq!(mean_sd(0.3, 1), 0.0);
        assert_eq!(mean_sd(0.0, 8), 0.0);
        // Sub-DN noise, but the mean's error a third of a code.
        assert_eq!(mean_sd(0.9 / 8.0, 8), 0.0);
        assert!((mean_sd(0.25 / 8.0, 8) - (0.25f64 / 8.0).sqrt()).abs() < 1e-12);
    }

    /// Clean levels, their 8-frame sums of rounded frames (per-frame SD `sd`), and what the rule
    /// leaves: per code, (pixels whose clean level rounds to it, pixels the burst assigned to
    /// it, of those kept the ones whose clean level rounds to it, and the others), and the
    /// pixels left out.
    fn ladder(truth: &[f64], sd: f64, rng: &mut ChaCha8Rng) -> (Vec<[usize; 4]>, u64) {
        const FRAMES: u32 = 8;
        let sums: Vec<u32> = truth
            .iter()
            .map(|&c| (0..FRAMES).map(|_| (c + sd * gaussian(rng)).round().max(0.0) as u32).sum())
            .collect();
        let mut clean: Vec<u16> = sums.iter().map(|&s| level_of(s as u64, FRAMES as u64, 255)).collect();
        let mut codes = vec![[0usize; 4]; 256];
        for (&t, &c) in truth.iter().zip(&clean) {
            codes[t.round() as usize][0] += 1;
            codes[c as usize][1] += 1;
        }
        // The mean's error as the flat test measures it: rounded frames, `(σ² + 1/12)/M`.
        let se = mean_sd((sd * sd + 1.0 / 12.0) / FRAMES as f64, FRAMES);
        assert!(se > 0.0);
        let sds: [Vec<f64>; POSITIONS] = std::array::from_fn(|_| vec![se; 256]);
        let left: u64 = leave_out(&mut clean, &sums, 128, FRAMES, 255, u16::MAX, &sds).iter().sum();
        for (&t, &c) in truth.iter().zip(&clean) {
            if c != u16::MAX {
                codes[c as usize][if c as f64 == t.round() { 2 } else { 3 }] += 1;
            }
        }
        (codes, left)
    }

    /// Known truth: a ladder of flat steps like sim_tiles.py's (levels 0.37 DN into a code or
    /// 0.13 DN below one, a fixed pattern of 0.1 DN, 8 rounded frames of SD 0.4 DN: `σ_e`
    /// 0.17 DN). The codes no step reaches (under 1 % of a step's clean levels round to them)
    /// held 1–2 % of a step's pixels, all one code off; the rule keeps at most a tenth of those
    /// wrong pixels there. A code that holds a step keeps at least 99.5 % of its pixels (a band
    /// of 2 `σ_e` around every half code, branch halfcode12's rule, left out 39 % of the 0.37 DN
    /// steps' pixels, and fails). Clean levels spread evenly over the codes (no cluster):
    /// nothing fires inside the range, so a rule that read the share of pixels near a half code
    /// (0.8·`σ_e` of every code) fails; the codes beyond the range's ends, which only its edge
    /// reaches, may lose theirs.
    #[test]
    fn leaves_out_wrong_codes_only_where_a_cluster_spills_into_an_empty_code() {
        let mut rng = ChaCha8Rng::seed_from_u64(21);
        let steps = [10.37, 13.87, 17.37, 20.87, 24.37, 27.87];
        let per_step = 16_384;
        let truth: Vec<f64> = steps
            .iter()
            .flat_map(|&l| (0..per_step).map(|_| l + 0.1 * gaussian(&mut rng)).collect::<Vec<_>>())
            .collect();
        let (codes, left) = ladder(&truth, 0.4, &mut rng);
        let (mut unreached, mut wrong_before, mut wrong_kept, mut unreached_pixels) = (0, 0, 0, 0);
        for (code, &[true_px, assigned, right, wrong]) in codes.iter().enumerate() {
            if assigned == 0 {
                continue;
            }
            eprintln!("code {code}: true {true_px} assigned {assigned} kept right {right} wrong {wrong}");
            if true_px * 100 < per_step {
                unreached += 1;
                unreached_pixels += assigned;
                wrong_before += assigned - true_px.min(assigned);
                wrong_kept += wrong;
            }
            if true_px * 2 > per_step {
                assert!(
                    (right + wrong) as f64 >= 0.995 * assigned as f64,
                    "code {code} (a step's): kept {} of {assigned}",
                    right + wrong
                );
            }
        }
        assert!(unreached >= 3 && wrong_before * 100 > 3 * per_step, "{unreached} codes, {wrong_before} wrong");
        assert!(10 * wrong_kept <= wrong_before, "{wrong_kept} of {wrong_before} wrong pixels kept");
        // Beyond the codes no step reaches, under 0.5 % of the pixels.
        assert!((left as f64) < (unreached_pixels as f64) + 0.005 * truth.len() as f64, "left out {left}");

        // From half code to half code: codes 10–25 lie inside, 9 and 26 beyond the ends.
        let even: Vec<f64> = (0..100_000).map(|_| 9.5 + 16.0 * rng.random::<f64>()).collect();
        let (codes, _) = ladder(&even, 0.4, &mut rng);
        for (code, &[_, assigned, right, wrong]) in codes.iter().enumerate().take(26).skip(10) {
            assert_eq!(right + wrong, assigned, "levels spread evenly: code {code} lost pixels");
        }
    }
}
