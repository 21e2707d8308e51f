package org.noisecal.capture.sim

import java.nio.ByteBuffer
import java.nio.ByteOrder
import java.util.Random
import kotlin.math.roundToInt
import kotlin.math.sqrt
import org.noisecal.capture.controller.CameraDevicePort
import org.noisecal.capture.controller.CameraEventSink
import org.noisecal.capture.controller.CaptureController
import org.noisecal.capture.controller.CapturePhase
import org.noisecal.capture.controller.CaptureProgress
import org.noisecal.capture.controller.CoverLensRequest
import org.noisecal.capture.controller.ProgressListener
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

/**
 * What the sensor sees with the lens covered: black level plus a per-pixel dark-shading offset that
 * grows with gain (DSNU, [dsnuDn] DN at [referenceIso], fixed per pixel by [seed]) plus read noise
 * ([readNoiseDn] at [referenceIso], ∝ √gain). No scene, whatever the exposure.
 */
class LensCoveredScene(
    private val black: Int,
    private val white: Int = 1023,
    private val referenceIso: Int = 100,
    private val readNoiseDn: Double = 1.5,
    private val dsnuDn: Double = 0.4,
    private val seed: Long = 1L,
) : FrameSource {
    override fun render(exposure: SimExposure): ShortArray {
        val gain = exposure.iso.toDouble() / referenceIso
        val pattern = Random(seed)
        val noise = Random(seed * 7_919L + 1_000_003L * exposure.sequence)
        return ShortArray(exposure.width * exposure.height) {
            val dn = black + pattern.nextGaussian() * dsnuDn * gain + noise.nextGaussian() * readNoiseDn * sqrt(gain)
            dn.roundToInt().coerceIn(0, white).toShort()
        }
    }
}

/** What the simulated person at the phone does when asked to cover the lens. */
enum class LensAction {
    /** Covers the lens, then confirms. */
    COVER,
    /** Confirms without covering it: the dark frames show the scene. */
    CONFIRM_UNCOVERED,
    /** Skips the dark step. */
    SKIP,
}

/**
 * The person at the phone, for host runs: answers each cover-the-lens prompt of the controller it
 * listens to ([CapturePhase.AWAITING_LENS_COVER]) with [action] of the prompt's number (0, 1, …),
 * covering or uncovering [port]'s lens as it says. [requests] are the prompts it saw.
 */
class SimulatedUser(
    private val port: SimulatedCameraPort,
    private val action: (prompt: Int) -> LensAction = { LensAction.COVER },
) : ProgressListener {
    private var controller: CaptureController? = null
    private var last: CoverLensRequest? = null
    val requests = mutableListOf<CoverLensRequest>()

    /** Listens to [c] and answers its prompts. */
    fun attach(c: CaptureController): SimulatedUser = apply { controller = c; c.addListener(this) }

    override fun onProgress(progress: CaptureProgress) {
        val ask = progress.coverLens ?: return
        if (progress.phase != CapturePhase.AWAITING_LENS_COVER || ask === last) return
        last = ask
        val c = checkNotNull(controller) { "attach the SimulatedUser to its controller" }
        when (action(requests.size).also { requests += ask }) {
            LensAction.COVER -> { port.lensCovered = true; c.confirmLensCovered() }
            LensAction.CONFIRM_UNCOVERED -> { port.lensCovered = false; c.confirmLensCovered() }
            LensAction.SKIP -> { port.lensCovered = false; c.skipDarkFrames() }
        }
    }
}

/** Thrown to emulate the OS killing the app: an [Error], so the controller does not catch it. */
class SimulatedProcessDeath(message: String) : Error(message)

/**
 * A camera in memory: answers each request synchronously (from inside [submit]) with an image and a
 * result, like a Camera2 device with an ImageReader of [maxImages] buffers. RAW rows are padded to
 * [rowStrideBytes]; samples are 16-bit little-endian in a direct ByteBuffer, like RAW_SENSOR.
 * It counts what a reviewer of the controller wants to know: images still open, the most ever open,
 * reader overruns (an image that found all buffers taken is dropped, as ImageReader does), and
 * buffer accesses after close (which throw, as `Image` does).
 *
 * [lensCovered] is the lens cap: while it is on, frames come from [coveredSource] (black level and
 * noise, no scene) instead of [source]. Nothing in the camera interface knows about it, as on a
 * phone; a [SimulatedUser] puts it on when the controller asks for the dark step.
 */
class SimulatedCameraPort(
    val width: Int,
    val height: Int,
    private val source: FrameSource,
    override val maxImages: Int = 8,
    val rowStrideBytes: Int = width * 2,
    private val behaviour: SimBehaviour = SimBehaviour(),
    private val coveredSource: FrameSource = LensCoveredScene(black = 64),
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
    /** Whether the lens is covered (see the class doc). */
    @Volatile var lensCovered = false
    /** Frames rendered with the lens covered. */
    var coveredFrames = 0L; private set

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
        val covered = lensCovered
        if (covered) coveredFrames++
        val samples = (if (covered) coveredSource else source).render(e)
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
