//! The calibration report: one self-contained HTML page (inline CSS and SVG, no scripts, no
//! external references) with what a pack holds and how well it does.
//!
//! Sections: the sensor and session; noise variance and mean vs level per ISO and CFA position
//! with the HG fit (paper Fig. 3); PMFs of chosen bins on a log scale against the HG and PG
//! baselines; the coverage map (samples per bin, filled bins marked); the measured gain ratios;
//! the structured components per ISO (row, column and frame offsets: their distributions and
//! their SD against ISO, which ones synthesis adds); conversion-gain switches and pack warnings;
//! and, with an evaluation, the JSD tables and bars
//! (leave-one-out and noise on noise when measured); with a denoiser benchmark's results
//! (`noisecal-bench --json`), its table and chart.

pub mod bench_section;
pub mod plots;
pub mod structure_plots;

use std::fmt::Write;

use noisecal_core::{ModelPack, POSITIONS};

use crate::eval::{EvalReport, FloorScore, ModelScore, SpatialEval};
use crate::models::origin_text;
use plots::Stat;

/// HTML-escapes text.
pub fn esc(s: &str) -> String {
    let mut o = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => o.push_str("&amp;"),
            '<' => o.push_str("&lt;"),
            '>' => o.push_str("&gt;"),
            '"' => o.push_str("&quot;"),
            '\'' => o.push_str("&#39;"),
            _ => o.push(c),
        }
    }
    o
}

