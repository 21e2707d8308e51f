//! Semantically impossible models are refused before they size anything: packs with a valid
//! framing but impossible content, absurd camera noise profiles, and far extrapolation.

use noisecal_core::derive::baselines::{self, BaselineKind};
use noisecal_core::derive::interp;
use noisecal_core::error::Remedy;
use noisecal_core::model::pack::{
    BinModel, BinSource, IsoModel, MAX_SIDE, ModelOrigin, ModelPack, NoiseProfile, PositionModel,
};
use noisecal_core::{CfaPattern, POSITIONS, SensorLayout};

/// A small valid pack: Gaussian-ish PMFs, calibrated at ISO 100 and 800.
fn pack() -> ModelPack {
    let layout = SensorLayout { width: 64, height: 64, cfa: CfaPattern::Rggb, black: [64.0; POSITIONS], white: 1023 };
    let bin_width = 4u16;
    let bins = ((1023.0 - 64.0) / bin_width as f32).floor() as usize + 1;
    let model = |iso: u32| {
        let spread = (iso / 100) as usize;
        IsoModel {
            iso,
            origin: ModelOrigin::Calibrated,
            frames: 8,
            drift_frames: 0,
            gain_ratio: [1.0; POSITIONS],
            noise_profile: Some(NoiseProfile([[1e-5 * iso as f64 / 100.0, 1e-7]; POSITIONS])),
            range: [[0, 1023]; POSITIONS],
            lattice: [None; POSITIONS],
            positions: (0..POSITIONS)
                .map(|_| {
                    PositionModel::new(
                        (0..bins)
                            .map(|_| BinModel {
                                first: -(spread as i32),
                                counts: (0..=2 * spread).map(|i| 1 + (spread - spread.abs_diff(i)) as u64).collect(),
                                samples: 1000,
                                source: BinSource::Measured,
                                measured: None,
                                clipped: false,
                                grid_step: 0,
                            })
                            .collect(),
                    )
                })
                .collect(),
        }
    };
    ModelPack {
        layout,
        make: "test".into(),
        model: "damaged".into(),
        bin_width,
        reference_iso: 100,
        pooling: None,
        isos: vec![model(100), model(800)],
        warnings: vec![],
        structure: vec![],
    }
}

#[test]
fn the_valid_pack_passes() {
    let p = pack();
    p.check().unwrap();
    assert!(baselines::fit(&p, &p.isos[0], BaselineKind::NoiseProfile).is_ok());
}

#[test]
fn impossible_packs_are_refused_by_check_and_decode() {
    type Damage = Box<dyn Fn(&mut ModelPack)>;
    let cases: Vec<(&str, Damage)> = vec![
        ("ISO 0", Box::new(|p| p.isos[0].iso = 0)),
        ("gain ratio NaN", Box::new(|p| p.isos[1].gain_ratio[2] = f64::NAN)),
        ("gain ratio", Box::new(|p| p.isos[1].gain_ratio[0] = -1.0)),
        ("NoiseProfile", Box::new(|p| p.isos[0].noise_profile = Some(NoiseProfile([[-1e-5, 1e-7]; POSITIONS])))),
        ("NoiseProfile", Box::new(|p| p.isos[0].noise_profile = Some(NoiseProfile([[1e-3, 1e10]; POSITIONS])))),
        ("pixels a side", Box::new(|p| p.layout.width = 100_000)),
    ];
    for (what, damage) in cases {
        let mut p = pack();
        damage(&mut p);
        let e = p.check().expect_err(what).to_string();
        assert!(e.contains(what) || e.contains(&MAX_SIDE.to_string()), "{what}: {e}");
        // The framing is valid (the encoder does not check): decoding must refuse it too.
        if let Ok(bytes) = p.to_bytes() {
            assert!(ModelPack::from_bytes(&bytes).is_err(), "{what} decoded");
        }
    }
}

#[test]
fn an_absurd_noise_profile_is_refused_without_allocating() {
    let mut p = pack();
    p.isos[0].noise_profile = Some(NoiseProfile([[1e-3, 1e10]; POSITIONS]));
    p.isos[1].noise_profile = Some(NoiseProfile([[1e-3, 1e6]; POSITIONS]));
    let err = baselines::fit(&p, &p.isos[0], BaselineKind::NoiseProfile).unwrap_err();
    assert_eq!(err.remedy(), Some(Remedy::ParametricModel));
    let e = err.to_string();
    assert!(e.contains("NoiseProfile is impossible") && e.contains("hg or pg"), "{e}");
    let e = baselines::interpolate(&p, 400, BaselineKind::NoiseProfile, false).unwrap_err().to_string();
    assert!(e.contains("impossible"), "{e}");
    assert!(NoiseProfile([[2e-4, 3e-6]; POSITIONS]).is_valid());
    assert!(!NoiseProfile([[f64::INFINITY, 0.0]; POSITIONS]).is_valid());
}

#[test]
fn extrapolation_is_bounded() {
    let p = pack();
    for iso in [800 * 16 + 1, 1_000_000, u32::MAX] {
        let e = interp::plan(&p, iso, true).unwrap_err().to_string();
        assert!(e.contains("stops beyond") && e.contains("calibrate an ISO nearer"), "{iso}: {e}");
        assert!(interp::model_for(&p, iso, true).is_err());
    }
    assert!(interp::plan(&p, 5, true).is_err(), "below 100/16");
    // Within reach it works, and the PMFs stay within the sensor's range.
    let (m, _) = interp::model_for(&p, 800 * 16, true).unwrap();
    let widest = m.positions.iter().flat_map(|pm| &pm.bins).map(|b| b.counts.len()).max().unwrap();
    assert!(widest <= 4 * 1024 + 8, "{widest}");
    assert!(interp::model_for(&p, 7, true).is_ok());
}
