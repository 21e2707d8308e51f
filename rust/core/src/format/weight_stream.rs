//! The PMF weights of one ISO model as pack versions 8 and 9 code them (version 8 one stream for
//! every ISO, [`super::pack_v8`]; version 9 one per ISO section, [`super::compact`]).
//!
//! Per bin its cell count, then one varint naming its [`Predictor`] and its grid step
//! (`predictor + 4·log2 k`: a bin kept in cells of `k` DN, [`crate::model::coarse_grid`], stores
//! the masses of its cells and is re-expanded at load; `k = 1` stores a weight per DN), then each
//! cell's code less its guess (the previous code plus the slope the previous bin's weights,
//! summed over this bin's cells, have at the same noise value, [`Slopes`]: neighbouring bins hold
//! nearly the same PMF; or the previous code; or the previous code plus the slope before it), all
//! as zigzagged LEB128 varints. The weights are the model's stored form
//! ([`crate::model::precision`]): each weight (or cell mass) holds the significant bits its bin's
//! [`Precision`](crate::model::precision::Precision) gives its bit length, and its code is its
//! index among the values that precision holds ([`WeightCode`]), so a code's step is one stored
//! step whatever the bin's precision. The precision is not stored: it follows from fields the
//! file holds (the model calibrated or not, the position estimated or plain, the bin's samples).
//! The guesses restart at each CFA position, so an ISO's weights stand alone.
//!
//! Both versions read this coding: a change to it is a new pack version, with this file frozen
//! as that version's reader (as [`super::pack_v7`] is). The differences wrap in 64 bits (a
//! bijection on `u64`): any codes round-trip and no input can overflow; a code naming no weight,
//! a cell count beyond what the stream holds, an unknown predictor or step, or more cells than
//! [`MAX_CELLS`] once expanded are refused as a damaged file.

use crate::error::CodecError;
use crate::format::code_predictor::{Predictor, read_codes, write_codes};
use crate::format::codec::{get_varint, put_varint};
use crate::format::weight_code::{WeightCode, precision_for, precision_of};
use crate::model::coarse_grid::{GRID_STEPS, cell_masses, expand, stored_step};
use crate::model::pack::IsoModel;

const WHAT: &str = "model pack";

/// The most cells (once re-expanded) a file's bins may hold together: 2²⁸ (2 GB of weights),
/// beyond any pack noisecal writes (the 14-bit phone's 3 ISOs hold 1.5·10⁷); a damaged count or
/// step cannot ask for more.
pub const MAX_CELLS: u64 = 1 << 28;

/// The steps a bin may be kept at, by their code (`log2 k`).
fn step_of(code: u64) -> Option<usize> {
    std::iter::once(1).chain(GRID_STEPS).find(|k| k.trailing_zeros() as u64 == code)
}

/// The slopes of the previous bin's weights summed over this bin's cells (`first`, `k` DN each),
/// coded at this bin's precision (`code[j] − code[j−1]`, the cell before the first included): the
/// prediction of this bin's code differences.
#[derive(Default)]
struct Slopes {
    slope: Vec<u64>,
}

impl Slopes {
    fn of(prev: Option<(i32, &[u64])>, first: i32, k: usize, cells: usize, code: &WeightCode) -> Self {
        let Some((pf, pw)) = prev else { return Self::default() };
        let mass = |j: i64| -> u64 {
            let lo = first as i64 + j * k as i64 - pf as i64;
            (lo..lo + k as i64)
                .filter_map(|i| usize::try_from(i).ok().and_then(|i| pw.get(i)))
                .fold(0u64, |a, &w| a.saturating_add(w))
        };
        let mut prev_code = code.code_near(mass(-1));
        let slope = (0..cells as i64)
            .map(|j| {
                let c = code.code_near(mass(j));
                c.wrapping_sub(std::mem::replace(&mut prev_code, c))
            })
            .collect();
        Self { slope }
    }

    /// The predicted slope at cell `j`.
    fn at(&self, j: usize) -> u64 {
        self.slope.get(j).copied().unwrap_or(0)
    }
}

