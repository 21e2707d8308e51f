//! A pack file read on demand: opening it reads its index only ([`compact`]: the pack-level
//! fields, the ISO list, each calibrated ISO's noise law), and an ISO's section is decoded the
//! first time it is asked for, then kept. A file of an older version (one deflate stream) is
//! decoded and migrated whole when it is opened.
//!
//! ```text
//! LazyPack::open(bytes) ─ index() (layout, ISOs, laws)
//!     pack_with(&[800, 1600]) → a ModelPack holding those ISOs only (decoded once, checked)
//!     to_pack()               → every ISO (what ModelPack::from_bytes gives)
//! ```
//!
//! The bytes are handed in (a copy, a mapping, a slice: anything that derefs to bytes): the core
//! reads no file. Thread-safe: a section
//! is decoded outside any lock and kept under a short one (two threads asking at once may both
//! decode it; the first kept wins, the two are equal), so a process forked while another thread
//! decodes is never left waiting on a lock nobody will release.

use std::ops::Range;
use std::sync::{Arc, Mutex};

use crate::error::CodecError;
use crate::format::codec;
use crate::format::compact::{self, IsoSection, PackIndex};
use crate::format::pack_version::{PACK_MAGIC, PACK_MAGIC_TEXT, PACK_VERSION, PACK_VERSION_MIN};
use crate::model::pack::{IsoModel, ModelPack};

const WHAT: &str = "model pack";

/// A pack file whose ISOs are decoded when first asked for.
pub struct LazyPack<B> {
    bytes: B,
    index: PackIndex,
    /// Where each ISO's section lies in `bytes` (in the index's order).
    sections: Vec<Range<usize>>,
    /// The whole pack, for a file of an older version (decoded when opened).
    whole: Option<ModelPack>,
    /// The sections decoded so far, in the index's order, and the weights they hold (once
    /// expanded): the file's limit holds over every section decoded, as for a whole file.
    decoded: Mutex<(Vec<Option<Arc<IsoSection>>>, u64)>,
}

impl<B> std::fmt::Debug for LazyPack<B> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("LazyPack")
            .field("isos", &self.index.isos.iter().map(|e| e.iso).collect::<Vec<_>>())
            .field("version", &if self.whole.is_some() { "older" } else { "current" })
            .finish()
    }
}

impl<B: std::ops::Deref<Target = [u8]>> LazyPack<B> {
    /// Opens a pack file of any version this noisecal reads: the index and the pack-level fields
    /// are checked now (a file cut short, damaged or of an unknown version is refused here, with
    /// [`ModelPack::from_bytes`]'s messages); each ISO when it is decoded.
    pub fn open(bytes: B) -> Result<Self, CodecError> {
        let b: &[u8] = &bytes;
        let version = codec::sealed_version(WHAT, PACK_MAGIC, PACK_MAGIC_TEXT, PACK_VERSION_MIN..=PACK_VERSION, b)?;
        if version != PACK_VERSION {
            let whole = ModelPack::from_bytes(b)?;
            let index = PackIndex::of(&whole);
            let n = index.isos.len();
            return Ok(Self {
                bytes,
                index,
                sections: Vec::new(),
                whole: Some(whole),
                decoded: Mutex::new((vec![None; n], 0)),
            });
        }
        let (_, head, rest) = codec::decode_sealed_head(WHAT, PACK_MAGIC, PACK_MAGIC_TEXT, version..=version, b)?;
        let (index, ranges) = compact::read_index(head, rest)?;
        let start = b.len() - rest.len();
        let sections = ranges.into_iter().map(|r| r.start + start..r.end + start).collect();
        index.empty_pack().check()?;
        let n = index.isos.len();
        Ok(Self { bytes, index, sections, whole: None, decoded: Mutex::new((vec![None; n], 0)) })
    }

    /// The pack-level fields and the ISO list.
    pub fn index(&self) -> &PackIndex {
        &self.index
    }

    /// The file's bytes when it is of the current version (what writing its pack again gives),
    /// `None` for an older one.
    pub fn current_bytes(&self) -> Option<&[u8]> {
        self.whole.is_none().then_some(&*self.bytes)
    }

