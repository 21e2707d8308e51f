//! The upper range is as smooth as the truth: a ramp over every clean code,
//! synthesized with the pixel-independent model, must not show the mean of the added noise
//! jumping between adjacent levels further than the calibration data can tell apart.
//!
//! The mean and variance of `finish(L + n) − L` are computed exactly from the sampler's tables
//! (no sampling error), per ISO, CFA position and clean level `L`.

use noisecal_core::model::structure::Components;
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::{ModelPack, model::pack::IsoModel};
use noisecal_e2e::{calibrate, calibrate_lenient, setup};
use noisecal_sim::SensorModel;
use noisecal_sim::{random_sensor, random_session};
use rayon::prelude::*;

/// Exact (mean, variance) of the added noise at clean level `level`.
fn moments_at(s: &IsoSampler, pos: usize, level: u16) -> (f64, f64) {
    let t = s.table(pos, level);
    let (mut m1, mut m2) = (0.0, 0.0);
    for (i, _) in t.cdf().iter().enumerate() {
        let n = t.first() + i as i32;
        let p = t.prob(n);
        if p == 0.0 {
            continue;
        }
        let d = s.finish(pos, level as i32 + n, false) as f64 - level as f64;
        m1 += p * d;
        m2 += p * d * d;
    }
    (m1, m2 - m1 * m1)
}

/// A bin whose mean steps away from the line through its neighbours' means.
struct Step {
    iso: u32,
    pos: usize,
    bin: usize,
    /// The bin's mean, and the mean of its two neighbours' (DN).
    mean: f64,
    neighbours: f64,
    /// The standard error of `mean − neighbours` the calibration samples support:
    /// `√(v/n + (v₋/n₋ + v₊/n₊)/4)`, `n` each bin's own samples.
    se: f64,
    clipped: bool,
}

impl Step {
    fn z(&self) -> f64 {
        (self.mean - self.neighbours).abs() / self.se
    }
}

/// Per bin, the mean over its levels of the added noise's exact mean, and its variance.
///
/// The ramp's mean is judged by second differences of the bins' means: a smooth truth (the
/// gain ratio's slope, the clamp's curve near white or the floor) has a bin's mean on the line
/// through its neighbours' to well within a standard error, while a bin that jumps does not.
/// The bin holding the ceiling (white, or the level where the output piles up below it, at the
/// ISO or at the reference ISO, or the lowest clipped bin at the top whose variance is not the
/// law's)
/// and every bin from the one below it up are left out: the truth itself jumps there
/// (a clean level at the ceiling means every reference frame read the ceiling: a saturated
/// pixel, whose noise the clean level does not predict). So is bin 0,
/// which also holds every level below black, where a clean image does not go.
fn steps(pack: &ModelPack, model: &IsoModel) -> Vec<Step> {
    let s = IsoSampler::with_components(pack, model, Components::PIXEL).without_lattice();
    let mut out = Vec::new();
    for pos in 0..4 {
        let [lo, hi] = s.range(pos);
        let lut = s.binning.lut(pos);
        let bins = &model.positions[pos].bins;
        let mut acc = vec![(0.0f64, 0.0f64, 0u32); bins.len()];
        for level in lo..=hi {
            let (m, v) = moments_at(&s, pos, level as u16);
            let a = &mut acc[lut[level as usize] as usize];
            *a = (a.0 + m, a.1 + v, a.2 + 1);
        }
        let stat: Vec<Option<(f64, f64)>> =
            acc.iter().map(|&(m, v, k)| (k > 0).then(|| (m / k as f64, v / k as f64))).collect();
        let var_n = |b: usize| stat[b].map_or(0.0, |(_, v)| v / bins[b].samples.max(1) as f64);
        // The bin of the ceiling (white, or where the output piles up below it, at this ISO or
        // at the reference ISO whose burst made the clean image) and the one below it have the
        // saturation's jump as a neighbour.
        let reference_top =
            pack.isos.iter().find(|r| r.iso == pack.reference_iso).map_or(hi, |r| r.range[pos][1] as i32);
        let mut ceiling = lut[hi.min(reference_top) as usize] as usize;
        // A pile-up the range does not record (the full well spread by PRNU): the lowest bin of
        // the top clipped run whose samples' variance is not the law's (under a quarter: the
        // target saturates too; over four times: the gain ratio spreads the unknown levels
        // beyond the reference's saturation).
        if let Some(est) = model.positions[pos].estimate.as_ref() {
            let mut b = ceiling;
            while b > 0 && (bins[b - 1].clipped || bins[b - 1].samples == 0) {
                b -= 1;
                if let Some([_, v]) = bins[b].measured
                    && bins[b].samples >= 32
                    && !(0.25..=4.0).contains(&(v / est.law[b][1] as f64))
                {
                    ceiling = b;
                }
            }
        }
        for b in 2..ceiling.saturating_sub(1).min(bins.len().saturating_sub(2)) {
            let (Some((m0, _)), Some((m, _)), Some((m1, _))) = (stat[b - 1], stat[b], stat[b + 1]) else {
                continue;
            };
            let se = (var_n(b) + 0.25 * (var_n(b - 1) + var_n(b + 1))).sqrt();
            let clipped = bins[b - 1].clipped || bins[b].clipped || bins[b + 1].clipped;
            out.push(Step { iso: model.iso, pos, bin: b, mean: m, neighbours: 0.5 * (m0 + m1), se, clipped });
        }
    }
    out
}

