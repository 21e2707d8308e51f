//! The part of a row- or column-mean variance that the pixels' own frame-to-frame noise makes
//! (method.md, "Evaluation", *row- and column-mean variance*): per line of `n` flat pixels
//! `Σ s² / n²`, `s²` a pixel's variance over the frames of its burst (each frame's mean noise
//! per CFA position taken out first, as the line statistic takes it out), averaged over the
//! lines. For noise independent from pixel to pixel it is what the line-mean variance measures;
//! a line component adds to the line-mean variance its whole variance and to this only `1/n` of
//! it.
//!
//! Why it is needed: a pack's pixel noise includes the calibration clean image's error (the
//! paper's convention, kept), which synthesis draws afresh in every frame, while in real
//! held-out frames the clean image's error is the same in every frame and the line statistic's
//! centring over frames takes it out. Synthetic pixels then vary more from frame to frame than
//! real ones, and the plain ratio of line-mean variances reads that as line noise. With the
//! pixels' own part of each side known, `(L_s − P_s + P_r) / L_r` judges what the lines share
//! on the real pixels' noise (the e2e studies' `line_ratios` in tests/e2e/src/moments.rs; the
//! same measure).

/// Pixels per line whose variance is kept: a line's `Σ s²` is estimated from at most this many
/// of its flat pixels, evenly spaced, so that a 12 MP image costs about 9 MB per set of frames
/// (not 20 B per flat pixel); the mean over thousands of lines keeps the estimate's noise small.
pub(crate) const PIXELS_PER_LINE: usize = 64;

/// One direction's lines (rows or columns): the sampled pixels of the current burst, per pixel
/// its line and `Σv`, `Σv²` over the burst's frames; per line its flat pixels and how many were
/// sampled.
#[derive(Debug, Clone, PartialEq, Default)]
struct Lines {
    px: Vec<(u32, u32)>,
    sum: Vec<f64>,
    sq: Vec<f64>,
    count: Vec<u32>,
    sampled: Vec<u32>,
}

impl Lines {
    /// Samples every `⌈n / PIXELS_PER_LINE⌉`-th flat pixel of each line; `line(i)` is the line of
    /// row-major index `i`, `count` the flat pixels per line.
    fn new(flat: &[u32], count: &[u32], line: impl Fn(usize) -> usize) -> Self {
        let mut seen = vec![0u32; count.len()];
        let mut sampled = vec![0u32; count.len()];
        let mut px = Vec::new();
        for &i in flat {
            let l = line(i as usize);
            let stride = (count[l] as usize).div_ceil(PIXELS_PER_LINE).max(1) as u32;
            if seen[l].is_multiple_of(stride) {
                px.push((i, l as u32));
                sampled[l] += 1;
            }
            seen[l] += 1;
        }
        let n = px.len();
        Self { px, sum: vec![0.0; n], sq: vec![0.0; n], count: count.to_vec(), sampled }
    }

    fn add(&mut self, value: &impl Fn(usize) -> f64) {
        for ((&(i, _), s), q) in self.px.iter().zip(&mut self.sum).zip(&mut self.sq) {
            let v = value(i as usize);
            *s += v;
            *q += v * v;
        }
    }

    /// The lines' mean of `Σ s² / n²` (each line's sum scaled up from its sampled pixels) over
    /// `k` frames, lines of fewer than `min_pixels` left out; `None` below two lines.
    fn part(&self, k: u32, min_pixels: usize) -> Option<f64> {
        let kf = k as f64;
        let mut s2 = vec![0.0f64; self.count.len()];
        for ((&(_, l), s), q) in self.px.iter().zip(&self.sum).zip(&self.sq) {
            s2[l as usize] += ((q - s * s / kf) / (kf - 1.0)).max(0.0);
        }
        let parts: Vec<f64> = s2
            .iter()
            .zip(&self.count)
            .zip(&self.sampled)
            .filter(|&((_, &n), &m)| n as usize >= min_pixels && m > 0)
            .map(|((s, &n), &m)| s / (n as f64 * m as f64))
            .collect();
        (parts.len() >= 2).then(|| parts.iter().sum::<f64>() / parts.len() as f64)
    }
}

/// The pixels' part of the line-mean variances, burst by burst.
#[derive(Debug, Clone, PartialEq, Default)]
pub(crate) struct LinePixelPart {
    /// The current burst's rows and columns, and its frames so far.
    burst: Option<[Lines; 2]>,
    frames: u32,
    /// Per frame of every finished burst of two frames or more: the rows' and the columns'
    /// pixel part (a burst's value once per frame, as the line-mean variances are kept).
    pub(crate) rows: Vec<f64>,
    pub(crate) cols: Vec<f64>,
}

impl LinePixelPart {
    /// Adds one frame: `flat` the layout's flat pixels (row-major, the same in every frame of a
    /// burst), `counts` its flat pixels per row and per column, `value(i)` the frame's centred
    /// noise at row-major index `i`.
    pub(crate) fn add_frame(
        &mut self,
        flat: &[u32],
        width: usize,
        counts: (&[u32], &[u32]),
        value: impl Fn(usize) -> f64,
    ) {
        let w = width.max(1);
        let lines = self
            .burst
            .get_or_insert_with(|| [Lines::new(flat, counts.0, |i| i / w), Lines::new(flat, counts.1, |i| i % w)]);
        for l in lines.iter_mut() {
            l.add(&value);
        }
        self.frames += 1;
    }

    /// Closes a burst; lines of fewer than `min_pixels` flat pixels are left out (as the line
    /// statistics leave them out).
    pub(crate) fn end_burst(&mut self, min_pixels: usize) {
        let k = self.frames;
        self.frames = 0;
        let Some([rows, cols]) = self.burst.take() else { return };
        if k < 2 {
            return;
        }
        for (acc, lines) in [(&mut self.rows, rows), (&mut self.cols, cols)] {
            if let Some(p) = lines.part(k, min_pixels) {
                acc.extend(std::iter::repeat_n(p, k as usize));
            }
        }
    }

    /// Mean over frames of the rows' (columns') pixel part.
    pub(crate) fn mean(v: &[f64]) -> Option<f64> {
        (!v.is_empty()).then(|| v.iter().sum::<f64>() / v.len() as f64)
    }

    pub(crate) fn merge(&mut self, other: &LinePixelPart) {
        self.rows.extend_from_slice(&other.rows);
        self.cols.extend_from_slice(&other.cols);
    }
}
