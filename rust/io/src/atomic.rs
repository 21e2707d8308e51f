//! Atomic replacement of a file: a temporary file in the target's directory, written through a
//! buffer, synced, renamed over the target, then the directory synced. Temporary files left by a
//! killed process are removed by the next write into their directory.

use std::collections::HashSet;
use std::fs::{self, File, OpenOptions};
use std::io::{self, BufWriter, Write};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, SystemTime};

/// Distinguishes the temporary files of one process (the process id distinguishes processes).
static COUNTER: AtomicU64 = AtomicU64::new(0);

/// How many names are tried when a temporary name is taken (a leftover of a killed process whose
/// id has been reused).
const NAME_ATTEMPTS: u32 = 64;

/// What marks a temporary file of noisecal: `.<target name>.noisecal-tmp.<pid>.<n>`.
const TEMP_MARK: &str = ".noisecal-tmp.";

/// A temporary file whose process is gone is removed once it is this old (a grace period for
/// processes in another pid namespace sharing the folder).
const DEAD_GRACE: Duration = Duration::from_secs(10);
/// Where a process's liveness cannot be learnt (no `/proc`), a temporary file untouched this long
/// is stale.
const UNKNOWN_AGE: Duration = Duration::from_secs(15 * 60);
/// A temporary file untouched this long is stale whatever its pid says (the pid was reused).
const MAX_AGE: Duration = Duration::from_secs(24 * 60 * 60);

/// Writes the file at `path` with what `write` produces, atomically: `path` is either left as it
/// was or replaced by the complete new content.
///
/// The content goes to a hidden temporary file in the same directory
/// (`.<name>.noisecal-tmp.<pid>.<n>`, see [`AtomicFile`]), through a buffer; the file is synced,
/// renamed over `path`, and the directory is synced where the platform supports it (so the rename
/// itself survives a power cut). Permissions follow the crate's policy (see the crate
/// documentation): a replaced file keeps its permission bits, a new file gets those of
/// [`File::create`]. A symlink at `path` is replaced, not followed.
///
/// On any error — including one returned by `write`, and a panic inside it — the temporary file is
/// removed and `path` is untouched. The directory must exist (it is not created). A `path` that is
/// a directory is refused ([`io::ErrorKind::IsADirectory`]).
///
/// Errors of `write` are returned unchanged; the others keep their [`io::ErrorKind`] and say which
/// step failed (callers add the path they were writing).
pub fn write_atomic<F>(path: &Path, write: F) -> io::Result<()>
where
    F: FnOnce(&mut dyn Write) -> io::Result<()>,
{
    let mut file = AtomicFile::create(path)?;
    write(&mut file)?;
    file.commit()
}

/// [`write_atomic`] of a byte slice.
pub fn write_bytes_atomic(path: &Path, bytes: &[u8]) -> io::Result<()> {
    write_atomic(path, |w| w.write_all(bytes))
}

/// A file being written atomically, for writers that stream (a recording of many frames): write
/// into it, then [`commit`](Self::commit) renames it over the target. Dropped without a commit (an
/// error, a panic), its temporary file is removed and the target is untouched; a process killed
/// while writing leaves a temporary file `.<name>.noisecal-tmp.<pid>.<n>` that the next
/// [`create`](Self::create) in that directory removes (its process is gone).
#[derive(Debug)]
pub struct AtomicFile {
    out: BufWriter<File>,
    guard: TempGuard,
    target: PathBuf,
    dir: PathBuf,
}

