//! Parametric baselines fitted from the same calibration histograms as the non-parametric model
//! (method.md, "Measuring fidelity"): the heteroscedastic Gaussian (HG), the Poisson–Gaussian
//! with clipping (PG), and the camera's own NoiseProfile (DNG tag 51041 /
//! `SENSOR_NOISE_PROFILE`).
//!
//! All three share one variance law per ISO and CFA position, `σ² = a·(l − black) + b` (DN²,
//! [`NoiseParams`]):
//! - **HG**: `a`, `b` fitted by non-negative weighted least squares on the per-bin variances of
//!   the calibrated PMFs ([`fit_params`]). Noise is `round(N(0, σ²))`, zero mean.
//! - **PG**: the same fit read as `gain = a` (DN per electron) and read variance
//!   `b − 1/12` (the rest of `b` is quantisation). Noise is
//!   `clamp(round(l + gain·(P − λ) + N(0, read)), 0, white) − l`, `P ~ Poisson(λ)`,
//!   `λ = (l − black)/gain`: exact Poisson sums up to λ = 1000, the Gaussian limit above.
//! - **NoiseProfile**: `σ²/(white − black)² = S·x + O` with `x = (l − black)/(white − black)`, so
//!   `a = S·(white − black)` and `b = O·(white − black)²`. Noise is `round(N(0, σ²))`.
//!
//! The variance of every baseline is the variance of the **integer** noise (as measured), so the
//! continuous Gaussian behind the rounding gets `σ² − 1/12`. Every baseline PMF includes the
//! clipping at 0 and white for the levels of its bin, so PMFs can be compared with calibrated
//! ones directly; synthesis clamps the same way ([`crate::sampler::IsoSampler::noisy`]).
//!
//! A baseline becomes an ordinary [`IsoModel`] with [`Baseline::to_model`] (one PMF per
//! position and bin, averaged over up to [`LEVELS_PER_BIN`] levels of the bin), so it reuses
//! [`crate::sampler::IsoSampler`], synthesis and every metric: that is what
//! `synth --model hg|pg|noiseprofile` runs.
//!
//! Across ISO the baselines are interpolated "the usual parametric way" (paper §4.1, after
//! [34]): `a` linear in ISO and `b = c + d·a²` (read noise before and after the gain), both
//! non-negative fits over the calibrated ISOs on the same side of any conversion-gain switch
//! ([`interpolate`]).

use rayon::prelude::*;

use crate::error::ModelError;
use crate::fit::{nn_poly_fit, poly_eval};
use crate::layout::{Binning, POSITIONS};
use crate::pack::{BinModel, IsoModel, ModelOrigin, ModelPack, PositionModel};
use crate::pmf::Pmf;

/// Levels of a bin whose PMFs are averaged into the bin's baseline PMF.
pub const LEVELS_PER_BIN: usize = 8;

/// Poisson means above this use the Gaussian limit in the PG PMF.
pub const PG_EXACT_MAX_LAMBDA: f64 = 1000.0;

/// Which parametric baseline.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum BaselineKind {
    /// Heteroscedastic Gaussian `σ² = a·(l − black) + b`.
    Hg,
    /// Poisson–Gaussian with clipping.
    Pg,
    /// The capture's own NoiseProfile `σ² = S·x + O` (normalised units).
    NoiseProfile,
}

impl BaselineKind {
    pub const ALL: [BaselineKind; 3] = [Self::Hg, Self::Pg, Self::NoiseProfile];

    /// `hg`, `pg`, `noiseprofile` (case-insensitive; `np` and `noise-profile` accepted).
    pub fn parse(s: &str) -> Option<Self> {
        match s.to_ascii_lowercase().as_str() {
            "hg" => Some(Self::Hg),
            "pg" => Some(Self::Pg),
            "noiseprofile" | "noise-profile" | "np" => Some(Self::NoiseProfile),
            _ => None,
        }
    }

