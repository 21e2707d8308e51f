//! The one rule for a bin width every front-end is given (`noisecal calibrate --bin-width`,
//! Python's `calibrate(bin_width=…)`, the app's `binWidth`): levels per bin, 1 to
//! [`MAX_BIN_WIDTH`]. A calibration session checks it (`CalibrationSession::new`); a
//! front-end may check it first to name its own parameter, with [`check`]'s message after the name.

use crate::error::LayoutError;

/// The widest bin: 4096 levels, a sixteenth of a 16-bit range (the default is about 240 bins
/// between black and white, [`crate::SensorLayout::default_bin_width`]).
pub const MAX_BIN_WIDTH: u16 = 4096;

/// `width` if it is a bin width (1 to [`MAX_BIN_WIDTH`] levels), else why not; the message starts
/// with the number, for a front-end to put its parameter's name before it.
pub fn check(width: u16) -> Result<u16, LayoutError> {
    if (1..=MAX_BIN_WIDTH).contains(&width) {
        Ok(width)
    } else {
        Err(LayoutError::BinWidth { width, max: MAX_BIN_WIDTH })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn widths_from_one_to_the_maximum() {
        assert_eq!(check(1), Ok(1));
        assert_eq!(check(MAX_BIN_WIDTH), Ok(MAX_BIN_WIDTH));
        assert_eq!(
            check(0).expect_err("0").to_string(),
            "0 is not a bin width: give 1 to 4096 levels per bin, or leave it to the default"
        );
        assert!(check(MAX_BIN_WIDTH + 1).is_err());
    }
}
