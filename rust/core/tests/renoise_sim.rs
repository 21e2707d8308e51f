//! Noise on noise on a simulated sensor whose truth is known exactly.
//!
//! The "true" noise PMFs are built analytically per (ISO, bin): a Poisson–Gaussian sensor with a
//! heavy-tailed read component, `n = round(g·(K − e) + R)`, `K ~ Poisson(e)`, `e` the electrons
//! of the bin's centre level at gain `g` DN/e⁻, `R` a scale mixture of two Gaussians (5 % of the
//! reads 4× wider: excess kurtosis ≈ 10), clipped at 0 and white. "Real" captures at any ISO are
//! drawn from these PMFs on a clean image of flat patches; fidelity is the JSD (natural log) of
//! noise histograms on flat pixels (method.md, "Measuring fidelity").

use std::collections::BTreeMap;

use ndarray::Array2;
use noisecal_core::model::pack::{BinModel, IsoModel, ModelOrigin, ModelPack, PositionModel};
use noisecal_core::renoise::bridge::{
    BridgeError, BridgeOptions, Deconvolution, FlagKind, build_bridge, build_bridge_with,
};
use noisecal_core::renoise::denoise::estimate_clean;
use noisecal_core::renoise::{Method, RenoiseError, Renoiser, renoise};
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::synthesize;
use noisecal_core::{CfaPattern, POSITIONS, SensorLayout};

const BLACK: f32 = 64.0;
const WHITE: u16 = 1023;
const BIN_WIDTH: u16 = 4;
/// Pre-gain read noise (e⁻) and post-gain read noise (DN).
const READ_PRE_E: f64 = 2.0;
const READ_POST_DN: f64 = 1.5;
/// Heavy tail: this fraction of reads is `TAIL_SCALE` times wider.
const TAIL_W: f64 = 0.05;
const TAIL_SCALE: f64 = 4.0;

/// DN per electron at an ISO (proportional to ISO: 0.25 at ISO 800).
fn gain(iso: u32) -> f64 {
    0.25 * iso as f64 / 800.0
}

/// erfc with fractional error < 1.2e-7 (Numerical Recipes' Chebyshev fit).
fn erfc(x: f64) -> f64 {
    let z = x.abs();
    let t = 1.0 / (1.0 + 0.5 * z);
    let r = t
        * (-z * z - 1.26551223
            + t * (1.00002368
                + t * (0.37409196
                    + t * (0.09678418
                        + t * (-0.18628806
                            + t * (0.27886807
                                + t * (-1.13520398 + t * (1.48851587 + t * (-0.82215223 + t * 0.17087277)))))))))
            .exp();
    if x >= 0.0 { r } else { 2.0 - r }
}

fn phi(x: f64, sd: f64) -> f64 {
    0.5 * erfc(-x / (sd * std::f64::consts::SQRT_2))
}

