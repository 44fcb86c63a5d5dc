//! VF eq. 5-6: gathering. Each pixel of the indirect-resolution G-buffer reads the
//! filtered lists of its four nearest low-resolution pixels, weighted bilinearly (`w_l`)
//! times the joint bilateral weight `w_G` ([`super::Surfel::weight`]) and normalised by
//! their sum `N_c`; a voxel in several lists gets the sum of its lists' weights, so it is
//! shaded once. A voxel whose centroid lies nearer than `R` (`sh_range`) gives the sum of
//! its VPLs' terms without visibility (eq. 6, first case: [`Vpl::connect`], the receiver's
//! BSDF at each VPL's direction, the many-light renderer's term); a farther one its SH
//! intensity towards the pixel ([`super::sh`]) with the receiver's BSDF at the centroid's
//! direction (second case).
//!
//! Where no neighbour lies on the pixel's surface (`N_c = 0`), the neighbours that saw a
//! surface count by `w_l` alone; a pixel with none of those, or a miss, gets zero.
//!
//! The receiver's BSDF is Phong's diffuse plus specular term; eq. 7 weights the specular
//! term towards each light by a Gaussian in `1 - cos^η θ` (θ: the angle between the light's
//! direction and the mirror direction of the view, η the Phong exponent) of width
//! `σ_θ` ([`specular_weight`]). The paper's `1 / (σ_θ √(2π))` is left out so that the
//! weight peaks at 1 and `σ_θ = ∞` (the default) is Phong's term unweighted, equal to
//! `method="vpl"`'s shading.
//!
//! [`Visibility::Traced`] replaces the lists by one shadow ray per VPL: the exact sum of
//! `method="vpl"` over the same set.

use glam::{DVec3, Vec3};

use super::grid::{index_points, GridFrame, VoxelIndex};
use super::march::Lists;
use super::sh::{project_voxel, VoxelSh};
use super::{Surfel, Visibility};
use crate::bsdf::Material;
use crate::camera::GBuffer;
use crate::error::Result;
use crate::estimators::indirect::shading_point_at;
use crate::estimators::many_lights::light_paths::{Connection, Receiver};
use crate::geometry::{Scene, TraversalCounters};
use crate::lights::vpl::{Vpl, VplSet};

/// Eq. 7's weight `exp(-½ ((1 - cos^η θ) / σ_θ)²)` of a specular term whose light lies at
/// `cos_theta` from the mirror direction (clamped to `[0, 1]`), for Phong exponent `eta`;
/// 1 for `sigma = ∞`. In `(0, 1]`, 1 at θ = 0, decreasing in θ.
#[inline]
pub fn specular_weight(eta: f32, cos_theta: f32, sigma: f32) -> f32 {
    if sigma == f32::INFINITY {
        return 1.0;
    }
    let x = (1.0 - cos_theta.clamp(0.0, 1.0).powf(eta)) / sigma;
    (-0.5 * x * x).exp()
}

/// The receiver's BSDF `f_x(ωo, wi)` with eq. 7's weight on Phong's specular part
/// (`sigma = ∞`: [`Material::eval`]).
#[inline]
pub fn weighted_f(material: &Material, n: Vec3, wo: Vec3, wi: Vec3, sigma: f32) -> Vec3 {
    let full = material.eval(n, wo, wi);
    match *material {
        Material::Phong { kd, exponent, .. } if sigma != f32::INFINITY && full != Vec3::ZERO => {
            let diffuse = Vec3::from(kd) * std::f32::consts::FRAC_1_PI;
            let r = 2.0 * n.dot(wo) * n - wo;
            let cos = r.dot(wi) / r.length();
            diffuse + (full - diffuse).max(Vec3::ZERO) * specular_weight(exponent, cos, sigma)
        }
        _ => full,
    }
}

/// The VPLs sorted into voxels with each voxel's SH (eq. 2).
#[derive(Clone, Debug)]
pub struct VoxelLights {
    /// Each VPL in the voxel that holds its position.
    pub index: VoxelIndex,
    pub vpls: Vec<Vpl>,
    /// Per entry of `index`.
    pub sh: Vec<VoxelSh>,
    /// The VPLs in `index.items` order as lanes, for voxels of diffuse VPLs.
    lanes: Lanes,
}

