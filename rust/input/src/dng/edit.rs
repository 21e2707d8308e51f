//! DNGs derived from another DNG: the input file, byte for byte, with only its raw pixels and its
//! ISO-dependent tags changed.
//!
//! Nothing of the input moves. The output starts as a copy of the input's bytes; then
//!
//! * the raw pixels are written over the stored ones when the raw image is stored uncompressed
//!   (16-bit samples in the file's byte order, or 10–15-bit MSB-packed rows), so masked areas,
//!   previews and every offset stay as they were; a compressed, linearized or interleaved raw
//!   image is instead appended as uncompressed 16-bit strips and its IFD points there;
//! * a tag whose new value has the old type and size is patched where it is; an IFD that gains,
//!   loses or resizes a tag is written again at the end of the file (its other entries copied as
//!   they are, so out-of-line values, maker notes and sub-IFDs are shared with the original) and
//!   the pointer to it (the header, the previous IFD's link, a SubIFDs or ExifIFD entry) is
//!   patched. Offsets inside maker notes therefore stay right.
//!
//! What changes: the raw pixels; the ISO (`ISOSpeedRatings`/`PhotographicSensitivity` wherever
//! the input has it, and `StandardOutputSensitivity`, `RecommendedExposureIndex`, `ISOSpeed`;
//! added to the EXIF IFD, else IFD0, when the input has none); `NoiseProfile` (the one given, in
//! the raw IFD, or none: the input's would not describe the new pixels); `RawImageDigest` and
//! `NewRawImageDigest` are dropped (they hash the old pixels) and `RawDataUniqueID` is changed (raw
//! converters key their caches on it).

use std::collections::BTreeMap;

use ndarray::{Array2, ArrayView2, ShapeBuilder};
use noisecal_core::SensorLayout;
use noisecal_core::model::layout::{CfaColor, POSITIONS};
use noisecal_core::model::pack::NoiseProfile;
use rayon::prelude::*;

use super::ifd::{Entry, FieldType, Order, Structure, walk};
use super::tags::Tag;
use super::tiff::pack_msb;

const PHOTOMETRIC_CFA: u64 = 32803;
const SHORT: u16 = FieldType::Short as u16;
const LONG: u16 = FieldType::Long as u16;

/// The structure walked by [`walk`], read the ways the editor needs.
impl Structure {
    fn parse(buf: &[u8]) -> Result<Self, String> {
        walk(buf)
    }

    fn entry(&self, dir: usize, t: Tag) -> Option<&Entry> {
        self.dirs[dir].entries.iter().find(|e| e.tag == t.to_u16())
    }

    /// The bytes of an entry's value (`None` when it lies outside the file or its type is unknown).
    fn bytes<'a>(&self, buf: &'a [u8], e: &'a Entry) -> Option<&'a [u8]> {
        let size = FieldType::from_code(e.ty)?.size().checked_mul(e.count as usize)?;
        if size <= 4 {
            Some(&e.field[..size])
        } else {
            let off = self.order.u32(&e.field, 0)? as usize;
            buf.get(off..off.checked_add(size)?)
        }
    }

    /// An unsigned integer value (BYTE, SHORT, LONG, IFD) as u64s.
    fn uints(&self, buf: &[u8], dir: usize, t: Tag) -> Option<Vec<u64>> {
        let e = self.entry(dir, t)?;
        let b = self.bytes(buf, e)?;
        let o = self.order;
        match FieldType::from_code(e.ty)? {
            FieldType::Byte | FieldType::Undefined => Some(b.iter().map(|&x| x as u64).collect()),
            FieldType::Short => Some((0..b.len() / 2).map(|i| o.u16(b, 2 * i).unwrap_or(0) as u64).collect()),
            FieldType::Long | FieldType::Ifd => {
                Some((0..b.len() / 4).map(|i| o.u32(b, 4 * i).unwrap_or(0) as u64).collect())
            }
            _ => None,
        }
    }

    fn uint(&self, buf: &[u8], dir: usize, t: Tag) -> Option<u64> {
        self.uints(buf, dir, t)?.first().copied()
    }

    /// The full-resolution CFA raw image, found as the reader finds it: NewSubfileType 0 with
    /// image data and CFA photometry, in the chain and its SubIFDs, in file order.
    fn raw_dir(&self, buf: &[u8]) -> Option<usize> {
        fn collect(s: &Structure, d: usize, out: &mut Vec<usize>) {
            out.push(d);
            for &(t, c) in &s.dirs[d].children {
                if t == Tag::SubIfds.to_u16() {
                    collect(s, c, out);
                }
            }
        }
        let mut all = Vec::new();
        for &d in &self.chain {
            collect(self, d, &mut all);
        }
        all.into_iter().find(|&d| {
            self.uint(buf, d, Tag::NewSubfileType).unwrap_or(0) == 0
                && (self.entry(d, Tag::StripOffsets).is_some() || self.entry(d, Tag::TileOffsets).is_some())
                && self.uint(buf, d, Tag::PhotometricInterpretation) == Some(PHOTOMETRIC_CFA)
        })
    }
}

/// A change to one tag of one directory.
#[derive(Debug, Clone)]
enum Edit {
    Set { ty: u16, count: u32, bytes: Vec<u8> },
    Remove,
}

#[derive(Default)]
struct Edits(BTreeMap<usize, BTreeMap<u16, Edit>>);

impl Edits {
    fn set(&mut self, dir: usize, t: Tag, ty: u16, count: u32, bytes: Vec<u8>) {
        self.0.entry(dir).or_default().insert(t.to_u16(), Edit::Set { ty, count, bytes });
    }

