package org.noisecal.capture.plan

import java.security.MessageDigest
import org.noisecal.jni.NoisecalSession
import kotlin.math.abs
import kotlin.math.ceil
import kotlin.math.ln
import kotlin.math.pow
import kotlin.math.roundToLong
import kotlin.math.sqrt

/** What the auto-exposure settled on for the scene (EV 0): ISO and exposure as a capture result reported them. */
data class Metering(val iso: Int, val exposureNs: Long) {
    /** ISO·s: the brightness product that every burst of one EV step shares. */
    val brightness: Double get() = iso.toDouble() * exposureNs * 1e-9
}

/**
 * The user's choices.
 *
 * @property metering the metered EV 0 exposure (any ISO; it is converted to the reference ISO).
 * @property targetIsos ISOs to calibrate; null picks [CapturePlanner.defaultTargetIsos].
 * @property evMin first EV step, relative to the metered exposure.
 * @property evMax last EV step.
 * @property evIncrement distance between EV steps.
 * @property framesPerBurst frames of each target burst (default 100).
 * @property referenceFramesPerBurst frames of each reference burst (default: [framesPerBurst]).
 * @property maxExposureNs optional cap on any exposure (keeps the session short), on top of the camera's own.
 * @property settleOverheadNs time counted per burst for settings to settle and frames to be re-taken.
 * @property recording whether a recording for desktop replay is written (counts in the storage estimate).
 * @property rowStrideBytes RAW row stride if known (for the recording size); 2·width otherwise.
 * @property darkFrames whether the plan ends with the optional dark step: the lens covered, a short
 *   burst per ISO (the reference ISO and every target), for the core's fixed-pattern ("fpn") component.
 * @property darkFramesPerIso frames of each dark burst (default 8).
 */
data class PlanOptions(
    val metering: Metering,
    val targetIsos: List<Int>? = null,
    val evMin: Double = -4.0,
    val evMax: Double = 4.0,
    val evIncrement: Double = 1.0,
    val framesPerBurst: Int = 100,
    val referenceFramesPerBurst: Int = framesPerBurst,
    val maxExposureNs: Long? = null,
    val settleOverheadNs: Long = 300_000_000L,
    val recording: Boolean = false,
    val rowStrideBytes: Int? = null,
    val darkFrames: Boolean = false,
    val darkFramesPerIso: Int = DEFAULT_DARK_FRAMES_PER_ISO,
) {
    companion object {
        /** Frames per ISO of the dark step unless the user chose otherwise. */
        const val DEFAULT_DARK_FRAMES_PER_ISO = 8
    }
}

/**
 * Whether a burst is the reference burst of its EV step, a target burst, or a burst of the dark
 * step (lens covered; see [CapturePlan.darkBursts]).
 */
enum class BurstRole { REFERENCE, TARGET, DARK }

/**
 * One burst: [frames] frames at [iso] and [exposureNs], each taking [frameDurationNs].
 * [index] is the position in [CapturePlan.bursts]; [stepIndex] the EV step it belongs to.
 */
data class Burst(
    val index: Int,
    val stepIndex: Int,
    val ev: Double,
    val role: BurstRole,
    val iso: Int,
    val exposureNs: Long,
    val frameDurationNs: Long,
    val frames: Int,
    val digitalGain: Boolean,
) {
    val brightness: Double get() = iso.toDouble() * exposureNs * 1e-9
    override fun toString(): String = if (role == BurstRole.DARK) {
        "burst $index (dark ISO $iso, ${fmtNs(exposureNs)} × $frames, lens covered)"
    } else {
        "burst $index (EV ${fmtEv(ev)} ${role.name.lowercase()} ISO $iso, ${fmtNs(exposureNs)} × $frames)"
    }
}

/** One EV step: its reference exposure and the bursts (reference first). */
data class EvStep(val index: Int, val ev: Double, val referenceExposureNs: Long, val bursts: List<Burst>)

