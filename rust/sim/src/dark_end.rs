//! Sensors whose noise at black is small against the noise at the darkest level a chart session
//! measures: the dark end, where a pack's coarse bins (64 DN at 14 bits) must follow the noise
//! law below the data. [`SensorModel::dark_14bit`] is the named preset; [`random_dark_sensor`]
//! draws members of the random family with the same property.

use crate::family::{RandomSensor, random_sensor};
use crate::model::{DualGain, OffsetShape, SensorModel};

impl SensorModel {
    /// A 14-bit dual-gain sensor with a low read noise in high conversion gain: RGGB, black
    /// 1024, white 16383 (64 DN bins by default), base ISO 100, 9.6 e⁻/DN at base, high
    /// conversion gain from ISO 800 (0.6 e⁻ pre-gain, 0.8 DN post-gain), digital gain above
    /// ISO 6400, Gaussian read noise. At ISO 3200 (3.33 DN/e⁻) the temporal variance is about
    /// 4.8 DN² at black and 105 DN² 30 DN above it: the case, where a pack held the
    /// darkest bin's variance down to black. `phone_14bit` is far noisier at black (its read
    /// noise dominates the first bins) and cannot show it.
    pub fn dark_14bit() -> Self {
        Self {
            cfa: noisecal_core::CfaPattern::Rggb,
            black: [1024.0; noisecal_core::POSITIONS],
            white: 16383,
            base_iso: 100,
            max_analog_iso: 6400,
            electrons_per_dn: 9.6,
            full_well_e: 150_000.0,
            gain_error_per_stop: 0.002,
            gain_error_at: Vec::new(),
            read_noise_pre_e: 2.5,
            read_noise_post_dn: 1.0,
            read_noise_dof: None,
            read_noise_tukey_lambda: None,
            gain_iso_exponent: 1.0,
            dsnu_pre_e: 0.0,
            dsnu_post_dn: 0.0,
            row_noise_pre_e: 0.05,
            row_noise_post_dn: 0.1,
            row_noise_shape: OffsetShape::Gaussian,
            frame_offset_pre_e: 0.0,
            frame_offset_post_dn: 0.0,
            frame_offset_shape: OffsetShape::Gaussian,
            frame_offset_shared: 0.0,
            col_noise_dn: 0.0,
            col_pattern_dn: 0.0,
            // The black level reported is the true dark level: a reported black off by δ DN moves
            // the truth near black by the shot slope × δ (3.3 DN² per DN at ISO 3200, 70 % of
            // the variance at black for δ = 1), which no chart data shows (method.md, *Known
            // limits*).
            bias_dn: [0.0; noisecal_core::POSITIONS],
            prnu: 0.005,
            dual_gain: Some(DualGain {
                min_iso: 800,
                read_noise_pre_e: 0.6,
                read_noise_post_dn: 0.8,
                gain_mismatch: 1.0,
                full_well_e: 40_000.0,
            }),
            flicker: None,
            jitter_px: 0.05,
            motion: None,
            poisson_exact_below: 1000.0,
            report_dynamic_black: false,
        }
    }
}

/// The `n`-th 14-bit dual-gain sensor of the random family (in seed order from 0) whose
/// variance at black, at `factor` × its base ISO in high conversion gain, is below a fifth of
/// its variance 30 DN above black, and whose black level is at least 20 noise SDs above the 0 DN
/// floor there (heavy tails then do not reach the floor's clamp, which is a case of its own);
/// with the seed it was drawn from. The family is unchanged: this only picks members of it.
pub fn random_dark_sensor(n: usize, factor: u32) -> RandomSensor {
    let mut found = 0;
    for seed in 0.. {
        let s = random_sensor(seed);
        if s.bits != 14 || s.clips_black || !has_dark_end(&s.model, factor) {
            continue;
        }
        if found == n {
            return s;
        }
        found += 1;
    }
    unreachable!("the seeds run out before the family does")
}

/// Whether `model` at `factor` × its base ISO reads in high conversion gain with a variance at
/// black below a fifth of that 30 DN above black and a black level 20 SDs of it above 0 (analog
/// part, digital gain left out).
fn has_dark_end(model: &SensorModel, factor: u32) -> bool {
    let iso = model.base_iso * factor;
    let Ok(s) = model.at_iso(iso) else { return false };
    if !s.high_conversion_gain {
        return false;
    }
    let g = s.dn_per_electron;
    let at_black = g * g * s.read_noise_pre_e.powi(2) + s.read_noise_post_dn.powi(2) + s.row_noise_dn.powi(2);
    let black = model.black.iter().cloned().fold(f32::INFINITY, f32::min) as f64;
    at_black < 0.2 * (at_black + g * 30.0) && black >= 20.0 * at_black.sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_preset_has_the_dark_end_and_the_family_members_do_too() {
        let m = SensorModel::dark_14bit();
        m.validate().expect("preset");
        assert!(has_dark_end(&m, 32));
        let s = m.at_iso(3200).expect("ISO 3200");
        let black = s.dn_per_electron.powi(2) * s.read_noise_pre_e.powi(2)
            + s.read_noise_post_dn.powi(2)
            + s.row_noise_dn.powi(2)
            + 1.0 / 12.0;
        assert!((4.5..5.2).contains(&black), "{black}");
        // Not every 14-bit sensor of the family has it (the property picks).
        assert!(!has_dark_end(&SensorModel::phone_14bit(), 32));
        for n in 0..2 {
            let r = random_dark_sensor(n, 16);
            assert_eq!(r.bits, 14);
            assert!(has_dark_end(&r.model, 16) && !r.clips_black, "{}", r.description);
        }
        assert_ne!(random_dark_sensor(0, 16).seed, random_dark_sensor(1, 16).seed);
    }
}