    fn remove(&mut self, dir: usize, t: Tag) {
        self.0.entry(dir).or_default().insert(t.to_u16(), Edit::Remove);
    }
}

fn shorts(o: Order, v: &[u16]) -> Vec<u8> {
    v.iter().flat_map(|&x| o.b16(x)).collect()
}

fn longs(o: Order, v: &[u32]) -> Vec<u8> {
    v.iter().flat_map(|&x| o.b32(x)).collect()
}

fn doubles(o: Order, v: &[f64]) -> Vec<u8> {
    v.iter().flat_map(|&x| if o.big { x.to_be_bytes() } else { x.to_le_bytes() }).collect()
}

/// How the new pixels get into the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum PixelMode {
    /// Over the stored 16-bit samples.
    InPlace16,
    /// Over the stored MSB-packed rows of this many bits.
    InPlacePacked(u32),
    /// As new uncompressed 16-bit strips at the end of the file.
    Appended,
}

/// Where the raw image's data lies.
struct RawGeometry {
    width: usize,
    height: usize,
    bits: u32,
    /// (top, left) of the active area.
    origin: (usize, usize),
    /// Strips: (rows per strip, offsets, byte counts); tiles: (tile width, tile length, offsets,
    /// byte counts).
    data: DataLayout,
}

enum DataLayout {
    Strips { rows: usize, offsets: Vec<u64>, counts: Vec<u64> },
    Tiles { width: usize, length: usize, offsets: Vec<u64>, counts: Vec<u64> },
}

/// The input DNG with `pixels` (the active area, as [`super::read_dng`] returns it) as its raw
/// image, `iso` as its ISO and `profile` (per CFA position of `layout`, normalised to its levels)
/// as its NoiseProfile. `decode_full` decodes the input's whole raw image (masked areas
/// included); it is called only when the pixels cannot be written over the stored ones and the
/// active area is not the whole image.
pub(crate) fn derive(
    mut out: Vec<u8>,
    layout: &SensorLayout,
    pixels: ArrayView2<'_, u16>,
    iso: u32,
    profile: Option<&NoiseProfile>,
    decode_full: impl FnOnce(&[u8]) -> Result<Vec<u16>, String>,
) -> Result<(Vec<u8>, PixelMode), String> {
    let input: &[u8] = &out;
    let s = Structure::parse(input)?;
    let o = s.order;
    let raw = s.raw_dir(input).ok_or("the template has no full-resolution CFA raw image")?;
    let geo = geometry(&s, input, raw)?;
    let (ah, aw) = pixels.dim();
    if (aw as u32, ah as u32) != (layout.width, layout.height) {
        return Err(format!(
            "the pixel array is {aw}×{ah} but the template's active area is {}×{}",
            layout.width, layout.height
        ));
    }
    if geo.origin.0 + ah > geo.height || geo.origin.1 + aw > geo.width {
        return Err(format!("the template's active area does not fit its {}×{} raw image", geo.width, geo.height));
    }
    let mode = pixel_mode(&s, input, raw, &geo, pixels);
    let planes: Vec<u64> =
        s.uints(input, raw, Tag::CfaPlaneColor).filter(|p| !p.is_empty() && p.len() <= 4).unwrap_or(vec![0, 1, 2]);
    let id = match pixels.as_slice() {
        Some(sl) => new_unique_id(&s, input, iso, sl.iter().step_by(UNIQUE_ID_STEP).copied()),
        None => new_unique_id(&s, input, iso, pixels.iter().step_by(UNIQUE_ID_STEP).copied()),
    };
    let mut edits = Edits::default();

    // --- Pixels.
    match mode {
        PixelMode::InPlace16 => write_16(&mut out, o, &geo, pixels),
        PixelMode::InPlacePacked(bits) => write_packed(&mut out, &geo, bits, pixels),
        PixelMode::Appended => {
            let (w, h) = (geo.width, geo.height);
            let full: Vec<u16> = if geo.origin == (0, 0) && (aw, ah) == (w, h) {
                pixels.iter().copied().collect()
            } else {
                let mut full = decode_full(&out)?;
                if full.len() < w * h {
                    return Err(format!("the template's raw image decodes to {} samples, not {w}×{h}", full.len()));
                }
                full.truncate(w * h);
                for (y, row) in pixels.rows().into_iter().enumerate() {
                    let at = (geo.origin.0 + y) * w + geo.origin.1;
                    for (d, &v) in full[at..at + aw].iter_mut().zip(row.iter()) {
                        *d = v;
                    }
                }
                full
            };
            let rows = ((1 << 20) / (2 * w)).clamp(1, h);
            let mut offsets = Vec::new();
            let mut counts = Vec::new();
            for chunk in full.chunks(rows * w) {
                align(&mut out);
                offsets.push(pos(&out)?);
                counts.push((chunk.len() * 2) as u32);
                out.reserve(chunk.len() * 2);
                for &v in chunk {
                    out.extend_from_slice(&o.b16(v));
                }
            }
            edits.set(raw, Tag::Compression, SHORT, 1, shorts(o, &[1]));
            edits.set(raw, Tag::BitsPerSample, SHORT, 1, shorts(o, &[16]));
            edits.set(raw, Tag::StripOffsets, LONG, offsets.len() as u32, longs(o, &offsets));
            edits.set(raw, Tag::StripByteCounts, LONG, counts.len() as u32, longs(o, &counts));
            edits.set(raw, Tag::RowsPerStrip, LONG, 1, longs(o, &[rows as u32]));
            for t in [
                Tag::TileWidth,
                Tag::TileLength,
                Tag::TileOffsets,
                Tag::TileByteCounts,
                Tag::Predictor,
                Tag::JpegTables,
                Tag::LinearizationTable,
                Tag::RowInterleaveFactor,
                Tag::ColumnInterleaveFactor,
                Tag::JxlDistance,
                Tag::JxlEffort,
                Tag::JxlDecodeSpeed,
            ] {
                edits.remove(raw, t);
            }
        }
    }

    metadata_edits(&s, raw, layout, iso, profile, &planes, id, &mut edits);
    apply(&s, &mut out, &edits)?;
    Ok((out, mode))
}

