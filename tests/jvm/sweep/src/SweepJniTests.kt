package org.noisecal.capture.sweeptest

import java.io.File
import java.nio.file.Files
import kotlin.math.roundToInt
import org.noisecal.capture.controller.CaptureOutcome
import org.noisecal.capture.controller.CapturePhase
import org.noisecal.capture.controller.CoverLensRequest
import org.noisecal.capture.controller.ProgressListener
import org.noisecal.capture.controller.CaptureUiState
import org.noisecal.capture.controller.ControllerConfig
import org.noisecal.capture.controller.FrameSink
import org.noisecal.capture.controller.FrameSinkFactory
import org.noisecal.capture.controller.ProgressRecord
import org.noisecal.capture.controller.SessionStore
import org.noisecal.capture.controller.UiStateListener
import org.noisecal.capture.plan.BurstRole
import org.noisecal.capture.plan.CameraCapabilities
import org.noisecal.capture.plan.CapturePlan
import org.noisecal.capture.plan.CapturePlanner
import org.noisecal.capture.plan.Metering
import org.noisecal.capture.plan.PlanOptions
import org.noisecal.capture.plan.PlanResult
import org.noisecal.capture.plan.SensorSpec
import org.noisecal.capture.sim.LensAction
import org.noisecal.capture.sim.SimBehaviour
import org.noisecal.capture.sim.SimulatedCameraPort
import org.noisecal.capture.sim.SimulatedProcessDeath
import org.noisecal.capture.sim.SimulatedSweep
import org.noisecal.capture.sim.SyntheticChart
import org.noisecal.capture.sink.NoisecalSinkFactory
import org.noisecal.jni.NoisecalSession

/**
 * A whole simulated sweep plan → [org.noisecal.capture.controller.CaptureController]
 * → real JNI library ([NoisecalSinkFactory]) → pack, compared byte for byte with
 * `noisecal calibrate` of the recording the same session wrote.
 */
class SweepJniTests(private val env: Env) : Suite("sweep-jni") {

    /** A small 10-bit RGGB sensor with base ISO 50, digital gain above 400. */
    private val capabilities = CameraCapabilities(
        cameraId = "0", make = "Simulated", model = "Sweep 128x96",
        sensitivityRange = 50..800, maxAnalogSensitivity = 400,
        exposureRangeNs = 10_000L..500_000_000L, maxFrameDurationNs = 1_000_000_000L, minFrameDurationNs = 5_000_000L,
        rawWidth = 128, rawHeight = 96, whiteLevel = 1023, blackLevelPattern = listOf(64, 64, 64, 64), cfaCode = 0,
        manualSensor = true, raw = true, lensShadingAppliedToRaw = false,
    )
    private val targetIsos = listOf(100, 200, 400, 800)

    private val plan: CapturePlan by lazy {
        when (val r = CapturePlanner.plan(capabilities, PlanOptions(Metering(100, 2_000_000L), targetIsos = targetIsos,
            evMin = -1.0, evMax = 1.0, framesPerBurst = 6, referenceFramesPerBurst = 6, recording = true))) {
            is PlanResult.Ok -> r.plan
            is PlanResult.Refused -> throw Failure("the test plan was refused: $r")
        }
    }

    private fun chart(p: CapturePlan) = SyntheticChart(p.sensor.width, p.sensor.height, p.sensor.blackLevels.min().roundToInt(),
        p.sensor.whiteLevel, p.sensor.referenceIso, p.options.metering.brightness, seed = 7L)

    /**
     * A request counts as lost [ControllerConfig.frameTimeoutMs] (+ 7 frame times) after it was
     * submitted. It must be long enough that a frame whose image and result sit in the controller's
     * queue behind slow pushes (JIT warm-up, the first native calls) is never declared lost: such a
     * spurious loss would make the run take a different frame than the fault-free one (seen at 30 ms
     * on a loaded 2-core machine). Only the deliberately dropped frames wait for it, so they are few.
     */
    private val config = ControllerConfig(frameTimeoutMs = 1_000L)

    /** Frames [b] loses among the first [n] camera frames: failed captures, dropped images, dropped results. */
    private fun expectedLost(b: SimBehaviour, n: Long): Int =
        (0 until n).count { b.failCapture(it) || b.dropImage(it) || b.dropResult(it) }