/** Something the planner changed or left out, and why. */
data class PlanAdjustment(val kind: Kind, val ev: Double?, val iso: Int?, val message: String) {
    enum class Kind { CLAMPED, DROPPED, DIGITAL_GAIN }
    override fun toString(): String = "${kind.name.lowercase()}: $message"
}

/**
 * The sensor as the calibration session needs it (what `NoisecalSession.create` takes, [binWidth]
 * included: the sink passes it on, so the pack's bin width is this one).
 *
 * @property binWidth levels per histogram bin; 0 (the planner's choice) leaves it to the Rust core's
 *   default for the sensor, the one rule for it: an open session reports the value it uses
 *   (`NoisecalSession.binWidth`, `NoisecalFrameSink.binWidth`).
 */
data class SensorSpec(
    val width: Int,
    val height: Int,
    val cfa: String,
    val blackLevels: List<Float>,
    val whiteLevel: Int,
    val referenceIso: Int,
    val make: String,
    val model: String,
    val binWidth: Int = 0,
)

/**
 * The core's default bin width for a camera's levels (levels per histogram bin), for the plan's pack
 * estimate. The sessions themselves never need it: they are created with [SensorSpec.binWidth] 0.
 */
fun interface BinWidthSource {
    /** The default bin width for [whiteLevel] and [blackLevels] (4 values), or null if unknown. */
    fun defaultBinWidth(whiteLevel: Int, blackLevels: List<Int>): Int?

    companion object {
        /**
         * Asks the Rust core (`NoisecalSession.defaultBinWidth`), loading the native library; null
         * when there is none to load (host JVM tests of the plan and the controller run without it).
         */
        val CORE = BinWidthSource { white, black ->
            try {
                NoisecalSession.defaultBinWidth(white, FloatArray(black.size) { black[it].toFloat() })
            } catch (e: LinkageError) {
                null
            }
        }
    }
}

/** A plan the camera can carry out. */
data class CapturePlan(
    val capabilities: CameraCapabilities,
    val options: PlanOptions,
    val sensor: SensorSpec,
    val referenceIso: Int,
    val targetIsos: List<Int>,
    val steps: List<EvStep>,
    val adjustments: List<PlanAdjustment>,
    val estimatedDurationNs: Long,
    /** Null when the core's bin width was unknown at planning (no native library). */
    val estimatedPackBytes: Long?,
    val estimatedRecordingBytes: Long,
    /**
     * The optional dark step, after the lit sweep (empty unless [PlanOptions.darkFrames]): one burst
     * per ISO, reference ISO first, captured with the lens covered. Its bursts have role
     * [BurstRole.DARK], [Burst.stepIndex] `steps.size` and [Burst.ev] 0.
     */
    val darkBursts: List<Burst> = emptyList(),
) {
    /** All bursts in capture order: the EV steps, then the dark step. */
    val bursts: List<Burst> = steps.flatMap { it.bursts } + darkBursts
    val totalFrames: Int get() = bursts.sumOf { it.frames }

    /** Frames of the dark step (0 without one). */
    val darkFrames: Int get() = darkBursts.sumOf { it.frames }

    /** Estimated time of one burst (frames plus settle overhead). */
    fun burstDurationNs(b: Burst): Long = b.frames * b.frameDurationNs + options.settleOverheadNs

    /** Stable identity of what is captured, so a resumed session only continues the same plan. */
    val fingerprint: String by lazy {
        val text = buildString {
            append("${sensor.width}x${sensor.height} ${sensor.cfa} ${sensor.whiteLevel} ${sensor.blackLevels} ")
            append("${sensor.referenceIso} ${sensor.make}/${sensor.model} ${sensor.binWidth}\n")
            for (b in bursts) append("${b.index} ${b.stepIndex} ${b.role} ${b.iso} ${b.exposureNs} ${b.frames}\n")
        }
        MessageDigest.getInstance("SHA-256").digest(text.toByteArray()).joinToString("") { "%02x".format(it) }.take(32)
    }

    /** A few lines for the plan screen. */
    fun describe(): String = buildString {
        append("Reference ISO $referenceIso; target ISOs ${targetIsos.joinToString()}\n")
        append("${steps.size} EV steps, ${bursts.size} bursts, $totalFrames frames\n")
        if (darkBursts.isNotEmpty()) {
            append("Dark step (lens covered): ${darkBursts.size} bursts of ${darkBursts.first().frames} frames, " +
                "ISO ${darkBursts.joinToString { it.iso.toString() }}\n")
        }
        append("Estimated time ${fmtDuration(estimatedDurationNs)}; ")
        append(estimatedPackBytes?.let { "pack ≈ ${fmtBytes(it)}" } ?: "pack size unknown (no native library)")
        if (options.recording) append("; recording ≈ ${fmtBytes(estimatedRecordingBytes)}")
        for (a in adjustments) append("\n• $a")
    }
}

