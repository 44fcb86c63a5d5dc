//! `viscache_rs._core.VPLs`: virtual point lights ([`crate::lights::vpl`]). The
//! many-light methods "vpl" and "vpl_sampled" render through `_core.render` and the
//! registry ([`crate::render::many_lights`]).

use pyo3::exceptions::PyTypeError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::camera::PyCamera;
use super::convert::{
    f32_vector, f64_arg, f64_vector, finite_rows, int_arg, or_default, rows3_array, rows_array,
    seed_or_zero, threads_arg, IntoPyResult,
};
use super::envmap::PyEnvMap;
use super::interrupt::{detach_interruptible, PyProgress};
use super::scene::PyScene;
use crate::estimators::many_lights::light_paths::kind_index;
use crate::lights::vpl::{
    Importance, TraceParams, VplKind, VplSet, MAX_AREA_POINTS, MAX_DEPTH, MAX_VPLS,
};

/// A set of virtual point lights: `VPLs.trace(setup, count, ...)` traces them from the
/// setup's map and area lights, `VPLs.from_lights(scene, positions, normals, flux)` makes
/// cosine point lights. Read-only.
#[pyclass(name = "VPLs", module = "viscache_rs._core", frozen)]
pub struct PyVpls {
    pub inner: VplSet,
}

/// `setup.<name>` as a `T`, with a `TypeError` naming it.
fn attribute<'py, T: pyo3::PyClass>(
    setup: &Bound<'py, PyAny>,
    name: &str,
) -> PyResult<Bound<'py, T>> {
    setup
        .getattr(name)
        .map_err(|_| PyTypeError::new_err(format!("setup: expected an object with .{name}")))?
        .cast_into::<T>()
        .map_err(|_| {
            PyTypeError::new_err(format!(
                "setup: .{name} is not a {}",
                std::any::type_name::<T>()
                    .rsplit("::")
                    .next()
                    .unwrap_or(name)
            ))
        })
}

/// `objects` (N,): object ids, integers in `[0, 2^32)`.
fn object_ids(obj: &Bound<'_, PyAny>) -> PyResult<Vec<u32>> {
    let v = f64_vector(obj, "objects")?;
    v.iter()
        .map(|&x| {
            if x.fract() == 0.0 && (0.0..=u32::MAX as f64).contains(&x) {
                Ok(x as u32)
            } else {
                Err(pyo3::exceptions::PyValueError::new_err(format!(
                    "objects: expected object ids (integers >= 0), got {x}"
                )))
            }
        })
        .collect()
}

/// Extractor of `depth=1`.
fn depth_arg(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    or_default(obj, 1, |o| {
        Ok(int_arg(o, "depth", 1, MAX_DEPTH as i128)? as u32)
    })
}

/// Extractor of `epsilon=0.05`.
fn epsilon_arg(obj: &Bound<'_, PyAny>) -> PyResult<f32> {
    or_default(obj, 0.05, |o| Ok(f64_arg(o, "epsilon")? as f32))
}

/// Extractor of `pilot_paths=4000`.
fn pilot_arg(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    or_default(obj, 4000, |o| {
        Ok(int_arg(o, "pilot_paths", 1, 1 << 24)? as u32)
    })
}

/// Extractor of `level=4` (an octahedral level; the map's own range is checked later).
fn level_arg(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    Ok(int_arg(obj, "level", 0, 64)? as u32)
}

/// Extractor of `points=16`.
fn points_arg(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    Ok(int_arg(obj, "points", 1, MAX_AREA_POINTS as i128)? as u32)
}

/// Extractor of `width=64`.
fn width_arg(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    Ok(int_arg(obj, "width", 1, 1024)? as u32)
}

