//! Compact packs (format version 6): a calibrated pack written compactly loads to its stored
//! form ([`ModelPack::compacted`]: weights rounded to fewer bits the further below their bin's
//! peak, tails cut where they hold no measurable mass); that form costs no held-out likelihood
//! beyond its budget and synthesizes images alike in distribution; older versions still load;
//! the file is a fraction of version 5's size.
//!
//! `cargo test -p noisecal-core --release --test pack_compact -- --ignored --nocapture` prints
//! the sizes, held-out cross-entropy and sampler tables of the demo's pack, the 14-bit phone's and
//! random-family sensors' packs in versions 5 and 6.

use ndarray::Array2;
use noisecal_core::format::pack_file::{PACK_MAGIC, PACK_VERSION};
use noisecal_core::model::precision::{TAIL_BITS, kept_bits, quantize};
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

/// Every stored weight against the exact pack's: the same bins, each stored cell rounded within
/// its kept bits, every cell the tails cut below about 2^−TAIL_BITS of its bin's largest, and no cell
/// inside the kept span set to zero. Returns the largest share of a bin's mass the cut tails held.
fn check_stored_form(exact: &ModelPack, stored: &ModelPack) -> f64 {
    let mut worst_cut = 0.0f64;
    for (me, ms) in exact.isos.iter().zip(&stored.isos) {
        for (be, bs) in me.positions.iter().flat_map(|p| &p.bins).zip(ms.positions.iter().flat_map(|p| &p.bins)) {
            let top = be.counts.iter().max().map_or(0, |&m| 64 - quantize(m).leading_zeros());
            let max = *be.counts.iter().max().expect("cells") as f64;
            let off = (bs.first - be.first) as usize;
            assert!(bs.first >= be.first && off + bs.counts.len() <= be.counts.len(), "the stored span lies inside");
            let total: f64 = be.counts.iter().map(|&c| c as f64).sum();
            let mut cut = 0.0;
            for (i, &c) in be.counts.iter().enumerate() {
                match i.checked_sub(off).and_then(|j| bs.counts.get(j)) {
                    Some(&q) => {
                        let k = kept_bits(c, top);
                        assert!(c == 0 || q > 0, "a kept cell lost its probability");
                        let err = (q as f64 - c as f64).abs() / (c.max(1) as f64);
                        assert!(err <= 0.5f64.powi(k as i32) + 1e-12, "{c} → {q} with {k} bits");
                    }
                    None => {
                        // Cut after rounding, which may have lowered it by up to a third.
                        assert!((c as f64) < max * 0.5f64.powi(TAIL_BITS as i32) * 1.6, "{c} cut, largest {max}");
                        cut += c as f64;
                    }
                }
            }
            worst_cut = worst_cut.max(cut / total);
        }
    }
    worst_cut
}

/// Noise histograms (DN) of `images` drawn from one pack on one clean image: `(value, count)`.
fn noise_of(pack: &ModelPack, clean: &Array2<u16>, iso: u32, seeds: std::ops::Range<u64>) -> Vec<i64> {
    let m = pack.iso(iso).expect("iso");
    let sampler = IsoSampler::new(pack, m);
    let mut out = Vec::new();
    for seed in seeds {
        let img = synthesize(&sampler, clean.view(), seed);
        out.extend(img.iter().zip(clean.iter()).map(|(&a, &c)| a as i64 - c as i64));
    }
    out
}

/// JSD (nats) of two samples' histograms over their common range.
fn sample_jsd(a: &[i64], b: &[i64]) -> f64 {
    let lo = *a.iter().chain(b).min().expect("samples");
    let hi = *a.iter().chain(b).max().expect("samples");
    let n = (hi - lo + 1) as usize;
    let (mut ha, mut hb) = (vec![0.0; n], vec![0.0; n]);
    a.iter().for_each(|&v| ha[(v - lo) as usize] += 1.0);
    b.iter().for_each(|&v| hb[(v - lo) as usize] += 1.0);
    noisecal_core::metrics::jsd(&ha, &hb)
}

/// Variance, and the 0.1 % and 99.9 % quantiles, of a sample.
fn spread(v: &mut [i64]) -> (f64, f64, f64) {
    let n = v.len() as f64;
    let mean = v.iter().sum::<i64>() as f64 / n;
    let var = v.iter().map(|&x| (x as f64 - mean).powi(2)).sum::<f64>() / n;
    v.sort_unstable();
    let q = |u: f64| v[((u * n) as usize).min(v.len() - 1)] as f64;
    (var, q(0.001), q(0.999))
}

