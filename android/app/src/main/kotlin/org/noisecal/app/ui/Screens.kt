package org.noisecal.app.ui

import android.Manifest
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
import androidx.lifecycle.compose.collectAsStateWithLifecycle
import org.noisecal.capture.controller.CapturePhase
import org.noisecal.capture.controller.CaptureUiState
import org.noisecal.capture.controller.ThermalLevel
import org.noisecal.capture.plan.PlanResult
import org.noisecal.capture.plan.fmtDuration
import org.noisecal.capture.plan.fmtNs

/** The whole app: permission, unsupported camera, or preview with a side panel per step. */
@Composable
fun NoisecalApp(vm: CaptureViewModel) {
    val state by vm.state.collectAsStateWithLifecycle()
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
    val capturing = state.step == Step.CAPTURE
    DisposableEffect(capturing) {
        view.keepScreenOn = capturing
        onDispose { view.keepScreenOn = false }
    }

    Surface(modifier = Modifier.fillMaxSize(), color = MaterialTheme.colorScheme.background) {
        Box(Modifier.safeDrawingPadding()) {
            when (state.step) {
                Step.PERMISSION -> Message("Camera permission", state.error ?: "noisecal needs the camera to calibrate it.") {
                    Button(onClick = { permission.launch(Manifest.permission.CAMERA) }) { Text("Grant camera access") }
                }
                Step.LOADING -> Message("Reading the cameras…", "")
                Step.UNSUPPORTED -> UnsupportedScreen(state)
                else -> Row(Modifier.fillMaxSize()) {
                    PreviewPane(vm, state, Modifier.weight(1f).fillMaxHeight())
                    Column(
                        Modifier.width(380.dp).fillMaxHeight().padding(12.dp).verticalScroll(rememberScrollState()),
                        verticalArrangement = Arrangement.spacedBy(8.dp),
                    ) {
                        state.error?.let { Text(it, color = MaterialTheme.colorScheme.error) }
                        state.notice?.let { Text(it, style = MaterialTheme.typography.bodyMedium) }
                        when (state.step) {
                            Step.PREVIEW -> PreviewPanel(vm, state)
                            Step.PLAN -> PlanPanel(vm, state)
                            Step.CAPTURE -> CapturePanel(vm, state.capture)
                            Step.DONE -> DonePanel(vm, state)
                            else -> Unit
                        }
                    }
                }
            }
        }
    }
}

@Composable
private fun Message(title: String, body: String, action: @Composable () -> Unit = {}) {
    Column(Modifier.fillMaxSize().padding(24.dp), verticalArrangement = Arrangement.Center, horizontalAlignment = Alignment.CenterHorizontally) {
        Text(title, style = MaterialTheme.typography.headlineSmall)
        Spacer(Modifier.height(8.dp))
        Text(body)
        Spacer(Modifier.height(16.dp))
        action()
    }
}

/** No camera can be calibrated: say which cameras there are and what each lacks. */
@Composable
private fun UnsupportedScreen(state: AppUiState) {
    Column(Modifier.fillMaxSize().padding(24.dp).verticalScroll(rememberScrollState())) {
        Text("This phone cannot be calibrated", style = MaterialTheme.typography.headlineSmall)
        Spacer(Modifier.height(8.dp))
        Text("noisecal needs a camera with manual sensor control and RAW output whose RAW frames have no lens shading applied.")
        Spacer(Modifier.height(16.dp))
        if (state.candidates.isEmpty()) Text("No camera was found.")
        for (c in state.candidates) {
            Text("Camera ${c.id} (${c.facingName})", style = MaterialTheme.typography.titleMedium)
            for (p in c.problems) Text("• $p")
            Spacer(Modifier.height(8.dp))
        }
    }
}

