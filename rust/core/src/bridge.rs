//! Bridge models for noise on noise (paper §4.2, method.md "Noise on noise").
//!
//! A capture at source ISO `a` already carries noise `n_a ~ p_a`. To make it look like a capture
//! at a higher target ISO `b`, we add *extra* noise `d ~ q`, independent of `n_a`, such that
//! `n_a + d` is distributed like the target noise: `p_a ∗ q ≈ p_b`. Per (position, bin) this is a
//! small discrete deconvolution with `q ≥ 0, Σq = 1`, solved by accelerated projected gradient on
//! the least-squares objective (FISTA with projection onto the simplex; the default, measured to
//! reach the lower residual) or by Richardson–Lucy (multiplicative updates minimising the
//! Kullback–Leibler divergence). Both start from the moment match: `p_b`'s shape rescaled to mean
//! `μ_b − μ_a` and variance `σ_b² − σ_a²`. The forward model clamps like the renoise does: mass
//! beyond white (or below 0) of the bin's clean level piles up there, so the clipped top bins fit.
//!
//! Every bin's fit is checked: its residual (total variation and JSD between `p_a ∗ q` and `p_b`)
//! is recorded, and bins where the target is not wider than the source (no such `q` exists; the
//! closest one is used) or where the residual is large are reported by ISO pair, position and bin.

use rayon::prelude::*;
use thiserror::Error;

use crate::layout::{Binning, POSITIONS};
use crate::pack::IsoModel;
use crate::pmf::Pmf;
use crate::sampler::BinTable;

/// How the deconvolution `p_a ∗ q ≈ p_b` is solved.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Deconvolution {
    /// Richardson–Lucy (multiplicative EM updates; minimises KL(p_b ‖ p_a ∗ q)).
    RichardsonLucy,
    /// Non-negative least squares on the simplex by accelerated projected gradient (FISTA). The
    /// default: at the same iteration budget it reached a lower residual (total variation and
    /// JSD) than Richardson–Lucy on simulated Poisson–Gaussian sensors with heavy read-noise
    /// tails (`tests/renoise_sim.rs`, `default_solver_has_the_lower_residual`).
    ProjectedGradient,
}

/// Settings of [`build_bridge_with`].
#[derive(Debug, Clone, PartialEq)]
pub struct BridgeOptions {
    pub solver: Deconvolution,
    /// Iteration cap per bin.
    pub max_iterations: usize,
    /// Stop when the objective improves by less than this fraction of itself over 10 iterations.
    pub tolerance: f64,
    /// Total variation between `p_a ∗ q` and `p_b` above which a bin is flagged, on top of what
    /// the histograms' own sampling noise explains (twice the expected total variation of a
    /// histogram of that many samples, source and target added).
    pub max_residual: f64,
    /// Tail mass (each side) of `p_a` and `p_b` dropped before solving.
    pub tail_mass: f64,
}

impl Default for BridgeOptions {
    fn default() -> Self {
        Self {
            solver: Deconvolution::ProjectedGradient,
            max_iterations: 150,
            tolerance: 0.01,
            max_residual: 0.05,
            tail_mass: 1e-8,
        }
    }
}

/// The extra-noise PMF of one (position, bin) and how well it fits.
#[derive(Debug, Clone, PartialEq)]
pub struct BridgeBin {
    /// The PMF `q` of the extra noise `d`.
    pub q: Pmf,
    /// Total variation `½ Σ |p_a ∗ q − p_b|` (0 = exact, 1 = disjoint).
    pub tv: f64,
    /// Jensen–Shannon divergence (natural log) between `p_a ∗ q` and `p_b`.
    pub jsd: f64,
    /// Source and target noise variances of this bin.
    pub var_source: f64,
    pub var_target: f64,
    /// Solver iterations used.
    pub iterations: usize,
}

/// Why a bin was flagged.
#[derive(Debug, Clone, PartialEq)]
pub enum FlagKind {
    /// `σ_b² ≤ σ_a²`: no added noise can make the source look like the target.
    NotWider,
    /// The fit's total variation exceeds the threshold.
    LargeResidual,
}

