//! A small TIFF writer: IFD chains, sub-IFDs (SubIFDs, ExifIFD), strips or tiles, either byte order.
//!
//! [`super::write_dng`] writes its DNGs through it, and tests use it to lay out fixtures the way
//! other writers do (Android `DngCreator`: 16-bit strips in IFD0, ISO in IFD0; big-endian files;
//! tiles; packed 10/12-bit data; missing tags).

use std::collections::BTreeMap;

pub use super::ifd::FieldType;
pub use super::tags::{Tag, tag};

/// A tag's value, typed as TIFF stores it.
#[derive(Debug, Clone, PartialEq)]
pub enum TagValue {
    Byte(Vec<u8>),
    /// Written with a trailing NUL.
    Ascii(String),
    Short(Vec<u16>),
    Long(Vec<u32>),
    /// (numerator, denominator) pairs.
    Rational(Vec<(u32, u32)>),
    SRational(Vec<(i32, i32)>),
    Undefined(Vec<u8>),
    Float(Vec<f32>),
    Double(Vec<f64>),
}

impl TagValue {
    fn type_code(&self) -> u16 {
        let t = match self {
            Self::Byte(_) => FieldType::Byte,
            Self::Ascii(_) => FieldType::Ascii,
            Self::Short(_) => FieldType::Short,
            Self::Long(_) => FieldType::Long,
            Self::Rational(_) => FieldType::Rational,
            Self::Undefined(_) => FieldType::Undefined,
            Self::SRational(_) => FieldType::SRational,
            Self::Float(_) => FieldType::Float,
            Self::Double(_) => FieldType::Double,
        };
        t.code()
    }

    fn count(&self) -> usize {
        match self {
            Self::Byte(v) | Self::Undefined(v) => v.len(),
            Self::Ascii(s) => s.len() + 1,
            Self::Short(v) => v.len(),
            Self::Long(v) => v.len(),
            Self::Rational(v) => v.len(),
            Self::SRational(v) => v.len(),
            Self::Float(v) => v.len(),
            Self::Double(v) => v.len(),
        }
    }

    fn encode(&self, big: bool) -> Vec<u8> {
        let mut out = Vec::new();
        macro_rules! put {
            ($x:expr) => {
                if big { out.extend_from_slice(&$x.to_be_bytes()) } else { out.extend_from_slice(&$x.to_le_bytes()) }
            };
        }
        match self {
            Self::Byte(v) | Self::Undefined(v) => out.extend_from_slice(v),
            Self::Ascii(s) => {
                out.extend_from_slice(s.as_bytes());
                out.push(0);
            }
            Self::Short(v) => v.iter().for_each(|x| put!(x)),
            Self::Long(v) => v.iter().for_each(|x| put!(x)),
            Self::Rational(v) => v.iter().for_each(|(n, d)| {
                put!(n);
                put!(d);
            }),
            Self::SRational(v) => v.iter().for_each(|(n, d)| {
                put!(n);
                put!(d);
            }),
            Self::Float(v) => v.iter().for_each(|x| put!(x)),
            Self::Double(v) => v.iter().for_each(|x| put!(x)),
        }
        out
    }
}

/// Encoded image data of one IFD; the writer adds the offset/byte-count tags.
#[derive(Debug, Clone, PartialEq)]
pub enum ImageData {
    Strips { rows_per_strip: u32, strips: Vec<Vec<u8>> },
    Tiles { tile_width: u32, tile_length: u32, tiles: Vec<Vec<u8>> },
}

/// One image file directory.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Ifd {
    /// The entries, in tag-number order (as TIFF requires).
    pub entries: BTreeMap<Tag, TagValue>,
    /// Pointer tags (e.g. [`Tag::SubIfds`], [`Tag::ExifIfd`]) and the directories they point to.
    pub sub_ifds: BTreeMap<Tag, Vec<Ifd>>,
    pub image: Option<ImageData>,
}

impl Ifd {
    pub fn new() -> Self {
        Self::default()
    }

    pub fn set(&mut self, tag: Tag, value: TagValue) -> &mut Self {
        self.entries.insert(tag, value);
        self
    }

    pub fn remove(&mut self, tag: Tag) -> Option<TagValue> {
        self.entries.remove(&tag)
    }

    pub fn get(&self, tag: Tag) -> Option<&TagValue> {
        self.entries.get(&tag)
    }
}

/// A TIFF file: a chain of IFDs (IFD0 first).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct TiffBuilder {
    pub big_endian: bool,
    pub chain: Vec<Ifd>,
}

impl TiffBuilder {
    /// Serializes the file. Fails only if it would exceed 4 GiB or has no IFD.
    pub fn to_bytes(&self) -> Result<Vec<u8>, String> {
        if self.chain.is_empty() {
            return Err("a TIFF file needs at least one IFD".into());
        }
        let mut w = Writer { out: Vec::new(), big: self.big_endian };
        w.out.extend_from_slice(if self.big_endian { b"MM\0\x2a" } else { b"II\x2a\0" });
        w.out.extend_from_slice(&[0; 4]);
        let mut first = 0;
        let mut prev_next_slot: Option<usize> = None;
        for ifd in &self.chain {
            let (offset, next_slot) = w.ifd(ifd)?;
            match prev_next_slot {
                None => first = offset,
                Some(slot) => w.patch_u32(slot, offset),
            }
            prev_next_slot = Some(next_slot);
        }
        w.patch_u32(4, first);
        Ok(w.out)
    }
}

