//! Inside proxies: spheres inscribed in watertight objects (BLD §3.4: a proxy inside `P`,
//! so `f_miss = 1` and eq. 19–20 apply; §5: 40 maximal inscribed spheres along the
//! dragon's medial axis).
//!
//! An object qualifies when it is edge-manifold and closed: after welding vertices with
//! equal coordinates, every edge is used exactly once in each direction (two triangles of
//! opposite orientation). Its spheres approximate the maximal inscribed ones:
//! 1. candidate centres on a grid of [`GRID`] points along the box's longest side,
//!    classified inside by ray parity along `x` (one scanline per grid row, rows set off
//!    the grid's symmetry planes; a row with a crossing exactly on an edge is skipped);
//! 2. each inside candidate's radius is a lower bound of its distance to the surface:
//!    the distance to the nearest surface sample (vertices, plus a lattice on triangles
//!    longer than the grid step) minus the farthest any surface point lies from its
//!    triangle's samples (`longest sub-edge / sqrt 3`), minus a rounding margin;
//!    Above [`DECIMATE_ABOVE`] samples, one per cell of half a grid step is kept and the
//!    bound grows by that cell's diagonal;
//! 3. greedily, the largest candidate not inside an already chosen sphere, `count` times
//!    (a discrete medial axis: centres of locally largest balls).
//!
//! Each sphere is tessellated as a once-subdivided icosahedron (80 triangles) whose
//! vertices lie on the sphere, so every triangle is a chord surface inside the ball,
//! hence inside the object.

use std::collections::HashMap;
use std::hash::{BuildHasherDefault, Hasher};

use glam::{DVec3, Vec3};
use kiddo::immutable::float::kdtree::ImmutableKdTree;
use kiddo::SquaredEuclidean;
use rayon::prelude::*;

use super::hull::quickhull;
use super::{per_object, ProxyKind, ProxySet, MAX_SPHERES};
use crate::error::{Error, Result};
use crate::geometry::{Bounds, Scene};

/// Candidate centres along the longest side of an object's box.
pub const GRID: usize = 48;

/// Surface samples above which they are thinned to one per half grid step (radii then
/// lose up to `0.87` grid steps).
const DECIMATE_ABOVE: usize = 20_000;

impl ProxySet {
    /// Inside proxies: up to `count` (1..=[`MAX_SPHERES`]) inscribed spheres per object of
    /// `parent` (`objects`, or every object with triangles), 80 triangles each (see the
    /// module docs). Errors name `spheres` for a bad count and `objects` for an object
    /// that is not watertight.
    pub fn inscribed(parent: &Scene, objects: Option<&[u32]>, count: usize) -> Result<Self> {
        if count == 0 || count > MAX_SPHERES {
            return Err(Error::invalid(
                "spheres",
                format!("must lie in [1, {MAX_SPHERES}], got {count}"),
            ));
        }
        let ball = unit_sphere();
        per_object(parent, objects, ProxyKind::Inside, |o, triangles| {
            if triangles.is_empty() {
                return Ok(None);
            }
            let welded = check_watertight(o, triangles)?;
            let spheres = inscribed_spheres(triangles, &welded, count);
            Ok((!spheres.is_empty()).then(|| tessellate(&spheres, &ball)))
        })
    }
}

/// A fast hasher for welding and cell keys (coordinate bits, cell indices), 8 bytes a
/// multiply.
#[derive(Default)]
pub(crate) struct Mix(u64);

/// Hash maps keyed by [`Mix`].
pub(crate) type MixMap<K, V> = HashMap<K, V, BuildHasherDefault<Mix>>;

