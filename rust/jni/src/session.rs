//! The session behind one Kotlin `NoisecalSession`: the core's [`CalibrationSession`] plus an
//! optional recording tee. Plain Rust (no JNI types), so it is tested without a JVM.

use std::path::Path;

use noisecal_core::calibrate::session::{FrameReport, Progress};
use noisecal_core::format::recording::{RecordingHeader, TEE_CHECKPOINT_MAGIC, TeeCheckpoint};
use noisecal_core::{CalibrationSession, CfaPattern, FrameMeta, FrameView, SensorLayout, SessionConfig};

use crate::error::{BoundaryError, Result};
use crate::files::write_atomically;
use crate::gap_calls::gap_calls_text;
use crate::recording::RecordingTee;

/// Magic of the core's own checkpoint (also accepted by [`NativeSession::restore_file`]).
const CORE_CHECKPOINT_MAGIC: &[u8; 8] = noisecal_core::format::checkpoint::CHECKPOINT_MAGIC;

/// What `NoisecalSession.create` passes.
#[derive(Debug, Clone)]
pub struct CreateParams<'a> {
    pub width: i32,
    pub height: i32,
    pub cfa: &'a str,
    pub black: &'a [f32],
    pub white: i32,
    pub reference_iso: i32,
    pub make: &'a str,
    pub model: &'a str,
    /// 0 = the default for the bit depth.
    pub bin_width: i32,
}

/// One frame's geometry and metadata as `NoisecalSession.pushFrame` passes them.
#[derive(Debug, Clone, Copy)]
pub struct PlaneParams<'a> {
    pub width: i32,
    pub height: i32,
    pub row_stride: i32,
    pub pixel_stride: i32,
    pub iso: i32,
    pub exposure_ns: i64,
    pub black: Option<&'a [f32]>,
}

fn positive(name: &'static str, v: i32) -> Result<u32> {
    u32::try_from(v).ok().filter(|&x| x > 0).ok_or_else(|| BoundaryError::arg(name, v, "it must be positive"))
}

fn non_negative(name: &'static str, v: i32) -> Result<usize> {
    usize::try_from(v).map_err(|_| BoundaryError::arg(name, v, "it must not be negative"))
}

fn white_level(v: i32) -> Result<u16> {
    u16::try_from(v)
        .ok()
        .filter(|&w| w > 0)
        .ok_or_else(|| BoundaryError::arg("whiteLevel", v, "it must be in 1..=65535"))
}

/// The core's default bin width for a sensor (what a session created with bin width 0 uses):
/// [`SensorLayout::default_bin_width`], which looks only at the white and black levels.
pub fn default_bin_width(white: i32, black: &[f32]) -> Result<u16> {
    let black = black4("blackLevels", black)?;
    // Any valid geometry: the rule does not depend on it.
    let layout = SensorLayout { width: 2, height: 2, cfa: CfaPattern::Rggb, black, white: white_level(white)? };
    layout.validate().map_err(noisecal_core::error::SessionError::from)?;
    Ok(layout.default_bin_width())
}

fn black4(name: &'static str, b: &[f32]) -> Result<[f32; 4]> {
    <[f32; 4]>::try_from(b).map_err(|_| {
        BoundaryError::arg(name, format!("an array of {} values", b.len()), "pass 4 values in CFA position order")
    })
}

/// The session state behind a handle.
/// What [`NativeSession::finish_with_gaps`] built: the one-line summary and the pack's gap calls
/// ([`crate::gap_calls`]'s text).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Finished {
    pub summary: String,
    pub gap_calls: String,
}

#[derive(Debug)]
pub struct NativeSession {
    session: CalibrationSession,
    recording: Option<RecordingTee>,
}

impl NativeSession {
    pub fn create(p: &CreateParams<'_>) -> Result<Self> {
        let width = positive("width", p.width)?;
        let height = positive("height", p.height)?;
        let cfa = CfaPattern::parse(p.cfa)
            .ok_or_else(|| BoundaryError::arg("cfa", format!("{:?}", p.cfa), "pass RGGB, BGGR, GRBG or GBRG"))?;
        let black = black4("blackLevels", p.black)?;
        let white = white_level(p.white)?;
        let reference_iso = positive("referenceIso", p.reference_iso)?;
        let bin_width = match p.bin_width {
            0 => None,
            // The core's rule (noisecal_core::model::bin_width), named by this boundary's argument.
            b => Some(u16::try_from(b).ok().and_then(|w| noisecal_core::model::bin_width::check(w).ok()).ok_or_else(
                || {
                    BoundaryError::arg(
                        "binWidth",
                        b,
                        format!(
                            "pass 0 for the default or 1..={} levels",
                            noisecal_core::model::bin_width::MAX_BIN_WIDTH
                        ),
                    )
                },
            )?),
        };
        let layout = SensorLayout { width, height, cfa, black, white };
        let mut config = SessionConfig::new(reference_iso);
        config.make = p.make.to_string();
        config.model = p.model.to_string();
        config.bin_width = bin_width;
        Ok(Self { session: CalibrationSession::new(layout, config)?, recording: None })
    }

