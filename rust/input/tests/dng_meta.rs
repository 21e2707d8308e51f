//! The metadata-only DNG read (used to group capture sets) says what the full read says.

use noisecal_core::{CfaPattern, FrameMeta, SensorLayout};
use noisecal_input::dng::{read_dng, read_dng_meta, write_dng_from_layout};

#[test]
fn metadata_read_matches_full_read() {
    let dir = tempfile::tempdir().unwrap();
    let layout =
        SensorLayout { width: 34, height: 22, cfa: CfaPattern::Gbrg, black: [256.0, 257.5, 255.0, 256.0], white: 4095 };
    let pixels = ndarray::Array2::from_shape_fn((22, 34), |(y, x)| (300 + 7 * y + x) as u16);
    let path = dir.path().join("a.dng");
    write_dng_from_layout(&path, &layout, &FrameMeta::new(640, 33_333_333), "Maker", "Phone", &pixels).unwrap();
    let full = read_dng(&path).unwrap();
    let meta = read_dng_meta(&path).unwrap();
    assert_eq!(full.pixels, pixels);
    assert_eq!(meta.pixels.len(), 0);
    assert_eq!(meta.layout, full.layout);
    assert_eq!(meta.meta, full.meta);
    assert_eq!((meta.make.as_str(), meta.model.as_str()), ("Maker", "Phone"));
    assert_eq!(meta.meta.iso, 640);
    assert_eq!(meta.meta.exposure_ns, 33_333_333);
    // Garbage is refused by both.
    std::fs::write(&path, b"II*\0not a dng").unwrap();
    assert!(read_dng_meta(&path).is_err());
}
