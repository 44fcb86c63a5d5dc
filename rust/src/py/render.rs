//! `viscache_rs._core.render`: the baseline renderer of [`crate::render`]. The Python
//! wrapper (`viscache_rs.render`) adds the progress bar.

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::camera::PyCamera;
use super::convert::{f64_arg, image_array, int_arg, seed_arg, threads_arg, IntoPyResult};
use super::envmap::PyEnvMap;
use super::scene::PyScene;
use crate::estimators::direct::Method;
use crate::render::{render as render_core, RenderParams, MAX_SPP};

/// Renders direct illumination; returns a dict with `image` and `variance` (H, W, 3)
/// float32 and `stats` (a dict). `callback(spp_done, spp_planned)`, if given, is called
/// after every pass with the GIL held; a falsy return or an exception stops the render
/// after that pass (the exception is then raised).
#[pyfunction]
#[pyo3(signature = (scene, envmap, camera, spp, method, seed=None, threads=None, time_budget=None, product_level=None, callback=None))]
#[allow(clippy::too_many_arguments)]
pub fn render<'py>(
    py: Python<'py>,
    scene: PyRef<'py, PyScene>,
    envmap: Bound<'py, PyEnvMap>,
    camera: PyRef<'py, PyCamera>,
    spp: &Bound<'py, PyAny>,
    method: &str,
    seed: Option<&Bound<'py, PyAny>>,
    threads: Option<&Bound<'py, PyAny>>,
    time_budget: Option<&Bound<'py, PyAny>>,
    product_level: Option<&Bound<'py, PyAny>>,
    callback: Option<Py<PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let method = Method::from_name(method).ok_or_else(|| {
        let names: Vec<&str> = Method::ALL.iter().map(|m| m.name()).collect();
        PyValueError::new_err(format!("method: expected one of {names:?}, got {method:?}"))
    })?;
    let params = RenderParams {
        spp: int_arg(spp, "spp", 1, MAX_SPP as i128)? as u32,
        method,
        seed: seed.map_or(Ok(0), seed_arg)?,
        time_budget: match time_budget {
            Some(b) if !b.is_none() => Some(f64_arg(b, "time_budget")?),
            _ => None,
        },
        product_level: product_level.map_or(Ok(5), |l| int_arg(l, "product_level", 1, 8))? as u32,
    };
    let threads = threads_arg(threads)?;
    let (scene, cam) = (scene.inner.clone(), camera.inner);
    let env: Py<PyEnvMap> = envmap.unbind();
    let mut failure: Option<PyErr> = None;
    let mut progress = |done: u32, planned: u32| -> bool {
        let Some(cb) = &callback else {
            return true;
        };
        Python::attach(|py| match cb.call1(py, (done, planned)) {
            Ok(r) => r.is_truthy(py).unwrap_or(true),
            Err(e) => {
                failure = Some(e);
                false
            }
        })
    };
    let out = py
        .detach(|| {
            render_core(
                &scene,
                &env.get().inner,
                &cam,
                &params,
                threads,
                &mut progress,
            )
        })
        .py()?;
    if let Some(e) = failure {
        return Err(e);
    }
    let (w, h) = (out.width as usize, out.height as usize);
    let d = PyDict::new(py);
    d.set_item(
        "image",
        image_array(py, out.image.into_flattened(), h, w, Some(3))?,
    )?;
    d.set_item(
        "variance",
        image_array(py, out.variance.into_flattened(), h, w, Some(3))?,
    )?;
    let s = &out.stats;
    let stats = PyDict::new(py);
    stats.set_item("method", method.name())?;
    stats.set_item("seconds", s.seconds)?;
    stats.set_item("spp", s.spp)?;
    stats.set_item("samples", s.samples)?;
    stats.set_item("primary_rays", s.primary_rays)?;
    stats.set_item("shadow_rays", s.shadow_rays)?;
    stats.set_item("bsdf_rays", s.bsdf_rays)?;
    stats.set_item("rays_per_second", s.rays_per_second)?;
    stats.set_item("samples_per_second", s.samples as f64 / s.seconds.max(1e-9))?;
    stats.set_item("primary_seconds", s.stages.primary)?;
    stats.set_item("direct_seconds", s.stages.direct)?;
    d.set_item("stats", stats)?;
    Ok(d)
}
