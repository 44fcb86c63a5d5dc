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
//! packets of [`PACKET`] from the eye, [`crate::geometry::Bvh::intersect_packet`]) and
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
//! ([`Shader::shared_lookup`]): any `Ṽ` keeps the control variate unbiased, and the lookup
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
//! ([`PassSchedule`]). The anchors' work is redone each pass from the G-buffer's hits (it
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
//! through [`PixelSampler`]: Owen-scrambled Sobol points, so the samples of a pixel are
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

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::Instant;

use glam::{Vec3, Vec3A};
use rayon::prelude::*;

use crate::bsdf::Material;
use crate::camera::{Camera, GBuffer, DIM_PIXEL_JITTER};
use crate::error::{Error, Result};
use crate::estimators::control_variate::{
    control_sample, neighbour_alphas, AlphaRule, CvSums, LobeControl,
};
use crate::estimators::direct::{
    DirectCounters, Lighting, Method, ProductLevel, ShadingPoint, Techniques,
};
use crate::estimators::indirect::{estimate_indirect, shading_point_at, PathParams, MAX_BOUNCES};
use crate::estimators::normal_products::NormalProducts;
use crate::geometry::bvh::PACKET;
use crate::geometry::{Scene, SurfaceHit, TraversalCounters};
use crate::lights::envmap::chroma::MapChroma;
use crate::lights::envmap::product::{GuidedProduct, ProductDistribution};
use crate::lights::envmap::{luminance, EnvMap};
use crate::moments::Moments;
use crate::parallel::{run_with_progress, with_threads};
use crate::sampling::rng::Sampler;
use crate::sampling::sobol::PixelSampler;
use crate::visibility::cache::interpolant::{ControlTables, Interpolant, ALPHA_MAX};
use crate::visibility::cache::{CacheState, Lookup, VisibilityCache};

pub mod adaptive;
pub(crate) mod schedule;
pub mod split;

use adaptive::{
    pilot_spp, sample_cap, Choices, DrawMoments, PixelTechniques, SampleShares, RELMSE_FLOOR,
};
use schedule::{PassSchedule, PassWork};

/// Rows per work item of a pass with even counts: small enough to balance two to hundreds
/// of threads.
const BAND_ROWS: usize = 4;

/// Most samples per pixel a render takes.
pub const MAX_SPP: u32 = 1 << 20;

/// Least edge share ([`split::edge_share`]) of a view whose jittered product sampling
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
    /// with its shadow ray, from a stream of its own ([`PixelSampler::light_draw`]). More
    /// than one pays where shadow rays are cheap beside the rest of a sample and the
    /// light's noise outweighs the pixel's.
    pub light_samples: u32,
    /// Method "product" under a time budget: the passes after the probe use the mixture
    /// weights learnt from the probe's draws ([`Techniques::learnt`]) instead of the given
    /// ones; with [`Self::adaptive`] counts, every pixel then takes the mixture its
    /// neighbours' pilot draws favour ([`adaptive::PixelTechniques`]).
    pub learn_techniques: bool,
    /// Samples go where they cut the image's relMSE most ([`adaptive`]): a pilot pass
    /// takes a quarter of them evenly, the rest follow each pixel's share measured from
    /// its neighbours. `spp` is then the mean per pixel (with a time budget, the most on
    /// average); renders of fewer than [`adaptive::MIN_ADAPTIVE_SPP`] samples per pixel
    /// take them evenly.
    pub adaptive: bool,
    /// The product methods under a time budget: the light draws per sample are chosen from
    /// the anchors and the probe pass ([`split`]: up to [`split::SPLIT_DRAWS`] where the
    /// view is mostly smooth surfaces, as many as the probe measures best; one where
    /// jittered hits leave their anchor's surface) instead of [`Self::light_samples`],
    /// which must then be 1.
    pub auto_light_samples: bool,
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
        self.direct && matches!(self.method, Method::Product | Method::ControlVariate)
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
    /// How many pixels took each mixture after the pilot ([`adaptive::PixelTechniques`]:
    /// the image's first, then [`adaptive::CANDIDATES`]).
    pub pixel_techniques: Option<[u64; adaptive::CHOICES]>,
    /// Light draws per sample the render took ([`RenderParams::light_samples`], or the
    /// count chosen by [`RenderParams::auto_light_samples`]).
    pub light_samples: u32,
    /// The view's edge share ([`split::edge_share`]), when the render chose its light
    /// draws from it.
    pub edge_share: Option<f64>,
    /// Lambert surfaces drew from products one level coarser
    /// ([`ProductLevel::CoarseDiffuse`], chosen by [`COARSE_EDGE_SHARE`]).
    pub coarse_products: bool,
    /// What the probe measured when the view split and the probe could tell: the ratios
    /// whose [`split::ProbeRatios::draws`] is the light draws per sample it found best,
    /// before rounding and capping (cost measured in time, variance a fixed function of
    /// the seed).
    pub probe_ratios: Option<split::ProbeRatios>,
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
}

/// A rendered image.
#[derive(Clone, Debug, PartialEq)]
pub struct Rendered {
    pub width: u32,
    pub height: u32,
    /// Mean radiance per pixel, row-major, row 0 at the top.
    pub image: Vec<[f32; 3]>,
    /// Per-pixel variance of the mean, per channel (infinite below two samples).
    pub variance: Vec<[f32; 3]>,
    /// Per-pixel `α` of the control variate (only for [`Method::ControlVariate`]).
    pub alpha: Option<Vec<[f32; 3]>>,
    /// Samples each pixel took, row-major.
    pub sample_counts: Vec<u32>,
    pub stats: RenderStats,
}

