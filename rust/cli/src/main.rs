//! `noisecal`: calibrate a camera's noise from RAW bursts, synthesize realistic noise, interpolate
//! ISOs, re-noise captures and measure fidelity. A thin binary over `noisecal-core`.

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use noisecal_cli::cmd;
use noisecal_cli::support::is_broken_pipe;

mod huge_pages;

/// Large blocks in huge pages (fewer page faults; the same bytes).
#[global_allocator]
static ALLOCATOR: huge_pages::HugePages = huge_pages::HugePages;

#[derive(Parser, Debug)]
#[command(name = "noisecal", version, about = "Calibrated, non-parametric camera noise models", long_about = None)]
struct Cli {
    /// Worker threads (default: all cores). Results do not depend on it.
    #[arg(long, global = true)]
    threads: Option<usize>,
    /// Only errors on stderr.
    #[arg(long, short, global = true)]
    quiet: bool,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Simulate a phone session, write it as DNGs, calibrate, synthesize and summarize.
    Demo(cmd::demo::Args),
    /// Write a simulated capture session as a DNG folder and/or a raw recording.
    Simulate(cmd::simulate::Args),
    /// Build a model pack from a folder of DNG bursts or a raw recording.
    Calibrate(cmd::calibrate::Args),
    /// Show what a model pack holds.
    Inspect(cmd::inspect::Args),
    /// Add calibrated noise at an ISO to clean raw DNGs.
    Synth(cmd::synth::Args),
    /// Materialize interpolated ISOs into a pack.
    Interp(cmd::interp::Args),
    /// Score noisecal and baselines against held-out captures (JSD, KL).
    Eval(cmd::eval::Args),
    /// Write a self-contained HTML report with plots.
    Report(cmd::report::Args),
    /// Turn captures at one ISO into realistic captures at a higher ISO.
    Renoise(cmd::renoise::Args),
}

/// The most worker threads `--threads` may ask for: 16 per core, at least 64, at most 1024.
fn max_threads() -> usize {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    cores.saturating_mul(16).clamp(64, 1024)
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let level = if cli.quiet { "error" } else { "warn" };
    env_logger::Builder::from_env(env_logger::Env::default().default_filter_or(level)).format_timestamp(None).init();
    let cap = max_threads();
    if let Some(n) = cli.threads
        && n > cap
    {
        eprintln!(
            "noisecal: --threads {n} is more than the {cap} worker threads allowed on this machine (16 per core); results do not depend on it, so leave it out to use every core"
        );
        return ExitCode::from(2);
    }
    if let Some(n) = cli.threads
        && let Err(e) = rayon::ThreadPoolBuilder::new().num_threads(n.max(1)).build_global()
    {
        eprintln!("noisecal: cannot set {n} threads: {e}");
        return ExitCode::from(2);
    }
    let quiet = cli.quiet;
    // A panic is a bug: report it as one. A closed stdout (`noisecal inspect --json | head`) is
    // an ordinary I/O error of kind BrokenPipe (Rust ignores SIGPIPE), found in the error chain.
    let result = std::panic::catch_unwind(move || match cli.command {
        Command::Demo(a) => cmd::demo::run(a, quiet),
        Command::Simulate(a) => cmd::simulate::run(a, quiet),
        Command::Calibrate(a) => cmd::calibrate::run(a, quiet),
        Command::Inspect(a) => cmd::inspect::run(a),
        Command::Synth(a) => cmd::synth::run(a, quiet),
        Command::Interp(a) => cmd::interp::run(a, quiet),
        Command::Eval(a) => cmd::eval::run(a, quiet),
        Command::Report(a) => cmd::report::run(a, quiet),
        Command::Renoise(a) => cmd::renoise::run(a, quiet),
    });
    match result {
        Ok(Ok(())) => ExitCode::SUCCESS,
        Ok(Err(e)) if is_broken_pipe(&e) => ExitCode::SUCCESS,
        Ok(Err(e)) => {
            eprintln!(
                "noisecal: error: {}",
                noisecal_cli::support::escape_terminal(&noisecal_cli::support::error_text(&e))
            );
            ExitCode::FAILURE
        }
        Err(_) => {
            eprintln!("noisecal: internal error (a bug): please report it with the command line you ran");
            ExitCode::from(3)
        }
    }
}