/// The true noise PMF of a clean level at an ISO, clipped to [0, white].
fn true_pmf(iso: u32, level: f64) -> (i32, Vec<f64>) {
    let g = gain(iso);
    let e = ((level - BLACK as f64) / g).max(0.0);
    let s1 = (g * g * READ_PRE_E * READ_PRE_E + READ_POST_DN * READ_POST_DN).sqrt();
    let s2 = TAIL_SCALE * s1;
    // Cell probability of the read noise, C(x) = P(R ∈ [x − ½, x + ½]), tabulated at 1/64 DN.
    let span = 9.0 * s2 + 1.0;
    let step = 1.0 / 64.0;
    let nt = (2.0 * span / step) as usize + 2;
    let cell: Vec<f64> = (0..nt)
        .map(|i| {
            let x = -span + i as f64 * step;
            let c = |sd: f64| phi(x + 0.5, sd) - phi(x - 0.5, sd);
            (1.0 - TAIL_W) * c(s1) + TAIL_W * c(s2)
        })
        .collect();
    let cell_at = |x: f64| -> f64 {
        let f = (x + span) / step;
        if f < 0.0 || f >= (nt - 1) as f64 {
            return 0.0;
        }
        let i = f as usize;
        let t = f - i as f64;
        cell[i] * (1.0 - t) + cell[i + 1] * t
    };
    // Poisson weights, built outward from the mode (no lgamma needed).
    let sd_k = e.sqrt();
    let k_lo = (e - 9.0 * sd_k - 10.0).floor().max(0.0) as i64;
    let k_hi = (e + 9.0 * sd_k + 10.0).ceil() as i64;
    let mode = e.floor() as i64;
    let mut pk = vec![0.0f64; (k_hi - k_lo + 1) as usize];
    pk[(mode - k_lo) as usize] = 1.0;
    for k in mode + 1..=k_hi {
        pk[(k - k_lo) as usize] = pk[(k - 1 - k_lo) as usize] * e / k as f64;
    }
    for k in (k_lo..mode).rev() {
        pk[(k - k_lo) as usize] = pk[(k + 1 - k_lo) as usize] * (k + 1) as f64 / e.max(1e-300);
    }
    let total: f64 = pk.iter().sum();
    pk.iter_mut().for_each(|p| *p /= total);

    let shot_sd = g * sd_k;
    let n_lo = (-(9.0 * shot_sd + span + 2.0)).floor() as i32;
    let n_hi = (9.0 * shot_sd + span + 2.0).ceil() as i32;
    let mut p = vec![0.0f64; (n_hi - n_lo + 1) as usize];
    for (ki, &w) in pk.iter().enumerate() {
        if w < 1e-13 {
            continue;
        }
        let s = g * ((k_lo + ki as i64) as f64 - e);
        let a = (s - span).floor() as i32 - 1;
        let b = (s + span).ceil() as i32 + 1;
        for n in a.max(n_lo)..=b.min(n_hi) {
            p[(n - n_lo) as usize] += w * cell_at(n as f64 - s);
        }
    }
    // Clip: values below −level pile at 0, above white − level at white.
    let lo = -(level.round() as i32);
    let hi = WHITE as i32 - level.round() as i32;
    let first = n_lo.max(lo);
    let last = n_hi.min(hi);
    let mut out = vec![0.0; (last - first + 1) as usize];
    for (i, &x) in p.iter().enumerate() {
        let n = (n_lo + i as i32).clamp(first, last);
        out[(n - first) as usize] += x;
    }
    (first, out)
}

fn layout() -> SensorLayout {
    SensorLayout { width: 512, height: 512, cfa: CfaPattern::Rggb, black: [BLACK; POSITIONS], white: WHITE }
}

/// One ISO's model: the true PMF at each bin's centre level, the same for all four positions.
fn iso_model(iso: u32, origin: ModelOrigin) -> IsoModel {
    let l = layout();
    let binning = noisecal_core::Binning::new(&l, BIN_WIDTH);
    let bins: Vec<BinModel> = (0..binning.bins(0))
        .map(|b| {
            let (first, p) = true_pmf(iso, binning.center(0, b) as f64);
            let pmf = noisecal_core::model::pmf::Pmf::from_weights(first, p).expect("non-empty PMF");
            BinModel::from_pmf(&pmf, 1_000_000, false)
        })
        .collect();
    IsoModel {
        iso,
        origin,
        frames: 0,
        drift_frames: 0,
        gain_ratio: [1.0; POSITIONS],
        noise_profile: None,
        range: [[0, WHITE]; POSITIONS],
        lattice: [None; POSITIONS],
        positions: vec![PositionModel::new(bins); POSITIONS],
    }
}

fn pack(isos: &[u32]) -> ModelPack {
    ModelPack {
        layout: layout(),
        make: "sim".into(),
        model: "analytic".into(),
        bin_width: BIN_WIDTH,
        reference_iso: 100,
        pooling: None,
        isos: isos.iter().map(|&i| iso_model(i, ModelOrigin::Calibrated)).collect(),
        warnings: Vec::new(),
        structure: Vec::new(),
    }
}

/// Shared fixture: the pack at ISO 800, 1600, 3200 (building it takes a moment).
fn fixture() -> &'static ModelPack {
    static P: std::sync::OnceLock<ModelPack> = std::sync::OnceLock::new();
    P.get_or_init(|| pack(&[800, 1600, 3200]))
}

