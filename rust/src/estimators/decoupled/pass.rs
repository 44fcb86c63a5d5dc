//! The per-pixel work of a relighting render (the passes themselves are the render
//! floor's, `render::relight`): what every pixel of the render reads ([`RelightPass`]), each
//! pixel's sums per light ([`RelightSums`]), one pixel's samples of a pass
//! ([`RelightPass::gather`]) and the blend of its estimates (SBF eq. 9-11, module docs of
//! [`super`]).

use super::*;

/// What the camera sees at a pixel before any light is added, and whether it sees a
/// surface (set by the pixel's first visit).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct PixelSeen {
    pub(super) radiance: Vec3,
    pub(super) surface: bool,
}

/// Everything one pixel gathered over the passes of a relighting render: what it sees, its
/// `LBV`-samples per light, and its sums per light ([`RelightPass::lights`] order). The
/// first visit ([`RelightPass::gather`] of a pixel not [`Self::visited`]) sets what it
/// sees, each light's `⟨V⟩` and its `LB`-samples.
#[derive(Clone, Debug, Default)]
pub struct RelightSums {
    visited: bool,
    seen: PixelSeen,
    /// `LBV`-samples per light taken (counted at pixels without a surface too, where they
    /// add nothing).
    lbv: u32,
    /// Per light, once visited.
    lights: Vec<LightSums>,
}

impl RelightSums {
    /// `LBV`-samples per light the pixel took (its sample count for the passes).
    pub fn lbv_samples(&self) -> u32 {
        self.lbv
    }

    /// Whether its first visit (what it sees, `⟨V⟩`, the `LB`-samples) was made.
    pub fn visited(&self) -> bool {
        self.visited
    }

    /// Whether it sees a surface (false before its first visit).
    pub fn surface(&self) -> bool {
        self.seen.surface
    }
}

/// What one pixel and light gathered over the passes of a relighting render.
#[derive(Clone, Copy, Debug)]
pub(super) struct LightSums {
    pub(super) lb: [Moments; 3],
    /// The new density's `LBV`-samples, each times its MIS weight `w₂` where stored
    /// samples are reused (`reuse_n > 0`), else as drawn.
    pub(super) lbv: [Moments; 3],
    /// The stored `V`-samples reused as `LBV`-samples of the converged density, each
    /// times its MIS weight `w₁` (empty without reuse): set by the pixel's first visit.
    pub(super) reused: [Moments; 3],
    /// `n₁` of the balance heuristic: the stored samples reused (0: no reuse).
    pub(super) reuse_n: f64,
    /// `Σ w₂` over the new `LBV`-samples (their count without reuse).
    pub(super) new_weight_sum: f64,
    /// The map's converged product's normalization where its samples are reused (0
    /// otherwise): with the same material and cells, its density at a direction follows
    /// from the current product's cells ([`ProductDistribution::pdf_with_map`]).
    pub(super) then_total: f64,
    /// `⟨V⟩` (NaN without one), its effective sample count, the spread of the records
    /// it interpolates (cache mode) and the share of the density no sample reached
    /// (reweighted pixels): fixed by the pixel's first visit.
    pub(super) v: f64,
    pub(super) ess: f64,
    pub(super) v_spread: f64,
    pub(super) v_unseen: f64,
}

impl LightSums {
    /// The unbiased part's estimate in channel `c`: `⟨LBV⟩`, plus the reused samples'
    /// share where stored samples are reused (the two MIS-weighted means add up).
    pub(super) fn unbiased_mean(&self, c: usize) -> f64 {
        self.lbv[c].mean + self.reused[c].mean
    }

    /// The variance of [`Self::unbiased_mean`] (its two means are independent).
    fn unbiased_variance_of_mean(&self, c: usize) -> f64 {
        self.lbv[c].variance_of_mean() + self.reused[c].variance_of_mean()
    }

