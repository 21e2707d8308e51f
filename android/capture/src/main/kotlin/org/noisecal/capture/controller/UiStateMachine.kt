package org.noisecal.capture.controller

import org.noisecal.capture.plan.CapturePlan
import org.noisecal.capture.plan.Metering
import org.noisecal.capture.plan.PlanResult

/**
 * What can happen to the screen: the user's answers, what the cameras and the repository report
 * ([CalibrationWorkflow] makes most of these), and what the [CaptureController] publishes.
 */
sealed interface UiEvent {
    data class PermissionAnswered(val granted: Boolean) : UiEvent

    /** The cameras were read; [chosen] is null when none qualifies; [earlier] is what the session folder holds for [chosen]. */
    data class CamerasFound(val cameras: List<CameraChoice>, val chosen: CameraChoice?, val earlier: EarlierSession? = null) : UiEvent

    /** The preview's auto-exposure settled on [metering]. */
    data class Metered(val metering: Metering) : UiEvent

    data class FormEdited(val form: PlanForm) : UiEvent

    /** "Change the settings": from the plan back to the preview. */
    data object BackToPreview : UiEvent

    /** The planner answered; [resume] is what an earlier run of the same plan left. */
    data class PlanMade(val result: PlanResult, val resume: ResumeInfo?) : UiEvent

    /** The session folder is ready and the controller about to run [plan]. */
    data class CaptureStarted(val plan: CapturePlan) : UiEvent

    /** The controller published [progress]. */
    data class Progress(val progress: CaptureProgress) : UiEvent

    /** The user asked the running capture to stop. */
    data object StopRequested : UiEvent

    /** At the [UiState.CoverLens] prompt: the lens is covered, take the dark frames. */
    data object LensCovered : UiEvent

    /** At the [UiState.CoverLens] prompt: skip the dark step, finish without it. */
    data object DarkFramesSkipped : UiEvent

    /** The controller's run returned [outcome]; [resume] is what the session folder now offers. */
    data class CaptureEnded(val outcome: CaptureOutcome, val resume: ResumeInfo?) : UiEvent

    /** The session folder was emptied for a new calibration. */
    data object SessionForgotten : UiEvent

    /** Something the user should read ([Banner.Error]). */
    data class Problem(val message: String) : UiEvent

    /** Something that went well ([Banner.Info]). */
    data class Info(val message: String) : UiEvent
}

/**
 * The screen's state machine: a pure function from a state and an event to the next state. An
 * event that does not fit the state (a late progress after the run ended, metering after the
 * plan was made) leaves the state as it is, so events from other threads can arrive in any order.
 * Being pure, it is safe inside `MutableStateFlow.update`, which may call it more than once.
 */
object UiStateMachine {
    fun reduce(state: UiState, event: UiEvent): UiState = when (event) {
        is UiEvent.PermissionAnswered -> when {
            // A running capture is never abandoned; the system kills the process if it revokes the permission.
            state is UiState.Capturing || state is UiState.CoverLens -> state
            !event.granted -> UiState.NeedsPermission(denied = true)
            state is UiState.NeedsPermission -> UiState.LoadingCameras
            else -> state
        }

        is UiEvent.CamerasFound -> if (state !is UiState.LoadingCameras) state else camerasFound(event)

        is UiEvent.Metered -> if (state is UiState.Preview) state.copy(setup = state.setup.copy(metering = event.metering)) else state

        is UiEvent.FormEdited -> if (state is UiState.Preview) state.copy(setup = state.setup.copy(form = event.form)) else state

        UiEvent.BackToPreview -> if (state is UiState.Planned) UiState.Preview(state.setup) else state

        is UiEvent.PlanMade -> if (state is UiState.Preview) UiState.Planned(state.setup, event.result, event.resume) else state

        is UiEvent.CaptureStarted ->
            if (state is UiState.Planned && state.capturable == event.plan) {
                UiState.Capturing(state.setup, event.plan, CaptureProgress.start(event.plan))
            } else {
                state
            }

        is UiEvent.Progress -> progress(state, event.progress)

        UiEvent.StopRequested -> when (state) {
            is UiState.Capturing -> state.copy(stopping = true)
            is UiState.CoverLens -> state.copy(stopping = true)
            else -> state
        }

        // The answer goes to the controller (CaptureRun); the screen shows the capture again at once.
        UiEvent.LensCovered, UiEvent.DarkFramesSkipped ->
            if (state is UiState.CoverLens) UiState.Capturing(state.setup, state.plan, state.progress, state.stopping, state.banner) else state

        is UiEvent.CaptureEnded -> when (state) {
            is UiState.Capturing -> captureEnded(state.setup, state.plan, event)
            is UiState.CoverLens -> captureEnded(state.setup, state.plan, event)
            else -> state
        }

        UiEvent.SessionForgotten -> when (state) {
            is UiState.Planned -> UiState.Preview(state.setup)
            is UiState.Done -> UiState.Preview(state.setup)
            else -> state
        }

        is UiEvent.Problem -> withBanner(state, Banner.Error(event.message))

        is UiEvent.Info -> withBanner(state, Banner.Info(event.message))
    }

