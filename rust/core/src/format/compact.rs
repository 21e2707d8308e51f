//! A version 9 pack file: a small sealed index (the pack-level fields and a table of its ISOs),
//! then one section per ISO, compressed and sealed on its own, so a reader decodes only the ISOs
//! it is asked for ([`super::lazy_pack`]):
//!
//! `magic | version u16 | reserved u16 | index_len u64 | crc32(index) u32 | index | section…`
//!
//! - **index**: `raw_len u64 | deflate(bincode(PackIndex))`, the [`PackIndex`]: layout, make, model, bin width, reference ISO,
//!   pooling, warnings, and per ISO ([`IsoEntry`], sorted by ISO) its origin, whether it has
//!   structured components, the noise law of a calibrated ISO per CFA position (what an
//!   interpolation's plan reads to find conversion-gain switches without decoding every ISO:
//!   [`crate::derive::noise_law::fit_params`] of the stored model, so the plan is the one the
//!   whole pack gives), and its section's length and CRC-32. Sections follow in the index's
//!   order, each right after the one before (offsets are the running sum of the lengths), and
//!   end exactly at the end of the file.
//! - **section**: `fields_len u64 | deflated_fields_len u64 | weights_len u64 |
//!   deflate(fields) | deflate(weights)`: the fields are bincode of the ISO's model with its
//!   bins' weights taken out and of its structured components, the weights its PMF weights as
//!   version 8 codes them ([`super::weight_stream`]). The two are deflated apart: one stream of
//!   both came out 2–3 % larger (deflate's blocks adapt poorly where the data changes kind).
//!
//! The index is checked whole when the file is opened (a file cut short or with bytes after its
//! last section is refused then, before any section is read); a section is checked against its
//! CRC, and its ISO, origin and components against the index, when it is decoded. Same pack in,
//! same bytes out.

use serde::{Deserialize, Serialize};

use crate::derive::noise_law::{NoiseParams, fit_params};
use crate::error::CodecError;
use crate::format::codec;
use crate::format::pack_version::{PACK_MAGIC, PACK_VERSION};
use crate::format::weight_stream::{check_used, decode_iso, encode_iso};
use crate::model::layout::{POSITIONS, SensorLayout};
use crate::model::pack::{IsoModel, ModelOrigin, ModelPack};
use crate::model::structure::IsoStructure;

const WHAT: &str = "model pack";

/// The pack-level fields of a version 9 file and the table of its ISO sections.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct PackIndex {
    pub layout: SensorLayout,
    pub make: String,
    pub model: String,
    pub bin_width: u16,
    pub reference_iso: u32,
    pub pooling: Option<u64>,
    pub warnings: Vec<String>,
    /// One entry per ISO, sorted by ISO, in the order of their sections.
    pub isos: Vec<IsoEntry>,
}

/// One ISO of a version 9 file, as its index lists it.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct IsoEntry {
    pub iso: u32,
    pub origin: ModelOrigin,
    /// The section holds structured components for this ISO.
    pub structured: bool,
    /// A calibrated ISO's noise law per CFA position, `[a, b]` of
    /// [`fit_params`] (`None` where it fits nothing; every position `None` for a derived ISO).
    pub law: [Option<[f64; 2]>; POSITIONS],
    /// The section's length in bytes and its CRC-32.
    pub len: u64,
    pub crc: u32,
}

impl IsoEntry {
    pub fn is_calibrated(&self) -> bool {
        matches!(self.origin, ModelOrigin::Calibrated)
    }

    /// The noise law per position, as [`fit_params`] gives it.
    pub fn noise_law(&self) -> [Option<NoiseParams>; POSITIONS] {
        self.law.map(|l| l.map(|[a, b]| NoiseParams { a, b }))
    }
}

impl PackIndex {
    /// The index of `pack` (in its stored form) with no sections measured yet.
    pub fn of(pack: &ModelPack) -> Self {
        let binning = pack.binning();
        Self {
            layout: pack.layout.clone(),
            make: pack.make.clone(),
            model: pack.model.clone(),
            bin_width: pack.bin_width,
            reference_iso: pack.reference_iso,
            pooling: pack.pooling,
            warnings: pack.warnings.clone(),
            isos: pack
                .isos
                .iter()
                .map(|m| IsoEntry {
                    iso: m.iso,
                    origin: m.origin.clone(),
                    structured: pack.structure_of(m.iso).is_some(),
                    law: std::array::from_fn(|pos| {
                        m.is_calibrated().then(|| fit_params(&binning, m, pos)).flatten().map(|p| [p.a, p.b])
                    }),
                    len: 0,
                    crc: 0,
                })
                .collect(),
        }
    }

    /// A pack with these fields and no ISO.
    pub fn empty_pack(&self) -> ModelPack {
        ModelPack {
            layout: self.layout.clone(),
            make: self.make.clone(),
            model: self.model.clone(),
            bin_width: self.bin_width,
            reference_iso: self.reference_iso,
            pooling: self.pooling,
            isos: Vec::new(),
            warnings: self.warnings.clone(),
            structure: Vec::new(),
        }
    }

