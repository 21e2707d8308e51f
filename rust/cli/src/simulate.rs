//! Writing a simulated capture session (the demo's and the tests' phone) as a DNG folder and/or a
//! raw recording, in capture order.

use std::io::BufWriter;
use std::path::Path;

use anyhow::Context;
use noisecal_core::recording::{RecordingHeader, RecordingWriter};
use noisecal_sim::{Chart, SensorModel, SessionPlan, Simulator};
use rayon::prelude::*;

use crate::dng;

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

impl SimSession {
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
        Ok(Self { sim, plan, make: "noisecal".into(), model: name.into(), index_offset: 0 })
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
                if let Some(parent) = p.parent().filter(|d| !d.as_os_str().is_empty()) {
                    std::fs::create_dir_all(parent)?;
                }
                let f = std::fs::File::create(p).with_context(|| format!("cannot create {}", p.display()))?;
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
        if let Some(w) = writer {
            w.finish()?;
        }
        Ok(())
    }
}
