//! The framing every binary file noisecal writes, in one place. All integers are little-endian.
//!
//! Every file opens with the same **preamble**, `magic (8 bytes) | format version u16`, checked by
//! one rule ([`check_preamble`]: wrong magic, cut short, newer or older version, each with its own
//! message), and seals what follows with CRC-32s. Two layouts follow the preamble:
//!
//! - **Sealed file** (model packs, checkpoints), written whole:
//!   `preamble | reserved u16 (0) | payload_len u64 | crc32(payload) u32 | payload`, the payload a
//!   bincode 2 value ([`encode`], [`decode`], [`decode_framing`] + [`decode_payload`] for readers
//!   that migrate older versions).
//! - **Record stream** (recordings), written as it happens and readable up to an interruption:
//!   `preamble | header_len u32 | header | crc32(header) u32` ([`encode_stream_header`],
//!   [`decode_stream_start`], [`open_sealed_header`]), then records
//!   `tag u8 | payload | crc32(tag + payload) u32` ([`write_record`], [`RecordSeal`]).
//!
//! Same value in, same bytes out. What the header and the records hold is the file's own business
//! (`model::pack`, `calibrate::session`, [`recording`](super::recording)).

use std::io::{self, Write};

use serde::{Serialize, de::DeserializeOwned};

use crate::error::CodecError;

/// Magic and format version.
const PREAMBLE: usize = 8 + 2;
/// Fixed part of a sealed file: preamble, reserved, payload length, CRC.
const SEALED_HEADER: usize = PREAMBLE + 2 + 8 + 4;
/// Fixed part of a record stream: preamble and header length.
pub const STREAM_START: usize = PREAMBLE + 4;
/// A record stream's header longer than this is refused as implausible (a damaged length field).
pub const MAX_STREAM_HEADER: usize = 1 << 20;
/// Bytes of a record's seal.
pub const SEAL: usize = 4;

fn config() -> bincode::config::Configuration {
    bincode::config::standard()
}

fn preamble(magic: &[u8; 8], version: u16) -> [u8; PREAMBLE] {
    let mut p = [0u8; PREAMBLE];
    p[..8].copy_from_slice(magic);
    p[8..].copy_from_slice(&version.to_le_bytes());
    p
}

/// Checks the preamble at the start of `bytes` (a file, or as much of its start as was read) and
/// returns the format version, one of `supported`. `fixed` is the length of the file's fixed
/// part (preamble included): fewer bytes than that is a truncated file.
pub fn check_preamble(
    what: &'static str,
    magic: &[u8; 8],
    magic_text: &'static str,
    supported: std::ops::RangeInclusive<u16>,
    bytes: &[u8],
    fixed: usize,
) -> Result<u16, CodecError> {
    if bytes.len() < 8 || &bytes[..8] != magic {
        if bytes.len() < 8 && magic.starts_with(bytes) && !bytes.is_empty() {
            return Err(CodecError::Truncated { what, len: bytes.len(), expected: fixed });
        }
        return Err(CodecError::BadMagic { what, expected: magic_text });
    }
    if bytes.len() < fixed.max(PREAMBLE) {
        return Err(CodecError::Truncated { what, len: bytes.len(), expected: fixed });
    }
    let found = u16::from_le_bytes([bytes[8], bytes[9]]);
    if found > *supported.end() {
        return Err(CodecError::NewerVersion { what, found, supported: *supported.end() });
    }
    if found < *supported.start() {
        return Err(CodecError::OlderVersion { what, found, supported: *supported.start() });
    }
    Ok(found)
}

/// Refuses a CRC that does not match.
pub fn check_crc(what: &'static str, found: u32, expected: u32) -> Result<(), CodecError> {
    if found != expected {
        return Err(CodecError::Checksum { what, found, expected });
    }
    Ok(())
}

fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]])
}

// ---- sealed files ----------------------------------------------------------------------------

