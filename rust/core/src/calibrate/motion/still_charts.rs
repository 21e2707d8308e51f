//! Registration on charts of flat patches with hard one-pixel steps and with blurred edges, in
//! every CFA order: a still frame registers as still (no shift, no sample left out), and a known
//! sub-pixel shift is recovered.
//!
//! The chart is like the JNI test kit's (8 × 6 patches of 40 px, shot and read noise, 10 bits at
//! black 64, patch levels in another order), each pixel the area integral of the scene over its
//! square, so a hard step shifted by a fraction of a pixel mixes the two levels in one pixel as a
//! sensor does.

use super::*;
use crate::calibrate::flat::{FlatReport, Groups};
use crate::model::layout::{CfaColor, SensorLayout};
use crate::{CfaPattern, FrameMeta};

const W: usize = 320;
const H: usize = 240;
const BLACK: f64 = 64.0;
/// Reference burst's frames.
const FRAMES: u32 = 6;
/// DN per electron at the reference ISO; read noise variance there (DN²).
const GAIN: f64 = 0.4;
const READ_VAR: f64 = 1.44;

/// The patches' levels: rising along the rows and down the chart (the JNI test kit's: every
/// horizontal step of the chart is the same), or in an order no row or column follows (a colour
/// chart's).
#[derive(Debug, Clone, Copy)]
enum Order {
    Rising,
    Shuffled,
}

/// How the patches' edges look: hard steps (a pixel's value is its area's mean) or blurred.
#[derive(Debug, Clone, Copy)]
enum Edges {
    Hard,
    /// tanh edges of this width (pixels).
    Blurred(f64),
}

/// A chart: its levels' order and its edges.
#[derive(Debug, Clone, Copy)]
struct Chart(Order, Edges);

/// Per patch along one axis (`n` patches over `len` pixels), its share of the pixel
/// `[t, t + 1)` (hard) or its smoothed membership there (blurred).
fn shares(t: f64, n: usize, len: usize, edges: Edges) -> Vec<f64> {
    let size = len as f64 / n as f64;
    // How much of the pixel lies past the step at `at`.
    let past = |at: f64| match edges {
        Edges::Hard => (t + 1.0 - at).clamp(0.0, 1.0),
        Edges::Blurred(b) => 0.5 * (1.0 + ((t + 0.5 - at) / b).tanh()),
    };
    (0..n)
        .map(|k| {
            let from = if k == 0 { 1.0 } else { past(k as f64 * size) };
            let to = if k + 1 == n { 0.0 } else { past((k + 1) as f64 * size) };
            from - to
        })
        .collect()
}

/// Signal (DN above black at the reference gain) of the pixel whose square starts at `(x, y)`
/// for a site of sensitivity `site`: 8 × 6 patches at 2–82 % of the range.
fn signal(x: f64, y: f64, site: f64, chart: Chart) -> f64 {
    let Chart(order, edges) = chart;
    let (sx, sy) = (shares(x, 8, W, edges), shares(y, 6, H, edges));
    let mut v = 0.0;
    for (j, wy) in sy.iter().enumerate() {
        for (i, wx) in sx.iter().enumerate() {
            let patch = match order {
                Order::Rising => (j * 8 + i) as f64,
                Order::Shuffled => ((i * 5 + j * 11) % 48) as f64,
            };
            v += wx * wy * (0.02 + 0.8 * patch / 47.0);
        }
    }
    v * site * (1023.0 - BLACK)
}

/// Per position, the site's sensitivity in this CFA order (red 0.7, green 1, blue 0.55).
fn sites(cfa: CfaPattern) -> [f64; POSITIONS] {
    cfa.colors().map(|c| match c {
        CfaColor::Red => 0.7,
        CfaColor::Green => 1.0,
        CfaColor::Blue => 0.55,
    })
}

/// An Irwin–Hall normal deviate (mean 0, variance 1) from one hash, as the JNI test kit makes.
fn normalish(k: u64) -> f64 {
    let mut z = k.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    let s = (z & 0xFFFF) + ((z >> 16) & 0xFFFF) + ((z >> 32) & 0xFFFF) + (z >> 48);
    (s as f64 / 65536.0 - 2.0) * 3.0f64.sqrt()
}

