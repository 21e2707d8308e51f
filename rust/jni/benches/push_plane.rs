//! The app's frame push at 12 MP (4032 × 3024): `NativeSession::push_plane`, the entry the
//! Kotlin `NoisecalSession.pushFrame` reaches through the JNI layer, on Camera2-like planes
//! (little-endian bytes, rows padded by 64 bytes), for reference frames and for target frames
//! (registration included). No JVM: the JNI functions only hand the plane's bytes to this call.
//! Run with `cargo bench -p noisecal-jni --bench push_plane`; with `NOISECAL_BENCH_LOOP=n`,
//! instead n planes of each in a plain loop, wall and CPU time per plane (as the core's
//! accumulation bench: on a shared machine CPU time compares two builds where wall time measures
//! the neighbours).

#[path = "../../core/benches/support/mod.rs"]
mod support;
use support::cpu_seconds;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use noisecal_jni::session::{CreateParams, NativeSession, PlaneParams};

const W: usize = 4032;
const H: usize = 3024;
const STRIDE: usize = W * 2 + 64;
const BLACK: [f32; 4] = [64.0; 4];
/// Planes of the target planes' reference burst (distinct noise each).
const REFERENCE_BURST: usize = 8;

/// A chart-like plane: 12 × 9 flat 10-bit patches plus cheap pseudo-random noise of about
/// ±`amp` DN, as the core's accumulation bench draws it.
fn plane(seed: u64, amp: u32) -> Vec<u8> {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    let mut out = vec![0u8; STRIDE * H];
    for y in 0..H {
        for x in 0..W {
            let p = (y * 9 / H) * 12 + x * 12 / W;
            let c = 64 + ((p * 37) % 108) as i32 * 8;
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let n = (s % (2 * amp as u64 + 1)) as i32 - amp as i32;
            let v = (c + n).clamp(0, 1023) as u16;
            out[y * STRIDE + 2 * x..y * STRIDE + 2 * x + 2].copy_from_slice(&v.to_le_bytes());
        }
    }
    out
}

fn params(iso: i32, exposure_ns: i64) -> PlaneParams<'static> {
    PlaneParams {
        width: W as i32,
        height: H as i32,
        row_stride: STRIDE as i32,
        pixel_stride: 2,
        iso,
        exposure_ns,
        black: Some(&BLACK),
    }
}

fn benches(c: &mut Criterion) {
    let refs: Vec<Vec<u8>> = (0..REFERENCE_BURST as u64).map(|k| plane(k, 2)).collect();
    let targets: Vec<Vec<u8>> = (0..4).map(|k| plane(100 + k, 12)).collect();
    let exposure = 10_000_000i64;
    let (ref_params, tgt_params) = (params(50, exposure), params(800, exposure / 16));
    let create = || {
        let mut s = NativeSession::create(&CreateParams {
            width: W as i32,
            height: H as i32,
            cfa: "RGGB",
            black: &BLACK,
            white: 1023,
            reference_iso: 50,
            make: "bench",
            model: "bench",
            bin_width: 0,
        })
        .expect("session");
        s.begin_step(exposure).expect("step");
        s
    };
    // Reference planes are measured on a session of their own, so that the target planes' clean
    // image is always that of the same burst, however many reference planes were pushed.
    let (mut references, mut session) = (create(), create());
    for p in &refs {
        references.push_plane(p, &ref_params).expect("push");
        session.push_plane(p, &ref_params).expect("push");
    }

    if let Some(n) = std::env::var("NOISECAL_BENCH_LOOP").ok().and_then(|s| s.parse::<usize>().ok()) {
        let threads = std::thread::available_parallelism().map_or(1, |t| t.get());
        let threads = std::env::var("RAYON_NUM_THREADS").ok().and_then(|s| s.parse().ok()).unwrap_or(threads);
        let per_plane = |what: &str, t0: std::time::Instant, c0: f64| {
            let (wall, cpu) = (t0.elapsed().as_secs_f64() / n as f64, (cpu_seconds() - c0) / n as f64);
            let mpix = (W * H) as f64 / 1e6;
            println!(
                "JNI push, {what}: {n} planes on {threads} thread(s): wall {:.1} ms ({:.0} Mpix/s), cpu {:.1} ms ({:.0} Mpix/s per thread)",
                wall * 1e3,
                mpix / wall,
                cpu * 1e3,
                mpix / cpu
            );
        };
        let (t0, c0) = (std::time::Instant::now(), cpu_seconds());
        for k in 0..n {
            references.push_plane(&refs[k % refs.len()], &ref_params).expect("push");
        }
        per_plane("reference plane", t0, c0);
        session.push_plane(&targets[0], &tgt_params).expect("push");
        let (t0, c0) = (std::time::Instant::now(), cpu_seconds());
        for k in 0..n {
            session.push_plane(&targets[k % targets.len()], &tgt_params).expect("push");
        }
        per_plane("target plane", t0, c0);
        return;
    }
    let mut g = c.benchmark_group("JNI push 12MP");
    g.throughput(Throughput::Elements((W * H) as u64));
    g.sample_size(10);
    let mut k = 0;
    g.bench_function("reference plane", |b| {
        b.iter(|| {
            k += 1;
            references.push_plane(&refs[k % refs.len()], &ref_params).expect("push")
        })
    });
    // The first target closes the reference burst (clean image and flat mask).
    session.push_plane(&targets[0], &tgt_params).expect("push");
    let mut k = 0;
    g.bench_function("target plane", |b| {
        b.iter(|| {
            k += 1;
            session.push_plane(&targets[k % targets.len()], &tgt_params).expect("push")
        })
    });
    g.finish();
}

criterion_group!(push, benches);
criterion_main!(push);
