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

use ndarray::ArrayView2;
use noisecal_core::SensorLayout;
use noisecal_core::model::layout::{CfaColor, POSITIONS};
use noisecal_core::model::pack::NoiseProfile;

use super::ifd::{Entry, FieldType, Order, Structure, walk};
use super::raw_data::{DataLayout, RawGeometry, geometry, plain, stored_fits, write_16, write_packed};
use super::tags::Tag;

const SHORT: u16 = FieldType::Short as u16;
const LONG: u16 = FieldType::Long as u16;

/// A change to one tag of one directory.
#[derive(Debug, Clone)]
enum Edit {
    Set { ty: u16, count: u32, bytes: Vec<u8> },
    Remove,
}

#[derive(Default)]
pub(super) struct Edits(BTreeMap<usize, BTreeMap<u16, Edit>>);

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
    let s = walk(input)?;
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
pub(super) fn metadata_edits(
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
pub(super) fn plane_pairs(p: &NoiseProfile, layout: &SensorLayout, planes: &[u64]) -> Vec<f64> {
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
pub(super) fn new_unique_id(s: &Structure, input: &[u8], iso: u32, sampled: impl Iterator<Item = u16>) -> [u8; 16] {
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
pub(super) trait Out {
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
pub(super) struct Overlay<'a> {
    pub(super) base: &'a [u8],
    pub(super) patches: Vec<(usize, Vec<u8>)>,
    pub(super) tail: Vec<u8>,
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
pub(super) fn apply(s: &Structure, out: &mut impl Out, edits: &Edits) -> Result<(), String> {
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
