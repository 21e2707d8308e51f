//! A folder of DNGs (any order, any names) grouped into EV steps by the settings their metadata
//! reports, never by file name (method.md, "Grouping"): reference frames (the lowest ISO) whose
//! exposures agree up to the rounding devices show are one step, and each target frame joins the
//! step whose ISO × exposure matches its own ([`StepKey`]), or is left out with a warning that
//! names it.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use anyhow::bail;
use noisecal_core::calibrate::step::{STEP_TOLERANCE, StepKey};
use noisecal_core::model::NoiseProfile;
use noisecal_core::{CfaPattern, FrameMeta, POSITIONS, SensorLayout};
use rayon::prelude::*;

use crate::dng::{self, DngImage};

/// Reference exposures within this relative distance are one setting: the rounding a device
/// shows in the exposure it reports for one requested setting (well below the 1 % that
/// separates neighbouring settings of a dense sweep).
const EXPOSURE_ROUNDING: f64 = 0.005;

/// A target frame joins its nearest step only when that step is at least this many times
/// nearer (in ISO × exposure) than the next one; otherwise it is ambiguous and left out.
const STEP_MARGIN: f64 = 3.0;

/// One DNG frame known by its metadata.
#[derive(Debug, Clone)]
pub struct DngFrame {
    pub path: PathBuf,
    pub meta: FrameMeta,
}

/// One EV step of a DNG capture set.
#[derive(Debug, Clone)]
pub struct DngStep {
    /// The reference ISO and the burst's (median) exposure.
    pub key: StepKey,
    pub reference: Vec<DngFrame>,
    /// Sorted by ISO, then file name.
    pub targets: Vec<DngFrame>,
}

/// A folder of DNGs, grouped.
#[derive(Debug, Clone)]
pub struct DngSet {
    pub layout: SensorLayout,
    pub make: String,
    pub model: String,
    pub reference_iso: u32,
    pub steps: Vec<DngStep>,
    /// The camera's NoiseProfile per ISO, mapped to CFA positions.
    pub noise_profiles: BTreeMap<u32, NoiseProfile>,
    /// What grouping noticed (steps without a reference burst, …).
    pub warnings: Vec<String>,
    /// Frames in no EV step (matching no reference burst, or a "reference burst" without
    /// targets): dark frames among them are used as such, recognised by their content
    /// ([`noisecal_core::calibrate::dark::check_dark`]); sorted by ISO, then file name.
    pub dark_candidates: Vec<DngFrame>,
}

impl DngSet {
    pub fn frames(&self) -> usize {
        self.steps.iter().map(|s| s.reference.len() + s.targets.len()).sum::<usize>() + self.dark_candidates.len()
    }

    /// Target ISOs present.
    pub fn target_isos(&self) -> Vec<u32> {
        let mut v: Vec<u32> = self.steps.iter().flat_map(|s| s.targets.iter().map(|f| f.meta.iso)).collect();
        v.sort_unstable();
        v.dedup();
        v
    }
}

/// Maps a DNG NoiseProfile (one pair, or one per colour plane R, G, B, or one per CFA position)
/// to CFA positions.
pub fn noise_profile_per_position(np: &[(f64, f64)], cfa: CfaPattern) -> Option<NoiseProfile> {
    use noisecal_core::model::layout::CfaColor;
    match np.len() {
        1 => Some(NoiseProfile([[np[0].0, np[0].1]; POSITIONS])),
        3 => Some(NoiseProfile(std::array::from_fn(|p| {
            let i = match cfa.colors()[p] {
                CfaColor::Red => 0,
                CfaColor::Green => 1,
                CfaColor::Blue => 2,
            };
            [np[i].0, np[i].1]
        }))),
        4 => Some(NoiseProfile(std::array::from_fn(|p| [np[p].0, np[p].1]))),
        _ => None,
    }
}

/// Reads the metadata of every DNG in `dir` (in parallel) and groups them into EV steps.
/// `reference_iso` overrides the lowest ISO found.
pub fn scan_dng_set(dir: &Path, reference_iso: Option<u32>) -> anyhow::Result<DngSet> {
    let paths = dng::scan_folder(dir)?;
    if paths.is_empty() {
        bail!("{} holds no .dng files: point at the folder of a capture session's DNGs", dir.display());
    }
    let heads: Vec<DngImage> = paths.par_iter().map(|p| dng::read_dng_meta(p)).collect::<Result<_, _>>()?;
    group_dngs(heads, reference_iso, dir)
}

