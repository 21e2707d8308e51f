package org.noisecal.app.ui

import android.Manifest
import android.content.Context
import android.content.Intent
import android.content.pm.PackageManager
import android.view.SurfaceHolder
import android.view.SurfaceView
import androidx.activity.compose.rememberLauncherForActivityResult
import androidx.activity.result.contract.ActivityResultContracts
import androidx.compose.foundation.Canvas
import androidx.compose.foundation.layout.Arrangement
import androidx.compose.foundation.layout.Box
import androidx.compose.foundation.layout.Column
import androidx.compose.foundation.layout.Row
import androidx.compose.foundation.layout.Spacer
import androidx.compose.foundation.layout.aspectRatio
import androidx.compose.foundation.layout.fillMaxHeight
import androidx.compose.foundation.layout.fillMaxSize
import androidx.compose.foundation.layout.fillMaxWidth
import androidx.compose.foundation.layout.height
import androidx.compose.foundation.layout.padding
import androidx.compose.foundation.layout.safeDrawingPadding
import androidx.compose.foundation.layout.width
import androidx.compose.foundation.rememberScrollState
import androidx.compose.foundation.text.KeyboardOptions
import androidx.compose.foundation.verticalScroll
import androidx.compose.material3.Button
import androidx.compose.material3.Checkbox
import androidx.compose.material3.LinearProgressIndicator
import androidx.compose.material3.MaterialTheme
import androidx.compose.material3.OutlinedButton
import androidx.compose.material3.OutlinedTextField
import androidx.compose.material3.Surface
import androidx.compose.material3.Text
import androidx.compose.runtime.Composable
import androidx.compose.runtime.DisposableEffect
import androidx.compose.runtime.LaunchedEffect
import androidx.compose.runtime.getValue
import androidx.compose.ui.Alignment
import androidx.compose.ui.Modifier
import androidx.compose.ui.geometry.Offset
import androidx.compose.ui.geometry.Size
import androidx.compose.ui.graphics.Color
import androidx.compose.ui.graphics.drawscope.Stroke
import androidx.compose.ui.platform.LocalContext
import androidx.compose.ui.platform.LocalView
import androidx.compose.ui.text.input.KeyboardType
import androidx.compose.ui.unit.dp
import androidx.compose.ui.viewinterop.AndroidView
import androidx.core.content.ContextCompat
import androidx.core.content.FileProvider
import androidx.lifecycle.compose.collectAsStateWithLifecycle
import java.io.File
import org.noisecal.capture.controller.Banner
import org.noisecal.capture.controller.CameraChoice
import org.noisecal.capture.controller.CapturePhase
import org.noisecal.capture.controller.FrameSize
import org.noisecal.capture.controller.PlanForm
import org.noisecal.capture.controller.ThermalLevel
import org.noisecal.capture.controller.UiState
import org.noisecal.capture.plan.PlanOptions
import org.noisecal.capture.plan.PlanResult
import org.noisecal.capture.plan.fmtDuration
import org.noisecal.capture.plan.fmtNs

/**
 * The whole app, driven by the one [UiState] of [CaptureViewModel] with an exhaustive `when`:
 * permission, loading, unsupported camera, or the camera screen (preview plus a panel per step).
 */
