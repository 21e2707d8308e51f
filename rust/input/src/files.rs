//! Writing the CLI's output files so that nothing already written is lost: missing parent
//! directories are created, then the file is written through [`noisecal_io::write_atomic`] (a
//! temporary file in the same directory, synced, then renamed; the permission policy is
//! `noisecal_io`'s: a replaced file keeps its permissions, a new one gets `File::create`'s).

use std::path::Path;

use anyhow::Context;

/// Writes `bytes` to `path` atomically, creating the parent directories first.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> anyhow::Result<()> {
    create_parent(path).with_context(|| format!("cannot create the directory of {}", path.display()))?;
    noisecal_io::write_bytes_atomic(path, bytes).with_context(|| format!("cannot write {}", path.display()))
}

/// Creates the directory an output file goes into when it is missing. Every CLI writer does this
/// (DNGs, packs, recordings, reports); `noisecal_io` itself refuses a missing directory, as the
/// app's checkpoints want.
pub fn create_parent(path: &Path) -> std::io::Result<()> {
    match path.parent() {
        Some(dir) if !dir.as_os_str().is_empty() => std::fs::create_dir_all(dir),
        _ => Ok(()),
    }
}
