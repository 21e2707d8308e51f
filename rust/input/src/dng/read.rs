//! Reading CFA DNGs with `rawler`: its TIFF parser for the tags, its decoders for the pixels.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;
use std::sync::Arc;

use ndarray::Array2;
use noisecal_core::{FrameMeta, SensorLayout};
use rawler::RawImageData;
use rawler::decoders::plain_image_from_ifd;
use rawler::formats::tiff::reader::TiffReader;
use rawler::formats::tiff::{GenericTiffReader, IFD};
use rawler::rawsource::RawSource;

use super::compressed::{Codec, Segment, check_segments};
use super::guard::check_structure;
use super::ifd::Structure;
use super::meta::{
    active_area, ascii, black_levels, find, find_raw_ifd, has, num, nums, read_cfa, read_exposure, read_iso, subs,
    tag_name, uint, value,
};
use super::tags::Tag;
use super::{Bytes, ColorTags, DngError, DngFile, DngImage};

const COMPRESSION_LOSSY_JPEG: u64 = 34892;
const COMPRESSION_LOSSLESS_JPEG: u64 = 7;
const COMPRESSION_JPEG_XL: u64 = 52546;

/// The largest file [`read_dng`] reads: 1 GiB. The largest raw image accepted (256 MP of 16-bit
/// samples) takes 512 MiB; the rest leaves room for previews and metadata.
pub const MAX_DNG_BYTES: u64 = 1 << 30;

/// Reads a Bayer CFA DNG: the active-area mosaic, its layout (CFA at (0,0), black per position,
/// white) and ISO / exposure time.
///
/// The file is read whole (it must be a regular file of at most [`MAX_DNG_BYTES`]; FIFOs, devices
/// and directories are refused) and decoded by [`decode_dng`].
///
/// Errors: [`DngError::Io`] if the file cannot be opened or read, or is not a regular file of a
/// sane size; [`DngError::Decode`] for anything that is not a readable TIFF/DNG (truncated, random
/// bytes, corrupt image data); [`DngError::MissingTag`] when ISO, exposure time or the CFA pattern
/// is absent; [`DngError::Unsupported`] for non-Bayer (X-Trans, 4-colour), demosaiced (LinearRaw),
/// lossy, floating-point or < 10-bit data, and levels that make no sense.
pub fn read_dng(path: &Path) -> Result<DngImage, DngError> {
    parse(Src::Raw(source_of(path)?), path, true)
}

/// As [`read_dng`] without decoding the pixels (`pixels` is empty): the metadata a capture set is
/// grouped by, at a fraction of the cost. The same checks apply, but for the data's integrity.
/// The raw image data itself is not read where the file's directories say where it lies and lie
/// outside it (see `sparse.rs`).
pub fn read_dng_meta(path: &Path) -> Result<DngImage, DngError> {
    let bytes = super::sparse::meta_bytes(path, super::sparse::END_BYTES)?;
    parse(Src::Slice(&bytes), path, false)
}

/// Decodes a DNG held in memory, as [`read_dng`] decodes a file: the entry point for fuzzing and
/// for callers that already hold the bytes. `source` names the data in errors and becomes
/// [`DngImage::source`]. Malformed input of any kind is an error, never a panic.
pub fn decode_dng(bytes: &[u8], source: &Path) -> Result<DngImage, DngError> {
    parse(Src::Slice(bytes), source, true)
}

/// As [`decode_dng`] without decoding the pixels, as [`read_dng_meta`].
pub fn decode_dng_meta(bytes: &[u8], source: &Path) -> Result<DngImage, DngError> {
    parse(Src::Slice(bytes), source, false)
}

/// As [`read_dng`], keeping the file's bytes: the template [`super::write_derived`] writes a
/// derived DNG from (the input with only its pixels and ISO-dependent tags changed). Read into
/// memory (a reused buffer), not mapped, as [`read_dng_source`]: a template truncated by another
/// program while synthesis holds it cannot raise `SIGBUS`.
pub fn read_dng_file(path: &Path) -> Result<DngFile, DngError> {
    let read = super::buffers::Buffer::read(path, MAX_DNG_BYTES).map_err(|e| DngError::io(path, e))?;
    let bytes = Arc::new(Bytes::Read(read));
    let image = parse(Src::Slice(&bytes), path, true)?;
    Ok(DngFile { image, bytes })
}

