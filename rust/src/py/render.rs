//! `viscache_rs._core.render`: every method of [`crate::render::registry`], and the registry.
//! The Python wrapper (`viscache_rs.render`) adds the progress bar.

use pyo3::exceptions::{PyTypeError, PyValueError};
use pyo3::prelude::*;
use pyo3::types::{PyDict, PyString};

use super::cache::PyVisibilityCache;
use super::camera::PyCamera;
use super::convert::{
    f64_arg, image_array, image_dict, int_arg, or_default, product_level_arg, seed_or_zero,
    threads_arg, IntoPyResult,
};
use super::envmap::PyEnvMap;
use super::gbuffer::{view_arg, PyGBuffer, View};
use super::importance::PyImportanceCache;
use super::interrupt::{detach_interruptible, PyProgress};
use super::irradiance::{params_arg as irradiance_params_arg, PyIrradianceCache};
use super::proxies::PyProxies;
use super::scene::PyScene;
use super::vf::{grid_arg as vf_grid_arg, params_arg as vf_params_arg};
use super::vpl::PyVpls;
use crate::estimators::control_variate::AlphaRule;
use crate::estimators::direct::Techniques;
use crate::estimators::indirect::MAX_BOUNCES;
use crate::estimators::many_lights::{Sampling, MAX_DRAWS};
use crate::render::output::{Stat, Stats, View as CoreView};
use crate::render::registry::{self, CacheKind, CacheRef, MethodInputs};
use crate::render::stochastic::StochasticInputs;
use crate::render::vf::VfRenderer;
use crate::render::{RenderParams, MAX_LIGHT_SAMPLES};
use crate::visibility::params::CacheParams;

/// `alpha`: a number, or "estimate" (neighbour pooling with `radius`).
fn alpha_arg(alpha: Option<&Bound<'_, PyAny>>, radius: u32) -> PyResult<AlphaRule> {
    let Some(alpha) = alpha.filter(|a| !a.is_none()) else {
        return Ok(AlphaRule::PAPER);
    };
    if let Ok(s) = alpha.cast::<PyString>() {
        let s = s.to_str()?;
        return if s == "estimate" {
            Ok(AlphaRule::Neighbours { radius })
        } else {
            Err(PyValueError::new_err(format!(
                "alpha: expected a number or \"estimate\", got {s:?}"
            )))
        };
    }
    if alpha.is_instance_of::<pyo3::types::PyBool>() {
        return Err(PyTypeError::new_err(
            "alpha: expected a number or \"estimate\", got a bool",
        ));
    }
    Ok(AlphaRule::Fixed(f64_arg(alpha, "alpha")?))
}

/// Extractor of `alpha_radius=4`.
fn alpha_radius_arg(obj: &Bound<'_, PyAny>) -> PyResult<u32> {
    or_default(obj, 4, |o| Ok(int_arg(o, "alpha_radius", 1, 64)? as u32))
}

/// `technique_weights`: a dict of weights by technique name ("product", "guided", "bsdf",
/// "env"; missing ones are 0), or None for the method's default.
fn techniques_arg(weights: Option<&Bound<'_, PyAny>>) -> PyResult<Option<Techniques>> {
    const NAMES: [&str; 4] = ["product", "guided", "bsdf", "env"];
    let Some(weights) = weights.filter(|w| !w.is_none()) else {
        return Ok(None);
    };
    let dict = weights.cast::<PyDict>().map_err(|_| {
        PyTypeError::new_err(format!(
            "technique_weights: expected a dict of weights by technique {NAMES:?} or None"
        ))
    })?;
    let mut w = [0.0f32; 4];
    for (key, value) in dict.iter() {
        let key: String = key
            .extract()
            .map_err(|_| PyTypeError::new_err("technique_weights: keys must be technique names"))?;
        let k = NAMES.iter().position(|n| *n == key).ok_or_else(|| {
            PyValueError::new_err(format!(
                "technique_weights: unknown technique {key:?}; expected one of {NAMES:?}"
            ))
        })?;
        w[k] = f64_arg(&value, "technique_weights")? as f32;
    }
    Ok(Some(Techniques::new(w[0], w[1], w[2], w[3])))
}

