//! The direct-lighting estimators at a pixel: every [`Method`] of [`super`], the control
//! variate ([`crate::estimators::control_variate`], CAM08 eq. 2-3) and indirect light by
//! path tracing ([`crate::estimators::indirect`]), with the per-pixel work done once at the
//! pixel's *anchor* (the first hit through its centre: the product distribution, the cache
//! lookup and `J`) and every sample shading its own jittered hit with it (the renderer's
//! module docs, `crate::render`, say why each sample stays unbiased). What the pass layer
//! runs per pixel is [`AnchoredShader::shade`]; the counters it keeps per band are
//! [`AnchorWork`].

use std::collections::BTreeMap;
use std::ops::Range;
use std::sync::Arc;
use std::time::Instant;

use glam::{Vec3, Vec3A};

use super::light_split;
use super::mixture_choice::{Choices, DrawMoments, PixelTechniques};
use super::{DirectCounters, Lighting, Method, ShadingPoint, Techniques};
use crate::bsdf::Material;
use crate::camera::{Camera, GBuffer, DIM_PIXEL_JITTER};
use crate::estimators::control_variate::{control_sample, LobeControl};
use crate::estimators::indirect::{estimate_indirect, shading_point_at, PathParams};
use crate::estimators::irradiance::build::diffuse_albedo;
use crate::estimators::irradiance::cache::IrradianceState;
use crate::estimators::normal_products::NormalProducts;
use crate::geometry::bvh::PACKET;
use crate::geometry::{SurfaceHit, TraversalCounters};
use crate::lights::envmap::chroma::MapChroma;
use crate::lights::envmap::luminance;
use crate::lights::envmap::product::{GuidedProduct, ProductDistribution};
use crate::math::RELMSE_FLOOR;
use crate::moments::Moments;
use crate::sampling::rng::Sampler;
use crate::sampling::sobol::PixelSampler;
use crate::visibility::cache::interpolant::{ControlTables, Interpolant};
use crate::visibility::cache::{CacheState, Lookup, VisibilityCache};

/// What the samples of a render read of its parameters.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AnchoredParams {
    /// The direct-lighting estimator.
    pub method: Method,
    /// Seed of every random number.
    pub seed: u64,
    /// A jittered primary ray per sample, shaded with its pixel's anchor; else every sample
    /// at the anchor.
    pub jitter: bool,
    /// Whether the image holds direct light.
    pub direct: bool,
    /// Bounces of indirect light by path tracing added to every sample (0: none).
    pub bounces: u32,
    /// Shading points that find no record ask for one ([`AnchorWork::requests`]).
    pub insert_missing: bool,
}

impl AnchoredParams {
    /// Whether the product's cells (and, for "cv", lookup and `J`) shade anything: not
    /// when only the indirect part is rendered.
    pub fn uses_product(&self) -> bool {
        self.direct && matches!(self.method, Method::Product | Method::ControlVariate)
    }
}

