//! The model pack: everything a sampler needs, as a value (its file, behind a magic, a format
//! version and a checksum, is the format module's `pack_file`). Same frames in, same value out.

use serde::{Deserialize, Serialize};

use crate::error::{CodecError, ModelError};
pub use crate::model::bin_source::BinSource;
use crate::model::codes::CodeLattice;
use crate::model::estimate_report::EstimateReport;
use crate::model::layout::{Binning, POSITIONS, SensorLayout};
use crate::model::pmf::Pmf;
use crate::model::structure::IsoStructure;

/// The largest sensor side a pack may describe (pixels).
pub const MAX_SIDE: u32 = 1 << 16;

/// A calibrated (or interpolated) non-parametric noise model of one camera.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ModelPack {
    pub layout: SensorLayout,
    pub make: String,
    pub model: String,
    /// Levels per bin (DN).
    pub bin_width: u16,
    /// The reference (lowest) ISO of the calibration session.
    pub reference_iso: u32,
    /// The pooling threshold the user fixed (`None`: chosen per ISO and position by
    /// cross-validation; see [`PositionModel::estimate`]).
    pub pooling: Option<u64>,
    /// One model per ISO, sorted by ISO.
    pub isos: Vec<IsoModel>,
    /// What the calibration noticed (drifting frames, gain ratios off 1, sparse bins …).
    pub warnings: Vec<String>,
    /// Row, column and frame offsets per ISO, sorted by ISO ([`crate::model::structure`]);
    /// empty for packs made before version 3 and for `--plain` packs.
    pub structure: Vec<IsoStructure>,
}

/// The camera's own noise model per CFA position, `σ²/(white − black)² = S·x + O` with
/// `x = (l − black)/(white − black)` (DNG `NoiseProfile`, Camera2 `SENSOR_NOISE_PROFILE`): `[S, O]`
/// per position.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct NoiseProfile(pub [[f64; 2]; POSITIONS]);

impl NoiseProfile {
    /// `S` (the signal-dependent coefficient) at a position.
    pub fn scale(&self, pos: usize) -> f64 {
        self.0[pos][0]
    }

    /// `O` (the signal-independent coefficient) at a position.
    pub fn offset(&self, pos: usize) -> f64 {
        self.0[pos][1]
    }

    /// Every coefficient finite and non-negative, and the noise at white no wider than the
    /// sensor's range (`S + O ≤ 1`: real profiles are 10⁻⁸ … 10⁻³).
    pub fn is_valid(&self) -> bool {
        self.problem().is_none()
    }

    /// What makes this profile impossible, if anything.
    pub fn problem(&self) -> Option<String> {
        for (pos, [s, o]) in self.0.iter().enumerate() {
            if !(s.is_finite() && o.is_finite() && *s >= 0.0 && *o >= 0.0) {
                return Some(format!("position {pos} has S = {s}, O = {o}: both must be finite and non-negative"));
            }
            if s + o > 1.0 {
                return Some(format!(
                    "position {pos} has S = {s}, O = {o}: its noise at white is wider than the sensor's whole range (S + O > 1)"
                ));
            }
        }
        None
    }
}

/// Where an ISO's model comes from.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub enum ModelOrigin {
    /// Measured from target bursts.
    Calibrated,
    /// Interpolated between calibrated ISOs (paper §4.1).
    Interpolated { from: Vec<u32> },
    /// Extrapolated beyond the calibrated range (asked for explicitly).
    Extrapolated { from: Vec<u32> },
}

/// The model of one ISO.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IsoModel {
    pub iso: u32,
    pub origin: ModelOrigin,
    /// Target frames folded in.
    pub frames: u64,
    /// Frames whose brightness drifted and was normalised.
    pub drift_frames: u64,
    /// Measured target/reference brightness ratio per CFA position (1 = gain exactly
    /// proportional to ISO).
    pub gain_ratio: [f64; POSITIONS],
    /// The camera's own noise profile `σ² = S·x + O` (x in \[0,1\]) per CFA position, when the
    /// captures carried one (DNG NoiseProfile / SENSOR_NOISE_PROFILE).
    pub noise_profile: Option<NoiseProfile>,
    /// Per CFA position, the codes the sensor writes, `[floor, ceiling]`: its output piles up
    /// there (a full well below the reported white level, a black clamp: the calibration's output
    /// range). Synthesis clamps to it.
    pub range: [[u16; 2]; POSITIONS],
    /// Per CFA position, the codes the sensor writes when it does not write every code
    /// (digital gain; [`crate::model::codes`]). Synthesis snaps its output onto them.
    pub lattice: [Option<CodeLattice>; POSITIONS],
    /// Per CFA position, per bin.
    pub positions: Vec<PositionModel>,
}

