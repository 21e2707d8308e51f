//! `noisecal report --bench results.json`: the denoiser benchmark's section shows the JSON's
//! numbers (table, controls) with its chart, a JSON of another kind is a clear error, and without
//! `--bench` the page is the page it was, byte for byte.

mod support;

use std::path::{Path, PathBuf};

use noisecal_cli::cmd::report::run;
use noisecal_cli::simulate::SimSession;
use noisecal_input::calibrate::{CalibrateOptions, calibrate_path};
use noisecal_sim::SensorModel;

fn pack(dir: &Path) -> PathBuf {
    let cal = dir.join("cal");
    let s = SimSession::new(SensorModel::phone_10bit(), "sim", 96, 64, 5, vec![100, 400], 4, vec![-2, 1])
        .expect("simulated session");
    s.write(Some(&cal), None, 0, || {}).expect("write DNGs");
    let (pack, _) = calibrate_path(&cal, &CalibrateOptions::default(), &mut |_, _| {}).expect("calibrate");
    let path = dir.join("p.pack");
    std::fs::write(&path, pack.to_bytes().expect("bytes")).expect("write pack");
    path
}

fn report(pack: &Path, bench: Option<PathBuf>, out: &Path) -> anyhow::Result<String> {
    run(support::report_args(pack, None, bench, out), true)?;
    Ok(std::fs::read_to_string(out).expect("read report"))
}

/// A benchmark result as `noisecal-bench --json` writes it (the fields the section reads, and
/// others it must ignore), with numbers that appear nowhere else in a report.
const RESULTS: &str = r#"{
 "config": {"packs": {"p.pack": "00"}, "eval": "/x", "train": "generated:4", "steps": 321, "batch": 12,
            "crop": 40, "width": 14, "lr": 0.003, "realizations": 2, "data_seed": 1, "device": "cpu"},
 "input": {"400": {"psnr": 31.0123, "ssim": 0.80123,
                   "bands": {"dark": {"psnr": 35.4321, "ssim": 0.9, "fraction": 0.5}, "bright": {"psnr": 22.9876, "ssim": 0.9, "fraction": 0.1}}}},
 "isos": [400], "calibrated_isos": [100, 400], "seeds": [0, 1],
 "networks": [{"model": "hg"}, {"model": "hg"}, {"model": "noisecal"}, {"model": "noisecal"}, {"model": "wrong"}, {"model": "wrong"}],
 "summary": [
  {"model": "noisecal", "kind": "noisecal", "iso": 400, "psnr": {"mean": 33.4567, "std": 0.1234, "n": 2},
   "ssim": {"mean": 0.87654, "std": 0.00123}, "bands": {"dark": {"mean": 38.7654, "std": 0.0456}},
   "delta_hg": {"mean": 0.2468, "std": 0.0135}},
  {"model": "hg", "kind": "hg", "iso": 400, "psnr": {"mean": 33.2099, "std": 0.1111}, "ssim": {"mean": 0.87001, "std": 0.00222}, "bands": {}},
  {"model": "wrong", "kind": "wrong", "iso": 400, "psnr": {"mean": 32.1357, "std": 0.0999}, "ssim": {"mean": 0.85001, "std": 0.00333},
   "bands": {}, "delta_hg": {"mean": -1.0742, "std": 0.0864}}
 ],
 "wall_seconds": 754.0,
 "controls": {"400": {"spread_db": 0.1234, "wrong_worst": true, "wrong_margin_db": 1.0742, "wrong_clear": true}},
 "headroom": {"400": {"linear_db": 0.0123, "guided_db": 6.4321}}
}"#;

