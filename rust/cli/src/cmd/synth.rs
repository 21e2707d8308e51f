//! `noisecal synth --pack pixel6.pack --iso 1600 --seed 7 clean.dng -o noisy.dng` (a folder in,
//! a folder out works too).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use noisecal_core::model::pack::IsoModel;
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::synthesize;

use crate::dng;
use crate::models::{ModelKind, align_input, check_layout_matches, resolve_model};
use crate::support::load_pack;

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model pack.
    #[arg(long)]
    pub pack: PathBuf,
    /// Target ISO; an ISO between calibrated ones is interpolated (said on stderr).
    #[arg(long)]
    pub iso: u32,
    /// Seed: the same inputs and seed give the same bytes on any thread count.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// Noise model: the calibrated non-parametric one, or a baseline for comparison.
    #[arg(long, value_enum, default_value_t = ModelKind::Noisecal)]
    pub model: ModelKind,
    /// Allow ISOs outside the calibrated range (extrapolated).
    #[arg(long)]
    pub extrapolate: bool,
    /// A clean raw DNG, or a folder of them.
    pub input: PathBuf,
    /// Output DNG, or a folder when the input is a folder.
    #[arg(short, long)]
    pub output: PathBuf,
}

pub fn run(args: Args, quiet: bool) -> anyhow::Result<()> {
    crate::support::refuse_overwriting_inputs(&args.output, &[&args.input, &args.pack])?;
    let pack = load_pack(&args.pack)?;
    let (model, note) = resolve_model(&pack, args.iso, args.model, args.extrapolate)?;
    if let Some(n) = note {
        eprintln!("{n}");
    }
    let sampler = IsoSampler::new(&pack, &model);
    let folder = args.input.is_dir();
    let jobs: Vec<(PathBuf, PathBuf)> = if folder {
        let files = dng::scan_folder(&args.input)?;
        if files.is_empty() {
            bail!("{} holds no .dng files", args.input.display());
        }
        std::fs::create_dir_all(&args.output).with_context(|| format!("cannot create {}", args.output.display()))?;
        files
            .into_iter()
            .map(|f| {
                let name = f.file_name().map(|n| n.to_owned()).unwrap_or_default();
                let out = args.output.join(name);
                (f, out)
            })
            .collect()
    } else {
        vec![(args.input.clone(), args.output.clone())]
    };
    let job = Job { pack: &pack, sampler: &sampler, model: &model, iso: args.iso, quiet };
    for (i, (input, output)) in jobs.iter().enumerate() {
        // Each file gets its own seed stream so a folder run equals single-file runs with seed + index.
        let seed = args.seed.wrapping_add(i as u64);
        let done = job.file(input, output, seed);
        if let Err(e) = done {
            if !folder {
                return Err(e);
            }
            let kept = match i {
                0 => "no output was written".to_string(),
                1 => format!("the 1 output written before it is kept in {}", args.output.display()),
                n => format!("the {n} outputs written before it are kept in {}", args.output.display()),
            };
            return Err(e.context(format!(
                "{} failed (file {} of {} in {}); {kept}; fix or remove it and run again",
                input.display(),
                i + 1,
                jobs.len(),
                args.input.display()
            )));
        }
        if !quiet {
            eprintln!("{} → {} (ISO {}, seed {seed})", input.display(), output.display(), args.iso);
        }
    }
    Ok(())
}

/// What every file of a run shares.
struct Job<'a> {
    pack: &'a noisecal_core::ModelPack,
    sampler: &'a IsoSampler,
    model: &'a IsoModel,
    iso: u32,
    quiet: bool,
}

impl Job<'_> {
    fn file(&self, input: &Path, output: &Path, seed: u64) -> anyhow::Result<()> {
        let pack = self.pack;
        if noisecal_io::same_file(input, output) {
            bail!(
                "{} is also an input ({}): write to another path; noisecal never writes over what it reads",
                output.display(),
                input.display()
            );
        }
        let file = dng::read_dng_file(input)?;
        let img = &file.image;
        check_layout_matches(pack, &img.layout, input)?;
        // The model is binned by level above the pack's black level: an image with another black level
        // is shifted onto the pack's, synthesized, and shifted back.
        let align = align_input(pack, &img.layout, input, self.quiet);
        let noisy = if align.is_identity() {
            synthesize(self.sampler, img.pixels.view(), seed)
        } else {
            let moved = align.apply(img.pixels.view(), pack.layout.white);
            align.undo(synthesize(self.sampler, moved.view(), seed).view(), img.layout.white)
        };
        let profile = dng::fitted_noise_profile(pack, self.model, &img.layout);
        dng::write_derived(output, &file, &noisy, self.iso, profile.as_ref())?;
        Ok(())
    }
}
