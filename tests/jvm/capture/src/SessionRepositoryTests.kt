package org.noisecal.capture.test

import java.io.ByteArrayOutputStream
import java.io.File
import java.io.IOException
import org.noisecal.capture.controller.Banner
import org.noisecal.capture.controller.CalibrationWorkflow
import org.noisecal.capture.controller.CaptureOutcome
import org.noisecal.capture.controller.CaptureRun
import org.noisecal.capture.controller.CaptureStart
import org.noisecal.capture.controller.PlanForm
import org.noisecal.capture.controller.SessionRepository
import org.noisecal.capture.controller.Setup
import org.noisecal.capture.controller.UiEvent
import org.noisecal.capture.controller.UiState
import org.noisecal.capture.controller.UiStateMachine
import org.noisecal.capture.plan.PlanInputs
import org.noisecal.capture.sim.SimulatedCameraPort

/**
 * The app without Android: the session repository in a temporary folder, the workflow over it,
 * the simulated camera and the fake sink, and the state machine folding every event, as the
 * ViewModel does. A "restart" is a new repository and workflow on the same folder.
 */
class App(val dir: File = tempDir("app"), val factory: RecordingSinkFactory = RecordingSinkFactory().withSensor(smallPlan().sensor)) {
    /** The recording path each sink factory was asked for. */
    val recordingPaths = mutableListOf<String?>()
    val repository = SessionRepository(dir) { rec -> recordingPaths += rec; factory }
    val workflow = CalibrationWorkflow(repository)
    var state: UiState = UiState.LoadingCameras
    val seen = mutableListOf<UiState>()
    /** A fresh simulated camera per run, as the app opens the camera again. */
    var port = SimulatedCameraPort(16, 8, TaggedFrames(), 6, 2 * 16 + 12, coveredSource = TaggedDarkFrames())

    fun dispatch(e: UiEvent) { state = UiStateMachine.reduce(state, e); seen += state }

    /** Permission granted, cameras read, preview metered and the form filled in, plan made. */
    fun toPlan(form: PlanForm = smallForm): UiState.Planned {
        dispatch(workflow.camerasFound(listOf(camera("1", supported = false), camera("0"))))
        dispatch(UiEvent.Metered(smallMetering))
        dispatch(UiEvent.FormEdited(form))
        dispatch(workflow.makePlan(expect<UiState.Preview>(state, "preview").setup))
        return expect(state, "planned")
    }

    /**
     * Starts the capture of the current plan and runs it to its end; [onProgress] may stop it;
     * [onPrompt] answers the cover-the-lens prompt (the screen's [UiState.CoverLens]).
     */
    fun capture(
        startOver: Boolean = false,
        onPrompt: (CaptureRun, UiState.CoverLens) -> Unit = { _, _ -> },
        onProgress: (CaptureRun, UiState.Capturing) -> Unit = { _, _ -> },
    ): CaptureOutcome {
        port = SimulatedCameraPort(16, 8, TaggedFrames(), 6, 2 * 16 + 12, coveredSource = TaggedDarkFrames())
        val start = workflow.startCapture(expect(state, "planned"), startOver, port, config = fastConfig, clock = FakeClock())
        val run = (start as? CaptureStart.Ready)?.run ?: throw Failure("capture refused: $start")
        dispatch(run.started)
        return run.run { e ->
            dispatch(e)
            when (val s = state) {
                is UiState.Capturing -> onProgress(run, s)
                is UiState.CoverLens -> onPrompt(run, s)
                else -> {}
            }
        }
    }
}

