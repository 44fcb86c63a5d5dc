//! The many-light renderer: every pixel lit by a set of virtual point lights
//! ([`crate::lights::vpl`]), as instant radiosity does (survey `004_d2289ee9e28a0f98.txt`
//! §6.2.1, eq. 6.1):
//!
//! `I(x) = Σ_k L(x ← v_k) f_s(x_{-1} ← x ← v_k) G(x ↔ v_k) V(x ↔ v_k)`,
//!
//! which for a surface VPL of flux `Φ_k` that arrived from `ω_k` is `f_x(ωo, ω) ·
//! f_k(ω_k, -ω) · Φ_k · cos θ_x cos θ_k / d²` ([`Vpl::connect`]). Two gathers:
//!
//! - [`Gather::Full`]: the sum over all VPLs with one shadow ray each. Unbiased for the
//!   VPL set (the set itself is an unbiased estimate of the light, so the image is too,
//!   but its error is correlated over the image: the VPL set's noise shows as blotches,
//!   not grain). The rays of a 4 x 4 tile of pixels towards one VPL start at the VPL and
//!   go out in nearby directions: they are handed to [`Scene::occluded`] as runs from one
//!   origin, which it traces as packets ([`crate::geometry::bvh::PACKET`] = 16 rays).
//! - [`Gather::Sampled`]: `M` VPLs per pixel sample drawn from a per-pixel distribution
//!   `p_k ∝ w_k` ([`VplDistribution`]; default [`Unoccluded`]: the luminance of the
//!   contribution without visibility), the estimate `(1/M) Σ_m c_{k_m} V_{k_m} / p_{k_m}`.
//!   Unbiased for the full sum wherever `w_k > 0` for every VPL that contributes. The hook
//!   is where importance caching (survey §6.2.3) puts its cached distributions.
//!
//! With `clamp`, the geometry term is `min(G, clamp)`: this removes the bright spots that
//! VPLs near a receiver make (`1/d²`) and is biased (dark corners, the light of short
//! paths lost); without (the default) the sum is unbiased for the set.
//!
//! ## Samples
//! Sample `s` shades its own first hits ([`GBuffer::render`] with the seed of sample `s`,
//! jittered: antialiased with a box filter, the same pixel integral the path tracer
//! estimates), so the full sum costs `spp · N` shadow rays per pixel; without `jitter` every
//! sample shades the pixel's centre. `variance` is the sample variance of the mean over the
//! `spp` samples, or with one sample the variance of the `M` draws' mean ([`Gather::Sampled`])
//! or infinity ([`Gather::Full`]).
//!
//! ## Direct light
//! With `direct` the image holds what the camera sees of emitters and the map, and the
//! light VPLs (generation 0: points on area lights, directions of the map) light the
//! receivers directly; without, only surface VPLs (generations `>= 1`) count: the indirect
//! part that `method="path", direct=False` estimates.
//!
//! ## Determinism
//! Tiles are fixed, each pixel is summed by one worker in VPL order in `f64`, and the draws
//! of [`Gather::Sampled`] read `(seed, pixel, sample, dimension)`: images are bit-identical
//! for any thread count.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use glam::{DVec3, Vec3};
use rayon::prelude::*;

use crate::camera::{Camera, GBuffer};
use crate::error::{Error, Result};
use crate::estimators::indirect::shading_point_at;
use crate::geometry::{RayBatch, Scene, TMax, TraversalCounters};
use crate::lights::envmap::EnvMap;
use crate::lights::vpl::{luminance, Vpl, VplKind, VplSet};
use crate::parallel::{run_polling, with_threads};
use crate::sampling::rng::{mix64, SampleRng};
use light_paths::Receiver as VplReceiver;

/// Most samples per pixel.
pub const MAX_SPP: u32 = 1 << 16;

/// Most VPLs drawn per pixel sample by [`Gather::Sampled`].
pub const MAX_DRAWS: u32 = 1 << 16;

/// Side of a tile in pixels: a tile's rays towards one VPL are one packet.
const TILE: u32 = 4;

/// VPLs whose rays go to [`Scene::occluded`] in one batch (16 per VPL per tile: 4096
/// rays, a few of its chunks).
const VPL_BLOCK: usize = 256;

/// Seconds between progress reports.
const PROGRESS_INTERVAL: Duration = Duration::from_millis(100);

