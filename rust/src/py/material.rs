//! `vc.Material`.

use glam::Vec3;
use numpy::PyArray1;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use super::convert::{
    f64_arg, image_array, int_arg, or_default, rows3_array, rows3_f32, unit_directions, vec3_arg,
    IntoPyResult,
};
use crate::bsdf::rows as bsdf_rows;
use crate::bsdf::{Material, MAX_CELL_LEVEL};
use crate::sampling::octahedral::morton_encode;

fn unit(v: Vec3, name: &str) -> PyResult<Vec3> {
    if !v.is_finite() {
        return Err(PyValueError::new_err(format!(
            "{name}: must be finite, got {v}"
        )));
    }
    let l = v.length();
    if !(l > 0.0 && l.is_finite()) {
        return Err(PyValueError::new_err(format!(
            "{name}: must have non-zero length, got {v}"
        )));
    }
    Ok(v / l)
}

/// Rows of normals, wo and wi of one batch, normalised (the core checks their lengths).
type ShadingRows = (Vec<Vec3>, Vec<Vec3>, Vec<Vec3>);

fn shading_rows(
    normals: &Bound<'_, PyAny>,
    wo: &Bound<'_, PyAny>,
    wi: &Bound<'_, PyAny>,
) -> PyResult<ShadingRows> {
    let n = unit_directions(normals, "normals")?;
    let o = unit_directions(wo, "wo")?;
    let i = unit_directions(wi, "wi")?;
    Ok((n, o, i))
}

/// A surface material: `Material.lambert(albedo)` or `Material.phong(kd, ks, exponent)`.
/// Extractor of `level=5` (B~ over 32 x 32 cells, the renderer's product level).
fn level_arg(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    or_default(obj, 5, |o| {
        Ok(int_arg(o, "level", 1, MAX_CELL_LEVEL as i128)? as u32)
    })
}

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

    /// BRDF values f_r (1/sr, RGB, no cosine) for rows of unit normals, wo and wi (each
    /// (N, 3); rows are normalised); zero where wo or wi is at or below the surface.
    fn eval<'py>(
        &self,
        py: Python<'py>,
        normals: &Bound<'py, PyAny>,
        wo: &Bound<'py, PyAny>,
        wi: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let (n, o, i) = shading_rows(normals, wo, wi)?;
        let mut out = vec![[0.0f32; 3]; n.len()];
        py.detach(|| bsdf_rows::eval_rows(&self.inner, &n, &o, &i, &mut out))
            .py()?;
        rows3_array(py, out)
    }

    /// Samples wi for rows of normals and wo (N, 3) with uniforms u (N, 3) in [0, 1]:
    /// u[:, 0] picks the lobe, u[:, 1:] the direction. Returns (wi (N, 3) float32,
    /// valid (N,) bool); invalid rows (sample below the surface) hold zeros.
    fn sample<'py>(
        &self,
        py: Python<'py>,
        normals: &Bound<'py, PyAny>,
        wo: &Bound<'py, PyAny>,
        u: &Bound<'py, PyAny>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let (n, o) = (
            unit_directions(normals, "normals")?,
            unit_directions(wo, "wo")?,
        );
        let u = rows3_f32(u, "u")?;
        let u = u.rows()?;
        let (mut wi, mut valid) = (vec![[0.0f32; 3]; n.len()], vec![false; n.len()]);
        py.detach(|| bsdf_rows::sample_rows(&self.inner, &n, &o, u, &mut wi, &mut valid))
            .py()?;
        Ok((
            rows3_array(py, wi)?,
            PyArray1::from_vec(py, valid).into_any(),
        ))
    }

    /// Solid-angle pdf (1/sr, float64, shape (N,)) of `sample` for rows of normals, wo, wi.
    fn pdf<'py>(
        &self,
        py: Python<'py>,
        normals: &Bound<'py, PyAny>,
        wo: &Bound<'py, PyAny>,
        wi: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let (n, o, i) = shading_rows(normals, wo, wi)?;
        let mut out = vec![0.0f64; n.len()];
        py.detach(|| bsdf_rows::pdf_rows(&self.inner, &n, &o, &i, &mut out))
            .py()?;
        Ok(PyArray1::from_vec(py, out).into_any())
    }

    /// B~ for one shading point: the conservative per-cell approximation of
    /// luminance(f_r) cos θi (1/sr) over the 2^level x 2^level octahedral grid, as a
    /// float32 array indexed [y, x] (row-major texels). level in 1..=8.
    #[pyo3(signature = (normal, wo, level=5))]
    fn product_cells<'py>(
        &self,
        py: Python<'py>,
        normal: &Bound<'py, PyAny>,
        wo: &Bound<'py, PyAny>,
        #[pyo3(from_py_with = level_arg)] level: u32,
    ) -> PyResult<Bound<'py, PyAny>> {
        let n = unit(Vec3::from(vec3_arg(normal, "normal")?), "normal")?;
        let o = unit(Vec3::from(vec3_arg(wo, "wo")?), "wo")?;
        let m = self.inner;
        let res = 1usize << level;
        let grid = py.detach(|| {
            let mut morton = vec![0.0f32; res * res];
            m.product_cells(n, o, level, &mut morton);
            let mut grid = vec![0.0f32; res * res];
            for y in 0..res {
                for x in 0..res {
                    grid[y * res + x] = morton[morton_encode(x as u32, y as u32) as usize];
                }
            }
            grid
        });
        image_array(py, grid, res, res, None)
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
