//! Method "cv" given no cache: the render builds one for its view first, then renders with
//! it from the same G-buffer (the records' points are the pixels' anchors). The policy lives
//! here, so that a Rust caller of [`super::render`] gets the render a Python caller gets:
//!
//! - the cache takes [`super::RenderParams::own_cache`]'s parameters, without closest-hit
//!   rays (the control variate never reads `R_i`);
//! - without a budget it holds at most one record per [`SAMPLES_PER_RECORD`] of the
//!   render's samples (pixels x spp), and at least the bootstrap's ([`record_cap`]): a
//!   record traces about 2,000 shadow rays, so the build spends at most ~5x the render's
//!   rays. Measured over the suite at 10 spp (benches/HISTORY.md, "Is auto the best
//!   setting?"): uncapped, the build took longer than the render on scales and meshes at
//!   256x192 (0.71x and 0.74x product's efficiency); one record per 400 samples keeps
//!   0.9-1.0x of the uncapped cache's efficiency where that one wins;
//! - under a time budget the build may spend [`CACHE_BUDGET_SHARE`] of it and the render
//!   has what is left; with a budget alone the samples the records will serve are
//!   estimated from two short pilots of product sampling ([`samples_within`]), so that the
//!   records kept, like the passes, depend on the machine's speed.

use std::time::Instant;

use super::frame::Frame;
use super::{render_with, RenderParams, Rendered, MAX_SPP};
use crate::camera::{Camera, GBuffer};
use crate::error::Result;
use crate::estimators::direct::Method;
use crate::geometry::Scene;
use crate::lights::envmap::EnvMap;
use crate::visibility::cache::VisibilityCache;
use crate::visibility::params::CacheParams;

/// Share of a time budget that method "cv" without a cache may spend building one.
pub const CACHE_BUDGET_SHARE: f64 = 0.25;
/// Without a budget, the render's own cache holds at most one record per this many of
/// the render's samples (module docs).
pub const SAMPLES_PER_RECORD: u64 = 400;
/// The pilots that estimate a time budget's samples ([`samples_within`]): spp.
const PILOT_SPP: [u32; 2] = [8, 32];
/// ... and at most this many pixels (at most 1/16 of the view).
const PILOT_PIXELS: f64 = 1200.0;
/// Seed offset of the pilots, so that they share no random numbers with the render.
const PILOT_SEED: u64 = 0x5A17;

/// What the render's own cache cost and holds.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct OwnCacheStats {
    /// Wall-clock seconds of the pilots, the G-buffer and the build.
    pub seconds: f64,
    pub records: usize,
    pub shadow_rays: u64,
    /// The coherence check kept no records: the predicted gain was below 1.
    pub incoherent: bool,
    /// The coherence check's predicted efficiency over product sampling.
    pub predicted_gain: Option<f32>,
    /// The check saw the map through none of its rays.
    pub blind: bool,
    /// The samples per pixel the records were planned for (`None`: unknown).
    pub planned_spp: Option<u32>,
}

/// Records the render's own cache may hold for `pixels` pixels at `spp` samples per pixel:
/// one per [`SAMPLES_PER_RECORD`] samples, at least the bootstrap's, at most `params`'
/// `max_records` (a checked build also stops at a tenth of the covered pixels).
pub fn record_cap(params: &CacheParams, pixels: u64, spp: u64) -> u32 {
    let wanted = (pixels * spp / SAMPLES_PER_RECORD).max(params.n_startup as u64);
    wanted.min(params.max_records as u64) as u32
}

