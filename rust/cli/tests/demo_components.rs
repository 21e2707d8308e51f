//! The demo's structured components against its pixel noise alone, scored by `noisecal eval` on
//! the held-out set `noisecal demo` writes beside its pack (`demo/heldout/`).
//!
//! Known truth: the demo's sensor has row noise (one offset per row and frame) and nothing else
//! structured, and the held-out set is the same sensor with fresh noise. The default components
//! must score at least as well as pixel-only on every per-pixel score below white and on the
//! row-mean variance; the same pack with its structured components deliberately doubled (4× the
//! variance) must score worse than the pack on the row-mean variance, which is where a wrong
//! component shows, and worse than pixel-only where both row parities carry row noise. The per-pixel scores cannot see the doubling on this sensor: synthesis takes
//! the components' variance out of the pixel PMFs (deconvolution), so a pixel's marginal keeps
//! its variance whatever the components, and the row variance is ≤ 0.4 % of a pixel's.
//!
//! The level group that reaches white (clipped pixels) is asserted at every ISO. Synthesis with
//! row offsets had moved the clamp's pile below white there (JSD up to 0.66 at ISO 3200 against
//! 0.004 for pixel-only; fixed by `spread_pile_start` in `noisecal_core::synth::structure`, and
//! for bins too narrow to deconvolve by `clamp_end` in `deconvolve_bin_within`). Since the
//! reference's saturated pixels leave the flat set (the full-well rule), that group holds no
//! saturated pixels: 640 real samples per ISO (596 R, 44 B), pixels below white whose noise
//! reaches it. ISO 100, which lost there before (0.0033 against 0.0006 with the saturated
//! pixels in), now scores 0.067 against pixel-only's 0.070; synthesized on flat clean images at
//! 1010–1023 DN the two agree at every ISO (share at white within 0.002, about one standard
//! error of that check; variance within 0.3 %). The marginal JSD, which pools that group, is
//! printed only.
//!
//! **No longer asserted here:** since the saturation rule's margin is the stated 2 noise SDs (it
//! was about 0.5), the held-out set keeps no flat pixel in the group that reaches white: both
//! models scored 0 there and a check at white could not fail, so it is gone (the group's score is
//! printed). What it guarded is asserted with known truth elsewhere: a clean level at white reads
//! white as the sensor does, and one code below it keeps the law's draw
//! (`rust/core/tests/synth_at_white.rs`); the clamp's pile under row offsets stays on white
//! (`a_pile_narrower_than_the_kernel_stays_at_the_clip` and its neighbours in
//! `rust/core/src/synth/tests_structure.rs`). The highest populated
//! group, 960–992 DN (1 076 real samples per ISO), scored ISO 100 0.0885 against pixel-only's
//! 0.0888, ISO 200 0.1038 / 0.1147, ISO 400 0.1277 / 0.1191 (one run of 2 seeds; one seed's
//! score of a group this size moves by up to 0.008 against another's): not asserted.

mod support;

use noisecal_cli::eval::{EvalReport, IsoEval, ModelScore};
use noisecal_core::ModelPack;
use std::path::Path;

/// The conditional JSD over the level groups below the one that reaches white, weighted by
/// their real samples as the overall conditional is; and the group at white.
fn below_and_at_white(m: &ModelScore, white: f32) -> (f64, f64) {
    let (mut below, mut at) = ((0.0, 0.0), (0.0, 0.0));
    for g in &m.groups {
        let acc = if g.hi > white { &mut at } else { &mut below };
        acc.0 += g.jsd * g.real_samples as f64;
        acc.1 += g.real_samples as f64;
    }
    (below.0 / below.1, if at.1 > 0.0 { at.0 / at.1 } else { 0.0 })
}

/// The JSD of the darkest level group of each position (R, Gr, Gb, B), where the default
/// components lost to pixel-only before the narrowing met its variance.
fn darkest(m: &ModelScore) -> [f64; 4] {
    std::array::from_fn(|pos| {
        m.groups.iter().filter(|g| g.pos == pos).min_by(|a, b| a.lo.total_cmp(&b.lo)).map_or(f64::NAN, |g| g.jsd)
    })
}

