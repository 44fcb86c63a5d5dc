//! The many-light renderer on the pass layer: [`render_many_lights`] runs the gathers of
//! [`crate::estimators::many_lights`] (instant radiosity, survey §6.2.1, eq. 6.1) through
//! [`run_passes`], which owns the passes, the time budget, progress, Ctrl-C and
//! determinism; this module adds the method's band shading and its stats.
//!
//! ## Bands and tiles
//! [`Gather::Full`] traces the rays of a [`TILE`] x [`TILE`] tile of pixels towards one VPL
//! together (packets from one origin), so a band ([`PixelPass::shade_band`]: four rows)
//! is shaded tile by tile, each tile sample by sample: sample `s` of every pixel of the
//! tile, then `s + 1`. A sample's estimate at a pixel is a pure function of the seed, the
//! pixel, the sample and the receivers of its tile at that sample (the tiles are fixed
//! on the image, whatever the band), and each pixel adds its samples in sample order, so
//! the image is the sample-by-sample one bit for bit, on any number of threads.
//! [`Gather::Sampled`] shades pixel by pixel.
//!
//! ## Passes
//! Without a time budget the render is one pass of `spp` samples per pixel. With one, the
//! driver's schedule applies ([`super::passes`]): a probe pass of a few samples in every
//! eighth band, then passes sized by the measured cost per sample until the budget is
//! spent, `spp` at most; every pixel gets at least one sample, and pixels of the probe's
//! bands may keep up to four more than the rest. `stats.spp` is the least any pixel took,
//! `stats.samples` all of them; each pixel's mean and variance are over its own samples.
//! A `false` from progress stops the pass under way within a tile's sample: pixels keep
//! the samples they took (`stats.complete` is then false).

use std::ops::Range;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Instant;

use glam::DVec3;

use super::estimator::{
    shade_pixels, BandPixel, Merge, PassPlan, PixelEstimator, PixelPass, PixelTiming,
};
use super::output::{RenderOutput, Stats, View};
use super::passes::{run_passes, PassParams};
use super::registry::{MethodInputs, MethodRenderer, MethodSpec};
use super::sums::PixelSums;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::estimators::many_lights::{
    tile_of, Gather, GatherWork, Gatherer, ManyLightParams, Sampling, Scratch, Unoccluded,
    VplDistribution, VplSums, TILE,
};
use crate::geometry::Scene;
use crate::lights::envmap::EnvMap;
use crate::lights::vpl::{Importance, TraceParams, VplSet};
use crate::parallel::with_threads;

impl PixelSums for VplSums {
    fn samples(&self) -> u32 {
        self.n
    }
}

/// Figures of one render.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ManyLightStats {
    /// Wall-clock seconds.
    pub seconds: f64,
    /// The least samples any pixel took (every pixel took `spp` without a time budget
    /// or a stop).
    pub spp: u32,
    /// False when progress stopped a pass part-way.
    pub complete: bool,
    /// Passes made.
    pub passes: u32,
    /// Seconds until every pixel had a sample, where the budget could not buy that
    /// ([`super::passes::PassRun::first_sample_seconds`]).
    pub first_sample_seconds: Option<f64>,
    /// VPLs the gather used (all, or the surface VPLs without `direct`).
    pub vpls: u64,
    /// Pixel samples taken.
    pub samples: u64,
    /// Primary rays traced: one per pixel sample.
    pub primary_rays: u64,
    /// Shadow rays traced (VPL pairs with a zero term take none).
    pub shadow_rays: u64,
    /// Wall-clock seconds of the passes (each sample's first hit and its gather; the
    /// first hits are one ray per sample beside the gather's one per VPL).
    pub gather_seconds: f64,
    /// Shadow rays per second of `gather_seconds`.
    pub shadow_rays_per_second: f64,
    /// All rays per wall-clock second.
    pub rays_per_second: f64,
}

