//! Noise on noise (paper §4.2, method.md "Noise on noise"): turn a real capture at source ISO `a`
//! into a realistic capture of the same scene at a higher target ISO `b`.
//!
//! Four methods, so they can be compared (measured, not assumed):
//! - [`Method::Bridge`] (default, paper Eq. 7): `out = in + d`, `d ~ q(position, bin of Î)` with
//!   `p_a ∗ q ≈ p_b` ([`crate::renoise::bridge`]).
//! - [`Method::Quantile`]: the input's own noise `n_a = in − round(Î)` is mapped through the source
//!   CDF of (position, bin of Î), randomised within its integer cell (randomised probability
//!   integral transform), then through the target inverse CDF: `out = round(Î) + F_b⁻¹(u)`.
//! - [`Method::Denoised`]: `out = round(Î) + n_b`, `n_b ~ p_b(bin of round(Î))`.
//! - [`Method::Naive`]: `out = in + n_b`, `n_b ~ p_b(bin of in)` (common practice; overshoots).
//!
//! `Î` is the clean estimate: the user's own, or [`crate::renoise::denoise::estimate_clean`]. Everything
//! is clamped to `[0, white]`. Draws come from one ChaCha stream per band of
//! [`crate::synth::BAND_ROWS`] rows ([`crate::synth::band_rng`], seeded with the user's seed mixed
//! with a renoise-specific constant so a renoise never reuses the draws of a synthesis with the
//! same seed): the same seed gives the same bytes whatever the thread count.

pub mod bridge;
pub mod denoise;

use ndarray::{Array2, ArrayView2};
use rand::Rng;
use rayon::prelude::*;
use thiserror::Error;

use crate::error::ModelError;
use crate::model::layout::{Binning, POSITIONS, SensorLayout, position};
use crate::model::pack::{IsoModel, ModelPack};
use crate::renoise::bridge::{Bridge, BridgeError, BridgeOptions, build_bridge_with};
use crate::synth::sampler::BinTable;
use crate::synth::{BAND_ROWS, band_rng};

/// How the target-ISO noise is produced.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Default)]
pub enum Method {
    /// `in + d`, `d` from the bridge model (paper Eq. 7).
    #[default]
    Bridge,
    /// The input's own noise mapped quantile-to-quantile onto the target PMF.
    Quantile,
    /// Clean estimate plus target noise.
    Denoised,
    /// Input plus target noise (the common practice).
    Naive,
}

impl Method {
    pub const ALL: [Method; 4] = [Method::Bridge, Method::Quantile, Method::Denoised, Method::Naive];

    pub fn name(self) -> &'static str {
        match self {
            Method::Bridge => "bridge",
            Method::Quantile => "quantile",
            Method::Denoised => "denoised",
            Method::Naive => "naive",
        }
    }

    /// Parses `bridge`, `quantile`, `denoised`, `naive` (case-insensitive).
    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|m| m.name().eq_ignore_ascii_case(s.trim()))
    }

    /// Whether the method needs a clean estimate.
    pub fn needs_estimate(self) -> bool {
        !matches!(self, Method::Naive)
    }
}

impl std::fmt::Display for Method {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Method {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::parse(s).ok_or_else(|| format!("unknown renoise method {s:?}: use bridge, quantile, denoised or naive"))
    }
}

/// A renoised image and what was noticed on the way.
#[derive(Debug, Clone, PartialEq)]
pub struct RenoiseOutput {
    pub image: Array2<u16>,
    /// Bridge flags (ISO pair and bins) and input problems, for the user.
    pub warnings: Vec<String>,
}

/// Why a renoise was refused.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum RenoiseError {
    #[error(transparent)]
    Bridge(#[from] BridgeError),
    #[error(transparent)]
    Model(#[from] ModelError),
    #[error(
        "the clean estimate is {est_width}×{est_height} but the image is {width}×{height}: give an estimate of the same capture (same crop)"
    )]
    EstimateSize { width: usize, height: usize, est_width: usize, est_height: usize },
    #[error(
        "the clean estimate has a non-finite value at row {row}, column {col}: give an estimate with finite levels in DN"
    )]
    EstimateNotFinite { row: usize, col: usize },
}

/// Per position, per bin: the source PMF's first value and its CDF `P(n ≤ first + i)`.
type SourceCdfs = [Vec<(i32, Vec<f64>)>; POSITIONS];

