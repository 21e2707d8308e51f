//! The simulator: renders the chart, runs the signal chain of [`SensorModel`] per pixel and
//! returns raw frames with their metadata. Deterministic in (seed, ISO, exposure, frame index)
//! whatever the call order or thread count: every row draws from its own PCG-64 stream keyed
//! by those four numbers.

use ndarray::Array2;
use noisecal_core::{FrameMeta, POSITIONS, SensorLayout};
use rand::Rng;
use rand_pcg::Pcg64Mcg;
use rayon::prelude::*;

use crate::chart::{Chart, color_index};
use crate::error::SimError;
use crate::model::ReadNoiseShape;
use crate::model::{IsoSettings, MOTION_BLOCK, Motion, SensorModel};
use crate::noise::{StudentT, TukeyLambda, UnitNoise, hashed_unit, mix64, normal, poisson, round_clamp, uniform_open};
use crate::truth::StructuredTruth;

/// Fraction of the black-to-white range at which [`Simulator::mid_range_exposure_ns`] puts the
/// brightest spot of the chart.
pub const MID_RANGE_FRACTION: f64 = 0.35;

/// Per-frame effects that are not sensor noise: flicker and misalignment.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameEffects {
    /// Brightness multiplier of the frame (1 without flicker).
    pub flicker: f32,
    /// Scene shift `(dx, dy)` in pixels (the motion's translation plus the jitter).
    pub jitter: (f32, f32),
    /// Scene rotation about the image centre (radians; 0 without [`Motion`](crate::Motion)).
    pub rotation: f32,
    /// Scene scale about the image centre (1 without [`Motion`](crate::Motion)).
    pub scale: f32,
}

/// The per-pixel signal chain at one ISO and CFA position.
#[derive(Debug, Clone, Copy)]
struct Chain {
    black: f64,
    offset: f64,
    g: f64,
    d: f64,
    pre: f64,
    post: f64,
    tails: UnitNoise,
    fw: f64,
    white: f64,
    gauss_above: f64,
}

impl Chain {
    /// One output value for mean electrons `lambda`; `extra` shifts the ADC input (DN), `row`
    /// is the row-noise offset (DN).
    #[inline]
    fn sample<R: Rng + ?Sized>(&self, lambda: f64, extra: f64, row: f64, rng: &mut R) -> u16 {
        let e = poisson(lambda, self.gauss_above, rng).min(self.fw);
        let mut a = self.offset + extra + row + self.g * e;
        if self.pre > 0.0 {
            a += self.g * self.pre * self.tails.sample(rng);
        }
        if self.post > 0.0 {
            a += self.post * self.tails.sample(rng);
        }
        let q = round_clamp(a, self.white);
        let out = if self.d > 1.0 { round_clamp(self.black + (q - self.black) * self.d, self.white) } else { q };
        out as u16
    }
}

/// A simulated phone camera pointed at a [`Chart`].
#[derive(Debug, Clone)]
pub struct Simulator {
    model: SensorModel,
    chart: Chart,
    seed: u64,
    prnu_seed: u64,
    dsnu_seed: u64,
    col_seed: u64,
}

/// Stream of a frame's black-level errors (far from the row streams `1 + y`).
const FRAME_OFFSET_STREAM: u64 = u64::MAX;
/// Stream of a frame's column noise.
const COLUMN_STREAM: u64 = u64::MAX - 1;
/// Dark frames draw their noise from frame indices with this bit set (no lit frame has it).
const DARK_FRAMES: u64 = 1 << 62;

impl Simulator {
    /// A simulator for `model` looking at `chart` (the chart's size is the frame size). `seed`
    /// fixes the PRNU map and every frame's noise. Fails if the model or chart is invalid.
    pub fn new(model: SensorModel, chart: Chart, seed: u64) -> Result<Self, SimError> {
        model.validate()?;
        chart.validate()?;
        Ok(Self {
            model,
            chart,
            seed,
            prnu_seed: mix64(seed ^ 0x5052_4E55_5F4D_4150),
            dsnu_seed: mix64(seed ^ 0x4453_4E55_5F4D_4150),
            col_seed: mix64(seed ^ 0x434F_4C5F_5041_5454),
        })
    }

