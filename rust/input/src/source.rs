//! A capture set as one stream of records in capture order, whatever it is stored as: a folder of
//! DNGs (grouped into EV steps by their metadata, [`crate::grouping`]; each step's reference
//! burst, then its target frames by ISO) or a raw recording made by the app (its records as they
//! were written). Calibration, evaluation and the demo read captures through it.
//!
//! ```text
//! Source::open(path) ─ info() ─ next() → BeginStep, Frame, Frame, …, NoiseProfile, BeginStep, …,
//!                                          BeginDark, Frame, …
//! ```

use std::collections::{BTreeMap, VecDeque};
use std::io::BufReader;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use ndarray::Array2;
use noisecal_core::error::{CodecError, FrameError};
use noisecal_core::format::recording::{self, RecordedFrame, RecordingReader};
use noisecal_core::format::replay::session_config;
use noisecal_core::model::NoiseProfile;
use noisecal_core::{FrameMeta, FrameView, SensorLayout, SessionConfig};
use rayon::prelude::*;

use crate::dng::{self, DngFile};
use crate::grouping::{self, DngFrame, DngStep};

/// What a path holds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum InputKind {
    DngFolder,
    Recording,
}

/// Tells a DNG folder from a recording file, with a clear error for anything else.
pub fn input_kind(path: &Path) -> anyhow::Result<InputKind> {
    let md = std::fs::metadata(path).with_context(|| format!("cannot read {}: does it exist?", path.display()))?;
    if md.is_dir() {
        return Ok(InputKind::DngFolder);
    }
    if !md.is_file() {
        bail!(
            "{} is not a regular file (a FIFO, socket or device): give a folder of DNGs or a recording file",
            path.display()
        );
    }
    let mut magic = [0u8; 8];
    use std::io::Read;
    let n = std::fs::File::open(path)
        .and_then(|mut f| f.read(&mut magic))
        .with_context(|| format!("cannot open {}", path.display()))?;
    if n == 8 && &magic == recording::RECORDING_MAGIC {
        return Ok(InputKind::Recording);
    }
    bail!("{} is neither a folder of DNGs nor a noisecal recording (.rec)", path.display())
}

/// What a capture set says before its frames are read.
#[derive(Debug, Clone)]
pub struct SourceInfo {
    pub path: PathBuf,
    pub kind: InputKind,
    pub layout: SensorLayout,
    pub reference_iso: u32,
    /// The calibration the captures imply: reference ISO, make and model, a recording's bin
    /// width; everything else at its default.
    pub config: SessionConfig,
    /// Target ISOs known up front (a DNG folder); empty for a recording.
    pub target_isos: Vec<u32>,
    /// The camera's NoiseProfile per ISO known up front (a DNG folder); a recording has
    /// [`Record::NoiseProfile`] records instead.
    pub noise_profiles: BTreeMap<u32, NoiseProfile>,
    /// What grouping noticed (frames left out, steps without targets, rounded ISOs).
    pub warnings: Vec<String>,
    /// Frames to expect: exact for a DNG folder, estimated from the file size for a recording.
    pub frames: u64,
}

/// One record of a capture set.
#[derive(Debug)]
pub enum Record {
    /// An EV step begins with a reference burst at this exposure. `targets` is its number of
    /// target frames when known up front (a DNG folder).
    BeginStep {
        index: usize,
        reference_exposure_ns: u64,
        targets: Option<usize>,
    },
    Frame(Frame),
    /// The camera's NoiseProfile for an ISO (recordings).
    NoiseProfile {
        iso: u32,
        profile: NoiseProfile,
    },
    /// A dark step begins: the frames up to the next [`Record::BeginStep`] are dark frames (lens
    /// covered): a recording's BeginDark record, or a DNG folder's frames in no EV step, last.
    BeginDark,
    /// The recording ends inside a record (an interrupted capture): nothing follows.
    CutShort(CodecError),
}

/// One frame with what the camera reported for it.
#[derive(Debug)]
pub struct Frame {
    /// Position among the set's frames (0-based, capture order).
    pub index: u64,
    pub meta: FrameMeta,
    /// The file it came from (a DNG folder).
    pub path: Option<PathBuf>,
    pixels: Pixels,
}

#[derive(Debug)]
enum Pixels {
    /// A DNG file's (memory-mapped: its uncompressed samples are read in place).
    Dng(Box<DngFile>),
    Recorded(RecordedFrame),
}

