//! A DNG folder's EV steps whose frames look dark, told apart: a dim lit step (a flat field a
//! fraction of a DN above black) stays an EV step, a covered lens becomes dark frames
//! (method.md, "Dim steps and dark frames").
//!
//! `check_dark` cannot tell them apart: it tests uniformity and a mean under 2 % of the range,
//! and a flat field is uniform. What can: the step's mean above black against the dark burst's
//! own mean and the spread of its frames' means ([`DarkLevels`]), the light the session's lit
//! frames show per unit of ISO × exposure ([`Law`]), and a step's frames against each other
//! (its lit frames, [`DimSteps::lit`]). Frames are held ([`Held`]) until that is known: a step
//! with a lit frame is decided then; a step without one waits for the dark burst, which a folder
//! streams last, and is then replayed as an EV step or pushed as dark frames.

use std::collections::BTreeMap;
use std::path::PathBuf;

use noisecal_core::{FrameMeta, POSITIONS};

/// A step is lit when its mean above the dark burst's is beyond this many standard errors of
/// the difference (the burst's frame-to-frame spread, which holds its flicker, over the step's
/// and the burst's frame counts). One-sided: under Gaussian flicker a covered step passes for
/// lit with probability 3·10⁻⁵.
pub const DIM_Z: f64 = 4.0;
/// Without a dark burst at the step's ISO, the black level is the metadata's: a covered lens may
/// sit this far above it (DN) and still be dark.
pub const NO_BURST_SLACK: f64 = 0.5;
/// Where dark current may lift a covered lens beyond the dark burst (a step exposed longer than
/// the burst, or no burst), a lit step must also show at least 1/`LAW_SHARE` of the light the
/// session's lit frames predict at its ISO × exposure: a covered lens at an exposure the lit
/// steps use shows none of it, only its dark current. Real sensors have an exposure offset (EMVA
/// set 002's 80 µs step holds 0.27 of what proportion predicts), so the share is wide.
pub const LAW_SHARE: f64 = 8.0;
/// A frame in a step with lit frames is dark when it holds less than 1/`PEER_SHARE` of their
/// light (at its own gain): a covered burst that happened to match the step's ISO × exposure.
pub const PEER_SHARE: f64 = 4.0;
/// The smallest difference (DN) from the dark burst's mean taken for light, whatever the
/// burst's spread: frame means of a sensor whose noise at black rounds to one code are all equal.
pub const MIN_LIGHT: f64 = 0.01;
/// Lit frames above this share of the range do not enter the exposure law (clipping bends it).
const LAW_TOP: f64 = 0.5;

/// What a held frame is known by.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Dim {
    pub iso: u32,
    pub exposure_ns: u64,
    /// ISO × exposure (ISO·s).
    pub brightness: f64,
    /// Its mean above black over the CFA positions (DN).
    pub level: f64,
}

impl Dim {
    pub fn of(meta: &FrameMeta, level: &[f64; POSITIONS]) -> Self {
        Self {
            iso: meta.iso,
            exposure_ns: meta.exposure_ns,
            brightness: meta.brightness(),
            level: level.iter().sum::<f64>() / POSITIONS as f64,
        }
    }
}

/// An EV step's frame that `check_dark` passed, held until it is known whether it is lit.
#[derive(Debug, Clone)]
pub struct Held {
    pub path: PathBuf,
    pub meta: FrameMeta,
    pub label: String,
    pub dim: Dim,
}

/// An EV step none of whose frames was lit, waiting for the dark burst.
#[derive(Debug, Clone)]
pub struct HeldStep {
    pub reference_exposure_ns: u64,
    pub frames: Vec<Held>,
    /// The step's lit frames' median level, when it had lit frames: its held frames are those
    /// that could not be decided alone (no dark burst at their ISO yet), decided against it.
    pub peer: Option<f64>,
}

/// The dark burst's frame means per ISO (frames in no EV step that the session took as dark).
#[derive(Debug, Clone, Default)]
pub struct DarkLevels {
    by_iso: BTreeMap<u32, Vec<f64>>,
    /// Per ISO, the burst's longest exposure (ns).
    exposure: BTreeMap<u32, u64>,
}

impl DarkLevels {
    pub fn push(&mut self, iso: u32, exposure_ns: u64, level: f64) {
        self.by_iso.entry(iso).or_default().push(level);
        let e = self.exposure.entry(iso).or_default();
        *e = (*e).max(exposure_ns);
    }

    /// Whether a frame at `exposure_ns` may hold more dark current than the burst at `iso`
    /// (its exposure is longer, beyond the rounding devices show).
    fn longer(&self, iso: u32, exposure_ns: u64) -> bool {
        self.exposure.get(&iso).is_none_or(|&d| exposure_ns as f64 > d as f64 * 1.005)
    }

