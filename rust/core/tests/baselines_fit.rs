//! Baselines recover the parameters they were fitted from, synthesize what they claim, and
//! interpolate the usual parametric way.

use noisecal_core::derive::baselines::{self, Baseline, BaselineKind, BaselineSource, NoiseParams};
use noisecal_core::error::Remedy;
use noisecal_core::model::pack::{IsoModel, ModelOrigin, ModelPack};
use noisecal_core::synth::sampler::BinTable;
use noisecal_core::{CfaPattern, POSITIONS, SensorLayout};
use rand::SeedableRng;

fn pack() -> ModelPack {
    ModelPack {
        layout: SensorLayout { width: 64, height: 64, cfa: CfaPattern::Rggb, black: [64.0; 4], white: 1023 },
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

/// A calibrated-looking model whose PMFs are exactly a baseline's (measured, 100k samples each).
fn model_from(pack: &ModelPack, b: &Baseline) -> IsoModel {
    let mut m = b.to_model(pack);
    m.origin = ModelOrigin::Calibrated;
    for pm in &mut m.positions {
        for bin in &mut pm.bins {
            bin.source = noisecal_core::model::pack::BinSource::Measured;
            bin.measured = Some([bin.moments().0, bin.moments().1]);
            bin.samples = 100_000;
        }
    }
    m
}

fn params(a: f64, b: f64) -> [NoiseParams; POSITIONS] {
    std::array::from_fn(|p| NoiseParams { a: a * (1.0 + 0.1 * p as f64), b: b * (1.0 + 0.2 * p as f64) })
}

fn close(x: f64, want: f64, rel: f64) -> bool {
    (x / want - 1.0).abs() < rel
}

#[test]
fn hg_and_pg_recover_their_parameters() {
    let p = pack();
    for (kind, truth) in [(BaselineKind::Hg, params(0.8, 3.0)), (BaselineKind::Pg, params(2.0, 9.0 + 1.0 / 12.0))] {
        let src = Baseline { kind, iso: 400, params: truth, source: BaselineSource::Fitted };
        let m = model_from(&p, &src);
        let fitted = baselines::fit(&p, &m, kind).expect("fit");
        for pos in 0..POSITIONS {
            let (f, t) = (fitted.params[pos], truth[pos]);
            assert!(close(f.a, t.a, 0.01) && close(f.b, t.b, 0.03), "{kind} pos {pos}: {f:?} vs {t:?}");
        }
    }
}

#[test]
fn pg_is_skewed_and_clipped_hg_is_not_skewed() {
    let p = pack();
    let binning = p.binning();
    let skew = |pmf: &noisecal_core::model::pmf::Pmf| {
        let (m, v) = pmf.moments();
        pmf.p.iter().enumerate().map(|(i, &q)| q * ((pmf.first + i as i32) as f64 - m).powi(3)).sum::<f64>()
            / v.powf(1.5)
    };
    // Gain 4 DN/e⁻, small read noise, 2 e⁻ at level black + 8: Poisson skew 1/√2.
    let pg = Baseline { kind: BaselineKind::Pg, iso: 1600, params: params(4.0, 1.0), source: BaselineSource::Fitted };
    let pmf = pg.level_pmf(&binning, 0, 72);
    assert!(skew(&pmf) > 0.5, "PG skew {}", skew(&pmf));
    let hg = Baseline { kind: BaselineKind::Hg, ..pg.clone() };
    assert!(skew(&hg.level_pmf(&binning, 0, 72)).abs() < 0.02);
    // Near white, noise piles up at white − level.
    let top = pg.level_pmf(&binning, 0, 1015);
    assert_eq!(top.last(), 8);
    assert!(top.at(8) > 0.2, "clipped mass {}", top.at(8));
}

#[test]
fn noise_profile_in_dn_and_synthesis_matches_variance() {
    let p = pack();
    let binning = p.binning();
    let (s, o) = (2.0e-3, 1.5e-5);
    let mut m = model_from(
        &p,
        &Baseline { kind: BaselineKind::Hg, iso: 800, params: params(1.0, 1.0), source: BaselineSource::Fitted },
    );
    m.noise_profile = Some(noisecal_core::model::NoiseProfile([[s, o]; POSITIONS]));
    let np = baselines::fit(&p, &m, BaselineKind::NoiseProfile).expect("profile");
    assert_eq!(np.source, BaselineSource::CameraProfile);
    let range: f64 = 1023.0 - 64.0;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    for level in [64i32, 300, 700] {
        let x = (level as f64 - 64.0) / range;
        let want = (s * x + o) * range * range;
        let (_, v) = np.level_pmf(&binning, 1, level).moments();
        assert!(close(v, want, 0.01), "level {level}: {v} vs {want}");
        // Through the sampler, as synth would draw it.
        let bin = binning.bin(1, level as f32);
        let model = np.to_model(&p);
        let t = BinTable::new(&model.positions[1].bins[bin]);
        let n = 200_000;
        let draws: Vec<f64> = (0..n).map(|_| t.sample(&mut rng) as f64).collect();
        let mean = draws.iter().sum::<f64>() / n as f64;
        let var = draws.iter().map(|d| (d - mean).powi(2)).sum::<f64>() / n as f64;
        let (_, bin_var) = model.positions[1].bins[bin].moments();
        let (bin_mean, _) = model.positions[1].bins[bin].moments();
        assert!(
            (mean - bin_mean).abs() < 4.0 * (bin_var / n as f64).sqrt()
                && bin_mean.abs() < 0.05
                && close(var, bin_var, 0.02),
            "level {level}: {mean} {var} vs {bin_var}"
        );
    }
    // No profile: a clear error that names the fix.
    m.noise_profile = None;
    let e = baselines::fit(&p, &m, BaselineKind::NoiseProfile).expect_err("none");
    assert_eq!(e.remedy(), Some(Remedy::ParametricModel));
    assert!(e.to_string().contains("use the hg or pg model"), "{e}");
}

#[test]
fn parametric_interpolation_recovers_a_linear_in_iso_and_b_quadratic_in_a() {
    let mut p = pack();
    let law = |iso: f64| {
        let a = 0.002 * iso;
        NoiseParams { a, b: 0.6 + 2.5 * a * a }
    };
    for iso in [100u32, 200, 800, 1600] {
        let b = Baseline {
            kind: BaselineKind::Hg,
            iso,
            params: [law(iso as f64); POSITIONS],
            source: BaselineSource::Fitted,
        };
        let m = model_from(&p, &b);
        p.insert(m);
    }
    let got = baselines::interpolate(&p, 400, BaselineKind::Hg, false).expect("inside");
    let want = law(400.0);
    for pos in 0..POSITIONS {
        assert!(
            close(got.params[pos].a, want.a, 0.02) && close(got.params[pos].b, want.b, 0.04),
            "{:?} vs {want:?}",
            got.params[pos]
        );
    }
    assert!(matches!(&got.source, BaselineSource::Interpolated { from, extrapolated: false } if from.len() == 4));
    // As a model: same layout as the pack, flagged interpolated; out of range refused.
    let m = baselines::baseline_model(&p, 400, BaselineKind::Pg, false).expect("pg model");
    assert!(matches!(m.origin, ModelOrigin::Interpolated { .. }));
    assert_eq!(m.positions.len(), POSITIONS);
    let mut q = p.clone();
    q.insert(m);
    q.check().expect("a valid pack");
    let e = baselines::baseline_model(&p, 3200, BaselineKind::Hg, false).unwrap_err();
    assert_eq!(e.remedy(), Some(Remedy::Extrapolate));
    assert!(e.to_string().contains("allow extrapolation") && !e.to_string().contains("--"), "{e}");
    // With extrapolation allowed the baseline is extrapolated, not refused
    // with advice to pass the flag that was given.
    let m = baselines::baseline_model(&p, 3200, BaselineKind::Hg, true).expect("extrapolated hg");
    assert!(matches!(m.origin, ModelOrigin::Extrapolated { .. }), "{:?}", m.origin);
    assert!(baselines::baseline_model(&p, 1_000_000, BaselineKind::Hg, true).is_err(), "far beyond: bounded");
}
