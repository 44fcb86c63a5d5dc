//! `viscache_rs._core.analysis`: CAM08 §4.1's visibility correlation measurements of
//! [`crate::visibility::correlation`]. Maps cross into Python in texel layout (row `y`,
//! column `x` of the equal-area square), like `VisibilityCache.record_bits`.

use numpy::{
    PyArray1, PyArrayDescrMethods, PyArrayMethods, PyReadonlyArray2, PyUntypedArray,
    PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::convert::{
    f64_arg, f64_vector, finite_rows, int_arg, log2_resolution, or_default, rows_array,
    seed_or_zero, threads_arg, IntoPyResult,
};
use super::interrupt::{detach_interruptible, PyProgress};
use super::scene::PyScene;
use crate::sampling::octahedral::morton_encode;
use crate::visibility::correlation::{
    correlation_bins as bins_core, local_correlation as local_core, sample_pairs as pairs_core,
    PairSampling, Pairs, VisibilityMaps, MAX_PARTNERS,
};

/// Visibility maps of many surface points (CAM08 eq. 7 over the sphere), made by
/// `analysis.visibility_maps`.
#[pyclass(name = "VisibilityMaps", module = "viscache_rs._core.analysis", frozen)]
pub struct PyVisibilityMaps {
    inner: VisibilityMaps,
}

#[pymethods]
impl PyVisibilityMaps {
    /// Number of maps (points).
    fn __len__(&self) -> usize {
        self.inner.len()
    }

    /// Side `R` of each `R x R` map.
    #[getter]
    fn resolution(&self) -> u32 {
        1 << self.inner.m()
    }

    /// (N, 3) float32 points the maps were traced at, world units.
    #[getter]
    fn points<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rows_array(
            py,
            self.inner.points().iter().map(|p| p.to_array()).collect(),
        )
    }

    /// (N, 3) float32 unit normals.
    #[getter]
    fn normals<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rows_array(
            py,
            self.inner.normals().iter().map(|p| p.to_array()).collect(),
        )
    }

    /// (N,) float64 fraction of each map's directions that is unoccluded.
    fn visible_fraction<'py>(&self, py: Python<'py>) -> Bound<'py, PyArray1<f64>> {
        let n = self.inner.directions() as f64;
        let v = (0..self.inner.len())
            .map(|i| self.inner.popcount(i) as f64 / n)
            .collect();
        PyArray1::from_vec(py, v)
    }

    /// (N, R, R) bool maps in texel layout (True = unoccluded), or the maps of `indices`
    /// only ((K,) integers). Direction `(y, x)` is `VisibilityCache.directions()[y * R + x]`
    /// of a cache of the same resolution.
    #[pyo3(signature = (indices=None))]
    fn bits<'py>(
        &self,
        py: Python<'py>,
        indices: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let ids: Vec<usize> = match indices {
            None => (0..self.inner.len()).collect(),
            Some(obj) => f64_vector(obj, "indices")?
                .into_iter()
                .map(|v| {
                    if v.fract() == 0.0 && v >= 0.0 && (v as usize) < self.inner.len() {
                        Ok(v as usize)
                    } else {
                        Err(PyValueError::new_err(format!(
                            "indices: {v} is not a map index in [0, {})",
                            self.inner.len()
                        )))
                    }
                })
                .collect::<PyResult<_>>()?,
        };
        let r = 1u32 << self.inner.m();
        let mut out = Vec::with_capacity(ids.len() * (r * r) as usize);
        for i in &ids {
            let map = self.inner.map(*i);
            out.extend((0..r * r).map(|t| {
                let z = morton_encode(t % r, t / r) as usize;
                (map[z / 64] >> (z % 64)) & 1 != 0
            }));
        }
        Ok(PyArray1::from_vec(py, out)
            .reshape([ids.len(), r as usize, r as usize])?
            .into_any())
    }

    fn __repr__(&self) -> String {
        format!(
            "VisibilityMaps(len={}, resolution={})",
            self.inner.len(),
            1 << self.inner.m()
        )
    }
}

