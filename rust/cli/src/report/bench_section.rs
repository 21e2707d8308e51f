//! The denoiser benchmark's results (the JSON `noisecal-bench --json` writes) as a report section:
//! per model and ISO the PSNR and SSIM mean ± spread over training seeds, the paired difference to
//! HG and the PSNR per brightness band, the noisy input, the controls, and a chart of each model's
//! PSNR gain over the noisy input, and the headroom (what a filter removes from the evaluation noise
//! without a network). Only the fields shown are read; the rest of the JSON is ignored.

use std::collections::BTreeMap;
use std::fmt::Write;
use std::path::Path;

use anyhow::Context;
use plotters::prelude::*;
use serde::Deserialize;

use super::plots::{FONT, color, err, legend, svg_chart};
use super::{esc, figure};

/// The brightness bands of the benchmark, in its order (by the clean level, share of the range).
const BANDS: [&str; 4] = ["dark", "shadow", "mid", "bright"];

/// A mean and its spread over training seeds.
#[derive(Debug, Clone, Copy, Deserialize)]
pub struct Spread {
    pub mean: f64,
    #[serde(default)]
    pub std: f64,
}

/// One (model, ISO) row of the benchmark's summary.
#[derive(Debug, Clone, Deserialize)]
pub struct BenchRow {
    pub model: String,
    #[serde(default)]
    pub kind: String,
    pub iso: u32,
    pub psnr: Spread,
    pub ssim: Spread,
    #[serde(default)]
    pub bands: BTreeMap<String, Spread>,
    #[serde(default)]
    pub delta_hg: Option<Spread>,
}

#[derive(Debug, Clone, Copy, Deserialize)]
pub struct BandScore {
    pub psnr: f64,
}

/// The noisy evaluation frames' own scores at an ISO.
#[derive(Debug, Clone, Deserialize)]
pub struct InputScore {
    pub psnr: f64,
    pub ssim: f64,
    #[serde(default)]
    pub bands: BTreeMap<String, BandScore>,
}

/// The controls at an ISO (see `noisecal.bench.controls`).
#[derive(Debug, Clone, Default, Deserialize)]
pub struct Controls {
    pub oracle_best: Option<bool>,
    pub oracle_within_spread: Option<bool>,
    pub oracle_gap_db: Option<f64>,
    pub wrong_worst: Option<bool>,
    pub wrong_clear: Option<bool>,
    pub wrong_margin_db: Option<f64>,
    pub loud_below_hg: Option<bool>,
    pub loud_margin_db: Option<f64>,
    /// The rows the wrong model is judged against by the paired test (HG and the oracle; absent
    /// in a JSON from before the paired test, whose `wrong_clear` meant "below every row").
    #[serde(default)]
    pub wrong_judged_against: Option<Vec<String>>,
    /// The rows the paired test does not put clearly above the wrong model.
    #[serde(default)]
    pub wrong_not_below: Option<Vec<String>>,
    /// The controls that did not order as expected, as `noisecal-bench` names them (absent in a
    /// JSON from before the verdict: then derived from the fields above, `Controls::failed`).
    #[serde(default)]
    pub failed: Option<Vec<String>>,
}

impl Controls {
    /// Whether the run had any control row at the ISO.
    fn any(&self) -> bool {
        self.oracle_best.is_some() || self.wrong_worst.is_some() || self.loud_below_hg.is_some()
    }

    /// The rows the paired test does not put clearly above the wrong control although it held
    /// (`noisecal.bench.scoring.rows_below_wrong`).
    fn rows_below_wrong(&self) -> Vec<String> {
        match (&self.wrong_judged_against, &self.wrong_not_below, self.wrong_clear) {
            (Some(judged), Some(rows), Some(true)) => rows.iter().filter(|r| !judged.contains(r)).cloned().collect(),
            _ => Vec::new(),
        }
    }

    /// The controls that did not order: the JSON's list, or the same rule on its fields
    /// (`noisecal.bench.scoring.failed_controls`).
    fn failed(&self) -> Vec<String> {
        if let Some(f) = &self.failed {
            return f.clone();
        }
        let mut out = Vec::new();
        if self.oracle_best == Some(false) && self.oracle_within_spread != Some(true) {
            out.push("oracle not best within the seed spread".to_string());
        }
        if self.wrong_worst.is_some() && self.wrong_clear != Some(true) {
            out.push("wrong (HG at ½ its variance) not clearly last".to_string());
        }
        if self.loud_below_hg == Some(false) {
            out.push("loud (HG at 2× its variance) not below HG at every seed".to_string());
        }
        out
    }
}

