//! Method "importance_cache" (survey ch. 6, eq. 6.2): the many-light sum of a VPL set
//! estimated per pixel sample from the importance cache's records near the sample's first
//! hit ([`crate::estimators::importance`]), on the pass layer ([`run_passes`]).
//!
//! A sample's first hit is the many-light renderer's ([`Gatherer::first_hit`]: jittered,
//! the same receiver as methods "vpl" and "vpl_sampled"); its `nearest` records under eq.
//! 6.3 give the distribution matrix, and [`Matrix::estimate`] draws `vpl_samples` lights
//! per row F, U, B, C, weighted by `combine` (eq. 6.6's α-max, the balance heuristic, or
//! one row), tracing a shadow ray only for draws of positive weight. The estimate is
//! unbiased for the set's sum (eq. 6.1) under "alpha_max" and "balance" whatever the
//! records hold: they shape the pdf only.
//!
//! Given no cache it builds one for the view first (its G-buffer through the pixels'
//! centres); `stats["seconds"]` includes that build, `stats["build_seconds"]` is the build
//! alone. Without `direct`, the light VPLs (generation 0) contribute nothing (drawn, they
//! cost no ray) and a cache built here holds the surface VPLs alone.
//!
//! ## Determinism
//! Sample `s` of a pixel is a pure function of `(seed, pixel, s)` and the records: its
//! first hit as the many-light renderer's, its draws from the stream `(seed, pixel, s)`.

use std::ops::Range;
use std::time::Instant;

use glam::DVec3;

use super::estimator::{PassPlan, PixelEstimator, PixelPass, PixelTiming};
use super::output::{RenderOutput, Stats, View};
use super::passes::{run_passes, PassParams};
use super::registry::{MethodInputs, MethodRenderer, MethodSpec};
use crate::camera::{Camera, GBuffer};
use crate::error::{Error, Result};
use crate::estimators::importance::build::ImportanceBuildReport;
use crate::estimators::importance::combine::Combine;
use crate::estimators::importance::records::{ImportanceCache, ImportanceParams, ImportanceState};
use crate::estimators::many_lights::{
    area_rng, Gather, GatherWork, Gatherer, ManyLightParams, Unoccluded, VplSums, MAX_DRAWS,
};
use crate::geometry::Scene;
use crate::lights::envmap::EnvMap;
use crate::lights::vpl::{Vpl, VplSet};
use crate::parallel::with_threads;

/// Lights drawn per row and pixel sample without `vpl_samples`.
pub const DEFAULT_IMPORTANCE_SAMPLES: u32 = 16;

/// Share of a time budget the build of a cache for the view may take.
pub const BUILD_SHARE: f64 = 0.5;

/// What method "importance_cache" reads beyond the cache's own parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImportanceRender {
    /// Samples per pixel, `1..=MAX_SPP` (the most with a time budget).
    pub spp: u32,
    pub seed: u64,
    pub jitter: bool,
    pub direct: bool,
    /// Draws per row and sample, `1..=MAX_DRAWS`.
    pub draws: u32,
    pub combine: Combine,
    /// `λ` of eq. 6.3 in median reaches.
    pub lam: f32,
    pub time_budget: Option<f64>,
}

/// The rays and figures of a band.
#[derive(Default)]
struct BandWork {
    gather: GatherWork,
    /// Draws of positive weight (each one shadow ray, or none for a zero term).
    calls: u64,
}

impl super::estimator::Merge for BandWork {
    fn merge(&mut self, other: Self) {
        self.gather += other.gather;
        self.calls += other.calls;
    }
}

/// The method on the pass layer; also its pass.
struct ImportancePass<'a> {
    gatherer: Gatherer<'a>,
    scene: &'a Scene,
    state: &'a ImportanceState,
    lights: &'a [Vpl],
    disk_area: f32,
    params: ImportanceRender,
    nearest: u32,
    lambda: f32,
}

