//! Dark frames through the binary: `simulate --dark` writes a lens-covered step after
//! the lit sweep; `calibrate` finds the dark frames of a DNG folder by their content (they match
//! the darkest EV step's ISO × exposure, so metadata alone would take them for targets) and a
//! recording's by its BeginDark record; both give every ISO the same fixed pattern, and no lit
//! frame is taken for a dark one.

use std::path::Path;

use serde_json::Value;

mod support;

fn noisecal(args: &[&str]) -> (bool, String, String) {
    let out = support::run(args);
    (out.ok, out.stdout, out.stderr)
}

fn ok(args: &[&str]) -> (String, String) {
    let (good, out, err) = noisecal(args);
    assert!(good, "noisecal {args:?} failed: {err}");
    (out, err)
}

fn s(p: &Path) -> &str {
    p.to_str().expect("UTF-8 path")
}

/// Per ISO: (target frames, fixed-pattern SD, added, dark frames).
fn patterns(pack: &Path) -> Vec<(u64, u64, f64, bool, u64)> {
    let (out, _) = ok(&["-q", "inspect", s(pack), "--json"]);
    let v: Value = serde_json::from_str(&out).expect("inspect JSON");
    v["isos"]
        .as_array()
        .expect("isos")
        .iter()
        .map(|i| {
            let f = &i["structure"]["fpn"];
            (
                i["iso"].as_u64().expect("iso"),
                i["frames"].as_u64().expect("frames"),
                f["sd"].as_f64().unwrap_or(-1.0),
                f["added"].as_bool().unwrap_or(false),
                f["dark_frames"].as_u64().unwrap_or(0),
            )
        })
        .collect()
}

