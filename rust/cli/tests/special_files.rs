//! Special files never block a command or fill memory: a FIFO or a device as the pack or the
//! input is refused at once with a message naming it.

use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

mod support;

/// Runs `noisecal args…`, failing the test if it takes more than 20 s; returns (exit ok, stderr).
fn run(args: &[&str]) -> (bool, String) {
    let mut child = support::command()
        .args(args)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .expect("noisecal runs");
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().expect("wait") {
            let mut err = String::new();
            use std::io::Read;
            child.stderr.take().expect("stderr").read_to_string(&mut err).expect("stderr text");
            return (status.success(), err);
        }
        if start.elapsed() > Duration::from_secs(20) {
            let _ = child.kill();
            panic!("noisecal {args:?} still running after 20 s");
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn mkfifo(path: &Path) {
    let ok = Command::new("mkfifo").arg(path).status().expect("mkfifo runs").success();
    assert!(ok, "mkfifo {}", path.display());
}

#[test]
fn a_device_as_pack_is_refused_at_once() {
    let (ok, err) = run(&["inspect", "/dev/zero"]);
    assert!(!ok);
    assert!(err.contains("/dev/zero") && err.contains("not a regular file"), "{err}");
}

#[test]
fn a_fifo_as_pack_or_input_is_refused_without_blocking() {
    let dir = tempfile::tempdir().expect("temp dir");
    let fifo = dir.path().join("p.pack");
    mkfifo(&fifo);
    let f = fifo.to_str().expect("utf-8 path");
    let (ok, err) = run(&["inspect", f]);
    assert!(!ok && err.contains("not a regular file"), "{err}");
    let (ok, err) = run(&["calibrate", f, "-o", dir.path().join("out.pack").to_str().expect("utf-8")]);
    assert!(!ok && err.contains("not a regular file"), "{err}");
    assert!(!dir.path().join("out.pack").exists());
}

#[test]
fn an_absurd_thread_count_is_refused_before_any_thread_starts() {
    let (ok, err) = run(&["--threads", "100000", "inspect", "/dev/null"]);
    assert!(!ok);
    assert!(err.contains("--threads 100000") && err.contains("leave it out"), "{err}");
    // The cap is a multiple of the cores: 16 per core, at least 64, at most 1024.
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get());
    let cap = (16 * cores).clamp(64, 1024);
    let (ok, err) = run(&["--threads", &(cap + 1).to_string(), "inspect", "/dev/null"]);
    assert!(!ok && err.contains(&format!("the {cap} worker threads allowed")), "{err}");
    let (_, err) = run(&["--threads", &cap.to_string(), "inspect", "/dev/null"]);
    assert!(!err.contains("worker threads allowed") && err.contains("/dev/null"), "{err}");
}
