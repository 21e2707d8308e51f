//! `noisecal demo --out demo/`: a simulated phone session written as DNGs, calibrated from that
//! folder, then real vs synthetic noise on held-out captures, per ISO. A held-out set of the same
//! sensor is written beside the pack (`demo/heldout/`, laid out as `noisecal eval` reads it), so
//! the demo pack can be scored and reported on like any other.

use std::io::Write;
use std::path::PathBuf;

use anyhow::Context;
use ndarray::Array2;
use noisecal_core::metrics::{Floor, NoiseSamples, compare};
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::synthesize;
use noisecal_core::{FrameView, ModelPack, POSITIONS};
use noisecal_sim::SensorModel;

use crate::simulate::{PRESET_HELDOUT_FRAMES, SimSession};
use crate::support::progress_bar;
use noisecal_core::resolve::{ModelKind, resolve_model};
use noisecal_core::synth::CleanAt;
use noisecal_input::calibrate::CalibrateOptions;
use noisecal_input::clean::CleanImages;
use noisecal_input::files::write_atomic;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// Folder for the captures, the pack, the held-out set (heldout/) and the example images.
    #[arg(long, default_value = "demo")]
    pub out: PathBuf,
    /// Image width of the simulated sensor.
    #[arg(long, default_value_t = 384, value_parser = clap::value_parser!(u32).range(crate::cmd::bounds::SIDE))]
    pub width: u32,
    #[arg(long, default_value_t = 288, value_parser = clap::value_parser!(u32).range(crate::cmd::bounds::SIDE))]
    pub height: u32,
    /// Frames per burst.
    #[arg(long, default_value_t = 10, value_parser = clap::value_parser!(u32).range(crate::cmd::bounds::FRAMES))]
    pub frames: u32,
    #[arg(long, default_value_t = 1)]
    pub seed: u64,
}

const ISOS: [u32; 6] = [100, 200, 400, 800, 1600, 3200];
const HELDOUT_BASE: u64 = 1 << 40;

