//! A baseline's sampler draws at each clean level the law's noise at that level, not its bin's
//! average (method.md, *Synthesis*, "Baselines at their level").
//!
//! Known truth: a pack whose ISO 200 bins are an HG law `σ² = 0.29·x + 9.5` (the EMVA 1288 set
//! 001 CCD's near black: 9.5 DN² at black, 14 at 16 DN) on 16 DN bins, and one whose bins are a
//! Poisson–Gaussian with a visible lattice (4 DN/e⁻, read noise 1 DN). The baseline refitted on
//! those bins is the law the sampler must follow; each level's table is read exactly (its
//! probabilities, clamped to `[0, white]` as synthesis clamps) and a synthesized flat image is
//! measured. What the bins alone give (every sampler before this change): 1.24× the law's
//! variance at black and 0.85× at the top of the first bin for HG; a wrong implementation that
//! kept them fails `worst < 1.006` by 20 %.

use ndarray::Array2;
use noisecal_core::derive::baselines::{self, Baseline, BaselineKind, BaselineSource, NoiseParams};
use noisecal_core::model::pack::{IsoModel, ModelOrigin, ModelPack};
use noisecal_core::model::structure::Components;
use noisecal_core::resolve::{ModelKind, resolve_model};
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::{CleanAt, synthesize};
use noisecal_core::{CfaPattern, POSITIONS, SensorLayout};

const BLACK: f32 = 64.0;
const WHITE: u16 = 4095;

fn pack() -> ModelPack {
    ModelPack {
        layout: SensorLayout { width: 64, height: 64, cfa: CfaPattern::Rggb, black: [BLACK; 4], white: WHITE },
        make: "t".into(),
        model: "t".into(),
        bin_width: 16,
        reference_iso: 100,
        pooling: None,
        isos: Vec::new(),
        warnings: Vec::new(),
        structure: Vec::new(),
    }
}

/// A pack whose ISO 200 is calibrated-looking bins of the baseline `kind` with `params`, at gain
/// ratio `gain`.
fn pack_of(kind: BaselineKind, params: NoiseParams, gain: f64) -> ModelPack {
    let mut p = pack();
    let truth = Baseline { kind, iso: 200, params: [params; POSITIONS], source: BaselineSource::Fitted };
    let mut m: IsoModel = truth.to_model(&p);
    m.origin = ModelOrigin::Calibrated;
    m.gain_ratio = [gain; POSITIONS];
    for pm in &mut m.positions {
        for bin in &mut pm.bins {
            bin.source = noisecal_core::model::pack::BinSource::Measured;
            bin.measured = Some([bin.moments().0, bin.moments().1]);
            bin.samples = 100_000;
        }
    }
    p.insert(m);
    p
}

fn sampler(p: &ModelPack, kind: ModelKind, clean_at: CleanAt) -> IsoSampler {
    let r = resolve_model(p, 200, kind, false).expect("resolve");
    r.sampler(p, Components::PIXEL, clean_at, false).expect("sampler")
}

/// The distribution synthesis draws at a clean level: the table's, clamped to `[0, white]`,
/// as `noisy − level`.
fn drawn(s: &IsoSampler, pos: usize, level: u16) -> Vec<(i32, f64)> {
    // At the target brightness synthesis reads the target's level → table map.
    let t = match s.target_tables(pos) {
        Some((lut, _)) => &s.tables(pos)[lut[level as usize] as usize],
        None => s.table(pos, level),
    };
    (0..t.len() as i32)
        .map(|i| {
            let n = t.first() + i;
            ((level as i32 + n).clamp(0, WHITE as i32) - level as i32, t.prob(n))
        })
        .collect()
}

fn moments(d: &[(i32, f64)]) -> (f64, f64) {
    let m: f64 = d.iter().map(|&(n, p)| n as f64 * p).sum();
    (m, d.iter().map(|&(n, p)| (n as f64 - m).powi(2) * p).sum())
}

fn ratio(x: f64, y: f64) -> f64 {
    (x / y).max(y / x)
}

