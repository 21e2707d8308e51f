//! `noisecal synth --pack pixel6.pack --iso 1600 --seed 7 clean.dng -o noisy.dng` (a folder in,
//! a folder out works too).

use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use ndarray::{Array2, ArrayView2};
use noisecal_core::SensorLayout;
use noisecal_core::model::pack::{IsoModel, NoiseProfile};
use noisecal_core::model::structure::Components;
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::sampler_up_to::SamplerUpTo;
use noisecal_core::synth::{CleanAt, DEFAULT_PATTERN_CACHE_BYTES, synthesize, synthesize_bands};

use noisecal_core::resolve::ModelKind;
use noisecal_input::dng;

use crate::models::{align_input, check_layout_matches, model_parser};
use crate::seeds::SeedBy;
use noisecal_input::files::{open_pack, resolve_pack};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model pack.
    #[arg(long)]
    pub pack: PathBuf,
    /// Target ISO; an ISO between calibrated ones is interpolated (said on stderr).
    #[arg(long)]
    pub iso: u32,
    /// Seed: the same inputs and seed give the same bytes on any thread count. In a folder, each
    /// file's seed is `seed_for(file name, seed)` (a keyed BLAKE2b of the name, as Python's
    /// `noisecal.seed_for`): a file keeps its noise when others are added or removed, and the
    /// same folder gets the same bytes from the Python package and its Ray actor.
    #[arg(long, default_value_t = 0)]
    pub seed: u64,
    /// How a folder's files are seeded: `name` (default, above) or `index` (the i-th file in
    /// sorted order gets seed + i, the rule before, and a batch of Python's `Pack.synth`).
    #[arg(long, value_enum, default_value_t = SeedBy::Name)]
    pub seed_by: SeedBy,
    /// Noise model: the calibrated non-parametric one, or a baseline for comparison.
    #[arg(long, value_parser = model_parser(), default_value = "noisecal")]
    pub model: ModelKind,
    /// Allow ISOs outside the calibrated range (extrapolated).
    #[arg(long)]
    pub extrapolate: bool,
    /// Noise components to add: pixel, row, column, frame, fpn (comma-separated; default: every
    /// component the pack calibrated). `pixel` alone is the pixel-independent model of version 2
    /// packs; the parametric baselines (`--model hg|pg|noiseprofile`) are always pixel-only.
    /// `fpn` is the sensor's fixed pattern from the dark step: for a clean image averaged from
    /// this sensor's own frames (a burst mean), which carries it already, pass `own` (every
    /// component but `fpn`, the same as `pixel,row,column,frame`).
    #[arg(long, value_parser = parse_components)]
    pub components: Option<Components>,
    /// The brightness the clean image is at. `reference` (default): the reference ISO's
    /// brightness for the same ISO × exposure, as the pack measured it (a clean image averaged
    /// from base-ISO frames); the output gets the target ISO's brightness, its gain ratio
    /// applied (`noisecal inspect` lists them). `target`: the clean image is already at the
    /// target ISO's brightness (averaged from frames at that ISO, or rendered to the output
    /// brightness); the noise then has no mean shift.
    #[arg(long, value_parser = parse_clean_at, default_value = "reference")]
    pub clean_at: CleanAt,
    /// Memory (MiB) for the fixed pattern kept between the files of a folder: the pattern is the
    /// sensor's, so files of one size reuse it instead of computing it pixel by pixel again. 0
    /// keeps nothing. The images are the same whatever the setting; only time and memory change.
    #[arg(long, default_value_t = DEFAULT_PATTERN_CACHE_BYTES >> 20, value_name = "MB")]
    pub pattern_cache_mb: usize,
    /// A clean raw DNG, or a folder of them.
    pub input: PathBuf,
    /// Output DNG, or a folder when the input is a folder.
    #[arg(short, long)]
    pub output: PathBuf,
}

fn parse_components(s: &str) -> Result<Components, String> {
    Components::parse(s)
}

