//! The structured components of the simulator against their declared truth: the
//! offsets a frame carries are the ones [`Simulator::frame_offsets`], [`Simulator::row_offsets`]
//! and [`Simulator::column_offsets`] report, and their laws are [`StructuredTruth`]'s.

use noisecal_core::POSITIONS;
use noisecal_core::model::layout::position;
use noisecal_sim::{
    Chart, OffsetShape, SensorModel, Simulator, StructuredTruth, random_sensor, random_sensor_structured,
};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// A dark (lens-capped) field: no signal, so frame means are offsets plus read noise.
fn dark_sim(model: SensorModel, w: u32, h: u32, seed: u64) -> Simulator {
    Simulator::new(model, Chart::flat(w, h, [0.0; 3]).expect("chart"), seed).expect("sim")
}

fn mean_var(v: &[f64]) -> (f64, f64) {
    let m = v.iter().sum::<f64>() / v.len() as f64;
    (m, v.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (v.len() - 1) as f64)
}

#[test]
fn frames_carry_the_offsets_the_simulator_reports() {
    let mut m = SensorModel::phone_12bit().with_structured_noise();
    m.col_noise_dn = 0.8;
    m.col_pattern_dn = 0.5;
    m.prnu = 0.0;
    let (w, h) = (256usize, 192usize);
    let sim = dark_sim(m, w as u32, h as u32, 4);
    let iso = 1600;
    let e = 1_000_000;
    let s = sim.iso_settings(iso).expect("settings");
    let black = sim.model().black.map(|b| b as f64);
    let bias = sim.model().bias_dn.map(|b| b as f64);
    for idx in 0..3u64 {
        let (frame, _) = sim.capture(iso, e, idx).expect("frame");
        let fo = sim.frame_offsets(iso, e, idx).expect("frame offsets");
        let rows = sim.row_offsets(iso, e, idx).expect("row offsets");
        let cols = sim.column_offsets(iso, e, idx).expect("column offsets");
        // Per position: mean − black − bias = frame offset + mean of the row and column offsets
        // (+ DSNU's mean ≈ 0) within the read noise's standard error.
        let pixel_sd = (s.read_noise_pre_e * s.dn_per_electron).hypot(s.read_noise_post_dn) + s.dsnu_dn;
        for p in 0..POSITIONS {
            let (dy, dx) = (p / 2, p % 2);
            let mut acc = 0.0;
            let mut n = 0.0;
            for y in (dy..h).step_by(2) {
                for x in (dx..w).step_by(2) {
                    acc += frame[(y, x)] as f64 - black[p] - bias[p] - rows[y] - cols[x];
                    n += 1.0;
                }
            }
            let got = acc / n;
            let se = pixel_sd / n.sqrt();
            assert!((got - fo[p]).abs() < 5.0 * se + 0.05, "frame {idx} pos {p}: {got:.3} vs {:.3} ± {se:.3}", fo[p]);
        }
        // Row means follow the reported row offsets.
        let resid: Vec<f64> = (0..h)
            .map(|y| {
                let mut acc = 0.0;
                for x in 0..w {
                    acc += frame[(y, x)] as f64 - black[position(y, x)] - bias[position(y, x)] - fo[position(y, x)];
                }
                acc / w as f64 - rows[y]
            })
            .collect();
        let (_, v) = mean_var(&resid);
        let (_, vr) = mean_var(&rows);
        assert!(v < 0.2 * vr, "frame {idx}: row residual variance {v:.4} vs row offsets {vr:.4}");
    }
}

#[test]
fn offset_laws_match_the_truth() {
    let sim = dark_sim(SensorModel::phone_10bit().with_structured_noise(), 64, 48, 8);
    for iso in [100u32, 1600, 6400] {
        let t: StructuredTruth = sim.structured_truth(iso).expect("truth");
        let s = sim.iso_settings(iso).expect("settings");
        assert_eq!(t.digital_gain, s.digital_gain);
        assert!((t.row_sd_dn - s.digital_gain * s.row_noise_dn).abs() < 1e-12);
        assert!(t.frame_offset_sd_dn.iter().all(|&v| v > 0.0) && t.dsnu_sd_dn > 0.0 && !t.is_zero());
        // The frames' offsets and the truth's samplers have the same spread.
        let e = 2_000_000;
        let from_frames: Vec<f64> = (0..600u64).map(|i| sim.frame_offsets(iso, e, i).expect("offsets")[1]).collect();
        let mut rng = ChaCha8Rng::seed_from_u64(iso as u64);
        let sampled: Vec<f64> = t.sample_frame_offsets_n(20_000, &mut rng).iter().map(|f| f[1]).collect();
        let (_, vf) = mean_var(&from_frames);
        let (_, vs) = mean_var(&sampled);
        let want = t.frame_offset_sd_dn[1].powi(2);
        assert!((vs / want - 1.0).abs() < 0.06, "ISO {iso}: sampled {vs} vs {want}");
        assert!((vf / want - 1.0).abs() < 0.3, "ISO {iso}: frames {vf} vs {want}");
        let rows: Vec<f64> = (0..20u64).flat_map(|i| sim.row_offsets(iso, e, i).expect("rows")).collect();
        let (_, vr) = mean_var(&rows);
        assert!((vr / t.row_sd_dn.powi(2) - 1.0).abs() < 0.2, "ISO {iso}: rows {vr} vs {}", t.row_sd_dn.powi(2));
    }
    // Positions share a third of the frame-offset variance.
    let t = sim.structured_truth(400).expect("truth");
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let f = t.sample_frame_offsets_n(40_000, &mut rng);
    let (a, b): (Vec<f64>, Vec<f64>) = f.iter().map(|v| (v[0], v[3])).unzip();
    let (ma, va) = mean_var(&a);
    let (mb, vb) = mean_var(&b);
    let cov = a.iter().zip(&b).map(|(x, y)| (x - ma) * (y - mb)).sum::<f64>() / (a.len() - 1) as f64;
    let corr = cov / (va * vb).sqrt();
    assert!((corr - 1.0 / 3.0).abs() < 0.03, "correlation {corr}");
}

