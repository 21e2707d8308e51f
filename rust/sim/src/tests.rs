//! Statistical and behavioural tests of the simulator. Bounds are set from the sampling error
//! of the statistic, so a wrong signal chain (missing term, wrong gain, wrong tails) fails.

use ndarray::Array2;
use noisecal_core::model::layout::position;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

use crate::*;

fn flat_sim(model: SensorModel, w: u32, h: u32, refl: f32, seed: u64) -> Simulator {
    Simulator::new(model, Chart::flat(w, h, [refl; 3]).expect("flat chart"), seed).expect("simulator")
}

/// Exposure giving mean electrons `e` on the green channel of a flat chart of reflectance 1.
fn exposure_for_electrons(sim: &Simulator, e: f64) -> u64 {
    let rate = sim.chart().background[1] as f64 * sim.chart().lamp_electrons_per_s[1] as f64;
    (e / rate * 1e9).round() as u64
}

/// Per-pixel temporal mean and (unbiased) variance over `n` frames.
fn temporal_stats(sim: &Simulator, iso: u32, exposure_ns: u64, n: u64) -> (Array2<f64>, Array2<f64>) {
    let (h, w) = (sim.height(), sim.width());
    let mut s1 = Array2::<f64>::zeros((h, w));
    let mut s2 = Array2::<f64>::zeros((h, w));
    for i in 0..n {
        let (f, _) = sim.capture(iso, exposure_ns, i).expect("capture");
        s1.zip_mut_with(&f, |a, &v| *a += v as f64);
        s2.zip_mut_with(&f, |a, &v| *a += (v as f64).powi(2));
    }
    let mean = s1.mapv(|v| v / n as f64);
    let mut var = s2;
    var.zip_mut_with(&mean, |v, &m| *v = (*v - n as f64 * m * m) / (n as f64 - 1.0));
    (mean, var)
}

fn moments(xs: impl Iterator<Item = f64> + Clone) -> (f64, f64, f64) {
    let n = xs.clone().count() as f64;
    let m = xs.clone().sum::<f64>() / n;
    let v = xs.clone().map(|x| (x - m).powi(2)).sum::<f64>() / n;
    let k = xs.map(|x| (x - m).powi(4)).sum::<f64>() / n / (v * v) - 3.0;
    (m, v, k)
}

#[test]
fn frames_are_deterministic_and_independent_of_order_and_threads() {
    let sim = Simulator::new(SensorModel::phone_12bit(), Chart::color_checker(96, 64).expect("chart"), 7).expect("sim");
    let e = sim.mid_range_exposure_ns(400).expect("exposure");
    let (b, _) = sim.capture(400, e, 4).expect("capture");
    let (a, meta) = sim.capture(400, e, 3).expect("capture");
    assert_eq!(meta, noisecal_core::FrameMeta::new(400, e));
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
    let (a1, _) = pool.install(|| sim.capture(400, e, 3)).expect("capture");
    assert_eq!(a, a1, "same seed, ISO, exposure, index ⇒ same frame on one thread");
    let differing = a.iter().zip(b.iter()).filter(|(x, y)| x != y).count();
    assert!(differing > a.len() / 2, "another frame index must give fresh noise ({differing} differ)");
    // Another seed gives another frame; ISO and exposure enter the key too.
    let other =
        Simulator::new(SensorModel::phone_12bit(), Chart::color_checker(96, 64).expect("chart"), 8).expect("sim");
    assert_ne!(other.capture(400, e, 3).expect("capture").0, a);
    assert_ne!(sim.capture(400, e + 1, 3).expect("capture").0, a);
    // Bad input is an error, not a panic.
    assert!(sim.capture(0, e, 0).expect_err("must be refused").to_string().contains("ISO is 0"));
    assert!(matches!(sim.capture(100, 0, 0), Err(SimError::Exposure)));
    assert!(matches!(sim.predicted_variance(100, 300.0, 4), Err(SimError::Position { pos: 4 })));
    assert!(sim.predicted_variance(100, f32::NAN, 0).is_err());
}

