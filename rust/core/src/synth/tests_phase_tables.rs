use super::*;

/// The PMF of `round(X)`, `X ~ N(m, sd²)`, exactly (by a fine quadrature), from code `lo` on.
fn rounded_gaussian(m: f64, sd: f64, lo: i32, hi: i32) -> Vec<f64> {
    let n = 4000;
    let p: Vec<f64> = (lo..=hi)
        .map(|k| {
            (0..n)
                .map(|g| {
                    let x = k as f64 - 0.5 + (g as f64 + 0.5) / n as f64;
                    (-0.5 * ((x - m) / sd).powi(2)).exp()
                })
                .sum::<f64>()
        })
        .collect();
    let t: f64 = p.iter().sum();
    p.into_iter().map(|x| x / t).collect()
}

/// Total variation between two PMFs from the same first value (the shorter padded with 0).
fn tv(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len().max(b.len());
    0.5 * (0..n).map(|i| (a.get(i).unwrap_or(&0.0) - b.get(i).unwrap_or(&0.0)).abs()).sum::<f64>()
}

/// Phase 0 draws the PMF it was made from, exactly (to the 2⁻³² thresholds).
#[test]
fn phase_zero_is_the_pmf() {
    let q = [0.03, 0.52, 0.43, 0.02];
    let set = phase_set(-1, &q).expect("a phase set");
    let (first, p0) = set.phase_pmf(0);
    assert_eq!(first, -1);
    for (k, &x) in q.iter().enumerate() {
        assert!((p0[k] - x).abs() < 1e-9, "phase 0 at {k}: {} against {x}", p0[k]);
    }
    assert!(p0[q.len()] < 1e-9);
}

/// Known truth: a sensor whose noise is `N(0, 0.33²)` about a clean level at 0.47 of a code
/// (EMVA set 002's code 4: one exposure, shares 0.003 / 0.50 / 0.49 / 0.003 at −1 … +2) rounds
/// once; the bin's PMF is that rounding. At each phase `φ` the table must be the rounding of the
/// same noise about `0.47 + φ`. Measured: total variation and variance error below 10⁻⁴ over
/// the 16 phases (the fitted Gaussian is the truth's). The dither (what synthesis drew before:
/// the PMF moved up a code with probability `φ`, a second rounding) scores a total variation up
/// to 0.37 and 0.37 DN² too much variance (at `φ` = ½).
#[test]
fn each_phase_is_the_sensors_one_rounding() {
    let (m, sd) = (0.47, 0.33);
    let q = rounded_gaussian(m, sd, -2, 3);
    let set = phase_set(-2, &q).expect("a phase set");
    let (mut worst_tv, mut worst_var, mut dither_tv, mut dither_var) = (0.0f64, 0.0f64, 0.0f64, 0.0f64);
    for j in 0..PHASES {
        let phi = j as f64 / PHASES as f64;
        let truth = rounded_gaussian(m + phi, sd, -2, 4);
        let (first, got) = set.phase_pmf(j);
        assert_eq!(first, -2);
        let dithered: Vec<f64> = (0..truth.len())
            .map(|k| {
                q.get(k).unwrap_or(&0.0) * (1.0 - phi) + k.checked_sub(1).and_then(|k| q.get(k)).unwrap_or(&0.0) * phi
            })
            .collect();
        let var = |p: &[f64]| moments(-2, p).1;
        worst_tv = worst_tv.max(tv(&got, &truth));
        worst_var = worst_var.max((var(&got) - var(&truth)).abs());
        dither_tv = dither_tv.max(tv(&dithered, &truth));
        dither_var = dither_var.max((var(&dithered) - var(&truth)).abs());
        let (mean_got, mean_truth) = (moments(-2, &got).0, moments(-2, &truth).0);
        assert!((mean_got - mean_truth).abs() < 0.01, "phase {j}: mean {mean_got} against the truth's {mean_truth}");
    }
    eprintln!(
        "phase tables: TV ≤ {worst_tv:.4}, |Δvar| ≤ {worst_var:.4}; the dither: TV ≤ {dither_tv:.4}, |Δvar| ≤ {dither_var:.4}"
    );
    assert!(
        worst_tv < 0.02,
        "a phase table is {worst_tv:.4} (TV) from the sensor's rounding (the dither: {dither_tv:.4})"
    );
    assert!(worst_var < 0.01, "a phase table's variance is {worst_var:.4} DN² off (the dither: {dither_var:.4})");
    assert!(dither_tv > 0.1 && dither_var > 0.1, "the dither must fail this test ({dither_tv:.4}, {dither_var:.4})");
}

