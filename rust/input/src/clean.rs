//! The clean image of an EV step of held-out captures: its reference burst summed by the core's
//! [`ReferenceBurst`], with the checks a calibration session makes of reference frames (size,
//! metadata, the burst's exposure, drift) and nothing else of a session. `eval` and `demo` use it.

use noisecal_core::calibrate::step::StepKey;
use noisecal_core::calibrate::{CleanImage, ReferenceBurst};
use noisecal_core::error::SessionError;
use noisecal_core::{Binning, DriftPolicy, FrameMeta, FrameView, SensorLayout, SessionConfig};

/// Clean images of captures from one sensor: how each reference burst is summed and closed.
#[derive(Debug, Clone)]
pub struct CleanImages {
    layout: SensorLayout,
    reference_iso: u32,
    binning: Binning,
    /// A calibration's defaults: flat test, region of interest, drift.
    config: SessionConfig,
}

impl CleanImages {
    /// For captures of `layout` whose reference ISO is `reference_iso`, binned like a pack with
    /// `bin_width` (the clean image's selection sums are per bin).
    pub fn new(layout: &SensorLayout, reference_iso: u32, bin_width: u16) -> Result<Self, SessionError> {
        layout.validate()?;
        Ok(Self {
            layout: layout.clone(),
            reference_iso,
            binning: Binning::new(layout, bin_width),
            config: SessionConfig::new(reference_iso),
        })
    }

    /// An empty reference burst at `exposure_ns`.
    pub fn burst(&self, exposure_ns: u64) -> Result<CleanBurst, SessionError> {
        if exposure_ns == 0 {
            return Err(SessionError::Metadata("reference exposure is 0 ns".into()));
        }
        let c = &self.config;
        Ok(CleanBurst {
            burst: ReferenceBurst::new(&self.layout, exposure_ns),
            key: StepKey::new(self.reference_iso, exposure_ns),
            layout: self.layout.clone(),
            binning: self.binning.clone(),
            policy: c.drift_policy(),
            roi: c.roi,
            flat_k: c.flat_k,
        })
    }
}

/// One reference burst being summed into a clean image.
#[derive(Debug, Clone)]
pub struct CleanBurst {
    burst: ReferenceBurst,
    key: StepKey,
    layout: SensorLayout,
    binning: Binning,
    policy: DriftPolicy,
    roi: Option<noisecal_core::calibrate::Roi>,
    flat_k: f64,
}

impl CleanBurst {
    /// Adds a frame at the reference ISO; a refused frame leaves the burst unchanged.
    pub fn push(&mut self, frame: &FrameView<'_>, meta: &FrameMeta) -> Result<(), SessionError> {
        frame.expect_size(self.layout.width as usize, self.layout.height as usize)?;
        meta.validate(&self.layout)?;
        if !self.key.admits_reference(meta) {
            return Err(SessionError::ReferenceExposure {
                exposure_ns: meta.exposure_ns,
                expected_ns: self.key.reference_exposure_ns,
            });
        }
        self.burst.push(frame, meta, &self.policy)?;
        Ok(())
    }

    /// The step this burst is the reference of.
    pub fn key(&self) -> StepKey {
        self.key
    }

    /// The clean image and its flat mask.
    pub fn close(&self) -> Result<CleanImage, SessionError> {
        if self.burst.frames() == 0 {
            return Err(SessionError::NoReference {
                iso: 0,
                exposure_ns: self.key.reference_exposure_ns,
                reference: self.key.reference_iso,
            });
        }
        self.burst.close(&self.binning, self.roi, self.flat_k)
    }
}