#[test]
fn mean_of_many_frames_converges_to_clean_expected_on_patches() {
    let model = SensorModel::phone_10bit();
    let sim = Simulator::new(model, Chart::color_checker(192, 128).expect("chart"), 11).expect("sim");
    let iso = 200;
    let e = sim.mid_range_exposure_ns(iso).expect("exposure");
    let n = 120;
    let (mean, var) = temporal_stats(&sim, iso, e, n);
    let clean = sim.clean_expected(iso, e).expect("clean");
    let margin = 3.0 * sim.chart().edge_blur_px + 2.0;
    let (mut z_sum, mut z2_sum, mut count) = (0.0, 0.0, 0.0);
    for rect in sim.chart().patch_rects() {
        let (rows, cols) = rect.interior(margin).expect("interior");
        for r in rows {
            for c in cols.clone() {
                // Standardised error of the per-pixel mean: must be N(0, 1)-like.
                let z = (mean[[r, c]] - clean[[r, c]] as f64) / (var[[r, c]] / n as f64).sqrt();
                z_sum += z;
                z2_sum += z * z;
                count += 1.0;
            }
        }
    }
    let z_mean = z_sum / count;
    let z_rms = (z2_sum / count).sqrt();
    assert!(count > 1000.0, "{count} pixels");
    // Row noise correlates the pixels of a row (≈ 5 % of the variance here): allow for it.
    assert!(z_mean.abs() < 0.15, "mean error {z_mean} σ: clean_expected is biased");
    assert!((z_rms - 1.0).abs() < 0.08, "RMS standardised error {z_rms}: clean_expected misses a fixed term (PRNU?)");
}

#[test]
fn temporal_variance_matches_the_analytic_prediction() {
    // (model, ISO, electrons on green): shot-dominated, read-dominated, Gaussian-shot regime,
    // digital gain, high conversion gain.
    let cases: Vec<(SensorModel, u32, f64)> = vec![
        (SensorModel::phone_10bit(), 400, 150.0),
        (SensorModel::phone_10bit(), 1600, 2.0),
        (SensorModel::phone_10bit(), 50, 2500.0),
        (SensorModel::phone_10bit(), 3200, 20.0),
        (SensorModel::phone_12bit(), 800, 40.0),
        (SensorModel::phone_14bit(), 100, 800.0),
    ];
    for (k, (model, iso, electrons)) in cases.into_iter().enumerate() {
        let sim = flat_sim(model, 64, 64, 1.0, 100 + k as u64);
        let e = exposure_for_electrons(&sim, electrons);
        let n = 48;
        let (_, var) = temporal_stats(&sim, iso, e, n);
        let clean = sim.clean_expected(iso, e).expect("clean");
        let (mut measured, mut predicted) = (0.0, 0.0);
        for ((r, c), v) in var.indexed_iter() {
            measured += v;
            predicted += sim.predicted_variance(iso, clean[[r, c]], position(r, c)).expect("variance");
        }
        let ratio = measured / predicted;
        assert!((ratio - 1.0).abs() < 0.03, "case {k} ISO {iso}: measured/predicted variance {ratio}");
    }
}

#[test]
fn sampled_noise_has_the_same_law_as_captured_noise() {
    let model = SensorModel::phone_12bit();
    let sim = flat_sim(model.clone(), 96, 64, 1.0, 5);
    // Read-noise-heavy level (2 e⁻ at ISO 640, low conversion gain): tails must match too.
    let iso = 640;
    let e = exposure_for_electrons(&sim, 2.0);
    let clean = sim.clean_expected(iso, e).expect("clean");
    // Pool the captured noise of Gr pixels (position 0 of GRBG) with their clean level.
    let mut captured = Vec::new();
    let mut levels = Vec::new();
    for i in 0..30 {
        let (f, _) = sim.capture(iso, e, i).expect("capture");
        for ((r, c), &v) in f.indexed_iter() {
            if position(r, c) == 0 {
                captured.push(v as f64 - clean[[r, c]].round() as f64);
                levels.push(clean[[r, c]]);
            }
        }
    }
    let level = levels.iter().sum::<f32>() / levels.len() as f32;
    let mut rng = ChaCha8Rng::seed_from_u64(99);
    let sampled = sim.sample_noise_at_level(iso, level, 0, captured.len(), &mut rng).expect("samples");
    let (mc, vc, kc) = moments(captured.iter().cloned());
    let (ms, vs, ks) = moments(sampled.iter().map(|&x| x as f64));
    let se = (vc / captured.len() as f64).sqrt();
    // Means differ by the spread of clean levels (PRNU) rounding only.
    assert!((mc - ms).abs() < 6.0 * se + 0.1, "means {mc} vs {ms}");
    assert!((vc / vs - 1.0).abs() < 0.04, "variances {vc} vs {vs}");
    assert!((kc - ks).abs() < 0.3, "kurtosis {kc} vs {ks}");
    let predicted = sim.predicted_variance(iso, level, 0).expect("variance");
    assert!((vs / predicted - 1.0).abs() < 0.03, "sampled {vs} vs predicted {predicted}");
    // Below the dark level the samples are shifted down, and never panic at extremes.
    let low = sim.sample_noise_at_level(iso, 200.0, 1, 20_000, &mut rng).expect("samples");
    let low_mean = low.iter().map(|&x| x as f64).sum::<f64>() / low.len() as f64;
    assert!(low_mean.abs() < 0.5, "{low_mean}");
    let top = sim.sample_noise_at_level(iso, 5000.0, 1, 100, &mut rng).expect("samples");
    assert!(top.iter().all(|&x| x == 4095 - 5000));
}

