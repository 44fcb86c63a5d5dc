//! `viscache_rs._core.Relighter`: SBF's relighting with decoupled visibility
//! ([`crate::estimators::decoupled`], its passes [`crate::render::relight`]). The Python wrapper (`viscache_rs.Relighter`) traces
//! the G-buffer and keeps the setup and cache.

use std::sync::Mutex;

use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::cache::PyVisibilityCache;
use super::convert::{
    f64_arg, image_array, image_dict, int_arg, or_default, product_level_arg, seed_or_zero,
    threads_arg, IntoPyResult,
};
use super::envmap::PyEnvMap;
use super::gbuffer::PyGBuffer;
use super::interrupt::{detach_interruptible, detach_stoppable, PyProgress};
use super::material::PyMaterial;
use super::scene::PyScene;
use crate::bsdf::Material;
use crate::estimators::decoupled::{
    RelightParams, Relighter, VisibilitySource, MAX_RELIGHT_SPP, MAX_VISIBILITY_SPP,
};
use crate::render::relight::relight;

/// Relighting with decoupled visibility (SBF) at the hits of a G-buffer:
/// `Relighter(scene, gbuffer, visibility="pixels" | "cache")`.
#[pyclass(name = "Relighter", module = "viscache_rs._core", frozen)]
pub struct PyRelighter {
    inner: Mutex<Relighter>,
    scene: Py<PyScene>,
}

fn source_arg(visibility: &str) -> PyResult<VisibilitySource> {
    match visibility {
        "pixels" => Ok(VisibilitySource::Pixels),
        "cache" => Ok(VisibilitySource::Cache),
        other => Err(PyValueError::new_err(format!(
            "visibility: expected \"pixels\" or \"cache\", got {other:?}"
        ))),
    }
}

/// `materials`: None or a dict of object id -> Material.
fn materials_arg(materials: Option<&Bound<'_, PyAny>>) -> PyResult<Vec<(u32, Material)>> {
    let Some(m) = materials.filter(|m| !m.is_none()) else {
        return Ok(Vec::new());
    };
    let dict = m.cast::<PyDict>().map_err(|_| {
        PyTypeError::new_err("materials: expected a dict of object id -> Material, or None")
    })?;
    let mut out = Vec::new();
    for (key, value) in dict.iter() {
        let id = int_arg(&key, "materials", 0, u32::MAX as i128)? as u32;
        let material = value.cast::<PyMaterial>().map_err(|_| {
            PyTypeError::new_err(format!(
                "materials: the value for object {id} is not a Material"
            ))
        })?;
        out.push((id, material.borrow().inner));
    }
    out.sort_by_key(|e| e.0);
    Ok(out)
}

/// Extractor of `lb_spp=64`.
fn lb_spp_arg(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    or_default(obj, 64, |o| {
        Ok(int_arg(o, "lb_spp", 1, MAX_RELIGHT_SPP as i128)? as u32)
    })
}

/// Extractor of `lbv_spp=8`.
fn lbv_spp_arg(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    or_default(obj, 8, |o| {
        Ok(int_arg(o, "lbv_spp", 0, MAX_RELIGHT_SPP as i128)? as u32)
    })
}

/// Extractor of `threshold=0.25`.
fn threshold_arg(obj: &Bound<'_, PyAny>) -> PyResult<f64> {
    or_default(obj, 0.25, |o| f64_arg(o, "threshold"))
}

/// Extractor of `epsilon=0.1`.
fn epsilon_arg(obj: &Bound<'_, PyAny>) -> PyResult<f64> {
    or_default(obj, 0.1, |o| f64_arg(o, "epsilon"))
}

