//! The calibration session: frames in, one at a time, histograms out (method.md, Calibration).
//!
//! Per EV step, the reference burst (at the reference ISO) is summed per pixel; when its first
//! target frame arrives, the burst's mean becomes the clean image of the step and its flat mask is
//! computed; every target frame of the step then adds, for each flat pixel, one integer sample
//! `n = noisy − round(I)` to the histogram of (ISO, position, bin). Memory is O(pixels) +
//! O(histograms) whatever the number of frames. A rejected frame changes nothing.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::codec;
use crate::drift::{DriftTracker, DriftVerdict, FrameBrightness, brightness_from_bands};
use crate::error::{CodecError, SessionError};
use crate::estimate::{BinLevels, FOLDS, Pooling, estimate_position};
use crate::flat::{CleanInputs, FlatReport, GROUPS, Groups, NOT_FLAT, Roi, TemporalStats, clean_and_mask};
use crate::frame::FrameView;
use crate::histogram::NoiseHistogram;
use crate::layout::{Binning, POSITIONS, SensorLayout};
use crate::meta::FrameMeta;
use crate::pack::{IsoModel, ModelOrigin, ModelPack, PositionModel};

pub const CHECKPOINT_MAGIC: &[u8; 8] = b"NCALCKPT";
pub const CHECKPOINT_VERSION: u16 = 2;
/// Row bands used to measure a frame's brightness and its standard error.
const BANDS: usize = 16;

/// How a session calibrates.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SessionConfig {
    /// The lowest ISO of the session (the sensor's minimum sensitivity).
    pub reference_iso: u32,
    pub make: String,
    pub model: String,
    /// Levels per bin; `None` picks the default for the sensor's bit depth.
    pub bin_width: Option<u16>,
    /// Pool each bin with neighbours until it holds this many samples; `None` chooses the
    /// pooling per ISO and position by cross-validation (the default; [`crate::estimate`]).
    pub pooling: Option<u64>,
    /// Build the plain per-bin histograms instead (for comparisons; overrides `pooling`).
    pub plain: bool,
    /// Only pixels inside this rectangle are used.
    pub roi: Option<Roi>,
    /// Flat-test threshold in standard deviations of a neighbour difference.
    pub flat_k: f64,
    /// Normalise the gain of frames whose brightness drifted (flicker) before using them.
    pub normalise_drift: bool,
    /// Drift threshold in standard errors of a frame's brightness.
    pub drift_z: f64,
    /// Drift threshold floor (relative).
    pub drift_floor: f64,
    /// Largest brightness departure from its burst that is normalised as flicker (relative); a
    /// frame further off is refused: it belongs to another setting, or the light changed.
    pub max_drift: f64,
    /// A target frame's ISO × exposure must match its step's within this relative tolerance.
    pub step_tolerance: f64,
}

/// A target frame's ISO × exposure may differ from its EV step's by this much (relative): the
/// rounding devices show in reported ISO and exposure, well below the 1 % that separates the
/// settings of a dense sweep from their neighbours' brightness by more than flicker does.
pub const STEP_TOLERANCE: f64 = 0.03;

/// Largest brightness departure of a frame from its burst that is treated as flicker.
pub const MAX_DRIFT: f64 = 0.05;

/// Bins with fewer samples than this are reported as under-sampled in [`Progress`] (a hint for
/// the capture UI; the estimator decides pooling from the data, not from this count).
pub const WELL_SAMPLED: u64 = 1000;

impl SessionConfig {
    pub fn new(reference_iso: u32) -> Self {
        Self {
            reference_iso,
            make: String::new(),
            model: String::new(),
            bin_width: None,
            pooling: None,
            plain: false,
            roi: None,
            flat_k: 4.5,
            normalise_drift: true,
            drift_z: 5.0,
            drift_floor: 0.002,
            max_drift: MAX_DRIFT,
            step_tolerance: STEP_TOLERANCE,
        }
    }
}

/// Per-ISO accumulation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct IsoAccumulator {
    /// `folds[k][pos][bin]`: target frame `i` of this ISO goes to fold `i mod FOLDS`.
    folds: Vec<Vec<Vec<NoiseHistogram>>>,
    frames: u64,
    samples: u64,
    drift_frames: u64,
    /// `shift[k][pos][bin]`: `[Σδ, Σδ², Σa]` of the selection over the samples of fold `k`.
    shift: Vec<Vec<Vec<[f64; 3]>>>,
    /// How often each output code (0 ..= white) occurs in the target frames, per position: the
    /// codes a sensor never writes ([`crate::lattice`]).
    codes: Vec<Vec<u64>>,
    /// Σ(target − black) and Σ(clean − black) over flat, unclipped pixels, per position.
    target_sum: [f64; POSITIONS],
    reference_sum: [f64; POSITIONS],
}

