package org.noisecal.app.ui

import android.net.Uri
import android.view.Surface
import androidx.lifecycle.ViewModel
import androidx.lifecycle.ViewModelProvider
import androidx.lifecycle.ViewModelProvider.AndroidViewModelFactory.Companion.APPLICATION_KEY
import androidx.lifecycle.viewModelScope
import androidx.lifecycle.viewmodel.initializer
import androidx.lifecycle.viewmodel.viewModelFactory
import java.io.File
import kotlinx.coroutines.CancellationException
import kotlinx.coroutines.CoroutineDispatcher
import kotlinx.coroutines.Dispatchers
import kotlinx.coroutines.Job
import kotlinx.coroutines.delay
import kotlinx.coroutines.flow.MutableStateFlow
import kotlinx.coroutines.flow.StateFlow
import kotlinx.coroutines.flow.asStateFlow
import kotlinx.coroutines.flow.getAndUpdate
import kotlinx.coroutines.flow.update
import kotlinx.coroutines.isActive
import kotlinx.coroutines.launch
import kotlinx.coroutines.withContext
import org.noisecal.app.camera.AndroidThermalSource
import org.noisecal.app.camera.Camera2Port
import org.noisecal.app.camera.CameraAccess
import org.noisecal.app.data.PackDocuments
import org.noisecal.capture.controller.CalibrationWorkflow
import org.noisecal.capture.controller.CaptureRun
import org.noisecal.capture.controller.CaptureStart
import org.noisecal.capture.controller.ControllerConfig
import org.noisecal.capture.controller.PlanForm
import org.noisecal.capture.controller.SessionRepository
import org.noisecal.capture.controller.ThermalStatusSource
import org.noisecal.capture.controller.UiEvent
import org.noisecal.capture.controller.UiState
import org.noisecal.capture.controller.UiStateMachine
import org.noisecal.capture.sink.NoisecalSinkFactory

/**
 * The screen's state holder: a plain [ViewModel] (no Context, no Application) that exposes one
 * sealed [UiState] and takes the user's actions as method calls.
 *
 * The decisions are not made here. [UiStateMachine] turns every event into the next [UiState];
 * [CalibrationWorkflow] over the [SessionRepository] plans, readies the session folder, builds the
 * controller and exports the pack. Both live in `:capture` and are tested on the host
 * (tests/jvm/capture). What is left is the Android glue: [viewModelScope], the dispatchers (the
 * blocking workflow steps and the capture run on [io]), the Camera2 port and its preview surface.
 *
 * The capture runs in a coroutine that outlives configuration changes with this ViewModel; a
 * capture the OS killed with the process is offered for resumption on the next start, because the
 * session folder is in `filesDir`.
 */
