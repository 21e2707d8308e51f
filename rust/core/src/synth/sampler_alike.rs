//! Whether a compact table ([`super::BinTable::regridded`], [`super::BinTable::in_blocks`])
//! draws like the per-DN table it stands for, at the draws a frame makes of one table: about
//! 10⁴ ([`FRAME_DRAWS`]: 12·10⁶ pixels over 4 positions × about 240 tables). Its mean and
//! variance within [`SE_SHARE`] of their standard errors there, and its 0.1 % and 99.9 %
//! quantiles within the per-DN table's own ±1 standard error range (the quantiles at `u ∓
//! √(u(1 − u)/n)`). A total variation bound alone does not hold the tails: on random sensor 0 at
//! ISO 4000 (bins on grids of 8–32 DN, SD 85–92 DN) six tables re-gridded within 4·10⁻³ moved
//! their 0.1 % quantile by 3–4 DN past a range of 2–3 DN.

/// Draws a 12 MP frame makes of one table.
pub(crate) const FRAME_DRAWS: f64 = 1e4;
/// The share of a standard error at [`FRAME_DRAWS`] the mean and the variance may move.
pub(crate) const SE_SHARE: f64 = 0.25;
/// The tail quantiles held.
const TAILS: [f64; 2] = [1e-3, 1.0 - 1e-3];
const ONE: f64 = 4294967296.0;

/// Mean, variance and quantile function of the table of cumulative weights `cdf` (units of
/// 2⁻³², the last 2³²) over `first ..`.
struct Drawn<'a> {
    first: i32,
    cdf: &'a [u64],
    mean: f64,
    var: f64,
}

impl<'a> Drawn<'a> {
    fn new(first: i32, cdf: &'a [u64]) -> Self {
        let (mut s1, mut s2, mut below) = (0.0, 0.0, 0u64);
        // About the middle value, so the variance keeps its digits for tables far from 0.
        let mid = f64::from(first) + (cdf.len() / 2) as f64;
        for (i, &c) in cdf.iter().enumerate() {
            let (w, x) = ((c - below) as f64 / ONE, f64::from(first) + i as f64 - mid);
            s1 += w * x;
            s2 += w * x * x;
            below = c;
        }
        Self { first, cdf, mean: mid + s1, var: (s2 - s1 * s1).max(0.0) }
    }

    /// The value at which the cumulative probability first reaches `u`.
    fn quantile(&self, u: f64) -> i32 {
        let i = self.cdf.partition_point(|&c| (c as f64) < u * ONE);
        self.first + i.min(self.cdf.len() - 1) as i32
    }
}

/// Whether the table of cumulative weights `cdf` over `first ..` draws like the per-DN table
/// `exact` over `exact_first ..` (module docs).
pub(crate) fn draws_alike(exact_first: i32, exact: &[u64], first: i32, cdf: &[u64]) -> bool {
    if exact.is_empty() || cdf.is_empty() {
        return false;
    }
    let (e, t) = (Drawn::new(exact_first, exact), Drawn::new(first, cdf));
    let n = FRAME_DRAWS;
    let mean_ok = (t.mean - e.mean).abs() <= SE_SHARE * (e.var / n).sqrt();
    let var_ok = (t.var - e.var).abs() <= SE_SHARE * e.var * (2.0 / n).sqrt();
    let tails_ok = TAILS.iter().all(|&u| {
        let se = (u * (1.0 - u) / n).sqrt();
        (e.quantile(u - se)..=e.quantile(u + se)).contains(&t.quantile(u))
    });
    mean_ok && var_ok && tails_ok
}