    /// A session over an existing core session (replay, tests).
    pub fn from_core(session: CalibrationSession) -> Self {
        Self { session, recording: None }
    }

    pub fn core(&self) -> &CalibrationSession {
        &self.session
    }

    /// The header a recording of this session starts with.
    pub fn recording_header(&self) -> RecordingHeader {
        let c = self.session.config();
        RecordingHeader {
            layout: self.session.layout().clone(),
            reference_iso: c.reference_iso,
            bin_width: c.bin_width.unwrap_or(0),
            make: c.make.clone(),
            model: c.model.clone(),
        }
    }

    /// The open recording's path, if any.
    pub fn recording_path(&self) -> Option<&Path> {
        self.recording.as_ref().map(|r| r.path())
    }

    /// Runs a recording write; on failure the recording is stopped (so the file never gets out of
    /// step with the session) and the error is returned.
    fn record(&mut self, f: impl FnOnce(&mut RecordingTee) -> Result<()>) -> Result<()> {
        if let Some(tee) = self.recording.as_mut()
            && let Err(e) = f(tee)
        {
            self.recording = None;
            log::error!("{e}");
            return Err(e);
        }
        Ok(())
    }

    pub fn begin_step(&mut self, exposure_ns: i64) -> Result<()> {
        let e = u64::try_from(exposure_ns)
            .map_err(|_| BoundaryError::arg("referenceExposureNs", exposure_ns, "it must be positive"))?;
        self.session.begin_step(e)?;
        self.record(|t| t.begin_step(e))
    }

    /// Begins a dark (lens-covered) step: the frames pushed until the next step are dark frames
    /// (the core refuses one with a scene in it, `SessionError::NotDark`). Recorded, so the
    /// recording replays the same.
    pub fn begin_dark(&mut self) -> Result<()> {
        self.session.begin_dark()?;
        self.record(|t| t.begin_dark())
    }

    /// Folds in one plane: `plane` is the whole buffer from its start (little-endian 16-bit samples,
    /// rows `row_stride` bytes apart). A rejected frame leaves the session unchanged.
    pub fn push_plane(&mut self, plane: &[u8], p: &PlaneParams<'_>) -> Result<FrameReport> {
        let width = non_negative("width", p.width)?;
        let height = non_negative("height", p.height)?;
        let row_stride = non_negative("rowStride", p.row_stride)?;
        let pixel_stride = non_negative("pixelStride", p.pixel_stride)?;
        let iso = u32::try_from(p.iso).map_err(|_| BoundaryError::arg("iso", p.iso, "it must not be negative"))?;
        let exposure_ns = u64::try_from(p.exposure_ns)
            .map_err(|_| BoundaryError::arg("exposureNs", p.exposure_ns, "it must not be negative"))?;
        let black = p.black.map(|b| black4("blackLevels", b)).transpose()?;
        let meta = FrameMeta { iso, exposure_ns, black };
        let view = FrameView::from_le_bytes(plane, width, height, row_stride, pixel_stride)?;
        let report = self.session.push_frame(&view, &meta)?;
        // Geometry fits u32: it was checked against the session's u32 layout and the plane length.
        self.record(|t| t.frame(&meta, width as u32, height as u32, row_stride as u32, pixel_stride as u32, plane))?;
        Ok(report)
    }

    /// Records the camera's own noise profile for an ISO (Camera2 `SENSOR_NOISE_PROFILE`): 8
    /// values, `(S, O)` per CFA position in position order, `σ² = S·x + O` with x in [0, 1].
    pub fn set_noise_profile(&mut self, iso: i32, profile: &[f64]) -> Result<()> {
        let iso = positive("iso", iso)?;
        if profile.len() != 8 || profile.iter().any(|v| !v.is_finite()) {
            return Err(BoundaryError::arg(
                "noise profile",
                format!("{profile:?}"),
                "pass 8 finite values: (S, O) for each of the 4 CFA positions",
            ));
        }
        let p = noisecal_core::model::NoiseProfile(std::array::from_fn(|i| [profile[2 * i], profile[2 * i + 1]]));
        self.session.set_noise_profile(iso, p);
        self.record(|t| t.noise_profile(iso, &p))
    }

    /// The session's progress (the JNI layer turns it into a Kotlin `NoisecalSession.Progress`).
    pub fn progress(&self) -> Progress {
        self.session.progress()
    }

    /// Levels per histogram bin: the pack's bin width.
    pub fn bin_width(&self) -> u16 {
        self.session.binning().bin_width
    }

