//! A pack file's magic and its format versions: the current one, and the oldest ones still read.

pub const PACK_MAGIC: &[u8; 8] = b"NCALPACK";
pub const PACK_MAGIC_TEXT: &str = "NCALPACK";
/// Bump on any change to the serialised structs or their coding.
pub const PACK_VERSION: u16 = 9;
/// The last version whose payload is the bare bincode value (what `ModelPack::to_bytes_v4`
/// writes).
pub const PACK_VERSION_UNCOMPRESSED: u16 = 4;
/// The version whose payload [`pack_v5`](super::pack_v5) reads.
pub const PACK_VERSION_V5: u16 = 5;
/// The version whose payload [`pack_v6`](super::pack_v6) reads.
pub const PACK_VERSION_V6: u16 = 6;
/// The version whose payload [`pack_v7`](super::pack_v7) reads.
pub const PACK_VERSION_V7: u16 = 7;
/// The version whose payload [`pack_v8`](super::pack_v8) reads.
pub const PACK_VERSION_V8: u16 = 8;
/// The oldest pack version this noisecal reads.
pub const PACK_VERSION_MIN: u16 = 1;
