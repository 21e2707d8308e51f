//! noisecal's file rules, in one place, so the CLI and the JNI boundary cannot drift apart (the
//! core stays free of I/O and does not depend on this crate).
//!
//! * [`write_atomic`] / [`write_bytes_atomic`] / [`AtomicFile`] (streamed): the one way noisecal
//!   writes a file. A reader, or a restore after a crash or a kill, sees the old file or the whole
//!   new one, never a torn one; the temporary file a kill leaves
//!   (`.<name>.noisecal-tmp.<pid>.<n>`) is removed by the next write into its folder
//!   ([`sweep_stale_temps`]).
//! * [`same_file`]: whether two paths name one file (device and inode, through symlinks and hard
//!   links), so a command can refuse an output that would overwrite one of its inputs.
//! * [`read_regular`]: reads a whole input file after checking it is a regular file of bounded
//!   size, so a FIFO, a device such as `/dev/zero` or a directory is refused with a clear message
//!   instead of blocking, reading forever or failing obscurely; [`map_regular`] maps it instead.
//!
//! # Permission policy
//!
//! One policy for every file noisecal writes:
//! * a file that **replaces** an existing one keeps the existing file's permission bits (Unix
//!   `rwx` for user, group and other; owner, group, ACLs and extended attributes are not copied);
//! * a **new** file gets the permissions of [`std::fs::File::create`]: `0o666` less the process
//!   umask (`0o644` under the usual umask `022`; `0o600` in an Android app, whose umask is `077`).
//!
//! Uses `std`, `memmap2` for [`map_regular`] and, on Linux, `libc` for
//! [`start_writeback`].

mod atomic;
mod identity;
mod read;

pub use atomic::{AtomicFile, start_writeback, sweep_stale_temps, write_all_at, write_atomic, write_bytes_atomic};
pub use identity::same_file;
pub use read::{Mapped, map_regular, open_regular, read_regular, read_regular_into};