/// What one band of one pass did.
#[derive(Clone, Default)]
struct BandWork {
    direct: DirectCounters,
    bvh: TraversalCounters,
    primary_rays: u64,
    primary_ns: u64,
    product_ns: u64,
    lookup_ns: u64,
    control_ns: u64,
    shading_ns: u64,
    indirect_ns: u64,
    sample_primary_ns: u64,
    /// Pixels shaded in this pass (each prepares its anchor) and samples taken.
    anchored_pixels: u64,
    samples: u64,
    /// CPU time of the anchors (all of [`Shader::prepare`]) and of the samples.
    anchor_ns: u64,
    sample_ns: u64,
    /// Samples whose hit left the control variate out (another object than the anchor).
    unmatched_samples: u64,
    cache_points: u64,
    points_without_records: u64,
    /// Shadow rays toward the map's sun.
    sun_rays: u64,
    records_used: u64,
    /// Per record id: (misses, uses).
    verdicts: BTreeMap<u32, (u32, u32)>,
    /// Pixels whose shading point found no record: (pixel, position, normal, footprint).
    requests: Vec<(u32, Vec3, Vec3, f32)>,
    /// The last lookup of this band, which the next pixel may share (see
    /// [`Shader::shared_lookup`]).
    last_lookup: Option<SharedLookup>,
    /// The last product distribution of this band that ignores the view, with its
    /// material and normal: a pixel with the same key has the same product.
    last_product: Option<((Material, Vec3), Arc<ProductDistribution>)>,
    /// Anchors that took the previous pixel's product.
    reused_products: u64,
    /// Lookups answered by a neighbour's.
    shared_lookups: u64,
    /// ... whose `J` was the neighbour's too (the same product distribution).
    reused_integrals: u64,
    /// The pixel being shaded, and the matched draws kept for learning the mixture:
    /// (pixel, `f cos L V` in luminance, techniques' densities, mixture density).
    pixel: u32,
    draws: Vec<(u32, f64, [f64; 4], f64)>,
    /// The pixel's draws for [`PixelTechniques`] (the adaptive pilot).
    moments: DrawMoments,
    /// What the probe measures for [`split::draws_from`], and the pixel's moments, over
    /// its samples of the pass, of their values and of their first-draw values (per
    /// channel).
    split: split::SplitProbe,
    pixel_values: [[Moments; 3]; 2],
}

/// A lookup, the point it was made for, and the interpolant made of it there.
#[derive(Clone)]
struct SharedLookup {
    pixel: usize,
    position: Vec3,
    normal: Vec3,
    d_max: f32,
    lookup: Lookup,
    /// What the point's product distribution depended on — its material and shading
    /// normal — when it had one and the material's product ignores the view: a point
    /// with the same key has the same product, so `interpolant`'s `J` holds there too.
    product_key: Option<(Material, Vec3)>,
    interpolant: Interpolant,
    /// The guided product made of the interpolant and that product.
    guided: Option<Arc<GuidedProduct>>,
}

impl BandWork {
    fn merge(&mut self, o: BandWork) {
        self.direct.shadow_rays += o.direct.shadow_rays;
        self.direct.bsdf_rays += o.direct.bsdf_rays;
        self.direct.bounce_rays += o.direct.bounce_rays;
        self.bvh += o.bvh;
        self.primary_rays += o.primary_rays;
        self.primary_ns += o.primary_ns;
        self.product_ns += o.product_ns;
        self.lookup_ns += o.lookup_ns;
        self.control_ns += o.control_ns;
        self.shading_ns += o.shading_ns;
        self.indirect_ns += o.indirect_ns;
        self.sample_primary_ns += o.sample_primary_ns;
        self.anchor_ns += o.anchor_ns;
        self.sample_ns += o.sample_ns;
        self.unmatched_samples += o.unmatched_samples;
        self.cache_points += o.cache_points;
        self.points_without_records += o.points_without_records;
        self.sun_rays += o.sun_rays;
        self.records_used += o.records_used;
        self.shared_lookups += o.shared_lookups;
        self.reused_integrals += o.reused_integrals;
        self.reused_products += o.reused_products;
        for (id, (m, u)) in o.verdicts {
            let e = self.verdicts.entry(id).or_default();
            e.0 += m;
            e.1 += u;
        }
        self.requests.extend(o.requests);
    }
}

/// A pixel's anchor: the hit through its centre, with everything computed once for it.
enum Point {
    /// The primary ray escaped: the environment seen directly.
    Miss(Vec3),
    Surface(Box<SurfacePoint>),
}

struct SurfacePoint {
    sp: ShadingPoint,
    /// The object hit.
    object: u32,
    /// `cos` of the material's [`crate::bsdf::Material::product_tolerance`]: a sample's
    /// hit on the same object whose normal is this close shares the anchor's work.
    cos_match: f32,
    /// [`crate::bsdf::Material::channel_ratios`] of the material: the control variate's
    /// per-channel scale.
    ratios: [f64; 3],
    emitted: Vec3,
    product: Option<Arc<ProductDistribution>>,
    /// The product guided by the records' visibility (method "cv", records found).
    guided: Option<Arc<GuidedProduct>>,
    interpolant: Interpolant,
    /// The control variate per lobe, where the material's lobes differ in colour.
    lobes: Option<Box<LobeControl>>,
}

/// Everything a pass reads.
struct Shader<'a> {
    lighting: Lighting<'a>,
    camera: &'a Camera,
    /// The pixels' anchors ([`RenderParams::needs_anchors`]).
    anchors: Option<&'a GBuffer>,
    params: &'a RenderParams,
    /// The cache's records (read-locked for the pass) and its search-radius scale.
    cache: Option<(&'a CacheState, &'a VisibilityCache)>,
    chroma: Option<&'a MapChroma>,
    /// The mixture's weights.
    techniques: Techniques,
    /// Whether matched draws are kept for [`Techniques::learnt`] (the probe pass).
    learning: bool,
    /// The mixtures whose moments the pixels' draws add up (the adaptive pilot), when
    /// they do ([`DrawMoments`]).
    choices: Option<Choices>,
    /// Each pixel's mixture, chosen after the pilot ([`PixelTechniques`]).
    pixel_techniques: Option<&'a PixelTechniques>,
    /// Light draws per sample.
    light_samples: u32,
    /// Whether the samples measure their variance with all draws and with the first
    /// alone, and the draws' time ([`split::SplitProbe`]).
    measure_split: bool,
    /// Products by normal for diffuse hits off their anchor's surface.
    normal_products: Option<&'a NormalProducts<'a>>,
}

