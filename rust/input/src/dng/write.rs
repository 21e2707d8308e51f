//! Writing CFA DNGs: derived from a read one ([`write_derived`], through the editor in
//! `super::edit`), or fresh (below).
//!
//! rawler's `DngWriter` converts a whole `RawImage` (camera definition, colour matrices, crop
//! modes) and asserts on anything it does not expect; writing a bare mosaic through it means
//! faking a camera. A Bayer DNG is one TIFF IFD with ~30 tags, so it is written here through the
//! small writer in [`super::tiff`], with exactly the tags noisecal and other readers need:
//! uncompressed 16-bit little-endian strips in IFD0 (like Android's `DngCreator`), CFA tags,
//! `BlackLevel` as a 2×2 rational pattern (fractional levels survive), `WhiteLevel`, colour tags,
//! and an EXIF IFD with `ExposureTime` and `ISOSpeedRatings`.

use std::path::Path;
use std::sync::Mutex;
use std::sync::atomic::{AtomicBool, AtomicU16, AtomicUsize, Ordering};

use ndarray::Array2;
use noisecal_core::model::layout::CfaColor;
use noisecal_core::{FrameMeta, SensorLayout};

use noisecal_core::model::pack::NoiseProfile;

use super::edit::{self, PixelMode};
use super::stream;
use super::tags::Tag;
use super::tiff::{Ifd, ImageData, TagValue, TiffBuilder, u16_bytes};
use super::{ColorTags, DngError, DngFile, DngImage};

/// Everything a written DNG says besides its pixels.
#[derive(Debug, Clone, PartialEq)]
pub struct DngSpec {
    pub layout: SensorLayout,
    /// ISO and exposure; `meta.black`, when set, overrides `layout.black` as the file's BlackLevel.
    pub meta: FrameMeta,
    pub make: String,
    pub model: String,
    pub color: ColorTags,
}

/// Writes `pixels` (the active area, as read) as a DNG derived from `template`: the template's
/// file with only its raw pixels, its ISO (`iso`) and its `NoiseProfile` (`noise_profile`, per CFA
/// position normalised to the template's levels, see [`super::fitted_noise_profile`]; `None`
/// drops the template's, which would not describe the new pixels) changed. Every other tag,
/// sub-IFD, preview, EXIF/GPS/maker-note data is kept byte for byte. An uncompressed raw image is
/// written over in place; a compressed (or linearized, interleaved) one is replaced by
/// uncompressed 16-bit strips. Written atomically.
pub fn write_derived(
    path: &Path,
    template: &DngFile,
    pixels: &Array2<u16>,
    iso: u32,
    noise_profile: Option<&NoiseProfile>,
) -> Result<(), DngError> {
    let (bytes, _) = derived_bytes(path, template, pixels, iso, noise_profile)?;
    // A failure leaves any existing file untouched and never a half-written DNG under `path`;
    // permissions follow noisecal_io's policy.
    create_parent(path)?;
    noisecal_io::write_bytes_atomic(path, &bytes).map_err(|e| DngError::io(path, e))
}

/// As [`write_derived`], consuming the template: its bytes become the output's without a copy.
pub fn write_derived_owned(
    path: &Path,
    template: DngFile,
    pixels: &Array2<u16>,
    iso: u32,
    noise_profile: Option<&NoiseProfile>,
) -> Result<(), DngError> {
    let source = template.image.source.clone();
    let layout = template.image.layout.clone();
    let (bytes, _) = edit::derive(template.into_bytes(), &layout, pixels.view(), iso, noise_profile, |b| {
        super::read::decode_full_raw(b, &source).map_err(|e| e.to_string())
    })
    .map_err(|what| DngError::invalid(path, format!("from the template {}: {what}", source.display())))?;
    create_parent(path)?;
    noisecal_io::write_bytes_atomic(path, &bytes).map_err(|e| DngError::io(path, e))
}

/// A DNG derived from a template ([`DngFile::streamed`]) written while its pixels are drawn: the
/// bytes [`write_derived`] writes, made in parts. The template's bytes around its raw rows go to
/// a temporary file next to the output first; each band of noisy rows is then encoded in the
/// file's byte order and written where the template stores those rows as soon as it is drawn,
/// on the thread that drew it, and the OS is asked to start writing it to the disk
/// ([`noisecal_io::start_writeback`]), so the sync of the commit waits for little; the tag
/// edits follow. There is no image-sized buffer and no separate encoding pass.
#[derive(Debug)]
pub struct DerivedStream<'a> {
    pub(super) template: &'a DngFile,
    pub(super) plan: stream::StreamPlan,
}