/// How each pixel sample gathers the VPLs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Gather {
    /// Every VPL, one shadow ray each.
    Full,
    /// `draws` VPLs drawn from the pixel's [`VplDistribution`], `1..=MAX_DRAWS`.
    Sampled { draws: u32 },
}

/// Parameters of [`render_many_lights`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ManyLightParams {
    /// Samples per pixel, `1..=MAX_SPP` (each its own first hits).
    pub spp: u32,
    pub seed: u64,
    /// Jittered first hits (antialiased) instead of the pixels' centres.
    pub jitter: bool,
    /// Upper bound of the geometry term `cos cos / d²` (1/m², biased), or none.
    pub clamp: Option<f32>,
    /// Whether the image holds direct light (module docs).
    pub direct: bool,
    pub gather: Gather,
    /// Stop after the first sample pass that ends past this many seconds.
    pub time_budget: Option<f64>,
}

impl ManyLightParams {
    /// One jittered sample of the full sum, unclamped, direct light included.
    pub const DEFAULT: Self = Self {
        spp: 1,
        seed: 0,
        jitter: true,
        clamp: None,
        direct: true,
        gather: Gather::Full,
        time_budget: None,
    };

    /// Fails with an error naming the first parameter out of range.
    pub fn validate(&self) -> Result<()> {
        crate::error::check_range("spp", self.spp, 1, MAX_SPP)?;
        if let Some(c) = self.clamp {
            if !(c.is_finite() && c > 0.0) {
                return Err(Error::invalid(
                    "clamp",
                    format!(
                        "must be a positive, finite bound of cos cos / d² (1/m²) or None, got {c}"
                    ),
                ));
            }
        }
        if let Gather::Sampled { draws } = self.gather {
            crate::error::check_range("vpl_samples", draws, 1, MAX_DRAWS)?;
        }
        crate::error::check_time_budget(self.time_budget)?;
        Ok(())
    }
}

impl Default for ManyLightParams {
    fn default() -> Self {
        Self::DEFAULT
    }
}

/// A per-pixel distribution over the VPLs for [`Gather::Sampled`].
pub trait VplDistribution: Sync {
    /// Fills `weights[k]` (finite, `>= 0`, any scale) for `vpls[k]` at the receiver `r` of
    /// `pixel` (row-major). Unbiased only if `weights[k] > 0` wherever VPL `k`'s
    /// contribution is.
    fn weights(
        &self,
        scene: &Scene,
        pixel: usize,
        r: &VplReceiver,
        vpls: &[Vpl],
        disk_area: f32,
        weights: &mut [f64],
    );
}

/// The default distribution: the luminance of each VPL's contribution without visibility
/// (with the render's clamp), positive exactly where the contribution can be.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Unoccluded {
    pub clamp: Option<f32>,
}

impl VplDistribution for Unoccluded {
    fn weights(
        &self,
        _scene: &Scene,
        _pixel: usize,
        r: &VplReceiver,
        vpls: &[Vpl],
        disk_area: f32,
        weights: &mut [f64],
    ) {
        for (w, v) in weights.iter_mut().zip(vpls) {
            *w = v
                .connect(r, self.clamp, disk_area)
                .map_or(0.0, |c| luminance(c.value) as f64);
        }
    }
}

/// Figures of one render.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ManyLightStats {
    /// Wall-clock seconds.
    pub seconds: f64,
    /// Samples every pixel received.
    pub spp: u32,
    /// False when progress stopped a pass part-way.
    pub complete: bool,
    /// VPLs the gather used (all, or the surface VPLs without `direct`).
    pub vpls: u64,
    /// Pixel samples taken.
    pub samples: u64,
    pub primary_rays: u64,
    /// Shadow rays traced (VPL pairs with a zero term take none).
    pub shadow_rays: u64,
    /// Wall-clock seconds spent in the gathers (shading and shadow rays).
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
    /// Per-pixel variance of the mean (module docs).
    pub variance: Vec<[f32; 3]>,
    pub stats: ManyLightStats,
}

/// One pixel sample's receiver.
#[derive(Clone, Copy)]
enum Receiver {
    /// Radiance the camera sees without a surface to shade (the map; zero without
    /// `direct`).
    Background(Vec3),
    /// A surface: light it emits towards the camera (with `direct`) and its shading point.
    Surface { emitted: Vec3, r: VplReceiver },
}