    /// Whether `LB`-samples would change nothing, so that the pixel's blend, variance and
    /// bound come out the same, bit for bit, without them: where there is no `⟨V⟩` (a
    /// point without records, an area light with cache visibility but no `light_cache`:
    /// `t = 0`, `⟨LBV⟩` alone), and where `⟨V⟩` is exactly 0 with nothing to widen its
    /// bound (every `V`-sample blocked, no reweighting blind spot, no spread of records: `⟨LB⟩⟨V⟩` and
    /// its bound are 0 whatever `⟨LB⟩`, `t = 1 − ε`; a closed room's map).
    fn lb_changes_nothing(&self) -> bool {
        self.v.is_nan() || (self.v == 0.0 && self.v_spread == 0.0 && self.v_unseen == 0.0)
    }
}

impl Default for LightSums {
    fn default() -> Self {
        Self {
            lb: [Moments::default(); 3],
            lbv: [Moments::default(); 3],
            reused: [Moments::default(); 3],
            reuse_n: 0.0,
            new_weight_sum: 0.0,
            then_total: 0.0,
            v: f64::NAN,
            ess: 0.0,
            v_spread: 0.0,
            v_unseen: 0.0,
        }
    }
}

/// What one run of pixels (a band of a pass, shaded in order by one worker) did and keeps:
/// its counters, and the latest product distributions, which the next pixel takes when
/// they were built for its material and normal (exact: the answers do not depend on it).
#[derive(Default)]
pub struct GatherWork {
    /// Shadow rays traced (`LBV`-samples whose `LB` is not zero by geometry).
    pub shadow_rays: u64,
    /// `LB`-samples not drawn where they change nothing ([`Relit::lb_skipped`]).
    pub lb_skipped: u64,
    products: LastProducts,
}

/// CPU time of one [`RelightPass::gather`], in nanoseconds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GatherTiming {
    /// The pixel's shading point and product distribution (every visit).
    pub prepare_ns: u64,
    /// The first visit's `⟨V⟩` and `LB`-samples (0 on later visits).
    pub first_visit_ns: u64,
    /// The `LBV`-samples.
    pub sample_ns: u64,
}

/// A product distribution kept for the next pixel of the same material and normal (the
/// renderer's reuse: flat diffuse surfaces share one).
pub(super) type LastProduct = Option<((Material, Vec3), Arc<ProductDistribution>)>;

/// A worker's latest products of a relighting render: for the current map, and for
/// the converged one (to redraw the stored samples when reweighting).
#[derive(Default)]
pub(super) struct LastProducts {
    pub(super) now: LastProduct,
    pub(super) then: LastProduct,
}

/// The product distribution of the map at `sp`: `last`'s where it was built for the same
/// view-independent material and normal, else a new one, kept in `last`.
pub(super) fn reused_product(
    env: &EnvMap,
    sp: &ShadingPoint,
    level: ProductLevel,
    last: &mut LastProduct,
) -> Option<Arc<ProductDistribution>> {
    let key = (!sp.material.product_depends_on_wo()).then_some((sp.material, sp.normal));
    match (&*last, key) {
        (Some((k, p)), Some(key)) if *k == key => Some(p.clone()),
        _ => {
            let p = product_of(env, sp, level).map(Arc::new);
            *last = key.zip(p.clone());
            p
        }
    }
}

/// What every pixel of a relighting render reads: the scene, the lights now, the materials
/// with their overrides, `⟨V⟩`'s source and the parameters ([`Relighter::relight_with`]
/// makes it).
pub struct RelightPass<'a> {
    pub(super) relighter: &'a Relighter,
    pub(super) scene: &'a Scene,
    pub(super) env: &'a EnvMap,
    pub(super) materials: &'a [Material],
    pub(super) lights: &'a [LightId],
    pub(super) converged: Option<&'a Converged>,
    pub(super) same_env_density: bool,
    pub(super) cache: Option<(&'a VisibilityCache, &'a CacheState)>,
    /// Records that see area lights ([`crate::visibility::CacheParams::emitters_visible`]).
    pub(super) light_cache: Option<(&'a VisibilityCache, &'a CacheState)>,
    pub(super) params: &'a RelightParams,
}

