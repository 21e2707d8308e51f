//! What the DNG integration tests share: deterministic pseudo-random pixels and bytes.

use ndarray::Array2;

/// Deterministic xorshift64* noise, so the tests need no RNG crate.
pub struct Rng(pub u64);

impl Rng {
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
}

/// A `h × w` image of values `0..=max`, the same for the same seed.
pub fn random_pixels(w: usize, h: usize, max: u16, seed: u64) -> Array2<u16> {
    let mut rng = Rng(seed | 1);
    Array2::from_shape_fn((h, w), |_| (rng.next() % (max as u64 + 1)) as u16)
}
