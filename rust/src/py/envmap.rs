//! `vc.EnvMap`: the octahedral HDR environment map of [`crate::lights::envmap`].

use super::interrupt::{detach_abandonable, detach_stoppable};
use std::path::PathBuf;

use glam::Vec3;
use numpy::PyArray1;
use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PySequence};

use super::convert::{
    f64_arg, image3_f32, int_arg, or_default, rows2_f64, rows3_array, rows3_f32, vec3_arg,
    IntoPyResult,
};
use crate::lights::envmap::rows as envmap_rows;
use crate::lights::envmap::{ExrLayout, MAX_EQUIRECT_SIDE, MAX_RESOLUTION};
use crate::lights::procedural::{self, Window};
use crate::lights::EnvMap;

/// Default octahedral resolution of maps built from images and procedures.
const DEFAULT_RESOLUTION: u32 = 256;

/// An HDR environment map on the equal-area octahedral map of the sphere (immutable:
/// every operation returns a new map).
#[pyclass(name = "EnvMap", module = "viscache_rs._core", frozen)]
pub struct PyEnvMap {
    /// The core map (read-only from Python; renderers borrow it without the GIL).
    pub inner: EnvMap,
}

/// A resolution argument: an integer in `[1, 4096]` that is a power of two.
fn resolution_arg(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    let r = int_arg(obj, "resolution", 1, MAX_RESOLUTION as i128)? as u32;
    crate::lights::envmap::check_resolution(r, "resolution").py()?;
    Ok(r)
}

/// Extractor of `resolution=256` ([`DEFAULT_RESOLUTION`], the literal in the signatures).
fn resolution_or_default(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    or_default(obj, DEFAULT_RESOLUTION, resolution_arg)
}
const _: () = assert!(
    DEFAULT_RESOLUTION == 256,
    "update the signatures' resolution=256"
);

/// An RGB argument: a number (grey) or three numbers.
fn rgb_arg(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<[f32; 3]> {
    let v = if obj.is_instance_of::<pyo3::types::PyInt>()
        || obj.is_instance_of::<pyo3::types::PyFloat>()
        || obj.is_instance_of::<pyo3::types::PyBool>()
    {
        let x = f64_arg(obj, name)? as f32;
        [x; 3]
    } else {
        vec3_arg(obj, name)?
    };
    if !crate::lights::valid_radiance(v) {
        return Err(PyValueError::new_err(format!(
            "{name}: {}",
            crate::lights::radiance_problem(v)
        )));
    }
    Ok(v)
}

/// Directions `(N, 3)`, each finite and non-zero, normalised in f64 (as
/// `convert::unit_directions`: a subnormal or huge row still has a direction).
fn dirs_arg(obj: &Bound<'_, PyAny>) -> PyResult<Vec<Vec3>> {
    let rows = rows3_f32(obj, "dirs")?;
    let rows = rows.rows()?;
    let unit = |r: &[f32; 3]| Vec3::from(*r).as_dvec3().normalize_or_zero().as_vec3();
    if let Some(i) = rows
        .iter()
        .position(|r| !r.iter().all(|c| c.is_finite()) || unit(r) == Vec3::ZERO)
    {
        return Err(PyValueError::new_err(format!(
            "dirs: row {i} is {:?}; directions must be finite and non-zero",
            rows[i]
        )));
    }
    crate::alloc::try_collect(rows.iter().map(unit), "dirs").py()
}

fn black_error() -> PyErr {
    PyValueError::new_err(
        "the environment map is black (every texel is zero), so it cannot be sampled",
    )
}

/// A window given as a dict with keys `azimuth_deg`, `elevation_deg`, `width_deg`,
/// `height_deg`, `radiance`, or as a 5-sequence in that order.
fn window_arg(obj: &Bound<'_, PyAny>, i: usize) -> PyResult<Window> {
    let name = format!("windows[{i}]");
    let keys = [
        "azimuth_deg",
        "elevation_deg",
        "width_deg",
        "height_deg",
        "radiance",
    ];
    let items: Vec<Bound<'_, PyAny>> = if let Ok(d) = obj.cast::<PyDict>() {
        for k in d.keys() {
            let k: String = k.extract().unwrap_or_default();
            if !keys.contains(&k.as_str()) {
                return Err(PyValueError::new_err(format!(
                    "{name}: unknown key {k:?}; expected {}",
                    keys.join(", ")
                )));
            }
        }
        keys.iter()
            .map(|k| {
                d.get_item(k)?
                    .ok_or_else(|| PyValueError::new_err(format!("{name}: missing key {k:?}")))
            })
            .collect::<PyResult<_>>()?
    } else if let Ok(s) = obj.cast::<PySequence>() {
        if s.len()? != 5 || obj.is_instance_of::<pyo3::types::PyString>() {
            return Err(PyValueError::new_err(format!(
                "{name}: expected (azimuth_deg, elevation_deg, width_deg, height_deg, radiance)"
            )));
        }
        (0..5).map(|k| s.get_item(k)).collect::<PyResult<_>>()?
    } else {
        return Err(PyTypeError::new_err(format!(
            "{name}: expected a dict or a sequence of five values"
        )));
    };
    let num = |k: usize| -> PyResult<f32> {
        Ok(f64_arg(&items[k], &format!("{name}.{}", keys[k]))? as f32)
    };
    Ok(Window {
        azimuth_deg: num(0)?,
        elevation_deg: num(1)?,
        width_deg: num(2)?,
        height_deg: num(3)?,
        radiance: rgb_arg(&items[4], &format!("{name}.radiance"))?,
    })
}

