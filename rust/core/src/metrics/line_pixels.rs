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

/// The pixels' part of the line-mean variances, burst by burst.
#[derive(Debug, Clone, PartialEq, Default)]
pub(crate) struct LinePixelPart {
    /// The current burst's flat pixels (row-major indices), its image width, and per pixel
    /// `Σv` and `Σv²` over its frames so far.
    px: Vec<u32>,
    width: usize,
    /// The layout's flat pixels per row and per column.
    row_count: Vec<u32>,
    col_count: Vec<u32>,
    sum: Vec<f64>,
    sq: Vec<f64>,
    frames: u32,
    /// Per frame of every finished burst of two frames or more: the rows' and the columns'
    /// pixel part (a burst's value once per frame, as the line-mean variances are kept).
    pub(crate) rows: Vec<f64>,
    pub(crate) cols: Vec<f64>,
}

impl LinePixelPart {
    /// Adds one frame: `flat` the layout's flat pixels (the same in every frame of a burst),
    /// `counts` its flat pixels per row and per column, `value(i)` the frame's centred noise at
    /// row-major index `i`.
    pub(crate) fn add_frame(
        &mut self,
        flat: &[u32],
        width: usize,
        counts: (&[u32], &[u32]),
        value: impl Fn(usize) -> f64,
    ) {
        if self.frames == 0 {
            self.px = flat.to_vec();
            self.width = width;
            self.row_count = counts.0.to_vec();
            self.col_count = counts.1.to_vec();
            self.sum = vec![0.0; flat.len()];
            self.sq = vec![0.0; flat.len()];
        }
        for ((&i, s), q) in self.px.iter().zip(&mut self.sum).zip(&mut self.sq) {
            let v = value(i as usize);
            *s += v;
            *q += v * v;
        }
        self.frames += 1;
    }

    /// Closes a burst; lines of fewer than `min_pixels` flat pixels are left out (as the line
    /// statistics leave them out).
    pub(crate) fn end_burst(&mut self, min_pixels: usize) {
        let k = self.frames;
        self.frames = 0;
        if k < 2 || self.width == 0 {
            return;
        }
        let kf = k as f64;
        let mut row_s2 = vec![0.0f64; self.row_count.len()];
        let mut col_s2 = vec![0.0f64; self.col_count.len()];
        for ((&i, s), q) in self.px.iter().zip(&self.sum).zip(&self.sq) {
            let s2 = ((q - s * s / kf) / (kf - 1.0)).max(0.0);
            let (y, x) = (i as usize / self.width, i as usize % self.width);
            row_s2[y] += s2;
            col_s2[x] += s2;
        }
        for (acc, s2, count) in [(&mut self.rows, row_s2, &self.row_count), (&mut self.cols, col_s2, &self.col_count)] {
            let parts: Vec<f64> = s2
                .iter()
                .zip(count)
                .filter(|&(_, &n)| n as usize >= min_pixels)
                .map(|(s, &n)| s / (n as f64 * n as f64))
                .collect();
            if parts.len() >= 2 {
                let p = parts.iter().sum::<f64>() / parts.len() as f64;
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