impl ImportancePass<'_> {
    /// Sample `s` of `pixel`.
    fn sample(&self, pixel: usize, s: u32, work: &mut BandWork) -> DVec3 {
        let (seen, receiver) = self.gatherer.first_hit(pixel, s, &mut work.gather);
        let Some(r) = receiver else {
            return seen;
        };
        let near = self
            .state
            .nearest(r.sp.origin, r.sp.normal, self.nearest, self.lambda);
        let Ok(matrix) = self.state.matrix(near.ids(), self.lights.len()) else {
            return seen;
        };
        let (scene, direct, disk_area) = (self.scene, self.params.direct, self.disk_area);
        let mut rays = 0u64;
        let counters = &mut work.gather.counters;
        // A drawn area light takes a fresh point on it per call (dimensions 3j..3j+2 of
        // the sample's own stream): the estimate stays unbiased for the true light.
        let points = area_rng(self.params.seed, pixel, s);
        let mut area_draws = 0u64;
        let (sum, calls) = matrix.estimate(
            &self.params.combine,
            self.params.draws,
            (self.params.seed, pixel as u64, s as u64),
            |k| {
                let v = &self.lights[k];
                if !direct && v.bounce == 0 {
                    return DVec3::ZERO;
                }
                let connection = if v.kind.is_area() {
                    let d = 3 * area_draws;
                    area_draws += 1;
                    let u = [points.get(d), points.get(d + 1), points.get(d + 2)];
                    v.sample_area(scene, &r, None, u)
                } else {
                    v.connect(&r, None, disk_area)
                };
                match connection {
                    Some(c) => {
                        rays += 1;
                        if scene.occluded1(c.origin, c.direction, c.tmax, counters) {
                            DVec3::ZERO
                        } else {
                            c.value.as_dvec3()
                        }
                    }
                    None => DVec3::ZERO,
                }
            },
        );
        work.gather.shadow_rays += rays;
        work.calls += calls as u64;
        seen + sum
    }
}

impl PixelPass for ImportancePass<'_> {
    type Work = BandWork;
    type Note = ();
    type Sums = VplSums;

    fn shade_pixel(
        &self,
        pixel: usize,
        samples: Range<u32>,
        acc: &mut VplSums,
        work: &mut BandWork,
        _note: &mut (),
    ) -> PixelTiming {
        let start = Instant::now();
        for s in samples {
            let x = self.sample(pixel, s, work);
            acc.add(x, DVec3::INFINITY);
        }
        PixelTiming {
            anchor_ns: 0,
            sample_ns: start.elapsed().as_nanos() as u64,
        }
    }
}

impl PixelEstimator for ImportancePass<'_> {
    type Work = BandWork;
    type Note = ();
    type Sums = VplSums;
    type Pass<'b>
        = ImportancePass<'b>
    where
        Self: 'b;

    fn pass<R>(&self, _plan: &PassPlan, run: impl FnOnce(&ImportancePass<'_>) -> R) -> R {
        run(self)
    }
}

/// An image of method "importance_cache" with its figures.
#[derive(Clone, Debug)]
pub struct ImportanceImage {
    pub width: u32,
    pub height: u32,
    /// Mean radiance per pixel, row-major.
    pub image: Vec<[f32; 3]>,
    /// Per-pixel variance of the mean (infinite with one sample).
    pub variance: Vec<[f32; 3]>,
    pub sample_counts: Vec<u32>,
    pub stats: Stats,
}