#[test]
fn offset_shapes_have_unit_variance_and_their_kurtosis() {
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for shape in [
        OffsetShape::Gaussian,
        OffsetShape::Laplace,
        OffsetShape::StudentT { dof: 8.0 },
        OffsetShape::ScaleMixture { weight: 0.1, ratio: 3.0 },
    ] {
        let xs: Vec<f64> = (0..400_000).map(|_| shape.sample_unit(&mut rng)).collect();
        let (m, v) = mean_var(&xs);
        let k = xs.iter().map(|x| (x - m).powi(4)).sum::<f64>() / xs.len() as f64 / (v * v) - 3.0;
        let want = shape.excess_kurtosis();
        assert!(m.abs() < 0.01 && (v - 1.0).abs() < 0.02, "{shape}: mean {m} variance {v}");
        assert!((k - want).abs() < 0.15 + 0.15 * want, "{shape}: kurtosis {k} vs {want}");
    }
    let mut bad = SensorModel::phone_10bit();
    bad.frame_offset_shape = OffsetShape::ScaleMixture { weight: 1.5, ratio: 2.0 };
    let e = bad.validate().expect_err("refused").to_string();
    assert!(e.contains("frame_offset_shape"), "{e}");
    bad.frame_offset_shape = OffsetShape::Gaussian;
    bad.frame_offset_shared = 2.0;
    assert!(bad.validate().expect_err("refused").to_string().contains("frame_offset_shared"));
}

#[test]
fn heavy_tailed_row_offsets_reach_the_frames() {
    let mut m = SensorModel::phone_10bit();
    m.row_noise_pre_e = 0.6;
    m.row_noise_shape = OffsetShape::Laplace;
    let sim = dark_sim(m, 64, 64, 2);
    let rows: Vec<f64> = (0..400u64).flat_map(|i| sim.row_offsets(800, 1_000_000, i).expect("rows")).collect();
    let (mu, v) = mean_var(&rows);
    let k = rows.iter().map(|x| (x - mu).powi(4)).sum::<f64>() / rows.len() as f64 / (v * v) - 3.0;
    assert!((k - 3.0).abs() < 0.8, "row-offset excess kurtosis {k}");
    let t = sim.structured_truth(800).expect("truth");
    assert!((v / t.row_sd_dn.powi(2) - 1.0).abs() < 0.08, "{v} vs {}", t.row_sd_dn.powi(2));
}

#[test]
fn a_sensor_without_structure_has_a_zero_truth_and_the_structured_family_keeps_the_pixel_chain() {
    let mut m = SensorModel::phone_14bit();
    m.row_noise_pre_e = 0.0;
    m.row_noise_post_dn = 0.0;
    let sim = dark_sim(m, 32, 32, 1);
    let t = sim.structured_truth(400).expect("truth");
    assert!(t.is_zero(), "{t:?}");
    assert_eq!(sim.frame_offsets(400, 1000, 0).expect("offsets"), [0.0; POSITIONS]);
    assert!(sim.column_offsets(400, 1000, 0).expect("cols").iter().all(|&c| c == 0.0));
    for seed in 0..60u64 {
        let plain = random_sensor(seed);
        let rs = random_sensor_structured(seed);
        rs.model.validate().unwrap_or_else(|e| panic!("seed {seed}: {e}\n{}", rs.description));
        assert_eq!(random_sensor_structured(seed), rs, "seed {seed}: deterministic");
        let (a, b) = (&plain.model, &rs.model);
        assert_eq!(
            (a.cfa, a.black, a.white, a.read_noise_pre_e, a.read_noise_post_dn, a.dual_gain.clone(), a.prnu),
            (b.cfa, b.black, b.white, b.read_noise_pre_e, b.read_noise_post_dn, b.dual_gain.clone(), b.prnu),
            "seed {seed}: the pixel chain is random_sensor's"
        );
        assert!(b.row_noise_pre_e > 0.0 && b.frame_offset_pre_e > 0.0 && b.has_structured_noise());
        assert!(rs.description.contains("frame offsets"), "{}", rs.description);
    }
    for p in [SensorModel::phone_10bit(), SensorModel::phone_12bit(), SensorModel::phone_14bit()] {
        p.with_structured_noise().validate().expect("structured preset");
    }
}
