//! Light paths that deposit virtual point lights (VPLs): instant radiosity (Keller 1997; survey
//! `004_d2289ee9e28a0f98.txt` §6.2.1) with the importance-driven acceptance of Georgiev &
//! Slusallek (survey §6.2.2, Algorithm 11).
//!
//! ## Light paths
//! A path starts at a light chosen in proportion to the luminance of its power:
//! - an area light: a point `y` uniform by area, a direction cosine-weighted about its
//!   normal, so the photon carries `Φ = π L_e A` (the light's power);
//! - the environment map: a direction `ω` (towards the light) drawn by the map's own
//!   distribution `p(ω)`, a start point uniform on the disk of radius `R` perpendicular to
//!   `ω` that covers the scene's bounding sphere, travelling along `-ω`: `Φ = L(ω) π R² /
//!   p(ω)`. Its expectation over `ω` and the disk is the power crossing the disk, and the
//!   part that hits the scene is the power the map sends into it.
//!
//! Each path's flux is divided by the probability of its light and by the number of paths
//! `P`, so summing any per-VPL quantity over the set estimates it for the lights' power
//! without bias. The path's start is a *light VPL* (`bounce = 0`): an oriented point light of
//! intensity `Φ cos θ / π` on an area light, or a directional light of irradiance `Φ / (π
//! R²)` for the map. They are what lets one many-light renderer do direct light too.
//! At each hit (every material here is non-specular: Lambert and normalised Phong) a
//! *surface VPL* of generation `bounce = j` is deposited with the incident flux, the
//! surface's material, its normal turned towards the incoming photon and the direction the
//! photon came from; the walk continues by BSDF sampling (throughput `f cos / p`) until
//! `depth` VPLs are deposited, with Russian roulette from the second continuation on (the
//! path survives with `q = min(1, max_c f cos / p)`, its flux divided by `q`).
//!
//! Summed over VPLs of generation `j`, eq. 6.1's contribution at a receiver estimates light
//! that bounced `j` times before reaching it (so generations `1..=k` are what the path
//! tracer's `bounces=k, direct=False` computes), and generation 0 its direct light.
//!
//! ## Importance-driven acceptance (survey Algorithm 11)
//! Optional ([`Importance`]). First `pilot_paths` paths are traced from another random
//! stream without acceptance; `Φ_v` is the mean over their surface VPLs of `Φ_i`, the
//! luminance of a VPL's contribution (shadow rays included) averaged over the first hits of
//! a small image of the camera ("the image plane as one big pixel"). Then every surface VPL
//! of the real paths is accepted with `p_i = min(Φ_i / Φ_v + ε, 1)`: its flux (and the
//! path's, for later VPLs) is divided by `p_i`, and a rejection ends the path (this VPL and
//! its descendants are dropped). The expectation of every VPL's flux is unchanged, while VPLs
//! the camera cannot see (the outside of a building lit by the sun) are mostly dropped.
//!
//! Two additions beyond Algorithm 11, both unbiased: light VPLs are accepted the same way
//! against the pilot's mean light VPL, but a rejected one does not end its path (it is
//! direct light alone, and the photon's flux does not depend on it); and the lights are
//! picked with probability `(p_k + v_k / Σ v) / 2`, half by power `p_k`, half by `v_k`, the
//! pilot's total `Φ` of the VPLs of light `k` (fluxes divided by the new probability).
//! Cornell's closed room under a white map is why: by power nine paths in ten start at the
//! map and end on the outside of the box.
//!
//! ## How many paths
//! `count` is the number of VPLs wanted. The pilot paths' mean number of VPLs per path
//! (with the acceptance replayed on them when it is on) fixes the number of paths
//! `P = ceil(count / mean)`, independently of the real paths, so the normalisation `1/P` is
//! a constant for them and the set stays unbiased; `len()` is then about `count` (within
//! the pilot's noise: a few per cent with 4000 pilot paths).
//!
//! ## Other lights of the same set
//! Beside traced sets, [`VplSet`] holds lights made directly (survey §6.3.3 and Fig. 6.5's
//! two forms, the point light on a surface and the directional light):
//! [`VplSet::from_lights`] (cosine point lights), [`VplSet::from_envmap`] (the map as one
//! directional light per texel of a coarse octahedral level), [`VplSet::from_directions`]
//! (a sun) and [`VplSet::from_area_lights`] (each area light as one light: its value at a
//! receiver from `K` fixed stratified points, [`Vpl::unoccluded`]; its shadow rays from a
//! fresh point by area, [`Vpl::sample_area`]). [`VplSet::concat`] joins sets and
//! [`VplSet::view_share`] counts the lights that reach a view.
//!
//! ## Determinism
//! Path `i` reads only `(seed, i, dimension)` of the counter-based generator, paths are
//! traced in fixed chunks and concatenated in path order: the set is bit-identical for any
//! thread count.

use glam::{DVec3, Vec2, Vec3};
use rayon::prelude::*;

use crate::bsdf::Material;
use crate::camera::{Camera, GBuffer};
use crate::error::{Error, Result};
use crate::estimators::direct::ShadingPoint;
use crate::geometry::{Scene, TraversalCounters};
use crate::lights::envmap::EnvMap;
use crate::lights::vpl::{
    area_points, checked_row, luminance, Importance, TraceParams, TraceStats, Vpl, VplKind, VplSet,
    MAX_AREA_POINTS, MAX_VPLS,
};
use crate::lights::AreaLight;
use crate::math::{triangle_cross, LUMINANCE_F32};
use crate::parallel::with_threads;
use crate::sampling::rng::{mix64, SampleRng};
use crate::stop::Stop;

#[cfg(test)]
mod tests;

/// Paths traced per parallel work item (fixed: the set never depends on the thread count).
const PATH_CHUNK: usize = 1024;

/// Least survival probability of Russian roulette (so no flux grows more than 20x a step).
const MIN_SURVIVAL: f32 = 0.05;

/// The white Lambert "BSDF" of an area light's emission: `f = 1/π`, so `Φ f cos` is the
/// radiant intensity `Φ cos θ / π` of a Lambertian emitter of power `Φ`.
const EMITTER: Material = Material::Lambert { albedo: [1.0; 3] };

