//! A whole calibration session at 12 MP (4032×3024) in one process: a reference burst of 8
//! frames and 8 target frames of one EV step pushed into a new session, then the pack built
//! (`finish`). No file I/O: what the core's calibration costs, start to end, as the process's
//! CPU time (user + system, all threads: on a shared machine the wall time measures the
//! neighbours; `/proc/self/stat`, so Linux only, 10 ms ticks against ~2 s a session). The same file
//! builds against older trees of the core (it uses only the session's public calls), so a
//! change's cost is compared on one benchmark:
//!
//!     cargo bench -p noisecal-core --bench calibration -- --save-baseline before
//!     (other tree)  cargo bench -p noisecal-core --bench calibration -- --baseline before

use std::hint::black_box;
use std::time::Duration;

use criterion::{Criterion, SamplingMode, Throughput, criterion_group, criterion_main};
use ndarray::Array2;
use noisecal_core::{CalibrationSession, CfaPattern, FrameMeta, FrameView, SensorLayout, SessionConfig};

const W: usize = 4032;
const H: usize = 3024;
/// Frames of the reference burst and target frames (distinct noise each).
const FRAMES: u64 = 8;

/// User + system CPU time of this process so far (Linux `/proc/self/stat`, 100 ticks per second).
fn cpu_seconds() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").expect("/proc/self/stat (Linux)");
    // Fields after the command name (in parentheses): utime and stime are the 12th and 13th.
    let rest = stat.rsplit_once(')').map(|(_, r)| r).expect("stat fields");
    let f: Vec<f64> = rest.split_whitespace().skip(11).take(2).map(|v| v.parse().expect("ticks")).collect();
    (f[0] + f[1]) / 100.0
}

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
    // One session per sample (each is seconds long): 10 samples, after one warm-up session.
    g.sample_size(10).sampling_mode(SamplingMode::Flat).warm_up_time(Duration::from_secs(1));
    g.measurement_time(Duration::from_secs(20));
    let calibrate = || {
        let mut session = CalibrationSession::new(layout(), SessionConfig::new(50)).expect("session");
        session.begin_step(exposure).expect("step");
        for f in &refs {
            session.push_frame(&FrameView::from_array(f).expect("view"), &ref_meta).expect("reference frame");
        }
        for f in &targets {
            session.push_frame(&FrameView::from_array(f).expect("view"), &tgt_meta).expect("target frame");
        }
        black_box(session.finish().expect("pack"));
    };
    g.bench_function("session: 8 reference + 8 target frames, finish (CPU time)", |b| {
        b.iter_custom(|iters| {
            let c0 = cpu_seconds();
            for _ in 0..iters {
                calibrate();
            }
            Duration::from_secs_f64(cpu_seconds() - c0)
        })
    });
    g.finish();
}

criterion_group!(calibration, benches);
criterion_main!(calibration);