    /// A pack holding the ISOs of `isos` that the file has (others are left out), with their
    /// structured components, each decoded on first use; checked as [`ModelPack::from_bytes`]
    /// checks a whole pack.
    pub fn pack_with(&self, isos: &[u32]) -> Result<ModelPack, CodecError> {
        let mut pack = self.index.empty_pack();
        if let Some(whole) = &self.whole {
            pack.isos = whole.isos.iter().filter(|m| isos.contains(&m.iso)).cloned().collect();
            pack.structure = whole.structure.iter().filter(|s| isos.contains(&s.iso)).cloned().collect();
            return Ok(pack);
        }
        for (i, entry) in self.index.isos.iter().enumerate() {
            if !isos.contains(&entry.iso) {
                continue;
            }
            let section = self.section(i)?;
            pack.isos.push(section.0.clone());
            pack.structure.extend(section.1.clone());
        }
        pack.check()?;
        Ok(pack)
    }

    /// Every ISO of the pack (what [`ModelPack::from_bytes`] gives).
    pub fn to_pack(&self) -> Result<ModelPack, CodecError> {
        match &self.whole {
            Some(whole) => Ok(whole.clone()),
            None => self.pack_with(&self.index.isos.iter().map(|e| e.iso).collect::<Vec<_>>()),
        }
    }

    /// The fields of `iso`'s model with no bins (gain ratios, code lattice, output range: what
    /// an interpolation's plan reads of a calibrated ISO besides its law) and its structured
    /// components, from one read of its section without decoding its weights unless the ISO is
    /// decoded already; `None` when the file has no such ISO. Not kept, and not counted as
    /// decoded ([`Self::decoded_isos`]).
    pub fn fields_of(&self, iso: u32) -> Result<Option<IsoSection>, CodecError> {
        let without_bins = |m: &IsoModel| IsoModel { positions: Vec::new(), ..m.clone() };
        if let Some(whole) = &self.whole {
            return Ok(whole
                .isos
                .iter()
                .find(|m| m.iso == iso)
                .map(|m| (without_bins(m), whole.structure_of(iso).cloned())));
        }
        let Some(i) = self.index.isos.iter().position(|e| e.iso == iso) else {
            return Ok(None);
        };
        if let Some(s) = self.decoded.lock().unwrap_or_else(|p| p.into_inner()).0[i].clone() {
            return Ok(Some((without_bins(&s.0), s.1.clone())));
        }
        let (m, st) = compact::decode_section_fields(&self.index.isos[i], &self.bytes[self.sections[i].clone()])?;
        Ok(Some((IsoModel { positions: Vec::new(), ..m }, st)))
    }

    /// The ISOs decoded so far (all of them for a file of an older version).
    pub fn decoded_isos(&self) -> Vec<u32> {
        if self.whole.is_some() {
            return self.index.isos.iter().map(|e| e.iso).collect();
        }
        let decoded = self.decoded.lock().unwrap_or_else(|p| p.into_inner());
        self.index.isos.iter().zip(decoded.0.iter()).filter(|(_, d)| d.is_some()).map(|(e, _)| e.iso).collect()
    }

    /// Section `i`, decoded now or earlier.
    fn section(&self, i: usize) -> Result<Arc<IsoSection>, CodecError> {
        let before = {
            let decoded = self.decoded.lock().unwrap_or_else(|p| p.into_inner());
            if let Some(s) = decoded.0[i].clone() {
                return Ok(s);
            }
            decoded.1
        };
        // Decoded outside the lock (see the module docs).
        let mut cells = before;
        let s =
            Arc::new(compact::decode_section(&self.index.isos[i], &self.bytes[self.sections[i].clone()], &mut cells)?);
        let mut decoded = self.decoded.lock().unwrap_or_else(|p| p.into_inner());
        if decoded.0[i].is_none() {
            decoded.1 = decoded.1.saturating_add(cells - before);
        }
        Ok(decoded.0[i].get_or_insert(s).clone())
    }
}