class SessionRepositoryTests : Suite("repository") {
    init {
        test("a whole calibration: plan, capture, Done with the pack; the next start of the app shows it finished") {
            val app = App()
            val p = app.toPlan()
            eq(smallPlan().fingerprint, p.capturable?.fingerprint, "the form gives the small plan")
            eq(null, p.resume, "nothing to resume in an empty folder")
            val outcome = app.capture()
            check(outcome is CaptureOutcome.Finished) { "$outcome" }
            val capturing = app.seen.filterIsInstance<UiState.Capturing>()
            check(capturing.size > 10) { "progress reached the screen: ${capturing.size} states" }
            eq(capturing.map { it.progress.framesDone }.sorted(), capturing.map { it.progress.framesDone }, "frames done never go back")
            eq(smallPlan().totalFrames, capturing.last().progress.framesDone, "every frame counted")
            val done = expect<UiState.Done>(app.state, "done")
            eq(app.repository.packFile.path, done.packPath, "pack path")
            check(File(done.packPath).isFile) { "pack written" }
            eq(PlanInputs("0", p.capturable!!.options), app.repository.savedInputs(), "inputs saved")
            eq(listOf<String?>(null), app.recordingPaths, "no recording asked for")
            checkSinkMatchesPlan(smallPlan(), app.factory.last.calls)

            val again = App(app.dir)
            again.dispatch(again.workflow.camerasFound(listOf(camera("1", supported = false), camera("0"))))
            val d = expect<UiState.Done>(again.state, "after a restart")
            eq(done.summary, d.summary, "summary from the progress record")
            eq(done.packPath, d.packPath, "same pack")
            eq(Setup(camera("0"), smallMetering, smallForm), d.setup, "setup restored from the saved inputs")
        }

        test("stopped mid-sweep: the next start offers the same plan, resuming continues from the checkpoint") {
            val app = App()
            app.toPlan()
            var stopAsked = false
            val out = app.capture { run, s ->
                if (!stopAsked && s.progress.burstsDone == 2) { stopAsked = true; run.requestStop(); app.dispatch(UiEvent.StopRequested) }
            }
            eq(CaptureOutcome.Stopped(2), out, "stopped after 2 bursts")
            check(app.seen.any { it is UiState.Capturing && it.stopping }) { "the screen showed the stop" }
            val stopped = expect<UiState.Planned>(app.state, "stopped")
            eq(2, stopped.resume?.completedBursts, "resume offer")
            check(stopped.canResume) { "resumable" }

            // The OS kills the app; on the next start the folder offers the run again.
            val factory = RecordingSinkFactory().withSensor(smallPlan().sensor)
            val again = App(app.dir, factory)
            again.dispatch(again.workflow.camerasFound(listOf(camera("0"))))
            val offer = expect<UiState.Planned>(again.state, "offer after a restart")
            eq(smallForm, offer.setup.form, "form restored")
            eq(2, offer.resume?.completedBursts, "bursts done")
            check(offer.banner is Banner.Info) { "${offer.banner}" }
            check(again.capture() is CaptureOutcome.Finished) { "resumed run finished" }
            check(factory.restoredFrom?.startsWith(app.dir.path) == true) { "restored from a checkpoint: ${factory.restoredFrom}" }
            checkSinkMatchesPlan(smallPlan(), factory.last.calls)
            expect<UiState.Done>(again.state, "done after resuming")
        }

        test("start over: the earlier session's files go, the resume is not taken, other files stay") {
            val app = App()
            app.toPlan()
            app.capture { run, s -> if (s.progress.burstsDone == 1) run.requestStop() }
            check(expect<UiState.Planned>(app.state, "stopped").canResume) { "resumable" }
            val foreign = File(app.dir, "notes.txt").apply { writeText("mine") }
            for (name in listOf("noise-model.pack", "noise-model.pack.tmp", "session.rec", "progress.txt.tmp", "checkpoint-0009.nck")) File(app.dir, name).writeText("x")
            val before = app.factory.made.size
            check(app.capture(startOver = true) is CaptureOutcome.Finished) { "finished" }
            eq(null, app.factory.restoredFrom, "not restored")
            eq(before + 1, app.factory.made.size, "a fresh sink")
            checkSinkMatchesPlan(smallPlan(), app.factory.last.calls)
            eq("mine", foreign.readText(), "foreign file kept")
            for (name in listOf("noise-model.pack.tmp", "session.rec", "progress.txt.tmp", "checkpoint-0009.nck")) {
                check(!File(app.dir, name).exists()) { "$name of the earlier session is still there" }
            }
        }

        test("forget: a new calibration empties the session but keeps the setup; the next start offers nothing") {
            val app = App()
            app.toPlan()
            app.capture()
            expect<UiState.Done>(app.state, "done")
            app.dispatch(app.workflow.forget())
            eq(UiState.Preview(Setup(camera("0"), smallMetering, smallForm)), app.state, "back to the preview")
            eq(emptyList<String>(), app.dir.listFiles()!!.map { it.name }.sorted(), "files left in the session folder")
            val again = App(app.dir)
            again.dispatch(again.workflow.camerasFound(listOf(camera("0"))))
            eq(UiState.Preview(Setup(camera("0"))), again.state, "a fresh start")
        }

        test("recording: the sink records into the session folder only when the plan asks for it") {
            val app = App()
            app.toPlan(smallForm.copy(recording = true))
            check(app.capture() is CaptureOutcome.Finished) { "finished" }
            eq(listOf<String?>(app.repository.recordingFile.path), app.recordingPaths, "recording path")
            eq(app.dir, app.repository.recordingFile.parentFile, "inside the session folder")
        }

        test("make plan: missing metering and a bad form are problems; a finished plan is not offered for resume") {
            val app = App()
            app.dispatch(app.workflow.camerasFound(listOf(camera("0"))))
            val setup = expect<UiState.Preview>(app.state, "preview").setup
            val noMeter = app.workflow.makePlan(setup)
            check(noMeter is UiEvent.Problem && noMeter.message.contains("not settled")) { "$noMeter" }
            val bad = app.workflow.makePlan(setup.copy(metering = smallMetering, form = smallForm.copy(frames = "many")))
            check(bad is UiEvent.Problem && bad.message.startsWith("Frames per burst")) { "$bad" }
            app.dispatch(bad)
            eq(Banner.Error((bad as UiEvent.Problem).message), expect<UiState.Preview>(app.state, "still the preview").banner, "shown")
            app.toPlan()
            app.capture()
            val again = app.workflow.makePlan(Setup(camera("0"), smallMetering, smallForm))
            check(again is UiEvent.PlanMade && again.resume == null) { "finished plan offered: $again" }
        }

        test("export: the pack's bytes to the document; no pack or no stream is a problem, not a crash") {
            val app = App()
            val none = app.workflow.exportPack { ByteArrayOutputStream() }
            check(none is UiEvent.Problem && none.message.startsWith("Saving failed")) { "$none" }
            app.toPlan()
            app.capture()
            val out = ByteArrayOutputStream()
            eq(UiEvent.Info("Model pack saved"), app.workflow.exportPack { out }, "saved")
            check(out.size() > 0) { "empty export" }
            eq(app.repository.packFile.readBytes().toList(), out.toByteArray().toList(), "same bytes")
            val noStream = app.workflow.exportPack { null }
            check(noStream is UiEvent.Problem && noStream.message.contains("no stream")) { "$noStream" }
            val failing = app.workflow.exportPack { object : java.io.OutputStream() { override fun write(b: Int) = throw IOException("disk full") } }
            check(failing is UiEvent.Problem && failing.message.contains("disk full")) { "$failing" }
        }

        test("a session folder that cannot be written refuses the start with the reason") {
            val parent = tempDir("ro")
            val notADir = File(parent, "session").apply { writeText("a file where the folder should be") }
            val app = App(notADir)
            app.toPlan()
            val start = app.workflow.startCapture(expect(app.state, "planned"), false, app.port)
            check(start is CaptureStart.Refused && start.problem.message.startsWith("Cannot write the session folder")) { "$start" }
            app.dispatch((start as CaptureStart.Refused).problem)
            check(expect<UiState.Planned>(app.state, "still planned").banner is Banner.Error) { "error shown" }
        }

        test("earlier session: none for another camera, a torn inputs file, or inputs that no longer make the plan") {
            val app = App()
            app.toPlan()
            app.capture { run, s -> if (s.progress.burstsDone == 1) run.requestStop() }
            check(app.repository.earlierSession(camera("0")) != null) { "offered for its camera" }
            eq(null, app.repository.earlierSession(camera("1")), "another camera")
            // The camera now reports a different range: the same inputs make another plan.
            val changed = camera("0").let { it.copy(capabilities = it.capabilities!!.copy(sensitivityRange = 100..800, maxAnalogSensitivity = 800)) }
            eq(null, app.repository.earlierSession(changed), "another plan")
            app.repository.inputsFile.writeText(app.repository.inputsFile.readText().take(40))
            eq(null, app.repository.savedInputs(), "torn inputs")
            eq(null, app.repository.earlierSession(camera("0")), "torn inputs offer nothing")
        }
    }
}