@Composable
fun NoisecalApp(vm: CaptureViewModel) {
    val state by vm.uiState.collectAsStateWithLifecycle()
    val context = LocalContext.current
    val permission = rememberLauncherForActivityResult(ActivityResultContracts.RequestPermission()) { vm.onPermission(it) }
    LaunchedEffect(Unit) {
        if (ContextCompat.checkSelfPermission(context, Manifest.permission.CAMERA) == PackageManager.PERMISSION_GRANTED) {
            vm.onPermission(true)
        } else {
            permission.launch(Manifest.permission.CAMERA)
        }
    }
    // An hour of capture with the phone on a tripod: keep the screen (and so the activity) on.
    val view = LocalView.current
    val capturing = state is UiState.Capturing || state is UiState.CoverLens
    DisposableEffect(capturing) {
        view.keepScreenOn = capturing
        onDispose { view.keepScreenOn = false }
    }

    Surface(modifier = Modifier.fillMaxSize(), color = MaterialTheme.colorScheme.background) {
        Box(Modifier.safeDrawingPadding()) {
            when (val s = state) {
                is UiState.NeedsPermission -> Message(
                    "Camera permission",
                    if (s.denied) "noisecal needs the camera permission to calibrate the camera" else "noisecal needs the camera to calibrate it.",
                ) {
                    Button(onClick = { permission.launch(Manifest.permission.CAMERA) }) { Text("Grant camera access") }
                }
                UiState.LoadingCameras -> Message("Reading the cameras…", "")
                is UiState.Unsupported -> UnsupportedScreen(s.cameras)
                // One call site for every state with a camera, so the preview survives the step changes.
                is UiState.AtCamera -> CameraScreen(vm, s)
            }
        }
    }
}

@Composable
private fun Message(title: String, body: String, modifier: Modifier = Modifier, action: @Composable () -> Unit = {}) {
    Column(modifier.fillMaxSize().padding(24.dp), verticalArrangement = Arrangement.Center, horizontalAlignment = Alignment.CenterHorizontally) {
        Text(title, style = MaterialTheme.typography.headlineSmall)
        Spacer(Modifier.height(8.dp))
        Text(body)
        Spacer(Modifier.height(16.dp))
        action()
    }
}

/** No camera can be calibrated: say which cameras there are and what each lacks. */
@Composable
private fun UnsupportedScreen(cameras: List<CameraChoice>, modifier: Modifier = Modifier) {
    Column(modifier.fillMaxSize().padding(24.dp).verticalScroll(rememberScrollState())) {
        Text("This phone cannot be calibrated", style = MaterialTheme.typography.headlineSmall)
        Spacer(Modifier.height(8.dp))
        Text("noisecal needs a camera with manual sensor control and RAW output whose RAW frames have no lens shading applied.")
        Spacer(Modifier.height(16.dp))
        if (cameras.isEmpty()) Text("No camera was found.")
        for (c in cameras) {
            Text("Camera ${c.id} (${c.facingName})", style = MaterialTheme.typography.titleMedium)
            for (p in c.problems) Text("• $p")
            Spacer(Modifier.height(8.dp))
        }
    }
}

/** The live preview on the left, the panel of the current step on the right. */
@Composable
private fun CameraScreen(vm: CaptureViewModel, state: UiState.AtCamera, modifier: Modifier = Modifier) {
    Row(modifier.fillMaxSize()) {
        PreviewPane(vm, state.setup.camera.previewSize, Modifier.weight(1f).fillMaxHeight())
        Column(
            Modifier.width(380.dp).fillMaxHeight().padding(12.dp).verticalScroll(rememberScrollState()),
            verticalArrangement = Arrangement.spacedBy(8.dp),
        ) {
            state.banner?.let { BannerLine(it) }
            when (state) {
                is UiState.Preview -> PreviewPanel(vm, state)
                is UiState.Planned -> PlanPanel(vm, state)
                is UiState.Capturing -> CapturePanel(vm, state)
                is UiState.CoverLens -> CoverLensPanel(vm, state)
                is UiState.Done -> DonePanel(vm, state)
            }
        }
    }
}

@Composable
private fun BannerLine(banner: Banner, modifier: Modifier = Modifier) {
    when (banner) {
        is Banner.Error -> Text(banner.text, modifier, color = MaterialTheme.colorScheme.error)
        is Banner.Info -> Text(banner.text, modifier, style = MaterialTheme.typography.bodyMedium)
    }
}

