//! The `external` functions of `org.noisecal.jni.NoisecalSession` (static methods of that class:
//! Kotlin compiles the companion's `@JvmStatic private external fun`s to `private static native`
//! methods of `NoisecalSession`, checked with `javap`).
//!
//! One error policy at the edge: each function runs its body inside [`EnvUnowned::with_env`]
//! (which catches panics) and resolves the outcome with [`ThrowNoisecal`]: every [`BoundaryError`]
//! and every panic becomes an `org.noisecal.jni.NoisecalException` with the error's message, and
//! the function returns 0 / null. Nothing on this path unwraps.

use std::any::Any;

use jni::errors::ErrorPolicy;
use jni::objects::{JByteBuffer, JClass, JDoubleArray, JFloatArray, JLongArray, JObject, JString};
use jni::strings::JNIString;
use jni::sys::{jint, jlong};
use jni::{Env, EnvUnowned, jni_str};

use crate::error::{BoundaryError, Result};
use crate::files::checked_path;
use crate::registry;
use crate::session::{CreateParams, NativeSession, PlaneParams};

/// Whether `throw_new` threw: jni-rs reports a thrown exception as `Err(JavaException)`.
fn thrown(r: jni::errors::Result<()>) -> bool {
    matches!(r, Ok(()) | Err(jni::errors::Error::JavaException))
}

/// Throws `NoisecalException(message)`; falls back to `RuntimeException` if that class cannot be
/// found (a packaging error, named in the message).
fn throw_noisecal(env: &mut Env<'_>, message: &str) {
    let msg = JNIString::from(message);
    if thrown(env.throw_new(jni_str!("org/noisecal/jni/NoisecalException"), &msg)) {
        return;
    }
    env.exception_clear();
    let fallback = JNIString::from(format!(
        "{message} (org.noisecal.jni.NoisecalException is missing from the class path: package NoisecalSession.kt with the library)"
    ));
    if !thrown(env.throw_new(jni_str!("java/lang/RuntimeException"), &fallback)) {
        log::error!("could not throw an exception for: {message}");
    }
}

fn panic_message(payload: &(dyn Any + Send)) -> String {
    if let Some(s) = payload.downcast_ref::<&'static str>() {
        (*s).to_string()
    } else if let Some(s) = payload.downcast_ref::<String>() {
        s.clone()
    } else {
        "non-string panic payload".to_string()
    }
}

/// The boundary's error policy: see the module docs.
#[derive(Debug, Default)]
pub struct ThrowNoisecal;

impl<T: Default> ErrorPolicy<T, BoundaryError> for ThrowNoisecal {
    type Captures<'unowned_env_local: 'native_method, 'native_method> = ();

    fn on_error<'unowned_env_local: 'native_method, 'native_method>(
        env: &mut Env<'unowned_env_local>,
        _cap: &mut Self::Captures<'unowned_env_local, 'native_method>,
        err: BoundaryError,
    ) -> jni::errors::Result<T> {
        // A Java exception already pending (thrown by a JNI call, e.g. OutOfMemoryError) goes
        // to the caller as it is.
        if !env.exception_check() {
            log::debug!("noisecal: {err}");
            throw_noisecal(env, &err.to_string());
        }
        Ok(T::default())
    }

    fn on_panic<'unowned_env_local: 'native_method, 'native_method>(
        env: &mut Env<'unowned_env_local>,
        _cap: &mut Self::Captures<'unowned_env_local, 'native_method>,
        payload: Box<dyn Any + Send + 'static>,
    ) -> jni::errors::Result<T> {
        let what = panic_message(payload.as_ref());
        // Dropping a payload may itself panic: leak it rather than risk unwinding into the JVM.
        std::mem::forget(payload);
        let message = format!(
            "internal error in the noisecal native core (panic: {what}); the session is unusable: close it and restore from the last checkpoint"
        );
        log::error!("{message}");
        if env.exception_check() {
            env.exception_clear();
        }
        throw_noisecal(env, &message);
        Ok(T::default())
    }
}

fn string(env: &Env<'_>, s: &JString<'_>, name: &'static str) -> Result<String> {
    if s.is_null() {
        return Err(BoundaryError::arg(name, "null", "pass a string"));
    }
    Ok(s.try_to_string(env)?)
}

fn floats(env: &Env<'_>, a: &JFloatArray<'_>) -> Result<Option<Vec<f32>>> {
    if a.is_null() {
        return Ok(None);
    }
    let n = a.len(env)?;
    let mut v = vec![0f32; n];
    a.get_region(env, 0, &mut v)?;
    Ok(Some(v))
}

