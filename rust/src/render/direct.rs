//! The registry's renderer of the direct methods ([`Method`]: "env", "bsdf", "mis",
//! "product", "cv" and "path"): the row's defaults and the caller's inputs make the
//! [`RenderParams`], [`super::render`] or [`super::render_from`] renders, and the stats
//! become named figures.

use super::output::{RenderOutput, Stats, View};
use super::registry::{MethodInputs, MethodRenderer, MethodSpec};
use super::{render, render_from, RenderParams, RenderStats};
use crate::error::Result;
use crate::estimators::control_variate::AlphaRule;
use crate::estimators::direct::Method;

/// Renders a registry row of the pass layer's direct methods with [`Method`] `.0`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DirectRenderer(pub Method);

impl DirectRenderer {
    /// The render's parameters: `inputs.params` with the method, samples, bounces,
    /// adaptive counts and light draws of the row and the inputs.
    pub fn params(&self, spec: &MethodSpec, inputs: &MethodInputs<'_>) -> Result<RenderParams> {
        let budget = inputs.params.time_budget;
        let params = RenderParams {
            method: self.0,
            spp: inputs.spp_for(spec),
            bounces: inputs.bounces_for(spec)?,
            // Adaptive by default under a time budget: what the budget buys is least error.
            adaptive: inputs.adaptive.unwrap_or(budget.is_some()),
            light_samples: inputs.light_samples.unwrap_or(1),
            // Without a count, budgeted product renders choose one from the view.
            auto_light_samples: inputs.light_samples.is_none(),
            ..inputs.params
        };
        params.validate()?;
        Ok(params)
    }
}

impl MethodRenderer for DirectRenderer {
    fn family(&self) -> &'static str {
        "direct"
    }

    fn render(
        &self,
        spec: &MethodSpec,
        inputs: &MethodInputs<'_>,
        progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
    ) -> Result<RenderOutput> {
        let params = self.params(spec, inputs)?;
        let cache = inputs.cache.and_then(|c| c.visibility());
        let (scene, env, threads) = (inputs.scene, inputs.env, inputs.threads);
        let out = match inputs.view {
            View::Camera(cam) => render(scene, env, cam, &params, cache, threads, progress)?,
            View::GBuffer(g) => render_from(scene, env, g, &params, cache, threads, progress)?,
        };
        Ok(out.map_stats(|s| stats(spec, &params, &s)))
    }
}

/// The mixture's techniques, in the order [`crate::estimators::direct::Techniques`]
/// keeps them.
const TECHNIQUES: [&str; 4] = ["product", "guided", "bsdf", "env"];

/// A direct render's figures by name.
pub(super) fn stats(spec: &MethodSpec, params: &RenderParams, s: &RenderStats) -> Stats {
    let mut d = Stats::default();
    d.set("method", spec.name);
    d.set("bounces", params.bounces);
    d.set("direct", params.direct);
    d.set("seconds", s.seconds);
    d.set("spp", s.spp);
    d.set("mean_spp", s.mean_spp);
    d.set("max_spp", s.max_spp);
    d.set("adaptive", params.adaptive);
    d.set("adaptive_gain", s.adaptive_gain);
    d.set("pixel_mixtures", s.pixel_techniques.map(|c| c.to_vec()));
    d.set("unmatched_samples", s.unmatched_samples);
    d.set("passes", s.passes);
    d.set("complete", s.complete);
    d.set("first_sample_seconds", s.first_sample_seconds);
    d.set("jitter", params.jitter);
    d.set("light_samples", s.light_samples);
    d.set("edge_share", s.edge_share);
    d.set("coarse_products", s.coarse_products);
    d.set("probe_draws", s.probe_ratios.map(|r| r.draws()));
    d.set("probe_cost_ratio", s.probe_ratios.map(|r| r.cost));
    d.set("probe_variance_ratio", s.probe_ratios.map(|r| r.variance));
    let named = |w: [f32; 4]| -> Vec<(&'static str, f64)> {
        TECHNIQUES.into_iter().zip(w.map(f64::from)).collect()
    };
    d.set(
        "technique_weights",
        super::output::Stat::Named(named(params.techniques().to_array())),
    );
    d.set(
        "learnt_weights",
        s.learnt_techniques.map_or(super::output::Stat::None, |w| {
            super::output::Stat::Named(named(w))
        }),
    );
    d.set("samples", s.samples);
    d.set("primary_rays", s.primary_rays);
    d.set("shadow_rays", s.shadow_rays);
    d.set("bsdf_rays", s.bsdf_rays);
    d.set("bounce_rays", s.bounce_rays);
    d.set("rays_per_second", s.rays_per_second);
    d.set("samples_per_second", s.samples as f64 / s.seconds.max(1e-9));
    d.set("primary_seconds", s.stages.primary);
    d.set("product_seconds", s.stages.product);
    d.set("lookup_seconds", s.stages.lookup);
    d.set("control_seconds", s.stages.control);
    d.set("shading_seconds", s.stages.shading);
    d.set("indirect_seconds", s.stages.indirect);
    d.set("sample_primary_seconds", s.stages.sample_primary);
    d.set("reused_products", s.reused_products);
    d.set(
        "direct_seconds",
        s.stages.product + s.stages.lookup + s.stages.control + s.stages.shading,
    );
    if params.method == Method::ControlVariate {
        let points = s.cache_points.max(1) as f64;
        match params.alpha {
            AlphaRule::Fixed(a) => d.set("alpha", a),
            AlphaRule::Neighbours { .. } => d.set("alpha", "estimate"),
        }
        d.set("mean_alpha", s.mean_alpha.to_vec());
        d.set("cache_points", s.cache_points);
        d.set("points_without_records", s.points_without_records);
        d.set("sun_rays", s.sun_rays);
        d.set("records_per_point", s.records_used as f64 / points);
        d.set("shared_lookups", s.shared_lookups);
        d.set("reused_integrals", s.reused_integrals);
        d.set("record_misses", s.record_misses);
        d.set("record_uses", s.record_uses);
        d.set(
            "miss_rate",
            s.record_misses as f64 / s.record_uses.max(1) as f64,
        );
        d.set("inserted_records", s.inserted_records);
    }
    if let Some(c) = &s.own_cache {
        d.set("cache_seconds", c.seconds);
        d.set("cache_records", c.records);
        d.set("cache_shadow_rays", c.shadow_rays);
        d.set("cache_incoherent", c.incoherent);
        d.set("cache_predicted_gain", c.predicted_gain);
        d.set("cache_blind", c.blind);
        d.set("cache_planned_spp", c.planned_spp);
    }
    d
}
