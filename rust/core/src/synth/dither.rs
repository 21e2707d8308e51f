//! The dither draws of one row of a structured synthesis ([`super::structured_filler`]): a
//! xorshift64* stream seeded per row, one 64-bit draw per pair of pixels (and one for the last
//! pixel of an odd width). The stream is drawn in [`CHAINS`] independent chains, each starting
//! where the serial stream reaches its share of the row (a jump ahead by a power of the
//! generator's matrix over GF(2)), so the draws are the serial stream's, bit for bit (tested),
//! without one chain of dependent shifts and XORs per row: the serial loop waited on that chain
//! (six dependent operations per draw), the chains run side by side.

/// Chains a row's draws are split into.
const CHAINS: usize = 4;
/// The multiplier of xorshift64*.
const MULTIPLIER: u64 = 0x2545_F491_4F6C_DD1D;

/// One step of the xorshift64 state (the stream's draw is the new state times [`MULTIPLIER`]).
#[inline(always)]
fn step(mut s: u64) -> u64 {
    s ^= s >> 12;
    s ^= s << 25;
    s ^= s >> 27;
    s
}

/// A linear map of 64-bit states over GF(2): column `b` is the image of bit `b`.
#[derive(Debug, Clone)]
struct Linear([u64; 64]);

impl Linear {
    /// The map of `steps` xorshift steps.
    fn of_steps(mut steps: usize) -> Self {
        let mut result = Linear(std::array::from_fn(|b| 1u64 << b));
        let mut power = Linear(std::array::from_fn(|b| step(1u64 << b)));
        while steps > 0 {
            if steps & 1 == 1 {
                result = power.after(&result);
            }
            power = power.after(&power);
            steps >>= 1;
        }
        result
    }

    /// `self ∘ first`: `first`, then `self`.
    fn after(&self, first: &Linear) -> Linear {
        Linear(std::array::from_fn(|b| self.apply(first.0[b])))
    }

    /// The image of state `s`.
    #[inline]
    fn apply(&self, s: u64) -> u64 {
        self.0.iter().enumerate().fold(0u64, |acc, (b, &col)| acc ^ (col & 0u64.wrapping_sub((s >> b) & 1)))
    }
}

/// The draws of rows of `draws` dithers each: the jump from one chain's start to the next.
#[derive(Debug, Clone)]
pub(crate) struct RowDither {
    draws: usize,
    /// Draws per chain (the last chain's share may run past the row: drawn, not read).
    per_chain: usize,
    jump: Linear,
}

impl RowDither {
    /// For rows of `draws` dither draws.
    pub(crate) fn new(draws: usize) -> Self {
        let per_chain = draws.div_ceil(CHAINS);
        Self { draws, per_chain, jump: Linear::of_steps(per_chain) }
    }

    /// The row's draws from the state `state` into `out` (its first `draws` entries are the
    /// serial stream's: draw `j` is `step^(j + 1)(state) × MULTIPLIER`).
    pub(crate) fn fill(&self, state: u64, out: &mut Vec<u64>) {
        let n = self.per_chain;
        out.clear();
        out.resize(n * CHAINS, 0);
        if n == 0 {
            return;
        }
        let mut s = [state; CHAINS];
        for c in 1..CHAINS {
            s[c] = self.jump.apply(s[c - 1]);
        }
        let (a, rest) = out.split_at_mut(n);
        let (b, rest) = rest.split_at_mut(n);
        let (c, d) = rest.split_at_mut(n);
        for (((a, b), c), d) in a.iter_mut().zip(b.iter_mut()).zip(c.iter_mut()).zip(d.iter_mut()) {
            s = [step(s[0]), step(s[1]), step(s[2]), step(s[3])];
            *a = s[0].wrapping_mul(MULTIPLIER);
            *b = s[1].wrapping_mul(MULTIPLIER);
            *c = s[2].wrapping_mul(MULTIPLIER);
            *d = s[3].wrapping_mul(MULTIPLIER);
        }
        out.truncate(self.draws);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{RngExt, SeedableRng};

    /// The serial stream: what the row loop drew one after the other.
    fn serial(mut state: u64, n: usize) -> Vec<u64> {
        (0..n)
            .map(|_| {
                state = step(state);
                state.wrapping_mul(MULTIPLIER)
            })
            .collect()
    }

    /// Every draw is the serial stream's, for row lengths from 0 to 5 000 draws (every length up
    /// to 70, where the chains' shares are uneven or empty) and random odd states. A jump by the
    /// wrong power, or the matrix applied transposed, differs from the second chain on.
    #[test]
    fn chains_are_the_serial_stream_bit_for_bit() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(12);
        let mut buf = Vec::new();
        let mut checked = 0usize;
        let lengths = (0..70).chain((0..40).map(|_| rng.random_range(70..5_000usize)));
        for n in lengths.collect::<Vec<_>>() {
            let state = rng.random::<u64>() | 1;
            let d = RowDither::new(n);
            d.fill(state, &mut buf);
            assert_eq!(buf.len(), n);
            assert_eq!(buf, serial(state, n), "{n} draws");
            checked += n;
        }
        assert!(checked > 50_000, "{checked} draws");
    }

    /// The jump matrix composes: `n` steps then `m` are `n + m` steps, and one step is the
    /// generator's.
    #[test]
    fn jumps_compose() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
        for _ in 0..50 {
            let s = rng.random::<u64>();
            let (n, m) = (rng.random_range(0..3000usize), rng.random_range(0..3000usize));
            let two = Linear::of_steps(m).apply(Linear::of_steps(n).apply(s));
            assert_eq!(two, Linear::of_steps(n + m).apply(s));
            assert_eq!(Linear::of_steps(1).apply(s), step(s));
            assert_eq!(Linear::of_steps(0).apply(s), s);
        }
    }
}