fn group_dngs(mut heads: Vec<DngImage>, reference_iso: Option<u32>, dir: &Path) -> anyhow::Result<DngSet> {
    let iso_notes = snap_isos(&mut heads);
    let first = &heads[0];
    let base = first.layout.clone();
    for h in &heads {
        if h.layout.width != base.width || h.layout.height != base.height || h.layout.cfa != base.cfa {
            bail!(
                "{} is {}×{} {} but {} is {}×{} {}: a capture set must come from one sensor mode",
                h.source.display(),
                h.layout.width,
                h.layout.height,
                h.layout.cfa,
                first.source.display(),
                base.width,
                base.height,
                base.cfa
            );
        }
        if h.layout.white != base.white {
            bail!(
                "{} has white level {} but {} has {}: mixed bit depths in one capture set",
                h.source.display(),
                h.layout.white,
                first.source.display(),
                base.white
            );
        }
    }
    let min_iso = heads.iter().map(|h| h.meta.iso).min().unwrap_or(0);
    let reference_iso = reference_iso.unwrap_or(min_iso);
    if min_iso < reference_iso {
        bail!(
            "frames at ISO {min_iso} are below the reference ISO {reference_iso}: the reference must be the lowest ISO"
        );
    }
    let mut noise_profiles = BTreeMap::new();
    for h in &heads {
        if let Some(np) = h.noise_profile.as_deref().and_then(|np| noise_profile_per_position(np, base.cfa)) {
            noise_profiles.entry(h.meta.iso).or_insert(np);
        }
    }
    // Layout black: the median of the reference frames' black levels (each frame keeps its own).
    let mut layout = base.clone();
    let mut refs: Vec<&DngImage> = heads.iter().filter(|h| h.meta.iso == reference_iso).collect();
    if refs.is_empty() {
        bail!(
            "no frame at the reference ISO {reference_iso}: every EV step needs a reference burst at the lowest ISO (missing reference burst)"
        );
    }
    refs.sort_by(|a, b| a.source.cmp(&b.source));
    for p in 0..POSITIONS {
        let mut v: Vec<f32> = refs.iter().map(|h| h.meta.black.unwrap_or(h.layout.black)[p]).collect();
        v.sort_by(|a, b| a.total_cmp(b));
        layout.black[p] = v[v.len() / 2];
    }
    let make = first.make.clone();
    let model = first.model.clone();

    let frames: Vec<DngFrame> = heads
        .into_iter()
        .map(|h| DngFrame {
            meta: FrameMeta { black: h.meta.black.or(Some(h.layout.black)), ..h.meta },
            path: h.source,
        })
        .collect();
    let (mut references, targets): (Vec<DngFrame>, Vec<DngFrame>) =
        frames.into_iter().partition(|f| f.meta.iso == reference_iso);
    let mut warnings = iso_notes;
    // Reference frames: one step per reported exposure (up to the device's rounding).
    references.sort_by(|a, b| a.meta.exposure_ns.cmp(&b.meta.exposure_ns).then(a.path.cmp(&b.path)));
    let mut clusters: Vec<Vec<DngFrame>> = Vec::new();
    for f in references {
        match clusters.last_mut() {
            Some(c) if f.meta.exposure_ns as f64 <= c[0].meta.exposure_ns as f64 * (1.0 + EXPOSURE_ROUNDING) => {
                c.push(f)
            }
            _ => clusters.push(vec![f]),
        }
    }
    let mut steps: Vec<DngStep> = clusters
        .into_iter()
        .map(|mut reference| {
            reference.sort_by(|a, b| a.path.cmp(&b.path));
            let mut exps: Vec<u64> = reference.iter().map(|f| f.meta.exposure_ns).collect();
            exps.sort_unstable();
            DngStep { key: StepKey::new(reference_iso, exps[exps.len() / 2]), reference, targets: Vec::new() }
        })
        .collect();
    // Target frames: the step whose ISO × exposure matches.
    let mut unmatched: Vec<String> = Vec::new();
    let mut dark_candidates: Vec<DngFrame> = Vec::new();
    let mut ambiguous: Vec<String> = Vec::new();
    for f in targets {
        let mut d: Vec<(f64, usize)> = steps.iter().enumerate().map(|(i, s)| (s.key.offset(&f.meta), i)).collect();
        d.sort_by(|x, y| x.0.total_cmp(&y.0));
        match d.as_slice() {
            [(r1, i), rest @ ..] if steps[*i].key.check(&f.meta, STEP_TOLERANCE).is_ok() => {
                if rest.first().is_some_and(|(r2, _)| *r1 * STEP_MARGIN > *r2) {
                    ambiguous.push(format!("{} (ISO {} × {} ns)", f.path.display(), f.meta.iso, f.meta.exposure_ns));
                } else {
                    steps[*i].targets.push(f);
                }
            }
            [(r1, i), ..] => {
                unmatched.push(format!(
                    "{} (ISO {} × {} ns = {:.4} ISO·s; nearest reference step {:.4}, off {:.1} %)",
                    f.path.display(),
                    f.meta.iso,
                    f.meta.exposure_ns,
                    f.meta.brightness(),
                    steps[*i].key.brightness(),
                    r1 * 100.0
                ));
                dark_candidates.push(f);
            }
            [] => {
                unmatched.push(format!("{} (no reference burst at all)", f.path.display()));
                dark_candidates.push(f);
            }
        }
    }
    let list = |v: &[String]| {
        let mut s = v.iter().take(8).cloned().collect::<Vec<_>>().join("; ");
        if v.len() > 8 {
            s.push_str(&format!("; … and {} more", v.len() - 8));
        }
        s
    };
    if !unmatched.is_empty() {
        warnings.push(format!(
            "{} target frame(s) match no reference burst within {:.0} % in ISO × exposure and are left out unless they are dark frames (lens covered, told by their content; otherwise capture a reference burst at ISO {reference_iso} with the same ISO × exposure): {}",
            unmatched.len(),
            STEP_TOLERANCE * 100.0,
            list(&unmatched)
        ));
    }
    if !ambiguous.is_empty() {
        warnings.push(format!(
            "{} target frame(s) lie between two reference steps and are left out (their ISO × exposure is not clearly nearer one of them): {}",
            ambiguous.len(),
            list(&ambiguous)
        ));
    }
    for s in &mut steps {
        s.targets.sort_by(|a, b| a.meta.iso.cmp(&b.meta.iso).then(a.path.cmp(&b.path)));
        if s.targets.is_empty() {
            warnings.push(format!(
                "EV step with reference exposure {} ns has no target frames: it adds nothing (unless its frames are dark frames, lens covered, told by their content)",
                s.key.reference_exposure_ns
            ));
            dark_candidates.append(&mut s.reference);
        }
    }
    steps.retain(|s| !s.targets.is_empty());
    dark_candidates.sort_by(|a, b| a.meta.iso.cmp(&b.meta.iso).then(a.path.cmp(&b.path)));
    if steps.iter().all(|s| s.targets.is_empty()) {
        bail!(
            "{}: no EV step has both a reference burst (ISO {reference_iso}) and target frames at a higher ISO",
            dir.display()
        );
    }
    Ok(DngSet { layout, make, model, reference_iso, steps, noise_profiles, warnings, dark_candidates })
}

