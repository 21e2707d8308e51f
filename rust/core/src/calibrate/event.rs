//! One record of a capture applied to a session: the one place where a stream of records (a
//! recording replayed, a DNG folder grouped into steps) meets [`CalibrationSession`], so every
//! source treats a step, a dark step, a NoiseProfile and a frame the same way.

use crate::calibrate::frame::FrameView;
use crate::calibrate::meta::FrameMeta;
use crate::calibrate::session::CalibrationSession;
use crate::error::{FrameError, SessionError};
use crate::model::pack::NoiseProfile;

/// One record of a capture, as any source delivers it.
#[derive(Debug)]
pub enum SessionRecord<'a> {
    /// An EV step begins with its reference burst, at this exposure.
    BeginStep { reference_exposure_ns: u64 },
    /// A dark step begins: the frames up to the next step are dark frames.
    BeginDark,
    /// The camera's NoiseProfile of an ISO.
    NoiseProfile { iso: u32, profile: NoiseProfile },
    /// A frame: its pixels (or why they cannot be viewed) and metadata.
    Frame { view: Result<FrameView<'a>, FrameError>, meta: &'a FrameMeta },
}

impl CalibrationSession {
    /// Applies one record. A step or dark step the session refuses is fatal (`Err`); a frame it
    /// rejects is not: `Ok(Some(why))`, the session unchanged, for the caller to list.
    pub fn apply(&mut self, record: SessionRecord<'_>) -> Result<Option<SessionError>, SessionError> {
        match record {
            SessionRecord::BeginStep { reference_exposure_ns } => self.begin_step(reference_exposure_ns)?,
            SessionRecord::BeginDark => self.begin_dark()?,
            SessionRecord::NoiseProfile { iso, profile } => self.set_noise_profile(iso, profile),
            SessionRecord::Frame { view, meta } => {
                return Ok(view.map_err(SessionError::from).and_then(|v| self.push_frame(&v, meta)).err());
            }
        }
        Ok(None)
    }
}