#[test]
fn read_noise_is_heavy_tailed_only_when_configured() {
    let mut kurt = Vec::new();
    for dof in [Some(6.0), None] {
        let mut model = SensorModel::phone_10bit();
        model.read_noise_dof = dof;
        let sim = flat_sim(model, 128, 64, 0.0, 21);
        let mut xs = Vec::new();
        for i in 0..24 {
            let (f, _) = sim.capture(800, 1_000_000, i).expect("capture");
            xs.extend(
                f.indexed_iter().map(|((r, c), &v)| v as f64 - 64.0 - sim.model().bias_dn[position(r, c)] as f64),
            );
        }
        let (m, _, k) = moments(xs.iter().cloned());
        assert!(m.abs() < 0.1, "dark mean {m}");
        kurt.push(k);
    }
    assert!(kurt[0] > 1.0, "t(6) read noise must show excess kurtosis, got {}", kurt[0]);
    assert!(kurt[1].abs() < 0.1, "Gaussian read noise must not, got {}", kurt[1]);
}

#[test]
fn flicker_moves_the_mean_of_affected_frames_only() {
    let mut model = SensorModel::phone_10bit();
    model.flicker = Some(Flicker { probability: 0.3, amplitude: 0.03 });
    let sim = flat_sim(model, 64, 64, 1.0, 3);
    let e = exposure_for_electrons(&sim, 1500.0);
    let clean = sim.clean_expected(50, e).expect("clean");
    let clean_mean = clean.iter().map(|&v| v as f64 - 64.0).sum::<f64>() / clean.len() as f64;
    let (mut up, mut down, mut steady) = (0, 0, 0);
    for i in 0..40 {
        let (f, _) = sim.capture(50, e, i).expect("capture");
        let m = f.iter().map(|&v| v as f64 - 64.0).sum::<f64>() / f.len() as f64;
        let fx = sim.frame_effects(50, e, i);
        // SE of a frame mean: σ ≈ 10 DN / 64 px ≈ 0.15 DN vs 3 % of ~375 DN ≈ 11 DN.
        assert!(
            (m / clean_mean - fx.flicker as f64).abs() < 0.003,
            "frame {i}: ratio {} vs flicker {}",
            m / clean_mean,
            fx.flicker
        );
        match fx.flicker {
            f if f > 1.0 => up += 1,
            f if f < 1.0 => down += 1,
            _ => steady += 1,
        }
    }
    assert!(up > 0 && down > 0 && steady > 15, "{up} up, {down} down, {steady} steady");
}

#[test]
fn dual_conversion_gain_makes_the_dark_variance_jump_down() {
    let sim = flat_sim(SensorModel::phone_12bit(), 96, 64, 0.0, 13);
    let mut measured = Vec::new();
    for iso in [640, 800] {
        let (_, var) = temporal_stats(&sim, iso, 1_000_000, 24);
        let m = var.mean().expect("mean");
        let p =
            (0..4).map(|pos| sim.predicted_variance(iso, sim.model().black[pos], pos).expect("v")).sum::<f64>() / 4.0;
        assert!((m / p - 1.0).abs() < 0.04, "ISO {iso}: measured {m} predicted {p}");
        measured.push(m);
    }
    assert!(sim.iso_settings(800).expect("800").high_conversion_gain);
    assert!(!sim.iso_settings(640).expect("640").high_conversion_gain);
    assert!(
        measured[1] < 0.5 * measured[0],
        "dark variance at ISO 800 ({}) must drop below ISO 640's ({})",
        measured[1],
        measured[0]
    );
}

