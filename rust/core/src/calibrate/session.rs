//! The calibration session: frames in, one at a time, a pack out (method.md, "Calibration").
//!
//! Per EV step a [`ReferenceBurst`] sums the reference frames; the first target frame closes it
//! into the step's [`CleanImage`], and every target frame of the step is folded into its ISO's
//! samples ([`crate::calibrate::accumulate`]). The session checks what arrives (sizes,
//! metadata, steps, drift), keeps progress and events, and builds the pack
//! at the end ([`crate::calibrate::assemble`]). Memory is O(pixels) + O(histograms) whatever the
//! number of frames. A rejected frame changes nothing.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::calibrate::accumulate::IsoAccumulator;
use crate::calibrate::dark::{DarkBurst, ReferencePattern, check_dark};
use crate::calibrate::drift::{DriftPolicy, DriftTracker, DriftVerdict, Transform, brightness_sums, clip_level};
use crate::calibrate::flat::{FlatReport, Roi};
use crate::calibrate::frame::FrameView;
use crate::calibrate::meta::FrameMeta;
use crate::calibrate::motion::{FrameMotion, MAX_MOTION_PX, register};
use crate::calibrate::reference::{CleanImage, ReferenceBurst};
use crate::calibrate::step::{STEP_TOLERANCE, StepKey};
use crate::error::SessionError;
use crate::model::histogram::NoiseHistogram;
use crate::model::layout::{Binning, POSITIONS, SensorLayout};
use crate::model::pack::NoiseProfile;
use crate::model::structure::FixedPattern;

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
    /// pooling per ISO and position by cross-validation (the default; [`crate::calibrate::estimate`]).
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

/// Largest brightness departure of a frame from its burst that is treated as flicker.
pub const MAX_DRIFT: f64 = 0.05;

/// Bins with fewer samples than this are reported as under-sampled in [`Progress`] (a hint for
/// the capture UI; the estimator decides pooling from the data, not from this count).
pub const WELL_SAMPLED: u64 = 1000;

impl SessionConfig {
    /// How a burst's frames are judged for drift under this configuration: the one policy of a
    /// session's bursts and of a clean image summed outside a session (`noisecal-input`'s `clean`).
    pub fn drift_policy(&self) -> DriftPolicy {
        DriftPolicy { z: self.drift_z, floor: self.drift_floor, max: self.max_drift, normalise: self.normalise_drift }
    }

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

#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
struct TargetPhase {
    image: CleanImage,
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
    /// Flat samples left out of this frame because its motion changed their level (method.md,
    /// "Motion between frames").
    pub left_out: u64,
    /// A target frame's motion against its reference burst, when registered (method.md,
    /// "Motion between frames").
    pub motion: Option<FrameMotion>,
}

impl FrameReport {
    /// The frame's largest displacement against its reference burst (pixels), when registered.
    pub fn shift_px(&self) -> Option<f64> {
        self.motion.as_ref().map(FrameMotion::max_shift)
    }

    /// Whether this frame moved enough that its burst is worth taking again
    /// ([`RETAKE_MOTION_PX`](crate::calibrate::motion::RETAKE_MOTION_PX)): a sturdier mount, the
    /// optical stabilisation off, a remote trigger.
    pub fn retake(&self) -> bool {
        self.shift_px().is_some_and(|s| s > crate::calibrate::motion::RETAKE_MOTION_PX)
    }
}

#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameKind {
    Reference,
    Target,
    /// A dark (lens-covered) frame ([`CalibrationSession::begin_dark`]).
    Dark,
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
    pub(super) layout: SensorLayout,
    pub(super) config: SessionConfig,
    pub(super) binning: Binning,
    step: Option<Step>,
    steps: u32,
    pub(super) isos: BTreeMap<u32, IsoAccumulator>,
    accepted: u64,
    rejected: u64,
    reference_frames: u64,
    drift_frames: u64,
    pub(super) events: Vec<String>,
    pub(super) noise_profiles: BTreeMap<u32, NoiseProfile>,
    /// In a dark step ([`Self::begin_dark`]): the burst being summed (one ISO at a time).
    dark: Option<Option<DarkBurst>>,
    /// The fixed pattern of each ISO with dark frames.
    pub(super) patterns: BTreeMap<u32, FixedPattern>,
    /// The reference ISO's dark pattern, pixel by pixel (O(pixels)): the other ISOs' patterns
    /// are compared with it to know what their pixel PMFs hold.
    pub(super) reference_pattern: Option<ReferencePattern>,
    /// Per ISO with dark frames, the noise they measure in bin 0 per position
    /// ([`DarkBurst::black_noise`]), of the burst its pattern comes from.
    #[serde(default)]
    pub(super) black_noise: BTreeMap<u32, [NoiseHistogram; POSITIONS]>,
    dark_frames: u64,
}

