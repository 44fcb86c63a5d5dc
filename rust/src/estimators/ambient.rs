//! Ambient occlusion from the visibility cache, and its ray-traced reference
//! (CAM08 §6.1, eq. 12, Fig. 10).
//!
//! Ambient occlusion here is eq. 12 divided by π: the cosine-weighted visible fraction
//! `A(x) = (1/π) ∫_Ω V(x, ω) (n·ω) dω` in `[0, 1]` (1 = nothing occludes), exactly what every
//! record stores (`A_i = Σ V cos / Σ cos` over its pattern directions above the plane).
//! Shading points are the G-buffer's first hits through pixel centres, one per pixel.
//!
//! ## From the cache (§6.1)
//! At a point `x` (unit normal `n`, pixel footprint `f`, world units) take the `m` nearest
//! records within `d_max = k·f` with `θ_i < θ_max` ([`CacheState::nearest`]: the candidate
//! set of the §5.1 lookup, but all `m`, not the `n` best) and average their `A_i` with
//! weights
//!
//! `g_i = exp(−d_i² / (2σ²)) · (1 − θ_i/π) · w_g,i`,  `σ = s·f`,
//!
//! the Gaussian of the paper with its width from the projected pixel, times eq. 9's normal
//! factor and Fig. 7's geometric factor `w_g = sqrt(1 − |n·v|)` (which lowers records in
//! front of or behind `x`, as it does for lookups). `s` is [`AoParams::sigma_scale`]; its
//! default was chosen by measurement on `garage` (see [`DEFAULT_SIGMA_SCALE`]).
//!
//! A record is inserted at `x` when `max_i [w_i · (1 − d_i / R_i)] < w_min` (§6.1's
//! criterion, with [`AoParams::w_min`], its own threshold, not the cache's §5.2 one), `w_i`
//! the eq. 9 weight of the lookup, `R_i` the record's distance to its nearest hit (`∞`
//! gives the factor 1; the factor is clamped at 0 when `d_i > R_i`). The §5.2
//! visibility-difference criterion is not used: §6.1 replaces it by `R_i`. Departure:
//! `R_i` is clamped below at `r·f` ([`AoParams::min_radius_scale`] footprints of the query
//! pixel), as irradiance caches clamp their radii in screen space [TL04]. Unclamped, a
//! record in a crease (`R_i → 0`) serves almost nobody: on `garage` at 128x96 the paper's
//! criterion took 7x the records and rays of the default clamp (1947 vs 279 records) for
//! RMSE 3.4% instead of 4.5% of the mean (`viscache experiment ao --quick`).
//!
//! The build is deterministic for any thread count, in waves like
//! [`VisibilityCache::build`] (the same [`WaveBuilder`], with §6.1's insertion test): pixels coarse to fine ([`coarse_to_fine_levels`]); a wave looks
//! up in parallel, traces its requests in parallel, then inserts them in pixel order,
//! re-checking each against the records inserted before it. Requests closer than
//! `d_max / 2` to an earlier request of their wave (normals within `θ_max`) wait for the
//! next wave. No bootstrap: the coarsest level (every 32nd pixel) plays its part.
//!
//! ## Reference
//! `N` rays per point, cosine-weighted (Shirley–Chiu concentric map) over a jittered
//! `c x r = N` grid (`c` the largest divisor of `N` not above `√N`, so the cells tile the
//! square for any `N`), jitter from `(seed, pixel, sample, DIM_AO)`; shadow rays leave from
//! `scene.offset_point`. `Â = (1/N) Σ V(ω_k)` is unbiased for eq. 12/π: each `ω_k` is
//! distributed with pdf `cos/π` over its cell's image and the cells have equal measure.

use glam::Vec3;
use rayon::prelude::*;
use std::ops::{Deref, DerefMut};
use std::time::Instant;

use crate::camera::{Camera, GBuffer};
use crate::error::{Error, Result};
use crate::geometry::Scene;
use crate::parallel::with_threads;
use crate::sampling::rng::SampleRng;
use crate::spatial::waves::{coarse_to_fine_levels, WaveBuilder, WaveTarget};
use crate::visibility::cache::nearest::Nearest;
use crate::visibility::cache::{check_scene_and_budget, CacheState, VisibilityCache};
use crate::visibility::params::CacheParams;
use crate::visibility::record::{Record, RecordRays};

