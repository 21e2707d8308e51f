//! `noisecal simulate --noise-profile`: every noisy DNG carries the simulated sensor's true
//! NoiseProfile at its ISO, read back by noisecal's own reader and by exiftool (when installed),
//! taken into the pack by `calibrate`; without the flag the DNGs carry none (their bytes as
//! before). Clean training images of a bench set carry none.

use std::path::Path;

use noisecal_cli::simulate::Preset;
use noisecal_cli::truth_profile::truth_noise_profile;
use noisecal_core::model::layout::CfaColor;

mod support;

fn s(p: &Path) -> &str {
    p.to_str().expect("UTF-8 path")
}

fn dngs(d: &Path) -> Vec<std::path::PathBuf> {
    let mut v: Vec<_> = std::fs::read_dir(d)
        .expect("dir")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|e| e == "dng"))
        .collect();
    v.sort();
    v
}

/// The truth's profile per colour plane (R, G, B): the mean over that colour's CFA positions.
fn truth_planes(iso: u32) -> Vec<(f64, f64)> {
    let chart = noisecal_sim::Chart::flat(16, 16, [0.5; 3]).expect("chart");
    let sim = noisecal_sim::Simulator::new(Preset::Phone12.model(), chart, 5).expect("sim");
    let p = truth_noise_profile(&sim, iso).expect("profile");
    let colors = sim.model().cfa.colors();
    [CfaColor::Red, CfaColor::Green, CfaColor::Blue]
        .iter()
        .map(|&c| {
            let pos: Vec<usize> = (0..4).filter(|&q| colors[q] == c).collect();
            let n = pos.len() as f64;
            (pos.iter().map(|&q| p.scale(q)).sum::<f64>() / n, pos.iter().map(|&q| p.offset(q)).sum::<f64>() / n)
        })
        .collect()
}

fn close(a: f64, b: f64) -> bool {
    (a - b).abs() <= 1e-9 * b.abs().max(1e-12)
}

#[test]
fn simulated_dngs_carry_the_true_noise_profile_and_the_pack_keeps_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (with, without) = (dir.path().join("with"), dir.path().join("without"));
    let common =
        ["simulate", "--preset", "phone12", "--isos", "400,1600", "--frames", "4", "--width", "64", "--height", "48"];
    let r = support::run_quiet(common.iter().copied().chain(["--dngs", s(&with), "--noise-profile"]));
    assert!(r.ok, "{}", r.stderr);
    let r = support::run_quiet(common.iter().copied().chain(["--dngs", s(&without)]));
    assert!(r.ok, "{}", r.stderr);

    let exiftool = std::process::Command::new("exiftool").arg("-ver").output().is_ok_and(|o| o.status.success());
    if !exiftool {
        eprintln!(
            "exiftool not installed (apt-get install libimage-exiftool-perl): NoiseProfile read back by noisecal only"
        );
    }
    let (files, plain) = (dngs(&with), dngs(&without));
    assert_eq!(files.len(), plain.len());
    let mut isos = std::collections::BTreeSet::new();
    for (f, g) in files.iter().zip(&plain) {
        let img = noisecal_input::dng::read_dng(f).expect("read");
        let iso = img.meta.iso;
        isos.insert(iso);
        let got = img.noise_profile.clone().expect("a NoiseProfile");
        let want = truth_planes(iso);
        assert_eq!(got.len(), 3, "{}: one pair per colour plane", f.display());
        for (g, w) in got.iter().zip(&want) {
            assert!(close(g.0, w.0) && close(g.1, w.1), "{} ISO {iso}: {got:?} vs truth {want:?}", f.display());
        }
        // Same pixels, no profile without the flag.
        let other = noisecal_input::dng::read_dng(g).expect("read");
        assert!(other.noise_profile.is_none(), "{} has a NoiseProfile without --noise-profile", g.display());
        assert_eq!(other.pixels, img.pixels);
        if exiftool {
            let out = std::process::Command::new("exiftool")
                .args(["-n", "-s3", "-NoiseProfile"])
                .arg(f)
                .output()
                .expect("exiftool");
            let text = String::from_utf8_lossy(&out.stdout);
            let vals: Vec<f64> = text.split_whitespace().map(|v| v.parse().expect("a number")).collect();
            assert_eq!(vals.len(), 6, "exiftool read {text:?} from {}", f.display());
            for (k, w) in want.iter().enumerate() {
                assert!(close(vals[2 * k], w.0) && close(vals[2 * k + 1], w.1), "exiftool: {vals:?} vs truth {want:?}");
            }
        }
    }
    // The profile grows with the gain: S (shot noise) and O (read noise) at 1600 above 400's.
    let (lo, hi) = (truth_planes(400), truth_planes(1600));
    assert!(hi[1].0 > 3.0 * lo[1].0 && hi[1].1 > lo[1].1, "{lo:?} → {hi:?}");
    assert!(isos.contains(&400) && isos.contains(&1600));

    // Calibrated, the pack keeps the camera's profile per ISO (the `noiseprofile` baseline).
    let pack = dir.path().join("p.pack");
    let r = support::run_quiet(["calibrate", s(&with), "-o", s(&pack)]);
    assert!(r.ok, "{}", r.stderr);
    let r = support::run_quiet(["inspect", s(&pack), "--json"]);
    assert!(r.ok, "{}", r.stderr);
    let v: serde_json::Value = serde_json::from_str(&r.stdout).expect("inspect JSON");
    for i in v["isos"].as_array().expect("isos") {
        assert_eq!(
            i["noise_profile"],
            serde_json::Value::Bool(true),
            "ISO {} has no NoiseProfile in the pack",
            i["iso"]
        );
    }
}
