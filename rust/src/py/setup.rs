//! Built-in setups: `vc.scenes.load(name)` returns a `Setup` with `scene`, `camera` and
//! `envmap`; animated ones (`animated=True`) move an object with `setup.at_frame(i)`.

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use super::camera::PyCamera;
use super::convert::{f64_arg, int_arg, or_default, rows3_array, seed_or_zero, IntoPyResult};
use super::envmap::PyEnvMap;
use super::scene::PyScene;
use crate::scenes::{self, animation, Animation};

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
    /// The moving object and its path (animated setups only).
    pub animation: Option<Animation>,
    /// The frame the scene is at.
    pub frame: u64,
    /// The built-in scene's variant (`vc.scenes.load(name, variant=...)`), None for the
    /// default.
    pub variant: Option<String>,
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
            animation: None,
            frame: 0,
            variant: None,
        }
    }

    /// Moves the scene to frame `frame` (an int >= 0): the moving object takes its pose at
    /// that frame (a pure function of `frame`, so any order of frames gives the same
    /// scene) and the BVH is refit. `setup.scene` is updated in place; if the scene is
    /// shared (e.g. held by a cache) it is copied first and the sharer keeps the old
    /// geometry. Setups that are not animated have only frame 0, where this does nothing;
    /// other frames raise ValueError. On error nothing changes.
    fn at_frame(&mut self, py: Python<'_>, frame: &Bound<'_, PyAny>) -> PyResult<()> {
        let frame = int_arg(frame, "frame", 0, u64::MAX as i128)? as u64;
        match self.animation {
            None => animation::static_frame(&self.name, frame).py()?,
            Some(anim) => {
                let scene_ref = self.scene.borrow(py);
                let scene: &PyScene = &scene_ref;
                let n = scene.get().num_objects();
                if anim.object as usize >= n {
                    return Err(PyValueError::new_err(format!(
                        "scene: has {n} objects, no moving object {} (was setup.scene replaced?)",
                        anim.object
                    )));
                }
                py.detach(|| scene.edit(|s| anim.apply(s, frame))).py()?;
            }
        }
        self.frame = frame;
        Ok(())
    }

    /// The frame the scene is at (0 as loaded).
    #[getter]
    fn frame(&self) -> u64 {
        self.frame
    }

    /// The built-in scene's variant (`vc.scenes.variants(name)`), or None for a default
    /// setup and for user setups.
    #[getter]
    fn variant(&self) -> Option<String> {
        self.variant.clone()
    }

    /// True for animated setups (`vc.scenes.load(name, animated=True)`).
    #[getter]
    fn animated(&self) -> bool {
        self.animation.is_some()
    }

    /// Object id of the moving object, or None if the setup is not animated.
    #[getter]
    fn moving_object(&self) -> Option<u32> {
        self.animation.map(|a| a.object)
    }

    /// Frames after which the motion repeats, or None if the setup is not animated.
    #[getter]
    fn period(&self) -> Option<u64> {
        self.animation.map(|a| a.period())
    }

    /// (2, 3) float32 array [min, max]: bounds of the moving object at the current frame;
    /// None if the setup is not animated.
    fn moving_bounds<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyAny>>> {
        let Some(anim) = self.animation else {
            return Ok(None);
        };
        let b = anim.bounds(&self.scene.borrow(py).get()).py()?;
        rows3_array(py, vec![b.min.into(), b.max.into()]).map(Some)
    }

    fn __repr__(&self, py: Python<'_>) -> String {
        let frame = match self.animation {
            Some(_) => format!(", frame={}", self.frame),
            None => String::new(),
        };
        let variant = match &self.variant {
            Some(v) => format!(", variant={v:?}"),
            None => String::new(),
        };
        format!(
            "Setup(name={:?}{variant}, scene={}, camera={}, envmap={}{frame})",
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

/// Names of the built-in scenes that have an animated variant.
#[pyfunction]
pub fn animated_scene_names() -> Vec<&'static str> {
    scenes::ANIMATED_NAMES.to_vec()
}

/// Names of the variants of the built-in scene `name` (possibly none); an unknown name
/// raises ValueError naming `name`.
#[pyfunction]
pub fn scene_variants(name: &str) -> PyResult<Vec<&'static str>> {
    scenes::variants(name).py()
}

/// The setups for indirect light, as (name, variant) pairs (variant None: the default).
#[pyfunction]
pub fn indirect_scene_names() -> Vec<(&'static str, Option<&'static str>)> {
    scenes::INDIRECT_NAMES.to_vec()
}

/// Extractor of `detail=1.0`.
fn detail_arg(obj: &Bound<'_, PyAny>) -> PyResult<f32> {
    or_default(obj, 1.0, |o| Ok(f64_arg(o, "detail")? as f32))
}

/// Builds a built-in scene. `detail` in (0, 16] scales its triangle count; `seed` drives
/// every random choice of the generator; `animated` selects the animated variant,
/// `variant` a named one (`scene_variants(name)`); the two cannot be combined.
#[pyfunction]
#[pyo3(signature = (name, detail=1.0, seed=0, animated=false, variant=None))]
pub fn load_scene(
    py: Python<'_>,
    name: &str,
    #[pyo3(from_py_with = detail_arg)] detail: f32,
    #[pyo3(from_py_with = seed_or_zero)] seed: u64,
    animated: bool,
    variant: Option<&str>,
) -> PyResult<PySetup> {
    if animated && variant.is_some() {
        return Err(PyValueError::new_err(
            "variant: animated setups have no named variants; pass animated=False",
        ));
    }
    let setup = py
        .detach(|| {
            if animated {
                scenes::load_animated(name, detail, seed)
            } else {
                scenes::load_variant(name, variant, detail, seed)
            }
        })
        .py()?;
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
        animation: setup.animation,
        frame: setup.frame,
        variant: setup.variant,
    })
}
