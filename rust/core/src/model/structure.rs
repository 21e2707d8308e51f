//! Structured noise (method.md, "Structured noise"): the parts of a sensor's noise that are not
//! independent from pixel to pixel — one offset per row, per column and per frame — as measured,
//! non-parametric distributions per ISO.
//!
//! - [`OffsetDistribution`]: one offset's distribution as its quantile function (row and column
//!   offsets: thousands of rows × frames stand behind it), with how it was separated from the
//!   sampling noise of a row mean.
//! - [`FrameOffsets`]: the per-frame, per-CFA-position black-level offsets themselves (a session
//!   has only a few dozen frames per ISO: the sample is kept whole, so their joint law across
//!   the four positions is kept too).
//! - [`IsoStructure`]: one ISO's components; [`Components`]: which ones synthesis adds.
//!
//! A component is only *significant* when its variance stands clear of what sampling noise alone
//! would give; synthesis adds significant components only, so a sensor without row noise gets
//! none and nothing changes for it.

use serde::{Deserialize, Serialize};

use crate::model::layout::POSITIONS;

/// Points of a stored quantile function (`u = i / (QUANTILES − 1)`).
pub const QUANTILES: usize = 513;

/// One offset's distribution (DN), zero-mean.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct OffsetDistribution {
    /// The true offset's quantile function at `u = i / (len − 1)`: the measured deviations
    /// shrunk about their mean by `√(1 − sampling / measured)` (variance of the sampling noise of
    /// a mean removed; shape kept).
    pub quantiles: Vec<f32>,
    /// Offsets measured (rows × frames, or columns × frames).
    pub count: u64,
    /// Variance of the measured deviations (DN²).
    pub measured_var: f64,
    /// Variance a mean of that many pixels has from pixel noise alone (DN²): the measured
    /// variance's part that is not the component.
    pub sampling_var: f64,
    /// The component's variance stands clear of the sampling variance (by three standard
    /// errors): synthesis adds it.
    pub significant: bool,
}

impl OffsetDistribution {
    /// The component's own variance (measured minus sampling, at least 0).
    pub fn variance(&self) -> f64 {
        (self.measured_var - self.sampling_var).max(0.0)
    }

    pub fn sd(&self) -> f64 {
        self.variance().sqrt()
    }

    /// The offset at a uniform draw `u ∈ [0, 1)` (linear between stored quantiles).
    #[inline]
    pub fn at(&self, u: f64) -> f64 {
        quantile_at(&self.quantiles, u)
    }

    /// The same distribution scaled by `k` (extrapolation).
    pub fn scaled(&self, k: f64) -> Self {
        Self {
            quantiles: self.quantiles.iter().map(|&q| (q as f64 * k) as f32).collect(),
            measured_var: self.measured_var * k * k,
            sampling_var: self.sampling_var * k * k,
            ..self.clone()
        }
    }

    /// The displacement interpolation `(1 − t)·Q_a + t·Q_b` of two distributions (quantile
    /// functions blended pointwise: the shape moves from one to the other).
    pub fn blend(a: &Self, b: &Self, t: f64) -> Self {
        let n = a.quantiles.len().max(b.quantiles.len()).max(2);
        let quantiles = (0..n)
            .map(|i| {
                let u = i as f64 / (n - 1) as f64;
                ((1.0 - t) * a.at_closed(u) + t * b.at_closed(u)) as f32
            })
            .collect();
        let mix = |x: f64, y: f64| (1.0 - t) * x + t * y;
        Self {
            quantiles,
            count: a.count.min(b.count),
            measured_var: mix(a.measured_var.sqrt(), b.measured_var.sqrt()).powi(2),
            sampling_var: mix(a.sampling_var.sqrt(), b.sampling_var.sqrt()).powi(2),
            significant: a.significant || b.significant,
        }
    }

    fn at_closed(&self, u: f64) -> f64 {
        quantile_at(&self.quantiles, u.min(1.0))
    }

    /// Finite quantiles, non-decreasing, and variances that are numbers.
    pub fn problem(&self) -> Option<String> {
        if self.quantiles.len() < 2 || self.quantiles.len() > 1 << 16 {
            return Some(format!("{} quantiles (2 ..= 65536 expected)", self.quantiles.len()));
        }
        if self.quantiles.iter().any(|q| !q.is_finite() || q.abs() > 1e6) {
            return Some("a quantile is not a finite offset".into());
        }
        if self.quantiles.windows(2).any(|w| w[1] < w[0]) {
            return Some("quantiles decrease".into());
        }
        let bad = |v: f64| !v.is_finite() || v < 0.0;
        if bad(self.measured_var) || bad(self.sampling_var) {
            return Some("a variance is negative or not a number".into());
        }
        None
    }
}

