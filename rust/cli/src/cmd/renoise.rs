//! `noisecal renoise --pack p.pack --to-iso 3200 in_iso1600.dng -o out_iso3200.dng`: turn real
//! captures at one ISO into realistic captures of the same scene at a higher ISO (noise on noise,
//! paper §4.2). A folder in gives a folder out (same file names). The source ISO comes from each
//! input's metadata unless `--from-iso` says otherwise.

use std::collections::BTreeMap;
use std::collections::btree_map::Entry;
use std::path::{Path, PathBuf};

use anyhow::{Context, bail};
use ndarray::Array2;
use noisecal_core::renoise::{Method, Renoiser};
use noisecal_core::{BlackAlignment, ModelPack, position};

use noisecal_core::resolve::ModelKind;
use noisecal_input::dng;

use crate::models::{align_input, check_layout_matches};
use crate::seeds::SeedBy;
use noisecal_core::format::lazy_pack::LazyPack;
use noisecal_core::model::structure::Components;
use noisecal_core::resolve::Resolved;
use noisecal_input::files::{open_pack, resolve_pack};

#[derive(clap::Args, Debug)]
pub struct Args {
    /// The model pack.
    #[arg(long)]
    pub pack: PathBuf,
    /// Target ISO (higher than the source ISO); between calibrated ISOs it is interpolated.
    #[arg(long = "to-iso")]
    pub to_iso: u32,
    /// Source ISO of the inputs (default: each input's own ISO metadata).
    #[arg(long = "from-iso")]
    pub from_iso: Option<u32>,
    /// Your own clean estimate of the input, as a raw DNG of the same size (a folder of DNGs with
    /// the same file names when the input is a folder). Default: the built-in denoiser.
    #[arg(long)]
    pub estimate: Option<PathBuf>,
    /// bridge (noise on noise, the default), quantile (the input's own noise mapped onto the
    /// target PMF), denoised (estimate + target noise) or naive (input + target noise).
    #[arg(long, default_value = "bridge", value_parser = parse_method)]
    pub method: Method,
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
    /// Allow ISOs outside the calibrated range (extrapolated).
    #[arg(long)]
    pub extrapolate: bool,
    /// A raw DNG captured at the source ISO, or a folder of them.
    pub input: PathBuf,
    /// Output DNG, or a folder when the input is a folder.
    #[arg(short, long)]
    pub output: PathBuf,
}

fn parse_method(s: &str) -> Result<Method, String> {
    s.parse()
}

/// One file to renoise.
struct Job {
    input: PathBuf,
    estimate: Option<PathBuf>,
    output: PathBuf,
}

