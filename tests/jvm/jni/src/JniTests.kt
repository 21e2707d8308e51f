package org.noisecal.jni.test

import org.noisecal.capture.plan.CameraCapabilities
import org.noisecal.capture.plan.GainGap
import org.noisecal.capture.plan.GainGapFollowUp
import org.noisecal.capture.plan.Metering
import org.noisecal.capture.plan.PlanOptions
import org.noisecal.jni.NoisecalException
import org.noisecal.jni.NoisecalNotDarkException
import org.noisecal.jni.NoisecalSession
import java.io.File
import java.lang.reflect.InvocationTargetException
import java.nio.ByteBuffer
import java.nio.ByteOrder

/** Native hooks of the harness (rust/jni/src/test_hooks.rs, cargo feature testkit: not in the Android library). */
object NativeHooks {
    @JvmStatic external fun panicInSession(handle: Long)
    @JvmStatic external fun liveSessions(): Long
}

class Failure(message: String) : AssertionError(message)

fun fail(message: String): Nothing = throw Failure(message)

fun check(condition: Boolean, message: () -> String) {
    if (!condition) fail(message())
}

/** Runs [block], expects a NoisecalException whose message contains [part]; returns the message. */
fun expectNoisecal(what: String, part: String, block: () -> Unit): String {
    try {
        block()
    } catch (e: NoisecalException) {
        val m = e.message ?: ""
        check(m.contains(part)) { "$what: message \"$m\" does not contain \"$part\"" }
        return m
    } catch (e: Throwable) {
        fail("$what: expected NoisecalException containing \"$part\", got $e")
    }
    fail("$what: expected NoisecalException containing \"$part\", nothing was thrown")
}

class Config(val tool: File, val recording: File, val work: File, val benchSize: Pair<Int, Int>, val benchTargets: Int)

/** Runs the Rust helper and returns its stdout; fails on a non-zero exit. */
fun tool(cfg: Config, vararg args: String): String {
    val p = ProcessBuilder(listOf(cfg.tool.path) + args).redirectError(ProcessBuilder.Redirect.INHERIT).start()
    val out = p.inputStream.bufferedReader().readText()
    val rc = p.waitFor()
    check(rc == 0) { "${cfg.tool.name} ${args.joinToString(" ")} exited with $rc" }
    return out
}

/** A direct buffer holding [f]'s rows at [rowStride] bytes; the last row padded or not; at [offset] of a larger buffer when > 0. */
fun directPlane(f: Record.Frame, rowStride: Int, padLastRow: Boolean, offset: Int = 0): ByteBuffer {
    val size = (f.height - 1) * rowStride + (if (padLastRow) rowStride else 2 * f.width)
    val whole = ByteBuffer.allocateDirect(size + offset)
    for (i in 0 until size + offset) whole.put(i, 0x5A)
    val plane = if (offset > 0) whole.position(offset).slice() else whole
    for (y in 0 until f.height) {
        plane.position(y * rowStride)
        plane.put(f.data, y * f.rowStride, 2 * f.width)
    }
    // Position left somewhere in the middle on purpose: the native side reads from the start.
    plane.position(size / 2)
    return plane
}

fun create(h: RecordingHeader): NoisecalSession =
    NoisecalSession.create(h.width, h.height, h.cfa, h.black, h.white, h.referenceIso, h.make, h.model, h.binWidth)

fun push(s: NoisecalSession, f: Record.Frame, buffer: ByteBuffer, rowStride: Int) =
    s.pushFrame(buffer, f.width, f.height, rowStride, 2, f.iso, f.exposureNs, f.black)

class Suite(private val cfg: Config) {
    private val rec = Recording.read(cfg.recording)
    private val frameCount = rec.frames.size
    /** The pack `noisecal calibrate` makes from the recording (the same replay, in Rust). */
    private val reference: ByteArray by lazy {
        val out = File(cfg.work, "reference.pack")
        tool(cfg, "replay", cfg.recording.path, out.path)
        out.readBytes()
    }

    private fun samePack(what: String, pack: File) {
        val got = pack.readBytes()
        check(got.contentEquals(reference)) {
            val at = got.indices.firstOrNull { it >= reference.size || got[it] != reference[it] } ?: got.size
            "$what: pack ${pack.name} (${got.size} bytes) differs from the replayed pack (${reference.size} bytes) at byte $at"
        }
    }

