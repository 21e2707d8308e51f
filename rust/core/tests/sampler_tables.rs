//! Sampler table bytes per ISO (issue 26 item 3: at most 4 MB per ISO at any bit depth), and
//! where they go.
//!
//! `cargo test -p noisecal-core --test sampler_tables -- --ignored --nocapture` prints, per ISO
//! and CFA position of packs named in `NOISECAL_PACKS` (comma-separated files) and of calibrated
//! random-family sensors (`NOISECAL_SEEDS`, default 0,1,2): the tables' entries and bytes, the
//! entries of each table's tails (cumulative weight below 2⁻¹² or above 1 − 2⁻¹²) and of cells
//! holding less than 2⁻²⁴ of the mass, the entries never drawn (no weight at the table's
//! 2⁻³² resolution), and the entries of bins whose weights are a coarse grid's re-expansion.

use noisecal_core::model::coarse_grid::{GRID_STEPS, cell_masses_at, expand, is_expansion};
use noisecal_core::model::layout::POSITIONS;
use noisecal_core::model::pack::BinModel;
use noisecal_core::model::structure::Components;
use noisecal_core::synth::sampler::{BinTable, Guide, IsoSampler};
use noisecal_core::{CalibrationSession, ModelPack, SessionConfig};
use noisecal_sim::{Chart, SensorModel, SessionPlan, Simulator, random_sensor, random_session};

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

