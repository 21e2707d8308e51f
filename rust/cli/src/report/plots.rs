//! The report's charts, drawn with plotters into SVG strings (no fonts or system libraries: text
//! stays SVG text and the browser renders it).

use anyhow::anyhow;
use noisecal_core::derive::baselines::{self, BaselineKind};
use noisecal_core::model::pack::IsoModel;
use noisecal_core::model::pmf::Pmf;
use noisecal_core::{ModelPack, POSITIONS};
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use crate::eval::{EvalReport, LooRow, ModelScore};

/// Colours for series (ISOs, models), readable on white and distinct in print.
pub const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

pub fn color(i: usize) -> RGBColor {
    PALETTE[i % PALETTE.len()]
}

pub(super) const FONT: &str = "sans-serif";

pub(super) fn err<E: std::fmt::Display>(e: E) -> anyhow::Error {
    anyhow!("drawing a chart: {e}")
}

/// An SVG chart of `size` on white: `draw` paints the drawing area, which is then presented.
pub(super) fn svg_chart(
    size: (u32, u32),
    draw: impl FnOnce(&DrawingArea<SVGBackend<'_>, plotters::coord::Shift>) -> anyhow::Result<()>,
) -> anyhow::Result<String> {
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, size).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        draw(&root)?;
        root.present().map_err(err)?;
    }
    Ok(buf)
}

/// The series legend as every chart draws it, at `at`, with labels of `font` px.
pub(super) fn legend<'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, SVGBackend<'a>, CT>,
    at: SeriesLabelPosition,
    font: u32,
) -> anyhow::Result<()> {
    chart
        .configure_series_labels()
        .position(at)
        .background_style(WHITE.mix(0.85))
        .border_style(RGBColor(180, 180, 180))
        .label_font((FONT, font))
        .draw()
        .map_err(err)
}

/// Which per-bin statistic to plot against level.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stat {
    Variance,
    Mean,
}