impl IsoAccumulator {
    fn new(binning: &Binning) -> Self {
        Self {
            shift: (0..FOLDS).map(|_| (0..POSITIONS).map(|p| vec![[0.0; 3]; binning.bins(p)]).collect()).collect(),
            codes: vec![vec![0; binning.white as usize + 1]; POSITIONS],
            folds: (0..FOLDS)
                .map(|_| (0..POSITIONS).map(|p| vec![NoiseHistogram::default(); binning.bins(p)]).collect())
                .collect(),
            frames: 0,
            samples: 0,
            drift_frames: 0,
            target_sum: [0.0; POSITIONS],
            reference_sum: [0.0; POSITIONS],
        }
    }
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct ReferenceBurst {
    frames: u32,
    sum: Vec<u32>,
    first: Vec<u16>,
    temporal: TemporalStats,
    drift: DriftTracker,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct TargetPhase {
    clean: Vec<u16>,
    /// Per position and bin, `[Σδ, Σδ², Σa]` of the clean image's selection over the flat pixels
    /// ([`crate::deselect::bin_sums`]): what one target frame adds to [`IsoAccumulator::shift`].
    shift: [Vec<[f64; 3]>; POSITIONS],
    reference_frames: u32,
    flat: FlatReport,
    drift: BTreeMap<u32, DriftTracker>,
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
enum Phase {
    Reference(ReferenceBurst),
    Targets(Box<TargetPhase>),
}

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct Step {
    index: u32,
    reference_exposure_ns: u64,
    phase: Phase,
}

/// What happened to an accepted frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameReport {
    pub kind: FrameKind,
    /// Relative brightness departure from the burst and whether it was judged a drift.
    pub departure: f64,
    pub drift_normalised: bool,
    /// Samples added (target frames).
    pub samples: u64,
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameKind {
    Reference,
    Target,
}

/// Progress of one ISO.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct IsoProgress {
    pub iso: u32,
    pub frames: u64,
    pub samples: u64,
    /// Bins (over all positions) with fewer than [`WELL_SAMPLED`] samples.
    pub under_sampled_bins: usize,
    pub total_bins: usize,
}

/// Progress of a session.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Progress {
    pub frames_accepted: u64,
    pub frames_rejected: u64,
    pub steps: u32,
    pub reference_frames: u64,
    pub drift_frames: u64,
    pub isos: Vec<IsoProgress>,
}

/// An incremental calibration session. See the module docs.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CalibrationSession {
    layout: SensorLayout,
    config: SessionConfig,
    binning: Binning,
    step: Option<Step>,
    steps: u32,
    isos: BTreeMap<u32, IsoAccumulator>,
    accepted: u64,
    rejected: u64,
    reference_frames: u64,
    drift_frames: u64,
    events: Vec<String>,
    noise_profiles: BTreeMap<u32, [[f64; 2]; POSITIONS]>,
}

/// How raw values of a frame map to the session's black level and brightness.
#[derive(Debug, Clone, Copy)]
struct Transform {
    /// Frame black − layout black, per position.
    delta: [f32; POSITIONS],
    black: [f32; POSITIONS],
    scale: f32,
}

impl Transform {
    fn identity(&self) -> bool {
        self.scale == 1.0 && self.delta.iter().all(|&d| d == 0.0)
    }

    #[inline]
    fn apply(&self, pos: usize, x: u16) -> f32 {
        self.black[pos] + (x as f32 - self.black[pos] - self.delta[pos]) * self.scale
    }
}

impl CalibrationSession {
    pub fn new(layout: SensorLayout, config: SessionConfig) -> Result<Self, SessionError> {
        layout.validate()?;
        if config.reference_iso == 0 {
            return Err(SessionError::Metadata("reference ISO is 0; pass the sensor's minimum sensitivity".into()));
        }
        let bin_width = config.bin_width.unwrap_or_else(|| layout.default_bin_width());
        let binning = Binning::new(&layout, bin_width);
        Ok(Self {
            layout,
            config,
            binning,
            step: None,
            steps: 0,
            isos: BTreeMap::new(),
            accepted: 0,
            rejected: 0,
            reference_frames: 0,
            drift_frames: 0,
            events: Vec::new(),
            noise_profiles: BTreeMap::new(),
        })
    }