    /// The sensor model.
    pub fn model(&self) -> &SensorModel {
        &self.model
    }

    /// The chart.
    pub fn chart(&self) -> &Chart {
        &self.chart
    }

    /// The seed.
    pub fn seed(&self) -> u64 {
        self.seed
    }

    /// Frame width (pixels).
    pub fn width(&self) -> usize {
        self.chart.width as usize
    }

    /// Frame height (pixels).
    pub fn height(&self) -> usize {
        self.chart.height as usize
    }

    /// The sensor layout of the frames, with the model's (reported) black and white levels.
    pub fn layout(&self) -> SensorLayout {
        SensorLayout {
            width: self.chart.width,
            height: self.chart.height,
            cfa: self.model.cfa,
            black: self.model.black,
            white: self.model.white,
        }
    }

    /// Settings of the signal chain at `iso`.
    pub fn iso_settings(&self, iso: u32) -> Result<IsoSettings, SimError> {
        self.model.at_iso(iso)
    }

    /// The fixed PRNU gain of a pixel (≈ 1 ± `prnu`).
    #[inline]
    pub fn prnu_gain(&self, row: usize, col: usize) -> f32 {
        let idx = (row * self.width() + col) as u64;
        let h = mix64(self.prnu_seed.wrapping_add(idx.wrapping_mul(0x9E37_79B9_7F4A_7C15)));
        1.0 + self.model.prnu * hashed_unit(h)
    }

    /// Whether the model has DSNU (a fixed per-pixel dark offset).
    fn has_dsnu(&self) -> bool {
        self.model.dsnu_pre_e > 0.0 || self.model.dsnu_post_dn > 0.0
    }

    /// The two fixed standardised DSNU maps at a pixel (pre-gain, post-gain), each ≈ N(0, 1)
    /// bounded by ±3.46, independent of each other and of the PRNU map. Keyed by (row, col), not
    /// by the frame width: a smaller frame of the same seed is a crop of the same map.
    #[inline]
    fn dsnu_units(&self, row: usize, col: usize) -> (f64, f64) {
        let idx = ((row as u64) << 32) | col as u64;
        let h = mix64(self.dsnu_seed.wrapping_add(idx.wrapping_mul(0x9E37_79B9_7F4A_7C15)));
        (hashed_unit(h) as f64, hashed_unit(mix64(h ^ 0x2F4A_7C15_9E37_79B9)) as f64)
    }

    /// The fixed DSNU offset of a pixel at the ADC (DN, before digital gain) with these
    /// settings: `G·dsnu_pre_e·u_pre + dsnu_post_dn·u_post`.
    #[inline]
    fn dsnu_at(&self, s: &IsoSettings, row: usize, col: usize) -> f64 {
        let (u_pre, u_post) = self.dsnu_units(row, col);
        s.dn_per_electron * self.model.dsnu_pre_e as f64 * u_pre + self.model.dsnu_post_dn as f64 * u_post
    }

    /// The fixed dark offset (DSNU) of a pixel at `iso`, in DN at the ADC (multiply by the
    /// digital gain for output DN); 0 without DSNU. Its pre-gain part grows with the analog gain.
    pub fn dsnu_offset_dn(&self, iso: u32, row: usize, col: usize) -> Result<f64, SimError> {
        let s = self.model.at_iso(iso)?;
        Ok(if self.has_dsnu() { self.dsnu_at(&s, row, col) } else { 0.0 })
    }

    /// Whether frames carry a black-level error.
    fn has_frame_offsets(&self) -> bool {
        self.model.frame_offset_pre_e > 0.0 || self.model.frame_offset_post_dn > 0.0
    }

    /// Whether frames carry column offsets (noise or pattern).
    fn has_columns(&self) -> bool {
        self.model.col_noise_dn > 0.0 || self.model.col_pattern_dn > 0.0
    }

