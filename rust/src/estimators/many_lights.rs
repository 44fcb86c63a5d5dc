//! The many-light maths: every pixel lit by a set of virtual point lights
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
//! - [`Gather::Sampled`]: `M` VPLs per pixel sample drawn from a distribution `p_k ∝ w_k`,
//!   the estimate `(1/M) Σ_m c_{k_m} V_{k_m} / p_{k_m}`. Unbiased for the full sum
//!   wherever `w_k > 0` for every VPL that contributes. [`Sampling`] picks `w`: the same
//!   for every VPL, the VPL's power, or per pixel ([`VplDistribution`]; default
//!   [`Unoccluded`]: the luminance of the contribution without visibility). The first two
//!   do not depend on the pixel: their table is built once per render. The per-pixel hook
//!   is where importance caching (survey §6.2.3) puts its cached distributions.
//!
//! An area light held as one light ([`VplKind::Area`]) is a point VPL for the distributions
//! (its weight is [`Vpl::unoccluded`]: a quadrature over fixed points, positive wherever it
//! can contribute) but not for the estimate: each time it is gathered, [`Gather::Full`] once
//! per pixel sample and [`Gather::Sampled`] once per draw, a fresh point on it is sampled by
//! area ([`Vpl::sample_area`]), so both gathers stay unbiased for the true area light.
//!
//! With `clamp`, the geometry term is `min(G, clamp)`: this removes the bright spots that
//! VPLs near a receiver make (`1/d²`) and is biased (dark corners, the light of short
//! paths lost); without (the default) the sum is unbiased for the set.
//!
//! ## Samples
//! Sample `s` of a pixel shades its own first hit ([`Gatherer`]: the hit
//! [`crate::camera::GBuffer::render`] gives with the seed of sample `s`, jittered:
//! antialiased with a box filter, the same pixel integral the path tracer estimates), so
//! the full sum costs `spp · N` shadow rays per pixel; without `jitter` every sample shades
//! the pixel's centre. A pixel's `variance` ([`VplSums::estimate`]) is the sample variance
//! of the mean over its samples, or with one sample the variance of the `M` draws' mean
//! ([`Gather::Sampled`]) or infinity ([`Gather::Full`]). The passes, the time budget and
//! progress are the render floor's (`render::many_lights`, which calls down here).
//!
//! ## Direct light
//! With `direct` the image holds what the camera sees of emitters and the map, and the
//! light VPLs (generation 0: points on area lights, directions of the map) light the
//! receivers directly; without, only surface VPLs (generations `>= 1`) count: the indirect
//! part that `method="path", direct=False` estimates.
//!
//! ## Determinism
//! A sample's estimate at a pixel is a pure function of `(seed, pixel, sample)` and, for
//! [`Gather::Full`], of the sample's receivers at the other pixels of its tile (tiles are
//! fixed on the image: [`tile_of`]); the VPLs' terms are summed in VPL order in `f64`, and
//! the draws of [`Gather::Sampled`] read `(seed, pixel, sample, dimension)`.

use glam::{DVec3, Vec3};

use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::estimators::indirect::shading_point_at;
use crate::geometry::{RayBatch, Scene, SurfaceHit, TMax, TraversalCounters};
use crate::lights::envmap::EnvMap;
use crate::lights::vpl::{luminance, Vpl, VplKind, VplSet};
use crate::sampling::rng::{mix64, SampleRng};
use light_paths::Receiver as VplReceiver;

/// Most samples per pixel.
pub const MAX_SPP: u32 = 1 << 16;

/// Most VPLs drawn per pixel sample by [`Gather::Sampled`].
pub const MAX_DRAWS: u32 = 1 << 16;

/// Side of a tile in pixels: a tile's rays towards one VPL are one packet.
pub const TILE: u32 = 4;

/// VPLs whose rays go to [`Scene::occluded`] in one batch (16 per VPL per tile: 4096
/// rays, a few of its chunks).
const VPL_BLOCK: usize = 256;

/// How each pixel sample gathers the VPLs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Gather {
    /// Every VPL, one shadow ray each.
    Full,
    /// `draws` VPLs (`1..=MAX_DRAWS`) drawn as `sampling` says.
    Sampled { draws: u32, sampling: Sampling },
}

