//! The native methods of `org.noisecal.jni.NoisecalSession`, each declared once, in
//! [`NATIVE_METHODS`], with jni's `native_method!`: its Java name, its JNI signature (checked at
//! compile time against the Rust function that implements it), its export under the JNI name the
//! JVM resolves (`Java_org_noisecal_jni_NoisecalSession_<name>__<argument signature>`, so
//! `System.loadLibrary` suffices; the table also serves `RegisterNatives`) and its error policy.
//! They are static methods of that class: Kotlin compiles the companion's
//! `@JvmStatic private external fun`s to `private static native` methods of `NoisecalSession`
//! (checked with `javap`), and each method checks that once at its first call.
//!
//! One error policy at the edge, [`ThrowNoisecal`]: every body runs inside
//! `EnvUnowned::with_env` (which catches panics), and every [`BoundaryError`] and every panic
//! becomes an `org.noisecal.jni.NoisecalException` carrying the error's message (the core's own
//! message for a core error); the method then returns 0 / null. A dark frame with a scene in it
//! (`SessionError::NotDark`) throws its subclass `org.noisecal.jni.NoisecalNotDarkException`, so
//! the app can tell "cover the lens" from other refusals without reading the message; a frame
//! that moved too far (`SessionError::Moved`) throws `org.noisecal.jni.NoisecalMovedException`. No Rust panic crosses into the
//! JVM, and nothing on this path unwraps.
//!
//! A pushed frame's verdict crosses as `NoisecalSession.FrameVerdict` (drift, motion, samples
//! left out, re-take), and a finished session's summary with its gap calls as
//! `NoisecalSession.Finished` ([`crate::gap_calls`]), built the same way. Progress crosses as a Kotlin object, `NoisecalSession.Progress` with its
//! `NoisecalSession.IsoProgress` list, constructed here through bindings of their constructors
//! (`bind_java_type!`): the Kotlin classes are the one definition of the type, and a constructor
//! that no longer matches fails loudly at the first call (a `NoisecalException` naming it), never
//! as numbers read at the wrong positions.

use std::any::Any;

use jni::errors::ErrorPolicy;
use jni::objects::{JByteBuffer, JClass, JDoubleArray, JFloatArray, JString};
use jni::strings::JNIString;
use jni::sys::{jint, jlong};
use jni::{Env, NativeMethod, jni_str, native_method};

use noisecal_core::error::SessionError;

use crate::error::{BoundaryError, Result};
use crate::files::checked_path;
use crate::registry;
use crate::session::{CreateParams, NativeSession, PlaneParams, default_bin_width};

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
    throw_fallback(env, message);
}

/// Throws what `err` is at the edge: `NoisecalNotDarkException` for a dark frame that is not
/// dark, `NoisecalMovedException` for a frame that moved too far, `NoisecalException` for
/// everything else.
fn throw_error(env: &mut Env<'_>, err: &BoundaryError) {
    let message = err.to_string();
    let subclass = match err {
        BoundaryError::Session(SessionError::NotDark { .. }) => {
            Some(jni_str!("org/noisecal/jni/NoisecalNotDarkException"))
        }
        BoundaryError::Session(SessionError::Moved { .. }) => Some(jni_str!("org/noisecal/jni/NoisecalMovedException")),
        _ => None,
    };
    if let Some(class) = subclass {
        let msg = JNIString::from(message.as_str());
        if thrown(env.throw_new(class, &msg)) {
            return;
        }
        env.exception_clear();
    }
    throw_noisecal(env, &message);
}

