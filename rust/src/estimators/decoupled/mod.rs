//! Decoupled visibility with an error bound, and relighting that reuses visibility (SBF:
//! Schwenk, Behr & Fellner, "An Error Bound for Decoupled Visibility with Application to
//! Relighting").
//!
//! Direct light from one light at a shading point is `L_o = ∫ LB V` (SBF eq. 2), with
//! `LB = L f cos` and binary visibility `V`. SBF replaces `V` by the scalar `V̂ = E_p[V]`,
//! the expected visibility of the samples drawn for `LB` with density `p`, so that
//! `L_o ≈ ∫ LB · V̂` (eq. 3). The error is `Err = Cov(LB/p, V)` (eq. 4-5), bounded by
//! `sqrt(Var(LB/p) Var(V))` (eq. 7, [`bound::error_bound`]). Once `V̂` has converged, a
//! lighting or material edit needs only cheap `LB` samples (no rays) to estimate
//! `⟨LB⟩ V̂`, and the bound decides per pixel how much of it to trust: the blend
//! `(1 − t)⟨LBV⟩ + t⟨LB⟩⟨V⟩` (eq. 9) with `t` from the relative bound against the user's
//! threshold (eq. 10-11, [`bound::blend_factor`]).
//!
//! ## Lights and densities
//! Every area light is one light, sampled by area (its `p` does not depend on its
//! radiance or on materials), and the environment map is one light sampled by the pixel's
//! product distribution `p ∝ L B~` (CAM08 §5.5), which changes with the map and the
//! material. Draws where `LB` is zero by geometry (below the surface's horizon, the back
//! of a light) trace no ray and are left out of `⟨V⟩`: `V̂` is `E_p[V | LB > 0]`, which is
//! `E_p[V]` for `V` set to that same value where `LB = 0` (where `V` does not change
//! `∫ LB V`), so eq. 5 holds and the binary variance over-estimates `Var(V)` (the bound
//! stays a bound). A point in the open gets `V̂ = 1` and a bound of 0.
//!
//! ## Where `⟨V⟩` comes from
//! - [`VisibilitySource::Pixels`]: [`Relighter::converge_visibility`] traces `V`-samples at
//!   every pixel's point and keeps, per pixel and light, their counts (for binary `V`,
//!   its moments) and the bits of the first [`REWEIGHT_SPP`]: 32 bytes, SBF's 8 floats.
//!   While a light's `p` is unchanged `⟨V⟩` is their mean; after an edit that
//!   changes the map's `p` (another map, a rotation, another material) the samples with
//!   bits are reweighted by `p'/p` (self-normalised importance sampling; the effective
//!   sample count `(Σw)²/Σw²` is reported), with no ray traced.
//! - [`VisibilitySource::Cache`]: `⟨V⟩ = E_p'[Ṽ]` with `Ṽ = Σ β_i V_i` the visibility
//!   cache's interpolated records (CAM08 eq. 9 weights), summed over the product's cells
//!   against their probabilities (no ray traced, no draw; the within-cell density is taken
//!   as uniform over the records' texels), so the points, hence the view, may change between renders
//!   (SBF §4.1 names world-space storage as the way to allow it). A record's rays find an
//!   area light's own triangles and mark its directions blocked, as the map's visibility
//!   needs; area lights read instead a second cache whose records count a ray that
//!   reaches a light as unoccluded ([`crate::visibility::CacheParams::emitters_visible`]):
//!   `⟨V⟩ = E_p[Ṽ]` over [`CACHED_AREA_DRAWS`] draws of the light's density, each reading
//!   the records' bits at its direction (no ray). Without that cache, area lights keep
//!   the unbiased `⟨LBV⟩` in this mode. Measured on SBF's case (the Cornell box, a
//!   light's texture switched; `viscache experiment relight`, 160x120, 2026-11-28): the
//!   bound holds on 95.2% of pixels, but the interpolated `⟨V⟩` is off where the blocks'
//!   shadows fall between records, and at threshold 0.25 the first frame has 3.7x the
//!   relMSE of `⟨LBV⟩` alone given its seconds (pixel visibility with its reused
//!   samples: 0.35x); so the relighter takes that cache only when given one.
//!
//! `Var(V)` is the binary variance `⟨V⟩(1 − ⟨V⟩)` in both cases. The bound adds the error of
//! `⟨V⟩` itself, carried by `⟨LB⟩⟨V⟩`: [`V_ERROR_SIGMAS`] times its standard error (pixels),
//! or times the spread `sqrt(Σ β_i (E_p'[V_i] − E_p'[Ṽ])² / Σ β_i)` of the records that
//! `Ṽ` blends (cache): where they agree the interpolation is trusted, where they differ
//! (a shadow's edge between records) the bound widens.
//! Reweighted samples also miss the part of `p'` that `p` never drew (a sun turned to
//! where the old map was dark): its share, estimated as `1 − Σw/n` (the weights' mean is
//! 1 when `p` covers `p'`), may hold any visibility, so the bound adds that share times
//! `max(⟨V⟩, 1 − ⟨V⟩)`. The effective sample count does not see this: the samples that
//! kept weight agree with each other. Without the term the bound held on 79-82% of
//! pixels after a map rotation or swap; with it, on 96-100% (`viscache experiment
//! relight`, 2026-11-26, seventh session).
//!
//! ## Stored samples as `LBV`-samples
//! A stored `V`-sample is a draw of the density it was converged under with its `V` known.
//! Redrawn (the same numbers give the same direction or point), it is an `LBV`-sample of
//! the lighting now at no ray's cost: `LB'V/p₁`, unbiased wherever `p₁` covers `LB'`.
//! [`RelightParams::reuse`] adds them to the unbiased part by the balance heuristic (Veach
//! 1997, §9.2) with the `n₂ = lbv_spp` draws of the current density `p₂`: weights `w₁ =
//! n₁p₁ / (n₁p₁ + n₂p₂)` and `w₂ = 1 − w₁`, so that where no stored sample lands (`p₁ = 0`,
//! or `LB = 0` then, where no bit was kept) the new draws carry the integral alone, and
//! where both densities agree the stored ones carry most of it. The two weighted means add
//! up to `∫ LB'V` for any fixed weights summing to one, so `n₂` is the nominal `lbv_spp`
//! however many `LBV`-samples the passes take. An area light is sampled by area whatever
//! its radiance or the materials, so its stored draws land where they did (`p₁ = p₂`); the
//! map's are reused after an edit that changes its density, when they are redrawn for
//! reweighting anyway. The area lights' redraws cost what an `LBV`-sample costs less its
//! shadow ray, and the map's product draws more than that; what they buy at threshold 0
//! (the cases of `viscache experiment relight`, 160x120, 256 `V`-samples, mean of three
//! seeds, 2026-11-28): on the Cornell box after SBF's pattern switch, relMSE 0.0012 →
//! 0.000012 at 0.15 → 0.44 s a frame; after a map edit, at +8-10% a frame, 1.8x (garage's
//! map rotated: its sun moved where few stored draws went), 2.3x (garage's other sky) and
//! 4.9x (meshes, rotated) lower. Where the unbiased part has the lower variance even
//! without a bias (a fully lit pixel whose 64 `LB`-samples face 232 `LBV`-samples), the
//! least-error share below weighs every channel.
//!
//! ## The blend beyond eq. 11: consistent
//! Eq. 11 sets `t` from the bound alone, so `⟨LB⟩⟨V⟩` keeps its share however many
//! `LBV`-samples later frames add, and so does its bias (SBF: the estimator "is not even
//! consistent"). Here `t` is at most eq. 11's and at most the share that minimises the
//! blend's expected squared error given the bias the two estimates measurably differ by
//! (`least_error_t`): where they agree it stays eq. 11's, where they differ it falls as the
//! unbiased part's variance does, and the blend converges to `⟨LBV⟩`. The threshold still
//! holds (a smaller `t` only lowers `t · Err_rel`), and so does `1 − ε`. Measured with
//! `viscache experiment relight` (160x120, threshold 0.25, 2026-11-27): first frames within
//! ±7% of eq. 11's relMSE but meshes with cache visibility (0.63x) and pixel visibility
//! after map edits (0.46-0.73x); given 0.5 s, garage 0.45-0.57x and meshes 0.06x (cache);
//! one run of each.
//!
//! ## Passes
//! This module holds the maths per pixel and light; a render's passes over the pixels
//! (how many `LBV`-samples each takes, a time budget, adaptive counts, progress, Ctrl-C)
//! are the pass layer's, on the render floor (`render::relight`).
//! [`Relighter::relight_with`] checks a render's inputs and lends what its pixels read
//! ([`RelightPass`]); [`RelightPass::gather`] adds a pixel's samples to its
//! [`RelightSums`] (the first visit also sets `⟨V⟩` and takes the `LB`-samples),
//! [`RelightPass::lbv_variance`] gives what adaptive counts weigh, and
//! [`RelightPass::resolve`] makes the images.
//!
//! ## Determinism
//! Every random number is a pure function of `(seed, pixel, stream, sample, dimension)`;
//! pixels are independent and their statistics accumulate in sample order, so results
//! are bit-identical for any thread count.
//!
//! Files: `bound.rs` (the error bound and the blend factor, eq. 7-11), `pass.rs` (a
//! pixel's samples and blend, eq. 9-11), `blend.rs` (the least-error share beyond eq. 11),
//! `cached.rs` (area lights' `⟨V⟩` from a cache), `reuse.rs` (stored samples reused).