/// The 14-bit dual-gain phone (`SensorModel::phone_14bit`, its structured components): a
/// 192×128 colour checker, ISOs 100, 400, 1600, 6400, 6 frames, ±3 EV (`tests/pack_compact.rs`'s
/// phone14 pack).
fn phone14_pack() -> ModelPack {
    let chart = Chart::color_checker(192, 128).expect("chart");
    let sim = Simulator::new(SensorModel::phone_14bit(), chart, 5).expect("simulator");
    let plan = SessionPlan::for_simulator(&sim, vec![100, 400, 1600, 6400], 6).expect("plan").with_ev_steps(-3..=3);
    calibrate(&sim, &plan)
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

/// The weights (units of 2⁻³²) a table draws, from its cumulative weights.
fn weights_of(t: &BinTable) -> Vec<u64> {
    let mut lo = 0;
    t.cdf()
        .into_iter()
        .map(|c| {
            let w = c - lo;
            lo = c;
            w
        })
        .collect()
}

/// Total variation distance between the weights `w` (over `first ..`, units of 2⁻³², total
/// 2³²) and their re-expansion at step `k` on the grid through `origin`.
fn regrid_tv(first: i32, w: &[u64], k: usize, origin: i32) -> (f64, usize) {
    let (start, masses) = cell_masses_at(first, w, k, origin);
    let e = expand(&masses, k);
    let lead = (first - start) as usize;
    let mut diff = 0u128;
    for (i, &x) in e.iter().enumerate() {
        let q = i.checked_sub(lead).and_then(|j| w.get(j)).copied().unwrap_or(0);
        diff += x.abs_diff(q) as u128;
    }
    (diff as f64 / 2.0 / (1u64 << 32) as f64, masses.len())
}

/// Entries of a table's two tails that hold at most `mass` (units of 2⁻³²) each.
fn tail_entries(w: &[u64], mass: u64) -> usize {
    let side = |it: &mut dyn Iterator<Item = &u64>| {
        let mut acc = 0u64;
        it.take_while(|&&x| {
            acc += x;
            acc <= mass
        })
        .count()
    };
    (side(&mut w.iter()) + side(&mut w.iter().rev())).min(w.len().saturating_sub(1))
}

/// Where the bytes of the default sampler's tables go per ISO: the tables of the position's
/// bins by what their source bin is (on a grid of `k` DN, per DN), the other tables (fine
/// levels, the ceiling's), and for the bins' tables what a grid at the source bin's step (and
/// at half and a quarter of it) would hold and how far (total variation) its re-expansion lies
/// from the table, with the grid at the table's first DN and on the source bin's grid.
fn structured_report(name: &str, pack: &ModelPack) {
    const ONE: u64 = 1 << 32;
    println!("{name}: default components, by table");
    for m in &pack.isos {
        let now = IsoSampler::new(pack, m);
        let total: usize = (0..POSITIONS).flat_map(|p| now.tables(p)).map(|t| t.heap_bytes()).sum();
        // Every table per DN: what the tables hold, exactly.
        let structure = pack.structure_of(m.iso);
        let s = IsoSampler::with_structure_within(pack, m, structure, Components::ALL, usize::MAX);
        let regridded = (0..POSITIONS)
            .map(|p| {
                let moved = |(a, b): (&BinTable, &BinTable)| a.first() != b.first() || a.cdf() != b.cdf();
                now.tables(p).iter().zip(s.tables(p)).filter(|&x| moved(x)).count()
            })
            .sum::<usize>();
        // The layout before the regrid: the bins kept as the pack has them (the same first and
        // length as a bin on a grid) from their cells, the rest per DN with the sparse guide
        // where that fits 4 MB, else the dense one.
        let (mut cells, mut rest) = (0usize, vec![]);
        for p in 0..POSITIONS {
            let bins = &m.positions[p].bins;
            for (i, t) in s.tables(p).iter().enumerate() {
                let kept = |b: &&BinModel| b.first == t.first() && BinTable::new(b).cdf() == t.cdf();
                match bins.get(i).filter(|b| b.grid_step > 1).filter(kept) {
                    Some(b) => {
                        let n = b.counts.len() / b.grid_step as usize;
                        cells += 8 * n + 2 * (1usize << n.next_power_of_two().trailing_zeros().clamp(3, 12)) + 56;
                    }
                    None => rest.push(t.len()),
                }
            }
        }
        let lens = || (0..POSITIONS).flat_map(|p| s.tables(p)).map(|t| t.len());
        let before = if lens().map(|n| Guide::Sparse.table_bytes(n)).sum::<usize>() > BYTES_PER_ISO {
            let g = Guide::for_tables(BYTES_PER_ISO.saturating_sub(cells), rest.iter().copied());
            cells + rest.iter().map(|&n| g.table_bytes(n)).sum::<usize>()
        } else {
            let g = Guide::for_tables(BYTES_PER_ISO, lens());
            lens().map(|n| g.table_bytes(n)).sum()
        };
        println!(
            "  ISO {}: {:.2} MB before (bins the pack keeps on a grid from their cells), {:.2} MB now ({regridded} tables put on a grid)",
            m.iso,
            before as f64 / 1e6,
            total as f64 / 1e6
        );
        // Per source step: tables, entries, bytes, bytes at the source step/1,2,4, TVs.
        let mut by = std::collections::BTreeMap::<
            usize,
            (usize, usize, usize, [usize; 3], [Vec<f64>; 3], f64, [usize; 4]),
        >::new();
        let (mut other_n, mut other_bytes) = (0, 0);
        for p in 0..POSITIONS {
            let bins = &m.positions[p].bins;
            for (i, t) in s.tables(p).iter().enumerate() {
                let Some(b) = bins.get(i) else {
                    other_n += 1;
                    other_bytes += t.heap_bytes();
                    continue;
                };
                let k = (b.grid_step as usize).max(1);
                let e = by.entry(k).or_default();
                let w = weights_of(t);
                e.0 += 1;
                e.1 += w.len();
                e.2 += t.heap_bytes();
                e.6[0] += tail_entries(&w, ONE >> 24);
                e.6[1] += tail_entries(&w, ONE >> 16);
                e.6[2] += w.iter().filter(|&&x| x == 0).count();
                e.6[3] += w.iter().filter(|&&x| x < 1 << 8).count();
                if k > 1 {
                    for (j, d) in [1usize, 2, 4].into_iter().enumerate() {
                        let kk = k / d;
                        if kk < 2 {
                            continue;
                        }
                        let (tv_own, cells) = regrid_tv(t.first(), &w, kk, t.first());
                        let (tv_src, _) = regrid_tv(t.first(), &w, kk, b.first);
                        e.3[j] += 8 * cells + 2 * cells.next_power_of_two().clamp(8, 4096);
                        e.4[j].push(tv_own);
                        if j == 0 {
                            e.5 = e.5.max(tv_src);
                            e.4[j].push(-tv_src);
                        }
                    }
                }
            }
        }
        println!("    other tables: {other_n}, {:.2} MB", other_bytes as f64 / 1e6);
        for (k, (n, entries, bytes, grid, tvs, _, counts)) in &by {
            println!(
                "    source step {k}: {n} tables, {entries} entries, {:.2} MB; tail entries ≤2⁻²⁴ {:.0} %, ≤2⁻¹⁶ {:.0} %, zero {:.0} %, below 2⁻²⁴ {:.0} %",
                *bytes as f64 / 1e6,
                100.0 * counts[0] as f64 / *entries as f64,
                100.0 * counts[1] as f64 / *entries as f64,
                100.0 * counts[2] as f64 / *entries as f64,
                100.0 * counts[3] as f64 / *entries as f64,
            );
            if *k > 1 {
                for (j, d) in [1usize, 2, 4].into_iter().enumerate() {
                    let mut own: Vec<f64> = tvs[j].iter().copied().filter(|&x| x >= 0.0).collect();
                    let mut src: Vec<f64> = tvs[j].iter().copied().filter(|&x| x < 0.0).map(|x| -x).collect();
                    if own.is_empty() {
                        continue;
                    }
                    own.sort_by(f64::total_cmp);
                    src.sort_by(f64::total_cmp);
                    let q = |v: &[f64], f: f64| {
                        v.get((v.len().saturating_sub(1) as f64 * f) as usize).copied().unwrap_or(f64::NAN)
                    };
                    println!(
                        "      grid k/{d}: {:.2} MB; TV at the table's first: median {:.1e}, 90 % {:.1e}, max {:.1e}; on the source's grid: median {:.1e}, max {:.1e}",
                        grid[j] as f64 / 1e6,
                        q(&own, 0.5),
                        q(&own, 0.9),
                        q(&own, 1.0),
                        q(&src, 0.5),
                        q(&src, 1.0)
                    );
                }
            }
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
            structured_report(f, &pack);
        }
    }
    // NOISECAL_PHONE14=FILE: the phone14 pack, calibrated and written there unless it exists.
    if let Ok(f) = std::env::var("NOISECAL_PHONE14") {
        let pack = match std::fs::read(&f) {
            Ok(bytes) => ModelPack::from_bytes(&bytes).expect("a pack"),
            Err(_) => {
                let pack = phone14_pack();
                std::fs::write(&f, pack.to_bytes().expect("bytes")).expect("write the pack");
                ModelPack::from_bytes(&std::fs::read(&f).expect("read")).expect("a pack")
            }
        };
        report("phone14", &pack);
        structured_report("phone14", &pack);
    }
    let seeds: Vec<u64> = std::env::var("NOISECAL_SEEDS")
        .ok()
        .map(|s| s.split(',').filter_map(|x| x.trim().parse().ok()).collect())
        .unwrap_or_else(|| vec![0, 1, 2]);
    for seed in seeds {
        let (pack, description) = random_pack(seed);
        report(&format!("random {seed}: {description}"), &pack);
        structured_report(&format!("random {seed}"), &pack);
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
    // Build times, alternating: one entry per DN, the cells at the step the decoder kept, and
    // the search for each bin's step that the cell layout made before it was kept (every bin
    // re-expanded at the widest steps until one gives it back).
    let search = || -> usize {
        (0..POSITIONS)
            .flat_map(|p| &m.positions[p].bins)
            .map(|b| GRID_STEPS.iter().rev().copied().find(|&k| is_expansion(&b.counts, k)).unwrap_or(1))
            .sum()
    };
    let (mut be, mut bc, mut bs) = (vec![], vec![], vec![]);
    for _ in 0..5 {
        let t0 = std::time::Instant::now();
        std::hint::black_box(build(false));
        be.push(t0.elapsed().as_secs_f64() * 1e3);
        let t0 = std::time::Instant::now();
        std::hint::black_box(build(true));
        bc.push(t0.elapsed().as_secs_f64() * 1e3);
        let t0 = std::time::Instant::now();
        std::hint::black_box(search());
        bs.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    println!(
        "  build (ms): entries {be:.0?}, cells at the kept step {bc:.0?}, the search for the steps alone {bs:.0?}"
    );
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
