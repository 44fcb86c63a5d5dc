//! VF Fig. 2c-d: sparse ray marching. From each pixel of a low-resolution G-buffer,
//! `rays_per_pixel` cosine-distributed rays (stratified over the unit square, jittered
//! per pixel) walk the voxel grid by 3D DDA (Amanatides & Woo 1987), test the discs listed
//! in each voxel they cross and stop at the nearest hit. A hit counts in the voxel being
//! walked only if it lies within the voxel's stretch of the ray, so the first voxel with a
//! hit holds the nearest disc of all (every disc is listed in every voxel its box
//! touches). The pixel keeps the sorted, distinct keys of the voxels that own the hit
//! discs' VPLs (the disc centres' voxels): the light those rays saw.

use glam::{UVec3, Vec3};

use super::grid::{Disc, GridFrame, VoxelIndex};
use crate::camera::GBuffer;
use crate::error::Result;
use crate::estimators::indirect::shading_point_at;
use crate::geometry::Scene;
use crate::math::to_world;
use crate::sampling::rng::{mix64, SampleRng};

/// A ray's nearest disc: its distance along the ray and its index.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DiscHit {
    pub t: f32,
    pub disc: u32,
}

/// The ray–disc test: the distance along unit `d` from `o` to the disc's plane when the
/// crossing lies within the disc, `None` for a ray parallel to the plane (grazing).
#[inline]
pub fn intersect_disc(disc: &Disc, o: Vec3, d: Vec3) -> Option<f32> {
    let denom = disc.normal.dot(d);
    if denom == 0.0 {
        return None;
    }
    let t = disc.normal.dot(disc.centre - o) / denom;
    let p = o + d * t;
    ((p - disc.centre).length_squared() <= disc.radius * disc.radius).then_some(t)
}

/// The nearest disc over all of them with `t` in `[tmin, tmax]` (the reference the
/// marching is tested against).
pub fn brute_force(discs: &[Disc], o: Vec3, d: Vec3, tmin: f32, tmax: f32) -> Option<DiscHit> {
    let mut best: Option<DiscHit> = None;
    for (i, disc) in discs.iter().enumerate() {
        if let Some(t) = intersect_disc(disc, o, d) {
            if t >= tmin && t <= tmax && best.is_none_or(|b| t < b.t) {
                best = Some(DiscHit { t, disc: i as u32 });
            }
        }
    }
    best
}

/// The nearest disc along the ray with `t` in `[tmin, tmax]`, by 3D DDA through `index`
/// (module docs); `d` unit.
pub fn march_ray(
    index: &VoxelIndex,
    discs: &[Disc],
    o: Vec3,
    d: Vec3,
    tmin: f32,
    tmax: f32,
) -> Option<DiscHit> {
    let frame: &GridFrame = &index.frame;
    let (lo, hi) = frame.bounds();
    // The ray's stretch inside the grid's box (slabs).
    let inv = d.recip();
    let (ta, tb) = ((lo - o) * inv, (hi - o) * inv);
    let (tnear, tfar) = (ta.min(tb), ta.max(tb));
    // NaN (0 · inf on a face, a zero direction component) means "no bound on that axis".
    let pick = |v: f32, none: f32| if v.is_nan() { none } else { v };
    let t_in = pick(tnear.x, f32::NEG_INFINITY)
        .max(pick(tnear.y, f32::NEG_INFINITY))
        .max(pick(tnear.z, f32::NEG_INFINITY))
        .max(tmin);
    let t_out = pick(tfar.x, f32::INFINITY)
        .min(pick(tfar.y, f32::INFINITY))
        .min(pick(tfar.z, f32::INFINITY))
        .min(tmax);
    if t_in.is_nan() || t_out.is_nan() || t_in > t_out {
        return None;
    }
    let mut v = frame.voxel_of(o + d * t_in).as_ivec3();
    let dims = UVec3::from(frame.dims).as_ivec3();
    let sign = |c: f32| (c > 0.0) as i32 - (c < 0.0) as i32;
    let step = glam::IVec3::new(sign(d.x), sign(d.y), sign(d.z));
    let next_boundary = |v: glam::IVec3, axis: usize| -> f32 {
        let s = step[axis];
        if s == 0 {
            return f32::INFINITY;
        }
        let face = frame.origin[axis] + (v[axis] + (s > 0) as i32) as f32 * frame.cell[axis];
        (face - o[axis]) / d[axis]
    };
    let mut t_next = Vec3::new(
        next_boundary(v, 0),
        next_boundary(v, 1),
        next_boundary(v, 2),
    );
    let delta = (frame.cell * inv).abs();
    // Hits a rounding past a face still count in the voxel before it: the disc is also
    // listed beyond (its box is grown), so nothing nearer can be missed.
    let slack = |t: f32| t.abs() * 1e-6 + f32::MIN_POSITIVE;
    let mut t_enter = t_in;
    loop {
        let t_exit = t_next.min_element().min(t_out);
        let mut best: Option<DiscHit> = None;
        for &i in index.get(v.as_uvec3()) {
            if let Some(t) = intersect_disc(&discs[i as usize], o, d) {
                if t >= tmin
                    && t <= tmax
                    && t >= t_enter - slack(t_enter)
                    && t <= t_exit + slack(t_exit)
                    && best.is_none_or(|b| t < b.t || (t == b.t && i < b.disc))
                {
                    best = Some(DiscHit { t, disc: i });
                }
            }
        }
        if best.is_some() || t_exit >= t_out {
            return best;
        }
        let axis = if t_next.x <= t_next.y && t_next.x <= t_next.z {
            0
        } else if t_next.y <= t_next.z {
            1
        } else {
            2
        };
        v[axis] += step[axis];
        if v[axis] < 0 || v[axis] >= dims[axis] {
            return None;
        }
        t_enter = t_next[axis];
        t_next[axis] += delta[axis];
    }
}

