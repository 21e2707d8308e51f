//! `-o` naming an input is refused by every command, also through symlinks and hard links, and
//! the input is left byte for byte as it was.

use std::path::{Path, PathBuf};

mod support;

fn noisecal(args: &[&Path]) -> (bool, String) {
    let out = support::run(std::iter::once(Path::new("-q")).chain(args.iter().copied()));
    (out.ok, out.stderr)
}

fn p(s: &str) -> PathBuf {
    PathBuf::from(s)
}

/// Runs a command that must be refused and checks `victim` is unchanged.
fn refused(args: &[&Path], victim: &Path) {
    let before = std::fs::read(victim).expect("victim readable");
    let (ok, err) = noisecal(args);
    assert!(!ok, "{args:?} succeeded");
    assert!(err.contains("never writes over what it reads"), "{args:?}: {err}");
    assert_eq!(std::fs::read(victim).expect("victim still there"), before, "{args:?} changed {}", victim.display());
}

#[test]
fn no_command_writes_over_its_inputs() {
    let dir = tempfile::tempdir().expect("temp dir");
    let d = dir.path();
    let (cal, rec, pack) = (d.join("cal"), d.join("s.rec"), d.join("p.pack"));
    let (ok, err) = noisecal(&[
        &p("simulate"),
        &p("--dngs"),
        &cal,
        &p("--rec"),
        &rec,
        &p("--width"),
        &p("64"),
        &p("--height"),
        &p("48"),
        &p("--frames"),
        &p("3"),
        &p("--isos"),
        &p("100,400"),
        &p("--ev=-2,0,2"),
    ]);
    assert!(ok, "{err}");
    let (ok, err) = noisecal(&[&p("calibrate"), &cal, &p("-o"), &pack]);
    assert!(ok, "{err}");
    let dng = std::fs::read_dir(&cal).expect("dngs").map(|e| e.expect("entry").path()).min().expect("a dng");
    let link = d.join("link.rec");
    std::os::unix::fs::symlink(&rec, &link).expect("symlink");
    let hard = d.join("hard.pack");
    std::fs::hard_link(&pack, &hard).expect("hard link");

    refused(&[&p("calibrate"), &rec, &p("-o"), &rec], &rec);
    refused(&[&p("calibrate"), &rec, &p("-o"), &link], &rec);
    refused(&[&p("calibrate"), &cal, &p("-o"), &dng], &dng);
    refused(&[&p("synth"), &p("--pack"), &pack, &p("--iso"), &p("400"), &dng, &p("-o"), &dng], &dng);
    refused(&[&p("synth"), &p("--pack"), &pack, &p("--iso"), &p("400"), &cal, &p("-o"), &cal], &dng);
    refused(&[&p("synth"), &p("--pack"), &pack, &p("--iso"), &p("400"), &dng, &p("-o"), &hard], &pack);
    refused(&[&p("eval"), &p("--pack"), &pack, &cal, &p("--json"), &pack], &pack);
    refused(&[&p("report"), &p("--pack"), &pack, &p("-o"), &hard], &pack);
    refused(&[&p("interp"), &p("--pack"), &pack, &p("--iso"), &p("200"), &p("-o"), &pack], &pack);
    refused(&[&p("renoise"), &p("--pack"), &pack, &p("--to-iso"), &p("400"), &dng, &p("-o"), &dng], &dng);
    // A different output is fine.
    let (ok, err) = noisecal(&[&p("interp"), &p("--pack"), &pack, &p("--iso"), &p("200"), &p("-o"), &d.join("i.pack")]);
    assert!(ok, "{err}");
}