    /// Tees every accepted frame from now on into a new recording at `path`. Only before the
    /// first step: a recording must replay the whole session.
    pub fn start_recording(&mut self, path: &Path) -> Result<()> {
        if let Some(r) = &self.recording {
            return Err(BoundaryError::Recording(format!(
                "already recording to {}: a session has one recording",
                r.path().display()
            )));
        }
        let p = self.session.progress();
        if p.steps > 0 || p.frames_accepted > 0 {
            return Err(BoundaryError::Recording(format!(
                "startRecording after {} step(s) and {} accepted frame(s): start the recording before the first beginStep so it replays the whole session",
                p.steps, p.frames_accepted
            )));
        }
        self.recording = Some(RecordingTee::create(path, &self.recording_header())?);
        Ok(())
    }

    /// The checkpoint file's bytes: a [`TeeCheckpoint`] (the core checkpoint and, when recording,
    /// where the recording stands).
    pub fn checkpoint_bytes(&mut self) -> Result<Vec<u8>> {
        let recording = match self.recording.as_mut() {
            Some(t) => match t.mark() {
                Ok(m) => Some((t.path().to_string_lossy().into_owned(), m)),
                Err(e) => {
                    self.recording = None;
                    return Err(e);
                }
            },
            None => None,
        };
        Ok(TeeCheckpoint { recording, session: self.session.checkpoint()? }.to_bytes()?)
    }

    /// Writes a checkpoint to `path` (temporary file, then rename).
    pub fn checkpoint_file(&mut self, path: &Path) -> Result<()> {
        let bytes = self.checkpoint_bytes()?;
        write_atomically("cannot write the checkpoint", path, &bytes)
    }

    /// Resumes from checkpoint bytes: a boundary checkpoint (the session and, if it was
    /// recording, the recording cut back to its length at the checkpoint and reopened) or a bare
    /// core checkpoint (no recording). If the recording cannot be resumed (file gone, shorter,
    /// or not this session's), the session still resumes, without a recording, and says so in
    /// the log.
    pub fn restore_bytes(bytes: &[u8]) -> Result<Self> {
        if bytes.starts_with(CORE_CHECKPOINT_MAGIC) {
            return Ok(Self::from_core(CalibrationSession::restore(bytes)?));
        }
        if !bytes.starts_with(TEE_CHECKPOINT_MAGIC) {
            return Err(BoundaryError::Recording(
                "checkpoint file is unreadable: it starts with neither NCALJSES nor NCALCKPT: this is not a noisecal checkpoint"
                    .into(),
            ));
        }
        let checkpoint = TeeCheckpoint::from_bytes(bytes)?;
        let mut s = Self::from_core(CalibrationSession::restore(&checkpoint.session)?);
        if let Some((path, mark)) = checkpoint.recording {
            let path = Path::new(&path);
            match RecordingTee::resume(path, mark, &s.recording_header()) {
                Ok(t) => {
                    log::info!("recording {} resumed at {} frames ({} bytes)", path.display(), mark.frames, mark.bytes);
                    s.recording = Some(t);
                }
                Err(e) => log::warn!("session restored without its recording: {e}"),
            }
        }
        Ok(s)
    }

    /// Resumes from a checkpoint file written by [`checkpoint_file`](Self::checkpoint_file).
    pub fn restore_file(path: &Path) -> Result<Self> {
        let bytes = std::fs::read(path).map_err(|e| BoundaryError::io("cannot read the checkpoint", path, e))?;
        Self::restore_bytes(&bytes)
    }

    /// Builds the pack, writes it to `path` (temporary file, then rename), flushes and syncs the
    /// recording (it stays open: more frames may follow; [`close`](Self::close) ends it) and
    /// returns a one-line summary. The session stays usable.
    pub fn finish_to(&mut self, path: &Path) -> Result<String> {
        Ok(self.finish_with_gaps(path)?.summary)
    }

    /// [`Self::finish_to`], with the pack's conversion-gain call per gap between neighbouring
    /// calibrated ISOs ([`gap_calls_text`]).
    pub fn finish_with_gaps(&mut self, path: &Path) -> Result<Finished> {
        let pack = self.session.finish()?;
        let gap_calls = gap_calls_text(&pack);
        let bytes = pack.to_bytes()?;
        write_atomically("cannot write the model pack", path, &bytes)?;
        let mut summary = format!(
            "{} {}: ISO {} from {} target frames, {} warnings; {} bytes to {}",
            pack.make,
            pack.model,
            pack.iso_summary(),
            pack.isos.iter().map(|m| m.frames).sum::<u64>(),
            pack.warnings.len(),
            bytes.len(),
            path.display()
        );
        if let Some(t) = self.recording.as_mut() {
            match t.mark() {
                Ok(m) => summary.push_str(&format!("; recording {} ({} frames)", t.path().display(), m.frames)),
                Err(e) => {
                    self.recording = None;
                    return Err(e);
                }
            }
        }
        Ok(Finished { summary, gap_calls })
    }

    /// Ends the session: writes the recording's End record, if recording.
    pub fn close(self) -> Result<()> {
        if let Some(t) = self.recording {
            let path = t.path().to_path_buf();
            let m = t.finish()?;
            log::info!("recording {} closed with {} frames ({} bytes)", path.display(), m.frames, m.bytes);
        }
        Ok(())
    }
}