/// Encodes `value` as a sealed file behind `magic` (8 bytes) and `version`.
pub fn encode<T: Serialize>(
    what: &'static str,
    magic: &[u8; 8],
    version: u16,
    value: &T,
) -> Result<Vec<u8>, CodecError> {
    Ok(encode_sealed(magic, version, &encode_payload(what, value)?))
}

/// The bincode payload of `value`, as [`encode`] seals it.
pub fn encode_payload<T: Serialize>(what: &'static str, value: &T) -> Result<Vec<u8>, CodecError> {
    bincode::serde::encode_to_vec(value, config()).map_err(|e| CodecError::Encode { what, detail: e.to_string() })
}

/// Seals `payload` (any bytes: a file whose payload is not a bare bincode value, such as a
/// compressed one) behind `magic` and `version`, as [`encode`] does.
pub fn encode_sealed(magic: &[u8; 8], version: u16, payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(SEALED_HEADER + payload.len());
    out.extend_from_slice(&preamble(magic, version));
    out.extend_from_slice(&0u16.to_le_bytes());
    out.extend_from_slice(&(payload.len() as u64).to_le_bytes());
    out.extend_from_slice(&crc32fast::hash(payload).to_le_bytes());
    out.extend_from_slice(payload);
    out
}

/// Decodes what [`encode`] wrote, refusing a wrong magic, a newer or older version, a truncated
/// file and a checksum mismatch, each with its own message.
pub fn decode<T: DeserializeOwned>(
    what: &'static str,
    magic: &[u8; 8],
    magic_text: &'static str,
    version: u16,
    bytes: &[u8],
) -> Result<T, CodecError> {
    let (_, payload) = decode_framing(what, magic, magic_text, version..=version, bytes)?;
    decode_payload(what, payload)
}

/// Checks the framing of what [`encode`] wrote and returns its format version (one of
/// `supported`) and its payload, for readers that migrate older versions.
pub fn decode_framing<'a>(
    what: &'static str,
    magic: &[u8; 8],
    magic_text: &'static str,
    supported: std::ops::RangeInclusive<u16>,
    bytes: &'a [u8],
) -> Result<(u16, &'a [u8]), CodecError> {
    let (found, payload, rest) = decode_sealed_head(what, magic, magic_text, supported, bytes)?;
    if !rest.is_empty() {
        return Err(CodecError::Invalid { what, detail: format!("{} trailing bytes after the payload", rest.len()) });
    }
    Ok((found, payload))
}

/// The format version of a sealed file (one of `supported`), from its preamble alone.
pub fn sealed_version(
    what: &'static str,
    magic: &[u8; 8],
    magic_text: &'static str,
    supported: std::ops::RangeInclusive<u16>,
    bytes: &[u8],
) -> Result<u16, CodecError> {
    check_preamble(what, magic, magic_text, supported, bytes, SEALED_HEADER)
}

/// A sealed file whose sealed payload is a head that more bytes follow (each sealed on its
/// own, as the head says): its format version, its head (checked against its CRC) and the
/// bytes after it.
pub fn decode_sealed_head<'a>(
    what: &'static str,
    magic: &[u8; 8],
    magic_text: &'static str,
    supported: std::ops::RangeInclusive<u16>,
    bytes: &'a [u8],
) -> Result<(u16, &'a [u8], &'a [u8]), CodecError> {
    let found = check_preamble(what, magic, magic_text, supported, bytes, SEALED_HEADER)?;
    let mut len_bytes = [0u8; 8];
    len_bytes.copy_from_slice(&bytes[12..20]);
    let len = u64::from_le_bytes(len_bytes);
    let crc = u32_at(bytes, 20);
    let payload = &bytes[SEALED_HEADER..];
    if (payload.len() as u64) < len {
        return Err(CodecError::Truncated {
            what,
            len: bytes.len(),
            expected: SEALED_HEADER.saturating_add(usize::try_from(len).unwrap_or(usize::MAX)),
        });
    }
    let (head, rest) = payload.split_at(len as usize);
    check_crc(what, crc32fast::hash(head), crc)?;
    Ok((found, head, rest))
}

