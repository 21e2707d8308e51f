//! A DNG truncated while calibration holds it: the frame already read keeps its pixels (the file
//! is read into memory, not mapped, so a page past the new end cannot raise SIGBUS), and reading
//! the truncated file again is an error that names it.

use noisecal_core::{CfaPattern, FrameMeta, SensorLayout};
use noisecal_input::dng::{read_dng_meta, read_dng_source, write_dng_from_layout};

/// A 10-bit RGGB DNG of `w × h` written to `dir/name`, pixels `64 + (a·y + b·x) mod 900`; its
/// path, layout and pixels.
fn written_dng(
    dir: &std::path::Path,
    name: &str,
    (w, h): (usize, usize),
    (a, b): (usize, usize),
) -> (std::path::PathBuf, SensorLayout, ndarray::Array2<u16>) {
    let layout =
        SensorLayout { width: w as u32, height: h as u32, cfa: CfaPattern::Rggb, black: [64.0; 4], white: 1023 };
    let pixels = ndarray::Array2::from_shape_fn((h, w), |(y, x)| (64 + (a * y + b * x) % 900) as u16);
    let path = dir.join(name);
    write_dng_from_layout(&path, &layout, &FrameMeta::new(400, 10_000_000), "M", "P", &pixels).expect("write the DNG");
    (path, layout, pixels)
}

#[test]
fn a_file_truncated_under_a_read_frame_is_an_error_not_a_crash() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (512usize, 384usize);
    let (path, layout, pixels) = written_dng(dir.path(), "f.dng", (w, h), (7, 3));
    let len = std::fs::metadata(&path).unwrap().len();
    assert!(len > 2 * (w * h) as u64, "the file holds the image");

    let frame = read_dng_source(&path).unwrap();
    // Another program truncates the file while the frame is held (a mapped file would now
    // raise SIGBUS on the first read of a page past the new end, killing the process).
    std::fs::OpenOptions::new().write(true).open(&path).unwrap().set_len(4096).unwrap();
    assert_eq!(frame.pixels(), pixels.view(), "the frame read before the truncation keeps its pixels");
    let view = frame.frame_view().unwrap();
    assert_eq!(&*view.row(h - 1), pixels.row(h - 1).as_slice().unwrap());

    // Read again, the truncated file is an error naming it, from both readers.
    let name = path.display().to_string();
    let e = read_dng_source(&path).expect_err("a truncated DNG").to_string();
    assert!(e.contains(&name), "{e}");
    let e = read_dng_meta(&path).expect_err("a truncated DNG").to_string();
    assert!(e.contains(&name), "{e}");
    // Truncated inside the image data, the directories intact: the full read says truncated.
    write_dng_from_layout(&path, &layout, &FrameMeta::new(400, 10_000_000), "M", "P", &pixels).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    let cut = len as usize / 2;
    let mut shortened = bytes[..cut].to_vec();
    shortened.extend_from_slice(&bytes[cut + 4096..]);
    std::fs::write(&path, &shortened).unwrap();
    let e = read_dng_source(&path).expect_err("a DNG whose data is cut short").to_string();
    assert!(e.contains(&name), "{e}");
}

/// A template read for synthesis or re-noising (`read_dng_file`) is held the same way: truncated
/// under it, its bytes and pixels stay (a mapped template raised SIGBUS on its next read).
#[test]
fn a_template_truncated_while_held_keeps_its_bytes() {
    let dir = tempfile::tempdir().unwrap();
    let (path, _, pixels) = written_dng(dir.path(), "t.dng", (512, 384), (5, 11));
    let original = std::fs::read(&path).unwrap();

    let file = noisecal_input::dng::read_dng_file(&path).unwrap();
    std::fs::OpenOptions::new().write(true).open(&path).unwrap().set_len(4096).unwrap();
    assert!(file.bytes() == original.as_slice(), "the template keeps the file's bytes as read");
    assert_eq!(file.pixels(), pixels.view(), "and its pixels");
    let e = noisecal_input::dng::read_dng_file(&path).expect_err("a truncated template").to_string();
    assert!(e.contains(&path.display().to_string()), "{e}");
}
