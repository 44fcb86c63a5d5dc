//! The ambient-occlusion renderers (CAM08 §6.1, Fig. 10) over the per-point maths of
//! [`crate::estimators::ambient`]: the ray-traced reference on the pass layer
//! ([`run_passes`]: one "sample" per pixel, all of its `N` rays), and cache AO, which grows
//! the cache for the view with §6.1's criterion in waves ([`WaveBuilder`], the cache
//! build's shape) and then interpolates every covered pixel.
//!
//! ## Budgets and stopping
//! Both count the time budget from the call's start, the G-buffer included. The reference
//! stops at the first progress report past the budget (about every 0.1 s; a pixel's rays
//! are never cut short, the estimate being stratified over all `N`), cache AO between
//! waves; pixels not reached stay NaN and `stats.complete` says so. A `false` from
//! progress stops either the same way.

use glam::Vec3;
use rayon::prelude::*;
use std::ops::{Deref, DerefMut, Range};
use std::time::Instant;

use super::estimator::{Merge, PassPlan, PixelEstimator, PixelPass, PixelTiming};
use super::passes::{run_passes, PassParams};
use super::sums::PixelSums;
use crate::camera::{Camera, GBuffer};
use crate::error::Result;
use crate::estimators::ambient::{
    cache_ao_at, check_rays, needs_ao_record, reference_ao_at, AoParams,
};
use crate::geometry::bvh::TraversalCounters;
use crate::geometry::Scene;
use crate::parallel::with_threads;
use crate::spatial::waves::{coarse_to_fine_levels, WaveBuilder, WaveTarget};
use crate::visibility::cache::{check_scene_and_budget, CacheState, VisibilityCache};
use crate::visibility::params::CacheParams;
use crate::visibility::record::{Record, RecordRays};

/// What an AO render did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct AoStats {
    /// Pixels of the camera.
    pub pixels: usize,
    /// Pixels whose primary ray hit something (the shading points).
    pub covered_pixels: usize,
    /// Covered pixels that got a value (cache: some record within reach; reference: traced
    /// before the time budget ran out).
    pub resolved_pixels: usize,
    /// AO shadow rays this call traced (cache: record rays, including discarded records).
    pub shadow_rays: u64,
    /// Closest-hit rays this call traced for `R_i` (0 for the reference).
    pub nearest_rays: u64,
    /// `(shadow_rays + nearest_rays) / covered_pixels`; primary rays are not counted.
    pub rays_per_point: f64,
    /// Records in the cache afterwards (0 for the reference).
    pub records: usize,
    /// Records this call inserted.
    pub records_inserted: usize,
    /// Records traced but found unneeded on re-check (their rays are counted).
    pub records_discarded: usize,
    /// Wall-clock seconds of the whole call (G-buffer included).
    pub seconds: f64,
    /// Seconds of the cache build (0 for the reference).
    pub build_seconds: f64,
    /// False when the time budget or the progress callback stopped the work early.
    pub complete: bool,
}

/// An AO image and how it was made.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AoImage {
    /// Image width, pixels.
    pub width: u32,
    /// Image height, pixels.
    pub height: u32,
    /// Row-major `A` in `[0, 1]`; NaN where the primary ray hit nothing or no value was
    /// computed (see [`AoStats::resolved_pixels`]).
    pub ao: Vec<f32>,
    /// Figures of the run.
    pub stats: AoStats,
}

impl AoImage {
    /// `camera`'s image with no pixel resolved yet (all NaN).
    fn unresolved(camera: &Camera) -> Self {
        AoImage {
            width: camera.width,
            height: camera.height,
            ao: vec![f32::NAN; camera.num_pixels()],
            stats: AoStats {
                pixels: camera.num_pixels(),
                complete: true,
                ..AoStats::default()
            },
        }
    }
}

/// A pixel of the reference: shaded once, with all of its rays.
#[derive(Clone, Copy, Debug, Default)]
struct ReferenceSum {
    shaded: bool,
    /// `Â`; NaN where the primary ray hit nothing.
    ao: f32,
}

