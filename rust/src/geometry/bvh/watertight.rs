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

use glam::{Vec3A, Vec4};

/// A ray prepared for repeated watertight triangle tests.
#[derive(Clone, Copy, Debug)]
pub struct WatertightRay {
    origin: Vec3A,
    /// `origin[kx], origin[ky], origin[kz]`.
    permuted_origin: [f32; 3],
    kx: usize,
    ky: usize,
    kz: usize,
    sx: f32,
    sy: f32,
    sz: f32,
}

impl WatertightRay {
    /// The ray of [`Self::new`] from its already chosen parts: `kz` the direction's largest
    /// axis, `kx, ky` the other two in the order `new` picks, and the shear `sx, sy, sz`
    /// (`new` ends here; packets compute the parts sixteen lanes at a time with the same
    /// operations).
    #[inline(always)]
    pub fn from_parts(origin: Vec3A, axes: [usize; 3], shear: [f32; 3]) -> Self {
        let [kx, ky, kz] = axes.map(|k| k & 3);
        let o = origin.extend(0.0).to_array();
        Self {
            origin,
            permuted_origin: [o[kx], o[ky], o[kz]],
            kx,
            ky,
            kz,
            sx: shear[0],
            sy: shear[1],
            sz: shear[2],
        }
    }

    /// Every field's bits, for tests that hold two ways of preparing a ray to each other.
    pub fn bits(&self) -> [u32; 12] {
        let f = |x: f32| x.to_bits();
        [
            f(self.origin.x),
            f(self.origin.y),
            f(self.origin.z),
            f(self.permuted_origin[0]),
            f(self.permuted_origin[1]),
            f(self.permuted_origin[2]),
            self.kx as u32,
            self.ky as u32,
            self.kz as u32,
            f(self.sx),
            f(self.sy),
            f(self.sz),
        ]
    }
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
        // that axis points backwards. Chosen with table look-ups rather than branches (the
        // axis is random for incoherent rays, so branches on it mispredict) and components
        // read from arrays (indexing a Vec3A by a run-time axis compiles to a branchy match).
        let a = direction.abs();
        let kz = [[2, 1][(a.y > a.z) as usize], [2, 0][(a.x > a.z) as usize]][(a.x > a.y) as usize];
        let d = direction.to_array();
        let backwards = (d[kz] < 0.0) as usize;
        let kx = [[1, 2, 0], [2, 0, 1]][backwards][kz];
        let ky = [[2, 0, 1], [1, 2, 0]][backwards][kz];
        let sz = 1.0 / d[kz];
        Self::from_parts(origin, [kx, ky, kz], [d[kx] * sz, d[ky] * sz, sz])
    }

    /// Intersects the triangle, returning the hit if its parameter lies in `[0, tmax)`.
    /// Degenerate triangles (zero projected area) never hit.
    #[inline(always)]
    pub fn intersect(&self, tri: &[Vec3A; 3], tmax: f32) -> Option<TriangleHit> {
        // Components are picked from 4-lane arrays with masked indices: indexing a Vec3A
        // by a run-time axis compiles to a branchy match and dominated the cost.
        let lanes = |v: Vec3A| v.extend(0.0).to_array();
        let a = lanes(tri[0] - self.origin);
        let b = lanes(tri[1] - self.origin);
        let c = lanes(tri[2] - self.origin);
        let (kx, ky, kz) = (self.kx & 3, self.ky & 3, self.kz & 3);
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

/// Four triangles in structure-of-arrays layout: `v[vertex][axis]` holds that coordinate
/// of the four lanes. Unused lanes repeat lane 0.
#[derive(Clone, Copy, Debug, PartialEq)]
#[repr(C, align(16))]
pub struct Triangle4 {
    v: [[Vec4; 3]; 3],
}

impl Triangle4 {
    /// Packs one to four triangles; lanes past `tris.len()` repeat the first.
    pub fn pack(tris: &[[Vec3A; 3]]) -> Self {
        assert!((1..=4).contains(&tris.len()));
        let lane = |l: usize| tris[l.min(tris.len() - 1)];
        let mut v = [[Vec4::ZERO; 3]; 3];
        for (k, vk) in v.iter_mut().enumerate() {
            for (axis, va) in vk.iter_mut().enumerate() {
                *va = Vec4::new(
                    lane(0)[k][axis],
                    lane(1)[k][axis],
                    lane(2)[k][axis],
                    lane(3)[k][axis],
                );
            }
        }
        Self { v }
    }

    /// The triangle in lane `l`.
    pub fn lane(&self, l: usize) -> [Vec3A; 3] {
        let l = l & 3;
        self.v.map(|vk| Vec3A::new(vk[0][l], vk[1][l], vk[2][l]))
    }
}

impl WatertightRay {
    /// The watertight test on four triangles at once: the same arithmetic as
    /// [`WatertightRay::intersect`] lane by lane (so the same answers), without branches.
    /// Returns the mask of lanes hit within `[0, tmax)` and their `(t, u, v)`.
    #[inline(always)]
    pub fn intersect4(&self, tri: &Triangle4, tmax: f32) -> (u32, Vec4, Vec4, Vec4) {
        // The permuted rows are read straight from the block (no copy of all nine rows to
        // index), and `relative[k][axis]` is the vertex minus the origin, as in `intersect`.
        let [ox, oy, oz] = self.permuted_origin.map(Vec4::splat);
        let (kx, ky, kz) = (self.kx, self.ky, self.kz);
        let relative = |k: usize| {
            let v = &tri.v[k];
            [v[kx] - ox, v[ky] - oy, v[kz] - oz]
        };
        let (a, b, c) = (relative(0), relative(1), relative(2));
        let (sx, sy) = (Vec4::splat(self.sx), Vec4::splat(self.sy));
        let ax = a[0] - sx * a[2];
        let ay = a[1] - sy * a[2];
        let bx = b[0] - sx * b[2];
        let by = b[1] - sy * b[2];
        let cx = c[0] - sx * c[2];
        let cy = c[1] - sy * c[2];
        let mut u = cx * by - cy * bx;
        let mut v = ax * cy - ay * cx;
        let mut w = bx * ay - by * ax;
        let zero = u.cmpeq(Vec4::ZERO) | v.cmpeq(Vec4::ZERO) | w.cmpeq(Vec4::ZERO);
        if zero.any() {
            // Lanes exactly on an edge in f32: decide them in f64, as the scalar test does.
            let lanes = zero.bitmask();
            let (mut ua, mut va, mut wa) = (u.to_array(), v.to_array(), w.to_array());
            let f = |x: Vec4, l: usize| x.to_array()[l] as f64;
            for l in (0..4).filter(|l| lanes & (1 << l) != 0) {
                let (ax, ay, bx, by, cx, cy) =
                    (f(ax, l), f(ay, l), f(bx, l), f(by, l), f(cx, l), f(cy, l));
                ua[l] = (cx * by - cy * bx) as f32;
                va[l] = (ax * cy - ay * cx) as f32;
                wa[l] = (bx * ay - by * ax) as f32;
            }
            (u, v, w) = (
                Vec4::from_array(ua),
                Vec4::from_array(va),
                Vec4::from_array(wa),
            );
        }
        let neg = u.cmplt(Vec4::ZERO) | v.cmplt(Vec4::ZERO) | w.cmplt(Vec4::ZERO);
        let pos = u.cmpgt(Vec4::ZERO) | v.cmpgt(Vec4::ZERO) | w.cmpgt(Vec4::ZERO);
        let det = u + v + w;
        let t_scaled = Vec4::splat(self.sz) * (u * a[2] + v * b[2] + w * c[2]);
        let inv_det = Vec4::ONE / det;
        let t = t_scaled * inv_det;
        // NaN t (det = 0) fails both comparisons.
        let hit =
            !(neg & pos) & det.cmpne(Vec4::ZERO) & t.cmpge(Vec4::ZERO) & t.cmplt(Vec4::splat(tmax));
        (hit.bitmask(), t, v * inv_det, w * inv_det)
    }
}

/// The sixteen lanes of a register.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
pub fn lanes(v: std::arch::x86_64::__m512) -> [f32; 16] {
    // SAFETY: a __m512 is sixteen f32s (a copy of bits, no AVX-512 instruction).
    unsafe { std::mem::transmute::<std::arch::x86_64::__m512, [f32; 16]>(v) }
}

/// Up to sixteen rays from one origin, for the watertight test run over the rays: one
/// triangle against every lane at once (AVX-512), each lane with its own axis permutation
/// and shear. Every lane computes what [`WatertightRay::intersect4`] computes for its ray,
/// with the same operations, so the answers are the same bit for bit.
#[cfg(target_arch = "x86_64")]
#[derive(Clone, Copy)]
pub struct WatertightPacket {
    origin: Vec3A,
    /// Lanes whose `kx` (`ky`, `kz`) is axis 1, and those where it is axis 2.
    axis_is: [[std::arch::x86_64::__mmask16; 2]; 3],
    shear: [std::arch::x86_64::__m512; 3],
}

#[cfg(target_arch = "x86_64")]
impl WatertightPacket {
    /// `rays` must share their origin (bit for bit).
    ///
    /// # Safety
    /// The CPU must have AVX-512 F.
    #[target_feature(enable = "avx512f")]
    pub fn new(rays: &[WatertightRay; 16]) -> Self {
        use std::arch::x86_64::*;
        let mut axis_is = [[0u16; 2]; 3];
        let mut shear = [[0f32; 16]; 3];
        for (l, r) in rays.iter().enumerate() {
            for (which, k) in [r.kx, r.ky, r.kz].into_iter().enumerate() {
                for axis in 1..3 {
                    axis_is[which][axis - 1] |= ((k == axis) as u16) << l;
                }
            }
            (shear[0][l], shear[1][l], shear[2][l]) = (r.sx, r.sy, r.sz);
        }
        // SAFETY: each row holds 16 f32s.
        let shear = shear.map(|row| unsafe { _mm512_loadu_ps(row.as_ptr()) });
        WatertightPacket {
            origin: rays[0].origin,
            axis_is,
            shear,
        }
    }

    /// The packet of the rays whose axes and shear are given lane by lane: `axis_is[k]` the
    /// lanes whose `kx` (`k = 0`), `ky` (1) or `kz` (2) is axis 1 and those where it is axis
    /// 2, and `shear` the lanes' `sx`, `sy`, `sz`; what [`Self::new`] gathers from the rays.
    pub fn from_lanes(
        origin: Vec3A,
        axis_is: [[std::arch::x86_64::__mmask16; 2]; 3],
        shear: [std::arch::x86_64::__m512; 3],
    ) -> Self {
        WatertightPacket {
            origin,
            axis_is,
            shear,
        }
    }

    /// Lane `l`'s ray, as [`WatertightRay::new`] prepares it: for the few lanes that reach
    /// a leaf, whose triangles are then tested ray by ray (four at once).
    #[inline]
    pub fn lane_ray(&self, l: usize) -> WatertightRay {
        let axis = |is: [std::arch::x86_64::__mmask16; 2]| {
            (is[0] >> l & 1) as usize + 2 * (is[1] >> l & 1) as usize
        };
        let lane = |v| lanes(v)[l & 15];
        WatertightRay::from_parts(self.origin, self.axis_is.map(axis), self.shear.map(lane))
    }

    /// The axis masks and the shear's bits, for tests that hold two ways of making a packet
    /// to each other.
    pub fn bits(&self) -> ([[u16; 2]; 3], [[u32; 16]; 3]) {
        (self.axis_is, self.shear.map(|v| lanes(v).map(f32::to_bits)))
    }

    /// The lanes of `lanes` whose ray hits triangle `t` (lane `t` of `tri`) within
    /// `[0, tmax)` (`tmax` per lane), as [`WatertightRay::intersect4`] decides it.
    ///
    /// # Safety
    /// The CPU must have AVX-512 F.
    #[target_feature(enable = "avx512f")]
    #[inline]
    pub fn hits(
        &self,
        tri: &Triangle4,
        t: usize,
        tmax: std::arch::x86_64::__m512,
        lanes: u16,
    ) -> u16 {
        self.hits_at(tri, t, tmax, lanes).0
    }

    /// [`Self::hits`] with each lane's distance and barycentrics `(t, u, v)` as
    /// [`WatertightRay::intersect4`] returns them (valid in the lanes hit).
    ///
    /// # Safety
    /// The CPU must have AVX-512 F.
    #[target_feature(enable = "avx512f")]
    #[inline]
    pub fn hits_at(
        &self,
        tri: &Triangle4,
        t: usize,
        tmax: std::arch::x86_64::__m512,
        lanes: u16,
    ) -> (
        u16,
        std::arch::x86_64::__m512,
        std::arch::x86_64::__m512,
        std::arch::x86_64::__m512,
    ) {
        use std::arch::x86_64::*;
        let rel = |k: usize| [0, 1, 2].map(|axis| tri.v[k][axis].to_array()[t] - self.origin[axis]);
        let pick = |which: usize, v: [f32; 3]| {
            let [is_y, is_z] = self.axis_is[which];
            let xy = _mm512_mask_blend_ps(is_y, _mm512_set1_ps(v[0]), _mm512_set1_ps(v[1]));
            _mm512_mask_blend_ps(is_z, xy, _mm512_set1_ps(v[2]))
        };
        let [sx, sy, sz] = self.shear;
        let (a, b, c) = (rel(0), rel(1), rel(2));
        let (akz, bkz, ckz) = (pick(2, a), pick(2, b), pick(2, c));
        let ax = _mm512_sub_ps(pick(0, a), _mm512_mul_ps(sx, akz));
        let ay = _mm512_sub_ps(pick(1, a), _mm512_mul_ps(sy, akz));
        let bx = _mm512_sub_ps(pick(0, b), _mm512_mul_ps(sx, bkz));
        let by = _mm512_sub_ps(pick(1, b), _mm512_mul_ps(sy, bkz));
        let cx = _mm512_sub_ps(pick(0, c), _mm512_mul_ps(sx, ckz));
        let cy = _mm512_sub_ps(pick(1, c), _mm512_mul_ps(sy, ckz));
        let cross = |p: __m512, q: __m512, r: __m512, s: __m512| {
            _mm512_sub_ps(_mm512_mul_ps(p, q), _mm512_mul_ps(r, s))
        };
        let mut u = cross(cx, by, cy, bx);
        let mut v = cross(ax, cy, ay, cx);
        let mut w = cross(bx, ay, by, ax);
        let zero = _mm512_setzero_ps();
        let on_edge = _mm512_mask_cmp_ps_mask::<_CMP_EQ_OQ>(lanes, u, zero)
            | _mm512_mask_cmp_ps_mask::<_CMP_EQ_OQ>(lanes, v, zero)
            | _mm512_mask_cmp_ps_mask::<_CMP_EQ_OQ>(lanes, w, zero);
        if on_edge != 0 {
            // Lanes exactly on an edge in f32: decide them in f64, as the scalar test does.
            let lane = |x: __m512| {
                let mut a = [0f32; 16];
                // SAFETY: `a` holds 16 f32s.
                unsafe { _mm512_storeu_ps(a.as_mut_ptr(), x) };
                a
            };
            let [ax, ay, bx, by, cx, cy] = [ax, ay, bx, by, cx, cy].map(lane);
            let (mut ua, mut va, mut wa) = (lane(u), lane(v), lane(w));
            let mut todo = on_edge;
            while todo != 0 {
                let l = todo.trailing_zeros() as usize;
                todo &= todo - 1;
                let f = |x: [f32; 16]| x[l] as f64;
                let (ax, ay, bx, by, cx, cy) = (f(ax), f(ay), f(bx), f(by), f(cx), f(cy));
                ua[l] = (cx * by - cy * bx) as f32;
                va[l] = (ax * cy - ay * cx) as f32;
                wa[l] = (bx * ay - by * ax) as f32;
            }
            // SAFETY: each array holds 16 f32s.
            unsafe {
                (u, v, w) = (
                    _mm512_loadu_ps(ua.as_ptr()),
                    _mm512_loadu_ps(va.as_ptr()),
                    _mm512_loadu_ps(wa.as_ptr()),
                );
            }
        }
        let below = |x: __m512| _mm512_cmp_ps_mask::<_CMP_LT_OQ>(x, zero);
        let above = |x: __m512| _mm512_cmp_ps_mask::<_CMP_GT_OQ>(x, zero);
        let neg = below(u) | below(v) | below(w);
        let pos = above(u) | above(v) | above(w);
        let det = _mm512_add_ps(_mm512_add_ps(u, v), w);
        let along = _mm512_add_ps(
            _mm512_add_ps(_mm512_mul_ps(u, akz), _mm512_mul_ps(v, bkz)),
            _mm512_mul_ps(w, ckz),
        );
        let t_scaled = _mm512_mul_ps(sz, along);
        let inv_det = _mm512_div_ps(_mm512_set1_ps(1.0), det);
        let t = _mm512_mul_ps(t_scaled, inv_det);
        let hit = lanes
            & !(neg & pos)
            & _mm512_cmp_ps_mask::<_CMP_NEQ_UQ>(det, zero)
            & _mm512_cmp_ps_mask::<_CMP_GE_OQ>(t, zero)
            & _mm512_cmp_ps_mask::<_CMP_LT_OQ>(t, tmax);
        (hit, t, _mm512_mul_ps(v, inv_det), _mm512_mul_ps(w, inv_det))
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

    /// The packet test decides every (ray, triangle) pair as `intersect4` does: random
    /// and integer-grid triangles (rays through their shared edges and vertices), degenerate
    /// ones, axis-aligned and mixed directions, finite and infinite `tmax`.
    #[cfg(target_arch = "x86_64")]
    #[test]
    fn packet_test_decides_every_pair_as_the_single_ray_test() {
        use crate::sampling::rng::{hash4, to_unit_f32};
        use std::arch::x86_64::_mm512_loadu_ps;
        if !crate::simd::has(crate::simd::SimdLevel::Avx512) {
            return;
        }
        let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 21));
        let mut hits = 0;
        for case in 0..3000u64 {
            let grid = case % 3 == 0;
            let point = |k: u64| {
                let p = vec3a(
                    unit(case, 3 * k),
                    unit(case, 3 * k + 1),
                    unit(case, 3 * k + 2),
                );
                if grid {
                    (p * 4.0).round()
                } else {
                    p * 2.0 - 1.0
                }
            };
            let tris: Vec<[Vec3A; 3]> = (0..4u64)
                .map(|t| match (case + t) % 9 {
                    0 => [point(10 * t), point(10 * t), point(10 * t + 1)],
                    _ => [point(10 * t), point(10 * t + 1), point(10 * t + 2)],
                })
                .collect();
            let block = Triangle4::pack(&tris);
            let origin = if grid {
                (point(99) + 0.5).floor()
            } else {
                point(99) * 3.0
            };
            let rays: [WatertightRay; 16] = std::array::from_fn(|l| {
                let aim = tris[l % 4][l / 4 % 3] + (point(100 + l as u64) - 0.5) * 0.3;
                let mut d = aim - origin;
                match (case as usize + l) % 6 {
                    0 => d = vec3a(0.0, 0.0, if d.z < 0.0 { -1.0 } else { 1.0 }),
                    1 => d.x = 0.0,
                    2 if grid => d = tris[l % 4][0] - origin,
                    _ => {}
                }
                if d.length() == 0.0 {
                    d = Vec3A::Y;
                }
                WatertightRay::new(origin, d)
            });
            let tmax: [f32; 16] =
                std::array::from_fn(|l| [f32::INFINITY, 1.0, 3.0, 0.0][(case as usize + l) % 4]);
            // SAFETY: AVX-512 F detected; `tmax` holds 16 f32s.
            let packet = unsafe { WatertightPacket::new(&rays) };
            for t in 0..4 {
                let got =
                    unsafe { packet.hits(&block, t, _mm512_loadu_ps(tmax.as_ptr()), u16::MAX) };
                for l in 0..16 {
                    let alone = rays[l].intersect4(&block, tmax[l]).0 >> t & 1 != 0;
                    assert_eq!(got >> l & 1 != 0, alone, "case {case} triangle {t} ray {l}");
                    hits += alone as usize;
                }
            }
        }
        assert!(hits > 5000, "{hits} hits");
    }

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
    fn four_wide_matches_scalar_lane_by_lane() {
        use crate::sampling::rng::SampleRng;
        let r = |i: u64, d: u64| SampleRng::new(9, i, 0).get(d) * 2.0 - 1.0;
        for i in 0..2000u64 {
            let tris: Vec<[Vec3A; 3]> = (0..4)
                .map(|k| {
                    [0, 1, 2].map(|v| {
                        vec3a(
                            r(i, k * 9 + v * 3),
                            r(i, k * 9 + v * 3 + 1),
                            r(i, k * 9 + v * 3 + 2),
                        )
                    })
                })
                .collect();
            let n = 1 + (i % 4) as usize;
            let packed = Triangle4::pack(&tris[..n]);
            let ray = WatertightRay::new(
                vec3a(r(i, 40), r(i, 41), r(i, 42)),
                vec3a(r(i, 43), r(i, 44), r(i, 45)),
            );
            let tmax = if i % 3 == 0 { 0.7 } else { f32::INFINITY };
            let (mask, t, u, v) = ray.intersect4(&packed, tmax);
            for l in 0..4 {
                let scalar = ray.intersect(&packed.lane(l), tmax);
                assert_eq!(mask & (1 << l) != 0, scalar.is_some(), "ray {i} lane {l}");
                if let Some(h) = scalar {
                    assert_eq!(
                        (h.t, h.u, h.v),
                        (t.to_array()[l], u.to_array()[l], v.to_array()[l])
                    );
                }
            }
            assert_eq!(packed.lane(0), tris[0]);
        }
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
