//! The sensor model: every parameter of the simulated signal chain, presets, and the per-ISO
//! settings derived from it.
//!
//! Signal chain of one pixel at CFA position `p` (all per frame):
//! ```text
//! electrons  e  ~ Poisson(λ),  λ = rate · t · flicker · PRNU        (clipped at the full well)
//! ADC input  a  = black_p + bias_p + G·(e + n_pre + f_pre) + n_post + f_post + r_row
//!                  + o_frame,p + c_col                      (G = DN per electron)
//! ADC output q  = clamp(round(a), 0, white)
//! output        = q                                        (ISO ≤ max_analog_iso)
//!               = clamp(round(black_p + (q − black_p)·d), 0, white)  (digital gain d > 1)
//! ```
//! `n_pre` (electrons) and `n_post` (DN) are Gaussian, unit-variance Student-t or unit-variance
//! Tukey-lambda ([`ReadNoiseShape`]) scaled by their sigmas; `r_row` is one offset per row and
//! frame (Gaussian, or any [`OffsetShape`]); `f_pre` (electrons) and `f_post` (DN) are the fixed
//! per-pixel dark offsets (DSNU, zero by default); `o_frame,p` is the frame's black-level error at
//! CFA position `p` (one draw per frame and position, zero by default) and `c_col` the column
//! offset (per-frame column noise plus a fixed column pattern, zero by default). The structured
//! components' true laws at an ISO are [`crate::Simulator::structured_truth`]. `G = g(iso) / electrons_per_dn`, where the analog gain
//! `g = (min(iso, max_analog_iso) / base_iso)^γ · (1 + gain error)` (γ =
//! [`SensorModel::gain_iso_exponent`], 1 by default), and the sensor's second conversion gain
//! (if any) changes the read noise and the gain error above its ISO.

use noisecal_core::{CfaPattern, POSITIONS};

use crate::error::SimError;

/// The second (high) conversion gain of a dual-conversion-gain sensor, used from `min_iso` up.
///
/// Brightness per ISO stays nominally the same across the switch (the analog gain compensates),
/// but the read noise referred to the input drops: the variance at dark levels jumps down there.
#[derive(Debug, Clone, PartialEq)]
pub struct DualGain {
    /// First ISO read out with the high conversion gain.
    pub min_iso: u32,
    /// Pre-gain read noise (electrons, RMS) in high conversion gain.
    pub read_noise_pre_e: f32,
    /// Post-gain read noise (DN, RMS) in high conversion gain.
    pub read_noise_post_dn: f32,
    /// Multiplier on the total gain in high conversion gain (e.g. 1.015: 1.5 % brighter than
    /// nominal), i.e. the electrons per DN change by its inverse.
    pub gain_mismatch: f32,
    /// Full-well capacity (electrons) in high conversion gain.
    pub full_well_e: f32,
}

/// The law of the read noise (both the pre- and the post-gain part), always scaled to unit
/// variance before the sigmas of [`SensorModel`] multiply it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ReadNoiseShape {
    /// Gaussian.
    Gaussian,
    /// Student-t with `dof` ≥ 3 degrees of freedom (excess kurtosis 6/(dof − 4) for dof > 4).
    StudentT {
        /// Degrees of freedom.
        dof: f32,
    },
    /// Tukey-lambda with shape `lambda` in [−0.45, 1]: heavy tails for λ < 0 (infinite kurtosis
    /// for λ ≤ −1/4), near-Gaussian at λ ≈ 0.14, lighter than Gaussian above, uniform at 1.
    TukeyLambda {
        /// Shape λ.
        lambda: f32,
    },
}

impl ReadNoiseShape {
    /// Excess kurtosis of the law (0 for Gaussian; +∞ where the 4th moment is infinite).
    pub fn excess_kurtosis(&self) -> f64 {
        match *self {
            ReadNoiseShape::Gaussian => 0.0,
            ReadNoiseShape::StudentT { dof } if dof > 4.0 => 6.0 / (dof as f64 - 4.0),
            ReadNoiseShape::StudentT { .. } => f64::INFINITY,
            ReadNoiseShape::TukeyLambda { lambda } => crate::noise::tukey_lambda_excess_kurtosis(lambda as f64),
        }
    }

    /// Variance of the law before it is scaled to unit variance (1 for Gaussian, dof/(dof − 2)
    /// for Student-t, the closed form via the beta function for Tukey-lambda).
    pub fn raw_variance(&self) -> f64 {
        match *self {
            ReadNoiseShape::Gaussian => 1.0,
            ReadNoiseShape::StudentT { dof } => dof as f64 / (dof as f64 - 2.0),
            ReadNoiseShape::TukeyLambda { lambda } => crate::noise::tukey_lambda_variance(lambda as f64),
        }
    }

    /// Whether the tails are heavier than Gaussian (positive excess kurtosis).
    pub fn is_heavy_tailed(&self) -> bool {
        self.excess_kurtosis() > 0.0
    }
}

