//! A DNG's bytes without its raw image data, for reading its metadata: grouping a capture folder
//! reads every file's tags, and the raw image (nearly all of a file's bytes) is read later, once,
//! when its frame is pushed.
//!
//! The file's two ends are read first (TIFF writers put their directories at the start or, as
//! noisecal's own writer does, at the end); the directories found there say where the raw
//! image's strips or tiles lie, and everything else is read. The returned buffer has the file's
//! length and its bytes everywhere but in the raw image data, which reads as zeros. It is used
//! only when the directories read from it point into no part of the data (their tables and their
//! values outside it, the data where they said); any other file is read whole.

use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::ops::Range;
use std::path::Path;

use super::ifd::{FieldType, Structure, walk};
use super::raw_data::{DataLayout, geometry};
use super::{Bytes, DngError, MAX_DNG_BYTES};

/// Bytes read from each end of a file before its directories are walked.
pub(super) const END_BYTES: usize = 256 * 1024;

/// The file's bytes, its raw image data left as zeros where [`sparse`] can tell what that is,
/// else the whole file; `ends`: the bytes read from each end first ([`END_BYTES`]).
pub(super) fn meta_bytes(path: &Path, ends: usize) -> Result<Bytes, DngError> {
    let io = |e| DngError::io(path, e);
    let (mut file, len) = noisecal_io::open_regular(path, MAX_DNG_BYTES).map_err(io)?;
    let len = usize::try_from(len).map_err(|_| DngError::decode(path, "the file is too large"))?;
    if len > 4 * ends
        && let Some(buf) = sparse(&mut file, len, ends).map_err(io)?
    {
        return Ok(Bytes::Zeroed(buf));
    }
    noisecal_io::read_regular(path, MAX_DNG_BYTES).map(Bytes::Owned).map_err(io)
}

/// The sparse read of a file of `len` bytes (see the module docs), or `None` when its
/// directories do not allow it.
fn sparse(file: &mut File, len: usize, ends: usize) -> std::io::Result<Option<memmap2::MmapMut>> {
    // A mapping of its own, whose pages are zero until written: the pages of the data are never
    // touched. (A `vec![0; len]` of the same size is, once the allocator keeps such sizes on its
    // heap: it clears all of them, 24 MB a 12 MP frame, every file.)
    let mut buf = memmap2::MmapMut::map_anon(len)?;
    read_range(file, &mut buf, 0..ends)?;
    read_range(file, &mut buf, len - ends..len)?;
    let Some(data) = image_data(&buf) else { return Ok(None) };
    let mut at = ends;
    for r in data.iter().chain(std::iter::once(&(len - ends..len))) {
        if r.start > at {
            read_range(file, &mut buf, at..r.start)?;
        }
        at = at.max(r.end);
    }
    // What the directories say now, every byte but the data read, must be what they said from
    // the ends alone, and point into no part of the data.
    if image_data(&buf).as_ref() != Some(&data) || walk(&buf).map_or(true, |s| touches(&s, &data)) {
        return Ok(None);
    }
    Ok(Some(buf))
}

fn read_range(file: &mut File, buf: &mut [u8], r: Range<usize>) -> std::io::Result<()> {
    file.seek(SeekFrom::Start(r.start as u64))?;
    file.read_exact(&mut buf[r])
}

/// The raw image's strips or tiles as sorted, merged byte ranges within `buf`, `None` where the
/// directories cannot be walked, name no raw image, or place data outside the file.
fn image_data(buf: &[u8]) -> Option<Vec<Range<usize>>> {
    let s = walk(buf).ok()?;
    let raw = s.raw_dir(buf)?;
    let (offsets, counts) = match geometry(&s, buf, raw).ok()?.data {
        DataLayout::Strips { offsets, counts, .. } | DataLayout::Tiles { offsets, counts, .. } => (offsets, counts),
    };
    if offsets.len() != counts.len() || offsets.is_empty() {
        return None;
    }
    let mut ranges = Vec::with_capacity(offsets.len());
    for (&o, &c) in offsets.iter().zip(&counts) {
        let start = usize::try_from(o).ok()?;
        let end = start.checked_add(usize::try_from(c).ok()?)?;
        if end > buf.len() {
            return None;
        }
        if end > start {
            ranges.push(start..end);
        }
    }
    ranges.sort_by_key(|r| r.start);
    let mut merged: Vec<Range<usize>> = Vec::with_capacity(ranges.len());
    for r in ranges {
        match merged.last_mut() {
            Some(last) if r.start <= last.end => last.end = last.end.max(r.end),
            _ => merged.push(r),
        }
    }
    Some(merged)
}

