//! Sensor layout: size, CFA order, black level per CFA position, white level.
//!
//! A CFA *position* is `(row % 2) * 2 + (col % 2)`; models are kept per position, not per colour,
//! so the two greens of a Bayer sensor stay separate (method.md, "Words").

use ndarray::{Array2, ArrayView2};
use serde::{Deserialize, Serialize};

use crate::error::LayoutError;

/// Number of CFA positions of a 2×2 mosaic.
pub const POSITIONS: usize = 4;

/// CFA position of a pixel.
#[inline]
pub fn position(row: usize, col: usize) -> usize {
    ((row & 1) << 1) | (col & 1)
}

/// Colour of one CFA site.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub enum CfaColor {
    Red,
    Green,
    Blue,
}

/// 2×2 Bayer order, named by the colours of positions 0, 1, 2, 3.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum CfaPattern {
    Rggb,
    Bggr,
    Grbg,
    Gbrg,
}

impl CfaPattern {
    pub const ALL: [CfaPattern; 4] = [Self::Rggb, Self::Bggr, Self::Grbg, Self::Gbrg];

    /// Colours of positions 0..4.
    pub fn colors(self) -> [CfaColor; POSITIONS] {
        use CfaColor::{Blue as B, Green as G, Red as R};
        match self {
            Self::Rggb => [R, G, G, B],
            Self::Bggr => [B, G, G, R],
            Self::Grbg => [G, R, B, G],
            Self::Gbrg => [G, B, R, G],
        }
    }

    /// Short name of a position, e.g. `R`, `Gr`, `Gb`, `B`.
    pub fn position_name(self, pos: usize) -> &'static str {
        let colors = self.colors();
        match colors[pos & 3] {
            CfaColor::Red => "R",
            CfaColor::Blue => "B",
            CfaColor::Green => {
                // A green shares its row with red (Gr) or with blue (Gb).
                let row_mate = colors[(pos & 2) | ((pos & 1) ^ 1)];
                if row_mate == CfaColor::Red { "Gr" } else { "Gb" }
            }
        }
    }

    /// Parses "RGGB", "bggr", … (case-insensitive).
    pub fn parse(s: &str) -> Option<Self> {
        match s.to_ascii_uppercase().as_str() {
            "RGGB" => Some(Self::Rggb),
            "BGGR" => Some(Self::Bggr),
            "GRBG" => Some(Self::Grbg),
            "GBRG" => Some(Self::Gbrg),
            _ => None,
        }
    }

    /// From the colours of positions 0..4 (DNG `CFAPattern` with 0=R, 1=G, 2=B).
    pub fn from_colors(c: [CfaColor; POSITIONS]) -> Option<Self> {
        Self::ALL.into_iter().find(|p| p.colors() == c)
    }

    /// Camera2 `SENSOR_INFO_COLOR_FILTER_ARRANGEMENT`: 0 RGGB, 1 GRBG, 2 GBRG, 3 BGGR.
    pub fn from_camera2(code: i32) -> Option<Self> {
        match code {
            0 => Some(Self::Rggb),
            1 => Some(Self::Grbg),
            2 => Some(Self::Gbrg),
            3 => Some(Self::Bggr),
            _ => None,
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Self::Rggb => "RGGB",
            Self::Bggr => "BGGR",
            Self::Grbg => "GRBG",
            Self::Gbrg => "GBRG",
        }
    }
}

impl std::fmt::Display for CfaPattern {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// Geometry and levels of a raw sensor readout.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct SensorLayout {
    pub width: u32,
    pub height: u32,
    pub cfa: CfaPattern,
    /// Black level per CFA position in DN (may be fractional, as DNG allows).
    pub black: [f32; POSITIONS],
    /// White (saturation) level in DN.
    pub white: u16,
}

impl SensorLayout {
    /// Checks the layout is usable: non-empty, even-sized, black below white.
    pub fn validate(&self) -> Result<(), LayoutError> {
        if self.width < 2 || self.height < 2 {
            return Err(LayoutError::TooSmall { width: self.width, height: self.height });
        }
        if self.white < 16 {
            return Err(LayoutError::WhiteLevel { white: self.white });
        }
        for (pos, &b) in self.black.iter().enumerate() {
            if !b.is_finite() || b < 0.0 || b >= self.white as f32 - 8.0 {
                return Err(LayoutError::BlackLevel { pos, black: b, white: self.white });
            }
        }
        Ok(())
    }