/// Linear interpolation in a quantile table at `u ∈ [0, 1]`.
#[inline]
pub fn quantile_at(q: &[f32], u: f64) -> f64 {
    match q.len() {
        0 => 0.0,
        1 => q[0] as f64,
        n => {
            let x = u.clamp(0.0, 1.0) * (n - 1) as f64;
            let i = (x as usize).min(n - 2);
            let f = x - i as f64;
            q[i] as f64 * (1.0 - f) + q[i + 1] as f64 * f
        }
    }
}

/// The per-frame black-level offsets of one ISO (DN per CFA position, each frame's deviation
/// from its burst's mean, rescaled for the mean's removal).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameOffsets {
    pub offsets: Vec<[f32; POSITIONS]>,
    /// Variance per position of the offsets (DN²).
    pub measured_var: [f64; POSITIONS],
    /// Variance per position a frame mean has from pixel and row noise alone (DN²).
    pub sampling_var: [f64; POSITIONS],
    pub significant: bool,
}

impl FrameOffsets {
    pub fn variance(&self, pos: usize) -> f64 {
        (self.measured_var[pos] - self.sampling_var[pos]).max(0.0)
    }

    /// One frame's offsets: a smoothed bootstrap of the measured ones (a measured frame picked
    /// by `pick`, plus a Gaussian kernel: [`Self::bootstrap`]). Deterministic in the draws.
    pub fn draw(&self, pick: u64, gauss: [f64; POSITIONS]) -> [f64; POSITIONS] {
        let n = self.offsets.len();
        if n == 0 {
            return [0.0; POSITIONS];
        }
        let i = ((pick as u128 * n as u128) >> 64) as usize;
        std::array::from_fn(|p| match self.bootstrap(p) {
            Some(b) => (self.offsets[i][p] as f64 - b.mean) * b.shrink + b.kernel_sd * gauss[p],
            None => 0.0,
        })
    }

    /// The smoothed bootstrap at one position: an offset `o` becomes `(o − mean)·shrink` plus a
    /// Gaussian of `kernel_sd` (Silverman's width `1.06·n^−⅕` of the sample's spread, the sum
    /// shrunk to the component's variance). `None` for a sample without spread.
    pub fn bootstrap(&self, pos: usize) -> Option<Bootstrap> {
        let n = self.offsets.len();
        if n == 0 {
            return None;
        }
        let mean = self.offsets.iter().map(|o| o[pos] as f64).sum::<f64>() / n as f64;
        let s2 = self.offsets.iter().map(|o| (o[pos] as f64 - mean).powi(2)).sum::<f64>() / n as f64;
        if s2 <= 0.0 {
            return None;
        }
        let h = 1.06 * (n as f64).powf(-0.2);
        let shrink = (self.variance(pos) / (s2 * (1.0 + h * h))).sqrt();
        Some(Bootstrap { mean, shrink, kernel_sd: h * s2.sqrt() * shrink })
    }

    pub fn scaled(&self, k: f64) -> Self {
        Self {
            offsets: self.offsets.iter().map(|o| o.map(|v| (v as f64 * k) as f32)).collect(),
            measured_var: self.measured_var.map(|v| v * k * k),
            sampling_var: self.sampling_var.map(|v| v * k * k),
            significant: self.significant,
        }
    }

    /// The nearer of two ISOs' samples, scaled to the blended standard deviation.
    pub fn blend(a: &Self, b: &Self, t: f64) -> Self {
        let (near, far) = if t <= 0.5 { (a, b) } else { (b, a) };
        let sd = |f: &Self| (0..POSITIONS).map(|p| f.variance(p)).sum::<f64>().sqrt();
        let (sa, sb) = (sd(a), sd(b));
        let target = (1.0 - t) * sa + t * sb;
        let own = sd(near);
        let k = if own > 0.0 { target / own } else { 1.0 };
        let mut out = near.scaled(k);
        out.significant = near.significant || far.significant;
        out
    }

