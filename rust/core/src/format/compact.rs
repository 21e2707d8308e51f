//! The compact payload of model packs from format version 6 on (method.md, "Pack file"). A
//! pack's bulk is its PMF weights; they are taken out of the bincode value and coded on their own:
//!
//! `raw_len u64 | fields_len u64 | deflate(bincode(pack without weights) | weights)`
//!
//! where `weights` holds, bin after bin (ISO, CFA position, bin order), the bin's cell count and
//! then each cell's slope (its [`code`] minus the previous cell's; the first from 0) as the
//! zigzagged difference from the previous bin's slope at the same noise value ([`Slopes`]:
//! neighbouring bins hold nearly the same PMF), all as LEB128 varints. The weights are the
//! model's stored form ([`crate::model::precision`]: at most [`MANTISSA_BITS`] significant bits
//! in a calibrated model, [`DERIVED_BITS`] in a derived one), whose codes are log-like (a weight
//! below 2^bits is its own code, a larger one its exponent and mantissa), so a smooth PMF's codes
//! change by small steps and its tails are runs of small numbers. Deflate is `miniz_oxide` at
//! level [`LEVEL`].
//!
//! Same pack in, same bytes out (deflate is deterministic for a given `miniz_oxide`, pinned by
//! Cargo.lock). The differences wrap in 64 bits (a bijection on `u64`): any codes round-trip and
//! no input can overflow; a code naming a weight beyond 64 bits, a cell count beyond what the
//! stream holds, or bytes left over are refused as a damaged file.

use crate::error::CodecError;
use crate::format::codec::{self, unzigzag, zigzag};
use crate::model::pack::ModelPack;
use crate::model::precision::{DERIVED_BITS, MANTISSA_BITS};

const WHAT: &str = "model pack";
/// Deflate level.
const LEVEL: u8 = 9;
/// The largest uncompressed payload a pack may claim (the bincode decoder's own limit).
const MAX_RAW: u64 = 1 << 30;
/// Significant bits the codes of one model's weights cover: a calibrated model's stored form
/// keeps at most [`MANTISSA_BITS`], a derived one's [`DERIVED_BITS`].
fn code_bits(calibrated: bool) -> u32 {
    if calibrated { MANTISSA_BITS } else { DERIVED_BITS }
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

fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// Reads a varint at `*at`, or `None` at the end of the bytes or past 64 bits.
fn get_varint(b: &[u8], at: &mut usize) -> Option<u64> {
    let mut v = 0u64;
    for shift in (0..64).step_by(7) {
        let byte = *b.get(*at)?;
        *at += 1;
        v |= ((byte & 0x7F) as u64).checked_shl(shift)?;
        if byte < 0x80 {
            return Some(v);
        }
    }
    None
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

/// The version 6 payload of `pack` (already in its stored form, [`ModelPack::compacted`]).
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
                    detail: format!("ISO {} holds a weight with more than {bits} significant bits: store the pack's compacted form", m.iso),
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
    let mut raw = codec::encode_payload(WHAT, &skeleton)?;
    drop(skeleton);
    let skeleton_len = raw.len() as u64;
    raw.extend_from_slice(&weights);
    let mut out = Vec::with_capacity(16 + raw.len() / 4);
    out.extend_from_slice(&(raw.len() as u64).to_le_bytes());
    out.extend_from_slice(&skeleton_len.to_le_bytes());
    out.extend_from_slice(&miniz_oxide::deflate::compress_to_vec(&raw, LEVEL));
    Ok(out)
}

/// The pack in a version 6 payload (checked by the caller), refusing a damaged one with a clear
/// error.
pub fn decode(payload: &[u8]) -> Result<ModelPack, CodecError> {
    let bad = |detail: String| CodecError::Invalid { what: WHAT, detail };
    let damaged = |what: &str| bad(format!("{what}: the file is damaged"));
    let Some((lens, deflated)) = payload.split_first_chunk::<16>() else {
        return Err(CodecError::Truncated { what: WHAT, len: payload.len(), expected: 16 });
    };
    let raw_len = u64::from_le_bytes(lens[..8].try_into().expect("8 bytes"));
    let skeleton_len = u64::from_le_bytes(lens[8..].try_into().expect("8 bytes"));
    if raw_len > MAX_RAW {
        return Err(bad(format!("the payload claims {raw_len} bytes uncompressed, beyond the {MAX_RAW}-byte limit")));
    }
    if skeleton_len > raw_len {
        return Err(damaged("the pack's fields claim more bytes than the payload holds"));
    }
    let raw = miniz_oxide::inflate::decompress_to_vec_with_limit(deflated, raw_len as usize).map_err(|_| {
        bad(format!("the compressed payload does not inflate to its stated {raw_len} bytes: the file is damaged"))
    })?;
    if raw.len() as u64 != raw_len {
        return Err(bad(format!(
            "the compressed payload inflates to {} bytes, not its stated {raw_len}: the file is damaged",
            raw.len()
        )));
    }
    let (fields, weights) = raw.split_at(skeleton_len as usize);
    let mut pack: ModelPack = codec::decode_payload(WHAT, fields)?;
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
