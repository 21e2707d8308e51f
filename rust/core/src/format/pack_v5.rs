//! Model packs of format version 5, read and migrated: the same bincode value as version 4,
//! with each bin's weights rounded to [`MANTISSA_BITS`] (9) significant bits and stored as
//! differences of their log-like codes ([`code`]: a weight below 2^[`MANTISSA_BITS`] is its own
//! code, a larger one its exponent and mantissa), zigzagged, the whole deflated
//! (`miniz_oxide`):
//!
//! `raw_len u64 | deflate(bincode(pack with delta-coded weight codes))`
//!
//! The differences wrap in 64 bits (a bijection on `u64`): any codes round-trip and no input can
//! overflow; a code naming a weight beyond 64 bits is refused. [`encode`] still writes the
//! format, for migration tests. The rounding is frozen here (not the model's current rule), so a
//! version 5 file reads the same whatever a later version keeps.

use crate::error::CodecError;
use crate::format::codec::{self, unzigzag, zigzag};
use crate::model::pack::ModelPack;
use crate::model::precision::quantize_to;

const WHAT: &str = "model pack";
/// Deflate level.
const LEVEL: u8 = 9;
/// Significant bits a version 5 weight keeps.
pub const MANTISSA_BITS: u32 = 9;
const HALF: u64 = 1 << (MANTISSA_BITS - 1);

/// `w` as a version 5 file rounds it.
pub fn quantize(w: u64) -> u64 {
    quantize_to(w, MANTISSA_BITS)
}

/// The log-like code of a weight with at most [`MANTISSA_BITS`] significant bits: itself below
/// 2^MANTISSA_BITS, else `e·2^(MANTISSA_BITS−1) + q` for `w = q·2^e`, `q` in
/// `[2^(MANTISSA_BITS−1), 2^MANTISSA_BITS)`, `e ≥ 1` (monotone and continuous with the small
/// weights).
fn code(w: u64) -> u64 {
    let bits = 64 - w.leading_zeros();
    if bits <= MANTISSA_BITS {
        return w;
    }
    let e = (bits - MANTISSA_BITS) as u64;
    e * HALF + (w >> e)
}

/// The weight of a code, or `None` when it names one beyond 64 bits.
fn weight(c: u64) -> Option<u64> {
    if c < 2 * HALF {
        return Some(c);
    }
    let e = c / HALF - 1;
    let q = c - e * HALF;
    (e + MANTISSA_BITS as u64 <= 64).then(|| q << e)
}

/// Each bin's weights become the wrapped differences of their codes (the first from 0).
fn delta_encode(pack: &mut ModelPack) {
    for c in pack.isos.iter_mut().flat_map(|m| m.positions.iter_mut()).flat_map(|p| p.bins.iter_mut()) {
        let mut prev = 0u64;
        for w in c.counts.iter_mut() {
            let k = code(quantize(*w));
            *w = zigzag(k.wrapping_sub(prev) as i64);
            prev = k;
        }
    }
}

/// Undoes [`delta_encode`] (up to the rounding), refusing a code beyond 64 bits.
fn delta_decode(pack: &mut ModelPack) -> Result<(), CodecError> {
    for (i, m) in pack.isos.iter_mut().enumerate() {
        for (pos, p) in m.positions.iter_mut().enumerate() {
            for (b, bin) in p.bins.iter_mut().enumerate() {
                let mut prev = 0u64;
                for w in bin.counts.iter_mut() {
                    prev = prev.wrapping_add(unzigzag(*w) as u64);
                    *w = weight(prev).ok_or_else(|| CodecError::Invalid {
                        what: WHAT,
                        detail: format!(
                            "model {i} position {pos} bin {b} has a weight beyond 64 bits: the file is damaged"
                        ),
                    })?;
                }
            }
        }
    }
    Ok(())
}

