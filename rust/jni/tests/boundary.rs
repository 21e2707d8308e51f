//! The boundary's session without a JVM: padded planes, bad input, the recording tee, checkpoint
//! and resume (with the recording cut back), all against the pack a plain replay makes.

use std::path::Path;

use noisecal_core::calibrate::Progress;
use noisecal_core::format::recording::{Record, RecordingReader};
use noisecal_jni::session::{CreateParams, NativeSession, PlaneParams, default_bin_width};
use noisecal_jni::testkit::{Plan, Synth, normalish, splitmix64, write_recording};
use noisecal_jni::{BoundaryError, replay_recording};

const W: usize = 320;
const H: usize = 240;

struct Frame {
    iso: u32,
    exposure_ns: u64,
    black: Option<[f32; 4]>,
    samples: Vec<u16>,
}

enum Event {
    Step(u64),
    Frame(Frame),
}

fn synthetic() -> (Synth, Vec<u8>, Vec<Event>) {
    let synth = Synth::new(W as u32, H as u32, 3);
    let mut rec = Vec::new();
    write_recording(&mut rec, &synth, &Plan::default(), 2 * W).expect("recording");
    let mut r = RecordingReader::new(&rec[..]).expect("reader");
    let mut events = Vec::new();
    while let Some(record) = r.next_record().expect("record") {
        match record {
            Record::BeginStep { exposure_ns } => events.push(Event::Step(exposure_ns)),
            Record::Frame(f) => {
                let v = f.view().expect("view");
                let samples = (0..H).flat_map(|y| v.row(y).into_owned()).collect();
                events.push(Event::Frame(Frame {
                    iso: f.meta.iso,
                    exposure_ns: f.meta.exposure_ns,
                    black: f.meta.black,
                    samples,
                }));
            }
            _ => {}
        }
    }
    (synth, rec, events)
}

fn reference_pack(rec: &[u8]) -> Vec<u8> {
    let pack = replay_recording(RecordingReader::new(rec).expect("reader")).expect("replay");
    pack.to_bytes().expect("pack bytes")
}

fn replay_file(path: &Path) -> (Vec<u8>, bool, u64) {
    let bytes = std::fs::read(path).expect("recording file");
    let mut r = RecordingReader::new(&bytes[..]).expect("reader");
    let mut frames = 0;
    let mut end = None;
    while let Some(rec) = r.next_record().expect("record") {
        match rec {
            Record::Frame(_) => frames += 1,
            Record::End { frames: n } => end = Some(n),
            _ => {}
        }
    }
    assert!(end.is_none() || end == Some(frames), "End counts {end:?}, file holds {frames}");
    (reference_pack(&bytes), end.is_some(), frames)
}

fn create(synth: &Synth) -> NativeSession {
    NativeSession::create(&CreateParams {
        width: synth.width as i32,
        height: synth.height as i32,
        cfa: "rggb",
        black: &[64.0; 4],
        white: 1023,
        reference_iso: 100,
        make: "noisecal",
        model: "synthetic",
        bin_width: 0,
    })
    .expect("session")
}

/// A plane with `pad` extra bytes per row (and a padded last row), filled with junk.
fn plane(f: &Frame, w: usize, h: usize, pad: usize) -> (Vec<u8>, usize) {
    let stride = 2 * w + pad;
    let mut p = vec![0x5Au8; stride * h];
    for y in 0..h {
        for x in 0..w {
            p[y * stride + 2 * x..y * stride + 2 * x + 2].copy_from_slice(&f.samples[y * w + x].to_le_bytes());
        }
    }
    (p, stride)
}

fn push(s: &mut NativeSession, f: &Frame, pad: usize) -> Result<(), BoundaryError> {
    let (p, stride) = plane(f, W, H, pad);
    s.push_plane(
        &p,
        &PlaneParams {
            width: W as i32,
            height: H as i32,
            row_stride: stride as i32,
            pixel_stride: 2,
            iso: f.iso as i32,
            exposure_ns: f.exposure_ns as i64,
            black: f.black.as_ref().map(|b| &b[..]),
        },
    )
    .map(|_| ())
}

fn run(s: &mut NativeSession, events: &[Event]) {
    for (i, e) in events.iter().enumerate() {
        match e {
            Event::Step(ns) => s.begin_step(*ns as i64).expect("step"),
            Event::Frame(f) => push(s, f, 8 * (i % 5) + 2).expect("frame"),
        }
    }
}

