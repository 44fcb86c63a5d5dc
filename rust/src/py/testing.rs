//! Ray sets of [`crate::testing`], for peer scripts and tests.

use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::convert::{
    f64_arg, f64_vector, int_arg, nan_or_unit_rows, or_default, rows3_array, rows_array,
    seed_or_zero,
};
use super::scene::PyScene;
use crate::sampling::chi2::{chi2_binned, integration_directions, integration_weight, Chi2Params};

type RayArrays<'py> = (Bound<'py, PyAny>, Bound<'py, PyAny>);

/// (origins, directions) of `n` incoherent shadow rays from the ground over its hemisphere.
#[pyfunction]
#[pyo3(signature = (scene, n, seed=0))]
pub fn ground_hemisphere_rays<'py>(
    py: Python<'py>,
    scene: PyRef<'py, PyScene>,
    n: &Bound<'py, PyAny>,
    #[pyo3(from_py_with = seed_or_zero)] seed: u64,
) -> PyResult<RayArrays<'py>> {
    let n = int_arg(n, "n", 0, 1 << 28)? as usize;
    let s = scene.get();
    let (o, d) = py.detach(|| crate::testing::ground_hemisphere_rays(&s, n, seed));
    Ok((rows3_array(py, o)?, rows3_array(py, d)?))
}

/// Extractor of `side=32`.
fn side_arg(obj: &Bound<'_, PyAny>) -> PyResult<usize> {
    or_default(obj, 32, |o| Ok(int_arg(o, "side", 1, 256)? as usize))
}

/// (origins, directions) of `points` record bundles of `side * side` rays each.
#[pyfunction]
#[pyo3(signature = (scene, points, side=32, seed=0))]
pub fn record_bundle_rays<'py>(
    py: Python<'py>,
    scene: PyRef<'py, PyScene>,
    points: &Bound<'py, PyAny>,
    #[pyo3(from_py_with = side_arg)] side: usize,
    #[pyo3(from_py_with = seed_or_zero)] seed: u64,
) -> PyResult<RayArrays<'py>> {
    let points = int_arg(points, "points", 0, 1 << 20)? as usize;
    let s = scene.get();
    let (o, d) = py.detach(|| crate::testing::record_bundle_rays(&s, points, side, seed));
    Ok((rows3_array(py, o)?, rows3_array(py, d)?))
}

/// Evaluates a Python pdf on `dirs` in one vectorised call: `(M,)` finite, non-negative.
fn call_pdf(py: Python<'_>, pdf: &Bound<'_, PyAny>, dirs: Vec<[f32; 3]>) -> PyResult<Vec<f64>> {
    let m = dirs.len();
    let values = pdf.call1((rows_array(py, dirs)?,))?;
    let values: Vec<f64> = f64_vector(&values, "pdf")?;
    if values.len() != m {
        return Err(PyValueError::new_err(format!(
            "pdf: returned {} values for {m} directions",
            values.len()
        )));
    }
    if let Some(i) = values.iter().position(|v| !(v.is_finite() && *v >= 0.0)) {
        return Err(PyValueError::new_err(format!(
            "pdf: value {} at direction {i} is not finite and >= 0",
            values[i]
        )));
    }
    Ok(values)
}

// Extractors of `chi2_sphere`'s arguments; the signature's literals are Chi2Params::DEFAULT.
const _: () = {
    let d = Chi2Params::DEFAULT;
    assert!(d.resolution == 32 && d.subdivisions == 8);
    assert!(d.min_expected == 5.0 && d.significance == 0.01);
};

fn chi2_resolution(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    or_default(obj, Chi2Params::DEFAULT.resolution, |o| {
        Ok(int_arg(o, "resolution", 1, 1024)? as u32)
    })
}

fn chi2_subdivisions(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    or_default(obj, Chi2Params::DEFAULT.subdivisions, |o| {
        Ok(int_arg(o, "subdivisions", 1, 64)? as u32)
    })
}

fn chi2_min_expected(obj: &Bound<'_, PyAny>) -> PyResult<f64> {
    or_default(obj, Chi2Params::DEFAULT.min_expected, |o| {
        f64_arg(o, "min_expected")
    })
}

fn chi2_significance(obj: &Bound<'_, PyAny>) -> PyResult<f64> {
    or_default(obj, Chi2Params::DEFAULT.significance, |o| {
        f64_arg(o, "significance")
    })
}

/// Pearson's chi-square test of sampled directions against their solid-angle pdf over the
/// equal-area octahedral bins ([`crate::sampling::chi2`]). `dirs` is `(N, 3)`, one row per
/// attempt, NaN rows for attempts the sampler rejected; `pdf(d)` maps an `(M, 3)` float32
/// array of unit directions to `(M,)` densities and is called twice (bins, samples).
#[pyfunction]
#[pyo3(signature = (dirs, pdf, resolution=32, subdivisions=8, min_expected=5.0, significance=0.01))]
pub fn chi2_sphere<'py>(
    py: Python<'py>,
    dirs: &Bound<'py, PyAny>,
    pdf: &Bound<'py, PyAny>,
    #[pyo3(from_py_with = chi2_resolution)] resolution: u32,
    #[pyo3(from_py_with = chi2_subdivisions)] subdivisions: u32,
    #[pyo3(from_py_with = chi2_min_expected)] min_expected: f64,
    #[pyo3(from_py_with = chi2_significance)] significance: f64,
) -> PyResult<Bound<'py, PyDict>> {
    if !(min_expected > 0.0 && min_expected.is_finite()) {
        return Err(PyValueError::new_err(format!(
            "min_expected: must be positive, got {min_expected}"
        )));
    }
    if !(significance > 0.0 && significance < 1.0) {
        return Err(PyValueError::new_err(format!(
            "significance: must lie in (0, 1), got {significance}"
        )));
    }
    if !pdf.is_callable() {
        return Err(PyTypeError::new_err("pdf: expected a callable"));
    }
    let params = Chi2Params {
        resolution,
        subdivisions,
        min_expected,
        significance,
    };
    let rows = nan_or_unit_rows(dirs, "dirs")?;
    let accepted: Vec<[f32; 3]> = rows.iter().flatten().map(|d| d.to_array()).collect();
    let at_samples = call_pdf(py, pdf, accepted)?;
    let impossible = at_samples.iter().filter(|&&p| p <= 0.0).count() as u64;
    let points: Vec<[f32; 3]> = integration_directions(&params)
        .iter()
        .map(|d| d.to_array())
        .collect();
    let at_points = call_pdf(py, pdf, points)?;
    let per_bin = (subdivisions * subdivisions) as usize;
    let weight = integration_weight(&params);
    let integrals = at_points
        .chunks(per_bin)
        .map(|c| c.iter().sum::<f64>() * weight)
        .collect();
    let o = chi2_binned(&rows, impossible, integrals, &params);
    let d = PyDict::new(py);
    d.set_item("statistic", o.statistic)?;
    d.set_item("dof", o.dof)?;
    d.set_item("p_value", o.p_value)?;
    d.set_item("integral", o.integral)?;
    d.set_item("samples_where_pdf_is_zero", o.samples_where_pdf_is_zero)?;
    d.set_item("rejected", o.rejected)?;
    d.set_item("passed", o.passed)?;
    Ok(d)
}

/// The vector instruction set the kernels run with on this CPU: "avx512", "avx2",
/// "popcnt" or "portable" (benches report it beside their timings).
#[pyfunction]
pub fn simd_level() -> &'static str {
    crate::simd::level().name()
}
