//! Where a `noisecal.Pack`'s models come from: a pack file's bytes read on demand (`Pack.load`,
//! `Pack.from_bytes`, a pickled pack in a DataLoader worker: the index when loaded, each ISO the
//! first time a sampler needs it), or a pack already in memory (`noisecal.calibrate`,
//! `Pack.interp`).
//!
//! Thread-safe and safe in a forked child: no lock is held while anything is decoded (the core's
//! [`LazyPack`] keeps decoded ISOs the same way, and the whole pack below is decoded outside its
//! lock and kept under a short one), so a process forked while another thread decodes finds no
//! lock held by a thread it does not have.

use std::sync::{Arc, Mutex};

use noisecal_core::ModelPack;
use noisecal_core::format::lazy_pack::LazyPack;
use noisecal_core::model::structure::Components;
use noisecal_core::resolve::{ModelKind, Resolved, resolve_model, resolve_on_demand};
use pyo3::PyResult;

use crate::errors::{err, to_py};

/// A pack's models, decoded on demand or already in memory.
#[derive(Debug)]
pub(crate) struct PackSource {
    /// The pack's fields (sensor layout, make, model, bins, warnings) without its ISOs.
    pub(crate) fields: ModelPack,
    isos: Vec<u32>,
    calibrated: Vec<u32>,
    /// The file, when the pack was read from one.
    file: Option<LazyPack<Vec<u8>>>,
    /// Every ISO, once something asked for all of them (at once for a pack made in memory).
    whole: Mutex<Option<Arc<ModelPack>>>,
}

impl PackSource {
    /// A pack made in memory.
    pub(crate) fn decoded(pack: ModelPack) -> Self {
        Self {
            fields: pack.fields_only(),
            isos: pack.iso_list(),
            calibrated: pack.calibrated_isos(),
            file: None,
            whole: Mutex::new(Some(Arc::new(pack))),
        }
    }

    /// A pack file opened to be read on demand.
    pub(crate) fn on_demand(file: LazyPack<Vec<u8>>) -> Self {
        let index = file.index();
        Self {
            fields: index.empty_pack(),
            isos: index.isos.iter().map(|e| e.iso).collect(),
            calibrated: index.isos.iter().filter(|e| e.is_calibrated()).map(|e| e.iso).collect(),
            file: Some(file),
            whole: Mutex::new(None),
        }
    }

    /// Every ISO the pack holds, ascending.
    pub(crate) fn isos(&self) -> &[u32] {
        &self.isos
    }

    /// The calibrated ISOs, ascending.
    pub(crate) fn calibrated_isos(&self) -> &[u32] {
        &self.calibrated
    }

    /// The whole pack (every ISO decoded, once).
    pub(crate) fn whole(&self) -> PyResult<Arc<ModelPack>> {
        if let Some(p) = self.whole.lock().map_err(|_| err("a pack's models were poisoned"))?.clone() {
            return Ok(p);
        }
        let file = self.file.as_ref().ok_or_else(|| err("a pack made in memory lost its models"))?;
        let pack = Arc::new(file.to_pack().map_err(|e| err(format!("cannot load the model pack: {e}")))?);
        let mut slot = self.whole.lock().map_err(|_| err("a pack's models were poisoned"))?;
        Ok(slot.get_or_insert(pack).clone())
    }

    /// The model of `kind` at `iso` and the pack of the ISOs it and its sampler with the
    /// components `which` stand on (from a file: only those are decoded).
    pub(crate) fn resolve(
        &self,
        iso: u32,
        kind: ModelKind,
        which: Components,
        extrapolate: bool,
    ) -> PyResult<(Arc<ModelPack>, Resolved)> {
        let whole = self.whole.lock().map_err(|_| err("a pack's models were poisoned"))?.clone();
        match (&self.file, whole) {
            (Some(file), None) => {
                let (pack, resolved) = resolve_on_demand(file, iso, kind, which, extrapolate).map_err(|e| match e {
                    noisecal_core::Error::Codec(c) => err(format!("cannot load the model pack: {c}")),
                    other => to_py(other),
                })?;
                Ok((Arc::new(pack), resolved))
            }
            (_, whole) => {
                let pack = match whole {
                    Some(p) => p,
                    None => self.whole()?,
                };
                let resolved = resolve_model(&pack, iso, kind, extrapolate).map_err(to_py)?;
                Ok((pack, resolved))
            }
        }
    }

    /// The pack as a file of the current version: a file's own bytes when it is one.
    pub(crate) fn to_bytes(&self) -> PyResult<Vec<u8>> {
        if let Some(b) = self.file.as_ref().and_then(|f| f.current_bytes()) {
            return Ok(b.to_vec());
        }
        self.whole()?.to_bytes().map_err(to_py)
    }
}
