package org.noisecal.app.camera

import android.content.Context
import android.os.Build
import android.os.PowerManager
import org.noisecal.capture.controller.ThermalLevel
import org.noisecal.capture.controller.ThermalStatusSource

/** `PowerManager.getCurrentThermalStatus()` (API 29+); reports NONE on API 28, which has no such status. */
class AndroidThermalSource(context: Context) : ThermalStatusSource {
    private val power = context.getSystemService(PowerManager::class.java)

    override fun current(): ThermalLevel =
        if (Build.VERSION.SDK_INT >= Build.VERSION_CODES.Q) ThermalLevel.fromCode(power.currentThermalStatus) else ThermalLevel.NONE
}
