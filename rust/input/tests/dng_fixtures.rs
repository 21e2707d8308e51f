//! DNGs laid out the way other writers do (Android `DngCreator`, big-endian, tiles, packed
//! 10/12/14-bit, lossless JPEG, ActiveArea, black-level deltas), built with the crate's TIFF
//! writer, and files that must be refused with the right error.

use std::path::{Path, PathBuf};

use ndarray::{Array2, s};
use noisecal_core::{CfaPattern, FrameMeta, SensorLayout};
use noisecal_input::dng::tiff::{Ifd, ImageData, TagValue, TiffBuilder, pack_msb, tag, u16_bytes};
use noisecal_input::dng::{DngError, DngSpec, dng_tiff, read_dng, write_dng_from_layout};

mod support;
use support::{Rng, random_pixels};

fn save(dir: &Path, name: &str, tiff: &TiffBuilder) -> PathBuf {
    let path = dir.join(name);
    std::fs::write(&path, tiff.to_bytes().expect("serialize")).expect("write fixture");
    path
}

/// The raw IFD of a bare CFA DNG, without image data or metadata.
fn cfa_ifd(w: u32, h: u32, bits: u16, cfa: [u8; 4]) -> Ifd {
    let mut ifd = Ifd::new();
    ifd.set(tag::NEW_SUBFILE_TYPE, TagValue::Long(vec![0]))
        .set(tag::IMAGE_WIDTH, TagValue::Long(vec![w]))
        .set(tag::IMAGE_LENGTH, TagValue::Long(vec![h]))
        .set(tag::BITS_PER_SAMPLE, TagValue::Short(vec![bits]))
        .set(tag::COMPRESSION, TagValue::Short(vec![1]))
        .set(tag::PHOTOMETRIC, TagValue::Short(vec![32803]))
        .set(tag::SAMPLES_PER_PIXEL, TagValue::Short(vec![1]))
        .set(tag::CFA_REPEAT_PATTERN_DIM, TagValue::Short(vec![2, 2]))
        .set(tag::CFA_PATTERN, TagValue::Byte(cfa.to_vec()))
        .set(tag::DNG_VERSION, TagValue::Byte(vec![1, 4, 0, 0]));
    ifd
}

fn one_strip(pixels: &Array2<u16>, big: bool) -> ImageData {
    let v: Vec<u16> = pixels.iter().copied().collect();
    ImageData::Strips { rows_per_strip: pixels.nrows() as u32, strips: vec![u16_bytes(&v, big)] }
}

