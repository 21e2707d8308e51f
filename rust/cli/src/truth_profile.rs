//! The DNG `NoiseProfile` a simulated sensor's DNGs carry with `noisecal simulate --noise-profile`:
//! the sensor model's own noise law at each ISO (its truth, not a fit), as a real camera writes
//! its profile.

use noisecal_core::model::layout::POSITIONS;
use noisecal_core::model::pack::NoiseProfile;
use noisecal_sim::Simulator;

/// Fractions of the range where the variance law is read: above the black floor's clipping, below
/// any full well.
const LOW: f64 = 0.05;
const HIGH: f64 = 0.25;

/// The NoiseProfile of `sim` at `iso`, per CFA position: `σ²/R² = S·x + O` with `x = (l − black)/R`
/// and `R = white − black` (Camera2's `SENSOR_NOISE_PROFILE`, DNG tag 51041), through the model's
/// temporal variance ([`Simulator::predicted_variance`]: shot noise, read noise, row and frame
/// offsets, quantisation; linear in the level) at 5 % and 25 % of the range. `O` is kept ≥ 0 (a
/// bias above black can put the line's foot below zero).
pub fn truth_noise_profile(sim: &Simulator, iso: u32) -> anyhow::Result<NoiseProfile> {
    let model = sim.model();
    let white = f64::from(model.white);
    let mut out = [[0.0; 2]; POSITIONS];
    for (pos, o) in out.iter_mut().enumerate() {
        let black = f64::from(model.black[pos]);
        let r = (white - black).max(1.0);
        let at = |x: f64| sim.predicted_variance(iso, (black + x * r) as f32, pos);
        let (lo, hi) = (at(LOW)?, at(HIGH)?);
        let slope = (hi - lo) / ((HIGH - LOW) * r); // DN² per DN
        let foot = lo - slope * LOW * r; // DN² at black
        *o = [(slope / r).max(0.0), (foot / (r * r)).max(0.0)];
    }
    let profile = NoiseProfile(out);
    if let Some(problem) = profile.problem() {
        anyhow::bail!("the simulated sensor's noise at ISO {iso} has no usable NoiseProfile: {problem}");
    }
    Ok(profile)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::simulate::Preset;

    /// Known truth in (the simulator's own frames), measured out: the profile's variance against
    /// the temporal variance of simulated frames of a flat field, per CFA position, at a low and a
    /// mid level, at a low-gain, a high-conversion-gain and a digital-gain ISO.
    #[test]
    fn the_profile_predicts_the_variance_of_simulated_frames() {
        let (w, h, frames) = (96usize, 64usize, 12u64);
        for (iso, exposure_scale) in [(400u32, 0.05f64), (1600, 0.05), (1600, 0.6), (6400, 0.3)] {
            let chart = noisecal_sim::Chart::flat(w as u32, h as u32, [0.5; 3]).expect("chart");
            let sim = Simulator::new(Preset::Phone12.model(), chart, 3).expect("sim");
            let exposure =
                ((sim.mid_range_exposure_ns(iso).expect("exposure") as f64) * exposure_scale).max(1.0) as u64;
            let caps: Vec<_> = (0..frames).map(|k| sim.capture(iso, exposure, k).expect("capture").0).collect();
            let p = truth_noise_profile(&sim, iso).expect("profile");
            let model = sim.model();
            for pos in 0..POSITIONS {
                let black = f64::from(model.black[pos]);
                let r = f64::from(model.white) - black;
                let (mut measured, mut predicted, mut n) = (0.0, 0.0, 0.0);
                for y in (pos / 2..h).step_by(2) {
                    for x in (pos % 2..w).step_by(2) {
                        let v: Vec<f64> = caps.iter().map(|c| f64::from(c[(y, x)])).collect();
                        let mean = v.iter().sum::<f64>() / frames as f64;
                        measured += v.iter().map(|a| (a - mean).powi(2)).sum::<f64>() / (frames - 1) as f64;
                        predicted += (p.scale(pos) * (mean - black) / r + p.offset(pos)) * r * r;
                        n += 1.0;
                    }
                }
                let ratio = measured / predicted;
                eprintln!("ISO {iso} ×{exposure_scale} position {pos}: measured / profile variance {ratio:.3}");
                // 1 536 pixels × 11 degrees of freedom per position: SE of the ratio ≈ 1.1 %.
                assert!(
                    (ratio - 1.0).abs() < 0.05,
                    "ISO {iso} ×{exposure_scale} pos {pos}: measured/profile {ratio:.3}"
                );
                assert!(n > 1000.0);
            }
        }
    }
}
