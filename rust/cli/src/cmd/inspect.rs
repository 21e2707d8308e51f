//! `noisecal inspect pixel6.pack [--json]`: sensor, ISOs, frames, samples per bin, gain ratios,
//! warnings.

use std::path::PathBuf;

use std::fmt::Write;

use noisecal_core::{ModelPack, POSITIONS};
use serde::Serialize;

use crate::models::origin_text;
use noisecal_input::files::load_pack;

use crate::support::{escape_terminal, print};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model pack.
    pub pack: PathBuf,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
}

#[derive(Serialize)]
struct PositionSummary {
    name: String,
    samples: u64,
    bins: usize,
    /// Bins without samples of their own (filled by the noise law from neighbours).
    filled_bins: usize,
    /// Bins whose own samples were pooled with neighbours'.
    pooled_bins: usize,
    /// Bins whose noise reaches 0 or white.
    clipped_bins: usize,
    /// Pooling threshold the estimator chose (samples; 0 = each bin's own histogram).
    pooling: Option<u64>,
    /// What clipped bins hold: `own` histogram or `law` (unclipped noise, clipped when synthesizing).
    clip_mode: Option<String>,
    /// Held-out cross-entropy of the plain per-bin histogram minus the pack's (nats per sample;
    /// ≥ 0: the pack is at least as likely on held-out frames).
    heldout_gain: Option<f64>,
    gain_ratio: f64,
}

#[derive(Serialize)]
struct IsoSummary {
    iso: u32,
    origin: String,
    frames: u64,
    drift_frames: u64,
    noise_profile: bool,
    positions: Vec<PositionSummary>,
    /// Row, column and frame offsets (version 3 packs; absent when the pack has none).
    #[serde(skip_serializing_if = "Option::is_none")]
    structure: Option<StructureSummary>,
}

/// One structured component: its standard deviation (DN, sampling noise taken out) and whether
/// synthesis adds it.
#[derive(Serialize)]
struct ComponentSummary {
    sd: f64,
    added: bool,
}

/// The fixed pattern of one ISO: its SD (DN, pixels and shading), the shading's part, the dark
/// frames' temporal SD (signal-independent noise at black), and whether synthesis adds it.
#[derive(Serialize)]
struct PatternSummary {
    sd: f64,
    shading_sd: f64,
    temporal_sd: f64,
    dark_frames: u32,
    added: bool,
}

#[derive(Serialize)]
struct StructureSummary {
    /// Per row parity.
    rows: [Option<ComponentSummary>; 2],
    /// Per column parity.
    columns: [Option<ComponentSummary>; 2],
    /// Per CFA position.
    frames: Option<[ComponentSummary; POSITIONS]>,
    /// Target frames in bursts of two or more (what the offsets were measured on).
    frames_used: u64,
    /// The fixed pattern (dark frames), when measured.
    #[serde(skip_serializing_if = "Option::is_none")]
    fpn: Option<PatternSummary>,
    /// Whether the offsets were derived from other ISOs' (interpolated or extrapolated).
    derived: bool,
}

fn structure_summary(p: &ModelPack, iso: u32) -> Option<StructureSummary> {
    let stored = p.structure_of(iso);
    let st = noisecal_core::derive::structure::structure_at(p, iso)?;
    let line = |d: &Option<noisecal_core::model::structure::OffsetDistribution>| {
        d.as_ref().map(|d| ComponentSummary { sd: d.sd(), added: d.significant })
    };
    Some(StructureSummary {
        rows: [line(&st.rows[0]), line(&st.rows[1])],
        columns: [line(&st.columns[0]), line(&st.columns[1])],
        frames: st.frames.as_ref().map(|f| {
            std::array::from_fn(|pos| ComponentSummary {
                sd: f.variance(pos).sqrt(),
                added: f.significant && !f.offsets.is_empty(),
            })
        }),
        frames_used: st.frames_used,
        fpn: st.fpn.as_ref().map(|f| PatternSummary {
            sd: f.sd(),
            shading_sd: ((0..POSITIONS).map(|p| f.shading_var(p)).sum::<f64>() / POSITIONS as f64).sqrt(),
            temporal_sd: (f.temporal_var.iter().sum::<f64>() / POSITIONS as f64).sqrt(),
            dark_frames: f.frames,
            added: f.significant,
        }),
        derived: stored.is_none() || p.iso(iso).is_some_and(|m| !m.is_calibrated()),
    })
}

