//! Deterministic mutations of seed inputs: bit flips, byte sets, truncation, splices, inserted and
//! deleted runs, length-field edits, and a repair of the CRC framing of recordings and packs so
//! that mutations reach past the checksums into the decoders behind them.

/// A small deterministic RNG (SplitMix64): the same seed gives the same run on any machine.
#[derive(Debug, Clone)]
pub struct Rng(u64);

impl Rng {
    pub fn new(seed: u64) -> Self {
        Self(seed ^ 0x9E37_79B9_7F4A_7C15)
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (`n` > 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next_u64() % n.max(1) as u64) as usize
    }

    pub fn chance(&mut self, one_in: usize) -> bool {
        self.below(one_in) == 0
    }
}

/// Values that break length and size fields.
const INTERESTING_32: [u32; 14] =
    [0, 1, 2, 3, 0x7f, 0x80, 0xff, 0x100, 0xffff, 0x1_0000, 0x7fff_ffff, 0x8000_0000, 0xffff_fffe, 0xffff_ffff];

/// Which framing a target's inputs have, for [`repair`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Framing {
    /// A record stream: `NCALREC\0`, header sealed by length and CRC, records `tag | payload | crc`.
    Recording,
    /// A sealed file: preamble, reserved, payload length u64, CRC, payload.
    Sealed,
    /// No checksums (DNG, JNI planes).
    None,
}

/// One mutated copy of `input`; `other` is another seed for splices.
pub fn mutate(rng: &mut Rng, input: &[u8], other: &[u8], framing: Framing, max_len: usize) -> Vec<u8> {
    let mut v = input.to_vec();
    let rounds = 1 + rng.below(4);
    for _ in 0..rounds {
        mutate_once(rng, &mut v, other);
    }
    v.truncate(max_len);
    if framing != Framing::None && !rng.chance(4) {
        repair(&mut v, framing);
    }
    v
}

fn mutate_once(rng: &mut Rng, v: &mut Vec<u8>, other: &[u8]) {
    if v.is_empty() {
        v.push(rng.next_u64() as u8);
        return;
    }
    let n = v.len();
    match rng.below(11) {
        // A flipped bit.
        0 | 1 => {
            let i = rng.below(n);
            v[i] ^= 1 << rng.below(8);
        }
        // A byte set to a random or boundary value.
        2 => {
            let i = rng.below(n);
            v[i] = [0, 0xff, 0x7f, 0x80, 1, rng.next_u64() as u8][rng.below(6)];
        }
        // A 32-bit little-endian field set to a boundary value, or nudged.
        3 | 4 => {
            if n >= 4 {
                let i = rng.below(n - 3);
                let old = u32::from_le_bytes([v[i], v[i + 1], v[i + 2], v[i + 3]]);
                let new = match rng.below(3) {
                    0 => INTERESTING_32[rng.below(INTERESTING_32.len())],
                    1 => old.wrapping_add(rng.below(33) as u32).wrapping_sub(16),
                    _ => old ^ (1 << rng.below(32)),
                };
                v[i..i + 4].copy_from_slice(&new.to_le_bytes());
            }
        }
        // A 16-bit field (TIFF types, counts, bit depths), big- or little-endian.
        5 => {
            if n >= 2 {
                let i = rng.below(n - 1);
                let val = [0u16, 1, 2, 8, 10, 12, 14, 16, 32, 0x7fff, 0xffff][rng.below(11)];
                let b = if rng.chance(2) { val.to_le_bytes() } else { val.to_be_bytes() };
                v[i..i + 2].copy_from_slice(&b);
            }
        }
        // Truncation.
        6 => {
            let keep = rng.below(n);
            v.truncate(keep);
        }
        // A run deleted.
        7 => {
            let i = rng.below(n);
            let len = 1 + rng.below((n - i).min(64));
            v.drain(i..i + len);
        }
        // A run of this input or of another inserted (duplicated records, spliced fields).
        8 | 9 => {
            let src: &[u8] = if rng.chance(2) && !other.is_empty() { other } else { v };
            let s = rng.below(src.len());
            let cap = if rng.chance(4) { 4096 } else { 64 };
            let len = 1 + rng.below((src.len() - s).min(cap));
            let chunk = src[s..s + len].to_vec();
            let at = rng.below(v.len() + 1);
            if rng.chance(2) {
                v.splice(at..at, chunk);
            } else {
                let end = (at + chunk.len()).min(v.len());
                v.splice(at..end, chunk);
            }
        }
        // Random bytes over a run.
        _ => {
            let i = rng.below(n);
            let len = 1 + rng.below((n - i).min(16));
            for b in &mut v[i..i + len] {
                *b = rng.next_u64() as u8;
            }
        }
    }
}