/// Android `DngCreator` layout: everything in IFD0 (ISO and exposure too, no EXIF IFD), one
/// 16-bit strip, LONG BlackLevel 2×2, LONG WhiteLevel, NoiseProfile, ActiveArea with an odd
/// offset so the CFA phase of the full sensor differs from that of the active area.
#[test]
fn android_dngcreator_layout() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (fw, fh) = (103u32, 71u32);
    let (top, left, bottom, right) = (3u32, 5u32, 69u32, 103u32); // 98×66 active
    let full = random_pixels(fw as usize, fh as usize, 1023, 11);
    // CFAPattern is relative to the active area's origin: GRBG there.
    let mut ifd = cfa_ifd(fw, fh, 16, [1, 0, 2, 1]);
    ifd.set(tag::MAKE, TagValue::Ascii("Google".into()))
        .set(tag::MODEL, TagValue::Ascii("Pixel 7".into()))
        .set(tag::ORIENTATION, TagValue::Short(vec![1]))
        .set(tag::BLACK_LEVEL_REPEAT_DIM, TagValue::Short(vec![2, 2]))
        .set(tag::BLACK_LEVEL, TagValue::Long(vec![64, 65, 63, 64]))
        .set(tag::WHITE_LEVEL, TagValue::Long(vec![1023]))
        .set(tag::ACTIVE_AREA, TagValue::Long(vec![top, left, bottom, right]))
        .set(tag::EXPOSURE_TIME, TagValue::Rational(vec![(1, 120)]))
        .set(tag::ISO_SPEED_RATINGS, TagValue::Short(vec![640]))
        .set(tag::CFA_PLANE_COLOR, TagValue::Byte(vec![0, 1, 2]))
        .set(tag::CFA_LAYOUT, TagValue::Short(vec![1]))
        .set(tag::NOISE_PROFILE, TagValue::Double(vec![2.5e-5, 1.5e-7, 2.4e-5, 1.4e-7, 2.6e-5, 1.6e-7]))
        .set(
            tag::COLOR_MATRIX_1,
            TagValue::SRational(vec![
                (12, 10),
                (-3, 10),
                (-1, 10),
                (-4, 10),
                (14, 10),
                (1, 10),
                (0, 1),
                (2, 10),
                (6, 10),
            ]),
        )
        .set(tag::AS_SHOT_NEUTRAL, TagValue::Rational(vec![(5, 10), (1, 1), (6, 10)]));
    ifd.image = Some(one_strip(&full, false));
    let path = save(dir.path(), "android.dng", &TiffBuilder { big_endian: false, chain: vec![ifd] });

    let img = read_dng(&path).expect("read Android layout");
    assert_eq!((img.layout.width, img.layout.height), (98, 66));
    assert_eq!(img.layout.cfa, CfaPattern::Grbg);
    assert_eq!(img.layout.black, [64.0, 65.0, 63.0, 64.0]);
    assert_eq!(img.layout.white, 1023);
    let active = full.slice(s![top as usize..bottom as usize, left as usize..right as usize]);
    assert_eq!(img.pixels, active);
    assert_eq!(img.meta.iso, 640);
    assert_eq!(img.meta.exposure_ns, 8_333_333); // 1/120 s rounded to the nearest ns
    assert_eq!((img.make.as_str(), img.model.as_str()), ("Google", "Pixel 7"));
    assert_eq!(img.noise_profile, Some(vec![(2.5e-5, 1.5e-7), (2.4e-5, 1.4e-7), (2.6e-5, 1.6e-7)]));
    let m = img.color.color_matrix1.clone().expect("colour matrix");
    assert!((m[0] - 1.2).abs() < 1e-12 && (m[8] - 0.6).abs() < 1e-12);

    // Written back from it, colour tags and levels carry over.
    let out = dir.path().join("copy.dng");
    noisecal_input::dng::write_dng(&out, &img, &img.pixels, 1600).expect("write");
    let copy = read_dng(&out).expect("read copy");
    assert_eq!(copy.layout, img.layout);
    assert_eq!(copy.pixels, img.pixels);
    assert_eq!(copy.meta.iso, 1600);
    assert_eq!(copy.meta.exposure_ns, 8_333_333);
    assert_eq!(copy.color.as_shot_neutral, Some(vec![0.5, 1.0, 0.6]));
    assert_eq!(copy.color.color_matrix1, img.color.color_matrix1);
}

