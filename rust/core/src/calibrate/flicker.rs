//! A frame's brightness (lamp flicker, exposure jitter: `∝` the signal) parted from its
//! black-level offset (the same DN at every level) in the frame offsets (method.md, "Frame
//! offsets: black level, not the lamp").
//!
//! Per burst, each frame's deviation from the burst's mean comes per CFA position from
//! [`structure`](super::structure)'s fits: at black (a burst whose levels resolve the frames'
//! slopes: the intercepts, the slope being the brightness) or at the burst's level (the frames'
//! mean deviations: offset and brightness together, `a + g·L`). For the latter this module
//! takes the brightness out where the data allows it:
//!
//! - the positions' **differences** within a frame are offsets (the brightness multiplies every
//!   position's level alike: it moves them apart by `g·(Lₚ − L̄)` only, taken out with it);
//! - the frame's **common part** `c` (the positions' mean deviation) is `a + g·L̄`, which one level
//!   cannot part. It is taken for brightness when brightness can explain it: the relative spread
//!   it asks for, `√(Var c − sampling)/L̄`, is at most [`MAX_FLICKER`] (a dark burst's deviations
//!   are not the lamp's) and within what the frames' fitted slopes allow where the burst's levels
//!   measured them (three standard errors up). Otherwise it stays an offset.
//!
//! Brightness is a property of the light, not of the sensor: it is reported per burst
//! ([`BurstFlicker`]), never synthesized (a user's clean image has none).

use serde::{Deserialize, Serialize};

use crate::model::layout::POSITIONS;

/// Largest relative brightness spread over a burst's frames taken for the lamp's: above it a
/// frame's common deviation is an offset. Drift (`drift.rs`) normalises frames whose brightness
/// departs beyond 0.2 % (or 5 of its standard errors), so what reaches the frame offsets is
/// below that; 1 % leaves room for the standard-error term on small or dark crops, and a burst
/// 0.03 DN above black whose frames move by 0.03 DN (the EMVA set's dark burst) is not flicker.
pub(crate) const MAX_FLICKER: f64 = 0.01;
/// Standard errors a spread must clear to count (as `structure.rs`'s components).
const SIGNIFICANCE: f64 = 3.0;

/// One frame's deviation from its burst's mean per CFA position, as the burst's fits give it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct FrameDeviation {
    /// The deviation (DN).
    pub(crate) value: [f64; POSITIONS],
    /// Its sampling variance (DN²).
    pub(crate) var: [f64; POSITIONS],
    /// The same with each line's leverage corrected for (`structure.rs`, `LevelFit`): what the
    /// frame component's significance test compares with.
    pub(crate) test_var: [f64; POSITIONS],
    /// The clean level above black it was taken at (DN); `NaN` for an intercept at black.
    pub(crate) level: [f64; POSITIONS],
}

/// The spread of one line parity's fitted slopes over a burst's frames (`structure.rs`,
/// `use_slope`): `Σ g²/(k − 1)` and the slopes' mean sampling variance.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SlopeSpread {
    pub(crate) spread: f64,
    pub(crate) sampling: f64,
    pub(crate) frames: usize,
}

/// What one burst's frames showed of the light: the relative spread of their brightness.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub(crate) struct BurstFlicker {
    /// The burst's mean clean level above black (DN).
    pub(crate) level: f64,
    /// SD of the frames' brightness over the burst, relative (sampling noise taken out; `0`
    /// when none shows).
    pub(crate) sd: f64,
    /// Its standard error.
    pub(crate) se: f64,
    pub(crate) frames: u32,
    /// `true`: measured by the frames' slopes (the offsets are taken at black); `false`: their
    /// common deviation, taken out of the offsets.
    pub(crate) from_slopes: bool,
}

impl BurstFlicker {
    /// From a relative variance `tau2` (sampling variance taken out; clamped at 0) and its
    /// standard error `se`: the SD and the SD's standard error (delta method; `√se` at 0).
    fn from_variance(level: f64, tau2: f64, se: f64, frames: usize, from_slopes: bool) -> Self {
        let sd = tau2.max(0.0).sqrt();
        let se = if sd > 0.0 { se / (2.0 * sd) } else { se.sqrt() };
        Self { level, sd, se, frames: frames as u32, from_slopes }
    }

    /// Whether the spread stands clear of its standard error.
    pub(crate) fn significant(&self) -> bool {
        self.sd > 0.0 && self.sd > SIGNIFICANCE * self.se
    }
}

/// `(τ², its standard error)` from the slopes of the line parities that fitted them: the spread
/// less the sampling variance, pooled.
fn slopes_tau2(slopes: &[SlopeSpread]) -> Option<(f64, f64)> {
    if slopes.is_empty() {
        return None;
    }
    let n = slopes.len() as f64;
    let spread = slopes.iter().map(|s| s.spread).sum::<f64>() / n;
    let sampling = slopes.iter().map(|s| s.sampling).sum::<f64>() / n;
    let dof: f64 = slopes.iter().map(|s| s.frames.saturating_sub(1) as f64).sum();
    if dof < 1.0 {
        return None;
    }
    Some((spread - sampling, spread * (2.0 / dof).sqrt()))
}

