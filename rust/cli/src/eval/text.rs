//! The text table `noisecal eval` prints.

use std::fmt::Write;

use noisecal_core::POSITIONS;

use noisecal_core::metrics::spatial::SpatialComparison;

use super::scores::{EvalReport, ModelScore, SpatialEval};

fn fmt_opt(v: Option<f64>) -> String {
    v.map_or_else(|| "—".into(), |x| format!("{x:.4}"))
}

/// The text table `noisecal eval` prints.
pub fn render_text(r: &EvalReport) -> String {
    let mut s = String::new();
    let pos = &r.positions;
    // The camera's make and model come from the pack (a DNG's tags): never raw to a terminal.
    let _ = writeln!(s, "pack {}  ({})", r.pack, crate::support::escape_terminal(&r.camera));
    let _ =
        writeln!(s, "held-out {}  ({} seed(s) per model, {} bins per level group)", r.heldout, r.seeds, r.group_bins);
    let _ = writeln!(
        s,
        "JSD in nats (0 … ln 2 = 0.6931), lower is closer to the real noise; cond = conditional (per level group), marg = marginal."
    );
    for ie in &r.isos {
        let total: u64 = ie.samples.iter().sum();
        let _ = writeln!(s);
        let _ = writeln!(
            s,
            "ISO {} — pack model {}; {} frames in {} EV step(s), {} flat-pixel samples",
            ie.iso, ie.origin, ie.frames, ie.steps, total
        );
        let _ = writeln!(
            s,
            "  {:<14} {:>8} {:>8} {:>8}   cond per position {:<32}",
            "model",
            "cond",
            "marg",
            "KL",
            pos.join(" / ")
        );
        let line = |s: &mut String, name: &str, c: f64, m: f64, kl: f64, per: &[Option<f64>; POSITIONS]| {
            let per: Vec<String> = per.iter().map(|v| fmt_opt(*v)).collect();
            let _ = writeln!(s, "  {name:<14} {c:>8.4} {m:>8.4} {kl:>8.4}   {}", per.join(" "));
        };
        let mut ranked: Vec<&ModelScore> = ie.models.iter().collect();
        ranked.sort_by(|a, b| a.conditional_overall.total_cmp(&b.conditional_overall));
        for m in &ranked {
            line(&mut s, &m.name, m.conditional_overall, m.marginal_overall, m.kl_overall, &m.conditional);
        }
        if let Some(f) = &ie.floor {
            line(&mut s, "floor (halves)", f.conditional_overall, f.marginal_overall, f.kl_overall, &f.conditional);
            let _ = writeln!(
                s,
                "  {:<14} {:>8.4} {:>8.4}            (halves' floor × {:.2}: the floor at the models' sample sizes)",
                "floor (scaled)",
                f.conditional_scaled(),
                f.marginal_scaled(),
                f.scale
            );
        }
        if let Some(sp) = &ie.spatial {
            spatial_lines(&mut s, sp);
        }
        // What each row holds (the pack's rows: which noise components).
        for m in ranked.iter().filter(|m| m.name.starts_with("noisecal")) {
            let _ = writeln!(s, "  {:<14} = {}", m.name, m.label);
        }
    }
    if let Some(rows) = &r.leave_one_out {
        let _ = writeln!(s);
        let _ = writeln!(s, "Leave-one-out (paper Fig. 4): conditional JSD / marginal JSD");
        let _ = writeln!(
            s,
            "  {:>6}  {:<22} {:>17} {:>17} {:>17} {:>17} {:>17}",
            "ISO",
            "interpolated from",
            "calibrated",
            "interpolated",
            "HG calibrated",
            "HG interpolated",
            "floor (scaled)"
        );
        for row in rows {
            let p = |v: [f64; 2]| format!("{:.4} / {:.4}", v[0], v[1]);
            let _ = writeln!(
                s,
                "  {:>6}  {:<22} {:>17} {:>17} {:>17} {:>17} {:>17}",
                row.iso,
                format!("{:?}", row.from),
                p(row.calibrated),
                p(row.interpolated),
                p(row.hg_calibrated),
                p(row.hg_interpolated),
                row.floor.map_or("—".into(), p)
            );
        }
        if rows.is_empty() {
            let _ = writeln!(s, "  (no inner calibrated ISO has held-out frames)");
        }
    }
    if let Some(rn) = &r.renoise {
        let _ = writeln!(s);
        let _ = writeln!(
            s,
            "Noise on noise ISO {} → {}: {} input frames re-noised, scored against {} real ISO {} frames in {} EV step(s)",
            rn.from, rn.to, rn.frames_from, rn.frames_to, rn.to, rn.steps
        );
        let _ = writeln!(s, "  {:<14} {:>8} {:>8} {:>8}", "method", "cond", "marg", "KL");
        for m in &rn.methods {
            let _ = writeln!(
                s,
                "  {:<14} {:>8.4} {:>8.4} {:>8.4}   {}",
                m.name, m.conditional_overall, m.marginal_overall, m.kl_overall, m.label
            );
        }
        if let Some(f) = &rn.floor {
            let _ = writeln!(
                s,
                "  {:<14} {:>8.4} {:>8.4}            (halves; × {:.2} = {:.4} / {:.4} at full size)",
                "floor",
                f.conditional_overall,
                f.marginal_overall,
                f.scale,
                f.conditional_scaled(),
                f.marginal_scaled()
            );
        }
        for w in &rn.warnings {
            let _ = writeln!(s, "  warning: {w}");
        }
    }
    if !r.notes.is_empty() {
        let _ = writeln!(s);
        let _ = writeln!(s, "notes:");
        for n in &r.notes {
            let _ = writeln!(s, "  - {n}");
        }
    }
    s
}