    /** Replays records [from, to) into [s]: odd row padding per frame, every third frame misaligned through a slice. */
    private fun replay(s: NoisecalSession, from: Int, to: Int, badEvery: Int = 0) {
        var frameIndex = 0
        for ((i, r) in rec.records.withIndex()) {
            if (r is Record.Frame) frameIndex++
            if (i < from || i >= to) continue
            when (r) {
                is Record.BeginStep -> s.beginStep(r.exposureNs)
                is Record.BeginDark -> s.beginDark()
                is Record.NoiseProfile -> s.setNoiseProfile(r.iso, r.profile)
                is Record.End -> {}
                is Record.Frame -> {
                    val stride = 2 * r.width + 64 + 32 * (frameIndex % 3) + 2 * (frameIndex % 2)
                    val buffer = directPlane(r, stride, padLastRow = frameIndex % 2 == 0, offset = if (frameIndex % 3 == 0) 1 else 0)
                    if (badEvery > 0 && frameIndex % badEvery == 0) badInputs(s, r, buffer, stride)
                    push(s, r, buffer, stride)
                }
            }
        }
    }

    /** Each bad input raises a NoisecalException that names it and leaves the session as it was. */
    private var badRounds = 0

    private fun badInputs(s: NoisecalSession, f: Record.Frame, good: ByteBuffer, stride: Int) {
        badRounds++
        val before = s.progress()
        val heap = ByteBuffer.wrap(ByteArray(good.capacity())).order(ByteOrder.LITTLE_ENDIAN)
        expectNoisecal("heap buffer", "buffer is not a direct ByteBuffer: pass Image.planes[0].buffer") { push(s, f, heap, stride) }
        val needed = (f.height - 1) * stride + 2 * f.width
        val short = ByteBuffer.allocateDirect(needed - 2)
        expectNoisecal("short buffer", "needs at least $needed bytes ((height − 1) · rowStride + 2 · width)") { push(s, f, short, stride) }
        expectNoisecal("pixel stride 4", "pixel stride is 4 bytes") {
            s.pushFrame(good, f.width, f.height, stride, 4, f.iso, f.exposureNs, f.black)
        }
        expectNoisecal("wrong width", "frame is ${f.width - 2}×${f.height} but the session's sensor is ${f.width}×${f.height}") {
            s.pushFrame(good, f.width - 2, f.height, stride, 2, f.iso, f.exposureNs, f.black)
        }
        expectNoisecal("row stride too small", "row stride ${2 * f.width - 2} bytes is less than") {
            s.pushFrame(good, f.width, f.height, 2 * f.width - 2, 2, f.iso, f.exposureNs, f.black)
        }
        expectNoisecal("three black levels", "pass 4 values in CFA position order") {
            s.pushFrame(good, f.width, f.height, stride, 2, f.iso, f.exposureNs, floatArrayOf(64f, 64f, 64f))
        }
        val after = s.progress()
        check(after.framesAccepted == before.framesAccepted && after.isos == before.isos && after.steps == before.steps) {
            "bad inputs changed the session: $before -> $after"
        }
    }

    fun tests(): List<Pair<String, () -> Unit>> = listOf(
        "synthetic frames match the Rust generator" to ::synthMatchesRust,
        "padded direct buffers give the replayed pack; bad inputs change nothing" to ::paddedPushGivesReplayedPack,
        "the session's recording replays to the same pack" to ::recordingReplays,
        "frame before beginStep" to ::frameBeforeStep,
        "closed and stale handles" to ::closedHandles,
        "a native panic becomes NoisecalException" to ::panicBecomesException,
        "kill and resume from a checkpoint gives the same pack" to ::killAndResume,
        "bad paths and checkpoints" to ::badPaths,
        "bin width: the core's default, reported by the session" to ::binWidths,
        "noise profiles are checked" to ::noiseProfiles,
        "dark step: beginDark + dark frames accepted, a lit frame refused as not dark, the pack replays" to ::darkFrames,
        "motion verdicts cross JNI with every push: target frames registered, re-take as the core judges it" to ::motionVerdicts,
        "gap calls cross JNI with the summary and feed the capture plan's follow-up" to ::gapCallsFollowUp,
        "12 MP frame through JNI vs the core alone" to ::bench,
    )