#[unsafe(no_mangle)]
pub extern "system" fn Java_org_noisecal_jni_NoisecalSession_nativeCreate<'local>(
    mut unowned: EnvUnowned<'local>,
    _class: JClass<'local>,
    width: jint,
    height: jint,
    cfa: JString<'local>,
    black_levels: JFloatArray<'local>,
    white_level: jint,
    reference_iso: jint,
    make: JString<'local>,
    model: JString<'local>,
    bin_width: jint,
) -> jlong {
    unowned
        .with_env(|env| -> Result<jlong> {
            crate::init_logging();
            let cfa = string(env, &cfa, "cfa")?;
            let black = floats(env, &black_levels)?
                .ok_or_else(|| BoundaryError::arg("blackLevels", "null", "pass 4 values in CFA position order"))?;
            let make = string(env, &make, "make")?;
            let model = string(env, &model, "model")?;
            let session = NativeSession::create(&CreateParams {
                width,
                height,
                cfa: &cfa,
                black: &black,
                white: white_level,
                reference_iso,
                make: &make,
                model: &model,
                bin_width,
            })?;
            let handle = registry::insert(session);
            log::info!(
                "session {handle} created: {width}×{height} {cfa}, reference ISO {reference_iso}, {make} {model}"
            );
            Ok(handle)
        })
        .resolve::<ThrowNoisecal>()
}

#[unsafe(no_mangle)]
pub extern "system" fn Java_org_noisecal_jni_NoisecalSession_nativeRestore<'local>(
    mut unowned: EnvUnowned<'local>,
    _class: JClass<'local>,
    path: JString<'local>,
) -> jlong {
    unowned
        .with_env(|env| -> Result<jlong> {
            crate::init_logging();
            let path = checked_path(&string(env, &path, "checkpointPath")?)?;
            let session = NativeSession::restore_file(&path)?;
            let handle = registry::insert(session);
            log::info!("session {handle} restored from {}", path.display());
            Ok(handle)
        })
        .resolve::<ThrowNoisecal>()
}

#[unsafe(no_mangle)]
pub extern "system" fn Java_org_noisecal_jni_NoisecalSession_nativeBeginStep<'local>(
    mut unowned: EnvUnowned<'local>,
    _class: JClass<'local>,
    handle: jlong,
    reference_exposure_ns: jlong,
) {
    unowned
        .with_env(|_env| -> Result<()> { registry::with(handle, |s| s.begin_step(reference_exposure_ns)) })
        .resolve::<ThrowNoisecal>()
}

/// Bit 0 of `nativePushFrame`'s result: the frame's brightness drifted and was normalised.
pub const VERDICT_DRIFT_NORMALISED: jint = 1;

/// Folds in one frame, read in place from the direct buffer's memory (no copy).
///
/// The plane starts at the buffer's *address* (`GetDirectBufferAddress`), whatever its
/// `position()`, and spans its `capacity()`: Camera2's `Image.Plane.getBuffer()` is positioned at
/// 0 and its row stride counts from the start, so this is what the app means; a caller that
/// wants an offset passes `buffer.slice()`, whose address starts there. The byte order is little
/// endian whatever `ByteBuffer.order()` says (that flag only affects Java-side getters).
/// The buffer must not be written by another thread during the call (an `Image` is not until it
/// is closed).
#[unsafe(no_mangle)]
pub extern "system" fn Java_org_noisecal_jni_NoisecalSession_nativePushFrame<'local>(
    mut unowned: EnvUnowned<'local>,
    _class: JClass<'local>,
    handle: jlong,
    buffer: JByteBuffer<'local>,
    width: jint,
    height: jint,
    row_stride: jint,
    pixel_stride: jint,
    iso: jint,
    exposure_ns: jlong,
    black_levels: JFloatArray<'local>,
) -> jint {
    unowned
        .with_env(|env| -> Result<jint> {
            if buffer.is_null() {
                return Err(BoundaryError::NullBuffer);
            }
            let black = floats(env, &black_levels)?;
            // A heap buffer has no address (JNI returns null) and capacity -1.
            let addr = env.get_direct_buffer_address(&buffer).map_err(|_| BoundaryError::NotDirect)?;
            let capacity = env.get_direct_buffer_capacity(&buffer).map_err(|_| BoundaryError::NotDirect)?;
            if addr.is_null() {
                return Err(BoundaryError::NotDirect);
            }
            // SAFETY: `addr` is the start of the direct buffer's memory, `capacity` bytes long
            // (JNI contract). The local reference `buffer` keeps the buffer, and so its memory,
            // alive until this native method returns, which outlives `plane`. We only read.
            let plane: &[u8] = unsafe { std::slice::from_raw_parts(addr.cast_const(), capacity) };
            let params =
                PlaneParams { width, height, row_stride, pixel_stride, iso, exposure_ns, black: black.as_deref() };
            let report = registry::with(handle, |s| s.push_plane(plane, &params))?;
            Ok(if report.drift_normalised { VERDICT_DRIFT_NORMALISED } else { 0 })
        })
        .resolve::<ThrowNoisecal>()
}