    /// The CLI name.
    pub fn name(self) -> &'static str {
        match self {
            Self::Hg => "hg",
            Self::Pg => "pg",
            Self::NoiseProfile => "noiseprofile",
        }
    }

    /// A human label for reports.
    pub fn label(self) -> &'static str {
        match self {
            Self::Hg => "heteroscedastic Gaussian",
            Self::Pg => "Poisson–Gaussian (clipped)",
            Self::NoiseProfile => "camera NoiseProfile",
        }
    }
}

impl std::fmt::Display for BaselineKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// The variance law of one CFA position: `σ² = a·(l − black) + b` in DN² (`l − black` clamped
/// at 0). For PG, `a` is the gain in DN per electron and `b − 1/12` the read variance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NoiseParams {
    pub a: f64,
    pub b: f64,
}

impl NoiseParams {
    /// Variance (DN²) at `level_above_black` (clamped at 0).
    pub fn variance(&self, level_above_black: f64) -> f64 {
        self.a * level_above_black.max(0.0) + self.b
    }

    /// Read variance referred to the input in electrons², `b / a²` (the shot slope `a` is the
    /// conversion gain in DN/e⁻). Infinite when `a` is 0.
    pub fn input_read_variance(&self) -> f64 {
        if self.a > 0.0 { self.b / (self.a * self.a) } else { f64::INFINITY }
    }
}

/// Where a baseline's parameters come from.
#[derive(Debug, Clone, PartialEq)]
pub enum BaselineSource {
    /// Fitted on the calibrated histograms of this ISO.
    Fitted,
    /// The NoiseProfile stored with this ISO's captures.
    CameraProfile,
    /// Interpolated (or extrapolated) parametrically from these calibrated ISOs.
    Interpolated { from: Vec<u32>, extrapolated: bool },
}

/// A parametric baseline at one ISO.
#[derive(Debug, Clone, PartialEq)]
pub struct Baseline {
    pub kind: BaselineKind,
    pub iso: u32,
    pub params: [NoiseParams; POSITIONS],
    pub source: BaselineSource,
}

/// The statistics of one calibrated bin used by the fits.
#[derive(Debug, Clone, PartialEq)]
pub struct BinStat {
    pub bin: usize,
    /// Centre level of the bin above black (DN).
    pub level_above_black: f64,
    pub mean: f64,
    pub var: f64,
    pub samples: u64,
    pub filled: bool,
    /// Some of the bin's noise reaches 0 or white (its variance is shrunk by clipping).
    pub clipped: bool,
}

/// Per-bin statistics of one position of a model.
pub fn bin_stats(binning: &Binning, model: &IsoModel, pos: usize) -> Vec<BinStat> {
    let bw = binning.bin_width as f64;
    let black = binning.black[pos] as f64;
    let white = binning.white as f64;
    model.positions[pos]
        .bins
        .iter()
        .enumerate()
        .map(|(bin, bm)| {
            // The PMF's moments: for calibrated bins the estimator's (own samples, pooled where
            // held-out frames favoured it), which are steadier than a sparse bin's own moments.
            let (mean, var) = bm.moments();
            let pmf = bm.pmf();
            let lo_level = black + bin as f64 * bw;
            let hi_level = (lo_level + bw).min(white);
            let clipped = lo_level.round() + pmf.quantile(0.001) < 0.5 || hi_level + pmf.quantile(0.999) > white - 0.5;
            BinStat {
                bin,
                level_above_black: (bin as f64 + 0.5) * bw,
                mean,
                var,
                samples: bm.samples,
                filled: bm.filled(),
                clipped,
            }
        })
        .collect()
}

