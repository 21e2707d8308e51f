package org.noisecal.capture.test

import java.io.File
import java.nio.file.Files
import org.noisecal.capture.controller.Clock
import org.noisecal.capture.controller.FrameMotion
import org.noisecal.capture.controller.FrameMovedException
import org.noisecal.capture.controller.FrameSink
import org.noisecal.capture.controller.FrameSinkFactory
import org.noisecal.capture.controller.IsoCoverage
import org.noisecal.capture.controller.LensNotCoveredException
import org.noisecal.capture.controller.PushedFrame
import org.noisecal.capture.controller.RawFrame
import org.noisecal.capture.controller.SinkProgress
import org.noisecal.capture.plan.SensorSpec
import org.noisecal.capture.sim.FrameSource
import org.noisecal.capture.sim.SimExposure

/**
 * Frames that carry their own identity: pixel (0,0) is the applied ISO, (1,0) the exposure in µs
 * (mod 2^16), (2,0) the running number (mod 2^16); every other pixel follows a pattern of x, y and
 * the running number. A sink that decodes them can tell whether the controller paired each image
 * with its own result and walked the rows with the right stride.
 */
class TaggedFrames(private val black: Int = 64) : FrameSource {
    override fun render(exposure: SimExposure): ShortArray {
        val out = ShortArray(exposure.width * exposure.height)
        for (y in 0 until exposure.height) for (x in 0 until exposure.width) out[y * exposure.width + x] = pattern(x, y, exposure.sequence).toShort()
        out[0] = exposure.iso.toShort()
        out[1] = ((exposure.exposureNs / 1000) and 0xFFFF).toShort()
        out[2] = (exposure.sequence and 0xFFFF).toShort()
        return out
    }

    fun pattern(x: Int, y: Int, seq: Long): Int = black + ((x * 3 + y * 5 + seq.toInt() * 7) and 511)
}

/**
 * What the tagged sensor gives with the lens covered: the same tags in row 0, black level with a
 * little noise (0..2 DN, by position and running number) everywhere else.
 */
class TaggedDarkFrames(private val black: Int = 64) : FrameSource {
    override fun render(exposure: SimExposure): ShortArray {
        val out = ShortArray(exposure.width * exposure.height) { (black + ((it * 7 + exposure.sequence.toInt()) % 3)).toShort() }
        out[0] = exposure.iso.toShort()
        out[1] = ((exposure.exposureNs / 1000) and 0xFFFF).toShort()
        out[2] = (exposure.sequence and 0xFFFF).toShort()
        return out
    }
}

/** One call the fake sink saw. */
data class SinkCall(val kind: String, val iso: Int = 0, val exposureNs: Long = 0, val seq: Long = -1)

/**
 * A [FrameSink] that records every call, reads every frame the way the core would (through the
 * row and pixel strides, checking the buffer size) and checks the tagged content against what the
 * result reported. Its checkpoint is its call log; [finish] writes per-(step, ISO) frame counts.
 * After [beginDark] (call "dark") it checks frames the way the core does: rows below the tags must
 * be black, or the push throws [LensNotCoveredException].
 */
