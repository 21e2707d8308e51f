//! Noise synthesis on clean raw images (paper Eq. 3): `noisy = clamp(clean + n, 0, white)`, `n`
//! drawn for (ISO, CFA position, bin of the clean level). Seeded and reproducible whatever the
//! thread count: each band of rows has its own ChaCha stream.

use ndarray::{Array2, ArrayView2};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use crate::layout::position;
use crate::sampler::IsoSampler;

/// Rows per RNG stream.
pub const BAND_ROWS: usize = 16;

/// The RNG of one band of rows.
pub fn band_rng(seed: u64, band: usize) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    rng.set_stream(band as u64);
    rng
}

/// Adds synthetic noise to a clean raw image (levels in DN, black included; CFA phase of the
/// pack's layout at (0, 0)).
pub fn synthesize(sampler: &IsoSampler, clean: ArrayView2<'_, u16>, seed: u64) -> Array2<u16> {
    let (h, w) = clean.dim();
    let mut out = vec![0u16; h * w];
    if w > 0 {
        out.par_chunks_mut(BAND_ROWS * w).enumerate().for_each(|(band, chunk)| {
            let mut rng = band_rng(seed, band);
            for (r, row) in chunk.chunks_mut(w).enumerate() {
                let y = band * BAND_ROWS + r;
                let src = clean.row(y);
                for (x, (o, &c)) in row.iter_mut().zip(src.iter()).enumerate() {
                    *o = sampler.noisy(position(y, x), c, rng.next_u32());
                }
            }
        });
    }
    Array2::from_shape_vec((h, w), out).expect("h × w samples")
}

/// As [`synthesize`], for a clean image with fractional levels (e.g. rendered from HDR data):
/// the bin and the base level are `round(clean)`.
pub fn synthesize_f32(sampler: &IsoSampler, clean: ArrayView2<'_, f32>, seed: u64) -> Array2<u16> {
    let rounded = clean.mapv(|v| v.round().clamp(0.0, sampler.white as f32) as u16);
    synthesize(sampler, rounded.view(), seed)
}