/// A flagged (position, bin).
#[derive(Debug, Clone, PartialEq)]
pub struct BridgeFlag {
    pub position: usize,
    pub bin: usize,
    pub kind: FlagKind,
    pub tv: f64,
    pub var_source: f64,
    pub var_target: f64,
}

/// A bridge from source ISO to target ISO: one extra-noise PMF per (position, bin), with
/// inverse-CDF tables for sampling.
#[derive(Debug, Clone)]
pub struct Bridge {
    pub source_iso: u32,
    pub target_iso: u32,
    /// Per position, per bin.
    pub bins: Vec<Vec<BridgeBin>>,
    tables: Vec<Vec<BinTable>>,
    /// Bins that were flagged, in position then bin order.
    pub flags: Vec<BridgeFlag>,
    /// Human-readable summary of the flags, naming the ISO pair and the bins.
    pub warnings: Vec<String>,
}

/// A pair of models the bridge cannot be built for.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum BridgeError {
    #[error(
        "cannot bridge ISO {from_iso} to ISO {to_iso}: noise on noise only adds noise, so the target ISO must be higher than the source ISO; pick a target ISO above {from_iso} (or renoise a capture taken at an ISO below {to_iso})"
    )]
    NotHigher { from_iso: u32, to_iso: u32 },
    #[error(
        "the models of ISO {from_iso} and ISO {to_iso} do not share a layout: {detail}; both must come from the same pack"
    )]
    Mismatch { from_iso: u32, to_iso: u32, detail: String },
}

impl Bridge {
    /// Sampling table of the extra noise for (position, bin).
    #[inline(always)]
    pub fn table(&self, pos: usize, bin: usize) -> &BinTable {
        &self.tables[pos][bin]
    }

    /// The extra-noise PMF of (position, bin).
    pub fn q(&self, pos: usize, bin: usize) -> &Pmf {
        &self.bins[pos][bin].q
    }

    /// Total-variation residual of (position, bin).
    pub fn residual(&self, pos: usize, bin: usize) -> f64 {
        self.bins[pos][bin].tv
    }

    /// Largest total-variation residual over all bins.
    pub fn max_residual(&self) -> f64 {
        self.bins.iter().flatten().map(|b| b.tv).fold(0.0, f64::max)
    }

    /// Mean total-variation residual over all bins.
    pub fn mean_residual(&self) -> f64 {
        let n = self.bins.iter().map(Vec::len).sum::<usize>().max(1);
        self.bins.iter().flatten().map(|b| b.tv).sum::<f64>() / n as f64
    }

    /// Mean JSD residual over all bins.
    pub fn mean_jsd(&self) -> f64 {
        let n = self.bins.iter().map(Vec::len).sum::<usize>().max(1);
        self.bins.iter().flatten().map(|b| b.jsd).sum::<f64>() / n as f64
    }
}

/// Builds the bridge `source → target` with default options. See [`build_bridge_with`].
pub fn build_bridge(source: &IsoModel, target: &IsoModel, binning: &Binning) -> Result<Bridge, BridgeError> {
    build_bridge_with(source, target, binning, &BridgeOptions::default())
}

