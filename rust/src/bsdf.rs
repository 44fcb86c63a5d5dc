//! Surface materials and their BSDFs: evaluation, importance sampling, the solid-angle pdf
//! of the sampler, and B~, the conservative per-cell approximation of the reflectance that
//! product importance sampling multiplies with the lighting (CAM08 §3 eq. 1-2: `B` is the
//! BRDF times the cosine, `p ∝ L B~`; §5.5 and §7: B~ lives on the same equal-area
//! octahedral quadtree as the lighting and the visibility records; Clarberg &
//! Akenine-Möller, "Practical Product Importance Sampling for Direct Illumination", 2008).
//!
//! Two materials: Lambert (`f = albedo / π`) and the energy-normalised Phong BRDF of
//! Lafortune & Willems, "Using the modified Phong reflectance model for physically based
//! rendering" (1994): `f = kd / π + ks (e + 2) / (2π) cos^e α`, `α` the angle between `wi`
//! and the mirror direction of `wo` about `n`. With `kd + ks ≤ 1` per channel its
//! directional albedo never exceeds 1 (the maximum is at normal incidence).
//!
//! Conventions: `n` is the unit shading normal, `wo` the unit direction towards the
//! viewer, `wi` the unit direction towards the light, all pointing away from the surface.
//! The BSDF is zero when `wi` or `wo` is at or below the surface (`dot(n, ·) ≤ 0`).
//!
//! ## B~ ([`Material::product_cells`])
//!
//! For one shading point, B~ is a piecewise-constant function over the `4^level` cells of
//! the `2^level` octahedral grid (Morton order) approximating the cell mean of the scalar
//! luminance (Rec. 709) of `f_r(wo, wi) cos θi`. It is **conservative**: a cell gets a
//! value > 0 whenever `f cos θi > 0` anywhere in it, so `p ∝ L B~` never misses a part of
//! the integrand. Per level, a static table ([`CellCones`]) holds each cell's centre
//! direction and the half-angle of a cone around it that contains the whole cell (measured
//! on a dense sampling of the cell border plus a margin of half the sampling gap). Per
//! cell then:
//!
//! * upper bounds over the cone: `cos θ ≤ cos(max(θc − a, 0))`, `cos α ≤ cos(max(αc − a,
//!   0))`, hence `bound = (lum(kd)/π + lum(ks)(e+2)/(2π) cos^e(max(αc − a, 0))) cos(max(θc − a, 0))`;
//! * an estimate of the mean: the clamped cosine averaged over a linear ramp across the
//!   cell, times the lobe blurred by a Gaussian of the cell's size
//!   (`s cos^(e s) αc` with `s = 1 / (1 + e σ²)`, `σ² = Ω / (2π)`; this preserves the lobe's
//!   integral and tends to the exact centre value for wide lobes);
//! * `B~ = clamp(estimate, FLOOR · bound, bound)`, and at least `f32::MIN_POSITIVE` in every
//!   cell whose cone reaches the support of `f cos θ`; exactly 0 elsewhere.
//!
//! The exponentials run through a branch-free `exp2`/`log2` pair so the loop vectorises.
//! Blocks of 16 cells are first tested with the cones of the level two up: a block below
//! the surface is zero, and a block where the lobe's bound is negligible (`2(e+2)·bound <
//! 1e-3`) skips the exponentials and takes the bound as its lobe estimate.
//!
//! Measured (test `product_cells_approximate_the_cell_means`, level 5, sampling efficiency
//! `I² / E[(g/p)²]`, 1 = perfect): B~ matches the best piecewise-constant pdf (exact cell
//! means) for Lambert (0.987) and Phong e ≤ 100 (within 0.01); for e = 1000 it reaches
//! 0.34-0.70 against 0.41-0.78, for e = 1e4 0.05-0.27 against 0.09-0.46 (a 32² grid cannot
//! resolve such lobes; plain centre values are biased there, efficiency 0). Cost
//! (`benches/bsdf.rs`, one loaded 2-core machine): 2-3.5 µs Lambert, 6-13 µs Phong e = 100,
//! ~8 µs e = 1e4 per shading point.

use glam::{DVec3, Vec2, Vec3};
use std::sync::OnceLock;

use crate::error::{Error, Result};
use crate::sampling::octahedral::{morton_decode, square_to_sphere};
use crate::sampling::rng::SampleRng;

/// A surface material. Colours are linear RGB reflectances in [0, 1].
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Material {
    /// Ideal diffuse reflector: f = albedo / pi.
    Lambert { albedo: [f32; 3] },
    /// Energy-normalised Phong: f = kd / pi + ks (e + 2) / (2 pi) cos^e(alpha), where alpha is
    /// the angle between the mirror direction and the outgoing direction. `kd + ks <= 1` per
    /// channel keeps it energy conserving; `exponent` lies in [1, 1e4].
    Phong {
        kd: [f32; 3],
        ks: [f32; 3],
        exponent: f32,
    },
}

impl Default for Material {
    fn default() -> Self {
        Material::DEFAULT
    }
}

fn check_color(name: &str, c: [f32; 3]) -> Result<()> {
    if c.iter().any(|v| !v.is_finite() || *v < 0.0 || *v > 1.0) {
        return Err(Error::invalid(
            name,
            format!("each channel must be finite and in [0, 1], got {c:?}"),
        ));
    }
    Ok(())
}

impl Material {
    /// A light grey diffuse material, used where none is given.
    pub const DEFAULT: Material = Material::Lambert {
        albedo: [0.7, 0.7, 0.7],
    };

    /// Lambertian material with the given albedo (each channel in [0, 1]).
    pub fn lambert(albedo: [f32; 3]) -> Result<Self> {
        check_color("albedo", albedo)?;
        Ok(Material::Lambert { albedo })
    }

    /// Normalised Phong; `kd + ks` must not exceed 1 in any channel, `exponent` in [1, 1e4].
    pub fn phong(kd: [f32; 3], ks: [f32; 3], exponent: f32) -> Result<Self> {
        check_color("kd", kd)?;
        check_color("ks", ks)?;
        if (0..3).any(|i| kd[i] + ks[i] > 1.0 + 1e-6) {
            return Err(Error::invalid(
                "ks",
                format!("kd + ks must not exceed 1 in any channel (energy conservation), got kd={kd:?} ks={ks:?}"),
            ));
        }
        if !(1.0..=1e4).contains(&exponent) {
            return Err(Error::invalid(
                "exponent",
                format!("must lie in [1, 1e4], got {exponent}"),
            ));
        }
        Ok(Material::Phong { kd, ks, exponent })
    }

    /// The diffuse colour, used for simple first-hit shading.
    pub fn base_color(&self) -> [f32; 3] {
        match *self {
            Material::Lambert { albedo } => albedo,
            Material::Phong { kd, ks, .. } => [kd[0] + ks[0], kd[1] + ks[1], kd[2] + ks[2]],
        }
    }

    /// Whether [`Self::product_cells`] depends on the outgoing direction beyond its side of
    /// the surface: only a specular lobe does. When it does not, points with the same
    /// normal and material share their product distribution bit for bit.
    pub fn product_depends_on_wo(&self) -> bool {
        match *self {
            Material::Lambert { .. } => false,
            Material::Phong { ks, .. } => luminance(ks) > 0.0,
        }
    }

