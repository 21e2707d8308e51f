//! A derived DNG written as its pixels are drawn: the plan of the bytes around the stored rows,
//! for inputs whose raw image is uncompressed 16-bit strips.

use noisecal_core::SensorLayout;
use noisecal_core::model::pack::NoiseProfile;

use super::edit::{Edits, Overlay, apply, metadata_edits, new_unique_id};
use super::ifd::{Structure, walk};
use super::raw_data::{DataLayout, geometry, plain, stored_fits};
use super::tags::Tag;

/// A derived DNG written as its pixels are drawn, when the input stores its raw image as
/// uncompressed 16-bit strips (any byte order, any strip order): the bytes
/// [`derive`](super::edit::derive) would give, made in parts: the input's bytes around the
/// stored rows of the active area ([`Self::gaps`]), those rows band by band
/// ([`Self::encode`]), then the tag edits ([`Self::finish`]).
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
/// is stored otherwise (or its IFDs lie among the stored rows): [`derive`](super::edit::derive)
/// writes those.
pub(crate) fn stream_plan(buf: &[u8], (ah, aw): (usize, usize)) -> Option<StreamPlan> {
    let s = walk(buf).ok()?;
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
    /// pixels at row-major indices that are multiples of
    /// [`UNIQUE_ID_STEP`](super::edit::UNIQUE_ID_STEP), in order.
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