/// Builds the bridge `source → target`: per (position, bin), the PMF `q ≥ 0, Σq = 1` with
/// `p_source ∗ q ≈ p_target`. Refuses a target ISO that is not higher than the source ISO.
/// Calibrated and interpolated models are treated alike. Deterministic (each bin is solved on its
/// own, whatever the thread count).
pub fn build_bridge_with(
    source: &IsoModel,
    target: &IsoModel,
    binning: &Binning,
    opts: &BridgeOptions,
) -> Result<Bridge, BridgeError> {
    let (from_iso, to_iso) = (source.iso, target.iso);
    if to_iso <= from_iso {
        return Err(BridgeError::NotHigher { from_iso, to_iso });
    }
    let mismatch = |detail: String| BridgeError::Mismatch { from_iso, to_iso, detail };
    for (m, name) in [(source, "source"), (target, "target")] {
        if m.positions.len() != POSITIONS {
            return Err(mismatch(format!("the {name} model has {} CFA positions, expected 4", m.positions.len())));
        }
    }
    for pos in 0..POSITIONS {
        let (na, nb, need) = (source.positions[pos].bins.len(), target.positions[pos].bins.len(), binning.bins(pos));
        if na != need || nb != need {
            return Err(mismatch(format!(
                "position {pos} has {na} bins at ISO {from_iso} and {nb} at ISO {to_iso}, the pack's binning needs {need}"
            )));
        }
    }

    let jobs: Vec<(usize, usize)> = (0..POSITIONS).flat_map(|p| (0..binning.bins(p)).map(move |b| (p, b))).collect();
    let solved: Vec<BridgeBin> = jobs
        .par_iter()
        .map(|&(p, b)| {
            let sa = &source.positions[p].bins[b];
            let tb = &target.positions[p].bins[b];
            let c = binning.center(p, b).round() as i32;
            solve_bin(&sa.pmf(), &tb.pmf(), (-c, binning.white as i32 - c), opts)
        })
        .collect();

    let mut bins: Vec<Vec<BridgeBin>> = (0..POSITIONS).map(|p| Vec::with_capacity(binning.bins(p))).collect();
    for (&(p, _), s) in jobs.iter().zip(solved) {
        bins[p].push(s);
    }
    let tables: Vec<Vec<BinTable>> = bins
        .iter()
        .map(|v| {
            v.iter()
                .map(|bb| {
                    let w: Vec<u64> = bb.q.p.iter().map(|&x| (x * (1u64 << 40) as f64).round() as u64).collect();
                    BinTable::from_weights(bb.q.first, &w)
                })
                .collect()
        })
        .collect();

    let mut flags = Vec::new();
    for p in 0..POSITIONS {
        for (b, bb) in bins[p].iter().enumerate() {
            let common = |kind| BridgeFlag {
                position: p,
                bin: b,
                kind,
                tv: bb.tv,
                var_source: bb.var_source,
                var_target: bb.var_target,
            };
            if bb.var_target <= bb.var_source {
                flags.push(common(FlagKind::NotWider));
            } else {
                // What the histograms' own sampling noise explains (both PMFs are estimates).
                let floor: f64 = [&source.positions[p].bins[b], &target.positions[p].bins[b]]
                    .iter()
                    .filter(|m| m.samples > 0)
                    .map(|m| sampling_tv(&m.pmf(), m.samples))
                    .sum();
                if bb.tv > opts.max_residual + 2.0 * floor {
                    flags.push(common(FlagKind::LargeResidual));
                }
            }
        }
    }
    let warnings = describe_flags(from_iso, to_iso, binning, &flags, opts.max_residual);
    Ok(Bridge { source_iso: from_iso, target_iso: to_iso, bins, tables, flags, warnings })
}

/// Expected total variation between a PMF and an `n`-sample histogram of it (normal
/// approximation per cell: `E|X − np| ≈ √(2/π) · √(np(1−p))`).
fn sampling_tv(p: &Pmf, n: u64) -> f64 {
    let n = n.max(1) as f64;
    0.5 * (2.0 / std::f64::consts::PI).sqrt() * p.p.iter().map(|&x| (x * (1.0 - x) / n).sqrt()).sum::<f64>()
}

