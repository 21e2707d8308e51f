package org.noisecal.capture.sweeptest

/**
 * A minimal JSON reader for `noisecal inspect --json`: objects become [Map], arrays [List], numbers
 * [Double] (or [Long] when integral), plus [String], [Boolean] and null. Throws [IllegalArgumentException]
 * naming the offset on malformed input.
 */
object Json {
    fun parse(text: String): Any? {
        val p = P(text)
        val v = p.value()
        p.ws()
        require(p.i == text.length) { "JSON: trailing text at offset ${p.i}" }
        return v
    }

    private class P(val s: String) {
        var i = 0

        fun ws() { while (i < s.length && s[i].isWhitespace()) i++ }

        fun expect(c: Char) {
            ws()
            require(i < s.length && s[i] == c) { "JSON: expected '$c' at offset $i" }
            i++
        }

        fun value(): Any? {
            ws()
            require(i < s.length) { "JSON: unexpected end" }
            return when (val c = s[i]) {
                '{' -> obj()
                '[' -> arr()
                '"' -> str()
                't' -> word("true", true)
                'f' -> word("false", false)
                'n' -> word("null", null)
                else -> if (c == '-' || c.isDigit()) num() else throw IllegalArgumentException("JSON: unexpected '$c' at offset $i")
            }
        }

        fun word(w: String, v: Any?): Any? {
            require(s.startsWith(w, i)) { "JSON: bad literal at offset $i" }
            i += w.length
            return v
        }

        fun num(): Any {
            val start = i
            while (i < s.length && (s[i].isDigit() || s[i] in "+-.eE")) i++
            val t = s.substring(start, i)
            return t.toLongOrNull() ?: t.toDoubleOrNull() ?: throw IllegalArgumentException("JSON: bad number '$t' at offset $start")
        }

        fun str(): String {
            expect('"')
            val b = StringBuilder()
            while (true) {
                require(i < s.length) { "JSON: unterminated string" }
                when (val c = s[i++]) {
                    '"' -> return b.toString()
                    '\\' -> {
                        val e = s[i++]
                        when (e) {
                            'n' -> b.append('\n'); 't' -> b.append('\t'); 'r' -> b.append('\r')
                            'b' -> b.append('\b'); 'f' -> b.append('\u000C')
                            'u' -> { b.append(s.substring(i, i + 4).toInt(16).toChar()); i += 4 }
                            else -> b.append(e)
                        }
                    }
                    else -> b.append(c)
                }
            }
        }

        fun arr(): List<Any?> {
            expect('[')
            val out = mutableListOf<Any?>()
            ws()
            if (s[i] == ']') { i++; return out }
            while (true) {
                out += value()
                ws()
                if (s[i] == ',') { i++; continue }
                expect(']')
                return out
            }
        }

        fun obj(): Map<String, Any?> {
            expect('{')
            val out = LinkedHashMap<String, Any?>()
            ws()
            if (s[i] == '}') { i++; return out }
            while (true) {
                ws()
                val k = str()
                expect(':')
                out[k] = value()
                ws()
                if (s[i] == ',') { i++; continue }
                expect('}')
                return out
            }
        }
    }
}
