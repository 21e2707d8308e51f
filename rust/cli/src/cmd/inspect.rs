//! `noisecal inspect pixel6.pack [--json]`: sensor, ISOs, frames, samples per bin, gain ratios,
//! warnings.

use std::path::PathBuf;

use anyhow::Context;
use noisecal_core::pack::ModelOrigin;
use noisecal_core::{ModelPack, POSITIONS};
use serde::Serialize;

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
    filled_bins: usize,
    min_samples_in_measured_bin: u64,
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
    min_samples: u64,
    isos: Vec<IsoSummary>,
    warnings: Vec<String>,
}

/// Reads a pack file with a message that names it.
pub fn load_pack(path: &std::path::Path) -> anyhow::Result<ModelPack> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read model pack {}", path.display()))?;
    ModelPack::from_bytes(&bytes).with_context(|| format!("{} is not a usable model pack", path.display()))
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
        min_samples: p.min_samples,
        isos: p
            .isos
            .iter()
            .map(|m| IsoSummary {
                iso: m.iso,
                origin: match &m.origin {
                    ModelOrigin::Calibrated => "calibrated".into(),
                    ModelOrigin::Interpolated { from } => format!("interpolated from {from:?}"),
                    ModelOrigin::Extrapolated { from } => format!("extrapolated from {from:?}"),
                },
                frames: m.frames,
                drift_frames: m.drift_frames,
                noise_profile: m.noise_profile.is_some(),
                positions: (0..POSITIONS)
                    .map(|pos| PositionSummary {
                        name: p.layout.cfa.position_name(pos).to_string(),
                        samples: m.samples(pos),
                        bins: m.positions[pos].bins.len(),
                        filled_bins: m.filled_bins(pos),
                        min_samples_in_measured_bin: m.positions[pos]
                            .bins
                            .iter()
                            .filter(|b| !b.filled)
                            .map(|b| b.samples)
                            .min()
                            .unwrap_or(0),
                        gain_ratio: m.gain_ratio[pos],
                    })
                    .collect(),
            })
            .collect(),
        warnings: p.warnings.clone(),
    }
}

pub fn run(args: Args) -> anyhow::Result<()> {
    let pack = load_pack(&args.pack)?;
    let s = summarize(&pack);
    if args.json {
        println!("{}", serde_json::to_string_pretty(&s)?);
        return Ok(());
    }
    println!("{}", args.pack.display());
    println!("  camera     {} {}", s.make, s.model);
    println!("  sensor     {} ({}-bit)", pack.layout.describe(), s.bit_depth);
    println!("  bins       {} DN wide, filled below {} samples", s.bin_width, s.min_samples);
    println!("  reference  ISO {}", s.reference_iso);
    println!();
    println!(
        "  {:>6}  {:<26} {:>6} {:>5}  {:<4} {:>12} {:>7} {:>9}",
        "ISO", "origin", "frames", "drift", "pos", "samples", "filled", "gain"
    );
    for iso in &s.isos {
        for (i, ps) in iso.positions.iter().enumerate() {
            let (a, b, c, d) = if i == 0 {
                (iso.iso.to_string(), iso.origin.clone(), iso.frames.to_string(), iso.drift_frames.to_string())
            } else {
                Default::default()
            };
            println!(
                "  {a:>6}  {b:<26} {c:>6} {d:>5}  {:<4} {:>12} {:>3}/{:<3} {:>9.4}",
                ps.name, ps.samples, ps.filled_bins, ps.bins, ps.gain_ratio
            );
        }
    }
    if !s.warnings.is_empty() {
        println!();
        println!("  warnings:");
        for w in &s.warnings {
            println!("    - {w}");
        }
    }
    Ok(())
}
