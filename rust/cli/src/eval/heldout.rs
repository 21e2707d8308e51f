//! Held-out captures laid out like a calibration session (a reference burst per EV step, then a
//! few frames per ISO), read from a [`Source`] one burst at a time: the reference burst of each
//! step becomes the step's clean image and flat mask ([`CleanBurst`]), and the target frames are
//! handed over per (step, ISO) with that clean image. Nothing but one burst is kept in memory.

use std::path::Path;

use anyhow::{Context, bail};
use ndarray::Array2;
use noisecal_core::calibrate::step::{STEP_TOLERANCE, StepKey};
use noisecal_core::model::NoiseProfile;
use noisecal_core::{FrameMeta, POSITIONS};

use crate::support::progress_bar;
use noisecal_input::clean::{CleanBurst, CleanImages};
use noisecal_input::source::{InputKind, Record, Source, SourceInfo, input_kind};

/// A burst of target frames at one ISO of one EV step, with the step's clean image.
#[derive(Debug)]
pub struct Burst<'a> {
    pub step: usize,
    pub iso: u32,
    /// Row-major `round(mean)` of the step's reference burst, [`noisecal_core::calibrate::flat::NOT_FLAT`]
    /// off flat regions.
    pub clean: &'a [u16],
    pub width: usize,
    pub height: usize,
    /// The frames, with what the camera reported for each.
    pub frames: Vec<(FrameMeta, Array2<u16>)>,
    /// The held-out layout's black level (the clean image's); a frame whose metadata reports
    /// none has this one.
    pub black: [f32; POSITIONS],
}