/// An `(P, 2)` integer array of map indices as `u32` pairs, each below `n`.
fn pairs_arg(obj: &Bound<'_, PyAny>, n: usize) -> PyResult<Vec<[u32; 2]>> {
    let np = obj.py().import("numpy")?;
    let arr = np
        .call_method1("asarray", (obj,))
        .map_err(|e| PyValueError::new_err(format!("pairs: cannot be read as an array ({e})")))?
        .cast_into::<PyUntypedArray>()
        .map_err(|_| PyTypeError::new_err("pairs: cannot be read as an array"))?;
    let kind = arr.dtype().kind();
    if !(kind == b'i' || kind == b'u') {
        return Err(PyTypeError::new_err(format!(
            "pairs: expected an integer array, got dtype {}",
            arr.dtype()
        )));
    }
    let shape = arr.shape();
    if !(shape.len() == 2 && shape[1] == 2) {
        return Err(PyValueError::new_err(format!(
            "pairs: expected shape (P, 2), got {shape:?}"
        )));
    }
    let a: PyReadonlyArray2<i64> = np
        .call_method1("ascontiguousarray", (arr, "int64"))?
        .extract()?;
    let flat = a
        .as_slice()
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    flat.as_chunks::<2>()
        .0
        .iter()
        .enumerate()
        .map(|(k, p)| {
            if p.iter().all(|&v| v >= 0 && (v as u64) < n as u64) {
                Ok([p[0] as u32, p[1] as u32])
            } else {
                Err(PyValueError::new_err(format!(
                    "pairs: row {k} {p:?} is not a pair of map indices in [0, {n})"
                )))
            }
        })
        .collect()
}

/// Extractor of `resolution=32`: its `log2`.
fn log2_resolution_or_5(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    or_default(obj, 5, log2_resolution)
}

/// Extractor of `neighbours=16`.
fn neighbours_arg(obj: &Bound<'_, PyAny>) -> PyResult<usize> {
    or_default(obj, 16, |o| partners(o, "neighbours"))
}

/// Extractor of `far=16`.
fn far_arg(obj: &Bound<'_, PyAny>) -> PyResult<usize> {
    or_default(obj, 16, |o| partners(o, "far"))
}

