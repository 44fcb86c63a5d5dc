//! PyO3 bindings: argument checks, numpy conversion, GIL release around the core. No logic
//! lives here; everything calls into the crate's modules.

mod ambient;
mod analysis;
mod cache;
mod camera;
mod convert;
mod envmap;
mod gbuffer;
mod image;
mod importance;
mod interrupt;
mod irradiance;
mod material;
mod octahedral;
mod preview;
mod proxies;
mod relight;
mod render;
mod scene;
mod setup;
mod testing;
mod vf;
mod vpl;

use pyo3::prelude::*;

/// Loads numpy's C API now. `numpy` loads it on first use, importing Python modules, and
/// panics if that import raises: a Ctrl-C pending when a long call made the process's first
/// array then gave a `PanicException` instead of `KeyboardInterrupt`. The modules are
/// imported here first, so that an error at this point is raised, not a panic.
fn load_numpy_api(py: Python<'_>) -> PyResult<()> {
    py.import("numpy")?;
    py.import("numpy.lib")?;
    let _ = numpy::PyArray1::<f32>::zeros(py, 0, false);
    Ok(())
}

/// The native module `viscache_rs._core`.
#[pymodule]
fn _core(m: &Bound<'_, PyModule>) -> PyResult<()> {
    load_numpy_api(m.py())?;
    m.add("__version__", env!("CARGO_PKG_VERSION"))?;
    m.add_class::<scene::PyScene>()?;
    m.add_class::<camera::PyCamera>()?;
    m.add_class::<gbuffer::PyGBuffer>()?;
    m.add_class::<material::PyMaterial>()?;
    m.add_class::<setup::PySetup>()?;
    m.add_class::<envmap::PyEnvMap>()?;
    m.add_class::<cache::PyVisibilityCache>()?;
    m.add_class::<irradiance::PyIrradianceCache>()?;
    m.add_class::<importance::PyImportanceCache>()?;
    m.add_class::<preview::PyLightingPreview>()?;
    m.add_class::<relight::PyRelighter>()?;
    m.add_class::<vf::PyProxyGrid>()?;
    m.add_class::<proxies::PyProxies>()?;
    m.add_function(wrap_pyfunction!(render::render, m)?)?;
    m.add_function(wrap_pyfunction!(render::methods, m)?)?;
    m.add_function(wrap_pyfunction!(render::check_method_args, m)?)?;
    m.add_function(wrap_pyfunction!(render::own_cache_record_cap, m)?)?;
    m.add(
        "OWN_CACHE_SAMPLES_PER_RECORD",
        crate::render::own_cache::SAMPLES_PER_RECORD,
    )?;
    m.add("DEFAULT_VPLS", crate::render::many_lights::DEFAULT_VPLS)?;
    m.add(
        "DEFAULT_VPL_SAMPLES",
        crate::render::many_lights::DEFAULT_VPL_SAMPLES,
    )?;
    m.add(
        "OWN_CACHE_BUDGET_SHARE",
        crate::render::own_cache::CACHE_BUDGET_SHARE,
    )?;
    m.add("LIMITS", limits(m.py())?)?;
    m.add_class::<vpl::PyVpls>()?;
    m.add_function(wrap_pyfunction!(ambient::render_ao, m)?)?;
    m.add_function(wrap_pyfunction!(image::write_exr, m)?)?;
    m.add_function(wrap_pyfunction!(setup::scene_names, m)?)?;
    m.add_function(wrap_pyfunction!(setup::load_scene, m)?)?;
    m.add_function(wrap_pyfunction!(setup::animated_scene_names, m)?)?;
    m.add_function(wrap_pyfunction!(setup::scene_variants, m)?)?;
    m.add_function(wrap_pyfunction!(setup::indirect_scene_names, m)?)?;
    let testing = PyModule::new(m.py(), "testing")?;
    testing.add_function(wrap_pyfunction!(testing::ground_hemisphere_rays, &testing)?)?;
    testing.add_function(wrap_pyfunction!(testing::record_bundle_rays, &testing)?)?;
    testing.add_function(wrap_pyfunction!(testing::chi2_sphere, &testing)?)?;
    testing.add_function(wrap_pyfunction!(testing::simd_level, &testing)?)?;
    m.add_submodule(&testing)?;
    let octa = PyModule::new(m.py(), "octahedral")?;
    octa.add_function(wrap_pyfunction!(octahedral::sphere_to_square, &octa)?)?;
    octa.add_function(wrap_pyfunction!(octahedral::square_to_sphere, &octa)?)?;
    octa.add_function(wrap_pyfunction!(octahedral::texel_of, &octa)?)?;
    m.add_submodule(&octa)?;
    let analysis = PyModule::new(m.py(), "analysis")?;
    analysis.add_class::<analysis::PyVisibilityMaps>()?;
    analysis.add_function(wrap_pyfunction!(analysis::visibility_maps, &analysis)?)?;
    analysis.add_function(wrap_pyfunction!(analysis::sample_pairs, &analysis)?)?;
    analysis.add_function(wrap_pyfunction!(analysis::pair_correlations, &analysis)?)?;
    analysis.add_function(wrap_pyfunction!(analysis::correlation_bins, &analysis)?)?;
    analysis.add_function(wrap_pyfunction!(analysis::local_correlation, &analysis)?)?;
    m.add_submodule(&analysis)?;
    Ok(())
}

/// The ranges the core's own checks accept, as `name -> (low, high)` (both ends included,
/// except `detail`'s 0), so that front ends such as the command line refuse a value before
/// any work with the same bounds instead of copies of them.
fn limits(py: Python<'_>) -> PyResult<Bound<'_, pyo3::types::PyDict>> {
    use crate::sampling::pattern::{MAX_LOG2_RESOLUTION, MIN_LOG2_RESOLUTION};
    let d = pyo3::types::PyDict::new(py);
    d.set_item("spp", (1u32, crate::render::MAX_SPP))?;
    d.set_item("threads", (1usize, crate::parallel::MAX_THREADS))?;
    d.set_item("seed", (0u64, u64::MAX))?;
    d.set_item("detail", (0.0f64, f64::from(crate::scenes::MAX_DETAIL)))?;
    d.set_item("image_side", (1u32, crate::camera::MAX_RESOLUTION))?;
    d.set_item(
        "record_resolution",
        (1u32 << MIN_LOG2_RESOLUTION, 1u32 << MAX_LOG2_RESOLUTION),
    )?;
    d.set_item(
        "alpha",
        (0.0f64, crate::visibility::cache::interpolant::ALPHA_MAX),
    )?;
    Ok(d)
}
