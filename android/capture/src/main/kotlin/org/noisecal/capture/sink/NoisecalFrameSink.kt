package org.noisecal.capture.sink

import org.noisecal.capture.controller.FrameMotion
import org.noisecal.capture.controller.FrameMovedException
import org.noisecal.capture.controller.FrameSink
import org.noisecal.capture.controller.FrameSinkFactory
import org.noisecal.capture.controller.IsoCoverage
import org.noisecal.capture.controller.LensNotCoveredException
import org.noisecal.capture.controller.PushedFrame
import org.noisecal.capture.controller.RawFrame
import org.noisecal.capture.controller.SinkProgress
import org.noisecal.capture.plan.GainGap
import org.noisecal.capture.plan.SensorSpec
import org.noisecal.jni.NoisecalMovedException
import org.noisecal.jni.NoisecalNotDarkException
import org.noisecal.jni.NoisecalSession

/**
 * The real sink: a [FrameSink] over the JNI [NoisecalSession]. Frames go straight from the
 * image's direct ByteBuffer into the Rust core. Closing the sink closes the session.
 */
class NoisecalFrameSink(val session: NoisecalSession) : FrameSink {
    /** Levels per histogram bin of the session: the pack's bin width (the core's default unless the sensor spec set one). */
    val binWidth: Int get() = session.binWidth

    override fun beginStep(referenceExposureNs: Long) = session.beginStep(referenceExposureNs)

    override fun beginDark() = session.beginDark()

    override fun pushFrame(frame: RawFrame): PushedFrame = try {
        pushed(session.pushFrame(frame.buffer, frame.width, frame.height, frame.rowStride, frame.pixelStride,
            frame.iso, frame.exposureNs, frame.blackLevels))
    } catch (e: NoisecalNotDarkException) {
        throw LensNotCoveredException(e.message ?: "the dark frame is not dark: cover the lens", e)
    } catch (e: NoisecalMovedException) {
        throw FrameMovedException(e.message ?: "the frame moved too far: use a sturdier mount", e)
    }

    override fun progress(): SinkProgress {
        val p = session.progress()
        return SinkProgress(p.framesAccepted, p.framesRejected, p.steps,
            p.isos.map { IsoCoverage(it.iso, it.frames, it.underSampledBins, it.totalBins) })
    }

    override fun checkpoint(path: String) = session.checkpoint(path)

    /**
     * The gaps the last [finish] left open (switches and undetermined gaps, parsed by
     * [GainGap.parseCalls] from the session's gap calls): what `GainGapFollowUp.propose` turns
     * into the next capture. Empty before [finish].
     */
    var gainGaps: List<GainGap> = emptyList()
        private set

    override fun finish(packPath: String): String {
        val done = session.finish(packPath)
        gainGaps = GainGap.parseCalls(done.gapCalls)
        return done.summary
    }

    override fun close() = session.close()
}

/**
 * Makes [NoisecalFrameSink]s for a [SensorSpec], its bin width included (0, the planner's choice,
 * lets the core pick its default, so the pack's bin width is always the spec's or the core's);
 * [recordingPath], when set, tees every accepted frame into a recording for desktop replay. A
 * session restored from a checkpoint reopens that recording and cuts it back to the length it had at
 * the checkpoint, so the frames of the burst a kill interrupted are dropped and the whole recording
 * still replays to the resumed session's pack (tests/jvm/sweep shows it).
 */
class NoisecalSinkFactory(
    private val recordingPath: String? = null,
) : FrameSinkFactory {
    override fun create(sensor: SensorSpec): FrameSink {
        val s = NoisecalSession.create(
            sensor.width, sensor.height, sensor.cfa, sensor.blackLevels.toFloatArray(), sensor.whiteLevel,
            sensor.referenceIso, sensor.make, sensor.model, sensor.binWidth,
        )
        try {
            if (recordingPath != null) s.startRecording(recordingPath)
        } catch (e: RuntimeException) {
            s.close()
            throw e
        }
        return NoisecalFrameSink(s)
    }

    override fun restore(checkpointPath: String): FrameSink = NoisecalFrameSink(NoisecalSession.restore(checkpointPath))
}

/** The controller's view of the core's verdict on a frame. */
internal fun pushed(v: NoisecalSession.FrameVerdict): PushedFrame = PushedFrame(
    driftNormalised = v.driftNormalised,
    motion = if (v.registered) FrameMotion(v.shiftPx, v.samples, v.leftOut, v.retake) else null,
)