/// A count of partners per point, in `[0, MAX_PARTNERS]`.
fn partners(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<usize> {
    Ok(int_arg(obj, name, 0, MAX_PARTNERS as i128)? as usize)
}

/// Traces the visibility map of every point (CAM08 eq. 7): `R x R` directions of the
/// record pattern over the whole sphere, the lower hemisphere occluded, exactly as
/// `VisibilityCache` records are traced. Deterministic for any `threads`.
/// `callback(done, total)`, if given, is called after every 1024 points with the GIL held;
/// a falsy return stops the trace (ValueError naming `progress`), an exception is raised.
#[pyfunction]
#[pyo3(signature = (scene, points, normals, resolution=32, threads=None, callback=None))]
pub fn visibility_maps(
    py: Python<'_>,
    scene: PyRef<'_, PyScene>,
    points: &Bound<'_, PyAny>,
    normals: &Bound<'_, PyAny>,
    // log2 of the resolution, from the extractor.
    #[pyo3(from_py_with = log2_resolution_or_5)] resolution: u32,
    threads: Option<&Bound<'_, PyAny>>,
    callback: Option<Py<PyAny>>,
) -> PyResult<PyVisibilityMaps> {
    let threads = threads_arg(threads)?;
    let p: Vec<glam::Vec3> = finite_rows::<3>(points, "points")?
        .into_iter()
        .map(glam::Vec3::from_array)
        .collect();
    // Normals are checked (finite, non-zero) by the core, which names the bad row.
    let n: Vec<glam::Vec3> = super::convert::rows3_f32(normals, "normals")?
        .rows()?
        .iter()
        .map(|r| glam::Vec3::from_array(*r))
        .collect();
    let scene = scene.get();
    let mut reporter = PyProgress::new(callback);
    let stop = reporter.stop_flag();
    let mut progress = |done: usize, total: usize| reporter.report(done as u64, total as u64);
    let out = detach_interruptible(py, &stop, || {
        VisibilityMaps::trace(&scene, &p, &n, resolution, threads, &mut progress)
    })?;
    reporter.finish()?;
    Ok(PyVisibilityMaps { inner: out.py()? })
}

/// Pairs of the maps' points for `correlation_bins` (CAM08 §4.1): for each point `i` in
/// order, its `neighbours` (default 16) nearest points, then `far` (default 16) partners,
/// each the point nearest to `x_i + r u` within `r / 2` of it, with `u` uniform on the
/// circle of `x_i`'s tangent plane and `r` log-uniform in `far_range = (min, max)` (world
/// units; default: 1e-3 to 1 times the points' bounding-box diagonal), drawn from
/// `(seed, i, draw)`; draws that find no point give no pair. Returns (P, 2) uint32
/// `(i, j)`, `i != j`. Deterministic for any `threads`.
#[pyfunction]
#[pyo3(signature = (maps, neighbours=16, far=16, far_range=None, seed=0, threads=None))]
pub fn sample_pairs<'py>(
    py: Python<'py>,
    maps: PyRef<'py, PyVisibilityMaps>,
    #[pyo3(from_py_with = neighbours_arg)] neighbours: usize,
    #[pyo3(from_py_with = far_arg)] far: usize,
    far_range: Option<&Bound<'py, PyAny>>,
    #[pyo3(from_py_with = seed_or_zero)] seed: u64,
    threads: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyAny>> {
    let m = &maps.inner;
    let p = m.points();
    let (far_min, far_max) = match far_range {
        Some(r) if !r.is_none() => {
            let v = f64_vector(r, "far_range")?;
            if v.len() != 2 {
                return Err(PyValueError::new_err(format!(
                    "far_range: expected (min, max), got {} numbers",
                    v.len()
                )));
            }
            (v[0] as f32, v[1] as f32)
        }
        _ => {
            let (lo, hi) = p.iter().fold(
                (glam::Vec3::INFINITY, glam::Vec3::NEG_INFINITY),
                |(lo, hi), q| (lo.min(*q), hi.max(*q)),
            );
            let diag = (hi - lo).length().max(f32::MIN_POSITIVE * 1e3);
            (1e-3 * diag, diag)
        }
    };
    let s = PairSampling {
        neighbours,
        far,
        far_min,
        far_max,
        seed,
    };
    let threads = threads_arg(threads)?;
    let pairs = py.detach(|| pairs_core(m, &s, threads)).py()?;
    rows_array(py, pairs)
}

/// Per-pair figures for (P, 2) `pairs` of map indices: a dict of (P,) float64 `rho`
/// (Pearson correlation of the two maps; NaN where a map is all visible or all occluded),
/// `distance` (world units) and `theta_deg` (angle between the normals, degrees).
#[pyfunction]
pub fn pair_correlations<'py>(
    py: Python<'py>,
    maps: PyRef<'py, PyVisibilityMaps>,
    pairs: &Bound<'py, PyAny>,
) -> PyResult<Bound<'py, PyDict>> {
    let m = &maps.inner;
    let pairs = pairs_arg(pairs, m.len())?;
    let (rho, (d, t)): (Vec<f64>, (Vec<f64>, Vec<f64>)) = py.detach(|| {
        pairs
            .iter()
            .map(|p| {
                let (i, j) = (p[0] as usize, p[1] as usize);
                (m.rho(i, j).unwrap_or(f64::NAN), m.distance_angle(i, j))
            })
            .unzip()
    });
    let out = PyDict::new(py);
    out.set_item("rho", PyArray1::from_vec(py, rho))?;
    out.set_item("distance", PyArray1::from_vec(py, d))?;
    out.set_item("theta_deg", PyArray1::from_vec(py, t))?;
    Ok(out)
}

