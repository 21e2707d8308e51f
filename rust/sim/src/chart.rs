//! The scene: a colour-checker-like grid of uniform patches with blurred edges over a
//! background, lit by a lamp, seen through a lens with some vignetting.
//!
//! Coordinates are continuous pixel coordinates: pixel `(row, col)` covers
//! `[col, col + 1) × [row, row + 1)` and is sampled at its centre. A blurred patch is the
//! rectangle convolved with a Gaussian of `edge_blur_px`, which is separable, so a whole frame is
//! rendered with a few error functions per row and column.

use ndarray::Array2;
use noisecal_core::{CfaPattern, model::layout::CfaColor};

use crate::error::SimError;

/// Linear reflectances of the 24 ColorChecker Classic patches (from their sRGB values).
const CHECKER_SRGB: [[u8; 3]; 24] = [
    [115, 82, 68],
    [194, 150, 130],
    [98, 122, 157],
    [87, 108, 67],
    [133, 128, 177],
    [103, 189, 170],
    [214, 126, 44],
    [80, 91, 166],
    [193, 90, 99],
    [94, 60, 108],
    [157, 188, 64],
    [224, 163, 46],
    [56, 61, 150],
    [70, 148, 73],
    [175, 54, 60],
    [231, 199, 31],
    [187, 86, 149],
    [8, 133, 161],
    [243, 243, 242],
    [200, 200, 200],
    [160, 160, 160],
    [122, 122, 121],
    [85, 85, 85],
    [52, 52, 52],
];

fn srgb_to_linear(v: u8) -> f32 {
    let c = v as f32 / 255.0;
    if c <= 0.04045 { c / 12.92 } else { ((c + 0.055) / 1.055).powf(2.4) }
}

/// Index 0, 1, 2 of a CFA colour (R, G, B).
#[inline]
pub(crate) fn color_index(c: CfaColor) -> usize {
    match c {
        CfaColor::Red => 0,
        CfaColor::Green => 1,
        CfaColor::Blue => 2,
    }
}

/// One patch of a [`Chart`], in continuous pixel coordinates.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct PatchRect {
    /// Patch row in the grid (0 at the top).
    pub grid_row: usize,
    /// Patch column in the grid (0 at the left).
    pub grid_col: usize,
    /// Left edge (x, pixels).
    pub x0: f32,
    /// Right edge (x, pixels).
    pub x1: f32,
    /// Top edge (y, pixels).
    pub y0: f32,
    /// Bottom edge (y, pixels).
    pub y1: f32,
    /// Linear reflectance per colour (R, G, B).
    pub reflectance: [f32; 3],
}

impl PatchRect {
    /// Pixel rows and columns whose centres lie at least `margin_px` inside the patch (`None`
    /// if nothing is left). A margin of 3·blur + 2 px keeps clear of edges and jitter.
    pub fn interior(&self, margin_px: f32) -> Option<(std::ops::Range<usize>, std::ops::Range<usize>)> {
        let span = |a: f32, b: f32| {
            let lo = (a + margin_px - 0.5).ceil().max(0.0) as usize;
            let hi_f = (b - margin_px - 0.5).floor();
            if hi_f < 0.0 {
                return None;
            }
            let hi = hi_f as usize + 1;
            (hi > lo).then_some(lo..hi)
        };
        Some((span(self.y0, self.y1)?, span(self.x0, self.x1)?))
    }
}