/// Fits `σ² = a·(l − black) + b` (non-negative `a`, `b`) to the per-bin variances of one
/// position. Bins whose PMF is clipped at 0 or white are left out; bins with samples of their own
/// are weighted by
/// `samples / σ⁴` (the inverse variance of a sample variance), bins without samples only when
/// fewer than two measured bins remain. Returns `None` when no bin is usable.
pub fn fit_params(binning: &Binning, model: &IsoModel, pos: usize) -> Option<NoiseParams> {
    let stats = bin_stats(binning, model, pos);
    let pick = |allow_filled: bool, allow_clipped: bool| -> Vec<&BinStat> {
        stats
            .iter()
            // A bin stands on data when it has samples of its own; a clipped bin whose PMF the
            // estimator replaced by the unclipped law is usable too (its PMF is not clipped).
            .filter(|s| (allow_filled || s.samples > 0) && (allow_clipped || !s.clipped))
            .filter(|s| s.samples > 0 || allow_filled)
            .collect()
    };
    let mut used = pick(false, false);
    if used.len() < 2 {
        used = pick(true, false);
    }
    if used.len() < 2 {
        used = pick(true, true);
    }
    if used.is_empty() {
        return None;
    }
    let x: Vec<f64> = used.iter().map(|s| s.level_above_black).collect();
    let y: Vec<f64> = used.iter().map(|s| s.var).collect();
    let w: Vec<f64> = used.iter().map(|s| s.samples.max(1) as f64 / s.var.max(1e-3).powi(2)).collect();
    let c = if used.len() >= 2 { nn_poly_fit(&x, &y, &w, 1) } else { vec![y[0], 0.0] };
    Some(NoiseParams { a: c[1], b: c[0] })
}

/// HG parameters of every position of a model (positions without usable bins get `a = 0` and
/// `b` = the mean variance of their bins).
pub fn fit_all(binning: &Binning, model: &IsoModel) -> [NoiseParams; POSITIONS] {
    std::array::from_fn(|pos| {
        fit_params(binning, model, pos).unwrap_or_else(|| {
            let st = bin_stats(binning, model, pos);
            let b = st.iter().map(|s| s.var).sum::<f64>() / st.len().max(1) as f64;
            NoiseParams { a: 0.0, b }
        })
    })
}

/// The NoiseProfile `[[S, O]; 4]` of a model as variance laws in DN.
pub fn profile_params(binning: &Binning, profile: &[[f64; 2]; POSITIONS]) -> [NoiseParams; POSITIONS] {
    std::array::from_fn(|pos| {
        let range = (binning.white as f64 - binning.black[pos] as f64).max(1.0);
        NoiseParams { a: profile[pos][0] * range, b: profile[pos][1] * range * range }
    })
}

/// The baseline of a calibrated ISO model: fitted (HG, PG) or read from its NoiseProfile.
pub fn fit(pack: &ModelPack, model: &IsoModel, kind: BaselineKind) -> Result<Baseline, ModelError> {
    let binning = pack.binning();
    let (params, source) = match kind {
        BaselineKind::Hg | BaselineKind::Pg => (fit_all(&binning, model), BaselineSource::Fitted),
        BaselineKind::NoiseProfile => {
            let Some(p) = &model.noise_profile else {
                return Err(no_profile(model.iso));
            };
            (profile_params(&binning, p), BaselineSource::CameraProfile)
        }
    };
    Ok(Baseline { kind, iso: model.iso, params, source })
}

fn no_profile(iso: u32) -> ModelError {
    ModelError::Unsupported(format!(
        "ISO {iso} has no NoiseProfile: its captures did not carry DNG tag 51041 / SENSOR_NOISE_PROFILE; use --model hg or pg instead"
    ))
}