/** Live preview (SurfaceView, rotated by the system) with a guide for placing the colour checker. */
@Composable
private fun PreviewPane(vm: CaptureViewModel, size: FrameSize?, modifier: Modifier = Modifier) {
    val aspect = if (size != null) size.width.toFloat() / size.height else 4f / 3f
    Box(modifier, contentAlignment = Alignment.Center) {
        Box(Modifier.aspectRatio(aspect)) {
            AndroidView(
                modifier = Modifier.fillMaxSize(),
                factory = { ctx ->
                    SurfaceView(ctx).apply {
                        if (size != null) holder.setFixedSize(size.width, size.height)
                        holder.addCallback(object : SurfaceHolder.Callback {
                            override fun surfaceCreated(holder: SurfaceHolder) = vm.onPreviewSurface(holder.surface)
                            override fun surfaceChanged(holder: SurfaceHolder, format: Int, width: Int, height: Int) = Unit
                            override fun surfaceDestroyed(holder: SurfaceHolder) = vm.onPreviewSurfaceDestroyed()
                        })
                    }
                },
            )
            FramingGuide(Modifier.fillMaxSize())
        }
    }
}

/**
 * Where the chart goes: a centred 3:2 frame (a 6×4-patch checker) filling about 60 % of the
 * width, with corner marks and a cross at the centre. Edges between patches are excluded by the
 * core anyway; a large, sharp, evenly lit chart gives the most flat pixels per level.
 */
@Composable
private fun FramingGuide(modifier: Modifier = Modifier) {
    Canvas(modifier) {
        val w = size.width * 0.6f
        val h = w / 1.5f
        val left = (size.width - w) / 2
        val top = (size.height - h) / 2
        val stroke = Stroke(width = 3.dp.toPx())
        val mark = 0.12f * h
        val guide = Color(0xCCFFFFFF)
        drawRect(guide, topLeft = Offset(left, top), size = Size(w, h), style = Stroke(width = 1.dp.toPx()))
        for ((x, y, dx, dy) in listOf(
            Quad(left, top, 1f, 1f), Quad(left + w, top, -1f, 1f), Quad(left, top + h, 1f, -1f), Quad(left + w, top + h, -1f, -1f),
        )) {
            drawLine(guide, Offset(x, y), Offset(x + dx * mark, y), strokeWidth = stroke.width)
            drawLine(guide, Offset(x, y), Offset(x, y + dy * mark), strokeWidth = stroke.width)
        }
        val c = center
        drawLine(guide, Offset(c.x - mark / 2, c.y), Offset(c.x + mark / 2, c.y), strokeWidth = 1.dp.toPx())
        drawLine(guide, Offset(c.x, c.y - mark / 2), Offset(c.x, c.y + mark / 2), strokeWidth = 1.dp.toPx())
    }
}

private data class Quad(val x: Float, val y: Float, val dx: Float, val dy: Float)

@Composable
private fun PreviewPanel(vm: CaptureViewModel, state: UiState.Preview, modifier: Modifier = Modifier) {
    val setup = state.setup
    val cam = setup.camera.capabilities
    Column(modifier, verticalArrangement = Arrangement.spacedBy(8.dp)) {
        Text("Set up", style = MaterialTheme.typography.titleLarge)
        Text("Mount the phone, fit the colour checker inside the frame under a steady lamp (no daylight, no flicker), then make the plan.")
        if (cam != null) {
            Text("Camera ${cam.cameraId}: ${cam.rawWidth}×${cam.rawHeight} RAW, ISO ${cam.sensitivityRange.first}–${cam.sensitivityRange.last}" +
                (cam.maxAnalogSensitivity?.let { " (analog to $it)" } ?: ""), style = MaterialTheme.typography.bodySmall)
        }
        Text(setup.metering?.let { "Metered: ISO ${it.iso}, ${fmtNs(it.exposureNs)}" } ?: "Metering…")
        PlanFormFields(setup.form, vm::updateForm)
        Button(onClick = vm::makePlan, enabled = setup.metering != null, modifier = Modifier.fillMaxWidth()) { Text("Make the plan") }
    }
}