/// As [`read_dng_file`], but the pixels of an uncompressed 16-bit raw image in this machine's
/// byte order are not copied out of the file's bytes: read them with [`DngFile::pixels`] (for
/// other storage they are decoded into `image.pixels`, as [`read_dng_file`] does). The file is
/// read into memory, not mapped: a file truncated or rewritten by another program while a
/// calibration runs is then a decode error naming it, never a crash (a mapped page past a new
/// end raises `SIGBUS`), at the cost of one copy from the page cache, into a buffer reused
/// from an earlier file ([`release_read_buffers`](super::release_read_buffers) frees them).
pub fn read_dng_source(path: &Path) -> Result<DngFile, DngError> {
    let read = super::buffers::Buffer::read(path, MAX_DNG_BYTES).map_err(|e| DngError::io(path, e))?;
    let bytes = Arc::new(Bytes::Read(read));
    let image = parse(Src::Slice(&bytes), path, false)?;
    let mut file = DngFile { image, bytes };
    if file.pixels().is_empty() {
        file.image = parse(Src::Slice(&file.bytes), path, true)?;
    }
    Ok(file)
}

/// As [`read_dng_file`] without decoding the pixels (`image.pixels` is empty): a template only.
pub fn read_dng_template(path: &Path) -> Result<DngFile, DngError> {
    let bytes = file_bytes(path)?;
    let image = parse(Src::Raw(RawSource::new_from_shared_vec(bytes.clone())), path, false)?;
    let bytes = Arc::new(Bytes::Owned(Arc::unwrap_or_clone(bytes)));
    Ok(DngFile { image, bytes })
}

/// A template from bytes already in memory (`source` names it in errors).
pub fn decode_dng_template(bytes: Vec<u8>, source: &Path) -> Result<DngFile, DngError> {
    let image = parse(Src::Slice(&bytes), source, false)?;
    Ok(DngFile { image, bytes: Arc::new(Bytes::Owned(bytes)) })
}

/// The whole raw image of a DNG (masked areas included, `ImageWidth × ImageLength` samples, as
/// the decoder gives them: linearized, de-interleaved).
pub(crate) fn decode_full_raw(bytes: &[u8], path: &Path) -> Result<Vec<u16>, DngError> {
    let src = RawSource::new_from_slice(bytes);
    check_structure(src.buf()).map_err(|d| DngError::decode(path, d))?;
    let tiff =
        guarded(path, "parsing the TIFF structure", || GenericTiffReader::new(&mut src.reader(), 0, 0, None, &[]))?
            .map_err(|e| DngError::decode(path, format!("invalid TIFF structure: {e}")))?;
    let chain: Vec<&IFD> = tiff.chains().iter().collect();
    let raw = find_raw_ifd(path, &chain)?;
    let data = guarded(path, "decoding the raw image data", || plain_image_from_ifd(raw, &src))
        .map_err(|e| panic_error(path, raw, e))?
        .map_err(|e| decode_error(path, raw, e))?;
    match data {
        RawImageData::Integer(d) => Ok(d),
        RawImageData::Float(_) => {
            Err(DngError::unsupported(path, "floating-point samples; noisecal needs integer sensor data"))
        }
    }
}

/// The file's bytes, read whole after checking it is a regular file of a sane size.
fn file_bytes(path: &Path) -> Result<Arc<Vec<u8>>, DngError> {
    let bytes = noisecal_io::read_regular(path, MAX_DNG_BYTES).map_err(|e| DngError::io(path, e))?;
    Ok(Arc::new(bytes))
}

/// What [`parse`] reads: a source for the decoder, or bytes (given to the decoder as a copy, only
/// when the pixels need the decoder).
enum Src<'a> {
    Raw(RawSource),
    Slice(&'a [u8]),
}

impl Src<'_> {
    fn buf(&self) -> &[u8] {
        match self {
            Src::Raw(r) => r.buf(),
            Src::Slice(b) => b,
        }
    }

    fn reader(&self) -> std::io::Cursor<&[u8]> {
        std::io::Cursor::new(self.buf())
    }
}