/// `r ± se` of a ratio, or a dash.
fn ratio(v: Option<f64>, se: Option<f64>) -> String {
    match (v, se) {
        (Some(r), Some(e)) => format!("{r:.3} ± {e:.3}"),
        (Some(r), None) => format!("{r:.3}"),
        _ => "—".into(),
    }
}

/// The spatial measures of one ISO (see `noisecal_core::metrics::spatial`).
fn spatial_lines(s: &mut String, sp: &SpatialEval) {
    let _ = writeln!(
        s,
        "  spatial, flat pixels — ratios synthetic/real (the floor row: real half/real half), JSD of row offsets, NPS distance (mean |ln P_synth/P_real|, spectra normalised to their white level; all curves, row curve):"
    );
    let _ = writeln!(
        s,
        "  {:<14} {:>15} {:>15} {:>10} {:>9} {:>9} {:>13}",
        "model", "row-mean var", "col-mean var", "row JSD", "NPS", "NPS rows", "frame-offset"
    );
    let row = |s: &mut String, name: &str, c: &SpatialComparison, jsd: Option<f64>, nps: [Option<f64>; 2]| {
        let _ = writeln!(
            s,
            "  {name:<14} {:>15} {:>15} {:>10} {:>9} {:>9} {:>13}",
            ratio(c.row_var_ratio, c.row_var_ratio_se),
            ratio(c.col_var_ratio, c.col_var_ratio_se),
            fmt_opt(jsd),
            fmt_opt(nps[0]),
            fmt_opt(nps[1]),
            ratio(c.frame_offset_var_ratio, None)
        );
    };
    for m in &sp.models {
        let c = &m.scores;
        row(s, &m.name, c, c.row_offset_jsd, [c.nps_distance, c.nps_row_distance]);
    }
    if let Some(f) = &sp.floor {
        let nps = [f.nps_distance_scaled(), f.nps_row_distance_scaled()];
        row(s, "floor (scaled)", &f.halves, f.row_offset_jsd_scaled(), nps);
    }
    let crops: u64 = sp.nps.iter().flatten().map(|c| c.periodograms).sum();
    let _ = writeln!(
        s,
        "  real: row-mean variance {} DN², column-mean {} DN² ({} frames, {} row means); NPS on {} crop×frame periodograms",
        fmt_opt(sp.row_var),
        fmt_opt(sp.col_var),
        sp.frames,
        sp.row_offsets,
        crops
    );
}
