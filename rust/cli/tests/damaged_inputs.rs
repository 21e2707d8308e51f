//! Damaged inputs through the real binary: damaged recordings are never taken for an
//! interrupted capture (a flipped length) nor for good (records removed or duplicated), temporary
//! files of killed runs are swept, and messages say what is wrong.

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant, SystemTime};

use noisecal_core::format::recording::{Record, RecordingReader, RecordingWriter};

mod support;

fn run(args: &[&str]) -> (bool, String, String) {
    let out = support::run(args);
    (out.ok, out.stdout, out.stderr)
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

/// A 64×48 session as a recording: 2 EV steps, 3 frames per burst, ISOs 200 and 800.
fn simulate_rec(dir: &Path) -> PathBuf {
    let rec = dir.join("s.rec");
    let (ok, _, err) = run(&support::simulate(("64", "48"), "3", "200,800", "--ev=-1,1", &["-q", "--rec", s(&rec)]));
    assert!(ok, "{err}");
    rec
}

/// Each record's (tag, offset, length) in a recording.
fn records(b: &[u8]) -> Vec<(u8, usize, usize)> {
    let hlen = u32::from_le_bytes(b[10..14].try_into().expect("4 bytes")) as usize;
    let mut at = 14 + hlen + 4;
    let mut v = Vec::new();
    while at < b.len() {
        let tag = b[at];
        let len = match tag {
            1 | 255 => 1 + 8 + 4,
            3 => 1 + 68 + 4,
            2 => 1 + 49 + 4 + u32::from_le_bytes(b[at + 46..at + 50].try_into().expect("4 bytes")) as usize,
            t => panic!("unexpected tag {t}"),
        };
        v.push((tag, at, len));
        at += len;
    }
    v
}

fn frame_records(b: &[u8]) -> Vec<(usize, usize, usize)> {
    records(b).into_iter().enumerate().filter(|(_, r)| r.0 == 2).map(|(i, (_, at, len))| (i, at, len)).collect()
}

/// Calibrates `rec` over an existing pack: must fail, name what it says, leave the pack as it was.
fn refused(dir: &Path, rec: &[u8], name: &str, says: &[&str]) {
    let path = dir.join(name);
    std::fs::write(&path, rec).expect("write damaged recording");
    let pack = dir.join("p.pack");
    let before = std::fs::read(&pack).expect("pack");
    let (ok, _, err) = run(&["calibrate", s(&path), "-o", s(&pack)]);
    assert!(!ok, "{name}: damaged data taken for good: {err}");
    for w in says {
        assert!(err.contains(w), "{name}: expected {w:?} in: {err}");
    }
    assert!(!err.contains("interrupted capture);"), "{name}: called an interruption: {err}");
    assert_eq!(std::fs::read(&pack).expect("pack"), before, "{name}: the existing pack was replaced");
}

/// Damaged recordings: a flipped length bit, removed and duplicated records.
#[test]
fn damaged_recordings_fail_and_keep_the_pack() {
    let dir = tempfile::tempdir().expect("tempdir");
    let rec = simulate_rec(dir.path());
    let good = std::fs::read(&rec).expect("read");
    let (ok, _, err) = run(&["calibrate", "-q", s(&rec), "-o", s(&dir.path().join("p.pack"))]);
    assert!(ok, "{err}");
    let frames = frame_records(&good);
    assert!(frames.len() >= 12);

    // A flipped length: bit 20 of a middle frame's length (7 680 → 1 056 256): runs past the end of file.
    let (idx, at, _) = frames[frames.len() / 2];
    let mut flipped = good.clone();
    flipped[at + 46 + 2] ^= 0x10;
    refused(dir.path(), &flipped, "flip-middle.rec", &[&format!("record {idx} at byte {at} is damaged")]);
    // A small flip of the last frame's length, still within its geometry's slack: damage, found
    // by the records it reads into, or (when it runs past the end) by the End record the file
    // still ends with.
    let (idx, at, len) = *frames.last().expect("frames");
    let mut flipped = good.clone();
    flipped[at + 46] ^= 0x40;
    refused(dir.path(), &flipped, "flip-last.rec", &[&format!("record {idx} at byte {at} is damaged")]);
    // The same record cut to end right after its fixed part plus the flipped plane, then the End
    // record: the length runs past the end of a file that ends with a whole End record.
    let mut past = good[..at + len - 4].to_vec();
    past.extend_from_slice(&good[good.len() - 13..]);
    let longer = u32::from_le_bytes(past[at + 46..at + 50].try_into().expect("4 bytes")) + 64;
    past[at + 46..at + 50].copy_from_slice(&longer.to_le_bytes());
    refused(dir.path(), &past, "past-end.rec", &["is damaged", "not an interrupted capture"]);

    // Records lost or repeated: a frame record removed; one duplicated.
    let (_, at, len) = frames[4];
    let mut removed = good[..at].to_vec();
    removed.extend_from_slice(&good[at + len..]);
    refused(dir.path(), &removed, "removed.rec", &["End record counts"]);
    let mut dup = good[..at + len].to_vec();
    dup.extend_from_slice(&good[at..]);
    refused(dir.path(), &dup, "duplicated.rec", &["repeats frame record"]);

    // A real interruption still calibrates from the whole records, with a warning.
    let (_, at, _) = frames[frames.len() - 2];
    let cut = dir.path().join("cut.rec");
    std::fs::write(&cut, &good[..at + 100]).expect("write");
    let (ok, _, err) = run(&["calibrate", s(&cut), "-o", s(&dir.path().join("cut.pack"))]);
    assert!(ok && err.contains("interrupted capture"), "{err}");
}

/// A temporary file left beside an output by a killed run is removed by the next run
/// that writes into that folder; `simulate --rec` writes through a temporary file, so a kill
/// leaves no partial recording.
#[test]
fn killed_writes_leave_nothing_that_lasts() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("out");
    std::fs::create_dir(&out).expect("mkdir");
    let rec = out.join("big.rec");
    let mut child = support::command()
        .args(["simulate", "-q", "--width", "1024", "--height", "768", "--frames", "16", "--rec", s(&rec)])
        .stderr(Stdio::null())
        .spawn()
        .expect("spawn");
    let temp_of = |dir: &Path| {
        std::fs::read_dir(dir)
            .expect("list")
            .flatten()
            .map(|e| e.path())
            .find(|p| p.file_name().is_some_and(|n| n.to_string_lossy().starts_with(".big.rec.noisecal-tmp.")))
    };
    let t0 = Instant::now();
    let temp = loop {
        if let Some(t) = temp_of(&out)
            && std::fs::metadata(&t).map(|m| m.len()).unwrap_or(0) > 1 << 20
        {
            break t;
        }
        assert!(t0.elapsed() < Duration::from_secs(120), "no temporary file appeared");
        assert!(child.try_wait().expect("wait").is_none(), "simulate ended before it could be killed");
        std::thread::sleep(Duration::from_millis(20));
    };
    child.kill().expect("kill -9");
    child.wait().expect("reap");
    assert!(!rec.exists(), "a killed simulate --rec left a partial recording");
    assert!(temp.exists(), "the temporary file of the killed run");
    // Older than the grace period given to other pid namespaces.
    let f = std::fs::File::options().write(true).open(&temp).expect("open");
    f.set_modified(SystemTime::now() - Duration::from_secs(60)).expect("mtime");
    drop(f);
    // A pack written into the folder by the next run sweeps it.
    let stale = out.join(".p.pack.noisecal-tmp.4194999.3");
    std::fs::write(&stale, b"partial").expect("stale");
    std::fs::File::options()
        .write(true)
        .open(&stale)
        .expect("open")
        .set_modified(SystemTime::now() - Duration::from_secs(60))
        .expect("mtime");
    let small = simulate_rec(dir.path());
    let pack = out.join("p.pack");
    let (ok, _, err) = run(&["calibrate", "-q", s(&small), "-o", s(&pack)]);
    assert!(ok, "{err}");
    assert!(!temp.exists() && !stale.exists(), "stale temporary files were not swept");
    let names: Vec<String> = std::fs::read_dir(&out)
        .expect("list")
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["p.pack"]);
}

