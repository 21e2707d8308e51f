//! Every input checked by name before the core sees it: dtype, shape, values (against the pack's
//! black and white levels), NaN/inf, and a DNG's metadata against the pack's sensor. Messages say
//! what is wrong and the fix, in Python terms.

use std::ffi::CString;

use ndarray::{ArrayView2, ArrayViewD, Axis};
use numpy::{Element, PyReadonlyArrayDyn};
use pyo3::prelude::*;

use noisecal_core::model::layout::{CfaPattern, position};
use noisecal_core::{ModelPack, POSITIONS, SensorLayout};

use crate::errors::{NoisecalWarning, input, mismatch, type_error};

/// What to do with pixels outside the pack's codes (`out_of_range=`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum OutOfRange {
    /// Refuse the input (default).
    Raise,
    /// Use it as `Allow` does, with a `NoisecalWarning` giving the counts.
    Warn,
    /// Use it as asked: the documented handling of each method.
    Allow,
}

impl OutOfRange {
    pub fn parse(s: &str) -> PyResult<Self> {
        match s {
            "raise" => Ok(Self::Raise),
            "warn" => Ok(Self::Warn),
            "allow" => Ok(Self::Allow),
            _ => Err(input(format!("out_of_range={s:?}: use \"raise\" (default), \"warn\" or \"allow\""))),
        }
    }
}

/// What to do when a DNG does not match the pack (`mismatch=` of `read_dng`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Mismatch {
    Raise,
    Warn,
    Ignore,
}

impl Mismatch {
    pub fn parse(s: &str) -> PyResult<Self> {
        match s {
            "raise" => Ok(Self::Raise),
            "warn" => Ok(Self::Warn),
            "ignore" => Ok(Self::Ignore),
            _ => Err(input(format!("mismatch={s:?}: use \"raise\" (default), \"warn\" or \"ignore\""))),
        }
    }
}

/// A `NoisecalWarning` with `msg`, attributed to the caller's line.
pub fn warn(py: Python<'_>, msg: &str) -> PyResult<()> {
    let msg = CString::new(msg.replace('\0', " ")).unwrap_or_default();
    PyErr::warn(py, &py.get_type::<NoisecalWarning>(), &msg, 2)
}

/// What the object is, for a TypeError: its dtype for an array, else its type.
fn describe(obj: &Bound<'_, PyAny>) -> String {
    let ty = obj.get_type().name().map(|n| n.to_string()).unwrap_or_else(|_| "object".into());
    match obj.getattr("dtype") {
        Ok(d) => format!("{ty} of dtype {}", d.str().map(|s| s.to_string()).unwrap_or_default()),
        Err(_) => ty,
    }
}

/// `obj` as a readonly numpy array of `T` (`dtype` its name), or a TypeError naming the argument
/// and `fix`. Any strides are read in place (a crop, a transposed view, negative steps).
pub fn array<'py, T: Element>(
    obj: &Bound<'py, PyAny>,
    name: &str,
    dtype: &str,
    fix: impl FnOnce(&str) -> String,
) -> PyResult<PyReadonlyArrayDyn<'py, T>> {
    match obj.extract::<PyReadonlyArrayDyn<'py, T>>() {
        Ok(a) => Ok(a),
        Err(e) => {
            let got = describe(obj);
            if got.ends_with(&format!("dtype {dtype}")) {
                // The right array, but not readable now (written by another thread).
                return Err(e);
            }
            Err(type_error(format!("{name} must be a numpy array of {dtype}, got {got}: {}", fix(&got))))
        }
    }
}

/// `(H, W)` or `(N, H, W)` → views of each image, and whether there was a batch axis. Refuses an
/// RGB(A) image (a trailing axis of 3 or 4), a channel axis, empty images and other ranks.
pub fn images<'a, T>(a: &'a ArrayViewD<'_, T>, name: &str) -> PyResult<(Vec<ArrayView2<'a, T>>, bool)> {
    let shape = a.shape();
    let shown = format!("{shape:?}").replace('[', "(").replace(']', ")");
    if a.ndim() == 3 && matches!(shape[2], 3 | 4) {
        return Err(input(format!(
            "{name} has shape {shown}: a trailing axis of {} is colour channels; pass the raw CFA mosaic, not RGB: one (H, W) plane of DN per image as the sensor wrote it (read_dng gives it), or a batch (N, H, W)",
            shape[2]
        )));
    }
    if a.ndim() == 3 && shape[2] == 1 {
        return Err(input(format!(
            "{name} has shape {shown}: drop the channel axis ({name}[..., 0]) and pass (H, W), or a batch (N, H, W)"
        )));
    }
    let imgs: Vec<ArrayView2<'a, T>> = match a.ndim() {
        2 => vec![a.view().into_dimensionality().map_err(|e| input(format!("{name}: {e}")))?],
        3 => a
            .axis_iter(Axis(0))
            .map(|v| v.into_dimensionality().map_err(|e| input(format!("{name}: {e}"))))
            .collect::<PyResult<_>>()?,
        n => {
            return Err(input(format!(
                "{name} has {n} dimensions (shape {shown}): give one raw image (H, W) or a batch (N, H, W)"
            )));
        }
    };
    if a.is_empty() {
        return Err(input(format!("{name} is empty (shape {shown}): give at least one pixel")));
    }
    Ok((imgs, a.ndim() == 3))
}

