//! The dark end judged level by level (method.md, *Synthesis*, "Within a bin near black"): the
//! exact synthetic distribution at every clean level from black up against the simulator's own
//! noise there, beside one PMF per bin and the plain histograms of the same frames. Shared by
//! `tests/dark_end.rs` and `tests/gain_switch.rs`.
//!
//! The synthetic distribution at a clean level is computed exactly from the sampler's tables (the
//! pixel-independent model, whose PMFs hold the whole noise), clamp, lattice and the target
//! brightness's dither included; the real one from the simulator's own noise process at that
//! level (`Simulator::sample_noise_at_level`, [`REAL_SAMPLES`] samples). At the reference
//! brightness the real level is the reference level's distance above black times the gain ratio;
//! at the target brightness the level itself. Levels: every integer code from black up over two
//! bins, then every quarter bin up to 16 bins.

use std::collections::BTreeMap;

use noisecal_core::model::structure::Components;
use noisecal_core::resolve::{ModelKind, resolve_model};
use noisecal_core::synth::CleanAt;
use noisecal_core::synth::sampler::{BinTable, IsoSampler};
use noisecal_core::{CalibrationSession, FrameView, ModelPack, SessionConfig};
use noisecal_sim::{Chart, SessionPlan, Simulator};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

/// The bound of the issue: synthetic / real variance within 1.10 either way.
pub const BOUND: f64 = 1.10;

/// Dark frames per ISO of a session's dark step.
pub const DARK_FRAMES: u64 = 16;

/// Samples of the real noise per level.
pub const REAL_SAMPLES: usize = 40_000;

/// The width of the plain histogram the issue found tying the truth near black (DN).
pub const FINE_PLAIN_WIDTH: u16 = 4;

/// A level is judged against the 4 DN plain histogram where that histogram's own bin holds at
/// least this many samples (its variance then within about 4 % of its pixels', one SE).
pub const PLAIN_SUPPORT: u64 = 1000;

/// A distribution over output codes.
pub type Codes = BTreeMap<i32, f64>;

/// The exact distribution of the code a sampler writes for clean code `c` at `pos`, clamp and
/// lattice included: at the reference brightness `c + n`, `n` from the level's table; at the
/// target brightness ([`CleanAt::Target`]) `c + n + ⌊s + U⌋`, the table of the level's
/// reference level and its offset `s` dithered by a uniform `U`, as synthesis draws it.
pub fn output_pmf(s: &IsoSampler, pos: usize, c: u16) -> Codes {
    let (table, shift) = match s.target_tables(pos) {
        Some((lut, sh)) => {
            let l = (c as usize).min(lut.len() - 1);
            (&s.tables(pos)[lut[l] as usize], sh[l])
        }
        None => (s.table(pos, c), 0),
    };
    table_pmf(s, table, pos, c, shift)
}

/// [`output_pmf`] for a given table and offset (2⁻³² DN): the offset's integer part and its
/// dither's two taps ([`kernel_pmf`]).
pub fn table_pmf(s: &IsoSampler, t: &BinTable, pos: usize, c: u16, shift: i64) -> Codes {
    let frac = (shift & 0xFFFF_FFFF) as f64 / 4_294_967_296.0;
    kernel_pmf(s, t, pos, c, (shift >> 32) as i32, &[1.0 - frac, frac])
}

/// The exact distribution of the code written for clean code `c` at `pos` when the table's noise
/// `n` is added to an integer offset drawn from `kernel` (`kernel[j]` the probability of
/// `k0 + j`), clamped and put on the lattice as synthesis does.
pub fn kernel_pmf(s: &IsoSampler, t: &BinTable, pos: usize, c: u16, k0: i32, kernel: &[f64]) -> Codes {
    let mut out = Codes::new();
    for i in 0..t.len() {
        let n = t.first() + i as i32;
        let p = t.prob(n);
        if p == 0.0 {
            continue;
        }
        for (j, &w) in kernel.iter().enumerate() {
            if w > 0.0 {
                *out.entry(s.finish(pos, c as i32 + n + k0 + j as i32, false) as i32).or_default() += p * w;
            }
        }
    }
    out
}