/// Bytes of a sealed file before its payload (preamble, reserved, length, CRC).
pub const SEALED_HEAD_BYTES: usize = SEALED_HEADER;

/// Decodes a payload returned by [`decode_framing`]; every byte must be used.
pub fn decode_payload<T: DeserializeOwned>(what: &'static str, payload: &[u8]) -> Result<T, CodecError> {
    // A length field is checked against the limit before anything is allocated for it (a
    // damaged string length once asked for 7.8 EB: found by noisecal-fuzz).
    let limited = config().with_limit::<{ 1 << 30 }>();
    let (value, used) = bincode::serde::decode_from_slice(payload, limited)
        .map_err(|e| CodecError::Decode { what, detail: describe_decode_error(&e) })?;
    if used != payload.len() {
        return Err(CodecError::Invalid { what, detail: format!("payload has {} unread bytes", payload.len() - used) });
    }
    Ok(value)
}

/// What a payload that fails to decode holds, in words (bincode's own text is its Rust `Debug`
/// form, e.g. `InvalidBooleanValue(130)`, which says nothing to a user).
fn describe_decode_error(e: &bincode::error::DecodeError) -> String {
    use bincode::error::DecodeError as E;
    let what = match e {
        E::UnexpectedEnd { .. } => "the payload ends inside a value".to_string(),
        E::InvalidBooleanValue(v) => format!("a yes/no field holds the byte {v} (only 0 or 1 are valid)"),
        E::UnexpectedVariant { found, .. } => format!("a field holds the unknown kind {found}"),
        E::Utf8 { .. } => "a text field is not UTF-8".to_string(),
        E::InvalidCharEncoding(_) => "a character field is not valid".to_string(),
        E::ArrayLengthMismatch { required, found } => {
            format!("an array holds {found} values where {required} belong")
        }
        E::OutsideUsizeRange(n) => format!("a length of {n} is out of range"),
        E::InvalidIntegerType { .. } => "a number is stored with the wrong width".to_string(),
        E::LimitExceeded => "a length exceeds the size limit".to_string(),
        _ => "a field holds a value of the wrong kind".to_string(),
    };
    format!("{what}; the file is damaged or was not written by noisecal")
}

// ---- record streams --------------------------------------------------------------------------

/// The start of a record stream: preamble, then `header` sealed by its length and CRC.
pub fn encode_stream_header(magic: &[u8; 8], version: u16, header: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(STREAM_START + header.len() + SEAL);
    out.extend_from_slice(&preamble(magic, version));
    out.extend_from_slice(&(header.len() as u32).to_le_bytes());
    out.extend_from_slice(header);
    out.extend_from_slice(&crc32fast::hash(header).to_le_bytes());
    out
}

/// Checks the first [`STREAM_START`] bytes of a record stream (`start` may be shorter if the
/// file is) and returns the format version and the header's length; the header and its CRC
/// ([`open_sealed_header`]) follow.
pub fn decode_stream_start(
    what: &'static str,
    magic: &[u8; 8],
    magic_text: &'static str,
    supported: std::ops::RangeInclusive<u16>,
    start: &[u8],
) -> Result<(u16, usize), CodecError> {
    let version = check_preamble(what, magic, magic_text, supported, start, STREAM_START)?;
    let len = u32_at(start, PREAMBLE) as usize;
    if len > MAX_STREAM_HEADER {
        return Err(CodecError::Invalid { what, detail: format!("header length {len} is implausible") });
    }
    Ok((version, len))
}

/// Checks a stream header's seal: `sealed` is the header followed by its CRC (the
/// `header_len + 4` bytes after [`decode_stream_start`]'s); returns the header.
pub fn open_sealed_header<'a>(what: &'static str, sealed: &'a [u8]) -> Result<&'a [u8], CodecError> {
    let Some(len) = sealed.len().checked_sub(SEAL) else {
        return Err(CodecError::Truncated { what, len: sealed.len(), expected: SEAL });
    };
    let header = &sealed[..len];
    check_crc(what, crc32fast::hash(header), u32_at(sealed, len))?;
    Ok(header)
}

