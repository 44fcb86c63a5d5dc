//! Method "vf"'s keyword arguments ([`crate::estimators::vf::VfParams`]) for
//! `_core.render`: each checked here with an error naming it, then the whole set by
//! [`VfParams::validate`] against the camera; and `ProxyGrid`, VF's view-independent half
//! ([`crate::estimators::vf::proxy_grid::ProxyGrid`]) built once and given to renders of
//! any view as `proxies=`.

use std::sync::Arc;

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::convert::{f64_arg, int_arg, seed_or_zero, threads_arg, IntoPyResult};
use super::envmap::PyEnvMap;
use super::interrupt::{detach_interruptible, PyProgress};
use super::scene::PyScene;
use crate::estimators::direct::Lighting;
use crate::estimators::vf::proxy_grid::ProxyGrid;
use crate::estimators::vf::{
    VfParams, MAX_FILTER, MAX_PROXIES, MAX_RAYS_PER_PIXEL, MAX_VOXELS_PER_AXIS,
};
use crate::parallel::with_threads;
use crate::render::RenderParams;

/// VF's proxies, their VPLs (lit by `envmap` and the scene's area lights) and voxel grids
/// (eq. 1-3): built once, rendered from any view with `render(method="vf", proxies=grid)`.
#[pyclass(name = "ProxyGrid", module = "viscache_rs._core", subclass, frozen)]
pub struct PyProxyGrid {
    pub(crate) inner: Arc<ProxyGrid>,
    /// The scene the grid was built in.
    #[pyo3(get)]
    scene: Py<PyScene>,
    /// The map that lit the proxies: a render under another map is refused.
    #[pyo3(get)]
    envmap: Py<PyEnvMap>,
    /// The seed of the proxies' placement and lighting.
    #[pyo3(get)]
    seed: u64,
}

#[pymethods]
impl PyProxyGrid {
    /// `ProxyGrid(scene, envmap, proxies=24000, voxels=(6, 6, 6), seed=0, threads=None,
    /// table_slots=None)`: about `proxies` proxies placed by area in `scene` and lit by
    /// `envmap` with stream `seed`, in a `voxels` grid (an int: the same on every axis) over
    /// the scene's bounds; `table_slots`: slots of the hashed table (None: dense when it
    /// fits). The same seed gives the grid a render with that seed builds for itself, bit
    /// for bit, on any `threads`.
    #[new]
    #[pyo3(signature = (scene, envmap, proxies=None, voxels=None, seed=0, threads=None, table_slots=None))]
    #[allow(clippy::too_many_arguments)]
    fn new(
        py: Python<'_>,
        scene: Py<PyScene>,
        envmap: Py<PyEnvMap>,
        proxies: Option<&Bound<'_, PyAny>>,
        voxels: Option<&Bound<'_, PyAny>>,
        #[pyo3(from_py_with = seed_or_zero)] seed: u64,
        threads: Option<&Bound<'_, PyAny>>,
        table_slots: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let mut p = VfParams::DEFAULT;
        if let Some(o) = set(proxies) {
            p.proxies = int_arg(o, "proxies", 1, MAX_PROXIES as i128)? as u32;
        }
        if let Some(o) = set(voxels) {
            p.voxels = sizes::<3>(o, "voxels", MAX_VOXELS_PER_AXIS)?;
        }
        if let Some(o) = set(table_slots) {
            p.table_slots = Some(int_arg(o, "table_slots", 1, u32::MAX as i128)? as u32);
        }
        let threads = threads_arg(threads)?;
        let s = scene.borrow(py).get();
        s.check_bvh_memory().py()?;
        let env = envmap.get().inner.at_least(2).py()?.into_owned();
        let reporter = PyProgress::new(None);
        let stop = reporter.stop_flag();
        let grid = detach_interruptible(py, &stop, || {
            with_threads(threads, || {
                let _ = s.bvh();
                let lighting = Lighting {
                    scene: &s,
                    env: &env,
                    product_level: RenderParams::DEFAULT.product_level,
                };
                ProxyGrid::build(&lighting, p.proxies, p.voxels, p.table_slots, seed, None)
            })
        })?
        .py()?
        .py()?;
        reporter.finish()?;
        Ok(Self {
            inner: Arc::new(grid),
            scene,
            envmap,
            seed,
        })
    }

    /// Proxies placed.
    fn __len__(&self) -> usize {
        self.inner.proxies.len()
    }

    /// Voxels per axis.
    #[getter]
    fn voxels(&self) -> (u32, u32, u32) {
        let d = self.inner.frame().dims;
        (d[0], d[1], d[2])
    }

    /// Figures of the build: proxies, vpls, occupied_voxels (holding a disc),
    /// nonempty_voxels (holding a VPL), hashed, proxy_seconds, voxelisation_seconds, and
    /// the VPLs' total flux (W per channel).
    #[getter]
    fn stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let g = &self.inner;
        let d = PyDict::new(py);
        d.set_item("proxies", g.proxies.len())?;
        d.set_item("vpls", g.vpls.len())?;
        d.set_item("occupied_voxels", g.occupied_voxels())?;
        d.set_item("nonempty_voxels", g.lit_voxels())?;
        d.set_item("hashed", g.disc_index.is_hashed())?;
        d.set_item("proxy_seconds", g.proxy_seconds)?;
        d.set_item("voxelisation_seconds", g.voxel_seconds)?;
        d.set_item("flux", g.flux().to_array())?;
        Ok(d)
    }

    fn __repr__(&self) -> String {
        let d = self.inner.frame().dims;
        format!(
            "ProxyGrid(proxies={}, voxels=({}, {}, {}), seed={})",
            self.inner.proxies.len(),
            d[0],
            d[1],
            d[2],
            self.seed
        )
    }
}

