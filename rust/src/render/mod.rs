//! The renderer: direct illumination from an environment map and area lights by any
//! [`Method`] of [`crate::estimators::direct`], including the visibility cache's control
//! variate ([`crate::estimators::control_variate`]), and optionally indirect light by
//! path tracing ([`crate::estimators::indirect`]).
//!
//! ## Anchors and samples
//! Every pixel has an *anchor*, the first hit through its centre: the G-buffer's point,
//! where the cache was built. The G-buffer is traced once before the passes, or handed in
//! ([`render_from`]: the very buffer the cache was built from, so the anchors are the
//! records' points by construction, not by equal seeds). The per-point work is done at the
//! anchor once per pixel and pass: the product distribution (B~ and the product pyramid), the cache lookup and `J`,
//! as in CAM08. By default (`jitter`) every sample then traces its own primary ray
//! through a random point of the pixel (antialiasing, box filter; the pixel's rays go as
//! packets of [`crate::geometry::bvh::PACKET`] from the eye, [`crate::geometry::Bvh::intersect_packet`]) and
//! shades its own hit
//! with the anchor's work: the environment is drawn from the one-sample mixture of the
//! anchor's product, BSDF sampling at the sample's hit and the map's own distribution
//! ([`Techniques`], [`Lighting::estimate_mixture`]), unbiased for any hit because BSDF
//! sampling covers every direction the hit reflects. Without `jitter` every sample is
//! drawn at the anchor (CAM08's fixed shading points).
//!
//! The control variate stays unbiased at any hit: its `g = κ L B~ Ṽ` and `J = ∫ g` are the
//! anchor's, a fixed function with a known integral, and the mixture's density is
//! positive wherever `g` is (the product's share covers `B~ > 0`), so `E[g/p] = J` for any
//! sample. A sample whose hit lies on another object than the anchor, or whose normal
//! turns away by more than the material's product tolerance
//! ([`crate::bsdf::Material::product_tolerance`]), is *unmatched*: it leaves the anchor's
//! product out of its mixture and the control variate out (`W = 0`); a hit with a diffuse
//! part then draws from the product of the nearest of a grid of normals instead, for
//! that part's share ([`crate::estimators::normal_products`]), any other from BSDF and
//! map sampling only. That choice depends only on the pixel jitter, which is independent of the
//! directions drawn, so each sample's estimate is unbiased given its hit, while a product
//! or a `g` that does not describe the hit adds no noise. With one anchor per pixel, a pixel in an odd
//! column shares its left neighbour's cache lookup when the two anchors nearly coincide
//! ([`crate::estimators::direct::anchored::AnchoredShader`]): any `Ṽ` keeps the control variate unbiased, and the lookup
//! is a third of what the control variate adds per pixel.
//!
//! ## Indirect light
//! With [`RenderParams::bounces`] `k > 0` every sample adds `k` bounces of a path from its
//! hit ([`crate::estimators::indirect`]) to whatever the method estimates there; the path
//! reads dimensions above the direct estimate's, so the direct part of each sample is
//! the same number with or without bounces. Without [`RenderParams::direct`] the sample
//! is the path's part alone (the map and emitters the camera sees count as direct).
//!
//! ## Passes, progress and budgets
//! Without a time budget the render is one pass of `spp` samples per pixel. With one, a
//! first probe pass takes four samples in every eighth band of pixels; from its timing the
//! renderer models a pixel's cost as its anchor plus a cost per sample (the probe's bands
//! are spread over the image, so costs that differ between sky and geometry average out),
//! and the main pass brings every pixel to the most samples that fit 95% of the budget
//! left; another pass follows only when a whole sample per pixel still fits
//! (the pass schedule). The anchors' work is redone each pass from the G-buffer's hits (it
//! is not kept: a product distribution is kilobytes), hence so few passes. Every pixel ends with the same number
//! of samples but the probe's, which may have up to four more.
//! With [`RenderParams::adaptive`] the main pass is a pilot of a quarter of its samples,
//! after which each pixel takes a share of the rest measured from its neighbours'
//! samples ([`adaptive`]); the passes that follow bring each pixel to its share of the
//! most that fits, each pixel's cost per sample taken from the pilot. Without a budget
//! the same two passes spend `spp` samples per pixel on average.
//! Progress is reported from the calling thread while the workers run, in pixel samples;
//! a `false` from it stops the pass (pixels not started keep the samples they had,
//! `stats.complete` says so).
//!
//! ## Samples
//! Sample `s` of pixel `i` draws every random number from `(seed, i, s, dimension)`
//! through [`crate::sampling::sobol::PixelSampler`]: Owen-scrambled Sobol points, so the samples of a pixel are
//! stratified over the pixel and over the environment's 2D sample together, and each is
//! uniform (unbiased). `variance` is the sample variance of the mean, which overestimates
//! the error of stratified samples (conservative).
//!
//! ## Determinism
//! Every random number is a pure function of `(seed, pixel, sample, dimension)`, a
//! pixel is shaded by one worker per pass and accumulates in sample order in `f64`, and
//! `α` is computed after all samples from neighbours' sums in a fixed order: images are
//! bit-identical for any thread count. (Pass sizes under a time budget depend on timing,
//! so a budgeted render is reproducible only through its `spp`.)