/// A test chart filling a `width × height` sensor: a `grid_rows × grid_cols` grid of uniform
/// patches with blurred edges over a uniform background. All fields are public.
#[derive(Debug, Clone, PartialEq)]
pub struct Chart {
    /// Image width (pixels).
    pub width: u32,
    /// Image height (pixels).
    pub height: u32,
    /// Number of patch rows.
    pub grid_rows: usize,
    /// Number of patch columns.
    pub grid_cols: usize,
    /// Linear reflectance (R, G, B) of each patch, row-major, `grid_rows × grid_cols` entries.
    pub patches: Vec<[f32; 3]>,
    /// Linear reflectance (R, G, B) around and between the patches.
    pub background: [f32; 3],
    /// x of the left edge of the first patch column (pixels).
    pub left: f32,
    /// y of the top edge of the first patch row (pixels).
    pub top: f32,
    /// Patch width (pixels).
    pub patch_width: f32,
    /// Patch height (pixels).
    pub patch_height: f32,
    /// Gap between neighbouring patches (pixels).
    pub gap: f32,
    /// Gaussian blur of the edges (sigma, pixels); 0 for sharp edges.
    pub edge_blur_px: f32,
    /// Electrons per second collected at reflectance 1 per colour channel (lamp spectrum ×
    /// channel sensitivity), before vignetting and PRNU.
    pub lamp_electrons_per_s: [f32; 3],
    /// Relative illumination loss in the image corners (0.1: corners get 90 %), quadratic in
    /// the distance from the centre; fixed to the sensor, not to the chart.
    pub vignetting: f32,
    /// A per-pixel scene replacing the patch grid (natural-statistics scenes for the denoiser
    /// benchmark, [`Chart::natural`]); `None` for a chart.
    pub texture: Option<std::sync::Arc<Texture>>,
}

/// A scene given per pixel: linear reflectance (R, G, B) of each pixel, row-major, looked up at
/// the nearest pixel (outside the image, the nearest edge pixel).
#[derive(Debug, Clone, PartialEq)]
pub struct Texture {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<[f32; 3]>,
}

impl Texture {
    #[inline]
    fn at(&self, x: f32, y: f32, c: usize) -> f32 {
        let xi = (x.floor().max(0.0) as usize).min(self.width as usize - 1);
        let yi = (y.floor().max(0.0) as usize).min(self.height as usize - 1);
        self.rgb[yi * self.width as usize + xi][c]
    }

    /// Bilinear between texel centres (edges clamped): a sub-pixel shift moves the scene, where
    /// [`Self::at`] (nearest texel) keeps every pixel's value under shifts below half a pixel.
    #[inline]
    fn smooth_at(&self, x: f32, y: f32, c: usize) -> f32 {
        let (w, h) = (self.width as usize, self.height as usize);
        let (u, v) = ((x - 0.5).clamp(0.0, (w - 1) as f32), (y - 0.5).clamp(0.0, (h - 1) as f32));
        let (x0, y0) = (u.floor() as usize, v.floor() as usize);
        let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
        let (fx, fy) = (u - x0 as f32, v - y0 as f32);
        let t = |xi: usize, yi: usize| self.rgb[yi * w + xi][c];
        let top = t(x0, y0) + (t(x1, y0) - t(x0, y0)) * fx;
        let bottom = t(x0, y1) + (t(x1, y1) - t(x0, y1)) * fx;
        top + (bottom - top) * fy
    }
}

impl Chart {
    /// A 6 × 4 ColorChecker-like chart (linear reflectances of the classic chart, white 0.9,
    /// black 0.03) centred on a dark surround (0.05), filling about 85 % of the frame, with
    /// edges blurred by `0.0012 × max(width, height)` px (0.7 … 4 px), a slightly bluish-deficient
    /// lamp (R, G, B = 0.6, 1.0, 0.75 × 2·10⁵ e⁻/s) and 10 % corner vignetting.
    pub fn color_checker(width: u32, height: u32) -> Result<Self, SimError> {
        check_size(width, height)?;
        let (cols, rows) = (6usize, 4usize);
        let pitch = (0.85 * width as f32 / cols as f32).min(0.85 * height as f32 / rows as f32);
        let gap = 0.2 * pitch;
        let patch = pitch - gap;
        let total_w = cols as f32 * pitch - gap;
        let total_h = rows as f32 * pitch - gap;
        let patches = CHECKER_SRGB.iter().map(|c| c.map(srgb_to_linear)).collect();
        let chart = Self {
            width,
            height,
            grid_rows: rows,
            grid_cols: cols,
            patches,
            background: [0.05; 3],
            left: (width as f32 - total_w) / 2.0,
            top: (height as f32 - total_h) / 2.0,
            patch_width: patch,
            patch_height: patch,
            gap,
            edge_blur_px: (0.0012 * width.max(height) as f32).clamp(0.7, 4.0),
            lamp_electrons_per_s: [1.2e5, 2.0e5, 1.5e5],
            vignetting: 0.1,
            texture: None,
        };
        chart.validate()?;
        Ok(chart)
    }

