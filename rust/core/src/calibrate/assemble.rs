//! The pack at the end of a session (method.md, "Estimation"): per ISO and position the
//! estimator over the fold histograms, the output range and lattice from the code counts, the
//! gain ratios and their warnings, then the pack's self-check.

use crate::calibrate::codes::{detect, output_range};
use crate::calibrate::dark::difference;
use crate::calibrate::estimate::{BinLevels, Pooling, estimate_position_with_black};
use crate::calibrate::motion::MOTION_TOLERANCE;
use crate::calibrate::session::CalibrationSession;
use crate::error::SessionError;
use crate::model::check::{self_check, spread_check};
use crate::model::layout::POSITIONS;
use crate::model::pack::{IsoModel, ModelOrigin, ModelPack, PositionModel};
use crate::model::structure::{FixedPattern, IsoStructure};

/// Measured noise variance (DN²) below which an ISO has no noise at all.
pub const NO_NOISE_VARIANCE: f64 = 1e-3;

/// A fixed pattern whose variance is below this share of the ISO's lowest pixel variance is not
/// added at synthesis.
pub const PATTERN_RELEVANCE: f64 = 0.01;

/// A gain ratio further than this from 1 is reported prominently: more likely a capture problem
/// than a sensor property.
pub const FAR_GAIN_RATIO: f64 = 0.10;
/// Fewer measured samples than this at a CFA position of an ISO is a sparse session (a tiny
/// region of interest, a chart mostly masked): most of its bins stand on the noise law, not on
/// measurements, and the pack says so.
pub const SPARSE_POSITION_SAMPLES: u64 = 1000;

impl CalibrationSession {
    /// Builds the model pack from everything folded in so far: per ISO and position, the
    /// estimator of [`crate::calibrate::estimate`] (pooling chosen by cross-validation over the folds unless
    /// the configuration fixes it), then the pack's self-check ([`crate::model::check`]). It is
    /// put in the form a pack file keeps ([`ModelPack::compacted`]), so the pack in memory is the
    /// one its file loads back.
    pub fn finish(&self) -> Result<ModelPack, SessionError> {
        Ok(self.finish_exact()?.compacted())
    }