/// Diffuse VPLs as structure of arrays, in `index.items` order: origin, normal and
/// intensity `Φ f_v` (W/sr per channel). A diffuse receiver's terms over a voxel's VPLs
/// are then one loop the compiler vectorises (the many-light renderer's tile lanes turned
/// round: one receiver, many VPLs).
#[derive(Clone, Debug, Default)]
struct Lanes {
    o: [Vec<f32>; 3],
    n: [Vec<f32>; 3],
    i: [Vec<f32>; 3],
    /// Per entry: every VPL of it is diffuse.
    diffuse: Vec<bool>,
}

/// Accumulators per lane group.
const WIDTH: usize = 8;

impl Lanes {
    fn new(index: &VoxelIndex, vpls: &[Vpl]) -> Self {
        let mut l = Lanes::default();
        for &k in &index.items {
            let v = &vpls[k as usize];
            let i = v.diffuse_intensity().unwrap_or(Vec3::ZERO);
            for a in 0..3 {
                l.o[a].push(v.origin[a]);
                l.n[a].push(v.normal[a]);
                l.i[a].push(i[a]);
            }
        }
        l.diffuse = (0..index.entries.len())
            .map(|e| {
                index
                    .range(e)
                    .iter()
                    .all(|&k| vpls[k as usize].diffuse_intensity().is_some())
            })
            .collect();
        l
    }

    /// `Σ Φ f_v cos θ_x cos θ_v / d²` over items `range` at a receiver at `o` with normal
    /// `n` (multiply by the receiver's `f_x`): [`Vpl::connect`]'s terms without
    /// visibility, summed in a fixed order.
    // One index runs through several arrays at once: the lanes' layout.
    #[allow(clippy::needless_range_loop)]
    #[inline]
    fn sum(&self, range: std::ops::Range<usize>, o: Vec3, n: Vec3) -> Vec3 {
        let mut acc = [[0.0f32; WIDTH]; 3];
        let (ox, oy, oz) = (
            &self.o[0][range.clone()],
            &self.o[1][range.clone()],
            &self.o[2][range.clone()],
        );
        let (nx, ny, nz) = (
            &self.n[0][range.clone()],
            &self.n[1][range.clone()],
            &self.n[2][range.clone()],
        );
        let (ir, ig, ib) = (
            &self.i[0][range.clone()],
            &self.i[1][range.clone()],
            &self.i[2][range],
        );
        let len = ox.len();
        let mut k = 0;
        while k < len {
            let m = WIDTH.min(len - k);
            for j in 0..m {
                let q = k + j;
                let (dx, dy, dz) = (ox[q] - o.x, oy[q] - o.y, oz[q] - o.z);
                let sx = n.x * dx + n.y * dy + n.z * dz;
                let sv = -(nx[q] * dx + ny[q] * dy + nz[q] * dz);
                let d2 = dx * dx + dy * dy + dz * dz;
                let g = if sx > 0.0 && sv > 0.0 {
                    sx * sv / (d2 * d2)
                } else {
                    0.0
                };
                acc[0][j] += g * ir[q];
                acc[1][j] += g * ig[q];
                acc[2][j] += g * ib[q];
            }
            k += WIDTH;
        }
        Vec3::new(
            acc[0].iter().sum(),
            acc[1].iter().sum(),
            acc[2].iter().sum(),
        )
    }
}

impl VoxelLights {
    /// Sorts `set`'s VPLs into `frame`'s voxels (`slots`: [`VoxelIndex::build`]) and
    /// projects each voxel.
    pub fn build(frame: GridFrame, set: &VplSet, slots: Option<u32>) -> Result<Self> {
        let points: Vec<Vec3> = set.vpls.iter().map(|v| v.position).collect();
        let index = index_points(frame, &points, slots)?;
        let sh = (0..index.entries.len())
            .map(|e| project_voxel(index.range(e).iter().map(|&i| &set.vpls[i as usize])))
            .collect();
        let lanes = Lanes::new(&index, &set.vpls);
        Ok(Self {
            index,
            vpls: set.vpls.clone(),
            sh,
            lanes,
        })
    }