/// Patch levels: bin centres (66 + 4k), dark to bright.
const LEVELS: [u16; 16] = [70, 98, 130, 166, 210, 250, 298, 350, 402, 450, 502, 558, 610, 662, 706, 750];
const PATCH: usize = 128;
const MARGIN: usize = 6;

/// A 512×512 clean image of 4×4 flat patches, and the patch index of each flat pixel (interior
/// `MARGIN` px away from patch edges), else `usize::MAX`.
fn clean_image() -> (Array2<u16>, Array2<usize>) {
    let n = 4 * PATCH;
    let mut clean = Array2::<u16>::zeros((n, n));
    let mut group = Array2::<usize>::from_elem((n, n), usize::MAX);
    for ((y, x), v) in clean.indexed_iter_mut() {
        let (py, px) = (y / PATCH, x / PATCH);
        let k = py * 4 + px;
        *v = LEVELS[k];
        let (iy, ix) = (y % PATCH, x % PATCH);
        if (MARGIN..PATCH - MARGIN).contains(&iy) && (MARGIN..PATCH - MARGIN).contains(&ix) {
            group[[y, x]] = k;
        }
    }
    (clean, group)
}

type Hist = BTreeMap<i32, u64>;

/// Noise histograms on flat pixels: pooled, and per patch.
fn noise_hists(img: &Array2<u16>, clean: &Array2<u16>, group: &Array2<usize>) -> (Hist, Vec<Hist>) {
    let mut pooled = Hist::new();
    let mut per = vec![Hist::new(); LEVELS.len()];
    for ((yx, &g), (&v, &c)) in group.indexed_iter().zip(img.iter().zip(clean.iter())) {
        let _ = yx;
        if g == usize::MAX {
            continue;
        }
        let n = v as i32 - c as i32;
        *pooled.entry(n).or_default() += 1;
        *per[g].entry(n).or_default() += 1;
    }
    (pooled, per)
}

/// JSD with natural log between two integer histograms.
fn jsd(a: &Hist, b: &Hist) -> f64 {
    let ta: u64 = a.values().sum();
    let tb: u64 = b.values().sum();
    let mut keys: Vec<i32> = a.keys().chain(b.keys()).copied().collect();
    keys.sort_unstable();
    keys.dedup();
    let mut s = 0.0;
    for k in keys {
        let p = *a.get(&k).unwrap_or(&0) as f64 / ta as f64;
        let q = *b.get(&k).unwrap_or(&0) as f64 / tb as f64;
        let m = 0.5 * (p + q);
        if p > 0.0 {
            s += 0.5 * p * (p / m).ln();
        }
        if q > 0.0 {
            s += 0.5 * q * (q / m).ln();
        }
    }
    s
}

/// Marginal (pooled) and conditional (per patch, weighted by count) JSD.
fn scores(img: &Array2<u16>, real: &Array2<u16>, clean: &Array2<u16>, group: &Array2<usize>) -> (f64, f64) {
    let (pa, ga) = noise_hists(img, clean, group);
    let (pb, gb) = noise_hists(real, clean, group);
    let total: u64 = gb.iter().map(|h| h.values().sum::<u64>()).sum();
    let cond = ga.iter().zip(&gb).map(|(a, b)| jsd(a, b) * b.values().sum::<u64>() as f64 / total as f64).sum();
    (jsd(&pa, &pb), cond)
}

#[test]
fn analytic_model_is_poisson_gaussian() {
    // The fixture itself: variance = g·(l − black) + g²σ_pre² (with tail) + σ_post² (with tail).
    let p = fixture();
    let binning = p.binning();
    for iso in [800, 1600, 3200] {
        let m = p.require_iso(iso).expect("ISO in the fixture");
        for b in [10, 60, 120] {
            let l = binning.center(0, b) as f64;
            let g = gain(iso);
            let read = g * g * READ_PRE_E * READ_PRE_E + READ_POST_DN * READ_POST_DN;
            let want = g * (l - BLACK as f64) + read * (1.0 - TAIL_W + TAIL_W * TAIL_SCALE * TAIL_SCALE) + 1.0 / 12.0;
            let (mean, var) = m.positions[0].bins[b].moments();
            assert!(mean.abs() < 0.02, "ISO {iso} bin {b}: mean {mean}");
            assert!((var - want).abs() / want < 0.02, "ISO {iso} bin {b}: var {var} vs {want}");
        }
    }
}