#[test]
fn padded_planes_and_recording_give_the_replayed_pack() {
    let (synth, rec, events) = synthetic();
    let want = reference_pack(&rec);
    let dir = tempfile::tempdir().expect("dir");
    let mut s = create(&synth);
    s.start_recording(&dir.path().join("s.rec")).expect("recording");
    run(&mut s, &events);
    let summary = s.finish_to(&dir.path().join("s.pack")).expect("finish");
    assert!(summary.contains("ISO 100, 200, 400"), "{summary}");
    assert_eq!(std::fs::read(dir.path().join("s.pack")).expect("pack"), want);
    s.close().expect("close");
    let (replayed, ended, frames) = replay_file(&dir.path().join("s.rec"));
    assert!(ended);
    assert_eq!(frames, events.iter().filter(|e| matches!(e, Event::Frame(_))).count() as u64);
    assert_eq!(replayed, want);
    // The tee writes the recording the core's writer writes for the same frames (the synthetic
    // recording has the same header and records, with rows of the same stride).
    let mut s = create(&synth);
    s.start_recording(&dir.path().join("t.rec")).expect("recording");
    for e in &events {
        match e {
            Event::Step(ns) => s.begin_step(*ns as i64).expect("step"),
            Event::Frame(f) => push(&mut s, f, 0).expect("frame"),
        }
    }
    s.close().expect("close");
    assert_eq!(std::fs::read(dir.path().join("t.rec")).expect("tee"), rec);
}

#[test]
fn bad_frames_are_named_and_change_nothing() {
    let (synth, rec, events) = synthetic();
    let want = reference_pack(&rec);
    let mut s = create(&synth);
    let Some(Event::Frame(first)) = events.get(1) else { panic!("a frame follows the first step") };
    let e = push(&mut s, first, 0).expect_err("no step yet");
    assert!(e.to_string().contains("no EV step has begun"), "{e}");
    for (i, ev) in events.iter().enumerate() {
        let Event::Frame(f) = ev else {
            if let Event::Step(ns) = ev {
                s.begin_step(*ns as i64).expect("step");
            }
            continue;
        };
        if i % 7 == 3 {
            let before = s.progress();
            let (p, stride) = plane(f, W, H, 4);
            let good = PlaneParams {
                width: W as i32,
                height: H as i32,
                row_stride: stride as i32,
                pixel_stride: 2,
                iso: f.iso as i32,
                exposure_ns: f.exposure_ns as i64,
                black: None,
            };
            let cases: Vec<(Vec<u8>, PlaneParams<'_>, &str)> = vec![
                (p[..p.len() - 10].to_vec(), good, "((height − 1) · rowStride + 2 · width)"),
                (p.clone(), PlaneParams { pixel_stride: 4, ..good }, "pixel stride is 4 bytes"),
                (p.clone(), PlaneParams { width: 318, ..good }, "frame is 318×240 but the session's sensor is 320×240"),
                (p.clone(), PlaneParams { row_stride: 100, ..good }, "row stride 100 bytes is less than"),
                (p.clone(), PlaneParams { iso: -1, ..good }, "iso is -1"),
                (p.clone(), PlaneParams { black: Some(&[64.0; 3]), ..good }, "pass 4 values"),
            ];
            for (bytes, params, msg) in cases {
                let e = s.push_plane(&bytes, &params).expect_err(msg);
                assert!(e.to_string().contains(msg), "{e} lacks {msg}");
            }
            let after = s.progress();
            // Only the core's rejection counter may move, and only for the size mismatch.
            assert_eq!(Progress { frames_rejected: before.frames_rejected, ..after }, before);
        }
        push(&mut s, f, 6).expect("frame");
    }
    let dir = tempfile::tempdir().expect("dir");
    s.finish_to(&dir.path().join("p")).expect("finish");
    assert_eq!(std::fs::read(dir.path().join("p")).expect("pack"), want);
}

