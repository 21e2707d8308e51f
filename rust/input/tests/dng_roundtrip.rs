//! write → read round trips of `noisecal_input::dng`, the writer's guarantees, and `scan_folder`.

use std::path::Path;

use noisecal_core::{CfaPattern, FrameMeta, SensorLayout};
use noisecal_input::dng::{DngError, read_dng, scan_folder, write_dng, write_dng_from_layout};

mod support;
use support::random_pixels;

fn layout(w: u32, h: u32, cfa: CfaPattern, black: [f32; 4], white: u16) -> SensorLayout {
    SensorLayout { width: w, height: h, cfa, black, white }
}

#[test]
fn round_trip_every_cfa_bit_depth_black_and_size() {
    let dir = tempfile::tempdir().expect("tempdir");
    let levels: [([f32; 4], u16); 4] = [
        ([64.0; 4], 1023),
        ([256.0, 256.5, 255.75, 257.25], 4095),
        ([1024.0, 1023.5, 1024.25, 1025.0], 16383),
        ([63.3, 64.1, 64.7, 511.125], 65535),
    ];
    let mut seed = 1;
    for cfa in CfaPattern::ALL {
        for (black, white) in levels {
            for (w, h) in [(98u32, 66u32), (97, 65), (2, 2)] {
                seed += 1;
                let lay = layout(w, h, cfa, black, white);
                let meta = FrameMeta::new(50 + seed as u32 * 7, 1_000_000 + seed * 33_333);
                let pixels = random_pixels(w as usize, h as usize, white, seed);
                let path = dir.path().join(format!("f{seed}.dng"));
                write_dng_from_layout(&path, &lay, &meta, "TestMake", "Test Model 1", &pixels).expect("write");

                let img = read_dng(&path).expect("read back");
                assert_eq!(img.layout, lay, "layout of {cfa} {w}×{h} white {white}");
                assert_eq!(img.pixels, pixels, "pixels of {cfa} {w}×{h}");
                assert_eq!(img.meta.iso, meta.iso);
                assert_eq!(img.meta.exposure_ns, meta.exposure_ns);
                assert_eq!(img.meta.black, Some(black));
                assert_eq!(img.make, "TestMake");
                assert_eq!(img.model, "Test Model 1");
                assert_eq!(img.bits_per_sample, 16);
                assert_eq!(img.noise_profile, None);
                assert_eq!(img.source, path);

                // Re-write through the template with new pixels and a new ISO.
                let pixels2 = random_pixels(w as usize, h as usize, white, seed + 1000);
                let path2 = dir.path().join(format!("g{seed}.dng"));
                write_dng(&path2, &img, &pixels2, 3200).expect("write from template");
                let img2 = read_dng(&path2).expect("read template copy");
                assert_eq!(img2.layout, lay);
                assert_eq!(img2.pixels, pixels2);
                assert_eq!(img2.meta.iso, 3200);
                assert_eq!(img2.meta.exposure_ns, meta.exposure_ns);
                assert_eq!((img2.make.as_str(), img2.model.as_str()), ("TestMake", "Test Model 1"));
            }
        }
    }
}

#[test]
fn multi_strip_round_trip() {
    // 1000 columns → 131 rows per 256 KiB strip: 3 strips, the last one partial.
    let dir = tempfile::tempdir().expect("tempdir");
    let lay = layout(1000, 300, CfaPattern::Bggr, [64.0, 64.5, 63.5, 64.0], 4095);
    let pixels = random_pixels(1000, 300, 4095, 42);
    let path = dir.path().join("strips.dng");
    write_dng_from_layout(&path, &lay, &FrameMeta::new(100, 10_000_000), "M", "N", &pixels).expect("write");
    let img = read_dng(&path).expect("read");
    assert_eq!(img.layout, lay);
    assert_eq!(img.pixels, pixels);
}