impl PixelSums for ReferenceSum {
    fn samples(&self) -> u32 {
        self.shaded as u32
    }
}

/// What a band of the reference traced.
#[derive(Default)]
struct ReferenceWork {
    counters: TraversalCounters,
    shadow_rays: u64,
}

impl Merge for ReferenceWork {
    fn merge(&mut self, other: Self) {
        self.counters += other.counters;
        self.shadow_rays += other.shadow_rays;
    }
}

/// The reference as a pass-layer method: `rays` stratified rays per covered pixel
/// ([`reference_ao_at`]), a pure function of `(seed, pixel)`.
struct ReferenceAo<'a> {
    scene: &'a Scene,
    g: &'a GBuffer,
    rays: u32,
    seed: u64,
}

impl PixelPass for ReferenceAo<'_> {
    type Work = ReferenceWork;
    type Note = ();
    type Sums = ReferenceSum;

    fn shade_pixel(
        &self,
        pixel: usize,
        _samples: Range<u32>,
        acc: &mut ReferenceSum,
        work: &mut ReferenceWork,
        _note: &mut (),
    ) -> PixelTiming {
        let start = Instant::now();
        acc.shaded = true;
        acc.ao = f32::NAN;
        if self.g.object[pixel] >= 0 {
            acc.ao = reference_ao_at(
                self.scene,
                Vec3::from(self.g.position[pixel]),
                Vec3::from(self.g.normal[pixel]),
                self.rays,
                self.seed,
                pixel as u64,
                &mut work.counters,
            );
            work.shadow_rays += self.rays as u64;
        }
        PixelTiming {
            anchor_ns: 0,
            sample_ns: start.elapsed().as_nanos() as u64,
        }
    }
}

impl PixelEstimator for ReferenceAo<'_> {
    type Work = ReferenceWork;
    type Note = ();
    type Sums = ReferenceSum;
    type Pass<'b>
        = ReferenceAo<'b>
    where
        Self: 'b;

    fn pass<R>(&self, _plan: &PassPlan, run: impl FnOnce(&ReferenceAo<'_>) -> R) -> R {
        run(self)
    }
}

/// Ray-traced AO with `rays` rays per shading point. `progress(done, total)` (pixels) is
/// called about every 0.1 s and at the end; returning false stops, as does `time_budget`
/// (seconds, module docs); pixels not reached stay NaN.
pub fn render_reference_ao(
    scene: &Scene,
    camera: &Camera,
    rays: u32,
    seed: u64,
    threads: Option<usize>,
    time_budget: Option<f64>,
    progress: &mut (dyn FnMut(usize, usize) -> bool + Send),
) -> Result<AoImage> {
    check_rays(rays)?;
    check_scene_and_budget(scene, time_budget)?;
    let start = Instant::now();
    let g = GBuffer::render(scene, camera, seed, false, threads)?;
    reference_ao_at_gbuffer(scene, &g, rays, seed, threads, start, time_budget, progress)
}

/// [`render_reference_ao`] at the hits of `gbuffer` (which must describe `scene` as posed
/// now), through its camera.
pub fn render_reference_ao_from(
    scene: &Scene,
    gbuffer: &GBuffer,
    rays: u32,
    seed: u64,
    threads: Option<usize>,
    time_budget: Option<f64>,
    progress: &mut (dyn FnMut(usize, usize) -> bool + Send),
) -> Result<AoImage> {
    check_rays(rays)?;
    check_scene_and_budget(scene, time_budget)?;
    gbuffer.check(scene, None)?;
    let start = Instant::now();
    reference_ao_at_gbuffer(
        scene,
        gbuffer,
        rays,
        seed,
        threads,
        start,
        time_budget,
        progress,
    )
}

