//! Replaying a recording into a pack, exactly as `noisecal calibrate session.rec` does: the
//! session is configured from the header; BeginStep → `begin_step`, Frame → `push_frame` over the
//! recorded bytes (a rejected frame is skipped with a warning), NoiseProfile →
//! `set_noise_profile`; then `finish`.

use std::io::Read;

use noisecal_core::recording::{Record, RecordingHeader, RecordingReader};
use noisecal_core::{CalibrationSession, ModelPack, SessionConfig};

use crate::error::Result;

/// The session a recording header describes (the same configuration `NoisecalSession.create`
/// builds from the same arguments).
pub fn session_for(header: &RecordingHeader) -> Result<CalibrationSession> {
    let mut config = SessionConfig::new(header.reference_iso);
    config.make = header.make.clone();
    config.model = header.model.clone();
    config.bin_width = (header.bin_width != 0).then_some(header.bin_width);
    Ok(CalibrationSession::new(header.layout.clone(), config)?)
}

/// Replays every record of `reader` into a fresh session and builds the pack.
pub fn replay_recording<R: Read>(mut reader: RecordingReader<R>) -> Result<ModelPack> {
    let mut session = session_for(reader.header())?;
    let mut index = 0u64;
    while let Some(record) = reader.next_record()? {
        match record {
            Record::BeginStep { exposure_ns } => session.begin_step(exposure_ns)?,
            Record::Frame(f) => {
                let pushed = f.view().map_err(Into::into).and_then(|v| session.push_frame(&v, &f.meta));
                if let Err(e) = pushed {
                    log::warn!("recorded frame {index} (ISO {}, {} ns) skipped: {e}", f.meta.iso, f.meta.exposure_ns);
                }
                index += 1;
            }
            Record::NoiseProfile { iso, profile } => session.set_noise_profile(iso, profile),
            Record::End { frames } => {
                if frames != index {
                    log::warn!("recording's End record counts {frames} frames but it holds {index}");
                }
            }
        }
    }
    if !reader.ended() {
        log::warn!("recording has no End record (interrupted capture): replayed its {index} frames");
    }
    Ok(session.finish()?)
}