/// The bins of one CFA position.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PositionModel {
    pub bins: Vec<BinModel>,
    /// What the estimator chose for this position (calibrated models of version 2 packs).
    pub estimate: Option<EstimateReport>,
}

impl PositionModel {
    pub fn new(bins: Vec<BinModel>) -> Self {
        Self { bins, estimate: None }
    }

    /// Whether the estimator made these bins (their weights probabilities × 2³⁰), rather than
    /// plain histograms (a `--plain` pack, or one older than the estimator).
    pub fn is_estimated(&self) -> bool {
        self.estimate.as_ref().is_some_and(|e| e.choice != crate::model::estimate_report::Choice::Plain)
    }
}

/// The noise PMF of one (ISO, position, bin): weights over `first ..` (counts for a plain
/// histogram; for estimated bins, probabilities scaled to a fixed total).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct BinModel {
    pub first: i32,
    pub counts: Vec<u64>,
    /// Real samples measured in this bin.
    pub samples: u64,
    pub source: BinSource,
    /// Mean and variance of the bin's own samples, when it has any, with the clean image's
    /// selection undone (the calibration's deselection; the same as measured where the reference
    /// burst was long).
    pub measured: Option<[f64; 2]>,
    /// The bin's samples reach 0 or white: its measured moments are shrunk by clipping.
    pub clipped: bool,
    /// The cell width `k > 1` of the coarse grid whose re-expansion the weights are, where that
    /// is known (`counts == expand(cell_masses(counts, k), k)`, [`crate::model::coarse_grid`]):
    /// set by the pack decoder, which read the bin as cells of `k` DN, and by
    /// [`ModelPack::compacted`], which stored it so. 0 where not known (kept per DN, derived,
    /// deconvolved, built by hand): whoever changes `counts` leaves it 0. The sampler draws a
    /// bin with a step from its cells (`synth/sampler_cells.rs`) without re-expanding it to find
    /// the step. Not in the file's fields (the weights' stream codes the step with the bin) and
    /// not compared by `==`: it says what the weights are, nothing besides.
    #[serde(skip)]
    pub grid_step: u16,
}

impl PartialEq for BinModel {
    fn eq(&self, o: &Self) -> bool {
        let Self { first, counts, samples, source, measured, clipped, grid_step: _ } = self;
        (first, counts, samples, source, measured, clipped)
            == (&o.first, &o.counts, &o.samples, &o.source, &o.measured, &o.clipped)
    }
}

impl BinModel {
    /// True when the PMF does not stand on the bin's own samples.
    pub fn filled(&self) -> bool {
        self.source == BinSource::Filled
    }

    /// Weights from an estimated PMF (probabilities × 2³⁰, so packs are deterministic; kept as a
    /// pack file keeps them when the calibration finishes, [`ModelPack::compacted`]).
    pub fn estimated(p: &Pmf, samples: u64, source: BinSource, measured: Option<[f64; 2]>, clipped: bool) -> Self {
        const SCALE: f64 = (1u64 << 30) as f64;
        let mut b = Self::from_scaled(p, SCALE);
        b.samples = samples;
        b.source = source;
        b.measured = measured;
        b.clipped = clipped;
        b
    }