/// ISOs within this factor of each other are one setting reported with rounding (some devices
/// report 98 or 101 for a requested 100); nominal ISOs are at least 1/3 stop (×1.26) apart.
const ISO_FACTOR: f64 = 1.04;

/// Gives frames whose reported ISOs differ only by rounding the ISO most of them report, and says
/// so: one model per real setting, not one per rounding.
fn snap_isos(heads: &mut [DngImage]) -> Vec<String> {
    let mut counts: BTreeMap<u32, usize> = BTreeMap::new();
    for h in heads.iter() {
        *counts.entry(h.meta.iso).or_default() += 1;
    }
    let mut clusters: Vec<Vec<(u32, usize)>> = Vec::new();
    for (&iso, &n) in &counts {
        match clusters.last_mut() {
            Some(c) if iso as f64 <= c[0].0 as f64 * ISO_FACTOR => c.push((iso, n)),
            _ => clusters.push(vec![(iso, n)]),
        }
    }
    let mut map = BTreeMap::new();
    let mut notes = Vec::new();
    for c in clusters.iter().filter(|c| c.len() > 1) {
        // Most frames wins; a tie goes to the lower ISO.
        let Some(&(to, _)) = c.iter().max_by(|a, b| a.1.cmp(&b.1).then(b.0.cmp(&a.0))) else { continue };
        let names: Vec<String> = c.iter().map(|(i, n)| format!("{i} ({n} frames)")).collect();
        notes.push(format!("ISOs {} are one setting reported with rounding: all used as ISO {to}", names.join(", ")));
        for &(from, _) in c {
            map.insert(from, to);
        }
    }
    for h in heads.iter_mut() {
        if let Some(&to) = map.get(&h.meta.iso) {
            h.meta.iso = to;
        }
    }
    notes
}

#[cfg(test)]
mod tests {
    use super::*;
    use noisecal_core::{CfaPattern, FrameMeta, SensorLayout};

