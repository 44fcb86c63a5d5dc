//! Outside proxies as convex hulls (BLD §3.3: a proxy enclosing `P`, so `f_hit = 1` and
//! eq. 17–18 apply; §5: the hairball's outside proxy is its convex hull, its general proxy
//! that hull cut down to 32 triangles).
//!
//! The hull is our own 3D quickhull in `f64` (Barber, Dobkin & Huhdanpaa 1996) over the
//! object's `f32` vertices: ~200 lines against a dependency (the `quickhull` crate pulls a
//! second `glam` and four more crates, `parry3d` a whole physics stack, `chull` is N-d and
//! generic). Its faces are triangles of input vertices, so they are exact; every other
//! vertex lies inside every face's plane up to `1e-12` of the object's coordinates.
//!
//! With a `target` below the exact hull's triangle count, the proxy is an *enclosing*
//! polytope instead: the intersection of support half-spaces `n·x <= max_v n·v + margin`,
//! starting from the 6 axis directions (the box) and adding, greedily, the hull face
//! violated most by the polytope's farthest vertex, while the polytope has at most
//! `target` triangles. Each half-space holds every vertex, so the polytope encloses the
//! object whatever the directions; `margin` (4 `f32` ulps of the object's largest
//! coordinate) covers rounding the polytope's vertices to `f32`. Its vertices come from
//! the dual: the hull of the points `n_j / h_j` (offsets `h_j` about an interior point)
//! has one face per polytope vertex.

use glam::{DVec3, Vec3};

use super::{box_triangles, per_object, ProxyKind, ProxySet};
use crate::error::{Error, Result};
use crate::geometry::{Bounds, Scene};

/// Smallest `target` a simplified hull takes: the box it starts from has 12 triangles.
pub const MIN_HULL_TARGET: usize = 12;

impl ProxySet {
    /// Outside proxies as the convex hull of each object of `parent` (`objects`, or every
    /// object with triangles), cut down to an enclosing polytope of at most `target`
    /// triangles (>= [`MIN_HULL_TARGET`]) when the hull has more (see the module docs). An
    /// object whose vertices are coplanar gets its box. Errors name `objects` and
    /// `target`.
    pub fn hulls(parent: &Scene, objects: Option<&[u32]>, target: Option<usize>) -> Result<Self> {
        if let Some(t) = target {
            if t < MIN_HULL_TARGET {
                return Err(Error::invalid(
                    "target",
                    format!("a hull needs at least {MIN_HULL_TARGET} triangles, got {t}"),
                ));
            }
        }
        per_object(parent, objects, ProxyKind::Outside, |_, triangles| {
            Ok(hull_triangles(triangles, target))
        })
    }
}

/// The triangles of the hull of `triangles`' vertices (see the module docs); `None` for
/// no vertices.
pub(crate) fn hull_triangles(
    triangles: &[[Vec3; 3]],
    target: Option<usize>,
) -> Option<Vec<[Vec3; 3]>> {
    let bounds = Bounds::of_triangles(triangles);
    if bounds.is_empty() {
        return None;
    }
    let points = triangles.as_flattened();
    let at = |i: u32| points[i as usize].as_dvec3();
    let Some(faces) = quickhull(points.len(), at) else {
        return Some(box_triangles(&bounds).to_vec());
    };
    if target.is_none_or(|t| faces.len() <= t) {
        return Some(
            faces
                .iter()
                .map(|f| f.map(|i| points[i as usize]))
                .collect(),
        );
    }
    let target = target.unwrap_or(usize::MAX);
    let margin = 4.0 * f32::EPSILON as f64 * bounds.max_abs() as f64;
    Some(
        enclosing_polytope(&faces, at, target, margin)
            .unwrap_or_else(|| box_triangles(&bounds).to_vec()),
    )
}