/// A rendered image.
#[derive(Clone, Debug, PartialEq)]
pub struct ManyLightImage {
    pub width: u32,
    pub height: u32,
    /// Mean radiance per pixel, row-major, row 0 at the top.
    pub image: Vec<[f32; 3]>,
    /// Per-pixel variance of the mean ([`VplSums::estimate`]).
    pub variance: Vec<[f32; 3]>,
    /// Samples each pixel took, row-major.
    pub sample_counts: Vec<u32>,
    pub stats: ManyLightStats,
}

/// The rays and scratch of one band, and the first error its gathers met.
#[derive(Default)]
struct BandWork {
    gather: GatherWork,
    scratch: Scratch,
    error: Option<Error>,
}

impl Merge for BandWork {
    fn merge(&mut self, other: Self) {
        self.gather += other.gather;
        if self.error.is_none() {
            self.error = other.error;
        }
    }
}

/// The many-light method on the pass layer; also its pass (it learns nothing between
/// passes).
struct ManyLights<'a> {
    gatherer: Gatherer<'a>,
    camera: &'a Camera,
    gather: Gather,
    /// Shade [`Gather::Full`] bands as tiles (false: pixel by pixel, each sample tracing
    /// its tile for one pixel; for the tests).
    tiles: bool,
    /// Set by the first gather that fails: the others stop.
    failed: AtomicBool,
}

impl ManyLights<'_> {
    /// Keeps the first error and stops the passes.
    fn fail(&self, e: Error, work: &mut BandWork) {
        self.failed.store(true, Ordering::Relaxed);
        work.error.get_or_insert(e);
    }

    /// Sample `s` of [`Gather::Full`] at `tile`, or `None` after a failure.
    fn full_tile(
        &self,
        tile: &[usize],
        s: u32,
        work: &mut BandWork,
        out: &mut Vec<DVec3>,
    ) -> Option<()> {
        let BandWork {
            gather, scratch, ..
        } = work;
        match self.gatherer.full_tile(tile, s, scratch, gather, out) {
            Ok(()) => Some(()),
            Err(e) => {
                self.fail(e, work);
                None
            }
        }
    }
}

