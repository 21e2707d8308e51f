//! What every subcommand needs and none owns: a progress bar, text on stdout, and telling a
//! closed stdout from a failure (pack files and output files: `noisecal_input::files`).

use std::io::{self, Write};
use std::path::Path;

use anyhow::Context;
use indicatif::{ProgressBar, ProgressStyle};
use noisecal_core::ModelPack;
use noisecal_input::calibrate::{CalibrateOptions, CalibrateReport, calibrate_path};

/// A progress bar over `len` frames on stderr (hidden with `--quiet`).
pub fn progress_bar(len: u64, quiet: bool, what: &str) -> ProgressBar {
    if quiet {
        return ProgressBar::hidden();
    }
    let pb = ProgressBar::new(len);
    pb.set_style(
        ProgressStyle::with_template("{msg:12} [{bar:40}] {pos}/{len} frames, {per_sec}, eta {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> "),
    );
    pb.set_message(what.to_string());
    pb
}

/// Calibrates from a DNG folder or a recording ([`calibrate_path`]) with a progress bar on
/// stderr (hidden with `--quiet`).
pub fn calibrate(path: &Path, opts: &CalibrateOptions, quiet: bool) -> anyhow::Result<(ModelPack, CalibrateReport)> {
    let pb = progress_bar(0, quiet, "calibrating");
    let done = calibrate_path(path, opts, &mut |frames, total| {
        pb.set_length(total);
        pb.set_position(frames);
    });
    pb.finish_and_clear();
    done
}

/// Writes `text` to stdout and flushes it. A closed stdout comes back as an error whose chain
/// holds an [`io::ErrorKind::BrokenPipe`] (see [`is_broken_pipe`]), never as a panic.
pub fn print(text: &str) -> anyhow::Result<()> {
    let mut out = io::stdout().lock();
    out.write_all(text.as_bytes()).context("writing to stdout")?;
    out.flush().context("writing to stdout")?;
    Ok(())
}

/// `s` made safe to print on a terminal: control characters (C0 but tab and newline, DEL, C1 —
/// the escape sequences a DNG's Make tag or a file name could carry) and bidirectional overrides
/// are shown as `\u{…}` escapes instead of being sent to the terminal.
pub fn escape_terminal(s: &str) -> std::borrow::Cow<'_, str> {
    let unsafe_char = |c: char| {
        (c.is_control() && c != '\n' && c != '\t') || matches!(c, '\u{202A}'..='\u{202E}' | '\u{2066}'..='\u{2069}')
    };
    if !s.chars().any(unsafe_char) {
        return std::borrow::Cow::Borrowed(s);
    }
    let mut o = String::with_capacity(s.len() + 8);
    for c in s.chars() {
        if unsafe_char(c) {
            o.push_str(&format!("\\u{{{:x}}}", c as u32));
        } else {
            o.push(c);
        }
    }
    std::borrow::Cow::Owned(o)
}

/// Whether an error is stdout (or another pipe) closed by its reader, as in
/// `noisecal inspect --json p.pack | head`: the program then ends quietly and successfully.
pub fn is_broken_pipe(err: &anyhow::Error) -> bool {
    err.chain().any(|cause| cause.downcast_ref::<io::Error>().is_some_and(|e| e.kind() == io::ErrorKind::BrokenPipe))
}

/// The error and its causes joined by `: ` as `{:#}` joins them, leaving out a cause its parent's
/// text already holds (an error that says its source, as [`noisecal_input::dng::DngError`]'s I/O error
/// does, would otherwise say it twice).
pub fn error_text(e: &anyhow::Error) -> String {
    let mut out = String::new();
    let mut parent = String::new();
    let remedy = noisecal_core::error::Remedy::in_chain(e.chain());
    for cause in e.chain() {
        let text = cause.to_string();
        if parent.is_empty() || !parent.contains(&text) {
            if !out.is_empty() {
                out.push_str(": ");
            }
            out.push_str(&text);
        }
        parent = text;
    }
    // The core names what to change; the flag that changes it is the CLI's.
    match remedy {
        Some(noisecal_core::error::Remedy::Extrapolate) => out.push_str(" (--extrapolate)"),
        Some(noisecal_core::error::Remedy::ParametricModel) => out.push_str(" (--model hg or pg)"),
        None => {}
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_cause_is_said_once() {
        let io = std::io::Error::other("x.dng is a named pipe (FIFO), not a regular file");
        let e =
            anyhow::Error::from(noisecal_input::dng::DngError::io(Path::new("x.dng"), io)).context("reading inputs");
        let text = error_text(&e);
        assert_eq!(text.matches("named pipe").count(), 1, "{text}");
        assert!(text.starts_with("reading inputs: x.dng: x.dng is a named pipe"), "{text}");
        let e = anyhow::anyhow!("inner").context("middle").context("outer");
        assert_eq!(error_text(&e), format!("{e:#}"));
    }

    #[test]
    fn broken_pipes_are_found_anywhere_in_the_chain() {
        let pipe = || io::Error::new(io::ErrorKind::BrokenPipe, "closed");
        assert!(is_broken_pipe(&anyhow::Error::new(pipe())));
        assert!(is_broken_pipe(&anyhow::Error::new(pipe()).context("writing to stdout").context("inspect")));
        let other = anyhow::Error::new(io::Error::new(io::ErrorKind::PermissionDenied, "no")).context("writing");
        assert!(!is_broken_pipe(&other));
        // Panic-like text is not a broken pipe: only the error kind counts.
        assert!(!is_broken_pipe(&anyhow::anyhow!("failed printing to stdout: Broken pipe (os error 32)")));
    }

    #[test]
    fn terminal_escapes_are_shown_not_sent() {
        assert_eq!(escape_terminal("Google Pixel 6\tok\n"), "Google Pixel 6\tok\n");
        assert_eq!(
            escape_terminal("\u{1b}]0;pwned\u{7}Evil\u{9b}2J\u{202e}"),
            "\\u{1b}]0;pwned\\u{7}Evil\\u{9b}2J\\u{202e}"
        );
    }
}
