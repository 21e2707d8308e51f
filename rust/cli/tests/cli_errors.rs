//! Bad input through the real binary: a clear error naming the thing and the fix, never a panic,
//! and nothing already written is lost.

use std::path::Path;

mod support;

fn noisecal(args: &[&str]) -> (bool, String) {
    let out = support::run_quiet(args);
    (out.ok, out.stderr)
}

/// The 64×48 test session (ISOs 200 and 800, EV −1 and +1, 3 frames a burst) as DNGs in
/// `dir/dngs`.
fn simulate(dir: &Path) {
    simulate_as(&dir.join("dngs"), "--dngs");
}

/// The same session written by `simulate` to `out` as `kind` (`--dngs` or `--rec`).
fn simulate_as(out: &Path, kind: &str) {
    let (ok, err) = noisecal(&support::simulate(
        ("64", "48"),
        "3",
        "200,800",
        "--ev=-1,1",
        &[kind, out.to_str().expect("a UTF-8 path")],
    ));
    assert!(ok, "{err}");
}

#[test]
fn bad_inputs_get_clear_errors() {
    let dir = tempfile::tempdir().unwrap();
    simulate(dir.path());
    let dngs = dir.path().join("dngs");
    let pack = dir.path().join("p.pack");
    let (ok, err) =
        noisecal(&["calibrate", dngs.to_str().unwrap(), "-o", pack.to_str().unwrap(), "--min-samples", "50"]);
    assert!(ok, "{err}");
    let good = std::fs::read(&pack).unwrap();

    // A truncated pack.
    let cut = dir.path().join("cut.pack");
    std::fs::write(&cut, &good[..good.len() / 2]).unwrap();
    let (ok, err) = noisecal(&["inspect", cut.to_str().unwrap()]);
    assert!(!ok && err.contains("truncated") && err.contains("cut.pack"), "{err}");
    // Not a pack at all.
    let (ok, err) = noisecal(&["inspect", dngs.join("f00000.dng").to_str().unwrap()]);
    assert!(!ok && err.contains("not a model pack"), "{err}");

    // An ISO outside the pack.
    let clean = dngs.join("f00000.dng");
    let out = dir.path().join("noisy.dng");
    let (ok, err) = noisecal(&[
        "synth",
        "--pack",
        pack.to_str().unwrap(),
        "--iso",
        "6400",
        clean.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ]);
    assert!(!ok && err.contains("6400") && err.contains("--extrapolate"), "{err}");
    assert!(!out.exists());

    // A corrupt DNG in the folder: named, and the existing pack is kept.
    let bad = dngs.join("f99999.dng");
    std::fs::write(&bad, b"II*\0garbage that is not a DNG at all").unwrap();
    let (ok, err) = noisecal(&["calibrate", dngs.to_str().unwrap(), "-o", pack.to_str().unwrap()]);
    assert!(!ok && err.contains("f99999.dng"), "{err}");
    assert_eq!(std::fs::read(&pack).unwrap(), good, "a failed calibration damaged the existing pack");
    std::fs::remove_file(&bad).unwrap();

    // A missing reference burst.
    let (ok, err) =
        noisecal(&["calibrate", dngs.to_str().unwrap(), "-o", pack.to_str().unwrap(), "--reference-iso", "25"]);
    assert!(!ok && err.contains("reference"), "{err}");

    // A frame of another size in the folder.
    let other = dir.path().join("other");
    let (ok, e) =
        noisecal(&support::simulate(("32", "32"), "1", "200", "--ev=0", &["--dngs", other.to_str().unwrap()]));
    assert!(ok, "{e}");
    std::fs::copy(other.join("f00000.dng"), dngs.join("zz_other.dng")).unwrap();
    let (ok, err) = noisecal(&["calibrate", dngs.to_str().unwrap(), "-o", pack.to_str().unwrap()]);
    assert!(!ok && err.contains("zz_other.dng") && err.contains("32×32"), "{err}");

    // Not a folder nor a recording.
    let (ok, err) = noisecal(&["calibrate", clean.to_str().unwrap(), "-o", pack.to_str().unwrap()]);
    assert!(!ok && err.contains("neither a folder of DNGs nor a noisecal recording"), "{err}");
    assert_eq!(std::fs::read(&pack).unwrap(), good);
}

