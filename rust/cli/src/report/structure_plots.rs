//! The report's structured-noise charts: each component's distribution at one ISO
//! (row and column offsets per parity as quantile functions, frame offsets per CFA position as
//! their sorted sample) and every component's standard deviation against ISO, marking which ones
//! synthesis adds.

use noisecal_core::model::structure::{FrameOffsets, IsoStructure, OffsetDistribution};
use noisecal_core::{ModelPack, POSITIONS};
use plotters::prelude::*;

use super::plots::{FONT, color, err, legend, svg_chart};

/// Components per ISO: rows (even, odd), columns (even, odd), the frame offset of each position,
/// the fixed pattern (dark frames).
pub const COMPONENTS: usize = 4 + POSITIONS + 1;

/// One component at one ISO: its standard deviation (DN, sampling noise taken out) and whether
/// synthesis adds it (the rule of `noisecal inspect`: [`IsoStructure::row`], `column`, `frame`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ComponentSd {
    pub sd: f64,
    pub added: bool,
}

/// The structured components a pack has (or derives) at one of its ISOs.
#[derive(Debug, Clone)]
pub struct IsoComponents {
    pub iso: u32,
    /// Derived from the calibrated ISOs' (interpolated or extrapolated), as `inspect` says.
    pub derived: bool,
    pub structure: IsoStructure,
}

impl IsoComponents {
    /// Every ISO of the pack with structured components, in the pack's order.
    pub fn of_pack(pack: &ModelPack) -> Vec<Self> {
        pack.isos
            .iter()
            .filter_map(|m| {
                let structure = noisecal_core::derive::structure::structure_at(pack, m.iso)?;
                let derived = pack.structure_of(m.iso).is_none() || !m.is_calibrated();
                Some(Self { iso: m.iso, derived, structure })
            })
            .collect()
    }

    /// The components in [`component_names`] order; `None` where none was measured.
    pub fn sds(&self) -> [Option<ComponentSd>; COMPONENTS] {
        let st = &self.structure;
        let line = |d: &Option<OffsetDistribution>, added: bool| d.as_ref().map(|d| ComponentSd { sd: d.sd(), added });
        std::array::from_fn(|i| match i {
            0 | 1 => line(&st.rows[i], st.row(i).is_some()),
            2 | 3 => line(&st.columns[i - 2], st.column(i - 2).is_some()),
            8 => st.fpn.as_ref().map(|f| ComponentSd { sd: f.sd(), added: st.fixed_pattern().is_some() }),
            _ => st.frames.as_ref().map(|f| ComponentSd { sd: f.variance(i - 4).sqrt(), added: st.frame().is_some() }),
        })
    }
}

/// Names of the components, as the report's table and legends show them.
pub fn component_names(pack: &ModelPack) -> [String; COMPONENTS] {
    std::array::from_fn(|i| match i {
        0 => "rows, even".to_string(),
        1 => "rows, odd".to_string(),
        2 => "columns, even".to_string(),
        3 => "columns, odd".to_string(),
        8 => "fixed pattern (dark frames)".to_string(),
        _ => format!("frame, {}", pack.layout.cfa.position_name(i - 4)),
    })
}

/// An axis label with at most `decimals` decimals, trailing zeros dropped, and no "-0".
fn tick(v: f64, decimals: usize) -> String {
    let t = format!("{v:.decimals$}");
    let t = if t.contains('.') { t.trim_end_matches('0').trim_end_matches('.') } else { &t };
    if t == "-0" { "0".to_string() } else { t.to_string() }
}

fn added_text(added: bool) -> &'static str {
    if added { "added" } else { "below detection" }
}

/// Row or column offsets.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Line {
    Rows,
    Columns,
}