    /// The product cells' level this material needs (CAM08 §5.5 refines B~ where the
    /// lobe is narrow): level 5 (32², cells about 6.4° across) for Lambert and for Phong
    /// lobes at least half a cell wide (`e` up to about 650), else 6 (3.2°). The lobe
    /// width is `sqrt(2 / (e + 2))` radians, the standard deviation of the normalised
    /// `cos^e` lobe about its axis for large `e`. Level 6 costs 4x in B~ and gained nothing
    /// for the renderer's mixture, whose BSDF share draws narrow lobes: with level 5
    /// instead of 6 for their Phong materials (e = 60 to 200), garage and dynamics
    /// rendered within 1% of the relMSE at equal samples for 40-60% of the product's time.
    pub fn product_level_hint(&self) -> u32 {
        const CELL_5: f32 = 0.111; // sqrt(4π) / 32 rad: a level-5 cell's width
        match *self {
            Material::Lambert { .. } => 5,
            Material::Phong { exponent, ks, .. } => {
                let lobe = (2.0 / (exponent + 2.0)).sqrt();
                if luminance(ks) > 0.0 && lobe < 0.5 * CELL_5 {
                    6
                } else {
                    5
                }
            }
        }
    }

    /// How far (radians) a surface normal may turn from the normal a product distribution
    /// was built at before the product stops describing this material's reflection there:
    /// 10° for diffuse reflection (B~ follows the cosine), and a quarter of the specular
    /// lobe's width `sqrt(2 / (e + 2))` when that is less (the mirror direction turns
    /// twice as fast as the normal). The renderer shares a pixel's product with the
    /// samples whose hits lie within it.
    pub fn product_tolerance(&self) -> f32 {
        const DIFFUSE: f32 = 10.0 * std::f32::consts::PI / 180.0;
        match *self {
            Material::Phong { exponent, ks, .. } if luminance(ks) > 0.0 => {
                DIFFUSE.min(0.25 * (2.0 / (exponent + 2.0)).sqrt())
            }
            _ => DIFFUSE,
        }
    }

    /// Each channel of the albedo `kd + ks` over its luminance (0 for a black material):
    /// how a channel of `f` compares with the luminance `B~` approximates. Exact at every
    /// direction for Lambert; for Phong, where the diffuse and specular colours mix by
    /// direction, the ratio of the two lobes' combined albedos. The control variate scales
    /// channel `c` of `L B~ Ṽ` by it, so `Z_c ≈ W_c` where the records are right.
    pub fn channel_ratios(&self) -> [f32; 3] {
        let albedo = self.base_color();
        let lum = luminance(albedo);
        if lum > 0.0 {
            albedo.map(|c| c / lum)
        } else {
            [0.0; 3]
        }
    }

    /// Probability that [`Material::sample`] picks the specular lobe: the lobe's share of
    /// the luminance of `kd + ks` (0 for Lambert and for a black material).
    #[inline]
    pub fn specular_probability(&self) -> f32 {
        match *self {
            Material::Lambert { .. } => 0.0,
            Material::Phong { kd, ks, .. } => {
                let (d, s) = (luminance(kd), luminance(ks));
                if d + s > 0.0 {
                    s / (d + s)
                } else {
                    0.0
                }
            }
        }
    }

    /// The BRDF `f_r(wo, wi)` in 1/sr, per RGB channel, without the cosine. Zero when `wo`
    /// or `wi` is at or below the surface, or when any input is NaN.
    pub fn eval(&self, n: Vec3, wo: Vec3, wi: Vec3) -> Vec3 {
        let (co, ci) = (n.dot(wo), n.dot(wi));
        if !(co > 0.0 && ci > 0.0) {
            return Vec3::ZERO;
        }
        match *self {
            Material::Lambert { albedo } => Vec3::from(albedo) * std::f32::consts::FRAC_1_PI,
            Material::Phong { kd, ks, exponent } => {
                let lobe = phong_lobe(exponent, cos_to_mirror(n, wo, wi)) as f32;
                Vec3::from(kd) * std::f32::consts::FRAC_1_PI + Vec3::from(ks) * lobe
            }
        }
    }

    /// Draws `wi` for a given `wo`: `uc ∈ [0,1)` picks the lobe (Phong: the specular lobe
    /// when `uc <` [`Material::specular_probability`]), `u ∈ [0,1)²` the direction within
    /// it (cosine-weighted hemisphere about `n`; Phong lobe `∝ cos^e α` about the mirror
    /// direction). `None` when the sample falls at or below the surface or `wo` is below it.
    /// The density of the returned directions is [`Material::pdf`].
    pub fn sample(&self, n: Vec3, wo: Vec3, uc: f32, u: Vec2) -> Option<Vec3> {
        if !is_above(n.dot(wo)) {
            return None;
        }
        let wi = match *self {
            Material::Phong { exponent, .. } if uc < self.specular_probability() => {
                let r = mirror(n.as_dvec3(), wo.as_dvec3());
                // cos α = u^(1/(e+1)); sin α from 1 - cos² = -expm1(2 ln u / (e+1)).
                let l = (u.x as f64).ln() / (exponent as f64 + 1.0);
                let cos_a = l.exp();
                let sin_a = (-(2.0 * l).exp_m1()).max(0.0).sqrt();
                let phi = std::f64::consts::TAU * u.y as f64;
                let (t, b) = r.normalize().any_orthonormal_pair();
                (t * (sin_a * phi.cos()) + b * (sin_a * phi.sin()) + r * cos_a)
                    .normalize()
                    .as_vec3()
            }
            _ => {
                let rad = u.x.sqrt();
                let phi = std::f32::consts::TAU * u.y;
                let z = (1.0 - u.x).max(0.0).sqrt();
                let (t, b) = n.any_orthonormal_pair();
                (t * (rad * phi.cos()) + b * (rad * phi.sin()) + n * z).normalize()
            }
        };
        (n.dot(wi) > 0.0 && wi.is_finite()).then_some(wi)
    }

    /// Solid-angle density (1/sr) of the directions [`Material::sample`] returns: the
    /// mixture of the cosine lobe (`cos θi / π`) and the Phong lobe (`(e+1)/(2π) cos^e α`)
    /// with the lobe-selection probabilities; zero at or below the surface, so its
    /// integral over the sphere is the probability that `sample` returns `Some`.
    pub fn pdf(&self, n: Vec3, wo: Vec3, wi: Vec3) -> f64 {
        let (co, ci) = (n.dot(wo), n.dot(wi));
        if !(co > 0.0 && ci > 0.0) {
            return 0.0;
        }
        let diffuse = ci as f64 * std::f64::consts::FRAC_1_PI;
        match *self {
            Material::Lambert { .. } => diffuse,
            Material::Phong { exponent, .. } => {
                let ps = self.specular_probability() as f64;
                let c = cos_to_mirror(n, wo, wi);
                let e = exponent as f64;
                let lobe = if c > 0.0 {
                    (e + 1.0) / std::f64::consts::TAU * c.powf(e)
                } else {
                    0.0
                };
                (1.0 - ps) * diffuse + ps * lobe
            }
        }
    }

