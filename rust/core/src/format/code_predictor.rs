//! How pack versions 7, 8 and 9 write a bin's weight codes ([`super::weight_code`]): each code
//! less a guess from the codes before it, as zigzagged LEB128 varints, with whichever
//! [`Predictor`] guesses the bin in the fewest bytes named before them. The versions differ only
//! in what "the previous bin's slope at this cell" is (version 7: per DN at the same noise value;
//! 8 and 9: summed over a cell of the bin's grid), which the caller gives as `above(i)`. Part of
//! all three formats' bytes: a change here is a format change.

use crate::format::codec::{get_varint, put_varint, unzigzag, zigzag};

/// How a cell's code is guessed from what came before it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Predictor {
    /// The previous cell's code plus the previous bin's slope at this noise value (a PMF that
    /// changes little from bin to bin, spikes of a code lattice included).
    Above = 0,
    /// The previous cell's code (a smooth PMF kept to few bits: runs of equal codes).
    Previous = 1,
    /// The previous cell's code plus the slope before it (a smooth PMF kept to many bits).
    Linear = 2,
}

impl Predictor {
    const ALL: [Predictor; 3] = [Predictor::Above, Predictor::Previous, Predictor::Linear];

    pub(super) fn from_id(id: u64) -> Option<Self> {
        Self::ALL.into_iter().find(|p| *p as u64 == id)
    }

    /// The guess of the code after `codes`, `above` the previous bin's slope there.
    fn guess(self, codes: &[u64], above: u64) -> u64 {
        let last = codes.last().copied().unwrap_or(0);
        match self {
            Predictor::Above => last.wrapping_add(above),
            Predictor::Previous => last,
            Predictor::Linear => match codes {
                [.., a, b] => b.wrapping_add(b.wrapping_sub(*a)),
                _ => last,
            },
        }
    }
}

/// `codes` written with the predictor that takes the fewest bytes (the lowest id of those that
/// tie), and that predictor. `above(i)` is the previous bin's slope at cell `i`.
pub(super) fn write_codes(codes: &[u64], above: impl Fn(usize) -> u64) -> (Predictor, Vec<u8>) {
    let coded = |predictor: Predictor| {
        let mut bytes = Vec::new();
        for (i, &c) in codes.iter().enumerate() {
            put_varint(&mut bytes, zigzag(c.wrapping_sub(predictor.guess(&codes[..i], above(i))) as i64));
        }
        bytes
    };
    Predictor::ALL
        .into_iter()
        .map(|p| (p, coded(p)))
        .min_by_key(|(p, bytes)| (bytes.len(), *p as u8))
        .expect("predictors")
}

/// The `n` codes `predictor` wrote at `*at` of `weights` (`above` as for [`write_codes`]), or
/// `None` where the bytes end inside one. The caller has checked that `n` cells can fit.
pub(super) fn read_codes(
    weights: &[u8],
    at: &mut usize,
    n: usize,
    predictor: Predictor,
    above: impl Fn(usize) -> u64,
) -> Option<Vec<u64>> {
    let mut codes = Vec::with_capacity(n);
    for i in 0..n {
        let z = get_varint(weights, at)?;
        let guess = predictor.guess(&codes, above(i));
        codes.push(guess.wrapping_add(unzigzag(z) as u64));
    }
    Some(codes)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Codes round-trip through every predictor, whatever the slopes (wrapping included), and
    /// the writer picks the shortest: a run of equal codes by `Previous`, a ramp by `Linear`, a
    /// copy of the slopes by `Above`.
    #[test]
    fn codes_round_trip_and_the_shortest_predictor_is_chosen() {
        let slopes = |i: usize| (i as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15);
        let cases: [(Vec<u64>, Predictor); 3] = [
            (vec![5_000; 40], Predictor::Previous),
            ((0..40).map(|i| 1_000 + 700 * i).collect(), Predictor::Linear),
            (
                (0..40usize).scan(0u64, |c, i| Some(std::mem::replace(c, c.wrapping_add(slopes(i + 1))))).collect(),
                Predictor::Above,
            ),
        ];
        for (codes, want) in cases {
            let (p, bytes) = write_codes(&codes, slopes);
            assert_eq!(p, want, "{codes:?}");
            for q in Predictor::ALL {
                let mut out = Vec::new();
                for (i, &c) in codes.iter().enumerate() {
                    put_varint(&mut out, zigzag(c.wrapping_sub(q.guess(&codes[..i], slopes(i))) as i64));
                }
                let mut at = 0;
                assert_eq!(read_codes(&out, &mut at, codes.len(), q, slopes).as_deref(), Some(&codes[..]));
                assert_eq!(at, out.len());
            }
            let mut at = 0;
            assert_eq!(read_codes(&bytes[..bytes.len() - 1], &mut at, codes.len(), p, slopes), None, "cut short");
        }
    }
}