    /**
     * The pack's conversion-gain call per gap crosses JNI with the summary
     * (NoisecalSession.Finished.gapCalls): the same text the Rust side gives for the pack file
     * (`noisecal-jni-tool gap-calls`), one line per gap between the calibrated ISOs, which the
     * capture library's own parser (GainGap.parseCalls) reads and GainGapFollowUp.propose turns
     * into the next capture: without dark frames, an undetermined gap turns the dark step on; a
     * switch adds its bisecting ISO. The dark-step session's calls (darkFrames, run before) parse
     * too.
     */
    private fun gapCallsFollowUp() {
        val calls = jniGapCalls ?: fail("needs the padded-push test's finish")
        val pack = jniPack ?: fail("needs the padded-push test's pack")
        check(calls == tool(cfg, "gap-calls", pack.path)) { "gap calls through JNI \"$calls\" differ from the pack's" }
        val lines = calls.lines().filter { it.isNotBlank() }
        check(lines.first() == GainGap.CALLS_HEADER) { "gap calls start with \"${lines.first()}\"" }
        // Calibrated: the ISOs the session's progress listed (those with target frames).
        val targets = jniIsos
        check(targets.size >= 2) { "the recording must calibrate two ISOs or more: $targets" }
        val expected = targets.zipWithNext().map { (a, b) -> "$a $b" }
        check(lines.drop(1).map { it.substringBeforeLast(' ') } == expected) { "gaps $lines, expected $expected" }
        println("    gap calls: ${lines.drop(1).joinToString("; ")}")
        val gaps = GainGap.parseCalls(calls)
        check(gaps.size == lines.drop(1).count { !it.endsWith(" none") }) { "parsed $gaps from $lines" }
        val range = rec.header.referenceIso..(4 * targets.last())
        val caps = CameraCapabilities(
            "0", rec.header.make, rec.header.model, range, targets.last(), 1_000L..1_000_000_000L, 1_000_000_000L,
            33_333_333L, rec.header.width, rec.header.height, rec.header.white, rec.header.black.map { it.toInt() },
            0, manualSensor = true, raw = true, lensShadingAppliedToRaw = false,
        )
        val options = PlanOptions(Metering(rec.header.referenceIso, 10_000_000L), targetIsos = targets)
        val f = GainGapFollowUp.propose(caps, options, targets, gaps)
        if (gaps.isEmpty()) {
            check(f == null) { "no open gap, yet a follow-up: $f" }
        } else {
            val follow = f ?: fail("open gaps $gaps, no follow-up")
            check(follow.darkFrames == gaps.any { it.call == GainGap.Call.UNDETERMINED }) { "dark step in $follow for $gaps" }
            for (g in gaps.filter { it.call == GainGap.Call.SWITCH }) {
                val half = g.bisectingIso
                if (half > g.belowIso && half < g.aboveIso) check(half in follow.addedIsos) { "switch $g: $follow" }
            }
            println("    follow-up: ${follow.reasons.joinToString("; ")}")
        }
        val dark = darkGapCalls ?: fail("needs the dark-step test's finish")
        GainGap.parseCalls(dark)
        println("    with dark frames: ${dark.lines().drop(1).filter { it.isNotBlank() }.joinToString("; ")}")
    }