#[test]
fn compact_packs_round_trip_and_migrate() {
    let p = small_pack();
    let v6 = p.to_bytes().expect("bytes");
    let v5 = p.to_bytes_v5().expect("bytes");
    let v4 = p.to_bytes_v4().expect("bytes");
    assert_eq!(&v6[..8], PACK_MAGIC);
    assert_eq!(u16::from_le_bytes([v6[8], v6[9]]), PACK_VERSION);
    assert_eq!(PACK_VERSION, 6);
    assert_eq!(u16::from_le_bytes([v5[8], v5[9]]), 5);
    assert_eq!(u16::from_le_bytes([v4[8], v4[9]]), 4);
    // Deterministic bytes.
    assert_eq!(v6, p.to_bytes().expect("bytes"));
    let from6 = ModelPack::from_bytes(&v6).expect("a version 6 pack loads");
    let from5 = ModelPack::from_bytes(&v5).expect("a version 5 pack still loads");
    let from4 = ModelPack::from_bytes(&v4).expect("a version 4 pack still loads");
    assert_eq!(from4, p, "version 4 loads byte for byte as before");
    assert_eq!(from6, p.compacted());
    assert_eq!(from6.compacted(), from6, "compacting is idempotent");
    // Version 5 loads as version 5 rounded it (9 significant bits, tails kept).
    let mut rounded5 = p.clone();
    rounded5
        .isos
        .iter_mut()
        .flat_map(|m| m.positions.iter_mut())
        .flat_map(|q| q.bins.iter_mut())
        .flat_map(|b| b.counts.iter_mut())
        .for_each(|w| *w = noisecal_core::format::pack_v5::quantize(*w));
    assert_eq!(from5, rounded5);
    // Migrated to version 6: a version 4 file gives the same bytes as the pack itself; a loaded
    // version 6 written again, the same bytes; a version 5 file, its own stored form.
    assert_eq!(from4.to_bytes().expect("bytes"), v6);
    assert_eq!(from6.to_bytes().expect("bytes"), v6);
    assert_eq!(ModelPack::from_bytes(&from5.to_bytes().expect("bytes")).expect("loads"), from5.compacted());
    // The cut tails hold at most the far tails of a bin's pseudo-sample (1/(N+1) of an N-sample
    // pool; measured 2.9·10⁻⁵ at most).
    let cut = check_stored_form(&p, &from6);
    eprintln!("the cut tails held at most {cut:.2e} of a bin's mass");
    assert!(cut < 1e-4, "a bin's cut tails held {cut} of its mass");
    // A model derived on the fly (interpolated) is the one a pack that stores it loads back,
    // so synthesis at a derived ISO gives the same bytes whether the pack stores it or not.
    let (m, _) = noisecal_core::derive::interp::model_for(&from6, 400, false).expect("interpolated");
    let mut with = from6.clone();
    with.insert(m.clone().into_owned());
    let back = ModelPack::from_bytes(&with.to_bytes().expect("bytes")).expect("loads");
    assert_eq!(back.iso(400), Some(m.as_ref()));
    // Size: measured 0.68× of version 5 (0.18× of version 4).
    eprintln!("version 4 {} bytes, version 5 {}, version 6 {}", v4.len(), v5.len(), v6.len());
    assert!(v6.len() * 10 <= v5.len() * 7, "version 6 {} bytes, version 5 {}", v6.len(), v5.len());
}

/// The stored form costs no held-out likelihood beyond its budget: a pack calibrated from one
/// simulated session scores an independent session's histograms (another seed, other frame
/// indices) within 0.2 % of the exact pack's cross-entropy (measured −4·10⁻⁴ … −1·10⁻⁵ of it on
/// the demo's, the 14-bit phone's and random sensors' sessions; the budget is 1 %), and its cut
/// tails leave out at most 2·10⁻⁴ more of the held-out samples.
#[test]
fn compaction_costs_no_held_out_likelihood() {
    let sim =
        Simulator::new(SensorModel::phone_10bit(), Chart::color_checker(96, 64).expect("chart"), 3).expect("simulator");
    let plan = SessionPlan::for_simulator(&sim, vec![100, 800], 4).expect("plan").with_ev_steps(-2..=2);
    let exact = calibrate(&sim, &plan);
    let hsim = Simulator::new(SensorModel::phone_10bit(), Chart::color_checker(96, 64).expect("chart"), 1003)
        .expect("simulator");
    let held = heldout(&hsim, &plan, 1 << 40, &exact);
    let stored = exact.compacted();
    let (ce_exact, out_exact) = cross_entropy(&exact, &held);
    let (ce_stored, out_stored) = cross_entropy(&stored, &held);
    eprintln!(
        "held-out cross-entropy {ce_exact:.6} → {ce_stored:.6} nats ({:+.2e}); outside the support {out_exact:.2e} → {out_stored:.2e}",
        (ce_stored - ce_exact) / ce_exact
    );
    assert!(ce_stored <= ce_exact * 1.002, "{ce_exact} → {ce_stored}");
    // Measured 1.2·10⁻⁵ → 1.0·10⁻⁴: the far tails of the pseudo-sample are not kept.
    assert!(out_stored <= out_exact + 2e-4, "{out_exact} → {out_stored}");
}