fn side_arg(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<usize> {
    Ok(int_arg(obj, name, 1, MAX_EQUIRECT_SIDE as i128)? as usize)
}

#[pymethods]
impl PyEnvMap {
    /// Resamples a lat-long image `rgb` of shape (H, W, 3) (row 0 at the top; column 0
    /// looks toward -z, W/4 toward +x, W/2 toward +z) onto a `resolution`² octahedral map,
    /// preserving its total power.
    #[staticmethod]
    #[pyo3(signature = (rgb, resolution=256))]
    fn from_equirect(
        py: Python<'_>,
        rgb: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = resolution_or_default)] resolution: u32,
    ) -> PyResult<Self> {
        let (pixels, h, w) = image3_f32(rgb, "rgb")?;
        if w > MAX_EQUIRECT_SIDE || h > MAX_EQUIRECT_SIDE {
            return Err(PyValueError::new_err(format!(
                "rgb: sides must be at most {MAX_EQUIRECT_SIDE}, got {h} x {w}"
            )));
        }
        let inner =
            detach_stoppable(py, || EnvMap::from_equirect(&pixels, w, h, resolution))?.py()?;
        Ok(Self { inner })
    }

    /// A map from its octahedral texels `rgb` of shape (R, R, 3), R a power of two <= 4096;
    /// `rgb[y, x]` is texel (x, y).
    #[staticmethod]
    fn from_octahedral(py: Python<'_>, rgb: &Bound<'_, PyAny>) -> PyResult<Self> {
        let (pixels, h, w) = image3_f32(rgb, "rgb")?;
        if h != w || !w.is_power_of_two() || w > MAX_RESOLUTION as usize {
            return Err(PyValueError::new_err(format!(
                "rgb: expected shape (R, R, 3) with R a power of two in [1, {MAX_RESOLUTION}], \
                 got ({h}, {w}, 3)"
            )));
        }
        let inner = py
            .detach(|| EnvMap::from_octahedral(w as u32, pixels))
            .map_err(|e| match e {
                crate::Error::InvalidArgument { reason, .. } => {
                    PyValueError::new_err(format!("rgb: {reason}"))
                }
                other => super::convert::to_py(other),
            })?;
        Ok(Self { inner })
    }

    /// Reads an OpenEXR file (octahedral or lat-long; see the module docs of
    /// `viscache_rs.envmaps`). `resolution=None` keeps an octahedral file's own and gives
    /// a lat-long one `min(4096, next_power_of_two(height))`.
    #[staticmethod]
    #[pyo3(signature = (path, resolution=None))]
    fn from_exr(
        py: Python<'_>,
        path: PathBuf,
        resolution: Option<&Bound<'_, PyAny>>,
    ) -> PyResult<Self> {
        let r = match resolution {
            Some(o) if !o.is_none() => Some(resolution_arg(o)?),
            _ => None,
        };
        // The EXR codec cannot be stopped part-way: on Ctrl-C the call returns at once and
        // the decoding thread's map is dropped when done.
        let inner = detach_abandonable(py, "viscache-exr", move || EnvMap::read_exr(&path, r))?
            .ok_or_else(|| pyo3::exceptions::PyRuntimeError::new_err("path: the reader failed"))?
            .py()?;
        Ok(Self { inner })
    }

    /// A uniform map of `value` (a number or an RGB triple, finite, in [0, 1e15]).
    #[staticmethod]
    #[pyo3(signature = (value, resolution=256))]
    fn constant(
        value: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = resolution_or_default)] resolution: u32,
    ) -> PyResult<Self> {
        let v = rgb_arg(value, "value")?;
        Ok(Self {
            inner: EnvMap::constant(v, resolution).py()?,
        })
    }

    /// A gradient sky with a disc sun (see `viscache_rs.envmaps.sky`).
    #[staticmethod]
    #[pyo3(signature = (sun_dir, sun_radiance, sun_angle, zenith, horizon, resolution=256))]
    fn sky(
        py: Python<'_>,
        sun_dir: &Bound<'_, PyAny>,
        sun_radiance: &Bound<'_, PyAny>,
        sun_angle: &Bound<'_, PyAny>,
        zenith: &Bound<'_, PyAny>,
        horizon: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = resolution_or_default)] resolution: u32,
    ) -> PyResult<Self> {
        let sun = Vec3::from(vec3_arg(sun_dir, "sun_dir")?);
        if sun.length() == 0.0 {
            return Err(PyValueError::new_err("sun_dir: must be non-zero"));
        }
        let sun_rgb = rgb_arg(sun_radiance, "sun_radiance")?;
        let angle = f64_arg(sun_angle, "sun_angle")? as f32;
        let z = rgb_arg(zenith, "zenith")?;
        let h = rgb_arg(horizon, "horizon")?;
        let inner = py
            .detach(|| procedural::sky(sun, sun_rgb, angle, z, h, resolution))
            .py()?;
        Ok(Self { inner })
    }

    /// Bright rectangles of directions on a dim background (see
    /// `viscache_rs.envmaps.windows`).
    #[staticmethod]
    #[pyo3(signature = (windows, background, resolution=256))]
    fn windows(
        py: Python<'_>,
        windows: &Bound<'_, PyAny>,
        background: &Bound<'_, PyAny>,
        #[pyo3(from_py_with = resolution_or_default)] resolution: u32,
    ) -> PyResult<Self> {
        let seq = windows
            .cast::<PySequence>()
            .map_err(|_| PyTypeError::new_err("windows: expected a sequence of windows"))?;
        let list: Vec<Window> = (0..seq.len()?)
            .map(|i| window_arg(&seq.get_item(i)?, i))
            .collect::<PyResult<_>>()?;
        let bg = rgb_arg(background, "background")?;
        let inner = py
            .detach(|| procedural::windows(&list, bg, resolution))
            .py()?;
        Ok(Self { inner })
    }

    /// Writes an OpenEXR file; `layout` is "octahedral" (bit-exact) or "latlong"
    /// (2R x R).
    #[pyo3(signature = (path, layout="octahedral"))]
    fn to_exr(&self, py: Python<'_>, path: PathBuf, layout: &str) -> PyResult<()> {
        let layout = ExrLayout::parse(layout, "layout").py()?;
        py.detach(|| self.inner.to_exr(&path, layout)).py()
    }

    /// A (height, width, 3) float32 lat-long image of the map.
    fn to_equirect<'py>(
        &self,
        py: Python<'py>,
        width: &Bound<'py, PyAny>,
        height: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let w = side_arg(width, "width")?;
        let h = side_arg(height, "height")?;
        // The image and its per-pixel sums (f64 base, excess and solid angle): at most 80
        // bytes a pixel, checked up front so that a size that cannot be met is a
        // MemoryError before any work.
        crate::alloc::check_memory(w.saturating_mul(h).saturating_mul(80), "to_equirect").py()?;
        let img = detach_stoppable(py, || self.inner.to_equirect(w, h))?.py()?;
        super::convert::image_array(py, img.into_flattened(), h, w, Some(3))
    }

    /// The map rotated by `degrees` about +y (right-handed: +90 takes +x to -z).
    fn rotated(&self, py: Python<'_>, degrees: &Bound<'_, PyAny>) -> PyResult<Self> {
        let deg = f64_arg(degrees, "degrees")?;
        if !deg.is_finite() {
            return Err(PyValueError::new_err(format!(
                "degrees: must be finite, got {deg}"
            )));
        }
        let inner = detach_stoppable(py, || self.inner.rotated(deg as f32))?;
        Ok(Self { inner })
    }

    /// Side R of the octahedral texture.
    #[getter]
    fn resolution(&self) -> u32 {
        self.inner.resolution()
    }

    /// Whether every texel is zero (the map cannot be sampled).
    #[getter]
    fn is_black(&self) -> bool {
        self.inner.is_black()
    }

    /// The texels as an (R, R, 3) float32 array; `[y, x]` is texel (x, y).
    fn texels<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let r = self.inner.resolution() as usize;
        super::convert::image_array(
            py,
            self.inner.texels().as_flattened().to_vec(),
            r,
            r,
            Some(3),
        )
    }

    /// Radiance (N, 3) float32 arriving from directions `dirs` (N, 3).
    fn eval<'py>(&self, py: Python<'py>, dirs: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
        let d = dirs_arg(dirs)?;
        let mut out = vec![[0.0f32; 3]; d.len()];
        py.detach(|| envmap_rows::eval_rows(&self.inner, &d, &mut out))
            .py()?;
        rows3_array(py, out)
    }

    /// Solid-angle pdf (N,) float64 of `sample` at directions `dirs` (N, 3); zeros for a
    /// black map.
    fn pdf<'py>(&self, py: Python<'py>, dirs: &Bound<'py, PyAny>) -> PyResult<Bound<'py, PyAny>> {
        let d = dirs_arg(dirs)?;
        let mut out = vec![0.0f64; d.len()];
        py.detach(|| envmap_rows::pdf_rows(&self.inner, &d, &mut out))
            .py()?;
        Ok(PyArray1::from_vec(py, out).into_any())
    }

    /// Draws directions for `u` (N, 2) in [0, 1): returns (dirs (N, 3) float32,
    /// pdf (N,) float64). A black map is a ValueError.
    fn sample<'py>(
        &self,
        py: Python<'py>,
        u: &Bound<'py, PyAny>,
    ) -> PyResult<(Bound<'py, PyAny>, Bound<'py, PyAny>)> {
        let rows = rows2_f64(u, "u")?;
        let rows = &rows[..];
        let (mut dirs, mut pdf) = (vec![[0.0f32; 3]; rows.len()], vec![0.0f64; rows.len()]);
        py.detach(|| envmap_rows::sample_rows(&self.inner, rows, &mut dirs, &mut pdf))
            .py()?;
        // Refused after the core's check of u, so that a bad u is still reported first.
        if self.inner.is_black() {
            return Err(black_error());
        }
        Ok((
            rows3_array(py, dirs)?,
            PyArray1::from_vec(py, pdf).into_any(),
        ))
    }

    /// The u (N, 2) float64 that `sample` maps to each direction of `dirs` (N, 3); NaN rows
    /// for directions of zero pdf. A black map is a ValueError.
    fn invert<'py>(
        &self,
        py: Python<'py>,
        dirs: &Bound<'py, PyAny>,
    ) -> PyResult<Bound<'py, PyAny>> {
        let d = dirs_arg(dirs)?;
        if self.inner.is_black() {
            return Err(black_error());
        }
        let mut out = vec![[0.0f64; 2]; d.len()];
        py.detach(|| envmap_rows::invert_rows(&self.inner, &d, &mut out))
            .py()?;
        super::convert::rows_array(py, out)
    }

    /// ∫ L dω over the sphere per channel, as (r, g, b).
    fn total_power(&self) -> (f64, f64, f64) {
        let [r, g, b] = self.inner.total_power();
        (r, g, b)
    }

    pub fn __repr__(&self) -> String {
        let [r, g, b] = self.inner.total_power();
        format!(
            "EnvMap(resolution={}, total_power=({r:.6e}, {g:.6e}, {b:.6e}))",
            self.inner.resolution()
        )
    }
}
