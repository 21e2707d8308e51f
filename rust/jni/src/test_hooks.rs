//! Host-only hooks for the JVM harness (`tests/jvm/jni`): not compiled for Android.
//!
//! `org.noisecal.jni.test.NativeHooks.panicInSession(handle)` panics inside a session's lock, to
//! check that a panic reaches Kotlin as a `NoisecalException`, that the poisoned session is then
//! refused with a clear message, and that it still closes.

use jni::EnvUnowned;
use jni::objects::JClass;
use jni::sys::jlong;

use crate::error::Result;
use crate::jni_api::ThrowNoisecal;
use crate::registry;

#[unsafe(no_mangle)]
pub extern "system" fn Java_org_noisecal_jni_test_NativeHooks_panicInSession<'local>(
    mut unowned: EnvUnowned<'local>,
    _class: JClass<'local>,
    handle: jlong,
) {
    unowned
        .with_env(|_env| -> Result<()> {
            registry::with(handle, |_session| -> Result<()> { panic!("deliberate panic from the test hook") })
        })
        .resolve::<ThrowNoisecal>()
}

#[unsafe(no_mangle)]
pub extern "system" fn Java_org_noisecal_jni_test_NativeHooks_liveSessions<'local>(
    mut unowned: EnvUnowned<'local>,
    _class: JClass<'local>,
) -> jlong {
    unowned.with_env(|_env| -> Result<jlong> { Ok(registry::live() as jlong) }).resolve::<ThrowNoisecal>()
}
