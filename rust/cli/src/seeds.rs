//! The seed of each file of a folder run: one rule for `noisecal synth`/`renoise` on a folder,
//! the Python package (`noisecal.seed_for`) and its Ray actor, so the same folder and seed give
//! the same bytes whichever tool drew them.
//!
//! A file's seed is a stable hash of its name (the final path component, as bytes: UTF-8 for
//! the names every tool shares) keyed by the run's seed: BLAKE2b (RFC 7693) with an 8-byte
//! digest and the run's seed as its 8-byte little-endian key, the digest read little-endian.
//! That is Python's `hashlib.blake2b(name, digest_size=8, key=seed.to_bytes(8, "little"))`, so
//! any language with BLAKE2b reproduces it. A file keeps its seed when others are added to or
//! removed from the folder, and a folder run equals single-file runs with `--seed
//! seed_for(name, seed)`. The older rule, `seed + index` in sorted file order, is
//! [`SeedBy::Index`] (`--seed-by index`).

use std::path::Path;

/// How a folder run seeds its files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, clap::ValueEnum)]
pub enum SeedBy {
    /// `seed_for(file name, seed)`: stable when the folder changes; the Python package's rule.
    #[default]
    Name,
    /// `seed + i` for the i-th file in sorted order (the rule before; a batch of `Pack.synth`).
    Index,
}

impl SeedBy {
    /// The seed of file `index` (sorted order) at `path`, in a run seeded with `seed`.
    pub fn seed(self, seed: u64, index: usize, path: &Path) -> u64 {
        match self {
            Self::Name => seed_for(path.file_name().map(|n| n.as_encoded_bytes()).unwrap_or_default(), seed),
            Self::Index => seed.wrapping_add(index as u64),
        }
    }
}

/// The seed of a key (a file name) in a run seeded with `seed`: the first 8 bytes of
/// BLAKE2b-64 of `key` keyed by `seed` (8 bytes, little-endian), little-endian.
pub fn seed_for(key: &[u8], seed: u64) -> u64 {
    let mut h = Blake2b::new(8, &seed.to_le_bytes());
    h.update(key);
    h.finish()
}

const IV: [u64; 8] = [
    0x6a09e667f3bcc908,
    0xbb67ae8584caa73b,
    0x3c6ef372fe94f82b,
    0xa54ff53a5f1d36f1,
    0x510e527fade682d1,
    0x9b05688c2b3e6c1f,
    0x1f83d9abfb41bd6b,
    0x5be0cd19137e2179,
];

const SIGMA: [[usize; 16]; 10] = [
    [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15],
    [14, 10, 4, 8, 9, 15, 13, 6, 1, 12, 0, 2, 11, 7, 5, 3],
    [11, 8, 12, 0, 5, 2, 15, 13, 10, 14, 3, 6, 7, 1, 9, 4],
    [7, 9, 3, 1, 13, 12, 11, 14, 2, 6, 5, 10, 4, 0, 15, 8],
    [9, 0, 5, 7, 2, 4, 10, 15, 14, 1, 11, 12, 6, 8, 3, 13],
    [2, 12, 6, 10, 0, 11, 8, 3, 4, 13, 7, 5, 15, 14, 1, 9],
    [12, 5, 1, 15, 14, 13, 4, 10, 0, 7, 6, 3, 9, 2, 8, 11],
    [13, 11, 7, 14, 12, 1, 3, 9, 5, 0, 15, 4, 8, 6, 2, 10],
    [6, 15, 14, 9, 11, 3, 0, 8, 12, 2, 13, 7, 1, 4, 10, 5],
    [10, 2, 8, 4, 7, 6, 1, 5, 15, 11, 9, 14, 3, 12, 13, 0],
];

/// BLAKE2b (RFC 7693) with a digest of at most 8 bytes: all a seed needs.
struct Blake2b {
    h: [u64; 8],
    /// Bytes hashed so far (compressed blocks).
    t: u128,
    buf: [u8; 128],
    len: usize,
    digest: usize,
}

impl Blake2b {
    fn new(digest: usize, key: &[u8]) -> Self {
        debug_assert!((1..=8).contains(&digest) && key.len() <= 64);
        let mut h = IV;
        h[0] ^= 0x0101_0000 ^ ((key.len() as u64) << 8) ^ digest as u64;
        let mut s = Self { h, t: 0, buf: [0; 128], len: 0, digest };
        if !key.is_empty() {
            s.buf[..key.len()].copy_from_slice(key);
            s.len = 128;
        }
        s
    }