/// Images synthesized from the stored pack and from the exact one, with different seeds, are
/// as alike as two draws from the exact pack: JSD within twice the two-seed floor, variance
/// within 1 %, 0.1 % and 99.9 % quantiles within a DN or 3 % (a pack whose tails were cut at
/// the bulk, or rounded to one bit throughout, fails these).
#[test]
fn synthesis_from_the_stored_pack_matches_in_distribution() {
    let exact = small_pack();
    let stored = ModelPack::from_bytes(&exact.to_bytes().expect("bytes")).expect("loads");
    let clean = ramp(&exact);
    for iso in exact.iso_list() {
        let mut a = noise_of(&exact, &clean, iso, 0..40);
        let mut b = noise_of(&exact, &clean, iso, 40..80);
        let mut c = noise_of(&stored, &clean, iso, 80..120);
        let floor = sample_jsd(&a, &b);
        let jsd = sample_jsd(&a, &c);
        let (va, la, ha) = spread(&mut a);
        let (vb, lb, hb) = spread(&mut b);
        let (vc, lc, hc) = spread(&mut c);
        eprintln!(
            "ISO {iso}: JSD exact/stored {jsd:.2e} (two exact seeds {floor:.2e}); variance {va:.2} / {vb:.2} / stored {vc:.2}; 0.1 % {la} / {lb} / {lc}; 99.9 % {ha} / {hb} / {hc}"
        );
        assert!(jsd <= 2.0 * floor + 1e-5, "ISO {iso}: JSD {jsd} against a floor of {floor}");
        assert!((vc / va - 1.0).abs() < 0.01, "ISO {iso}: variance {va} → {vc}");
        for (x, y) in [(la, lc), (ha, hc)] {
            assert!((x - y).abs() <= 1.0f64.max(0.03 * x.abs()), "ISO {iso}: quantile {x} → {y}");
        }
    }
}

/// Size bound on a random-family sensor's pack, and its round trip.
#[test]
fn a_random_sensors_pack_is_compact() {
    let p = random_pack(1);
    let v6 = p.to_bytes().expect("bytes");
    let v5 = p.to_bytes_v5().expect("bytes");
    assert_eq!(ModelPack::from_bytes(&v6).expect("loads"), p.compacted());
    // Measured 1.085×: on this 14-bit sensor the wide PMFs' cores hold most of the bytes, and
    // predicting a bin's slopes from the previous bin's does not pay for 7-bit weights there.
    assert!(v6.len() * 10 <= v5.len() * 11, "version 6 {} bytes, version 5 {}", v6.len(), v5.len());
}