/// The file's bytes, read whole after checking it is a regular file of a sane size.
fn source_of(path: &Path) -> Result<RawSource, DngError> {
    Ok(RawSource::new_from_shared_vec(file_bytes(path)?))
}

fn parse(src: Src<'_>, path: &Path, decode_pixels: bool) -> Result<DngImage, DngError> {
    let len = src.buf().len();
    if len < 8 {
        return Err(DngError::decode(path, format!("the file is only {len} bytes long; a DNG is a TIFF file")));
    }
    // The one walk of the file's directories: checked here, read again by the fast path for
    // uncompressed data.
    let structure = check_structure(src.buf()).map_err(|d| DngError::decode(path, d))?;

    let tiff =
        guarded(path, "parsing the TIFF structure", || GenericTiffReader::new(&mut src.reader(), 0, 0, None, &[]))?
            .map_err(|e| DngError::decode(path, format!("invalid TIFF structure: {e}")))?;
    let chain: Vec<&IFD> = tiff.chains().iter().collect();
    if !chain.iter().any(|ifd| has(ifd, Tag::DngVersion)) {
        return Err(DngError::unsupported(
            path,
            "this TIFF file has no DNGVersion tag, so it is not a DNG; convert camera raw files to DNG first \
             (e.g. with Adobe DNG Converter or dnglab)",
        ));
    }
    let raw = find_raw_ifd(path, &chain)?;

    // --- Geometry and sample format.
    let int_tag = |t: Tag| -> Result<Option<u64>, DngError> {
        match value(raw, t) {
            None => Ok(None),
            Some(_) => uint(raw, t)
                .map(Some)
                .ok_or_else(|| DngError::decode(path, format!("{} of the raw image is not an integer", tag_name(t)))),
        }
    };
    let width = int_tag(Tag::ImageWidth)?.ok_or_else(|| DngError::decode(path, "the raw image has no ImageWidth"))?;
    let height =
        int_tag(Tag::ImageLength)?.ok_or_else(|| DngError::decode(path, "the raw image has no ImageLength"))?;
    // Bounds keep a corrupt header from making the decoder allocate gigabytes (≤ 256 MP).
    if width == 0 || height == 0 || width > 65535 || height > 65535 || width * height > 1 << 28 {
        return Err(DngError::decode(path, format!("implausible raw image size {width}×{height}")));
    }
    let (width, height) = (width as usize, height as usize);
    for t in [Tag::RowsPerStrip, Tag::TileWidth, Tag::TileLength] {
        if int_tag(t)? == Some(0) {
            return Err(DngError::decode(path, format!("{} of the raw image is 0", tag_name(t))));
        }
    }
    // rawler allocates the image padded to whole tiles before it reads a byte: bound that too.
    if let (Some(tw), Some(th)) = (int_tag(Tag::TileWidth)?, int_tag(Tag::TileLength)?) {
        let (pw, ph) = ((width as u64).div_ceil(tw) * tw, (height as u64).div_ceil(th) * th);
        if pw > 65535 + 65535 || ph > 65535 + 65535 || pw * ph > 1 << 28 {
            return Err(DngError::decode(
                path,
                format!(
                    "TileWidth × TileLength {tw}×{th} pads the {width}×{height} raw image to {pw}×{ph} pixels; \
                     tiles that much larger than the image are corrupt"
                ),
            ));
        }
    }
    let spp = int_tag(Tag::SamplesPerPixel)?.unwrap_or(1);
    if spp != 1 {
        return Err(DngError::unsupported(
            path,
            format!("{spp} samples per pixel; noisecal reads 1-sample CFA mosaics"),
        ));
    }
    let bits = int_tag(Tag::BitsPerSample)?.unwrap_or(1).min(64) as u32;
    if !(10..=16).contains(&bits) {
        return Err(DngError::unsupported(
            path,
            format!("{bits} bits per sample; noisecal reads 10- to 16-bit raw data"),
        ));
    }
    if let Some(fmt) = uint(raw, Tag::SampleFormat)
        && fmt != 1
    {
        return Err(DngError::unsupported(
            path,
            "floating-point (HDR-merged) samples; noisecal needs the integer data the sensor delivered",
        ));
    }
    if uint(raw, Tag::Compression) == Some(COMPRESSION_LOSSY_JPEG) {
        return Err(DngError::unsupported(
            path,
            "lossy-compressed DNG; its noise is not the sensor's: save uncompressed or lossless DNGs",
        ));
    }

    let cfa = read_cfa(path, raw)?;
    let (top, left, bottom, right) = active_area(path, raw, width, height)?;
    let (aw, ah) = (right - left, bottom - top);

    let white = match value(raw, Tag::WhiteLevel).and_then(|v| num(v, 0)) {
        Some(w) if w.is_finite() && (0.0..=65535.0).contains(&w) => w.round() as u16,
        Some(w) => {
            return Err(DngError::unsupported(path, format!("WhiteLevel {w} does not fit 16-bit samples")));
        }
        None => ((1u32 << bits) - 1) as u16,
    };
    let black = black_levels(path, raw, aw, ah)?;

    // --- Pixels.
    let pixels = if decode_pixels {
        decode(path, raw, &src, &structure, (width, height), (top, left, bottom, right), bits)?
    } else {
        Array2::zeros((0, 0))
    };

    let layout = SensorLayout { width: aw as u32, height: ah as u32, cfa, black, white };
    layout.validate().map_err(|e| DngError::unsupported(path, format!("the levels in this DNG are unusable: {e}")))?;

    // --- Capture metadata.
    let mut meta_ifds: Vec<&IFD> = Vec::new();
    for ifd in std::iter::once(raw).chain(chain.iter().copied()) {
        if let Some(subs) = subs(ifd, Tag::ExifIfd) {
            meta_ifds.extend(subs.iter());
        }
    }
    meta_ifds.push(raw);
    meta_ifds.extend(chain.iter().copied());
    let iso = read_iso(path, &meta_ifds)?;
    let exposure_ns = read_exposure(path, &meta_ifds)?;

    let root_then_raw: Vec<&IFD> = chain.iter().copied().chain(std::iter::once(raw)).collect();
    let raw_then_root: Vec<&IFD> = std::iter::once(raw).chain(chain.iter().copied()).collect();
    let noise_profile = find(&raw_then_root, Tag::NoiseProfile).and_then(|v| {
        let vals = nums(v);
        (vals.len() >= 2 && vals.iter().all(|x| x.is_finite()))
            .then(|| vals.chunks_exact(2).map(|p| (p[0], p[1])).collect())
    });
    let color = ColorTags {
        color_matrix1: find(&root_then_raw, Tag::ColorMatrix1).map(nums).filter(|v| !v.is_empty()),
        calibration_illuminant1: find(&root_then_raw, Tag::CalibrationIlluminant1)
            .and_then(|v| num(v, 0))
            .map(|x| x as u16),
        as_shot_neutral: find(&root_then_raw, Tag::AsShotNeutral).map(nums).filter(|v| !v.is_empty()),
    };

    Ok(DngImage {
        meta: FrameMeta { iso, exposure_ns, black: Some(layout.black) },
        layout,
        pixels,
        make: ascii(&root_then_raw, Tag::Make),
        model: ascii(&root_then_raw, Tag::Model),
        noise_profile,
        bits_per_sample: bits,
        color,
        source: path.to_path_buf(),
    })
}