/// Per-pixel lists of voxel keys, sorted and distinct (compressed rows).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Lists {
    /// `keys[offsets[p]..offsets[p + 1]]` is pixel `p`'s list.
    pub offsets: Vec<usize>,
    pub keys: Vec<u64>,
}

impl Lists {
    /// Lists from per-pixel vectors (each sorted and distinct).
    pub fn from_rows(rows: impl IntoIterator<Item = Vec<u64>>) -> Self {
        let mut out = Lists {
            offsets: vec![0],
            keys: Vec::new(),
        };
        for r in rows {
            out.keys.extend_from_slice(&r);
            out.offsets.push(out.keys.len());
        }
        out
    }

    /// Number of pixels.
    pub fn len(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    /// Whether there is no pixel.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Pixel `p`'s list.
    #[inline]
    pub fn get(&self, p: usize) -> &[u64] {
        &self.keys[self.offsets[p]..self.offsets[p + 1]]
    }

    /// The sum of the lists' lengths.
    pub fn total(&self) -> usize {
        self.keys.len()
    }
}

/// Unit direction `j` of `n` cosine-distributed rays about `normal`: the unit square cut
/// into `⌈√n⌉` columns and as many rows as needed, ray `j` jittered in cell `j`.
#[inline]
pub fn stratified_cosine(j: u32, n: u32, u: [f32; 2], normal: Vec3) -> Vec3 {
    let cols = (n as f32).sqrt().ceil().max(1.0) as u32;
    let rows = n.div_ceil(cols);
    let a = ((j % cols) as f32 + u[0]) / cols as f32;
    let b = ((j / cols) as f32 + u[1]) / rows as f32;
    let r = a.sqrt();
    let phi = std::f32::consts::TAU * b;
    let local = Vec3::new(r * phi.cos(), r * phi.sin(), (1.0 - a).max(0.0).sqrt());
    to_world(local, normal).normalize()
}

/// The marching of every pixel of `gbuffer` (module docs): `rays_per_pixel` rays per hit
/// pixel from its shading point, stream `(seed, pixel, ray)`; `home[i]` is the key of
/// the voxel that owns disc `i`'s light. Misses get empty lists. Polls the current stop
/// between rows; deterministic for any thread count.
pub fn march(
    scene: &Scene,
    gbuffer: &GBuffer,
    index: &VoxelIndex,
    discs: &[Disc],
    home: &[u64],
    rays_per_pixel: u32,
    seed: u64,
) -> Result<Lists> {
    let (w, h) = (gbuffer.width() as usize, gbuffer.height() as usize);
    let rows: Vec<usize> = (0..h).collect();
    let stream = mix64(seed ^ 0x5646_4d41_5243_4800);
    let per_row = crate::parallel::map_in_order(&rows, |&y| {
        let mut out = Vec::with_capacity(w);
        for x in 0..w {
            let p = y * w + x;
            let Some(hit) = gbuffer.surface_hit(p) else {
                out.push(Vec::new());
                continue;
            };
            let dir = Vec3::from(gbuffer.direction[p]);
            let sp = shading_point_at(scene, &hit, -dir);
            let tmin = scene.ray_epsilon(sp.origin);
            let mut keys = Vec::new();
            for j in 0..rays_per_pixel {
                let u = SampleRng::new(stream, p as u64, j as u64).get2(0);
                let d = stratified_cosine(j, rays_per_pixel, u, sp.normal);
                if let Some(hit) = march_ray(index, discs, sp.origin, d, tmin, f32::INFINITY) {
                    keys.push(home[hit.disc as usize]);
                }
            }
            keys.sort_unstable();
            keys.dedup();
            out.push(keys);
        }
        out
    })?;
    Ok(Lists::from_rows(per_row.into_iter().flatten()))
}
