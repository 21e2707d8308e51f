//! `noisecal.Pack`: a model pack and what can be done with it from numpy.

use std::collections::HashMap;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use ndarray::{Array2, Array3, ArrayD, ArrayView2, Axis};
use numpy::{PyArray1, PyArray2, PyArray3, PyArrayDyn};

use pyo3::prelude::*;
use pyo3::types::{PyBytes, PyDict};

use noisecal_core::derive::interp::{self, InterpOptions};
use noisecal_core::model::layout::{BlackAlignment, position};
use noisecal_core::model::structure::Components;
use noisecal_core::renoise::{Method, Renoiser};
use noisecal_core::resolve::ModelKind;
use noisecal_core::synth::sampler::IsoSampler;
use noisecal_core::synth::{CleanAt, DEFAULT_PATTERN_CACHE_BYTES, synthesize_at};
use noisecal_core::{ModelPack, POSITIONS};

use crate::checks::{self, OutOfRange, images};
use crate::errors::{err, guarded, input, to_py};
use crate::pack_source::PackSource;
use crate::pool;

/// A sampler cache key: ISO, model, extrapolate, components, brightness of the clean image.
type SamplerKey = (u32, ModelKind, bool, Components, CleanAt);

/// A renoiser cache key: source ISO, target ISO, method, extrapolate (the bridge options are the
/// defaults, the only ones the binding offers).
type RenoiserKey = (u32, u32, Method, bool);

/// A calibrated noise model of one camera (a `.pack` file).
#[derive(Debug)]
#[pyclass(frozen, module = "noisecal")]
pub struct Pack {
    /// Its models: read from its file on demand, or made in memory (shared by copies).
    pub(crate) source: Arc<PackSource>,
    /// Samplers already built, by (ISO, model, extrapolate, components): building one costs more
    /// than synthesizing a small crop, and a training loop asks for the same few ISOs again and
    /// again.
    samplers: Mutex<HashMap<SamplerKey, Arc<IsoSampler>>>,
    /// The most bytes each sampler keeps of a fixed pattern between calls (`pattern_cache_mb`).
    pattern_cache_bytes: AtomicUsize,
    /// Renoisers already built, by (source ISO, target ISO, method, extrapolate): a bridge is a
    /// deconvolution per bin, and a training set re-noises many captures with the same pair.
    /// Locked only while the GIL is held (never inside `py.detach`), so no other thread can hold
    /// it when a thread forks the process: a forked child never finds it locked.
    renoisers: Mutex<HashMap<RenoiserKey, Arc<Renoiser>>>,
}

impl Pack {
    pub(crate) fn new(pack: ModelPack) -> Self {
        Self::sharing(Arc::new(PackSource::decoded(pack)), DEFAULT_PATTERN_CACHE_BYTES)
    }

    /// A pack file's bytes, read on demand (each ISO decoded when a sampler first needs it).
    fn from_file(file: noisecal_core::format::lazy_pack::LazyPack<Vec<u8>>) -> Self {
        Self::sharing(Arc::new(PackSource::on_demand(file)), DEFAULT_PATTERN_CACHE_BYTES)
    }

    /// A pack of these models with no sampler built yet.
    fn sharing(source: Arc<PackSource>, pattern_cache_bytes: usize) -> Self {
        Self {
            source,
            samplers: Mutex::new(HashMap::new()),
            pattern_cache_bytes: AtomicUsize::new(pattern_cache_bytes),
            renoisers: Mutex::new(HashMap::new()),
        }
    }

