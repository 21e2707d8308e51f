//! Structured noise (issue 11): row and frame offsets calibrated from the session, recovered
//! against the simulator's truth, and synthesized so that held-out row means vary as much as
//! real ones — without the pixel marginals getting worse, and with nothing added on a sensor that
//! has no such noise.

use ndarray::Array2;
use noisecal_core::metrics::{NoiseSamples, compare};
use noisecal_core::model::layout::position;
use noisecal_core::model::structure::Components;
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::synthesize;
use noisecal_e2e::{Setup, calibrate, heldout_clean, setup};
use noisecal_sim::SensorModel;

fn row_noise_sensor(pre_e: f32, post_dn: f32) -> SensorModel {
    let mut m = SensorModel::phone_10bit();
    m.row_noise_pre_e = pre_e;
    m.row_noise_post_dn = post_dn;
    m
}

/// Row-mean deviations over flat pixels: per frame and row (≥ 32 flat pixels), the row's mean
/// noise minus that row's mean over the frames (the clean image's own row error cancels), scaled
/// by `√(k/(k−1))`. Returns `Σ dev²` and the count.
fn row_mean_var(frames: &[Array2<u16>], clean: &Array2<u16>, flat: &[bool]) -> f64 {
    let (h, w) = clean.dim();
    let k = frames.len() as f64;
    let mut acc = 0.0;
    let mut n = 0usize;
    for y in 0..h {
        let xs: Vec<usize> = (0..w).filter(|&x| flat[y * w + x]).collect();
        if xs.len() < 32 {
            continue;
        }
        let means: Vec<f64> = frames
            .iter()
            .map(|f| xs.iter().map(|&x| f[(y, x)] as f64 - clean[(y, x)] as f64).sum::<f64>() / xs.len() as f64)
            .collect();
        let m = means.iter().sum::<f64>() / k;
        for v in means {
            acc += (v - m).powi(2) * k / (k - 1.0);
            n += 1;
        }
    }
    acc / n as f64
}

struct IsoResult {
    iso: u32,
    true_row_sd: f64,
    fitted_row_sd: f64,
    significant: bool,
    /// Row-mean variance, synthetic / real, with components and pixel-only.
    ratio: f64,
    ratio_pixel_only: f64,
    /// Marginal JSD (overall) with components, pixel-only, and real vs real (the floor).
    marg: f64,
    marg_pixel_only: f64,
    marg_floor: f64,
}

fn run(s: &Setup, isos: &[u32]) -> Vec<IsoResult> {
    let (_, pack) = calibrate(s, |_| {});
    let exp0 = s.plan.exposure_ns(-1, s.plan.reference_iso);
    let (clean, flat) = heldout_clean(s, exp0, 16, 1 << 40, pack.bin_width);
    let (h, w) = clean.dim();
    let binning = pack.binning();
    let mut out = Vec::new();
    for (i, &iso) in isos.iter().enumerate() {
        let model = pack.iso(iso).expect("calibrated ISO");
        let st = pack.structure_of(iso).expect("structure measured");
        let truth = s.sim.iso_settings(iso).expect("settings");
        let all = IsoSampler::new(&pack, model);
        let pixel = IsoSampler::with_components(&pack, model, Components::PIXEL);
        let exp = s.plan.exposure_ns(-1, iso);
        let (mut real, mut syn, mut pix) = (Vec::new(), Vec::new(), Vec::new());
        let mut samples = [(); 4].map(|_| NoiseSamples::new(&binning, 4));
        for k in 0..12u64 {
            let (px, _) = s.sim.capture(iso, exp, (1 << 41) + 1000 * i as u64 + k).expect("capture");
            let a = synthesize(&all, clean.view(), 100 + k);
            let b = synthesize(&pixel, clean.view(), 100 + k);
            for y in 0..h {
                for x in 0..w {
                    if !flat[y * w + x] {
                        continue;
                    }
                    let c = clean[(y, x)];
                    let pos = position(y, x);
                    let idx = if k % 2 == 0 { 0 } else { 3 };
                    samples[idx].add(pos, c as f32, px[(y, x)] as i32 - c as i32);
                    if k % 2 == 0 {
                        samples[1].add(pos, c as f32, a[(y, x)] as i32 - c as i32);
                        samples[2].add(pos, c as f32, b[(y, x)] as i32 - c as i32);
                    }
                }
            }
            real.push(px);
            syn.push(a);
            pix.push(b);
        }
        // More synthetic frames for the marginals: synthetic row offsets make a marginal of few
        // frames fluctuate as a real one does; the model's marginal is what is compared.
        for k in 12..36u64 {
            let a = synthesize(&all, clean.view(), 100 + k);
            let b = synthesize(&pixel, clean.view(), 100 + k);
            for y in 0..h {
                for x in 0..w {
                    if flat[y * w + x] {
                        let c = clean[(y, x)];
                        let pos = position(y, x);
                        samples[1].add(pos, c as f32, a[(y, x)] as i32 - c as i32);
                        samples[2].add(pos, c as f32, b[(y, x)] as i32 - c as i32);
                    }
                }
            }
        }
        let vr = row_mean_var(&real, &clean, &flat);
        for (name, smp) in [("real", &samples[0]), ("all", &samples[1]), ("pixel", &samples[2])] {
            let m = smp.marginal(0).trimmed();
            eprintln!("  ISO {iso} {name}: marginal moments {:?}", m.moments());
        }
        let row = st.rows[0].as_ref().expect("rows measured");
        out.push(IsoResult {
            iso,
            true_row_sd: truth.row_noise_dn,
            fitted_row_sd: row.sd(),
            significant: st.row(0).is_some() && st.row(1).is_some(),
            ratio: row_mean_var(&syn, &clean, &flat) / vr,
            ratio_pixel_only: row_mean_var(&pix, &clean, &flat) / vr,
            marg: compare(&samples[0], &samples[1]).marginal_overall,
            marg_pixel_only: compare(&samples[0], &samples[2]).marginal_overall,
            marg_floor: compare(&samples[0], &samples[3]).marginal_overall,
        });
    }
    for r in &out {
        eprintln!(
            "ISO {}: row sd true {:.3} fitted {:.3} (significant {}); row-mean var ratio {:.3} (pixel only {:.3}); marginal JSD {:.5} (pixel only {:.5}, floor {:.5})",
            r.iso,
            r.true_row_sd,
            r.fitted_row_sd,
            r.significant,
            r.ratio,
            r.ratio_pixel_only,
            r.marg,
            r.marg_pixel_only,
            r.marg_floor
        );
    }
    out
}

