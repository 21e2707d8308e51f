//! Compact packs (format version 5): a calibrated pack written compactly loads
//! to the pack with its weights rounded to 9 significant bits ([`ModelPack::compacted`]), whose
//! log-probabilities are within 2·2⁻⁹ nats of the pack's and whose synthesized images, drawn with
//! the same random numbers, differ in a small fraction of pixels by a step; the same pack written
//! uncompressed (version 4) still loads as it was; and the compact file is a fraction of the size.
//!
//! `cargo test -p noisecal-core --release --test pack_compact -- --ignored --nocapture` prints
//! the sizes of the demo's pack and of random-family sensors' packs in both versions.

use ndarray::Array2;
use noisecal_core::format::compact::MANTISSA_BITS;
use noisecal_core::model::pack::{PACK_MAGIC, PACK_VERSION};
use noisecal_core::synth::sampler::{BinTable, IsoSampler};
use noisecal_core::synth::synthesize;
use noisecal_core::{CalibrationSession, ModelPack, SessionConfig};
use noisecal_sim::{Chart, SensorModel, SessionPlan, Simulator, random_sensor, random_session};

fn calibrate(sim: &Simulator, plan: &SessionPlan) -> ModelPack {
    let mut config = SessionConfig::new(plan.reference_iso);
    config.make = "sim".into();
    let mut session = CalibrationSession::new(sim.layout(), config).expect("session");
    plan.feed(sim, &mut session, |_, _| ()).expect("capture");
    let exact = session.finish_exact().expect("a pack");
    assert_eq!(session.finish().expect("a pack"), exact.compacted(), "calibration rounds as a file stores");
    exact
}

/// A small simulated session of the demo's phone: 2 ISOs, 4 frames per burst.
fn small_pack() -> ModelPack {
    let sim =
        Simulator::new(SensorModel::phone_10bit(), Chart::color_checker(96, 64).expect("chart"), 3).expect("simulator");
    let plan = SessionPlan::for_simulator(&sim, vec![100, 800], 4).expect("plan").with_ev_steps(-2..=2);
    calibrate(&sim, &plan)
}

/// The demo's session (`noisecal demo`: 384×288 colour checker, 6 ISOs, 10 frames, ±4 EV),
/// calibrated from the frames instead of DNGs.
fn demo_pack() -> ModelPack {
    let sim = Simulator::new(SensorModel::phone_10bit(), Chart::color_checker(384, 288).expect("chart"), 1)
        .expect("simulator");
    let plan =
        SessionPlan::for_simulator(&sim, vec![100, 200, 400, 800, 1600, 3200], 10).expect("plan").with_ev_steps(-4..=4);
    calibrate(&sim, &plan)
}

fn random_pack(seed: u64) -> ModelPack {
    let sensor = random_sensor(seed);
    let spec = random_session(seed, &sensor.model);
    let sim = spec.simulator(&sensor.model, seed ^ 0xA5A5).expect("simulator");
    let plan = spec.plan(&sim).expect("plan");
    calibrate(&sim, &plan)
}

/// Plain histograms of an independent held-out session (`plan` on `sim`, frame indices shifted
/// by `offset`), binned as `pack` is.
fn heldout(sim: &Simulator, plan: &SessionPlan, offset: u64, pack: &ModelPack) -> ModelPack {
    let mut config = SessionConfig::new(plan.reference_iso);
    config.bin_width = Some(pack.bin_width);
    config.plain = true;
    let mut session = CalibrationSession::new(sim.layout(), config).expect("session");
    let mut step = None;
    for f in plan.frames() {
        if step != Some(f.step) {
            session.begin_step(plan.exposure_ns(f.step, plan.reference_iso)).expect("step");
            step = Some(f.step);
        }
        let (px, meta) = sim.capture(f.iso, f.exposure_ns, f.index + offset).expect("capture");
        let _ = session.push_frame(&noisecal_core::FrameView::from_array(&px).expect("view"), &meta);
    }
    session.finish_exact().expect("held-out histograms")
}

/// Held-out cross-entropy (nats per sample) of `pack`'s PMFs on `held`'s measured histograms,
/// and the fraction of held-out samples on values the pack gives no probability (left out).
fn cross_entropy(pack: &ModelPack, held: &ModelPack) -> (f64, f64) {
    let (mut nll, mut n, mut out) = (0.0f64, 0.0f64, 0.0f64);
    for h in &held.isos {
        let Some(m) = pack.iso(h.iso) else { continue };
        for (pm, ph) in m.positions.iter().zip(&h.positions) {
            for (b, hb) in pm.bins.iter().zip(&ph.bins) {
                if hb.source != noisecal_core::model::pack::BinSource::Measured {
                    continue;
                }
                let t: f64 = b.counts.iter().map(|&c| c as f64).sum();
                for (i, &c) in hb.counts.iter().enumerate() {
                    if c == 0 {
                        continue;
                    }
                    let v = hb.first as i64 + i as i64 - b.first as i64;
                    let w = usize::try_from(v).ok().and_then(|v| b.counts.get(v)).copied().unwrap_or(0);
                    if w == 0 {
                        out += c as f64;
                    } else {
                        nll -= c as f64 * (w as f64 / t).ln();
                        n += c as f64;
                    }
                }
            }
        }
    }
    (nll / n.max(1.0), out / (n + out).max(1.0))
}