/// Variance, 0.1 % and 99.9 % quantiles (about the mean) of a distribution.
#[derive(Debug, Clone, Copy)]
pub struct Moments {
    pub var: f64,
    pub lo: f64,
    pub hi: f64,
    /// Fourth moment over the squared variance.
    pub kurtosis: f64,
}

pub fn moments(d: &Codes) -> Moments {
    let mean: f64 = d.iter().map(|(&c, &p)| c as f64 * p).sum();
    let var = d.iter().map(|(&c, &p)| p * (c as f64 - mean).powi(2)).sum();
    let quantile = |q: f64| {
        let mut acc = 0.0;
        for (&c, &p) in d {
            acc += p;
            if acc >= q {
                return c as f64 - mean;
            }
        }
        *d.keys().last().expect("codes") as f64 - mean
    };
    let m4: f64 = d.iter().map(|(&c, &p)| p * (c as f64 - mean).powi(4)).sum();
    Moments { var, lo: quantile(0.001), hi: quantile(0.999), kurtosis: m4 / (var * var) }
}

/// Jensen–Shannon divergence (nats) between two distributions over codes.
pub fn jsd(p: &Codes, q: &Codes) -> f64 {
    let kl = |a: &Codes, b: &Codes| -> f64 {
        a.iter()
            .filter(|(_, pa)| **pa > 0.0)
            .map(|(c, &pa)| {
                let m = 0.5 * (pa + b.get(c).copied().unwrap_or(0.0));
                pa * (pa / m).ln()
            })
            .sum()
    };
    0.5 * kl(p, q) + 0.5 * kl(q, p)
}

/// The real output codes at `level` (DN, the target ISO's brightness), as a distribution.
pub fn real_codes(sim: &Simulator, iso: u32, level: f32, pos: usize, rng: &mut ChaCha8Rng) -> Codes {
    let real = sim.sample_noise_at_level(iso, level, pos, REAL_SAMPLES, rng).expect("truth");
    let clean = level.round() as i32;
    let mut d = Codes::new();
    for n in real {
        *d.entry(clean + n).or_default() += 1.0 / REAL_SAMPLES as f64;
    }
    d
}

/// One model's figures at one level against the real noise there.
#[derive(Debug, Clone, Copy)]
pub struct Fit {
    pub m: Moments,
    pub jsd: f64,
}

impl Fit {
    pub fn of(model: &Codes, real: &Codes) -> Self {
        Self { m: moments(model), jsd: jsd(model, real) }
    }

    /// `|ln|` of the variance ratio against `real`.
    pub fn var_err(&self, real: &Moments) -> f64 {
        (self.m.var / real.var).ln().abs()
    }

    /// The larger `|ln|` of the two tail-quantile ratios against `real` (quantiles about the
    /// mean; a quantile within 1 DN of the mean on either side is judged as 1 DN).
    pub fn tail_err(&self, real: &Moments) -> f64 {
        let r = |a: f64, b: f64| (a.abs().max(1.0) / b.abs().max(1.0)).ln().abs();
        r(self.m.lo, real.lo).max(r(self.m.hi, real.hi))
    }
}

/// The models compared at a level.
#[derive(Debug, Clone, Copy)]
pub struct Models {
    /// The pack at the reference brightness.
    pub pack: Fit,
    /// One PMF per bin (the bin's own table, as before the levels near black were split): the
    /// test's power.
    pub held: Fit,
    /// The plain histogram of the same frames at the pack's bin width, and at 4 DN.
    pub plain: Fit,
    pub plain4: Fit,
    /// Samples in the 4 DN plain histogram's own bin.
    pub plain4_samples: u64,
    pub real: Moments,
    /// The pack with the clean image at the target ISO's brightness, and the real noise there
    /// (the level then the target's own).
    pub target: Fit,
    pub real_target: Moments,
}

/// One level's comparison.
#[derive(Debug)]
pub struct Level {
    pub pos: usize,
    pub above_black: i32,
    pub at: Models,
}

impl Level {
    /// Three standard errors of the ratio of a variance to the real one measured from
    /// [`REAL_SAMPLES`] samples (relative, `√((κ − 1)/n)` each).
    pub fn slack(real: &Moments) -> f64 {
        3.0 * ((real.kurtosis - 1.0).max(0.0) / REAL_SAMPLES as f64).sqrt()
    }

