//! `vc.Scene`: geometry input, ray queries, counters and the G-buffer.

use super::interrupt::{detach_abandonable, detach_stoppable};
use std::path::PathBuf;
use std::sync::{Arc, RwLock};

use numpy::{PyArray1, PyArrayMethods};
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::camera::PyCamera;
use super::convert::{
    f32_vector, f64_arg, finite_rows, image3_f32, int_arg, rows3_array, rows3_f32, rows3_i64,
    seed_or_zero, threads_arg, vec3_arg, IntoPyResult,
};
use super::gbuffer::PyGBuffer;
use super::material::PyMaterial;
use crate::bsdf::Material;
use crate::camera::GBuffer;
use crate::geometry::{BuildQuality, Mesh, RayBatch, Scene, TMax};
use crate::lights::area::EmissionTexture;

/// Triangles grouped into objects, with a BVH built on first query.
///
/// Mutating methods copy the geometry first when it is shared (for example with a cache
/// built over it, or a render still running in another thread), so objects and calls that
/// hold the scene keep seeing the geometry they were given. Safe to share across threads:
/// calls that run without the GIL work on the scene as it was when they started, and an
/// edit waits only for another edit.
#[pyclass(name = "Scene", module = "viscache_rs._core")]
pub struct PyScene {
    inner: RwLock<Arc<Scene>>,
}

/// The upper ends of the ray segments: None (unbounded), a number, or one per ray.
enum TMaxArg {
    Scalar(f32),
    PerRay(Vec<f32>),
}

fn tmax_arg(obj: Option<&Bound<'_, PyAny>>, n: usize) -> PyResult<TMaxArg> {
    let Some(obj) = obj.filter(|o| !o.is_none()) else {
        return Ok(TMaxArg::Scalar(f32::INFINITY));
    };
    let np = obj.py().import("numpy")?;
    let ndim: usize = np.call_method1("ndim", (obj,))?.extract()?;
    if ndim == 0 {
        return Ok(TMaxArg::Scalar(f64_arg(obj, "tmax")? as f32));
    }
    let arr = np
        .call_method1("asarray", (obj,))
        .map_err(|e| PyValueError::new_err(format!("tmax: cannot be read as an array ({e})")))?;
    let kind: String = arr.getattr("dtype")?.getattr("kind")?.extract()?;
    if !matches!(kind.as_str(), "f" | "i" | "u") {
        return Err(PyTypeError::new_err(format!(
            "tmax: expected real numbers, got dtype kind {kind:?}"
        )));
    }
    let shape: Vec<usize> = arr.getattr("shape")?.extract()?;
    if shape != [n] {
        return Err(PyValueError::new_err(format!(
            "tmax: expected a number or shape ({n},), got shape {shape:?}"
        )));
    }
    Ok(TMaxArg::PerRay(f32_vector(&arr, "tmax")?))
}

impl PyScene {
    pub fn new_from(scene: Scene) -> Self {
        Self {
            inner: RwLock::new(Arc::new(scene)),
        }
    }

    /// The scene as it is now. Calls that release the GIL work on this snapshot: edits from
    /// other threads meanwhile copy the scene rather than change it under them.
    pub fn get(&self) -> Arc<Scene> {
        self.inner.read().unwrap_or_else(|e| e.into_inner()).clone()
    }

    /// `obj` as an object id of an emitter of the scene, or an error naming `obj`.
    fn emitting_object(&self, obj: &Bound<'_, PyAny>) -> PyResult<u32> {
        let n = self.get().mesh().objects.len();
        let obj = int_arg(obj, "obj", 0, n as i128 - 1)? as u32;
        if self.get().emitter(obj).is_none() {
            return Err(PyValueError::new_err(format!(
                "obj: object {obj} does not emit (see set_emitter)"
            )));
        }
        Ok(obj)
    }

    /// Runs `f` on the scene, copying it first if a snapshot of it is in use. Edits from
    /// other threads wait for this one.
    pub fn edit<R>(&self, f: impl FnOnce(&mut Scene) -> R) -> R {
        let mut guard = self.inner.write().unwrap_or_else(|e| e.into_inner());
        f(Arc::make_mut(&mut guard))
    }

