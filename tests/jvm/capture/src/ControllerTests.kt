package org.noisecal.capture.test

import java.io.File
import org.noisecal.capture.controller.CaptureController
import org.noisecal.capture.controller.CaptureOutcome
import org.noisecal.capture.controller.CapturePhase
import org.noisecal.capture.controller.CaptureProgress
import org.noisecal.capture.controller.ControllerConfig
import org.noisecal.capture.controller.ProgressRecord
import org.noisecal.capture.controller.SessionStore
import org.noisecal.capture.controller.ThermalLevel
import org.noisecal.capture.controller.ThermalStatusSource
import org.noisecal.capture.plan.BurstRole
import org.noisecal.capture.plan.CapturePlan
import org.noisecal.capture.plan.CapturePlanner
import org.noisecal.capture.plan.Metering
import org.noisecal.capture.plan.PlanOptions
import org.noisecal.capture.sim.LensAction
import org.noisecal.capture.sim.SimBehaviour
import org.noisecal.capture.sim.SimulatedUser
import org.noisecal.capture.sim.SimulatedCameraPort
import org.noisecal.capture.sim.SimulatedProcessDeath

/**
 * A tiny sensor and a short plan: 2 EV steps × (reference + ISO 200 + ISO 400), 5 frames each; with
 * [darkFrames], the dark step too (ISO 100, 200, 400, that many frames each).
 */
fun smallPlan(frames: Int = 5, evMin: Double = -1.0, evMax: Double = 0.0, darkFrames: Int? = null): CapturePlan = planOk(CapturePlanner.plan(
    caps(range = 100..400, maxAnalog = 400, exposure = 10_000L..1_000_000_000L, minFrame = 1_000_000L, w = 16, h = 8),
    PlanOptions(Metering(100, 2_000_000L), evMin = evMin, evMax = evMax, framesPerBurst = frames, settleOverheadNs = 0,
        darkFrames = darkFrames != null, darkFramesPerIso = darkFrames ?: PlanOptions.DEFAULT_DARK_FRAMES_PER_ISO),
))

val fastConfig = ControllerConfig(frameTimeoutMs = 30L, thermalCheckIntervalMs = 0L, thermalPollMs = 1000L)

class Harness(
    val plan: CapturePlan,
    val dir: File = tempDir("ctl"),
    val behaviour: SimBehaviour = SimBehaviour(),
    val factory: RecordingSinkFactory = RecordingSinkFactory().withSensor(plan.sensor),
    val maxImages: Int = 6,
    val padding: Int = 12,
    val thermal: ThermalStatusSource = ThermalStatusSource.NONE,
    val config: ControllerConfig = fastConfig,
    val clock: FakeClock = FakeClock(),
    /** What the person at the phone does at each cover-the-lens prompt (plans with a dark step). */
    lens: (prompt: Int) -> LensAction = { LensAction.COVER },
) {
    val port = SimulatedCameraPort(plan.sensor.width, plan.sensor.height, TaggedFrames(), maxImages, 2 * plan.sensor.width + padding,
        behaviour, TaggedDarkFrames())
    val controller = CaptureController(plan, port, factory, SessionStore(dir), thermal, config, clock)
    val states = mutableListOf<CaptureProgress>()
    init { controller.addListener { states += it } }
    val user = SimulatedUser(port, lens).attach(controller)
    fun run(): CaptureOutcome = controller.run()
}

/** The frames a sink got, as (ISO, exposure) per step: what a pack is made of. */
fun framesOf(s: RecordingSink) = s.calls.filter { it.kind != "checkpoint" }.map { Triple(it.kind, it.iso, it.exposureNs) }

/**
 * Checks that the sink got exactly the plan: one step call per EV step, then each burst's frames at
 * its settings; one dark call before the dark bursts.
 */
fun checkSinkMatchesPlan(plan: CapturePlan, calls: List<SinkCall>) {
    val expected = mutableListOf<Triple<String, Int, Long>>()
    for (b in plan.bursts) {
        if (b.role == BurstRole.REFERENCE) expected += Triple("step", 0, b.exposureNs)
        if (b == plan.darkBursts.firstOrNull()) expected += Triple("dark", 0, 0L)
        repeat(b.frames) { expected += Triple("frame", b.iso, b.exposureNs) }
    }
    eq(expected, calls.map { Triple(it.kind, it.iso, it.exposureNs) }, "sink calls")
}