mod blend;
pub mod bound;
mod cached;
mod pass;
mod reuse;

use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use glam::{DVec2, DVec3, Vec2, Vec3};
use rayon::prelude::*;

use self::bound::{
    binary_variance, blend, blend_factor, error_bound, least_error_factor, relative_error,
};
use super::direct::{sample_area_light, ProductLevel, ShadingPoint};
use super::indirect::shading_point_at;
use crate::bsdf::Material;
use crate::camera::GBuffer;
use crate::error::{Error, Result};
use crate::estimators::direct::dims;
use crate::geometry::{Scene, SurfaceHit, TraversalCounters};
use crate::lights::envmap::product::ProductDistribution;
use crate::lights::envmap::EnvMap;
use crate::lights::AreaLight;
use crate::moments::Moments;
use crate::parallel::run_with_progress;
use crate::sampling::octahedral::{sphere_to_square, texel_of};
use crate::sampling::rng::Sampler;
use crate::sampling::sobol::PixelSampler;
use crate::stop::Stop;
use crate::visibility::cache::interpolant::Interpolant;
use crate::visibility::cache::{CacheState, VisibilityCache};
use blend::least_error_t;
use cached::cached_area_visibility;
use pass::{reused_product, LastProduct, LightSums};
pub use pass::{GatherTiming, GatherWork, RelightPass, RelightSums};
use reuse::{converged_lights, reused_area, reweighted, ReuseWeights, StoredDensity};

