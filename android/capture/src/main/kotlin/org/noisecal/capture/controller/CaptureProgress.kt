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
    /**
     * The motion verdict of every burst whose frames the core registered or refused for motion,
     * in capture order (the current burst's updated as its frames arrive): the result check.
     */
    val burstMotion: List<BurstMotion> = emptyList(),
) {
    /** The bursts the user should take again (a sturdier mount, OIS off, a remote trigger). */
    val retakeBursts: List<BurstMotion> get() = burstMotion.filter { it.retake }

    val overallFraction: Double get() = if (framesTotal == 0) 0.0 else framesDone.toDouble() / framesTotal
    val burstFraction: Double get() = if (burstFramesWanted == 0) 0.0 else burstFramesAccepted.toDouble() / burstFramesWanted

    companion object {
        /** Nothing captured yet of [plan]. */
        fun start(plan: CapturePlan) = CaptureProgress(burstCount = plan.bursts.size, framesTotal = plan.totalFrames)
    }
}

/**
 * One burst's motion verdict, from the core's measurement of each frame against its reference
 * burst: [framesRegistered] frames measured, [maxShiftPx] the largest displacement found
 * (pixels), [samples] flat samples kept and [leftOut] left out where the motion changed their
 * level, [framesRefused] frames refused for moving over 2 px (and taken again), [framesToRetake]
 * frames the core judged moved enough for the burst to be taken again. [verdict] is the line the
 * result check shows.
 */
data class BurstMotion(
    val burst: Burst,
    val framesRegistered: Int = 0,
    val maxShiftPx: Double = 0.0,
    val samples: Long = 0,
    val leftOut: Long = 0,
    val framesRefused: Int = 0,
    val framesToRetake: Int = 0,
) {
    /** Whether the user should take this burst again. */
    val retake: Boolean get() = framesToRetake > 0 || framesRefused > 0

    /** Share of the flat samples left out because the frames moved. */
    val leftOutFraction: Double get() = if (samples + leftOut == 0L) 0.0 else leftOut.toDouble() / (samples + leftOut)

    /** This tally with one more accepted frame. */
    fun with(m: FrameMotion): BurstMotion = copy(
        framesRegistered = framesRegistered + 1,
        maxShiftPx = maxOf(maxShiftPx, m.shiftPx),
        samples = samples + m.samples,
        leftOut = leftOut + m.leftOut,
        framesToRetake = framesToRetake + if (m.retake) 1 else 0,
    )

    /** One line for the result check. */
    val verdict: String get() {
        val shift = "moved up to ${"%.2f".format(maxShiftPx)} px over $framesRegistered frame(s)"
        val left = "${"%.1f".format(100 * leftOutFraction)} % of flat samples left out"
        val refused = if (framesRefused > 0) ", $framesRefused frame(s) refused for moving over 2 px" else ""
        return if (retake) {
            "$burst: $shift, $left$refused: re-take it with a sturdier mount, optical stabilisation off, a remote trigger"
        } else {
            "$burst: steady ($shift, $left)"
        }
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
    /** The pack is written; [motion] is the per-burst motion verdict ([CaptureProgress.burstMotion]). */
    data class Finished(val packPath: String, val summary: String, val motion: List<BurstMotion> = emptyList()) : CaptureOutcome()
    /** [CaptureController.requestStop] was called; the session resumes from [completedBursts] bursts. */
    data class Stopped(val completedBursts: Int) : CaptureOutcome()
    /** Something failed; [resumable] says whether a later run continues from the last checkpoint. */
    data class Failed(val reason: String, val resumable: Boolean) : CaptureOutcome()
}
