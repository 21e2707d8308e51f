//! Writing a simulated capture session (the demo's and the tests' phone) as a DNG folder and/or a
//! raw recording, in capture order.

use std::io::BufWriter;
use std::path::Path;

use anyhow::Context;
use noisecal_core::format::recording::{RecordingHeader, RecordingWriter};
use noisecal_sim::{Chart, RandomSensor, SensorModel, SessionPlan, SessionSpec, Simulator};
use rayon::prelude::*;

use noisecal_input::dng;

/// Frame indices of a preset's held-out set (`noisecal simulate --heldout` on a preset, and the
/// `heldout/` folder `noisecal demo` writes) start here: the same sensor and chart with fresh
/// noise, past the frames of any calibration session and of the demo's own printed table.
pub const PRESET_HELDOUT_OFFSET: u64 = 1 << 41;
/// Frames per burst of a preset's held-out set unless given: a few per ISO, as `eval` needs.
pub const PRESET_HELDOUT_FRAMES: u32 = 4;

/// A simulated session: sensor, scene and plan.
#[derive(Debug, Clone)]
pub struct SimSession {
    pub sim: Simulator,
    pub plan: SessionPlan,
    pub make: String,
    pub model: String,
    /// Added to every frame index: a held-out session of the same sensor (same seed) gets fresh
    /// noise by starting at another index.
    pub index_offset: u64,
    /// Dark frames (lens covered) per ISO, written after the lit frames (a recording's dark step).
    pub dark_frames: u32,
    /// Whether the DNGs carry the sensor's true NoiseProfile at their ISO
    /// ([`crate::truth_profile::truth_noise_profile`]); recordings never do.
    pub noise_profile: bool,
}

/// Sensor presets by bit depth.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Preset {
    /// 10-bit, black 64, white 1023, RGGB, base ISO 50.
    Phone10,
    /// 12-bit, per-position black ~256, white 4095, GRBG, base ISO 100, dual conversion gain.
    Phone12,
    /// 14-bit, black 1024, white 16383, BGGR, base ISO 100, dual conversion gain.
    Phone14,
}

impl Preset {
    pub fn model(self) -> SensorModel {
        match self {
            Preset::Phone10 => SensorModel::phone_10bit(),
            Preset::Phone12 => SensorModel::phone_12bit(),
            Preset::Phone14 => SensorModel::phone_14bit(),
        }
    }

    pub fn name(self) -> &'static str {
        match self {
            Preset::Phone10 => "simulated phone 10-bit",
            Preset::Phone12 => "simulated phone 12-bit",
            Preset::Phone14 => "simulated phone 14-bit",
        }
    }
}

/// What `--sensor` names: a preset or a sensor of the random family.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SensorChoice {
    Preset(Preset),
    /// `random:SEED`: [`noisecal_sim::random_sensor`] and [`noisecal_sim::random_session`] of SEED.
    Random(u64),
}

impl std::str::FromStr for SensorChoice {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        use clap::ValueEnum;
        if let Some(seed) = s.strip_prefix("random:") {
            return seed
                .trim()
                .parse()
                .map(SensorChoice::Random)
                .map_err(|_| format!("`{s}`: the random family takes an integer seed, e.g. random:17"));
        }
        Preset::from_str(s, true)
            .map(SensorChoice::Preset)
            .map_err(|_| format!("`{s}`: use phone10, phone12, phone14 or random:SEED (e.g. random:17)"))
    }
}

impl SimSession {
    /// A session from a simulator and a plan (frame indices start at 0).
    pub fn from_parts(sim: Simulator, plan: SessionPlan, name: &str) -> anyhow::Result<Self> {
        plan.validate()?;
        Ok(Self {
            sim,
            plan,
            make: "noisecal".into(),
            model: name.into(),
            index_offset: 0,
            dark_frames: 0,
            noise_profile: false,
        })
    }

