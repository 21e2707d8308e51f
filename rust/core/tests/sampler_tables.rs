//! Sampler table bytes per ISO (issue 26 item 3: at most 4 MB per ISO at any bit depth), and
//! where they go.
//!
//! `cargo test -p noisecal-core --test sampler_tables -- --ignored --nocapture` prints, per ISO
//! and CFA position of packs named in `NOISECAL_PACKS` (comma-separated files) and of calibrated
//! random-family sensors (`NOISECAL_SEEDS`, default 0,1,2): the tables' entries and bytes, the
//! entries of each table's tails (cumulative weight below 2⁻¹² or above 1 − 2⁻¹²) and of cells
//! holding less than 2⁻²⁴ of the mass, the entries never drawn (no weight at the table's
//! 2⁻³² resolution), and the entries of bins whose weights are a coarse grid's re-expansion.

use noisecal_core::model::coarse_grid::{GRID_STEPS, is_expansion};
use noisecal_core::model::layout::POSITIONS;
use noisecal_core::model::structure::Components;
use noisecal_core::synth::sampler::{BinTable, Guide, IsoSampler};
use noisecal_core::{CalibrationSession, ModelPack, SessionConfig};
use noisecal_sim::{SessionPlan, Simulator, random_sensor, random_session};

fn calibrate(sim: &Simulator, plan: &SessionPlan) -> ModelPack {
    let mut config = SessionConfig::new(plan.reference_iso);
    config.make = "sim".into();
    let mut session = CalibrationSession::new(sim.layout(), config).expect("session");
    plan.feed(sim, &mut session, |_, _| ()).expect("capture");
    session.finish().expect("a pack")
}

/// The calibrated pack of random-family sensor `seed`, and the sensor's description.
fn random_pack(seed: u64) -> (ModelPack, String) {
    let sensor = random_sensor(seed);
    let spec = random_session(seed, &sensor.model);
    let sim = spec.simulator(&sensor.model, seed ^ 0xA5A5).expect("simulator");
    let plan = spec.plan(&sim).expect("plan");
    (calibrate(&sim, &plan), sensor.description)
}

/// The widest grid step whose re-expansion `w` is (1: none).
fn step_of(w: &[u64]) -> usize {
    GRID_STEPS.iter().rev().copied().find(|&k| is_expansion(w, k)).unwrap_or(1)
}

/// Per ISO: its table bytes, with the sampler `synth` builds (every component the pack has).
fn per_iso_bytes(pack: &ModelPack) -> Vec<(u32, usize)> {
    pack.isos
        .iter()
        .map(|m| {
            let s = IsoSampler::new(pack, m);
            (m.iso, (0..POSITIONS).flat_map(|p| s.tables(p)).map(|t| t.heap_bytes()).sum())
        })
        .collect()
}

fn report(name: &str, pack: &ModelPack) {
    const ONE: u64 = 1 << 32;
    println!("{name}");
    for m in &pack.isos {
        let s = IsoSampler::new(pack, m);
        let total: usize = (0..POSITIONS).flat_map(|p| s.tables(p)).map(|t| t.heap_bytes()).sum();
        println!(
            "  ISO {} ({}): {:.2} MB",
            m.iso,
            if m.is_calibrated() { "calibrated" } else { "derived" },
            total as f64 / 1e6
        );
        for p in 0..POSITIONS {
            let tabs = s.tables(p);
            let bins = &m.positions[p].bins;
            let (mut entries, mut bytes, mut tails, mut small, mut dead, mut longest) = (0, 0, 0, 0, 0, 0);
            for t in tabs {
                let cdf = t.cdf();
                entries += cdf.len();
                bytes += t.heap_bytes();
                longest = longest.max(cdf.len());
                let mut lo = 0u64;
                for &c in &cdf {
                    let w = c - lo;
                    tails += usize::from(c < ONE >> 12 || lo > ONE - (ONE >> 12));
                    small += usize::from(w < 1 << 8);
                    dead += usize::from(w == 0);
                    lo = c;
                }
            }
            // Entries of the model's own bins by grid step (pixel-only's tables are these bins).
            let mut by_step = std::collections::BTreeMap::<usize, (usize, usize)>::new();
            for b in bins {
                let e = by_step.entry(step_of(&b.counts)).or_default();
                e.0 += 1;
                e.1 += b.counts.len();
            }
            let steps: Vec<String> = by_step.iter().map(|(k, (n, c))| format!("k={k}: {n} bins {c} entries")).collect();
            println!(
                "    position {p}: {} tables, {entries} entries ({longest} longest), {:.2} MB; tails {:.0} %, cells below 2⁻²⁴ {:.0} %, never drawn {:.0} %; own bins {}",
                tabs.len(),
                bytes as f64 / 1e6,
                100.0 * tails as f64 / entries as f64,
                100.0 * small as f64 / entries as f64,
                100.0 * dead as f64 / entries as f64,
                steps.join(", ")
            );
        }
    }
}

