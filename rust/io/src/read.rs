//! Reading whole input files, refusing what is not a regular file of bounded size.

use std::fs::{self, File};
use std::io::{self, Read};
use std::path::Path;

/// Reads the whole file at `path` (symlinks followed), after checking that it is a regular file
/// of at most `max_bytes` bytes.
///
/// Refused, with a message that names the path:
/// * a directory ([`io::ErrorKind::IsADirectory`]);
/// * anything else that is not a regular file — a FIFO, a socket, a character or block device
///   such as `/dev/zero` ([`io::ErrorKind::InvalidInput`]); the kind is checked before opening,
///   so a FIFO without a writer does not block;
/// * a file larger than `max_bytes`, or one that grows past it while being read
///   ([`io::ErrorKind::FileTooLarge`]).
///
/// Errors of the OS (a missing or unreadable file) are returned as [`std::fs::read`] returns
/// them: callers add the path.
pub fn read_regular(path: &Path, max_bytes: u64) -> io::Result<Vec<u8>> {
    let mut buf = Vec::new();
    read_regular_into(path, max_bytes, &mut buf)?;
    Ok(buf)
}

/// As [`read_regular`] (the same checks, the same errors), into `buf` (cleared first): a buffer
/// kept from an earlier file already has its pages, where a fresh one must have them faulted in
/// and zeroed.
pub fn read_regular_into(path: &Path, max_bytes: u64, buf: &mut Vec<u8>) -> io::Result<()> {
    let (file, len) = open_regular(path, max_bytes)?;
    buf.clear();
    buf.reserve_exact(usize::try_from(len).unwrap_or(0));
    file.take(max_bytes.saturating_add(1)).read_to_end(buf)?;
    if buf.len() as u64 > max_bytes {
        return Err(too_large(path, buf.len() as u64, max_bytes));
    }
    Ok(())
}

/// The file at `path` opened for reading, with its length, after the checks of
/// [`read_regular`] (the same errors): for callers that read parts of it.
pub fn open_regular(path: &Path, max_bytes: u64) -> io::Result<(File, u64)> {
    check_regular(path, &fs::metadata(path)?)?;
    let file = File::open(path)?;
    // The open file is checked again: the path may have been replaced since.
    let meta = file.metadata()?;
    check_regular(path, &meta)?;
    if meta.len() > max_bytes {
        return Err(too_large(path, meta.len(), max_bytes));
    }
    Ok((file, meta.len()))
}

fn too_large(path: &Path, len: u64, max_bytes: u64) -> io::Error {
    io::Error::new(
        io::ErrorKind::FileTooLarge,
        format!("{} is {len} bytes long, more than the {max_bytes} bytes accepted", path.display()),
    )
}

/// A read-only view of a whole regular file: memory-mapped (no copy; pages come from the page
/// cache as they are touched), or an empty slice for an empty file.
#[derive(Debug)]
pub struct Mapped(Option<memmap2::Mmap>);

impl std::ops::Deref for Mapped {
    type Target = [u8];

    fn deref(&self) -> &[u8] {
        self.0.as_deref().unwrap_or(&[])
    }
}

/// As [`read_regular`] (the same checks, the same errors), but the file is memory-mapped instead
/// of copied: for large inputs that are read once (a 24 MB DNG maps in well under a millisecond;
/// reading it costs a copy and as many fresh pages). The pages are mapped in advance.
///
/// The file must not be truncated while the mapping lives: reading a page past the new end raises
/// `SIGBUS` (as for any mapped input). noisecal never writes over its inputs.
pub fn map_regular(path: &Path, max_bytes: u64) -> io::Result<Mapped> {
    let (file, len) = open_regular(path, max_bytes)?;
    if len == 0 {
        return Ok(Mapped(None));
    }
    // SAFETY: a read-only private mapping of a regular file checked above; the bytes are only
    // read. Another process truncating the file while it is mapped is the one hazard (SIGBUS),
    // documented above.
    let map = unsafe { memmap2::MmapOptions::new().len(len as usize).populate().map(&file)? };
    Ok(Mapped(Some(map)))
}

fn check_regular(path: &Path, meta: &fs::Metadata) -> io::Result<()> {
    let ft = meta.file_type();
    if ft.is_file() {
        return Ok(());
    }
    if ft.is_dir() {
        return Err(io::Error::new(
            io::ErrorKind::IsADirectory,
            format!("{} is a directory, not a regular file", path.display()),
        ));
    }
    Err(io::Error::new(io::ErrorKind::InvalidInput, format!("{} is {}, not a regular file", path.display(), kind(&ft))))
}