/// Writes one record, `tag | parts… | crc32(tag + parts…)`, and returns its length in bytes. The
/// parts are written as they are (a frame's plane is not copied).
pub fn write_record<W: Write>(out: &mut W, tag: u8, parts: &[&[u8]]) -> io::Result<u64> {
    let mut seal = RecordSeal::new(tag);
    out.write_all(&[tag])?;
    let mut len = 1 + SEAL as u64;
    for p in parts {
        seal.update(p);
        out.write_all(p)?;
        len += p.len() as u64;
    }
    out.write_all(&seal.finish().to_le_bytes())?;
    Ok(len)
}

/// The CRC of a record being read: started with its tag, fed its payload, checked against the
/// stored seal.
#[derive(Debug, Clone)]
pub struct RecordSeal(crc32fast::Hasher);

impl RecordSeal {
    pub fn new(tag: u8) -> Self {
        let mut h = crc32fast::Hasher::new();
        h.update(&[tag]);
        Self(h)
    }

    pub fn update(&mut self, bytes: &[u8]) {
        self.0.update(bytes);
    }

    fn finish(self) -> u32 {
        self.0.finalize()
    }

    /// The CRC of what was fed so far (the value the stored seal must hold).
    pub fn value(&self) -> u32 {
        self.0.clone().finalize()
    }

    /// Checks the 4 stored seal bytes.
    pub fn check(self, what: &'static str, stored: [u8; SEAL]) -> Result<(), CodecError> {
        check_crc(what, self.finish(), u32::from_le_bytes(stored))
    }
}

/// Deflate level of the compact pack payloads (versions 6 and 7).
const DEFLATE_LEVEL: u8 = 9;
/// The largest uncompressed payload a pack may claim (the bincode decoder's own limit).
pub(crate) const MAX_INFLATED: u64 = 1 << 30;

/// The compact pack payloads' envelope (versions 6 and 7): the uncompressed length and the
/// length of the bincode `fields` (little-endian u64 each), then the fields followed by the
/// weight stream, deflated together.
pub(crate) fn deflate_fields_and_weights<T: Serialize>(
    what: &'static str,
    fields: &T,
    weights: &[u8],
) -> Result<Vec<u8>, CodecError> {
    let mut raw = encode_payload(what, fields)?;
    let fields_len = raw.len() as u64;
    raw.extend_from_slice(weights);
    let mut out = Vec::with_capacity(16 + raw.len() / 4);
    out.extend_from_slice(&(raw.len() as u64).to_le_bytes());
    out.extend_from_slice(&fields_len.to_le_bytes());
    out.extend_from_slice(&miniz_oxide::deflate::compress_to_vec(&raw, DEFLATE_LEVEL));
    Ok(out)
}

/// The fields and the weight stream of [`deflate_fields_and_weights`], refusing a damaged
/// envelope with a clear error.
pub(crate) fn inflate_fields_and_weights<T: DeserializeOwned>(
    what: &'static str,
    payload: &[u8],
) -> Result<(T, Vec<u8>), CodecError> {
    let Some((lens, deflated)) = payload.split_first_chunk::<16>() else {
        return Err(CodecError::Truncated { what, len: payload.len(), expected: 16 });
    };
    let raw_len = u64::from_le_bytes(lens[..8].try_into().expect("8 bytes"));
    let fields_len = u64::from_le_bytes(lens[8..].try_into().expect("8 bytes"));
    // (A claim beyond the limit is refused by `inflate_exact` as such.)
    if fields_len > raw_len && raw_len <= MAX_INFLATED {
        return Err(CodecError::Invalid {
            what,
            detail: "the pack's fields claim more bytes than the payload holds: the file is damaged".into(),
        });
    }
    let mut raw = inflate_exact(what, raw_len, deflated)?;
    let weights = raw.split_off(fields_len as usize);
    Ok((decode_payload(what, &raw)?, weights))
}

