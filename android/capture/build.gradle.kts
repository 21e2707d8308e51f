// :capture — everything of the capture app that is not Camera2 or UI: the capture plan, the capture
// controller over a small camera interface, thermal policy, the simulated camera, and the JNI class
// (org.noisecal.jni.NoisecalSession). Plain Kotlin/JVM, so it is compiled and tested on a desktop
// too (tests/jvm/capture/run.sh) with nothing but the Kotlin standard library.
plugins {
    alias(libs.plugins.kotlin.jvm)
}

kotlin {
    jvmToolchain(libs.versions.jvm.get().toInt())
    // As on the host (tests/jvm/kotlin.sh compiles this module with -Werror): a warning fails the build.
    compilerOptions {
        allWarningsAsErrors = true
    }
}

dependencies {
    // Intentionally none beyond the Kotlin standard library (added by the Kotlin plugin).
}
