//! Errors by category. Every message names the thing that was wrong and, where there is one, the fix.

use thiserror::Error;

/// A sensor layout that cannot be used.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum LayoutError {
    #[error("sensor layout {width}×{height} is too small: a frame needs at least 2×2 pixels")]
    TooSmall { width: u32, height: u32 },
    #[error("white level {white} is too low to be a raw sensor's saturation level")]
    WhiteLevel { white: u16 },
    #[error(
        "black level {black} at CFA position {pos} is not below the white level {white}; check the BlackLevel/WhiteLevel metadata"
    )]
    BlackLevel { pos: usize, black: f32, white: u16 },
    #[error("{width} is not a bin width: give 1 to {max} levels per bin, or leave it to the default")]
    BinWidth { width: u16, max: u16 },
}

/// A raw buffer that cannot be read as a frame of the expected size.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum FrameError {
    #[error("pixel stride is {pixel_stride} bytes; RAW_SENSOR frames are 16-bit samples with pixel stride 2")]
    PixelStride { pixel_stride: usize },
    #[error("row stride {row_stride} bytes is less than width × 2 = {min} bytes")]
    RowStride { row_stride: usize, min: usize },
    #[error(
        "buffer holds {len} bytes but a {width}×{height} frame with row stride {row_stride} needs at least {needed} bytes ((height − 1) · rowStride + 2 · width)"
    )]
    TooShort { len: usize, needed: usize, width: usize, height: usize, row_stride: usize },
    #[error("frame is {width}×{height} but the session's sensor is {expected_width}×{expected_height}")]
    SizeMismatch { width: usize, height: usize, expected_width: usize, expected_height: usize },
    #[error("frame is empty ({width}×{height})")]
    Empty { width: usize, height: usize },
}

/// A frame or request the calibration session refuses; the session is unchanged.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum SessionError {
    #[error(transparent)]
    Frame(#[from] FrameError),
    #[error(transparent)]
    Layout(#[from] LayoutError),
    #[error("no EV step has begun: call begin_step (the reference burst's exposure) before pushing frames")]
    NoStep,
    #[error(
        "frame at ISO {iso} is below the session's reference ISO {reference}: the reference must be the lowest ISO (the sensor's minimum sensitivity)"
    )]
    BelowReference { iso: u32, reference: u32 },
    #[error(
        "target frame at ISO {iso} with exposure {exposure_ns} ns arrived before any reference frame of this EV step: capture the reference burst (ISO {reference}) first"
    )]
    NoReference { iso: u32, exposure_ns: u64, reference: u32 },
    #[error(
        "target frame at ISO {iso}, exposure {exposure_ns} ns has brightness ISO×exposure {got:.4e} but this EV step's reference has {expected:.4e} (off by {off_pct:.1} %): it belongs to another EV step, or its exposure did not apply"
    )]
    WrongStep { iso: u32, exposure_ns: u64, got: f64, expected: f64, off_pct: f64 },
    #[error(
        "reference frame with exposure {exposure_ns} ns does not match this EV step's reference exposure {expected_ns} ns: begin a new step for it"
    )]
    ReferenceExposure { exposure_ns: u64, expected_ns: u64 },
    #[error(
        "reference frame arrived after the reference burst of this EV step was closed by a target frame: begin a new step"
    )]
    ReferenceClosed,
    #[error(
        "{kind} frame at ISO {iso}, exposure {exposure_ns} ns is {departure_pct:+.1} % off the brightness of its burst: more than flicker (normalised only up to ±{max_pct:.0} %). It belongs to another setting, or the light changed; the frame is refused"
    )]
    Drift { kind: &'static str, iso: u32, exposure_ns: u64, departure_pct: f64, max_pct: f64 },
    #[error(
        "target frame at ISO {iso}, exposure {exposure_ns} ns (EV step {step}) moved {shift_px:.2} px against its reference burst (at most {max_px:.1} px is measured around): the chart or the phone moved between frames. Use a sturdier mount, turn optical stabilisation off where the camera allows it, trigger remotely (no touch), and capture this burst again; the frame is refused"
    )]
    Moved { iso: u32, exposure_ns: u64, step: u32, shift_px: f64, max_px: f64 },
    #[error("frame metadata is invalid: {0}")]
    Metadata(String),
    #[error("per-frame black level {black} at position {pos} is not below white {white}")]
    FrameBlack { pos: usize, black: f32, white: u16 },
    #[error("the session has no target samples yet: capture target bursts before finishing")]
    NothingCalibrated,
    #[error(
        "the target frames of ISO {iso} carry no noise at all (every sample equals the clean level): they are copies of each other or of their reference, not captures; calibrate from real captures"
    )]
    NoNoise { iso: u32 },
    #[error(
        "the target frames of ISO {iso} are saturated: most samples are at the sensor's white level and every one measured is clipped, so no noise below it can be measured; lower the exposure or the light and capture again"
    )]
    Saturated { iso: u32 },
    #[error(
        "the reference burst of this EV step has no flat pixels: the chart is out of focus or moving, or the region of interest is empty"
    )]
    NoFlatPixels,
    #[error(
        "dark frame at ISO {iso} is not dark: {why}. Dark frames need the lens covered (an opaque cap, or a finger under a dark cloth, no light leaks); cover it and capture the dark step again, or skip the dark step"
    )]
    NotDark { iso: u32, why: String },
    #[error(transparent)]
    Codec(#[from] CodecError),
}

