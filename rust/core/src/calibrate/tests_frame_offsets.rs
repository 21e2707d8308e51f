//! The frame component's significance rule against known truth: sessions of many short bursts
//! (2–4 frames, as the random family's sensors 1, 3, 9 and 22 have), each burst a chart whose
//! line cells sit at their own fraction of the burst's level, with row noise and frame-to-frame
//! brightness jitter, fed to the accumulator as the line sums a capture would give; with no
//! frame offsets (the rule's false-positive rate) or with per-frame offsets of a known SD (its
//! power).

use rand::{RngExt, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use super::structure::{CELLS, FrameSums, StructureAccumulator};
use crate::model::layout::POSITIONS;

const W: usize = 96;
const H: usize = 72;

/// A session: burst levels above black and frames per burst; pixel variance `4 + 2·level` DN²
/// (a high-gain ISO), row noise of 0.5 DN².
struct Session {
    levels: Vec<f64>,
    frames: usize,
}

fn pixel_var(level: f64) -> f64 {
    4.0 + 2.0 * level
}

const ROW_VAR: f64 = 0.5;

/// What one trial measured of the frame component: whether it is significant, and the rule the
/// frame component had before (`own > 3·sampling·√(2/n)`, `n` the frames: their deviations
/// from their bursts' means taken as `n` independent values) applied to the same numbers.
struct Outcome {
    significant: bool,
    naive: bool,
    own: f64,
}

/// One trial: frame offsets of SD `frame_sd` (independent per position; 0: none).
fn trial(session: &Session, seed: u64, frame_sd: f64) -> Outcome {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let unit = Normal::new(0.0, 1.0).expect("normal");
    let mut acc = StructureAccumulator::default();
    let row_scale: Vec<[f64; CELLS]> = (0..H).map(|_| std::array::from_fn(|_| 0.5 + rng.random::<f64>())).collect();
    let col_scale: Vec<[f64; CELLS]> = (0..W).map(|_| std::array::from_fn(|_| 0.5 + rng.random::<f64>())).collect();
    for (step, &level) in session.levels.iter().enumerate() {
        for _ in 0..session.frames {
            let brightness = 1.0 + 0.002 * unit.sample(&mut rng);
            let frame: [f64; POSITIONS] = std::array::from_fn(|_| frame_sd * unit.sample(&mut rng));
            let rows: Vec<f64> = (0..H).map(|_| ROW_VAR.sqrt() * unit.sample(&mut rng)).collect();
            let row_sum: [f64; CELLS] = std::array::from_fn(|c| (c..H).step_by(CELLS).map(|y| rows[y]).sum());
            let mut sums = FrameSums::new(W, H, [0.0; 4]);
            let cell = |m: usize, clean: f64, offsets: f64, rng: &mut ChaCha8Rng| -> [i64; 3] {
                let m_f = m as f64;
                let n = m_f * clean * (brightness - 1.0) + offsets + (m_f * pixel_var(clean)).sqrt() * unit.sample(rng);
                [n.round() as i64, (m_f * clean).round() as i64, m as i64]
            };
            let m_row = W / CELLS;
            for y in 0..H {
                for c in 0..CELLS {
                    let offsets = m_row as f64 * (rows[y] + frame[(y & 1) * 2 + (c & 1)]);
                    sums.rows[y][c] = cell(m_row, level * row_scale[y][c], offsets, &mut rng);
                }
            }
            let m_col = H / CELLS;
            for x in 0..W {
                for c in 0..CELLS {
                    let offsets = row_sum[c] + m_col as f64 * frame[(c & 1) * 2 + (x & 1)];
                    sums.cols[x][c] = cell(m_col, level * col_scale[x][c], offsets, &mut rng);
                }
            }
            acc.add_frame(step as u32, &sums);
        }
    }
    // The ISO's lowest pixel variance: the darkest level's (the family's sensor 1 reports
    // 2.25 DN² there, far below its frame offsets' sampling variance, so the relevance floor
    // does not hold the rule's false positives back).
    let st = acc.structure(1250, pixel_var(0.0));
    let f = st.frames.as_ref().expect("frame offsets measured");
    let n = f.offsets.len() as f64;
    let naive = (0..POSITIONS).any(|p| {
        let own = f.measured_var[p] - f.sampling_var[p];
        own > 3.0 * f.sampling_var[p] * (2.0 / n).sqrt() && own >= 0.01 * pixel_var(0.0)
    });
    let own = (0..POSITIONS).map(|p| f.variance(p)).sum::<f64>() / POSITIONS as f64;
    Outcome { significant: st.frame().is_some(), naive, own }
}

/// Sensor 1's session: 2-frame bursts at 24 levels from 200 to 900 DN above black.
fn dense_pairs() -> Session {
    Session { levels: (0..24).map(|i| 200.0 + 700.0 * i as f64 / 23.0).collect(), frames: 2 }
}

/// Sensor 3's and 22's: 3-frame bursts at 9 levels from near black to a third of the range.
fn sparse_triples() -> Session {
    Session { levels: vec![2.0, 4.0, 9.0, 17.0, 39.0, 71.0, 132.0, 184.0, 292.0], frames: 3 }
}

/// No frame offsets: the component is found at most at the rule's stated rate (0.13 % per
/// position, four positions: at most 0.54 % of trials) — at most 4 of 300 trials per session
/// kind (expected ≤ 1.6; measured 0 and 0). The rule before (`naive`: the frames' deviations
/// counted as `n` independent values where their spread has `Σ(k − 1)` degrees of freedom, a
/// normal approximation to a `χ²` with few of them, and the sandwich variance without its
/// leverage correction) found it in 200 of 300 trials of 2-frame bursts and 48 of 300 of
/// 3-frame bursts.
#[test]
fn no_frame_offsets_are_found_at_the_stated_rate() {
    for (name, session) in [("2-frame bursts", dense_pairs()), ("3-frame bursts", sparse_triples())] {
        let trials = 300;
        let (mut found, mut naive, mut own) = (0, 0, 0.0);
        for t in 0..trials {
            let o = trial(&session, 7000 + t, 0.0);
            found += o.significant as usize;
            naive += o.naive as usize;
            own += o.own / trials as f64;
        }
        println!(
            "{name}, no frame offsets: {found} of {trials} found; the rule before: {naive}; mean estimate {own:.4} DN²"
        );
        assert!(found <= 4, "{name}: {found} of {trials} sessions without frame offsets got them");
        assert!(
            naive > 2 * found.max(2),
            "{name}: the rule before found only {naive}: the test cannot tell the rules apart"
        );
    }
}

/// Frame offsets of SD 0.3× the pixel SD at black (0.6 DN), in sessions of 3-frame bursts from
/// 2 to 292 DN: found in at least 75 of 100 sessions (measured 86; the test's variance is the
/// leverage-corrected one, a little above the truth, so it is conservative) and their variance
/// within 25 % on average (measured 0.373 DN² against 0.36). A rule blind to them (never
/// significant) scores 0.
#[test]
fn frame_offsets_are_found() {
    let sd = 0.3 * pixel_var(0.0).sqrt();
    let trials = 100;
    let (mut found, mut own) = (0, 0.0);
    for t in 0..trials {
        let o = trial(&sparse_triples(), 9100 + t, sd);
        found += o.significant as usize;
        own += o.own / trials as f64;
    }
    println!("frame SD {sd:.2} DN: found in {found} of {trials}; mean variance {own:.4} against {:.4}", sd * sd);
    assert!(found >= 75, "frame offsets of SD {sd:.2} DN found in {found} of {trials}");
    assert!((own / (sd * sd) - 1.0).abs() < 0.25, "frame variance {own:.4} against {:.4}", sd * sd);
}