#[test]
fn bridge_matches_target_moments_with_small_residual() {
    let p = fixture();
    let binning = p.binning();
    let a = p.require_iso(1600).expect("ISO in the fixture");
    let b = p.require_iso(3200).expect("ISO in the fixture");
    let t = std::time::Instant::now();
    let br = build_bridge(a, b, &binning).expect("succeeds");
    eprintln!(
        "bridge 1600→3200: built in {:.2?}, mean TV {:.5}, max TV {:.5}, mean JSD {:.2e}, flags {}",
        t.elapsed(),
        br.mean_residual(),
        br.max_residual(),
        br.mean_jsd(),
        br.flags.len()
    );
    assert_eq!((br.source_iso, br.target_iso), (1600, 3200));
    for pos in 0..POSITIONS {
        for bin in (0..binning.bins(pos)).step_by(7) {
            let q = br.q(pos, bin);
            assert!(q.p.iter().all(|&x| x >= 0.0) && (q.p.iter().sum::<f64>() - 1.0).abs() < 1e-9);
            let (mq, vq) = q.moments();
            let (ma, va) = a.positions[pos].bins[bin].moments();
            let (mb, vb) = b.positions[pos].bins[bin].moments();
            let level = binning.center(pos, bin);
            // Away from the few-electron bottom (where p_b is not exactly p_a ∗ q for any q ≥ 0)
            // and from the clipped top (where clipped variances do not add), q must carry the
            // variance difference (a naive bridge q = p_b would carry all of vb) and the mean
            // shift.
            if level >= 100.0 && level as f64 + 6.0 * vb.sqrt() < WHITE as f64 {
                assert!((vq - (vb - va)).abs() / (vb - va) < 0.05, "bin {bin}: var {vq} vs {}", vb - va);
                assert!((mq - (mb - ma)).abs() < 0.1, "bin {bin}: mean {mq} vs {}", mb - ma);
            }
            // Everywhere, clipped top included (the fit clamps like the renoise does), the
            // convolution reproduces the target closely.
            assert!(br.residual(pos, bin) < 0.01, "bin {bin}: tv {}", br.residual(pos, bin));
        }
    }
    // No bin of this well-behaved pair is flagged.
    assert!(br.flags.is_empty() && br.warnings.is_empty(), "{:?}", br.warnings);
}

#[test]
fn default_solver_has_the_lower_residual() {
    // The measurement behind the default solver: same pairs, same iteration budget.
    let p = fixture();
    let binning = p.binning();
    let mut res = Vec::new();
    for solver in [Deconvolution::RichardsonLucy, Deconvolution::ProjectedGradient] {
        let opts = BridgeOptions { solver, ..BridgeOptions::default() };
        let is_default = solver == BridgeOptions::default().solver;
        let mut tv = 0.0;
        let mut js = 0.0;
        for (a, b) in [(800, 1600), (1600, 3200), (800, 3200)] {
            let t = std::time::Instant::now();
            let br = build_bridge_with(
                p.require_iso(a).expect("ISO in the fixture"),
                p.require_iso(b).expect("ISO in the fixture"),
                &binning,
                &opts,
            )
            .expect("succeeds");
            eprintln!(
                "{solver:?} {a}→{b}: {:.2?}, mean TV {:.5}, max TV {:.5}, mean JSD {:.3e}",
                t.elapsed(),
                br.mean_residual(),
                br.max_residual(),
                br.mean_jsd()
            );
            tv += br.mean_residual();
            js += br.mean_jsd();
        }
        res.push((is_default, tv, js));
    }
    let (def, other): (Vec<&(bool, f64, f64)>, Vec<_>) = res.iter().partition(|r| r.0);
    assert!(def[0].1 <= other[0].1 && def[0].2 <= other[0].2, "default {def:?} vs other {other:?}");
}