    pub fn pixels(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Bits needed to hold the white level (10, 12, 14 …).
    pub fn bit_depth(&self) -> u32 {
        16 - self.white.leading_zeros()
    }

    /// Default bin width: about 240 bins per position between black and white, rounded to a
    /// power of two (4 DN at 10 bits, 16 at 12, 64 at 14; method.md).
    pub fn default_bin_width(&self) -> u16 {
        let min_black = self.black.iter().cloned().fold(f32::INFINITY, f32::min);
        let range = (self.white as f32 - min_black).max(1.0);
        let raw = range / 240.0;
        let mut w = 1u16;
        while (w as f32) * 1.5 < raw && w < 4096 {
            w *= 2;
        }
        w
    }

    /// A short human description, e.g. `4032×3024 RGGB black 64/64/64/64 white 1023`.
    pub fn describe(&self) -> String {
        let blacks: Vec<String> = self.black.iter().map(|b| format!("{b}")).collect();
        format!("{}×{} {} black {} white {}", self.width, self.height, self.cfa, blacks.join("/"), self.white)
    }
}

impl SensorLayout {
    /// How this readout's levels carry onto `target`'s black level (a pack's layout): models
    /// are binned by level above black, so an image whose black level is not the pack's is
    /// shifted onto it, worked on, and shifted back ([`BlackAlignment`]).
    pub fn align_to(&self, target: &SensorLayout) -> BlackAlignment {
        BlackAlignment::between(self.black, target.black)
    }
}

/// The one black-level alignment: levels are taken above black. A readout whose black level is
/// `from` is carried onto black level `to` by adding, per CFA position, the difference of the
/// two rounded to whole DN ([`SensorLayout::align_to`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BlackAlignment {
    /// `to − from` per position (DN, may be fractional).
    pub offset: [f32; POSITIONS],
    /// `offset` rounded: what is added to a level to carry it onto `to`.
    pub shift: [i32; POSITIONS],
}

impl BlackAlignment {
    /// The alignment of black levels `from` onto `to`.
    pub fn between(from: [f32; POSITIONS], to: [f32; POSITIONS]) -> Self {
        let offset: [f32; POSITIONS] = std::array::from_fn(|p| to[p] - from[p]);
        Self { offset, shift: offset.map(|d| d.round() as i32) }
    }

    /// Nothing moves (every offset rounds to 0).
    pub fn is_identity(&self) -> bool {
        self.shift.iter().all(|&d| d == 0)
    }

    /// The largest offset in DN, either way.
    pub fn max_offset(&self) -> f32 {
        self.offset.iter().map(|d| d.abs()).fold(0.0, f32::max)
    }

    /// A level at position `pos` carried over, unclamped (for differences such as noise).
    #[inline]
    pub fn level(&self, pos: usize, v: u16) -> i32 {
        v as i32 + self.shift[pos]
    }

    /// An image carried onto the target black level, clamped to `[0, white]`.
    pub fn apply(&self, img: ArrayView2<'_, u16>, white: u16) -> Array2<u16> {
        self.apply_at(img, white, (0, 0))
    }

    /// An image carried back from the target black level, clamped to `[0, white]`.
    pub fn undo(&self, img: ArrayView2<'_, u16>, white: u16) -> Array2<u16> {
        self.undo_at(img, white, (0, 0))
    }

    /// As [`Self::apply`], for a crop whose pixel (0, 0) sits at `origin` (row, column) of the
    /// sensor: each pixel moves by its true CFA position's shift.
    pub fn apply_at(&self, img: ArrayView2<'_, u16>, white: u16, origin: (usize, usize)) -> Array2<u16> {
        self.carry(img, white, origin, 1)
    }

    /// As [`Self::undo`], for a crop at `origin`.
    pub fn undo_at(&self, img: ArrayView2<'_, u16>, white: u16, origin: (usize, usize)) -> Array2<u16> {
        self.carry(img, white, origin, -1)
    }

    fn carry(&self, img: ArrayView2<'_, u16>, white: u16, origin: (usize, usize), sign: i32) -> Array2<u16> {
        let white = white as i32;
        let (oy, ox) = (origin.0 & 1, origin.1 & 1);
        Array2::from_shape_fn(img.dim(), |(y, x)| {
            (img[(y, x)] as i32 + sign * self.shift[position(y + oy, x + ox)]).clamp(0, white) as u16
        })
    }
}

/// Maps a clean level (DN) to its bin at one CFA position.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Binning {
    pub bin_width: u16,
    pub black: [f32; POSITIONS],
    pub white: u16,
}

impl Binning {
    pub fn new(layout: &SensorLayout, bin_width: u16) -> Self {
        Self { bin_width: bin_width.max(1), black: layout.black, white: layout.white }
    }

    /// Number of bins at a position: from its black level up to white.
    pub fn bins(&self, pos: usize) -> usize {
        let span = (self.white as f32 - self.black[pos]).max(0.0);
        (span / self.bin_width as f32).floor() as usize + 1
    }

    /// `b = floor((l - black_c) / bin_width)`, clamped to `[0, bins-1]`.
    #[inline]
    pub fn bin(&self, pos: usize, level: f32) -> usize {
        let b = ((level - self.black[pos]) / self.bin_width as f32).floor();
        if b <= 0.0 { 0 } else { (b as usize).min(self.bins(pos) - 1) }
    }

