//! Where a DNG's raw samples lie in its file (strips or tiles, bit depth, the active area's
//! origin), and reading or writing uncompressed samples there in place, without a decoder.

use ndarray::{Array2, ArrayView2, ShapeBuilder};
use rayon::prelude::*;

use super::ifd::{Order, Structure, walk};
use super::tags::Tag;
use super::tiff::pack_msb;

/// Where the raw image's data lies.
pub(super) struct RawGeometry {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) bits: u32,
    /// (top, left) of the active area.
    pub(super) origin: (usize, usize),
    /// Strips: (rows per strip, offsets, byte counts); tiles: (tile width, tile length, offsets,
    /// byte counts).
    pub(super) data: DataLayout,
}

pub(super) enum DataLayout {
    Strips { rows: usize, offsets: Vec<u64>, counts: Vec<u64> },
    Tiles { width: usize, length: usize, offsets: Vec<u64>, counts: Vec<u64> },
}

pub(super) fn geometry(s: &Structure, buf: &[u8], raw: usize) -> Result<RawGeometry, String> {
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
    s: &Structure,
    buf: &[u8],
    (width, height): (usize, usize),
    (top, left, bottom, right): (usize, usize, usize, usize),
) -> Option<Array2<u16>> {
    let raw = s.raw_dir(buf)?;
    let g = geometry(s, buf, raw).ok()?;
    if (g.width, g.height) != (width, height)
        || g.origin != (top, left)
        || g.bits != 16
        || !plain(s, buf, raw)
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
    let (samples, stride) = active_samples(buf, (ah, aw))?;
    ArrayView2::from_shape((ah, aw).strides((stride, 1)), samples).ok()
}

/// [`active_view`] as the samples from the active area's first to its last, with the row
/// stride (in samples) they are laid out with.
pub(crate) fn active_samples(buf: &[u8], (ah, aw): (usize, usize)) -> Option<(&[u16], usize)> {
    let s = walk(buf).ok()?;
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
    Some((samples, g.width))
}

/// Uncompressed single-sample integer data, stored as it reads (no linearization, no
/// interleaving).
pub(super) fn plain(s: &Structure, buf: &[u8], raw: usize) -> bool {
    s.uint(buf, raw, Tag::Compression).unwrap_or(1) == 1
        && s.uint(buf, raw, Tag::SamplesPerPixel).unwrap_or(1) == 1
        && s.uint(buf, raw, Tag::SampleFormat).unwrap_or(1) == 1
        && s.entry(raw, Tag::LinearizationTable).is_none()
        && s.uint(buf, raw, Tag::RowInterleaveFactor).unwrap_or(1) == 1
        && s.uint(buf, raw, Tag::ColumnInterleaveFactor).unwrap_or(1) == 1
}

/// Whether every strip or tile of 16-bit data is where the file says and as long as it must be
/// (`None` for other bit depths).
pub(super) fn stored_fits(buf: &[u8], g: &RawGeometry) -> Option<bool> {
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

pub(super) fn write_16(out: &mut [u8], o: Order, g: &RawGeometry, pixels: ArrayView2<'_, u16>) {
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

pub(super) fn write_packed(out: &mut [u8], g: &RawGeometry, bits: u32, pixels: ArrayView2<'_, u16>) {
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
pub(super) fn unpack_msb(b: &[u8], bits: u32, n: usize) -> Vec<u16> {
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