impl AtomicFile {
    /// Starts replacing `path`: removes stale temporary files of killed noisecal processes in its
    /// directory, then creates this one's. See [`write_atomic`] for the rules.
    pub fn create(path: &Path) -> io::Result<Self> {
        let Some(name) = path.file_name() else {
            return Err(io::Error::new(
                io::ErrorKind::InvalidInput,
                format!("{} does not name a file", path.display()),
            ));
        };
        let dir = match path.parent() {
            Some(d) if !d.as_os_str().is_empty() => d,
            _ => Path::new("."),
        };
        let existing = fs::metadata(path).ok();
        if existing.as_ref().is_some_and(fs::Metadata::is_dir) {
            return Err(io::Error::new(
                io::ErrorKind::IsADirectory,
                format!("{} is a directory; refusing to replace it with a file", path.display()),
            ));
        }
        sweep_once(dir);
        let (file, guard) = create_temp(dir, &name.to_string_lossy())?;
        if let Some(meta) = &existing {
            keep_permissions(&file, meta).map_err(|e| {
                io::Error::new(e.kind(), format!("cannot set the permissions of {}: {e}", guard.path.display()))
            })?;
        }
        Ok(Self {
            out: BufWriter::with_capacity(1 << 16, file),
            guard,
            target: path.to_path_buf(),
            dir: dir.to_path_buf(),
        })
    }

    /// The temporary file being written.
    pub fn temp_path(&self) -> &Path {
        &self.guard.path
    }

    /// The temporary file, for positioned writes ([`write_all_at`], from any number of threads)
    /// and [`start_writeback`]: what was written through [`Write`] is flushed first. Do not mix
    /// the two afterwards (buffered writes go where the file's cursor is).
    pub fn positioned(&mut self) -> io::Result<&File> {
        self.out.flush()?;
        Ok(self.out.get_ref())
    }

    /// Flushes, syncs and renames the temporary file over the target, then syncs the directory.
    pub fn commit(self) -> io::Result<()> {
        let Self { out, guard, target, dir } = self;
        let step = |what: &str, e: io::Error| io::Error::new(e.kind(), format!("{what} {}: {e}", guard.path.display()));
        let file = out.into_inner().map_err(|e| step("cannot write", e.into_error()))?;
        file.sync_all().map_err(|e| step("cannot sync", e))?;
        // Closed before the rename: some platforms cannot rename an open file.
        drop(file);
        fs::rename(&guard.path, &target).map_err(|e| {
            io::Error::new(e.kind(), format!("cannot rename {} onto {}: {e}", guard.path.display(), target.display()))
        })?;
        guard.disarm();
        sync_dir(&dir);
        Ok(())
    }
}

impl Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> io::Result<usize> {
        self.out.write(buf)
    }

    fn write_all(&mut self, buf: &[u8]) -> io::Result<()> {
        self.out.write_all(buf)
    }

    fn flush(&mut self) -> io::Result<()> {
        self.out.flush()
    }
}

/// Writes all of `buf` at `offset` of `file` (a positioned write: the file's cursor is neither
/// used nor moved, so threads may write disjoint parts of one file at once).
pub fn write_all_at(file: &File, buf: &[u8], offset: u64) -> io::Result<()> {
    #[cfg(unix)]
    {
        std::os::unix::fs::FileExt::write_all_at(file, buf, offset)
    }
    #[cfg(windows)]
    {
        let (mut buf, mut offset) = (buf, offset);
        while !buf.is_empty() {
            match std::os::windows::fs::FileExt::seek_write(file, buf, offset) {
                Ok(0) => return Err(io::Error::from(io::ErrorKind::WriteZero)),
                Ok(n) => {
                    buf = &buf[n..];
                    offset += n as u64;
                }
                Err(e) if e.kind() == io::ErrorKind::Interrupted => {}
                Err(e) => return Err(e),
            }
        }
        Ok(())
    }
}

