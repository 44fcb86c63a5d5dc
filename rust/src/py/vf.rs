//! Method "vf"'s keyword arguments ([`crate::estimators::vf::VfParams`]) for
//! `_core.render`: each checked here with an error naming it, then the whole set by
//! [`VfParams::validate`] against the camera.

use pyo3::exceptions::PyValueError;
use pyo3::prelude::*;

use super::convert::{f64_arg, int_arg};
use crate::estimators::vf::{
    VfParams, MAX_FILTER, MAX_PROXIES, MAX_RAYS_PER_PIXEL, MAX_VOXELS_PER_AXIS,
};

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
    if let Some(o) = set(proxies) {
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
