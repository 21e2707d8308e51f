//! Frames of sensors without the structured components (frame offsets, column noise, heavy-tailed
//! row offsets) stay byte-identical: the digests below were taken before those components were
//! added, so every existing pack, test and `noisecal demo` output stays what it was.

use noisecal_sim::{Chart, SensorModel, Simulator, random_sensor};

/// FNV-1a over the frame's samples and its metadata.
fn digest(sim: &Simulator, iso: u32, exposure_ns: u64, index: u64) -> u64 {
    let (frame, meta) = sim.capture(iso, exposure_ns, index).expect("capture");
    let mut h = 0xcbf2_9ce4_8422_2325u64;
    let mut eat = |b: u8| {
        h ^= b as u64;
        h = h.wrapping_mul(0x0100_0000_01b3);
    };
    for v in frame.iter() {
        for b in v.to_le_bytes() {
            eat(b);
        }
    }
    for b in meta.iso.to_le_bytes().into_iter().chain(meta.exposure_ns.to_le_bytes()) {
        eat(b);
    }
    h
}

fn digests() -> Vec<u64> {
    let mut out = Vec::new();
    let mut dsnu = SensorModel::phone_12bit();
    dsnu.dsnu_pre_e = 0.4;
    dsnu.dsnu_post_dn = 0.3;
    for (i, model) in [SensorModel::phone_10bit(), dsnu, SensorModel::phone_14bit()].into_iter().enumerate() {
        let sim = Simulator::new(model, Chart::color_checker(96, 72).expect("chart"), 3 + i as u64).expect("sim");
        let base = sim.model().base_iso;
        let e = sim.mid_range_exposure_ns(base).expect("exposure");
        for (iso, k) in [(base, 1u64), (base * 8, 8), (base * 64, 64)] {
            out.push(digest(&sim, iso, e / k, 5));
        }
        let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(9);
        let s = sim.sample_noise_at_level(base * 8, 300.0, 1, 2000, &mut rng).expect("samples");
        out.push(s.iter().fold(0u64, |a, &x| a.wrapping_mul(31).wrapping_add(x as i64 as u64)));
        let v = sim.predicted_variance(base * 8, 300.0, 2).expect("variance");
        out.push(v.to_bits());
        let c = sim.clean_expected(base * 8, e / 8).expect("clean");
        out.push(c.iter().fold(0u64, |a, &x| a.wrapping_mul(31).wrapping_add(x.to_bits() as u64)));
    }
    for seed in [3u64, 17, 40] {
        let rs = random_sensor(seed);
        let sim = Simulator::new(rs.model.clone(), Chart::color_checker(64, 48).expect("chart"), seed).expect("sim");
        let base = sim.model().base_iso;
        let e = sim.mid_range_exposure_ns(base).expect("exposure");
        out.push(digest(&sim, base * 4, e / 4, 2));
    }
    out
}

#[test]
fn frames_without_structured_components_are_unchanged() {
    let got = digests();
    let want: [u64; 21] = [
        14015156367162862658,
        10299505341174247552,
        230755680181138248,
        2682969079607986620,
        4647301442332122290,
        2973940993378094038,
        7762908884795028370,
        11527998626589922117,
        9408966356079196087,
        6030878191385462835,
        4643485400730086021,
        12070159300827855903,
        409164376888317529,
        8949622074795947218,
        3230463045514823823,
        16190942816072587449,
        4647234603701847856,
        6544963448779849593,
        6305202979013677761,
        15206612607924867361,
        10376355528079010102,
    ];
    assert_eq!(got, want.to_vec(), "frames changed: {got:?}");
}