pub fn run(args: Args, quiet: bool) -> anyhow::Result<()> {
    let mut inputs: Vec<&Path> = vec![&args.input, &args.pack];
    if let Some(e) = &args.estimate {
        inputs.push(e);
    }
    noisecal_input::files::refuse_overwriting_inputs(&args.output, &inputs)?;
    // Only the ISOs the source and target models stand on are decoded; `pack` is the pack's
    // fields (sensor layout, bins) without its ISOs, all the rest of the run needs.
    let lazy = open_pack(&args.pack)?;
    let pack = lazy.index().empty_pack();
    let jobs = plan_jobs(&args)?;
    let mut renoisers: BTreeMap<u32, Renoiser> = BTreeMap::new();
    let mut target_note_shown = false;
    let mut target_model: Option<noisecal_core::model::pack::IsoModel> = None;
    let folder = args.input.is_dir();
    for (i, job) in jobs.iter().enumerate() {
        let seed = if folder { args.seed_by.seed(args.seed, i, &job.input) } else { args.seed };
        let file = dng::read_dng_file(&job.input)?;
        let img = &file.image;
        check_layout_matches(&pack, &img.layout, &job.input)?;
        // Levels are taken above black: an input with another black level is shifted onto the
        // pack's, re-noised, and shifted back.
        let align = align_input(&pack, &img.layout, &job.input, quiet);
        let from = args.from_iso.unwrap_or(img.meta.iso);
        if args.from_iso.is_some() && img.meta.iso != from && !quiet {
            eprintln!(
                "noisecal: warning: {} says ISO {} but --from-iso {from} is used",
                job.input.display(),
                img.meta.iso
            );
        }
        let renoiser = match renoisers.entry(from) {
            Entry::Occupied(e) => e.into_mut(),
            Entry::Vacant(e) => {
                let r = prepare(&lazy, &pack, from, &args, quiet, !target_note_shown)?;
                target_note_shown = true;
                e.insert(r)
            }
        };
        let estimate = match &job.estimate {
            Some(p) => Some(read_estimate(p, img.pixels.dim(), &align)?),
            None => None,
        };
        let mut warnings = Vec::new();
        let noisy = align
            .try_around(img.pixels.view(), pack.layout.white, (0, 0), |input| {
                let out = renoiser.apply(input, estimate.as_ref().map(|e| e.view()), seed)?;
                warnings = out.warnings;
                Ok::<_, noisecal_core::renoise::RenoiseError>(out.image)
            })
            .with_context(|| format!("cannot renoise {}", job.input.display()))?;
        if !quiet {
            for w in warnings.iter().filter(|w| !renoiser.warnings().contains(w)) {
                eprintln!("noisecal: warning: {}: {w}", job.input.display());
            }
        }
        // The written NoiseProfile is the target model's fit (resolved once, after `prepare` checked the ISOs).
        let target = match &target_model {
            Some(m) => m,
            None => target_model.insert(resolve(&lazy, &args, args.to_iso)?.model),
        };
        let profile = dng::fitted_noise_profile(&pack, target, &img.layout);
        dng::write_derived(&job.output, &file, &noisy, args.to_iso, profile.as_ref())?;
        if !quiet {
            eprintln!(
                "{} → {} (ISO {from} → {}, {}, seed {seed}{})",
                job.input.display(),
                job.output.display(),
                args.to_iso,
                args.method,
                if job.estimate.is_some() { ", your estimate" } else { "" }
            );
        }
    }
    Ok(())
}

/// Input/estimate/output paths, checked before any work is done.
fn plan_jobs(args: &Args) -> anyhow::Result<Vec<Job>> {
    if !args.input.exists() {
        bail!("{} does not exist: give a raw DNG or a folder of them", args.input.display());
    }
    if args.input.is_dir() {
        let files = dng::scan_folder(&args.input)?;
        if files.is_empty() {
            bail!("{} holds no .dng files", args.input.display());
        }
        if args.output.exists() && !args.output.is_dir() {
            bail!(
                "the input {} is a folder, so the output {} must be a folder too",
                args.input.display(),
                args.output.display()
            );
        }
        if same_path(&args.input, &args.output) {
            bail!(
                "the output folder {} is the input folder: pick another one so the captures are kept",
                args.output.display()
            );
        }
        if let Some(e) = &args.estimate
            && !e.is_dir()
        {
            bail!(
                "the input {} is a folder, so --estimate must be a folder of DNGs with the same file names ({} is not)",
                args.input.display(),
                e.display()
            );
        }
        std::fs::create_dir_all(&args.output).with_context(|| format!("cannot create {}", args.output.display()))?;
        files
            .into_iter()
            .map(|f| {
                let name = f.file_name().map(|n| n.to_owned()).unwrap_or_default();
                let estimate = match &args.estimate {
                    Some(dir) => {
                        let p = dir.join(&name);
                        if !p.is_file() {
                            bail!(
                                "{} has no clean estimate {} in {}",
                                f.display(),
                                Path::new(&name).display(),
                                dir.display()
                            );
                        }
                        Some(p)
                    }
                    None => None,
                };
                Ok(Job { output: args.output.join(&name), input: f, estimate })
            })
            .collect()
    } else {
        let output = if args.output.is_dir() {
            args.output.join(args.input.file_name().unwrap_or_default())
        } else {
            args.output.clone()
        };
        if same_path(&args.input, &output) {
            bail!("the output {} is the input: pick another name so the capture is kept", output.display());
        }
        if let Some(e) = &args.estimate
            && !e.is_file()
        {
            bail!(
                "--estimate {} is not a file: give the clean estimate of {} as a raw DNG",
                e.display(),
                args.input.display()
            );
        }
        Ok(vec![Job { input: args.input.clone(), estimate: args.estimate.clone(), output }])
    }
}