/// A baseline interpolated "the usual parametric way" across ISO: per position `a` linear in
/// ISO and `b = c + d·a²` (non-negative fits) over the calibrated ISOs on the target's side of
/// any conversion-gain switch ([`crate::interp::plan`]). With one such ISO, `a` scales with the
/// ISO ratio `r` and `b` with `r²`. Outside the calibrated range this is refused unless
/// `extrapolate`. For NoiseProfile, only calibrated ISOs that carry a profile are used.
pub fn interpolate(pack: &ModelPack, iso: u32, kind: BaselineKind, extrapolate: bool) -> Result<Baseline, ModelError> {
    let plan = crate::interp::plan(pack, iso, extrapolate)?;
    let binning = pack.binning();
    let mut pts: Vec<(f64, [NoiseParams; POSITIONS])> = Vec::new();
    for &k in &plan.segment {
        let Some(m) = pack.iso(k) else { continue };
        let params = match kind {
            BaselineKind::Hg | BaselineKind::Pg => fit_all(&binning, m),
            BaselineKind::NoiseProfile => match &m.noise_profile {
                Some(p) => profile_params(&binning, p),
                None => continue,
            },
        };
        pts.push((k as f64, params));
    }
    if pts.is_empty() {
        return Err(match kind {
            BaselineKind::NoiseProfile => ModelError::Unsupported(format!(
                "no calibrated ISO next to ISO {iso} carries a NoiseProfile; use --model hg or pg instead"
            )),
            _ => ModelError::IsoMissing { iso, available: pack.iso_summary() },
        });
    }
    let j = iso as f64;
    let params = std::array::from_fn(|pos| {
        if pts.len() == 1 {
            let r = j / pts[0].0;
            let p = pts[0].1[pos];
            return NoiseParams { a: p.a * r, b: p.b * r * r };
        }
        let scale = pts.iter().map(|p| p.0).fold(0.0, f64::max);
        let xs: Vec<f64> = pts.iter().map(|p| p.0 / scale).collect();
        let av: Vec<f64> = pts.iter().map(|p| p.1[pos].a).collect();
        let bv: Vec<f64> = pts.iter().map(|p| p.1[pos].b).collect();
        let w_a: Vec<f64> = av.iter().map(|&a| 1.0 / a.max(1e-6).powi(2)).collect();
        let ca = nn_poly_fit(&xs, &av, &w_a, 1);
        let a = poly_eval(&ca, j / scale);
        let a2: Vec<f64> = av.iter().map(|&a| a * a).collect();
        let a2_scale = a2.iter().cloned().fold(1e-12, f64::max);
        let x2: Vec<f64> = a2.iter().map(|v| v / a2_scale).collect();
        let w_b: Vec<f64> = bv.iter().map(|&b| 1.0 / b.max(1e-6).powi(2)).collect();
        let cb = nn_poly_fit(&x2, &bv, &w_b, 1);
        let b = poly_eval(&cb, a * a / a2_scale);
        NoiseParams { a, b }
    });
    Ok(Baseline {
        kind,
        iso,
        params,
        source: BaselineSource::Interpolated {
            from: pts.iter().map(|p| p.0 as u32).collect(),
            extrapolated: plan.extrapolated,
        },
    })
}

/// The baseline at an ISO: fitted when the ISO is calibrated in the pack, else interpolated
/// parametrically ([`interpolate`]).
pub fn baseline(pack: &ModelPack, iso: u32, kind: BaselineKind, extrapolate: bool) -> Result<Baseline, ModelError> {
    match pack.iso(iso) {
        Some(m) if m.is_calibrated() => fit(pack, m, kind),
        _ => interpolate(pack, iso, kind, extrapolate),
    }
}

/// The baseline at an ISO as an [`IsoModel`] (for `synth --model hg|pg|noiseprofile`; refuses
/// ISOs outside the calibrated range).
pub fn baseline_model(pack: &ModelPack, iso: u32, kind: BaselineKind) -> Result<IsoModel, ModelError> {
    Ok(baseline(pack, iso, kind, false)?.to_model(pack))
}

impl Baseline {
    /// Variance (DN²) at a level (DN, black included) and position.
    pub fn variance(&self, binning: &Binning, pos: usize, level: f64) -> f64 {
        self.params[pos].variance(level - binning.black[pos] as f64)
    }

