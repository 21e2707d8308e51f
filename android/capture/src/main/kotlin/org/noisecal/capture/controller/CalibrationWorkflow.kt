package org.noisecal.capture.controller

import java.io.IOException
import java.io.OutputStream
import org.noisecal.capture.plan.CapturePlan
import org.noisecal.capture.plan.CapturePlanner
import org.noisecal.capture.plan.PlanResult

/**
 * The steps of a calibration that read or write the session folder or run the planner, as plain
 * blocking calls that answer with a [UiEvent] for [UiStateMachine]. No coroutines here (this
 * library depends on the Kotlin standard library only, so the host tests need nothing else): the
 * app's ViewModel calls each step on `Dispatchers.IO` in `viewModelScope` and reduces the answer
 * into its `StateFlow<UiState>`.
 */
class CalibrationWorkflow(val repository: SessionRepository) {

    /** The cameras were read: choose one (the saved session's camera first) and look for its earlier session. */
    fun camerasFound(cameras: List<CameraChoice>): UiEvent.CamerasFound {
        val chosen = CameraChoice.choose(cameras, repository.savedInputs()?.cameraId)
        return UiEvent.CamerasFound(cameras, chosen, chosen?.let(repository::earlierSession))
    }

    /** Plans from [setup]: [UiEvent.PlanMade], or [UiEvent.Problem] when the metering or the form is missing or wrong. */
    fun makePlan(setup: Setup): UiEvent {
        val caps = setup.camera.capabilities ?: return UiEvent.Problem("Camera ${setup.camera.id} reported nothing to plan with")
        val metering = setup.metering
            ?: return UiEvent.Problem("The exposure has not settled yet: point the camera at the chart and wait a moment")
        val options = try {
            setup.form.toOptions(metering)
        } catch (e: IllegalArgumentException) {
            return UiEvent.Problem(e.message ?: "The plan form is not complete")
        }
        val result = CapturePlanner.plan(caps, options)
        val resume = (result as? PlanResult.Ok)?.let { repository.resumeInfo(it.plan) }?.takeIf { it.samePlan && !it.finished }
        return UiEvent.PlanMade(result, resume)
    }

    /**
     * Readies the folder for the plan of [state] and a controller that captures it through [port]:
     * it resumes the earlier run when [UiState.Planned.canResume], unless [startOver].
     */
    fun startCapture(
        state: UiState.Planned,
        startOver: Boolean,
        port: CameraDevicePort,
        thermal: ThermalStatusSource = ThermalStatusSource.NONE,
        config: ControllerConfig = ControllerConfig(),
        clock: Clock = Clock.SYSTEM,
    ): CaptureStart {
        val plan = state.capturable ?: return CaptureStart.Refused(UiEvent.Problem("There is no plan to capture"))
        try {
            repository.begin(plan, resume = state.canResume && !startOver)
        } catch (e: IOException) {
            return CaptureStart.Refused(UiEvent.Problem("Cannot write the session folder: ${e.message}"))
        }
        return CaptureStart.Ready(CaptureRun(plan, repository.controller(plan, port, thermal, config, clock), repository))
    }

    /** Empties the session folder for a new calibration. */
    fun forget(): UiEvent = try {
        repository.forget()
        UiEvent.SessionForgotten
    } catch (e: IOException) {
        UiEvent.Problem("Cannot empty the session folder: ${e.message}")
    }

    /** Copies the pack into the stream [open] gives (a document the user picked; null if the provider gave none). */
    fun exportPack(open: () -> OutputStream?): UiEvent = try {
        val out = open() ?: throw IOException("the document provider returned no stream")
        out.use { repository.copyPack(it) }
        UiEvent.Info("Model pack saved")
    } catch (e: IOException) {
        UiEvent.Problem("Saving failed: ${e.message}")
    } catch (e: SecurityException) {
        UiEvent.Problem("Saving failed: ${e.message}")
    }
}

/** The answer of [CalibrationWorkflow.startCapture]. */
sealed interface CaptureStart {
    data class Ready(val run: CaptureRun) : CaptureStart
    data class Refused(val problem: UiEvent.Problem) : CaptureStart
}

/**
 * One capture, ready to go: reduce [started] first, then call [run] off the main thread. It
 * blocks until the plan is done, stopped ([requestStop], from any thread) or failed.
 */
class CaptureRun(val plan: CapturePlan, val controller: CaptureController, private val repository: SessionRepository) {
    val started: UiEvent get() = UiEvent.CaptureStarted(plan)

    /** Runs the controller, handing every [UiEvent.Progress] and finally the [UiEvent.CaptureEnded] to [dispatch]. */
    fun run(dispatch: (UiEvent) -> Unit): CaptureOutcome {
        val listener = ProgressListener { dispatch(UiEvent.Progress(it)) }
        controller.addListener(listener)
        val outcome = try {
            controller.run()
        } finally {
            controller.removeListener(listener)
        }
        dispatch(UiEvent.CaptureEnded(outcome, repository.resumeInfo(plan)))
        return outcome
    }

    fun requestStop() = controller.requestStop()

    /** The user covered the lens at the [UiState.CoverLens] prompt; reduce [UiEvent.LensCovered] too. */
    fun confirmLensCovered() = controller.confirmLensCovered()

    /** The user skipped the dark step at the prompt; reduce [UiEvent.DarkFramesSkipped] too. */
    fun skipDarkFrames() = controller.skipDarkFrames()
}
