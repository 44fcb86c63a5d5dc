//! `viscache_rs.VisibilityCache`: the visibility cache of [`crate::visibility::cache`].
//! Directions and record bits cross into Python in texel layout (row `y`, column `x` of the
//! equal-area square), not the core's Morton order.

use std::path::PathBuf;
use std::sync::{Arc, Condvar, Mutex};
use std::thread::ThreadId;

use numpy::{PyArray1, PyArray2, PyArray3, PyArrayMethods};
use pyo3::exceptions::{PyRuntimeError, PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyType};

use super::camera::PyCamera;
use super::convert::{
    f64_arg, f64_vector, int_arg, log2_resolution, or_default, points_and_normals, seed_arg,
    seed_or_zero, threads_arg, vec3_arg, IntoPyResult,
};
use super::gbuffer::{view_arg, PyGBuffer, View};
use super::interrupt::{detach_interruptible_with, detach_stoppable, PyProgress};
use super::scene::PyScene;
use crate::sampling::octahedral::{morton_decode, morton_encode};
use crate::visibility::cache::{Lookup, VisibilityCache};
use crate::visibility::params::CacheParams;
use crate::visibility::record::bytes_per_record;

/// A world-space cache of visibility records over a scene (CAM08 §5). See the module
/// docs of `viscache_rs` and `VisibilityCache.build`.
// `subclass`: `viscache_rs.VisibilityCache` adds the progress bar in Python.
#[pyclass(name = "VisibilityCache", module = "viscache_rs._core", subclass)]
pub struct PyVisibilityCache {
    pub(crate) inner: Arc<VisibilityCache>,
    /// The scene records are traced in (read at each call, so edits are seen).
    #[pyo3(get)]
    pub(super) scene: Py<PyScene>,
    /// Calls that read the records for their whole length (renders, previews, relighting)
    /// against calls that change or renumber them (see [`CallGate`]).
    gate: Arc<CallGate>,
}

/// Who holds a cache: the threads of the calls reading it, or the one changing it.
#[derive(Default)]
struct GateState {
    readers: Vec<ThreadId>,
    writer: Option<(ThreadId, &'static str)>,
}

/// Keeps a cache still while a call reads it. A render reads the records pass after pass
/// and reports their misses by id at the end; `end_frame` from another thread in between
/// evicted and renumbered them, so the render failed ("ids: record 0 does not exist") or
/// mixed two caches. Calls that read take the gate shared for their whole length; calls
/// that change the records (`end_frame`, `build`, `insert`, `record_misses`) take it alone
/// and wait for the readers to finish, and readers that arrive meanwhile wait for them.
/// Renders then give the image they give without the race, and their misses reach the
/// records that earned them. The cost is an uncontended mutex per call. Waits release the
/// GIL (a reader's progress callback needs it). A progress callback that would have to
/// wait (calling `end_frame` on the cache its own render reads) gets an error instead.
#[derive(Default)]
struct CallGate {
    state: Mutex<GateState>,
    changed: Condvar,
}

impl CallGate {
    fn lock(&self) -> std::sync::MutexGuard<'_, GateState> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn wait<'a>(
        &self,
        guard: std::sync::MutexGuard<'a, GateState>,
    ) -> std::sync::MutexGuard<'a, GateState> {
        self.changed.wait(guard).unwrap_or_else(|e| e.into_inner())
    }

    /// Enters as a reader once no call changes the cache.
    fn read(self: &Arc<Self>, py: Python<'_>) -> PyResult<CacheRead> {
        let me = std::thread::current().id();
        py.detach(|| {
            let mut state = self.lock();
            loop {
                match state.writer {
                    Some((id, call)) if id == me || InCallback::active() => {
                        return Err(PyRuntimeError::new_err(format!(
                            "cache: being changed by {call}; a progress callback cannot wait \
                             for it (it may be its own call's)"
                        )))
                    }
                    Some(_) => state = self.wait(state),
                    None => break,
                }
            }
            state.readers.push(me);
            Ok(())
        })?;
        Ok(CacheRead { gate: self.clone() })
    }

