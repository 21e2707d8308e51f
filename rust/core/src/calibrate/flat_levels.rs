//! Which clean levels the flat pixels of a clean image have, per CFA position, and how many flat
//! pixels each position has: computed once per clean image, on first use, so that a target
//! frame's counts ([`crate::calibrate::window_counts`]) give a table to the levels that occur and
//! to no other.

use std::sync::OnceLock;

use crate::calibrate::flat::NOT_FLAT;
use crate::model::layout::{POSITIONS, position};

/// The levels of one clean image's flat pixels.
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct FlatLevels {
    /// Per position, the distinct clean levels of its flat pixels, ascending.
    pub(crate) levels: [Vec<u16>; POSITIONS],
    /// Per position, its flat pixels.
    pub(crate) pixels: [u64; POSITIONS],
}

impl FlatLevels {
    /// The flat levels of `levels` (row-major, `w` wide, [`NOT_FLAT`] where not flat).
    pub(crate) fn new(levels: &[u16], w: usize) -> Self {
        let mut seen: [Vec<bool>; POSITIONS] = std::array::from_fn(|_| vec![false; NOT_FLAT as usize + 1]);
        let mut pixels = [0u64; POSITIONS];
        for (y, row) in levels.chunks_exact(w.max(1)).enumerate() {
            for (x, &c) in row.iter().enumerate() {
                let pos = position(y, x);
                seen[pos][c as usize] = true;
                pixels[pos] += (c != NOT_FLAT) as u64;
            }
        }
        let levels = std::array::from_fn(|p| (0..NOT_FLAT).filter(|&c| seen[p][c as usize]).collect());
        Self { levels, pixels }
    }
}

/// A clean image's [`FlatLevels`], computed on first use. Derived data: it never takes part in a
/// comparison or a checkpoint (two images are equal whether or not either has computed it).
#[derive(Debug, Clone, Default)]
pub(crate) struct FlatLevelsCache(OnceLock<FlatLevels>);

impl FlatLevelsCache {
    /// The flat levels of `levels` (`w` wide): the cached ones, or computed and cached.
    pub(crate) fn get(&self, levels: &[u16], w: usize) -> &FlatLevels {
        self.0.get_or_init(|| FlatLevels::new(levels, w))
    }
}

impl PartialEq for FlatLevelsCache {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Levels and counts per position of a small image with pixels that are not flat.
    #[test]
    fn levels_and_pixels_per_position() {
        // 4 × 3: positions 0 1 0 1 / 2 3 2 3 / 0 1 0 1.
        let n = NOT_FLAT;
        let levels = [7, 9, 5, n, 3, n, 3, 4, 7, 2, n, 9];
        let f = FlatLevels::new(&levels, 4);
        assert_eq!(f.levels[0], vec![5, 7]);
        assert_eq!(f.levels[1], vec![2, 9]);
        assert_eq!(f.levels[2], vec![3]);
        assert_eq!(f.levels[3], vec![4]);
        assert_eq!(f.pixels, [3, 3, 2, 1]);
    }
}
