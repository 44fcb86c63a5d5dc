//! Argument checking and numpy conversion shared by the bindings. Every failure becomes a
//! `TypeError` (wrong kind of value or dtype) or `ValueError` (wrong shape or value) whose
//! message starts with the argument's name.
//!
//! Every array argument is copied here, with the GIL held, before the bindings release the
//! GIL: a numpy array is mutable, and another Python thread writing to it while the core
//! reads it in place (checked, then read again without the GIL) would change answers
//! silently or break what the checks established (a direction zeroed after it was checked).
//! A Python thread writes only while it holds the GIL, so a copy taken under it is a
//! consistent snapshot. The copy is a memcpy of 24 MB per 1M rays: `occluded` with
//! `tmax=0` (conversion, checks and output only) measured 28-40 ms before and 43-47 ms
//! after, against 220-270 ms for `intersect` on the same rays. Copies are allocated fallibly
//! ([`crate::alloc`]): an input too large to copy is a `MemoryError` naming it.

use numpy::{
    PyArray1, PyArrayDescrMethods, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2,
    PyUntypedArray, PyUntypedArrayMethods,
};
use pyo3::exceptions::{PyFileNotFoundError, PyOSError, PyTypeError, PyValueError};
use pyo3::prelude::*;

use crate::error::Error;

/// Maps a core error to the matching Python exception.
pub fn to_py(e: Error) -> PyErr {
    match &e {
        Error::Io { source, .. } if source.kind() == std::io::ErrorKind::NotFound => {
            PyFileNotFoundError::new_err(e.to_string())
        }
        Error::Io { .. } => PyOSError::new_err(e.to_string()),
        Error::InvalidArgument { .. } | Error::Parse { .. } => PyValueError::new_err(e.to_string()),
        Error::OutOfMemory { .. } => pyo3::exceptions::PyMemoryError::new_err(e.to_string()),
        Error::Interrupted { .. } => pyo3::exceptions::PyKeyboardInterrupt::new_err(e.to_string()),
    }
}

/// Extension to turn `crate::Result` into `PyResult`.
pub trait IntoPyResult<T> {
    fn py(self) -> PyResult<T>;
}

impl<T> IntoPyResult<T> for crate::Result<T> {
    fn py(self) -> PyResult<T> {
        self.map_err(to_py)
    }
}

fn numpy(py: Python<'_>) -> PyResult<Bound<'_, PyModule>> {
    py.import("numpy")
}

/// `numpy.asarray(obj)`, with failures (ragged lists and the like) reported against `name`.
fn as_array<'py>(obj: &Bound<'py, PyAny>, name: &str) -> PyResult<Bound<'py, PyUntypedArray>> {
    let arr = numpy(obj.py())?
        .call_method1("asarray", (obj,))
        .map_err(|e| PyValueError::new_err(format!("{name}: cannot be read as an array ({e})")))?;
    arr.cast_into::<PyUntypedArray>()
        .map_err(|_| PyTypeError::new_err(format!("{name}: cannot be read as an array")))
}

fn check_kind(
    arr: &Bound<'_, PyUntypedArray>,
    name: &str,
    kinds: &[u8],
    what: &str,
) -> PyResult<()> {
    let dtype = arr.dtype();
    if kinds.contains(&dtype.kind()) {
        Ok(())
    } else {
        Err(PyTypeError::new_err(format!(
            "{name}: expected {what}, got dtype {dtype}"
        )))
    }
}

fn check_rows(arr: &Bound<'_, PyUntypedArray>, name: &str, cols: usize) -> PyResult<()> {
    let shape = arr.shape();
    if shape.len() == 2 && shape[1] == cols {
        Ok(())
    } else {
        Err(PyValueError::new_err(format!(
            "{name}: expected shape (N, {cols}), got {shape:?}"
        )))
    }
}

fn contiguous<'py>(arr: &Bound<'py, PyUntypedArray>, dtype: &str) -> PyResult<Bound<'py, PyAny>> {
    numpy(arr.py())?.call_method1("ascontiguousarray", (arr, dtype))
}