/// The polytope of the module docs: at most `target` triangles enclosing the hull whose
/// `faces` index points `at`; `None` when the dual is degenerate (never for a 3D hull).
fn enclosing_polytope(
    faces: &[[u32; 3]],
    at: impl Fn(u32) -> DVec3,
    target: usize,
    margin: f64,
) -> Option<Vec<[Vec3; 3]>> {
    // The hull's vertices, their centroid (strictly inside) and the face planes.
    let mut ids: Vec<u32> = faces.iter().flatten().copied().collect();
    ids.sort_unstable();
    ids.dedup();
    let verts: Vec<DVec3> = ids.iter().map(|&i| at(i)).collect();
    let centre = verts.iter().sum::<DVec3>() / verts.len() as f64;
    let verts: Vec<DVec3> = verts.iter().map(|&v| v - centre).collect();
    let planes: Vec<(DVec3, f64)> = faces
        .iter()
        .map(|f| {
            let [a, b, c] = f.map(|i| at(i) - centre);
            let n = (b - a).cross(c - a).normalize_or_zero();
            (n, n.dot(a + b + c) / 3.0)
        })
        .collect();
    let support = |n: DVec3| verts.iter().map(|v| n.dot(*v)).fold(f64::MIN, f64::max) + margin;
    let mut normals: Vec<DVec3> = vec![
        DVec3::X,
        DVec3::NEG_X,
        DVec3::Y,
        DVec3::NEG_Y,
        DVec3::Z,
        DVec3::NEG_Z,
    ];
    let mut offsets: Vec<f64> = normals.iter().map(|&n| support(n)).collect();
    let mut used = vec![false; planes.len()];
    let mut best: Option<Vec<[DVec3; 3]>> = None;
    while let Some(tris) = half_space_intersection(&normals, &offsets) {
        if tris.len() > target {
            break;
        }
        // The polytope vertex farthest outside the hull, and the face it violates most.
        let mut worst = (margin * 2.0, usize::MAX);
        for t in &tris {
            for x in t {
                for (f, (n, d)) in planes.iter().enumerate() {
                    let v = n.dot(*x) - d;
                    if v > worst.0 && !used[f] {
                        worst = (v, f);
                    }
                }
            }
        }
        best = Some(tris);
        if worst.1 == usize::MAX {
            break;
        }
        used[worst.1] = true;
        let n = planes[worst.1].0;
        if n == DVec3::ZERO {
            break;
        }
        normals.push(n);
        offsets.push(support(n));
    }
    best.map(|tris| {
        tris.into_iter()
            .map(|t| t.map(|x| (x + centre).as_vec3()))
            .collect()
    })
}

/// The triangles of `{x : normals[j]·x <= offsets[j]}` (all offsets > 0, so the origin
/// is inside), through the dual hull; `None` when unbounded or degenerate.
fn half_space_intersection(normals: &[DVec3], offsets: &[f64]) -> Option<Vec<[DVec3; 3]>> {
    let dual: Vec<DVec3> = normals.iter().zip(offsets).map(|(n, h)| *n / *h).collect();
    let dual_faces = quickhull(dual.len(), |i| dual[i as usize])?;
    // Each dual face `m·q = e` is the primal vertex `m / e`.
    let mut corners = Vec::with_capacity(dual_faces.len());
    for f in &dual_faces {
        let [a, b, c] = f.map(|i| dual[i as usize]);
        let m = (b - a).cross(c - a);
        let e = m.dot(a + b + c) / 3.0;
        if e <= 0.0 {
            return None;
        }
        corners.push(m / e);
    }
    let faces = quickhull(corners.len(), |i| corners[i as usize])?;
    Some(
        faces
            .iter()
            .map(|f| f.map(|i| corners[i as usize]))
            .collect(),
    )
}

/// One face of the hull under construction.
struct Face {
    /// Vertices, counter-clockwise seen from outside.
    v: [u32; 3],
    /// Unit outward normal.
    n: DVec3,
    /// Plane offset: `n·x = d` on the face.
    d: f64,
    /// The face across edge `(v[i], v[i+1])`.
    adj: [u32; 3],
    /// Points above this face (assigned to it first).
    outside: Vec<u32>,
    /// The farthest of them and its distance.
    far: (f64, u32),
    alive: bool,
}

impl Face {
    fn new(v: [u32; 3], at: &impl Fn(u32) -> DVec3) -> Self {
        let [a, b, c] = v.map(at);
        let n = (b - a).cross(c - a).normalize_or_zero();
        Face {
            v,
            n,
            d: n.dot(a + b + c) / 3.0,
            adj: [u32::MAX; 3],
            outside: Vec::new(),
            far: (0.0, u32::MAX),
            alive: true,
        }
    }

