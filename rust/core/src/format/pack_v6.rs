//! Model packs of format version 6, read and migrated (and still written by [`encode`], for
//! migration tests): the pack's fields as bincode with every bin's weights taken out, then the
//! weights as a stream, the whole deflated (`miniz_oxide`):
//!
//! `raw_len u64 | fields_len u64 | deflate(bincode(pack without weights) | weights)`
//!
//! The weights: per bin its cell count, then the differences of its weights' log-like codes
//! ([`code`]: a weight below 2^bits is its own code, a larger one its exponent and mantissa; 7
//! bits in a calibrated model, 9 in a derived one), each less the previous bin's slope at the same
//! noise value ([`Slopes`]), as LEB128 varints. The differences wrap in 64 bits (a bijection on
//! `u64`): any codes round-trip and no input can overflow; a code naming a weight beyond 64 bits, a
//! cell count beyond what the stream holds, or bytes left over are refused as a damaged file. The
//! coding is frozen here (not the model's current rule), so a version 6 file reads the same
//! whatever a later version keeps.

use crate::error::CodecError;
use crate::format::codec::{self, get_varint, put_varint, unzigzag, zigzag};
use crate::model::pack::ModelPack;
use crate::model::precision::{TAIL_BITS, measurable_span, quantize_to};

const WHAT: &str = "model pack";
/// Significant bits the codes of one model's weights cover: 7 in a calibrated model, 9 in a
/// derived one.
fn code_bits(calibrated: bool) -> u32 {
    if calibrated { 7 } else { 9 }
}

/// The log-like code of a weight with at most `m` significant bits: itself below 2^m, else
/// `e·2^(m−1) + q` for `w = q·2^e`, `q` in `[2^(m−1), 2^m)`, `e ≥ 1` (monotone and continuous
/// with the small weights); `None` for a weight with more significant bits.
fn code(w: u64, m: u32) -> Option<u64> {
    let bits = 64 - w.leading_zeros();
    if bits <= m {
        return Some(w);
    }
    let e = (bits - m) as u64;
    (w & ((1 << e) - 1) == 0).then(|| e * (1 << (m - 1)) + (w >> e))
}

/// The weight of a code of `m` bits, or `None` when it names one beyond 64 bits.
fn weight(c: u64, m: u32) -> Option<u64> {
    let half = 1u64 << (m - 1);
    if c < 2 * half {
        return Some(c);
    }
    let e = c / half - 1;
    let q = c - e * half;
    (e + m as u64 <= 64).then(|| q << e)
}

/// The slopes of the previous bin's codes (`code[n] − code[n−1]` at noise value `n`), the
/// prediction of the next bin's: neighbouring bins hold nearly the same PMF.
#[derive(Default)]
struct Slopes {
    first: i32,
    slope: Vec<u64>,
}

impl Slopes {
    fn of(first: i32, codes: &[u64]) -> Self {
        let slope = codes.iter().scan(0u64, |prev, &k| Some(k.wrapping_sub(std::mem::replace(prev, k)))).collect();
        Self { first, slope }
    }

    /// The predicted slope at noise value `n`: the previous bin's there, 0 where it has no cell
    /// (or at its first, whose slope is from 0).
    fn at(&self, n: i32) -> u64 {
        let i = (n as i64) - (self.first as i64);
        if i <= 0 { 0 } else { self.slope.get(i as usize).copied().unwrap_or(0) }
    }
}

/// `pack` as a version 6 file stores it: a calibrated model's weights rounded half up to 7
/// significant bits and each bin's tails cut to [`measurable_span`] at [`TAIL_BITS`]; a derived
/// model's to 9 bits.
pub fn stored_form(pack: &ModelPack) -> ModelPack {
    let mut p = pack.clone();
    for m in p.isos.iter_mut() {
        let bits = code_bits(m.is_calibrated());
        let calibrated = m.is_calibrated();
        for b in m.positions.iter_mut().flat_map(|q| q.bins.iter_mut()) {
            b.counts.iter_mut().for_each(|w| *w = quantize_to(*w, bits));
            if let Some((lo, hi)) = measurable_span(&b.counts, TAIL_BITS).filter(|_| calibrated) {
                b.counts.truncate(hi + 1);
                b.counts.drain(..lo);
                b.first += lo as i32;
            }
        }
    }
    p
}