    /// The session `spec` of a random-family sensor with noise seed `seed`: its calibration
    /// capture, or with `heldout` its held-out set (same sensor, same base exposure, fewer frames,
    /// fresh noise from the spec's frame-index offset, possibly another image size).
    pub fn random(sensor: &RandomSensor, spec: &SessionSpec, seed: u64, heldout: bool) -> anyhow::Result<Self> {
        let sim = spec.simulator(&sensor.model, seed)?;
        let plan = spec.plan(&sim)?;
        let mut s = if heldout {
            let held = spec.heldout_plan(&plan)?;
            Self::from_parts(spec.heldout_simulator(&sensor.model, seed)?, held, &sensor.name())?
        } else {
            Self::from_parts(sim, plan, &sensor.name())?
        };
        if heldout {
            s.index_offset = spec.heldout.index_offset;
        }
        Ok(s)
    }

    pub fn new(
        model: SensorModel,
        name: &str,
        width: u32,
        height: u32,
        seed: u64,
        target_isos: Vec<u32>,
        frames_per_burst: u32,
        ev_steps: Vec<i32>,
    ) -> anyhow::Result<Self> {
        let chart = Chart::color_checker(width, height)?;
        let sim = Simulator::new(model, chart, seed)?;
        let plan = SessionPlan::for_simulator(&sim, target_isos, frames_per_burst)?.with_ev_steps(ev_steps);
        Self::from_parts(sim, plan, name)
    }

    /// The held-out set of this (preset) session: the same sensor, chart, ISOs and EV steps with
    /// `frames` per burst (the reference bursts included) and fresh noise from
    /// [`PRESET_HELDOUT_OFFSET`].
    pub fn heldout(mut self, frames: u32) -> anyhow::Result<Self> {
        self.plan.frames_per_burst = frames;
        self.plan.validate()?;
        self.index_offset = PRESET_HELDOUT_OFFSET;
        Ok(self)
    }

    /// Frames the session writes, dark frames included.
    pub fn frames(&self) -> usize {
        self.plan.len() + self.plan.dark_settings().len() * self.dark_frames as usize
    }

    /// Writes the session: DNGs named by capture index into `dngs`, and/or a recording with
    /// `padding` extra bytes per row into `rec`.
    pub fn write(
        &self,
        dngs: Option<&Path>,
        rec: Option<&Path>,
        padding: usize,
        mut tick: impl FnMut(),
    ) -> anyhow::Result<()> {
        let layout = self.sim.layout();
        if let Some(d) = dngs {
            std::fs::create_dir_all(d).with_context(|| format!("cannot create {}", d.display()))?;
        }
        let mut writer = match rec {
            Some(p) => {
                noisecal_input::files::create_parent(p)
                    .with_context(|| format!("cannot create the directory of {}", p.display()))?;
                // Streamed into a temporary file renamed over `p` at the end: a kill leaves no
                // partial recording (the next write into the folder removes the temporary file).
                let f = noisecal_io::AtomicFile::create(p).with_context(|| format!("cannot create {}", p.display()))?;
                let header = RecordingHeader {
                    layout: layout.clone(),
                    reference_iso: self.plan.reference_iso,
                    bin_width: 0,
                    make: self.make.clone(),
                    model: self.model.clone(),
                };
                Some(RecordingWriter::new(BufWriter::with_capacity(1 << 20, f), &header)?)
            }
            None => None,
        };
        let frames: Vec<_> = self.plan.frames().collect();
        let profiles = Profiles::new(&self.sim, self.noise_profile && dngs.is_some());
        let stride = layout.width as usize * 2 + padding;
        let chunk = (rayon::current_num_threads() * 2).max(2);
        let mut last_step = None;
        for group in frames.chunks(chunk) {
            let caps: Vec<_> = group
                .par_iter()
                .map(|f| self.sim.capture(f.iso, f.exposure_ns, f.index + self.index_offset))
                .collect::<Result<Vec<_>, _>>()?;
            for (f, (pixels, meta)) in group.iter().zip(caps) {
                if let Some(w) = writer.as_mut()
                    && last_step != Some(f.step)
                {
                    w.begin_step(self.plan.exposure_ns(f.step, self.plan.reference_iso))?;
                    last_step = Some(f.step);
                }
                self.emit(dngs, writer.as_mut(), &profiles, f.index, &pixels, &meta, stride)?;
                tick();
            }
        }
        // Dark frames (lens covered) last: per ISO of the plan, at the shortest exposure it uses.
        if self.dark_frames > 0 {
            if let Some(w) = writer.as_mut() {
                w.begin_dark()?;
            }
            let mut index = frames.iter().map(|f| f.index + 1).max().unwrap_or(0);
            for (iso, exposure_ns) in self.plan.dark_settings() {
                let caps: Vec<_> = (0..self.dark_frames as u64)
                    .into_par_iter()
                    .map(|i| self.sim.capture_dark(iso, exposure_ns, i + self.index_offset))
                    .collect::<Result<Vec<_>, _>>()?;
                for (pixels, meta) in caps {
                    self.emit(dngs, writer.as_mut(), &profiles, index, &pixels, &meta, stride)?;
                    index += 1;
                    tick();
                }
            }
        }
        if let Some(w) = writer {
            let p = rec.unwrap_or(Path::new("the recording"));
            let file = w.finish()?.into_inner().map_err(|e| e.into_error())?;
            file.commit().with_context(|| format!("cannot write {}", p.display()))?;
        }
        Ok(())
    }