class CaptureViewModel(
    private val workflow: CalibrationWorkflow,
    private val cameras: CameraAccess,
    private val thermal: ThermalStatusSource,
    private val documents: PackDocuments,
    private val io: CoroutineDispatcher = Dispatchers.IO,
) : ViewModel() {
    private val _uiState = MutableStateFlow<UiState>(UiState.NeedsPermission())
    val uiState: StateFlow<UiState> = _uiState.asStateFlow()

    // Touched on the main thread only.
    private var port: Camera2Port? = null
    private var portSurface: Surface? = null
    private var surface: Surface? = null
    private var meteringJob: Job? = null
    private var capturing = false
    private var run: CaptureRun? = null
    private var cleared = false

    /** Folds [event] into the state. Safe from any thread: the controller reports from its own. */
    private fun dispatch(event: UiEvent) = _uiState.update { UiStateMachine.reduce(it, event) }

    fun onPermission(granted: Boolean) {
        val before = _uiState.getAndUpdate { UiStateMachine.reduce(it, UiEvent.PermissionAnswered(granted)) }
        // Only the answer that moved NeedsPermission to LoadingCameras loads them (not a re-created activity's).
        if (!granted || before !is UiState.NeedsPermission) return
        viewModelScope.launch {
            dispatch(withContext(io) { workflow.camerasFound(cameras.readAll()) })
        }
    }

    /** The preview surface exists: open the camera on it, unless a capture holds the camera. */
    fun onPreviewSurface(s: Surface) {
        surface = s
        if (!capturing) openCamera()
    }

    /** The preview surface is gone (app in the background): release the camera unless a capture runs. */
    fun onPreviewSurfaceDestroyed() {
        surface = null
        if (!capturing) closeCamera()
    }

    fun updateForm(form: PlanForm) = dispatch(UiEvent.FormEdited(form))

    fun backToPreview() = dispatch(UiEvent.BackToPreview)

    /** Plans from the camera, the metering and the form. */
    fun makePlan() {
        val s = _uiState.value as? UiState.Preview ?: return
        viewModelScope.launch { dispatch(withContext(io) { workflow.makePlan(s.setup) }) }
    }

    /** Starts the capture of the plan on screen: resumes the earlier run of it unless [startOver]. */
    fun startCapture(startOver: Boolean = false) {
        val s = _uiState.value as? UiState.Planned ?: return
        if (capturing) return
        val p = port ?: return dispatch(UiEvent.Problem("The camera is not open yet"))
        capturing = true
        viewModelScope.launch {
            try {
                val config = ControllerConfig(focusDistanceDiopters = p.latestFocusDiopters)
                when (val start = withContext(io) { workflow.startCapture(s, startOver, p, thermal, config) }) {
                    is CaptureStart.Refused -> dispatch(start.problem)
                    is CaptureStart.Ready -> {
                        run = start.run
                        dispatch(start.run.started)
                        // Blocks an IO thread until the plan is done, stopped or failed; a cancelled
                        // scope (the ViewModel cleared) still waits here until onCleared's stop lands.
                        withContext(io) { start.run.run(::dispatch) }
                    }
                }
            } finally {
                run = null
                capturing = false
                afterCapture(p)
            }
        }
    }

    /** Asks the running capture to stop after the current frame; the session resumes later from its last burst. */
    fun stopCapture() {
        val r = run ?: return
        r.requestStop()
        dispatch(UiEvent.StopRequested)
    }

    /** At the cover-the-lens prompt: the lens is covered, the controller takes the dark frames. */
    fun confirmLensCovered() {
        if (_uiState.value !is UiState.CoverLens) return
        val r = run ?: return
        r.confirmLensCovered()
        dispatch(UiEvent.LensCovered)
    }

    /** At the cover-the-lens prompt: skip the dark step; the session finishes without it. */
    fun skipDarkFrames() {
        if (_uiState.value !is UiState.CoverLens) return
        val r = run ?: return
        r.skipDarkFrames()
        dispatch(UiEvent.DarkFramesSkipped)
    }

    /** Forgets the finished or abandoned session and goes back to the preview. */
    fun newCalibration() {
        if (capturing) return
        viewModelScope.launch { dispatch(withContext(io) { workflow.forget() }) }
    }

    /** Copies the pack to the document the user picked (`ACTION_CREATE_DOCUMENT`). */
    fun exportPack(uri: Uri) {
        viewModelScope.launch { dispatch(withContext(io) { workflow.exportPack { documents.openForWriting(uri) } }) }
    }

    private fun openCamera() {
        val s = surface ?: return
        if (port != null && portSurface === s) return
        closeCamera()
        val camera = (_uiState.value as? UiState.AtCamera)?.setup?.camera ?: return
        val p = cameras.port(camera) ?: return
        port = p
        portSurface = s
        viewModelScope.launch {
            try {
                p.open(s)
            } catch (e: CancellationException) {
                throw e
            } catch (e: Exception) {
                dispatch(UiEvent.Problem("Cannot open camera ${camera.id}: ${e.message}"))
                if (port === p) closeCamera()
                return@launch
            }
            if (port !== p) return@launch
            meteringJob?.cancel()
            meteringJob = launch {
                // The preview's auto-exposure; only the preview state takes it (the reducer ignores it elsewhere).
                while (isActive) {
                    p.latestMetering?.let { dispatch(UiEvent.Metered(it)) }
                    delay(250)
                }
            }
        }
    }

    private fun closeCamera() {
        meteringJob?.cancel()
        meteringJob = null
        port?.close()
        port = null
        portSurface = null
    }

    /** The capture let go of the camera: back to the preview on whatever surface there is now. */
    private fun afterCapture(p: Camera2Port) {
        when {
            cleared || surface == null -> closeCamera()
            surface !== portSurface || port !== p -> openCamera()
            else -> try {
                p.startPreview()
            } catch (e: Exception) {
                // The camera may be gone; the next surface reopens it.
            }
        }
    }

    override fun onCleared() {
        cleared = true
        run?.requestStop()
        // A running capture closes the camera itself once the controller has stopped (afterCapture).
        if (!capturing) closeCamera()
    }

    companion object {
        /** Builds the ViewModel's dependencies from the application (manual constructor injection). */
        val Factory: ViewModelProvider.Factory = viewModelFactory {
            initializer {
                val app = checkNotNull(this[APPLICATION_KEY]) { "no Application in the CreationExtras" }
                val repository = SessionRepository(File(app.filesDir, "session")) { recording -> NoisecalSinkFactory(recordingPath = recording) }
                CaptureViewModel(
                    workflow = CalibrationWorkflow(repository),
                    cameras = CameraAccess(app),
                    thermal = AndroidThermalSource(app),
                    documents = PackDocuments(app.contentResolver),
                )
            }
        }
    }
}