/// The standard normal quantile Φ⁻¹(u) for `u ∈ (0, 1)` (Acklam's rational approximation,
/// relative error below 1.2·10⁻⁹): the x axis of the normal Q–Q charts.
fn normal_score(u: f64) -> f64 {
    const A: [f64; 6] = [
        -3.969683028665376e1,
        2.209460984245205e2,
        -2.759285104469687e2,
        1.38357751867269e2,
        -3.066479806614716e1,
        2.506628277459239,
    ];
    const B: [f64; 5] =
        [-5.447609879822406e1, 1.615858368580409e2, -1.556989798598866e2, 6.680131188771972e1, -1.328068155288572e1];
    const C: [f64; 6] = [
        -7.784894002430293e-3,
        -3.223964580411365e-1,
        -2.400758277161838,
        -2.549732539343734,
        4.374664141464968,
        2.938163982698783,
    ];
    const D: [f64; 4] = [7.784695709041462e-3, 3.224671290700398e-1, 2.445134137142996, 3.754408661907416];
    let tail = |p: f64| {
        let q = (-2.0 * p.ln()).sqrt();
        (((((C[0] * q + C[1]) * q + C[2]) * q + C[3]) * q + C[4]) * q + C[5])
            / ((((D[0] * q + D[1]) * q + D[2]) * q + D[3]) * q + 1.0)
    };
    let u = u.clamp(1e-300, 1.0 - f64::EPSILON);
    const LOW: f64 = 0.02425;
    if u < LOW {
        tail(u)
    } else if u > 1.0 - LOW {
        -tail(1.0 - u)
    } else {
        let q = u - 0.5;
        let r = q * q;
        (((((A[0] * r + A[1]) * r + A[2]) * r + A[3]) * r + A[4]) * r + A[5]) * q
            / (((((B[0] * r + B[1]) * r + B[2]) * r + B[3]) * r + B[4]) * r + 1.0)
    }
}

/// One curve of a normal Q–Q chart: offsets (DN) at cumulative probabilities.
struct QqSeries {
    label: String,
    color: RGBColor,
    /// (cumulative probability, offset) in increasing order.
    points: Vec<(f64, f64)>,
    sd: f64,
    added: bool,
    /// Mark each point (a small sample) or not (a quantile function).
    dots: bool,
}

/// Offsets against the standard normal quantile of their cumulative probability (a normal Q–Q
/// plot): a Gaussian component is a straight line of slope SD — the faint line of each curve —
/// and heavier tails bend away from it at both ends. Solid where synthesis adds the curve's
/// component, dashed where it is below detection.
fn qq_chart(title: &str, series: &[QqSeries], size: (u32, u32)) -> anyhow::Result<String> {
    let z: Vec<Vec<(f64, f64)>> =
        series.iter().map(|s| s.points.iter().map(|&(u, v)| (normal_score(u), v)).collect()).collect();
    let zmax = z.iter().flatten().map(|p| p.0.abs()).fold(0.0, f64::max).max(1.0) * 1.05;
    let m = z.iter().flatten().map(|p| p.1.abs()).fold(0.0, f64::max);
    let m = (m * 1.15).max(0.01);
    svg_chart(size, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption(title, (FONT, 13))
            .margin(8)
            .x_label_area_size(32)
            .y_label_area_size(52)
            .build_cartesian_2d(-zmax..zmax, -m..m)
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("standard normal quantile")
            .y_desc("offset (DN)")
            .x_label_formatter(&|v| tick(*v, 1))
            .y_label_formatter(&|v| tick(*v, 2))
            .label_style((FONT, 11))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(err)?;
        for (s, pts) in series.iter().zip(&z) {
            let c = s.color;
            let (a, b) = (-zmax * s.sd, zmax * s.sd);
            chart.draw_series(LineSeries::new([(-zmax, a.max(-m)), (zmax, b.min(m))], c.mix(0.35))).map_err(err)?;
            let style = c.stroke_width(2);
            let drawn = if s.added {
                chart.draw_series(LineSeries::new(pts.clone(), style)).map_err(err)?
            } else {
                chart.draw_series(DashedLineSeries::new(pts.clone(), 5, 4, style)).map_err(err)?
            };
            drawn.label(s.label.clone()).legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], style));
            if s.dots {
                chart.draw_series(pts.iter().map(|&p| Circle::new(p, 2, c.filled()))).map_err(err)?;
            }
        }
        legend(&mut chart, SeriesLabelPosition::UpperLeft, 10)
    })
}