/// Random-number dimensions of one light path (stream `(seed, path, 0)`).
mod dims {
    /// Which light.
    pub const LIGHT: u64 = 0;
    /// Area light: the triangle.
    pub const TRIANGLE: u64 = 1;
    /// Area light: the point on it; map: the direction (two dimensions).
    pub const POINT: u64 = 2;
    /// Area light: the emitted direction; map: the point on the disk (two dimensions).
    pub const EMISSION: u64 = 4;
    /// The light VPL's acceptance.
    pub const ACCEPT_LIGHT: u64 = 6;
    /// Bounce `j` (1-based) reads from `BOUNCE + 8 (j - 1)`: lobe, roulette, direction
    /// (two), acceptance.
    pub const BOUNCE: u64 = 8;
    pub const LOBE: u64 = 0;
    pub const ROULETTE: u64 = 1;
    pub const DIRECTION: u64 = 2;
    pub const ACCEPT: u64 = 4;
}

/// One VPL's contribution at a receiver before visibility, and the shadow ray that decides
/// it: from `origin` along unit `direction` up to `tmax`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Connection {
    /// `f_x · f_v · Φ · G` (eq. 6.1 without `V`), W/(m² sr) per channel.
    pub value: Vec3,
    pub origin: Vec3,
    pub direction: Vec3,
    pub tmax: f32,
}

/// A receiver of VPL light: a shading point with what every VPL's term reads of it
/// computed once.
#[derive(Clone, Copy, Debug)]
pub struct Receiver {
    pub sp: ShadingPoint,
    /// `f_x` when it does not depend on directions (Lambert: `ρ / π`).
    diffuse: Option<Vec3>,
    /// How far short of `sp.origin` shadow rays stop: twice the scene's epsilon there.
    shorten: f32,
}

impl Receiver {
    /// The receiver at `sp` in `scene`.
    pub fn new(scene: &Scene, sp: ShadingPoint) -> Self {
        let diffuse = match sp.material {
            Material::Lambert { albedo } => Some(Vec3::from(albedo) * std::f32::consts::FRAC_1_PI),
            _ => None,
        };
        Self {
            sp,
            diffuse,
            shorten: 2.0 * scene.ray_epsilon(sp.origin),
        }
    }

    /// `f_x`, when it does not depend on directions (Lambert: `ρ / π`).
    pub fn diffuse(&self) -> Option<Vec3> {
        self.diffuse
    }

    /// How far short of `sp.origin` shadow rays stop (world units).
    pub fn shorten(&self) -> f32 {
        self.shorten
    }

    /// `f_x(ωo, w)` for `w` above the surface.
    #[inline(always)]
    fn f(&self, w: Vec3) -> Vec3 {
        match self.diffuse {
            Some(f) => f,
            None => self.sp.material.eval(self.sp.normal, self.sp.wo, w),
        }
    }
}

impl Vpl {
    /// Eq. 6.1's term of this VPL at receiver `r` without visibility: `f_x(ωo, ω) ·
    /// f_v(ω_in, -ω) · Φ · cos θ_x cos θ_v / d²` for a point VPL, `f_x · cos θ_x · Φ /
    /// disk_area` for a map direction. With `clamp`, the geometry term `cos cos / d²` is
    /// replaced by `min(G, clamp)` (biased: it removes the spikes of VPLs close to the
    /// receiver, and the light they carry). `None` when the term is zero (either side
    /// faces away, a black BSDF) so no ray is needed. The shadow ray runs from the VPL
    /// to the receiver (rays towards one VPL then share their origin: packets) and stops
    /// short of the receiver's origin by twice the scene's epsilon there.
    ///
    /// A [`VplKind::Area`] light has no single point: `None` here; its term without
    /// visibility is [`Vpl::unoccluded`] and its shadow rays come from [`Vpl::sample_area`].
    #[inline(always)]
    pub fn connect(&self, r: &Receiver, clamp: Option<f32>, disk_area: f32) -> Option<Connection> {
        let sp = &r.sp;
        if self.kind.is_area() {
            return None;
        }
        if self.kind == VplKind::Env {
            let w = self.normal;
            let cos = sp.normal.dot(w);
            if cos <= 0.0 {
                return None;
            }
            let value = r.f(w) * self.flux * (cos / disk_area);
            if value == Vec3::ZERO {
                return None;
            }
            return Some(Connection {
                value,
                origin: sp.origin,
                direction: w,
                tmax: f32::INFINITY,
            });
        }
        let d = self.origin - sp.origin;
        // The sides first, on the unnormalised offset: most pairs that fail do so here,
        // before the square root.
        let (side_x, side_v) = (sp.normal.dot(d), -self.normal.dot(d));
        if !(side_x > 0.0 && side_v > 0.0) {
            return None;
        }
        let dist2 = d.length_squared();
        let dist = dist2.sqrt();
        let inv = 1.0 / dist;
        let w = d * inv; // receiver -> VPL
        let (cos_x, cos_v) = (side_x * inv, side_v * inv);
        let f_v = match (self.kind, self.material) {
            (VplKind::Surface, Material::Lambert { albedo }) => {
                Vec3::from(albedo) * std::f32::consts::FRAC_1_PI
            }
            (VplKind::Surface, m) => m.eval(self.normal, self.incident, -w),
            _ => Vec3::splat(std::f32::consts::FRAC_1_PI),
        };
        let mut g = cos_x * cos_v / dist2;
        if let Some(c) = clamp {
            g = g.min(c);
        }
        let value = r.f(w) * f_v * self.flux * g;
        if value == Vec3::ZERO {
            return None;
        }
        let tmax = dist - r.shorten;
        if tmax <= 0.0 {
            return None;
        }
        Some(Connection {
            value,
            origin: self.origin,
            direction: -w,
            tmax,
        })
    }
}