/// Everything needed to renoise captures from one ISO to another with one method, built once
/// (bridge deconvolution, sampling tables) and applied to any number of images.
#[derive(Debug, Clone)]
pub struct Renoiser {
    method: Method,
    source: IsoModel,
    target_iso: u32,
    layout: SensorLayout,
    binning: Binning,
    luts: [Vec<u16>; POSITIONS],
    /// Target PMFs (naive, denoised, quantile).
    target_tables: Option<[Vec<BinTable>; POSITIONS]>,
    /// Source CDFs per bin for the quantile method: (first, P(n ≤ first + i)).
    source_cdfs: Option<SourceCdfs>,
    bridge: Option<Bridge>,
    warnings: Vec<String>,
}

/// Salt mixed into the user's seed: renoise draws never coincide with a synthesis's draws.
const SEED_SALT: u64 = 0x5245_4e4f_4953_4521; // "RENOISE!"

impl Renoiser {
    /// Prepares `source → target` renoising with `method` (default bridge options).
    pub fn new(pack: &ModelPack, source: &IsoModel, target: &IsoModel, method: Method) -> Result<Self, RenoiseError> {
        Self::with_options(pack, source, target, method, &BridgeOptions::default())
    }

    /// As [`Renoiser::new`] with explicit bridge options. Refuses a target ISO that is not above
    /// the source ISO (for every method: noise on noise only adds noise).
    pub fn with_options(
        pack: &ModelPack,
        source: &IsoModel,
        target: &IsoModel,
        method: Method,
        opts: &BridgeOptions,
    ) -> Result<Self, RenoiseError> {
        if target.iso <= source.iso {
            return Err(BridgeError::NotHigher { from_iso: source.iso, to_iso: target.iso }.into());
        }
        let binning = pack.binning();
        for m in [source, target] {
            let ok =
                m.positions.len() == POSITIONS && (0..POSITIONS).all(|p| m.positions[p].bins.len() == binning.bins(p));
            if !ok {
                return Err(BridgeError::Mismatch {
                    from_iso: source.iso,
                    to_iso: target.iso,
                    detail: format!("the ISO {} model does not match the pack's binning", m.iso),
                }
                .into());
            }
        }
        let luts = std::array::from_fn(|p| binning.lut(p));
        let bridge = match method {
            Method::Bridge => Some(build_bridge_with(source, target, &binning, opts)?),
            _ => None,
        };
        let target_tables = match method {
            Method::Bridge => None,
            _ => Some(std::array::from_fn(|p| target.positions[p].bins.iter().map(BinTable::new).collect())),
        };
        let source_cdfs = match method {
            Method::Quantile => Some(std::array::from_fn(|p| {
                source.positions[p]
                    .bins
                    .iter()
                    .map(|b| {
                        let pmf = b.pmf();
                        (pmf.first, pmf.cdf())
                    })
                    .collect()
            })),
            _ => None,
        };
        let warnings = bridge.as_ref().map(|b| b.warnings.clone()).unwrap_or_default();
        Ok(Self {
            method,
            source: source.clone(),
            target_iso: target.iso,
            layout: pack.layout.clone(),
            binning,
            luts,
            target_tables,
            source_cdfs,
            bridge,
            warnings,
        })
    }

    pub fn method(&self) -> Method {
        self.method
    }

    pub fn source_iso(&self) -> u32 {
        self.source.iso
    }

    pub fn target_iso(&self) -> u32 {
        self.target_iso
    }

    /// The bridge model (bridge method only).
    pub fn bridge(&self) -> Option<&Bridge> {
        self.bridge.as_ref()
    }

    /// Warnings of the preparation (bridge flags naming the ISO pair and bins).
    pub fn warnings(&self) -> &[String] {
        &self.warnings
    }

    /// The built-in clean estimate of a capture at the source ISO.
    pub fn estimate(&self, noisy: ArrayView2<'_, u16>) -> Array2<f32> {
        crate::renoise::denoise::estimate_clean(noisy, &self.source, &self.binning, &self.layout)
    }