/// Thumbnail in IFD0, raw in a SubIFD (dnglab / Adobe layout), big-endian, 16-bit tiles with
/// padded edge tiles, ISO in the EXIF IFD.
#[test]
fn big_endian_tiles_in_subifd() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (w, h, tw, th) = (97usize, 65usize, 32usize, 16usize);
    let pixels = random_pixels(w, h, 4095, 12);
    let mut raw = cfa_ifd(w as u32, h as u32, 16, [2, 1, 1, 0]);
    raw.set(tag::BLACK_LEVEL, TagValue::Rational(vec![(2561, 10)])).set(tag::WHITE_LEVEL, TagValue::Short(vec![4095]));
    let mut tiles = Vec::new();
    for ty in 0..h.div_ceil(th) {
        for tx in 0..w.div_ceil(tw) {
            let mut tile = vec![0u16; tw * th];
            for r in 0..th {
                for c in 0..tw {
                    let (y, x) = (ty * th + r, tx * tw + c);
                    if y < h && x < w {
                        tile[r * tw + c] = pixels[[y, x]];
                    }
                }
            }
            tiles.push(u16_bytes(&tile, true));
        }
    }
    raw.image = Some(ImageData::Tiles { tile_width: tw as u32, tile_length: th as u32, tiles });

    let mut thumb = Ifd::new();
    thumb
        .set(tag::NEW_SUBFILE_TYPE, TagValue::Long(vec![1]))
        .set(tag::IMAGE_WIDTH, TagValue::Long(vec![4]))
        .set(tag::IMAGE_LENGTH, TagValue::Long(vec![2]))
        .set(tag::BITS_PER_SAMPLE, TagValue::Short(vec![8, 8, 8]))
        .set(tag::COMPRESSION, TagValue::Short(vec![1]))
        .set(tag::PHOTOMETRIC, TagValue::Short(vec![2]))
        .set(tag::SAMPLES_PER_PIXEL, TagValue::Short(vec![3]))
        .set(tag::MAKE, TagValue::Ascii("SomeMake ".into()))
        .set(tag::MODEL, TagValue::Ascii("X1".into()))
        .set(tag::DNG_VERSION, TagValue::Byte(vec![1, 6, 0, 0]));
    thumb.image = Some(ImageData::Strips { rows_per_strip: 2, strips: vec![vec![128; 24]] });
    let mut exif = Ifd::new();
    exif.set(tag::EXPOSURE_TIME, TagValue::Rational(vec![(1, 4000)]))
        .set(tag::ISO_SPEED_RATINGS, TagValue::Short(vec![50]));
    thumb.sub_ifds.insert(tag::EXIF_IFD, vec![exif]);
    thumb.sub_ifds.insert(tag::SUB_IFDS, vec![raw]);
    let path = save(dir.path(), "be.dng", &TiffBuilder { big_endian: true, chain: vec![thumb] });

    let img = read_dng(&path).expect("read big-endian tiles");
    assert_eq!(img.layout.cfa, CfaPattern::Bggr);
    assert_eq!(img.layout.black, [256.1; 4]);
    assert_eq!(img.layout.white, 4095);
    assert_eq!(img.pixels, pixels);
    assert_eq!((img.meta.iso, img.meta.exposure_ns), (50, 250_000));
    assert_eq!(img.make, "SomeMake");
}

/// Packed 10/12/14-bit big-endian data, default WhiteLevel from BitsPerSample.
#[test]
fn packed_bit_depths() {
    let dir = tempfile::tempdir().expect("tempdir");
    for bits in [10u16, 12, 14] {
        let (w, h) = (96usize, 64usize);
        let max = (1u32 << bits) as u16 - 1;
        let pixels = random_pixels(w, h, max, bits as u64);
        let mut ifd = cfa_ifd(w as u32, h as u32, bits, [0, 1, 1, 2]);
        ifd.set(tag::EXPOSURE_TIME, TagValue::Rational(vec![(1, 30)]))
            .set(tag::ISO_SPEED_RATINGS, TagValue::Short(vec![100]));
        // Two strips of 32 rows.
        let v: Vec<u16> = pixels.iter().copied().collect();
        let strips = v.chunks(32 * w).map(|c| pack_msb(c, bits as u32)).collect();
        ifd.image = Some(ImageData::Strips { rows_per_strip: 32, strips });
        let path = save(dir.path(), &format!("p{bits}.dng"), &TiffBuilder { big_endian: false, chain: vec![ifd] });
        let img = read_dng(&path).unwrap_or_else(|e| panic!("{bits}-bit: {e}"));
        assert_eq!(img.pixels, pixels, "{bits}-bit");
        assert_eq!(img.layout.white, max);
        assert_eq!(img.layout.black, [0.0; 4]);
        assert_eq!(img.bits_per_sample, bits as u32);
    }
}

/// A 12-bit CFA tile as lossless JPEG, encoded as dnglab / Adobe DNG Converter do: a
/// 2-component image of half the width.
fn ljpeg_tile(pixels: &Array2<u16>) -> Vec<u8> {
    let v: Vec<u16> = pixels.iter().copied().collect();
    let (h, w) = pixels.dim();
    rawler::ljpeg92::LjpegCompressor::new(&v, w / 2, h, 2, 12, 1, 0, 0).expect("compressor").encode().expect("encode")
}