#[test]
fn refused_pairs_name_both_isos() {
    let p = fixture();
    let binning = p.binning();
    let lo = p.require_iso(800).expect("ISO in the fixture");
    let hi = p.require_iso(1600).expect("ISO in the fixture");
    for (a, b) in [(hi, lo), (hi, hi)] {
        let e = build_bridge(a, b, &binning).expect_err("must be refused");
        assert_eq!(e, BridgeError::NotHigher { from_iso: a.iso, to_iso: b.iso });
        let msg = e.to_string();
        assert!(msg.contains(&format!("ISO {}", a.iso)) && msg.contains(&format!("ISO {}", b.iso)), "{msg}");
        assert!(msg.contains("higher"), "{msg}");
    }
    let img = Array2::<u16>::from_elem((8, 8), 300);
    for m in Method::ALL {
        let e = renoise(p, 1600, 800, img.view(), None, m, 1).expect_err("must be refused");
        assert!(matches!(e, RenoiseError::Bridge(BridgeError::NotHigher { from_iso: 1600, to_iso: 800 })), "{e}");
    }
    // An ISO outside the pack's range is a clear model error naming the range.
    let e = renoise(p, 1600, 6400, img.view(), None, Method::Bridge, 1).expect_err("must be refused");
    assert!(e.to_string().contains("6400") && e.to_string().contains("800–3200"), "{e}");
}

#[test]
fn narrower_target_bins_are_flagged_by_pair_and_bin() {
    // A target that is narrower than the source in bins 100..=104 of position 2.
    let p = fixture();
    let binning = p.binning();
    let a = p.require_iso(1600).expect("ISO in the fixture").clone();
    let mut b = p.require_iso(3200).expect("ISO in the fixture").clone();
    for bin in 100..=104 {
        let (first, w) = true_pmf(800, binning.center(2, bin) as f64);
        let pmf = noisecal_core::model::pmf::Pmf::from_weights(first, w).expect("non-empty PMF");
        b.positions[2].bins[bin] = BinModel::from_pmf(&pmf, 1_000_000, false);
    }
    let br = build_bridge(&a, &b, &binning).expect("succeeds");
    let narrow: Vec<(usize, usize)> =
        br.flags.iter().filter(|f| f.kind == FlagKind::NotWider).map(|f| (f.position, f.bin)).collect();
    assert_eq!(narrow, (100..=104).map(|b| (2, b)).collect::<Vec<_>>());
    let w = br.warnings.iter().find(|w| w.contains("not wider")).expect("a warning for the narrow bins");
    assert!(w.contains("ISO 1600 → 3200") && w.contains("position 2") && w.contains("bins 100–104"), "{w}");
}

#[test]
fn bridges_between_interpolated_isos() {
    // Models marked as interpolated (here: the analytic truth at ISO 1200 and 2400) bridge alike.
    let p = fixture();
    let binning = p.binning();
    let a = iso_model(1200, ModelOrigin::Interpolated { from: vec![800, 1600] });
    let b = iso_model(2400, ModelOrigin::Interpolated { from: vec![1600, 3200] });
    let br = build_bridge(&a, &b, &binning).expect("succeeds");
    assert_eq!((br.source_iso, br.target_iso), (1200, 2400));
    assert!(br.mean_residual() < 0.005, "mean TV {}", br.mean_residual());
}