/// Rows of an `(N, 3)` real array as `float32`, copied from the caller's array (values
/// beyond the `float32` range become infinite, which the finiteness checks then report).
pub struct Rows3(Vec<[f32; 3]>);

impl Rows3 {
    /// The rows.
    pub fn rows(&self) -> PyResult<&[[f32; 3]]> {
        Ok(&self.0)
    }
}

/// A copy of `items` made while the GIL is held, or `MemoryError` naming `name`.
fn snapshot<T: Clone>(items: &[T], name: &str) -> PyResult<Vec<T>> {
    crate::alloc::try_copy(items, name).map_err(to_py)
}

/// The rows of a C-contiguous `(N, C)` array, copied (see the module docs).
fn copy_rows<T: numpy::Element + Copy, const C: usize>(
    arr: &PyReadonlyArray2<'_, T>,
    name: &str,
) -> PyResult<Vec<[T; C]>> {
    let flat = arr
        .as_slice()
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    snapshot(flat.as_chunks::<C>().0, name)
}

/// An `(N, 3)` array of real numbers (any float or integer dtype); bool, complex, object
/// and string dtypes are a `TypeError`, other shapes a `ValueError`.
pub fn rows3_f32(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Rows3> {
    let arr = as_array(obj, name)?;
    check_kind(&arr, name, b"fiu", "a real-valued array")?;
    check_rows(&arr, name, 3)?;
    if arr.dtype().is_equiv_to(&numpy::dtype::<f32>(obj.py())) {
        let a: PyReadonlyArray2<f32> = contiguous(&arr, "float32")?.extract()?;
        return Ok(Rows3(copy_rows(&a, name)?));
    }
    let wide: PyReadonlyArray2<f64> = contiguous(&arr, "float64")?.extract()?;
    let rows = as_rows(&wide)?.iter().map(|r| r.map(|v| v as f32));
    Ok(Rows3(crate::alloc::try_collect(rows, name).map_err(to_py)?))
}

/// Rows of an `(N, C)` array of finite reals, converted to `float32` (NaN and infinities, and
/// values beyond the `float32` range, are a `ValueError` naming the first bad row).
pub fn finite_rows<const C: usize>(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<[f32; C]>> {
    let arr = as_array(obj, name)?;
    check_kind(&arr, name, b"fiu", "a real-valued array")?;
    check_rows(&arr, name, C)?;
    let wide: PyReadonlyArray2<f64> = contiguous(&arr, "float64")?.extract()?;
    let flat = wide
        .as_slice()
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    let rows = flat.as_chunks::<C>().0.iter().map(|r| r.map(|v| v as f32));
    let rows: Vec<[f32; C]> = crate::alloc::try_collect(rows, name).map_err(to_py)?;
    if let Some(i) = rows.iter().position(|r| r.iter().any(|v| !v.is_finite())) {
        return Err(PyValueError::new_err(format!(
            "{name}: row {i} is not finite: {:?}",
            rows[i]
        )));
    }
    Ok(rows)
}

/// A lookup's `points` (N, 3), finite, and `normals` (N, 3), made unit
/// ([`unit_directions`]); a `ValueError` naming the argument for bad rows or counts that
/// differ.
pub fn points_and_normals(
    points: &Bound<'_, PyAny>,
    normals: &Bound<'_, PyAny>,
) -> PyResult<(Vec<glam::Vec3>, Vec<glam::Vec3>)> {
    let pts: Vec<glam::Vec3> = finite_rows::<3>(points, "points")?
        .into_iter()
        .map(glam::Vec3::from)
        .collect();
    let nrm = unit_directions(normals, "normals")?;
    if nrm.len() != pts.len() {
        return Err(PyValueError::new_err(format!(
            "normals: expected {} rows like points, got {}",
            pts.len(),
            nrm.len()
        )));
    }
    Ok((pts, nrm))
}

/// Rows of an `(N, 3)` array of directions, normalised in f64: any finite row that is
/// non-zero in `float32` has a direction, however short or long (a subnormal `1e-40` or
/// `3e38`, whose squared length under- or overflows in f32). Zero-length or non-finite
/// rows are a `ValueError` naming the first bad row.
pub fn unit_directions(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<glam::Vec3>> {
    let rows = finite_rows::<3>(obj, name)?;
    let mut dirs = crate::alloc::try_with_capacity(rows.len(), name).map_err(to_py)?;
    for (i, r) in rows.iter().enumerate() {
        let unit = glam::Vec3::from_array(*r)
            .as_dvec3()
            .normalize_or_zero()
            .as_vec3();
        if unit == glam::Vec3::ZERO {
            return Err(PyValueError::new_err(format!(
                "{name}: row {i} has zero length: {r:?}"
            )));
        }
        dirs.push(unit);
    }
    Ok(dirs)
}

/// `(N, C)` float32 array from rows.
pub fn rows_array<'py, T: numpy::Element, const C: usize>(
    py: Python<'py>,
    rows: Vec<[T; C]>,
) -> PyResult<Bound<'py, PyAny>> {
    let n = rows.len();
    Ok(PyArray1::from_vec(py, rows.into_flattened())
        .reshape([n, C])?
        .into_any())
}

/// Rows of an `(M, 3)` integer array as `int64`, copied.
pub fn rows3_i64(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<[i64; 3]>> {
    let arr = as_array(obj, name)?;
    check_kind(&arr, name, b"iu", "an integer array")?;
    check_rows(&arr, name, 3)?;
    copy_rows(&contiguous(&arr, "int64")?.extract()?, name)
}

/// Views a contiguous `(N, 3)` array as rows.
pub fn as_rows<'a, T: numpy::Element + Copy>(
    arr: &'a PyReadonlyArray2<'_, T>,
) -> PyResult<&'a [[T; 3]]> {
    let flat = arr
        .as_slice()
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    Ok(flat.as_chunks::<3>().0)
}

