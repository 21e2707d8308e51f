package org.noisecal.capture.controller

import java.io.File
import java.util.concurrent.CopyOnWriteArrayList
import java.util.concurrent.LinkedBlockingQueue
import java.util.concurrent.TimeUnit
import kotlin.math.abs
import org.noisecal.capture.plan.Burst
import org.noisecal.capture.plan.BurstRole
import org.noisecal.capture.plan.CapturePlan

/**
 * Tuning of the controller. The defaults suit a phone; tests shorten the timeouts.
 *
 * @property maxInFlight requests allowed between submit and image close; null = `maxImages − 3`
 *   (so in-flight stays below `maxImages − 2`, leaving the reader room for late or orphan images).
 * @property isoTolerance relative difference allowed between reported and planned ISO.
 * @property exposureTolerance relative difference allowed between reported and planned exposure…
 * @property exposureToleranceNs …or this absolute one, whichever is larger (line-time rounding).
 * @property blackLevelToleranceDn allowed |dynamic − static| black level; null = max(2, white/256).
 * @property maxRetakes rejected + lost frames allowed per burst before it fails; null = frames + 20.
 * @property frameTimeoutMs how long a request may stay unanswered beyond its own frame time.
 * @property pauseAt thermal level at which capturing pauses; [resumeAt] the level at which it goes on.
 * @property thermalPollMs sleep between thermal polls while paused.
 * @property thermalCheckIntervalMs how often the thermal status is read while capturing.
 * @property coverageEveryFrames accepted frames between coverage refreshes (each reads the sink's progress).
 */
data class ControllerConfig(
    val maxInFlight: Int? = null,
    val isoTolerance: Double = 0.01,
    val exposureTolerance: Double = 0.02,
    val exposureToleranceNs: Long = 20_000L,
    val blackLevelToleranceDn: Float? = null,
    val maxRetakes: Int? = null,
    val frameTimeoutMs: Long = 2_000L,
    val pauseAt: ThermalLevel = ThermalLevel.SEVERE,
    val resumeAt: ThermalLevel = ThermalLevel.MODERATE,
    val thermalPollMs: Long = 10_000L,
    val thermalCheckIntervalMs: Long = 1_000L,
    val focusDistanceDiopters: Float? = null,
    val coverageEveryFrames: Int = 10,
)

/** What an earlier, unfinished run left in a [SessionStore], for a "resume?" prompt. */
data class ResumeInfo(val completedBursts: Int, val totalBursts: Int, val samePlan: Boolean, val finished: Boolean)

/**
 * Drives a [CapturePlan] through a [CameraDevicePort] into a [FrameSink].
 *
 * Per burst it submits manual requests (never more than [ControllerConfig.maxInFlight] unclosed),
 * matches each image with its result by timestamp, checks the reported ISO, exposure and black
 * level against the plan (rejecting and re-taking frames that differ, as the first frames after a
 * settings change do), pushes accepted frames into the sink, closes every image, and checkpoints
 * after the burst. A later controller on the same [SessionStore] and plan resumes after the last
 * completed burst (the OS may kill the app at any moment; a partial burst is taken again). The
 * thermal status is watched, and capturing pauses at [ControllerConfig.pauseAt].
 *
 * The optional dark step ([CapturePlan.darkBursts]) comes last. Before it the controller publishes
 * [CapturePhase.AWAITING_LENS_COVER] with a [CoverLensRequest] and waits for [confirmLensCovered]
 * (then [FrameSink.beginDark] and the dark bursts, through the same sink) or [skipDarkFrames] (the
 * session finishes without them). A dark frame the sink refuses as not dark
 * ([LensNotCoveredException]) rolls the session back to the checkpoint before the interrupted burst
 * (so no lit frame and no partial burst stays in it) and asks again, saying what was wrong.
 *
 * One controller serves one [run]. [run] blocks, so call it off the main thread (the app runs it
 * in a coroutine on `Dispatchers.IO`; this library itself has no coroutine dependency).
 * [requestStop] may be called from any thread.
 */