    /** Row padding of the fault-free run and of the faulty run: different on purpose (the pack must not depend on it). */
    private val cleanPadding = 32
    private val faultyPadding = 96

    /** Faults of the run that gets killed ([kill] frames in) and of the run that resumes it ([kill] null). */
    private fun faults(kill: Long?) = SimBehaviour(
        settingsLagFrames = 2,
        dropImage = { it % 37L == 5L },
        dropResult = { it % 41L == 11L },
        failCapture = { it % 29L == 13L },
        dynamicBlackLevels = { if (it % 31L == 7L) FloatArray(4) { 90f } else null },
        deathAfterFrames = kill,
    )

    /** Which frames, rendered with the burst's own settings, reach the sink under [b]. */
    private fun acceptedUnder(b: SimBehaviour): (Long) -> Boolean =
        { seq -> !b.dropResult(seq) && b.dynamicBlackLevels?.invoke(seq) == null }

    /** The last state a controller published. */
    private class StateLog : UiStateListener {
        @Volatile var last: CaptureUiState? = null
        override fun onState(state: CaptureUiState) { last = state }
    }

    class SweepOutput(val pack: File, val recording: File, val summary: String, val killAt: Long, val notes: String)

    /** Sinks whose close() does nothing: the native session stays open, as when the OS kills the process. */
    private class AbandoningFactory(private val inner: FrameSinkFactory) : FrameSinkFactory {
        private fun wrap(s: FrameSink): FrameSink = object : FrameSink by s {
            override fun close() { /* left open on purpose; freed when the JVM exits */ }
        }
        override fun create(sensor: SensorSpec): FrameSink = wrap(inner.create(sensor))
        override fun restore(checkpointPath: String): FrameSink = wrap(inner.restore(checkpointPath))
    }

    private fun fresh(name: String): File {
        val d = File(env.work, name).absoluteFile
        d.deleteRecursively()
        check(d.mkdirs()) { "cannot create $d" }
        return d
    }

    private fun checkPortClean(port: SimulatedCameraPort, what: String) {
        eq(0, port.openImages, "$what: images left open")
        eq(0L, port.accessAfterClose, "$what: buffer reads after close")
        eq(port.imagesDelivered, port.imagesClosed, "$what: images delivered vs closed")
        check(port.maxOpenImages <= port.maxImages) { "$what: ${port.maxOpenImages} images open at once, reader has ${port.maxImages}" }
    }

    private fun checkFinished(outcome: CaptureOutcome, what: String): CaptureOutcome.Finished {
        check(outcome is CaptureOutcome.Finished) { "$what: sweep did not finish: $outcome" }
        return outcome as CaptureOutcome.Finished
    }

    /** The summary ends with "; recording PATH (N frames)": every planned frame must be in the recording. */
    private fun checkRecordedFrames(summary: String, rec: File, what: String) {
        val m = Regex("""; recording (.+) \((\d+) frames\)""").find(summary)
            ?: throw Failure("$what: the session is no longer recording (summary: $summary)")
        eq(rec.path, m.groupValues[1], "$what: recording path")
        eq(plan.totalFrames.toLong(), m.groupValues[2].toLong(), "$what: frames in the recording")
    }

    private val clean: SweepOutput by lazy {
        val dir = fresh("clean")
        val rec = File(dir, "session.rec")
        val log = StateLog()
        val run = SimulatedSweep.run(plan, NoisecalSinkFactory(rec.path), dir, PlannedFrames(plan, chart(plan)) { true },
            SimBehaviour(), rowPaddingBytes = cleanPadding, config = config, listener = log)
        val done = checkFinished(run.outcome, "fault-free run")
        checkPortClean(run.port, "fault-free run")
        val s = log.last!!
        eq(0, s.framesRejected, "fault-free run: frames rejected")
        eq(0, s.framesLost, "fault-free run: frames lost (timing: frames still queued were given up; is the machine overloaded?)")
        eq(plan.totalFrames.toLong(), run.port.imagesDelivered, "fault-free run: images delivered")
        checkRecordedFrames(done.summary, rec, "fault-free run")
        SweepOutput(File(done.packPath), rec, done.summary, -1, "${plan.bursts.size} bursts, ${plan.totalFrames} frames")
    }

    private val faulty: SweepOutput by lazy { faultySweep("faulty", closeOnKill = true, 60L..120L step 3) }