    /// The fixed column-pattern offset of column `col` at the ADC (DN, any ISO): ≈ N(0,
    /// `col_pattern_dn`²) bounded by ±3.46 RMS, keyed by the column (a crop keeps its pattern).
    #[inline]
    fn column_pattern_at(&self, col: usize) -> f64 {
        let h = mix64(self.col_seed.wrapping_add((col as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)));
        self.model.col_pattern_dn as f64 * hashed_unit(h) as f64
    }

    /// The true laws of the structured components at these settings.
    fn truth_at(&self, s: &IsoSettings) -> StructuredTruth {
        let m = &self.model;
        let d = s.digital_gain;
        StructuredTruth {
            iso: s.iso,
            digital_gain: d,
            row_sd_dn: d * s.row_noise_dn,
            row_shape: m.row_noise_shape,
            col_sd_dn: d * s.col_noise_dn,
            col_pattern_sd_dn: d * s.col_pattern_dn,
            frame_offset_sd_dn: [d * s.frame_offset_dn; POSITIONS],
            frame_offset_shape: m.frame_offset_shape,
            frame_offset_shared: m.frame_offset_shared as f64,
            dsnu_sd_dn: d * s.dsnu_dn,
        }
    }

    /// The frame's black-level error per CFA position at the ADC (DN), from its own stream.
    fn frame_offsets_adc(&self, s: &IsoSettings, key: u64) -> [f64; POSITIONS] {
        let mut rng = Self::stream(key, FRAME_OFFSET_STREAM);
        self.truth_at(s).sample_frame_offsets_adc(&mut rng)
    }

    /// The frame's column offsets at the ADC (DN): column noise from its own stream plus the
    /// fixed pattern.
    fn column_offsets_adc(&self, s: &IsoSettings, key: u64, width: usize) -> Vec<f64> {
        let mut rng = Self::stream(key, COLUMN_STREAM);
        (0..width)
            .map(|x| {
                let noise = if s.col_noise_dn > 0.0 { s.col_noise_dn * normal(&mut rng) } else { 0.0 };
                let pattern = if s.col_pattern_dn > 0.0 { self.column_pattern_at(x) } else { 0.0 };
                noise + pattern
            })
            .collect()
    }

    /// The true laws of the structured components at `iso`, in output DN (digital gain
    /// included): row, column and frame-offset RMS and shapes, the column pattern and DSNU
    /// spread, and samplers of the row- and frame-offset distributions
    /// ([`StructuredTruth::sample_row_offset`], [`StructuredTruth::sample_frame_offsets`]).
    pub fn structured_truth(&self, iso: u32) -> Result<StructuredTruth, SimError> {
        Ok(self.truth_at(&self.model.at_iso(iso)?))
    }

    /// The black-level error of each CFA position that [`Simulator::capture`] adds to this
    /// frame, in output DN (`digital_gain ×` the ADC offset; before rounding). Zeros without
    /// frame offsets.
    pub fn frame_offsets(&self, iso: u32, exposure_ns: u64, frame_index: u64) -> Result<[f64; POSITIONS], SimError> {
        let s = self.check(iso, exposure_ns)?;
        if !self.has_frame_offsets() {
            return Ok([0.0; POSITIONS]);
        }
        Ok(self.frame_offsets_adc(&s, self.frame_key(iso, exposure_ns, frame_index)).map(|v| v * s.digital_gain))
    }

    /// The row offsets that [`Simulator::capture`] adds to the rows of this frame, in output DN
    /// (`digital_gain ×` the ADC offset; before rounding), one per row.
    pub fn row_offsets(&self, iso: u32, exposure_ns: u64, frame_index: u64) -> Result<Vec<f64>, SimError> {
        let s = self.check(iso, exposure_ns)?;
        let key = self.frame_key(iso, exposure_ns, frame_index);
        Ok((0..self.height())
            .map(|y| {
                let mut rng = Self::stream(key, y as u64 + 1);
                s.digital_gain * s.row_noise_dn * self.model.row_noise_shape.sample_unit(&mut rng)
            })
            .collect())
    }

