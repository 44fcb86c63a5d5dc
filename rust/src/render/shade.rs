//! The direct-lighting methods on the pass layer: every [`Method`] of
//! [`crate::estimators::direct`], the control variate
//! ([`crate::estimators::control_variate`]) and indirect light by path tracing
//! ([`crate::estimators::indirect`]) as one [`PixelEstimator`], whose per-pixel sampling is
//! [`AnchoredShader`] (the renderer's docs in [`super`] say what a pixel's anchor and
//! samples do). Between passes it learns the mixture's weights and the light draws per
//! sample from the probe, and each pixel's mixture from the adaptive pilot; afterwards it
//! reports the records' misses to the cache.

use std::ops::Range;

use glam::Vec3;

use super::adaptive::SampleShares;
use super::estimator::{Merge, PassPlan, PixelEstimator, PixelPass, PixelTiming};
use super::sums::{neighbour_alphas, CvSums};
use super::{RenderParams, RenderStats, StageSeconds};
use crate::camera::{Camera, GBuffer};
use crate::error::Result;
use crate::estimators::control_variate::AlphaRule;
use crate::estimators::direct::anchored::{AnchorWork, AnchoredShader};
use crate::estimators::direct::light_split;
use crate::estimators::direct::mixture_choice::{Choices, DrawMoments, PixelTechniques};
use crate::estimators::direct::{Lighting, ProductLevel, Techniques};
use crate::estimators::irradiance::cache::IrradianceCache;
use crate::estimators::normal_products::NormalProducts;
use crate::lights::envmap::chroma::MapChroma;
use crate::lights::envmap::luminance;
use crate::math::RELMSE_FLOOR;
use crate::parallel::with_threads;
use crate::visibility::cache::VisibilityCache;

impl Merge for AnchorWork {
    fn merge(&mut self, other: Self) {
        AnchorWork::merge(self, other);
    }
}

impl PixelPass for AnchoredShader<'_> {
    type Work = AnchorWork;
    type Note = DrawMoments;
    type Sums = CvSums;

    fn shade_pixel(
        &self,
        pixel: usize,
        samples: Range<u32>,
        acc: &mut CvSums,
        work: &mut AnchorWork,
        note: &mut DrawMoments,
    ) -> PixelTiming {
        let (anchor_ns, sample_ns) = self.shade(pixel, samples, |z, w| acc.add(z, w), work, note);
        PixelTiming {
            anchor_ns,
            sample_ns,
        }
    }
}

/// The direct-lighting methods as a [`PixelEstimator`]: what their passes read, and what
/// they learn between passes.
pub(super) struct DirectMethod<'a> {
    pub(super) lighting: Lighting<'a>,
    pub(super) camera: &'a Camera,
    /// The pixels' anchors ([`RenderParams::needs_anchors`]).
    pub(super) anchors: Option<&'a GBuffer>,
    pub(super) params: &'a RenderParams,
    /// The control variate's cache (method "cv").
    pub(super) cache: Option<&'a VisibilityCache>,
    pub(super) chroma: Option<MapChroma>,
    /// Products by normal for diffuse hits off their anchor's surface.
    pub(super) normal_products: Option<NormalProducts<'a>>,
    /// The mixture's weights: the given ones, then those learnt from the probe.
    pub(super) techniques: Techniques,
    /// Whether the probe's draws teach the mixture ([`Techniques::learnt`]).
    pub(super) learn: bool,
    /// The weights learnt, when they were.
    pub(super) learnt: Option<[f32; 4]>,
    /// Whether every pixel takes its own mixture after the adaptive pilot.
    pub(super) choose_mixtures: bool,
    pub(super) pixel_techniques: Option<PixelTechniques>,
    /// Light draws per sample: the given count or the view's, then the probe's.
    pub(super) light_samples: u32,
    /// Whether the probe measures the light draws per sample ([`split`]).
    pub(super) splits: bool,
    pub(super) probe_ratios: Option<light_split::ProbeRatios>,
    /// The irradiance cache whose records give the diffuse part of one bounce (method
    /// "irradiance_cache").
    pub(super) irradiance: Option<&'a IrradianceCache>,
}

