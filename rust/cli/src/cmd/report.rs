//! `noisecal report --pack p.pack [--eval heldout/ | --eval scores.json] [--bench bench.json]
//! -o report.html`: one self-contained HTML page with inline SVG plots.

use std::path::PathBuf;

use anyhow::Context;

use crate::cmd::eval::ScoringArgs;
use crate::eval::{EvalReport, evaluate};
use crate::report::bench_section::BenchResults;
use crate::report::render_html_with_bench;
use noisecal_input::files::load_pack;
use noisecal_input::files::write_atomic;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model pack.
    #[arg(long)]
    pub pack: PathBuf,
    /// Held-out captures to score the pack on (as `noisecal eval`), or the JSON that
    /// `noisecal eval --json` wrote.
    #[arg(long)]
    pub eval: Option<PathBuf>,
    /// With --eval on captures: how to score them (as `noisecal eval`).
    #[command(flatten)]
    pub scoring: ScoringArgs,
    /// The results of the denoiser benchmark (the JSON `noisecal-bench --json` wrote): a section
    /// with its table and chart.
    #[arg(long)]
    pub bench: Option<PathBuf>,
    /// The HTML file to write.
    #[arg(short, long)]
    pub output: PathBuf,
}

pub fn run(args: Args, quiet: bool) -> anyhow::Result<()> {
    let mut inputs: Vec<&std::path::Path> = vec![&args.pack];
    if let Some(e) = &args.eval {
        inputs.push(e);
    }
    if let Some(b) = &args.bench {
        inputs.push(b);
    }
    noisecal_input::files::refuse_overwriting_inputs(&args.output, &inputs)?;
    let pack = load_pack(&args.pack)?;
    let eval: Option<EvalReport> = match &args.eval {
        None => None,
        Some(p) if p.is_file() && p.extension().is_some_and(|e| e.eq_ignore_ascii_case("json")) => {
            let bytes = std::fs::read(p).with_context(|| format!("cannot read {}", p.display()))?;
            Some(
                serde_json::from_slice(&bytes)
                    .with_context(|| format!("{} is not the JSON of `noisecal eval --json`", p.display()))?,
            )
        }
        Some(p) => Some(evaluate(&pack, &args.pack, p, &args.scoring.options(), quiet)?),
    };
    let bench = args.bench.as_deref().map(BenchResults::load).transpose()?;
    let bench_name = args.bench.as_ref().map(|p| p.display().to_string()).unwrap_or_default();
    let html = render_html_with_bench(
        &pack,
        &args.pack.display().to_string(),
        eval.as_ref(),
        bench.as_ref().map(|b| (b, bench_name.as_str())),
    )?;
    write_atomic(&args.output, html.as_bytes()).with_context(|| format!("writing {}", args.output.display()))?;
    if !quiet {
        eprintln!("{}: {} KB", args.output.display(), html.len() / 1024);
    }
    Ok(())
}