/// Decodes the raw image data and crops it to the active area.
fn decode(
    path: &Path,
    raw: &IFD,
    src: &Src<'_>,
    structure: &Structure,
    (width, height): (usize, usize),
    (top, left, bottom, right): (usize, usize, usize, usize),
    bits: u32,
) -> Result<Array2<u16>, DngError> {
    let (aw, ah) = (right - left, bottom - top);
    let data_bytes = check_data_within_file(path, raw, src.buf().len())?;
    let needed = (width * height * bits as usize).div_ceil(8) as u64;
    if uint(raw, Tag::Compression).unwrap_or(1) == 1 && data_bytes < needed {
        return Err(DngError::decode(
            path,
            format!(
                "the uncompressed {width}×{height} {bits}-bit image needs {needed} bytes but the file stores \
                 {data_bytes}: it is truncated or corrupt"
            ),
        ));
    }
    // 16-bit samples labelled 10, 12 or 14 bits would unpack into garbage: an uncompressed image
    // storing as many bytes as 16-bit samples need is not what its BitsPerSample says. Strip rows
    // are padded to a byte at most (TIFF 6.0), so from 4 pixels a row a 14-bit row is at least a
    // byte shorter than a 16-bit one (tiles pad to their size: not judged).
    let full = (width * height * 2) as u64;
    if uint(raw, Tag::Compression).unwrap_or(1) == 1
        && bits < 16
        && width >= 4
        && has(raw, Tag::StripOffsets)
        && data_bytes >= full
    {
        return Err(DngError::decode(
            path,
            format!(
                "BitsPerSample says {bits} bits, but the uncompressed {width}×{height} image stores {data_bytes} bytes, \
                 as many as 16-bit samples need ({needed} for {bits}-bit): the tag does not describe the data; \
                 fix BitsPerSample (e.g. exiftool -BitsPerSample=16) or re-export the DNG"
            ),
        ));
    }
    // Uncompressed 16-bit data (Android's DngCreator, noisecal's own files) is read straight
    // into the active area; the rest goes through the decoder.
    if let Some(pixels) =
        super::raw_data::read_active_16(structure, src.buf(), (width, height), (top, left, bottom, right))
    {
        return Ok(pixels);
    }
    let codec = match uint(raw, Tag::Compression) {
        Some(COMPRESSION_LOSSLESS_JPEG) => Some(Codec::LosslessJpeg),
        Some(COMPRESSION_JPEG_XL) => Some(Codec::JpegXl),
        _ => None,
    };
    if let Some(codec) = codec {
        let segments = segments(path, raw, src.buf(), (width, height))?;
        guarded(path, "checking the compressed data", || check_segments(codec, &segments))?
            .map_err(|e| DngError::decode(path, e))?;
    }
    let copy;
    let src = match src {
        Src::Raw(r) => r,
        Src::Slice(b) => {
            copy = RawSource::new_from_slice(b);
            &copy
        }
    };
    let data = guarded(path, "decoding the raw image data", || plain_image_from_ifd(raw, src))
        .map_err(|e| panic_error(path, raw, e))?
        .map_err(|e| decode_error(path, raw, e))?;
    let data = match data {
        RawImageData::Integer(d) => d,
        RawImageData::Float(_) => {
            return Err(DngError::unsupported(path, "floating-point samples; noisecal needs integer sensor data"));
        }
    };
    if data.len() < width * height {
        return Err(DngError::decode(path, format!("decoded {} samples for a {width}×{height} image", data.len())));
    }
    let mut cropped = Vec::with_capacity(aw * ah);
    for row in top..bottom {
        cropped.extend_from_slice(&data[row * width + left..row * width + right]);
    }
    drop(data);
    let pixels = Array2::from_shape_vec((ah, aw), cropped)
        .map_err(|e| DngError::decode(path, format!("cannot shape the mosaic: {e}")))?;

    Ok(pixels)
}