/// Most `V`-samples per pixel and light [`Relighter::converge_visibility`] takes (its
/// counts are 16-bit).
pub const MAX_VISIBILITY_SPP: u32 = u16::MAX as u32;

/// `V`-samples per pixel and light whose visibility bits are kept for reweighting the map's
/// light and for reuse as `LBV`-samples (the first ones drawn): with the two 16-bit
/// counts, 32 bytes per pixel and light, SBF's 8 floats.
/// Measured against all 256 of `viscache experiment relight` (bound holds at lb_spp 64,
/// pixel visibility, 2026-11-27): garage rotated 97.3 → 97.4%, garage's other sky 96.0 →
/// 95.4%, meshes 99.8% both; 192 bits gave 94.5% on the sky.
pub const REWEIGHT_SPP: u32 = 224;

/// `V`-samples per pixel and light of one pass of [`Relighter::converge_visibility`].
pub const VISIBILITY_PASS_SPP: u32 = 16;

/// Most `LB`- or `LBV`-samples per pixel and light a relighting render is asked for
/// ([`RelightParams::lb_spp`], [`RelightParams::lbv_spp`]); under a time budget, the most
/// `LBV`-samples its even passes take (adaptive counts may give a pixel up to 16 times
/// the mean of a pass).
pub const MAX_RELIGHT_SPP: u32 = 1 << 16;

/// Standard errors of `⟨V⟩` (or record spreads, in cache mode) added to the bound (module
/// docs).
pub const V_ERROR_SIGMAS: f64 = 2.0;

/// Sample streams, kept apart so that `V`-, `LB`- and `LBV`-samples are independent.
const STREAM_V: u64 = 1 << 32;
const STREAM_LB: u64 = 2 << 32;
const STREAM_LBV: u64 = 3 << 32;
const STREAM_V_CACHE: u64 = 4 << 32;

/// Draws of an area light's density per pixel that read `⟨V⟩` off records that see
/// emitters (no ray: a bit lookup each per record).
pub const CACHED_AREA_DRAWS: u32 = 16;

/// Where a relighting render takes `⟨V⟩` from (module docs).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum VisibilitySource {
    /// `V`-samples traced at the pixels by [`Relighter::converge_visibility`].
    Pixels,
    /// The visibility cache's records, integrated against the current density.
    Cache,
}