#[derive(Serialize)]
struct PackSummary {
    make: String,
    model: String,
    width: u32,
    height: u32,
    cfa: String,
    black: [f32; POSITIONS],
    white: u16,
    bit_depth: u32,
    bin_width: u16,
    reference_iso: u32,
    /// Pooling fixed by the user at calibration (`null`: cross-validated).
    pooling: Option<u64>,
    isos: Vec<IsoSummary>,
    warnings: Vec<String>,
}

fn summarize(p: &ModelPack) -> PackSummary {
    PackSummary {
        make: p.make.clone(),
        model: p.model.clone(),
        width: p.layout.width,
        height: p.layout.height,
        cfa: p.layout.cfa.to_string(),
        black: p.layout.black,
        white: p.layout.white,
        bit_depth: p.layout.bit_depth(),
        bin_width: p.bin_width,
        reference_iso: p.reference_iso,
        pooling: p.pooling,
        isos: p
            .isos
            .iter()
            .map(|m| IsoSummary {
                iso: m.iso,
                origin: origin_text(&m.origin),
                frames: m.frames,
                drift_frames: m.drift_frames,
                noise_profile: m.noise_profile.is_some(),
                structure: structure_summary(p, m.iso),
                positions: (0..POSITIONS)
                    .map(|pos| PositionSummary {
                        name: p.layout.cfa.position_name(pos).to_string(),
                        samples: m.samples(pos),
                        bins: m.positions[pos].bins.len(),
                        filled_bins: m.filled_bins(pos),
                        pooled_bins: m.pooled_bins(pos),
                        clipped_bins: m.positions[pos].bins.iter().filter(|b| b.clipped).count(),
                        pooling: m.positions[pos].estimate.as_ref().map(|e| e.pooling),
                        clip_mode: m.positions[pos]
                            .estimate
                            .as_ref()
                            .map(|e| format!("{:?}", e.clip_mode).to_lowercase()),
                        heldout_gain: m.positions[pos]
                            .estimate
                            .as_ref()
                            .and_then(|e| e.gain_over_plain())
                            .map(|(plain, chosen)| plain - chosen),
                        gain_ratio: m.gain_ratio[pos],
                    })
                    .collect(),
            })
            .collect(),
        warnings: {
            // The pack's own warnings, then what the self-check finds now (older packs never ran it).
            let mut w = p.warnings.clone();
            for f in noisecal_core::model::check::self_check(p) {
                let f = f.to_string();
                if !w.contains(&f) {
                    w.push(f);
                }
            }
            w
        },
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let pack = load_pack(&args.pack)?;
    let s = summarize(&pack);
    if args.json {
        return print(&format!("{}\n", serde_json::to_string_pretty(&s)?));
    }
    print(&render_text(&args.pack, &pack, &s))
}

/// The text `noisecal inspect` prints.
fn render_text(path: &std::path::Path, pack: &ModelPack, s: &PackSummary) -> String {
    let mut o = String::new();
    // Make, model and warnings come from the captures (a DNG's tags): escaped, never sent raw.
    let _ = writeln!(o, "{}", escape_terminal(&path.display().to_string()));
    let _ = writeln!(o, "  camera     {} {}", escape_terminal(&s.make), escape_terminal(&s.model));
    let _ = writeln!(o, "  sensor     {} ({}-bit)", pack.layout.describe(), s.bit_depth);
    let pooling = match s.pooling {
        Some(m) => format!("pooled to {m} samples (fixed at calibration)"),
        None => "pooling chosen per ISO and position on held-out frames".to_string(),
    };
    let _ = writeln!(o, "  bins       {} DN wide, {pooling}", s.bin_width);
    let _ = writeln!(o, "  reference  ISO {}", s.reference_iso);
    let _ = writeln!(o);
    let _ = writeln!(
        o,
        "  {:>6}  {:<26} {:>6} {:>5}  {:<4} {:>12} {:>7} {:>7} {:>7} {:>8} {:>9} {:>9}",
        "ISO",
        "origin",
        "frames",
        "drift",
        "pos",
        "samples",
        "filled",
        "pooled",
        "clipped",
        "pooling",
        "gain",
        "held-out"
    );
    for iso in &s.isos {
        for (i, ps) in iso.positions.iter().enumerate() {
            let (a, b, c, d) = if i == 0 {
                (iso.iso.to_string(), iso.origin.clone(), iso.frames.to_string(), iso.drift_frames.to_string())
            } else {
                Default::default()
            };
            let pooling = ps.pooling.map_or("-".to_string(), |m| m.to_string());
            let heldout = ps.heldout_gain.map_or("-".to_string(), |g| format!("{:+.4}", -g));
            let _ = writeln!(
                o,
                "  {a:>6}  {b:<26} {c:>6} {d:>5}  {:<4} {:>12} {:>7} {:>7} {:>7} {:>8} {:>9.4} {:>9}",
                ps.name, ps.samples, ps.filled_bins, ps.pooled_bins, ps.clipped_bins, pooling, ps.gain_ratio, heldout
            );
        }
    }
    let _ = writeln!(o);
    let _ = writeln!(
        o,
        "  held-out: the pack's held-out cross-entropy minus the plain per-bin histogram's (nats per sample; ≤ 0 is better)"
    );
    if s.isos.iter().any(|i| i.structure.is_some()) {
        let _ = writeln!(o);
        let _ = writeln!(
            o,
            "  structured noise (RMS in DN, sampling noise taken out; * = added at synthesis, else below detection):"
        );
        let _ = writeln!(
            o,
            "  {:>6}  {:<17} {:<17} {:<35} {:>6}  {:<24}",
            "ISO", "rows (even, odd)", "columns", "frame offsets per position", "frames", "fixed pattern (shading)"
        );
        let c = |x: &Option<ComponentSummary>| match x {
            Some(c) => format!("{:.3}{}", c.sd, if c.added { "*" } else { "" }),
            None => "-".into(),
        };
        for iso in &s.isos {
            let Some(st) = &iso.structure else { continue };
            let frames = match &st.frames {
                Some(f) => f
                    .iter()
                    .map(|c| format!("{:.3}{}", c.sd, if c.added { "*" } else { "" }))
                    .collect::<Vec<_>>()
                    .join(" "),
                None => "-".into(),
            };
            let fpn = match &st.fpn {
                Some(f) => format!("{:.3}{} ({:.3})", f.sd, if f.added { "*" } else { "" }, f.shading_sd),
                None => "-".into(),
            };
            let _ = writeln!(
                o,
                "  {:>6}  {:<17} {:<17} {:<35} {:>6}  {:<24}{}",
                iso.iso,
                format!("{} {}", c(&st.rows[0]), c(&st.rows[1])),
                format!("{} {}", c(&st.columns[0]), c(&st.columns[1])),
                frames,
                st.frames_used,
                fpn,
                if st.derived { "  (derived from calibrated ISOs)" } else { "" }
            );
        }
    }
    if !s.warnings.is_empty() {
        let _ = writeln!(o);
        let _ = writeln!(o, "  warnings:");
        for w in &s.warnings {
            let _ = writeln!(o, "    - {}", escape_terminal(w));
        }
    }
    o
}