thread_local! {
    /// Per thread, the stored rows of a band being encoded.
    static SCRATCH: std::cell::RefCell<Vec<u8>> = const { std::cell::RefCell::new(Vec::new()) };
}

impl DerivedStream<'_> {
    /// Writes the derived DNG with ISO `iso` to a temporary file next to `path`, and returns it
    /// uncommitted: [`noisecal_io::AtomicFile::commit`] syncs it and renames it over `path`
    /// (dropping it instead removes it). `draw` is given the sink the noisy image goes to, as
    /// [`noisecal_core::synth::synthesize_bands`] hands it over (`sink(first row, whole rows of
    /// the active area)`; every row exactly once, in any order, from any thread), and returns the
    /// NoiseProfile to write (see [`write_derived`]).
    pub fn write(
        &self,
        path: &Path,
        iso: u32,
        draw: impl FnOnce(&(dyn Fn(usize, &[u16]) + Sync)) -> Option<NoiseProfile>,
    ) -> Result<noisecal_io::AtomicFile, DngError> {
        if iso == 0 {
            return Err(DngError::invalid(path, "ISO is 0; pass the sensitivity of the frame"));
        }
        let input = self.template.bytes();
        let layout = &self.template.image.layout;
        let (ah, aw) = (layout.height as usize, layout.width as usize);
        let io = |e: std::io::Error| DngError::io(path, e);
        create_parent(path)?;
        let mut out = noisecal_io::AtomicFile::create(path).map_err(io)?;
        let file = out.positioned().map_err(io)?;
        for (a, b) in self.plan.gaps(input.len()) {
            noisecal_io::write_all_at(file, &input[a..b], a as u64).map_err(io)?;
        }
        let step = edit::UNIQUE_ID_STEP;
        let sampled: Vec<AtomicU16> = (0..(ah * aw).div_ceil(step)).map(|_| AtomicU16::new(0)).collect();
        let rows_done = AtomicUsize::new(0);
        let failed: Mutex<Option<std::io::Error>> = Mutex::new(None);
        let stop = AtomicBool::new(false);
        let sink = |y0: usize, samples: &[u16]| {
            // The pixels the new RawDataUniqueID hashes.
            let first = y0 * aw;
            let mut k = first.div_ceil(step) * step;
            while k < first + samples.len() {
                if let Some(slot) = sampled.get(k / step) {
                    slot.store(samples[k - first], Ordering::Relaxed);
                }
                k += step;
            }
            let whole_rows = samples.len().is_multiple_of(aw.max(1)) && y0 + samples.len() / aw.max(1) <= ah;
            if stop.load(Ordering::Relaxed) || !whole_rows {
                stop.store(true, Ordering::Relaxed);
                return;
            }
            let written = SCRATCH.with(|scratch| {
                let mut scratch = scratch.borrow_mut();
                self.plan.encode(input, y0, samples, &mut scratch, |at, bytes| {
                    noisecal_io::write_all_at(file, bytes, at)?;
                    noisecal_io::start_writeback(file, at, bytes.len() as u64);
                    Ok::<(), std::io::Error>(())
                })
            });
            match written {
                Ok(()) => {
                    rows_done.fetch_add(samples.len() / aw, Ordering::Relaxed);
                }
                Err(e) => {
                    stop.store(true, Ordering::Relaxed);
                    if let Ok(mut f) = failed.lock() {
                        f.get_or_insert(e);
                    }
                }
            }
        };
        let profile = draw(&sink);
        if let Some(e) = failed.into_inner().ok().flatten() {
            return Err(io(e));
        }
        if stop.load(Ordering::Relaxed) || rows_done.load(Ordering::Relaxed) != ah {
            return Err(DngError::invalid(path, "the noisy image was not drawn whole (internal error)"));
        }
        let source = &self.template.image.source;
        let (patches, tail) = self
            .plan
            .finish(input, layout, iso, profile.as_ref(), sampled.iter().map(|v| v.load(Ordering::Relaxed)))
            .map_err(|what| DngError::invalid(path, format!("from the template {}: {what}", source.display())))?;
        for (at, bytes) in &patches {
            noisecal_io::write_all_at(file, bytes, *at as u64).map_err(io)?;
        }
        if !tail.is_empty() {
            noisecal_io::write_all_at(file, &tail, input.len() as u64).map_err(io)?;
        }
        Ok(out)
    }
}