/// Parameters of a relighting render ([`Relighter::relight_with`]; its passes are the
/// render floor's `render::relight`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RelightParams {
    /// `LB`-samples per pixel and light (no rays).
    pub lb_spp: u32,
    /// `LBV`-samples per pixel and light (one shadow ray each); 0 leaves the unbiased part
    /// out (`t = 1`). Under a [`Self::time_budget`] the first pass takes them all the same
    /// and later passes add as many as fit; this is the `n₂` of the reused samples' MIS
    /// weights (module docs, "Stored samples as `LBV`-samples").
    pub lbv_spp: u32,
    /// `Err_relThres` of SBF eq. 11: the largest relative error wanted (`≥ 0`; 0 gives
    /// the unbiased estimator alone).
    pub threshold: f64,
    /// `ε` of SBF eq. 11, in `(0, 1)`: the unbiased part keeps at least this share.
    pub epsilon: f64,
    /// Seed of the `LB`- and `LBV`-samples.
    pub seed: u64,
    /// Octahedral level of the map's product cells.
    pub product_level: ProductLevel,
    /// Seconds (from the render's start) after which no further pass of `LBV`-samples
    /// starts; `None`: one pass of [`Self::lbv_spp`]. With a budget (and `lbv_spp > 0`) that
    /// first pass is timed, and passes sized by its timing bring every pixel to as many as
    /// fit (the pass layer's schedule).
    pub time_budget: Option<f64>,
    /// Under a [`Self::time_budget`], whether the pass after the first is a pilot of a
    /// quarter of its samples after which each pixel takes the share of the rest that cuts
    /// the image's relMSE most for its cost (SBF §4.1's adaptive sampling: `√(v/c)`, `v`
    /// the relative variance per `LBV`-sample of its blend, `c` its cost), rather than the
    /// same to every pixel. Without a budget it changes nothing.
    pub adaptive: bool,
    /// Whether `t` is also capped by the least-error share (module docs, "The blend beyond
    /// eq. 11"); `false` gives SBF's eq. 11 alone, so that a large `threshold` and a small
    /// `epsilon` leave `⟨LB⟩⟨V⟩` itself.
    pub least_error: bool,
    /// Whether the stored `V`-samples join the unbiased part as `LBV`-samples of the
    /// density they were drawn from (module docs, "Stored samples as `LBV`-samples"):
    /// every area light's, and the map's after an edit that changes its density. Pixel
    /// visibility only. `false` gives SBF's `⟨LBV⟩` of the current density alone, and with
    /// `threshold` 0 SBF's classical estimator, which reads no `⟨V⟩` (visibility and
    /// bound NaN).
    pub reuse: bool,
}

impl RelightParams {
    /// SBF's settings: 64 `LB`-samples, 8 `LBV`-samples, threshold 0.25, `ε = 0.1`.
    pub const DEFAULT: Self = Self {
        lb_spp: 64,
        lbv_spp: 8,
        threshold: 0.25,
        epsilon: 0.1,
        seed: 0,
        product_level: ProductLevel::PerMaterial,
        time_budget: None,
        adaptive: true,
        least_error: true,
        reuse: true,
    };

    /// Fails with an error naming the first parameter out of range.
    pub fn validate(&self) -> Result<()> {
        crate::error::check_range("lb_spp", self.lb_spp, 1, MAX_RELIGHT_SPP)?;
        crate::error::check_range("lbv_spp", self.lbv_spp, 0, MAX_RELIGHT_SPP)?;
        if !(self.threshold.is_finite() && self.threshold >= 0.0) {
            return Err(Error::invalid(
                "threshold",
                format!("must be a finite number >= 0, got {}", self.threshold),
            ));
        }
        if !(self.epsilon > 0.0 && self.epsilon < 1.0) {
            return Err(Error::invalid(
                "epsilon",
                format!("must lie in (0, 1), got {}", self.epsilon),
            ));
        }
        crate::error::check_time_budget(self.time_budget)?;
        self.product_level.validate()
    }
}

impl Default for RelightParams {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// One light of a relighter: the map, or area light `k` of the scene.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum LightId {
    Env,
    Area(usize),
}

/// One draw for a light at a shading point: `LB/p` per channel and what a shadow ray
/// needs (`None`: `LB = 0` by geometry, `V = 0` without a ray).
struct LightDraw {
    lb_over_p: Vec3,
    ray: Option<(Vec3, f32)>,
    /// The direction drawn and its solid-angle density.
    dir: Vec3,
    pdf: f64,
    /// The point drawn on an area light (unused for the map).
    point: Vec3,
}

/// What one pixel's light sees at render time: the lights' densities.
struct PixelLights<'a> {
    scene: &'a Scene,
    env: &'a EnvMap,
    /// The area lights drawn from: the scene's now, or as they were converged.
    area_lights: &'a [AreaLight],
    sp: ShadingPoint,
    product: Option<Arc<ProductDistribution>>,
}

