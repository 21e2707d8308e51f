package org.noisecal.app.camera

import android.graphics.ImageFormat
import android.graphics.SurfaceTexture
import android.hardware.camera2.CameraAccessException
import android.hardware.camera2.CameraCharacteristics
import android.hardware.camera2.CameraManager
import android.os.Build
import android.util.Size
import android.view.SurfaceHolder
import org.noisecal.capture.controller.CameraChoice
import org.noisecal.capture.controller.CameraFacing
import org.noisecal.capture.controller.FrameSize
import org.noisecal.capture.plan.CameraCapabilities
import org.noisecal.capture.plan.CapturePlanner
import kotlin.math.abs

/**
 * Reads `CameraCharacteristics` into the plain [CameraChoice] / [CameraCapabilities] of `:capture`
 * (which camera to use is [CameraChoice.choose]'s decision, tested on the host).
 */
object Camera2Capabilities {

    fun readAll(manager: CameraManager): List<CameraChoice> =
        try {
            manager.cameraIdList.map { read(manager, it) }
        } catch (e: CameraAccessException) {
            emptyList()
        }

    fun read(manager: CameraManager, id: String): CameraChoice {
        val ch = try {
            manager.getCameraCharacteristics(id)
        } catch (e: CameraAccessException) {
            return CameraChoice(id, CameraFacing.UNKNOWN, null, null, listOf("camera $id cannot be read: ${e.message}"))
        } catch (e: IllegalArgumentException) {
            return CameraChoice(id, CameraFacing.UNKNOWN, null, null, listOf("camera $id does not exist: ${e.message}"))
        }
        val facing = when (ch.get(CameraCharacteristics.LENS_FACING)) {
            CameraCharacteristics.LENS_FACING_BACK -> CameraFacing.BACK
            CameraCharacteristics.LENS_FACING_FRONT -> CameraFacing.FRONT
            CameraCharacteristics.LENS_FACING_EXTERNAL -> CameraFacing.EXTERNAL
            else -> CameraFacing.UNKNOWN
        }
        val caps = ch.get(CameraCharacteristics.REQUEST_AVAILABLE_CAPABILITIES) ?: IntArray(0)
        val map = ch.get(CameraCharacteristics.SCALER_STREAM_CONFIGURATION_MAP)
        val rawSize = map?.getOutputSizes(ImageFormat.RAW_SENSOR)?.maxByOrNull { it.width.toLong() * it.height }
        val minFrame = if (map != null && rawSize != null) map.getOutputMinFrameDuration(ImageFormat.RAW_SENSOR, rawSize) else 0L
        val sensitivity = ch.get(CameraCharacteristics.SENSOR_INFO_SENSITIVITY_RANGE)
        val exposure = ch.get(CameraCharacteristics.SENSOR_INFO_EXPOSURE_TIME_RANGE)
        val pattern = ch.get(CameraCharacteristics.SENSOR_BLACK_LEVEL_PATTERN)
        // CFA position (row % 2) * 2 + (col % 2); BlackLevelPattern.getOffsetForIndex takes (column, row).
        val black = if (pattern != null) {
            listOf(pattern.getOffsetForIndex(0, 0), pattern.getOffsetForIndex(1, 0), pattern.getOffsetForIndex(0, 1), pattern.getOffsetForIndex(1, 1))
        } else {
            emptyList()
        }
        val early = buildList {
            if (sensitivity == null) add("camera $id reports no sensitivity range")
            if (exposure == null) add("camera $id reports no exposure time range")
            if (rawSize == null) add("camera $id has no RAW_SENSOR output")
        }
        if (sensitivity == null || exposure == null) return CameraChoice(id, facing, null, null, early)

        val capabilities = CameraCapabilities(
            cameraId = id,
            make = Build.MANUFACTURER,
            model = Build.MODEL,
            sensitivityRange = sensitivity.lower..sensitivity.upper,
            maxAnalogSensitivity = ch.get(CameraCharacteristics.SENSOR_MAX_ANALOG_SENSITIVITY),
            exposureRangeNs = exposure.lower..exposure.upper,
            maxFrameDurationNs = ch.get(CameraCharacteristics.SENSOR_INFO_MAX_FRAME_DURATION),
            minFrameDurationNs = minFrame,
            rawWidth = rawSize?.width ?: 0,
            rawHeight = rawSize?.height ?: 0,
            whiteLevel = ch.get(CameraCharacteristics.SENSOR_INFO_WHITE_LEVEL) ?: 0,
            blackLevelPattern = black,
            cfaCode = ch.get(CameraCharacteristics.SENSOR_INFO_COLOR_FILTER_ARRANGEMENT) ?: -1,
            manualSensor = CameraCharacteristics.REQUEST_AVAILABLE_CAPABILITIES_MANUAL_SENSOR in caps,
            raw = CameraCharacteristics.REQUEST_AVAILABLE_CAPABILITIES_RAW in caps && rawSize != null,
            lensShadingAppliedToRaw = ch.get(CameraCharacteristics.SENSOR_INFO_LENS_SHADING_APPLIED) ?: false,
        )
        // rawSize came from map, so both are null or neither; testing both keeps every Kotlin
        // compiler free of "unnecessary safe call" warnings (K2 infers map from rawSize, K1 does not).
        val previewSize = if (map != null && rawSize != null) {
            val sizes = map.getOutputSizes(SurfaceHolder::class.java) ?: map.getOutputSizes(SurfaceTexture::class.java) ?: emptyArray()
            choosePreviewSize(sizes.toList(), rawSize)
        } else {
            null
        }
        return CameraChoice(id, facing, capabilities, previewSize?.let { FrameSize(it.width, it.height) },
            CapturePlanner.unsupportedReasons(capabilities))
    }

    /** The largest preview size up to 1920×1080 whose aspect ratio is closest to the RAW frame's. */
    fun choosePreviewSize(sizes: List<Size>, raw: Size): Size? {
        val aspect = raw.width.toDouble() / raw.height
        return sizes.filter { it.width <= 1920 && it.height <= 1440 }
            .sortedWith(compareBy<Size> { abs(it.width.toDouble() / it.height - aspect) > 0.01 }.thenByDescending { it.width.toLong() * it.height })
            .firstOrNull()
    }
}