/// Draws a band keeps for [`Techniques::learnt`].
const LEARNT_DRAWS_PER_BAND: usize = 2048;

fn elapsed_ns(since: Instant) -> u64 {
    since.elapsed().as_nanos() as u64
}

impl Shader<'_> {
    /// The hits of the jittered primary rays of samples `rngs` of `pixel` (at most
    /// [`PACKET`]), traced as one packet from the eye (a pixel's rays visit nearly the
    /// same nodes, so together they cost a fraction of tracing them one by one), with the
    /// rays' directions. Lanes past `rngs.len()` hold nothing.
    fn trace_samples(
        &self,
        pixel: usize,
        rngs: &[PixelSampler],
        work: &mut BandWork,
    ) -> ([Option<SurfaceHit>; PACKET], [Vec3A; PACKET]) {
        let width = self.camera.width as usize;
        let (px, py) = ((pixel % width) as u32, (pixel / width) as u32);
        let n = rngs.len();
        let mut directions = [Vec3A::ZERO; PACKET];
        let jitters = rngs.iter().map(|rng| rng.get2(DIM_PIXEL_JITTER));
        self.camera
            .pixel_directions(px, py, jitters, &mut directions);
        let start = Instant::now();
        let hits = self.lighting.scene.intersect_packet(
            self.camera.eye,
            &directions[..n],
            &[f32::INFINITY; PACKET][..n],
            &mut work.bvh,
        );
        work.sample_primary_ns += elapsed_ns(start);
        work.primary_rays += n as u64;
        (hits, directions)
    }

    /// The anchor's `Ṽ` on the map's sun ([`Interpolant::with_sun`]): 1 when a shadow ray
    /// from `sp` toward `sun` (a unit direction) escapes, 0 when it is blocked or `sun` lies
    /// below the surface.
    fn sun_visibility(&self, sp: &ShadingPoint, sun: Vec3, work: &mut BandWork) -> f64 {
        if sp.normal.dot(sun) <= 0.0 {
            return 0.0;
        }
        work.sun_rays += 1;
        let scene = self.lighting.scene;
        !scene.occluded1(sp.origin, sun, f32::INFINITY, &mut work.bvh) as u8 as f64
    }

    /// Prepares the anchor of `pixel` at its G-buffer hit.
    fn prepare(&self, anchors: &GBuffer, pixel: usize, work: &mut BandWork) -> Point {
        let dir = Vec3::from(anchors.direction[pixel]);
        let Some(hit) = anchors.surface_hit(pixel) else {
            return Point::Miss(self.lighting.env.eval(dir));
        };
        let sp = shading_point_at(self.lighting.scene, &hit, -dir);
        let normal = sp.normal;
        let emitted = self.lighting.scene.emitted(&hit, sp.wo);
        let mut product = None;
        // A product that ignores the view is the previous pixel's when the material and
        // normal are (flat diffuse surfaces: most pixels of most scenes).
        let product_key = (!sp.material.product_depends_on_wo()).then_some((sp.material, normal));
        if self.params.uses_product() {
            let start = Instant::now();
            product = match (&work.last_product, product_key) {
                (Some((key, p)), Some(k)) if *key == k => {
                    work.reused_products += 1;
                    Some(p.clone())
                }
                _ => self.lighting.product(&sp).map(Arc::new),
            };
            if let (Some(k), Some(p)) = (product_key, &product) {
                work.last_product = Some((k, p.clone()));
            }
            work.product_ns += elapsed_ns(start);
        }
        let mut interpolant = Interpolant::EMPTY;
        let mut guided = None;
        let mut lobes = None;
        if let (Some((state, cache)), Some(chroma)) = (self.cache, self.chroma) {
            let start = Instant::now();
            let d_max = cache.params().d_max_scale * anchors.footprint[pixel];
            let shared = self.shared_lookup(pixel, hit.position, normal, d_max, work);
            let lookup = match &shared {
                Some(shared) => {
                    work.shared_lookups += 1;
                    shared.lookup
                }
                None => state.lookup_records(cache.params(), hit.position, normal, d_max),
            };
            let looked = Instant::now();
            work.lookup_ns += (looked - start).as_nanos() as u64;
            // The neighbour's J (and guided product) hold when its product was this
            // point's too.
            let same_product = shared.as_ref().filter(|s| {
                product.is_some() && product_key.is_some() && s.product_key == product_key
            });
            interpolant = match (product.as_deref(), same_product) {
                (Some(_), Some(s)) if !lookup.neighbours().is_empty() => {
                    work.reused_integrals += 1;
                    guided = s.guided.clone();
                    s.interpolant
                }
                (Some(p), _) if !lookup.neighbours().is_empty() => {
                    let tables = ControlTables::new(p, chroma, state.store().m());
                    let env = self.lighting.env;
                    let mut interpolant = Interpolant::new(state, &lookup, Some((&tables, p, env)));
                    let sun = chroma.sun().map(|d| self.sun_visibility(&sp, d, work));
                    if let Some(sun) = sun {
                        interpolant = interpolant.with_sun(state, &tables, p, sun);
                    }
                    if self.techniques.guided > 0.0 {
                        guided = p
                            .guided(interpolant.cell_visibility(state, p.level()))
                            .map(Arc::new);
                    }
                    lobes =
                        LobeControl::new(p, &sp, (state, &lookup), chroma, env, sun).map(Box::new);
                    interpolant
                }
                _ => Interpolant::new(state, &lookup, None),
            };
            if shared.is_none() {
                work.last_lookup = Some(SharedLookup {
                    pixel,
                    position: hit.position,
                    normal,
                    d_max,
                    lookup,
                    product_key: product.as_ref().and(product_key),
                    interpolant,
                    guided: guided.clone(),
                });
            }
            work.control_ns += elapsed_ns(looked);
            work.cache_points += 1;
            work.records_used += interpolant.ids().len() as u64;
            if interpolant.is_empty() {
                work.points_without_records += 1;
                if self.params.insert_missing {
                    work.requests
                        .push((pixel as u32, hit.position, normal, d_max));
                }
            }
        }
        Point::Surface(Box::new(SurfacePoint {
            ratios: sp.material.channel_ratios().map(f64::from),
            object: hit.obj,
            cos_match: sp.material.product_tolerance().cos(),
            sp,
            emitted,
            product,
            guided,
            interpolant,
            lobes,
        }))
    }

    /// The lookup of the pixel to the left when this pixel may share it: an odd column, and
    /// the neighbour's anchor within a quarter of `d_max` with a normal within 5°. Records
    /// chosen for a point that close serve this one about as well (the estimate stays
    /// unbiased whatever `Ṽ` is), and half the lookups are saved.
    fn shared_lookup(
        &self,
        pixel: usize,
        position: Vec3,
        normal: Vec3,
        d_max: f32,
        work: &BandWork,
    ) -> Option<SharedLookup> {
        const COS_5_DEG: f32 = 0.996_194_7;
        let width = self.camera.width as usize;
        let last = work.last_lookup.as_ref()?;
        let odd = (pixel % width) % 2 == 1;
        (odd && last.pixel + 1 == pixel
            && last.normal.dot(normal) >= COS_5_DEG
            && last.position.distance(position) <= 0.25 * d_max.min(last.d_max))
        .then(|| last.clone())
    }

    /// One sample at `sp` (the anchor's point, or the sample's own hit with `anchor` its
    /// pixel's): the plain estimate `Z` and the control variate's zero-mean term
    /// `W = g/p − J` (zero without records, or when `matched` is false: the hit is not the
    /// anchor's surface). Record verdicts go to `verdicts[k]` (misses, uses) for kept
    /// record `k`.
    #[allow(clippy::too_many_arguments)]
    fn sample(
        &self,
        anchor: Option<&SurfacePoint>,
        sp: &ShadingPoint,
        emitted: Vec3,
        matched: bool,
        rng: &PixelSampler,
        work: &mut BandWork,
        verdicts: &mut [(u32, u32)],
    ) -> (Vec3, [f64; 3]) {
        let indirect = self.indirect(sp, rng, work);
        if !self.params.direct {
            return (indirect, [0.0; 3]);
        }
        if !self.params.uses_product() {
            let l = self.lighting.estimate(
                sp,
                self.params.method,
                rng,
                &mut work.direct,
                &mut work.bvh,
            );
            return (emitted + l + indirect, [0.0; 3]);
        }
        let mixture = match self.pixel_techniques {
            Some(p) => *p.get(work.pixel as usize),
            None => self.techniques,
        };
        // The anchor's product where it describes the hit; for a hit elsewhere with a
        // diffuse part, the product of the nearest grid normal for that part's share;
        // else BSDF and map sampling.
        let (product, guided, techniques, share) = match anchor {
            Some(a) if matched && a.product.is_some() => {
                (a.product.as_deref(), a.guided.as_deref(), mixture, 1.0)
            }
            _ => match self
                .normal_products
                .and_then(|t| t.get(&sp.material, sp.normal))
            {
                Some(p) => {
                    let share = NormalProducts::diffuse_share(&sp.material);
                    (Some(p), None, mixture.with_product_share(share), share)
                }
                None => (None, None, mixture.without_product(), 1.0),
            },
        };
        // The pilot's candidate mixtures as this hit would draw them.
        let choices = match (self.choices, product) {
            (Some(c), Some(_)) if share < 1.0 => Some(c.with_product_share(share)),
            (c, Some(_)) => c,
            (_, None) => None,
        };
        // The control variate where the anchor's records and product describe the hit.
        let control = match (anchor, self.cache, self.chroma, matched) {
            (Some(a), Some((state, _)), Some(chroma), true)
                if !a.interpolant.is_empty() && a.product.is_some() =>
            {
                Some((a, state, chroma))
            }
            _ => None,
        };
        let draws = self.light_samples;
        let mut l = Vec3::ZERO;
        let mut g_over_p = [0.0; 3];
        let mut gd_over_p = [0.0; 3];
        // The probe's one-draw value of the sample, and the draws' time.
        let measure = self.measure_split && draws > 1;
        let mut first = Vec3::ZERO;
        let drawing = measure.then(Instant::now);
        for j in 0..draws {
            let draw = if draws == 1 {
                *rng
            } else {
                rng.light_draw(j, draws)
            };
            let (lj, drawn) = self.lighting.estimate_mixture(
                sp,
                product,
                guided,
                &techniques,
                &draw,
                &mut work.direct,
                &mut work.bvh,
            );
            l += lj;
            if j == 0 {
                first = lj;
            }
            if let (Some(choices), Some(d)) = (&choices, &drawn) {
                let value = luminance(d.value.to_array());
                work.moments.add(choices, value, d.technique_pdfs, d.pdf);
            }
            if let (true, true, Some(d)) = (self.learning, product.is_some(), &drawn) {
                if work.draws.len() < LEARNT_DRAWS_PER_BAND {
                    work.draws.push((
                        work.pixel,
                        luminance(d.value.to_array()),
                        d.technique_pdfs,
                        d.pdf,
                    ));
                }
            }
            // g/p of the mixture; a draw of no direction is a sample of g/p = 0.
            if let (Some((a, state, chroma)), Some(d)) = (control, drawn) {
                let interp = &a.interpolant;
                let g = control_sample(state, interp, chroma, d.square);
                if let Some(visible) = d.visible {
                    for (k, v) in verdicts.iter_mut().enumerate().take(interp.ids().len()) {
                        let predicted = g.visible_mask >> k & 1 == 1;
                        v.0 += (predicted != visible) as u32;
                        v.1 += 1;
                    }
                }
                for (c, gp) in g_over_p.iter_mut().enumerate() {
                    *gp += g.value[c] * d.product_ratio;
                }
                if let Some(lobes) = &a.lobes {
                    let share = lobes.share(d.square) * d.product_ratio;
                    for (c, gp) in gd_over_p.iter_mut().enumerate() {
                        *gp += g.value[c] * share;
                    }
                }
            }
        }
        let inv = 1.0 / draws as f64;
        let z = emitted + l * inv as f32 + indirect;
        if let Some(started) = drawing {
            work.split.draw_ns += elapsed_ns(started);
            let one = emitted + first + indirect;
            let [all, first] = &mut work.pixel_values;
            Moments::push_each(all, z.as_dvec3().to_array());
            Moments::push_each(first, one.as_dvec3().to_array());
        }
        let Some((a, _, _)) = control else {
            return (z, [0.0; 3]);
        };
        let g_over_p = g_over_p.map(|g| g * inv);
        let j = &a.interpolant.j;
        let w = match &a.lobes {
            Some(l) => l.w(g_over_p, gd_over_p.map(|g| g * inv), j),
            None => std::array::from_fn(|c| a.ratios[c] * (g_over_p[c] - j[c])),
        };
        (z, w)
    }

    /// The light of [`RenderParams::bounces`] bounces at `sp` (zero without), on the
    /// dimensions above the direct estimate's ([`crate::estimators::indirect`]).
    fn indirect(&self, sp: &ShadingPoint, rng: &PixelSampler, work: &mut BandWork) -> Vec3 {
        if self.params.bounces == 0 {
            return Vec3::ZERO;
        }
        let start = Instant::now();
        let l = estimate_indirect(
            &self.lighting,
            sp,
            &PathParams::new(self.params.bounces),
            rng,
            &mut work.direct,
            &mut work.bvh,
        );
        work.indirect_ns += elapsed_ns(start);
        l
    }

    /// What the camera sees of the map through a pixel: direct light.
    fn background(&self, radiance: Vec3) -> Vec3 {
        if self.params.direct {
            radiance
        } else {
            Vec3::ZERO
        }
    }

    /// Samples `samples` of one pixel, accumulated into `acc`.
    fn shade_pixel(
        &self,
        pixel: usize,
        samples: std::ops::Range<u32>,
        acc: &mut CvSums,
        work: &mut BandWork,
    ) {
        let seed = self.params.seed;
        work.pixel = pixel as u32;
        if self.measure_split {
            work.pixel_values = Default::default();
        }
        let n_samples = samples.len() as u32;
        let start = Instant::now();
        let anchor = self.anchors.map(|g| self.prepare(g, pixel, work));
        let prepared = Instant::now();
        work.anchor_ns += (prepared - start).as_nanos() as u64;
        let anchor_surface = match &anchor {
            Some(Point::Surface(p)) => Some(&**p),
            _ => None,
        };
        // Record verdicts add up over the pixel and reach the band's map once.
        let mut verdicts = [(0u32, 0u32); crate::visibility::cache::interpolant::MAX_KEPT];
        if self.params.jitter {
            let scene = self.lighting.scene;
            // Packets of the pixel's samples, shaded in sample order straight from the
            // packet's arrays (no hit is copied on the way).
            for first in samples.clone().step_by(PACKET) {
                let n = (samples.end - first).min(PACKET as u32) as usize;
                // Only the packet's own samples are made; the rest of the array repeats
                // the first.
                let head = PixelSampler::new(seed, pixel as u64, first as u64);
                let rngs: [PixelSampler; PACKET] = std::array::from_fn(|k| match k {
                    0 => head,
                    k if k < n => {
                        PixelSampler::new(seed, pixel as u64, (first as usize + k) as u64)
                    }
                    _ => head,
                });
                let (hits, directions) = self.trace_samples(pixel, &rngs[..n], work);
                for ((hit, dir), rng) in hits.iter().zip(directions).zip(&rngs).take(n) {
                    let dir = Vec3::from(dir);
                    let (z, w) = match hit {
                        None => (self.background(self.lighting.env.eval(dir)), [0.0; 3]),
                        Some(hit) => {
                            let sp = shading_point_at(scene, hit, -dir);
                            let emitted = scene.emitted(hit, sp.wo);
                            let matched = anchor_surface.is_some_and(|a| {
                                a.object == hit.obj && a.sp.normal.dot(sp.normal) >= a.cos_match
                            });
                            work.unmatched_samples += !matched as u64;
                            self.sample(
                                anchor_surface,
                                &sp,
                                emitted,
                                matched,
                                rng,
                                work,
                                &mut verdicts,
                            )
                        }
                    };
                    acc.add(z, w);
                }
            }
        } else {
            for s in samples {
                let rng = PixelSampler::new(seed, pixel as u64, s as u64);
                let (z, w) = match anchor.as_ref().expect("fixed points have an anchor") {
                    Point::Miss(l) => (self.background(*l), [0.0; 3]),
                    Point::Surface(p) => {
                        self.sample(Some(p), &p.sp, p.emitted, true, &rng, work, &mut verdicts)
                    }
                };
                acc.add(z, w);
            }
        }
        let sampled = elapsed_ns(prepared);
        work.sample_ns += sampled;
        work.shading_ns += sampled;
        if self.measure_split {
            probe_pixel(n_samples, sampled, work);
        }
        if let Some(a) = anchor_surface {
            flush_verdicts(a, &mut verdicts, work);
        }
    }
}

