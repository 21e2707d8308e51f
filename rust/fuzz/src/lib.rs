//! Mutation fuzzing of noisecal's byte-taking entry points on the stable toolchain (no
//! libFuzzer, no nightly): [`mutate`] derives inputs from a seed corpus with a deterministic RNG,
//! and each [`Target`] runs one input through a decoder. The `noisecal-fuzz` binary drives them
//! (under `catch_unwind`, with a per-input time limit, saving failures); `docs/fuzzing.md` says how.
//!
//! | target      | entry point                                                                 |
//! |-------------|-----------------------------------------------------------------------------|
//! | `dng`       | `noisecal_input::dng::decode_dng` and `decode_dng_meta`                        |
//! | `recording` | `RecordingReader::from_bytes`, every record, frame views, and a replay       |
//! | `pack`      | `ModelPack::from_bytes` and `LazyPack` (must agree), the self-check, a sampler and a small synthesis |
//! | `jni-frame` | `NativeSession::push_plane` (the JNI `pushFrame` without a JVM) and `FrameView::from_le_bytes` |

pub mod mutate;

use std::path::Path;

use mutate::Framing;
use noisecal_core::format::recording::{Record, RecordingReader};
use noisecal_core::format::replay;
use noisecal_core::{FrameView, ModelPack};
use noisecal_jni::session::{CreateParams, NativeSession, PlaneParams};

/// A decoder under test.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Target {
    Dng,
    Recording,
    Pack,
    JniFrame,
}

impl Target {
    pub const ALL: [Target; 4] = [Target::Dng, Target::Recording, Target::Pack, Target::JniFrame];

    pub fn name(self) -> &'static str {
        match self {
            Target::Dng => "dng",
            Target::Recording => "recording",
            Target::Pack => "pack",
            Target::JniFrame => "jni-frame",
        }
    }

    pub fn parse(s: &str) -> Option<Self> {
        Self::ALL.into_iter().find(|t| t.name() == s)
    }

    pub fn framing(self) -> Framing {
        match self {
            Target::Recording => Framing::Recording,
            Target::Pack => Framing::Sealed,
            Target::Dng | Target::JniFrame => Framing::None,
        }
    }

    /// Longest input the mutator makes (seeds are far shorter).
    pub fn max_len(self) -> usize {
        match self {
            Target::JniFrame => 64 << 10,
            _ => 4 << 20,
        }
    }

    /// Runs one input. `Ok` is any outcome that is not a bug (accepted or refused with an
    /// error); the string names the outcome without its numbers (a cheap signal of new
    /// behaviour, to keep inputs that reach it). A panic propagates (the driver catches it).
    pub fn run(self, input: &[u8]) -> String {
        match self {
            Target::Dng => run_dng(input),
            Target::Recording => run_recording(input),
            Target::Pack => run_pack(input),
            Target::JniFrame => run_jni_frame(input),
        }
    }
}

/// An outcome's text without its numbers (every word holding a digit), cut to a short prefix.
fn signature(s: &str) -> String {
    let words: Vec<&str> =
        s.split_whitespace().map(|w| if w.chars().any(|c| c.is_ascii_digit()) { "#" } else { w }).collect();
    words.join(" ").chars().take(96).collect()
}

fn run_dng(input: &[u8]) -> String {
    let src = Path::new("fuzz.dng");
    let meta = noisecal_input::dng::decode_dng_meta(input, src);
    match noisecal_input::dng::decode_dng(input, src) {
        Ok(img) => {
            assert!(meta.is_ok(), "decode_dng accepted what decode_dng_meta refused: {:?}", meta.err());
            let (h, w) = img.pixels.dim();
            assert_eq!((w as u32, h as u32), (img.layout.width, img.layout.height), "pixels and layout disagree");
            format!("ok {}", if img.meta.black.is_some() { "black" } else { "" })
        }
        Err(e) => format!("err {}", signature(&e.to_string())),
    }
}

fn run_recording(input: &[u8]) -> String {
    let mut reader = match RecordingReader::from_bytes(input) {
        Ok(r) => r,
        Err(e) => return format!("header {}", signature(&e.to_string())),
    };
    let mut frames = 0usize;
    let outcome = loop {
        match reader.next_record() {
            Ok(Some(Record::Frame(f))) => {
                frames += 1;
                if let Ok(v) = f.view() {
                    let _ = v.row(v.height() - 1)[v.width() - 1];
                }
            }
            Ok(Some(_)) => {}
            Ok(None) => break format!("end {}", reader.ended()),
            Err(e) => break format!("err {}", signature(&e.to_string())),
        }
    };
    // The same bytes replayed into a calibration session, as `calibrate session.rec` does.
    if frames > 0
        && let Ok(r) = RecordingReader::from_bytes(input)
        && let Ok((session, _)) = replay::replay(r, |_| {}, |_| {})
    {
        let _ = session.finish();
    }
    outcome
}

