package org.noisecal.capture.sim

import java.io.File
import java.util.Random
import kotlin.math.roundToInt
import kotlin.math.sqrt
import org.noisecal.capture.controller.CaptureController
import org.noisecal.capture.controller.CaptureOutcome
import org.noisecal.capture.controller.Clock
import org.noisecal.capture.controller.ControllerConfig
import org.noisecal.capture.controller.FrameSinkFactory
import org.noisecal.capture.controller.SessionStore
import org.noisecal.capture.controller.ThermalStatusSource
import org.noisecal.capture.controller.ProgressListener
import org.noisecal.capture.plan.CapturePlan

/**
 * A chart of flat patches under a steady lamp, seen by a sensor with shot and read noise: enough
 * for the controller and the core to have something real-looking to chew on. Deterministic in
 * the frame's running number.
 *
 * The mean level of a patch is `black + reflectance · fullWell-fraction · (ISO·exposure / [ev0Brightness])`
 * where EV 0 puts a reflectance-1 patch at [ev0Fraction] of the range; noise is Poisson in
 * electrons (with [electronsPerDnAtRef] at [referenceIso]) plus Gaussian read noise ([readNoiseDn] at the
 * reference ISO, scaling with gain), clipped to [0, white].
 */
class SyntheticChart(
    private val width: Int,
    private val height: Int,
    private val black: Int,
    private val white: Int,
    private val referenceIso: Int,
    private val ev0Brightness: Double,
    private val ev0Fraction: Double = 0.25,
    private val electronsPerDnAtRef: Double = 4.0,
    private val readNoiseDn: Double = 1.5,
    private val patchesX: Int = 6,
    private val patchesY: Int = 4,
    private val seed: Long = 1L,
) : FrameSource {
    private val reflectance = DoubleArray(patchesX * patchesY) { 0.03 + 0.97 * it / (patchesX * patchesY - 1.0) }

    override fun render(exposure: SimExposure): ShortArray {
        val rng = Random(seed * 1_000_003L + exposure.sequence)
        val gain = exposure.iso.toDouble() / referenceIso
        val brightness = exposure.iso.toDouble() * exposure.exposureNs * 1e-9 / ev0Brightness
        val range = (white - black).toDouble()
        val out = ShortArray(width * height)
        for (y in 0 until height) {
            val py = (y * patchesY / height).coerceAtMost(patchesY - 1)
            for (x in 0 until width) {
                val px = (x * patchesX / width).coerceAtMost(patchesX - 1)
                val meanDn = reflectance[py * patchesX + px] * ev0Fraction * range * brightness
                // Electrons collected do not depend on ISO; gain scales them to DN.
                val meanE = meanDn / gain * electronsPerDnAtRef
                val e = poisson(rng, meanE)
                val dn = black + e / electronsPerDnAtRef * gain + rng.nextGaussian() * readNoiseDn * sqrt(gain)
                out[y * width + x] = dn.roundToInt().coerceIn(0, white).toShort()
            }
        }
        return out
    }

    private fun poisson(rng: Random, mean: Double): Double {
        if (mean <= 0) return 0.0
        if (mean > 50) return (mean + sqrt(mean) * rng.nextGaussian()).coerceAtLeast(0.0)
        val l = Math.exp(-mean)
        var k = 0
        var p = 1.0
        do { k++; p *= rng.nextDouble() } while (p > l)
        return (k - 1).toDouble()
    }
}

/**
 * Runs a whole plan through a [CaptureController] against a [SimulatedCameraPort] whose frames
 * come from [frames]: the host-side stand-in for a capture on a phone. A plan with the dark step
 * has its cover-the-lens prompt answered per [lens] (default: the lens is covered, and the frames
 * become black level plus noise). Use the same [storeDir]
 * again to resume after a [SimulatedProcessDeath]. Returns the outcome and the port (for its
 * counters).
 */
object SimulatedSweep {
    data class Run(val outcome: CaptureOutcome, val port: SimulatedCameraPort, val controller: CaptureController)

    fun run(
        plan: CapturePlan,
        sinkFactory: FrameSinkFactory,
        storeDir: File,
        frames: FrameSource,
        behaviour: SimBehaviour = SimBehaviour(),
        rowPaddingBytes: Int = 0,
        maxImages: Int = 8,
        config: ControllerConfig = ControllerConfig(frameTimeoutMs = 40L),
        thermal: ThermalStatusSource = ThermalStatusSource.NONE,
        clock: Clock = Clock.SYSTEM,
        listener: ProgressListener? = null,
        lens: (prompt: Int) -> LensAction = { LensAction.COVER },
    ): Run {
        val s = plan.sensor
        val port = SimulatedCameraPort(s.width, s.height, frames, maxImages, 2 * s.width + rowPaddingBytes, behaviour,
            LensCoveredScene(s.blackLevels.min().roundToInt(), s.whiteLevel, s.referenceIso))
        val controller = CaptureController(plan, port, sinkFactory, SessionStore(storeDir), thermal, config, clock)
        if (listener != null) controller.addListener(listener)
        // The person at the phone answers the dark step's prompt (a plan without one never asks).
        SimulatedUser(port, lens).attach(controller)
        return Run(controller.run(), port, controller)
    }

    /** Like [run] with a [SyntheticChart] matched to the plan's sensor and metering. */
    fun runWithChart(plan: CapturePlan, sinkFactory: FrameSinkFactory, storeDir: File, behaviour: SimBehaviour = SimBehaviour(),
                     rowPaddingBytes: Int = 0, config: ControllerConfig = ControllerConfig(frameTimeoutMs = 40L)): Run {
        val s = plan.sensor
        val chart = SyntheticChart(s.width, s.height, s.blackLevels.min().roundToInt(), s.whiteLevel, s.referenceIso,
            plan.options.metering.brightness)
        return run(plan, sinkFactory, storeDir, chart, behaviour, rowPaddingBytes, config = config)
    }
}