impl PixelLights<'_> {
    /// `LB` of the map at `dir` (the texel's radiance, as its draws see it).
    fn env_lb(&self, dir: Vec3) -> Vec3 {
        let sp = &self.sp;
        let cos = sp.normal.dot(dir);
        if cos <= 0.0 {
            return Vec3::ZERO;
        }
        sp.material.eval(sp.normal, sp.wo, dir)
            * self.env.texel(texel_of(dir, self.env.resolution()))
            * cos
    }

    fn draw(&self, light: LightId, rng: &impl Sampler) -> Option<LightDraw> {
        let sp = &self.sp;
        let (dir, radiance, pdf, tmax, point) = match light {
            LightId::Env => {
                let product = self.product.as_ref()?;
                let s = product.sample_point(self.env, unit_pair(rng.get2(dims::ENV)));
                let dir = s.direction;
                (dir, self.env.texel(s.texel), s.pdf, f32::INFINITY, dir)
            }
            LightId::Area(k) => {
                let light = &self.area_lights[k];
                let s = sample_area_light(light, k, sp.origin, rng)?;
                let tmax = self.scene.segment_end(s.distance, s.point);
                (s.direction, s.radiance, s.pdf, tmax, s.point)
            }
        };
        let cos = sp.normal.dot(dir);
        let f = if cos > 0.0 && tmax > 0.0 {
            sp.material.eval(sp.normal, sp.wo, dir)
        } else {
            Vec3::ZERO
        };
        let lb_over_p = f * radiance * cos.max(0.0) * (1.0 / pdf) as f32;
        let ray = (lb_over_p != Vec3::ZERO).then_some((dir, tmax));
        Some(LightDraw {
            lb_over_p,
            ray,
            dir,
            pdf,
            point,
        })
    }

    /// Whether the ray of `draw` reaches its light (`false` for draws with `LB = 0`).
    fn visible(&self, draw: &LightDraw, bvh: &mut TraversalCounters) -> bool {
        match draw.ray {
            None => false,
            Some((dir, tmax)) => !self.scene.occluded1(self.sp.origin, dir, tmax, bvh),
        }
    }
}

fn unit_pair(u: [f32; 2]) -> DVec2 {
    DVec2::new(u[0] as f64, u[1] as f64)
}

/// `V`-statistics of one pixel and light from [`Relighter::converge_visibility`]: for
/// binary `V` the counts are all (mean `visible / samples`, variance binary): two
/// 16-bit words ([`MAX_VISIBILITY_SPP`]).
#[derive(Clone, Copy, Debug, Default)]
struct PixelVisibility {
    /// Draws with `LB > 0`, each with a shadow ray.
    samples: u16,
    /// Those whose ray reached the light.
    visible: u16,
}

impl PixelVisibility {
    fn mean(&self) -> f64 {
        self.visible as f64 / self.samples.max(1) as f64
    }
}

/// The state the `V`-samples were drawn under.
#[derive(Clone, Debug)]
struct Converged {
    env: EnvMap,
    materials: Vec<Material>,
    /// The scene's area lights then (radiance and texture: which draws kept a bit).
    area_lights: Vec<AreaLight>,
    spp: u32,
    seed: u64,
    product_level: ProductLevel,
    /// Per pixel, per light ([`Relighter::lights`] order).
    stats: Vec<PixelVisibility>,
    /// Per pixel and light, `words` words of the visibility of the first
    /// `min(spp, REWEIGHT_SPP)` samples, bit `s` for sample `s` (the samples are redrawn
    /// from the stored density to reweight or reuse them).
    bits: Vec<u32>,
    words: usize,
}

impl Converged {
    /// Bytes kept per pixel and light.
    pub fn bytes_per_pixel_and_light(&self) -> usize {
        std::mem::size_of::<PixelVisibility>() + 4 * self.words
    }

    /// The stored visibility of sample `s` of light `l` (index into the lights) at `pixel`.
    fn bit(&self, pixel: usize, l: usize, s: u32) -> bool {
        let word = self.bits[(pixel * self.n_lights() + l) * self.words + s as usize / 32];
        (word >> (s % 32)) & 1 == 1
    }

    /// Samples per pixel and light whose bits are stored (the first ones drawn).
    fn stored_samples(&self) -> u32 {
        self.spp.min(REWEIGHT_SPP)
    }

    /// Lights in [`Relighter::lights`] order: the map, then the area lights.
    fn n_lights(&self) -> usize {
        self.area_lights.len() + 1
    }
}