    /// The column offsets (column noise plus the fixed pattern) that [`Simulator::capture`] adds
    /// to the columns of this frame, in output DN (before rounding), one per column.
    pub fn column_offsets(&self, iso: u32, exposure_ns: u64, frame_index: u64) -> Result<Vec<f64>, SimError> {
        let s = self.check(iso, exposure_ns)?;
        let key = self.frame_key(iso, exposure_ns, frame_index);
        Ok(self.column_offsets_adc(&s, key, self.width()).into_iter().map(|v| v * s.digital_gain).collect())
    }

    fn frame_key(&self, iso: u32, exposure_ns: u64, frame_index: u64) -> u64 {
        mix64(mix64(mix64(mix64(self.seed) ^ iso as u64) ^ exposure_ns) ^ frame_index)
    }

    /// Stream `stream` of a frame: a PCG-64 (MCG) generator whose 128-bit state is hashed from
    /// the frame key and the stream number (0: frame effects, 1 + y: row y).
    fn stream(key: u64, stream: u64) -> Pcg64Mcg {
        let lo = mix64(key ^ mix64(stream));
        let hi = mix64(lo ^ 0xD1B5_4A32_D192_ED03);
        let mut rng = Pcg64Mcg::new(((hi as u128) << 64) | lo as u128);
        // Discard one output so that nearby states decorrelate fully.
        let _ = rng.next_u64();
        rng
    }

    fn check(&self, iso: u32, exposure_ns: u64) -> Result<IsoSettings, SimError> {
        let s = self.model.at_iso(iso)?;
        if exposure_ns == 0 {
            return Err(SimError::Exposure);
        }
        Ok(s)
    }

    fn chains(&self, s: &IsoSettings) -> [Chain; POSITIONS] {
        std::array::from_fn(|p| Chain {
            black: self.model.black[p] as f64,
            offset: self.model.black[p] as f64 + self.model.bias_dn[p] as f64,
            g: s.dn_per_electron,
            d: s.digital_gain,
            pre: s.read_noise_pre_e,
            post: s.read_noise_post_dn,
            tails: match self.model.read_noise_shape() {
                ReadNoiseShape::Gaussian => UnitNoise::Gaussian,
                ReadNoiseShape::StudentT { dof } => UnitNoise::StudentT(StudentT::new(dof as f64)),
                ReadNoiseShape::TukeyLambda { lambda } => UnitNoise::TukeyLambda(TukeyLambda::new(lambda as f64)),
            },
            fw: s.full_well_e,
            white: self.model.white as f64,
            gauss_above: self.model.poisson_exact_below as f64,
        })
    }

    /// Flicker and misalignment of one frame (the same values [`Simulator::capture`] uses).
    pub fn frame_effects(&self, iso: u32, exposure_ns: u64, frame_index: u64) -> FrameEffects {
        let mut rng = Self::stream(self.frame_key(iso, exposure_ns, frame_index), 0);
        let j = self.model.jitter_px as f64;
        let mut jitter = ((j * normal(&mut rng)) as f32, (j * normal(&mut rng)) as f32);
        let (u, sign) = (uniform_open(&mut rng), uniform_open(&mut rng));
        let flicker = match &self.model.flicker {
            Some(f) if u < f.probability as f64 => {
                if sign < 0.5 {
                    1.0 - f.amplitude
                } else {
                    1.0 + f.amplitude
                }
            }
            _ => 1.0,
        };
        let (mut rotation, mut scale) = (0.0, 1.0);
        if let Some(m) = &self.model.motion {
            let [dx, dy, rot, breath] = self.motion_pose(m, frame_index);
            jitter = ((jitter.0 as f64 + dx) as f32, (jitter.1 as f64 + dy) as f32);
            rotation = rot as f32;
            scale = (1.0 + breath) as f32;
        }
        FrameEffects { flicker, jitter, rotation, scale }
    }

