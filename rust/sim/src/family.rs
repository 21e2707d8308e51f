//! A family of random simulated sensors and capture sessions, drawn (deterministically) from
//! wide parameter ranges, so that noisecal's estimators are tested on sensors nobody tuned them
//! on. [`random_sensor`] draws a [`SensorModel`], [`random_session`] a [`SessionSpec`] for it:
//! image size, bursts, target ISOs, sparse or dense EV sweep, and a matching held-out set.
//!
//! Ranges of [`random_sensor`] (each trait drawn independently unless noted):
//!
//! | trait | range |
//! |---|---|
//! | bits | 10, 12 or 14 (white 2^bits − 1; 1 in 4 sensors 0.5–4 % lower) |
//! | CFA | RGGB, BGGR, GRBG, GBRG |
//! | black | 0–4 DN (1 in 5: the floor clips) or 0.5–6.25 % of the range; 2 in 5 with per-position differences of up to ±1, ±2, ±8 DN (10, 12, 14 bits); 1 in 6 fractional |
//! | base ISO | 40, 50, 64, 80, 100, 125 |
//! | e⁻/DN at base | log-uniform: 10-bit 1.5–8, 12-bit 0.4–3, 14-bit 0.2–0.8 |
//! | full well | (white − black) · e⁻/DN · 0.8–1.6 (below 1: the well fills before the ADC clips) |
//! | read noise | pre-gain 0.5–4 e⁻, post-gain 10-bit 0.15–1.5, 12-bit 0.4–3, 14-bit 1–8 DN (log-uniform) |
//! | shape | Gaussian, Student-t (3–10 dof) or Tukey-λ (λ in [−0.25, 0.14]), 1 in 3 each |
//! | γ (gain ∝ ISO^γ) | 1 exactly (1 in 4) or uniform in [0.8, 1.25]; gain error ±0.6 %/stop |
//! | dual conversion gain | 9 in 20: from 3–16 × base ISO, read noise × 0.3–0.7 (pre) and 0.6–1 (post), gain mismatch ±3 %, full well × 0.3–0.6 |
//! | digital gain | 1 in 2: above 8, 16 or 32 × base ISO (above the dual-gain switch) |
//! | row noise | 1 in 4 none, else up to 20 % (pre) and 25 % (post) of the read noise |
//! | PRNU | 0–1 % |
//! | DSNU | 2 in 5 none, else pre-gain 0.05–1.5 e⁻ and/or post-gain 5–50 % of the post read noise |
//! | bias | ±0.5 (10-bit), ±1 (12-bit), ±2.5 DN (14-bit) per position |
//! | jitter | 0–0.12 px; dynamic black reported 3 in 10 |
//!
//! Sessions ([`random_session`]): reference at the base ISO; 2–4 target ISOs from the
//! third-stop series above the base up to 64 × base (a few off-series), with a pair straddling
//! the dual-gain switch or the start of digital gain in 3 of 5 sessions whose sensor has one;
//! frames per burst 2–32 (sparse) or 2–8 (dense); EV steps sparse (whole stops within −4..=4)
//! or dense (tenth stops over up to ±1 EV, or 10–40 settings 17 or 18 per stop, 3.9–4.2 %
//! apart); image size 64×48 to 256×192 ([`SessionScale::Test`]) or 320×240 to 1024×768
//! ([`SessionScale::Large`]).

use noisecal_core::{CfaPattern, POSITIONS};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::chart::Chart;
use crate::error::SimError;
use crate::model::{DualGain, Flicker, Motion, OffsetShape, ReadNoiseShape, SensorModel};
use crate::noise::{mix64, uniform_open};
use crate::plan::SessionPlan;
use crate::sim::{MID_RANGE_FRACTION, Simulator};

/// Highest target ISO of a random session, as a multiple of the base ISO.
pub const FAMILY_MAX_ISO_FACTOR: u32 = 64;

/// |γ − 1| above which the gain counts as clearly non-proportional to the ISO.
const GAMMA_TOLERANCE: f32 = 0.05;

/// Dark pixels reach the 0 DN floor more often than this (one-sided Gaussian 3σ) ⇒ the black
/// floor clips.
const BLACK_CLIP_SIGMAS: f64 = 3.0;

/// A sensor of the random family with what was drawn.
#[derive(Debug, Clone, PartialEq)]
pub struct RandomSensor {
    /// The seed it was drawn from.
    pub seed: u64,
    /// The sensor (valid: passes [`SensorModel::validate`]).
    pub model: SensorModel,
    /// ADC bit depth (10, 12 or 14).
    pub bits: u32,
    /// A short human description naming the drawn traits.
    pub description: String,
    /// Read noise with positive excess kurtosis (Student-t, or Tukey-λ below ≈ 0.14).
    pub heavy_tails: bool,
    /// Dark pixels clip at 0 DN already at the base ISO (more often than 1 in 740, i.e. the
    /// black level is less than 3 σ of the dark noise, DSNU included). At higher ISOs many more
    /// sensors clip: see [`SessionSpec::clips_black`].
    pub clips_black: bool,
    /// Heavy-tailed read noise, black-floor clipping at the base ISO, or |γ − 1| > 0.05:
    /// Gaussian, proportional-gain noise models are expected to be off on this sensor.
    pub non_gaussian: bool,
}

impl RandomSensor {
    /// A name for file metadata, e.g. `simulated random sensor 17`.
    pub fn name(&self) -> String {
        format!("simulated random sensor {}", self.seed)
    }
}

/// Image sizes of a random session.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum SessionScale {
    /// 64×48 up to 256×192 pixels (unit and end-to-end tests).
    #[default]
    Test,
    /// 320×240 up to 1024×768 pixels.
    Large,
}