#[test]
fn digital_gain_leaves_combs_and_clipping_is_exact() {
    let sim = flat_sim(SensorModel::phone_10bit(), 64, 32, 1.0, 17);
    assert_eq!(sim.iso_settings(3200).expect("3200").digital_gain, 2.0);
    let (f, _) = sim.capture(3200, exposure_for_electrons(&sim, 30.0), 0).expect("capture");
    assert!(
        f.iter().all(|&v| v == 1023 || (v as i32 - 64) % 2 == 0),
        "digital gain 2 must leave only every other code"
    );
    let (f, _) = sim.capture(1600, exposure_for_electrons(&sim, 30.0), 0).expect("capture");
    assert!(f.iter().any(|&v| (v as i32 - 64) % 2 != 0), "analog gain fills every code");
    let (f, _) = sim.capture(50, exposure_for_electrons(&sim, 20_000.0), 0).expect("capture");
    assert!(f.iter().all(|&v| v == 1023), "saturated pixels sit exactly at white");
}

#[test]
fn session_plan_spans_dark_to_clipped() {
    let sim =
        Simulator::new(SensorModel::phone_10bit(), Chart::color_checker(192, 128).expect("chart"), 1).expect("sim");
    let plan = SessionPlan::for_simulator(&sim, vec![100, 800], 2).expect("plan");
    assert_eq!(plan.reference_iso, 50);
    let margin = 3.0 * sim.chart().edge_blur_px + 2.0;
    let centre_of = |img: &Array2<f32>, rect: &PatchRect| {
        let (r, c) = rect.interior(margin).expect("interior");
        img[[(r.start + r.end) / 2, (c.start + c.end) / 2]]
    };
    for f in plan.frames().filter(|f| f.in_burst == 0) {
        let clean = sim.clean_expected(f.iso, f.exposure_ns).expect("clean");
        let levels: Vec<f32> = sim.chart().patch_rects().iter().map(|r| centre_of(&clean, r)).collect();
        let clipped = levels.iter().filter(|&&l| l >= 1023.0).count();
        let max = levels.iter().cloned().fold(0.0, f32::max);
        match f.step {
            4 => assert!(clipped > 0 && clipped < 24, "EV+4 must clip some patches: {clipped}"),
            0 => assert!(clipped == 0 && max > 64.0 + 0.2 * 959.0 && max < 64.0 + 0.5 * 959.0, "EV 0 max {max}"),
            -4 => assert!(max < 64.0 + 0.05 * 959.0, "EV−4 must be dark: max {max}"),
            _ => {}
        }
    }
}

#[test]
fn camera2_plane_of_a_captured_frame_reads_back() {
    let sim = flat_sim(SensorModel::phone_14bit(), 32, 16, 0.5, 2);
    let (f, _) = sim.capture(400, 5_000_000, 0).expect("capture");
    let stride = 2 * 32 + 64;
    let bytes = to_padded_le_bytes(&f, stride);
    assert_eq!(bytes.len(), 15 * stride + 64);
    let view = noisecal_core::FrameView::from_le_bytes(&bytes, 32, 16, stride, 2).expect("view");
    assert_eq!(view.to_array(), f);
}

/// Speed check for a full 12 MP frame; run with
/// `cargo test -p noisecal-sim --release -- --ignored --nocapture full_frame_speed`.
#[test]
#[ignore = "timing; run in release"]
fn full_frame_speed() {
    let sim =
        Simulator::new(SensorModel::phone_12bit(), Chart::color_checker(4032, 3024).expect("chart"), 1).expect("sim");
    let e = sim.mid_range_exposure_ns(400).expect("exposure");
    let _ = sim.capture(400, e, 0).expect("warm-up");
    let t = std::time::Instant::now();
    let (f, _) = sim.capture(400, e, 1).expect("capture");
    let dt = t.elapsed();
    println!("4032×3024 frame in {dt:?} on {} threads", rayon::current_num_threads());
    assert_eq!(f.dim(), (3024, 4032));
    assert!(dt.as_secs_f64() < 1.0, "{dt:?}");
}