    pub fn layout(&self) -> &SensorLayout {
        &self.layout
    }

    pub fn config(&self) -> &SessionConfig {
        &self.config
    }

    pub fn binning(&self) -> &Binning {
        &self.binning
    }

    /// Warnings and notable events so far.
    pub fn events(&self) -> &[String] {
        &self.events
    }

    /// Records the camera's own noise profile for an ISO (a free baseline).
    pub fn set_noise_profile(&mut self, iso: u32, profile: [[f64; 2]; POSITIONS]) {
        self.noise_profiles.insert(iso, profile);
    }

    /// Begins an EV step whose reference burst has this exposure. A step still in its
    /// reference phase is discarded.
    pub fn begin_step(&mut self, reference_exposure_ns: u64) -> Result<(), SessionError> {
        if reference_exposure_ns == 0 {
            return Err(SessionError::Metadata("reference exposure is 0 ns".into()));
        }
        let n = self.layout.pixels();
        self.step = Some(Step {
            index: self.steps,
            reference_exposure_ns,
            phase: Phase::Reference(ReferenceBurst {
                frames: 0,
                sum: vec![0; n],
                first: vec![0; n],
                temporal: TemporalStats::default(),
                drift: DriftTracker::default(),
            }),
        });
        self.steps += 1;
        Ok(())
    }

    /// Folds one frame in. On error the session is unchanged (apart from the rejected count).
    pub fn push_frame(&mut self, frame: &FrameView<'_>, meta: &FrameMeta) -> Result<FrameReport, SessionError> {
        match self.push_inner(frame, meta) {
            Ok(r) => {
                self.accepted += 1;
                Ok(r)
            }
            Err(e) => {
                self.rejected += 1;
                Err(e)
            }
        }
    }

    fn push_inner(&mut self, frame: &FrameView<'_>, meta: &FrameMeta) -> Result<FrameReport, SessionError> {
        frame.expect_size(self.layout.width as usize, self.layout.height as usize)?;
        meta.validate(&self.layout)?;
        let reference = self.config.reference_iso;
        if meta.iso < reference {
            return Err(SessionError::BelowReference { iso: meta.iso, reference });
        }
        let step = self.step.as_ref().ok_or(SessionError::NoStep)?;
        let ref_exposure = step.reference_exposure_ns;
        let in_reference = matches!(step.phase, Phase::Reference(_));
        let expected = reference as f64 * ref_exposure as f64 * 1e-9;
        let exposure_off = (meta.exposure_ns as f64 / ref_exposure as f64 - 1.0).abs();
        if in_reference && meta.iso == reference {
            if exposure_off > 0.02 {
                return Err(SessionError::ReferenceExposure {
                    exposure_ns: meta.exposure_ns,
                    expected_ns: ref_exposure,
                });
            }
            return self.push_reference(frame, meta);
        }
        let got = meta.brightness();
        let off = (got / expected - 1.0).abs();
        if off > self.config.step_tolerance {
            return Err(SessionError::WrongStep {
                iso: meta.iso,
                exposure_ns: meta.exposure_ns,
                got,
                expected,
                off_pct: off * 100.0,
            });
        }
        if in_reference {
            if matches!(&step.phase, Phase::Reference(b) if b.frames == 0) {
                return Err(SessionError::NoReference { iso: meta.iso, exposure_ns: meta.exposure_ns, reference });
            }
            self.close_reference()?;
        }
        self.push_target(frame, meta)
    }

    fn transform(&self, meta: &FrameMeta, scale: f64) -> Transform {
        let fb = meta.black_or(&self.layout);
        Transform {
            delta: std::array::from_fn(|p| fb[p] - self.layout.black[p]),
            black: self.layout.black,
            scale: scale as f32,
        }
    }

