package org.noisecal.jni.test

import java.io.BufferedInputStream
import java.io.DataInputStream
import java.io.EOFException
import java.io.File
import java.io.FileInputStream
import java.nio.ByteBuffer
import java.nio.ByteOrder
import java.util.zip.CRC32

/**
 * A reader of noisecal's recording format v1 (rust/core/src/recording.rs), all integers little-endian:
 * magic "NCALREC\0" | version u16 | header_len u32 | header | crc32(header) u32, then records
 * tag u8 | payload | crc32(tag + payload) u32 (1 BeginStep, 2 Frame, 3 NoiseProfile, 4 BeginDark
 * (no payload), 255 End).
 */
class RecordingHeader(
    val width: Int,
    val height: Int,
    val cfa: String,
    val white: Int,
    val black: FloatArray,
    val referenceIso: Int,
    val binWidth: Int,
    val make: String,
    val model: String,
)

sealed class Record {
    data class BeginStep(val exposureNs: Long) : Record()
    class Frame(
        val iso: Int,
        val exposureNs: Long,
        val black: FloatArray?,
        val width: Int,
        val height: Int,
        val rowStride: Int,
        val pixelStride: Int,
        val data: ByteArray,
    ) : Record()
    class NoiseProfile(val iso: Int, val profile: DoubleArray) : Record()
    data object BeginDark : Record()
    data class End(val frames: Long) : Record()
}

class Recording(val header: RecordingHeader, val records: List<Record>, val ended: Boolean) {
    val frames: List<Record.Frame> get() = records.filterIsInstance<Record.Frame>()

    companion object {
        private val MAGIC = "NCALREC\u0000".toByteArray(Charsets.US_ASCII)
        private val CFA = arrayOf("RGGB", "BGGR", "GRBG", "GBRG")

        private fun le(b: ByteArray): ByteBuffer = ByteBuffer.wrap(b).order(ByteOrder.LITTLE_ENDIAN)

        private fun crc(vararg parts: ByteArray): Int {
            val c = CRC32()
            for (p in parts) c.update(p)
            return c.value.toInt()
        }

        fun read(file: File): Recording {
            DataInputStream(BufferedInputStream(FileInputStream(file), 1 shl 20)).use { input ->
                fun bytes(n: Int): ByteArray = ByteArray(n).also { input.readFully(it) }
                val fixed = bytes(14)
                require(fixed.copyOfRange(0, 8).contentEquals(MAGIC)) { "$file is not a noisecal recording" }
                val f = le(fixed)
                val version = f.getShort(8).toInt()
                require(version == 1) { "$file has recording version $version, this reader knows 1" }
                val len = f.getInt(10)
                val h = bytes(len)
                val hcrc = le(bytes(4)).getInt()
                require(hcrc == crc(h)) { "$file: header checksum mismatch" }
                val hb = le(h)
                val width = hb.getInt()
                val height = hb.getInt()
                val cfa = CFA[hb.get().toInt()]
                val white = hb.getShort().toInt() and 0xFFFF
                val black = FloatArray(4) { hb.getFloat() }
                val referenceIso = hb.getInt()
                val binWidth = hb.getShort().toInt() and 0xFFFF
                fun text(): String {
                    val n = hb.getShort().toInt() and 0xFFFF
                    val t = ByteArray(n)
                    hb.get(t)
                    return String(t, Charsets.UTF_8)
                }
                val make = text()
                val model = text()
                val header = RecordingHeader(width, height, cfa, white, black, referenceIso, binWidth, make, model)
                val records = ArrayList<Record>()
                var ended = false
                while (!ended) {
                    val tag = input.read()
                    if (tag < 0) break
                    val tagBytes = byteArrayOf(tag.toByte())
                    val record: Record
                    val parts: List<ByteArray>
                    when (tag) {
                        1 -> {
                            val p = bytes(8)
                            parts = listOf(p)
                            record = Record.BeginStep(le(p).getLong())
                        }
                        2 -> {
                            val p = bytes(4 + 8 + 1 + 16 + 20)
                            val b = le(p)
                            val iso = b.getInt()
                            val exposure = b.getLong()
                            val hasBlack = b.get().toInt() != 0
                            val bl = FloatArray(4) { b.getFloat() }
                            val w = b.getInt()
                            val hh = b.getInt()
                            val rs = b.getInt()
                            val ps = b.getInt()
                            val n = b.getInt()
                            val data = bytes(n)
                            parts = listOf(p, data)
                            record = Record.Frame(iso, exposure, if (hasBlack) bl else null, w, hh, rs, ps, data)
                        }
                        3 -> {
                            val p = bytes(4 + 64)
                            val b = le(p)
                            val iso = b.getInt()
                            parts = listOf(p)
                            record = Record.NoiseProfile(iso, DoubleArray(8) { b.getDouble() })
                        }
                        4 -> {
                            parts = emptyList()
                            record = Record.BeginDark
                        }
                        255 -> {
                            val p = bytes(8)
                            parts = listOf(p)
                            record = Record.End(le(p).getLong())
                            ended = true
                        }
                        else -> throw IllegalStateException("$file: record ${records.size} has unknown tag $tag")
                    }
                    val stored = try {
                        le(bytes(4)).getInt()
                    } catch (e: EOFException) {
                        throw IllegalStateException("$file: cut short inside record ${records.size}", e)
                    }
                    check(stored == crc(tagBytes, *parts.toTypedArray())) { "$file: record ${records.size} checksum mismatch" }
                    records.add(record)
                }
                return Recording(header, records, ended)
            }
        }
    }
}
