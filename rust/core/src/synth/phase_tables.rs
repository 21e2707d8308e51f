//! One rounding per pixel where a bin's PMF sits at the lattice's floor (method.md, *Fixed
//! pattern*, "The dither"): the pixel's noise drawn at the sub-DN phase of its structured offset.
//!
//! Synthesis adds a pixel's fractional offset `o` (fixed pattern, row, column, frame) to whole
//! codes by a dither, `⌊o⌋ + [v < o − ⌊o⌋]`: a second rounding whose variance `f(1 − f)` the
//! narrowing takes out of the bin's PMF. A PMF on whole codes with mean fraction `f` holds at
//! least `f(1 − f)`, so where the noise is sub-DN and a bin's clean levels sit at one fraction of
//! a code (EMVA set 002, codes 4 and 7: one exposure each) the dither cannot be taken out and
//! is added on top. The sensor rounds once: signal, pattern and noise together. So in such a bin
//! the noise is read as a continuous `Y` whose rounding is the bin's deconvolved PMF `Q₀` (the
//! other components' kernel taken out, not the dither), and a pixel draws `⌊o⌋ + round(Y + φ)`,
//! `φ` the fraction of `o` on a grid of [`PHASES`] phases (dithered between its two nearest, so
//! the mean is `o` exactly): one table per phase.
//!
//! `Y`'s shape within a code is what the PMF cannot say; it is taken from the Gaussian whose
//! rounding has `Q₀`'s mean and variance, re-weighted code by code to `Q₀`'s masses (the
//! distribution nearest that Gaussian, in relative entropy, whose rounding is `Q₀` exactly), so
//! phase 0 draws `Q₀` itself. The piecewise-uniform reading (`Y` uniform within each code) is
//! the dither itself: it adds `f(1 − f)` whatever `Q₀`.

use crate::math::round::{floor_i32, round_half_away};

/// Phases per DN ([`PhaseSet`]): a power of two.
pub(crate) const PHASE_BITS: u32 = 4;
pub(crate) const PHASES: usize = 1 << PHASE_BITS;
/// Grid points per DN on which `Y` is held (a multiple of [`PHASES`], so each phase moves it by
/// whole grid points and no point sits on a code's edge).
const GRID: usize = 64;
/// The narrowest Gaussian tried (DN): a grid point and a half.
const SD_MIN: f64 = 1.5 / GRID as f64;

/// A bin's tables, one per phase `j/PHASES` of the pixel's offset: the PMF of `round(Y + j/PHASES)`.
#[derive(Debug, Clone, PartialEq)]
pub struct PhaseSet {
    first: i32,
    /// Values per phase (the same span for every phase).
    len: usize,
    /// Per phase, `len − 1` thresholds (units of 2⁻³²): a draw `u` gives `first + #{t ≤ u}`.
    thresholds: Box<[u64]>,
}

impl PhaseSet {
    /// The noise of a pixel whose structured offset is `o` (2⁻³² DN, fixed point): `⌊o⌋ +
    /// round(Y + φ)`, the phase `φ` the fraction of `o` put on the grid of [`PHASES`] by the
    /// pixel's dither draw `v` (the one the dither would have used), the noise drawn by `u`.
    #[inline]
    pub(crate) fn draw(&self, o: i64, v: u32, u: u32) -> i32 {
        let base = (o >> 32) as i32;
        let frac = (o as u64) & 0xFFFF_FFFF;
        let j = (((frac << PHASE_BITS) + u64::from(v)) >> 32) as usize;
        let (base, j) = if j == PHASES { (base + 1, 0) } else { (base, j) };
        base + self.sample(j, u)
    }

    /// A draw from phase `j`'s table.
    #[inline]
    fn sample(&self, j: usize, u: u32) -> i32 {
        let t = &self.thresholds[j * (self.len - 1)..(j + 1) * (self.len - 1)];
        self.first + t.iter().filter(|&&x| x <= u64::from(u)).count() as i32
    }

    /// Phase `j`'s PMF: `(first, probabilities)`.
    pub fn phase_pmf(&self, j: usize) -> (i32, Vec<f64>) {
        let t = &self.thresholds[j * (self.len - 1)..(j + 1) * (self.len - 1)];
        let edges: Vec<u64> = std::iter::once(0).chain(t.iter().copied()).chain(std::iter::once(1u64 << 32)).collect();
        (self.first, edges.windows(2).map(|w| (w[1] - w[0]) as f64 / 4294967296.0).collect())
    }

    /// Heap bytes held.
    pub fn heap_bytes(&self) -> usize {
        self.thresholds.len() * 8
    }
}