impl RelightPass<'_> {
    /// The render's parameters.
    pub fn params(&self) -> &RelightParams {
        self.params
    }

    /// The G-buffer whose pixels it shades (row-major, `width x height`).
    pub fn gbuffer(&self) -> &GBuffer {
        &self.relighter.gbuffer
    }

    /// Lights per pixel: the map, then the scene's area lights.
    pub fn lights(&self) -> usize {
        self.lights.len()
    }

    /// Adds `LBV`-samples `lbv` (per light) of pixel `i` to its `sums`, in sample order;
    /// the pixel's first visit (`sums` not [`RelightSums::visited`]) first sets what it
    /// sees and each light's `⟨V⟩` and takes its [`RelightParams::lb_spp`] `LB`-samples.
    /// An `LBV`-sample's `LB` value is an `LB`-sample too. Every random number comes from
    /// `(seed, i, stream, sample, dimension)`; `work` only counts and lends product
    /// distributions.
    pub fn gather(
        &self,
        i: usize,
        sums: &mut RelightSums,
        lbv: std::ops::Range<u32>,
        work: &mut GatherWork,
    ) -> GatherTiming {
        let started = Instant::now();
        let first = !sums.visited;
        let lb = if first { 0..self.params.lb_spp } else { 0..0 };
        if first {
            sums.visited = true;
            sums.lights = vec![LightSums::default(); self.lights.len()];
        }
        sums.lbv += lbv.len() as u32;
        let last_products = &mut work.products;
        let (seen, sums) = (&mut sums.seen, &mut sums.lights[..]);
        let Some((hit, sp)) = self.relighter.point(self.scene, self.materials, i) else {
            if first {
                let dir = Vec3::from(self.relighter.gbuffer.direction[i]);
                seen.radiance = self.env.eval(dir);
            }
            return GatherTiming {
                prepare_ns: started.elapsed().as_nanos() as u64,
                ..GatherTiming::default()
            };
        };
        let at = PixelLights {
            scene: self.scene,
            env: self.env,
            area_lights: self.scene.area_lights(),
            product: reused_product(
                self.env,
                &sp,
                self.params.product_level,
                &mut last_products.now,
            ),
            sp,
        };
        let prepared = Instant::now();
        if first {
            seen.radiance = self.scene.emitted(&hit, sp.wo);
            seen.surface = true;
            // At threshold 0 without reuse the image is `⟨LBV⟩` alone: SBF's classical
            // estimator, which reads no `⟨V⟩`.
            if self.params.threshold > 0.0 || self.params.reuse {
                self.visibility_of(i, &hit, &at, sums, &mut last_products.then);
            }
        }
        let mut bvh = TraversalCounters::default();
        // One sampler per sample serves every light (each reads its own dimensions); each
        // light's moments still take its samples in order.
        let unused = sums.iter().filter(|s| s.lb_changes_nothing()).count();
        work.lb_skipped += lb.len() as u64 * unused as u64;
        for s in lb {
            let rng = PixelSampler::new(self.params.seed, i as u64, STREAM_LB + s as u64);
            for (sums, &light) in sums.iter_mut().zip(self.lights) {
                if sums.lb_changes_nothing() {
                    continue;
                }
                let x = at.draw(light, &rng).map_or(Vec3::ZERO, |d| d.lb_over_p);
                Moments::push_each(&mut sums.lb, x.as_dvec3().to_array());
            }
        }
        let sampled = Instant::now();
        // The converged density, where the map's stored samples are reused: the new
        // samples' MIS weights read it.
        let stored = self
            .converged
            .filter(|_| !lbv.is_empty() && sums.iter().any(|s| s.reuse_n > 0.0))
            .map(|c| {
                let same_material = c.materials[hit.obj as usize] == at.sp.material;
                // The same cells: the same material, level and map resolution (which caps
                // the level).
                let same_cells = same_material
                    && c.product_level == self.params.product_level
                    && c.env.resolution() == self.env.resolution();
                // The map's converged product only where its stored samples are reused
                // and it cannot be read off the current one's cells.
                let last =
                    (sums[0].reuse_n > 0.0 && !same_cells).then_some(&mut last_products.then);
                StoredDensity {
                    then: converged_lights(c, &at, hit.obj, last),
                    converged: c,
                    same_material,
                    same_cells,
                }
            });
        for s in lbv.clone() {
            let rng = PixelSampler::new(self.params.seed, i as u64, STREAM_LBV + s as u64);
            for (sums, &light) in sums.iter_mut().zip(self.lights) {
                let (lb_x, x, w2) = match at.draw(light, &rng) {
                    Some(d) => {
                        work.shadow_rays += d.ray.is_some() as u64;
                        let v = at.visible(&d, &mut bvh);
                        let weights = ReuseWeights {
                            n1: sums.reuse_n,
                            n2: self.params.lbv_spp as f64,
                        };
                        let p1 = match &stored {
                            Some(stored) if sums.reuse_n > 0.0 && d.ray.is_some() => {
                                stored.pdf(&at, light, &d, &rng, sums.then_total)
                            }
                            _ => 0.0,
                        };
                        let w2 = 1.0 - weights.stored(p1, d.pdf);
                        let x = if v { d.lb_over_p } else { Vec3::ZERO };
                        (d.lb_over_p, x.as_dvec3() * w2, w2)
                    }
                    None => (Vec3::ZERO, DVec3::ZERO, 1.0),
                };
                // An LBV-sample is an LB-sample of the same density too.
                Moments::push_each(&mut sums.lbv, x.to_array());
                Moments::push_each(&mut sums.lb, lb_x.as_dvec3().to_array());
                sums.new_weight_sum += w2;
            }
        }
        let ns = |a: Instant, b: Instant| b.duration_since(a).as_nanos() as u64;
        let end = Instant::now();
        GatherTiming {
            prepare_ns: ns(started, prepared),
            // `⟨V⟩` and the LB-samples of the first visit are not repeated.
            first_visit_ns: ns(prepared, sampled),
            sample_ns: ns(sampled, end),
        }
    }

    /// Sets each light's `⟨V⟩`, its effective sample count and (cache) the records'
    /// spread at pixel `i`.
    fn visibility_of(
        &self,
        i: usize,
        hit: &SurfaceHit,
        at: &PixelLights,
        sums: &mut [LightSums],
        last_then: &mut LastProduct,
    ) {
        let interpolant = |cache: &VisibilityCache, state: &CacheState| {
            let d_max = cache.params().d_max_scale * self.relighter.gbuffer.footprint[i];
            let lookup = state.lookup_records(cache.params(), hit.position, at.sp.normal, d_max);
            Interpolant::new(state, &lookup, None)
        };
        let lookup = self.cache.map(|(c, s)| (s, interpolant(c, s)));
        let light_lookup = self
            .light_cache
            .filter(|_| self.lights.len() > 1)
            .map(|(c, s)| (s, interpolant(c, s)));
        let n_lights = self.lights.len();
        for (l, (sums, &light)) in sums.iter_mut().zip(self.lights).enumerate() {
            let (v, ess) = match (self.converged, &lookup) {
                (Some(c), _) => {
                    let stats = &c.stats[i * n_lights + l];
                    let reuse = (self.params.reuse && self.params.lbv_spp > 0)
                        .then_some(self.params.lbv_spp as f64);
                    match light {
                        LightId::Env if !self.same_env_density => {
                            let r = reweighted(c, at, hit.obj, i, last_then, reuse);
                            sums.v_unseen = r.unseen;
                            sums.reused = r.reused;
                            sums.reuse_n = r.reuse_n;
                            sums.then_total = r.then_total;
                            (r.v, r.ess)
                        }
                        LightId::Area(k) => {
                            if let Some(n2) = reuse {
                                (sums.reused, sums.reuse_n) = reused_area(c, at, (l, k), i, n2);
                            }
                            (stats.mean(), stats.samples as f64)
                        }
                        LightId::Env => (stats.mean(), stats.samples as f64),
                    }
                }
                // Records see an area light's own geometry as an occluder: they tell
                // nothing of its visibility.
                (None, Some((state, interp))) if !interp.is_empty() && light == LightId::Env => {
                    // E_p'[Ṽ] over the product's cells, exactly: no draws.
                    match &at.product {
                        Some(product) => {
                            // Ṽ = Σ β_i V_i, so E_p'[Ṽ] is the β-blend of the records'
                            // own averages; Ṽ interpolates records that may disagree
                            // here: their spread about it stands for its error.
                            let records = interp.record_averages(state, product.pyramid());
                            let betas: f64 = records.iter().map(|r| r.0 as f64).sum();
                            let v = (records.iter().map(|&(b, vi)| b as f64 * vi).sum::<f64>()
                                / betas.max(f64::MIN_POSITIVE))
                            .clamp(0.0, 1.0);
                            let spread = records
                                .iter()
                                .map(|&(b, vi)| b as f64 * (vi - v).powi(2))
                                .sum::<f64>()
                                / betas.max(f64::MIN_POSITIVE);
                            sums.v_spread = spread.sqrt();
                            (v, f64::INFINITY)
                        }
                        None => (f64::NAN, 0.0),
                    }
                }
                (None, _) if light != LightId::Env => match (&light_lookup, light) {
                    (Some((state, interp)), LightId::Area(k)) if !interp.is_empty() => {
                        match cached_area_visibility(at, k, state, interp, self.params.seed, i) {
                            Some(c) => {
                                sums.v_spread = c.spread;
                                (c.v, c.draws as f64)
                            }
                            None => (f64::NAN, 0.0),
                        }
                    }
                    _ => (f64::NAN, 0.0),
                },
                // No records here: nothing to decouple, the unbiased part alone.
                _ => (f64::NAN, 0.0),
            };
            // No draw with `LB > 0`: no `⟨V⟩` (nor light to decouple).
            sums.v = if ess > 0.0 { v } else { f64::NAN };
            sums.ess = ess;
        }
    }

    /// The render's images from every pixel's sums (row-major, one per pixel of
    /// [`Self::gbuffer`]) and its `LBV`-sample counts; the passes' own figures
    /// ([`Relit::passes`], rays, timings) are left at their defaults for the caller.
    pub fn resolve(&self, pixels: &[RelightSums]) -> Relit {
        let n_lights = self.lights.len();
        let lbv_counts: Vec<u32> = pixels
            .iter()
            .map(|p| if p.seen.surface { p.lbv } else { 0 })
            .collect();
        let surfaces = pixels.iter().filter(|p| p.seen.surface).count();
        let lbv_total: u64 = lbv_counts.iter().map(|&n| n as u64).sum();
        let mut relit = Relit {
            lights: n_lights,
            lbv_spp: lbv_counts.iter().copied().max().unwrap_or(0),
            lbv_spp_mean: lbv_total as f64 / surfaces.max(1) as f64,
            lbv_counts,
            ..Relit::default()
        };
        for pixel in pixels {
            let p = self.finish(pixel);
            relit.image.push(p.rgb.map(|v| v as f32));
            relit.variance.push(p.variance.map(|v| v as f32));
            relit.error_bound.push(p.error_bound.map(|v| v as f32));
            relit.t.extend(p.t);
            relit.bound.extend(p.bound);
            relit.visibility.extend(p.visibility);
            relit.effective_samples.extend(p.effective_samples);
        }
        relit
    }

    /// What a pixel's share of further `LBV`-samples is measured from: per channel, the
    /// variance of one `LBV`-sample of its blend, `Σ_l (1 − t_l)² Var(LBV_l/p)` over the
    /// lights, and the blend's estimate (its pixel of [`Self::resolve`]'s image). `None`
    /// where the pixel sees no surface or a light has fewer than two `LBV`-samples.
    pub fn lbv_variance(&self, sums: &RelightSums) -> Option<([f64; 3], [f64; 3])> {
        let lights = &sums.lights;
        if !sums.seen.surface || lights.iter().any(|s| s.lbv[0].count < 2) {
            return None;
        }
        let blend = self.finish(sums);
        let var = std::array::from_fn(|c| {
            lights
                .iter()
                .zip(&blend.t)
                .map(|(s, &t)| (1.0 - t as f64).powi(2) * s.lbv[c].variance())
                .sum()
        });
        Some((var, blend.rgb))
    }

    /// The pixel's blend (eq. 9) from what the passes gathered.
    pub(super) fn finish(&self, pixel: &RelightSums) -> PixelResult {
        let mut out = PixelResult::miss(pixel.seen.radiance, self.lights.len());
        if !pixel.seen.surface {
            return out;
        }
        let sums = &pixel.lights;
        let params = self.params;
        for (l, s) in sums.iter().enumerate() {
            let v = s.v;
            let lb_mean = s.lb.map(|w| w.mean);
            // Without `⟨V⟩` (no records, no weighted sample) the unbiased part alone; with
            // no `LBV`-samples the decoupled part alone.
            let (t, rel) = if v.is_nan() {
                (0.0, f64::NAN)
            } else {
                let var_v = binary_variance(v);
                // Eq. 7 assumes the exact E_p[V]; ⟨V⟩ from `ess` samples is off by about
                // sqrt(Var(V)/ess), which ⟨LB⟩⟨V⟩ carries too. From the cache, `Ṽ` is no
                // sample mean but an interpolation: its records' spread takes that place.
                // Reweighted, the share of the new density no stored sample reached may
                // hold any visibility: ⟨V⟩ is off by up to that share of its distance to 0
                // or 1.
                let v_error = V_ERROR_SIGMAS * ((var_v / s.ess.max(1.0)).sqrt() + s.v_spread)
                    + s.v_unseen * v.max(1.0 - v);
                let err: [f64; 3] = std::array::from_fn(|c| {
                    error_bound(s.lb[c].variance(), var_v) + lb_mean[c].abs() * v_error
                });
                (0..3).for_each(|c| out.error_bound[c] += err[c]);
                let rel = relative_error(err, lb_mean);
                let t = if s.lbv[0].count == 0 {
                    1.0
                } else {
                    let sbf = blend_factor(err, lb_mean, params.threshold, params.epsilon);
                    if params.least_error {
                        sbf.min(least_error_t(s, v, &err))
                    } else {
                        sbf
                    }
                };
                (t, rel)
            };
            let v_or_zero = if v.is_nan() { 0.0 } else { v };
            for (c, lb) in s.lb.iter().enumerate() {
                out.rgb[c] += blend(s.unbiased_mean(c), lb.mean, v_or_zero, t);
                out.variance[c] += (1.0 - t).powi(2) * s.unbiased_variance_of_mean(c)
                    + (t * v_or_zero).powi(2) * lb.variance_of_mean();
            }
            out.t[l] = t as f32;
            out.bound[l] = rel as f32;
            out.visibility[l] = v as f32;
            out.effective_samples[l] = s.ess as f32;
        }
        out
    }
}

/// One pixel's blend ([`RelightPass::finish`]).
pub(super) struct PixelResult {
    pub(super) rgb: [f64; 3],
    pub(super) variance: [f64; 3],
    pub(super) error_bound: [f64; 3],
    pub(super) t: Vec<f32>,
    pub(super) bound: Vec<f32>,
    pub(super) visibility: Vec<f32>,
    pub(super) effective_samples: Vec<f32>,
}

impl PixelResult {
    /// A pixel showing `radiance` (the map, or an emitter) before any light is added.
    fn miss(radiance: Vec3, lights: usize) -> Self {
        Self {
            rgb: radiance.as_dvec3().to_array(),
            variance: [0.0; 3],
            error_bound: [0.0; 3],
            t: vec![f32::NAN; lights],
            bound: vec![f32::NAN; lights],
            visibility: vec![f32::NAN; lights],
            effective_samples: vec![0.0; lights],
        }
    }
}
