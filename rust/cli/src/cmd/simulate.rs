//! `noisecal simulate --dngs captures/ --rec session.rec`: a simulated phone session, for trying
//! the tool and for tests.

use std::path::PathBuf;

use anyhow::bail;

use crate::calibrate::progress_bar;
use crate::simulate::{Preset, SimSession};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Sensor preset.
    #[arg(long, value_enum, default_value_t = Preset::Phone10)]
    pub preset: Preset,
    #[arg(long, default_value_t = 320)]
    pub width: u32,
    #[arg(long, default_value_t = 240)]
    pub height: u32,
    /// Target ISOs (comma-separated).
    #[arg(long, value_delimiter = ',', default_values_t = [100u32, 200, 400, 800, 1600])]
    pub isos: Vec<u32>,
    /// Frames per burst.
    #[arg(long, default_value_t = 8)]
    pub frames: u32,
    /// EV steps (comma-separated).
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true, default_values_t = [-4i32, -3, -2, -1, 0, 1, 2, 3, 4])]
    pub ev: Vec<i32>,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Some frames flicker by this fraction (e.g. 0.03).
    #[arg(long)]
    pub flicker: Option<f32>,
    /// Write DNGs into this folder.
    #[arg(long)]
    pub dngs: Option<PathBuf>,
    /// Write a raw recording (the app's format) to this file.
    #[arg(long)]
    pub rec: Option<PathBuf>,
    /// Start frame indices here: the same sensor (same --seed) with fresh noise, e.g. a held-out set.
    #[arg(long, default_value_t = 0)]
    pub index_offset: u64,
    /// Extra bytes of padding per row in the recording (Camera2 row stride).
    #[arg(long, default_value_t = 32)]
    pub padding: usize,
}

pub fn run(args: Args, quiet: bool) -> anyhow::Result<()> {
    if args.dngs.is_none() && args.rec.is_none() {
        bail!("nothing to write: give --dngs DIR and/or --rec FILE");
    }
    let mut model = args.preset.model();
    if let Some(a) = args.flicker {
        model.flicker = Some(noisecal_sim::Flicker { probability: 0.1, amplitude: a });
    }
    let mut s = SimSession::new(
        model,
        args.preset.name(),
        args.width,
        args.height,
        args.seed,
        args.isos,
        args.frames,
        args.ev,
    )?;
    s.index_offset = args.index_offset;
    let pb = progress_bar(s.plan.len() as u64, quiet, "simulating");
    s.write(args.dngs.as_deref(), args.rec.as_deref(), args.padding, || pb.inc(1))?;
    pb.finish_and_clear();
    if !quiet {
        eprintln!("{} frames simulated ({}×{}, {})", s.plan.len(), args.width, args.height, args.preset.name());
    }
    Ok(())
}