    pub fn ratio(&self) -> f64 {
        self.at.pack.m.var / self.at.real.var
    }

    pub fn target_ratio(&self) -> f64 {
        self.at.target.m.var / self.at.real_target.var
    }
}

/// The packs of one session: the estimated pack, and the plain histograms of the same frames
/// at its bin width and at [`FINE_PLAIN_WIDTH`].
#[derive(Debug)]
pub struct Packs {
    pub pack: ModelPack,
    pub plain: ModelPack,
    pub plain4: ModelPack,
}

/// The sampler of `pack` at `iso` (calibrated or interpolated), pixel-independent part only
/// (its PMFs hold the whole noise), for clean images at `clean_at`.
pub fn sampler(pack: &ModelPack, iso: u32, clean_at: CleanAt) -> IsoSampler {
    resolve_model(pack, iso, ModelKind::Noisecal, false)
        .and_then(|r| r.sampler(pack, Components::PIXEL, clean_at, false))
        .expect("a sampler")
}

/// Every model against the real noise at every level of the dark end, at each ISO of `isos`
/// (calibrated or interpolated).
pub fn compare(sim: &Simulator, packs: &Packs, isos: &[u32], seed: u64) -> Vec<(u32, Vec<Level>)> {
    let pack = &packs.pack;
    let bw = pack.bin_width as i32;
    let mut offsets: Vec<i32> = (0..=2 * bw).collect();
    offsets.extend((8..=64).map(|q| q * bw / 4).filter(|&k| k > 2 * bw));
    isos.iter()
        .map(|&iso| {
            let model = resolve_model(pack, iso, ModelKind::Noisecal, false).expect("model").model;
            eprintln!(
                "ISO {iso}: {}, gain ratios {:.4?}, black {:?}",
                noisecal_core::resolve::origin_text(&model.origin),
                model.gain_ratio,
                pack.layout.black
            );
            let s = sampler(pack, iso, CleanAt::Reference);
            let st = sampler(pack, iso, CleanAt::Target);
            let sp = sampler(&packs.plain, iso, CleanAt::Reference);
            let s4 = sampler(&packs.plain4, iso, CleanAt::Reference);
            let plain4 = packs.plain4.iso(iso);
            let jobs: Vec<(usize, i32)> = (0..4).flat_map(|p| offsets.iter().map(move |&k| (p, k))).collect();
            let levels = jobs
                .par_iter()
                .map(|&(pos, k)| {
                    let code = pack.layout.black[pos].ceil() as i32 + k;
                    let mut rng =
                        ChaCha8Rng::seed_from_u64(seed ^ ((iso as u64) << 32) ^ ((pos as u64) << 24) ^ k as u64);
                    // The pack's clean levels are at the reference ISO's brightness; the target's
                    // level is `g` times as far above black (the gain ratio: a gain not ∝ ISO;
                    // method.md, *Synthesis*).
                    let black = pack.layout.black[pos] as f64;
                    let level = (black + model.gain_ratio[pos] * (code as f64 - black)) as f32;
                    let real = real_codes(sim, iso, level, pos, &mut rng);
                    let real_target = real_codes(sim, iso, code as f32, pos, &mut rng);
                    let c = code as u16;
                    let bin = &model.positions[pos].bins[pack.binning().bin(pos, code as f32)];
                    let plain4_samples = plain4
                        .map_or(0, |m| m.positions[pos].bins[packs.plain4.binning().bin(pos, code as f32)].samples);
                    Level {
                        pos,
                        above_black: k,
                        at: Models {
                            pack: Fit::of(&output_pmf(&s, pos, c), &real),
                            held: Fit::of(&table_pmf(&s, &BinTable::new(bin), pos, c, 0), &real),
                            plain: Fit::of(&output_pmf(&sp, pos, c), &real),
                            plain4: Fit::of(&output_pmf(&s4, pos, c), &real),
                            plain4_samples,
                            real: moments(&real),
                            target: Fit::of(&output_pmf(&st, pos, c), &real_target),
                            real_target: moments(&real_target),
                        },
                    }
                })
                .collect();
            (iso, levels)
        })
        .collect()
}

