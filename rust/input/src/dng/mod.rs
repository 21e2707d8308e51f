//! DNG input and output.
//!
//! * [`read_dng`] reads a Bayer CFA DNG file (uncompressed 10–16-bit strips or tiles, lossless
//!   JPEG, whatever `rawler` decodes) into the mosaic of its active area, with the levels, CFA
//!   order and capture metadata the calibration needs. It reads the file whole and hands the bytes
//!   to [`decode_dng`], the entry point for callers (and fuzzers) that hold the bytes. The returned layout describes position (0,0) of the
//!   returned array: DNG gives `CFAPattern` and `BlackLevel` relative to the `ActiveArea`, which is
//!   exactly what is returned.
//! * [`write_derived`] writes a DNG derived from a read one ([`read_dng_file`]): the input file
//!   with only its raw pixels, its ISO and its `NoiseProfile` changed, every other tag, sub-IFD,
//!   preview and maker note kept byte for byte (the editor in `edit`). [`write_dng`] does the same
//!   from a [`DngImage`] (re-reading its file). [`DngFile::streamed`] writes the same bytes while
//!   the pixels are drawn, band by band, for inputs stored as uncompressed 16-bit strips.
//! * [`write_dng_from_layout`] writes a fresh uncompressed 16-bit CFA DNG (one IFD, the way
//!   Android's `DngCreator` lays it out) through the small TIFF writer in [`tiff`], atomically,
//!   for the simulator, which has no input file.
//! * [`fitted_noise_profile`] is the DNG `NoiseProfile` of the noise a pack's model synthesizes.
//! * [`Tag`] names every TIFF/DNG tag the reader and the writer use.
//! * [`scan_folder`] lists the DNGs of a folder.

mod buffers;
mod compressed;
mod edit;
mod error;
mod guard;
mod ifd;
mod meta;
mod profile;
mod raw_data;
mod read;
mod sparse;
mod stream;
mod tags;
pub mod tiff;
mod write;

use std::path::{Path, PathBuf};
use std::sync::Arc;

use ndarray::{Array2, ArrayView2};
use noisecal_core::error::FrameError;
use noisecal_core::{FrameMeta, FrameView, SensorLayout};

pub use buffers::release as release_read_buffers;
pub use edit::PixelMode;
pub use error::DngError;
pub use profile::fitted_noise_profile;
pub use read::{
    MAX_DNG_BYTES, decode_dng, decode_dng_meta, decode_dng_template, read_dng, read_dng_file, read_dng_meta,
    read_dng_source, read_dng_template,
};
pub use tags::Tag;
pub use write::{
    DerivedStream, DngSpec, derived_bytes, dng_tiff, write_derived, write_derived_owned, write_dng,
    write_dng_from_layout, write_dng_from_layout_with_profile,
};

/// Colour tags carried from a read DNG to the ones written from it, so other tools still render
/// them. They play no part in the noise model.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ColorTags {
    /// `ColorMatrix1` (XYZ → camera), 9 values for a 3-colour sensor.
    pub color_matrix1: Option<Vec<f64>>,
    /// `CalibrationIlluminant1` (EXIF light source code; 21 = D65).
    pub calibration_illuminant1: Option<u16>,
    /// `AsShotNeutral`, one value per colour plane.
    pub as_shot_neutral: Option<Vec<f64>>,
}

/// A decoded CFA DNG.
#[derive(Debug, Clone)]
pub struct DngImage {
    /// Size of `pixels`, CFA order at its (0,0), black level per CFA position (the DNG
    /// `BlackLevel` pattern, plus `BlackLevelDeltaH/V` averaged per position), white level.
    pub layout: SensorLayout,
    /// ISO and exposure time from EXIF; `black` is `Some(layout.black)`: each DNG carries its own
    /// black level, which is therefore a per-frame value.
    pub meta: FrameMeta,
    /// The CFA mosaic of the active area, `height × width` (row-major).
    pub pixels: Array2<u16>,
    /// `Make` of IFD0 (trimmed; empty if absent).
    pub make: String,
    /// `Model` of IFD0 (trimmed; empty if absent).
    pub model: String,
    /// DNG `NoiseProfile` (tag 51041): `(S, O)` pairs, one per colour plane (or one for all).
    pub noise_profile: Option<Vec<(f64, f64)>>,
    /// Bits per sample of the stored data (10–16).
    pub bits_per_sample: u32,
    /// Colour tags kept for writing.
    pub color: ColorTags,
    /// The file this was read from.
    pub source: PathBuf,
}