/// One frame moved by `(sx, sy)` px, at `iso_gain` times the reference ISO (same brightness:
/// shorter exposure), noise from `seed`.
fn frame(cfa: CfaPattern, chart: Chart, sx: f64, sy: f64, iso_gain: f64, seed: u64) -> Vec<u16> {
    let site = sites(cfa);
    let (g, read) = (GAIN * iso_gain, READ_VAR * iso_gain);
    (0..H)
        .flat_map(|y| {
            (0..W).map(move |x| {
                let s = signal(x as f64 + sx, y as f64 + sy, site[position(y, x)], chart);
                let sd = (s * g + read).sqrt();
                let k = seed.wrapping_mul(0x0000_0100_0000_01B3) ^ (y * W + x) as u64;
                (BLACK + s + sd * normalish(k)).round().clamp(0.0, 1023.0) as u16
            })
        })
        .collect()
}

/// The probe of a still reference burst of [`FRAMES`] frames (flat: 3 px or more inside a patch).
fn probe(cfa: CfaPattern, chart: Chart) -> MotionProbe {
    let mut sum = vec![0u32; W * H];
    for k in 0..FRAMES as u64 {
        for (s, v) in sum.iter_mut().zip(frame(cfa, chart, 0.0, 0.0, 1.0, 1000 + k)) {
            *s += v as u32;
        }
    }
    let mean: Vec<u16> = sum.iter().map(|&s| (s as f64 / FRAMES as f64).round() as u16).collect();
    let levels: Vec<u16> = mean
        .iter()
        .enumerate()
        .map(|(i, &m)| {
            let (ex, ey) = ((i % W) % 40, (i / W) % 40);
            if (3..=36).contains(&ex) && (3..=36).contains(&ey) { m } else { NOT_FLAT }
        })
        .collect();
    let groups = Groups { black: [BLACK as f32; POSITIONS], white: 1023 };
    let mut flat = FlatReport::default();
    // Noise of the burst's mean: one frame's (read + shot) over the frames.
    let f = FRAMES as f64;
    flat.mean_noise = [[READ_VAR / f, GAIN / f, 0.0]; POSITIONS];
    flat.mean_noise_groups = vec![f32::NAN; POSITIONS * crate::calibrate::flat::GROUPS];
    MotionProbe::new(mean, &levels, W, H, FRAMES, &flat, &groups, 1000.0)
}

fn transform(cfa: CfaPattern) -> Transform {
    let layout = SensorLayout { width: W as u32, height: H as u32, cfa, black: [BLACK as f32; POSITIONS], white: 1023 };
    Transform::of(&layout, &FrameMeta { iso: 100, exposure_ns: 1, black: None }, 1.0)
}

/// Flat samples the motion leaves out of a frame, over all flat samples.
fn left_out_share(probe: &MotionProbe, m: &FrameMotion) -> f64 {
    let (mut keep, mut correction) = (vec![true; W], vec![0i32; W]);
    let (mut flat, mut left) = (0usize, 0usize);
    // The probe's mean stands for the clean levels; only flat pixels count.
    let levels: Vec<u16> = (0..W * H)
        .map(|i| {
            let (ex, ey) = ((i % W) % 40, (i / W) % 40);
            let flat = (3..=36).contains(&ex) && (3..=36).contains(&ey);
            if flat { probe.mean[i] } else { NOT_FLAT }
        })
        .collect();
    let gradient = probe.gradients(&levels, W);
    for y in 0..H {
        let row = &levels[y * W..(y + 1) * W];
        m.row_effects(probe, &gradient[y * W..(y + 1) * W], y, row, &mut keep, &mut correction);
        flat += row.iter().filter(|&&c| c != NOT_FLAT).count();
        left += keep.iter().zip(row).filter(|&(&k, &c)| !k && c != NOT_FLAT).count();
    }
    left as f64 / flat as f64
}

/// Hard and blurred edges, both orders of levels.
const CHARTS: [Chart; 6] = [
    Chart(Order::Rising, Edges::Hard),
    Chart(Order::Rising, Edges::Blurred(0.7)),
    Chart(Order::Rising, Edges::Blurred(1.5)),
    Chart(Order::Shuffled, Edges::Hard),
    Chart(Order::Shuffled, Edges::Blurred(0.7)),
    Chart(Order::Shuffled, Edges::Blurred(1.5)),
];

