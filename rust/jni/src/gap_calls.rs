//! What a finished calibration says about each gap between neighbouring calibrated ISOs
//! (`noisecal_core::derive::gain_switch::gaps`), as the text that crosses JNI with the summary
//! (`NoisecalSession.Finished.gapCalls`) and that the app's `GainGap.parseCalls`
//! (android/capture/.../plan/GainGapFollowUp.kt) reads. The form is stable:
//!
//! ```text
//! noisecal-gap-calls 1
//! 200 800 switch
//! 800 1600 none
//! 1600 3200 undetermined
//! ```
//!
//! A header line (its version), then one line per gap in ISO order: the calibrated ISO below
//! the gap, the one above, and the call: `switch` (a conversion-gain switch), `none` (one
//! conversion gain across it), `undetermined` (a side's read noise at black is not pinned:
//! dark frames settle it). Fields are separated by one space; lines end with `\n`. A pack with
//! fewer than two calibrated ISOs has the header only.

use noisecal_core::ModelPack;
use noisecal_core::derive::gain_switch::{GapCall, calibrated_laws, gaps};

/// The header line of [`gap_calls_text`], with the form's version.
pub const HEADER: &str = "noisecal-gap-calls 1";

/// The gap calls of `pack` in the form the module documents.
pub fn gap_calls_text(pack: &ModelPack) -> String {
    let mut out = format!("{HEADER}\n");
    for g in gaps(&calibrated_laws(pack)) {
        let call = match g.call {
            GapCall::Switch(_) => "switch",
            GapCall::NoSwitch => "none",
            GapCall::Undetermined => "undetermined",
        };
        out.push_str(&format!("{} {} {call}\n", g.below_iso, g.above_iso));
    }
    out
}