    /// Centre level (DN) of a bin.
    pub fn center(&self, pos: usize, bin: usize) -> f32 {
        self.black[pos] + (bin as f32 + 0.5) * self.bin_width as f32
    }

    /// Lookup table level → bin for one position, for every u16 level up to white.
    pub fn lut(&self, pos: usize) -> Vec<u16> {
        (0..=self.white as u32).map(|l| self.bin(pos, l as f32) as u16).collect()
    }
}

/// The reference level a clean level `c` stands for when the clean image is at the target ISO's
/// brightness (`synth::CleanAt::Target`): `black + (c − black)/gain`, clamped to `[0, top]`.
#[inline]
pub fn reference_level(c: usize, black: f64, gain: f64, top: f64) -> f64 {
    (black + (c as f64 - black) / gain).clamp(0.0, top)
}

/// A level → table map read at each level's rounded [`reference_level`]: the map of a clean image
/// at the target brightness, from the reference brightness's `lut`.
pub fn lut_at_reference_levels(lut: &[u16], black: f64, gain: f64) -> Vec<u16> {
    let top = (lut.len() - 1) as f64;
    (0..lut.len()).map(|c| lut[reference_level(c, black, gain, top).round() as usize]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn positions_and_names() {
        assert_eq!(position(0, 0), 0);
        assert_eq!(position(0, 1), 1);
        assert_eq!(position(1, 0), 2);
        assert_eq!(position(3, 3), 3);
        assert_eq!(CfaPattern::Rggb.position_name(1), "Gr");
        assert_eq!(CfaPattern::Rggb.position_name(2), "Gb");
        assert_eq!(CfaPattern::Bggr.position_name(1), "Gb");
        assert_eq!(CfaPattern::Grbg.position_name(0), "Gr");
        assert_eq!(CfaPattern::Gbrg.position_name(3), "Gr");
        for p in CfaPattern::ALL {
            assert_eq!(CfaPattern::from_colors(p.colors()), Some(p));
            assert_eq!(CfaPattern::parse(p.name()), Some(p));
        }
    }

    #[test]
    fn default_bin_widths_follow_bit_depth() {
        let mut l = SensorLayout { width: 8, height: 8, cfa: CfaPattern::Rggb, black: [64.0; 4], white: 1023 };
        assert_eq!(l.default_bin_width(), 4);
        assert_eq!(Binning::new(&l, 4).bins(0), 240);
        l.black = [256.0; 4];
        l.white = 4095;
        assert_eq!(l.default_bin_width(), 16);
        l.black = [1024.0; 4];
        l.white = 16383;
        assert_eq!(l.default_bin_width(), 64);
        assert_eq!(l.bit_depth(), 14);
    }

    #[test]
    fn binning_clamps_and_handles_fractional_black() {
        let l =
            SensorLayout { width: 8, height: 8, cfa: CfaPattern::Rggb, black: [63.5, 64.0, 64.0, 64.0], white: 1023 };
        let b = Binning::new(&l, 4);
        assert_eq!(b.bin(0, 0.0), 0);
        assert_eq!(b.bin(0, 67.0), 0);
        assert_eq!(b.bin(0, 67.5), 1);
        assert_eq!(b.bin(1, 1023.0), b.bins(1) - 1);
        assert_eq!(b.lut(1)[68], 1);
    }

    #[test]
    fn black_levels_align_by_whole_dn_per_position() {
        let img =
            SensorLayout { width: 4, height: 2, cfa: CfaPattern::Rggb, black: [60.0, 64.0, 63.6, 64.5], white: 1023 };
        let pack = SensorLayout { black: [64.0; POSITIONS], ..img.clone() };
        let a = img.align_to(&pack);
        // Half a DN rounds away from zero, as `f32::round` does.
        assert_eq!(a.shift, [4, 0, 0, -1]);
        assert_eq!((a.offset[0], a.offset[3]), (4.0, -0.5));
        assert!(!a.is_identity() && a.max_offset() == 4.0);
        assert!(pack.align_to(&pack).is_identity());
        assert_eq!(pack.align_to(&img).shift, [-4, 0, 0, 1]);
        let px = ndarray::array![[0u16, 1, 2, 1023], [10, 1023, 5, 6]];
        let moved = a.apply(px.view(), 1023);
        assert_eq!(moved, ndarray::array![[4u16, 1, 6, 1023], [10, 1022, 5, 5]]);
        assert_eq!(a.undo(moved.view(), 1023), ndarray::array![[0u16, 1, 2, 1023], [10, 1023, 5, 6]]);
        assert_eq!(a.level(0, 2), 6);
        assert_eq!(BlackAlignment::between([64.0; 4], [60.0; 4]).level(0, 2), -2);
    }

    #[test]
    fn validate_rejects_bad_levels() {
        let l = SensorLayout { width: 8, height: 8, cfa: CfaPattern::Rggb, black: [1020.0; 4], white: 1023 };
        assert!(l.validate().is_err());
    }
}
