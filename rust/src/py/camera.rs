//! `vc.Camera`.

use glam::Vec3;
use pyo3::prelude::*;

use super::convert::{
    f64_arg, int_arg, or_default, rows3_array, seed_or_zero, vec3_arg, IntoPyResult,
};
use crate::camera::{Camera, MAX_RESOLUTION};

/// A pinhole camera. The field of view spans the vertical axis (image height); images are
/// (height, width) arrays with row 0 at the top.
#[pyclass(name = "Camera", module = "viscache_rs._core", frozen, from_py_object)]
#[derive(Clone)]
pub struct PyCamera {
    pub inner: Camera,
}

fn resolution(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<u32> {
    Ok(int_arg(obj, name, 1, MAX_RESOLUTION as i128)? as u32)
}

/// Extractor of `up=(0, 1, 0)`.
fn up_arg(obj: &Bound<'_, PyAny>) -> PyResult<[f32; 3]> {
    or_default(obj, [0.0, 1.0, 0.0], |o| vec3_arg(o, "up"))
}

/// Extractor of `fov_deg=45.0`.
fn fov_arg(obj: &Bound<'_, PyAny>) -> PyResult<f32> {
    or_default(obj, 45.0, |o| Ok(f64_arg(o, "fov_deg")? as f32))
}

/// Extractor of `width=256`.
fn width_arg(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    or_default(obj, 256, |o| resolution(o, "width"))
}

/// Extractor of `height=192`.
fn height_arg(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    or_default(obj, 192, |o| resolution(o, "height"))
}

#[pymethods]
impl PyCamera {
    /// Camera at `eye` looking at `target`; `up` fixes the roll; `fov_deg` is the vertical
    /// field of view in degrees, in (0, 180).
    // The text signature is spelt out: the generated one cannot show a tuple default.
    #[staticmethod]
    #[pyo3(
        signature = (eye, target, up=[0.0, 1.0, 0.0], fov_deg=45.0, width=256, height=192),
        text_signature = "(eye, target, up=(0, 1, 0), fov_deg=45.0, width=256, height=192)"
    )]
    fn look_at(
        eye: &Bound<'_, PyAny>,
        target: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = up_arg)] up: [f32; 3],
        #[pyo3(from_py_with = fov_arg)] fov_deg: f32,
        #[pyo3(from_py_with = width_arg)] width: u32,
        #[pyo3(from_py_with = height_arg)] height: u32,
    ) -> PyResult<Self> {
        let cam = Camera::look_at(
            vec3_arg(eye, "eye")?.into(),
            vec3_arg(target, "target")?.into(),
            Vec3::from(up),
            fov_deg,
            width,
            height,
        )
        .py()?;
        Ok(Self { inner: cam })
    }

    /// The same view at another resolution.
    fn with_resolution(
        &self,
        width: &Bound<'_, PyAny>,
        height: &Bound<'_, PyAny>,
    ) -> PyResult<Self> {
        let c = self
            .inner
            .with_resolution(resolution(width, "width")?, resolution(height, "height")?)
            .py()?;
        Ok(Self { inner: c })
    }

    #[getter]
    fn width(&self) -> u32 {
        self.inner.width
    }

    #[getter]
    fn height(&self) -> u32 {
        self.inner.height
    }

    /// Vertical field of view in degrees.
    #[getter]
    fn fov_deg(&self) -> f32 {
        self.inner.fov_y_deg
    }

    #[getter]
    fn eye(&self) -> [f32; 3] {
        self.inner.eye.into()
    }

    /// Unit viewing direction.
    #[getter]
    fn forward(&self) -> [f32; 3] {
        self.inner.forward.into()
    }

    /// Unit vector toward the right edge of the image.
    #[getter]
    fn right(&self) -> [f32; 3] {
        self.inner.right.into()
    }

    /// Unit vector toward the top edge of the image.
    #[getter]
    fn up(&self) -> [f32; 3] {
        self.inner.up.into()
    }

    /// Primary rays, one per pixel in row-major order: (origins, directions) as (H*W, 3)
    /// arrays, jittered from (seed, pixel) like `Scene.gbuffer`, or through pixel centres.
    #[pyo3(signature = (seed=0, jitter=true))]
    fn rays<'py>(
        &self,
        py: Python<'py>,
        #[pyo3(from_py_with = seed_or_zero)] seed: u64,
        jitter: bool,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let c = self.inner;
        let n = c.num_pixels();
        // Both arrays are checked together before either is filled: a size that cannot be
        // met is a MemoryError at once.
        let what = "rays";
        crate::alloc::check_memory(crate::alloc::bytes_of::<[[f32; 3]; 2]>(n), what).py()?;
        let origins = crate::alloc::try_filled(n, c.eye.into(), what).py()?;
        let dirs: Vec<[f32; 3]> = crate::alloc::try_collect(
            (0..n).map(|i| c.primary_ray(i, seed, jitter).1.into()),
            what,
        )
        .py()?;
        Ok((rows3_array(py, origins)?, rows3_array(py, dirs)?))
    }

    pub fn __repr__(&self) -> String {
        let c = &self.inner;
        format!(
            "Camera(eye={:?}, forward={:?}, fov_deg={}, width={}, height={})",
            c.eye.to_array(),
            c.forward.to_array(),
            c.fov_y_deg,
            c.width,
            c.height
        )
    }
}
