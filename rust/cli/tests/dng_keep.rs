//! Synthesized DNGs are their input with only the raw pixels, the ISO and the NoiseProfile
//! changed: every other tag, sub-IFD, EXIF/GPS entry and maker-note byte survives, at the same
//! offsets. Checked on DNGs laid out as other tools write them (Adobe DNG Converter: preview in
//! IFD0, raw in a SubIFD, big-endian; camera DNGs: raw in IFD0, packed 12-bit; lossless-JPEG
//! tiles), with `exiftool -validate` and LibRaw (rawpy) when they are installed.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

use ndarray::Array2;
use noisecal_core::resolve::{ModelKind, resolve_model};
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::synthesize;
use noisecal_input::dng::tiff::{Ifd, ImageData, TagValue, TiffBuilder, pack_msb, tag, u16_bytes};
use noisecal_input::dng::{Tag, fitted_noise_profile, read_dng};

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

#[derive(Clone, Copy, PartialEq, Debug)]
enum Kind {
    /// Adobe DNG Converter: big-endian, IFD0 a preview, the raw image (16-bit) in a SubIFD.
    AdobeSubIfd,
    /// A camera DNG: the raw image in IFD0, packed 12-bit strips, masked borders.
    CameraPacked12,
    /// Lossless-JPEG tiles (rewritten as uncompressed strips).
    LosslessJpegTiles,
}

const W: u32 = 72;
const H: u32 = 52;
/// ActiveArea: top, left, bottom, right (masked borders around a 64×48 image).
const ACTIVE: [u32; 4] = [2, 4, 50, 68];

fn t(n: u16) -> Tag {
    Tag::from_u16(n)
}

/// Raw pixels of the whole sensor: a smooth scene in the active area, dark masked borders.
fn scene() -> Array2<u16> {
    Array2::from_shape_fn((H as usize, W as usize), |(y, x)| {
        let inside = (ACTIVE[0] as usize..ACTIVE[2] as usize).contains(&y)
            && (ACTIVE[1] as usize..ACTIVE[3] as usize).contains(&x);
        if inside { (80 + (x * 11 + y * 7) % 900) as u16 } else { (60 + (x + y) % 9) as u16 }
    })
}

