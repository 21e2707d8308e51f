package org.noisecal.capture.sim

import java.nio.ByteBuffer
import java.nio.ByteOrder
import org.noisecal.capture.controller.CameraDevicePort
import org.noisecal.capture.controller.CameraEventSink
import org.noisecal.capture.controller.FrameRequest
import org.noisecal.capture.controller.FrameResult
import org.noisecal.capture.controller.ImageHandle
import org.noisecal.capture.controller.ManualSettings

/**
 * What the simulated sensor exposes for one frame: the settings actually *applied* (which lag the
 * request after a change when [SimBehaviour.settingsLagFrames] > 0) and the frame's running
 * number. A [FrameSource] turns it into samples.
 */
data class SimExposure(val iso: Int, val exposureNs: Long, val sequence: Long, val width: Int, val height: Int)

/** Makes the samples of one frame: `width × height` values, row-major, black level included. */
fun interface FrameSource {
    fun render(exposure: SimExposure): ShortArray
}

/**
 * Misbehaviour of the simulated camera, all deterministic in the frame's running number.
 *
 * @property settingsLagFrames after a settings change, this many frames still run (and report) the old settings.
 * @property dropImage the result arrives but the image does not (reader overrun, dropped buffer).
 * @property dropResult the image arrives but no result does.
 * @property failCapture `onCaptureFailed` instead of a result (the image is not captured).
 * @property reverseOrder deliver the result before the image (Camera2 gives no ordering guarantee).
 * @property dynamicBlackLevels per-frame `SENSOR_DYNAMIC_BLACK_LEVEL`, or null to report none.
 * @property exposureScale the exposure the sensor actually applies (and reports), relative to the request.
 * @property deathAfterFrames throw [SimulatedProcessDeath] from [SimulatedCameraPort.submit] once this many frames were produced (a kill).
 */
data class SimBehaviour(
    val settingsLagFrames: Int = 0,
    val dropImage: (Long) -> Boolean = { false },
    val dropResult: (Long) -> Boolean = { false },
    val failCapture: (Long) -> Boolean = { false },
    val reverseOrder: (Long) -> Boolean = { it % 2L == 1L },
    val dynamicBlackLevels: ((Long) -> FloatArray?)? = null,
    val exposureScale: (Long) -> Double = { 1.0 },
    val deathAfterFrames: Long? = null,
)

/** Thrown to emulate the OS killing the app: an [Error], so the controller does not catch it. */
class SimulatedProcessDeath(message: String) : Error(message)

/**
 * A camera in memory: answers each request synchronously (from inside [submit]) with an image and a
 * result, like a Camera2 device with an ImageReader of [maxImages] buffers. RAW rows are padded to
 * [rowStrideBytes]; samples are 16-bit little-endian in a direct ByteBuffer, like RAW_SENSOR.
 * It counts what a reviewer of the controller wants to know: images still open, the most ever open,
 * reader overruns (an image that found all buffers taken is dropped, as ImageReader does), and
 * buffer accesses after close (which throw, as `Image` does).
 */
class SimulatedCameraPort(
    val width: Int,
    val height: Int,
    private val source: FrameSource,
    override val maxImages: Int = 8,
    val rowStrideBytes: Int = width * 2,
    private val behaviour: SimBehaviour = SimBehaviour(),
) : CameraDevicePort {
    init {
        require(rowStrideBytes >= 2 * width) { "rowStrideBytes $rowStrideBytes is less than 2 × width ${2 * width}" }
    }

    private var events: CameraEventSink? = null
    private var applied: ManualSettings? = null
    private var lagLeft = 0
    private var previousRequested: ManualSettings? = null
    private var timestamp = 1_000_000_000L

    var sequence = 0L; private set
    var openImages = 0; private set
    var maxOpenImages = 0; private set
    var imagesDelivered = 0L; private set
    var imagesClosed = 0L; private set
    var readerOverruns = 0L; private set
    var accessAfterClose = 0L; private set
    var requestsSubmitted = 0L; private set
    var stopped = false; private set

    override fun start(events: CameraEventSink) { this.events = events; stopped = false }

    override fun stop() { stopped = true }

    @Synchronized
    override fun submit(requests: List<FrameRequest>) {
        val ev = checkNotNull(events) { "start() was not called" }
        for (req in requests) {
            requestsSubmitted++
            val death = behaviour.deathAfterFrames
            if (death != null && sequence >= death) throw SimulatedProcessDeath("simulated kill after $sequence frames")
            val seq = sequence++
            // Settings pipeline: a change takes effect only after `settingsLagFrames` frames.
            val wanted = req.settings
            if (wanted != previousRequested) { lagLeft = behaviour.settingsLagFrames; previousRequested = wanted }
            val set = if (lagLeft > 0 && applied != null) { lagLeft--; applied!! } else wanted
            applied = set
            val scale = behaviour.exposureScale(seq)
            val now = if (scale == 1.0) set else set.copy(exposureNs = Math.round(set.exposureNs * scale))
            timestamp += maxOf(now.exposureNs, now.frameDurationNs)
            val ts = timestamp
            if (behaviour.failCapture(seq)) { ev.onFailure(req.tag, "simulated failure of frame $seq", false); continue }
            val black = behaviour.dynamicBlackLevels?.invoke(seq)
            val result = FrameResult(req.tag, ts, now.iso, now.exposureNs, now.frameDurationNs, black)
            val image = if (behaviour.dropImage(seq)) null else makeImage(SimExposure(now.iso, now.exposureNs, seq, width, height), ts)
            val sendResult = !behaviour.dropResult(seq)
            if (behaviour.reverseOrder(seq)) {
                if (sendResult) ev.onResult(result)
                image?.let { ev.onImage(it) }
            } else {
                image?.let { ev.onImage(it) }
                if (sendResult) ev.onResult(result)
            }
        }
    }

    private fun makeImage(e: SimExposure, ts: Long): ImageHandle? {
        if (openImages >= maxImages) { readerOverruns++; return null }
        val samples = source.render(e)
        require(samples.size == width * height) { "FrameSource returned ${samples.size} samples for a ${width}×$height frame" }
        // Last row unpadded, as on real devices: (height − 1)·rowStride + 2·width bytes.
        val buf = ByteBuffer.allocateDirect((height - 1) * rowStrideBytes + 2 * width).order(ByteOrder.LITTLE_ENDIAN)
        for (y in 0 until height) {
            val base = y * rowStrideBytes
            for (x in 0 until width) buf.putShort(base + 2 * x, samples[y * width + x])
            if (y < height - 1) for (p in 2 * width until rowStrideBytes) buf.put(base + p, 0x5A) // padding garbage
        }
        openImages++; imagesDelivered++
        maxOpenImages = maxOf(maxOpenImages, openImages)
        return SimImage(buf, ts)
    }

    private inner class SimImage(private val data: ByteBuffer, override val timestampNs: Long) : ImageHandle {
        private var closed = false
        override val width: Int get() = this@SimulatedCameraPort.width
        override val height: Int get() = this@SimulatedCameraPort.height
        override val buffer: ByteBuffer
            get() {
                if (closed) { accessAfterClose++; throw IllegalStateException("Image is already closed") }
                return data.duplicate().order(ByteOrder.LITTLE_ENDIAN)
            }
        override val rowStride: Int get() = rowStrideBytes
        override val pixelStride: Int get() = 2

        override fun close() {
            synchronized(this@SimulatedCameraPort) {
                if (closed) return
                closed = true
                openImages--; imagesClosed++
            }
        }
    }
}