impl PixelEstimator for DirectMethod<'_> {
    type Work = AnchorWork;
    type Note = DrawMoments;
    type Sums = CvSums;
    const ADAPTS: bool = true;
    // The product methods learn their mixture and light draws from the probe.
    const LEARNS_FROM_PROBE: bool = true;
    type Pass<'b>
        = AnchoredShader<'b>
    where
        Self: 'b;

    fn pass<R>(&self, plan: &PassPlan, run: impl FnOnce(&AnchoredShader<'_>) -> R) -> R {
        let guard = self.cache.map(|c| c.read());
        let irradiance = self.irradiance.map(|c| c.read());
        // The mixtures the pilot's draws are weighed for, and chosen among after it.
        let choices = (plan.pilot && self.choose_mixtures).then(|| Choices::new(self.techniques));
        let shader = AnchoredShader {
            lighting: self.lighting,
            camera: self.camera,
            anchors: self.anchors,
            params: self.params.anchored(),
            // Without direct light the records predict nothing a sample uses.
            cache: guard
                .as_deref()
                .zip(self.cache)
                .filter(|_| self.params.direct),
            chroma: self.chroma.as_ref(),
            techniques: self.techniques,
            learning: plan.probe && self.learn,
            choices,
            pixel_techniques: self.pixel_techniques.as_ref(),
            light_samples: self.light_samples,
            // A view that splits lets its probe choose how many draws the passes take.
            measure_split: plan.probe && self.splits,
            normal_products: self.normal_products.as_ref(),
            irradiance: irradiance.as_deref(),
        };
        run(&shader)
    }

    fn end_pass(&mut self, plan: &PassPlan, works: &[AnchorWork], sums: &[CvSums]) {
        if plan.probe && self.splits {
            let mut measured = light_split::SplitProbe::default();
            works.iter().for_each(|w| measured += w.split);
            self.probe_ratios = light_split::probe_ratios(&measured, self.light_samples);
            let optimum = self.probe_ratios.map(|r| r.draws());
            self.light_samples = light_split::draws_after_probe(optimum, self.light_samples);
        }
        if plan.probe && self.learn {
            // Each draw counts as its pixel counts in relMSE: 1 / (mean² + 10⁻²).
            let weight = |p: u32| {
                let (mean, _) = sums[p as usize].estimate([0.0; 3]);
                let m = luminance(mean.map(|v| v as f32));
                1.0 / (m * m + RELMSE_FLOOR)
            };
            let draws: Vec<(f64, f64, [f64; 4], f64)> = works
                .iter()
                .flat_map(|w| &w.draws)
                .map(|&(p, f, pdfs, p0)| (weight(p), f, pdfs, p0))
                .collect();
            self.techniques = self.techniques.learnt(&draws);
            self.learnt = Some(self.techniques.to_array());
        }
    }

    fn after_pilot(&mut self, notes: &[DrawMoments], width: usize, height: usize) {
        if self.choose_mixtures {
            let choices = Choices::new(self.techniques);
            self.pixel_techniques = Some(PixelTechniques::measure(notes, &choices, width, height));
        }
    }

    fn shares(
        &self,
        sums: &[CvSums],
        costs: Option<&[f32]>,
        width: usize,
        height: usize,
    ) -> Option<SampleShares> {
        let alphas = self.alphas(sums, width, height);
        Some(SampleShares::measure(sums, &alphas, costs, width, height))
    }
}

