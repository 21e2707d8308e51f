//! `noisecal eval --pack p.pack heldout/ [--json out.json] [--seeds N] [--leave-one-out]
//! [--renoise-from A --to B]`: JSD (and KL) of noisecal and the baselines against held-out
//! captures, per ISO and CFA position, with the finite-sample floor.

use std::path::PathBuf;

use anyhow::Context;

use crate::eval::{EvalOptions, evaluate, render_text};
use noisecal_input::files::load_pack;
use noisecal_input::files::write_atomic;

use crate::support::print;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model pack.
    #[arg(long)]
    pub pack: PathBuf,
    /// Held-out captures laid out like a calibration session (a reference burst per EV step,
    /// a few frames per ISO): a DNG folder or a recording.
    pub heldout: PathBuf,
    /// Also write every score (per ISO, position, level group and seed) as JSON.
    #[arg(long)]
    pub json: Option<PathBuf>,
    #[command(flatten)]
    pub scoring: ScoringArgs,
}

/// How held-out captures are scored: the options `eval` and `report --eval` share.
#[derive(clap::Args, Debug, Clone, PartialEq)]
pub struct ScoringArgs {
    /// Synthetic sets per model (seeds 0..N); scores are their mean.
    #[arg(long, default_value_t = 3, value_parser = clap::value_parser!(u32).range(crate::cmd::bounds::SEEDS))]
    pub seeds: u32,
    /// Pack bins per level group of the conditional JSD.
    #[arg(long, default_value_t = noisecal_core::metrics::DEFAULT_GROUP_BINS, value_parser = crate::cmd::bounds::group_bins)]
    pub group_bins: usize,
    /// Remove each inner calibrated ISO, interpolate it from the rest and score it (paper Fig. 4).
    #[arg(long)]
    pub leave_one_out: bool,
    /// Score noise on noise: re-noise the held-out frames at this ISO …
    #[arg(long, requires = "to")]
    pub renoise_from: Option<u32>,
    /// … to this ISO, against the real frames there.
    #[arg(long, requires = "renoise_from")]
    pub to: Option<u32>,
}

impl ScoringArgs {
    pub fn options(&self) -> EvalOptions {
        EvalOptions {
            seeds: self.seeds,
            group_bins: self.group_bins,
            leave_one_out: self.leave_one_out,
            renoise: self.renoise_from.zip(self.to),
        }
    }
}

pub fn run(args: Args, quiet: bool) -> anyhow::Result<()> {
    if let Some(json) = &args.json {
        noisecal_input::files::refuse_overwriting_inputs(json, &[&args.pack, &args.heldout])?;
    }
    let pack = load_pack(&args.pack)?;
    let report = evaluate(&pack, &args.pack, &args.heldout, &args.scoring.options(), quiet)?;
    print(&render_text(&report))?;
    if let Some(path) = &args.json {
        let bytes = serde_json::to_vec_pretty(&report).context("serializing the scores")?;
        write_atomic(path, &bytes).with_context(|| format!("writing {}", path.display()))?;
        if !quiet {
            eprintln!("scores written to {}", path.display());
        }
    }
    Ok(())
}