/// Per-bin variance (or mean) of the noise vs clean level above black at one CFA position, one
/// colour per ISO: each bin's own measured samples as dots (crosses where the bin is clipped, so
/// its moments are shrunk), the pack's PMFs as a line through them — which must follow the dots
/// up to clipping — and the HG fit `σ² = a·(l − black) + b` as a faint line (paper Fig. 3).
pub fn level_chart(pack: &ModelPack, pos: usize, stat: Stat, size: (u32, u32)) -> anyhow::Result<String> {
    let binning = pack.binning();
    let models: Vec<&IsoModel> = pack.isos.iter().collect();
    let series: Vec<Vec<baselines::BinStat>> = models.iter().map(|m| baselines::bin_stats(&binning, m, pos)).collect();
    let xmax = (pack.layout.white as f64 - pack.layout.black[pos] as f64).max(1.0);
    let pick = |v: [f64; 2]| match stat {
        Stat::Variance => v[1],
        Stat::Mean => v[0],
    };
    let val = |s: &baselines::BinStat| pick([s.mean, s.var]);
    let measured_of = |m: &IsoModel| -> Vec<(f64, f64, bool)> {
        m.positions[pos]
            .bins
            .iter()
            .enumerate()
            .filter_map(|(b, bm)| {
                bm.measured.map(|mv| ((b as f64 + 0.5) * binning.bin_width as f64, pick(mv), bm.clipped))
            })
            .collect()
    };
    let points: Vec<Vec<(f64, f64, bool)>> = models.iter().map(|m| measured_of(m)).collect();
    let vals = series
        .iter()
        .flatten()
        .filter(|s| s.samples > 0 || s.filled)
        .map(val)
        .chain(points.iter().flatten().filter(|p| !p.2).map(|p| p.1));
    let (mut lo, mut hi) = vals.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), v| (a.min(v), b.max(v)));
    if !lo.is_finite() {
        (lo, hi) = (0.0, 1.0);
    }
    let (ylo, yhi) = match stat {
        Stat::Variance => (0.0, hi * 1.08 + 1e-3),
        Stat::Mean => {
            let m = lo.abs().max(hi.abs()).max(0.05) * 1.15;
            (-m, m)
        }
    };
    let name = pack.layout.cfa.position_name(pos);
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, size).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let title = match stat {
            Stat::Variance => format!("Noise variance vs level — {name} (position {pos})"),
            Stat::Mean => format!("Noise mean vs level — {name} (position {pos})"),
        };
        let mut chart = ChartBuilder::on(&root)
            .caption(title, (FONT, 15))
            .margin(8)
            .x_label_area_size(36)
            .y_label_area_size(52)
            .build_cartesian_2d(0f64..xmax, ylo..yhi)
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("clean level above black (DN)")
            .y_desc(match stat {
                Stat::Variance => "variance (DN²)",
                Stat::Mean => "mean (DN)",
            })
            .x_label_formatter(&|v| format!("{v:.0}"))
            .y_label_formatter(&|v| match stat {
                Stat::Variance => format!("{v:.0}"),
                Stat::Mean => format!("{v:.1}"),
            })
            .label_style((FONT, 11))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(err)?;
        for (i, (m, st)) in models.iter().zip(&series).enumerate() {
            let c = color(i);
            let label = match m.is_calibrated() {
                true => format!("ISO {}", m.iso),
                false => format!("ISO {} (interp.)", m.iso),
            };
            // The pack: a line over every bin.
            let line: Vec<(f64, f64)> =
                st.iter().map(|s| (s.level_above_black, val(s))).filter(|p| p.1 <= yhi).collect();
            chart
                .draw_series(LineSeries::new(line, c.stroke_width(2)))
                .map_err(err)?
                .label(label)
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], c.stroke_width(2)));
            // What was measured: dots, crosses where clipped.
            let pts = &points[i];
            chart
                .draw_series(
                    pts.iter().filter(|p| !p.2 && p.1 <= yhi).map(|p| Circle::new((p.0, p.1), 2, c.mix(0.7).filled())),
                )
                .map_err(err)?;
            chart
                .draw_series(
                    pts.iter().filter(|p| p.2 && p.1 <= yhi).map(|p| Cross::new((p.0, p.1), 3, c.stroke_width(1))),
                )
                .map_err(err)?;
            if stat == Stat::Variance {
                let hg = baselines::fit_all(&binning, m)[pos];
                chart
                    .draw_series(LineSeries::new([(0.0, hg.b), (xmax, hg.variance(xmax))], c.mix(0.35).stroke_width(1)))
                    .map_err(err)?;
            } else {
                chart.draw_series(LineSeries::new([(0.0, 0.0), (xmax, 0.0)], BLACK.mix(0.4))).map_err(err)?;
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(180, 180, 180))
            .label_font((FONT, 11))
            .draw()
            .map_err(err)?;
        root.present().map_err(err)?;
    }
    Ok(buf)
}

/// The PMF of one (ISO, position, bin) on a log scale: the calibrated histogram against the HG
/// and PG baselines fitted on the same data.
pub fn pmf_chart(
    pack: &ModelPack,
    model: &IsoModel,
    pos: usize,
    bin: usize,
    size: (u32, u32),
) -> anyhow::Result<String> {
    let binning = pack.binning();
    let bm = &model.positions[pos].bins[bin];
    let ours = bm.pmf();
    let mut curves: Vec<(String, Pmf)> = vec![(format!("noisecal ({} samples)", bm.samples), ours.clone())];
    for kind in [BaselineKind::Hg, BaselineKind::Pg] {
        if let Ok(b) = baselines::fit(pack, model, kind) {
            curves.push((kind.name().to_uppercase(), b.bin_pmf(&binning, pos, bin)));
        }
    }
    let lo = ours.quantile(0.00005).floor() as i32 - 2;
    let hi = ours.quantile(0.99995).ceil() as i32 + 2;
    let floor_p = 1e-6f64;
    let (l0, l1) = (
        binning.black[pos] as f64 + bin as f64 * binning.bin_width as f64,
        binning.black[pos] as f64 + (bin + 1) as f64 * binning.bin_width as f64,
    );
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, size).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!(
                    "ISO {} {} bin {bin} (levels {l0:.0}–{:.0}){}",
                    model.iso,
                    pack.layout.cfa.position_name(pos),
                    l1 - 1.0,
                    if bm.filled() { ", filled" } else { "" }
                ),
                (FONT, 13),
            )
            .margin(8)
            .x_label_area_size(32)
            .y_label_area_size(52)
            .build_cartesian_2d(lo as f64..hi as f64, (floor_p..40.0).log_scale())
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("noise n (DN)")
            .y_desc("P(n)")
            .x_label_formatter(&|v| format!("{v:.0}"))
            .y_label_formatter(&|v| if *v > 1.01 { String::new() } else { format!("{v:.0e}") })
            .label_style((FONT, 11))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(err)?;
        for (i, (label, p)) in curves.iter().enumerate() {
            let c = if i == 0 { RGBColor(20, 20, 20) } else { color(i) };
            let pts: Vec<(f64, f64)> = (lo..=hi).map(|n| (n as f64, p.at(n))).filter(|(_, v)| *v >= floor_p).collect();
            let style = if i == 0 { c.stroke_width(2) } else { c.stroke_width(1) };
            chart
                .draw_series(LineSeries::new(pts.clone(), style))
                .map_err(err)?
                .label(label.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], style));
            if i == 0 {
                chart.draw_series(pts.iter().map(|&q| Circle::new(q, 2, c.filled()))).map_err(err)?;
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(180, 180, 180))
            .label_font((FONT, 11))
            .draw()
            .map_err(err)?;
        root.present().map_err(err)?;
    }
    Ok(buf)
}