impl std::fmt::Display for ReadNoiseShape {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ReadNoiseShape::Gaussian => write!(f, "Gaussian"),
            ReadNoiseShape::StudentT { dof } => write!(f, "Student-t({dof:.1} dof)"),
            ReadNoiseShape::TukeyLambda { lambda } => write!(f, "Tukey-lambda(λ={lambda:.3})"),
        }
    }
}

/// The law of a structured offset (row offsets, frame offsets), scaled to unit variance before
/// its RMS multiplies it. Gaussian by default; the others have heavier tails.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub enum OffsetShape {
    /// Gaussian.
    #[default]
    Gaussian,
    /// Laplace (double exponential): excess kurtosis 3.
    Laplace,
    /// Student-t with `dof` ≥ 3 degrees of freedom (excess kurtosis 6/(dof − 4) for dof > 4).
    StudentT {
        /// Degrees of freedom.
        dof: f32,
    },
    /// A Gaussian scale mixture: with probability `weight` the offset is `ratio` times wider
    /// (occasional large offsets, e.g. a black-level clamp that sometimes misses).
    ScaleMixture {
        /// Probability of the wide component, in (0, 1).
        weight: f32,
        /// Width of the wide component over the narrow one, in [1, 50].
        ratio: f32,
    },
}

impl OffsetShape {
    /// Excess kurtosis of the law (0 for Gaussian; +∞ where the 4th moment is infinite).
    pub fn excess_kurtosis(&self) -> f64 {
        match *self {
            OffsetShape::Gaussian => 0.0,
            OffsetShape::Laplace => 3.0,
            OffsetShape::StudentT { dof } if dof > 4.0 => 6.0 / (dof as f64 - 4.0),
            OffsetShape::StudentT { .. } => f64::INFINITY,
            OffsetShape::ScaleMixture { weight, ratio } => {
                let (w, r2) = (weight as f64, (ratio as f64).powi(2));
                3.0 * (1.0 - w + w * r2 * r2) / (1.0 - w + w * r2).powi(2) - 3.0
            }
        }
    }

    /// Checks the parameters; the message names the valid range.
    pub(crate) fn check(&self) -> Result<(), &'static str> {
        match *self {
            OffsetShape::Gaussian | OffsetShape::Laplace => Ok(()),
            OffsetShape::StudentT { dof } if dof.is_finite() && (3.0..=1000.0).contains(&dof) => Ok(()),
            OffsetShape::StudentT { .. } => Err("a Student-t offset needs 3 ≤ dof ≤ 1000"),
            OffsetShape::ScaleMixture { weight, ratio }
                if weight.is_finite()
                    && weight > 0.0
                    && weight < 1.0
                    && ratio.is_finite()
                    && (1.0..=50.0).contains(&ratio) =>
            {
                Ok(())
            }
            OffsetShape::ScaleMixture { .. } => Err("a scale mixture needs 0 < weight < 1 and 1 ≤ ratio ≤ 50"),
        }
    }

    /// One unit-variance draw. Gaussian draws exactly one standard normal (as row noise always did).
    #[inline]
    pub fn sample_unit<R: rand::Rng + ?Sized>(&self, rng: &mut R) -> f64 {
        use crate::noise::{StudentT, normal, uniform_open};
        match *self {
            OffsetShape::Gaussian => normal(rng),
            OffsetShape::Laplace => {
                let u = uniform_open(rng);
                let b = std::f64::consts::FRAC_1_SQRT_2;
                if u < 0.5 { b * (2.0 * u).ln() } else { -b * (2.0 * (1.0 - u)).ln() }
            }
            OffsetShape::StudentT { dof } => StudentT::new(dof as f64).sample(rng),
            OffsetShape::ScaleMixture { weight, ratio } => {
                let (w, r) = (weight as f64, ratio as f64);
                let wide = uniform_open(rng) < w;
                let z = normal(rng);
                let norm = (1.0 - w + w * r * r).sqrt();
                if wide { z * r / norm } else { z / norm }
            }
        }
    }
}

impl std::fmt::Display for OffsetShape {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            OffsetShape::Gaussian => write!(f, "Gaussian"),
            OffsetShape::Laplace => write!(f, "Laplace"),
            OffsetShape::StudentT { dof } => write!(f, "Student-t({dof:.1} dof)"),
            OffsetShape::ScaleMixture { weight, ratio } => write!(f, "scale mixture({weight:.2} at ×{ratio:.1})"),
        }
    }
}

/// Mains-like flicker: some frames are brighter or darker by a fixed fraction.
#[derive(Debug, Clone, PartialEq)]
pub struct Flicker {
    /// Probability that a frame is affected (0..=1).
    pub probability: f32,
    /// Relative brightness change of an affected frame (e.g. 0.03 → ×0.97 or ×1.03).
    pub amplitude: f32,
}