#[test]
fn exposure_and_iso_extremes_survive() {
    let dir = tempfile::tempdir().expect("tempdir");
    let lay = layout(8, 6, CfaPattern::Grbg, [64.0; 4], 1023);
    let pixels = random_pixels(8, 6, 1023, 9);
    for (iso, ns) in
        [(1u32, 1u64), (100, 33_333_333), (65534, 4_294_967_295), (102_400, 30_000_000_000), (409_600, 250_000)]
    {
        let path = dir.path().join("x.dng");
        write_dng_from_layout(&path, &lay, &FrameMeta::new(iso, ns), "M", "N", &pixels).expect("write");
        let img = read_dng(&path).expect("read");
        assert_eq!((img.meta.iso, img.meta.exposure_ns), (iso, ns));
    }
}

#[test]
fn frame_black_overrides_layout_black() {
    let dir = tempfile::tempdir().expect("tempdir");
    let lay = layout(10, 10, CfaPattern::Rggb, [64.0; 4], 1023);
    let meta = FrameMeta { iso: 400, exposure_ns: 10_000_000, black: Some([63.25, 64.5, 64.75, 62.0]) };
    let path = dir.path().join("b.dng");
    write_dng_from_layout(&path, &lay, &meta, "M", "N", &random_pixels(10, 10, 1023, 3)).expect("write");
    let img = read_dng(&path).expect("read");
    assert_eq!(img.layout.black, [63.25, 64.5, 64.75, 62.0]);
    assert_eq!(img.meta.black, Some(img.layout.black));
}

#[test]
fn bad_write_input_is_refused_and_leaves_existing_file_intact() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("keep.dng");
    let lay = layout(12, 8, CfaPattern::Bggr, [64.0; 4], 1023);
    let meta = FrameMeta::new(100, 1_000_000);
    let pixels = random_pixels(12, 8, 1023, 5);
    write_dng_from_layout(&path, &lay, &meta, "M", "N", &pixels).expect("write");
    let before = std::fs::read(&path).expect("read bytes");

    let wrong = random_pixels(11, 8, 1023, 6);
    let err = write_dng_from_layout(&path, &lay, &meta, "M", "N", &wrong).expect_err("wrong shape");
    assert!(matches!(err, DngError::InvalidInput { .. }), "{err}");
    assert!(err.to_string().contains("keep.dng") && err.to_string().contains("11×8"), "{err}");

    let err = write_dng_from_layout(&path, &lay, &FrameMeta::new(0, 1), "M", "N", &pixels).expect_err("ISO 0");
    assert!(err.to_string().contains("ISO"), "{err}");
    let bad_black = FrameMeta { black: Some([2000.0; 4]), ..meta };
    assert!(write_dng_from_layout(&path, &lay, &bad_black, "M", "N", &pixels).is_err());

    assert_eq!(std::fs::read(&path).expect("read bytes"), before, "existing file was changed");
    // No temporary files are left behind.
    let names: Vec<_> = std::fs::read_dir(dir.path()).expect("ls").map(|e| e.expect("entry").file_name()).collect();
    assert_eq!(names.len(), 1, "{names:?}");

    // A missing folder is created, as for every output of the CLI (a path that names a new folder is not an error); a folder
    // that cannot be made (a file stands in its way) is an I/O error naming the file.
    let missing = dir.path().join("no/such/dir/x.dng");
    write_dng_from_layout(&missing, &lay, &meta, "M", "N", &pixels).expect("into a missing folder");
    assert_eq!(read_dng(&missing).expect("read").pixels, pixels);
    let blocked = path.join("x.dng");
    let err = write_dng_from_layout(&blocked, &lay, &meta, "M", "N", &pixels).expect_err("a file as the folder");
    assert!(matches!(err, DngError::Io { .. }) && err.to_string().contains("x.dng"), "{err}");
}

#[test]
fn overwriting_replaces_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let path = dir.path().join("o.dng");
    let lay = layout(6, 4, CfaPattern::Gbrg, [10.0; 4], 1023);
    write_dng_from_layout(&path, &lay, &FrameMeta::new(100, 1000), "A", "B", &random_pixels(6, 4, 1023, 1))
        .expect("first");
    let second = random_pixels(6, 4, 1023, 2);
    write_dng_from_layout(&path, &lay, &FrameMeta::new(200, 1000), "A", "B", &second).expect("second");
    let img = read_dng(&path).expect("read");
    assert_eq!((img.meta.iso, &img.pixels), (200, &second));
    #[cfg(unix)]
    {
        // Same permissions as any file the user creates (0666 less umask), not the 0600 of temp files.
        use std::os::unix::fs::PermissionsExt;
        let plain = dir.path().join("plain");
        std::fs::write(&plain, b"x").expect("write plain");
        let mode = |p: &Path| std::fs::metadata(p).expect("stat").permissions().mode() & 0o777;
        assert_eq!(mode(&path), mode(&plain));
    }
}