/// The held-out (evaluation) set of a [`SessionSpec`]: the same sensor, ISOs and base exposure
/// with fewer frames, fresh noise and possibly another image size. Another size is another crop
/// of the sensor: the DSNU map is the same per (row, col), the PRNU map (keyed by the pixel
/// index, as it always was) is another draw of the same statistics.
#[derive(Debug, Clone, PartialEq)]
pub struct HeldOutSpec {
    /// Image width (pixels, even).
    pub width: u32,
    /// Image height (pixels, even).
    pub height: u32,
    /// Frames per burst (≤ the calibration's).
    pub frames_per_burst: u32,
    /// EV steps (in the calibration's unit `1 / ev_steps_per_stop`): the calibration's, or for a
    /// dense sweep a subset ≥ 0.2 EV apart (a DNG folder of them groups into distinct steps).
    pub ev_steps: Vec<i32>,
    /// Add to every planned frame index when capturing: fresh noise from the same seed.
    pub index_offset: u64,
}

/// A random capture session for a sensor: what a test needs to build a [`Simulator`] and the
/// calibration and held-out [`SessionPlan`]s. Every field is public; change what a test needs.
#[derive(Debug, Clone, PartialEq)]
pub struct SessionSpec {
    /// The seed it was drawn from.
    pub seed: u64,
    /// Image width (pixels, even).
    pub width: u32,
    /// Image height (pixels, even).
    pub height: u32,
    /// Frames per burst.
    pub frames_per_burst: u32,
    /// Reference ISO (the sensor's base ISO).
    pub reference_iso: u32,
    /// Target ISOs, ascending, each ≥ 6 % from the others.
    pub target_isos: Vec<u32>,
    /// EV steps in capture order, in units of `1 / ev_steps_per_stop` EV.
    pub ev_steps: Vec<i32>,
    /// EV steps per stop (1 for sparse sessions).
    pub ev_steps_per_stop: u32,
    /// Whether the sweep is dense (fractional steps).
    pub dense: bool,
    /// The held-out set.
    pub heldout: HeldOutSpec,
    /// Some target ISO uses the second conversion gain (the reference never does).
    pub crosses_dual_gain: bool,
    /// Some target ISO has digital gain.
    pub crosses_digital_gain: bool,
    /// Dark pixels clip at 0 DN at some ISO of the session (see [`RandomSensor::clips_black`]).
    pub clips_black: bool,
    /// The brightest spot of the chart reaches white or the full well in some burst (every
    /// sparse session reaching EV +2 does, like the presets' sessions at EV +4).
    pub clips_white: bool,
    /// Heavy-tailed read noise, |γ − 1| > 0.05, or black-floor clipping at some ISO of the
    /// session. White clipping is not counted: it is in nearly every session by design and
    /// estimators drop clipped levels anyway; read `clips_white` for it.
    pub non_gaussian: bool,
    /// A short human description of the session.
    pub description: String,
    /// Edge blur of the calibration chart (sigma, pixels); `None` for the chart's default.
    pub edge_blur_px: Option<f32>,
}

impl SessionSpec {
    /// The calibration scene: a colour checker of the session's size (and blur).
    pub fn chart(&self) -> Result<Chart, SimError> {
        let mut chart = Chart::color_checker(self.width, self.height)?;
        if let Some(b) = self.edge_blur_px {
            chart.edge_blur_px = b;
            chart.validate()?;
        }
        Ok(chart)
    }

    /// The calibration simulator for `sensor` with noise seed `noise_seed`.
    pub fn simulator(&self, sensor: &SensorModel, noise_seed: u64) -> Result<Simulator, SimError> {
        Simulator::new(sensor.clone(), self.chart()?, noise_seed)
    }

    /// The calibration plan (reference at the base ISO, EV 0 at mid-range).
    pub fn plan(&self, sim: &Simulator) -> Result<SessionPlan, SimError> {
        let plan = SessionPlan::for_simulator(sim, self.target_isos.clone(), self.frames_per_burst)?
            .with_ev_steps_per_stop(self.ev_steps_per_stop)
            .with_ev_steps(self.ev_steps.iter().copied());
        plan.validate()?;
        Ok(plan)
    }

    /// The held-out simulator: same sensor and noise seed (capture with
    /// [`HeldOutSpec::index_offset`] added to the frame index for fresh noise), the held-out
    /// image size, and a scene that does not move (no [`Motion`], no flicker: the truth a
    /// moving calibration is judged against).
    pub fn heldout_simulator(&self, sensor: &SensorModel, noise_seed: u64) -> Result<Simulator, SimError> {
        let mut still = sensor.clone();
        still.motion = None;
        still.flicker = None;
        Simulator::new(still, Chart::color_checker(self.heldout.width, self.heldout.height)?, noise_seed)
    }

    /// The held-out plan: the calibration plan's ISOs and base exposure, the held-out frames
    /// and EV steps.
    pub fn heldout_plan(&self, calibration: &SessionPlan) -> Result<SessionPlan, SimError> {
        let mut plan = calibration.clone().with_ev_steps(self.heldout.ev_steps.iter().copied());
        plan.frames_per_burst = self.heldout.frames_per_burst;
        plan.validate()?;
        Ok(plan)
    }
}

/// Deterministic draws from a ChaCha8 stream; only `next_u64` is used, so the values do not
/// depend on `rand`'s distribution algorithms.
struct Draw(ChaCha8Rng);

impl Draw {
    fn new(seed: u64, salt: u64) -> Self {
        Self(ChaCha8Rng::seed_from_u64(mix64(seed ^ salt)))
    }

    fn unit(&mut self) -> f64 {
        uniform_open(&mut self.0)
    }

    fn uniform(&mut self, lo: f64, hi: f64) -> f64 {
        lo + (hi - lo) * self.unit()
    }

    fn log_uniform(&mut self, lo: f64, hi: f64) -> f64 {
        (lo.ln() + (hi.ln() - lo.ln()) * self.unit()).exp()
    }

    fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }

    /// Uniform integer in `lo..=hi`.
    fn int(&mut self, lo: i64, hi: i64) -> i64 {
        lo + ((self.unit() * (hi - lo + 1) as f64) as i64).min(hi - lo)
    }

    fn pick<T: Copy>(&mut self, xs: &[T]) -> T {
        xs[self.int(0, xs.len() as i64 - 1) as usize]
    }
}