impl Frame {
    /// The pixels as the core reads them; a recorded buffer may not be a usable frame.
    pub fn view(&self) -> Result<FrameView<'_>, FrameError> {
        match &self.pixels {
            Pixels::Dng(f) => f.frame_view(),
            Pixels::Recorded(f) => f.view(),
        }
    }

    /// The pixels as an image.
    pub fn into_array(self) -> Result<Array2<u16>, FrameError> {
        match self.pixels {
            Pixels::Dng(f) => Ok(f.pixels().to_owned()),
            Pixels::Recorded(f) => Ok(f.view()?.to_array()),
        }
    }

    /// How messages name the frame: its file, or its place in the recording.
    pub fn label(&self) -> String {
        match &self.path {
            Some(p) => p.display().to_string(),
            None => format!("frame {} (ISO {}, {} ns)", self.index, self.meta.iso, self.meta.exposure_ns),
        }
    }
}

/// A capture set being read. See the module docs.
#[derive(Debug)]
pub struct Source {
    info: SourceInfo,
    stream: Stream,
}

#[derive(Debug)]
enum Stream {
    Dngs(DngStream),
    Recording(RecordingStream),
}

impl Source {
    /// A DNG folder or a recording. `reference_iso` overrides the lowest ISO of a DNG folder; a
    /// recording's is fixed by its header.
    pub fn open(path: &Path, reference_iso: Option<u32>) -> anyhow::Result<Self> {
        match input_kind(path)? {
            InputKind::DngFolder => Self::dngs(path, reference_iso),
            InputKind::Recording => Self::recording(path, reference_iso),
        }
    }

    /// A folder of DNGs, grouped into EV steps ([`grouping::scan_dng_set`]).
    pub fn dngs(dir: &Path, reference_iso: Option<u32>) -> anyhow::Result<Self> {
        let set = grouping::scan_dng_set(dir, reference_iso)?;
        let mut config = SessionConfig::new(set.reference_iso);
        config.make = set.make.clone();
        config.model = set.model.clone();
        let info = SourceInfo {
            path: dir.to_path_buf(),
            kind: InputKind::DngFolder,
            layout: set.layout.clone(),
            reference_iso: set.reference_iso,
            config,
            target_isos: set.target_isos(),
            noise_profiles: set.noise_profiles.clone(),
            warnings: set.warnings.clone(),
            frames: set.frames() as u64,
        };
        let stream = DngStream {
            steps: set.steps,
            dark: set.dark_candidates,
            step: 0,
            begun: false,
            next: 0,
            read: VecDeque::new(),
            frames: 0,
        };
        Ok(Self { info, stream: Stream::Dngs(stream) })
    }

    /// A recording made by the app (or `noisecal simulate --rec`).
    pub fn recording(path: &Path, reference_iso: Option<u32>) -> anyhow::Result<Self> {
        let f = std::fs::File::open(path).with_context(|| format!("cannot open {}", path.display()))?;
        let reader = RecordingReader::new(BufReader::with_capacity(1 << 20, f))
            .with_context(|| format!("{} is not a usable recording", path.display()))?;
        let header = reader.header().clone();
        if let Some(r) = reference_iso
            && r != header.reference_iso
        {
            bail!("the recording's reference ISO is {}; --reference-iso {r} cannot change it", header.reference_iso);
        }
        let len = std::fs::metadata(path).map(|m| m.len()).unwrap_or(0);
        let frame_bytes = header.layout.pixels() as u64 * 2 + 64;
        let info = SourceInfo {
            path: path.to_path_buf(),
            kind: InputKind::Recording,
            layout: header.layout.clone(),
            reference_iso: header.reference_iso,
            config: session_config(&header),
            target_isos: Vec::new(),
            noise_profiles: BTreeMap::new(),
            warnings: Vec::new(),
            frames: len / frame_bytes.max(1),
        };
        let stream = RecordingStream { reader, steps: 0, frames: 0, skipping: false, done: false };
        Ok(Self { info, stream: Stream::Recording(stream) })
    }

    pub fn info(&self) -> &SourceInfo {
        &self.info
    }

    /// The next record, `None` at the end. A DNG that cannot be read, or a recording that cannot
    /// be decoded (other than cut short), is an error.
    pub fn next_record(&mut self) -> anyhow::Result<Option<Record>> {
        match &mut self.stream {
            Stream::Dngs(s) => s.next_record(),
            Stream::Recording(s) => s.next_record().with_context(|| format!("reading {}", self.info.path.display())),
        }
    }

    /// Leaves out the current step's remaining frames (a DNG folder does not read them).
    pub fn skip_step(&mut self) {
        match &mut self.stream {
            Stream::Dngs(s) => s.skip_step(),
            Stream::Recording(s) => s.skipping = true,
        }
    }

    /// Whether the set ended as it should: a recording's End record was read.
    pub fn complete(&self) -> bool {
        match &self.stream {
            Stream::Dngs(_) => true,
            Stream::Recording(s) => s.reader.ended(),
        }
    }
}