/// A 3-vector from any length-3 sequence of finite reals.
pub fn vec3_arg(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<[f32; 3]> {
    let arr = as_array(obj, name)?;
    check_kind(&arr, name, b"fiu", "three real numbers")?;
    if arr.shape() != [3] {
        return Err(PyValueError::new_err(format!(
            "{name}: expected three numbers, got shape {:?}",
            arr.shape()
        )));
    }
    let a: PyReadonlyArray1<f64> = contiguous(&arr, "float64")?.extract()?;
    let s = a
        .as_slice()
        .map_err(|e| PyValueError::new_err(e.to_string()))?;
    let v = [s[0] as f32, s[1] as f32, s[2] as f32];
    if v.iter().any(|c| !c.is_finite()) {
        return Err(PyValueError::new_err(format!(
            "{name}: must be finite, got {v:?}"
        )));
    }
    Ok(v)
}

/// A real scalar (int or float, not bool).
pub fn f64_arg(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<f64> {
    if obj.is_instance_of::<pyo3::types::PyBool>() {
        return Err(PyTypeError::new_err(format!(
            "{name}: expected a number, got bool"
        )));
    }
    obj.extract::<f64>().map_err(|_| {
        PyTypeError::new_err(format!("{name}: expected a number, got {}", type_name(obj)))
    })
}

/// An integer in `[min, max]` (bool rejected); out-of-range and overflow are `ValueError`.
pub fn int_arg(obj: &Bound<'_, PyAny>, name: &str, min: i128, max: i128) -> PyResult<i128> {
    if obj.is_instance_of::<pyo3::types::PyBool>() || !obj.is_instance_of::<pyo3::types::PyInt>() {
        // numpy integers are not PyInt subclasses but index like one.
        if let Ok(i) = obj.call_method0("__index__") {
            if !obj.is_instance_of::<pyo3::types::PyBool>() {
                return int_arg(&i, name, min, max);
            }
        }
        return Err(PyTypeError::new_err(format!(
            "{name}: expected an integer, got {}",
            type_name(obj)
        )));
    }
    match obj.extract::<i128>() {
        Ok(v) if (min..=max).contains(&v) => Ok(v),
        _ => Err(PyValueError::new_err(format!(
            "{name}: must be an integer in [{min}, {max}], got {obj}"
        ))),
    }
}

/// Optional thread count: `None` uses every core.
pub fn threads_arg(obj: Option<&Bound<'_, PyAny>>) -> PyResult<Option<usize>> {
    match obj {
        None => Ok(None),
        Some(o) if o.is_none() => Ok(None),
        Some(o) => Ok(Some(
            int_arg(o, "threads", 1, crate::parallel::MAX_THREADS as i128)? as usize,
        )),
    }
}

/// A seed in `[0, 2^64)`.
pub fn seed_arg(obj: &Bound<'_, PyAny>) -> PyResult<u64> {
    Ok(int_arg(obj, "seed", 0, u64::MAX as i128)? as u64)
}

/// `read(obj)`, or `default` for None. For the `#[pyo3(from_py_with = ...)]` extractors of
/// arguments whose signature states their default: None passed explicitly (as wrappers
/// forwarding their own None do) still means that default, as it did when the signature
/// said None. The extractor's `default` must equal the signature's literal.
pub fn or_default<'py, T>(
    obj: &Bound<'py, PyAny>,
    default: T,
    read: impl FnOnce(&Bound<'py, PyAny>) -> PyResult<T>,
) -> PyResult<T> {
    if obj.is_none() {
        Ok(default)
    } else {
        read(obj)
    }
}

/// Extractor of `seed=0`: a seed in `[0, 2^64)`, None for 0.
pub fn seed_or_zero(obj: &Bound<'_, PyAny>) -> PyResult<u64> {
    or_default(obj, 0, seed_arg)
}

fn type_name(obj: &Bound<'_, PyAny>) -> String {
    obj.get_type()
        .name()
        .map(|n| n.to_string())
        .unwrap_or_else(|_| "?".into())
}

/// `(N, 3)` float32 array from rows, without copying the data.
pub fn rows3_array<'py>(py: Python<'py>, rows: Vec<[f32; 3]>) -> PyResult<Bound<'py, PyAny>> {
    rows_array(py, rows)
}