/// Whether the header, a directory's table or an entry's value stored outside its table lies
/// (partly) in one of `data`'s ranges.
fn touches(s: &Structure, data: &[Range<usize>]) -> bool {
    let hits = |r: Range<usize>| data.iter().any(|d| r.start < d.end && d.start < r.end);
    if hits(0..8) {
        return true;
    }
    s.dirs.iter().any(|dir| {
        let table = dir.offset..dir.offset + 2 + 12 * dir.entries.len() + 4;
        hits(table)
            || dir.entries.iter().any(|e| {
                let size = e.count as usize * FieldType::size_of_code(e.ty);
                size > 4
                    && s.order.u32(&e.field, 0).is_some_and(|o| hits(o as usize..(o as usize).saturating_add(size)))
            })
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The sparse read of a file whose directories sit at its end (noisecal's writer) reads every
    /// byte but the raw image data; one whose directories are not at either end is read whole.
    #[test]
    fn reads_all_but_the_image_data() {
        let dir = tempfile::tempdir().expect("tempdir");
        let path = dir.path().join("a.dng");
        let layout = noisecal_core::SensorLayout {
            width: 64,
            height: 48,
            cfa: noisecal_core::CfaPattern::Rggb,
            black: [64.0; 4],
            white: 1023,
        };
        let pixels = ndarray::Array2::from_shape_fn((48, 64), |(y, x)| (100 + 3 * y + x) as u16);
        let meta = noisecal_core::FrameMeta::new(400, 10_000_000);
        super::super::write_dng_from_layout(&path, &layout, &meta, "M", "P", &pixels).expect("write");
        let whole = std::fs::read(&path).expect("read");
        // Ends that hold the directories after the data (a quarter of this small file, as
        // 256 KB is of a 12 MP frame's).
        let ends = whole.len() / 4 - 1;
        let sparse = meta_bytes(&path, ends).expect("sparse read");
        assert_eq!(sparse.len(), whole.len());
        assert!(matches!(sparse, Bytes::Zeroed(_)));
        assert_ne!(&sparse[..], &whole[..], "the sparse read was taken");
        let data = image_data(&whole).expect("strips");
        let in_data = |i: usize| data.iter().any(|r| r.contains(&i));
        let data_bytes: usize = data.iter().map(|r| r.len()).sum();
        assert!(data_bytes >= 64 * 48 * 2, "the strips hold the image");
        // The two ends are read whatever they hold.
        let in_ends = |i: usize| i < ends || i >= whole.len() - ends;
        for (i, (&a, &b)) in sparse.iter().zip(&whole).enumerate() {
            if in_data(i) && !in_ends(i) {
                assert_eq!(a, 0, "byte {i} of the data was read");
            } else {
                assert_eq!(a, b, "byte {i} outside the data differs");
            }
        }
        assert!(
            whole.iter().enumerate().any(|(i, &b)| in_data(i) && !in_ends(i) && b != 0),
            "the data is not all zeros"
        );
        // Ends so large they cover the file: read whole.
        assert_eq!(&meta_bytes(&path, whole.len()).expect("whole")[..], &whole[..]);
        // A file truncated inside its data: no sparse read (the strips end past the file), read
        // whole; the reader then says it is truncated.
        std::fs::write(&path, &whole[..whole.len() - 100]).expect("truncate");
        let cut = meta_bytes(&path, ends).expect("truncated file read whole");
        assert_eq!(&cut[..], &whole[..whole.len() - 100]);
    }

    /// On every DNG of the fuzz corpus (strips and tiles, both byte orders, compressed, odd
    /// directories), the metadata read from the sparse bytes is the metadata of the whole file,
    /// or the same error.
    #[test]
    fn metadata_of_the_sparse_bytes_is_the_files() {
        let corpus = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fuzz-corpus/dng");
        let mut files: Vec<_> = std::fs::read_dir(&corpus).expect("corpus").map(|e| e.expect("entry").path()).collect();
        files.sort();
        let mut sparse_reads = 0;
        for path in files.iter().filter(|p| p.extension().is_some_and(|e| e == "dng")) {
            let whole = std::fs::read(path).expect("read");
            let a = super::super::decode_dng_meta(&whole, path);
            for ends in [64, 1024, (whole.len() / 4).saturating_sub(1).max(8)] {
                let sparse = meta_bytes(path, ends).expect("read");
                sparse_reads += (sparse[..] != whole[..]) as u32;
                let b = super::super::decode_dng_meta(&sparse, path);
                assert_eq!(format!("{a:?}"), format!("{b:?}"), "{} (ends {ends})", path.display());
            }
        }
        assert!(sparse_reads >= 3, "only {sparse_reads} corpus files took the sparse read");
    }
}