impl Vpl {
    /// Eq. 6.1's term at `r` without visibility (W/(m² sr) per channel), for any kind: what
    /// distributions over the set read (survey §6.3.2's `U = L f_s G`). For a point or
    /// directional light it is [`Vpl::connect`]'s value (zero where that is `None`); for a
    /// [`VplKind::Area`] light, the quadrature over its `K` fixed points ([`area_points`]):
    /// `Σ_i f_x(ω_i) L(y_i) (A / K) cos θ_x cos θ_i / d_i²` (each `G` bounded by `clamp`).
    /// Where that sum is zero but part of the light is in front of `r` and `r` in front of
    /// it, the value is a floor `1e-3 L̄ f_x min(1, A / d²)` (`d` to the centroid), so a
    /// pdf in proportion to it is positive wherever the light can contribute and a gather
    /// that samples it stays unbiased.
    pub fn unoccluded(
        &self,
        scene: &Scene,
        r: &Receiver,
        clamp: Option<f32>,
        disk_area: f32,
    ) -> Vec3 {
        let VplKind::Area { points } = self.kind else {
            return self
                .connect(r, clamp, disk_area)
                .map_or(Vec3::ZERO, |c| c.value);
        };
        let Some(light) = area_light_of(scene, self) else {
            return Vec3::ZERO;
        };
        let sp = &r.sp;
        let bound = clamp.unwrap_or(f32::INFINITY);
        let mut sum = Vec3::ZERO;
        area_points(light, points, |q| {
            let d = q.position - sp.origin;
            let (side_x, side_y) = (sp.normal.dot(d), -q.normal.dot(d));
            if !(side_x > 0.0 && side_y > 0.0) {
                return;
            }
            let dist2 = d.length_squared();
            let w = d / dist2.sqrt();
            let g = (side_x * side_y / (dist2 * dist2)).min(bound);
            sum += r.f(w) * q.value * g;
        });
        if sum != Vec3::ZERO || !area_reaches(light, sp.origin, sp.normal) {
            return sum;
        }
        let d = self.position - sp.origin;
        let w = d.normalize_or(sp.normal);
        let w = if sp.normal.dot(w) > 0.0 { w } else { sp.normal };
        let area = light.area() as f32;
        let reach = (area / d.length_squared().max(f32::MIN_POSITIVE)).min(1.0);
        r.f(w) * light.radiance() * (1e-3 * reach)
    }

    /// One sample of a [`VplKind::Area`] light at `r` from `u` in `[0, 1)³`: a point `y`
    /// by area (`AreaLight::sample`'s triangle pick and warp, density `1 / A`) and its term
    /// over that density, `f_x(ω) L(y) cos θ_x cos θ_y / d² · A` (`G` bounded by `clamp`),
    /// with the shadow ray from `r` towards `y`, stopping short of it. Its expectation over `u`
    /// is the light's exact direct term (clamped by `clamp` if given). `None` when the
    /// term is zero (the point faces away, `r` is behind it) or the kind is not `Area`.
    pub fn sample_area(
        &self,
        scene: &Scene,
        r: &Receiver,
        clamp: Option<f32>,
        u: [f32; 3],
    ) -> Option<Connection> {
        if !self.kind.is_area() {
            return None;
        }
        let light = area_light_of(scene, self)?;
        let sp = &r.sp;
        let s = light.sample(sp.origin, u[0], Vec2::new(u[1], u[2]))?;
        // `s.pdf = d² / (A cos θ_y)` (solid angle), so `cos θ_y / d² = 1 / (A pdf)`.
        let cos_x = sp.normal.dot(s.direction);
        if cos_x.is_nan() || cos_x <= 0.0 {
            return None;
        }
        let mut g = (cos_x as f64 / (light.area() * s.pdf)) as f32;
        if let Some(c) = clamp {
            g = g.min(c);
        }
        let value = r.f(s.direction) * s.radiance * (g * light.area() as f32);
        if !(value.is_finite() && value != Vec3::ZERO) {
            return None;
        }
        // From the receiver to the point, stopping short of the light's own triangle (as
        // the direct estimators' shadow rays to area lights).
        let tmax = scene.segment_end(s.distance, s.point);
        if tmax.is_nan() || tmax <= 0.0 {
            return None;
        }
        Some(Connection {
            value,
            origin: sp.origin,
            direction: s.direction,
            tmax,
        })
    }
}

/// The scene's area light a [`VplKind::Area`] VPL stands for.
fn area_light_of<'s>(scene: &'s Scene, v: &Vpl) -> Option<&'s AreaLight> {
    (v.light as usize)
        .checked_sub(1)
        .and_then(|k| scene.area_lights().get(k))
}

/// Whether some part of `light` is strictly above the plane of `(p, n)` while `p` is
/// strictly in front of that part's triangle: the light can reach `p` (without
/// visibility). Exact for every triangle, so never false where the light contributes.
fn area_reaches(light: &AreaLight, p: Vec3, n: Vec3) -> bool {
    light.triangles().iter().enumerate().any(|(t, tri)| {
        let m = light.normal(t);
        m != Vec3::ZERO && m.dot(p - tri[0]) > 0.0 && tri.iter().any(|v| n.dot(*v - p) > 0.0)
    })
}

/// The lights of a scene, to start paths from.
struct Sources<'a> {
    scene: &'a Scene,
    env: &'a EnvMap,
    /// Centre and radius of the disk that covers the scene's bounding sphere.
    centre: Vec3,
    radius: f32,
    /// Cumulative probabilities of the map (index 0) and each area light (1..).
    cumulative: Vec<f64>,
    /// Per area light: cumulative triangle areas.
    areas: Vec<Vec<f64>>,
}

impl<'a> Sources<'a> {
    fn new(scene: &'a Scene, env: &'a EnvMap) -> Result<Self> {
        if scene.bounds().is_empty() {
            return Err(Error::invalid(
                "scene",
                "has no triangles to deposit VPLs on",
            ));
        }
        let (centre, radius) = bounding_disk(scene);
        let disk = std::f64::consts::PI * (radius as f64).powi(2);
        let lum = |p: DVec3| {
            p.x * LUMINANCE_F32[0] as f64
                + p.y * LUMINANCE_F32[1] as f64
                + p.z * LUMINANCE_F32[2] as f64
        };
        let mut weights = vec![lum(DVec3::from_array(env.total_power())) * disk];
        let mut areas = Vec::new();
        for light in scene.area_lights() {
            weights.push(lum(DVec3::from_array(light.power())));
            let mut acc = 0.0;
            areas.push(
                light
                    .triangles()
                    .iter()
                    .map(|t| {
                        acc += 0.5 * triangle_cross(t).as_dvec3().length();
                        acc
                    })
                    .collect(),
            );
        }
        let total: f64 = weights.iter().sum();
        if !(total > 0.0 && total.is_finite()) {
            return Err(Error::invalid(
                "setup",
                "has no light: the environment map is black and there are no area lights \
                 with positive radiance",
            ));
        }
        let mut acc = 0.0;
        let cumulative = weights
            .iter()
            .map(|w| {
                acc += w / total;
                acc
            })
            .collect();
        Ok(Self {
            scene,
            env,
            centre,
            radius,
            cumulative,
            areas,
        })
    }

    fn disk_area(&self) -> f32 {
        std::f32::consts::PI * self.radius * self.radius
    }

    /// Probability of light `k`.
    fn probability(&self, k: usize) -> f64 {
        self.cumulative[k] - if k == 0 { 0.0 } else { self.cumulative[k - 1] }
    }

