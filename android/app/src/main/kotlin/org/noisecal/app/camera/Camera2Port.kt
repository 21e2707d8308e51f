package org.noisecal.app.camera

import android.annotation.SuppressLint
import android.content.Context
import android.graphics.ImageFormat
import android.hardware.camera2.CameraCaptureSession
import android.hardware.camera2.CameraDevice
import android.hardware.camera2.CameraManager
import android.hardware.camera2.CaptureFailure
import android.hardware.camera2.CaptureRequest
import android.hardware.camera2.CaptureResult
import android.hardware.camera2.TotalCaptureResult
import android.hardware.camera2.params.OutputConfiguration
import android.hardware.camera2.params.SessionConfiguration
import android.media.Image
import android.media.ImageReader
import android.os.Handler
import android.os.HandlerThread
import android.util.Log
import android.util.Size
import android.view.Surface
import java.nio.ByteBuffer
import java.util.concurrent.Executor
import kotlin.coroutines.resume
import kotlin.coroutines.resumeWithException
import kotlinx.coroutines.suspendCancellableCoroutine
import org.noisecal.capture.controller.CameraDevicePort
import org.noisecal.capture.controller.CameraEventSink
import org.noisecal.capture.controller.FrameRequest
import org.noisecal.capture.controller.FrameResult
import org.noisecal.capture.controller.ImageHandle
import org.noisecal.capture.controller.ManualSettings
import org.noisecal.capture.plan.Metering

/**
 * The Camera2 side of [CameraDevicePort]: one [CameraDevice], one session with a preview surface
 * and an [ImageReader] of RAW_SENSOR frames. Camera callbacks run on one background
 * [HandlerThread], images arrive on another; both only hand events to the controller, which
 * pushes each frame into the core and closes the [Image] at once.
 *
 * Before [start], a repeating auto-exposure preview request runs: it feeds the preview and keeps
 * [latestMetering] / [latestFocusDiopters] for the plan. [start] stops it, so that only the
 * controller's manual requests reach the sensor.
 */