fn percent(n: usize, total: usize) -> String {
    let p = 100.0 * n as f64 / total.max(1) as f64;
    if p >= 0.1 { format!("{p:.1} %") } else { format!("{p:.3} %") }
}

/// Refuses, or warns about, pixels above the pack's white level (DN, uint16): noisecal has no
/// noise measured there, and a 12-bit image given to a 10-bit pack looks like this.
pub fn levels_in_range(
    py: Python<'_>,
    imgs: &[ArrayView2<'_, u16>],
    name: &str,
    pack: &ModelPack,
    policy: OutOfRange,
    allowed: &str,
) -> PyResult<()> {
    if policy == OutOfRange::Allow {
        return Ok(());
    }
    let white = pack.layout.white;
    let (count, max, total) = py.detach(|| {
        imgs.iter().fold((0usize, 0u16, 0usize), |(c, m, t), img| {
            let (ci, mi) = img.iter().fold((0usize, 0u16), |(c, m), &v| (c + (v > white) as usize, m.max(v)));
            (c + ci, m.max(mi), t + img.len())
        })
    });
    if count == 0 {
        return Ok(());
    }
    let bits = 16 - max.leading_zeros();
    let hint = if bits > pack.layout.bit_depth() {
        format!(
            " ({bits}-bit values for the pack's {}-bit sensor: an image from another camera or mode?)",
            pack.layout.bit_depth()
        )
    } else {
        String::new()
    };
    let msg = format!(
        "{name} has {count} pixels ({}) above the pack's white level {white}, up to {max}{hint}: they are not codes of this sensor. Give DN of the pack's sensor (clip with np.minimum({name}, {white}) if that is what you mean), or pass out_of_range=\"warn\" or \"allow\" to {allowed}",
        percent(count, total)
    );
    match policy {
        OutOfRange::Raise => Err(input(msg)),
        _ => warn(py, &msg),
    }
}

/// NaN/inf refused; values outside the pack's codes once denormalised (DN = x·(white − black) +
/// black per CFA position, rounded) refused or warned about.
pub fn floats_in_range(
    py: Python<'_>,
    imgs: &[ArrayView2<'_, f32>],
    name: &str,
    pack: &ModelPack,
    origin: (usize, usize),
    policy: OutOfRange,
) -> PyResult<()> {
    let black = pack.layout.black;
    let white = pack.layout.white as f32;
    let scale: [f32; POSITIONS] = std::array::from_fn(|p| (white - black[p]).max(1.0));
    let (nan, inf, low, high, lo, hi, total) = py.detach(|| {
        let mut s = (0usize, 0usize, 0usize, 0usize, f32::INFINITY, f32::NEG_INFINITY, 0usize);
        for img in imgs {
            for ((y, x), &v) in img.indexed_iter() {
                s.6 += 1;
                if v.is_nan() {
                    s.0 += 1;
                    continue;
                }
                if v.is_infinite() {
                    s.1 += 1;
                    continue;
                }
                let p = position(y + origin.0, x + origin.1);
                let dn = (v * scale[p] + black[p]).round();
                s.2 += (dn < 0.0) as usize;
                s.3 += (dn > white) as usize;
                s.4 = s.4.min(v);
                s.5 = s.5.max(v);
            }
        }
        s
    });
    if nan + inf > 0 {
        return Err(input(format!(
            "{name} has {nan} NaN and {inf} infinite values ({} of the pixels): noise cannot be drawn on them; replace them first (np.nan_to_num({name}, nan=0.0, posinf=1.0, neginf=0.0), or your own fill)",
            percent(nan + inf, total)
        )));
    }
    if low + high == 0 || policy == OutOfRange::Allow {
        return Ok(());
    }
    let floor = black.iter().map(|b| -b / (white - b).max(1.0)).fold(f32::INFINITY, f32::min);
    let hint = if hi > 2.0 {
        format!(
            " Values up to {hi} look like DN, not normalised levels: for uint16 DN use synth; to normalise, (dn - black) / ({white} - black) per CFA position."
        )
    } else {
        String::new()
    };
    let msg = format!(
        "{name} has {} values ({}) outside the pack's codes: {low} below DN 0 (about {floor:.4}) and {high} above white (1.0), the values spanning {lo} to {hi}; synth_float takes levels normalised by the pack's black and white, (DN − black)/(white − black), which would be clamped to [0, white] DN here.{hint} Pass out_of_range=\"warn\" or \"allow\" to clamp them knowingly.",
        low + high,
        percent(low + high, total),
    );
    match policy {
        OutOfRange::Raise => Err(input(msg)),
        _ => warn(py, &msg),
    }
}

/// The offset `(dy, dx)` at which an image with CFA `image` reads as the pack's CFA `pack`: its
/// pixel (y, x) has the colour of the pack's (y + dy, x + dx).
pub fn cfa_offset(image: CfaPattern, pack: CfaPattern) -> Option<(usize, usize)> {
    let (ci, cp) = (image.colors(), pack.colors());
    [(0, 0), (0, 1), (1, 0), (1, 1)]
        .into_iter()
        .find(|&(dy, dx)| (0..2).all(|y| (0..2).all(|x| ci[position(y, x)] == cp[position(y + dy, x + dx)])))
}

/// A DNG's sensor against the pack's, as `noisecal synth` checks it (CFA, white level), plus the
/// camera (make and model differ: a warning, as the CLI accepts it).
pub fn dng_matches(
    py: Python<'_>,
    path: &std::path::Path,
    layout: &SensorLayout,
    make: &str,
    model: &str,
    pack: &ModelPack,
    policy: Mismatch,
) -> PyResult<()> {
    if policy == Mismatch::Ignore {
        return Ok(());
    }
    let mut problems = Vec::new();
    if layout.cfa != pack.layout.cfa {
        let fix = match cfa_offset(layout.cfa, pack.layout.cfa) {
            Some((dy, dx)) => format!(
                "crop it to the pack's phase (pixels[{dy}:, {dx}:]) or pass cfa_origin=({dy}, {dx}) to Pack.synth, with read_dng(..., mismatch=\"ignore\")"
            ),
            None => "use a pack of this camera".into(),
        };
        problems.push(format!("has CFA {} but the pack's sensor is {}: {fix}", layout.cfa, pack.layout.cfa));
    }
    if layout.white != pack.layout.white {
        problems.push(format!(
            "has white level {} ({}-bit) but the pack's sensor has {} ({}-bit): it comes from another camera or mode; use a pack calibrated on it",
            layout.white,
            layout.bit_depth(),
            pack.layout.white,
            pack.layout.bit_depth()
        ));
    }
    let path = path.display();
    if !problems.is_empty() {
        let msg = format!("{path} {} (or read_dng(..., mismatch=\"warn\") to go on)", problems.join("; and "));
        return match policy {
            Mismatch::Raise => Err(mismatch(msg)),
            _ => warn(py, &msg),
        };
    }
    let norm = |s: &str| s.trim().to_ascii_lowercase();
    let known = !pack.make.trim().is_empty() && !make.trim().is_empty();
    if known && (norm(make) != norm(&pack.make) || norm(model) != norm(&pack.model)) {
        warn(
            py,
            &format!(
                "{path} is from a {} {} but the pack is of a {} {}: the noise added is the pack's camera's (read_dng(..., mismatch=\"ignore\") to silence this)",
                make.trim(),
                model.trim(),
                pack.make.trim(),
                pack.model.trim()
            ),
        )?;
    }
    Ok(())
}

/// Black levels given by the caller: finite, at least 0 and below the pack's white level.
pub fn black_values(v: &[f64], white: u16) -> PyResult<()> {
    for (i, b) in v.iter().enumerate() {
        if !b.is_finite() || *b < 0.0 || *b >= white as f64 {
            return Err(input(format!(
                "black_level[{i}] = {b} is not a black level of this sensor (0 ≤ black < white {white}): give the image's black level in DN, as read_dng's meta[\"black\"]"
            )));
        }
    }
    Ok(())
}
