//! `Proxies`: a proxy set of BLD (`crate::geometry::proxies`) for method "stochastic"
//! (`render(method="stochastic", proxies=...)`).

use std::sync::Arc;

use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::PyDict;

use super::convert::{int_arg, rows3_f32, rows3_i64, IntoPyResult};
use super::scene::PyScene;
use crate::bsdf::Material;
use crate::geometry::proxies::{self, ProxyKind, ProxyOptions, ProxySet};
use crate::geometry::Mesh;

/// Cheap geometry standing for some of a scene's objects, with one guarantee (`kind`):
/// "outside" (encloses each object; solid), "inside" (lies within each watertight object)
/// or "general" (neither). Its own scene with its own BVH, tied to the scene it was made
/// for: a render of another scene refuses it.
#[pyclass(name = "Proxies", module = "viscache_rs._core", frozen)]
pub struct PyProxies {
    pub(crate) inner: Arc<ProxySet>,
}

/// `objects`: None, or object ids (non-negative ints).
fn objects_arg(objects: Option<&Bound<'_, PyAny>>) -> PyResult<Option<Vec<u32>>> {
    let Some(o) = objects.filter(|o| !o.is_none()) else {
        return Ok(None);
    };
    let items: Vec<Bound<'_, PyAny>> = o
        .try_iter()
        .map_err(|_| PyTypeError::new_err("objects: expected None or a sequence of object ids"))?
        .collect::<PyResult<_>>()?;
    items
        .iter()
        .map(|i| int_arg(i, "objects", 0, u32::MAX as i128).map(|v| v as u32))
        .collect::<PyResult<Vec<u32>>>()
        .map(Some)
}

#[pymethods]
impl PyProxies {
    /// `Proxies.boxes(scene, objects=None)`: one axis-aligned box (12 triangles) per object
    /// (`objects`, or every object with triangles): outside proxies.
    #[staticmethod]
    #[pyo3(signature = (scene, objects=None))]
    fn boxes(
        py: Python<'_>,
        scene: PyRef<'_, PyScene>,
        objects: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let objects = objects_arg(objects)?;
        let scene = scene.get();
        let set = py
            .detach(|| ProxySet::boxes(&scene, objects.as_deref()))
            .py()?;
        Ok(Self {
            inner: Arc::new(set),
        })
    }

    /// `Proxies.from_meshes(scene, {obj_id: (V, F)}, kind="outside")`: user-made proxies,
    /// one mesh ((N, 3) vertices, (M, 3) faces) per object id; the guarantee `kind` is taken
    /// on trust (outside proxies must be closed surfaces enclosing their object).
    #[staticmethod]
    #[pyo3(signature = (scene, meshes, kind="outside"))]
    fn from_meshes(
        py: Python<'_>,
        scene: PyRef<'_, PyScene>,
        meshes: &Bound<'_, PyAny>,
        kind: &str,
    ) -> PyResult<Self> {
        let kind = ProxyKind::parse(kind).py()?;
        let dict = meshes.cast::<PyDict>().map_err(|_| {
            PyTypeError::new_err("meshes: expected a dict {object id: (vertices, faces)}")
        })?;
        let mut parts = Vec::with_capacity(dict.len());
        for (k, v) in dict.iter() {
            let id = int_arg(&k, "meshes", 0, u32::MAX as i128)? as u32;
            let (vertices, faces): (Bound<'_, PyAny>, Bound<'_, PyAny>) =
                v.extract().map_err(|_| {
                    PyTypeError::new_err(format!(
                        "meshes: object {id}'s value must be a (vertices, faces) pair"
                    ))
                })?;
            let rows = rows3_f32(&vertices, "vertices")?;
            let f = rows3_i64(&faces, "faces")?;
            let mut m = Mesh::new();
            m.add_indexed(rows.rows()?, &f, Material::DEFAULT, None)
                .py()?;
            parts.push((id, m));
        }
        parts.sort_by_key(|p| p.0);
        let scene = scene.get();
        let set = py
            .detach(|| ProxySet::from_meshes(&scene, kind, parts))
            .py()?;
        Ok(Self {
            inner: Arc::new(set),
        })
    }

    /// `Proxies.build(scene, kind="outside", hull=False, target=None, spheres=40,
    /// cell=0.03, objects=None)`: "outside" (boxes, or convex hulls with `hull`, at most
    /// `target` triangles each), "inside" (`spheres` inscribed spheres per watertight
    /// object), "general" (vertex clustering with cells of `cell` of each object's box, or
    /// grown to at most `target` triangles) or "mixed".
    #[staticmethod]
    #[pyo3(signature = (scene, kind="outside", hull=false, target=None, spheres=None, cell=None, objects=None))]
    #[allow(clippy::too_many_arguments)]
    fn build(
        py: Python<'_>,
        scene: PyRef<'_, PyScene>,
        kind: &str,
        hull: bool,
        target: Option<&Bound<'_, PyAny>>,
        spheres: Option<&Bound<'_, PyAny>>,
        cell: Option<&Bound<'_, PyAny>>,
        objects: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let mut options = ProxyOptions {
            hull,
            objects: objects_arg(objects)?,
            ..ProxyOptions::DEFAULT
        };
        if let Some(t) = target.filter(|t| !t.is_none()) {
            options.target = Some(int_arg(t, "target", 1, u32::MAX as i128)? as usize);
        }
        if let Some(s) = spheres.filter(|s| !s.is_none()) {
            options.spheres = int_arg(s, "spheres", 1, proxies::MAX_SPHERES as i128)? as usize;
        }
        if let Some(c) = cell.filter(|c| !c.is_none()) {
            let c: f64 = c
                .extract()
                .map_err(|_| PyTypeError::new_err("cell: expected a number"))?;
            if !c.is_finite() {
                return Err(PyValueError::new_err(format!(
                    "cell: must be finite, got {c}"
                )));
            }
            options.cell = c as f32;
        }
        let kind = kind.to_string();
        let scene = scene.get();
        let set = py.detach(|| proxies::build(&scene, &kind, &options)).py()?;
        Ok(Self {
            inner: Arc::new(set),
        })
    }

    /// The guarantee: "outside", "inside" or "general".
    #[getter]
    fn kind(&self) -> &'static str {
        self.inner.kind().name()
    }

    /// Number of proxy triangles.
    #[getter]
    fn num_triangles(&self) -> usize {
        self.inner.num_triangles()
    }

    /// The ids of the objects the proxies stand for, one per proxy object, in order.
    #[getter]
    fn objects(&self) -> Vec<u32> {
        self.inner.objects().to_vec()
    }

    fn __repr__(&self) -> String {
        format!(
            "Proxies(kind={:?}, objects={}, num_triangles={})",
            self.kind(),
            self.inner.objects().len(),
            self.inner.num_triangles()
        )
    }
}