/// A clean image sweeping every level of the sensor.
fn ramp(pack: &ModelPack) -> Array2<u16> {
    let (w, h) = (pack.layout.width as usize, pack.layout.height as usize);
    let white = pack.layout.white as usize;
    Array2::from_shape_fn((h, w), |(y, x)| (((y * w + x) * 7919) % (white + 1)) as u16)
}

/// Every ISO's sampler tables and a synthesized image of each, for comparing two loads.
fn fingerprint(pack: &ModelPack) -> Vec<(Vec<Vec<u64>>, Array2<u16>)> {
    let clean = ramp(pack);
    pack.isos
        .iter()
        .map(|m| {
            let tables: Vec<Vec<u64>> =
                m.positions.iter().flat_map(|p| &p.bins).map(|b| BinTable::new(b).cdf().to_vec()).collect();
            (tables, synthesize(&IsoSampler::new(pack, m), clean.view(), 42))
        })
        .collect()
}

/// Largest change of any value's log-probability between two packs of the same bins, and the
/// mean KL divergence per bin (nats).
fn log_prob_change(a: &ModelPack, b: &ModelPack) -> (f64, f64) {
    let (mut worst, mut kl, mut n) = (0.0f64, 0.0f64, 0usize);
    for (ma, mb) in a.isos.iter().zip(&b.isos) {
        for (ba, bb) in ma.positions.iter().flat_map(|p| &p.bins).zip(mb.positions.iter().flat_map(|p| &p.bins)) {
            assert_eq!((ba.first, ba.counts.len()), (bb.first, bb.counts.len()), "same support");
            let ta: f64 = ba.counts.iter().map(|&c| c as f64).sum();
            let tb: f64 = bb.counts.iter().map(|&c| c as f64).sum();
            for (&ca, &cb) in ba.counts.iter().zip(&bb.counts) {
                assert_eq!(ca == 0, cb == 0, "no value gains or loses probability");
                if ca > 0 {
                    let (pa, pb) = (ca as f64 / ta, cb as f64 / tb);
                    worst = worst.max((pa / pb).ln().abs());
                    kl += pa * (pa / pb).ln();
                }
            }
            n += 1;
        }
    }
    (worst, kl / n.max(1) as f64)
}

