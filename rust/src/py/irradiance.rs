//! `viscache_rs.IrradianceCache`: the irradiance cache of
//! [`crate::estimators::irradiance`] (Survey ch. 3).

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use numpy::{PyArray1, PyArrayMethods};
use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyTuple, PyType};

use super::camera::PyCamera;
use super::convert::{
    f64_arg, int_arg, points_and_normals, seed_or_zero, threads_arg, vec3_arg, IntoPyResult,
};
use super::envmap::PyEnvMap;
use super::gbuffer::{view_arg, PyGBuffer, View};
use super::interrupt::{detach_interruptible, PyProgress};
use super::scene::PyScene;
use crate::camera::GBuffer;
use crate::estimators::direct::{Lighting, ProductLevel};
use crate::estimators::irradiance::cache::{
    Gradients, IrradianceCache, IrradianceParams, MAX_SECONDARY_SPP, MAX_STRATA,
};
use crate::parallel::with_threads;

/// One-bounce irradiance records with gradients over a scene (Survey ch. 3).
#[pyclass(name = "IrradianceCache", module = "viscache_rs._core", subclass)]
pub struct PyIrradianceCache {
    pub(crate) inner: Arc<IrradianceCache>,
    /// The scene records are traced in.
    #[pyo3(get)]
    pub(super) scene: Py<PyScene>,
}

/// `strata`: two integers `(M, N)`, each `>= 1`, with `M·N <= MAX_STRATA`.
fn strata_arg(obj: &Bound<'_, PyAny>) -> PyResult<(u32, u32)> {
    let bad = || {
        PyTypeError::new_err(format!(
            "strata: expected two integers (M, N) of theta and phi strata, got {}",
            obj.repr().map(|r| r.to_string()).unwrap_or_default()
        ))
    };
    let items: Vec<Bound<'_, PyAny>> = match obj.cast::<PyTuple>() {
        Ok(t) => t.iter().collect(),
        Err(_) => match obj.extract::<Vec<Bound<'_, PyAny>>>() {
            Ok(v) if !obj.is_instance_of::<pyo3::types::PyString>() => v,
            _ => return Err(bad()),
        },
    };
    if items.len() != 2 {
        return Err(bad());
    }
    let m = int_arg(&items[0], "strata", 1, MAX_STRATA as i128)? as u32;
    let n = int_arg(&items[1], "strata", 1, MAX_STRATA as i128)? as u32;
    Ok((m, n))
}

/// The cache's parameters from Python values (None: the default); errors name the
/// argument.
#[allow(clippy::too_many_arguments)]
pub(crate) fn params_arg<'py>(
    a: Option<&Bound<'py, PyAny>>,
    strata: Option<&Bound<'py, PyAny>>,
    r_min: Option<&Bound<'py, PyAny>>,
    r_max: Option<&Bound<'py, PyAny>>,
    gradients: Option<&Bound<'py, PyAny>>,
    clamp_neighbours: Option<&Bound<'py, PyAny>>,
    secondary_spp: Option<&Bound<'py, PyAny>>,
) -> PyResult<IrradianceParams> {
    let mut p = IrradianceParams::DEFAULT;
    let given = |o: Option<&Bound<'py, PyAny>>| o.filter(|o| !o.is_none()).cloned();
    if let Some(a) = given(a) {
        p.a = f64_arg(&a, "a")? as f32;
    }
    if let Some(s) = given(strata) {
        p.strata = strata_arg(&s)?;
    }
    if let Some(r) = given(r_min) {
        p.r_min = f64_arg(&r, "r_min")? as f32;
    }
    if let Some(r) = given(r_max) {
        p.r_max = f64_arg(&r, "r_max")? as f32;
    }
    if let Some(g) = given(gradients) {
        let name: String = g.extract().map_err(|_| {
            PyTypeError::new_err("gradients: expected \"none\", \"rotation\" or \"both\"")
        })?;
        p.gradients = Gradients::parse(&name).py()?;
    }
    if let Some(c) = given(clamp_neighbours) {
        p.clamp_neighbours = c
            .cast::<pyo3::types::PyBool>()
            .map_err(|_| PyTypeError::new_err("clamp_neighbours: expected a bool"))?
            .is_true();
    }
    if let Some(s) = given(secondary_spp) {
        p.secondary_spp = int_arg(&s, "secondary_spp", 1, MAX_SECONDARY_SPP as i128)? as u32;
    }
    p.validate().py()?;
    Ok(p)
}