/// What [`Gather::Sampled`] draws VPLs in proportion to (survey §6.2.3's baselines).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash)]
pub enum Sampling {
    /// Every VPL alike, `p_k = 1/N`: positive wherever a VPL contributes, blind to all
    /// else.
    Uniform,
    /// The luminance of the VPL's flux `Φ_k` (W; for a map VPL the flux through the
    /// scene's disk): the "power" row of survey Fig. 6.8, positive for every VPL that
    /// carries light, blind to where the receiver is.
    Power,
    /// Per pixel, from the [`VplDistribution`] the render is given (default
    /// [`Unoccluded`]): the luminance of each VPL's term without visibility.
    #[default]
    Unoccluded,
}

impl Sampling {
    /// Every value, in the order the errors list them.
    pub const ALL: [Sampling; 3] = [Sampling::Uniform, Sampling::Power, Sampling::Unoccluded];

    /// The name `sampling=` takes.
    pub const fn name(self) -> &'static str {
        match self {
            Sampling::Uniform => "uniform",
            Sampling::Power => "power",
            Sampling::Unoccluded => "unoccluded",
        }
    }

    /// The value called `name`; an error naming `sampling` and listing the names otherwise.
    pub fn parse(name: &str) -> Result<Self> {
        Self::ALL
            .into_iter()
            .find(|s| s.name() == name)
            .ok_or_else(|| {
                let names: Vec<&str> = Self::ALL.iter().map(|s| s.name()).collect();
                Error::invalid(
                    "sampling",
                    format!("expected one of {names:?}, got {name:?}"),
                )
            })
    }

    /// The weight `w_k` of a VPL under a pixel-independent sampling (`None` for
    /// [`Sampling::Unoccluded`]).
    pub fn fixed_weight(self, v: &Vpl) -> Option<f64> {
        match self {
            Sampling::Uniform => Some(1.0),
            Sampling::Power => Some(luminance(v.flux) as f64),
            Sampling::Unoccluded => None,
        }
    }
}

/// Parameters of the many-light renderer (`render::many_lights::render_many_lights`, on
/// the render floor).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ManyLightParams {
    /// Samples per pixel, `1..=MAX_SPP` (each its own first hit); with a time budget, the
    /// most to take.
    pub spp: u32,
    pub seed: u64,
    /// Jittered first hits (antialiased) instead of the pixels' centres.
    pub jitter: bool,
    /// Upper bound of the geometry term `cos cos / d²` (1/m², biased), or none.
    pub clamp: Option<f32>,
    /// Whether the image holds direct light (module docs).
    pub direct: bool,
    pub gather: Gather,
    /// Seconds the render may take (from its start): passes sized by the pass driver's
    /// schedule (a probe, then as many samples as fit, `spp` at most); none: `spp` samples
    /// in every pixel.
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
        if let Gather::Sampled { draws, .. } = self.gather {
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
        scene: &Scene,
        _pixel: usize,
        r: &VplReceiver,
        vpls: &[Vpl],
        disk_area: f32,
        weights: &mut [f64],
    ) {
        for (w, v) in weights.iter_mut().zip(vpls) {
            *w = luminance(v.unoccluded(scene, r, self.clamp, disk_area)) as f64;
        }
    }
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

/// One pixel's sums over its samples, in sample order: the estimates' sum and sum of
/// squares, and the last sample's variance of its draws' mean ([`Gather::Sampled`]; zero
/// for [`Gather::Full`] and where the sample saw no surface).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct VplSums {
    /// Samples added.
    pub n: u32,
    /// Sum of the samples' estimates (radiance, W/(m² sr) per channel).
    pub sum: DVec3,
    /// Sum of their squares.
    pub sum2: DVec3,
    /// The latest sample's variance of its draws' mean.
    pub draw_variance: DVec3,
}

impl VplSums {
    /// Adds sample `n` (the next in sample order): its estimate `x` and its draws' variance
    /// of the mean.
    #[inline]
    pub fn add(&mut self, x: DVec3, draw_variance: DVec3) {
        self.n += 1;
        self.sum += x;
        self.sum2 += x * x;
        self.draw_variance = draw_variance;
    }

    /// The pixel's mean and the variance of that mean (module docs): the sample variance
    /// over `n >= 2` samples, or with one sample its draws' variance (`sampled`) or
    /// infinity; no sample gives mean 0 and infinite variance.
    pub fn estimate(&self, sampled: bool) -> ([f32; 3], [f32; 3]) {
        let n = self.n.max(1) as f64;
        let mean = self.sum / n;
        let var = if self.n >= 2 {
            ((self.sum2 / n - mean * mean) / (n - 1.0)).max(DVec3::ZERO)
        } else if sampled && self.n == 1 {
            self.draw_variance
        } else {
            DVec3::INFINITY
        };
        (mean.as_vec3().to_array(), var.as_vec3().to_array())
    }
}