/// The evaluation set's headroom at an ISO (see `noisecal.bench.headroom`): the PSNR gain over the
/// noisy input of the best linear 5×5 filter, and of a filter told where the clean image is flat
/// (an oracle: it reads the clean image).
#[derive(Debug, Clone, Copy, Default, Deserialize)]
pub struct Headroom {
    pub linear_db: Option<f64>,
    pub guided_db: Option<f64>,
}

/// Below this gain of the best linear filter, a network starting as the identity may not learn
/// (as `noisecal-bench` warns: `LINEAR_FLOOR_DB` in `noisecal/bench/report.py`).
const LINEAR_FLOOR_DB: f64 = 0.05;

#[derive(Debug, Clone, Deserialize)]
pub struct BenchConfig {
    pub steps: u64,
    pub batch: u64,
    pub crop: u64,
    pub width: u64,
}

/// What the section shows of a `noisecal-bench --json` file.
#[derive(Debug, Clone, Deserialize)]
pub struct BenchResults {
    pub config: BenchConfig,
    pub summary: Vec<BenchRow>,
    /// By ISO (JSON object keys are strings).
    #[serde(default)]
    pub input: BTreeMap<String, InputScore>,
    #[serde(default)]
    pub controls: BTreeMap<String, Controls>,
    #[serde(default)]
    pub seeds: Vec<i64>,
    #[serde(default)]
    pub calibrated_isos: Vec<u32>,
    #[serde(default)]
    pub networks: Vec<serde::de::IgnoredAny>,
    #[serde(default)]
    pub wall_seconds: f64,
    /// By ISO; absent in runs before the headroom was measured.
    #[serde(default)]
    pub headroom: BTreeMap<String, Headroom>,
}

impl BenchResults {
    /// Reads the JSON `noisecal-bench --json` wrote.
    pub fn load(path: &Path) -> anyhow::Result<Self> {
        let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
        let out: Self = serde_json::from_slice(&bytes).with_context(|| {
            format!("{} is not the JSON of `noisecal-bench --json` (give the file its --json wrote)", path.display())
        })?;
        if out.summary.is_empty() {
            anyhow::bail!(
                "{} holds no benchmark rows (its summary is empty): run noisecal-bench to the end",
                path.display()
            );
        }
        Ok(out)
    }

    /// The ISOs in order, each with its rows in the JSON's order.
    fn isos(&self) -> Vec<u32> {
        let mut isos: Vec<u32> = self.summary.iter().map(|r| r.iso).collect();
        isos.sort_unstable();
        isos.dedup();
        isos
    }

    fn input_at(&self, iso: u32) -> Option<&InputScore> {
        self.input.get(&iso.to_string())
    }
}

fn pm(s: &Spread, digits: usize) -> String {
    format!("{:.digits$}±{:.digits$}", s.mean, s.std)
}

/// The section: a paragraph on the run, the chart, the table and the controls.
pub fn bench_section(o: &mut String, b: &BenchResults, source: &str) -> anyhow::Result<()> {
    let _ = write!(o, "<h2 id=\"bench\">Denoiser benchmark</h2>");
    let _ = write!(
        o,
        "<p>From <code>{}</code>: the same small network trained on each model's synthetic noise ({} networks, {} steps each, batch {}, crop {}, width {}; training seeds {:?}; {:.1} min) and scored on real noisy/clean pairs. PSNR and SSIM are the mean ± spread over training seeds; Δ HG is the paired difference to the HG-trained network (same seed, same data); the bands are the PSNR of the pooled error by clean level (dark &lt; 2 % of the range, shadow 2–10 %, mid 10–40 %, bright ≥ 40 %). A network that does not beat the noisy input did not train.</p>",
        esc(source),
        b.networks.len(),
        b.config.steps,
        b.config.batch,
        b.config.crop,
        b.config.width,
        b.seeds,
        b.wall_seconds / 60.0
    );
    let svg = gain_chart(b, (1040, 380))?;
    figure(
        o,
        &svg,
        "PSNR gain of each model's network over the noisy input per ISO (mean over training seeds; the whisker is ± their spread).",
    );
    let _ = write!(
        o,
        "<table><tr><th class=\"l\">model</th><th>ISO</th><th>PSNR dB</th><th>SSIM</th><th>Δ HG dB</th>{}</tr>",
        BANDS.iter().map(|n| format!("<th>{n}</th>")).collect::<String>()
    );
    let calibrated = &b.calibrated_isos;
    for iso in b.isos() {
        let rows: Vec<&BenchRow> = b.summary.iter().filter(|r| r.iso == iso).collect();
        let best = rows.iter().map(|r| r.psnr.mean).fold(f64::NEG_INFINITY, f64::max);
        for r in rows {
            let interp =
                r.model.split(':').next() == Some("noisecal") && !calibrated.is_empty() && !calibrated.contains(&iso);
            let _ = write!(
                o,
                "<tr{}><td class=\"l\">{}{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>",
                if r.psnr.mean == best { " class=\"best\"" } else { "" },
                esc(&r.model),
                if interp { " (interp)" } else { "" },
                iso,
                pm(&r.psnr, 2),
                pm(&r.ssim, 4),
                r.delta_hg.as_ref().map(|d| pm(d, 2)).unwrap_or_default()
            );
            for band in BANDS {
                let _ = write!(o, "<td>{}</td>", r.bands.get(band).map(|s| pm(s, 2)).unwrap_or_default());
            }
            let _ = write!(o, "</tr>");
        }
        if let Some(inp) = b.input_at(iso) {
            let _ = write!(
                o,
                "<tr class=\"floor\"><td class=\"l\">(noisy input)</td><td>{iso}</td><td>{:.2}</td><td>{:.4}</td><td></td>",
                inp.psnr, inp.ssim
            );
            for band in BANDS {
                let _ =
                    write!(o, "<td>{}</td>", inp.bands.get(band).map(|s| format!("{:.2}", s.psnr)).unwrap_or_default());
            }
            let _ = write!(o, "</tr>");
        }
    }
    let _ = write!(o, "</table>");
    controls(o, b);
    headroom(o, b);
    Ok(())
}