    /// A uniform field of one reflectance (R, G, B), no patches, no vignetting: every pixel is
    /// flat (for flat-field statistics).
    pub fn flat(width: u32, height: u32, reflectance: [f32; 3]) -> Result<Self, SimError> {
        check_size(width, height)?;
        let chart = Self {
            width,
            height,
            grid_rows: 0,
            grid_cols: 0,
            patches: Vec::new(),
            background: reflectance,
            left: 0.0,
            top: 0.0,
            patch_width: 1.0,
            patch_height: 1.0,
            gap: 0.0,
            edge_blur_px: 0.0,
            lamp_electrons_per_s: [1.2e5, 2.0e5, 1.5e5],
            vignetting: 0.0,
            texture: None,
        };
        chart.validate()?;
        Ok(chart)
    }

    /// A natural-statistics scene of `width × height` pixels for the denoiser benchmark (not a
    /// chart): dead leaves (opaque discs, front to back, radii with density ∝ r⁻³ between 1.5 px
    /// and a quarter of the larger side, which gives the 1/f² power spectrum of natural images),
    /// each leaf a colour of log-uniform luminance over 0.004 … 0.9 (dark shadows to white) and
    /// random chroma, under a smooth illumination gradient of up to 2 stops across the frame and
    /// 10 % corner vignetting. The same `seed` gives the same scene.
    pub fn natural(width: u32, height: u32, seed: u64) -> Result<Self, SimError> {
        use crate::noise::uniform_open;
        use rand::SeedableRng;
        let mut chart = Self::flat(width, height, [0.0; 3])?;
        let mut rng = rand_pcg::Pcg64Mcg::seed_from_u64(seed ^ 0x6e61_7475_7261_6c5f);
        let (w, h) = (width as usize, height as usize);
        let mut rgb = vec![[0.0f32; 3]; w * h];
        let mut covered = vec![false; w * h];
        let mut left = w * h;
        let (rmin, rmax) = (1.5f64, (w.max(h) as f64 / 4.0).max(2.0));
        // Inverse CDF of the density ∝ r⁻³ on [rmin, rmax].
        let (a, b) = (rmin.powi(-2), rmax.powi(-2));
        let mut leaves = 0usize;
        while left > 0 && leaves < 200_000 {
            leaves += 1;
            let r = (a - uniform_open(&mut rng) * (a - b)).powf(-0.5);
            let cx = uniform_open(&mut rng) * (w as f64 + 2.0 * r) - r;
            let cy = uniform_open(&mut rng) * (h as f64 + 2.0 * r) - r;
            let lum = (0.004f64.ln() + uniform_open(&mut rng) * (0.9f64 / 0.004).ln()).exp();
            let chroma: [f64; 3] = std::array::from_fn(|_| 0.6 + 0.8 * uniform_open(&mut rng));
            let mean = (chroma[0] + chroma[1] + chroma[2]) / 3.0;
            let color = chroma.map(|c| (lum * c / mean).min(1.0) as f32);
            let (x0, x1) = ((cx - r).floor().max(0.0) as usize, ((cx + r).ceil().max(0.0) as usize).min(w));
            let (y0, y1) = ((cy - r).floor().max(0.0) as usize, ((cy + r).ceil().max(0.0) as usize).min(h));
            for y in y0..y1 {
                let dy = y as f64 + 0.5 - cy;
                for x in x0..x1 {
                    let dx = x as f64 + 0.5 - cx;
                    let i = y * w + x;
                    if !covered[i] && dx * dx + dy * dy <= r * r {
                        covered[i] = true;
                        rgb[i] = color;
                        left -= 1;
                    }
                }
            }
        }
        // A smooth illumination gradient: exp2 of a plane spanning up to 2 stops, at most 1.
        let (gx, gy) = (uniform_open(&mut rng) * 2.0 - 1.0, uniform_open(&mut rng) * 2.0 - 1.0);
        let norm = (gx.abs() + gy.abs()).max(1e-9);
        for (i, v) in rgb.iter_mut().enumerate() {
            let (x, y) = ((i % w) as f64 / w as f64, (i / w) as f64 / h as f64);
            let e: f64 = 2.0 * ((gx * x + gy * y) / norm - (gx.max(0.0) + gy.max(0.0)) / norm);
            let f = e.exp2() as f32;
            *v = v.map(|c| c * f);
        }
        chart.vignetting = 0.1;
        chart.texture = Some(std::sync::Arc::new(Texture { width, height, rgb }));
        chart.validate()?;
        Ok(chart)
    }

