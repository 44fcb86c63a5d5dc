//! `vc.Material`.

use pyo3::prelude::*;

use super::convert::{f64_arg, vec3_arg, IntoPyResult};
use crate::bsdf::Material;

/// A surface material: `Material.lambert(albedo)` or `Material.phong(kd, ks, exponent)`.
#[pyclass(
    name = "Material",
    module = "viscache_rs._core",
    frozen,
    eq,
    from_py_object
)]
#[derive(Clone, PartialEq)]
pub struct PyMaterial {
    pub inner: Material,
}

#[pymethods]
impl PyMaterial {
    /// Diffuse material; `albedo` is linear RGB in [0, 1].
    #[staticmethod]
    fn lambert(albedo: &Bound<'_, PyAny>) -> PyResult<Self> {
        Ok(Self {
            inner: Material::lambert(vec3_arg(albedo, "albedo")?).py()?,
        })
    }

    /// Energy-normalised Phong: `kd + ks <= 1` per channel, `exponent` in [1, 1e4].
    #[staticmethod]
    fn phong(
        kd: &Bound<'_, PyAny>,
        ks: &Bound<'_, PyAny>,
        exponent: &Bound<'_, PyAny>,
    ) -> PyResult<Self> {
        let e = f64_arg(exponent, "exponent")? as f32;
        Ok(Self {
            inner: Material::phong(vec3_arg(kd, "kd")?, vec3_arg(ks, "ks")?, e).py()?,
        })
    }

    /// `"lambert"` or `"phong"`.
    #[getter]
    fn kind(&self) -> &'static str {
        match self.inner {
            Material::Lambert { .. } => "lambert",
            Material::Phong { .. } => "phong",
        }
    }

    /// Parameters as a dict (`albedo`, or `kd`, `ks`, `exponent`).
    fn params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
        let d = pyo3::types::PyDict::new(py);
        match self.inner {
            Material::Lambert { albedo } => d.set_item("albedo", albedo)?,
            Material::Phong { kd, ks, exponent } => {
                d.set_item("kd", kd)?;
                d.set_item("ks", ks)?;
                d.set_item("exponent", exponent)?;
            }
        }
        Ok(d)
    }

    fn __repr__(&self) -> String {
        match self.inner {
            Material::Lambert { albedo } => format!("Material.lambert({albedo:?})"),
            Material::Phong { kd, ks, exponent } => {
                format!("Material.phong({kd:?}, {ks:?}, {exponent})")
            }
        }
    }
}
