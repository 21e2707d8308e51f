//! Folder runs that fail part-way say which file and what was kept; lossless-JPEG DNGs the decoder
//! cannot read get an accurate message.

use std::path::Path;
use std::process::Command;

use noisecal_input::dng::tiff::{Ifd, ImageData, TagValue, TiffBuilder, tag};
use noisecal_input::dng::{DngError, read_dng};

mod support;

fn noisecal(args: &[&str]) -> (bool, String) {
    let out = support::run(args);
    (out.ok, out.stderr)
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

#[test]
fn a_folder_run_names_the_failing_file_and_keeps_what_was_written() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let (cal, pack, input, output) = (d.join("cal"), d.join("p.pack"), d.join("in"), d.join("out"));
    let (ok, err) =
        noisecal(&support::simulate(("64", "48"), "2", "100,400", "--ev=-2,0,2", &["-q", "--dngs", s(&cal)]));
    assert!(ok, "{err}");
    let (ok, err) = noisecal(&["-q", "calibrate", s(&cal), "-o", s(&pack)]);
    assert!(ok, "{err}");
    let dng = std::fs::read_dir(&cal).expect("dngs").map(|e| e.expect("entry").path()).min().expect("a dng");
    std::fs::create_dir_all(&input).expect("input dir");
    for name in ["a.dng", "b.dng", "d.dng"] {
        std::fs::copy(&dng, input.join(name)).expect("copy");
    }
    let bytes = std::fs::read(&dng).expect("read");
    std::fs::write(input.join("c.dng"), &bytes[..bytes.len() / 3]).expect("truncated copy");

    let (ok, err) = noisecal(&["-q", "synth", "--pack", s(&pack), "--iso", "400", s(&input), "-o", s(&output)]);
    assert!(!ok, "a truncated DNG in the folder must fail the run");
    assert!(err.contains("c.dng failed (file 3 of 4"), "{err}");
    assert!(err.contains("the 2 outputs written before it are kept in"), "{err}");
    assert!(err.contains("truncated"), "the cause is given too: {err}");
    for (name, kept) in [("a.dng", true), ("b.dng", true), ("c.dng", false), ("d.dng", false)] {
        assert_eq!(output.join(name).exists(), kept, "{name}: {err}");
    }
    read_dng(&output.join("b.dng")).expect("a kept output is a whole DNG");

    // The first file failing: nothing written, said so.
    std::fs::rename(input.join("c.dng"), input.join("0.dng")).expect("rename");
    let (ok, err) = noisecal(&["-q", "synth", "--pack", s(&pack), "--iso", "400", s(&input), "-o", s(&d.join("out2"))]);
    assert!(!ok && err.contains("0.dng failed (file 1 of 4") && err.contains("no output was written"), "{err}");
}