#[pymethods]
impl PyRelighter {
    #[new]
    #[pyo3(signature = (scene, gbuffer, visibility="pixels"))]
    fn new(
        py: Python<'_>,
        scene: Bound<'_, PyScene>,
        gbuffer: PyRef<'_, PyGBuffer>,
        visibility: &str,
    ) -> PyResult<Self> {
        let source = source_arg(visibility)?;
        let core = scene.borrow().get();
        let g = (*gbuffer.inner).clone();
        let inner = detach_stoppable(py, || Relighter::new(&core, g, source))?.py()?;
        Ok(Self {
            inner: Mutex::new(inner),
            scene: scene.unbind(),
        })
    }

    /// "pixels" or "cache".
    #[getter]
    fn visibility(&self) -> &'static str {
        match self.lock().source() {
            VisibilitySource::Pixels => "pixels",
            VisibilitySource::Cache => "cache",
        }
    }

    /// V-samples per pixel and light traced by `converge_visibility` (0 before).
    #[getter]
    fn visibility_spp(&self) -> u32 {
        self.lock().visibility_spp()
    }

    /// Traces `spp` V-samples per pixel and light under `envmap` and the scene's materials
    /// (replacing earlier ones), in passes of 16; with `time_budget` (seconds) no pass
    /// starts once it is spent. `callback(done, planned)` (pixel samples), if given, is
    /// called with the GIL held about every 0.1 s; a falsy return, an exception or Ctrl-C
    /// stops, leaving the relighter as it was. Returns a dict: spp (taken), shadow_rays,
    /// seconds, bytes_per_pixel_and_light (the visibility kept).
    #[pyo3(signature = (envmap, spp, seed=0, product_level=None, threads=None, time_budget=None, callback=None))]
    #[allow(clippy::too_many_arguments)]
    fn converge_visibility<'py>(
        &self,
        py: Python<'py>,
        envmap: PyRef<'py, PyEnvMap>,
        spp: &Bound<'py, PyAny>,
        #[pyo3(from_py_with = seed_or_zero)] seed: u64,
        product_level: Option<&Bound<'py, PyAny>>,
        threads: Option<&Bound<'py, PyAny>>,
        time_budget: Option<&Bound<'py, PyAny>>,
        callback: Option<Py<PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let spp = int_arg(spp, "spp", 1, MAX_VISIBILITY_SPP as i128)? as u32;
        let level = product_level_arg(product_level)?;
        let threads = threads_arg(threads)?;
        let budget = match time_budget {
            Some(b) if !b.is_none() => Some(f64_arg(b, "time_budget")?),
            _ => None,
        };
        let scene = self.scene.borrow(py).get();
        let env = &envmap.inner;
        let start = std::time::Instant::now();
        let mut reporter = PyProgress::new(callback);
        let stop = reporter.stop_flag();
        let mut progress = |done: u64, planned: u64| reporter.report(done, planned);
        let out = detach_interruptible(py, &stop, || {
            let mut inner = self.lock();
            inner.converge_visibility(
                &scene,
                env,
                spp,
                seed,
                level,
                threads,
                budget,
                &mut progress,
            )
        })?;
        reporter.finish()?;
        let (taken, rays) = out.py()?;
        let bytes = self.lock().visibility_bytes_per_pixel_and_light();
        let d = PyDict::new(py);
        d.set_item("spp", taken)?;
        d.set_item("shadow_rays", rays)?;
        d.set_item("seconds", start.elapsed().as_secs_f64())?;
        d.set_item("bytes_per_pixel_and_light", bytes)?;
        Ok(d)
    }

    /// Relights the view: see `viscache_rs.Relighter.render`. Returns a dict of arrays
    /// (image, variance: (H, W, 3); t, bound, visibility, effective_samples: (H, W, L);
    /// lbv_counts: (H, W)) and stats.
    #[pyo3(signature = (envmap, materials=None, cache=None, light_cache=None, lb_spp=64, lbv_spp=8, threshold=0.25, epsilon=0.1, seed=0, product_level=None, threads=None, time_budget=None, adaptive=true, least_error=true, reuse=true, callback=None))]
    #[allow(clippy::too_many_arguments)]
    fn render<'py>(
        &self,
        py: Python<'py>,
        envmap: PyRef<'py, PyEnvMap>,
        materials: Option<&Bound<'py, PyAny>>,
        cache: Option<PyRef<'py, PyVisibilityCache>>,
        light_cache: Option<PyRef<'py, PyVisibilityCache>>,
        #[pyo3(from_py_with = lb_spp_arg)] lb_spp: u32,
        #[pyo3(from_py_with = lbv_spp_arg)] lbv_spp: u32,
        #[pyo3(from_py_with = threshold_arg)] threshold: f64,
        #[pyo3(from_py_with = epsilon_arg)] epsilon: f64,
        #[pyo3(from_py_with = seed_or_zero)] seed: u64,
        product_level: Option<&Bound<'py, PyAny>>,
        threads: Option<&Bound<'py, PyAny>>,
        time_budget: Option<&Bound<'py, PyAny>>,
        adaptive: bool,
        least_error: bool,
        reuse: bool,
        callback: Option<Py<PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let params = RelightParams {
            lb_spp,
            lbv_spp,
            threshold,
            epsilon,
            seed,
            product_level: product_level_arg(product_level)?,
            time_budget: match time_budget {
                Some(b) if !b.is_none() => Some(f64_arg(b, "time_budget")?),
                _ => None,
            },
            adaptive,
            least_error,
            reuse,
        };
        params.validate().py()?;
        let overrides = materials_arg(materials)?;
        let threads = threads_arg(threads)?;
        let cache = cache.map(|c| c.bound(py)).transpose()?;
        let light_cache = light_cache.map(|c| c.bound(py)).transpose()?;
        let scene = self.scene.borrow(py).get();
        let env = &envmap.inner;
        let mut reporter = PyProgress::new(callback);
        let stop = reporter.stop_flag();
        let mut progress = |done: u64, total: u64| reporter.report(done, total);
        let out = detach_interruptible(py, &stop, || {
            let inner = self.lock();
            relight(
                &inner,
                &scene,
                env,
                &overrides,
                cache.as_deref(),
                light_cache.as_deref(),
                &params,
                threads,
                &mut progress,
            )
        })?;
        reporter.finish()?;
        let out = out.py()?;
        let (w, h) = {
            let inner = self.lock();
            (
                inner.gbuffer().width() as usize,
                inner.gbuffer().height() as usize,
            )
        };
        let lights = out.lights;
        let d = image_dict(py, out.image, out.variance, h, w)?;
        d.set_item(
            "error_bound",
            image_array(py, out.error_bound.into_flattened(), h, w, Some(3))?,
        )?;
        d.set_item("t", image_array(py, out.t, h, w, Some(lights))?)?;
        d.set_item("bound", image_array(py, out.bound, h, w, Some(lights))?)?;
        d.set_item(
            "visibility",
            image_array(py, out.visibility, h, w, Some(lights))?,
        )?;
        d.set_item(
            "effective_samples",
            image_array(py, out.effective_samples, h, w, Some(lights))?,
        )?;
        d.set_item("lbv_counts", image_array(py, out.lbv_counts, h, w, None)?)?;
        let stats = PyDict::new(py);
        stats.set_item("lights", lights)?;
        stats.set_item("shadow_rays", out.shadow_rays)?;
        stats.set_item("lb_skipped", out.lb_skipped)?;
        stats.set_item("seconds", out.seconds)?;
        stats.set_item("first_pass_seconds", out.first_pass_seconds)?;
        stats.set_item("passes", out.passes)?;
        stats.set_item("lb_spp", params.lb_spp)?;
        stats.set_item("lbv_spp", out.lbv_spp)?;
        stats.set_item("lbv_spp_mean", out.lbv_spp_mean)?;
        stats.set_item("adaptive", params.adaptive)?;
        stats.set_item("reuse", params.reuse)?;
        d.set_item("stats", stats)?;
        Ok(d)
    }
}

impl PyRelighter {
    fn lock(&self) -> std::sync::MutexGuard<'_, Relighter> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }
}
