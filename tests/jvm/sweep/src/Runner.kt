package org.noisecal.capture.sweeptest

import java.io.File
import kotlin.system.exitProcess

/** A failed expectation. */
class Failure(message: String) : AssertionError(message)

fun check(cond: Boolean, msg: () -> String) { if (!cond) throw Failure(msg()) }

fun <T> eq(expected: T, actual: T, what: String) {
    if (expected != actual) throw Failure("$what: expected <$expected>, got <$actual>")
}

/** Where the harness finds the CLI and keeps its files. */
class Env(val cli: File, val work: File)

/** A named group of tests. */
open class Suite(val name: String) {
    val tests = mutableListOf<Pair<String, () -> Unit>>()
    fun test(name: String, body: () -> Unit) { tests += name to body }
}

private fun usage(msg: String): Nothing {
    System.err.println("error: $msg\nusage: SweepJniTestsKt --cli PATH/noisecal --work DIR [--filter NAME]")
    exitProcess(2)
}

/** Runs every test (or those whose "suite :: name" contains --filter); `N passed, M failed` last; exit 1 on any failure. */
fun main(args: Array<String>) {
    var cli: File? = null
    var work: File? = null
    var filter: String? = null
    var i = 0
    while (i < args.size) {
        val v = args.getOrNull(i + 1) ?: usage("${args[i]} needs a value")
        when (args[i]) {
            "--cli" -> cli = File(v)
            "--work" -> work = File(v)
            "--filter" -> filter = v
            else -> usage("unknown argument ${args[i]}")
        }
        i += 2
    }
    val env = Env(cli ?: usage("--cli missing"), work ?: usage("--work missing"))
    if (!env.cli.canExecute()) usage("${env.cli} is not an executable: build it with cargo build --release -p noisecal-cli")
    env.work.mkdirs()

    val suites = listOf(SweepJniTests(env))
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
            if (e !is Failure) e.stackTrace.take(10).forEach { println("    at $it") }
        }
    }
    println("$passed passed, $failed failed")
    exitProcess(if (failed == 0 && passed > 0) 0 else 1)
}
