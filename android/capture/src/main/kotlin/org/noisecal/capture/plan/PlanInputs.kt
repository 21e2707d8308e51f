package org.noisecal.capture.plan

import java.io.File
import java.io.IOException

/**
 * What a plan was made from (camera id and user choices, metering included), saved next to the
 * session when the capture starts. After the OS kills the app, the same inputs give the same plan
 * (same [CapturePlan.fingerprint]) even though the scene would now meter slightly differently, so
 * the session resumes instead of starting over.
 */
data class PlanInputs(val cameraId: String, val options: PlanOptions) {
    fun encode(): String = buildString {
        append("format=noisecal-plan-inputs-1\n")
        append("camera=$cameraId\n")
        append("meteringIso=${options.metering.iso}\n")
        append("meteringExposureNs=${options.metering.exposureNs}\n")
        append("targetIsos=${options.targetIsos?.joinToString(",") ?: "default"}\n")
        append("evMin=${options.evMin}\nevMax=${options.evMax}\nevIncrement=${options.evIncrement}\n")
        append("framesPerBurst=${options.framesPerBurst}\nreferenceFramesPerBurst=${options.referenceFramesPerBurst}\n")
        append("maxExposureNs=${options.maxExposureNs ?: "none"}\n")
        append("settleOverheadNs=${options.settleOverheadNs}\n")
        append("recording=${options.recording}\n")
        append("rowStrideBytes=${options.rowStrideBytes ?: "none"}\n")
        append("darkFrames=${options.darkFrames}\ndarkFramesPerIso=${options.darkFramesPerIso}\n")
    }

    fun save(file: File) {
        file.parentFile?.mkdirs()
        val tmp = File(file.path + ".tmp")
        tmp.writeText(encode())
        if (!tmp.renameTo(file)) { file.delete(); if (!tmp.renameTo(file)) throw IOException("cannot write $file") }
    }

    companion object {
        /** Parses [encode]'s output; null when the text is not a complete record. */
        fun decode(text: String): PlanInputs? {
            val kv = text.lineSequence().filter { '=' in it }.associate { it.substringBefore('=') to it.substringAfter('=') }
            if (kv["format"] != "noisecal-plan-inputs-1") return null
            return try {
                val isos = kv.getValue("targetIsos").let { if (it == "default") null else it.split(',').map(String::toInt) }
                PlanInputs(
                    kv.getValue("camera"),
                    PlanOptions(
                        metering = Metering(kv.getValue("meteringIso").toInt(), kv.getValue("meteringExposureNs").toLong()),
                        targetIsos = isos,
                        evMin = kv.getValue("evMin").toDouble(),
                        evMax = kv.getValue("evMax").toDouble(),
                        evIncrement = kv.getValue("evIncrement").toDouble(),
                        framesPerBurst = kv.getValue("framesPerBurst").toInt(),
                        referenceFramesPerBurst = kv.getValue("referenceFramesPerBurst").toInt(),
                        maxExposureNs = kv.getValue("maxExposureNs").let { if (it == "none") null else it.toLong() },
                        settleOverheadNs = kv.getValue("settleOverheadNs").toLong(),
                        recording = kv.getValue("recording").toBooleanStrict(),
                        rowStrideBytes = kv.getValue("rowStrideBytes").let { if (it == "none") null else it.toInt() },
                        // Absent in inputs saved before the dark step existed: a plan without it.
                        darkFrames = kv["darkFrames"]?.toBooleanStrict() ?: false,
                        darkFramesPerIso = kv["darkFramesPerIso"]?.toInt() ?: PlanOptions.DEFAULT_DARK_FRAMES_PER_ISO,
                    ),
                )
            } catch (e: NoSuchElementException) {
                null
            } catch (e: IllegalArgumentException) {
                null
            }
        }

        fun load(file: File): PlanInputs? = if (file.isFile) try { decode(file.readText()) } catch (e: IOException) { null } else null
    }
}
