package org.noisecal.capture.controller

/** `PowerManager.THERMAL_STATUS_*`, in the same order and with the same codes. */
enum class ThermalLevel(val code: Int) {
    NONE(0), LIGHT(1), MODERATE(2), SEVERE(3), CRITICAL(4), EMERGENCY(5), SHUTDOWN(6);

    companion object {
        fun fromCode(code: Int): ThermalLevel = entries.firstOrNull { it.code == code } ?: if (code > 6) SHUTDOWN else NONE
    }
}

/** Where the controller reads the phone's thermal status (PowerManager on Android, a script in tests). */
fun interface ThermalStatusSource {
    fun current(): ThermalLevel

    companion object {
        /** A source for devices that report nothing (API < 29). */
        val NONE = ThermalStatusSource { ThermalLevel.NONE }
    }
}

/** Time for the controller: elapsed time for the UI and sleeping while the phone cools. */
interface Clock {
    fun nanoTime(): Long
    fun sleepMs(ms: Long)

    companion object {
        val SYSTEM: Clock = object : Clock {
            override fun nanoTime(): Long = System.nanoTime()
            override fun sleepMs(ms: Long) = Thread.sleep(ms)
        }
    }
}
