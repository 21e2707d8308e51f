//! `noisecal` for Python: the calibrated non-parametric noise model of a camera, numpy in, numpy
//! out. This crate is the extension module `noisecal._noisecal`; the Python package around it is
//! `python/noisecal/` (the façade, type stubs, the torch sampler and the Ray actor).
//!
//! - [`pack::Pack`]: a model pack (load, properties, `synth`, `synth_float`, `renoise`,
//!   `interp`, `tables`).
//! - [`io`]: `calibrate`, `read_dng`, `write_dng` over `noisecal-input` (the DNG and capture-set code the CLI uses).
//! - [`checks`]: every input checked by name before the core sees it (dtype, shape, values
//!   against the pack's black and white, NaN/inf, a DNG's sensor against the pack's).
//! - [`errors`]: `NoisecalError(ValueError)` and its `InputError`, `MismatchError`; a wrong
//!   dtype is a `TypeError`; a Rust panic is caught at the boundary and becomes an error too.
//! - [`pack_source`]: a `Pack`'s models, read from its file on demand (each ISO decoded when a
//!   sampler first needs it) or made in memory.
//! - [`pool`]: the worker threads, one pool per process (so a forked child works).
//! - [`rounded_gaussian`]: `rounded_gaussian_sd` and `rounded_variance`, the core's rounded
//!   Gaussian (HG's rule below 1.3 DN²) over arrays.
//!
//! Arrays are read without copying, the GIL is released while the core works (`Python::detach`),
//! and the core runs on a pool of all cores; outputs depend only on inputs and seeds.

// The module map above links the crate's private modules (the extension's API is Python's).
#![allow(rustdoc::private_intra_doc_links)]

mod checks;
mod errors;
mod io;
mod pack;
mod pack_source;
mod pool;
mod rounded_gaussian;

use pyo3::prelude::*;

#[pymodule]
fn _noisecal(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("NoisecalError", m.py().get_type::<errors::NoisecalError>())?;
    m.add("InputError", m.py().get_type::<errors::InputError>())?;
    m.add("MismatchError", m.py().get_type::<errors::MismatchError>())?;
    m.add("NoisecalWarning", m.py().get_type::<errors::NoisecalWarning>())?;
    m.add_class::<pack::Pack>()?;
    m.add_function(wrap_pyfunction!(io::calibrate, m)?)?;
    m.add_function(wrap_pyfunction!(io::read_dng, m)?)?;
    m.add_function(wrap_pyfunction!(io::write_dng, m)?)?;
    m.add_function(wrap_pyfunction!(io::write_raw_dng, m)?)?;
    m.add_function(wrap_pyfunction!(rounded_gaussian::rounded_gaussian_sd, m)?)?;
    m.add_function(wrap_pyfunction!(rounded_gaussian::rounded_variance, m)?)?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    Ok(())
}