    /**
     * The motion verdict crosses JNI with each pushed frame (NoisecalSession.FrameVerdict):
     * reference frames are not registered; every target frame is, with its samples, and is marked
     * for a re-take exactly when the core's rule says so (over 0.3 px). The recording's chart does
     * not move: every target frame registers as still (under 0.05 px, no sample left out), hard
     * one-pixel patch steps and all (the registration once read 0.9–1.3 px there; the core's test
     * calibrate/motion/still_charts.rs holds the cause). (A refusal for moving over 2 px,
     * NoisecalMovedException, cannot be provoked on this chart: on unblurred steps the bilinear
     * lattice model does not find a real shift either; the controller's handling of it is tested
     * in tests/jvm/capture.)
     */
    private fun motionVerdicts() {
        create(rec.header).use { s ->
            var targets = 0
            var dark = false
            for (r in rec.records) {
                when (r) {
                    is Record.BeginStep -> s.beginStep(r.exposureNs)
                    is Record.BeginDark -> dark = true
                    is Record.Frame -> {
                        if (dark) continue
                        val v = push(s, r, directPlane(r, 2 * r.width, padLastRow = false), 2 * r.width)
                        // A reference-ISO frame is a target once its burst is closed (the
                        // recording's ISO 100 targets come last in each step).
                        if (r.iso == rec.header.referenceIso && v.samples == 0L) {
                            check(!v.registered) { "reference frame registered: $v" }
                        } else {
                            targets++
                            check(v.registered) { "target frame $targets at ISO ${r.iso} not registered: $v" }
                            check(v.retake == (v.shiftPx > 0.3)) { "target frame $targets: re-take against the core's rule: $v" }
                            check(v.samples > 0 && v.leftOut == 0L && v.shiftPx < 0.05) { "still target frame $targets registered as moved: $v" }
                        }
                    }
                    else -> {}
                }
            }
            check(targets >= rec.frames.count { it.iso != rec.header.referenceIso }) { "only $targets target frames registered" }
        }
    }

    private fun synthMatchesRust() {
        val (w, h) = 96 to 64
        val synth = Synth(w, h, 5)
        val buf = ByteBuffer.allocateDirect(2 * w * h).order(ByteOrder.LITTLE_ENDIAN)
        synth.frameInto(400, 2_500_000, 7, buf, 2 * w)
        var hash = -0x340d631b7bdddcdbL // FNV-1a offset basis 0xcbf29ce484222325
        for (i in 0 until w * h) hash = (hash xor (buf.getShort(2 * i).toLong() and 0xFFFF)) * 0x100000001B3L
        val rust = tool(cfg, "frame-hash", "$w", "$h", "400", "2500000", "7", "5").trim()
        check(String.format("%016x", hash) == rust) { "Kotlin synth hash ${String.format("%016x", hash)} != Rust $rust" }
    }

    private var jniRecording: File? = null
    private var jniPack: File? = null
    private var jniGapCalls: String? = null
    private var darkGapCalls: String? = null
    private var jniIsos: List<Int> = emptyList()

    private fun paddedPushGivesReplayedPack() {
        val pack = File(cfg.work, "jni.pack")
        val recording = File(cfg.work, "jni.rec")
        create(rec.header).use { s ->
            s.startRecording(recording.path)
            replay(s, 0, rec.records.size, badEvery = 5)
            val p = s.progress()
            check(p.framesAccepted == frameCount.toLong()) { "accepted ${p.framesAccepted} of $frameCount frames" }
            check(p.isos.isNotEmpty()) { "no ISO in progress: $p" }
            // Every field arrives in its place: the counts add up and follow the recording.
            check(p.steps == rec.records.count { it is Record.BeginStep }) { "steps in $p" }
            // Of each round of bad inputs, the core counts the frame of the wrong size as rejected.
            check(p.framesRejected == badRounds.toLong()) { "$badRounds rounds of bad inputs, rejected frames in $p" }
            check(p.referenceFrames + p.isos.sumOf { it.frames } == p.framesAccepted) { "reference + target frames != accepted in $p" }
            check(p.isos.map { it.iso } == p.isos.map { it.iso }.sorted().distinct()) { "ISOs not ascending in $p" }
            check(p.isos.all { it.samples > 0 && it.totalBins > 0 && it.underSampledBins in 0..it.totalBins }) { "ISO progress out of range: $p" }
            check(s.binWidth == NoisecalSession.defaultBinWidth(rec.header.white, rec.header.black)) { "bin width ${s.binWidth}" }
            val done = s.finish(pack.path)
            val summary = done.summary
            check(summary.contains(pack.path)) { "summary \"$summary\" does not name the pack" }
            println("    finish: $summary")
            jniGapCalls = done.gapCalls
            jniIsos = p.isos.map { it.iso }
        }
        samePack("padded JNI session", pack)
        jniRecording = recording
        jniPack = pack
    }

