//! A whole calibration session at 12 MP (4032×3024) in one process: a reference burst of 8
//! frames and 8 target frames of one EV step pushed into a new session, then the pack built
//! (`finish`). No file I/O: what the core's calibration costs, start to end. The same file
//! builds against older trees of the core (it uses only the session's public calls), so a
//! change's cost is compared on one benchmark:
//!
//!     cargo bench -p noisecal-core --bench calibration -- --save-baseline before
//!     (other tree)  cargo bench -p noisecal-core --bench calibration -- --baseline before

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ndarray::Array2;
use noisecal_core::{CalibrationSession, CfaPattern, FrameMeta, FrameView, SensorLayout, SessionConfig};

const W: usize = 4032;
const H: usize = 3024;
/// Frames of the reference burst and target frames (distinct noise each).
const FRAMES: u64 = 8;

fn layout() -> SensorLayout {
    SensorLayout { width: W as u32, height: H as u32, cfa: CfaPattern::Rggb, black: [64.0; 4], white: 1023 }
}

/// A chart-like clean image: 12 × 9 flat patches over the 10-bit range.
fn clean() -> Array2<u16> {
    Array2::from_shape_fn((H, W), |(y, x)| {
        let p = (y * 9 / H) * 12 + x * 12 / W;
        64 + ((p * 37) % 108) as u16 * 8
    })
}

/// `clean` plus cheap pseudo-random noise of about ±`amp` DN.
fn noisy(clean: &Array2<u16>, seed: u64, amp: u32) -> Array2<u16> {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    clean.mapv(|c| {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        let n = (s % (2 * amp as u64 + 1)) as i32 - amp as i32;
        (c as i32 + n).clamp(0, 1023) as u16
    })
}

fn benches(c: &mut Criterion) {
    let clean = clean();
    let refs: Vec<Array2<u16>> = (0..FRAMES).map(|k| noisy(&clean, k, 2)).collect();
    let targets: Vec<Array2<u16>> = (0..FRAMES).map(|k| noisy(&clean, 100 + k, 12)).collect();
    let exposure = 10_000_000u64;
    let ref_meta = FrameMeta::new(50, exposure);
    let tgt_meta = FrameMeta::new(800, exposure / 16);

    let mut g = c.benchmark_group("calibration 12MP");
    g.throughput(Throughput::Elements((W * H) as u64 * 2 * FRAMES));
    g.sample_size(10);
    g.bench_function("session: 8 reference + 8 target frames, finish", |b| {
        b.iter(|| {
            let mut session = CalibrationSession::new(layout(), SessionConfig::new(50)).expect("session");
            session.begin_step(exposure).expect("step");
            for f in &refs {
                session.push_frame(&FrameView::from_array(f).expect("view"), &ref_meta).expect("reference frame");
            }
            for f in &targets {
                session.push_frame(&FrameView::from_array(f).expect("view"), &tgt_meta).expect("target frame");
            }
            black_box(session.finish().expect("pack"))
        })
    });
    g.finish();
}

criterion_group!(calibration, benches);
criterion_main!(calibration);