class Camera2Port(
    context: Context,
    private val cameraId: String,
    private val rawSize: Size,
    override val maxImages: Int = 6,
) : CameraDevicePort, AutoCloseable {
    private val manager = context.getSystemService(CameraManager::class.java)
    private val cameraThread = HandlerThread("noisecal-camera").apply { start() }
    private val cameraHandler = Handler(cameraThread.looper)
    private val cameraExecutor = Executor { cameraHandler.post(it) }
    private val imageThread = HandlerThread("noisecal-raw").apply { start() }
    private val imageHandler = Handler(imageThread.looper)

    private var device: CameraDevice? = null
    private var session: CameraCaptureSession? = null
    private var reader: ImageReader? = null
    private var previewSurface: Surface? = null
    @Volatile private var events: CameraEventSink? = null

    /** What the preview's auto-exposure settled on (the plan's EV 0). */
    @Volatile var latestMetering: Metering? = null
        private set

    /** Where the preview's autofocus put the lens; the capture keeps it there. */
    @Volatile var latestFocusDiopters: Float? = null
        private set

    /** Opens the camera and the session and starts the metering preview on [preview]. */
    suspend fun open(preview: Surface) {
        val d = openDevice()
        device = d
        val r = ImageReader.newInstance(rawSize.width, rawSize.height, ImageFormat.RAW_SENSOR, maxImages)
        reader = r
        previewSurface = preview
        session = createSession(d, listOf(preview, r.surface))
        startPreview()
    }

    @SuppressLint("MissingPermission") // The activity asks for CAMERA before anything opens a port.
    private suspend fun openDevice(): CameraDevice = suspendCancellableCoroutine { cont ->
        manager.openCamera(cameraId, cameraExecutor, object : CameraDevice.StateCallback() {
            override fun onOpened(camera: CameraDevice) {
                if (cont.isActive) cont.resume(camera) else camera.close()
            }

            override fun onDisconnected(camera: CameraDevice) {
                camera.close()
                events?.onDeviceError("camera $cameraId was disconnected (another app took it?)")
                if (cont.isActive) cont.resumeWithException(IllegalStateException("camera $cameraId was disconnected while opening"))
            }

            override fun onError(camera: CameraDevice, error: Int) {
                camera.close()
                val what = when (error) {
                    CameraDevice.StateCallback.ERROR_CAMERA_IN_USE -> "in use"
                    CameraDevice.StateCallback.ERROR_MAX_CAMERAS_IN_USE -> "too many cameras in use"
                    CameraDevice.StateCallback.ERROR_CAMERA_DISABLED -> "disabled by policy"
                    CameraDevice.StateCallback.ERROR_CAMERA_DEVICE -> "device error"
                    CameraDevice.StateCallback.ERROR_CAMERA_SERVICE -> "camera service error"
                    else -> "error $error"
                }
                events?.onDeviceError("camera $cameraId: $what")
                if (cont.isActive) cont.resumeWithException(IllegalStateException("camera $cameraId: $what"))
            }
        })
    }

    private suspend fun createSession(d: CameraDevice, targets: List<Surface>): CameraCaptureSession =
        suspendCancellableCoroutine { cont ->
            val config = SessionConfiguration(
                SessionConfiguration.SESSION_REGULAR,
                targets.map { OutputConfiguration(it) },
                cameraExecutor,
                object : CameraCaptureSession.StateCallback() {
                    override fun onConfigured(s: CameraCaptureSession) {
                        if (cont.isActive) cont.resume(s)
                    }

                    override fun onConfigureFailed(s: CameraCaptureSession) {
                        if (cont.isActive) cont.resumeWithException(IllegalStateException("camera $cameraId cannot stream preview and RAW ${rawSize.width}×${rawSize.height} together"))
                    }
                },
            )
            d.createCaptureSession(config)
        }

    /** Auto-exposure, continuous-focus preview that records what AE and AF settle on. */
    fun startPreview() {
        val d = device ?: return
        val s = session ?: return
        val target = previewSurface ?: return
        val request = d.createCaptureRequest(CameraDevice.TEMPLATE_PREVIEW).apply {
            addTarget(target)
            set(CaptureRequest.CONTROL_MODE, CaptureRequest.CONTROL_MODE_AUTO)
            set(CaptureRequest.CONTROL_AE_MODE, CaptureRequest.CONTROL_AE_MODE_ON)
            set(CaptureRequest.CONTROL_AF_MODE, CaptureRequest.CONTROL_AF_MODE_CONTINUOUS_PICTURE)
        }.build()
        s.setRepeatingRequest(request, object : CameraCaptureSession.CaptureCallback() {
            override fun onCaptureCompleted(session: CameraCaptureSession, request: CaptureRequest, result: TotalCaptureResult) {
                val iso = result.get(CaptureResult.SENSOR_SENSITIVITY)
                val exposure = result.get(CaptureResult.SENSOR_EXPOSURE_TIME)
                if (iso != null && exposure != null && iso > 0 && exposure > 0) latestMetering = Metering(iso, exposure)
                result.get(CaptureResult.LENS_FOCUS_DISTANCE)?.let { latestFocusDiopters = it }
            }
        }, cameraHandler)
    }

    override fun start(events: CameraEventSink) {
        this.events = events
        session?.stopRepeating()
        val r = checkNotNull(reader) { "Camera2Port.open() was not called" }
        r.setOnImageAvailableListener({ rd ->
            val image = try {
                rd.acquireNextImage()
            } catch (e: IllegalStateException) {
                // maxImages already acquired: the controller keeps in-flight below it, so this is a bug.
                Log.w(TAG, "RAW image dropped: ${e.message}")
                null
            } ?: return@setOnImageAvailableListener
            val sink = this.events
            if (sink == null) image.close() else sink.onImage(AndroidImage(image))
        }, imageHandler)
    }

    override fun submit(requests: List<FrameRequest>) {
        val s = checkNotNull(session) { "camera session is not open" }
        val built = requests.map { build(it) }
        if (built.size == 1) s.capture(built[0], captureCallback, cameraHandler) else s.captureBurst(built, captureCallback, cameraHandler)
    }

    override fun stop() {
        events = null
        try {
            session?.abortCaptures()
        } catch (e: Exception) {
            Log.w(TAG, "abortCaptures: ${e.message}")
        }
        reader?.setOnImageAvailableListener(null, null)
    }

    override fun close() {
        stop()
        session?.close(); session = null
        device?.close(); device = null
        reader?.close(); reader = null
        cameraThread.quitSafely()
        imageThread.quitSafely()
    }

    private fun build(r: FrameRequest): CaptureRequest {
        val d = checkNotNull(device) { "camera is not open" }
        val s: ManualSettings = r.settings
        return d.createCaptureRequest(CameraDevice.TEMPLATE_MANUAL).apply {
            addTarget(checkNotNull(reader).surface)
            set(CaptureRequest.CONTROL_MODE, CaptureRequest.CONTROL_MODE_OFF)
            set(CaptureRequest.CONTROL_AE_MODE, if (s.autoExposure) CaptureRequest.CONTROL_AE_MODE_ON else CaptureRequest.CONTROL_AE_MODE_OFF)
            // No flash or torch in any burst (with AE off it is the only control of it): it would light the chart unevenly and the dark frames.
            set(CaptureRequest.FLASH_MODE, CaptureRequest.FLASH_MODE_OFF)
            set(CaptureRequest.CONTROL_AF_MODE, if (s.autoFocus) CaptureRequest.CONTROL_AF_MODE_AUTO else CaptureRequest.CONTROL_AF_MODE_OFF)
            set(CaptureRequest.CONTROL_AWB_MODE, if (s.autoWhiteBalance) CaptureRequest.CONTROL_AWB_MODE_AUTO else CaptureRequest.CONTROL_AWB_MODE_OFF)
            s.focusDistanceDiopters?.let { set(CaptureRequest.LENS_FOCUS_DISTANCE, it) }
            set(CaptureRequest.SENSOR_SENSITIVITY, s.iso)
            set(CaptureRequest.SENSOR_EXPOSURE_TIME, s.exposureNs)
            set(CaptureRequest.SENSOR_FRAME_DURATION, s.frameDurationNs)
            set(CaptureRequest.NOISE_REDUCTION_MODE, if (s.noiseReduction) CaptureRequest.NOISE_REDUCTION_MODE_FAST else CaptureRequest.NOISE_REDUCTION_MODE_OFF)
            set(CaptureRequest.HOT_PIXEL_MODE, if (s.hotPixelCorrection) CaptureRequest.HOT_PIXEL_MODE_FAST else CaptureRequest.HOT_PIXEL_MODE_OFF)
            set(CaptureRequest.EDGE_MODE, if (s.edgeEnhancement) CaptureRequest.EDGE_MODE_FAST else CaptureRequest.EDGE_MODE_OFF)
            set(CaptureRequest.CONTROL_POST_RAW_SENSITIVITY_BOOST, s.postRawSensitivityBoost)
            set(CaptureRequest.BLACK_LEVEL_LOCK, s.blackLevelLock)
            set(CaptureRequest.LENS_OPTICAL_STABILIZATION_MODE, CaptureRequest.LENS_OPTICAL_STABILIZATION_MODE_OFF)
            set(CaptureRequest.CONTROL_VIDEO_STABILIZATION_MODE, CaptureRequest.CONTROL_VIDEO_STABILIZATION_MODE_OFF)
            setTag(r.tag)
        }.build()
    }

    private val captureCallback = object : CameraCaptureSession.CaptureCallback() {
        override fun onCaptureCompleted(session: CameraCaptureSession, request: CaptureRequest, result: TotalCaptureResult) {
            val tag = request.tag as? Long ?: return
            val timestamp = result.get(CaptureResult.SENSOR_TIMESTAMP) ?: return
            events?.onResult(
                FrameResult(
                    tag = tag,
                    timestampNs = timestamp,
                    iso = result.get(CaptureResult.SENSOR_SENSITIVITY) ?: 0,
                    exposureNs = result.get(CaptureResult.SENSOR_EXPOSURE_TIME) ?: 0L,
                    frameDurationNs = result.get(CaptureResult.SENSOR_FRAME_DURATION),
                    // Same order as SENSOR_BLACK_LEVEL_PATTERN: the CFA's channels in raster order = CFA positions.
                    dynamicBlackLevels = result.get(CaptureResult.SENSOR_DYNAMIC_BLACK_LEVEL),
                ),
            )
        }

        override fun onCaptureFailed(session: CameraCaptureSession, request: CaptureRequest, failure: CaptureFailure) {
            val tag = request.tag as? Long ?: return
            val why = if (failure.reason == CaptureFailure.REASON_FLUSHED) "flushed" else "error"
            events?.onFailure(tag, "capture $why (frame ${failure.frameNumber})", failure.wasImageCaptured())
        }
    }

    /** Plane 0 of a RAW_SENSOR [Image]; closing it returns the buffer to the reader. */
    private class AndroidImage(private val image: Image) : ImageHandle {
        private val plane = image.planes[0]
        override val timestampNs: Long = image.timestamp
        override val width: Int = image.width
        override val height: Int = image.height
        override val buffer: ByteBuffer get() = plane.buffer
        override val rowStride: Int = plane.rowStride
        override val pixelStride: Int = plane.pixelStride
        override fun close() = image.close()
    }

    private companion object {
        const val TAG = "noisecal"
    }
}
