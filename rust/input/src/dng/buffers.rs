//! Buffers for the DNG files calibration reads whole, kept for the next files while a calibration
//! runs: a file read into a buffer a frame before left has its pages already in memory, where a
//! fresh buffer is fresh pages the kernel must fault in and zero (6 000 for a 24 MB file), which
//! cost more than the copy from the page cache itself. [`release`] frees them when the
//! calibration ends.

use std::path::Path;
use std::sync::Mutex;

/// Buffers kept at most (a calibration reads a few frames per thread ahead).
const KEPT: usize = 64;

static FREE: Mutex<Vec<Vec<u8>>> = Mutex::new(Vec::new());

/// A file's bytes in a buffer that goes back to the free buffers when dropped.
#[derive(Debug, Default)]
pub(super) struct Buffer(Vec<u8>);

impl Buffer {
    /// The file's bytes ([`noisecal_io::read_regular_into`]: its checks and errors), read into
    /// a free buffer where there is one.
    pub(super) fn read(path: &Path, max_bytes: u64) -> std::io::Result<Self> {
        let mut buf = Buffer(FREE.lock().ok().and_then(|mut f| f.pop()).unwrap_or_default());
        noisecal_io::read_regular_into(path, max_bytes, &mut buf.0)?;
        Ok(buf)
    }

    /// The bytes, owned (the buffer does not go back).
    pub(super) fn into_vec(mut self) -> Vec<u8> {
        std::mem::take(&mut self.0)
    }
}

impl std::ops::Deref for Buffer {
    type Target = [u8];

    fn deref(&self) -> &[u8] {
        &self.0
    }
}

impl Drop for Buffer {
    fn drop(&mut self) {
        if self.0.capacity() == 0 {
            return;
        }
        if let Ok(mut free) = FREE.lock()
            && free.len() < KEPT
        {
            free.push(std::mem::take(&mut self.0));
        }
    }
}

/// Frees the buffers kept for reuse (at the end of a calibration).
pub fn release() {
    if let Ok(mut free) = FREE.lock() {
        *free = Vec::new();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A dropped buffer is reused by the next read, which holds the new file's bytes only.
    #[test]
    fn buffers_are_reused_and_hold_the_file() {
        let dir = tempfile::tempdir().expect("tempdir");
        let (a, b) = (dir.path().join("a"), dir.path().join("b"));
        std::fs::write(&a, vec![7u8; 100_000]).expect("write");
        std::fs::write(&b, b"short").expect("write");
        release();
        let first = Buffer::read(&a, 1 << 20).expect("read a");
        assert_eq!(&*first, &vec![7u8; 100_000][..]);
        let at = first.0.as_ptr();
        drop(first);
        let second = Buffer::read(&b, 1 << 20).expect("read b");
        assert_eq!(&*second, b"short");
        assert_eq!(second.0.as_ptr(), at, "the dropped buffer was reused");
        assert_eq!(second.into_vec(), b"short");
        release();
        assert!(FREE.lock().expect("lock").is_empty());
        let e = Buffer::read(&a, 10).expect_err("over the cap");
        assert_eq!(e.kind(), std::io::ErrorKind::FileTooLarge);
    }
}
