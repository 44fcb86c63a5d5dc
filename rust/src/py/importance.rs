//! `viscache_rs.ImportanceCache`: the importance cache of
//! [`crate::estimators::importance`] (survey ch. 6).

use std::path::PathBuf;
use std::sync::Arc;

use numpy::{PyArray1, PyArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyType};

use super::camera::PyCamera;
use super::convert::{
    f64_arg, int_arg, points_and_normals, seed_or_zero, threads_arg, IntoPyResult,
};
use super::gbuffer::{view_arg, PyGBuffer, View};
use super::interrupt::{detach_interruptible, PyProgress};
use super::scene::PyScene;
use super::vpl::PyVpls;
use crate::camera::GBuffer;
use crate::estimators::importance::records::{
    ImportanceCache, ImportanceParams, MAX_NEAREST, MAX_SPACING,
};
use crate::parallel::with_threads;

/// Importance records over a scene and a light set (survey ch. 6).
#[pyclass(name = "ImportanceCache", module = "viscache_rs._core", subclass)]
pub struct PyImportanceCache {
    pub(crate) inner: Arc<ImportanceCache>,
    /// The scene records are made in.
    #[pyo3(get)]
    pub(super) scene: Py<PyScene>,
    /// The lights the records' rows are over.
    #[pyo3(get)]
    pub(super) lights: Py<PyVpls>,
}

/// `o` unless it is None (or Python's None).
pub(crate) fn given<'a, 'py>(o: Option<&'a Bound<'py, PyAny>>) -> Option<&'a Bound<'py, PyAny>> {
    o.filter(|o| !o.is_none())
}

/// `alpha`: four numbers `(α_F, α_U, α_B, α_C)`, each in `(0, 1]`.
pub(crate) fn alpha4_arg(obj: &Bound<'_, PyAny>) -> PyResult<[f64; 4]> {
    let bad = || {
        PyTypeError::new_err(format!(
            "alpha: expected four numbers (alpha_F, alpha_U, alpha_B, alpha_C), got {}",
            obj.repr().map(|r| r.to_string()).unwrap_or_default()
        ))
    };
    if obj.is_instance_of::<pyo3::types::PyString>() {
        return Err(bad());
    }
    let items: Vec<Bound<'_, PyAny>> = obj.extract().map_err(|_| bad())?;
    if items.len() != 4 {
        return Err(PyValueError::new_err(format!(
            "alpha: expected four values (alpha_F, alpha_U, alpha_B, alpha_C), got {}",
            items.len()
        )));
    }
    let mut a = [0.0; 4];
    for (slot, item) in a.iter_mut().zip(&items) {
        *slot = f64_arg(item, "alpha")?;
    }
    crate::estimators::importance::combine::Combine::AlphaMax(a)
        .validate()
        .py()?;
    Ok(a)
}

/// The cache's parameters from Python values (None: the default); errors name the
/// argument.
pub(crate) fn params_arg(
    spacing: Option<&Bound<'_, PyAny>>,
    nearest: Option<&Bound<'_, PyAny>>,
    lam: Option<&Bound<'_, PyAny>>,
    alpha: Option<&Bound<'_, PyAny>>,
) -> PyResult<ImportanceParams> {
    let mut p = ImportanceParams::DEFAULT;
    if let Some(s) = given(spacing) {
        p.spacing = int_arg(s, "spacing", 1, MAX_SPACING as i128)? as u32;
    }
    if let Some(n) = given(nearest) {
        p.nearest = int_arg(n, "nearest", 1, MAX_NEAREST as i128)? as u32;
    }
    if let Some(l) = given(lam) {
        p.lam = f64_arg(l, "lam")? as f32;
    }
    if let Some(a) = given(alpha) {
        p.alpha = alpha4_arg(a)?;
    }
    p.validate().py()?;
    Ok(p)
}