    pub fn problem(&self) -> Option<String> {
        if self.offsets.len() > 1 << 20 {
            return Some(format!("{} frame offsets", self.offsets.len()));
        }
        if self.offsets.iter().flatten().any(|v| !v.is_finite() || v.abs() > 1e6) {
            return Some("a frame offset is not a finite number".into());
        }
        if self.measured_var.iter().chain(&self.sampling_var).any(|v| !(v.is_finite() && *v >= 0.0)) {
            return Some("a variance is negative or not a number".into());
        }
        None
    }
}

/// The smoothed bootstrap of [`FrameOffsets`] at one position ([`FrameOffsets::bootstrap`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Bootstrap {
    pub mean: f64,
    pub shrink: f64,
    pub kernel_sd: f64,
}

/// Points of a fixed pattern's stored quantile function: a pattern has millions of pixels behind
/// it, and its tails (warm pixels) are what a coarser table would smear.
pub const PATTERN_QUANTILES: usize = 4097;

/// The fixed pattern of one ISO, from dark (lens-covered) frames: what every frame of that ISO
/// carries at the same pixel, whatever the light (dark signal non-uniformity and dark shading).
///
/// A pixel's pattern is `shading(x, y) + residual`: the shading is the low-frequency part (a
/// coarse grid of cell means per CFA position, bilinear between cell centres), the residual its
/// pixel-to-pixel part, stored as its distribution per position (the per-pixel maps themselves
/// would be as large as a frame per ISO). Synthesis gives each sensor pixel one uniform draw from
/// a fixed key, the same at every ISO: a pixel high in the pattern at one ISO is high at all, the
/// non-parametric reading of a per-pixel `k·gain + b`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FixedPattern {
    /// Per position, the residual's distribution (zero mean; the sampling noise of a mean of
    /// `frames` dark frames taken out).
    pub pixels: [OffsetDistribution; POSITIONS],
    /// Per position, the shading grid `grid[0] × grid[1]` (rows × columns, row-major, DN, zero
    /// mean over the sensor).
    pub shading: [Vec<f32>; POSITIONS],
    pub grid: [u32; 2],
    /// The sensor size the grid spans.
    pub size: [u32; 2],
    /// Dark frames behind it.
    pub frames: u32,
    /// Per position, the variance of a dark pixel from frame to frame (DN²): the
    /// signal-independent noise at black.
    pub temporal_var: [f64; POSITIONS],
    /// Per position, what the pixel PMFs already hold of the pattern (the change of the pattern
    /// from the reference ISO, whose clean image carries its own): synthesis takes it out of them.
    pub in_pixel_noise: [OffsetDistribution; POSITIONS],
    /// The pattern stands clear of sampling noise and is at least 1 % of the pixel variance.
    pub significant: bool,
}

impl FixedPattern {
    /// The pattern's variance at a position (pixels and shading).
    pub fn variance(&self, pos: usize) -> f64 {
        self.pixels[pos].variance() + self.shading_var(pos)
    }

    pub fn sd(&self) -> f64 {
        ((0..POSITIONS).map(|p| self.variance(p)).sum::<f64>() / POSITIONS as f64).sqrt()
    }

    /// The variance of a position's shading grid about its mean.
    pub fn shading_var(&self, pos: usize) -> f64 {
        let g = &self.shading[pos];
        if g.is_empty() {
            return 0.0;
        }
        let m = g.iter().map(|&v| v as f64).sum::<f64>() / g.len() as f64;
        g.iter().map(|&v| (v as f64 - m).powi(2)).sum::<f64>() / g.len() as f64
    }

    /// A position's shading grid interpolated to sensor row `y` (one value per grid column;
    /// `None` without a usable grid). [`Self::shading_on_line`] finishes the bilinear
    /// interpolation along the row.
    pub fn shading_line(&self, pos: usize, y: usize) -> Option<Vec<f64>> {
        let [gh, gw] = self.grid.map(|v| v as usize);
        let g = &self.shading[pos];
        if gh == 0 || gw == 0 || g.len() != gh * gw {
            return None;
        }
        let (r0, r1, fy) = grid_coord(y, self.size[0], gh);
        Some((0..gw).map(|c| g[r0 * gw + c] as f64 * (1.0 - fy) + g[r1 * gw + c] as f64 * fy).collect())
    }