/// A file's bytes, read into memory (a buffer of its own, or one reused, or the sparse read's
/// anonymous mapping). Never a mapping of the file: a mapped page past the end of a file
/// truncated under it raises `SIGBUS`.
#[derive(Debug)]
enum Bytes {
    Owned(Vec<u8>),
    Read(buffers::Buffer),
    /// The file's length of zeroed memory mapped for one read alone ([`sparse::meta_bytes`]),
    /// the bytes outside the raw image data read into it; its untouched pages cost nothing.
    Zeroed(memmap2::MmapMut),
}

impl std::ops::Deref for Bytes {
    type Target = [u8];

    fn deref(&self) -> &[u8] {
        match self {
            Bytes::Owned(v) => v,
            Bytes::Read(b) => b,
            Bytes::Zeroed(m) => m,
        }
    }
}

/// A DNG as read, with its file's bytes: the template of the DNGs derived from it.
#[derive(Debug, Clone)]
pub struct DngFile {
    /// The decoded image (`pixels` is empty when read with [`read_dng_template`]).
    pub image: DngImage,
    bytes: Arc<Bytes>,
}

impl DngFile {
    /// The file's bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// A writer of the DNGs derived from this one that writes the pixels as they are drawn,
    /// when the raw image is stored as uncompressed 16-bit strips (see [`DerivedStream`]);
    /// `None` for other storage ([`write_derived`] writes those).
    pub fn streamed(&self) -> Option<DerivedStream<'_>> {
        let (h, w) = (self.image.layout.height as usize, self.image.layout.width as usize);
        stream::stream_plan(&self.bytes, (h, w)).map(|plan| DerivedStream { template: self, plan })
    }

    /// The active area's pixels: a view of the file's bytes when the raw image is stored as
    /// uncompressed 16-bit samples in this machine's byte order (no copy), else the decoded ones.
    pub fn pixels(&self) -> ArrayView2<'_, u16> {
        self.view().unwrap_or_else(|| self.image.pixels.view())
    }

    /// The active area as the core reads frames: in place when [`DngFile::pixels`] is a view of
    /// the file's bytes, else over the decoded pixels.
    pub fn frame_view(&self) -> Result<FrameView<'_>, FrameError> {
        let (h, w) = (self.image.layout.height as usize, self.image.layout.width as usize);
        match raw_data::active_samples(&self.bytes, (h, w)) {
            Some((samples, stride)) => FrameView::from_u16(samples, w, h, stride),
            None => FrameView::from_array(&self.image.pixels),
        }
    }

    fn view(&self) -> Option<ArrayView2<'_, u16>> {
        raw_data::active_view(&self.bytes, (self.image.layout.height as usize, self.image.layout.width as usize))
    }

    /// The file's bytes, owned (copied only if this template is shared).
    pub(crate) fn into_bytes(self) -> Vec<u8> {
        match Arc::try_unwrap(self.bytes) {
            Ok(Bytes::Owned(v)) => v,
            Ok(Bytes::Read(b)) => b.into_vec(),
            Ok(Bytes::Zeroed(m)) => m.to_vec(),
            Err(shared) => shared.to_vec(),
        }
    }
}

/// Every `*.dng` (any case) directly in `dir`, sorted by file name. Sub-folders are not searched.
pub fn scan_folder(dir: &Path) -> Result<Vec<PathBuf>, DngError> {
    let entries = std::fs::read_dir(dir).map_err(|e| DngError::io(dir, e))?;
    let mut out = Vec::new();
    for entry in entries {
        let entry = entry.map_err(|e| DngError::io(dir, e))?;
        let path = entry.path();
        let is_dng = path.extension().and_then(|e| e.to_str()).is_some_and(|e| e.eq_ignore_ascii_case("dng"));
        if !is_dng {
            continue;
        }
        // Follows symlinks: a link to a DNG counts, a folder named x.dng does not.
        let is_file = std::fs::metadata(&path).map(|m| m.is_file()).unwrap_or(false);
        if is_file {
            out.push(path);
        }
    }
    out.sort_by(|a, b| a.file_name().cmp(&b.file_name()));
    Ok(out)
}