impl PixelPass for ManyLights<'_> {
    type Work = BandWork;
    type Note = ();
    type Sums = VplSums;

    fn shade_pixel(
        &self,
        pixel: usize,
        samples: Range<u32>,
        acc: &mut VplSums,
        work: &mut BandWork,
        _note: &mut (),
    ) -> PixelTiming {
        let start = Instant::now();
        match self.gather {
            Gather::Sampled { draws, .. } => {
                for s in samples {
                    let (x, var) = self.gatherer.sampled_pixel(
                        pixel,
                        s,
                        draws,
                        &mut work.scratch,
                        &mut work.gather,
                    );
                    acc.add(x, var);
                }
            }
            Gather::Full => {
                // The pixel's value depends on its tile's receivers: trace them all.
                let (mut tile, mut out) = (Vec::new(), Vec::new());
                tile_of(pixel, self.camera.width, self.camera.height, &mut tile);
                let k = tile.iter().position(|&p| p == pixel).expect("in its tile");
                for s in samples {
                    if self.failed.load(Ordering::Relaxed)
                        || self.full_tile(&tile, s, work, &mut out).is_none()
                    {
                        break;
                    }
                    acc.add(out[k], DVec3::ZERO);
                }
            }
        }
        PixelTiming {
            anchor_ns: 0,
            sample_ns: start.elapsed().as_nanos() as u64,
        }
    }

    /// [`Gather::Full`]: tile by tile ([`TILE`] x [`TILE`], fixed on the image), each tile
    /// sample by sample (module docs); the tile's time is shared among its pixels by the
    /// samples they took.
    fn shade_band(
        &self,
        pixels: &mut [BandPixel<'_, VplSums, ()>],
        work: &mut BandWork,
        stop: &dyn Fn() -> bool,
    ) {
        let stop = || stop() || self.failed.load(Ordering::Relaxed);
        if self.gather != Gather::Full || !self.tiles {
            return shade_pixels(self, pixels, work, &stop);
        }
        let (Some(first), Some(last)) = (pixels.first(), pixels.last()) else {
            return;
        };
        let (first, last) = (first.pixel, last.pixel);
        let (width, height) = (self.camera.width, self.camera.height);
        let (w, t) = (width as usize, TILE as usize);
        let (mut tile, mut out) = (Vec::with_capacity(t * t), Vec::with_capacity(t * t));
        // Tiles that hold a pixel of the band: their rows' tiles, left to right.
        for ty in first / w / t..=last / w / t {
            for tx in 0..w.div_ceil(t) {
                tile_of((ty * t * w) + tx * t, width, height, &mut tile);
                // The band's pixels of the tile (by index into `pixels`).
                let mine: Vec<(usize, usize)> = tile
                    .iter()
                    .enumerate()
                    .filter(|(_, &p)| (first..=last).contains(&p))
                    .map(|(k, &p)| (k, p - first))
                    .collect();
                let due = |p: &BandPixel<'_, VplSums, ()>, s: u32| p.acc.n == s && s < p.target;
                let lo = mine.iter().map(|&(_, i)| pixels[i].acc.n).min();
                let hi = mine.iter().map(|&(_, i)| pixels[i].target).max();
                let (Some(lo), Some(hi)) = (lo, hi) else {
                    continue;
                };
                let start = Instant::now();
                let counts: Vec<u32> = mine.iter().map(|&(_, i)| pixels[i].acc.n).collect();
                let mut stopped = false;
                for s in lo..hi {
                    if !mine.iter().any(|&(_, i)| due(&pixels[i], s)) {
                        continue;
                    }
                    if stop() || self.full_tile(&tile, s, work, &mut out).is_none() {
                        stopped = true;
                        break;
                    }
                    for &(k, i) in &mine {
                        if due(&pixels[i], s) {
                            pixels[i].acc.add(out[k], DVec3::ZERO);
                        }
                    }
                }
                // The tile's time, shared by the samples its pixels took.
                let ns = start.elapsed().as_nanos() as u64;
                let added: Vec<u64> = mine
                    .iter()
                    .zip(&counts)
                    .map(|(&(_, i), &n)| (pixels[i].acc.n - n) as u64)
                    .collect();
                let total = added.iter().sum::<u64>().max(1);
                for (&(_, i), a) in mine.iter().zip(added) {
                    pixels[i].timing.sample_ns += ns * a / total;
                }
                if stopped {
                    return;
                }
            }
        }
    }
}

impl PixelEstimator for ManyLights<'_> {
    type Work = BandWork;
    type Note = ();
    type Sums = VplSums;
    type Pass<'b>
        = ManyLights<'b>
    where
        Self: 'b;

    fn pass<R>(&self, _plan: &PassPlan, run: impl FnOnce(&ManyLights<'_>) -> R) -> R {
        run(self)
    }
}

/// Samples per pixel of the many-light methods without `spp` or a time budget.
pub const DEFAULT_VPL_SPP: u32 = 1;

/// The registry's renderer of methods "vpl" (`sampled` false: every VPL summed) and
/// "vpl_sampled" (VPLs drawn per sample): without `vpls` it traces the default set for the
/// view ([`default_vpls`], `bounces` generations), then renders ([`render_many_lights`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ManyLightsRenderer {
    pub sampled: bool,
}