    fn push_reference(&mut self, frame: &FrameView<'_>, meta: &FrameMeta) -> Result<FrameReport, SessionError> {
        let (w, h) = (self.layout.width as usize, self.layout.height as usize);
        let white = self.layout.white;
        let groups = Groups { black: self.layout.black, white };
        let clip = clip_level(&self.layout);
        let cfg_drift = (self.config.drift_z, self.config.drift_floor, self.config.normalise_drift);
        let max_drift = self.config.max_drift;
        let ident = self.transform(meta, 1.0);
        let Some(Step { phase: Phase::Reference(burst), .. }) = self.step.as_mut() else {
            return Err(SessionError::NoStep);
        };
        if burst.frames >= 60_000 {
            return Err(SessionError::Metadata("reference burst exceeds 60000 frames".into()));
        }
        // Brightness against the burst's first frame.
        let mut verdict = DriftVerdict { departure: 0.0, drifted: false, scale: 1.0 };
        let fb = if burst.frames > 0 {
            let sums = brightness_sums(frame, &burst.first, &ident, clip, w, h);
            brightness_from_bands(&sums.frame_bands, &sums.base_bands)
        } else {
            Some(FrameBrightness { ratio: 1.0, sigma: 0.0 })
        };
        if let Some(fb) = fb {
            verdict = burst.drift.judge(fb, cfg_drift.0, cfg_drift.1);
            if verdict.drifted && verdict.departure.abs() > max_drift {
                return Err(SessionError::Drift {
                    kind: "reference",
                    iso: meta.iso,
                    exposure_ns: meta.exposure_ns,
                    departure_pct: verdict.departure * 100.0,
                    max_pct: max_drift * 100.0,
                });
            }
            burst.drift.record(fb);
        }
        let scale = if verdict.drifted && cfg_drift.2 { verdict.scale } else { 1.0 };
        let tf = Transform { scale: scale as f32, ..ident };
        let first_frame = burst.frames == 0;
        let stats_rows = if h > 512 { 4 } else { 1 };
        let ReferenceBurst { sum, first, temporal, .. } = burst;
        let mut rows: [Vec<RowPair<'_>>; 2] = [Vec::new(), Vec::new()];
        for (y, (s, f)) in sum.chunks_mut(w).zip(first.chunks_mut(w)).enumerate() {
            rows[y & 1].push((y, s, f));
        }
        let [even_rows, odd_rows] = rows;
        let work = |rows: Vec<RowPair<'_>>| {
            let mut acc = vec![[0.0f64; 3]; POSITIONS * GROUPS];
            let mut row_buf = vec![0u16; w];
            for (y, sum_row, first_row) in rows {
                frame.read_row(y, &mut row_buf);
                let take_stats = (y / 2) % stats_rows == 0;
                for x in 0..w {
                    let pos = ((y & 1) << 1) | (x & 1);
                    let v = if tf.identity() {
                        row_buf[x] as u32
                    } else {
                        tf.apply(pos, row_buf[x]).round().clamp(0.0, white as f32) as u32
                    };
                    sum_row[x] += v;
                    if first_frame {
                        first_row[x] = v as u16;
                    } else if take_stats {
                        let f0 = first_row[x];
                        let d = v as f64 - f0 as f64;
                        let a = &mut acc[pos * GROUPS + groups.group(pos, f0 as f32)];
                        a[0] += 1.0;
                        a[1] += d;
                        a[2] += d * d;
                    }
                }
            }
            acc
        };
        let acc_parts = {
            let (a, b) = rayon::join(|| work(even_rows), || work(odd_rows));
            [a, b]
        };
        for part in &acc_parts {
            for (t, a) in temporal.acc.iter_mut().zip(part) {
                for k in 0..3 {
                    t[k] += a[k];
                }
            }
        }
        burst.frames += 1;
        self.reference_frames += 1;
        if verdict.drifted {
            self.drift_frames += 1;
            self.note(format!(
                "reference frame at ISO {} exposure {} ns: brightness off its burst by {:+.2} %{}",
                meta.iso,
                meta.exposure_ns,
                verdict.departure * 100.0,
                if scale != 1.0 { ", normalised" } else { "" }
            ));
        }
        Ok(FrameReport {
            kind: FrameKind::Reference,
            departure: verdict.departure,
            drift_normalised: scale != 1.0,
            samples: 0,
        })
    }