/// The tag edits every derived DNG gets: the ISO, the NoiseProfile (or none), the raw digests
/// dropped and the raw data ID changed.
fn metadata_edits(
    s: &Structure,
    raw: usize,
    layout: &SensorLayout,
    iso: u32,
    profile: Option<&NoiseProfile>,
    planes: &[u64],
    id: [u8; 16],
    edits: &mut Edits,
) {
    let o = s.order;
    // --- ISO.
    let iso_tags = [Tag::IsoSpeedRatings, Tag::StandardOutputSensitivity, Tag::RecommendedExposureIndex, Tag::IsoSpeed];
    let mut has_iso = false;
    for d in 0..s.dirs.len() {
        for t in iso_tags {
            let Some(e) = s.entry(d, t) else { continue };
            has_iso |= t == Tag::IsoSpeedRatings;
            let n = e.count.max(1) as usize;
            match FieldType::from_code(e.ty) {
                Some(FieldType::Short) => edits.set(d, t, SHORT, n as u32, shorts(o, &vec![iso.min(65535) as u16; n])),
                _ => edits.set(d, t, LONG, n as u32, longs(o, &vec![iso; n])),
            }
        }
        if iso > 65535 && s.entry(d, Tag::IsoSpeedRatings).is_some() {
            if s.entry(d, Tag::IsoSpeed).is_none() {
                edits.set(d, Tag::IsoSpeed, LONG, 1, longs(o, &[iso]));
            }
            if s.entry(d, Tag::SensitivityType).is_none() {
                edits.set(d, Tag::SensitivityType, SHORT, 1, shorts(o, &[3]));
            }
        }
    }
    if !has_iso {
        let exif = s.dirs.iter().flat_map(|d| &d.children).find(|(t, _)| *t == Tag::ExifIfd.to_u16()).map(|&(_, c)| c);
        let d = exif.unwrap_or(s.chain[0]);
        edits.set(d, Tag::IsoSpeedRatings, SHORT, 1, shorts(o, &[iso.min(65535) as u16]));
        if iso > 65535 {
            edits.set(d, Tag::IsoSpeed, LONG, 1, longs(o, &[iso]));
            edits.set(d, Tag::SensitivityType, SHORT, 1, shorts(o, &[3]));
        }
    }

    // --- NoiseProfile, digests, raw data ID.
    let profile_pairs = profile.map(|p| plane_pairs(p, layout, planes));
    for d in 0..s.dirs.len() {
        if d == raw
            && let Some(pairs) = &profile_pairs
        {
            edits.set(d, Tag::NoiseProfile, FieldType::Double.code(), pairs.len() as u32, doubles(o, pairs));
        } else if s.entry(d, Tag::NoiseProfile).is_some() {
            edits.remove(d, Tag::NoiseProfile);
        }
        for t in [Tag::RawImageDigest, Tag::NewRawImageDigest] {
            if s.entry(d, t).is_some() {
                edits.remove(d, t);
            }
        }
        if let Some(e) = s.entry(d, Tag::RawDataUniqueId)
            && e.count == 16
            && matches!(FieldType::from_code(e.ty), Some(FieldType::Byte | FieldType::Undefined))
        {
            edits.set(d, Tag::RawDataUniqueId, e.ty, 16, id.to_vec());
        }
    }
}

/// NoiseProfile pairs `[S₀, O₀, S₁, O₁, …]` per colour plane (CFAPlaneColor order): the mean of the
/// positions of that colour.
fn plane_pairs(p: &NoiseProfile, layout: &SensorLayout, planes: &[u64]) -> Vec<f64> {
    let colors = layout.cfa.colors();
    let code = |c: CfaColor| match c {
        CfaColor::Red => 0u64,
        CfaColor::Green => 1,
        CfaColor::Blue => 2,
    };
    let mut out = Vec::with_capacity(2 * planes.len());
    for &plane in planes {
        let mut pos: Vec<usize> = (0..POSITIONS).filter(|&q| code(colors[q]) == plane).collect();
        if pos.is_empty() {
            pos = (0..POSITIONS).collect();
        }
        let n = pos.len() as f64;
        out.push(pos.iter().map(|&q| p.scale(q)).sum::<f64>() / n);
        out.push(pos.iter().map(|&q| p.offset(q)).sum::<f64>() / n);
    }
    out
}

/// Every this many pixels (in row-major order of the active area, from the first) one goes into
/// the new `RawDataUniqueID`.
pub(crate) const UNIQUE_ID_STEP: usize = 997;

