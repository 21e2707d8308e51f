//! Packs read on demand (format version 9, `format::lazy_pack`): a model resolved from the
//! ISOs it needs is the whole pack's, byte for byte in what it synthesizes (calibrated, stored
//! interpolated, interpolated now across a conversion-gain switch, extrapolated; every component
//! and the pixel-only model; clean images at the reference and the target brightness); only
//! those ISOs are decoded; older versions open too; a damaged or cut file is refused with an
//! error that names it, never a panic.

mod interp_sim;

use ndarray::Array2;
use noisecal_core::derive::interp::{self, InterpOptions};
use noisecal_core::format::lazy_pack::LazyPack;
use noisecal_core::model::structure::Components;
use noisecal_core::resolve::{ModelKind, resolve_model, resolve_on_demand};
use noisecal_core::synth::{CleanAt, synthesize};
use noisecal_core::{CalibrationSession, ModelPack, SessionConfig};
use noisecal_sim::{Chart, SensorModel, SessionPlan, Simulator};

/// A small simulated session with structured components at 4 calibrated ISOs, and 2 more ISOs
/// interpolated into the pack (stored, as `noisecal interp` stores them).
fn structured_pack() -> ModelPack {
    let sim =
        Simulator::new(SensorModel::phone_10bit(), Chart::color_checker(96, 64).expect("chart"), 5).expect("simulator");
    let plan = SessionPlan::for_simulator(&sim, vec![100, 400, 1600, 3200], 4).expect("plan").with_ev_steps(-2..=2);
    let mut config = SessionConfig::new(plan.reference_iso);
    config.make = "sim".into();
    let mut session = CalibrationSession::new(sim.layout(), config).expect("session");
    plan.feed(&sim, &mut session, |_, _| ()).expect("capture");
    let pack = session.finish().expect("a pack");
    assert!(pack.structure.len() == 4, "the session calibrates structured components at every ISO");
    interp::materialize(&pack, &[200, 800], false, &InterpOptions::default()).expect("interpolated").0
}

/// A 6-ISO pack of a dual-gain sensor (switch between ISO 400 and 800), no structured
/// components.
fn switch_pack() -> ModelPack {
    let sim = interp_sim::simulator(SensorModel::phone_12bit(), 3);
    interp_sim::sim_pack(&sim, &[100, 200, 400, 800, 1600, 3200], 64, 3_000, 5).compacted()
}

fn ramp(pack: &ModelPack) -> Array2<u16> {
    let (h, w) = (24, 32);
    let white = pack.layout.white as usize;
    Array2::from_shape_fn((h, w), |(y, x)| ((y * w + x) * white / (h * w)) as u16)
}

/// Resolves `iso` on the whole pack and on demand from its file, and checks the two agree: the
/// same model, the same error, the same synthesized bytes. Returns the ISOs decoded (`None`
/// when both refuse).
fn compare(
    bytes: &[u8],
    whole: &ModelPack,
    iso: u32,
    which: Components,
    clean_at: CleanAt,
    ext: bool,
) -> Option<Vec<u32>> {
    let lazy = LazyPack::open(bytes).expect("opens");
    let full = resolve_model(whole, iso, ModelKind::Noisecal, ext);
    let demand = resolve_on_demand(&lazy, iso, ModelKind::Noisecal, which, ext);
    let (part, resolved) = match (full, demand) {
        (Err(a), Err(b)) => {
            assert_eq!(noisecal_core::Error::from(a).to_string(), b.to_string(), "ISO {iso}");
            return None;
        }
        (Ok(a), Ok((part, b))) => {
            assert_eq!(a.model, b.model, "ISO {iso}: the model");
            (part, b)
        }
        (a, b) => {
            panic!("ISO {iso}: whole pack {:?}, on demand {:?}", a.map(|r| r.model.iso), b.map(|r| r.1.model.iso))
        }
    };
    let s_full = resolved.sampler(whole, which, clean_at, ext).expect("sampler");
    let s_part = resolved.sampler(&part, which, clean_at, ext).expect("sampler");
    let clean = ramp(whole);
    for seed in [1, 2] {
        assert_eq!(
            synthesize(&s_full, clean.view(), seed),
            synthesize(&s_part, clean.view(), seed),
            "ISO {iso} {which:?} {clean_at:?}: the same bytes"
        );
    }
    assert_eq!(part.iso_list(), lazy.decoded_isos(), "the pack handed back holds what was decoded");
    Some(lazy.decoded_isos())
}