#[test]
fn kill_and_resume_gives_the_same_pack_and_recording() {
    let (synth, rec, events) = synthetic();
    let want = reference_pack(&rec);
    let dir = tempfile::tempdir().expect("dir");
    let rec_path = dir.path().join("s.rec");
    let ckpt = dir.path().join("s.ckpt");
    let half = events.len() / 2;
    {
        let mut s = create(&synth);
        s.start_recording(&rec_path).expect("recording");
        run(&mut s, &events[..half]);
        s.checkpoint_file(&ckpt).expect("checkpoint");
        // Frames after the checkpoint, then a kill (no close): the restored session never saw them.
        run(&mut s, &events[half..half + 5]);
        drop(s);
    }
    let mut s = NativeSession::restore_file(&ckpt).expect("restore");
    assert_eq!(s.recording_path(), Some(rec_path.as_path()));
    run(&mut s, &events[half..]);
    s.finish_to(&dir.path().join("r.pack")).expect("finish");
    s.close().expect("close");
    assert_eq!(std::fs::read(dir.path().join("r.pack")).expect("pack"), want);
    let (replayed, ended, _) = replay_file(&rec_path);
    assert!(ended);
    assert_eq!(replayed, want);

    // A checkpoint whose recording is gone still resumes the session (without recording).
    std::fs::remove_file(&rec_path).expect("rm");
    let s = NativeSession::restore_file(&ckpt).expect("restore without recording");
    assert_eq!(s.recording_path(), None);
    // Damaged, cut, older and foreign checkpoints are refused with a reason.
    let good = std::fs::read(&ckpt).expect("ckpt");
    let mut bytes = good.clone();
    let n = bytes.len();
    bytes[n - 3] ^= 0xFF;
    let e = NativeSession::restore_bytes(&bytes).expect_err("corrupt");
    assert!(e.to_string().contains("session checkpoint is corrupt: checksum"), "{e}");
    let e = NativeSession::restore_bytes(&good[..n - 1]).expect_err("cut");
    assert!(e.to_string().contains("session checkpoint is truncated"), "{e}");
    let mut v1 = good.clone();
    v1[8] = 1;
    let e = NativeSession::restore_bytes(&v1).expect_err("version 1");
    assert!(e.to_string().contains("format version 1, older than this noisecal reads (2)"), "{e}");
    let e = NativeSession::restore_bytes(b"hello world, not a checkpoint").expect_err("foreign");
    assert!(e.to_string().contains("not a noisecal checkpoint"), "{e}");
    let e = NativeSession::restore_file(&dir.path().join("nope")).expect_err("missing");
    assert!(e.to_string().contains("cannot read the checkpoint"), "{e}");
}

#[test]
fn recording_only_from_the_start() {
    let (synth, _, events) = synthetic();
    let dir = tempfile::tempdir().expect("dir");
    let mut s = create(&synth);
    run(&mut s, &events[..3]);
    let e = s.start_recording(&dir.path().join("late.rec")).expect_err("late");
    assert!(e.to_string().contains("before the first beginStep"), "{e}");
    let e = create(&synth).start_recording(&dir.path().join("missing/x.rec")).expect_err("bad dir");
    assert!(e.to_string().contains("cannot create the recording"), "{e}");
}

#[test]
fn bad_session_arguments_are_named() {
    let synth = Synth::new(64, 48, 1);
    let good = CreateParams {
        width: 64,
        height: 48,
        cfa: "RGGB",
        black: &[64.0; 4],
        white: 1023,
        reference_iso: 100,
        make: "m",
        model: "m",
        bin_width: 0,
    };
    let cases: Vec<(CreateParams<'_>, &str)> = vec![
        (CreateParams { cfa: "RGBW", ..good.clone() }, "pass RGGB, BGGR, GRBG or GBRG"),
        (CreateParams { width: -4, ..good.clone() }, "width is -4"),
        (CreateParams { black: &[64.0; 2], ..good.clone() }, "blackLevels"),
        (CreateParams { white: 70000, ..good.clone() }, "whiteLevel is 70000"),
        (CreateParams { reference_iso: 0, ..good.clone() }, "referenceIso is 0"),
        (CreateParams { black: &[2000.0; 4], ..good.clone() }, "black level 2000"),
    ];
    for (p, msg) in cases {
        let e = NativeSession::create(&p).expect_err(msg);
        assert!(e.to_string().contains(msg), "{e} lacks {msg}");
    }
    assert_eq!(create(&synth).core().layout().width, 64);
}

