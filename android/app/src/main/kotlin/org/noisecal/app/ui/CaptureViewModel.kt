package org.noisecal.app.ui

import android.app.Application
import android.content.Intent
import android.hardware.camera2.CameraManager
import android.net.Uri
import android.view.Surface
import androidx.core.content.FileProvider
import androidx.lifecycle.AndroidViewModel
import androidx.lifecycle.viewModelScope
import java.io.File
import java.io.IOException
import kotlin.concurrent.thread
import kotlinx.coroutines.Dispatchers
import kotlinx.coroutines.Job
import kotlinx.coroutines.delay
import kotlinx.coroutines.flow.MutableStateFlow
import kotlinx.coroutines.flow.StateFlow
import kotlinx.coroutines.flow.asStateFlow
import kotlinx.coroutines.flow.update
import kotlinx.coroutines.isActive
import kotlinx.coroutines.launch
import kotlinx.coroutines.withContext
import org.noisecal.app.camera.AndroidThermalSource
import org.noisecal.app.camera.Camera2Capabilities
import org.noisecal.app.camera.Camera2Port
import org.noisecal.app.camera.CameraCandidate
import org.noisecal.capture.controller.CaptureController
import org.noisecal.capture.controller.CaptureOutcome
import org.noisecal.capture.controller.CaptureUiState
import org.noisecal.capture.controller.ControllerConfig
import org.noisecal.capture.controller.ResumeInfo
import org.noisecal.capture.controller.SessionStore
import org.noisecal.capture.plan.CapturePlanner
import org.noisecal.capture.plan.Metering
import org.noisecal.capture.plan.PlanInputs
import org.noisecal.capture.plan.PlanOptions
import org.noisecal.capture.plan.PlanResult
import org.noisecal.capture.sink.NoisecalSinkFactory

/** The app's screens, in the order a calibration walks through them. */
enum class Step { PERMISSION, LOADING, UNSUPPORTED, PREVIEW, PLAN, CAPTURE, DONE }

/** The plan form as typed (strings, so half-typed numbers survive recomposition). */
data class PlanForm(
    val isos: String = "",
    val evMin: String = "-4",
    val evMax: String = "4",
    val frames: String = "100",
    val recording: Boolean = false,
)

/** Everything the UI shows. */
data class AppUiState(
    val step: Step = Step.PERMISSION,
    val candidates: List<CameraCandidate> = emptyList(),
    val camera: CameraCandidate? = null,
    val metering: Metering? = null,
    val form: PlanForm = PlanForm(),
    val plan: PlanResult? = null,
    val resume: ResumeInfo? = null,
    val capture: CaptureUiState = CaptureUiState(),
    val error: String? = null,
    val notice: String? = null,
)

/**
 * Holds the camera, the plan and the running capture across configuration changes. The capture
 * runs on its own thread ([CaptureController.run] blocks); its states arrive through a listener
 * and are folded into [state]. The session folder is in `filesDir`, so a capture the OS killed is
 * offered for resumption on the next start (same camera, same saved plan inputs).
 */
class CaptureViewModel(app: Application) : AndroidViewModel(app) {
    private val _state = MutableStateFlow(AppUiState())
    val state: StateFlow<AppUiState> = _state.asStateFlow()

    private val sessionDir = File(app.filesDir, "session")
    private val store = SessionStore(sessionDir)
    private val inputsFile = File(sessionDir, "plan-inputs.txt")
    private var port: Camera2Port? = null
    private var meteringJob: Job? = null
    private var controller: CaptureController? = null
    private var worker: Thread? = null

    fun onPermission(granted: Boolean) {
        if (!granted) {
            _state.update { it.copy(step = Step.PERMISSION, error = "noisecal needs the camera permission to calibrate the camera") }
            return
        }
        if (_state.value.step != Step.PERMISSION) return
        _state.update { it.copy(step = Step.LOADING, error = null) }
        viewModelScope.launch {
            val manager = getApplication<Application>().getSystemService(CameraManager::class.java)
            val candidates = withContext(Dispatchers.Default) { Camera2Capabilities.readAll(manager) }
            val saved = withContext(Dispatchers.IO) { PlanInputs.load(inputsFile) }
            val chosen = saved?.let { s -> candidates.firstOrNull { it.id == s.cameraId && it.supported } } ?: Camera2Capabilities.choose(candidates)
            _state.update { it.copy(step = if (chosen == null) Step.UNSUPPORTED else Step.PREVIEW, candidates = candidates, camera = chosen) }
            if (chosen != null && saved != null && saved.cameraId == chosen.id) offerResume(chosen, saved)
        }
    }

