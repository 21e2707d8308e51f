//! Files: calibrating from a capture set, reading and writing raw DNGs. These call the same code
//! as the `noisecal` command, so a pack or an image is the same whichever made it.

use std::path::PathBuf;

use numpy::PyArray2;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use noisecal_core::model::structure::Components;
use noisecal_core::resolve::ModelKind;
use noisecal_input::calibrate::{CalibrateOptions, calibrate_path};
use noisecal_input::dng;

use crate::checks::{self, Mismatch};
use crate::errors::{err, guarded, input, to_py};
use crate::pack::Pack;
use crate::pool;

/// Builds a model pack from a folder of DNG bursts or a raw recording, as `noisecal calibrate`.
#[pyfunction]
#[pyo3(signature = (path, *, reference_iso=None, bin_width=None, pooling=None, plain=false))]
pub fn calibrate(
    py: Python<'_>,
    path: PathBuf,
    reference_iso: Option<u32>,
    bin_width: Option<u16>,
    pooling: Option<u64>,
    plain: bool,
) -> PyResult<Pack> {
    if let Some(w) = bin_width {
        noisecal_core::model::bin_width::check(w).map_err(|e| input(format!("bin_width {e}")))?;
    }
    let opts = CalibrateOptions { reference_iso, bin_width, pooling, plain, ..Default::default() };
    py.detach(|| {
        guarded("calibrate", || {
            pool::run(|| calibrate_path(&path, &opts, &mut |_, _| {}).map(|(pack, _)| Pack::new(pack)).map_err(to_py))
        })
    })
}

/// Reads a raw DNG: the CFA array (uint16, `(H, W)`) and its metadata. With `pack`, the image is
/// checked against the pack's sensor as `noisecal synth` checks it: another CFA phase or white
/// level (bit depth) raises `MismatchError` (`mismatch="warn"`: a warning instead; `"ignore"`: no
/// check); another camera (make, model) gives a `NoisecalWarning`.
#[pyfunction]
#[pyo3(signature = (path, *, pack=None, mismatch="raise"))]
pub fn read_dng<'py>(
    py: Python<'py>,
    path: PathBuf,
    pack: Option<PyRef<'py, Pack>>,
    mismatch: &str,
) -> PyResult<(Bound<'py, PyArray2<u16>>, Bound<'py, PyDict>)> {
    let policy = Mismatch::parse(mismatch)?;
    let img = py.detach(|| guarded("read_dng", || pool::run(|| dng::read_dng(&path).map_err(to_py))))?;
    if let Some(pack) = &pack {
        checks::dng_matches(py, &path, &img.layout, &img.make, &img.model, &pack.source.fields, policy)?;
    }
    let d = PyDict::new(py);
    d.set_item("iso", img.meta.iso)?;
    d.set_item("exposure_ns", img.meta.exposure_ns)?;
    d.set_item("cfa", img.layout.cfa.name())?;
    d.set_item("black", img.layout.black.to_vec())?;
    d.set_item("white", img.layout.white)?;
    d.set_item("bits_per_sample", img.bits_per_sample)?;
    d.set_item("make", &img.make)?;
    d.set_item("model", &img.model)?;
    d.set_item("noise_profile", img.noise_profile.clone())?;
    Ok((PyArray2::from_owned_array(py, img.pixels), d))
}