/// Per-pixel sums over samples: the estimates' sum and sum of squares, and (one sample of
/// [`Gather::Sampled`]) the draws' variance of the mean.
#[derive(Clone, Copy, Default)]
struct PixelSums {
    sum: DVec3,
    sum2: DVec3,
    draw_variance: DVec3,
}

/// The seed of sample `s`'s first hits.
fn sample_seed(seed: u64, s: u32) -> u64 {
    mix64(seed ^ mix64(0x4d41_4e59_4c49_4748 ^ s as u64))
}

/// The receivers of sample `s`.
fn receivers(
    scene: &Scene,
    env: &EnvMap,
    camera: &Camera,
    params: &ManyLightParams,
    s: u32,
) -> Result<Vec<Receiver>> {
    let g = GBuffer::render(
        scene,
        camera,
        sample_seed(params.seed, s),
        params.jitter,
        None,
    )?;
    Ok((0..g.object.len())
        .map(|i| {
            let dir = Vec3::from(g.direction[i]);
            let Some(hit) = g.surface_hit(i) else {
                let l = if params.direct {
                    env.eval(dir)
                } else {
                    Vec3::ZERO
                };
                return Receiver::Background(l);
            };
            let sp = shading_point_at(scene, &hit, -dir);
            let emitted = if params.direct {
                scene.emitted(&hit, sp.wo)
            } else {
                Vec3::ZERO
            };
            Receiver::Surface {
                emitted,
                r: VplReceiver::new(scene, sp),
            }
        })
        .collect())
}

/// Rays and figures of one work item.
#[derive(Default)]
struct Work {
    shadow_rays: u64,
    counters: TraversalCounters,
}

/// What a tile of one pass gives: (pixel, estimate, draws' variance) per pixel, and its
/// work.
type TileOut = (Vec<(usize, DVec3, DVec3)>, Work);

/// Reusable buffers of a tile's batches.
#[derive(Default)]
struct Batch {
    origins: Vec<[f32; 3]>,
    directions: Vec<[f32; 3]>,
    tmax: Vec<f32>,
    values: Vec<Vec3>,
    owner: Vec<u8>,
}

impl Batch {
    fn clear(&mut self) {
        self.origins.clear();
        self.directions.clear();
        self.tmax.clear();
        self.values.clear();
        self.owner.clear();
    }

    fn push(&mut self, c: light_paths::Connection, owner: usize) {
        self.origins.push(c.origin.to_array());
        self.directions.push(c.direction.to_array());
        self.tmax.push(c.tmax);
        self.values.push(c.value);
        self.owner.push(owner as u8);
    }

    /// Traces the batch through [`Scene::occluded`] and adds the visible terms to `sums`.
    fn flush(&mut self, scene: &Scene, sums: &mut [DVec3], work: &mut Work) -> Result<()> {
        if self.origins.is_empty() {
            return Ok(());
        }
        let rays = RayBatch {
            origins: &self.origins,
            directions: &self.directions,
            tmax: TMax::PerRay(&self.tmax),
        };
        let occluded = scene.occluded(&rays, None)?;
        work.shadow_rays += occluded.len() as u64;
        for ((o, v), &owner) in occluded.iter().zip(&self.values).zip(&self.owner) {
            if !o {
                sums[owner as usize] += v.as_dvec3();
            }
        }
        self.clear();
        Ok(())
    }
}

/// A tile's receivers in lanes (structure of arrays), when every one is diffuse: the terms
/// of a diffuse VPL at all of them are computed together, in the vector registers. The
/// term is [`Vpl::connect`]'s with `G = (n_x · d)(-n_v · d) / |d|⁴`.
struct Lanes {
    origin: [[f32; LANES]; 3],
    normal: [[f32; LANES]; 3],
    diffuse: [Vec3; LANES],
    shorten: [f32; LANES],
    len: usize,
}

/// Receivers per tile.
const LANES: usize = (TILE * TILE) as usize;