/// Random dimensions of a reference AO ray (dimensions 0–1 belong to the pixel jitter).
pub const DIM_AO: u64 = 2;
/// Most reference rays per point.
pub const MAX_AO_RAYS: u32 = 1 << 16;
/// Default `s` of `σ = s·footprint`. The three defaults were chosen together on `garage` at
/// 256x192 (medium preset, 32x32 records, `k = 12`) against a 1024-ray reference, sweeping
/// `s` in {2, 2.5, 3, 4, 6}, `r` in {4, 10, 20, 40, 60, 1000} and `w_min` in {0.3 … 0.5} for
/// the least RMSE at ≥ 50x fewer rays: `s = 3, r = 40, w_min = 0.45` gave 59x fewer rays
/// at RMSE 2.9% of the mean (the reference's own noise is 1.1%). Narrower Gaussians show
/// each record's quadrature error as blotches; wider ones blur contact shadows.
pub const DEFAULT_SIGMA_SCALE: f32 = 3.0;
/// Default `r` of the `R_i >= r·footprint` clamp (see [`DEFAULT_SIGMA_SCALE`]). At 40 (over
/// three times `k`), `R_i` lowers a weight by at most 30%: the unclamped criterion (`r = 0`)
/// put records in every crease of `garage` at several times the rays for little accuracy.
pub const DEFAULT_MIN_RADIUS_SCALE: f32 = 40.0;
/// Default `w_min` of §6.1's criterion (see [`DEFAULT_SIGMA_SCALE`]).
pub const DEFAULT_AO_W_MIN: f32 = 0.45;
/// Rays per step of the reference render: progress, Ctrl-C and the time budget are checked
/// between steps (about 0.1 s of work on two cores), and results do not depend on it.
const REFERENCE_STEP_RAYS: usize = 1 << 19;

/// Points per step of the reference render at `rays` rays per point.
fn reference_step_points(rays: u32) -> usize {
    (REFERENCE_STEP_RAYS / rays.max(1) as usize).clamp(8, 4096)
}

/// Parameters of cache AO on top of the cache's own.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AoParams {
    /// `s > 0`: the Gaussian's `σ` is `s` pixel footprints (world units at the point).
    pub sigma_scale: f32,
    /// `r >= 0`: `R_i` is clamped below at `r` footprints of the query pixel (0: the paper's
    /// unclamped criterion; `+inf`: `R_i` ignored, plain `max w_i < w_min`).
    pub min_radius_scale: f32,
    /// `w_min` of §6.1's criterion, in `[0, 1]`. Separate from the cache's §5.2 `w_min`
    /// (which steers lookups for rendering), so one cache serves both.
    pub w_min: f32,
}

impl Default for AoParams {
    fn default() -> Self {
        Self {
            sigma_scale: DEFAULT_SIGMA_SCALE,
            min_radius_scale: DEFAULT_MIN_RADIUS_SCALE,
            w_min: DEFAULT_AO_W_MIN,
        }
    }
}

impl AoParams {
    /// Checks the ranges; the error names the parameter.
    pub fn validate(&self) -> Result<()> {
        if !(self.sigma_scale.is_finite() && self.sigma_scale > 0.0) {
            return Err(Error::invalid(
                "sigma_scale",
                format!("must be finite and > 0, got {}", self.sigma_scale),
            ));
        }
        if self.min_radius_scale.is_nan() || self.min_radius_scale < 0.0 {
            return Err(Error::invalid(
                "min_radius_scale",
                format!("must be >= 0, got {}", self.min_radius_scale),
            ));
        }
        if !(0.0..=1.0).contains(&self.w_min) {
            return Err(Error::invalid(
                "w_min",
                format!("must lie in [0, 1], got {}", self.w_min),
            ));
        }
        Ok(())
    }
}

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

/// `max_i [w_i · (1 − d_i / max(R_i, r_min))]` over the candidates (0 when none): §6.1's
/// coverage of a point by the cache. `r_min` is the clamp of `R_i`, world units.
pub fn coverage(state: &CacheState, nearest: &Nearest, r_min: f32) -> f32 {
    nearest
        .candidates()
        .iter()
        .map(|c| {
            let r = state
                .store()
                .header(c.id as usize)
                .nearest_hit_distance
                .max(r_min);
            // A record covers nothing at or beyond its radius, even when the radius is 0
            // (a record in a corner) and the point its own.
            let factor = if !r.is_finite() {
                1.0
            } else if c.distance < r {
                1.0 - c.distance / r
            } else {
                0.0
            };
            c.weight * factor
        })
        .fold(0.0, f32::max)
}

/// §6.1: does a point with these candidates need a record of its own?
pub fn needs_ao_record(state: &CacheState, ao: &AoParams, nearest: &Nearest, r_min: f32) -> bool {
    coverage(state, nearest, r_min) < ao.w_min
}

/// Cache AO from candidates: `Σ g_i A_i / Σ g_i` with `σ` in world units (module docs);
/// `None` when there are none or every weight is 0.
pub fn interpolate_ao(state: &CacheState, nearest: &Nearest, sigma: f32) -> Option<f32> {
    let inv = 1.0 / (2.0 * sigma as f64 * sigma as f64);
    let (mut sum, mut total) = (0.0f64, 0.0f64);
    for c in nearest.candidates() {
        let d = c.distance as f64;
        let g = (-d * d * inv).exp()
            * (1.0 - c.theta as f64 / std::f64::consts::PI)
            * c.geometric as f64;
        sum += g * state.store().header(c.id as usize).ambient_occlusion() as f64;
        total += g;
    }
    (total > 0.0).then(|| (sum / total) as f32)
}