    /// PMF of `noisy − level` at one integer clean level (clipping at 0 and white included).
    pub fn level_pmf(&self, binning: &Binning, pos: usize, level: i32) -> Pmf {
        let p = self.params[pos];
        let above = (level as f64 - binning.black[pos] as f64).max(0.0);
        let raw = match self.kind {
            BaselineKind::Hg | BaselineKind::NoiseProfile => {
                let var = (p.variance(above) - 1.0 / 12.0).max(1e-8);
                gaussian_cells(0.0, var.sqrt())
            }
            BaselineKind::Pg => pg_cells(p.a, (p.b - 1.0 / 12.0).max(0.0), above),
        };
        clip(&raw, level, binning.white as i32)
    }

    /// PMF of one bin: the mean of [`Self::level_pmf`] over up to [`LEVELS_PER_BIN`] levels
    /// spread across the bin.
    pub fn bin_pmf(&self, binning: &Binning, pos: usize, bin: usize) -> Pmf {
        let levels = bin_levels(binning, pos, bin);
        let pmfs: Vec<Pmf> = levels.iter().map(|&l| self.level_pmf(binning, pos, l)).collect();
        average(&pmfs)
    }

    /// The baseline as an ordinary model of its ISO: gain ratios, frame counts and noise profile
    /// are copied from the pack's model of that ISO when it has one. Bins are marked filled
    /// (they are not measured PMFs) and keep the calibrated sample counts.
    pub fn to_model(&self, pack: &ModelPack) -> IsoModel {
        let binning = pack.binning();
        let src = pack.iso(self.iso);
        let positions = (0..POSITIONS)
            .map(|pos| {
                // PMFs of a Poisson–Gaussian bin are costly; bins are independent (order kept).
                PositionModel::new(
                    (0..binning.bins(pos))
                        .into_par_iter()
                        .map(|bin| {
                            let samples = src
                                .and_then(|m| m.positions.get(pos))
                                .and_then(|pm| pm.bins.get(bin))
                                .map_or(0, |b| b.samples);
                            BinModel::from_pmf(&self.bin_pmf(&binning, pos, bin), samples, true)
                        })
                        .collect(),
                )
            })
            .collect();
        let origin = match &self.source {
            BaselineSource::Interpolated { from, extrapolated: true } => {
                ModelOrigin::Extrapolated { from: from.clone() }
            }
            BaselineSource::Interpolated { from, .. } => ModelOrigin::Interpolated { from: from.clone() },
            _ => src.map_or(ModelOrigin::Calibrated, |m| m.origin.clone()),
        };
        IsoModel {
            iso: self.iso,
            origin,
            frames: src.map_or(0, |m| m.frames),
            drift_frames: src.map_or(0, |m| m.drift_frames),
            gain_ratio: src.map_or([1.0; POSITIONS], |m| m.gain_ratio),
            noise_profile: src.and_then(|m| m.noise_profile),
            // A parametric baseline knows nothing of the codes a sensor writes.
            range: [[0, pack.layout.white]; POSITIONS],
            lattice: [None; POSITIONS],
            positions,
        }
    }
}

/// Up to [`LEVELS_PER_BIN`] integer levels spread evenly over a bin (from the black level up).
pub fn bin_levels(binning: &Binning, pos: usize, bin: usize) -> Vec<i32> {
    let bw = binning.bin_width as f64;
    let black = binning.black[pos] as f64;
    let last_bin = binning.bins(pos) - 1;
    let start = (black + bin as f64 * bw).ceil() as i32;
    let end = if bin >= last_bin { binning.white as i32 } else { (black + (bin + 1) as f64 * bw).ceil() as i32 - 1 };
    if end < start {
        return vec![binning.center(pos, bin).round() as i32];
    }
    let count = (end - start + 1) as usize;
    let k = count.min(LEVELS_PER_BIN);
    (0..k).map(|i| start + (((i as f64 + 0.5) * count as f64 / k as f64).floor() as i32)).collect()
}

