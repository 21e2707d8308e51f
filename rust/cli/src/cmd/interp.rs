//! `noisecal interp`: materialize interpolated (or, with `--extrapolate`, extrapolated) ISOs into
//! a copy of a model pack. Each new ISO is flagged as such in the pack (its origin lists the
//! calibrated ISOs it came from); calibrated ISOs are never replaced.

use std::io::Write;
use std::path::PathBuf;

use anyhow::{Context, bail};
use noisecal_core::derive::interp::{self, InterpOptions, Materialized};

use noisecal_input::files::load_pack;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model pack to read.
    #[arg(long, value_name = "PACK")]
    pub pack: PathBuf,
    /// An ISO to interpolate; repeat for several (`--iso 1000 --iso 2500`).
    #[arg(long = "iso", value_name = "ISO", required = true)]
    pub isos: Vec<u32>,
    /// Where to write the new pack (written atomically; may be the input pack).
    #[arg(short, long, value_name = "PACK")]
    pub output: PathBuf,
    /// Allow ISOs outside the calibrated range (extrapolated from the nearest calibrated ISOs).
    #[arg(long)]
    pub extrapolate: bool,
}

pub fn run(args: Args, quiet: bool) -> anyhow::Result<()> {
    noisecal_input::files::refuse_overwriting_inputs(&args.output, &[&args.pack])?;
    let pack = load_pack(&args.pack)?;
    let mut stdout = std::io::stdout().lock();
    if args.isos.contains(&0) {
        bail!("--iso 0 is not an ISO; give the sensitivities to interpolate, e.g. --iso 1000");
    }
    let switches = noisecal_core::derive::gain_switch::detect_gain_switches(&pack);
    for s in &switches {
        writeln!(stdout, "detected: {s}")?;
    }
    let (out, done) = interp::materialize(&pack, &args.isos, args.extrapolate, &InterpOptions::default())
        .context("cannot interpolate the ISOs asked for")?;
    let list = |v: &[u32]| v.iter().map(u32::to_string).collect::<Vec<_>>().join(", ");
    for step in &done {
        let plan = match step {
            Materialized::Kept(iso) => {
                writeln!(stdout, "ISO {iso}: calibrated in the pack; kept as is")?;
                continue;
            }
            Materialized::Derived(plan) => plan,
        };
        let iso = plan.iso;
        let how = if plan.extrapolated { "extrapolated" } else { "interpolated" };
        let shape = match plan.shape_from.as_slice() {
            [a, b] => format!("shape blended from ISO {a} and {b}"),
            [a] => format!("shape from ISO {a}"),
            _ => String::new(),
        };
        writeln!(stdout, "ISO {iso}: {how} from calibrated ISO {} ({shape})", list(&plan.neighbours))?;
        for s in &plan.avoided {
            let side = if s.above_iso <= plan.neighbours[0] { "below" } else { "above" };
            writeln!(
                stdout,
                "  avoided the conversion-gain switch between ISO {} and {}: calibrated ISOs {side} it were not used",
                s.below_iso, s.above_iso
            )?;
        }
        for (lo, hi) in &plan.unpinned {
            let what = if (*lo..=*hi).contains(&iso) { "stands on these two only" } else { "did not reach across it" };
            writeln!(
                stdout,
                "  {what}: between ISO {lo} and {hi} the read noise at black is not pinned, so a conversion-gain switch there can be neither shown nor ruled out"
            )?;
        }
        // The pack keeps this warning (materialize added it); say it too.
        if let Some(msg) = plan.gap_warning()
            && !quiet
        {
            eprintln!("noisecal: warning: {msg}");
        }
    }
    let bytes = out.to_bytes().context("cannot encode the new model pack")?;
    noisecal_input::files::write_atomic(&args.output, &bytes)?;
    writeln!(
        stdout,
        "wrote {} (ISOs {})",
        args.output.display(),
        out.isos
            .iter()
            .map(|m| if m.is_calibrated() { m.iso.to_string() } else { format!("{}*", m.iso) })
            .collect::<Vec<_>>()
            .join(", ")
    )?;
    writeln!(stdout, "  * interpolated or extrapolated, not calibrated")?;
    Ok(())
}