/// `raw` deflated at the compact pack payloads' level.
pub(crate) fn deflate(raw: &[u8]) -> Vec<u8> {
    miniz_oxide::deflate::compress_to_vec(raw, DEFLATE_LEVEL)
}

/// `deflated` inflated to exactly `raw_len` bytes (at most [`MAX_INFLATED`]), refusing a claim
/// beyond the limit or a stream that does not inflate to its stated length.
pub(crate) fn inflate_exact(what: &'static str, raw_len: u64, deflated: &[u8]) -> Result<Vec<u8>, CodecError> {
    let bad = |detail: String| CodecError::Invalid { what, detail };
    if raw_len > MAX_INFLATED {
        return Err(bad(format!(
            "the payload claims {raw_len} bytes uncompressed, beyond the {MAX_INFLATED}-byte limit"
        )));
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
    Ok(raw)
}

/// A signed difference as an unsigned one whose size follows its magnitude (0, −1, 1, −2 … →
/// 0, 1, 2, 3 …), for the compact pack payloads' varints.
pub(crate) fn zigzag(d: i64) -> u64 {
    ((d << 1) ^ (d >> 63)) as u64
}

/// The inverse of [`zigzag`].
pub(crate) fn unzigzag(z: u64) -> i64 {
    ((z >> 1) as i64) ^ -((z & 1) as i64)
}

/// Appends `v` as an LEB128 varint (7 bits a byte, low first).
pub(crate) fn put_varint(out: &mut Vec<u8>, mut v: u64) {
    while v >= 0x80 {
        out.push((v as u8) | 0x80);
        v >>= 7;
    }
    out.push(v as u8);
}

/// Reads an LEB128 varint at `*at`, or `None` at the end of the bytes or past 64 bits.
pub(crate) fn get_varint(b: &[u8], at: &mut usize) -> Option<u64> {
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

#[cfg(test)]
mod tests {
    use super::*;

    const M: &[u8; 8] = b"NCTEST\0\x01";

    #[test]
    fn round_trip_and_each_refusal() {
        let v: Vec<u32> = (0..1000).collect();
        let b = encode("test file", M, 3, &v).unwrap();
        assert_eq!(b, encode("test file", M, 3, &v).unwrap());
        let back: Vec<u32> = decode("test file", M, "NCTEST", 3, &b).unwrap();
        assert_eq!(back, v);
        assert!(matches!(
            decode::<Vec<u32>>("t", M, "NCTEST", 3, &b[..b.len() - 1]),
            Err(CodecError::Truncated { .. })
        ));
        assert!(matches!(decode::<Vec<u32>>("t", M, "NCTEST", 3, &b[..10]), Err(CodecError::Truncated { .. })));
        assert!(matches!(decode::<Vec<u32>>("t", M, "NCTEST", 3, &b[..3]), Err(CodecError::Truncated { .. })));
        assert!(matches!(decode::<Vec<u32>>("t", M, "NCTEST", 2, &b), Err(CodecError::NewerVersion { .. })));
        assert!(matches!(decode::<Vec<u32>>("t", M, "NCTEST", 4, &b), Err(CodecError::OlderVersion { .. })));
        let mut c = b.clone();
        let last = c.len() - 5;
        c[last] ^= 0x40;
        assert!(matches!(decode::<Vec<u32>>("t", M, "NCTEST", 3, &c), Err(CodecError::Checksum { .. })));
        assert!(matches!(
            decode::<Vec<u32>>("t", M, "NCTEST", 3, b"hello world, not a pack"),
            Err(CodecError::BadMagic { .. })
        ));
    }

    /// A payload that does not decode says so in words, not in Rust's
    /// (`InvalidBooleanValue(130)`).
    #[test]
    fn undecodable_payloads_are_described_in_words() {
        let b = encode("test file", M, 3, &(true, 7u32)).unwrap();
        let mut bad = b.clone();
        let at = SEALED_HEADER;
        bad[at] = 130;
        let crc = crc32fast::hash(&bad[SEALED_HEADER..]);
        bad[20..24].copy_from_slice(&crc.to_le_bytes());
        let e = decode::<(bool, u32)>("test file", M, "NCTEST", 3, &bad).unwrap_err().to_string();
        assert!(e.contains("yes/no field holds the byte 130"), "{e}");
        assert!(!e.contains("InvalidBooleanValue"), "{e}");
        // A string claiming 7.8 EB (noisecal-fuzz's pack finding): refused, not allocated.
        let mut huge = vec![0xFDu8]; // varint: a u64 follows
        huge.extend_from_slice(&7_809_660_717_469_758_603u64.to_le_bytes());
        let e = decode_payload::<String>("test file", &huge).unwrap_err().to_string();
        assert!(e.contains("size limit"), "{e}");
        let e = decode::<(bool, u32, u64)>("test file", M, "NCTEST", 3, &b).unwrap_err().to_string();
        assert!(e.contains("ends inside a value") && !e.contains("UnexpectedEnd"), "{e}");
    }

    /// The sealed layout, written out byte by byte: a change to it breaks every pack on disk.
    #[test]
    fn sealed_layout_is_the_documented_one() {
        let b = encode("t", M, 7, &(5u8, 300u16)).unwrap();
        let payload = [5u8, 251, 44, 1]; // bincode varints: 5, then 300 = 0xFB + u16
        let mut want = M.to_vec();
        want.extend_from_slice(&[7, 0, 0, 0]);
        want.extend_from_slice(&(payload.len() as u64).to_le_bytes());
        want.extend_from_slice(&crc32fast::hash(&payload).to_le_bytes());
        want.extend_from_slice(&payload);
        assert_eq!(b, want);
    }

    #[test]
    fn streams_seal_their_header_and_each_record() {
        let start = encode_stream_header(M, 2, b"head");
        assert_eq!(&start[..10], &preamble(M, 2));
        assert_eq!(&start[10..14], &4u32.to_le_bytes());
        let (version, len) = decode_stream_start("t", M, "NCTEST", 1..=2, &start[..STREAM_START]).unwrap();
        assert_eq!((version, len), (2, 4));
        assert_eq!(open_sealed_header("t", &start[STREAM_START..]).unwrap(), b"head");
        let mut bad = start.clone();
        bad[STREAM_START] ^= 1;
        assert!(matches!(open_sealed_header("t", &bad[STREAM_START..]), Err(CodecError::Checksum { .. })));
        assert!(matches!(
            decode_stream_start("t", M, "NCTEST", 1..=1, &start[..STREAM_START]),
            Err(CodecError::NewerVersion { .. })
        ));
        assert!(matches!(
            decode_stream_start("t", M, "NCTEST", 2..=2, &start[..12]),
            Err(CodecError::Truncated { .. })
        ));
        let mut huge = start.clone();
        huge[10..14].copy_from_slice(&(MAX_STREAM_HEADER as u32 + 1).to_le_bytes());
        assert!(matches!(
            decode_stream_start("t", M, "NCTEST", 2..=2, &huge[..STREAM_START]),
            Err(CodecError::Invalid { .. })
        ));

        let mut rec = Vec::new();
        let n = write_record(&mut rec, 9, &[b"ab", b"", b"cde"]).unwrap();
        assert_eq!(n as usize, rec.len());
        let mut want = vec![9u8];
        want.extend_from_slice(b"abcde");
        want.extend_from_slice(&crc32fast::hash(&want).to_le_bytes());
        assert_eq!(rec, want);
        let mut seal = RecordSeal::new(9);
        seal.update(b"abcde");
        seal.check("t", rec[6..10].try_into().unwrap()).unwrap();
        let mut other = RecordSeal::new(8);
        other.update(b"abcde");
        assert!(matches!(other.check("t", rec[6..10].try_into().unwrap()), Err(CodecError::Checksum { .. })));
    }
}