#[test]
fn bridge_lands_near_direct_synthesis_and_far_below_naive() {
    let p = fixture();
    let (clean, group) = clean_image();
    let s1600 = IsoSampler::new(p, p.require_iso(1600).expect("ISO in the fixture"));
    let s3200 = IsoSampler::new(p, p.require_iso(3200).expect("ISO in the fixture"));
    // "Real" captures: the source at 1600, the target at 3200, and a second real 3200 set for
    // the finite-sample floor; "direct" = synthesizing 3200 on the true clean image.
    let src = synthesize(&s1600, clean.view(), 11);
    let real = synthesize(&s3200, clean.view(), 22);
    let real2 = synthesize(&s3200, clean.view(), 33);
    let direct = synthesize(&s3200, clean.view(), 44);
    let floor = scores(&real2, &real, &clean, &group);
    let direct_s = scores(&direct, &real, &clean, &group);
    eprintln!("floor    marginal {:.5} conditional {:.5}", floor.0, floor.1);
    eprintln!("direct   marginal {:.5} conditional {:.5}", direct_s.0, direct_s.1);

    let mut got = BTreeMap::new();
    for m in Method::ALL {
        let r = Renoiser::new(
            p,
            p.require_iso(1600).expect("ISO in the fixture"),
            p.require_iso(3200).expect("ISO in the fixture"),
            m,
        )
        .expect("succeeds");
        let out = r.apply(src.view(), None, 5).expect("succeeds");
        let s = scores(&out.image, &real, &clean, &group);
        eprintln!("{:<8} marginal {:.5} conditional {:.5}", m.name(), s.0, s.1);
        got.insert(m.name(), s);
    }
    // With the true clean image as the estimate too.
    let clean_f = clean.mapv(|v| v as f32);
    for m in [Method::Bridge, Method::Quantile, Method::Denoised] {
        let out = renoise(p, 1600, 3200, src.view(), Some(clean_f.view()), m, 5).expect("succeeds");
        let s = scores(&out.image, &real, &clean, &group);
        eprintln!("{:<8} (true Î) marginal {:.5} conditional {:.5}", m.name(), s.0, s.1);
        assert!(s.1 < direct_s.1 + 0.004, "{m} with the true clean image: {s:?} vs direct {direct_s:?}");
    }

    let bridge = got["bridge"];
    let naive = got["naive"];
    // Bridge within a small margin of direct synthesis, marginal and conditional.
    assert!(bridge.0 < direct_s.0 + 0.002, "bridge {bridge:?} vs direct {direct_s:?}");
    assert!(bridge.1 < direct_s.1 + 0.004, "bridge {bridge:?} vs direct {direct_s:?}");
    // The paper's ordering: naive ≫ bridge.
    assert!(naive.0 > 5.0 * bridge.0 && naive.1 > 3.0 * bridge.1, "naive {naive:?} vs bridge {bridge:?}");
    assert!(naive.0 > 0.005, "naive should overshoot: {naive:?}");
    // Quantile mapping with the built-in estimate is also far better than naive.
    assert!(got["quantile"].1 < naive.1 / 2.0, "{got:?}");
}

#[test]
fn reproducible_with_a_seed_whatever_the_thread_count() {
    let p = fixture();
    let (clean, _) = clean_image();
    let clean = clean.slice(ndarray::s![..200, ..300]).to_owned();
    let s1600 = IsoSampler::new(p, p.require_iso(1600).expect("ISO in the fixture"));
    let src = synthesize(&s1600, clean.view(), 3);
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("a 1-thread pool");
    for m in Method::ALL {
        let a = renoise(p, 1600, 3200, src.view(), None, m, 7).expect("succeeds");
        let b = one.install(|| renoise(p, 1600, 3200, src.view(), None, m, 7)).expect("succeeds");
        assert_eq!(a.image, b.image, "{m}: 1 thread vs default");
        let c = renoise(p, 1600, 3200, src.view(), None, m, 8).expect("succeeds");
        let differ = a.image.iter().zip(c.image.iter()).filter(|(x, y)| x != y).count();
        // (Quantile keeps most of the input's own noise: only the randomised PIT within a cell
        // depends on the seed.)
        assert!(differ > a.image.len() / 4, "{m}: another seed changed only {differ} pixels");
        // Output stays in range and actually differs from the input.
        assert!(a.image.iter().all(|&v| v <= WHITE));
        assert!(a.image.iter().zip(src.iter()).filter(|(x, y)| x != y).count() > a.image.len() / 2);
    }
}