/// Calibrates `plan` on `sim` as the CLI would, then (when `dark`) a dark step of
/// [`DARK_FRAMES`] per ISO at the shortest exposure the ISO uses; `plain` with the plain
/// per-bin histograms of `bin_width` (the default width when `None`).
pub fn calibrate_with(
    sim: &Simulator,
    plan: &SessionPlan,
    dark: bool,
    plain: bool,
    bin_width: Option<u16>,
) -> ModelPack {
    let mut config = SessionConfig::new(plan.reference_iso);
    config.make = "sim".into();
    config.plain = plain;
    config.bin_width = bin_width;
    let mut session = CalibrationSession::new(sim.layout(), config).expect("session");
    plan.feed(sim, &mut session, |_, _| ()).expect("capture");
    if dark {
        session.begin_dark().expect("dark step");
        for (iso, exposure) in plan.dark_settings() {
            for k in 0..DARK_FRAMES {
                let (px, meta) = sim.capture_dark(iso, exposure, k).expect("dark capture");
                session.push_frame(&FrameView::from_array(&px).expect("view"), &meta).expect("dark frame accepted");
            }
        }
    }
    session.finish().expect("a pack")
}

/// The estimated pack (with a dark step when `dark`) and the plain histograms of the same frames.
pub fn calibrate(sim: &Simulator, plan: &SessionPlan, dark: bool) -> Packs {
    Packs {
        pack: calibrate_with(sim, plan, dark, false, None),
        plain: calibrate_with(sim, plan, false, true, None),
        plain4: calibrate_with(sim, plan, false, true, Some(FINE_PLAIN_WIDTH)),
    }
}

/// The worst `|ln|` of `f` over `levels`, as a ratio.
pub fn worst(levels: &[&Level], f: impl Fn(&Level) -> f64) -> f64 {
    levels.iter().map(|l| f(l)).fold(0.0, f64::max).exp()
}

/// Mean of `f` over `levels`.
pub fn mean(levels: &[&Level], f: impl Fn(&Level) -> f64) -> f64 {
    levels.iter().map(|l| f(l)).sum::<f64>() / levels.len().max(1) as f64
}

/// How `pick` (a model) does against the plain 4 DN histogram where that histogram stands on
/// [`PLAIN_SUPPORT`] samples of its own: worst variance ratio, worst tail ratio and mean JSD,
/// each for the model and for the histogram.
#[derive(Debug)]
pub struct AgainstPlain {
    pub levels: usize,
    pub var: [f64; 2],
    pub tail: [f64; 2],
    pub jsd: [f64; 2],
}

pub fn against_plain(levels: &[Level], pick: impl Fn(&Models) -> Fit) -> AgainstPlain {
    let on: Vec<&Level> = levels.iter().filter(|l| l.at.plain4_samples >= PLAIN_SUPPORT).collect();
    let real = |l: &Level| l.at.real;
    AgainstPlain {
        levels: on.len(),
        var: [worst(&on, |l| pick(&l.at).var_err(&real(l))), worst(&on, |l| l.at.plain4.var_err(&real(l)))],
        tail: [worst(&on, |l| pick(&l.at).tail_err(&real(l))), worst(&on, |l| l.at.plain4.tail_err(&real(l)))],
        jsd: [mean(&on, |l| pick(&l.at).jsd), mean(&on, |l| l.at.plain4.jsd)],
    }
}

impl AgainstPlain {
    /// Whether the model does not lose to the histogram: mean JSD at most the histogram's (with
    /// [`JSD_TIE`] for the two sides' sampling noise), worst variance and tail ratios at most
    /// the histogram's or the bounds (×1.10, ×1.25), whichever is larger.
    pub fn holds(&self) -> bool {
        self.jsd[0] <= self.jsd[1] * JSD_TIE
            && self.var[0] <= self.var[1].max(BOUND)
            && self.tail[0] <= self.tail[1].max(TAIL_BOUND)
    }

    pub fn text(&self) -> String {
        format!(
            "{} levels with a 4 DN plain bin of its own: worst variance ratio {:.3} (plain 4 DN {:.3}), worst tail {:.3} ({:.3}), mean JSD {:.2e} ({:.2e})",
            self.levels, self.var[0], self.var[1], self.tail[0], self.tail[1], self.jsd[0], self.jsd[1]
        )
    }
}