/// Motion of the scene between frames, as a phone on a tripod shows it: optical image
/// stabilisation re-centring, shutter and focus-motor shake, a swaying tripod, and focus
/// breathing. The pose of frame `t` (its capture index) follows a random walk over the frames
/// of a block of [`MOTION_BLOCK`] consecutive indices (a session's bursts are consecutive
/// indices): each frame moves by a Gaussian step or, with `jump_probability`, jumps to a fresh
/// position; every coordinate is kept within its bound by reflection. Rotation and scale are
/// about the image centre.
#[derive(Debug, Clone, PartialEq)]
pub struct Motion {
    /// Bound of the translation on each axis (pixels).
    pub max_shift_px: f32,
    /// RMS step of the translation walk per frame (pixels, per axis).
    pub step_px: f32,
    /// Probability per frame of a jump to a uniformly drawn pose within the bounds.
    pub jump_probability: f32,
    /// Bound of the rotation about the image centre (radians); its walk steps by a sixth of it.
    pub max_rotation_rad: f32,
    /// Bound of the focus breathing: the scene scaled by `1 ± breathing` (e.g. 0.001 = 0.1 %);
    /// its walk steps by a sixth of it.
    pub breathing: f32,
}

/// Frames per block of the motion walk ([`Motion`]): the pose of a frame is found by walking
/// from the block's start, so a frame costs at most this many draws whatever its index.
pub const MOTION_BLOCK: u64 = 64;

/// All parameters of a simulated phone raw sensor. Every field is public; start from a preset
/// ([`SensorModel::phone_10bit`], [`SensorModel::phone_12bit`], [`SensorModel::phone_14bit`])
/// and change what a test needs, then [`SensorModel::validate`] (the simulator does it too).
#[derive(Debug, Clone, PartialEq)]
pub struct SensorModel {
    /// Bayer order of the colour filter array.
    pub cfa: CfaPattern,
    /// Black level per CFA position (DN), as the sensor reports it.
    pub black: [f32; POSITIONS],
    /// White (saturation) level (DN).
    pub white: u16,
    /// Lowest ISO (analog gain 1).
    pub base_iso: u32,
    /// Highest ISO reached with analog gain; above it the rest is digital gain applied to the
    /// quantised value (combs in the histogram).
    pub max_analog_iso: u32,
    /// Electrons per DN at the base ISO (the inverse conversion gain).
    pub electrons_per_dn: f32,
    /// Full-well capacity (electrons); collected charge saturates there.
    pub full_well_e: f32,
    /// Gain non-proportionality: relative gain error per stop above the base ISO
    /// (gain error = this × log2(iso / base_iso)).
    pub gain_error_per_stop: f32,
    /// Explicit relative gain errors at given ISOs; they replace the per-stop rule there.
    pub gain_error_at: Vec<(u32, f32)>,
    /// Pre-gain read noise (electrons, RMS): amplified with the analog gain.
    pub read_noise_pre_e: f32,
    /// Post-gain read noise (DN, RMS at the ADC): independent of the analog gain.
    pub read_noise_post_dn: f32,
    /// Student-t degrees of freedom of both read-noise parts (heavy tails; ≥ 3, excess kurtosis
    /// 6/(dof−4) for dof > 4); `None` for Gaussian read noise (or Tukey-lambda, below).
    pub read_noise_dof: Option<f32>,
    /// Tukey-lambda shape λ of both read-noise parts (unit variance; see
    /// [`ReadNoiseShape::TukeyLambda`]); `None` (default) for Gaussian or Student-t. Exclusive
    /// with `read_noise_dof`; [`SensorModel::read_noise_shape`] reads both.
    pub read_noise_tukey_lambda: Option<f32>,
    /// Exponent γ of the analog gain in the ISO: `g ∝ (iso / base_iso)^γ`. 1 (default) is gain
    /// proportional to ISO; otherwise brightness at a constant ISO × exposure changes by
    /// `(iso / base_iso)^(γ − 1)`.
    pub gain_iso_exponent: f32,
    /// Pre-gain dark-signal non-uniformity (electrons, RMS): a fixed per-pixel dark offset
    /// (seeded like the PRNU map) amplified with the analog gain, so it does not cancel between
    /// ISOs. 0 (default) for none.
    pub dsnu_pre_e: f32,
    /// Post-gain dark-signal non-uniformity (DN at the ADC, RMS): a fixed per-pixel dark offset
    /// independent of the analog gain. 0 (default) for none.
    pub dsnu_post_dn: f32,
    /// Row noise before the gain (electrons, RMS): one Gaussian offset per row and frame.
    pub row_noise_pre_e: f32,
    /// Row noise after the gain (DN, RMS at the ADC).
    pub row_noise_post_dn: f32,
    /// Law of the row offsets (unit variance; Gaussian by default, which draws exactly what row
    /// noise always drew). One value per row and frame, shared by both CFA columns of the row.
    pub row_noise_shape: OffsetShape,
    /// Per-frame black-level error before the gain (electrons, RMS): one offset per frame and
    /// CFA position, amplified with the analog gain. 0 (default) for none.
    pub frame_offset_pre_e: f32,
    /// Per-frame black-level error after the gain (DN at the ADC, RMS), per frame and CFA
    /// position. 0 (default) for none.
    pub frame_offset_post_dn: f32,
    /// Law of the frame offsets (unit variance; Gaussian by default).
    pub frame_offset_shape: OffsetShape,
    /// Fraction of the frame-offset variance shared by the four CFA positions of a frame (0:
    /// independent per position, 1: one offset for the whole frame).
    pub frame_offset_shared: f32,
    /// Column noise (DN at the ADC, RMS): one Gaussian offset per column and frame. 0 (default)
    /// for none.
    pub col_noise_dn: f32,
    /// Fixed column pattern (DN at the ADC, RMS): one fixed offset per column (seeded like the
    /// DSNU map). 0 (default) for none.
    pub col_pattern_dn: f32,
    /// Small offset per CFA position (DN at the ADC) between the reported black level and the
    /// true dark level.
    pub bias_dn: [f32; POSITIONS],
    /// Photo-response non-uniformity: RMS of the fixed per-pixel gain map (e.g. 0.005 = 0.5 %).
    pub prnu: f32,
    /// Optional second conversion gain.
    pub dual_gain: Option<DualGain>,
    /// Optional per-frame flicker.
    pub flicker: Option<Flicker>,
    /// RMS of the per-frame sub-pixel misalignment of the scene (pixels, per axis).
    pub jitter_px: f32,
    /// Scene motion between frames (a random walk with jumps, rotation and breathing), on top of
    /// the jitter; `None` (the presets) for a scene that only jitters.
    pub motion: Option<Motion>,
    /// Mean electron count from which shot noise uses a Gaussian approximation instead of the
    /// exact Poisson draw.
    pub poisson_exact_below: f32,
    /// Report the black level as a per-frame dynamic black level in [`FrameMeta::black`]
    /// (Camera2 `SENSOR_DYNAMIC_BLACK_LEVEL`).
    ///
    /// [`FrameMeta::black`]: noisecal_core::FrameMeta::black
    pub report_dynamic_black: bool,
}