/// `clamp`: a positive, finite bound of the geometry term (1/m²), or None.
fn clamp_arg(clamp: Option<&Bound<'_, PyAny>>) -> PyResult<Option<f32>> {
    match clamp {
        Some(c) if !c.is_none() => {
            let v = f64_arg(c, "clamp")?;
            if !(v.is_finite() && v > 0.0) {
                return Err(PyValueError::new_err(format!(
                    "clamp: must be a positive, finite bound of the geometry term cos cos / d² \
                     (1/m²) or None, got {v}"
                )));
            }
            Ok(Some(v as f32))
        }
        _ => Ok(None),
    }
}

/// An optional integer argument in `[lo, hi]`.
fn opt_int(obj: Option<&Bound<'_, PyAny>>, name: &str, lo: u32, hi: u32) -> PyResult<Option<u32>> {
    match obj {
        Some(o) if !o.is_none() => Ok(Some(int_arg(o, name, lo as i128, hi as i128)? as u32)),
        _ => Ok(None),
    }
}

/// Renders by any registered method (`methods()`); returns a dict with `image` and
/// `variance` (H, W, 3) float32, `alpha` (H, W, 3) float32 for the control variate (else
/// None), `sample_counts` (H, W) uint32 and `stats` (a dict of the method's figures).
/// `callback(done, planned)` (pixel samples), if given, is called about every 0.1 s and
/// after every pass with the GIL held; a falsy return or an exception stops the render
/// (the exception is then raised). None stands for the defaults, which are the
/// registry's and the core's: `spp` the method's (16, or 1 for the many-light methods;
/// as many as fit with a time budget), `threads` every core, `time_budget` none,
/// `product_level` "auto" (per material), `alpha` 1.0 (CAM08's), `technique_weights` the
/// method's own, `bounces` the method's (1 for "path", "vpl" and "vpl_sampled", else 0),
/// `adaptive` under a time budget only, `vpls` a default set traced for the view,
/// `sampling` (method "vpl_sampled": "uniform", "power" or "unoccluded") "unoccluded". With
/// `gbuffer` (traced through `camera`) its hits are the pixels' anchors. Method "cv"
/// without `cache` builds one of `preset` for the view first
/// (`crate::render::own_cache`; its figures are the stats' `cache_*`).
#[pyfunction]
#[pyo3(signature = (scene, envmap, camera, spp=None, method="mis", seed=0, threads=None, time_budget=None, product_level=None, callback=None, cache=None, jitter=true, alpha=None, alpha_radius=4, insert_missing=false, technique_weights=None, bounces=None, direct=true, gbuffer=None, light_samples=None, learn_techniques=true, adaptive=None, preset="auto", vpls=None, clamp=None, vpl_samples=None, a=None, strata=None, r_min=None, r_max=None, gradients=None, clamp_neighbours=None, secondary_spp=None, proxies=None, voxels=None, marching=None, indirect=None, rays_per_pixel=None, filter=None, depth_tol=None, normal_tol=None, sh_range=None, sampling=None, combine=None, lam=None, spacing=None, nearest=None, probabilities=None, probe_rays=None))]
#[allow(clippy::too_many_arguments)]
pub fn render<'py>(
    py: Python<'py>,
    scene: PyRef<'py, PyScene>,
    envmap: Bound<'py, PyEnvMap>,
    camera: PyRef<'py, PyCamera>,
    spp: Option<&Bound<'py, PyAny>>,
    method: &str,
    #[pyo3(from_py_with = seed_or_zero)] seed: u64,
    threads: Option<&Bound<'py, PyAny>>,
    time_budget: Option<&Bound<'py, PyAny>>,
    product_level: Option<&Bound<'py, PyAny>>,
    callback: Option<Py<PyAny>>,
    cache: Option<&Bound<'py, PyAny>>,
    jitter: bool,
    alpha: Option<&Bound<'py, PyAny>>,
    #[pyo3(from_py_with = alpha_radius_arg)] alpha_radius: u32,
    insert_missing: bool,
    technique_weights: Option<&Bound<'py, PyAny>>,
    bounces: Option<&Bound<'py, PyAny>>,
    direct: bool,
    gbuffer: Option<PyRef<'py, PyGBuffer>>,
    light_samples: Option<&Bound<'py, PyAny>>,
    learn_techniques: bool,
    adaptive: Option<bool>,
    preset: &str,
    vpls: Option<Bound<'py, PyVpls>>,
    clamp: Option<&Bound<'py, PyAny>>,
    vpl_samples: Option<&Bound<'py, PyAny>>,
    a: Option<&Bound<'py, PyAny>>,
    strata: Option<&Bound<'py, PyAny>>,
    r_min: Option<&Bound<'py, PyAny>>,
    r_max: Option<&Bound<'py, PyAny>>,
    gradients: Option<&Bound<'py, PyAny>>,
    clamp_neighbours: Option<&Bound<'py, PyAny>>,
    secondary_spp: Option<&Bound<'py, PyAny>>,
    proxies: Option<&Bound<'py, PyAny>>,
    voxels: Option<&Bound<'py, PyAny>>,
    marching: Option<&Bound<'py, PyAny>>,
    indirect: Option<&Bound<'py, PyAny>>,
    rays_per_pixel: Option<&Bound<'py, PyAny>>,
    filter: Option<&Bound<'py, PyAny>>,
    depth_tol: Option<&Bound<'py, PyAny>>,
    normal_tol: Option<&Bound<'py, PyAny>>,
    sh_range: Option<&Bound<'py, PyAny>>,
    sampling: Option<&str>,
    combine: Option<&str>,
    lam: Option<&Bound<'py, PyAny>>,
    spacing: Option<&Bound<'py, PyAny>>,
    nearest: Option<&Bound<'py, PyAny>>,
    probabilities: Option<&str>,
    probe_rays: Option<&Bound<'py, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    // Method "stochastic" reads `proxies` as a proxy set (`Proxies`), VF as counts or a grid.
    let stochastic_proxies = match proxies.filter(|p| !p.is_none()) {
        Some(p) if p.is_instance_of::<PyProxies>() => {
            Some(p.cast::<PyProxies>()?.get().inner.clone())
        }
        Some(p) if method == "stochastic" => {
            return Err(PyTypeError::new_err(format!(
                "proxies: method \"stochastic\" takes a Proxies set, got {}",
                p.get_type().name()?
            )))
        }
        _ => None,
    };
    let proxies = if stochastic_proxies.is_some() {
        None
    } else {
        proxies
    };
    let probe_rays = opt_int(
        probe_rays,
        "probe_rays",
        1,
        crate::render::stochastic::MAX_PROBE_RAYS,
    )?;
    if let Some(p) = probabilities {
        crate::estimators::stochastic_visibility::split::ProbabilityMode::parse(p).py()?;
    }
    let importance_method = method == "importance_cache";
    use super::importance::given;
    let importance = if importance_method
        && (combine.is_some()
            || [lam, spacing, nearest, alpha]
                .iter()
                .any(|o| given(*o).is_some()))
    {
        let mut i = crate::render::importance::ImportanceInputs {
            combine,
            ..Default::default()
        };
        if let Some(a) = given(alpha) {
            i.alpha = Some(super::importance::alpha4_arg(a)?);
        }
        if let Some(l) = given(lam) {
            i.lam = Some(f64_arg(l, "lam")? as f32);
        }
        if let Some(s) = given(spacing) {
            i.spacing = Some(int_arg(
                s,
                "spacing",
                1,
                crate::estimators::importance::records::MAX_SPACING as i128,
            )? as u32);
        }
        if let Some(n) = given(nearest) {
            i.nearest = Some(int_arg(
                n,
                "nearest",
                1,
                crate::estimators::importance::records::MAX_NEAREST as i128,
            )? as u32);
        }
        Some(i)
    } else {
        if let Some((name, _)) = [("lam", lam), ("spacing", spacing), ("nearest", nearest)]
            .into_iter()
            .find(|(_, o)| given(*o).is_some())
            .or(combine.map(|_| ("combine", None)))
        {
            return Err(PyValueError::new_err(format!(
                "{name}: method {method:?} does not take it (methods that do: \
                 [\"importance_cache\"])"
            )));
        }
        None
    };
    let alpha = if importance_method { None } else { alpha };
    let view = view_arg(Some(camera), gbuffer)?;
    let vf = vf_params_arg(
        proxies,
        voxels,
        marching,
        indirect,
        rays_per_pixel,
        filter,
        depth_tol,
        normal_tol,
        sh_range,
    )?;
    let irradiance_given = [
        a,
        strata,
        r_min,
        r_max,
        gradients,
        clamp_neighbours,
        secondary_spp,
    ]
    .iter()
    .any(|o| o.is_some_and(|o| !o.is_none()));
    let irradiance = if irradiance_given {
        Some(irradiance_params_arg(
            a,
            strata,
            r_min,
            r_max,
            gradients,
            clamp_neighbours,
            secondary_spp,
        )?)
    } else {
        None
    };
    let spec = registry::method(method).py()?;
    let spp = opt_int(spp, "spp", 1, spec.max_spp)?;
    let bounces = opt_int(bounces, "bounces", 0, MAX_BOUNCES)?;
    let time_budget = match time_budget {
        Some(b) if !b.is_none() => Some(f64_arg(b, "time_budget")?),
        _ => None,
    };
    let params = RenderParams {
        seed,
        time_budget,
        product_level: product_level_arg(product_level)?,
        jitter,
        techniques: techniques_arg(technique_weights)?,
        alpha: alpha_arg(alpha, alpha_radius)?,
        insert_missing,
        direct,
        learn_techniques,
        own_cache: CacheParams::preset(preset).py()?,
        ..RenderParams::DEFAULT
    };
    let light_samples = opt_int(light_samples, "light_samples", 1, MAX_LIGHT_SAMPLES)?;
    let vpl_samples = opt_int(vpl_samples, "vpl_samples", 1, MAX_DRAWS)?;
    let clamp = clamp_arg(clamp)?;
    let sampling = sampling.map(Sampling::parse).transpose().py()?;
    let threads = threads_arg(threads)?;
    let scene = scene.get();
    scene.check_bvh_memory().py()?;
    let cache = cache.filter(|c| !c.is_none());
    let visibility = match cache {
        Some(c) if c.is_instance_of::<PyVisibilityCache>() => {
            Some(c.cast::<PyVisibilityCache>()?.borrow().bound(py)?)
        }
        _ => None,
    };
    let importance_cache = match cache {
        Some(c) if c.is_instance_of::<PyImportanceCache>() => {
            Some(c.cast::<PyImportanceCache>()?.borrow().inner.clone())
        }
        _ => None,
    };
    let irradiance_cache = match cache {
        Some(c) if c.is_instance_of::<PyIrradianceCache>() => {
            Some(c.cast::<PyIrradianceCache>()?.borrow().inner.clone())
        }
        Some(c) if visibility.is_none() && importance_cache.is_none() => {
            return Err(PyTypeError::new_err(format!(
                "cache: expected a VisibilityCache, an IrradianceCache, an ImportanceCache \
                 or None, got {}",
                c.get_type().name()?
            )))
        }
        _ => None,
    };
    let vf_grid = vf_grid_arg(proxies, &envmap)?;
    let env: Py<PyEnvMap> = envmap.unbind();
    let vpls: Option<Py<PyVpls>> = vpls.map(Bound::unbind);
    let mut reporter = PyProgress::new(callback);
    let stop = reporter.stop_flag();
    let mut progress = |done: u64, planned: u64| reporter.report(done, planned);
    let out = detach_interruptible(py, &stop, || {
        let view = match &view {
            View::Camera(cam) => CoreView::Camera(cam),
            View::GBuffer(g) => CoreView::GBuffer(g),
        };
        let inputs = MethodInputs {
            threads,
            spp,
            bounces,
            adaptive,
            light_samples,
            params,
            cache: match (&visibility, &irradiance_cache, &importance_cache) {
                (Some(v), _, _) => Some(CacheRef::Visibility(v)),
                (None, Some(i), _) => Some(CacheRef::Irradiance(i)),
                (None, None, Some(i)) => Some(CacheRef::Importance(i)),
                (None, None, None) => None,
            },
            importance,
            irradiance,
            vpls: vpls.as_ref().map(|v| &v.get().inner),
            clamp,
            vpl_samples,
            sampling,
            vf,
            stochastic: (stochastic_proxies.is_some()
                || probabilities.is_some()
                || probe_rays.is_some())
            .then_some(StochasticInputs {
                proxies: stochastic_proxies.as_deref(),
                probabilities,
                probe_rays,
            }),
            ..MethodInputs::new(&scene, &env.get().inner, view)
        };
        match &vf_grid {
            // A grid built beforehand (`proxies=ProxyGrid`) goes to VF's renderer itself:
            // the registry's inputs carry parameters, not grids.
            Some(g) => VfRenderer.render_with(spec, &inputs, Some(g.as_ref()), &mut progress),
            None => spec.render(&inputs, &mut progress),
        }
    })?
    .py()?;
    reporter.finish()?;
    let (w, h) = (out.width as usize, out.height as usize);
    let d = image_dict(py, out.image, out.variance, h, w)?;
    match out.alpha {
        Some(a) => d.set_item("alpha", image_array(py, a.into_flattened(), h, w, Some(3))?)?,
        None => d.set_item("alpha", py.None())?,
    }
    d.set_item(
        "sample_counts",
        image_array(py, out.sample_counts, h, w, None)?,
    )?;
    d.set_item("stats", stats_dict(py, &out.stats)?)?;
    Ok(d)
}