/// A lossless-JPEG DNG whose JPEG stream carries a quantization table (DQT) segment, as some
/// cameras (Blackmagic) write: LibRaw skips the segment, rawler 0.8 refuses the stream.
fn ljpeg_with_dqt() -> Vec<u8> {
    let (w, h) = (64usize, 32usize);
    let v: Vec<u16> = (0..w * h).map(|i| (100 + i * 7 % 800) as u16).collect();
    let jpeg =
        rawler::ljpeg92::LjpegCompressor::new(&v, w / 2, h, 2, 12, 1, 0, 0).expect("encoder").encode().expect("encode");
    let mut stream = jpeg[..2].to_vec(); // SOI
    stream.extend_from_slice(&[0xff, 0xdb, 0, 67, 0]);
    stream.extend_from_slice(&[1u8; 64]);
    stream.extend_from_slice(&jpeg[2..]);
    let mut ifd = Ifd::new();
    ifd.set(tag::NEW_SUBFILE_TYPE, TagValue::Long(vec![0]))
        .set(tag::IMAGE_WIDTH, TagValue::Long(vec![w as u32]))
        .set(tag::IMAGE_LENGTH, TagValue::Long(vec![h as u32]))
        .set(tag::BITS_PER_SAMPLE, TagValue::Short(vec![12]))
        .set(tag::COMPRESSION, TagValue::Short(vec![7]))
        .set(tag::PHOTOMETRIC, TagValue::Short(vec![32803]))
        .set(tag::MAKE, TagValue::Ascii("Blackmagic Design".into()))
        .set(tag::MODEL, TagValue::Ascii("Pocket Cinema Camera 4K".into()))
        .set(tag::SAMPLES_PER_PIXEL, TagValue::Short(vec![1]))
        .set(tag::CFA_REPEAT_PATTERN_DIM, TagValue::Short(vec![2, 2]))
        .set(tag::CFA_PATTERN, TagValue::Byte(vec![0, 1, 1, 2]))
        .set(tag::DNG_VERSION, TagValue::Byte(vec![1, 4, 0, 0]))
        .set(tag::UNIQUE_CAMERA_MODEL, TagValue::Ascii("Blackmagic Pocket Cinema Camera 4K".into()))
        .set(tag::BLACK_LEVEL, TagValue::Long(vec![64]))
        .set(tag::WHITE_LEVEL, TagValue::Long(vec![4095]))
        .set(tag::COLOR_MATRIX_1, TagValue::SRational((0..9).map(|i| (i32::from(i % 4 == 0), 1)).collect()))
        .set(tag::AS_SHOT_NEUTRAL, TagValue::Rational(vec![(1, 2), (1, 1), (1, 2)]))
        .set(tag::EXPOSURE_TIME, TagValue::Rational(vec![(1, 50)]))
        .set(tag::ISO_SPEED_RATINGS, TagValue::Short(vec![400]));
    ifd.image = Some(ImageData::Tiles { tile_width: w as u32, tile_length: h as u32, tiles: vec![stream] });
    TiffBuilder { big_endian: false, chain: vec![ifd] }.to_bytes().expect("serialize")
}

#[test]
fn lossless_jpeg_the_decoder_cannot_read_is_named_as_such() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("P1000123.dng");
    std::fs::write(&path, ljpeg_with_dqt()).expect("write");
    let e = read_dng(&path).expect_err("rawler refuses the stream");
    let msg = e.to_string();
    assert!(matches!(e, DngError::Unsupported { .. }), "{msg}");
    assert!(
        msg.contains("P1000123.dng") && msg.contains("lossless-JPEG compressed") && msg.contains("rawler"),
        "{msg}"
    );
    assert!(msg.contains("uncompressed DNG") && !msg.contains("copy it from the phone"), "{msg}");

    // The claim in the message: LibRaw reads it (checked when rawpy is installed).
    let python = std::env::var_os("NOISECAL_PYTHON").map(std::path::PathBuf::from).unwrap_or_else(|| {
        let venv = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../target/pyenv/bin/python");
        if venv.exists() { venv } else { "python3".into() }
    });
    let script = "import sys\ntry:\n import rawpy\nexcept ImportError:\n print('NO-RAWPY'); sys.exit(0)\nwith rawpy.imread(sys.argv[1]) as r:\n print(int(r.raw_image.sum()))";
    match Command::new(python).arg("-c").arg(script).arg(&path).output() {
        Ok(o) if String::from_utf8_lossy(&o.stdout).contains("NO-RAWPY") => eprintln!("rawpy not installed: skipped"),
        Ok(o) => {
            assert!(o.status.success(), "LibRaw cannot read it either: {}", String::from_utf8_lossy(&o.stderr));
            let sum: u64 = String::from_utf8_lossy(&o.stdout).trim().parse().expect("sum");
            let want: u64 = (0..64 * 32).map(|i| (100 + i * 7 % 800) as u64).sum();
            assert_eq!(sum, want, "LibRaw decodes the stream rawler refuses");
        }
        Err(_) => eprintln!("no python: skipped"),
    }
}