    /// Renoises one capture at the source ISO (CFA phase of the pack's layout at (0, 0)).
    /// `estimate` is the clean estimate `Î` in DN (same size); without one, the built-in
    /// denoiser runs (not needed by the naive method).
    pub fn apply(
        &self,
        noisy: ArrayView2<'_, u16>,
        estimate: Option<ArrayView2<'_, f32>>,
        seed: u64,
    ) -> Result<RenoiseOutput, RenoiseError> {
        let (h, w) = noisy.dim();
        let white = self.layout.white;
        let mut warnings = self.warnings.clone();
        // The clean level (rounded, clamped) that picks the bin, when the method uses one.
        let clean: Option<Array2<u16>> = if self.method.needs_estimate() {
            let est_owned;
            let est = match estimate {
                Some(e) => {
                    if e.dim() != (h, w) {
                        return Err(RenoiseError::EstimateSize {
                            width: w,
                            height: h,
                            est_width: e.ncols(),
                            est_height: e.nrows(),
                        });
                    }
                    if let Some(((row, col), _)) = e.indexed_iter().find(|(_, v)| !v.is_finite()) {
                        return Err(RenoiseError::EstimateNotFinite { row, col });
                    }
                    e
                }
                None => {
                    est_owned = self.estimate(noisy);
                    est_owned.view()
                }
            };
            let outside = est.iter().filter(|&&v| v < -0.5 || v > white as f32 + 0.5).count();
            if outside > 0 {
                warnings.push(format!(
                    "{outside} pixel(s) of the clean estimate lie outside [0, {white}] DN and were clamped; is it a raw-domain estimate with the black level included?"
                ));
            }
            Some(est.mapv(|v| v.round().clamp(0.0, white as f32) as u16))
        } else {
            None
        };

        let mut out = vec![0u16; h * w];
        if w > 0 {
            let seed = seed ^ SEED_SALT;
            out.par_chunks_mut(BAND_ROWS * w).enumerate().for_each(|(band, chunk)| {
                let mut rng = band_rng(seed, band);
                for (r, row) in chunk.chunks_mut(w).enumerate() {
                    let y = band * BAND_ROWS + r;
                    for (x, o) in row.iter_mut().enumerate() {
                        let pos = position(y, x);
                        let input = noisy[[y, x]];
                        let level = clean.as_ref().map_or(input, |c| c[[y, x]]);
                        *o = self.pixel(pos, input, level, &mut rng, white);
                    }
                }
            });
        }
        let image = Array2::from_shape_vec((h, w), out).expect("h × w samples");
        Ok(RenoiseOutput { image, warnings })
    }

    #[inline(always)]
    fn bin(&self, pos: usize, level: u16) -> usize {
        let lut = &self.luts[pos];
        lut[(level as usize).min(lut.len() - 1)] as usize
    }

    /// One output pixel. `level` is round(Î) (or the input itself for the naive method).
    #[inline(always)]
    fn pixel<R: Rng + ?Sized>(&self, pos: usize, input: u16, level: u16, rng: &mut R, white: u16) -> u16 {
        let bin = self.bin(pos, level);
        let v = match self.method {
            Method::Bridge => {
                let b = self.bridge.as_ref().expect("bridge built for the bridge method");
                input as i32 + b.table(pos, bin).sample_u32(rng.next_u32())
            }
            Method::Naive | Method::Denoised => {
                let t = &self.target_tables.as_ref().expect("target tables built")[pos][bin];
                let base = if self.method == Method::Naive { input } else { level };
                base as i32 + t.sample_u32(rng.next_u32())
            }
            Method::Quantile => {
                let (first, cdf) = &self.source_cdfs.as_ref().expect("source CDFs built")[pos][bin];
                let t = &self.target_tables.as_ref().expect("target tables built")[pos][bin];
                let n_a = input as i32 - level as i32;
                let v = rng.next_u32() as f64 / 4_294_967_296.0;
                let i = n_a - first;
                let (below, at) = if i < 0 {
                    (0.0, 0.0)
                } else if i as usize >= cdf.len() {
                    (1.0, 0.0)
                } else {
                    let i = i as usize;
                    let below = if i == 0 { 0.0 } else { cdf[i - 1] };
                    (below, cdf[i] - below)
                };
                let u = (below + v * at).clamp(0.0, 1.0);
                let u32v = (u * 4_294_967_296.0).min(4_294_967_295.0) as u32;
                level as i32 + t.sample_u32(u32v)
            }
        };
        v.clamp(0, white as i32) as u16
    }
}

/// Renoises `noisy` (a capture at `source_iso`) to `target_iso` with `method`. Models come from
/// [`crate::derive::interp::model_for`]: calibrated, or interpolated inside the calibrated range (use
/// [`Renoiser`] with models of your choice to extrapolate). `estimate` is the clean estimate in DN
/// (same size); without one the built-in denoiser runs. Same seed, same bytes, whatever the
/// thread count.
pub fn renoise(
    pack: &ModelPack,
    source_iso: u32,
    target_iso: u32,
    noisy: ArrayView2<'_, u16>,
    estimate: Option<ArrayView2<'_, f32>>,
    method: Method,
    seed: u64,
) -> Result<RenoiseOutput, RenoiseError> {
    if target_iso <= source_iso {
        return Err(BridgeError::NotHigher { from_iso: source_iso, to_iso: target_iso }.into());
    }
    let (source, _) = crate::derive::interp::model_for(pack, source_iso, false)?;
    let (target, _) = crate::derive::interp::model_for(pack, target_iso, false)?;
    Renoiser::new(pack, &source, &target, method)?.apply(noisy, estimate, seed)
}