    /**
     * The same, but the killed run's session is never closed, as when the OS kills the process: no End record, no flush.
     * It starts from the faulty run's kill point and moves on if that one lands between bursts here: on a loaded
     * machine the session's worker can lag the camera, so the same frame count can fall on a burst boundary.
     */
    private val abandoned: SweepOutput by lazy { faultySweep("abandoned", closeOnKill = false, faulty.killAt..120L step 3) }

    /**
     * Runs the plan with [faults] in [name]: a first controller killed mid-burst, then a second one
     * that resumes from the checkpoint. With [closeOnKill] false the killed run's native session is
     * left open (never closed, so never flushed or ended), as after a real process death; otherwise
     * the controller's `use` closes it on the way out, writing the recording's End record.
     */
    private fun faultySweep(name: String, closeOnKill: Boolean, killCandidates: LongProgression): SweepOutput {
        val dir = fresh(name)
        val rec = File(dir, "session.rec")
        val realFactory = NoisecalSinkFactory(rec.path)
        val factory = if (closeOnKill) realFactory else AbandoningFactory(realFactory)
        val store = SessionStore(dir)

        // Run 1: faults, then the OS kills the app in the middle of a burst. Where a kill after n
        // camera frames lands depends on the controller's batching (and, on a loaded machine, on how
        // far the session's worker lags), so try n = 60, 63, … (each attempt in a fresh folder) and
        // keep the first that lands mid-burst,
        // after some of that burst's frames already reached the session and its recording.
        var killed: Triple<Long, CaptureUiState, ProgressRecord>? = null
        val tried = mutableListOf<String>()
        for (killAt in killCandidates) {
            dir.deleteRecursively()
            val log1 = StateLog()
            val b1 = faults(killAt)
            try {
                val r = SimulatedSweep.run(plan, factory, dir, PlannedFrames(plan, chart(plan), acceptedUnder(b1)), b1,
                    rowPaddingBytes = faultyPadding, config = config, listener = log1)
                throw Failure("the simulated kill after $killAt camera frames did not happen: ${r.outcome}")
            } catch (e: SimulatedProcessDeath) {
                // expected
            }
            val atKill = log1.last!!
            val record = store.load() ?: throw Failure("no progress record after a kill after $killAt frames")
            val b = atKill.currentBurst ?: throw Failure("no burst was running at the kill after $killAt frames")
            tried += "$killAt: ${atKill.burstFramesAccepted}/${b.frames} of burst ${b.index}"
            if (atKill.burstFramesAccepted in 1 until b.frames) { killed = Triple(killAt, atKill, record); break }
        }
        val (killAt, atKill, record) = killed ?: throw Failure("no kill landed mid-burst: $tried")
        val interrupted = atKill.currentBurst!!
        check(interrupted.index !in record.completedBursts) { "burst ${interrupted.index} was running yet is recorded as done" }
        check(record.completedBursts.size in 1 until plan.bursts.size) { "kill after ${record.completedBursts.size} bursts: not mid-sweep" }
        eq((0 until interrupted.index).toSet(), record.completedBursts, "bursts recorded as done at the kill")
        check(atKill.framesRejected > 0) { "run 1: no frame was rejected (settings lag, black level)" }
        check(atKill.framesLost > 0) { "run 1: no frame was lost (dropped image/result, failed capture)" }
        val recBytesAtKill = rec.length()

        // Run 2: a new controller on the same folder resumes from the checkpoint, still with faults.
        val log2 = StateLog()
        val b2 = faults(null)
        val run2 = SimulatedSweep.run(plan, realFactory, dir, PlannedFrames(plan, chart(plan), acceptedUnder(b2)), b2,
            rowPaddingBytes = faultyPadding, config = config, listener = log2)
        val done = checkFinished(run2.outcome, "resumed run")
        checkPortClean(run2.port, "resumed run")
        val s2 = log2.last!!
        eq(record.completedBursts.size, s2.resumedFromBurst, "resumed run: bursts restored from the checkpoint")
        check(s2.framesRejected > 0) { "resumed run: no frame was rejected (settings lag, black level)" }
        eq(0L, run2.port.readerOverruns, "resumed run: reader overruns")
        eq(expectedLost(b2, run2.port.sequence), s2.framesLost, "resumed run: frames lost (only the dropped/failed ones; more means queued frames timed out: machine overloaded?)")
        checkRecordedFrames(done.summary, rec, "resumed run")
        return SweepOutput(File(done.packPath), rec, done.summary, killAt,
            "killed after $killAt camera frames in $interrupted after ${atKill.burstFramesAccepted} of its frames and ${record.completedBursts.size} bursts " +
                "(recording $recBytesAtKill bytes); rejected ${atKill.framesRejected}+${s2.framesRejected}, " +
                "lost ${atKill.framesLost}+${s2.framesLost}, camera frames ${run2.port.sequence} after resume")
    }

