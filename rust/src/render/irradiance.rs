//! Method "irradiance_cache" (Survey ch. 3): the one-bounce light of diffuse surfaces from
//! an irradiance cache, in the two passes of §3.2.2. Pass 1 grows the cache over the view's
//! G-buffer ([`IrradianceCache::build_from`]: records coarse to fine where none is usable);
//! pass 2 is the direct methods' pass layer with MIS, every sample taking its diffuse part
//! of the bounce from the records at its own (jittered) hit, Phong's specular part from a
//! path of that lobe; a hit no record reaches takes its anchor's irradiance when it lies on
//! the anchor's surface (`irradiance_from_anchor`), else a whole path
//! ([`crate::estimators::direct::anchored::AnchoredShader`]). So a budget that stops pass 1
//! early leaves the uncovered pixels to paths, counted in the stats (`irradiance_misses`).
//!
//! ## Budget
//! `time_budget` counts from the call: pass 1 may take [`BUILD_SHARE`] of it (of what is
//! left after the G-buffer), pass 2 the rest. `stats["seconds"]` includes the build.

use std::time::Instant;

use super::direct::{stats as direct_stats, DirectRenderer};
use super::output::{RenderOutput, View};
use super::registry::{MethodInputs, MethodRenderer, MethodSpec};
use super::render_with_caches;
use crate::camera::GBuffer;
use crate::error::{Error, Result};
use crate::estimators::direct::{Lighting, Method};
use crate::estimators::irradiance::cache::IrradianceCache;
use crate::parallel::with_threads;

/// Share of the time budget pass 1 (the records) may take; the samples take the rest.
/// The samples of a view without direct light only interpolate (cheap), and its
/// antialiasing needs few; with direct light they also estimate it, so the share is lower.
pub const BUILD_SHARE: f64 = 0.85;
/// [`BUILD_SHARE`] when the image holds direct light.
pub const BUILD_SHARE_WITH_DIRECT: f64 = 0.5;

/// Renders the registry row "irradiance_cache".
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct IrradianceRenderer;

impl MethodRenderer for IrradianceRenderer {
    fn family(&self) -> &'static str {
        "irradiance_cache"
    }

    fn render(
        &self,
        spec: &MethodSpec,
        inputs: &MethodInputs<'_>,
        progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
    ) -> Result<RenderOutput> {
        let start = Instant::now();
        let direct = DirectRenderer(Method::Mis);
        let mut params = direct.params(spec, inputs)?;
        if params.bounces != 1 {
            return Err(Error::invalid(
                "bounces",
                format!(
                    "the irradiance cache holds one bounce of light: bounces must be 1, got {}",
                    params.bounces
                ),
            ));
        }
        let scene = inputs.scene;
        let own;
        let cache = match inputs.cache.and_then(|c| c.irradiance()) {
            Some(c) => {
                if inputs.irradiance.is_some() {
                    return Err(Error::invalid(
                        "cache",
                        "a given cache has its own parameters: drop the irradiance cache's \
                         keyword arguments (a, strata, ...) or the cache",
                    ));
                }
                c
            }
            None => {
                own = IrradianceCache::new(inputs.irradiance.unwrap_or_default())?;
                &own
            }
        };
        cache.bind_scene(scene)?;
        let env = &*inputs.env.at_least(2)?;
        let lighting = Lighting {
            scene,
            env,
            product_level: params.product_level,
        };
        let traced;
        let gbuffer = match inputs.view {
            View::GBuffer(g) => g,
            View::Camera(camera) => {
                traced = with_threads(inputs.threads, || {
                    GBuffer::render(scene, camera, 0, false, None)
                })??;
                &traced
            }
        };
        let share = if params.direct {
            BUILD_SHARE_WITH_DIRECT
        } else {
            BUILD_SHARE
        };
        let build_budget = params
            .time_budget
            .map(|b| (b - start.elapsed().as_secs_f64()).max(0.0) * share);
        let mut report_build = |done: usize, total: usize| progress(done as u64, total as u64);
        let report = cache.build_from(
            &lighting,
            gbuffer,
            params.seed,
            inputs.threads,
            Instant::now(),
            build_budget.map(|b| b.max(1e-3)),
            &mut report_build,
        )?;
        if let Some(b) = params.time_budget {
            params.time_budget = Some((b - start.elapsed().as_secs_f64()).max(1e-3));
        }
        let out = render_with_caches(
            scene,
            inputs.env,
            &gbuffer.camera,
            Some(gbuffer),
            &params,
            (None, Some(cache)),
            inputs.threads,
            progress,
        )?;
        let seconds = start.elapsed().as_secs_f64();
        Ok(out.map_stats(|s| {
            let mut d = direct_stats(spec, &params, &s);
            d.set("seconds", seconds);
            d.set("records", cache.len());
            d.set("records_inserted", report.inserted);
            d.set("records_discarded", report.discarded);
            d.set("record_bytes", IrradianceCache::record_bytes());
            d.set("cache_bytes", cache.memory_bytes());
            d.set("build_seconds", report.seconds);
            d.set("build_complete", report.complete);
            d.set("hemisphere_rays", report.hemisphere_rays);
            d.set("secondary_rays", report.secondary_rays);
            d.set("clamped_radii", report.clamped_radii);
            d.set("irradiance_lookups", s.irradiance_lookups);
            d.set("irradiance_misses", s.irradiance_misses);
            d.set("irradiance_from_anchor", s.irradiance_from_anchor);
            d.set("clamped_channels", s.irradiance_clamped);
            d.set("a", cache.params().a);
            d.set("gradients", cache.params().gradients.name());
            d.set("clamp_neighbours", cache.params().clamp_neighbours);
            d
        }))
    }
}