#[test]
fn row_noise_is_recovered_and_synthesized() {
    let isos = vec![100, 400, 1600];
    let s = setup(row_noise_sensor(1.0, 0.6), 256, 192, 21, isos.clone(), 8, vec![-4, -2, 0, 2]);
    for r in run(&s, &isos) {
        assert!(r.significant, "ISO {}: row noise of {:.2} DN not found", r.iso, r.true_row_sd);
        let rel = r.fitted_row_sd / r.true_row_sd;
        assert!(
            (0.85..1.15).contains(&rel),
            "ISO {}: fitted row sd {:.3} vs true {:.3}",
            r.iso,
            r.fitted_row_sd,
            r.true_row_sd
        );
        assert!((0.85..1.15).contains(&r.ratio), "ISO {}: row-mean variance ratio {:.3}", r.iso, r.ratio);
        assert!(
            r.ratio_pixel_only < 0.7,
            "ISO {}: pixel-only ratio {:.3} should show the gap",
            r.iso,
            r.ratio_pixel_only
        );
        assert!(
            r.marg <= r.marg_pixel_only * 1.15 + r.marg_floor * 0.5,
            "ISO {}: marginal JSD {:.5} worse than pixel-only {:.5} (floor {:.5})",
            r.iso,
            r.marg,
            r.marg_pixel_only,
            r.marg_floor
        );
    }
}

#[test]
fn a_sensor_without_row_noise_gets_none() {
    let isos = vec![100, 1600];
    let s = setup(row_noise_sensor(0.0, 0.0), 256, 192, 22, isos.clone(), 8, vec![-4, -2, 0, 2]);
    let (_, pack) = calibrate(&s, |_| {});
    for &iso in &isos {
        let st = pack.structure_of(iso).expect("structure measured");
        if let Some(f) = &st.frames {
            eprintln!(
                "ISO {iso}: frame offsets measured var {:?} sampling {:?} significant {}",
                f.measured_var, f.sampling_var, f.significant
            );
        }
        for p in 0..2 {
            let d = st.rows[p].as_ref().expect("rows measured");
            assert!(st.row(p).is_none(), "ISO {iso}: row noise found where there is none: {:.4} DN", d.sd());
            assert!(d.sd() < 0.05, "ISO {iso}: row sd {:.4}", d.sd());
            assert!(st.column(p).is_none(), "ISO {iso}: column noise found where there is none");
        }
        // No component: the sampler is the pixel-only one, byte for byte.
        let model = pack.iso(iso).expect("model");
        let clean = Array2::from_elem((16, 16), 300u16);
        let a = synthesize(&IsoSampler::new(&pack, model), clean.view(), 5);
        let b = synthesize(&IsoSampler::with_components(&pack, model, Components::PIXEL), clean.view(), 5);
        if st.frame().is_none() {
            assert_eq!(a, b, "ISO {iso}: nothing structured, yet synthesis changed");
        }
    }
}
