package org.noisecal.capture.test

import java.io.File
import org.noisecal.capture.controller.Banner
import org.noisecal.capture.controller.CaptureOutcome
import org.noisecal.capture.controller.CapturePhase
import org.noisecal.capture.controller.CaptureProgress
import org.noisecal.capture.controller.CoverLensRequest
import org.noisecal.capture.controller.SessionStore
import org.noisecal.capture.controller.Setup
import org.noisecal.capture.controller.UiEvent
import org.noisecal.capture.controller.UiState
import org.noisecal.capture.plan.BurstRole
import org.noisecal.capture.plan.CapturePlan
import org.noisecal.capture.plan.CapturePlanner
import org.noisecal.capture.plan.Metering
import org.noisecal.capture.plan.PlanInputs
import org.noisecal.capture.plan.PlanOptions
import org.noisecal.capture.plan.PlanResult
import org.noisecal.capture.sim.LensAction
import org.noisecal.capture.sim.LensCoveredScene
import org.noisecal.capture.sim.SimExposure

/** The sink calls of [bursts] (plan order), with "step" before each reference burst. */
private fun callsOf(bursts: List<org.noisecal.capture.plan.Burst>): List<Triple<String, Int, Long>> = buildList {
    for (b in bursts) {
        if (b.role == BurstRole.REFERENCE) add(Triple("step", 0, b.exposureNs))
        repeat(b.frames) { add(Triple("frame", b.iso, b.exposureNs)) }
    }
}

private fun kinds(s: RecordingSink) = s.calls.map { Triple(it.kind, it.iso, it.exposureNs) }
private fun darkCall() = Triple("dark", 0, 0L)
private fun lit(p: CapturePlan) = p.bursts.filter { it.role != BurstRole.DARK }