/// Per-pixel temporal mean minus black and bias (DN at the output) over `n` frames.
fn dark_offsets(sim: &Simulator, iso: u32, n: u64) -> Array2<f64> {
    let (mean, _) = temporal_stats(sim, iso, 1_000_000, n);
    let m = sim.model();
    let mut off = mean;
    for ((r, c), v) in off.indexed_iter_mut() {
        let p = position(r, c);
        *v -= m.black[p] as f64 + sim.iso_settings(iso).expect("iso").digital_gain * m.bias_dn[p] as f64;
    }
    off
}

#[test]
fn dsnu_is_a_fixed_offset_whose_pre_gain_part_scales_with_the_analog_gain() {
    let mut model = SensorModel::phone_10bit();
    model.prnu = 0.0;
    model.dsnu_pre_e = 1.5;
    model.dsnu_post_dn = 0.4;
    let sim = flat_sim(model.clone(), 64, 64, 0.0, 31);
    let n = 24;
    let mut spatial = Vec::new();
    for iso in [100, 800] {
        let s = sim.iso_settings(iso).expect("iso");
        let off = dark_offsets(&sim, iso, n);
        // The measured per-pixel offsets are the model's DSNU map (same pixels, right scale).
        let truth: Vec<f64> =
            off.indexed_iter().map(|((r, c), _)| sim.dsnu_offset_dn(iso, r, c).expect("dsnu")).collect();
        let meas: Vec<f64> = off.iter().copied().collect();
        let slope = meas.iter().zip(&truth).map(|(m, t)| m * t).sum::<f64>() / truth.iter().map(|t| t * t).sum::<f64>();
        // Spatial variance of the offsets, minus the temporal noise left in an n-frame mean.
        let (mean, var, _) = moments(meas.iter().copied());
        let temporal = (0..4).map(|p| sim.predicted_variance(iso, model.black[p], p).expect("v")).sum::<f64>() / 4.0;
        let dsnu_var = var - temporal / n as f64;
        let want = (s.dn_per_electron * 1.5).powi(2) + (model.dsnu_post_dn as f64).powi(2);
        assert!((s.dsnu_dn.powi(2) / want - 1.0).abs() < 1e-9);
        let fpv = sim.fixed_pattern_variance(iso, model.black[0], 0).expect("fpv");
        assert!((fpv / want - 1.0).abs() < 1e-9, "fixed_pattern_variance {fpv} vs {want}");
        // SE of a variance over 4096 pixels ≈ √(2/4096) ≈ 2.2 %; the hashed map is ~N(0, 1).
        assert!((dsnu_var / want - 1.0).abs() < 0.1, "ISO {iso}: DSNU variance {dsnu_var} vs {want}");
        assert!((slope - 1.0).abs() < 0.05, "ISO {iso}: offsets vs the DSNU map, slope {slope}");
        assert!(mean.abs() < 0.1 + 4.0 * (var / 4096.0).sqrt(), "ISO {iso}: DSNU mean {mean}");
        spatial.push(dsnu_var);
    }
    // ISO 100 → 800 is 8× the analog gain: the pre-gain part grows 8× in DN, the post part not.
    let g = |iso| sim.iso_settings(iso).expect("iso").dn_per_electron;
    let post = (model.dsnu_post_dn as f64).powi(2);
    let want_ratio = ((g(800) * 1.5).powi(2) + post) / ((g(100) * 1.5).powi(2) + post);
    let ratio = spatial[1] / spatial[0];
    assert!(want_ratio > 40.0, "{want_ratio}");
    assert!((ratio / want_ratio - 1.0).abs() < 0.1, "DSNU variance ratio ISO 800/100 {ratio} vs {want_ratio}");
    // The map is per (row, col): a smaller frame of the same seed is a crop of it.
    let crop = flat_sim(model.clone(), 32, 16, 0.0, 31);
    for (r, c) in [(0, 0), (5, 17), (15, 31)] {
        assert_eq!(crop.dsnu_offset_dn(800, r, c).expect("dsnu"), sim.dsnu_offset_dn(800, r, c).expect("dsnu"));
    }
    // Off by default: the preset's dark offsets are only temporal noise.
    let plain = flat_sim(SensorModel::phone_10bit(), 64, 64, 0.0, 31);
    assert_eq!(plain.dsnu_offset_dn(800, 3, 5).expect("dsnu"), 0.0);
    let (_, v, _) = moments(dark_offsets(&plain, 800, n).iter().copied());
    let temporal = plain.predicted_variance(800, 64.0, 0).expect("v") / n as f64;
    assert!(v < 1.3 * temporal, "no DSNU: offset variance {v} vs temporal {temporal}");
    // clean_expected carries the DSNU offset.
    let clean = sim.clean_expected(800, 1_000_000).expect("clean");
    let want = 64.0 + model.bias_dn[position(7, 9)] as f64 + sim.dsnu_offset_dn(800, 7, 9).expect("dsnu");
    assert!((clean[[7, 9]] as f64 - want).abs() < 1e-3, "{} vs {want}", clean[[7, 9]]);
}

