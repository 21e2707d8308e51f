//! The dim-step rule on figures like EMVA set 002's (black 2.87 DN, dark frame means spread by
//! 0.05 DN of flicker).

use super::*;

/// A dark burst at 140 µs (set 002's: ISO 100 and 200 alike).
fn burst(levels: impl IntoIterator<Item = (u32, f64)>) -> DarkLevels {
    let mut d = DarkLevels::default();
    for (iso, l) in levels {
        d.push(iso, 140_000, l);
    }
    d
}

/// 50 frames per ISO at `mean`, spread ±`sd` (alternating, so the sample SD is about `sd`).
fn flickering(mean: f64, sd: f64) -> DarkLevels {
    burst([100, 200].into_iter().flat_map(|iso| (0..50).map(move |i| (iso, mean + if i % 2 == 0 { sd } else { -sd }))))
}

/// A step's 8 reference frames (ISO 100, twice the target's exposure) and its target (ISO 200).
fn step(level_ref: f64, level_target: f64, exposure_s: f64) -> Vec<Dim> {
    let ns = (exposure_s * 1e9) as u64;
    let at = |iso: u32, ns: u64, level| Dim { iso, exposure_ns: ns, brightness: iso as f64 * ns as f64 * 1e-9, level };
    let mut v: Vec<Dim> = (0..8).map(|_| at(100, 2 * ns, level_ref)).collect();
    v.push(at(200, ns, level_target));
    v
}

#[test]
fn a_dim_flat_field_above_the_dark_burst_is_lit_and_one_at_it_is_dark() {
    let dark = flickering(0.0, 0.05);
    // Set 002's 80 µs step: 1.6 DN at both ISOs (the target's gain is the reference's there);
    // the law from its bright steps (0.08 DN/µs at ISO 200) predicts 6.4 DN.
    let law = Some(0.08 / (200.0 * 1e-6));
    let lit = decide(&step(1.6, 1.6, 80e-6), None, &dark, law);
    assert_eq!(lit.dark, vec![false; 9], "{}", lit.why);
    // 0.1 DN on 8 reference frames: 0.1 / (0.05·√(1/8 + 1/50)) = 5.3 standard errors: lit,
    // though the law predicts 3.2 DN: the references' 80 µs are shorter than the burst's.
    let dim = decide(&step(0.1, 0.1, 40e-6), None, &dark, law);
    assert_eq!(dim.dark, vec![false; 9], "{}", dim.why);
    // The same mean at a longer exposure than the burst's may be dark current: dark.
    let v = decide(&step(0.1, 0.1, 400e-6), None, &dark, law);
    assert_eq!(v.dark, vec![true; 9], "{}", v.why);
    // At the dark burst's own mean, or within its flicker (0.06 DN: 3.2 SE), dark.
    for e in [0.0, 0.06, -0.3] {
        let v = decide(&step(e, e, 1e-6), None, &dark, law);
        assert_eq!(v.dark, vec![true; 9], "{e}: {}", v.why);
    }
}

#[test]
fn a_covered_lens_at_the_exposures_of_lit_steps_is_dark_without_a_dark_burst() {
    let none = DarkLevels::default();
    // Lit frames show 0.5 DN per µs at the reference gain (ISO 100 × 2 µs per µs of target).
    let law = Some(0.5 / (200.0 * 1e-6));
    // A covered lens 0.7 DN above the metadata's black (dark current, a black level that is off)
    // at exposures where light would give 20–200 DN: dark.
    for us in [40.0, 100.0, 400.0] {
        let v = decide(&step(0.7, 0.7, us * 1e-6), None, &none, law);
        assert_eq!(v.dark, vec![true; 9], "{us} µs: {}", v.why);
    }
    // A dim lit step at 2 DN where light predicts 5 DN: lit; under the slack (0.4 DN): dark.
    assert_eq!(decide(&step(2.0, 2.0, 10e-6), None, &none, law).dark, vec![false; 9]);
    assert_eq!(decide(&step(0.4, 0.4, 0.8e-6), None, &none, law).dark, vec![true; 9]);
}