    /// Checks sizes, counts and that every number is finite and in range.
    pub fn validate(&self) -> Result<(), SimError> {
        check_size(self.width, self.height)?;
        let bad = |what: &'static str, value: String, fix: &'static str| SimError::Parameter { what, value, fix };
        if let Some(t) = &self.texture {
            if (t.width, t.height) != (self.width, self.height) || t.rgb.len() != t.width as usize * t.height as usize {
                return Err(bad(
                    "Chart::texture",
                    format!(
                        "{}×{} with {} values for a {}×{} chart",
                        t.width,
                        t.height,
                        t.rgb.len(),
                        self.width,
                        self.height
                    ),
                    "give one reflectance per pixel of the chart",
                ));
            }
            if !t.rgb.iter().all(|r| r.iter().all(|v| v.is_finite() && (0.0..=1.5).contains(v))) {
                return Err(bad(
                    "Chart::texture",
                    "out of range".into(),
                    "reflectances must be finite and in [0, 1.5]",
                ));
            }
        }
        if self.patches.len() != self.grid_rows * self.grid_cols {
            return Err(bad(
                "Chart::patches",
                format!("{} entries for a {}×{} grid", self.patches.len(), self.grid_rows, self.grid_cols),
                "give one reflectance per patch (grid_rows × grid_cols)",
            ));
        }
        let refl_ok = |r: &[f32; 3]| r.iter().all(|v| v.is_finite() && (0.0..=1.5).contains(v));
        if !self.patches.iter().all(refl_ok) || !refl_ok(&self.background) {
            return Err(bad("Chart reflectance", "out of range".into(), "reflectances must be finite and in [0, 1.5]"));
        }
        for (what, v) in [
            ("Chart::left", self.left),
            ("Chart::top", self.top),
            ("Chart::gap", self.gap),
            ("Chart::edge_blur_px", self.edge_blur_px),
            ("Chart::vignetting", self.vignetting),
        ] {
            if !v.is_finite() || v < 0.0 && what != "Chart::left" && what != "Chart::top" {
                return Err(bad(what, v.to_string(), "must be a finite number (≥ 0 except left/top)"));
            }
        }
        if self.vignetting >= 1.0 {
            return Err(bad("Chart::vignetting", self.vignetting.to_string(), "must be in [0, 1)"));
        }
        if !(self.patch_width.is_finite()
            && self.patch_width > 0.0
            && self.patch_height.is_finite()
            && self.patch_height > 0.0)
        {
            return Err(bad(
                "Chart patch size",
                format!("{}×{}", self.patch_width, self.patch_height),
                "patch width and height must be positive",
            ));
        }
        if !self.lamp_electrons_per_s.iter().all(|v| v.is_finite() && *v > 0.0) {
            return Err(bad(
                "Chart::lamp_electrons_per_s",
                format!("{:?}", self.lamp_electrons_per_s),
                "must be positive electron rates",
            ));
        }
        Ok(())
    }