    /// Monte Carlo estimate of the directional albedo `∫ f_r(wo, wi) cos θi dωi` per RGB
    /// channel (dimensionless, ≤ 1 for an energy-conserving material), from `samples`
    /// draws of [`Material::sample`] with the counter-based RNG of `seed`. Returns the mean
    /// and its standard error. For tests and diagnostics.
    pub fn directional_albedo(&self, n: Vec3, wo: Vec3, samples: u32, seed: u64) -> (DVec3, DVec3) {
        let (mut sum, mut sum2) = (DVec3::ZERO, DVec3::ZERO);
        for i in 0..samples as u64 {
            let rng = SampleRng::new(seed, 0, i);
            if let Some(wi) = self.sample(n, wo, rng.get(0), Vec2::from(rng.get2(1))) {
                let p = self.pdf(n, wo, wi);
                if p > 0.0 {
                    let x = self.eval(n, wo, wi).as_dvec3() * (n.dot(wi) as f64 / p);
                    sum += x;
                    sum2 += x * x;
                }
            }
        }
        let k = samples.max(1) as f64;
        let mean = sum / k;
        let var = (sum2 / k - mean * mean).max(DVec3::ZERO) / (k - 1.0).max(1.0);
        (mean, DVec3::new(var.x.sqrt(), var.y.sqrt(), var.z.sqrt()))
    }

    /// B~: for each of the `4^level` cells of the `2^level` octahedral grid, in Morton order,
    /// an approximation of the cell mean of `luminance(f_r(wo, wi)) · cos θi` (1/sr), the
    /// reflectance factor of product importance sampling (CAM08 §3, §5.5). Conservative:
    /// `out[k] > 0` whenever `f cos θi > 0` somewhere in cell `k`; `out[k] = 0` when the
    /// cell's bounding cone lies entirely below the surface, and everywhere when `wo` is at
    /// or below it (or an input is NaN). Never exceeds the analytic upper bound of the
    /// integrand over the cell's cone. See the module documentation for the construction.
    ///
    /// # Panics
    /// When `level` is outside `1..=8` or `out.len() != 4^level` (callers validate first).
    pub fn product_cells(&self, n: Vec3, wo: Vec3, level: u32, out: &mut [f32]) {
        assert!(
            (1..=MAX_CELL_LEVEL).contains(&level),
            "level must lie in 1..={MAX_CELL_LEVEL}, got {level}"
        );
        assert_eq!(
            out.len(),
            1usize << (2 * level),
            "out must hold 4^level cells"
        );
        if !is_above(n.dot(wo)) || !n.is_finite() || !wo.is_finite() {
            out.fill(0.0);
            return;
        }
        let cones = CellCones::get(level);
        let (kd_l, ks_l, e) = match *self {
            Material::Lambert { albedo } => (luminance(albedo), 0.0, 1.0),
            Material::Phong { kd, ks, exponent } => (luminance(kd), luminance(ks), exponent),
        };
        if kd_l + ks_l <= 0.0 {
            out.fill(0.0);
            return;
        }
        let diffuse = kd_l * std::f32::consts::FRAC_1_PI;
        if ks_l <= 0.0 {
            cells_lambert(cones, n, diffuse, out);
        } else {
            let r = mirror(n.as_dvec3(), wo.as_dvec3()).normalize().as_vec3();
            let spec = ks_l * (e + 2.0) / std::f32::consts::TAU;
            cells_phong(cones, n, r, diffuse, spec, e, out);
        }
    }
}

/// Rec. 709 luminance weights of linear RGB.
pub const LUMINANCE: [f32; 3] = [0.2126, 0.7152, 0.0722];

/// Rec. 709 luminance of a linear RGB triple.
#[inline]
pub fn luminance(c: [f32; 3]) -> f32 {
    LUMINANCE[0] * c[0] + LUMINANCE[1] * c[1] + LUMINANCE[2] * c[2]
}

/// `x > 0`, false for NaN.
#[inline]
fn is_above(x: f32) -> bool {
    x > 0.0
}

/// Mirror direction of `wo` about `n` (unit when both are).
#[inline]
fn mirror(n: DVec3, wo: DVec3) -> DVec3 {
    2.0 * n.dot(wo) * n - wo
}

/// `cos α`: cosine between `wi` and the mirror direction of `wo`, in f64 (the lobe of
/// exponent 1e4 needs the precision).
#[inline]
fn cos_to_mirror(n: Vec3, wo: Vec3, wi: Vec3) -> f64 {
    let r = mirror(n.as_dvec3(), wo.as_dvec3());
    (r.dot(wi.as_dvec3()) / r.length()).min(1.0)
}

/// The normalised Phong lobe `(e+2)/(2π) cos^e α`, zero for `cos α ≤ 0`.
#[inline]
fn phong_lobe(e: f32, cos_a: f64) -> f64 {
    if cos_a > 0.0 {
        (e as f64 + 2.0) / std::f64::consts::TAU * cos_a.powf(e as f64)
    } else {
        0.0
    }
}

/// Finest level [`Material::product_cells`] accepts (a 256² grid).
pub const MAX_CELL_LEVEL: u32 = 8;

/// Fraction of the cone's upper bound that B~ never falls below in a cell of the support:
/// guards against a narrow lobe that the smooth estimate places in a neighbouring cell.
pub const BOUND_FLOOR: f32 = 1e-4;

/// Per-level static geometry of the octahedral cells, in Morton order (structure of
/// arrays so the per-cell loops vectorise): centre direction (unit) and the cosine and sine
/// of a half-angle `a` such that every direction of the cell lies within angle `a` of the
/// centre.
#[derive(Debug)]
pub struct CellCones {
    /// Grid level: `2^level` cells per side.
    pub level: u32,
    /// Centre directions, components in separate arrays.
    pub cx: Vec<f32>,
    pub cy: Vec<f32>,
    pub cz: Vec<f32>,
    /// `cos a` and `sin a` of each cell's bounding half-angle `a` (radians).
    pub cos_a: Vec<f32>,
    pub sin_a: Vec<f32>,
    /// Per-cell half-angle `a` in radians (for diagnostics).
    pub half_angle: Vec<f32>,
    /// Solid angle of one cell, `4π / 4^level` sr.
    pub cell_solid_angle: f32,
}

impl CellCones {
    /// Centre components and cone `cos a`, `sin a` of cells `first..first + len`, as
    /// equal-length slices (what the per-cell loops vectorise over).
    fn slices(&self, first: usize, len: usize) -> [&[f32]; 5] {
        let r = first..first + len;
        [
            &self.cx[r.clone()],
            &self.cy[r.clone()],
            &self.cz[r.clone()],
            &self.cos_a[r.clone()],
            &self.sin_a[r],
        ]
    }
}

static CELL_CONES: [OnceLock<CellCones>; MAX_CELL_LEVEL as usize + 1] =
    [const { OnceLock::new() }; MAX_CELL_LEVEL as usize + 1];

/// Border points per cell edge used to measure the bounding cones.
fn border_samples(level: u32) -> u32 {
    (4096u32 >> level).max(32)
}

