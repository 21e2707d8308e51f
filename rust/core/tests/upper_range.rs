//! The upper range is as smooth as the truth (issue 21, item 6): the mean of the noise a pack
//! adds moves from level to level only as fast as its calibration samples can show.

use noisecal_core::model::pack::ModelPack;
use noisecal_core::model::structure::Components;
use noisecal_core::synth::sampler::IsoSampler;

/// The exact mean and variance of `finish(l + n) − l` under a sampler's table, per level.
fn level_moments(s: &IsoSampler, pos: usize, l: i32) -> (f64, f64) {
    let t = s.table(pos, l as u16);
    let (mut m, mut m2) = (0.0, 0.0);
    for (i, _) in t.cdf().iter().enumerate() {
        let n = t.first() + i as i32;
        let p = t.prob(n);
        if p == 0.0 {
            continue;
        }
        let o = 0.5 * (s.finish(pos, l + n, false) as f64 + s.finish(pos, l + n, true) as f64) - l as f64;
        m += p * o;
        m2 += p * o * o;
    }
    (m, m2 - m * m)
}

/// Diagnostic: `NOISECAL_PACK=demo.pack cargo test --test upper_range -- --ignored --nocapture`.
#[test]
#[ignore]
fn print_pack_bins() {
    let Ok(path) = std::env::var("NOISECAL_PACK") else { return };
    let pack = ModelPack::from_bytes(&std::fs::read(path).unwrap()).unwrap();
    let binning = pack.binning();
    let only: Option<u32> = std::env::var("ISO").ok().and_then(|s| s.parse().ok());
    for m in pack.isos.iter().filter(|m| m.is_calibrated()) {
        if only.is_some_and(|i| i != m.iso) {
            continue;
        }
        let s = IsoSampler::with_components(&pack, m, Components::PIXEL);
        for pos in 0..4 {
            let est = m.positions[pos].estimate.as_ref();
            println!(
                "ISO {} pos {pos} range {:?} clipped {} pooling {:?} clip_mode {:?} clip_scores {:?} heldout {:?}",
                m.iso,
                m.range[pos],
                est.map_or(0, |e| e.clipped.len()),
                est.map(|e| e.pooling),
                est.map(|e| e.clip_mode),
                est.and_then(|e| e.clip_scores),
                est.map(|e| e.heldout_samples)
            );
            let bw = binning.bin_width as i32;
            let black = binning.black[pos] as i32;
            for (b, bin) in m.positions[pos].bins.iter().enumerate() {
                let (pm, pv) = bin.moments();
                let l = black + b as i32 * bw;
                let (em, ev) = level_moments(&s, pos, l.min(pack.layout.white as i32));
                let law = est.and_then(|e| e.law.get(b)).copied().unwrap_or([0.0, 0.0]);
                println!(
                    "  b {b:3} l {l:4} n {:8} {:?} clip {} pmf {pm:8.2} {pv:9.1} meas {:?} law {:8.2} {:9.1} eff {em:8.2} {ev:9.1}",
                    bin.samples,
                    bin.source,
                    bin.clipped as u8,
                    bin.measured.map(|[a, b]| (format!("{a:.2}"), format!("{b:.1}"))),
                    law[0],
                    law[1]
                );
            }
        }
    }
}