/// The bytes [`write_derived`] writes (`path` names the output in errors), and how the pixels
/// got in.
pub fn derived_bytes(
    path: &Path,
    template: &DngFile,
    pixels: &Array2<u16>,
    iso: u32,
    noise_profile: Option<&NoiseProfile>,
) -> Result<(Vec<u8>, PixelMode), DngError> {
    if iso == 0 {
        return Err(DngError::invalid(path, "ISO is 0; pass the sensitivity of the frame"));
    }
    let source = &template.image.source;
    let decode_full = |b: &[u8]| super::read::decode_full_raw(b, source).map_err(|e| e.to_string());
    edit::derive(template.bytes().to_vec(), &template.image.layout, pixels.view(), iso, noise_profile, decode_full)
        .map_err(|what| DngError::invalid(path, format!("from the template {}: {what}", source.display())))
}

/// Writes `pixels` as a DNG derived from the file `template` was read from, as [`write_derived`]
/// with no `NoiseProfile`. `pixels` must have the template's size. If that file is gone, or no
/// longer holds the image `template` describes, a fresh DNG is written from `template`'s metadata
/// (make, model, CFA, levels, exposure, colour tags) instead.
pub fn write_dng(path: &Path, template: &DngImage, pixels: &Array2<u16>, iso: u32) -> Result<(), DngError> {
    let file = noisecal_io::read_regular(&template.source, super::MAX_DNG_BYTES)
        .ok()
        .and_then(|b| super::decode_dng_template(b, &template.source).ok())
        .filter(|f| f.image.layout == template.layout);
    if let Some(file) = file {
        return write_derived(path, &file, pixels, iso, None);
    }
    let spec = DngSpec {
        layout: template.layout.clone(),
        // The template's layout is authoritative (read_dng sets meta.black to the same values).
        meta: FrameMeta { iso, black: None, ..template.meta },
        make: template.make.clone(),
        model: template.model.clone(),
        color: template.color.clone(),
    };
    write_spec(path, &spec, pixels)
}

/// Writes `pixels` as a DNG described by `layout` and `meta` (for the simulator and demos, which
/// have no template DNG). Same writer as [`write_dng`].
pub fn write_dng_from_layout(
    path: &Path,
    layout: &SensorLayout,
    meta: &FrameMeta,
    make: &str,
    model: &str,
    pixels: &Array2<u16>,
) -> Result<(), DngError> {
    write_dng_from_layout_with_profile(path, layout, meta, make, model, pixels, None)
}

/// As [`write_dng_from_layout`], with the DNG `NoiseProfile` (tag 51041) `profile` in IFD0 when
/// given: one `(S, O)` pair per colour plane (R, G, B, the file's `CFAPlaneColor`), the mean of
/// that colour's CFA positions, as [`write_derived`] writes it. For the simulator, which knows
/// its sensor's noise law. `None` writes exactly the bytes of [`write_dng_from_layout`].
pub fn write_dng_from_layout_with_profile(
    path: &Path,
    layout: &SensorLayout,
    meta: &FrameMeta,
    make: &str,
    model: &str,
    pixels: &Array2<u16>,
    profile: Option<&NoiseProfile>,
) -> Result<(), DngError> {
    let spec = DngSpec {
        layout: layout.clone(),
        meta: *meta,
        make: make.to_string(),
        model: model.to_string(),
        color: ColorTags::default(),
    };
    let Some(profile) = profile else { return write_spec(path, &spec, pixels) };
    if let Some(problem) = profile.problem() {
        return Err(DngError::invalid(path, format!("the NoiseProfile to write is not usable: {problem}")));
    }
    let mut tiff = dng_tiff(&spec, pixels).map_err(|what| DngError::invalid(path, what))?;
    tiff.chain[0].set(Tag::NoiseProfile, TagValue::Double(edit::plane_pairs(profile, layout, &[0, 1, 2])));
    let bytes = tiff.to_bytes().map_err(|what| DngError::invalid(path, what))?;
    create_parent(path)?;
    noisecal_io::write_bytes_atomic(path, &bytes).map_err(|e| DngError::io(path, e))
}

