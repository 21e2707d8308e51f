package org.noisecal.capture.controller

import kotlin.math.abs
import org.noisecal.capture.plan.CameraCapabilities
import org.noisecal.capture.plan.CapturePlan
import org.noisecal.capture.plan.Metering
import org.noisecal.capture.plan.PlanOptions
import org.noisecal.capture.plan.PlanResult

/**
 * The one state the app's screen shows (camera-samples style: a sealed UiState that the screen
 * consumes with an exhaustive `when`). Plain data without Android types, so the state machine
 * that makes it ([UiStateMachine]) is tested on the host.
 *
 * A calibration walks NeedsPermission → LoadingCameras → Preview ⇄ Planned → Capturing → Done;
 * a plan with the dark step passes Capturing → [CoverLens] → Capturing before it is done.
 * [Unsupported] ends it when no camera qualifies. The states with a live camera share
 * [AtCamera]: the screen keeps one preview for all of them.
 */
sealed interface UiState {
    /** Waiting for the camera permission; [denied] once the user refused it. */
    data class NeedsPermission(val denied: Boolean = false) : UiState

    /** Reading what the cameras report. */
    data object LoadingCameras : UiState

    /** No camera can be calibrated; each lists what it lacks. */
    data class Unsupported(val cameras: List<CameraChoice>) : UiState

    /** A camera is open with its preview; [setup] is what a plan is made from. */
    sealed interface AtCamera : UiState {
        val setup: Setup
        /** A line above the panel: what just happened or went wrong. */
        val banner: Banner?
    }

    /** Framing the chart, metering and filling in the plan form. */
    data class Preview(override val setup: Setup, override val banner: Banner? = null) : AtCamera

    /**
     * A plan (or the planner's refusal) waiting for "Start". [resume] is what an earlier run of
     * the same plan left in the session folder.
     */
    data class Planned(
        override val setup: Setup,
        val plan: PlanResult,
        val resume: ResumeInfo? = null,
        override val banner: Banner? = null,
    ) : AtCamera {
        /** The plan, when the planner accepted it. */
        val capturable: CapturePlan? get() = (plan as? PlanResult.Ok)?.plan

        /** Whether "Start" continues an earlier run instead of starting over. */
        val canResume: Boolean get() = capturable != null && resume != null && resume.samePlan && !resume.finished && resume.completedBursts > 0
    }

    /** The controller runs [plan]; [stopping] once the user asked it to stop. */
    data class Capturing(
        override val setup: Setup,
        val plan: CapturePlan,
        val progress: CaptureProgress,
        val stopping: Boolean = false,
        override val banner: Banner? = null,
    ) : AtCamera

    /**
     * A prompt, like [NeedsPermission] and the resume offer of [Planned]: the lit sweep is done and
     * the controller waits for the user to cover the lens for the dark step ("Lens covered", event
     * [UiEvent.LensCovered]) or to skip it ([UiEvent.DarkFramesSkipped]). [request] says which ISOs
     * and how many frames; its [CoverLensRequest.notCovered] is set when the last try had light in
     * it. The capture goes on behind it: [progress] keeps arriving, stop still works.
     */
    data class CoverLens(
        override val setup: Setup,
        val plan: CapturePlan,
        val progress: CaptureProgress,
        val request: CoverLensRequest,
        val stopping: Boolean = false,
        override val banner: Banner? = null,
    ) : AtCamera

    /**
     * The pack at [packPath] is written; [summary] is the core's one-line verdict; [motion] the
     * per-burst motion verdicts of the run ([BurstMotion.verdict]), with [retakeBursts] the bursts
     * to take again.
     */
    data class Done(
        override val setup: Setup,
        val packPath: String,
        val summary: String,
        override val banner: Banner? = null,
        val motion: List<BurstMotion> = emptyList(),
    ) : AtCamera {
        /** The bursts that moved enough to be worth taking again. */
        val retakeBursts: List<BurstMotion> get() = motion.filter { it.retake }

        /** The file name offered when the pack is saved elsewhere. */
        val exportName: String get() = packExportName(setup.camera.capabilities)
    }
}

/** A line above the panel. */
sealed interface Banner {
    val text: String

    data class Info(override val text: String) : Banner
    data class Error(override val text: String) : Banner
}

