//! Model packs of format version 8, read and migrated (and still written by [`encode`], for
//! migration tests and for noisecal builds before version 9). The payload: the pack's fields as
//! bincode with every bin's weights taken out, then every ISO's weights
//! ([`super::weight_stream`]) one after the other, the whole deflated as one stream, so no ISO
//! can be read without inflating all of them (version 9 gives each ISO its own section,
//! [`super::compact`]):
//!
//! `raw_len u64 | fields_len u64 | deflate(bincode(pack without weights) | weights)`
//!
//! The stored form is the current one ([`ModelPack::compacted`]); the envelope (lengths,
//! deflate) is version 6's, [`codec::deflate_fields_and_weights`]. Same pack in, same bytes out
//! (deflate is deterministic for a given `miniz_oxide`, pinned by Cargo.lock); bytes left after
//! the last weight are refused as a damaged file.

use crate::error::CodecError;
use crate::format::codec;
use crate::format::weight_stream::{check_used, decode_iso, encode_iso};
use crate::model::pack::ModelPack;

const WHAT: &str = "model pack";

/// The version 8 payload of `pack` (already in its stored form, [`ModelPack::compacted`]).
pub fn encode(pack: &ModelPack) -> Result<Vec<u8>, CodecError> {
    let mut weights = Vec::new();
    for m in &pack.isos {
        encode_iso(m, &mut weights)?;
    }
    let mut fields = pack.clone();
    fields.isos.iter_mut().flat_map(|m| m.positions.iter_mut()).flat_map(|p| p.bins.iter_mut()).for_each(|b| {
        b.counts = Vec::new();
    });
    codec::deflate_fields_and_weights(WHAT, &fields, &weights)
}

/// The pack in a version 8 payload (checked by the caller), refusing a damaged one with a clear
/// error.
pub fn decode(payload: &[u8]) -> Result<ModelPack, CodecError> {
    let (mut pack, weights): (ModelPack, Vec<u8>) = codec::inflate_fields_and_weights(WHAT, payload)?;
    let mut at = 0usize;
    let mut cells = 0u64;
    for (i, m) in pack.isos.iter_mut().enumerate() {
        decode_iso(m, &format!("model {i}"), &weights, &mut at, &mut cells)?;
    }
    check_used(&weights, at)?;
    Ok(pack)
}