#[test]
fn dark_step_from_dng_folders_and_recordings() {
    let dir = tempfile::tempdir().expect("tempdir");
    let d = dir.path();
    let (dngs, rec) = (d.join("dngs"), d.join("s.rec"));
    let common = ["-q", "simulate", "--sensor", "phone10", "--structured", "--width", "192", "--height", "128"];
    let sweep = ["--frames", "4", "--isos", "200,800", "--ev=-2,0,2"];
    let mut args: Vec<&str> = common.to_vec();
    args.extend(sweep);
    args.extend(["--dark", "8", "--dngs", s(&dngs), "--rec", s(&rec)]);
    ok(&args);
    // Without the dark step, for comparison.
    let plain = d.join("plain");
    let mut args: Vec<&str> = common.to_vec();
    args.extend(sweep);
    args.extend(["--dngs", s(&plain)]);
    ok(&args);

    let (p_dng, p_rec, p_plain) = (d.join("dng.pack"), d.join("rec.pack"), d.join("plain.pack"));
    let (_, err) = ok(&["calibrate", s(&dngs), "-o", s(&p_dng)]);
    assert!(err.contains("dark frame(s)"), "the dark frames are announced: {err}");
    ok(&["-q", "calibrate", s(&rec), "-o", s(&p_rec)]);
    ok(&["-q", "calibrate", s(&plain), "-o", s(&p_plain)]);

    let (a, b, c) = (patterns(&p_dng), patterns(&p_rec), patterns(&p_plain));
    assert_eq!(a.len(), 2);
    for ((x, y), z) in a.iter().zip(&b).zip(&c) {
        // Every lit target frame stays a target: none was taken for a dark frame.
        assert_eq!(x.1, z.1, "ISO {}: target frames with the dark step {} vs without {}", x.0, x.1, z.1);
        assert_eq!(x.4, 8, "ISO {}: 8 dark frames measured the pattern", x.0);
        assert!(x.3 && x.2 > 0.0, "ISO {}: the pattern is added ({x:?})", x.0);
        // The folder and the recording hold the same frames: the same pattern.
        assert!((x.2 - y.2).abs() < 1e-9, "ISO {}: folder {} vs recording {}", x.0, x.2, y.2);
        assert_eq!(z.2, -1.0, "no pattern without dark frames");
    }

    // The report shows the pattern per ISO, added.
    let html = d.join("r.html");
    ok(&["-q", "report", "--pack", s(&p_dng), "-o", s(&html)]);
    let html = std::fs::read_to_string(&html).unwrap();
    assert!(html.contains("fixed pattern (dark frames)"), "report lists the component");
    assert!(html.contains("the fixed pattern at ISO 200, 800"), "report says where it is added");

    // Synthesis with and without the pattern (that it repeats across seeds is measured in
    // tests/e2e fixed_pattern and the Python tests): fpn changes the output, quietly.
    let clean = dngs.join("f00000.dng");
    let synth = |seed: &str, components: &str, name: &str| -> Vec<u8> {
        let out = d.join(name);
        let (stdout, _) = ok(&[
            "-q",
            "synth",
            "--pack",
            s(&p_dng),
            "--iso",
            "800",
            "--seed",
            seed,
            "--components",
            components,
            s(&clean),
            "-o",
            s(&out),
        ]);
        assert!(stdout.is_empty());
        std::fs::read(&out).unwrap()
    };
    let with = synth("1", "pixel,fpn", "a.dng");
    let without = synth("1", "pixel,row,column,frame", "c.dng");
    assert_ne!(with, without, "fpn changes the output");

    // A folder of one size keeps the pattern from its second file on: the same bytes as with
    // nothing kept (--pattern-cache-mb 0), and as each file synthesized alone.
    let folder = d.join("few");
    std::fs::create_dir(&folder).unwrap();
    for f in ["f00000.dng", "f00001.dng", "f00002.dng"] {
        std::fs::copy(dngs.join(f), folder.join(f)).unwrap();
    }
    let run_folder = |extra: &[&str], out: &str| -> Vec<Vec<u8>> {
        let out = d.join(out);
        let mut args = vec!["-q", "synth", "--pack", s(&p_dng), "--iso", "800", "--seed", "3", "--seed-by", "index"];
        args.extend(extra);
        args.extend([s(&folder), "-o", s(&out)]);
        ok(&args);
        ["f00000.dng", "f00001.dng", "f00002.dng"].iter().map(|f| std::fs::read(out.join(f)).unwrap()).collect()
    };
    let kept = run_folder(&[], "kept");
    assert_eq!(kept, run_folder(&["--pattern-cache-mb", "0"], "none"), "the pattern cache changes no byte");
    assert_eq!(kept, run_folder(&["--pattern-cache-mb", "1"], "small"), "the pattern cache changes no byte");

    // A lit frame inside a recording's dark step is refused by name, the rest still calibrates.
    let bad = d.join("bad.rec");
    {
        use noisecal_core::format::recording::{Record, RecordingReader, RecordingWriter};
        let bytes = std::fs::read(&rec).unwrap();
        let mut r = RecordingReader::from_bytes(&bytes).unwrap();
        let mut w = RecordingWriter::new(Vec::new(), &r.header().clone()).unwrap();
        let mut lit = None;
        while let Some(rec) = r.next_record().unwrap() {
            match rec {
                Record::BeginStep { exposure_ns } => w.begin_step(exposure_ns).unwrap(),
                Record::Frame(f) => {
                    w.frame(&f.meta, f.width, f.height, f.row_stride, f.pixel_stride, &f.data).unwrap();
                    lit.get_or_insert(f);
                }
                Record::NoiseProfile { iso, profile } => w.noise_profile(iso, &profile).unwrap(),
                Record::BeginDark => {
                    w.begin_dark().unwrap();
                    // Not a byte-for-byte repeat (that is refused as damage): its exposure differs.
                    let f = lit.as_ref().unwrap();
                    let meta = noisecal_core::FrameMeta { exposure_ns: f.meta.exposure_ns + 1, ..f.meta };
                    w.frame(&meta, f.width, f.height, f.row_stride, f.pixel_stride, &f.data).unwrap();
                }
                Record::End { .. } => {}
            }
        }
        std::fs::write(&bad, w.finish().unwrap()).unwrap();
    }
    let (_, err) = ok(&["calibrate", s(&bad), "-o", s(&d.join("bad.pack"))]);
    assert!(err.contains("is not dark") && err.contains("cover"), "{err}");
}
