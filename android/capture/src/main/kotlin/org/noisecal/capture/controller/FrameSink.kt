package org.noisecal.capture.controller

import java.nio.ByteBuffer
import org.noisecal.capture.plan.SensorSpec

/**
 * One accepted RAW frame as it is handed to the sink: plane 0 of the image (valid only during
 * [FrameSink.pushFrame]), its geometry, and ISO / exposure / black levels as the capture result
 * reported them.
 */
class RawFrame(
    val buffer: ByteBuffer,
    val width: Int,
    val height: Int,
    val rowStride: Int,
    val pixelStride: Int,
    val iso: Int,
    val exposureNs: Long,
    val blackLevels: FloatArray?,
)

/** Coverage of one target ISO: bins that already have enough samples, out of all. */
data class IsoCoverage(val iso: Int, val frames: Long, val underSampledBins: Int, val totalBins: Int) {
    val filledFraction: Double get() = if (totalBins == 0) 0.0 else (totalBins - underSampledBins).toDouble() / totalBins
}

/** What a sink reports about itself (the session's progress). */
data class SinkProgress(val framesAccepted: Long, val framesRejected: Long, val steps: Int, val isos: List<IsoCoverage>)

/**
 * Where accepted frames go: the calibration session (see [org.noisecal.capture.sink.NoisecalFrameSink])
 * or a test double. Calls come from the controller's thread only.
 */
interface FrameSink : AutoCloseable {
    /** Begins an EV step; the reference burst that follows has [referenceExposureNs]. */
    fun beginStep(referenceExposureNs: Long)

    /**
     * Begins the dark step: every frame pushed until the next [beginStep] or [beginDark] was taken
     * with the lens covered, at the ISO its metadata reports (any number of ISOs, one burst each).
     */
    fun beginDark()

    /**
     * Folds one frame in and returns what the core made of it ([PushedFrame]: whether its
     * brightness drifted and was normalised, a target frame's motion). Throws (any
     * RuntimeException) when the frame is refused, leaving the sink unchanged; a frame of the dark
     * step that shows a scene (the lens is not covered) is refused with [LensNotCoveredException],
     * a target frame that moved too far (over 2 px) with [FrameMovedException].
     */
    fun pushFrame(frame: RawFrame): PushedFrame

    fun progress(): SinkProgress

    /** Writes a checkpoint from which [FrameSinkFactory.restore] resumes (temporary file, then rename). */
    fun checkpoint(path: String)

    /** Builds and writes the model pack; returns a one-line summary. */
    fun finish(packPath: String): String
}

/** Makes a fresh sink for a sensor, or restores one from a checkpoint. */
interface FrameSinkFactory {
    fun create(sensor: SensorSpec): FrameSink
    fun restore(checkpointPath: String): FrameSink
}

/**
 * A frame of the dark step was refused because it is not dark: light reaches the sensor (the lens
 * is not covered, or not fully). The controller answers it by asking the user to cover the lens
 * and taking the dark step again; [message] is the core's explanation.
 */
class LensNotCoveredException(message: String, cause: Throwable? = null) : RuntimeException(message, cause)

/**
 * What the core made of an accepted frame: [driftNormalised] its brightness drifted (flicker) and
 * was normalised; [motion] a target frame's motion against its reference burst, when the core
 * registered it (null for reference and dark frames, and where the chart has no edges).
 */
data class PushedFrame(val driftNormalised: Boolean, val motion: FrameMotion? = null)

/**
 * A target frame's motion as the core measured it: [shiftPx] its largest displacement anywhere
 * in the frame (pixels); [samples] the flat samples it added and [leftOut] those left out because
 * the motion changed their level (motion is not noise); [retake] the core's verdict that it moved
 * enough for its burst to be worth taking again.
 */
data class FrameMotion(val shiftPx: Double, val samples: Long, val leftOut: Long, val retake: Boolean)

/**
 * A target frame was refused because it moved too far against its reference burst (over 2 px).
 * The controller takes another frame, counts it against the burst's motion verdict
 * ([BurstMotion.framesRefused]); [message] is the core's (which burst, how far, what to do).
 */
class FrameMovedException(message: String, cause: Throwable? = null) : RuntimeException(message, cause)
