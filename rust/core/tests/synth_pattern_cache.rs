//! The fixed pattern a sampler keeps between calls changes only time and memory: whatever its
//! limit (none kept, a limit just under or at the region, the default), repeated synthesis gives
//! the bytes of the row-by-row computation, on one thread and on three.

use ndarray::Array2;
mod support;

use noisecal_core::POSITIONS;
use noisecal_core::model::pack::{IsoModel, ModelPack};
use noisecal_core::model::structure::{Components, FixedPattern, IsoStructure, OffsetDistribution, QUANTILES};
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::{DEFAULT_PATTERN_CACHE_BYTES, synthesize_at};

const H: usize = 40;
const W: usize = 61;
const ORIGIN: (usize, usize) = (3, 1);

/// A 10-bit pack of one ISO whose bins all draw a small skewed PMF over −6 … 6 DN.
fn pack() -> (ModelPack, IsoModel) {
    let counts: Vec<u64> = (0..13u64).map(|i| 1 + (i * 37 + 11) % 50 + 200 / (1 + i.abs_diff(6))).collect();
    support::one_iso_pack((128, 96), 8, (8, 1000), "pattern", |_| (-6, counts.clone()))
}

/// A spread of `sd` DN (a scaled uniform quantile function: the shape does not matter here).
fn spread(sd: f64) -> OffsetDistribution {
    let half = sd * 3f64.sqrt();
    let quantiles = (0..QUANTILES).map(|i| (-half + 2.0 * half * i as f64 / (QUANTILES - 1) as f64) as f32).collect();
    OffsetDistribution { quantiles, count: 1000, measured_var: sd * sd, sampling_var: 0.0, significant: true }
}

/// Row offsets and a fixed pattern (shading plus a per-pixel residual of 1.5 DN).
fn structure() -> IsoStructure {
    let fp = FixedPattern {
        pixels: std::array::from_fn(|_| spread(1.5)),
        shading: std::array::from_fn(|p| (0..12).map(|i| (i as f32 * 0.37 + p as f32).sin() * 2.0).collect()),
        grid: [3, 4],
        size: [96, 128],
        frames: 8,
        temporal_var: [1.0; POSITIONS],
        in_pixel_noise: std::array::from_fn(|_| spread(0.5)),
        significant: true,
    };
    IsoStructure { rows: [Some(spread(0.7)), Some(spread(0.7))], fpn: Some(fp), ..IsoStructure::empty(100) }
}

fn clean() -> Array2<u16> {
    Array2::from_shape_fn((H, W), |(y, x)| (70 + 13 * x + 7 * y) as u16)
}

/// Four calls (seeds 1, 2, 1, 3) on a fresh sampler whose pattern cache holds at most `limit`
/// bytes, on a pool of `threads`.
fn run(limit: usize, threads: usize) -> Vec<Array2<u16>> {
    let (pack, model) = pack();
    let s =
        IsoSampler::with_structure(&pack, &model, Some(&structure()), Components::ALL).with_pattern_cache_bytes(limit);
    assert_eq!(s.structure().map(|st| st.pattern_cache_bytes()), Some(limit));
    let clean = clean();
    let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
    pool.install(|| [1u64, 2, 1, 3].iter().map(|&seed| synthesize_at(&s, clean.view(), seed, ORIGIN)).collect())
}

#[test]
fn the_pattern_cache_limit_changes_no_byte() {
    let reference = run(0, 1);
    assert_eq!(reference[0], reference[2], "same seed, same bytes");
    // The pattern is in the images: without it they differ.
    let (pack, model) = pack();
    let no_fpn = Components::parse("pixel,row,column,frame").expect("components");
    let plain = IsoSampler::with_structure(&pack, &model, Some(&structure()), no_fpn);
    assert_ne!(synthesize_at(&plain, clean().view(), 1, ORIGIN), reference[0], "the fixed pattern is drawn");
    let region = H * W * 8;
    for limit in [0, region - 1, region, 1 << 20, DEFAULT_PATTERN_CACHE_BYTES] {
        for threads in [1, 3] {
            assert!(run(limit, threads) == reference, "limit {limit} bytes on {threads} threads");
        }
    }
}

#[test]
fn lowering_the_limit_between_calls_changes_no_byte() {
    let reference = run(0, 2);
    let (pack, model) = pack();
    let s = IsoSampler::with_structure(&pack, &model, Some(&structure()), Components::ALL);
    let clean = clean();
    let mut got = Vec::new();
    for (seed, limit) in [(1u64, 1usize << 20), (2, 1 << 20), (1, 0), (3, 1 << 20)] {
        s.set_pattern_cache_bytes(limit);
        got.push(synthesize_at(&s, clean.view(), seed, ORIGIN));
    }
    assert!(got == reference);
}
