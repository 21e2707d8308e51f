package org.noisecal.capture.controller

import java.io.File
import java.io.IOException
import java.nio.file.AtomicMoveNotSupportedException
import java.nio.file.Files
import java.nio.file.StandardCopyOption

/**
 * Which bursts of which plan are done, and the checkpoint that holds them. Written after each
 * burst's checkpoint, atomically, so the record never names bursts the checkpoint lacks.
 */
data class ProgressRecord(
    val planFingerprint: String,
    val completedBursts: Set<Int>,
    val checkpointName: String?,
    val finished: Boolean = false,
    val summary: String? = null,
) {
    fun encode(): String = buildString {
        append("format=noisecal-progress-1\n")
        append("plan=$planFingerprint\n")
        append("completed=${completedBursts.sorted().joinToString(",")}\n")
        append("checkpoint=${checkpointName ?: ""}\n")
        append("finished=$finished\n")
        // The summary is one line from the core; keep it on one line whatever it holds.
        append("summary=${summary?.replace('\n', ' ') ?: ""}\n")
    }

    companion object {
        /** Parses [encode]'s output; null (with no exception) for anything else, so a torn file means "start over". */
        fun decode(text: String): ProgressRecord? {
            val kv = text.lineSequence().filter { '=' in it }.associate { it.substringBefore('=') to it.substringAfter('=') }
            if (kv["format"] != "noisecal-progress-1") return null
            val plan = kv["plan"]?.takeIf { it.isNotEmpty() } ?: return null
            val completed = kv["completed"]?.split(',')?.filter { it.isNotBlank() }?.map { it.trim().toIntOrNull() ?: return null }?.toSet()
                ?: return null
            return ProgressRecord(
                plan, completed, kv["checkpoint"]?.takeIf { it.isNotEmpty() },
                kv["finished"] == "true", kv["summary"]?.takeIf { it.isNotEmpty() },
            )
        }
    }
}

/**
 * The session's folder: progress record, checkpoints (`checkpoint-NNNN.nck`, NNNN = bursts done),
 * the pack and the optional recording. On Android it lives in `filesDir`, so it survives the OS
 * killing the app.
 */
class SessionStore(val dir: File, val packName: String = "noise-model.pack") {
    val progressFile: File get() = File(dir, "progress.txt")
    val packFile: File get() = File(dir, packName)
    val recordingFile: File get() = File(dir, "session.rec")

    fun checkpointFile(name: String): File = File(dir, name)
    fun checkpointName(completedCount: Int): String = "checkpoint-%04d.nck".format(completedCount)

    fun load(): ProgressRecord? {
        val f = progressFile
        if (!f.isFile) return null
        return try { ProgressRecord.decode(f.readText()) } catch (e: IOException) { null }
    }

    fun save(record: ProgressRecord) {
        ensureDir()
        val tmp = File(dir, "progress.txt.tmp")
        tmp.writeText(record.encode())
        moveAtomically(tmp, progressFile)
    }

    /** Deletes checkpoints other than [keep] (after the record that names [keep] is safely written). */
    fun pruneCheckpoints(keep: String?) {
        dir.listFiles()?.filter { it.name.startsWith("checkpoint-") && it.name != keep }?.forEach { it.delete() }
    }

    /** Forgets any earlier session in this folder. */
    fun reset() {
        ensureDir()
        dir.listFiles()?.filter { it.name.startsWith("checkpoint-") || it.name.startsWith("progress.txt") }?.forEach { it.delete() }
    }

    fun ensureDir() {
        if (!dir.isDirectory && !dir.mkdirs()) throw IOException("cannot create the session folder $dir")
    }

    private fun moveAtomically(from: File, to: File) {
        try {
            Files.move(from.toPath(), to.toPath(), StandardCopyOption.ATOMIC_MOVE, StandardCopyOption.REPLACE_EXISTING)
        } catch (e: AtomicMoveNotSupportedException) {
            Files.move(from.toPath(), to.toPath(), StandardCopyOption.REPLACE_EXISTING)
        }
    }
}