#[test]
#[ignore = "measurement: calibrates random-family sensors (minutes)"]
fn table_bytes_per_iso() {
    if let Ok(files) = std::env::var("NOISECAL_PACKS") {
        for f in files.split(',').filter(|f| !f.is_empty()) {
            let pack = ModelPack::from_bytes(&std::fs::read(f).expect("read pack")).expect("a pack");
            report(f, &pack);
        }
    }
    let seeds: Vec<u64> = std::env::var("NOISECAL_SEEDS")
        .ok()
        .map(|s| s.split(',').filter_map(|x| x.trim().parse().ok()).collect())
        .unwrap_or_else(|| vec![0, 1, 2]);
    for seed in seeds {
        let (pack, description) = random_pack(seed);
        report(&format!("random {seed}: {description}"), &pack);
    }
}

/// The goal per ISO at any bit depth (issue 26 item 3).
const BYTES_PER_ISO: usize = 4_000_000;

/// A 14-bit family sensor's tables stay within 4 MB per ISO, and draw what one entry per DN
/// draws. Random sensor 1 (14-bit, SD of hundreds of DN at ISO 1250, 256 bins of 6 000–10 000
/// DN): 23.86 and 30.90 MB per ISO with one entry per DN (what a sampler without the cell
/// layout scores here), 0.5 and 0.6 MB with its coarse bins drawn from their cells. For every
/// table drawn from cells, pixel-only's tables (the pack's own bins), the cumulative weights at
/// every DN and the draws at each DN's boundary and either side of it are the per-DN table's.
#[test]
fn a_14_bit_family_sensors_tables_fit_4_mb_per_iso() {
    let (pack, description) = random_pack(1);
    assert!(description.starts_with("14-bit"), "{description}");
    for (iso, bytes) in per_iso_bytes(&pack) {
        assert!(bytes <= BYTES_PER_ISO, "ISO {iso}: {bytes} bytes of tables");
    }
    let (mut tables, mut draws) = (0, 0u64);
    for m in &pack.isos {
        let s = IsoSampler::with_components(&pack, m, Components::PIXEL);
        for p in 0..POSITIONS {
            for (t, b) in s.tables(p).iter().zip(&m.positions[p].bins).filter(|(t, _)| t.is_cells()) {
                let entries = BinTable::with_guide(b, Guide::Dense);
                let cdf = entries.cdf();
                assert_eq!((t.first(), t.cdf()), (entries.first(), cdf.clone()), "ISO {} position {p}", m.iso);
                for u in
                    cdf.iter().flat_map(|&c| [c.saturating_sub(1), c, c + 1]).map(|c| c.min(u32::MAX as u64) as u32)
                {
                    assert_eq!(t.sample_u32(u), entries.sample_u32(u), "ISO {} position {p}, u {u}", m.iso);
                    draws += 1;
                }
                tables += 1;
            }
        }
    }
    // 256 bins × 4 positions × 2 ISOs, nearly all on a coarse grid.
    assert!(tables >= 1500, "{tables} tables drawn from cells");
    assert!(draws >= 1_000_000, "{draws} draws compared");
}