/// What a worker's samples did over one band of pixels: counters, timings, the records'
/// verdicts and what the passes learn from (added up over bands by [`Self::merge`]).
#[derive(Clone, Default)]
pub struct AnchorWork {
    pub direct: DirectCounters,
    pub bvh: TraversalCounters,
    pub primary_rays: u64,
    pub product_ns: u64,
    pub lookup_ns: u64,
    pub control_ns: u64,
    pub shading_ns: u64,
    pub indirect_ns: u64,
    pub sample_primary_ns: u64,
    /// Samples whose hit left the control variate out (another object than the anchor).
    pub unmatched_samples: u64,
    pub cache_points: u64,
    pub points_without_records: u64,
    /// Shadow rays toward the map's sun.
    pub sun_rays: u64,
    pub records_used: u64,
    /// Per record id: (misses, uses).
    pub verdicts: BTreeMap<u32, (u32, u32)>,
    /// Pixels whose shading point found no record: (pixel, position, normal, footprint).
    pub requests: Vec<(u32, Vec3, Vec3, f32)>,
    /// The last lookup of this band, which the next pixel may share (see
    /// [`AnchoredShader::shared_lookup`]).
    last_lookup: Option<SharedLookup>,
    /// The last product distribution of this band that ignores the view, with its
    /// material and normal: a pixel with the same key has the same product.
    last_product: Option<((Material, Vec3), Arc<ProductDistribution>)>,
    /// Anchors that took the previous pixel's product.
    pub reused_products: u64,
    /// Lookups answered by a neighbour's.
    pub shared_lookups: u64,
    /// ... whose `J` was the neighbour's too (the same product distribution).
    pub reused_integrals: u64,
    /// Samples whose diffuse indirect light the irradiance cache interpolated.
    pub irradiance_lookups: u64,
    /// ... and those where no record was usable (a path traced instead).
    pub irradiance_misses: u64,
    /// ... and those that took their anchor's irradiance (no record reached the hit).
    pub irradiance_from_anchor: u64,
    /// Channels the gradients pushed below 0, clamped.
    pub irradiance_clamped: u64,
    /// The pixel being shaded, and the matched draws kept for learning the mixture:
    /// (pixel, `f cos L V` in luminance, techniques' densities, mixture density).
    pixel: u32,
    pub draws: Vec<(u32, f64, [f64; 4], f64)>,
    /// The pixel's draws for [`PixelTechniques`] (the adaptive pilot).
    moments: DrawMoments,
    /// What the probe measures for [`light_split::draws_from`], and the pixel's moments, over
    /// its samples of the pass, of their values and of their first-draw values (per
    /// channel).
    pub split: light_split::SplitProbe,
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

impl AnchorWork {
    /// Adds `o` (a band shaded after this one) to `self`.
    pub fn merge(&mut self, o: AnchorWork) {
        self.direct.shadow_rays += o.direct.shadow_rays;
        self.direct.bsdf_rays += o.direct.bsdf_rays;
        self.direct.bounce_rays += o.direct.bounce_rays;
        self.bvh += o.bvh;
        self.primary_rays += o.primary_rays;
        self.product_ns += o.product_ns;
        self.lookup_ns += o.lookup_ns;
        self.control_ns += o.control_ns;
        self.shading_ns += o.shading_ns;
        self.indirect_ns += o.indirect_ns;
        self.sample_primary_ns += o.sample_primary_ns;
        self.unmatched_samples += o.unmatched_samples;
        self.cache_points += o.cache_points;
        self.points_without_records += o.points_without_records;
        self.sun_rays += o.sun_rays;
        self.records_used += o.records_used;
        self.shared_lookups += o.shared_lookups;
        self.reused_integrals += o.reused_integrals;
        self.reused_products += o.reused_products;
        self.irradiance_lookups += o.irradiance_lookups;
        self.irradiance_misses += o.irradiance_misses;
        self.irradiance_from_anchor += o.irradiance_from_anchor;
        self.irradiance_clamped += o.irradiance_clamped;
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
pub struct AnchoredShader<'a> {
    pub lighting: Lighting<'a>,
    pub camera: &'a Camera,
    /// The pixels' anchors (`RenderParams::needs_anchors` of the renderer).
    pub anchors: Option<&'a GBuffer>,
    pub params: AnchoredParams,
    /// The cache's records (read-locked for the pass) and its search-radius scale.
    pub cache: Option<(&'a CacheState, &'a VisibilityCache)>,
    pub chroma: Option<&'a MapChroma>,
    /// The mixture's weights.
    pub techniques: Techniques,
    /// Whether matched draws are kept for [`Techniques::learnt`] (the probe pass).
    pub learning: bool,
    /// The mixtures whose moments the pixels' draws add up (the adaptive pilot), when
    /// they do ([`DrawMoments`]).
    pub choices: Option<Choices>,
    /// Each pixel's mixture, chosen after the pilot ([`PixelTechniques`]).
    pub pixel_techniques: Option<&'a PixelTechniques>,
    /// Light draws per sample.
    pub light_samples: u32,
    /// Whether the samples measure their variance with all draws and with the first
    /// alone, and the draws' time ([`light_split::SplitProbe`]).
    pub measure_split: bool,
    /// Products by normal for diffuse hits off their anchor's surface.
    pub normal_products: Option<&'a NormalProducts<'a>>,
    /// The irradiance cache's records (read-locked for the pass): one-bounce light of the
    /// diffuse part interpolated from them instead of traced ([`Self::cached_indirect`]).
    pub irradiance: Option<&'a IrradianceState>,
}

thread_local! {
    /// The records an irradiance interpolation gathers, reused between samples.
    static REACHING: std::cell::RefCell<Vec<(u32, f32)>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// Draws a band keeps for [`Techniques::learnt`].
const LEARNT_DRAWS_PER_BAND: usize = 2048;

fn elapsed_ns(since: Instant) -> u64 {
    since.elapsed().as_nanos() as u64
}

impl AnchoredShader<'_> {
    /// The hits of the jittered primary rays of samples `rngs` of `pixel` (at most
    /// [`PACKET`]), traced as one packet from the eye (a pixel's rays visit nearly the
    /// same nodes, so together they cost a fraction of tracing them one by one), with the
    /// rays' directions. Lanes past `rngs.len()` hold nothing.
    fn trace_samples(
        &self,
        pixel: usize,
        rngs: &[PixelSampler],
        work: &mut AnchorWork,
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
    fn sun_visibility(&self, sp: &ShadingPoint, sun: Vec3, work: &mut AnchorWork) -> f64 {
        if sp.normal.dot(sun) <= 0.0 {
            return 0.0;
        }
        work.sun_rays += 1;
        let scene = self.lighting.scene;
        !scene.occluded1(sp.origin, sun, f32::INFINITY, &mut work.bvh) as u8 as f64
    }

    /// Prepares the anchor of `pixel` at its G-buffer hit.
    fn prepare(&self, anchors: &GBuffer, pixel: usize, work: &mut AnchorWork) -> Point {
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
        work: &AnchorWork,
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
        work: &mut AnchorWork,
        verdicts: &mut [(u32, u32)],
    ) -> (Vec3, [f64; 3]) {
        // A jittered hit that no record reaches may take its anchor's irradiance when it
        // lies on the anchor's surface.
        let own_anchor = anchor.filter(|_| matched).map(|a| &a.sp);
        let indirect = self.indirect(sp, own_anchor, rng, work);
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

    /// The light of [`AnchoredParams::bounces`] bounces at `sp` (zero without), on the
    /// dimensions above the direct estimate's ([`crate::estimators::indirect`]).
    fn indirect(
        &self,
        sp: &ShadingPoint,
        anchor: Option<&ShadingPoint>,
        rng: &PixelSampler,
        work: &mut AnchorWork,
    ) -> Vec3 {
        if self.params.bounces == 0 {
            return Vec3::ZERO;
        }
        let start = Instant::now();
        let l = match self.irradiance {
            Some(state) => self.cached_indirect(state, sp, anchor, rng, work),
            None => self.path(sp, rng, work),
        };
        work.indirect_ns += elapsed_ns(start);
        l
    }

    /// [`estimate_indirect`] at `sp` with the render's bounces.
    fn path(&self, sp: &ShadingPoint, rng: &PixelSampler, work: &mut AnchorWork) -> Vec3 {
        estimate_indirect(
            &self.lighting,
            sp,
            &PathParams::new(self.params.bounces),
            rng,
            &mut work.direct,
            &mut work.bvh,
        )
    }

    /// One bounce at `sp` with the irradiance cache (Survey eq. 3.8): the diffuse part
    /// `k_d/π · E(x)` interpolated from the records, Phong's specular part by a path
    /// sampling that lobe alone (radiance caching, §3.4, is not built). A jittered hit that
    /// no record reaches but lies on its pixel's `anchor` surface takes the anchor's `E`
    /// (the pixel is finer than the cache there: small `a`, or a radius clamped by a
    /// neighbour); elsewhere without a usable record the whole bounce is a path, so such
    /// samples stay unbiased.
    fn cached_indirect(
        &self,
        state: &IrradianceState,
        sp: &ShadingPoint,
        anchor: Option<&ShadingPoint>,
        rng: &PixelSampler,
        work: &mut AnchorWork,
    ) -> Vec3 {
        let albedo = Vec3::from(diffuse_albedo(&sp.material));
        if albedo == Vec3::ZERO {
            return self.path(sp, rng, work);
        }
        let found = REACHING.with(|r| {
            let scratch = &mut r.borrow_mut();
            state
                .interpolate(sp.origin, sp.normal, scratch)
                .or_else(|| {
                    let a = anchor?;
                    let found = state.interpolate(a.origin, a.normal, scratch);
                    work.irradiance_from_anchor += found.is_some() as u64;
                    found
                })
        });
        let Some(found) = found else {
            work.irradiance_misses += 1;
            return self.path(sp, rng, work);
        };
        work.irradiance_lookups += 1;
        work.irradiance_clamped += found.clamped as u64;
        let diffuse = albedo * Vec3::from(found.irradiance) * std::f32::consts::FRAC_1_PI;
        let specular = match sp.material {
            Material::Phong { ks, exponent, .. } if ks != [0.0; 3] => {
                let lobe = ShadingPoint {
                    material: Material::Phong {
                        kd: [0.0; 3],
                        ks,
                        exponent,
                    },
                    ..*sp
                };
                self.path(&lobe, rng, work)
            }
            _ => Vec3::ZERO,
        };
        diffuse + specular
    }

    /// What the camera sees of the map through a pixel: direct light.
    fn background(&self, radiance: Vec3) -> Vec3 {
        if self.params.direct {
            radiance
        } else {
            Vec3::ZERO
        }
    }

    /// Samples `samples` of one pixel, each `(Z, W)` handed to `add` in sample order (`W`
    /// the control variate's zero-mean term, zero without one); the pilot's draws go to
    /// `moments` when it measures them. Returns the CPU nanoseconds of the pixel's anchor
    /// and of its samples.
    pub fn shade(
        &self,
        pixel: usize,
        samples: Range<u32>,
        mut add: impl FnMut(Vec3, [f64; 3]),
        work: &mut AnchorWork,
        moments: &mut DrawMoments,
    ) -> (u64, u64) {
        let seed = self.params.seed;
        work.pixel = pixel as u32;
        if self.measure_split {
            work.pixel_values = Default::default();
        }
        let n_samples = samples.len() as u32;
        let start = Instant::now();
        let anchor = self.anchors.map(|g| self.prepare(g, pixel, work));
        let prepared = Instant::now();
        let anchor_ns = (prepared - start).as_nanos() as u64;
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
                    add(z, w);
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
                add(z, w);
            }
        }
        let sampled = elapsed_ns(prepared);
        work.shading_ns += sampled;
        if self.measure_split {
            probe_pixel(n_samples, sampled, work);
        }
        if let Some(a) = anchor_surface {
            flush_verdicts(a, &mut verdicts, work);
        }
        if self.choices.is_some() {
            *moments = std::mem::take(&mut work.moments);
        }
        (anchor_ns, sampled)
    }
}

/// Adds a measured pixel (`n` samples taking `ns`, their moments in `work.pixel_values`)
/// to the band's [`light_split::SplitProbe`]: each channel's variance between samples, of their
/// values and of their first draws', weighted as the pixel counts in relMSE.
fn probe_pixel(n: u32, ns: u64, work: &mut AnchorWork) {
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
fn flush_verdicts(point: &SurfacePoint, verdicts: &mut [(u32, u32)], work: &mut AnchorWork) {
    for (id, v) in point.interpolant.ids().iter().zip(verdicts.iter()) {
        if v.1 > 0 {
            let e = work.verdicts.entry(*id).or_default();
            e.0 += v.0;
            e.1 += v.1;
        }
    }
    verdicts.fill((0, 0));
}