use std::time::Instant;

use crate::camera::{Camera, GBuffer};
use crate::error::{Error, Result};
use crate::estimators::control_variate::AlphaRule;
use crate::estimators::direct::anchored::AnchoredParams;
use crate::estimators::direct::light_split;
use crate::estimators::direct::{Lighting, Method, ProductLevel, Techniques};
use crate::estimators::indirect::MAX_BOUNCES;
use crate::estimators::irradiance::cache::IrradianceCache;
use crate::estimators::normal_products::NormalProducts;
use crate::geometry::Scene;
use crate::lights::envmap::chroma::MapChroma;
use crate::lights::envmap::EnvMap;
use crate::parallel::with_threads;
use crate::visibility::cache::interpolant::ALPHA_MAX;
use crate::visibility::cache::VisibilityCache;
use crate::visibility::params::CacheParams;

pub mod adaptive;
pub mod ambient;
pub mod direct;
pub mod estimator;
pub mod frame;
pub mod importance;
pub mod irradiance;
pub mod many_lights;
pub mod output;
pub mod own_cache;
pub mod passes;
pub mod registry;
pub mod relight;
pub(crate) mod schedule;
mod shade;
pub mod stochastic;
pub mod sums;
pub mod vf;

use frame::Frame;
use passes::{run_passes, PassParams};
use shade::DirectMethod;

/// Most samples per pixel a render takes.
pub const MAX_SPP: u32 = 1 << 20;

/// Least edge share ([`light_split::edge_share`]) of a view whose jittered product sampling
/// (or control variate without records) takes [`ProductLevel::CoarseDiffuse`] when the
/// level is left to the materials. Measured
/// at 1 s on the suite, 160x120, 16² cells on Lambert surfaces against 32² (relMSE ratio,
/// edge share in brackets): garden (1.00) 0.83, strands (0.66) 0.87, instances (0.59)
/// 0.96, hairball (0.44) 0.81, where the products' build fell from 0.09-0.23 to 0.03-0.09
/// CPU seconds and the samples per pixel rose 4-18%; scales (0.30) 1.05 and room (0.13)
/// 1.08 lose, their samples sharing their anchor's product.
pub const COARSE_EDGE_SHARE: f64 = 0.4;