/// Groups flags into one line per (position, kind) with bin ranges and their levels.
fn describe_flags(from: u32, to: u32, binning: &Binning, flags: &[BridgeFlag], max_residual: f64) -> Vec<String> {
    let mut out = Vec::new();
    for p in 0..POSITIONS {
        for kind in [FlagKind::NotWider, FlagKind::LargeResidual] {
            let sel: Vec<&BridgeFlag> = flags.iter().filter(|f| f.position == p && f.kind == kind).collect();
            if sel.is_empty() {
                continue;
            }
            let mut ranges: Vec<(usize, usize)> = Vec::new();
            for f in &sel {
                match ranges.last_mut() {
                    Some((_, hi)) if *hi + 1 == f.bin => *hi = f.bin,
                    _ => ranges.push((f.bin, f.bin)),
                }
            }
            let half = binning.bin_width as f32 / 2.0;
            let list: Vec<String> = ranges
                .iter()
                .map(|&(lo, hi)| {
                    let l0 = (binning.center(p, lo) - half).max(0.0);
                    let l1 = (binning.center(p, hi) + half - 1.0).min(binning.white as f32);
                    if lo == hi {
                        format!("bin {lo} (levels {l0:.0}–{l1:.0})")
                    } else {
                        format!("bins {lo}–{hi} (levels {l0:.0}–{l1:.0})")
                    }
                })
                .collect();
            let line = match kind {
                FlagKind::NotWider => format!(
                    "ISO {from} → {to}, CFA position {p}: the target noise is not wider than the source noise in {} bin(s): {}; no added noise can narrow it, so these bins get the closest non-negative bridge (usually clipping near white or a mis-calibrated bin)",
                    sel.len(),
                    list.join(", ")
                ),
                FlagKind::LargeResidual => {
                    let worst = sel.iter().map(|f| f.tv).fold(0.0, f64::max);
                    format!(
                        "ISO {from} → {to}, CFA position {p}: the bridge fits poorly (total variation above {max_residual} plus sampling noise, worst {worst:.3}) in {} bin(s): {}",
                        sel.len(),
                        list.join(", ")
                    )
                }
            };
            out.push(line);
        }
    }
    out
}

/// Drops tails of mass below `eps` on each side and renormalises.
fn trim_tails(p: &Pmf, eps: f64) -> Pmf {
    let mut lo = 0;
    let mut acc = 0.0;
    while lo + 1 < p.p.len() && acc + p.p[lo] < eps {
        acc += p.p[lo];
        lo += 1;
    }
    let mut hi = p.p.len() - 1;
    let mut acc = 0.0;
    while hi > lo && acc + p.p[hi] < eps {
        acc += p.p[hi];
        hi -= 1;
    }
    Pmf::from_weights(p.first + lo as i32, p.p[lo..=hi].iter().copied()).unwrap_or_else(|| p.clone())
}

/// Full discrete convolution `out[i + j] += a[i] q[j]`.
fn convolve(a: &[f64], q: &[f64], out: &mut [f64]) {
    out.fill(0.0);
    for (j, &qj) in q.iter().enumerate() {
        if qj == 0.0 {
            continue;
        }
        for (o, &ai) in out[j..j + a.len()].iter_mut().zip(a) {
            *o += ai * qj;
        }
    }
}

/// Adjoint of [`convolve`]: `out[j] = Σ_i a[i] r[i + j]`.
fn correlate(a: &[f64], r: &[f64], out: &mut [f64]) {
    for (j, o) in out.iter_mut().enumerate() {
        *o = a.iter().zip(&r[j..j + a.len()]).map(|(x, y)| x * y).sum();
    }
}

/// Jensen–Shannon divergence (natural log) of two aligned PMFs.
pub(crate) fn jsd_aligned(p: &[f64], q: &[f64]) -> f64 {
    let mut s = 0.0;
    for (&x, &y) in p.iter().zip(q) {
        let t = x + y;
        if x > 1e-300 {
            s += 0.5 * x * (2.0 * x / t).ln();
        }
        if y > 1e-300 {
            s += 0.5 * y * (2.0 * y / t).ln();
        }
    }
    s.max(0.0)
}

/// Euclidean projection onto the probability simplex (`scratch` has `v`'s length).
fn project_simplex(v: &mut [f64], scratch: &mut [f64]) {
    let u = scratch;
    u.copy_from_slice(v);
    u.sort_unstable_by(|a, b| b.total_cmp(a));
    let mut cum = 0.0;
    let mut theta = 0.0;
    for (i, &x) in u.iter().enumerate() {
        cum += x;
        let t = (cum - 1.0) / (i + 1) as f64;
        if x - t > 0.0 {
            theta = t;
        }
    }
    for x in v.iter_mut() {
        *x = (*x - theta).max(0.0);
    }
}