    /// These lights picked with probability `(p_k + v_k / Σ v) / 2` instead of `p_k` (by
    /// power): half by power, so every light keeps its share, half by `view[k] >= 0`, each
    /// light's contribution to the view. Unchanged when no light contributes.
    fn reweighted(&self, view: &[f64]) -> Sources<'a> {
        let total: f64 = view.iter().sum();
        let mut cumulative = self.cumulative.clone();
        if total > 0.0 && total.is_finite() {
            let mut acc = 0.0;
            for (k, c) in cumulative.iter_mut().enumerate() {
                acc += 0.5 * (self.probability(k) + view[k] / total);
                *c = acc;
            }
        }
        Sources {
            scene: self.scene,
            env: self.env,
            centre: self.centre,
            radius: self.radius,
            cumulative,
            areas: self.areas.clone(),
        }
    }

    /// The light of `u` and its probability.
    fn pick(&self, u: f32) -> (usize, f64) {
        let u = u as f64;
        let k = self
            .cumulative
            .partition_point(|&c| c <= u)
            .min(self.cumulative.len() - 1);
        let lo = if k == 0 { 0.0 } else { self.cumulative[k - 1] };
        // A light of zero probability is never picked: step past it.
        let mut k = k;
        let mut lo = lo;
        while self.cumulative[k] - lo <= 0.0 && k + 1 < self.cumulative.len() {
            lo = self.cumulative[k];
            k += 1;
        }
        (k, self.cumulative[k] - lo)
    }
}

/// Centre and radius of the disk perpendicular to any direction that covers the scene's
/// bounding sphere: a hair larger than the sphere, so no surface touches the disk.
fn bounding_disk(scene: &Scene) -> (Vec3, f32) {
    let b = scene.bounds();
    if b.is_empty() {
        return (Vec3::ZERO, 1.0);
    }
    let centre = 0.5 * (b.min + b.max);
    let radius = 0.5 * (b.max - b.min).length() * 1.001 + scene.ray_epsilon(centre);
    (centre, radius)
}

/// A unit vector's orthonormal frame.
fn frame(n: Vec3) -> (Vec3, Vec3) {
    n.any_orthonormal_pair()
}

/// A point of the unit disk, uniform by area (Shirley-Chiu's concentric map is not needed:
/// the points are not stratified).
fn disk_point(u: [f32; 2]) -> Vec2 {
    let r = u[0].sqrt();
    let phi = std::f32::consts::TAU * u[1];
    Vec2::new(r * phi.cos(), r * phi.sin())
}

/// Stores a path's light VPL when the acceptance keeps it, its flux divided by the
/// probability. Unlike a surface VPL's, a rejection does not end the path: the light VPL
/// is direct light alone, and the photon's flux does not depend on it.
#[allow(clippy::too_many_arguments)]
fn keep_light(
    store: bool,
    mut vpl: Vpl,
    rng: &SampleRng,
    accept: &dyn Fn(&Vpl, &mut TraversalCounters, &mut u64) -> f32,
    out: &mut Vec<Vpl>,
    counters: &mut TraversalCounters,
    shadow_rays: &mut u64,
    rejected: &mut u64,
) {
    if !store {
        return;
    }
    let p = accept(&vpl, counters, shadow_rays);
    if p < 1.0 {
        if rng.get(dims::ACCEPT_LIGHT) >= p {
            *rejected += 1;
            return;
        }
        vpl.flux /= p;
    }
    out.push(vpl);
}

/// The VPLs of one light path, in order, appended to `out`, with the acceptance `accept`
/// (`None`: every VPL), which returns `Φ_i`-based probabilities. `flux_scale` is
/// `1 / P`; `lights`: whether to keep the light VPL. Counts the rays in `rays` and
/// rejections in `rejected`.
#[allow(clippy::too_many_arguments)]
fn trace_path(
    src: &Sources,
    path: u64,
    seed: u64,
    depth: u32,
    lights: bool,
    flux_scale: f64,
    accept: &dyn Fn(&Vpl, &mut TraversalCounters, &mut u64) -> f32,
    out: &mut Vec<Vpl>,
    counters: &mut TraversalCounters,
    rays: &mut u64,
    shadow_rays: &mut u64,
    rejected: &mut u64,
) {
    let scene = src.scene;
    let rng = SampleRng::new(seed, path, 0);
    let (light, prob) = src.pick(rng.get(dims::LIGHT));
    let scale = flux_scale / prob;
    // The photon: start, direction of travel, flux.
    let (start, dir, mut flux) = if light == 0 {
        let u = rng.get2(dims::POINT);
        let Some((w, pdf)) = src.env.sample(glam::DVec2::new(u[0] as f64, u[1] as f64)) else {
            return;
        };
        let l = src.env.eval(w);
        let flux = (l.as_dvec3() * (src.disk_area() as f64 / pdf * scale)).as_vec3();
        keep_light(
            lights,
            Vpl {
                position: Vec3::ZERO,
                origin: Vec3::ZERO,
                normal: w,
                incident: Vec3::ZERO,
                material: EMITTER,
                flux,
                kind: VplKind::Env,
                bounce: 0,
                light: 0,
            },
            &rng,
            accept,
            out,
            counters,
            shadow_rays,
            rejected,
        );
        let (t, b) = frame(w);
        let p = disk_point(rng.get2(dims::EMISSION)) * src.radius;
        let start = src.centre + w * src.radius + t * p.x + b * p.y;
        (start, -w, flux)
    } else {
        let area_light = &src.scene.area_lights()[light - 1];
        let cumulative = &src.areas[light - 1];
        let total = *cumulative.last().expect("lights have triangles");
        let target = rng.get(dims::TRIANGLE) as f64 * total;
        let index = cumulative
            .partition_point(|&c| c <= target)
            .min(cumulative.len() - 1);
        let [a, b, c] = area_light.triangles()[index];
        let u = rng.get2(dims::POINT);
        let su = u[0].sqrt();
        let (b0, b1) = (1.0 - su, u[1] * su);
        let y = a * b0 + b * b1 + c * (1.0 - b0 - b1);
        let n = area_light.normal(index);
        // The point's share of the light's power (its texel, for a textured light).
        let power = area_light.radiance_at(y).as_dvec3() * std::f64::consts::PI * area_light.area();
        let flux = (power * scale).as_vec3();
        let origin = scene.offset_point(y, n);
        keep_light(
            lights,
            Vpl {
                position: y,
                origin,
                normal: n,
                incident: Vec3::ZERO,
                material: EMITTER,
                flux,
                kind: VplKind::Emitter,
                bounce: 0,
                light: light as u32,
            },
            &rng,
            accept,
            out,
            counters,
            shadow_rays,
            rejected,
        );
        let Some(w) = EMITTER.sample(n, n, 0.0, Vec2::from_array(rng.get2(dims::EMISSION))) else {
            return;
        };
        (origin, w, flux)
    };
    let (mut origin, mut dir) = (start, dir);
    for bounce in 1..=depth {
        let base = dims::BOUNCE + 8 * (bounce as u64 - 1);
        *rays += 1;
        let Some(hit) = scene.intersect1(origin, dir, f32::INFINITY, counters) else {
            return;
        };
        let wi = -dir;
        let normal = if hit.normal.dot(wi) < 0.0 {
            -hit.normal
        } else {
            hit.normal
        };
        let material = scene.mesh().objects[hit.obj as usize].material;
        let mut vpl = Vpl {
            position: hit.position,
            origin: scene.offset_hit(&hit, normal),
            normal,
            incident: wi,
            material,
            flux,
            kind: VplKind::Surface,
            bounce,
            light: light as u32,
        };
        let p = accept(&vpl, counters, shadow_rays);
        if p < 1.0 {
            if rng.get(base + dims::ACCEPT) >= p {
                *rejected += 1;
                return;
            }
            flux /= p;
            vpl.flux = flux;
        }
        out.push(vpl);
        if bounce == depth {
            return;
        }
        // Continue by BSDF sampling from the hit, `wo` towards where the photon came from.
        let u = Vec2::from_array(rng.get2(base + dims::DIRECTION));
        let Some(w) = material.sample(normal, wi, rng.get(base + dims::LOBE), u) else {
            return;
        };
        let pdf = material.pdf(normal, wi, w);
        let cos = normal.dot(w);
        if !(pdf > 0.0 && cos > 0.0) {
            return;
        }
        let weight = material.eval(normal, wi, w) * (cos as f64 / pdf) as f32;
        if bounce >= 2 {
            // Russian roulette from the second continuation on (towards the third hit).
            let q = weight.max_element().clamp(MIN_SURVIVAL, 1.0);
            if rng.get(base + dims::ROULETTE) >= q {
                return;
            }
            flux *= weight / q;
        } else {
            flux *= weight;
        }
        if flux == Vec3::ZERO {
            return;
        }
        origin = vpl.origin;
        dir = w;
    }
}