    /// The patches with their edges and reflectances, row-major.
    pub fn patch_rects(&self) -> Vec<PatchRect> {
        let mut v = Vec::with_capacity(self.patches.len());
        for i in 0..self.grid_rows {
            for j in 0..self.grid_cols {
                let (x0, x1) = self.col_span(j);
                let (y0, y1) = self.row_span(i);
                v.push(PatchRect {
                    grid_row: i,
                    grid_col: j,
                    x0,
                    x1,
                    y0,
                    y1,
                    reflectance: self.patches[i * self.grid_cols + j],
                });
            }
        }
        v
    }

    /// Largest reflectance × lamp rate over patches, background and colours (e⁻/s): the
    /// brightest spot of the chart before vignetting.
    pub fn max_rate(&self) -> f32 {
        let texture = self.texture.as_deref().map_or(&[][..], |t| &t.rgb[..]);
        self.patches
            .iter()
            .chain(std::iter::once(&self.background))
            .chain(texture)
            .flat_map(|r| (0..3).map(move |c| r[c] * self.lamp_electrons_per_s[c]))
            .fold(0.0, f32::max)
    }

    fn col_span(&self, j: usize) -> (f32, f32) {
        let x0 = self.left + j as f32 * (self.patch_width + self.gap);
        (x0, x0 + self.patch_width)
    }

    fn row_span(&self, i: usize) -> (f32, f32) {
        let y0 = self.top + i as f32 * (self.patch_height + self.gap);
        (y0, y0 + self.patch_height)
    }

    /// Expected electron rate (e⁻/s, before PRNU) at pixel `(row, col)` for a CFA colour, with
    /// the scene shifted by `jitter = (dx, dy)` pixels.
    pub fn irradiance(&self, row: usize, col: usize, color: CfaColor, jitter: (f32, f32)) -> f32 {
        let x = col as f32 + 0.5 - jitter.0;
        let y = row as f32 + 0.5 - jitter.1;
        let c = color_index(color);
        self.lamp_electrons_per_s[c] * self.vignette(row, col) * self.reflectance_at(x, y, c)
    }

    /// Illumination factor of the vignetting at a pixel (1 at the centre).
    pub fn vignette(&self, row: usize, col: usize) -> f32 {
        let (vx, vy) = self.vignette_axes();
        1.0 - self.vignetting * (vx(col) + vy(row))
    }

    fn vignette_axes(&self) -> (impl Fn(usize) -> f32, impl Fn(usize) -> f32) {
        let cx = self.width as f32 / 2.0;
        let cy = self.height as f32 / 2.0;
        let r2 = cx * cx + cy * cy;
        (move |x: usize| (x as f32 + 0.5 - cx).powi(2) / r2, move |y: usize| (y as f32 + 0.5 - cy).powi(2) / r2)
    }

    /// Expected electron rate (e⁻/s, before PRNU) of every pixel for its CFA colour, scene
    /// shifted by `jitter`.
    pub fn render(&self, cfa: CfaPattern, jitter: (f32, f32)) -> Array2<f32> {
        let p = self.prepare(jitter);
        let (w, h) = (self.width as usize, self.height as usize);
        let mut v = vec![0.0f32; w * h];
        let colors = cfa.colors().map(color_index);
        for (y, row) in v.chunks_mut(w).enumerate() {
            p.row_rates(y, [colors[(y & 1) * 2], colors[(y & 1) * 2 + 1]], row);
        }
        Array2::from_shape_vec((h, w), v).expect("w × h values")
    }

