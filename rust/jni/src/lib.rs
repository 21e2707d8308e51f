//! noisecal's JNI boundary: Camera2 `RAW_SENSOR` planes from Kotlin
//! (`org.noisecal.jni.NoisecalSession`, `android/capture/src/main/kotlin/org/noisecal/jni/`) into
//! the Rust calibration core, read in place from the direct `ByteBuffer`.
//!
//! - [`jni_api`]: the `external` functions; one error policy turns every error and every panic into
//!   an `org.noisecal.jni.NoisecalException` with a message that says what was wrong.
//! - [`registry`]: handles are ids into a map of live sessions, so a closed handle is an exception,
//!   never a dangling pointer.
//! - [`session`]: the session behind a handle (core session + recording tee), JNI-free.
//! - [`gap_calls`]: a finished pack's conversion-gain call per gap between calibrated ISOs, as
//!   the text that crosses with the summary.
//! - [`recording`]: the tee into a recording file, resumable from a checkpoint.
//! - [`replay`]: a recording back into a pack, as `noisecal calibrate session.rec` does.
//! - `testkit` (feature `testkit`, host builds only): synthetic captures for tests and the JVM
//!   harness, and the harness's native hooks (`test_hooks`). The Android library is built
//!   without it; `tests/jvm/*/run.sh`, the `noisecal-jni-tool` bin and this crate's tests enable it.
//!
//! Why a `ByteBuffer` and not the `ndk` crate's `AImage`: the app gets its frames from a Kotlin
//! `ImageReader` (it needs the `TotalCaptureResult` for ISO, exposure and dynamic black level,
//! matched to the image by timestamp in Kotlin anyway); `Image.planes[0].buffer` is a direct buffer
//! over the very same native memory an `AImage` plane exposes, so reading it through
//! `GetDirectBufferAddress` is already zero-copy. Going through `AImageReader` instead would move
//! the reader, its listener thread and the result matching into native code, tie the library to
//! API 24+ `libmediandk`, and make the boundary untestable on a host JVM. The `ndk` crate would
//! serve only if capture itself moved to native code.

pub mod error;
pub mod files;
pub mod gap_calls;
pub mod jni_api;
pub mod recording;
pub mod registry;
pub mod replay;
pub mod session;
#[cfg(feature = "testkit")]
pub mod test_hooks;
#[cfg(feature = "testkit")]
pub mod testkit;

pub use error::{BoundaryError, Result};
pub use replay::replay_recording;
pub use session::NativeSession;

/// Starts logging once: `android_logger` (tag `noisecal`) on Android, `env_logger` to stderr on a
/// host (level from `RUST_LOG`, default `warn`).
pub fn init_logging() {
    static ONCE: std::sync::Once = std::sync::Once::new();
    ONCE.call_once(|| {
        #[cfg(target_os = "android")]
        android_logger::init_once(
            android_logger::Config::default().with_max_level(log::LevelFilter::Info).with_tag("noisecal"),
        );
        #[cfg(not(target_os = "android"))]
        {
            // Another logger already installed (the host program's own) is fine.
            let _ = env_logger::Builder::from_env(env_logger::Env::default().default_filter_or("warn"))
                .target(env_logger::Target::Stderr)
                .try_init();
        }
    });
}