/// Per ISO, the headroom line `noisecal-bench` prints under its controls, with its warning.
fn headroom(o: &mut String, b: &BenchResults) {
    let mut items = Vec::new();
    for iso in b.isos() {
        let Some(&Headroom { linear_db: Some(lin), guided_db: Some(guided) }) = b.headroom.get(&iso.to_string()) else {
            continue;
        };
        let warn = if lin < LINEAR_FLOOR_DB && guided > 1.0 {
            ": only an edge-aware filter removes this noise; a row at the noisy input's PSNR did not learn it and ranks nothing"
        } else {
            ""
        };
        items.push(format!(
            "<li>ISO {iso}: best linear 5×5 filter {lin:+.2} dB, clean-guided flat filter {guided:+.2} dB over the noisy input{}</li>",
            esc(warn)
        ));
    }
    if !items.is_empty() {
        let _ = write!(
            o,
            "<p>Headroom (no network): what the best linear filter, and a filter told where the clean image is flat (an oracle), gain over the noisy input on the evaluation pairs:</p><ul>{}</ul>",
            items.concat()
        );
    }
}

/// The controls per ISO, as `noisecal-bench` prints them under its table.
fn controls(o: &mut String, b: &BenchResults) {
    let mut items = Vec::new();
    for iso in b.isos() {
        let Some(c) = b.controls.get(&iso.to_string()) else { continue };
        let mut parts = Vec::new();
        if let (Some(best), Some(gap)) = (c.oracle_best, c.oracle_gap_db) {
            let verdict = if best {
                "yes"
            } else if c.oracle_within_spread == Some(true) {
                "within the seed spread"
            } else {
                "NO"
            };
            parts.push(format!("oracle best: {verdict} (best − oracle {gap:.2} dB)"));
        }
        if let (Some(worst), Some(judged)) = (c.wrong_worst, &c.wrong_judged_against) {
            let verdict = if c.wrong_clear == Some(true) { "yes, clearly" } else { "NOT clearly" };
            let on_means = if worst { "yes" } else { "no" };
            parts.push(format!(
                "wrong below {}: {verdict} (paired test over the seeds); wrong worst on the means: {on_means}",
                judged.join(" and ")
            ));
        } else if let Some(worst) = c.wrong_worst {
            let verdict = match (c.wrong_clear, worst) {
                (Some(true), _) => "yes, clearly",
                (_, true) => "yes, but not clearly",
                _ => "NO",
            };
            let margin = c.wrong_margin_db.map(|m| format!(" (by {m:.2} dB)")).unwrap_or_default();
            parts.push(format!("wrong worst: {verdict}{margin}"));
        }
        if let Some(below) = c.loud_below_hg {
            let verdict = if below { "yes" } else { "NO: the evaluation rewards smoothing, not fidelity" };
            let margin = c.loud_margin_db.map(|m| format!(" (by {m:.2} dB)")).unwrap_or_default();
            parts.push(format!("loud (2× HG variance) below HG: {verdict}{margin}"));
        }
        if !parts.is_empty() {
            items.push(format!("<li>ISO {iso}: {}</li>", esc(&parts.join("; "))));
        }
        if c.any() {
            let failed = c.failed();
            let verdict = if failed.is_empty() {
                let below = c.rows_below_wrong();
                let note = if below.is_empty() {
                    String::new()
                } else {
                    format!("; not clearly above the wrong control: {}", below.join(", "))
                };
                format!("the controls ordered as expected: the benchmark tells models apart on this data{note}")
            } else {
                format!(
                    "the controls did NOT order as expected ({}): the ranking of the other rows is not established on this data",
                    failed.join("; ")
                )
            };
            items.push(format!("<li>ISO {iso}, verdict: {}</li>", esc(&verdict)));
        }
    }
    if !items.is_empty() {
        let _ = write!(
            o,
            "<p>Controls (the oracle — the sensor's own noise, where known — should be best; the wrong model, HG with half its variance, clearly worst):</p><ul>{}</ul>",
            items.concat()
        );
    }
}