    /// Ends the reference burst of the current step: clean image and flat mask.
    fn close_reference(&mut self) -> Result<(), SessionError> {
        let (w, h) = (self.layout.width as usize, self.layout.height as usize);
        let Some(step) = self.step.as_ref() else {
            return Err(SessionError::NoStep);
        };
        let Phase::Reference(burst) = &step.phase else {
            return Ok(());
        };
        if burst.frames == 0 {
            return Err(SessionError::NoReference {
                iso: 0,
                exposure_ns: step.reference_exposure_ns,
                reference: self.config.reference_iso,
            });
        }
        let (clean, flat) = clean_and_mask(&CleanInputs {
            sum: &burst.sum,
            frames: burst.frames,
            width: w,
            height: h,
            black: self.layout.black,
            white: self.layout.white,
            temporal: &burst.temporal,
            roi: self.config.roi,
            k: self.config.flat_k,
        });
        if flat.total_flat() == 0 {
            return Err(SessionError::NoFlatPixels);
        }
        let luts: [Vec<u16>; POSITIONS] = std::array::from_fn(|p| self.binning.lut(p));
        let groups = Groups { black: self.layout.black, white: self.layout.white };
        let shift = crate::deselect::bin_sums(&clean, w, NOT_FLAT, |pos, c| flat.mean_noise_at(&groups, pos, c), &luts);
        let frames = burst.frames;
        let index = step.index;
        let considered: u64 = flat.considered.iter().sum();
        self.note(format!(
            "EV step {index}: reference burst of {frames} frames, {:.1} % of pixels flat",
            100.0 * flat.total_flat() as f64 / considered.max(1) as f64
        ));
        if let Some(step) = self.step.as_mut() {
            step.phase = Phase::Targets(Box::new(TargetPhase {
                clean,
                shift,
                reference_frames: frames,
                flat,
                drift: BTreeMap::new(),
            }));
        }
        Ok(())
    }

    fn push_target(&mut self, frame: &FrameView<'_>, meta: &FrameMeta) -> Result<FrameReport, SessionError> {
        let (w, h) = (self.layout.width as usize, self.layout.height as usize);
        let white = self.layout.white;
        let clip = clip_level(&self.layout);
        let ident = self.transform(meta, 1.0);
        let (z, floor, normalise) = (self.config.drift_z, self.config.drift_floor, self.config.normalise_drift);
        let max_drift = self.config.max_drift;
        let binning = self.binning.clone();
        let Some(Step { phase: Phase::Targets(tp), .. }) = self.step.as_mut() else {
            return Err(SessionError::NoStep);
        };
        let sums = brightness_sums(frame, &tp.clean, &ident, clip, w, h);
        let fb = brightness_from_bands(&sums.frame_bands, &sums.base_bands);
        let verdict = match fb {
            Some(fb) => {
                let tracker = tp.drift.entry(meta.iso).or_default();
                let v = tracker.judge(fb, z, floor);
                if v.drifted && v.departure.abs() > max_drift {
                    return Err(SessionError::Drift {
                        kind: "target",
                        iso: meta.iso,
                        exposure_ns: meta.exposure_ns,
                        departure_pct: v.departure * 100.0,
                        max_pct: max_drift * 100.0,
                    });
                }
                tracker.record(fb);
                v
            }
            None => DriftVerdict { departure: 0.0, drifted: false, scale: 1.0 },
        };
        let scale = if verdict.drifted && normalise { verdict.scale } else { 1.0 };
        let tf = Transform { scale: scale as f32, ..ident };
        let luts: [Vec<u16>; POSITIONS] = std::array::from_fn(|p| binning.lut(p));
        let acc = self.isos.entry(meta.iso).or_insert_with(|| IsoAccumulator::new(&binning));
        let clean = &tp.clean;
        let fold = (acc.frames % FOLDS as u64) as usize;
        for (sum, add) in acc.shift[fold].iter_mut().zip(&tp.shift) {
            for (s, a) in sum.iter_mut().zip(add) {
                for k in 0..3 {
                    s[k] += a[k];
                }
            }
        }
        let (even, odd) = acc.folds[fold].split_at_mut(2);
        let (codes_even, codes_odd) = acc.codes.split_at_mut(2);
        let (s0, s1) = rayon::join(
            || fold_rows(0, frame, clean, w, h, &luts, even, codes_even, &tf, white),
            || fold_rows(1, frame, clean, w, h, &luts, odd, codes_odd, &tf, white),
        );
        let samples = s0 + s1;
        // Brightness sums per position for the gain ratio (after normalisation).
        for p in 0..POSITIONS {
            acc.target_sum[p] += sums.frame_pos[p] * scale;
            acc.reference_sum[p] += sums.base_pos[p];
        }
        acc.frames += 1;
        acc.samples += samples;
        if verdict.drifted {
            acc.drift_frames += 1;
            self.drift_frames += 1;
            self.note(format!(
                "target frame at ISO {} exposure {} ns: brightness off its burst by {:+.2} %{}",
                meta.iso,
                meta.exposure_ns,
                verdict.departure * 100.0,
                if scale != 1.0 { ", normalised" } else { "" }
            ));
        }
        Ok(FrameReport {
            kind: FrameKind::Target,
            departure: verdict.departure,
            drift_normalised: scale != 1.0,
            samples,
        })
    }

