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
//! [`crate::visibility::cache::VisibilityCache::build`] (the same
//! [`crate::spatial::waves::WaveBuilder`], with §6.1's insertion test; the renderers are
//! in [`crate::render::ambient`]): pixels coarse to fine ([`crate::spatial::waves::coarse_to_fine_levels`]); a wave looks
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

use crate::error::{Error, Result};
use crate::geometry::Scene;
use crate::sampling::rng::SampleRng;
use crate::visibility::cache::nearest::Nearest;
use crate::visibility::cache::{check_scene_and_budget, CacheState};
use crate::visibility::params::CacheParams;

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

/// `max_i [w_i · (1 − d_i / max(R_i, r_min))]` over the candidates (0 when none): §6.1's
/// coverage of a point by the cache ([`crate::spatial::coverage`]: a record covers nothing
/// at or beyond its radius, even when the radius is 0, a record in a corner, and the point
/// its own; an infinite radius gives the factor 1). `r_min` is the clamp of `R_i`, world
/// units.
pub fn coverage(state: &CacheState, nearest: &Nearest, r_min: f32) -> f32 {
    crate::spatial::coverage(nearest.candidates().iter().map(|c| {
        let header = state.store().header(c.id as usize);
        (c.weight, c.distance, header.nearest_hit_distance.max(r_min))
    }))
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

/// Fails naming `reference_rays` unless `1 <= rays <= MAX_AO_RAYS`.
pub(crate) fn check_rays(rays: u32) -> Result<()> {
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

#[cfg(test)]
pub(crate) mod tests;
