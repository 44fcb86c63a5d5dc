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
    /// Per entry of diffuse VPLs, those VPLs merged by [`MERGE_CELLS`]³ sub-cell and
    /// normal ([`merge`]), and each entry's range of them: what a receiver farther than
    /// the merge range from the voxel sums instead of the VPLs themselves.
    coarse: Lanes,
    coarse_ranges: Vec<std::ops::Range<usize>>,
    /// Per entry: what decides that none of its VPLs can light a receiver.
    bounds: Vec<VoxelBounds>,
}

/// The extent of a voxel's VPLs that lets a receiver skip them all: the box of their
/// positions (none lies above the receiver's tangent plane when no corner does) and, when
/// they share one normal (a flat patch), the least offset of their plane (the receiver
/// lies behind every one of them when it lies behind that).
#[derive(Clone, Copy, Debug)]
struct VoxelBounds {
    lo: Vec3,
    hi: Vec3,
    /// The common normal and `min n·o` over the VPLs, if every normal is the same.
    plane: Option<(Vec3, f32)>,
    /// Slack of the tests (world units): a part in 1e5 of the box's diagonal and of its
    /// distance from the origin. Coplanar VPLs (a receiver on the patch itself, whose
    /// terms are zero but whose tests round either way) are culled; a VPL within the
    /// slack above the tangent plane is dropped with its term, of cosine at most
    /// `slack / d`.
    slack: f32,
}

impl VoxelBounds {
    fn new<'a>(vpls: impl Iterator<Item = &'a Vpl>) -> Self {
        let (mut lo, mut hi) = (Vec3::INFINITY, Vec3::NEG_INFINITY);
        let mut normal: Option<Vec3> = None;
        let mut shared = true;
        let mut offset = f32::INFINITY;
        for v in vpls {
            lo = lo.min(v.origin);
            hi = hi.max(v.origin);
            match normal {
                None => normal = Some(v.normal),
                Some(n) if n != v.normal => shared = false,
                _ => {}
            }
            offset = offset.min(v.normal.dot(v.origin));
        }
        let scale = (hi - lo).length() + lo.abs().max(hi.abs()).length();
        Self {
            lo,
            hi,
            plane: normal.filter(|_| shared).map(|n| (n, offset)),
            slack: 1e-5 * scale,
        }
    }

    /// True when no VPL of the voxel can reach a receiver at `o` with normal `n`: every
    /// one lies at or below its tangent plane, or (a flat patch) it lies at or behind
    /// theirs, within the slack. Such VPLs' terms are zero (either cosine is) but for
    /// those within the slack.
    #[inline]
    fn dark(&self, o: Vec3, n: Vec3) -> bool {
        // The corner farthest along n.
        let far = Vec3::select(n.cmpge(Vec3::ZERO), self.hi, self.lo);
        if n.dot(far - o) <= self.slack {
            return true;
        }
        match self.plane {
            Some((nv, offset)) => nv.dot(o) - offset <= self.slack,
            None => false,
        }
    }
}

/// Sub-cells per axis of a voxel's VPL box that [`merge`] pools VPLs in.
pub const MERGE_CELLS: usize = 4;