/// Grouped bars per ISO: each model's PSNR gain over the noisy input, with ± spread whiskers.
fn gain_chart(b: &BenchResults, size: (u32, u32)) -> anyhow::Result<String> {
    let isos = b.isos();
    let mut models: Vec<&str> = Vec::new();
    for r in &b.summary {
        if !models.contains(&r.model.as_str()) {
            models.push(&r.model);
        }
    }
    // (ISO index, model index, gain, spread)
    let bars: Vec<(usize, usize, f64, f64)> = b
        .summary
        .iter()
        .filter_map(|r| {
            let base = b.input_at(r.iso)?.psnr;
            let gi = isos.iter().position(|&i| i == r.iso)?;
            let mi = models.iter().position(|&m| m == r.model)?;
            Some((gi, mi, r.psnr.mean - base, r.psnr.std))
        })
        .filter(|(_, _, g, s)| g.is_finite() && s.is_finite())
        .collect();
    let hi = bars.iter().map(|&(_, _, g, s)| g + s).fold(0.0f64, f64::max);
    let lo = bars.iter().map(|&(_, _, g, s)| g - s).fold(0.0f64, f64::min);
    let span = (hi - lo).max(0.1);
    let (y0, y1) = (lo - 0.12 * span, hi + 0.45 * span); // room for the ISO labels and the legend
    let ng = isos.len().max(1) as f64;
    let w = 0.8 / models.len().max(1) as f64;
    svg_chart(size, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption("Denoiser PSNR gain over the noisy input per ISO (higher is better)", (FONT, 15))
            .margin(8)
            .x_label_area_size(6)
            .y_label_area_size(60)
            .build_cartesian_2d(0f64..ng, y0..y1)
            .map_err(err)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(0)
            .y_desc("PSNR gain (dB)")
            .y_label_formatter(&|v| format!("{v:.2}"))
            .label_style((FONT, 11))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(err)?;
        for (mi, name) in models.iter().enumerate() {
            let c = color(mi);
            let x = |gi: usize| gi as f64 + 0.1 + mi as f64 * w;
            let mine: Vec<_> = bars.iter().filter(|b| b.1 == mi).collect();
            chart
                .draw_series(
                    mine.iter()
                        .map(|&&(gi, _, g, _)| Rectangle::new([(x(gi), 0.0), (x(gi) + w * 0.92, g)], c.filled())),
                )
                .map_err(err)?
                .label(name.to_string())
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 12, y + 5)], c.filled()));
            chart
                .draw_series(mine.iter().map(|&&(gi, _, g, s)| {
                    let xm = x(gi) + w * 0.46;
                    PathElement::new(vec![(xm, g - s), (xm, g + s)], BLACK.stroke_width(1))
                }))
                .map_err(err)?;
        }
        chart.draw_series(LineSeries::new([(0.0, 0.0), (ng, 0.0)], BLACK.stroke_width(1))).map_err(err)?;
        let style = TextStyle::from((FONT, 13).into_font()).pos(plotters::style::text_anchor::Pos::new(
            plotters::style::text_anchor::HPos::Center,
            plotters::style::text_anchor::VPos::Center,
        ));
        chart
            .draw_series(
                isos.iter().enumerate().map(|(gi, iso)| {
                    Text::new(format!("ISO {iso}"), (gi as f64 + 0.5, y0 + 0.05 * span), style.clone())
                }),
            )
            .map_err(err)?;
        legend(&mut chart, SeriesLabelPosition::UpperLeft, 11)
    })
}