impl SensorModel {
    /// A 10-bit phone sensor like the paper's: RGGB, black 64, white 1023, base ISO 50,
    /// 4 e⁻/DN at base, digital gain above ISO 1600, heavy-tailed read noise (t, 6 dof).
    pub fn phone_10bit() -> Self {
        Self {
            cfa: CfaPattern::Rggb,
            black: [64.0; POSITIONS],
            white: 1023,
            base_iso: 50,
            max_analog_iso: 1600,
            electrons_per_dn: 4.0,
            full_well_e: 4300.0,
            gain_error_per_stop: 0.004,
            gain_error_at: Vec::new(),
            read_noise_pre_e: 1.6,
            read_noise_post_dn: 0.7,
            read_noise_dof: Some(6.0),
            read_noise_tukey_lambda: None,
            gain_iso_exponent: 1.0,
            dsnu_pre_e: 0.0,
            dsnu_post_dn: 0.0,
            row_noise_pre_e: 0.12,
            row_noise_post_dn: 0.15,
            row_noise_shape: OffsetShape::Gaussian,
            frame_offset_pre_e: 0.0,
            frame_offset_post_dn: 0.0,
            frame_offset_shape: OffsetShape::Gaussian,
            frame_offset_shared: 0.0,
            col_noise_dn: 0.0,
            col_pattern_dn: 0.0,
            bias_dn: [0.35, -0.2, 0.15, -0.3],
            prnu: 0.005,
            dual_gain: None,
            flicker: None,
            jitter_px: 0.08,
            motion: None,
            poisson_exact_below: 1000.0,
            report_dynamic_black: false,
        }
    }

    /// A 12-bit phone sensor: GRBG, blacks 256/257/255/256, white 4095, base ISO 100,
    /// 1.5 e⁻/DN at base, high conversion gain from ISO 800, digital gain above ISO 3200.
    pub fn phone_12bit() -> Self {
        Self {
            cfa: CfaPattern::Grbg,
            black: [256.0, 257.0, 255.0, 256.0],
            white: 4095,
            base_iso: 100,
            max_analog_iso: 3200,
            electrons_per_dn: 1.5,
            full_well_e: 6200.0,
            gain_error_per_stop: 0.004,
            gain_error_at: Vec::new(),
            read_noise_pre_e: 2.0,
            read_noise_post_dn: 1.1,
            read_noise_dof: Some(6.0),
            read_noise_tukey_lambda: None,
            gain_iso_exponent: 1.0,
            dsnu_pre_e: 0.0,
            dsnu_post_dn: 0.0,
            row_noise_pre_e: 0.15,
            row_noise_post_dn: 0.3,
            row_noise_shape: OffsetShape::Gaussian,
            frame_offset_pre_e: 0.0,
            frame_offset_post_dn: 0.0,
            frame_offset_shape: OffsetShape::Gaussian,
            frame_offset_shared: 0.0,
            col_noise_dn: 0.0,
            col_pattern_dn: 0.0,
            bias_dn: [0.4, -0.3, 0.2, 0.5],
            prnu: 0.005,
            dual_gain: Some(DualGain {
                min_iso: 800,
                read_noise_pre_e: 0.9,
                read_noise_post_dn: 1.0,
                gain_mismatch: 1.015,
                full_well_e: 3000.0,
            }),
            flicker: None,
            jitter_px: 0.08,
            motion: None,
            poisson_exact_below: 1000.0,
            report_dynamic_black: false,
        }
    }

