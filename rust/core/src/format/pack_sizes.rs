//! Where a pack file's bytes go: each part of the pack encoded and deflated on its own (the PMF
//! weights as the pack file codes them ([`super::weight_stream`]), the estimator's reports, the structured
//! components, the bins' other fields, the rest), for `inspect` and the size measurements.
//! Parts deflated apart sum to a little more than the file (each pays its own deflate header and
//! cannot borrow from the others).

use crate::error::CodecError;
use crate::format::codec;
use crate::format::weight_stream::encode_iso;
use crate::model::pack::ModelPack;

/// One part of a pack: its name, its bytes before and after deflate.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PartSize {
    pub name: &'static str,
    pub raw: usize,
    pub deflated: usize,
}

const WHAT: &str = "model pack";

fn part(name: &'static str, raw: Vec<u8>) -> PartSize {
    PartSize { name, raw: raw.len(), deflated: miniz_oxide::deflate::compress_to_vec(&raw, 9).len() }
}

/// The parts of `pack` (in its stored form, [`ModelPack::compacted`]) as the current pack
/// version writes them.
pub fn part_sizes(pack: &ModelPack) -> Result<Vec<PartSize>, CodecError> {
    let stored = pack.compacted();
    let mut weights = Vec::new();
    for m in &stored.isos {
        encode_iso(m, &mut weights)?;
    }
    let mut rest = stored.clone();
    let mut reports = Vec::new();
    let mut bins = Vec::new();
    for m in rest.isos.iter_mut() {
        for p in m.positions.iter_mut() {
            reports.push(p.estimate.take());
            for b in p.bins.iter_mut() {
                b.counts = Vec::new();
                bins.push((b.first, b.samples, b.source, b.measured, b.clipped));
            }
        }
    }
    let structure = std::mem::take(&mut rest.structure);
    rest.isos.iter_mut().for_each(|m| m.positions.iter_mut().for_each(|p| p.bins.clear()));
    Ok(vec![
        part("PMF weights", weights),
        part("estimator reports", codec::encode_payload(WHAT, &reports)?),
        part("bins' other fields", codec::encode_payload(WHAT, &bins)?),
        part("structured components", codec::encode_payload(WHAT, &structure)?),
        part("layout, ISOs, warnings", codec::encode_payload(WHAT, &rest)?),
    ])
}