/// Rounds to `digits` decimals (for readable drawn values).
fn round_to(x: f64, digits: i32) -> f32 {
    let k = 10f64.powi(digits);
    ((x * k).round() / k) as f32
}

const SENSOR_SALT: u64 = 0x5345_4E53_4F52_5F46; // "SENSOR_F"
const SESSION_SALT: u64 = 0x5345_5353_494F_4E5F; // "SESSION_"

/// Draws a sensor of the random family from `seed` (same seed, same sensor). See the module
/// documentation for the ranges.
pub fn random_sensor(seed: u64) -> RandomSensor {
    let mut d = Draw::new(seed, SENSOR_SALT);
    let bits = d.pick(&[10u32, 12, 14]);
    let full = (1u32 << bits) - 1;
    let range = (full + 1) as f64;
    let white = if d.chance(0.25) { full - (d.uniform(0.005, 0.04) * full as f64).round() as u32 } else { full };
    let cfa = d.pick(&CfaPattern::ALL);

    // Black level: the floor clips for 1 in 5 sensors.
    let low_black = d.chance(0.2);
    let black0 = if low_black { d.int(0, 4) as f64 } else { (d.uniform(0.005, 0.0625) * range).round() };
    let mut black = [black0 as f32; POSITIONS];
    if d.chance(0.4) {
        let spread = (range / 2048.0).round().max(1.0) as i64;
        for b in &mut black {
            *b = (black0 + d.int(-spread, spread) as f64).max(0.0) as f32;
        }
    }
    if d.chance(1.0 / 6.0) {
        let frac = d.pick(&[0.25f32, 0.5, 0.75]);
        for b in &mut black {
            *b += frac;
        }
    }

    let base_iso = d.pick(&[40u32, 50, 64, 80, 100, 125]);
    let (epd_lo, epd_hi, post_lo, post_hi, bias_scale) = match bits {
        10 => (1.5, 8.0, 0.15, 1.5, 0.5),
        12 => (0.4, 3.0, 0.4, 3.0, 1.0),
        _ => (0.2, 0.8, 1.0, 8.0, 2.5),
    };
    let electrons_per_dn = round_to(d.log_uniform(epd_lo, epd_hi), 3);
    let max_black = black.iter().cloned().fold(0.0f32, f32::max) as f64;
    let well_ratio = d.log_uniform(0.8, 1.6);
    let full_well_e = ((white as f64 - max_black) * electrons_per_dn as f64 * well_ratio).round() as f32;
    let read_noise_pre_e = round_to(d.log_uniform(0.5, 4.0), 3);
    let read_noise_post_dn = round_to(d.log_uniform(post_lo, post_hi), 3);

    let shape = match d.int(0, 2) {
        0 => ReadNoiseShape::Gaussian,
        1 => ReadNoiseShape::StudentT { dof: round_to(d.uniform(3.0, 10.0), 2) },
        _ => ReadNoiseShape::TukeyLambda { lambda: round_to(d.uniform(-0.25, 0.14), 3) },
    };
    let gamma = if d.chance(0.25) { 1.0 } else { round_to(d.uniform(0.8, 1.25), 3) };
    let gain_error_per_stop = round_to(d.uniform(-0.006, 0.006), 4);

    let dual_gain = d.chance(0.45).then(|| {
        let factor = d.pick(&[3u32, 4, 6, 8, 12, 16]);
        DualGain {
            min_iso: base_iso * factor,
            read_noise_pre_e: round_to(read_noise_pre_e as f64 * d.uniform(0.3, 0.7), 3),
            read_noise_post_dn: round_to(read_noise_post_dn as f64 * d.uniform(0.6, 1.0), 3),
            gain_mismatch: round_to(d.uniform(0.97, 1.03), 4),
            full_well_e: (full_well_e as f64 * d.uniform(0.3, 0.6)).round() as f32,
        }
    });
    let dg_factor = dual_gain.as_ref().map_or(1, |g| g.min_iso / base_iso);
    let max_analog_iso = if d.chance(0.5) {
        let options: Vec<u32> = [8u32, 16, 32].into_iter().filter(|&f| f > dg_factor).collect();
        base_iso * if options.is_empty() { 32 } else { d.pick(&options) }
    } else {
        base_iso * 16 * FAMILY_MAX_ISO_FACTOR
    };

    let (row_noise_pre_e, row_noise_post_dn) = if d.chance(0.25) {
        (0.0, 0.0)
    } else {
        (
            round_to(read_noise_pre_e as f64 * d.uniform(0.0, 0.2), 3),
            round_to(read_noise_post_dn as f64 * d.uniform(0.0, 0.25), 3),
        )
    };
    let prnu = round_to(d.uniform(0.0, 0.01), 4);
    let (dsnu_pre_e, dsnu_post_dn) = match d.int(0, 4) {
        0 | 1 => (0.0, 0.0),
        2 => (round_to(d.log_uniform(0.05, 1.5), 3), 0.0),
        3 => (0.0, round_to(read_noise_post_dn as f64 * d.uniform(0.05, 0.5), 3)),
        _ => (round_to(d.log_uniform(0.05, 1.5), 3), round_to(read_noise_post_dn as f64 * d.uniform(0.05, 0.5), 3)),
    };
    let bias_dn: [f32; POSITIONS] = std::array::from_fn(|_| round_to(d.uniform(-1.0, 1.0) * bias_scale, 3));
    let jitter_px = round_to(d.uniform(0.0, 0.12), 3);
    let report_dynamic_black = d.chance(0.3);

    let mut model = SensorModel {
        cfa,
        black,
        white: white as u16,
        base_iso,
        max_analog_iso,
        electrons_per_dn,
        full_well_e,
        gain_error_per_stop,
        gain_error_at: Vec::new(),
        read_noise_pre_e,
        read_noise_post_dn,
        read_noise_dof: None,
        read_noise_tukey_lambda: None,
        gain_iso_exponent: gamma,
        dsnu_pre_e,
        dsnu_post_dn,
        row_noise_pre_e,
        row_noise_post_dn,
        row_noise_shape: OffsetShape::Gaussian,
        frame_offset_pre_e: 0.0,
        frame_offset_post_dn: 0.0,
        frame_offset_shape: OffsetShape::Gaussian,
        frame_offset_shared: 0.0,
        col_noise_dn: 0.0,
        col_pattern_dn: 0.0,
        bias_dn,
        prnu,
        dual_gain,
        flicker: None,
        jitter_px,
        motion: None,
        poisson_exact_below: 1000.0,
        report_dynamic_black,
    };
    model.set_read_noise_shape(shape);

    let heavy_tails = shape.is_heavy_tailed();
    let clips_black = black_floor_clips(&model, base_iso);
    let non_gaussian = heavy_tails || clips_black || (gamma - 1.0).abs() > GAMMA_TOLERANCE;
    let description = describe_sensor(&model, bits, low_black, clips_black);
    RandomSensor { seed, model, bits, description, heavy_tails, clips_black, non_gaussian }
}