/// Colour of a sample count on a log scale (light yellow → dark blue).
fn heat(v: f64, vmax: f64) -> RGBColor {
    const STOPS: [(f64, (u8, u8, u8)); 5] = [
        (0.0, (255, 255, 217)),
        (0.25, (161, 218, 180)),
        (0.5, (65, 182, 196)),
        (0.75, (34, 94, 168)),
        (1.0, (8, 29, 88)),
    ];
    let t = if vmax <= 0.0 { 0.0 } else { (v.max(0.0).ln_1p() / vmax.ln_1p()).clamp(0.0, 1.0) };
    for w in STOPS.windows(2) {
        let ((t0, a), (t1, b)) = (w[0], w[1]);
        if t <= t1 {
            let f = (t - t0) / (t1 - t0);
            let mix = |x: u8, y: u8| (x as f64 + (y as f64 - x as f64) * f).round() as u8;
            return RGBColor(mix(a.0, b.0), mix(a.1, b.1), mix(a.2, b.2));
        }
    }
    RGBColor(8, 29, 88)
}

/// Samples per bin (columns) and ISO (rows) at one position; filled bins carry a red mark.
pub fn coverage_chart(pack: &ModelPack, pos: usize, size: (u32, u32)) -> anyhow::Result<String> {
    let n = pack.isos.len();
    let bins = pack.isos.first().map_or(0, |m| m.positions[pos].bins.len());
    let vmax = pack.isos.iter().flat_map(|m| m.positions[pos].bins.iter().map(|b| b.samples)).max().unwrap_or(1) as f64;
    let isos: Vec<u32> = pack.iso_list();
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, size).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(
                format!(
                    "Samples per bin — {} (position {pos}); red mark = filled from neighbours",
                    pack.layout.cfa.position_name(pos)
                ),
                (FONT, 13),
            )
            .margin(8)
            .x_label_area_size(30)
            .y_label_area_size(64)
            .build_cartesian_2d(0f64..bins.max(1) as f64, (0..n.max(1)).into_segmented())
            .map_err(err)?;
        let fmt = |v: &SegmentValue<usize>| match v {
            SegmentValue::CenterOf(i) => isos.get(*i).map_or(String::new(), |iso| format!("ISO {iso}")),
            _ => String::new(),
        };
        chart
            .configure_mesh()
            .disable_mesh()
            .x_desc("bin")
            .y_label_formatter(&fmt)
            .label_style((FONT, 11))
            .draw()
            .map_err(err)?;
        for (i, m) in pack.isos.iter().enumerate() {
            chart
                .draw_series(m.positions[pos].bins.iter().enumerate().map(|(b, bm)| {
                    Rectangle::new(
                        [(b as f64, SegmentValue::Exact(i)), (b as f64 + 1.0, SegmentValue::Exact(i + 1))],
                        heat(bm.samples as f64, vmax).filled(),
                    )
                }))
                .map_err(err)?;
            chart
                .draw_series(m.positions[pos].bins.iter().enumerate().filter(|(_, bm)| bm.filled()).map(|(b, _)| {
                    Rectangle::new(
                        [(b as f64 + 0.2, SegmentValue::CenterOf(i)), (b as f64 + 0.8, SegmentValue::Exact(i + 1))],
                        RGBColor(220, 30, 30).filled(),
                    )
                }))
                .map_err(err)?;
        }
        root.present().map_err(err)?;
    }
    Ok(buf)
}