/// The steps of a DNG folder, read in parallel a few frames at a time, handed over in order.
#[derive(Debug)]
struct DngStream {
    steps: Vec<DngStep>,
    /// Frames in no EV step, offered as dark frames after the steps.
    dark: Vec<DngFrame>,
    step: usize,
    begun: bool,
    /// Next frame of the step to read (reference frames, then targets).
    next: usize,
    read: VecDeque<(DngFrame, Result<DngFile, dng::DngError>)>,
    frames: u64,
}

impl DngStream {
    fn next_record(&mut self) -> anyhow::Result<Option<Record>> {
        loop {
            let Some(step) = self.steps.get(self.step) else { return self.next_dark() };
            if !self.begun {
                self.begun = true;
                self.next = 0;
                return Ok(Some(Record::BeginStep {
                    index: self.step,
                    reference_exposure_ns: step.key.reference_exposure_ns,
                    targets: Some(step.targets.len()),
                }));
            }
            if let Some((fr, img)) = self.read.pop_front() {
                let img = img?;
                let index = self.frames;
                self.frames += 1;
                return Ok(Some(Record::Frame(Frame {
                    index,
                    meta: fr.meta,
                    path: Some(fr.path),
                    pixels: Pixels::Dng(Box::new(img)),
                })));
            }
            let in_step = step.reference.len() + step.targets.len();
            if self.next >= in_step {
                self.step += 1;
                self.begun = false;
                continue;
            }
            // A frame per thread: each frame read ahead holds a buffer of the file's size (kept
            // for the next files), whose pages are faulted in once; more frames ahead only
            // fault in more of them.
            let end = (self.next + rayon::current_num_threads().max(2)).min(in_step);
            let group: Vec<&DngFrame> =
                step.reference.iter().chain(&step.targets).skip(self.next).take(end - self.next).collect();
            let imgs: Vec<Result<DngFile, dng::DngError>> =
                group.par_iter().map(|fr| dng::read_dng_source(&fr.path)).collect();
            self.read.extend(group.into_iter().cloned().zip(imgs));
            self.next = end;
        }
    }

    /// After the steps: BeginDark, then the frames in no step.
    fn next_dark(&mut self) -> anyhow::Result<Option<Record>> {
        if self.dark.is_empty() {
            return Ok(None);
        }
        if !self.begun {
            self.begun = true;
            self.next = 0;
            return Ok(Some(Record::BeginDark));
        }
        if self.read.is_empty() && self.next < self.dark.len() {
            let end = (self.next + rayon::current_num_threads().max(2)).min(self.dark.len());
            let group = &self.dark[self.next..end];
            let imgs: Vec<Result<DngFile, dng::DngError>> =
                group.par_iter().map(|fr| dng::read_dng_source(&fr.path)).collect();
            self.read.extend(group.iter().cloned().zip(imgs));
            self.next = end;
        }
        let Some((fr, img)) = self.read.pop_front() else { return Ok(None) };
        let img = img?;
        let index = self.frames;
        self.frames += 1;
        Ok(Some(Record::Frame(Frame { index, meta: fr.meta, path: Some(fr.path), pixels: Pixels::Dng(Box::new(img)) })))
    }

    fn skip_step(&mut self) {
        self.read.clear();
        if self.step >= self.steps.len() {
            self.dark.clear();
            return;
        }
        if self.begun {
            self.step += 1;
            self.begun = false;
        }
    }
}

#[derive(Debug)]
struct RecordingStream {
    reader: RecordingReader<BufReader<std::fs::File>>,
    steps: usize,
    frames: u64,
    skipping: bool,
    done: bool,
}

impl RecordingStream {
    fn next_record(&mut self) -> Result<Option<Record>, CodecError> {
        while !self.done {
            let record = match self.reader.next_record() {
                Ok(Some(r)) => r,
                Ok(None) => break,
                Err(e @ CodecError::CutShort { .. }) => {
                    self.done = true;
                    return Ok(Some(Record::CutShort(e)));
                }
                Err(e) => return Err(e),
            };
            match record {
                recording::Record::BeginStep { exposure_ns } => {
                    let index = self.steps;
                    self.steps += 1;
                    self.skipping = false;
                    return Ok(Some(Record::BeginStep { index, reference_exposure_ns: exposure_ns, targets: None }));
                }
                recording::Record::Frame(f) => {
                    let index = self.frames;
                    self.frames += 1;
                    if !self.skipping {
                        return Ok(Some(Record::Frame(Frame {
                            index,
                            meta: f.meta,
                            path: None,
                            pixels: Pixels::Recorded(f),
                        })));
                    }
                }
                recording::Record::NoiseProfile { iso, profile } => {
                    return Ok(Some(Record::NoiseProfile { iso, profile }));
                }
                recording::Record::BeginDark => {
                    self.skipping = false;
                    return Ok(Some(Record::BeginDark));
                }
                recording::Record::End { .. } => {}
            }
        }
        self.done = true;
        Ok(None)
    }
}