    /// Enters as the only call on the cache once the readers have left; `call` names it in
    /// errors. The cache is free again when the returned value is dropped.
    fn hold(self: &Arc<Self>, py: Python<'_>, call: &'static str) -> PyResult<CacheChange> {
        let me = std::thread::current().id();
        py.detach(|| {
            let mut state = self.lock();
            loop {
                let busy = !state.readers.is_empty() || state.writer.is_some();
                if state.readers.contains(&me)
                    || state.writer.is_some_and(|(id, _)| id == me)
                    || (busy && InCallback::active())
                {
                    return Err(PyRuntimeError::new_err(format!(
                        "cache: {call} must wait for the calls using the cache, which a \
                         progress callback cannot do (it may be its own call's)"
                    )));
                }
                if state.writer.is_none() && state.readers.is_empty() {
                    break;
                }
                state = self.wait(state);
            }
            state.writer = Some((me, call));
            Ok(())
        })?;
        Ok(CacheChange { gate: self.clone() })
    }
}

/// The one call changing a cache (see [`CallGate::hold`]).
struct CacheChange {
    gate: Arc<CallGate>,
}

impl Drop for CacheChange {
    fn drop(&mut self) {
        self.gate.lock().writer = None;
        self.gate.changed.notify_all();
    }
}

thread_local! {
    static IN_CALLBACK: std::cell::Cell<u32> = const { std::cell::Cell::new(0) };
}

/// Marks the current thread as running a Python progress callback: a call's callback runs
/// on the thread doing its work, not the one that entered the gate, so a callback that
/// waited on the gate could wait for its own call. Calls on the gate from a callback
/// that would have to wait fail instead.
pub struct InCallback(());

impl InCallback {
    /// Marks the thread until the returned value is dropped.
    pub fn enter() -> Self {
        IN_CALLBACK.with(|c| c.set(c.get() + 1));
        InCallback(())
    }

    fn active() -> bool {
        IN_CALLBACK.with(|c| c.get() > 0)
    }
}

impl Drop for InCallback {
    fn drop(&mut self) {
        IN_CALLBACK.with(|c| c.set(c.get() - 1));
    }
}

/// The core cache for a call that reads it throughout (see [`CallGate`]); calls that change
/// the records wait until it is dropped.
pub struct CacheRead {
    gate: Arc<CallGate>,
}

impl Drop for CacheRead {
    fn drop(&mut self) {
        let me = std::thread::current().id();
        let mut state = self.gate.lock();
        if let Some(k) = state.readers.iter().position(|&id| id == me) {
            state.readers.swap_remove(k);
        } else {
            // Dropped on another thread than it was taken on: leave as someone.
            state.readers.pop();
        }
        drop(state);
        self.gate.changed.notify_all();
    }
}

/// A cache bound to its scene, held still for the call that asked for it.
pub struct BoundCache {
    cache: Arc<VisibilityCache>,
    _read: CacheRead,
}

impl std::ops::Deref for BoundCache {
    type Target = VisibilityCache;
    fn deref(&self) -> &VisibilityCache {
        &self.cache
    }
}

/// Applies keyword overrides to `p`, naming unknown or out-of-range ones.
fn apply_overrides(p: &mut CacheParams, overrides: &Bound<'_, PyDict>) -> PyResult<()> {
    for (key, value) in overrides.iter() {
        let key: String = key.extract()?;
        let k = key.as_str();
        let u32_of = |max: i128| -> PyResult<u32> { Ok(int_arg(&value, k, 0, max)? as u32) };
        let f32_of = || -> PyResult<f32> { Ok(f64_arg(&value, k)? as f32) };
        match k {
            "n_startup" => p.n_startup = u32_of(u32::MAX as i128)?,
            "d_max_scale" => p.d_max_scale = f32_of()?,
            "theta_max_deg" => p.theta_max_deg = f32_of()?,
            "lambda_falloff" => p.lambda_falloff = f32_of()?,
            "m_search" => p.m_search = u32_of(u32::MAX as i128)?,
            "n_keep" => p.n_keep = u32_of(u32::MAX as i128)?,
            "w_min" => p.w_min = f32_of()?,
            "delta_max" => p.delta_max = f32_of()?,
            "epsilon_max" => p.epsilon_max = f32_of()?,
            "evict_worst" => p.evict_worst = u32_of(u32::MAX as i128)?,
            "unused_frames" => p.unused_frames = u32_of(u32::MAX as i128)?,
            "max_records" => p.max_records = u32_of(u32::MAX as i128)?,
            "nearest_hits" => {
                p.nearest_hits = value
                    .extract::<bool>()
                    .map_err(|_| PyTypeError::new_err("nearest_hits: must be a bool"))?
            }
            "check_coherence" => {
                p.check_coherence = value
                    .extract::<bool>()
                    .map_err(|_| PyTypeError::new_err("check_coherence: must be a bool"))?
            }
            "emitters_visible" => {
                p.emitters_visible = value
                    .extract::<bool>()
                    .map_err(|_| PyTypeError::new_err("emitters_visible: must be a bool"))?
            }
            "pattern_seed" => {
                p.pattern_seed = seed_arg(&value).map_err(|_| {
                    PyValueError::new_err("pattern_seed: must be an integer in [0, 2^64)")
                })?
            }
            _ => {
                return Err(PyTypeError::new_err(format!(
                    "unknown parameter {k:?}; expected one of {PARAM_NAMES:?}"
                )))
            }
        }
    }
    Ok(())
}