    /// One captured frame as `f{index:05}.dng` in `dngs` (with its NoiseProfile when profiles
    /// are written) and as the next frame of the recording `writer`, each when given.
    #[allow(clippy::too_many_arguments)]
    fn emit<W: std::io::Write>(
        &self,
        dngs: Option<&Path>,
        writer: Option<&mut RecordingWriter<W>>,
        profiles: &Profiles<'_>,
        index: u64,
        pixels: &ndarray::Array2<u16>,
        meta: &noisecal_core::FrameMeta,
        stride: usize,
    ) -> anyhow::Result<()> {
        let layout = self.sim.layout();
        if let Some(d) = dngs {
            let path = d.join(format!("f{index:05}.dng"));
            let np = profiles.at(meta.iso)?;
            dng::write_dng_from_layout_with_profile(
                &path,
                &layout,
                meta,
                &self.make,
                &self.model,
                pixels,
                np.as_ref(),
            )?;
        }
        if let Some(w) = writer {
            let bytes = noisecal_sim::to_padded_le_bytes(pixels, stride);
            w.frame(meta, layout.width, layout.height, stride as u32, 2, &bytes)?;
        }
        Ok(())
    }
}

/// What `noisecal simulate --bench` writes.
#[derive(Debug, Clone)]
pub struct BenchSpec {
    pub width: u32,
    pub height: u32,
    /// Target ISOs (the base ISO, the sensor's, is the reference).
    pub isos: Vec<u32>,
    /// Base-ISO frames per evaluation scene.
    pub burst: u32,
    pub scenes: u32,
    pub train_scenes: u32,
    /// Real frames per training scene and target ISO.
    pub train_frames: u32,
    /// Noise seed (the sensor's PRNU/DSNU and every frame); scenes are seeded from it too.
    pub seed: u64,
    /// Whether every DNG carries the sensor's true NoiseProfile at its ISO.
    pub noise_profile: bool,
}

impl BenchSpec {
    /// Frames (and clean images) written; `moving`: a moving scene's evaluation scenes have no
    /// burst (their clean images are the truth, see [`write_bench_set`]).
    pub fn frames(&self, moving: bool) -> usize {
        let per_eval = if moving { 0 } else { self.burst as usize } + self.isos.len();
        let per_train = 1 + self.isos.len() * self.train_frames as usize;
        self.scenes as usize * per_eval + self.train_scenes as usize * per_train
    }
}

/// The true NoiseProfile per ISO, computed once per ISO when wanted.
struct Profiles<'a> {
    sim: &'a Simulator,
    on: bool,
    cache: std::sync::Mutex<std::collections::BTreeMap<u32, noisecal_core::model::pack::NoiseProfile>>,
}

impl<'a> Profiles<'a> {
    fn new(sim: &'a Simulator, on: bool) -> Self {
        Self { sim, on, cache: Default::default() }
    }

    /// The profile at `iso`, or `None` when profiles are not written.
    fn at(&self, iso: u32) -> anyhow::Result<Option<noisecal_core::model::pack::NoiseProfile>> {
        if !self.on {
            return Ok(None);
        }
        let mut cache = self.cache.lock().unwrap_or_else(|e| e.into_inner());
        if let Some(p) = cache.get(&iso) {
            return Ok(Some(*p));
        }
        let p = crate::truth_profile::truth_noise_profile(self.sim, iso)?;
        cache.insert(iso, p);
        Ok(Some(p))
    }
}