/// The draw's mean: at a whole offset, the PMF's plus the offset exactly; over offsets spread
/// evenly over a code, `Y`'s mean plus theirs (the phase is dithered between its two nearest
/// grid points by `v`, so no grid point's rounding is left over). A draw that ignored the
/// phase's fraction (the nearest grid point alone) or its dither misses the second by up to
/// 1/32 DN.
#[test]
fn draws_carry_the_offset() {
    let q = [0.06, 0.91, 0.03];
    let set = phase_set(-1, &q).expect("a phase set");
    let (base, var) = moments(-1, &q);
    let (m, sd) = fit_rounded_gaussian(base, var);
    let y = within_codes(-1, &q, m, sd);
    let y_mean: f64 = y.iter().enumerate().map(|(i, &w)| w * (-1.0 - 0.5 + (i as f64 + 0.5) / GRID as f64)).sum();
    // The mean of the draws at offset `o` over a grid of `u` and `v`.
    let mean_at = |o: f64| {
        let of = (o * 4294967296.0f64).round() as i64;
        let n = 1u64 << 10;
        let mut sum = 0i64;
        for a in 0..n {
            for b in 0..32u64 {
                let u = ((a * 2 + 1) << 31) / n;
                let v = ((b * 2 + 1) << 31) / 32;
                sum += i64::from(set.draw(of, v as u32, u as u32));
            }
        }
        sum as f64 / (n * 32) as f64
    };
    for o in [0.0, 1.0, -2.0] {
        assert!((mean_at(o) - base - o).abs() < 1e-3, "offset {o}: mean {} against {}", mean_at(o), base + o);
    }
    let offsets: Vec<f64> = (0..96).map(|k| 0.3 + k as f64 / 96.0).collect();
    let spread = offsets.iter().map(|&o| mean_at(o)).sum::<f64>() / offsets.len() as f64;
    let expected = y_mean + offsets.iter().sum::<f64>() / offsets.len() as f64;
    assert!((spread - expected).abs() < 0.004, "offsets over a code: mean {spread} against Y's {expected}");
}

/// Known truth at black on a sub-DN sensor (EMVA set 002's black bin): noise `N(0, 0.27²)`
/// about black at −0.07 of its code and a Gaussian pattern of 0.12 DN, both under one rounding;
/// the bin's PMF is that of `round(−0.07 + p + n)` (the clean level rounded is the code for
/// every pixel), so it holds the pattern. At each phase `φ` (the pattern's fraction at a pixel)
/// the table must be `round(−0.07 + φ + n)`, the pattern itself left to the phase. Measured:
/// total variation at most 2·10⁻³ over the 16 phases, the phase-0 variance within 2 % of the
/// truth's. [`phase_set`] (the PMF read as it is, the pattern left in `Y`) scores a phase-0
/// variance 1.2× the truth's: the pattern drawn twice.
#[test]
fn a_bin_that_holds_the_pattern_has_it_taken_out_of_y() {
    let (m, sd, ps) = (-0.07, 0.27, 0.12);
    // The pattern on 97 points over ±4 SD, and the PMF: the mixture of the roundings.
    let held: Vec<(f64, f64)> = (-48..=48)
        .map(|i| {
            let o = ps * i as f64 / 12.0;
            (o, (-0.5 * (o / ps).powi(2)).exp())
        })
        .collect();
    let hw: f64 = held.iter().map(|h| h.1).sum();
    let mut q = vec![0.0; 5];
    for &(o, w) in &held {
        for (k, x) in rounded_gaussian(m + o, sd, -2, 2).into_iter().enumerate() {
            q[k] += x * w / hw;
        }
    }
    let set = phase_set_less_held(-2, &q, &held).expect("a phase set");
    let var = |first: i32, p: &[f64]| {
        let mean: f64 = p.iter().enumerate().map(|(k, x)| (first + k as i32) as f64 * x).sum();
        p.iter().enumerate().map(|(k, x)| ((first + k as i32) as f64 - mean).powi(2) * x).sum::<f64>()
    };
    let mut worst_tv = 0.0f64;
    for j in 0..PHASES {
        let truth = rounded_gaussian(m + j as f64 / PHASES as f64, sd, -2, 3);
        let (first, got) = set.phase_pmf(j);
        assert_eq!(first, -2);
        worst_tv = worst_tv.max(tv(&got, &truth));
    }
    let truth0 = rounded_gaussian(m, sd, -2, 3);
    let (_, got0) = set.phase_pmf(0);
    let (_, old0) = phase_set(-2, &q).expect("a phase set").phase_pmf(0);
    let (t, g, o) = (var(-2, &truth0), var(-2, &got0), var(-2, &old0));
    eprintln!("worst TV {worst_tv:.5}; phase-0 variance truth {t:.4} held out {g:.4} as it is {o:.4}");
    assert!(worst_tv < 5e-3, "total variation {worst_tv:.4} from the sensor's rounding");
    assert!((g / t - 1.0).abs() < 0.03, "phase-0 variance {g:.4} against the truth's {t:.4}");
    assert!(o / t > 1.1, "the PMF as it is holds the pattern: {o:.4} against {t:.4}");
}

