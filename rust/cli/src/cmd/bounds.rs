//! Bounds on numeric arguments: a number that sizes an allocation or a loop is checked when the
//! command line is parsed, with a message naming the accepted range, so no value of any flag can
//! make a command allocate without bound.

/// Side of a simulated image (pixels).
pub const SIDE: std::ops::RangeInclusive<i64> = 2..=16384;
/// Frames per simulated burst.
pub const FRAMES: std::ops::RangeInclusive<i64> = 1..=1024;
/// Evaluation seeds per model.
pub const SEEDS: std::ops::RangeInclusive<i64> = 1..=64;
/// Padding bytes per recorded row.
pub const PADDING_MAX: usize = 1 << 16;
/// `--bin-width`: levels per bin, by the core's rule ([`noisecal_core::model::bin_width::check`]).
pub fn bin_width(s: &str) -> Result<u16, String> {
    let v: u16 = s.parse().map_err(|e| format!("{e}"))?;
    noisecal_core::model::bin_width::check(v).map_err(|e| e.to_string())
}

/// Bins per level group in eval.
pub const GROUP_BINS_MAX: usize = 4096;

/// A finite, positive number (a threshold in standard deviations).
pub fn positive_finite(s: &str) -> Result<f64, String> {
    let v: f64 = s.trim().parse().map_err(|_| format!("{s:?} is not a number"))?;
    if v.is_finite() && v > 0.0 { Ok(v) } else { Err(format!("{s} must be a finite number above 0")) }
}

/// Padding bytes per row: 0 to [`PADDING_MAX`].
pub fn padding(s: &str) -> Result<usize, String> {
    let v: usize = s.trim().parse().map_err(|_| format!("{s:?} is not a whole number of bytes"))?;
    if v <= PADDING_MAX { Ok(v) } else { Err(format!("{v} bytes of padding per row: at most {PADDING_MAX}")) }
}

/// Bins per level group: 1 to [`GROUP_BINS_MAX`].
pub fn group_bins(s: &str) -> Result<usize, String> {
    let v: usize = s.trim().parse().map_err(|_| format!("{s:?} is not a whole number of bins"))?;
    if (1..=GROUP_BINS_MAX).contains(&v) {
        Ok(v)
    } else {
        Err(format!("{v} bins per group: give 1 to {GROUP_BINS_MAX}"))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parsers_refuse_what_they_must() {
        assert!(positive_finite("NaN").is_err());
        assert!(positive_finite("inf").is_err());
        assert!(positive_finite("0").is_err());
        assert_eq!(positive_finite("4.5"), Ok(4.5));
        assert!(padding("4294967295").is_err());
        assert_eq!(padding("32"), Ok(32));
        assert!(group_bins("0").is_err());
        assert_eq!(group_bins("8"), Ok(8));
    }
}