/// Asks the OS to start writing `len` bytes at `offset` of `file` to the disk now, without
/// waiting (Linux: `sync_file_range(SYNC_FILE_RANGE_WRITE)`; elsewhere, Android included, whose
/// `libc` bindings lack the flag, nothing). A
/// file written in parts then has most of its data on the disk by the time it is complete, and
/// the sync of [`AtomicFile::commit`] (which this does not replace: it makes no promise of
/// durability) waits for the rest only. Best effort: errors are ignored.
pub fn start_writeback(file: &File, offset: u64, len: u64) {
    #[cfg(target_os = "linux")]
    {
        use std::os::fd::AsRawFd;
        let (Ok(offset), Ok(len)) = (libc::off64_t::try_from(offset), libc::off64_t::try_from(len)) else {
            return;
        };
        // SAFETY: a plain system call on an open descriptor; no memory is passed.
        unsafe {
            libc::sync_file_range(file.as_raw_fd(), offset, len, libc::SYNC_FILE_RANGE_WRITE);
        }
    }
    #[cfg(not(target_os = "linux"))]
    {
        let _ = (file, offset, len);
    }
}

/// Removes the temporary file unless disarmed: on an error return and on a panic alike.
#[derive(Debug)]
struct TempGuard {
    path: PathBuf,
    armed: bool,
}

impl TempGuard {
    fn disarm(mut self) {
        self.armed = false;
    }
}

impl Drop for TempGuard {
    fn drop(&mut self) {
        if self.armed {
            let _ = fs::remove_file(&self.path);
        }
    }
}

/// A new, empty temporary file in `dir` for a target named `name`, created exclusively (never an
/// existing file), with the permissions of [`File::create`].
fn create_temp(dir: &Path, name: &str) -> io::Result<(File, TempGuard)> {
    let pid = std::process::id();
    // A long target name is shortened (on a character boundary) so the temporary name fits.
    let mut short = name.trim_start_matches('.');
    while short.len() > 120 {
        let mut cut = 120;
        while !short.is_char_boundary(cut) {
            cut -= 1;
        }
        short = &short[..cut];
    }
    let mut last = None;
    for _ in 0..NAME_ATTEMPTS {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let path = dir.join(format!(".{short}{TEMP_MARK}{pid}.{n}"));
        match OpenOptions::new().write(true).create_new(true).open(&path) {
            Ok(file) => return Ok((file, TempGuard { path, armed: true })),
            Err(e) if e.kind() == io::ErrorKind::AlreadyExists => last = Some(e),
            Err(e) => {
                return Err(io::Error::new(
                    e.kind(),
                    format!("cannot create a temporary file in {}: {e}", dir.display()),
                ));
            }
        }
    }
    let e = last.unwrap_or_else(|| io::Error::from(io::ErrorKind::AlreadyExists));
    Err(io::Error::new(e.kind(), format!("cannot create a temporary file in {}: {e}", dir.display())))
}

/// The process id in a temporary file's name: `.<name>.noisecal-tmp.<pid>.<n>`, or the older
/// `.noisecal-<pid>-<n>.tmp`.
fn temp_pid(file_name: &str) -> Option<u32> {
    if !file_name.starts_with('.') {
        return None;
    }
    if let Some(at) = file_name.rfind(TEMP_MARK) {
        let (pid, n) = file_name[at + TEMP_MARK.len()..].split_once('.')?;
        n.parse::<u64>().ok()?;
        return pid.parse().ok();
    }
    let (pid, n) = file_name.strip_prefix(".noisecal-")?.strip_suffix(".tmp")?.split_once('-')?;
    n.parse::<u64>().ok()?;
    pid.parse().ok()
}

/// Whether process `pid` is alive: `Some` where the platform says (`/proc`), `None` elsewhere.
fn pid_alive(pid: u32) -> Option<bool> {
    if !Path::new("/proc/self").exists() {
        return None;
    }
    Some(Path::new(&format!("/proc/{pid}")).exists())
}

/// Whether a temporary file of process `pid`, last modified `age` ago, is a stale leftover.
fn is_stale(pid: u32, age: Duration) -> bool {
    if pid == std::process::id() {
        return false;
    }
    if age >= MAX_AGE {
        return true;
    }
    match pid_alive(pid) {
        Some(alive) => !alive && age >= DEAD_GRACE,
        None => age >= UNKNOWN_AGE,
    }
}