    fn from_scaled(p: &Pmf, scale: f64) -> Self {
        let counts: Vec<u64> = p.p.iter().map(|&x| (x * scale).round() as u64).collect();
        let lo = counts.iter().position(|&c| c > 0);
        let hi = counts.iter().rposition(|&c| c > 0);
        let (first, counts) = match (lo, hi) {
            (Some(lo), Some(hi)) => (p.first + lo as i32, counts[lo..=hi].to_vec()),
            _ => (p.first + p.p.len() as i32 / 2, vec![1]),
        };
        Self { first, counts, samples: 0, source: BinSource::Filled, measured: None, clipped: false, grid_step: 0 }
    }

    pub fn pmf(&self) -> Pmf {
        Pmf::from_weights(self.first, self.counts.iter().map(|&c| c as f64)).unwrap_or(Pmf { first: 0, p: vec![1.0] })
    }

    pub fn moments(&self) -> (f64, f64) {
        crate::model::histogram::moments(self.first, self.counts.iter().map(|&c| c as f64))
    }

    /// `self.pmf().quantile(u)` without building the PMF (the same arithmetic on the counts).
    pub fn quantile(&self, u: f64) -> f64 {
        let t: f64 = self.counts.iter().map(|&c| c as f64).sum();
        let Some(last) = self.counts.iter().rposition(|&c| c > 0).filter(|_| t > 0.0) else {
            return self.pmf().quantile(u);
        };
        let mut acc = 0.0;
        for (i, &c) in self.counts.iter().enumerate() {
            let p = c as f64 / t;
            if acc + p >= u && p > 0.0 {
                let frac = ((u - acc) / p).clamp(0.0, 1.0);
                return self.first as f64 + i as f64 - 0.5 + frac;
            }
            acc += p;
        }
        self.first as f64 + last as f64 + 0.5
    }

    /// Weights from a derived PMF (interpolated or parametric), with a fixed total so such bins
    /// serialise deterministically, in the form a pack file stores them
    /// ([`crate::model::precision::quantize_derived`]: a model derived on the fly is the one a
    /// pack that stores it loads back). `filled` marks a PMF that stands on no measured bin.
    pub fn from_pmf(p: &Pmf, samples: u64, filled: bool) -> Self {
        const SCALE: f64 = (1u64 << 24) as f64;
        let counts: Vec<u64> =
            p.p.iter().map(|&x| crate::model::precision::quantize_derived((x * SCALE).round() as u64)).collect();
        let mut b = BinModel {
            first: p.first,
            counts,
            samples,
            source: if filled { BinSource::Filled } else { BinSource::Pooled },
            measured: None,
            clipped: false,
            grid_step: 0,
        };
        if b.counts.iter().all(|&c| c == 0) {
            b.counts = vec![1];
            b.first = p.first + p.p.len() as i32 / 2;
        }
        b
    }

    /// A bin that is exactly a measured histogram.
    pub fn from_histogram(h: &crate::model::histogram::NoiseHistogram) -> Self {
        let t = h.trimmed();
        let samples = t.total();
        let (m, v) = t.moments();
        if samples == 0 {
            return Self {
                first: 0,
                counts: vec![1],
                samples: 0,
                source: BinSource::Filled,
                measured: None,
                clipped: false,
                grid_step: 0,
            };
        }
        Self {
            first: t.first,
            counts: t.counts,
            samples,
            source: BinSource::Measured,
            measured: Some([m, v]),
            clipped: false,
            grid_step: 0,
        }
    }
}

impl IsoModel {
    pub fn is_calibrated(&self) -> bool {
        matches!(self.origin, ModelOrigin::Calibrated)
    }

    /// Total real samples per position.
    pub fn samples(&self, pos: usize) -> u64 {
        self.positions[pos].bins.iter().map(|b| b.samples).sum()
    }

    /// Bins filled from neighbours, per position.
    pub fn filled_bins(&self, pos: usize) -> usize {
        self.positions[pos].bins.iter().filter(|b| b.filled()).count()
    }

    /// Bins whose PMF pools neighbouring bins with their own samples, per position.
    pub fn pooled_bins(&self, pos: usize) -> usize {
        self.positions[pos].bins.iter().filter(|b| b.source == BinSource::Pooled).count()
    }
}

impl ModelPack {
    pub fn binning(&self) -> Binning {
        Binning::new(&self.layout, self.bin_width)
    }

