//! A calibration session as bytes, to resume after an interruption: the session's state in the
//! common framing ([`crate::format::codec`]) under its own magic and version.

use crate::calibrate::session::CalibrationSession;
use crate::error::CodecError;
use crate::format::codec;

pub const CHECKPOINT_MAGIC: &[u8; 8] = b"NCALCKPT";
/// Version 3 adds the structured-noise sums; version 4 the dark frames; version 5 the motion
/// probe of the clean image and the per-ISO motion figures; version 6 the same layout, with a
/// finished burst's line sums holding the spread of its line components over lines (their standard
/// error), not over line-frames: a version-5 session would resume with too small an error on the
/// bursts it had finished, so it is refused by name rather than resumed into different bytes.
/// Version 7 keeps, per finished burst, the flicker its frames showed (taken out of the frame
/// offsets; `calibrate/flicker.rs`); a version-6 session's finished bursts hold offsets with the
/// flicker in, so it is refused by name the same way. Version 8 keeps per frame its burst and the
/// sampling variance the frame component's significance test takes (`calibrate/structure.rs`,
/// `frame_test`); a version-7 session lacks them and is refused by name. Version 9 no longer
/// stores the motion probe's per-pixel gradients (2 bytes a pixel; made again from the clean
/// image when a frame that moved first needs them, `calibrate/motion/probe.rs`): a version-8
/// session's probe holds them where version 9 expects the next field, so it is refused by name.
pub const CHECKPOINT_VERSION: u16 = 9;

impl CalibrationSession {
    /// The session as bytes, to resume after an interruption.
    pub fn checkpoint(&self) -> Result<Vec<u8>, CodecError> {
        codec::encode("checkpoint", CHECKPOINT_MAGIC, CHECKPOINT_VERSION, self)
    }

    /// Resumes a session from [`checkpoint`](Self::checkpoint) bytes.
    pub fn restore(bytes: &[u8]) -> Result<Self, CodecError> {
        let s: Self = codec::decode("checkpoint", CHECKPOINT_MAGIC, "NCALCKPT", CHECKPOINT_VERSION, bytes)?;
        if !s.is_consistent() {
            return Err(CodecError::Invalid { what: "checkpoint", detail: "inconsistent session state".into() });
        }
        Ok(s)
    }
}