    /// The motion's pose `[dx, dy, rotation, breathing]` at capture index `index`: a walk from
    /// the start of its block of [`MOTION_BLOCK`] indices (seeded by the simulator's seed and
    /// the block, not by the ISO or exposure: frames captured one after the other move
    /// together whatever their settings).
    fn motion_pose(&self, m: &Motion, index: u64) -> [f64; 4] {
        let block = index / MOTION_BLOCK;
        let mut rng = Self::stream(mix64(mix64(self.seed ^ 0x4D4F_5449_4F4E_5741) ^ block), 0);
        let bounds = [m.max_shift_px as f64, m.max_shift_px as f64, m.max_rotation_rad as f64, m.breathing as f64];
        let steps = [m.step_px as f64, m.step_px as f64, bounds[2] / 6.0, bounds[3] / 6.0];
        let fresh =
            |rng: &mut Pcg64Mcg| -> [f64; 4] { std::array::from_fn(|k| bounds[k] * (2.0 * uniform_open(rng) - 1.0)) };
        let mut pose = fresh(&mut rng);
        for _ in block * MOTION_BLOCK..index {
            let jump = uniform_open(&mut rng) < m.jump_probability as f64;
            let next = fresh(&mut rng);
            for k in 0..4 {
                let walked = reflect(pose[k] + steps[k] * normal(&mut rng), bounds[k]);
                pose[k] = if jump { next[k] } else { walked };
            }
        }
        pose
    }

    /// One raw frame at `iso` and `exposure_ns`; `frame_index` tells frames of a burst apart.
    /// Returns the frame (`height × width`, row-major) and what the camera reports for it.
    pub fn capture(&self, iso: u32, exposure_ns: u64, frame_index: u64) -> Result<(Array2<u16>, FrameMeta), SimError> {
        self.capture_with(iso, exposure_ns, frame_index, true)
    }

    /// One dark frame (lens covered: no light reaches the sensor; every other effect — DSNU,
    /// row, column and frame offsets, read noise — as in [`Self::capture`]), with noise of its
    /// own (a frame index of the dark stream).
    pub fn capture_dark(
        &self,
        iso: u32,
        exposure_ns: u64,
        frame_index: u64,
    ) -> Result<(Array2<u16>, FrameMeta), SimError> {
        self.capture_with(iso, exposure_ns, frame_index ^ DARK_FRAMES, false)
    }

    fn capture_with(
        &self,
        iso: u32,
        exposure_ns: u64,
        frame_index: u64,
        lit: bool,
    ) -> Result<(Array2<u16>, FrameMeta), SimError> {
        let s = self.check(iso, exposure_ns)?;
        let chains = self.chains(&s);
        let fx = self.frame_effects(iso, exposure_ns, frame_index);
        let key = self.frame_key(iso, exposure_ns, frame_index);
        let prepared = if self.model.motion.is_some() {
            self.chart.prepare_moving(fx.jitter, fx.rotation, fx.scale)
        } else {
            self.chart.prepare_posed(fx.jitter, fx.rotation, fx.scale)
        };
        let t = exposure_ns as f64 * 1e-9 * fx.flicker as f64;
        let (w, h) = (self.width(), self.height());
        let colors = self.model.cfa.colors().map(color_index);
        let dsnu = self.has_dsnu();
        // Structured offsets at the ADC; absent components draw nothing, so frames without them
        // are what they always were.
        let frame_off = self.has_frame_offsets().then(|| self.frame_offsets_adc(&s, key));
        let cols = self.has_columns().then(|| self.column_offsets_adc(&s, key, w));
        let row_shape = self.model.row_noise_shape;
        let mut data = vec![0u16; w * h];
        data.par_chunks_mut(w).enumerate().for_each_init(
            || vec![0.0f32; w],
            |rates, (y, row)| {
                let mut rng = Self::stream(key, y as u64 + 1);
                let ry = (y & 1) * 2;
                if lit {
                    prepared.row_rates(y, [colors[ry], colors[ry + 1]], rates);
                }
                let row_off = s.row_noise_dn * row_shape.sample_unit(&mut rng);
                for (x, out) in row.iter_mut().enumerate() {
                    let lambda = rates[x] as f64 * t * self.prnu_gain(y, x) as f64;
                    let mut extra = if dsnu { self.dsnu_at(&s, y, x) } else { 0.0 };
                    if let Some(f) = &frame_off {
                        extra += f[ry + (x & 1)];
                    }
                    if let Some(c) = &cols {
                        extra += c[x];
                    }
                    *out = chains[ry + (x & 1)].sample(lambda, extra, row_off, &mut rng);
                }
            },
        );
        let frame = Array2::from_shape_vec((h, w), data).expect("h × w samples");
        let meta = FrameMeta { iso, exposure_ns, black: self.model.report_dynamic_black.then_some(self.model.black) };
        Ok((frame, meta))
    }