/// Adds a measured pixel (`n` samples taking `ns`, their moments in `work.pixel_values`)
/// to the band's [`split::SplitProbe`]: each channel's variance between samples, of their
/// values and of their first draws', weighted as the pixel counts in relMSE.
fn probe_pixel(n: u32, ns: u64, work: &mut BandWork) {
    work.split.sample_ns += ns;
    work.split.samples += n as u64;
    let [all, first] = &work.pixel_values;
    for (all, first) in all.iter().zip(first) {
        let weight = 1.0 / (all.mean * all.mean + RELMSE_FLOOR);
        work.split.all += weight * all.variance();
        work.split.first += weight * first.variance();
    }
}

/// Adds a point's per-record `(misses, uses)` to the band's totals and clears them.
fn flush_verdicts(point: &SurfacePoint, verdicts: &mut [(u32, u32)], work: &mut BandWork) {
    for (id, v) in point.interpolant.ids().iter().zip(verdicts.iter()) {
        if v.1 > 0 {
            let e = work.verdicts.entry(*id).or_default();
            e.0 += v.0;
            e.1 += v.1;
        }
    }
    verdicts.fill((0, 0));
}

/// Renders `camera`'s view of `scene` lit by `env` and the scene's area lights.
///
/// [`Method::ControlVariate`] needs `cache` (records of this scene); its miss counts are
/// reported to the cache afterwards (`record_misses`), and with `insert_missing` the
/// points that found no record are given one. `progress(done, planned)` (pixel samples)
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
    let chroma = cv.then(|| MapChroma::new(env));
    let mut lighting = Lighting {
        scene,
        env,
        product_level: params.product_level,
    };
    let (width, height) = (camera.width as usize, camera.height as usize);
    let pixels = width * height;
    let start = Instant::now();
    let mut sums = vec![CvSums::default(); pixels];
    let mut total = BandWork::default();
    let mut passes = 0u32;
    let mut complete = true;
    let planned = params.spp as u64 * pixels as u64;
    let done = AtomicU64::new(0);
    let cancel = AtomicBool::new(false);
    // The BVH is built once, in parallel, before the passes.
    with_threads(threads, || {
        let _ = scene.bvh();
    })?;
    // The anchors' G-buffer, traced once for every pass.
    let traced = match anchors {
        None if params.needs_anchors() => {
            let started = Instant::now();
            let (g, threads) = with_threads(threads, || {
                let g = GBuffer::render(scene, camera, 0, false, None);
                (g, rayon::current_num_threads())
            })?;
            // CPU seconds, as the other stages count them.
            total.primary_ns += started.elapsed().as_nanos() as u64 * threads as u64;
            total.primary_rays += pixels as u64;
            Some(g?)
        }
        _ => None,
    };
    let anchors = anchors.or(traced.as_ref());
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
        .map(|g| split::edge_share(g, scene));
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
    let mut light_samples = edge_share.map_or(params.light_samples, split::draws_for);
    let mut probe_ratios = None;
    let splits = edge_share.is_some() && light_samples > 1;
    let mut schedule = PassSchedule::default();
    // Method "product" under a budget learns its mixture from the probe pass.
    let mut techniques = params.techniques();
    let learn = learn_techniques_per_pixel(params) && params.time_budget.is_some();
    let mut learnt = None;
    let mut taken = 0u64;
    // Adaptive renders: the shares measured after the pilot pass, the most samples a
    // pixel may take, and each pixel's CPU nanoseconds per sample in its latest pass.
    let adapt = params.adaptive;
    let mut shares: Option<(SampleShares, u32)> = None;
    let mut pilot_state = vec![PixelPilot::default(); pixels];
    // Method "product" with adaptive counts chooses each pixel's mixture after the pilot.
    let choose_mixtures = adapt && learn_techniques_per_pixel(params);
    let mut pixel_techniques: Option<PixelTechniques> = None;
    // Jittered hits off their anchor's surface draw from products by normal.
    let normal_products = (params.jitter && params.uses_product())
        .then(|| NormalProducts::new(env, lighting.product_level));
    let mut adaptive_gain = None;
    let counts = |sums: &[CvSums]| sums.iter().map(|s| s.n).collect::<Vec<u32>>();
    let alphas = |sums: &[CvSums]| pixel_alphas(cv, params.alpha, sums, width, height);
    loop {
        // Each pass brings the pixels it covers up to their target.
        let mut pilot = None;
        let (targets, probe) = match params.time_budget {
            None if passes == 0 => match pilot_spp(params.spp).filter(|_| adapt) {
                Some(p) => {
                    pilot = Some(sample_cap(params.spp, MAX_SPP));
                    (Targets::Even(p), false)
                }
                None => (Targets::Even(params.spp), false),
            },
            // The adaptive pass of a render of `spp` samples per pixel on average: the
            // budget is the samples left.
            None if passes == 1 && shares.is_some() => {
                let (shares, cap) = shares.as_ref().expect("measured after the pilot");
                let current = counts(&sums);
                let left = planned.saturating_sub(taken) as f64;
                let lambda = shares.scale_for(&current, *cap, left, |_, added| added as f64);
                (Targets::scaled(shares, lambda, &current, *cap), false)
            }
            None => break,
            Some(_) if passes == 0 => {
                (Targets::Even(PassSchedule::PROBE_SPP.min(params.spp)), true)
            }
            Some(budget) => {
                let left = budget - start.elapsed().as_secs_f64();
                let min = sums.iter().map(|s| s.n).min().unwrap_or(0);
                let done_all = match shares {
                    Some(_) => taken >= planned,
                    None => min >= params.spp,
                };
                if done_all {
                    break;
                }
                match &shares {
                    Some((shares, cap)) => {
                        let current = counts(&sums);
                        let (per_pixel, wall_ns) =
                            (schedule.anchor_seconds(), schedule.wall_per_cpu_ns());
                        let mean_ns = schedule.sample_ns_mean();
                        let cost = |i: usize, added: u32| {
                            let ns = match pilot_state[i].ns_per_sample {
                                ns if ns.is_finite() => ns as f64,
                                _ => mean_ns,
                            };
                            per_pixel + wall_ns * ns * added as f64
                        };
                        let by_time = shares.scale_for(&current, *cap, schedule.spend(left), cost);
                        let left_samples = planned.saturating_sub(taken) as f64;
                        let by_count =
                            shares.scale_for(&current, *cap, left_samples, |_, a| a as f64);
                        let t = Targets::scaled(shares, by_time.min(by_count), &current, *cap);
                        // A pass is worth its anchors when it adds a sample per pixel on
                        // average.
                        if t.added(&current) < pixels as u64 {
                            break;
                        }
                        (t, false)
                    }
                    None => match schedule.next_target(left, pixels as u64, taken, min) {
                        Some(t) => {
                            let t = t.min(params.spp);
                            match pilot_spp(t).filter(|&p| adapt && p > min) {
                                Some(p) => {
                                    pilot = Some(sample_cap(t, MAX_SPP));
                                    (Targets::Even(p), false)
                                }
                                None => (Targets::Even(t), false),
                            }
                        }
                        // Every pixel gets a sample, whatever the budget.
                        None if min == 0 => (Targets::Even(1), false),
                        None => break,
                    },
                }
            }
        };
        // Adaptive counts make some rows cost many times others: rows one by one keep
        // the threads busy to the end.
        let rows = match targets {
            Targets::PerPixel(_) => 1,
            Targets::Even(_) => BAND_ROWS,
        };
        let pass_start = Instant::now();
        let guard = cache.map(|c| c.read());
        // The mixtures the pilot's draws are weighed for, and chosen among after it.
        let pilot_choices = (pilot.is_some() && choose_mixtures).then(|| Choices::new(techniques));
        let shader = Shader {
            lighting,
            camera,
            anchors,
            params,
            // Without direct light the records predict nothing a sample uses.
            cache: guard.as_deref().zip(cache).filter(|_| params.direct),
            chroma: chroma.as_ref(),
            techniques,
            learning: probe && learn,
            choices: pilot_choices,
            pixel_techniques: pixel_techniques.as_ref(),
            light_samples,
            // A view that splits lets its probe choose how many draws the passes take.
            measure_split: probe && splits,
            normal_products: normal_products.as_ref(),
        };
        let work = run_with_progress(
            threads,
            || {
                sums.par_chunks_mut(rows * width)
                    .zip(pilot_state.par_chunks_mut(rows * width))
                    .enumerate()
                    // Every band a task of its own: rayon's default splits the bands into
                    // a few runs per thread, and a thread that ends its runs first cannot
                    // take part of another's (measured: 13% of a pass idle on cornell).
                    .with_max_len(1)
                    .map(|(band, (band_sums, band_pilot))| {
                        let mut work = BandWork::default();
                        if cancel.load(Ordering::Relaxed)
                            || (probe && band % PassSchedule::PROBE_STRIDE != 0)
                        {
                            return work;
                        }
                        let first = band * rows * width;
                        let mut band_samples = 0u64;
                        for (i, (acc, state)) in band_sums.iter_mut().zip(band_pilot).enumerate() {
                            // A band of many samples takes seconds; stop within a pixel.
                            if cancel.load(Ordering::Relaxed) {
                                break;
                            }
                            let target = targets.of(first + i);
                            if acc.n < target {
                                let added = target - acc.n;
                                band_samples += added as u64;
                                work.anchored_pixels += 1;
                                let before = work.sample_ns;
                                shader.shade_pixel(first + i, acc.n..target, acc, &mut work);
                                state.ns_per_sample =
                                    (work.sample_ns - before) as f32 / added as f32;
                                if shader.choices.is_some() {
                                    state.moments = std::mem::take(&mut work.moments);
                                }
                            }
                        }
                        work.samples += band_samples;
                        done.fetch_add(band_samples, Ordering::Relaxed);
                        work
                    })
                    .collect::<Vec<BandWork>>()
            },
            &mut || {
                let keep = progress(done.load(Ordering::Relaxed), planned);
                if !keep {
                    cancel.store(true, Ordering::Relaxed);
                }
                keep
            },
        )?;
        drop(guard);
        let mut pass = PassWork::default();
        for w in &work {
            pass.anchored_pixels += w.anchored_pixels;
            pass.samples += w.samples;
            pass.anchor_ns += w.anchor_ns;
            pass.sample_ns += w.sample_ns;
        }
        if probe && splits {
            let mut measured = split::SplitProbe::default();
            work.iter().for_each(|w| measured += w.split);
            probe_ratios = split::probe_ratios(&measured, light_samples);
            let optimum = probe_ratios.map(|r| r.draws());
            light_samples = split::draws_after_probe(optimum, light_samples);
        }
        if probe && learn {
            // Each draw counts as its pixel counts in relMSE: 1 / (mean² + 10⁻²).
            let weight = |p: u32| {
                let (mean, _) = sums[p as usize].estimate([0.0; 3]);
                let m = luminance(mean.map(|v| v as f32));
                1.0 / (m * m + RELMSE_FLOOR)
            };
            let draws: Vec<(f64, f64, [f64; 4], f64)> = work
                .iter()
                .flat_map(|w| &w.draws)
                .map(|&(p, f, pdfs, p0)| (weight(p), f, pdfs, p0))
                .collect();
            techniques = techniques.learnt(&draws);
            learnt = Some(techniques.to_array());
        }
        for w in work {
            total.merge(w);
        }
        passes += 1;
        taken += pass.samples;
        schedule.record(pass_start.elapsed().as_secs_f64(), pass);
        if let Some(cap) = pilot {
            // Under a budget, a sample's cost counts too: sky is cheap, grass is not.
            let ns: Vec<f32> = pilot_state.iter().map(|p| p.ns_per_sample).collect();
            let costs = params.time_budget.map(|_| &ns[..]);
            let measured = SampleShares::measure(&sums, &alphas(&sums), costs, width, height);
            if let Some(choices) = &pilot_choices {
                let moments: Vec<DrawMoments> = pilot_state.iter().map(|p| p.moments).collect();
                pixel_techniques = Some(PixelTechniques::measure(&moments, choices, width, height));
            }
            adaptive_gain = Some(measured.gain());
            shares = Some((measured, cap));
        }
        if cancel.load(Ordering::Relaxed) {
            complete = false;
            break;
        }
        let keep_going = progress(done.load(Ordering::Relaxed), planned);
        // Every pixel gets a sample, whatever the budget: a probe pass alone leaves most
        // of them at none.
        let unsampled = sums.iter().any(|s| s.n == 0);
        let over_budget = params
            .time_budget
            .is_some_and(|b| start.elapsed().as_secs_f64() >= b && !unsampled);
        if !keep_going || over_budget {
            break;
        }
    }
    if scene.counting_enabled() {
        scene.add_counters(total.bvh);
    }

    // α per pixel, then the estimates.
    let alpha = alphas(&sums);
    let mut image = Vec::with_capacity(pixels);
    let mut variance = Vec::with_capacity(pixels);
    for (s, a) in sums.iter().zip(&alpha) {
        let (mean, var) = s.estimate(*a);
        image.push(mean.map(|v| v as f32));
        variance.push(var.map(|v| v as f32));
    }
    let mut stats = RenderStats {
        spp: sums.iter().map(|s| s.n).min().unwrap_or(0),
        passes,
        complete,
        samples: sums.iter().map(|s| s.n as u64).sum(),
        mean_spp: sums.iter().map(|s| s.n as f64).sum::<f64>() / pixels.max(1) as f64,
        max_spp: sums.iter().map(|s| s.n).max().unwrap_or(0),
        primary_rays: total.primary_rays,
        shadow_rays: total.direct.shadow_rays,
        bsdf_rays: total.direct.bsdf_rays,
        bounce_rays: total.direct.bounce_rays,
        stages: StageSeconds {
            primary: total.primary_ns as f64 * 1e-9,
            product: total.product_ns as f64 * 1e-9,
            lookup: total.lookup_ns as f64 * 1e-9,
            control: total.control_ns as f64 * 1e-9,
            shading: total.shading_ns as f64 * 1e-9,
            indirect: total.indirect_ns as f64 * 1e-9,
            sample_primary: total.sample_primary_ns as f64 * 1e-9,
        },
        cache_points: total.cache_points,
        points_without_records: total.points_without_records,
        sun_rays: total.sun_rays,
        records_used: total.records_used,
        shared_lookups: total.shared_lookups,
        reused_integrals: total.reused_integrals,
        reused_products: total.reused_products,
        unmatched_samples: total.unmatched_samples,
        record_misses: total.verdicts.values().map(|v| v.0 as u64).sum(),
        record_uses: total.verdicts.values().map(|v| v.1 as u64).sum(),
        learnt_techniques: learnt,
        adaptive_gain,
        pixel_techniques: pixel_techniques.as_ref().map(PixelTechniques::counts),
        light_samples,
        edge_share,
        probe_ratios,
        coarse_products: lighting.product_level == ProductLevel::CoarseDiffuse,
        ..RenderStats::default()
    };
    if cv {
        for c in 0..3 {
            stats.mean_alpha[c] = alpha.iter().map(|a| a[c]).sum::<f64>() / pixels.max(1) as f64;
        }
    }
    if let Some(cache) = cache {
        // §5.3: what the records predicted wrongly goes back to them.
        let ids: Vec<u32> = total.verdicts.keys().copied().collect();
        let misses: Vec<u32> = total.verdicts.values().map(|v| v.0).collect();
        let uses: Vec<u32> = total.verdicts.values().map(|v| v.1).collect();
        cache.record_misses(&ids, &misses, &uses)?;
        if params.insert_missing && !total.requests.is_empty() {
            // Pixel order, each point once (a jittered render may ask more than once).
            total.requests.sort_by_key(|r| r.0);
            total.requests.dedup_by_key(|r| r.0);
            let points: Vec<(Vec3, Vec3, f32)> =
                total.requests.iter().map(|r| (r.1, r.2, r.3)).collect();
            stats.inserted_records =
                with_threads(threads, || cache.refine_points(scene, &points))?? as u64;
        }
    }
    stats.seconds = start.elapsed().as_secs_f64();
    let rays = stats.primary_rays + stats.shadow_rays + stats.bsdf_rays + stats.bounce_rays;
    stats.rays_per_second = rays as f64 / stats.seconds.max(1e-9);
    Ok(Rendered {
        width: camera.width,
        height: camera.height,
        image,
        variance,
        alpha: cv.then(|| alpha.iter().map(|a| a.map(|v| v as f32)).collect()),
        sample_counts: counts(&sums),
        stats,
    })
}

