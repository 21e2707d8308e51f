//! Structured components at an ISO the pack has none for: between two calibrated ISOs, their
//! distributions blended in log ISO (quantile functions averaged pointwise, the displacement
//! interpolation); beyond them, the nearest one scaled along the trend of the components'
//! standard deviation over the calibrated ISOs (clamped to grow no faster than the gain).

use crate::model::pack::ModelPack;
use crate::model::structure::IsoStructure;

/// The components for `iso`: the pack's own, else derived from its calibrated ISOs.
pub fn structure_at(pack: &ModelPack, iso: u32) -> Option<IsoStructure> {
    if let Some(s) = pack.structure_of(iso) {
        return Some(s.clone());
    }
    derived_structure(pack, iso)
}

/// Which calibrated ISOs' components [`derived_structure`] reads, and how.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Sources {
    /// This ISO's own.
    Own(u32),
    /// The nearest end of the calibrated ones, scaled along the trend between the first and the
    /// last.
    Beyond { near: u32, first: u32, last: u32 },
    /// The two calibrated ISOs around it, blended.
    Between(u32, u32),
}

/// How `iso`'s components come from `measured` (the calibrated ISOs that have components,
/// ascending); `None` when there are none.
fn sources(measured: &[u32], iso: u32) -> Option<Sources> {
    let (&first, &last) = (measured.first()?, measured.last()?);
    if measured.contains(&iso) {
        return Some(Sources::Own(iso));
    }
    if iso < first || iso > last {
        return Some(Sources::Beyond { near: if iso < first { first } else { last }, first, last });
    }
    let above = measured.iter().position(|&k| k > iso)?;
    Some(Sources::Between(measured[above - 1], measured[above]))
}

/// The calibrated ISOs whose components [`derived_structure`] reads for `iso`, of `measured`
/// (the calibrated ISOs that have components, ascending): what a pack read on demand must decode
/// to derive them.
pub fn derived_structure_sources(measured: &[u32], iso: u32) -> Vec<u32> {
    match sources(measured, iso) {
        None => Vec::new(),
        Some(Sources::Own(k)) => vec![k],
        Some(Sources::Beyond { first, last, .. }) => vec![first, last],
        Some(Sources::Between(a, b)) => vec![a, b],
    }
}

/// The components derived for `iso` from the calibrated ISOs' (ignoring any stored for `iso`).
pub fn derived_structure(pack: &ModelPack, iso: u32) -> Option<IsoStructure> {
    let measured: Vec<&IsoStructure> =
        pack.structure.iter().filter(|s| pack.iso(s.iso).is_some_and(|m| m.is_calibrated())).collect();
    let isos: Vec<u32> = measured.iter().map(|s| s.iso).collect();
    let of = |k: u32| measured.iter().find(|s| s.iso == k).copied();
    let ln = |i: u32| (i.max(1) as f64).ln();
    match sources(&isos, iso)? {
        Sources::Own(k) => of(k).cloned(),
        Sources::Beyond { near, first, last } => {
            let (near, first, last) = (of(near)?, of(first)?, of(last)?);
            let slope = if last.iso > first.iso {
                let (a, b) = (total_sd(first), total_sd(last));
                if a > 0.0 && b > 0.0 { ((b / a).ln() / (ln(last.iso) - ln(first.iso))).clamp(0.0, 1.0) } else { 1.0 }
            } else {
                1.0
            };
            let k = (iso.max(1) as f64 / near.iso as f64).powf(slope);
            Some(near.scaled(iso, k))
        }
        Sources::Between(a, b) => {
            let (a, b) = (of(a)?, of(b)?);
            let t = (ln(iso) - ln(a.iso)) / (ln(b.iso) - ln(a.iso));
            Some(IsoStructure::blend(iso, a, b, t))
        }
    }
}

/// The standard deviation of all components together (rows, columns and frame, averaged over
/// parities and positions).
fn total_sd(s: &IsoStructure) -> f64 {
    let lines: f64 = s.rows.iter().chain(&s.columns).flatten().map(|d| d.variance()).sum::<f64>() / 2.0;
    let frame = s.frames.as_ref().map_or(0.0, |f| (0..4).map(|p| f.variance(p)).sum::<f64>() / 4.0);
    (lines + frame).sqrt()
}