#[test]
fn bench_section_shows_the_json_and_leaves_the_rest_unchanged() {
    let dir = tempfile::tempdir().expect("tempdir");
    let pack = pack(dir.path());
    let json = dir.path().join("bench.json");
    std::fs::write(&json, RESULTS).expect("write results");
    let without = report(&pack, None, &dir.path().join("a.html")).expect("report");
    let with = report(&pack, Some(json.clone()), &dir.path().join("b.html")).expect("report with bench");

    let at = with.find("<h2 id=\"bench\">").expect("a bench section");
    let section = &with[at..with.find("<p class=\"sub\" style=\"margin-top:40px\">").expect("footer")];
    for shown in [
        "33.46±0.12",                                              // noisecal PSNR mean ± spread
        "0.8765±0.0012",                                           // its SSIM
        "0.25±0.01",                                               // Δ HG
        "38.77±0.05",                                              // its dark band
        "33.21±0.11",                                              // hg
        "-1.07±0.09",                                              // wrong's Δ HG
        "31.01",                                                   // the noisy input
        "35.43",                                                   // … its dark band
        "22.99",                                                   // … its bright band
        "6 networks, 321 steps each, batch 12, crop 40, width 14", // the run
        "12.6 min",
        "ISO 400: wrong worst: yes, clearly (by 1.07 dB)",
        "ISO 400, verdict: the controls ordered as expected",
        "PSNR gain over the noisy input",
        // The headroom line, with the warning its numbers call for (linear < 0.05, guided > 1 dB).
        "ISO 400: best linear 5×5 filter +0.01 dB, clean-guided flat filter +6.43 dB over the noisy input: only an edge-aware filter",
    ] {
        assert!(section.contains(shown), "the bench section lacks {shown:?}:\n{section}");
    }
    assert!(section.contains(&format!("<code>{}</code>", json.display())), "the section names its file");
    // The best row is marked, and it is noisecal's.
    let best = section.split("<tr class=\"best\">").nth(1).expect("a best row");
    assert!(best.starts_with("<td class=\"l\">noisecal</td>"), "{best}");
    // The chart: one SVG with a bar per row (3 models) plus their whiskers, and the ISO label.
    assert_eq!(section.matches("<svg").count(), 1);
    let svg = &section[section.find("<svg").unwrap()..section.find("</svg>").unwrap()];
    assert!(svg.contains("ISO 400") && svg.contains("noisecal") && svg.contains("wrong"));

    // Without --bench, the page is the page with the section and its link taken out, byte for byte.
    let nav = "<a href=\"#bench\">Denoiser benchmark</a>";
    assert_eq!(with.matches(nav).count(), 1);
    assert_eq!(with.replacen(section, "", 1).replacen(nav, "", 1), without);
    assert!(!without.contains("id=\"bench\""));

    // Another kind of JSON (noisecal eval's), or an empty run, is refused by name.
    std::fs::write(&json, r#"{"isos": [], "heldout": "x"}"#).expect("write");
    let err = report(&pack, Some(json.clone()), &dir.path().join("c.html")).expect_err("not a bench JSON");
    assert!(format!("{err:#}").contains("is not the JSON of `noisecal-bench --json`"), "{err:#}");
    let empty = RESULTS.replace(
        &RESULTS[RESULTS.find("\"summary\"").unwrap()..RESULTS.find("\"wall_seconds\"").unwrap()],
        "\"summary\": [],\n ",
    );
    std::fs::write(&json, empty).expect("write");
    let err = report(&pack, Some(json.clone()), &dir.path().join("c.html")).expect_err("empty summary");
    assert!(format!("{err:#}").contains("holds no benchmark rows"), "{err:#}");
    assert!(!dir.path().join("c.html").exists(), "nothing is written on an error");
}

#[test]
fn the_paired_wrong_control_renders() {
    // A JSON with the paired test's fields: the wrong model clearly below HG (the row it is judged
    // against) but not last on the means, a pack row below it. The control held, the verdict says
    // so and names the row below the control; the earlier "wrong worst: yes, clearly" would
    // misread it.
    let dir = tempfile::tempdir().expect("tempdir");
    let pack = pack(dir.path());
    let json = dir.path().join("bench.json");
    let controls = r#""controls": {"400": {"spread_db": 0.1234, "wrong_worst": false, "wrong_margin_db": -0.25,
        "wrong_clear": true, "wrong_judged_against": ["hg"], "wrong_not_below": ["noisecal"], "failed": []}},"#;
    let at = RESULTS.find("\"controls\"").expect("controls");
    let end = at + RESULTS[at..].find("\n").expect("line end");
    std::fs::write(&json, format!("{}{controls}{}", &RESULTS[..at], &RESULTS[end..])).expect("write");
    let html = report(&pack, Some(json), &dir.path().join("p.html")).expect("report");
    for shown in [
        "ISO 400: wrong below hg: yes, clearly (paired test over the seeds); wrong worst on the means: no",
        "ISO 400, verdict: the controls ordered as expected: the benchmark tells models apart on this data; not clearly above the wrong control: noisecal",
    ] {
        assert!(html.contains(shown), "the report lacks {shown:?}");
    }
    assert!(!html.contains("wrong worst: yes"));
}

#[test]
fn the_committed_bench_results_render() {
    // A real run's JSON (docs/bench-results/random3.json): every summary row's PSNR shows.
    let dir = tempfile::tempdir().expect("tempdir");
    let pack = pack(dir.path());
    let json = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/bench-results/random3.json");
    let html = report(&pack, Some(json.clone()), &dir.path().join("r.html")).expect("report");
    let results: serde_json::Value = serde_json::from_slice(&std::fs::read(&json).unwrap()).unwrap();
    let rows = results["summary"].as_array().expect("summary");
    assert!(rows.len() >= 4);
    for r in rows {
        let (m, s) = (r["psnr"]["mean"].as_f64().unwrap(), r["psnr"]["std"].as_f64().unwrap());
        let cell = format!("<td>{m:.2}±{s:.2}</td>");
        assert!(html.contains(&cell), "row {} lacks {cell}", r["model"]);
    }
    assert!(html.contains("ISO 500: oracle best: within the seed spread"));
    // A run from before the headroom was measured has none: no headroom paragraph.
    assert!(results.get("headroom").is_none() && !html.contains("Headroom (no network)"));
    assert!(html.contains("ISO 500, verdict: the controls ordered as expected"), "random3's controls held");
    // Set 002's run whose controls did not order (a JSON from before `failed`: derived from its
    // fields): the verdict says so and names both.
    let json = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../docs/bench-results/emva002-tiles-controls-1200.json");
    let html = report(&pack, Some(json), &dir.path().join("s.html")).expect("report");
    assert!(
        html.contains("ISO 200, verdict: the controls did NOT order as expected (wrong (HG at ½ its variance) not clearly last; loud (HG at 2× its variance) not below HG at every seed)"),
        "set 002's verdict"
    );
    assert!(html.contains("loud (2× HG variance) below HG: NO"));
}