/// A render's figures as a dict, in their order.
fn stats_dict<'py>(py: Python<'py>, stats: &Stats) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    for (name, value) in stats.iter() {
        let v = match value {
            Stat::None => py.None().into_bound(py),
            Stat::Bool(b) => b.into_pyobject(py)?.to_owned().into_any(),
            Stat::Int(i) => i.into_pyobject(py)?.into_any(),
            Stat::Float(f) => f.into_pyobject(py)?.into_any(),
            Stat::Text(t) => t.into_pyobject(py)?.into_any(),
            Stat::Ints(v) => v.into_pyobject(py)?.into_any(),
            Stat::Floats(v) => v.into_pyobject(py)?.into_any(),
            Stat::Named(pairs) => {
                let named = PyDict::new(py);
                for (k, v) in pairs {
                    named.set_item(k, v)?;
                }
                named.into_any()
            }
        };
        d.set_item(name, v)?;
    }
    Ok(d)
}

/// The method registry ([`crate::render::registry`]): one dict per method, in order, with
/// `name`, `about`, `estimator` (its family: "direct" or "many_lights"), `params` (keyword
/// parameters beyond `common`), `common`, `caches` (the cache types it accepts),
/// `min_bounces`, `default_bounces`, `default_spp` and `max_spp`.
#[pyfunction]
pub fn methods(py: Python<'_>) -> PyResult<Vec<Bound<'_, PyDict>>> {
    registry::METHODS
        .iter()
        .map(|m| {
            let d = PyDict::new(py);
            d.set_item("name", m.name)?;
            d.set_item("about", m.about)?;
            d.set_item("estimator", m.renderer.family())?;
            d.set_item("params", m.params.to_vec())?;
            d.set_item("common", registry::COMMON_PARAMS.to_vec())?;
            let caches: Vec<&str> = m.caches.iter().map(|c| c.name()).collect();
            d.set_item("caches", caches)?;
            d.set_item("min_bounces", m.min_bounces)?;
            d.set_item("default_bounces", m.default_bounces)?;
            d.set_item("default_spp", m.default_spp)?;
            d.set_item("max_spp", m.max_spp)?;
            Ok(d)
        })
        .collect()
}

/// Checks `render`'s arguments against the registry: `method` must be a registered name,
/// every name in `given` (the keyword parameters the caller set) one it reads, and
/// `cache`, if not None, a cache it accepts. Raises ValueError naming the first argument
/// that is not, with what the method takes.
#[pyfunction]
#[pyo3(signature = (method, given, cache=None))]
pub fn check_method_args(
    method: &str,
    given: Vec<String>,
    cache: Option<&Bound<'_, PyAny>>,
) -> PyResult<()> {
    let spec = registry::method(method).py()?;
    let given: Vec<&str> = given.iter().map(String::as_str).collect();
    let kind = match cache.filter(|c| !c.is_none()) {
        None => None,
        Some(c) if c.is_instance_of::<PyVisibilityCache>() => Some(CacheKind::Visibility),
        Some(c) if c.is_instance_of::<PyIrradianceCache>() => Some(CacheKind::Irradiance),
        Some(c) if c.is_instance_of::<PyImportanceCache>() => Some(CacheKind::Importance),
        Some(c) => {
            return Err(PyTypeError::new_err(format!(
                "cache: expected a VisibilityCache, an IrradianceCache, an ImportanceCache or \
                 None, got {}",
                c.get_type().name()?
            )))
        }
    };
    spec.check_args(&given, kind).py()
}

/// The most records the cache `render(method="cv")` builds for itself may hold for
/// `pixels` pixels at `spp` samples per pixel with cache preset `preset`
/// ([`crate::render::own_cache::record_cap`]).
#[pyfunction]
#[pyo3(signature = (pixels, spp, preset="auto"))]
pub fn own_cache_record_cap(pixels: u64, spp: u64, preset: &str) -> PyResult<u32> {
    let params = CacheParams::preset(preset).py()?;
    Ok(crate::render::own_cache::record_cap(&params, pixels, spp))
}
