//! Compressed raw data, checked segment by segment before rawler decodes it, since rawler sizes
//! its buffers from each segment's own header and a failed allocation aborts the process, past
//! any `catch_unwind`.
//!
//! - **Lossless JPEG** (Compression 7): rawler decodes a whole frame of the SOF header's size
//!   (up to 65 535 × 65 535 samples per component) into a fresh buffer, then copies the tile out.
//!   A fuzzed tile claiming a frame thousands of times its size ran for minutes. The frame may be
//!   at most twice the tile's size each way (writers make them equal).
//! - **JPEG XL** (DNG 1.7, Compression 52546): jxl-oxide sizes its buffers from the codestream,
//!   whose frames may claim up to 2³⁰ × 2³⁰ pixels. Every segment is decoded first under a
//!   [`jxl_oxide::AllocTracker`] sized for the tile it fills, and its image must fit that tile;
//!   rawler then decodes data known to fit. This decodes JPEG XL DNGs twice; they are rare, and a
//!   bound is worth it.

use jxl_oxide::{AllocTracker, JxlImage};
use rawler::decompressors::ljpeg::LjpegDecompressor;
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

/// The compressions checked here.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Codec {
    LosslessJpeg,
    JpegXl,
}

/// Checks every segment; the error is the reason, for the caller to name the file.
pub(super) fn check_segments(codec: Codec, segments: &[Segment<'_>]) -> Result<(), String> {
    segments.par_iter().enumerate().try_for_each(|(i, s)| match codec {
        Codec::LosslessJpeg => check_ljpeg(s).map_err(|e| format!("lossless-JPEG segment {i}: {e}")),
        Codec::JpegXl => check_jxl(s).map_err(|e| format!("JPEG XL segment {i}: {e}")),
    })
}

/// The SOF header's frame, from rawler's own parser, is at most twice the segment each way.
fn check_ljpeg(s: &Segment<'_>) -> Result<(), String> {
    // An unparsable header is rawler's to report, as it does.
    let Ok(d) = LjpegDecompressor::new(s.data) else { return Ok(()) };
    let (w, h) = (d.width(), d.height());
    if w > 2 * s.width || h > 2 * s.height {
        return Err(format!("its frame is {w}×{h} samples, far larger than the {}×{} it fills", s.width, s.height));
    }
    Ok(())
}

fn check_jxl(s: &Segment<'_>) -> Result<(), String> {
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
