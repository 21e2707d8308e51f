//! Frame brightness drift (mains flicker, a mechanical shutter, exposure not truly locked): a
//! frame whose brightness departs from its burst's by more than its noise explains is reported and,
//! by default, normalised to its burst (method.md, Calibration 2).

use serde::{Deserialize, Serialize};

/// Brightness of one frame against a base image (the clean image, or the burst's first frame).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FrameBrightness {
    /// Σ(frame − black) / Σ(base − black) over the pixels compared.
    pub ratio: f64,
    /// Standard error of `ratio` from its spread over row bands (includes row noise).
    pub sigma: f64,
}

/// Builds [`FrameBrightness`] from per-band sums of (frame − black) and (base − black).
pub fn brightness_from_bands(frame_sums: &[f64], base_sums: &[f64]) -> Option<FrameBrightness> {
    let f: f64 = frame_sums.iter().sum();
    let b: f64 = base_sums.iter().sum();
    if b.partial_cmp(&0.0) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let ratio = f / b;
    let bands: Vec<f64> = frame_sums.iter().zip(base_sums).filter(|(_, b)| **b > 0.0).map(|(f, b)| f / b).collect();
    let k = bands.len();
    let sigma = if k >= 2 {
        let m = bands.iter().sum::<f64>() / k as f64;
        let var = bands.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (k - 1) as f64;
        (var / k as f64).sqrt()
    } else {
        0.0
    };
    Some(FrameBrightness { ratio, sigma })
}

/// What the tracker decided for one frame.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct DriftVerdict {
    /// Relative departure from the burst's running median brightness.
    pub departure: f64,
    /// Departure beyond what the noise explains.
    pub drifted: bool,
    /// Multiply (frame − black) by this to bring it to the burst's brightness (1 when not drifted).
    pub scale: f64,
}

/// Running robust brightness of one burst.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct DriftTracker {
    ratios: Vec<f64>,
}

impl DriftTracker {
    /// Judges a frame against the running median of the burst (this frame included), with a
    /// threshold of `z` standard errors (from the frame itself and the burst's spread) and at least
    /// `floor` relative, and records it.
    pub fn assess(&mut self, b: FrameBrightness, z: f64, floor: f64) -> DriftVerdict {
        let v = self.judge(b, z, floor);
        self.record(b);
        v
    }

    /// [`assess`](Self::assess) without recording the frame (for a frame that may be refused).
    pub fn judge(&self, b: FrameBrightness, z: f64, floor: f64) -> DriftVerdict {
        let mut ratios = self.ratios.clone();
        ratios.push(b.ratio);
        let med = median(&ratios);
        let departure = b.ratio / med - 1.0;
        let spread = if ratios.len() >= 5 {
            let dev: Vec<f64> = ratios.iter().map(|r| (r / med - 1.0).abs()).collect();
            1.4826 * median(&dev)
        } else {
            0.0
        };
        let threshold = floor.max(z * (b.sigma / med)).max(z * spread);
        let drifted = departure.abs() > threshold;
        DriftVerdict { departure, drifted, scale: if drifted { med / b.ratio } else { 1.0 } }
    }

    /// Adds a frame's brightness to the burst.
    pub fn record(&mut self, b: FrameBrightness) {
        self.ratios.push(b.ratio);
    }

    pub fn frames(&self) -> usize {
        self.ratios.len()
    }

    /// Median brightness ratio of the burst so far.
    pub fn median(&self) -> Option<f64> {
        (!self.ratios.is_empty()).then(|| median(&self.ratios))
    }
}

fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(|a, b| a.total_cmp(b));
    let n = s.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 { s[n / 2] } else { 0.5 * (s[n / 2 - 1] + s[n / 2]) }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flicker_frame_is_flagged_and_scaled_back() {
        let mut t = DriftTracker::default();
        let fb = |r: f64| FrameBrightness { ratio: r, sigma: 0.0005 };
        for r in [1.0, 1.0004, 0.9997, 1.0002, 0.9999] {
            assert!(!t.assess(fb(r), 5.0, 0.001).drifted);
        }
        let v = t.assess(fb(1.03), 5.0, 0.001);
        assert!(v.drifted);
        assert!((v.scale * 1.03 - 1.0).abs() < 0.002);
        assert!(!t.assess(fb(1.0001), 5.0, 0.001).drifted);
    }

    #[test]
    fn noisy_dark_frames_are_not_flagged() {
        let mut t = DriftTracker::default();
        // 2 % noise on the ratio: a 3 % departure is within 5 σ.
        for r in [1.0, 1.02, 0.98, 1.03, 0.99] {
            assert!(!t.assess(FrameBrightness { ratio: r, sigma: 0.02 }, 5.0, 0.001).drifted);
        }
    }

    #[test]
    fn bands_give_ratio_and_error() {
        let b = brightness_from_bands(&[101.0, 99.0, 102.0, 98.0], &[100.0; 4]).unwrap();
        assert!((b.ratio - 1.0).abs() < 1e-12);
        assert!(b.sigma > 0.005 && b.sigma < 0.02);
        assert!(brightness_from_bands(&[1.0], &[0.0]).is_none());
    }
}