/// Still frames at 1, 2 and 4 × the reference ISO register as still on hard and blurred edges
/// in every CFA order. Before the warp's gradient and the likelihood ratio took the clean
/// image's own noise into account, the hard chart "moved" 0.8–1.2 px (the interpolated mean is
/// smoothest half-way between lattice nodes, and a hard step tells only the pixel beside it).
#[test]
fn still_frames_register_as_still_on_hard_and_blurred_edges() {
    let mut worst: f64 = 0.0;
    let mut worst_left: f64 = 0.0;
    for cfa in CfaPattern::ALL {
        let tf = transform(cfa);
        for chart in CHARTS {
            let probe = probe(cfa, chart);
            for (k, iso_gain) in [1.0, 2.0, 4.0, 1.0, 2.0].into_iter().enumerate() {
                let f = frame(cfa, chart, 0.0, 0.0, iso_gain, 7 + k as u64);
                let view = FrameView::from_u16(&f, W, H, W).expect("view");
                let m = register(&probe, &view, &tf, W, H, 1000.0, FRAMES).expect("registered");
                let shift = m.max_shift();
                let left = left_out_share(&probe, &m);
                assert!(shift < 0.05, "{cfa:?} {chart:?} ×{iso_gain}: a still frame moved {shift:.3} px");
                assert!(left < 1e-3, "{cfa:?} {chart:?} ×{iso_gain}: {:.2} % of flat samples left out", 100.0 * left);
                worst = worst.max(shift);
                worst_left = worst_left.max(left);
            }
        }
    }
    eprintln!("still: worst shift {worst:.4} px, worst share left out {worst_left:.5}");
}

/// A known sub-pixel shift is recovered within 15 % (+ 0.02 px), the motion model's accuracy,
/// on the colour chart with edges blurred over 1.5 px: every component found is within that, and
/// at most one in sixteen is left out (set to 0 when the fits on alternate row pairs disagree by
/// more than half of it: one vertical shift of 0.35 px in Gbrg, its halves at 0.47 and 0.29).
/// (Not on the rising chart: each of its horizontal steps is the same along the whole row, so a
/// vertical shift there is a row offset, which the fit takes out of every row. On steps sharper
/// than about a pixel the bilinear model on a colour's 2-px lattice misses a moved edge's pixels
/// by half the shift times the step, the robust fit takes them for outliers, and the frame
/// registers as still or with a component dropped: its moved samples near edges are then not
/// left out. docs/method.md, "Motion between frames".)
#[test]
fn known_shifts_are_recovered_on_blurred_edges() {
    let tol = |t: f64| 0.15 * t.abs() + 0.02;
    let chart = Chart(Order::Shuffled, Edges::Blurred(1.5));
    let (mut worst, mut dropped, mut components) = (0.0f64, 0, 0);
    for cfa in CfaPattern::ALL {
        let tf = transform(cfa);
        let probe = probe(cfa, chart);
        for (k, (tx, ty)) in [(0.3, -0.2), (-0.45, 0.35), (0.15, 0.6), (-0.7, -0.1)].into_iter().enumerate() {
            let f = frame(cfa, chart, tx, ty, 1.0, 50 + k as u64);
            let view = FrameView::from_u16(&f, W, H, W).expect("view");
            let m = register(&probe, &view, &tf, W, H, 1000.0, FRAMES).expect("registered");
            let u = m.at(W as f64 / 2.0, H as f64 / 2.0);
            for (found, truth) in [(u[0], tx), (u[1], ty)] {
                components += 1;
                if found == 0.0 {
                    dropped += 1;
                    continue;
                }
                worst = worst.max((found - truth).abs());
                assert!((found - truth).abs() < tol(truth), "{cfa:?}: shift {u:?} vs ({tx}, {ty})");
            }
            // The field is a translation: nothing at the corners beyond it.
            let corner = m.at(0.0, 0.0);
            assert!((corner[0] - u[0]).abs() < 0.03 && (corner[1] - u[1]).abs() < 0.03, "{cfa:?}: {corner:?} vs {u:?}");
        }
    }
    eprintln!("shifts: worst error {worst:.4} px, {dropped} of {components} components left out");
    assert!(dropped * 16 <= components, "{dropped} of {components} shift components left out");
}
