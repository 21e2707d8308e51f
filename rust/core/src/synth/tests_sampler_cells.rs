//! Tables drawn from a coarse grid's cells ([`Layout::Cells`]) against the per-DN table of the
//! same bin: the same cumulative weights at every DN and the same value for every draw tested
//! (each DN's boundary, the draws either side of it, and random ones).

use super::*;
use crate::model::bin_source::BinSource;
use crate::model::coarse_grid::GRID_STEPS;
use crate::model::coarse_grid::expand;
use rand::SeedableRng;

/// A bin of weights `counts` the pack keeps on a grid of `k` DN (0: per DN).
fn bin(first: i32, counts: Vec<u64>, k: usize) -> BinModel {
    BinModel {
        first,
        counts,
        samples: 1000,
        source: BinSource::Measured,
        measured: None,
        clipped: false,
        grid_step: k as u16,
    }
}

/// Cell masses of every shape the sampler meets: smooth bodies with floor-count tails, empty
/// cells inside and at the ends, a single spike, totals below and above 2³² (the per-DN table's
/// three ways of dividing) and masses past 40 significant bits (the shape then drops bits).
fn grids() -> Vec<(Vec<u64>, usize)> {
    let mut state = 0x9E37_79B9_7F4A_7C15u64;
    let mut next = move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        state
    };
    let mut out = vec![(vec![5u64], 2), (vec![0, 7, 0], 4), (vec![1, 1, 1, 1], 128), (vec![0, 0, 1 << 30, 0], 8)];
    for &(cells, scale) in &[(3usize, 1u64 << 10), (40, 1 << 30), (200, 1 << 20), (90, 1 << 40), (64, 1 << 52), (17, 3)]
    {
        for &k in &GRID_STEPS {
            let masses = (0..cells)
                .map(|j| {
                    let x = (j as f64 - cells as f64 / 2.5) / (cells as f64 / 7.0);
                    let body = ((-0.5 * x * x).exp() * scale as f64) as u64;
                    match next() % 10 {
                        0 => 0,
                        1 => 1 + next() % 3,
                        _ => body + next() % (1 + body / 64),
                    }
                })
                .collect();
            out.push((masses, k));
        }
    }
    out
}

#[test]
fn cells_draw_what_the_entries_draw() {
    let mut checked = 0u64;
    let mut as_cells = 0;
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    for (masses, k) in grids() {
        let b = bin(-(masses.len() as i32) * k as i32 / 3, expand(&masses, k), k);
        let entries = BinTable::with_guide(&b, Guide::Dense);
        let cells = BinTable::with_layout(&b, Layout::Cells(Guide::Dense));
        if !cells.is_cells() {
            // No mass: the entries, unchanged.
            assert!(masses.iter().all(|&m| m == 0), "{} cells of {k} not drawn from cells", masses.len());
            assert_eq!(cells, entries);
            continue;
        }
        as_cells += 1;
        assert_eq!(cells.len(), entries.len());
        let cdf = entries.cdf();
        assert_eq!(cells.cdf(), cdf, "cumulative weights, {} cells of {k}", masses.len());
        let mut us: Vec<u32> =
            cdf.iter().flat_map(|&c| [c.wrapping_sub(1), c, c + 1]).map(|c| c.min(u32::MAX as u64) as u32).collect();
        us.extend([0, 1, u32::MAX, u32::MAX - 1]);
        us.extend((0..2000).map(|_| rng.next_u32()));
        // The guide of a cell per four cells draws the same (a guide cell one past its start, or
        // a walk that stops short, would draw a later or an earlier value).
        let sparse = cells.clone().with_cell_guide(Guide::Sparse);
        assert_eq!(sparse.cdf(), cdf);
        assert_eq!(sparse.heap_bytes(), cells.bytes_with_cell_guide(Guide::Sparse));
        assert_eq!(cells.heap_bytes(), cells.bytes_with_cell_guide(Guide::Dense));
        assert!(sparse.heap_bytes() < cells.heap_bytes() || masses.len() <= 8, "{} cells", masses.len());
        for u in us {
            let want = entries.sample_u32(u);
            assert_eq!(cells.sample_u32(u), want, "u {u}, {} cells of {k}", masses.len());
            assert_eq!(sparse.sample_u32(u), want, "u {u}, {} cells of {k}, sparse guide", masses.len());
            checked += 1;
        }
        assert!(
            cells.heap_bytes() * 2 <= entries.heap_bytes() || k <= 4 || masses.len() < 8,
            "{} against {}",
            cells.heap_bytes(),
            entries.heap_bytes()
        );
    }
    assert!(as_cells >= 30, "{as_cells} tables drawn from cells");
    assert!(checked > 100_000, "{checked} draws");
}