/// Black's bin on a sensor with bins of 1 DN and a fixed pattern of several DN: the pattern
/// (SD 2.5 DN, on the 1/32 DN grid the structured offsets use) wrapped into black's code as
/// `StructureSampler::black_phase_set` holds it, 641 held points over 10 codes, past
/// [`HELD_TABLE_CAP`]. Known truth as above: each phase's table is the sensor's one rounding
/// `round(m + φ + n)`. The held points folded by phase ([`held_by_phase`]) give `Y` within
/// 10⁻¹² of the table of codes ([`held_by_table`]) on the same start, and the same thresholds
/// to a unit of 2⁻³²: a fold that put a phase's weight one code off (`a + code(r, o)` read at
/// the wrong phase) moves whole masses between codes, and fails both.
#[test]
fn held_points_folded_by_phase_are_the_table_of_codes() {
    let (m, sd, ps, f0) = (-0.13, 0.9, 2.5, -0.13);
    let held: Vec<(f64, f64)> = (-320..=320)
        .map(|i| {
            let g = f0 + i as f64 / 32.0;
            ((g - (g + 0.5).floor()) - f0, (-0.5 * (i as f64 / 32.0 / ps).powi(2)).exp())
        })
        .collect();
    let hw: f64 = held.iter().map(|h| h.1).sum();
    let (lo, hi) = (-5, 4);
    let mut q = vec![0.0; (hi - lo + 1) as usize];
    for &(o, w) in &held {
        for (k, x) in rounded_gaussian(m + o, sd, lo, hi).into_iter().enumerate() {
            q[k] += x * w / hw;
        }
    }
    assert!(q.len() * GRID * held.len() > HELD_TABLE_CAP, "the folded path is the one taken");
    let set = phase_set_less_held(lo, &q, &held).expect("a phase set");
    let mut worst_tv = 0.0f64;
    for j in 0..PHASES {
        let truth = rounded_gaussian(m + j as f64 / PHASES as f64, sd, lo, hi + 1);
        let (first, got) = set.phase_pmf(j);
        assert_eq!(first, lo);
        worst_tv = worst_tv.max(tv(&got, &truth));
    }
    // The two ways on the same start: a Gaussian on the grid, normalised.
    let n = q.len() * GRID;
    let at = |g: usize| f64::from(lo) - 0.5 + (g as f64 + 0.5) / GRID as f64;
    let held_n: Vec<(f64, f64)> = held.iter().map(|&(o, w)| (o, w / hw)).collect();
    let mut y0: Vec<f64> = (0..n).map(|g| (-0.5 * ((at(g) - m) / 0.5).powi(2)).exp()).collect();
    normalise(&mut y0).expect("a start");
    let code = |g: usize, o: f64| floor_i32(at(g) + o + 0.5) - lo;
    let by_table = held_by_table(&q, &held_n, y0.clone(), code).expect("by table");
    let by_phase = held_by_phase(&q, &held_n, y0, code).expect("by phase");
    let worst_y = by_table.iter().zip(&by_phase).map(|(a, b)| (a - b).abs()).fold(0.0, f64::max);
    let (a, b) = (tables_of(lo, &by_table), tables_of(lo, &by_phase));
    let worst_t = a.thresholds.iter().zip(&b.thresholds).map(|(x, y)| x.abs_diff(*y)).max().unwrap_or(0);
    eprintln!("worst TV {worst_tv:.5}; folded against the table: y {worst_y:.2e}, thresholds {worst_t} units of 2⁻³²");
    assert!(worst_tv < 5e-3, "total variation {worst_tv:.4} from the sensor's rounding");
    assert!(worst_y < 1e-12, "y {worst_y:e} apart");
    assert!(worst_t <= 1, "thresholds {worst_t} apart");
}