    fn update(&mut self, mut data: &[u8]) {
        while !data.is_empty() {
            if self.len == 128 {
                // A full block is compressed only once more input follows: the last one is final.
                self.t += 128;
                let block = self.buf;
                self.compress(&block, false);
                self.len = 0;
            }
            let n = (128 - self.len).min(data.len());
            self.buf[self.len..self.len + n].copy_from_slice(&data[..n]);
            self.len += n;
            data = &data[n..];
        }
    }

    fn finish(mut self) -> u64 {
        self.t += self.len as u128;
        let mut block = [0u8; 128];
        block[..self.len].copy_from_slice(&self.buf[..self.len]);
        self.compress(&block, true);
        let bytes = self.h[0].to_le_bytes();
        let mut out = [0u8; 8];
        out[..self.digest].copy_from_slice(&bytes[..self.digest]);
        u64::from_le_bytes(out)
    }

    fn compress(&mut self, block: &[u8; 128], last: bool) {
        let m: [u64; 16] = std::array::from_fn(|i| {
            let mut w = [0u8; 8];
            w.copy_from_slice(&block[8 * i..8 * i + 8]);
            u64::from_le_bytes(w)
        });
        let mut v = [0u64; 16];
        v[..8].copy_from_slice(&self.h);
        v[8..].copy_from_slice(&IV);
        v[12] ^= self.t as u64;
        v[13] ^= (self.t >> 64) as u64;
        if last {
            v[14] = !v[14];
        }
        for r in 0..12 {
            let s = &SIGMA[r % 10];
            g(&mut v, 0, 4, 8, 12, m[s[0]], m[s[1]]);
            g(&mut v, 1, 5, 9, 13, m[s[2]], m[s[3]]);
            g(&mut v, 2, 6, 10, 14, m[s[4]], m[s[5]]);
            g(&mut v, 3, 7, 11, 15, m[s[6]], m[s[7]]);
            g(&mut v, 0, 5, 10, 15, m[s[8]], m[s[9]]);
            g(&mut v, 1, 6, 11, 12, m[s[10]], m[s[11]]);
            g(&mut v, 2, 7, 8, 13, m[s[12]], m[s[13]]);
            g(&mut v, 3, 4, 9, 14, m[s[14]], m[s[15]]);
        }
        for i in 0..8 {
            self.h[i] ^= v[i] ^ v[i + 8];
        }
    }
}

fn g(v: &mut [u64; 16], a: usize, b: usize, c: usize, d: usize, x: u64, y: u64) {
    v[a] = v[a].wrapping_add(v[b]).wrapping_add(x);
    v[d] = (v[d] ^ v[a]).rotate_right(32);
    v[c] = v[c].wrapping_add(v[d]);
    v[b] = (v[b] ^ v[c]).rotate_right(24);
    v[a] = v[a].wrapping_add(v[b]).wrapping_add(y);
    v[d] = (v[d] ^ v[a]).rotate_right(16);
    v[c] = v[c].wrapping_add(v[d]);
    v[b] = (v[b] ^ v[c]).rotate_right(63);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Python's `noisecal.seed_for` (hashlib's BLAKE2b) on the same keys.
    #[test]
    fn equals_pythons_seed_for() {
        assert_eq!(seed_for(b"f00000.dng", 0), 15051219569181496992);
        assert_eq!(seed_for(b"img_0001.dng", 7), 1079507364089641411);
        assert_eq!(seed_for(b"", 0), 4331143152044847043);
        // More than one block of input, and the largest key.
        assert_eq!(seed_for(&[b'x'; 200], u64::MAX), 4870422386021949646);
        assert_eq!(seed_for("ä.dng".as_bytes(), 11), 6646802087109855594);
    }

    #[test]
    fn folder_rules() {
        let p = Path::new("/data/in/img_0001.dng");
        assert_eq!(SeedBy::Name.seed(7, 3, p), seed_for(b"img_0001.dng", 7));
        assert_eq!(SeedBy::Index.seed(7, 3, p), 10);
        assert_eq!(SeedBy::Index.seed(u64::MAX, 1, p), 0);
    }
}
