//! Saving the input that aborts the process.
//!
//! `catch_unwind` catches panics, not aborts: a failed allocation (`memory allocation of N bytes
//! failed`), a stack overflow or a panic while panicking end the process with SIGABRT, and the
//! input that did it was lost. CI's fuzz run died that way once (a 32 GB allocation in rawler's
//! TIFF parser) and left nothing to replay. [`arm`] installs a SIGABRT handler that writes the
//! running input to `<crashes>/<target>/abort.bin` with async-signal-safe calls only (`open`,
//! `write`, `close` on a path and a buffer prepared beforehand), then lets the abort go on.

use std::ffi::CString;
use std::path::Path;
use std::ptr::null_mut;
use std::sync::atomic::{AtomicPtr, AtomicUsize, Ordering};

static INPUT: AtomicPtr<u8> = AtomicPtr::new(null_mut());
static LEN: AtomicUsize = AtomicUsize::new(0);
static PATH: AtomicPtr<libc::c_char> = AtomicPtr::new(null_mut());

/// Where an aborting input of this target is saved.
pub fn path(crashes: &Path, target: &str) -> std::path::PathBuf {
    crashes.join(target).join("abort.bin")
}

/// Installs the handler (once) and points it at this target's `abort.bin`.
pub fn arm(crashes: &Path, target: &str) {
    let p = path(crashes, target);
    if let Some(dir) = p.parent() {
        let _ = std::fs::create_dir_all(dir);
    }
    let Ok(c) = CString::new(p.as_os_str().as_encoded_bytes()) else { return };
    // Leaked on purpose: the handler may read it at any moment until the process ends.
    PATH.store(c.into_raw(), Ordering::SeqCst);
    let handler: extern "C" fn(libc::c_int) = on_abort;
    // SAFETY: `on_abort` only calls async-signal-safe functions on data set up before the run.
    unsafe {
        libc::signal(libc::SIGABRT, handler as libc::sighandler_t);
    }
}

/// The input now running (it must stay alive until [`finished`]).
pub fn running(input: &[u8]) {
    LEN.store(0, Ordering::SeqCst);
    INPUT.store(input.as_ptr().cast_mut(), Ordering::SeqCst);
    LEN.store(input.len(), Ordering::SeqCst);
}

/// No input is running.
pub fn finished() {
    LEN.store(0, Ordering::SeqCst);
    INPUT.store(null_mut(), Ordering::SeqCst);
}

extern "C" fn on_abort(_: libc::c_int) {
    let (input, len, path) = (INPUT.load(Ordering::SeqCst), LEN.load(Ordering::SeqCst), PATH.load(Ordering::SeqCst));
    if !input.is_null() && !path.is_null() {
        // SAFETY: `path` is a leaked NUL-terminated string; `input` points at `len` bytes that the
        // fuzz loop keeps alive while they run (the abort happens inside that run).
        unsafe {
            let fd = libc::open(path, libc::O_WRONLY | libc::O_CREAT | libc::O_TRUNC, 0o644);
            if fd >= 0 {
                let mut done = 0usize;
                while done < len {
                    let n = libc::write(fd, input.add(done).cast(), len - done);
                    if n <= 0 {
                        break;
                    }
                    done += n as usize;
                }
                libc::close(fd);
                let msg = b"noisecal-fuzz: ABORT; the input is saved as abort.bin under the crashes folder\n";
                libc::write(2, msg.as_ptr().cast(), msg.len());
            }
        }
    }
    // The default action then ends the process as the abort meant to.
    // SAFETY: resetting a disposition is async-signal-safe.
    unsafe {
        libc::signal(libc::SIGABRT, libc::SIG_DFL);
    }
}
