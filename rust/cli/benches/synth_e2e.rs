//! `noisecal synth` of an uncompressed 12 MP DNG end to end (read, sample, encode, atomic write),
//! as the command runs it (a process: pack load and fsync included; with every component the pack
//! has, and with `--components pixel`) and in process by stage (pack load, sampler build, read,
//! sample, NoiseProfile fit, encode, atomic write; and the command's one pass for such a file:
//! the input mapped, the pixels written while they are drawn).
//!
//!     cargo bench -p noisecal-cli --bench synth_e2e
//!
//! The pack and the 4000×3000 DNG (10-bit, Android `DngCreator` layout) come from the simulator,
//! made once in a temporary folder.

use std::hint::black_box;
use std::path::Path;
use std::process::Command;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use noisecal_core::ModelPack;
use noisecal_core::model::structure::Components;
use noisecal_core::resolve::{ModelKind, resolve_model};
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::{synthesize, synthesize_bands};
use noisecal_input::dng::{derived_bytes, fitted_noise_profile, read_dng_file, read_dng_source};

const ISO: u32 = 800;

fn noisecal(args: &[&str]) {
    let out = Command::new(env!("CARGO_BIN_EXE_noisecal")).args(args).output().expect("noisecal runs");
    assert!(out.status.success(), "noisecal {args:?}: {}", String::from_utf8_lossy(&out.stderr));
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

fn benches(c: &mut Criterion) {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let (cal, pack, big) = (d.join("cal"), d.join("p.pack"), d.join("big"));
    noisecal(&["-q", "simulate", "--dngs", s(&cal), "--width", "256", "--height", "192", "--frames", "4"]);
    noisecal(&["-q", "calibrate", s(&cal), "-o", s(&pack)]);
    noisecal(&[
        "-q",
        "simulate",
        "--dngs",
        s(&big),
        "--width",
        "4000",
        "--height",
        "3000",
        "--frames",
        "1",
        "--isos",
        "100",
        "--ev=0",
    ]);
    let input = std::fs::read_dir(&big).expect("big").map(|e| e.expect("entry").path()).min().expect("a dng");
    let output = d.join("out.dng");

    let file = read_dng_file(&input).expect("read");
    let px = file.image.pixels.len() as u64;
    let mut g = c.benchmark_group("synth_e2e_12mp");
    g.throughput(Throughput::Elements(px));
    g.sample_size(10);

    g.bench_function("cli", |b| {
        b.iter(|| {
            noisecal(&["-q", "synth", "--pack", s(&pack), "--iso", "800", "--seed", "7", s(&input), "-o", s(&output)])
        })
    });
    // The pixel-independent model alone: no structured components, so no deconvolved tables.
    g.bench_function("cli_pixel", |b| {
        b.iter(|| {
            noisecal(&[
                "-q",
                "synth",
                "--pack",
                s(&pack),
                "--iso",
                "800",
                "--seed",
                "7",
                "--components",
                "pixel",
                s(&input),
                "-o",
                s(&output),
            ])
        })
    });

    let pack_bytes = std::fs::read(&pack).expect("pack");
    g.bench_function("pack_load", |b| b.iter(|| black_box(ModelPack::from_bytes(&pack_bytes).expect("pack"))));
    let pack = ModelPack::from_bytes(&pack_bytes).expect("pack");
    let model = resolve_model(&pack, ISO, ModelKind::Noisecal, false).expect("model").model;
    // Per run: the sampler's tables (with the structured components taken out of every bin's PMF
    // by deconvolution), and without components.
    g.bench_function("sampler_build", |b| b.iter(|| black_box(IsoSampler::new(&pack, &model))));
    g.bench_function("sampler_build_pixel", |b| {
        b.iter(|| black_box(IsoSampler::with_components(&pack, &model, Components::PIXEL)))
    });
    g.bench_function("noise_profile", |b| {
        b.iter(|| black_box(fitted_noise_profile(&pack, &model, &file.image.layout)))
    });
    let sampler = IsoSampler::new(&pack, &model);
    let profile = fitted_noise_profile(&pack, &model, &file.image.layout);
    g.bench_function("read", |b| b.iter(|| black_box(read_dng_file(&input).expect("read"))));
    g.bench_function("sample", |b| b.iter(|| black_box(synthesize(&sampler, file.image.pixels.view(), 7))));
    let noisy = synthesize(&sampler, file.image.pixels.view(), 7);
    g.bench_function("encode", |b| {
        b.iter(|| black_box(derived_bytes(&output, &file, &noisy, ISO, profile.as_ref()).expect("encode")))
    });
    let (bytes, _) = derived_bytes(&output, &file, &noisy, ISO, profile.as_ref()).expect("encode");
    g.bench_function("write_atomic", |b| b.iter(|| noisecal_io::write_bytes_atomic(&output, &bytes).expect("write")));
    // What the command does for such a file: the input mapped, not decoded (`read_source`),
    // then sampling, encoding and writing in one pass while the bands are drawn, with the
    // NoiseProfile fit alongside, and the commit (sync, rename) (`sample_write_streamed`).
    g.bench_function("read_source", |b| b.iter(|| black_box(read_dng_source(&input).expect("read"))));
    let source = read_dng_source(&input).expect("read");
    g.bench_function("sample_write_streamed", |b| {
        b.iter(|| {
            let stream = source.streamed().expect("uncompressed 16-bit strips");
            let tmp = stream
                .write(&output, ISO, |sink| {
                    let draw = || synthesize_bands(&sampler, source.pixels(), 7, (0, 0), sink);
                    rayon::join(draw, || fitted_noise_profile(&pack, &model, &source.image.layout)).1
                })
                .expect("write");
            tmp.commit().expect("commit");
        })
    });
    g.bench_function("in_process", |b| {
        b.iter(|| {
            let f = read_dng_file(&input).expect("read");
            let noisy = synthesize(&sampler, f.image.pixels.view(), 7);
            let (bytes, _) = derived_bytes(&output, &f, &noisy, ISO, profile.as_ref()).expect("encode");
            noisecal_io::write_bytes_atomic(&output, &bytes).expect("write");
        })
    });
    g.finish();
}

criterion_group!(e2e, benches);
criterion_main!(e2e);