#[test]
fn the_bin_width_is_the_cores_and_the_packs() {
    // The core's rule: about 240 bins between the lowest black level and white, a power of two.
    assert_eq!(default_bin_width(1023, &[64.0; 4]).expect("10 bit"), 4);
    assert_eq!(default_bin_width(4095, &[256.0; 4]).expect("12 bit"), 16);
    assert_eq!(default_bin_width(16383, &[1024.0; 4]).expect("14 bit"), 64);
    // It follows the black level too, not only the bit depth.
    assert_eq!(default_bin_width(1023, &[512.0; 4]).expect("high black"), 2);
    let e = default_bin_width(1023, &[64.0; 3]).expect_err("3 black levels");
    assert!(e.to_string().contains("pass 4 values"), "{e}");
    let e = default_bin_width(1023, &[2000.0; 4]).expect_err("black above white");
    assert!(e.to_string().contains("black level 2000"), "{e}");

    let (synth, rec, events) = synthetic();
    let mut s = create(&synth);
    assert_eq!(s.bin_width(), default_bin_width(1023, &[64.0; 4]).expect("default"));
    run(&mut s, &events);
    let dir = tempfile::tempdir().expect("dir");
    s.finish_to(&dir.path().join("p")).expect("finish");
    let pack =
        noisecal_core::ModelPack::from_bytes(&std::fs::read(dir.path().join("p")).expect("pack")).expect("decode");
    assert_eq!(pack.bin_width, s.bin_width());
    assert_eq!(std::fs::read(dir.path().join("p")).expect("pack"), reference_pack(&rec));
    let wide = NativeSession::create(&CreateParams {
        width: 64,
        height: 48,
        cfa: "RGGB",
        black: &[64.0; 4],
        white: 1023,
        reference_iso: 100,
        make: "m",
        model: "m",
        bin_width: 32,
    })
    .expect("explicit bin width");
    assert_eq!(wide.bin_width(), 32);
}

/// A lens-covered frame: black level, a fixed per-pixel offset growing with gain, read noise.
fn dark_frame(iso: u32, index: u64) -> Frame {
    let gain = iso as f64 / 100.0;
    let samples = (0..W * H)
        .map(|i| {
            let i = i as u64;
            let pattern = 0.4 * gain * normalish(splitmix64(0xDA4B ^ i));
            let read = 1.2 * gain.sqrt() * normalish(splitmix64(splitmix64(index + 1) ^ i));
            (64.0 + pattern + read + 0.5).floor().clamp(0.0, 1023.0) as u16
        })
        .collect();
    Frame { iso, exposure_ns: 1_000_000, black: None, samples }
}

#[test]
fn dark_step_is_recorded_and_a_lit_frame_in_it_is_refused_unchanged() {
    let (synth, rec, events) = synthetic();
    let lit_only = reference_pack(&rec);
    let dir = tempfile::tempdir().expect("dir");
    let mut s = create(&synth);
    s.start_recording(&dir.path().join("d.rec")).expect("recording");
    run(&mut s, &events);
    s.begin_dark().expect("begin_dark");
    let mut index = 0;
    for iso in [100, 200, 400] {
        for _ in 0..6 {
            push(&mut s, &dark_frame(iso, index), 6).expect("dark frame");
            index += 1;
        }
    }
    let before = s.progress();
    let lit = events
        .iter()
        .rev()
        .find_map(|e| match e {
            Event::Frame(f) => Some(f),
            Event::Step(_) => None,
        })
        .expect("a lit frame");
    match push(&mut s, lit, 4) {
        Err(BoundaryError::Session(noisecal_core::error::SessionError::NotDark { iso, .. })) => {
            assert_eq!(iso, lit.iso)
        }
        other => panic!("a lit frame in the dark step: {other:?}"),
    }
    let err = push(&mut s, lit, 4).expect_err("refused again").to_string();
    assert!(err.contains("is not dark") && err.contains("cover"), "{err}");
    let after = s.progress();
    assert_eq!((after.frames_accepted, after.isos, after.steps), (before.frames_accepted, before.isos, before.steps));
    s.finish_to(&dir.path().join("d.pack")).expect("finish");
    s.close().expect("close");
    let pack = std::fs::read(dir.path().join("d.pack")).expect("pack");
    assert_ne!(pack, lit_only, "the dark frames changed nothing in the pack");
    let (replayed, ended, frames) = replay_file(&dir.path().join("d.rec"));
    assert!(ended);
    let lit_frames = events.iter().filter(|e| matches!(e, Event::Frame(_))).count() as u64;
    assert_eq!(frames, lit_frames + 18, "the refused frames are not recorded");
    assert_eq!(replayed, pack, "the recording replays to the session's pack");
    let bytes = std::fs::read(dir.path().join("d.rec")).expect("recording");
    let mut r = RecordingReader::new(&bytes[..]).expect("reader");
    let mut dark_records = 0;
    while let Some(record) = r.next_record().expect("record") {
        dark_records += usize::from(matches!(record, Record::BeginDark));
    }
    assert_eq!(dark_records, 1, "one BeginDark record");
}
