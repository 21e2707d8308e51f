//! The one walker of a TIFF file's directory structure, and the one table of TIFF field types.
//!
//! [`walk`] reads the header, then every IFD of the chain and, below each, the IFDs its SubIFDs
//! and ExifIFD entries point to (four levels at most), refusing what a reader must not trust: a
//! file that is not TIFF, an IFD loop or more than [`MAX_IFDS`] IFDs, an empty IFD or one that runs
//! past the file, and an entry whose value would be larger than the file. The reader checks a file
//! with it before rawler parses it (`guard.rs`, which adds where rawler itself goes) and hands the
//! walk on to read uncompressed samples in place (`raw_data.rs`); the editor of derived DNGs finds
//! the directories it patches with it (`edit.rs`).

use std::collections::HashSet;

use super::tags::Tag;

/// The most IFDs a file may hold (more is taken for corrupt links).
pub(crate) const MAX_IFDS: usize = 512;
/// How deep SubIFDs/ExifIFD pointers are followed below the chain.
const MAX_DEPTH: u32 = 4;
/// PhotometricInterpretation of a CFA raw image.
const PHOTOMETRIC_CFA: u64 = 32803;

/// A TIFF field type (TIFF 6.0 §2 and the IFD type of TIFF Technical Note 1).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FieldType {
    Byte = 1,
    Ascii = 2,
    Short = 3,
    Long = 4,
    Rational = 5,
    SByte = 6,
    Undefined = 7,
    SShort = 8,
    SLong = 9,
    SRational = 10,
    Float = 11,
    Double = 12,
    Ifd = 13,
}

impl FieldType {
    /// The type a stored code names (`None` for codes TIFF does not define).
    pub fn from_code(code: u16) -> Option<Self> {
        use FieldType::*;
        Some(match code {
            1 => Byte,
            2 => Ascii,
            3 => Short,
            4 => Long,
            5 => Rational,
            6 => SByte,
            7 => Undefined,
            8 => SShort,
            9 => SLong,
            10 => SRational,
            11 => Float,
            12 => Double,
            13 => Ifd,
            _ => return None,
        })
    }

    /// The code stored in an IFD entry.
    pub fn code(self) -> u16 {
        self as u16
    }

    /// Bytes per value.
    pub fn size(self) -> usize {
        use FieldType::*;
        match self {
            Byte | Ascii | SByte | Undefined => 1,
            Short | SShort => 2,
            Long | SLong | Float | Ifd => 4,
            Rational | SRational | Double => 8,
        }
    }

    /// Bytes per value of a stored code; a code TIFF does not define counts one byte a value
    /// (what a reader that skips it would allocate at least).
    pub fn size_of_code(code: u16) -> usize {
        Self::from_code(code).map_or(1, Self::size)
    }
}

/// Byte order of a TIFF file.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Order {
    pub big: bool,
}

impl Order {
    pub fn u16(self, b: &[u8], at: usize) -> Option<u16> {
        let x: [u8; 2] = b.get(at..at.checked_add(2)?)?.try_into().ok()?;
        Some(if self.big { u16::from_be_bytes(x) } else { u16::from_le_bytes(x) })
    }

    pub fn u32(self, b: &[u8], at: usize) -> Option<u32> {
        let x: [u8; 4] = b.get(at..at.checked_add(4)?)?.try_into().ok()?;
        Some(if self.big { u32::from_be_bytes(x) } else { u32::from_le_bytes(x) })
    }

    pub fn b16(self, v: u16) -> [u8; 2] {
        if self.big { v.to_be_bytes() } else { v.to_le_bytes() }
    }

    pub fn b32(self, v: u32) -> [u8; 4] {
        if self.big { v.to_be_bytes() } else { v.to_le_bytes() }
    }
}

/// One IFD entry as stored.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Entry {
    pub tag: u16,
    /// The type code as stored ([`FieldType::from_code`]); kept raw, so an entry of a type this
    /// code does not know is copied as it is.
    pub ty: u16,
    pub count: u32,
    /// The value/offset field as stored (file byte order).
    pub field: [u8; 4],
}

/// One IFD.
#[derive(Debug)]
pub(crate) struct Dir {
    pub offset: usize,
    pub entries: Vec<Entry>,
    /// File position of the u32 that points to this directory.
    pub pointer_at: usize,
    /// Directories this one points to, with the pointer tag (SubIFDs or ExifIFD).
    pub children: Vec<(u16, usize)>,
}

/// The IFD structure of a TIFF file: every directory, in pre-order (a directory before the ones
/// it points to), and which of them form the chain.
#[derive(Debug)]
pub(crate) struct Structure {
    pub order: Order,
    pub dirs: Vec<Dir>,
    pub chain: Vec<usize>,
}

/// Walks the IFD structure of `buf` (see the module docs); the error says what is wrong where.
pub(crate) fn walk(buf: &[u8]) -> Result<Structure, String> {
    let big = match buf.get(..4) {
        Some(b"II\x2a\0") => false,
        Some(b"MM\0\x2a") => true,
        other => {
            return Err(format!(
                "not a TIFF/DNG file (it starts with bytes {:02x?}; a DNG starts with \"II*\\0\" or \"MM\\0*\")",
                other.unwrap_or(buf)
            ));
        }
    };
    let mut s = Structure { order: Order { big }, dirs: Vec::new(), chain: Vec::new() };
    let first = s.order.u32(buf, 4).unwrap_or(0) as usize;
    if first == 0 || first >= buf.len() {
        return Err(format!("the first IFD offset {first} lies outside the {}-byte file (truncated?)", buf.len()));
    }
    let mut visited = HashSet::new();
    let mut pointer_at = 4usize;
    while let Some(off) = s.order.u32(buf, pointer_at).filter(|&o| o != 0) {
        let idx = s.dir(buf, off as usize, pointer_at, 0, &mut visited)?;
        s.chain.push(idx);
        pointer_at = s.dirs[idx].offset + 2 + 12 * s.dirs[idx].entries.len();
    }
    Ok(s)
}