    /// Per-frame tables for row rendering of the scene shifted by `jitter`, rotated by
    /// `rotation` (radians) and scaled by `scale` about the image centre. A pure shift keeps the
    /// separable tables; a rotation or scale evaluates the chart per pixel.
    pub(crate) fn prepare_posed(&self, jitter: (f32, f32), rotation: f32, scale: f32) -> Prepared<'_> {
        let mut p = self.prepare(jitter);
        if rotation != 0.0 || scale != 1.0 {
            p.pose = Some(Pose { dx: jitter.0, dy: jitter.1, cos: rotation.cos(), sin: rotation.sin(), scale });
        }
        p
    }

    /// [`Self::prepare_posed`] for a moving scene: a texture is sampled bilinearly, so its
    /// sub-pixel motion shows (a chart's blurred edges move already).
    pub(crate) fn prepare_moving(&self, jitter: (f32, f32), rotation: f32, scale: f32) -> Prepared<'_> {
        let mut p = self.prepare_posed(jitter, rotation, scale);
        p.smooth = true;
        p
    }

    /// Electron rate of the chart (before lamp and vignetting) for colour `c` at chart
    /// coordinates `(x, y)`.
    fn reflectance_at(&self, x: f32, y: f32, c: usize) -> f32 {
        if let Some(t) = &self.texture {
            return t.at(x, y, c);
        }
        let mut s = self.background[c];
        for i in 0..self.grid_rows {
            let (y0, y1) = self.row_span(i);
            let fy = band(y, y0, y1, self.edge_blur_px);
            if fy == 0.0 {
                continue;
            }
            for j in 0..self.grid_cols {
                let (x0, x1) = self.col_span(j);
                let fx = band(x, x0, x1, self.edge_blur_px);
                if fx != 0.0 {
                    s += (self.patches[i * self.grid_cols + j][c] - self.background[c]) * fy * fx;
                }
            }
        }
        s
    }

    /// Per-frame tables for fast row rendering.
    pub(crate) fn prepare(&self, jitter: (f32, f32)) -> Prepared<'_> {
        let (w, h) = (self.width as usize, self.height as usize);
        let (gc, gr) = (self.grid_cols, self.grid_rows);
        let mut fx = vec![0.0f32; w * gc];
        for x in 0..w {
            let xc = x as f32 + 0.5 - jitter.0;
            for j in 0..gc {
                let (x0, x1) = self.col_span(j);
                fx[x * gc + j] = band(xc, x0, x1, self.edge_blur_px);
            }
        }
        let mut fy = vec![0.0f32; h * gr];
        for y in 0..h {
            let yc = y as f32 + 0.5 - jitter.1;
            for i in 0..gr {
                let (y0, y1) = self.row_span(i);
                fy[y * gr + i] = band(yc, y0, y1, self.edge_blur_px);
            }
        }
        let (vxf, vyf) = self.vignette_axes();
        let vx = (0..w).map(|x| self.vignetting * vxf(x)).collect();
        let vy = (0..h).map(|y| self.vignetting * vyf(y)).collect();
        // A per-pixel scene is evaluated per pixel (the pose path with the identity pose).
        let pose =
            self.texture.is_some().then_some(Pose { dx: jitter.0, dy: jitter.1, cos: 1.0, sin: 0.0, scale: 1.0 });
        Prepared { chart: self, fx, fy, vx, vy, pose, smooth: false }
    }
}

/// A frame's scene pose beyond a shift: the chart point a pixel sees is the pixel centre
/// minus the shift, rotated back and unscaled about the image centre.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Pose {
    dx: f32,
    dy: f32,
    cos: f32,
    sin: f32,
    scale: f32,
}

/// Separable tables of one frame's scene position.
pub(crate) struct Prepared<'a> {
    chart: &'a Chart,
    /// `fx[x * grid_cols + j]`: blurred indicator of patch column j at pixel column x.
    fx: Vec<f32>,
    /// `fy[y * grid_rows + i]`: blurred indicator of patch row i at pixel row y.
    fy: Vec<f32>,
    vx: Vec<f32>,
    vy: Vec<f32>,
    /// Rotation or scale: the chart is evaluated per pixel.
    pose: Option<Pose>,
    /// A texture is sampled bilinearly ([`Chart::prepare_moving`]), not at its nearest texel.
    smooth: bool,
}