/// The error for raw data the decoder refused. Lossless-JPEG data that rawler cannot read (it
/// reads the common ITU T.81 predictors only; some cameras, e.g. Blackmagic, write JPEG streams
/// it rejects) is named as such: the file is usually fine and other readers (LibRaw, Adobe)
/// decode it.
fn decode_error(path: &Path, raw: &IFD, e: impl std::fmt::Display) -> DngError {
    let detail = e.to_string();
    if uint(raw, Tag::Compression) == Some(COMPRESSION_LOSSLESS_JPEG) {
        return DngError::unsupported(
            path,
            format!(
                "its raw data is lossless-JPEG compressed in a form the DNG decoder (rawler) cannot read ({detail}); \
                 the file is probably not damaged (LibRaw and Adobe read such files): convert it to an \
                 uncompressed DNG, e.g. with Adobe DNG Converter (Preferences → Compatibility → Custom, \
                 Uncompressed) or `dnglab convert --compression none`"
            ),
        );
    }
    DngError::decode(path, format!("raw image data: {detail}"))
}

/// A decoder panic on lossless-JPEG data is that data's error too.
fn panic_error(path: &Path, raw: &IFD, e: DngError) -> DngError {
    match e {
        DngError::Decode { detail, .. } if uint(raw, Tag::Compression) == Some(COMPRESSION_LOSSLESS_JPEG) => {
            decode_error(path, raw, detail)
        }
        other => other,
    }
}