    fn dist(&self, p: DVec3) -> f64 {
        self.n.dot(p) - self.d
    }

    fn take(&mut self, i: u32, dist: f64) {
        self.outside.push(i);
        if dist > self.far.0 {
            self.far = (dist, i);
        }
    }
}

/// The convex hull of the `n` points `at(0..n)` as outward-facing triangles of point
/// indices; `None` when the points do not span 3D (fewer than 4, or all within `1e-12`
/// of the coordinates' size of one plane). Points within that tolerance of the hull are
/// treated as inside.
pub(crate) fn quickhull(n: usize, at: impl Fn(u32) -> DVec3) -> Option<Vec<[u32; 3]>> {
    if n < 4 {
        return None;
    }
    let n = n as u32;
    // Extreme points along the axes, and the scale of the coordinates.
    let mut ext = [0u32; 6];
    let mut scale = 0.0f64;
    for i in 0..n {
        let p = at(i);
        scale = scale.max(p.abs().max_element());
        for k in 0..3 {
            if p[k] < at(ext[2 * k])[k] {
                ext[2 * k] = i;
            }
            if p[k] > at(ext[2 * k + 1])[k] {
                ext[2 * k + 1] = i;
            }
        }
    }
    let eps = 1e-12 * scale.max(f64::MIN_POSITIVE);
    // The initial tetrahedron: the farthest extreme pair, the point farthest from their
    // line, the point farthest from their plane.
    let (mut i0, mut i1, mut far) = (0, 0, -1.0);
    for &a in &ext {
        for &b in &ext {
            let d = at(a).distance_squared(at(b));
            if d > far {
                (i0, i1, far) = (a, b, d);
            }
        }
    }
    let (a, b) = (at(i0), at(i1));
    let ab = (b - a).normalize_or_zero();
    let (mut i2, mut far) = (0, -1.0);
    for i in 0..n {
        let d = (at(i) - a).cross(ab).length();
        if d > far {
            (i2, far) = (i, d);
        }
    }
    if far <= eps {
        return None;
    }
    let nrm = (b - a).cross(at(i2) - a).normalize_or_zero();
    let (mut i3, mut far) = (0, -1.0);
    for i in 0..n {
        let d = nrm.dot(at(i) - a).abs();
        if d > far {
            (i3, far) = (i, d);
        }
    }
    if far <= eps {
        return None;
    }
    let tet = [i0, i1, i2, i3];
    let mut faces: Vec<Face> = Vec::new();
    for skip in 0..4 {
        let mut v = [0u32; 3];
        let mut k = 0;
        for (j, &t) in tet.iter().enumerate() {
            if j != skip {
                v[k] = t;
                k += 1;
            }
        }
        let mut f = Face::new(v, &at);
        if f.dist(at(tet[skip])) > 0.0 {
            f = Face::new([v[0], v[2], v[1]], &at);
        }
        faces.push(f);
    }
    for f in 0..4 {
        for e in 0..3 {
            let (p, q) = (faces[f].v[e], faces[f].v[(e + 1) % 3]);
            let g = (0..4)
                .find(|&g| (0..3).any(|k| faces[g].v[k] == q && faces[g].v[(k + 1) % 3] == p))
                .expect("a tetrahedron's faces meet along every edge");
            faces[f].adj[e] = g as u32;
        }
    }
    for i in 0..n {
        if tet.contains(&i) {
            continue;
        }
        let p = at(i);
        for f in faces.iter_mut() {
            let d = f.dist(p);
            if d > eps {
                f.take(i, d);
                break;
            }
        }
    }
    let mut work: Vec<u32> = (0..4).collect();
    let mut visible: Vec<u32> = Vec::new();
    let mut horizon: Vec<(u32, u32, u32)> = Vec::new();
    let mut stamp: Vec<u32> = vec![0; 4];
    let mut round = 0u32;
    while let Some(f) = work.pop() {
        let f = f as usize;
        if !faces[f].alive || faces[f].outside.is_empty() {
            continue;
        }
        round += 1;
        let eye_i = faces[f].far.1;
        let eye = at(eye_i);
        // Faces seen from the eye (connected through the first), and the horizon.
        visible.clear();
        horizon.clear();
        visible.push(f as u32);
        stamp[f] = round;
        let mut k = 0;
        while k < visible.len() {
            let g = visible[k] as usize;
            k += 1;
            for e in 0..3 {
                let h = faces[g].adj[e] as usize;
                if stamp[h] == round {
                    continue;
                }
                if faces[h].dist(eye) > eps {
                    stamp[h] = round;
                    visible.push(h as u32);
                } else {
                    horizon.push((faces[g].v[e], faces[g].v[(e + 1) % 3], h as u32));
                }
            }
        }
        // A face on the horizon may have been reached as "not visible" before it was
        // found visible through another edge: drop those edges.
        horizon.retain(|&(_, _, h)| stamp[h as usize] != round);
        let mut orphans: Vec<u32> = Vec::new();
        for &g in &visible {
            let g = &mut faces[g as usize];
            g.alive = false;
            orphans.extend(g.outside.drain(..).filter(|&i| i != eye_i));
        }
        let first = faces.len() as u32;
        let mut starts: Vec<(u32, u32)> = Vec::with_capacity(horizon.len());
        for (j, &(a, b, h)) in horizon.iter().enumerate() {
            let id = first + j as u32;
            let mut nf = Face::new([a, b, eye_i], &at);
            nf.adj[0] = h;
            let hf = &mut faces[h as usize];
            let e = (0..3)
                .find(|&e| hf.v[e] == b && hf.v[(e + 1) % 3] == a)
                .expect("a horizon edge is shared with the face behind it");
            hf.adj[e] = id;
            faces.push(nf);
            stamp.push(0);
            starts.push((a, id));
        }
        starts.sort_unstable();
        if starts.windows(2).any(|w| w[0].0 == w[1].0) {
            // The horizon is not one simple loop (numerically broken input): give up
            // rather than return a wrong hull.
            return None;
        }
        for (j, &(_, b, _)) in horizon.iter().enumerate() {
            // Edge (b, eye) of face (a, b, eye) is edge (eye, b) of the new face that
            // starts at b.
            let id = first + j as u32;
            let k = starts.partition_point(|&(s, _)| s < b);
            let &(s, next) = starts.get(k)?;
            if s != b {
                return None;
            }
            faces[id as usize].adj[1] = next;
            faces[next as usize].adj[2] = id;
        }
        for i in orphans {
            let p = at(i);
            for f in faces[first as usize..].iter_mut() {
                let d = f.dist(p);
                if d > eps {
                    f.take(i, d);
                    break;
                }
            }
        }
        work.extend((first..faces.len() as u32).filter(|&g| !faces[g as usize].outside.is_empty()));
    }
    Some(faces.iter().filter(|f| f.alive).map(|f| f.v).collect())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Largest signed distance of any point outside any of `tris`' planes.
    fn worst_outside(tris: &[[Vec3; 3]], points: &[Vec3]) -> f64 {
        let mut worst = f64::MIN;
        for t in tris {
            let [a, b, c] = t.map(|v| v.as_dvec3());
            let n = (b - a).cross(c - a);
            if n.length() == 0.0 {
                continue;
            }
            let n = n.normalize();
            for p in points {
                worst = worst.max(n.dot(p.as_dvec3() - a));
            }
        }
        worst
    }

    fn random_points(n: usize, seed: u64) -> Vec<Vec3> {
        let mut s = seed;
        let mut next = move || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            ((s >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
        };
        (0..n).map(|_| Vec3::new(next(), next(), next())).collect()
    }

    #[test]
    fn quickhull_of_a_cube_cloud_is_its_twelve_triangles() {
        let mut pts: Vec<Vec3> = random_points(500, 1).iter().map(|p| *p * 0.9).collect();
        for i in 0..8 {
            pts.push(Vec3::new(
                if i & 1 == 0 { -1.0 } else { 1.0 },
                if i & 2 == 0 { -1.0 } else { 1.0 },
                if i & 4 == 0 { -1.0 } else { 1.0 },
            ));
        }
        let faces = quickhull(pts.len(), |i| pts[i as usize].as_dvec3()).unwrap();
        assert_eq!(faces.len(), 12);
        let tris: Vec<[Vec3; 3]> = faces.iter().map(|f| f.map(|i| pts[i as usize])).collect();
        assert!(worst_outside(&tris, &pts) <= 1e-6);
        // Outward: the origin is behind every face.
        assert!(worst_outside(&tris, &[Vec3::ZERO]) < -0.5);
    }

    #[test]
    fn hulls_of_spheres_enclose_and_close() {
        for seed in 0..5 {
            let pts: Vec<Vec3> = random_points(3000, seed)
                .into_iter()
                .map(|p| p.normalize_or_zero() * (1.0 + 0.01 * p.x))
                .collect();
            let faces = quickhull(pts.len(), |i| pts[i as usize].as_dvec3()).unwrap();
            let tris: Vec<[Vec3; 3]> = faces.iter().map(|f| f.map(|i| pts[i as usize])).collect();
            assert!(worst_outside(&tris, &pts) <= 1e-6, "seed {seed}");
            // A closed surface: Euler's V - E + F = 2 over the used vertices.
            let mut vs: Vec<u32> = faces.iter().flatten().copied().collect();
            vs.sort_unstable();
            vs.dedup();
            assert_eq!(2 * vs.len(), faces.len() + 4, "seed {seed}");
        }
    }

    #[test]
    fn degenerate_clouds_have_no_hull() {
        let flat: Vec<Vec3> = random_points(100, 3)
            .iter()
            .map(|p| Vec3::new(p.x, p.y, 0.5))
            .collect();
        assert!(quickhull(flat.len(), |i| flat[i as usize].as_dvec3()).is_none());
        assert!(quickhull(3, |i| DVec3::splat(i as f64)).is_none());
        assert!(quickhull(50, |_| DVec3::ONE).is_none());
    }

    #[test]
    fn hull_proxies_enclose_every_vertex_at_every_scale() {
        use crate::geometry::proxies::test_meshes::*;
        for scale in [1e-4f32, 1.0, 1e4] {
            let ball = bumpy_ball(3, Vec3::new(3.0, 1.0, -2.0) * scale, scale, 0.3);
            let quad = vec![
                [
                    Vec3::ZERO,
                    Vec3::X * scale,
                    Vec3::new(1.0, 0.0, 1.0) * scale,
                ],
                [
                    Vec3::ZERO,
                    Vec3::new(1.0, 0.0, 1.0) * scale,
                    Vec3::Z * scale,
                ],
            ];
            let scene = scene_of(&[ball.clone(), Vec::new(), quad]);
            let points = ball.as_flattened();
            let tol = 1e-6 * 5.0 * scale as f64;
            let mut sizes = Vec::new();
            for target in [None, Some(64), Some(32), Some(12)] {
                let set = ProxySet::hulls(&scene, None, target).unwrap();
                assert_eq!(set.kind(), ProxyKind::Outside);
                assert_eq!(set.objects(), &[0, 2], "the empty object gets none");
                set.check_scene(&scene).unwrap();
                let hull = proxy_triangles(&set, 0);
                let w = worst_outside(&hull, points);
                assert!(w <= tol, "scale {scale} target {target:?}: {w} outside");
                assert!(hull.len() <= target.unwrap_or(usize::MAX), "{}", hull.len());
                // The coplanar quad gets its (flat) box.
                assert_eq!(proxy_triangles(&set, 1).len(), 12);
                sizes.push(hull.len());
            }
            // The greedy planes did cut the box, and the exact hull is larger.
            assert!(sizes[2] > 12 && sizes[0] > 64, "scale {scale}: {sizes:?}");
        }
        let scene = scene_of(&[bumpy_ball(2, Vec3::ZERO, 1.0, 0.1)]);
        let err = ProxySet::hulls(&scene, None, Some(11)).unwrap_err();
        assert!(err.to_string().starts_with("target"), "{err}");
        let err = ProxySet::hulls(&scene, Some(&[1]), None).unwrap_err();
        assert!(err.to_string().starts_with("objects"), "{err}");
    }
}