    /** Runs the CLI; returns stdout; fails with its stderr on a non-zero exit. */
    private fun cli(vararg args: String): String {
        val err = File.createTempFile("noisecal-", ".err", env.work)
        try {
            val p = ProcessBuilder(listOf(env.cli.path) + args).redirectError(err).start()
            val out = p.inputStream.bufferedReader().readText()
            val rc = p.waitFor()
            check(rc == 0) { "noisecal ${args.joinToString(" ")} exited with $rc: ${err.readText().trim()}" }
            return out
        } finally {
            err.delete()
        }
    }

    private fun calibrate(rec: File, out: File): File {
        out.delete()
        cli("calibrate", rec.path, "-o", out.path, "-q")
        check(out.isFile) { "noisecal calibrate wrote no $out" }
        return out
    }

    private fun assertSameBytes(expected: File, actual: File, what: String) {
        val a = Files.readAllBytes(expected.toPath())
        val b = Files.readAllBytes(actual.toPath())
        check(a.isNotEmpty()) { "$what: $expected is empty" }
        if (a.contentEquals(b)) return
        val first = (0 until minOf(a.size, b.size)).firstOrNull { a[it] != b[it] } ?: minOf(a.size, b.size)
        throw Failure("$what: $expected (${a.size} bytes) and $actual (${b.size} bytes) differ first at byte $first")
    }

    /** The same sweep with the dark step: 4 frames per ISO (50, then each target). */
    private val darkPlan: CapturePlan by lazy {
        when (val r = CapturePlanner.plan(capabilities, plan.options.copy(darkFrames = true, darkFramesPerIso = 4))) {
            is PlanResult.Ok -> r.plan
            is PlanResult.Refused -> throw Failure("the dark test plan was refused: $r")
        }
    }

    class DarkRun(val outcome: CaptureOutcome.Finished, val pack: File, val recording: File, val prompts: List<CoverLensRequest>,
                  val last: CaptureUiState, val port: SimulatedCameraPort)

    /** [darkPlan] through the real library, the person at the phone doing [lens] at each cover-the-lens prompt. */
    private fun darkSweep(name: String, lens: (Int) -> LensAction): DarkRun {
        val dir = fresh(name)
        val rec = File(dir, "session.rec")
        val prompts = mutableListOf<CoverLensRequest>()
        var last: CaptureUiState? = null
        val listener = ProgressListener { p ->
            last = p
            val ask = p.coverLens
            if (p.phase == CapturePhase.AWAITING_LENS_COVER && ask != null && prompts.lastOrNull() !== ask) prompts += ask
        }
        val run = SimulatedSweep.run(darkPlan, NoisecalSinkFactory(rec.path), dir, chart(darkPlan), SimBehaviour(),
            rowPaddingBytes = cleanPadding, config = config, listener = listener, lens = lens)
        val done = checkFinished(run.outcome, name)
        checkPortClean(run.port, name)
        return DarkRun(done, File(done.packPath), rec, prompts, checkNotNull(last), run.port)
    }

    private val darkCovered: DarkRun by lazy { darkSweep("dark", lens = { LensAction.COVER }) }

    /** Per ISO of [pack], its fixed-pattern component as `noisecal inspect --json` shows it (null: none). */
    private fun fpnOf(pack: File): Map<Int, Map<*, *>?> {
        val root = Json.parse(cli("inspect", pack.path, "--json")) as? Map<*, *> ?: throw Failure("inspect --json did not print an object")
        val isos = (root["isos"] as? List<*>)?.map { it as Map<*, *> } ?: throw Failure("inspect --json has no \"isos\" array")
        return isos.associate { (it["iso"] as Number).toInt() to ((it["structure"] as? Map<*, *>)?.get("fpn") as? Map<*, *>) }
    }

    /** Frames of the recording, from the summary's "; recording PATH (N frames)". */
    private fun recordedFrames(summary: String): Long =
        Regex("""; recording .+ \((\d+) frames\)""").find(summary)?.groupValues?.get(1)?.toLong()
            ?: throw Failure("the session is no longer recording (summary: $summary)")

