//! `noisecal simulate --dngs captures/ --rec session.rec`: a simulated phone session, for trying
//! the tool and for tests. `--sensor random:SEED` draws a sensor and its session from the
//! random family of `noisecal-sim` instead of a preset.

use std::path::PathBuf;

use anyhow::bail;

use crate::simulate::{PRESET_HELDOUT_FRAMES, Preset, SensorChoice, SimSession};
use crate::support::progress_bar;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Sensor preset.
    #[arg(long, value_enum, default_value_t = Preset::Phone10)]
    pub preset: Preset,
    /// Sensor: a preset (phone10, phone12, phone14) or `random:SEED`, a sensor and session drawn
    /// from the random family (bit depth, CFA, black, gains, read-noise shape, γ, dual and
    /// digital gain, row noise, PRNU, DSNU…; printed unless --quiet). With random:SEED the size,
    /// ISOs, frames and EV steps come from the drawn session unless given. Overrides --preset.
    #[arg(long, value_name = "SENSOR")]
    pub sensor: Option<SensorChoice>,
    /// Image width [default: 320, or the random session's].
    #[arg(long, value_parser = clap::value_parser!(u32).range(crate::cmd::bounds::SIDE))]
    pub width: Option<u32>,
    /// Image height [default: 240, or the random session's].
    #[arg(long, value_parser = clap::value_parser!(u32).range(crate::cmd::bounds::SIDE))]
    pub height: Option<u32>,
    /// Target ISOs (comma-separated) [default: 100,200,400,800,1600, or the random session's].
    #[arg(long, value_delimiter = ',')]
    pub isos: Option<Vec<u32>>,
    /// Frames per burst [default: 8, or the random session's].
    #[arg(long, value_parser = clap::value_parser!(u32).range(crate::cmd::bounds::FRAMES))]
    pub frames: Option<u32>,
    /// EV steps (comma-separated), in units of 1/--ev-per-stop EV [default: -4..4, or the random
    /// session's].
    #[arg(long, value_delimiter = ',', allow_negative_numbers = true)]
    pub ev: Option<Vec<i32>>,
    /// EV steps per stop: 1 for whole stops, e.g. 10 for `--ev -10,-9,…,10` = ±1 EV in tenths
    /// [default: 1, or the random session's].
    #[arg(long)]
    pub ev_per_stop: Option<u32>,
    /// Noise seed (PRNU/DSNU maps and every frame's noise); the sensor's seed is in --sensor.
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
    /// Some frames flicker by this fraction (e.g. 0.03).
    #[arg(long)]
    pub flicker: Option<f32>,
    /// The scene moves between frames, as a phone on a tripod shows it: the random family's
    /// moving scene (`random_moving_scene`, drawn from the family seed of random:SEED, else from
    /// --seed: a walk of sub-pixel shifts with jumps, rotation, focus breathing, and in 1 draw
    /// of 3 a flickering lamp unless --flicker is given; with random:SEED the chart's edges are
    /// blurred too). Printed unless --quiet. With --bench the evaluation frames move (each with
    /// its own truth); the training scenes, clean images and captures, stay still; --heldout
    /// stays still.
    #[arg(long)]
    pub moving: bool,
    /// Write the session's held-out set instead of its calibration capture: the same sensor and
    /// exposures with fresh noise and fewer frames. With random:SEED, the drawn session's held-out
    /// set (possibly another size); with a preset, the same chart, size, ISOs and EV steps as the
    /// calibration session given by the same options, 4 frames per burst unless --frames (the
    /// demo's is `--preset phone10 --width 384 --height 288 --isos 100,200,400,800,1600,3200`,
    /// which `noisecal demo` writes as demo/heldout/).
    #[arg(long)]
    pub heldout: bool,
    /// Write DNGs into this folder.
    #[arg(long)]
    pub dngs: Option<PathBuf>,
    /// Write a raw recording (the app's format) to this file.
    #[arg(long)]
    pub rec: Option<PathBuf>,
    /// Start frame indices here: the same sensor (same --seed) with fresh noise, e.g. a held-out set.
    /// Added to the held-out offset with --heldout.
    #[arg(long, default_value_t = 0)]
    pub index_offset: u64,
    /// Extra bytes of padding per row in the recording (Camera2 row stride).
    #[arg(long, default_value_t = 32, value_parser = crate::cmd::bounds::padding)]
    pub padding: usize,
    /// Give the sensor (preset or random:SEED) phone-like structured noise, scaled on its read
    /// noise σ_pre (e⁻, before the gain) and σ_post (DN, after it; with dual gain, the first
    /// conversion gain's): row noise of σ/8 RMS (one Gaussian offset per row and frame), a
    /// per-frame black-level error per CFA position of 0.25·σ_pre and 0.4·σ_post RMS (Laplace, a
    /// third of its variance shared by the four positions), and DSNU (fixed per-pixel dark
    /// offsets) of σ/5 RMS; these replace the sensor's own row noise and DSNU, and their pre-gain
    /// parts grow with the analog gain. No column noise. The values are printed unless --quiet.
    #[arg(long)]
    pub structured: bool,
    /// Dark frames (lens covered) per ISO, after the lit frames, at the shortest exposure each ISO
    /// uses: the optional dark step that measures the fixed pattern. 0 = none.
    #[arg(long, default_value_t = 0, value_parser = clap::value_parser!(u32).range(0..=256))]
    pub dark: u32,
    /// Every DNG (noisy frames; not --bench's clean training images) carries the sensor's true
    /// NoiseProfile at its ISO (DNG tag 51041, Camera2's SENSOR_NOISE_PROFILE: per colour plane,
    /// variance/R² = S·x + O on the signal x = (level − black)/R, R = white − black), as a
    /// camera writes its own: what the `noiseprofile` baseline and `noisecal-bench --models
    /// noiseprofile` read. Off by default, so earlier sessions keep their bytes.
    #[arg(long)]
    pub noise_profile: bool,
    /// Write a denoiser-benchmark set into this folder instead of a calibration session (for
    /// `noisecal-bench`): natural-statistics scenes (dead leaves, not charts), `eval/sceneNNN/`
    /// each a burst of --frames at the base ISO (its mean is the clean image) and one frame per
    /// target ISO at the same ISO × exposure; `train/clean/` the noiseless scenes at the base ISO
    /// (clean training images); `train/captures/` --train-frames real frames of each training
    /// scene per target ISO (the oracle's training data, and the ISO-a captures noise on noise
    /// starts from). Scene i is exposed i mod 4 EV below the exposure that puts its brightest part at 84 % of the
    /// range (low light included).
    #[arg(long, value_name = "DIR", conflicts_with_all = ["dngs", "rec", "heldout", "dark"])]
    pub bench: Option<PathBuf>,
    /// With --bench: evaluation scenes.
    #[arg(long, default_value_t = 8, requires = "bench", value_parser = clap::value_parser!(u32).range(1..=10000))]
    pub scenes: u32,
    /// With --bench: training scenes.
    #[arg(long, default_value_t = 16, requires = "bench", value_parser = clap::value_parser!(u32).range(1..=100000))]
    pub train_scenes: u32,
    /// With --bench: real frames per training scene and target ISO.
    #[arg(long, default_value_t = 2, requires = "bench", value_parser = clap::value_parser!(u32).range(1..=256))]
    pub train_frames: u32,
}

