//! The fixed pattern of an image region kept between synthesis calls. The pattern is the
//! sensor's (a hash of each pixel's position through the pack's quantile function, plus the
//! shading), the same in every image: a training pipeline that synthesizes many images of one
//! size at one origin would otherwise compute it anew, pixel by pixel, for every image. A region
//! is kept from its second request on (a single image pays nothing for it), one region per
//! sampler, of at most the sampler's limit in bytes (8 per pixel; [`DEFAULT_PATTERN_CACHE_BYTES`]
//! unless set: a process with many samplers, or many DataLoader workers, lowers it, and 0 keeps
//! nothing). What is kept changes only the time: kept or computed, the values are the same.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

/// Bytes a sampler's kept region may hold unless set otherwise: 24 Mpx of 8 bytes, 192 MiB.
pub const DEFAULT_PATTERN_CACHE_BYTES: usize = 192 << 20;

/// Bytes one pixel of a kept region takes.
const PIXEL_BYTES: usize = std::mem::size_of::<i64>();

/// An image region in sensor pixels: its first row and column, its height and width.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct Region {
    pub(crate) origin: (usize, usize),
    pub(crate) height: usize,
    pub(crate) width: usize,
}

/// The fixed pattern of one region, 2⁻³² DN per pixel, row by row.
#[derive(Debug)]
pub(crate) struct PatternRegion {
    region: Region,
    values: Vec<i64>,
}

impl PatternRegion {
    /// Row `y` of the region (0 = its first).
    #[inline]
    pub(crate) fn row(&self, y: usize) -> &[i64] {
        let w = self.region.width;
        &self.values[y * w..(y + 1) * w]
    }
}

/// What a sampler keeps: the region last asked for, and the pattern of the one kept.
#[derive(Debug)]
pub(crate) struct PatternCache {
    state: Mutex<CacheState>,
    /// The most bytes a kept region may take (0: nothing is kept).
    limit_bytes: AtomicUsize,
}

impl Default for PatternCache {
    fn default() -> Self {
        Self { state: Mutex::default(), limit_bytes: AtomicUsize::new(DEFAULT_PATTERN_CACHE_BYTES) }
    }
}

#[derive(Debug, Default)]
struct CacheState {
    last_asked: Option<Region>,
    kept: Option<Arc<PatternRegion>>,
}

impl PatternCache {
    /// The most bytes a kept region may take.
    pub(crate) fn limit_bytes(&self) -> usize {
        self.limit_bytes.load(Ordering::Relaxed)
    }

    /// Sets the most bytes a kept region may take; a kept region larger than that is let go.
    pub(crate) fn set_limit_bytes(&self, bytes: usize) {
        self.limit_bytes.store(bytes, Ordering::Relaxed);
        if let Ok(mut s) = self.state.lock()
            && s.kept.as_ref().is_some_and(|k| k.region.height.saturating_mul(k.region.width) > bytes / PIXEL_BYTES)
        {
            s.kept = None;
        }
    }

    /// The pattern of `region` when it is kept, or was asked for just before (then computed
    /// now, in parallel, and kept); `None`: the caller computes it row by row. `filler` is called
    /// only when the region is computed here: it gives the function that writes the pattern of
    /// sensor row `y` onto a row of zeros, the same function the caller's row-by-row path uses,
    /// so the kept values are its values bit for bit.
    pub(crate) fn get<F>(&self, region: Region, filler: impl FnOnce() -> F) -> Option<Arc<PatternRegion>>
    where
        F: Fn(usize, &mut [i64]) + Sync,
    {
        {
            // A poisoned lock only loses the cache.
            let mut s = self.state.lock().ok()?;
            if let Some(k) = &s.kept
                && k.region == region
            {
                return Some(k.clone());
            }
            let again = s.last_asked == Some(region);
            s.last_asked = Some(region);
            let max_pixels = self.limit_bytes() / PIXEL_BYTES;
            if !again || region.height.saturating_mul(region.width) > max_pixels || region.width == 0 {
                return None;
            }
        }
        // Built outside the lock: rayon may run another synthesis call's band on this thread
        // while it waits, and that call takes the lock.
        let fill = filler();
        let mut values = vec![0i64; region.height * region.width];
        values.par_chunks_mut(region.width).enumerate().for_each(|(y, row)| fill(region.origin.0 + y, row));
        let kept = Arc::new(PatternRegion { region, values });
        if let Ok(mut s) = self.state.lock() {
            // Kept only if the limit still allows it (it may have been lowered meanwhile).
            let max_pixels = self.limit_bytes() / PIXEL_BYTES;
            s.kept = (region.height.saturating_mul(region.width) <= max_pixels).then(|| kept.clone());
        }
        Some(kept)
    }
}
