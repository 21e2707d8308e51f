//! JPEG XL raw data (DNG 1.7, Compression 52546), decoded once with an allocation budget before
//! rawler decodes it without one.
//!
//! rawler hands each tile or strip to jxl-oxide, which sizes its buffers from the codestream's
//! own header: a frame may claim up to 2³⁰ × 2³⁰ pixels (2⁴⁰ in area). Allocations that large fail,
//! and a failed allocation aborts the process, past any `catch_unwind`. Here every segment is
//! decoded first under a [`jxl_oxide::AllocTracker`] sized for the tile it fills, and its image
//! must fit that tile; a segment that does not is refused by name. rawler then decodes data known
//! to fit. This decodes JPEG XL DNGs twice; they are rare, and a bound is worth it.

use jxl_oxide::{AllocTracker, JxlImage};
use rayon::prelude::*;

/// Bytes the budget allows per pixel of a segment: up to 4 channels of 32-bit samples, twice
/// (jxl-oxide keeps modular and rendered buffers), with room for the transform's scratch.
const BYTES_PER_PIXEL: usize = 4 * 4 * 4;
/// Fixed allowance per segment for tables and small buffers.
const BASE_BYTES: usize = 64 << 20;

/// A segment of the raw image: its bytes and the pixels it must fill.
#[derive(Debug)]
pub(super) struct Segment<'a> {
    pub data: &'a [u8],
    pub width: usize,
    pub height: usize,
}

/// Checks that every segment decodes within its budget and fits its tile or strip; the error is
/// the reason, for the caller to name the file.
pub(super) fn check_segments(segments: &[Segment<'_>]) -> Result<(), String> {
    segments.par_iter().enumerate().try_for_each(|(i, s)| check(s).map_err(|e| format!("JPEG XL segment {i}: {e}")))
}

fn check(s: &Segment<'_>) -> Result<(), String> {
    let budget = s.width.saturating_mul(s.height).saturating_mul(BYTES_PER_PIXEL).saturating_add(BASE_BYTES);
    let image = JxlImage::builder()
        .alloc_tracker(AllocTracker::with_limit(budget))
        .read(s.data)
        .map_err(|e| format!("not a readable JPEG XL codestream ({e})"))?;
    let (w, h) = (image.width() as usize, image.height() as usize);
    if w > s.width || h > s.height {
        return Err(format!("its image is {w}×{h} pixels, larger than the {}×{} it fills", s.width, s.height));
    }
    image
        .render_frame(0)
        .map_err(|e| format!("cannot be decoded within {} MB for {w}×{h} pixels ({e})", budget >> 20))?;
    Ok(())
}