pub fn run(args: Args, quiet: bool) -> anyhow::Result<()> {
    if let Some(dir) = &args.bench {
        return bench_set(&args, dir, quiet);
    }
    if args.dngs.is_none() && args.rec.is_none() {
        bail!("nothing to write: give --dngs DIR and/or --rec FILE");
    }
    let choice = args.sensor.unwrap_or(SensorChoice::Preset(args.preset));
    let mut s = match choice {
        SensorChoice::Preset(preset) => {
            let mut model = preset.model();
            if args.structured {
                model = model.with_structured_noise();
                if !quiet {
                    eprintln!("sensor {}{}", preset.name(), structured_text(&model));
                }
            }
            if let Some(a) = args.flicker {
                model.flicker = Some(noisecal_sim::Flicker { probability: 0.1, amplitude: a });
            }
            if args.moving && !args.heldout {
                move_scene(&mut model, args.seed, args.flicker.is_some(), quiet);
            }
            let mut s = SimSession::new(
                model,
                preset.name(),
                args.width.unwrap_or(320),
                args.height.unwrap_or(240),
                args.seed,
                args.isos.clone().unwrap_or_else(|| vec![100, 200, 400, 800, 1600]),
                args.frames.unwrap_or(8),
                args.ev.clone().unwrap_or_else(|| (-4..=4).collect()),
            )?;
            if args.heldout {
                s = s.heldout(args.frames.unwrap_or(PRESET_HELDOUT_FRAMES))?;
            }
            if let Some(k) = args.ev_per_stop {
                s.plan = s.plan.clone().with_ev_steps_per_stop(k);
                s.plan.validate()?;
            }
            s
        }
        SensorChoice::Random(family_seed) => {
            let mut sensor = noisecal_sim::random_sensor(family_seed);
            if args.structured {
                sensor.model = sensor.model.with_structured_noise();
                sensor.description.push_str(&structured_text(&sensor.model));
            }
            if let Some(a) = args.flicker {
                sensor.model.flicker = Some(noisecal_sim::Flicker { probability: 0.1, amplitude: a });
            }
            let mut spec = noisecal_sim::random_session(family_seed, &sensor.model);
            if args.moving && !args.heldout {
                let flicker = sensor.model.flicker.clone();
                noisecal_sim::random_moving_scene(family_seed).apply(&mut sensor.model, &mut spec);
                if args.flicker.is_some() {
                    sensor.model.flicker = flicker;
                }
            }
            if args.heldout {
                let h = &mut spec.heldout;
                h.width = args.width.unwrap_or(h.width);
                h.height = args.height.unwrap_or(h.height);
                h.frames_per_burst = args.frames.unwrap_or(h.frames_per_burst);
                h.ev_steps = args.ev.clone().unwrap_or_else(|| h.ev_steps.clone());
            } else {
                spec.width = args.width.unwrap_or(spec.width);
                spec.height = args.height.unwrap_or(spec.height);
                spec.frames_per_burst = args.frames.unwrap_or(spec.frames_per_burst);
                spec.ev_steps = args.ev.clone().unwrap_or_else(|| spec.ev_steps.clone());
            }
            spec.target_isos = args.isos.clone().unwrap_or_else(|| spec.target_isos.clone());
            spec.ev_steps_per_stop = args.ev_per_stop.unwrap_or(spec.ev_steps_per_stop);
            if !quiet {
                eprintln!("sensor random:{family_seed}: {}", sensor.description);
                eprintln!("session: {}", spec.description);
            }
            SimSession::random(&sensor, &spec, args.seed, args.heldout)?
        }
    };
    s.index_offset += args.index_offset;
    s.dark_frames = args.dark;
    s.noise_profile = args.noise_profile;
    let pb = progress_bar(s.frames() as u64, quiet, "simulating");
    s.write(args.dngs.as_deref(), args.rec.as_deref(), args.padding, || pb.inc(1))?;
    pb.finish_and_clear();
    if !quiet {
        eprintln!("{} frames simulated ({}×{}, {})", s.frames(), s.sim.width(), s.sim.height(), s.model);
    }
    Ok(())
}

