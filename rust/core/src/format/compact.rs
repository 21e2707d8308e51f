//! The compact payload of model packs from format version 5 on (issue 26 item 3): the same
//! bincode value as version 4, with each bin's weights stored as differences from the cell
//! before (zigzag, so a smooth PMF's long tails of small, slowly changing weights become runs of
//! small numbers), the whole deflated (`miniz_oxide`, level [`LEVEL`]):
//!
//! `raw_len u64 | deflate(bincode(pack with delta-coded weights))`
//!
//! Lossless: a version 5 pack loads to exactly the [`ModelPack`] that was written, so its
//! sampler tables and every synthesized image are byte for byte those of the same pack written
//! as version 4. The differences wrap in 64 bits (a bijection on `u64`): any weights round-trip
//! and no input can overflow. Same pack in, same bytes out (deflate is deterministic for a
//! given `miniz_oxide`, pinned by Cargo.lock).

use crate::error::CodecError;
use crate::format::codec;
use crate::model::pack::ModelPack;

const WHAT: &str = "model pack";
/// Deflate level: 9 is 2–4 % smaller than 6 on calibrated packs at a few hundred ms more for
/// a 20 MB pack (encoding only; inflating costs the same).
const LEVEL: u8 = 9;
/// The largest uncompressed payload a pack may claim (the bincode decoder's own limit).
const MAX_RAW: u64 = 1 << 30;

fn zigzag(d: i64) -> u64 {
    ((d << 1) ^ (d >> 63)) as u64
}

fn unzigzag(z: u64) -> i64 {
    ((z >> 1) as i64) ^ -((z & 1) as i64)
}

/// Each bin's weights become their wrapped differences (the first from 0).
fn delta_encode(pack: &mut ModelPack) {
    for c in pack.isos.iter_mut().flat_map(|m| m.positions.iter_mut()).flat_map(|p| p.bins.iter_mut()) {
        let mut prev = 0u64;
        for w in c.counts.iter_mut() {
            let d = w.wrapping_sub(prev) as i64;
            prev = *w;
            *w = zigzag(d);
        }
    }
}

/// Undoes [`delta_encode`].
fn delta_decode(pack: &mut ModelPack) {
    for c in pack.isos.iter_mut().flat_map(|m| m.positions.iter_mut()).flat_map(|p| p.bins.iter_mut()) {
        let mut prev = 0u64;
        for w in c.counts.iter_mut() {
            prev = prev.wrapping_add(unzigzag(*w) as u64);
            *w = prev;
        }
    }
}

/// The version 5 payload of `pack`.
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
    let bad = |detail: String| CodecError::Invalid { what: WHAT, detail };
    let Some((len, deflated)) = payload.split_first_chunk::<8>() else {
        return Err(CodecError::Truncated { what: WHAT, len: payload.len(), expected: 8 });
    };
    let raw_len = u64::from_le_bytes(*len);
    if raw_len > MAX_RAW {
        return Err(bad(format!("the payload claims {raw_len} bytes uncompressed, beyond the {MAX_RAW}-byte limit")));
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
    let mut pack: ModelPack = codec::decode_payload(WHAT, &raw)?;
    delta_decode(&mut pack);
    Ok(pack)
}

#[cfg(test)]
mod tests {
    use super::*;

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
        let mut huge = (MAX_RAW + 1).to_le_bytes().to_vec();
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
