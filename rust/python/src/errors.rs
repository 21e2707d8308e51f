//! The exceptions, and the boundary that turns errors and panics into them.
//!
//! - `NoisecalError(ValueError)`: every failure of the core (a damaged pack, an ISO outside the
//!   calibrated range, …).
//!   - `InputError(NoisecalError)`: an input array or argument is wrong; the message names the
//!     argument, what is wrong and the fix.
//!     - `MismatchError(InputError)`: an image does not match the pack's sensor (CFA, white
//!       level, bit depth), as `noisecal synth` refuses it.
//! - A wrong dtype or type is a `TypeError` naming the argument and what to pass.
//! - `NoisecalWarning(UserWarning)`: what `out_of_range="warn"` or `check="warn"` reports.

use std::panic::{AssertUnwindSafe, catch_unwind};

use noisecal_core::error::Remedy;
use pyo3::PyErr;
use pyo3::create_exception;
use pyo3::exceptions::{PyTypeError, PyUserWarning, PyValueError};

create_exception!(
    noisecal,
    NoisecalError,
    PyValueError,
    "A noisecal operation failed: bad input (the message names it and the fix) or a damaged pack."
);
create_exception!(
    noisecal,
    InputError,
    NoisecalError,
    "An input array or argument is wrong: the message names it, what is wrong and the fix."
);
create_exception!(
    noisecal,
    MismatchError,
    InputError,
    "An image does not match the pack's sensor (CFA phase, white level, bit depth)."
);
create_exception!(
    noisecal,
    NoisecalWarning,
    PyUserWarning,
    "Input noisecal used as asked but that looks wrong (pixels out of range, another camera)."
);

/// Some input-library messages still name command-line flags: in Python they are arguments.
fn pythonic(msg: String) -> String {
    const FLAGS: [(&str, &str); 3] =
        [("--reference-iso ", "reference_iso="), ("--clean-at", "clean_at"), ("--components", "components")];
    FLAGS.iter().fold(msg, |m, (flag, arg)| m.replace(flag, arg))
}

/// An error of the core or the input library as a `NoisecalError` with its full chain of causes.
pub fn to_py(e: impl Into<anyhow::Error>) -> PyErr {
    let e: anyhow::Error = e.into();
    // The core names what to change; the argument that changes it is Python's.
    let remedy = match Remedy::in_chain(e.chain()) {
        Some(Remedy::Extrapolate) => " (extrapolate=True)",
        Some(Remedy::ParametricModel) => " (model=\"hg\" or model=\"pg\")",
        None => "",
    };
    NoisecalError::new_err(pythonic(format!("{e:#}{remedy}")))
}

/// A `NoisecalError` with a message.
pub fn err(msg: impl Into<String>) -> PyErr {
    NoisecalError::new_err(pythonic(msg.into()))
}

/// An `InputError`: a wrong argument value.
pub fn input(msg: impl Into<String>) -> PyErr {
    InputError::new_err(msg.into())
}

/// A `TypeError`: a wrong dtype or type.
pub fn type_error(msg: impl Into<String>) -> PyErr {
    PyTypeError::new_err(msg.into())
}

/// A `MismatchError`: an image that is not of the pack's sensor.
pub fn mismatch(msg: impl Into<String>) -> PyErr {
    MismatchError::new_err(msg.into())
}

/// Runs `f`, turning a panic into a `NoisecalError` (no panic crosses into Python).
pub fn guarded<T>(what: &str, f: impl FnOnce() -> Result<T, PyErr>) -> Result<T, PyErr> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(r) => r,
        Err(p) => {
            let msg = p
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| p.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".into());
            Err(err(format!("internal error in {what}: {msg} (please report it with the inputs)")))
        }
    }
}
