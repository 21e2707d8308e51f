package org.noisecal.capture.sweeptest

import org.noisecal.capture.plan.CapturePlan
import org.noisecal.capture.sim.FrameSource
import org.noisecal.capture.sim.SimExposure

/**
 * A [FrameSource] whose samples depend only on *which planned frame* a frame will become, not on
 * the simulated camera's running number: the k-th frame of burst b that the controller will accept
 * always gets the same samples, however many frames were dropped, lagged, rejected or killed before
 * it. So a run with faults pushes exactly the frames a fault-free run pushes, and the two packs can
 * be compared byte for byte.
 *
 * The burst is identified by the settings the sensor actually applied (ISO, exposure); a frame
 * still running the previous burst's settings (settings lag) is counted against that earlier,
 * finished burst. [accepted] says, from the camera's running number, whether a frame rendered with
 * the right settings reaches the sink (its result is delivered and it passes the controller's
 * checks); only those advance the burst's frame counter. Make a new instance for every controller
 * run: a resumed run takes the interrupted burst again from its first frame.
 *
 * Samples come from [chart], asked for "frame" `burstIndex · 1 000 000 + k`.
 */
class PlannedFrames(
    plan: CapturePlan,
    private val chart: FrameSource,
    private val accepted: (Long) -> Boolean,
) : FrameSource {
    private val burstOf: Map<Pair<Int, Long>, Int>
    private val taken = IntArray(plan.bursts.size)

    init {
        val keys = plan.bursts.groupBy { it.iso to it.exposureNs }
        val dup = keys.filterValues { it.size > 1 }
        require(dup.isEmpty()) { "bursts share ISO and exposure, so frames cannot be told apart: ${dup.values}" }
        burstOf = keys.mapValues { it.value.single().index }
    }

    /** Frames handed out per burst that will be accepted (a copy). */
    val takenPerBurst: List<Int> get() = taken.toList()

    override fun render(exposure: SimExposure): ShortArray {
        val b = burstOf[exposure.iso to exposure.exposureNs]
            ?: throw IllegalStateException("no planned burst at ISO ${exposure.iso}, ${exposure.exposureNs} ns")
        val k = taken[b]
        if (accepted(exposure.sequence)) taken[b]++
        return chart.render(exposure.copy(sequence = b * 1_000_000L + k))
    }
}