/// Draw time of an ISO's tables, one entry per DN against the cells of the bins on a coarse
/// grid, alternating in one run: pixel-only tables of the pack in `NOISECAL_TIMING_PACK` (its
/// highest ISO), drawn along a ramp over every bin (rows of 4 000 pixels, 2×2 positions), 3 MP
/// per round, the same draws for both. Prints ns per draw per round and the medians.
#[test]
#[ignore = "measurement: set NOISECAL_TIMING_PACK"]
fn draw_time_entries_against_cells() {
    use rand::{Rng, SeedableRng};
    let Ok(path) = std::env::var("NOISECAL_TIMING_PACK") else {
        eprintln!("set NOISECAL_TIMING_PACK; nothing measured");
        return;
    };
    let pack = ModelPack::from_bytes(&std::fs::read(&path).expect("read pack")).expect("a pack");
    let m = pack.isos.last().expect("an ISO");
    let build = |layout: bool| -> Vec<Vec<BinTable>> {
        (0..POSITIONS)
            .map(|p| {
                m.positions[p]
                    .bins
                    .iter()
                    .map(|b| {
                        if layout {
                            BinTable::with_layout(b, noisecal_core::synth::sampler::Layout::Cells(Guide::Dense))
                        } else {
                            BinTable::with_guide(b, Guide::Dense)
                        }
                    })
                    .collect()
            })
            .collect()
    };
    // Build times, alternating (the cell layout first finds each bin's grid step).
    let (mut be, mut bc) = (vec![], vec![]);
    for _ in 0..3 {
        let t0 = std::time::Instant::now();
        std::hint::black_box(build(false));
        be.push(t0.elapsed().as_secs_f64() * 1e3);
        let t0 = std::time::Instant::now();
        std::hint::black_box(build(true));
        bc.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    println!("  build (one thread, ms): entries {be:.0?}, cells {bc:.0?}");
    let (entries, cells) = (build(false), build(true));
    let bytes = |t: &Vec<Vec<BinTable>>| t.iter().flatten().map(BinTable::heap_bytes).sum::<usize>();
    println!("{path} ISO {}: entries {} bytes, cells {} bytes", m.iso, bytes(&entries), bytes(&cells));
    let (w, h) = (4000usize, 750usize);
    let round = |tabs: &Vec<Vec<BinTable>>, seed: u64| -> (f64, i64) {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let t0 = std::time::Instant::now();
        let mut sum = 0i64;
        for y in 0..h {
            for x in 0..w {
                let p = (y & 1) * 2 + (x & 1);
                let bins = &tabs[p];
                let b = x * bins.len() / w;
                sum += bins[b].sample_u32(rng.next_u32()) as i64;
            }
        }
        (t0.elapsed().as_secs_f64() * 1e9 / (w * h) as f64, sum)
    };
    let (mut te, mut tc) = (vec![], vec![]);
    for r in 0..6u64 {
        let (a, sa) = if r % 2 == 0 { round(&entries, r) } else { (0.0, 0) };
        let (c, sc) = round(&cells, r);
        let (a, sa) = if r % 2 == 1 { round(&entries, r) } else { (a, sa) };
        assert_eq!(sa, sc, "the same draws");
        println!("  round {r}: entries {a:.2} ns/draw, cells {c:.2} ns/draw");
        te.push(a);
        tc.push(c);
    }
    te.sort_by(f64::total_cmp);
    tc.sort_by(f64::total_cmp);
    println!("  median: entries {:.2} ns/draw, cells {:.2} ns/draw", te[3], tc[3]);
}