    /// The entry of exactly this ISO.
    pub fn entry(&self, iso: u32) -> Option<&IsoEntry> {
        self.isos.iter().find(|e| e.iso == iso)
    }
}

/// One ISO's model and structured components, as a section holds them.
pub type IsoSection = (IsoModel, Option<IsoStructure>);

/// The version 9 file of `pack` (already in its stored form, [`ModelPack::compacted`]).
pub fn encode(pack: &ModelPack) -> Result<Vec<u8>, CodecError> {
    let mut index = PackIndex::of(pack);
    let mut sections = Vec::new();
    for (m, entry) in pack.isos.iter().zip(index.isos.iter_mut()) {
        let section = encode_section(m, pack.structure_of(m.iso))?;
        entry.len = section.len() as u64;
        entry.crc = crc32fast::hash(&section);
        sections.extend_from_slice(&section);
    }
    let raw = codec::encode_payload(WHAT, &index)?;
    let mut head = (raw.len() as u64).to_le_bytes().to_vec();
    head.extend_from_slice(&codec::deflate(&raw));
    let mut out = codec::encode_sealed(PACK_MAGIC, PACK_VERSION, &head);
    out.extend_from_slice(&sections);
    Ok(out)
}

fn encode_section(m: &IsoModel, structure: Option<&IsoStructure>) -> Result<Vec<u8>, CodecError> {
    let mut weights = Vec::new();
    encode_iso(m, &mut weights)?;
    let mut fields = m.clone();
    fields.positions.iter_mut().flat_map(|p| p.bins.iter_mut()).for_each(|b| b.counts = Vec::new());
    let fields = codec::encode_payload(WHAT, &(fields, structure))?;
    let (f, w) = (codec::deflate(&fields), codec::deflate(&weights));
    let mut out = Vec::with_capacity(SECTION_LENGTHS + f.len() + w.len());
    for len in [fields.len(), f.len(), weights.len()] {
        out.extend_from_slice(&(len as u64).to_le_bytes());
    }
    out.extend_from_slice(&f);
    out.extend_from_slice(&w);
    Ok(out)
}

/// Bytes of a section's lengths (fields, deflated fields, weights).
const SECTION_LENGTHS: usize = 24;

/// The fields of `entry`'s section (model without weights, structured components), checked
/// against the index (CRC, ISO, origin, components), and the section's still deflated weights
/// with their inflated length.
fn section_fields<'a>(entry: &IsoEntry, section: &'a [u8]) -> Result<(IsoSection, &'a [u8], u64), CodecError> {
    let iso = entry.iso;
    let damaged = |what: String| CodecError::Invalid { what: WHAT, detail: format!("{what}: the file is damaged") };
    codec::check_crc(WHAT, crc32fast::hash(section), entry.crc)?;
    let Some((lens, rest)) = section.split_first_chunk::<SECTION_LENGTHS>() else {
        return Err(CodecError::Truncated { what: WHAT, len: section.len(), expected: SECTION_LENGTHS });
    };
    let len = |i: usize| u64::from_le_bytes(lens[8 * i..8 * i + 8].try_into().expect("8 bytes"));
    let (fields_len, deflated_len, weights_len) = (len(0), len(1), len(2));
    if deflated_len > rest.len() as u64 {
        return Err(damaged(format!(
            "an ISO section claims {deflated_len} bytes of fields, more than its {} bytes",
            rest.len()
        )));
    }
    let (f, w) = rest.split_at(deflated_len as usize);
    let (m, structure): IsoSection = codec::decode_payload(WHAT, &codec::inflate_exact(WHAT, fields_len, f)?)?;
    if m.iso != iso || m.origin != entry.origin {
        return Err(damaged(format!("the section of ISO {iso} holds the model of ISO {} ({:?})", m.iso, m.origin)));
    }
    if structure.is_some() != entry.structured || structure.as_ref().is_some_and(|s| s.iso != iso) {
        return Err(damaged(format!("the structured components of ISO {iso} do not match the index")));
    }
    Ok(((m, structure), w, weights_len))
}