/// `proxies` as a [`PyProxyGrid`]'s grid, checked against the render's `envmap` (the map
/// that lit it); `None` when `proxies` is not a grid.
pub fn grid_arg(
    proxies: Option<&Bound<'_, PyAny>>,
    envmap: &Bound<'_, PyEnvMap>,
) -> PyResult<Option<Arc<ProxyGrid>>> {
    let Some(o) = set(proxies) else {
        return Ok(None);
    };
    let Ok(g) = o.cast::<PyProxyGrid>() else {
        return Ok(None);
    };
    let g = g.get();
    if !g.envmap.bind(o.py()).is(envmap) {
        return Err(PyValueError::new_err(
            "proxies: the ProxyGrid's proxies were lit by another envmap; build one for \
             this map",
        ));
    }
    Ok(Some(g.inner.clone()))
}

/// `n` integers in `[1, max]` from an integer (repeated) or a sequence of `n`.
fn sizes<const N: usize>(obj: &Bound<'_, PyAny>, name: &str, max: u32) -> PyResult<[u32; N]> {
    let scalar = int_arg(obj, name, 1, max as i128);
    let items: Vec<Bound<'_, PyAny>> = match (scalar, obj.try_iter()) {
        (Ok(v), _) => return Ok([v as u32; N]),
        (Err(_), Ok(it)) if !obj.is_instance_of::<pyo3::types::PyString>() => {
            it.collect::<PyResult<_>>()?
        }
        // A scalar that is not an integer in range: its own error.
        (Err(e), _) => return Err(e),
    };
    if items.len() != N {
        return Err(PyValueError::new_err(format!(
            "{name}: expected an integer or {N} integers, got {} values",
            items.len()
        )));
    }
    let mut out = [0u32; N];
    for (o, item) in out.iter_mut().zip(&items) {
        *o = int_arg(item, name, 1, max as i128)? as u32;
    }
    Ok(out)
}

/// A number in `[0, 1]`.
fn tolerance(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<f32> {
    let v = f64_arg(obj, name)?;
    if !(0.0..=1.0).contains(&v) {
        return Err(PyValueError::new_err(format!(
            "{name}: must lie in [0, 1], got {v}"
        )));
    }
    Ok(v as f32)
}

fn set<'a, 'py>(o: Option<&'a Bound<'py, PyAny>>) -> Option<&'a Bound<'py, PyAny>> {
    o.filter(|o| !o.is_none())
}

/// Method "vf"'s parameters from the keyword arguments (`None`s keep
/// [`VfParams::DEFAULT`]'s); `None` when none is set.
#[allow(clippy::too_many_arguments)]
pub fn params_arg(
    proxies: Option<&Bound<'_, PyAny>>,
    voxels: Option<&Bound<'_, PyAny>>,
    marching: Option<&Bound<'_, PyAny>>,
    indirect: Option<&Bound<'_, PyAny>>,
    rays_per_pixel: Option<&Bound<'_, PyAny>>,
    filter: Option<&Bound<'_, PyAny>>,
    depth_tol: Option<&Bound<'_, PyAny>>,
    normal_tol: Option<&Bound<'_, PyAny>>,
    sh_range: Option<&Bound<'_, PyAny>>,
) -> PyResult<Option<VfParams>> {
    let all = [
        proxies,
        voxels,
        marching,
        indirect,
        rays_per_pixel,
        filter,
        depth_tol,
        normal_tol,
        sh_range,
    ];
    if all.iter().all(|o| set(*o).is_none()) {
        return Ok(None);
    }
    let mut p = VfParams::DEFAULT;
    let grid = set(proxies).is_some_and(|o| o.is_instance_of::<PyProxyGrid>());
    if grid && set(voxels).is_some() {
        return Err(PyValueError::new_err(
            "voxels: fixed by the ProxyGrid given as proxies; leave it None",
        ));
    }
    if let Some(o) = set(proxies).filter(|_| !grid) {
        p.proxies = int_arg(o, "proxies", 1, MAX_PROXIES as i128)? as u32;
    }
    if let Some(o) = set(voxels) {
        p.voxels = sizes::<3>(o, "voxels", MAX_VOXELS_PER_AXIS)?;
    }
    if let Some(o) = set(marching) {
        p.marching = Some(sizes::<2>(o, "marching", u32::MAX)?);
    }
    if let Some(o) = set(indirect) {
        p.indirect = Some(sizes::<2>(o, "indirect", u32::MAX)?);
    }
    if let Some(o) = set(rays_per_pixel) {
        p.rays_per_pixel = int_arg(o, "rays_per_pixel", 1, MAX_RAYS_PER_PIXEL as i128)? as u32;
    }
    if let Some(o) = set(filter) {
        let f = int_arg(o, "filter", 1, MAX_FILTER as i128)? as u32;
        if f.is_multiple_of(2) {
            return Err(PyValueError::new_err(format!(
                "filter: must be an odd window side (2m + 1), got {f}"
            )));
        }
        p.filter = f;
    }
    if let Some(o) = set(depth_tol) {
        p.depth_tol = tolerance(o, "depth_tol")?;
    }
    if let Some(o) = set(normal_tol) {
        p.normal_tol = tolerance(o, "normal_tol")?;
    }
    if let Some(o) = set(sh_range) {
        let r = f64_arg(o, "sh_range")?;
        if r.is_nan() || r < 0.0 {
            return Err(PyValueError::new_err(format!(
                "sh_range: must be >= 0 (world units; inf: VPLs only), got {r}"
            )));
        }
        p.sh_range = Some(r as f32);
    }
    Ok(Some(p))
}