#[pymethods]
impl PyVpls {
    /// Traces about `count` VPLs from `setup`'s map (or `envmap`) and area lights by light
    /// tracing with `depth` generations of surface VPLs; with `importance`, accepted by
    /// their contribution to the view of `setup`'s camera (or `camera`) (survey Algorithm
    /// 11, `epsilon`, `pilot_paths`). Without `lights` the set has no light VPLs (direct
    /// light) and `count` counts surface VPLs. Bit-identical for any `threads` at a fixed
    /// `seed`.
    #[staticmethod]
    #[pyo3(signature = (setup, count, seed=0, importance=true, depth=1, epsilon=0.05, pilot_paths=4000, lights=true, camera=None, envmap=None, threads=None))]
    #[allow(clippy::too_many_arguments)]
    fn trace(
        py: Python<'_>,
        setup: &Bound<'_, PyAny>,
        count: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = seed_or_zero)] seed: u64,
        importance: bool,
        #[pyo3(from_py_with = depth_arg)] depth: u32,
        #[pyo3(from_py_with = epsilon_arg)] epsilon: f32,
        #[pyo3(from_py_with = pilot_arg)] pilot_paths: u32,
        lights: bool,
        camera: Option<Bound<'_, PyCamera>>,
        envmap: Option<Bound<'_, PyEnvMap>>,
        threads: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let count = int_arg(count, "count", 1, MAX_VPLS as i128)? as u64;
        let threads = threads_arg(threads)?;
        let scene = attribute::<PyScene>(setup, "scene")?.borrow().get();
        let camera = match camera {
            Some(c) => c,
            None => attribute::<PyCamera>(setup, "camera")?,
        }
        .borrow()
        .inner;
        let env: Py<PyEnvMap> = match envmap {
            Some(e) => e,
            None => attribute::<PyEnvMap>(setup, "envmap")?,
        }
        .unbind();
        let params = TraceParams {
            count,
            depth,
            seed,
            importance: importance.then_some(Importance {
                epsilon,
                pilot_paths,
                ..Importance::DEFAULT
            }),
            lights,
        };
        params.validate().py()?;
        let stop = PyProgress::new(None).stop_flag();
        let set = detach_interruptible(py, &stop, || {
            VplSet::trace(&scene, &env.get().inner, Some(&camera), &params, threads)
        })?
        .py()?;
        Ok(Self { inner: set })
    }

    /// Cosine point lights (light VPLs, direct light) at `positions` (N, 3) facing
    /// `normals` (N, 3, normalised here) with `flux` (N, 3; W, finite and >= 0), for
    /// `scene`.
    #[staticmethod]
    fn from_lights(
        scene: PyRef<'_, PyScene>,
        positions: &Bound<'_, PyAny>,
        normals: &Bound<'_, PyAny>,
        flux: &Bound<'_, PyAny>,
    ) -> PyResult<Self> {
        let p = finite_rows::<3>(positions, "positions")?;
        let n = finite_rows::<3>(normals, "normals")?;
        let f = finite_rows::<3>(flux, "flux")?;
        let set = VplSet::from_lights(&scene.get(), &p, &n, &f).py()?;
        Ok(Self { inner: set })
    }

    /// First-bounce surface VPLs (VF's proxies, `bounce` 1): at `positions` (N, 3) facing
    /// `normals` (N, 3, normalised here), with direct irradiance `irradiance` (N, 3; W/m²,
    /// finite and >= 0) over `areas` (N,; world units², > 0) and the material of object
    /// `objects` (N,) of `scene`: flux `irradiance * area`, reflected by that material as
    /// light that arrived along the normal.
    #[staticmethod]
    fn from_surface(
        scene: PyRef<'_, PyScene>,
        positions: &Bound<'_, PyAny>,
        normals: &Bound<'_, PyAny>,
        irradiance: &Bound<'_, PyAny>,
        areas: &Bound<'_, PyAny>,
        objects: &Bound<'_, PyAny>,
    ) -> PyResult<Self> {
        let p = finite_rows::<3>(positions, "positions")?;
        let n = finite_rows::<3>(normals, "normals")?;
        let e = finite_rows::<3>(irradiance, "irradiance")?;
        let a = f32_vector(areas, "areas")?;
        let o = object_ids(objects)?;
        let set =
            crate::estimators::vf::proxies::surface_vpls(&scene.get(), &p, &n, &e, &a, &o, false)
                .py()?;
        Ok(Self { inner: set })
    }

    /// Directional lights from an environment map, one per texel of its octahedral
    /// `level` (`2**level` texels a side, `0..=log2(resolution)`), each the texel's
    /// `sum(radiance * solid angle)` as irradiance from the luminance-weighted mean of its
    /// directions. `env_or_setup` is a setup (its `.envmap` and `.scene`) or an `EnvMap`,
    /// which needs `scene`.
    #[staticmethod]
    #[pyo3(signature = (env_or_setup, level=4, scene=None))]
    fn from_envmap(
        py: Python<'_>,
        env_or_setup: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = level_arg)] level: u32,
        scene: Option<Bound<'_, PyScene>>,
    ) -> PyResult<Self> {
        let (env, scene) = match env_or_setup.cast::<PyEnvMap>() {
            Ok(env) => {
                let Some(scene) = scene else {
                    return Err(PyTypeError::new_err(
                        "scene: an EnvMap needs the scene the lights are for (or pass a setup)",
                    ));
                };
                (env.clone().unbind(), scene.borrow().get())
            }
            Err(_) => {
                let env = attribute::<PyEnvMap>(env_or_setup, "envmap").map_err(|_| {
                    PyTypeError::new_err(
                        "env_or_setup: expected an EnvMap or a setup with .envmap and .scene",
                    )
                })?;
                let scene = match scene {
                    Some(s) => s.borrow().get(),
                    None => attribute::<PyScene>(env_or_setup, "scene")?.borrow().get(),
                };
                (env.unbind(), scene)
            }
        };
        let set = py
            .detach(|| VplSet::from_envmap(&scene, &env.get().inner, level))
            .py()?;
        Ok(Self { inner: set })
    }

    /// Directional lights (a sun) for `scene`: light from `directions` (N, 3; towards the
    /// light, normalised here) of `irradiance` (N, 3; W/m² on a surface facing it, finite
    /// and >= 0).
    #[staticmethod]
    fn from_directions(
        scene: PyRef<'_, PyScene>,
        directions: &Bound<'_, PyAny>,
        irradiance: &Bound<'_, PyAny>,
    ) -> PyResult<Self> {
        let d = finite_rows::<3>(directions, "directions")?;
        let e = finite_rows::<3>(irradiance, "irradiance")?;
        let set = VplSet::from_directions(&scene.get(), &d, &e).py()?;
        Ok(Self { inner: set })
    }

    /// `scene`'s area lights as one light each: its term without visibility (what
    /// `"vpl_sampled"` draws by) from `points` fixed stratified points on it; its shadow
    /// rays go to a fresh point by area per gather, so renders stay unbiased for the true
    /// area light.
    #[staticmethod]
    #[pyo3(signature = (scene, points=16))]
    fn from_area_lights(
        scene: PyRef<'_, PyScene>,
        #[pyo3(from_py_with = points_arg)] points: u32,
    ) -> PyResult<Self> {
        let k = points;
        let set = VplSet::from_area_lights(&scene.get(), k).py()?;
        Ok(Self { inner: set })
    }

    /// The share of the lights that reach the view of `setup`'s camera (or `camera`): a
    /// positive, unoccluded term at one pixel centre at least of a G-buffer `width` pixels
    /// wide. Returns `{"share", "contributing", "total", "points", "by_kind"}`, the last
    /// `{kind: (contributing, total)}` for the kinds the set holds (codes of `.kinds`).
    #[pyo3(signature = (setup, camera=None, width=64, threads=None))]
    fn view_share<'py>(
        &self,
        py: Python<'py>,
        setup: &Bound<'py, PyAny>,
        camera: Option<Bound<'py, PyCamera>>,
        #[pyo3(from_py_with = width_arg)] width: u32,
        threads: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let threads = threads_arg(threads)?;
        let scene = attribute::<PyScene>(setup, "scene")?.borrow().get();
        let camera = match camera {
            Some(c) => c,
            None => attribute::<PyCamera>(setup, "camera")?,
        }
        .borrow()
        .inner;
        let stop = PyProgress::new(None).stop_flag();
        let share = detach_interruptible(py, &stop, || {
            self.inner.view_share(&scene, &camera, width, threads)
        })?
        .py()?;
        let d = PyDict::new(py);
        d.set_item("share", share.fraction())?;
        d.set_item("contributing", share.contributing)?;
        d.set_item("total", share.total)?;
        d.set_item("points", share.points)?;
        let kinds = PyDict::new(py);
        for (k, &(c, t)) in share.by_kind.iter().enumerate() {
            if t > 0 {
                kinds.set_item(k, (c, t))?;
            }
        }
        d.set_item("by_kind", kinds)?;
        Ok(d)
    }

    /// The union `self + other` (same scene; directional fluxes rescaled to one disk,
    /// stats combined).
    fn __add__(&self, other: &Bound<'_, PyAny>) -> PyResult<Self> {
        let other = other.cast::<PyVpls>().map_err(|_| {
            PyTypeError::new_err(format!(
                "other: expected VPLs, got {}",
                other
                    .get_type()
                    .name()
                    .map_or("?".into(), |n| n.to_string())
            ))
        })?;
        let set = self.inner.concat(&other.get().inner).py()?;
        Ok(Self { inner: set })
    }

    fn __len__(&self) -> usize {
        self.inner.len()
    }

    fn __repr__(&self) -> String {
        format!(
            "VPLs({} lights from {} paths)",
            self.inner.len(),
            self.inner.stats.paths
        )
    }

    /// Positions (N, 3) float32 (zero for map directions).
    #[getter]
    fn positions<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rows3_array(
            py,
            self.inner
                .vpls
                .iter()
                .map(|v| v.position.to_array())
                .collect(),
        )
    }

    /// Unit normals (N, 3) float32 on the side the light leaves; for map directions the
    /// direction towards the map.
    #[getter]
    fn normals<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rows3_array(
            py,
            self.inner
                .vpls
                .iter()
                .map(|v| v.normal.to_array())
                .collect(),
        )
    }

    /// Flux (N, 3) float32, W per channel (the paths' normalisation included).
    #[getter]
    fn flux<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rows3_array(
            py,
            self.inner.vpls.iter().map(|v| v.flux.to_array()).collect(),
        )
    }

    /// Unit directions (N, 3) float32 the light arrived from (surface VPLs; zero else).
    #[getter]
    fn incident<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        rows3_array(
            py,
            self.inner
                .vpls
                .iter()
                .map(|v| v.incident.to_array())
                .collect(),
        )
    }

    /// The fixed points of each area light (N,) int32 (0 for other kinds).
    #[getter]
    fn area_points<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let rows: Vec<[i32; 1]> = self
            .inner
            .vpls
            .iter()
            .map(|v| match v.kind {
                VplKind::Area { points } => [points as i32],
                _ => [0],
            })
            .collect();
        rows_array(py, rows)?.call_method1("reshape", (-1,))
    }

    /// Generation (N,) int32: 0 for light VPLs, j for the j-th hit of a light path.
    #[getter]
    fn bounces<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let rows: Vec<[i32; 1]> = self.inner.vpls.iter().map(|v| [v.bounce as i32]).collect();
        rows_array(py, rows)?.call_method1("reshape", (-1,))
    }

    /// Kind (N,) int8: 0 a point on an area light (or from_lights), 1 a directional light
    /// (a map direction or texel, from_directions), 2 a surface hit, 3 a whole area light.
    #[getter]
    fn kinds<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let rows: Vec<[i8; 1]> = self
            .inner
            .vpls
            .iter()
            .map(|v| [kind_index(v.kind) as i8])
            .collect();
        rows_array(py, rows)?.call_method1("reshape", (-1,))
    }

    /// `π R²` of the map's disk (world units²): a map VPL's irradiance is flux / disk_area.
    #[getter]
    fn disk_area(&self) -> f32 {
        self.inner.disk_area
    }

    /// Figures of the trace: paths, pilot_paths, path_rays, shadow_rays, rejected,
    /// mean_contribution, seconds.
    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let s = &self.inner.stats;
        let d = PyDict::new(py);
        d.set_item("vpls", self.inner.len())?;
        d.set_item("paths", s.paths)?;
        d.set_item("pilot_paths", s.pilot_paths)?;
        d.set_item("path_rays", s.path_rays)?;
        d.set_item("shadow_rays", s.shadow_rays)?;
        d.set_item("rejected", s.rejected)?;
        d.set_item("mean_contribution", s.mean_contribution)?;
        d.set_item("seconds", s.seconds)?;
        Ok(d)
    }
}
