//! Calibration from a DNG folder or a recording into a model pack: the CLI's options on top of
//! what the captures imply, and the one loop that feeds a session.

use std::collections::BTreeMap;
use std::io::{Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use noisecal_core::calibrate::SessionRecord;
use noisecal_core::calibrate::dark::{check_dark, frame_level, lit_by_level};
use noisecal_core::calibrate::flat::Roi;
use noisecal_core::error::CodecError;
use noisecal_core::format::recording;
use noisecal_core::{CalibrationSession, FrameMeta, FrameView, ModelPack, SensorLayout, SessionConfig};

use crate::dim_steps::{Dim, DimSteps, Held};
use crate::source::{InputKind, Record, Source};

/// Options a user can set on top of what the captures imply.
#[derive(Debug, Clone, Default)]
pub struct CalibrateOptions {
    pub reference_iso: Option<u32>,
    pub bin_width: Option<u16>,
    pub pooling: Option<u64>,
    pub plain: bool,
    pub roi: Option<Roi>,
    pub flat_k: Option<f64>,
    pub no_drift_normalise: bool,
}

impl CalibrateOptions {
    fn apply(&self, c: &mut SessionConfig) {
        if let Some(b) = self.bin_width {
            c.bin_width = Some(b);
        }
        if let Some(m) = self.pooling {
            c.pooling = Some(m);
        }
        c.plain = self.plain;
        if self.roi.is_some() {
            c.roi = self.roi;
        }
        if let Some(k) = self.flat_k {
            c.flat_k = k;
        }
        if self.no_drift_normalise {
            c.normalise_drift = false;
        }
    }
}

/// What calibration did, besides the pack.
#[derive(Debug, Clone, Default)]
pub struct CalibrateReport {
    pub frames: u64,
    /// Each rejected frame: its label and why.
    pub rejected: Vec<String>,
    /// Why frames were rejected, one line per reason with its count ([`summarize_rejections`]).
    pub rejection_reasons: Vec<String>,
    pub warnings: Vec<String>,
}

/// Groups rejection reasons that differ only in their numbers (ISO, exposure, percentages,
/// sizes): one line per reason, most frequent first, `N× reason (e.g. the first one's text)`.
pub fn summarize_rejections(reasons: &[String]) -> Vec<String> {
    let mut groups: BTreeMap<String, (usize, usize, &str)> = BTreeMap::new();
    for (i, r) in reasons.iter().enumerate() {
        let mut key = String::with_capacity(r.len());
        let mut in_number = false;
        for c in r.chars() {
            let numeric = c.is_ascii_digit() || (in_number && (c == '.' || c == 'e' || c == '-'));
            if numeric {
                if !in_number {
                    key.push('#');
                }
            } else {
                key.push(c);
            }
            in_number = numeric;
        }
        groups.entry(key).or_insert((0, i, r)).0 += 1;
    }
    let mut v: Vec<(usize, usize, &str)> = groups.into_values().collect();
    v.sort_by_key(|&(n, first, _)| (std::cmp::Reverse(n), first));
    v.into_iter().map(|(n, _, example)| format!("{n}× {example}")).collect()
}

/// Refuses a region of interest that does not lie inside the image.
fn check_roi(roi: &Roi, layout: &SensorLayout) -> anyhow::Result<()> {
    if roi.x1 > layout.width || roi.y1 > layout.height {
        bail!(
            "--roi {},{},{},{} reaches outside the {}×{} image: give x0,y0,x1,y1 with x1 ≤ {} and y1 ≤ {}",
            roi.x0,
            roi.y0,
            roi.x1,
            roi.y1,
            layout.width,
            layout.height,
            layout.width,
            layout.height
        );
    }
    Ok(())
}

/// Whether the recording file at `path` ends with a whole End record: then a record running
/// past its end is damage, not an interrupted capture.
fn recording_ends_whole(path: &Path) -> bool {
    let tail = || -> std::io::Result<Vec<u8>> {
        let mut f = std::fs::File::open(path)?;
        let len = f.metadata()?.len();
        let n = len.min(13);
        f.seek(SeekFrom::Start(len - n))?;
        let mut t = Vec::with_capacity(n as usize);
        f.take(n).read_to_end(&mut t)?;
        Ok(t)
    };
    tail().is_ok_and(|t| recording::ends_with_end_record(&t))
}

/// Calibrates from a DNG folder or a recording: every record of the [`Source`] into one
/// [`CalibrationSession`], in capture order. `progress(done, total)` is told of each frame read
/// (a front-end draws its own progress from it, or passes `&mut |_, _| {}`).
pub fn calibrate_path(
    path: &Path,
    opts: &CalibrateOptions,
    progress: &mut dyn FnMut(u64, u64),
) -> anyhow::Result<(ModelPack, CalibrateReport)> {
    // The DNG read buffers are reused from frame to frame and freed when this returns (declared
    // before the source, so dropped after the frames it holds).
    let _buffers = ReleaseReadBuffers;
    let mut source = Source::open(path, opts.reference_iso)?;
    let info = source.info();
    let mut config = info.config.clone();
    opts.apply(&mut config);
    if let Some(roi) = &config.roi {
        check_roi(roi, &info.layout)?;
    }
    let is_recording = info.kind == InputKind::Recording;
    let total_frames = info.frames;
    let layout = info.layout.clone();
    let mut session = CalibrationSession::new(info.layout.clone(), config)?;
    for (&iso, np) in &info.noise_profiles {
        session.set_noise_profile(iso, *np);
    }
    let mut report = CalibrateReport { warnings: info.warnings.clone(), ..Default::default() };
    let mut reasons = Vec::new();
    let mut in_dark = false;
    let mut deferred: Vec<(PathBuf, FrameMeta, String)> = Vec::new();
    // A DNG folder's EV-step frames that look dark: dim lit steps or a covered lens, told apart
    // against the step's lit frames, the dark burst and the exposure law (dim_steps.rs).
    let mut dim = DimSteps::default();
    while let Some(record) = source.next_record()? {
        match record {
            Record::BeginStep { reference_exposure_ns, .. } => {
                session.apply(SessionRecord::BeginStep { reference_exposure_ns })?;
                dim.begin_step(reference_exposure_ns);
                in_dark = false;
            }
            Record::BeginDark => {
                session.apply(SessionRecord::BeginDark)?;
                dim.end_step();
                in_dark = true;
                push_deferred(&mut session, &mut deferred, &mut report, &mut reasons);
            }
            Record::Frame(frame) => {
                report.frames += 1;
                progress(report.frames, total_frames);
                if !in_dark
                    && !is_recording
                    && let Some(path) = &frame.path
                    && let Ok(v) = frame.view()
                {
                    let black = frame.meta.black_or(&layout);
                    let level = frame_level(&v, &black);
                    let d = Dim::of(&frame.meta, &level);
                    // Most frames are lit: the quick test spares them the whole one.
                    if lit_by_level(&level, &black, &layout) || check_dark(&v, &black, &layout, frame.meta.iso).is_err()
                    {
                        let range =
                            layout.white as f64 - black.iter().map(|&b| b as f64).sum::<f64>() / black.len() as f64;
                        let (lit, dark) = dim.lit(d, range);
                        push_held(&mut session, lit, &mut report, &mut reasons);
                        deferred.extend(dark.into_iter().map(|h| (h.path, h.meta, h.label)));
                    } else {
                        let held = Held { path: path.clone(), meta: frame.meta, label: frame.label(), dim: d };
                        match dim.dim(held) {
                            // Dark: kept for the dark step.
                            Some(true) => {
                                deferred.push((path.clone(), frame.meta, frame.label()));
                                continue;
                            }
                            Some(false) => {}
                            None => continue,
                        }
                    }
                }
                let accepted = match session.apply(SessionRecord::Frame { view: frame.view(), meta: &frame.meta })? {
                    Some(e) => {
                        report.rejected.push(format!("{}: {e}", frame.label()));
                        reasons.push(e.to_string());
                        false
                    }
                    None => true,
                };
                // The dark burst's frame means, for the steps that wait for them.
                if accepted
                    && in_dark
                    && dim.waiting()
                    && let Ok(v) = frame.view()
                {
                    let level = frame_level(&v, &frame.meta.black_or(&layout));
                    dim.dark_frame(&frame.meta, Dim::of(&frame.meta, &level).level);
                }
            }
            Record::NoiseProfile { iso, profile } => {
                session.apply(SessionRecord::NoiseProfile { iso, profile })?;
            }
            Record::CutShort(e) => {
                // Only a missing tail is an interruption: a file that still ends with its End
                // record has a damaged length or tag in the middle.
                if is_recording && recording_ends_whole(path) {
                    bail!(
                        "{} is damaged: {e:#}, yet the file ends with a whole End record, so this is not an interrupted capture but a damaged record (its length or tag); nothing was written",
                        path.display()
                    );
                }
                report.warnings.push(match e {
                    CodecError::CutShort { context, .. } => {
                        format!("the recording ends inside {context} (an interrupted capture); replayed up to it")
                    }
                    other => other.to_string(),
                })
            }
        }
    }
    let (lit_steps, dark) = dim.finish();
    deferred.extend(dark.into_iter().map(|h| (h.path, h.meta, h.label)));
    if !deferred.is_empty() {
        if !in_dark {
            session.begin_dark()?;
        }
        push_deferred(&mut session, &mut deferred, &mut report, &mut reasons);
    }
    // Dim lit steps that waited for the dark burst, replayed as EV steps.
    for step in lit_steps {
        session.apply(SessionRecord::BeginStep { reference_exposure_ns: step.reference_exposure_ns })?;
        push_held(&mut session, step.frames, &mut report, &mut reasons);
    }
    report.warnings.append(&mut dim.notes);
    if session.dark_frames() > 0 {
        report.warnings.push(format!(
            "{} dark frame(s) (lens covered, told by their content) measured the fixed pattern",
            session.dark_frames()
        ));
    }
    report.rejection_reasons = summarize_rejections(&reasons);
    if !source.complete() {
        report.warnings.push(format!(
            "{} has no end marker (an interrupted capture): using its {} complete frames",
            path.display(),
            report.frames
        ));
    }
    let pack = session.finish().with_context(|| {
        let mut msg = format!("building the model pack from {}", path.display());
        if !report.rejected.is_empty() {
            msg.push_str(&format!(
                " ({} of {} frames were rejected: {})",
                report.rejected.len(),
                report.frames,
                report.rejection_reasons.join("; ")
            ));
        }
        // Frames all at the black level go to the dark step: say so, or "no target samples" is a
        // riddle for a folder of them.
        let dark = session.dark_frames();
        if dark > 0 {
            msg.push_str(&format!(
                " ({dark} of {} frames are dark, at the black level as with the lens covered, and were taken as dark frames, not targets)",
                report.frames
            ));
        }
        msg
    })?;
    Ok((pack, report))
}

/// Frees the DNG read buffers when dropped.
struct ReleaseReadBuffers;

impl Drop for ReleaseReadBuffers {
    fn drop(&mut self) {
        crate::dng::release_read_buffers();
    }
}

/// Pushes held frames found lit (re-read from their files) into the session's current step.
fn push_held(
    session: &mut CalibrationSession,
    frames: Vec<Held>,
    report: &mut CalibrateReport,
    reasons: &mut Vec<String>,
) {
    for h in frames {
        push_from_file(session, &h.path, &h.meta, &h.label, report, reasons);
    }
}

/// Re-reads the frame at `path` and pushes it into the session's current step; a file that no
/// longer reads, or a frame the session refuses, is reported as rejected under `label`.
fn push_from_file(
    session: &mut CalibrationSession,
    path: &Path,
    meta: &FrameMeta,
    label: &str,
    report: &mut CalibrateReport,
    reasons: &mut Vec<String>,
) {
    let pushed = crate::dng::read_dng(path).map_err(|e| e.to_string()).and_then(|img| {
        match session.apply(SessionRecord::Frame { view: FrameView::from_array(&img.pixels), meta }) {
            Ok(None) => Ok(()),
            Ok(Some(e)) | Err(e) => Err(e.to_string()),
        }
    });
    if let Err(e) = pushed {
        report.rejected.push(format!("{label}: {e}"));
        reasons.push(e);
    }
}

/// Pushes the dark frames found inside EV steps (re-read from their files, by ISO) into the
/// session's dark step.
fn push_deferred(
    session: &mut CalibrationSession,
    deferred: &mut Vec<(PathBuf, FrameMeta, String)>,
    report: &mut CalibrateReport,
    reasons: &mut Vec<String>,
) {
    deferred.sort_by(|a, b| a.1.iso.cmp(&b.1.iso).then(a.0.cmp(&b.0)));
    for (path, meta, label) in deferred.drain(..) {
        push_from_file(session, &path, &meta, &label, report, reasons);
    }
}