impl Lanes {
    /// The lanes of `points` (at most [`LANES`]), or `None` when one is not diffuse.
    fn new(points: &[(usize, VplReceiver)]) -> Option<Self> {
        if points.len() > LANES {
            return None;
        }
        // Unused lanes have a zero normal: every term there is zero.
        let mut lanes = Lanes {
            origin: [[0.0; LANES]; 3],
            normal: [[0.0; LANES]; 3],
            diffuse: [Vec3::ZERO; LANES],
            shorten: [0.0; LANES],
            len: points.len(),
        };
        for (k, (_, r)) in points.iter().enumerate() {
            lanes.diffuse[k] = r.diffuse()?;
            for a in 0..3 {
                lanes.origin[a][k] = r.sp.origin[a];
                lanes.normal[a][k] = r.sp.normal[a];
            }
            lanes.shorten[k] = r.shorten();
        }
        Some(lanes)
    }

    /// Pushes the rays of VPL `v` (of intensity `Φ f_v`) to the receivers its term
    /// reaches, with their terms.
    #[inline(always)]
    fn connect(&self, v: &Vpl, intensity: Vec3, clamp: Option<f32>, batch: &mut Batch) {
        let (o, m) = (v.origin, v.normal);
        let bound = clamp.unwrap_or(f32::INFINITY);
        let (mut g, mut inv) = ([0.0f32; LANES], [0.0f32; LANES]);
        for k in 0..LANES {
            let dx = o.x - self.origin[0][k];
            let dy = o.y - self.origin[1][k];
            let dz = o.z - self.origin[2][k];
            let sx = self.normal[0][k] * dx + self.normal[1][k] * dy + self.normal[2][k] * dz;
            let sv = -(m.x * dx + m.y * dy + m.z * dz);
            let d2 = dx * dx + dy * dy + dz * dz;
            let term = (sx * sv / (d2 * d2)).min(bound);
            g[k] = if sx > 0.0 && sv > 0.0 { term } else { 0.0 };
            inv[k] = 1.0 / d2.sqrt();
        }
        for k in 0..self.len {
            if g[k] <= 0.0 {
                continue;
            }
            let value = self.diffuse[k] * intensity * g[k];
            let d = Vec3::new(
                self.origin[0][k] - o.x,
                self.origin[1][k] - o.y,
                self.origin[2][k] - o.z,
            );
            let d2 = d.length_squared();
            let tmax = d2 * inv[k] - self.shorten[k];
            if value == Vec3::ZERO || tmax <= 0.0 {
                continue;
            }
            batch.origins.push(o.to_array());
            batch.directions.push((d * inv[k]).to_array());
            batch.tmax.push(tmax);
            batch.values.push(value);
            batch.owner.push(k as u8);
        }
    }
}

/// The full sum of eq. 6.1 at the receivers of one tile (up to 16 pixels, `shading`
/// holds their indices into `points`); adds each to `out`.
#[allow(clippy::too_many_arguments)]
fn gather_full(
    scene: &Scene,
    points: &[(usize, VplReceiver)],
    vpls: &[Vpl],
    disk_area: f32,
    clamp: Option<f32>,
    out: &mut [DVec3],
    batch: &mut Batch,
    work: &mut Work,
) -> Result<()> {
    // Point VPLs: rays from the VPL to each receiver of the tile (one origin per run).
    let lanes = Lanes::new(points);
    for block in vpls.chunks(VPL_BLOCK) {
        for v in block.iter().filter(|v| v.kind != VplKind::Env) {
            match (&lanes, v.diffuse_intensity()) {
                (Some(lanes), Some(intensity)) => {
                    lanes.connect(v, intensity, clamp, batch);
                }
                _ => {
                    for (k, (_, r)) in points.iter().enumerate() {
                        if let Some(c) = v.connect(r, clamp, disk_area) {
                            batch.push(c, k);
                        }
                    }
                }
            }
        }
        batch.flush(scene, out, work)?;
    }
    // Map directions: rays from each receiver (one origin per run).
    let env: Vec<&Vpl> = vpls.iter().filter(|v| v.kind == VplKind::Env).collect();
    for (k, (_, r)) in points.iter().enumerate() {
        for block in env.chunks(VPL_BLOCK * 16) {
            for v in block {
                if let Some(c) = v.connect(r, clamp, disk_area) {
                    batch.push(c, k);
                }
            }
            batch.flush(scene, out, work)?;
        }
    }
    Ok(())
}