/// A voxel's diffuse VPLs pooled by sub-cell of their box (`MERGE_CELLS`³) and normal
/// (bit for bit): one VPL per pool at the intensity-weighted centroid, with the pool's
/// normal and summed intensity `Σ Φ f_v`, in pool order (deterministic). A receiver at
/// distance `d` sees a pool of size `s` with a relative error of order `(s / d)²` in each
/// term, hence its use only beyond the merge range. Rows are (origin, normal, intensity).
pub fn merge(vpls: &[&Vpl], lo: Vec3, hi: Vec3) -> Vec<(Vec3, Vec3, Vec3)> {
    let extent = (hi - lo).max(Vec3::splat(f32::MIN_POSITIVE));
    let m = MERGE_CELLS as f32;
    // (sub-cell, normal bits) -> (Σ w p, Σ w, Σ intensity, normal).
    type Pool = (DVec3, f64, DVec3, Vec3);
    let mut pools: std::collections::BTreeMap<([u32; 3], [u32; 3]), Pool> =
        std::collections::BTreeMap::new();
    for v in vpls {
        let i = v.diffuse_intensity().unwrap_or(Vec3::ZERO);
        let c = ((v.origin - lo) / extent * m)
            .floor()
            .clamp(Vec3::ZERO, Vec3::splat(m - 1.0));
        let key = (
            [c.x as u32, c.y as u32, c.z as u32],
            v.normal.to_array().map(f32::to_bits),
        );
        let w = (i.x + i.y + i.z) as f64;
        let e = pools
            .entry(key)
            .or_insert((DVec3::ZERO, 0.0, DVec3::ZERO, v.normal));
        e.0 += v.origin.as_dvec3() * w.max(1e-30);
        e.1 += w.max(1e-30);
        e.2 += i.as_dvec3();
    }
    pools
        .into_values()
        .map(|(p, w, i, n)| ((p / w).as_vec3(), n, i.as_vec3()))
        .collect()
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
    /// Lanes of `(origin, normal, intensity)` rows, in order (no per-entry flags).
    fn from_rows(rows: &[(Vec3, Vec3, Vec3)]) -> Self {
        let mut l = Lanes::default();
        for (o, n, i) in rows {
            for a in 0..3 {
                l.o[a].push(o[a]);
                l.n[a].push(n[a]);
                l.i[a].push(i[a]);
            }
        }
        l
    }

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
        let bounds: Vec<VoxelBounds> = (0..index.entries.len())
            .map(|e| VoxelBounds::new(index.range(e).iter().map(|&i| &set.vpls[i as usize])))
            .collect();
        let mut rows = Vec::new();
        let mut coarse_ranges = Vec::with_capacity(index.entries.len());
        for (e, b) in bounds.iter().enumerate() {
            let start = rows.len();
            if lanes.diffuse[e] {
                let vs: Vec<&Vpl> = index
                    .range(e)
                    .iter()
                    .map(|&i| &set.vpls[i as usize])
                    .collect();
                rows.extend(merge(&vs, b.lo, b.hi));
            }
            coarse_ranges.push(start..rows.len());
        }
        let coarse = Lanes::from_rows(&rows);
        Ok(Self {
            index,
            vpls: set.vpls.clone(),
            sh,
            lanes,
            coarse,
            coarse_ranges,
            bounds,
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
        merge_range: f32,
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
            if self.bounds[e].dark(sp.origin, sp.normal) {
                counts.culled_voxels += 1;
                return DVec3::ZERO;
            }
            let entry = &self.index.entries[e];
            if let (Some(f), true) = (r.diffuse(), self.lanes.diffuse[e]) {
                // Beyond the merge range the voxel's pooled VPLs stand in for its VPLs.
                let (lanes, range) = if d2 >= merge_range * merge_range {
                    (&self.coarse, self.coarse_ranges[e].clone())
                } else {
                    (&self.lanes, entry.start as usize..entry.end as usize)
                };
                counts.vpl_terms += range.len() as u64;
                return (f * lanes.sum(range, sp.origin, sp.normal)).as_dvec3();
            }
            counts.vpl_terms += (entry.end - entry.start) as u64;
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
    /// Near voxels skipped whole: every VPL of theirs below the receiver's tangent
    /// plane, or the receiver behind their common plane.
    pub culled_voxels: u64,
    /// Shadow rays ([`Visibility::Traced`]).
    pub shadow_rays: u64,
}

impl std::ops::AddAssign for GatherCounts {
    fn add_assign(&mut self, o: Self) {
        self.vpl_terms += o.vpl_terms;
        self.sh_terms += o.sh_terms;
        self.culled_voxels += o.culled_voxels;
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
    merge_range: f32,
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
            // The four lists are sorted and distinct: merge them, a voxel in several
            // taking the sum of their weights in neighbour order (what a stable sort of
            // their concatenation gave, without its cost).
            let lists: [&[u64]; 4] = std::array::from_fn(|j| {
                if ws[j] > 0.0 {
                    low.lists.get(near[j].0)
                } else {
                    &[]
                }
            });
            let mut heads = [0usize; 4];
            let mut sum = DVec3::ZERO;
            loop {
                let mut key = u64::MAX;
                for j in 0..4 {
                    if let Some(&k) = lists[j].get(heads[j]) {
                        key = key.min(k);
                    }
                }
                if key == u64::MAX {
                    break;
                }
                let mut wk = 0.0f64;
                for j in 0..4 {
                    if lists[j].get(heads[j]) == Some(&key) {
                        wk += (ws[j] / nc) as f64;
                        heads[j] += 1;
                    }
                }
                sum +=
                    lights.voxel_light(key, &r, sh_range, merge_range, specular_sigma, &mut counts)
                        * wk;
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