/// The problem on the solver's grid: `y = fold(a ∗ q)` compared with `b`, where `fold` piles the
/// mass beyond the clip indices onto them (the renoised value is clamped to [0, white] too).
struct Problem {
    a: Vec<f64>,
    b: Vec<f64>,
    /// Output indices where the clamp at 0 and at white piles mass (inclusive).
    clip_lo: usize,
    clip_hi: usize,
}

impl Problem {
    fn forward(&self, q: &[f64], y: &mut [f64]) {
        convolve(&self.a, q, y);
        let n = y.len();
        if self.clip_hi + 1 < n {
            let s: f64 = y[self.clip_hi + 1..].iter().sum();
            y[self.clip_hi] += s;
            y[self.clip_hi + 1..].fill(0.0);
        }
        if self.clip_lo > 0 {
            let s: f64 = y[..self.clip_lo].iter().sum();
            y[self.clip_lo] += s;
            y[..self.clip_lo].fill(0.0);
        }
    }

    /// Adjoint of [`Problem::forward`]: unfold `r` (beyond a clip, the clip's value), correlate.
    fn adjoint(&self, r: &mut [f64], g: &mut [f64]) {
        let n = r.len();
        if self.clip_hi + 1 < n {
            let v = r[self.clip_hi];
            r[self.clip_hi + 1..].fill(v);
        }
        if self.clip_lo > 0 {
            let v = r[self.clip_lo];
            r[..self.clip_lo].fill(v);
        }
        correlate(&self.a, r, g);
    }
}

/// Largest number of unknowns solved for at full resolution; wider bridges (deep sensors at
/// high ISO) are solved on a grid of `s` DN cells (`s` odd) and spread back uniformly, which adds
/// only `(s² − 1)/12` DN² to a variance of at least `(4s)²`.
const MAX_UNKNOWNS: usize = 160;

/// Sums `p` (over integers from `first`) into cells of `s` starting at `base` (`base ≤ first`).
fn pool(first: i32, p: &[f64], base: i32, s: i32, len: usize) -> Vec<f64> {
    let mut out = vec![0.0; len];
    for (i, &x) in p.iter().enumerate() {
        let k = ((first + i as i32 - base).div_euclid(s)).clamp(0, len as i32 - 1) as usize;
        out[k] += x;
    }
    out
}