/// Reshapes a flat per-pixel array to `(height, width, *tail)`.
pub fn image_array<'py, T: numpy::Element>(
    py: Python<'py>,
    data: Vec<T>,
    height: usize,
    width: usize,
    channels: Option<usize>,
) -> PyResult<Bound<'py, PyAny>> {
    let a = PyArray1::from_vec(py, data);
    Ok(match channels {
        Some(c) => a.reshape([height, width, c])?.into_any(),
        None => a.reshape([height, width])?.into_any(),
    })
}

/// A 1-D array of reals as `f32`, copied (values beyond the `float32` range become
/// infinite).
pub fn f32_vector(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<f32>> {
    real_vector(obj, name, "float32")
}

/// A 1-D real array (any float or integer dtype) as `T` (numpy's `dtype`), copied.
fn real_vector<T: numpy::Element + Copy>(
    obj: &Bound<'_, PyAny>,
    name: &str,
    dtype: &str,
) -> PyResult<Vec<T>> {
    let arr = as_array(obj, name)?;
    check_kind(&arr, name, b"fiu", "a real-valued array")?;
    if arr.ndim() != 1 {
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape (N,), got {:?}",
            arr.shape()
        )));
    }
    let a: PyReadonlyArray1<T> = contiguous(&arr, dtype)?.extract()?;
    snapshot(
        a.as_slice()
            .map_err(|e| PyValueError::new_err(e.to_string()))?,
        name,
    )
}

/// A dict of `image` and `variance`, (H, W, 3) float32 each: what every renderer returns
/// first.
pub fn image_dict<'py>(
    py: Python<'py>,
    image: Vec<[f32; 3]>,
    variance: Vec<[f32; 3]>,
    height: usize,
    width: usize,
) -> PyResult<Bound<'py, pyo3::types::PyDict>> {
    let d = pyo3::types::PyDict::new(py);
    let rgb = |v: Vec<[f32; 3]>| image_array(py, v.into_flattened(), height, width, Some(3));
    d.set_item("image", rgb(image)?)?;
    d.set_item("variance", rgb(variance)?)?;
    Ok(d)
}