impl CellCones {
    /// The table of `level` (`1..=8`), built on first use (≈ ms) and shared afterwards.
    pub fn get(level: u32) -> &'static CellCones {
        assert!((1..=MAX_CELL_LEVEL).contains(&level), "level {level}");
        CELL_CONES[level as usize].get_or_init(|| Self::build(level))
    }

    fn build(level: u32) -> CellCones {
        let res = 1u32 << level;
        let cells = (res * res) as usize;
        let k = border_samples(level);
        let mut t = CellCones {
            level,
            cx: Vec::with_capacity(cells),
            cy: Vec::with_capacity(cells),
            cz: Vec::with_capacity(cells),
            cos_a: Vec::with_capacity(cells),
            sin_a: Vec::with_capacity(cells),
            half_angle: Vec::with_capacity(cells),
            cell_solid_angle: (4.0 * std::f64::consts::PI / cells as f64) as f32,
        };
        // Cells in parallel (level 6 walks a million border points). Per cell the border
        // point farthest from the centre, and the widest gap between neighbours, are found
        // by their dot products; only those two angles take the accurate atan2 form.
        use rayon::prelude::*;
        let cones: Vec<(DVec3, f64)> = (0..cells as u32)
            .into_par_iter()
            .map(|code| {
                let cell = morton_decode(code);
                let x0 = cell.x as f64 / res as f64;
                let y0 = cell.y as f64 / res as f64;
                let side = 1.0 / res as f64;
                let centre = square_to_sphere(Vec2::new(
                    (x0 + 0.5 * side) as f32,
                    (y0 + 0.5 * side) as f32,
                ))
                .as_dvec3()
                .normalize();
                let border = |i: u32| {
                    let (edge, j) = (i / k, (i % k) as f64 / k as f64);
                    let (px, py) = match edge {
                        0 => (j, 0.0),
                        1 => (1.0, j),
                        2 => (1.0 - j, 1.0),
                        _ => (0.0, 1.0 - j),
                    };
                    square_to_sphere(Vec2::new((x0 + px * side) as f32, (y0 + py * side) as f32))
                        .as_dvec3()
                        .normalize()
                };
                // Walk the border counter-clockwise, 4k points.
                let first = border(0);
                let (mut far, mut far_dot) = (first, centre.dot(first));
                let (mut gap, mut gap_dot) = ((first, first), 1.0f64);
                let mut prev = first;
                for i in 1..=4 * k {
                    let d = if i == 4 * k { first } else { border(i) };
                    let to_centre = centre.dot(d);
                    if to_centre < far_dot {
                        (far, far_dot) = (d, to_centre);
                    }
                    let to_prev = prev.dot(d);
                    if to_prev < gap_dot {
                        (gap, gap_dot) = ((prev, d), to_prev);
                    }
                    prev = d;
                }
                let max_angle = angle_between(centre, far);
                let max_gap = angle_between(gap.0, gap.1);
                // A border point between two samples lies within half the gap of one of
                // them; 1e-5 rad more covers the f32 rounding of the map and of the
                // per-cell maths (and the dot products' choice of the extreme points).
                let a = (max_angle + 0.5 * max_gap + 1e-5).min(std::f64::consts::PI);
                (centre, a)
            })
            .collect();
        for (centre, a) in cones {
            let c = centre.as_vec3();
            t.cx.push(c.x);
            t.cy.push(c.y);
            t.cz.push(c.z);
            t.cos_a.push(a.cos() as f32);
            t.sin_a.push(a.sin() as f32);
            t.half_angle.push(a as f32);
        }
        t
    }
}

/// Angle between two unit vectors, accurate for small and large angles.
fn angle_between(a: DVec3, b: DVec3) -> f64 {
    a.cross(b).length().atan2(a.dot(b))
}

/// `2^x`, relative error ≈ 2e-7, for `x ≥ -126` (clamped below); branch-free.
#[inline(always)]
fn fast_exp2(x: f32) -> f32 {
    let x = x.clamp(-126.0, 126.0);
    // Round to nearest with the 1.5 · 2^23 trick (`f32::round` is a library call on
    // baseline x86-64 and would stop the loops from vectorising).
    const MAGIC: f32 = 12_582_912.0;
    let shifted = x + MAGIC;
    let i = shifted - MAGIC;
    let f = x - i; // [-0.5, 0.5]
                   // The integer sits in the low mantissa bits of `shifted`: no float-to-int conversion.
    let i_int = shifted.to_bits().wrapping_sub(MAGIC.to_bits());
    // Taylor series of 2^f = e^(f ln 2) to degree 6.
    const C: [f32; 7] = [
        1.0,
        std::f32::consts::LN_2,
        0.240_226_5,
        0.055_504_11,
        0.009_618_129,
        0.001_333_355_8,
        0.000_154_035_3,
    ];
    let p = C[0] + f * (C[1] + f * (C[2] + f * (C[3] + f * (C[4] + f * (C[5] + f * C[6])))));
    p * f32::from_bits(i_int.wrapping_add(127) << 23)
}

/// `log2(x)` for normal positive `x`, absolute error ≈ 1e-7; branch-free.
#[inline(always)]
fn fast_log2(x: f32) -> f32 {
    let bits = x.to_bits();
    // Split into 2^e · m with m in [√½, √2).
    let offset = 0x3f35_04f3u32; // bits of √½
    let ei = (bits.wrapping_sub(offset) as i32) >> 23;
    let m = f32::from_bits(bits.wrapping_sub((ei << 23) as u32));
    let e = ei as f32;
    let t = (m - 1.0) / (m + 1.0);
    let t2 = t * t;
    let ln_m = 2.0 * t * (1.0 + t2 * (1.0 / 3.0 + t2 * (0.2 + t2 * (1.0 / 7.0 + t2 / 9.0))));
    e + ln_m * std::f32::consts::LOG2_E
}

/// Lobe blur: variance (sr) of the Gaussian a cell is approximated by, per unit of cell
/// solid angle. `1/(2π)` keeps the peak of a lobe much narrower than a cell at its exact
/// cell mean and preserves the lobe's integral.
const BLUR_PER_SOLID_ANGLE: f32 = 1.0 / std::f32::consts::TAU;

/// Share of the cone half-angle the cosine ramp of [`cos_parts`] spans.
const RAMP_CONE: f32 = 1.0;

/// Per cell of the cos θ part: `(upper bound over the cone, estimate of the cell mean)`.
#[inline(always)]
fn cos_parts(x: f32, ca: f32, sa: f32, half_side: f32) -> (f32, f32) {
    let s = (1.0 - x * x).max(0.0).sqrt();
    let ub = if x >= ca { 1.0 } else { x * ca + s * sa };
    // Mean of max(cos, 0) over a linear ramp x ± h across the cell, h between the cell's
    // half side and its cone (so a cell with a sliver above the surface gets some mass).
    let h = s * (RAMP_CONE * sa).max(half_side);
    let est = if x >= h {
        x
    } else if x <= -h {
        0.0
    } else {
        (x + h) * (x + h) / (4.0 * h)
    };
    (ub, est)
}