/// Mean of PMFs on their common grid.
fn average(pmfs: &[Pmf]) -> Pmf {
    let Some(first) = pmfs.iter().map(|p| p.first).min() else {
        return Pmf { first: 0, p: vec![1.0] };
    };
    let last = pmfs.iter().map(|p| p.last()).max().unwrap_or(first);
    let mut acc = vec![0.0; (last - first + 1) as usize];
    for p in pmfs {
        let off = (p.first - first) as usize;
        for (i, &x) in p.p.iter().enumerate() {
            acc[off + i] += x;
        }
    }
    Pmf::from_weights(first, acc).unwrap_or(Pmf { first: 0, p: vec![1.0] })
}

/// Folds the mass of `level + n < 0` onto `n = −level` and of `level + n > white` onto
/// `n = white − level`.
fn clip(p: &Pmf, level: i32, white: i32) -> Pmf {
    let lo = -level;
    let hi = white - level;
    if p.first >= lo && p.last() <= hi {
        return p.clone();
    }
    let first = p.first.max(lo).min(hi);
    let last = p.last().min(hi).max(lo);
    let mut out = vec![0.0; (last - first + 1).max(1) as usize];
    for (i, &x) in p.p.iter().enumerate() {
        let n = (p.first + i as i32).clamp(lo, hi).clamp(first, last);
        out[(n - first) as usize] += x;
    }
    Pmf::from_weights(first, out).unwrap_or(Pmf { first, p: vec![1.0] })
}

/// `round(N(mu, sd²))` on the integer grid.
fn gaussian_cells(mu: f64, sd: f64) -> Pmf {
    let mut acc = Vec::new();
    let first = add_gaussian_cells(&mut acc, None, mu, sd, 1.0);
    Pmf::from_weights(first, acc).unwrap_or(Pmf { first: mu.round() as i32, p: vec![1.0] })
}

/// Adds `weight · round(N(mu, sd²))` into `acc` (which starts at `first`, or is created when
/// `first` is `None`); grows as needed and returns the (possibly new) first value.
fn add_gaussian_cells(acc: &mut Vec<f64>, first: Option<i32>, mu: f64, sd: f64, weight: f64) -> i32 {
    let sd = sd.max(1e-6);
    let lo = (mu - 8.0 * sd - 1.0).floor() as i32;
    let hi = (mu + 8.0 * sd + 1.0).ceil() as i32;
    let mut first = first.unwrap_or(lo);
    if acc.is_empty() {
        first = lo;
        acc.resize((hi - lo + 1) as usize, 0.0);
    }
    if lo < first {
        let shift = (first - lo) as usize;
        let mut v = vec![0.0; shift];
        v.extend_from_slice(acc);
        *acc = v;
        first = lo;
    }
    let need = (hi - first + 1) as usize;
    if acc.len() < need {
        acc.resize(need, 0.0);
    }
    let mut prev = (lo as f64 - 0.5 - mu) / sd;
    for n in lo..=hi {
        let next = (n as f64 + 0.5 - mu) / sd;
        acc[(n - first) as usize] += weight * normal_mass(prev, next);
        prev = next;
    }
    first
}

/// Poisson–Gaussian noise (DN) around a level `above` DN over black: gain `gain` DN/e⁻,
/// continuous read variance `read_var`, rounded to integers (no clipping here).
fn pg_cells(gain: f64, read_var: f64, above: f64) -> Pmf {
    let sd = read_var.sqrt().max(1e-3);
    if gain <= 0.0 || above <= 0.0 {
        return gaussian_cells(0.0, sd);
    }
    let lambda = above / gain;
    if lambda > PG_EXACT_MAX_LAMBDA {
        return gaussian_cells(0.0, (gain * above + read_var).sqrt());
    }
    let spread = 10.0 * lambda.sqrt() + 10.0;
    let k0 = (lambda - spread).floor().max(0.0) as i64;
    let k1 = (lambda + spread).ceil() as i64;
    let mut acc = Vec::new();
    let mut first: Option<i32> = None;
    for k in k0..=k1 {
        let lp = k as f64 * lambda.ln() - lambda - ln_gamma(k as f64 + 1.0);
        let pk = lp.exp();
        if pk < 1e-15 {
            continue;
        }
        first = Some(add_gaussian_cells(&mut acc, first, gain * (k as f64 - lambda), sd, pk));
    }
    Pmf::from_weights(first.unwrap_or(0), acc).unwrap_or(Pmf { first: 0, p: vec![1.0] })
}