/// Reading or writing a model pack, a checkpoint or a recording.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum CodecError {
    #[error("{what} is truncated: {len} bytes, expected {expected}; the file was cut short, write it again")]
    Truncated { what: &'static str, len: usize, expected: usize },
    #[error("{what} does not start with the magic {expected:?}: this is not a {what}")]
    BadMagic { what: &'static str, expected: &'static str },
    #[error("{what} has format version {found}, newer than this noisecal reads ({supported}): upgrade noisecal")]
    NewerVersion { what: &'static str, found: u16, supported: u16 },
    #[error("{what} has format version {found}, older than this noisecal reads ({supported}); recreate it")]
    OlderVersion { what: &'static str, found: u16, supported: u16 },
    #[error("{what} is corrupt: checksum {found:08x} does not match {expected:08x}")]
    Checksum { what: &'static str, found: u32, expected: u32 },
    #[error("{what} is cut short inside {context}: the capture was interrupted; the records before it are whole")]
    CutShort { what: &'static str, context: String },
    #[error("{what} could not be decoded: {detail}")]
    Decode { what: &'static str, detail: String },
    #[error("{what} could not be encoded: {detail}")]
    Encode { what: &'static str, detail: String },
    #[error("{what} is inconsistent: {detail}")]
    Invalid { what: &'static str, detail: String },
}

/// Asking a model for something it does not hold.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ModelError {
    #[error("ISO {iso} is outside the pack's calibrated range {min}–{max}; calibrate it, or allow extrapolation")]
    IsoOutOfRange { iso: u32, min: u32, max: u32 },
    #[error("ISO {iso} is not in the pack (calibrated: {available}); interpolate it or pick one of those")]
    IsoMissing { iso: u32, available: String },
    #[error("image is {width}×{height} but the pack's sensor is {expected_width}×{expected_height} with CFA {cfa}")]
    ImageMismatch { width: usize, height: usize, expected_width: usize, expected_height: usize, cfa: String },
    /// The NoiseProfile baseline cannot be had at an ISO (no tag, or a damaged one).
    #[error("{0}; use the hg or pg model instead")]
    NoNoiseProfile(String),
    #[error("{0}")]
    Unsupported(String),
}

/// What a user changes to get past a [`ModelError`], for a front-end to name in its own words
/// (the CLI's flag, Python's argument, the app's setting) after the core's message.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Remedy {
    /// Allow extrapolation beyond the calibrated ISOs.
    Extrapolate,
    /// Synthesize with a parametric baseline (hg or pg) instead of the NoiseProfile one.
    ParametricModel,
}

impl ModelError {
    /// The remedy this error's message ends on, if any.
    pub fn remedy(&self) -> Option<Remedy> {
        match self {
            ModelError::IsoOutOfRange { .. } => Some(Remedy::Extrapolate),
            ModelError::NoNoiseProfile(_) => Some(Remedy::ParametricModel),
            _ => None,
        }
    }
}

impl Remedy {
    /// The remedy of the first error in a chain of causes (a [`ModelError`] alone or inside an
    /// [`enum@Error`]) that has one.
    pub fn in_chain<'a>(chain: impl IntoIterator<Item = &'a (dyn std::error::Error + 'static)>) -> Option<Remedy> {
        chain.into_iter().find_map(|e| {
            e.downcast_ref::<ModelError>()
                .or_else(|| match e.downcast_ref::<Error>() {
                    Some(Error::Model(m)) => Some(m),
                    _ => None,
                })
                .and_then(ModelError::remedy)
        })
    }
}

/// Everything the core can fail with.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum Error {
    #[error(transparent)]
    Layout(#[from] LayoutError),
    #[error(transparent)]
    Frame(#[from] FrameError),
    #[error(transparent)]
    Session(#[from] SessionError),
    #[error(transparent)]
    Codec(#[from] CodecError),
    #[error(transparent)]
    Model(#[from] ModelError),
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