const STRUCTURED_SALT: u64 = 0x5354_5255_4354_5552; // "STRUCTUR"

/// A sensor of the random family with structured noise: [`random_sensor`]`(seed)`
/// (same draws, so the same pixel chain) plus, from a separate stream,
///
/// | trait | range |
/// |---|---|
/// | row noise | always: pre-gain 6–20 % of the read noise, post-gain 6–25 % (log-uniform); law Gaussian (1 in 2), Laplace, Student-t 4–10 dof or a scale mixture (5–20 % at ×2–4) |
/// | frame offsets | always: pre-gain 10–50 %, post-gain 10–60 % of the read noise; same choice of laws; 0–60 % shared by the positions |
/// | DSNU | kept if drawn, else pre-gain 0.05–1 e⁻ and post-gain 5–30 % of the post read noise |
/// | column noise | 1 in 3: 3–15 % of the post read noise per frame; 1 in 4: a fixed pattern 3–15 % |
///
/// [`random_sensor`] itself never draws these, so the existing family stays what it was.
pub fn random_sensor_structured(seed: u64) -> RandomSensor {
    let base = random_sensor(seed);
    let mut m = base.model.clone();
    let mut d = Draw::new(seed, STRUCTURED_SALT);
    let shape = |d: &mut Draw| match d.int(0, 5) {
        0..=2 => OffsetShape::Gaussian,
        3 => OffsetShape::Laplace,
        4 => OffsetShape::StudentT { dof: round_to(d.uniform(4.0, 10.0), 2) },
        _ => OffsetShape::ScaleMixture {
            weight: round_to(d.uniform(0.05, 0.2), 3),
            ratio: round_to(d.uniform(2.0, 4.0), 2),
        },
    };
    let (pre, post) = (m.read_noise_pre_e as f64, m.read_noise_post_dn as f64);
    m.row_noise_pre_e = round_to(pre * d.log_uniform(0.06, 0.2), 3);
    m.row_noise_post_dn = round_to(post * d.log_uniform(0.06, 0.25), 3);
    m.row_noise_shape = shape(&mut d);
    m.frame_offset_pre_e = round_to(pre * d.log_uniform(0.1, 0.5), 3);
    m.frame_offset_post_dn = round_to(post * d.log_uniform(0.1, 0.6), 3);
    m.frame_offset_shape = shape(&mut d);
    m.frame_offset_shared = round_to(d.uniform(0.0, 0.6), 2);
    if m.dsnu_pre_e == 0.0 && m.dsnu_post_dn == 0.0 {
        m.dsnu_pre_e = round_to(d.log_uniform(0.05, 1.0), 3);
        m.dsnu_post_dn = round_to(post * d.uniform(0.05, 0.3), 3);
    }
    if d.chance(1.0 / 3.0) {
        m.col_noise_dn = round_to(post * d.uniform(0.03, 0.15), 3);
    }
    if d.chance(0.25) {
        m.col_pattern_dn = round_to(post * d.uniform(0.03, 0.15), 3);
    }
    let heavy_tails = base.heavy_tails;
    let clips_black = black_floor_clips(&m, m.base_iso);
    let non_gaussian = heavy_tails || clips_black || (m.gain_iso_exponent - 1.0).abs() > GAMMA_TOLERANCE;
    let low_black = base.description.contains("(low)");
    let description = describe_sensor(&m, base.bits, low_black, clips_black);
    RandomSensor { seed, model: m, bits: base.bits, description, heavy_tails, clips_black, non_gaussian }
}

/// Whether dark pixels at `iso` fall below 0 DN more often than the one-sided 3σ tail:
/// `min_p(black_p + d·bias_p) < 3·d·σ`, σ² = G²σ_pre² + σ_post² + σ_row² + σ_dsnu² (+ the
/// structured components of [`random_sensor_structured`]: frame offsets, column noise, pattern).
fn black_floor_clips(model: &SensorModel, iso: u32) -> bool {
    let Ok(s) = model.at_iso(iso) else { return false };
    let sigma = ((s.dn_per_electron * s.read_noise_pre_e).powi(2)
        + s.read_noise_post_dn.powi(2)
        + s.row_noise_dn.powi(2)
        + s.dsnu_dn.powi(2)
        + s.frame_offset_dn.powi(2)
        + s.col_noise_dn.powi(2)
        + s.col_pattern_dn.powi(2))
    .sqrt()
        * s.digital_gain;
    (0..POSITIONS)
        .map(|p| model.black[p] as f64 + s.digital_gain * model.bias_dn[p] as f64)
        .any(|floor| floor < BLACK_CLIP_SIGMAS * sigma)
}