    /** An unfinished session from an earlier run (the OS may have killed the app): show its plan with "Resume". */
    private fun offerResume(camera: CameraCandidate, saved: PlanInputs) {
        val caps = camera.capabilities ?: return
        val result = CapturePlanner.plan(caps, saved.options)
        val plan = (result as? PlanResult.Ok)?.plan ?: return
        val info = CaptureController.resumeInfo(store, plan) ?: return
        if (!info.samePlan) return
        _state.update {
            it.copy(step = if (info.finished) Step.DONE else Step.PLAN, plan = result, resume = info, metering = saved.options.metering,
                notice = if (info.finished) "The last calibration is finished" else "An unfinished calibration was found: ${info.completedBursts} of ${info.totalBursts} bursts done")
        }
    }

    /** The preview surface exists: open the camera on it and start metering. */
    fun onPreviewSurface(surface: Surface) {
        val cam = _state.value.camera ?: return
        val raw = cam.rawSize ?: return
        if (port != null) return
        val p = Camera2Port(getApplication(), cam.id, raw)
        port = p
        viewModelScope.launch {
            try {
                p.open(surface)
            } catch (e: Exception) {
                _state.update { it.copy(error = "Cannot open camera ${cam.id}: ${e.message}") }
                p.close()
                if (port === p) port = null
                return@launch
            }
            meteringJob?.cancel()
            meteringJob = launch {
                while (isActive) {
                    val m = p.latestMetering
                    if (m != null && _state.value.step == Step.PREVIEW) _state.update { it.copy(metering = m) }
                    delay(250)
                }
            }
        }
    }

    /** The preview surface is gone (app in background): release the camera unless a capture runs. */
    fun onPreviewSurfaceDestroyed() {
        if (worker?.isAlive == true) return
        meteringJob?.cancel()
        port?.close()
        port = null
    }

    fun updateForm(form: PlanForm) = _state.update { it.copy(form = form) }

    fun backToPreview() = _state.update { it.copy(step = Step.PREVIEW, plan = null, resume = null, error = null, notice = null) }

    /** Builds the plan from the camera, the metering and the form. */
    fun makePlan() {
        val s = _state.value
        val caps = s.camera?.capabilities ?: return
        val metering = s.metering ?: run {
            _state.update { it.copy(error = "The exposure has not settled yet: point the camera at the chart and wait a moment") }
            return
        }
        val options = try {
            formToOptions(s.form, metering)
        } catch (e: IllegalArgumentException) {
            _state.update { it.copy(error = e.message) }
            return
        }
        val result = CapturePlanner.plan(caps, options)
        val resume = (result as? PlanResult.Ok)?.plan?.let { CaptureController.resumeInfo(store, it) }?.takeIf { it.samePlan && !it.finished }
        _state.update { it.copy(step = Step.PLAN, plan = result, resume = resume, error = null) }
    }

    /** Starts (or resumes) the capture of the current plan on a worker thread. */
    fun startCapture() {
        val s = _state.value
        val plan = (s.plan as? PlanResult.Ok)?.plan ?: return
        val p = port ?: run {
            _state.update { it.copy(error = "The camera is not open yet") }
            return
        }
        if (worker?.isAlive == true) return
        val resuming = s.resume?.samePlan == true && (s.resume.completedBursts > 0)
        if (!resuming) {
            try {
                store.reset()
                store.packFile.delete()
                PlanInputs(plan.capabilities.cameraId, plan.options).save(inputsFile)
            } catch (e: IOException) {
                _state.update { it.copy(error = "Cannot write the session folder: ${e.message}") }
                return
            }
        }
        meteringJob?.cancel()
        val recording = if (plan.options.recording) store.recordingFile.path else null
        val c = CaptureController(
            plan, p, NoisecalSinkFactory(recordingPath = recording), store, AndroidThermalSource(getApplication()),
            ControllerConfig(focusDistanceDiopters = p.latestFocusDiopters),
        )
        c.addListener { cs -> _state.update { it.copy(capture = cs) } }
        controller = c
        _state.update { it.copy(step = Step.CAPTURE, error = null, notice = null) }
        worker = thread(name = "noisecal-capture") {
            val outcome = c.run()
            _state.update {
                when (outcome) {
                    is CaptureOutcome.Finished -> it.copy(step = Step.DONE, notice = outcome.summary)
                    is CaptureOutcome.Stopped -> it.copy(step = Step.PLAN, resume = CaptureController.resumeInfo(store, plan),
                        notice = "Stopped after ${outcome.completedBursts} bursts; resume whenever you are ready")
                    is CaptureOutcome.Failed -> it.copy(step = Step.PLAN,
                        resume = if (outcome.resumable) CaptureController.resumeInfo(store, plan) else null, error = outcome.reason)
                }
            }
            try { p.startPreview() } catch (e: Exception) { /* the camera may be gone; the next surface reopens it */ }
        }
    }