#[cfg(unix)]
fn kind(ft: &fs::FileType) -> &'static str {
    use std::os::unix::fs::FileTypeExt;
    if ft.is_fifo() {
        "a named pipe (FIFO)"
    } else if ft.is_char_device() {
        "a character device"
    } else if ft.is_block_device() {
        "a block device"
    } else if ft.is_socket() {
        "a socket"
    } else {
        "a special file"
    }
}

#[cfg(not(unix))]
fn kind(_ft: &fs::FileType) -> &'static str {
    "a special file"
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn tempdir(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("noisecal-io-read-{tag}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        fs::create_dir_all(&d).expect("create test dir");
        d
    }

    #[test]
    fn reads_regular_files_within_the_cap() {
        let d = tempdir("cap");
        let p = d.join("f");
        fs::write(&p, b"0123456789").expect("write");
        assert_eq!(read_regular(&p, 10).expect("exactly the cap"), b"0123456789");
        assert_eq!(read_regular(&p, 1 << 20).expect("under the cap"), b"0123456789");
        let e = read_regular(&p, 9).expect_err("over the cap");
        assert_eq!(e.kind(), io::ErrorKind::FileTooLarge, "{e}");
        assert!(e.to_string().contains(&p.display().to_string()) && e.to_string().contains("10 bytes"), "{e}");

        let e = read_regular(&d.join("missing"), 10).expect_err("missing");
        assert_eq!(e.kind(), io::ErrorKind::NotFound, "{e}");

        let e = read_regular(&d, 10).expect_err("directory");
        assert_eq!(e.kind(), io::ErrorKind::IsADirectory, "{e}");
        assert!(e.to_string().contains(&d.display().to_string()), "{e}");
        fs::remove_dir_all(&d).expect("clean");
    }

    #[test]
    fn maps_like_it_reads() {
        let d = tempdir("map");
        let p = d.join("f");
        fs::write(&p, b"0123456789").expect("write");
        assert_eq!(&*map_regular(&p, 10).expect("map"), b"0123456789");
        let e = map_regular(&p, 9).expect_err("over the cap");
        assert_eq!(e.kind(), io::ErrorKind::FileTooLarge, "{e}");
        let empty = d.join("empty");
        fs::write(&empty, b"").expect("write");
        assert!(map_regular(&empty, 10).expect("empty").is_empty());
        assert_eq!(map_regular(&d, 10).expect_err("directory").kind(), io::ErrorKind::IsADirectory);
        assert_eq!(map_regular(&d.join("missing"), 10).expect_err("missing").kind(), io::ErrorKind::NotFound);
        #[cfg(unix)]
        assert_eq!(map_regular(Path::new("/dev/zero"), 10).expect_err("device").kind(), io::ErrorKind::InvalidInput);
        fs::remove_dir_all(&d).expect("clean");
    }

    #[cfg(unix)]
    #[test]
    fn devices_are_refused() {
        let e = read_regular(Path::new("/dev/zero"), u64::MAX).expect_err("/dev/zero");
        assert_eq!(e.kind(), io::ErrorKind::InvalidInput, "{e}");
        assert!(e.to_string().contains("/dev/zero") && e.to_string().contains("character device"), "{e}");
    }

    #[cfg(unix)]
    #[test]
    fn fifo_is_refused_without_blocking() {
        let d = tempdir("fifo");
        let fifo = d.join("pipe");
        let status = std::process::Command::new("mkfifo").arg(&fifo).status().expect("run mkfifo");
        assert!(status.success(), "mkfifo failed");
        // Opening a FIFO for reading blocks until a writer comes: read on another thread, with a
        // deadline, so a regression fails instead of hanging.
        let (tx, rx) = std::sync::mpsc::channel();
        let p = fifo.clone();
        std::thread::spawn(move || {
            let _ = tx.send(read_regular(&p, 1 << 20));
        });
        let r = rx.recv_timeout(std::time::Duration::from_secs(10)).expect("read_regular blocked on a FIFO");
        let e = r.expect_err("FIFO");
        assert_eq!(e.kind(), io::ErrorKind::InvalidInput, "{e}");
        assert!(e.to_string().contains(&fifo.display().to_string()) && e.to_string().contains("FIFO"), "{e}");
        fs::remove_dir_all(&d).expect("clean");
    }
}