    pub fn iso_list(&self) -> Vec<u32> {
        self.isos.iter().map(|m| m.iso).collect()
    }

    /// The pack's own fields (sensor layout, names, bins, warnings) without its ISOs and their
    /// structured components; nothing of those is copied.
    pub fn fields_only(&self) -> ModelPack {
        ModelPack {
            layout: self.layout.clone(),
            make: self.make.clone(),
            model: self.model.clone(),
            bin_width: self.bin_width,
            reference_iso: self.reference_iso,
            pooling: self.pooling,
            isos: Vec::new(),
            warnings: self.warnings.clone(),
            structure: Vec::new(),
        }
    }

    pub fn calibrated_isos(&self) -> Vec<u32> {
        self.isos.iter().filter(|m| m.is_calibrated()).map(|m| m.iso).collect()
    }

    /// The model of exactly this ISO.
    pub fn iso(&self, iso: u32) -> Option<&IsoModel> {
        self.isos.iter().find(|m| m.iso == iso)
    }

    /// The model of this ISO or a clear error that lists what the pack holds.
    pub fn require_iso(&self, iso: u32) -> Result<&IsoModel, ModelError> {
        self.iso(iso).ok_or_else(|| ModelError::IsoMissing { iso, available: self.iso_summary() })
    }

    pub fn iso_summary(&self) -> String {
        self.isos.iter().map(|m| m.iso.to_string()).collect::<Vec<_>>().join(", ")
    }

    /// The structured components stored for exactly this ISO.
    pub fn structure_of(&self, iso: u32) -> Option<&IsoStructure> {
        self.structure.iter().find(|s| s.iso == iso)
    }

    /// Inserts or replaces an ISO's structured components, keeping the list sorted.
    pub fn insert_structure(&mut self, s: IsoStructure) {
        self.structure.retain(|x| x.iso != s.iso);
        let at = self.structure.partition_point(|x| x.iso < s.iso);
        self.structure.insert(at, s);
    }

    /// Inserts or replaces an ISO model, keeping the list sorted.
    pub fn insert(&mut self, m: IsoModel) {
        self.isos.retain(|x| x.iso != m.iso);
        let at = self.isos.partition_point(|x| x.iso < m.iso);
        self.isos.insert(at, m);
    }

    /// Structural checks a decoder cannot make.
    pub fn check(&self) -> Result<(), CodecError> {
        let bad = |detail: String| CodecError::Invalid { what: "model pack", detail };
        self.layout.validate().map_err(|e| bad(e.to_string()))?;
        if self.bin_width == 0 {
            return Err(bad("bin width is 0".into()));
        }
        let binning = self.binning();
        for w in self.isos.windows(2) {
            if w[0].iso >= w[1].iso {
                return Err(bad(format!("ISOs are not sorted and unique ({} then {})", w[0].iso, w[1].iso)));
            }
        }
        if self.layout.width > MAX_SIDE || self.layout.height > MAX_SIDE {
            return Err(bad(format!(
                "the sensor is {}×{}, beyond {MAX_SIDE} pixels a side",
                self.layout.width, self.layout.height
            )));
        }
        for w in self.structure.windows(2) {
            if w[0].iso >= w[1].iso {
                return Err(bad(format!(
                    "structured components are not sorted by ISO ({} then {})",
                    w[0].iso, w[1].iso
                )));
            }
        }
        for st in &self.structure {
            if self.iso(st.iso).is_none() {
                return Err(bad(format!("structured components for ISO {}, which the pack has no model of", st.iso)));
            }
            if let Some(p) = st.problem() {
                return Err(bad(format!("ISO {} {p}", st.iso)));
            }
        }
        for m in &self.isos {
            if m.iso == 0 {
                return Err(bad("a model has ISO 0".into()));
            }
            if let Some((pos, g)) = m.gain_ratio.iter().enumerate().find(|(_, g)| !(g.is_finite() && **g > 0.0)) {
                return Err(bad(format!("ISO {} position {pos} has gain ratio {g}", m.iso)));
            }
            if let Some(p) = m.noise_profile.as_ref().and_then(NoiseProfile::problem) {
                return Err(bad(format!("ISO {} NoiseProfile: {p}", m.iso)));
            }
            if m.positions.len() != POSITIONS {
                return Err(bad(format!("ISO {} has {} CFA positions, expected 4", m.iso, m.positions.len())));
            }
            for (pos, pm) in m.positions.iter().enumerate() {
                if pm.bins.len() != binning.bins(pos) {
                    return Err(bad(format!(
                        "ISO {} position {pos} has {} bins, the layout needs {}",
                        m.iso,
                        pm.bins.len(),
                        binning.bins(pos)
                    )));
                }
                let [f, c] = m.range[pos];
                if f >= c || c > self.layout.white {
                    return Err(bad(format!(
                        "ISO {} position {pos} writes codes {f}..={c}, outside 0..={} or empty",
                        m.iso, self.layout.white
                    )));
                }
                if m.lattice[pos].is_some_and(|l| !l.is_valid()) {
                    return Err(bad(format!("ISO {} position {pos} has an impossible code lattice", m.iso)));
                }
                if let Some((b, _)) = pm.bins.iter().enumerate().find(|(_, b)| b.counts.iter().all(|&c| c == 0)) {
                    return Err(bad(format!("ISO {} position {pos} bin {b} has an empty PMF", m.iso)));
                }
            }
        }
        Ok(())
    }
}