/// The version 6 payload of `pack`, whose weights must have at most 7 significant bits (9 in a
/// derived model), as [`stored_form`] leaves them.
pub fn encode(pack: &ModelPack) -> Result<Vec<u8>, CodecError> {
    let mut skeleton = pack.clone();
    let mut weights = Vec::new();
    for m in skeleton.isos.iter_mut() {
        let bits = code_bits(m.is_calibrated());
        for p in m.positions.iter_mut() {
            let mut above = Slopes::default();
            for b in p.bins.iter_mut() {
                put_varint(&mut weights, b.counts.len() as u64);
                let codes: Vec<u64> = b
                .counts
                .iter()
                .map(|&w| code(w, bits))
                .collect::<Option<_>>()
                .ok_or_else(|| CodecError::Encode {
                    what: WHAT,
                    detail: format!("ISO {} holds a weight with more than {bits} significant bits: version 6 keeps at most that", m.iso),
                })?;
                let mut prev = 0u64;
                for (i, &k) in codes.iter().enumerate() {
                    let d = k.wrapping_sub(prev);
                    put_varint(&mut weights, zigzag(d.wrapping_sub(above.at(b.first + i as i32)) as i64));
                    prev = k;
                }
                above = Slopes::of(b.first, &codes);
                b.counts = Vec::new();
            }
        }
    }
    codec::deflate_fields_and_weights(WHAT, &skeleton, &weights)
}

/// The pack in a version 6 payload (checked by the caller), refusing a damaged one with a clear
/// error.
pub fn decode(payload: &[u8]) -> Result<ModelPack, CodecError> {
    let damaged = |what: &str| CodecError::Invalid { what: WHAT, detail: format!("{what}: the file is damaged") };
    let (mut pack, weights): (ModelPack, Vec<u8>) = codec::inflate_fields_and_weights(WHAT, payload)?;
    let weights = &weights[..];
    let mut at = 0usize;
    for (i, m) in pack.isos.iter_mut().enumerate() {
        let bits = code_bits(m.is_calibrated());
        for (pos, p) in m.positions.iter_mut().enumerate() {
            let mut above = Slopes::default();
            for (b, bin) in p.bins.iter_mut().enumerate() {
                let here = || format!("model {i} position {pos} bin {b}");
                let n =
                    get_varint(weights, &mut at).ok_or_else(|| damaged(&format!("{} has no cell count", here())))?;
                // Every cell takes at least a byte: a count beyond the bytes left is damage (and
                // never allocated).
                if n > (weights.len() - at) as u64 {
                    return Err(damaged(&format!("{} claims {n} cells, more than the file holds", here())));
                }
                let mut prev = 0u64;
                let mut codes = Vec::with_capacity(n as usize);
                for c in 0..n as i32 {
                    let z = get_varint(weights, &mut at)
                        .ok_or_else(|| damaged(&format!("{} ends inside a weight", here())))?;
                    prev = prev.wrapping_add(above.at(bin.first.wrapping_add(c))).wrapping_add(unzigzag(z) as u64);
                    codes.push(prev);
                }
                bin.counts = codes
                    .iter()
                    .map(|&k| {
                        weight(k, bits).ok_or_else(|| damaged(&format!("{} has a weight beyond 64 bits", here())))
                    })
                    .collect::<Result<_, _>>()?;
                above = Slopes::of(bin.first, &codes);
            }
        }
    }
    if at != weights.len() {
        return Err(damaged(&format!("{} bytes follow the last weight", weights.len() - at)));
    }
    Ok(pack)
}