    /// A 14-bit phone sensor: BGGR, black 1024, white 16383, base ISO 100, 0.4 e⁻/DN at base,
    /// high conversion gain from ISO 400, digital gain above ISO 6400.
    pub fn phone_14bit() -> Self {
        Self {
            cfa: CfaPattern::Bggr,
            black: [1024.0; POSITIONS],
            white: 16383,
            base_iso: 100,
            max_analog_iso: 6400,
            electrons_per_dn: 0.4,
            full_well_e: 6800.0,
            gain_error_per_stop: -0.003,
            gain_error_at: Vec::new(),
            read_noise_pre_e: 2.4,
            read_noise_post_dn: 3.0,
            read_noise_dof: Some(6.0),
            read_noise_tukey_lambda: None,
            gain_iso_exponent: 1.0,
            dsnu_pre_e: 0.0,
            dsnu_post_dn: 0.0,
            row_noise_pre_e: 0.2,
            row_noise_post_dn: 0.6,
            row_noise_shape: OffsetShape::Gaussian,
            frame_offset_pre_e: 0.0,
            frame_offset_post_dn: 0.0,
            frame_offset_shape: OffsetShape::Gaussian,
            frame_offset_shared: 0.0,
            col_noise_dn: 0.0,
            col_pattern_dn: 0.0,
            bias_dn: [1.0, -0.8, 0.6, -0.4],
            prnu: 0.005,
            dual_gain: Some(DualGain {
                min_iso: 400,
                read_noise_pre_e: 1.1,
                read_noise_post_dn: 2.8,
                gain_mismatch: 0.985,
                full_well_e: 3500.0,
            }),
            flicker: None,
            jitter_px: 0.08,
            motion: None,
            poisson_exact_below: 1000.0,
            report_dynamic_black: false,
        }
    }

    /// This sensor with phone-like structured noise: row noise at about an eighth
    /// of the read noise (RMS, pre- and post-gain), a per-frame black-level error per CFA
    /// position with Laplace tails (a third of it shared by the four positions), and DSNU (a
    /// fifth of the read noise, pre- and post-gain). No column noise. Scaled on this sensor's
    /// read noise, so it suits every preset.
    pub fn with_structured_noise(mut self) -> Self {
        self.row_noise_pre_e = (0.125 * self.read_noise_pre_e * 1000.0).round() / 1000.0;
        self.row_noise_post_dn = (0.125 * self.read_noise_post_dn * 1000.0).round() / 1000.0;
        self.row_noise_shape = OffsetShape::Gaussian;
        self.frame_offset_pre_e = (0.25 * self.read_noise_pre_e * 1000.0).round() / 1000.0;
        self.frame_offset_post_dn = (0.4 * self.read_noise_post_dn * 1000.0).round() / 1000.0;
        self.frame_offset_shape = OffsetShape::Laplace;
        self.frame_offset_shared = 1.0 / 3.0;
        self.dsnu_pre_e = (0.2 * self.read_noise_pre_e * 1000.0).round() / 1000.0;
        self.dsnu_post_dn = (0.2 * self.read_noise_post_dn * 1000.0).round() / 1000.0;
        self
    }

    /// Whether any structured component beyond the per-pixel chain is on: row noise, frame
    /// offsets, column noise or pattern, DSNU.
    pub fn has_structured_noise(&self) -> bool {
        [
            self.row_noise_pre_e,
            self.row_noise_post_dn,
            self.frame_offset_pre_e,
            self.frame_offset_post_dn,
            self.col_noise_dn,
            self.col_pattern_dn,
            self.dsnu_pre_e,
            self.dsnu_post_dn,
        ]
        .iter()
        .any(|&v| v > 0.0)
    }