    /// [`CalibrationSession::finish`] before the pack is put in the form its file keeps (what a
    /// version 4 pack held): for measuring what that changes.
    pub fn finish_exact(&self) -> Result<ModelPack, SessionError> {
        use rayon::prelude::*;
        let mut warnings: Vec<String> = self.events.iter().filter(|e| e.contains("brightness")).cloned().collect();
        let pooling =
            if self.config.plain { Pooling::Plain } else { self.config.pooling.map_or(Pooling::Auto, Pooling::Fixed) };
        let levels: Vec<BinLevels> = (0..POSITIONS).map(|p| BinLevels::new(&self.binning, p)).collect();
        let jobs: Vec<(u32, usize)> = self.isos.keys().flat_map(|&iso| (0..POSITIONS).map(move |p| (iso, p))).collect();
        // An ISO with a position no sample reached is left out below: none of its positions is
        // estimated (estimation is the costly part of finishing).
        let unreached: std::collections::BTreeMap<u32, Option<usize>> = self
            .isos
            .iter()
            .map(|(&iso, acc)| {
                let empty = |p: &usize| acc.folds_of(*p).iter().all(|f| f.iter().all(|h| h.total() == 0));
                (iso, (0..POSITIONS).find(empty))
            })
            .collect();
        let black_noise = self.all_black_noise();
        // Every (ISO, position) is estimated on its own: in parallel, collected in order.
        let estimates: Vec<_> = jobs
            .par_iter()
            .map(|&(iso, p)| {
                let acc = &self.isos[&iso];
                let folds = acc.folds_of(p);
                let shifts = acc.shifts_of(p);
                let range = output_range(&acc.codes[p], self.layout.white);
                let levels = levels[p].clone().with_range([range.floor, range.saturation]);
                let black = black_noise.get(&iso).map(|h| &h[p]);
                unreached[&iso]
                    .is_none()
                    .then(|| estimate_position_with_black(&folds, &shifts, &levels, pooling, black))
            })
            .collect();
        let mut isos = Vec::new();
        for (i, (&iso, acc)) in self.isos.iter().enumerate() {
            if let Some(p) = unreached[&iso] {
                warnings.push(format!(
                    "ISO {iso}: no flat pixel at CFA position {p} ({}) gave a sample; the ISO is left out — capture more frames",
                    self.layout.cfa.position_name(p),
                ));
                continue;
            }
            // Every position of a reached ISO was estimated.
            let positions: Vec<PositionModel> = estimates[i * POSITIONS..(i + 1) * POSITIONS]
                .iter()
                .flatten()
                .map(|e| PositionModel { bins: e.bins.clone(), estimate: Some(e.report.clone()) })
                .collect();
            // Real raw noise is never below quantisation's 1/12 DN²: none at all means copied frames.
            // Only clipped bins with most codes at white mean nothing below the clip was seen:
            // saturated frames. (Copies of a flat frame also give only clipped bins, their one code
            // looking like a pile-up, and so can a sparse region of interest.)
            let measured: Vec<(f64, bool)> = positions
                .iter()
                .flat_map(|pm| &pm.bins)
                .filter_map(|b| b.measured.filter(|_| b.samples > 0).map(|[_, v]| (v, b.clipped)))
                .collect();
            let all_clipped = measured.iter().all(|m| m.1);
            let judged = measured.iter().filter(|m| all_clipped || !m.1);
            if !measured.is_empty() && all_clipped {
                let white = self.layout.white as usize;
                let (at_white, all) = acc.codes.iter().fold((0u64, 0u64), |(w, a), c| {
                    (w + c.get(white).copied().unwrap_or(0), a + c.iter().sum::<u64>())
                });
                if 2 * at_white > all {
                    return Err(SessionError::Saturated { iso });
                }
            }
            if !measured.is_empty() && judged.clone().all(|&(v, _)| v < NO_NOISE_VARIANCE) {
                return Err(SessionError::NoNoise { iso });
            }
            let gain_ratio: [f64; POSITIONS] = std::array::from_fn(|p| {
                if acc.reference_sum[p] > 0.0 { acc.target_sum[p] / acc.reference_sum[p] } else { 1.0 }
            });
            for (p, pm) in positions.iter().enumerate() {
                let samples: u64 = pm.bins.iter().map(|b| b.samples).sum();
                if samples < SPARSE_POSITION_SAMPLES {
                    warnings.push(format!(
                        "ISO {iso} {}: only {samples} samples were measured (a pack wants ≥ {SPARSE_POSITION_SAMPLES} per position, and real sessions give millions); most of its noise is filled in from the noise law, not measured. Widen the region of interest or capture more frames",
                        self.layout.cfa.position_name(p)
                    ));
                }
            }
            for (p, g) in gain_ratio.iter().enumerate() {
                let name = self.layout.cfa.position_name(p);
                if (g - 1.0).abs() > FAR_GAIN_RATIO {
                    warnings.push(format!(
                        "ISO {iso} {name}: GAIN RATIO {g:.3} IS FAR FROM 1 ({:+.0} %): the target bursts are {} than their reference bursts at the same ISO × exposure. Check that the light did not change between bursts and that the exposures applied; if the camera really is this far from nominal, the model keeps the mean shift",
                        (g - 1.0) * 100.0,
                        if *g > 1.0 { "brighter" } else { "darker" }
                    ));
                } else if (g - 1.0).abs() > 0.02 {
                    warnings.push(format!(
                        "ISO {iso} {name}: measured gain ratio {g:.4} is off 1 by {:+.1} % (gain not proportional to ISO); the model keeps the mean shift",
                        (g - 1.0) * 100.0
                    ));
                }
            }
            let mt = &acc.motion;
            if mt.moved().is_some() {
                warnings.push(format!(
                    "ISO {iso}: the chart moved between frames: target frames were up to {:.2} px (median {:.2} px) off their reference bursts; {:.2} % of flat samples were left out where that motion changed the level by more than {:.2} SD of the noise (it is not noise). Over about 0.3 px, a sturdier mount, optical stabilisation off or a remote trigger gives more samples",
                    mt.max_shift,
                    mt.median_shift(),
                    100.0 * mt.left_out as f64 / mt.offered.max(1) as f64,
                    MOTION_TOLERANCE,
                ));
            }
            isos.push(IsoModel {
                iso,
                origin: ModelOrigin::Calibrated,
                frames: acc.frames,
                drift_frames: acc.drift_frames,
                gain_ratio,
                noise_profile: match self.noise_profiles.get(&iso) {
                    Some(p) if !p.is_valid() => {
                        warnings.push(format!(
                            "ISO {iso}: the captures' NoiseProfile is impossible ({}); it was left out of the pack (the tag is damaged)",
                            p.problem().unwrap_or_default()
                        ));
                        None
                    }
                    p => p.copied(),
                },
                range: std::array::from_fn(|p| {
                    let r = output_range(&acc.codes[p], self.layout.white);
                    [r.floor, r.ceiling]
                }),
                lattice: if self.config.plain {
                    [None; POSITIONS]
                } else {
                    std::array::from_fn(|p| detect(&acc.codes[p], self.layout.white))
                },
                positions,
            });
        }
        if isos.is_empty() {
            return Err(SessionError::NothingCalibrated);
        }
        if !self.config.plain {
            // What the bursts showed of the light (taken out of the frame offsets, not noise).
            warnings.extend(isos.iter().filter_map(|m| self.isos[&m.iso].structure.flicker_note(m.iso)));
        }
        let mut pack = ModelPack {
            layout: self.layout.clone(),
            make: self.config.make.clone(),
            model: self.config.model.clone(),
            bin_width: self.binning.bin_width,
            reference_iso: self.config.reference_iso,
            pooling: self.config.pooling,
            structure: if self.config.plain {
                Vec::new()
            } else {
                isos.iter().map(|m| self.isos[&m.iso].structure.structure(m.iso, lowest_pixel_var(m))).collect()
            },
            isos,
            warnings,
        };
        if !self.config.plain {
            self.attach_patterns(&mut pack);
        }
        let checks = self_check(&pack);
        pack.warnings.extend(checks.into_iter().map(|c| c.to_string()));
        let spread = spread_check(
            &pack,
            |iso, pos| self.isos.get(&iso).and_then(|a| a.histograms(pos)),
            |iso| self.isos.get(&iso).and_then(|a| a.motion.moved()),
        );
        pack.warnings.extend(spread.into_iter().map(|c| c.to_string()));
        Ok(pack)
    }
}

