//! The report's "Structured noise" section, end to end through the binary:
//!
//! - `simulate --structured` (row noise, frame offsets, DSNU), `calibrate`, `report`: the section
//!   has the SD-vs-ISO chart and, for every ISO, one chart per component (rows, columns, frame
//!   offsets); its table and the chart's filled (added) and open (below detection) marks agree
//!   with `inspect --json`, the row and frame components are added where the simulated sensor
//!   has them well above detection, and the columns (which it lacks) are not;
//! - a sensor without any structured component: the section says none are added, and nothing
//!   is marked added; a pack without components at all says none were calibrated.

use std::path::Path;

use noisecal_cli::simulate::SimSession;
use noisecal_core::ModelPack;
use noisecal_sim::SensorModel;
use serde_json::Value;

mod support;

const ISOS: [u32; 3] = [100, 400, 1600];

/// Runs the binary; panics with its stderr when it fails. Returns stdout.
fn noisecal(args: &[&str]) -> String {
    let out = support::run(std::iter::once("-q").chain(args.iter().copied()));
    assert!(out.ok, "noisecal {args:?} failed: {}", out.stderr);
    out.stdout
}

fn s(p: &Path) -> &str {
    p.to_str().expect("UTF-8 path")
}

/// Calibrates `dngs` into a pack, reports it; returns the pack path, the report's structured
/// section and `inspect --json`.
fn calibrate_and_report(dir: &Path, dngs: &Path, name: &str) -> (std::path::PathBuf, String, Value) {
    let pack = dir.join(format!("{name}.pack"));
    let html = dir.join(format!("{name}.html"));
    noisecal(&["calibrate", s(dngs), "-o", s(&pack)]);
    noisecal(&["report", "--pack", s(&pack), "-o", s(&html)]);
    let inspect: Value = serde_json::from_str(&noisecal(&["inspect", s(&pack), "--json"])).expect("inspect JSON");
    let html = std::fs::read_to_string(&html).expect("read report");
    (pack, section(&html, "structure"), inspect)
}

/// The text of the `<h2 id="…">` section `id`, up to the next `<h2`.
fn section(html: &str, id: &str) -> String {
    let start = html.find(&format!("<h2 id=\"{id}\">")).unwrap_or_else(|| panic!("no section {id}"));
    let rest = &html[start + 4..];
    rest[..rest.find("<h2").unwrap_or(rest.len())].to_string()
}

/// The SVG documents of a piece of HTML, in order.
fn svgs(html: &str) -> Vec<&str> {
    html.match_indices("<svg").map(|(i, _)| &html[i..i + html[i..].find("</svg>").expect("closed <svg>")]).collect()
}

/// The circles of an SVG: `true` for filled, `false` for open (`fill="none"`).
fn circles(svg: &str) -> Vec<bool> {
    svg.match_indices("<circle")
        .map(|(i, _)| !svg[i..i + svg[i..].find("/>").expect("closed")].contains("fill=\"none\""))
        .collect()
}

/// One component in `inspect --json`: (SD formatted as the report shows it, added).
fn component(v: &Value) -> Option<(String, bool)> {
    if v.is_null() {
        return None;
    }
    let sd = v["sd"].as_f64().expect("sd");
    Some((format!("{sd:.3}"), v["added"].as_bool().expect("added")))
}

/// Per ISO: its components, each `(text, added)` or `None` when the pack has none.
type IsoComponents = Vec<(u32, Vec<Option<(String, bool)>>)>;

/// Per ISO of `inspect --json` with structure: the 8 components in the report's order (rows
/// even, odd; columns even, odd; frame offset per position).
fn inspect_components(inspect: &Value) -> IsoComponents {
    inspect["isos"]
        .as_array()
        .expect("isos")
        .iter()
        .filter(|i| !i["structure"].is_null())
        .map(|i| {
            let st = &i["structure"];
            let mut c: Vec<Option<(String, bool)>> = Vec::new();
            c.extend(st["rows"].as_array().expect("rows").iter().map(component));
            c.extend(st["columns"].as_array().expect("columns").iter().map(component));
            match st["frames"].as_array() {
                Some(f) => c.extend(f.iter().map(component)),
                None => c.extend([None, None, None, None]),
            }
            (i["iso"].as_u64().expect("iso") as u32, c)
        })
        .collect()
}

/// The table row of `iso` in the section: each cell as (text without `*`, added), `None` for "—".
fn table_row(sec: &str, iso: u32) -> Vec<Option<(String, bool)>> {
    let start = sec.find(&format!("<tr data-iso=\"{iso}\">")).unwrap_or_else(|| panic!("no table row for ISO {iso}"));
    let row = &sec[start..start + sec[start..].find("</tr>").expect("closed row")];
    let cells: Vec<&str> = row.split("<td").skip(2).take(8).collect();
    assert_eq!(cells.len(), 8, "ISO {iso}: {row}");
    cells
        .iter()
        .map(|c| {
            let class_added = c.starts_with(" class=\"added\"");
            let text = c.split('>').nth(1).and_then(|t| t.split('<').next()).expect("cell text");
            if text == "—" {
                return None;
            }
            assert_eq!(class_added, text.ends_with('*'), "ISO {iso}: class and * disagree in {c}");
            Some((text.trim_end_matches('*').to_string(), class_added))
        })
        .collect()
}