/// What a relighting render returns: images per pixel (row-major) and per pixel and
/// light.
#[derive(Clone, Debug, Default)]
pub struct Relit {
    /// The blended estimate of direct light plus what the camera sees of emitters and
    /// the map, RGB.
    pub image: Vec<[f32; 3]>,
    /// Variance of the estimate, treating `⟨V⟩` as exact: `(1 − t)² Var⟨LBV⟩ +
    /// t² ⟨V⟩² Var⟨LB⟩` summed over lights, `⟨LBV⟩` with the reused samples where
    /// [`RelightParams::reuse`] adds them.
    pub variance: Vec<[f32; 3]>,
    /// The estimated absolute error of `⟨LB⟩⟨V⟩` per pixel, RGB, summed over lights (eq. 7
    /// plus `⟨V⟩`'s uncertainty; 0 where no light has `⟨V⟩`).
    pub error_bound: Vec<[f32; 3]>,
    /// Blend factor `t` per pixel and light (`lights` values per pixel; NaN where the
    /// pixel has no surface).
    pub t: Vec<f32>,
    /// Estimated relative error bound per pixel and light (worst channel; SBF eq. 10).
    pub bound: Vec<f32>,
    /// `⟨V⟩` per pixel and light.
    pub visibility: Vec<f32>,
    /// Effective sample count of `⟨V⟩` per pixel and light (the reweighted samples'
    /// `(Σw)²/Σw²`; the sample count when not reweighted; infinite for the cache's exact
    /// sum over cells; 0 without `⟨V⟩`).
    pub effective_samples: Vec<f32>,
    /// Lights per pixel in `t`, `bound`, `visibility` and `effective_samples`.
    pub lights: usize,
    /// Shadow rays traced (`LBV`-samples).
    pub shadow_rays: u64,
    /// `LB`-samples of the pixels' first visits not drawn, summed over pixels and lights:
    /// where they would change nothing, at a light without `⟨V⟩` or whose `⟨V⟩` is exactly
    /// 0 with a bound of 0 (`LightSums::lb_changes_nothing`).
    pub lb_skipped: u64,
    /// The most `LBV`-samples a pixel took per light: [`RelightParams::lbv_spp`], or as
    /// the passes of a time budget gave them.
    pub lbv_spp: u32,
    /// `LBV`-samples per light, on average over the pixels that see a surface.
    pub lbv_spp_mean: f64,
    /// `LBV`-samples per light each pixel took (row-major; 0 where it sees no surface).
    pub lbv_counts: Vec<u32>,
    /// Passes over the pixels (1 without a time budget).
    pub passes: u32,
    /// Wall-clock seconds of the first pass: without a time budget the only one (every
    /// pixel's `LB`-samples, `⟨V⟩` and `LBV`-samples).
    pub first_pass_seconds: f64,
    /// Wall-clock seconds.
    pub seconds: f64,
}

/// Relighting with decoupled visibility (module docs) at the hits of one G-buffer.
#[derive(Clone, Debug)]
pub struct Relighter {
    gbuffer: GBuffer,
    source: VisibilitySource,
    converged: Option<Converged>,
}

impl Relighter {
    /// A relighter at `gbuffer`'s hits (which must describe `scene` as posed now) taking
    /// `⟨V⟩` from `source`.
    pub fn new(scene: &Scene, gbuffer: GBuffer, source: VisibilitySource) -> Result<Self> {
        gbuffer.check(scene, None)?;
        Ok(Self {
            gbuffer,
            source,
            converged: None,
        })
    }

    /// The G-buffer it shades.
    pub fn gbuffer(&self) -> &GBuffer {
        &self.gbuffer
    }

    /// Where `⟨V⟩` comes from.
    pub fn source(&self) -> VisibilitySource {
        self.source
    }

    /// Lights of `scene`: the map, then every area light.
    fn lights(scene: &Scene) -> Vec<LightId> {
        std::iter::once(LightId::Env)
            .chain((0..scene.area_lights().len()).map(LightId::Area))
            .collect()
    }

    /// `V`-samples traced so far per pixel and light (0 before
    /// [`Self::converge_visibility`]).
    pub fn visibility_spp(&self) -> u32 {
        self.converged.as_ref().map_or(0, |c| c.spp)
    }

    /// Bytes of stored visibility per pixel and light (0 before
    /// [`Self::converge_visibility`]): two 16-bit counts and one bit per V-sample up to
    /// [`REWEIGHT_SPP`]: at most 32.
    pub fn visibility_bytes_per_pixel_and_light(&self) -> usize {
        self.converged
            .as_ref()
            .map_or(0, Converged::bytes_per_pixel_and_light)
    }

    /// The hit of pixel `i` and its shading point with `materials` (per object), or
    /// `None` for a miss.
    fn point(
        &self,
        scene: &Scene,
        materials: &[Material],
        i: usize,
    ) -> Option<(SurfaceHit, ShadingPoint)> {
        let hit = self.gbuffer.surface_hit(i)?;
        let mut sp = shading_point_at(scene, &hit, -Vec3::from(self.gbuffer.direction[i]));
        sp.material = materials[hit.obj as usize];
        Some((hit, sp))
    }