/// Runs decoder code that may panic on malformed input, turning a panic into [`DngError::Decode`].
fn guarded<T>(path: &Path, what: &str, f: impl FnOnce() -> T) -> Result<T, DngError> {
    catch_unwind(AssertUnwindSafe(f)).map_err(|payload| {
        let msg = payload
            .downcast_ref::<&str>()
            .map(|s| (*s).to_string())
            .or_else(|| payload.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "internal decoder error".into());
        DngError::decode(path, format!("the decoder failed while {what}: {msg}"))
    })
}

/// Clear error for a truncated file, before the decoder sees the data. Returns the data's size.
/// The tiles or strips of compressed raw data, each with the pixels it fills (checked to lie in the
/// file by [`check_data_within_file`]).
fn segments<'a>(
    path: &Path,
    raw: &IFD,
    buf: &'a [u8],
    (width, height): (usize, usize),
) -> Result<Vec<Segment<'a>>, DngError> {
    let dim = |t: Tag| uint(raw, t).map(|v| v as usize);
    let strips = has(raw, Tag::StripOffsets);
    let (offs, counts) = if strips {
        (value(raw, Tag::StripOffsets), value(raw, Tag::StripByteCounts))
    } else {
        (value(raw, Tag::TileOffsets), value(raw, Tag::TileByteCounts))
    };
    let rows = dim(Tag::RowsPerStrip).unwrap_or(height).clamp(1, height);
    let (tw, th) = (dim(Tag::TileWidth).unwrap_or(width), dim(Tag::TileLength).unwrap_or(height));
    let sizes = |i: usize| if strips { (width, rows.min(height.saturating_sub(i * rows))) } else { (tw, th) };
    let (Some(offs), Some(counts)) = (offs, counts) else {
        return Err(DngError::decode(path, "the raw image has no strip/tile byte counts"));
    };
    (0..offs.count().min(counts.count()))
        .map(|i| {
            let (o, c) = (num(offs, i).unwrap_or(f64::NAN), num(counts, i).unwrap_or(f64::NAN));
            let data = (o.is_finite() && c.is_finite())
                .then(|| buf.get(o as usize..(o + c) as usize))
                .flatten()
                .ok_or_else(|| DngError::decode(path, format!("compressed segment {i} lies outside the file")))?;
            let (width, height) = sizes(i);
            Ok(Segment { data, width, height })
        })
        .collect()
}

fn check_data_within_file(path: &Path, raw: &IFD, file_len: usize) -> Result<u64, DngError> {
    let (offs, counts) = if has(raw, Tag::StripOffsets) {
        (value(raw, Tag::StripOffsets), value(raw, Tag::StripByteCounts))
    } else {
        (value(raw, Tag::TileOffsets), value(raw, Tag::TileByteCounts))
    };
    let (Some(offs), Some(counts)) = (offs, counts) else {
        return Err(DngError::decode(path, "the raw image has no strip/tile byte counts"));
    };
    if offs.count() != counts.count() || offs.count() == 0 {
        return Err(DngError::decode(
            path,
            format!("{} data offsets but {} byte counts", offs.count(), counts.count()),
        ));
    }
    let mut end = 0u64;
    let mut total = 0u64;
    for i in 0..offs.count() {
        let o = num(offs, i).unwrap_or(f64::INFINITY);
        let c = num(counts, i).unwrap_or(f64::INFINITY);
        end = end.max((o + c).min(u64::MAX as f64) as u64);
        total = total.saturating_add(c.min(u64::MAX as f64) as u64);
    }
    if end > file_len as u64 {
        return Err(DngError::decode(
            path,
            format!("the image data ends at byte {end} but the file has only {file_len} bytes: it is truncated"),
        ));
    }
    Ok(total)
}

// ---------------------------------------------------------------------------------------------
// Capture metadata

#[cfg(test)]
mod tests {
    use super::*;
    use crate::dng::tiff::TagValue;
    use crate::dng::{DngSpec, dng_tiff};
    use noisecal_core::CfaPattern;
    use std::path::PathBuf;