    /// The renoiser of `from_iso → to_iso` with `method`, built once per pack (the build runs
    /// without the GIL; the cache is looked up and filled with it, see `renoisers`). Two threads
    /// asking at once may both build it; the first one stored is kept, and both are the same.
    fn renoiser(
        &self,
        py: Python<'_>,
        from_iso: u32,
        to_iso: u32,
        method: Method,
        extrapolate: bool,
    ) -> PyResult<Arc<Renoiser>> {
        let key = (from_iso, to_iso, method, extrapolate);
        let poisoned = || err("the renoiser cache was poisoned");
        if let Some(r) = self.renoisers.lock().map_err(|_| poisoned())?.get(&key) {
            return Ok(r.clone());
        }
        let pack = &self.source.fields;
        let built = py.detach(|| {
            guarded("Pack.renoise", || {
                pool::run(|| {
                    let model = |iso: u32, which: &str| {
                        self.source
                            .resolve(iso, ModelKind::Noisecal, Components::PIXEL, extrapolate)
                            .map(|r| r.1.model)
                            .map_err(|e| err(format!("no model for the {which} ISO {iso}: {e}")))
                    };
                    let (source, target) = (model(from_iso, "source")?, model(to_iso, "target")?);
                    Renoiser::new(pack, &source, &target, method).map_err(to_py)
                })
            })
        })?;
        Ok(self.renoisers.lock().map_err(|_| poisoned())?.entry(key).or_insert_with(|| Arc::new(built)).clone())
    }

    /// The sampler of `iso` for a model kind and noise components, built once per pack. The
    /// parametric baselines are pixel-independent models: they get no structured components.
    fn sampler(
        &self,
        iso: u32,
        kind: ModelKind,
        extrapolate: bool,
        which: Components,
        clean_at: CleanAt,
    ) -> PyResult<Arc<IsoSampler>> {
        let which = kind.components(Some(which));
        let key = (iso, kind, extrapolate, which, clean_at);
        if let Some(s) = self.samplers.lock().map_err(|_| err("a sampler cache was poisoned"))?.get(&key) {
            return Ok(s.clone());
        }
        // Only the ISOs the model stands on are decoded (once per pack file).
        let (pack, resolved) = self.source.resolve(iso, kind, which, extrapolate)?;
        let s = Arc::new(resolved.sampler(&pack, which, clean_at, extrapolate).map_err(to_py)?);
        s.set_pattern_cache_bytes(self.pattern_cache_bytes.load(Ordering::Relaxed));
        self.samplers.lock().map_err(|_| err("a sampler cache was poisoned"))?.insert(key, s.clone());
        Ok(s)
    }
}

/// `None` → every calibrated component; else a comma-separated list (`"pixel,row,column,frame,fpn"`).
fn parse_components(which: Option<&str>) -> PyResult<Components> {
    match which {
        None => Ok(Components::ALL),
        Some(s) => Components::parse(s).map_err(input),
    }
}

/// `clean_at="reference"|"target"`.
fn parse_clean_at(s: &str) -> PyResult<CleanAt> {
    CleanAt::parse(s).map_err(|e| input(e.replace("clean-at", "clean_at")))
}

/// `model="noisecal"|"hg"|"pg"|"noiseprofile"` (the core's names, any case).
fn parse_model(name: &str) -> PyResult<ModelKind> {
    ModelKind::parse(name).map_err(input)
}

/// Per-position black levels for the input: the pack's, one number, or four (CFA order).
fn black_levels(pack: &ModelPack, black_level: Option<Vec<f64>>) -> PyResult<[f32; POSITIONS]> {
    if let Some(v) = &black_level {
        checks::black_values(v, pack.layout.white)?;
    }
    match black_level.as_deref() {
        None => Ok(pack.layout.black),
        Some([b]) => Ok([*b as f32; POSITIONS]),
        Some(v) if v.len() == POSITIONS => Ok(std::array::from_fn(|p| v[p] as f32)),
        Some(v) => Err(input(format!(
            "black_level has {} values: give one number, or four in CFA order (top-left, top-right, bottom-left, bottom-right)",
            v.len()
        ))),
    }
}