/// Builds the TIFF structure of a DNG (IFD0 = raw image, EXIF sub-IFD) without writing it, so
/// callers (tests) can alter tags before serializing with [`TiffBuilder::to_bytes`].
pub fn dng_tiff(spec: &DngSpec, pixels: &Array2<u16>) -> Result<TiffBuilder, String> {
    let layout = &spec.layout;
    let (h, w) = pixels.dim();
    if (w, h) != (layout.width as usize, layout.height as usize) {
        return Err(format!("the pixel array is {w}×{h} but the layout says {}×{}", layout.width, layout.height));
    }
    layout.validate().map_err(|e| format!("invalid layout: {e}"))?;
    if spec.meta.iso == 0 {
        return Err("ISO is 0; pass the sensitivity of the frame".into());
    }
    if spec.meta.exposure_ns == 0 {
        return Err("exposure time is 0 ns; pass the exposure of the frame".into());
    }
    let black = spec.meta.black_or(layout);
    if let Some((pos, b)) =
        black.iter().enumerate().find(|(_, b)| !b.is_finite() || **b < 0.0 || **b >= layout.white as f32)
    {
        return Err(format!("black level {b} at CFA position {pos} is not in [0, white={})", layout.white));
    }

    let mut raw = Ifd::new();
    raw.set(Tag::NewSubfileType, TagValue::Long(vec![0]))
        .set(Tag::ImageWidth, TagValue::Long(vec![layout.width]))
        .set(Tag::ImageLength, TagValue::Long(vec![layout.height]))
        .set(Tag::BitsPerSample, TagValue::Short(vec![16]))
        .set(Tag::Compression, TagValue::Short(vec![1]))
        .set(Tag::PhotometricInterpretation, TagValue::Short(vec![32803]))
        .set(Tag::Make, TagValue::Ascii(spec.make.trim().to_string()))
        .set(Tag::Model, TagValue::Ascii(spec.model.trim().to_string()))
        .set(Tag::Orientation, TagValue::Short(vec![1]))
        .set(Tag::SamplesPerPixel, TagValue::Short(vec![1]))
        .set(Tag::PlanarConfiguration, TagValue::Short(vec![1]))
        .set(Tag::Software, TagValue::Ascii(format!("noisecal {}", env!("CARGO_PKG_VERSION"))))
        .set(Tag::CfaRepeatPatternDim, TagValue::Short(vec![2, 2]))
        .set(Tag::CfaPattern, TagValue::Byte(layout.cfa.colors().map(color_code).to_vec()))
        .set(Tag::DngVersion, TagValue::Byte(vec![1, 4, 0, 0]))
        .set(Tag::DngBackwardVersion, TagValue::Byte(vec![1, 1, 0, 0]))
        .set(Tag::UniqueCameraModel, TagValue::Ascii(unique_model(&spec.make, &spec.model)))
        .set(Tag::CfaPlaneColor, TagValue::Byte(vec![0, 1, 2]))
        .set(Tag::CfaLayout, TagValue::Short(vec![1]))
        .set(Tag::BlackLevelRepeatDim, TagValue::Short(vec![2, 2]))
        .set(Tag::BlackLevel, TagValue::Rational(black.iter().map(|&b| rational_f32(b)).collect()))
        .set(Tag::WhiteLevel, TagValue::Long(vec![u32::from(layout.white)]));

    // Colour tags: what the template had, else neutral placeholders so renderers accept the file.
    let matrix = spec.color.color_matrix1.as_ref().filter(|m| m.len() == 9 && m.iter().all(|x| x.is_finite()));
    let matrix: Vec<(i32, i32)> = match matrix {
        Some(m) => {
            m.iter().map(|&x| ((x * 10000.0).round().clamp(i32::MIN as f64, i32::MAX as f64) as i32, 10000)).collect()
        }
        None => (0..9).map(|i| (if i % 4 == 0 { 1 } else { 0 }, 1)).collect(),
    };
    raw.set(Tag::ColorMatrix1, TagValue::SRational(matrix))
        .set(Tag::CalibrationIlluminant1, TagValue::Short(vec![spec.color.calibration_illuminant1.unwrap_or(21)]));
    let neutral =
        spec.color.as_shot_neutral.as_ref().filter(|n| n.len() == 3 && n.iter().all(|x| x.is_finite() && *x > 0.0));
    let neutral: Vec<(u32, u32)> = match neutral {
        Some(n) => n.iter().map(|&x| ((x * 10000.0).round().min(u32::MAX as f64) as u32, 10000)).collect(),
        None => vec![(1, 1); 3],
    };
    raw.set(Tag::AsShotNeutral, TagValue::Rational(neutral));

    // Pixels: 16-bit little-endian strips of about 256 KiB.
    let rows_per_strip = ((256 * 1024) / (2 * w)).clamp(1, h);
    let samples: Vec<u16> = match pixels.as_slice() {
        Some(s) => s.to_vec(),
        None => pixels.iter().copied().collect(),
    };
    let strips = samples.chunks(rows_per_strip * w).map(|c| u16_bytes(c, false)).collect();
    raw.image = Some(ImageData::Strips { rows_per_strip: rows_per_strip as u32, strips });

    let mut exif = Ifd::new();
    exif.set(Tag::ExposureTime, TagValue::Rational(vec![exposure_rational(spec.meta.exposure_ns)]))
        .set(Tag::ExifVersion, TagValue::Undefined(b"0230".to_vec()));
    if spec.meta.iso <= 65535 {
        exif.set(Tag::IsoSpeedRatings, TagValue::Short(vec![spec.meta.iso as u16]));
    } else {
        exif.set(Tag::IsoSpeedRatings, TagValue::Short(vec![65535]))
            .set(Tag::SensitivityType, TagValue::Short(vec![3]))
            .set(Tag::IsoSpeed, TagValue::Long(vec![spec.meta.iso]));
    }
    raw.sub_ifds.insert(Tag::ExifIfd, vec![exif]);

    Ok(TiffBuilder { big_endian: false, chain: vec![raw] })
}