/// Lossless JPEG (compression 7) tiles as dnglab / Adobe DNG Converter write them.
#[test]
fn lossless_jpeg_tiles() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (w, h) = (64usize, 48usize);
    let pixels = random_pixels(w, h, 4095, 21);
    let jpeg = ljpeg_tile(&pixels);
    let mut ifd = cfa_ifd(w as u32, h as u32, 12, [1, 2, 0, 1]);
    ifd.set(tag::COMPRESSION, TagValue::Short(vec![7]))
        .set(tag::WHITE_LEVEL, TagValue::Short(vec![4095]))
        .set(tag::BLACK_LEVEL_REPEAT_DIM, TagValue::Short(vec![2, 2]))
        .set(tag::BLACK_LEVEL, TagValue::Short(vec![256, 257, 258, 259]))
        .set(tag::EXPOSURE_TIME, TagValue::Rational(vec![(1, 50)]))
        .set(tag::ISO_SPEED_RATINGS, TagValue::Short(vec![200]));
    ifd.image = Some(ImageData::Tiles { tile_width: w as u32, tile_length: h as u32, tiles: vec![jpeg] });
    let path = save(dir.path(), "ljpeg.dng", &TiffBuilder { big_endian: false, chain: vec![ifd] });
    let img = read_dng(&path).expect("read lossless JPEG");
    assert_eq!(img.pixels, pixels);
    assert_eq!(img.layout.cfa, CfaPattern::Gbrg);
    assert_eq!(img.layout.black, [256.0, 257.0, 258.0, 259.0]);
}

/// BlackLevel 1×1, 2×2 and 4×4 patterns with BlackLevelDeltaH/V: each position's black is the mean
/// black of its pixels (checked by brute force over the active area).
#[test]
fn black_level_patterns_and_deltas() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (w, h) = (30usize, 20usize);
    let (top, left) = (1usize, 3usize);
    let (fw, fh) = (w + left + 2, h + top + 1);
    let cases: Vec<(usize, usize, Vec<f64>)> = vec![
        (1, 1, vec![64.5]),
        (2, 2, vec![60.0, 61.25, 62.5, 63.75]),
        (4, 4, (0..16).map(|i| 100.0 + i as f64 * 0.5).collect()),
        (1, 2, vec![50.0, 52.0]),
    ];
    for (k, (rr, rc, levels)) in cases.into_iter().enumerate() {
        let dh: Vec<f64> = (0..w).map(|j| if j % 2 == 0 { 0.5 } else { -0.25 } + j as f64 * 0.01).collect();
        let dv: Vec<f64> = (0..h).map(|i| (i % 3) as f64 * 0.2).collect();
        let mut ifd = cfa_ifd(fw as u32, fh as u32, 16, [0, 1, 1, 2]);
        ifd.set(tag::BLACK_LEVEL_REPEAT_DIM, TagValue::Short(vec![rr as u16, rc as u16]))
            .set(tag::BLACK_LEVEL, TagValue::Rational(levels.iter().map(|&b| ((b * 100.0) as u32, 100)).collect()))
            .set(
                tag::BLACK_LEVEL_DELTA_H,
                TagValue::SRational(dh.iter().map(|&d| ((d * 1000.0).round() as i32, 1000)).collect()),
            )
            .set(
                tag::BLACK_LEVEL_DELTA_V,
                TagValue::SRational(dv.iter().map(|&d| ((d * 1000.0).round() as i32, 1000)).collect()),
            )
            .set(tag::WHITE_LEVEL, TagValue::Long(vec![4095]))
            .set(tag::ACTIVE_AREA, TagValue::Short(vec![top as u16, left as u16, (top + h) as u16, (left + w) as u16]))
            .set(tag::EXPOSURE_TIME, TagValue::Rational(vec![(1, 30)]))
            .set(tag::ISO_SPEED_RATINGS, TagValue::Short(vec![100]));
        ifd.image = Some(one_strip(&random_pixels(fw, fh, 4095, k as u64), false));
        let path = save(dir.path(), &format!("bl{k}.dng"), &TiffBuilder { big_endian: false, chain: vec![ifd] });
        let img = read_dng(&path).expect("read");

        let mut sum = [0f64; 4];
        let mut cnt = [0f64; 4];
        for i in 0..h {
            for j in 0..w {
                let pos = (i % 2) * 2 + j % 2;
                sum[pos] += levels[(i % rr) * rc + j % rc] + dh[j] + dv[i];
                cnt[pos] += 1.0;
            }
        }
        for pos in 0..4 {
            let want = sum[pos] / cnt[pos];
            let got = img.layout.black[pos] as f64;
            assert!((got - want).abs() < 1e-4, "case {k} position {pos}: {got} vs {want}");
        }
    }
}

