//! Helper for the JVM harness (`tests/jvm/jni/run.sh`), built with the `testkit` feature
//! (`cargo build -p noisecal-jni --features testkit`):
//!
//! ```text
//! noisecal-jni-tool write-recording OUT.rec [--size WxH] [--seed N] [--row-stride BYTES]
//! noisecal-jni-tool replay IN.rec OUT.pack          # the replay `noisecal calibrate` does
//! noisecal-jni-tool bench [--size WxH] [--targets N] # core-only push timings, no JNI
//! noisecal-jni-tool frame-hash W H ISO EXPOSURE_NS INDEX SEED   # cross-check of the Kotlin synth
//! noisecal-jni-tool gap-calls IN.pack               # the pack's gap calls, as finish returns them
//! ```

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Instant;

use noisecal_core::format::recording::RecordingReader;
use noisecal_core::{CalibrationSession, FrameMeta, FrameView};
use noisecal_jni::gap_calls::gap_calls_text;
use noisecal_jni::replay::session_for;
use noisecal_jni::testkit::{Plan, Synth, to_plane, write_recording};
use noisecal_jni::{BoundaryError, files, replay_recording};

type Fallible<T> = Result<T, String>;

fn parse<T: std::str::FromStr>(name: &str, v: &str) -> Fallible<T> {
    v.parse().map_err(|_| format!("{name} {v:?} is not a valid number"))
}

fn size(v: &str) -> Fallible<(u32, u32)> {
    let (w, h) = v.split_once('x').ok_or_else(|| format!("--size {v:?}: expected WxH, e.g. 320x240"))?;
    Ok((parse("width", w)?, parse("height", h)?))
}

/// `--name value` options after the positional arguments.
fn option<'a>(args: &'a [String], name: &str) -> Fallible<Option<&'a str>> {
    match args.iter().position(|a| a == name) {
        None => Ok(None),
        Some(i) => args.get(i + 1).map(|s| Some(s.as_str())).ok_or_else(|| format!("{name} needs a value")),
    }
}

fn write_rec(args: &[String]) -> Fallible<()> {
    let out = args.first().ok_or("write-recording needs an output path")?;
    let (w, h) = option(args, "--size")?.map(size).transpose()?.unwrap_or((320, 240));
    let seed = option(args, "--seed")?.map(|v| parse("--seed", v)).transpose()?.unwrap_or(1);
    let stride = option(args, "--row-stride")?.map(|v| parse("--row-stride", v)).transpose()?.unwrap_or(2 * w as usize);
    let synth = Synth::new(w, h, seed);
    // Atomic like every other writer: a failed or killed run leaves no partial
    // recording under `out`.
    let failed = |e: std::io::Error| format!("writing {out} failed: {e}");
    // AtomicFile buffers its writes itself.
    let mut file =
        noisecal_io::AtomicFile::create(std::path::Path::new(out)).map_err(|e| format!("cannot create {out}: {e}"))?;
    let frames = write_recording(&mut file, &synth, &Plan::default(), stride).map_err(failed)?;
    file.commit().map_err(failed)?;
    println!("wrote {out}: {frames} frames {w}×{h}, row stride {stride} bytes");
    Ok(())
}

fn replay(args: &[String]) -> Fallible<()> {
    let [input, output, ..] = args else { return Err("replay needs IN.rec OUT.pack".into()) };
    let file = std::fs::File::open(input).map_err(|e| format!("cannot open {input}: {e}"))?;
    let reader = RecordingReader::new(std::io::BufReader::new(file)).map_err(|e| format!("{input}: {e}"))?;
    let pack = replay_recording(reader).map_err(|e: BoundaryError| format!("{input}: {e}"))?;
    let bytes = pack.to_bytes().map_err(|e| e.to_string())?;
    files::write_atomically("cannot write the model pack", &PathBuf::from(output), &bytes)
        .map_err(|e| e.to_string())?;
    println!("{output}: ISO {} ({} bytes)", pack.iso_summary(), bytes.len());
    Ok(())
}