    private fun recordingReplays() {
        val recording = jniRecording ?: fail("needs the padded-push test's recording")
        val r = Recording.read(recording)
        check(r.ended) { "the session's recording has no End record" }
        check(r.frames.size == frameCount) { "recording holds ${r.frames.size} frames, pushed $frameCount" }
        check((r.records.last() as Record.End).frames == frameCount.toLong()) { "End record counts ${r.records.last()}" }
        val out = File(cfg.work, "jni-replayed.pack")
        tool(cfg, "replay", recording.path, out.path)
        samePack("replay of the JNI recording", out)
    }

    /**
     * A lens-covered frame of the synthetic sensor: black level, a fixed per-pixel offset growing
     * with gain (dark shading) and read noise, no scene.
     */
    private fun darkPlane(h: RecordingHeader, iso: Int, index: Long, rowStride: Int): ByteBuffer {
        val buf = ByteBuffer.allocateDirect((h.height - 1) * rowStride + 2 * h.width).order(ByteOrder.LITTLE_ENDIAN)
        val gain = iso.toDouble() / h.referenceIso
        val k = Synth.splitmix64(0x5EEDL xor Synth.splitmix64(index + 1))
        for (y in 0 until h.height) for (x in 0 until h.width) {
            val i = y.toLong() * h.width + x
            val pattern = 0.4 * gain * Synth.normalish(Synth.splitmix64(0xDA4BL xor i))
            val read = 1.2 * kotlin.math.sqrt(gain) * Synth.normalish(Synth.splitmix64(k xor i))
            val v = kotlin.math.floor(h.black[(y % 2) * 2 + x % 2] + pattern + read + 0.5).coerceIn(0.0, h.white.toDouble())
            buf.putShort(y * rowStride + 2 * x, v.toInt().toShort())
        }
        return buf
    }

    private fun darkFrames() {
        val h = rec.header
        val pack = File(cfg.work, "dark.pack")
        val recording = File(cfg.work, "dark.rec")
        val isos = listOf(h.referenceIso) + rec.frames.map { it.iso }.filter { it != h.referenceIso }.distinct().sorted()
        val perIso = 8
        val exposure = rec.frames.minOf { it.exposureNs }
        val stride = 2 * h.width + 48
        create(h).use { s ->
            s.startRecording(recording.path)
            replay(s, 0, rec.records.size)
            val lit = s.progress()
            s.beginDark()
            var index = 0L
            for (iso in isos) repeat(perIso) {
                s.pushFrame(darkPlane(h, iso, index++, stride), h.width, h.height, stride, 2, iso, exposure, null)
            }
            val dark = s.progress()
            check(dark.framesAccepted >= lit.framesAccepted) { "dark frames lost accepted frames: $lit -> $dark" }
            // A frame of the lit chart while the dark step runs: the lens is not covered.
            val f = rec.frames.last()
            var refused: NoisecalNotDarkException? = null
            try {
                push(s, f, directPlane(f, stride, padLastRow = false), stride)
            } catch (e: NoisecalNotDarkException) {
                refused = e
            }
            val m = refused?.message ?: fail("a lit frame during the dark step was accepted")
            check(m.contains("dark frame at ISO ${f.iso} is not dark") && m.contains("cover")) { "not-dark message: \"$m\"" }
            val after = s.progress()
            check(after.framesAccepted == dark.framesAccepted && after.isos == dark.isos && after.steps == dark.steps) {
                "the refused frame changed the session: $dark -> $after"
            }
            // Other refusals stay plain NoisecalExceptions.
            val heap = ByteBuffer.wrap(ByteArray(16))
            try {
                push(s, f, heap, stride)
                fail("a heap buffer was accepted")
            } catch (e: NoisecalException) {
                check(e !is NoisecalNotDarkException) { "a heap buffer is not a not-dark frame: $e" }
            }
            // The lens covered again: dark frames go on being accepted, and the session finishes.
            s.pushFrame(darkPlane(h, isos.last(), index++, stride), h.width, h.height, stride, 2, isos.last(), exposure, null)
            val done = s.finish(pack.path)
            println("    finish: ${done.summary}")
            darkGapCalls = done.gapCalls
            check(done.gapCalls == tool(cfg, "gap-calls", pack.path)) {
                "dark session: gap calls through JNI \"${done.gapCalls}\" differ from the pack's"
            }
        }
        val bytes = pack.readBytes()
        check(bytes.isNotEmpty()) { "no pack" }
        check(!bytes.contentEquals(reference)) { "the dark frames left the pack as the lit sweep alone makes it" }
        val r = Recording.read(recording)
        check(r.ended) { "the recording has no End record" }
        check(r.records.count { it == Record.BeginDark } == 1) { "one BeginDark record expected" }
        val afterDark = r.records.dropWhile { it != Record.BeginDark }.drop(1)
        check(afterDark.filterIsInstance<Record.Frame>().size == isos.size * perIso + 1) { "dark frames in the recording: ${afterDark.size}" }
        check(r.frames.size == frameCount + isos.size * perIso + 1) { "recording holds ${r.frames.size} frames: the refused one must not be there" }
        val out = File(cfg.work, "dark-replayed.pack")
        tool(cfg, "replay", recording.path, out.path)
        check(out.readBytes().contentEquals(bytes)) { "the replayed recording gives another pack than the session" }
    }