/// The index of a version 9 file whose framing (magic, version) was checked: `head` is its
/// sealed index, `rest` the bytes after it. Returns the index and each section's byte range in
/// `rest`. A file cut short inside its sections, or with bytes after the last, is refused here.
pub fn read_index(head: &[u8], rest: &[u8]) -> Result<(PackIndex, Vec<std::ops::Range<usize>>), CodecError> {
    let bad = |detail: String| CodecError::Invalid { what: WHAT, detail };
    let Some((raw_len, deflated)) = head.split_first_chunk::<8>() else {
        return Err(CodecError::Truncated { what: WHAT, len: codec::SEALED_HEAD_BYTES + head.len(), expected: 8 });
    };
    let index: PackIndex =
        codec::decode_payload(WHAT, &codec::inflate_exact(WHAT, u64::from_le_bytes(*raw_len), deflated)?)?;
    for w in index.isos.windows(2) {
        if w[0].iso >= w[1].iso {
            return Err(bad(format!(
                "the index lists ISOs out of order ({} then {}): the file is damaged",
                w[0].iso, w[1].iso
            )));
        }
    }
    if let Some(e) = index.isos.iter().find(|e| e.law.iter().flatten().flatten().any(|v| !v.is_finite())) {
        return Err(bad(format!(
            "the index holds a noise law that is not a number for ISO {}: the file is damaged",
            e.iso
        )));
    }
    let mut ranges = Vec::with_capacity(index.isos.len());
    let mut at = 0u64;
    for e in &index.isos {
        let end = at.saturating_add(e.len);
        ranges.push(at as usize..end.min(rest.len() as u64) as usize);
        at = end;
    }
    if at > rest.len() as u64 {
        let header = codec::SEALED_HEAD_BYTES + head.len();
        return Err(CodecError::Truncated {
            what: WHAT,
            len: header + rest.len(),
            expected: header.saturating_add(usize::try_from(at).unwrap_or(usize::MAX)),
        });
    }
    if at < rest.len() as u64 {
        return Err(bad(format!("{} trailing bytes after the last ISO section", rest.len() as u64 - at)));
    }
    Ok((index, ranges))
}

/// The model and structured components of `entry` from its section's bytes, refusing a damaged
/// section with a clear error. `cells` counts the weights decoded so far from this file (a
/// limit for the whole file: [`super::weight_stream::MAX_CELLS`]).
pub fn decode_section(entry: &IsoEntry, section: &[u8], cells: &mut u64) -> Result<IsoSection, CodecError> {
    let ((mut m, structure), deflated_weights, weights_len) = section_fields(entry, section)?;
    let weights = codec::inflate_exact(WHAT, weights_len, deflated_weights)?;
    let mut at = 0;
    decode_iso(&mut m, &format!("ISO {}", entry.iso), &weights, &mut at, cells)?;
    check_used(&weights, at)?;
    Ok((m, structure))
}

/// The model's fields (its bins' weights not inflated nor expanded) and the structured
/// components of `entry` from its section's bytes, the section checked as [`decode_section`]
/// checks it.
pub fn decode_section_fields(entry: &IsoEntry, section: &[u8]) -> Result<IsoSection, CodecError> {
    Ok(section_fields(entry, section)?.0)
}

/// Every ISO of a version 9 file (`head` its sealed index, `rest` the bytes after it), as one
/// pack (checked by the caller).
pub fn decode(head: &[u8], rest: &[u8]) -> Result<ModelPack, CodecError> {
    let (index, ranges) = read_index(head, rest)?;
    let mut pack = index.empty_pack();
    let mut cells = 0u64;
    for (entry, range) in index.isos.iter().zip(ranges) {
        let (m, structure) = decode_section(entry, &rest[range], &mut cells)?;
        pack.isos.push(m);
        pack.structure.extend(structure);
    }
    Ok(pack)
}

/// A version 9 file with its seals made to match its bytes again: each section's length kept
/// (the last one's running to the end of the file) and its CRC recomputed, the index written
/// again and resealed. For fuzzers, whose mutations would otherwise stop at the checksums; `None`
/// when the file's framing or index cannot be read at all.
pub fn reseal(file: &[u8]) -> Option<Vec<u8>> {
    let header = codec::SEALED_HEAD_BYTES;
    let head_len = usize::try_from(u64::from_le_bytes(file.get(12..20)?.try_into().ok()?)).ok()?;
    let head = file.get(header..header.checked_add(head_len)?)?;
    let rest = &file[header + head_len..];
    let (raw_len, deflated) = head.split_first_chunk::<8>()?;
    let raw = codec::inflate_exact(WHAT, u64::from_le_bytes(*raw_len), deflated).ok()?;
    let mut index: PackIndex = codec::decode_payload(WHAT, &raw).ok()?;
    let mut at = 0usize;
    let n = index.isos.len();
    for (i, e) in index.isos.iter_mut().enumerate() {
        let len = if i + 1 == n { rest.len().checked_sub(at)? } else { usize::try_from(e.len).ok()? };
        let section = rest.get(at..at.checked_add(len)?)?;
        e.len = len as u64;
        e.crc = crc32fast::hash(section);
        at += len;
    }
    let raw = codec::encode_payload(WHAT, &index).ok()?;
    let mut head = (raw.len() as u64).to_le_bytes().to_vec();
    head.extend_from_slice(&codec::deflate(&raw));
    let version = u16::from_le_bytes([file[8], file[9]]);
    let mut out = codec::encode_sealed(PACK_MAGIC, version, &head);
    out.extend_from_slice(rest);
    Some(out)
}