/// The quantile function of the row (or column) offset of each parity at one ISO (DN), as a
/// normal Q–Q chart. `None` when no parity was measured.
pub fn line_chart(s: &IsoStructure, line: Line, size: (u32, u32)) -> anyhow::Result<Option<String>> {
    let (dists, what) = match line {
        Line::Rows => (&s.rows, "Row"),
        Line::Columns => (&s.columns, "Column"),
    };
    if dists.iter().all(Option::is_none) {
        return Ok(None);
    }
    let added = |p: usize| match line {
        Line::Rows => s.row(p).is_some(),
        Line::Columns => s.column(p).is_some(),
    };
    let series: Vec<QqSeries> = dists
        .iter()
        .enumerate()
        .filter_map(|(p, d)| {
            let d = d.as_ref()?;
            // Stored at u = i/(n − 1); the two ends (the extreme offsets) at half a step inside.
            let n = d.quantiles.len().max(2) - 1;
            let half = 0.5 / n as f64;
            let points =
                d.quantiles.iter().enumerate().map(|(i, &q)| ((i as f64 / n as f64).clamp(half, 1.0 - half), q as f64));
            Some(QqSeries {
                label: format!("{}: SD {:.3} DN, {}", ["even", "odd"][p], d.sd(), added_text(added(p))),
                color: color(p),
                points: points.collect(),
                sd: d.sd(),
                added: added(p),
                dots: false,
            })
        })
        .collect();
    qq_chart(&format!("{what} offsets, ISO {}", s.iso), &series, size).map(Some)
}

/// The frame offsets of each CFA position at one ISO: the measured frames' offsets, centred and
/// scaled to the component's standard deviation (sampling noise taken out), as a normal Q–Q
/// chart.
pub fn frame_chart(pack: &ModelPack, s: &IsoStructure, f: &FrameOffsets, size: (u32, u32)) -> anyhow::Result<String> {
    let added = s.frame().is_some();
    let n = f.offsets.len().max(1);
    let series: Vec<QqSeries> = (0..POSITIONS)
        .map(|pos| {
            let mean = f.offsets.iter().map(|o| o[pos] as f64).sum::<f64>() / n as f64;
            let s2 = f.offsets.iter().map(|o| (o[pos] as f64 - mean).powi(2)).sum::<f64>() / n as f64;
            let sd = f.variance(pos).sqrt();
            let k = if s2 > 0.0 { sd / s2.sqrt() } else { 0.0 };
            let mut v: Vec<f64> = f.offsets.iter().map(|o| (o[pos] as f64 - mean) * k).collect();
            v.sort_by(f64::total_cmp);
            QqSeries {
                label: format!("{}: SD {sd:.3} DN", pack.layout.cfa.position_name(pos)),
                color: color(pos),
                points: v.iter().enumerate().map(|(i, &x)| ((i as f64 + 0.5) / n as f64, x)).collect(),
                sd,
                added,
                dots: true,
            }
        })
        .collect();
    let title = format!("Frame offsets, ISO {} ({} frames, {})", s.iso, f.offsets.len(), added_text(added));
    qq_chart(&title, &series, size)
}