fn describe_sensor(m: &SensorModel, bits: u32, low_black: bool, clips_black: bool) -> String {
    let mut parts = vec![format!("{bits}-bit")];
    if m.white as u32 != (1u32 << bits) - 1 {
        parts.push(format!("white {}", m.white));
    }
    parts.push(format!("{:?}", m.cfa).to_uppercase());
    let (lo, hi) = m.black.iter().fold((f32::MAX, f32::MIN), |(a, b), &x| (a.min(x), b.max(x)));
    let mut black = if lo == hi { format!("black {lo}") } else { format!("black {lo}–{hi}") };
    if low_black {
        black.push_str(" (low)");
    }
    if clips_black {
        black.push_str(", floor clips");
    }
    parts.push(black);
    parts.push(format!("base ISO {}", m.base_iso));
    parts.push(format!("{} e/DN", m.electrons_per_dn));
    let adc_well = (m.white as f32 - m.black[0]) * m.electrons_per_dn;
    parts.push(format!(
        "full well {:.0} e{}",
        m.full_well_e,
        if m.full_well_e < adc_well { " (< ADC range)" } else { "" }
    ));
    parts.push(format!("read {} e + {} DN {}", m.read_noise_pre_e, m.read_noise_post_dn, m.read_noise_shape()));
    if m.gain_iso_exponent == 1.0 {
        parts.push("γ 1".into());
    } else {
        parts.push(format!("γ {}", m.gain_iso_exponent));
    }
    match &m.dual_gain {
        Some(g) => parts.push(format!(
            "dual gain from ISO {} (read {} e + {} DN, mismatch {})",
            g.min_iso, g.read_noise_pre_e, g.read_noise_post_dn, g.gain_mismatch
        )),
        None => parts.push("single gain".into()),
    }
    if m.max_analog_iso < m.base_iso * FAMILY_MAX_ISO_FACTOR {
        parts.push(format!("digital gain above ISO {}", m.max_analog_iso));
    }
    if m.row_noise_pre_e > 0.0 || m.row_noise_post_dn > 0.0 {
        parts.push(format!("row noise {} e + {} DN", m.row_noise_pre_e, m.row_noise_post_dn));
    } else {
        parts.push("no row noise".into());
    }
    parts.push(format!("PRNU {:.2} %", m.prnu * 100.0));
    if m.dsnu_pre_e > 0.0 || m.dsnu_post_dn > 0.0 {
        parts.push(format!("DSNU {} e + {} DN", m.dsnu_pre_e, m.dsnu_post_dn));
    }
    if m.row_noise_shape != OffsetShape::Gaussian {
        parts.push(format!("row offsets {}", m.row_noise_shape));
    }
    if m.frame_offset_pre_e > 0.0 || m.frame_offset_post_dn > 0.0 {
        parts.push(format!(
            "frame offsets {} e + {} DN {} ({:.0} % shared)",
            m.frame_offset_pre_e,
            m.frame_offset_post_dn,
            m.frame_offset_shape,
            100.0 * m.frame_offset_shared
        ));
    }
    if m.col_noise_dn > 0.0 || m.col_pattern_dn > 0.0 {
        parts.push(format!("column noise {} DN + pattern {} DN", m.col_noise_dn, m.col_pattern_dn));
    }
    if m.report_dynamic_black {
        parts.push("dynamic black".into());
    }
    parts.join(", ")
}

/// The third-stop ISO series.
const ISO_SERIES: [u32; 28] = [
    25, 32, 40, 50, 64, 80, 100, 125, 160, 200, 250, 320, 400, 500, 640, 800, 1000, 1250, 1600, 2000, 2500, 3200, 4000,
    5000, 6400, 8000, 10000, 12800,
];

/// Test-scale image sizes (4:3, even).
const TEST_SIZES: [(u32, u32); 6] = [(64, 48), (96, 72), (128, 96), (160, 120), (192, 144), (256, 192)];
/// Large image sizes (4:3, even).
const LARGE_SIZES: [(u32, u32); 4] = [(320, 240), (512, 384), (768, 576), (1024, 768)];

/// Draws a test-sized session for `sensor` from `seed` (same seed and sensor, same session).
pub fn random_session(seed: u64, sensor: &SensorModel) -> SessionSpec {
    random_session_scaled(seed, sensor, SessionScale::Test)
}