/// The first hits of a small image of the camera, as shading points (for `Φ_i`).
fn view_points(
    scene: &Scene,
    camera: &Camera,
    width: u32,
    threads: Option<usize>,
) -> Result<Vec<Receiver>> {
    let height =
        ((width as f32 * camera.height as f32 / camera.width as f32).round() as u32).max(1);
    let small = camera.with_resolution(width, height)?;
    let g = GBuffer::render(scene, &small, 0, false, threads)?;
    Ok((0..g.object.len())
        .filter_map(|i| g.surface_hit(i).map(|hit| (i, hit)))
        .map(|(i, hit)| {
            let wo = -Vec3::from(g.direction[i]);
            Receiver::new(
                scene,
                crate::estimators::indirect::shading_point_at(scene, &hit, wo),
            )
        })
        .collect())
}

/// `Φ_i`: the luminance of `vpl`'s contribution (eq. 6.1, shadow rays traced) averaged
/// over `points`.
fn view_contribution(
    scene: &Scene,
    points: &[Receiver],
    vpl: &Vpl,
    disk_area: f32,
    counters: &mut TraversalCounters,
    shadow_rays: &mut u64,
) -> f64 {
    if points.is_empty() {
        return 0.0;
    }
    let mut sum = 0.0f64;
    for sp in points {
        if let Some(c) = vpl.connect(sp, None, disk_area) {
            *shadow_rays += 1;
            if !scene.occluded1(c.origin, c.direction, c.tmax, counters) {
                sum += luminance(c.value) as f64;
            }
        }
    }
    sum / points.len() as f64
}

/// What the paths of one stream produced.
struct Traced {
    vpls: Vec<Vpl>,
    counters: TraversalCounters,
    rays: u64,
    shadow_rays: u64,
    rejected: u64,
}

/// Traces paths `0..paths` of stream `seed` in fixed chunks, in path order. Chunks poll
/// the current [`Stop`]: once it is set the rest are skipped and the paths are refused
/// with [`Error::Interrupted`].
fn trace_paths(
    src: &Sources,
    paths: u64,
    seed: u64,
    depth: u32,
    lights: bool,
    accept: &(dyn Fn(&Vpl, &mut TraversalCounters, &mut u64) -> f32 + Sync),
) -> Result<Traced> {
    let stop = Stop::current();
    let chunks = paths.div_ceil(PATH_CHUNK as u64);
    let parts: Vec<Traced> = (0..chunks)
        .into_par_iter()
        .map(|c| {
            let mut t = Traced {
                vpls: Vec::new(),
                counters: TraversalCounters::default(),
                rays: 0,
                shadow_rays: 0,
                rejected: 0,
            };
            if stop.is_set() {
                return t;
            }
            let end = ((c + 1) * PATH_CHUNK as u64).min(paths);
            for path in c * PATH_CHUNK as u64..end {
                trace_path(
                    src,
                    path,
                    seed,
                    depth,
                    lights,
                    1.0 / paths as f64,
                    accept,
                    &mut t.vpls,
                    &mut t.counters,
                    &mut t.rays,
                    &mut t.shadow_rays,
                    &mut t.rejected,
                );
            }
            t
        })
        .collect();
    stop.check("tracing VPLs")?;
    let mut all = Traced {
        vpls: Vec::with_capacity(parts.iter().map(|p| p.vpls.len()).sum()),
        counters: TraversalCounters::default(),
        rays: 0,
        shadow_rays: 0,
        rejected: 0,
    };
    for p in parts {
        all.vpls.extend(p.vpls);
        all.counters += p.counters;
        all.rays += p.rays;
        all.shadow_rays += p.shadow_rays;
        all.rejected += p.rejected;
    }
    Ok(all)
}

/// The pilot's stream, independent of the set's.
fn pilot_seed(seed: u64) -> u64 {
    mix64(seed ^ 0x5049_4c4f_5450_4154)
}