/// Rows of an `(N, 2)` array of real numbers as `float64`, copied.
pub fn rows2_f64(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<[f64; 2]>> {
    let arr = as_array(obj, name)?;
    check_kind(&arr, name, b"fiu", "a real-valued array")?;
    check_rows(&arr, name, 2)?;
    copy_rows(&contiguous(&arr, "float64")?.extract()?, name)
}

/// An `(H, W, 3)` image of real numbers as row-major RGB `float32` texels, with `(H, W)`.
/// Values beyond the `float32` range become infinite (the callers' checks report them).
pub fn image3_f32(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<(Vec<[f32; 3]>, usize, usize)> {
    let arr = as_array(obj, name)?;
    check_kind(&arr, name, b"fiu", "a real-valued array")?;
    let shape = arr.shape().to_vec();
    if shape.len() != 3 || shape[2] != 3 || shape[0] == 0 || shape[1] == 0 {
        return Err(PyValueError::new_err(format!(
            "{name}: expected shape (H, W, 3) with H, W >= 1, got {shape:?}"
        )));
    }
    let flat = contiguous(&arr, "float32")?.call_method1("reshape", ((shape[0] * shape[1], 3),))?;
    let a: PyReadonlyArray2<f32> = flat.extract()?;
    Ok((copy_rows(&a, name)?, shape[0], shape[1]))
}

/// A 1-D array of reals as `f64` (any float or integer dtype).
pub fn f64_vector(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<f64>> {
    real_vector(obj, name, "float64")
}

/// Rows of an `(N, 3)` array of directions where an all-NaN row stands for "no direction"
/// (`None`); other rows are normalised, and partly NaN, infinite or zero rows are a
/// `ValueError` naming the first bad row.
pub fn nan_or_unit_rows(obj: &Bound<'_, PyAny>, name: &str) -> PyResult<Vec<Option<glam::Vec3>>> {
    let arr = as_array(obj, name)?;
    check_kind(&arr, name, b"fiu", "a real-valued array")?;
    check_rows(&arr, name, 3)?;
    let wide: PyReadonlyArray2<f64> = contiguous(&arr, "float64")?.extract()?;
    as_rows(&wide)?
        .iter()
        .enumerate()
        .map(|(i, r)| {
            if r.iter().all(|v| v.is_nan()) {
                return Ok(None);
            }
            let d = glam::DVec3::from_array(*r);
            let unit = d.normalize_or_zero().as_vec3();
            if !d.is_finite() || unit == glam::Vec3::ZERO {
                return Err(PyValueError::new_err(format!(
                    "{name}: row {i} is neither a direction nor all NaN: {r:?}"
                )));
            }
            Ok(Some(unit))
        })
        .collect()
}

/// `product_level`: None or "auto" (per material) or an int in `[1, 8]`.
pub fn product_level_arg(
    obj: Option<&Bound<'_, PyAny>>,
) -> PyResult<crate::estimators::direct::ProductLevel> {
    use crate::estimators::direct::ProductLevel;
    let Some(obj) = obj.filter(|o| !o.is_none()) else {
        return Ok(ProductLevel::PerMaterial);
    };
    if let Ok(s) = obj.cast::<pyo3::types::PyString>() {
        let s = s.to_str()?;
        return if s == "auto" {
            Ok(ProductLevel::PerMaterial)
        } else {
            Err(PyValueError::new_err(format!(
                "product_level: expected an int in [1, 8] or \"auto\", got {s:?}"
            )))
        };
    }
    Ok(ProductLevel::Fixed(
        int_arg(obj, "product_level", 1, 8)? as u32
    ))
}

/// `log2` of a resolution argument that must be a power of two in 2..=128 (records and
/// visibility maps).
pub fn log2_resolution(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    let r = int_arg(obj, "resolution", 2, 128)? as u32;
    if !r.is_power_of_two() {
        return Err(PyValueError::new_err(format!(
            "resolution: must be a power of two in 2..=128, got {r}"
        )));
    }
    Ok(r.trailing_zeros())
}