    /// Traces `spp` `V`-samples per pixel and light under `env` and the scene's materials
    /// now (their densities), replacing earlier ones; returns the samples per pixel and
    /// light taken and the shadow rays traced. Needed for [`VisibilitySource::Pixels`].
    ///
    /// Samples go in passes of [`VISIBILITY_PASS_SPP`] over every pixel; with
    /// `time_budget` (seconds) no pass starts once it is spent and a pass after the first
    /// that it ends part-way is dropped, so fewer than `spp` may be taken (every pixel the
    /// same number; the result equals a run asked for that many). Ctrl-C (the current
    /// [`Stop`]) stops as `progress` does.
    /// `progress(done, planned)` (pixel samples) is called on the calling thread about
    /// every 0.1 s; returning `false` stops: the passes completed before are kept, as
    /// under a budget, and with none completed the call fails with
    /// [`Error::Interrupted`], leaving the relighter as it was.
    #[allow(clippy::too_many_arguments)]
    pub fn converge_visibility(
        &mut self,
        scene: &Scene,
        env: &EnvMap,
        spp: u32,
        seed: u64,
        product_level: ProductLevel,
        threads: Option<usize>,
        time_budget: Option<f64>,
        progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
    ) -> Result<(u32, u64)> {
        crate::error::check_range("spp", spp, 1, MAX_VISIBILITY_SPP)?;
        crate::error::check_time_budget(time_budget)?;
        product_level.validate()?;
        self.gbuffer.check(scene, None)?;
        let start = Instant::now();
        let env = env.at_least(2)?.into_owned();
        let materials: Vec<Material> = scene.mesh().objects.iter().map(|o| o.material).collect();
        let lights = Self::lights(scene);
        let n_lights = lights.len();
        let words = (spp.min(REWEIGHT_SPP) as usize).div_ceil(32);
        let pixels = self.gbuffer.len();
        let mut stats = vec![PixelVisibility::default(); pixels * n_lights];
        let mut bits = vec![0u32; pixels * n_lights * words];
        let planned = spp as u64 * pixels as u64;
        let done = AtomicU64::new(0);
        let mut rays = 0u64;
        let mut taken = 0u32;
        let deadline = time_budget.map(|b| start + std::time::Duration::from_secs_f64(b));
        while taken < spp {
            let pass = taken..(taken + VISIBILITY_PASS_SPP).min(spp);
            // Set by Ctrl-C (the current stop), by progress, and after the first pass by
            // the budget's end: a pass it stops is dropped whole.
            let cancel = Stop::current().child(deadline.filter(|_| taken > 0));
            // What the completed passes gave, kept in case this one is stopped.
            let before = (taken > 0).then(|| (stats.clone(), bits.clone()));
            let this = &*self;
            let work = || {
                stats
                    .par_chunks_mut(n_lights)
                    .zip(bits.par_chunks_mut(n_lights * words))
                    .enumerate()
                    .with_min_len(64)
                    .map_init(
                        || None,
                        |last_product, (i, (stats, bits))| {
                            if cancel.is_set() {
                                return 0;
                            }
                            done.fetch_add(pass.len() as u64, Ordering::Relaxed);
                            let Some((_, sp)) = this.point(scene, &materials, i) else {
                                return 0;
                            };
                            let at = PixelLights {
                                scene,
                                env: &env,
                                area_lights: scene.area_lights(),
                                product: reused_product(&env, &sp, product_level, last_product),
                                sp,
                            };
                            let mut bvh = TraversalCounters::default();
                            let mut rays = 0u64;
                            for s in pass.clone() {
                                let rng = PixelSampler::new(seed, i as u64, STREAM_V + s as u64);
                                for (l, (stats, &light)) in
                                    stats.iter_mut().zip(&lights).enumerate()
                                {
                                    // Draws with `LB = 0` tell nothing (module docs).
                                    let Some(d) = at.draw(light, &rng).filter(|d| d.ray.is_some())
                                    else {
                                        continue;
                                    };
                                    rays += 1;
                                    let visible = at.visible(&d, &mut bvh);
                                    stats.samples += 1;
                                    stats.visible += visible as u16;
                                    if visible && s < REWEIGHT_SPP {
                                        bits[l * words + s as usize / 32] |= 1 << (s % 32);
                                    }
                                }
                            }
                            rays
                        },
                    )
                    .sum::<u64>()
            };
            let pass_rays = run_with_progress(threads, work, &mut || {
                let keep = progress(done.load(Ordering::Relaxed), planned);
                if !keep {
                    cancel.set();
                }
                keep
            })?;
            if cancel.is_set() || !progress(done.load(Ordering::Relaxed), planned) {
                let Some((s, b)) = before else {
                    return Err(Error::Interrupted {
                        what: "converge_visibility".into(),
                    });
                };
                (stats, bits) = (s, b);
                break;
            }
            rays += pass_rays;
            taken = pass.end;
            if time_budget.is_some_and(|b| start.elapsed().as_secs_f64() >= b) {
                break;
            }
        }
        self.converged = Some(Converged {
            env,
            materials,
            area_lights: scene.area_lights().to_vec(),
            spp: taken,
            seed,
            product_level,
            stats,
            bits,
            words,
        });
        Ok((taken, rays))
    }