const PARAM_NAMES: [&str; 16] = [
    "n_startup",
    "d_max_scale",
    "theta_max_deg",
    "lambda_falloff",
    "m_search",
    "n_keep",
    "w_min",
    "delta_max",
    "epsilon_max",
    "evict_worst",
    "unused_frames",
    "max_records",
    "pattern_seed",
    "nearest_hits",
    "check_coherence",
    "emitters_visible",
];

fn params_dict<'py>(py: Python<'py>, p: &CacheParams) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("resolution", 1u32 << p.log2_resolution)?;
    d.set_item("n_startup", p.n_startup)?;
    d.set_item("d_max_scale", p.d_max_scale)?;
    d.set_item("theta_max_deg", p.theta_max_deg)?;
    d.set_item("lambda_falloff", p.lambda_falloff)?;
    d.set_item("m_search", p.m_search)?;
    d.set_item("n_keep", p.n_keep)?;
    d.set_item("w_min", p.w_min)?;
    d.set_item("delta_max", p.delta_max)?;
    d.set_item("epsilon_max", p.epsilon_max)?;
    d.set_item("evict_worst", p.evict_worst)?;
    d.set_item("unused_frames", p.unused_frames)?;
    d.set_item("max_records", p.max_records)?;
    d.set_item("pattern_seed", p.pattern_seed)?;
    d.set_item("nearest_hits", p.nearest_hits)?;
    d.set_item("check_coherence", p.check_coherence)?;
    d.set_item("emitters_visible", p.emitters_visible)?;
    Ok(d)
}

impl PyVisibilityCache {
    /// The core cache, bound to the geometry of the scene it was made with if nothing bound
    /// it before (`VisibilityCache::bind_scene`): a cache passed to a call on another scene
    /// is then refused by the core even before its first build. Calls that change the
    /// records (`end_frame` and the like) wait until the returned value is dropped: keep it
    /// for the length of the call that reads the cache.
    pub fn bound(&self, py: Python<'_>) -> PyResult<BoundCache> {
        if self.inner.scene_fingerprint().is_none() {
            let scene = self.scene.borrow(py).get();
            self.inner.bind_scene(&scene).py()?;
        }
        Ok(BoundCache {
            _read: self.gate.read(py)?,
            cache: self.inner.clone(),
        })
    }

    fn record_id(&self, id: &Bound<'_, PyAny>) -> PyResult<usize> {
        let len = self.inner.len();
        let i = int_arg(id, "id", 0, i64::MAX as i128)? as usize;
        if i >= len {
            return Err(PyValueError::new_err(format!(
                "id: record {i} does not exist (the cache holds {len})"
            )));
        }
        Ok(i)
    }
}

