//! Model packs of format version 7, read and migrated (and still written by [`encode`], for
//! migration tests). The payload: the pack's fields as bincode with every bin's weights
//! taken out, then the weights as a stream, the whole deflated:
//!
//! `raw_len u64 | fields_len u64 | deflate(bincode(pack without weights) | weights)`
//!
//! The weights: per bin its cell count, the [`Predictor`] its codes are guessed with, then each
//! code less its guess (the previous code plus the slope the previous bin's weights have at the
//! same noise value, [`Slopes`]: neighbouring bins hold nearly the same PMF; or the previous code;
//! or the previous code plus the slope before it), all as zigzagged LEB128 varints. The weights are the model's stored form
//! ([`crate::model::precision`]): each holds the significant bits its bin's [`Precision`](crate::model::precision::Precision) gives
//! its bit length, and its code is its index among the values that precision holds
//! ([`WeightCode`]), so a code's step is one stored step whatever the bin's precision: a smooth
//! PMF's codes change by small steps and a tail kept to a bit or two is a run of near-equal
//! numbers. The precision is not stored: it follows from fields the file holds (the model
//! calibrated or not, the position estimated or plain, the bin's samples). The envelope (lengths,
//! deflate) is version 6's, [`codec::deflate_fields_and_weights`].
//!
//! The coding is frozen here; its stored form ([`stored_form`]: every bin kept per DN) is the
//! rounding and tail cut of [`crate::model::precision`], which version 8 keeps for the bins it
//! does not keep on a coarse grid.
//!
//! Same pack in, same bytes out (deflate is deterministic for a given `miniz_oxide`, pinned by
//! Cargo.lock). The differences wrap in 64 bits (a bijection on `u64`): any codes round-trip and
//! no input can overflow; a code naming no weight, a cell count beyond what the stream holds, or
//! bytes left over are refused as a damaged file.

use crate::error::CodecError;
use crate::format::code_predictor::{Predictor, read_codes, write_codes};
use crate::format::codec::{self, get_varint, put_varint};
use crate::format::weight_code::{WeightCode, precision_for, precision_of};
use crate::model::pack::ModelPack;
use crate::model::precision::{bin_precision, quantize_derived, store_bin};

const WHAT: &str = "model pack";

/// The slopes of the previous bin's weights, coded at this bin's precision
/// (`code[n] − code[n−1]` at noise value `n`): the prediction of this bin's code differences.
#[derive(Default)]
struct Slopes {
    first: i32,
    slope: Vec<u64>,
}

impl Slopes {
    fn of(first: i32, weights: &[u64], code: &WeightCode) -> Self {
        let slope = weights
            .iter()
            .scan(0u64, |prev, &w| {
                let k = code.code_near(w);
                Some(k.wrapping_sub(std::mem::replace(prev, k)))
            })
            .collect();
        Self { first, slope }
    }

    /// The predicted slope at noise value `n`: the previous bin's there, 0 where it has no cell
    /// (or at its first, whose slope is from 0).
    fn at(&self, n: i32) -> u64 {
        let i = (n as i64) - (self.first as i64);
        if i <= 0 { 0 } else { self.slope.get(i as usize).copied().unwrap_or(0) }
    }
}

/// `pack` as a version 7 file stores it: each calibrated bin rounded and cut by
/// [`store_bin`] at its [`bin_precision`], each derived weight by [`quantize_derived`].
pub fn stored_form(pack: &ModelPack) -> ModelPack {
    let mut p = pack.clone();
    for m in p.isos.iter_mut() {
        let calibrated = m.is_calibrated();
        for q in m.positions.iter_mut() {
            let estimated = q.is_estimated();
            for b in q.bins.iter_mut() {
                if calibrated {
                    store_bin(&mut b.first, &mut b.counts, bin_precision(estimated, b.samples));
                } else {
                    b.counts.iter_mut().for_each(|w| *w = quantize_derived(*w));
                }
            }
        }
    }
    p
}