    private fun frameBeforeStep() {
        create(rec.header).use { s ->
            val f = rec.frames.first()
            val stride = 2 * f.width + 16
            val buffer = directPlane(f, stride, padLastRow = true)
            expectNoisecal("frame before beginStep", "no EV step has begun: call begin_step") { push(s, f, buffer, stride) }
            check(s.progress().framesAccepted == 0L) { "a rejected frame was counted as accepted" }
            s.beginStep((rec.records.first { it is Record.BeginStep } as Record.BeginStep).exposureNs)
            push(s, f, buffer, stride)
            check(s.progress().framesAccepted == 1L) { "the session is not usable after the rejection" }
        }
    }

    private fun handleOf(s: NoisecalSession): Long =
        NoisecalSession::class.java.getDeclaredField("handle").apply { isAccessible = true }.getLong(s)

    /** Calls the private static native nativeBeginStep directly with any handle. */
    private fun rawBeginStep(handle: Long) {
        val m = NoisecalSession::class.java.getDeclaredMethod(
            "nativeBeginStep", java.lang.Long.TYPE, java.lang.Long.TYPE,
        ).apply { isAccessible = true }
        try {
            m.invoke(null, handle, 1_000_000L)
        } catch (e: InvocationTargetException) {
            throw e.cause ?: e
        }
    }

    private fun closedHandles() {
        val live = NativeHooks.liveSessions()
        val s = create(rec.header)
        val h = handleOf(s)
        check(NativeHooks.liveSessions() == live + 1) { "live sessions did not grow" }
        s.close()
        s.close() // twice is fine
        check(NativeHooks.liveSessions() == live) { "close did not free the native session" }
        val f = rec.frames.first()
        val buffer = directPlane(f, 2 * f.width, padLastRow = false)
        expectNoisecal("push after close", "NoisecalSession is closed") { push(s, f, buffer, 2 * f.width) }
        expectNoisecal("progress after close", "NoisecalSession is closed") { s.progress() }
        expectNoisecal("stale handle", "session handle $h is closed or was never opened") { rawBeginStep(h) }
        expectNoisecal("zero handle", "session handle 0 is closed") { rawBeginStep(0) }
        expectNoisecal("forged handle", "session handle 987654321 is closed") { rawBeginStep(987654321) }
    }

    private fun panicBecomesException() {
        val live = NativeHooks.liveSessions()
        val s = create(rec.header)
        val m = expectNoisecal("panic", "internal error in the noisecal native core (panic: deliberate panic") {
            NativeHooks.panicInSession(handleOf(s))
        }
        check(m.contains("restore from the last checkpoint")) { "panic message gives no way out: $m" }
        expectNoisecal("poisoned session", "is unusable") { s.progress() }
        s.close()
        check(NativeHooks.liveSessions() == live) { "a poisoned session was not freed by close" }
        // The library still works for other sessions.
        create(rec.header).use { it.beginStep(1_000_000) }
    }