/// The bound on the 0.1 % / 99.9 % quantiles.
pub const TAIL_BOUND: f64 = 1.25;

/// Mean JSDs within this ratio tie.
pub const JSD_TIE: f64 = 1.02;

/// Prints the comparison and returns the levels beyond the bounds: the pack's variance within
/// [`BOUND`] at every level, at the reference brightness and (when `target`) at the target's;
/// and, where the 4 DN plain histogram stands on data of its own, the pack no worse than it
/// ([`AgainstPlain::holds`]), where one PMF per bin is (the check's power).
pub fn judge(name: &str, results: &[(u32, Vec<Level>)], target: bool, known_shape_loss: &[u32]) -> Vec<String> {
    let mut failures = Vec::new();
    for (iso, levels) in results {
        let all: Vec<&Level> = levels.iter().collect();
        let worst_pack = worst(&all, |l| l.ratio().ln().abs());
        let worst_target = worst(&all, |l| l.target_ratio().ln().abs());
        let held = worst(&all, |l| l.at.held.var_err(&l.at.real));
        let plain = worst(&all, |l| l.at.plain.var_err(&l.at.real));
        let plain4 = worst(&all, |l| l.at.plain4.var_err(&l.at.real));
        let at_black: Vec<String> = levels
            .iter()
            .filter(|l| l.above_black == 0)
            .map(|l| format!("{:.1}/{:.1}", l.at.pack.m.var, l.at.real.var))
            .collect();
        eprintln!(
            "{name} ISO {iso}: worst variance ratio, every level: pack {worst_pack:.3}, clean at target {worst_target:.3}, one PMF per bin {held:.3}, plain {plain:.3}, plain 4 DN {plain4:.3}; at black (synthetic/real DN², per position) {}",
            at_black.join(", ")
        );
        let pack = against_plain(levels, |m| m.pack);
        let held = against_plain(levels, |m| m.held);
        eprintln!("  pack: {}\n  one PMF per bin: {}", pack.text(), held.text());
        for l in levels.iter().filter(|l| l.pos == 0 && (l.above_black % 8 == 0 || l.above_black < 8)) {
            let a = &l.at;
            eprintln!(
                "  +{:>4} DN: real {:8.2} [{:6.1} {:6.1}] | pack {:.3} [{:.2} {:.2}] {:.1e} | plain {:.3} {:.1e} | plain 4 DN {:.3} {:.1e} ({:>6}) | held {:.3} | target {:.3}",
                l.above_black,
                a.real.var,
                a.real.lo,
                a.real.hi,
                l.ratio(),
                a.pack.m.lo / a.real.lo,
                a.pack.m.hi / a.real.hi,
                a.pack.jsd,
                a.plain.m.var / a.real.var,
                a.plain.jsd,
                a.plain4.m.var / a.real.var,
                a.plain4.jsd,
                a.plain4_samples,
                a.held.m.var / a.real.var,
                l.target_ratio(),
            );
        }
        let mut beyond = |what: &str, r: f64, real: &Moments, l: &Level| {
            let b = BOUND * (1.0 + Level::slack(real));
            if !(1.0 / b..=b).contains(&r) {
                failures.push(format!(
                    "{name} ISO {iso} position {} +{} DN: {what} {r:.3} (real {:.2} DN², bound ×{b:.3})",
                    l.pos, l.above_black, real.var
                ));
            }
        };
        for l in levels {
            beyond("synthetic / real variance", l.ratio(), &l.at.real, l);
            if target {
                beyond("synthetic / real variance, clean at target", l.target_ratio(), &l.at.real_target, l);
            }
        }
        if known_shape_loss.contains(iso) {
            // Variance and tails are still judged; the shape is known to lose (printed).
            let both = AgainstPlain { jsd: [0.0, 0.0], ..pack };
            if pack.levels > 0 && !both.holds() {
                failures.push(format!("{name} ISO {iso}: the pack loses to the 4 DN plain histogram: {}", pack.text()));
            }
            eprintln!("  known: the pack's shape loses to the 4 DN plain histogram here (mean JSD above)");
        } else if pack.levels > 0 && !pack.holds() {
            failures.push(format!("{name} ISO {iso}: the pack loses to the 4 DN plain histogram: {}", pack.text()));
        }
    }
    failures
}

