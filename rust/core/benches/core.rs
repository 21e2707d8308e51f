//! Throughput on a 4032×3024 (12 MP) frame (with `NOISECAL_BENCH_LOOP=n`, instead n frames of
//! reference and of target accumulation in a plain loop, wall and CPU time per frame): reference accumulation, target accumulation,
//! the estimator (one ISO, and one wide sparse position), synthesis on 1 and 2 threads, pack load. Run with `cargo bench -p noisecal-core`.

mod support;
use support::cpu_seconds;

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ndarray::Array2;
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::synthesize;
use noisecal_core::{CalibrationSession, CfaPattern, FrameMeta, FrameView, ModelPack, SensorLayout, SessionConfig};

const W: usize = 4032;
const H: usize = 3024;
/// Frames of the target frames' reference burst (distinct noise each).
const REFERENCE_BURST: usize = 8;

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
    let refs: Vec<Array2<u16>> = (0..REFERENCE_BURST as u64).map(|k| noisy(&clean, k, 2)).collect();
    let targets: Vec<Array2<u16>> = (0..4).map(|k| noisy(&clean, 100 + k, 12)).collect();
    let exposure = 10_000_000u64;
    let ref_meta = FrameMeta::new(50, exposure);
    let tgt_meta = FrameMeta::new(800, exposure / 16);

    let mut g = c.benchmark_group("12MP");
    g.throughput(Throughput::Elements((W * H) as u64));
    g.sample_size(10);

    // Reference frames are measured on a session of their own, so that the target frames' clean
    // image (and flat mask) is always that of the same burst, however many reference frames the
    // reference measurement pushed.
    let mut references = CalibrationSession::new(layout(), SessionConfig::new(50)).expect("session");
    references.begin_step(exposure).expect("step");
    let mut session = CalibrationSession::new(layout(), SessionConfig::new(50)).expect("session");
    session.begin_step(exposure).expect("step");
    for f in &refs {
        references.push_frame(&FrameView::from_array(f).expect("view"), &ref_meta).expect("push");
        session.push_frame(&FrameView::from_array(f).expect("view"), &ref_meta).expect("push");
    }
    if let Some(n) = std::env::var("NOISECAL_BENCH_LOOP").ok().and_then(|s| s.parse::<usize>().ok()) {
        // A plain loop with the process's CPU time as well as the wall time per frame: on a
        // shared machine CPU time compares two builds where wall time measures the neighbours.
        let threads = rayon::current_num_threads();
        let per_frame = |what: &str, t0: std::time::Instant, c0: f64| {
            let (wall, cpu) = (t0.elapsed().as_secs_f64() / n as f64, (cpu_seconds() - c0) / n as f64);
            let mpix = (W * H) as f64 / 1e6;
            println!(
                "{what}: {n} frames on {threads} thread(s): wall {:.1} ms ({:.0} Mpix/s), cpu {:.1} ms ({:.0} Mpix/s per thread)",
                wall * 1e3,
                mpix / wall,
                cpu * 1e3,
                mpix / cpu
            );
        };
        let (t0, c0) = (std::time::Instant::now(), cpu_seconds());
        for k in 0..n {
            references
                .push_frame(&FrameView::from_array(&refs[k % refs.len()]).expect("view"), &ref_meta)
                .expect("push");
        }
        per_frame("reference accumulation", t0, c0);
        session.push_frame(&FrameView::from_array(&targets[0]).expect("view"), &tgt_meta).expect("push");
        let (t0, c0) = (std::time::Instant::now(), cpu_seconds());
        for k in 0..n {
            session
                .push_frame(&FrameView::from_array(&targets[k % targets.len()]).expect("view"), &tgt_meta)
                .expect("push");
        }
        per_frame("target accumulation", t0, c0);
        return;
    }
    let mut k = 0;
    g.bench_function("reference accumulation", |b| {
        b.iter(|| {
            let f = &refs[k % refs.len()];
            k += 1;
            references.push_frame(&FrameView::from_array(f).expect("view"), &ref_meta).expect("push")
        })
    });
    // The first target closes the reference burst (clean image and flat mask).
    session.push_frame(&FrameView::from_array(&targets[0]).expect("view"), &tgt_meta).expect("push");
    let mut k = 0;
    g.bench_function("target accumulation", |b| {
        b.iter(|| {
            let f = &targets[k % targets.len()];
            k += 1;
            session.push_frame(&FrameView::from_array(f).expect("view"), &tgt_meta).expect("push")
        })
    });
    // Camera2-like plane: little-endian bytes with padded rows.
    let stride = W * 2 + 64;
    let mut plane = vec![0u8; stride * H];
    for (y, row) in targets[1].rows().into_iter().enumerate() {
        for (x, v) in row.iter().enumerate() {
            plane[y * stride + 2 * x..y * stride + 2 * x + 2].copy_from_slice(&v.to_le_bytes());
        }
    }
    g.bench_function("target accumulation, padded byte plane", |b| {
        b.iter(|| {
            let v = FrameView::from_le_bytes(&plane, W, H, stride, 2).expect("view");
            session.push_frame(&v, &tgt_meta).expect("push")
        })
    });

    g.finish();

    // The estimator: cross-validated pooling, law, clip modes, for one ISO's four positions.
    let mut g = c.benchmark_group("estimate");
    g.sample_size(10);
    g.bench_function("finish (1 ISO, 4 positions, 4 folds)", |b| b.iter(|| session.finish().expect("pack")));
    // A wide noise distribution (σ ≈ 60 DN, 240 bins × ~720 values) with sparse bins.
    let wide: Vec<Vec<noisecal_core::model::histogram::NoiseHistogram>> = (0..4)
        .map(|f| {
            (0..240)
                .map(|bin| {
                    let mut h = noisecal_core::model::histogram::NoiseHistogram::default();
                    let n = if bin % 3 == 0 { 4000 } else { 40 };
                    let mut s = ((f * 1000 + bin) as u64 * 0x9E37_79B9_7F4A_7C15) | 1;
                    for _ in 0..n {
                        let mut z = 0i32;
                        for _ in 0..12 {
                            s ^= s << 13;
                            s ^= s >> 7;
                            s ^= s << 17;
                            z += (s % 41) as i32 - 20;
                        }
                        h.add(z);
                    }
                    h
                })
                .collect()
        })
        .collect();
    let folds: Vec<&[noisecal_core::model::histogram::NoiseHistogram]> = wide.iter().map(|f| f.as_slice()).collect();
    let levels = noisecal_core::model::bin_levels::BinLevels::new(&noisecal_core::Binning::new(&layout(), 4), 0);
    g.bench_function("one position, σ ≈ 60 DN, sparse", |b| {
        b.iter(|| {
            noisecal_core::calibrate::estimate::estimate_position(
                black_box(&folds),
                &[],
                &levels,
                noisecal_core::calibrate::estimate::Pooling::Auto,
            )
        })
    });
    g.finish();

    let mut g = c.benchmark_group("12MP");
    g.throughput(Throughput::Elements((W * H) as u64));
    g.sample_size(10);
    let pack = session.finish().expect("pack");
    let bytes = pack.to_bytes().expect("bytes");
    let sampler = IsoSampler::new(&pack, &pack.isos[0]);
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        g.bench_function(format!("synthesis, {threads} thread(s)"), |b| {
            b.iter(|| pool.install(|| synthesize(&sampler, black_box(clean.view()), 7)))
        });
    }
    // The same pack with row offsets (1 DN RMS) and frame offsets (0.5 DN RMS) per ISO.
    let mut spack = pack.clone();
    let row = noisecal_core::model::structure::OffsetDistribution {
        quantiles: (0..513).map(|i| (i as f32 / 512.0 - 0.5) * 3.46).collect(),
        count: 100_000,
        measured_var: 1.0,
        sampling_var: 0.0,
        significant: true,
    };
    let frames = noisecal_core::model::structure::FrameOffsets {
        offsets: (0..32).map(|i| [((i % 7) as f32 - 3.0) * 0.25; 4]).collect(),
        measured_var: [0.25; 4],
        sampling_var: [0.0; 4],
        significant: true,
    };
    spack.structure = pack
        .isos
        .iter()
        .map(|m| noisecal_core::model::structure::IsoStructure {
            iso: m.iso,
            rows: [Some(row.clone()), Some(row.clone())],
            columns: [None, None],
            frames: Some(frames.clone()),
            frames_used: 32,
            fpn: None,
        })
        .collect();
    let structured = IsoSampler::new(&spack, &spack.isos[0]);
    assert!(structured.structure().is_some());
    for threads in [1usize, 2] {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
        g.bench_function(format!("synthesis with row and frame offsets, {threads} thread(s)"), |b| {
            b.iter(|| pool.install(|| synthesize(&structured, black_box(clean.view()), 7)))
        });
    }
    g.finish();

    let mut g = c.benchmark_group("pack");
    g.bench_function("sampler tables with row and frame offsets (deconvolution)", |b| {
        b.iter(|| IsoSampler::new(black_box(&spack), &spack.isos[0]))
    });
    g.throughput(Throughput::Bytes(bytes.len() as u64));
    g.bench_function("load + sampler tables", |b| {
        b.iter(|| {
            let p = ModelPack::from_bytes(black_box(&bytes)).expect("pack");
            IsoSampler::new(&p, &p.isos[0])
        })
    });
    g.finish();
    eprintln!(
        "pack: {} bytes for {} ISO(s); checkpoint of a 12 MP session in its target phase: {} bytes",
        bytes.len(),
        pack.isos.len(),
        session.checkpoint().map(|c| c.len()).unwrap_or(0)
    );
}

criterion_group!(core, benches);
criterion_main!(core);