#[test]
fn synth_is_reproducible_and_reads_back() {
    let dir = tempfile::tempdir().unwrap();
    simulate(dir.path());
    let dngs = dir.path().join("dngs");
    let pack = dir.path().join("p.pack");
    assert!(noisecal(&["calibrate", dngs.to_str().unwrap(), "-o", pack.to_str().unwrap(), "--min-samples", "50"]).0);
    let clean = dngs.join("f00000.dng");
    let run = |name: &str, seed: &str, threads: &str| {
        let out = dir.path().join(name);
        let (ok, err) = noisecal(&[
            "--threads",
            threads,
            "synth",
            "--pack",
            pack.to_str().unwrap(),
            "--iso",
            "800",
            "--seed",
            seed,
            clean.to_str().unwrap(),
            "-o",
            out.to_str().unwrap(),
        ]);
        assert!(ok, "{err}");
        std::fs::read(out).unwrap()
    };
    let a = run("a.dng", "7", "1");
    let b = run("b.dng", "7", "2");
    let c = run("c.dng", "8", "2");
    assert_eq!(a, b, "same seed, different thread count, different bytes");
    assert_ne!(a, c);
    let img = noisecal_input::dng::read_dng(&dir.path().join("a.dng")).unwrap();
    assert_eq!(img.meta.iso, 800);
    // ISO 400 is between the calibrated 200 and 800: interpolated, and said so (not under -q).
    let out = dir.path().join("i.dng");
    let args = [
        "synth",
        "--pack",
        pack.to_str().unwrap(),
        "--iso",
        "400",
        clean.to_str().unwrap(),
        "-o",
        out.to_str().unwrap(),
    ];
    let loud = support::command().args(args).output().expect("run noisecal");
    let err = String::from_utf8_lossy(&loud.stderr);
    assert!(loud.status.success() && err.contains("interpolated"), "{err}");
    let (ok, err) = noisecal(&args);
    assert!(ok && !err.contains("interpolated"), "-q still printed: {err}");
}

#[test]
fn synth_takes_levels_above_black() {
    let dir = tempfile::tempdir().unwrap();
    simulate(dir.path());
    let dngs = dir.path().join("dngs");
    let pack = dir.path().join("p.pack");
    assert!(noisecal(&["calibrate", dngs.to_str().unwrap(), "-o", pack.to_str().unwrap(), "--min-samples", "50"]).0);
    let template = noisecal_input::dng::read_dng(&dngs.join("f00000.dng")).unwrap();
    // The same scene written with the pack's black level (64) and with black 60.
    let scene =
        ndarray::Array2::from_shape_fn(template.pixels.dim(), |(y, x)| (150 + 3 * ((x / 8 + y / 8) % 20)) as u16);
    let mut layout = template.layout.clone();
    let meta = noisecal_core::FrameMeta { black: None, ..template.meta };
    let a = dir.path().join("a.dng");
    noisecal_input::dng::write_dng_from_layout(&a, &layout, &meta, "m", "p", &scene).unwrap();
    layout.black = [60.0; 4];
    let b = dir.path().join("b.dng");
    noisecal_input::dng::write_dng_from_layout(&b, &layout, &meta, "m", "p", &scene.mapv(|v| v - 4)).unwrap();
    for (input, out) in [(&a, "na.dng"), (&b, "nb.dng")] {
        let (ok, err) = noisecal(&[
            "synth",
            "--pack",
            pack.to_str().unwrap(),
            "--iso",
            "800",
            "--seed",
            "3",
            input.to_str().unwrap(),
            "-o",
            dir.path().join(out).to_str().unwrap(),
        ]);
        assert!(ok, "{err}");
    }
    let na = noisecal_input::dng::read_dng(&dir.path().join("na.dng")).unwrap().pixels;
    let nb = noisecal_input::dng::read_dng(&dir.path().join("nb.dng")).unwrap().pixels;
    assert_ne!(na, scene, "noise was added");
    assert_eq!(nb, na.mapv(|v| v.saturating_sub(4)), "the same noise, 4 DN lower");
}