fn cells_lambert(t: &CellCones, n: Vec3, diffuse: f32, out: &mut [f32]) {
    let half_side = 0.5 * t.cell_solid_angle.sqrt();
    let len = out.len();
    let (cx, cy, cz) = (&t.cx[..len], &t.cy[..len], &t.cz[..len]);
    let (cos_a, sin_a) = (&t.cos_a[..len], &t.sin_a[..len]);
    for (k, o) in out.iter_mut().enumerate() {
        let x = n.x * cx[k] + n.y * cy[k] + n.z * cz[k];
        let (ub, est) = cos_parts(x, cos_a[k], sin_a[k], half_side);
        let bound = diffuse * ub;
        let v = (diffuse * est)
            .min(bound)
            .max(BOUND_FLOOR * bound)
            .max(f32::MIN_POSITIVE);
        *o = if ub > 0.0 { v } else { 0.0 };
    }
}

/// Blocks of 16 cells (a node two levels up) whose lobe bound times `2(e+2)` is below this
/// skip the exponentials: their lobe estimate is the block's bound, which wastes at most
/// this fraction of the lobe's mass on them.
const LOBE_SKIP: f32 = 1e-3;

fn cells_phong(t: &CellCones, n: Vec3, r: Vec3, diffuse: f32, spec: f32, e: f32, out: &mut [f32]) {
    let p = PhongCells::new(t, n, r, diffuse, spec, e);
    if t.level < 3 {
        p.full(0, out);
        return;
    }
    // Cull per block of 16 cells with the cones of the level two up, which contain them.
    let coarse = CellCones::get(t.level - 2);
    for (b, block) in out.chunks_exact_mut(16).enumerate() {
        let c = Vec3::new(coarse.cx[b], coarse.cy[b], coarse.cz[b]);
        let (ca, sa) = (coarse.cos_a[b], coarse.sin_a[b]);
        let (cub, _) = cos_parts(n.dot(c), ca, sa, 0.0);
        if cub <= 0.0 {
            block.fill(0.0); // the whole block lies below the surface
            continue;
        }
        let y = r.dot(c);
        let aub = if y >= ca {
            1.0
        } else {
            y * ca + (1.0 - y * y).max(0.0).sqrt() * sa
        };
        let lub = if aub > 0.0 { (e * aub.ln()).exp() } else { 0.0 };
        if 2.0 * (e + 2.0) * lub < LOBE_SKIP {
            p.skipped(16 * b, lub, aub > 0.0, block);
        } else {
            p.full(16 * b, block);
        }
    }
}

/// Per-shading-point constants of the Phong B~ loops.
struct PhongCells<'a> {
    t: &'a CellCones,
    n: Vec3,
    r: Vec3,
    diffuse: f32,
    spec: f32,
    e: f32,
    half_side: f32,
    s: f32,
    es: f32,
    blend: f32,
    half_side_lobe: f32,
    cos_r: f32,
}

impl<'a> PhongCells<'a> {
    fn new(t: &'a CellCones, n: Vec3, r: Vec3, diffuse: f32, spec: f32, e: f32) -> Self {
        let half_side = 0.5 * t.cell_solid_angle.sqrt();
        let s = 1.0 / (1.0 + e * BLUR_PER_SOLID_ANGLE * t.cell_solid_angle);
        Self {
            t,
            n,
            r,
            diffuse,
            spec,
            e,
            half_side,
            s,
            es: e * s,
            blend: 1.0 - s,
            half_side_lobe: half_side * s.sqrt(),
            cos_r: n.dot(r),
        }
    }

    /// Cells `first..first + out.len()` with the full per-cell bound and estimate.
    fn full(&self, first: usize, out: &mut [f32]) {
        let (n, r) = (self.n, self.r);
        let [tx, ty, tz, tca, tsa] = self.t.slices(first, out.len());
        let has_diffuse = self.diffuse > 0.0;
        for (k, o) in out.iter_mut().enumerate() {
            let (cx, cy, cz, ca, sa) = (tx[k], ty[k], tz[k], tca[k], tsa[k]);
            let x = n.x * cx + n.y * cy + n.z * cz;
            let (cub, cest) = cos_parts(x, ca, sa, self.half_side);
            let y = r.x * cx + r.y * cy + r.z * cz;
            let sy = (1.0 - y * y).max(0.0).sqrt();
            let aub = if y >= ca { 1.0 } else { y * ca + sy * sa };
            let lub = fast_exp2(self.e * fast_log2(aub.max(1e-30)));
            let lest = self.s * fast_exp2(self.es * fast_log2(y.max(1e-30)));
            let lest = if y > 0.0 { lest } else { 0.0 };
            // The lobe's mass within the cell sits between the centre and the mirror
            // direction (the product of the two Gaussians): take the cosine there, over a
            // ramp shrunk to the product's width.
            let xl = x + self.blend * (self.cos_r - x);
            let (_, clest) = cos_parts(xl, 1.0, 0.0, self.half_side_lobe);
            let bound = (self.diffuse + self.spec * lub) * cub;
            let est = self.diffuse * cest + self.spec * lest * clest;
            let v = est
                .min(bound)
                .max(BOUND_FLOOR * bound)
                .max(f32::MIN_POSITIVE);
            let support = cub > 0.0 && (has_diffuse || aub > 0.0);
            *o = if support { v } else { 0.0 };
        }
    }

    /// Cells of a block whose lobe is bounded by `lub` (`lobe_support`: whether the block's
    /// cone reaches the lobe's support): the lobe term takes its bound.
    fn skipped(&self, first: usize, lub: f32, lobe_support: bool, out: &mut [f32]) {
        let n = self.n;
        let [tx, ty, tz, tca, tsa] = self.t.slices(first, out.len());
        let f = self.diffuse + self.spec * lub;
        let support = self.diffuse > 0.0 || lobe_support;
        for (k, o) in out.iter_mut().enumerate() {
            let x = n.x * tx[k] + n.y * ty[k] + n.z * tz[k];
            let (cub, cest) = cos_parts(x, tca[k], tsa[k], self.half_side);
            let v = (f * cest)
                .min(f * cub)
                .max(BOUND_FLOOR * f * cub)
                .max(f32::MIN_POSITIVE);
            *o = if support && cub > 0.0 { v } else { 0.0 };
        }
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use crate::sampling::chi2::{chi2_sphere, Chi2Params};
    use crate::sampling::octahedral::{morton_encode, sphere_to_square, texel_of};
    use crate::sampling::rng::{hash4, to_unit_f32};
    use glam::UVec2;
    use rayon::prelude::*;

    #[test]
    fn validation_names_the_parameter() {
        assert!(Material::lambert([0.5, 0.5, 0.5]).is_ok());
        let e = Material::lambert([1.5, 0.0, 0.0]).unwrap_err().to_string();
        assert!(e.starts_with("albedo"), "{e}");
        let e = Material::phong([0.6; 3], [0.6; 3], 10.0)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("ks"), "{e}");
        let e = Material::phong([0.1; 3], [0.1; 3], 0.5)
            .unwrap_err()
            .to_string();
        assert!(e.starts_with("exponent"), "{e}");
        assert!(Material::phong([0.1; 3], [0.1; 3], f32::NAN).is_err());
        assert!(Material::phong([0.1; 3], [0.9; 3], 1e4).is_ok());
    }

    fn rand_dir(seed: u64, i: u64) -> Vec3 {
        let u = to_unit_f32(hash4(seed, i, 0, 0));
        let v = to_unit_f32(hash4(seed, i, 0, 1));
        square_to_sphere(Vec2::new(u, v)).normalize()
    }