/// Takes the brightness out of a burst's frame deviations where it can (module docs) and says
/// what the burst showed of it. `frames` in capture order; `slopes` per line parity whose
/// slopes were fitted; `level` the burst's mean level above black (for the report when every
/// position is at black).
pub(crate) fn separate(frames: &mut [FrameDeviation], slopes: &[SlopeSpread], level: f64) -> Option<BurstFlicker> {
    let k = frames.len();
    if k < 2 {
        return None;
    }
    let tau2 = slopes_tau2(slopes);
    let at_level: Vec<usize> =
        (0..POSITIONS).filter(|&p| frames.iter().all(|f| f.level[p].is_finite() && f.value[p].is_finite())).collect();
    if at_level.is_empty() {
        // Every position at black: the slopes are the brightness, already apart.
        let (t2, se) = tau2?;
        return Some(BurstFlicker::from_variance(level, t2, se, k, true));
    }
    let n = at_level.len() as f64;
    // Per frame: the common deviation, its sampling variance, the mean level.
    let common: Vec<(f64, f64, f64)> = frames
        .iter()
        .map(|f| {
            let c = at_level.iter().map(|&p| f.value[p]).sum::<f64>() / n;
            let v = at_level.iter().map(|&p| f.var[p]).sum::<f64>() / (n * n);
            let l = at_level.iter().map(|&p| f.level[p]).sum::<f64>() / n;
            (c, v, l)
        })
        .collect();
    let kf = k as f64;
    let mean_c = common.iter().map(|c| c.0).sum::<f64>() / kf;
    let var_c = common.iter().map(|c| (c.0 - mean_c).powi(2)).sum::<f64>() / (kf - 1.0);
    let sampling = common.iter().map(|c| c.1).sum::<f64>() / kf;
    let l = common.iter().map(|c| c.2).sum::<f64>() / kf;
    let own = var_c - sampling;
    // Relative: `τ²` the brightness needs, and the standard error of `Var c`.
    let need = own.max(0.0) / (l * l);
    let se_need = var_c * (2.0 / (kf - 1.0)).sqrt() / (l * l);
    let slopes_allow = tau2.is_none_or(|(t2, se)| need <= t2.max(0.0) + SIGNIFICANCE * se);
    // At or below black no lamp moves a frame (and `need` is not a number there).
    if !(l > 0.0 && need.sqrt() <= MAX_FLICKER && slopes_allow) {
        // An offset: left as it is; the slopes' brightness, where measured, reported.
        return tau2.map(|(t2, se)| BurstFlicker::from_variance(l, t2, se, k, true));
    }
    for (f, &(c, _, _)) in frames.iter_mut().zip(&common) {
        let g = c / l;
        let (var, test_var) = (f.var, f.test_var);
        let sum_var: f64 = at_level.iter().map(|&p| var[p]).sum();
        let sum_test: f64 = at_level.iter().map(|&p| test_var[p]).sum();
        for &p in &at_level {
            // `aₚ = vₚ − rₚ·c`, `rₚ = Lₚ/L̄`: its sampling variance with the positions' errors
            // independent.
            let r = f.level[p] / l;
            f.value[p] -= g * f.level[p];
            f.var[p] = var[p] * (1.0 - 2.0 * r / n) + r * r * sum_var / (n * n);
            f.test_var[p] = test_var[p] * (1.0 - 2.0 * r / n) + r * r * sum_test / (n * n);
        }
    }
    Some(BurstFlicker::from_variance(l, need, se_need, k, false))
}

