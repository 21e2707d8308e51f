//! A recording replayed into a calibration session, exactly as the app fed it: what
//! `noisecal calibrate session.rec` and the JNI crate's replay run.

use std::io::Read;

use crate::calibrate::{CalibrationSession, SessionConfig, SessionRecord};
use crate::error::{CodecError, SessionError};
use crate::format::recording::{Record, RecordingHeader, RecordingReader};

/// What a replay did.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ReplayReport {
    pub frames: u64,
    pub rejected: Vec<String>,
    /// False when the recording has no End record (an interrupted capture).
    pub complete: bool,
}

/// The session configuration a recording implies: its reference ISO, bin width, make and model,
/// everything else at its default.
pub fn session_config(header: &RecordingHeader) -> SessionConfig {
    let mut c = SessionConfig::new(header.reference_iso);
    c.make = header.make.clone();
    c.model = header.model.clone();
    c.bin_width = (header.bin_width != 0).then_some(header.bin_width);
    c
}

/// Replays a recording into a new session, exactly as the app fed it: BeginStep → `begin_step`,
/// Frame → `push_frame` (rejected frames are listed, not fatal), NoiseProfile →
/// `set_noise_profile`, BeginDark → `begin_dark`. `configure` may adjust the implied configuration.
pub fn replay<R: Read>(
    mut reader: RecordingReader<R>,
    configure: impl FnOnce(&mut SessionConfig),
    mut on_frame: impl FnMut(u64),
) -> Result<(CalibrationSession, ReplayReport), SessionError> {
    let mut config = session_config(reader.header());
    configure(&mut config);
    let mut session = CalibrationSession::new(reader.header().layout.clone(), config)?;
    let mut report = ReplayReport::default();
    loop {
        let record = match reader.next_record() {
            Ok(Some(r)) => r,
            Ok(None) => break,
            // An app killed mid-write leaves a partial last record: replay what is whole.
            Err(CodecError::CutShort { context, .. }) => {
                report
                    .rejected
                    .push(format!("the recording ends inside {context} (an interrupted capture); replayed up to it"));
                break;
            }
            Err(e) => return Err(e.into()),
        };
        let applied = match &record {
            Record::BeginStep { exposure_ns } => {
                session.apply(SessionRecord::BeginStep { reference_exposure_ns: *exposure_ns })?
            }
            Record::Frame(f) => {
                report.frames += 1;
                session.apply(SessionRecord::Frame { view: f.view(), meta: &f.meta })?
            }
            Record::NoiseProfile { iso, profile } => {
                session.apply(SessionRecord::NoiseProfile { iso: *iso, profile: *profile })?
            }
            Record::BeginDark => session.apply(SessionRecord::BeginDark)?,
            Record::End { .. } => None,
        };
        if let Record::Frame(f) = &record {
            if let Some(e) = applied {
                report.rejected.push(format!(
                    "frame {} (ISO {}, {} ns): {e}",
                    report.frames - 1,
                    f.meta.iso,
                    f.meta.exposure_ns
                ));
            }
            on_frame(report.frames);
        }
    }
    report.complete = reader.ended();
    Ok((session, report))
}