    fn note(&mut self, s: String) {
        log::info!("{s}");
        if self.events.len() < 2000 {
            self.events.push(s);
        }
    }

    /// Ends the current step's reference burst now (normally the first target frame does it):
    /// computes the clean image and flat mask. Used by evaluation, which needs the clean image
    /// of held-out captures.
    pub fn close_reference_burst(&mut self) -> Result<(), SessionError> {
        self.close_reference()
    }

    /// The current step's clean image (row-major, `round(mean)` of the reference burst) with
    /// [`NOT_FLAT`] where a pixel is not on a flat region; `None` before the burst is closed.
    pub fn clean_image(&self) -> Option<&[u16]> {
        match &self.step {
            Some(Step { phase: Phase::Targets(tp), .. }) => Some(&tp.clean),
            _ => None,
        }
    }

    /// The current step's flat-test report; `None` before the burst is closed.
    pub fn flat_report(&self) -> Option<&FlatReport> {
        match &self.step {
            Some(Step { phase: Phase::Targets(tp), .. }) => Some(&tp.flat),
            _ => None,
        }
    }

    /// Frames, samples and under-sampled bins so far.
    pub fn progress(&self) -> Progress {
        let isos = self
            .isos
            .iter()
            .map(|(&iso, acc)| {
                let mut under = 0;
                let mut total = 0;
                for pos in 0..POSITIONS {
                    let bins = acc.folds[0][pos].len();
                    total += bins;
                    under += (0..bins)
                        .filter(|&b| acc.folds.iter().map(|f| f[pos][b].total()).sum::<u64>() < WELL_SAMPLED)
                        .count();
                }
                IsoProgress {
                    iso,
                    frames: acc.frames,
                    samples: acc.samples,
                    under_sampled_bins: under,
                    total_bins: total,
                }
            })
            .collect();
        Progress {
            frames_accepted: self.accepted,
            frames_rejected: self.rejected,
            steps: self.steps,
            reference_frames: self.reference_frames,
            drift_frames: self.drift_frames,
            isos,
        }
    }

    /// The session as bytes, to resume after an interruption.
    pub fn checkpoint(&self) -> Result<Vec<u8>, CodecError> {
        codec::encode("checkpoint", CHECKPOINT_MAGIC, CHECKPOINT_VERSION, self)
    }

    /// Resumes a session from [`checkpoint`](Self::checkpoint) bytes.
    pub fn restore(bytes: &[u8]) -> Result<Self, CodecError> {
        let s: Self = codec::decode("checkpoint", CHECKPOINT_MAGIC, "NCALCKPT", CHECKPOINT_VERSION, bytes)?;
        let bins: Vec<usize> = (0..POSITIONS).map(|p| s.binning.bins(p)).collect();
        let bad_acc = |a: &IsoAccumulator| {
            a.folds.len() != FOLDS
                || a.folds.iter().any(|f| f.len() != POSITIONS || f.iter().zip(&bins).any(|(h, &n)| h.len() != n))
        };
        let bad_codes = |a: &IsoAccumulator| {
            a.codes.len() != POSITIONS
                || a.codes.iter().any(|c| c.len() != s.layout.white as usize + 1)
                || a.shift.len() != FOLDS
                || a.shift.iter().any(|f| f.len() != POSITIONS || f.iter().zip(&bins).any(|(h, &n)| h.len() != n))
        };
        if s.layout.validate().is_err() || s.isos.values().any(|a| bad_acc(a) || bad_codes(a)) {
            return Err(CodecError::Invalid { what: "checkpoint", detail: "inconsistent session state".into() });
        }
        Ok(s)
    }

    /// The histograms of one ISO and position summed over folds (`None` for an ISO without
    /// target frames), e.g. for the plain empirical estimator.
    pub fn histograms(&self, iso: u32, pos: usize) -> Option<Vec<NoiseHistogram>> {
        let acc = self.isos.get(&iso)?;
        let mut out = acc.folds.first()?.get(pos)?.clone();
        for f in &acc.folds[1..] {
            for (o, h) in out.iter_mut().zip(&f[pos]) {
                o.merge(h);
            }
        }
        Some(out.iter().map(|h| h.trimmed()).collect())
    }

    /// Target ISOs with samples so far.
    pub fn target_isos(&self) -> Vec<u32> {
        self.isos.keys().copied().collect()
    }