    fn with_rays<R: Send>(
        &self,
        py: Python<'_>,
        origins: &Bound<'_, PyAny>,
        directions: &Bound<'_, PyAny>,
        tmax: Option<&Bound<'_, PyAny>>,
        f: impl FnOnce(&Scene, &RayBatch) -> crate::Result<R> + Send,
    ) -> PyResult<R> {
        let o = rows3_f32(origins, "origins")?;
        let d = rows3_f32(directions, "directions")?;
        let (o, d) = (o.rows()?, d.rows()?);
        if o.len() != d.len() {
            return Err(PyValueError::new_err(format!(
                "directions: has {} rows but origins has {}",
                d.len(),
                o.len()
            )));
        }
        let t = tmax_arg(tmax, o.len())?;
        let t = match &t {
            TMaxArg::Scalar(v) => TMax::Scalar(*v),
            TMaxArg::PerRay(a) => TMax::PerRay(a),
        };
        let batch = RayBatch {
            origins: o,
            directions: d,
            tmax: t,
        };
        let scene = self.get();
        detach_stoppable(py, || f(&scene, &batch))?.py()
    }
}

#[pymethods]
impl PyScene {
    /// An empty scene.
    #[new]
    fn py_new() -> Self {
        Self::new_from(Scene::new())
    }

    /// Adds an indexed triangle mesh as one object and returns its id.
    ///
    /// vertices: (N, 3) real array; faces: (M, 3) integer array of indices into vertices;
    /// material: a Material (default: light grey Lambert); name: str.
    #[pyo3(signature = (vertices, faces, material=None, name=None))]
    fn add_mesh(
        &self,
        py: Python<'_>,
        vertices: &Bound<'_, PyAny>,
        faces: &Bound<'_, PyAny>,
        material: Option<PyMaterial>,
        name: Option<String>,
    ) -> PyResult<u32> {
        let v = rows3_f32(vertices, "vertices")?;
        let f = rows3_i64(faces, "faces")?;
        let v = v.rows()?;
        let material = material.map_or(Material::DEFAULT, |m| m.inner);
        let name = name.unwrap_or_else(|| format!("object{}", self.get().num_objects()));
        // Validate against a scratch mesh first, so a failure leaves the scene untouched and
        // a shared scene is only copied when the mesh is good.
        let mut part = Mesh::new();
        py.detach(|| part.add_indexed(v, &f, material, Some(name)))
            .py()?;
        Ok(py.detach(|| {
            self.edit(|scene| {
                let first = scene.num_objects() as u32;
                scene.append(&part);
                first
            })
        }))
    }

    /// Adds a one-sided area light: a triangle (3 vertices) or a quad (4, in order around
    /// its border) that emits `radiance` (W/(m² sr), RGB) on the side of the winding normal
    /// `(v1 - v0) x (v2 - v0)`. It is also geometry (black, so it reflects nothing) and
    /// occludes like any other object. Returns its object id.
    #[pyo3(signature = (vertices, radiance, name=None))]
    fn add_area_light(
        &self,
        vertices: &Bound<'_, PyAny>,
        radiance: &Bound<'_, PyAny>,
        name: Option<String>,
    ) -> PyResult<u32> {
        let v = finite_rows::<3>(vertices, "vertices")?;
        let radiance = vec3_arg(radiance, "radiance")?;
        // Validate on a scratch scene first: a failure leaves this one untouched and a
        // shared scene is only copied for a good light.
        Scene::new()
            .add_area_light(&v, radiance, name.clone())
            .py()?;
        self.edit(|s| s.add_area_light(&v, radiance, name)).py()
    }