impl Structure {
    fn dir(
        &mut self,
        buf: &[u8],
        off: usize,
        pointer_at: usize,
        depth: u32,
        visited: &mut HashSet<usize>,
    ) -> Result<usize, String> {
        if !visited.insert(off) {
            return Err(format!("IFD at offset {off} is referenced twice (corrupt IFD links)"));
        }
        if visited.len() > MAX_IFDS {
            return Err(format!("more than {MAX_IFDS} IFDs (corrupt IFD links)"));
        }
        let o = self.order;
        let n =
            o.u16(buf, off).ok_or_else(|| format!("IFD at offset {off} lies past the end of the file (truncated?)"))?
                as usize;
        if n == 0 {
            return Err(format!("IFD at offset {off} has no entries"));
        }
        if off + 2 + 12 * n > buf.len() {
            return Err(format!("IFD at offset {off} with {n} entries runs past the end of the file (truncated?)"));
        }
        let entries: Vec<Entry> = (0..n)
            .map(|i| {
                let e = off + 2 + 12 * i;
                Entry {
                    tag: o.u16(buf, e).unwrap_or(0),
                    ty: o.u16(buf, e + 2).unwrap_or(0),
                    count: o.u32(buf, e + 4).unwrap_or(0),
                    field: buf[e + 8..e + 12].try_into().unwrap_or([0; 4]),
                }
            })
            .collect();
        for e in &entries {
            let size = e.count as u64 * FieldType::size_of_code(e.ty) as u64;
            if size > buf.len() as u64 {
                return Err(format!(
                    "tag {} in the IFD at offset {off} claims {size} bytes in a {}-byte file (corrupt)",
                    e.tag,
                    buf.len()
                ));
            }
        }
        let idx = self.dirs.len();
        self.dirs.push(Dir { offset: off, entries: entries.clone(), pointer_at, children: Vec::new() });
        if depth < MAX_DEPTH {
            for (i, e) in entries.iter().enumerate() {
                let t = Tag::from_u16(e.tag);
                if !(t == Tag::SubIfds || t == Tag::ExifIfd) || FieldType::size_of_code(e.ty) != 4 {
                    continue;
                }
                let inline = e.count <= 1;
                let base = if inline { off + 2 + 12 * i + 8 } else { o.u32(&e.field, 0).unwrap_or(0) as usize };
                for k in 0..e.count as usize {
                    let at = base + 4 * k;
                    if let Some(child) = o.u32(buf, at).filter(|&c| c != 0) {
                        let c = self.dir(buf, child as usize, at, depth + 1, visited)?;
                        self.dirs[idx].children.push((e.tag, c));
                    }
                }
            }
        }
        Ok(idx)
    }

    /// The chain's directories (depth 0).
    pub fn chain_dirs(&self) -> impl Iterator<Item = &Dir> {
        self.chain.iter().map(|&d| &self.dirs[d])
    }
}

/// The structure walked by [`walk`], read the ways the editor and the raw-data reader need.
impl Structure {
    pub(super) fn entry(&self, dir: usize, t: Tag) -> Option<&Entry> {
        self.dirs[dir].entries.iter().find(|e| e.tag == t.to_u16())
    }

    /// The bytes of an entry's value (`None` when it lies outside the file or its type is unknown).
    pub(super) fn bytes<'a>(&self, buf: &'a [u8], e: &'a Entry) -> Option<&'a [u8]> {
        let size = FieldType::from_code(e.ty)?.size().checked_mul(e.count as usize)?;
        if size <= 4 {
            Some(&e.field[..size])
        } else {
            let off = self.order.u32(&e.field, 0)? as usize;
            buf.get(off..off.checked_add(size)?)
        }
    }

    /// An unsigned integer value (BYTE, SHORT, LONG, IFD) as u64s.
    pub(super) fn uints(&self, buf: &[u8], dir: usize, t: Tag) -> Option<Vec<u64>> {
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

    pub(super) fn uint(&self, buf: &[u8], dir: usize, t: Tag) -> Option<u64> {
        self.uints(buf, dir, t)?.first().copied()
    }

    /// The full-resolution CFA raw image, found as the reader finds it: NewSubfileType 0 with
    /// image data and CFA photometry, in the chain and its SubIFDs, in file order.
    pub(super) fn raw_dir(&self, buf: &[u8]) -> Option<usize> {
        pub(super) fn collect(s: &Structure, d: usize, out: &mut Vec<usize>) {
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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_code_round_trips_and_unknown_codes_are_bytes() {
        for code in 1..=13 {
            let t = FieldType::from_code(code).expect("a TIFF type");
            assert_eq!(t.code(), code);
        }
        assert_eq!(FieldType::from_code(0), None);
        assert_eq!(FieldType::size_of_code(14), 1);
        assert_eq!(FieldType::Double.size(), 8);
        assert_eq!(FieldType::Ifd.size(), 4);
    }
}
