//! The baseline renderer: direct illumination from an environment map and area lights,
//! by any [`Method`] of [`crate::estimators::direct`].
//!
//! Pixels are independent: sample `s` of pixel `i` draws every random number from
//! `(seed, i, s, dimension)` and is accumulated in `f64` in sample order, so images are
//! bit-identical for any thread count. Work is split into bands of rows over rayon and
//! done in passes of one sample per pixel, so a time budget can stop between passes and
//! progress is reported after each.

use std::time::Instant;

use glam::Vec3;
use rayon::prelude::*;

use crate::camera::{Camera, DIM_PIXEL_JITTER};
use crate::error::{Error, Result};
use crate::estimators::direct::{DirectCounters, Lighting, Method, ShadingPoint};
use crate::geometry::{Scene, TraversalCounters};
use crate::lights::envmap::EnvMap;
use crate::parallel::with_threads;
use crate::sampling::rng::SampleRng;

/// Rows per work item: small enough to balance two to hundreds of threads.
const BAND_ROWS: usize = 4;

/// Most passes a time-budgeted render makes.
pub const MAX_SPP: u32 = 1 << 20;

/// Parameters of [`render`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RenderParams {
    /// Samples per pixel; with a time budget, the most passes to make.
    pub spp: u32,
    /// The direct-lighting estimator.
    pub method: Method,
    /// Seed of every random number.
    pub seed: u64,
    /// Stop after the first pass that ends past this many seconds.
    pub time_budget: Option<f64>,
    /// Octahedral level of the product's cells (5 = 32²), for [`Method::Product`].
    pub product_level: u32,
}

impl RenderParams {
    /// 16 samples per pixel by MIS, seed 0, no budget, 32² product cells.
    pub const DEFAULT: Self = Self {
        spp: 16,
        method: Method::Mis,
        seed: 0,
        time_budget: None,
        product_level: 5,
    };

    /// The defaults with another method and sample count.
    pub const fn with(method: Method, spp: u32) -> Self {
        Self {
            method,
            spp,
            ..Self::DEFAULT
        }
    }

    fn validate(&self) -> Result<()> {
        if self.spp == 0 || self.spp > MAX_SPP {
            return Err(Error::invalid(
                "spp",
                format!("must lie in [1, {MAX_SPP}], got {}", self.spp),
            ));
        }
        if let Some(b) = self.time_budget {
            if !(b.is_finite() && b > 0.0) {
                return Err(Error::invalid(
                    "time_budget",
                    format!("must be a positive number of seconds, got {b}"),
                ));
            }
        }
        if !(1..=8).contains(&self.product_level) {
            return Err(Error::invalid(
                "product_level",
                format!("must lie in [1, 8], got {}", self.product_level),
            ));
        }
        Ok(())
    }
}

impl Default for RenderParams {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// Where the time went, summed over threads (CPU seconds).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageSeconds {
    /// Primary rays (closest hits).
    pub primary: f64,
    /// Direct lighting: sampling, BSDF evaluation, shadow and BSDF rays.
    pub direct: f64,
}

/// Figures of one render.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct RenderStats {
    /// Wall-clock seconds.
    pub seconds: f64,
    /// Samples per pixel reached.
    pub spp: u32,
    /// Pixel samples taken (`spp × pixels`).
    pub samples: u64,
    /// Primary rays traced.
    pub primary_rays: u64,
    /// Shadow rays traced.
    pub shadow_rays: u64,
    /// BSDF rays traced.
    pub bsdf_rays: u64,
    /// All rays per wall-clock second.
    pub rays_per_second: f64,
    /// Per-stage CPU seconds.
    pub stages: StageSeconds,
}

/// A rendered image.
#[derive(Clone, Debug, PartialEq)]
pub struct Rendered {
    pub width: u32,
    pub height: u32,
    /// Mean radiance per pixel, row-major, row 0 at the top.
    pub image: Vec<[f32; 3]>,
    /// Per-pixel variance of the mean, per channel (infinite with one sample).
    pub variance: Vec<[f32; 3]>,
    pub stats: RenderStats,
}

/// Running sums of one pixel.
#[derive(Clone, Copy, Default)]
struct PixelSums {
    sum: [f64; 3],
    sum_sq: [f64; 3],
}

/// What one band of one pass did.
#[derive(Clone, Copy, Default)]
struct BandWork {
    direct: DirectCounters,
    bvh: TraversalCounters,
    primary_ns: u64,
    direct_ns: u64,
}

impl BandWork {
    fn add(mut self, o: BandWork) -> BandWork {
        self.direct.shadow_rays += o.direct.shadow_rays;
        self.direct.bsdf_rays += o.direct.bsdf_rays;
        self.bvh += o.bvh;
        self.primary_ns += o.primary_ns;
        self.direct_ns += o.direct_ns;
        self
    }
}