#[test]
fn large_iso_uses_iso_speed_tag() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut ifd = cfa_ifd(4, 4, 16, [0, 1, 1, 2]);
    ifd.set(tag::EXPOSURE_TIME, TagValue::Rational(vec![(1, 10)]))
        .set(tag::ISO_SPEED_RATINGS, TagValue::Short(vec![65535]))
        .set(tag::ISO_SPEED, TagValue::Long(vec![204_800]));
    ifd.image = Some(one_strip(&random_pixels(4, 4, 65535, 1), false));
    let path = save(dir.path(), "iso.dng", &TiffBuilder { big_endian: false, chain: vec![ifd] });
    assert_eq!(read_dng(&path).expect("read").meta.iso, 204_800);
}

// ---------------------------------------------------------------------------------------------
// Refusals

fn valid_spec() -> (DngSpec, Array2<u16>) {
    let layout = SensorLayout { width: 40, height: 30, cfa: CfaPattern::Rggb, black: [64.0; 4], white: 1023 };
    let spec = DngSpec {
        layout,
        meta: FrameMeta::new(100, 20_000_000),
        make: "M".into(),
        model: "N".into(),
        color: Default::default(),
    };
    (spec, random_pixels(40, 30, 1023, 99))
}

fn valid_bytes() -> Vec<u8> {
    let (spec, px) = valid_spec();
    dng_tiff(&spec, &px).expect("build").to_bytes().expect("bytes")
}

#[test]
fn truncated_files_are_decode_errors() {
    let dir = tempfile::tempdir().expect("tempdir");
    let bytes = valid_bytes();
    // (A file missing only the final next-IFD pointer loses nothing and is read, like rawler does.)
    for cut in [0usize, 3, 7, 8, 100, bytes.len() / 2, bytes.len() - 5] {
        let path = dir.path().join(format!("cut{cut}.dng"));
        std::fs::write(&path, &bytes[..cut]).expect("write");
        let err = read_dng(&path).expect_err("truncated file must fail");
        assert!(matches!(err, DngError::Decode { .. }), "cut at {cut}: {err}");
        assert!(err.to_string().contains(&format!("cut{cut}.dng")), "{err}");
    }
}

#[test]
fn random_bytes_are_decode_errors() {
    let dir = tempfile::tempdir().expect("tempdir");
    let mut rng = Rng(12345);
    for k in 0..20 {
        let mut bytes: Vec<u8> = (0..4096 + k * 300).map(|_| rng.next() as u8).collect();
        if k % 2 == 1 {
            // Looks like a TIFF, garbage after the header.
            bytes[..4].copy_from_slice(b"II\x2a\0");
            let off = (rng.next() % 4000) as u32 + 8;
            bytes[4..8].copy_from_slice(&off.to_le_bytes());
        }
        let path = dir.path().join(format!("r{k}.dng"));
        std::fs::write(&path, &bytes).expect("write");
        match read_dng(&path) {
            Err(DngError::Decode { .. }) | Err(DngError::Unsupported { .. }) => {}
            other => panic!("random file {k}: expected Decode/Unsupported, got {other:?}"),
        }
        if k % 2 == 0 {
            assert!(matches!(read_dng(&path), Err(DngError::Decode { .. })));
        }
    }
}