    /** Discards the unfinished session of this plan and captures it from the start. */
    fun startOver() {
        if (worker?.isAlive == true) return
        _state.update { it.copy(resume = null) }
        startCapture()
    }

    fun stopCapture() {
        controller?.requestStop()
    }

    /** Forgets the finished or abandoned session and goes back to the preview. */
    fun newCalibration() {
        if (worker?.isAlive == true) return
        store.reset()
        store.packFile.delete()
        inputsFile.delete()
        _state.update { it.copy(step = Step.PREVIEW, plan = null, resume = null, capture = CaptureUiState(), notice = null, error = null) }
    }

    /** Copies the pack to a document the user picked with ACTION_CREATE_DOCUMENT. */
    fun exportTo(uri: Uri) {
        viewModelScope.launch {
            val message = withContext(Dispatchers.IO) {
                try {
                    val out = getApplication<Application>().contentResolver.openOutputStream(uri)
                        ?: throw IOException("the document provider returned no stream")
                    out.use { o -> store.packFile.inputStream().use { it.copyTo(o) } }
                    "Model pack saved"
                } catch (e: IOException) {
                    "Saving failed: ${e.message}"
                } catch (e: SecurityException) {
                    "Saving failed: ${e.message}"
                }
            }
            _state.update { it.copy(notice = message) }
        }
    }

    /** A share-sheet intent for the pack (through the FileProvider), or null when there is none. */
    fun shareIntent(): Intent? {
        val app = getApplication<Application>()
        val pack = store.packFile
        if (!pack.isFile) return null
        val uri = FileProvider.getUriForFile(app, "${app.packageName}.fileprovider", pack)
        val send = Intent(Intent.ACTION_SEND).apply {
            type = "application/octet-stream"
            putExtra(Intent.EXTRA_STREAM, uri)
            putExtra(Intent.EXTRA_SUBJECT, "noisecal model pack")
            _state.value.capture.summary?.let { putExtra(Intent.EXTRA_TEXT, it) }
            addFlags(Intent.FLAG_GRANT_READ_URI_PERMISSION)
        }
        return Intent.createChooser(send, "Share the noise model pack")
    }

    /** File name offered in the "save as" dialog. */
    fun suggestedPackName(): String {
        val c = _state.value.camera?.capabilities
        val model = (c?.model ?: "camera").replace(Regex("[^A-Za-z0-9._-]+"), "_")
        return "noisecal-$model-cam${c?.cameraId ?: "0"}.pack"
    }

    override fun onCleared() {
        controller?.requestStop()
        worker?.join(5_000)
        meteringJob?.cancel()
        port?.close()
        port = null
    }

    companion object {
        /** Parses the plan form; throws IllegalArgumentException naming the field that is wrong. */
        fun formToOptions(form: PlanForm, metering: Metering): PlanOptions {
            val isos = form.isos.split(',', ' ', ';').filter { it.isNotBlank() }.map {
                it.trim().toIntOrNull() ?: throw IllegalArgumentException("ISO list: \"$it\" is not a number (e.g. 200, 400, 800)")
            }
            val evMin = form.evMin.trim().toDoubleOrNull() ?: throw IllegalArgumentException("EV from: \"${form.evMin}\" is not a number (e.g. -4)")
            val evMax = form.evMax.trim().toDoubleOrNull() ?: throw IllegalArgumentException("EV to: \"${form.evMax}\" is not a number (e.g. 4)")
            val frames = form.frames.trim().toIntOrNull() ?: throw IllegalArgumentException("Frames per burst: \"${form.frames}\" is not a whole number (e.g. 100)")
            return PlanOptions(
                metering = metering,
                targetIsos = isos.ifEmpty { null },
                evMin = evMin,
                evMax = evMax,
                framesPerBurst = frames,
                recording = form.recording,
            )
        }
    }
}