#[test]
fn compact_packs_round_trip_and_synthesize_as_version_4() {
    let p = small_pack();
    let v5 = p.to_bytes().expect("bytes");
    let v4 = p.to_bytes_v4().expect("bytes");
    assert_eq!(&v5[..8], PACK_MAGIC);
    assert_eq!(u16::from_le_bytes([v5[8], v5[9]]), PACK_VERSION);
    assert_eq!(PACK_VERSION, 5);
    assert_eq!(u16::from_le_bytes([v4[8], v4[9]]), 4);
    // Deterministic bytes.
    assert_eq!(v5, p.to_bytes().expect("bytes"));
    let from5 = ModelPack::from_bytes(&v5).expect("a version 5 pack loads");
    let from4 = ModelPack::from_bytes(&v4).expect("a version 4 pack still loads");
    assert_eq!(from4, p, "version 4 loads byte for byte as before");
    assert_eq!(from5, p.compacted());
    assert_eq!(from5.compacted(), from5, "compacting is idempotent");
    // A version 4 file migrated to 5, and a loaded version 5 written again: the same bytes.
    assert_eq!(from4.to_bytes().expect("bytes"), v5);
    assert_eq!(from5.to_bytes().expect("bytes"), v5);
    // The rounding: within its bound on every value's log-probability (so on any held-out
    // cross-entropy), and a negligible KL divergence.
    let (worst, kl) = log_prob_change(&from4, &from5);
    let bound = 2.0 * 0.5f64.powi(MANTISSA_BITS as i32) * 1.001;
    assert!(worst <= bound, "log-probability moved by {worst} nats, bound {bound}");
    assert!(kl < 1e-5, "mean KL {kl}");
    eprintln!("rounding: largest log-probability change {worst:.2e} nats, mean KL per bin {kl:.2e} nats");
    // Synthesis with the same random numbers: a pixel changes only where its draw falls between
    // a table entry and its rounded one, by one step.
    let (a, b) = (fingerprint(&from4), fingerprint(&from5));
    for ((ta, ia), (tb, ib)) in a.iter().zip(&b) {
        let moved: u64 =
            ta.iter().zip(tb).flat_map(|(x, y)| x.iter().zip(y)).map(|(&x, &y)| x.abs_diff(y)).max().unwrap_or(0);
        // A draw lands on another value only inside the gaps between old and new entries.
        let gaps = ta
            .iter()
            .zip(tb)
            .map(|(x, y)| x.iter().zip(y).map(|(&x, &y)| x.abs_diff(y) as f64).sum::<f64>() / 2f64.powi(32))
            .fold(0.0, f64::max);
        assert!(moved as f64 <= 2.0f64.powi(32 - MANTISSA_BITS as i32), "a CDF entry moved by {moved} / 2³²");
        let differ = ia.iter().zip(ib).filter(|(x, y)| x != y).count();
        let far = ia.iter().zip(ib).filter(|(x, y)| x.abs_diff(**y) > 4).count();
        let frac = differ as f64 / ia.len() as f64;
        eprintln!(
            "synthesis: {differ} of {} pixels differ ({frac:.2e}; a bin's gaps hold at most {gaps:.2e} of the draws), {far} by more than 4 DN",
            ia.len()
        );
        assert!(frac < 1e-2, "{differ} of {} pixels differ", ia.len());
        assert_eq!(far, 0);
    }
    // A model derived on the fly (interpolated) is the one a pack that stores it loads back,
    // so synthesis at a derived ISO gives the same bytes whether the pack stores it or not.
    let (m, _) = noisecal_core::derive::interp::model_for(&from5, 400, false).expect("interpolated");
    let mut with = from5.clone();
    with.insert(m.clone().into_owned());
    let back = ModelPack::from_bytes(&with.to_bytes().expect("bytes")).expect("loads");
    assert_eq!(back.iso(400), Some(m.as_ref()));
    // Size: measured 0.27× of the uncompressed file.
    eprintln!("version 4 {} bytes, version 5 {}", v4.len(), v5.len());
    assert!(v5.len() * 2 <= v4.len(), "version 5 {} bytes, version 4 {}", v5.len(), v4.len());
}

/// Size bound on a random-family sensor's pack, and its round trip.
#[test]
fn a_random_sensors_pack_is_compact() {
    let p = random_pack(1);
    let v5 = p.to_bytes().expect("bytes");
    let v4 = p.to_bytes_v4().expect("bytes");
    assert_eq!(ModelPack::from_bytes(&v5).expect("loads"), p.compacted());
    // Measured 0.20×.
    assert!(v5.len() * 10 <= v4.len() * 3, "version 5 {} bytes, version 4 {}", v5.len(), v4.len());
}

/// Damage inside the compressed payload (with the CRC recomputed, as a fuzzer's mutants may
/// be): refused with an error, never a panic.
#[test]
fn damaged_compact_packs_are_refused() {
    let p = small_pack();
    let v5 = p.to_bytes().expect("bytes");
    let header = 8 + 2 + 2 + 8 + 4;
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    for k in 0..200 {
        let mut b = v5.clone();
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        let at = header + (state as usize) % (b.len() - header);
        b[at] ^= 1 << (k % 8);
        let crc = crc32fast_hash(&b[header..]);
        b[20..24].copy_from_slice(&crc.to_le_bytes());
        if let Ok(q) = ModelPack::from_bytes(&b) {
            // A flip the format cannot see (a weight, a float) still gives a valid pack.
            q.check().expect("a loaded pack passes its checks");
        }
    }
    for cut in [header, header + 3, header + 8, v5.len() - 1] {
        let mut b = v5[..cut].to_vec();
        let len = (cut - header) as u64;
        b[12..20].copy_from_slice(&len.to_le_bytes());
        let crc = crc32fast_hash(&b[header..]);
        b[20..24].copy_from_slice(&crc.to_le_bytes());
        assert!(ModelPack::from_bytes(&b).is_err(), "cut at {cut}");
    }
}

/// CRC-32 (IEEE), as the framing computes it (the test does not depend on crc32fast).
fn crc32fast_hash(b: &[u8]) -> u32 {
    let mut crc = !0u32;
    for &x in b {
        crc ^= x as u32;
        for _ in 0..8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
        }
    }
    !crc
}