fn run_pack(input: &[u8]) -> String {
    // The on-demand reader agrees with the whole one: both take the file or both refuse it, and
    // take it to the same pack (compared as text: a pack may hold NaN, which equals nothing).
    let lazy = noisecal_core::format::lazy_pack::LazyPack::open(input);
    if let Ok(l) = &lazy
        && let Some(e) = l.index().isos.first()
    {
        let _ = l.pack_with(&[e.iso]);
    }
    let lazy_whole = lazy.and_then(|l| l.to_pack());
    let whole = ModelPack::from_bytes(input);
    let text = |p: &ModelPack| format!("{p:?}");
    assert!(
        lazy_whole.as_ref().ok().map(text) == whole.as_ref().ok().map(text),
        "the on-demand reader and the whole one disagree"
    );
    let pack = match whole {
        Ok(p) => p,
        Err(e) => return format!("err {}", signature(&e.to_string())),
    };
    let findings = noisecal_core::model::check::self_check(&pack);
    // A small synthesis with the first ISO's model: tables built, samples drawn.
    if let Some(model) = pack.isos.first() {
        let sampler = noisecal_core::synth::sampler::IsoSampler::new(&pack, model);
        let w = (pack.layout.width as usize).min(8);
        let h = (pack.layout.height as usize).min(8);
        let clean = ndarray::Array2::from_elem((h, w), pack.layout.white / 2);
        let _ = noisecal_core::synth::synthesize(&sampler, clean.view(), 1);
    }
    format!("ok {}", findings.len().min(3))
}

/// Reads the fuzz input as a sequence of choices.
struct Bytes<'a>(&'a [u8]);

impl Bytes<'_> {
    fn u8(&mut self) -> u8 {
        let Some((&b, rest)) = self.0.split_first() else { return 0 };
        self.0 = rest;
        b
    }

    fn i32(&mut self) -> i32 {
        i32::from_le_bytes([self.u8(), self.u8(), self.u8(), self.u8()])
    }

    fn i64(&mut self) -> i64 {
        (self.i32() as u32 as i64) | ((self.i32() as i64) << 32)
    }
}

/// A session of `(2..=64)²` pixels, then up to three frames pushed through the JNI boundary's
/// `push_plane`: each field either what the session expects or raw bytes of the input, the plane
/// the input's remaining bytes. The same geometry also goes to `FrameView::from_le_bytes`.
fn run_jni_frame(input: &[u8]) -> String {
    let mut b = Bytes(input);
    let sw = 2 * (1 + (b.u8() % 32) as i32);
    let sh = 2 * (1 + (b.u8() % 32) as i32);
    let pushes = 1 + b.u8() % 3;
    let mut specs = Vec::new();
    for _ in 0..pushes {
        let flags = b.u8();
        let raw = |bit: u8, b: &mut Bytes<'_>, default: i32| if flags & (1 << bit) != 0 { b.i32() } else { default };
        let width = raw(0, &mut b, sw);
        let height = raw(1, &mut b, sh);
        let pad = (b.u8() % 8) as i32 * 2;
        let row_stride = raw(2, &mut b, width.wrapping_mul(2).wrapping_add(pad));
        let pixel_stride = raw(3, &mut b, 2);
        let iso = raw(4, &mut b, [100, 200, 400][(flags >> 6) as usize % 3]);
        let exposure_ns = if flags & (1 << 5) != 0 { b.i64() } else { 4_000_000 * 100 / iso.max(1) as i64 };
        let black: Option<Vec<f32>> = match b.u8() % 4 {
            0 => None,
            1 => Some(vec![64.0; 4]),
            2 => Some(vec![f32::from_bits(b.i32() as u32); 4]),
            _ => Some(vec![64.0; (b.u8() % 6) as usize]),
        };
        specs.push((PlaneParams { width, height, row_stride, pixel_stride, iso, exposure_ns, black: None }, black));
    }
    let plane = b.0;
    let params = CreateParams {
        width: sw,
        height: sh,
        cfa: "RGGB",
        black: &[64.0; 4],
        white: 1023,
        reference_iso: 100,
        make: "fuzz",
        model: "fuzz",
        bin_width: 0,
    };
    let mut session = NativeSession::create(&params).expect("a valid session");
    let _ = session.begin_step(4_000_000);
    let mut out = String::new();
    let share = plane.len() / specs.len().max(1);
    for (i, (mut p, black)) in specs.into_iter().enumerate() {
        p.black = black.as_deref();
        // Each push gets its share of the plane, the last one the rest.
        let bytes = if i + 1 == pushes as usize { &plane[i * share..] } else { &plane[i * share..(i + 1) * share] };
        let _ = FrameView::from_le_bytes(
            bytes,
            p.width.max(0) as usize,
            p.height.max(0) as usize,
            p.row_stride.max(0) as usize,
            p.pixel_stride.max(0) as usize,
        );
        match session.push_plane(bytes, &p) {
            Ok(_) => out.push_str("ok "),
            Err(e) => out.push_str(&signature(&e.to_string())),
        }
    }
    out
}

/// Seeds of the `jni-frame` target: valid pushes of synthetic frames (the other targets' seeds
/// are files noisecal writes: docs/fuzzing.md, "Corpus", says what wrote each).
pub fn jni_seeds() -> Vec<Vec<u8>> {
    let mut seeds = Vec::new();
    for (k, (w, h, pad)) in [(8u8, 8u8, 0u8), (16, 12, 2), (4, 4, 7)].into_iter().enumerate() {
        let sw = 2 * (w as usize / 2);
        let sh = 2 * (h as usize / 2);
        let mut v = vec![(sw / 2 - 1) as u8, (sh / 2 - 1) as u8, 1 + k as u8];
        let stride = sw * 2 + (pad as usize % 8) * 2;
        let pushes = 2 + k;
        for i in 0..pushes {
            let iso_choice = if i == 0 { 0u8 } else { 1 };
            v.push(iso_choice << 6);
            v.push(pad);
            v.push(1);
        }
        for i in 0..pushes {
            for y in 0..sh {
                for x in 0..stride / 2 {
                    let s = 64 + ((x * 37 + y * 11 + i * 5) % 200) as u16;
                    v.extend_from_slice(&s.to_le_bytes());
                }
            }
        }
        seeds.push(v);
    }
    seeds
}
