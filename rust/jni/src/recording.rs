//! The recording tee: every accepted frame, exactly as it was handed over, into a recording file
//! (format: [`noisecal_core::format::recording`]), so a device session replays on a desktop to the same pack.
//!
//! A recording can be resumed after a kill: a checkpoint stores the recording's path and its
//! [`RecordingMark`] (length in bytes, frame count) at checkpoint time (the tee is flushed and
//! synced first); restoring truncates the file back to that length (dropping the frames the killed
//! session pushed after the checkpoint, which the restored session has not seen either) and
//! continues it with the core's [`RecordingWriter::resume`]. The single file then replays to the
//! same pack as the resumed session, and is byte for byte the file an uninterrupted session writes.

use std::fs::{File, OpenOptions};
use std::io::{self, BufWriter, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

use noisecal_core::FrameMeta;
use noisecal_core::format::recording::{RecordingHeader, RecordingMark, RecordingWriter, encode_header};

use crate::error::{BoundaryError, Result};

/// An open recording.
#[derive(Debug)]
pub struct RecordingTee {
    path: PathBuf,
    writer: RecordingWriter<BufWriter<File>>,
    /// The same open file (shared offset), to sync it.
    file: File,
}

impl RecordingTee {
    /// Creates (or replaces) a recording at `path` and writes its header.
    pub fn create(path: &Path, header: &RecordingHeader) -> Result<Self> {
        let file = File::create(path).map_err(|e| BoundaryError::io("cannot create the recording", path, e))?;
        let out = Self::buffered(path, &file)?;
        let writer =
            RecordingWriter::new(out, header).map_err(|e| BoundaryError::io("cannot write the recording", path, e))?;
        Ok(Self { path: path.to_path_buf(), writer, file })
    }

    fn buffered(path: &Path, file: &File) -> Result<BufWriter<File>> {
        let clone = file.try_clone().map_err(|e| BoundaryError::io("cannot write the recording", path, e))?;
        Ok(BufWriter::with_capacity(1 << 20, clone))
    }

    /// Re-opens the recording a checkpoint marked: checks the file starts with this session's
    /// header and holds at least the marked bytes, cuts it back to them and continues from there.
    pub fn resume(path: &Path, mark: RecordingMark, header: &RecordingHeader) -> Result<Self> {
        let expected = encode_header(header);
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .open(path)
            .map_err(|e| BoundaryError::io("cannot reopen the recording to resume it", path, e))?;
        let len = file.metadata().map_err(|e| BoundaryError::io("cannot read the recording", path, e))?.len();
        if len < mark.bytes || mark.bytes < expected.len() as u64 {
            return Err(BoundaryError::Recording(format!(
                "recording {} holds {len} bytes, fewer than the {} it held at the checkpoint: it cannot be resumed; start a new recording",
                path.display(),
                mark.bytes
            )));
        }
        let mut head = vec![0u8; expected.len()];
        file.read_exact(&mut head).map_err(|e| BoundaryError::io("cannot read the recording", path, e))?;
        if head != expected {
            return Err(BoundaryError::Recording(format!(
                "recording {} does not belong to this session (its header differs): it was not resumed; start a new recording",
                path.display()
            )));
        }
        file.set_len(mark.bytes).map_err(|e| BoundaryError::io("cannot truncate the recording", path, e))?;
        file.seek(SeekFrom::End(0)).map_err(|e| BoundaryError::io("cannot seek in the recording", path, e))?;
        let writer = RecordingWriter::resume(Self::buffered(path, &file)?, mark);
        Ok(Self { path: path.to_path_buf(), writer, file })
    }

    pub fn path(&self) -> &Path {
        &self.path
    }

    fn err(&self, e: io::Error) -> BoundaryError {
        BoundaryError::io(
            "writing the recording failed; recording stopped (the file holds every record before this one)",
            &self.path,
            e,
        )
    }

    pub fn begin_step(&mut self, exposure_ns: u64) -> Result<()> {
        self.writer.begin_step(exposure_ns).map_err(|e| self.err(e))
    }

    pub fn begin_dark(&mut self) -> Result<()> {
        self.writer.begin_dark().map_err(|e| self.err(e))
    }

    /// Records a frame exactly as handed over: `plane` from the buffer's start.
    pub fn frame(
        &mut self,
        meta: &FrameMeta,
        width: u32,
        height: u32,
        row_stride: u32,
        pixel_stride: u32,
        plane: &[u8],
    ) -> Result<()> {
        self.writer.frame(meta, width, height, row_stride, pixel_stride, plane).map_err(|e| self.err(e))
    }

    pub fn noise_profile(&mut self, iso: u32, profile: &noisecal_core::model::NoiseProfile) -> Result<()> {
        self.writer.noise_profile(iso, profile).map_err(|e| self.err(e))
    }

    /// Flushes and syncs, and says where the recording stands (for a checkpoint).
    pub fn mark(&mut self) -> Result<RecordingMark> {
        self.writer.flush().map_err(|e| self.err(e))?;
        self.file.sync_data().map_err(|e| self.err(e))?;
        Ok(self.writer.mark())
    }

    /// Writes the End record (with the frame count of the whole file) and closes the recording.
    pub fn finish(self) -> Result<RecordingMark> {
        let Self { path, writer, file } = self;
        let err = |e| BoundaryError::io("finishing the recording failed", &path, e);
        let frames = writer.mark().frames;
        drop(writer.finish().map_err(err)?);
        file.sync_data().map_err(err)?;
        Ok(RecordingMark { bytes: file.metadata().map_err(err)?.len(), frames })
    }
}
