package org.noisecal.jni.test

import kotlin.math.floor
import kotlin.math.sqrt

/**
 * Kotlin port of rust/jni/src/testkit.rs `Synth` (same integer hashing, same IEEE f64 operations in
 * the same order), so both sides push bit-identical frames; checked against `noisecal-jni-tool
 * frame-hash`.
 */
class Synth(val width: Int, val height: Int, val seed: Long) {
    val black = 64.0
    val white = 1023
    val referenceIso = 100
    val gain = 0.4
    val readDn = 1.2

    fun rate(y: Int, x: Int): Double {
        val px = minOf(x * PATCHES_X / width, PATCHES_X - 1)
        val py = minOf(y * PATCHES_Y / height, PATCHES_Y - 1)
        val patch = (py * PATCHES_X + px).toDouble()
        val fraction = 0.02 + 0.8 * patch / (PATCHES_X * PATCHES_Y - 1).toDouble()
        val site = if ((y and 1) == (x and 1)) 1.0 else 0.85
        return fraction * site * (white.toDouble() - black) / gain / 10.0
    }

    /** Writes one frame's samples into [out] (little-endian order set) at [rowStride] bytes per row. */
    fun frameInto(iso: Int, exposureNs: Long, index: Long, out: java.nio.ByteBuffer, rowStride: Int) {
        val g = gain * iso.toDouble() / referenceIso.toDouble()
        val read = readDn * sqrt(iso.toDouble() / referenceIso.toDouble())
        val ms = exposureNs.toDouble() / 1e6
        val k = splitmix64(seed xor splitmix64((index + 1) * 0x100000001B3L))
        for (y in 0 until height) {
            val rowBase = y * rowStride
            for (x in 0 until width) {
                val electrons = rate(y, x) * ms
                val signal = electrons * g
                val sd = sqrt(signal * g + read * read)
                val i = y.toLong() * width.toLong() + x.toLong()
                var v = black + signal + sd * normalish(splitmix64(k xor i))
                v = floor(v + 0.5).coerceIn(0.0, white.toDouble())
                out.putShort(rowBase + 2 * x, v.toInt().toShort())
            }
        }
    }

    companion object {
        const val PATCHES_X = 8
        const val PATCHES_Y = 6

        fun splitmix64(x: Long): Long {
            var z = x + -0x61c8864680b583ebL
            z = (z xor (z ushr 30)) * -0x40a7b892e31b1a47L
            z = (z xor (z ushr 27)) * -0x6b2fb644ecceee15L
            return z xor (z ushr 31)
        }

        fun normalish(h: Long): Double {
            val s = (h and 0xFFFF) + ((h ushr 16) and 0xFFFF) + ((h ushr 32) and 0xFFFF) + (h ushr 48)
            return (s.toDouble() / 65536.0 - 2.0) * sqrt(3.0)
        }
    }
}