#[pymethods]
impl PyVisibilityCache {
    /// `VisibilityCache(scene, resolution=None, preset="auto", **overrides)`: an empty cache
    /// of `resolution x resolution` records (None: the preset's, 64 for "auto", 32 for the
    /// others). Overrides take the parameter names of `params` (CAM08 Table 1 plus m, n,
    /// λ, k, ε_max, F, max_records, nearest_hits, check_coherence).
    #[new]
    #[pyo3(signature = (scene, resolution=None, preset="auto", **overrides))]
    fn new(
        scene: Py<PyScene>,
        resolution: Option<&Bound<'_, PyAny>>,
        preset: &str,
        overrides: Option<&Bound<'_, PyDict>>,
    ) -> PyResult<Self> {
        let mut p = CacheParams::preset(preset).py()?;
        if let Some(r) = resolution {
            p.log2_resolution = log2_resolution(r)?;
        }
        if let Some(o) = overrides {
            apply_overrides(&mut p, o)?;
        }
        Ok(Self {
            inner: Arc::new(VisibilityCache::new(p).py()?),
            scene,
            gate: Arc::default(),
        })
    }

    /// Lets this cache serve `scene` although its records were traced in another geometry
    /// (calls with a scene whose geometry differs from the cache's are refused otherwise):
    /// for studying stale or foreign records on purpose. The records are unchanged.
    fn bind(&self, py: Python<'_>, scene: PyRef<'_, PyScene>) {
        let scene = scene.get();
        py.detach(|| self.inner.rebind_scene(&scene));
    }

    /// Records per side, `2^M`.
    #[getter]
    fn resolution(&self) -> u32 {
        self.inner.resolution()
    }