/// A note on the flicker an ISO's bursts showed (those where it stands clear of its standard
/// error), for the pack's warnings; `None` when none did.
pub(crate) fn note(iso: u32, bursts: &[BurstFlicker]) -> Option<String> {
    let shown: Vec<String> = bursts
        .iter()
        .filter(|b| b.significant())
        .map(|b| {
            format!(
                "{:.3} % ± {:.3} % over {} frames at {:.0} DN{}",
                100.0 * b.sd,
                100.0 * b.se,
                b.frames,
                b.level,
                if b.from_slopes { "" } else { " (taken out of the frame offsets)" }
            )
        })
        .collect();
    (!shown.is_empty()).then(|| {
        format!(
            "ISO {iso}: the frames' brightness changed within a burst (lamp flicker or exposure jitter, not sensor noise; not synthesized): {}",
            shown.join("; ")
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use rand_distr::{Distribution, Normal};

    /// `k` frames of a flat field at `level` (all four positions) with brightness SD `tau`,
    /// common offsets SD `common`, per-position offsets SD `own`, and sampling SD `noise`;
    /// and the frames' brightness changes.
    fn burst(
        k: usize,
        level: f64,
        tau: f64,
        common: f64,
        own: f64,
        noise: f64,
        seed: u64,
    ) -> (Vec<FrameDeviation>, Vec<f64>) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let unit = Normal::new(0.0, 1.0).expect("normal");
        (0..k)
            .map(|_| {
                let g = tau * unit.sample(&mut rng);
                let c = common * unit.sample(&mut rng);
                let value = std::array::from_fn(|_| {
                    c + g * level + own * unit.sample(&mut rng) + noise * unit.sample(&mut rng)
                });
                (
                    FrameDeviation {
                        value,
                        var: [noise * noise; POSITIONS],
                        test_var: [noise * noise; POSITIONS],
                        level: [level; POSITIONS],
                    },
                    g,
                )
            })
            .unzip()
    }

    fn sample_sd(x: &[f64]) -> f64 {
        let k = x.len() as f64;
        let m = x.iter().sum::<f64>() / k;
        (x.iter().map(|v| (v - m).powi(2)).sum::<f64>() / (k - 1.0)).sqrt()
    }

    /// The offsets' SD over frames at each position, sampling variance taken out.
    fn offset_sd(frames: &[FrameDeviation]) -> f64 {
        let k = frames.len() as f64;
        let mut total = 0.0;
        for p in 0..POSITIONS {
            let m = frames.iter().map(|f| f.value[p]).sum::<f64>() / k;
            let v = frames.iter().map(|f| (f.value[p] - m).powi(2)).sum::<f64>() / (k - 1.0);
            let s = frames.iter().map(|f| f.var[p]).sum::<f64>() / k;
            total += (v - s) / POSITIONS as f64;
        }
        total.max(0.0).sqrt()
    }

    /// A bright flat field whose frames only flicker (0.05 % at 2 000 DN: 1 DN) gives offsets of
    /// 0 and the flicker back; kept as offsets (before), the positions read ~1 DN. Over 200
    /// seeds: the offsets' SD below 0.1 DN (sampling SD 0.1 DN per position: what is left is
    /// the sampling variance's estimation noise, ~0.001 DN² per position) and the flicker within
    /// 0.005 % of the frames' sample SD (the common deviation's sampling noise, 0.05 DN, moves it
    /// by ~0.0005 %).
    #[test]
    fn flicker_alone_is_taken_out_and_reported() {
        for seed in 0..200 {
            let (mut f, g) = burst(25, 2000.0, 5e-4, 0.0, 0.0, 0.1, seed);
            let before = offset_sd(&f);
            let b = separate(&mut f, &[], 2000.0).expect("reported");
            let want = sample_sd(&g);
            assert!(before > 0.6, "seed {seed}: the burst's offsets before {before:.3} DN");
            assert!(offset_sd(&f) < 0.1, "seed {seed}: offsets {:.3} DN left", offset_sd(&f));
            assert!(
                !b.from_slopes && (b.sd - want).abs() < 5e-5,
                "seed {seed}: flicker {:.4} % reported, {:.4} % in the frames",
                100.0 * b.sd,
                100.0 * want
            );
            assert!(b.significant(), "seed {seed}: 1 DN of flicker not significant");
        }
    }

    /// Per-position offsets (0.25 DN each, the EMVA dark burst's scale) under the same flicker
    /// are kept: over 200 seeds their SD within 0.1 DN of 0.25 √(3/4) (the positions' common
    /// part goes with the brightness, a quarter of their variance); a wrong split that took all
    /// of each position's deviation for brightness would leave 0, one that kept it all ~1 DN.
    #[test]
    fn per_position_offsets_survive_the_flicker() {
        let want = 0.25 * 0.75f64.sqrt();
        let mut worst: f64 = 0.0;
        for seed in 0..200 {
            let (mut f, _) = burst(25, 2000.0, 5e-4, 0.0, 0.25, 0.1, 1000 + seed);
            separate(&mut f, &[], 2000.0).expect("reported");
            worst = worst.max((offset_sd(&f) - want).abs());
        }
        assert!(worst < 0.1, "offsets off by up to {worst:.3} DN");
    }

    /// A dark burst (3 DN above black) whose frames move by 0.3 DN is not flicker (it would need
    /// 10 %): its deviations stay offsets, none is reported.
    #[test]
    fn a_dark_bursts_deviations_stay_offsets() {
        let (mut f, _) = burst(25, 3.0, 0.0, 0.3, 0.0, 0.05, 7);
        let before = f.clone();
        let b = separate(&mut f, &[], 3.0);
        assert_eq!(f, before, "a dark burst's offsets changed");
        assert!(b.is_none(), "{b:?}");
    }

    /// Where the slopes were measured and rule brightness out (their spread is their sampling
    /// noise), a common deviation of 1 DN at 2 000 DN stays an offset.
    #[test]
    fn slopes_that_saw_no_flicker_keep_the_offsets() {
        let (mut f, _) = burst(25, 2000.0, 0.0, 1.0, 0.0, 0.1, 8);
        let before = f.clone();
        let slopes = [SlopeSpread { spread: 1e-10, sampling: 1e-10, frames: 25 }; 2];
        let b = separate(&mut f, &slopes, 2000.0).expect("the slopes' report");
        assert_eq!(f, before);
        assert!(b.from_slopes && !b.significant(), "{b:?}");
    }
}