impl Hasher for Mix {
    fn finish(&self) -> u64 {
        self.0 ^ (self.0 >> 32)
    }
    fn write(&mut self, bytes: &[u8]) {
        let mut chunks = bytes.chunks_exact(8);
        for c in &mut chunks {
            self.write_u64(u64::from_le_bytes(c.try_into().unwrap_or_default()));
        }
        let rest = chunks.remainder();
        if !rest.is_empty() {
            let mut buf = [0u8; 8];
            buf[..rest.len()].copy_from_slice(rest);
            self.write_u64(u64::from_le_bytes(buf));
        }
    }
    fn write_u32(&mut self, v: u32) {
        self.write_u64(v as u64);
    }
    fn write_u64(&mut self, v: u64) {
        self.0 = (self.0.rotate_left(5) ^ v).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
}

/// Vertices welded by equal coordinates (`-0.0 == 0.0`).
pub(crate) struct Welded {
    /// Distinct positions, in order of first use.
    pub positions: Vec<Vec3>,
    /// Per triangle, its corners' indices in `positions`.
    pub corners: Vec<[u32; 3]>,
}

/// Welds `triangles`' corners with equal coordinates.
pub(crate) fn weld(triangles: &[[Vec3; 3]]) -> Welded {
    let mut index: MixMap<[u32; 3], u32> =
        HashMap::with_capacity_and_hasher(triangles.len() / 2 + 3, Default::default());
    let mut positions = Vec::new();
    let corners = triangles
        .iter()
        .map(|t| {
            t.map(|v| {
                let v = v + Vec3::ZERO;
                *index
                    .entry(v.to_array().map(f32::to_bits))
                    .or_insert_with(|| {
                        positions.push(v);
                        positions.len() as u32 - 1
                    })
            })
        })
        .collect();
    Welded { positions, corners }
}

/// The welded object when every edge of `triangles` is used exactly once in each
/// direction; otherwise an error naming `objects` and one offending edge of object `o`.
pub(crate) fn check_watertight(o: u32, triangles: &[[Vec3; 3]]) -> Result<Welded> {
    let welded = weld(triangles);
    let (mut fwd, mut bwd) = (Vec::new(), Vec::new());
    for t in &welded.corners {
        for e in 0..3 {
            let (a, b) = (t[e], t[(e + 1) % 3]);
            match a.cmp(&b) {
                std::cmp::Ordering::Less => fwd.push((a as u64) << 32 | b as u64),
                std::cmp::Ordering::Greater => bwd.push((b as u64) << 32 | a as u64),
                std::cmp::Ordering::Equal => {}
            }
        }
    }
    fwd.par_sort_unstable();
    bwd.par_sort_unstable();
    let dup = |v: &[u64]| v.windows(2).find(|w| w[0] == w[1]).map(|w| w[0]);
    let bad = dup(&fwd).or_else(|| dup(&bwd)).or_else(|| {
        fwd.iter()
            .zip(&bwd)
            .find(|(a, b)| a != b)
            .map(|(a, b)| *a.min(b))
            .or_else(|| match fwd.len().cmp(&bwd.len()) {
                std::cmp::Ordering::Less => Some(bwd[fwd.len()]),
                std::cmp::Ordering::Greater => Some(fwd[bwd.len()]),
                std::cmp::Ordering::Equal => None,
            })
    });
    if fwd.is_empty() {
        return Err(Error::invalid(
            "objects",
            format!("object {o} is not watertight: its triangles have no area"),
        ));
    }
    match bad {
        None => Ok(welded),
        Some(key) => {
            let p = |i: u64| welded.positions[i as usize].to_array();
            Err(Error::invalid(
                "objects",
                format!(
                    "object {o} is not watertight: the edge {:?}-{:?} is not shared by \
                     exactly two triangles of opposite orientation (inside proxies need a \
                     closed, edge-manifold mesh)",
                    p(key >> 32),
                    p(key & 0xffff_ffff)
                ),
            ))
        }
    }
}

/// Up to `count` spheres `(centre, radius)` inside the closed surface `triangles`
/// (welded as `welded`), largest first (see the module docs).
pub(crate) fn inscribed_spheres(
    triangles: &[[Vec3; 3]],
    welded: &Welded,
    count: usize,
) -> Vec<(DVec3, f64)> {
    let b = Bounds::of_triangles(triangles);
    let (lo, size) = (b.min.as_dvec3(), (b.max - b.min).as_dvec3());
    let longest = size.max_element();
    if longest <= 0.0 {
        return Vec::new();
    }
    let step = longest / GRID as f64;
    let n = (size / step).ceil().max(DVec3::ONE).as_uvec3();
    let cell = size / n.as_dvec3();
    // Row (j, k) runs along x at y_j, z_k, set off the cell centres by odd fractions.
    let row_y = |j: u32| lo.y + (j as f64 + 0.5 + 0.1372) * cell.y;
    let row_z = |k: u32| lo.z + (k as f64 + 0.5 + 0.2913) * cell.z;
    let rows = (n.y * n.z) as usize;
    let mut buckets: Vec<Vec<u32>> = vec![Vec::new(); rows];
    let range = |min: f64, max: f64, l: f64, c: f64, off: f64, n: u32| {
        let a = ((min - l) / c - 0.5 - off).ceil().max(0.0) as u32;
        let b = ((max - l) / c - 0.5 - off).floor().min(n as f64 - 1.0);
        (a, if b < 0.0 { None } else { Some(b as u32) })
    };
    for (i, t) in triangles.iter().enumerate() {
        let tb = Bounds::of_triangles(std::slice::from_ref(t));
        let (j0, j1) = range(tb.min.y as f64, tb.max.y as f64, lo.y, cell.y, 0.1372, n.y);
        let (k0, k1) = range(tb.min.z as f64, tb.max.z as f64, lo.z, cell.z, 0.2913, n.z);
        let (Some(j1), Some(k1)) = (j1, k1) else {
            continue;
        };
        for k in k0..=k1 {
            for j in j0..=j1 {
                buckets[(k * n.y + j) as usize].push(i as u32);
            }
        }
    }
    // Inside candidates per row, by parity of the crossings before each point.
    let inside: Vec<DVec3> = buckets
        .par_iter()
        .enumerate()
        .flat_map_iter(|(r, tris)| {
            let (j, k) = (r as u32 % n.y, r as u32 / n.y);
            let (y, z) = (row_y(j), row_z(k));
            let mut xs = Vec::with_capacity(tris.len());
            let mut clean = true;
            for &t in tris {
                let [a, bb, c] = triangles[t as usize].map(|v| v.as_dvec3());
                let o2 = |p: DVec3, q: DVec3| (q.y - p.y) * (z - p.z) - (q.z - p.z) * (y - p.y);
                let (w0, w1, w2) = (o2(bb, c), o2(c, a), o2(a, bb));
                if w0 == 0.0 || w1 == 0.0 || w2 == 0.0 {
                    let all_pos = w0 >= 0.0 && w1 >= 0.0 && w2 >= 0.0;
                    let all_neg = w0 <= 0.0 && w1 <= 0.0 && w2 <= 0.0;
                    if all_pos || all_neg {
                        clean = false;
                    }
                    continue;
                }
                if (w0 > 0.0) == (w1 > 0.0) && (w1 > 0.0) == (w2 > 0.0) {
                    xs.push((w0 * a.x + w1 * bb.x + w2 * c.x) / (w0 + w1 + w2));
                }
            }
            let mut out = Vec::new();
            if clean && xs.len() % 2 == 0 {
                xs.sort_unstable_by(f64::total_cmp);
                for i in 0..n.x {
                    let x = lo.x + (i as f64 + 0.5) * cell.x;
                    if xs.partition_point(|&c| c < x) % 2 == 1 && !xs.contains(&x) {
                        out.push(DVec3::new(x, y, z));
                    }
                }
            }
            out.into_iter()
        })
        .collect();
    if inside.is_empty() {
        return Vec::new();
    }
    // Surface samples: the welded vertices, plus a lattice on triangles longer than a
    // grid step; `cover` bounds the distance from any surface point to its samples.
    let mut samples: Vec<[f32; 3]> = welded.positions.iter().map(|p| p.to_array()).collect();
    let mut cover = 0.0f64;
    for t in triangles {
        let [a, bb, c] = t.map(|v| v.as_dvec3());
        let edge = (bb - a)
            .length()
            .max((c - bb).length())
            .max((a - c).length());
        let m = (edge / step).ceil().max(1.0);
        cover = cover.max(edge / m / 3f64.sqrt());
        let m = m as u32;
        for i in 0..=m {
            for j in 0..=m - i {
                if (j == 0 && (i == 0 || i == m)) || (i == 0 && j == m) {
                    continue;
                }
                let p = a + (bb - a) * (i as f64 / m as f64) + (c - a) * (j as f64 / m as f64);
                samples.push(p.as_vec3().to_array());
            }
        }
    }
    if samples.len() > DECIMATE_ABOVE {
        // One sample per cell of side step / 2: a dropped sample lies within the cell's
        // diagonal of the kept one. Deep candidates are nearly equidistant from many
        // samples, so the kd-tree's cost follows the sample count.
        let h = step / 2.0;
        let mut kept: MixMap<[i64; 3], ()> = MixMap::default();
        samples.retain(|p| {
            let key = ((Vec3::from(*p).as_dvec3() - lo) / h)
                .floor()
                .as_i64vec3()
                .to_array();
            kept.insert(key, ()).is_none()
        });
        cover += h * 3f64.sqrt();
    }
    let tree: ImmutableKdTree<f32, u32, 3, 32> = ImmutableKdTree::new_from_slice(&samples);
    // Rounding: the f32 search and the f32 vertices of the tessellation.
    let slack = 1e-5 * longest + 8.0 * f32::EPSILON as f64 * b.max_abs() as f64;
    let mut candidates: Vec<(DVec3, f64)> = inside
        .par_iter()
        .map(|&p| {
            let q = p.as_vec3().to_array();
            let near = tree.nearest_one::<SquaredEuclidean>(&q);
            let s = Vec3::from(samples[near.item as usize]).as_dvec3();
            (
                p,
                (p - s).length().min((near.distance as f64).sqrt()) - cover - slack,
            )
        })
        .filter(|&(_, r)| r > 0.0)
        .collect();
    // Largest first; ties by position for a fixed order.
    candidates.sort_by(|a, b| {
        b.1.total_cmp(&a.1)
            .then(a.0.x.total_cmp(&b.0.x))
            .then(a.0.y.total_cmp(&b.0.y))
            .then(a.0.z.total_cmp(&b.0.z))
    });
    let mut chosen: Vec<(DVec3, f64)> = Vec::with_capacity(count);
    for (c, r) in candidates {
        if chosen.len() == count {
            break;
        }
        if chosen.iter().all(|&(d, s)| c.distance(d) >= s) {
            chosen.push((c, r));
        }
    }
    chosen
}

/// The spheres `(centre, radius)` as copies of `ball` (a unit sphere's triangles).
pub(crate) fn tessellate(spheres: &[(DVec3, f64)], ball: &[[DVec3; 3]]) -> Vec<[Vec3; 3]> {
    spheres
        .iter()
        .flat_map(|&(c, r)| ball.iter().map(move |t| t.map(|v| (c + v * r).as_vec3())))
        .collect()
}

/// The unit sphere as a once-subdivided icosahedron (80 outward triangles, vertices on
/// the sphere).
pub(crate) fn unit_sphere() -> Vec<[DVec3; 3]> {
    let g = (1.0 + 5f64.sqrt()) / 2.0;
    let mut v = Vec::with_capacity(12);
    for s in [-1.0, 1.0] {
        for t in [-1.0, 1.0] {
            v.push(DVec3::new(0.0, s, t * g).normalize());
            v.push(DVec3::new(s, t * g, 0.0).normalize());
            v.push(DVec3::new(t * g, 0.0, s).normalize());
        }
    }
    let faces = quickhull(v.len(), |i| v[i as usize]).expect("an icosahedron spans 3D");
    let mut out = Vec::with_capacity(4 * faces.len());
    for f in faces {
        let [a, b, c] = f.map(|i| v[i as usize]);
        let (ab, bc, ca) = (
            (a + b).normalize(),
            (b + c).normalize(),
            (c + a).normalize(),
        );
        out.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::proxies::test_meshes::*;

    #[test]
    fn inscribed_spheres_lie_inside_the_object_at_every_scale() {
        for scale in [1e-4f32, 1.0, 1e4] {
            let ball = bumpy_ball(3, Vec3::new(-1.0, 2.0, 0.5) * scale, scale, 0.3);
            let scene = scene_of(&[Vec::new(), ball.clone()]);
            let set = ProxySet::inscribed(&scene, None, 40).unwrap();
            assert_eq!(set.kind(), ProxyKind::Inside);
            assert_eq!(set.objects(), &[1]);
            let proxy = proxy_triangles(&set, 0);
            assert_eq!(proxy.len() % 80, 0);
            assert!(proxy.len() >= 80 * 20, "{} spheres", proxy.len() / 80);
            for p in points_on(&proxy) {
                assert!(inside_by_parity(&ball, p), "scale {scale}: {p} is outside");
            }
            // Not a token: the spheres reach across most of the object.
            let (pb, ob) = (Bounds::of_triangles(&proxy), Bounds::of_triangles(&ball));
            assert!(pb.extent() > 0.6 * ob.extent(), "{pb:?} in {ob:?}");
        }
    }

    #[test]
    fn objects_that_are_not_closed_are_refused() {
        let ball = bumpy_ball(2, Vec3::ZERO, 1.0, 0.2);
        let mut open = ball.clone();
        open.pop();
        let mut flipped = ball.clone();
        flipped[7].swap(0, 1);
        let mut doubled = ball.clone();
        doubled.push(ball[3]);
        for (name, bad) in [("open", open), ("flipped", flipped), ("doubled", doubled)] {
            let scene = scene_of(&[ball.clone(), bad]);
            let err = ProxySet::inscribed(&scene, None, 8).unwrap_err();
            let msg = err.to_string();
            assert!(
                msg.starts_with("objects") && msg.contains("object 1 is not watertight"),
                "{name}: {msg}"
            );
            // The closed one alone is fine.
            ProxySet::inscribed(&scene, Some(&[0]), 8).unwrap();
        }
        let scene = scene_of(&[ball, Vec::new()]);
        let set = ProxySet::inscribed(&scene, Some(&[1]), 8).unwrap();
        assert_eq!(set.num_triangles(), 0, "an empty object gets no spheres");
        let err = ProxySet::inscribed(&scene, None, 0).unwrap_err();
        assert!(err.to_string().starts_with("spheres"), "{err}");
    }

    #[test]
    fn thinned_samples_keep_spheres_inside() {
        // Level 6: 40,962 vertices, above the thinning threshold.
        let ball = bumpy_ball(6, Vec3::new(0.5, -0.2, 0.1), 1.0, 0.25);
        let welded = check_watertight(0, &ball).unwrap();
        assert!(welded.positions.len() > DECIMATE_ABOVE);
        let spheres = inscribed_spheres(&ball, &welded, 12);
        assert_eq!(spheres.len(), 12);
        let proxy = tessellate(&spheres, &unit_sphere());
        for p in points_on(&proxy) {
            assert!(inside_by_parity(&ball, p), "{p} is outside");
        }
        // Largest radius: at least the bumps' trough (0.75) less the grid and thinning
        // losses (about 2.5 steps of 2.5 / 48).
        assert!(spheres[0].1 > 0.5, "{:?}", spheres[0]);
    }

    #[test]
    fn one_sphere_in_a_ball_is_nearly_the_ball() {
        let ball = bumpy_ball(4, Vec3::ZERO, 1.0, 0.0);
        let welded = check_watertight(0, &ball).unwrap();
        let s = inscribed_spheres(&ball, &welded, 1);
        assert_eq!(s.len(), 1);
        // The icosphere's faces are ~0.004 inside the unit sphere; the grid step 2/48.
        let (c, r) = s[0];
        assert!(c.length() < 0.05 && r > 0.9 && r < 1.0, "{c} {r}");
    }
}