/// Writes `pixels` as a raw DNG at `iso`, derived from the DNG `template`: the template's file
/// with only its raw pixels, its ISO and its NoiseProfile changed, every other tag (orientation,
/// crop, colour, opcode lists, EXIF, maker notes) kept byte for byte; atomically (a temporary
/// file, then a rename). With `pack`, the NoiseProfile is the pack's fit at `iso` (as `noisecal
/// synth` writes it); without, the template's NoiseProfile is dropped (it would not describe the
/// new pixels). `path` may not be the template.
#[pyfunction]
#[pyo3(signature = (path, pixels, *, template, iso, pack=None))]
pub fn write_dng<'py>(
    py: Python<'py>,
    path: PathBuf,
    pixels: &Bound<'py, PyAny>,
    template: PathBuf,
    iso: u32,
    pack: Option<PyRef<'py, Pack>>,
) -> PyResult<()> {
    let pixels = one_image(pixels, "write_dng", " (what synth returns)")?;
    let pack = pack.map(|p| p.source.clone());
    py.detach(|| {
        guarded("write_dng", || {
            pool::run(|| {
                noisecal_input::files::refuse_overwriting_inputs(&path, &[&template]).map_err(to_py)?;
                let t = dng::read_dng_template(&template).map_err(to_py)?;
                let layout = &t.image.layout;
                let (h, w) = pixels.dim();
                if (w as u32, h as u32) != (layout.width, layout.height) {
                    return Err(err(format!(
                        "pixels are {w}×{h} but the template {} is {}×{}: give an image of the template's size",
                        template.display(),
                        layout.width,
                        layout.height
                    )));
                }
                let profile = match &pack {
                    Some(source) => {
                        let (pack, resolved) = source.resolve(iso, ModelKind::Noisecal, Components::PIXEL, false)?;
                        dng::fitted_noise_profile(&pack, &resolved.model, layout)
                    }
                    None => None,
                };
                dng::write_derived(&path, &t, &pixels, iso, profile.as_ref()).map_err(to_py)
            })
        })
    })
}

/// Writes `pixels` as a fresh raw DNG described by its arguments alone (no template): the sensor's
/// CFA order, black level per CFA position (one value for all four, or four), white level, and
/// the frame's ISO and exposure. For converting raw frames that come in another container (a
/// 16-bit PNG, a numpy array) into a folder `noisecal calibrate` groups by ISO × exposure.
/// Written atomically (a temporary file, then a rename), by the writer of `noisecal simulate`.
#[pyfunction]
#[pyo3(signature = (path, pixels, *, cfa, black, white, iso, exposure_ns, make="noisecal", model="converted"))]
#[allow(clippy::too_many_arguments)] // the DNG's fields, each a keyword argument
pub fn write_raw_dng<'py>(
    py: Python<'py>,
    path: PathBuf,
    pixels: &Bound<'py, PyAny>,
    cfa: &str,
    black: Vec<f32>,
    white: u16,
    iso: u32,
    exposure_ns: u64,
    make: &str,
    model: &str,
) -> PyResult<()> {
    let pixels = one_image(pixels, "write_raw_dng", "")?;
    let cfa = noisecal_core::CfaPattern::parse(cfa)
        .ok_or_else(|| input(format!("cfa {cfa:?}: use RGGB, BGGR, GRBG or GBRG")))?;
    let black: [f32; noisecal_core::POSITIONS] = match black.as_slice() {
        [b] => [*b; noisecal_core::POSITIONS],
        [a, b, c, d] => [*a, *b, *c, *d],
        other => {
            return Err(input(format!("black has {} values: give one, or four (one per CFA position)", other.len())));
        }
    };
    let (h, w) = pixels.dim();
    let layout = noisecal_core::SensorLayout { width: w as u32, height: h as u32, cfa, black, white };
    layout.validate().map_err(|e| input(format!("the DNG's layout: {e}")))?;
    if iso == 0 || exposure_ns == 0 {
        return Err(input("iso and exposure_ns must be above 0: give the frame's ISO and exposure (ns)"));
    }
    let meta = noisecal_core::FrameMeta::new(iso, exposure_ns);
    py.detach(|| {
        guarded("write_raw_dng", || {
            pool::run(|| dng::write_dng_from_layout(&path, &layout, &meta, make, model, &pixels).map_err(to_py))
        })
    })
}

/// The one (H, W) uint16 image `pixels` a DNG writer (`writer`) takes, refused by name if it is
/// of another type or a batch; `source` says where such pixels come from, in the hint.
fn one_image(pixels: &Bound<'_, PyAny>, writer: &str, source: &str) -> PyResult<ndarray::Array2<u16>> {
    let pixels = checks::array::<u16>(pixels, "pixels", "uint16", |_| {
        format!("raw DN, black included{source}: np.rint(pixels).astype(np.uint16) within [0, white]")
    })?;
    let view = pixels.as_array();
    let (imgs, batch) = checks::images(&view, "pixels")?;
    if batch {
        return Err(input(format!(
            "pixels is a batch of {} images: {writer} writes one (H, W) image per file",
            imgs.len()
        )));
    }
    Ok(imgs[0].to_owned())
}