/// A DNG carrying everything a DNG carries besides its pixels.
fn rich_dng(kind: Kind) -> Vec<u8> {
    let full = scene();
    let v: Vec<u16> = full.iter().copied().collect();
    let big = kind == Kind::AdobeSubIfd;
    let mut raw = Ifd::new();
    raw.set(tag::NEW_SUBFILE_TYPE, TagValue::Long(vec![0]))
        .set(tag::IMAGE_WIDTH, TagValue::Long(vec![W]))
        .set(tag::IMAGE_LENGTH, TagValue::Long(vec![H]))
        .set(tag::PHOTOMETRIC, TagValue::Short(vec![32803]))
        .set(tag::SAMPLES_PER_PIXEL, TagValue::Short(vec![1]))
        .set(tag::PLANAR_CONFIGURATION, TagValue::Short(vec![1]))
        .set(tag::CFA_REPEAT_PATTERN_DIM, TagValue::Short(vec![2, 2]))
        .set(tag::CFA_PATTERN, TagValue::Byte(vec![0, 1, 1, 2]))
        .set(tag::CFA_PLANE_COLOR, TagValue::Byte(vec![0, 1, 2]))
        .set(tag::CFA_LAYOUT, TagValue::Short(vec![1]))
        .set(tag::BLACK_LEVEL_REPEAT_DIM, TagValue::Short(vec![2, 2]))
        .set(tag::BLACK_LEVEL, TagValue::Rational(vec![(64, 1); 4]))
        .set(tag::WHITE_LEVEL, TagValue::Long(vec![1023]))
        .set(tag::ACTIVE_AREA, TagValue::Long(ACTIVE.to_vec()))
        .set(t(50719), TagValue::Long(vec![2, 2])) // DefaultCropOrigin
        .set(t(50720), TagValue::Long(vec![60, 44])) // DefaultCropSize
        .set(t(50733), TagValue::Long(vec![2])) // BayerGreenSplit
        .set(t(50738), TagValue::Rational(vec![(1, 2)])) // AntiAliasStrength
        .set(t(50780), TagValue::Rational(vec![(7, 10)])) // BestQualityScale
        .set(t(51008), TagValue::Undefined(b"\0\0\0\x01opcode-list-1 blob".to_vec())) // OpcodeList1
        .set(t(51009), TagValue::Undefined(b"\0\0\0\x01gain-map-opcode-list-2 blob with bytes".to_vec())) // OpcodeList2
        .set(t(51022), TagValue::Undefined(b"\0\0\0\x01warp-rectilinear opcode list 3".to_vec())) // OpcodeList3
        .set(tag::NOISE_PROFILE, TagValue::Double(vec![1e-5, 1e-7]));
    match kind {
        Kind::AdobeSubIfd => {
            raw.set(tag::BITS_PER_SAMPLE, TagValue::Short(vec![16])).set(tag::COMPRESSION, TagValue::Short(vec![1]));
            raw.image = Some(ImageData::Strips {
                rows_per_strip: 16,
                strips: v.chunks(16 * W as usize).map(|c| u16_bytes(c, big)).collect(),
            });
        }
        Kind::CameraPacked12 => {
            raw.set(tag::BITS_PER_SAMPLE, TagValue::Short(vec![12])).set(tag::COMPRESSION, TagValue::Short(vec![1]));
            raw.image = Some(ImageData::Strips {
                rows_per_strip: 8,
                strips: v.chunks(8 * W as usize).map(|c| pack_msb(c, 12)).collect(),
            });
        }
        Kind::LosslessJpegTiles => {
            raw.set(tag::BITS_PER_SAMPLE, TagValue::Short(vec![12])).set(tag::COMPRESSION, TagValue::Short(vec![7]));
            let (tw, tl) = (W as usize / 2, H as usize);
            let tiles = (0..2)
                .map(|k| {
                    let tile: Vec<u16> = full
                        .rows()
                        .into_iter()
                        .flat_map(|r| r.iter().skip(k * tw).take(tw).copied().collect::<Vec<_>>())
                        .collect();
                    rawler::ljpeg92::LjpegCompressor::new(&tile, tw / 2, tl, 2, 12, 1, 0, 0)
                        .expect("encoder")
                        .encode()
                        .expect("encode")
                })
                .collect();
            raw.image = Some(ImageData::Tiles { tile_width: tw as u32, tile_length: tl as u32, tiles });
        }
    }

    // IFD0 metadata (the raw IFD's own, or the preview's when the raw image is a SubIFD).
    let mut main = Ifd::new();
    main.set(tag::MAKE, TagValue::Ascii("Canon".into()))
        .set(tag::MODEL, TagValue::Ascii("Canon EOS Kiss X4".into()))
        .set(tag::ORIENTATION, TagValue::Short(vec![6]))
        .set(tag::SOFTWARE, TagValue::Ascii("Adobe DNG Converter 15.0".into()))
        .set(tag::DNG_VERSION, TagValue::Byte(vec![1, 4, 0, 0]))
        .set(tag::DNG_BACKWARD_VERSION, TagValue::Byte(vec![1, 1, 0, 0]))
        .set(tag::UNIQUE_CAMERA_MODEL, TagValue::Ascii("Canon EOS Kiss X4".into()))
        .set(
            tag::COLOR_MATRIX_1,
            TagValue::SRational(vec![
                (6719, 10000),
                (-994, 10000),
                (-925, 10000),
                (-4408, 10000),
                (12426, 10000),
                (2211, 10000),
                (-887, 10000),
                (2129, 10000),
                (6051, 10000),
            ]),
        )
        .set(
            t(50722),
            TagValue::SRational(vec![
                (6461, 10000),
                (-907, 10000),
                (-882, 10000),
                (-4300, 10000),
                (12184, 10000),
                (2378, 10000),
                (-819, 10000),
                (1944, 10000),
                (5931, 10000),
            ]),
        ) // ColorMatrix2
        .set(t(50727), TagValue::Rational(vec![(1, 1), (1, 1), (1, 1)])) // AnalogBalance
        .set(tag::AS_SHOT_NEUTRAL, TagValue::Rational(vec![(4853, 10000), (1, 1), (6532, 10000)]))
        .set(t(50730), TagValue::SRational(vec![(25, 100)])) // BaselineExposure
        .set(tag::CALIBRATION_ILLUMINANT_1, TagValue::Short(vec![17]))
        .set(t(50779), TagValue::Short(vec![21])) // CalibrationIlluminant2
        .set(
            t(50964),
            TagValue::SRational(vec![
                (7763, 10000),
                (1065, 10000),
                (815, 10000),
                (2792, 10000),
                (8639, 10000),
                (-1431, 10000),
                (-69, 10000),
                (-3022, 10000),
                (12303, 10000),
            ]),
        ) // ForwardMatrix1
        .set(
            t(50965),
            TagValue::SRational(vec![
                (7434, 10000),
                (1270, 10000),
                (939, 10000),
                (2659, 10000),
                (8912, 10000),
                (-1571, 10000),
                (-59, 10000),
                (-1999, 10000),
                (11270, 10000),
            ]),
        ) // ForwardMatrix2
        .set(tag::RAW_DATA_UNIQUE_ID, TagValue::Byte((0..16).collect()))
        .set(tag::NEW_RAW_IMAGE_DIGEST, TagValue::Byte(vec![0xab; 16]))
        .set(t(50827), TagValue::Byte(b"IMG_0001.CR2\0".to_vec())); // OriginalRawFileName
    let mut exif = Ifd::new();
    exif.set(tag::EXPOSURE_TIME, TagValue::Rational(vec![(1, 60)]))
        .set(t(33437), TagValue::Rational(vec![(28, 10)])) // FNumber
        .set(tag::ISO_SPEED_RATINGS, TagValue::Short(vec![100]))
        .set(tag::EXIF_VERSION, TagValue::Undefined(b"0230".to_vec()))
        .set(t(36867), TagValue::Ascii("2024:05:06 07:08:09".into())) // DateTimeOriginal
        .set(t(37386), TagValue::Rational(vec![(18, 1)])) // FocalLength
        .set(t(37500), TagValue::Undefined(maker_note(big))); // MakerNote
    let mut gps = Ifd::new();
    gps.set(t(0), TagValue::Byte(vec![2, 3, 0, 0])).set(t(1), TagValue::Ascii("N".into()));
    main.sub_ifds.insert(tag::EXIF_IFD, vec![exif]);
    main.sub_ifds.insert(t(34853), vec![gps]);

    let chain = if kind == Kind::AdobeSubIfd {
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

/// A Canon maker note: one IFD (CanonModelID), in the file's byte order.
fn maker_note(big: bool) -> Vec<u8> {
    let mut b = Vec::new();
    let n16 = |v: u16| if big { v.to_be_bytes() } else { v.to_le_bytes() };
    let n32 = |v: u32| if big { v.to_be_bytes() } else { v.to_le_bytes() };
    b.extend_from_slice(&n16(1));
    b.extend_from_slice(&n16(0x10));
    b.extend_from_slice(&n16(4));
    b.extend_from_slice(&n32(1));
    b.extend_from_slice(&n32(0x8000_0270));
    b.extend_from_slice(&n32(0));
    b
}

/// One tag as stored: type, count, value bytes, the value/offset field.
type Stored = (u16, u32, Vec<u8>, [u8; 4]);

/// Every directory of a TIFF file by path (`0`, `0/330.0`, `0/34665`, …): its tags as stored.
fn directories(b: &[u8]) -> BTreeMap<String, BTreeMap<u16, Stored>> {
    let big = &b[..2] == b"MM";
    let r16 = |o: usize| if big { u16::from_be_bytes([b[o], b[o + 1]]) } else { u16::from_le_bytes([b[o], b[o + 1]]) };
    let r32 = |o: usize| {
        let x = [b[o], b[o + 1], b[o + 2], b[o + 3]];
        if big { u32::from_be_bytes(x) } else { u32::from_le_bytes(x) }
    };
    let mut out = BTreeMap::new();
    let mut todo: Vec<(String, usize)> = Vec::new();
    let mut next = r32(4) as usize;
    let mut k = 0;
    while next != 0 {
        todo.push((k.to_string(), next));
        let n = r16(next) as usize;
        next = r32(next + 2 + 12 * n) as usize;
        k += 1;
    }
    while let Some((path, off)) = todo.pop() {
        let n = r16(off) as usize;
        let mut tags = BTreeMap::new();
        for i in 0..n {
            let e = off + 2 + 12 * i;
            let (tg, ty, count) = (r16(e), r16(e + 2), r32(e + 4));
            let unit = match ty {
                3 | 8 => 2,
                4 | 9 | 11 | 13 => 4,
                5 | 10 | 12 => 8,
                _ => 1,
            };
            let size = unit * count as usize;
            let value =
                if size <= 4 { b[e + 8..e + 8 + size].to_vec() } else { b[r32(e + 8) as usize..][..size].to_vec() };
            let field: [u8; 4] = b[e + 8..e + 12].try_into().expect("4 bytes");
            if matches!(tg, 330 | 34665 | 34853) {
                for j in 0..count as usize {
                    let at = if size <= 4 { e + 8 + 4 * j } else { r32(e + 8) as usize + 4 * j };
                    todo.push((format!("{path}/{tg}.{j}"), r32(at) as usize));
                }
            }
            tags.insert(tg, (ty, count, value, field));
        }
        out.insert(path, tags);
    }
    out
}

/// Tags noisecal may change: ISO, NoiseProfile, digests, the raw data ID, pointers to sub-IFDs
/// and (when the raw image is rewritten) its data layout.
fn owned(tag: u16, rewritten: bool) -> bool {
    matches!(tag, 34855 | 34864..=34867 | 51041 | 50972 | 51111 | 50781 | 330 | 34665 | 34853)
        || (rewritten && matches!(tag, 258 | 259 | 273 | 278 | 279 | 317 | 322..=325 | 347 | 50712))
}

fn f64s(b: &[u8], big: bool) -> Vec<f64> {
    b.chunks_exact(8)
        .map(|c| {
            let x: [u8; 8] = c.try_into().expect("8 bytes");
            if big { f64::from_be_bytes(x) } else { f64::from_le_bytes(x) }
        })
        .collect()
}

fn check_kept(kind: Kind) {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let pack_path = pack(d);
    let input = d.join("in.dng");
    let bytes = rich_dng(kind);
    std::fs::write(&input, &bytes).expect("write fixture");
    let output = d.join("out.dng");
    let (ok, err) =
        noisecal(&["-q", "synth", "--pack", s(&pack_path), "--iso", "800", "--seed", "5", s(&input), "-o", s(&output)]);
    assert!(ok, "{kind:?}: {err}");
    let out = std::fs::read(&output).expect("output");
    let big = kind == Kind::AdobeSubIfd;
    let rewritten = kind == Kind::LosslessJpegTiles;

    // Every tag of every directory, but the ones noisecal owns, is the input's, at the same place.
    let (before, after) = (directories(&bytes), directories(&out));
    assert_eq!(before.keys().collect::<Vec<_>>(), after.keys().collect::<Vec<_>>(), "{kind:?}: directories");
    for (path, tags) in &before {
        let new = &after[path];
        for (tg, v) in tags {
            if !owned(*tg, rewritten) {
                assert_eq!(new.get(tg), Some(v), "{kind:?}: tag {tg} of IFD {path} changed");
            }
        }
        for tg in new.keys() {
            assert!(tags.contains_key(tg) || owned(*tg, rewritten), "{kind:?}: tag {tg} added to IFD {path}");
        }
    }
    let raw_path = if kind == Kind::AdobeSubIfd { "0/330.0" } else { "0" };
    let exif = after.iter().find(|(p, _)| p.ends_with("/34665.0")).expect("EXIF IFD").1;
    assert_eq!(exif[&34855].2, if big { 800u16.to_be_bytes() } else { 800u16.to_le_bytes() }, "{kind:?}: ISO");
    assert!(after.values().all(|t| !t.contains_key(&51111) && !t.contains_key(&50972)), "{kind:?}: digests dropped");
    let ids: Vec<&Vec<u8>> = after.values().filter_map(|t| t.get(&50781)).map(|v| &v.2).collect();
    assert!(
        ids.len() == 1 && ids[0].len() == 16 && *ids[0] != (0..16).collect::<Vec<u8>>(),
        "{kind:?}: RawDataUniqueID changed"
    );

    // NoiseProfile: the pack's fit at ISO 800, per plane (R, G = mean of both greens, B).
    let pack = noisecal_core::ModelPack::from_bytes(&std::fs::read(&pack_path).expect("pack")).expect("pack");
    let model = resolve_model(&pack, 800, ModelKind::Noisecal, false).expect("model").model;
    let clean = read_dng(&input).expect("read input");
    let np = fitted_noise_profile(&pack, &model, &clean.layout).expect("profile");
    let want = [
        np.0[0][0],
        np.0[0][1],
        (np.0[1][0] + np.0[2][0]) / 2.0,
        (np.0[1][1] + np.0[2][1]) / 2.0,
        np.0[3][0],
        np.0[3][1],
    ];
    let (ty, count, value, _) = &after[raw_path][&51041];
    assert_eq!((*ty, *count), (12, 6), "{kind:?}: NoiseProfile is 3 DOUBLE pairs");
    assert_eq!(f64s(value, big), want, "{kind:?}: NoiseProfile");
    assert!(after.iter().all(|(p, t)| p == raw_path || !t.contains_key(&51041)), "{kind:?}: one NoiseProfile");

    // Pixels: exactly what the sampler gives for this seed, masked borders as they were.
    let noisy = read_dng(&output).expect("read output");
    let sampler = IsoSampler::new(&pack, &model);
    assert_eq!(noisy.pixels, synthesize(&sampler, clean.pixels.view(), 5), "{kind:?}: pixels");
    assert_eq!(
        (noisy.meta.iso, noisy.meta.exposure_ns, noisy.layout.clone()),
        (800, clean.meta.exposure_ns, clean.layout.clone())
    );

    external_checks(kind, &input, &output, noisy.pixels.view());
    if let Some(keep) = std::env::var_os("NOISECAL_KEEP_DIR") {
        let keep = PathBuf::from(keep);
        std::fs::create_dir_all(&keep).expect("keep dir");
        std::fs::copy(&input, keep.join(format!("{kind:?}-in.dng"))).expect("keep input");
        std::fs::copy(&output, keep.join(format!("{kind:?}-out.dng"))).expect("keep output");
    }
}

#[test]
fn adobe_layout_keeps_everything() {
    check_kept(Kind::AdobeSubIfd);
}

#[test]
fn packed_camera_dng_keeps_everything() {
    check_kept(Kind::CameraPacked12);
}

#[test]
fn lossless_jpeg_dng_keeps_everything_but_its_compression() {
    check_kept(Kind::LosslessJpegTiles);
}

/// The Python of the repository's venv (`target/pyenv`), or `NOISECAL_PYTHON`, or `python3`.
fn python() -> PathBuf {
    if let Some(p) = std::env::var_os("NOISECAL_PYTHON") {
        return p.into();
    }
    let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target/pyenv/bin/python");
    if venv.exists() { venv } else { "python3".into() }
}

/// `exiftool -validate` finds nothing in the output it does not find in the input, and LibRaw
/// (rawpy) reads the output's pixels as noisecal does (each skipped when not installed).
fn external_checks(kind: Kind, input: &Path, output: &Path, active: ndarray::ArrayView2<'_, u16>) {
    let validate = |p: &Path| -> Option<Vec<String>> {
        let o = Command::new("exiftool").args(["-validate", "-warning", "-error", "-a", "-s"]).arg(p).output().ok()?;
        let text = String::from_utf8_lossy(&o.stdout).into_owned();
        Some(text.lines().filter(|l| !l.starts_with("Validate")).map(|l| l.to_string()).collect())
    };
    match (validate(input), validate(output)) {
        (Some(before), Some(after)) => {
            let new: Vec<&String> = after.iter().filter(|l| !before.contains(l)).collect();
            assert!(new.is_empty(), "{kind:?}: exiftool -validate finds new problems: {new:?} (input: {before:?})");
        }
        _ => eprintln!("exiftool not found: skipping its validation"),
    }
    let script = r#"
import sys
try:
    import rawpy
except ImportError:
    print("NO-RAWPY"); sys.exit(0)
with rawpy.imread(sys.argv[1]) as r:
    s = r.sizes
    a = r.raw_image_visible
    print(s.top_margin, s.left_margin, a.shape[0], a.shape[1])
    a.astype("<u2").tofile(sys.argv[2])
"#;
    let dump = output.with_extension("raw");
    let o = Command::new(python()).arg("-c").arg(script).arg(output).arg(&dump).output();
    let Ok(o) = o else {
        eprintln!("no python: skipping the LibRaw check");
        return;
    };
    let text = String::from_utf8_lossy(&o.stdout);
    if text.contains("NO-RAWPY") || !o.status.success() && String::from_utf8_lossy(&o.stderr).contains("No module") {
        eprintln!("rawpy not installed: skipping the LibRaw check");
        return;
    }
    assert!(o.status.success(), "{kind:?}: rawpy cannot read the output: {}", String::from_utf8_lossy(&o.stderr));
    let dims: Vec<usize> = text.split_whitespace().map(|x| x.parse().expect("number")).collect();
    assert_eq!(dims[..2], [ACTIVE[0] as usize, ACTIVE[1] as usize], "{kind:?}: LibRaw's margins are the ActiveArea");
    let b = std::fs::read(&dump).expect("dump");
    let px: Vec<u16> = b.chunks_exact(2).map(|c| u16::from_le_bytes([c[0], c[1]])).collect();
    let seen = Array2::from_shape_vec((dims[2], dims[3]), px).expect("shape");
    assert_eq!(seen, active, "{kind:?}: LibRaw reads other pixels than noisecal wrote");
}