impl Prepared<'_> {
    /// Electron rates of row `y`; `colors` are the colour indices of even and odd columns.
    pub(crate) fn row_rates(&self, y: usize, colors: [usize; 2], out: &mut [f32]) {
        let ch = self.chart;
        if let Some(p) = self.pose {
            let (cx, cy) = (ch.width as f32 / 2.0, ch.height as f32 / 2.0);
            let vy = self.vy[y];
            let v = y as f32 + 0.5 - cy - p.dy;
            for (x, o) in out.iter_mut().enumerate() {
                let c = colors[x & 1];
                let u = x as f32 + 0.5 - cx - p.dx;
                let xs = cx + (p.cos * u + p.sin * v) / p.scale;
                let ys = cy + (-p.sin * u + p.cos * v) / p.scale;
                let r = match &ch.texture {
                    Some(t) if self.smooth => t.smooth_at(xs, ys, c),
                    _ => ch.reflectance_at(xs, ys, c),
                };
                *o = ch.lamp_electrons_per_s[c] * (1.0 - self.vx[x] - vy) * r;
            }
            return;
        }
        let (gc, gr) = (ch.grid_cols, ch.grid_rows);
        // coef[k][j] = Σ_i (ρ_ij − bg) · fy_i(y) for the row's two colours.
        let mut coef = vec![0.0f32; 2 * gc];
        for (k, &c) in colors.iter().enumerate() {
            for i in 0..gr {
                let f = self.fy[y * gr + i];
                if f == 0.0 {
                    continue;
                }
                for j in 0..gc {
                    coef[k * gc + j] += (ch.patches[i * gc + j][c] - ch.background[c]) * f;
                }
            }
        }
        let vy = self.vy[y];
        for (x, o) in out.iter_mut().enumerate() {
            let k = x & 1;
            let c = colors[k];
            let fx = &self.fx[x * gc..x * gc + gc];
            let cf = &coef[k * gc..k * gc + gc];
            let mut s = ch.background[c];
            for j in 0..gc {
                s += cf[j] * fx[j];
            }
            *o = ch.lamp_electrons_per_s[c] * (1.0 - self.vx[x] - vy) * s;
        }
    }
}

fn check_size(width: u32, height: u32) -> Result<(), SimError> {
    if width < 2 || height < 2 || width % 2 == 1 || height % 2 == 1 || width > 16384 || height > 16384 {
        return Err(SimError::Parameter {
            what: "chart size",
            value: format!("{width}×{height}"),
            fix: "use an even width and height between 2 and 16384 pixels (a whole number of Bayer quads)",
        });
    }
    Ok(())
}

/// Blurred indicator of `[a, b]` at `x`: Φ((b − x)/σ) − Φ((a − x)/σ), or the sharp indicator.
#[inline]
fn band(x: f32, a: f32, b: f32, sigma: f32) -> f32 {
    if sigma <= 0.0 {
        return if x >= a && x < b { 1.0 } else { 0.0 };
    }
    let k = std::f32::consts::FRAC_1_SQRT_2 / sigma;
    let lo = (a - x) * k;
    let hi = (b - x) * k;
    if lo > 6.0 || hi < -6.0 {
        return 0.0;
    }
    0.5 * (erf(hi) - erf(lo))
}

