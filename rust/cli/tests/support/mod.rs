//! Shared by the CLI's integration tests (`mod support;`): the one way they run the `noisecal`
//! binary, and the arguments of a small simulated session. A test file shapes [`Run`] into what
//! its assertions read; how the binary is started and what every run must never do (panic, exit
//! with the internal-error code 3) is written here once.

// Each test binary uses a part of this module.
#![allow(dead_code)]

use std::ffi::OsStr;
use std::process::{Command, Stdio};

/// The exit code of an internal error (a caught panic).
pub const INTERNAL_ERROR: i32 = 3;

/// The `noisecal` binary this test target was built with, as a command to add arguments to
/// (for runs that need their own pipes or a kill; [`run`] covers the rest).
pub fn command() -> Command {
    Command::new(env!("CARGO_BIN_EXE_noisecal"))
}

/// What a finished run of `noisecal` did.
#[derive(Debug)]
pub struct Run {
    pub ok: bool,
    pub stdout: String,
    pub stderr: String,
}

/// Runs `noisecal args…` to its end (stdin closed) and checks that no panic crossed the CLI and
/// that it did not end with an internal error, whatever the arguments.
pub fn run<S: AsRef<OsStr>>(args: impl IntoIterator<Item = S>) -> Run {
    let out = command().args(args).stdin(Stdio::null()).output().expect("run noisecal");
    let stderr = String::from_utf8_lossy(&out.stderr).into_owned();
    assert!(!stderr.contains("panicked"), "a panic crossed the CLI: {stderr}");
    assert_ne!(out.status.code(), Some(INTERNAL_ERROR), "internal error: {stderr}");
    Run { ok: out.status.success(), stdout: String::from_utf8_lossy(&out.stdout).into_owned(), stderr }
}

/// As [`run`] with `-q` (after the arguments).
pub fn run_quiet<S: AsRef<OsStr>>(args: impl IntoIterator<Item = S>) -> Run {
    let mut all: Vec<std::ffi::OsString> = args.into_iter().map(|a| a.as_ref().to_owned()).collect();
    all.push("-q".into());
    run(all)
}

/// The arguments of `noisecal simulate` for a small session: a `width`×`height` sensor, `frames`
/// a burst at each of `isos` (comma-separated) and EV step (`ev` as given, e.g. `--ev=-1,1`),
/// then `rest` (where to write, and any other flag).
pub fn simulate<'a>(
    (width, height): (&'a str, &'a str),
    frames: &'a str,
    isos: &'a str,
    ev: &'a str,
    rest: &[&'a str],
) -> Vec<&'a str> {
    let mut args = vec!["simulate", "--width", width, "--height", height, "--frames", frames, "--isos", isos, ev];
    args.extend_from_slice(rest);
    args
}

/// The arguments of an in-process `noisecal report` of `pack` into `output`: one synthetic set
/// per model, no leave-one-out or re-noise scoring unless the caller sets them on the result.
pub fn report_args(
    pack: &std::path::Path,
    eval: Option<std::path::PathBuf>,
    bench: Option<std::path::PathBuf>,
    output: &std::path::Path,
) -> noisecal_cli::cmd::report::Args {
    noisecal_cli::cmd::report::Args {
        pack: pack.to_path_buf(),
        eval,
        scoring: noisecal_cli::cmd::eval::ScoringArgs {
            seeds: 1,
            leave_one_out: false,
            renoise_from: None,
            to: None,
            group_bins: noisecal_core::metrics::DEFAULT_GROUP_BINS,
        },
        bench,
        output: output.to_path_buf(),
    }
}