/// Sizes before (version 4) and after (version 5), for the report.
#[test]
#[ignore = "measurement: calibrates the demo session and random sensors (minutes in a debug build)"]
fn pack_sizes() {
    let seeds: Vec<u64> = std::env::var("NOISECAL_SEEDS")
        .ok()
        .map(|s| s.split(',').filter_map(|x| x.trim().parse().ok()).collect())
        .unwrap_or_else(|| vec![0, 1, 2, 3]);
    let mut packs: Vec<(String, ModelPack, ModelPack)> = Vec::new();
    {
        let p = demo_pack();
        let sim = Simulator::new(SensorModel::phone_10bit(), Chart::color_checker(384, 288).expect("chart"), 1001)
            .expect("simulator");
        let plan = SessionPlan::for_simulator(&sim, vec![100, 200, 400, 800, 1600, 3200], 10)
            .expect("plan")
            .with_ev_steps(-4..=4);
        let h = heldout(&sim, &plan, 1 << 40, &p);
        packs.push(("demo".into(), p, h));
    }
    for seed in seeds {
        let sensor = random_sensor(seed);
        let spec = random_session(seed, &sensor.model);
        let p = random_pack(seed);
        let sim = spec.simulator(&sensor.model, seed ^ 0xA5A5).expect("simulator");
        let plan = spec.plan(&sim).expect("plan");
        let hsim = spec.heldout_simulator(&sensor.model, seed ^ 0xA5A5).expect("held-out simulator");
        let hplan = spec.heldout_plan(&plan).expect("held-out plan");
        let h = heldout(&hsim, &hplan, spec.heldout.index_offset, &p);
        packs.push((format!("random {seed}: {}", sensor.description), p, h));
    }
    for (name, p, held) in &packs {
        let t0 = std::time::Instant::now();
        let v5 = p.to_bytes().expect("bytes");
        let enc = t0.elapsed();
        let t0 = std::time::Instant::now();
        let back = ModelPack::from_bytes(&v5).expect("loads");
        let dec = t0.elapsed();
        assert_eq!(back, p.compacted());
        let (worst, kl) = log_prob_change(p, &back);
        let (ce4, uncovered) = cross_entropy(p, held);
        let (ce5, _) = cross_entropy(&back, held);
        let v4 = p.to_bytes_v4().expect("bytes");
        let cells: usize = p.isos.iter().flat_map(|m| &m.positions).flat_map(|q| &q.bins).map(|b| b.counts.len()).sum();
        let cal = p.isos.iter().filter(|m| m.is_calibrated()).count().max(1);
        println!(
            "{name}\n  {} ISOs ({cal} calibrated), {cells} PMF cells: version 4 {} bytes, version 5 {} bytes ({:.3}×), {} bytes per calibrated ISO; encode {:?}, load {:?}; largest log-probability change {worst:.2e} nats, mean KL per bin {kl:.2e}\n  held-out cross-entropy {ce4:.6} → {ce5:.6} nats ({:+.2e} relative; {:.2e} of the held-out samples on values without probability, left out)",
            p.isos.len(),
            v4.len(),
            v5.len(),
            v5.len() as f64 / v4.len() as f64,
            v5.len() / cal,
            enc,
            dec,
            (ce5 - ce4) / ce4,
            uncovered
        );
        assert!(ce5 <= ce4 * 1.01, "{name}: cross-entropy {ce4} → {ce5}");
        if let Ok(dir) = std::env::var("NOISECAL_DUMP") {
            let stem = name.split(':').next().unwrap_or("pack").replace(' ', "-");
            std::fs::write(format!("{dir}/{stem}.v4.pack"), &v4).expect("write");
            std::fs::write(format!("{dir}/{stem}.v5.pack"), &v5).expect("write");
        }
    }
}

/// The fuzz corpus's packs (written by an older noisecal, version 3) still load, and written as
/// version 5 load back as their rounded selves. `NOISECAL_WRITE_SEEDS=1` writes those version 5
/// files into the corpus as seeds (`*-v5.pack`).
#[test]
fn older_pack_files_load_and_migrate_to_version_5() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fuzz-corpus/pack");
    for name in ["plain", "two-isos", "interpolated"] {
        let bytes = std::fs::read(dir.join(format!("{name}.pack"))).expect("read seed");
        assert_eq!(u16::from_le_bytes([bytes[8], bytes[9]]), 3, "{name} is a version 3 file");
        let old = ModelPack::from_bytes(&bytes).expect("a version 3 pack loads");
        let v5 = old.to_bytes().expect("bytes");
        assert_eq!(ModelPack::from_bytes(&v5).expect("loads"), old.compacted(), "{name}");
        assert_eq!(ModelPack::from_bytes(&old.to_bytes_v4().expect("bytes")).expect("loads"), old, "{name}");
        if std::env::var_os("NOISECAL_WRITE_SEEDS").is_some() && name != "interpolated" {
            std::fs::write(dir.join(format!("{name}-v5.pack")), &v5).expect("write seed");
        }
    }
}