/// Error function (Abramowitz & Stegun 7.1.26, |error| < 1.5·10⁻⁷).
fn erf(x: f32) -> f32 {
    let t = 1.0 / (1.0 + 0.327_591_1 * x.abs());
    let y = 1.0
        - (((((1.061_405_4 * t - 1.453_152_1) * t) + 1.421_413_7) * t - 0.284_496_74) * t + 0.254_829_6)
            * t
            * (-x * x).exp();
    if x >= 0.0 { y } else { -y }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checker_geometry_and_render_agree_with_pointwise_irradiance() {
        let c = Chart::color_checker(96, 64).expect("chart");
        let rects = c.patch_rects();
        assert_eq!(rects.len(), 24);
        assert!(rects.iter().all(|r| r.x0 >= 0.0 && r.x1 <= 96.0 && r.y0 >= 0.0 && r.y1 <= 64.0));
        let img = c.render(CfaPattern::Rggb, (0.3, -0.2));
        let colors = CfaPattern::Rggb.colors();
        for (row, col) in [(0, 0), (10, 17), (31, 48), (63, 95), (40, 3)] {
            let want = c.irradiance(row, col, colors[noisecal_core::model::layout::position(row, col)], (0.3, -0.2));
            assert!((img[[row, col]] - want).abs() <= 1e-3 * want.abs() + 1e-2, "{row},{col}");
        }
        // The white patch's interior has the white reflectance × green lamp × vignetting.
        let white = rects[18];
        let (rr, cc) = white.interior(3.0 * c.edge_blur_px + 1.0).expect("interior");
        for (r, k) in [(rr.start, cc.start), (rr.end - 1, cc.end - 1), (rr.start + 1, cc.end - 2)] {
            let ci = color_index(colors[noisecal_core::model::layout::position(r, k)]);
            let want = white.reflectance[ci] * c.lamp_electrons_per_s[ci] * c.vignette(r, k);
            assert!((img[[r, k]] - want).abs() < 1e-4 * want, "{} vs {want}", img[[r, k]]);
        }
        // Blurred edge: half-way between patch and background at the edge.
        let x = white.x0;
        let mid = 0.5 * (white.reflectance[1] + c.background[1]);
        let y = (white.y0 + white.y1) / 2.0;
        let at = c.irradiance(y as usize, x as usize, CfaColor::Green, (0.5 - x.fract(), 0.0))
            / (c.lamp_electrons_per_s[1] * c.vignette(y as usize, x as usize));
        assert!((at - mid).abs() < 0.01, "{at} vs {mid}");
    }

    #[test]
    fn natural_scenes_are_seeded_textured_and_span_the_range() {
        let a = Chart::natural(128, 96, 3).expect("scene");
        assert_eq!(a, Chart::natural(128, 96, 3).expect("scene"));
        assert_ne!(a, Chart::natural(128, 96, 4).expect("scene"));
        let img = a.render(CfaPattern::Rggb, (0.0, 0.0));
        let colors = CfaPattern::Rggb.colors();
        for (row, col) in [(0, 0), (10, 17), (95, 127), (40, 3)] {
            let want = a.irradiance(row, col, colors[noisecal_core::model::layout::position(row, col)], (0.0, 0.0));
            assert!((img[[row, col]] - want).abs() <= 1e-4 * want.abs() + 1e-3, "{row},{col}");
        }
        // Not a chart: many distinct levels, dark and bright parts (over 20× apart in green).
        let green: Vec<f32> = img.indexed_iter().filter(|((y, x), _)| (y + x) % 2 == 1).map(|(_, v)| *v).collect();
        let mut sorted = green.clone();
        sorted.sort_by(f32::total_cmp);
        let (p5, p95) = (sorted[sorted.len() / 20], sorted[sorted.len() * 19 / 20]);
        assert!(p95 > 20.0 * p5, "p5 {p5}, p95 {p95}");
        sorted.dedup();
        assert!(sorted.len() > 200, "{} distinct levels", sorted.len());
        // Exposed by its brightest texel, not by the (black) background of the flat chart below it.
        assert!(a.max_rate() > 0.3 * a.lamp_electrons_per_s[1], "{}", a.max_rate());
        let mut bad = a.clone();
        bad.texture = Some(std::sync::Arc::new(Texture { width: 4, height: 4, rgb: vec![[0.5; 3]; 16] }));
        assert!(bad.validate().expect_err("size mismatch").to_string().contains("Chart::texture"));
    }

    #[test]
    fn bad_sizes_are_refused() {
        assert!(Chart::color_checker(95, 64).expect_err("must be refused").to_string().contains("even width"));
        assert!(Chart::flat(0, 64, [0.5; 3]).is_err());
        let mut c = Chart::flat(8, 8, [0.5; 3]).expect("flat");
        c.patches.push([0.1; 3]);
        assert!(c.validate().expect_err("must be refused").to_string().contains("Chart::patches"));
    }
}