struct Writer {
    out: Vec<u8>,
    big: bool,
}

impl Writer {
    fn align(&mut self) {
        while !self.out.len().is_multiple_of(4) {
            self.out.push(0);
        }
    }

    fn pos(&self) -> Result<u32, String> {
        u32::try_from(self.out.len()).map_err(|_| "TIFF file would exceed 4 GiB".to_string())
    }

    fn put_u16(&mut self, v: u16) {
        self.out.extend_from_slice(&if self.big { v.to_be_bytes() } else { v.to_le_bytes() });
    }

    fn put_u32(&mut self, v: u32) {
        self.out.extend_from_slice(&if self.big { v.to_be_bytes() } else { v.to_le_bytes() });
    }

    fn patch_u32(&mut self, at: usize, v: u32) {
        let b = if self.big { v.to_be_bytes() } else { v.to_le_bytes() };
        self.out[at..at + 4].copy_from_slice(&b);
    }

    fn blobs(&mut self, blobs: &[Vec<u8>]) -> Result<(Vec<u32>, Vec<u32>), String> {
        let mut offsets = Vec::with_capacity(blobs.len());
        let mut counts = Vec::with_capacity(blobs.len());
        for b in blobs {
            self.align();
            offsets.push(self.pos()?);
            counts.push(u32::try_from(b.len()).map_err(|_| "a strip or tile exceeds 4 GiB".to_string())?);
            self.out.extend_from_slice(b);
        }
        Ok((offsets, counts))
    }

    /// Writes an IFD (its data first), returns its offset and the position of its next-IFD slot.
    fn ifd(&mut self, ifd: &Ifd) -> Result<(u32, usize), String> {
        let mut entries = ifd.entries.clone();
        match &ifd.image {
            None => {}
            Some(ImageData::Strips { rows_per_strip, strips }) => {
                let (off, cnt) = self.blobs(strips)?;
                entries.insert(Tag::StripOffsets, TagValue::Long(off));
                entries.insert(Tag::StripByteCounts, TagValue::Long(cnt));
                entries.insert(Tag::RowsPerStrip, TagValue::Long(vec![*rows_per_strip]));
            }
            Some(ImageData::Tiles { tile_width, tile_length, tiles }) => {
                let (off, cnt) = self.blobs(tiles)?;
                entries.insert(Tag::TileOffsets, TagValue::Long(off));
                entries.insert(Tag::TileByteCounts, TagValue::Long(cnt));
                entries.insert(Tag::TileWidth, TagValue::Long(vec![*tile_width]));
                entries.insert(Tag::TileLength, TagValue::Long(vec![*tile_length]));
            }
        }
        for (&t, subs) in &ifd.sub_ifds {
            let mut offsets = Vec::with_capacity(subs.len());
            for sub in subs {
                offsets.push(self.ifd(sub)?.0);
            }
            entries.insert(t, TagValue::Long(offsets));
        }
        // Out-of-line values, then the directory itself.
        let mut encoded: Vec<(u16, u16, u32, [u8; 4])> = Vec::with_capacity(entries.len());
        for (&t, v) in &entries {
            let t = t.to_u16();
            if v.count() == 0 {
                return Err(format!("tag {t} has an empty value"));
            }
            let bytes = v.encode(self.big);
            let count = u32::try_from(v.count()).map_err(|_| format!("tag {t} is too long"))?;
            let mut field = [0u8; 4];
            if bytes.len() <= 4 {
                field[..bytes.len()].copy_from_slice(&bytes);
            } else {
                self.align();
                let off = self.pos()?;
                self.out.extend_from_slice(&bytes);
                field = if self.big { off.to_be_bytes() } else { off.to_le_bytes() };
            }
            encoded.push((t, v.type_code(), count, field));
        }
        self.align();
        let offset = self.pos()?;
        let n = u16::try_from(encoded.len()).map_err(|_| "too many tags in one IFD".to_string())?;
        self.put_u16(n);
        for (t, ty, count, field) in encoded {
            self.put_u16(t);
            self.put_u16(ty);
            self.put_u32(count);
            self.out.extend_from_slice(&field);
        }
        let next_slot = self.out.len();
        self.put_u32(0);
        Ok((offset, next_slot))
    }
}

/// 16-bit samples in the file's byte order.
pub fn u16_bytes(samples: &[u16], big_endian: bool) -> Vec<u8> {
    let mut out = Vec::with_capacity(samples.len() * 2);
    for &s in samples {
        out.extend_from_slice(&if big_endian { s.to_be_bytes() } else { s.to_le_bytes() });
    }
    out
}

/// Samples packed MSB-first with `bits` bits each, continuous across rows (DNG packed 10/12/14-bit).
pub fn pack_msb(samples: &[u16], bits: u32) -> Vec<u8> {
    let mut out = Vec::with_capacity((samples.len() * bits as usize).div_ceil(8));
    let mut acc: u64 = 0;
    let mut n = 0u32;
    let mask = if bits >= 16 { u16::MAX } else { (1u16 << bits) - 1 };
    for &s in samples {
        acc = (acc << bits) | u64::from(s & mask);
        n += bits;
        while n >= 8 {
            n -= 8;
            out.push((acc >> n) as u8);
        }
        acc &= (1u64 << n) - 1;
    }
    if n > 0 {
        out.push((acc << (8 - n)) as u8);
    }
    out
}
