//! Peak memory of a 12 MP calibration session (Linux: VmHWM of this process).
//!
//! `cargo run --release -p noisecal-cli --example session_memory` — pushes reference and target
//! frames of two EV steps at three ISOs through one session, checkpoints it and builds the pack,
//! then prints the process's peak resident memory. The frames are generated one at a time, as a
//! camera would deliver them.

use ndarray::Array2;
use noisecal_core::{CalibrationSession, CfaPattern, FrameMeta, FrameView, SensorLayout, SessionConfig};

const W: usize = 4032;
const H: usize = 3024;

fn frame(seed: u64, scale: u16, amp: u32) -> Array2<u16> {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    Array2::from_shape_fn((H, W), |(y, x)| {
        s ^= s << 13;
        s ^= s >> 7;
        s ^= s << 17;
        let p = (y * 9 / H) * 12 + x * 12 / W;
        let c = 64 + ((p * 37) % 108) as u16 * scale;
        (c as i32 + (s % (2 * amp as u64 + 1)) as i32 - amp as i32).clamp(0, 1023) as u16
    })
}

fn peak_kib() -> Option<u64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    line.split_whitespace().nth(1)?.parse().ok()
}

fn main() -> anyhow::Result<()> {
    let layout =
        SensorLayout { width: W as u32, height: H as u32, cfa: CfaPattern::Rggb, black: [64.0; 4], white: 1023 };
    let mut session = CalibrationSession::new(layout, SessionConfig::new(50))?;
    let base = peak_kib().unwrap_or(0);
    let mut checkpoint_len = 0;
    for (step, scale) in [(0u64, 4u16), (1, 8)] {
        let exposure = 10_000_000 * (step + 1);
        session.begin_step(exposure)?;
        for k in 0..3 {
            let f = frame(step * 100 + k, scale, 2);
            session.push_frame(&FrameView::from_array(&f)?, &FrameMeta::new(50, exposure))?;
        }
        for (i, iso) in [200u32, 800, 3200].into_iter().enumerate() {
            for k in 0..2 {
                let f = frame(step * 100 + 10 * (i as u64 + 1) + k, scale, 4 << i);
                session.push_frame(&FrameView::from_array(&f)?, &FrameMeta::new(iso, exposure * 50 / iso as u64))?;
            }
        }
        checkpoint_len = session.checkpoint()?.len();
    }
    let pack = session.finish()?;
    let bytes = pack.to_bytes()?;
    println!(
        "12 MP session: peak resident {:.1} MB (process start {:.1} MB; frames are generated one at a time, 24 MB each); checkpoint {:.1} MB; pack {:.2} MB for {} ISOs",
        peak_kib().unwrap_or(0) as f64 / 1024.0,
        base as f64 / 1024.0,
        checkpoint_len as f64 / 1e6,
        bytes.len() as f64 / 1e6,
        pack.isos.len()
    );
    Ok(())
}