/// What every ISO's part of the section must hold, checked against `inspect --json`; returns
/// the inspected components.
fn check_against_inspect(sec: &str, inspect: &Value) -> IsoComponents {
    let comps = inspect_components(inspect);
    assert_eq!(comps.iter().map(|c| c.0).collect::<Vec<_>>(), ISOS, "inspect lists structure for every ISO");
    let all = svgs(sec);
    let sd_chart = all.first().expect("the SD-vs-ISO chart");
    assert!(sd_chart.contains("standard deviation per ISO"), "the section opens with the SD chart");
    // Its marks: one per measured component and ISO, filled exactly where inspect says added.
    let marks = circles(sd_chart);
    let measured: Vec<bool> = comps.iter().flat_map(|(_, c)| c.iter().flatten().map(|c| c.1)).collect();
    assert_eq!(marks.len(), measured.len(), "one mark per component and ISO");
    assert_eq!(
        marks.iter().filter(|f| **f).count(),
        measured.iter().filter(|a| **a).count(),
        "filled marks = components inspect marks added"
    );
    for (iso, c) in &comps {
        assert_eq!(&table_row(sec, *iso), c, "ISO {iso}: the report's table differs from inspect --json");
        // One chart per component kind under the ISO's heading.
        let h = sec.find(&format!("<h3>ISO {iso}")).unwrap_or_else(|| panic!("no heading for ISO {iso}"));
        let part = &sec[h + 3..];
        let part = &part[..part.find("<h3>").unwrap_or(part.len())];
        let charts = svgs(part);
        assert_eq!(charts.len(), 3, "ISO {iso}: rows, columns and frame offsets, each an SVG");
        for (chart, title) in charts.iter().zip(["Row offsets", "Column offsets", "Frame offsets"]) {
            assert!(chart.contains(&format!("{title}, ISO {iso}")), "ISO {iso}: expected the {title} chart");
        }
    }
    assert_eq!(all.len(), 1 + 3 * ISOS.len(), "SD chart plus three per ISO");
    comps
}

#[test]
fn structured_sensor_components_per_iso_agree_with_inspect() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dngs = dir.path().join("dngs");
    let isos = ISOS.map(|i| i.to_string()).join(",");
    noisecal(&[
        "simulate",
        "--structured",
        "--width",
        "256",
        "--height",
        "192",
        "--frames",
        "8",
        "--isos",
        &isos,
        "--ev=-4,-2,0,2,4",
        "--dngs",
        s(&dngs),
    ]);
    let (_, sec, inspect) = calibrate_and_report(dir.path(), &dngs, "structured");
    assert!(sec.contains("Structured noise"));
    let comps = check_against_inspect(&sec, &inspect);
    let added = |iso: u32, range: std::ops::Range<usize>| {
        comps.iter().find(|c| c.0 == iso).expect("ISO").1[range].iter().all(|c| c.as_ref().is_some_and(|c| c.1))
    };
    // Row noise of phone10 --structured: 0.2 e⁻ + 0.088 DN, ≈ 1.6 DN at ISO 1600 — far above
    // detection there; frame offsets 0.4 e⁻ + 0.28 DN, ≥ 0.34 DN at every ISO.
    assert!(added(1600, 0..2), "row offsets must be added at ISO 1600: {:?}", comps);
    for iso in ISOS {
        assert!(added(iso, 4..8), "frame offsets must be added at ISO {iso}: {comps:?}");
        let cols = &comps.iter().find(|c| c.0 == iso).expect("ISO").1[2..4];
        assert!(cols.iter().flatten().all(|c| !c.1), "no column noise was simulated, yet ISO {iso} adds some");
    }
    assert!(
        sec.contains("Added at synthesis: row offsets at ISO") && sec.contains("frame offsets at ISO 100, 400, 1600")
    );
    assert!(!sec.contains("none are added"), "the structured sensor's section says none are added");
}

#[test]
fn sensor_without_structured_noise_adds_none() {
    let dir = tempfile::tempdir().expect("tempdir");
    let dngs = dir.path().join("dngs");
    // The phone10 preset without --structured still has row noise; this sensor has none at all.
    let mut model = SensorModel::phone_10bit();
    (model.row_noise_pre_e, model.row_noise_post_dn) = (0.0, 0.0);
    assert!(!model.has_structured_noise());
    let session =
        SimSession::new(model, "plain", 256, 192, 3, ISOS.to_vec(), 8, vec![-4, -2, 0, 2, 4]).expect("session");
    session.write(Some(&dngs), None, 0, || {}).expect("write DNGs");
    let (pack_path, sec, inspect) = calibrate_and_report(dir.path(), &dngs, "plain");
    let comps = check_against_inspect(&sec, &inspect);
    assert!(comps.iter().all(|(_, c)| c.iter().flatten().all(|c| !c.1)), "inspect adds a component: {comps:?}");
    assert!(sec.contains("none are added at synthesis"), "the section must say none are added");
    assert!(!sec.contains("class=\"added\"") && !sec.contains("Added at synthesis:"));
    assert!(!circles(svgs(&sec)[0]).iter().any(|f| *f), "a filled (added) mark on the SD chart");

    // The same pack with its structured components removed: none were calibrated, no charts.
    let mut pack = ModelPack::from_bytes(&std::fs::read(&pack_path).expect("read pack")).expect("pack");
    assert!(!pack.structure.is_empty());
    pack.structure.clear();
    let bare = dir.path().join("bare.pack");
    std::fs::write(&bare, pack.to_bytes().expect("bytes")).expect("write pack");
    let html = dir.path().join("bare.html");
    noisecal(&["report", "--pack", s(&bare), "-o", s(&html)]);
    let sec = section(&std::fs::read_to_string(&html).expect("read report"), "structure");
    assert!(sec.contains("No structured components calibrated"), "{sec}");
    assert_eq!(svgs(&sec).len(), 0, "charts without components");
}