#[test]
fn scan_folder_lists_dngs_by_name() {
    let dir = tempfile::tempdir().expect("tempdir");
    let touch = |name: &str| std::fs::write(dir.path().join(name), b"x").expect("touch");
    for n in ["c.DNG", "a.dng", "b.Dng", "notes.txt", "d.dng.bak", "e.tif"] {
        touch(n);
    }
    std::fs::create_dir(dir.path().join("f.dng")).expect("mkdir");
    let found = scan_folder(dir.path()).expect("scan");
    let names: Vec<_> = found.iter().map(|p| p.file_name().and_then(|n| n.to_str()).unwrap_or("")).collect();
    assert_eq!(names, ["a.dng", "b.Dng", "c.DNG"]);

    let err = scan_folder(&dir.path().join("absent")).expect_err("missing folder");
    assert!(matches!(err, DngError::Io { .. }) && err.to_string().contains("absent"), "{err}");
}

#[test]
fn missing_file_is_io_error() {
    let err = read_dng(Path::new("/definitely/not/here.dng")).expect_err("missing");
    assert!(matches!(err, DngError::Io { .. }), "{err}");
    assert!(err.to_string().contains("/definitely/not/here.dng"), "{err}");
}

/// 12 MP round trip; run with `cargo test --release -p noisecal-input --test dng_roundtrip -- --ignored --nocapture`.
#[test]
#[ignore = "timing; run in release"]
fn read_12mp_fast() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (w, h) = (4032usize, 3024usize);
    let lay = layout(w as u32, h as u32, CfaPattern::Rggb, [64.0; 4], 1023);
    let pixels = random_pixels(w, h, 1023, 77);
    let path = dir.path().join("big.dng");
    let t = std::time::Instant::now();
    write_dng_from_layout(&path, &lay, &FrameMeta::new(100, 10_000_000), "M", "N", &pixels).expect("write");
    let write_s = t.elapsed().as_secs_f64();
    let t = std::time::Instant::now();
    let img = read_dng(&path).expect("read");
    let read_s = t.elapsed().as_secs_f64();
    println!("12 MP: write {write_s:.3} s, read {read_s:.3} s");
    assert_eq!(img.pixels, pixels);
    assert!(read_s < 1.0, "reading 12 MP took {read_s} s");
}

/// rawler's full DNG decoder (an independent reader of the tags) sees the same image.
#[test]
fn rawler_decoder_reads_written_dng() {
    let dir = tempfile::tempdir().expect("tempdir");
    let lay = layout(98, 66, CfaPattern::Gbrg, [64.5, 64.0, 63.5, 64.25], 4095);
    let pixels = random_pixels(98, 66, 4095, 8);
    let path = dir.path().join("r.dng");
    write_dng_from_layout(&path, &lay, &FrameMeta::new(100, 10_000_000), "Make", "Model", &pixels).expect("write");
    let raw = rawler::decode_file(&path).expect("rawler decodes it");
    assert_eq!((raw.width, raw.height, raw.cpp), (98, 66, 1));
    assert_eq!(raw.blacklevel.as_bayer_array(), [64.5, 64.0, 63.5, 64.25]);
    assert_eq!(raw.whitelevel.0, vec![4095]);
    assert_eq!(raw.camera.cfa.to_string(), "GBRG");
    assert_eq!((raw.make.as_str(), raw.model.as_str()), ("Make", "Model"));
    match raw.data {
        rawler::RawImageData::Integer(d) => assert_eq!(d, pixels.iter().copied().collect::<Vec<_>>()),
        rawler::RawImageData::Float(_) => panic!("float data"),
    }
}
