//! `noisecal synth --clean-at reference|target` through the real binary, on a pack of a
//! simulated phone whose gain is not ∝ ISO (`gain_iso_exponent` 0.9: ISO 800 is 0.77 as bright
//! as ISO 50 at equal ISO × exposure): a clean ramp at ISO 800's own brightness gets noise of
//! zero mean with `--clean-at target`, and the gain shift `(g − 1)·(level − black)` by default,
//! which `--clean-at reference` spells out (same bytes). A bad value names the option.

use std::path::Path;

use ndarray::Array2;
use noisecal_core::{CalibrationSession, SessionConfig};
use noisecal_input::dng;
use noisecal_sim::{Chart, SensorModel, SessionPlan, Simulator};

mod support;

fn noisecal(args: &[&str]) -> (bool, String) {
    let out = support::run_quiet(args);
    (out.ok, out.stderr)
}

fn s(p: &Path) -> String {
    p.to_str().expect("utf-8 path").to_string()
}

#[test]
fn clean_at_target_adds_noise_without_mean_shift() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut model = SensorModel::phone_10bit();
    model.gain_iso_exponent = 0.9;
    let sim = Simulator::new(model, Chart::color_checker(128, 96).expect("chart"), 4).expect("sim");
    let plan = SessionPlan::for_simulator(&sim, vec![800], 5).expect("plan");
    let mut session = CalibrationSession::new(sim.layout(), SessionConfig::new(plan.reference_iso)).expect("session");
    plan.feed(&sim, &mut session, |_, r| {
        r.expect("push");
    })
    .expect("capture");
    let pack = session.finish().expect("finish");
    let g = pack.iso(800).expect("ISO 800").gain_ratio;
    assert!(g.iter().all(|g| (0.72..0.82).contains(g)), "gain ratios {g:?}");
    let pack_path = dir.path().join("p.pack");
    std::fs::write(&pack_path, pack.to_bytes().expect("encode")).expect("write pack");

    // A ramp at ISO 800's brightness: columns from black to 60 % of where the reference saturates.
    let layout = sim.layout();
    let black = layout.black[0] as f64;
    let top = 0.6 * g[0] * (layout.white as f64 - black);
    let (h, w) = (layout.height as usize, layout.width as usize);
    let clean = Array2::from_shape_fn((h, w), |(_, x)| (black + x as f64 * top / w as f64).round() as u16);
    let (_, meta) = sim.capture(800, plan.exposure_ns(0, 800), 0).expect("capture");
    let clean_path = dir.path().join("clean.dng");
    dng::write_dng_from_layout(&clean_path, &layout, &meta, "Sim", "Phone", &clean).expect("clean DNG");

    let run = |name: &str, extra: &[&str]| -> Array2<u16> {
        let out = dir.path().join(name);
        let p = s(&pack_path);
        let mut args = vec!["synth", "--pack", &p, "--iso", "800", "--seed", "5"];
        args.extend_from_slice(&["--components", "pixel"]);
        args.extend_from_slice(extra);
        let (c, o) = (s(&clean_path), s(&out));
        args.extend_from_slice(&[&c, "-o", &o]);
        let (ok, err) = noisecal(&args);
        assert!(ok, "synth {extra:?}: {err}");
        dng::read_dng_source(&out).expect("read back").pixels().to_owned()
    };
    let default = run("default.dng", &[]);
    let reference = run("reference.dng", &["--clean-at", "reference"]);
    let target = run("target.dng", &["--clean-at", "target"]);
    assert_eq!(default, reference, "--clean-at reference is the default, byte for byte");

    // Per band of level above black: mean of noisy − clean, its SE (pixels are independent with
    // `--components pixel`), and the gain shift.
    const BANDS: usize = 4;
    let stats = |noisy: &Array2<u16>| -> Vec<(f64, f64, f64, f64)> {
        let mut acc = [(0.0f64, 0.0f64, 0usize, 0.0f64); BANDS];
        for ((y, x), &c) in clean.indexed_iter() {
            let l = c as f64 - black;
            let b = ((l / top * BANDS as f64) as usize).min(BANDS - 1);
            let d = noisy[(y, x)] as f64 - c as f64;
            let a = &mut acc[b];
            a.0 += d;
            a.1 += d * d;
            a.2 += 1;
            a.3 += (g[(y & 1) * 2 + (x & 1)] - 1.0) * l;
        }
        acc.iter()
            .enumerate()
            .map(|(b, &(s1, s2, n, shift))| {
                let n = n as f64;
                let m = s1 / n;
                let se = ((s2 / n - m * m).max(0.0) / n).sqrt();
                ((b as f64 + 0.5) * top / BANDS as f64, m, se, shift / n)
            })
            .collect()
    };
    for ((c, m, se, shift), (_, mr, ser, _)) in stats(&target).into_iter().zip(stats(&reference)) {
        if std::env::var_os("NOISECAL_PRINT").is_some() {
            eprintln!(
                "level {c:5.0}: target {m:+.3} (SE {se:.3}), reference {mr:+.2} (SE {ser:.3}), gain shift {shift:+.2}"
            );
        }
        assert!(m.abs() <= 3.0 * se + 0.25 + 0.002 * c, "level {c:.0}: --clean-at target mean shift {m:+.3} DN");
        assert!((mr - shift).abs() <= 3.0 * ser + 0.5 + 0.005 * c, "level {c:.0}: default {mr:+.2} DN vs {shift:+.2}");
    }

    // A single image at the target brightness (built for its levels alone) says which gain
    // ratios divide its levels, as a folder's run does.
    let (c, o) = (s(&clean_path), s(&dir.path().join("told.dng")));
    let p = s(&pack_path);
    let told = support::run(["synth", "--pack", &p, "--iso", "800", "--clean-at", "target", &c, "-o", &o]);
    assert!(told.ok && told.stderr.contains("divided by the gain ratios"), "{}", told.stderr);

    // A wrong value names the option and its values.
    let (c, o) = (s(&clean_path), s(&dir.path().join("bad.dng")));
    let p = s(&pack_path);
    let (ok, err) = noisecal(&["synth", "--pack", &p, "--iso", "800", "--clean-at", "brighter", &c, "-o", &o]);
    assert!(!ok && err.contains("--clean-at") && err.contains("reference") && err.contains("target"), "{err}");
}