/// Every component's standard deviation against ISO (log axes): filled circles where synthesis
/// adds the component, open circles where it is below detection. An SD of 0 (no more variance
/// than sampling noise gives) sits on the bottom edge. The chart's only circles are those marks.
pub fn sd_chart(pack: &ModelPack, isos: &[IsoComponents], size: (u32, u32)) -> anyhow::Result<String> {
    let names = component_names(pack);
    let sds: Vec<(f64, [Option<ComponentSd>; COMPONENTS])> = isos.iter().map(|i| (i.iso as f64, i.sds())).collect();
    let (x0, x1) = sds.iter().fold((f64::INFINITY, 0.0f64), |(a, b), (iso, _)| (a.min(*iso), b.max(*iso)));
    let (x0, x1) = if x1 > 0.0 { (x0 / 1.3, x1 * 1.3) } else { (50.0, 100.0) };
    let positive = sds.iter().flat_map(|(_, c)| c.iter().flatten().map(|c| c.sd)).filter(|v| *v > 0.0);
    let (lo, hi) = positive.fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
    let (lo, hi) = if hi > 0.0 { ((lo / 1.5).max(hi / 1000.0), hi * 2.5) } else { (0.01, 1.0) };
    svg_chart(size, |root| {
        let mut chart = ChartBuilder::on(root)
            .caption("Structured components: standard deviation per ISO (filled: added at synthesis)", (FONT, 15))
            .margin(8)
            .x_label_area_size(36)
            .y_label_area_size(56)
            .build_cartesian_2d((x0..x1).log_scale(), (lo..hi).log_scale())
            .map_err(err)?;
        chart
            .configure_mesh()
            .x_desc("ISO")
            .y_desc("SD (DN)")
            .x_label_formatter(&|v| format!("{v:.0}"))
            .y_label_formatter(&|v| format!("{v:.3}"))
            .label_style((FONT, 11))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(err)?;
        for (i, name) in names.iter().enumerate() {
            let pts: Vec<(f64, f64, bool)> =
                sds.iter().filter_map(|(iso, c)| c[i].map(|c| (*iso, c.sd.max(lo), c.added))).collect();
            if pts.is_empty() {
                continue;
            }
            let c = color(i);
            // Rows solid, columns dashed, frame offsets dotted-ish (short dashes), the fixed
            // pattern solid and heavier.
            let style = c.stroke_width(if i == COMPONENTS - 1 { 2 } else { 1 });
            let line: Vec<(f64, f64)> = pts.iter().map(|p| (p.0, p.1)).collect();
            let drawn = match i {
                0 | 1 | 8 => chart.draw_series(LineSeries::new(line, style)).map_err(err)?,
                2 | 3 => chart.draw_series(DashedLineSeries::new(line, 6, 4, style)).map_err(err)?,
                _ => chart.draw_series(DashedLineSeries::new(line, 2, 3, style)).map_err(err)?,
            };
            drawn.label(name.clone()).legend(move |(x, y)| PathElement::new([(x, y), (x + 16, y)], c.stroke_width(2)));
            chart
                .draw_series(
                    pts.iter().map(|&(x, y, added)| {
                        Circle::new((x, y), 4, if added { c.filled() } else { c.stroke_width(2) })
                    }),
                )
                .map_err(err)?;
        }
        legend(&mut chart, SeriesLabelPosition::UpperLeft, 10)
    })
}

#[cfg(test)]
mod tests {
    use super::normal_score;

    #[test]
    fn ticks() {
        assert_eq!(super::tick(-0.001, 2), "0");
        assert_eq!(super::tick(-0.5, 1), "-0.5");
        assert_eq!(super::tick(2.0, 1), "2");
        assert_eq!(super::tick(0.25, 2), "0.25");
        assert_eq!(super::tick(10.0, 2), "10");
    }

    #[test]
    fn normal_quantiles() {
        for (u, z) in [(0.5, 0.0), (0.975, 1.959963984540054), (0.001, -3.090232306167813), (1e-6, -4.753424308822899)]
        {
            assert!((normal_score(u) - z).abs() < 1e-8, "Φ⁻¹({u}) = {} ≠ {z}", normal_score(u));
            assert!((normal_score(1.0 - u) + z).abs() < 1e-6, "symmetry at {u}");
        }
    }
}