/// Solves one bin. `pa_full`, `pb_full` are normalised PMFs of noise relative to the clean
/// level; `clip` the noise values at which the clamp to 0 and to white piles mass.
fn solve_bin(pa_full: &Pmf, pb_full: &Pmf, clip: (i32, i32), opts: &BridgeOptions) -> BridgeBin {
    let (mu_a, var_a) = pa_full.moments();
    let (mu_b, var_b) = pb_full.moments();
    let pa = trim_tails(pa_full, opts.tail_mass);
    let pb = trim_tails(pb_full, opts.tail_mass);
    let d_mean = mu_b - mu_a;
    let d_var = (var_b - var_a).max(0.0);
    let d_sd = d_var.sqrt();

    // Support of q: wide enough for the tails p_b needs beyond p_a, and for the moment match.
    // The tails are taken at quantiles 10⁻⁴ / 1 − 10⁻⁴, so a few outlying samples in a sparse
    // calibrated bin do not stretch the support (they stay in the residual).
    const Q: f64 = 1e-4;
    let tail_lo = (pb.quantile(Q) - pa.quantile(Q)).floor() as i32;
    let tail_hi = (pb.quantile(1.0 - Q) - pa.quantile(1.0 - Q)).ceil() as i32;
    let mut lo = tail_lo.min((d_mean - 6.0 * d_sd - 1.0).floor() as i32);
    let mut hi = tail_hi.max((d_mean + 6.0 * d_sd + 1.0).ceil() as i32);
    lo = lo.max(pb.first - pa.last());
    hi = hi.min(pb.last() - pa.first);
    if lo > hi {
        let c = d_mean.round() as i32;
        lo = c;
        hi = c;
    }
    let m_full = (hi - lo + 1) as usize;
    // Cell size of the solver grid (odd, so cell centres add up on the integer grid).
    let mut s = 1i32;
    if m_full > MAX_UNKNOWNS {
        let cap = ((d_sd.min(var_a.sqrt()) / 4.0).floor() as i32).max(1);
        s = (m_full.div_ceil(MAX_UNKNOWNS) as i32).min(cap);
        if s % 2 == 0 {
            s -= 1;
        }
        s = s.max(1);
    }
    let half = (s - 1) / 2;
    let m = (m_full as i32 + s - 1) as usize / s as usize;
    let na = (pa.p.len() as i32 + s - 1) as usize / s as usize;
    let a = pool(pa.first, &pa.p, pa.first, s, na);
    // Cell k of the output is centred on pa.first + lo + k·s + (s − 1).
    let y_base = pa.first + lo + half;
    let n_out = na + m - 1;
    let b = pool(pb.first, &pb.p, y_base, s, n_out);
    let cell = |v: i32| (v - y_base).div_euclid(s).clamp(0, n_out as i32 - 1) as usize;
    let prob = Problem { a, b, clip_lo: cell(clip.0), clip_hi: cell(clip.1) };

    // Start from the moment match: p_b's shape at mean μ_b − μ_a and variance σ_b² − σ_a².
    let init = pb_full.rescaled(d_mean, d_var.max(1e-3));
    let init_fine: Vec<f64> = (0..m * s as usize).map(|j| init.at(lo + j as i32)).collect();
    let mut q: Vec<f64> = init_fine.chunks(s as usize).map(|c| c.iter().sum()).collect();
    let floor = 1e-6 / m as f64;
    q.iter_mut().for_each(|x| *x += floor);
    let t: f64 = q.iter().sum();
    q.iter_mut().for_each(|x| *x /= t);

    let iterations = match opts.solver {
        Deconvolution::RichardsonLucy => richardson_lucy(&prob, &mut q, opts),
        Deconvolution::ProjectedGradient => projected_gradient(&prob, &mut q, opts),
    };

    // Back on the integer grid, then the residual at full resolution.
    let q_fine: Vec<f64> =
        q.iter().flat_map(|&x| std::iter::repeat_n(if x < 1e-15 { 0.0 } else { x / s as f64 }, s as usize)).collect();
    let n_fine = pa.p.len() + q_fine.len() - 1;
    let fine_cell = |v: i32| (v - (pa.first + lo)).clamp(0, n_fine as i32 - 1) as usize;
    let fine = Problem {
        a: pa.p.clone(),
        b: pool(pb.first, &pb.p, pa.first + lo, 1, n_fine),
        clip_lo: fine_cell(clip.0),
        clip_hi: fine_cell(clip.1),
    };
    let mut y = vec![0.0; fine.b.len()];
    fine.forward(&q_fine, &mut y);
    let tv = 0.5 * y.iter().zip(&fine.b).map(|(u, v)| (u - v).abs()).sum::<f64>();
    let jsd = jsd_aligned(&y, &fine.b);
    let q = Pmf::from_weights(lo, q_fine).unwrap_or(Pmf { first: d_mean.round() as i32, p: vec![1.0] });
    // Variances add under convolution (clipping aside), so a q far from σ_b² − σ_a² fitted the
    // histograms' sampling noise (sparse calibrated bins), not the noise: use the moment match.
    let vq = q.moments().1;
    let clipped = pb_full.at(clip.0) + pb_full.at(clip.1) + pa_full.at(clip.0) + pa_full.at(clip.1);
    if d_var > 1.0 && clipped < 0.01 && (vq - d_var).abs() > 0.25 * d_var {
        let mm = init.clone();
        let n = pa.p.len() + mm.p.len() - 1;
        let first = pa.first + mm.first;
        let cell = |v: i32| (v - first).clamp(0, n as i32 - 1) as usize;
        let prob = Problem {
            a: pa.p.clone(),
            b: pool(pb.first, &pb.p, first, 1, n),
            clip_lo: cell(clip.0),
            clip_hi: cell(clip.1),
        };
        let mut y = vec![0.0; n];
        prob.forward(&mm.p, &mut y);
        let tv = 0.5 * y.iter().zip(&prob.b).map(|(u, v)| (u - v).abs()).sum::<f64>();
        let jsd = jsd_aligned(&y, &prob.b);
        return BridgeBin { q: mm, tv, jsd, var_source: var_a, var_target: var_b, iterations };
    }
    BridgeBin { q, tv, jsd, var_source: var_a, var_target: var_b, iterations }
}