impl VplSet {
    /// Traces a set of about `params.count` VPLs lit by `env` and the scene's area
    /// lights (module docs). `camera` is the view importance-driven acceptance aims at
    /// (needed only with [`TraceParams::importance`]). Fails on bad parameters, a scene
    /// without triangles or a setup without light; stops with [`Error::Interrupted`]
    /// within a chunk of paths of the current [`Stop`] being set.
    pub fn trace(
        scene: &Scene,
        env: &EnvMap,
        camera: Option<&Camera>,
        params: &TraceParams,
        threads: Option<usize>,
    ) -> Result<VplSet> {
        params.validate()?;
        // The chunks' VPLs and their concatenation, with room for the pilot's noise in the
        // count: MemoryError up front rather than an abort part-way.
        crate::error::check_memory(
            (params.count as usize).saturating_mul(4 * std::mem::size_of::<Vpl>()),
            "vpls",
        )?;
        let start = std::time::Instant::now();
        let src = Sources::new(scene, env)?;
        let disk_area = src.disk_area();
        let importance = match (params.importance, camera) {
            (Some(imp), Some(cam)) => Some((imp, cam)),
            (Some(_), None) => {
                return Err(Error::invalid(
                    "importance",
                    "needs a camera to aim at (the setup's)",
                ))
            }
            (None, _) => None,
        };
        with_threads(threads, || {
            let mut stats = TraceStats::default();
            let every = |_: &Vpl, _: &mut TraversalCounters, _: &mut u64| 1.0f32;
            // The pilot: VPLs per path, and with importance Φ_v.
            // A pilot path costs about one VPL (its shadow rays to a small view): a
            // fixed pilot is a few milliseconds, and its noise is the VPL count's.
            let pilot_paths = match importance {
                Some((imp, _)) => imp.pilot_paths as u64,
                None => Importance::DEFAULT.pilot_paths as u64,
            };
            // The pilot keeps its light VPLs: they start its paths in the replay below.
            let pilot = trace_paths(
                &src,
                pilot_paths,
                pilot_seed(params.seed),
                params.depth,
                true,
                &every,
            )?;
            stats.pilot_paths = pilot_paths;
            let pilot_src_probability: Vec<f64> = (0..src.cumulative.len())
                .map(|k| src.probability(k))
                .collect();
            stats.path_rays += pilot.rays;
            let mut counters = pilot.counters;
            let (src, per_path, rule) = match importance {
                None => {
                    let kept = pilot
                        .vpls
                        .iter()
                        .filter(|v| params.lights || v.kind == VplKind::Surface)
                        .count();
                    (src, kept as f64 / pilot_paths as f64, None)
                }
                Some((imp, cam)) => {
                    let points = view_points(scene, cam, imp.view_width, None)?;
                    Stop::current().check("tracing VPLs")?;
                    let phis: Vec<(f64, u64, TraversalCounters)> = pilot
                        .vpls
                        .par_iter()
                        .map(|v| {
                            let mut c = TraversalCounters::default();
                            let mut rays = 0;
                            // Without light VPLs, only the indirect light counts.
                            let phi = if params.lights || v.kind == VplKind::Surface {
                                view_contribution(scene, &points, v, disk_area, &mut c, &mut rays)
                            } else {
                                0.0
                            };
                            (phi, rays, c)
                        })
                        .collect();
                    // Φ_v of surface and of light VPLs, and each light's share of the view.
                    let (mut sums, mut counts) = ([0.0f64; 2], [0u64; 2]);
                    let mut view = vec![0.0f64; src.cumulative.len()];
                    for (v, (phi, rays, c)) in pilot.vpls.iter().zip(&phis) {
                        stats.shadow_rays += rays;
                        counters += *c;
                        let kind = (v.kind == VplKind::Surface) as usize;
                        sums[kind] += phi;
                        counts[kind] += 1;
                        view[v.light as usize] += phi;
                    }
                    let means = [0, 1].map(|k| {
                        if counts[k] > 0 {
                            sums[k] / counts[k] as f64
                        } else {
                            0.0
                        }
                    });
                    stats.mean_contribution = means[1];
                    let src = src.reweighted(&view);
                    let eps = imp.epsilon as f64;
                    let p_of = |phi: f64, mean: f64| {
                        if mean > 0.0 {
                            (phi / mean + eps).min(1.0)
                        } else {
                            1.0
                        }
                    };
                    // Replay the acceptance on the pilot's paths for the expected number of
                    // VPLs per real path. A pilot path from light k stands for q_k / p_k
                    // real ones (the lights' probabilities changed from p to q), whose
                    // fluxes are p_k / q_k of its own; a surface VPL survives with the
                    // product of its path's acceptance probabilities so far, each computed
                    // with the flux divided by the ones before (Φ_i is linear in the flux).
                    let mut expected = 0.0f64;
                    let (mut weight, mut ratio, mut survive) = (1.0f64, 1.0f64, 1.0f64);
                    for (v, (phi, _, _)) in pilot.vpls.iter().zip(&phis) {
                        if v.kind != VplKind::Surface {
                            let k = v.light as usize;
                            let (p, q) = (pilot_src_probability[k], src.probability(k));
                            (weight, ratio, survive) = (q / p, p / q, 1.0);
                            if params.lights {
                                expected += weight * p_of(phi * ratio, means[0]);
                            }
                            continue;
                        }
                        survive *= p_of(phi * ratio / survive, means[1]);
                        expected += weight * survive;
                    }
                    let rule = (means[0] > 0.0 || means[1] > 0.0).then_some((points, means, eps));
                    (src, expected / pilot_paths as f64, rule)
                }
            };
            let paths = if per_path > 0.0 {
                ((params.count as f64 / per_path).ceil() as u64).clamp(1, MAX_VPLS)
            } else {
                params.count
            };
            let traced = match &rule {
                None => trace_paths(
                    &src,
                    paths,
                    params.seed,
                    params.depth,
                    params.lights,
                    &every,
                )?,
                Some((points, means, eps)) => {
                    // Fluxes carry `1 / paths`, the pilot's `1 / pilot_paths`: compare
                    // contributions per path.
                    let per_path = paths as f64 / pilot_paths as f64;
                    let accept = |v: &Vpl, c: &mut TraversalCounters, rays: &mut u64| -> f32 {
                        let mean = means[(v.kind == VplKind::Surface) as usize];
                        if mean <= 0.0 {
                            return 1.0;
                        }
                        let phi = view_contribution(scene, points, v, disk_area, c, rays);
                        ((phi * per_path / mean + eps) as f32).min(1.0)
                    };
                    trace_paths(
                        &src,
                        paths,
                        params.seed,
                        params.depth,
                        params.lights,
                        &accept,
                    )?
                }
            };
            counters += traced.counters;
            scene.add_counters(counters);
            stats.paths = paths;
            stats.path_rays += traced.rays;
            stats.shadow_rays += traced.shadow_rays;
            stats.rejected = traced.rejected;
            stats.seconds = start.elapsed().as_secs_f64();
            Ok(VplSet {
                vpls: traced.vpls,
                disk_area,
                fingerprint: scene.geometry_fingerprint(),
                stats,
            })
        })?
    }