/// Parameters of [`render`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderParams {
    /// Samples per pixel (on average, with [`Self::adaptive`] counts); with a time
    /// budget, the most to take.
    pub spp: u32,
    /// The direct-lighting estimator.
    pub method: Method,
    /// Seed of every random number.
    pub seed: u64,
    /// Stop after the first pass that ends past this many seconds.
    pub time_budget: Option<f64>,
    /// Octahedral level of the product's cells, for the product methods.
    pub product_level: ProductLevel,
    /// A new jittered primary ray per sample (antialiased, box filter), shaded with its
    /// pixel's anchor (module docs), instead of every sample at the anchor.
    pub jitter: bool,
    /// Weights of the one-sample mixture that samples the environment in the product
    /// methods ([`Techniques`]); `None`: the method's default
    /// ([`Techniques::default_for`]).
    pub techniques: Option<Techniques>,
    /// `α` of the control variate ([`Method::ControlVariate`]).
    pub alpha: AlphaRule,
    /// One-pass mode: afterwards, the cache traces and inserts records for the shading
    /// points that found none (§5.2's criteria re-checked, in pixel order), so the next
    /// render of the view finds them.
    pub insert_missing: bool,
    /// Bounces of indirect light added to every sample by path tracing
    /// ([`crate::estimators::indirect`]), `0..=MAX_BOUNCES`; 0: direct light only.
    pub bounces: u32,
    /// Whether the image holds direct light (what the camera sees of emitters and the map,
    /// and light reflected once); `false` keeps only the indirect part (`bounces >= 1`).
    pub direct: bool,
    /// Light draws per sample in the product methods, `1..=MAX_LIGHT_SAMPLES`: each
    /// sample's hit averages this many draws of the mixture (and of each area light), each
    /// with its shadow ray, from a stream of its own ([`crate::sampling::sobol::PixelSampler::light_draw`]). More
    /// than one pays where shadow rays are cheap beside the rest of a sample and the
    /// light's noise outweighs the pixel's.
    pub light_samples: u32,
    /// Method "product" under a time budget: the passes after the probe use the mixture
    /// weights learnt from the probe's draws ([`Techniques::learnt`]) instead of the given
    /// ones; with [`Self::adaptive`] counts, every pixel then takes the mixture its
    /// neighbours' pilot draws favour ([`crate::estimators::direct::mixture_choice::PixelTechniques`]).
    pub learn_techniques: bool,
    /// Samples go where they cut the image's relMSE most ([`adaptive`]): a pilot pass
    /// takes a quarter of them evenly, the rest follow each pixel's share measured from
    /// its neighbours. `spp` is then the mean per pixel (with a time budget, the most on
    /// average); renders of fewer than [`adaptive::MIN_ADAPTIVE_SPP`] samples per pixel
    /// take them evenly.
    pub adaptive: bool,
    /// The product methods under a time budget: the light draws per sample are chosen from
    /// the anchors and the probe pass ([`light_split`]: up to [`light_split::SPLIT_DRAWS`] where the
    /// view is mostly smooth surfaces, as many as the probe measures best; one where
    /// jittered hits leave their anchor's surface) instead of [`Self::light_samples`],
    /// which must then be 1.
    pub auto_light_samples: bool,
    /// Method "cv" given no cache: the parameters of the cache the render builds for its
    /// view first ([`own_cache`]).
    pub own_cache: CacheParams,
}

/// Most light draws per sample ([`RenderParams::light_samples`]).
pub const MAX_LIGHT_SAMPLES: u32 = 64;

impl RenderParams {
    /// 16 samples per pixel by MIS, seed 0, no budget, product cells per material,
    /// jittered samples with the defensive mixture, `α = 1`, no insertion.
    pub const DEFAULT: Self = Self {
        spp: 16,
        method: Method::Mis,
        seed: 0,
        time_budget: None,
        product_level: ProductLevel::PerMaterial,
        jitter: true,
        techniques: None,
        alpha: AlphaRule::PAPER,
        insert_missing: false,
        bounces: 0,
        direct: true,
        light_samples: 1,
        learn_techniques: true,
        adaptive: false,
        auto_light_samples: false,
        own_cache: CacheParams::AUTO,
    };

    /// The defaults with another method and sample count.
    pub const fn with(method: Method, spp: u32) -> Self {
        Self {
            method,
            spp,
            ..Self::DEFAULT
        }
    }

    /// CAM08's setting: every sample at the pixel's anchor, the environment by plain
    /// product sampling (for the paper's tables).
    pub const fn fixed_points(mut self) -> Self {
        self.jitter = false;
        self.techniques = Some(Techniques::PRODUCT_ONLY);
        self.learn_techniques = false;
        self
    }

    /// The unbiased reference with indirect light: light and BSDF sampling (MIS) at every
    /// vertex and `bounces` bounces ([`crate::estimators::indirect`]).
    pub const fn path(bounces: u32, spp: u32) -> Self {
        Self {
            bounces,
            ..Self::with(Method::Mis, spp)
        }
    }

    /// Whether the product's cells (and, for "cv", lookup and `J`) shade anything: not
    /// when only the indirect part is rendered.
    pub fn uses_product(&self) -> bool {
        self.anchored().uses_product()
    }

