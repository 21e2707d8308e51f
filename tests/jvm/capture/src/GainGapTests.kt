package org.noisecal.capture.test

import org.noisecal.capture.plan.BurstRole
import org.noisecal.capture.plan.CapturePlanner
import org.noisecal.capture.plan.GainGap
import org.noisecal.capture.plan.GainGapFollowUp
import org.noisecal.capture.plan.Metering
import org.noisecal.capture.plan.PlanOptions

/** The follow-up capture a calibration's conversion-gain gaps ask for (the bisecting ISO, the dark step). */
class GainGapTests : Suite("gain gaps") {
    init {
        test("bisecting ISO: halfway in log ISO, rounded, as the core's GainSwitch::bisecting_iso") {
            // The core's unit test: 400 → 800 gives 566; random 22's 256 → 1024 gives 512 (the
            // arithmetic mean, a wrong midpoint, would give 600 and 640).
            eq(566, GainGap(400, 800, GainGap.Call.SWITCH).bisectingIso, "400 → 800")
            eq(512, GainGap(256, 1024, GainGap.Call.SWITCH).bisectingIso, "256 → 1024")
            eq(400, GainGap(200, 800, GainGap.Call.SWITCH).bisectingIso, "phone12's 200 → 800")
            eq(100, GainGap(100, 101, GainGap.Call.SWITCH).bisectingIso, "no whole ISO inside: an end (√10100 = 100.5 rounds down)")
            throws<IllegalArgumentException>("a gap the wrong way round") { GainGap(800, 400, GainGap.Call.SWITCH) }
        }

        test("a switch adds its bisecting ISO to the plan; the sweep then captures it") {
            val c = caps(range = 50..3200, maxAnalog = 800)
            val o = PlanOptions(Metering(100, 10_000_000L), targetIsos = listOf(200, 800, 3200))
            val calibrated = planOk(CapturePlanner.plan(c, o)).targetIsos
            eq(listOf(200, 800, 3200), calibrated, "calibrated targets")
            val f = GainGapFollowUp.propose(c, o, calibrated, listOf(GainGap(200, 800, GainGap.Call.SWITCH)))
                ?: throw Failure("a switch with ISOs inside its gap asks for one more")
            eq(listOf(400), f.addedIsos, "the bisecting ISO")
            eq(false, f.darkFrames, "no dark step for a switch")
            eq(listOf(200, 400, 800, 3200), f.options.targetIsos, "targets of the follow-up")
            check(f.reasons.single().contains("ISO 400")) { f.reasons.toString() }
            val p = planOk(CapturePlanner.plan(c, f.options))
            checkInvariants(p)
            check(p.bursts.any { it.iso == 400 && it.role == BurstRole.TARGET }) { "ISO 400 is captured: ${p.describe()}" }
        }

        test("an undetermined gap turns the dark step on; with it on already, the gap is bisected") {
            val c = caps(range = 50..3200, maxAnalog = 800)
            val o = PlanOptions(Metering(100, 10_000_000L), targetIsos = listOf(400, 1600))
            val gaps = listOf(GainGap(400, 1600, GainGap.Call.UNDETERMINED))
            val f = GainGapFollowUp.propose(c, o, listOf(400, 1600), gaps) ?: throw Failure("an undetermined gap asks for dark frames")
            eq(true, f.darkFrames, "dark step on")
            eq(emptyList<Int>(), f.addedIsos, "no ISO added while dark frames may settle it")
            val p = planOk(CapturePlanner.plan(c, f.options))
            eq(listOf(50, 400, 1600), p.darkBursts.map { it.iso }, "dark bursts at the reference and the gap's ISOs")
            val again = GainGapFollowUp.propose(c, f.options, listOf(400, 1600), gaps) ?: throw Failure("still undetermined with dark frames")
            eq(listOf(800), again.addedIsos, "bisected once dark frames did not settle it")
            eq(true, again.options.darkFrames, "dark step kept")
        }

        test("gap calls as finish returns them: parsed, 'none' left out, bad text refused with the line named") {
            val text = "noisecal-gap-calls 1\n125 250 none\n250 500 switch\n500 1600 undetermined\n"
            eq(
                listOf(GainGap(250, 500, GainGap.Call.SWITCH), GainGap(500, 1600, GainGap.Call.UNDETERMINED)),
                GainGap.parseCalls(text),
                "parsed",
            )
            eq(emptyList<GainGap>(), GainGap.parseCalls("noisecal-gap-calls 1\n"), "one calibrated ISO: no gap")
            // Fed to the follow-up: the dark step for the undetermined gap, the bisecting ISO of the switch.
            val c = caps(range = 50..3200, maxAnalog = 800)
            val o = PlanOptions(Metering(100, 10_000_000L), targetIsos = listOf(125, 250, 500, 1600))
            val f = GainGapFollowUp.propose(c, o, listOf(125, 250, 500, 1600), GainGap.parseCalls(text))
                ?: throw Failure("open gaps ask for a follow-up")
            eq(true, f.darkFrames, "dark step for the undetermined gap")
            eq(listOf(354), f.addedIsos, "√(250·500) = 353.6")
            for ((bad, part) in listOf(
                "" to "must start with",
                "noisecal-gap-calls 2\n100 200 none" to "different versions",
                "noisecal-gap-calls 1\n100 200" to "line 2",
                "noisecal-gap-calls 1\n100 200 maybe" to "unknown call \"maybe\"",
                "noisecal-gap-calls 1\n100 x none" to "is not a number",
                "noisecal-gap-calls 1\n200 100 none" to "lower ISO to a higher one",
                "noisecal-gap-calls 1\n200 400 none\n100 200 none" to "line 3",
            )) {
                val m = throws<IllegalArgumentException>("\"$bad\"") { GainGap.parseCalls(bad) }.message ?: ""
                check(m.contains(part)) { "\"$bad\": message \"$m\" does not say \"$part\"" }
            }
        }

        test("nothing to settle: no follow-up") {
            val c = caps(range = 50..3200, maxAnalog = 800)
            val o = PlanOptions(Metering(100, 10_000_000L), targetIsos = listOf(100, 101))
            eq(null, GainGapFollowUp.propose(c, o, listOf(100, 101), emptyList()), "no gaps")
            eq(null, GainGapFollowUp.propose(c, o, listOf(100, 101), listOf(GainGap(100, 101, GainGap.Call.SWITCH))), "no whole ISO inside")
            // Already calibrated at the bisecting ISO (its neighbours' calls were made without it).
            eq(null, GainGapFollowUp.propose(c, o, listOf(200, 400, 800), listOf(GainGap(200, 800, GainGap.Call.SWITCH))), "bisector calibrated")
        }
    }
}