/// Synthesizes one image whose black level may differ from the pack's: levels are taken above
/// black (the image is carried onto the pack's black level, synthesized, and carried back:
/// [`BlackAlignment::around`]), as `noisecal synth` does.
fn synth_one(
    pack: &ModelPack,
    sampler: &IsoSampler,
    clean: ArrayView2<'_, u16>,
    black: &[f32; POSITIONS],
    seed: u64,
    origin: (usize, usize),
) -> Array2<u16> {
    BlackAlignment::between(*black, pack.layout.black)
        .around(clean, pack.layout.white, origin, |c| synthesize_at(sampler, c, seed, origin))
}

/// The structured components `synth` adds at `iso` by default (`components=None`), which the
/// tables leave out: `row`, `column`, `frame`, `fpn` (none for the parametric baselines).
fn structured_components(pack: &ModelPack, iso: u32, kind: ModelKind) -> Vec<&'static str> {
    if kind != ModelKind::Noisecal {
        return Vec::new();
    }
    let Some(st) = noisecal_core::derive::structure::structure_at(pack, iso) else { return Vec::new() };
    [
        ((0..2).any(|p| st.row(p).is_some()), "row"),
        ((0..2).any(|p| st.column(p).is_some()), "column"),
        (st.frame().is_some(), "frame"),
        (st.fixed_pattern().is_some(), "fpn"),
    ]
    .into_iter()
    .filter_map(|(on, name)| on.then_some(name))
    .collect()
}