/// Per-pixel `α` of the control variate by `rule` (zeros for the other methods).
fn pixel_alphas(
    cv: bool,
    rule: AlphaRule,
    sums: &[CvSums],
    width: usize,
    height: usize,
) -> Vec<[f64; 3]> {
    match (cv, rule) {
        (true, AlphaRule::Neighbours { radius }) => neighbour_alphas(sums, width, height, radius),
        (true, AlphaRule::Fixed(a)) => vec![[a; 3]; sums.len()],
        _ => vec![[0.0; 3]; sums.len()],
    }
}

/// The sample count a pass brings each pixel up to.
enum Targets {
    /// Every pixel the same.
    Even(u32),
    /// Per pixel, row-major ([`adaptive`]).
    PerPixel(Vec<u32>),
}

impl Targets {
    /// `shares` at scale `lambda` over the pixels' `current` counts.
    fn scaled(shares: &SampleShares, lambda: f64, current: &[u32], cap: u32) -> Self {
        Self::PerPixel(
            current
                .iter()
                .enumerate()
                .map(|(i, &n)| shares.target(i, lambda, n, cap))
                .collect(),
        )
    }

    fn of(&self, pixel: usize) -> u32 {
        match self {
            Self::Even(t) => *t,
            Self::PerPixel(t) => t[pixel],
        }
    }

    /// Samples the pass adds to pixels at `current`.
    fn added(&self, current: &[u32]) -> u64 {
        current
            .iter()
            .enumerate()
            .map(|(i, &n)| self.of(i).saturating_sub(n) as u64)
            .sum()
    }
}

/// What the adaptive pilot measured at a pixel.
#[derive(Clone, Copy, Debug)]
struct PixelPilot {
    /// CPU nanoseconds per sample of the pixel's latest pass (NaN before any).
    ns_per_sample: f32,
    /// The pilot's draws ([`PixelTechniques`]).
    moments: DrawMoments,
}

impl Default for PixelPilot {
    fn default() -> Self {
        Self {
            ns_per_sample: f32::NAN,
            moments: DrawMoments::default(),
        }
    }
}

/// Whether a render's mixture is learnt (from the probe) and chosen per pixel (after an
/// adaptive pilot): method "product" shading direct light with `learn_techniques`.
fn learn_techniques_per_pixel(params: &RenderParams) -> bool {
    params.learn_techniques && params.method == Method::Product && params.direct
}
