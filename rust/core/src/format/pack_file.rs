//! A model pack as a file: the magic and format version, the payload of the current version
//! ([`compact`]), and the dispatch that reads every older version and migrates
//! it to the current structs ([`pack_v1`] … [`pack_v8`]). [`super::lazy_pack`] reads the same
//! files, decoding only the ISOs it is asked for.
//!
//! Version history: 2 adds, per bin, where its PMF comes from, its measured moments and whether it
//! is clipped, and per position the estimator's report; 3 the structured components per ISO; 4
//! their fixed pattern (dark frames); 5 stores the same structs compactly (weights rounded to 9
//! significant bits, delta-coded, deflated); 6 keeps each bin's PMF only as far as its tails hold
//! measurable mass, its weights to 7 significant bits ([`pack_v6`]); 7 keeps each weight to the
//! bits its bin's samples justify, rounded by error diffusion ([`crate::model::precision`]), and
//! codes it ([`pack_v7`]); 8 keeps a wide bin's PMF as the masses of cells several DN wide where it
//! is smooth over them ([`crate::model::coarse_grid`]), re-expanded at load ([`pack_v8`]); 9 the
//! same models, each ISO in a section of its own behind an index ([`compact`]), so one ISO is
//! read without decoding the others. Version 4 is read as it is ([`ModelPack::to_bytes_v4`] still writes it, for diffing packs
//! byte by byte).

use crate::error::CodecError;
use crate::format::{codec, compact, pack_v1, pack_v2, pack_v3, pack_v5, pack_v6, pack_v7, pack_v8};
use crate::model::pack::ModelPack;

pub use crate::format::pack_version::{
    PACK_MAGIC, PACK_MAGIC_TEXT, PACK_VERSION, PACK_VERSION_MIN, PACK_VERSION_UNCOMPRESSED, PACK_VERSION_V5,
    PACK_VERSION_V6, PACK_VERSION_V7, PACK_VERSION_V8,
};

const WHAT: &str = "model pack";

impl ModelPack {
    /// The pack as a file of the current version; it loads back as [`ModelPack::compacted`].
    pub fn to_bytes(&self) -> Result<Vec<u8>, CodecError> {
        compact::encode(&self.compacted())
    }

    /// The pack as a version 8 file (the current stored form in one deflate stream), for
    /// noisecal builds before version 9 and for migration tests.
    pub fn to_bytes_v8(&self) -> Result<Vec<u8>, CodecError> {
        Ok(codec::encode_sealed(PACK_MAGIC, PACK_VERSION_V8, &pack_v8::encode(&self.compacted())?))
    }

    /// The pack as a version 4 file: the same value uncompressed and unrounded (for diffing packs
    /// byte by byte). It loads to the same pack.
    pub fn to_bytes_v4(&self) -> Result<Vec<u8>, CodecError> {
        codec::encode(WHAT, PACK_MAGIC, PACK_VERSION_UNCOMPRESSED, self)
    }

    /// The pack as a version 5 file (its weights rounded to 9 significant bits, tails as they
    /// are), for noisecal builds before version 6 and for migration tests.
    pub fn to_bytes_v5(&self) -> Result<Vec<u8>, CodecError> {
        Ok(codec::encode_sealed(PACK_MAGIC, PACK_VERSION_V5, &pack_v5::encode(self)?))
    }

    /// The pack as a version 6 file (in version 6's stored form, [`pack_v6::stored_form`]), for
    /// noisecal builds before version 7 and for migration tests.
    pub fn to_bytes_v6(&self) -> Result<Vec<u8>, CodecError> {
        Ok(codec::encode_sealed(PACK_MAGIC, PACK_VERSION_V6, &pack_v6::encode(&pack_v6::stored_form(self))?))
    }

    /// The pack as a version 7 file (in version 7's stored form, [`pack_v7::stored_form`]), for
    /// noisecal builds before version 8 and for migration tests.
    pub fn to_bytes_v7(&self) -> Result<Vec<u8>, CodecError> {
        Ok(codec::encode_sealed(PACK_MAGIC, PACK_VERSION_V7, &pack_v7::encode(&pack_v7::stored_form(self))?))
    }

    /// Reads a pack of this version or an older one (migrated).
    pub fn from_bytes(bytes: &[u8]) -> Result<Self, CodecError> {
        let version = codec::sealed_version(WHAT, PACK_MAGIC, PACK_MAGIC_TEXT, PACK_VERSION_MIN..=PACK_VERSION, bytes)?;
        if version == PACK_VERSION {
            let (_, head, rest) =
                codec::decode_sealed_head(WHAT, PACK_MAGIC, PACK_MAGIC_TEXT, PACK_VERSION..=PACK_VERSION, bytes)?;
            let p = compact::decode(head, rest)?;
            p.check()?;
            return Ok(p);
        }
        let (version, payload) =
            codec::decode_framing(WHAT, PACK_MAGIC, PACK_MAGIC_TEXT, PACK_VERSION_MIN..=PACK_VERSION, bytes)?;
        let p: ModelPack = match version {
            1 => codec::decode_payload::<pack_v1::ModelPackV1>(WHAT, payload)?.migrate(),
            2 => codec::decode_payload::<pack_v2::ModelPackV2>(WHAT, payload)?.migrate(),
            3 => codec::decode_payload::<pack_v3::ModelPackV3>(WHAT, payload)?.migrate(),
            PACK_VERSION_UNCOMPRESSED => codec::decode_payload(WHAT, payload)?,
            PACK_VERSION_V5 => pack_v5::decode(payload)?,
            PACK_VERSION_V6 => pack_v6::decode(payload)?,
            PACK_VERSION_V7 => pack_v7::decode(payload)?,
            _ => pack_v8::decode(payload)?,
        };
        p.check()?;
        Ok(p)
    }
}
