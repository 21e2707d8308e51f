//! What a sampler table layout of fewer bits per entry would cost: for each ISO of a pack, the
//! exact tables' bytes, how many entries sit in the body of their PMFs (cumulative weight
//! between 2⁻¹² and 1 − 2⁻¹²) and how many tables are alike (exact layouts can share only
//! those); then, for an inexact layout that keeps the draws' quantiles on a grid of `M` cells
//! (each cell's mass spread evenly over the values between its two ends, the outermost cells
//! refined geometrically down to 2⁻³²), its bytes and its divergence from the exact draws per
//! bin: Jensen–Shannon divergence, variance ratio and the 0.1 % / 99.9 % quantiles.
//!
//!     cargo run --release -p noisecal-core --example table_layouts -- some.pack [M …]

use std::collections::HashSet;

use noisecal_core::ModelPack;
use noisecal_core::derive::interp::model_for;
use noisecal_core::synth::sampler::{Guide, IsoSampler};

const ONE: f64 = 4294967296.0;

/// The PMF a quantile grid of `m` cells (`m` a power of two) draws, from the exact cumulative
/// weights `cdf` (units of 2⁻³², the last 2³²). Returns the PMF over the same values and the
/// grid's entries (2 bytes each).
fn grid_pmf(cdf: &[u64], m: u64) -> (Vec<f64>, usize) {
    let quantile = |u: u64| cdf.partition_point(|&c| c <= u);
    // Grid points: 0, the geometric refinements of the first cell, the body, those of the last.
    let cell = (1u64 << 32) / m;
    let mut pts: Vec<u64> = vec![0];
    let mut k = 1u64;
    while k < cell {
        pts.push(k);
        k <<= 1;
    }
    pts.extend((1..m).map(|j| j * cell));
    let mut k = cell >> 1;
    while k >= 1 {
        pts.push((1u64 << 32) - k);
        k >>= 1;
    }
    pts.push(1u64 << 32);
    let mut q = vec![0.0; cdf.len()];
    for w in pts.windows(2) {
        let (a, b) = (w[0], w[1]);
        let (lo, hi) = (quantile(a), quantile(b - 1));
        let share = (b - a) as f64 / ONE / (hi - lo + 1) as f64;
        for v in &mut q[lo..=hi] {
            *v += share;
        }
    }
    (q, pts.len())
}

fn moments(p: &[f64]) -> (f64, f64) {
    let m: f64 = p.iter().enumerate().map(|(i, w)| i as f64 * w).sum();
    (m, p.iter().enumerate().map(|(i, w)| (i as f64 - m).powi(2) * w).sum())
}

fn quantile(p: &[f64], at: f64) -> usize {
    let mut acc = 0.0;
    for (i, w) in p.iter().enumerate() {
        acc += w;
        if acc >= at {
            return i;
        }
    }
    p.len() - 1
}

fn jsd(p: &[f64], q: &[f64]) -> f64 {
    let kl = |a: f64, m: f64| if a > 0.0 { a * (a / m).ln() } else { 0.0 };
    p.iter().zip(q).map(|(&a, &b)| 0.5 * (kl(a, 0.5 * (a + b)) + kl(b, 0.5 * (a + b)))).sum::<f64>() / 2f64.ln()
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let pack = ModelPack::from_bytes(&std::fs::read(&args[1]).expect("pack file")).expect("a pack");
    let grids: Vec<u64> = args[2..].iter().map(|s| s.parse().expect("M")).collect();
    for iso in pack.isos.iter().map(|m| m.iso) {
        let (model, _) = model_for(&pack, iso, false).expect("model");
        let s = IsoSampler::new(&pack, &model);
        let tables: Vec<_> = (0..4).flat_map(|p| s.tables(p).iter()).collect();
        let bytes: usize = tables.iter().map(|t| t.heap_bytes()).sum();
        let entries: usize = tables.iter().map(|t| t.len()).sum();
        let cdfs: Vec<Vec<u64>> = tables.iter().map(|t| t.cdf()).collect();
        let body: usize = cdfs.iter().flatten().filter(|&&c| c > 1 << 20 && c < (1u64 << 32) - (1 << 20)).count();
        let distinct: HashSet<(i32, &Vec<u64>)> = tables.iter().zip(&cdfs).map(|(t, c)| (t.first(), c)).collect();
        let with = |g: Guide| tables.iter().map(|t| g.table_bytes(t.len())).sum::<usize>() as f64 / 1e6;
        println!(
            "ISO {iso}: {} tables, {entries} entries, {:.2} MB exact (guide of a cell per four entries {:.2} MB, per two {:.2} MB); {:.0} % of entries in the body; {} distinct tables",
            tables.len(),
            bytes as f64 / 1e6,
            with(Guide::Sparse),
            with(Guide::Dense),
            100.0 * body as f64 / entries as f64,
            distinct.len()
        );
        for &m in &grids {
            let (mut grid_bytes, mut js, mut var, mut q_lo, mut q_hi) = (0usize, vec![], vec![], 0i64, 0i64);
            for (t, c) in tables.iter().zip(&cdfs) {
                let p: Vec<f64> =
                    c.iter().enumerate().map(|(i, &v)| (v - if i == 0 { 0 } else { c[i - 1] }) as f64 / ONE).collect();
                let (q, n) = grid_pmf(c, m);
                // A table no larger than its grid stays exact.
                if t.heap_bytes() <= 2 * n {
                    grid_bytes += t.heap_bytes();
                    js.push(0.0);
                    var.push(1.0);
                    continue;
                }
                grid_bytes += 2 * n;
                js.push(jsd(&p, &q));
                var.push(moments(&q).1 / moments(&p).1.max(1e-12));
                q_lo = q_lo.max((quantile(&q, 0.001) as i64 - quantile(&p, 0.001) as i64).abs());
                q_hi = q_hi.max((quantile(&q, 0.999) as i64 - quantile(&p, 0.999) as i64).abs());
            }
            js.sort_by(f64::total_cmp);
            var.sort_by(f64::total_cmp);
            println!(
                "  grid of {m} cells: {:.2} MB; JSD median {:.1e} max {:.1e}; variance ratio {:.5}–{:.5}; 0.1 % / 99.9 % quantiles off by at most {q_lo} / {q_hi} DN",
                grid_bytes as f64 / 1e6,
                js[js.len() / 2],
                js[js.len() - 1],
                var[0],
                var[var.len() - 1]
            );
        }
    }
}