/// Corrupting single bytes of a valid DNG never panics (errors or, for harmless bytes, success).
#[test]
fn corrupted_bytes_never_panic() {
    let dir = tempfile::tempdir().expect("tempdir");
    let good = valid_bytes();
    let path = dir.path().join("c.dng");
    let mut rng = Rng(777);
    // The IFD and tag data sit after the pixels: corrupt there mostly.
    let pixel_end = 8 + 40 * 30 * 2;
    for _ in 0..300 {
        let mut bytes = good.clone();
        for _ in 0..3 {
            let at = if rng.next().is_multiple_of(4) {
                (rng.next() as usize) % bytes.len()
            } else {
                pixel_end + (rng.next() as usize) % (bytes.len() - pixel_end)
            };
            bytes[at] = rng.next() as u8;
        }
        std::fs::write(&path, &bytes).expect("write");
        let _ = read_dng(&path);
    }
}

fn with_spec_edit(name: &str, edit: impl FnOnce(&mut TiffBuilder)) -> (tempfile::TempDir, PathBuf) {
    let dir = tempfile::tempdir().expect("tempdir");
    let (spec, px) = valid_spec();
    let mut t = dng_tiff(&spec, &px).expect("build");
    edit(&mut t);
    let path = save(dir.path(), name, &t);
    (dir, path)
}

fn exif(t: &mut TiffBuilder) -> &mut Ifd {
    &mut t.chain[0].sub_ifds.get_mut(&tag::EXIF_IFD).expect("exif")[0]
}

#[test]
fn inconsistent_sizes_are_decode_errors() {
    for (name, w, h) in [("huge.dng", 60000u32, 60000u32), ("wide.dng", 41, 30), ("zero.dng", 0, 30)] {
        let (_d, path) = with_spec_edit(name, |t| {
            t.chain[0].set(tag::IMAGE_WIDTH, TagValue::Long(vec![w])).set(tag::IMAGE_LENGTH, TagValue::Long(vec![h]));
        });
        match read_dng(&path) {
            Err(e @ DngError::Decode { .. }) => assert!(e.to_string().contains(name), "{e}"),
            other => panic!("{name}: expected Decode, got {other:?}"),
        }
    }
}

#[test]
fn missing_iso_or_exposure_is_missing_tag() {
    let (_d, path) = with_spec_edit("noiso.dng", |t| {
        exif(t).remove(tag::ISO_SPEED_RATINGS);
    });
    match read_dng(&path) {
        Err(e @ DngError::MissingTag { .. }) => {
            let msg = e.to_string();
            assert!(msg.contains("noiso.dng") && msg.contains("ISO") && msg.contains("exiftool"), "{msg}");
        }
        other => panic!("expected MissingTag, got {other:?}"),
    }
    let (_d, path) = with_spec_edit("noexp.dng", |t| {
        exif(t).remove(tag::EXPOSURE_TIME);
    });
    assert!(
        matches!(read_dng(&path), Err(DngError::MissingTag { tag, .. }) if tag.contains("ExposureTime")),
        "missing exposure"
    );
    let (_d, path) = with_spec_edit("nocfa.dng", |t| {
        t.chain[0].remove(tag::CFA_PATTERN);
    });
    assert!(matches!(read_dng(&path), Err(DngError::MissingTag { tag, .. }) if tag.contains("CFAPattern")));
}