impl MethodRenderer for ManyLightsRenderer {
    fn family(&self) -> &'static str {
        "many_lights"
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
        if inputs.vpls.is_some() && inputs.bounces.is_some() {
            return Err(Error::invalid(
                "bounces",
                "a given VPL set has its own depth; pass bounces=None or trace the set with \
                 depth=bounces",
            ));
        }
        let depth = inputs.bounces_for(spec)?;
        let gather = match (self.sampled, inputs.vpl_samples, inputs.sampling) {
            (true, draws, sampling) => Gather::Sampled {
                draws: draws.unwrap_or(DEFAULT_VPL_SAMPLES),
                sampling: sampling.unwrap_or_default(),
            },
            (false, None, None) => Gather::Full,
            (false, draws, _) => {
                let name = if draws.is_some() {
                    "vpl_samples"
                } else {
                    "sampling"
                };
                return Err(Error::invalid(
                    name,
                    format!(
                        "method {:?} sums every VPL; \"vpl_sampled\" draws them",
                        spec.name
                    ),
                ));
            }
        };
        let p = &inputs.params;
        let params = ManyLightParams {
            spp: inputs.spp_for(spec),
            seed: p.seed,
            jitter: p.jitter,
            clamp: inputs.clamp,
            direct: p.direct,
            gather,
            time_budget: p.time_budget,
        };
        params.validate()?;
        let (scene, env, threads) = (inputs.scene, inputs.env, inputs.threads);
        // The budget covers the default set's tracing too: the passes get what is left.
        let start = Instant::now();
        let traced = match inputs.vpls {
            Some(_) => None,
            None => Some(default_vpls(
                scene, env, camera, p.seed, depth, p.direct, threads,
            )?),
        };
        let vpls = inputs
            .vpls
            .or(traced.as_ref())
            .expect("traced when not given");
        let params = ManyLightParams {
            time_budget: params
                .time_budget
                .map(|b| (b - start.elapsed().as_secs_f64()).max(1e-3)),
            ..params
        };
        let out = render_many_lights(scene, env, camera, vpls, &params, None, threads, progress)?;
        let s = &out.stats;
        let mut d = Stats::default();
        d.set("method", spec.name);
        d.set("seconds", start.elapsed().as_secs_f64());
        d.set("spp", s.spp);
        d.set("complete", s.complete);
        d.set("passes", s.passes);
        // From the call's start: the default set's tracing comes first.
        let before_passes = start.elapsed().as_secs_f64() - s.seconds;
        d.set(
            "first_sample_seconds",
            s.first_sample_seconds.map(|t| t + before_passes),
        );
        d.set("jitter", params.jitter);
        d.set("direct", params.direct);
        d.set("clamp", params.clamp);
        d.set(
            "vpl_samples",
            match gather {
                Gather::Sampled { draws, .. } => Some(draws),
                Gather::Full => None,
            },
        );
        d.set(
            "sampling",
            match gather {
                Gather::Sampled { sampling, .. } => Some(sampling.name()),
                Gather::Full => None,
            },
        );
        d.set("vpls", s.vpls);
        d.set("samples", s.samples);
        d.set("primary_rays", s.primary_rays);
        d.set("shadow_rays", s.shadow_rays);
        d.set("gather_seconds", s.gather_seconds);
        d.set("shadow_rays_per_second", s.shadow_rays_per_second);
        d.set("rays_per_second", s.rays_per_second);
        d.set(
            "bounces",
            vpls.vpls.iter().map(|v| v.bounce).max().unwrap_or(0),
        );
        if let Some(t) = &traced {
            d.set("vpl_trace_seconds", t.stats.seconds);
        }
        Ok(RenderOutput {
            width: out.width,
            height: out.height,
            image: out.image,
            variance: out.variance,
            alpha: None,
            sample_counts: out.sample_counts,
            stats: d,
        })
    }
}

/// VPLs a render of method "vpl" or "vpl_sampled" traces when given none.
pub const DEFAULT_VPLS: u64 = 4096;
/// VPLs method "vpl_sampled" draws per pixel sample when not told.
pub const DEFAULT_VPL_SAMPLES: u32 = 16;

/// The set a render given no VPLs traces: [`DEFAULT_VPLS`] by light tracing from `env`
/// and the scene's area lights with acceptance by importance to `camera`'s view, surface
/// VPLs of `depth` generations, and light VPLs only with `direct` (without, the set holds
/// indirect light alone, as `direct = false` renders it).
pub fn default_vpls(
    scene: &Scene,
    env: &EnvMap,
    camera: &Camera,
    seed: u64,
    depth: u32,
    direct: bool,
    threads: Option<usize>,
) -> Result<VplSet> {
    let params = TraceParams {
        count: DEFAULT_VPLS,
        depth,
        seed,
        importance: Some(Importance::DEFAULT),
        lights: direct,
    };
    VplSet::trace(scene, env, Some(camera), &params, threads)
}