/// Receives the held-out set burst by burst.
pub trait HeldOutVisitor {
    /// Called once, before any burst, with what the set says up front.
    fn start(&mut self, info: &SourceInfo) -> anyhow::Result<()>;
    /// One burst of target frames (all frames of one ISO in one step).
    fn burst(&mut self, burst: Burst<'_>) -> anyhow::Result<()>;
    /// The current step is over (its bursts were all delivered).
    fn end_step(&mut self) -> anyhow::Result<()>;
    /// A NoiseProfile record of a recording (DNG folders give theirs in [`SourceInfo`]).
    fn noise_profile(&mut self, iso: u32, profile: NoiseProfile);
}

/// Where the current step stands.
enum Clean {
    /// Summing the reference burst.
    Open(Box<CleanBurst>),
    /// The clean image (row-major, `NOT_FLAT` off flat regions).
    Closed(Vec<u16>),
    /// No usable clean image: the step's targets are skipped.
    Failed,
}

struct Step {
    index: usize,
    key: StepKey,
    targets: Option<usize>,
    clean: Clean,
    frames: Vec<(FrameMeta, Array2<u16>)>,
}

/// Streams a held-out set (DNG folder or recording) into `visitor`. `bin_width` is the pack's
/// (it only matters for the clean images' bookkeeping). Returns notes (rejected frames, steps
/// without a reference burst, …).
pub fn stream_heldout(
    path: &Path,
    bin_width: u16,
    quiet: bool,
    visitor: &mut dyn HeldOutVisitor,
) -> anyhow::Result<Vec<String>> {
    let mut source = match input_kind(path)? {
        InputKind::DngFolder => {
            Source::dngs(path, None).with_context(|| format!("reading the held-out set {}", path.display()))?
        }
        InputKind::Recording => Source::recording(path, None)?,
    };
    let info = source.info().clone();
    visitor.start(&info)?;
    let images = CleanImages::new(&info.layout, info.reference_iso, bin_width)
        .context("setting up the held-out set's clean images")?;
    let (w, h) = (info.layout.width as usize, info.layout.height as usize);
    let pb = progress_bar(info.frames, quiet, "evaluating");
    let mut notes = info.warnings.clone();
    let mut step: Option<Step> = None;
    let mut steps = 0usize;
    let flush = |st: &mut Step, visitor: &mut dyn HeldOutVisitor| -> anyhow::Result<()> {
        if st.frames.is_empty() {
            return Ok(());
        }
        let frames = std::mem::take(&mut st.frames);
        if let Clean::Closed(clean) = &st.clean {
            let iso = frames[0].0.iso;
            visitor.burst(Burst {
                step: st.index,
                iso,
                clean,
                width: w,
                height: h,
                frames,
                black: info.layout.black,
            })?;
        }
        Ok(())
    };
    while let Some(record) = source.next_record()? {
        let frame = match record {
            Record::BeginStep { index, reference_exposure_ns, targets } => {
                if let Some(mut st) = step.take() {
                    flush(&mut st, visitor)?;
                    visitor.end_step()?;
                }
                steps += 1;
                if targets == Some(0) {
                    source.skip_step();
                    continue;
                }
                let burst = images.burst(reference_exposure_ns)?;
                let key = burst.key();
                step = Some(Step { index, key, targets, clean: Clean::Open(Box::new(burst)), frames: Vec::new() });
                continue;
            }
            Record::NoiseProfile { iso, profile } => {
                visitor.noise_profile(iso, profile);
                continue;
            }
            // Dark frames hold no scene to evaluate against.
            Record::BeginDark => {
                if let Some(mut st) = step.take() {
                    flush(&mut st, visitor)?;
                    visitor.end_step()?;
                }
                source.skip_step();
                continue;
            }
            Record::CutShort(e) => return Err(anyhow::Error::new(e).context(format!("reading {}", path.display()))),
            Record::Frame(f) => f,
        };
        pb.inc(1);
        let Some(st) = step.as_mut() else {
            notes.push(format!("{} comes before any EV step; skipped", frame.label()));
            continue;
        };
        let view = match frame.view() {
            Ok(v) => v,
            Err(e) => {
                notes.push(format!("{}: {e}; skipped", frame.label()));
                continue;
            }
        };
        if let Clean::Open(burst) = &mut st.clean {
            if frame.meta.iso == info.reference_iso {
                if let Err(e) = burst.push(&view, &frame.meta) {
                    notes.push(format!("{}: reference frame rejected: {e}", frame.label()));
                }
                continue;
            }
            st.clean = match burst.close() {
                Ok(image) => Clean::Closed(image.levels),
                Err(e) => {
                    let which = match st.targets {
                        Some(n) => format!("its {n} target frames"),
                        None => "its target frames".to_string(),
                    };
                    notes.push(format!("EV step {}: no usable clean image ({e}); {which} are skipped", st.index));
                    source.skip_step();
                    Clean::Failed
                }
            };
        }
        if matches!(st.clean, Clean::Failed) {
            continue;
        }
        if view.width() != w || view.height() != h {
            notes.push(format!(
                "{}: {}×{} frame in a {w}×{h} set; skipped",
                frame.label(),
                view.width(),
                view.height()
            ));
            continue;
        }
        if let Err(m) = st.key.check(&frame.meta, STEP_TOLERANCE) {
            notes.push(format!(
                "{}: ISO × exposure {:.4} does not match its step's {:.4}; skipped",
                frame.label(),
                m.got,
                m.expected
            ));
            continue;
        }
        if st.frames.first().is_some_and(|(m, _)| m.iso != frame.meta.iso) {
            flush(st, visitor)?;
        }
        let meta = frame.meta;
        st.frames.push((meta, frame.into_array()?));
    }
    if let Some(mut st) = step.take() {
        flush(&mut st, visitor)?;
        visitor.end_step()?;
    }
    pb.finish_and_clear();
    if !source.complete() {
        notes.push(format!(
            "{} has no end marker (an interrupted capture): its complete frames were used",
            path.display()
        ));
    }
    if steps == 0 {
        bail!(
            "{} holds no EV step: a held-out set needs a reference burst per step and frames per ISO",
            path.display()
        );
    }
    Ok(notes)
}