/// The phase tables of a bin whose deconvolved PMF is `q` (first value `first`), read as the
/// rounding of a continuous `Y` (module docs). `None` for an empty or non-finite PMF.
pub(crate) fn phase_set(first: i32, q: &[f64]) -> Option<PhaseSet> {
    let total: f64 = q.iter().sum();
    if q.is_empty() || !(total.is_finite() && total > 0.0) {
        return None;
    }
    let q: Vec<f64> = q.iter().map(|&x| x.max(0.0) / total).collect();
    let (mu, var) = moments(first, &q);
    let (m, sd) = fit_rounded_gaussian(mu, var);
    let y = within_codes(first, &q, m, sd);
    Some(tables_of(first, &y))
}

/// Richardson–Lucy iterations of [`phase_set_less_held`]'s `Y` (its masses per code then match
/// the PMF's to about 10⁻⁴ on set 002's bin at black; each costs the grid times the held points).
const HELD_ITERATIONS: usize = 40;

/// The phase tables of a bin whose PMF `q` (first value `first`) is the rounding of `Y + h`, `h`
/// an offset the PMF holds that synthesis adds again at the pixel's phase (`held`: `(DN, weight)`
/// points; at black on a sub-DN sensor, the fixed pattern wrapped about black's fraction, method.md,
/// *Fixed pattern*, "Black's bin holds the pattern"): `Y` is the Gaussian whose rounding has `q`'s
/// mean and variance with `h`'s mean and variance taken out, then re-weighted by Richardson–Lucy
/// so that the rounding of `Y + h` has `q`'s masses (with `h` a point at 0 its first step is
/// [`phase_set`]'s code-by-code re-weighting). `None` for an empty or non-finite PMF or `held`.
pub(crate) fn phase_set_less_held(first: i32, q: &[f64], held: &[(f64, f64)]) -> Option<PhaseSet> {
    let total: f64 = q.iter().sum();
    let hw: f64 = held.iter().map(|h| h.1).sum();
    if q.is_empty() || !(total.is_finite() && total > 0.0 && hw.is_finite() && hw > 0.0) {
        return None;
    }
    let q: Vec<f64> = q.iter().map(|&x| x.max(0.0) / total).collect();
    let held: Vec<(f64, f64)> = held.iter().map(|&(o, w)| (o, w.max(0.0) / hw)).collect();
    let (mu, var) = moments(first, &q);
    let hm: f64 = held.iter().map(|&(o, w)| o * w).sum();
    let hv: f64 = held.iter().map(|&(o, w)| (o - hm).powi(2) * w).sum();
    let (m, sd) = fit_rounded_gaussian(mu, var);
    let (m, sd) = (m - hm, (sd * sd - hv).max(SD_MIN * SD_MIN).sqrt());
    // `Y` on `q`'s codes: grid point `g` sits at `first − ½ + (g + ½)/GRID`.
    let n = q.len() * GRID;
    let at = |g: usize| f64::from(first) - 0.5 + (g as f64 + 0.5) / GRID as f64;
    let mut y: Vec<f64> = (0..n).map(|g| (-0.5 * ((at(g) - m) / sd).powi(2)).exp()).collect();
    normalise(&mut y)?;
    // Per grid point and held point, the code of `q` that `Y + h` rounds to (`None` outside).
    let code = |g: usize, o: f64| floor_i32(at(g) + o + 0.5) - first;
    let y = match n * held.len() <= HELD_TABLE_CAP {
        true => held_by_table(&q, &held, y, code)?,
        false => held_by_phase(&q, &held, y, code)?,
    };
    Some(tables_of(first, &y))
}

/// The most grid points × held points [`phase_set_less_held`] keeps as a table of codes (16
/// bytes each: 1 MB), its Richardson–Lucy steps then costing that many products each; past it
/// the held points are folded by the grid point's phase ([`held_by_phase`]). Measured on the
/// 10-bit phone with structured components, a fixed pattern of 3 DN and bins of 1 DN
/// (`rust/core/tests/phase_black_cost.rs`): black's bins held 15–105 codes and 342–827 held
/// points, tables of 9.5–69 MB and `black_phase_set` took 0.3–2.2 s per position (load 17);
/// folded, no table, 60–350 ms (load 5–10; the rest is the Gaussian fit and the others'
/// deconvolution, not measured apart). EMVA set 002's (a 0.12 DN pattern: 8 192–9 472) stay
/// under it, drawn as before.
const HELD_TABLE_CAP: usize = 1 << 16;