const CSS: &str = r#"
body { font-family: -apple-system, "Segoe UI", Helvetica, Arial, sans-serif; color: #222; margin: 0; background: #f6f6f4; }
main { max-width: 1120px; margin: 0 auto; padding: 24px 28px 60px; background: #fff; }
h1 { font-size: 26px; margin: 8px 0 4px; }
h2 { font-size: 20px; margin: 36px 0 8px; padding-bottom: 4px; border-bottom: 2px solid #e3e3e0; }
h3 { font-size: 16px; margin: 20px 0 6px; }
p, li { line-height: 1.45; font-size: 14px; }
.sub { color: #666; font-size: 14px; margin-top: 0; }
nav { font-size: 13px; margin: 12px 0 0; }
nav a { color: #1f77b4; margin-right: 14px; text-decoration: none; }
.grid2 { display: grid; grid-template-columns: repeat(2, 1fr); gap: 10px; }
.grid3 { display: grid; grid-template-columns: repeat(3, 1fr); gap: 8px; }
figure { margin: 10px 0 16px; }
figure svg { width: 100%; height: auto; display: block; border: 1px solid #eee; }
figcaption { font-size: 13px; color: #555; margin-top: 6px; line-height: 1.4; }
table { border-collapse: collapse; font-size: 13px; margin: 8px 0 14px; }
th, td { padding: 4px 9px; border-bottom: 1px solid #e6e6e6; text-align: right; }
th { background: #f2f2ef; font-weight: 600; }
td.l, th.l { text-align: left; }
tr.best td { background: #eef7ee; font-weight: 600; }
tr.floor td { color: #777; font-style: italic; }
.warn { background: #fff8e5; border-left: 4px solid #f0b400; padding: 8px 12px; font-size: 13px; }
.warn li { font-size: 13px; }
.ok { background: #eef7ee; border-left: 4px solid #4a4; padding: 8px 12px; font-size: 13px; }
td.added { font-weight: 600; }
td.below { color: #777; }
code { background: #f2f2ef; padding: 1px 4px; border-radius: 3px; }
"#;

fn figure(out: &mut String, svg: &str, caption: &str) {
    let _ = write!(out, "<figure>{svg}<figcaption>{}</figcaption></figure>", esc(caption));
}

/// Up to `k` measured bins of a position spread over its levels (dark, mid, bright).
fn chosen_bins(model: &noisecal_core::model::pack::IsoModel, pos: usize, k: usize) -> Vec<usize> {
    let measured: Vec<usize> = model.positions[pos]
        .bins
        .iter()
        .enumerate()
        .filter(|(_, b)| !b.filled() && b.samples > 0)
        .map(|(i, _)| i)
        .collect();
    let pool = if measured.is_empty() { (0..model.positions[pos].bins.len()).collect() } else { measured };
    let mut out: Vec<usize> =
        [0.1, 0.45, 0.85].iter().take(k).map(|f| pool[((pool.len() - 1) as f64 * f).round() as usize]).collect();
    out.dedup();
    out
}

/// Writes the report page for a pack and, optionally, an evaluation of it.
pub fn render_html(pack: &ModelPack, pack_name: &str, eval: Option<&EvalReport>) -> anyhow::Result<String> {
    render_html_with_bench(pack, pack_name, eval, None)
}

/// [`render_html`] with, optionally, a denoiser benchmark's results and the name of their file
/// (a section after the evaluation's; without them the page is byte for byte `render_html`'s).
pub fn render_html_with_bench(
    pack: &ModelPack,
    pack_name: &str,
    eval: Option<&EvalReport>,
    bench: Option<(&bench_section::BenchResults, &str)>,
) -> anyhow::Result<String> {
    let mut o = String::new();
    let camera = format!("{} {}", pack.make, pack.model).trim().to_string();
    let _ = write!(
        o,
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><meta name=\"viewport\" content=\"width=device-width, initial-scale=1\"><title>noisecal report — {}</title><style>{CSS}</style></head><body><main>",
        esc(&camera)
    );
    let _ = write!(
        o,
        "<h1>noisecal calibration report</h1><p class=\"sub\">{} · pack <code>{}</code></p>",
        esc(&camera),
        esc(pack_name)
    );
    let _ = write!(
        o,
        "<nav><a href=\"#sensor\">Sensor</a><a href=\"#levels\">Variance &amp; mean</a><a href=\"#pmfs\">PMFs</a><a href=\"#coverage\">Coverage</a><a href=\"#gain\">Gain ratios</a><a href=\"#structure\">Structured noise</a><a href=\"#warnings\">Warnings</a>{}{}</nav>",
        if eval.is_some() { "<a href=\"#eval\">Fidelity</a>" } else { "" },
        if bench.is_some() { "<a href=\"#bench\">Denoiser benchmark</a>" } else { "" }
    );

    // Sensor and session.
    let _ = write!(o, "<h2 id=\"sensor\">Sensor and session</h2>");
    let _ = write!(
        o,
        "<p>{} ({}-bit), bins {} DN wide, {}, reference ISO {}.</p>",
        esc(&pack.layout.describe()),
        pack.layout.bit_depth(),
        pack.bin_width,
        match pack.pooling {
            Some(m) => format!("every bin pooled with its neighbours up to {m} samples (fixed at calibration)"),
            None => "pooling of neighbouring bins chosen per ISO and position by held-out likelihood".to_string(),
        },
        pack.reference_iso
    );
    let names: Vec<&str> = (0..POSITIONS).map(|p| pack.layout.cfa.position_name(p)).collect();
    let _ = write!(o, "<table><tr><th>ISO</th><th class=\"l\">origin</th><th>frames</th><th>drift-normalised</th>");
    for n in &names {
        let _ = write!(o, "<th>{n} samples</th><th>{n} filled</th>");
    }
    let _ = write!(o, "</tr>");
    for m in &pack.isos {
        let _ = write!(
            o,
            "<tr><td>{}</td><td class=\"l\">{}</td><td>{}</td><td>{}</td>",
            m.iso,
            esc(&origin_text(&m.origin)),
            m.frames,
            m.drift_frames
        );
        for p in 0..POSITIONS {
            let _ = write!(o, "<td>{}</td><td>{}/{}</td>", m.samples(p), m.filled_bins(p), m.positions[p].bins.len());
        }
        let _ = write!(o, "</tr>");
    }
    let _ = write!(o, "</table>");

    // Variance and mean vs level.
    let _ = write!(o, "<h2 id=\"levels\">Noise variance and mean vs level</h2>");
    let _ = write!(
        o,
        "<p>Per bin of clean level, one colour per ISO: the dots are what each bin's own samples measured (crosses: clipped bins, whose spread is shrunk by 0 or white), the thick line is the pack's noise PMF, which must follow the dots up to clipping and continue along the fitted noise law beyond them; the faint line is the heteroscedastic Gaussian fit <code>σ² = a·(l − black) + b</code> (paper Fig. 3). Where the dots leave the faint line, a Gaussian model is off. A mean that drifts with level is a gain ratio off 1, kept by the model.</p>"
    );
    let _ = write!(o, "<div class=\"grid2\">");
    for pos in 0..POSITIONS {
        let svg = plots::level_chart(pack, pos, Stat::Variance, (540, 360))?;
        figure(&mut o, &svg, &format!("Variance vs level at {} (position {pos}).", names[pos]));
    }
    let _ = write!(o, "</div><div class=\"grid2\">");
    for pos in 0..POSITIONS {
        let svg = plots::level_chart(pack, pos, Stat::Mean, (540, 300))?;
        figure(&mut o, &svg, &format!("Mean of the noise vs level at {} (position {pos}); 0 = unbiased.", names[pos]));
    }
    let _ = write!(o, "</div>");

    // PMFs.
    let _ = write!(o, "<h2 id=\"pmfs\">Noise PMFs of chosen bins</h2>");
    let _ = write!(
        o,
        "<p>The calibrated PMF (black, dots) of a dark, a middle and a bright bin against the HG and PG baselines fitted on the same histograms, on a log scale so the tails show. Heavy read-noise tails, clipping near black or white, and skew appear as departures of the baselines from the dots.</p>"
    );
    let cal: Vec<&noisecal_core::model::pack::IsoModel> = pack.isos.iter().filter(|m| m.is_calibrated()).collect();
    let mut show: Vec<&noisecal_core::model::pack::IsoModel> = Vec::new();
    if let Some(m) = cal.first() {
        show.push(m);
    }
    if let Some(m) = cal.last()
        && cal.len() > 1
    {
        show.push(m);
    }
    let pmf_pos = 1usize.min(POSITIONS - 1);
    for m in show {
        let _ = write!(o, "<h3>ISO {} — {}</h3><div class=\"grid3\">", m.iso, names[pmf_pos]);
        for bin in chosen_bins(m, pmf_pos, 3) {
            let svg = plots::pmf_chart(pack, m, pmf_pos, bin, (360, 280))?;
            figure(&mut o, &svg, &format!("ISO {} {} bin {bin}: noisecal vs HG and PG.", m.iso, names[pmf_pos]));
        }
        let _ = write!(o, "</div>");
    }

    // Coverage.
    let _ = write!(o, "<h2 id=\"coverage\">Coverage: samples per bin</h2>");
    let _ = write!(
        o,
        "<p>Each cell is one (ISO, bin); darker means more flat-pixel samples (log scale). Red marks are bins without samples of their own, filled from their neighbours by the noise law: capture more EV steps at those levels to measure them.</p>"
    );
    let _ = write!(o, "<div class=\"grid2\">");
    let rows = pack.isos.len().max(1) as u32;
    for pos in 0..POSITIONS {
        let svg = plots::coverage_chart(pack, pos, (540, 90 + 26 * rows))?;
        figure(&mut o, &svg, &format!("Coverage at {} (position {pos}).", names[pos]));
    }
    let _ = write!(o, "</div>");

    // Gain ratios.
    let _ = write!(o, "<h2 id=\"gain\">Measured gain ratios</h2>");
    let svg = plots::gain_chart(pack, (900, 340))?;
    figure(
        &mut o,
        &svg,
        "Brightness of each ISO's bursts over their reference bursts (flat pixels, black removed), per CFA position. 1 means the gain is exactly proportional to the nominal ISO; the dashed lines are ±2 %, beyond which calibration warns.",
    );
    let _ = write!(o, "<table><tr><th>ISO</th>");
    for n in &names {
        let _ = write!(o, "<th>{n}</th>");
    }
    let _ = write!(o, "</tr>");
    for m in &cal {
        let _ = write!(o, "<tr><td>{}</td>", m.iso);
        for p in 0..POSITIONS {
            let g = m.gain_ratio[p];
            let style = if (g - 1.0).abs() > 0.02 { " style=\"color:#b00;font-weight:600\"" } else { "" };
            let _ = write!(o, "<td{style}>{g:.4}</td>");
        }
        let _ = write!(o, "</tr>");
    }
    let _ = write!(o, "</table>");

    structure_section(&mut o, pack)?;

    // Warnings and gain switches.
    let _ = write!(o, "<h2 id=\"warnings\">Warnings</h2>");
    let switches = noisecal_core::derive::gain_switch::detect_gain_switches(pack);
    if switches.is_empty() {
        let _ = write!(
            o,
            "<p class=\"ok\">No conversion-gain switch between calibrated ISOs: interpolation may use every calibrated ISO.</p>"
        );
    } else {
        let _ = write!(o, "<div class=\"warn\"><ul>");
        for s in &switches {
            let _ = write!(o, "<li>{} — interpolation does not fit across it.</li>", esc(&s.to_string()));
        }
        let _ = write!(o, "</ul></div>");
    }
    // The pack's own warnings, then what the self-check finds now (older packs never ran it).
    let mut warnings = pack.warnings.clone();
    for f in noisecal_core::model::check::self_check(pack) {
        let f = f.to_string();
        if !warnings.contains(&f) {
            warnings.push(f);
        }
    }
    let self_check: Vec<&String> = warnings.iter().filter(|w| w.starts_with("self-check")).collect();
    if self_check.is_empty() {
        let _ = write!(
            o,
            "<p class=\"ok\">Self-check: the pack's noise variance stays within 10 % of the measured variance at every checked level, and no fill spans clipped bins.</p>"
        );
    }
    if warnings.is_empty() {
        let _ = write!(o, "<p class=\"ok\">The pack carries no calibration warnings.</p>");
    } else {
        let _ = write!(o, "<div class=\"warn\"><ul>");
        for w in warnings.iter().take(60) {
            let _ = write!(o, "<li>{}</li>", esc(w));
        }
        if warnings.len() > 60 {
            let _ = write!(o, "<li>… and {} more (see <code>noisecal inspect</code>)</li>", warnings.len() - 60);
        }
        let _ = write!(o, "</ul></div>");
    }

    if let Some(ev) = eval {
        eval_section(&mut o, ev)?;
    }
    if let Some((b, source)) = bench {
        bench_section::bench_section(&mut o, b, source)?;
    }
    let _ = write!(
        o,
        "<p class=\"sub\" style=\"margin-top:40px\">Written by noisecal {}.</p></main></body></html>",
        env!("CARGO_PKG_VERSION")
    );
    Ok(o)
}

/// Row, column and frame offsets per ISO (`noisecal_core::model::structure`): a chart of every
/// component's SD against ISO with its table, then each ISO's distributions.
fn structure_section(o: &mut String, pack: &ModelPack) -> anyhow::Result<()> {
    use structure_plots::{IsoComponents, Line};
    let _ = write!(o, "<h2 id=\"structure\">Structured noise</h2>");
    let isos = IsoComponents::of_pack(pack);
    if isos.is_empty() {
        let _ = write!(
            o,
            "<p class=\"ok\">No structured components calibrated: the pack holds no row, column or frame offsets (a pack of an older version, or calibrated without them), so none are added at synthesis, which adds per-pixel noise only.</p>"
        );
        return Ok(());
    }
    let _ = write!(
        o,
        "<p>Noise shared along a line or by a whole frame, which a pixel-independent model cannot make: one offset per row (by row parity) and per column (by column parity), and one black-level offset per frame and CFA position, measured on the flat cells of each burst with the sampling noise of a mean taken out; and, where the session had a dark (lens-covered) step, the fixed pattern: each pixel's own dark offset (DSNU and dark shading), the same in every image. Synthesis adds a component only where its variance stands clear of what sampling noise alone gives; the others are below detection and shown for reference (as in <code>noisecal inspect</code>). ISOs the pack interpolates carry components derived from the calibrated ISOs'.</p>"
    );
    let names = structure_plots::component_names(pack);
    // What synthesis adds, by component kind and ISO.
    let kinds: [(&str, std::ops::Range<usize>); 4] = [
        ("row offsets", 0..2),
        ("column offsets", 2..4),
        ("frame offsets", 4..4 + POSITIONS),
        ("the fixed pattern", 4 + POSITIONS..structure_plots::COMPONENTS),
    ];
    let mut added: Vec<String> = Vec::new();
    for (kind, range) in &kinds {
        let at: Vec<String> = isos
            .iter()
            .filter(|i| i.sds()[range.clone()].iter().flatten().any(|c| c.added))
            .map(|i| i.iso.to_string())
            .collect();
        if !at.is_empty() {
            added.push(format!("{kind} at ISO {}", at.join(", ")));
        }
    }
    if added.is_empty() {
        let _ = write!(
            o,
            "<p class=\"ok\">No structured component stands clear of sampling noise at any ISO: none are added at synthesis, which adds per-pixel noise only.</p>"
        );
    } else {
        let _ = write!(o, "<p>Added at synthesis: {}.</p>", esc(&added.join("; ")));
    }
    let svg = structure_plots::sd_chart(pack, &isos, (1040, 380))?;
    figure(
        o,
        &svg,
        "Standard deviation of each component (DN, sampling noise taken out) per ISO, log scales; filled circles are added at synthesis, open circles are below detection. Rows solid, columns dashed, frame offsets dotted, the fixed pattern solid; an SD of 0 sits on the bottom edge.",
    );
    let _ = write!(o, "<table><tr><th>ISO</th>");
    for n in &names {
        let _ = write!(o, "<th>{}</th>", esc(n));
    }
    let _ = write!(o, "<th>frames</th><th class=\"l\">origin</th></tr>");
    for i in &isos {
        let _ = write!(o, "<tr data-iso=\"{}\"><td>{}</td>", i.iso, i.iso);
        for c in i.sds() {
            match c {
                Some(c) if c.added => {
                    let _ = write!(o, "<td class=\"added\">{:.3}*</td>", c.sd);
                }
                Some(c) => {
                    let _ = write!(o, "<td class=\"below\">{:.3}</td>", c.sd);
                }
                None => {
                    let _ = write!(o, "<td>—</td>");
                }
            }
        }
        let _ = write!(
            o,
            "<td>{}</td><td class=\"l\">{}</td></tr>",
            i.structure.frames_used,
            if i.derived { "derived from calibrated ISOs" } else { "measured" }
        );
    }
    let _ = write!(
        o,
        "</table><p class=\"sub\">SD in DN; * = added at synthesis, else below detection; — = not measured. Frames: target frames in bursts of two or more, which the offsets were measured on.</p>"
    );
    for i in &isos {
        let st = &i.structure;
        let _ = write!(
            o,
            "<h3>ISO {}{}</h3><div class=\"grid3\">",
            i.iso,
            if i.derived { " — derived from calibrated ISOs" } else { "" }
        );
        for (line, what) in [(Line::Rows, "row"), (Line::Columns, "column")] {
            match structure_plots::line_chart(st, line, (360, 280))? {
                Some(svg) => figure(
                    o,
                    &svg,
                    &format!(
                        "ISO {}: quantile function of the {what} offset per {what} parity (DN) against the normal quantile; a Gaussian offset follows its faint straight line (slope = SD), heavier tails bend away at the ends. Solid: added at synthesis, dashed: below detection.",
                        i.iso
                    ),
                ),
                None => {
                    let _ =
                        write!(o, "<figure><p class=\"sub\">ISO {}: no {what} offsets measured.</p></figure>", i.iso);
                }
            }
        }
        match st.frames.as_ref().filter(|f| !f.offsets.is_empty()) {
            Some(f) => {
                let svg = structure_plots::frame_chart(pack, st, f, (360, 280))?;
                figure(
                    o,
                    &svg,
                    &format!(
                        "ISO {}: each measured frame's black-level offset per CFA position (DN), centred and scaled to the component's SD, against the normal quantile of its rank; faint lines: Gaussians of the same SD. Solid: added at synthesis, dashed: below detection.",
                        i.iso
                    ),
                );
            }
            None => {
                let _ = write!(o, "<figure><p class=\"sub\">ISO {}: no frame offsets measured.</p></figure>", i.iso);
            }
        }
        let _ = write!(o, "</div>");
    }
    Ok(())
}

fn f4(v: Option<f64>) -> String {
    v.map_or_else(|| "—".into(), |x| format!("{x:.4}"))
}

fn score_row(o: &mut String, m: &ModelScore, best: bool) {
    let _ = write!(
        o,
        "<tr{}><td class=\"l\">{}</td><td class=\"l\">{}</td><td>{:.4}</td><td>{:.4}</td><td>{:.4}</td>",
        if best { " class=\"best\"" } else { "" },
        esc(&m.name),
        esc(&m.origin),
        m.conditional_overall,
        m.marginal_overall,
        m.kl_overall
    );
    for p in 0..POSITIONS {
        let _ = write!(o, "<td>{}</td>", f4(m.conditional[p]));
    }
    let _ = write!(o, "</tr>");
}

fn floor_row(o: &mut String, f: &FloorScore) {
    let _ = write!(
        o,
        "<tr class=\"floor\"><td class=\"l\">floor</td><td class=\"l\">real half vs real half ({} / {} samples); × {:.2} at full size</td><td>{:.4}</td><td>{:.4}</td><td>{:.4}</td>",
        f.samples_a,
        f.samples_b,
        f.scale,
        f.conditional_scaled(),
        f.marginal_scaled(),
        f.kl_overall
    );
    for p in 0..POSITIONS {
        let _ = write!(o, "<td>{}</td>", f4(f.conditional[p].map(|v| v * f.scale)));
    }
    let _ = write!(o, "</tr>");
}

/// `r ± se`, or a dash.
fn ratio_cell(r: Option<f64>, se: Option<f64>) -> String {
    match (r, se) {
        (Some(r), Some(se)) => format!("{r:.3} ± {se:.3}"),
        (Some(r), None) => format!("{r:.3}"),
        _ => "—".into(),
    }
}

/// Row, column and frame-level noise and noise power spectra (`noisecal_core::metrics::spatial`).
fn spatial_section(o: &mut String, ev: &EvalReport) -> anyhow::Result<()> {
    let spatial: Vec<(u32, &SpatialEval)> = ev.isos.iter().filter_map(|i| Some((i.iso, i.spatial.as_ref()?))).collect();
    if spatial.is_empty() {
        return Ok(());
    }
    let _ = write!(o, "<h3>Spatial noise: rows, columns, frames, spectra</h3>");
    let _ = write!(
        o,
        "<p>A pixel-independent model cannot make banding. On the same flat pixels, per frame: the mean noise of each row (column), taken relative to its mean over the frames of its burst (fixed patterns are not banding) — their variance across rows, synthetic over real, is 1 when the synthetic frames band as much as the real ones and falls towards <code>1/(1 + m·σ_row²/σ²)</code> for a pixel-only model on a sensor with row noise; the row-offset JSD compares the distributions of those row values; the frame-offset ratio compares the spread of the frames' mean noise within a burst (black-level errors); the NPS distance is the mean |ln(P<sub>synth</sub>/P<sub>real</sub>)| over the row, column and radial curves of the noise power spectra of 32×32-pixel flat crops (per CFA plane, each spectrum divided by its white level so that only its shape counts; “NPS rows”: the row curve alone, where banding shows). The floor row is one half of the real frames against the other (JSD and NPS scaled to the full sample sizes): ratios there scatter around 1 by their standard error.</p>"
    );
    let ratios = plots::spatial_ratio_chart(ev, plots::Lines::Rows, (1040, 340))?;
    figure(
        o,
        &ratios,
        "Row-mean variance ratio synthetic/real per ISO (±1 SE); 1 is as much banding as the real frames.",
    );
    let cols = plots::spatial_ratio_chart(ev, plots::Lines::Columns, (1040, 300))?;
    figure(o, &cols, "Column-mean variance ratio synthetic/real per ISO (±1 SE).");
    for (iso, sp) in &spatial {
        let _ = write!(
            o,
            "<table><tr><th class=\"l\">ISO {iso}</th><th>row-mean var</th><th>col-mean var</th><th>row-offset JSD</th><th>NPS distance</th><th>NPS rows</th><th>frame-offset var</th></tr>"
        );
        for m in &sp.models {
            let c = &m.scores;
            let _ = write!(
                o,
                "<tr><td class=\"l\">{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                esc(&m.name),
                ratio_cell(c.row_var_ratio, c.row_var_ratio_se),
                ratio_cell(c.col_var_ratio, c.col_var_ratio_se),
                f4(c.row_offset_jsd),
                f4(c.nps_distance),
                f4(c.nps_row_distance),
                ratio_cell(c.frame_offset_var_ratio, None)
            );
        }
        if let Some(f) = &sp.floor {
            let c = &f.halves;
            let _ = write!(
                o,
                "<tr class=\"floor\"><td class=\"l\">floor (real halves)</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                ratio_cell(c.row_var_ratio, c.row_var_ratio_se),
                ratio_cell(c.col_var_ratio, c.col_var_ratio_se),
                f4(f.row_offset_jsd_scaled()),
                f4(f.nps_distance_scaled()),
                f4(f.nps_row_distance_scaled()),
                ratio_cell(c.frame_offset_var_ratio, None)
            );
        }
        let _ = write!(
            o,
            "</table><p class=\"sub\">Real: row-mean variance {} DN², column-mean {} DN² over {} frames.</p>",
            f4(sp.row_var),
            f4(sp.col_var),
            sp.frames
        );
    }
    let pos = 1usize.min(POSITIONS - 1);
    let pos_name = ev.positions.get(pos).cloned().unwrap_or_default();
    let _ = write!(o, "<div class=\"grid2\">");
    for (iso, sp) in &spatial {
        if sp.nps[pos].is_none() {
            continue;
        }
        let names: Vec<&str> = ["noisecal", "noisecal-pixel"].into_iter().filter(|n| sp.model(n).is_some()).collect();
        let svg = plots::nps_chart(sp, *iso, pos, &pos_name, &names, (520, 340))?;
        figure(
            o,
            &svg,
            &format!(
                "ISO {iso}, {pos_name}: noise power of flat crops, real (black) and synthetic; solid: at zero horizontal frequency, where row noise adds its power; dashed: off both axes (pixel noise)."
            ),
        );
    }
    let _ = write!(o, "</div>");
    Ok(())
}

fn eval_section(o: &mut String, ev: &EvalReport) -> anyhow::Result<()> {
    let _ = write!(o, "<h2 id=\"eval\">Fidelity on held-out captures</h2>");
    let _ = write!(
        o,
        "<p>Held-out set <code>{}</code>, {} synthetic set(s) per model. On flat pixels, real noise is <code>capture − round(clean)</code> and synthetic noise <code>synthesized − round(clean)</code> from the same clean image; the Jensen–Shannon divergence uses natural logs (0 … ln 2 ≈ 0.693). The conditional JSD scores each level group of {} bins separately (weighted by samples) and is the stricter one. The floor is the JSD between two halves of the real frames, scaled to the models' sample sizes: no model can be shown to be better than it.</p>",
        esc(&ev.heldout),
        ev.seeds,
        ev.group_bins
    );
    let svg = plots::eval_bars(ev, (1040, 380))?;
    figure(o, &svg, "Conditional JSD of each model per ISO; the dashed black mark is the scaled finite-sample floor.");
    for ie in &ev.isos {
        let total: u64 = ie.samples.iter().sum();
        let _ = write!(
            o,
            "<h3>ISO {} — pack model {}; {} frames, {} samples</h3>",
            ie.iso,
            esc(&ie.origin),
            ie.frames,
            total
        );
        let _ = write!(
            o,
            "<table><tr><th class=\"l\">model</th><th class=\"l\">origin</th><th>cond. JSD</th><th>marg. JSD</th><th>KL (add-one)</th>"
        );
        for n in &ev.positions {
            let _ = write!(o, "<th>cond. {}</th>", esc(n));
        }
        let _ = write!(o, "</tr>");
        let mut ranked: Vec<&ModelScore> = ie.models.iter().collect();
        ranked.sort_by(|a, b| a.conditional_overall.total_cmp(&b.conditional_overall));
        for (i, m) in ranked.iter().enumerate() {
            // What the row holds (e.g. the pixel noise alone, without the structured components)
            // beside where its model comes from.
            let shown = ModelScore { origin: format!("{}; {}", m.label, m.origin), ..(*m).clone() };
            score_row(o, &shown, i == 0);
        }
        if let Some(f) = &ie.floor {
            floor_row(o, f);
        }
        let _ = write!(o, "</table>");
    }
    spatial_section(o, ev)?;
    if let Some(rows) = &ev.leave_one_out {
        let _ = write!(o, "<h3>Leave-one-out interpolation (paper Fig. 4)</h3>");
        if rows.is_empty() {
            let _ = write!(o, "<p>No inner calibrated ISO had held-out frames.</p>");
        } else {
            let svg = plots::loo_bars(rows, (1040, 360))?;
            figure(
                o,
                &svg,
                "Each inner calibrated ISO removed from the pack and interpolated from the others (noisecal, Eq. 4–6) or parametrically (HG), scored on that ISO's held-out frames next to the calibrated models.",
            );
            let _ = write!(
                o,
                "<table><tr><th>ISO</th><th class=\"l\">from</th><th>calibrated</th><th>interpolated</th><th>HG calibrated</th><th>HG interpolated</th><th>floor</th></tr>"
            );
            for r in rows {
                let _ = write!(
                    o,
                    "<tr><td>{}</td><td class=\"l\">{:?}</td><td>{:.4}</td><td>{:.4}</td><td>{:.4}</td><td>{:.4}</td><td>{}</td></tr>",
                    r.iso,
                    r.from,
                    r.calibrated[0],
                    r.interpolated[0],
                    r.hg_calibrated[0],
                    r.hg_interpolated[0],
                    f4(r.floor.map(|f| f[0]))
                );
            }
            let _ = write!(o, "</table><p class=\"sub\">Conditional JSD (nats).</p>");
        }
    }
    if let Some(rn) = &ev.renoise {
        let _ = write!(o, "<h3>Noise on noise: ISO {} → {}</h3>", rn.from, rn.to);
        let svg = plots::renoise_bars(
            &rn.methods,
            rn.floor.as_ref().map(|f| f.conditional_scaled()),
            &format!("Held-out ISO {} frames re-noised to ISO {}, against real ISO {} frames", rn.from, rn.to, rn.to),
            (1040, 360),
        )?;
        figure(
            o,
            &svg,
            "bridge adds extra noise q with p_A ∗ q ≈ p_B; quantile maps the input's own noise; denoised adds ISO B noise to the clean estimate; naive adds ISO B noise to the noisy input; direct synthesizes ISO B on the true clean image (a reference, not a method).",
        );
        let _ = write!(
            o,
            "<table><tr><th class=\"l\">method</th><th class=\"l\">what</th><th>cond. JSD</th><th>marg. JSD</th><th>KL (add-one)</th>"
        );
        for n in &ev.positions {
            let _ = write!(o, "<th>cond. {}</th>", esc(n));
        }
        let _ = write!(o, "</tr>");
        for m in &rn.methods {
            let shown = ModelScore { origin: m.label.clone(), ..m.clone() };
            score_row(o, &shown, false);
        }
        if let Some(f) = &rn.floor {
            floor_row(o, f);
        }
        let _ = write!(o, "</table>");
        if !rn.warnings.is_empty() {
            let _ = write!(o, "<div class=\"warn\"><ul>");
            for w in rn.warnings.iter().take(12) {
                let _ = write!(o, "<li>{}</li>", esc(w));
            }
            let _ = write!(o, "</ul></div>");
        }
    }
    if !ev.notes.is_empty() {
        let _ = write!(o, "<h3>Notes</h3><ul>");
        for n in &ev.notes {
            let _ = write!(o, "<li>{}</li>", esc(n));
        }
        let _ = write!(o, "</ul>");
    }
    Ok(())
}