/// Measured target/reference brightness ratio per ISO and position, with the ±2 % band.
pub fn gain_chart(pack: &ModelPack, size: (u32, u32)) -> anyhow::Result<String> {
    let cal: Vec<&IsoModel> = pack.isos.iter().filter(|m| m.is_calibrated()).collect();
    let (x0, x1) = match (cal.first(), cal.last()) {
        (Some(a), Some(b)) => (a.iso as f64 / 1.3, b.iso as f64 * 1.3),
        _ => (50.0, 100.0),
    };
    let vals = cal.iter().flat_map(|m| m.gain_ratio.iter().copied());
    let (lo, hi) = vals.fold((0.97f64, 1.03f64), |(a, b), v| (a.min(v), b.max(v)));
    let pad = (hi - lo) * 0.08;
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, size).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption("Measured gain ratio (target / reference brightness) per ISO", (FONT, 15))
            .margin(8)
            .x_label_area_size(36)
            .y_label_area_size(56)
            .build_cartesian_2d((x0..x1).log_scale(), (lo - pad)..(hi + pad))
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("ISO")
            .y_desc("gain ratio")
            .x_label_formatter(&|v| format!("{v:.0}"))
            .y_label_formatter(&|v| format!("{v:.3}"))
            .label_style((FONT, 11))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(err)?;
        let band = RGBColor(150, 150, 150);
        for y in [0.98, 1.0, 1.02] {
            chart.draw_series(DashedLineSeries::new([(x0, y), (x1, y)], 4, 4, band.stroke_width(1))).map_err(err)?;
        }
        for pos in 0..POSITIONS {
            let c = color(pos);
            let pts: Vec<(f64, f64)> = cal.iter().map(|m| (m.iso as f64, m.gain_ratio[pos])).collect();
            chart
                .draw_series(LineSeries::new(pts.clone(), c.stroke_width(1)))
                .map_err(err)?
                .label(pack.layout.cfa.position_name(pos))
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], c.stroke_width(2)));
            chart.draw_series(pts.iter().map(|&p| Circle::new(p, 3, c.filled()))).map_err(err)?;
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(180, 180, 180))
            .label_font((FONT, 11))
            .draw()
            .map_err(err)?;
        root.present().map_err(err)?;
    }
    Ok(buf)
}

/// Grouped bars: one group per label, one bar per series; `None` values are left out. A dashed
/// mark per group shows `floor` when given.
pub fn grouped_bars(
    title: &str,
    y_desc: &str,
    groups: &[String],
    series: &[String],
    values: &[Vec<Option<f64>>],
    floor: &[Option<f64>],
    size: (u32, u32),
) -> anyhow::Result<String> {
    let ymax =
        values.iter().flatten().flatten().chain(floor.iter().flatten()).cloned().fold(0.0f64, f64::max).max(1e-4) * 1.6; // headroom for the legend
    let ng = groups.len().max(1) as f64;
    let ns = series.len().max(1) as f64;
    let below = ymax * 0.09;
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, size).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(title, (FONT, 15))
            .margin(8)
            .x_label_area_size(6)
            .y_label_area_size(60)
            .build_cartesian_2d(0f64..ng, -below..ymax)
            .map_err(err)?;
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(0)
            .y_desc(y_desc)
            .y_label_formatter(&|v| if *v < 0.0 { String::new() } else { format!("{v:.4}") })
            .label_style((FONT, 11))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(err)?;
        let w = 0.8 / ns;
        for (si, name) in series.iter().enumerate() {
            let c = color(si);
            let bars: Vec<Rectangle<(f64, f64)>> = values
                .iter()
                .enumerate()
                .filter_map(|(gi, row)| {
                    let v = (*row.get(si)?)?;
                    let x = gi as f64 + 0.1 + si as f64 * w;
                    Some(Rectangle::new([(x, 0.0), (x + w * 0.92, v)], c.filled()))
                })
                .collect();
            chart
                .draw_series(bars)
                .map_err(err)?
                .label(name.clone())
                .legend(move |(x, y)| Rectangle::new([(x, y - 5), (x + 12, y + 5)], c.filled()));
        }
        for (gi, f) in floor.iter().enumerate() {
            if let Some(f) = f {
                chart
                    .draw_series(DashedLineSeries::new(
                        [(gi as f64 + 0.05, *f), (gi as f64 + 0.95, *f)],
                        5,
                        3,
                        BLACK.stroke_width(2),
                    ))
                    .map_err(err)?;
            }
        }
        if floor.iter().any(|f| f.is_some()) {
            chart
                .draw_series(std::iter::once(PathElement::new(vec![(0.0, -1.0), (0.0, -1.0)], BLACK.stroke_width(2))))
                .map_err(err)?
                .label("finite-sample floor (scaled)")
                .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 14, y)], BLACK.stroke_width(2)));
        }
        chart.draw_series(LineSeries::new([(0.0, 0.0), (ng, 0.0)], BLACK.stroke_width(1))).map_err(err)?;
        let style = TextStyle::from((FONT, 13).into_font()).pos(Pos::new(HPos::Center, VPos::Center));
        chart
            .draw_series(
                groups
                    .iter()
                    .enumerate()
                    .map(|(gi, g)| Text::new(g.clone(), (gi as f64 + 0.5, -below * 0.5), style.clone())),
            )
            .map_err(err)?;
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(180, 180, 180))
            .label_font((FONT, 11))
            .draw()
            .map_err(err)?;
        root.present().map_err(err)?;
    }
    Ok(buf)
}