fn throw_fallback(env: &mut Env<'_>, message: &str) {
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
            throw_error(env, &err);
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

/// `native_method!` with what every method of `NoisecalSession` shares: the class and the error
/// policy.
macro_rules! session_method {
    ($($spec:tt)*) => {
        native_method! {
            java_type = "org.noisecal.jni.NoisecalSession",
            type_map = {
                JProgress => "org.noisecal.jni.NoisecalSession$Progress",
                JFrameVerdict => "org.noisecal.jni.NoisecalSession$FrameVerdict",
                JFinished => "org.noisecal.jni.NoisecalSession$Finished",
            },
            error_policy = ThrowNoisecal,
            $($spec)*
        }
    };
}

/// Every native method of `NoisecalSession`, in the order the Kotlin class declares them.
pub const NATIVE_METHODS: &[NativeMethod<'_>] = &[
    session_method! {
        static extern fn native_create(
            width: jint, height: jint, cfa: JString, black_levels: jfloat[], white_level: jint,
            reference_iso: jint, make: JString, model: JString, bin_width: jint,
        ) -> jlong,
    },
    session_method! { static extern fn native_restore(path: JString) -> jlong },
    session_method! { static extern fn native_begin_step(handle: jlong, reference_exposure_ns: jlong) },
    session_method! { static extern fn native_begin_dark(handle: jlong) },
    session_method! {
        static extern fn native_push_frame(
            handle: jlong, buffer: java.nio.ByteBuffer, width: jint, height: jint, row_stride: jint,
            pixel_stride: jint, iso: jint, exposure_ns: jlong, black_levels: jfloat[],
        ) -> JFrameVerdict,
    },
    session_method! { static extern fn native_set_noise_profile(handle: jlong, iso: jint, profile: jdouble[]) },
    session_method! { static extern fn native_progress(handle: jlong) -> JProgress },
    session_method! { static extern fn native_bin_width(handle: jlong) -> jint },
    session_method! { static extern fn native_default_bin_width(white_level: jint, black_levels: jfloat[]) -> jint },
    session_method! { static extern fn native_checkpoint(handle: jlong, path: JString) },
    session_method! { static extern fn native_start_recording(handle: jlong, path: JString) },
    session_method! { static extern fn native_finish(handle: jlong, pack_path: JString) -> JFinished },
    session_method! { static extern fn native_close(handle: jlong) },
];

/// Bindings of the Kotlin classes progress is made of (and of the list that holds them).
mod bindings {
    // The generated code names the binding types without their lifetime.
    #![allow(elided_lifetimes_in_paths)]

    use jni::bind_java_type;

    bind_java_type! {
        rust_type = JProgress,
        rust_type_vis = pub(super),
        java_type = "org.noisecal.jni.NoisecalSession$Progress",
        constructors {
            fn new(frames_accepted: jlong, frames_rejected: jlong, steps: jint, reference_frames: jlong, isos: JList),
        },
    }

    bind_java_type! {
        rust_type = JIsoProgress,
        rust_type_vis = pub(super),
        java_type = "org.noisecal.jni.NoisecalSession$IsoProgress",
        constructors {
            fn new(iso: jint, frames: jlong, samples: jlong, under_sampled_bins: jint, total_bins: jint),
        },
    }

    bind_java_type! {
        rust_type = JFrameVerdict,
        rust_type_vis = pub(super),
        java_type = "org.noisecal.jni.NoisecalSession$FrameVerdict",
        constructors {
            fn new(drift_normalised: jboolean, registered: jboolean, shift_px: jdouble, samples: jlong, left_out: jlong, retake: jboolean),
        },
    }

    bind_java_type! {
        rust_type = JFinished,
        rust_type_vis = pub(super),
        java_type = "org.noisecal.jni.NoisecalSession$Finished",
        constructors {
            fn new(summary: JString, gap_calls: JString),
        },
    }

    bind_java_type! {
        rust_type = JArrayList,
        rust_type_vis = pub(super),
        java_type = java.util.ArrayList,
        is_instance_of = { list: JList },
        constructors {
            fn with_capacity { sig = (capacity: jint) },
        },
    }
}

use bindings::{JArrayList, JFinished, JFrameVerdict, JIsoProgress, JProgress};

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

fn black_levels(env: &Env<'_>, a: &JFloatArray<'_>) -> Result<Vec<f32>> {
    floats(env, a)?.ok_or_else(|| BoundaryError::arg("blackLevels", "null", "pass 4 values in CFA position order"))
}

/// A count for a Kotlin `Long` (saturating) or `Int` (saturating).
fn long(v: u64) -> jlong {
    jlong::try_from(v).unwrap_or(jlong::MAX)
}

fn int(v: impl TryInto<jint>) -> jint {
    v.try_into().unwrap_or(jint::MAX)
}

fn native_create<'local>(
    env: &mut Env<'local>,
    _class: JClass<'local>,
    width: jint,
    height: jint,
    cfa: JString<'local>,
    black: JFloatArray<'local>,
    white_level: jint,
    reference_iso: jint,
    make: JString<'local>,
    model: JString<'local>,
    bin_width: jint,
) -> Result<jlong> {
    crate::init_logging();
    let cfa = string(env, &cfa, "cfa")?;
    let black = black_levels(env, &black)?;
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
    log::info!("session {handle} created: {width}×{height} {cfa}, reference ISO {reference_iso}, {make} {model}");
    Ok(handle)
}

fn native_restore<'local>(env: &mut Env<'local>, _class: JClass<'local>, path: JString<'local>) -> Result<jlong> {
    crate::init_logging();
    let path = checked_path(&string(env, &path, "checkpointPath")?)?;
    let session = NativeSession::restore_file(&path)?;
    let handle = registry::insert(session);
    log::info!("session {handle} restored from {}", path.display());
    Ok(handle)
}

fn native_begin_step<'local>(
    _env: &mut Env<'local>,
    _class: JClass<'local>,
    handle: jlong,
    reference_exposure_ns: jlong,
) -> Result<()> {
    registry::with(handle, |s| s.begin_step(reference_exposure_ns))
}

/// Begins a dark (lens-covered) step; recorded like `native_begin_step`.
fn native_begin_dark<'local>(_env: &mut Env<'local>, _class: JClass<'local>, handle: jlong) -> Result<()> {
    registry::with(handle, |s| s.begin_dark())
}