/// Draws a session for `sensor` from `seed` with images of `scale`.
pub fn random_session_scaled(seed: u64, sensor: &SensorModel, scale: SessionScale) -> SessionSpec {
    let mut d = Draw::new(seed, SESSION_SALT);
    let sizes: &[(u32, u32)] = match scale {
        SessionScale::Test => &TEST_SIZES,
        SessionScale::Large => &LARGE_SIZES,
    };
    let (width, height) = d.pick(sizes);
    let base = sensor.base_iso;
    let top = base.saturating_mul(FAMILY_MAX_ISO_FACTOR);
    let candidates: Vec<u32> =
        ISO_SERIES.iter().copied().filter(|&i| i as f64 > base as f64 * 1.06 && i <= top).collect();
    let n_targets = d.int(2, 4) as usize;
    let mut targets: Vec<u32> = Vec::new();
    let far_enough = |t: &[u32], iso: u32| {
        iso as f64 > base as f64 * 1.06 && t.iter().all(|&o| (iso as f64 / o as f64).ln().abs() > 1.06f64.ln())
    };
    // A pair straddling the dual-gain switch or the start of digital gain.
    let straddle = |d: &mut Draw, t: &mut Vec<u32>, switch: u32, above_inclusive: bool| {
        let below = candidates.iter().copied().rfind(|&i| if above_inclusive { i < switch } else { i <= switch });
        let above = candidates.iter().copied().find(|&i| if above_inclusive { i >= switch } else { i > switch });
        if let (Some(b), Some(a)) = (below, above)
            && d.chance(0.6)
        {
            for iso in [b, a] {
                if far_enough(t, iso) {
                    t.push(iso);
                }
            }
        }
    };
    if let Some(g) = &sensor.dual_gain {
        straddle(&mut d, &mut targets, g.min_iso, true);
    }
    if sensor.max_analog_iso < top {
        straddle(&mut d, &mut targets, sensor.max_analog_iso, false);
    }
    targets.truncate(4);
    let mut guard = 0;
    while targets.len() < n_targets && guard < 1000 {
        guard += 1;
        let iso = if d.chance(0.15) {
            // An off-series ISO, as phones report.
            (base as f64 * 2f64.powf(d.uniform(0.3, FAMILY_MAX_ISO_FACTOR.ilog2() as f64))).round() as u32
        } else {
            d.pick(&candidates)
        };
        if iso <= top && far_enough(&targets, iso) {
            targets.push(iso);
        }
    }
    targets.sort_unstable();

    let dense = d.chance(0.45);
    let (ev_steps, ev_steps_per_stop, frames_per_burst): (Vec<i32>, u32, u32) = if dense {
        let frames = d.pick(&[2u32, 3, 4, 6, 8]);
        if d.chance(0.5) {
            // Tenth-stop steps over up to ±1 EV.
            let (lo, hi) = (d.int(-10, -5) as i32, d.int(5, 10) as i32);
            ((lo..=hi).collect(), 10, frames)
        } else {
            // Photon-transfer-style: 10–40 settings 3.9–4.2 % apart around −1.5..0 EV.
            let per_stop = d.pick(&[17u32, 18]);
            let count = d.int(10, 40) as i32;
            let centre = (d.uniform(-1.5, 0.0) * per_stop as f64).round() as i32;
            let first = centre - count / 2;
            ((first..first + count).collect(), per_stop, frames)
        }
    } else {
        let frames = d.pick(&[2u32, 3, 4, 5, 6, 8, 10, 12, 16, 20, 24, 32]);
        let steps = match d.int(0, 4) {
            0 | 1 => (-4..=4).collect(),
            2 | 3 => (d.int(-4, -2) as i32..=d.int(2, 4) as i32).collect(),
            _ => vec![-4, -2, 0, 2, 4],
        };
        (steps, 1, frames)
    };

    let heldout_size = if d.chance(0.3) { d.pick(sizes) } else { (width, height) };
    // Dense held-out sets keep settings ≥ 0.2 EV (15 %) apart, so that grouping them as a DNG
    // folder (steps closer than 12 % merge) keeps them apart.
    let stride = (0.2 * ev_steps_per_stop as f64).ceil() as usize;
    let heldout_steps: Vec<i32> = ev_steps.iter().copied().step_by(stride.max(1)).collect();
    let heldout = HeldOutSpec {
        width: heldout_size.0,
        height: heldout_size.1,
        frames_per_burst: (frames_per_burst / 2).clamp(2, 8).min(frames_per_burst),
        ev_steps: heldout_steps,
        index_offset: 1_000_000,
    };

    let crosses_dual_gain = sensor.dual_gain.as_ref().is_some_and(|g| targets.iter().any(|&i| i >= g.min_iso));
    let crosses_digital_gain = targets.iter().any(|&i| i > sensor.max_analog_iso);
    let clips_black = std::iter::once(base).chain(targets.iter().copied()).any(|iso| black_floor_clips(sensor, iso));
    let max_ev = ev_steps.iter().copied().max().unwrap_or(0) as f64 / ev_steps_per_stop as f64;
    let clips_white = white_clips(sensor, &targets, max_ev);
    let gamma_off = (sensor.gain_iso_exponent - 1.0).abs() > GAMMA_TOLERANCE;
    let heavy = sensor.read_noise_shape().is_heavy_tailed();
    let non_gaussian = heavy || gamma_off || clips_black;

    let ev_text = if dense {
        format!(
            "dense EV {:+.2}..{:+.2} in 1/{} stops ({} settings)",
            ev_steps[0] as f64 / ev_steps_per_stop as f64,
            max_ev,
            ev_steps_per_stop,
            ev_steps.len()
        )
    } else {
        format!("EV steps {ev_steps:?}")
    };
    let mut description = format!(
        "{width}×{height}, {frames_per_burst} frames/burst, ISO {base} → {targets:?}, {ev_text}; held-out {}×{}, {} frames",
        heldout.width, heldout.height, heldout.frames_per_burst
    );
    for (flag, text) in [
        (crosses_dual_gain, "crosses dual gain"),
        (crosses_digital_gain, "crosses digital gain"),
        (clips_black, "black floor clips"),
        (clips_white, "white clips"),
    ] {
        if flag {
            description.push_str("; ");
            description.push_str(text);
        }
    }

    SessionSpec {
        seed,
        width,
        height,
        frames_per_burst,
        reference_iso: base,
        target_isos: targets,
        ev_steps,
        ev_steps_per_stop,
        dense,
        heldout,
        crosses_dual_gain,
        crosses_digital_gain,
        clips_black,
        clips_white,
        non_gaussian,
        description,
        edge_blur_px: None,
    }
}

const MOTION_SALT: u64 = 0x4D4F_5649_4E47_5343; // "MOVINGSC"

/// What a calibration capture on a real phone adds to a still scene: the chart moves between
/// frames, its edges are blurred, and the lamp may flicker. [`random_moving_scene`] draws one;
/// [`MovingScene::apply`] puts it on a sensor and a session.
#[derive(Debug, Clone, PartialEq)]
pub struct MovingScene {
    /// The scene's motion between frames.
    pub motion: Motion,
    /// Flicker of the lamp (`None`: steady).
    pub flicker: Option<Flicker>,
    /// Edge blur of the chart (sigma, pixels).
    pub edge_blur_px: f32,
}

impl MovingScene {
    /// `sensor` and `session` with this scene: motion and flicker on the sensor (the held-out
    /// simulator leaves both out), the blur on the session's chart.
    pub fn apply(&self, sensor: &mut SensorModel, session: &mut SessionSpec) {
        sensor.motion = Some(self.motion.clone());
        sensor.flicker = self.flicker.clone();
        session.edge_blur_px = Some(self.edge_blur_px);
        session.description.push_str(&format!("; {}", self.describe()));
    }

    /// A short description, e.g. `moves ≤ 0.42 px (step 0.08, 5 % jumps), rotation ≤ 0.0010 rad,
    /// breathing ±0.08 %, blur 1.3 px, flicker 20 % of frames ±0.5 %`.
    pub fn describe(&self) -> String {
        let m = &self.motion;
        let mut s = format!(
            "moves ≤ {:.2} px (step {:.2}, {:.0} % jumps), rotation ≤ {:.4} rad, breathing ±{:.2} %, blur {:.1} px",
            m.max_shift_px,
            m.step_px,
            m.jump_probability * 100.0,
            m.max_rotation_rad,
            m.breathing * 100.0,
            self.edge_blur_px
        );
        if let Some(f) = &self.flicker {
            s.push_str(&format!(", flicker {:.0} % of frames ±{:.2} %", f.probability * 100.0, f.amplitude * 100.0));
        }
        s
    }
}