/// A new `RawDataUniqueID`: a hash of the old one, the ISO and a sample of the new pixels (those
/// at row-major indices that are multiples of [`UNIQUE_ID_STEP`], in order).
fn new_unique_id(s: &Structure, input: &[u8], iso: u32, sampled: impl Iterator<Item = u16>) -> [u8; 16] {
    let old = s.dirs.iter().enumerate().find_map(|(d, _)| {
        let e = s.entry(d, Tag::RawDataUniqueId)?;
        s.bytes(input, e).map(<[u8]>::to_vec)
    });
    let mut h1: u64 = 0xcbf2_9ce4_8422_2325;
    let mut h2: u64 = 0x6c62_272e_07bb_0142;
    let mut feed = |b: u8| {
        h1 = (h1 ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3);
        h2 = (h2 ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3).rotate_left(7);
    };
    old.unwrap_or_default().into_iter().chain(iso.to_le_bytes()).for_each(&mut feed);
    sampled.flat_map(|v| v.to_le_bytes()).for_each(&mut feed);
    let mut id = [0u8; 16];
    id[..8].copy_from_slice(&h1.to_be_bytes());
    id[8..].copy_from_slice(&h2.to_be_bytes());
    id
}

fn geometry(s: &Structure, buf: &[u8], raw: usize) -> Result<RawGeometry, String> {
    let width = s.uint(buf, raw, Tag::ImageWidth).ok_or("the raw image has no ImageWidth")? as usize;
    let height = s.uint(buf, raw, Tag::ImageLength).ok_or("the raw image has no ImageLength")? as usize;
    let bits = s.uint(buf, raw, Tag::BitsPerSample).unwrap_or(1) as u32;
    let origin = match s.uints(buf, raw, Tag::ActiveArea) {
        Some(a) if a.len() == 4 => (a[0] as usize, a[1] as usize),
        _ => match s.entry(raw, Tag::ActiveArea) {
            // ActiveArea stored as something else than SHORT/LONG: the reader's numbers.
            Some(_) => return Err("the template's ActiveArea is not a list of 4 integers".into()),
            None => (0, 0),
        },
    };
    let data = if s.entry(raw, Tag::StripOffsets).is_some() {
        DataLayout::Strips {
            rows: s.uint(buf, raw, Tag::RowsPerStrip).map_or(height, |r| (r as usize).clamp(1, height.max(1))),
            offsets: s.uints(buf, raw, Tag::StripOffsets).unwrap_or_default(),
            counts: s.uints(buf, raw, Tag::StripByteCounts).unwrap_or_default(),
        }
    } else {
        DataLayout::Tiles {
            width: s.uint(buf, raw, Tag::TileWidth).unwrap_or(0) as usize,
            length: s.uint(buf, raw, Tag::TileLength).unwrap_or(0) as usize,
            offsets: s.uints(buf, raw, Tag::TileOffsets).unwrap_or_default(),
            counts: s.uints(buf, raw, Tag::TileByteCounts).unwrap_or_default(),
        }
    };
    Ok(RawGeometry { width, height, bits, origin, data })
}

/// The active area of an uncompressed 16-bit raw image (strips or tiles), read straight from the
/// file's bytes: the samples a decoder gives, without decoding the whole image and cropping it.
/// `None` for any other storage (or data the file does not hold), left to the decoder.
pub(crate) fn read_active_16(
    buf: &[u8],
    (width, height): (usize, usize),
    (top, left, bottom, right): (usize, usize, usize, usize),
) -> Option<Array2<u16>> {
    let s = Structure::parse(buf).ok()?;
    let raw = s.raw_dir(buf)?;
    let g = geometry(&s, buf, raw).ok()?;
    if (g.width, g.height) != (width, height)
        || g.origin != (top, left)
        || g.bits != 16
        || !plain(&s, buf, raw)
        || stored_fits(buf, &g) != Some(true)
    {
        return None;
    }
    let (ah, aw) = (bottom - top, right - left);
    let mut out = vec![0u16; ah * aw];
    let big = s.order.big;
    let get = |dst: &mut [u16], src: &[u8]| {
        if big {
            for (d, c) in dst.iter_mut().zip(src.chunks_exact(2)) {
                *d = u16::from_be_bytes([c[0], c[1]]);
            }
        } else {
            for (d, c) in dst.iter_mut().zip(src.chunks_exact(2)) {
                *d = u16::from_le_bytes([c[0], c[1]]);
            }
        }
    };
    out.par_chunks_mut(aw.max(1)).enumerate().for_each(|(y, row)| {
        let fy = top + y;
        match &g.data {
            DataLayout::Strips { rows, offsets, .. } => {
                let at = offsets[fy / rows] as usize + ((fy % rows) * g.width + left) * 2;
                get(row, &buf[at..at + 2 * aw]);
            }
            DataLayout::Tiles { width: tw, length: tl, offsets, .. } => {
                let across = g.width.div_ceil(*tw);
                let mut x = left;
                while x < right {
                    let tx = x / tw;
                    let stop = ((tx + 1) * tw).min(right);
                    let at = offsets[(fy / tl) * across + tx] as usize + ((fy % tl) * tw + (x - tx * tw)) * 2;
                    get(&mut row[x - left..stop - left], &buf[at..at + 2 * (stop - x)]);
                    x = stop;
                }
            }
        }
    });
    Array2::from_shape_vec((ah, aw), out).ok()
}