/// Renders `camera`'s view of `scene` lit by `cache`'s lights, drawn from its records
/// (module docs). `env` is what misses see with `direct`. Fails, naming the argument, on
/// parameters out of range or a cache of another scene.
#[allow(clippy::too_many_arguments)]
pub fn render_importance(
    scene: &Scene,
    env: &EnvMap,
    camera: &Camera,
    cache: &ImportanceCache,
    params: &ImportanceRender,
    threads: Option<usize>,
    progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
) -> Result<ImportanceImage> {
    crate::error::check_range("vpl_samples", params.draws, 1, MAX_DRAWS)?;
    params.combine.validate()?;
    if !(params.lam.is_finite() && params.lam >= 0.0) {
        return Err(Error::invalid(
            "lam",
            format!("must be finite and >= 0, got {}", params.lam),
        ));
    }
    cache.check_scene(scene)?;
    let start = Instant::now();
    let many = ManyLightParams {
        spp: params.spp,
        seed: params.seed,
        jitter: params.jitter,
        clamp: None,
        direct: params.direct,
        gather: Gather::Full,
        time_budget: params.time_budget,
    };
    many.validate()?;
    camera.check_buffers()?;
    // The gatherer serves first hits only: it is given no VPLs.
    let none = empty_set(cache);
    let unoccluded = Unoccluded::default();
    let state = cache.read();
    let lambda = ImportanceCache::lambda_world(&state, params.lam);
    let mut pass = ImportancePass {
        gatherer: Gatherer::new(scene, env, camera, &none, &many, &unoccluded),
        scene,
        state: &state,
        lights: &cache.lights,
        disk_area: cache.disk_area,
        params: *params,
        nearest: cache.params().nearest,
        lambda,
    };
    with_threads(threads, || {
        let _ = scene.bvh();
    })?;
    let pass_params = PassParams {
        spp: params.spp,
        time_budget: params.time_budget,
        adaptive: false,
        first_spp: None,
    };
    let run = run_passes(
        &mut pass,
        camera.width as usize,
        camera.height as usize,
        &pass_params,
        start,
        threads,
        progress,
    )?;
    let work = &run.total;
    scene.add_counters(work.gather.counters);
    let (image, variance) = run.sums.iter().map(|p| p.estimate(true)).unzip();
    let seconds = start.elapsed().as_secs_f64();
    let mut d = Stats::default();
    d.set("seconds", seconds);
    d.set("render_seconds", seconds);
    d.set("spp", run.min_spp());
    d.set("complete", run.complete);
    d.set("passes", run.passes);
    d.set("samples", run.samples());
    d.set("primary_rays", work.gather.primary_rays);
    d.set("shadow_rays", work.gather.shadow_rays);
    d.set("weighted_draws", work.calls);
    Ok(ImportanceImage {
        width: camera.width,
        height: camera.height,
        image,
        variance,
        sample_counts: run.counts(),
        stats: d,
    })
}

/// A set with `cache`'s disk and fingerprint and no VPLs.
fn empty_set(cache: &ImportanceCache) -> VplSet {
    VplSet {
        vpls: Vec::new(),
        disk_area: cache.disk_area,
        fingerprint: cache.scene,
        stats: Default::default(),
    }
}

/// Builds `cache` over the G-buffer of `camera`'s view through the pixels' centres.
pub fn build_for_view(
    scene: &Scene,
    camera: &Camera,
    cache: &ImportanceCache,
    threads: Option<usize>,
    time_budget: Option<f64>,
    progress: &mut (dyn FnMut(usize, usize) -> bool + Send),
) -> Result<ImportanceBuildReport> {
    let start = Instant::now();
    let gbuffer = with_threads(threads, || GBuffer::render(scene, camera, 0, false, None))??;
    cache.build_from(scene, &gbuffer, threads, start, time_budget, progress)
}

/// What method "importance_cache" reads beside the common parameters, as given (`None`:
/// the default, or the cache's).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ImportanceInputs<'a> {
    /// "alpha_max", "balance", "F", "U", "B" or "C".
    pub combine: Option<&'a str>,
    pub alpha: Option<[f64; 4]>,
    pub lam: Option<f32>,
    pub spacing: Option<u32>,
    pub nearest: Option<u32>,
}

/// The registry's renderer of method "importance_cache".
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ImportanceRenderer;