#[allow(clippy::too_many_arguments)]
fn reference_ao_at_gbuffer(
    scene: &Scene,
    g: &GBuffer,
    rays: u32,
    seed: u64,
    threads: Option<usize>,
    start: Instant,
    time_budget: Option<f64>,
    progress: &mut (dyn FnMut(usize, usize) -> bool + Send),
) -> Result<AoImage> {
    let mut image = AoImage::unresolved(&g.camera);
    with_threads(threads, || {
        let _ = scene.bvh();
    })?;
    let mut method = ReferenceAo {
        scene,
        g,
        rays,
        seed,
    };
    // One pass of one "sample" per pixel; the budget stops it like a progress report
    // would, never within a pixel's rays.
    let params = PassParams {
        spp: 1,
        time_budget: None,
        adaptive: false,
        first_spp: None,
    };
    let mut report = |done: u64, total: u64| {
        let over = time_budget.is_some_and(|b| start.elapsed().as_secs_f64() >= b);
        progress(done as usize, total as usize) && !(over && done < total)
    };
    let (width, height) = (g.camera.width as usize, g.camera.height as usize);
    let run = run_passes(
        &mut method,
        width,
        height,
        &params,
        start,
        threads,
        &mut report,
    )?;
    scene.add_counters(run.total.counters);
    let s = &mut image.stats;
    for (i, p) in run.sums.iter().enumerate() {
        if g.object[i] >= 0 {
            s.covered_pixels += 1;
            if p.shaded {
                s.resolved_pixels += 1;
                image.ao[i] = p.ao;
            }
        }
    }
    s.complete = s.resolved_pixels == s.covered_pixels;
    s.shadow_rays = run.total.shadow_rays;
    s.rays_per_point = s.shadow_rays as f64 / s.covered_pixels.max(1) as f64;
    s.seconds = start.elapsed().as_secs_f64();
    Ok(image)
}

/// Cache AO (§6.1): grows `cache` for the view with the §6.1 criterion (module docs), then
/// interpolates every covered pixel. Records already in `cache` are used and kept.
/// Deterministic for any `threads`. `progress(done, total)` (covered pixels) is called after
/// every wave; returning false stops the build, as does `time_budget` (seconds, checked
/// between waves); the image is then made from the records so far.
#[allow(clippy::too_many_arguments)]
pub fn render_cache_ao(
    scene: &Scene,
    camera: &Camera,
    cache: &VisibilityCache,
    ao: &AoParams,
    seed: u64,
    threads: Option<usize>,
    time_budget: Option<f64>,
    progress: &mut (dyn FnMut(usize, usize) -> bool + Send),
) -> Result<AoImage> {
    ao.validate()?;
    check_scene_and_budget(scene, time_budget)?;
    cache.bind_scene(scene)?;
    let start = Instant::now();
    let g = GBuffer::render(scene, camera, seed, false, threads)?;
    cache_ao_at_gbuffer(scene, &g, cache, ao, threads, start, time_budget, progress)
}

/// [`render_cache_ao`] at the hits of `gbuffer` (which must describe `scene` as posed
/// now), through its camera: with the buffer a cache was built from, the points its
/// records were placed for.
#[allow(clippy::too_many_arguments)]
pub fn render_cache_ao_from(
    scene: &Scene,
    gbuffer: &GBuffer,
    cache: &VisibilityCache,
    ao: &AoParams,
    threads: Option<usize>,
    time_budget: Option<f64>,
    progress: &mut (dyn FnMut(usize, usize) -> bool + Send),
) -> Result<AoImage> {
    ao.validate()?;
    check_scene_and_budget(scene, time_budget)?;
    gbuffer.check(scene, None)?;
    cache.bind_scene(scene)?;
    let start = Instant::now();
    cache_ao_at_gbuffer(
        scene,
        gbuffer,
        cache,
        ao,
        threads,
        start,
        time_budget,
        progress,
    )
}

