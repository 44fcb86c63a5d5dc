//! Method "stochastic": direct light with BLD's probabilistic visibility
//! (`002_f6f7ae5fac667f5c.txt`, eq. 4–8 with splitting, eq. 25–27; probabilities §4.1–4.2)
//! on the pass layer ([`run_passes`]).
//!
//! A sample is method "env"'s (a jittered primary ray, the map's own distribution and one
//! point on each area light, the same random numbers:
//! [`Lighting::estimate_lights_with`]) with each shadow ray's `V` replaced by eq. 8's
//! `Ṽ` ([`SplitVisibility::estimate`]): `0`, `1/p` or `−1/p`, unclamped, so the image is
//! unbiased for "env"'s and pixels may be negative. The term of a ray is drawn from its own
//! stream `(seed ^ TERM_STREAM, pixel, sample)`, dimension = the ray's index in the sample.
//!
//! Probabilities: "equal" ([`Probabilities::equal`]); "optimal" and "cost" from
//! `probe_rays` probes per pixel (§4.1), traced once from the hit through the pixel's
//! centre toward points drawn from the lights (the lights in turn) and kept for the
//! pixel's samples in every pass (any probabilities with the needed terms positive are
//! unbiased, so a sample off the centre's point stays unbiased).
//!
//! ## Determinism
//! Sample `s` of a pixel is a pure function of `(seed, pixel, s)`, the pixel's probes of
//! `(seed, pixel)`: the image is the same for any thread count.

use std::ops::Range;
use std::time::Instant;

use glam::{DVec2, Vec2, Vec3, Vec3A};

use super::estimator::{Merge, PassPlan, PixelEstimator, PixelPass, PixelTiming};
use super::output::{RenderOutput, Stats, View};
use super::passes::{run_passes, PassParams};
use super::registry::{MethodInputs, MethodRenderer, MethodSpec};
use super::sums::{resolve, CvSums};
use crate::camera::{Camera, DIM_PIXEL_JITTER};
use crate::error::{Error, Result};
use crate::estimators::direct::{DirectCounters, Lighting, ProductLevel};
use crate::estimators::indirect::shading_point_at;
use crate::estimators::stochastic_visibility::split::{
    ProbabilityMode, ShadowWork, SplitVisibility,
};
use crate::estimators::stochastic_visibility::Probabilities;
use crate::geometry::proxies::ProxySet;
use crate::geometry::{Scene, TraversalCounters};
use crate::lights::envmap::EnvMap;
use crate::parallel::with_threads;
use crate::sampling::rng::{SampleRng, Sampler};
use crate::sampling::sobol::PixelSampler;

/// Probe rays per pixel without `probe_rays` (the paper's 16, §4.1).
pub const DEFAULT_PROBE_RAYS: u32 = 16;

/// Most probe rays per pixel.
pub const MAX_PROBE_RAYS: u32 = 65_536;

/// Stream of the terms' draws (xor-ed into the seed).
const TERM_STREAM: u64 = 0x5eed_7e2a_0b1d_0001;

/// Stream of the probes' light points (xor-ed into the seed).
const PROBE_STREAM: u64 = 0x5eed_7e2a_0b1d_0002;

/// What method "stochastic" reads beside the common parameters, as given (`None`: the
/// default).
#[derive(Clone, Copy, Debug)]
pub struct StochasticInputs<'a> {
    /// The proxy set (required).
    pub proxies: Option<&'a ProxySet>,
    /// "equal", "optimal" or "cost"; `None`: "optimal".
    pub probabilities: Option<&'a str>,
    /// Probe rays per pixel (`>= 1`); `None`: [`DEFAULT_PROBE_RAYS`].
    pub probe_rays: Option<u32>,
}

/// A render's parameters, checked.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StochasticParams {
    pub spp: u32,
    pub seed: u64,
    pub jitter: bool,
    pub time_budget: Option<f64>,
    pub mode: ProbabilityMode,
    pub probe_rays: u32,
    /// Exact visibility instead of eq. 8 (the reference with the same samples; Rust only).
    pub exact: bool,
}