    /// The shading at column `x` of a row's [`Self::shading_line`].
    #[inline]
    pub fn shading_on_line(&self, line: &[f64], x: usize) -> f64 {
        let (c0, c1, f) = grid_coord(x, self.size[1], line.len());
        line[c0] * (1.0 - f) + line[c1] * f
    }

    /// The shading at sensor pixel `(y, x)` (bilinear between cell centres, held flat past the
    /// outer ones; 0 without a grid).
    pub fn shading_at(&self, pos: usize, y: usize, x: usize) -> f64 {
        self.shading_line(pos, y).map_or(0.0, |line| self.shading_on_line(&line, x))
    }

    /// Scaled by `k` (extrapolation along the gain).
    pub fn scaled(&self, k: f64) -> Self {
        Self {
            pixels: self.pixels.clone().map(|d| d.scaled(k)),
            shading: self.shading.clone().map(|g| g.iter().map(|&v| (v as f64 * k) as f32).collect()),
            temporal_var: self.temporal_var.map(|v| v * k * k),
            in_pixel_noise: self.in_pixel_noise.clone().map(|d| d.scaled(k)),
            ..self.clone()
        }
    }

    /// Between two ISOs' patterns at fraction `t` (quantile functions and grids blended).
    pub fn blend(a: &Self, b: &Self, t: f64) -> Self {
        let mix = |x: f64, y: f64| (1.0 - t) * x + t * y;
        let shading = std::array::from_fn(|p| {
            if a.shading[p].len() == b.shading[p].len() {
                a.shading[p].iter().zip(&b.shading[p]).map(|(&x, &y)| mix(x as f64, y as f64) as f32).collect()
            } else if t <= 0.5 {
                a.shading[p].clone()
            } else {
                b.shading[p].clone()
            }
        });
        let (near, _) = if t <= 0.5 { (a, b) } else { (b, a) };
        Self {
            pixels: std::array::from_fn(|p| OffsetDistribution::blend(&a.pixels[p], &b.pixels[p], t)),
            shading: if a.grid == b.grid { shading } else { near.shading.clone() },
            grid: near.grid,
            size: near.size,
            frames: a.frames.min(b.frames),
            temporal_var: std::array::from_fn(|p| mix(a.temporal_var[p].sqrt(), b.temporal_var[p].sqrt()).powi(2)),
            in_pixel_noise: std::array::from_fn(|p| {
                OffsetDistribution::blend(&a.in_pixel_noise[p], &b.in_pixel_noise[p], t)
            }),
            significant: a.significant || b.significant,
        }
    }

    pub fn problem(&self) -> Option<String> {
        for (p, d) in self.pixels.iter().chain(&self.in_pixel_noise).enumerate() {
            if let Some(why) = d.problem() {
                return Some(format!("pattern distribution {p}: {why}"));
            }
        }
        let [gh, gw] = self.grid;
        if gh as u64 * gw as u64 > 1 << 16 {
            return Some(format!("a {gh} × {gw} shading grid (at most 65536 cells)"));
        }
        if self.shading.iter().any(|g| g.len() != (gh * gw) as usize) {
            return Some(format!("a shading grid does not hold {gh} × {gw} cells"));
        }
        if self.shading.iter().flatten().any(|v| !v.is_finite() || v.abs() > 1e6) {
            return Some("a shading value is not a finite offset".into());
        }
        if self.temporal_var.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            return Some("a temporal variance is negative or not a number".into());
        }
        None
    }
}

/// Along an axis of `size` pixels cut into `cells` cells: the two cells whose centres bracket
/// pixel `v` and the weight of the second (held flat past the outer centres).
#[inline]
pub fn grid_coord(v: usize, size: u32, cells: usize) -> (usize, usize, f64) {
    let c = ((v as f64 + 0.5) / size.max(1) as f64 * cells as f64 - 0.5).clamp(0.0, cells.saturating_sub(1) as f64);
    let i = (c as usize).min(cells.saturating_sub(2));
    let f = if cells > 1 { c - i as f64 } else { 0.0 };
    (i, (i + 1).min(cells.saturating_sub(1)), f)
}

