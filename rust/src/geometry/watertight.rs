//! Watertight ray/triangle intersection after Woop, Benthin and Wald, "Watertight
//! Ray/Triangle Intersection" (JCGT 2013).
//!
//! The ray is sheared so that it runs along +z; the three 2D edge functions of the triangle
//! are then evaluated at the origin. Edges shared by two triangles produce bit-identical edge
//! functions with opposite signs, so a ray through a shared edge or vertex of a closed mesh
//! can never slip between them. Edge functions that round to exactly zero are recomputed in
//! `f64`. We write this ourselves instead of using obvhs's Möller–Trumbore test because that
//! one is not watertight (it can leak through shared edges), which visibility records and
//! closed-mesh tests cannot accept.

use glam::Vec3A;

/// A ray prepared for repeated watertight triangle tests.
#[derive(Clone, Copy, Debug)]
pub struct WatertightRay {
    origin: Vec3A,
    kx: usize,
    ky: usize,
    kz: usize,
    sx: f32,
    sy: f32,
    sz: f32,
}

/// A hit on one triangle: `t` is the ray parameter, `(u, v)` the barycentric weights of the
/// second and third vertex (position = (1 - u - v) v0 + u v1 + v v2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TriangleHit {
    pub t: f32,
    pub u: f32,
    pub v: f32,
}

impl WatertightRay {
    /// Prepares `origin + t * direction`; `direction` must be finite and non-zero.
    #[inline]
    pub fn new(origin: Vec3A, direction: Vec3A) -> Self {
        // Largest axis of the direction becomes z; keep the winding by swapping x/y when
        // that axis points backwards.
        let a = direction.abs();
        let kz = if a.x > a.y {
            if a.x > a.z {
                0
            } else {
                2
            }
        } else if a.y > a.z {
            1
        } else {
            2
        };
        let mut kx = (kz + 1) % 3;
        let mut ky = (kx + 1) % 3;
        if direction[kz] < 0.0 {
            std::mem::swap(&mut kx, &mut ky);
        }
        let sz = 1.0 / direction[kz];
        Self {
            origin,
            kx,
            ky,
            kz,
            sx: direction[kx] * sz,
            sy: direction[ky] * sz,
            sz,
        }
    }