/// Conditional JSD per ISO for every model of the evaluation, with the scaled floor.
pub fn eval_bars(ev: &EvalReport, size: (u32, u32)) -> anyhow::Result<String> {
    let mut names: Vec<String> = Vec::new();
    for ie in &ev.isos {
        for m in &ie.models {
            if !names.contains(&m.name) {
                names.push(m.name.clone());
            }
        }
    }
    let groups: Vec<String> = ev.isos.iter().map(|i| format!("ISO {}", i.iso)).collect();
    let values: Vec<Vec<Option<f64>>> =
        ev.isos.iter().map(|ie| names.iter().map(|n| ie.model(n).map(|m| m.conditional_overall)).collect()).collect();
    let floor: Vec<Option<f64>> = ev.isos.iter().map(|ie| ie.floor.as_ref().map(|f| f.conditional_scaled())).collect();
    grouped_bars(
        "Conditional JSD per ISO (lower is closer to the real noise)",
        "conditional JSD (nats)",
        &groups,
        &names,
        &values,
        &floor,
        size,
    )
}

/// The leave-one-out study as bars (paper Fig. 4).
pub fn loo_bars(rows: &[LooRow], size: (u32, u32)) -> anyhow::Result<String> {
    let groups: Vec<String> = rows.iter().map(|r| format!("ISO {}", r.iso)).collect();
    let names = ["calibrated", "interpolated", "HG calibrated", "HG interpolated"].map(String::from).to_vec();
    let values: Vec<Vec<Option<f64>>> = rows
        .iter()
        .map(|r| {
            vec![Some(r.calibrated[0]), Some(r.interpolated[0]), Some(r.hg_calibrated[0]), Some(r.hg_interpolated[0])]
        })
        .collect();
    let floor: Vec<Option<f64>> = rows.iter().map(|r| r.floor.map(|f| f[0])).collect();
    grouped_bars(
        "Leave-one-out: each inner ISO interpolated from the others",
        "conditional JSD (nats)",
        &groups,
        &names,
        &values,
        &floor,
        size,
    )
}

/// Noise-on-noise methods as bars.
pub fn renoise_bars(
    methods: &[ModelScore],
    floor: Option<f64>,
    title: &str,
    size: (u32, u32),
) -> anyhow::Result<String> {
    let groups: Vec<String> = methods.iter().map(|m| m.name.clone()).collect();
    let names = vec!["conditional JSD".to_string(), "marginal JSD".to_string()];
    let values: Vec<Vec<Option<f64>>> =
        methods.iter().map(|m| vec![Some(m.conditional_overall), Some(m.marginal_overall)]).collect();
    let floors: Vec<Option<f64>> = methods.iter().map(|_| floor).collect();
    grouped_bars(title, "JSD (nats)", &groups, &names, &values, &floors, size)
}