/// Judges one pack: no bin steps beyond [`MAX_SE`], and at most [`MAX_FRACTION`] of the bins of
/// any ISO beyond 3 SE (a smooth pack has about 0.27 % there by chance, as the truth itself
/// would). Returns the failures.
fn judge(name: &str, pack: &ModelPack) -> Vec<String> {
    let mut failures = Vec::new();
    for m in &pack.isos {
        let st = steps(pack, m);
        let mut bad: Vec<&Step> = st.iter().filter(|j| j.z() > 3.0).collect();
        bad.sort_by(|a, b| b.z().total_cmp(&a.z()));
        for j in bad.iter().take(4) {
            eprintln!(
                "{name} ISO {} pos {} bin {}: {:+.2} DN against {:+.2} of its neighbours ({:.1} SE){}",
                j.iso,
                j.pos,
                j.bin,
                j.mean,
                j.neighbours,
                j.z(),
                if j.clipped { " clipped" } else { "" }
            );
        }
        eprintln!("{name} ISO {}: {} of {} bins step beyond 3 SE", m.iso, bad.len(), st.len());
        let limit = (MAX_FRACTION * st.len() as f64).ceil() as usize;
        if bad.len() > limit {
            failures.push(format!("{name} ISO {}: {} bins beyond 3 SE (at most {limit})", m.iso, bad.len()));
        }
        if let Some(j) = bad.first().filter(|j| j.z() > MAX_SE) {
            failures.push(format!("{name} ISO {} pos {} bin {}: {:.1} SE", m.iso, j.pos, j.bin, j.z()));
        }
    }
    failures
}

/// No bin may step further than this (SE): the estimator keeps a bin's own mean off the law
/// only beyond 4.5 SE of what bursts and samples explain (`MEAN_LIMIT_SE`).
const MAX_SE: f64 = 6.0;
/// … and at most this fraction of an ISO's bins beyond 3 SE.
const MAX_FRACTION: f64 = 0.01;

/// The demo's 10-bit phone. Before (one clip mode per position, bins' means as measured): the
/// upper range of ISO 800–3200 stepped by up to 28 DN between bins of 10–900 samples, and 4–46
/// bins per ISO stepped beyond 3 SE (up to 26 SE near black, the bins' burst offsets).
#[test]
fn demo_ramp_means_do_not_jump() {
    let s =
        setup(SensorModel::phone_10bit(), 384, 288, 1, vec![100, 200, 400, 800, 1600, 3200], 10, (-4..=4).collect());
    let (_, pack) = calibrate(&s, |_| ());
    let failures = judge("demo", &pack);
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Sensors of the random family (bit depths, CFA orders, gain laws, dual gain, heavy tails, row
/// noise), each calibrated from its own random session.
#[test]
fn random_family_ramps_do_not_jump() {
    let failures: Vec<String> = (0..SENSORS)
        .into_par_iter()
        .flat_map(|seed| {
            let sensor = random_sensor(seed);
            let spec = random_session(seed, &sensor.model);
            let sim = spec.simulator(&sensor.model, seed ^ 0x5A5A).expect("simulator");
            let plan = spec.plan(&sim).expect("plan");
            let (_, pack) = calibrate_lenient(&sim, &plan);
            eprintln!("sensor {seed}: {}", sensor.description);
            judge(&format!("sensor {seed}"), &pack)
        })
        .collect();
    assert!(failures.is_empty(), "{failures:#?}");
}

/// Random sensors in the ramp study.
const SENSORS: u64 = 6;
