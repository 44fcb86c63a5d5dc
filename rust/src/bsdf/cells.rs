//! B~ ([`Material::product_cells`]): the conservative per-cell approximation of the
//! reflectance that product importance sampling multiplies with the lighting.
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
//! resolve such lobes; plain centre values are biased there, efficiency 0). Cost: see
//! `benches/bsdf.rs`.

use glam::{DVec3, Vec2, Vec3};
use std::sync::OnceLock;

use super::{is_above, luminance, mirror, Material};
use crate::sampling::octahedral::{morton_decode, square_to_sphere};

impl Material {
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
pub(super) fn border_samples(level: u32) -> u32 {
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
pub(super) fn angle_between(a: DVec3, b: DVec3) -> f64 {
    a.cross(b).length().atan2(a.dot(b))
}

/// `2^x`, relative error ≈ 2e-7, for `x ≥ -126` (clamped below); branch-free.
#[inline(always)]
pub(super) fn fast_exp2(x: f32) -> f32 {
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
pub(super) fn fast_log2(x: f32) -> f32 {
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