/// Prints a pack file's gap calls ([`gap_calls_text`]): what `NoisecalSession.finish` returns
/// with the summary, for the JVM harness to compare.
fn gap_calls(args: &[String]) -> Fallible<()> {
    let [input, ..] = args else { return Err("gap-calls needs IN.pack".into()) };
    let bytes = std::fs::read(input).map_err(|e| format!("cannot read {input}: {e}"))?;
    let pack = noisecal_core::ModelPack::from_bytes(&bytes).map_err(|e| format!("{input}: {e}"))?;
    print!("{}", gap_calls_text(&pack));
    Ok(())
}

/// Core-only timings of the same pushes the JVM harness times through JNI (same synthetic frames,
/// same padded row stride, generation untimed).
fn bench(args: &[String]) -> Fallible<()> {
    let (w, h) = option(args, "--size")?.map(size).transpose()?.unwrap_or((4032, 3024));
    let targets: usize = option(args, "--targets")?.map(|v| parse("--targets", v)).transpose()?.unwrap_or(4);
    let references = 3;
    let synth = Synth::new(w, h, 11);
    let stride = 2 * w as usize + 96;
    let header = noisecal_core::format::recording::RecordingHeader {
        layout: synth.layout(),
        reference_iso: 100,
        bin_width: 0,
        make: "noisecal".into(),
        model: "bench".into(),
    };
    let mut session: CalibrationSession = session_for(&header).map_err(|e| e.to_string())?;
    session.begin_step(10_000_000).map_err(|e| e.to_string())?;
    let mut push = |iso: u32, ns: u64, index: u64| -> Fallible<f64> {
        let plane = to_plane(&synth.frame(iso, ns, index), w as usize, h as usize, stride);
        let t = Instant::now();
        let view = FrameView::from_le_bytes(&plane, w as usize, h as usize, stride, 2).map_err(|e| e.to_string())?;
        session.push_frame(&view, &FrameMeta::new(iso, ns)).map_err(|e| e.to_string())?;
        Ok(t.elapsed().as_secs_f64() * 1e3)
    };
    let mut index = 0;
    let mut reference = Vec::new();
    for _ in 0..references {
        reference.push(push(100, 10_000_000, index)?);
        index += 1;
    }
    let close = push(200, 5_000_000, index)?;
    index += 1;
    let mut target = Vec::new();
    for _ in 0..targets {
        target.push(push(200, 5_000_000, index)?);
        index += 1;
    }
    println!(
        "BENCH core {w}x{h} reference_ms={:.1} close_ms={close:.1} target_ms={:.1} target_min_ms={:.1}",
        median(&mut reference),
        median(&mut target),
        target.iter().cloned().fold(f64::INFINITY, f64::min)
    );
    Ok(())
}

/// Median (mean of the middle two for an even count).
fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n == 0 {
        f64::NAN
    } else if n % 2 == 1 {
        v[n / 2]
    } else {
        (v[n / 2 - 1] + v[n / 2]) / 2.0
    }
}

fn frame_hash(args: &[String]) -> Fallible<()> {
    let [w, h, iso, ns, index, seed, ..] = args else {
        return Err("frame-hash needs W H ISO EXPOSURE_NS INDEX SEED".into());
    };
    let synth = Synth::new(parse("W", w)?, parse("H", h)?, parse("SEED", seed)?);
    let samples = synth.frame(parse("ISO", iso)?, parse("EXPOSURE_NS", ns)?, parse("INDEX", index)?);
    // FNV-1a over the samples.
    let mut hash: u64 = 0xcbf2_9ce4_8422_2325;
    for v in samples {
        hash = (hash ^ v as u64).wrapping_mul(0x0000_0100_0000_01B3);
    }
    println!("{hash:016x}");
    Ok(())
}

fn main() -> ExitCode {
    noisecal_jni::init_logging();
    let args: Vec<String> = std::env::args().skip(1).collect();
    let result = match args.first().map(String::as_str) {
        Some("write-recording") => write_rec(&args[1..]),
        Some("replay") => replay(&args[1..]),
        Some("bench") => bench(&args[1..]),
        Some("frame-hash") => frame_hash(&args[1..]),
        Some("gap-calls") => gap_calls(&args[1..]),
        _ => {
            Err("usage: noisecal-jni-tool write-recording|replay|bench|frame-hash|gap-calls … (see the source's doc comment)"
                .into())
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}
