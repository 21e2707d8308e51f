package org.noisecal.capture.test

import kotlin.system.exitProcess

/** A failed expectation. */
class Failure(message: String) : AssertionError(message)

fun check(cond: Boolean, msg: () -> String) { if (!cond) throw Failure(msg()) }

fun <T> eq(expected: T, actual: T, what: String) {
    if (expected != actual) throw Failure("$what: expected <$expected>, got <$actual>")
}

fun near(expected: Double, actual: Double, relTol: Double, what: String) {
    val tol = relTol * maxOf(1e-12, kotlin.math.abs(expected))
    if (kotlin.math.abs(expected - actual) > tol) throw Failure("$what: expected $expected ± $tol, got $actual")
}

inline fun <reified E : Throwable> throws(what: String, block: () -> Unit): E {
    try { block() } catch (e: Throwable) {
        if (e is E) return e
        throw Failure("$what: expected ${E::class.simpleName}, got ${e.javaClass.simpleName}: ${e.message}")
    }
    throw Failure("$what: expected ${E::class.simpleName}, nothing was thrown")
}

/** A named group of tests. */
open class Suite(val name: String) {
    val tests = mutableListOf<Pair<String, () -> Unit>>()
    fun test(name: String, body: () -> Unit) { tests += name to body }
}

/** Runs every suite; prints one line per test and `N passed, M failed` last; exits 1 on any failure. */
fun main(args: Array<String>) {
    val suites = listOf(PlanTests(), ControllerTests(), SweepTests(), UiStateTests(), SessionRepositoryTests(), DarkStepTests(), GainGapTests())
    val filter = args.firstOrNull()
    var passed = 0
    var failed = 0
    for (s in suites) for ((name, body) in s.tests) {
        val full = "${s.name} :: $name"
        if (filter != null && !full.contains(filter)) continue
        val t0 = System.nanoTime()
        try {
            body()
            passed++
            println("PASS $full (${(System.nanoTime() - t0) / 1_000_000} ms)")
        } catch (e: Throwable) {
            failed++
            println("FAIL $full: ${e.javaClass.simpleName}: ${e.message}")
            if (e !is Failure) e.stackTrace.take(8).forEach { println("    at $it") }
        }
    }
    println("$passed passed, $failed failed")
    exitProcess(if (failed == 0 && passed > 0) 0 else 1)
}