#[test]
fn gamma_changes_brightness_at_equal_iso_times_exposure() {
    for gamma in [0.85f32, 1.0, 1.2] {
        let mut model = SensorModel::phone_10bit();
        model.gain_error_per_stop = 0.0;
        model.gain_iso_exponent = gamma;
        let sim = flat_sim(model, 64, 64, 1.0, 41);
        // ISO 100 and 800 at the same ISO × exposure: 300 and 37.5 electrons.
        let e100 = exposure_for_electrons(&sim, 300.0);
        let means: Vec<f64> = [(100u32, e100), (800, e100 / 8)]
            .iter()
            .map(|&(iso, e)| {
                let (mean, _) = temporal_stats(&sim, iso, e, 4);
                mean.indexed_iter()
                    .map(|((r, c), v)| v - 64.0 - sim.model().bias_dn[position(r, c)] as f64)
                    .sum::<f64>()
                    / mean.len() as f64
            })
            .collect();
        let ratio = means[1] / means[0];
        let want = 8f64.powf(gamma as f64 - 1.0);
        // SE of the ratio ≈ 0.3 % (shot noise of 37.5 e⁻ over 4 × 4096 pixels).
        assert!((ratio / want - 1.0).abs() < 0.005, "γ {gamma}: brightness ratio {ratio} vs {want}");
        let s = sim.iso_settings(800).expect("iso");
        assert!((s.analog_gain - 16f64.powf(gamma as f64)).abs() < 1e-9 * s.analog_gain, "γ {gamma}");
    }
    let mut m = SensorModel::phone_12bit();
    m.gain_iso_exponent = 1.0;
    assert_eq!(m.at_iso(1600).expect("iso"), SensorModel::phone_12bit().at_iso(1600).expect("iso"));
    m.gain_iso_exponent = 3.0;
    assert!(m.validate().expect_err("must be refused").to_string().contains("gain_iso_exponent"));
}

#[test]
fn tukey_lambda_read_noise_reaches_the_frames_with_its_tails() {
    let mut model = SensorModel::phone_10bit();
    model.set_read_noise_shape(ReadNoiseShape::TukeyLambda { lambda: -0.08 });
    assert_eq!((model.read_noise_dof, model.read_noise_tukey_lambda), (None, Some(-0.08)));
    model.validate().expect("valid");
    let sim = flat_sim(model.clone(), 128, 64, 0.0, 23);
    let iso = 800;
    let mut xs = Vec::new();
    for i in 0..24 {
        let (f, _) = sim.capture(iso, 1_000_000, i).expect("capture");
        xs.extend(f.indexed_iter().map(|((r, c), &v)| v as f64 - 64.0 - model.bias_dn[position(r, c)] as f64));
    }
    let (m, v, k) = moments(xs.iter().cloned());
    let s = sim.iso_settings(iso).expect("iso");
    // Kurtosis of the sum: the read-noise parts carry the Tukey kurtosis, row noise and
    // quantisation none.
    let kr = ReadNoiseShape::TukeyLambda { lambda: -0.08 }.excess_kurtosis();
    let (vpre, vpost) = ((s.dn_per_electron * s.read_noise_pre_e).powi(2), s.read_noise_post_dn.powi(2));
    let total = sim.predicted_variance(iso, 64.0, 0).expect("v");
    let want_k = kr * (vpre.powi(2) + vpost.powi(2)) / total.powi(2);
    assert!(m.abs() < 0.1, "dark mean {m}");
    assert!((v / total - 1.0).abs() < 0.03, "variance {v} vs predicted {total}");
    assert!(want_k > 2.0 && (k / want_k - 1.0).abs() < 0.15, "kurtosis {k} vs {want_k}");
    // Both shapes at once are refused.
    model.read_noise_dof = Some(5.0);
    assert!(model.validate().expect_err("must be refused").to_string().contains("not both"));
}