/// `a` as a numpy `.npy` file (format 1.0, little-endian float32, C order), atomically. Written by
/// hand: the format is a fixed header and the raw values, and the workspace has no npy crate.
fn write_npy_f32(path: &Path, a: &ndarray::Array2<f32>) -> anyhow::Result<()> {
    let (h, w) = a.dim();
    let mut header = format!("{{'descr': '<f4', 'fortran_order': False, 'shape': ({h}, {w}), }}");
    // Magic (6) + version (2) + length (2) + header + '\n', padded to a multiple of 64 bytes.
    let pad = (64 - (10 + header.len() + 1) % 64) % 64;
    header.push_str(&" ".repeat(pad));
    header.push('\n');
    let mut bytes = Vec::with_capacity(10 + header.len() + 4 * h * w);
    bytes.extend_from_slice(b"\x93NUMPY\x01\x00");
    bytes.extend_from_slice(&(header.len() as u16).to_le_bytes());
    bytes.extend_from_slice(header.as_bytes());
    for v in a.iter() {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    noisecal_io::write_bytes_atomic(path, &bytes).with_context(|| format!("cannot write {}", path.display()))
}

/// Frame indices of training scenes start here (evaluation scenes below it): fresh noise.
const TRAIN_INDEX: u64 = 1 << 40;
/// Frame indices per scene.
const SCENE_FRAMES: u64 = 1 << 20;

/// Writes a denoiser-benchmark set (see `noisecal simulate --bench`) into `dir`:
/// `eval/sceneNNN/ref_KKK.dng` (the base-ISO burst) and `eval/sceneNNN/iso<ISO>.dng`;
/// `train/clean/sceneNNN.dng` (the noiseless base-ISO image, rounded) and
/// `train/captures/sceneNNN_iso<ISO>_<K>.dng`. A moving scene (`model.motion`) would blur a
/// burst's mean, so its evaluation frames come with their truth instead:
/// `eval/sceneNNN_iso<ISO>/iso<ISO>.dng` and `clean.npy`, the frame's own noiseless image at the
/// base ISO's brightness ([`Simulator::clean_expected_frame`], float32 DN), and no burst. Scene `i` is exposed `−(i mod 4)` EV below
/// the exposure that puts its brightest texel at 84 % of the range at the base ISO; a target ISO keeps ISO × exposure. Deterministic in
/// the spec on any thread count. The training scenes never move, a moving model's included: their
/// captures are the noisy halves of pairs whose clean half is the one still image, and a capture
/// that moved would pair the noise with another pose (the same bytes as the still set's).
pub fn write_bench_set(
    model: &SensorModel,
    name: &str,
    spec: &BenchSpec,
    dir: &Path,
    mut tick: impl FnMut(),
) -> anyhow::Result<()> {
    let base = model.base_iso;
    if let Some(bad) = spec.isos.iter().find(|&&i| i <= base) {
        anyhow::bail!(
            "--isos: ISO {bad} is not above the sensor's base ISO {base} (the clean images' ISO): give higher target ISOs"
        );
    }
    let eval = dir.join("eval");
    let clean_dir = dir.join("train").join("clean");
    let cap_dir = dir.join("train").join("captures");
    for d in [&eval, &clean_dir, &cap_dir] {
        std::fs::create_dir_all(d).with_context(|| format!("cannot create {}", d.display()))?;
    }
    let make = "noisecal";
    let moving = model.motion.is_some();
    let scene_sim = |scene_seed: u64| -> anyhow::Result<Simulator> {
        let chart = Chart::natural(spec.width, spec.height, scene_seed)?;
        Ok(Simulator::new(model.clone(), chart, spec.seed)?)
    };
    let exposure = |sim: &Simulator, i: u32, iso: u32| -> anyhow::Result<u64> {
        // The brightest texel at 0.35 × 2.4 = 84 % of the range, then 1, 2, 3 EV darker in turn.
        let mid = sim.mid_range_exposure_ns(base)? as f64 * 2.4 / f64::from(1u32 << (i % 4));
        Ok(((mid * base as f64 / iso as f64).round() as u64).max(1))
    };
    for i in 0..spec.scenes {
        let sim = scene_sim(spec.seed.wrapping_mul(1_000_003).wrapping_add(i as u64))?;
        let layout = sim.layout();
        let d = eval.join(format!("scene{i:03}"));
        let first = i as u64 * SCENE_FRAMES;
        let mut jobs: Vec<(u32, u64, std::path::PathBuf)> = Vec::new();
        if !moving {
            std::fs::create_dir_all(&d).with_context(|| format!("cannot create {}", d.display()))?;
            jobs.extend((0..spec.burst).map(|k| (base, first + k as u64, d.join(format!("ref_{k:03}.dng")))));
        }
        for (j, &iso) in spec.isos.iter().enumerate() {
            let index = first + (spec.burst as usize + j) as u64;
            let path = if moving {
                let own = eval.join(format!("scene{i:03}_iso{iso}"));
                std::fs::create_dir_all(&own).with_context(|| format!("cannot create {}", own.display()))?;
                let truth =
                    sim.clean_expected_frame(iso, exposure(&sim, i, iso)?, index, base, exposure(&sim, i, base)?)?;
                write_npy_f32(&own.join("clean.npy"), &truth)?;
                own.join(format!("iso{iso}.dng"))
            } else {
                d.join(format!("iso{iso}.dng"))
            };
            jobs.push((iso, index, path));
        }
        let caps: Vec<_> = jobs
            .par_iter()
            .map(|(iso, k, _)| sim.capture(*iso, exposure(&sim, i, *iso)?, *k).map_err(anyhow::Error::from))
            .collect::<anyhow::Result<Vec<_>>>()?;
        let profiles = Profiles::new(&sim, spec.noise_profile);
        for ((_, _, path), (pixels, meta)) in jobs.iter().zip(caps) {
            dng::write_dng_from_layout_with_profile(
                path,
                &layout,
                &meta,
                make,
                name,
                &pixels,
                profiles.at(meta.iso)?.as_ref(),
            )?;
            tick();
        }
    }
    let still = SensorModel { motion: None, ..model.clone() };
    for i in 0..spec.train_scenes {
        let seed = spec.seed.wrapping_mul(1_000_003).wrapping_add(TRAIN_INDEX + i as u64);
        let sim = Simulator::new(still.clone(), Chart::natural(spec.width, spec.height, seed)?, spec.seed)?;
        let layout = sim.layout();
        let exp = exposure(&sim, i, base)?;
        let clean = sim.clean_expected(base, exp)?.mapv(|v| v.round().clamp(0.0, layout.white as f32) as u16);
        let meta = noisecal_core::FrameMeta { iso: base, exposure_ns: exp, black: None };
        // The clean image is noiseless: it carries no NoiseProfile.
        dng::write_dng_from_layout(&clean_dir.join(format!("scene{i:03}.dng")), &layout, &meta, make, name, &clean)?;
        tick();
        let jobs: Vec<(u32, u32)> =
            spec.isos.iter().flat_map(|&iso| (0..spec.train_frames).map(move |k| (iso, k))).collect();
        let caps: Vec<_> = jobs
            .par_iter()
            .enumerate()
            .map(|(n, (iso, _))| {
                let index = TRAIN_INDEX + i as u64 * SCENE_FRAMES + n as u64;
                sim.capture(*iso, exposure(&sim, i, *iso)?, index).map_err(anyhow::Error::from)
            })
            .collect::<anyhow::Result<Vec<_>>>()?;
        let profiles = Profiles::new(&sim, spec.noise_profile);
        for ((iso, k), (pixels, meta)) in jobs.iter().zip(caps) {
            let path = cap_dir.join(format!("scene{i:03}_iso{iso}_{k}.dng"));
            dng::write_dng_from_layout_with_profile(
                &path,
                &layout,
                &meta,
                make,
                name,
                &pixels,
                profiles.at(*iso)?.as_ref(),
            )?;
            tick();
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sensor_choices_parse() {
        assert_eq!("random:17".parse::<SensorChoice>(), Ok(SensorChoice::Random(17)));
        assert_eq!("phone12".parse::<SensorChoice>(), Ok(SensorChoice::Preset(Preset::Phone12)));
        assert!("random:x".parse::<SensorChoice>().expect_err("bad seed").contains("integer seed"));
        assert!("phone13".parse::<SensorChoice>().expect_err("bad name").contains("random:SEED"));
    }

    #[test]
    fn random_sessions_and_their_held_out_sets() {
        let mut dense_seen = false;
        for seed in 0..12 {
            let sensor = noisecal_sim::random_sensor(seed);
            let spec = noisecal_sim::random_session(seed, &sensor.model);
            let cal = SimSession::random(&sensor, &spec, 1, false).expect("calibration session");
            let held = SimSession::random(&sensor, &spec, 1, true).expect("held-out session");
            assert_eq!(cal.index_offset, 0);
            assert_eq!(held.index_offset, spec.heldout.index_offset);
            assert!(held.index_offset >= cal.plan.len() as u64);
            assert_eq!(held.plan.base_exposure_ns, cal.plan.base_exposure_ns);
            assert_eq!((held.sim.width() as u32, held.sim.height() as u32), (spec.heldout.width, spec.heldout.height));
            dense_seen |= spec.dense;
        }
        assert!(dense_seen);
    }

    /// Known truth in, measured out: a moving frame minus its own truth is the sensor's noise
    /// alone (variance as the model predicts it), where the unmoved scene leaves the motion in.
    #[test]
    fn a_moving_frames_truth_is_its_own_noiseless_image() {
        let mut model = Preset::Phone10.model();
        model.motion = Some(noisecal_sim::random_moving_scene(3).motion);
        let white = f32::from(model.white);
        let sim = Simulator::new(model, Chart::natural(128, 128, 11).expect("scene"), 4).expect("sim");
        let iso = 400;
        let exp = sim.mid_range_exposure_ns(iso).expect("exposure") * 2;
        let still = sim.clean_expected(iso, exp).expect("still truth");
        let (mut own, mut unmoved, mut predicted) = (0.0, 0.0, 0.0);
        for k in [1u64, 5, 9] {
            let (frame, _) = sim.capture(iso, exp, k).expect("frame");
            let truth = sim.clean_expected_frame(iso, exp, k, iso, exp).expect("truth");
            for ((y, x), &v) in frame.indexed_iter() {
                let t = truth[(y, x)];
                if t > 0.9 * white {
                    continue; // clipping: the mean of clipped noise is not the clean level
                }
                own += (f64::from(v) - f64::from(t)).powi(2);
                unmoved += (f64::from(v) - f64::from(still[(y, x)])).powi(2);
                predicted +=
                    sim.predicted_variance(iso, t, noisecal_core::model::layout::position(y, x)).expect("variance");
            }
        }
        let (r_own, r_unmoved) = (own / predicted, unmoved / predicted);
        eprintln!(
            "moving frame − its truth: {r_own:.3}; − the unmoved scene: {r_unmoved:.3} (× the predicted noise variance)"
        );
        // ~49 000 pixels: the ratio's sampling SE is under 1 %.
        assert!((r_own - 1.0).abs() < 0.05, "frame − its truth: {r_own:.3} × the predicted noise variance");
        assert!(
            r_unmoved > 1.3,
            "frame − the unmoved scene: {r_unmoved:.3} × the noise variance (the motion should show)"
        );
    }

    #[test]
    fn bench_sets_are_laid_out_and_the_same_bytes_on_any_thread_count() {
        let spec = BenchSpec {
            width: 32,
            height: 32,
            isos: vec![400, 1600],
            burst: 3,
            scenes: 2,
            train_scenes: 2,
            train_frames: 2,
            seed: 4,
            noise_profile: false,
        };
        let model = Preset::Phone10.model();
        let write = |threads: usize| {
            let dir = tempfile::tempdir().expect("tempdir");
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            let mut n = 0;
            pool.install(|| write_bench_set(&model, "sim", &spec, dir.path(), || n += 1)).expect("bench set");
            assert_eq!(n, spec.frames(false));
            dir
        };
        let (a, b) = (write(1), write(3));
        let mut files = Vec::new();
        for sub in ["eval/scene000", "eval/scene001", "train/clean", "train/captures"] {
            for e in std::fs::read_dir(a.path().join(sub)).expect("dir") {
                files.push(std::path::Path::new(sub).join(e.expect("entry").file_name()));
            }
        }
        files.sort();
        // 2 × (3 + 2) evaluation frames, 2 clean images, 2 × 2 × 2 captures.
        assert_eq!(files.len(), 10 + 2 + 8);
        assert!(files.iter().any(|f| f.ends_with("eval/scene001/iso1600.dng")));
        assert!(files.iter().any(|f| f.ends_with("train/captures/scene001_iso400_1.dng")));
        for f in &files {
            let (x, y) = (std::fs::read(a.path().join(f)).expect("a"), std::fs::read(b.path().join(f)).expect("b"));
            assert!(x == y, "{} differs between 1 and 3 threads", f.display());
        }
        // A moving scene (the random family's motion): the same bytes on any thread count too,
        // and its evaluation frames move while the training scenes (clean images and captures)
        // stay: the still set's bytes.
        let mut moving = model.clone();
        moving.motion = Some(noisecal_sim::random_moving_scene(3).motion);
        let write_moving = |threads: usize| {
            let dir = tempfile::tempdir().expect("tempdir");
            let pool = rayon::ThreadPoolBuilder::new().num_threads(threads).build().expect("pool");
            pool.install(|| write_bench_set(&moving, "sim", &spec, dir.path(), || {})).expect("moving set");
            dir
        };
        let (m1, m3) = (write_moving(1), write_moving(3));
        let read = |d: &std::path::Path, f: &std::path::Path| std::fs::read(d.join(f)).expect("read");
        // A moving evaluation scene has no burst (its mean would blur): each target frame has a
        // folder of its own with its truth, clean.npy.
        let mut mfiles = Vec::new();
        for sub in ["train/clean", "train/captures"] {
            for e in std::fs::read_dir(m1.path().join(sub)).expect("dir") {
                mfiles.push(std::path::Path::new(sub).join(e.expect("entry").file_name()));
            }
        }
        for i in 0..2 {
            for iso in [400, 1600] {
                let d = std::path::Path::new("eval").join(format!("scene{i:03}_iso{iso}"));
                mfiles.push(d.join(format!("iso{iso}.dng")));
                mfiles.push(d.join("clean.npy"));
            }
        }
        assert!(!m1.path().join("eval/scene000").exists(), "a moving scene has no burst folder");
        let mut moved = 0;
        for f in &mfiles {
            assert!(
                read(m1.path(), f) == read(m3.path(), f),
                "{} (moving) differs between 1 and 3 threads",
                f.display()
            );
            if f.starts_with("train/clean") {
                assert!(read(m1.path(), f) == read(a.path(), f), "the clean image {} moved", f.display());
            } else if f.starts_with("train/captures") {
                moved += usize::from(read(m1.path(), f) != read(a.path(), f));
            }
        }
        assert_eq!(moved, 0, "the training captures stay still, as their clean images");
        for i in 0..2u32 {
            for iso in [400u32, 1600] {
                let d = m1.path().join(format!("eval/scene{i:03}_iso{iso}"));
                let still = read(a.path(), &std::path::Path::new("eval").join(format!("scene{i:03}/iso{iso}.dng")));
                assert!(
                    read(&d, std::path::Path::new(&format!("iso{iso}.dng"))) != still,
                    "scene {i} ISO {iso} did not move"
                );
                let npy = read(&d, std::path::Path::new("clean.npy"));
                assert_eq!(&npy[..8], b"\x93NUMPY\x01\x00");
                let hlen = u16::from_le_bytes([npy[8], npy[9]]) as usize;
                assert_eq!((10 + hlen) % 64, 0, "the header is padded to 64 bytes");
                let header = std::str::from_utf8(&npy[10..10 + hlen]).expect("ASCII header");
                assert!(header.contains("'descr': '<f4'") && header.contains("'shape': (32, 32)"), "{header}");
                assert_eq!(npy.len(), 10 + hlen + 4 * 32 * 32);
            }
        }
        let low = BenchSpec { isos: vec![50, 400], ..spec.clone() };
        let err = write_bench_set(&model, "sim", &low, a.path(), || {}).expect_err("base ISO as a target");
        assert!(err.to_string().contains("not above the sensor's base ISO 50"), "{err}");
    }
}