/// Richardson–Lucy: `q ← q ⊙ Aᵀ(b ⊘ Aq)` (columns of A sum to 1, so Σq stays 1). Stops when the
/// KL divergence improves by less than `tolerance` (relative) over 10 iterations.
fn richardson_lucy(prob: &Problem, q: &mut [f64], opts: &BridgeOptions) -> usize {
    let n = prob.b.len();
    let mut y = vec![0.0; n];
    let mut ratio = vec![0.0; n];
    let mut g = vec![0.0; q.len()];
    let mut last = f64::INFINITY;
    for it in 0..opts.max_iterations {
        prob.forward(q, &mut y);
        if it % 10 == 0 {
            let obj = kl(&prob.b, &y);
            if obj < 1e-10 || last - obj < opts.tolerance * obj {
                return it;
            }
            last = obj;
        }
        for ((r, &bi), &yi) in ratio.iter_mut().zip(&prob.b).zip(&y) {
            *r = if yi > 0.0 { bi / yi } else { 0.0 };
        }
        prob.adjoint(&mut ratio, &mut g);
        for (qj, &gj) in q.iter_mut().zip(&g) {
            *qj *= gj;
        }
        let s: f64 = q.iter().sum();
        if s > 0.0 {
            q.iter_mut().for_each(|x| *x /= s);
        }
    }
    opts.max_iterations
}

/// FISTA on `½‖fold(a ∗ q) − b‖²` over the simplex, step `1/L` with `L` from power iteration.
/// Stops when the objective changes by less than `tolerance` (relative) over 10 iterations.
fn projected_gradient(prob: &Problem, q: &mut [f64], opts: &BridgeOptions) -> usize {
    let n = prob.b.len();
    let m = q.len();
    let mut y = vec![0.0; n];
    let mut g = vec![0.0; m];
    let mut scratch = vec![0.0; m];
    // Largest eigenvalue of AᵀA (with the fold). Without the fold it is exactly 1 (a ≥ 0, Σa = 1).
    let mut v = vec![1.0 / (m as f64).sqrt(); m];
    let mut lip = 1.0f64;
    let folds = prob.clip_lo > 0 || prob.clip_hi + 1 < n;
    for _ in 0..if folds { 20 } else { 0 } {
        prob.forward(&v, &mut y);
        prob.adjoint(&mut y, &mut g);
        let norm = g.iter().map(|x| x * x).sum::<f64>().sqrt();
        if norm.is_nan() || norm <= 0.0 {
            break;
        }
        lip = lip.max(norm);
        v.iter_mut().zip(&g).for_each(|(vi, gi)| *vi = gi / norm);
    }
    let step = 1.0 / (1.1 * lip);
    let mut x = q.to_vec();
    let mut xn = vec![0.0; m];
    let mut z = q.to_vec();
    let mut t = 1.0f64;
    let mut last = f64::INFINITY;
    for it in 0..opts.max_iterations {
        prob.forward(&z, &mut y);
        for (yi, &bi) in y.iter_mut().zip(&prob.b) {
            *yi -= bi;
        }
        if it % 10 == 0 {
            let obj = 0.5 * y.iter().map(|r| r * r).sum::<f64>();
            if obj < 1e-16 || (last - obj).abs() < opts.tolerance * obj {
                q.copy_from_slice(&x);
                return it;
            }
            last = obj;
        }
        prob.adjoint(&mut y, &mut g);
        for ((o, zj), gj) in xn.iter_mut().zip(&z).zip(&g) {
            *o = zj - step * gj;
        }
        project_simplex(&mut xn, &mut scratch);
        let tn = 0.5 * (1.0 + (1.0 + 4.0 * t * t).sqrt());
        let beta = (t - 1.0) / tn;
        for j in 0..m {
            z[j] = xn[j] + beta * (xn[j] - x[j]);
        }
        std::mem::swap(&mut x, &mut xn);
        t = tn;
    }
    q.copy_from_slice(&x);
    opts.max_iterations
}