/// The structured components of one ISO.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IsoStructure {
    pub iso: u32,
    /// Row offsets per row parity (one offset shared by every pixel of a row).
    pub rows: [Option<OffsetDistribution>; 2],
    /// Column offsets per column parity (one offset shared by every pixel of a column).
    pub columns: [Option<OffsetDistribution>; 2],
    /// Per-frame offsets per CFA position.
    pub frames: Option<FrameOffsets>,
    /// Target frames that stood in a burst of at least two at their ISO (the offsets are
    /// deviations from a burst's mean; a lone frame has none).
    pub frames_used: u64,
    /// The fixed pattern, when dark frames were captured at this ISO.
    pub fpn: Option<FixedPattern>,
}

impl IsoStructure {
    /// The distribution synthesis adds for a component, when it is significant.
    pub fn row(&self, parity: usize) -> Option<&OffsetDistribution> {
        self.rows[parity].as_ref().filter(|d| d.significant)
    }

    pub fn column(&self, parity: usize) -> Option<&OffsetDistribution> {
        self.columns[parity].as_ref().filter(|d| d.significant)
    }

    pub fn frame(&self) -> Option<&FrameOffsets> {
        self.frames.as_ref().filter(|f| f.significant && !f.offsets.is_empty())
    }

    pub fn fixed_pattern(&self) -> Option<&FixedPattern> {
        self.fpn.as_ref().filter(|f| f.significant)
    }

    /// Whether any component is significant.
    pub fn any(&self) -> bool {
        (0..2).any(|p| self.row(p).is_some() || self.column(p).is_some())
            || self.frame().is_some()
            || self.fixed_pattern().is_some()
    }

    /// No components measured (an ISO with only dark frames starts here).
    pub fn empty(iso: u32) -> Self {
        Self { iso, rows: [None, None], columns: [None, None], frames: None, frames_used: 0, fpn: None }
    }

    /// Scaled by `k` (DN per DN; extrapolation along the gain).
    pub fn scaled(&self, iso: u32, k: f64) -> Self {
        Self {
            iso,
            rows: self.rows.clone().map(|d| d.map(|d| d.scaled(k))),
            columns: self.columns.clone().map(|d| d.map(|d| d.scaled(k))),
            frames: self.frames.as_ref().map(|f| f.scaled(k)),
            frames_used: self.frames_used,
            fpn: self.fpn.as_ref().map(|f| f.scaled(k)),
        }
    }

    /// Between two ISOs' components at fraction `t` (0 = `a`).
    pub fn blend(iso: u32, a: &Self, b: &Self, t: f64) -> Self {
        let pair = |x: &Option<OffsetDistribution>, y: &Option<OffsetDistribution>| {
            blend_either(x, y, t, OffsetDistribution::blend, OffsetDistribution::scaled)
        };
        Self {
            iso,
            rows: std::array::from_fn(|p| pair(&a.rows[p], &b.rows[p])),
            columns: std::array::from_fn(|p| pair(&a.columns[p], &b.columns[p])),
            frames: blend_either(&a.frames, &b.frames, t, FrameOffsets::blend, FrameOffsets::scaled),
            frames_used: a.frames_used.min(b.frames_used),
            fpn: blend_either(&a.fpn, &b.fpn, t, FixedPattern::blend, FixedPattern::scaled),
        }
    }

    pub fn problem(&self) -> Option<String> {
        for (name, d) in [("row", &self.rows), ("column", &self.columns)] {
            for (p, d) in d.iter().enumerate() {
                if let Some(why) = d.as_ref().and_then(OffsetDistribution::problem) {
                    return Some(format!("{name} offsets of parity {p}: {why}"));
                }
            }
        }
        if let Some(w) = self.fpn.as_ref().and_then(FixedPattern::problem) {
            return Some(format!("fixed pattern: {w}"));
        }
        self.frames.as_ref().and_then(FrameOffsets::problem).map(|w| format!("frame offsets: {w}"))
    }
}

/// One component between two ISOs at fraction `t`: blended where both have it, else the one
/// that has it faded towards the other (scaled by its weight).
fn blend_either<T>(
    a: &Option<T>,
    b: &Option<T>,
    t: f64,
    blend: impl Fn(&T, &T, f64) -> T,
    scaled: impl Fn(&T, f64) -> T,
) -> Option<T> {
    match (a, b) {
        (Some(x), Some(y)) => Some(blend(x, y, t)),
        (Some(x), None) => Some(scaled(x, 1.0 - t)),
        (None, Some(y)) => Some(scaled(y, t)),
        (None, None) => None,
    }
}