/// Renders `camera`'s view of `scene` lit by `vpls` ([`crate::estimators::many_lights`],
/// passes as the module docs say); `env` is what misses see (with `direct`).
/// `distribution` replaces [`Unoccluded`] for [`Gather::Sampled`] with
/// [`Sampling::Unoccluded`] (with another sampling it is an error). `progress(done,
/// planned)` (pixel samples) is called from the calling thread about every 0.1 s and after
/// each pass; `false` stops the render, within the tiles under way if a pass is
/// (`stats.complete` is then false). Fails on bad parameters or a VPL set traced in other
/// geometry.
#[allow(clippy::too_many_arguments)]
pub fn render_many_lights(
    scene: &Scene,
    env: &EnvMap,
    camera: &Camera,
    vpls: &VplSet,
    params: &ManyLightParams,
    distribution: Option<&dyn VplDistribution>,
    threads: Option<usize>,
    progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
) -> Result<ManyLightImage> {
    render_with(
        scene,
        env,
        camera,
        vpls,
        params,
        distribution,
        threads,
        progress,
        true,
    )
}

/// [`render_many_lights`], with [`Gather::Full`] bands shaded as tiles or (`tiles =
/// false`) pixel by pixel.
#[allow(clippy::too_many_arguments)]
fn render_with(
    scene: &Scene,
    env: &EnvMap,
    camera: &Camera,
    vpls: &VplSet,
    params: &ManyLightParams,
    distribution: Option<&dyn VplDistribution>,
    threads: Option<usize>,
    progress: &mut (dyn FnMut(u64, u64) -> bool + Send),
    tiles: bool,
) -> Result<ManyLightImage> {
    params.validate()?;
    camera.check_buffers()?;
    if vpls.fingerprint != scene.geometry_fingerprint() {
        return Err(Error::invalid(
            "vpls",
            "were traced in other geometry: trace them again for this scene",
        ));
    }
    if let (Some(_), Gather::Sampled { sampling, .. }) = (distribution, params.gather) {
        if sampling != Sampling::Unoccluded {
            return Err(Error::invalid(
                "sampling",
                format!(
                    "{:?} draws from one table for every pixel; a per-pixel distribution \
                     needs \"unoccluded\"",
                    sampling.name()
                ),
            ));
        }
    }
    let start = Instant::now();
    let default = Unoccluded {
        clamp: params.clamp,
    };
    let distribution = distribution.unwrap_or(&default);
    let mut method = ManyLights {
        gatherer: Gatherer::new(scene, env, camera, vpls, params, distribution),
        camera,
        gather: params.gather,
        tiles,
        failed: AtomicBool::new(false),
    };
    with_threads(threads, || {
        let _ = scene.bvh();
    })?;
    let (width, height) = (camera.width, camera.height);
    let pass_params = PassParams {
        spp: params.spp,
        time_budget: params.time_budget,
        adaptive: false,
        first_spp: None,
    };
    let passes_start = Instant::now();
    let run = run_passes(
        &mut method,
        width as usize,
        height as usize,
        &pass_params,
        start,
        threads,
        progress,
    )?;
    let gather_seconds = passes_start.elapsed().as_secs_f64();
    let work = run.total.gather;
    scene.add_counters(work.counters);
    if let Some(e) = run.total.error {
        return Err(e);
    }
    let sampled = matches!(params.gather, Gather::Sampled { .. });
    let (image, variance) = run.sums.iter().map(|p| p.estimate(sampled)).unzip();
    let seconds = start.elapsed().as_secs_f64();
    let stats = ManyLightStats {
        seconds,
        spp: run.min_spp(),
        complete: run.complete,
        passes: run.passes,
        first_sample_seconds: run.first_sample_seconds,
        vpls: method.gatherer.used().len() as u64,
        samples: run.samples(),
        primary_rays: work.primary_rays,
        shadow_rays: work.shadow_rays,
        gather_seconds,
        shadow_rays_per_second: work.shadow_rays as f64 / gather_seconds.max(1e-9),
        rays_per_second: (work.shadow_rays + work.primary_rays) as f64 / seconds.max(1e-9),
    };
    Ok(ManyLightImage {
        width,
        height,
        image,
        variance,
        sample_counts: run.counts(),
        stats,
    })
}

#[cfg(test)]
mod tests;