    /// Checks every parameter; the error names the first bad one and its valid range.
    pub fn validate(&self) -> Result<(), SimError> {
        fn bad(what: &'static str, value: impl std::fmt::Display, fix: &'static str) -> SimError {
            SimError::Parameter { what, value: value.to_string(), fix }
        }
        let fin_nonneg = |x: f32| x.is_finite() && x >= 0.0;
        if self.white < 16 {
            return Err(bad("SensorModel::white", self.white, "use the sensor's saturation level (≥ 16 DN)"));
        }
        for &b in &self.black {
            if !fin_nonneg(b) || b >= self.white as f32 - 8.0 {
                return Err(bad("SensorModel::black", b, "each black level must be ≥ 0 and below white − 8"));
            }
        }
        if self.base_iso == 0 {
            return Err(bad("SensorModel::base_iso", 0, "use the sensor's minimum ISO (≥ 1)"));
        }
        if self.max_analog_iso < self.base_iso {
            return Err(bad("SensorModel::max_analog_iso", self.max_analog_iso, "must be ≥ base_iso"));
        }
        if !(self.electrons_per_dn.is_finite() && self.electrons_per_dn > 0.0) {
            return Err(bad("SensorModel::electrons_per_dn", self.electrons_per_dn, "must be a positive number"));
        }
        if !(self.full_well_e.is_finite() && self.full_well_e > 0.0) {
            return Err(bad("SensorModel::full_well_e", self.full_well_e, "must be a positive number of electrons"));
        }
        if !(self.gain_error_per_stop.is_finite() && self.gain_error_per_stop.abs() < 0.2) {
            return Err(bad("SensorModel::gain_error_per_stop", self.gain_error_per_stop, "must be within ±0.2"));
        }
        for &(iso, e) in &self.gain_error_at {
            if iso == 0 || !(e.is_finite() && e > -0.5 && e < 1.0) {
                return Err(bad(
                    "SensorModel::gain_error_at",
                    format!("({iso}, {e})"),
                    "each entry is (ISO ≥ 1, relative error in (−0.5, 1))",
                ));
            }
        }
        for (what, v) in [
            ("SensorModel::read_noise_pre_e", self.read_noise_pre_e),
            ("SensorModel::read_noise_post_dn", self.read_noise_post_dn),
            ("SensorModel::row_noise_pre_e", self.row_noise_pre_e),
            ("SensorModel::row_noise_post_dn", self.row_noise_post_dn),
            ("SensorModel::jitter_px", self.jitter_px),
        ] {
            if !fin_nonneg(v) {
                return Err(bad(what, v, "must be a finite number ≥ 0"));
            }
        }
        for (what, v) in [
            ("SensorModel::frame_offset_pre_e", self.frame_offset_pre_e),
            ("SensorModel::frame_offset_post_dn", self.frame_offset_post_dn),
            ("SensorModel::col_noise_dn", self.col_noise_dn),
            ("SensorModel::col_pattern_dn", self.col_pattern_dn),
        ] {
            if !(v.is_finite() && (0.0..64.0).contains(&v)) {
                return Err(bad(what, v, "must be a finite RMS in [0, 64)"));
            }
        }
        if !(self.frame_offset_shared.is_finite() && (0.0..=1.0).contains(&self.frame_offset_shared)) {
            return Err(bad(
                "SensorModel::frame_offset_shared",
                self.frame_offset_shared,
                "must be a fraction of the variance in [0, 1]",
            ));
        }
        for (what, shape) in [
            ("SensorModel::row_noise_shape", self.row_noise_shape),
            ("SensorModel::frame_offset_shape", self.frame_offset_shape),
        ] {
            if let Err(e) = shape.check() {
                return Err(SimError::Parameter { what, value: shape.to_string(), fix: e });
            }
        }
        if let Some(d) = self.read_noise_dof
            && !(d.is_finite() && (3.0..=1000.0).contains(&d))
        {
            return Err(bad(
                "SensorModel::read_noise_dof",
                d,
                "Student-t read noise needs 3 ≤ dof ≤ 1000 (finite variance); use None for Gaussian",
            ));
        }
        if let Some(l) = self.read_noise_tukey_lambda {
            if !(l.is_finite() && (-0.45..=1.0).contains(&l)) {
                return Err(bad(
                    "SensorModel::read_noise_tukey_lambda",
                    l,
                    "Tukey-lambda read noise needs −0.45 ≤ λ ≤ 1 (finite variance); use None for Gaussian",
                ));
            }
            if self.read_noise_dof.is_some() {
                return Err(bad(
                    "SensorModel::read_noise_tukey_lambda",
                    l,
                    "set either read_noise_dof (Student-t) or read_noise_tukey_lambda, not both",
                ));
            }
        }
        if !(self.gain_iso_exponent.is_finite() && (0.5..=2.0).contains(&self.gain_iso_exponent)) {
            return Err(bad(
                "SensorModel::gain_iso_exponent",
                self.gain_iso_exponent,
                "must be in [0.5, 2] (1 = gain ∝ ISO)",
            ));
        }
        for (what, v) in
            [("SensorModel::dsnu_pre_e", self.dsnu_pre_e), ("SensorModel::dsnu_post_dn", self.dsnu_post_dn)]
        {
            if !(v.is_finite() && (0.0..64.0).contains(&v)) {
                return Err(bad(what, v, "must be a finite RMS in [0, 64)"));
            }
        }
        for &b in &self.bias_dn {
            if !(b.is_finite() && b.abs() < 64.0) {
                return Err(bad("SensorModel::bias_dn", b, "each bias must be a small finite offset (|bias| < 64 DN)"));
            }
        }
        if !(self.prnu.is_finite() && (0.0..0.2).contains(&self.prnu)) {
            return Err(bad("SensorModel::prnu", self.prnu, "must be in [0, 0.2) (0.005 = 0.5 %)"));
        }
        if !(self.poisson_exact_below.is_finite() && self.poisson_exact_below >= 10.0) {
            return Err(bad("SensorModel::poisson_exact_below", self.poisson_exact_below, "must be ≥ 10 electrons"));
        }
        if let Some(dg) = &self.dual_gain {
            if dg.min_iso <= self.base_iso {
                return Err(bad("DualGain::min_iso", dg.min_iso, "must be above the base ISO"));
            }
            if !fin_nonneg(dg.read_noise_pre_e) || !fin_nonneg(dg.read_noise_post_dn) {
                return Err(bad(
                    "DualGain read noise",
                    format!("{}/{}", dg.read_noise_pre_e, dg.read_noise_post_dn),
                    "must be finite numbers ≥ 0",
                ));
            }
            if !(dg.gain_mismatch.is_finite() && dg.gain_mismatch > 0.5 && dg.gain_mismatch < 2.0) {
                return Err(bad("DualGain::gain_mismatch", dg.gain_mismatch, "must be in (0.5, 2) (1 = none)"));
            }
            if !(dg.full_well_e.is_finite() && dg.full_well_e > 0.0) {
                return Err(bad("DualGain::full_well_e", dg.full_well_e, "must be a positive number of electrons"));
            }
        }
        if let Some(m) = &self.motion {
            let ok = |v: f32, hi: f32| v.is_finite() && (0.0..=hi).contains(&v);
            if !(ok(m.max_shift_px, 8.0)
                && ok(m.step_px, 8.0)
                && ok(m.jump_probability, 1.0)
                && ok(m.max_rotation_rad, 0.05)
                && ok(m.breathing, 0.05))
            {
                return Err(bad(
                    "SensorModel::motion",
                    format!("{m:?}"),
                    "shifts and steps must be in [0, 8] px, the jump probability in [0, 1], rotation in [0, 0.05] rad and breathing in [0, 0.05]",
                ));
            }
        }
        if let Some(f) = &self.flicker
            && !(f.probability.is_finite()
                && (0.0..=1.0).contains(&f.probability)
                && f.amplitude.is_finite()
                && (0.0..0.5).contains(&f.amplitude))
        {
            return Err(bad(
                "SensorModel::flicker",
                format!("probability {} amplitude {}", f.probability, f.amplitude),
                "probability must be in [0, 1] and amplitude in [0, 0.5)",
            ));
        }
        Ok(())
    }