/** Live preview (SurfaceView, rotated by the system) with a guide for placing the colour checker. */
@Composable
private fun PreviewPane(vm: CaptureViewModel, state: AppUiState, modifier: Modifier) {
    val size = state.camera?.previewSize
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
private fun FramingGuide(modifier: Modifier) {
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
private fun PreviewPanel(vm: CaptureViewModel, state: AppUiState) {
    val cam = state.camera?.capabilities
    Text("Set up", style = MaterialTheme.typography.titleLarge)
    Text("Mount the phone, fit the colour checker inside the frame under a steady lamp (no daylight, no flicker), then make the plan.")
    if (cam != null) {
        Text("Camera ${cam.cameraId}: ${cam.rawWidth}×${cam.rawHeight} RAW, ISO ${cam.sensitivityRange.first}–${cam.sensitivityRange.last}" +
            (cam.maxAnalogSensitivity?.let { " (analog to $it)" } ?: ""), style = MaterialTheme.typography.bodySmall)
    }
    Text(state.metering?.let { "Metered: ISO ${it.iso}, ${fmtNs(it.exposureNs)}" } ?: "Metering…")
    PlanFormFields(vm, state.form)
    Button(onClick = vm::makePlan, enabled = state.metering != null, modifier = Modifier.fillMaxWidth()) { Text("Make the plan") }
}

@Composable
private fun PlanFormFields(vm: CaptureViewModel, form: PlanForm) {
    OutlinedTextField(form.isos, { vm.updateForm(form.copy(isos = it)) }, label = { Text("Target ISOs (empty: 100·2ⁿ in range)") },
        singleLine = true, modifier = Modifier.fillMaxWidth())
    Row(horizontalArrangement = Arrangement.spacedBy(8.dp)) {
        OutlinedTextField(form.evMin, { vm.updateForm(form.copy(evMin = it)) }, label = { Text("EV from") }, singleLine = true,
            keyboardOptions = KeyboardOptions(keyboardType = KeyboardType.Number), modifier = Modifier.weight(1f))
        OutlinedTextField(form.evMax, { vm.updateForm(form.copy(evMax = it)) }, label = { Text("EV to") }, singleLine = true,
            keyboardOptions = KeyboardOptions(keyboardType = KeyboardType.Number), modifier = Modifier.weight(1f))
        OutlinedTextField(form.frames, { vm.updateForm(form.copy(frames = it)) }, label = { Text("Frames") }, singleLine = true,
            keyboardOptions = KeyboardOptions(keyboardType = KeyboardType.Number), modifier = Modifier.weight(1f))
    }
    Row(verticalAlignment = Alignment.CenterVertically) {
        Checkbox(form.recording, { vm.updateForm(form.copy(recording = it)) })
        Text("Also record the frames for desktop replay")
    }
}

@Composable
private fun PlanPanel(vm: CaptureViewModel, state: AppUiState) {
    Text("Plan", style = MaterialTheme.typography.titleLarge)
    when (val r = state.plan) {
        is PlanResult.Ok -> {
            val p = r.plan
            Text("Takes about ${fmtDuration(p.estimatedDurationNs)}", style = MaterialTheme.typography.titleMedium)
            Text(p.describe(), style = MaterialTheme.typography.bodySmall)
            val resume = state.resume
            if (resume != null && resume.samePlan && !resume.finished && resume.completedBursts > 0) {
                Button(onClick = vm::startCapture, modifier = Modifier.fillMaxWidth()) {
                    Text("Resume (${resume.completedBursts} of ${resume.totalBursts} bursts done)")
                }
                OutlinedButton(onClick = vm::startOver, modifier = Modifier.fillMaxWidth()) { Text("Start over") }
            } else {
                Button(onClick = vm::startCapture, modifier = Modifier.fillMaxWidth()) { Text("Start the capture") }
            }
        }
        is PlanResult.Refused -> {
            Text("This plan cannot be captured:", color = MaterialTheme.colorScheme.error)
            for (reason in r.reasons) Text("• $reason")
        }
        null -> Unit
    }
    OutlinedButton(onClick = vm::backToPreview, modifier = Modifier.fillMaxWidth()) { Text("Change the settings") }
}

@Composable
private fun CapturePanel(vm: CaptureViewModel, s: CaptureUiState) {
    Text(
        when (s.phase) {
            CapturePhase.PAUSED_THERMAL -> "Paused: cooling down"
            CapturePhase.FINISHING -> "Building the model pack…"
            CapturePhase.FAILED -> "Capture failed"
            else -> "Capturing"
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
    if (s.coverage.isNotEmpty()) {
        Text("Coverage (bins with enough samples)", style = MaterialTheme.typography.titleSmall)
        for (c in s.coverage) {
            Text("ISO ${c.iso}: ${c.totalBins - c.underSampledBins} / ${c.totalBins}", style = MaterialTheme.typography.bodySmall)
            LinearProgressIndicator(progress = { c.filledFraction.toFloat() }, modifier = Modifier.fillMaxWidth())
        }
    }
    OutlinedButton(onClick = vm::stopCapture, modifier = Modifier.fillMaxWidth()) { Text("Stop (resume later)") }
}

@Composable
private fun DonePanel(vm: CaptureViewModel, state: AppUiState) {
    val context = LocalContext.current
    val saveAs = rememberLauncherForActivityResult(ActivityResultContracts.CreateDocument("application/octet-stream")) { uri ->
        if (uri != null) vm.exportTo(uri)
    }
    Text("Done", style = MaterialTheme.typography.titleLarge)
    Text(state.capture.summary ?: state.notice ?: "The model pack is ready.")
    Button(onClick = { saveAs.launch(vm.suggestedPackName()) }, modifier = Modifier.fillMaxWidth()) { Text("Save as…") }
    OutlinedButton(onClick = { vm.shareIntent()?.let { context.startActivity(it) } }, modifier = Modifier.fillMaxWidth()) { Text("Share") }
    OutlinedButton(onClick = vm::newCalibration, modifier = Modifier.fillMaxWidth()) { Text("New calibration") }
}