    /// Builds the model pack from everything folded in so far: per ISO and position, the
    /// estimator of [`crate::estimate`] (pooling chosen by cross-validation over the folds unless
    /// the configuration fixes it), then the pack's self-check ([`crate::check`]).
    pub fn finish(&self) -> Result<ModelPack, SessionError> {
        use rayon::prelude::*;
        let mut warnings: Vec<String> = self.events.iter().filter(|e| e.contains("brightness")).cloned().collect();
        let pooling =
            if self.config.plain { Pooling::Plain } else { self.config.pooling.map_or(Pooling::Auto, Pooling::Fixed) };
        let levels: Vec<BinLevels> = (0..POSITIONS).map(|p| BinLevels::new(&self.binning, p)).collect();
        let jobs: Vec<(u32, usize)> = self.isos.keys().flat_map(|&iso| (0..POSITIONS).map(move |p| (iso, p))).collect();
        // Every (ISO, position) is estimated on its own: in parallel, collected in order.
        let estimates: Vec<_> = jobs
            .par_iter()
            .map(|&(iso, p)| {
                let acc = &self.isos[&iso];
                let folds: Vec<&[NoiseHistogram]> = acc.folds.iter().map(|f| f[p].as_slice()).collect();
                let shifts: Vec<&[[f64; 3]]> = acc.shift.iter().map(|f| f[p].as_slice()).collect();
                let empty = folds.iter().all(|f| f.iter().all(|h| h.total() == 0));
                let range = crate::lattice::output_range(&acc.codes[p], self.layout.white);
                let levels = levels[p].clone().with_range([range.floor, range.saturation]);
                (!empty).then(|| estimate_position(&folds, &shifts, &levels, pooling))
            })
            .collect();
        let mut isos = Vec::new();
        for (i, (&iso, acc)) in self.isos.iter().enumerate() {
            let mut positions = Vec::with_capacity(POSITIONS);
            let mut missing = None;
            for p in 0..POSITIONS {
                match &estimates[i * POSITIONS + p] {
                    Some(e) => positions.push(PositionModel { bins: e.bins.clone(), estimate: Some(e.report.clone()) }),
                    None => {
                        missing = Some(p);
                        break;
                    }
                }
            }
            if let Some(p) = missing {
                warnings.push(format!(
                    "ISO {iso}: no flat pixel at CFA position {p} ({}) gave a sample; the ISO is left out — capture more frames",
                    self.layout.cfa.position_name(p),
                ));
                continue;
            }
            let gain_ratio: [f64; POSITIONS] = std::array::from_fn(|p| {
                if acc.reference_sum[p] > 0.0 { acc.target_sum[p] / acc.reference_sum[p] } else { 1.0 }
            });
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
            isos.push(IsoModel {
                iso,
                origin: ModelOrigin::Calibrated,
                frames: acc.frames,
                drift_frames: acc.drift_frames,
                gain_ratio,
                noise_profile: self.noise_profiles.get(&iso).copied(),
                range: std::array::from_fn(|p| {
                    let r = crate::lattice::output_range(&acc.codes[p], self.layout.white);
                    [r.floor, r.ceiling]
                }),
                lattice: if self.config.plain {
                    [None; POSITIONS]
                } else {
                    std::array::from_fn(|p| crate::lattice::detect(&acc.codes[p], self.layout.white))
                },
                positions,
            });
        }
        if isos.is_empty() {
            return Err(SessionError::NothingCalibrated);
        }
        let mut pack = ModelPack {
            layout: self.layout.clone(),
            make: self.config.make.clone(),
            model: self.config.model.clone(),
            bin_width: self.binning.bin_width,
            reference_iso: self.config.reference_iso,
            pooling: self.config.pooling,
            isos,
            warnings,
        };
        let checks = crate::check::self_check(&pack);
        pack.warnings.extend(checks.into_iter().map(|c| c.to_string()));
        Ok(pack)
    }
}

/// A gain ratio further than this from 1 is reported prominently: more likely a capture problem
/// than a sensor property.
pub const FAR_GAIN_RATIO: f64 = 0.10;

/// One row of the reference sums and first frame, with its index.
type RowPair<'a> = (usize, &'a mut [u32], &'a mut [u16]);

/// Levels above this (90 % of the range) are left out of brightness ratios: clipping bends them.
fn clip_level(l: &SensorLayout) -> f32 {
    let b = l.black.iter().cloned().fold(f32::INFINITY, f32::min);
    b + 0.9 * (l.white as f32 - b)
}