    private fun killAndResume() {
        val recording = File(cfg.work, "resume.rec")
        val checkpoint = File(cfg.work, "resume.ckpt")
        val pack = File(cfg.work, "resume.pack")
        // Cut the records after the frame in the middle.
        val frameIdx = rec.records.withIndex().filter { it.value is Record.Frame }.map { it.index }
        val cut = frameIdx[frameIdx.size / 2] + 1
        val lost = frameIdx.getOrElse(frameIdx.size / 2 + 4) { rec.records.size - 1 } + 1
        val first = create(rec.header)
        first.startRecording(recording.path)
        replay(first, 0, cut)
        first.checkpoint(checkpoint.path)
        // Frames after the checkpoint, then the process "dies": they are lost to the resumed session
        // and cut from the recording.
        replay(first, cut, lost)
        val accepted = first.progress().framesAccepted
        first.close()
        NoisecalSession.restore(checkpoint.path).use { s ->
            val p = s.progress()
            check(p.framesAccepted == (frameIdx.size / 2 + 1).toLong() && p.framesAccepted < accepted) {
                "restored session has ${p.framesAccepted} frames, expected ${frameIdx.size / 2 + 1}"
            }
            replay(s, cut, rec.records.size)
            s.finish(pack.path)
        }
        samePack("resumed session", pack)
        val r = Recording.read(recording)
        check(r.ended && r.frames.size == frameCount) { "resumed recording holds ${r.frames.size} frames (ended ${r.ended})" }
        val replayed = File(cfg.work, "resume-replayed.pack")
        tool(cfg, "replay", recording.path, replayed.path)
        samePack("replay of the resumed recording", replayed)
        // The same pushes without the kill: the resumed recording is that file byte for byte.
        jniRecording?.let { whole ->
            check(recording.readBytes().contentEquals(whole.readBytes())) { "resumed recording differs from the uninterrupted ${whole.name}" }
        }
    }

    private fun binWidths() {
        fun black(v: Float) = floatArrayOf(v, v, v, v)
        check(NoisecalSession.defaultBinWidth(1023, black(64f)) == 4) { "10 bit" }
        check(NoisecalSession.defaultBinWidth(4095, black(256f)) == 16) { "12 bit" }
        check(NoisecalSession.defaultBinWidth(16383, black(1024f)) == 64) { "14 bit" }
        check(NoisecalSession.defaultBinWidth(1023, black(512f)) == 2) { "the black level counts, not only the bit depth" }
        expectNoisecal("three black levels", "pass 4 values in CFA position order") {
            NoisecalSession.defaultBinWidth(1023, floatArrayOf(64f, 64f, 64f))
        }
        expectNoisecal("white level 0", "whiteLevel is 0") { NoisecalSession.defaultBinWidth(0, black(64f)) }
        val h = rec.header
        create(h).use { s -> check(s.binWidth == NoisecalSession.defaultBinWidth(h.white, h.black)) { "default session: ${s.binWidth}" } }
        NoisecalSession.create(h.width, h.height, h.cfa, h.black, h.white, h.referenceIso, h.make, h.model, 8).use { s ->
            check(s.binWidth == 8) { "explicit bin width: ${s.binWidth}" }
        }
        val closed = create(h).apply { close() }
        expectNoisecal("bin width after close", "NoisecalSession is closed") { closed.binWidth }
    }

    private fun noiseProfiles() {
        create(rec.header).use { s ->
            expectNoisecal("7 values", "pass 8 finite values") { s.setNoiseProfile(200, DoubleArray(7) { 1e-5 }) }
            expectNoisecal("NaN", "pass 8 finite values") { s.setNoiseProfile(200, DoubleArray(8) { Double.NaN }) }
            expectNoisecal("ISO 0", "iso is 0") { s.setNoiseProfile(0, DoubleArray(8) { 1e-5 }) }
            s.setNoiseProfile(200, DoubleArray(8) { if (it % 2 == 0) 1e-5 else 1e-7 })
        }
    }

    private fun badPaths() {
        create(rec.header).use { s ->
            expectNoisecal("checkpoint into a missing directory", "does not exist") {
                s.checkpoint(File(cfg.work, "missing/dir/x.ckpt").path)
            }
            expectNoisecal("empty path", "bad path \"\"") { s.checkpoint("") }
            expectNoisecal("finish with nothing calibrated", "no target samples yet") { s.finish(File(cfg.work, "x.pack").path) }
            check(!File(cfg.work, "x.pack").exists()) { "a failed finish left a pack file" }
            s.beginStep(1_000_000)
            expectNoisecal("late recording", "before the first beginStep") { s.startRecording(File(cfg.work, "late.rec").path) }
        }
        expectNoisecal("restore from a missing file", "cannot read the checkpoint") {
            NoisecalSession.restore(File(cfg.work, "nope.ckpt").path)
        }
        val notCheckpoint = File(cfg.work, "not.ckpt").apply { writeText("hello") }
        expectNoisecal("restore from a text file", "not a noisecal checkpoint") { NoisecalSession.restore(notCheckpoint.path) }
        expectNoisecal("bad CFA", "pass RGGB, BGGR, GRBG or GBRG") {
            NoisecalSession.create(64, 48, "RGBW", floatArrayOf(64f, 64f, 64f, 64f), 1023, 100, "m", "m")
        }
    }