    fn head(name: &str, iso: u32, exposure_ns: u64) -> DngImage {
        let layout = SensorLayout { width: 8, height: 8, cfa: CfaPattern::Rggb, black: [64.0; 4], white: 1023 };
        DngImage {
            meta: FrameMeta { iso, exposure_ns, black: Some(layout.black) },
            layout,
            pixels: ndarray::Array2::zeros((0, 0)),
            make: "m".into(),
            model: "p".into(),
            noise_profile: None,
            bits_per_sample: 16,
            color: Default::default(),
            source: PathBuf::from(name),
        }
    }

    #[test]
    fn rounded_isos_are_one_setting_and_steps_follow_brightness() {
        let mut heads = Vec::new();
        for (i, (iso, exp)) in [(50, 8_000_000), (50, 8_000_000), (200, 2_000_000), (201, 2_000_000), (200, 2_000_000)]
            .into_iter()
            .enumerate()
        {
            heads.push(head(&format!("a{i}.dng"), iso, exp));
        }
        // A second EV step, shuffled names, one frame reported at ISO 49.
        for (i, (iso, exp)) in
            [(800, 1_000_000), (50, 16_000_000), (49, 16_000_000), (800, 1_000_000)].into_iter().enumerate()
        {
            heads.push(head(&format!("z{i}.dng"), iso, exp));
        }
        let set = group_dngs(heads, None, Path::new("x")).unwrap();
        assert_eq!(set.reference_iso, 50);
        assert_eq!(set.steps.len(), 2);
        assert_eq!(set.target_isos(), vec![200, 800]);
        assert_eq!(set.steps[0].reference.len(), 2);
        assert_eq!(set.steps[0].targets.len(), 3);
        assert_eq!(set.steps[1].reference.len(), 2);
        assert!(set.warnings.iter().any(|w| w.contains("used as ISO 200")), "{:?}", set.warnings);
        assert!(set.warnings.iter().any(|w| w.contains("used as ISO 50")), "{:?}", set.warnings);
        // 1/3-stop ISOs stay apart.
        let heads = vec![head("a", 100, 8_000_000), head("b", 125, 6_400_000), head("c", 160, 5_000_000)];
        let mut h = heads;
        assert!(snap_isos(&mut h).is_empty());
    }

    #[test]
    fn a_dense_sweep_keeps_settings_one_percent_apart() {
        // 41 settings 1 % apart, each a 3-frame reference at ISO 100 and one target at ISO 400
        // (reported with the rounding of a real device: ±0.1 % on the exposure).
        let mut heads = Vec::new();
        for k in 0..41u64 {
            let e = (10_000_000.0 * 1.01f64.powi(k as i32)).round() as u64;
            for r in 0..3 {
                heads.push(head(&format!("r{k:02}_{r}.dng"), 100, e + r));
            }
            let jitter = if k % 2 == 0 { 1.001 } else { 0.999 };
            heads.push(head(&format!("t{k:02}.dng"), 400, (e as f64 / 4.0 * jitter).round() as u64));
        }
        let set = group_dngs(heads, None, Path::new("x")).unwrap();
        assert_eq!(set.steps.len(), 41, "{:?}", set.warnings);
        for (k, s) in set.steps.iter().enumerate() {
            assert_eq!(s.reference.len(), 3);
            assert_eq!(s.targets.len(), 1);
            assert_eq!(s.targets[0].path, PathBuf::from(format!("t{k:02}.dng")));
        }
    }

    #[test]
    fn targets_that_match_no_step_or_two_are_named_and_left_out() {
        let heads = vec![
            head("ra.dng", 100, 10_000_000),
            head("rb.dng", 100, 10_200_000),
            head("ok.dng", 400, 2_500_000),
            // 1 % from both reference steps: ambiguous.
            head("between.dng", 400, 2_525_000),
            // 20 % off everything: another setting, or the exposure did not apply.
            head("stray.dng", 400, 3_000_000),
        ];
        let set = group_dngs(heads, None, Path::new("x")).unwrap();
        // The second reference burst has no targets: its frame, and the stray one, are offered
        // as dark frames (their content decides); the ambiguous one is left out.
        assert_eq!(set.steps.len(), 1);
        assert_eq!(set.steps[0].targets.len(), 1);
        let dark: Vec<_> = set.dark_candidates.iter().map(|f| f.path.to_str().unwrap()).collect();
        assert_eq!(dark, ["rb.dng", "stray.dng"]);
        let w = set.warnings.join("\n");
        assert!(w.contains("between.dng") && w.contains("lie between two reference steps"), "{w}");
        assert!(w.contains("stray.dng") && w.contains("match no reference burst"), "{w}");
    }
}