#[test]
fn on_demand_models_are_the_whole_packs_and_decode_only_their_sources() {
    let whole = structured_pack();
    let bytes = whole.to_bytes().expect("bytes");
    let whole = ModelPack::from_bytes(&bytes).expect("loads");
    assert_eq!(whole.iso_list(), vec![100, 200, 400, 800, 1600, 3200]);
    let all = Components::ALL;
    let pixel = Components::PIXEL;
    // A calibrated ISO with its own components: itself only.
    for clean_at in [CleanAt::Reference, CleanAt::Target] {
        assert_eq!(compare(&bytes, &whole, 1600, all, clean_at, false), Some(vec![1600]));
    }
    assert_eq!(compare(&bytes, &whole, 400, pixel, CleanAt::Reference, false), Some(vec![400]));
    // A stored interpolated ISO (stored with its derived components): itself.
    assert!(whole.structure_of(800).is_some());
    assert_eq!(compare(&bytes, &whole, 800, all, CleanAt::Reference, false), Some(vec![800]));
    // Without stored components, the calibrated ISOs they are derived from too.
    let mut bare = whole.clone();
    bare.structure.retain(|s| s.iso != 800);
    let bare_bytes = bare.to_bytes().expect("bytes");
    assert_eq!(compare(&bare_bytes, &bare, 800, all, CleanAt::Reference, false), Some(vec![400, 800, 1600]));
    assert_eq!(compare(&bytes, &whole, 200, pixel, CleanAt::Target, false), Some(vec![200]));
    // Interpolated now: the plan's neighbours (at most 4 of the 4 calibrated here; never the
    // stored interpolated ones).
    for iso in [300, 1000, 2500] {
        let decoded = compare(&bytes, &whole, iso, all, CleanAt::Reference, false).expect("inside");
        let plan = interp::plan(&whole, iso, false).expect("plan");
        let mut want: Vec<u32> = plan.neighbours.clone();
        want.sort_unstable();
        assert_eq!(decoded, want, "ISO {iso}");
    }
    // Extrapolated (when asked), refused alike otherwise.
    assert!(compare(&bytes, &whole, 6400, all, CleanAt::Reference, true).is_some());
    assert!(compare(&bytes, &whole, 6400, all, CleanAt::Reference, false).is_none());
    assert!(compare(&bytes, &whole, 50, all, CleanAt::Target, true).is_some());
}

/// Across a conversion-gain switch the plan read from the index's noise laws is the decoded
/// pack's: the same neighbours, the same bytes; an ISO on the high-gain side decodes none of the
/// low-gain ISOs.
#[test]
fn on_demand_plans_see_the_gain_switch() {
    let whole = switch_pack();
    let bytes = whole.to_bytes().expect("bytes");
    let whole = ModelPack::from_bytes(&bytes).expect("loads");
    for iso in [150, 300, 500, 700, 1200, 2400] {
        let decoded = compare(&bytes, &whole, iso, Components::ALL, CleanAt::Reference, false).expect("inside");
        let plan = interp::plan(&whole, iso, false).expect("plan");
        assert!(decoded.iter().all(|k| plan.neighbours.contains(k) || plan.shape_from.contains(k)), "ISO {iso}");
        if iso >= 700 {
            assert!(decoded.iter().all(|&k| k >= 800), "ISO {iso} decoded {decoded:?}");
        }
    }
    // The index's laws are the decoded models' fits, bit for bit.
    let lazy = LazyPack::open(&bytes[..]).expect("opens");
    let laws = interp::calibrated_laws(&whole);
    let stored: Vec<_> =
        lazy.index().isos.iter().filter(|e| e.is_calibrated()).map(|e| (e.iso, e.noise_law())).collect();
    assert_eq!(stored, laws.iter().map(|l| (l.iso, l.law)).collect::<Vec<_>>());
}