/// The active area of uncompressed 16-bit data stored in the host's byte order, in strips that
/// follow each other in the file, as a view of the file's bytes: no copy. `None` for any other
/// storage (or when the bytes are not 2-aligned in memory).
pub(crate) fn active_view(buf: &[u8], (ah, aw): (usize, usize)) -> Option<ArrayView2<'_, u16>> {
    let s = Structure::parse(buf).ok()?;
    let raw = s.raw_dir(buf)?;
    let g = geometry(&s, buf, raw).ok()?;
    let DataLayout::Strips { rows, offsets, .. } = &g.data else { return None };
    let host_big = cfg!(target_endian = "big");
    if g.bits != 16 || s.order.big != host_big || !plain(&s, buf, raw) || stored_fits(buf, &g) != Some(true) {
        return None;
    }
    let (top, left) = g.origin;
    if ah == 0 || aw == 0 || top + ah > g.height || left + aw > g.width {
        return None;
    }
    let strip = (rows * g.width * 2) as u64;
    if offsets.windows(2).any(|w| w[1] != w[0] + strip) {
        return None;
    }
    let base = offsets[0] as usize + (top * g.width + left) * 2;
    let len = ((ah - 1) * g.width + aw) * 2;
    let samples: &[u16] = bytemuck::try_cast_slice(buf.get(base..base + len)?).ok()?;
    ArrayView2::from_shape((ah, aw).strides((g.width, 1)), samples).ok()
}

/// A derived DNG written as its pixels are drawn, when the input stores its raw image as
/// uncompressed 16-bit strips (any byte order, any strip order): the bytes
/// [`derive`] would give, made in parts: the input's bytes around the stored rows of the active
/// area ([`Self::gaps`]), those rows band by band ([`Self::encode`]), then the tag edits
/// ([`Self::finish`]).
#[derive(Debug)]
pub(crate) struct StreamPlan {
    s: Structure,
    raw: usize,
    /// Samples per stored row.
    width: usize,
    origin: (usize, usize),
    /// (height, width) of the active area.
    active: (usize, usize),
    rows_per_strip: usize,
    offsets: Vec<u64>,
    /// The file's byte ranges `[start, end)` the stored rows of the active area cover, sorted,
    /// touching ranges merged.
    rows: Vec<(usize, usize)>,
}

/// The [`StreamPlan`] of an input whose active area is `(ah, aw)`, or `None` when its raw image
/// is stored otherwise (or its IFDs lie among the stored rows): [`derive`] writes those.
pub(crate) fn stream_plan(buf: &[u8], (ah, aw): (usize, usize)) -> Option<StreamPlan> {
    let s = Structure::parse(buf).ok()?;
    let raw = s.raw_dir(buf)?;
    let g = geometry(&s, buf, raw).ok()?;
    let (top, left) = g.origin;
    if ah == 0 || aw == 0 || top + ah > g.height || left + aw > g.width {
        return None;
    }
    if g.bits != 16 || !plain(&s, buf, raw) || stored_fits(buf, &g) != Some(true) {
        return None;
    }
    let DataLayout::Strips { rows: rows_per_strip, offsets, .. } = g.data else { return None };
    let row_bytes = g.width * 2;
    let mut rows: Vec<(usize, usize)> = Vec::new();
    for fy in top..top + ah {
        let at = offsets[fy / rows_per_strip] as usize + (fy % rows_per_strip) * row_bytes;
        match rows.last_mut() {
            Some(last) if last.1 == at => last.1 += row_bytes,
            _ => rows.push((at, at + row_bytes)),
        }
    }
    rows.sort_unstable();
    let mut merged: Vec<(usize, usize)> = Vec::with_capacity(rows.len());
    for r in rows {
        match merged.last_mut() {
            // Rows stored over each other: left to `derive`.
            Some(last) if r.0 < last.1 => return None,
            Some(last) if r.0 == last.1 => last.1 = r.1,
            _ => merged.push(r),
        }
    }
    let overlaps = |a: usize, b: usize| {
        let i = merged.partition_point(|r| r.1 <= a);
        merged.get(i).is_some_and(|r| r.0 < b)
    };
    if s.dirs.iter().any(|d| overlaps(d.offset, d.offset + 2 + 12 * d.entries.len() + 4)) {
        return None;
    }
    Some(StreamPlan {
        raw,
        width: g.width,
        origin: g.origin,
        active: (ah, aw),
        rows_per_strip,
        offsets,
        rows: merged,
        s,
    })
}

impl StreamPlan {
    /// The byte ranges `[start, end)` of the input (of `len` bytes) that the output keeps as they
    /// are (before the tag edits): everything but the stored rows of the active area.
    pub(crate) fn gaps(&self, len: usize) -> Vec<(usize, usize)> {
        let mut out = Vec::new();
        let mut at = 0;
        for &(a, b) in &self.rows {
            if a > at {
                out.push((at, a));
            }
            at = b;
        }
        if len > at {
            out.push((at, len));
        }
        out
    }

