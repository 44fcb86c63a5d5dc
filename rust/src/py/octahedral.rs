//! `viscache_rs._core.octahedral`: the equal-area octahedral map of
//! [`crate::sampling::octahedral`], batched over numpy arrays.

use glam::Vec2;
use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use super::convert::{finite_rows, int_arg, rows_array, unit_directions};
use crate::sampling::octahedral;

/// `(N, 2)` points of `[0,1]^2` for `(N, 3)` directions (normalised first).
#[pyfunction]
pub fn sphere_to_square<'py>(
    py: Python<'py>,
    dirs: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyAny>> {
    let dirs = unit_directions(dirs, "dirs")?;
    let uv = py.detach(|| {
        dirs.iter()
            .map(|&d| octahedral::sphere_to_square(d).to_array())
            .collect()
    });
    rows_array(py, uv)
}

/// `(N, 3)` unit directions for `(N, 2)` points of `[0,1]^2`.
#[pyfunction]
pub fn square_to_sphere<'py>(
    py: Python<'py>,
    uv: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyAny>> {
    let uv = finite_rows::<2>(uv, "uv")?;
    if let Some(i) = uv
        .iter()
        .position(|p| p.iter().any(|c| !(0.0..=1.0).contains(c)))
    {
        return Err(PyValueError::new_err(format!(
            "uv: row {i} lies outside [0, 1]^2: {:?}",
            uv[i]
        )));
    }
    let dirs = py.detach(|| {
        uv.iter()
            .map(|&p| octahedral::square_to_sphere(Vec2::from_array(p)).to_array())
            .collect()
    });
    rows_array(py, dirs)
}

/// `(N, 2)` integer texel coordinates `(x, y)` of `(N, 3)` directions on a `res x res` grid.
#[pyfunction]
pub fn texel_of<'py>(
    py: Python<'py>,
    dirs: &Bound<'py, PyAny>,
    res: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyAny>> {
    let res = int_arg(res, "res", 1, octahedral::MAX_RESOLUTION as i128)? as u32;
    let dirs = unit_directions(dirs, "dirs")?;
    let texels: Vec<[i64; 2]> = py.detach(|| {
        dirs.iter()
            .map(|&d| {
                let t = octahedral::texel_of(d, res);
                [t.x as i64, t.y as i64]
            })
            .collect()
    });
    rows_array(py, texels)
}