/// `--moving` on a sensor: the motion (and, unless `--flicker` set one, the flicker) of the
/// random family's moving scene drawn from `seed`.
fn move_scene(model: &mut noisecal_sim::SensorModel, seed: u64, keep_flicker: bool, quiet: bool) {
    let scene = noisecal_sim::random_moving_scene(seed);
    model.motion = Some(scene.motion.clone());
    if !keep_flicker {
        model.flicker = scene.flicker.clone();
    }
    if !quiet {
        eprintln!("--moving: {}", scene.describe());
    }
}

/// What `--structured` gave the sensor, for the printed description.
fn structured_text(m: &noisecal_sim::SensorModel) -> String {
    format!(
        "; --structured: row noise {} e + {} DN ({}), frame offsets {} e + {} DN per position ({}, {:.0} % shared), DSNU {} e + {} DN",
        m.row_noise_pre_e,
        m.row_noise_post_dn,
        m.row_noise_shape,
        m.frame_offset_pre_e,
        m.frame_offset_post_dn,
        m.frame_offset_shape,
        100.0 * m.frame_offset_shared,
        m.dsnu_pre_e,
        m.dsnu_post_dn
    )
}

/// `--bench DIR`: the denoiser benchmark's evaluation and training set.
fn bench_set(args: &Args, dir: &std::path::Path, quiet: bool) -> anyhow::Result<()> {
    let choice = args.sensor.unwrap_or(SensorChoice::Preset(args.preset));
    let (mut model, name, isos) = match choice {
        SensorChoice::Preset(p) => (p.model(), p.name().to_string(), vec![100, 200, 400, 800, 1600]),
        SensorChoice::Random(seed) => {
            let sensor = noisecal_sim::random_sensor(seed);
            let spec = noisecal_sim::random_session(seed, &sensor.model);
            if !quiet {
                eprintln!("sensor random:{seed}: {}", sensor.description);
            }
            (sensor.model.clone(), sensor.name(), spec.target_isos.clone())
        }
    };
    if args.structured {
        model = model.with_structured_noise();
        if !quiet {
            eprintln!("sensor {name}{}", structured_text(&model));
        }
    }
    if let Some(a) = args.flicker {
        model.flicker = Some(noisecal_sim::Flicker { probability: 0.1, amplitude: a });
    }
    if args.moving {
        let seed = match choice {
            SensorChoice::Random(family_seed) => family_seed,
            SensorChoice::Preset(_) => args.seed,
        };
        move_scene(&mut model, seed, args.flicker.is_some(), quiet);
    }
    let spec = crate::simulate::BenchSpec {
        width: args.width.unwrap_or(256),
        height: args.height.unwrap_or(256),
        isos: args.isos.clone().unwrap_or(isos),
        burst: args.frames.unwrap_or(16),
        scenes: args.scenes,
        train_scenes: args.train_scenes,
        train_frames: args.train_frames,
        seed: args.seed,
        noise_profile: args.noise_profile,
    };
    let total = spec.frames(model.motion.is_some());
    let pb = progress_bar(total as u64, quiet, "simulating");
    crate::simulate::write_bench_set(&model, &name, &spec, dir, || pb.inc(1))?;
    pb.finish_and_clear();
    if !quiet {
        eprintln!(
            "benchmark set written to {}: {} evaluation scenes (burst of {} at ISO {} + ISOs {:?}), {} training scenes ({} frames per ISO), {}×{}",
            dir.display(),
            spec.scenes,
            spec.burst,
            model.base_iso,
            spec.isos,
            spec.train_scenes,
            spec.train_frames,
            spec.width,
            spec.height
        );
    }
    Ok(())
}