/// Folds in one frame, read in place from the direct buffer's memory (no copy), and returns the
/// core's report of it as a `NoisecalSession.FrameVerdict` (drift; a target frame's motion,
/// samples left out and whether its burst is worth taking again: `FrameReport::retake`).
///
/// The plane starts at the buffer's *address* (`GetDirectBufferAddress`), whatever its
/// `position()`, and spans its `capacity()`: Camera2's `Image.Plane.getBuffer()` is positioned at
/// 0 and its row stride counts from the start, so this is what the app means; a caller that
/// wants an offset passes `buffer.slice()`, whose address starts there. The byte order is little
/// endian whatever `ByteBuffer.order()` says (that flag only affects Java-side getters).
/// The buffer must not be written by another thread during the call (an `Image` is not until it
/// is closed).
fn native_push_frame<'local>(
    env: &mut Env<'local>,
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
) -> Result<JFrameVerdict<'local>> {
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
    // SAFETY: `addr` is the start of the direct buffer's memory, `capacity` bytes long (JNI
    // contract). The local reference `buffer` keeps the buffer, and so its memory, alive until
    // this native method returns, which outlives `plane`. We only read.
    let plane: &[u8] = unsafe { std::slice::from_raw_parts(addr.cast_const(), capacity) };
    let params = PlaneParams { width, height, row_stride, pixel_stride, iso, exposure_ns, black: black.as_deref() };
    let report = registry::with(handle, |s| s.push_plane(plane, &params))?;
    Ok(JFrameVerdict::new(
        env,
        report.drift_normalised,
        report.motion.is_some(),
        report.shift_px().unwrap_or(0.0),
        long(report.samples),
        long(report.left_out),
        report.retake(),
    )?)
}

fn native_set_noise_profile<'local>(
    env: &mut Env<'local>,
    _class: JClass<'local>,
    handle: jlong,
    iso: jint,
    profile: JDoubleArray<'local>,
) -> Result<()> {
    if profile.is_null() {
        return Err(BoundaryError::arg("noise profile", "null", "pass 8 values: (S, O) per CFA position"));
    }
    let mut values = vec![0f64; profile.len(env)?];
    profile.get_region(env, 0, &mut values)?;
    registry::with(handle, |s| s.set_noise_profile(iso, &values))
}

fn native_progress<'local>(env: &mut Env<'local>, _class: JClass<'local>, handle: jlong) -> Result<JProgress<'local>> {
    let p = registry::with(handle, |s| Ok(s.progress()))?;
    let isos = JArrayList::with_capacity(env, int(p.isos.len()))?;
    for i in &p.isos {
        let item = JIsoProgress::new(
            env,
            int(i.iso),
            long(i.frames),
            long(i.samples),
            int(i.under_sampled_bins),
            int(i.total_bins),
        )?;
        isos.as_list().add(env, &item)?;
        env.delete_local_ref(item);
    }
    Ok(JProgress::new(
        env,
        long(p.frames_accepted),
        long(p.frames_rejected),
        int(p.steps),
        long(p.reference_frames),
        isos.as_list(),
    )?)
}

fn native_bin_width<'local>(_env: &mut Env<'local>, _class: JClass<'local>, handle: jlong) -> Result<jint> {
    registry::with(handle, |s| Ok(s.bin_width() as jint))
}

fn native_default_bin_width<'local>(
    env: &mut Env<'local>,
    _class: JClass<'local>,
    white_level: jint,
    black: JFloatArray<'local>,
) -> Result<jint> {
    Ok(default_bin_width(white_level, &black_levels(env, &black)?)? as jint)
}

fn native_checkpoint<'local>(
    env: &mut Env<'local>,
    _class: JClass<'local>,
    handle: jlong,
    path: JString<'local>,
) -> Result<()> {
    let path = checked_path(&string(env, &path, "path")?)?;
    registry::with(handle, |s| s.checkpoint_file(&path))
}

fn native_start_recording<'local>(
    env: &mut Env<'local>,
    _class: JClass<'local>,
    handle: jlong,
    path: JString<'local>,
) -> Result<()> {
    let path = checked_path(&string(env, &path, "path")?)?;
    registry::with(handle, |s| s.start_recording(&path))
}

/// Builds and writes the pack; returns a `NoisecalSession.Finished`: the one-line summary and
/// the pack's conversion-gain call per gap between calibrated ISOs ([`crate::gap_calls`]).
fn native_finish<'local>(
    env: &mut Env<'local>,
    _class: JClass<'local>,
    handle: jlong,
    pack_path: JString<'local>,
) -> Result<JFinished<'local>> {
    let path = checked_path(&string(env, &pack_path, "packPath")?)?;
    let done = registry::with(handle, |s| s.finish_with_gaps(&path))?;
    log::info!("session {handle}: {}", done.summary);
    let summary = JString::from_str(env, &done.summary)?;
    let gap_calls = JString::from_str(env, &done.gap_calls)?;
    Ok(JFinished::new(env, &summary, &gap_calls)?)
}

fn native_close<'local>(_env: &mut Env<'local>, _class: JClass<'local>, handle: jlong) -> Result<()> {
    if let Some(session) = registry::remove(handle)? {
        session.close()?;
    }
    log::info!("session {handle} closed");
    Ok(())
}
