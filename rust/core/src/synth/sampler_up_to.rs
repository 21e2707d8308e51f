//! A sampler built for one image's levels ([`SamplerUpTo`]): it draws only images whose clean
//! levels are all at most the level it was built up to, and refuses the others.

use ndarray::{Array2, ArrayView2};

use crate::model::pack::{IsoModel, ModelPack};
use crate::model::structure::{Components, IsoStructure};
use crate::synth::sampler::{BinTable, IsoSampler};
use crate::synth::{BAND_ROWS, clean_row, synthesize_bands_guarded, synthesize_guarded};

/// An image with a clean level above the level a [`SamplerUpTo`] was built up to.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error(
    "clean level {level} (row {row}) is above {top}, the highest level this sampler was built for \
     (a sampler built for one image's levels): build the sampler for this image, or the full one"
)]
pub struct LevelAboveTop {
    pub level: u16,
    pub row: usize,
    pub top: u16,
}

/// [`IsoSampler`] built for clean images whose levels are all at most `top` (a single image's,
/// as `noisecal synth` of one file reads it before the build): the bins that hold no level up
/// to `top` are not deconvolved, and their tables draw from the model's own bins, with the
/// structured offsets counted twice. So it draws nothing but through [`Self::synthesize_at`]
/// and [`Self::synthesize_bands`], which refuse an image with a level above `top`
/// ([`LevelAboveTop`]) before any of its noise is drawn in the band that holds it: each band's
/// clean rows are checked as the band begins (one pass over rows the draw reads next, from
/// cache), not pixel by pixel. An image within `top` gets the bytes the full sampler
/// ([`IsoSampler::with_structure`]) gives it.
#[derive(Debug, Clone)]
pub struct SamplerUpTo {
    sampler: IsoSampler,
    top: u16,
}

impl SamplerUpTo {
    /// The sampler of `model` with the structured components `structure` (those `which` asks
    /// for; [`IsoSampler::with_structure`]) for clean levels up to `top`.
    pub fn new(
        pack: &ModelPack,
        model: &IsoModel,
        structure: Option<&IsoStructure>,
        which: Components,
        top: u16,
    ) -> Self {
        Self { sampler: IsoSampler::built_up_to(pack, model, structure, which, top), top }
    }

    /// A sampler of every level (`sampler`) that draws those up to `top` alone, as a sampler
    /// built for them does.
    pub(crate) fn full(sampler: IsoSampler, top: u16) -> Self {
        Self { sampler, top }
    }

    /// The same sampler for the same levels with `f` applied to the inner one (which must keep
    /// its tables up to `top` those of the full sampler given the same `f`).
    pub(crate) fn map<E>(self, f: impl FnOnce(IsoSampler) -> Result<IsoSampler, E>) -> Result<Self, E> {
        Ok(Self { sampler: f(self.sampler)?, top: self.top })
    }

    /// The highest clean level this sampler draws.
    pub fn top(&self) -> u16 {
        self.top
    }

    /// The ISO the sampler draws.
    pub fn iso(&self) -> u32 {
        self.sampler.iso
    }

    /// [`IsoSampler::target_gains`].
    pub fn target_gains(&self) -> Option<[f64; crate::POSITIONS]> {
        self.sampler.target_gains()
    }

    /// The table a clean level at a position draws from; `None` above [`Self::top`].
    pub fn table(&self, pos: usize, level: u16) -> Option<&BinTable> {
        (level <= self.top).then(|| self.sampler.table(pos, level))
    }

    /// Every table of a position ([`IsoSampler::tables`]), those past `top` included: to compare
    /// builds, not to draw.
    pub fn tables(&self, pos: usize) -> &[BinTable] {
        self.sampler.tables(pos)
    }

    /// [`IsoSampler::set_pattern_cache_bytes`].
    pub fn set_pattern_cache_bytes(&self, bytes: usize) {
        self.sampler.set_pattern_cache_bytes(bytes);
    }

    /// [`crate::synth::synthesize_at`] with this sampler, or the first band's level above `top`.
    pub fn synthesize_at(
        &self,
        clean: ArrayView2<'_, u16>,
        seed: u64,
        origin: (usize, usize),
    ) -> Result<Array2<u16>, LevelAboveTop> {
        synthesize_guarded(&self.sampler, clean, seed, origin, |band| self.check(&clean, band))
    }

    /// [`crate::synth::synthesize_bands`] with this sampler. Refused bands reach no sink; bands
    /// drawn before the refusal may have (the caller drops what they went to).
    pub fn synthesize_bands<F>(
        &self,
        clean: ArrayView2<'_, u16>,
        seed: u64,
        origin: (usize, usize),
        sink: F,
    ) -> Result<(), LevelAboveTop>
    where
        F: Fn(usize, &[u16]) + Sync,
    {
        synthesize_bands_guarded(&self.sampler, clean, seed, origin, sink, |band| self.check(&clean, band))
    }

    /// Whether band `band` of `clean` stays within `top`: the first level above it otherwise.
    fn check(&self, clean: &ArrayView2<'_, u16>, band: usize) -> Result<(), LevelAboveTop> {
        let h = clean.dim().0;
        for y in band * BAND_ROWS..h.min((band + 1) * BAND_ROWS) {
            let row = clean_row(clean, y);
            // A max the compiler vectorises; the position only when refusing.
            if row.iter().copied().max().is_some_and(|m| m > self.top) {
                let level = row.iter().copied().find(|&l| l > self.top).unwrap_or(self.top);
                return Err(LevelAboveTop { level, row: y, top: self.top });
            }
        }
        Ok(())
    }
}