/// The counters of a band.
#[derive(Default)]
struct BandWork {
    shadow: ShadowWork,
    direct: DirectCounters,
    primary: TraversalCounters,
    primary_rays: u64,
    /// Scene queries per pixel (row-major pixel, count), in pixel order.
    pixel_scene_rays: Vec<(u32, u32)>,
}

impl Merge for BandWork {
    fn merge(&mut self, o: Self) {
        self.shadow.merge(&o.shadow);
        self.direct.shadow_rays += o.direct.shadow_rays;
        self.primary += o.primary;
        self.primary_rays += o.primary_rays;
        self.pixel_scene_rays.extend(o.pixel_scene_rays);
    }
}

/// The method on the pass layer; also its pass.
struct StochasticPass<'a> {
    lighting: Lighting<'a>,
    camera: &'a Camera,
    split: SplitVisibility<'a>,
    params: StochasticParams,
}

impl StochasticPass<'_> {
    /// The pixel's probabilities: equal, or from probes at its centre's hit (§4.1).
    fn probabilities(&self, pixel: usize, work: &mut BandWork) -> Probabilities {
        let kind = self.split.kind();
        if !self.params.mode.probes() {
            return Probabilities::equal(kind);
        }
        let scene = self.lighting.scene;
        let (origin, dir) = self.camera.primary_ray(pixel, self.params.seed, false);
        work.primary_rays += 1;
        let Some(hit) = scene.intersect1(origin, dir, f32::INFINITY, &mut work.primary) else {
            return Probabilities::equal(kind);
        };
        let sp = shading_point_at(scene, &hit, -dir);
        let at = self.split.point(hit.obj, sp.origin, &mut work.shadow);
        let (env, lights) = (self.lighting.env, scene.area_lights());
        let sources = lights.len() + usize::from(!env.is_black());
        if sources == 0 {
            return Probabilities::equal(kind);
        }
        let mut counts = [0u64; 4];
        for k in 0..self.params.probe_rays {
            let rng = SampleRng::new(self.params.seed ^ PROBE_STREAM, pixel as u64, k as u64);
            let [a, b] = rng.get2(0);
            let which = k as usize % sources;
            let (d, tmax) = if which < lights.len() {
                let choice = rng.get(2);
                match lights[which].sample(sp.origin, choice, Vec2::new(a, b)) {
                    Some(s) => (s.direction, scene.segment_end(s.distance, s.point)),
                    None => continue,
                }
            } else {
                match env.sample(DVec2::new(a as f64, b as f64)) {
                    Some((d, _)) => (d, f32::INFINITY),
                    None => continue,
                }
            };
            if sp.normal.dot(d) <= 0.0 || tmax <= 0.0 {
                continue;
            }
            counts[self.split.probe(&at, sp.origin, d, tmax, &mut work.shadow)] += 1;
        }
        self.split.probabilities(self.params.mode, counts)
    }

    /// Sample `s` of `pixel`.
    fn sample(&self, pixel: usize, s: u32, p: &Probabilities, work: &mut BandWork) -> Vec3 {
        let (scene, env) = (self.lighting.scene, self.lighting.env);
        let width = self.camera.width as usize;
        let (px, py) = ((pixel % width) as u32, (pixel / width) as u32);
        let rng = PixelSampler::new(self.params.seed, pixel as u64, s as u64);
        let j = if self.params.jitter {
            rng.get2(DIM_PIXEL_JITTER)
        } else {
            [0.5, 0.5]
        };
        let mut d = [Vec3A::ZERO; 1];
        self.camera.pixel_directions(px, py, [j], &mut d);
        let dir = Vec3::from(d[0]);
        work.primary_rays += 1;
        let hit = scene.intersect1(self.camera.eye, dir, f32::INFINITY, &mut work.primary);
        let Some(hit) = hit else {
            return env.eval(dir);
        };
        let sp = shading_point_at(scene, &hit, -dir);
        let emitted = scene.emitted(&hit, sp.wo);
        let terms = SampleRng::new(self.params.seed ^ TERM_STREAM, pixel as u64, s as u64);
        let (split, exact) = (&self.split, self.params.exact);
        let shadow = &mut work.shadow;
        let at = split.point(hit.obj, sp.origin, shadow);
        let mut ray = 0u64;
        let l = self
            .lighting
            .estimate_lights_with(&sp, &rng, &mut work.direct, |d, tmax| {
                let u = terms.get(ray) as f64;
                ray += 1;
                if exact {
                    shadow.shadow_rays += 1;
                    split.exact(sp.origin, d, tmax, shadow) as u8 as f64
                } else {
                    split.estimate(p, u, &at, sp.origin, d, tmax, shadow)
                }
            });
        emitted + l
    }
}