/// Which line-mean ratio to plot.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Lines {
    Rows,
    Columns,
}

/// The row- (or column-) mean variance ratio synthetic/real per ISO, one colour per model with
/// ±1 SE bars; the grey crosses are real half against real half (what the data allow), the
/// dashed line is 1 (as much banding as the real frames).
pub fn spatial_ratio_chart(ev: &EvalReport, lines: Lines, size: (u32, u32)) -> anyhow::Result<String> {
    let isos: Vec<&crate::eval::IsoEval> = ev.isos.iter().filter(|i| i.spatial.is_some()).collect();
    let mut names: Vec<String> = Vec::new();
    for ie in &isos {
        for m in &ie.spatial.as_ref().expect("filtered").models {
            if !names.contains(&m.name) {
                names.push(m.name.clone());
            }
        }
    }
    let pick = |c: &noisecal_core::metrics::spatial::SpatialComparison| match lines {
        Lines::Rows => (c.row_var_ratio, c.row_var_ratio_se),
        Lines::Columns => (c.col_var_ratio, c.col_var_ratio_se),
    };
    let mut ymax = 1.5f64;
    for ie in &isos {
        let sp = ie.spatial.as_ref().expect("filtered");
        for c in sp.models.iter().map(|m| &m.scores).chain(sp.floor.as_ref().map(|f| &f.halves)) {
            if let (Some(r), se) = pick(c) {
                ymax = ymax.max(r + se.unwrap_or(0.0));
            }
        }
    }
    let ymax = (ymax * 1.1).min(20.0);
    let ng = isos.len().max(1) as f64;
    let ns = names.len().max(1) as f64 + 1.0;
    let what = match lines {
        Lines::Rows => "Row-mean variance",
        Lines::Columns => "Column-mean variance",
    };
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, size).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(format!("{what}, synthetic / real, per ISO"), (FONT, 15))
            .margin(8)
            .x_label_area_size(30)
            .y_label_area_size(56)
            .build_cartesian_2d(0f64..ng, 0f64..ymax)
            .map_err(err)?;
        let labels: Vec<String> = isos.iter().map(|i| format!("ISO {}", i.iso)).collect();
        chart
            .configure_mesh()
            .disable_x_mesh()
            .x_labels(isos.len().max(1) * 2 + 1)
            .x_label_formatter(&|v| {
                let i = v.floor() as usize;
                if (v - i as f64 - 0.5).abs() < 0.26 {
                    labels.get(i).cloned().unwrap_or_default()
                } else {
                    String::new()
                }
            })
            .y_desc("ratio")
            .y_label_formatter(&|v| format!("{v:.2}"))
            .label_style((FONT, 11))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(err)?;
        chart.draw_series(DashedLineSeries::new([(0.0, 1.0), (ng, 1.0)], 5, 4, BLACK.stroke_width(1))).map_err(err)?;
        let x_of = |gi: usize, si: usize| gi as f64 + (si as f64 + 1.0) / (ns + 1.0);
        for (si, name) in names.iter().enumerate() {
            let c = color(si);
            let pts: Vec<(f64, f64, f64)> = isos
                .iter()
                .enumerate()
                .filter_map(|(gi, ie)| {
                    let m = ie.spatial.as_ref()?.model(name)?;
                    let (r, se) = pick(&m.scores);
                    Some((x_of(gi, si), r?, se.unwrap_or(0.0)))
                })
                .collect();
            chart
                .draw_series(pts.iter().map(|&(x, r, _)| Circle::new((x, r.min(ymax)), 4, c.filled())))
                .map_err(err)?
                .label(name.clone())
                .legend(move |(x, y)| Circle::new((x + 6, y), 4, c.filled()));
            for &(x, r, se) in &pts {
                chart
                    .draw_series(LineSeries::new([(x, (r - se).max(0.0)), (x, (r + se).min(ymax))], c.stroke_width(2)))
                    .map_err(err)?;
            }
        }
        let grey = RGBColor(120, 120, 120);
        let halves: Vec<(f64, f64, f64)> = isos
            .iter()
            .enumerate()
            .filter_map(|(gi, ie)| {
                let f = ie.spatial.as_ref()?.floor.as_ref()?;
                let (r, se) = pick(&f.halves);
                Some((x_of(gi, names.len()), r?, se.unwrap_or(0.0)))
            })
            .collect();
        if !halves.is_empty() {
            chart
                .draw_series(halves.iter().map(|&(x, r, _)| Cross::new((x, r.min(ymax)), 5, grey.stroke_width(2))))
                .map_err(err)?
                .label("real half / real half")
                .legend(move |(x, y)| Cross::new((x + 6, y), 5, grey.stroke_width(2)));
            for &(x, r, se) in &halves {
                chart
                    .draw_series(LineSeries::new(
                        [(x, (r - se).max(0.0)), (x, (r + se).min(ymax))],
                        grey.stroke_width(1),
                    ))
                    .map_err(err)?;
            }
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(180, 180, 180))
            .label_font((FONT, 11))
            .draw()
            .map_err(err)?;
        root.present().map_err(err)?;
    }
    Ok(buf)
}