@Composable
private fun PlanFormFields(form: PlanForm, onChange: (PlanForm) -> Unit, modifier: Modifier = Modifier) {
    Column(modifier, verticalArrangement = Arrangement.spacedBy(8.dp)) {
        OutlinedTextField(form.isos, { onChange(form.copy(isos = it)) }, label = { Text("Target ISOs (empty: 100·2ⁿ in range)") },
            singleLine = true, modifier = Modifier.fillMaxWidth())
        Row(horizontalArrangement = Arrangement.spacedBy(8.dp)) {
            OutlinedTextField(form.evMin, { onChange(form.copy(evMin = it)) }, label = { Text("EV from") }, singleLine = true,
                keyboardOptions = KeyboardOptions(keyboardType = KeyboardType.Number), modifier = Modifier.weight(1f))
            OutlinedTextField(form.evMax, { onChange(form.copy(evMax = it)) }, label = { Text("EV to") }, singleLine = true,
                keyboardOptions = KeyboardOptions(keyboardType = KeyboardType.Number), modifier = Modifier.weight(1f))
            OutlinedTextField(form.frames, { onChange(form.copy(frames = it)) }, label = { Text("Frames") }, singleLine = true,
                keyboardOptions = KeyboardOptions(keyboardType = KeyboardType.Number), modifier = Modifier.weight(1f))
        }
        Row(verticalAlignment = Alignment.CenterVertically) {
            Checkbox(form.recording, { onChange(form.copy(recording = it)) })
            Text("Also record the frames for desktop replay")
        }
        DarkFramesOption(form, onChange)
    }
}

/** The optional dark step: its toggle, what it is for and what it asks of the user. */
@Composable
private fun DarkFramesOption(form: PlanForm, onChange: (PlanForm) -> Unit, modifier: Modifier = Modifier) {
    val perIso = form.darkFramesPerIso.trim().toIntOrNull() ?: PlanOptions.DEFAULT_DARK_FRAMES_PER_ISO
    Column(modifier, verticalArrangement = Arrangement.spacedBy(4.dp)) {
        Row(verticalAlignment = Alignment.CenterVertically) {
            Checkbox(form.darkFrames, { onChange(form.copy(darkFrames = it)) })
            Text("Dark frames (lens covered)")
        }
        Text(
            "Optional. After the lit sweep the app asks you to cover the lens and takes a short burst of about $perIso frames " +
                "per ISO (the lowest ISO and every target), at that ISO's shortest exposure. With no light on the sensor it " +
                "measures what the sensor adds by itself: the fixed-pattern noise (dark shading, a per-pixel offset that grows " +
                "with gain) and the signal-independent read noise, so the pack gets a fixed-pattern component per ISO. Cover the " +
                "lens with an opaque lens cap, or a fingertip with a dark cloth over it and the phone, so that no light leaks in " +
                "from the sides; frames with light in them are refused and the step is asked for again. You can still skip it " +
                "when asked.",
            style = MaterialTheme.typography.bodySmall,
        )
        if (form.darkFrames) {
            OutlinedTextField(form.darkFramesPerIso, { onChange(form.copy(darkFramesPerIso = it)) }, label = { Text("Dark frames per ISO") },
                singleLine = true, keyboardOptions = KeyboardOptions(keyboardType = KeyboardType.Number), modifier = Modifier.fillMaxWidth())
        }
    }
}