/// Σ(frame − black) and Σ(base − black) over pixels where the base is flat and unclipped, per row
/// band (for a frame's brightness and its standard error) and per CFA position (for gain ratios),
/// in one pass over every fourth row pair of large frames.
struct BrightnessSums {
    frame_bands: Vec<f64>,
    base_bands: Vec<f64>,
    frame_pos: [f64; POSITIONS],
    base_pos: [f64; POSITIONS],
}

fn brightness_sums(
    frame: &FrameView<'_>,
    base: &[u16],
    tf: &Transform,
    clip: f32,
    w: usize,
    h: usize,
) -> BrightnessSums {
    let mut out = BrightnessSums {
        frame_bands: vec![0.0; BANDS],
        base_bands: vec![0.0; BANDS],
        frame_pos: [0.0; POSITIONS],
        base_pos: [0.0; POSITIONS],
    };
    let rows_per_band = h.div_ceil(BANDS).max(1);
    let step = if h > 512 { 4 } else { 1 };
    let mut buf = vec![0u16; w];
    for y in (0..h).step_by(2 * step).flat_map(|y| [y, y + 1]).filter(|&y| y < h) {
        frame.read_row(y, &mut buf);
        let band = (y / rows_per_band).min(BANDS - 1);
        let (mut f, mut b) = (0.0f64, 0.0f64);
        for x in 0..w {
            let c = base[y * w + x];
            if c == NOT_FLAT || c as f32 > clip {
                continue;
            }
            let pos = ((y & 1) << 1) | (x & 1);
            let fv = (tf.apply(pos, buf[x]) - tf.black[pos]) as f64;
            let bv = (c as f32 - tf.black[pos]) as f64;
            f += fv;
            b += bv;
            out.frame_pos[pos] += fv;
            out.base_pos[pos] += bv;
        }
        out.frame_bands[band] += f;
        out.base_bands[band] += b;
    }
    out
}

/// Folds the rows of one parity into that parity's two positions' histograms.
#[allow(clippy::too_many_arguments)]
fn fold_rows(
    parity: usize,
    frame: &FrameView<'_>,
    clean: &[u16],
    w: usize,
    h: usize,
    luts: &[Vec<u16>; POSITIONS],
    hists: &mut [Vec<NoiseHistogram>],
    codes: &mut [Vec<u64>],
    tf: &Transform,
    white: u16,
) -> u64 {
    let mut samples = 0u64;
    let mut buf = vec![0u16; w];
    let identity = tf.identity();
    let (h0, h1) = hists.split_at_mut(1);
    let (hist0, hist1) = (&mut h0[0], &mut h1[0]);
    let (c0, c1) = codes.split_at_mut(1);
    let (codes0, codes1) = (&mut c0[0][..], &mut c1[0][..]);
    let top = white as usize;
    let (lut0, lut1) = (&luts[parity * 2], &luts[parity * 2 + 1]);
    for y in (parity..h).step_by(2) {
        let row: &[u16] = match frame.row(y) {
            std::borrow::Cow::Borrowed(r) => r,
            std::borrow::Cow::Owned(v) => {
                buf.copy_from_slice(&v);
                &buf
            }
        };
        let crow = &clean[y * w..y * w + w];
        if identity {
            for (x, (&v, &c)) in row.iter().zip(crow).enumerate() {
                if c == NOT_FLAT {
                    continue;
                }
                let n = v as i32 - c as i32;
                if x & 1 == 0 {
                    hist0[lut0[c as usize] as usize].add(n);
                    codes0[(v as usize).min(top)] += 1;
                } else {
                    hist1[lut1[c as usize] as usize].add(n);
                    codes1[(v as usize).min(top)] += 1;
                }
                samples += 1;
            }
        } else {
            for (x, (&v, &c)) in row.iter().zip(crow).enumerate() {
                if c == NOT_FLAT {
                    continue;
                }
                let pos = parity * 2 + (x & 1);
                let t = tf.apply(pos, v).round().clamp(0.0, white as f32) as i32;
                let n = t - c as i32;
                if x & 1 == 0 {
                    hist0[lut0[c as usize] as usize].add(n);
                    codes0[(v as usize).min(top)] += 1;
                } else {
                    hist1[lut1[c as usize] as usize].add(n);
                    codes1[(v as usize).min(top)] += 1;
                }
                samples += 1;
            }
        }
    }
    samples
}