    /// The stored rows of active rows `y0 ..` (`samples`: whole rows of the active area) as the
    /// output holds them, handed to `write(file offset, bytes)` run by run (rows stored one after
    /// the other form one run). Masked columns keep the input's bytes. `scratch` is reused.
    pub(crate) fn encode<E>(
        &self,
        input: &[u8],
        y0: usize,
        samples: &[u16],
        scratch: &mut Vec<u8>,
        mut write: impl FnMut(u64, &[u8]) -> Result<(), E>,
    ) -> Result<(), E> {
        let (_, aw) = self.active;
        let (top, left) = self.origin;
        let row_bytes = self.width * 2;
        let n = samples.len() / aw;
        let at = |y: usize| {
            let fy = top + y;
            self.offsets[fy / self.rows_per_strip] as usize + (fy % self.rows_per_strip) * row_bytes
        };
        let host = self.s.order.big == cfg!(target_endian = "big");
        let mut y = 0;
        while y < n {
            // A run: rows stored one after the other.
            let start = at(y0 + y);
            let mut end = y + 1;
            while end < n && at(y0 + end) == start + (end - y) * row_bytes {
                end += 1;
            }
            let rows = &samples[y * aw..end * aw];
            if host && aw == self.width {
                write(start as u64, bytemuck::cast_slice(rows))?;
            } else {
                scratch.clear();
                scratch.extend_from_slice(&input[start..start + (end - y) * row_bytes]);
                for (dst, src) in scratch.chunks_exact_mut(row_bytes).zip(rows.chunks_exact(aw)) {
                    let dst = &mut dst[left * 2..(left + aw) * 2];
                    if self.s.order.big {
                        for (d, &v) in dst.chunks_exact_mut(2).zip(src) {
                            d.copy_from_slice(&v.to_be_bytes());
                        }
                    } else {
                        for (d, &v) in dst.chunks_exact_mut(2).zip(src) {
                            d.copy_from_slice(&v.to_le_bytes());
                        }
                    }
                }
                write(start as u64, scratch)?;
            }
            y = end;
        }
        Ok(())
    }

    /// The tag edits, once every row is written: overwrites of the output's bytes, to be applied
    /// in order after the rows, and the bytes appended after the input's. `sampled` are the new
    /// pixels at row-major indices that are multiples of [`UNIQUE_ID_STEP`], in order.
    #[allow(clippy::type_complexity)]
    pub(crate) fn finish(
        &self,
        input: &[u8],
        layout: &SensorLayout,
        iso: u32,
        profile: Option<&NoiseProfile>,
        sampled: impl Iterator<Item = u16>,
    ) -> Result<(Vec<(usize, Vec<u8>)>, Vec<u8>), String> {
        let (ah, aw) = self.active;
        if (aw as u32, ah as u32) != (layout.width, layout.height) {
            return Err(format!(
                "the pixel array is {aw}×{ah} but the template's active area is {}×{}",
                layout.width, layout.height
            ));
        }
        let s = &self.s;
        let planes: Vec<u64> = s
            .uints(input, self.raw, Tag::CfaPlaneColor)
            .filter(|p| !p.is_empty() && p.len() <= 4)
            .unwrap_or(vec![0, 1, 2]);
        let id = new_unique_id(s, input, iso, sampled);
        let mut edits = Edits::default();
        metadata_edits(s, self.raw, layout, iso, profile, &planes, id, &mut edits);
        let mut out = Overlay { base: input, patches: Vec::new(), tail: Vec::new() };
        apply(s, &mut out, &edits)?;
        Ok((out.patches, out.tail))
    }
}

/// Uncompressed single-sample integer data, stored as it reads (no linearization, no
/// interleaving).
fn plain(s: &Structure, buf: &[u8], raw: usize) -> bool {
    s.uint(buf, raw, Tag::Compression).unwrap_or(1) == 1
        && s.uint(buf, raw, Tag::SamplesPerPixel).unwrap_or(1) == 1
        && s.uint(buf, raw, Tag::SampleFormat).unwrap_or(1) == 1
        && s.entry(raw, Tag::LinearizationTable).is_none()
        && s.uint(buf, raw, Tag::RowInterleaveFactor).unwrap_or(1) == 1
        && s.uint(buf, raw, Tag::ColumnInterleaveFactor).unwrap_or(1) == 1
}

/// Whether every strip or tile of 16-bit data is where the file says and as long as it must be
/// (`None` for other bit depths).
fn stored_fits(buf: &[u8], g: &RawGeometry) -> Option<bool> {
    if g.bits != 16 || g.width == 0 || g.height == 0 {
        return None;
    }
    let fits = |offsets: &[u64], counts: &[u64], n: usize, need: &dyn Fn(usize) -> u64| {
        offsets.len() == n
            && counts.len() == n
            && (0..n).all(|i| counts[i] >= need(i) && offsets[i].saturating_add(need(i)) <= buf.len() as u64)
    };
    match &g.data {
        DataLayout::Strips { rows, offsets, counts } => {
            let n = g.height.div_ceil(*rows);
            Some(fits(offsets, counts, n, &|i| ((*rows).min(g.height - i * rows) * g.width * 2) as u64))
        }
        DataLayout::Tiles { width, length, offsets, counts } if *width > 0 && *length > 0 => {
            let n = g.width.div_ceil(*width) * g.height.div_ceil(*length);
            Some(fits(offsets, counts, n, &|_| (width * length * 2) as u64))
        }
        DataLayout::Tiles { .. } => Some(false),
    }
}

/// Whether the new pixels can be written over the stored ones.
fn pixel_mode(s: &Structure, buf: &[u8], raw: usize, g: &RawGeometry, pixels: ArrayView2<'_, u16>) -> PixelMode {
    let plain = plain(s, buf, raw);
    if !plain || g.width == 0 || g.height == 0 {
        return PixelMode::Appended;
    }
    let fits = |offsets: &[u64], counts: &[u64], n: usize, need: &dyn Fn(usize) -> u64| {
        offsets.len() == n
            && counts.len() == n
            && (0..n).all(|i| counts[i] >= need(i) && offsets[i].saturating_add(need(i)) <= buf.len() as u64)
    };
    match (&g.data, g.bits) {
        (_, 16) => {
            if stored_fits(buf, g) == Some(true) {
                PixelMode::InPlace16
            } else {
                PixelMode::Appended
            }
        }
        (DataLayout::Strips { rows, offsets, counts }, bits) if (10..16).contains(&bits) => {
            let max = (1u32 << bits) - 1;
            let row_bytes = g.width * bits as usize / 8;
            let n = g.height.div_ceil(*rows);
            let need = |i: usize| ((*rows).min(g.height - i * rows) * row_bytes) as u64;
            if (g.width * bits as usize).is_multiple_of(8)
                && fits(offsets, counts, n, &need)
                && pixels.iter().all(|&v| u32::from(v) <= max)
            {
                PixelMode::InPlacePacked(bits)
            } else {
                PixelMode::Appended
            }
        }
        _ => PixelMode::Appended,
    }
}