@Composable
private fun PlanPanel(vm: CaptureViewModel, state: UiState.Planned, modifier: Modifier = Modifier) {
    Column(modifier, verticalArrangement = Arrangement.spacedBy(8.dp)) {
        Text("Plan", style = MaterialTheme.typography.titleLarge)
        when (val r = state.plan) {
            is PlanResult.Ok -> {
                val p = r.plan
                Text("Takes about ${fmtDuration(p.estimatedDurationNs)}", style = MaterialTheme.typography.titleMedium)
                Text(p.describe(), style = MaterialTheme.typography.bodySmall)
                val resume = state.resume
                if (state.canResume && resume != null) {
                    Button(onClick = { vm.startCapture() }, modifier = Modifier.fillMaxWidth()) {
                        Text("Resume (${resume.completedBursts} of ${resume.totalBursts} bursts done)")
                    }
                    OutlinedButton(onClick = { vm.startCapture(startOver = true) }, modifier = Modifier.fillMaxWidth()) { Text("Start over") }
                } else {
                    Button(onClick = { vm.startCapture() }, modifier = Modifier.fillMaxWidth()) { Text("Start the capture") }
                }
            }
            is PlanResult.Refused -> {
                Text("This plan cannot be captured:", color = MaterialTheme.colorScheme.error)
                for (reason in r.reasons) Text("• $reason")
            }
        }
        OutlinedButton(onClick = vm::backToPreview, modifier = Modifier.fillMaxWidth()) { Text("Change the settings") }
    }
}

@Composable
private fun CapturePanel(vm: CaptureViewModel, state: UiState.Capturing, modifier: Modifier = Modifier) {
    val s = state.progress
    Column(modifier, verticalArrangement = Arrangement.spacedBy(8.dp)) {
        Text(
            when (s.phase) {
                CapturePhase.IDLE -> "Starting…"
                CapturePhase.RUNNING -> "Capturing"
                CapturePhase.AWAITING_LENS_COVER -> "Waiting for the lens to be covered"
                CapturePhase.PAUSED_THERMAL -> "Paused: cooling down"
                CapturePhase.FINISHING -> "Building the model pack…"
                CapturePhase.DONE -> "Done"
                CapturePhase.STOPPED -> "Stopped"
                CapturePhase.FAILED -> "Capture failed"
            },
            style = MaterialTheme.typography.titleLarge,
        )
        Text("Overall: ${s.framesDone} / ${s.framesTotal} frames, burst ${minOf(s.burstsDone + 1, s.burstCount)} of ${s.burstCount}")
        LinearProgressIndicator(progress = { s.overallFraction.toFloat() }, modifier = Modifier.fillMaxWidth())
        s.currentBurst?.let { b ->
            Text("This burst: EV ${"%+.1f".format(b.ev)}, ISO ${b.iso}, ${fmtNs(b.exposureNs)} — ${s.burstFramesAccepted} / ${s.burstFramesWanted}")
            LinearProgressIndicator(progress = { s.burstFraction.toFloat() }, modifier = Modifier.fillMaxWidth())
        }
        Text("Elapsed ${fmtDuration(s.elapsedMs * 1_000_000)}, about ${fmtDuration(s.remainingMs * 1_000_000)} left")
        if (s.thermal >= ThermalLevel.MODERATE) Text("Thermal status: ${s.thermal.name.lowercase()}", color = MaterialTheme.colorScheme.error)
        Text("Re-taken: ${s.framesRejected} rejected, ${s.framesLost} lost; ${s.framesDriftNormalised} flicker-corrected", style = MaterialTheme.typography.bodySmall)
        s.lastRejection?.let { Text("Last: $it", style = MaterialTheme.typography.bodySmall) }
        s.message?.let { Text(it, style = MaterialTheme.typography.bodySmall) }
        for (m in s.retakeBursts) Text(m.verdict, style = MaterialTheme.typography.bodySmall, color = MaterialTheme.colorScheme.error)
        if (s.coverage.isNotEmpty()) {
            Text("Coverage (bins with enough samples)", style = MaterialTheme.typography.titleSmall)
            for (c in s.coverage) {
                Text("ISO ${c.iso}: ${c.totalBins - c.underSampledBins} / ${c.totalBins}", style = MaterialTheme.typography.bodySmall)
                LinearProgressIndicator(progress = { c.filledFraction.toFloat() }, modifier = Modifier.fillMaxWidth())
            }
        }
        OutlinedButton(onClick = vm::stopCapture, enabled = !state.stopping, modifier = Modifier.fillMaxWidth()) {
            Text(if (state.stopping) "Stopping…" else "Stop (resume later)")
        }
    }
}