    /// Mean electrons per pixel at `exposure_ns` (PRNU included; no flicker, no jitter).
    pub fn mean_electrons(&self, exposure_ns: u64) -> Array2<f32> {
        let mut e = self.chart.render(self.model.cfa, (0.0, 0.0));
        let t = exposure_ns as f32 * 1e-9;
        for ((y, x), v) in e.indexed_iter_mut() {
            *v *= t * self.prnu_gain(y, x);
        }
        e
    }

    /// The noiseless mean of every pixel in DN, black level, bias, DSNU and the fixed column
    /// pattern included, at `iso`
    /// and `exposure_ns` (no flicker, no jitter; clamped to [0, white] and the full well; the
    /// clamp is applied to the mean, not to the noise, so it is not the mean of clipped frames).
    pub fn clean_expected(&self, iso: u32, exposure_ns: u64) -> Result<Array2<f32>, SimError> {
        let s = self.check(iso, exposure_ns)?;
        let mut e = self.mean_electrons(exposure_ns);
        let dsnu = self.has_dsnu();
        let pattern = self.model.col_pattern_dn > 0.0;
        for ((y, x), v) in e.indexed_iter_mut() {
            let mut extra = if dsnu { self.dsnu_at(&s, y, x) } else { 0.0 };
            if pattern {
                extra += self.column_pattern_at(x);
            }
            *v = self.mean_level(&s, layout_pos(y, x), *v as f64, extra) as f32;
        }
        Ok(e)
    }

    /// The noiseless mean of the frame `frame_index` captured at `iso` and `exposure_ns`, in DN
    /// at the brightness of `at_iso` and `at_exposure_ns` (e.g. the base ISO's, where a still
    /// scene's clean image is a burst's mean): as [`Self::clean_expected`], but with that frame's
    /// own pose (jitter and motion, rendered as [`Self::capture`] renders a moving scene) and
    /// flicker. The truth of a frame of a moving scene, which no burst mean gives.
    pub fn clean_expected_frame(
        &self,
        iso: u32,
        exposure_ns: u64,
        frame_index: u64,
        at_iso: u32,
        at_exposure_ns: u64,
    ) -> Result<Array2<f32>, SimError> {
        self.check(iso, exposure_ns)?;
        let s = self.check(at_iso, at_exposure_ns)?;
        let fx = self.frame_effects(iso, exposure_ns, frame_index);
        let prepared = if self.model.motion.is_some() {
            self.chart.prepare_moving(fx.jitter, fx.rotation, fx.scale)
        } else {
            self.chart.prepare_posed(fx.jitter, fx.rotation, fx.scale)
        };
        let t = at_exposure_ns as f64 * 1e-9 * fx.flicker as f64;
        let (w, h) = (self.width(), self.height());
        let colors = self.model.cfa.colors().map(color_index);
        let (dsnu, pattern) = (self.has_dsnu(), self.model.col_pattern_dn > 0.0);
        let mut out = Array2::<f32>::zeros((h, w));
        let mut rates = vec![0.0f32; w];
        for (y, mut row) in out.rows_mut().into_iter().enumerate() {
            let ry = (y & 1) * 2;
            prepared.row_rates(y, [colors[ry], colors[ry + 1]], &mut rates);
            for (x, v) in row.iter_mut().enumerate() {
                let electrons = rates[x] as f64 * t * self.prnu_gain(y, x) as f64;
                let mut extra = if dsnu { self.dsnu_at(&s, y, x) } else { 0.0 };
                if pattern {
                    extra += self.column_pattern_at(x);
                }
                *v = self.mean_level(&s, layout_pos(y, x), electrons, extra) as f32;
            }
        }
        Ok(out)
    }