    /// What the samples read of these parameters.
    pub fn anchored(&self) -> AnchoredParams {
        AnchoredParams {
            method: self.method,
            seed: self.seed,
            jitter: self.jitter,
            direct: self.direct,
            bounces: self.bounces,
            insert_missing: self.insert_missing,
        }
    }

    /// Whether pixels need anchors (a G-buffer through their centres): always without
    /// jitter (samples are shaded there), and for the product methods (their product,
    /// lookup and `J`).
    pub fn needs_anchors(&self) -> bool {
        !self.jitter || self.uses_product()
    }

    /// The mixture's weights: the given ones or the method's default.
    pub fn techniques(&self) -> Techniques {
        self.techniques
            .unwrap_or(Techniques::default_for(self.method))
    }

    /// Fails with an error naming the first parameter out of range.
    pub fn validate(&self) -> Result<()> {
        crate::error::check_range("spp", self.spp, 1, MAX_SPP)?;
        crate::error::check_time_budget(self.time_budget)?;
        crate::error::check_range("bounces", self.bounces, 0, MAX_BOUNCES)?;
        crate::error::check_range("light_samples", self.light_samples, 1, MAX_LIGHT_SAMPLES)?;
        if self.auto_light_samples && self.light_samples != 1 {
            return Err(Error::invalid(
                "light_samples",
                "a fixed count of light draws excludes the count chosen from the view",
            ));
        }
        if self.light_samples > 1 && !self.uses_product() {
            return Err(Error::invalid(
                "light_samples",
                "more than one light draw per sample needs a product method (\"product\" or \
                 \"cv\") shading direct light",
            ));
        }
        if !self.direct && self.bounces == 0 {
            return Err(Error::invalid(
                "direct",
                "False leaves nothing to render without bounces: set bounces >= 1",
            ));
        }
        self.product_level.validate()?;
        self.techniques().validate(self.jitter)?;
        match self.alpha {
            AlphaRule::Fixed(a) if !(a.is_finite() && (0.0..=ALPHA_MAX).contains(&a)) => {
                return Err(Error::invalid(
                    "alpha",
                    format!("must be a number in [0, {ALPHA_MAX}] or \"estimate\", got {a}"),
                ))
            }
            AlphaRule::Neighbours { radius } if !(1..=64).contains(&radius) => {
                return Err(Error::invalid(
                    "alpha_radius",
                    format!("must lie in [1, 64] pixels, got {radius}"),
                ))
            }
            _ => {}
        }
        Ok(())
    }
}

impl Default for RenderParams {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Where the time went, summed over threads (CPU seconds). The anchors' stages are timed
/// one by one; the samples as a whole, per pixel (a clock read per sample would cost a
/// tenth of a sample).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageSeconds {
    /// The anchors' primary rays (closest hits).
    pub primary: f64,
    /// Product distributions: B~ per cell and the product pyramid.
    pub product: f64,
    /// Cache lookups.
    pub lookup: f64,
    /// `J`: the control variate's integral (prefix sums and hierarchy traversals).
    pub control: f64,
    /// The samples: their jittered primary rays, sampling and shading, BSDF evaluation,
    /// shadow and BSDF rays, `Ṽ` (indirect paths included).
    pub shading: f64,
    /// Of `shading`, the indirect paths ([`RenderParams::bounces`]).
    pub indirect: f64,
    /// Of `shading`, the jittered samples' primary rays: their packets from the eye and
    /// the hits' surfaces (0 without [`RenderParams::jitter`]). What antialiasing adds to
    /// a sample at least (`benches/jitter_cost.py` reports it as the ratio's floor).
    pub sample_primary: f64,
}