    /// The parameters as a dict (the names `VisibilityCache(...)` takes as overrides).
    #[getter]
    fn params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        params_dict(py, self.inner.params())
    }

    /// The current frame (0 until the first `end_frame`).
    #[getter]
    fn frame(&self) -> u32 {
        self.inner.read().frame()
    }

    /// The radius `lookup` uses without `radius` or `footprints`: `d_max_scale` times the
    /// median pixel footprint of the last build (None before a build; saved and loaded with
    /// the cache).
    #[getter]
    fn default_radius(&self) -> Option<f32> {
        self.inner.default_radius()
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "VisibilityCache(records={}, resolution={}, frame={})",
            self.inner.len(),
            self.inner.resolution(),
            self.inner.read().frame()
        )
    }

    /// Record directions, `(R*R, 3)` float32 unit vectors in texel layout: row `y*R + x`
    /// is the direction bit `[y, x]` of `record_bits` stands for.
    fn directions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyArray2<f32>>> {
        let r = self.inner.resolution() as usize;
        let pattern = self.inner.directions();
        let mut out = vec![0f32; r * r * 3];
        for (z, d) in pattern.iter().enumerate() {
            let t = morton_decode(z as u32);
            let row = t.y as usize * r + t.x as usize;
            out[3 * row..3 * row + 3].copy_from_slice(&d.to_array());
        }
        PyArray1::from_vec(py, out).reshape([r * r, 3])
    }

    /// Builds the cache for `camera`'s view (bootstrap of `n_startup` records when empty,
    /// then a pass over the G-buffer applying both insertion criteria), or at the points of
    /// `gbuffer` (from `Scene.gbuffer`: the same buffer given to `render` then anchors its
    /// pixels at exactly these points, with no primary ray traced twice). Deterministic for
    /// any `threads`. Stops after the wave that spends `time_budget` seconds (None: no
    /// budget). `callback(done, total)` (pixels), if given, is called with the GIL held
    /// after every wave; a falsy return or an exception stops the build (the exception is
    /// then raised). `spp` (a positive int or None): the samples per pixel of the renders
    /// the records will serve, which the coherence check weighs their cost against.
    /// Returns a dict: records, bootstrap_records,
    /// refined_records, discarded_records, pixels, covered_pixels, shadow_rays,
    /// nearest_rays, shadow_rays_per_pixel (CAM08 Table 2's last row), seconds, complete,
    /// incoherence, predicted_variance_ratio, predicted_gain, incoherent, blind.
    #[pyo3(signature = (camera=None, seed=0, threads=None, *, gbuffer=None, time_budget=None, callback=None, spp=None))]
    #[allow(clippy::too_many_arguments)]
    fn build<'py>(
        &self,
        py: Python<'py>,
        camera: Option<PyRef<'py, PyCamera>>,
        #[pyo3(from_py_with = seed_or_zero)] seed: u64,
        threads: Option<&Bound<'py, PyAny>>,
        gbuffer: Option<PyRef<'py, PyGBuffer>>,
        time_budget: Option<&Bound<'py, PyAny>>,
        callback: Option<Py<PyAny>>,
        spp: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let view = view_arg(camera, gbuffer)?;
        let threads = threads_arg(threads)?;
        let spp = match spp {
            Some(s) if !s.is_none() => Some(int_arg(s, "spp", 1, u32::MAX as i128)? as u32),
            _ => None,
        };
        let budget = match time_budget {
            Some(b) if !b.is_none() => Some(f64_arg(b, "time_budget")?),
            _ => None,
        };
        let scene = self.scene.borrow(py).get();
        let mut reporter = PyProgress::new(callback);
        let stop = reporter.stop_flag();
        let mut callback = |done: usize, total: usize| reporter.report(done as u64, total as u64);
        let inner = self.inner.clone();
        inner.plan_samples(spp);
        let _alone = self.gate.hold(py, "build")?;
        let out = detach_interruptible_with(py, &stop, &|| inner.request_stop(), || match &view {
            View::Camera(cam) => inner.build(&scene, cam, seed, threads, budget, &mut callback),
            View::GBuffer(g) => inner.build_from(&scene, g, seed, threads, budget, &mut callback),
        });
        reporter.finish()?;
        let r = out?.py()?;
        let d = PyDict::new(py);
        d.set_item("records", r.records)?;
        d.set_item("bootstrap_records", r.bootstrap_records)?;
        d.set_item("refined_records", r.refined_records)?;
        d.set_item("discarded_records", r.discarded_records)?;
        d.set_item("pixels", r.pixels)?;
        d.set_item("covered_pixels", r.covered_pixels)?;
        d.set_item("shadow_rays", r.shadow_rays)?;
        d.set_item("nearest_rays", r.nearest_rays)?;
        d.set_item("shadow_rays_per_pixel", r.shadow_rays_per_pixel)?;
        d.set_item("seconds", r.seconds)?;
        d.set_item("complete", r.complete)?;
        d.set_item("incoherence", r.incoherence)?;
        d.set_item("predicted_variance_ratio", r.predicted_variance_ratio)?;
        d.set_item("predicted_gain", r.predicted_gain)?;
        d.set_item("incoherent", r.incoherent)?;
        d.set_item("blind", r.blind)?;
        Ok(d)
    }

    /// Traces a record at `point` with `normal` (need not be unit) and inserts it whatever
    /// the criteria say; returns its id, or None when the cache holds `max_records`.
    fn insert(
        &self,
        py: Python<'_>,
        point: &Bound<'_, PyAny>,
        normal: &Bound<'_, PyAny>,
    ) -> PyResult<Option<u32>> {
        let p = vec3_arg(point, "point")?;
        let n = vec3_arg(normal, "normal")?;
        let scene = self.scene.borrow(py).get();
        let inner = self.inner.clone();
        let _alone = self.gate.hold(py, "insert")?;
        py.detach(|| inner.insert(&scene, p.into(), n.into())).py()
    }

    /// §5.1 lookups for `points` (N, 3) with `normals` (N, 3; need not be unit) within
    /// `radius` (a number or (N,) world units) or `d_max_scale * footprints` ((N,)); with
    /// neither, `default_radius`. Returns a dict: `ids` (N, n) int64 (-1 pads), `beta` and
    /// `weight` (N, n) float32, `max_weight`, `mean_difference` (N,) float32,
    /// `needs_record` (N,) bool (§5.2's criteria), and with `interpolate=True` `map`
    /// (N, R, R) float32 = Σ β_i V_i in texel layout.
    #[pyo3(signature = (points, normals, radius=None, footprints=None, interpolate=false, threads=None))]
    #[allow(clippy::too_many_arguments)]
    fn lookup<'py>(
        &self,
        py: Python<'py>,
        points: &Bound<'py, PyAny>,
        normals: &Bound<'py, PyAny>,
        radius: Option<&Bound<'py, PyAny>>,
        footprints: Option<&Bound<'py, PyAny>>,
        interpolate: bool,
        threads: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let (pts, nrm) = points_and_normals(points, normals)?;
        let n = pts.len();
        let radii = self.radii(radius, footprints, n)?;
        let threads = threads_arg(threads)?;
        let inner = self.inner.clone();
        let looks: Vec<Lookup> =
            detach_stoppable(py, || inner.lookup_batch(&pts, &nrm, &radii, threads))?.py()?;
        let keep = self.inner.params().n_keep as usize;
        let mut ids = vec![-1i64; n * keep];
        let mut beta = vec![0f32; n * keep];
        let mut weight = vec![0f32; n * keep];
        for (i, l) in looks.iter().enumerate() {
            for (j, k) in l.neighbours().iter().enumerate() {
                ids[i * keep + j] = k.id as i64;
                beta[i * keep + j] = k.beta;
                weight[i * keep + j] = k.weight;
            }
        }
        let p = *self.inner.params();
        let d = PyDict::new(py);
        d.set_item("ids", PyArray1::from_vec(py, ids).reshape([n, keep])?)?;
        d.set_item("beta", PyArray1::from_vec(py, beta).reshape([n, keep])?)?;
        d.set_item("weight", PyArray1::from_vec(py, weight).reshape([n, keep])?)?;
        let col =
            |f: &dyn Fn(&Lookup) -> f32| PyArray1::from_vec(py, looks.iter().map(f).collect());
        d.set_item("max_weight", col(&|l| l.max_weight))?;
        d.set_item("mean_difference", col(&|l| l.mean_difference))?;
        let needs: Vec<bool> = looks.iter().map(|l| l.needs_record(&p)).collect();
        d.set_item("needs_record", PyArray1::from_vec(py, needs))?;
        if interpolate {
            let r = self.inner.resolution() as usize;
            let maps = py.detach(|| {
                let state = inner.read();
                let mut maps = vec![0f32; n * r * r];
                for (l, out) in looks.iter().zip(maps.chunks_mut(r * r)) {
                    state.interpolate(l, out);
                }
                maps
            });
            let maps: Bound<'py, PyArray3<f32>> =
                PyArray1::from_vec(py, maps).reshape([n, r, r])?;
            d.set_item("map", maps)?;
        }
        Ok(d)
    }

    /// Visibility of record `id` as an (R, R) bool array in texel layout (True = open).
    fn record_bits<'py>(
        &self,
        py: Python<'py>,
        id: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyArray2<bool>>> {
        let i = self.record_id(id)?;
        let r = self.inner.resolution();
        let state = self.inner.read();
        let bits = state.store().bits(i);
        let out: Vec<bool> = (0..r * r)
            .map(|t| bits.get(morton_encode(t % r, t / r) as usize))
            .collect();
        PyArray1::from_vec(py, out).reshape([r as usize, r as usize])
    }

    /// The 2-bit coverage hierarchy of record `id` (CAM08 Fig. 9): one (2^l, 2^l) uint8
    /// array per quadtree level l = 0..M in texel layout, each node's code as the core keeps
    /// it: 1 = all visible, 2 = all occluded, 3 = partly visible (bit 0 "some direction
    /// visible", bit 1 "some occluded"). Levels down to 8 x 8-texel nodes are the stored
    /// codes; finer ones are read from the bits.
    fn record_hierarchy<'py>(
        &self,
        py: Python<'py>,
        id: &Bound<'py, PyAny>,
    ) -> PyResult<Vec<Bound<'py, PyArray2<u8>>>> {
        let i = self.record_id(id)?;
        let m = self.inner.params().log2_resolution;
        let state = self.inner.read();
        let bits = state.store().bits(i);
        let levels: Vec<(usize, Vec<u8>)> = (0..=m)
            .map(|level| {
                let side = 1u32 << level;
                let codes = (0..side * side)
                    .map(|t| bits.coverage(level, morton_encode(t % side, t / side)) as u8)
                    .collect();
                (side as usize, codes)
            })
            .collect();
        drop(state);
        levels
            .into_iter()
            .map(|(side, codes)| PyArray1::from_vec(py, codes).reshape([side, side]))
            .collect()
    }

    /// Bytes the records occupy (`len * bytes_per_record`; 172 per record at 32 x 32).
    fn memory_bytes(&self) -> usize {
        self.inner.memory_bytes()
    }

    /// Per-record arrays for plots and tests: `position`, `normal` (N, 3) float32, `ao`,
    /// `nearest_hit_distance` (N,) float32, `misses`, `uses`, `last_frame` (N,) uint32.
    fn records<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let state = self.inner.read();
        let s = state.store();
        let n = s.len();
        let headers: Vec<_> = (0..n).map(|i| *s.header(i)).collect();
        drop(state);
        let vec3s = |f: &dyn Fn(usize) -> [f32; 3]| -> PyResult<Bound<'py, PyArray2<f32>>> {
            PyArray1::from_vec(py, (0..n).flat_map(f).collect()).reshape([n, 3])
        };
        let d = PyDict::new(py);
        d.set_item("position", vec3s(&|i| headers[i].position)?)?;
        d.set_item("normal", vec3s(&|i| headers[i].normal().to_array())?)?;
        let f32s = |f: &dyn Fn(usize) -> f32| PyArray1::from_vec(py, (0..n).map(f).collect());
        d.set_item("ao", f32s(&|i| headers[i].ambient_occlusion()))?;
        d.set_item(
            "nearest_hit_distance",
            f32s(&|i| headers[i].nearest_hit_distance),
        )?;
        let u32s = |f: &dyn Fn(usize) -> u32| PyArray1::from_vec(py, (0..n).map(f).collect());
        d.set_item("misses", u32s(&|i| headers[i].misses))?;
        d.set_item("uses", u32s(&|i| headers[i].uses))?;
        d.set_item("last_frame", u32s(&|i| headers[i].last_frame))?;
        Ok(d)
    }

    /// Adds this frame's per-record counts (§5.3): `ids` (N,) record ids, `misses` and
    /// `uses` (N,) non-negative integers with misses <= uses. Nothing changes on error.
    fn record_misses(
        &self,
        py: Python<'_>,
        ids: &Bound<'_, PyAny>,
        misses: &Bound<'_, PyAny>,
        uses: &Bound<'_, PyAny>,
    ) -> PyResult<()> {
        let ids = counts(ids, "ids")?;
        let misses = counts(misses, "misses")?;
        let uses = counts(uses, "uses")?;
        let _alone = self.gate.hold(py, "record_misses")?;
        self.inner.record_misses(&ids, &misses, &uses).py()
    }

    /// Re-traces `rays_per_record` of each record's directions (drawn from `seed`, the
    /// record and the frame) in the scene as it is now and records the disagreements as
    /// misses, as an estimator's samples would (§5.3); call after `setup.at_frame(i)` and
    /// before `end_frame()`. Returns a dict: rays, misses.
    #[pyo3(signature = (rays_per_record=16, seed=0, threads=None))]
    fn validate<'py>(
        &self,
        py: Python<'py>,
        #[pyo3(from_py_with = rays_per_record_arg)] rays_per_record: u32,
        #[pyo3(from_py_with = seed_or_zero)] seed: u64,
        threads: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let k = rays_per_record;
        let threads = threads_arg(threads)?;
        let scene = self.scene.borrow(py).get();
        let inner = self.inner.clone();
        let (rays, misses) =
            detach_stoppable(py, || inner.validate(&scene, k, seed, threads))?.py()?;
        let d = PyDict::new(py);
        d.set_item("rays", rays)?;
        d.set_item("misses", misses)?;
        Ok(d)
    }

    /// Ends the frame (§5.3): removes records whose miss rate this frame exceeds
    /// `epsilon_max` (or the `evict_worst` worst) and records unused for `unused_frames`
    /// frames; ids are compacted (kept records keep their order). Returns a dict: frame,
    /// by_misses, unused, remaining.
    fn end_frame<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let _alone = self.gate.hold(py, "end_frame")?;
        let r = self.inner.end_frame().py()?;
        let d = PyDict::new(py);
        d.set_item("frame", r.frame)?;
        d.set_item("by_misses", r.by_misses)?;
        d.set_item("unused", r.unused)?;
        d.set_item("remaining", r.remaining)?;
        Ok(d)
    }

    /// Totals: records, frame, memory_bytes, bytes_per_record, index_bytes (kd-tree leaves
    /// and stems, sites and chain links, spare capacity included),
    /// inserted, evicted, refused_full, shadow_rays, nearest_rays, lookups.
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let c = self.inner.counters();
        let d = PyDict::new(py);
        d.set_item("records", self.inner.len())?;
        d.set_item("frame", self.inner.read().frame())?;
        d.set_item("memory_bytes", self.inner.memory_bytes())?;
        d.set_item(
            "bytes_per_record",
            bytes_per_record(self.inner.params().log2_resolution),
        )?;
        d.set_item("index_bytes", self.inner.index_bytes())?;
        d.set_item("inserted", c.inserted)?;
        d.set_item("evicted", c.evicted)?;
        d.set_item("refused_full", c.refused_full)?;
        d.set_item("shadow_rays", c.shadow_rays)?;
        d.set_item("nearest_rays", c.nearest_rays)?;
        d.set_item("lookups", c.lookups)?;
        Ok(d)
    }

    /// Writes the cache (versioned binary format) to `path`.
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let inner = self.inner.clone();
        py.detach(|| inner.save(&path)).py()
    }

    /// Reads a cache written by `save`, attached to `scene`. A truncated or corrupted file
    /// raises ValueError naming the file; so does a cache built for another scene (files
    /// record the scene's geometry fingerprint; older files without one are accepted).
    /// Returns an instance of the class it is called on (`viscache_rs.VisibilityCache`).
    #[classmethod]
    fn load<'py>(
        cls: &Bound<'py, PyType>,
        path: PathBuf,
        scene: Py<PyScene>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let py = cls.py();
        let core_scene = scene.borrow(py).get();
        let cache = py
            .detach(|| VisibilityCache::load_for(&path, &core_scene))
            .py()?;
        // PyO3 makes instances of a Python subclass only through `cls(...)`: make an empty
        // cache of the smallest resolution and give it the loaded one.
        let kw = PyDict::new(py);
        kw.set_item("resolution", 2)?;
        let obj = cls.call((scene,), Some(&kw))?;
        obj.cast::<Self>()?.borrow_mut().inner = Arc::new(cache);
        Ok(obj)
    }
}

