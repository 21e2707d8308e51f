package org.noisecal.jni

import java.nio.ByteBuffer

/**
 * The JNI boundary to the Rust calibration core (library `noisecal_jni`).
 *
 * One object owns one native session handle and closes it ([AutoCloseable]). Every native error
 * and every native panic arrives as a [NoisecalException] whose message says what was wrong; a
 * rejected frame leaves the session unchanged.
 *
 * This file is compiled both by the Android app and by the host JVM harness in `tests/jvm`. Its
 * `external` functions are declared once on the native side too, in rust/jni/src/jni_api.rs
 * (`NATIVE_METHODS`), in the same order.
 *
 * Threads: calls on one session are serialised natively (a per-session lock), so [pushFrame] on the
 * ImageReader thread and [progress] on the UI thread may overlap. A closed session throws
 * [NoisecalException] on every call.
 *
 * Kill and resume: [checkpoint] stores the session and, when recording, the recording's path and
 * length at that moment. [restore] reopens that recording, cuts it back to that length (the frames a
 * killed session pushed after its last checkpoint are gone from both) and keeps appending, so one
 * recording file still replays to the resumed session's pack. If the file is gone or shorter, the
 * session resumes without recording (logged).
 */
class NoisecalSession private constructor(@Volatile private var handle: Long) : AutoCloseable {

    /** Begins an EV step: the reference burst (at the reference ISO) that follows has this exposure. */
    fun beginStep(referenceExposureNs: Long) = nativeBeginStep(live(), referenceExposureNs)

    /**
     * Begins a dark step: every frame pushed from now until the next [beginStep] or [beginDark] was
     * taken with the lens covered, at the ISO its metadata reports (a short burst per ISO, any
     * number of ISOs). The core checks each one is really dark: a frame with a scene in it is
     * refused with [NoisecalNotDarkException] (the session unchanged), whose message tells the user
     * to cover the lens. Recorded like [beginStep].
     */
    fun beginDark() = nativeBeginDark(live())

    /**
     * Folds one RAW_SENSOR frame in, read in place (no copy) from the buffer's native memory. [buffer]
     * must be a direct ByteBuffer (`Image.planes[0].buffer`); the plane is read from the buffer's
     * start address over its capacity, whatever its position (Camera2 planes start at 0; pass
     * `buffer.slice()` to start elsewhere), as little-endian 16-bit samples. It must hold
     * `(height − 1) · rowStride + 2 · width` bytes and must not change during the call (an Image's
     * planes do not until it is closed).
     * [rowStride] and [pixelStride] in bytes as the plane reports them; [iso] and [exposureNs] as the
     * TotalCaptureResult reported them; [blackLevels] the per-frame dynamic black level (4 values,
     * CFA position order) or null. Returns what the core made of the frame ([FrameVerdict]):
     * whether its brightness drifted (flicker) and was normalised, and for a target frame its
     * motion against its reference burst. During a dark step ([beginDark]) a frame that is not
     * dark throws [NoisecalNotDarkException]; a target frame that moved too far (over 2 px) throws
     * [NoisecalMovedException] (the session unchanged).
     */
    fun pushFrame(
        buffer: ByteBuffer,
        width: Int,
        height: Int,
        rowStride: Int,
        pixelStride: Int,
        iso: Int,
        exposureNs: Long,
        blackLevels: FloatArray?,
    ): FrameVerdict = nativePushFrame(live(), buffer, width, height, rowStride, pixelStride, iso, exposureNs, blackLevels)

    /** Current progress of the session. */
    fun progress(): Progress = nativeProgress(live())

    /**
     * Levels per histogram bin of this session: the bin width its pack will have (the core's
     * [defaultBinWidth] for the sensor unless [create] was given another).
     */
    val binWidth: Int get() = nativeBinWidth(live())

    /**
     * Records the camera's own noise profile for an ISO (`SENSOR_NOISE_PROFILE`): [profile] holds 8
     * values, (S, O) for each CFA position in position order ((row % 2) * 2 + (col % 2)).
     */
    fun setNoiseProfile(iso: Int, profile: DoubleArray) = nativeSetNoiseProfile(live(), iso, profile)

    /** Writes a checkpoint (temporary file, then rename) from which [restore] resumes. */
    fun checkpoint(path: String) = nativeCheckpoint(live(), path)

    /**
     * Tees every accepted frame (exactly as handed over), every [beginStep], [beginDark] and
     * [setNoiseProfile] from now on into a recording file for desktop replay
     * (`noisecal calibrate session.rec` gives the same pack). Call it before the first [beginStep].
     */
    fun startRecording(path: String) = nativeStartRecording(live(), path)

    /**
     * Builds the model pack and writes it to [packPath] (temporary file, then rename). Returns a
     * one-line summary and the pack's conversion-gain call per gap ([Finished]). The session
     * stays usable; the recording is flushed and stays open.
     */
    fun finish(packPath: String): Finished = nativeFinish(live(), packPath)

    /** Frees the native session; ends the recording (its End record). Safe to call twice. */
    override fun close() {
        val h = handle
        handle = 0
        if (h != 0L) nativeClose(h)
    }

    private fun live(): Long {
        if (handle == 0L) throw NoisecalException("NoisecalSession is closed: create or restore a new one")
        return handle
    }