/// The PMF weights of `pack` (already in version 7's stored form) as the payload codes them.
fn weight_stream(pack: &ModelPack) -> Result<Vec<u8>, CodecError> {
    let mut out = Vec::new();
    for m in &pack.isos {
        for p in &m.positions {
            let mut prev: Option<(i32, &[u64])> = None;
            for b in &p.bins {
                let code = WeightCode::new(precision_of(m, p, b.samples));
                let above = prev.map_or_else(Slopes::default, |(f, w)| Slopes::of(f, w, &code));
                put_varint(&mut out, b.counts.len() as u64);
                let codes = code.codes(&b.counts, m.iso)?;
                let (predictor, bytes) = write_codes(&codes, |i| above.at(b.first.wrapping_add(i as i32)));
                put_varint(&mut out, predictor as u64);
                out.extend_from_slice(&bytes);
                prev = Some((b.first, &b.counts));
            }
        }
    }
    Ok(out)
}

/// The version 7 payload of `pack` (already in version 7's stored form, [`stored_form`]).
pub fn encode(pack: &ModelPack) -> Result<Vec<u8>, CodecError> {
    let weights = weight_stream(pack)?;
    let mut fields = pack.clone();
    fields.isos.iter_mut().flat_map(|m| m.positions.iter_mut()).flat_map(|p| p.bins.iter_mut()).for_each(|b| {
        b.counts = Vec::new();
    });
    codec::deflate_fields_and_weights(WHAT, &fields, &weights)
}

/// The pack in a version 7 payload (checked by the caller), refusing a damaged one with a clear
/// error.
pub fn decode(payload: &[u8]) -> Result<ModelPack, CodecError> {
    let damaged = |what: &str| CodecError::Invalid { what: WHAT, detail: format!("{what}: the file is damaged") };
    let (mut pack, weights): (ModelPack, Vec<u8>) = codec::inflate_fields_and_weights(WHAT, payload)?;
    let weights = &weights[..];
    let mut at = 0usize;
    for (i, m) in pack.isos.iter_mut().enumerate() {
        let calibrated = m.is_calibrated();
        for (pos, p) in m.positions.iter_mut().enumerate() {
            let estimated = p.is_estimated();
            let mut prev: Option<(i32, Vec<u64>)> = None;
            for (b, bin) in p.bins.iter_mut().enumerate() {
                let here = || format!("model {i} position {pos} bin {b}");
                let precision = precision_for(calibrated, estimated, bin.samples);
                let code = WeightCode::new(precision);
                let above = prev.as_ref().map_or_else(Slopes::default, |(f, w)| Slopes::of(*f, w, &code));
                let n =
                    get_varint(weights, &mut at).ok_or_else(|| damaged(&format!("{} has no cell count", here())))?;
                // Every cell takes at least a byte: a count beyond the bytes left is damage (and
                // never allocated).
                if n > (weights.len() - at) as u64 {
                    return Err(damaged(&format!("{} claims {n} cells, more than the file holds", here())));
                }
                let predictor = get_varint(weights, &mut at)
                    .and_then(Predictor::from_id)
                    .ok_or_else(|| damaged(&format!("{} names no known predictor", here())))?;
                let codes =
                    read_codes(weights, &mut at, n as usize, predictor, |i| above.at(bin.first.wrapping_add(i as i32)))
                        .ok_or_else(|| damaged(&format!("{} ends inside a weight", here())))?;
                let counts = codes
                    .iter()
                    .map(|&k| code.weight(k).ok_or_else(|| damaged(&format!("{} has a code naming no weight", here()))))
                    .collect::<Result<Vec<u64>, _>>()?;
                bin.counts = counts;
                prev = Some((bin.first, bin.counts.clone()));
            }
        }
    }
    if at != weights.len() {
        return Err(damaged(&format!("{} bytes follow the last weight", weights.len() - at)));
    }
    Ok(pack)
}