fn same_path(a: &Path, b: &Path) -> bool {
    noisecal_io::same_file(a, b)
}

/// The non-parametric model of `iso` (pixel noise: re-noising adds no structured components),
/// decoding only the ISOs it stands on.
fn resolve(lazy: &LazyPack<Vec<u8>>, args: &Args, iso: u32) -> anyhow::Result<Resolved> {
    Ok(resolve_pack(lazy, &args.pack, iso, ModelKind::Noisecal, Components::PIXEL, args.extrapolate)?.1)
}

/// Models and bridge for `from → to`, with their notes and flags on stderr. `pack` holds the
/// pack's fields (its ISOs are read from `lazy`).
fn prepare(
    lazy: &LazyPack<Vec<u8>>,
    pack: &ModelPack,
    from: u32,
    args: &Args,
    quiet: bool,
    show_target_note: bool,
) -> anyhow::Result<Renoiser> {
    let to = args.to_iso;
    if to <= from {
        bail!(
            "cannot renoise ISO {from} captures to ISO {to}: noise on noise only adds noise, so --to-iso must be above the source ISO {from}"
        );
    }
    let source = resolve(lazy, args, from).with_context(|| format!("no model for the source ISO {from}"))?;
    let target = resolve(lazy, args, to).with_context(|| format!("no model for the target ISO {to}"))?;
    let (source_note, target_note) = (crate::models::note(&source), crate::models::note(&target));
    let renoiser = Renoiser::new(pack, &source.model, &target.model, args.method)?;
    if !quiet {
        if let Some(n) = source_note {
            eprintln!("noisecal: {n}");
        }
        if show_target_note && let Some(n) = target_note {
            eprintln!("noisecal: {n}");
        }
        match renoiser.bridge() {
            Some(b) if b.flags.is_empty() => eprintln!(
                "noisecal: bridge ISO {from} → {to}: all bins fit (mean total variation {:.4}, worst {:.4})",
                b.mean_residual(),
                b.max_residual()
            ),
            Some(b) => eprintln!(
                "noisecal: bridge ISO {from} → {to}: {} of {} bins flagged (mean total variation {:.4}, worst {:.4})",
                b.flags.len(),
                b.bins.iter().map(Vec::len).sum::<usize>(),
                b.mean_residual(),
                b.max_residual()
            ),
            None => {}
        }
        for w in renoiser.warnings() {
            eprintln!("noisecal: warning: {w}");
        }
    }
    Ok(renoiser)
}

/// A clean estimate DNG as levels in DN on the pack's black level (`align`, the input's),
/// checked against the input's size.
fn read_estimate(path: &Path, dim: (usize, usize), align: &BlackAlignment) -> anyhow::Result<Array2<f32>> {
    let e = dng::read_dng(path).with_context(|| format!("cannot read the clean estimate {}", path.display()))?;
    if e.pixels.dim() != dim {
        bail!(
            "the clean estimate {} is {}×{} but the input is {}×{}: give an estimate of the same capture (same crop)",
            path.display(),
            e.pixels.ncols(),
            e.pixels.nrows(),
            dim.1,
            dim.0
        );
    }
    Ok(Array2::from_shape_fn(dim, |(y, x)| e.pixels[(y, x)] as f32 + align.shift[position(y, x)] as f32))
}