/// KL(b ‖ y) over aligned vectors (terms with b = 0 vanish).
fn kl(b: &[f64], y: &[f64]) -> f64 {
    b.iter()
        .zip(y)
        .filter(|(bi, _)| **bi > 1e-300)
        .map(|(&bi, &yi)| if yi > 1e-300 { bi * (bi / yi).ln() } else { 1e3 * bi })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gauss(mu: f64, sd: f64) -> Pmf {
        let lo = (mu - 9.0 * sd).floor() as i32 - 1;
        let hi = (mu + 9.0 * sd).ceil() as i32 + 1;
        Pmf::from_weights(lo, (lo..=hi).map(|n| (-(n as f64 - mu).powi(2) / (2.0 * sd * sd)).exp()))
            .expect("non-empty PMF")
    }

    fn conv(a: &Pmf, q: &Pmf) -> Pmf {
        let mut y = vec![0.0; a.p.len() + q.p.len() - 1];
        convolve(&a.p, &q.p, &mut y);
        Pmf::from_weights(a.first + q.first, y).expect("non-empty PMF")
    }

    #[test]
    fn recovers_a_known_extra_noise() {
        // p_b = p_a ∗ q_true exactly, with a skewed q_true: both solvers must recover its moments
        // and reach a tiny residual.
        let pa = gauss(0.5, 3.0);
        let q_true = Pmf::from_weights(-2, (0..30).map(|n| (-(n as f64) / 4.0).exp())).expect("non-empty PMF");
        let pb = conv(&pa, &q_true);
        let (mq, vq) = q_true.moments();
        for solver in [Deconvolution::RichardsonLucy, Deconvolution::ProjectedGradient] {
            let opts = BridgeOptions { solver, max_iterations: 3000, tolerance: 1e-7, ..BridgeOptions::default() };
            let r = solve_bin(&pa, &pb, (-1000, 1000), &opts);
            let (m, v) = r.q.moments();
            assert!(r.tv < 0.01, "{solver:?}: tv {}", r.tv);
            assert!((m - mq).abs() < 0.05, "{solver:?}: mean {m} vs {mq}");
            assert!((v - vq).abs() / vq < 0.05, "{solver:?}: var {v} vs {vq}");
            assert!(r.q.p.iter().all(|&x| x >= 0.0));
            assert!((r.q.p.iter().sum::<f64>() - 1.0).abs() < 1e-9);
        }
    }

    #[test]
    fn narrower_target_gets_the_closest_bridge() {
        let pa = gauss(0.0, 4.0);
        let pb = gauss(1.0, 3.0);
        let r = solve_bin(&pa, &pb, (-1000, 1000), &BridgeOptions::default());
        assert!(r.var_target < r.var_source);
        // The best it can do is (close to) a shift: most mass within ±1 of the mean shift.
        let near: f64 = (0..=2).map(|n| r.q.at(n)).sum();
        assert!(near > 0.8, "{:?}", r.q);
        assert!(r.tv > 0.03);
    }

    #[test]
    fn simplex_projection() {
        let mut v = vec![0.5, 0.9, -0.2, 0.1];
        project_simplex(&mut v, &mut [0.0; 4]);
        assert!((v.iter().sum::<f64>() - 1.0).abs() < 1e-12);
        assert!(v.iter().all(|&x| x >= 0.0));
        assert!((v[1] - v[0] - 0.4).abs() < 1e-12);
    }
}