impl PixelPass for StochasticPass<'_> {
    type Work = BandWork;
    type Note = Option<[f64; 3]>;
    type Sums = CvSums;

    fn shade_pixel(
        &self,
        pixel: usize,
        samples: Range<u32>,
        acc: &mut CvSums,
        work: &mut BandWork,
        note: &mut Option<[f64; 3]>,
    ) -> PixelTiming {
        let start = Instant::now();
        let before = work.shadow.scene_rays;
        let p = match note {
            Some(p) => Probabilities { p: *p },
            None => {
                let p = self.probabilities(pixel, work);
                *note = Some(p.p);
                p
            }
        };
        let anchor_ns = start.elapsed().as_nanos() as u64;
        for s in samples {
            let x = self.sample(pixel, s, &p, work);
            acc.add(x, [0.0; 3]);
        }
        let rays = (work.shadow.scene_rays - before).min(u32::MAX as u64) as u32;
        work.pixel_scene_rays.push((pixel as u32, rays));
        PixelTiming {
            anchor_ns,
            sample_ns: (start.elapsed().as_nanos() as u64).saturating_sub(anchor_ns),
        }
    }
}

impl PixelEstimator for StochasticPass<'_> {
    type Work = BandWork;
    type Note = Option<[f64; 3]>;
    type Sums = CvSums;
    type Pass<'b>
        = StochasticPass<'b>
    where
        Self: 'b;

    fn pass<R>(&self, _plan: &PassPlan, run: impl FnOnce(&StochasticPass<'_>) -> R) -> R {
        run(self)
    }
}

/// An image of method "stochastic" with its figures and the scene queries per pixel
/// (Fig. 7's image: probes, `E` tests and exact tests, row-major).
#[derive(Clone, Debug)]
pub struct StochasticImage {
    pub output: RenderOutput,
    pub scene_rays: Vec<u32>,
}

/// Renders `camera`'s view of `scene` lit by `env` and its area lights, with shadow rays
/// estimated against `proxies` (module docs). Fails, naming the argument, on proxies of
/// another scene.
pub fn render_stochastic(
    scene: &Scene,
    env: &EnvMap,
    camera: &Camera,
    proxies: &ProxySet,
    params: &StochasticParams,
    threads: Option<usize>,
    progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
) -> Result<StochasticImage> {
    let start = Instant::now();
    crate::error::check_range("probe_rays", params.probe_rays, 1, MAX_PROBE_RAYS)?;
    crate::error::check_range("spp", params.spp, 1, super::MAX_SPP)?;
    let split = SplitVisibility::new(scene, proxies)?;
    camera.check_buffers()?;
    with_threads(threads, || {
        let _ = scene.bvh();
    })?;
    let mut pass = StochasticPass {
        lighting: Lighting {
            scene,
            env,
            product_level: ProductLevel::PerMaterial,
        },
        camera,
        split,
        params: *params,
    };
    let pass_params = PassParams {
        spp: params.spp,
        time_budget: params.time_budget,
        adaptive: false,
        first_spp: None,
    };
    let (w, h) = (camera.width as usize, camera.height as usize);
    let run = run_passes(&mut pass, w, h, &pass_params, start, threads, progress)?;
    let work = &run.total;
    let sh = &work.shadow;
    if scene.counting_enabled() {
        let mut c = work.primary;
        c += sh.scene;
        scene.add_counters(c);
    }
    if proxies.scene().counting_enabled() {
        proxies.scene().add_counters(sh.proxy);
    }
    let mut scene_rays = vec![0u32; w * h];
    for &(p, n) in &work.pixel_scene_rays {
        scene_rays[p as usize] = scene_rays[p as usize].saturating_add(n);
    }
    let (image, variance) = resolve(&run.sums, &vec![[0.0; 3]; run.sums.len()]);
    let seconds = start.elapsed().as_secs_f64();
    let mut d = Stats::default();
    d.set("seconds", seconds);
    d.set("spp", run.min_spp());
    d.set("complete", run.complete);
    d.set("passes", run.passes);
    d.set("samples", run.samples());
    d.set("jitter", params.jitter);
    d.set("probabilities", params.mode.name());
    d.set("exact", params.exact);
    d.set("probe_rays_per_pixel", params.probe_rays);
    d.set("proxy_kind", proxies.kind().name());
    d.set("proxy_triangles", proxies.num_triangles());
    d.set("primary_rays", work.primary_rays);
    d.set("shadow_rays", sh.shadow_rays);
    d.set("proxy_rays", sh.proxy_rays);
    d.set("scene_rays", sh.scene_rays);
    d.set("split_rays", sh.split_rays);
    d.set("probe_rays", sh.probe_rays);
    d.set("inside_points", sh.inside_points);
    d.set("terms", sh.terms.to_vec());
    d.set("proxy_nodes", sh.proxy.nodes);
    d.set("proxy_triangle_tests", sh.proxy.triangles);
    d.set("scene_nodes", sh.scene.nodes);
    d.set("scene_triangle_tests", sh.scene.triangles);
    d.set("primary_nodes", work.primary.nodes);
    d.set("primary_triangle_tests", work.primary.triangles);
    Ok(StochasticImage {
        output: RenderOutput {
            width: camera.width,
            height: camera.height,
            image,
            variance,
            alpha: None,
            sample_counts: run.counts(),
            stats: d,
        },
        scene_rays,
    })
}