/// [`HELD_ITERATIONS`] Richardson–Lucy steps of `Y` (normalised, on `q`'s grid) against `q`
/// through the held offsets `held`, `code(g, o)` the code (from `q`'s first) that grid point `g`
/// plus offset `o` rounds to: with a table of the code of every grid point and held point.
fn held_by_table(
    q: &[f64],
    held: &[(f64, f64)],
    mut y: Vec<f64>,
    code: impl Fn(usize, f64) -> i32,
) -> Option<Vec<f64>> {
    let len = q.len() as i32;
    let code = &code;
    let codes: Vec<Option<usize>> = (0..y.len())
        .flat_map(|g| held.iter().map(move |&(o, _)| Some(code(g, o)).filter(|k| (0..len).contains(k))))
        .map(|k| k.map(|k| k as usize))
        .collect();
    for _ in 0..HELD_ITERATIONS {
        let mut pred = vec![0.0; q.len()];
        for (g, &v) in y.iter().enumerate() {
            for (c, &(_, w)) in codes[g * held.len()..(g + 1) * held.len()].iter().zip(held) {
                if let Some(k) = c {
                    pred[*k] += v * w;
                }
            }
        }
        for (g, v) in y.iter_mut().enumerate() {
            let r: f64 = codes[g * held.len()..(g + 1) * held.len()]
                .iter()
                .zip(held)
                .map(|(c, &(_, w))| c.map_or(0.0, |k| if pred[k] > 0.0 { w * q[k] / pred[k] } else { 0.0 }))
                .sum();
            *v *= r;
        }
        normalise(&mut y)?;
    }
    Some(y)
}

/// [`held_by_table`]'s steps with the held points folded by the grid point's phase: grid point
/// `g = GRID·a + r` plus offset `o` rounds to `a + code(r, o)` (`Y`'s grid moved by whole codes),
/// so per phase `r` and code offset the held weight that lands there is summed once, and a step
/// costs the grid times the few codes a phase's held points reach (3 for a pattern wrapped into
/// one code) instead of the grid times the held points. The same sums, grouped otherwise.
fn held_by_phase(
    q: &[f64],
    held: &[(f64, f64)],
    mut y: Vec<f64>,
    code: impl Fn(usize, f64) -> i32,
) -> Option<Vec<f64>> {
    let reach = |f: fn(i32, i32) -> i32, z: i32| {
        (0..GRID).flat_map(|r| held.iter().map(move |&(o, _)| (r, o))).map(|(r, o)| code(r, o)).fold(z, f)
    };
    let (lo, hi) = (reach(i32::min, i32::MAX), reach(i32::max, i32::MIN));
    let span = (hi - lo + 1) as usize;
    // Per phase `r`, the held weight landing `lo + j` codes past the grid point's own code.
    let mut folded = vec![0.0; GRID * span];
    for r in 0..GRID {
        for &(o, w) in held {
            folded[r * span + (code(r, o) - lo) as usize] += w;
        }
    }
    let len = q.len() as i32;
    // The codes grid point `g` reaches, with the folded weight of each.
    let reached = |g: usize| {
        let base = (g / GRID) as i32 + lo;
        let f = &folded[(g % GRID) * span..(g % GRID + 1) * span];
        f.iter().enumerate().filter_map(move |(j, &w)| {
            let k = base + j as i32;
            (w > 0.0 && (0..len).contains(&k)).then_some((k as usize, w))
        })
    };
    for _ in 0..HELD_ITERATIONS {
        let mut pred = vec![0.0; q.len()];
        for (g, &v) in y.iter().enumerate() {
            for (k, w) in reached(g) {
                pred[k] += v * w;
            }
        }
        let ratio: Vec<f64> = q.iter().zip(&pred).map(|(&x, &p)| if p > 0.0 { x / p } else { 0.0 }).collect();
        for (g, v) in y.iter_mut().enumerate() {
            *v *= reached(g).map(|(k, w)| w * ratio[k]).sum::<f64>();
        }
        normalise(&mut y)?;
    }
    Some(y)
}

/// Scales `y` to sum to 1; `None` where its sum is not a positive number.
fn normalise(y: &mut [f64]) -> Option<()> {
    let s: f64 = y.iter().sum();
    if !(s.is_finite() && s > 0.0) {
        return None;
    }
    y.iter_mut().for_each(|v| *v /= s);
    Some(())
}