fn parse_clean_at(s: &str) -> Result<CleanAt, String> {
    CleanAt::parse(s).map_err(|e| format!("{e} (--clean-at reference|target)"))
}

pub fn run(args: Args, quiet: bool) -> anyhow::Result<()> {
    noisecal_input::files::refuse_overwriting_inputs(&args.output, &[&args.input, &args.pack])?;
    let folder = args.input.is_dir();
    std::thread::scope(|scope| {
        // A single input is read while the pack loads.
        let prefetch = (!folder).then(|| scope.spawn(|| dng::read_dng_source(&args.input)));
        // Only the ISOs the model stands on are decoded (the pack file is mapped, not copied).
        let which = args.model.components(args.components);
        let lazy = open_pack(&args.pack)?;
        let (pack, resolved) = resolve_pack(&lazy, &args.pack, args.iso, args.model, which, args.extrapolate)?;
        if let Some(n) = crate::models::note(&resolved)
            && !quiet
        {
            eprintln!("{n}");
        }
        // A single image is read before the build: the sampler then builds only the tables its
        // levels reach ([`SamplerUpTo`], which draws no other level). A folder's images take them all.
        let prefetched = prefetch.map(|h| {
            h.join().unwrap_or_else(|_| {
                Err(dng::DngError::Io {
                    path: args.input.clone(),
                    source: std::io::Error::other("the reading thread panicked"),
                })
            })
        });
        let top = match &prefetched {
            Some(Ok(f)) if f.image.layout.align_to(&pack.layout).is_identity() => highest_level(f.pixels()),
            _ => None,
        };
        let sampler = match top {
            Some(top) => {
                RunSampler::UpTo(resolved.sampler_up_to(&pack, which, args.clean_at, args.extrapolate, top)?)
            }
            None => RunSampler::Full(resolved.sampler(&pack, which, args.clean_at, args.extrapolate)?),
        };
        sampler.set_pattern_cache_bytes(args.pattern_cache_mb.saturating_mul(1 << 20));
        let model = resolved.model;
        if args.clean_at == CleanAt::Target
            && !quiet
            && let Some(g) = sampler.target_gains()
            && g.iter().any(|g| (g - 1.0).abs() > 0.02)
        {
            eprintln!(
                "clean image at ISO {}'s brightness (--clean-at target): levels above black divided by the gain ratios {:.3?} to pick their noise",
                args.iso, g
            );
        }
        let jobs: Vec<(PathBuf, PathBuf)> = if folder {
            let files = dng::scan_folder(&args.input)?;
            if files.is_empty() {
                bail!("{} holds no .dng files", args.input.display());
            }
            std::fs::create_dir_all(&args.output)
                .with_context(|| format!("cannot create {}", args.output.display()))?;
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
        let job =
            Job { pack: &pack, sampler: &sampler, model: &model, iso: args.iso, quiet, profiles: Default::default() };
        // Three stages overlap: reading file i + 1, sampling file i, writing file i − 1.
        let (read_tx, read_rx) = std::sync::mpsc::sync_channel::<anyhow::Result<dng::DngFile>>(1);
        let (write_tx, write_rx) = std::sync::mpsc::sync_channel::<Written>(1);
        let reader_jobs = jobs.clone();
        scope.spawn(move || {
            let mut prefetched = prefetched;
            for (input, output) in &reader_jobs {
                let file = match prefetched.take() {
                    Some(f) => f,
                    None => dng::read_dng_source(input),
                };
                let file = file.map_err(anyhow::Error::from).and_then(|f| {
                    if noisecal_io::same_file(input, output) {
                        bail!(
                            "{} is also an input ({}): write to another path; noisecal never writes over what it reads",
                            output.display(),
                            input.display()
                        );
                    }
                    Ok(f)
                });
                if read_tx.send(file).is_err() {
                    break;
                }
            }
        });
        let iso = args.iso;
        let writer = scope.spawn(move || -> (usize, Option<anyhow::Error>) {
            let mut written = 0;
            for w in write_rx {
                let done = match w.out {
                    Output::Pixels { file, noisy, profile } => {
                        dng::write_derived_owned(&w.output, file, &noisy, iso, profile.as_ref())
                    }
                    Output::Streamed(file) => file.commit().map_err(|e| dng::DngError::io(&w.output, e)),
                };
                if let Err(e) = done {
                    return (written, Some(e.into()));
                }
                written += 1;
                if !quiet {
                    eprintln!("{} → {} (ISO {iso}, seed {})", w.input.display(), w.output.display(), w.seed);
                }
            }
            (written, None)
        });
        let mut failed: Option<(usize, anyhow::Error)> = None;
        for (i, ((input, output), file)) in jobs.iter().zip(read_rx).enumerate() {
            // Each file gets its own seed stream (crate::seeds): a folder run equals single-file runs
            // with `--seed seed_for(file name, seed)`, and Python's and Ray's runs of the folder.
            let seed = if folder { args.seed_by.seed(args.seed, i, input) } else { args.seed };
            match file.and_then(|f| job.sample(input, output, f, seed)) {
                Ok(out) => {
                    let w = Written { input: input.clone(), output: output.clone(), seed, out };
                    if write_tx.send(w).is_err() {
                        break;
                    }
                }
                Err(e) => {
                    failed = Some((i, e));
                    break;
                }
            }
        }
        drop(write_tx);
        let (written, write_error) =
            writer.join().unwrap_or_else(|_| (0, Some(anyhow::anyhow!("the writing thread panicked"))));
        // The first failure in file order: a write fails only for files sampled before.
        let failed = match write_error {
            Some(e) => Some((written, e)),
            None => failed,
        };
        let Some((i, e)) = failed else { return Ok(()) };
        if !folder {
            return Err(e);
        }
        let kept = match i {
            0 => "no output was written".to_string(),
            1 => format!("the 1 output written before it is kept in {}", args.output.display()),
            n => format!("the {n} outputs written before it are kept in {}", args.output.display()),
        };
        Err(e.context(format!(
            "{} failed (file {} of {} in {}); {kept}; fix or remove it and run again",
            jobs[i].0.display(),
            i + 1,
            jobs.len(),
            args.input.display()
        )))
    })
}

/// The highest level of an image (`None` for an empty one).
fn highest_level(pixels: ndarray::ArrayView2<'_, u16>) -> Option<u16> {
    match pixels.as_slice() {
        Some(s) => s.iter().copied().max(),
        None => pixels.rows().into_iter().filter_map(|r| r.iter().copied().max()).max(),
    }
}

/// The sampler of a run: of every level (a folder, or an image the full build serves), or built
/// for the single image's levels, which draws no image with a higher one.
enum RunSampler {
    Full(IsoSampler),
    UpTo(SamplerUpTo),
}

impl RunSampler {
    /// The gain ratios clean levels are divided by (clean images at the target brightness).
    fn target_gains(&self) -> Option<[f64; noisecal_core::POSITIONS]> {
        match self {
            RunSampler::Full(s) => s.target_gains(),
            RunSampler::UpTo(s) => s.target_gains(),
        }
    }

    fn set_pattern_cache_bytes(&self, bytes: usize) {
        match self {
            RunSampler::Full(s) => s.set_pattern_cache_bytes(bytes),
            RunSampler::UpTo(s) => s.set_pattern_cache_bytes(bytes),
        }
    }

    /// [`synthesize`] of a whole image.
    fn synthesize(&self, clean: ArrayView2<'_, u16>, seed: u64) -> anyhow::Result<Array2<u16>> {
        match self {
            RunSampler::Full(s) => Ok(synthesize(s, clean, seed)),
            RunSampler::UpTo(s) => Ok(s.synthesize_at(clean, seed, (0, 0))?),
        }
    }

    /// [`synthesize_bands`] of a whole image.
    fn synthesize_bands(
        &self,
        clean: ArrayView2<'_, u16>,
        seed: u64,
        sink: impl Fn(usize, &[u16]) + Sync,
    ) -> anyhow::Result<()> {
        match self {
            RunSampler::Full(s) => {
                synthesize_bands(s, clean, seed, (0, 0), sink);
                Ok(())
            }
            RunSampler::UpTo(s) => Ok(s.synthesize_bands(clean, seed, (0, 0), sink)?),
        }
    }
}

/// A sampled file on its way to the writer.
struct Written {
    input: PathBuf,
    output: PathBuf,
    seed: u64,
    out: Output,
}

/// What the writer finishes (one per file: the size of the variants does not matter).
#[allow(clippy::large_enum_variant)]
enum Output {
    /// The noisy pixels, to write into a DNG derived from the file.
    Pixels { file: dng::DngFile, noisy: Array2<u16>, profile: Option<NoiseProfile> },
    /// The derived DNG, written while it was drawn ([`dng::DerivedStream`]), to commit.
    Streamed(noisecal_io::AtomicFile),
}

/// What every file of a run shares.
struct Job<'a> {
    pack: &'a noisecal_core::ModelPack,
    sampler: &'a RunSampler,
    model: &'a IsoModel,
    /// The ISO the outputs are written with.
    iso: u32,
    quiet: bool,
    /// The NoiseProfile per image layout met so far (a folder's images share one, usually).
    profiles: std::sync::Mutex<Vec<(SensorLayout, Option<NoiseProfile>)>>,
}