/// One sample of [`Gather::Sampled`] at `sp`: the estimate and the variance of its mean
/// over the draws.
#[allow(clippy::too_many_arguments)]
fn gather_sampled(
    scene: &Scene,
    pixel: usize,
    r: &VplReceiver,
    vpls: &[Vpl],
    disk_area: f32,
    params: &ManyLightParams,
    draws: u32,
    sample: u32,
    distribution: &dyn VplDistribution,
    cdf: &mut Vec<f64>,
    work: &mut Work,
) -> (DVec3, DVec3) {
    cdf.resize(vpls.len(), 0.0);
    distribution.weights(scene, pixel, r, vpls, disk_area, cdf);
    let mut total = 0.0f64;
    for w in cdf.iter_mut() {
        total += if w.is_finite() && *w > 0.0 { *w } else { 0.0 };
        *w = total;
    }
    if !(total > 0.0 && total.is_finite()) {
        return (DVec3::ZERO, DVec3::ZERO);
    }
    let rng = SampleRng::new(params.seed, pixel as u64, sample as u64);
    let (mut sum, mut sum2) = (DVec3::ZERO, DVec3::ZERO);
    for m in 0..draws as u64 {
        let u = rng.get(m) as f64 * total;
        let k = cdf.partition_point(|&c| c <= u).min(vpls.len() - 1);
        let p = (cdf[k] - if k == 0 { 0.0 } else { cdf[k - 1] }) / total;
        let x = match vpls[k].connect(r, params.clamp, disk_area) {
            Some(c) if p > 0.0 => {
                work.shadow_rays += 1;
                if scene.occluded1(c.origin, c.direction, c.tmax, &mut work.counters) {
                    DVec3::ZERO
                } else {
                    c.value.as_dvec3() / p
                }
            }
            _ => DVec3::ZERO,
        };
        sum += x;
        sum2 += x * x;
    }
    let n = draws as f64;
    let mean = sum / n;
    let var = if draws > 1 {
        ((sum2 / n - mean * mean) / (n - 1.0)).max(DVec3::ZERO)
    } else {
        DVec3::INFINITY
    };
    (mean, var)
}