    /// Makes object `obj` emit `radiance` (W/(m² sr), RGB) on the side of its triangles'
    /// winding normal, keeping its material (a lamp modelled as geometry, or the walls
    /// of a furnace). Fails, leaving the scene unchanged, if it already emits.
    #[pyo3(signature = (obj, radiance))]
    fn set_emitter(&self, obj: &Bound<'_, PyAny>, radiance: &Bound<'_, PyAny>) -> PyResult<()> {
        let n = self.get().mesh().objects.len();
        let obj = int_arg(obj, "obj", 0, n as i128 - 1)? as u32;
        let radiance = vec3_arg(radiance, "radiance")?;
        if self.get().emitter(obj).is_some() {
            return Err(PyValueError::new_err(format!(
                "obj: object {obj} already emits"
            )));
        }
        self.edit(|s| s.set_emitter(obj, radiance)).py()
    }

    /// Gives the emitting object `obj` another `radiance` (W/(m² sr), RGB); its geometry
    /// and sampling stay. Fails, leaving the scene unchanged, if it does not emit.
    #[pyo3(signature = (obj, radiance))]
    fn set_emission(&self, obj: &Bound<'_, PyAny>, radiance: &Bound<'_, PyAny>) -> PyResult<()> {
        let obj = self.emitting_object(obj)?;
        let radiance = vec3_arg(radiance, "radiance")?;
        self.edit(|s| s.set_emission(obj, radiance)).py()
    }

    /// Gives the emitting quad `obj` an RGB `texture` of shape (H, W, 3) over its uv square
    /// (uv (0, 0) at its first vertex, (1, 0) at the second, (0, 1) at the fourth; row 0
    /// at v = 0): it then emits its radiance times the texel. None removes the texture.
    /// Sampling stays by area. Fails, leaving the scene unchanged, if `obj` does not emit
    /// or is not a quad.
    #[pyo3(signature = (obj, texture))]
    fn set_emission_texture(
        &self,
        obj: &Bound<'_, PyAny>,
        texture: &Bound<'_, PyAny>,
    ) -> PyResult<()> {
        let obj = self.emitting_object(obj)?;
        let texture = if texture.is_none() {
            None
        } else {
            let (texels, h, w) = image3_f32(texture, "texture")?;
            Some(EmissionTexture::new(w, h, texels).py()?)
        };
        self.edit(|s| s.set_emission_texture(obj, texture)).py()
    }

    /// Object ids of the area lights, in the order they were added.
    fn area_lights(&self) -> Vec<u32> {
        self.get().area_lights().iter().map(|l| l.object).collect()
    }

    /// The radiance (W/(m² sr), RGB) object `obj` emits on the side of its triangles'
    /// winding normal: an area light's, `(0, 0, 0)` for any other object.
    fn emission(&self, obj: &Bound<'_, PyAny>) -> PyResult<(f32, f32, f32)> {
        let scene = self.get();
        let n = scene.mesh().objects.len();
        let obj = int_arg(obj, "obj", 0, n as i128 - 1)? as u32;
        Ok(scene
            .emitter(obj)
            .map_or((0.0, 0.0, 0.0), |l| l.radiance().into()))
    }

    /// Loads a Wavefront OBJ file (triangulated; one object per OBJ object/group).
    #[staticmethod]
    fn from_obj(py: Python<'_>, path: PathBuf) -> PyResult<Self> {
        let mesh = py.detach(|| crate::geometry::obj::load_obj(&path)).py()?;
        Ok(Self::new_from(Scene::from_mesh(mesh)))
    }