/// `f(image, seed + i)` for image `i` of a batch (a folder run of the CLI numbers its files the
/// same way).
fn per_image<T, U>(
    imgs: &[ArrayView2<'_, T>],
    seed: u64,
    f: impl Fn(ArrayView2<'_, T>, u64) -> PyResult<U>,
) -> PyResult<Vec<U>> {
    imgs.iter().enumerate().map(|(i, img)| f(img.view(), seed.wrapping_add(i as u64))).collect()
}

/// The outputs as one array: `(H, W)`, or `(N, H, W)` for a batch.
fn stack<T: Clone + Default>(mut outs: Vec<Array2<T>>, batch: bool) -> ArrayD<T> {
    if !batch && outs.len() == 1 {
        return outs.pop().expect("one image").into_dyn();
    }
    let (h, w) = outs.first().map(|o| o.dim()).unwrap_or((0, 0));
    let mut all = Array3::<T>::from_elem((outs.len(), h, w), T::default());
    for (mut dst, src) in all.axis_iter_mut(Axis(0)).zip(outs) {
        dst.assign(&src);
    }
    all.into_dyn()
}

#[pymethods]
impl Pack {
    /// Loads a model pack from a file.
    #[staticmethod]
    fn load(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        py.detach(|| {
            guarded("Pack.load", || {
                pool::run(|| noisecal_input::files::open_pack(&path).map(Self::from_file).map_err(to_py))
            })
        })
    }

    /// Decodes a model pack from bytes.
    #[staticmethod]
    fn from_bytes(py: Python<'_>, data: &[u8]) -> PyResult<Self> {
        py.detach(|| {
            guarded("Pack.from_bytes", || {
                pool::run(|| {
                    noisecal_core::format::lazy_pack::LazyPack::open(data.to_vec())
                        .map(Self::from_file)
                        .map_err(|e| err(format!("cannot load the model pack: {e}")))
                })
            })
        })
    }

    /// The pack as bytes (what `save` writes).
    fn to_bytes<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyBytes>> {
        let b = py.detach(|| self.source.to_bytes())?;
        Ok(PyBytes::new(py, &b))
    }

    /// Writes the pack atomically (a temporary file, then a rename).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let source = self.source.clone();
        py.detach(move || {
            let b = source.to_bytes()?;
            noisecal_input::files::write_atomic(&path, &b).map_err(to_py)
        })
    }

    /// Every ISO the pack holds (calibrated and derived), ascending.
    #[getter]
    fn isos(&self) -> Vec<u32> {
        self.source.isos().to_vec()
    }

    /// The calibrated ISOs, ascending.
    #[getter]
    fn calibrated_isos(&self) -> Vec<u32> {
        self.source.calibrated_isos().to_vec()
    }

    /// The sensor: CFA, black levels per CFA position, white level, bit depth, size.
    #[getter]
    fn layout<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let l = &self.source.fields.layout;
        let d = PyDict::new(py);
        d.set_item("cfa", l.cfa.name())?;
        d.set_item("black", l.black.to_vec())?;
        d.set_item("white", l.white)?;
        d.set_item("bits", l.bit_depth())?;
        d.set_item("width", l.width)?;
        d.set_item("height", l.height)?;
        Ok(d)
    }

    #[getter]
    fn make(&self) -> String {
        self.source.fields.make.clone()
    }

    #[getter]
    fn model(&self) -> String {
        self.source.fields.model.clone()
    }

    /// Levels per bin (DN).
    #[getter]
    fn bin_width(&self) -> u16 {
        self.source.fields.bin_width
    }

    /// What the calibration noticed.
    #[getter]
    fn warnings(&self) -> Vec<String> {
        self.source.fields.warnings.clone()
    }

    fn __repr__(&self) -> String {
        format!(
            "<noisecal.Pack {} {} {} ISOs {}>",
            self.source.fields.make,
            self.source.fields.model,
            self.source.fields.layout.cfa.name(),
            self.source.isos().iter().map(|i| i.to_string()).collect::<Vec<_>>().join(", ")
        )
    }

    /// Memory (MiB) each of this pack's samplers may keep of the sensor's fixed pattern between
    /// calls (default 192): a loop over images of one size and `cfa_origin` then reuses it
    /// instead of computing it pixel by pixel. Set it with `set_pattern_cache_mb`.
    #[getter]
    fn pattern_cache_mb(&self) -> usize {
        self.pattern_cache_bytes.load(Ordering::Relaxed) >> 20
    }

    /// Sets the memory (MiB) each sampler of this pack may keep of the fixed pattern (0: none,
    /// every image computes it). The images are the same whatever the setting: only time and
    /// memory change. Copies and pickles (DataLoader workers) keep the setting.
    fn set_pattern_cache_mb(&self, mb: usize) -> PyResult<()> {
        let bytes = mb.saturating_mul(1 << 20);
        self.pattern_cache_bytes.store(bytes, Ordering::Relaxed);
        for s in self.samplers.lock().map_err(|_| err("a sampler cache was poisoned"))?.values() {
            s.set_pattern_cache_bytes(bytes);
        }
        Ok(())
    }

    /// Pickling (multiprocessing with spawn, Ray, DataLoader workers): the pack's bytes and its
    /// `pattern_cache_mb`, decoded again by `noisecal.Pack.from_bytes` on the other side.
    #[allow(clippy::type_complexity)]
    fn __reduce__<'py>(&self, py: Python<'py>) -> PyResult<(Bound<'py, PyAny>, (Bound<'py, PyBytes>, usize))> {
        let ctor = py.import("noisecal")?.getattr("_pack_from_bytes")?;
        Ok((ctor, (self.to_bytes(py)?, self.pattern_cache_mb())))
    }

    /// A pack is immutable: a copy shares its models (and builds its own samplers).
    fn __copy__(&self) -> Self {
        Self::sharing(self.source.clone(), self.pattern_cache_bytes.load(Ordering::Relaxed))
    }

    /// As `__copy__`: nothing in a pack can change, so sharing its models is a deep copy.
    fn __deepcopy__(&self, _memo: &Bound<'_, PyAny>) -> Self {
        self.__copy__()
    }

    /// Adds noise at `iso` to clean raw images (uint16 DN, black included), `(H, W)` or
    /// `(N, H, W)`; image `i` of a batch uses seed `seed + i` (a folder's files are seeded by
    /// name instead: `noisecal.seed_for`). `components` chooses the noise components
    /// (`"pixel,row,column,frame,fpn"`; default: all the pack calibrated), as `noisecal synth
    /// --components`. The rule: a clean image from your own burst means (this sensor's frames
    /// averaged) carries the sensor's fixed pattern already, so pass `components="own"` (the same
    /// as `"pixel,row,column,frame"`: every component but `fpn`); a clean image without it
    /// (rendered, another camera's, denoised) takes the default. `clean_at` is the brightness the clean image is at, as `noisecal synth
    /// --clean-at`: `"reference"` (default: the reference ISO's brightness for the same ISO ×
    /// exposure; the output gets the target ISO's, its gain ratios `gain_ratios(iso)` applied) or
    /// `"target"` (already at the target ISO's brightness: the noise has no mean shift).
    /// Pixels above the pack's white level are refused (`out_of_range="raise"`); with `"warn"`
    /// or `"allow"` they keep their level, draw from the top bin, and the output is clipped to
    /// the sensor's codes (with another `black_level`, they are clipped to white first).
    #[pyo3(signature = (clean, iso, seed=0, *, model="noisecal", black_level=None, cfa_origin=(0, 0), extrapolate=false, components=None, clean_at="reference", out_of_range="raise"))]
    #[allow(clippy::too_many_arguments)]
    fn synth<'py>(
        &self,
        py: Python<'py>,
        clean: &Bound<'py, PyAny>,
        iso: u32,
        seed: u64,
        model: &str,
        black_level: Option<Vec<f64>>,
        cfa_origin: (usize, usize),
        extrapolate: bool,
        components: Option<&str>,
        clean_at: &str,
        out_of_range: &str,
    ) -> PyResult<Bound<'py, PyArrayDyn<u16>>> {
        let clean = checks::array::<u16>(clean, "clean", "uint16", |got| {
            if got.contains("float") {
                "raw DN as uint16 (np.rint(clean).astype(np.uint16)); for float32 levels normalised by black and white use synth_float".into()
            } else {
                "raw DN, black included: clean.astype(np.uint16) once its values are within [0, white]".into()
            }
        })?;
        let kind = parse_model(model)?;
        let which = parse_components(components)?;
        let clean_at = parse_clean_at(clean_at)?;
        let policy = OutOfRange::parse(out_of_range)?;
        let black = black_levels(&self.source.fields, black_level)?;
        let view = clean.as_array();
        let (imgs, batch) = images(&view, "clean")?;
        let pack = &self.source.fields;
        checks::levels_in_range(
            py,
            &imgs,
            "clean",
            pack,
            policy,
            "synthesize them at their level (drawn from the top bin, the output clipped to the sensor's codes)",
        )?;
        let outs = py.detach(|| {
            guarded("Pack.synth", || {
                pool::run(|| {
                    let sampler = self.sampler(iso, kind, extrapolate, which, clean_at)?;
                    per_image(&imgs, seed, |img, s| Ok(synth_one(pack, &sampler, img, &black, s, cfa_origin)))
                })
            })
        })?;
        Ok(PyArrayDyn::from_owned_array(py, stack(outs, batch)))
    }

    /// As `synth`, for float32 images normalised by black and white (`(DN − black)/(white −
    /// black)` per CFA position, the usual torch input): the result is normalised the same way.
    /// `clean_at` as in `synth`. NaN and infinities are refused; levels outside the pack's codes
    /// (below DN 0 or above white once denormalised) are refused (`out_of_range="raise"`), or
    /// clamped to them with `"warn"` (and a warning with the counts) or `"allow"`.
    #[pyo3(signature = (clean, iso, seed=0, *, model="noisecal", cfa_origin=(0, 0), extrapolate=false, components=None, clean_at="reference", out_of_range="raise"))]
    #[allow(clippy::too_many_arguments)]
    fn synth_float<'py>(
        &self,
        py: Python<'py>,
        clean: &Bound<'py, PyAny>,
        iso: u32,
        seed: u64,
        model: &str,
        cfa_origin: (usize, usize),
        extrapolate: bool,
        components: Option<&str>,
        clean_at: &str,
        out_of_range: &str,
    ) -> PyResult<Bound<'py, PyArrayDyn<f32>>> {
        let clean = checks::array::<f32>(clean, "clean", "float32", |got| {
            if got.contains("uint16") {
                "for uint16 DN use synth; synth_float takes float32 levels normalised by black and white".into()
            } else {
                "pass clean.astype(np.float32), levels normalised by black and white: (DN − black)/(white − black)"
                    .into()
            }
        })?;
        let kind = parse_model(model)?;
        let which = parse_components(components)?;
        let clean_at = parse_clean_at(clean_at)?;
        let policy = OutOfRange::parse(out_of_range)?;
        let view = clean.as_array();
        let (imgs, batch) = images(&view, "clean")?;
        let pack = &self.source.fields;
        checks::floats_in_range(py, &imgs, "clean", pack, cfa_origin, policy)?;
        let black = pack.layout.black;
        let white = pack.layout.white as f32;
        let scale: [f32; POSITIONS] = std::array::from_fn(|p| (white - black[p]).max(1.0));
        let outs = py.detach(|| {
            guarded("Pack.synth_float", || {
                pool::run(|| {
                    let sampler = self.sampler(iso, kind, extrapolate, which, clean_at)?;
                    let pos = |y: usize, x: usize| position(y + cfa_origin.0, x + cfa_origin.1);
                    per_image(&imgs, seed, |img, s| {
                        let dn = Array2::from_shape_fn(img.dim(), |(y, x)| {
                            let p = pos(y, x);
                            (img[(y, x)] * scale[p] + black[p]).round().clamp(0.0, white) as u16
                        });
                        let out = synthesize_at(&sampler, dn.view(), s, cfa_origin);
                        Ok(Array2::from_shape_fn(out.dim(), |(y, x)| {
                            let p = pos(y, x);
                            (out[(y, x)] as f32 - black[p]) / scale[p]
                        }))
                    })
                })
            })
        })?;
        Ok(PyArrayDyn::from_owned_array(py, stack(outs, batch)))
    }

    /// Turns captures at `from_iso` into captures at the higher `to_iso` (noise on noise), as
    /// `noisecal renoise` does; `method` is "bridge" (default), "quantile", "denoised" or "naive".
    /// `black_level` is the captures' black level (default: the pack's; one number, or four in
    /// CFA order): captures with another one are carried onto the pack's, re-noised, and carried
    /// back, as `noisecal renoise` does with a DNG's own black level.
    /// Pixels above the pack's white level are refused unless `out_of_range` is "warn" or "allow".
    /// `estimate` is your own clean estimate of the captures (float, DN on the captures' black
    /// level, the shape of `noisy`), as `noisecal renoise --estimate`: it picks each pixel's bin
    /// (bridge, quantile, denoised); without it the built-in filter estimates it. The renoiser of
    /// an ISO pair and method (the bridge's deconvolution, the tables) is built on the first call
    /// and kept by this Pack (not by its copies), so later calls only draw.
    #[pyo3(signature = (noisy, from_iso, to_iso, seed=0, *, method="bridge", black_level=None, extrapolate=false, out_of_range="raise", estimate=None))]
    #[allow(clippy::too_many_arguments)]
    fn renoise<'py>(
        &self,
        py: Python<'py>,
        noisy: &Bound<'py, PyAny>,
        from_iso: u32,
        to_iso: u32,
        seed: u64,
        method: &str,
        black_level: Option<Vec<f64>>,
        extrapolate: bool,
        out_of_range: &str,
        estimate: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyArrayDyn<u16>>> {
        let noisy = checks::array::<u16>(noisy, "noisy", "uint16", |_| {
            "raw DN of captures at from_iso, black included, as read_dng gives them".into()
        })?;
        let estimate = estimate
            .map(|e| {
                checks::array::<f32>(e, "estimate", "float32", |_| {
                    "the clean estimate of each capture in DN, black included: convert with .astype(np.float32)".into()
                })
            })
            .transpose()?;
        let method = Method::parse(method)
            .ok_or_else(|| input(format!("unknown method {method:?}: use bridge, quantile, denoised or naive")))?;
        if to_iso <= from_iso {
            return Err(input(format!(
                "cannot renoise ISO {from_iso} captures to ISO {to_iso}: noise on noise only adds noise, so to_iso must be above from_iso"
            )));
        }
        let policy = OutOfRange::parse(out_of_range)?;
        let black = black_levels(&self.source.fields, black_level)?;
        let view = noisy.as_array();
        let (imgs, batch) = images(&view, "noisy")?;
        let est_view = estimate.as_ref().map(|e| e.as_array());
        let ests = match &est_view {
            Some(v) => {
                if v.shape() != view.shape() {
                    return Err(input(format!(
                        "estimate has shape {:?} but noisy has {:?}: give one clean estimate per capture, of the same size",
                        v.shape(),
                        view.shape()
                    )));
                }
                Some(images(v, "estimate")?.0)
            }
            None => None,
        };
        let pack = &self.source.fields;
        checks::levels_in_range(py, &imgs, "noisy", pack, policy, "re-noise them as they are")?;
        let align = BlackAlignment::between(black, pack.layout.black);
        let r = self.renoiser(py, from_iso, to_iso, method, extrapolate)?;
        let outs = py.detach(|| {
            guarded("Pack.renoise", || {
                pool::run(|| {
                    let white = pack.layout.white;
                    per_image(&imgs, seed, |img, s| {
                        // The estimate of image i (its seed is seed + i), carried onto the pack's
                        // black level as the captures are.
                        let est = ests.as_ref().map(|e| {
                            let e = e[s.wrapping_sub(seed) as usize];
                            Array2::from_shape_fn(e.dim(), |(y, x)| e[(y, x)] + align.shift[position(y, x)] as f32)
                        });
                        align
                            .try_around(img, white, (0, 0), |a| {
                                r.apply(a, est.as_ref().map(|e| e.view()), s).map(|o| o.image)
                            })
                            .map_err(to_py)
                    })
                })
            })
        })?;
        Ok(PyArrayDyn::from_owned_array(py, stack(outs, batch)))
    }

    /// A new pack with models for `isos` derived from the calibrated ones (as `noisecal interp`).
    #[pyo3(signature = (isos, *, extrapolate=false))]
    fn interp(&self, py: Python<'_>, isos: Vec<u32>, extrapolate: bool) -> PyResult<Self> {
        py.detach(|| {
            guarded("Pack.interp", || {
                pool::run(|| {
                    interp::materialize(&*self.source.whole()?, &isos, extrapolate, &InterpOptions::default())
                        .map(|(p, _)| Self::new(p))
                        .map_err(to_py)
                })
            })
        })
    }

    /// The gain ratios of `iso` per CFA position (CFA order): how much brighter above black the
    /// ISO's captures are than the reference ISO's at the same ISO × exposure (1 = gain ∝ ISO).
    /// A calibrated ISO's are measured; an uncalibrated one's are interpolated in log ISO.
    /// `synth(..., clean_at="target")` divides clean levels by them to pick their noise.
    #[pyo3(signature = (iso, *, extrapolate=false))]
    fn gain_ratios(&self, py: Python<'_>, iso: u32, extrapolate: bool) -> PyResult<Vec<f64>> {
        py.detach(|| {
            guarded("Pack.gain_ratios", || {
                pool::run(|| {
                    let pack = self.source.whole()?;
                    interp::gain_ratio_at(&pack, iso, extrapolate).map(|g| g.to_vec()).map_err(to_py)
                })
            })
        })
    }

    /// The sampler's tables at `iso`, for samplers on other devices (`noisecal.torch`):
    /// `lut[p, level]` is the bin of a clean level at CFA position `p`; `cdf[p, bin, i]` the
    /// cumulative weights (units of 2⁻³², padded with 2³²) over noise values `first[p, bin] + i`;
    /// `range[p]` the codes the sensor writes. A uniform 32-bit draw `u` maps to
    /// `first + searchsorted(cdf, u, right=True)`. `lattice` tells where the core also snaps to a
    /// code lattice (not reproduced by table samplers). The tables are the pixel-independent
    /// model, `synth(..., components="pixel")`: the row, column and frame offsets of a version 3
    /// pack are not in them (`structure` lists those `synth` adds at `iso` by default). `gain_ratio[p]` is the ISO's gain ratio per position
    /// (`gain_ratios`). With `clean_at="target"`, `lut` maps a level at the target brightness to
    /// the bin of its reference level and `shift[p, level]` (DN, float64) is added to the draw,
    /// dithered onto the integers (`floor(shift + U[0, 1))`): the gain shift taken out. With
    /// `"reference"` `shift` is all zeros.
    #[pyo3(signature = (iso, *, model="noisecal", extrapolate=false, clean_at="reference"))]
    fn tables<'py>(
        &self,
        py: Python<'py>,
        iso: u32,
        model: &str,
        extrapolate: bool,
        clean_at: &str,
    ) -> PyResult<Bound<'py, PyDict>> {
        let kind = parse_model(model)?;
        let clean_at = parse_clean_at(clean_at)?;
        let pack = &self.source.fields;
        let (sampler, gains, structure) = py.detach(|| {
            guarded("Pack.tables", || {
                pool::run(|| {
                    let s = self.sampler(iso, kind, extrapolate, Components::PIXEL, clean_at)?;
                    let whole = self.source.whole()?;
                    let g = interp::gain_ratio_at(&whole, iso, extrapolate).map_err(to_py)?;
                    Ok((s, g, structured_components(&whole, iso, kind)))
                })
            })
        })?;
        let levels = pack.layout.white as usize + 1;
        let nbins = (0..POSITIONS).map(|p| sampler.tables(p).len()).max().unwrap_or(0);
        let len = (0..POSITIONS).flat_map(|p| sampler.tables(p).iter().map(|t| t.cdf().len())).max().unwrap_or(1);
        let mut lut = Array2::<i64>::zeros((POSITIONS, levels));
        let mut cdf = Array3::<u64>::from_elem((POSITIONS, nbins, len), 1u64 << 32);
        let mut first = Array2::<i32>::zeros((POSITIONS, nbins));
        let mut range = Array2::<i32>::zeros((POSITIONS, 2));
        let mut shift = Array2::<f64>::zeros((POSITIONS, levels));
        for p in 0..POSITIONS {
            let (l, tabs) = sampler.position_tables(p);
            let (l, sh) = sampler.target_tables(p).unwrap_or((l, &[]));
            for (lv, &b) in l.iter().enumerate().take(levels) {
                lut[(p, lv)] = b as i64;
            }
            for (lv, &k) in sh.iter().enumerate().take(levels) {
                shift[(p, lv)] = k as f64 / 4294967296.0;
            }
            for (b, t) in tabs.iter().enumerate() {
                first[(p, b)] = t.first();
                for (i, &c) in t.cdf().iter().enumerate() {
                    cdf[(p, b, i)] = c;
                }
            }
            let [lo, hi] = sampler.range(p);
            range[(p, 0)] = lo;
            range[(p, 1)] = hi;
        }
        let lattice: Vec<bool> = (0..POSITIONS).map(|p| sampler.has_lattice(p)).collect();
        let d = PyDict::new(py);
        d.set_item("iso", iso)?;
        d.set_item("lut", PyArray2::from_owned_array(py, lut))?;
        d.set_item("cdf", PyArray3::from_owned_array(py, cdf))?;
        d.set_item("first", PyArray2::from_owned_array(py, first))?;
        d.set_item("range", PyArray2::from_owned_array(py, range))?;
        d.set_item("lattice", PyArray1::from_vec(py, lattice))?;
        d.set_item("white", pack.layout.white)?;
        d.set_item("gain_ratio", gains.to_vec())?;
        d.set_item("clean_at", clean_at.name())?;
        d.set_item("shift", PyArray2::from_owned_array(py, shift))?;
        d.set_item("structure", structure)?;
        Ok(d)
    }
}