impl Job<'_> {
    /// The noisy pixels of a read file and the NoiseProfile its DNG gets, or, for a file whose
    /// raw image is stored as uncompressed 16-bit strips, its derived DNG written (uncommitted)
    /// while the pixels are drawn.
    fn sample(&self, input: &Path, output: &Path, file: dng::DngFile, seed: u64) -> anyhow::Result<Output> {
        let pack = self.pack;
        let layout = file.image.layout.clone();
        check_layout_matches(pack, &layout, input)?;
        // The model is binned by level above the pack's black level: an image with another black level
        // is shifted onto the pack's, synthesized, and shifted back.
        let align = align_input(pack, &layout, input, self.quiet);
        if align.is_identity()
            && let Some(stream) = file.streamed()
        {
            // The NoiseProfile fit is single-threaded: it runs next to the sampling.
            let mut drawn = Ok(());
            let out = stream.write(output, self.iso, |sink| {
                let draw = || self.sampler.synthesize_bands(file.pixels(), seed, sink);
                let profile;
                (drawn, profile) = rayon::join(draw, || self.profile(&layout));
                profile
            });
            // A refused image is the error, not the incomplete file it left (removed unwritten).
            drawn.with_context(|| format!("{}", input.display()))?;
            return Ok(Output::Streamed(out?));
        }
        let clean = file.pixels();
        // The NoiseProfile fit is single-threaded: it runs next to the sampling, not after it.
        let (noisy, profile) = rayon::join(
            || align.try_around(clean, pack.layout.white, (0, 0), |c| self.sampler.synthesize(c, seed)),
            || self.profile(&layout),
        );
        let noisy = noisy.with_context(|| format!("{}", input.display()))?;
        Ok(Output::Pixels { file, noisy, profile })
    }

    /// The NoiseProfile of the images with `layout` (fitted once per layout).
    fn profile(&self, layout: &SensorLayout) -> Option<NoiseProfile> {
        let known =
            |p: &Vec<(SensorLayout, Option<NoiseProfile>)>| p.iter().find(|(l, _)| l == layout).map(|(_, n)| *n);
        if let Some(n) = self.profiles.lock().ok().and_then(|p| known(&p)) {
            return n;
        }
        let n = dng::fitted_noise_profile(self.pack, self.model, layout);
        if let Ok(mut p) = self.profiles.lock() {
            p.push((layout.clone(), n));
        }
        n
    }
}