/// Figures of one render.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RenderStats {
    /// Wall-clock seconds.
    pub seconds: f64,
    /// The mixture weights the passes after the probe used, when learnt
    /// ([`RenderParams::learn_techniques`]): `[product, guided, bsdf, env]`.
    pub learnt_techniques: Option<[f32; 4]>,
    /// The predicted gain of adaptive counts measured after the pilot
    /// ([`adaptive::SampleShares::gain`]; below [`adaptive::MIN_GAIN`] the counts stayed
    /// even), when [`RenderParams::adaptive`] made a pilot.
    pub adaptive_gain: Option<f64>,
    /// Seconds until every pixel had a sample, where the budget could not buy that
    /// ([`passes::PassRun::first_sample_seconds`]).
    pub first_sample_seconds: Option<f64>,
    /// How many pixels took each mixture after the pilot ([`crate::estimators::direct::mixture_choice::PixelTechniques`]:
    /// the image's first, then [`crate::estimators::direct::mixture_choice::CANDIDATES`]).
    pub pixel_techniques: Option<[u64; crate::estimators::direct::mixture_choice::CHOICES]>,
    /// Light draws per sample the render took ([`RenderParams::light_samples`], or the
    /// count chosen by [`RenderParams::auto_light_samples`]).
    pub light_samples: u32,
    /// The view's edge share ([`light_split::edge_share`]), when the render chose its light
    /// draws from it.
    pub edge_share: Option<f64>,
    /// Lambert surfaces drew from products one level coarser
    /// ([`ProductLevel::CoarseDiffuse`], chosen by [`COARSE_EDGE_SHARE`]).
    pub coarse_products: bool,
    /// What the probe measured when the view split and the probe could tell: the ratios
    /// whose [`light_split::ProbeRatios::draws`] is the light draws per sample it found best,
    /// before rounding and capping (cost measured in time, variance a fixed function of
    /// the seed).
    pub probe_ratios: Option<light_split::ProbeRatios>,
    /// Samples every pixel received (the least, with adaptive counts).
    pub spp: u32,
    /// Passes made.
    pub passes: u32,
    /// False when progress stopped a pass part-way.
    pub complete: bool,
    /// Pixel samples taken.
    pub samples: u64,
    /// Samples per pixel on average, and the most any pixel received.
    pub mean_spp: f64,
    pub max_spp: u32,
    /// Primary rays traced.
    pub primary_rays: u64,
    /// Shadow rays traced.
    pub shadow_rays: u64,
    /// BSDF rays traced.
    pub bsdf_rays: u64,
    /// Bounce rays of indirect paths traced.
    pub bounce_rays: u64,
    /// All rays per wall-clock second.
    pub rays_per_second: f64,
    /// Per-stage CPU seconds.
    pub stages: StageSeconds,
    /// Control variate: shading points that looked up the cache.
    pub cache_points: u64,
    /// ... and found no record (plain product sampling there).
    pub points_without_records: u64,
    /// Shadow rays of the shading points toward the map's sun
    /// ([`crate::visibility::cache::interpolant::Interpolant::with_sun`]).
    pub sun_rays: u64,
    /// Records kept, summed over the points that looked up.
    pub records_used: u64,
    /// Points that shared their left neighbour's lookup instead of making one.
    pub shared_lookups: u64,
    /// ... and its `J` too: the same material, shading normal and (a BSDF whose product
    /// ignores the view) so the same product distribution.
    pub reused_integrals: u64,
    /// Anchors whose product distribution was the previous pixel's (the same material
    /// and normal, a product that ignores the view).
    pub reused_products: u64,
    /// Jittered samples whose hit was not their anchor's surface (another object, or a
    /// normal turned beyond the material's product tolerance): they were shaded without
    /// the anchor's product and control variate.
    pub unmatched_samples: u64,
    /// Record predictions that disagreed with a traced shadow ray (CAM08 §5.3).
    pub record_misses: u64,
    /// Record predictions checked against a traced shadow ray.
    pub record_uses: u64,
    /// Records inserted afterwards ([`RenderParams::insert_missing`]).
    pub inserted_records: u64,
    /// Mean `α` over the pixels, per channel.
    pub mean_alpha: [f64; 3],
    /// Method "cv" given no cache: the cache the render built ([`own_cache`]).
    pub own_cache: Option<own_cache::OwnCacheStats>,
    /// Samples whose diffuse indirect light the irradiance cache interpolated.
    pub irradiance_lookups: u64,
    /// ... and those where no record was usable (a path traced instead).
    pub irradiance_misses: u64,
    /// ... and those that took their anchor's irradiance (no record reached the hit).
    pub irradiance_from_anchor: u64,
    /// Channels the gradients pushed below 0, clamped.
    pub irradiance_clamped: u64,
}

/// A rendered image of the direct methods, with their stats as a struct.
pub type Rendered = output::RenderOutput<RenderStats>;