    /**
     * What the core made of an accepted frame: [driftNormalised] its brightness drifted and was
     * normalised. For a target frame the core registered on its reference burst ([registered]):
     * [shiftPx] its largest displacement anywhere in the frame (pixels), [samples] the flat samples
     * it added, [leftOut] the flat samples left out because the motion changed their level (motion
     * is not noise), and [retake] the core's verdict that the frame moved enough for its burst to
     * be worth taking again (a sturdier mount, OIS off, a remote trigger).
     *
     * Built by the native library through this constructor (rust/jni/src/jni_api.rs binds it),
     * like [Progress].
     */
    data class FrameVerdict(
        val driftNormalised: Boolean,
        val registered: Boolean,
        val shiftPx: Double,
        val samples: Long,
        val leftOut: Long,
        val retake: Boolean,
    )

    /**
     * What [finish] built: [summary] one line (ISOs, frames, warnings, bytes, path); [gapCalls]
     * what the pack says about each gap between neighbouring calibrated ISOs, as text in a stable
     * form (rust/jni/src/gap_calls.rs): a header line `noisecal-gap-calls 1`, then one line per gap
     * in ISO order, `BELOW ABOVE CALL` with CALL `switch` (a conversion-gain switch), `none` or
     * `undetermined` (the read noise at black of a side is not pinned). The capture library's
     * `GainGap.parseCalls` reads it for `GainGapFollowUp.propose`.
     *
     * Built by the native library through this constructor (rust/jni/src/jni_api.rs binds it),
     * like [Progress].
     */
    data class Finished(val summary: String, val gapCalls: String)

    /**
     * Per-ISO progress: target frames folded in, samples, bins still under-sampled of all bins.
     *
     * Built by the native library through this constructor (rust/jni/src/jni_api.rs binds it):
     * change the parameters there too; a mismatch fails the first [progress] call with a
     * [NoisecalException] (tests/jvm/jni checks it), never a silent misreading.
     */
    data class IsoProgress(val iso: Int, val frames: Long, val samples: Long, val underSampledBins: Int, val totalBins: Int)

    /** Session progress, built by the native library like [IsoProgress]. */
    data class Progress(
        val framesAccepted: Long,
        val framesRejected: Long,
        val steps: Int,
        val referenceFrames: Long,
        val isos: List<IsoProgress>,
    )

    companion object {
        init {
            System.loadLibrary("noisecal_jni")
        }

        /**
         * A new session for a sensor. [cfa] is "RGGB", "BGGR", "GRBG" or "GBRG"; [blackLevels] holds
         * 4 values in CFA position order ((row % 2) * 2 + (col % 2)); [referenceIso] is the sensor's
         * lowest ISO; [binWidth] 0 picks the core's [defaultBinWidth] for the sensor.
         */
        fun create(
            width: Int,
            height: Int,
            cfa: String,
            blackLevels: FloatArray,
            whiteLevel: Int,
            referenceIso: Int,
            make: String,
            model: String,
            binWidth: Int = 0,
        ): NoisecalSession =
            NoisecalSession(nativeCreate(width, height, cfa, blackLevels, whiteLevel, referenceIso, make, model, binWidth))

        /** Resumes a session from a checkpoint file. */
        fun restore(checkpointPath: String): NoisecalSession = NoisecalSession(nativeRestore(checkpointPath))

        /**
         * The core's default histogram bin width for a sensor (levels per bin), what a session
         * created with binWidth 0 uses and its pack records: about 240 bins between the lowest of
         * [blackLevels] (4 values) and [whiteLevel], rounded to a power of two (4 DN for a 10-bit
         * sensor with black 64, 16 at 12 bits, 64 at 14; docs/method.md). The rule lives in the
         * Rust core only.
         */
        fun defaultBinWidth(whiteLevel: Int, blackLevels: FloatArray): Int = nativeDefaultBinWidth(whiteLevel, blackLevels)

        @JvmStatic private external fun nativeCreate(
            width: Int, height: Int, cfa: String, blackLevels: FloatArray, whiteLevel: Int,
            referenceIso: Int, make: String, model: String, binWidth: Int,
        ): Long
        @JvmStatic private external fun nativeRestore(path: String): Long
        @JvmStatic private external fun nativeBeginStep(handle: Long, referenceExposureNs: Long)
        @JvmStatic private external fun nativeBeginDark(handle: Long)
        @JvmStatic private external fun nativePushFrame(
            handle: Long, buffer: ByteBuffer, width: Int, height: Int, rowStride: Int, pixelStride: Int,
            iso: Int, exposureNs: Long, blackLevels: FloatArray?,
        ): FrameVerdict
        @JvmStatic private external fun nativeSetNoiseProfile(handle: Long, iso: Int, profile: DoubleArray)
        @JvmStatic private external fun nativeProgress(handle: Long): Progress
        @JvmStatic private external fun nativeBinWidth(handle: Long): Int
        @JvmStatic private external fun nativeDefaultBinWidth(whiteLevel: Int, blackLevels: FloatArray): Int
        @JvmStatic private external fun nativeCheckpoint(handle: Long, path: String)
        @JvmStatic private external fun nativeStartRecording(handle: Long, path: String)
        @JvmStatic private external fun nativeFinish(handle: Long, packPath: String): Finished
        @JvmStatic private external fun nativeClose(handle: Long)
    }
}

/** Any failure inside the native core, with its message. */
open class NoisecalException(message: String) : RuntimeException(message)

/**
 * A frame pushed during a dark step ([NoisecalSession.beginDark]) has a scene in it: light reaches
 * the sensor. The message (the core's) tells the user to cover the lens; the session is unchanged.
 */
class NoisecalNotDarkException(message: String) : NoisecalException(message)

/**
 * A target frame moved too far against its reference burst (over 2 px): the core refused it (the
 * session unchanged). The message (the core's) names the burst, how far it moved and what to do:
 * a sturdier mount, optical stabilisation off, a remote trigger.
 */
class NoisecalMovedException(message: String) : NoisecalException(message)