    /// Checks a relighting render's inputs and hands `run` what its pixels read
    /// ([`RelightPass`]): the view under `env`, the scene's area lights as they are now,
    /// and the scene's materials with `overrides` (object id, material) applied; per pixel
    /// and light, `LB`- and `LBV`-samples under the current densities, `⟨V⟩` from the
    /// source, and SBF's blend (module docs). `cache` is needed for
    /// [`VisibilitySource::Cache`] (records of this scene; it and `light_cache` stay
    /// read-locked while `run` runs); [`VisibilitySource::Pixels`] needs a converged
    /// visibility. The passes are the caller's (the render floor's `render::relight`);
    /// errors name the argument that is wrong.
    #[allow(clippy::too_many_arguments)]
    pub fn relight_with<R>(
        &self,
        scene: &Scene,
        env: &EnvMap,
        overrides: &[(u32, Material)],
        cache: Option<&VisibilityCache>,
        light_cache: Option<&VisibilityCache>,
        params: &RelightParams,
        run: impl FnOnce(&RelightPass<'_>) -> Result<R>,
    ) -> Result<R> {
        params.validate()?;
        self.gbuffer.check(scene, None)?;
        let mut materials: Vec<Material> =
            scene.mesh().objects.iter().map(|o| o.material).collect();
        for &(object, material) in overrides {
            let slot = materials.get_mut(object as usize).ok_or_else(|| {
                Error::invalid(
                    "materials",
                    format!(
                        "no object {object} in a scene of {} objects",
                        scene.num_objects()
                    ),
                )
            })?;
            *slot = material;
        }
        let lights = Self::lights(scene);
        let converged = match self.source {
            VisibilitySource::Pixels => {
                let c = self.converged.as_ref().ok_or_else(|| {
                    Error::invalid(
                        "visibility",
                        "no visibility yet: call converge_visibility first",
                    )
                })?;
                if c.stats.len() != self.gbuffer.len() * lights.len() {
                    return Err(Error::invalid(
                        "visibility",
                        "the scene's area lights changed since converge_visibility: \
                         converge again",
                    ));
                }
                Some(c)
            }
            VisibilitySource::Cache => None,
        };
        let cache = match self.source {
            VisibilitySource::Cache => {
                let cache = cache.ok_or_else(|| {
                    Error::invalid("cache", "visibility=\"cache\" needs a visibility cache")
                })?;
                cache.bind_scene(scene)?;
                Some(cache)
            }
            VisibilitySource::Pixels => None,
        };
        if cache.is_some_and(|c| c.params().emitters_visible) {
            return Err(Error::invalid(
                "cache",
                "the map's cache must see area lights as occluders (emitters_visible=False); \
                 a cache with emitters_visible=True serves the area lights, as light_cache",
            ));
        }
        let light_cache = match self.source {
            VisibilitySource::Cache => match light_cache {
                Some(c) if !c.params().emitters_visible => {
                    return Err(Error::invalid(
                        "light_cache",
                        "the area lights' cache needs records that see emitters \
                         (emitters_visible=True)",
                    ))
                }
                Some(c) => {
                    c.bind_scene(scene)?;
                    Some(c)
                }
                None => None,
            },
            VisibilitySource::Pixels => None,
        };
        let env = &*env.at_least(2)?;
        let state = cache.map(|c| c.read());
        let light_state = light_cache.map(|c| c.read());
        let pass = RelightPass {
            relighter: self,
            scene,
            env,
            materials: &materials,
            lights: &lights,
            // Whether the map's density is the converged one (same map, same materials).
            same_env_density: converged.is_some_and(|c| {
                c.env.resolution() == env.resolution()
                    && c.env.texels() == env.texels()
                    && c.materials == materials
                    && c.product_level == params.product_level
            }),
            converged,
            cache: cache.zip(state.as_deref()),
            light_cache: light_cache.zip(light_state.as_deref()),
            params,
        };
        run(&pass)
    }
}

/// The product distribution of the map at `sp` (`None`: nothing to sample).
fn product_of(env: &EnvMap, sp: &ShadingPoint, level: ProductLevel) -> Option<ProductDistribution> {
    ProductDistribution::new(
        env,
        &sp.material,
        sp.normal,
        sp.wo,
        level.for_material(&sp.material),
    )
}

#[cfg(test)]
mod tests;
