package org.noisecal.capture.plan

/**
 * Camera2 `SENSOR_INFO_COLOR_FILTER_ARRANGEMENT` values that name a 2×2 Bayer mosaic. [label] is
 * the name the core takes ("RGGB", …): it lists the colours of CFA positions 0..3, i.e.
 * `(row % 2) * 2 + (col % 2)`.
 */
enum class CfaArrangement(val camera2Code: Int, val label: String) {
    RGGB(0, "RGGB"),
    GRBG(1, "GRBG"),
    GBRG(2, "GBRG"),
    BGGR(3, "BGGR");

    companion object {
        /** The Bayer arrangement for a Camera2 code, or null for RGB (4), MONO (5), NIR (6) and unknown codes. */
        fun fromCamera2(code: Int): CfaArrangement? = entries.firstOrNull { it.camera2Code == code }

        /** Human-readable name of any Camera2 arrangement code, for messages. */
        fun describeCamera2(code: Int): String = when (code) {
            in 0..3 -> entries.first { it.camera2Code == code }.label
            4 -> "RGB (not a mosaic)"
            5 -> "MONO"
            6 -> "NIR"
            else -> "unknown code $code"
        }
    }
}

/**
 * One `SENSOR_NOISE_PROFILE` pair for one CFA channel: variance `S·x + O` of a value `x`
 * normalised to [0, 1], as the camera reported it in a capture result at [atIso].
 */
data class NoiseProfilePair(val scale: Double, val offset: Double)

/**
 * What a camera reports about itself, read from `CameraCharacteristics` (see the Camera2 adapter
 * in `:app`) or made up by a test. Plain data: no `android.*` types.
 *
 * @property sensitivityRange `SENSOR_INFO_SENSITIVITY_RANGE`; its lower end is the reference ISO.
 * @property maxAnalogSensitivity `SENSOR_MAX_ANALOG_SENSITIVITY`, or null when not reported.
 * @property exposureRangeNs `SENSOR_INFO_EXPOSURE_TIME_RANGE` in ns.
 * @property maxFrameDurationNs `SENSOR_INFO_MAX_FRAME_DURATION` in ns, or null when not reported.
 * @property minFrameDurationNs `StreamConfigurationMap.getOutputMinFrameDuration(RAW_SENSOR, size)`.
 * @property blackLevelPattern `SENSOR_BLACK_LEVEL_PATTERN` in CFA position order (4 values).
 * @property cfaCode `SENSOR_INFO_COLOR_FILTER_ARRANGEMENT` as Camera2 reports it.
 * @property lensShadingAppliedToRaw `SENSOR_INFO_LENS_SHADING_APPLIED`.
 * @property noiseProfile `SENSOR_NOISE_PROFILE` (one pair per CFA channel) from a result at [noiseProfileIso], if any.
 * @property rawRowStrideBytes row stride of a RAW_SENSOR plane if already known (first image), else null (2·width assumed).
 */
data class CameraCapabilities(
    val cameraId: String,
    val make: String,
    val model: String,
    val sensitivityRange: IntRange,
    val maxAnalogSensitivity: Int?,
    val exposureRangeNs: LongRange,
    val maxFrameDurationNs: Long?,
    val minFrameDurationNs: Long,
    val rawWidth: Int,
    val rawHeight: Int,
    val whiteLevel: Int,
    val blackLevelPattern: List<Int>,
    val cfaCode: Int,
    val manualSensor: Boolean,
    val raw: Boolean,
    val lensShadingAppliedToRaw: Boolean,
    val noiseProfile: List<NoiseProfilePair>? = null,
    val noiseProfileIso: Int? = null,
    val rawRowStrideBytes: Int? = null,
) {
    /** The lowest ISO the sensor offers: the session's reference ISO. */
    val referenceIso: Int get() = sensitivityRange.first

    /** The Bayer arrangement, or null when the sensor is not a 2×2 Bayer mosaic. */
    val cfa: CfaArrangement? get() = CfaArrangement.fromCamera2(cfaCode)

    /** Longest exposure a request can actually get: the exposure range capped by the max frame duration. */
    val maxUsableExposureNs: Long
        get() = maxFrameDurationNs?.let { minOf(it, exposureRangeNs.last) } ?: exposureRangeNs.last

    /** Whether [iso] is above the analog range and so reached by digital gain. */
    fun isDigitalGain(iso: Int): Boolean = maxAnalogSensitivity?.let { iso > it } ?: false
}