fn write_16(out: &mut [u8], o: Order, g: &RawGeometry, pixels: ArrayView2<'_, u16>) {
    let (top, left) = g.origin;
    let put = |dst: &mut [u8], src: &[u16]| {
        if o.big {
            for (d, &v) in dst.chunks_exact_mut(2).zip(src) {
                d.copy_from_slice(&v.to_be_bytes());
            }
        } else {
            for (d, &v) in dst.chunks_exact_mut(2).zip(src) {
                d.copy_from_slice(&v.to_le_bytes());
            }
        }
    };
    // Strips that follow each other hold the rows in order: rows are written in parallel.
    if let DataLayout::Strips { rows, offsets, .. } = &g.data {
        let strip = (rows * g.width * 2) as u64;
        let (ah, aw) = pixels.dim();
        let start = offsets.first().map_or(0, |&o| o as usize) + top * g.width * 2;
        let len = ah * g.width * 2;
        if aw > 0
            && offsets.windows(2).all(|w| w[1] == w[0] + strip)
            && start.checked_add(len).is_some_and(|end| end <= out.len())
        {
            out[start..start + len].par_chunks_mut(g.width * 2).enumerate().for_each(|(y, dst)| {
                let dst = &mut dst[left * 2..(left + aw) * 2];
                let row = pixels.row(y);
                match row.as_slice() {
                    Some(src) => put(dst, src),
                    None => put(dst, &row.to_vec()),
                }
            });
            return;
        }
    }
    let mut scratch = Vec::new();
    for (y, row) in pixels.rows().into_iter().enumerate() {
        let src: &[u16] = match row.as_slice() {
            Some(s) => s,
            None => {
                scratch.clear();
                scratch.extend(row.iter().copied());
                &scratch
            }
        };
        let fy = top + y;
        match &g.data {
            DataLayout::Strips { rows, offsets, .. } => {
                let at = offsets[fy / rows] as usize + ((fy % rows) * g.width + left) * 2;
                put(&mut out[at..at + 2 * src.len()], src);
            }
            DataLayout::Tiles { width: tw, length: tl, offsets, .. } => {
                let across = g.width.div_ceil(*tw);
                let mut x = left;
                let end = left + src.len();
                while x < end {
                    let tx = x / tw;
                    let stop = ((tx + 1) * tw).min(end);
                    let at = offsets[(fy / tl) * across + tx] as usize + ((fy % tl) * tw + (x - tx * tw)) * 2;
                    put(&mut out[at..at + 2 * (stop - x)], &src[x - left..stop - left]);
                    x = stop;
                }
            }
        }
    }
}

fn write_packed(out: &mut [u8], g: &RawGeometry, bits: u32, pixels: ArrayView2<'_, u16>) {
    let DataLayout::Strips { rows, offsets, .. } = &g.data else { return };
    let (top, left) = g.origin;
    let row_bytes = g.width * bits as usize / 8;
    for (y, row) in pixels.rows().into_iter().enumerate() {
        let fy = top + y;
        let at = offsets[fy / rows] as usize + (fy % rows) * row_bytes;
        let dst = &mut out[at..at + row_bytes];
        let mut full = unpack_msb(dst, bits, g.width);
        for (d, &v) in full[left..left + row.len()].iter_mut().zip(row.iter()) {
            *d = v;
        }
        dst.copy_from_slice(&pack_msb(&full, bits));
    }
}

/// `n` samples of `bits` bits, MSB first.
fn unpack_msb(b: &[u8], bits: u32, n: usize) -> Vec<u16> {
    let mut out = Vec::with_capacity(n);
    let mut acc: u64 = 0;
    let mut have = 0u32;
    let mask = (1u64 << bits) - 1;
    let mut bytes = b.iter();
    while out.len() < n {
        while have < bits {
            acc = (acc << 8) | u64::from(*bytes.next().unwrap_or(&0));
            have += 8;
        }
        have -= bits;
        out.push(((acc >> have) & mask) as u16);
    }
    out
}

fn align(out: &mut impl Out) {
    while !out.len().is_multiple_of(4) {
        out.push(&[0]);
    }
}

fn pos(out: &impl Out) -> Result<u32, String> {
    u32::try_from(out.len()).map_err(|_| "the DNG would exceed 4 GiB".to_string())
}

/// What [`apply`] edits: the output's bytes (the input's, pixels written), or the input with
/// the edits kept aside ([`Overlay`]).
trait Out {
    fn len(&self) -> usize;
    /// The 4 bytes at `at` (`None` past the end).
    fn get4(&self, at: usize) -> Option<[u8; 4]>;
    /// Overwrites bytes inside the output.
    fn put(&mut self, at: usize, bytes: &[u8]);
    /// Appends bytes.
    fn push(&mut self, bytes: &[u8]);
}

impl Out for Vec<u8> {
    fn len(&self) -> usize {
        <[u8]>::len(self)
    }