/** The planner's answer: a plan, or the reasons there can be none. */
sealed class PlanResult {
    data class Ok(val plan: CapturePlan) : PlanResult()
    data class Refused(val reasons: List<String>) : PlanResult() {
        override fun toString(): String = "plan refused: " + reasons.joinToString("; ")
    }
}

/** Turns camera capabilities and user choices into an ordered, clamped, estimated capture plan. */
object CapturePlanner {

    /** Two EV steps closer than this (in EV) after clamping are duplicates: the later one is dropped. */
    const val DUPLICATE_EV = 1.0 / 3.0

    /**
     * Reasons this camera cannot be calibrated at all (empty when it can): no MANUAL_SENSOR or RAW
     * capability, lens shading applied to RAW, not a Bayer mosaic, nonsensical levels or ranges.
     */
    fun unsupportedReasons(c: CameraCapabilities): List<String> {
        val r = mutableListOf<String>()
        if (!c.manualSensor) r += "camera ${c.cameraId} lacks the MANUAL_SENSOR capability: ISO and exposure cannot be locked"
        if (!c.raw) r += "camera ${c.cameraId} lacks the RAW capability: no RAW_SENSOR frames"
        if (c.lensShadingAppliedToRaw) {
            r += "camera ${c.cameraId} applies lens shading to its RAW frames (SENSOR_INFO_LENS_SHADING_APPLIED): " +
                "the noise would be scaled differently across the frame"
        }
        if (c.cfa == null) r += "camera ${c.cameraId} is not a 2×2 Bayer sensor (colour filter arrangement ${CfaArrangement.describeCamera2(c.cfaCode)})"
        if (c.rawWidth < 2 || c.rawHeight < 2) r += "camera ${c.cameraId} reports no usable RAW size (${c.rawWidth}×${c.rawHeight})"
        if (c.blackLevelPattern.size != 4) {
            r += "camera ${c.cameraId} reports ${c.blackLevelPattern.size} black levels; 4 (one per CFA position) are needed"
        } else if (c.blackLevelPattern.any { it < 0 || it >= c.whiteLevel }) {
            r += "camera ${c.cameraId} reports black levels ${c.blackLevelPattern} not below its white level ${c.whiteLevel}"
        }
        if (c.sensitivityRange.isEmpty() || c.sensitivityRange.first <= 0) r += "camera ${c.cameraId} reports an empty sensitivity range ${c.sensitivityRange}"
        if (c.exposureRangeNs.isEmpty() || c.exposureRangeNs.first <= 0) r += "camera ${c.cameraId} reports an empty exposure range ${c.exposureRangeNs}"
        return r
    }

    /** Nominal ISOs 100·2^m strictly above the reference ISO and inside the sensitivity range. */
    fun defaultTargetIsos(c: CameraCapabilities): List<Int> =
        (-3..12).map { (100.0 * 2.0.pow(it)).roundToLong().toInt() }
            .filter { it > c.referenceIso && it <= c.sensitivityRange.last }