    /// Light VPLs given by the user: oriented point lights at `positions` with unit
    /// `normals` (normalised here) and `flux` (W per channel, finite and `>= 0`), each of
    /// intensity `Φ cos θ / π`. Fails naming the argument on bad values.
    pub fn from_lights(
        scene: &Scene,
        positions: &[[f32; 3]],
        normals: &[[f32; 3]],
        flux: &[[f32; 3]],
    ) -> Result<VplSet> {
        let n = positions.len();
        crate::parallel::check_rows("normals", normals.len(), n, "positions")?;
        crate::parallel::check_rows("flux", flux.len(), n, "positions")?;
        if n == 0 {
            return Err(Error::invalid("positions", "needs at least one VPL, got 0"));
        }
        let mut vpls = Vec::with_capacity(n);
        for i in 0..n {
            let (p, nrm) = checked_row(i, positions[i], normals[i], flux[i], "flux")?;
            vpls.push(Vpl {
                position: p,
                origin: scene.offset_point(p, nrm),
                normal: nrm,
                incident: Vec3::ZERO,
                material: EMITTER,
                flux: Vec3::from(flux[i]),
                kind: VplKind::Emitter,
                bounce: 0,
                light: u32::MAX,
            });
        }
        let radius = bounding_disk(scene).1;
        let disk_area = std::f32::consts::PI * radius * radius;
        Ok(VplSet {
            vpls,
            disk_area,
            fingerprint: scene.geometry_fingerprint(),
            stats: TraceStats::default(),
        })
    }
}

/// How many of a set's lights reach a view ([`VplSet::view_share`]).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ViewShare {
    /// Lights with a positive, unoccluded term at one point of the view at least.
    pub contributing: u64,
    /// Lights in the set.
    pub total: u64,
    /// First hits of the view's G-buffer (the points tested).
    pub points: u64,
    /// `contributing` and `total` per kind, indexed by [`kind_index`].
    pub by_kind: [(u64, u64); 4],
}

/// A kind's index in [`ViewShare::by_kind`] (and Python's `VPLs.kinds`): 0 emitter point,
/// 1 directional, 2 surface, 3 whole area light.
pub fn kind_index(kind: VplKind) -> usize {
    match kind {
        VplKind::Emitter => 0,
        VplKind::Env => 1,
        VplKind::Surface => 2,
        VplKind::Area { .. } => 3,
    }
}

impl ViewShare {
    /// `contributing / total` (0 for an empty set).
    pub fn fraction(&self) -> f64 {
        if self.total == 0 {
            0.0
        } else {
            self.contributing as f64 / self.total as f64
        }
    }
}

/// Whether `v` lights receiver `r` at all: a positive term and an unoccluded shadow ray
/// (for an area light, towards one of its fixed points at least).
fn reaches(
    scene: &Scene,
    v: &Vpl,
    r: &Receiver,
    disk_area: f32,
    c: &mut TraversalCounters,
) -> bool {
    let VplKind::Area { points } = v.kind else {
        return v
            .connect(r, None, disk_area)
            .is_some_and(|k| !scene.occluded1(k.origin, k.direction, k.tmax, c));
    };
    let Some(light) = area_light_of(scene, v) else {
        return false;
    };
    let sp = &r.sp;
    let mut seen = false;
    area_points(light, points, |q| {
        if seen || q.value == Vec3::ZERO {
            return;
        }
        let d = q.position - sp.origin;
        if !(sp.normal.dot(d) > 0.0 && -q.normal.dot(d) > 0.0) {
            return;
        }
        let dist = d.length();
        let tmax = scene.segment_end(dist, q.position);
        seen = tmax > 0.0 && !scene.occluded1(sp.origin, d / dist, tmax, c);
    });
    seen
}

impl VplSet {
    /// The environment map as directional lights ([`VplKind::Env`]), one per texel of its
    /// octahedral level `level` (`2^level` texels a side, `0..=log2(resolution)`): a coarse
    /// texel covers `4^(L - level)` texels of the map's level `L` exactly (the map is
    /// equal-area and its quadtree nests), so its light carries their `Σ L_t ω_t` as the
    /// irradiance `E` it gives a surface facing it (flux `E · disk_area`), from the
    /// luminance-weighted mean of their directions (a sun inside a coarse texel keeps its
    /// direction). Black texels make no light. At a receiver of normal `n` the set's
    /// irradiance `Σ E_k max(0, n · ω_k)` converges to `∫ L(ω) max(0, n · ω) dω` as the
    /// level grows. Fails naming `level` when out of range.
    pub fn from_envmap(scene: &Scene, env: &EnvMap, level: u32) -> Result<VplSet> {
        use crate::sampling::octahedral::{texel_center, texel_solid_angle};
        let res = env.resolution();
        let finest = res.trailing_zeros();
        crate::error::check_range("level", level, 0, finest)?;
        let (side, block) = (1u32 << level, res >> level);
        let omega = texel_solid_angle(res);
        let disk_area = bounding_disk_area(scene);
        let mut vpls = Vec::with_capacity((side * side) as usize);
        for cy in 0..side {
            for cx in 0..side {
                let (mut power, mut mean) = (DVec3::ZERO, DVec3::ZERO);
                for y in cy * block..(cy + 1) * block {
                    for x in cx * block..(cx + 1) * block {
                        let t = glam::UVec2::new(x, y);
                        let l = env.texel(t).as_dvec3();
                        power += l * omega;
                        let lum = l.dot(DVec3::from_array(LUMINANCE_F32.map(|c| c as f64)));
                        mean += texel_center(t, res).as_dvec3() * (lum * omega);
                    }
                }
                if power == DVec3::ZERO {
                    continue;
                }
                let centre = texel_center(glam::UVec2::new(cx, cy), side);
                let dir = mean.normalize_or_zero().as_vec3();
                let dir = if dir == Vec3::ZERO { centre } else { dir };
                vpls.push(env_light(dir, (power * disk_area as f64).as_vec3(), 0));
            }
        }
        Ok(VplSet {
            vpls,
            disk_area,
            fingerprint: scene.geometry_fingerprint(),
            stats: TraceStats::default(),
        })
    }