    /// xorshift: deterministic garbage.
    struct Rng(u64);
    impl Rng {
        fn next(&mut self) -> u64 {
            self.0 ^= self.0 >> 12;
            self.0 ^= self.0 << 25;
            self.0 ^= self.0 >> 27;
            self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
        }
    }

    fn valid_spec() -> (DngSpec, Array2<u16>) {
        let layout = SensorLayout { width: 24, height: 16, cfa: CfaPattern::Grbg, black: [64.0; 4], white: 1023 };
        let mut rng = Rng(99);
        let pixels = Array2::from_shape_fn((16, 24), |_| (rng.next() % 1024) as u16);
        let spec = DngSpec {
            layout,
            meta: FrameMeta::new(400, 10_000_000),
            make: "M".into(),
            model: "N".into(),
            color: ColorTags::default(),
        };
        (spec, pixels)
    }

    fn valid() -> (Vec<u8>, Array2<u16>) {
        let (spec, pixels) = valid_spec();
        (dng_tiff(&spec, &pixels).expect("build").to_bytes().expect("bytes"), pixels)
    }

    #[test]
    fn sixteen_bit_data_labelled_fewer_bits_is_refused() {
        // 48 pixels a row: the mutation run's DNGs, which a 64-pixel floor let through.
        for width in [64usize, 48, 8] {
            let layout =
                SensorLayout { width: width as u32, height: 8, cfa: CfaPattern::Rggb, black: [64.0; 4], white: 1023 };
            let pixels = Array2::from_shape_fn((8, width), |(y, x)| (64 + y * 64 + x) as u16);
            let spec = DngSpec {
                layout,
                meta: FrameMeta::new(100, 1_000_000),
                make: "M".into(),
                model: "N".into(),
                color: ColorTags::default(),
            };
            let mut tiff = dng_tiff(&spec, &pixels).expect("build");
            let ok = decode_dng(&tiff.to_bytes().expect("bytes"), Path::new("ok.dng")).expect("16-bit");
            assert_eq!(ok.pixels, pixels);
            for bits in [10u16, 12, 14] {
                tiff.chain[0].set(Tag::BitsPerSample, TagValue::Short(vec![bits]));
                let e = decode_dng(&tiff.to_bytes().expect("bytes"), Path::new("mislabelled.dng"))
                    .expect_err("mislabelled")
                    .to_string();
                assert!(e.contains(&format!("BitsPerSample says {bits} bits")) && e.contains("mislabelled.dng"), "{e}");
                assert!(!e.contains("  "), "runs of spaces in the message: {e}");
            }
        }
    }

    #[test]
    fn bytes_decode_like_files() {
        let (bytes, pixels) = valid();
        let name = Path::new("memory.dng");
        let img = decode_dng(&bytes, name).expect("decode");
        assert_eq!(img.pixels, pixels);
        assert_eq!((img.meta.iso, img.meta.exposure_ns, img.layout.cfa), (400, 10_000_000, CfaPattern::Grbg));
        assert_eq!(img.source, name);
        let meta = decode_dng_meta(&bytes, name).expect("decode meta");
        assert_eq!((meta.pixels.dim(), meta.layout), ((0, 0), img.layout));
    }