fun checkAllClosed(port: SimulatedCameraPort) {
    eq(port.imagesDelivered, port.imagesClosed, "every image closed")
    eq(0, port.openImages, "images left open")
    eq(0L, port.readerOverruns, "reader overruns")
    eq(0L, port.accessAfterClose, "buffer used after close")
}

class ControllerTests : Suite("controller") {
    init {
        test("clean run: every burst in order, in-flight below maxImages - 2, all images closed, checkpoints per burst") {
            val h = Harness(smallPlan())
            val out = h.run()
            check(out is CaptureOutcome.Finished) { "outcome $out" }
            val sink = h.factory.last
            checkSinkMatchesPlan(h.plan, sink.calls)
            checkAllClosed(h.port)
            check(h.port.maxOpenImages < h.port.maxImages - 2) { "max open ${h.port.maxOpenImages} with maxImages ${h.port.maxImages}" }
            eq(h.plan.bursts.size, sink.checkpoints.size, "one checkpoint per burst")
            check(sink.closed) { "sink closed at the end" }
            val rec = SessionStore(h.dir).load()!!
            check(rec.finished && rec.completedBursts == h.plan.bursts.indices.toSet()) { "progress record $rec" }
            check(File(h.dir, "noise-model.pack").isFile) { "pack written" }
            eq(1, h.dir.listFiles()!!.count { it.name.startsWith("checkpoint-") }, "old checkpoints pruned")
            val last = h.states.last()
            eq(CapturePhase.DONE, last.phase, "final phase")
            eq(h.plan.totalFrames, last.framesDone, "frames done")
            eq(0, last.framesRejected, "nothing rejected")
            check(h.states.zipWithNext().all { (a, b) -> b.framesDone >= a.framesDone }) { "progress never goes back" }
            check(h.states.any { it.coverage.isNotEmpty() }) { "coverage reported" }
        }

        test("settings that did not apply: the first frames after each change are rejected and re-taken") {
            val h = Harness(smallPlan(), behaviour = SimBehaviour(settingsLagFrames = 2))
            val out = h.run()
            check(out is CaptureOutcome.Finished) { "outcome $out" }
            checkSinkMatchesPlan(h.plan, h.factory.last.calls)
            // Every burst after the first changes ISO or exposure: 2 stale frames each.
            eq(2 * (h.plan.bursts.size - 1), h.states.last().framesRejected, "rejected frames")
            check(h.states.last().lastRejection!!.contains("planned")) { "reason names the plan: ${h.states.last().lastRejection}" }
            checkAllClosed(h.port)
        }

        test("dropped images, dropped results and failed captures are re-taken; nothing leaks") {
            val h = Harness(smallPlan(), behaviour = SimBehaviour(
                dropImage = { it % 7L == 3L }, dropResult = { it % 11L == 5L }, failCapture = { it % 13L == 8L }))
            val out = h.run()
            check(out is CaptureOutcome.Finished) { "outcome $out" }
            checkSinkMatchesPlan(h.plan, h.factory.last.calls)
            val lost = h.states.last().framesLost
            // Frames 0..N: at least the failures and drops in the first plan.totalFrames sequence numbers.
            val n = h.plan.totalFrames.toLong()
            val expectedMin = (0 until n).count { it % 7L == 3L || it % 11L == 5L || it % 13L == 8L }
            check(lost >= expectedMin) { "lost $lost, expected at least $expectedMin" }
            checkAllClosed(h.port)
            check(h.port.maxOpenImages < h.port.maxImages - 2 + 1) { "open images ${h.port.maxOpenImages}" }
        }

        test("exposure off the plan by more than 2 % is rejected, within it accepted with the reported value") {
            val h = Harness(smallPlan(), behaviour = SimBehaviour(exposureScale = { seq ->
                when (seq) { in 3L..5L -> 1.1; 8L -> 0.99; else -> 1.0 } }))
            val out = h.run()
            check(out is CaptureOutcome.Finished) { "outcome $out" }
            eq(3, h.states.last().framesRejected, "three frames 10 % too long")
            check(h.states.last().lastRejection!!.contains("exposure")) { "reason: ${h.states.last().lastRejection}" }
            val frames = h.factory.last.calls.filter { it.kind == "frame" }
            // The frame 1 % short is kept, with the exposure the camera reported (the core needs the real one).
            eq(1, frames.count { c -> h.plan.bursts.none { it.exposureNs == c.exposureNs } }, "frames with a reported, not planned, exposure")
            checkAllClosed(h.port)
        }

        test("black level off the plan is rejected") {
            val h = Harness(smallPlan(), behaviour = SimBehaviour(dynamicBlackLevels = { seq ->
                if (seq in 4L..6L) floatArrayOf(90f, 64f, 64f, 64f) else floatArrayOf(64.5f, 64f, 63.5f, 64f) }))
            val out = h.run()
            check(out is CaptureOutcome.Finished) { "outcome $out" }
            eq(3, h.states.last().framesRejected, "three frames with a black level 26 DN off")
            check(h.states.last().lastRejection!!.contains("black level")) { "reason" }
            checkSinkMatchesPlan(h.plan, h.factory.last.calls)
        }

        test("a kill in the middle of a target burst resumes from the last checkpoint to the same result") {
            val plan = smallPlan()
            val clean = Harness(plan)
            check(clean.run() is CaptureOutcome.Finished) { "clean run" }
            val dir = tempDir("kill")
            // Burst 0 (ref) and 1 (ISO 200) take 10 frames; kill 2 frames into burst 2 (ISO 400).
            val first = Harness(plan, dir = dir, behaviour = SimBehaviour(deathAfterFrames = 12))
            throws<SimulatedProcessDeath>("the kill") { first.run() }
            val rec = SessionStore(dir).load()!!
            eq(setOf(0, 1), rec.completedBursts, "bursts recorded as done")
            check(!rec.finished) { "not finished" }
            val factory = RecordingSinkFactory().withSensor(plan.sensor)
            val second = Harness(plan, dir = dir, factory = factory)
            val out = second.run()
            check(out is CaptureOutcome.Finished) { "resumed outcome $out" }
            check(factory.restoredFrom!!.endsWith("checkpoint-0002.nck")) { "restored from ${factory.restoredFrom}" }
            eq(2, second.states.first { it.resumedFromBurst != null }.resumedFromBurst, "resumed after 2 bursts")
            // Same frames in the same steps as the uninterrupted run: the partial burst was taken again, once.
            eq(framesOf(clean.factory.last), framesOf(factory.last), "resumed session equals the uninterrupted one")
            checkSinkMatchesPlan(plan, factory.last.calls)
            eq(File(clean.dir, "noise-model.pack").readText(), File(dir, "noise-model.pack").readText(), "same pack")
            checkAllClosed(second.port)
            // The resumed run asked for the rest only (plus nothing re-taken in a clean camera).
            eq((plan.totalFrames - 10).toLong(), second.port.requestsSubmitted, "frames requested after resume")
        }

        test("a kill during a reference burst resumes with a new step; a finished session is not redone") {
            val plan = smallPlan()
            val dir = tempDir("kill2")
            // Step 0 is bursts 0..2 (15 frames); kill 3 frames into burst 3, the reference of step 1.
            throws<SimulatedProcessDeath>("the kill") { Harness(plan, dir = dir, behaviour = SimBehaviour(deathAfterFrames = 18)).run() }
            eq(setOf(0, 1, 2), SessionStore(dir).load()!!.completedBursts, "step 0 done")
            val factory = RecordingSinkFactory().withSensor(plan.sensor)
            check(Harness(plan, dir = dir, factory = factory).run() is CaptureOutcome.Finished) { "resumed" }
            checkSinkMatchesPlan(plan, factory.last.calls)
            eq(2, factory.last.calls.count { it.kind == "step" }, "one step call per EV step")
            // Running again finds the finished session and does nothing.
            val again = Harness(plan, dir = dir)
            val out = again.run()
            check(out is CaptureOutcome.Finished) { "again: $out" }
            eq(0L, again.port.requestsSubmitted, "nothing captured again")
            eq(0, again.factory.made.size, "no session opened again")
        }

        test("an earlier session of another plan is not resumed") {
            val dir = tempDir("other")
            throws<SimulatedProcessDeath>("kill") { Harness(smallPlan(), dir = dir, behaviour = SimBehaviour(deathAfterFrames = 12)).run() }
            val other = smallPlan(frames = 4)
            eq(false, CaptureController.resumeInfo(SessionStore(dir), other)!!.samePlan, "resume info")
            val h = Harness(other, dir = dir)
            check(h.run() is CaptureOutcome.Finished) { "fresh run" }
            eq(null, h.factory.restoredFrom, "not restored")
            checkSinkMatchesPlan(other, h.factory.last.calls)
        }

        test("thermal: pauses at SEVERE without requests in flight, resumes at MODERATE") {
            var reads = 0
            val clock = FakeClock()
            // LIGHT for a while, then SEVERE until the controller has slept two polls, then MODERATE.
            val script = ThermalStatusSource {
                reads++
                when {
                    reads < 8 -> ThermalLevel.LIGHT
                    clock.sleptMs < 2 * fastConfig.thermalPollMs -> ThermalLevel.SEVERE
                    else -> ThermalLevel.MODERATE
                }
            }
            var submittedWhilePaused = 0L
            var portRef: SimulatedCameraPort? = null
            var atPause = -1L
            val h = Harness(smallPlan(), thermal = script, clock = clock)
            portRef = h.port
            h.controller.addListener { s ->
                if (s.phase == CapturePhase.PAUSED_THERMAL) {
                    if (atPause < 0) atPause = portRef.requestsSubmitted
                    submittedWhilePaused = portRef.requestsSubmitted - atPause
                    eq(0, portRef.openImages, "images open while paused")
                }
            }
            val out = h.run()
            check(out is CaptureOutcome.Finished) { "outcome $out" }
            check(h.states.any { it.phase == CapturePhase.PAUSED_THERMAL }) { "paused" }
            check(h.states.any { it.thermal == ThermalLevel.SEVERE }) { "thermal level shown" }
            eq(0L, submittedWhilePaused, "requests submitted while paused")
            // Paused until MODERATE: one read after each poll sleep, the second one cool enough.
            eq(2 * fastConfig.thermalPollMs, h.clock.sleptMs, "time slept while hot")
            check(h.states.any { it.phase == CapturePhase.RUNNING && it.thermal == ThermalLevel.MODERATE }) { "capturing again at MODERATE" }
            checkSinkMatchesPlan(h.plan, h.factory.last.calls)
            checkAllClosed(h.port)
        }

        test("a camera that never applies the settings fails the burst with the reason, resumably") {
            val h = Harness(smallPlan(), behaviour = SimBehaviour(settingsLagFrames = 1_000_000))
            val out = h.run()
            check(out is CaptureOutcome.Failed && out.resumable) { "outcome $out" }
            val reason = (out as CaptureOutcome.Failed).reason
            check(reason.contains("burst 1") && reason.contains("ISO 100 reported, 200 planned")) { reason }
            eq(CapturePhase.FAILED, h.states.last().phase, "phase")
            eq(setOf(0), SessionStore(h.dir).load()!!.completedBursts, "burst 0 kept")
            checkAllClosed(h.port)
        }

        test("frames the session refuses are re-taken") {
            val factory = RecordingSinkFactory(refuse = { it == 3 || it == 4 })
            val h = Harness(smallPlan(), factory = factory)
            check(h.run() is CaptureOutcome.Finished) { "finished" }
            eq(2, h.states.last().framesRejected, "refused frames counted")
            check(h.states.any { it.lastRejection?.contains("fake refusal") == true }) { "reason shown" }
            checkSinkMatchesPlan(h.plan, factory.last.calls)
        }

        test("motion verdict per burst: a burst that moved is marked for a re-take with its shift, samples left out and refusals; still ones are steady") {
            val plan = smallPlan(frames = 5)
            val targets = plan.bursts.filter { it.role != org.noisecal.capture.plan.BurstRole.REFERENCE && it.role != org.noisecal.capture.plan.BurstRole.DARK }
            check(targets.size >= 2) { "the plan has ${targets.size} target bursts" }
            val moving = targets[1]
            // Pushes arrive in plan order, one per accepted frame: the moving burst's pushes
            // are those after every frame of the bursts before it (plus one refusal).
            val first = plan.bursts.takeWhile { it.index != moving.index }.sumOf { it.frames }
            val factory = RecordingSinkFactory(motion = { n, iso ->
                when {
                    iso == plan.sensor.referenceIso -> null
                    n == first + 1 -> 2.6 // refused: over 2 px
                    n in first until first + moving.frames + 1 -> 0.45
                    else -> 0.02
                }
            })
            val h = Harness(plan, factory = factory)
            val outcome = h.run()
            check(outcome is CaptureOutcome.Finished) { "finished: $outcome" }
            val verdicts = (outcome as CaptureOutcome.Finished).motion
            eq(targets.map { it.index }, verdicts.map { it.burst.index }, "one verdict per target burst, in order")
            val m = verdicts.single { it.burst.index == moving.index }
            eq(moving.frames, m.framesRegistered, "the moving burst's frames registered")
            eq(1, m.framesRefused, "one frame refused for moving over 2 px")
            check(m.retake && m.maxShiftPx == 0.45 && m.leftOut > 0) { "moving burst: $m" }
            check(m.verdict.contains("re-take") && m.verdict.contains("0.45 px") && m.verdict.contains("sturdier mount")) { m.verdict }
            for (v in verdicts - m) {
                check(!v.retake && v.framesRefused == 0 && v.maxShiftPx == 0.02) { "still burst: $v" }
                check(v.verdict.contains("steady")) { v.verdict }
            }
            eq(listOf(moving.index), h.states.last().retakeBursts.map { it.burst.index }, "progress lists the burst to re-take")
            check(h.states.any { it.lastRejection?.startsWith("moved:") == true }) { "the refusal is shown" }
            eq(1, h.states.last().framesRejected, "the refused frame counted and re-taken")
            checkSinkMatchesPlan(h.plan, factory.last.calls)
            // The result screen gets the verdicts and says which burst to take again.
            val capturing = org.noisecal.capture.controller.UiStateMachine.reduce(
                org.noisecal.capture.controller.UiState.Planned(
                    org.noisecal.capture.controller.Setup(camera(), smallMetering, smallForm),
                    org.noisecal.capture.plan.PlanResult.Ok(plan)),
                org.noisecal.capture.controller.UiEvent.CaptureStarted(plan))
            val done = expect<org.noisecal.capture.controller.UiState.Done>(
                fold(capturing, org.noisecal.capture.controller.UiEvent.CaptureEnded(outcome, null)), "finished")
            eq(listOf(moving.index), done.retakeBursts.map { it.burst.index }, "the result check lists the burst to re-take")
            val banner = done.banner
            check(banner is org.noisecal.capture.controller.Banner.Error && banner.text.contains("re-take")) { "banner: $banner" }
        }

        test("stop request: stops between events and resumes later") {
            val plan = smallPlan()
            val dir = tempDir("stop")
            val h = Harness(plan, dir = dir)
            h.controller.addListener { if (it.framesDone == 17) h.controller.requestStop() }
            val out = h.run()
            eq(CaptureOutcome.Stopped(3), out, "stopped after 3 bursts")
            checkAllClosed(h.port)
            val factory = RecordingSinkFactory().withSensor(plan.sensor)
            check(Harness(plan, dir = dir, factory = factory).run() is CaptureOutcome.Finished) { "resumed" }
            checkSinkMatchesPlan(plan, factory.last.calls)
        }

        test("a camera error fails the run; a sink that cannot open fails it unresumably") {
            val plan = smallPlan()
            val h = Harness(plan, behaviour = SimBehaviour(failCapture = { true }))
            val out = h.run()
            check(out is CaptureOutcome.Failed && out.reason.contains("simulated failure")) { "$out" }
            val broken = object : org.noisecal.capture.controller.FrameSinkFactory {
                override fun create(sensor: org.noisecal.capture.plan.SensorSpec) = throw UnsatisfiedLinkError("no noisecal_jni in java.library.path")
                override fun restore(checkpointPath: String) = throw IllegalStateException("unused")
            }
            val h2 = Harness(plan, factory = RecordingSinkFactory())
            val c2 = CaptureController(plan, h2.port, broken, SessionStore(tempDir("broken")), config = fastConfig)
            val out2 = c2.run()
            check(out2 is CaptureOutcome.Failed && !out2.resumable && out2.reason.contains("noisecal_jni")) { "$out2" }
        }

        test("progress record round-trips and a torn record reads as none") {
            val r = ProgressRecord("abc", setOf(3, 1, 2), "checkpoint-0003.nck", finished = false, summary = "two\nlines")
            eq(r.copy(summary = "two lines"), ProgressRecord.decode(r.encode())!!, "round trip")
            eq(null, ProgressRecord.decode(r.encode().take(30)), "torn record")
            eq(null, ProgressRecord.decode("garbage"), "garbage")
        }
    }
}