impl PyVisibilityCache {
    fn radii(
        &self,
        radius: Option<&Bound<'_, PyAny>>,
        footprints: Option<&Bound<'_, PyAny>>,
        n: usize,
    ) -> PyResult<Vec<f32>> {
        let radius = radius.filter(|r| !r.is_none());
        let footprints = footprints.filter(|f| !f.is_none());
        let positive = |v: Vec<f64>, name: &str, scale: f64| -> PyResult<Vec<f32>> {
            if v.len() != n {
                return Err(PyValueError::new_err(format!(
                    "{name}: expected {n} values (one per point), got {}",
                    v.len()
                )));
            }
            if let Some(i) = v.iter().position(|x| !(x.is_finite() && *x >= 0.0)) {
                return Err(PyValueError::new_err(format!(
                    "{name}: entry {i} must be finite and >= 0, got {}",
                    v[i]
                )));
            }
            Ok(v.into_iter().map(|x| (x * scale) as f32).collect())
        };
        match (radius, footprints) {
            (Some(_), Some(_)) => Err(PyValueError::new_err(
                "radius: give radius or footprints, not both",
            )),
            (Some(r), None) => {
                if let Ok(x) = f64_arg(r, "radius") {
                    positive(vec![x; n], "radius", 1.0)
                } else {
                    positive(f64_vector(r, "radius")?, "radius", 1.0)
                }
            }
            (None, Some(f)) => positive(
                f64_vector(f, "footprints")?,
                "footprints",
                self.inner.params().d_max_scale as f64,
            ),
            (None, None) => match self.inner.default_radius() {
                Some(r) => Ok(vec![r; n]),
                None => Err(PyValueError::new_err(
                    "radius: pass radius= or footprints= (no build has set a default radius)",
                )),
            },
        }
    }
}

/// Extractor of `rays_per_record=16`.
fn rays_per_record_arg(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    or_default(obj, 16, |o| {
        Ok(int_arg(o, "rays_per_record", 1, 1 << 14)? as u32)
    })
}

/// A 1-D array of counts (non-negative integers below 2^32).
fn counts(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<u32>> {
    let v = f64_vector(obj, name)?;
    if let Some(i) = v
        .iter()
        .position(|x| !(x.fract() == 0.0 && *x >= 0.0 && *x <= u32::MAX as f64))
    {
        return Err(PyValueError::new_err(format!(
            "{name}: entry {i} must be a non-negative integer, got {}",
            v[i]
        )));
    }
    Ok(v.into_iter().map(|x| x as u32).collect())
}
