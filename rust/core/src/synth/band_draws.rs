//! A band stream's draws for one row taken at once: `n` 64-bit draws in one copy out of the
//! block RNG's buffer, the values (and the stream's position after them) of `n` calls of
//! `next_u64`. Each call checks the buffer's index, reads two words and stores the index back in
//! memory, so a loop of calls carried that store and reload from pair to pair; a row's pixel
//! loop then reads its draws from a slice instead.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// The next `n` draws of `rng` into `out` (resized to `n`), as `n` calls of `next_u64` return
/// them. The block RNG hands out its 32-bit words in order, `next_u64` the next two as `lo | hi
/// << 32`, and `fill_bytes` the same words as little-endian bytes: read back as little-endian
/// 64-bit values, the bytes are those draws (tested from every offset in a block).
#[inline]
pub(crate) fn next_u64s(rng: &mut ChaCha8Rng, n: usize, out: &mut Vec<u64>) {
    // Every value is overwritten: only a longer row's buffer is zeroed (once per band).
    out.resize(n, 0);
    rng.fill_bytes(bytemuck::cast_slice_mut(out.as_mut_slice()));
    if cfg!(target_endian = "big") {
        out.iter_mut().for_each(|v| *v = u64::from_le(*v));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    /// A stream as a band's (`synth::band_rng`, not called: the test stays inside this file).
    fn band_rng(seed: u64, band: usize) -> ChaCha8Rng {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        rng.set_stream(band as u64);
        rng
    }

    /// From every word offset within and across the RNG's 64-word blocks (odd offsets by a
    /// 32-bit draw first), runs of 0 to 300 draws are the `next_u64` calls' values, and the
    /// stream goes on from the same place after them. A fill that swapped a draw's halves
    /// differs in every draw.
    #[test]
    fn draws_are_the_calls() {
        let mut checked = 0;
        for skip in 0..70 {
            for n in [0usize, 1, 2, 31, 32, 33, 63, 64, 65, 300] {
                let (mut a, mut b) = (band_rng(11, skip), band_rng(11, skip));
                for _ in 0..skip {
                    a.next_u32();
                    b.next_u32();
                }
                let want: Vec<u64> = (0..n).map(|_| a.next_u64()).collect();
                let mut got = vec![7; 3];
                next_u64s(&mut b, n, &mut got);
                assert_eq!(got, want, "skip {skip}, n {n}");
                assert_eq!(a.next_u64(), b.next_u64(), "the stream after them, skip {skip}, n {n}");
                checked += n;
            }
        }
        assert!(checked > 40_000);
        // What a wrong fill scores: halves swapped.
        let (mut a, mut b) = (band_rng(3, 0), band_rng(3, 0));
        let mut got = Vec::new();
        next_u64s(&mut b, 100, &mut got);
        assert!(got.iter().all(|&g| g.rotate_left(32) != a.next_u64()));
    }
}
