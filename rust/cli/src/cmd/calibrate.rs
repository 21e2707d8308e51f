//! `noisecal calibrate captures/ -o pixel6.pack` (or `session.rec`).

use std::path::PathBuf;

use anyhow::Context;
use noisecal_core::calibrate::flat::Roi;

use crate::support::escape_terminal;
use noisecal_input::calibrate::CalibrateOptions;
use noisecal_input::files::write_atomic;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// A folder of DNGs (any order, any names) or a raw recording (.rec) made by the app.
    pub input: PathBuf,
    /// The model pack to write.
    #[arg(short, long)]
    pub output: PathBuf,
    /// Reference ISO (default: the lowest ISO found).
    #[arg(long)]
    pub reference_iso: Option<u32>,
    /// Levels per bin in DN (default: ~240 bins between black and white).
    #[arg(long, value_parser = crate::cmd::bounds::bin_width)]
    pub bin_width: Option<u16>,
    /// Pool every bin with its neighbours until it holds this many samples (default: chosen per
    /// ISO and CFA position by cross-validation on held-out frames; 0 = each bin's own histogram).
    #[arg(long, alias = "min-samples")]
    pub pooling: Option<u64>,
    /// Write the plain per-bin histograms instead of the estimator's PMFs (each bin its own
    /// samples, the nearest bin with samples for empty ones): a yardstick for `eval`.
    #[arg(long, conflicts_with = "pooling")]
    pub plain: bool,
    /// Only use pixels in this rectangle: x0,y0,x1,y1 (pixels, end exclusive).
    #[arg(long, value_parser = parse_roi)]
    pub roi: Option<Roi>,
    /// Flat-test threshold in standard deviations (default 4.5).
    #[arg(long, value_parser = crate::cmd::bounds::positive_finite)]
    pub flat_k: Option<f64>,
    /// Report frames whose brightness drifted (flicker) but use them as they are.
    #[arg(long)]
    pub no_drift_normalise: bool,
}

pub fn parse_roi(s: &str) -> Result<Roi, String> {
    let v: Vec<u32> = s
        .split(',')
        .map(|p| p.trim().parse::<u32>().map_err(|_| format!("'{p}' is not a pixel coordinate")))
        .collect::<Result<_, _>>()?;
    match v[..] {
        [x0, y0, x1, y1] if x1 > x0 && y1 > y0 => Ok(Roi { x0, y0, x1, y1 }),
        _ => Err("expected x0,y0,x1,y1 with x1 > x0 and y1 > y0".into()),
    }
}

pub fn run(args: Args, quiet: bool) -> anyhow::Result<()> {
    let opts = CalibrateOptions {
        reference_iso: args.reference_iso,
        bin_width: args.bin_width,
        pooling: args.pooling,
        plain: args.plain,
        roi: args.roi,
        flat_k: args.flat_k,
        no_drift_normalise: args.no_drift_normalise,
    };
    noisecal_input::files::refuse_overwriting_inputs(&args.output, &[&args.input])?;
    let (pack, report) = crate::support::calibrate(&args.input, &opts, quiet)?;
    let bytes = pack.to_bytes()?;
    write_atomic(&args.output, &bytes).with_context(|| format!("writing {}", args.output.display()))?;
    // `-q`: only errors on stderr. The warnings stay in the pack (`noisecal inspect` shows them).
    if quiet {
        return Ok(());
    }
    for w in report.warnings.iter().chain(&pack.warnings) {
        eprintln!("warning: {}", escape_terminal(w));
    }
    // What one more capture would settle about the conversion gain between the ISOs taken.
    use noisecal_core::derive::gain_switch::{calibrated_laws, capture_advice};
    for a in capture_advice(&calibrated_laws(&pack)) {
        eprintln!("note: {a}");
    }
    if !report.rejected.is_empty() {
        eprintln!("{} of {} frames rejected, by reason:", report.rejected.len(), report.frames);
        for r in &report.rejection_reasons {
            eprintln!("  {}", escape_terminal(r));
        }
        eprintln!("rejected frames:");
        for r in report.rejected.iter().take(20) {
            eprintln!("  {}", escape_terminal(r));
        }
        if report.rejected.len() > 20 {
            eprintln!("  … and {} more", report.rejected.len() - 20);
        }
    }
    eprintln!(
        "{}: {} frames, ISOs {} (reference {}), {} bytes",
        args.output.display(),
        report.frames,
        pack.iso_summary(),
        pack.reference_iso,
        bytes.len()
    );
    Ok(())
}
