//! The rounded Gaussian behind HG's noise, for Python: the core's
//! `derive::baselines::rounded_gaussian_sd` and `rounded_variance`, element by element over an
//! array, so that Python code drawing HG-like noise (the benchmark's wrong and loud controls,
//! `noisecal.bench.scaled_hg`) uses the very rule the core's HG tables use.

use numpy::{AllowTypeChange, IntoPyArray, PyArrayDyn, PyArrayLikeDyn};
use pyo3::prelude::*;

use noisecal_core::derive::baselines;

use crate::errors::{guarded, input};

/// Checks that every value is finite and not negative; `what` names the argument.
fn check_values(values: &ndarray::ArrayViewD<'_, f64>, what: &str) -> PyResult<()> {
    match values.iter().find(|v| !v.is_finite() || **v < 0.0) {
        Some(v) => {
            Err(input(format!("{what} must be finite and ≥ 0 (DN²/DN), got {v}: pass the noise's variance or SD")))
        }
        None => Ok(()),
    }
}

/// `f` applied to every element of `values` (checked as [`check_values`] does, `what` naming the
/// argument), with the GIL released.
fn map_values<'py>(
    py: Python<'py>,
    values: PyArrayLikeDyn<'py, f64, AllowTypeChange>,
    what: &'static str,
    name: &'static str,
    f: fn(f64) -> f64,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    let v = values.as_array();
    check_values(&v, what)?;
    let v = v.to_owned();
    let out = py.detach(|| guarded(name, || Ok(v.mapv(f))))?;
    Ok(out.into_pyarray(py))
}

/// The SD `s` (DN) for which `round(N(0, s²))` has the integer variance `var` (DN²), per element:
/// `√(var − 1/12)` from 1.3 DN² up, below it bisection on the exact cell sums; 0 gives 0.
#[pyfunction]
pub fn rounded_gaussian_sd<'py>(
    py: Python<'py>,
    var: PyArrayLikeDyn<'py, f64, AllowTypeChange>,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    map_values(py, var, "var", "rounded_gaussian_sd", baselines::rounded_gaussian_sd)
}

/// The variance (DN²) of `round(N(0, sd²))` on the integers, per element (exact cell sums).
#[pyfunction]
pub fn rounded_variance<'py>(
    py: Python<'py>,
    sd: PyArrayLikeDyn<'py, f64, AllowTypeChange>,
) -> PyResult<Bound<'py, PyArrayDyn<f64>>> {
    map_values(py, sd, "sd", "rounded_variance", baselines::rounded_variance)
}