    fn get4(&self, at: usize) -> Option<[u8; 4]> {
        self.get(at..at.checked_add(4)?)?.try_into().ok()
    }

    fn put(&mut self, at: usize, bytes: &[u8]) {
        self[at..at + bytes.len()].copy_from_slice(bytes);
    }

    fn push(&mut self, bytes: &[u8]) {
        self.extend_from_slice(bytes);
    }
}

/// The input's bytes with the edits [`apply`] makes kept aside: overwrites of the input's bytes
/// (to be applied in order) and what is appended after it. Reads see the edits.
#[derive(Debug)]
struct Overlay<'a> {
    base: &'a [u8],
    patches: Vec<(usize, Vec<u8>)>,
    tail: Vec<u8>,
}

impl Out for Overlay<'_> {
    fn len(&self) -> usize {
        self.base.len() + self.tail.len()
    }

    fn get4(&self, at: usize) -> Option<[u8; 4]> {
        let n = self.base.len();
        let mut b = [0u8; 4];
        for (k, v) in b.iter_mut().enumerate() {
            let i = at.checked_add(k)?;
            *v = if i < n { self.base[i] } else { *self.tail.get(i - n)? };
        }
        for (p, bytes) in &self.patches {
            for (k, v) in b.iter_mut().enumerate() {
                if let Some(x) = (at + k).checked_sub(*p).and_then(|i| bytes.get(i)) {
                    *v = *x;
                }
            }
        }
        Some(b)
    }

    fn put(&mut self, at: usize, bytes: &[u8]) {
        let n = self.base.len();
        let inside = n.saturating_sub(at).min(bytes.len());
        if inside > 0 {
            self.patches.push((at, bytes[..inside].to_vec()));
        }
        for (k, &x) in bytes.iter().enumerate().skip(inside) {
            self.tail[at + k - n] = x;
        }
    }

    fn push(&mut self, bytes: &[u8]) {
        self.tail.extend_from_slice(bytes);
    }
}

/// Applies the edits: in place where every changed tag keeps its type and size, else by writing
/// the directory again at the end and patching the pointer to it. Directories are visited from
/// the last found to the first, so a directory is rewritten after the ones it points to have
/// patched their pointers inside it.
fn apply(s: &Structure, out: &mut impl Out, edits: &Edits) -> Result<(), String> {
    let o = s.order;
    for (&d, changes) in edits.0.iter().rev() {
        let dir = &s.dirs[d];
        let n = dir.entries.len();
        // Entries as they are now (pointers inside may have been patched).
        let current: Vec<Entry> = (0..n)
            .map(|i| {
                let e = dir.offset + 2 + 12 * i;
                Entry { field: out.get4(e + 8).unwrap_or([0; 4]), ..dir.entries[i] }
            })
            .collect();
        let find = |tag: u16| current.iter().position(|e| e.tag == tag);
        let in_place = changes.iter().all(|(&tag, edit)| match (edit, find(tag)) {
            (Edit::Remove, None) => true,
            (Edit::Remove, Some(_)) => false,
            (Edit::Set { .. }, None) => false,
            (Edit::Set { ty, count, bytes }, Some(i)) => {
                let e = &current[i];
                e.ty == *ty
                    && e.count == *count
                    && (bytes.len() <= 4
                        || o.u32(&e.field, 0)
                            .is_some_and(|off| (off as usize).saturating_add(bytes.len()) <= out.len()))
            }
        });
        if in_place {
            for (&tag, edit) in changes {
                let (Edit::Set { bytes, .. }, Some(i)) = (edit, find(tag)) else { continue };
                let at = if bytes.len() <= 4 {
                    dir.offset + 2 + 12 * i + 8
                } else {
                    o.u32(&current[i].field, 0).unwrap_or(0) as usize
                };
                out.put(at, bytes);
                if bytes.len() < 4 {
                    out.put(at + bytes.len(), &[0; 4][bytes.len()..]);
                }
            }
            continue;
        }
        let next = out.get4(dir.offset + 2 + 12 * n).and_then(|b| o.u32(&b, 0)).unwrap_or(0);
        let mut entries: BTreeMap<u16, Entry> = current.iter().map(|e| (e.tag, *e)).collect();
        for (&tag, edit) in changes {
            match edit {
                Edit::Remove => {
                    entries.remove(&tag);
                }
                Edit::Set { ty, count, bytes } => {
                    let mut field = [0u8; 4];
                    if bytes.len() <= 4 {
                        field[..bytes.len()].copy_from_slice(bytes);
                    } else {
                        align(out);
                        field = o.b32(pos(out)?);
                        out.push(bytes);
                    }
                    entries.insert(tag, Entry { tag, ty: *ty, count: *count, field });
                }
            }
        }
        align(out);
        let at = pos(out)?;
        out.push(&o.b16(u16::try_from(entries.len()).map_err(|_| "too many tags in one IFD")?));
        for e in entries.values() {
            out.push(&o.b16(e.tag));
            out.push(&o.b16(e.ty));
            out.push(&o.b32(e.count));
            out.push(&e.field);
        }
        out.push(&o.b32(next));
        out.put(dir.pointer_at, &o.b32(at));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packing_round_trips() {
        for bits in 10..16u32 {
            let v: Vec<u16> = (0..64).map(|i| ((i * 2654435761u64 as usize) as u32 % (1 << bits)) as u16).collect();
            assert_eq!(unpack_msb(&pack_msb(&v, bits), bits, v.len()), v, "{bits} bits");
        }
    }
}