    /// Intersects the triangle, returning the hit if its parameter lies in `[0, tmax)`.
    /// Degenerate triangles (zero projected area) never hit.
    #[inline(always)]
    pub fn intersect(&self, tri: &[Vec3A; 3], tmax: f32) -> Option<TriangleHit> {
        let a = tri[0] - self.origin;
        let b = tri[1] - self.origin;
        let c = tri[2] - self.origin;
        let (kx, ky, kz) = (self.kx, self.ky, self.kz);
        let ax = a[kx] - self.sx * a[kz];
        let ay = a[ky] - self.sy * a[kz];
        let bx = b[kx] - self.sx * b[kz];
        let by = b[ky] - self.sy * b[kz];
        let cx = c[kx] - self.sx * c[kz];
        let cy = c[ky] - self.sy * c[kz];

        let mut u = cx * by - cy * bx;
        let mut v = ax * cy - ay * cx;
        let mut w = bx * ay - by * ax;
        if u == 0.0 || v == 0.0 || w == 0.0 {
            // Exactly on an edge in f32: decide it in f64 so neighbours agree.
            let (ax, ay, bx, by, cx, cy) = (
                ax as f64, ay as f64, bx as f64, by as f64, cx as f64, cy as f64,
            );
            u = (cx * by - cy * bx) as f32;
            v = (ax * cy - ay * cx) as f32;
            w = (bx * ay - by * ax) as f32;
        }
        if (u < 0.0 || v < 0.0 || w < 0.0) && (u > 0.0 || v > 0.0 || w > 0.0) {
            return None;
        }
        let det = u + v + w;
        if det == 0.0 {
            return None;
        }
        let t_scaled = self.sz * (u * a[kz] + v * b[kz] + w * c[kz]);
        let inv_det = 1.0 / det;
        let t = t_scaled * inv_det;
        if !(t >= 0.0 && t < tmax) {
            return None;
        }
        Some(TriangleHit {
            t,
            u: v * inv_det,
            v: w * inv_det,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::vec3a;

    const TRI: [Vec3A; 3] = [
        Vec3A::new(0.0, 0.0, 0.0),
        Vec3A::new(1.0, 0.0, 0.0),
        Vec3A::new(0.0, 1.0, 0.0),
    ];

    #[test]
    fn hits_inside_with_barycentrics_and_both_windings() {
        let r = WatertightRay::new(vec3a(0.25, 0.5, 2.0), vec3a(0.0, 0.0, -1.0));
        let h = r.intersect(&TRI, f32::INFINITY).unwrap();
        assert!((h.t - 2.0).abs() < 1e-6);
        assert!((h.u - 0.25).abs() < 1e-6 && (h.v - 0.5).abs() < 1e-6);
        let flipped = [TRI[0], TRI[2], TRI[1]];
        let h = r.intersect(&flipped, f32::INFINITY).unwrap();
        assert!((h.u - 0.5).abs() < 1e-6 && (h.v - 0.25).abs() < 1e-6);
        let up = WatertightRay::new(vec3a(0.25, 0.5, -2.0), vec3a(0.0, 0.0, 1.0));
        assert!(up.intersect(&TRI, f32::INFINITY).is_some());
    }

    #[test]
    fn segment_is_half_open() {
        let r = WatertightRay::new(vec3a(0.25, 0.25, 2.0), vec3a(0.0, 0.0, -1.0));
        assert!(r.intersect(&TRI, 2.0).is_none());
        assert!(r.intersect(&TRI, 2.0001).is_some());
        let behind = WatertightRay::new(vec3a(0.25, 0.25, -1.0), vec3a(0.0, 0.0, -1.0));
        assert!(behind.intersect(&TRI, f32::INFINITY).is_none());
        let on_plane = WatertightRay::new(vec3a(0.25, 0.25, 0.0), vec3a(0.0, 0.0, -1.0));
        assert_eq!(on_plane.intersect(&TRI, 1.0).unwrap().t, 0.0);
    }

    #[test]
    fn degenerate_and_parallel_never_hit() {
        let line = [TRI[0], TRI[1], vec3a(2.0, 0.0, 0.0)];
        let point = [TRI[0]; 3];
        for d in [
            vec3a(0.0, 0.0, -1.0),
            vec3a(0.3, -0.2, -1.0),
            vec3a(1.0, 0.0, 0.0),
        ] {
            let r = WatertightRay::new(vec3a(0.5, 0.0, 1.0), d);
            assert!(r.intersect(&line, f32::INFINITY).is_none());
            assert!(r.intersect(&point, f32::INFINITY).is_none());
        }
        let grazing = WatertightRay::new(vec3a(-1.0, 0.25, 0.0), vec3a(1.0, 0.0, 0.0));
        assert!(grazing.intersect(&TRI, f32::INFINITY).is_none());
    }

    #[test]
    fn shared_edge_and_vertex_do_not_leak() {
        // A fan of 8 triangles around the origin in the z = 0 plane; rays straight down
        // through the shared spokes and the hub must hit at least one triangle.
        let fan: Vec<[Vec3A; 3]> = (0..8)
            .map(|i| {
                let a0 = i as f32 * std::f32::consts::TAU / 8.0;
                let a1 = (i + 1) as f32 * std::f32::consts::TAU / 8.0;
                [
                    Vec3A::ZERO,
                    vec3a(a0.cos(), a0.sin(), 0.0),
                    vec3a(a1.cos(), a1.sin(), 0.0),
                ]
            })
            .collect();
        for i in 0..8 {
            let a = i as f32 * std::f32::consts::TAU / 8.0;
            for s in [0.0f32, 0.1, 0.37, 0.9] {
                let o = vec3a(s * a.cos(), s * a.sin(), 3.0);
                let r = WatertightRay::new(o, vec3a(0.0, 0.0, -1.0));
                let hits = fan
                    .iter()
                    .filter(|t| r.intersect(t, f32::INFINITY).is_some());
                assert!(hits.count() >= 1, "leak at spoke {i}, radius {s}");
            }
        }
    }
}