/// Samples per pixel a product-sampling render of `camera` takes in the part of
/// `time_budget` the cache leaves. The coherence check weighs the records' cost against
/// the samples they will serve, which a budget alone does not say: without this it
/// assumed samples without end, and a 1 s render of hairball at 160x120 spent 0.9 s on
/// records it could not repay. A pixel costs `a + b spp` (its product, anchor and camera
/// ray are 10-20 samples' worth), so pilots at the two spp of [`PILOT_SPP`] over at most
/// [`PILOT_PIXELS`] (at most 1/16 of the view) give `a` and `b`. At 160x120 and 1, 3 and
/// 10 s on hairball, instances and strands the estimate was 0.8-1.3x the samples product
/// sampling reached in the same time, the pilots costing 12-38 ms.
pub fn samples_within(
    scene: &Scene,
    env: &EnvMap,
    camera: &Camera,
    params: &RenderParams,
    time_budget: f64,
    threads: Option<usize>,
) -> Result<u32> {
    let pixels = camera.num_pixels() as f64;
    let scale = ((pixels / 16.0).min(PILOT_PIXELS) / pixels).sqrt();
    // Rounded half to even, as the Python wrapper this replaced did.
    let size = |n: u32| ((n as f64 * scale).round_ties_even() as u32).max(1);
    let pilot = camera.with_resolution(size(camera.width), size(camera.height))?;
    let product = |spp: u32, seed: u64| RenderParams {
        jitter: params.jitter,
        seed,
        ..RenderParams::with(Method::Product, spp)
    };
    let quiet = &mut |_: u64, _: u64| true;
    // A process's first render sets up what later ones reuse (tens of ms on hairball).
    let one = camera.with_resolution(1, 1)?;
    render_with(scene, env, &one, None, &product(1, 0), None, threads, quiet)?;
    let mut seconds = [0.0; 2];
    for (t, spp) in seconds.iter_mut().zip(PILOT_SPP) {
        let start = Instant::now();
        let p = product(spp, params.seed ^ PILOT_SEED);
        render_with(scene, env, &pilot, None, &p, None, threads, quiet)?;
        *t = start.elapsed().as_secs_f64() / pilot.num_pixels() as f64;
    }
    let ([few, many], [t_few, t_many]) = (PILOT_SPP.map(f64::from), seconds);
    // A pixel's own work is at most ~3x its samples' at the larger pilot (12 samples'
    // worth on hairball): the floor keeps a noisy difference from promising endless spp.
    let per_sample = ((t_many - t_few) / (many - few)).max(0.25 * t_many / many);
    let per_pixel = (t_few - few * per_sample).max(0.0);
    let left = (1.0 - CACHE_BUDGET_SHARE) * time_budget.max(0.0) / pixels - per_pixel;
    Ok((left / per_sample).clamp(1.0, (MAX_SPP - 1) as f64) as u32)
}

/// [`super::render`] of method "cv" given no cache (module docs): traces `anchors` through
/// `camera` unless given, builds a cache of [`RenderParams::own_cache`] at them, then
/// renders from them with it. The cache's figures are in the result's
/// [`super::RenderStats::own_cache`]; the build's progress is reported as no samples done,
/// and a `false` stops it.
#[allow(clippy::too_many_arguments)]
pub(super) fn render_with_own_cache(
    scene: &Scene,
    env: &EnvMap,
    camera: &Camera,
    anchors: Option<&GBuffer>,
    params: &RenderParams,
    threads: Option<usize>,
    progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
) -> Result<Rendered> {
    params.validate()?;
    let start = Instant::now();
    let pixels = camera.num_pixels() as u64;
    let frame = Frame::prepare(scene, camera, anchors, true, threads)?;
    let anchors = frame.anchors().expect("traced or given");
    // `spp` at its most stands for "as many as the budget buys".
    let planned = match params.time_budget {
        _ if params.spp < MAX_SPP => Some(params.spp),
        Some(budget) => Some(samples_within(
            scene,
            env,
            camera,
            params,
            budget - start.elapsed().as_secs_f64(),
            threads,
        )?),
        None => None,
    };
    let mut cache_params = CacheParams {
        nearest_hits: false,
        ..params.own_cache
    };
    if let Some(spp) = planned {
        cache_params.max_records = record_cap(&params.own_cache, pixels, spp as u64);
    }
    let cache = VisibilityCache::new(cache_params)?;
    cache.plan_samples(planned);
    let planned_samples = params.spp as u64 * pixels;
    let report = cache.build_from(
        scene,
        anchors,
        params.seed,
        threads,
        params.time_budget.map(|b| CACHE_BUDGET_SHARE * b),
        &mut |_, _| progress(0, planned_samples),
    )?;
    let built = start.elapsed().as_secs_f64();
    let rest = RenderParams {
        time_budget: params.time_budget.map(|b| (b - built).max(1e-3)),
        ..*params
    };
    let mut out = render_with(
        scene,
        env,
        &anchors.camera,
        Some(anchors),
        &rest,
        Some(&cache),
        threads,
        progress,
    )?;
    // The G-buffer's rays are the render's primary rays, its time the cache's; the
    // render's seconds are the call's, the build's included.
    out.stats.primary_rays += frame.primary_rays;
    out.stats.seconds = start.elapsed().as_secs_f64();
    out.stats.first_sample_seconds = out.stats.first_sample_seconds.map(|t| t + built);
    out.stats.own_cache = Some(OwnCacheStats {
        seconds: built,
        records: report.records,
        shadow_rays: report.shadow_rays,
        incoherent: report.incoherent,
        predicted_gain: report.predicted_gain,
        blind: report.blind,
        planned_spp: planned,
    });
    Ok(out)
}

#[cfg(test)]
mod tests;
