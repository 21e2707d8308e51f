//! Writing a simulated capture session (the demo's and the tests' phone) as a DNG folder and/or a
//! raw recording, in capture order.

use std::io::BufWriter;
use std::path::Path;

use anyhow::Context;
use noisecal_core::format::recording::{RecordingHeader, RecordingWriter};
use noisecal_sim::{Chart, RandomSensor, SensorModel, SessionPlan, SessionSpec, Simulator};
use rayon::prelude::*;

use noisecal_input::dng;

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
        Ok(Self { sim, plan, make: "noisecal".into(), model: name.into(), index_offset: 0, dark_frames: 0 })
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
        plan.validate()?;
        Ok(Self { sim, plan, make: "noisecal".into(), model: name.into(), index_offset: 0, dark_frames: 0 })
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
        let stride = layout.width as usize * 2 + padding;
        let chunk = (rayon::current_num_threads() * 2).max(2);
        let mut last_step = None;
        for group in frames.chunks(chunk) {
            let caps: Vec<_> = group
                .par_iter()
                .map(|f| self.sim.capture(f.iso, f.exposure_ns, f.index + self.index_offset))
                .collect::<Result<Vec<_>, _>>()?;
            for (f, (pixels, meta)) in group.iter().zip(caps) {
                if let Some(d) = dngs {
                    let path = d.join(format!("f{:05}.dng", f.index));
                    dng::write_dng_from_layout(&path, &layout, &meta, &self.make, &self.model, &pixels)?;
                }
                if let Some(w) = writer.as_mut() {
                    if last_step != Some(f.step) {
                        w.begin_step(self.plan.exposure_ns(f.step, self.plan.reference_iso))?;
                        last_step = Some(f.step);
                    }
                    let bytes = noisecal_sim::to_padded_le_bytes(&pixels, stride);
                    w.frame(&meta, layout.width, layout.height, stride as u32, 2, &bytes)?;
                }
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
                    if let Some(d) = dngs {
                        let path = d.join(format!("f{index:05}.dng"));
                        dng::write_dng_from_layout(&path, &layout, &meta, &self.make, &self.model, &pixels)?;
                    }
                    if let Some(w) = writer.as_mut() {
                        let bytes = noisecal_sim::to_padded_le_bytes(&pixels, stride);
                        w.frame(&meta, layout.width, layout.height, stride as u32, 2, &bytes)?;
                    }
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
}