#[test]
fn a_closed_stdout_ends_quietly() {
    let dir = tempfile::tempdir().expect("tempdir");
    simulate(dir.path());
    let dngs = dir.path().join("dngs");
    let pack = dir.path().join("p.pack");
    assert!(noisecal(&["calibrate", dngs.to_str().expect("path"), "-o", pack.to_str().expect("path")]).0);
    let (pack, dngs) = (pack.to_str().expect("path"), dngs.to_str().expect("path"));
    let interp = dir.path().join("i.pack");
    let runs: [&[&str]; 4] = [
        &["inspect", pack],
        &["inspect", "--json", pack],
        &["eval", "--pack", pack, dngs, "--seeds", "1"],
        &["interp", "--pack", pack, "--iso", "400", "-o", interp.to_str().expect("path")],
    ];
    for args in runs {
        // The reader is gone before the command writes a byte: every write fails with EPIPE.
        let (reader, writer) = std::io::pipe().expect("pipe");
        drop(reader);
        let child = support::command()
            .args(args)
            .arg("-q")
            .stdout(writer)
            .stderr(std::process::Stdio::piped())
            .spawn()
            .expect("run noisecal");
        let out = child.wait_with_output().expect("wait");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(out.status.success(), "{args:?} with a closed stdout: {:?}, {stderr}", out.status);
        assert!(stderr.is_empty(), "{args:?} with a closed stdout said: {stderr}");
    }
}

#[test]
fn renoise_takes_levels_above_black() {
    let dir = tempfile::tempdir().expect("tempdir");
    simulate(dir.path());
    let dngs = dir.path().join("dngs");
    let pack = dir.path().join("p.pack");
    let (ok, err) = noisecal(&[
        "calibrate",
        dngs.to_str().expect("path"),
        "-o",
        pack.to_str().expect("path"),
        "--min-samples",
        "50",
    ]);
    assert!(ok, "{err}");
    // One capture written with the pack's black level (64) and again 4 DN lower, black 60.
    let capture = noisecal_input::dng::read_dng(&dngs.join("f00003.dng")).expect("read");
    let mut layout = capture.layout.clone();
    let meta = noisecal_core::FrameMeta { black: None, ..capture.meta };
    let a = dir.path().join("a.dng");
    noisecal_input::dng::write_dng_from_layout(&a, &layout, &meta, "m", "p", &capture.pixels).expect("write");
    layout.black = [60.0; 4];
    let b = dir.path().join("b.dng");
    let lowered = capture.pixels.mapv(|v| v.saturating_sub(4));
    noisecal_input::dng::write_dng_from_layout(&b, &layout, &meta, "m", "p", &lowered).expect("write");
    for (input, out) in [(&a, "ra.dng"), (&b, "rb.dng")] {
        let (ok, err) = noisecal(&[
            "renoise",
            "--pack",
            pack.to_str().expect("path"),
            "--from-iso",
            "200",
            "--to-iso",
            "800",
            "--seed",
            "3",
            input.to_str().expect("path"),
            "-o",
            dir.path().join(out).to_str().expect("path"),
        ]);
        assert!(ok, "{err}");
    }
    let ra = noisecal_input::dng::read_dng(&dir.path().join("ra.dng")).expect("read").pixels;
    let rb = noisecal_input::dng::read_dng(&dir.path().join("rb.dng")).expect("read").pixels;
    assert_ne!(ra, capture.pixels, "noise was added");
    assert_eq!(rb, ra.mapv(|v| v.saturating_sub(4)), "the same noise on noise, 4 DN lower");
}