    /// The burst's mean level, the SD of its frames' levels and its frame count, with at least
    /// two frames.
    fn at(&self, iso: u32) -> Option<(f64, f64, usize)> {
        let v = self.by_iso.get(&iso).filter(|v| v.len() >= 2)?;
        let n = v.len() as f64;
        let mean = v.iter().sum::<f64>() / n;
        let var = v.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0);
        Some((mean, var.sqrt(), v.len()))
    }

    fn mean(&self, iso: u32) -> f64 {
        self.at(iso).map_or(0.0, |(m, _, _)| m)
    }
}

/// The light per unit of ISO × exposure (DN per ISO·s) of the session's lit frames.
#[derive(Debug, Clone, Default)]
pub struct Law {
    ratios: Vec<f64>,
}

impl Law {
    /// Adds a lit frame (above the dark level, `range` DN from black to white).
    pub fn push(&mut self, dim: &Dim, range: f64) {
        if dim.brightness > 0.0 && dim.level > 0.0 && dim.level < LAW_TOP * range {
            self.ratios.push(dim.level / dim.brightness);
        }
    }

    /// The median ratio.
    fn slope(&self) -> Option<f64> {
        let mut v = self.ratios.clone();
        if v.is_empty() {
            return None;
        }
        v.sort_by(f64::total_cmp);
        Some(v[v.len() / 2])
    }
}

/// How a held step was decided, for the report.
#[derive(Debug, Clone, PartialEq)]
pub struct Verdict {
    /// Per frame, whether it is dark.
    pub dark: Vec<bool>,
    pub why: String,
}

/// Decides a held step's frames: with `peer` (its lit frames' median level), each ISO's frames
/// against it; otherwise the lowest ISO's frames (the reference burst) against the dark burst and
/// the law, and the others against them when lit. A step's frames share one ISO × exposure, so
/// lit ones show the same level above black at every ISO.
pub fn decide(frames: &[Dim], peer: Option<f64>, dark: &DarkLevels, law: Option<f64>) -> Verdict {
    let Some(iso0) = frames.iter().map(|f| f.iso).min() else {
        return Verdict { dark: Vec::new(), why: String::new() };
    };
    // Per ISO: the frames' mean level above the dark burst's, how many, and the level beyond
    // which a covered lens is unlikely (with what it was compared with).
    let group = |iso: u32| {
        let v: Vec<f64> = frames.iter().filter(|f| f.iso == iso).map(|f| f.level).collect();
        let k = v.len().max(1) as f64;
        let (tau, against) = match dark.at(iso) {
            Some((_, sd, n)) => (
                (DIM_Z * sd * (1.0 / k + 1.0 / n as f64).sqrt()).max(MIN_LIGHT),
                format!("the dark burst's {n} frames at ISO {iso}"),
            ),
            None => (NO_BURST_SLACK, format!("the metadata's black (no dark burst at ISO {iso})")),
        };
        (v.iter().sum::<f64>() / k - dark.mean(iso), tau, against)
    };
    let (peer, why) = match peer {
        Some(p) => (p, format!("its lit frames are {p:.2} DN above black")),
        None => {
            let (e, tau, against) = group(iso0);
            let at0 = || frames.iter().filter(|f| f.iso == iso0);
            let b = at0().map(|f| f.brightness).sum::<f64>() / at0().count().max(1) as f64;
            // The law decides only where dark current may exceed the burst's: at a longer
            // exposure, or with no burst to compare with.
            let longer = at0().any(|f| dark.longer(iso0, f.exposure_ns));
            let predicted = law.filter(|_| longer).map(|r| r * b);
            let lawful = predicted.is_none_or(|p| e >= p / LAW_SHARE);
            let law_note = predicted.map_or(String::new(), |p| format!("; the lit frames predict {p:.2} DN"));
            let why = format!("{e:+.3} DN against {against} (lit beyond {tau:.3} DN){law_note}");
            if !(e > tau && lawful) {
                return Verdict { dark: vec![true; frames.len()], why: format!("{why}: a covered lens") };
            }
            (e, format!("{why}: lit"))
        }
    };
    // An ISO's frames are dark when they hold less than 1/PEER_SHARE of the lit frames' light
    // and are not beyond the dark burst's spread.
    let mut verdicts: BTreeMap<u32, bool> = BTreeMap::new();
    let dark = frames
        .iter()
        .map(|f| {
            *verdicts.entry(f.iso).or_insert_with(|| {
                let (e, tau, _) = group(f.iso);
                e < peer / PEER_SHARE && e <= tau
            })
        })
        .collect();
    Verdict { dark, why }
}

