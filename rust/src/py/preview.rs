//! `viscache_rs._core.LightingPreview`: CAM08 §6.2's preview of `J`
//! ([`crate::estimators::preview`]), direct or from a cached transfer.

use super::interrupt::detach_stoppable;
use std::sync::{Arc, RwLock};

use glam::DMat3;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::cache::PyVisibilityCache;
use super::camera::PyCamera;
use super::convert::{f64_arg, image_array, int_arg, product_level_arg, threads_arg, IntoPyResult};
use super::envmap::PyEnvMap;
use super::gbuffer::{view_arg, PyGBuffer, View};
use super::material::PyMaterial;
use super::scene::PyScene;
use crate::estimators::preview::light::rotation_about_y;
use crate::estimators::preview::transfer::{Basis, TransferSettings};
use crate::estimators::preview::{BasisChoice, LightingPreview, TransferInfo, TransferRequest};
use crate::geometry::Scene;

/// The first hits of a view, kept so that `render(cache, envmap)` can show `J` (the
/// control variate's integral) under any lighting without tracing a ray.
#[pyclass(name = "LightingPreview", module = "viscache_rs._core", frozen)]
pub struct PyLightingPreview {
    inner: RwLock<LightingPreview>,
    /// The scene as posed when the view was traced (for tracing a few records when a
    /// transfer chooses its form of `Ṽ`).
    scene: Arc<Scene>,
}

impl PyLightingPreview {
    fn get(&self) -> std::sync::RwLockReadGuard<'_, LightingPreview> {
        self.inner.read().unwrap_or_else(|e| e.into_inner())
    }
}

/// `rotation`: None, degrees about +y (as `EnvMap.rotated`), or a 3x3 rotation matrix
/// (row-major; a feature at `ω` moves to `R ω`).
fn rotation_arg(obj: Option<&Bound<'_, PyAny>>) -> PyResult<Option<DMat3>> {
    let Some(obj) = obj.filter(|o| !o.is_none()) else {
        return Ok(None);
    };
    if let Ok(degrees) = obj.extract::<f64>() {
        return rotation_about_y(degrees).map(Some).py();
    }
    let rows: Vec<Vec<f64>> = obj
        .call_method0("tolist")
        .and_then(|l| l.extract())
        .or_else(|_| obj.extract())
        .map_err(|_| {
            PyValueError::new_err(
                "rotation: must be None, degrees about +y or a 3x3 rotation matrix",
            )
        })?;
    if rows.len() != 3 || rows.iter().any(|r| r.len() != 3) {
        return Err(PyValueError::new_err(format!(
            "rotation: a matrix must be 3x3, got {} rows",
            rows.len()
        )));
    }
    let m = DMat3::from_cols_array_2d(&[
        [rows[0][0], rows[1][0], rows[2][0]],
        [rows[0][1], rows[1][1], rows[2][1]],
        [rows[0][2], rows[1][2], rows[2][2]],
    ]);
    crate::estimators::preview::light::check_rotation(&m).py()?;
    Ok(Some(m))
}

fn basis_dict(basis: Basis, d: &Bound<'_, PyDict>) -> PyResult<()> {
    d.set_item("basis", basis.name())?;
    match basis {
        Basis::Texels { level } => d.set_item("basis_level", level)?,
        Basis::Haar { terms } => d.set_item("terms", terms)?,
        Basis::Sh { order } => d.set_item("order", order)?,
    }
    Ok(())
}

