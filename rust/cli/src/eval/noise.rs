//! Noise samples on the flat pixels of an EV step: real noise is `capture − round(clean)`,
//! synthetic noise `synthesized − round(clean)`, both on the clean image of the step's reference
//! burst. Levels are taken above black: the clean image and every frame are carried onto the
//! pack's black level ([`SensorLayout::align_to`](noisecal_core::SensorLayout::align_to)) before
//! they are binned or synthesized on.

use std::borrow::Cow;

use anyhow::Context;
use ndarray::{Array2, ArrayView2};
use noisecal_core::calibrate::flat::NOT_FLAT;
use noisecal_core::metrics::NoiseSamples;
use noisecal_core::metrics::spatial::{FlatLayout, SpatialSamples};
use noisecal_core::{BlackAlignment, FrameMeta, POSITIONS, SensorLayout, position};

/// A flat pixel: index, CFA position, clean level (on the pack's black).
#[derive(Clone, Copy)]
struct FlatPx {
    idx: u32,
    pos: u8,
    clean: u16,
}

/// The clean image of a step on the pack's black level, with its flat pixels.
pub(super) struct StepClean {
    /// Row-major levels, [`NOT_FLAT`] off flat regions.
    levels: Vec<u16>,
    width: usize,
    height: usize,
    flat: Vec<FlatPx>,
    /// The held-out set's black level: frames whose metadata reports none have it.
    black: [f32; POSITIONS],
    /// The pack's layout: the black level everything is carried onto, and its white level.
    pack: SensorLayout,
    /// The flat pixels as the spatial measures use them (rows, columns, NPS crops).
    spatial: FlatLayout,
}

impl StepClean {
    /// `clean` (row-major, `width` wide, at black level `black`) carried onto `pack`'s black.
    pub(super) fn new(
        clean: &[u16],
        width: usize,
        height: usize,
        black: [f32; POSITIONS],
        pack: &SensorLayout,
    ) -> Self {
        let align = BlackAlignment::between(black, pack.black);
        let white = pack.white as i32;
        let levels: Vec<u16> = if align.is_identity() {
            clean.to_vec()
        } else {
            clean
                .iter()
                .enumerate()
                .map(|(i, &c)| {
                    if c == NOT_FLAT {
                        c
                    } else {
                        align.level(position(i / width, i % width), c).clamp(0, white) as u16
                    }
                })
                .collect()
        };
        let flat = levels
            .iter()
            .enumerate()
            .filter(|(_, c)| **c != NOT_FLAT)
            .map(|(i, &c)| FlatPx { idx: i as u32, pos: position(i / width, i % width) as u8, clean: c })
            .collect();
        let spatial = FlatLayout::new(width, height, |i| levels[i] != NOT_FLAT);
        Self { levels, width, height, flat, black, pack: pack.clone(), spatial }
    }

    /// The clean levels as an image (synthesis input).
    pub(super) fn view(&self) -> anyhow::Result<ArrayView2<'_, u16>> {
        ArrayView2::from_shape((self.height, self.width), self.levels.as_slice()).context("clean image shape")
    }

    /// How a frame's levels carry onto the pack's black level.
    pub(super) fn frame_alignment(&self, meta: &FrameMeta) -> BlackAlignment {
        BlackAlignment::between(meta.black.unwrap_or(self.black), self.pack.black)
    }

    /// A real frame carried onto the pack's black level (an input to re-noise).
    pub(super) fn align_frame<'a>(&self, meta: &FrameMeta, img: &'a Array2<u16>) -> Cow<'a, Array2<u16>> {
        let align = self.frame_alignment(meta);
        if align.is_identity() { Cow::Borrowed(img) } else { Cow::Owned(align.apply(img.view(), self.pack.white)) }
    }

    /// Adds the real noise of a frame.
    pub(super) fn add_real(&self, samples: &mut NoiseSamples, meta: &FrameMeta, img: &Array2<u16>) {
        self.add(samples, img, &self.frame_alignment(meta));
    }

    /// Adds the noise of an image synthesized on this clean image.
    pub(super) fn add_synthetic(&self, samples: &mut NoiseSamples, img: &Array2<u16>) {
        self.add(samples, img, &BlackAlignment::between(self.pack.black, self.pack.black));
    }

    /// Adds the spatial statistics of a real frame's noise.
    pub(super) fn add_real_spatial(&self, acc: &mut SpatialSamples, meta: &FrameMeta, img: &Array2<u16>) {
        acc.add_frame(&self.spatial, &self.noise_image(img, &self.frame_alignment(meta)));
    }

    /// Adds the spatial statistics of the noise of an image synthesized on this clean image.
    pub(super) fn add_synthetic_spatial(&self, acc: &mut SpatialSamples, img: &Array2<u16>) {
        acc.add_frame(
            &self.spatial,
            &self.noise_image(img, &BlackAlignment::between(self.pack.black, self.pack.black)),
        );
    }

    /// `img − clean` at the flat pixels (0 elsewhere), row-major, `img` carried by `align`.
    fn noise_image(&self, img: &Array2<u16>, align: &BlackAlignment) -> Vec<i32> {
        let data: Cow<'_, [u16]> = match img.as_slice() {
            Some(s) => Cow::Borrowed(s),
            None => Cow::Owned(img.iter().copied().collect()),
        };
        let mut out = vec![0i32; self.width * self.height];
        for px in &self.flat {
            out[px.idx as usize] = align.level(px.pos as usize, data[px.idx as usize]) - px.clean as i32;
        }
        out
    }

    /// Adds `img − clean` of the flat pixels, `img` carried by `align` (unclamped: noise).
    fn add(&self, samples: &mut NoiseSamples, img: &Array2<u16>, align: &BlackAlignment) {
        let data: Cow<'_, [u16]> = match img.as_slice() {
            Some(s) => Cow::Borrowed(s),
            None => Cow::Owned(img.iter().copied().collect()),
        };
        for px in &self.flat {
            let v = align.level(px.pos as usize, data[px.idx as usize]);
            samples.add(px.pos as usize, px.clean as f32, v - px.clean as i32);
        }
    }
}

/// Seed of synthetic set `s` for the `frame`-th real frame: every frame its own stream.
pub(super) fn synth_seed(s: u32, frame: u64) -> u64 {
    ((s as u64) << 40) ^ frame
}
