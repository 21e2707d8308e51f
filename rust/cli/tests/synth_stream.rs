//! `noisecal synth` writes a DNG whose raw image is stored as uncompressed 16-bit strips while it
//! draws the pixels (`DngFile::streamed`): the output must be the bytes the in-memory path writes
//! (read, synthesize, `derived_bytes`), bit for bit, on any thread count, for little- and
//! big-endian files, full and masked active areas, IFD0 and SubIFD raw images; inputs stored
//! otherwise (tiles, packed rows) keep the in-memory path and give the same bytes too.

use std::path::{Path, PathBuf};

use ndarray::Array2;
use noisecal_core::resolve::{ModelKind, resolve_model};
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::synthesize;
use noisecal_input::dng::tiff::{Ifd, ImageData, TagValue, TiffBuilder, pack_msb, tag, u16_bytes};
use noisecal_input::dng::{Tag, derived_bytes, fitted_noise_profile, read_dng_file};

mod support;

fn noisecal(args: &[&str]) -> (bool, String) {
    let out = support::run(args);
    (out.ok, out.stderr)
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// A pack of the simulated 10-bit RGGB phone (black 64, white 1023).
fn pack(dir: &Path) -> PathBuf {
    let (cal, pack) = (dir.join("cal"), dir.join("p.pack"));
    let (ok, err) = noisecal(&[
        "-q",
        "simulate",
        "--dngs",
        s(&cal),
        "--width",
        "64",
        "--height",
        "48",
        "--frames",
        "3",
        "--isos",
        "100,400,1600",
        "--ev=-2,0,2",
    ]);
    assert!(ok, "{err}");
    let (ok, err) = noisecal(&["-q", "calibrate", s(&cal), "-o", s(&pack)]);
    assert!(ok, "{err}");
    pack
}

#[derive(Clone, Copy, Debug)]
enum Storage {
    Strips16 { rows: usize },
    Tiles16 { width: usize, length: usize },
    Packed12 { rows: usize },
}

/// A DNG of a `w`×`h` sensor with active area `active` (top, left, bottom, right), the raw image
/// in IFD0 or in a SubIFD behind a preview.
fn dng(big: bool, sub_ifd: bool, (w, h): (usize, usize), active: [usize; 4], storage: Storage) -> Vec<u8> {
    let full = Array2::from_shape_fn((h, w), |(y, x)| {
        let inside = (active[0]..active[2]).contains(&y) && (active[1]..active[3]).contains(&x);
        if inside { (70 + (x * 13 + y * 7) % 940) as u16 } else { (60 + (x + y) % 9) as u16 }
    });
    let v: Vec<u16> = full.iter().copied().collect();
    let mut raw = Ifd::new();
    raw.set(tag::NEW_SUBFILE_TYPE, TagValue::Long(vec![0]))
        .set(tag::IMAGE_WIDTH, TagValue::Long(vec![w as u32]))
        .set(tag::IMAGE_LENGTH, TagValue::Long(vec![h as u32]))
        .set(tag::PHOTOMETRIC, TagValue::Short(vec![32803]))
        .set(tag::SAMPLES_PER_PIXEL, TagValue::Short(vec![1]))
        .set(tag::PLANAR_CONFIGURATION, TagValue::Short(vec![1]))
        .set(tag::CFA_REPEAT_PATTERN_DIM, TagValue::Short(vec![2, 2]))
        .set(tag::CFA_PATTERN, TagValue::Byte(vec![0, 1, 1, 2]))
        .set(tag::CFA_PLANE_COLOR, TagValue::Byte(vec![0, 1, 2]))
        .set(tag::BLACK_LEVEL, TagValue::Long(vec![64]))
        .set(tag::WHITE_LEVEL, TagValue::Long(vec![1023]))
        .set(tag::ACTIVE_AREA, TagValue::Long(active.iter().map(|&a| a as u32).collect()))
        .set(tag::COMPRESSION, TagValue::Short(vec![1]))
        .set(tag::RAW_DATA_UNIQUE_ID, TagValue::Byte((0..16).collect()));
    match storage {
        Storage::Strips16 { rows } => {
            raw.set(tag::BITS_PER_SAMPLE, TagValue::Short(vec![16]));
            raw.image = Some(ImageData::Strips {
                rows_per_strip: rows as u32,
                strips: v.chunks(rows * w).map(|c| u16_bytes(c, big)).collect(),
            });
        }
        Storage::Packed12 { rows } => {
            raw.set(tag::BITS_PER_SAMPLE, TagValue::Short(vec![12]));
            raw.image = Some(ImageData::Strips {
                rows_per_strip: rows as u32,
                strips: v.chunks(rows * w).map(|c| pack_msb(c, 12)).collect(),
            });
        }
        Storage::Tiles16 { width: tw, length: tl } => {
            raw.set(tag::BITS_PER_SAMPLE, TagValue::Short(vec![16]));
            let mut tiles = Vec::new();
            for ty in 0..h.div_ceil(tl) {
                for tx in 0..w.div_ceil(tw) {
                    let tile: Vec<u16> = (0..tl * tw)
                        .map(|i| {
                            let (y, x) = (ty * tl + i / tw, tx * tw + i % tw);
                            if y < h && x < w { full[(y, x)] } else { 0 }
                        })
                        .collect();
                    tiles.push(u16_bytes(&tile, big));
                }
            }
            raw.image = Some(ImageData::Tiles { tile_width: tw as u32, tile_length: tl as u32, tiles });
        }
    }
    let mut main = Ifd::new();
    main.set(tag::MAKE, TagValue::Ascii("Maker".into()))
        .set(tag::MODEL, TagValue::Ascii("Model".into()))
        .set(tag::DNG_VERSION, TagValue::Byte(vec![1, 4, 0, 0]))
        .set(tag::UNIQUE_CAMERA_MODEL, TagValue::Ascii("Maker Model".into()));
    let mut exif = Ifd::new();
    exif.set(tag::EXPOSURE_TIME, TagValue::Rational(vec![(1, 60)]))
        .set(tag::ISO_SPEED_RATINGS, TagValue::Short(vec![100]));
    main.sub_ifds.insert(tag::EXIF_IFD, vec![exif]);
    let chain = if sub_ifd {
        let mut preview = main;
        preview
            .set(tag::NEW_SUBFILE_TYPE, TagValue::Long(vec![1]))
            .set(tag::IMAGE_WIDTH, TagValue::Long(vec![8]))
            .set(tag::IMAGE_LENGTH, TagValue::Long(vec![6]))
            .set(tag::BITS_PER_SAMPLE, TagValue::Short(vec![8, 8, 8]))
            .set(tag::COMPRESSION, TagValue::Short(vec![1]))
            .set(tag::PHOTOMETRIC, TagValue::Short(vec![2]))
            .set(tag::SAMPLES_PER_PIXEL, TagValue::Short(vec![3]));
        preview.image = Some(ImageData::Strips { rows_per_strip: 6, strips: vec![(0..144u8).collect()] });
        preview.sub_ifds.insert(tag::SUB_IFDS, vec![raw]);
        vec![preview]
    } else {
        for (k, v) in main.entries {
            raw.entries.entry(k).or_insert(v);
        }
        raw.sub_ifds = main.sub_ifds;
        vec![raw]
    };
    TiffBuilder { big_endian: big, chain }.to_bytes().expect("serialize")
}

/// What the in-memory path writes for `input` (seed 7, ISO 800, every component).
fn in_memory(pack: &Path, input: &Path, output: &Path) -> Vec<u8> {
    let pack = noisecal_input::files::load_pack(pack).expect("pack");
    let model = resolve_model(&pack, 800, ModelKind::Noisecal, false).expect("model").model;
    let sampler = IsoSampler::new(&pack, &model);
    let file = read_dng_file(input).expect("read");
    let noisy = synthesize(&sampler, file.image.pixels.view(), 7);
    let profile = fitted_noise_profile(&pack, &model, &file.image.layout);
    derived_bytes(output, &file, &noisy, 800, profile.as_ref()).expect("encode").0
}

#[test]
fn streamed_output_equals_the_in_memory_path() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let pack = pack(d);
    // The simulated phone's sensor is 64×48: the active areas are that size.
    // (name, big-endian, raw image in a sub-IFD, full size, active area, storage): [`dng`]'s inputs.
    type Case = (&'static str, bool, bool, (usize, usize), [usize; 4], Storage);
    let cases: Vec<Case> = vec![
        ("le_full_strips", false, false, (64, 48), [0, 0, 48, 64], Storage::Strips16 { rows: 5 }),
        ("le_full_one_strip", false, false, (64, 48), [0, 0, 48, 64], Storage::Strips16 { rows: 48 }),
        ("le_masked_subifd", false, true, (72, 52), [2, 4, 50, 68], Storage::Strips16 { rows: 16 }),
        ("be_masked_subifd", true, true, (72, 52), [2, 4, 50, 68], Storage::Strips16 { rows: 7 }),
        ("be_full_ifd0", true, false, (64, 48), [0, 0, 48, 64], Storage::Strips16 { rows: 16 }),
        ("le_tiles", false, false, (72, 52), [2, 4, 50, 68], Storage::Tiles16 { width: 32, length: 16 }),
        ("be_tiles", true, true, (64, 48), [0, 0, 48, 64], Storage::Tiles16 { width: 16, length: 32 }),
        ("be_packed12", true, false, (72, 52), [2, 4, 50, 68], Storage::Packed12 { rows: 8 }),
    ];
    let mut streamed = 0;
    for (name, big, sub, size, active, storage) in cases {
        let input = d.join(format!("{name}.dng"));
        std::fs::write(&input, dng(big, sub, size, active, storage)).expect("write input");
        let file = read_dng_file(&input).expect("read");
        let expect_stream = matches!(storage, Storage::Strips16 { .. });
        assert_eq!(file.streamed().is_some(), expect_stream, "{name}");
        streamed += usize::from(file.streamed().is_some());
        let want = in_memory(&pack, &input, &d.join("x.dng"));
        for threads in ["1", "2", "3"] {
            let out = d.join(format!("{name}.t{threads}.out.dng"));
            let (ok, err) = noisecal(&[
                "-q",
                "--threads",
                threads,
                "synth",
                "--pack",
                s(&pack),
                "--iso",
                "800",
                "--seed",
                "7",
                s(&input),
                "-o",
                s(&out),
            ]);
            assert!(ok, "{name}: {err}");
            let got = std::fs::read(&out).expect("output");
            assert!(got == want, "{name} on {threads} threads: the output differs from the in-memory path");
        }
    }
    assert_eq!(streamed, 5);
    let leftovers: Vec<_> = std::fs::read_dir(d)
        .expect("list")
        .filter_map(|e| e.ok())
        .filter(|e| e.file_name().to_string_lossy().contains("noisecal-tmp"))
        .collect();
    assert!(leftovers.is_empty(), "temporary files left: {leftovers:?}");
    let _ = Tag::from_u16(0);
}

/// A folder run streams each file and equals single-file runs with `seed_for(file name, seed)`
/// (with `--seed-by index`, seed + index); a failed write
/// (the output folder's file is a directory) leaves no temporary file behind.
#[test]
fn streamed_folder_runs_and_failures() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let pack = pack(d);
    let input = d.join("in");
    std::fs::create_dir(&input).expect("mkdir");
    for (i, big) in [false, true, false].into_iter().enumerate() {
        let bytes = dng(big, big, (64, 48), [0, 0, 48, 64], Storage::Strips16 { rows: 3 + i });
        std::fs::write(input.join(format!("f{i}.dng")), bytes).expect("write");
    }
    // `noisecal -q synth --pack PACK --iso 800 --seed SEED [extra…] INPUT -o OUTPUT`, which must succeed.
    let synth = |seed: &str, extra: &[&str], input: &std::path::Path, output: &std::path::Path| {
        let mut args = vec!["-q", "synth", "--pack", s(&pack), "--iso", "800", "--seed", seed];
        args.extend_from_slice(extra);
        args.extend([s(input), "-o", s(output)]);
        let (ok, err) = noisecal(&args);
        assert!(ok, "{err}");
    };
    let out = d.join("out");
    synth("5", &[], &input, &out);
    let by_index = d.join("by_index");
    synth("5", &["--seed-by", "index"], &input, &by_index);
    for i in 0..3 {
        let name = format!("f{i}.dng");
        let f = input.join(&name);
        for (folder, seed) in [(&out, noisecal_cli::seeds::seed_for(name.as_bytes(), 5)), (&by_index, 5 + i as u64)] {
            let single = d.join(format!("single{i}_{seed}.dng"));
            synth(&seed.to_string(), &[], &f, &single);
            let a = std::fs::read(folder.join(&name)).expect("folder output");
            assert!(a == std::fs::read(&single).expect("single output"), "file {i} of {}", folder.display());
        }
    }
    assert!(
        std::fs::read(out.join("f1.dng")).expect("by name")
            != std::fs::read(by_index.join("f1.dng")).expect("by index"),
        "the two rules give different seeds"
    );
    // The output is a directory: refused, nothing left behind.
    let blocked = d.join("blocked");
    std::fs::create_dir_all(blocked.join("f0.dng")).expect("mkdir");
    let (ok, err) = noisecal(&[
        "-q",
        "synth",
        "--pack",
        s(&pack),
        "--iso",
        "800",
        s(&input.join("f0.dng")),
        "-o",
        s(&blocked.join("f0.dng")),
    ]);
    assert!(!ok && err.contains("directory"), "{err}");
    let names: Vec<String> = std::fs::read_dir(&blocked)
        .expect("list")
        .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["f0.dng"]);
}
