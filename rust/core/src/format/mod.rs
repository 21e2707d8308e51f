//! The binary files noisecal writes and reads: one framing ([`codec`]: magic, version, length,
//! CRC-32, bincode payload) for packs, checkpoints ([`checkpoint`]) and recordings; the recording's
//! records ([`recording`]) and their replay into a session ([`replay`]); the pack file and its
//! version dispatch ([`pack_file`]), where its bytes go ([`pack_sizes`]), the current version's
//! index and per-ISO sections ([`compact`]) and the reader that decodes only the ISOs asked for
//! ([`lazy_pack`]), and packs of older versions ([`pack_v1`], [`pack_v2`], [`pack_v3`],
//! [`pack_v5`], [`pack_v6`], [`pack_v7`], [`pack_v8`]; version 4 is the current structs
//! uncompressed), with the weight codes versions 7 to 9 share ([`weight_code`]) and the weight
//! coding of versions 8 and 9 ([`weight_stream`]).

pub mod checkpoint;
pub(crate) mod code_predictor;
pub(crate) mod codec;
pub mod compact;
pub mod lazy_pack;
pub mod pack_file;
pub mod pack_sizes;
pub(crate) mod pack_v1;
pub(crate) mod pack_v2;
pub(crate) mod pack_v3;
pub mod pack_v5;
pub mod pack_v6;
pub mod pack_v7;
pub mod pack_v8;
pub(crate) mod pack_version;
pub mod recording;
pub mod replay;
pub(crate) mod weight_code;
pub(crate) mod weight_stream;