#[test]
fn unsupported_dngs_are_refused_clearly() {
    let expect_unsupported = |name: &str, edit: &dyn Fn(&mut TiffBuilder), needle: &str| {
        let (_d, path) = with_spec_edit(name, |t| edit(t));
        match read_dng(&path) {
            Err(e @ DngError::Unsupported { .. }) => {
                let msg = e.to_string();
                assert!(msg.contains(name) && msg.contains(needle), "{name}: {msg}");
            }
            other => panic!("{name}: expected Unsupported, got {other:?}"),
        }
    };
    expect_unsupported(
        "xtrans.dng",
        &|t| {
            t.chain[0]
                .set(tag::CFA_REPEAT_PATTERN_DIM, TagValue::Short(vec![6, 6]))
                .set(tag::CFA_PATTERN, TagValue::Byte(vec![1; 36]));
        },
        "X-Trans",
    );
    expect_unsupported(
        "quad.dng",
        &|t| {
            t.chain[0].set(tag::CFA_PATTERN, TagValue::Byte(vec![1, 1, 1, 1]));
        },
        "not a Bayer order",
    );
    expect_unsupported(
        "cmy.dng",
        &|t| {
            t.chain[0].set(tag::CFA_PLANE_COLOR, TagValue::Byte(vec![3, 4, 5]));
        },
        "not an RGB Bayer",
    );
    expect_unsupported(
        "linear.dng",
        &|t| {
            t.chain[0].set(tag::PHOTOMETRIC, TagValue::Short(vec![34892]));
        },
        "LinearRaw",
    );
    expect_unsupported(
        "eight.dng",
        &|t| {
            t.chain[0].set(tag::BITS_PER_SAMPLE, TagValue::Short(vec![8]));
        },
        "8 bits",
    );
    expect_unsupported(
        "notdng.dng",
        &|t| {
            t.chain[0].remove(tag::DNG_VERSION);
        },
        "DNGVersion",
    );
    expect_unsupported(
        "float.dng",
        &|t| {
            t.chain[0].set(tag::SAMPLE_FORMAT, TagValue::Short(vec![3]));
        },
        "floating-point",
    );
    expect_unsupported(
        "blackwhite.dng",
        &|t| {
            t.chain[0].set(tag::BLACK_LEVEL, TagValue::Short(vec![2000]));
        },
        "levels",
    );
}

#[test]
fn writer_output_is_what_android_readers_expect() {
    // The writer's own file: IFD0 is the raw CFA image with 16-bit strips and an EXIF IFD.
    let dir = tempfile::tempdir().expect("tempdir");
    let (spec, px) = valid_spec();
    let path = dir.path().join("w.dng");
    write_dng_from_layout(&path, &spec.layout, &spec.meta, "M", "N", &px).expect("write");
    let bytes = std::fs::read(&path).expect("read");
    assert_eq!(&bytes[..4], b"II\x2a\0");
    let t = dng_tiff(&spec, &px).expect("build");
    assert_eq!(t.to_bytes().expect("bytes"), bytes, "written file equals the built structure");
    let ifd0 = &t.chain[0];
    assert_eq!(ifd0.get(tag::PHOTOMETRIC), Some(&TagValue::Short(vec![32803])));
    assert_eq!(ifd0.get(tag::BITS_PER_SAMPLE), Some(&TagValue::Short(vec![16])));
    assert_eq!(ifd0.get(tag::CFA_PATTERN), Some(&TagValue::Byte(vec![0, 1, 1, 2])));
    assert!(ifd0.get(tag::DNG_VERSION).is_some() && ifd0.get(tag::COLOR_MATRIX_1).is_some());
}

/// A tile as wide and long as the TIFF allows makes rawler allocate the padded image
/// (⌈width / TileWidth⌉ · TileWidth × ⌈height / TileLength⌉ · TileLength pixels) before it reads a
/// byte: 2²⁰ × 2²⁰ tiles on a 97 × 65 image were a 2 TB allocation whose failure aborts. Tiles larger
/// than the image they pad are refused by name.
#[test]
fn tiles_far_larger_than_the_image_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (w, h) = (97u32, 65u32);
    let pixels = random_pixels(w as usize, h as usize, 4095, 5);
    // (TileWidth, TileLength, refused): the last is one tile padding the image to 128 × 96.
    for (tw, th, refused) in
        [(1u32 << 20, 1u32 << 20, true), (16, 1 << 24, true), (1 << 18, 16, true), (128, 96, false)]
    {
        let mut raw = cfa_ifd(w, h, 16, [0, 1, 1, 2]);
        raw.set(tag::WHITE_LEVEL, TagValue::Short(vec![4095]))
            .set(tag::ISO_SPEED_RATINGS, TagValue::Short(vec![100]))
            .set(tag::EXPOSURE_TIME, TagValue::Rational(vec![(1, 100)]));
        let mut tile = vec![0u16; 128 * 96];
        for ((y, x), &v) in pixels.indexed_iter() {
            tile[y * 128 + x] = v;
        }
        raw.image = Some(ImageData::Tiles { tile_width: tw, tile_length: th, tiles: vec![u16_bytes(&tile, false)] });
        let tiff = TiffBuilder { big_endian: false, chain: vec![raw] };
        let name = format!("tiles-{tw}x{th}.dng");
        let path = save(dir.path(), &name, &tiff);
        if refused {
            let e = read_dng(&path).expect_err("a tile far larger than the image").to_string();
            assert!(e.contains(&name) && e.contains("TileWidth"), "{e}");
        } else {
            assert_eq!(read_dng(&path).expect("one tile padding the image").pixels, pixels);
        }
    }
}