    /**
     * Plans a capture. The sensor spec leaves the bin width to the core ([SensorSpec.binWidth] 0);
     * [binWidths] only sizes the pack estimate.
     */
    fun plan(c: CameraCapabilities, o: PlanOptions, binWidths: BinWidthSource = BinWidthSource.CORE): PlanResult {
        val refusals = unsupportedReasons(c).toMutableList()
        refusals += optionErrors(o)
        if (refusals.isNotEmpty()) return PlanResult.Refused(refusals)

        val adjustments = mutableListOf<PlanAdjustment>()
        val refIso = c.referenceIso
        val minExp = c.exposureRangeNs.first
        val maxExp = o.maxExposureNs?.let { minOf(it, c.maxUsableExposureNs) } ?: c.maxUsableExposureNs

        // Target ISOs: inside the range, above the reference, no duplicates.
        val targets = mutableListOf<Int>()
        for (iso in (o.targetIsos ?: defaultTargetIsos(c)).distinct().sorted()) {
            when {
                iso == refIso -> adjustments += PlanAdjustment(PlanAdjustment.Kind.DROPPED, null, iso,
                    "ISO $iso is the reference ISO; it is captured in every EV step anyway")
                iso < refIso || iso > c.sensitivityRange.last -> adjustments += PlanAdjustment(PlanAdjustment.Kind.DROPPED, null, iso,
                    "ISO $iso is outside the camera's sensitivity range ${c.sensitivityRange.first}..${c.sensitivityRange.last}")
                else -> {
                    targets += iso
                    if (c.isDigitalGain(iso)) adjustments += PlanAdjustment(PlanAdjustment.Kind.DIGITAL_GAIN, null, iso,
                        "ISO $iso is above the max analog sensitivity ${c.maxAnalogSensitivity}: reached by digital gain")
                }
            }
        }
        if (targets.isEmpty()) {
            return PlanResult.Refused(listOf("no target ISO left: the camera's range is ${c.sensitivityRange.first}..${c.sensitivityRange.last} " +
                "and the reference ISO $refIso is not a target; choose ISOs above $refIso"))
        }

        // EV steps at the reference ISO.
        val baseRefExposure = o.metering.brightness / refIso * 1e9
        val evs = generateSequence(o.evMin) { it + o.evIncrement }.takeWhile { it <= o.evMax + 1e-9 }.toList()
        val steps = mutableListOf<EvStep>()
        val isosWithBursts = mutableSetOf<Int>()
        var lastKeptExposure: Long? = null
        var burstIndex = 0
        for (ev in evs) {
            val wanted = (baseRefExposure * 2.0.pow(ev)).roundToLong()
            val refExp = wanted.coerceIn(minExp, maxExp)
            if (refExp != wanted) {
                val off = ln(refExp.toDouble() / wanted) / ln(2.0)
                val prev = lastKeptExposure
                if (prev != null && abs(ln(refExp.toDouble() / prev) / ln(2.0)) < DUPLICATE_EV) {
                    adjustments += PlanAdjustment(PlanAdjustment.Kind.DROPPED, ev, refIso,
                        "EV ${fmtEv(ev)}: reference exposure ${fmtNs(wanted)} is outside ${fmtNs(minExp)}..${fmtNs(maxExp)}; " +
                            "clamped it would repeat the previous step")
                    continue
                }
                adjustments += PlanAdjustment(PlanAdjustment.Kind.CLAMPED, ev, refIso,
                    "EV ${fmtEv(ev)}: reference exposure ${fmtNs(wanted)} clamped to ${fmtNs(refExp)} (${fmtEv(off)} EV)")
            }
            val stepIndex = steps.size
            val bursts = mutableListOf<Burst>()
            for (iso in targets) {
                val exp = (refExp.toDouble() * refIso / iso).roundToLong()
                if (exp < minExp) {
                    adjustments += PlanAdjustment(PlanAdjustment.Kind.DROPPED, ev, iso,
                        "EV ${fmtEv(ev)} ISO $iso: exposure ${fmtNs(exp)} would be below the camera's minimum ${fmtNs(minExp)}")
                    continue
                }
                bursts += Burst(0, stepIndex, ev, BurstRole.TARGET, iso, exp, maxOf(exp, c.minFrameDurationNs), o.framesPerBurst, c.isDigitalGain(iso))
            }
            if (bursts.isEmpty()) {
                adjustments += PlanAdjustment(PlanAdjustment.Kind.DROPPED, ev, null,
                    "EV ${fmtEv(ev)}: no target ISO can match its brightness, so the step is left out")
                continue
            }
            val ref = Burst(0, stepIndex, ev, BurstRole.REFERENCE, refIso, refExp, maxOf(refExp, c.minFrameDurationNs),
                o.referenceFramesPerBurst, c.isDigitalGain(refIso))
            val numbered = (listOf(ref) + bursts).map { it.copy(index = burstIndex++) }
            bursts.forEach { isosWithBursts += it.iso }
            steps += EvStep(stepIndex, ev, refExp, numbered)
            lastKeptExposure = refExp
        }
        if (steps.isEmpty()) {
            return PlanResult.Refused(listOf("nothing left after clamping to the camera's exposure range " +
                "${fmtNs(minExp)}..${fmtNs(maxExp)}: " + adjustments.filter { it.kind == PlanAdjustment.Kind.DROPPED }.joinToString("; ") { it.message }))
        }
        for (iso in targets) if (iso !in isosWithBursts) {
            adjustments += PlanAdjustment(PlanAdjustment.Kind.DROPPED, null, iso, "ISO $iso: no EV step fits the exposure range, so it is not calibrated")
        }
        val kept = targets.filter { it in isosWithBursts }
        val darkBursts = if (o.darkFrames) darkStep(c, o, steps, refIso, kept, burstIndex) else emptyList()
        val cfa = requireNotNull(c.cfa)
        val sensor = SensorSpec(c.rawWidth, c.rawHeight, cfa.label, c.blackLevelPattern.map { it.toFloat() }, c.whiteLevel,
            refIso, c.make, c.model)
        val packBytes = binWidths.defaultBinWidth(c.whiteLevel, c.blackLevelPattern)?.let { estimatePackBytes(c, kept, it) }
        val allBursts = steps.flatMap { it.bursts } + darkBursts
        val duration = allBursts.sumOf { it.frames * it.frameDurationNs + o.settleOverheadNs }
        val frames = allBursts.sumOf { it.frames.toLong() }
        val rowStride = (o.rowStrideBytes ?: c.rawRowStrideBytes ?: (2 * c.rawWidth)).toLong()
        val recording = if (o.recording) frames * rowStride * c.rawHeight + allBursts.size * 4096L else 0L
        return PlanResult.Ok(CapturePlan(c, o, sensor, refIso, kept, steps, adjustments, duration, packBytes, recording, darkBursts))
    }

