package org.noisecal.capture.controller

import org.noisecal.capture.plan.Burst

/** Where a capture stands. */
enum class CapturePhase { IDLE, RUNNING, PAUSED_THERMAL, FINISHING, DONE, STOPPED, FAILED }

/**
 * Everything the progress screen shows, as one immutable value (camera-samples style UiState).
 * Times are in ms; [remainingMs] is the plan's estimate for what is left, corrected by how fast the
 * finished bursts actually went.
 */
data class CaptureUiState(
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
) {
    val overallFraction: Double get() = if (framesTotal == 0) 0.0 else framesDone.toDouble() / framesTotal
    val burstFraction: Double get() = if (burstFramesWanted == 0) 0.0 else burstFramesAccepted.toDouble() / burstFramesWanted
}

/** Receives every new [CaptureUiState] (on the controller's thread). */
fun interface UiStateListener {
    fun onState(state: CaptureUiState)
}

/** How a run ended. */
sealed class CaptureOutcome {
    data class Finished(val packPath: String, val summary: String) : CaptureOutcome()
    /** [requestStop] was called; the session resumes from [completedBursts] bursts. */
    data class Stopped(val completedBursts: Int) : CaptureOutcome()
    /** Something failed; [resumable] says whether a later run continues from the last checkpoint. */
    data class Failed(val reason: String, val resumable: Boolean) : CaptureOutcome()
}
