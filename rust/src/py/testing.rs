//! Ray sets of [`crate::testing`], for peer scripts and tests.

use pyo3::prelude::*;

use super::convert::{int_arg, rows3_array, seed_arg};
use super::scene::PyScene;

type RayArrays<'py> = (Bound<'py, PyAny>, Bound<'py, PyAny>);

/// (origins, directions) of `n` incoherent shadow rays from the ground over its hemisphere.
#[pyfunction]
#[pyo3(signature = (scene, n, seed=None))]
pub fn ground_hemisphere_rays<'py>(
    py: Python<'py>,
    scene: PyRef<'py, PyScene>,
    n: &Bound<'py, PyAny>,
    seed: Option<&Bound<'py, PyAny>>,
) -> PyResult<RayArrays<'py>> {
    let n = int_arg(n, "n", 0, 1 << 28)? as usize;
    let seed = seed.map_or(Ok(0), seed_arg)?;
    let s = scene.inner.clone();
    let (o, d) = py.detach(|| crate::testing::ground_hemisphere_rays(&s, n, seed));
    Ok((rows3_array(py, o)?, rows3_array(py, d)?))
}

/// (origins, directions) of `points` record bundles of `side * side` rays each.
#[pyfunction]
#[pyo3(signature = (scene, points, side=None, seed=None))]
pub fn record_bundle_rays<'py>(
    py: Python<'py>,
    scene: PyRef<'py, PyScene>,
    points: &Bound<'py, PyAny>,
    side: Option<&Bound<'py, PyAny>>,
    seed: Option<&Bound<'py, PyAny>>,
) -> PyResult<RayArrays<'py>> {
    let points = int_arg(points, "points", 0, 1 << 20)? as usize;
    let side = side.map_or(Ok(32), |s| int_arg(s, "side", 1, 256))? as usize;
    let seed = seed.map_or(Ok(0), seed_arg)?;
    let s = scene.inner.clone();
    let (o, d) = py.detach(|| crate::testing::record_bundle_rays(&s, points, side, seed));
    Ok((rows3_array(py, o)?, rows3_array(py, d)?))
}