/** The optional dark step: plan, controller (prompt, beginDark, not-dark retry, skip, stop), screen state, app flow. */
class DarkStepTests : Suite("dark step") {
    init {
        test("plan: off by default; on, one burst per ISO (reference first) after the sweep at that ISO's shortest exposure") {
            val c = caps(range = 50..3200, maxAnalog = 800)
            val o = PlanOptions(Metering(100, 10_000_000L))
            val off = planOk(CapturePlanner.plan(c, o))
            eq(false, o.darkFrames, "off by default")
            eq(emptyList<Any>(), off.darkBursts, "no dark bursts")
            check(off.bursts.none { it.role == BurstRole.DARK }) { "no dark role without the option" }
            check(!off.describe().contains("Dark step")) { off.describe() }

            val on = planOk(CapturePlanner.plan(c, o.copy(darkFrames = true)))
            checkInvariants(on)
            eq(off.steps, on.steps, "the lit sweep is unchanged")
            eq(listOf(50, 100, 200, 400, 800, 1600, 3200), on.darkBursts.map { it.iso }, "reference ISO, then every target")
            eq(off.bursts, on.bursts.take(off.bursts.size), "dark bursts come after the lit sweep")
            eq(on.darkBursts, on.bursts.drop(off.bursts.size), "…and last")
            // EV 0 at ISO 50 is 20 ms; EV −4 is the shortest: 1.25 ms at ISO 50, 1.25 ms · 50 / 3200 at ISO 3200.
            eq(1_250_000L, on.darkBursts.first().exposureNs, "ISO 50 at its shortest exposure")
            eq(19_531L, on.darkBursts.last().exposureNs, "ISO 3200 at its shortest exposure")
            for (d in on.darkBursts) {
                eq(BurstRole.DARK, d.role, "role of $d")
                eq(8, d.frames, "default frames of $d")
                eq(on.steps.size, d.stepIndex, "step index of $d")
                eq(off.bursts.filter { it.iso == d.iso }.minOf { it.exposureNs }, d.exposureNs, "shortest lit exposure of ISO ${d.iso}")
                eq(maxOf(d.exposureNs, c.minFrameDurationNs), d.frameDurationNs, "frame duration of $d")
                eq(d.iso > 800, d.digitalGain, "digital gain flag of $d")
            }
            eq(off.totalFrames + 7 * 8, on.totalFrames, "8 frames per ISO more")
            eq(7 * 8, on.darkFrames, "dark frames")
            eq(off.estimatedDurationNs + on.darkBursts.sumOf { 8 * it.frameDurationNs + o.settleOverheadNs }, on.estimatedDurationNs, "time estimate")
            check(on.fingerprint != off.fingerprint) { "the dark step is part of what is captured" }
            check(on.describe().contains("Dark step (lens covered): 7 bursts of 8 frames, ISO 50, 100, 200")) { on.describe() }
            check(on.darkBursts.first().toString().contains("dark ISO 50")) { "${on.darkBursts.first()}" }

            val twelve = planOk(CapturePlanner.plan(c, o.copy(darkFrames = true, darkFramesPerIso = 12)))
            check(twelve.darkBursts.all { it.frames == 12 }) { "configurable frames" }
            check(refused(CapturePlanner.plan(c, o.copy(darkFrames = true, darkFramesPerIso = 1))).any { it.contains("darkFramesPerIso") }) { "1 frame refused" }
            eq(off.fingerprint, planOk(CapturePlanner.plan(c, o.copy(darkFramesPerIso = 1))).fingerprint, "frames per dark burst ignored when off")
        }

        test("plan inputs and the form carry the dark step; inputs saved before it existed read as off") {
            val o = PlanOptions(Metering(100, 10_000_000L), darkFrames = true, darkFramesPerIso = 5)
            val inputs = PlanInputs("0", o)
            eq(inputs, PlanInputs.decode(inputs.encode()), "round trip")
            val old = inputs.encode().lines().filterNot { it.startsWith("dark") }.joinToString("\n")
            eq(PlanInputs("0", o.copy(darkFrames = false, darkFramesPerIso = PlanOptions.DEFAULT_DARK_FRAMES_PER_ISO)), PlanInputs.decode(old), "old inputs")
            eq(null, PlanInputs.decode(inputs.encode().replace("darkFrames=true", "darkFrames=yes")), "a bad flag")

            val form = smallForm.copy(darkFrames = true, darkFramesPerIso = "4")
            val fo = form.toOptions(smallMetering)
            eq(true, fo.darkFrames, "toggle")
            eq(4, fo.darkFramesPerIso, "frames per ISO")
            eq(form, org.noisecal.capture.controller.PlanForm.from(fo), "form round trip")
            eq(false, smallForm.toOptions(smallMetering).darkFrames, "off in the default form")
            val e = throws<IllegalArgumentException>("bad dark frames") { form.copy(darkFramesPerIso = "many").toOptions(smallMetering) }
            check(e.message!!.startsWith("Dark frames per ISO")) { "${e.message}" }
            // Off, the field is not read.
            eq(false, form.copy(darkFrames = false, darkFramesPerIso = "many").toOptions(smallMetering).darkFrames, "ignored when off")
        }

        test("simulated lens cap: covered frames are black level plus noise whatever the exposure") {
            val scene = LensCoveredScene(black = 64, white = 1023, referenceIso = 100)
            for (iso in listOf(100, 800)) {
                val f = scene.render(SimExposure(iso, 500_000_000L, 3, 64, 32))
                val mean = f.map { it.toInt() }.average()
                check(kotlin.math.abs(mean - 64) < 0.5) { "ISO $iso: mean $mean, black 64" }
                check(f.all { it in 30..100 }) { "ISO $iso: a sample far from black" }
                val sd = kotlin.math.sqrt(f.map { (it - mean) * (it - mean) }.average())
                check(sd > 1.0 && sd < 10.0) { "ISO $iso: noise sd $sd" }
            }
        }

        test("controller: after the lit sweep it prompts once, then beginDark and every dark burst of covered frames, checkpointed") {
            val plan = smallPlan(darkFrames = 3)
            val h = Harness(plan)
            val out = h.run()
            check(out is CaptureOutcome.Finished) { "outcome $out" }
            val sink = h.factory.last
            checkSinkMatchesPlan(plan, sink.calls)
            eq(callsOf(lit(plan)) + listOf(darkCall()) + callsOf(plan.darkBursts), kinds(sink), "beginDark before the dark frames")
            eq(1, h.user.requests.size, "one prompt")
            eq(CoverLensRequest(listOf(100, 200, 400), 9, 9L, null), h.user.requests[0], "what the prompt asks for")
            val asked = h.states.filter { it.phase == CapturePhase.AWAITING_LENS_COVER }
            eq(1, asked.size, "one waiting state")
            eq(lit(plan).sumOf { it.frames }, asked[0].framesDone, "asked after every lit frame, before any dark one")
            eq(9L, h.port.coveredFrames, "dark frames came through the covered lens, none re-taken")
            eq(0, sink.notDark, "no dark frame refused")
            eq(plan.bursts.size, sink.checkpoints.size, "a checkpoint per burst, dark ones included")
            eq(plan.bursts.indices.toSet(), SessionStore(h.dir).load()!!.completedBursts, "every burst completed")
            // Row 0 carries the tags (ISO, exposure, number): a few DN on a 16×8 frame; the rest is black.
            check(sink.means.takeLast(9).all { it < 12.0 }) { "dark frames are dark: ${sink.means.takeLast(9)}" }
            checkAllClosed(h.port)
            // Without the step nothing is asked.
            val plain = Harness(smallPlan())
            check(plain.run() is CaptureOutcome.Finished) { "plain run" }
            eq(0, plain.user.requests.size, "no prompt without a dark step")
            check(plain.factory.last.calls.none { it.kind == "dark" }) { "no beginDark without a dark step" }
        }

        test("controller: an uncovered lens is caught, the step rolled back and asked again with the reason; covered, it finishes") {
            val plan = smallPlan(darkFrames = 3)
            val h = Harness(plan, lens = { if (it == 0) LensAction.CONFIRM_UNCOVERED else LensAction.COVER })
            val out = h.run()
            check(out is CaptureOutcome.Finished) { "a refused dark frame is not a crash: $out" }
            eq(2, h.user.requests.size, "asked again")
            eq(null, h.user.requests[0].notCovered, "first prompt")
            val why = h.user.requests[1].notCovered
            check(why != null && why.contains("cover the lens")) { "the retry says why: $why" }
            eq(2, h.factory.made.size, "the session was rolled back to a checkpoint")
            eq(1, h.factory.made[0].notDark, "the first uncovered frame was refused")
            val litBursts = lit(plan).size
            eq(SessionStore(h.dir).checkpointFile(SessionStore(h.dir).checkpointName(litBursts)).path, h.factory.restoredFrom, "rolled back to the last lit burst")
            // The final session holds the plan exactly: no lit frame in its dark step, one beginDark.
            checkSinkMatchesPlan(plan, h.factory.last.calls)
            check(h.states.any { it.lastRejection?.startsWith("not dark") == true }) { "the rejection was shown" }
            val retry = h.states.last { it.phase == CapturePhase.AWAITING_LENS_COVER }
            check(retry.message?.contains("cover the lens fully") == true) { "${retry.message}" }
            eq(plan.totalFrames, h.states.last().framesDone, "frames done counted once")
            checkAllClosed(h.port)
        }

        test("controller: light in the middle of the dark step keeps the dark bursts already checkpointed and retakes the rest") {
            // 8 frames per dark burst: more than the 3 in flight when the light comes in.
            val plan = smallPlan(darkFrames = 8)
            val second = plan.darkBursts[1]
            val h = Harness(plan)
            var uncovered = false
            h.controller.addListener { p ->
                if (!uncovered && p.currentBurst == second && p.burstFramesAccepted == 1) { uncovered = true; h.port.lensCovered = false }
            }
            check(h.run() is CaptureOutcome.Finished) { "finished" }
            eq(2, h.user.requests.size, "asked again after the light")
            eq(listOf(200, 400), h.user.requests[1].isos, "only what is left is asked for")
            val expected = callsOf(lit(plan)) + listOf(darkCall()) + callsOf(listOf(plan.darkBursts[0])) +
                listOf(darkCall()) + callsOf(plan.darkBursts.drop(1))
            eq(expected, kinds(h.factory.last), "the partial burst is gone, the complete one stays")
            eq(plan.totalFrames, h.states.last().framesDone, "frames done")
        }

        test("controller: skipping at the prompt finishes normally without dark frames, also after a failed try") {
            for (actions in listOf(listOf(LensAction.SKIP), listOf(LensAction.CONFIRM_UNCOVERED, LensAction.SKIP))) {
                val plan = smallPlan(darkFrames = 3)
                val h = Harness(plan, lens = { actions[it] })
                val out = h.run()
                check(out is CaptureOutcome.Finished) { "$actions: $out" }
                eq(actions.size, h.user.requests.size, "$actions: prompts")
                eq(callsOf(lit(plan)), kinds(h.factory.last), "$actions: only the lit sweep in the session")
                eq(0L, h.port.coveredFrames, "$actions: the lens stayed open")
                val last = h.states.last()
                check(last.darkSkipped) { "$actions: skipped is reported" }
                eq(lit(plan).sumOf { it.frames }, last.framesTotal, "$actions: frames to do without the dark step")
                eq(last.framesTotal, last.framesDone, "$actions: all done")
                eq(CapturePhase.DONE, last.phase, "$actions: done")
                check(SessionStore(h.dir).load()!!.finished) { "$actions: the record says finished" }
                checkAllClosed(h.port)
            }
        }

        test("controller: stop at the prompt keeps the lit sweep; the resumed run asks again and takes the dark step") {
            val plan = smallPlan(darkFrames = 2)
            val dir = tempDir("dark-stop")
            // The user would skip, but the stop (asked while the prompt waits) comes first.
            val stopper = Harness(plan, dir, lens = { LensAction.SKIP })
            val ctl = stopper.controller
            ctl.addListener { if (it.phase == CapturePhase.AWAITING_LENS_COVER) ctl.requestStop() }
            val out = ctl.run()
            eq(CaptureOutcome.Stopped(lit(plan).size), out, "stopped with the lit sweep done")
            eq(lit(plan).indices.toSet(), SessionStore(dir).load()!!.completedBursts, "the lit sweep is checkpointed")
            check(!SessionStore(dir).load()!!.finished) { "not finished" }
            val resumed = Harness(plan, dir)
            check(resumed.run() is CaptureOutcome.Finished) { "resumed" }
            check(resumed.factory.restoredFrom != null) { "resumed from the checkpoint" }
            eq(1, resumed.user.requests.size, "asked again")
            checkSinkMatchesPlan(plan, resumed.factory.last.calls)
        }

        test("screen: a progress asking for the lens shows the CoverLens prompt; covered or skipped goes back to Capturing") {
            val plan = smallPlan(darkFrames = 3)
            val setup = Setup(camera(), smallMetering, smallForm.copy(darkFrames = true, darkFramesPerIso = "3"))
            val capturing = fold(UiState.Planned(setup, PlanResult.Ok(plan)), UiEvent.CaptureStarted(plan))
            val request = CoverLensRequest(listOf(100, 200, 400), 9, 9L)
            val ask = CaptureProgress.start(plan).copy(phase = CapturePhase.AWAITING_LENS_COVER, coverLens = request, framesDone = 30)
            val prompt = expect<UiState.CoverLens>(fold(capturing, UiEvent.Progress(ask)), "prompt")
            eq(request, prompt.request, "request")
            eq(setup, prompt.setup, "setup kept")
            eq(plan, prompt.plan, "plan kept")
            val covered = expect<UiState.Capturing>(fold(prompt, UiEvent.LensCovered), "covered")
            eq(ask, covered.progress, "progress kept")
            expect<UiState.Capturing>(fold(prompt, UiEvent.DarkFramesSkipped), "skipped")
            // The controller going on (or a retry) also moves the screen.
            val running = ask.copy(phase = CapturePhase.RUNNING, coverLens = null)
            expect<UiState.Capturing>(fold(prompt, UiEvent.Progress(running)), "running again")
            val retry = ask.copy(coverLens = request.copy(notCovered = "light: cover the lens"))
            eq("light: cover the lens", expect<UiState.CoverLens>(fold(covered, UiEvent.Progress(running), UiEvent.Progress(retry)), "retry").request.notCovered, "reason")
            // Answers outside the prompt change nothing.
            eq(capturing, fold(capturing, UiEvent.LensCovered, UiEvent.DarkFramesSkipped), "no prompt, no answer")
            // Stop, permission, banners and the end work from the prompt.
            eq(true, expect<UiState.CoverLens>(fold(prompt, UiEvent.StopRequested), "stop").stopping, "stopping")
            eq(prompt, fold(prompt, UiEvent.PermissionAnswered(false)), "a prompt is a running capture")
            eq(Banner.Error("x"), expect<UiState.CoverLens>(fold(prompt, UiEvent.Problem("x")), "banner").banner, "banner")
            eq(prompt, fold(prompt, UiEvent.SessionForgotten), "not forgotten while capturing")
            val stopped = expect<UiState.Planned>(fold(prompt, UiEvent.CaptureEnded(CaptureOutcome.Stopped(6), null)), "stopped")
            check(stopped.banner?.text?.contains("6 of ${plan.bursts.size}") == true) { "${stopped.banner}" }
            expect<UiState.Done>(fold(prompt, UiEvent.CaptureEnded(CaptureOutcome.Finished("/p", "s"), null)), "finished")
        }

        test("app: the form's toggle plans the step; the prompt is answered through the run and the session finishes with it") {
            for (action in listOf(LensAction.COVER, LensAction.SKIP)) {
                val app = App()
                val p = app.toPlan(smallForm.copy(darkFrames = true, darkFramesPerIso = "3"))
                val plan = p.capturable!!
                eq(smallPlan(darkFrames = 3).fingerprint, plan.fingerprint, "the form gives the small plan with its dark step")
                val outcome = app.capture(onPrompt = { run, prompt ->
                    eq(listOf(100, 200, 400), prompt.request.isos, "$action: the prompt names the ISOs")
                    // What the screen's buttons do (CaptureViewModel): answer the run, reduce the event.
                    if (action == LensAction.COVER) {
                        app.port.lensCovered = true
                        run.confirmLensCovered(); app.dispatch(UiEvent.LensCovered)
                    } else {
                        run.skipDarkFrames(); app.dispatch(UiEvent.DarkFramesSkipped)
                    }
                })
                check(outcome is CaptureOutcome.Finished) { "$action: $outcome" }
                eq(1, app.seen.count { it is UiState.CoverLens }, "$action: the prompt was shown once")
                expect<UiState.Done>(app.state, "$action: done")
                check(File(app.repository.packFile.path).isFile) { "$action: pack" }
                val calls = kinds(app.factory.last)
                if (action == LensAction.COVER) checkSinkMatchesPlan(plan, app.factory.last.calls)
                else eq(callsOf(lit(plan)), calls, "skipped: the lit sweep only")
            }
        }
    }
}
