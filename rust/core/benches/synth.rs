//! In-memory synthesis of a 12 MP frame through the whole-image entry point the Python binding
//! calls (`Pack.synth` → `synthesize_at` on rayon's global pool, i.e. all cores), on the pack, ISO
//! and clean image of the package's benchmark (`rust/python/tests/test_bench.py`), so that the
//! Mpix/s of both are comparable. Also on one thread (a pool of one), for the per-thread figure.
//!
//! The pack is a file: `NOISECAL_BENCH_PACK=path` (ISO from `NOISECAL_BENCH_ISO`, default 800).
//! `rust/python/benches/throughput.py` makes the pack, runs this bench, the pytest benchmarks and
//! the vectorised numpy sampler in one run, and prints the table. Without the variable the bench
//! says so and measures nothing.
//!
//!     NOISECAL_BENCH_PACK=bench.pack cargo bench -p noisecal-core --bench synth
//!
//! "pattern not kept" keeps no fixed pattern between calls (`with_pattern_cache_bytes(0)`): each
//! frame computes it in its offsets pass, as a single image does (`noisecal synth` of one file).
//!
//! "sampler build" times building the sampler (default components and pixel-only, and the
//! default components for clean images at the target brightness) on its own.
//!
//! With `NOISECAL_BENCH_LOOP=n` it instead times n frames in a plain loop and prints the wall and
//! the process CPU time per frame (for `rust/python/benches/interleaved.py --cpu`).

mod support;
use support::cpu_seconds;

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use ndarray::Array2;
use noisecal_core::ModelPack;
use noisecal_core::derive::interp::model_for;
use noisecal_core::model::structure::Components;
use noisecal_core::resolve::{ModelKind, sampler_for};
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::{CleanAt, synthesize_at};

/// 12 MP, as `test_bench.py`.
const H: usize = 3000;
const W: usize = 4000;

/// The clean image of `test_bench.py`: a horizontal ramp `64 + x·936 / (W − 1)`, every row alike.
fn clean() -> Array2<u16> {
    Array2::from_shape_fn((H, W), |(_, x)| (64 + x * 936 / (W - 1)) as u16)
}

fn benches(c: &mut Criterion) {
    let Ok(path) = std::env::var("NOISECAL_BENCH_PACK") else {
        eprintln!(
            "synth bench: set NOISECAL_BENCH_PACK to a .pack file (rust/python/benches/throughput.py makes one); nothing measured"
        );
        return;
    };
    let iso: u32 = std::env::var("NOISECAL_BENCH_ISO").ok().and_then(|s| s.parse().ok()).unwrap_or(800);
    let bytes = std::fs::read(&path).unwrap_or_else(|e| panic!("cannot read {path}: {e}"));
    let pack = ModelPack::from_bytes(&bytes).expect("pack");
    // What `Pack.synth(model="noisecal")` builds (noisecal_core::resolve::resolve_model → model_for).
    let (model, _) = model_for(&pack, iso, false).expect("model");
    let sampler = IsoSampler::new(&pack, &model);
    // `Pack.synth(components="pixel")`: the pixel-independent model alone, the yardstick of the
    // default components' cost.
    let pixel = IsoSampler::with_components(&pack, &model, Components::PIXEL);
    // Nothing kept between calls: every frame computes the fixed pattern in its offsets pass,
    // as a single image (the CLI's) does.
    let unkept = IsoSampler::new(&pack, &model).with_pattern_cache_bytes(0);
    let clean = clean();
    let threads = rayon::current_num_threads();
    if let Some(n) = std::env::var("NOISECAL_BENCH_LOOP").ok().and_then(|s| s.parse::<u32>().ok()) {
        // A plain loop, with the process's CPU time as well as the wall time: on a shared machine
        // CPU time per frame compares two builds where wall time mostly measures the neighbours.
        let cases =
            [("default components", &sampler), ("components=pixel", &pixel), ("default, pattern not kept", &unkept)];
        for (what, sampler) in cases {
            synthesize_at(sampler, clean.view(), 1, (0, 0));
            let (t0, c0) = (std::time::Instant::now(), cpu_seconds());
            for _ in 0..n {
                black_box(synthesize_at(sampler, black_box(clean.view()), 1, (0, 0)));
            }
            let (wall, cpu) = (t0.elapsed().as_secs_f64() / n as f64, (cpu_seconds() - c0) / n as f64);
            println!(
                "loop {n} × {H}×{W} on {threads} threads, {what}: wall {:.2} ms, cpu {:.2} ms per frame",
                wall * 1e3,
                cpu * 1e3
            );
        }
        return;
    }

    // The sampler build alone (what `noisecal synth` does once per run before the first image,
    // and `Pack.synth` once per pack and ISO): the structured components' deconvolution of every
    // bin, the fine levels near black, the tables.
    let mut g = c.benchmark_group("sampler build");
    g.sample_size(20);
    g.bench_function(format!("default components, global pool ({threads} threads)"), |b| {
        b.iter(|| IsoSampler::new(black_box(&pack), black_box(&model)))
    });
    g.bench_function(format!("components=pixel, global pool ({threads} threads)"), |b| {
        b.iter(|| IsoSampler::with_components(black_box(&pack), black_box(&model), Components::PIXEL))
    });
    // `--clean-at target` (`Pack.synth(clean_at="target")`): the fine levels near black read the
    // deconvolved bins again.
    g.bench_function(format!("default components, clean at target, global pool ({threads} threads)"), |b| {
        b.iter(|| {
            let (pack, model) = (black_box(&pack), black_box(&model));
            sampler_for(pack, model, ModelKind::Noisecal, Components::ALL, CleanAt::Target, false).expect("sampler")
        })
    });
    g.finish();

    let mut g = c.benchmark_group("synth 12MP");
    g.throughput(Throughput::Elements((W * H) as u64));
    g.sample_size(20);
    g.bench_function(format!("synthesize_at, global pool ({threads} threads)"), |b| {
        b.iter(|| synthesize_at(&sampler, black_box(clean.view()), 1, (0, 0)))
    });
    let one = rayon::ThreadPoolBuilder::new().num_threads(1).build().expect("pool");
    g.bench_function("synthesize_at, 1 thread", |b| {
        b.iter(|| one.install(|| synthesize_at(&sampler, black_box(clean.view()), 1, (0, 0))))
    });
    g.bench_function(format!("synthesize_at, components=pixel, global pool ({threads} threads)"), |b| {
        b.iter(|| synthesize_at(&pixel, black_box(clean.view()), 1, (0, 0)))
    });
    g.bench_function(format!("synthesize_at, pattern not kept, global pool ({threads} threads)"), |b| {
        b.iter(|| synthesize_at(&unkept, black_box(clean.view()), 1, (0, 0)))
    });
    g.finish();
}

criterion_group!(synth, benches);
criterion_main!(synth);