    /// Mean output of a pixel with mean `electrons` and fixed ADC offset `extra` (DSNU).
    fn mean_level(&self, s: &IsoSettings, pos: usize, electrons: f64, extra: f64) -> f64 {
        let black = self.model.black[pos] as f64;
        let adc = (self.model.bias_dn[pos] as f64 + extra) + s.dn_per_electron * electrons.min(s.full_well_e);
        (black + s.digital_gain * adc).clamp(0.0, self.model.white as f64)
    }

    /// Mean electrons (`λ`) and extra ADC offset (≤ 0, for levels below the dark level) that
    /// give the clean output `level` at a position.
    fn lambda_for_level(&self, s: &IsoSettings, pos: usize, level: f64) -> (f64, f64) {
        let black = self.model.black[pos] as f64;
        let adc_above_dark = (level - black) / s.digital_gain - self.model.bias_dn[pos] as f64;
        if adc_above_dark >= 0.0 { (adc_above_dark / s.dn_per_electron, 0.0) } else { (0.0, adc_above_dark) }
    }

    fn check_level(&self, level: f32, pos: usize) -> Result<(), SimError> {
        if pos >= POSITIONS {
            return Err(SimError::Position { pos });
        }
        if !level.is_finite() {
            return Err(SimError::Level { level, white: self.model.white });
        }
        Ok(())
    }

    /// Temporal variance (DN²) of the output at clean level `level_dn` and CFA position `pos`,
    /// computed analytically from the model: `d²·(G²(λ + σ_pre²) + σ_post² + σ_row² + σ_frame² +
    /// σ_col² + 1/12)` (frame offsets and column noise are temporal too)
    /// plus the rounding after digital gain. Shot noise is Poisson in electrons, Student-t and
    /// Tukey-lambda read noise have unit-scaled variance (the shape changes the tails, not the
    /// variance), quantisation adds 1/12; γ, dual gain and digital gain enter through
    /// [`SensorModel::at_iso`]. Valid away from 0 and white (clipping at the black floor and at
    /// white is ignored) and where the analog noise exceeds ≈ 0.5 DN (Sheppard's correction).
    ///
    /// DSNU and PRNU are fixed patterns: they add no temporal variance (the level already
    /// contains a pixel's offset) but spread pixels of one nominal level over space; see
    /// [`Simulator::fixed_pattern_variance`]. A pixel with a DSNU offset is treated as a pixel
    /// whose clean level is `level_dn` (its electrons are `λ` of that level), which is exact
    /// for the post-gain part and shifts `λ` by the offset for the pre-gain part (negligible
    /// unless the offset is comparable to the signal).
    pub fn predicted_variance(&self, iso: u32, level_dn: f32, pos: usize) -> Result<f64, SimError> {
        let s = self.model.at_iso(iso)?;
        self.check_level(level_dn, pos)?;
        let (lambda, _) = self.lambda_for_level(&s, pos, level_dn as f64);
        let g = s.dn_per_electron;
        let mut shot = lambda;
        if lambda >= self.model.poisson_exact_below as f64 {
            shot += 1.0 / 12.0; // the Gaussian approximation is rounded to whole electrons
        }
        let analog = g * g * (shot + s.read_noise_pre_e.powi(2))
            + s.read_noise_post_dn.powi(2)
            + s.row_noise_dn.powi(2)
            + s.frame_offset_dn.powi(2)
            + s.col_noise_dn.powi(2)
            + 1.0 / 12.0;
        if s.digital_gain <= 1.0 {
            return Ok(analog);
        }
        // Second rounding: mean squared error of round(black + (q − black)·d) over the ADC codes
        // around the level.
        let black = self.model.black[pos] as f64;
        let q0 = (black + (level_dn as f64 - black) / s.digital_gain).round();
        let r2 = (-128..128)
            .map(|k| {
                let y = black + (q0 + k as f64 - black) * s.digital_gain;
                (y.round() - y).powi(2)
            })
            .sum::<f64>()
            / 256.0;
        Ok(s.digital_gain.powi(2) * analog + r2)
    }

