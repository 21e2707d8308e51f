package org.noisecal.capture.plan

import kotlin.math.sqrt

/**
 * What a calibration said about the gap between two neighbouring calibrated ISOs that one more
 * capture can settle (the core's `derive::gain_switch::GapCall`; `noisecal calibrate` prints the
 * same as capture advice). Gaps called "no switch" need nothing and are not listed.
 *
 * @property belowIso the calibrated ISO below the gap.
 * @property aboveIso the calibrated ISO above it.
 */
data class GainGap(val belowIso: Int, val aboveIso: Int, val call: Call) {
    init {
        require(belowIso in 1 until aboveIso) { "a gap runs from a lower ISO to a higher one: $belowIso → $aboveIso" }
    }

    enum class Call {
        /** A conversion-gain switch: which gain the camera uses between the two ISOs is unknown. */
        SWITCH,

        /** A side's read noise at black is not pinned (the chart's darkest patches lie far above black). */
        UNDETERMINED,
    }

    companion object {
        /** The header line of the gap calls' text form, with its version. */
        const val CALLS_HEADER = "noisecal-gap-calls 1"

        /**
         * The gaps a finished calibration leaves open, read from its gap calls
         * (`NoisecalSession.Finished.gapCalls`; the form is documented in rust/jni/src/gap_calls.rs:
         * the header [CALLS_HEADER], then `BELOW ABOVE CALL` per gap, CALL `switch`, `none` or
         * `undetermined`). Gaps called `none` need nothing and are left out. Throws
         * [IllegalArgumentException] naming the line when the text is not in that form (another
         * version, a missing field, an unknown call, ISOs out of order).
         */
        fun parseCalls(text: String): List<GainGap> {
            val lines = text.lines().filter { it.isNotBlank() }
            require(lines.firstOrNull() == CALLS_HEADER) {
                "gap calls must start with \"$CALLS_HEADER\", got \"${lines.firstOrNull() ?: ""}\": " +
                    "the native library and the app are of different versions"
            }
            val out = mutableListOf<GainGap>()
            var previousAbove = 0
            for ((i, line) in lines.drop(1).withIndex()) {
                val f = line.split(' ')
                val where = "gap calls line ${i + 2} \"$line\""
                require(f.size == 3) { "$where: expected BELOW ABOVE CALL" }
                val below = requireNotNull(f[0].toIntOrNull()) { "$where: ISO \"${f[0]}\" is not a number" }
                val above = requireNotNull(f[1].toIntOrNull()) { "$where: ISO \"${f[1]}\" is not a number" }
                require(below in 1 until above) { "$where: a gap runs from a lower ISO to a higher one" }
                require(below >= previousAbove) { "$where: gaps must come in ISO order" }
                previousAbove = above
                when (f[2]) {
                    "switch" -> out += GainGap(below, above, Call.SWITCH)
                    "undetermined" -> out += GainGap(below, above, Call.UNDETERMINED)
                    "none" -> {}
                    else -> throw IllegalArgumentException("$where: unknown call \"${f[2]}\" (switch, none or undetermined)")
                }
            }
            return out
        }
    }

    /**
     * The ISO halfway between the two in log ISO, rounded to a whole ISO and kept inside the gap:
     * the one calibration that halves the range where the conversion gain is unknown (the core's
     * `GainSwitch::bisecting_iso`: `round(√(below·above))`).
     */
    val bisectingIso: Int
        get() = Math.round(sqrt(belowIso.toDouble() * aboveIso.toDouble())).toInt().coerceIn(belowIso, aboveIso)
}

/**
 * A follow-up capture: [options] plan the calibrated ISOs again with [addedIsos] among the
 * targets, and the dark step on when an undetermined gap asks for it; [reasons] say why, one
 * sentence per gap.
 */
data class FollowUp(val options: PlanOptions, val addedIsos: List<Int>, val darkFrames: Boolean, val reasons: List<String>)

/** Turns a calibration's gap calls into the next capture. */
object GainGapFollowUp {
    /**
     * The follow-up to a calibration of [calibratedIsos] (its target ISOs) planned with
     * [previous] on camera [c], given its [gaps]; null when no capture would settle more.
     *
     * - A switch whose gap holds a whole ISO strictly between its ends (and inside the camera's
     *   sensitivity range) adds its [GainGap.bisectingIso] as a target.
     * - An undetermined gap turns the dark step on (dark frames pin the read noise at black of
     *   both ISOs); when the dark step was already on, its bisecting ISO is added instead, as
     *   for a switch.
     */
    fun propose(c: CameraCapabilities, previous: PlanOptions, calibratedIsos: List<Int>, gaps: List<GainGap>): FollowUp? {
        val added = sortedSetOf<Int>()
        val reasons = mutableListOf<String>()
        var dark = previous.darkFrames
        for (g in gaps.sortedBy { it.belowIso }) {
            val half = g.bisectingIso
            val halves = half > g.belowIso && half < g.aboveIso && half in c.sensitivityRange && half !in calibratedIsos
            when {
                g.call == GainGap.Call.UNDETERMINED && !previous.darkFrames -> {
                    dark = true
                    reasons += "whether the conversion gain changes between ISO ${g.belowIso} and ${g.aboveIso} is unknown: " +
                        "the chart does not pin the read noise at black there; the dark step (lens covered) settles it"
                }
                halves && added.add(half) -> reasons += when (g.call) {
                    GainGap.Call.SWITCH -> "the sensor switches conversion gain between ISO ${g.belowIso} and ${g.aboveIso}: " +
                        "ISO $half (halfway in log ISO) halves the range where the gain is unknown"
                    GainGap.Call.UNDETERMINED -> "whether the conversion gain changes between ISO ${g.belowIso} and ${g.aboveIso} " +
                        "is unknown even with dark frames: ISO $half (halfway in log ISO) halves that range"
                }
            }
        }
        if (added.isEmpty() && dark == previous.darkFrames) return null
        val targets = (calibratedIsos + added).distinct().sorted()
        return FollowUp(previous.copy(targetIsos = targets, darkFrames = dark), added.toList(), dark && !previous.darkFrames, reasons)
    }
}
