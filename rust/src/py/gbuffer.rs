//! `vc.GBuffer`: the first hits of a view ([`crate::camera::GBuffer`]), traced once by
//! `Scene.gbuffer` and handed to `VisibilityCache.build`, `render`, `render_ao` and
//! `LightingPreview`, which then trace no primary ray of their own.

use std::sync::Arc;

use pyo3::exceptions::{PyKeyError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyIterator, PyList};

use super::camera::PyCamera;
use super::convert::image_array;
use crate::camera::{Camera, GBuffer};

/// The arrays of a G-buffer, in the order `keys()` lists them.
const KEYS: [&str; 7] = [
    "position",
    "normal",
    "direction",
    "object",
    "prim",
    "depth",
    "footprint",
];

/// First hits of one primary ray per pixel of `camera`. Read like a dict of (H, W, ...)
/// arrays (fresh copies): position, normal (facing the camera), direction, object and prim
/// (int32, -1 on miss), depth (distance from the eye, inf on miss) and footprint (square
/// root of the pixel's area projected onto the hit's tangent plane, world units). Holds for
/// the scene, in the pose, it was traced in: calls given it for another refuse it.
#[pyclass(name = "GBuffer", module = "viscache_rs._core", frozen)]
pub struct PyGBuffer {
    pub inner: Arc<GBuffer>,
}

#[pymethods]
impl PyGBuffer {
    /// The camera whose rays were traced.
    #[getter]
    fn camera(&self) -> PyCamera {
        PyCamera {
            inner: self.inner.camera,
        }
    }

    /// Image width in pixels.
    #[getter]
    fn width(&self) -> u32 {
        self.inner.width()
    }

    /// Image height in pixels.
    #[getter]
    fn height(&self) -> u32 {
        self.inner.height()
    }

    /// Whether the rays passed through jittered points (drawn from `seed`) rather than
    /// pixel centres.
    #[getter]
    fn jittered(&self) -> bool {
        self.inner.jittered
    }

    /// Seed of the jitter.
    #[getter]
    fn seed(&self) -> u64 {
        self.inner.seed
    }

    /// Pixels whose ray hit something.
    #[getter]
    fn covered_pixels(&self) -> usize {
        self.inner.covered_pixels()
    }

    /// Names of the arrays.
    fn keys(&self) -> Vec<&'static str> {
        KEYS.to_vec()
    }

    /// The arrays as a dict.
    fn as_dict<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let d = PyDict::new(py);
        for key in KEYS {
            d.set_item(key, self.array(py, key)?)?;
        }
        Ok(d)
    }

    fn __getitem__<'py>(&self, py: Python<'py>, key: &str) -> PyResult<Bound<'py, PyAny>> {
        self.array(py, key)
    }

    fn __iter__<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyIterator>> {
        PyList::new(py, KEYS)?.try_iter()
    }

    fn __contains__(&self, key: &str) -> bool {
        KEYS.contains(&key)
    }

    fn __repr__(&self) -> String {
        format!(
            "GBuffer(width={}, height={}, jittered={}, covered_pixels={})",
            self.inner.width(),
            self.inner.height(),
            if self.inner.jittered { "True" } else { "False" },
            self.inner.covered_pixels()
        )
    }
}

impl PyGBuffer {
    fn array<'py>(&self, py: Python<'py>, key: &str) -> PyResult<Bound<'py, PyAny>> {
        let g = &*self.inner;
        let (h, w) = (g.height() as usize, g.width() as usize);
        let rows = |v: &Vec<[f32; 3]>| image_array(py, v.as_flattened().to_vec(), h, w, Some(3));
        match key {
            "position" => rows(&g.position),
            "normal" => rows(&g.normal),
            "direction" => rows(&g.direction),
            "object" => image_array(py, g.object.clone(), h, w, None),
            "prim" => image_array(py, g.prim.clone(), h, w, None),
            "depth" => image_array(py, g.depth.clone(), h, w, None),
            "footprint" => image_array(py, g.footprint.clone(), h, w, None),
            _ => Err(PyKeyError::new_err(format!(
                "{key:?}: a G-buffer has {}",
                KEYS.join(", ")
            ))),
        }
    }
}

/// What a call looks through: a camera (the call traces its own G-buffer) or a G-buffer
/// already traced.
pub enum View {
    Camera(Camera),
    GBuffer(Arc<GBuffer>),
}

/// The view of `camera=` and `gbuffer=`: one of them, or both when the buffer was traced
/// through that camera.
pub fn view_arg(
    camera: Option<PyRef<'_, PyCamera>>,
    gbuffer: Option<PyRef<'_, PyGBuffer>>,
) -> PyResult<View> {
    match (camera, gbuffer) {
        (None, None) => Err(PyValueError::new_err(
            "camera: pass a Camera, or gbuffer= (from Scene.gbuffer)",
        )),
        (Some(c), None) => Ok(View::Camera(c.inner)),
        (c, Some(g)) => {
            if c.is_some_and(|c| c.inner != g.inner.camera) {
                return Err(PyValueError::new_err(
                    "gbuffer: was traced through another camera than `camera`",
                ));
            }
            Ok(View::GBuffer(g.inner.clone()))
        }
    }
}
