//! Known truth for the pixels' part of the line-mean variances (`metrics/line_pixels.rs`) and
//! the line-mean variance ratio on the real pixels' noise it gives (`metrics/spatial.rs`).

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::metrics::line_pixels::LinePixelPart;
use crate::metrics::spatial::{FlatLayout, SpatialSamples, compare_spatial};

const W: usize = 64;
const H: usize = 48;
const BURSTS: u64 = 40;
const FRAMES: u64 = 4;

/// Bursts of noise over a `W × H` image whose left third is not flat (rows of 43 flat
/// pixels, columns of 48): per pixel a variance `1 + y / 8` (the line statistics are
/// dominated by some lines, as on a chart), plus per burst and pixel a constant of variance
/// `fixed · (1 + y / 8)` (a clean image's error: the same in every frame of a burst), or the
/// same drawn afresh in every frame with variance `fresh · (1 + y / 8)`, plus per frame and row
/// a row offset of variance `row` (all ×256 in the integer noise).
fn samples(fixed: f64, row: f64, fresh: f64, seed: u64) -> SpatialSamples {
    let layout = FlatLayout::new(W, H, |i| i % W >= W / 3);
    let unit = Normal::new(0.0, 1.0).expect("normal");
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut s = SpatialSamples::new();
    for _ in 0..BURSTS {
        let constant: Vec<f64> =
            (0..W * H).map(|i| (fixed * (1.0 + (i / W) as f64 / 8.0)).sqrt() * unit.sample(&mut rng)).collect();
        for _ in 0..FRAMES {
            let rows: Vec<f64> = (0..H).map(|_| row.sqrt() * unit.sample(&mut rng)).collect();
            let noise: Vec<i32> = (0..W * H)
                .map(|i| {
                    let sd = ((1.0 + fresh) * (1.0 + (i / W) as f64 / 8.0)).sqrt();
                    // Scaled by 16 so that rounding to integers does not matter.
                    (16.0 * (sd * unit.sample(&mut rng) + constant[i] + rows[i / W])).round() as i32
                })
                .collect();
            s.add_frame(&layout, &noise);
        }
        s.end_burst();
    }
    s
}

#[test]
fn the_pixel_part_is_the_line_variance_of_independent_noise() {
    // Independent noise: the line-mean variance is the pixels' part, within sampling error
    // (40 bursts × 4 frames × 48 rows: relative SE about 2 %); a fixed part per burst is
    // in neither (both centre each pixel over its burst).
    let s = samples(0.5, 0.0, 0.0, 1);
    let (l, _) = s.row_var().expect("row variance");
    let p = LinePixelPart::mean(&s.line_pixels.rows).expect("pixel part");
    assert!((l / p - 1.0).abs() < 0.08, "rows: line variance {l:.5}, pixel part {p:.5}");
    let (l, _) = s.col_var().expect("col variance");
    let p = LinePixelPart::mean(&s.line_pixels.cols).expect("pixel part");
    assert!((l / p - 1.0).abs() < 0.08, "columns: line variance {l:.5}, pixel part {p:.5}");
    // Rows of 43 flat pixels with variances 1 … 6.9 (×256): the expectation is known (the
    // pixel part's relative SE is under 1 %: 40 × 3 degrees of freedom per pixel).
    let truth = 256.0 * (0..H).map(|y| (1.0 + y as f64 / 8.0) / 43.0).sum::<f64>() / H as f64;
    let p = LinePixelPart::mean(&s.line_pixels.rows).expect("pixel part");
    assert!((p / truth - 1.0).abs() < 0.03, "row pixel part {p:.4} vs truth {truth:.4}");
}

#[test]
fn on_the_real_pixels_a_fresh_pixel_error_is_no_line_noise_and_missing_row_noise_shows() {
    // The "synthetic" set draws the clean image's error afresh in every frame (its pixels vary
    // 25 % more); the plain ratio reads that as line noise, the ratio on the real pixels does
    // not.
    let real = samples(0.25, 0.0, 0.0, 2);
    let synth = samples(0.0, 0.0, 0.25, 3);
    let c = compare_spatial(&real, &synth, None);
    let (raw, on_real) = (c.row_var_ratio.expect("ratio"), c.row_var_ratio_on_real.expect("on real"));
    assert!(raw > 1.15, "plain ratio {raw:.3}");
    assert!((on_real - 1.0).abs() < 0.06, "ratio on the real pixels {on_real:.3}");
    // A sensor with row noise (as large as the pixels' part of a row) and a model without
    // it: the ratio on the real pixels is about a half, as the plain one; with it, about 1.
    let row = (0..H).map(|y| (1.0 + y as f64 / 8.0) / 43.0).sum::<f64>() / H as f64;
    let real = samples(0.0, row, 0.0, 4);
    let without = compare_spatial(&real, &samples(0.0, 0.0, 0.0, 5), None);
    let with = compare_spatial(&real, &samples(0.0, row, 0.0, 6), None);
    for (what, r, lo, hi) in [
        ("plain, without", without.row_var_ratio, 0.4, 0.6),
        ("on real, without", without.row_var_ratio_on_real, 0.4, 0.6),
        ("on real, with", with.row_var_ratio_on_real, 0.9, 1.1),
    ] {
        let r = r.expect("ratio");
        assert!((lo..hi).contains(&r), "{what} row noise: {r:.3}");
    }
}

#[test]
fn long_lines_are_sampled_without_bias() {
    // Rows of 1 024 flat pixels (16× the pixels a line keeps), variance 1 + x / 128 along the
    // row: the rows' part is the mean variance over 1 024², within 3 % (the sampled columns'
    // mean variance is 1.2 % below the row's; 30 bursts × 3 degrees of freedom × 8 rows × 64
    // pixels: 0.5 % of sampling error).
    let (w, h) = (1024usize, 8usize);
    let layout = FlatLayout::new(w, h, |_| true);
    let unit = Normal::new(0.0, 1.0).expect("normal");
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let mut s = SpatialSamples::new();
    for _ in 0..30 {
        for _ in 0..FRAMES {
            let noise: Vec<i32> = (0..w * h)
                .map(|i| (16.0 * (1.0 + (i % w) as f64 / 128.0).sqrt() * unit.sample(&mut rng)).round() as i32)
                .collect();
            s.add_frame(&layout, &noise);
        }
        s.end_burst();
    }
    let truth = 256.0 * (0..w).map(|x| 1.0 + x as f64 / 128.0).sum::<f64>() / w as f64 / w as f64;
    let p = LinePixelPart::mean(&s.line_pixels.rows).expect("pixel part");
    assert!((p / truth - 1.0).abs() < 0.03, "rows of 1 024: pixel part {p:.5} vs truth {truth:.5}");
}