    /// The read-noise law, from `read_noise_dof` and `read_noise_tukey_lambda`.
    pub fn read_noise_shape(&self) -> ReadNoiseShape {
        match (self.read_noise_dof, self.read_noise_tukey_lambda) {
            (Some(dof), _) => ReadNoiseShape::StudentT { dof },
            (None, Some(lambda)) => ReadNoiseShape::TukeyLambda { lambda },
            (None, None) => ReadNoiseShape::Gaussian,
        }
    }

    /// Sets `read_noise_dof` and `read_noise_tukey_lambda` for a read-noise law.
    pub fn set_read_noise_shape(&mut self, shape: ReadNoiseShape) {
        (self.read_noise_dof, self.read_noise_tukey_lambda) = match shape {
            ReadNoiseShape::Gaussian => (None, None),
            ReadNoiseShape::StudentT { dof } => (Some(dof), None),
            ReadNoiseShape::TukeyLambda { lambda } => (None, Some(lambda)),
        };
    }

    /// Relative analog gain error at an ISO (0 at the base ISO).
    pub fn gain_error(&self, iso: u32) -> f32 {
        if let Some(&(_, e)) = self.gain_error_at.iter().find(|(i, _)| *i == iso) {
            return e;
        }
        self.gain_error_per_stop * (iso.max(1) as f32 / self.base_iso.max(1) as f32).log2()
    }