#[test]
fn predicted_variance_holds_on_random_family_sensors() {
    // Temporal variance at mid-range on a flat field for sensors of the family (Tukey-λ and
    // Student-t tails, γ ≠ 1, DSNU, dual and digital gain): the prediction must hold.
    let mut checked = 0;
    for seed in 0..24u64 {
        let rs = random_sensor(seed);
        let m = rs.model.clone();
        let sim = flat_sim(m.clone(), 64, 48, 1.0, 300 + seed);
        let spec = random_session(seed, &m);
        let iso = *spec.target_isos.last().expect("targets");
        let s = sim.iso_settings(iso).expect("iso");
        // Electrons for ~45 % of the range at this ISO (clear of the black floor and white even
        // at high gain), below the full well.
        let span = m.white as f64 - m.black.iter().cloned().fold(0.0f32, f32::max) as f64;
        let electrons = (0.45 * span / s.total_dn_per_electron()).min(0.5 * s.full_well_e);
        let e = exposure_for_electrons(&sim, electrons);
        let n = 24;
        let (_, var) = temporal_stats(&sim, iso, e, n);
        let clean = sim.clean_expected(iso, e).expect("clean");
        let (mut measured, mut predicted) = (0.0, 0.0);
        for ((r, c), v) in var.indexed_iter() {
            measured += v;
            predicted += sim.predicted_variance(iso, clean[[r, c]], position(r, c)).expect("variance");
        }
        let ratio = measured / predicted;
        // SE of the pooled variance over 3072 pixels × 23 dof ≈ 0.5 % (× √(1 + κ/2) tails).
        assert!((ratio - 1.0).abs() < 0.04, "seed {seed} ISO {iso}: measured/predicted {ratio}\n{}", rs.description);
        checked += 1;
    }
    assert_eq!(checked, 24);
}

#[test]
fn motion_walks_within_its_bounds_and_moves_frames_captured_together() {
    let mut model = SensorModel::phone_10bit();
    model.jitter_px = 0.0;
    let motion =
        Motion { max_shift_px: 0.5, step_px: 0.1, jump_probability: 0.05, max_rotation_rad: 0.001, breathing: 0.001 };
    model.motion = Some(motion.clone());
    let sim = Simulator::new(model.clone(), Chart::color_checker(96, 72).expect("chart"), 7).expect("simulator");
    let poses: Vec<FrameEffects> = (0..300).map(|i| sim.frame_effects(100, 1_000_000, i)).collect();
    let mut steps = Vec::new();
    for (i, p) in poses.iter().enumerate() {
        assert!(p.jitter.0.abs() <= 0.5 + 1e-6 && p.jitter.1.abs() <= 0.5 + 1e-6, "frame {i}: {:?}", p.jitter);
        assert!(p.rotation.abs() <= 0.001 + 1e-7 && (p.scale - 1.0).abs() <= 0.001 + 1e-7, "frame {i}");
        // The same capture index at another ISO and exposure is where the scene was then.
        let other = sim.frame_effects(800, 125_000, i as u64);
        assert_eq!((other.jitter, other.rotation, other.scale), (p.jitter, p.rotation, p.scale));
        if i > 0 && !(i as u64).is_multiple_of(MOTION_BLOCK) {
            steps
                .push(((p.jitter.0 - poses[i - 1].jitter.0) as f64).hypot((p.jitter.1 - poses[i - 1].jitter.1) as f64));
        }
    }
    // A walk: most steps near the step size, some jumps, never frozen.
    steps.sort_by(f64::total_cmp);
    let median = steps[steps.len() / 2];
    assert!((0.05..0.25).contains(&median), "median step {median:.3} px for 0.1 px per axis");
    assert!(steps.iter().filter(|&&s| s == 0.0).count() == 0);
    let spread = poses.iter().map(|p| p.jitter.0 as f64).fold((f64::MAX, f64::MIN), |(a, b), x| (a.min(x), b.max(x)));
    assert!(spread.1 - spread.0 > 0.6, "the walk covers its range: {spread:?}");
    // Without motion nothing changes: the pose is the jitter alone.
    model.motion = None;
    let still = Simulator::new(model, Chart::color_checker(96, 72).expect("chart"), 7).expect("simulator");
    let p = still.frame_effects(100, 1_000_000, 3);
    assert_eq!((p.jitter, p.rotation, p.scale), ((0.0, 0.0), 0.0, 1.0));
}