/// JPEG XL raw data (DNG 1.7): a lossless 32 × 16 tile decodes to its samples (the codestream was
/// written by libjxl through imagecodecs), and a codestream whose image is larger than the tile it
/// fills is refused by name before rawler sizes buffers from it.
#[test]
fn jpeg_xl_tiles_decode_and_oversized_ones_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    let samples: Vec<u16> = std::fs::read(data.join("random-32x16.u16le"))
        .expect("samples")
        .chunks_exact(2)
        .map(|b| u16::from_le_bytes([b[0], b[1]]))
        .collect();
    let expected = Array2::from_shape_vec((16, 32), samples).expect("shape");
    for (name, file) in [("jxl.dng", "random-32x16.jxl"), ("jxl-oversized.dng", "flat-256x64.jxl")] {
        let mut raw = cfa_ifd(32, 16, 16, [0, 1, 1, 2]);
        raw.set(tag::COMPRESSION, TagValue::Short(vec![52546]))
            .set(tag::WHITE_LEVEL, TagValue::Short(vec![4095]))
            .set(tag::ISO_SPEED_RATINGS, TagValue::Short(vec![100]))
            .set(tag::EXPOSURE_TIME, TagValue::Rational(vec![(1, 100)]));
        let tile = std::fs::read(data.join(file)).expect("codestream");
        raw.image = Some(ImageData::Tiles { tile_width: 32, tile_length: 16, tiles: vec![tile] });
        let path = save(dir.path(), name, &TiffBuilder { big_endian: false, chain: vec![raw] });
        match read_dng(&path) {
            Ok(img) if name == "jxl.dng" => assert_eq!(img.pixels, expected),
            Err(e) if name != "jxl.dng" => {
                let e = e.to_string();
                assert!(e.contains(name) && e.contains("JPEG XL segment 0") && e.contains("256×64"), "{e}");
            }
            other => panic!("{name}: {other:?}"),
        }
    }
}

/// A lossless-JPEG tile whose frame header claims far more samples than the tile holds: rawler
/// decodes the whole frame into a buffer of the header's size first (a fuzzed tile doing so ran
/// for minutes), so it is refused by name; a frame the tile's size still decodes.
#[test]
fn lossless_jpeg_frames_far_larger_than_their_tile_are_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (w, h) = (16usize, 8usize);
    for (fw, fh, refused) in [(128usize, 96usize, true), (w, h, false)] {
        let pixels = random_pixels(fw, fh, 4095, 22);
        let jpeg = ljpeg_tile(&pixels);
        let mut ifd = cfa_ifd(w as u32, h as u32, 12, [0, 1, 1, 2]);
        ifd.set(tag::COMPRESSION, TagValue::Short(vec![7]))
            .set(tag::WHITE_LEVEL, TagValue::Short(vec![4095]))
            .set(tag::EXPOSURE_TIME, TagValue::Rational(vec![(1, 50)]))
            .set(tag::ISO_SPEED_RATINGS, TagValue::Short(vec![200]));
        ifd.image = Some(ImageData::Tiles { tile_width: w as u32, tile_length: h as u32, tiles: vec![jpeg] });
        let name = format!("ljpeg-{fw}x{fh}.dng");
        let path = save(dir.path(), &name, &TiffBuilder { big_endian: false, chain: vec![ifd] });
        if refused {
            let e = read_dng(&path).expect_err("a frame far larger than its tile").to_string();
            assert!(e.contains(&name) && e.contains("lossless-JPEG segment 0") && e.contains("128×96"), "{e}");
        } else {
            assert_eq!(read_dng(&path).expect("a frame the tile's size").pixels, pixels);
        }
    }
}