impl DirectMethod<'_> {
    /// `α` per pixel and channel: the rule's for the control variate, else 0.
    pub(super) fn alphas(&self, sums: &[CvSums], width: usize, height: usize) -> Vec<[f64; 3]> {
        match (self.cache.is_some(), self.params.alpha) {
            (true, AlphaRule::Neighbours { radius }) => {
                neighbour_alphas(sums, width, height, radius)
            }
            (true, AlphaRule::Fixed(a)) => vec![[a; 3]; sums.len()],
            _ => vec![[0.0; 3]; sums.len()],
        }
    }

    /// The method's figures of the render into `stats`, with the passes' `total` work and
    /// `alpha` per pixel; the records' misses go back to the cache (CAM08 §5.3), and with
    /// [`RenderParams::insert_missing`] the points that found none get records.
    pub(super) fn finish(
        &self,
        mut total: AnchorWork,
        alpha: &[[f64; 3]],
        stats: &mut RenderStats,
        threads: Option<usize>,
    ) -> Result<()> {
        let scene = self.lighting.scene;
        if scene.counting_enabled() {
            scene.add_counters(total.bvh);
        }
        let pixels = alpha.len();
        stats.primary_rays += total.primary_rays;
        stats.shadow_rays = total.direct.shadow_rays;
        stats.bsdf_rays = total.direct.bsdf_rays;
        stats.bounce_rays = total.direct.bounce_rays;
        stats.stages = StageSeconds {
            primary: stats.stages.primary,
            product: total.product_ns as f64 * 1e-9,
            lookup: total.lookup_ns as f64 * 1e-9,
            control: total.control_ns as f64 * 1e-9,
            shading: total.shading_ns as f64 * 1e-9,
            indirect: total.indirect_ns as f64 * 1e-9,
            sample_primary: total.sample_primary_ns as f64 * 1e-9,
        };
        stats.cache_points = total.cache_points;
        stats.points_without_records = total.points_without_records;
        stats.sun_rays = total.sun_rays;
        stats.records_used = total.records_used;
        stats.shared_lookups = total.shared_lookups;
        stats.reused_integrals = total.reused_integrals;
        stats.reused_products = total.reused_products;
        stats.irradiance_lookups = total.irradiance_lookups;
        stats.irradiance_misses = total.irradiance_misses;
        stats.irradiance_from_anchor = total.irradiance_from_anchor;
        stats.irradiance_clamped = total.irradiance_clamped;
        stats.unmatched_samples = total.unmatched_samples;
        stats.record_misses = total.verdicts.values().map(|v| v.0 as u64).sum();
        stats.record_uses = total.verdicts.values().map(|v| v.1 as u64).sum();
        stats.learnt_techniques = self.learnt;
        stats.pixel_techniques = self.pixel_techniques.as_ref().map(PixelTechniques::counts);
        stats.light_samples = self.light_samples;
        stats.probe_ratios = self.probe_ratios;
        stats.coarse_products = self.lighting.product_level == ProductLevel::CoarseDiffuse;
        if self.cache.is_some() {
            for c in 0..3 {
                stats.mean_alpha[c] =
                    alpha.iter().map(|a| a[c]).sum::<f64>() / pixels.max(1) as f64;
            }
        }
        if let Some(cache) = self.cache {
            // §5.3: what the records predicted wrongly goes back to them.
            let ids: Vec<u32> = total.verdicts.keys().copied().collect();
            let misses: Vec<u32> = total.verdicts.values().map(|v| v.0).collect();
            let uses: Vec<u32> = total.verdicts.values().map(|v| v.1).collect();
            cache.record_misses(&ids, &misses, &uses)?;
            if self.params.insert_missing && !total.requests.is_empty() {
                // Pixel order, each point once (a jittered render may ask more than once).
                total.requests.sort_by_key(|r| r.0);
                total.requests.dedup_by_key(|r| r.0);
                let points: Vec<(Vec3, Vec3, f32)> =
                    total.requests.iter().map(|r| (r.1, r.2, r.3)).collect();
                stats.inserted_records =
                    with_threads(threads, || cache.refine_points(scene, &points))?? as u64;
            }
        }
        Ok(())
    }
}
