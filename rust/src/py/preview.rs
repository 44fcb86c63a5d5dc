//! `viscache_rs._core.LightingPreview`: CAM08 §6.2's preview of `J`
//! ([`crate::estimators::preview`]).

use pyo3::prelude::*;

use super::cache::PyVisibilityCache;
use super::camera::PyCamera;
use super::convert::{image_array, product_level_arg, threads_arg, IntoPyResult};
use super::envmap::PyEnvMap;
use super::gbuffer::{view_arg, PyGBuffer, View};
use super::scene::PyScene;
use crate::estimators::preview::LightingPreview;

/// The first hits of a view, kept so that `render(cache, envmap)` can show `J` (the
/// control variate's integral) under any lighting without tracing a ray.
#[pyclass(name = "LightingPreview", module = "viscache_rs._core", frozen)]
pub struct PyLightingPreview {
    inner: LightingPreview,
}

#[pymethods]
impl PyLightingPreview {
    /// `LightingPreview(scene, camera=None, threads=None, gbuffer=None)`: traces one
    /// primary ray per pixel centre of `camera`, or keeps the hits of `gbuffer` (from
    /// `Scene.gbuffer`; the buffer a cache was built from gives its records' points).
    #[new]
    #[pyo3(signature = (scene, camera=None, threads=None, gbuffer=None))]
    fn new(
        py: Python<'_>,
        scene: PyRef<'_, PyScene>,
        camera: Option<PyRef<'_, PyCamera>>,
        threads: Option<&Bound<'_, PyAny>>,
        gbuffer: Option<PyRef<'_, PyGBuffer>>,
    ) -> PyResult<Self> {
        let view = view_arg(camera, gbuffer)?;
        let threads = threads_arg(threads)?;
        let scene = scene.get();
        let inner = py
            .detach(|| match &view {
                View::Camera(cam) => LightingPreview::new(&scene, cam, threads),
                View::GBuffer(g) => LightingPreview::from_gbuffer(&scene, g),
            })
            .py()?;
        Ok(Self { inner })
    }

    /// (width, height) of the view.
    #[getter]
    fn size(&self) -> (u32, u32) {
        self.inner.size()
    }

    /// `J` per pixel as an (H, W, 3) float32 image under `envmap` with `cache`'s records;
    /// traces no rays. `product_level` None is "auto" (per material).
    #[pyo3(signature = (cache, envmap, product_level=None, threads=None))]
    fn render<'py>(
        &self,
        py: Python<'py>,
        cache: PyRef<'py, PyVisibilityCache>,
        envmap: PyRef<'py, PyEnvMap>,
        product_level: Option<&Bound<'py, PyAny>>,
        threads: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let level = product_level_arg(product_level)?;
        let threads = threads_arg(threads)?;
        let cache = cache.bound(py)?;
        let env = &envmap.inner;
        let image = py
            .detach(|| self.inner.render(&cache, env, level, threads))
            .py()?;
        let (w, h) = self.inner.size();
        image_array(py, image.into_flattened(), h as usize, w as usize, Some(3))
    }
}