fn write_spec(path: &Path, spec: &DngSpec, pixels: &Array2<u16>) -> Result<(), DngError> {
    let bytes = dng_tiff(spec, pixels).and_then(|t| t.to_bytes()).map_err(|what| DngError::invalid(path, what))?;
    // A failure leaves any existing file untouched and never a half-written DNG under `path`;
    // permissions follow noisecal_io's policy.
    create_parent(path)?;
    noisecal_io::write_bytes_atomic(path, &bytes).map_err(|e| DngError::io(path, e))
}

/// The output DNG's folder, created when missing (as for every CLI output).
fn create_parent(path: &Path) -> Result<(), DngError> {
    crate::files::create_parent(path).map_err(|e| DngError::io(path, e))
}

fn color_code(c: CfaColor) -> u8 {
    match c {
        CfaColor::Red => 0,
        CfaColor::Green => 1,
        CfaColor::Blue => 2,
    }
}

fn unique_model(make: &str, model: &str) -> String {
    let s = format!("{} {}", make.trim(), model.trim()).trim().to_string();
    if s.is_empty() { "noisecal".into() } else { s }
}

/// A rational that reads back as exactly `x` (as f32): the smallest power-of-ten denominator that
/// does, else 1/65536 steps.
fn rational_f32(x: f32) -> (u32, u32) {
    let v = x as f64;
    for d in [1u32, 10, 100, 1000, 10_000, 100_000] {
        let n = (v * d as f64).round();
        if n <= u32::MAX as f64 && (n / d as f64) as f32 == x {
            return (n as u32, d);
        }
    }
    ((v * 65536.0).round().min(u32::MAX as f64) as u32, 65536)
}

/// Exposure time in ns as an EXIF rational in seconds (exact below 4.29 s after reduction).
fn exposure_rational(ns: u64) -> (u32, u32) {
    fn gcd(a: u64, b: u64) -> u64 {
        if b == 0 { a } else { gcd(b, a % b) }
    }
    let g = gcd(ns, 1_000_000_000).max(1);
    let (mut n, mut d) = (ns / g, 1_000_000_000 / g);
    while n > u32::MAX as u64 && d >= 10 {
        n = (n + 5) / 10;
        d /= 10;
    }
    (n.min(u32::MAX as u64) as u32, d as u32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rationals_read_back_exactly() {
        for x in [0.0f32, 64.0, 63.5, 64.25, 255.75, 1023.3, 511.125, 4096.0, 0.1] {
            let (n, d) = rational_f32(x);
            assert_eq!((n as f64 / d as f64) as f32, x, "{x} -> {n}/{d}");
        }
        for ns in [1u64, 33_333_333, 10_000_000, 1_000_000_000, 4_500_000_000, 30_000_000_000] {
            let (n, d) = exposure_rational(ns);
            let back = ((n as u128 * 1_000_000_000 + d as u128 / 2) / d as u128) as u64;
            assert_eq!(back, ns, "{ns} -> {n}/{d}");
        }
        // 12.3456789012 s cannot be exact in u32/u32; it stays within 1 µs.
        let (n, d) = exposure_rational(12_345_678_901);
        let back = n as f64 / d as f64 * 1e9;
        assert!((back - 12_345_678_901.0).abs() < 1e3, "{back}");
    }
}