    private fun camerasFound(e: UiEvent.CamerasFound): UiState {
        val camera = e.chosen ?: return UiState.Unsupported(e.cameras)
        val earlier = e.earlier?.takeIf { it.cameraId == camera.id }
            ?: return UiState.Preview(Setup(camera))
        val setup = Setup(camera, earlier.options.metering, PlanForm.from(earlier.options))
        val pack = earlier.packPath
        return if (earlier.resume.finished && pack != null) {
            UiState.Done(setup, pack, earlier.summary ?: "The model pack is ready.", Banner.Info("The last calibration is finished"))
        } else {
            UiState.Planned(setup, PlanResult.Ok(earlier.plan), earlier.resume,
                Banner.Info("An unfinished calibration was found: ${earlier.resume.completedBursts} of ${earlier.resume.totalBursts} bursts done"))
        }
    }

    /**
     * A progress while capturing: the controller asking for the lens to be covered turns the
     * screen into the [UiState.CoverLens] prompt; any other progress while prompting (the answer
     * arrived, the dark frames run) turns it back.
     */
    private fun progress(state: UiState, p: CaptureProgress): UiState {
        val ask = p.coverLens?.takeIf { p.phase == CapturePhase.AWAITING_LENS_COVER }
        return when (state) {
            is UiState.Capturing ->
                if (ask != null) UiState.CoverLens(state.setup, state.plan, p, ask, state.stopping, state.banner) else state.copy(progress = p)
            is UiState.CoverLens ->
                if (ask != null) state.copy(progress = p, request = ask) else UiState.Capturing(state.setup, state.plan, p, state.stopping, state.banner)
            else -> state
        }
    }

    private fun captureEnded(setup: Setup, plan: CapturePlan, e: UiEvent.CaptureEnded): UiState = when (val o = e.outcome) {
        is CaptureOutcome.Finished -> UiState.Done(setup, o.packPath, o.summary, motion = o.motion,
            banner = o.motion.filter { it.retake }.takeIf { it.isNotEmpty() }
                ?.let { Banner.Error("${it.size} burst(s) moved: ${it.first().verdict}") })
        is CaptureOutcome.Stopped -> UiState.Planned(setup, PlanResult.Ok(plan), e.resume,
            Banner.Info("Stopped after ${o.completedBursts} of ${plan.bursts.size} bursts; resume whenever you are ready"))
        is CaptureOutcome.Failed -> UiState.Planned(setup, PlanResult.Ok(plan), if (o.resumable) e.resume else null, Banner.Error(o.reason))
    }

    private fun withBanner(state: UiState, banner: Banner): UiState = when (state) {
        is UiState.Preview -> state.copy(banner = banner)
        is UiState.Planned -> state.copy(banner = banner)
        is UiState.Capturing -> state.copy(banner = banner)
        is UiState.CoverLens -> state.copy(banner = banner)
        is UiState.Done -> state.copy(banner = banner)
        // Before a camera is open there is nowhere to show a banner, and nothing that reports one.
        is UiState.NeedsPermission, UiState.LoadingCameras, is UiState.Unsupported -> state
    }
}
