//! `noisecal report`: one self-contained HTML file, a plot in every plotting section, no external
//! references, and the evaluation tables when asked.

mod support;

use std::path::Path;

use noisecal_cli::cmd::report::run;
use noisecal_cli::simulate::SimSession;
use noisecal_input::calibrate::{CalibrateOptions, calibrate_path};
use noisecal_sim::SensorModel;

fn simulate(dir: &Path, seed: u64, frames: u32) {
    let s = SimSession::new(
        SensorModel::phone_10bit(),
        "sim",
        160,
        120,
        seed,
        vec![100, 400, 800],
        frames,
        vec![-4, -1, 2],
    )
    .expect("simulated session");
    s.write(Some(dir), None, 0, || {}).expect("write DNGs");
}

/// The text of each `<h2 id=…>` section, by id.
fn sections(html: &str) -> Vec<(String, String)> {
    html.split("<h2 id=\"")
        .skip(1)
        .map(|s| {
            let id = s.split('"').next().unwrap_or_default().to_string();
            (id, s.to_string())
        })
        .collect()
}

fn assert_self_contained(html: &str) {
    let stripped = html.replace("xmlns=\"http://www.w3.org/2000/svg\"", "");
    for bad in ["http://", "https://", "<script", "<link", "src=", "url(", "@import", "<img", "<iframe"] {
        assert!(!stripped.contains(bad), "the report has an external reference or script: {bad}");
    }
}

#[test]
fn report_with_eval_is_one_self_contained_page() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (cal, held) = (dir.path().join("cal"), dir.path().join("held"));
    simulate(&cal, 21, 4);
    simulate(&held, 22, 2);
    let (pack, _) = calibrate_path(&cal, &CalibrateOptions::default(), &mut |_, _| {}).expect("calibrate");
    let pack_path = dir.path().join("p.pack");
    std::fs::write(&pack_path, pack.to_bytes().expect("bytes")).expect("write pack");

    // Without an evaluation.
    let plain = dir.path().join("plain.html");
    run(support::report_args(&pack_path, None, None, &plain), true).expect("report");
    let html = std::fs::read_to_string(&plain).expect("read report");
    assert!(html.starts_with("<!DOCTYPE html>") && html.trim_end().ends_with("</html>"));
    assert_self_contained(&html);
    let secs = sections(&html);
    let ids: Vec<&str> = secs.iter().map(|(i, _)| i.as_str()).collect();
    assert_eq!(ids, ["sensor", "levels", "pmfs", "coverage", "gain", "structure", "warnings"]);
    for (id, body) in &secs {
        let svgs = body.matches("<svg").count();
        let want = match id.as_str() {
            "levels" => 8,
            "pmfs" => 4,
            "coverage" => 4,
            "gain" => 1,
            _ => 0,
        };
        assert!(svgs >= want, "section {id} has {svgs} plots, expected at least {want}");
        assert_eq!(body.matches("<svg").count(), body.matches("</svg>").count(), "section {id}: unbalanced <svg>");
    }
    // Every calibrated ISO appears in the gain table and the legend of the variance plots.
    for iso in [100, 400, 800] {
        assert!(html.contains(&format!("ISO {iso}")), "ISO {iso} missing");
    }

    // With an evaluation (run in-process on held-out captures), plus leave-one-out.
    let full = dir.path().join("full.html");
    run(
        {
            let mut a = support::report_args(&pack_path, Some(held.clone()), None, &full);
            a.scoring.leave_one_out = true;
            a.scoring.renoise_from = Some(400);
            a.scoring.to = Some(800);
            a
        },
        true,
    )
    .expect("report with eval");
    let html = std::fs::read_to_string(&full).expect("read report");
    assert_self_contained(&html);
    let secs = sections(&html);
    let (_, ev) = secs.iter().find(|(i, _)| i == "eval").expect("fidelity section");
    // Bars per ISO, leave-one-out bars, renoise bars; tables name every model and method.
    assert!(ev.matches("<svg").count() >= 3, "fidelity section plots");
    for needle in ["noisecal", "hg", "pg", "floor", "Leave-one-out", "bridge", "naive", "ISO 400 → 800"] {
        assert!(ev.contains(needle), "fidelity section lacks {needle}");
    }
    // The JSD table carries numbers in [0, ln 2].
    let first_row = ev.split("<tr class=\"best\">").nth(1).expect("a best row");
    let cells: Vec<f64> = first_row.split("<td>").skip(1).filter_map(|c| c.split('<').next()?.parse().ok()).collect();
    assert!(!cells.is_empty() && cells.iter().all(|v| (0.0..=std::f64::consts::LN_2).contains(v)), "{cells:?}");

    // A bad --eval path is a clear error.
    let err = run(support::report_args(&pack_path, Some(dir.path().join("nope")), None, &full), true)
        .expect_err("missing held-out set");
    assert!(format!("{err:#}").contains("nope"), "{err:#}");
}