/// Degenerate sessions: a capture folder whose frames are all saturated, all one
/// noiseless level, all at black, or all masked (a texture with no flat pixel anywhere) is
/// refused, naming what is wrong; the existing pack is kept.
#[test]
fn degenerate_sessions_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    simulate(dir.path());
    let dngs = dir.path().join("dngs");
    let pack = dir.path().join("p.pack");
    let (ok, err) = noisecal(&["calibrate", dngs.to_str().unwrap(), "-o", pack.to_str().unwrap()]);
    assert!(ok, "{err}");
    let good = std::fs::read(&pack).unwrap();
    let mut files: Vec<_> = std::fs::read_dir(&dngs).unwrap().map(|e| e.unwrap().path()).collect();
    files.sort();
    // A fixed hash: the same texture in every frame, and fresh noise in each.
    let hash = |a: u64| {
        let mut z = a.wrapping_mul(0x9E37_79B9_7F4A_7C15);
        z = (z ^ (z >> 31)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z ^ (z >> 29)
    };
    let textured = |y: usize, x: usize, i: usize| {
        let texture = 100 + hash((y * 1000 + x) as u64) % 800;
        let noise = hash(((i + 1) * 1_000_003 + y * 1000 + x) as u64) % 9;
        (texture + noise) as u16
    };
    type Pixels<'a> = &'a dyn Fn(usize, usize, usize) -> u16;
    let cases: [(&str, Pixels<'_>, &str); 4] = [
        ("saturated", &|_, _, _| 1023, "are saturated"),
        ("flat", &|_, _, _| 500, "carry no noise at all"),
        ("black", &|_, _, _| 64, "frames are dark, at the black level"),
        ("masked", &textured, "has no flat pixels"),
    ];
    for (name, pixel, says) in cases {
        let d = dir.path().join(name);
        std::fs::create_dir(&d).unwrap();
        for (i, f) in files.iter().enumerate() {
            let img = noisecal_input::dng::read_dng(f).unwrap();
            let meta = noisecal_core::FrameMeta { black: None, ..img.meta };
            let px = ndarray::Array2::from_shape_fn(img.pixels.dim(), |(y, x)| pixel(y, x, i));
            let out = d.join(f.file_name().unwrap());
            noisecal_input::dng::write_dng_from_layout(&out, &img.layout, &meta, &img.make, &img.model, &px).unwrap();
        }
        let (ok, err) = noisecal(&["calibrate", d.to_str().unwrap(), "-o", pack.to_str().unwrap()]);
        assert!(!ok, "{name}: a degenerate session calibrated");
        assert!(err.contains(says), "{name}: {err}");
        assert_eq!(std::fs::read(&pack).unwrap(), good, "{name}: the existing pack was replaced");
    }
}

/// Flags are honoured: `synth --model hg|pg --extrapolate` extrapolates instead of asking
/// for the flag it was given; `synth` and `renoise` create a missing output folder as the other
/// commands do; `eval` does not suggest `--extrapolate`, which it lacks; `-q` silences
/// `calibrate`'s and `renoise`'s warnings.
#[test]
fn flags_folders_and_quiet_do_what_they_say() {
    let dir = tempfile::tempdir().unwrap();
    simulate(dir.path());
    let dngs = dir.path().join("dngs");
    let pack = dir.path().join("p.pack");
    let s = |p: &Path| p.to_str().unwrap().to_string();
    let (ok, err) = noisecal(&["calibrate", &s(&dngs), "-o", &s(&pack)]);
    assert!(ok, "{err}");
    let clean = s(&dngs.join("f00000.dng"));

    for model in ["hg", "pg"] {
        let out = dir.path().join(format!("x-{model}.dng"));
        let args = ["synth", "--pack", &s(&pack), "--iso", "3200", "--model", model, &clean, "-o", &s(&out)];
        let (ok, err) = noisecal(&args);
        assert!(!ok && err.contains("--extrapolate"), "{model}: {err}");
        let (ok, err) = noisecal(&[&args[..], &["--extrapolate"]].concat());
        assert!(ok, "{model} --extrapolate: {err}");
        assert_eq!(noisecal_input::dng::read_dng(&out).unwrap().meta.iso, 3200);
    }

    let deep = dir.path().join("new/deeper/n.dng");
    let (ok, err) = noisecal(&["synth", "--pack", &s(&pack), "--iso", "200", &clean, "-o", &s(&deep)]);
    assert!(ok && deep.is_file(), "synth into a missing folder: {err}");
    let deep = dir.path().join("new2/deeper/r.dng");
    let renoise = ["renoise", "--pack", &s(&pack), "--from-iso", "200", "--to-iso", "800", &clean, "-o", &s(&deep)];
    let (ok, err) = noisecal(&renoise);
    assert!(ok && deep.is_file(), "renoise into a missing folder: {err}");
    // -q (which `noisecal` adds) leaves stderr empty; without it the warnings are said.
    assert!(err.is_empty(), "renoise -q printed: {err}");
    let loud = support::command().args(renoise).output().unwrap();
    assert!(loud.status.success() && String::from_utf8_lossy(&loud.stderr).contains("warning"));

    // A recording cut short calibrates with a warning, which -q keeps off stderr.
    let rec = dir.path().join("s.rec");
    simulate_as(&rec, "--rec");
    let bytes = std::fs::read(&rec).unwrap();
    let cut = dir.path().join("cut.rec");
    std::fs::write(&cut, &bytes[..bytes.len() - 2000]).unwrap();
    let args = ["calibrate", &s(&cut), "-o", &s(&dir.path().join("cut.pack"))];
    let loud = support::command().args(args).output().unwrap();
    let loud_err = String::from_utf8_lossy(&loud.stderr);
    assert!(loud.status.success() && loud_err.contains("interrupted capture"), "{loud_err}");
    let (ok, err) = noisecal(&args);
    assert!(ok && err.is_empty(), "calibrate -q printed: {err}");

    // Held-out frames at an ISO beyond the pack: eval says what to do without a flag it lacks.
    let held = dir.path().join("held");
    let held_dir = s(&held);
    let (ok, err) = noisecal(&support::simulate(
        ("64", "48"),
        "2",
        "3200",
        "--ev=0",
        &["--index-offset", "100000", "--dngs", &held_dir],
    ));
    assert!(ok, "{err}");
    let (ok, err) = noisecal(&["eval", "--pack", &s(&pack), &s(&held)]);
    assert!(!ok && err.contains("eval only scores ISOs the pack models"), "{err}");
    assert!(!err.contains("--extrapolate"), "eval suggested a flag it lacks: {err}");
}

/// A session that measured almost nothing (a 4×4 region of interest: 4 pixels a position) still
/// calibrates, but its pack says by name, per position, that its noise is mostly filled in; a
/// full session's pack does not.
#[test]
fn a_sparse_session_is_warned_about_by_name() {
    let dir = tempfile::tempdir().unwrap();
    simulate(dir.path());
    let dngs = dir.path().join("dngs");
    let inspect = |pack: &Path| -> String {
        let out = support::command().args(["inspect", pack.to_str().unwrap()]).output().unwrap();
        assert!(out.status.success());
        String::from_utf8_lossy(&out.stdout).into_owned()
    };
    let sparse = dir.path().join("sparse.pack");
    let (ok, err) =
        noisecal(&["calibrate", dngs.to_str().unwrap(), "--roi", "20,20,24,24", "-o", sparse.to_str().unwrap()]);
    assert!(ok, "{err}");
    let text = inspect(&sparse);
    for name in ["R", "Gr", "Gb", "B"] {
        assert!(text.contains(&format!("ISO 800 {name}: only ")), "no sparse warning for {name}: {text}");
    }
    assert!(text.contains("samples were measured"), "{text}");
    let full = dir.path().join("full.pack");
    let (ok, err) = noisecal(&["calibrate", dngs.to_str().unwrap(), "-o", full.to_str().unwrap()]);
    assert!(ok, "{err}");
    assert!(!inspect(&full).contains("samples were measured"));
}