class CaptureController(
    private val plan: CapturePlan,
    private val port: CameraDevicePort,
    private val sinkFactory: FrameSinkFactory,
    private val store: SessionStore,
    private val thermal: ThermalStatusSource = ThermalStatusSource.NONE,
    private val config: ControllerConfig = ControllerConfig(),
    private val clock: Clock = Clock.SYSTEM,
) {
    private sealed class Event {
        class Image(val image: ImageHandle) : Event()
        class Result(val result: FrameResult) : Event()
        class Failure(val tag: Long, val reason: String, val imageCaptured: Boolean) : Event()
        class DeviceError(val message: String) : Event()
    }

    private class HeldImage(val image: ImageHandle, val sinceNs: Long)
    private class Pending(val submittedNs: Long)
    private class StopRequested : RuntimeException("stop requested")
    private class CaptureFailure(message: String) : RuntimeException(message)
    private class DarkRefused(val reason: String) : RuntimeException(reason)

    private val events = LinkedBlockingQueue<Event>()
    private val listeners = CopyOnWriteArrayList<ProgressListener>()
    private val pending = LinkedHashMap<Long, Pending>()
    private val results = HashMap<Long, FrameResult>() // by timestamp, only for pending tags
    private val images = HashMap<Long, HeldImage>() // by timestamp
    private var nextTag = 1L
    private var started = false
    @Volatile private var stopRequested = false
    @Volatile private var current = CaptureProgress.start(plan)
    /** The user's answers to the cover-the-lens prompt: true covered, false skip. */
    private val lensAnswers = LinkedBlockingQueue<Boolean>()
    /** The sink of this run: replaced when the dark step is rolled back to a checkpoint. */
    private var sink: FrameSink? = null

    val maxInFlight: Int = (config.maxInFlight ?: (port.maxImages - 3)).coerceAtLeast(1)
    private val blackTolerance: Float = config.blackLevelToleranceDn ?: maxOf(2f, plan.sensor.whiteLevel / 256f)

    // Run statistics (for the UI and the time estimate).
    private var runStartNs = 0L
    private var plannedDoneNs = 0L
    private var lastThermalCheckNs = Long.MIN_VALUE
    private var thermalLevel = ThermalLevel.NONE
    /** Set at [ControllerConfig.pauseAt], cleared at [ControllerConfig.resumeAt] (hysteresis). */
    private var cooling = false

    /** The latest progress. */
    val state: CaptureProgress get() = current

    /** Adds [l] and hands it the current progress at once; later ones arrive on the thread that calls [run]. */
    fun addListener(l: ProgressListener) { listeners += l; l.onProgress(current) }
    fun removeListener(l: ProgressListener) { listeners -= l }

    /** Asks [run] to stop at the next event; the session resumes later from its last completed burst. */
    fun requestStop() { stopRequested = true }

    /**
     * The user covered the lens: the dark step starts. Any thread; only an answer given while the
     * controller waits ([CapturePhase.AWAITING_LENS_COVER]) or just before counts.
     */
    fun confirmLensCovered() { lensAnswers.put(true) }

    /** The user skips the dark step at the prompt: the session finishes without dark frames. Any thread. */
    fun skipDarkFrames() { lensAnswers.put(false) }

    private val eventSink = object : CameraEventSink {
        override fun onImage(image: ImageHandle) { events.put(Event.Image(image)) }
        override fun onResult(result: FrameResult) { events.put(Event.Result(result)) }
        override fun onFailure(tag: Long, reason: String, imageCaptured: Boolean) { events.put(Event.Failure(tag, reason, imageCaptured)) }
        override fun onDeviceError(message: String) { events.put(Event.DeviceError(message)) }
    }

    /** Runs (or resumes) the whole plan. Blocks until it is done, stopped or failed. */
    fun run(): CaptureOutcome {
        check(!started) { "a CaptureController runs once; make a new one to resume" }
        started = true
        runStartNs = clock.nanoTime()
        val fingerprint = plan.fingerprint

        val record = store.load()
        if (record != null && record.planFingerprint == fingerprint && record.finished && store.packFile.isFile) {
            val summary = record.summary ?: "finished earlier"
            update { it.copy(phase = CapturePhase.DONE, burstsDone = plan.bursts.size, framesDone = plan.totalFrames,
                packPath = store.packFile.path, summary = summary) }
            return CaptureOutcome.Finished(store.packFile.path, summary)
        }
        val completed = sortedSetOf<Int>()
        try {
            val ckpt = record?.checkpointName?.let { store.checkpointFile(it) }
            if (record != null && record.planFingerprint == fingerprint && ckpt != null && ckpt.isFile) {
                sink = sinkFactory.restore(ckpt.path)
                completed += record.completedBursts.filter { it in plan.bursts.indices }
                update { it.copy(resumedFromBurst = completed.size, message = "Resumed after ${completed.size} of ${plan.bursts.size} bursts") }
            } else {
                if (record != null) update { it.copy(message = "An earlier session for another plan was discarded") }
                store.reset()
                sink = sinkFactory.create(plan.sensor)
            }
        } catch (e: Exception) {
            return fail("cannot open the calibration session: ${e.message}", resumable = false)
        } catch (e: LinkageError) {
            // The native library is missing or does not match (UnsatisfiedLinkError, ExceptionInInitializerError).
            return fail("cannot load the calibration core: ${e.message}", resumable = false)
        }

        val doneFrames = plan.bursts.filter { it.index in completed }.sumOf { it.frames }
        update { it.copy(phase = CapturePhase.RUNNING, burstsDone = completed.size, framesDone = doneFrames) }
        try {
            try {
                port.start(eventSink)
                refreshCoverage(sink())
                for (b in plan.bursts) {
                    if (b.index in completed || b.role == BurstRole.DARK) continue
                    if (stopRequested) throw StopRequested()
                    if (b.role == BurstRole.REFERENCE) sink().beginStep(b.exposureNs)
                    captureAndCheckpoint(b, completed)
                }
                darkStep(completed)
                update { it.copy(phase = CapturePhase.FINISHING, currentBurst = null, message = "Building the model pack") }
                store.ensureDir()
                val summary = sink().finish(store.packFile.path)
                store.save(ProgressRecord(fingerprint, completed.toSet(), store.checkpointName(completed.size), finished = true, summary = summary))
                update { it.copy(phase = CapturePhase.DONE, remainingMs = 0, packPath = store.packFile.path, summary = summary, message = summary) }
                return CaptureOutcome.Finished(store.packFile.path, summary, current.burstMotion)
            } catch (e: StopRequested) {
                update { it.copy(phase = CapturePhase.STOPPED, message = "Stopped after ${completed.size} of ${plan.bursts.size} bursts") }
                return CaptureOutcome.Stopped(completed.size)
            } catch (e: CaptureFailure) {
                return fail(e.message ?: "capture failed", resumable = true)
            } catch (e: Exception) {
                return fail("${e.javaClass.simpleName}: ${e.message}", resumable = true)
            } finally {
                try { port.stop() } catch (_: Exception) { }
                closeAllHeld()
            }
        } finally {
            sink?.close()
        }
    }

    private fun sink(): FrameSink = checkNotNull(sink) { "no open sink" }

    /** Captures [b] into the sink, then checkpoints and records it as completed. */
    private fun captureAndCheckpoint(b: Burst, completed: MutableSet<Int>) {
        val burstStart = clock.nanoTime()
        val sink = sink()
        captureBurst(b, sink)
        completed += b.index
        val name = store.checkpointName(completed.size)
        sink.checkpoint(store.checkpointFile(name).path)
        store.save(ProgressRecord(plan.fingerprint, completed.toSet(), name))
        store.pruneCheckpoints(name)
        plannedDoneNs += plan.burstDurationNs(b)
        refreshCoverage(sink)
        update { s -> s.copy(burstsDone = completed.size, remainingMs = remainingMs(completed, null, 0),
            message = "Burst ${b.index + 1} done in ${(clock.nanoTime() - burstStart) / 1_000_000} ms") }
    }

    /**
     * The dark step's bursts not yet completed: the prompt, then [FrameSink.beginDark] and the
     * bursts; again from the prompt after a frame that is not dark; nothing once the user skips.
     */
    private fun darkStep(completed: MutableSet<Int>) {
        var notCovered: String? = null
        while (true) {
            val left = plan.darkBursts.filter { it.index !in completed }
            if (left.isEmpty()) return
            if (stopRequested) throw StopRequested()
            if (!awaitLensCover(left, notCovered)) {
                update { it.copy(phase = CapturePhase.RUNNING, burstCount = it.burstCount - left.size,
                    framesTotal = it.framesTotal - left.sumOf { b -> b.frames }, darkSkipped = true,
                    message = "Dark frames skipped: the pack has no fixed-pattern component") }
                return
            }
            try {
                sink().beginDark()
                for (b in left) {
                    if (stopRequested) throw StopRequested()
                    captureAndCheckpoint(b, completed)
                }
                return
            } catch (e: DarkRefused) {
                notCovered = e.reason
                rollBack(completed)
            }
        }
    }

    /** Waits for the user's answer to the cover-the-lens prompt: true covered, false skip. */
    private fun awaitLensCover(left: List<Burst>, notCovered: String?): Boolean {
        lensAnswers.clear()
        val request = CoverLensRequest(left.map { it.iso }, left.sumOf { it.frames },
            left.sumOf { plan.burstDurationNs(it) } / 1_000_000, notCovered)
        update { it.copy(phase = CapturePhase.AWAITING_LENS_COVER, currentBurst = null, coverLens = request,
            message = if (notCovered == null) "Cover the lens for the dark frames, or skip them"
            else "Light reached the sensor during the dark frames: cover the lens fully and take them again") }
        while (true) {
            if (stopRequested) throw StopRequested()
            val covered = lensAnswers.poll(LENS_POLL_MS, TimeUnit.MILLISECONDS) ?: continue
            update { it.copy(phase = CapturePhase.RUNNING, coverLens = null,
                message = if (covered) "Lens covered: taking the dark frames" else it.message) }
            return covered
        }
    }

    /**
     * After a dark frame with light in it: back to the checkpoint of the last completed burst
     * (the interrupted burst's accepted frames, and a recording's, go with it).
     */
    private fun rollBack(completed: Set<Int>) {
        closeAllHeld()
        val name = store.load()?.checkpointName
        val file = name?.let { store.checkpointFile(it) }
        if (file == null || !file.isFile) throw CaptureFailure("cannot take the dark step again: the last checkpoint is missing")
        sink?.close()
        sink = null
        sink = sinkFactory.restore(file.path)
        update { it.copy(currentBurst = null, burstFramesAccepted = 0,
            framesDone = plan.bursts.filter { b -> b.index in completed }.sumOf { b -> b.frames }) }
    }

    private fun fail(reason: String, resumable: Boolean): CaptureOutcome.Failed {
        update { it.copy(phase = CapturePhase.FAILED, message = reason) }
        return CaptureOutcome.Failed(reason, resumable)
    }

    /** Captures [b] until its frames are accepted; throws [CaptureFailure] past the retake budget. */
    private fun captureBurst(b: Burst, sink: FrameSink) {
        val settings = ManualSettings.forBurst(b, config.focusDistanceDiopters)
        val maxRetakes = config.maxRetakes ?: (b.frames + 20)
        val timeoutNs = config.frameTimeoutMs * 1_000_000L + b.frameDurationNs * (maxInFlight + 2)
        val pollMs = (config.frameTimeoutMs / 4).coerceIn(2L, 100L)
        // Requests of earlier bursts that never answered cannot count here.
        pending.clear(); results.clear()
        var accepted = 0
        var retakes = 0
        var lastReason: String? = null
        update { it.copy(currentBurst = b, burstFramesAccepted = 0, burstFramesWanted = b.frames, phase = CapturePhase.RUNNING) }
        checkThermal(force = true)

        while (accepted < b.frames) {
            if (stopRequested) throw StopRequested()
            checkThermal(force = false)
            val hot = cooling
            if (hot && pending.isEmpty()) {
                pauseWhileHot()
                continue
            }
            if (!hot) {
                val room = minOf(maxInFlight - inFlight(), b.frames - accepted - pending.size)
                if (room > 0) {
                    val now = System.nanoTime()
                    val reqs = List(room) { FrameRequest(nextTag++, settings) }
                    for (r in reqs) pending[r.tag] = Pending(now)
                    port.submit(reqs)
                }
            }
            // Handle everything already queued before expiring requests: a frame whose image and
            // result have arrived must not be given up because only one event was read.
            var next: Event? = events.poll(pollMs, TimeUnit.MILLISECONDS)
            while (next != null) {
                val ev: Event = next
                when (ev) {
                    is Event.Image -> {
                        val old = images.put(ev.image.timestampNs, HeldImage(ev.image, System.nanoTime()))
                        old?.image?.close()
                        val r = results[ev.image.timestampNs]
                        if (r != null) {
                            when (val verdict = consume(b, r, sink)) {
                                null -> accepted++
                                else -> { retakes++; lastReason = verdict }
                            }
                        }
                    }
                    is Event.Result -> {
                        val r = ev.result
                        if (pending.containsKey(r.tag)) {
                            results[r.timestampNs] = r
                            if (images.containsKey(r.timestampNs)) {
                                when (val verdict = consume(b, r, sink)) {
                                    null -> accepted++
                                    else -> { retakes++; lastReason = verdict }
                                }
                            }
                        } else {
                            // A late answer to a request already given up: free its image now.
                            images.remove(r.timestampNs)?.image?.close()
                        }
                    }
                    is Event.Failure -> {
                        if (pending.remove(ev.tag) != null) {
                            retakes++; lastReason = "capture failed: ${ev.reason}"
                            update { it.copy(framesLost = it.framesLost + 1, lastRejection = lastReason) }
                        }
                    }
                    is Event.DeviceError -> throw CaptureFailure("camera error: ${ev.message}")
                }
                next = if (accepted < b.frames) events.poll() else null
            }
            retakes += expire(timeoutNs)
            if (retakes > maxRetakes) {
                throw CaptureFailure("$b: $retakes frames rejected or lost (limit $maxRetakes); last: ${lastReason ?: "frames did not arrive"}")
            }
        }
    }

    /** Checks, pushes and closes the image at [r]'s timestamp; returns null when accepted, else why not. */
    private fun consume(b: Burst, r: FrameResult, sink: FrameSink): String? {
        val held = images.remove(r.timestampNs) ?: return "no image"
        results.remove(r.timestampNs)
        pending.remove(r.tag)
        val img = held.image
        try {
            val reason = verify(b, r, img)
            if (reason != null) {
                update { it.copy(framesRejected = it.framesRejected + 1, lastRejection = reason) }
                return reason
            }
            val pushed = try {
                sink.pushFrame(RawFrame(img.buffer, img.width, img.height, img.rowStride, img.pixelStride, r.iso, r.exposureNs, r.dynamicBlackLevels))
            } catch (e: FrameMovedException) {
                val why = "moved: ${e.message}"
                update { s -> s.copy(framesRejected = s.framesRejected + 1, lastRejection = why,
                    burstMotion = tallied(s.burstMotion, b) { it.copy(framesRefused = it.framesRefused + 1) }) }
                return why
            } catch (e: LensNotCoveredException) {
                val why = "not dark: ${e.message}"
                update { it.copy(framesRejected = it.framesRejected + 1, lastRejection = why) }
                if (b.role == BurstRole.DARK) throw DarkRefused(e.message ?: "the frame is not dark: cover the lens")
                return why
            } catch (e: RuntimeException) {
                val why = "the session refused the frame: ${e.message}"
                update { it.copy(framesRejected = it.framesRejected + 1, lastRejection = why) }
                return why
            }
            val motion = pushed.motion
            update { s ->
                s.copy(burstFramesAccepted = s.burstFramesAccepted + 1, framesDone = s.framesDone + 1,
                    framesDriftNormalised = s.framesDriftNormalised + if (pushed.driftNormalised) 1 else 0,
                    elapsedMs = (clock.nanoTime() - runStartNs) / 1_000_000,
                    burstMotion = if (motion == null) s.burstMotion else tallied(s.burstMotion, b) { it.with(motion) })
            }
            if (current.burstFramesAccepted % config.coverageEveryFrames.coerceAtLeast(1) == 0) refreshCoverage(sink)
            return null
        } finally {
            img.close()
        }
    }

    /**
     * [list] with [b]'s motion verdict changed by [f]: the last entry when it is [b]'s (its
     * frames arrive together), else a new one. A burst taken again after a rollback starts anew.
     */
    private fun tallied(list: List<BurstMotion>, b: Burst, f: (BurstMotion) -> BurstMotion): List<BurstMotion> {
        val last = list.lastOrNull()
        return if (last != null && last.burst.index == b.index) list.dropLast(1) + f(last) else list + f(BurstMotion(b))
    }

    /** Why a frame does not match [b], or null when it does. */
    internal fun verify(b: Burst, r: FrameResult, img: ImageHandle): String? {
        if (abs(r.iso - b.iso) > b.iso * config.isoTolerance) return "ISO ${r.iso} reported, ${b.iso} planned"
        val expSlack = maxOf((b.exposureNs * config.exposureTolerance).toLong(), config.exposureToleranceNs)
        if (abs(r.exposureNs - b.exposureNs) > expSlack) return "exposure ${r.exposureNs} ns reported, ${b.exposureNs} ns planned"
        val dyn = r.dynamicBlackLevels
        if (dyn != null) {
            if (dyn.size != 4) return "${dyn.size} dynamic black levels reported, 4 expected"
            for (i in 0 until 4) {
                val planned = plan.sensor.blackLevels[i]
                if (!dyn[i].isFinite() || abs(dyn[i] - planned) > blackTolerance) {
                    return "black level ${dyn[i]} reported at CFA position $i, $planned expected (± $blackTolerance)"
                }
            }
        }
        if (img.width != plan.sensor.width || img.height != plan.sensor.height) {
            return "image is ${img.width}×${img.height}, the sensor is ${plan.sensor.width}×${plan.sensor.height}"
        }
        return null
    }

    /** Requests that went unanswered too long, and images whose result never came: lost frames. */
    private fun expire(timeoutNs: Long): Int {
        val now = System.nanoTime()
        var lost = 0
        val it = pending.entries.iterator()
        while (it.hasNext()) {
            val (tag, p) = it.next()
            if (now - p.submittedNs > timeoutNs) {
                it.remove(); lost++
                results.entries.removeIf { e -> e.value.tag == tag }
            }
        }
        val stale = images.entries.filter { now - it.value.sinceNs > timeoutNs }
        for (e in stale) { images.remove(e.key); e.value.image.close() }
        if (lost > 0) update { it.copy(framesLost = it.framesLost + lost, lastRejection = "$lost frame(s) never arrived") }
        return lost
    }

    /** Requests whose image may still occupy the reader, plus images we hold that no pending request explains. */
    private fun inFlight(): Int {
        val awaitingResult = pending.size - results.size
        return pending.size + maxOf(0, images.size - awaitingResult)
    }

    private fun checkThermal(force: Boolean) {
        val now = System.nanoTime()
        if (!force && now - lastThermalCheckNs < config.thermalCheckIntervalMs * 1_000_000L) return
        lastThermalCheckNs = now
        val level = try { thermal.current() } catch (e: Exception) { ThermalLevel.NONE }
        if (level >= config.pauseAt) cooling = true else if (level <= config.resumeAt) cooling = false
        if (level != thermalLevel) {
            thermalLevel = level
            update { it.copy(thermal = level) }
        }
    }

    private fun pauseWhileHot() {
        closeAllHeld()
        update { it.copy(phase = CapturePhase.PAUSED_THERMAL, message = "Paused: the phone is hot (${thermalLevel.name.lowercase()}); waiting to cool") }
        while (cooling) {
            if (stopRequested) throw StopRequested()
            clock.sleepMs(config.thermalPollMs)
            checkThermal(force = true)
            update { it.copy(elapsedMs = (clock.nanoTime() - runStartNs) / 1_000_000) }
        }
        update { it.copy(phase = CapturePhase.RUNNING, message = "Cooled down (${thermalLevel.name.lowercase()}); capturing again") }
    }

    private fun closeAllHeld() {
        for (h in images.values) try { h.image.close() } catch (_: Exception) { }
        images.clear(); results.clear()
        // Images still on their way are closed as they arrive (they no longer match a pending request).
        while (true) {
            val ev = events.poll() ?: break
            if (ev is Event.Image) try { ev.image.close() } catch (_: Exception) { }
        }
        pending.clear()
    }

    private fun refreshCoverage(sink: FrameSink) {
        val p = try { sink.progress() } catch (e: RuntimeException) { return }
        update { it.copy(coverage = p.isos) }
    }

    /** Plan estimate of what is left, scaled by how fast finished bursts went in this run. */
    private fun remainingMs(completed: Set<Int>, currentBurst: Burst?, currentAccepted: Int): Long {
        var left = 0L
        for (b in plan.bursts) if (b.index !in completed && b != currentBurst) left += plan.burstDurationNs(b)
        if (currentBurst != null) left += (currentBurst.frames - currentAccepted).coerceAtLeast(0) * currentBurst.frameDurationNs
        val elapsed = clock.nanoTime() - runStartNs
        val speed = if (plannedDoneNs > 0) (elapsed.toDouble() / plannedDoneNs).coerceIn(0.5, 5.0) else 1.0
        return (left * speed / 1e6).toLong()
    }

    private fun update(f: (CaptureProgress) -> CaptureProgress) {
        val s0 = f(current)
        val b = s0.currentBurst
        val s = if (b != null && s0.phase == CapturePhase.RUNNING) {
            val done = plan.bursts.filter { it.index < b.index }.map { it.index }.toSet()
            s0.copy(elapsedMs = (clock.nanoTime() - runStartNs) / 1_000_000, remainingMs = remainingMs(done, b, s0.burstFramesAccepted))
        } else s0
        current = s
        for (l in listeners) l.onProgress(s)
    }

    companion object {
        /** How often the cover-the-lens wait looks at [requestStop]. */
        private const val LENS_POLL_MS = 50L

        /** What an earlier run left in [store] for [plan] (null when nothing). */
        fun resumeInfo(store: SessionStore, plan: CapturePlan): ResumeInfo? {
            val r = store.load() ?: return null
            val same = r.planFingerprint == plan.fingerprint
            val ckptOk = r.checkpointName?.let { File(store.dir, it).isFile } ?: false
            return ResumeInfo(if (same && ckptOk) r.completedBursts.size else 0, plan.bursts.size, same, same && r.finished)
        }
    }
}