/// Damage inside the compressed payload (with the CRC recomputed, as a fuzzer's mutants may
/// be): refused with an error, never a panic.
#[test]
fn damaged_compact_packs_are_refused() {
    let p = small_pack();
    let v6 = p.to_bytes().expect("bytes");
    let header = 8 + 2 + 2 + 8 + 4;
    let mut state = 0x2545_F491_4F6C_DD1Du64;
    for k in 0..200 {
        let mut b = v6.clone();
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
    for cut in [header, header + 3, header + 8, header + 16, v6.len() - 1] {
        let mut b = v6[..cut].to_vec();
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

/// Sizes, held-out cross-entropy and sampler tables before (version 5) and after (version 6),
/// for the report: the demo's phone, the 14-bit dual-gain phone and random-family sensors
/// (`NOISECAL_SEEDS=0,1,2`).
#[test]
#[ignore = "measurement: calibrates the demo session and random sensors (minutes in a debug build)"]
fn pack_sizes() {
    let seeds: Vec<u64> = std::env::var("NOISECAL_SEEDS")
        .ok()
        .map(|s| s.split(',').filter_map(|x| x.trim().parse().ok()).collect())
        .unwrap_or_else(|| vec![0, 1, 2]);
    let mut packs: Vec<(String, ModelPack, ModelPack)> = Vec::new();
    let (p, h) = demo_pack_and_heldout();
    packs.push(("demo (10-bit phone)".into(), p, h));
    let (p, h) = phone14_pack_and_heldout();
    packs.push(("phone14 (14-bit dual gain, 192×128)".into(), p, h));
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
        let v6 = p.to_bytes().expect("bytes");
        let enc = t0.elapsed();
        let t0 = std::time::Instant::now();
        let back = ModelPack::from_bytes(&v6).expect("loads");
        let dec = t0.elapsed();
        assert_eq!(back, p.compacted());
        let v5 = p.to_bytes_v5().expect("bytes");
        let old = ModelPack::from_bytes(&v5).expect("loads");
        let (ce5, out5) = cross_entropy(&old, held);
        let (ce6, out6) = cross_entropy(&back, held);
        let cal = p.isos.iter().filter(|m| m.is_calibrated()).count().max(1);
        println!(
            "{name}\n  {} ISOs ({cal} calibrated): version 5 {} bytes ({} per calibrated ISO), version 6 {} bytes ({} per calibrated ISO, {:.3}×); encode {enc:?}, load {dec:?}\n  held-out cross-entropy {ce5:.6} → {ce6:.6} nats ({:+.2e} relative); held-out samples outside the support {out5:.2e} → {out6:.2e}",
            p.isos.len(),
            v5.len(),
            v5.len() / cal,
            v6.len(),
            v6.len() / cal,
            v6.len() as f64 / v5.len() as f64,
            (ce6 - ce5) / ce5,
        );
        for ((iso, x), (_, y)) in sampler_bytes(&old).iter().zip(&sampler_bytes(&back)) {
            println!("  sampler tables ISO {iso}: {:.2} MB → {:.2} MB", *x as f64 / 1e6, *y as f64 / 1e6);
        }
        if let Ok(dir) = std::env::var("NOISECAL_DUMP") {
            let stem = name.split([':', ' ']).next().unwrap_or("pack");
            std::fs::write(format!("{dir}/{stem}.v5.pack"), &v5).expect("write");
            std::fs::write(format!("{dir}/{stem}.v6.pack"), &v6).expect("write");
        }
    }
}

/// The fuzz corpus's packs (written by older noisecal builds, versions 3 and 5) still load, and
/// written as version 6 load back in their stored form. `NOISECAL_WRITE_SEEDS=1` writes those
/// version 6 files into the corpus as seeds (`*-v6.pack`).
#[test]
fn older_pack_files_load_and_migrate_to_version_6() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fuzz-corpus/pack");
    for (name, version) in [("plain", 3), ("two-isos", 3), ("interpolated", 3), ("plain-v5", 5), ("two-isos-v5", 5)] {
        let bytes = std::fs::read(dir.join(format!("{name}.pack"))).expect("read seed");
        assert_eq!(u16::from_le_bytes([bytes[8], bytes[9]]), version, "{name} is a version {version} file");
        let old = ModelPack::from_bytes(&bytes).expect("an older pack loads");
        let v6 = old.to_bytes().expect("bytes");
        assert_eq!(ModelPack::from_bytes(&v6).expect("loads"), old.compacted(), "{name}");
        assert_eq!(ModelPack::from_bytes(&old.to_bytes_v4().expect("bytes")).expect("loads"), old, "{name}");
        if std::env::var_os("NOISECAL_WRITE_SEEDS").is_some() && version == 3 && name != "interpolated" {
            std::fs::write(dir.join(format!("{name}-v6.pack")), &v6).expect("write seed");
        }
    }
}

/// Bytes of one inverse-CDF table (its entries and its guide).
fn table_bytes(t: &BinTable) -> usize {
    t.heap_bytes()
}

/// Per-ISO sampler table bytes (with every component the pack has, as `synth` builds them).
fn sampler_bytes(pack: &ModelPack) -> Vec<(u32, usize)> {
    pack.isos
        .iter()
        .map(|m| {
            let s = IsoSampler::new(pack, m);
            (m.iso, (0..4).flat_map(|p| s.tables(p)).map(table_bytes).sum())
        })
        .collect()
}

/// The 14-bit dual-gain phone: a 192×128 colour checker, 4 ISOs, 6 frames, ±3 EV.
fn phone14_pack_and_heldout() -> (ModelPack, ModelPack) {
    let chart = || Chart::color_checker(192, 128).expect("chart");
    let sim = Simulator::new(SensorModel::phone_14bit(), chart(), 5).expect("simulator");
    let plan = SessionPlan::for_simulator(&sim, vec![100, 400, 1600, 6400], 6).expect("plan").with_ev_steps(-3..=3);
    let p = calibrate(&sim, &plan);
    let hsim = Simulator::new(SensorModel::phone_14bit(), chart(), 1005).expect("simulator");
    let h = heldout(&hsim, &plan, 1 << 40, &p);
    (p, h)
}

fn demo_pack_and_heldout() -> (ModelPack, ModelPack) {
    let p = demo_pack();
    let sim = Simulator::new(SensorModel::phone_10bit(), Chart::color_checker(384, 288).expect("chart"), 1001)
        .expect("simulator");
    let plan =
        SessionPlan::for_simulator(&sim, vec![100, 200, 400, 800, 1600, 3200], 10).expect("plan").with_ev_steps(-4..=4);
    let h = heldout(&sim, &plan, 1 << 40, &p);
    (p, h)
}