/// One pixel sample: radiance along the primary ray (emission seen directly, the
/// environment on a miss, direct illumination at the first hit).
fn pixel_sample(
    lighting: &Lighting,
    camera: &Camera,
    params: &RenderParams,
    pixel: usize,
    sample: u32,
    work: &mut BandWork,
) -> Vec3 {
    let scene = lighting.scene;
    let rng = SampleRng::new(params.seed, pixel as u64, sample as u64);
    let width = camera.width as usize;
    let (px, py) = ((pixel % width) as u32, (pixel / width) as u32);
    let (origin, dir) = camera.pixel_ray(px, py, rng.get2(DIM_PIXEL_JITTER));
    let start = Instant::now();
    let hit = scene.intersect1(origin, dir, f32::INFINITY, &mut work.bvh);
    let traced = Instant::now();
    work.primary_ns += (traced - start).as_nanos() as u64;
    let Some(hit) = hit else {
        return lighting.env.eval(dir);
    };
    let wo = -dir;
    let normal = if hit.normal.dot(wo) < 0.0 {
        -hit.normal
    } else {
        hit.normal
    };
    let sp = ShadingPoint {
        origin: scene.offset_point(hit.position, normal),
        normal,
        wo,
        material: scene.mesh().objects[hit.obj as usize].material,
    };
    let radiance = scene.emitted(&hit, wo)
        + lighting.estimate(&sp, params.method, &rng, &mut work.direct, &mut work.bvh);
    work.direct_ns += traced.elapsed().as_nanos() as u64;
    radiance
}

/// Renders `camera`'s view of `scene` lit by `env` and the scene's area lights.
/// `progress(spp_done, spp_planned)` is called after every pass on the calling thread;
/// returning `false` stops after that pass (the image so far is returned). Work runs on
/// `threads` workers (`None`: all cores).
pub fn render(
    scene: &Scene,
    env: &EnvMap,
    camera: &Camera,
    params: &RenderParams,
    threads: Option<usize>,
    progress: &mut (dyn FnMut(u32, u32) -> bool + Send),
) -> Result<Rendered> {
    params.validate()?;
    let lighting = Lighting {
        scene,
        env,
        product_level: params.product_level,
    };
    let (width, height) = (camera.width as usize, camera.height as usize);
    let start = Instant::now();
    let mut sums = vec![PixelSums::default(); width * height];
    let mut total = BandWork::default();
    let mut spp = 0u32;
    with_threads(threads, || {
        // The BVH is built once, in parallel, before the passes.
        let _ = scene.bvh();
        while spp < params.spp {
            let pass = spp;
            let work = sums
                .par_chunks_mut(BAND_ROWS * width)
                .enumerate()
                .map(|(band, pixels)| {
                    let mut work = BandWork::default();
                    let first = band * BAND_ROWS * width;
                    for (i, acc) in pixels.iter_mut().enumerate() {
                        let l = pixel_sample(&lighting, camera, params, first + i, pass, &mut work);
                        for c in 0..3 {
                            let v = l[c] as f64;
                            acc.sum[c] += v;
                            acc.sum_sq[c] += v * v;
                        }
                    }
                    work
                })
                .reduce(BandWork::default, BandWork::add);
            total = total.add(work);
            spp += 1;
            let keep_going = progress(spp, params.spp);
            let over_budget = params
                .time_budget
                .is_some_and(|b| start.elapsed().as_secs_f64() >= b);
            if !keep_going || over_budget {
                break;
            }
        }
    })?;
    if scene.counting_enabled() {
        scene.add_counters(total.bvh);
    }

    let n = spp as f64;
    let image = sums.iter().map(|s| s.sum.map(|v| (v / n) as f32)).collect();
    let variance = sums
        .iter()
        .map(|s| {
            std::array::from_fn(|c| {
                if spp < 2 {
                    return f32::INFINITY;
                }
                let mean = s.sum[c] / n;
                let var = ((s.sum_sq[c] - mean * s.sum[c]) / (n - 1.0)).max(0.0);
                (var / n) as f32
            })
        })
        .collect();
    let seconds = start.elapsed().as_secs_f64();
    let pixels = (width * height) as u64;
    let rays = pixels * spp as u64 + total.direct.shadow_rays + total.direct.bsdf_rays;
    Ok(Rendered {
        width: camera.width,
        height: camera.height,
        image,
        variance,
        stats: RenderStats {
            seconds,
            spp,
            samples: pixels * spp as u64,
            primary_rays: pixels * spp as u64,
            shadow_rays: total.direct.shadow_rays,
            bsdf_rays: total.direct.bsdf_rays,
            rays_per_second: rays as f64 / seconds.max(1e-9),
            stages: StageSeconds {
                primary: total.primary_ns as f64 * 1e-9,
                direct: total.direct_ns as f64 * 1e-9,
            },
        },
    })
}