    /// Builds a scene from a `trimesh.Trimesh` or a `trimesh.Scene` (node transforms
    /// applied; one object per node, named after it).
    #[staticmethod]
    fn from_trimesh(py: Python<'_>, mesh: &Bound<'_, PyAny>) -> PyResult<Self> {
        let parts: Vec<Bound<'_, PyAny>> = if mesh.hasattr("graph")? && mesh.hasattr("dump")? {
            mesh.call_method0("dump")?.extract()?
        } else if mesh.hasattr("vertices")? && mesh.hasattr("faces")? {
            vec![mesh.clone()]
        } else {
            return Err(PyTypeError::new_err(
                "mesh: expected a trimesh.Trimesh or trimesh.Scene",
            ));
        };
        let scene = Self::py_new();
        for part in parts {
            if !part.hasattr("faces")? {
                continue; // paths and point clouds carry no triangles
            }
            let meta = part.getattr("metadata").ok();
            let name = meta
                .and_then(|m| m.call_method1("get", ("node",)).ok())
                .and_then(|n| n.extract::<String>().ok());
            scene.add_mesh(
                py,
                &part.getattr("vertices")?,
                &part.getattr("faces")?,
                None,
                name,
            )?;
        }
        Ok(scene)
    }

    /// Number of triangles (degenerate ones included).
    #[getter]
    fn num_triangles(&self) -> usize {
        self.get().num_triangles()
    }

    /// Number of objects.
    #[getter]
    fn num_objects(&self) -> usize {
        self.get().num_objects()
    }

    /// (2, 3) float32 array [min, max]; an empty scene gives [+inf, -inf].
    #[getter]
    fn bounds<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let b = self.get().bounds();
        rows3_array(py, vec![b.min.into(), b.max.into()])
    }

    /// (M, 3, 3) float32 array of triangle vertices.
    fn triangles<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let scene = self.get();
        let flat: Vec<f32> = scene
            .mesh()
            .triangles
            .iter()
            .flat_map(|t| t.iter().flat_map(|v| v.to_array()))
            .collect();
        let m = scene.num_triangles();
        Ok(PyArray1::from_vec(py, flat).reshape([m, 3, 3])?.into_any())
    }

    /// (M,) int32 array: the object id of each triangle.
    fn object_ids<'py>(&self, py: Python<'py>) -> Bound<'py, PyAny> {
        let ids: Vec<i32> = self
            .get()
            .mesh()
            .object_ids
            .iter()
            .map(|&i| i as i32)
            .collect();
        PyArray1::from_vec(py, ids).into_any()
    }

    /// Names of the objects, indexed by object id.
    fn object_names(&self) -> Vec<String> {
        self.get()
            .mesh()
            .objects
            .iter()
            .map(|o| o.name.clone())
            .collect()
    }

    /// Gives object `obj` another material (geometry, caches and G-buffers stay valid).
    fn set_material(
        &self,
        obj: &Bound<'_, PyAny>,
        material: PyRef<'_, PyMaterial>,
    ) -> PyResult<()> {
        let obj = int_arg(obj, "obj", 0, u32::MAX as i128)? as u32;
        let m = material.inner;
        self.edit(|s| s.set_material(obj, m)).py()
    }

    /// Material of object `obj`.
    fn material(&self, obj: usize) -> PyResult<PyMaterial> {
        self.get()
            .mesh()
            .objects
            .get(obj)
            .map(|o| PyMaterial { inner: o.material })
            .ok_or_else(|| {
                PyValueError::new_err(format!(
                    "obj: no object {obj} (the scene has {})",
                    self.get().num_objects()
                ))
            })
    }

    /// Builds the BVH now (otherwise it is built on the first query). quality: "auto"
    /// (default: builds our binned SAH tree and obvhs's "slow" PLOC tree and keeps the PLOC
    /// tree where it does 5% less work on 4096 sample shadow rays; meshes over 262,144
    /// triangles get the SAH tree only; `bvh_stats()` says which and why), "sah" (our binned SAH
    /// builder) or one of obvhs's PLOC presets "fastest", "very_fast", "fast", "medium",
    /// "slow", "very_slow". Returns the build time in seconds.
    ///
    /// Ctrl-C returns at once (KeyboardInterrupt) and leaves the scene as it was: the tree
    /// is built on a thread of its own, which the builders cannot stop part-way, so an
    /// interrupted build runs on to its end in the background and is then dropped.
    #[pyo3(signature = (quality="auto", threads=None))]
    fn build(
        &self,
        py: Python<'_>,
        quality: &str,
        threads: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<f64> {
        let q = BuildQuality::parse(quality).py()?;
        let threads = threads_arg(threads)?;
        self.get().check_bvh_memory().py()?;
        let snapshot = self.get();
        let built_for = snapshot.pose_fingerprint();
        // The builder cannot be stopped part-way: on Ctrl-C the call returns at once and
        // the tree, built aside, is dropped when done.
        let bvh = detach_abandonable(py, "viscache-bvh", move || {
            crate::parallel::with_threads(threads, || snapshot.build_aside(q))
        })?;
        let bvh = bvh
            .ok_or_else(|| pyo3::exceptions::PyRuntimeError::new_err("build: the builder failed"))?
            .py()?;
        let seconds = bvh.build_time().as_secs_f64();
        let installed = self.edit(|scene| scene.install_bvh(q, built_for, bvh));
        if !installed {
            // Edited from another thread meanwhile: build the scene as it is now.
            return detach_stoppable(py, || {
                self.edit(|scene| {
                    crate::parallel::with_threads(threads, || {
                        scene.build(q).build_time().as_secs_f64()
                    })
                })
            })?
            .py();
        }
        Ok(seconds)
    }

    /// Statistics of the BVH (built if needed): quality (the builder that made it),
    /// requested (the preset asked for, e.g. "auto"), sah_cost (expected block tests and
    /// node visits of a ray crossing the scene's box), auto_costs (node visits plus block
    /// tests per sample shadow ray of each tree "auto" compared: "sah", "slow", and
    /// "sah_objects_apart" for a scene of several objects; else None), objects_apart
    /// (whether each object has a subtree of its own), nodes, bytes, build seconds.
    fn bvh_stats<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let scene = self.get();
        let bvh = py.detach(|| scene.bvh());
        let d = PyDict::new(py);
        d.set_item("quality", bvh.quality().name())?;
        d.set_item("requested", bvh.requested_quality().name())?;
        d.set_item("sah_cost", bvh.sah_cost())?;
        match bvh.auto_costs() {
            Some(costs) => {
                let c = PyDict::new(py);
                c.set_item("sah", costs.sah)?;
                c.set_item(
                    crate::geometry::bvh::AUTO_ALTERNATIVE.name(),
                    costs.alternative,
                )?;
                if let Some(apart) = costs.objects_apart {
                    c.set_item("sah_objects_apart", apart)?;
                }
                d.set_item("auto_costs", c)?;
            }
            None => d.set_item("auto_costs", py.None())?,
        }
        d.set_item("objects_apart", bvh.objects_apart())?;
        d.set_item("nodes", bvh.num_nodes())?;
        d.set_item("memory_bytes", bvh.memory_bytes())?;
        d.set_item("build_seconds", bvh.build_time().as_secs_f64())?;
        Ok(d)
    }

    /// (N,) bool: whether anything lies on `origins + t * directions`, t in [0, tmax).
    /// origins, directions: (N, 3) real arrays (directions non-zero, any length);
    /// tmax: None (unbounded), a number, or (N,) array >= 0; threads: None = all cores.
    #[pyo3(signature = (origins, directions, tmax=None, threads=None))]
    fn occluded<'py>(
        &self,
        py: Python<'py>,
        origins: &Bound<'py, PyAny>,
        directions: &Bound<'py, PyAny>,
        tmax: Option<&Bound<'py, PyAny>>,
        threads: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let threads = threads_arg(threads)?;
        let occ = self.with_rays(py, origins, directions, tmax, |s, b| s.occluded(b, threads))?;
        Ok(PyArray1::from_vec(py, occ).into_any())
    }

    /// Closest hits, as a dict of arrays: t (inf on miss, in units of the given direction's
    /// length), prim and obj (int32, -1 on miss), u and v (barycentrics of the second and
    /// third vertex), position and normal ((N, 3), unit geometric normal, NaN on miss).
    #[pyo3(signature = (origins, directions, tmax=None, threads=None))]
    fn intersect<'py>(
        &self,
        py: Python<'py>,
        origins: &Bound<'py, PyAny>,
        directions: &Bound<'py, PyAny>,
        tmax: Option<&Bound<'py, PyAny>>,
        threads: Option<&Bound<'py, PyAny>>,
    ) -> PyResult<Bound<'py, PyDict>> {
        let threads = threads_arg(threads)?;
        let h = self.with_rays(py, origins, directions, tmax, |s, b| {
            s.intersect(b, threads)
        })?;
        let d = PyDict::new(py);
        d.set_item("t", PyArray1::from_vec(py, h.t))?;
        d.set_item("prim", PyArray1::from_vec(py, h.prim))?;
        d.set_item("obj", PyArray1::from_vec(py, h.obj))?;
        d.set_item("u", PyArray1::from_vec(py, h.u))?;
        d.set_item("v", PyArray1::from_vec(py, h.v))?;
        d.set_item("position", rows3_array(py, h.position)?)?;
        d.set_item("normal", rows3_array(py, h.normal)?)?;
        Ok(d)
    }

    /// Moves points off their surface along `normals` by an epsilon that scales with the
    /// scene's size and the points' magnitude: where shadow rays should start. A normal of
    /// zero length or not finite (no side to move to) is a ValueError naming `normals` and
    /// its row.
    fn offset_points<'py>(
        &self,
        py: Python<'py>,
        points: &Bound<'py, PyAny>,
        normals: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let p = rows3_f32(points, "points")?;
        let n = rows3_f32(normals, "normals")?;
        let (p, n) = (p.rows()?, n.rows()?);
        if p.len() != n.len() {
            return Err(PyValueError::new_err(format!(
                "normals: has {} rows but points has {}",
                n.len(),
                p.len()
            )));
        }
        // A zero normal would return the point unchanged: refused like zero directions.
        if let Some(i) = n
            .iter()
            .position(|r| glam::Vec3::from(*r).normalize_or_zero() == glam::Vec3::ZERO)
        {
            return Err(PyValueError::new_err(format!(
                "normals: row {i} is not a direction (zero length or not finite): {:?}",
                n[i]
            )));
        }
        let out = p
            .iter()
            .zip(n)
            .map(|(p, n)| self.get().offset_point((*p).into(), (*n).into()).into())
            .collect();
        rows3_array(py, out)
    }

    /// Traversal counters since the last reset: rays, nodes (BVH nodes whose children were
    /// tested) and triangles (ray/triangle tests). Exact, summed over threads.
    fn counters<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyDict>> {
        let c = self.get().counters();
        let d = PyDict::new(py);
        d.set_item("rays", c.rays)?;
        d.set_item("nodes", c.nodes)?;
        d.set_item("triangles", c.triangles)?;
        Ok(d)
    }

    /// Sets all counters to zero.
    fn reset_counters(&self) {
        self.get().reset_counters();
    }

    /// Whether queries update the counters (default True).
    #[getter]
    fn get_counting(&self) -> bool {
        self.get().counting_enabled()
    }

    #[setter]
    fn set_counting(&self, on: bool) {
        self.get().set_counting(on);
    }

    /// First hits of one primary ray per pixel (a `GBuffer`, read like a dict of (H, W,
    /// ...) arrays). With jitter the ray passes through a point drawn from (seed, pixel);
    /// without, through the pixel centre: the points `VisibilityCache.build`, `render`,
    /// `render_ao` and `LightingPreview` use when given it as `gbuffer=`.
    #[pyo3(signature = (camera, seed=0, jitter=true, threads=None))]
    fn gbuffer(
        &self,
        py: Python<'_>,
        camera: PyRef<'_, PyCamera>,
        #[pyo3(from_py_with = seed_or_zero)] seed: u64,
        jitter: bool,
        threads: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<PyGBuffer> {
        let threads = threads_arg(threads)?;
        let cam = camera.inner;
        let scene = self.get();
        let scene = &*scene;
        let g =
            detach_stoppable(py, || GBuffer::render(scene, &cam, seed, jitter, threads))?.py()?;
        Ok(PyGBuffer { inner: Arc::new(g) })
    }

    fn __len__(&self) -> usize {
        self.get().num_triangles()
    }

    pub fn __repr__(&self) -> String {
        format!(
            "Scene(num_triangles={}, num_objects={})",
            self.get().num_triangles(),
            self.get().num_objects()
        )
    }
}
