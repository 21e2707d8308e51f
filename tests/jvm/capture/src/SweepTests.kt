package org.noisecal.capture.test

import kotlin.math.abs
import kotlin.math.sqrt
import org.noisecal.capture.controller.CaptureOutcome
import org.noisecal.capture.plan.BurstRole
import org.noisecal.capture.plan.CapturePlanner
import org.noisecal.capture.plan.Metering
import org.noisecal.capture.plan.PlanOptions
import org.noisecal.capture.sim.SimBehaviour
import org.noisecal.capture.sim.SimulatedSweep

/** The helper the end-to-end test uses: a whole plan through the controller against a simulated chart. */
class SweepTests : Suite("sweep") {
    init {
        test("simulated sweep with a chart: every target burst as bright as its reference (statistically)") {
            val plan = planOk(CapturePlanner.plan(
                caps(range = 50..800, maxAnalog = 400, exposure = 10_000L..1_000_000_000L, minFrame = 1_000_000L, w = 48, h = 32),
                PlanOptions(Metering(100, 4_000_000L), evMin = -2.0, evMax = 1.0, framesPerBurst = 12, settleOverheadNs = 0)))
            val factory = RecordingSinkFactory(tagged = null).withSensor(plan.sensor)
            val run = SimulatedSweep.runWithChart(plan, factory, tempDir("sweep"), SimBehaviour(settingsLagFrames = 1), rowPaddingBytes = 32)
            check(run.outcome is CaptureOutcome.Finished) { "${run.outcome}" }
            checkAllClosed(run.port)
            val sink = factory.last
            val means = sink.means
            eq(plan.totalFrames, means.size, "frames")
            var i = 0
            var worst = 0.0
            for (step in plan.steps) {
                val ref = step.bursts.first()
                val refMeans = means.subList(i, i + ref.frames)
                i += ref.frames
                val refMean = refMeans.average()
                check(ref.role == BurstRole.REFERENCE) { "reference first" }
                for (b in step.bursts.drop(1)) {
                    val m = means.subList(i, i + b.frames)
                    i += b.frames
                    // Standard error of a burst mean from its own spread; a wrong exposure scaling (×2) is far outside.
                    val sd = sqrt(m.map { (it - m.average()) * (it - m.average()) }.sum() / (m.size - 1))
                    val se = sd / sqrt(m.size.toDouble()) + 0.002 * refMean
                    val z = abs(m.average() - refMean) / se
                    worst = maxOf(worst, abs(m.average() / refMean - 1))
                    check(z < 6) { "EV ${step.ev} ISO ${b.iso}: mean ${m.average()} vs reference $refMean (z=$z)" }
                }
            }
            check(worst < 0.05) { "brightness off by ${worst * 100} %" }
        }
    }
}