/// Removes the temporary files of dead noisecal processes in `dir` (best effort; only regular
/// files with noisecal's temporary names) and returns how many it removed.
pub fn sweep_stale_temps(dir: &Path) -> usize {
    let Ok(entries) = fs::read_dir(dir) else { return 0 };
    let now = SystemTime::now();
    let mut removed = 0;
    for entry in entries.flatten() {
        let name = entry.file_name();
        let Some(pid) = name.to_str().and_then(temp_pid) else { continue };
        let Ok(meta) = entry.metadata() else { continue };
        if !meta.is_file() {
            continue;
        }
        let age = meta.modified().ok().and_then(|m| now.duration_since(m).ok()).unwrap_or_default();
        if is_stale(pid, age) && fs::remove_file(entry.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

/// [`sweep_stale_temps`] once per directory per process (a folder of outputs is listed once).
fn sweep_once(dir: &Path) {
    static SWEPT: Mutex<Option<HashSet<PathBuf>>> = Mutex::new(None);
    let key = fs::canonicalize(dir).unwrap_or_else(|_| dir.to_path_buf());
    let first = match SWEPT.lock() {
        Ok(mut g) => g.get_or_insert_with(HashSet::new).insert(key),
        Err(_) => true,
    };
    if first {
        sweep_stale_temps(dir);
    }
}

#[cfg(unix)]
fn keep_permissions(file: &File, existing: &fs::Metadata) -> io::Result<()> {
    use std::os::unix::fs::PermissionsExt;
    file.set_permissions(fs::Permissions::from_mode(existing.permissions().mode() & 0o777))
}

#[cfg(not(unix))]
fn keep_permissions(file: &File, existing: &fs::Metadata) -> io::Result<()> {
    // The one permission there is: read-only. A read-only target cannot be replaced anyway.
    let mut p = file.metadata()?.permissions();
    p.set_readonly(existing.permissions().readonly());
    file.set_permissions(p)
}

/// Makes the rename durable. Best effort: the new content is already in place, and some file
/// systems refuse to sync a directory.
#[cfg(unix)]
fn sync_dir(dir: &Path) {
    if let Ok(d) = File::open(dir) {
        let _ = d.sync_all();
    }
}

#[cfg(not(unix))]
fn sync_dir(_dir: &Path) {}

#[cfg(test)]
mod tests {
    use super::*;

    fn tempdir(tag: &str) -> PathBuf {
        let n = COUNTER.fetch_add(1, Ordering::Relaxed);
        let d = std::env::temp_dir().join(format!("noisecal-io-test-{tag}-{}-{n}", std::process::id()));
        let _ = fs::remove_dir_all(&d);
        fs::create_dir_all(&d).expect("create test dir");
        d
    }

    fn names(dir: &Path) -> Vec<String> {
        let mut v: Vec<String> = fs::read_dir(dir)
            .expect("list")
            .map(|e| e.expect("entry").file_name().to_string_lossy().into_owned())
            .collect();
        v.sort();
        v
    }

    #[test]
    fn content_lands_and_replaces() {
        let d = tempdir("lands");
        let p = d.join("x.bin");
        // Larger than the write buffer, so the flush path is exercised.
        let big: Vec<u8> = (0..100_000u32).map(|i| (i * 7 % 251) as u8).collect();
        write_bytes_atomic(&p, &big).expect("first write");
        assert_eq!(fs::read(&p).expect("read"), big);
        write_atomic(&p, |w| {
            w.write_all(b"two")?;
            w.write_all(b"!")
        })
        .expect("second write");
        assert_eq!(fs::read(&p).expect("read"), b"two!");
        assert_eq!(names(&d), ["x.bin"]);
        // A file in a sub-directory.
        let rel = d.join("sub");
        fs::create_dir(&rel).expect("mkdir");
        write_bytes_atomic(&rel.join("y"), b"y").expect("nested");
        assert_eq!(fs::read(rel.join("y")).expect("read"), b"y");
        fs::remove_dir_all(&d).expect("clean");
    }

    #[test]
    fn error_mid_write_keeps_the_old_file_and_no_temporary() {
        let d = tempdir("midwrite");
        let p = d.join("keep.bin");
        fs::write(&p, b"old content").expect("seed");
        let err = write_atomic(&p, |w| {
            w.write_all(&[1u8; 20_000])?;
            Err(io::Error::other("disk full, say"))
        })
        .expect_err("the writer's error is returned");
        assert_eq!(err.to_string(), "disk full, say");
        assert_eq!(fs::read(&p).expect("read"), b"old content");
        assert_eq!(names(&d), ["keep.bin"]);

        // A panic inside the writer: same guarantees.
        let r = std::panic::catch_unwind(|| {
            let _ = write_atomic(&p, |w| {
                w.write_all(b"partial")?;
                panic!("writer panicked");
            });
        });
        assert!(r.is_err());
        assert_eq!(fs::read(&p).expect("read"), b"old content");
        assert_eq!(names(&d), ["keep.bin"]);
        fs::remove_dir_all(&d).expect("clean");
    }

    #[test]
    fn missing_directory_and_directory_target_are_refused() {
        let d = tempdir("refuse");
        let e = write_bytes_atomic(&d.join("no/such/x.bin"), b"z").expect_err("missing dir");
        assert_eq!(e.kind(), io::ErrorKind::NotFound, "{e}");
        assert!(e.to_string().contains("temporary file"), "{e}");
        fs::create_dir(d.join("sub")).expect("mkdir");
        let e = write_bytes_atomic(&d.join("sub"), b"z").expect_err("directory target");
        assert_eq!(e.kind(), io::ErrorKind::IsADirectory, "{e}");
        assert!(d.join("sub").is_dir());
        assert_eq!(names(&d), ["sub"]);
        fs::remove_dir_all(&d).expect("clean");
    }

    #[test]
    fn temporary_names_are_recognisable() {
        assert_eq!(temp_pid(".x.pack.noisecal-tmp.1234.7"), Some(1234));
        assert_eq!(temp_pid(".a.noisecal-tmp.b.noisecal-tmp.99.0"), Some(99));
        assert_eq!(temp_pid(".noisecal-4321-0.tmp"), Some(4321));
        for other in
            ["x.pack.noisecal-tmp.1.2", ".x.noisecal-tmp.1", ".x.noisecal-tmp.a.2", ".noisecal-1.tmp", "f00001.dng"]
        {
            assert_eq!(temp_pid(other), None, "{other}");
        }
        assert!(!is_stale(std::process::id(), MAX_AGE * 2), "never this process's own");
        assert!(is_stale(u32::MAX - 1, MAX_AGE));
        assert!(!is_stale(u32::MAX - 1, Duration::ZERO), "a grace period");
        if pid_alive(1).is_some() {
            assert!(is_stale(u32::MAX - 1, DEAD_GRACE), "a dead process's");
            assert!(!is_stale(1, DEAD_GRACE * 10), "a live process's");
        }
    }

    /// A temporary file left by a killed process is removed by the next write
    /// into its folder; a live process's and unrelated files are kept.
    #[test]
    fn stale_temporaries_are_swept_by_the_next_write() {
        let d = tempdir("sweep");
        let old = SystemTime::now() - Duration::from_secs(60);
        let mk = |name: &str, when: SystemTime| {
            let f = File::create(d.join(name)).expect("create");
            f.set_modified(when).expect("mtime");
        };
        // A pid that is not running: above any pid_max.
        let dead = 4_194_999u32;
        mk(&format!(".out.pack{TEMP_MARK}{dead}.0"), old);
        mk(&format!(".noisecal-{dead}-3.tmp"), old);
        mk(&format!(".fresh.pack{TEMP_MARK}{dead}.1"), SystemTime::now());
        mk(&format!(".live.pack{TEMP_MARK}1.0"), old);
        mk(".hidden-but-mine", old);
        write_bytes_atomic(&d.join("out.pack"), b"new").expect("write");
        let mut want =
            vec![format!(".fresh.pack{TEMP_MARK}{dead}.1"), ".hidden-but-mine".to_string(), "out.pack".into()];
        if pid_alive(1).is_some() {
            want.insert(1, format!(".live.pack{TEMP_MARK}1.0"));
        }
        want.sort();
        assert_eq!(names(&d), want);
        fs::remove_dir_all(&d).expect("clean");
    }

    #[test]
    fn a_streamed_file_appears_only_when_committed() {
        let d = tempdir("stream");
        let p = d.join("s.rec");
        fs::write(&p, b"old").expect("seed");
        let mut f = AtomicFile::create(&p).expect("create");
        f.write_all(&[7u8; 200_000]).expect("write");
        assert!(f.temp_path().file_name().expect("name").to_string_lossy().starts_with(".s.rec.noisecal-tmp."));
        assert_eq!(fs::read(&p).expect("read"), b"old");
        drop(f);
        assert_eq!(names(&d), ["s.rec"], "dropped uncommitted: no temporary left");
        let mut f = AtomicFile::create(&p).expect("create");
        f.write_all(b"new").expect("write");
        f.commit().expect("commit");
        assert_eq!(fs::read(&p).expect("read"), b"new");
        assert_eq!(names(&d), ["s.rec"]);
        fs::remove_dir_all(&d).expect("clean");
    }

    #[test]
    fn positioned_writes_land_where_asked() {
        let d = tempdir("positioned");
        let p = d.join("p.bin");
        let mut f = AtomicFile::create(&p).expect("create");
        f.write_all(b"head").expect("write");
        let file = f.positioned().expect("positioned");
        std::thread::scope(|s| {
            s.spawn(|| write_all_at(file, b"CCCC", 12).expect("write at 12"));
            s.spawn(|| write_all_at(file, b"BBBB", 8).expect("write at 8"));
        });
        write_all_at(file, b"AAAA", 4).expect("write at 4");
        start_writeback(file, 0, 16);
        assert_eq!(fs::read(&p).ok(), None, "not there before the commit");
        f.commit().expect("commit");
        assert_eq!(fs::read(&p).expect("read"), b"headAAAABBBBCCCC");
        assert_eq!(names(&d), ["p.bin"]);
        fs::remove_dir_all(&d).expect("clean");
    }

    #[cfg(unix)]
    #[test]
    fn permissions_kept_on_replace_and_default_on_create() {
        use std::os::unix::fs::PermissionsExt;
        let d = tempdir("perm");
        let mode = |p: &Path| fs::metadata(p).expect("stat").permissions().mode() & 0o777;
        let p = d.join("kept");
        fs::write(&p, b"old").expect("seed");
        fs::set_permissions(&p, fs::Permissions::from_mode(0o640)).expect("chmod");
        write_bytes_atomic(&p, b"new").expect("replace");
        assert_eq!(mode(&p), 0o640);
        fs::set_permissions(&p, fs::Permissions::from_mode(0o604)).expect("chmod");
        write_bytes_atomic(&p, b"newer").expect("replace");
        assert_eq!(mode(&p), 0o604);
        assert_eq!(fs::read(&p).expect("read"), b"newer");

        // A new file: as File::create makes it (0o666 less the umask), not a temp file's 0o600.
        let plain = d.join("plain");
        File::create(&plain).expect("create");
        let fresh = d.join("fresh");
        write_bytes_atomic(&fresh, b"x").expect("create");
        assert_eq!(mode(&fresh), mode(&plain));
        fs::remove_dir_all(&d).expect("clean");
    }
}
