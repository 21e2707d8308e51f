package org.noisecal.capture.controller

import org.noisecal.capture.plan.Burst
import org.noisecal.capture.plan.CapturePlan

/**
 * Where a capture stands. [AWAITING_LENS_COVER]: the lit sweep is done and the controller waits
 * for the user to cover the lens for the dark step (or to skip it); [CaptureProgress.coverLens]
 * says what for.
 */
enum class CapturePhase { IDLE, RUNNING, AWAITING_LENS_COVER, PAUSED_THERMAL, FINISHING, DONE, STOPPED, FAILED }

/**
 * The prompt before the dark step: cover the lens for [frames] frames at [isos] (about
 * [estimatedMs]). [notCovered] is set when this is a retry: the core found light in a dark frame
 * (its message), so the step is taken again from its start.
 */
data class CoverLensRequest(val isos: List<Int>, val frames: Int, val estimatedMs: Long, val notCovered: String? = null)

/**
 * How far a [CaptureController] run has got, as one immutable value: what the capture screen
 * shows inside [UiState.Capturing]. Times are in ms; [remainingMs] is the plan's estimate for what
 * is left, corrected by how fast the finished bursts actually went.
 */
data class CaptureProgress(
    val phase: CapturePhase = CapturePhase.IDLE,
    val burstCount: Int = 0,
    val burstsDone: Int = 0,
    val currentBurst: Burst? = null,
    val burstFramesAccepted: Int = 0,
    val burstFramesWanted: Int = 0,
    val framesDone: Int = 0,
    val framesTotal: Int = 0,
    val framesRejected: Int = 0,
    val framesLost: Int = 0,
    val framesDriftNormalised: Int = 0,
    val elapsedMs: Long = 0,
    val remainingMs: Long = 0,
    val thermal: ThermalLevel = ThermalLevel.NONE,
    val coverage: List<IsoCoverage> = emptyList(),
    val resumedFromBurst: Int? = null,
    val lastRejection: String? = null,
    val message: String? = null,
    val packPath: String? = null,
    val summary: String? = null,
    /** Set while [phase] is [CapturePhase.AWAITING_LENS_COVER]. */
    val coverLens: CoverLensRequest? = null,
    /** The dark step was skipped at the prompt; the session finishes without it. */
    val darkSkipped: Boolean = false,
) {
    val overallFraction: Double get() = if (framesTotal == 0) 0.0 else framesDone.toDouble() / framesTotal
    val burstFraction: Double get() = if (burstFramesWanted == 0) 0.0 else burstFramesAccepted.toDouble() / burstFramesWanted

    companion object {
        /** Nothing captured yet of [plan]. */
        fun start(plan: CapturePlan) = CaptureProgress(burstCount = plan.bursts.size, framesTotal = plan.totalFrames)
    }
}

/** Receives every new [CaptureProgress], on the controller's thread. */
fun interface ProgressListener {
    fun onProgress(progress: CaptureProgress)
}

/**
 * The names of [CaptureProgress] and [ProgressListener] before the screen got its sealed
 * [UiState]; tests/jvm/sweep still uses them. Remove both once nothing does.
 */
typealias CaptureUiState = CaptureProgress

/** See [CaptureUiState]: the old listener, with its old method name. */
fun interface UiStateListener : ProgressListener {
    fun onState(state: CaptureProgress)
    override fun onProgress(progress: CaptureProgress) = onState(progress)
}

/** How a run ended. */
sealed class CaptureOutcome {
    data class Finished(val packPath: String, val summary: String) : CaptureOutcome()
    /** [CaptureController.requestStop] was called; the session resumes from [completedBursts] bursts. */
    data class Stopped(val completedBursts: Int) : CaptureOutcome()
    /** Something failed; [resumable] says whether a later run continues from the last checkpoint. */
    data class Failed(val reason: String, val resumable: Boolean) : CaptureOutcome()
}
