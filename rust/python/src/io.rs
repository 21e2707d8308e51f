//! Files: calibrating from a capture set, reading and writing raw DNGs. These call the same code
//! as the `noisecal` command, so a pack or an image is the same whichever made it.

use std::path::PathBuf;

use numpy::{PyArray2, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use noisecal_cli::calibrate::{CalibrateOptions, calibrate_path};
use noisecal_cli::dng;
use noisecal_cli::models::{ModelKind, resolve_model};

use crate::errors::{err, guarded, to_py};
use crate::pack::Pack;

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
    if bin_width == Some(0) {
        return Err(err("bin_width 0 is not a width: give levels per bin (1 or more), or leave it to the default"));
    }
    let opts = CalibrateOptions { reference_iso, bin_width, pooling, plain, ..Default::default() };
    py.detach(|| {
        guarded("calibrate", || calibrate_path(&path, &opts, true).map(|(pack, _)| Pack::new(pack)).map_err(to_py))
    })
}

/// Reads a raw DNG: the CFA array (uint16, `(H, W)`) and its metadata.
#[pyfunction]
pub fn read_dng<'py>(py: Python<'py>, path: PathBuf) -> PyResult<(Bound<'py, PyArray2<u16>>, Bound<'py, PyDict>)> {
    let img = py.detach(|| guarded("read_dng", || dng::read_dng(&path).map_err(to_py)))?;
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
pub fn write_dng(
    py: Python<'_>,
    path: PathBuf,
    pixels: PyReadonlyArray2<'_, u16>,
    template: PathBuf,
    iso: u32,
    pack: Option<PyRef<'_, Pack>>,
) -> PyResult<()> {
    let pixels = pixels.as_array().to_owned();
    let pack = pack.map(|p| p.inner.clone());
    py.detach(|| {
        guarded("write_dng", || {
            noisecal_cli::support::refuse_overwriting_inputs(&path, &[&template]).map_err(to_py)?;
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
                Some(pack) => {
                    let (model, _) = resolve_model(pack, iso, ModelKind::Noisecal, false).map_err(to_py)?;
                    dng::fitted_noise_profile(pack, &model, layout)
                }
                None => None,
            };
            dng::write_derived(&path, &t, &pixels, iso, profile.as_ref()).map_err(to_py)
        })
    })
}
