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

/// The components derived for `iso` from the calibrated ISOs' (ignoring any stored for `iso`).
pub fn derived_structure(pack: &ModelPack, iso: u32) -> Option<IsoStructure> {
    let measured: Vec<&IsoStructure> =
        pack.structure.iter().filter(|s| pack.iso(s.iso).is_some_and(|m| m.is_calibrated())).collect();
    let first = *measured.first()?;
    let last = *measured.last()?;
    if let Some(s) = measured.iter().find(|s| s.iso == iso) {
        return Some((*s).clone());
    }
    let ln = |i: u32| (i.max(1) as f64).ln();
    if iso < first.iso || iso > last.iso {
        let near = if iso < first.iso { first } else { last };
        let slope = if last.iso > first.iso {
            let (a, b) = (total_sd(first), total_sd(last));
            if a > 0.0 && b > 0.0 { ((b / a).ln() / (ln(last.iso) - ln(first.iso))).clamp(0.0, 1.0) } else { 1.0 }
        } else {
            1.0
        };
        let k = (iso.max(1) as f64 / near.iso as f64).powf(slope);
        return Some(near.scaled(iso, k));
    }
    let above = measured.iter().position(|s| s.iso > iso)?;
    let (a, b) = (measured[above - 1], measured[above]);
    let t = (ln(iso) - ln(a.iso)) / (ln(b.iso) - ln(a.iso));
    Some(IsoStructure::blend(iso, a, b, t))
}

/// The standard deviation of all components together (rows, columns and frame, averaged over
/// parities and positions).
fn total_sd(s: &IsoStructure) -> f64 {
    let lines: f64 = s.rows.iter().chain(&s.columns).flatten().map(|d| d.variance()).sum::<f64>() / 2.0;
    let frame = s.frames.as_ref().map_or(0.0, |f| (0..4).map(|p| f.variance(p)).sum::<f64>() / 4.0);
    (lines + frame).sqrt()
}