/// The version 5 payload of `pack` (its weights rounded as version 5 rounds them).
pub fn encode(pack: &ModelPack) -> Result<Vec<u8>, CodecError> {
    let mut coded = pack.clone();
    delta_encode(&mut coded);
    let raw = codec::encode_payload(WHAT, &coded)?;
    drop(coded);
    let mut out = Vec::with_capacity(8 + raw.len() / 4);
    out.extend_from_slice(&(raw.len() as u64).to_le_bytes());
    out.extend_from_slice(&miniz_oxide::deflate::compress_to_vec(&raw, LEVEL));
    Ok(out)
}

/// The pack in a version 5 payload (checked by the caller), refusing a damaged one with a clear
/// error.
pub fn decode(payload: &[u8]) -> Result<ModelPack, CodecError> {
    let Some((len, deflated)) = payload.split_first_chunk::<8>() else {
        return Err(CodecError::Truncated { what: WHAT, len: payload.len(), expected: 8 });
    };
    let raw = codec::inflate_exact(WHAT, u64::from_le_bytes(*len), deflated)?;
    let mut pack: ModelPack = codec::decode_payload(WHAT, &raw)?;
    delta_decode(&mut pack)?;
    Ok(pack)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn weights_round_to_their_significant_bits_and_codes_invert() {
        // Version 5 rounds with the pack model's rule at its own 9 bits.
        for (w, q) in crate::model::precision::tests::assert_rounds_to_bits(MANTISSA_BITS) {
            assert_eq!(quantize(w), q);
            assert_eq!(weight(code(q)), Some(q), "{w} → {q} → {}", code(q));
        }
        // Codes are monotone in the weight and step by one across the exact range's end.
        let mut last = None;
        for w in (0..1u64 << 14).map(quantize) {
            let c = code(w);
            if let Some(l) = last {
                assert!(c == l || c == l + 1, "{w}: {l} then {c}");
            }
            last = Some(c);
        }
        assert_eq!(weight(u64::MAX), None);
    }

    #[test]
    fn zigzag_and_wrapping_deltas_are_bijections() {
        for d in [0i64, 1, -1, 2, -2, i64::MAX, i64::MIN, 123_456_789, -987_654_321] {
            assert_eq!(unzigzag(zigzag(d)), d);
        }
        assert_eq!((zigzag(0), zigzag(-1), zigzag(1), zigzag(-2)), (0, 1, 2, 3));
        let ws = [0u64, u64::MAX, 1, 0, u64::MAX - 7, 1 << 63, 5, 5, 5];
        let mut prev = 0u64;
        let coded: Vec<u64> = ws
            .iter()
            .map(|&w| {
                let z = zigzag(w.wrapping_sub(prev) as i64);
                prev = w;
                z
            })
            .collect();
        let mut prev = 0u64;
        let back: Vec<u64> = coded
            .iter()
            .map(|&z| {
                prev = prev.wrapping_add(unzigzag(z) as u64);
                prev
            })
            .collect();
        assert_eq!(back, ws);
    }

    #[test]
    fn damaged_payloads_are_refused_with_words() {
        let e = decode(&[1, 2, 3]).unwrap_err().to_string();
        assert!(!e.is_empty());
        let mut huge = (codec::MAX_INFLATED + 1).to_le_bytes().to_vec();
        huge.extend_from_slice(&[0; 16]);
        let e = decode(&huge).unwrap_err().to_string();
        assert!(e.contains("limit"), "{e}");
        let mut junk = 100u64.to_le_bytes().to_vec();
        junk.extend_from_slice(&[0xFF; 40]);
        let e = decode(&junk).unwrap_err().to_string();
        assert!(e.contains("damaged"), "{e}");
        // A valid deflate stream of the wrong length.
        let mut short = 100u64.to_le_bytes().to_vec();
        short.extend_from_slice(&miniz_oxide::deflate::compress_to_vec(&[7u8; 10], 6));
        let e = decode(&short).unwrap_err().to_string();
        assert!(e.contains("not its stated 100"), "{e}");
        let mut long = 5u64.to_le_bytes().to_vec();
        long.extend_from_slice(&miniz_oxide::deflate::compress_to_vec(&[7u8; 10], 6));
        let e = decode(&long).unwrap_err().to_string();
        assert!(e.contains("damaged"), "{e}");
    }
}