    #[test]
    fn truncated_and_garbage_bytes_are_errors_not_panics() {
        let (bytes, _) = valid();
        let name = Path::new("fuzz.dng");
        // Every cut through the header and the IFD (at the end), and a spread through the pixels.
        // (Losing only the final next-IFD pointer loses nothing, as for rawler.)
        let cuts = (0..bytes.len() - 4).filter(|&c| c < 64 || c > bytes.len() - 700 || c % 97 == 0);
        for cut in cuts {
            let e = decode_dng(&bytes[..cut], name).expect_err("truncated data must fail");
            assert!(matches!(e, DngError::Decode { .. }), "cut at {cut}: {e}");
            assert!(e.to_string().contains("fuzz.dng"), "{e}");
        }
        let mut rng = Rng(2024);
        for k in 0..200usize {
            let mut g: Vec<u8> = (0..(k * 37) % 3000).map(|_| rng.next() as u8).collect();
            if k % 2 == 1 && g.len() >= 8 {
                // A TIFF header pointing into garbage.
                g[..4].copy_from_slice(if k % 4 == 1 { b"II\x2a\0" } else { b"MM\0\x2a" });
                let off = (rng.next() % g.len() as u64) as u32;
                g[4..8].copy_from_slice(&if k % 4 == 1 { off.to_le_bytes() } else { off.to_be_bytes() });
            }
            assert!(decode_dng(&g, name).is_err(), "garbage {k} decoded");
            assert!(decode_dng_meta(&g, name).is_err(), "garbage {k} decoded (meta)");
        }
        // A valid file with bytes overwritten in its IFD and tag data: an error or an image,
        // never a panic.
        let ifd_start = 8 + 24 * 16 * 2;
        for _ in 0..300 {
            let mut c = bytes.clone();
            for _ in 0..4 {
                let at = ifd_start + (rng.next() as usize) % (c.len() - ifd_start);
                c[at] = rng.next() as u8;
            }
            let _ = decode_dng(&c, name);
        }
    }

    /// rawler follows a chain IFD's GPSInfo and InterColorProfile tags as IFDs, of any type (an
    /// UNDEFINED value is read as the IFD itself), and allocates each entry's count before reading
    /// it: one DOUBLE tag of count 2³² − 16 there was a 32 GB allocation that aborted the fuzzer in
    /// CI. Such tags are refused by name before rawler runs; a sane one still decodes.
    #[test]
    fn huge_tags_in_the_ifds_rawler_follows_are_refused_before_it_allocates() {
        let (spec, pixels) = valid_spec();
        // An IFD of one entry: tag 33434, type `ty`, `count`, value offset 8; no next IFD.
        let ifd = |ty: u16, count: u32| -> Vec<u8> {
            let mut b = 1u16.to_le_bytes().to_vec();
            b.extend(33434u16.to_le_bytes());
            b.extend(ty.to_le_bytes());
            b.extend(count.to_le_bytes());
            b.extend(8u32.to_le_bytes());
            b.extend([0u8; 8]);
            b
        };
        for via in [34853u16, 34675] {
            for (ty, count) in [(12u16, 0xFFFF_FFF0u32), (5, 0x8000_0000), (3, 0x4000_0000), (99, 0x1000_0000)] {
                let mut tiff = dng_tiff(&spec, &pixels).expect("build");
                tiff.chain[0].set(Tag::from_u16(via), TagValue::Undefined(ifd(ty, count)));
                let bytes = tiff.to_bytes().expect("bytes");
                assert_eq!(&bytes[..2], b"II");
                let e = decode_dng_meta(&bytes, Path::new("crafted.dng")).expect_err("huge tag").to_string();
                let names = if via == 34675 { "InterColorProfile (tag 34675)" } else { "through tag 34853" };
                assert!(e.contains("crafted.dng") && e.contains("tag 33434") && e.contains(names), "{e}");
            }
            let mut tiff = dng_tiff(&spec, &pixels).expect("build");
            tiff.chain[0].set(Tag::from_u16(via), TagValue::Undefined(ifd(12, 1)));
            let img = decode_dng(&tiff.to_bytes().expect("bytes"), Path::new("sane.dng")).expect("a sane tag decodes");
            assert_eq!(img.pixels, pixels);
        }
    }

    fn tempdir(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("noisecal-cli-dng-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).expect("create test dir");
        d
    }

    #[test]
    fn files_that_are_not_regular_are_refused() {
        let d = tempdir("kinds");
        let e = read_dng(&d).expect_err("directory");
        assert!(matches!(e, DngError::Io { .. }) && e.to_string().contains("not a regular file"), "{e}");
        #[cfg(unix)]
        {
            let e = read_dng_meta(Path::new("/dev/zero")).expect_err("/dev/zero");
            assert!(matches!(e, DngError::Io { .. }) && e.to_string().contains("character device"), "{e}");
        }
        let (bytes, pixels) = valid();
        let f = d.join("ok.dng");
        std::fs::write(&f, &bytes).expect("write");
        assert_eq!(read_dng(&f).expect("read").pixels, pixels);
        std::fs::remove_dir_all(&d).expect("clean");
    }
}