fn info_dict<'py>(py: Python<'py>, info: &TransferInfo) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    basis_dict(info.basis, &d)?;
    d.set_item("level", info.level)?;
    d.set_item("seconds", info.seconds)?;
    d.set_item("bytes", info.bytes)?;
    d.set_item("pixels", info.pixels)?;
    let measured = PyDict::new(py);
    for (basis, err) in &info.measured {
        let name = match basis {
            Basis::Texels { level } => format!("texels{level}"),
            Basis::Haar { terms } => format!("haar{terms}"),
            Basis::Sh { order } => format!("sh{order}"),
        };
        measured.set_item(name, err)?;
    }
    d.set_item("measured", measured)?;
    d.set_item("nearest", info.nearest)?;
    if let Some(m) = info.visibility_measured {
        let v = PyDict::new(py);
        v.set_item("blend", m.blend)?;
        v.set_item("nearest", m.nearest)?;
        v.set_item("standard_error", m.standard_error)?;
        d.set_item("visibility_measured", v)?;
    }
    Ok(d)
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
        let inner = detach_stoppable(py, || match &view {
            View::Camera(cam) => LightingPreview::new(&scene, cam, threads),
            View::GBuffer(g) => LightingPreview::from_gbuffer(&scene, g),
        })?
        .py()?;
        Ok(Self {
            inner: RwLock::new(inner),
            scene,
        })
    }

    /// (width, height) of the view.
    #[getter]
    fn size(&self) -> (u32, u32) {
        self.get().size()
    }

    /// `J` per pixel as an (H, W, 3) float32 image under `envmap` turned by `rotation`
    /// (None, degrees about +y, or a 3x3 matrix) with `cache`'s records; traces no rays
    /// but, from a truncated transfer, shadow rays toward a sun where a pixel's records
    /// disagree on it (at most `edge_rays` per pixel, see `prepare`).
    /// By default from the kept transfer (built on the first call for a cache, rebuilt
    /// when the cache changes); `direct=True` integrates every pixel from scratch
    /// (no rotation then). `product_level`: the level of `B~`'s cells; None is "auto" (per
    /// material) for the direct path and the transfer's own level for the transfer.
    #[pyo3(signature = (cache, envmap, rotation=None, product_level=None, threads=None, direct=false))]
    #[allow(clippy::too_many_arguments)]
    fn render<'py>(
        &self,
        py: Python<'py>,
        cache: PyRef<'py, PyVisibilityCache>,
        envmap: PyRef<'py, PyEnvMap>,
        rotation: Option<&Bound<'py, PyAny>>,
        product_level: Option<&Bound<'py, PyAny>>,
        threads: Option<&Bound<'py, PyAny>>,
        direct: bool,
    ) -> PyResult<Bound<'py, PyAny>> {
        let level = product_level_arg(product_level)?;
        let threads = threads_arg(threads)?;
        let rotation = rotation_arg(rotation)?;
        let cache = cache.bound(py)?;
        let env = &envmap.inner;
        let preview = self.get();
        let image = if direct {
            if rotation.is_some() {
                return Err(PyValueError::new_err(
                    "rotation: not taken with direct=True; pass envmap.rotated(degrees)",
                ));
            }
            detach_stoppable(py, || preview.render(&cache, env, level, threads))?.py()?
        } else {
            if product_level.is_some() {
                preview.set_product_level(Some(level));
            }
            let scene = Some(&*self.scene);
            detach_stoppable(py, || {
                preview.render_lighting(scene, &cache, env, rotation.as_ref(), threads)
            })?
            .py()?
        };
        let (w, h) = preview.size();
        image_array(py, image.into_flattened(), h as usize, w as usize, Some(3))
    }

    /// Builds and keeps the transfer of `cache` for this view: `basis` "auto" (the
    /// candidates that fit `budget_mb` measured against the untruncated transfer under
    /// `envmap`, or a sun-and-sky probe, and the one that reads the fewest bytes a change
    /// kept among those within 1.25x of the least error; `budget_mb` None is 200), "full", "texels",
    /// "haar" or "sh". `nearest`: True takes visibility from each pixel's heaviest record
    /// only, False from the cache's blend of records, None (default) the one whose `J` lies
    /// closer to exact visibility at 1024 pixels (a record traced at each) — and, for a
    /// truncated basis, visibility toward each lighting's bright cells (a sun) where a
    /// pixel's records disagree on them by shadow rays, at most `edge_rays` (default 1/16)
    /// per pixel of the view a lighting change, and in the form that those rays judge
    /// best where the budget runs out (see `last_bright`; 0 traces none). Returns a dict:
    /// basis, terms, basis_level or order, level, seconds, bytes, pixels, measured,
    /// nearest, visibility_measured.
    #[pyo3(signature = (cache, envmap=None, basis="auto", budget_mb=None, product_level=None, nearest=None, edge_rays=None, threads=None))]
    #[allow(clippy::too_many_arguments)]
    fn prepare<'py>(
        &self,
        py: Python<'py>,
        cache: PyRef<'py, PyVisibilityCache>,
        envmap: Option<PyRef<'py, PyEnvMap>>,
        basis: &str,
        budget_mb: Option<&Bound<'py, PyAny>>,
        product_level: Option<&Bound<'py, PyAny>>,
        nearest: Option<bool>,
        edge_rays: Option<&Bound<'py, PyAny>>,
        threads: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let basis = BasisChoice::parse(basis).py()?;
        let edge_rays = match edge_rays {
            Some(r) => f64_arg(r, "edge_rays")?,
            None => TransferRequest::DEFAULT.edge_rays,
        };
        let budget = match budget_mb {
            Some(b) => f64_arg(b, "budget_mb")?,
            None => TransferRequest::DEFAULT.budget_bytes as f64 * 1e-6,
        };
        if !(budget.is_finite() && budget > 0.0) {
            return Err(PyValueError::new_err(format!(
                "budget_mb: must be a positive, finite number of megabytes, got {budget}"
            )));
        }
        let request = TransferRequest {
            basis,
            budget_bytes: (budget * 1e6).min(usize::MAX as f64 / 2.0) as usize,
            settings: TransferSettings {
                product_level: match product_level {
                    Some(_) => Some(product_level_arg(product_level)?),
                    None => None,
                },
                nearest: nearest.unwrap_or(false),
            },
            choose_visibility: nearest.is_none(),
            edge_rays,
        };
        let threads = threads_arg(threads)?;
        let cache = cache.bound(py)?;
        let env = envmap.as_ref().map(|e| &e.inner);
        let preview = self.get();
        let scene = Some(&*self.scene);
        let info =
            detach_stoppable(py, || preview.prepare(scene, &cache, env, request, threads))?.py()?;
        info_dict(py, &info)
    }

    /// What the kept transfer reports (as `prepare` returns it), or None.
    #[getter]
    fn transfer_info<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        self.get()
            .transfer_info()
            .map(|i| info_dict(py, &i))
            .transpose()
    }

    /// How the last transfer render added the map's bright cells (a sun's), or None (no
    /// render yet, no bright cell, or a whole transfer, which needs none): a dict with
    /// `cells`, `rays` (shadow rays traced toward them from the pixels whose records
    /// disagree on them; None when the render had no scene), `pixels` (how many pixels
    /// traced), `nearest` (where no ray was traced, visibility from each pixel's heaviest
    /// record, else the cache's blend: the two differ only where the records disagree)
    /// and `errors` (`{"blend", "nearest", "pixels"}`: when the ray budget left some
    /// disagreeing pixels untraced, each form's error against the rays on a spread sample
    /// of them, which chose `nearest`; else None).
    #[getter]
    fn last_bright<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(choice) = self.get().last_bright() else {
            return Ok(None);
        };
        let d = PyDict::new(py);
        d.set_item("cells", choice.cells)?;
        d.set_item("nearest", choice.nearest)?;
        d.set_item("rays", choice.rays)?;
        d.set_item("pixels", choice.pixels)?;
        match choice.errors {
            Some(e) => {
                let errors = PyDict::new(py);
                errors.set_item("blend", e.blend)?;
                errors.set_item("nearest", e.nearest)?;
                errors.set_item("pixels", e.pixels)?;
                d.set_item("errors", errors)?;
            }
            None => d.set_item("errors", py.None())?,
        }
        Ok(Some(d))
    }

    /// Gives object `obj` the material `material` in this view; with `cache` (the one the
    /// kept transfer was built from) only that object's pixels are rebuilt, without it the
    /// transfer is dropped. Returns the number of pixels of the object.
    #[pyo3(signature = (obj, material, cache=None, threads=None))]
    fn set_material<'py>(
        &self,
        py: Python<'py>,
        obj: &Bound<'py, PyAny>,
        material: PyRef<'py, PyMaterial>,
        cache: Option<PyRef<'py, PyVisibilityCache>>,
        threads: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<usize> {
        let obj = int_arg(obj, "obj", 0, u32::MAX as i128)? as u32;
        let threads = threads_arg(threads)?;
        let m = material.inner;
        let cache = cache.map(|c| c.bound(py)).transpose()?;
        detach_stoppable(py, || {
            let mut preview = self.inner.write().unwrap_or_else(|e| e.into_inner());
            preview.set_material(cache.as_deref(), obj, m, threads)
        })?
        .py()
    }
}