#[test]
fn a_rotated_scene_is_the_chart_seen_through_the_rotation() {
    // The posed (per-pixel) render equals the separable one for a pure shift, and a rotation
    // moves an edge far from the centre by rotation × distance.
    let chart = Chart::color_checker(192, 144).expect("chart");
    let colors = [0usize, 1];
    let shifted = chart.prepare((0.3, -0.2));
    let posed = chart.prepare_posed((0.3, -0.2), 1e-9, 1.0);
    let (mut a, mut b) = (vec![0.0f32; 192], vec![0.0f32; 192]);
    for y in [10usize, 40, 77, 130] {
        shifted.row_rates(y, colors, &mut a);
        posed.row_rates(y, colors, &mut b);
        for x in 0..192 {
            assert!((a[x] - b[x]).abs() <= 1e-3 * a[x].abs() + 1e-2, "row {y} col {x}: {} vs {}", a[x], b[x]);
        }
    }
    // Rotating by θ about the centre shifts row y by θ·(y − cy) along x: the same as a shift.
    let theta = 0.004f32;
    // Row 31 is mid-way down the first patch row (11 px from its horizontal edges).
    let y = 31usize;
    let dx = -theta * (y as f32 + 0.5 - 72.0);
    let rotated = chart.prepare_posed((0.0, 0.0), theta, 1.0);
    let moved = chart.prepare((dx, 0.0));
    rotated.row_rates(y, colors, &mut a);
    moved.row_rates(y, colors, &mut b);
    let worst = a.iter().zip(&b).map(|(p, q)| (p - q).abs() / q.abs().max(1.0)).fold(0.0f32, f32::max);
    assert!(worst < 0.02, "rotation vs the shift it makes at row {y}: {worst:.4}");
}

#[test]
fn a_moving_texture_moves_by_sub_pixel_shifts() {
    // A natural scene sampled at its nearest texel ignores shifts below half a pixel; a moving
    // scene samples it bilinearly: unmoved it is the same scene, and shifted right by 0.3 px each
    // pixel is 0.7 of its own texel and 0.3 of its left neighbour's.
    let chart = Chart::natural(64, 48, 7).expect("scene");
    let mut changed = 0;
    for y in [3usize, 20, 41] {
        for c in 0..3usize {
            let rates = |p: crate::chart::Prepared<'_>| {
                let mut out = vec![0.0f32; 64];
                p.row_rates(y, [c, c], &mut out);
                out
            };
            let still = rates(chart.prepare((0.0, 0.0)));
            let left = rates(chart.prepare((1.0, 0.0))); // each pixel sees its left neighbour's texel
            let same = rates(chart.prepare_moving((0.0, 0.0), 0.0, 1.0));
            let moved = rates(chart.prepare_moving((0.3, 0.0), 0.0, 1.0));
            let nearest = rates(chart.prepare_posed((0.3, 0.0), 0.0, 1.0));
            for x in 1..64 {
                assert!((still[x] - same[x]).abs() <= 1e-4 * still[x].abs(), "row {y} col {x}");
                assert_eq!(nearest[x], still[x], "nearest texel under a 0.3 px shift, row {y} col {x}");
                let want = 0.7 * still[x] + 0.3 * left[x];
                assert!((moved[x] - want).abs() <= 1e-3 * want.abs() + 1e-3, "row {y} col {x}: {} vs {want}", moved[x]);
                changed += usize::from(moved[x] != still[x]);
            }
        }
    }
    assert!(changed > 100, "the shift changed {changed} pixels");
}