/// Renders `camera`'s view of `scene` lit by `env` and the scene's area lights.
///
/// [`Method::ControlVariate`] reads `cache` (records of this scene); its miss counts are
/// reported to the cache afterwards (`record_misses`), and with `insert_missing` the
/// points that found no record are given one. Without a cache it builds one for the view
/// first ([`own_cache`], [`RenderParams::own_cache`]). `progress(done, planned)` (pixel samples)
/// is called on the calling thread about every 0.1 s and after each pass; returning
/// `false` stops. Work runs on `threads` workers (`None`: all cores). When the pixels
/// need anchors ([`RenderParams::needs_anchors`]) their G-buffer is traced first, once;
/// [`render_from`] takes one already traced.
pub fn render(
    scene: &Scene,
    env: &EnvMap,
    camera: &Camera,
    params: &RenderParams,
    cache: Option<&VisibilityCache>,
    threads: Option<usize>,
    progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
) -> Result<Rendered> {
    if params.method == Method::ControlVariate && cache.is_none() {
        let build = own_cache::render_with_own_cache;
        return build(scene, env, camera, None, params, threads, progress);
    }
    render_with(scene, env, camera, None, params, cache, threads, progress)
}

/// [`render`] through `gbuffer`'s camera with its hits as the pixels' anchors (whatever
/// [`RenderParams::needs_anchors`] says): the points the cache was built at
/// ([`VisibilityCache::build_from`] with the same buffer), no primary ray traced again. A
/// jittered buffer is accepted: the anchors are only where the per-pixel work is done,
/// and every estimate stays unbiased (module docs); without `jitter` the samples are
/// shaded at its hits. `gbuffer` must describe `scene` as posed now.
pub fn render_from(
    scene: &Scene,
    env: &EnvMap,
    gbuffer: &GBuffer,
    params: &RenderParams,
    cache: Option<&VisibilityCache>,
    threads: Option<usize>,
    progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
) -> Result<Rendered> {
    gbuffer.check(scene, None)?;
    let camera = &gbuffer.camera;
    if params.method == Method::ControlVariate && cache.is_none() {
        let build = own_cache::render_with_own_cache;
        return build(scene, env, camera, Some(gbuffer), params, threads, progress);
    }
    render_with(
        scene,
        env,
        camera,
        Some(gbuffer),
        params,
        cache,
        threads,
        progress,
    )
}

#[allow(clippy::too_many_arguments)]
fn render_with(
    scene: &Scene,
    env: &EnvMap,
    camera: &Camera,
    anchors: Option<&GBuffer>,
    params: &RenderParams,
    cache: Option<&VisibilityCache>,
    threads: Option<usize>,
    progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
) -> Result<Rendered> {
    let caches = (cache, None);
    render_with_caches(
        scene, env, camera, anchors, params, caches, threads, progress,
    )
}