#[test]
fn estimate_is_flat_on_flat_regions_and_sharp_at_edges() {
    // Flat halves at 250 and 610 DN with a vertical step edge at column 101 (odd: the edge falls
    // between positions), noise of ISO 1600.
    let p = fixture();
    let m = p.require_iso(1600).expect("ISO in the fixture");
    let binning = p.binning();
    let (h, w) = (160, 200);
    let edge = 101;
    let clean = Array2::from_shape_fn((h, w), |(_, x)| if x < edge { 250u16 } else { 610 });
    let noisy = synthesize(&IsoSampler::new(p, m), clean.view(), 9);
    let est = estimate_clean(noisy.view(), m, &binning, &p.layout);
    let sd = |l: f32| m.positions[0].bins[binning.bin(0, l)].moments().1.sqrt() as f32;
    // Flat: columns ≥ 12 px from the edge and the borders.
    for (lo, hi, level) in [(12, edge - 12, 250.0f32), (edge + 12, w - 12, 610.0)] {
        let mut se = 0.0f64;
        let mut n = 0;
        for y in 12..h - 12 {
            for x in lo..hi {
                se += ((est[[y, x]] - level) as f64).powi(2);
                n += 1;
            }
        }
        let rmse = (se / n as f64).sqrt() as f32;
        eprintln!("flat {level}: rmse {rmse:.3} DN, noise sd {:.2} DN", sd(level));
        assert!(rmse < 0.2 * sd(level), "flat region at {level}: rmse {rmse} vs noise sd {}", sd(level));
    }
    // Edge: the two columns on either side keep their own level (no bleeding).
    let step = 360.0;
    for (x, level) in [(edge - 2, 250.0f32), (edge - 1, 250.0), (edge, 610.0), (edge + 1, 610.0)] {
        let mean: f32 = (10..h - 10).map(|y| (est[[y, x]] - level).abs()).sum::<f32>() / (h - 20) as f32;
        eprintln!("column {x}: mean |error| {mean:.3} DN");
        assert!(mean < 0.05 * step, "column {x} bleeds: mean |error| {mean}");
    }
}

#[test]
fn estimate_never_mixes_cfa_positions() {
    // A flat "coloured" patch: every position at its own level. A filter that mixed positions
    // would pull them together.
    let p = fixture();
    let m = p.require_iso(1600).expect("ISO in the fixture");
    let levels = [130u16, 610, 402, 210];
    let clean = Array2::from_shape_fn((96, 96), |(y, x)| levels[noisecal_core::model::layout::position(y, x)]);
    let noisy = synthesize(&IsoSampler::new(p, m), clean.view(), 4);
    let est = estimate_clean(noisy.view(), m, &p.binning(), &p.layout);
    for pos in 0..POSITIONS {
        let vals: Vec<f32> = est
            .indexed_iter()
            .filter(|((y, x), _)| noisecal_core::model::layout::position(*y, *x) == pos)
            .map(|(_, &v)| v)
            .collect();
        let mean = vals.iter().sum::<f32>() / vals.len() as f32;
        let sd = m.positions[pos].bins[p.binning().bin(pos, levels[pos] as f32)].moments().1.sqrt() as f32;
        let rmse = (vals.iter().map(|v| (v - levels[pos] as f32).powi(2)).sum::<f32>() / vals.len() as f32).sqrt();
        assert!((mean - levels[pos] as f32).abs() < 0.1 * sd, "position {pos}: mean {mean}");
        assert!(rmse < 0.3 * sd, "position {pos}: rmse {rmse} vs sd {sd}");
    }
}

#[test]
fn bad_estimates_are_refused_clearly() {
    let p = fixture();
    let img = Array2::<u16>::from_elem((16, 16), 300);
    let small = Array2::<f32>::zeros((8, 16));
    let e = renoise(p, 1600, 3200, img.view(), Some(small.view()), Method::Bridge, 1).expect_err("must be refused");
    assert_eq!(e, RenoiseError::EstimateSize { width: 16, height: 16, est_width: 16, est_height: 8 });
    let mut nan = Array2::<f32>::from_elem((16, 16), 300.0);
    nan[[3, 5]] = f32::NAN;
    let e = renoise(p, 1600, 3200, img.view(), Some(nan.view()), Method::Quantile, 1).expect_err("must be refused");
    assert!(e.to_string().contains("row 3, column 5"), "{e}");
    assert_eq!(Method::parse("BRIDGE"), Some(Method::Bridge));
    assert!("wiener".parse::<Method>().expect_err("must be refused").contains("bridge, quantile, denoised or naive"));
}