#[test]
fn hg_draws_its_law_at_every_level_not_its_bins_average() {
    let p = pack_of(BaselineKind::Hg, NoiseParams { a: 0.29, b: 9.5 }, 1.0);
    let binning = p.binning();
    let law = baselines::baseline(&p, 200, BaselineKind::Hg, false).expect("fit");
    let s = sampler(&p, ModelKind::Hg, CleanAt::Reference);
    let bins = &p.iso(200).expect("iso").positions[1].bins;
    let (mut worst, mut before): (f64, f64) = (1.0, 1.0);
    for level in 0..=WHITE {
        let want = law.level_pmf(&binning, 1, level as i32).moments().1;
        let (_, got) = moments(&drawn(&s, 1, level));
        worst = worst.max(ratio(got, want));
        if level >= BLACK as u16 {
            let old = bins[binning.bin(1, level as f32)].moments().1;
            before = before.max(ratio(old, want));
        }
    }
    // Runs of 0.5 % in variance drawn at their middle: within 0.25 %, plus the table's rounding.
    assert!(worst < 1.006, "worst level {worst}");
    assert!(before > 1.2, "the bins alone: {before}");
    // Near black, measured on a synthesized flat image at the bin's first and middle levels.
    for above in [0u16, 8, 16] {
        let level = BLACK as u16 + above;
        let clean = Array2::from_elem((256, 256), level);
        let out = synthesize(&s, clean.view(), 7);
        let n = out.len() as f64;
        let mean = out.iter().map(|&v| v as f64).sum::<f64>() / n;
        let var = out.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / n;
        let want = law.variance(&binning, 1, level as f64);
        // SE of a variance over 65 536 pixels: 0.55 %; the bins' averages are 16–24 % off here.
        assert!(
            ratio(var, want) < 1.025 && (mean - level as f64).abs() < 0.05,
            "{above} DN: {var} vs {want}, mean {mean}"
        );
    }
}

#[test]
fn at_the_target_brightness_a_level_draws_the_law_at_its_reference_level() {
    let g = 1.25;
    let p = pack_of(BaselineKind::Hg, NoiseParams { a: 0.29, b: 9.5 }, g);
    let law = baselines::baseline(&p, 200, BaselineKind::Hg, false).expect("fit");
    let s = sampler(&p, ModelKind::Hg, CleanAt::Target);
    let mut worst: f64 = 1.0;
    for c in BLACK as u16..2000 {
        let x = (c as f64 - BLACK as f64) / g;
        let want = law.params[2].variance(x);
        let (m, got) = moments(&drawn(&s, 2, c));
        assert!(m.abs() < 1e-3, "zero mean at {c}: {m}");
        worst = worst.max(ratio(got, want));
    }
    assert!(worst < 1.006, "{worst}");
}

#[test]
fn pg_levels_keep_their_own_lattice() {
    // 4 DN per electron and 1 DN of read noise: the lattice's phase moves with the level, so
    // each level has its table; each must be that level's PMF (total variation), not a
    // neighbour's (two levels 2 DN apart are half a period out of phase).
    let p = pack_of(BaselineKind::Pg, NoiseParams { a: 4.0, b: 1.0 }, 1.0);
    let binning = p.binning();
    let law = baselines::baseline(&p, 200, BaselineKind::Pg, false).expect("fit");
    let s = sampler(&p, ModelKind::Pg, CleanAt::Reference);
    let tv = |d: &[(i32, f64)], level: i32| {
        let pmf = law.level_pmf(&binning, 0, level);
        let lo = d.iter().map(|x| x.0).min().unwrap_or(0).min(pmf.first);
        let hi = d.iter().map(|x| x.0).max().unwrap_or(0).max(pmf.last());
        (lo..=hi).map(|n| (d.iter().filter(|x| x.0 == n).map(|x| x.1).sum::<f64>() - pmf.at(n)).abs()).sum::<f64>()
            / 2.0
    };
    let mut worst: f64 = 0.0;
    for level in (BLACK as i32..BLACK as i32 + 200).chain([2000, 4000, 4090]) {
        worst = worst.max(tv(&drawn(&s, 0, level as u16), level));
    }
    assert!(worst < 1e-3, "{worst}");
    // Against the table of a level half a period away the same measure is large (0.32: the read
    // noise blurs the lattice), so a map that gave levels a neighbour's table fails the bound.
    let off = tv(&drawn(&s, 0, 102), 100);
    assert!(off > 0.2, "{off}");
}

#[test]
fn pg_without_a_visible_lattice_shares_tables_and_still_follows_its_law() {
    // 4 DN per electron under 3 DN of read noise: the lattice's modulation is exp(−2π²·9/16) ≈
    // 2·10⁻⁵, so levels share tables as HG's do (one per level would be 4 096 per position).
    let p = pack_of(BaselineKind::Pg, NoiseParams { a: 4.0, b: 9.0 }, 1.0);
    let binning = p.binning();
    let law = baselines::baseline(&p, 200, BaselineKind::Pg, false).expect("fit");
    let s = sampler(&p, ModelKind::Pg, CleanAt::Reference);
    let tables = s.tables(0).len() - binning.bins(0);
    assert!(tables < 1500, "{tables} level tables");
    let mut worst: f64 = 1.0;
    for level in BLACK as u16..WHITE - 300 {
        let want = law.level_pmf(&binning, 0, level as i32).moments().1;
        worst = worst.max(ratio(moments(&drawn(&s, 0, level)).1, want));
    }
    assert!(worst < 1.006, "{worst}");
}