/// A chart of 24 neutral patches from reflectance 0.9 down to 0.03 (log-spaced, the
/// ColorChecker's white to its black) on the ColorChecker's layout and lamp: every CFA position
/// sees its darkest patch at about a thirtieth of its brightest, so at −2 EV the darkest
/// calibrated level is 20–40 DN above black at every position (a colour chart's saturated
/// patches reach within a few DN of black in one channel).
pub fn grey_chart(width: u32, height: u32) -> Chart {
    let mut chart = Chart::color_checker(width, height).expect("chart");
    chart.patches = (0..24).map(|i| [0.9f32 * (0.03f32 / 0.9).powf(i as f32 / 23.0); 3]).collect();
    chart
}

/// The darkest clean level (DN above black) of a session's darkest step, per CFA position.
pub fn darkest_levels(sim: &Simulator, plan: &SessionPlan, step: i32) -> [f32; 4] {
    let clean = sim.clean_expected(plan.reference_iso, plan.exposure_ns(step, plan.reference_iso)).expect("clean");
    let black = sim.layout().black;
    std::array::from_fn(|p| {
        clean
            .indexed_iter()
            .filter(|((y, x), _)| (y % 2) * 2 + x % 2 == p)
            .map(|(_, &v)| v - black[p])
            .fold(f32::INFINITY, f32::min)
    })
}

/// The variance at black a law fitted on the chart's bins alone gives (no dark step): the
/// intercept of `b + a·x` on the six darkest bins read (the darkest calibrated one left out, as
/// [`noisecal_core::derive::fine_levels`] reads them), each bin's variance weighted by its
/// samples / (2σ⁴), with its standard error, against the truth at black. Printed: it is why
/// a pack without a dark step keeps whole bins.
pub fn print_fitted_black(sim: &Simulator, pack: &ModelPack, isos: &[u32]) {
    let w = pack.bin_width as f64;
    for &iso in isos {
        let model = pack.iso(iso).expect("calibrated");
        for pos in 0..4 {
            let bins = &model.positions[pos].bins;
            let lowest = bins.iter().position(|b| b.samples > 0).expect("data");
            let used: Vec<(f64, f64, f64)> = bins
                .iter()
                .enumerate()
                .skip(lowest + 1)
                .filter(|(_, b)| b.samples > 0 && !b.clipped)
                .take(6)
                .map(|(k, b)| ((k as f64 + 0.5) * w, b.moments().1, b.samples as f64 / (2.0 * b.moments().1.powi(2))))
                .collect();
            let (s0, s1, s2) =
                used.iter().fold((0.0, 0.0, 0.0), |a, u| (a.0 + u.2, a.1 + u.2 * u.0, a.2 + u.2 * u.0 * u.0));
            let (t0, t1) = used.iter().fold((0.0, 0.0), |a, u| (a.0 + u.2 * u.1, a.1 + u.2 * u.0 * u.1));
            let det = s0 * s2 - s1 * s1;
            let intercept = (s2 * t0 - s1 * t1) / det;
            let se = (s2 / det).sqrt();
            let mut rng = ChaCha8Rng::seed_from_u64(iso as u64 ^ pos as u64);
            let real = moments(&real_codes(sim, iso, pack.layout.black[pos], pos, &mut rng)).var;
            eprintln!(
                "  ISO {iso} position {pos}: from the chart alone the variance at black is {intercept:.2} ± {se:.2} DN² (bins from {:.0} DN up); the truth {real:.2}",
                used.first().map_or(0.0, |u| u.0)
            );
        }
    }
}

/// Whether one PMF per bin loses to the 4 DN plain histogram at some ISO of `results`: the
/// comparison with the histogram can fail.
pub fn held_loses(results: &[(u32, Vec<Level>)]) -> bool {
    results.iter().any(|(_, levels)| {
        let held = against_plain(levels, |m| m.held);
        held.levels > 0 && !held.holds()
    })
}