/// Renders `camera`'s view of `scene` lit by `vpls` (module docs); `env` is what misses
/// see (with `direct`). `distribution` replaces [`Unoccluded`] for [`Gather::Sampled`].
/// `progress(done, planned)` (pixel samples) is called from the calling thread about every
/// 0.1 s; `false` stops the render after the pass's tiles under way (`stats.complete`).
/// Fails on bad parameters or a VPL set traced in other geometry.
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
    params.validate()?;
    camera.check_buffers()?;
    if vpls.fingerprint != scene.geometry_fingerprint() {
        return Err(Error::invalid(
            "vpls",
            "were traced in other geometry: trace them again for this scene",
        ));
    }
    let start = Instant::now();
    let used: Vec<Vpl> = vpls
        .vpls
        .iter()
        .filter(|v| params.direct || v.bounce >= 1)
        .copied()
        .collect();
    let default = Unoccluded {
        clamp: params.clamp,
    };
    let distribution = distribution.unwrap_or(&default);
    let (width, height) = (camera.width, camera.height);
    let pixels = camera.num_pixels();
    let mut sums = vec![PixelSums::default(); pixels];
    let mut stats = ManyLightStats {
        vpls: used.len() as u64,
        complete: true,
        ..Default::default()
    };
    let tiles_x = width.div_ceil(TILE);
    let tiles = (tiles_x * height.div_ceil(TILE)) as usize;
    let planned = params.spp as u64 * pixels as u64;
    let done = AtomicU64::new(0);
    let cancel = AtomicBool::new(false);
    with_threads(threads, || {
        let _ = scene.bvh();
    })?;
    let mut counters = TraversalCounters::default();
    for s in 0..params.spp {
        if let Some(b) = params.time_budget {
            if s > 0 && start.elapsed().as_secs_f64() > b {
                break;
            }
        }
        let points = with_threads(threads, || receivers(scene, env, camera, params, s))??;
        stats.primary_rays += pixels as u64;
        let gather_start = Instant::now();
        // Each tile: (pixel, estimate, draws' variance) of its pixels, or an error.
        let tile_work = || -> Vec<Result<TileOut>> {
            (0..tiles)
                .into_par_iter()
                .map_init(
                    || (Batch::default(), Vec::new()),
                    |(batch, cdf), t| {
                        let mut work = Work::default();
                        let mut out = Vec::with_capacity((TILE * TILE) as usize);
                        if cancel.load(Ordering::Relaxed) {
                            return Ok((out, work));
                        }
                        let (tx, ty) = (t as u32 % tiles_x, t as u32 / tiles_x);
                        let mut shading: Vec<(usize, VplReceiver)> = Vec::new();
                        for y in ty * TILE..((ty + 1) * TILE).min(height) {
                            for x in tx * TILE..((tx + 1) * TILE).min(width) {
                                let i = (y * width + x) as usize;
                                match points[i] {
                                    Receiver::Background(l) => {
                                        out.push((i, l.as_dvec3(), DVec3::ZERO))
                                    }
                                    Receiver::Surface { emitted, r } => {
                                        out.push((i, emitted.as_dvec3(), DVec3::ZERO));
                                        shading.push((out.len() - 1, r));
                                    }
                                }
                            }
                        }
                        match params.gather {
                            Gather::Full => {
                                let mut acc = vec![DVec3::ZERO; shading.len()];
                                gather_full(
                                    scene,
                                    &shading,
                                    &used,
                                    vpls.disk_area,
                                    params.clamp,
                                    &mut acc,
                                    batch,
                                    &mut work,
                                )?;
                                for ((slot, _), a) in shading.iter().zip(acc) {
                                    out[*slot].1 += a;
                                }
                            }
                            Gather::Sampled { draws } => {
                                for (slot, r) in &shading {
                                    let pixel = out[*slot].0;
                                    let (mean, var) = gather_sampled(
                                        scene,
                                        pixel,
                                        r,
                                        &used,
                                        vpls.disk_area,
                                        params,
                                        draws,
                                        s,
                                        distribution,
                                        cdf,
                                        &mut work,
                                    );
                                    out[*slot].1 += mean;
                                    out[*slot].2 = var;
                                }
                            }
                        }
                        done.fetch_add(out.len() as u64, Ordering::Relaxed);
                        Ok((out, work))
                    },
                )
                .collect()
        };
        let base = s as u64 * pixels as u64;
        let results = run_polling(
            || with_threads(threads, tile_work),
            PROGRESS_INTERVAL,
            &mut || {
                if !progress(base + done.load(Ordering::Relaxed), planned) {
                    cancel.store(true, Ordering::Relaxed);
                }
            },
        )?;
        done.store(0, Ordering::Relaxed);
        stats.gather_seconds += gather_start.elapsed().as_secs_f64();
        let mut tiles_done = Vec::with_capacity(results.len());
        for r in results {
            let (out, work) = r?;
            stats.shadow_rays += work.shadow_rays;
            counters += work.counters;
            tiles_done.push(out);
        }
        // A stopped pass is dropped whole, so every pixel keeps the same samples.
        if cancel.load(Ordering::Relaxed) {
            stats.complete = false;
            break;
        }
        for (i, x, var) in tiles_done.into_iter().flatten() {
            let p = &mut sums[i];
            p.sum += x;
            p.sum2 += x * x;
            p.draw_variance = var;
        }
        stats.spp = s + 1;
        stats.samples += pixels as u64;
        if !progress(stats.samples, planned) {
            stats.complete = s + 1 == params.spp;
            break;
        }
    }
    scene.add_counters(counters);
    let n = stats.spp.max(1) as f64;
    let sampled = matches!(params.gather, Gather::Sampled { .. });
    let image = sums
        .iter()
        .map(|p| (p.sum / n).as_vec3().to_array())
        .collect();
    let variance = sums
        .iter()
        .map(|p| {
            let v = if stats.spp >= 2 {
                let mean = p.sum / n;
                ((p.sum2 / n - mean * mean) / (n - 1.0)).max(DVec3::ZERO)
            } else if sampled {
                p.draw_variance
            } else {
                DVec3::INFINITY
            };
            v.as_vec3().to_array()
        })
        .collect();
    stats.seconds = start.elapsed().as_secs_f64();
    stats.shadow_rays_per_second = stats.shadow_rays as f64 / stats.gather_seconds.max(1e-9);
    stats.rays_per_second =
        (stats.shadow_rays + stats.primary_rays) as f64 / stats.seconds.max(1e-9);
    Ok(ManyLightImage {
        width,
        height,
        image,
        variance,
        stats,
    })
}

pub mod light_paths;
#[cfg(test)]
mod tests;