    /// Directional lights ([`VplKind::Env`], a sun): light from unit `directions` (towards
    /// the light; normalised here) of `irradiance` (W/m² per channel on a surface facing
    /// it, finite and `>= 0`). Fails naming the argument on an empty or mismatched input,
    /// a zero or non-finite direction or a bad irradiance.
    pub fn from_directions(
        scene: &Scene,
        directions: &[[f32; 3]],
        irradiance: &[[f32; 3]],
    ) -> Result<VplSet> {
        let n = directions.len();
        crate::parallel::check_rows("irradiance", irradiance.len(), n, "directions")?;
        if n == 0 {
            return Err(Error::invalid(
                "directions",
                "needs at least one light, got 0",
            ));
        }
        let disk_area = bounding_disk_area(scene);
        let mut vpls = Vec::with_capacity(n);
        for (i, (d, e)) in directions.iter().zip(irradiance).enumerate() {
            let w = Vec3::from(*d).as_dvec3();
            let len = w.length();
            if !(len.is_finite() && len > 0.0) {
                return Err(Error::invalid(
                    "directions",
                    format!("row {i} must be finite and non-zero, got {d:?}"),
                ));
            }
            if !crate::lights::valid_radiance(*e) {
                return Err(Error::invalid(
                    "irradiance",
                    format!("row {i} {}", crate::lights::radiance_problem(*e)),
                ));
            }
            let flux = Vec3::from(*e) * disk_area;
            vpls.push(env_light((w / len).as_vec3(), flux, u32::MAX));
        }
        Ok(VplSet {
            vpls,
            disk_area,
            fingerprint: scene.geometry_fingerprint(),
            stats: TraceStats::default(),
        })
    }

    /// The scene's area lights, one [`VplKind::Area`] light each, whose term without
    /// visibility comes from `points` fixed stratified points on it
    /// ([`crate::lights::vpl::area_points`], `1..=MAX_AREA_POINTS`) and whose shadow rays
    /// go to a fresh point per gather ([`Vpl::sample_area`]). Fails naming `points` out of
    /// range or `scene` without area lights.
    pub fn from_area_lights(scene: &Scene, points: u32) -> Result<VplSet> {
        crate::error::check_range("points", points, 1, MAX_AREA_POINTS)?;
        let lights = scene.area_lights();
        if lights.is_empty() {
            return Err(Error::invalid(
                "scene",
                "has no area lights (Scene.add_area_light or set_emitter make them)",
            ));
        }
        let mut vpls = Vec::with_capacity(lights.len());
        for (k, light) in lights.iter().enumerate() {
            let (mut centroid, mut normal) = (DVec3::ZERO, DVec3::ZERO);
            for t in light.triangles() {
                let cross = triangle_cross(t).as_dvec3();
                let area = 0.5 * cross.length();
                centroid += (t[0] + t[1] + t[2]).as_dvec3() / 3.0 * area;
                normal += 0.5 * cross;
            }
            let centroid = (centroid / light.area()).as_vec3();
            // A closed emitter's normals cancel: any of its own then stands for it.
            let normal = match normal.normalize_or_zero().as_vec3() {
                Vec3::ZERO => (0..light.triangles().len())
                    .map(|t| light.normal(t))
                    .find(|n| *n != Vec3::ZERO)
                    .unwrap_or(Vec3::Y),
                n => n,
            };
            vpls.push(Vpl {
                position: centroid,
                origin: scene.offset_point(centroid, normal),
                normal,
                incident: Vec3::ZERO,
                material: EMITTER,
                flux: Vec3::from(light.power().map(|c| c as f32)),
                kind: VplKind::Area { points },
                bounce: 0,
                light: k as u32 + 1,
            });
        }
        Ok(VplSet {
            vpls,
            disk_area: bounding_disk_area(scene),
            fingerprint: scene.geometry_fingerprint(),
            stats: TraceStats::default(),
        })
    }

    /// How many of the set's lights contribute to `camera`'s view: those with a positive,
    /// unoccluded term (eq. 6.1 without clamping) at one first hit at least of a G-buffer
    /// `width` pixels wide (rows by the camera's aspect; `1..=1024`), pixel centres. Area
    /// lights count when one of their fixed points does. Fails naming `vpls` for a set of
    /// another scene, `width` out of range; counts do not depend on `threads`.
    pub fn view_share(
        &self,
        scene: &Scene,
        camera: &Camera,
        width: u32,
        threads: Option<usize>,
    ) -> Result<ViewShare> {
        if self.fingerprint != scene.geometry_fingerprint() {
            return Err(Error::invalid(
                "vpls",
                "were made for another scene (geometry fingerprints differ)",
            ));
        }
        crate::error::check_range("width", width, 1, 1024)?;
        let points = view_points(scene, camera, width, threads)?;
        let disk_area = self.disk_area;
        let (hits, counters) = with_threads(threads, || {
            self.vpls
                .par_iter()
                .map(|v| {
                    let mut c = TraversalCounters::default();
                    let hit = points
                        .iter()
                        .any(|r| reaches(scene, v, r, disk_area, &mut c));
                    (hit, c)
                })
                .unzip::<bool, TraversalCounters, Vec<bool>, Vec<TraversalCounters>>()
        })?;
        let mut total = TraversalCounters::default();
        for c in counters {
            total += c;
        }
        scene.add_counters(total);
        let mut by_kind = [(0u64, 0u64); 4];
        for (v, hit) in self.vpls.iter().zip(&hits) {
            let k = &mut by_kind[kind_index(v.kind)];
            k.0 += *hit as u64;
            k.1 += 1;
        }
        Ok(ViewShare {
            contributing: by_kind.iter().map(|k| k.0).sum(),
            total: self.len() as u64,
            points: points.len() as u64,
            by_kind,
        })
    }
}

/// `π R²` of the disk that covers `scene` (the normalisation of directional fluxes).
fn bounding_disk_area(scene: &Scene) -> f32 {
    let radius = bounding_disk(scene).1;
    std::f32::consts::PI * radius * radius
}

/// A directional light from unit `dir` of flux `flux` (irradiance times the disk's area).
fn env_light(dir: Vec3, flux: Vec3, light: u32) -> Vpl {
    Vpl {
        position: Vec3::ZERO,
        origin: Vec3::ZERO,
        normal: dir,
        incident: Vec3::ZERO,
        material: EMITTER,
        flux,
        kind: VplKind::Env,
        bounce: 0,
        light,
    }
}