/// The bookkeeping of held frames over a folder's stream.
#[derive(Debug, Clone, Default)]
pub struct DimSteps {
    /// The current step's held frames.
    step: Option<HeldStep>,
    /// The current step's lit frames' levels.
    peers: Vec<f64>,
    /// Steps none of whose frames was lit.
    held: Vec<HeldStep>,
    dark: DarkLevels,
    law: Law,
    /// One line per decided step.
    pub notes: Vec<String>,
}

impl DimSteps {
    pub fn begin_step(&mut self, reference_exposure_ns: u64) {
        self.end_step();
        self.step = Some(HeldStep { reference_exposure_ns, frames: Vec::new(), peer: None });
    }

    /// Ends the current step: its held frames wait for the dark burst.
    pub fn end_step(&mut self) {
        let peer = self.peer();
        self.peers.clear();
        if let Some(mut s) = self.step.take()
            && !s.frames.is_empty()
        {
            s.peer = peer;
            self.held.push(s);
        }
    }

    /// Whether steps wait for the dark burst (then its frames' levels are wanted).
    pub fn waiting(&self) -> bool {
        !self.held.is_empty()
    }

    fn peer(&self) -> Option<f64> {
        let mut v = self.peers.clone();
        v.sort_by(f64::total_cmp);
        v.get(v.len() / 2).copied()
    }

    /// A lit frame of the current step (`range`: its DN from black to white). Returns the held
    /// frames to push before it (lit) and those that are dark.
    pub fn lit(&mut self, dim: Dim, range: f64) -> (Vec<Held>, Vec<Held>) {
        self.law.push(&dim, range);
        self.peers.push(dim.level);
        match self.step.as_mut().map(|s| std::mem::take(&mut s.frames)) {
            Some(frames) if !frames.is_empty() => self.split(frames, None, self.peer()),
            _ => (Vec::new(), Vec::new()),
        }
    }

    /// A frame of the current step that `check_dark` passed: `Some(true)` when it is dark,
    /// `Some(false)` when lit (push it now), `None` when held.
    pub fn dim(&mut self, held: Held) -> Option<bool> {
        // With a dark burst at its ISO a frame is decided alone. Without one (yet) a single
        // frame's mean says little: the sensor's frame offsets move a covered frame by more than
        // `NO_BURST_SLACK` (a simulated phone's covered frames at ISO 800 read −1.7 … +0.9 DN),
        // so it is held and decided with its ISO's other held frames of the step, against the
        // step's lit frames, once the burst is known.
        if let Some(p) = self.peer()
            && (self.dark.at(held.dim.iso).is_some() || held.dim.level - self.dark.mean(held.dim.iso) >= p / PEER_SHARE)
        {
            let v = decide(&[held.dim], Some(p), &self.dark, None);
            return Some(v.dark[0]);
        }
        // Outside a step (no stream makes one) the frame is dark, as it always was.
        let Some(s) = self.step.as_mut() else { return Some(true) };
        s.frames.push(held);
        None
    }

    /// A frame the session took as dark outside the EV steps, at `level` above black.
    pub fn dark_frame(&mut self, meta: &FrameMeta, level: f64) {
        self.dark.push(meta.iso, meta.exposure_ns, level);
    }

    /// Decides `frames` (with the step's exposure for the note): (lit, dark).
    fn split(&mut self, frames: Vec<Held>, exposure: Option<u64>, peer: Option<f64>) -> (Vec<Held>, Vec<Held>) {
        let dims: Vec<Dim> = frames.iter().map(|h| h.dim).collect();
        let v = decide(&dims, peer, &self.dark, self.law.slope());
        let n_dark = v.dark.iter().filter(|&&d| d).count();
        let step = exposure.map_or(String::new(), |ns| format!(" (reference exposure {ns} ns)"));
        self.notes.push(format!(
            "EV step{step}: {} of {} frame(s) that look dark are dark frames, the rest dim but lit: {}",
            n_dark,
            frames.len(),
            v.why
        ));
        let (mut lit, mut dark) = (Vec::new(), Vec::new());
        for (h, d) in frames.into_iter().zip(v.dark) {
            if d { dark.push(h) } else { lit.push(h) }
        }
        (lit, dark)
    }

    /// After the stream: the waiting steps decided against the dark burst. Returns the lit steps
    /// (to replay as EV steps) and the dark frames.
    pub fn finish(&mut self) -> (Vec<HeldStep>, Vec<Held>) {
        self.end_step();
        let mut steps = Vec::new();
        let mut dark = Vec::new();
        for s in std::mem::take(&mut self.held) {
            let (lit, d) = self.split(s.frames, Some(s.reference_exposure_ns), s.peer);
            dark.extend(d);
            if !lit.is_empty() {
                steps.push(HeldStep { reference_exposure_ns: s.reference_exposure_ns, frames: lit, peer: None });
            }
        }
        (steps, dark)
    }
}

#[cfg(test)]
#[path = "tests_dim_steps.rs"]
mod tests;