#[pymethods]
impl PyImportanceCache {
    /// `ImportanceCache(scene, lights, spacing=8, nearest=3, lam=1.0, alpha=(0.5, 0.5,
    /// 0.5, 1.0))`: an empty cache over `lights` (a `VPLs` traced in `scene`).
    #[new]
    #[pyo3(signature = (scene, lights, spacing=None, nearest=None, lam=None, alpha=None))]
    fn new(
        py: Python<'_>,
        scene: Py<PyScene>,
        lights: Py<PyVpls>,
        spacing: Option<&Bound<'_, PyAny>>,
        nearest: Option<&Bound<'_, PyAny>>,
        lam: Option<&Bound<'_, PyAny>>,
        alpha: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let p = params_arg(spacing, nearest, lam, alpha)?;
        let core = scene.borrow(py).get();
        let set = &lights.get().inner;
        if set.fingerprint != core.geometry_fingerprint() {
            return Err(PyValueError::new_err(
                "lights: were traced in other geometry: trace them again for this scene",
            ));
        }
        let inner = ImportanceCache::new(set, p).py()?;
        Ok(Self {
            inner: Arc::new(inner),
            scene,
            lights,
        })
    }

    /// The parameters as a dict: spacing, nearest, lam, alpha.
    #[getter]
    fn params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let p = self.inner.params();
        let d = PyDict::new(py);
        d.set_item("spacing", p.spacing)?;
        d.set_item("nearest", p.nearest)?;
        d.set_item("lam", p.lam)?;
        d.set_item("alpha", (p.alpha[0], p.alpha[1], p.alpha[2], p.alpha[3]))?;
        Ok(d)
    }

    /// Bytes of the records (rows F, U, B: at most 12 per light and record, less where
    /// rows are sparse) and their index.
    fn memory_bytes(&self) -> usize {
        self.inner.memory_bytes()
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    fn __repr__(&self) -> String {
        let p = self.inner.params();
        format!(
            "ImportanceCache(records={}, lights={}, spacing={}, nearest={}, lam={}, alpha={:?})",
            self.inner.len(),
            self.inner.lights.len(),
            p.spacing,
            p.nearest,
            p.lam,
            p.alpha
        )
    }

    /// Grows the cache for the view (Algorithm 12): a record every `spacing` pixels of the
    /// surfaces with a diffuse part, then at every such pixel with fewer than `nearest`
    /// records within reach. Deterministic for any `threads`; `time_budget` (seconds) and
    /// a falsy `callback(done, total)` stop between waves, keeping the records so far.
    /// `seed` is accepted for the shape of the other caches' builds (the records take no
    /// random numbers). Returns a dict: records, inserted, discarded, grid, pixels, points,
    /// pairs (record-light pairs evaluated), rays, seconds, us_per_pair, complete.
    #[pyo3(signature = (camera=None, seed=0, threads=None, *, gbuffer=None, time_budget=None, callback=None))]
    #[allow(clippy::too_many_arguments)]
    fn build<'py>(
        &self,
        py: Python<'py>,
        camera: Option<PyRef<'py, PyCamera>>,
        #[pyo3(from_py_with = seed_or_zero)] seed: u64,
        threads: Option<&Bound<'py, PyAny>>,
        gbuffer: Option<PyRef<'py, PyGBuffer>>,
        time_budget: Option<&Bound<'py, PyAny>>,
        callback: Option<Py<PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let _ = seed;
        let view = view_arg(camera, gbuffer)?;
        let threads = threads_arg(threads)?;
        let budget = match time_budget {
            Some(b) if !b.is_none() => Some(f64_arg(b, "time_budget")?),
            _ => None,
        };
        crate::error::check_time_budget(budget).py()?;
        let scene = self.scene.borrow(py).get();
        let inner = self.inner.clone();
        let mut reporter = PyProgress::new(callback);
        let stop = reporter.stop_flag();
        let mut callback = |done: usize, total: usize| reporter.report(done as u64, total as u64);
        let out = detach_interruptible(py, &stop, || {
            let start = std::time::Instant::now();
            let traced;
            let g = match &view {
                View::GBuffer(g) => g,
                View::Camera(cam) => {
                    traced =
                        with_threads(threads, || GBuffer::render(&scene, cam, 0, false, None))??;
                    &traced
                }
            };
            inner.build_from(&scene, g, threads, start, budget, &mut callback)
        });
        reporter.finish()?;
        let r = out?.py()?;
        let d = PyDict::new(py);
        d.set_item("records", r.records)?;
        d.set_item("inserted", r.inserted)?;
        d.set_item("discarded", r.discarded)?;
        d.set_item("grid", r.grid)?;
        d.set_item("pixels", r.pixels)?;
        d.set_item("points", r.points)?;
        d.set_item("pairs", r.pairs)?;
        d.set_item("rays", r.rays)?;
        d.set_item("seconds", r.seconds)?;
        d.set_item("us_per_pair", r.seconds * 1e6 / (r.pairs.max(1) as f64))?;
        d.set_item("complete", r.complete)?;
        Ok(d)
    }

    /// Eq. 6.3 at `points` (N, 3) with `normals` (N, 3; need not be unit): the records a
    /// shading point there draws from. Returns a dict: `ids` (N, nearest) int64 in id
    /// order (-1 pads), `records` (N,) int32.
    #[pyo3(signature = (points, normals, lam=None))]
    fn lookup<'py>(
        &self,
        py: Python<'py>,
        points: &Bound<'py, PyAny>,
        normals: &Bound<'py, PyAny>,
        lam: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let (pts, nrm) = points_and_normals(points, normals)?;
        let lam = match lam {
            Some(l) if !l.is_none() => {
                let l = f64_arg(l, "lam")? as f32;
                if l < 0.0 {
                    return Err(PyValueError::new_err(format!("lam: must be >= 0, got {l}")));
                }
                l
            }
            _ => self.inner.params().lam,
        };
        let k = self.inner.params().nearest as usize;
        let inner = self.inner.clone();
        let found: Vec<Vec<u32>> = py.detach(|| {
            let state = inner.read();
            let lambda = ImportanceCache::lambda_world(&state, lam);
            pts.iter()
                .zip(&nrm)
                .map(|(&x, &n)| state.nearest(x, n, k as u32, lambda).ids().to_vec())
                .collect()
        });
        let n = pts.len();
        let mut ids = vec![-1i64; n * k];
        let mut records = vec![0i32; n];
        for (i, f) in found.iter().enumerate() {
            records[i] = f.len() as i32;
            for (j, id) in f.iter().enumerate() {
                ids[i * k + j] = *id as i64;
            }
        }
        let d = PyDict::new(py);
        d.set_item("ids", PyArray1::from_vec(py, ids).reshape([n, k])?)?;
        d.set_item("records", PyArray1::from_vec(py, records))?;
        Ok(d)
    }

    /// The records as arrays: `position`, `normal` (N, 3) float32, `radius` (N,) float32
    /// and `F`, `U`, `B` (N, lights) float32, each light's luminance in that row.
    fn records<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let state = self.inner.read();
        let recs = &state.index.records().records;
        let (n, l) = (recs.len(), self.inner.lights.len());
        let d = PyDict::new(py);
        let v3 =
            |f: &dyn Fn(&crate::estimators::importance::records::ImportanceRecord) -> [f32; 3]| {
                PyArray1::from_vec(py, recs.iter().flat_map(f).collect::<Vec<f32>>())
                    .reshape([n, 3])
            };
        d.set_item("position", v3(&|r| r.position.to_array())?)?;
        d.set_item("normal", v3(&|r| r.normal.to_array())?)?;
        d.set_item(
            "radius",
            PyArray1::from_vec(py, recs.iter().map(|r| r.radius).collect::<Vec<f32>>()),
        )?;
        use crate::estimators::importance::combine::Row;
        for (name, row) in [("F", Row::F), ("U", Row::U), ("B", Row::B)] {
            let v: Vec<f32> = recs
                .iter()
                .flat_map(|r| {
                    let sums = r.row(row).dense(l);
                    (0..l).map(move |k| sums[k] - if k == 0 { 0.0 } else { sums[k - 1] })
                })
                .collect();
            d.set_item(name, PyArray1::from_vec(py, v).reshape([n, l])?)?;
        }
        Ok(d)
    }

    /// Writes the cache to `path` (with the scene's geometry fingerprint and a hash of the
    /// lights).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let inner = self.inner.clone();
        py.detach(|| inner.save(&path)).py()
    }

    /// Reads a cache written by `save` for `scene` and `lights`; a truncated or corrupted
    /// file, another scene or another light set raises ValueError naming it.
    #[classmethod]
    fn load<'py>(
        cls: &Bound<'py, PyType>,
        path: PathBuf,
        scene: Py<PyScene>,
        lights: Py<PyVpls>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let py = cls.py();
        let core_scene = scene.borrow(py).get();
        let cache = {
            let set = &lights.get().inner;
            py.detach(|| ImportanceCache::load_for(&path, &core_scene, set))
                .py()?
        };
        let obj = cls.call1((scene, lights))?;
        obj.cast::<Self>()?.borrow_mut().inner = Arc::new(cache);
        Ok(obj)
    }
}