    /// A unit vector at angle `theta` from `n` (radians), in an arbitrary azimuth.
    fn at_angle(n: Vec3, theta: f32, azimuth: f32) -> Vec3 {
        let (t, b) = n.any_orthonormal_pair();
        (n * theta.cos() + (t * azimuth.cos() + b * azimuth.sin()) * theta.sin()).normalize()
    }

    /// A normal that is not ±y, so horizon discontinuities do not run along bin diagonals.
    fn test_normal() -> Vec3 {
        Vec3::new(0.3, 0.8, -0.5).normalize()
    }

    fn phong(e: f32) -> Material {
        Material::phong([0.3, 0.2, 0.1], [0.5, 0.6, 0.7], e).unwrap()
    }

    /// (name, wo) at normal, oblique (60°) and grazing (89°) incidence.
    fn incidences(n: Vec3) -> [(&'static str, Vec3); 3] {
        [
            ("normal", n),
            ("oblique", at_angle(n, 60f32.to_radians(), 0.7)),
            ("grazing", at_angle(n, 89f32.to_radians(), 2.1)),
        ]
    }

    fn chi2_of(
        m: Material,
        n: Vec3,
        wo: Vec3,
        samples: u64,
        params: &Chi2Params,
    ) -> crate::sampling::chi2::Chi2Outcome {
        let draws = (0..samples).map(|i| {
            let rng = SampleRng::new(17, 3, i);
            m.sample(n, wo, rng.get(0), Vec2::from(rng.get2(1)))
        });
        chi2_sphere(draws, |wi| m.pdf(n, wo, wi), params)
    }

    #[test]
    fn fast_exp2_and_log2_are_accurate() {
        for i in 0..10_000 {
            let x = -126.0 + 252.0 * i as f32 / 9999.0;
            let rel = (fast_exp2(x) as f64 / 2f64.powf(x as f64) - 1.0).abs();
            assert!(rel < 1e-6, "exp2({x}) rel error {rel}");
            let y = 1e-30f32 * 1.0173f32.powi(i % 4000);
            let abs = (fast_log2(y) as f64 - (y as f64).log2()).abs();
            assert!(
                abs < 2e-6 * (y as f64).log2().abs().max(1.0),
                "log2({y}) error {abs}"
            );
        }
    }

    #[test]
    fn chi2_lambert_and_phong_low_exponents() {
        let n = test_normal();
        for m in [
            Material::lambert([0.8, 0.5, 0.2]).unwrap(),
            phong(1.0),
            phong(10.0),
        ] {
            for (name, wo) in incidences(n) {
                let out = chi2_of(m, n, wo, 200_000, &Chi2Params::with_resolution(32));
                assert!(out.passed, "{m:?} {name}: {out:?}");
            }
        }
    }

    #[test]
    fn chi2_phong_100() {
        let n = test_normal();
        for (name, wo) in incidences(n) {
            let out = chi2_of(
                phong(100.0),
                n,
                wo,
                300_000,
                &Chi2Params::with_resolution(64),
            );
            assert!(out.passed, "{name}: {out:?}");
        }
    }

    /// The e = 1e4 lobe is ~0.01 rad wide, narrower than a bin of the default 32² grid
    /// (0.11 rad): use 512² bins (0.007 rad) and a 12² midpoint grid per bin.
    #[test]
    fn chi2_phong_1e4() {
        let n = test_normal();
        let params = Chi2Params::with_resolution(512).with_subdivisions(12);
        for (name, wo) in incidences(n) {
            let out = chi2_of(phong(1e4), n, wo, 300_000, &params);
            assert!(out.passed, "{name}: {out:?}");
        }
    }

    #[test]
    fn pure_specular_and_black_materials_are_consistent() {
        let n = test_normal();
        let (_, wo) = incidences(n)[1];
        let spec = Material::phong([0.0; 3], [1.0; 3], 30.0).unwrap();
        let out = chi2_of(spec, n, wo, 100_000, &Chi2Params::with_resolution(32));
        assert!(out.passed && out.rejected > 0, "{out:?}");
        let black = Material::phong([0.0; 3], [0.0; 3], 30.0).unwrap();
        let out = chi2_of(black, n, wo, 100_000, &Chi2Params::with_resolution(32));
        assert!(out.passed, "{out:?}");
        let mut cells = vec![1.0; 1024];
        black.product_cells(n, wo, 5, &mut cells);
        assert!(cells.iter().all(|&c| c == 0.0));
    }

    #[test]
    fn below_the_surface_is_zero_and_nan_is_harmless() {
        let n = Vec3::Y;
        let up = Vec3::new(0.1, 0.9, 0.0).normalize();
        let down = Vec3::new(0.1, -0.9, 0.0).normalize();
        let tangent = Vec3::X;
        for m in [Material::DEFAULT, phong(50.0)] {
            for (wo, wi) in [
                (up, down),
                (down, up),
                (tangent, up),
                (up, tangent),
                (Vec3::NAN, up),
            ] {
                assert_eq!(m.eval(n, wo, wi), Vec3::ZERO);
                assert_eq!(m.pdf(n, wo, wi), 0.0);
            }
            assert_eq!(m.sample(n, down, 0.5, Vec2::splat(0.5)), None);
            assert_eq!(m.sample(n, Vec3::NAN, 0.5, Vec2::splat(0.5)), None);
            let mut cells = vec![1.0; 64];
            m.product_cells(n, down, 3, &mut cells);
            assert!(cells.iter().all(|&c| c == 0.0));
            m.product_cells(Vec3::NAN, up, 3, &mut cells);
            assert!(cells.iter().all(|&c| c == 0.0));
        }
        // Extreme sample coordinates stay finite.
        for u in [
            Vec2::ZERO,
            Vec2::new(0.0, 0.999_999_9),
            Vec2::splat(0.999_999_9),
        ] {
            for m in [Material::DEFAULT, phong(1e4)] {
                for uc in [0.0, 0.999_999_9] {
                    if let Some(wi) = m.sample(n, up, uc, u) {
                        assert!(wi.is_finite() && (wi.length() - 1.0).abs() < 1e-5);
                    }
                }
            }
        }
    }

    #[test]
    fn reciprocity() {
        for m in [Material::DEFAULT, phong(1.0), phong(100.0), phong(1e4)] {
            for i in 0..10_000 {
                let n = rand_dir(1, i);
                let a = rand_dir(2, i);
                // Every tenth pair near the mirror configuration, where the lobe is large.
                let b = if i % 10 == 0 {
                    let r = (2.0 * n.dot(a) * n - a).normalize();
                    at_angle(r, 0.005, i as f32)
                } else {
                    rand_dir(3, i)
                };
                let (fab, fba) = (m.eval(n, a, b), m.eval(n, b, a));
                // f32 inputs: cos α is known to ~1e-7, so the lobe to ~e · 1e-7 relative.
                let e = match m {
                    Material::Phong { exponent, .. } => exponent,
                    _ => 0.0,
                };
                let tol = (1e-5 + 2e-7 * e) * fab.max_element() + 1e-7;
                assert!(
                    (fab - fba).abs().max_element() <= tol,
                    "{m:?} {n} {a} {b}: {fab} vs {fba}"
                );
            }
        }
    }

    #[test]
    fn energy_conservation_at_every_incidence() {
        let n = test_normal();
        let mats = [
            Material::lambert([1.0; 3]).unwrap(),
            Material::phong([0.5; 3], [0.5; 3], 1.0).unwrap(),
            Material::phong([0.0; 3], [1.0; 3], 1.0).unwrap(),
            Material::phong([0.2; 3], [0.8; 3], 10.0).unwrap(),
            Material::phong([0.0; 3], [1.0; 3], 100.0).unwrap(),
            Material::phong([0.1; 3], [0.9; 3], 1e4).unwrap(),
        ];
        for m in mats {
            for deg in [0.0f32, 30.0, 60.0, 80.0, 89.0, 89.9] {
                let wo = at_angle(n, deg.to_radians(), 0.3);
                let (mean, se) = m.directional_albedo(n, wo, 20_000, 5);
                for c in 0..3 {
                    assert!(
                        mean[c] <= 1.0 + 4.0 * se[c] + 1e-9,
                        "{m:?} at {deg}°: {mean} ± {se}"
                    );
                }
                if deg == 0.0 {
                    // At normal incidence kd + ks = 1 reflects everything (the lobe lies above the surface).
                    for c in 0..3 {
                        assert!(mean[c] > 0.99 - 4.0 * se[c], "{m:?}: {mean} ± {se}");
                    }
                }
            }
        }
    }

    #[test]
    fn lambert_albedo_is_the_albedo() {
        let m = Material::lambert([0.8, 0.5, 0.2]).unwrap();
        let n = test_normal();
        for (name, wo) in incidences(n) {
            // Importance sampling a Lambertian is exact (zero variance); also check uniform
            // hemisphere sampling, which has a proper standard error.
            let (mean, se) = m.directional_albedo(n, wo, 10_000, 9);
            assert!(
                (mean - DVec3::new(0.8, 0.5, 0.2)).abs().max_element()
                    < 1e-5 + 4.0 * se.max_element(),
                "{name}: {mean}"
            );
            let k = 100_000u64;
            let (mut s, mut s2) = (0.0f64, 0.0f64);
            for i in 0..k {
                let d = rand_dir(21, i);
                let d = if d.dot(n) < 0.0 {
                    d - 2.0 * d.dot(n) * n
                } else {
                    d
                };
                let x =
                    m.eval(n, wo, d).x as f64 * n.dot(d).max(0.0) as f64 * std::f64::consts::TAU;
                s += x;
                s2 += x * x;
            }
            let mean = s / k as f64;
            let se = ((s2 / k as f64 - mean * mean) / (k - 1) as f64).sqrt();
            assert!((mean - 0.8).abs() < 4.0 * se, "{name}: {mean} ± {se}");
        }
    }

    /// The cones contain their cells: a 4x denser border walk and a 64² interior grid of
    /// every cell stay within the half-angle (which itself is within a few per cent of the
    /// measured maximum, so it is not wastefully loose).
    #[test]
    fn cell_cones_contain_their_cells() {
        for level in [1, 3, 5, 7] {
            let t = CellCones::get(level);
            let res = 1u32 << level;
            let k = 4 * border_samples(level);
            let worst: Vec<(f64, f64)> = (0..res * res)
                .into_par_iter()
                .map(|code| {
                    let cell = morton_decode(code);
                    let c = DVec3::new(
                        t.cx[code as usize] as f64,
                        t.cy[code as usize] as f64,
                        t.cz[code as usize] as f64,
                    );
                    let a = t.half_angle[code as usize] as f64;
                    let mut far = 0.0f64;
                    let mut check = |p: Vec2| {
                        let d = square_to_sphere((cell.as_vec2() + p) / res as f32)
                            .as_dvec3()
                            .normalize();
                        far = far.max(angle_between(c, d));
                    };
                    for i in 0..=k {
                        let j = i as f32 / k as f32;
                        for p in [
                            Vec2::new(j, 0.0),
                            Vec2::new(1.0, j),
                            Vec2::new(j, 1.0),
                            Vec2::new(0.0, j),
                        ] {
                            check(p);
                        }
                    }
                    for i in 0..64 {
                        for j in 0..64 {
                            check((Vec2::new(i as f32, j as f32) + 0.5) / 64.0);
                        }
                    }
                    (far, a)
                })
                .collect();
            for (code, &(far, a)) in worst.iter().enumerate() {
                assert!(far <= a, "level {level} cell {code}: {far} > {a}");
                assert!(
                    a <= far * 1.05 + 2e-5,
                    "level {level} cell {code}: cone {a} loose vs {far}"
                );
            }
        }
    }

    fn lum_fcos(m: &Material, n: Vec3, wo: Vec3, wi: Vec3) -> f32 {
        let f = m.eval(n, wo, wi);
        luminance([f.x, f.y, f.z]) * n.dot(wi).max(0.0)
    }

    /// Points of cell `cell` of a `res` grid: a `sub²` interior grid and `sub` points per
    /// edge (corners included).
    fn cell_points(cell: UVec2, res: u32, sub: u32) -> impl Iterator<Item = Vec3> {
        let interior = (0..sub * sub)
            .map(move |i| (Vec2::new((i % sub) as f32, (i / sub) as f32) + 0.5) / sub as f32);
        let border = (0..=sub).flat_map(move |i| {
            let j = i as f32 / sub as f32;
            [
                Vec2::new(j, 0.0),
                Vec2::new(1.0, j),
                Vec2::new(j, 1.0),
                Vec2::new(0.0, j),
            ]
        });
        interior
            .chain(border)
            .map(move |p| square_to_sphere((cell.as_vec2() + p) / res as f32))
    }

    /// No cell where f cos θ > 0 anywhere gets B~ = 0: random normals, wo from normal to
    /// 1e-3 above the horizon, Lambert and Phong up to e = 1e4, each cell sampled on a 16²
    /// grid plus its border plus the exact mirror direction.
    #[test]
    fn product_cells_are_conservative() {
        let mats = [
            Material::lambert([0.5, 0.2, 0.9]).unwrap(),
            phong(10.0),
            Material::phong([0.0; 3], [1.0; 3], 100.0).unwrap(),
            Material::phong([0.0; 3], [1.0; 3], 1e4).unwrap(),
            phong(1e4),
        ];
        let cos_o = [1.0f32, 0.7, 0.2, 0.03, 1e-2, 1e-3];
        let cases: Vec<(usize, Vec3, Vec3, u32)> = (0..60u64)
            .map(|i| {
                let n = if i < 4 {
                    [Vec3::Y, -Vec3::Y, Vec3::X, test_normal()][i as usize]
                } else {
                    rand_dir(31, i)
                };
                let wo = at_angle(
                    n,
                    cos_o[(i % 6) as usize].acos(),
                    6.0 * to_unit_f32(hash4(32, i, 0, 0)),
                );
                let level = [5, 5, 5, 3, 6][(i % 5) as usize];
                ((i % 5) as usize, n, wo, level)
            })
            .collect();
        let failures: Vec<String> = cases
            .par_iter()
            .flat_map_iter(|&(mi, n, wo, level)| {
                let m = mats[mi];
                let res = 1u32 << level;
                let mut cells = vec![0.0f32; 1 << (2 * level)];
                m.product_cells(n, wo, level, &mut cells);
                let mut bad = Vec::new();
                assert!(cells.iter().all(|c| c.is_finite() && *c >= 0.0));
                for code in 0..cells.len() as u32 {
                    let cell = morton_decode(code);
                    let positive = cell_points(cell, res, 16).any(|d| lum_fcos(&m, n, wo, d) > 0.0);
                    if positive && cells[code as usize] <= 0.0 {
                        bad.push(format!("{m:?} n={n} wo={wo} level {level} cell {cell}"));
                    }
                }
                let r = (2.0 * n.dot(wo) * n - wo).normalize();
                let rc = texel_of(r, res);
                if lum_fcos(&m, n, wo, r) > 0.0 && cells[morton_encode(rc.x, rc.y) as usize] <= 0.0
                {
                    bad.push(format!("mirror cell {rc} of {m:?} n={n} wo={wo}"));
                }
                bad
            })
            .collect();
        assert!(
            failures.is_empty(),
            "{} failures, e.g. {:?}",
            failures.len(),
            &failures[..failures.len().min(5)]
        );
    }

    /// B~ is zero for cells whose cone is below the horizon, and cells that lie entirely
    /// below it (by dense sampling) but whose cone still reaches above get at most the
    /// bound floor: together a negligible share of the total.
    #[test]
    fn product_cells_vanish_below_the_horizon() {
        for (i, m) in [Material::DEFAULT, phong(100.0), phong(1e4)]
            .into_iter()
            .enumerate()
        {
            for j in 0..10u64 {
                let n = rand_dir(41, j + 10 * i as u64);
                let wo = at_angle(n, [0.0f32, 1.0, 1.5, 1.569][(j % 4) as usize], j as f32);
                let t = CellCones::get(5);
                let mut cells = vec![0.0f32; 1024];
                m.product_cells(n, wo, 5, &mut cells);
                let total: f64 = cells.iter().map(|&c| c as f64).sum();
                let mut below_mass = 0.0f64;
                for k in 0..1024usize {
                    let c = Vec3::new(t.cx[k], t.cy[k], t.cz[k]);
                    let theta_c = n.dot(c).clamp(-1.0, 1.0).acos();
                    if theta_c - t.half_angle[k] >= std::f32::consts::FRAC_PI_2 + 1e-4 {
                        assert_eq!(cells[k], 0.0, "cone below the horizon, cell {k}");
                    }
                    let all_below =
                        cell_points(morton_decode(k as u32), 32, 16).all(|d| n.dot(d) <= 0.0);
                    if all_below {
                        below_mass += cells[k] as f64;
                    }
                }
                assert!(
                    below_mass <= 2e-3 * total,
                    "{m:?}: {below_mass} of {total} below the horizon"
                );
            }
        }
    }

    /// Points that share a normal and a material whose product ignores the view share
    /// their cells bit for bit (the renderer then reuses `J`); a specular lobe follows the
    /// view.
    #[test]
    fn product_cells_ignore_the_view_unless_the_material_says_otherwise() {
        let diffuse_phong = Material::phong([0.5; 3], [0.0; 3], 50.0).unwrap();
        for (m, depends) in [
            (Material::DEFAULT, false),
            (diffuse_phong, false),
            (phong(100.0), true),
        ] {
            assert_eq!(m.product_depends_on_wo(), depends, "{m:?}");
            for j in 0..10u64 {
                let n = rand_dir(43, j);
                let cells = |angle: f32| {
                    let mut out = vec![0.0f32; 1024];
                    m.product_cells(n, at_angle(n, angle, j as f32), 5, &mut out);
                    out
                };
                let (a, b) = (cells(0.2), cells(1.2));
                assert!(a.iter().any(|&c| c > 0.0));
                let same = a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits());
                assert_eq!(same, !depends, "{m:?}, normal {n}");
            }
        }
    }