#[allow(clippy::too_many_arguments)]
fn cache_ao_at_gbuffer(
    scene: &Scene,
    g: &GBuffer,
    cache: &VisibilityCache,
    ao: &AoParams,
    threads: Option<usize>,
    start: Instant,
    time_budget: Option<f64>,
    progress: &mut (dyn FnMut(usize, usize) -> bool + Send),
) -> Result<AoImage> {
    let before = cache.counters();
    let params = *cache.params();
    let camera = &g.camera;
    let mut image = AoImage::unresolved(camera);
    with_threads(threads, || -> Result<()> {
        let query = |i: u32| {
            let i = i as usize;
            (
                Vec3::from(g.position[i]),
                Vec3::from(g.normal[i]),
                g.footprint[i],
            )
        };
        let total = g.object.iter().filter(|&&o| o >= 0).count();
        image.stats.covered_pixels = total;
        let levels = coarse_to_fine_levels(camera.width, camera.height)
            .into_iter()
            .map(|level| level.into_iter().filter(|&i| g.object[i as usize] >= 0));
        let target = AoRefine {
            cache,
            scene,
            params: &params,
            ao,
            query: &query,
        };
        let waves = WaveBuilder::new(start, time_budget, progress).run(&target, levels, total)?;
        image.stats.records_inserted += waves.inserted;
        image.stats.records_discarded += waves.discarded;
        image.stats.complete = waves.complete;
        image.stats.build_seconds = start.elapsed().as_secs_f64();
        let state = cache.read();
        let values: Vec<Option<f32>> = (0..g.object.len())
            .into_par_iter()
            .with_min_len(256)
            .map(|i| {
                if g.object[i] < 0 {
                    return None;
                }
                let (x, n, f) = query(i as u32);
                cache_ao_at(&state, &params, ao, x, n, f)
            })
            .collect();
        for (px, v) in image.ao.iter_mut().zip(&values) {
            if let Some(a) = v {
                *px = *a;
                image.stats.resolved_pixels += 1;
            }
        }
        Ok(())
    })??;
    let after = cache.counters();
    let s = &mut image.stats;
    s.records = cache.len();
    s.shadow_rays = after.shadow_rays - before.shadow_rays;
    s.nearest_rays = after.nearest_rays - before.nearest_rays;
    s.rays_per_point = (s.shadow_rays + s.nearest_rays) as f64 / s.covered_pixels.max(1) as f64;
    s.seconds = start.elapsed().as_secs_f64();
    Ok(image)
}

/// The cache as [`WaveBuilder`] grows it for AO: §6.1's criterion ([`needs_ao_record`])
/// at the points `query(i) = (position, unit normal, footprint)`.
struct AoRefine<'a, Q> {
    cache: &'a VisibilityCache,
    scene: &'a Scene,
    params: &'a CacheParams,
    ao: &'a AoParams,
    query: Q,
}

impl<Q: Fn(u32) -> (Vec3, Vec3, f32) + Sync> WaveTarget for AoRefine<'_, Q> {
    type State = CacheState;
    type Record = (Record, RecordRays);

    fn read(&self) -> impl Deref<Target = CacheState> + '_ {
        self.cache.read()
    }

    fn write(&self) -> impl DerefMut<Target = CacheState> + '_ {
        self.cache.write()
    }

    fn records(&self) -> usize {
        self.cache.len()
    }

    fn point(&self, i: u32) -> (Vec3, Vec3, f32) {
        let (x, n, f) = (self.query)(i);
        (x, n, self.params.d_max_scale * f)
    }

    fn cos_max(&self) -> f32 {
        self.params.theta_max().cos()
    }

    fn wants(&self, state: &CacheState, i: u32) -> bool {
        let (x, n, f) = (self.query)(i);
        let nearest = state.nearest(self.params, x, n, self.params.d_max_scale * f);
        needs_ao_record(state, self.ao, &nearest, self.ao.min_radius_scale * f)
    }

    fn make(&self, i: u32) -> Result<(Record, RecordRays)> {
        let (x, n, _) = (self.query)(i);
        self.cache.trace(self.scene, x, n)
    }

    fn insert(
        &self,
        state: &mut CacheState,
        i: u32,
        (record, rays): &(Record, RecordRays),
    ) -> Result<bool> {
        let id = state.insert_traced_if(self.params, record, *rays, |s| self.wants(s, i))?;
        Ok(id.is_some())
    }
}

#[cfg(test)]
mod tests;