impl MethodRenderer for ImportanceRenderer {
    fn family(&self) -> &'static str {
        "many_lights"
    }

    fn render(
        &self,
        spec: &MethodSpec,
        inputs: &MethodInputs<'_>,
        progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
    ) -> Result<RenderOutput> {
        let start = Instant::now();
        let View::Camera(camera) = inputs.view else {
            return Err(Error::invalid(
                "gbuffer",
                format!("method {:?} traces its own first hits", spec.name),
            ));
        };
        if inputs.vpls.is_some() && inputs.bounces.is_some() {
            return Err(Error::invalid(
                "bounces",
                "a given VPL set has its own depth; pass bounces=None or trace the set with \
                 depth=bounces",
            ));
        }
        let depth = inputs.bounces_for(spec)?;
        let imp = inputs.importance.unwrap_or_default();
        let p = &inputs.params;
        let (scene, threads) = (inputs.scene, inputs.threads);
        let given = inputs.cache.and_then(|c| c.importance());
        let own;
        let mut build: Option<ImportanceBuildReport> = None;
        let cache = match given {
            Some(c) => {
                if imp.spacing.is_some() || imp.nearest.is_some() {
                    return Err(Error::invalid(
                        "cache",
                        "a given cache has its own spacing and nearest: drop them or the cache",
                    ));
                }
                if let Some(v) = inputs.vpls {
                    if v.vpls != c.lights {
                        return Err(Error::invalid(
                            "vpls",
                            "are not the lights the cache was built over: pass the cache's \
                             lights or none",
                        ));
                    }
                }
                c.check_scene(scene)?;
                c
            }
            None => {
                let defaults = ImportanceParams::DEFAULT;
                let cparams = ImportanceParams {
                    spacing: imp.spacing.unwrap_or(defaults.spacing),
                    nearest: imp.nearest.unwrap_or(defaults.nearest),
                    lam: imp.lam.unwrap_or(defaults.lam),
                    alpha: imp.alpha.unwrap_or(defaults.alpha),
                };
                cparams.validate()?;
                let traced;
                let vpls = match inputs.vpls {
                    Some(v) => v,
                    None => {
                        traced = super::many_lights::default_vpls(
                            scene, inputs.env, camera, p.seed, depth, p.direct, threads,
                        )?;
                        &traced
                    }
                };
                if vpls.fingerprint != scene.geometry_fingerprint() {
                    return Err(Error::invalid(
                        "vpls",
                        "were traced in other geometry: trace them again for this scene",
                    ));
                }
                // Without direct light the light VPLs add nothing: leave them out.
                let used = VplSet {
                    vpls: vpls
                        .vpls
                        .iter()
                        .filter(|v| p.direct || v.bounce >= 1)
                        .copied()
                        .collect(),
                    disk_area: vpls.disk_area,
                    fingerprint: vpls.fingerprint,
                    stats: vpls.stats,
                };
                if used.vpls.is_empty() {
                    return Err(Error::invalid(
                        "vpls",
                        "hold no light the render uses (without direct light, no surface VPL)",
                    ));
                }
                own = ImportanceCache::new(&used, cparams)?;
                let budget = p
                    .time_budget
                    .map(|b| ((b - start.elapsed().as_secs_f64()) * BUILD_SHARE).max(1e-3));
                let mut report = |done: usize, total: usize| progress(done as u64, total as u64);
                build = Some(build_for_view(
                    scene,
                    camera,
                    &own,
                    threads,
                    budget,
                    &mut report,
                )?);
                &own
            }
        };
        let alpha = imp.alpha.unwrap_or(cache.params().alpha);
        let combine = Combine::parse(imp.combine.unwrap_or("alpha_max"), alpha)?;
        let params = ImportanceRender {
            spp: inputs.spp_for(spec),
            seed: p.seed,
            jitter: p.jitter,
            direct: p.direct,
            draws: inputs.vpl_samples.unwrap_or(DEFAULT_IMPORTANCE_SAMPLES),
            combine,
            lam: imp.lam.unwrap_or(cache.params().lam),
            time_budget: p
                .time_budget
                .map(|b| (b - start.elapsed().as_secs_f64()).max(1e-3)),
        };
        let out = render_importance(scene, inputs.env, camera, cache, &params, threads, progress)?;
        let mut d = Stats::default();
        d.set("method", spec.name);
        for (name, value) in out.stats.iter() {
            d.set(name, value.clone());
        }
        let _ = &d;
        d.set("seconds", start.elapsed().as_secs_f64());
        d.set("jitter", params.jitter);
        d.set("direct", params.direct);
        d.set("vpl_samples", params.draws);
        d.set("combine", combine.name());
        d.set("alpha", alpha.to_vec());
        d.set("lam", params.lam);
        d.set("spacing", cache.params().spacing);
        d.set("nearest", cache.params().nearest);
        d.set("vpls", cache.lights.len());
        d.set("records", cache.len());
        d.set("cache_bytes", cache.memory_bytes());
        d.set(
            "row_bytes_per_light_record",
            cache.row_bytes() as f64 / (cache.len() * cache.lights.len()).max(1) as f64,
        );
        d.set("build_seconds", build.map(|b| b.seconds).unwrap_or(0.0));
        d.set("build_pairs", build.map(|b| b.pairs).unwrap_or(0));
        d.set("build_rays", build.map(|b| b.rays).unwrap_or(0));
        d.set("build_complete", build.map(|b| b.complete));
        Ok(RenderOutput {
            width: out.width,
            height: out.height,
            image: out.image,
            variance: out.variance,
            alpha: None,
            sample_counts: out.sample_counts,
            stats: d,
        })
    }
}

#[cfg(test)]
mod tests;