/// The phase tables of `Y` held on the grid of its codes from `first` ([`GRID`] points each).
fn tables_of(first: i32, y: &[f64]) -> PhaseSet {
    // Values `round(Y + φ)` reach one code past `Y`'s last.
    let len = y.len() / GRID + 1;
    let mut thresholds = Vec::with_capacity(PHASES * (len - 1));
    for j in 0..PHASES {
        let mut pmf = vec![0.0; len];
        // Grid point `g` of code `k` sits at `k − ½ + (g + ½)/GRID`; a phase moves it by
        // `j·GRID/PHASES` points, past the code's upper edge into the next.
        let shift = j * GRID / PHASES;
        for (k, cells) in y.chunks_exact(GRID).enumerate() {
            for (g, &w) in cells.iter().enumerate() {
                pmf[k + (g + shift) / GRID] += w;
            }
        }
        let mut acc = 0.0;
        for &p in &pmf[..len - 1] {
            acc += p;
            thresholds.push((round_half_away(acc * 4294967296.0).max(0) as u64).min(1u64 << 32));
        }
    }
    PhaseSet { first, len, thresholds: thresholds.into() }
}

/// Mean and variance of the PMF `q` (summing to 1) whose first value is `first`.
fn moments(first: i32, q: &[f64]) -> (f64, f64) {
    let mean: f64 = q.iter().enumerate().map(|(i, &p)| (first + i as i32) as f64 * p).sum();
    let var = q.iter().enumerate().map(|(i, &p)| ((first + i as i32) as f64 - mean).powi(2) * p).sum();
    (mean, var)
}

/// `Y` on the grid, code by code of `q` ([`GRID`] points each): the Gaussian `N(m, sd²)`
/// re-weighted so that each code holds `q`'s mass; a code where the Gaussian holds nothing (far
/// out in its tail) holds its mass evenly.
fn within_codes(first: i32, q: &[f64], m: f64, sd: f64) -> Vec<f64> {
    let mut y = Vec::with_capacity(q.len() * GRID);
    for (k, &mass) in q.iter().enumerate() {
        let code = (first + k as i32) as f64;
        let cells: Vec<f64> = (0..GRID)
            .map(|g| {
                let z = (code - 0.5 + (g as f64 + 0.5) / GRID as f64 - m) / sd;
                (-0.5 * z * z).exp()
            })
            .collect();
        let s: f64 = cells.iter().sum();
        match s > 0.0 && s.is_finite() {
            true => y.extend(cells.iter().map(|&c| mass * c / s)),
            false => y.extend(std::iter::repeat_n(mass / GRID as f64, GRID)),
        }
    }
    y
}

/// The mean and SD `(m, sd)` of the Gaussian whose rounding has mean `mu` and variance `var`
/// (the narrowest tried, [`SD_MIN`], where `var` is at or below what any rounding with that mean
/// holds: the lattice's floor).
fn fit_rounded_gaussian(mu: f64, var: f64) -> (f64, f64) {
    let centre_for = |sd: f64| {
        // The rounding's mean rises with `m`, and lies within ½ of it.
        let (mut lo, mut hi) = (mu - 1.0, mu + 1.0);
        for _ in 0..40 {
            let mid = 0.5 * (lo + hi);
            if rounded_moments(mid, sd).0 < mu {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        0.5 * (lo + hi)
    };
    let var_at = |sd: f64| rounded_moments(centre_for(sd), sd).1;
    let (mut lo, mut hi) = (SD_MIN, var.max(0.0).sqrt() + 1.0);
    if var_at(lo) >= var {
        return (centre_for(lo), lo);
    }
    for _ in 0..30 {
        let mid = 0.5 * (lo + hi);
        if var_at(mid) < var {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    let sd = 0.5 * (lo + hi);
    (centre_for(sd), sd)
}

/// Mean and variance of `round(X)`, `X ~ N(m, sd²)`, its codes' masses read on the grid (as
/// [`within_codes`] holds `Y`).
fn rounded_moments(m: f64, sd: f64) -> (f64, f64) {
    let lo = floor_i32(m - 8.0 * sd - 1.0);
    let hi = floor_i32(m + 8.0 * sd + 1.0) + 1;
    let (mut s0, mut s1, mut s2) = (0.0, 0.0, 0.0);
    for k in lo..=hi {
        let code = k as f64;
        let mass: f64 = (0..GRID)
            .map(|g| {
                let z = (code - 0.5 + (g as f64 + 0.5) / GRID as f64 - m) / sd;
                (-0.5 * z * z).exp()
            })
            .sum();
        s0 += mass;
        s1 += mass * code;
        s2 += mass * code * code;
    }
    let mean = s1 / s0;
    (mean, (s2 / s0 - mean * mean).max(0.0))
}

#[cfg(test)]
#[path = "tests_phase_tables.rs"]
mod tests;