/// Draws a moving scene from `seed` (a stream of its own: the sensor and session drawn from the
/// same seed stay what they were).
///
/// | trait | range |
/// |---|---|
/// | translation | bound 0.05–0.6 px per axis; walk step 5–40 % of the bound per frame; jumps in 0–10 % of frames |
/// | rotation | bound 0–0.0015 rad about the centre (≤ 0.2 px at the corners of a 256 × 192 image) |
/// | breathing | scale 1 ± 0–0.1 % |
/// | blur | chart edges 0.5–2 px (sigma) |
/// | flicker | 1 in 3: 5–30 % of frames ±0.2–1 % |
pub fn random_moving_scene(seed: u64) -> MovingScene {
    let mut d = Draw::new(seed, MOTION_SALT);
    let max_shift_px = round_to(d.uniform(0.05, 0.6), 3);
    let motion = Motion {
        max_shift_px,
        step_px: round_to(max_shift_px as f64 * d.uniform(0.05, 0.4), 3),
        jump_probability: round_to(d.uniform(0.0, 0.1), 3),
        max_rotation_rad: round_to(d.uniform(0.0, 0.0015), 5),
        breathing: round_to(d.uniform(0.0, 0.001), 5),
    };
    let edge_blur_px = round_to(d.uniform(0.5, 2.0), 2);
    let flicker = d.chance(1.0 / 3.0).then(|| Flicker {
        probability: round_to(d.uniform(0.05, 0.3), 2),
        amplitude: round_to(d.uniform(0.002, 0.01), 4),
    });
    MovingScene { motion, flicker, edge_blur_px }
}

