package org.noisecal.capture.controller

import java.nio.ByteBuffer
import org.noisecal.capture.plan.Burst

/**
 * Neutral manual settings of one request. The Camera2 adapter maps every field to its key:
 * `CONTROL_MODE`/`CONTROL_AE_MODE`/`CONTROL_AF_MODE`/`CONTROL_AWB_MODE` OFF, `LENS_FOCUS_DISTANCE`,
 * `SENSOR_SENSITIVITY`, `SENSOR_EXPOSURE_TIME`, `SENSOR_FRAME_DURATION`, `NOISE_REDUCTION_MODE`,
 * `HOT_PIXEL_MODE` and `EDGE_MODE` OFF, `CONTROL_POST_RAW_SENSITIVITY_BOOST` 100, `BLACK_LEVEL_LOCK`.
 * The defaults are the only values a calibration uses; they are spelled out so an adapter cannot
 * silently forget one.
 */
data class ManualSettings(
    val iso: Int,
    val exposureNs: Long,
    val frameDurationNs: Long,
    /** Fixed focus distance in diopters (0 = infinity); null leaves the lens where the preview left it. */
    val focusDistanceDiopters: Float? = null,
    val autoExposure: Boolean = false,
    val autoFocus: Boolean = false,
    val autoWhiteBalance: Boolean = false,
    val noiseReduction: Boolean = false,
    val hotPixelCorrection: Boolean = false,
    val edgeEnhancement: Boolean = false,
    /** `CONTROL_POST_RAW_SENSITIVITY_BOOST`: 100 means none. */
    val postRawSensitivityBoost: Int = 100,
    val blackLevelLock: Boolean = true,
) {
    companion object {
        fun forBurst(b: Burst, focusDistanceDiopters: Float? = null) =
            ManualSettings(b.iso, b.exposureNs, b.frameDurationNs, focusDistanceDiopters)
    }
}

/** One capture request: [tag] comes back in the matching [FrameResult] (Camera2 `CaptureRequest.Builder.setTag`). */
data class FrameRequest(val tag: Long, val settings: ManualSettings)

/**
 * What the camera reported for one frame (`TotalCaptureResult`).
 * [timestampNs] is `SENSOR_TIMESTAMP`, equal to the matching [ImageHandle.timestampNs].
 * [dynamicBlackLevels] is `SENSOR_DYNAMIC_BLACK_LEVEL` (4 values, CFA position order) when reported.
 */
class FrameResult(
    val tag: Long,
    val timestampNs: Long,
    val iso: Int,
    val exposureNs: Long,
    val frameDurationNs: Long? = null,
    val dynamicBlackLevels: FloatArray? = null,
) {
    override fun toString(): String =
        "FrameResult(tag=$tag, t=$timestampNs, iso=$iso, exp=$exposureNs, black=${dynamicBlackLevels?.toList()})"
}

/**
 * One RAW_SENSOR image held by the camera's reader. [buffer] (plane 0) is valid until [close];
 * every handle must be closed exactly once, or the reader runs out of images.
 */
interface ImageHandle {
    val timestampNs: Long
    val width: Int
    val height: Int
    val buffer: ByteBuffer
    val rowStride: Int
    val pixelStride: Int
    fun close()
}

/** Where a port delivers what the camera produces. Calls may come from any thread. */
interface CameraEventSink {
    fun onImage(image: ImageHandle)
    fun onResult(result: FrameResult)
    /** The request with [tag] produced no result (`onCaptureFailed`); an image may still arrive if [imageCaptured]. */
    fun onFailure(tag: Long, reason: String, imageCaptured: Boolean)
    /** The device is gone or broken (`CameraDevice.StateCallback.onError` / `onDisconnected`). */
    fun onDeviceError(message: String)
}

/**
 * The small camera interface the controller drives: implemented by the Camera2 adapter in `:app`
 * and by [org.noisecal.capture.sim.SimulatedCameraPort] on the host.
 */
interface CameraDevicePort {
    /** The RAW reader's `maxImages`. */
    val maxImages: Int

    /** Starts delivering events to [events]; called once, before the first [submit]. */
    fun start(events: CameraEventSink)

    /** Queues these requests in order (Camera2 `capture`/`captureBurst`). */
    fun submit(requests: List<FrameRequest>)

    /** Stops delivering events and drops what is queued (`abortCaptures`). Safe to call twice. */
    fun stop()
}