fn params_dict<'py>(py: Python<'py>, p: &IrradianceParams) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    d.set_item("a", p.a)?;
    d.set_item("strata", (p.strata.0, p.strata.1))?;
    d.set_item("r_min", p.r_min)?;
    d.set_item("r_max", p.r_max)?;
    d.set_item("gradients", p.gradients.name())?;
    d.set_item("clamp_neighbours", p.clamp_neighbours)?;
    d.set_item("secondary_spp", p.secondary_spp)?;
    Ok(d)
}

/// The lighting of records: `scene` lit by `envmap` and its area lights.
fn lighting<'a>(
    scene: &'a crate::geometry::Scene,
    env: &'a crate::lights::envmap::EnvMap,
) -> Lighting<'a> {
    Lighting {
        scene,
        env,
        product_level: ProductLevel::PerMaterial,
    }
}

#[pymethods]
impl PyIrradianceCache {
    /// `IrradianceCache(scene, a=0.2, strata=(16, 64), r_min=1.5, r_max=32.0,
    /// gradients="both", clamp_neighbours=True, secondary_spp=1)`: an empty cache.
    #[new]
    #[pyo3(signature = (scene, a=None, strata=None, r_min=None, r_max=None, gradients=None, clamp_neighbours=None, secondary_spp=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        scene: Py<PyScene>,
        a: Option<&Bound<'_, PyAny>>,
        strata: Option<&Bound<'_, PyAny>>,
        r_min: Option<&Bound<'_, PyAny>>,
        r_max: Option<&Bound<'_, PyAny>>,
        gradients: Option<&Bound<'_, PyAny>>,
        clamp_neighbours: Option<&Bound<'_, PyAny>>,
        secondary_spp: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let p = params_arg(
            a,
            strata,
            r_min,
            r_max,
            gradients,
            clamp_neighbours,
            secondary_spp,
        )?;
        Ok(Self {
            inner: Arc::new(IrradianceCache::new(p).py()?),
            scene,
        })
    }

    /// The parameters as a dict.
    #[getter]
    fn params<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        params_dict(py, self.inner.params())
    }

    /// Bytes of one record (position, normal, E, R_i and both gradients).
    #[getter]
    fn record_bytes(&self) -> usize {
        IrradianceCache::record_bytes()
    }

    /// Bytes of the records and of their index.
    fn memory_bytes(&self) -> usize {
        self.inner.memory_bytes()
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    fn __repr__(&self) -> String {
        let p = self.inner.params();
        format!(
            "IrradianceCache(records={}, a={}, strata={:?}, gradients={:?})",
            self.inner.len(),
            p.a,
            p.strata,
            p.gradients.name()
        )
    }

    /// Grows the cache for the view (pass 1 of the survey's §3.2.2): every pixel whose first
    /// hit reflects diffusely gets a usable record, made coarse to fine where none is.
    /// `envmap` lights the records (with the scene's area lights). Deterministic for any
    /// `threads`; `time_budget` (seconds) and a falsy `callback(done, total)` stop between
    /// waves, keeping the records so far. Returns a dict: records, inserted, discarded,
    /// pixels, points, hemisphere_rays, secondary_rays, rays, clamped_radii, seconds,
    /// complete.
    #[pyo3(signature = (camera=None, seed=0, threads=None, *, envmap, gbuffer=None, time_budget=None, callback=None))]
    #[allow(clippy::too_many_arguments)]
    fn build<'py>(
        &self,
        py: Python<'py>,
        camera: Option<PyRef<'py, PyCamera>>,
        #[pyo3(from_py_with = seed_or_zero)] seed: u64,
        threads: Option<&Bound<'py, PyAny>>,
        envmap: PyRef<'py, PyEnvMap>,
        gbuffer: Option<PyRef<'py, PyGBuffer>>,
        time_budget: Option<&Bound<'py, PyAny>>,
        callback: Option<Py<PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let view = view_arg(camera, gbuffer)?;
        let threads = threads_arg(threads)?;
        let budget = match time_budget {
            Some(b) if !b.is_none() => Some(f64_arg(b, "time_budget")?),
            _ => None,
        };
        crate::error::check_time_budget(budget).py()?;
        let scene = self.scene.borrow(py).get();
        let env = envmap.inner.at_least(2).py()?.into_owned();
        let inner = self.inner.clone();
        let mut reporter = PyProgress::new(callback);
        let stop = reporter.stop_flag();
        let mut callback = |done: usize, total: usize| reporter.report(done as u64, total as u64);
        let out = detach_interruptible(py, &stop, || {
            let start = Instant::now();
            let lighting = lighting(&scene, &env);
            let traced;
            let g = match &view {
                View::GBuffer(g) => g,
                View::Camera(cam) => {
                    traced =
                        with_threads(threads, || GBuffer::render(&scene, cam, 0, false, None))??;
                    &traced
                }
            };
            inner.build_from(&lighting, g, seed, threads, start, budget, &mut callback)
        });
        reporter.finish()?;
        let r = out?.py()?;
        let d = PyDict::new(py);
        d.set_item("records", r.records)?;
        d.set_item("inserted", r.inserted)?;
        d.set_item("discarded", r.discarded)?;
        d.set_item("pixels", r.pixels)?;
        d.set_item("points", r.points)?;
        d.set_item("hemisphere_rays", r.hemisphere_rays)?;
        d.set_item("secondary_rays", r.secondary_rays)?;
        d.set_item("rays", r.hemisphere_rays + r.secondary_rays)?;
        d.set_item("clamped_radii", r.clamped_radii)?;
        d.set_item("seconds", r.seconds)?;
        d.set_item("complete", r.complete)?;
        Ok(d)
    }

    /// Traces a record at `point` (normal `normal`, need not be unit) lit by `envmap` and
    /// inserts it whatever the records near it; `footprint` (world units) sets its radius
    /// bounds (None: the last build's median footprint). Returns its id.
    #[pyo3(signature = (point, normal, *, envmap, footprint=None, seed=0))]
    fn insert(
        &self,
        py: Python<'_>,
        point: &Bound<'_, PyAny>,
        normal: &Bound<'_, PyAny>,
        envmap: PyRef<'_, PyEnvMap>,
        footprint: Option<&Bound<'_, PyAny>>,
        #[pyo3(from_py_with = seed_or_zero)] seed: u64,
    ) -> PyResult<u32> {
        let p = vec3_arg(point, "point")?;
        let n = vec3_arg(normal, "normal")?;
        let footprint = match footprint {
            Some(f) if !f.is_none() => Some(f64_arg(f, "footprint")? as f32),
            _ => None,
        };
        let scene = self.scene.borrow(py).get();
        let env = envmap.inner.at_least(2).py()?.into_owned();
        let inner = self.inner.clone();
        py.detach(|| inner.insert(&lighting(&scene, &env), p.into(), n.into(), footprint, seed))
            .py()
    }

    /// Eq. 3.8 at `points` (N, 3) with `normals` (N, 3; need not be unit). Returns a dict:
    /// `irradiance` (N, 3) float32 (NaN where no record is usable), `weight_sum` (N,)
    /// float64 (0 there; inf at a record's own point), `records` (N,) int32 (records used),
    /// `ids` (N, K) int64 of the records used (-1 pads), `clamped` (N,) int32 (channels
    /// clamped at 0).
    #[pyo3(signature = (points, normals, threads=None))]
    fn lookup<'py>(
        &self,
        py: Python<'py>,
        points: &Bound<'py, PyAny>,
        normals: &Bound<'py, PyAny>,
        threads: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let (pts, nrm) = points_and_normals(points, normals)?;
        let threads = threads_arg(threads)?;
        let inner = self.inner.clone();
        let found = py
            .detach(|| inner.interpolate_batch(&pts, &nrm, threads))
            .py()?;
        let n = pts.len();
        let k = found
            .iter()
            .map(|f| f.as_ref().map_or(0, |(_, ids)| ids.len()))
            .max()
            .unwrap_or(0);
        let mut irradiance = vec![f32::NAN; n * 3];
        let mut weight = vec![0f64; n];
        let mut records = vec![0i32; n];
        let mut clamped = vec![0i32; n];
        let mut ids = vec![-1i64; n * k];
        for (i, f) in found.iter().enumerate() {
            if let Some((e, used)) = f {
                irradiance[3 * i..3 * i + 3].copy_from_slice(&e.irradiance);
                weight[i] = e.weight_sum;
                records[i] = e.records as i32;
                clamped[i] = e.clamped as i32;
                for (j, id) in used.iter().enumerate() {
                    ids[i * k + j] = *id as i64;
                }
            }
        }
        let d = PyDict::new(py);
        d.set_item(
            "irradiance",
            PyArray1::from_vec(py, irradiance).reshape([n, 3])?,
        )?;
        d.set_item("weight_sum", PyArray1::from_vec(py, weight))?;
        d.set_item("records", PyArray1::from_vec(py, records))?;
        d.set_item("ids", PyArray1::from_vec(py, ids).reshape([n, k])?)?;
        d.set_item("clamped", PyArray1::from_vec(py, clamped))?;
        Ok(d)
    }

    /// The records as arrays: `position`, `normal`, `irradiance` (N, 3) float32, `radius`
    /// (N,) float32, `rotation` and `translation` (N, 3, 3) float32 (channel, then xyz).
    fn records<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let state = self.inner.read();
        let r = state.records();
        let n = r.len();
        let rows =
            |f: &dyn Fn(&crate::estimators::irradiance::record::IrradianceRecord) -> [f32; 3]| {
                PyArray1::from_vec(py, r.iter().flat_map(f).collect::<Vec<f32>>()).reshape([n, 3])
            };
        let grads = |f: &dyn Fn(
            &crate::estimators::irradiance::record::IrradianceRecord,
        ) -> [glam::Vec3; 3]| {
            let v: Vec<f32> = r
                .iter()
                .flat_map(|rec| f(rec).into_iter().flat_map(|g| g.to_array()))
                .collect();
            PyArray1::from_vec(py, v).reshape([n, 3, 3])
        };
        let d = PyDict::new(py);
        d.set_item("position", rows(&|r| r.position.to_array())?)?;
        d.set_item("normal", rows(&|r| r.normal.to_array())?)?;
        d.set_item("irradiance", rows(&|r| r.irradiance)?)?;
        d.set_item(
            "radius",
            PyArray1::from_vec(py, r.iter().map(|r| r.radius).collect::<Vec<f32>>()),
        )?;
        d.set_item("rotation", grads(&|r| r.rotation)?)?;
        d.set_item("translation", grads(&|r| r.translation)?)?;
        Ok(d)
    }

    /// Totals since creation: records_inserted, records_discarded, hemisphere_rays,
    /// secondary_rays, clamped_radii.
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let c = self.inner.counters();
        let d = PyDict::new(py);
        d.set_item("records_inserted", c.records_inserted)?;
        d.set_item("records_discarded", c.records_discarded)?;
        d.set_item("hemisphere_rays", c.hemisphere_rays)?;
        d.set_item("secondary_rays", c.secondary_rays)?;
        d.set_item("clamped_radii", c.clamped_radii)?;
        Ok(d)
    }

    /// Writes the cache to `path` (with the scene's geometry fingerprint).
    fn save(&self, py: Python<'_>, path: PathBuf) -> PyResult<()> {
        let inner = self.inner.clone();
        py.detach(|| inner.save(&path)).py()
    }

    /// Reads a cache written by `save` for `scene`; a truncated or corrupted file, or a
    /// cache of another scene, raises ValueError naming it.
    #[classmethod]
    fn load<'py>(
        cls: &Bound<'py, PyType>,
        path: PathBuf,
        scene: Py<PyScene>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let py = cls.py();
        let core_scene = scene.borrow(py).get();
        let cache = py
            .detach(|| IrradianceCache::load_for(&path, &core_scene))
            .py()?;
        let obj = cls.call1((scene,))?;
        obj.cast::<Self>()?.borrow_mut().inner = Arc::new(cache);
        Ok(obj)
    }
}