#[test]
fn covered_frames_in_a_lit_step_are_dark_and_dim_ones_are_not() {
    let dark = flickering(0.0, 0.05);
    // The step's lit reference frames are 8 DN above black (a step's frames share one ISO ×
    // exposure, so its lit frames show that at every ISO): a frame at ISO 800 that holds 0.3 DN
    // is a covered lens; one at 7 DN is lit, and so is one at 1 DN beyond the burst's flicker.
    let covered = Dim { iso: 800, exposure_ns: 1000, brightness: 1.0, level: 0.3 };
    assert_eq!(decide(&[covered], Some(8.0), &dark, None).dark, vec![true]);
    let lit = Dim { level: 7.0, ..covered };
    assert_eq!(decide(&[lit], Some(8.0), &dark, None).dark, vec![false]);
    let dim = Dim { iso: 200, level: 1.0, ..covered };
    assert_eq!(decide(&[dim], Some(8.0), &dark, None).dark, vec![false]);
}

#[test]
fn held_steps_wait_for_the_dark_burst_and_lit_frames_decide_their_step() {
    let mut s = DimSteps::default();
    let held = |iso, level| Held {
        path: PathBuf::from(format!("f{iso}_{level}.dng")),
        meta: FrameMeta::new(iso, 1000),
        label: String::new(),
        dim: Dim { iso, exposure_ns: 1000, brightness: iso as f64 * 1e-6, level },
    };
    // A step of dim frames only: held until the end.
    s.begin_step(2000);
    assert_eq!(s.dim(held(100, 1.0)), None);
    assert_eq!(s.dim(held(200, 2.0)), None);
    // A step whose references are dim and whose target is lit: the references are pushed
    // before the target, a covered frame after it is dark.
    s.begin_step(4000);
    assert_eq!(s.dim(held(100, 1.0)), None);
    let (lit, dark) = s.lit(Dim { iso: 800, exposure_ns: 1000, brightness: 1.0, level: 8.0 }, 250.0);
    assert_eq!((lit.len(), dark.len()), (1, 0));
    // A frame as lit as its peers is decided at once; a covered one at an ISO with no dark
    // burst yet waits for its ISO's other covered frames (below).
    assert_eq!(s.dim(held(800, 0.1)), None);
    assert_eq!(s.dim(held(800, 7.5)), Some(false));
    assert!(s.waiting());
    for i in 0..20 {
        s.dark_frame(&FrameMeta::new(100, 1000), 0.01 * (i % 2) as f64);
        s.dark_frame(&FrameMeta::new(200, 1000), 0.01 * (i % 2) as f64);
    }
    let (steps, dark) = s.finish();
    assert_eq!(steps.len(), 1, "{:?}", s.notes);
    assert_eq!((steps[0].reference_exposure_ns, steps[0].frames.len(), dark.len()), (2000, 2, 1));
}

#[test]
fn covered_frames_in_a_lit_step_without_a_burst_are_decided_together() {
    // `rust/cli/tests/dark_frames.rs`'s case: a lens-covered burst matching a lit step's ISO ×
    // exposure, no separate dark burst, and frame offsets that move single covered frames by
    // up to 0.9 DN above black (beyond `NO_BURST_SLACK`). Deciding each frame alone took 3 of 8
    // for lit.
    let mut s = DimSteps::default();
    let held = |level: f64| Held {
        path: PathBuf::from(format!("f800_{level}.dng")),
        meta: FrameMeta::new(800, 1000),
        label: String::new(),
        dim: Dim { iso: 800, exposure_ns: 1000, brightness: 800e-6, level },
    };
    s.begin_step(1000);
    let (lit, dark) = s.lit(Dim { iso: 800, exposure_ns: 1000, brightness: 800e-6, level: 40.0 }, 1000.0);
    assert_eq!((lit.len(), dark.len()), (0, 0));
    let levels = [0.7, -1.7, 0.87, 0.2, -0.3, 0.71, 0.4, -0.5];
    for &l in &levels {
        assert_eq!(s.dim(held(l)), None, "held until its ISO's group is known");
    }
    let (steps, dark) = s.finish();
    assert!(steps.is_empty(), "{:?}", s.notes);
    assert_eq!(dark.len(), levels.len(), "{:?}", s.notes);
    // The same frames 4 DN brighter (a tenth of the step's light, beyond the slack as a group)
    // are lit: the group test still tells light.
    let mut s = DimSteps::default();
    s.begin_step(1000);
    s.lit(Dim { iso: 800, exposure_ns: 1000, brightness: 800e-6, level: 40.0 }, 1000.0);
    for &l in &levels {
        assert_eq!(s.dim(held(l + 4.0)), None);
    }
    let (steps, dark) = s.finish();
    assert_eq!((steps.len(), dark.len()), (1, 0), "{:?}", s.notes);
}