    /**
     * The dark step: per ISO (the reference ISO, then each kept target) one burst of
     * [PlanOptions.darkFramesPerIso] frames at the shortest exposure that ISO has in the lit
     * sweep, numbered from [firstIndex]. Dark shading (the per-pixel offset, k·gain + b) and the
     * signal-independent noise are properties of the read-out at that gain, not of the exposure
     * time, so long exposures would add time and dark current without telling the core more; the
     * shortest exposure already in the plan is one the camera is known to apply at that ISO.
     */
    private fun darkStep(c: CameraCapabilities, o: PlanOptions, steps: List<EvStep>, refIso: Int, targets: List<Int>, firstIndex: Int): List<Burst> {
        val lit = steps.flatMap { it.bursts }
        var index = firstIndex
        return (listOf(refIso) + targets).map { iso ->
            val exp = lit.filter { it.iso == iso }.minOf { it.exposureNs }
            Burst(index++, steps.size, 0.0, BurstRole.DARK, iso, exp, maxOf(exp, c.minFrameDurationNs), o.darkFramesPerIso, c.isDigitalGain(iso))
        }
    }

    /**
     * Rough pack size: per target ISO, per CFA position, per bin, one histogram about 12σ wide of
     * 4-byte counts plus a small header. σ at mid-range comes from the camera's noise profile when it
     * has one (scale ∝ gain, offset ∝ gain²), otherwise from a typical phone sensor (0.5 % of the
     * range at the reference ISO, growing with √gain).
     */
    fun estimatePackBytes(c: CameraCapabilities, isos: List<Int>, binWidth: Int): Long {
        val black = c.blackLevelPattern.minOrNull() ?: 0
        val range = (c.whiteLevel - black).coerceAtLeast(1).toDouble()
        val bins = ceil(range / binWidth).toLong()
        var total = 4096L
        for (iso in isos) {
            val np = c.noiseProfile
            val npIso = c.noiseProfileIso
            val sigma = if (np != null && np.isNotEmpty() && npIso != null && npIso > 0) {
                val g = iso.toDouble() / npIso
                np.map { sqrt((it.scale * g * 0.5 + it.offset * g * g).coerceAtLeast(0.0)) * range }.average()
            } else {
                0.005 * range * sqrt(iso.toDouble() / c.referenceIso)
            }
            val width = (12 * sigma + 1).coerceAtLeast(3.0).toLong()
            total += 4 * bins * (32 + 4 * width)
        }
        return total
    }