/// Cache AO at `x` (unit normal `n`) for a pixel of footprint `footprint` (world units).
pub fn cache_ao_at(
    state: &CacheState,
    params: &CacheParams,
    ao: &AoParams,
    x: Vec3,
    n: Vec3,
    footprint: f32,
) -> Option<f32> {
    let nearest = state.nearest(params, x, n, params.d_max_scale * footprint);
    interpolate_ao(state, &nearest, ao.sigma_scale * footprint)
}

/// `(c, r)` with `c · r = n`, `c` the largest divisor of `n` not above `√n`.
fn grid(n: u32) -> (u32, u32) {
    let mut c = (n as f64).sqrt() as u32;
    while c > 1 && !n.is_multiple_of(c) {
        c -= 1;
    }
    let c = c.max(1);
    (c, n / c)
}

/// Shirley–Chiu concentric map of `[0,1)^2` onto the unit disk (area-preserving, so cells
/// stay equal-area).
fn concentric_disk(u: f32, v: f32) -> (f32, f32) {
    let (a, b) = (2.0 * u - 1.0, 2.0 * v - 1.0);
    if a == 0.0 && b == 0.0 {
        return (0.0, 0.0);
    }
    let q = std::f32::consts::FRAC_PI_4;
    if a.abs() > b.abs() {
        let phi = q * (b / a);
        (a * phi.cos(), a * phi.sin())
    } else {
        let phi = 2.0 * q - q * (a / b);
        (b * phi.cos(), b * phi.sin())
    }
}

/// Reference AO at one point: `rays` cosine-weighted stratified shadow rays (module docs),
/// random numbers from `(seed, pixel, k, DIM_AO)`. `n` must be unit.
pub fn reference_ao_at(
    scene: &Scene,
    x: Vec3,
    n: Vec3,
    rays: u32,
    seed: u64,
    pixel: u64,
    counters: &mut crate::geometry::bvh::TraversalCounters,
) -> f32 {
    let (cols, rows) = grid(rays);
    let (t, b) = n.any_orthonormal_pair();
    let origin = scene.offset_point(x, n);
    let mut visible = 0u32;
    for k in 0..rays {
        let [j0, j1] = SampleRng::new(seed, pixel, k as u64).get2(DIM_AO);
        let u = ((k % cols) as f32 + j0) / cols as f32;
        let v = ((k / cols) as f32 + j1) / rows as f32;
        let (dx, dy) = concentric_disk(u.min(1.0 - f32::EPSILON), v.min(1.0 - f32::EPSILON));
        let dz = (1.0 - dx * dx - dy * dy).max(0.0).sqrt();
        let d = (t * dx + b * dy + n * dz).normalize();
        visible += !scene.occluded1(origin, d, f32::INFINITY, counters) as u32;
    }
    visible as f32 / rays as f32
}

fn check_rays(rays: u32) -> Result<()> {
    if rays == 0 || rays > MAX_AO_RAYS {
        return Err(Error::invalid(
            "reference_rays",
            format!("must be between 1 and {MAX_AO_RAYS}, got {rays}"),
        ));
    }
    Ok(())
}

/// Reference AO at arbitrary points (unit `normals`; point `i` draws from "pixel" `i`).
/// Deterministic for any `threads`.
pub fn reference_ao_points(
    scene: &Scene,
    points: &[Vec3],
    normals: &[Vec3],
    rays: u32,
    seed: u64,
    threads: Option<usize>,
) -> Result<Vec<f32>> {
    check_rays(rays)?;
    check_scene_and_budget(scene, None)?;
    if normals.len() != points.len() {
        return Err(Error::invalid(
            "normals",
            format!(
                "expected {} like points, got {}",
                points.len(),
                normals.len()
            ),
        ));
    }
    scene.map_rays(points.len(), threads, |i, c| {
        reference_ao_at(scene, points[i], normals[i], rays, seed, i as u64, c)
    })
}

/// Ray-traced AO with `rays` rays per shading point. `progress(done, total)` (covered
/// pixels) is called after every step; returning false stops, as does `time_budget`
/// (seconds); pixels not reached stay NaN.
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
    with_threads(threads, || -> Result<()> {
        let covered: Vec<usize> = (0..g.object.len()).filter(|&i| g.object[i] >= 0).collect();
        image.stats.covered_pixels = covered.len();
        let mut done = 0;
        for step in covered.chunks(reference_step_points(rays)) {
            let values = scene.map_rays(step.len(), None, |k, c| {
                let i = step[k];
                reference_ao_at(
                    scene,
                    Vec3::from(g.position[i]),
                    Vec3::from(g.normal[i]),
                    rays,
                    seed,
                    i as u64,
                    c,
                )
            })?;
            for (&i, v) in step.iter().zip(values) {
                image.ao[i] = v;
            }
            done += step.len();
            let over = time_budget.is_some_and(|b| start.elapsed().as_secs_f64() >= b);
            if !progress(done, covered.len()) || (over && done < covered.len()) {
                image.stats.complete = done == covered.len();
                break;
            }
        }
        image.stats.resolved_pixels = done;
        image.stats.shadow_rays = done as u64 * rays as u64;
        Ok(())
    })??;
    let s = &mut image.stats;
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