/// `P(z0 < Z < z1)` for a standard normal `Z`, accurate in both tails.
pub fn normal_mass(z0: f64, z1: f64) -> f64 {
    if z1 <= z0 {
        return 0.0;
    }
    let q = |z: f64| 0.5 * erfc(z / std::f64::consts::SQRT_2); // upper tail
    let m = if z0 >= 0.0 {
        q(z0) - q(z1)
    } else if z1 <= 0.0 {
        q(-z1) - q(-z0)
    } else {
        1.0 - q(-z0) - q(z1)
    };
    m.max(0.0)
}

/// Complementary error function (Numerical Recipes' Chebyshev fit, fractional error
/// < 1.2·10⁻⁷ everywhere).
pub fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let r = t
        * (-z * z - 1.265_512_23
            + t * (1.000_023_68
                + t * (0.374_091_96
                    + t * (0.096_784_18
                        + t * (-0.186_288_06
                            + t * (0.278_868_07
                                + t * (-1.135_203_98
                                    + t * (1.488_515_87 + t * (-0.822_152_23 + t * 0.170_872_77)))))))))
            .exp();
    if x >= 0.0 { r } else { 2.0 - r }
}

/// ln Γ(x) for x > 0 (Lanczos, g = 7).
pub fn ln_gamma(x: f64) -> f64 {
    const C: [f64; 9] = [
        0.999_999_999_999_809_9,
        676.520_368_121_885_1,
        -1_259.139_216_722_402_8,
        771.323_428_777_653_1,
        -176.615_029_162_140_6,
        12.507_343_278_686_905,
        -0.138_571_095_265_720_12,
        9.984_369_578_019_572e-6,
        1.505_632_735_149_311_6e-7,
    ];
    if x < 0.5 {
        // Reflection.
        let s = (std::f64::consts::PI * x).sin();
        return std::f64::consts::PI.ln() - s.abs().ln() - ln_gamma(1.0 - x);
    }
    let x = x - 1.0;
    let mut a = C[0];
    for (i, &c) in C.iter().enumerate().skip(1) {
        a += c / (x + i as f64);
    }
    let t = x + 7.5;
    0.5 * (2.0 * std::f64::consts::PI).ln() + (x + 0.5) * t.ln() - t + a.ln()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn special_functions() {
        // Φ(1) − Φ(−1) = 0.682689492…, upper tail at 5σ = 2.8665e-7.
        assert!((normal_mass(-1.0, 1.0) - 0.682_689_492).abs() < 1e-7);
        let t5 = normal_mass(5.0, 50.0);
        assert!((t5 / 2.866_515_7e-7 - 1.0).abs() < 1e-5, "{t5}");
        let mut f = 1.0f64;
        for k in 1..40 {
            f *= k as f64;
            assert!((ln_gamma(k as f64 + 1.0) - f.ln()).abs() < 1e-10 * f.ln().max(1.0));
        }
    }

    #[test]
    fn pg_cells_moments() {
        // gain 2 DN/e, read var 4, 50 e⁻ → variance 2·100 + 4 + 1/12, mean 0, skew 1/√λ.
        let p = pg_cells(2.0, 4.0, 100.0);
        let (m, v) = p.moments();
        assert!(m.abs() < 1e-6, "{m}");
        assert!((v - (204.0 + 1.0 / 12.0)).abs() < 0.05, "{v}");
        // Large gain, no read noise: a lattice every 8 DN.
        let p = pg_cells(8.0, 0.0, 40.0);
        assert!(p.at(0) > 0.1 && p.at(4) < 1e-9 && p.at(8) > 0.1);
    }
}