class RecordingSink(
    val sensor: SensorSpec,
    val calls: MutableList<SinkCall> = mutableListOf(),
    private val tagged: TaggedFrames? = TaggedFrames(),
    private val refuse: (Int) -> Boolean = { false },
    /**
     * What the core would measure of push n at ISO iso: a target frame's shift (px), or null for
     * no registration; over 2 px the push is refused with [FrameMovedException] as the core does.
     */
    private val motion: (n: Int, iso: Int) -> Double? = { _, iso -> if (iso == sensor.referenceIso) null else 0.01 },
) : FrameSink {
    var closed = false
    var pushes = 0
    val checkpoints = mutableListOf<String>()
    /** Mean level (black removed) of every accepted frame, in order. */
    val means = mutableListOf<Double>()
    /** Whether a dark step is open: the last step call was "dark". */
    val dark: Boolean get() = calls.lastOrNull { it.kind == "step" || it.kind == "dark" }?.kind == "dark"
    /** Frames refused as not dark. */
    var notDark = 0

    override fun beginDark() {
        check(!closed) { "sink closed" }
        calls += SinkCall("dark")
    }

    override fun beginStep(referenceExposureNs: Long) {
        check(!closed) { "sink closed" }
        calls += SinkCall("step", exposureNs = referenceExposureNs)
    }

    override fun pushFrame(frame: RawFrame): PushedFrame {
        check(!closed) { "sink closed" }
        val n = pushes++
        if (refuse(n)) throw IllegalArgumentException("fake refusal of push $n")
        val shift = if (dark) null else motion(n, frame.iso)
        if (shift != null && shift > 2.0) {
            throw FrameMovedException("fake: target frame at ISO ${frame.iso} moved ${"%.2f".format(shift)} px: use a sturdier mount")
        }
        val buf = frame.buffer
        require(buf.isDirect) { "heap ByteBuffer" }
        require(frame.pixelStride == 2) { "pixel stride ${frame.pixelStride}" }
        require(frame.width == sensor.width && frame.height == sensor.height) { "frame ${frame.width}×${frame.height}" }
        val need = (frame.height - 1) * frame.rowStride + 2 * frame.width
        require(buf.capacity() >= need) { "buffer ${buf.capacity()} < $need" }
        fun px(x: Int, y: Int): Int = buf.getShort(y * frame.rowStride + x * frame.pixelStride).toInt() and 0xFFFF
        var sum = 0.0
        for (y in 0 until frame.height) for (x in 0 until frame.width) sum += px(x, y)
        val mean = sum / (frame.width * frame.height) - sensor.blackLevels.average()
        var seq = -1L
        if (tagged != null) {
            if (px(0, 0) != frame.iso) throw Failure("image carries ISO ${px(0, 0)} but its result says ${frame.iso}: image and result mismatched")
            if (px(1, 0).toLong() != ((frame.exposureNs / 1000) and 0xFFFF)) throw Failure("image exposure tag ${px(1, 0)} vs result ${frame.exposureNs}")
            seq = px(2, 0).toLong()
            if (dark) {
                val lit = (1 until frame.height).sumOf { y -> (0 until frame.width).count { x -> px(x, y) > sensor.blackLevels[0] + 8 } }
                if (lit > 0) {
                    notDark++
                    throw LensNotCoveredException("fake: dark frame $seq at ISO ${frame.iso} has $lit lit pixels: cover the lens")
                }
            } else for (y in 1 until frame.height) for (x in 0 until frame.width) {
                if (px(x, y) != tagged.pattern(x, y, seq)) throw Failure("pixel ($x,$y) of frame $seq wrong: row stride misused?")
            }
        }
        means += mean
        calls += SinkCall("frame", frame.iso, frame.exposureNs, seq)
        // As the core: samples left out where the motion moved edges (here 1 % per 0.1 px).
        val samples = (frame.width * frame.height).toLong()
        val leftOut = if (shift == null) 0L else (samples * shift / 10).toLong()
        return PushedFrame(false, shift?.let { FrameMotion(it, samples - leftOut, leftOut, it > 0.3) })
    }

    override fun progress(): SinkProgress {
        val frames = calls.filter { it.kind == "frame" }
        val isos = frames.map { it.iso }.filter { it != sensor.referenceIso }.distinct().sorted()
        return SinkProgress(frames.size.toLong(), 0, calls.count { it.kind == "step" },
            isos.map { iso -> val f = frames.count { it.iso == iso }.toLong(); IsoCoverage(iso, f, (100 - f).coerceAtLeast(0).toInt(), 100) })
    }

    override fun checkpoint(path: String) {
        checkpoints += path
        val tmp = File("$path.tmp")
        tmp.writeText(encode(calls))
        Files.move(tmp.toPath(), File(path).toPath(), java.nio.file.StandardCopyOption.REPLACE_EXISTING)
    }

    override fun finish(packPath: String): String {
        val counts = countsByStep(calls)
        File(packPath).writeText(counts.entries.joinToString("\n") { "${it.key}=${it.value}" })
        return "fake pack: ${calls.count { it.kind == "frame" }} frames in ${calls.count { it.kind == "step" }} steps"
    }

    override fun close() { closed = true }

    companion object {
        fun encode(calls: List<SinkCall>) = calls.joinToString("\n") { "${it.kind} ${it.iso} ${it.exposureNs} ${it.seq}" }
        fun decode(text: String): MutableList<SinkCall> = text.lines().filter { it.isNotBlank() }.map {
            val p = it.split(' ')
            SinkCall(p[0], p[1].toInt(), p[2].toLong(), p[3].toLong())
        }.toMutableList()

        /** "step#iso" → frames, the content of the fake pack. */
        fun countsByStep(calls: List<SinkCall>): Map<String, Int> {
            val m = linkedMapOf<String, Int>()
            var step = -1
            for (c in calls) if (c.kind == "step" || c.kind == "dark") step++ else m.merge("$step#${c.iso}@${c.exposureNs}", 1, Int::plus)
            return m
        }
    }
}

/** Makes [RecordingSink]s; [restore] rebuilds one from its checkpoint (the call log). */
class RecordingSinkFactory(
    private val tagged: TaggedFrames? = TaggedFrames(),
    private val refuse: (Int) -> Boolean = { false },
    private val motion: ((n: Int, iso: Int) -> Double?)? = null,
) : FrameSinkFactory {
    val made = mutableListOf<RecordingSink>()
    var restoredFrom: String? = null
    private var sensor: SensorSpec? = null

    fun withSensor(s: SensorSpec) = apply { sensor = s }

    override fun create(sensor: SensorSpec): FrameSink {
        this.sensor = sensor
        return sink(sensor, mutableListOf()).also { made += it }
    }

    override fun restore(checkpointPath: String): FrameSink {
        restoredFrom = checkpointPath
        val s = checkNotNull(sensor) { "restore needs the sensor: call withSensor" }
        return sink(s, RecordingSink.decode(File(checkpointPath).readText())).also { made += it }
    }

    private fun sink(s: SensorSpec, calls: MutableList<SinkCall>): RecordingSink =
        if (motion == null) RecordingSink(s, calls, tagged, refuse) else RecordingSink(s, calls, tagged, refuse, motion)

    val last: RecordingSink get() = made.last()
}

/** A clock whose sleeps take no time. */
class FakeClock : Clock {
    var sleptMs = 0L
    override fun nanoTime(): Long = System.nanoTime() + sleptMs * 1_000_000L
    override fun sleepMs(ms: Long) { sleptMs += ms }
}

/** A fresh temporary folder, removed with its contents when the test JVM exits. */
fun tempDir(name: String): File =
    Files.createTempDirectory("noisecal-$name").toFile().also { dir ->
        Runtime.getRuntime().addShutdownHook(Thread { dir.deleteRecursively() })
    }