impl ModelPack {
    /// The pack as a file of the current version stores it ([`crate::model::precision`],
    /// [`crate::model::coarse_grid`]): what loading its file gives. Idempotent: a bin already in
    /// its stored form at a coarse step is left as it is.
    pub fn compacted(&self) -> ModelPack {
        use crate::model::coarse_grid::{choose_step, store_coarse, stored_form};
        let mut p = self.clone();
        for m in p.isos.iter_mut() {
            let calibrated = m.is_calibrated();
            for (pos, q) in m.positions.iter_mut().enumerate() {
                let estimated = q.is_estimated();
                // A sensor that writes only some codes has a PMF of spikes: kept per DN.
                let may_coarsen = estimated && m.lattice[pos].is_none();
                for b in q.bins.iter_mut() {
                    // The weights change below, or are found stored at a known step.
                    b.grid_step = 0;
                    if calibrated {
                        let precision = crate::model::precision::bin_precision(estimated, b.samples);
                        if let Some(k) = stored_form(&b.counts, precision).filter(|_| may_coarsen) {
                            b.grid_step = if k > 1 { k as u16 } else { 0 };
                            continue;
                        }
                        let k = if may_coarsen { choose_step(&b.counts, b.samples, precision) } else { 1 };
                        if k > 1 {
                            store_coarse(&mut b.first, &mut b.counts, k, precision);
                            b.grid_step = k as u16;
                        } else {
                            crate::model::precision::store_bin(&mut b.first, &mut b.counts, precision);
                        }
                    } else {
                        b.counts.iter_mut().for_each(|w| *w = crate::model::precision::quantize_derived(*w));
                    }
                }
            }
        }
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `BinModel::quantile` gives exactly `pmf().quantile`, zeros at either end and inside, and
    /// an all-zero bin, included.
    #[test]
    fn bin_quantile_is_the_pmfs() {
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = move || {
            state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = state;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            z ^ (z >> 31)
        };
        let mut cases: Vec<Vec<u64>> = vec![vec![0, 0, 0], vec![0, 5, 0], vec![7], vec![0, 0, 3, 0, 1, 0, 0]];
        for _ in 0..200 {
            let n = 1 + (next() % 40) as usize;
            cases.push((0..n).map(|_| if next() % 3 == 0 { 0 } else { next() % 1_000_000 }).collect());
        }
        for counts in cases {
            let b = BinModel {
                first: -(counts.len() as i32) / 2,
                counts,
                samples: 1,
                source: BinSource::Measured,
                measured: None,
                clipped: false,
                grid_step: 0,
            };
            for u in [0.0, 1e-3, 0.25, 0.5, 0.999, 1.0] {
                assert_eq!(b.quantile(u).to_bits(), b.pmf().quantile(u).to_bits(), "{:?} at {u}", b.counts);
            }
        }
    }
}
