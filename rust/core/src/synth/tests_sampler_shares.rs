//! Tables kept in blocks ([`BinTable::in_blocks`]) against the per-DN table of the same bin:
//! each value's weight within its block's mass over 65 535 (so the total variation within
//! `(BLOCK − 1)/(2·65 535)`), no weight where the per-DN table has none, the blocks' ends exactly
//! the per-DN table's, and every draw the inverse CDF of the weights the blocks report.

use super::shares::BLOCK;
use super::*;
use crate::model::bin_source::BinSource;
use rand::SeedableRng;

fn bin(first: i32, counts: Vec<u64>) -> BinModel {
    BinModel { first, counts, samples: 1000, source: BinSource::Measured, measured: None, clipped: false, grid_step: 0 }
}

/// Weights of every shape a deconvolved table has: smooth bodies with floor-count tails, combs
/// (every other code, or blocks of four high and four low, random sensor 0's ISO 4000), steep
/// edges, zeros at the ends and inside, a single spike, lengths off the block size, and totals in
/// each of [`cdf_of`]'s three ways of dividing.
fn shapes() -> Vec<Vec<u64>> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
    let mut out = Vec::new();
    for &(len, scale) in &[(64usize, 1e6), (65, 1e9), (300, 1e12), (1001, 3e8), (4000, 1e14), (70_000, 1e9)] {
        let sd = len as f64 / 9.0;
        let body = |i: usize| {
            let x = (i as f64 - len as f64 * 0.45) / sd;
            (scale * (-0.5 * x * x).exp()) as u64
        };
        out.push((0..len).map(|i| body(i) + rng.next_u32() as u64 % 3).collect());
        out.push((0..len).map(|i| if i % 2 == 0 { body(i) } else { 0 }).collect());
        out.push((0..len).map(|i| if (i / 4) % 2 == 0 { body(i) } else { body(i) / 18 }).collect());
        out.push((0..len).map(|i| if i < len / 3 || i > len - 7 { 0 } else { body(i) + 1 }).collect());
        out.push((0..len).map(|i| if rng.next_u32() % 5 == 0 { 0 } else { body(i) }).collect());
        let mut spike = vec![0u64; len];
        spike[len / 2] = scale as u64;
        spike[len / 2 + 1] = 1;
        out.push(spike);
    }
    out
}

#[test]
fn blocks_draw_within_their_bound_of_the_entries() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
    let (mut tables, mut draws, mut largest) = (0usize, 0usize, 0u64);
    let bound = ((BLOCK as u64 - 1) << 32).div_ceil(2 * 65_535);
    for w in shapes() {
        let b = bin(-17, w.clone());
        let entries = BinTable::with_guide(&b, Guide::Dense);
        let (blocks, reported) = BinTable::of_blocks(b.first, &entries.cdf()).expect("a table of 64 entries or more");
        assert!(blocks.is_blocks());
        assert_eq!((blocks.first(), blocks.len()), (entries.first(), entries.len()));
        let (exact, kept) = (entries.cdf(), blocks.cdf());
        // The blocks' ends are the per-DN table's; inside, each cumulative weight within the
        // block's mass over 65 535 (a share rounded down, or to 2⁻¹⁶ of 2³², would move values
        // by up to twice that and fail here).
        let mut twice = 0u64;
        for i in 0..exact.len() {
            let blk = i / BLOCK;
            let lo = if blk == 0 { 0 } else { exact[blk * BLOCK - 1] };
            let hi = exact[((blk + 1) * BLOCK).min(exact.len()) - 1];
            if i % BLOCK == BLOCK - 1 || i + 1 == exact.len() {
                assert_eq!(kept[i], exact[i], "end of block {blk}");
            }
            assert!(
                kept[i].abs_diff(exact[i]) <= (hi - lo).div_ceil(2 * 65_535) + 1,
                "entry {i}: {} against {}",
                kept[i],
                exact[i]
            );
            let (we, wk) =
                (exact[i] - if i == 0 { 0 } else { exact[i - 1] }, kept[i] - if i == 0 { 0 } else { kept[i - 1] });
            assert!(we > 0 || wk == 0, "entry {i} has no weight and is drawn");
            twice += we.abs_diff(wk);
        }
        let tv = twice.div_ceil(2);
        assert_eq!(tv, reported, "the total variation the blocks report");
        assert!(tv <= bound, "total variation {tv} > {bound} (units of 2⁻³²)");
        largest = largest.max(tv);
        // Every draw is the inverse CDF of the weights the blocks report: at each boundary, either
        // side of it, and on random draws (a count of shares off by one draws the next value).
        let reference = |u: u32| -17 + kept.partition_point(|&c| c <= u as u64) as i32;
        let mut us: Vec<u32> =
            kept.iter().flat_map(|&c| [c.wrapping_sub(1), c, c + 1]).map(|c| c.min(u32::MAX as u64) as u32).collect();
        us.extend([0, 1, u32::MAX, u32::MAX - 1]);
        us.extend((0..5000).map(|_| rng.next_u32()));
        for u in us {
            assert_eq!(blocks.sample_u32(u), reference(u), "u {u}, {} entries", w.len());
            draws += 1;
        }
        // About 2.2 bytes per entry (4 per block's end, 30 of shares, the blocks' guide), against
        // 5 to 6 per DN; the fixed cost counted for the shortest.
        assert!(
            blocks.heap_bytes() * 10 <= 24 * w.len() + 2000,
            "{} bytes for {} entries (per DN: {})",
            blocks.heap_bytes(),
            w.len(),
            entries.heap_bytes()
        );
        tables += 1;
    }
    assert!(tables >= 36 && draws > 500_000, "{tables} tables, {draws} draws");
    assert!(largest > 0, "the blocks moved no weight: the comparison cannot fail");
    // Too short to save bytes, beyond the bound, or drawing unlike the per-DN table at a frame's
    // draws: kept per DN.
    assert!(BinTable::in_blocks(&bin(0, vec![1; BLOCK * 4 - 1]), u64::MAX).is_none());
    assert!(BinTable::in_blocks(&bin(0, (0..300).map(|i| 1 + i % 7).collect()), 0).is_none());
    assert!(BinTable::in_blocks(&bin(0, (0..300).map(|i| 1 + i % 7).collect()), u64::MAX).is_some());
}