    private fun optionErrors(o: PlanOptions): List<String> {
        val r = mutableListOf<String>()
        if (o.metering.iso <= 0 || o.metering.exposureNs <= 0) r += "metering (ISO ${o.metering.iso}, ${o.metering.exposureNs} ns) must be positive: meter the scene first"
        if (o.framesPerBurst < 2) r += "framesPerBurst is ${o.framesPerBurst}; at least 2 are needed (100 recommended)"
        if (o.referenceFramesPerBurst < 2) r += "referenceFramesPerBurst is ${o.referenceFramesPerBurst}; at least 2 are needed (per-pixel spread)"
        if (o.evIncrement <= 0.0 || o.evIncrement.isNaN()) r += "evIncrement is ${o.evIncrement}; it must be > 0"
        if (o.evMin > o.evMax || o.evMin.isNaN() || o.evMax.isNaN()) r += "EV range ${o.evMin}..${o.evMax} is empty; evMin must be ≤ evMax"
        if ((o.maxExposureNs ?: 1) <= 0) r += "maxExposureNs is ${o.maxExposureNs}; it must be > 0"
        if (o.settleOverheadNs < 0) r += "settleOverheadNs is ${o.settleOverheadNs}; it must be ≥ 0"
        if (o.darkFrames && o.darkFramesPerIso < 2) r += "darkFramesPerIso is ${o.darkFramesPerIso}; at least 2 are needed (8 recommended)"
        o.targetIsos?.filter { it <= 0 }?.let { if (it.isNotEmpty()) r += "target ISOs $it must be positive" }
        return r
    }
}

internal fun fmtEv(ev: Double): String = if (ev == Math.rint(ev)) "%+d".format(ev.toLong()) else "%+.2f".format(ev)

/** Exposure for people: 12.5 ms, 1/8000 s as 125 µs, 2.0 s. */
fun fmtNs(ns: Long): String = when {
    ns >= 1_000_000_000L -> "%.2f s".format(ns / 1e9)
    ns >= 1_000_000L -> "%.2f ms".format(ns / 1e6)
    else -> "%.1f µs".format(ns / 1e3)
}

fun fmtDuration(ns: Long): String {
    val s = (ns + 500_000_000L) / 1_000_000_000L
    return when {
        s >= 3600 -> "%d h %02d min".format(s / 3600, (s % 3600) / 60)
        s >= 60 -> "%d min %02d s".format(s / 60, s % 60)
        else -> "$s s"
    }
}

fun fmtBytes(b: Long): String = when {
    b >= 1L shl 30 -> "%.1f GiB".format(b / (1L shl 30).toDouble())
    b >= 1L shl 20 -> "%.1f MiB".format(b / (1L shl 20).toDouble())
    b >= 1L shl 10 -> "%.1f KiB".format(b / 1024.0)
    else -> "$b B"
}