/// Files of older versions open (decoded whole) and resolve alike; a whole pack from a version
/// 9 file is `ModelPack::from_bytes`'s; its bytes are handed back as they are.
#[test]
fn older_versions_open_and_whole_packs_agree() {
    let whole = switch_pack();
    let v9 = whole.to_bytes().expect("bytes");
    let v8 = whole.to_bytes_v8().expect("bytes");
    let from9 = LazyPack::open(&v9[..]).expect("opens");
    assert!(from9.decoded_isos().is_empty(), "opening decodes no ISO");
    assert_eq!(from9.current_bytes(), Some(&v9[..]));
    assert_eq!(from9.to_pack().expect("all"), ModelPack::from_bytes(&v9).expect("loads"));
    let from8 = LazyPack::open(v8).expect("opens");
    assert_eq!(from8.current_bytes(), None);
    let listed = |l: &noisecal_core::format::compact::PackIndex| {
        l.isos.iter().map(|e| (e.iso, e.origin.clone(), e.structured, e.law)).collect::<Vec<_>>()
    };
    assert_eq!(listed(from8.index()), listed(from9.index()), "the same ISO list and laws");
    for iso in [200, 1200] {
        let (a, ra) = resolve_on_demand(&from8, iso, ModelKind::Noisecal, Components::ALL, false).expect("v8");
        let (b, rb) = resolve_on_demand(&from9, iso, ModelKind::Noisecal, Components::ALL, false).expect("v9");
        assert_eq!((a, ra.model), (b, rb.model));
    }
    // A baseline decodes the whole pack and is the whole pack's.
    let (_, hg) = resolve_on_demand(&from9, 1200, ModelKind::Hg, Components::ALL, false).expect("hg");
    assert_eq!(hg.model, resolve_model(&whole, 1200, ModelKind::Hg, false).expect("hg").model);
}

/// Damage anywhere (the index's CRC recomputed, so the damage itself is what is read; in a
/// section, its own CRC caught), a file cut short anywhere, bytes added: an error naming the
/// model pack and what is wrong, from the whole reader and the on-demand one alike, never a
/// panic.
#[test]
fn damaged_and_cut_files_are_refused_with_a_clear_error() {
    let whole = switch_pack();
    let v9 = whole.to_bytes().expect("bytes");
    let header = 24;
    let index_len = u64::from_le_bytes(v9[12..20].try_into().expect("8 bytes")) as usize;
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut refused = 0;
    for k in 0..300 {
        let mut b = v9.clone();
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        let at = header + (state as usize) % (b.len() - header);
        b[at] ^= 1 << (k % 8);
        if at < header + index_len {
            let crc = crc32fast::hash(&b[header..header + index_len]);
            b[20..24].copy_from_slice(&crc.to_le_bytes());
        }
        let whole = ModelPack::from_bytes(&b);
        let lazy = LazyPack::open(&b[..]).and_then(|l| l.to_pack());
        assert_eq!(whole.is_ok(), lazy.is_ok(), "flip at {at}");
        match whole {
            Ok(q) => q.check().expect("a loaded pack passes its checks"),
            Err(e) => {
                let text = e.to_string();
                assert!(text.starts_with("model pack"), "{text}");
                refused += 1;
            }
        }
    }
    assert!(refused > 250, "only {refused} of 300 damaged files refused");
    for cut in [1, 9, header - 1, header + 3, header + index_len, v9.len() - 100, v9.len() - 1] {
        let e = LazyPack::open(&v9[..cut]).expect_err("a cut file is refused when opened").to_string();
        assert!(e.contains("truncated") && e.contains("write it again"), "cut at {cut}: {e}");
        assert_eq!(ModelPack::from_bytes(&v9[..cut]).expect_err("refused").to_string(), e);
    }
    let mut longer = v9.clone();
    longer.extend_from_slice(b"more");
    let e = LazyPack::open(&longer[..]).expect_err("refused").to_string();
    assert!(e.contains("4 trailing bytes after the last ISO section"), "{e}");
    // A section's damage is found when that ISO is decoded: the others still decode.
    let lazy_ok = LazyPack::open(&v9[..]).expect("opens");
    let last = lazy_ok.index().isos.last().expect("an ISO").iso;
    let mut b = v9.clone();
    let n = b.len();
    b[n - 10] ^= 0x10;
    let lazy = LazyPack::open(&b[..]).expect("the index is whole");
    assert!(lazy.pack_with(&[100]).is_ok());
    let e = lazy.pack_with(&[last]).expect_err("refused").to_string();
    assert!(e.contains("model pack is corrupt: checksum"), "{e}");
}