/**
 * The prompt before the dark step: cover the lens (how, and what is taken), then confirm; or skip
 * the step. After frames with light in them it says so and asks again.
 */
@Composable
private fun CoverLensPanel(vm: CaptureViewModel, state: UiState.CoverLens, modifier: Modifier = Modifier) {
    val r = state.request
    Column(modifier, verticalArrangement = Arrangement.spacedBy(8.dp)) {
        Text("Cover the lens", style = MaterialTheme.typography.titleLarge)
        r.notCovered?.let {
            Text("Light reached the sensor, so the dark frames were not kept: $it", color = MaterialTheme.colorScheme.error)
        }
        Text(
            "The lit sweep is done. For the dark frames, cover the lens completely without moving the phone: an opaque lens " +
                "cap, or a fingertip over the lens with a dark cloth over finger and phone. No light may leak in from the sides. " +
                "Then tap \"Lens covered\".",
        )
        Text(
            "${r.frames} frames at ISO ${r.isos.joinToString()}, about ${fmtDuration(r.estimatedMs * 1_000_000)}. " +
                "They measure the sensor's fixed-pattern noise (dark shading) and its signal-independent noise.",
            style = MaterialTheme.typography.bodySmall,
        )
        Button(onClick = vm::confirmLensCovered, enabled = !state.stopping, modifier = Modifier.fillMaxWidth()) {
            Text("Lens covered: take the dark frames")
        }
        OutlinedButton(onClick = vm::skipDarkFrames, enabled = !state.stopping, modifier = Modifier.fillMaxWidth()) {
            Text("Skip the dark frames and finish")
        }
        OutlinedButton(onClick = vm::stopCapture, enabled = !state.stopping, modifier = Modifier.fillMaxWidth()) {
            Text(if (state.stopping) "Stopping…" else "Stop (resume later)")
        }
    }
}

@Composable
private fun DonePanel(vm: CaptureViewModel, state: UiState.Done, modifier: Modifier = Modifier) {
    val context = LocalContext.current
    val saveAs = rememberLauncherForActivityResult(ActivityResultContracts.CreateDocument("application/octet-stream")) { uri ->
        if (uri != null) vm.exportPack(uri)
    }
    Column(modifier, verticalArrangement = Arrangement.spacedBy(8.dp)) {
        Text("Done", style = MaterialTheme.typography.titleLarge)
        Text(state.summary)
        if (state.motion.isNotEmpty()) {
            Text("Motion per burst", style = MaterialTheme.typography.titleSmall)
            for (m in state.motion) {
                Text(m.verdict, style = MaterialTheme.typography.bodySmall,
                    color = if (m.retake) MaterialTheme.colorScheme.error else MaterialTheme.colorScheme.onSurface)
            }
        }
        Button(onClick = { saveAs.launch(state.exportName) }, modifier = Modifier.fillMaxWidth()) { Text("Save as…") }
        OutlinedButton(onClick = { sharePackIntent(context, File(state.packPath), state.summary)?.let { context.startActivity(it) } },
            modifier = Modifier.fillMaxWidth()) { Text("Share") }
        OutlinedButton(onClick = vm::newCalibration, modifier = Modifier.fillMaxWidth()) { Text("New calibration") }
    }
}

/** A share-sheet intent for [pack] (through the FileProvider of file_paths.xml), or null when there is none. */
private fun sharePackIntent(context: Context, pack: File, summary: String): Intent? {
    if (!pack.isFile) return null
    val uri = FileProvider.getUriForFile(context, "${context.packageName}.fileprovider", pack)
    val send = Intent(Intent.ACTION_SEND).apply {
        type = "application/octet-stream"
        putExtra(Intent.EXTRA_STREAM, uri)
        putExtra(Intent.EXTRA_SUBJECT, "noisecal model pack")
        putExtra(Intent.EXTRA_TEXT, summary)
        addFlags(Intent.FLAG_GRANT_READ_URI_PERMISSION)
    }
    return Intent.createChooser(send, "Share the noise model pack")
}
