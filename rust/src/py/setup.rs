//! Built-in setups: `vc.scenes.load(name)` returns a `Setup` with `scene`, `camera` and
//! `envmap`.

use pyo3::prelude::*;

use super::camera::PyCamera;
use super::convert::{f64_arg, seed_arg, IntoPyResult};
use super::envmap::PyEnvMap;
use super::scene::PyScene;
use crate::scenes;

/// A scene with the camera that frames it and the environment map that lights it: what
/// `vc.render` takes. Built-in ones come from `vc.scenes.load`; `Setup(scene, camera,
/// envmap, name="custom")` makes one from user objects.
#[pyclass(name = "Setup", module = "viscache_rs._core")]
pub struct PySetup {
    /// Name of the built-in scene.
    #[pyo3(get)]
    pub name: String,
    /// The geometry (the same object every time it is read).
    #[pyo3(get, set)]
    pub scene: Py<PyScene>,
    /// The camera.
    #[pyo3(get, set)]
    pub camera: Py<PyCamera>,
    /// The environment map that lights the scene.
    #[pyo3(get, set)]
    pub envmap: Py<PyEnvMap>,
}

#[pymethods]
impl PySetup {
    #[new]
    #[pyo3(signature = (scene, camera, envmap, name=None))]
    fn new(
        scene: Py<PyScene>,
        camera: Py<PyCamera>,
        envmap: Py<PyEnvMap>,
        name: Option<String>,
    ) -> Self {
        Self {
            name: name.unwrap_or_else(|| "custom".into()),
            scene,
            camera,
            envmap,
        }
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        format!(
            "Setup(name={:?}, scene={}, camera={}, envmap={})",
            self.name,
            self.scene.borrow(py).__repr__(),
            self.camera.get().__repr__(),
            self.envmap.get().__repr__()
        )
    }
}

/// Names of the built-in scenes.
#[pyfunction]
pub fn scene_names() -> Vec<&'static str> {
    scenes::names().to_vec()
}

/// Builds a built-in scene. `detail` in (0, 16] scales its triangle count; `seed` drives
/// every random choice of the generator.
#[pyfunction]
#[pyo3(signature = (name, detail=None, seed=None))]
pub fn load_scene(
    py: Python<'_>,
    name: &str,
    detail: Option<&Bound<'_, PyAny>>,
    seed: Option<&Bound<'_, PyAny>>,
) -> PyResult<PySetup> {
    let detail = detail.map_or(Ok(1.0), |d| f64_arg(d, "detail"))? as f32;
    let seed = seed.map_or(Ok(0), seed_arg)?;
    let setup = py.detach(|| scenes::load(name, detail, seed)).py()?;
    Ok(PySetup {
        name: setup.name,
        scene: Py::new(py, PyScene::new_from(setup.scene))?,
        camera: Py::new(
            py,
            PyCamera {
                inner: setup.camera,
            },
        )?,
        envmap: Py::new(
            py,
            PyEnvMap {
                inner: setup.envmap,
            },
        )?,
    })
}