    init {
        test("plan: base ISO 50, 10-bit 128x96, ISO ${targetIsos.joinToString("/")}, EV -1..+1") {
            eq(targetIsos, plan.targetIsos, "target ISOs")
            eq(3, plan.steps.size, "EV steps")
            eq(15, plan.bursts.size, "bursts")
            eq(50, plan.referenceIso, "reference ISO")
            check(plan.bursts.any { it.digitalGain && it.iso == 800 }) { "ISO 800 should be digital gain" }
        }

        test("fault-free sweep through the JNI sink: pack == noisecal calibrate of its recording") {
            val c = clean
            val cliPack = calibrate(c.recording, File(c.pack.parentFile, "cli.pack"))
            assertSameBytes(c.pack, cliPack, "app pack vs CLI pack")
            println("    ${c.notes}; pack ${c.pack.length()} bytes, recording ${c.recording.length()} bytes")
        }

        test("faults + kill mid-burst + resume: pack == calibrate of the final recording == fault-free pack") {
            val f = faulty
            val cliPack = calibrate(f.recording, File(f.pack.parentFile, "cli.pack"))
            assertSameBytes(f.pack, cliPack, "resumed app pack vs CLI pack of the final recording")
            assertSameBytes(clean.pack, f.pack, "fault-free pack vs faulty/resumed pack")
            println("    ${f.notes}")
        }

        test("kill without closing the session (no End record), resume: pack == calibrate of the recording == fault-free pack") {
            val f = abandoned
            val cliPack = calibrate(f.recording, File(f.pack.parentFile, "cli.pack"))
            assertSameBytes(f.pack, cliPack, "resumed app pack vs CLI pack of the final recording")
            assertSameBytes(clean.pack, f.pack, "fault-free pack vs abandoned/resumed pack")
            println("    ${f.notes}")
        }

        test("inspect --json lists the planned target ISOs") {
            val root = Json.parse(cli("inspect", faulty.pack.path, "--json")) as? Map<*, *>
                ?: throw Failure("inspect --json did not print an object")
            val isos = (root["isos"] as? List<*>)?.map { it as Map<*, *> } ?: throw Failure("inspect --json has no \"isos\" array")
            eq(targetIsos, isos.map { (it["iso"] as Number).toInt() }, "ISOs in the pack (inspect --json)")
            eq(50, (root["reference_iso"] as Number).toInt(), "reference ISO")
            eq(listOf(128, 96), listOf((root["width"] as Number).toInt(), (root["height"] as Number).toInt()), "size")
            eq(10, (root["bit_depth"] as Number).toInt(), "bit depth")
            eq(0, plan.sensor.binWidth, "the plan leaves the bin width to the core")
            val core = NoisecalSession.defaultBinWidth(capabilities.whiteLevel, capabilities.blackLevelPattern.map { it.toFloat() }.toFloatArray())
            eq(core, (root["bin_width"] as Number).toInt(), "bin width (the pack's vs the core's default)")
            eq(CapturePlanner.estimatePackBytes(capabilities, plan.targetIsos, core), plan.estimatedPackBytes, "pack estimate at the core's bin width")
            eq("RGGB", root["cfa"], "CFA")
            eq(capabilities.make to capabilities.model, root["make"] to root["model"], "make/model")
            val framesPerIso = plan.bursts.filter { it.role == BurstRole.TARGET }
                .groupBy { it.iso }.mapValues { e -> e.value.sumOf { it.frames } }
            for (m in isos) {
                val iso = (m["iso"] as Number).toInt()
                eq("calibrated", m["origin"], "ISO $iso origin")
                eq(framesPerIso[iso]!!.toLong(), (m["frames"] as Number).toLong(), "ISO $iso frames")
                val positions = m["positions"] as List<*>
                eq(4, positions.size, "ISO $iso CFA positions")
                for (p in positions.map { it as Map<*, *> }) {
                    val filled = (p["filled_bins"] as Number).toInt()
                    val samples = (p["samples"] as Number).toLong()
                    check(filled > 0 && samples > 0) { "ISO $iso ${p["name"]}: $samples samples, $filled filled bins" }
                }
            }
            println("    ISOs ${isos.map { it["iso"] }}, warnings ${root["warnings"]}")
        }

        test("dark step: covered frames through the JNI sink are accepted; pack == noisecal calibrate of its recording") {
            eq(listOf(50) + targetIsos, darkPlan.darkBursts.map { it.iso }, "dark bursts: base ISO and every target")
            val d = darkCovered
            eq(1, d.prompts.size, "one prompt")
            eq(null, d.prompts[0].notCovered, "nothing to retry")
            eq(0, d.last.framesRejected, "no frame refused")
            eq(darkPlan.darkFrames.toLong(), d.port.coveredFrames, "dark frames taken with the lens covered, none again")
            eq(darkPlan.totalFrames.toLong(), recordedFrames(d.outcome.summary), "every planned frame, dark ones included, recorded")
            assertSameBytes(d.pack, calibrate(d.recording, File(d.pack.parentFile, "cli.pack")), "app pack vs CLI pack (dark step)")
            // The pack has a fixed-pattern component per target ISO, near the simulated lens cap's
            // DSNU (LensCoveredScene: 0.4 DN × ISO / 50 per pixel).
            val fpn = fpnOf(d.pack)
            eq(targetIsos, fpn.keys.toList(), "ISOs with a fixed-pattern component (inspect --json)")
            for ((iso, component) in fpn) {
                val f = component ?: throw Failure("ISO $iso has no fpn component")
                eq(4, (f["dark_frames"] as Number).toInt(), "ISO $iso dark frames")
                eq(true, f["added"], "ISO $iso: the pattern is added at synthesis")
                val sd = (f["sd"] as Number).toDouble()
                val truth = 0.4 * iso / 50
                check(sd in 0.75 * truth..1.25 * truth) { "ISO $iso: fixed-pattern SD $sd DN, simulated $truth DN" }
            }
            println("    fixed-pattern SD per ISO: ${fpn.mapValues { "%.2f".format((it.value!!["sd"] as Number).toDouble()) }}")
            println("    ${darkPlan.darkBursts.size} dark bursts, pack ${d.pack.length()} bytes (lit-only sweep: ${clean.pack.length()})")
        }

        test("dark step with the lens uncovered: the core refuses the frame, the step is asked again and finishes covered") {
            val d = darkSweep("dark-uncovered", lens = { if (it == 0) LensAction.CONFIRM_UNCOVERED else LensAction.COVER })
            eq(2, d.prompts.size, "asked again after the refusal")
            val why = d.prompts[1].notCovered ?: throw Failure("the second prompt does not say why")
            check(why.contains("is not dark") && why.contains("cover")) { "the core's not-dark message: \"$why\"" }
            check(d.last.framesRejected >= 1) { "the lit frame was counted as rejected: ${d.last}" }
            eq(darkPlan.totalFrames, d.last.framesDone, "frames done after the retry")
            // The refused frame is not in the recording, and the retry's rollback cut nothing else.
            eq(darkPlan.totalFrames.toLong(), recordedFrames(d.outcome.summary), "recorded frames")
            assertSameBytes(d.pack, calibrate(d.recording, File(d.pack.parentFile, "cli.pack")), "app pack vs CLI pack (retried dark step)")
        }

        test("dark step skipped at the prompt: the session finishes on the lit sweep alone") {
            val d = darkSweep("dark-skipped", lens = { LensAction.SKIP })
            eq(1, d.prompts.size, "one prompt")
            check(d.last.darkSkipped) { "skip reported" }
            eq(0L, d.port.coveredFrames, "no dark frame taken")
            val litFrames = darkPlan.totalFrames - darkPlan.darkFrames
            eq(litFrames.toLong(), recordedFrames(d.outcome.summary), "only the lit sweep recorded")
            assertSameBytes(d.pack, calibrate(d.recording, File(d.pack.parentFile, "cli.pack")), "app pack vs CLI pack (skipped)")
            // Up to the prompt both runs took the same frames: only the dark frames tell the packs apart.
            val covered = darkCovered
            check(!Files.readAllBytes(d.pack.toPath()).contentEquals(Files.readAllBytes(covered.pack.toPath()))) {
                "the dark frames left the pack as the lit sweep alone makes it"
            }
            println("    pack ${d.pack.length()} bytes without the dark step, ${covered.pack.length()} with it")
            eq(targetIsos.associateWith { null }, fpnOf(d.pack), "no fixed-pattern component without dark frames")
        }
    }
}