fn u32_at(v: &[u8], at: usize) -> Option<u32> {
    v.get(at..at + 4).map(|b| u32::from_le_bytes([b[0], b[1], b[2], b[3]]))
}

/// Rewrites the checksums (and a sealed file's payload length) so that the mutated content, not
/// the framing, is what the decoder sees. A version 9 pack (an index, then sections sealed by the
/// index) keeps its index length and has its sections' seals rewritten in the index when the
/// index still reads ([`noisecal_core::format::compact::reseal`]), else its index's CRC alone.
pub fn repair(v: &mut Vec<u8>, framing: Framing) {
    match framing {
        Framing::Sealed if v.len() >= 24 && v.starts_with(b"NCALPACK") && v[8..10] == 9u16.to_le_bytes() => {
            if let Some(resealed) = noisecal_core::format::compact::reseal(v) {
                *v = resealed;
            } else if let Some(len) = usize::try_from(u64::from_le_bytes(v[12..20].try_into().expect("8 bytes")))
                .ok()
                .filter(|&l| l <= v.len() - 24)
            {
                let crc = crc32fast::hash(&v[24..24 + len]);
                v[20..24].copy_from_slice(&crc.to_le_bytes());
            }
        }
        Framing::Sealed => {
            if v.len() >= 24 {
                let len = (v.len() - 24) as u64;
                v[12..20].copy_from_slice(&len.to_le_bytes());
                let crc = crc32fast::hash(&v[24..]);
                v[20..24].copy_from_slice(&crc.to_le_bytes());
            }
        }
        Framing::Recording => repair_recording(v),
        Framing::None => {}
    }
}

/// Walks a recording's records as the reader would and reseals each whole one.
fn repair_recording(v: &mut [u8]) {
    let Some(hlen) = u32_at(v, 10).map(|l| l as usize) else { return };
    let hend = 14usize.saturating_add(hlen);
    if hend + 4 > v.len() {
        return;
    }
    let crc = crc32fast::hash(&v[14..hend]);
    v[hend..hend + 4].copy_from_slice(&crc.to_le_bytes());
    let mut at = hend + 4;
    while at < v.len() {
        let fixed: usize = match v[at] {
            1 | 255 => 8,
            2 => 49,
            3 => 4 + 16 * 4,
            _ => return,
        };
        let mut len = 1 + fixed;
        if v[at] == 2 {
            let Some(data) = u32_at(v, at + 1 + 45) else { return };
            len = len.saturating_add(data as usize);
        }
        let end = at.saturating_add(len);
        if end + 4 > v.len() {
            return;
        }
        let crc = crc32fast::hash(&v[at..end]);
        v[end..end + 4].copy_from_slice(&crc.to_le_bytes());
        at = end + 4;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rng_is_deterministic_and_mutations_stay_bounded() {
        let mut a = Rng::new(7);
        let mut b = Rng::new(7);
        let seed: Vec<u8> = (0..200u8).collect();
        for _ in 0..2000 {
            let x = mutate(&mut a, &seed, &seed, Framing::Recording, 300);
            assert_eq!(x, mutate(&mut b, &seed, &seed, Framing::Recording, 300));
            assert!(x.len() <= 300);
        }
    }

    #[test]
    fn sealed_repair_matches_the_codec() {
        let mut v = vec![0u8; 24];
        v.extend_from_slice(b"payload");
        repair(&mut v, Framing::Sealed);
        assert_eq!(u64::from_le_bytes(v[12..20].try_into().expect("8 bytes")), 7);
        assert_eq!(u32_at(&v, 20), Some(crc32fast::hash(b"payload")));
    }

    /// A version 9 pack damaged in a section and repaired reaches the section's decoder: its
    /// checksums match again, and the file reads up to the damage.
    #[test]
    fn indexed_pack_repair_reseals_the_sections() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../tests/fuzz-corpus/pack");
        let good = std::fs::read(dir.join("two-isos-v9.pack")).expect("seed");
        noisecal_core::ModelPack::from_bytes(&good).expect("the seed loads");
        let mut v = good.clone();
        let n = v.len();
        v[n - 40] ^= 0x55;
        let before = noisecal_core::ModelPack::from_bytes(&v).expect_err("damaged").to_string();
        assert!(before.contains("checksum"), "{before}");
        repair(&mut v, Framing::Sealed);
        if let Err(e) = noisecal_core::ModelPack::from_bytes(&v) {
            assert!(!e.to_string().contains("checksum"), "{e}");
        }
        let mut same = good.clone();
        repair(&mut same, Framing::Sealed);
        assert_eq!(same, good, "an undamaged file is left as it is");
    }
}
