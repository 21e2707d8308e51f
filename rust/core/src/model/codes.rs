//! Output codes a sensor never writes, and where its output stops (method.md, "Output codes").
//!
//! Above its highest analog gain a camera reaches an ISO by multiplying the quantised value:
//! `round(black + (q − black)·d)`. With `d = 4` it only ever writes every fourth code; with
//! `d = 1.5`, two codes in three. The per-bin noise PMFs cannot show this, because a bin pools
//! clean levels whose lattices are shifted against each other, so synthesis would write every
//! code: measured on the simulated 10-bit phone at ISO 6400 (`d = 4`), the conditional JSD is
//! 0.0112 without the lattice and 0.0055 with it (finite-sample floor 0.0048).
//!
//! The session counts, per ISO and CFA position, how often each output code occurs in the
//! target frames (flat pixels). For every period `p ≤ 64` over which the codes seen span at
//! least 8 periods, the residue classes holding less than 1 % of their share
//! under a smooth distribution are empty; the lattice is the period that leaves the fewest codes
//! allowed per unit length (a period-4 lattice also looks like a period-2 one), with at least
//! 20 000 samples (the detection and its thresholds are the calibration's, `calibrate/codes.rs`);
//! codes 0 and white (clipping) are left out. Synthesis then moves every
//! value to the nearest allowed code ([`Snap`]); a value midway between two allowed codes goes
//! down or up on alternate pixels of the same colour.

use serde::{Deserialize, Serialize};

/// Longest lattice period.
pub const MAX_PERIOD: u16 = 64;

/// The codes a sensor writes at one ISO and CFA position: `code mod period` is in `allowed`
/// (a bit mask over residues).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct CodeLattice {
    pub period: u16,
    pub allowed: u64,
}

impl CodeLattice {
    pub fn allows(&self, code: i64) -> bool {
        let r = code.rem_euclid(self.period as i64) as u32;
        self.allowed >> r & 1 == 1
    }

    /// Checks a lattice read from a file.
    pub fn is_valid(&self) -> bool {
        (2..=MAX_PERIOD).contains(&self.period)
            && self.allowed != 0
            && self.allowed & !mask(self.period) == 0
            && self.allowed != mask(self.period)
    }

    /// Allowed residues, e.g. `{0}` of 4.
    pub fn describe(&self) -> String {
        let r: Vec<String> = (0..self.period).filter(|&r| self.allowed >> r & 1 == 1).map(|r| r.to_string()).collect();
        format!("codes ≡ {{{}}} mod {}", r.join(","), self.period)
    }
}

pub(crate) fn mask(period: u16) -> u64 {
    if period >= 64 { u64::MAX } else { (1u64 << period) - 1 }
}

/// Lookup tables that move a value to the nearest allowed code of a lattice, for values
/// `0 ..= white` (0 and white, the clips, stay).
#[derive(Debug, Clone, PartialEq)]
pub struct Snap {
    /// Nearest allowed code, ties going down.
    down: Vec<u16>,
    /// Nearest allowed code, ties going up.
    up: Vec<u16>,
}

impl Snap {
    pub fn new(lattice: &CodeLattice, white: u16) -> Self {
        let n = white as usize + 1;
        let mut down = Vec::with_capacity(n);
        let mut up = Vec::with_capacity(n);
        for v in 0..n as i64 {
            if v == 0 || v == white as i64 || lattice.allows(v) {
                down.push(v as u16);
                up.push(v as u16);
                continue;
            }
            let p = lattice.period as i64;
            let below = (1..p).map(|k| v - k).find(|&c| lattice.allows(c));
            let above = (1..p).map(|k| v + k).find(|&c| lattice.allows(c));
            let clamp = |c: i64| c.clamp(0, white as i64) as u16;
            let (d, u) = match (below, above) {
                (Some(b), Some(a)) => {
                    let (db, da) = (v - b, a - v);
                    if db < da {
                        (b, b)
                    } else if da < db {
                        (a, a)
                    } else {
                        (b, a)
                    }
                }
                (Some(b), None) => (b, b),
                (None, Some(a)) => (a, a),
                (None, None) => (v, v),
            };
            down.push(clamp(d));
            up.push(clamp(u));
        }
        Self { down, up }
    }

    /// The allowed code for `value` (already clamped to `0 ..= white`); `alternate` picks the
    /// upper code on ties.
    #[inline(always)]
    pub fn apply(&self, value: u16, alternate: bool) -> u16 {
        let t = if alternate { &self.up } else { &self.down };
        t[(value as usize).min(t.len() - 1)]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn snap_moves_to_the_nearest_allowed_code() {
        let l = CodeLattice { period: 4, allowed: 1 };
        let s = Snap::new(&l, 1023);
        assert_eq!(s.apply(64, false), 64);
        assert_eq!(s.apply(65, false), 64);
        assert_eq!(s.apply(67, false), 68);
        assert_eq!((s.apply(66, false), s.apply(66, true)), (64, 68));
        assert_eq!(s.apply(1023, false), 1023, "white stays");
        assert_eq!(s.apply(0, true), 0, "0 stays");
        assert_eq!(s.apply(1022, true), 1023, "never above white");
        // Snapping a smooth distribution onto the lattice keeps its mean.
        let mut mean = 0.0;
        let mut n = 0.0;
        for v in 100..900u16 {
            for alt in [false, true] {
                mean += s.apply(v, alt) as f64 - v as f64;
                n += 1.0;
            }
        }
        assert!((mean / n).abs() < 1e-9, "{}", mean / n);
    }
}

/// Where a sensor's output stops, at one ISO and position.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct OutputRange {
    /// Lowest code written (a hard black clamp), else 0.
    pub floor: u16,
    /// Highest code written: white, or the top of a pile-up below it.
    pub ceiling: u16,
    /// Where the pile-up at the top begins (= `ceiling` for a clip at one code, lower for a
    /// full well whose saturated output still carries read noise): samples reaching it are
    /// clipped.
    pub saturation: u16,
}
