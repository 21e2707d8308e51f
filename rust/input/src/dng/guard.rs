//! The check a DNG's bytes pass before rawler parses them: the directory structure walked once
//! (and handed on), and every size rawler would allocate bounded by the file.

use super::ifd::{FieldType, Structure, walk};

/// Tags of a chain IFD whose values rawler 0.8 follows as sub-IFDs, one level deep
/// (`GenericTiffReader::wellknown_sub_ifd_tags`): SubIFDs, ExifIFD, GPSInfo and InterColorProfile.
pub(super) const RAWLER_SUB_IFD_TAGS: [u16; 4] = [330, 34665, 34853, 34675];
/// rawler 0.8 reads at most this many entries of an IFD.
pub(super) const RAWLER_MAX_IFD_ENTRIES: usize = 4096;

/// Walks the IFD structure before rawler does: rejects non-TIFF data, IFD loops and tags whose
/// size exceeds the file, which rawler would allocate blindly — a count of 2³² DOUBLEs is a 32 GB
/// allocation whose failure aborts the process, and no `catch_unwind` stops an abort.
///
/// Two walks. The strict one is the IFD walker of this crate ([`walk`]: the chain and its
/// SubIFDs/ExifIFD pointers; an IFD that is empty or runs past the file is refused). The second
/// mirrors where rawler 0.8 itself goes: the chain IFDs' [`RAWLER_SUB_IFD_TAGS`], whatever their
/// type (a LONG's values, an UNDEFINED value's own offset, an unknown type's first byte). rawler
/// ignores errors in those IFDs — an ICC profile read as an IFD is not one — so only the sizes it
/// would allocate are checked there.
pub(super) fn check_structure(buf: &[u8]) -> Result<Structure, String> {
    let s = walk(buf)?;
    let o = s.order;
    // The bytes rawler allocates for an entry: a value's size, except that the IFD type (13) is
    // unknown to rawler (a byte a value), so never more than `count · size`.
    let rawler_size = |ty: u16, count: u32| -> u64 {
        count as u64 * if ty == FieldType::Ifd.code() { 1 } else { FieldType::size_of_code(ty) as u64 }
    };
    let too_big = |t: u16, size: u64, off: usize| {
        format!("tag {t} in the IFD at offset {off} claims {size} bytes in a {}-byte file (corrupt)", buf.len())
    };
    // IFDs rawler follows from a chain IFD: (offset, the tag that points there).
    let mut rawler_subs: Vec<(usize, u16)> = Vec::new();
    for dir in s.chain_dirs() {
        for (i, e) in dir.entries.iter().enumerate() {
            let (tag, ty, count) = (e.tag, e.ty, e.count);
            if !RAWLER_SUB_IFD_TAGS.contains(&tag) {
                continue;
            }
            let at_entry = dir.offset + 2 + 12 * i;
            // Where rawler finds the value: inline when its own size is ≤ 4 bytes (type 13 is one
            // byte a value to rawler, four to us).
            let at = if rawler_size(ty, count) <= 4 {
                Some(at_entry + 8)
            } else {
                o.u32(buf, at_entry + 8).map(|o| o as usize)
            };
            match (FieldType::from_code(ty), at) {
                (Some(FieldType::Long), Some(at)) => rawler_subs
                    .extend((0..count as usize).filter_map(|k| o.u32(buf, at + 4 * k)).map(|o| (o as usize, tag))),
                (Some(FieldType::Undefined), Some(at)) => rawler_subs.push((at, tag)),
                (None | Some(FieldType::Ifd), Some(at)) if count > 0 => {
                    rawler_subs.extend(buf.get(at).map(|&o| (o as usize, tag)));
                }
                // rawler indexes the first value of an unknown type here, and has none.
                (None | Some(FieldType::Ifd), _) => {
                    return Err(format!("tag {tag} (an IFD pointer) in the IFD at offset {} has no value", dir.offset));
                }
                _ => {}
            }
        }
    }
    for (off, via) in rawler_subs {
        let Some(n) = o.u16(buf, off) else { continue };
        for i in 0..(n as usize).min(RAWLER_MAX_IFD_ENTRIES) {
            let e = off + 2 + 12 * i;
            let (Some(tag), Some(ty), Some(count)) = (o.u16(buf, e), o.u16(buf, e + 2), o.u32(buf, e + 4)) else {
                break;
            };
            let size = rawler_size(ty, count);
            // rawler reads the value's offset, refuses u32::MAX, then allocates.
            if size > 4 && o.u32(buf, e + 8).is_none_or(|o| o == u32::MAX) {
                continue;
            }
            if size > buf.len() as u64 && via == 34675 {
                // An ICC profile is no IFD, but rawler 0.8 parses it as one.
                return Err(format!(
                    "the DNG decoder (rawler) reads the InterColorProfile (tag 34675) as an IFD and would \
                     allocate {size} bytes for what it takes for tag {tag} there; remove the profile \
                     (exiftool -icc_profile= FILE) or re-export the DNG"
                ));
            }
            if size > buf.len() as u64 {
                return Err(format!("{} (reached through tag {via})", too_big(tag, size, off)));
            }
        }
    }
    Ok(s)
}