/// Noise power spectra of flat crops at one ISO and CFA position: the real frames (black) and
/// the models in `names` (colours); solid lines are the row curve `P(f_y, f_x = 0)` (banding),
/// dashed lines the radial mean off the axes (pixel noise), on a log scale.
pub fn nps_chart(
    sp: &crate::eval::SpatialEval,
    iso: u32,
    pos: usize,
    pos_name: &str,
    names: &[&str],
    size: (u32, u32),
) -> anyhow::Result<String> {
    use noisecal_core::metrics::spatial::NpsCurves;
    let mut curves: Vec<(String, RGBColor, &NpsCurves)> = Vec::new();
    if let Some(c) = sp.nps[pos].as_ref() {
        curves.push(("real".into(), RGBColor(20, 20, 20), c));
    }
    for (i, n) in names.iter().enumerate() {
        if let Some(c) = sp.model(n).and_then(|m| m.nps[pos].as_ref()) {
            curves.push(((*n).to_string(), color(i), c));
        }
    }
    let vals = curves.iter().flat_map(|(_, _, c)| c.row.iter().chain(&c.radial).chain(&c.col).copied());
    let (lo, hi) = vals.filter(|v| *v > 0.0).fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
    let (lo, hi) = if lo.is_finite() && hi > 0.0 { (lo / 1.3, hi * 1.6) } else { (0.1, 10.0) };
    let mut buf = String::new();
    {
        let root = SVGBackend::with_string(&mut buf, size).into_drawing_area();
        root.fill(&WHITE).map_err(err)?;
        let mut chart = ChartBuilder::on(&root)
            .caption(format!("Noise power spectrum, ISO {iso}, {pos_name}"), (FONT, 14))
            .margin(8)
            .x_label_area_size(34)
            .y_label_area_size(56)
            .build_cartesian_2d(0f64..0.72, (lo..hi).log_scale())
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("frequency (cycles per same-colour pixel)")
            .y_desc("power (DN²)")
            .x_label_formatter(&|v| format!("{v:.2}"))
            .y_label_formatter(&|v| format!("{v:.3}"))
            .label_style((FONT, 11))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(err)?;
        for (name, c, nps) in &curves {
            let c = *c;
            let row: Vec<(f64, f64)> = nps.freq.iter().copied().zip(nps.row.iter().copied()).collect();
            chart
                .draw_series(LineSeries::new(row, c.stroke_width(2)))
                .map_err(err)?
                .label(format!("{name}: rows (f_x = 0)"))
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], c.stroke_width(2)));
            let radial: Vec<(f64, f64)> = nps.radial_freq.iter().copied().zip(nps.radial.iter().copied()).collect();
            chart
                .draw_series(DashedLineSeries::new(radial, 4, 3, c.stroke_width(1)))
                .map_err(err)?
                .label(format!("{name}: off-axis (radial)"))
                .legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], c.mix(0.6).stroke_width(1)));
        }
        chart
            .configure_series_labels()
            .position(SeriesLabelPosition::UpperRight)
            .background_style(WHITE.mix(0.85))
            .border_style(RGBColor(180, 180, 180))
            .label_font((FONT, 10))
            .draw()
            .map_err(err)?;
        root.present().map_err(err)?;
    }
    Ok(buf)
}