impl CalibrationSession {
    pub fn new(layout: SensorLayout, config: SessionConfig) -> Result<Self, SessionError> {
        layout.validate()?;
        if config.reference_iso == 0 {
            return Err(SessionError::Metadata("reference ISO is 0; pass the sensor's minimum sensitivity".into()));
        }
        let bin_width = match config.bin_width {
            Some(w) => crate::model::bin_width::check(w)?,
            None => layout.default_bin_width(),
        };
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
            dark: None,
            patterns: BTreeMap::new(),
            reference_pattern: None,
            black_noise: BTreeMap::new(),
            dark_frames: 0,
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
    pub fn set_noise_profile(&mut self, iso: u32, profile: NoiseProfile) {
        self.noise_profiles.insert(iso, profile);
    }

    /// Begins an EV step whose reference burst has this exposure. A step still in its
    /// reference phase is discarded.
    pub fn begin_step(&mut self, reference_exposure_ns: u64) -> Result<(), SessionError> {
        if reference_exposure_ns == 0 {
            return Err(SessionError::Metadata("reference exposure is 0 ns".into()));
        }
        self.end_dark();
        self.step = Some(Step {
            index: self.steps,
            reference_exposure_ns,
            phase: Phase::Reference(ReferenceBurst::new(&self.layout, reference_exposure_ns)),
        });
        self.steps += 1;
        Ok(())
    }

    /// Begins a dark step: the lens is covered, and every frame until the next
    /// [`begin_step`](Self::begin_step) or `begin_dark` is a dark frame of the ISO its metadata
    /// reports (bursts of several ISOs one after the other; each frame is checked to be dark).
    /// Dark frames give each ISO its fixed pattern (method.md, "Fixed pattern"). The EV step in
    /// progress ends.
    pub fn begin_dark(&mut self) -> Result<(), SessionError> {
        self.end_dark();
        self.step = None;
        self.dark = Some(None);
        Ok(())
    }

    /// Closes the dark burst in progress into its ISO's pattern (a burst of more frames than one
    /// already measured at that ISO replaces it).
    fn end_dark(&mut self) {
        if let Some(Some(burst)) = self.dark.take() {
            self.close_dark(burst);
        }
    }

    fn close_dark(&mut self, burst: DarkBurst) {
        let (new_reference, pattern) = self.closed(&burst);
        if new_reference.is_some() {
            self.reference_pattern = new_reference;
        }
        let Some(fp) = pattern else {
            self.note(format!(
                "dark burst at ISO {} ({} frames) adds no fixed pattern: fewer than 2 frames, or fewer than one already measured at that ISO",
                burst.iso,
                burst.frames()
            ));
            return;
        };
        self.note(format!(
            "dark burst at ISO {}: {} frames, pattern SD {:.3} DN, temporal SD {:.3} DN",
            burst.iso,
            fp.frames,
            fp.sd(),
            (fp.temporal_var.iter().sum::<f64>() / POSITIONS as f64).sqrt()
        ));
        self.patterns.insert(burst.iso, fp);
        match burst.black_noise(&self.binning) {
            Some(h) => self.black_noise.insert(burst.iso, h),
            None => self.black_noise.remove(&burst.iso),
        };
    }

    /// What closing `burst` gives: the reference ISO's new pattern map (when the burst is the
    /// reference ISO's and the better one), and its ISO's pattern when it has more frames than
    /// the one already measured there (closing is skipped otherwise).
    pub(super) fn closed(&self, burst: &DarkBurst) -> (Option<ReferencePattern>, Option<FixedPattern>) {
        let better = self.patterns.get(&burst.iso).is_none_or(|old| old.frames < burst.frames());
        if !better {
            return (None, None);
        }
        let new_reference =
            if burst.iso == self.config.reference_iso { burst.pattern_map(&self.layout.black) } else { None };
        let reference = new_reference.as_ref().or(self.reference_pattern.as_ref());
        let pattern = burst.close(&self.layout.black, reference);
        (new_reference, pattern)
    }

    fn push_dark(&mut self, frame: &FrameView<'_>, meta: &FrameMeta) -> Result<FrameReport, SessionError> {
        let black = meta.black_or(&self.layout);
        check_dark(frame, &black, &self.layout, meta.iso)?;
        let open = match self.dark.as_mut() {
            Some(slot) => slot.as_ref().map(|b| b.iso),
            None => return Err(SessionError::NoStep),
        };
        if open.is_some_and(|iso| iso != meta.iso) {
            self.end_dark();
            self.dark = Some(None);
        }
        let layout = &self.layout;
        let slot = self.dark.as_mut().ok_or(SessionError::NoStep)?;
        let burst = slot.get_or_insert_with(|| DarkBurst::new(layout, meta.iso));
        burst.push(frame, &black)?;
        self.dark_frames += 1;
        Ok(FrameReport {
            kind: FrameKind::Dark,
            departure: 0.0,
            drift_normalised: false,
            samples: 0,
            left_out: 0,
            motion: None,
        })
    }

    /// The dark burst in progress.
    pub(super) fn open_dark(&self) -> Option<&DarkBurst> {
        self.dark.as_ref().and_then(Option::as_ref)
    }

    /// Dark frames accepted so far.
    pub fn dark_frames(&self) -> u64 {
        self.dark_frames
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
        if self.dark.is_some() {
            return self.push_dark(frame, meta);
        }
        let step = self.step.as_ref().ok_or(SessionError::NoStep)?;
        let key = StepKey::new(reference, step.reference_exposure_ns);
        let in_reference = matches!(step.phase, Phase::Reference(_));
        if in_reference && meta.iso == reference {
            if !key.admits_reference(meta) {
                return Err(SessionError::ReferenceExposure {
                    exposure_ns: meta.exposure_ns,
                    expected_ns: key.reference_exposure_ns,
                });
            }
            return self.push_reference(frame, meta);
        }
        if let Err(m) = key.check(meta, self.config.step_tolerance) {
            return Err(SessionError::WrongStep {
                iso: meta.iso,
                exposure_ns: meta.exposure_ns,
                got: m.got,
                expected: m.expected,
                off_pct: m.off * 100.0,
            });
        }
        if in_reference {
            if matches!(&step.phase, Phase::Reference(b) if b.frames() == 0) {
                return Err(SessionError::NoReference { iso: meta.iso, exposure_ns: meta.exposure_ns, reference });
            }
            self.close_reference()?;
        }
        self.push_target(frame, meta)
    }

    fn drift_policy(&self) -> DriftPolicy {
        self.config.drift_policy()
    }

    fn push_reference(&mut self, frame: &FrameView<'_>, meta: &FrameMeta) -> Result<FrameReport, SessionError> {
        let policy = self.drift_policy();
        let Some(Step { phase: Phase::Reference(burst), .. }) = self.step.as_mut() else {
            return Err(SessionError::NoStep);
        };
        let r = burst.push(frame, meta, &policy)?;
        self.reference_frames += 1;
        if r.verdict.drifted {
            self.drift_frames += 1;
            self.note(format!(
                "reference frame at ISO {} exposure {} ns: brightness off its burst by {:+.2} %{}",
                meta.iso,
                meta.exposure_ns,
                r.verdict.departure * 100.0,
                if r.normalised { ", normalised" } else { "" }
            ));
        }
        Ok(FrameReport {
            kind: FrameKind::Reference,
            departure: r.verdict.departure,
            drift_normalised: r.normalised,
            samples: 0,
            left_out: 0,
            motion: None,
        })
    }

    /// Ends the reference burst of the current step: clean image and flat mask.
    fn close_reference(&mut self) -> Result<(), SessionError> {
        let Some(step) = self.step.as_mut() else {
            return Err(SessionError::NoStep);
        };
        let Phase::Reference(burst) = &mut step.phase else {
            return Ok(());
        };
        if burst.frames() == 0 {
            return Err(SessionError::NoReference {
                iso: 0,
                exposure_ns: step.reference_exposure_ns,
                reference: self.config.reference_iso,
            });
        }
        // The burst is replaced by the image below: closing may take its buffers.
        let image = burst.close_spending(&self.binning, self.config.roi, self.config.flat_k)?;
        let (frames, index) = (image.frames, step.index);
        let considered: u64 = image.flat.considered.iter().sum();
        let unsteady: u64 = image.flat.unsteady.iter().sum();
        let half_code: u64 = image.flat.half_code.iter().sum();
        self.note(format!(
            "EV step {index}: reference burst of {frames} frames, {:.1} % of pixels flat{}{}",
            100.0 * image.flat.total_flat() as f64 / considered.max(1) as f64,
            left_out(unsteady, considered, "their spread over the burst is beyond the noise at their level"),
            left_out(
                half_code,
                considered,
                "sub-DN noise, their clean code most likely one off, at codes such pixels would bias"
            )
        ));
        if let Some(step) = self.step.as_mut() {
            step.phase = Phase::Targets(Box::new(TargetPhase { image, drift: BTreeMap::new() }));
        }
        Ok(())
    }

    fn push_target(&mut self, frame: &FrameView<'_>, meta: &FrameMeta) -> Result<FrameReport, SessionError> {
        let (w, h) = (self.layout.width as usize, self.layout.height as usize);
        let clip = clip_level(&self.layout);
        let ident = Transform::of(&self.layout, meta, 1.0);
        let policy = self.drift_policy();
        let Some(Step { index, phase: Phase::Targets(tp), .. }) = self.step.as_mut() else {
            return Err(SessionError::NoStep);
        };
        let step = *index;
        // Registered on the clean image while its brightness is measured: the registration fits
        // each position's gain, so a drift normalisation does not change the motion it finds.
        let (sums, motion) = rayon::join(
            || brightness_sums(frame, &tp.image.levels, &ident, clip, w, h),
            || register(&tp.image.probe, frame, &ident, w, h, clip, tp.image.frames),
        );
        let verdict = match sums.brightness() {
            Some(fb) => {
                let tracker = tp.drift.entry(meta.iso).or_default();
                let v = tracker.judge(fb, policy.z, policy.floor);
                if v.drifted && v.departure.abs() > policy.max {
                    return Err(SessionError::Drift {
                        kind: "target",
                        iso: meta.iso,
                        exposure_ns: meta.exposure_ns,
                        departure_pct: v.departure * 100.0,
                        max_pct: policy.max * 100.0,
                    });
                }
                tracker.record(fb);
                v
            }
            None => DriftVerdict { departure: 0.0, drifted: false, scale: 1.0 },
        };
        let scale = if verdict.drifted && policy.normalise { verdict.scale } else { 1.0 };
        let tf = Transform { scale: scale as f32, ..ident };
        // A frame that moved too far is refused, and the flat pixels its motion changes are left
        // out of it (method.md, "Motion between frames").
        if let Some(m) = &motion
            && m.max_shift() > MAX_MOTION_PX
        {
            return Err(SessionError::Moved {
                iso: meta.iso,
                exposure_ns: meta.exposure_ns,
                step,
                shift_px: m.max_shift(),
                max_px: MAX_MOTION_PX,
            });
        }
        let binning = &self.binning;
        let acc = self.isos.entry(meta.iso).or_insert_with(|| IsoAccumulator::new(binning));
        let (samples, left_out) = acc.add_frame(step, frame, &tp.image, binning, &tf, &sums, scale, motion.as_ref());
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
            left_out,
            motion,
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
    /// [`NOT_FLAT`](crate::calibrate::NOT_FLAT) where a pixel is not on a flat region; `None` before the burst is closed.
    pub fn clean_image(&self) -> Option<&[u16]> {
        match &self.step {
            Some(Step { phase: Phase::Targets(tp), .. }) => Some(&tp.image.levels),
            _ => None,
        }
    }

    /// The current step's flat-test report; `None` before the burst is closed.
    pub fn flat_report(&self) -> Option<&FlatReport> {
        match &self.step {
            Some(Step { phase: Phase::Targets(tp), .. }) => Some(&tp.image.flat),
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

    /// Whether a session read back from bytes holds together: a valid layout, and every ISO's
    /// histograms fitting the binning (a checkpoint's bytes may be damaged or foreign).
    pub(crate) fn is_consistent(&self) -> bool {
        self.layout.validate().is_ok() && self.isos.values().all(|a| a.fits(&self.binning))
    }

    /// The histograms of one ISO and position summed over folds (`None` for an ISO without
    /// target frames), e.g. for the plain empirical estimator.
    pub fn histograms(&self, iso: u32, pos: usize) -> Option<Vec<NoiseHistogram>> {
        self.isos.get(&iso)?.histograms(pos)
    }

    /// The current step's clean image, once its reference burst is closed.
    pub fn clean(&self) -> Option<&CleanImage> {
        match &self.step {
            Some(Step { phase: Phase::Targets(tp), .. }) => Some(&tp.image),
            _ => None,
        }
    }

    /// Target ISOs with samples so far.
    pub fn target_isos(&self) -> Vec<u32> {
        self.isos.keys().copied().collect()
    }
}

/// The note's clause for `count` of `considered` pixels left out for `why`; empty when none was.
fn left_out(count: u64, considered: u64, why: &str) -> String {
    if count == 0 {
        return String::new();
    }
    format!(" ({:.2} % left out: {why})", 100.0 * count as f64 / considered.max(1) as f64)
}