    private fun bench() {
        val (w, h) = cfg.benchSize
        val targets = cfg.benchTargets
        val rust = tool(cfg, "bench", "--size", "${w}x$h", "--targets", "$targets").trim().lines().last()
        val core = Regex("(\\w+)_ms=([0-9.]+)").findAll(rust).associate { it.groupValues[1] to it.groupValues[2].toDouble() }
        val synth = Synth(w, h, 11)
        val stride = 2 * w + 96
        val buffer = ByteBuffer.allocateDirect((h - 1) * stride + 2 * w).order(ByteOrder.LITTLE_ENDIAN)
        var index = 0L
        fun timed(s: NoisecalSession, iso: Int, ns: Long): Double {
            synth.frameInto(iso, ns, index++, buffer, stride)
            val t = System.nanoTime()
            s.pushFrame(buffer, w, h, stride, 2, iso, ns, null)
            return (System.nanoTime() - t) / 1e6
        }
        fun median(v: List<Double>): Double = v.sorted().let { if (it.size % 2 == 1) it[it.size / 2] else (it[it.size / 2 - 1] + it[it.size / 2]) / 2 }
        val jni = HashMap<String, Double>()
        NoisecalSession.create(w, h, "RGGB", floatArrayOf(64f, 64f, 64f, 64f), 1023, 100, "noisecal", "bench").use { s ->
            s.beginStep(10_000_000)
            jni["reference"] = median((0 until 3).map { timed(s, 100, 10_000_000) })
            jni["close"] = timed(s, 200, 5_000_000)
            val t = (0 until targets).map { timed(s, 200, 5_000_000) }
            jni["target"] = median(t)
            jni["target_min"] = t.minOrNull() ?: Double.NaN
        }
        for (k in listOf("reference", "close", "target", "target_min")) {
            println(String.format("    %-10s push: JNI %7.1f ms/frame, core alone %7.1f ms/frame (%dx%d, median)", k, jni[k], core[k], w, h))
        }
        val c = core["target_min"] ?: fail("no core figure in \"$rust\"")
        val j = jni["target_min"] ?: fail("no JNI figure")
        // JNI adds only a lookup and a lock; a copy of the 24 MB plane alone would cost several ms.
        check(j <= 1.5 * c + 50.0) { "JNI target push $j ms vs core $c ms: more than the core plus a small constant" }
    }
}

fun main(args: Array<String>) {
    fun arg(name: String): String? = args.indexOf(name).takeIf { it >= 0 }?.let { args.getOrNull(it + 1) }
    val tool = File(arg("--tool") ?: "target/debug/noisecal-jni-tool")
    val work = File(arg("--work") ?: "target/jvm-jni/work").apply { mkdirs() }
    val recording = File(arg("--rec") ?: File(work, "session.rec").path)
    val size = (arg("--bench-size") ?: "4032x3024").split("x").map { it.toInt() }
    val cfg = Config(tool, recording, work, size[0] to size[1], (arg("--bench-targets") ?: "6").toInt())
    val filter = arg("--filter")
    val suite = Suite(cfg)
    var passed = 0
    var failed = 0
    for ((name, test) in suite.tests()) {
        if (filter != null && !name.contains(filter)) continue
        val t = System.nanoTime()
        try {
            test()
            passed++
            println(String.format("PASS %s (%.1f s)", name, (System.nanoTime() - t) / 1e9))
        } catch (e: Throwable) {
            failed++
            println("FAIL $name: $e")
            if (e !is Failure) e.printStackTrace(System.out)
        }
    }
    println("$passed passed, $failed failed")
    if (failed > 0) kotlin.system.exitProcess(1)
}