impl CalibrationSession {
    /// Every ISO's fixed pattern, the dark burst in progress included.
    fn all_patterns(&self) -> std::collections::BTreeMap<u32, FixedPattern> {
        let mut patterns = self.patterns.clone();
        if let Some(burst) = self.open_dark()
            && let (_, Some(fp)) = self.closed(burst)
        {
            patterns.insert(burst.iso, fp);
        }
        patterns
    }

    /// Every ISO's noise at black from its dark frames, the dark burst in progress included
    /// (when it is the one its ISO's pattern would come from).
    fn all_black_noise(&self) -> std::collections::BTreeMap<u32, [crate::model::histogram::NoiseHistogram; POSITIONS]> {
        let mut out = self.black_noise.clone();
        if let Some(burst) = self.open_dark()
            && self.patterns.get(&burst.iso).is_none_or(|old| old.frames < burst.frames())
            && let Some(h) = burst.black_noise(&self.binning)
        {
            out.insert(burst.iso, h);
        }
        out
    }

    /// Gives each calibrated ISO with dark frames its fixed pattern: significant when it stands
    /// clear of its sampling noise and is at least [`PATTERN_RELEVANCE`] of the pixel variance;
    /// what the pixel PMFs already hold of it is the pattern's change from the reference ISO's
    /// (the clean images are means of reference frames, which carry that one): measured pixel by
    /// pixel when the reference ISO's dark burst came before, else derived from the two
    /// distributions.
    fn attach_patterns(&self, pack: &mut ModelPack) {
        let patterns = self.all_patterns();
        let reference = patterns.get(&self.config.reference_iso).cloned();
        if !patterns.is_empty() && reference.is_none() {
            pack.warnings.push(format!(
                "no dark frames at the reference ISO {}: the pixel PMFs are taken to hold each ISO's whole fixed pattern (capture the dark step at every ISO, the reference included)",
                self.config.reference_iso
            ));
        }
        for (&iso, fp) in &patterns {
            let Some(model) = pack.iso(iso) else {
                if iso == self.config.reference_iso {
                    continue; // the reference for the others' (above); no model of its own
                }
                pack.warnings.push(format!(
                    "dark frames at ISO {iso}, which has no target frames: its fixed pattern is not used"
                ));
                continue;
            };
            let pixel_var = lowest_pixel_var(model);
            let mut fp = fp.clone();
            let n = fp.frames.max(2) as f64;
            let mut own = 0.0;
            let mut se = 0.0;
            for p in 0..POSITIONS {
                let d = &fp.pixels[p];
                let count = d.count.max(1) as f64;
                own += fp.variance(p) / POSITIONS as f64;
                se += (d.measured_var * (2.0 / count).sqrt() + d.sampling_var * (2.0 / (count * (n - 1.0))).sqrt())
                    / POSITIONS as f64;
            }
            fp.significant = own > 3.0 * se && own >= PATTERN_RELEVANCE * pixel_var && own > 1e-6;
            for p in 0..POSITIONS {
                fp.pixels[p].significant = fp.significant;
                // Measured pixel by pixel against the reference's map when that came first;
                // else the two patterns coupled through one uniform per pixel.
                if fp.in_pixel_noise[p].count == 0 {
                    fp.in_pixel_noise[p] = difference(&fp, reference.as_ref(), p);
                }
            }
            let mut st = pack.structure_of(iso).cloned().unwrap_or_else(|| IsoStructure::empty(iso));
            st.fpn = Some(fp);
            pack.insert_structure(st);
        }
    }
}

/// An ISO's lowest measured pixel variance (DN², unclipped bins with samples; 0 without any):
/// what the structured components' relevance is judged against.
fn lowest_pixel_var(m: &IsoModel) -> f64 {
    let v = m
        .positions
        .iter()
        .flat_map(|pm| &pm.bins)
        .filter(|b| b.samples > 0 && !b.clipped)
        .filter_map(|b| b.measured.map(|[_, v]| v))
        .fold(f64::INFINITY, f64::min);
    if v.is_finite() { v } else { 0.0 }
}