#[unsafe(no_mangle)]
pub extern "system" fn Java_org_noisecal_jni_NoisecalSession_nativeSetNoiseProfile<'local>(
    mut unowned: EnvUnowned<'local>,
    _class: JClass<'local>,
    handle: jlong,
    iso: jint,
    profile: JDoubleArray<'local>,
) {
    unowned
        .with_env(|env| -> Result<()> {
            if profile.is_null() {
                return Err(BoundaryError::arg("noise profile", "null", "pass 8 values: (S, O) per CFA position"));
            }
            let mut values = vec![0f64; profile.len(env)?];
            profile.get_region(env, 0, &mut values)?;
            registry::with(handle, |s| s.set_noise_profile(iso, &values))
        })
        .resolve::<ThrowNoisecal>()
}

#[unsafe(no_mangle)]
pub extern "system" fn Java_org_noisecal_jni_NoisecalSession_nativeProgress<'local>(
    mut unowned: EnvUnowned<'local>,
    _class: JClass<'local>,
    handle: jlong,
) -> JLongArray<'local> {
    unowned
        .with_env(|env| -> Result<JLongArray<'local>> {
            let values = registry::with(handle, |s| Ok(s.progress_array()))?;
            let array = env.new_long_array(values.len())?;
            array.set_region(env, 0, &values)?;
            Ok(array)
        })
        .resolve::<ThrowNoisecal>()
}

#[unsafe(no_mangle)]
pub extern "system" fn Java_org_noisecal_jni_NoisecalSession_nativeCheckpoint<'local>(
    mut unowned: EnvUnowned<'local>,
    _class: JClass<'local>,
    handle: jlong,
    path: JString<'local>,
) {
    unowned
        .with_env(|env| -> Result<()> {
            let path = checked_path(&string(env, &path, "path")?)?;
            registry::with(handle, |s| s.checkpoint_file(&path))
        })
        .resolve::<ThrowNoisecal>()
}

#[unsafe(no_mangle)]
pub extern "system" fn Java_org_noisecal_jni_NoisecalSession_nativeStartRecording<'local>(
    mut unowned: EnvUnowned<'local>,
    _class: JClass<'local>,
    handle: jlong,
    path: JString<'local>,
) {
    unowned
        .with_env(|env| -> Result<()> {
            let path = checked_path(&string(env, &path, "path")?)?;
            registry::with(handle, |s| s.start_recording(&path))
        })
        .resolve::<ThrowNoisecal>()
}

#[unsafe(no_mangle)]
pub extern "system" fn Java_org_noisecal_jni_NoisecalSession_nativeFinish<'local>(
    mut unowned: EnvUnowned<'local>,
    _class: JClass<'local>,
    handle: jlong,
    pack_path: JString<'local>,
) -> JObject<'local> {
    unowned
        .with_env(|env| -> Result<JObject<'local>> {
            let path = checked_path(&string(env, &pack_path, "packPath")?)?;
            let summary = registry::with(handle, |s| s.finish_to(&path))?;
            log::info!("session {handle}: {summary}");
            Ok(env.new_string(summary)?.into())
        })
        .resolve::<ThrowNoisecal>()
}

#[unsafe(no_mangle)]
pub extern "system" fn Java_org_noisecal_jni_NoisecalSession_nativeClose<'local>(
    mut unowned: EnvUnowned<'local>,
    _class: JClass<'local>,
    handle: jlong,
) {
    unowned
        .with_env(|_env| -> Result<()> {
            if let Some(session) = registry::remove(handle)? {
                session.close()?;
            }
            log::info!("session {handle} closed");
            Ok(())
        })
        .resolve::<ThrowNoisecal>()
}
