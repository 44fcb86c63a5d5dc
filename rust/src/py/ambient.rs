//! `viscache_rs._core.render_ao`: ambient occlusion of [`crate::render::ambient`],
//! from a visibility cache or ray traced. The Python wrapper (`viscache_rs.render_ao`) makes
//! the cache and the progress bar.

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::cache::PyVisibilityCache;
use super::camera::PyCamera;
use super::convert::{f64_arg, image_array, int_arg, seed_or_zero, threads_arg, IntoPyResult};
use super::gbuffer::{view_arg, PyGBuffer, View};
use super::interrupt::{detach_interruptible, PyProgress};
use super::scene::PyScene;
use crate::estimators::ambient::{AoParams, MAX_AO_RAYS};
use crate::render::ambient::{
    render_cache_ao, render_cache_ao_from, render_reference_ao, render_reference_ao_from, AoStats,
};

/// AO of `scene` seen through `camera` (or at the hits of `gbuffer`): with `reference_rays=N`, ray traced with N rays per
/// shading point; otherwise from `cache` (grown for the view by §6.1's criterion). Returns a
/// dict with `image` (H, W) float32 (NaN where nothing was hit or nothing computed) and
/// `stats`. `callback(done, total)` is called with the GIL held after every wave; a falsy
/// return or an exception stops the work (the exception is then raised). None stands for
/// the core's defaults: `sigma_scale`, `min_radius_scale` and `w_min` those of `AoParams`
/// (3, 40, 0.45), `threads` every core, `time_budget` none.
#[pyfunction]
#[pyo3(signature = (scene, camera=None, cache=None, reference_rays=None, seed=0, threads=None, time_budget=None, sigma_scale=None, min_radius_scale=None, w_min=None, callback=None, gbuffer=None))]
#[allow(clippy::too_many_arguments)]
pub fn render_ao<'py>(
    py: Python<'py>,
    scene: Bound<'py, PyScene>,
    camera: Option<PyRef<'py, PyCamera>>,
    cache: Option<Bound<'py, PyVisibilityCache>>,
    reference_rays: Option<&Bound<'py, PyAny>>,
    #[pyo3(from_py_with = seed_or_zero)] seed: u64,
    threads: Option<&Bound<'py, PyAny>>,
    time_budget: Option<&Bound<'py, PyAny>>,
    sigma_scale: Option<&Bound<'py, PyAny>>,
    min_radius_scale: Option<&Bound<'py, PyAny>>,
    w_min: Option<&Bound<'py, PyAny>>,
    callback: Option<Py<PyAny>>,
    gbuffer: Option<PyRef<'py, PyGBuffer>>,
) -> PyResult<Bound<'py, PyDict>> {
    let view = view_arg(camera, gbuffer)?;
    let some = |o: Option<&Bound<'py, PyAny>>| o.filter(|v| !v.is_none()).cloned();
    let rays = some(reference_rays)
        .map(|r| int_arg(&r, "reference_rays", 1, MAX_AO_RAYS as i128))
        .transpose()?
        .map(|r| r as u32);
    let threads = threads_arg(threads)?;
    let budget = some(time_budget)
        .map(|b| f64_arg(&b, "time_budget"))
        .transpose()?;
    let mut ao = AoParams::default();
    if let Some(s) = some(sigma_scale) {
        ao.sigma_scale = f64_arg(&s, "sigma_scale")? as f32;
    }
    if let Some(r) = some(min_radius_scale) {
        ao.min_radius_scale = f64_arg(&r, "min_radius_scale")? as f32;
    }
    if let Some(w) = some(w_min) {
        ao.w_min = f64_arg(&w, "w_min")? as f32;
    }
    ao.validate().py()?;
    let cache = match (&cache, rays) {
        // The core refuses a cache of other geometry (`VisibilityCache::bind_scene`).
        (Some(c), None) => Some(c.borrow().bound(py)?),
        (None, None) => {
            return Err(PyValueError::new_err(
                "cache: pass a VisibilityCache, or reference_rays= to ray trace",
            ))
        }
        (_, Some(_)) => None,
    };
    let core_scene = scene.borrow().get();
    let mut reporter = PyProgress::new(callback);
    let stop = reporter.stop_flag();
    let mut progress = |done: usize, total: usize| reporter.report(done as u64, total as u64);
    let out = detach_interruptible(py, &stop, || match (&cache, rays, &view) {
        (_, Some(n), View::Camera(cam)) => {
            render_reference_ao(&core_scene, cam, n, seed, threads, budget, &mut progress)
        }
        (_, Some(n), View::GBuffer(g)) => {
            render_reference_ao_from(&core_scene, g, n, seed, threads, budget, &mut progress)
        }
        (Some(c), None, View::Camera(cam)) => render_cache_ao(
            &core_scene,
            cam,
            c,
            &ao,
            seed,
            threads,
            budget,
            &mut progress,
        ),
        (Some(c), None, View::GBuffer(g)) => {
            render_cache_ao_from(&core_scene, g, c, &ao, threads, budget, &mut progress)
        }
        (None, None, _) => unreachable!("checked above"),
    })?
    .py()?;
    reporter.finish()?;
    let d = PyDict::new(py);
    let (h, w) = (out.height as usize, out.width as usize);
    d.set_item("image", image_array(py, out.ao, h, w, None)?)?;
    d.set_item("stats", stats_dict(py, &out.stats, rays, &ao)?)?;
    Ok(d)
}

fn stats_dict<'py>(
    py: Python<'py>,
    s: &AoStats,
    rays: Option<u32>,
    ao: &AoParams,
) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("method", if rays.is_some() { "reference" } else { "cache" })?;
    d.set_item("pixels", s.pixels)?;
    d.set_item("covered_pixels", s.covered_pixels)?;
    d.set_item("resolved_pixels", s.resolved_pixels)?;
    d.set_item("shadow_rays", s.shadow_rays)?;
    d.set_item("nearest_rays", s.nearest_rays)?;
    d.set_item("rays", s.shadow_rays + s.nearest_rays)?;
    d.set_item("rays_per_point", s.rays_per_point)?;
    d.set_item(
        "shadow_rays_per_point",
        s.shadow_rays as f64 / s.covered_pixels.max(1) as f64,
    )?;
    d.set_item("records", s.records)?;
    d.set_item("records_inserted", s.records_inserted)?;
    d.set_item("records_discarded", s.records_discarded)?;
    d.set_item("seconds", s.seconds)?;
    d.set_item("build_seconds", s.build_seconds)?;
    d.set_item("complete", s.complete)?;
    if let Some(n) = rays {
        d.set_item("reference_rays", n)?;
    } else {
        d.set_item("sigma_scale", ao.sigma_scale)?;
        d.set_item("min_radius_scale", ao.min_radius_scale)?;
        d.set_item("w_min", ao.w_min)?;
    }
    Ok(d)
}