/// The seed of sample `s`'s first hits.
fn sample_seed(seed: u64, s: u32) -> u64 {
    mix64(seed ^ mix64(0x4d41_4e59_4c49_4748 ^ s as u64))
}

/// Rays and figures of the samples a worker took.
#[derive(Clone, Copy, Debug, Default)]
pub struct GatherWork {
    /// Primary rays traced for the samples' first hits.
    pub primary_rays: u64,
    /// Shadow rays traced (VPL pairs with a zero term take none).
    pub shadow_rays: u64,
    /// The rays' BVH figures.
    pub counters: TraversalCounters,
}

impl std::ops::AddAssign for GatherWork {
    fn add_assign(&mut self, o: Self) {
        self.primary_rays += o.primary_rays;
        self.shadow_rays += o.shadow_rays;
        self.counters += o.counters;
    }
}

/// A worker's reusable buffers ([`Gatherer::full_tile`], [`Gatherer::sampled_pixel`]).
#[derive(Default)]
pub struct Scratch {
    batch: Batch,
    cdf: Vec<f64>,
    shading: Vec<(usize, VplReceiver)>,
    acc: Vec<DVec3>,
    rngs: Vec<SampleRng>,
}

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
    fn flush(&mut self, scene: &Scene, sums: &mut [DVec3], work: &mut GatherWork) -> Result<()> {
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
///
/// An area light ([`VplKind::Area`]) takes one fresh point per receiver
/// ([`Vpl::sample_area`]), read from `rngs[k]` (receiver `k`'s stream, dimensions
/// `3 j ..= 3 j + 2` for the `j`-th area light of `vpls`).
#[allow(clippy::too_many_arguments)]
fn gather_full(
    scene: &Scene,
    points: &[(usize, VplReceiver)],
    rngs: &[SampleRng],
    vpls: &[Vpl],
    disk_area: f32,
    clamp: Option<f32>,
    out: &mut [DVec3],
    batch: &mut Batch,
    work: &mut GatherWork,
) -> Result<()> {
    // Point VPLs: rays from the VPL to each receiver of the tile (one origin per run).
    let lanes = Lanes::new(points);
    for block in vpls.chunks(VPL_BLOCK) {
        let point = |v: &&Vpl| !(v.kind == VplKind::Env || v.kind.is_area());
        for v in block.iter().filter(point) {
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
    // Area lights: rays from each receiver to a fresh point on each light.
    let areas: Vec<&Vpl> = vpls.iter().filter(|v| v.kind.is_area()).collect();
    for (k, (_, r)) in points.iter().enumerate() {
        for (b, block) in areas.chunks(VPL_BLOCK * 16).enumerate() {
            for (i, v) in block.iter().enumerate() {
                let d = 3 * (b * VPL_BLOCK * 16 + i) as u64;
                let u = [rngs[k].get(d), rngs[k].get(d + 1), rngs[k].get(d + 2)];
                if let Some(c) = v.sample_area(scene, r, clamp, u) {
                    batch.push(c, k);
                }
            }
            batch.flush(scene, out, work)?;
        }
    }
    Ok(())
}

/// The stream of the points sampled on area lights by sample `s` of `pixel` (apart from
/// the draws' stream of [`gather_sampled`]).
pub fn area_rng(seed: u64, pixel: usize, s: u32) -> SampleRng {
    SampleRng::new(mix64(seed ^ 0x4152_4541_4c49_4748), pixel as u64, s as u64)
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
    distribution: Distribution<'_>,
    cdf: &mut Vec<f64>,
    work: &mut GatherWork,
) -> (DVec3, DVec3) {
    let cdf: &[f64] = match distribution {
        Distribution::Fixed(fixed) => fixed,
        Distribution::PerPixel(d) => {
            cdf.resize(vpls.len(), 0.0);
            d.weights(scene, pixel, r, vpls, disk_area, cdf);
            to_cdf(cdf);
            cdf
        }
    };
    let total = cdf.last().copied().unwrap_or(0.0);
    if !(total > 0.0 && total.is_finite()) {
        return (DVec3::ZERO, DVec3::ZERO);
    }
    let rng = SampleRng::new(params.seed, pixel as u64, sample as u64);
    let points = area_rng(params.seed, pixel, sample);
    let (mut sum, mut sum2) = (DVec3::ZERO, DVec3::ZERO);
    for m in 0..draws as u64 {
        let u = rng.get(m) as f64 * total;
        let k = cdf.partition_point(|&c| c <= u).min(vpls.len() - 1);
        let p = (cdf[k] - if k == 0 { 0.0 } else { cdf[k - 1] }) / total;
        let v = &vpls[k];
        let connection = if v.kind.is_area() {
            // A fresh point on the light for each draw.
            let u = [
                points.get(3 * m),
                points.get(3 * m + 1),
                points.get(3 * m + 2),
            ];
            v.sample_area(scene, r, params.clamp, u)
        } else {
            v.connect(r, params.clamp, disk_area)
        };
        let x = match connection {
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

/// Turns weights into their running sum in place (non-finite or negative weights count
/// as zero, so the sum is finite unless the weights overflow `f64`).
fn to_cdf(weights: &mut [f64]) {
    let mut total = 0.0f64;
    for w in weights.iter_mut() {
        total += if w.is_finite() && *w > 0.0 { *w } else { 0.0 };
        *w = total;
    }
}

/// Where [`gather_sampled`] reads its running sums of weights.
#[derive(Clone, Copy)]
enum Distribution<'a> {
    /// One table for every pixel ([`Sampling::Uniform`], [`Sampling::Power`]).
    Fixed(&'a [f64]),
    /// Each pixel's own weights.
    PerPixel(&'a dyn VplDistribution),
}

/// What a render's samples read: the scene, what misses see, the camera, the parameters,
/// the VPLs the gather uses and the distribution [`Gather::Sampled`] draws them from.
/// Every sample is a pure function of `(seed, pixel, sample)` and, for [`Gather::Full`],
/// of the sample's receivers at the other pixels of its [`TILE`] x [`TILE`] tile.
pub struct Gatherer<'a> {
    scene: &'a Scene,
    env: &'a EnvMap,
    camera: &'a Camera,
    params: ManyLightParams,
    used: Vec<Vpl>,
    disk_area: f32,
    distribution: &'a dyn VplDistribution,
    /// The running sums of [`Sampling::fixed_weight`] over `used`, for a pixel-independent
    /// [`Gather::Sampled`]; empty otherwise.
    fixed: Vec<f64>,
}

impl<'a> Gatherer<'a> {
    /// The gather of `camera`'s view of `scene` lit by `vpls` (the surface VPLs only,
    /// without `params.direct`); `env` is what misses see; `distribution` serves
    /// [`Sampling::Unoccluded`]. Checks nothing: the caller validates `params` and the
    /// set's geometry.
    pub fn new(
        scene: &'a Scene,
        env: &'a EnvMap,
        camera: &'a Camera,
        vpls: &VplSet,
        params: &ManyLightParams,
        distribution: &'a dyn VplDistribution,
    ) -> Self {
        let used: Vec<Vpl> = vpls
            .vpls
            .iter()
            .filter(|v| params.direct || v.bounce >= 1)
            .copied()
            .collect();
        let mut fixed = Vec::new();
        if let Gather::Sampled { sampling, .. } = params.gather {
            if sampling != Sampling::Unoccluded {
                fixed = used
                    .iter()
                    .map(|v| sampling.fixed_weight(v).unwrap_or(0.0))
                    .collect();
                to_cdf(&mut fixed);
            }
        }
        Self {
            scene,
            env,
            camera,
            params: *params,
            used,
            disk_area: vpls.disk_area,
            distribution,
            fixed,
        }
    }

    /// The VPLs the gather uses.
    pub fn used(&self) -> &[Vpl] {
        &self.used
    }

    /// Sample `s` of `pixel` before any gather: the radiance it sees directly (the map or
    /// what the surface emits, zero without `direct`) and, where it sees a surface, the
    /// receiver to gather at. For gathers of other estimators (the importance cache).
    pub fn first_hit(
        &self,
        pixel: usize,
        s: u32,
        work: &mut GatherWork,
    ) -> (DVec3, Option<VplReceiver>) {
        match self.receiver(pixel, s, work) {
            Receiver::Background(l) => (l.as_dvec3(), None),
            Receiver::Surface { emitted, r } => (emitted.as_dvec3(), Some(r)),
        }
    }

    /// The receiver of sample `s` of `pixel` (row-major): the first hit of the pixel's
    /// primary ray with the seed of sample `s` (jittered or through the centre), exactly
    /// as [`crate::camera::GBuffer::render`] and [`crate::camera::GBuffer::surface_hit`]
    /// give it.
    fn receiver(&self, pixel: usize, s: u32, work: &mut GatherWork) -> Receiver {
        let (scene, params) = (self.scene, &self.params);
        let seed = sample_seed(params.seed, s);
        let (origin, dir) = self.camera.primary_ray(pixel, seed, params.jitter);
        work.primary_rays += 1;
        let Some(h) = scene.intersect1(origin, dir, f32::INFINITY, &mut work.counters) else {
            let l = if params.direct {
                self.env.eval(dir)
            } else {
                Vec3::ZERO
            };
            return Receiver::Background(l);
        };
        // The G-buffer's hit: the normal facing the camera, no barycentrics.
        let normal = if h.normal.dot(dir) > 0.0 {
            -h.normal
        } else {
            h.normal
        };
        let hit = SurfaceHit {
            u: 0.0,
            v: 0.0,
            normal,
            ..h
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
    }

    /// Sample `s` of [`Gather::Full`] at the pixels `tile` (row-major indices, the pixels
    /// of one [`TILE`] x [`TILE`] tile of the image in row order, clipped to the image):
    /// each pixel's estimate, in `tile`'s order, into `out` (cleared first). The tile's
    /// shadow rays towards a VPL are traced together, as packets.
    pub fn full_tile(
        &self,
        tile: &[usize],
        s: u32,
        scratch: &mut Scratch,
        work: &mut GatherWork,
        out: &mut Vec<DVec3>,
    ) -> Result<()> {
        out.clear();
        scratch.shading.clear();
        for &pixel in tile {
            match self.receiver(pixel, s, work) {
                Receiver::Background(l) => out.push(l.as_dvec3()),
                Receiver::Surface { emitted, r } => {
                    out.push(emitted.as_dvec3());
                    scratch.shading.push((out.len() - 1, r));
                }
            }
        }
        scratch.acc.clear();
        scratch.acc.resize(scratch.shading.len(), DVec3::ZERO);
        scratch.rngs.clear();
        scratch.rngs.extend(
            scratch
                .shading
                .iter()
                .map(|(slot, _)| area_rng(self.params.seed, tile[*slot], s)),
        );
        gather_full(
            self.scene,
            &scratch.shading,
            &scratch.rngs,
            &self.used,
            self.disk_area,
            self.params.clamp,
            &mut scratch.acc,
            &mut scratch.batch,
            work,
        )?;
        for ((slot, _), a) in scratch.shading.iter().zip(&scratch.acc) {
            out[*slot] += *a;
        }
        Ok(())
    }

    /// Sample `s` of `pixel` by [`Gather::Sampled`] with `draws` VPLs: its estimate and
    /// its draws' variance of the mean (zero where the sample sees no surface).
    pub fn sampled_pixel(
        &self,
        pixel: usize,
        s: u32,
        draws: u32,
        scratch: &mut Scratch,
        work: &mut GatherWork,
    ) -> (DVec3, DVec3) {
        match self.receiver(pixel, s, work) {
            Receiver::Background(l) => (l.as_dvec3(), DVec3::ZERO),
            Receiver::Surface { emitted, r } => {
                let (mean, var) = gather_sampled(
                    self.scene,
                    pixel,
                    &r,
                    &self.used,
                    self.disk_area,
                    &self.params,
                    draws,
                    s,
                    match self.params.gather {
                        Gather::Sampled {
                            sampling: Sampling::Unoccluded,
                            ..
                        }
                        | Gather::Full => Distribution::PerPixel(self.distribution),
                        Gather::Sampled { .. } => Distribution::Fixed(&self.fixed),
                    },
                    &mut scratch.cdf,
                    work,
                );
                (emitted.as_dvec3() + mean, var)
            }
        }
    }
}

/// The pixels of the [`TILE`] x [`TILE`] tile of a `width x height` image that holds
/// `pixel` (row-major), in row order, into `out` (cleared first).
pub fn tile_of(pixel: usize, width: u32, height: u32, out: &mut Vec<usize>) {
    let (w, t) = (width as usize, TILE as usize);
    let (x0, y0) = (pixel % w / t * t, pixel / w / t * t);
    out.clear();
    for y in y0..(y0 + t).min(height as usize) {
        out.extend((x0..(x0 + t).min(w)).map(|x| y * w + x));
    }
}

pub mod light_paths;
#[cfg(test)]
mod tests;