/// Appends the PMF weights of `m` (already in its stored form, [`crate::model::pack::ModelPack::compacted`]) to `out`.
pub(crate) fn encode_iso(m: &IsoModel, out: &mut Vec<u8>) -> Result<(), CodecError> {
    for p in &m.positions {
        let mut prev: Option<(i32, &[u64])> = None;
        for b in &p.bins {
            let precision = precision_of(m, p, b.samples);
            let code = WeightCode::new(precision);
            let k = stored_step(&b.counts, precision);
            let values = if k > 1 { cell_masses(&b.counts, k) } else { b.counts.clone() };
            let above = Slopes::of(prev, b.first, k, values.len(), &code);
            put_varint(out, values.len() as u64);
            let codes = code.codes(&values, m.iso)?;
            let (predictor, bytes) = write_codes(&codes, |i| above.at(i));
            put_varint(out, predictor as u64 + 4 * k.trailing_zeros() as u64);
            out.extend_from_slice(&bytes);
            prev = Some((b.first, &b.counts));
        }
    }
    Ok(())
}

/// Reads the PMF weights of `m` (its fields decoded, its bins' weights empty) from `weights` at
/// `*at` into its bins. `label` names the model in messages (`model 2`, `ISO 800`); `cells`
/// counts the cells of the file so far (once expanded), refused beyond [`MAX_CELLS`].
pub(crate) fn decode_iso(
    m: &mut IsoModel,
    label: &str,
    weights: &[u8],
    at: &mut usize,
    cells: &mut u64,
) -> Result<(), CodecError> {
    let damaged = |what: &str| CodecError::Invalid { what: WHAT, detail: format!("{what}: the file is damaged") };
    let calibrated = m.is_calibrated();
    for (pos, p) in m.positions.iter_mut().enumerate() {
        let estimated = p.is_estimated();
        let mut prev: Option<(i32, Vec<u64>)> = None;
        for (b, bin) in p.bins.iter_mut().enumerate() {
            let here = || format!("{label} position {pos} bin {b}");
            let precision = precision_for(calibrated, estimated, bin.samples);
            let code = WeightCode::new(precision);
            let n = get_varint(weights, at).ok_or_else(|| damaged(&format!("{} has no cell count", here())))?;
            // Every cell takes at least a byte: a count beyond the bytes left is damage (and
            // never allocated).
            if n > (weights.len() - *at) as u64 {
                return Err(damaged(&format!("{} claims {n} cells, more than the file holds", here())));
            }
            let mode = get_varint(weights, at).ok_or_else(|| damaged(&format!("{} has no predictor", here())))?;
            let predictor =
                Predictor::from_id(mode % 4).ok_or_else(|| damaged(&format!("{} names no known predictor", here())))?;
            let k = step_of(mode / 4).ok_or_else(|| damaged(&format!("{} names no known grid step", here())))?;
            *cells = cells.saturating_add(n.saturating_mul(k as u64));
            if *cells > MAX_CELLS {
                return Err(damaged(&format!("{} takes the pack beyond {MAX_CELLS} cells", here())));
            }
            let above = Slopes::of(prev.as_ref().map(|(f, w)| (*f, &w[..])), bin.first, k, n as usize, &code);
            let codes = read_codes(weights, at, n as usize, predictor, |i| above.at(i))
                .ok_or_else(|| damaged(&format!("{} ends inside a weight", here())))?;
            let values = codes
                .iter()
                .map(|&k| code.weight(k).ok_or_else(|| damaged(&format!("{} has a code naming no weight", here()))))
                .collect::<Result<Vec<u64>, _>>()?;
            bin.counts = if k > 1 { expand(&values, k) } else { values };
            bin.grid_step = if k > 1 { k as u16 } else { 0 };
            prev = Some((bin.first, bin.counts.clone()));
        }
    }
    Ok(())
}

/// Refuses bytes left after the last weight of a stream.
pub(crate) fn check_used(weights: &[u8], at: usize) -> Result<(), CodecError> {
    if at != weights.len() {
        return Err(CodecError::Invalid {
            what: WHAT,
            detail: format!("{} bytes follow the last weight: the file is damaged", weights.len() - at),
        });
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The step codes name exactly 1 DN and the grid's steps (`log2 k`); any other is refused.
    #[test]
    fn step_codes_name_the_grid_steps_only() {
        let named: Vec<usize> = (0..64).filter_map(step_of).collect();
        let mut want = vec![1];
        want.extend(GRID_STEPS);
        assert_eq!(named, want);
        for (code, k) in want.iter().enumerate() {
            assert_eq!(step_of(code as u64), Some(*k));
        }
        assert_eq!(step_of(u64::MAX / 4), None);
    }
}