/// CAM08 §4.1's `ρ̄(d, θ)`: the Pearson correlation of every pair's maps binned by distance
/// (`distance_edges`, world units) and angle between the normals (`theta_edges`, degrees in
/// [0, 180]); edges are strictly increasing and bins half-open except the last, like
/// `numpy.histogram`. `pairs`: (P, 2) map indices (e.g. from `sample_pairs`), or None for
/// every unordered pair once. Returns a dict: `count`, `mean`, `std` (population),
/// `undefined` (pairs with a constant map, not in the mean) as (D, T) arrays (`mean`/`std`
/// NaN where `count` is 0), the edges, `outside` (pairs beyond the edges) and `pairs`.
/// Deterministic for any `threads`.
#[pyfunction]
#[pyo3(signature = (maps, distance_edges, theta_edges, pairs=None, threads=None))]
pub fn correlation_bins<'py>(
    py: Python<'py>,
    maps: PyRef<'py, PyVisibilityMaps>,
    distance_edges: &Bound<'py, PyAny>,
    theta_edges: &Bound<'py, PyAny>,
    pairs: Option<&Bound<'py, PyAny>>,
    threads: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let de = f64_vector(distance_edges, "distance_edges")?;
    let te = f64_vector(theta_edges, "theta_edges")?;
    let list = match pairs {
        Some(p) if !p.is_none() => Some(pairs_arg(p, maps.inner.len())?),
        _ => None,
    };
    let threads = threads_arg(threads)?;
    let m = &maps.inner;
    let b = py
        .detach(|| {
            let which = list.as_deref().map_or(Pairs::All, Pairs::List);
            bins_core(m, which, &de, &te, threads)
        })
        .py()?;
    let shape = [de.len() - 1, te.len() - 1];
    let out = PyDict::new(py);
    let count: Vec<i64> = b.moments.iter().map(|x| x.count as i64).collect();
    let mean: Vec<f64> = b
        .moments
        .iter()
        .map(|x| if x.count == 0 { f64::NAN } else { x.mean })
        .collect();
    let std: Vec<f64> = b.moments.iter().map(|x| x.std()).collect();
    let undefined: Vec<i64> = b.undefined.iter().map(|&u| u as i64).collect();
    out.set_item("count", PyArray1::from_vec(py, count).reshape(shape)?)?;
    out.set_item("mean", PyArray1::from_vec(py, mean).reshape(shape)?)?;
    out.set_item("std", PyArray1::from_vec(py, std).reshape(shape)?)?;
    out.set_item(
        "undefined",
        PyArray1::from_vec(py, undefined).reshape(shape)?,
    )?;
    out.set_item("distance_edges", PyArray1::from_vec(py, b.distance_edges))?;
    out.set_item("theta_edges", PyArray1::from_vec(py, b.theta_edges))?;
    out.set_item("outside", b.outside)?;
    out.set_item("pairs", b.pairs)?;
    Ok(out)
}

/// CAM08 Fig. 4 (top row): per map, the mean ρ to the other points within `d_max` (world
/// units, inclusive) whose normals differ by less than `theta_max_deg` degrees, and how
/// many partners had a defined ρ. Returns a dict: `mean` (N,) float64, NaN where there was
/// none, and `count` (N,) int64. Deterministic for any `threads`.
#[pyfunction]
#[pyo3(signature = (maps, d_max, theta_max_deg, threads=None))]
pub fn local_correlation<'py>(
    py: Python<'py>,
    maps: PyRef<'py, PyVisibilityMaps>,
    d_max: &Bound<'py, PyAny>,
    theta_max_deg: &Bound<'py, PyAny>,
    threads: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let d_max = f64_arg(d_max, "d_max")?;
    let theta = f64_arg(theta_max_deg, "theta_max_deg")?;
    let threads = threads_arg(threads)?;
    let m = &maps.inner;
    let (mean, count) = py.detach(|| local_core(m, d_max, theta, threads)).py()?;
    let count: Vec<i64> = count.into_iter().map(i64::from).collect();
    let out = PyDict::new(py);
    out.set_item("mean", PyArray1::from_vec(py, mean))?;
    out.set_item("count", PyArray1::from_vec(py, count))?;
    Ok(out)
}