    /// Eq. 6 for the voxel of `key` at receiver `r`: its VPLs' terms when its centroid is
    /// nearer than `sh_range` (a diffuse receiver of a voxel of diffuse VPLs sums them
    /// in lanes, equal to [`Vpl::connect`]'s terms to rounding), else its SH's; zero for
    /// an empty voxel. Counts the VPL terms and SH lookups in `counts`.
    #[inline]
    pub fn voxel_light(
        &self,
        key: u64,
        r: &Receiver,
        sh_range: f32,
        specular_sigma: f32,
        counts: &mut GatherCounts,
    ) -> DVec3 {
        let Some(e) = self.index.entry_of_key(key) else {
            return DVec3::ZERO;
        };
        let sh = &self.sh[e];
        let sp = &r.sp;
        let to = sh.centroid - sp.origin;
        let d2 = to.length_squared();
        if d2 < sh_range * sh_range || sh_range == f32::INFINITY {
            let entry = &self.index.entries[e];
            counts.vpl_terms += (entry.end - entry.start) as u64;
            if let (Some(f), true) = (r.diffuse(), self.lanes.diffuse[e]) {
                let range = entry.start as usize..entry.end as usize;
                return (f * self.lanes.sum(range, sp.origin, sp.normal)).as_dvec3();
            }
            let mut sum = DVec3::ZERO;
            for &i in self.index.range(e) {
                if let Some(c) = self.vpls[i as usize].connect(r, None, 0.0) {
                    sum += weighted(&c, r, specular_sigma).as_dvec3();
                }
            }
            return sum;
        }
        counts.sh_terms += 1;
        let d = d2.sqrt();
        let w = to / d;
        let cos = sp.normal.dot(w);
        if !(cos > 0.0 && d2 > 0.0) {
            return DVec3::ZERO;
        }
        let f = weighted_f(&sp.material, sp.normal, sp.wo, w, specular_sigma).as_dvec3();
        f * sh.intensity(-w) * (cos / d2) as f64
    }

    /// Every VPL's term with its own shadow ray, in VPL order.
    pub fn traced(
        &self,
        scene: &Scene,
        r: &Receiver,
        specular_sigma: f32,
        counts: &mut GatherCounts,
        bvh: &mut TraversalCounters,
    ) -> DVec3 {
        let mut sum = DVec3::ZERO;
        for v in &self.vpls {
            counts.vpl_terms += 1;
            if let Some(c) = v.connect(r, None, 0.0) {
                counts.shadow_rays += 1;
                if !scene.occluded1(c.origin, c.direction, c.tmax, bvh) {
                    sum += weighted(&c, r, specular_sigma).as_dvec3();
                }
            }
        }
        sum
    }
}

/// A surface VPL's term `c` at `r` with eq. 7's weight: its `f_x` factor replaced by
/// [`weighted_f`]'s, channel by channel (unchanged for `sigma = ∞` or a Lambert receiver).
#[inline]
fn weighted(c: &Connection, r: &Receiver, sigma: f32) -> Vec3 {
    if sigma == f32::INFINITY || r.diffuse().is_some() {
        return c.value;
    }
    let sp = &r.sp;
    // A point VPL's ray runs from it to the receiver (the light arrives from
    // -direction); a map direction's (unbounded) from the receiver towards it.
    let wi = if c.tmax == f32::INFINITY {
        c.direction
    } else {
        -c.direction
    };
    let full = sp.material.eval(sp.normal, sp.wo, wi);
    let w = weighted_f(&sp.material, sp.normal, sp.wo, wi, sigma);
    Vec3::from_array(std::array::from_fn(|k| {
        if full[k] > 0.0 {
            c.value[k] * (w[k] / full[k])
        } else {
            0.0
        }
    }))
}

/// Work of a gather.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct GatherCounts {
    /// VPL terms evaluated (eq. 6, first case, or every VPL when traced).
    pub vpl_terms: u64,
    /// Voxels shaded by their SH (second case).
    pub sh_terms: u64,

    /// Shadow rays ([`Visibility::Traced`]).
    pub shadow_rays: u64,
}

impl std::ops::AddAssign for GatherCounts {
    fn add_assign(&mut self, o: Self) {
        self.vpl_terms += o.vpl_terms;
        self.sh_terms += o.sh_terms;

        self.shadow_rays += o.shadow_rays;
    }
}

/// What the gather reads of the low-resolution stages.
#[derive(Clone, Copy)]
pub struct LowRes<'a> {
    pub lists: &'a Lists,
    pub surfels: &'a [Surfel],
    pub width: usize,
    pub height: usize,
}