    /// Sampling efficiency `I² / E[(g/p)²]` (1 = perfect) of a piecewise-constant pdf with
    /// the given per-cell weights, for the integrand `g = lum(f) cos` sampled on `sub²`
    /// points per cell.
    fn efficiency(weights: &[f32], g_mean: &[f64], g2_mean: &[f64], omega: f64) -> f64 {
        let wsum: f64 = weights.iter().map(|&w| w as f64).sum();
        let integral: f64 = g_mean.iter().sum::<f64>() * omega;
        let mut second = 0.0;
        for k in 0..weights.len() {
            if g2_mean[k] > 0.0 {
                let p = weights[k] as f64 / (wsum * omega);
                second += if p > 0.0 {
                    g2_mean[k] * omega / p
                } else {
                    f64::INFINITY
                };
            }
        }
        integral * integral / second
    }

    /// Quality of B~ against the best piecewise-constant approximation (exact cell means)
    /// and against plain centre values; prints a table (run with --nocapture).
    #[test]
    fn product_cells_approximate_the_cell_means() {
        let n = test_normal();
        let t = CellCones::get(5);
        let omega = t.cell_solid_angle as f64;
        let mut worst = Vec::new();
        for m in [
            Material::DEFAULT,
            phong(10.0),
            phong(100.0),
            phong(1000.0),
            phong(1e4),
        ] {
            for (name, wo) in incidences(n) {
                let mut cells = vec![0.0f32; 1024];
                m.product_cells(n, wo, 5, &mut cells);
                let sub = 32;
                let (mut gm, mut g2m, mut centre) =
                    (vec![0.0; 1024], vec![0.0; 1024], vec![0.0f32; 1024]);
                for k in 0..1024 {
                    let cell = morton_decode(k as u32);
                    let (mut s, mut s2) = (0.0f64, 0.0f64);
                    for d in cell_points(cell, 32, sub).take((sub * sub) as usize) {
                        let g = lum_fcos(&m, n, wo, d) as f64;
                        s += g;
                        s2 += g * g;
                    }
                    gm[k] = s / (sub * sub) as f64;
                    g2m[k] = s2 / (sub * sub) as f64;
                    centre[k] = lum_fcos(&m, n, wo, Vec3::new(t.cx[k], t.cy[k], t.cz[k]));
                }
                let exact: Vec<f32> = gm.iter().map(|&g| g as f32).collect();
                let (eb, ee, ec) = (
                    efficiency(&cells, &gm, &g2m, omega),
                    efficiency(&exact, &gm, &g2m, omega),
                    efficiency(&centre, &gm, &g2m, omega),
                );
                let sum_b: f64 = cells.iter().map(|&c| c as f64).sum::<f64>() * omega;
                let sum_e: f64 = gm.iter().sum::<f64>() * omega;
                println!("{:>28} {name:>8}: efficiency B~ {eb:.3}  exact means {ee:.3}  centres {ec:.3}  ∫B~/∫B {:.3}", format!("{m:?}").chars().take(28).collect::<String>(), sum_b / sum_e);
                if eb < 0.5 * ee {
                    worst.push(format!("{m:?} {name}: {eb} vs {ee}"));
                }
            }
        }
        assert!(worst.is_empty(), "{worst:?}");
    }

    #[test]
    fn sphere_to_square_is_the_cell_lookup() {
        // B~ cells are indexed by the same map the samplers use.
        let d = test_normal();
        let p = sphere_to_square(d) * 32.0;
        let c = texel_of(d, 32);
        assert_eq!(c, UVec2::new(p.x as u32, p.y as u32));
    }
}
