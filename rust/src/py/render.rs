//! `viscache_rs._core.render`: the renderer of [`crate::render`], and its method registry.
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
use super::interrupt::{detach_interruptible, PyProgress};
use super::scene::PyScene;
use crate::estimators::control_variate::AlphaRule;
use crate::estimators::direct::{Method, Techniques};
use crate::estimators::indirect::MAX_BOUNCES;
use crate::render::registry::{self, CacheKind, Estimator};
use crate::render::{render as render_core, render_from, RenderParams, MAX_LIGHT_SAMPLES, MAX_SPP};
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

/// Renders direct illumination; returns a dict with `image` and `variance` (H, W, 3)
/// float32, `alpha` (H, W, 3) float32 for method "cv" (else None) and `stats` (a dict).
/// `callback(done, planned)` (pixel samples), if given, is called about every 0.1 s and
/// after every pass with the GIL held; a falsy return or an exception stops the render
/// (the exception is then raised). None stands for the core's defaults: `threads` every
/// core, `time_budget` none, `product_level` "auto" (per material), `alpha` 1.0 (CAM08's),
/// `technique_weights` the method's own, `bounces` 1 for method "path" and 0 otherwise.
/// With `gbuffer` (traced through `camera`) its hits are the pixels' anchors. `adaptive`
/// None: adaptive sample counts under a time budget only. Method "cv" without `cache`
/// builds one of `preset` for the view first (`crate::render::own_cache`; its figures are
/// the stats' `cache_*`). Also returns `sample_counts` (H, W) uint32.
#[pyfunction]
#[pyo3(signature = (scene, envmap, camera, spp, method, seed=0, threads=None, time_budget=None, product_level=None, callback=None, cache=None, jitter=true, alpha=None, alpha_radius=4, insert_missing=false, technique_weights=None, bounces=None, direct=true, gbuffer=None, light_samples=None, learn_techniques=true, adaptive=None, preset="auto"))]
#[allow(clippy::too_many_arguments)]
pub fn render<'py>(
    py: Python<'py>,
    scene: PyRef<'py, PyScene>,
    envmap: Bound<'py, PyEnvMap>,
    camera: PyRef<'py, PyCamera>,
    spp: &Bound<'py, PyAny>,
    method: &str,
    #[pyo3(from_py_with = seed_or_zero)] seed: u64,
    threads: Option<&Bound<'py, PyAny>>,
    time_budget: Option<&Bound<'py, PyAny>>,
    product_level: Option<&Bound<'py, PyAny>>,
    callback: Option<Py<PyAny>>,
    cache: Option<PyRef<'py, PyVisibilityCache>>,
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
) -> PyResult<Bound<'py, PyDict>> {
    let view = view_arg(Some(camera), gbuffer)?;
    let spec = registry::method(method).py()?;
    let spp = int_arg(spp, "spp", 1, MAX_SPP as i128)? as u32;
    // The row's method and default bounces.
    let Some(defaults) = spec.render_params(spp) else {
        return Err(PyValueError::new_err(format!(
            "method: {:?} renders through viscache_rs.render (the many-light renderer)",
            spec.name
        )));
    };
    let bounces = match bounces {
        Some(b) if !b.is_none() => {
            int_arg(b, "bounces", spec.min_bounces as i128, MAX_BOUNCES as i128)? as u32
        }
        _ => defaults.bounces,
    };
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
        bounces,
        direct,
        light_samples: match light_samples {
            Some(n) if !n.is_none() => {
                int_arg(n, "light_samples", 1, MAX_LIGHT_SAMPLES as i128)? as u32
            }
            _ => 1,
        },
        // Without a count, budgeted product renders choose one from the view.
        auto_light_samples: light_samples.is_none_or(|n| n.is_none()),
        learn_techniques,
        // Adaptive by default under a time budget: what the budget buys is least error.
        adaptive: adaptive.unwrap_or(time_budget.is_some()),
        own_cache: CacheParams::preset(preset).py()?,
        ..defaults
    };
    params.validate().py()?;
    let threads = threads_arg(threads)?;
    let scene = scene.get();
    scene.check_bvh_memory().py()?;
    spec.check_args(&[], cache.as_ref().map(|_| CacheKind::Visibility))
        .py()?;
    let cache = cache.map(|c| c.bound(py)).transpose()?;
    let env: Py<PyEnvMap> = envmap.unbind();
    let mut reporter = PyProgress::new(callback);
    let stop = reporter.stop_flag();
    let mut progress = |done: u64, planned: u64| reporter.report(done, planned);
    let out = detach_interruptible(py, &stop, || {
        let (env, cache) = (&env.get().inner, cache.as_deref());
        match &view {
            View::Camera(cam) => {
                render_core(&scene, env, cam, &params, cache, threads, &mut progress)
            }
            View::GBuffer(g) => render_from(&scene, env, g, &params, cache, threads, &mut progress),
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
    let s = &out.stats;
    d.set_item(
        "sample_counts",
        image_array(py, out.sample_counts, h, w, None)?,
    )?;
    let stats = PyDict::new(py);
    stats.set_item("method", spec.name)?;
    stats.set_item("bounces", params.bounces)?;
    stats.set_item("direct", params.direct)?;
    stats.set_item("seconds", s.seconds)?;
    stats.set_item("spp", s.spp)?;
    stats.set_item("mean_spp", s.mean_spp)?;
    stats.set_item("max_spp", s.max_spp)?;
    stats.set_item("adaptive", params.adaptive)?;
    stats.set_item("adaptive_gain", s.adaptive_gain)?;
    stats.set_item("pixel_mixtures", s.pixel_techniques.map(|c| c.to_vec()))?;
    stats.set_item("unmatched_samples", s.unmatched_samples)?;
    stats.set_item("passes", s.passes)?;
    stats.set_item("complete", s.complete)?;
    stats.set_item("jitter", params.jitter)?;
    stats.set_item("light_samples", s.light_samples)?;
    stats.set_item("edge_share", s.edge_share)?;
    stats.set_item("coarse_products", s.coarse_products)?;
    stats.set_item("probe_draws", s.probe_ratios.map(|r| r.draws()))?;
    stats.set_item("probe_cost_ratio", s.probe_ratios.map(|r| r.cost))?;
    stats.set_item("probe_variance_ratio", s.probe_ratios.map(|r| r.variance))?;
    let t = params.techniques();
    let weights = PyDict::new(py);
    for (name, w) in ["product", "guided", "bsdf", "env"]
        .iter()
        .zip(t.to_array())
    {
        weights.set_item(name, w)?;
    }
    stats.set_item("technique_weights", weights)?;
    match s.learnt_techniques {
        Some(w) => {
            let learnt = PyDict::new(py);
            for (name, v) in ["product", "guided", "bsdf", "env"].iter().zip(w) {
                learnt.set_item(name, v)?;
            }
            stats.set_item("learnt_weights", learnt)?;
        }
        None => stats.set_item("learnt_weights", py.None())?,
    }
    stats.set_item("samples", s.samples)?;
    stats.set_item("primary_rays", s.primary_rays)?;
    stats.set_item("shadow_rays", s.shadow_rays)?;
    stats.set_item("bsdf_rays", s.bsdf_rays)?;
    stats.set_item("bounce_rays", s.bounce_rays)?;
    stats.set_item("rays_per_second", s.rays_per_second)?;
    stats.set_item("samples_per_second", s.samples as f64 / s.seconds.max(1e-9))?;
    stats.set_item("primary_seconds", s.stages.primary)?;
    stats.set_item("product_seconds", s.stages.product)?;
    stats.set_item("lookup_seconds", s.stages.lookup)?;
    stats.set_item("control_seconds", s.stages.control)?;
    stats.set_item("shading_seconds", s.stages.shading)?;
    stats.set_item("indirect_seconds", s.stages.indirect)?;
    stats.set_item("sample_primary_seconds", s.stages.sample_primary)?;
    stats.set_item("reused_products", s.reused_products)?;
    stats.set_item(
        "direct_seconds",
        s.stages.product + s.stages.lookup + s.stages.control + s.stages.shading,
    )?;
    if params.method == Method::ControlVariate {
        let points = s.cache_points.max(1) as f64;
        stats.set_item(
            "alpha",
            match params.alpha {
                AlphaRule::Fixed(a) => a.into_pyobject(py)?.into_any(),
                AlphaRule::Neighbours { .. } => "estimate".into_pyobject(py)?.into_any(),
            },
        )?;
        stats.set_item("mean_alpha", s.mean_alpha.to_vec())?;
        stats.set_item("cache_points", s.cache_points)?;
        stats.set_item("points_without_records", s.points_without_records)?;
        stats.set_item("sun_rays", s.sun_rays)?;
        stats.set_item("records_per_point", s.records_used as f64 / points)?;
        stats.set_item("shared_lookups", s.shared_lookups)?;
        stats.set_item("reused_integrals", s.reused_integrals)?;
        stats.set_item("record_misses", s.record_misses)?;
        stats.set_item("record_uses", s.record_uses)?;
        stats.set_item(
            "miss_rate",
            s.record_misses as f64 / s.record_uses.max(1) as f64,
        )?;
        stats.set_item("inserted_records", s.inserted_records)?;
    }
    if let Some(c) = &s.own_cache {
        stats.set_item("cache_seconds", c.seconds)?;
        stats.set_item("cache_records", c.records)?;
        stats.set_item("cache_shadow_rays", c.shadow_rays)?;
        stats.set_item("cache_incoherent", c.incoherent)?;
        stats.set_item("cache_predicted_gain", c.predicted_gain)?;
        stats.set_item("cache_blind", c.blind)?;
        stats.set_item("cache_planned_spp", c.planned_spp)?;
    }
    d.set_item("stats", stats)?;
    Ok(d)
}

/// The method registry ([`crate::render::registry`]): one dict per method, in order, with
/// `name`, `about`, `estimator` ("direct" or "many_lights"), `params` (keyword parameters beyond `common`), `common`, `caches` (the
/// cache types it accepts), `min_bounces` and `default_bounces`.
#[pyfunction]
pub fn methods(py: Python<'_>) -> PyResult<Vec<Bound<'_, PyDict>>> {
    registry::METHODS
        .iter()
        .map(|m| {
            let d = PyDict::new(py);
            d.set_item("name", m.name)?;
            d.set_item("about", m.about)?;
            let estimator = match m.estimator {
                Estimator::Direct(_) => "direct",
                Estimator::ManyLights { .. } => "many_lights",
            };
            d.set_item("estimator", estimator)?;
            d.set_item("params", m.params.to_vec())?;
            d.set_item("common", registry::COMMON_PARAMS.to_vec())?;
            let caches: Vec<&str> = m.caches.iter().map(|c| c.name()).collect();
            d.set_item("caches", caches)?;
            d.set_item("min_bounces", m.min_bounces)?;
            d.set_item("default_bounces", m.default_bounces)?;
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
        Some(c) => {
            return Err(PyTypeError::new_err(format!(
                "cache: expected a VisibilityCache or None, got {}",
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