pub fn run(args: Args, quiet: bool) -> anyhow::Result<()> {
    let model = SensorModel::phone_10bit();
    let session = SimSession::new(
        model,
        "simulated phone 10-bit",
        args.width,
        args.height,
        args.seed,
        ISOS.to_vec(),
        args.frames,
        (-4..=4).collect(),
    )?;
    let captures = args.out.join("captures");
    write_fresh(&session, &captures, quiet)?;
    // The same sensor and chart with fresh noise, fewer frames: what `noisecal eval` scores on
    // (the same frames as `noisecal simulate --preset phone10 --heldout` with the demo's size,
    // ISOs and seed).
    let heldout = args.out.join("heldout");
    write_fresh(&session.clone().heldout(PRESET_HELDOUT_FRAMES)?, &heldout, quiet)?;

    let (pack, report) = crate::support::calibrate(&captures, &CalibrateOptions::default(), quiet)?;
    let pack_path = args.out.join("demo.pack");
    write_atomic(&pack_path, &pack.to_bytes()?)?;
    if !quiet {
        eprintln!("calibrated {} frames → {} (ISOs {})", report.frames, pack_path.display(), pack.iso_summary());
    }

    // Held-out captures at EV 0: a reference burst for the clean image, then a few frames per ISO.
    let sim = &session.sim;
    let plan = &session.plan;
    let layout = sim.layout();
    let ref_exp = plan.exposure_ns(0, plan.reference_iso);
    let mut burst = CleanImages::new(&layout, plan.reference_iso, pack.bin_width)?.burst(ref_exp)?;
    for k in 0..16 {
        let (px, meta) = sim.capture(plan.reference_iso, ref_exp, HELDOUT_BASE + k)?;
        burst.push(&FrameView::from_array(&px)?, &meta)?;
    }
    let (clean, mask) = burst.close()?.to_arrays();
    let (h, w) = (layout.height as usize, layout.width as usize);
    let clean_f = clean.mapv(|c| c as f32);

    let mut stdout = std::io::stdout().lock();
    writeln!(stdout)?;
    writeln!(stdout, "Real vs synthetic noise on held-out captures ({}×{}, EV 0, flat pixels):", w, h)?;
    writeln!(
        stdout,
        "{:>6} {:>11} {:>11} {:>8} {:>13} {:>13} {:>13}",
        "ISO", "real var", "synth var", "ratio", "JSD noisecal", "JSD HG", "JSD floor"
    )?;
    let binning = pack.binning();
    for (i, &iso) in ISOS.iter().enumerate() {
        let exp = plan.exposure_ns(0, iso);
        let frames = 4u64;
        let mut real_a = NoiseSamples::new(&binning, 8);
        let mut real_b = NoiseSamples::new(&binning, 8);
        let mut syn = NoiseSamples::new(&binning, 8);
        let mut hg = NoiseSamples::new(&binning, 8);
        let m_nc = resolve_model(&pack, iso, ModelKind::Noisecal, false)?.model;
        let s_nc = IsoSampler::new(&pack, &m_nc);
        // HG as `synth --model hg` draws it: the law at each clean level (the clean image is at
        // the reference brightness).
        let s_hg = resolve_model(&pack, iso, ModelKind::Hg, false)?.sampler(
            &pack,
            noisecal_core::model::structure::Components::PIXEL,
            CleanAt::Reference,
            false,
        )?;
        for k in 0..frames {
            let (px, _) = sim.capture(iso, exp, HELDOUT_BASE + 1000 * (i as u64 + 1) + k)?;
            if k % 2 == 1 {
                real_b.add_frame(clean_f.view(), px.view(), Some(mask.view()))?;
                continue;
            }
            real_a.add_frame(clean_f.view(), px.view(), Some(mask.view()))?;
            syn.add_frame(clean_f.view(), synthesize(&s_nc, clean.view(), 1000 + k).view(), Some(mask.view()))?;
            hg.add_frame(clean_f.view(), synthesize(&s_hg, clean.view(), 2000 + k).view(), Some(mask.view()))?;
        }
        let (rv, sv) = (pooled_variance(&real_a), pooled_variance(&syn));
        let s = compare(&real_a, &syn);
        let s_hg = compare(&real_a, &hg);
        // Two real sets of the size compared: the floor's scale is 1.
        let compared = (0..POSITIONS).map(|p| real_a.total(p)).sum();
        let floor = Floor::measure(&real_a, &real_b, compared)
            .map_or((0.0, 0.0), |f| (f.marginal_scaled(), f.conditional_scaled()));
        writeln!(
            stdout,
            "{iso:>6} {:>11.2} {:>11.2} {:>8.3} {:>6.4}/{:<6.4} {:>6.4}/{:<6.4} {:>6.4}/{:<6.4}",
            rv,
            sv,
            sv / rv,
            s.marginal_overall,
            s.conditional_overall,
            s_hg.marginal_overall,
            s_hg.conditional_overall,
            floor.0,
            floor.1
        )?;
    }
    writeln!(stdout, "(JSD marginal/conditional, natural log; floor = two independent real sets of the same size)")?;

    // Example images a user can open: the clean EV 0 image and ISO 1600 synthesized on it.
    let m = resolve_model(&pack, 1600, ModelKind::Noisecal, false)?.model;
    let noisy = synthesize(&IsoSampler::new(&pack, &m), clean.view(), args.seed);
    write_example(&args.out, &pack, &clean, &noisy)?;
    if !quiet {
        eprintln!("example images: {0}/clean_ev0.dng, {0}/synth_iso1600.dng", args.out.display());
        eprintln!(
            "every score, the structured components against the pixel noise alone included: noisecal eval --pack {} {}",
            pack_path.display(),
            heldout.display()
        );
    }
    Ok(())
}

/// Writes `session`'s DNGs into `dir`, emptied first (a folder of an earlier run would mix in).
fn write_fresh(session: &SimSession, dir: &std::path::Path, quiet: bool) -> anyhow::Result<()> {
    if dir.exists() {
        std::fs::remove_dir_all(dir).with_context(|| format!("cannot clear {}", dir.display()))?;
    }
    let pb = progress_bar(session.plan.len() as u64, quiet, "simulating");
    session.write(Some(dir), None, 0, || pb.inc(1))?;
    pb.finish_and_clear();
    if !quiet {
        eprintln!("wrote {} DNGs to {}", session.plan.len(), dir.display());
    }
    Ok(())
}

fn write_example(
    out: &std::path::Path,
    pack: &ModelPack,
    clean: &Array2<u16>,
    noisy: &Array2<u16>,
) -> anyhow::Result<()> {
    let meta = noisecal_core::FrameMeta::new(pack.reference_iso, 10_000_000);
    noisecal_input::dng::write_dng_from_layout(
        &out.join("clean_ev0.dng"),
        &pack.layout,
        &meta,
        &pack.make,
        &pack.model,
        clean,
    )?;
    let meta = noisecal_core::FrameMeta::new(1600, 10_000_000 * pack.reference_iso as u64 / 1600);
    noisecal_input::dng::write_dng_from_layout(
        &out.join("synth_iso1600.dng"),
        &pack.layout,
        &meta,
        &pack.make,
        &pack.model,
        noisy,
    )?;
    Ok(())
}

/// Variance of the noise samples of all CFA positions together.
fn pooled_variance(s: &NoiseSamples) -> f64 {
    let mut h = noisecal_core::model::histogram::NoiseHistogram::default();
    for pos in 0..POSITIONS {
        h.merge(&s.marginal(pos));
    }
    h.moments().1
}