/// Whether the brightest spot of the chart (at [`MID_RANGE_FRACTION`] of the range at EV 0 and
/// the reference ISO) reaches white or the full well at EV `max_ev` at the reference or a target
/// ISO (same ISO × exposure: brightness changes with the gain's departure from proportionality).
fn white_clips(m: &SensorModel, targets: &[u32], max_ev: f64) -> bool {
    let Ok(r) = m.at_iso(m.base_iso) else { return false };
    let max_black = m.black.iter().cloned().fold(0.0f32, f32::max) as f64;
    let span = m.white as f64 - max_black;
    let ref_electrons = MID_RANGE_FRACTION * span / r.total_dn_per_electron() * 2f64.powf(max_ev);
    std::iter::once(m.base_iso).chain(targets.iter().copied()).any(|iso| {
        let Ok(s) = m.at_iso(iso) else { return false };
        let electrons = ref_electrons * m.base_iso as f64 / iso as f64;
        electrons >= s.full_well_e || electrons * s.total_dn_per_electron() >= span
    })
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeSet;

    use super::*;

    #[test]
    fn two_hundred_seeds_validate_and_are_deterministic() {
        let mut descriptions = BTreeSet::new();
        for seed in 0..200u64 {
            let rs = random_sensor(seed);
            rs.model.validate().unwrap_or_else(|e| panic!("seed {seed}: {e}\n{}", rs.description));
            assert_eq!(random_sensor(seed), rs, "seed {seed}: same seed, same sensor");
            let m = &rs.model;
            assert!([10, 12, 14].contains(&rs.bits));
            let full = (1u32 << rs.bits) - 1;
            assert!(m.white as u32 <= full && m.white as f64 >= 0.95 * full as f64, "seed {seed}: white {}", m.white);
            assert!(m.black.iter().all(|&b| b <= 0.07 * full as f32), "seed {seed}: black {:?}", m.black);
            assert!(descriptions.insert(rs.description.clone()), "seed {seed}: duplicate sensor");
            assert!(rs.description.contains(&format!("{}-bit", rs.bits)));

            let spec = random_session(seed, m);
            assert_eq!(random_session(seed, m), spec, "seed {seed}: same seed, same session");
            let ctx = || format!("seed {seed}: {}\n{}", rs.description, spec.description);
            assert!(
                spec.width.is_multiple_of(2) && spec.height.is_multiple_of(2) && (64..=256).contains(&spec.width),
                "{}",
                ctx()
            );
            assert!((2..=32).contains(&spec.frames_per_burst), "{}", ctx());
            assert!((2..=4).contains(&spec.target_isos.len()), "{}", ctx());
            assert_eq!(spec.reference_iso, m.base_iso);
            for w in spec.target_isos.windows(2) {
                assert!(w[1] as f64 > w[0] as f64 * 1.06, "{}: ISOs too close", ctx());
            }
            assert!(spec.target_isos.iter().all(|&i| i as f64 > 1.06 * m.base_iso as f64 && i <= 64 * m.base_iso));
            let sim = spec.simulator(m, 1).unwrap_or_else(|e| panic!("{}: {e}", ctx()));
            let plan = spec.plan(&sim).unwrap_or_else(|e| panic!("{}: {e}", ctx()));
            assert_eq!(plan.len(), spec.ev_steps.len() * (1 + spec.target_isos.len()) * spec.frames_per_burst as usize);
            let held_sim = spec.heldout_simulator(m, 1).unwrap_or_else(|e| panic!("{}: {e}", ctx()));
            let held = spec.heldout_plan(&plan).unwrap_or_else(|e| panic!("{}: {e}", ctx()));
            assert_eq!(held_sim.width(), spec.heldout.width as usize);
            assert_eq!(held.base_exposure_ns, plan.base_exposure_ns);
            assert!(
                held.frames_per_burst <= plan.frames_per_burst && held.frames_per_burst >= 2.min(plan.frames_per_burst)
            );
            assert!(spec.heldout.index_offset >= plan.len() as u64, "{}", ctx());
            // Held-out steps are distinct settings for DNG-folder grouping (≥ 12 % apart).
            let mut evs: Vec<f64> = held.ev_steps.iter().map(|&s| held.ev(s)).collect();
            evs.sort_by(f64::total_cmp);
            assert!(evs.windows(2).all(|w| 2f64.powf(w[1] - w[0]) > 1.13), "{}: held-out {evs:?}", ctx());
            assert!(evs.len() >= 3, "{}", ctx());
            if spec.dense {
                assert!(spec.ev_steps_per_stop >= 10 && spec.ev_steps.len() >= 10, "{}", ctx());
                let span = (plan.ev(*spec.ev_steps.last().expect("steps")) - plan.ev(spec.ev_steps[0])).abs();
                assert!(span <= 2.4, "{}: dense span {span}", ctx());
            } else {
                assert!(spec.ev_steps_per_stop == 1 && spec.ev_steps.iter().all(|s| (-4..=4).contains(s)), "{}", ctx());
            }
            // Every planned frame has a positive exposure and distinct indices.
            assert!(plan.frames().all(|f| f.exposure_ns > 0));
        }
    }

    #[test]
    fn the_family_covers_every_trait() {
        let mut seen = BTreeSet::new();
        for seed in 0..100u64 {
            let rs = random_sensor(seed);
            let m = &rs.model;
            let spec = random_session(seed, m);
            let gamma = m.gain_iso_exponent;
            let traits = [
                format!("bits {}", rs.bits),
                format!("cfa {:?}", m.cfa),
                match m.read_noise_shape() {
                    ReadNoiseShape::Gaussian => "gaussian".to_string(),
                    ReadNoiseShape::StudentT { .. } => "student-t".to_string(),
                    ReadNoiseShape::TukeyLambda { lambda } if lambda < 0.0 => "tukey λ < 0".to_string(),
                    ReadNoiseShape::TukeyLambda { .. } => "tukey λ ≥ 0".to_string(),
                },
                if gamma < 1.0 {
                    "gamma < 1"
                } else if gamma > 1.0 {
                    "gamma > 1"
                } else {
                    "gamma = 1"
                }
                .to_string(),
                format!("dual gain {}", m.dual_gain.is_some()),
                format!("digital gain {}", m.max_analog_iso < 64 * m.base_iso),
                format!("white below max {}", (m.white as u32) < (1u32 << rs.bits) - 1),
                format!("per-position black {}", m.black.iter().any(|&b| b != m.black[0])),
                format!("row noise {}", m.row_noise_pre_e > 0.0),
                format!("dsnu pre {}", m.dsnu_pre_e > 0.0),
                format!("dsnu post {}", m.dsnu_post_dn > 0.0),
                format!("sensor clips black {}", rs.clips_black),
                format!("sensor non-gaussian {}", rs.non_gaussian),
                format!("dense {}", spec.dense),
                format!("steps per stop {}", spec.ev_steps_per_stop.min(17)),
                format!("crosses dual gain {}", spec.crosses_dual_gain),
                format!("crosses digital gain {}", spec.crosses_digital_gain),
                format!("session clips white {}", spec.clips_white),
                format!("session clips black {}", spec.clips_black),
                format!("session non-gaussian {}", spec.non_gaussian),
                format!(
                    "held-out size differs {}",
                    (spec.heldout.width, spec.heldout.height) != (spec.width, spec.height)
                ),
                format!("targets {}", spec.target_isos.len()),
            ];
            seen.extend(traits);
        }
        let mut want: Vec<String> =
            ["bits 10", "bits 12", "bits 14", "gaussian", "student-t", "tukey λ < 0", "tukey λ ≥ 0"]
                .map(String::from)
                .into();
        want.extend(CfaPattern::ALL.map(|c| format!("cfa {c:?}")));
        want.extend(
            ["gamma < 1", "gamma > 1", "gamma = 1", "steps per stop 1", "steps per stop 10", "steps per stop 17"]
                .map(String::from),
        );
        want.extend(["targets 2", "targets 3", "targets 4"].map(String::from));
        for flag in [
            "dual gain",
            "digital gain",
            "white below max",
            "per-position black",
            "row noise",
            "dsnu pre",
            "dsnu post",
            "sensor clips black",
            "sensor non-gaussian",
            "dense",
            "crosses dual gain",
            "crosses digital gain",
            "session clips white",
            "session clips black",
            "session non-gaussian",
            "held-out size differs",
        ] {
            want.push(format!("{flag} true"));
            want.push(format!("{flag} false"));
        }
        let missing: Vec<&String> = want.iter().filter(|w| !seen.contains(*w)).collect();
        assert!(missing.is_empty(), "traits never drawn in 100 seeds: {missing:?}");
    }

    /// Prints the first sensors and sessions of the family:
    /// `cargo test -p noisecal-sim -- --ignored --nocapture print_family`.
    #[test]
    #[ignore = "prints"]
    fn print_family() {
        for seed in 0..20 {
            let rs = random_sensor(seed);
            let spec = random_session(seed, &rs.model);
            println!("#{seed}: {}\n     {}", rs.description, spec.description);
        }
        let n = 1000;
        let mut counts = std::collections::BTreeMap::<&str, usize>::new();
        for seed in 0..n {
            let rs = random_sensor(seed);
            let spec = random_session(seed, &rs.model);
            for (flag, on) in [
                ("sensor heavy tails", rs.heavy_tails),
                ("sensor clips black at base", rs.clips_black),
                ("sensor non-gaussian", rs.non_gaussian),
                ("session dense", spec.dense),
                ("session crosses dual gain", spec.crosses_dual_gain),
                ("session crosses digital gain", spec.crosses_digital_gain),
                ("session clips black", spec.clips_black),
                ("session clips white", spec.clips_white),
                ("session non-gaussian", spec.non_gaussian),
            ] {
                *counts.entry(flag).or_default() += on as usize;
            }
        }
        for (flag, c) in counts {
            println!("{flag}: {:.1} %", 100.0 * c as f64 / n as f64);
        }
    }
}