fn model<'a>(iso: &'a IsoEval, name: &str) -> &'a ModelScore {
    iso.model(name).unwrap_or_else(|| panic!("ISO {}: no {name} row", iso.iso))
}

/// The row-mean variance ratio of `name` at `iso` and its standard error.
fn row_ratio(iso: &IsoEval, name: &str) -> (f64, f64) {
    let s = iso.spatial.as_ref().expect("spatial scores");
    let m = s.models.iter().find(|m| m.name == name).unwrap_or_else(|| panic!("ISO {}: no spatial {name}", iso.iso));
    (m.scores.row_var_ratio.expect("row ratio"), m.scores.row_var_ratio_se.expect("row ratio SE"))
}

fn eval(pack: &Path, heldout: &Path, json: &Path) -> EvalReport {
    let r = support::run_quiet([
        "eval".as_ref(),
        "--pack".as_ref(),
        pack.as_os_str(),
        heldout.as_os_str(),
        "--seeds".as_ref(),
        "2".as_ref(),
        "--json".as_ref(),
        json.as_os_str(),
    ]);
    assert!(r.ok, "eval failed: {}", r.stderr);
    serde_json::from_slice(&std::fs::read(json).expect("eval JSON")).expect("eval JSON parses")
}

#[test]
fn the_demos_components_beat_pixel_only_and_doubled_ones_do_not() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("demo");
    let r = support::run_quiet(["demo".as_ref(), "--out".as_ref(), out.as_os_str()]);
    assert!(r.ok, "demo failed: {}", r.stderr);
    let (pack_path, heldout) = (out.join("demo.pack"), out.join("heldout"));
    assert!(heldout.join("f00000.dng").is_file(), "the demo wrote no held-out set");

    // The same pack with every structured component at twice its amplitude.
    let pack = ModelPack::from_bytes(&std::fs::read(&pack_path).expect("pack")).expect("pack parses");
    let white = f32::from(pack.layout.white);
    let mut doubled = pack.clone();
    doubled.structure = pack.structure.iter().map(|s| s.scaled(s.iso, 2.0)).collect();
    let doubled_path = dir.path().join("doubled.pack");
    std::fs::write(&doubled_path, doubled.to_bytes().expect("encode")).expect("write doubled pack");
    let with_rows: Vec<u32> =
        pack.structure.iter().filter(|s| s.row(0).is_some() || s.row(1).is_some()).map(|s| s.iso).collect();
    assert!(with_rows.len() >= 4, "the demo's pack adds row noise at ISOs {with_rows:?} only");
    let both_parities: Vec<u32> =
        pack.structure.iter().filter(|s| s.row(0).is_some() && s.row(1).is_some()).map(|s| s.iso).collect();
    assert!(both_parities.len() >= 3, "the demo's pack adds row noise to both parities at ISOs {both_parities:?} only");

    let real = eval(&pack_path, &heldout, &dir.path().join("real.json"));
    let wrong = eval(&doubled_path, &heldout, &dir.path().join("doubled.json"));
    assert_eq!(real.isos.len(), 6, "every ISO of the demo is scored");
    for (iso, dbl) in real.isos.iter().zip(&wrong.isos) {
        let (nc, px) = (model(iso, "noisecal"), model(iso, "noisecal-pixel"));
        let ((nc_below, nc_white), (px_below, px_white)) =
            (below_and_at_white(nc, white), below_and_at_white(px, white));
        let ((nc_row, nc_se), (px_row, px_se), (dbl_row, dbl_se)) =
            (row_ratio(iso, "noisecal"), row_ratio(iso, "noisecal-pixel"), row_ratio(dbl, "noisecal"));
        eprintln!(
            "ISO {:>4}: conditional {:.5} / pixel {:.5}, below white {nc_below:.5} / {px_below:.5}; at white {nc_white:.4} / {px_white:.4}; marginal {:.5} / {:.5}; darkest group {:.5?} / {:.5?}; row-mean variance ratio {nc_row:.3} ± {nc_se:.3} / pixel {px_row:.3} ± {px_se:.3} / doubled {dbl_row:.3} ± {dbl_se:.3}",
            iso.iso,
            nc.conditional_overall,
            px.conditional_overall,
            nc.marginal_overall,
            px.marginal_overall,
            darkest(nc),
            darkest(px)
        );
        // Below white: the same pixel PMFs, so the two differ by their synthetic sampling only
        // (seeds differ by about 10⁻⁴ here): 5 % and 2·10⁻⁴ of slack.
        assert!(
            nc_below <= 1.05 * px_below + 2e-4,
            "ISO {}: with its components the pack scores {nc_below:.4} below white, pixel-only {px_below:.4}",
            iso.iso
        );
        // At ISO 100–200 overall, conditional and marginal: the darkest bins (a PMF a few DN wide,
        // the row kernel 9 % of its variance) are narrowed alone, and the narrowing's re-binning
        // lost 3 % of their variance and thinned their tails; with it, ISO 100 scored 0.00132 /
        // 0.00024 against pixel-only's 0.00125 / 0.00020 and ISO 200 0.00136 / 0.00013 against
        // 0.00132 / 0.00012 (3 seeds; conditional 1.056× and 1.03×). Now 0.00125 / 0.00021
        // against 0.00125 / 0.00020, and 0.00133 / 0.00012 against 0.00132 / 0.00012 (2 seeds,
        // printed to 5 digits): 2 % of slack on the conditional, 3·10⁻⁵ on the marginal.
        if iso.iso <= 200 {
            assert!(
                nc.conditional_overall <= 1.02 * px.conditional_overall
                    && nc.marginal_overall <= px.marginal_overall + 3e-5,
                "ISO {}: with its components the pack scores {:.5} / {:.5}, pixel-only {:.5} / {:.5}",
                iso.iso,
                nc.conditional_overall,
                nc.marginal_overall,
                px.conditional_overall,
                px.marginal_overall
            );
        }
        // The darkest level group of every position: at ISO 3200 (black's clamp within 2.3 noise
        // SDs) the pile a bin pools over its levels was read from its end cells, kept in place or
        // moved inward, and R scored 0.00040 against pixel-only's 0.00028 (4 seeds); with the
        // pile known from the floor, 0.00019 / 0.00028, and at most 1.07× pixel-only elsewhere
        // (ISO 100 R, 0.00031 / 0.00029). 10 % and 3·10⁻⁵ of slack for the 2 seeds here.
        for (pos, (d, p)) in darkest(nc).iter().zip(darkest(px)).enumerate() {
            assert!(
                *d <= 1.1 * p + 3e-5,
                "ISO {}, position {pos}: the darkest group scores {d:.5} with the components, {p:.5} without",
                iso.iso
            );
        }
        // Closer to the real row-mean variance than pixel-only, within two standard errors.
        let (nc_off, px_off, dbl_off) = (nc_row.ln().abs(), px_row.ln().abs(), dbl_row.ln().abs());
        assert!(
            nc_off <= px_off + 2.0 * nc_se / nc_row,
            "ISO {}: row-mean variance ratio {nc_row:.3} with the components, {px_row:.3} without",
            iso.iso
        );
        // The doubled pack is judged against the same real frames, so the real set's share of
        // the standard errors is common to both ratios: one SE of slack is conservative.
        if with_rows.contains(&iso.iso) {
            assert!(
                dbl_off > nc_off + dbl_se / dbl_row,
                "ISO {}: doubled components give a row-mean variance ratio {dbl_row:.3}, no worse than the pack's {nc_row:.3}",
                iso.iso
            );
        }
        // Where both row parities carry row noise, doubling it is worse than leaving it out. (Where
        // only one does, as at ISO 200, the doubling adds 3× a half-image component and lands
        // about as far above 1 as pixel-only lands below it.)
        if both_parities.contains(&iso.iso) {
            assert!(
                dbl_off > px_off + dbl_se / dbl_row,
                "ISO {}: doubled components give a row-mean variance ratio {dbl_row:.3}, no worse than pixel-only's {px_row:.3}",
                iso.iso
            );
        }
    }
}
