//! The frame-independent half of a target frame's line sums: per row and per column cell, the
//! clean levels and the count of the flat pixels the line sums take (those at or below the line
//! top). Every frame of an EV step sums the same pixels into each line (motion leaves pixels out
//! of the histograms, never out of the lines), so these are computed once per clean image and a
//! frame adds only its noise per pixel ([`crate::calibrate::accumulate`]).

use std::sync::OnceLock;

use crate::calibrate::flat::NOT_FLAT;
use crate::calibrate::structure::CELLS;

/// `[Σ clean level, pixels]` of one line cell.
pub(crate) type CellBase = [i64; 2];

/// The clean-image half of the line sums of one clean image at one line top.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct LineBase {
    /// The level above which pixels are left out of the lines.
    pub(crate) line_top: u16,
    /// Per row, by cell `x & 3`.
    pub(crate) rows: Vec<[CellBase; CELLS]>,
    /// Per column, by cell `y & 3`.
    pub(crate) cols: Vec<[CellBase; CELLS]>,
}

impl LineBase {
    /// The sums over the flat pixels of `levels` (`w` wide, [`NOT_FLAT`] elsewhere) at or below
    /// `line_top`.
    pub(crate) fn new(levels: &[u16], w: usize, line_top: u16) -> Self {
        let h = levels.len().checked_div(w).unwrap_or(0);
        let mut rows = vec![[[0i64; 2]; CELLS]; h];
        let mut cols = vec![[[0i64; 2]; CELLS]; w];
        for (y, (crow, row)) in levels.chunks_exact(w.max(1)).zip(rows.iter_mut()).enumerate() {
            let cell = y & 3;
            for (x, (&c, col)) in crow.iter().zip(cols.iter_mut()).enumerate() {
                if in_lines(c, line_top) {
                    let (c, r) = (c as i64, &mut row[x & 3]);
                    r[0] += c;
                    r[1] += 1;
                    col[cell][0] += c;
                    col[cell][1] += 1;
                }
            }
        }
        Self { line_top, rows, cols }
    }
}

/// Whether a pixel of clean level `c` is in the line sums.
#[inline(always)]
pub(crate) fn in_lines(c: u16, line_top: u16) -> bool {
    c != NOT_FLAT && c <= line_top
}

/// A clean image's [`LineBase`], computed on first use. Derived data: it never takes part in a
/// comparison or a checkpoint (two images are equal whether or not either has computed it).
#[derive(Debug, Clone, Default)]
pub(crate) struct LineBaseCache(OnceLock<LineBase>);

impl LineBaseCache {
    /// The line base of `levels` at `line_top`: the cached one, or computed (and cached when
    /// nothing was cached yet).
    pub(crate) fn get(&self, levels: &[u16], w: usize, line_top: u16) -> std::borrow::Cow<'_, LineBase> {
        let base = self.0.get_or_init(|| LineBase::new(levels, w, line_top));
        if base.line_top == line_top {
            std::borrow::Cow::Borrowed(base)
        } else {
            std::borrow::Cow::Owned(LineBase::new(levels, w, line_top))
        }
    }
}

impl PartialEq for LineBaseCache {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}