/// [`render_with`] with the caches a render may read: the visibility cache (method "cv")
/// and the irradiance cache, whose records then give the diffuse part of the one bounce
/// ([`irradiance`]).
#[allow(clippy::too_many_arguments)]
pub(crate) fn render_with_caches(
    scene: &Scene,
    env: &EnvMap,
    camera: &Camera,
    anchors: Option<&GBuffer>,
    params: &RenderParams,
    (cache, irradiance): (Option<&VisibilityCache>, Option<&IrradianceCache>),
    threads: Option<usize>,
    progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
) -> Result<Rendered> {
    params.validate()?;
    camera.check_buffers()?;
    let cv = params.method == Method::ControlVariate;
    let cache = if cv {
        Some(cache.ok_or_else(|| {
            Error::invalid(
                "cache",
                "method \"cv\" needs a visibility cache of the scene",
            )
        })?)
    } else {
        None
    };
    if let Some(c) = cache {
        c.bind_scene(scene)?;
    }
    // The product needs cells of level >= 1; a 1 x 1 map is the same map at 2 x 2.
    let env = &*env.at_least(2)?;
    let mut lighting = Lighting {
        scene,
        env,
        product_level: params.product_level,
    };
    let (width, height) = (camera.width as usize, camera.height as usize);
    let start = Instant::now();
    let frame = Frame::prepare(scene, camera, anchors, params.needs_anchors(), threads)?;
    let anchors = frame.anchors();
    // Product sampling of jittered samples that mostly leave their anchor's surface builds
    // products for most samples' normals: cheaper ones pay there. So does the control
    // variate without records, which is product sampling (the "auto" cache's coherence
    // check leaves such views without records).
    let samples_products = match params.method {
        Method::Product => true,
        Method::ControlVariate => cache.is_none_or(|c| c.is_empty()),
        _ => false,
    };
    let chooses_level =
        params.product_level == ProductLevel::PerMaterial && samples_products && params.jitter;
    // Light draws per sample, from the anchors where the render chooses them.
    let chooses_draws =
        params.auto_light_samples && params.time_budget.is_some() && params.uses_product();
    let view_edge_share = anchors
        .filter(|_| chooses_level || chooses_draws)
        .map(|g| light_split::edge_share(g, scene));
    if chooses_level && view_edge_share.is_some_and(|share| share >= COARSE_EDGE_SHARE) {
        lighting.product_level = ProductLevel::CoarseDiffuse;
    }
    // The per-level cone tables of B~ are built once per process; build them before the
    // passes so the first pass's timing models what the others cost.
    if matches!(params.method, Method::Product | Method::ControlVariate) {
        with_threads(threads, || {
            for object in &scene.mesh().objects {
                crate::bsdf::CellCones::get(lighting.product_level.for_material(&object.material));
            }
        })?;
    }
    let edge_share = view_edge_share.filter(|_| chooses_draws);
    let light_samples = edge_share.map_or(params.light_samples, light_split::draws_for);
    let mut method = DirectMethod {
        lighting,
        camera,
        anchors,
        params,
        cache,
        chroma: cv.then(|| MapChroma::new(env)),
        // Jittered hits off their anchor's surface draw from products by normal.
        normal_products: (params.jitter && params.uses_product())
            .then(|| NormalProducts::new(env, lighting.product_level)),
        techniques: params.techniques(),
        // Method "product" under a budget learns its mixture from the probe pass.
        learn: learn_techniques_per_pixel(params) && params.time_budget.is_some(),
        learnt: None,
        // Method "product" with adaptive counts chooses each pixel's mixture after the
        // pilot.
        choose_mixtures: params.adaptive && learn_techniques_per_pixel(params),
        pixel_techniques: None,
        light_samples,
        splits: edge_share.is_some() && light_samples > 1,
        probe_ratios: None,
        irradiance,
    };
    let pass_params = PassParams {
        spp: params.spp,
        time_budget: params.time_budget,
        adaptive: params.adaptive,
        first_spp: None,
    };
    let run = run_passes(
        &mut method,
        width,
        height,
        &pass_params,
        start,
        threads,
        progress,
    )?;
    let alpha = method.alphas(&run.sums, width, height);
    let (image, variance) = sums::resolve(&run.sums, &alpha);
    let mut stats = RenderStats {
        spp: run.min_spp(),
        passes: run.passes,
        complete: run.complete,
        samples: run.samples(),
        mean_spp: run.mean_spp(),
        max_spp: run.max_spp(),
        primary_rays: frame.primary_rays,
        adaptive_gain: run.adaptive_gain,
        first_sample_seconds: run.first_sample_seconds,
        edge_share,
        ..RenderStats::default()
    };
    stats.stages.primary = frame.primary_seconds;
    let sample_counts = run.counts();
    method.finish(run.total, &alpha, &mut stats, threads)?;
    stats.seconds = start.elapsed().as_secs_f64();
    let rays = stats.primary_rays + stats.shadow_rays + stats.bsdf_rays + stats.bounce_rays;
    stats.rays_per_second = rays as f64 / stats.seconds.max(1e-9);
    Ok(Rendered {
        width: camera.width,
        height: camera.height,
        image,
        variance,
        alpha: cv.then(|| alpha.iter().map(|a| a.map(|v| v as f32)).collect()),
        sample_counts,
        stats,
    })
}

/// Whether a render's mixture is learnt (from the probe) and chosen per pixel (after an
/// adaptive pilot): method "product" shading direct light with `learn_techniques`.
fn learn_techniques_per_pixel(params: &RenderParams) -> bool {
    params.learn_techniques && params.method == Method::Product && params.direct
}