/// Rewrites a recording with another make (and, with `shrink`, frames cut to half size, which
/// every session rejects).
fn rewrite(src: &[u8], make: &str, shrink: bool) -> Vec<u8> {
    let mut r = RecordingReader::from_bytes(src).expect("reader");
    let mut header = r.header().clone();
    header.make = make.into();
    let mut w = RecordingWriter::new(Vec::new(), &header).expect("writer");
    while let Some(rec) = r.next_record().expect("record") {
        match rec {
            Record::BeginStep { exposure_ns } => w.begin_step(exposure_ns).expect("step"),
            Record::Frame(f) if shrink => {
                let (hw, hh) = (f.width / 2, f.height / 2);
                w.frame(&f.meta, hw, hh, f.row_stride, f.pixel_stride, &f.data[..(hh * f.row_stride) as usize])
                    .expect("frame")
            }
            Record::Frame(f) => {
                w.frame(&f.meta, f.width, f.height, f.row_stride, f.pixel_stride, &f.data).expect("frame")
            }
            Record::NoiseProfile { iso, profile } => w.noise_profile(iso, &profile).expect("profile"),
            Record::BeginDark => w.begin_dark().expect("dark"),
            Record::End { .. } => {}
        }
    }
    w.finish().expect("finish")
}

/// Messages that say what is wrong: an ROI outside the image says so; when no frame is usable the error
/// says why frames were rejected, per reason with counts; `inspect` escapes a make that carries
/// terminal escapes.
#[test]
fn messages_say_what_is_wrong() {
    let dir = tempfile::tempdir().expect("tempdir");
    let rec = simulate_rec(dir.path());
    let good = std::fs::read(&rec).expect("read");
    let pack = dir.path().join("p.pack");

    let (ok, _, err) = run(&["calibrate", s(&rec), "-o", s(&pack), "--roi", "0,0,1000,20"]);
    assert!(!ok && err.contains("--roi 0,0,1000,20 reaches outside the 64×48 image"), "{err}");
    assert!(!err.contains("capture target bursts"), "{err}");

    let small = dir.path().join("small.rec");
    std::fs::write(&small, rewrite(&good, "noisecal", true)).expect("write");
    let (ok, _, err) = run(&["calibrate", s(&small), "-o", s(&pack)]);
    let n = frame_records(&good).len();
    assert!(!ok && err.contains(&format!("{n} of {n} frames were rejected: {n}× ")), "{err}");
    assert!(!pack.exists());

    let evil = dir.path().join("evil.rec");
    std::fs::write(&evil, rewrite(&good, "Evil\u{1b}[2J\u{1b}]0;pwned\u{7}\u{9b}31m", false)).expect("write");
    let (ok, _, err) = run(&["calibrate", "-q", s(&evil), "-o", s(&pack)]);
    assert!(ok, "{err}");
    let (ok, out, err) = run(&["inspect", s(&pack)]);
    assert!(ok, "{err}");
    assert!(!out.contains('\u{1b}') && !out.contains('\u{7}') && !out.contains('\u{9b}'), "raw escapes: {out:?}");
    assert!(out.contains("Evil\\u{1b}[2J\\u{1b}]0;pwned\\u{7}\\u{9b}31m"), "{out}");
    // JSON escapes them its own way.
    let (ok, out, _) = run(&["inspect", "--json", s(&pack)]);
    assert!(ok && !out.contains('\u{1b}'), "{out:?}");
    // `eval` names the pack's camera too.
    let held = dir.path().join("held");
    let (ok, _, err) = run(&support::simulate(
        ("64", "48"),
        "2",
        "200",
        "--ev=0",
        &["-q", "--index-offset", "100000", "--dngs", s(&held)],
    ));
    assert!(ok, "{err}");
    let (ok, out, err) = run(&["eval", "-q", "--pack", s(&pack), s(&held)]);
    assert!(ok, "{err}");
    assert!(!out.contains('\u{1b}') && !out.contains('\u{7}') && !out.contains('\u{9b}'), "raw escapes: {out:?}");
    assert!(out.contains("Evil\\u{1b}[2J"), "{out}");
}