/// Which noise components synthesis adds.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Components {
    pub pixel: bool,
    pub row: bool,
    pub column: bool,
    pub frame: bool,
    /// The fixed pattern (from dark frames).
    pub fpn: bool,
}

impl Components {
    /// Every calibrated component (the default).
    pub const ALL: Self = Self { pixel: true, row: true, column: true, frame: true, fpn: true };
    /// Every component but the fixed pattern (`own`): for clean images averaged from this
    /// sensor's own frames (held-out captures, burst means, re-noising), which carry its pattern
    /// already. On EMVA 1288 set 002 the default read above pixel-only by about the pattern's
    /// variance against such clean images; without `fpn` it reads as pixel-only
    /// (method.md, *Fixed pattern*, "Which components for which clean image").
    pub const ON_OWN_CAPTURES: Self = Self { pixel: true, row: true, column: true, frame: true, fpn: false };
    /// The pixel-independent model alone (version 2 packs, `--components pixel`).
    pub const PIXEL: Self = Self { pixel: true, row: false, column: false, frame: false, fpn: false };

    /// Parses `pixel,row,column,frame,fpn` (also `col`, `dsnu`; `all` for every component, `own`
    /// for [`Self::ON_OWN_CAPTURES`]).
    pub fn parse(s: &str) -> Result<Self, String> {
        let mut c = Self { pixel: false, row: false, column: false, frame: false, fpn: false };
        for part in s.split(',').map(str::trim).filter(|p| !p.is_empty()) {
            match part.to_ascii_lowercase().as_str() {
                "all" => c = Self::ALL,
                "own" => c = Self { pixel: true, row: true, column: true, frame: true, fpn: c.fpn },
                "pixel" => c.pixel = true,
                "row" | "rows" => c.row = true,
                "column" | "columns" | "col" => c.column = true,
                "frame" | "frames" => c.frame = true,
                "fpn" | "dsnu" | "pattern" => c.fpn = true,
                other => {
                    return Err(format!(
                        "unknown noise component {other:?}; choose from pixel,row,column,frame,fpn, or all (every one) or own (all but fpn, for clean images averaged from this sensor's own frames)"
                    ));
                }
            }
        }
        if !c.pixel {
            return Err("the components must include pixel (the per-pixel noise every other component adds to)".into());
        }
        Ok(c)
    }

    /// Whether any structured component is asked for.
    pub fn structured(&self) -> bool {
        self.row || self.column || self.frame || self.fpn
    }
}

impl Default for Components {
    fn default() -> Self {
        Self::ALL
    }
}

impl std::fmt::Display for Components {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let names: Vec<&str> = [
            (self.pixel, "pixel"),
            (self.row, "row"),
            (self.column, "column"),
            (self.frame, "frame"),
            (self.fpn, "fpn"),
        ]
        .iter()
        .filter(|(on, _)| *on)
        .map(|(_, n)| *n)
        .collect();
        write!(f, "{}", names.join(","))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn components_parse() {
        assert_eq!(Components::parse("pixel").unwrap(), Components::PIXEL);
        assert_eq!(Components::parse("all").unwrap(), Components::ALL);
        assert_eq!(Components::parse("pixel,row,column,frame,fpn").unwrap(), Components::ALL);
        assert_eq!(Components::parse("own").unwrap(), Components::ON_OWN_CAPTURES);
        assert_eq!(Components::parse("Own").unwrap(), Components::parse("pixel,row,column,frame").unwrap());
        assert_eq!(Components::parse("own,fpn").unwrap(), Components::ALL);
        assert_eq!(Components::parse("fpn,own").unwrap(), Components::ALL);
        assert!(!Components::parse("pixel,row,column,frame").unwrap().fpn);
        assert!(Components::parse("row").unwrap_err().contains("must include pixel"));
        assert!(Components::parse("pixel,dsnu").unwrap().fpn);
        assert!(Components::parse("pixel,banana").unwrap_err().contains("banana"));
        assert_eq!(Components::ALL.to_string(), "pixel,row,column,frame,fpn");
    }

    #[test]
    fn quantile_interpolation() {
        let q = [-1.0f32, 0.0, 3.0];
        assert_eq!(quantile_at(&q, 0.0), -1.0);
        assert_eq!(quantile_at(&q, 0.25), -0.5);
        assert_eq!(quantile_at(&q, 0.75), 1.5);
        assert_eq!(quantile_at(&q, 1.0), 3.0);
    }
}