    /// Settings of the signal chain at an ISO.
    pub fn at_iso(&self, iso: u32) -> Result<IsoSettings, SimError> {
        if iso == 0 {
            return Err(SimError::Iso { base_iso: self.base_iso });
        }
        let analog_iso = iso.min(self.max_analog_iso);
        let digital_gain = if iso > self.max_analog_iso { iso as f64 / self.max_analog_iso as f64 } else { 1.0 };
        let hcg = self.dual_gain.as_ref().filter(|d| iso >= d.min_iso);
        let mismatch = hcg.map_or(1.0, |d| d.gain_mismatch as f64);
        let ratio = analog_iso as f64 / self.base_iso as f64;
        // γ = 1 keeps the exact arithmetic of a proportional gain.
        let ratio = if self.gain_iso_exponent == 1.0 { ratio } else { ratio.powf(self.gain_iso_exponent as f64) };
        let analog_gain = ratio * (1.0 + self.gain_error(iso) as f64) * mismatch;
        let dn_per_electron = analog_gain / self.electrons_per_dn as f64;
        Ok(IsoSettings {
            iso,
            analog_gain,
            digital_gain,
            dn_per_electron,
            high_conversion_gain: hcg.is_some(),
            read_noise_pre_e: hcg.map_or(self.read_noise_pre_e, |d| d.read_noise_pre_e) as f64,
            read_noise_post_dn: hcg.map_or(self.read_noise_post_dn, |d| d.read_noise_post_dn) as f64,
            full_well_e: hcg.map_or(self.full_well_e, |d| d.full_well_e) as f64,
            row_noise_dn: ((self.row_noise_pre_e as f64 * analog_gain / self.electrons_per_dn as f64).powi(2)
                + (self.row_noise_post_dn as f64).powi(2))
            .sqrt(),
            dsnu_dn: ((self.dsnu_pre_e as f64 * dn_per_electron).powi(2) + (self.dsnu_post_dn as f64).powi(2)).sqrt(),
            frame_offset_dn: ((self.frame_offset_pre_e as f64 * dn_per_electron).powi(2)
                + (self.frame_offset_post_dn as f64).powi(2))
            .sqrt(),
            col_noise_dn: self.col_noise_dn as f64,
            col_pattern_dn: self.col_pattern_dn as f64,
        })
    }
}

/// The signal chain at one ISO, derived from a [`SensorModel`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct IsoSettings {
    /// The ISO.
    pub iso: u32,
    /// Analog gain relative to the base ISO, gain error and conversion-gain mismatch included.
    pub analog_gain: f64,
    /// Digital gain applied after quantisation (1 at or below `max_analog_iso`).
    pub digital_gain: f64,
    /// ADC DN per electron (analog part only; the output gets `× digital_gain` more).
    pub dn_per_electron: f64,
    /// Whether the second conversion gain is in use.
    pub high_conversion_gain: bool,
    /// Pre-gain read noise (electrons, RMS).
    pub read_noise_pre_e: f64,
    /// Post-gain read noise (DN at the ADC, RMS).
    pub read_noise_post_dn: f64,
    /// Full-well capacity (electrons).
    pub full_well_e: f64,
    /// Total row-noise RMS at the ADC (DN).
    pub row_noise_dn: f64,
    /// Total DSNU RMS at the ADC (DN): the spread of the fixed per-pixel dark offsets,
    /// `√((G·dsnu_pre_e)² + dsnu_post_dn²)`.
    pub dsnu_dn: f64,
    /// RMS of the per-frame black-level error of each CFA position at the ADC (DN):
    /// `√((G·frame_offset_pre_e)² + frame_offset_post_dn²)`.
    pub frame_offset_dn: f64,
    /// RMS of the per-frame column offsets at the ADC (DN).
    pub col_noise_dn: f64,
    /// RMS of the fixed column pattern at the ADC (DN).
    pub col_pattern_dn: f64,
}

impl IsoSettings {
    /// Output DN per electron, digital gain included.
    pub fn total_dn_per_electron(&self) -> f64 {
        self.dn_per_electron * self.digital_gain
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn presets_are_valid_and_gain_is_nearly_proportional() {
        for m in [SensorModel::phone_10bit(), SensorModel::phone_12bit(), SensorModel::phone_14bit()] {
            m.validate().expect("preset");
            let b = m.at_iso(m.base_iso).expect("base");
            assert_eq!(b.analog_gain, 1.0);
            assert_eq!(b.digital_gain, 1.0);
            let s = m.at_iso(m.base_iso * 8).expect("3 stops");
            let ratio = s.total_dn_per_electron() / b.total_dn_per_electron() / 8.0;
            assert!((ratio - 1.0).abs() < 0.03 && ratio != 1.0, "{ratio}");
            let d = m.at_iso(m.max_analog_iso * 2).expect("digital");
            assert_eq!(d.digital_gain, 2.0);
        }
    }

    #[test]
    fn bad_parameters_are_named() {
        let mut m = SensorModel::phone_10bit();
        m.read_noise_dof = Some(2.0);
        let e = m.validate().expect_err("must be refused").to_string();
        assert!(e.contains("read_noise_dof") && e.contains("None for Gaussian"), "{e}");
        let mut m = SensorModel::phone_12bit();
        m.max_analog_iso = 50;
        assert!(m.validate().expect_err("must be refused").to_string().contains("max_analog_iso"));
        assert!(SensorModel::phone_10bit().at_iso(0).expect_err("must be refused").to_string().contains("ISO is 0"));
    }
}
