//! The files every front-end reads and writes: a pack file read (whole, or on demand) with a
//! message that names it, and
//! output files written so that nothing already written is lost (an output is refused when it
//! would write over an input; missing parent directories are created, then the file is written through [`noisecal_io::write_atomic`] (a
//! temporary file in the same directory, synced, then renamed; the permission policy is
//! `noisecal_io`'s: a replaced file keeps its permissions, a new one gets `File::create`'s).

use std::path::Path;

use anyhow::Context;
use noisecal_core::ModelPack;
use noisecal_core::format::lazy_pack::LazyPack;
use noisecal_core::model::structure::Components;
use noisecal_core::resolve::{ModelKind, Resolved, resolve_on_demand};

/// Writes `bytes` to `path` atomically, creating the parent directories first.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    create_parent(path).with_context(|| format!("cannot create the directory of {}", path.display()))?;
    noisecal_io::write_bytes_atomic(path, bytes).with_context(|| format!("cannot write {}", path.display()))
}

/// Creates the directory an output file goes into when it is missing. Every writer does this
/// (DNGs, packs, recordings, reports); `noisecal_io` itself refuses a missing directory, as the
/// app's checkpoints want.
pub fn create_parent(path: &Path) -> std::io::Result<()> {
    match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => std::fs::create_dir_all(dir),
        _ => Ok(()),
    }
}

/// The largest pack file read (a 14-bit pack with many ISOs is tens of MB).
pub const MAX_PACK_BYTES: u64 = 1 << 30;

/// Reads a pack file with a message that names it. Only regular files are read: a FIFO or a
/// device such as `/dev/zero` is refused instead of blocking or filling memory.
pub fn load_pack(path: &Path) -> anyhow::Result<ModelPack> {
    let bytes = noisecal_io::read_regular(path, MAX_PACK_BYTES)
        .with_context(|| format!("cannot read model pack {}", path.display()))?;
    ModelPack::from_bytes(&bytes).with_context(|| format!("{} is not a usable model pack", path.display()))
}

/// Opens a pack file to be read on demand ([`LazyPack`]: its index now, each ISO when first
/// asked for), with a message that names it. Only regular files are read, as [`load_pack`] reads
/// them. The file is copied into memory, not mapped: a pack rewritten or truncated by another
/// program while it is open (a long synthesis run, a Python `Pack` kept for hours) cannot pull
/// pages from under it (a mapped page past a new end raises `SIGBUS`); the copy is one read of a
/// file of a few MB.
pub fn open_pack(path: &Path) -> anyhow::Result<LazyPack<Vec<u8>>> {
    let bytes = noisecal_io::read_regular(path, MAX_PACK_BYTES)
        .with_context(|| format!("cannot read model pack {}", path.display()))?;
    LazyPack::open(bytes).with_context(|| format!("{} is not a usable model pack", path.display()))
}

/// The model of `kind` at `iso` from a pack opened by [`open_pack`] (`path` names it), and the
/// pack of the ISOs it stands on ([`resolve_on_demand`]): a section that fails to decode is
/// named as [`load_pack`] names a bad file; a model the pack cannot give keeps the core's error
/// (and its remedy).
pub fn resolve_pack<B: std::ops::Deref<Target = [u8]>>(
    lazy: &LazyPack<B>,
    path: &Path,
    iso: u32,
    kind: ModelKind,
    which: Components,
    extrapolate: bool,
) -> anyhow::Result<(ModelPack, Resolved)> {
    resolve_on_demand(lazy, iso, kind, which, extrapolate).map_err(|e| match e {
        noisecal_core::Error::Codec(c) => {
            anyhow::Error::from(c).context(format!("{} is not a usable model pack", path.display()))
        }
        other => anyhow::Error::from(other),
    })
}

/// Refuses an output that would write over an input: the same file (through symlinks and hard
/// links), the same folder, or a DNG inside an input folder. Checked before any work, so a
/// refused run leaves everything as it was.
pub fn refuse_overwriting_inputs(output: &Path, inputs: &[&Path]) -> anyhow::Result<()> {
    for input in inputs {
        if noisecal_io::same_file(output, input) {
            anyhow::bail!(
                "{} is also an input ({}): write to another path; noisecal never writes over what it reads",
                output.display(),
                input.display()
            );
        }
        let is_dng = output.extension().is_some_and(|e| e.eq_ignore_ascii_case("dng"));
        if input.is_dir()
            && is_dng
            && output.exists()
            && output.parent().is_some_and(|p| {
                noisecal_io::same_file(if p.as_os_str().is_empty() { Path::new(".") } else { p }, input)
            })
        {
            anyhow::bail!(
                "{} is one of the captures in {}: write to another path; noisecal never writes over what it reads",
                output.display(),
                input.display()
            );
        }
    }
    Ok(())
}