/** What a plan is made from: the camera, what its preview metered (EV 0), and the form as typed. */
data class Setup(val camera: CameraChoice, val metering: Metering? = null, val form: PlanForm = PlanForm())

/** Which way a camera faces (`CameraCharacteristics.LENS_FACING`). */
enum class CameraFacing { BACK, FRONT, EXTERNAL, UNKNOWN }

/** A width × height in pixels. */
data class FrameSize(val width: Int, val height: Int)

/**
 * One camera of the phone as the screens need it: what it reports ([capabilities], null when it
 * could not be read), the preview size that matches its RAW aspect, and why it cannot be
 * calibrated ([problems], empty when it can). The Camera2 adapter in `:app` fills it.
 */
data class CameraChoice(
    val id: String,
    val facing: CameraFacing,
    val capabilities: CameraCapabilities?,
    val previewSize: FrameSize?,
    val problems: List<String>,
) {
    val supported: Boolean get() = capabilities != null && problems.isEmpty()
    val facingName: String get() = facing.name.lowercase()

    companion object {
        /** The camera to use: [preferredId] (the saved session's) if it is supported, else the first supported back camera, else any supported one. */
        fun choose(cameras: List<CameraChoice>, preferredId: String? = null): CameraChoice? =
            cameras.firstOrNull { it.supported && it.id == preferredId }
                ?: cameras.firstOrNull { it.supported && it.facing == CameraFacing.BACK }
                ?: cameras.firstOrNull { it.supported }
    }
}

/** The plan form as typed (strings, so half-typed numbers survive recomposition). */
data class PlanForm(
    val isos: String = "",
    val evMin: String = "-4",
    val evMax: String = "4",
    val frames: String = "100",
    val recording: Boolean = false,
    /** The optional dark step (lens covered), off by default. */
    val darkFrames: Boolean = false,
    val darkFramesPerIso: String = PlanOptions.DEFAULT_DARK_FRAMES_PER_ISO.toString(),
) {
    /** The planner's options for [metering]; throws [IllegalArgumentException] naming the field that is wrong. */
    fun toOptions(metering: Metering): PlanOptions {
        val isoList = isos.split(',', ' ', ';').filter { it.isNotBlank() }.map {
            it.trim().toIntOrNull() ?: throw IllegalArgumentException("ISO list: \"$it\" is not a number (e.g. 200, 400, 800)")
        }
        val from = evMin.trim().toDoubleOrNull() ?: throw IllegalArgumentException("EV from: \"$evMin\" is not a number (e.g. -4)")
        val to = evMax.trim().toDoubleOrNull() ?: throw IllegalArgumentException("EV to: \"$evMax\" is not a number (e.g. 4)")
        val n = frames.trim().toIntOrNull() ?: throw IllegalArgumentException("Frames per burst: \"$frames\" is not a whole number (e.g. 100)")
        val dark = if (!darkFrames) PlanOptions.DEFAULT_DARK_FRAMES_PER_ISO else darkFramesPerIso.trim().toIntOrNull()
            ?: throw IllegalArgumentException("Dark frames per ISO: \"$darkFramesPerIso\" is not a whole number (e.g. 8)")
        return PlanOptions(metering = metering, targetIsos = isoList.ifEmpty { null }, evMin = from, evMax = to, framesPerBurst = n,
            recording = recording, darkFrames = darkFrames, darkFramesPerIso = dark)
    }

    companion object {
        /** The form that gives [options] back (for a plan restored from the session folder). */
        fun from(options: PlanOptions) = PlanForm(
            isos = options.targetIsos?.joinToString(", ") ?: "",
            evMin = plain(options.evMin),
            evMax = plain(options.evMax),
            frames = options.framesPerBurst.toString(),
            recording = options.recording,
            darkFrames = options.darkFrames,
            darkFramesPerIso = options.darkFramesPerIso.toString(),
        )

        private fun plain(x: Double): String = if (x % 1.0 == 0.0 && abs(x) < 1e15) x.toLong().toString() else x.toString()
    }
}

/** "noisecal-MODEL-camID.pack", with anything but letters, digits, '.', '_' and '-' in the model replaced. */
fun packExportName(c: CameraCapabilities?): String {
    val model = (c?.model ?: "camera").replace(Regex("[^A-Za-z0-9._-]+"), "_")
    return "noisecal-$model-cam${c?.cameraId ?: "0"}.pack"
}