/// The registry's renderer of method "stochastic".
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StochasticRenderer;

impl StochasticRenderer {
    /// The render's parameters from the row and the inputs; errors name the argument.
    pub fn params(spec: &MethodSpec, inputs: &MethodInputs<'_>) -> Result<StochasticParams> {
        let s = inputs.stochastic;
        let mode = ProbabilityMode::parse(s.and_then(|s| s.probabilities).unwrap_or("optimal"))?;
        let probe_rays = s.and_then(|s| s.probe_rays).unwrap_or(DEFAULT_PROBE_RAYS);
        crate::error::check_range("probe_rays", probe_rays, 1, MAX_PROBE_RAYS)?;
        if inputs.bounces_for(spec)? != 0 {
            return Err(Error::invalid(
                "bounces",
                "method \"stochastic\" renders direct light only: pass bounces=0 or None",
            ));
        }
        if !inputs.params.direct {
            return Err(Error::invalid(
                "direct",
                "method \"stochastic\" renders direct light: pass direct=True",
            ));
        }
        Ok(StochasticParams {
            spp: inputs.spp_for(spec),
            seed: inputs.params.seed,
            jitter: inputs.params.jitter,
            time_budget: inputs.params.time_budget,
            mode,
            probe_rays,
            exact: false,
        })
    }
}

impl MethodRenderer for StochasticRenderer {
    fn family(&self) -> &'static str {
        "direct"
    }

    fn render(
        &self,
        spec: &MethodSpec,
        inputs: &MethodInputs<'_>,
        progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
    ) -> Result<RenderOutput> {
        let View::Camera(camera) = inputs.view else {
            return Err(Error::invalid(
                "gbuffer",
                format!("method {:?} traces its own first hits", spec.name),
            ));
        };
        let Some(proxies) = inputs.stochastic.and_then(|s| s.proxies) else {
            return Err(Error::invalid(
                "proxies",
                "method \"stochastic\" needs a proxy set (vc.Proxies)",
            ));
        };
        let params = Self::params(spec, inputs)?;
        let out = render_stochastic(
            inputs.scene,
            inputs.env,
            camera,
            proxies,
            &params,
            inputs.threads,
            progress,
        )?;
        let mut o = out.output;
        let mut d = Stats::default();
        d.set("method", spec.name);
        for (name, value) in o.stats.iter() {
            d.set(name, value.clone());
        }
        d.set(
            "pixel_scene_rays",
            out.scene_rays
                .iter()
                .map(|&n| n as u64)
                .collect::<Vec<u64>>(),
        );
        o.stats = d;
        Ok(o)
    }
}

#[cfg(test)]
mod tests;