    /// Spatial variance (DN², output) that the fixed patterns add between pixels of the same
    /// nominal level `level_dn` at `iso` and `pos`: `d²·((G·λ·prnu)² + (G·dsnu_pre_e)² +
    /// dsnu_post_dn² + col_pattern_dn²)` (PRNU on the signal electrons, DSNU and the column
    /// pattern in the dark). Not part of
    /// [`Simulator::predicted_variance`], which is temporal.
    pub fn fixed_pattern_variance(&self, iso: u32, level_dn: f32, pos: usize) -> Result<f64, SimError> {
        let s = self.model.at_iso(iso)?;
        self.check_level(level_dn, pos)?;
        let (lambda, _) = self.lambda_for_level(&s, pos, level_dn as f64);
        let prnu = s.dn_per_electron * lambda * self.model.prnu as f64;
        Ok(s.digital_gain.powi(2) * (prnu.powi(2) + s.dsnu_dn.powi(2) + s.col_pattern_dn.powi(2)))
    }

    /// `n` samples of `noisy − round(level_dn)` at `iso` and CFA position `pos`, drawn by the
    /// same per-pixel process as [`Simulator::capture`] for a pixel whose clean level is
    /// `level_dn` (row noise, frame offsets and column noise drawn independently per sample:
    /// same marginal, no correlation; a pixel without DSNU offset or column pattern).
    pub fn sample_noise_at_level<R: Rng + ?Sized>(
        &self,
        iso: u32,
        level_dn: f32,
        pos: usize,
        n: usize,
        rng: &mut R,
    ) -> Result<Vec<i32>, SimError> {
        let s = self.model.at_iso(iso)?;
        self.check_level(level_dn, pos)?;
        let chain = self.chains(&s)[pos];
        let (lambda, extra) = self.lambda_for_level(&s, pos, level_dn as f64);
        let clean = level_dn.round() as i32;
        let truth = self.truth_at(&s);
        let (frame, col) = (self.has_frame_offsets(), s.col_noise_dn > 0.0);
        Ok((0..n)
            .map(|_| {
                let row = s.row_noise_dn * self.model.row_noise_shape.sample_unit(rng);
                let mut extra = extra;
                if frame {
                    extra += truth.sample_frame_offsets_adc(rng)[pos];
                }
                if col {
                    extra += s.col_noise_dn * normal(rng);
                }
                chain.sample(lambda, extra, row, rng) as i32 - clean
            })
            .collect())
    }

    /// Exposure (ns) that puts the brightest spot of the chart at [`MID_RANGE_FRACTION`] of the
    /// black-to-white range at `iso`: EV 0 of a session; EV +4 then clips the bright patches and
    /// EV −4 leaves the chart dark.
    pub fn mid_range_exposure_ns(&self, iso: u32) -> Result<u64, SimError> {
        let s = self.model.at_iso(iso)?;
        let black = self.model.black.iter().cloned().fold(0.0f32, f32::max) as f64;
        let target_dn = MID_RANGE_FRACTION * (self.model.white as f64 - black);
        let rate = self.chart.max_rate() as f64;
        let secs = target_dn / (rate * s.total_dn_per_electron());
        Ok(((secs * 1e9).round() as u64).max(1))
    }
}

#[inline]
fn layout_pos(row: usize, col: usize) -> usize {
    noisecal_core::model::layout::position(row, col)
}

/// `v` reflected into `[−bound, bound]` (0 when the bound is 0).
fn reflect(v: f64, bound: f64) -> f64 {
    if bound <= 0.0 {
        return 0.0;
    }
    let period = 4.0 * bound;
    let u = (v + bound).rem_euclid(period);
    if u <= 2.0 * bound { u - bound } else { 3.0 * bound - u }
}