/// The four low-resolution neighbours of pixel `(x, y)` of a `w x h` image and their
/// bilinear weights (pixel centres aligned; clamped at the borders).
#[inline]
pub fn bilinear(x: usize, y: usize, w: usize, h: usize, lw: usize, lh: usize) -> [(usize, f32); 4] {
    let axis = |x: usize, n: usize, ln: usize| {
        let f = (x as f32 + 0.5) * (ln as f32 / n as f32) - 0.5;
        let x0 = (f.floor().max(0.0) as usize).min(ln - 1);
        let x1 = (x0 + 1).min(ln - 1);
        let a = (f - x0 as f32).clamp(0.0, 1.0);
        (x0, x1, a)
    };
    let (x0, x1, ax) = axis(x, w, lw);
    let (y0, y1, ay) = axis(y, h, lh);
    [
        (y0 * lw + x0, (1.0 - ax) * (1.0 - ay)),
        (y0 * lw + x1, ax * (1.0 - ay)),
        (y1 * lw + x0, (1.0 - ax) * ay),
        (y1 * lw + x1, ax * ay),
    ]
}

/// Eq. 5 at every pixel of `gbuffer` (the indirect resolution): the indirect radiance
/// (W/(m² sr) per channel), row-major, and the work. Deterministic; polls the current
/// stop between rows.
#[allow(clippy::too_many_arguments)]
pub fn gather(
    scene: &Scene,
    gbuffer: &GBuffer,
    low: LowRes<'_>,
    lights: &VoxelLights,
    sh_range: f32,
    specular_sigma: f32,
    depth_tol: f32,
    normal_tol: f32,
    visibility: Visibility,
) -> Result<(Vec<DVec3>, GatherCounts)> {
    let (w, h) = (gbuffer.width() as usize, gbuffer.height() as usize);
    let rows: Vec<usize> = (0..h).collect();
    let per_row = crate::parallel::map_in_order(&rows, |&y| {
        let mut out = Vec::with_capacity(w);
        let mut counts = GatherCounts::default();
        let mut bvh = TraversalCounters::default();
        let mut weighted: Vec<(u64, f32)> = Vec::new();
        for x in 0..w {
            let p = y * w + x;
            let Some(hit) = gbuffer.surface_hit(p) else {
                out.push(DVec3::ZERO);
                continue;
            };
            let dir = Vec3::from(gbuffer.direction[p]);
            let sp = shading_point_at(scene, &hit, -dir);
            let r = Receiver::new(scene, sp);
            if visibility == Visibility::Traced {
                out.push(lights.traced(scene, &r, specular_sigma, &mut counts, &mut bvh));
                continue;
            }
            let me = Surfel {
                depth: gbuffer.depth[p],
                normal: Vec3::from(gbuffer.normal[p]),
            };
            let near = bilinear(x, y, w, h, low.width, low.height);
            let mut ws = near.map(|(q, wl)| wl * me.weight(&low.surfels[q], depth_tol, normal_tol));
            let mut nc: f32 = ws.iter().sum();
            if nc.is_nan() || nc <= 0.0 {
                ws = near.map(|(q, wl)| {
                    if low.surfels[q].depth.is_finite() {
                        wl
                    } else {
                        0.0
                    }
                });
                nc = ws.iter().sum();
            }
            if nc.is_nan() || nc <= 0.0 {
                out.push(DVec3::ZERO);
                continue;
            }
            weighted.clear();
            for ((q, _), wq) in near.iter().zip(ws) {
                if wq > 0.0 {
                    weighted.extend(low.lists.get(*q).iter().map(|&k| (k, wq / nc)));
                }
            }
            weighted.sort_by_key(|&(k, _)| k);
            let mut sum = DVec3::ZERO;
            let mut i = 0;
            while i < weighted.len() {
                let key = weighted[i].0;
                let mut wk = 0.0f64;
                while i < weighted.len() && weighted[i].0 == key {
                    wk += weighted[i].1 as f64;
                    i += 1;
                }
                sum += lights.voxel_light(key, &r, sh_range, specular_sigma, &mut counts) * wk;
            }
            out.push(sum);
        }
        scene.add_counters(bvh);
        (out, counts)
    })?;
    let mut counts = GatherCounts::default();
    let mut image = Vec::with_capacity(w * h);
    for (row, c) in per_row {
        image.extend(row);
        counts += c;
    }
    Ok((image, counts))
}
