//! Clarberg's equal-area octahedral map of the full sphere onto `[0,1]^2` (CAM08 §3;
//! Clarberg, "Fast equal-area mapping of the (hemi)sphere using SIMD", 2008; pbrt-v4's
//! `EqualAreaSquareToSphere` / `EqualAreaSphereToSquare` / `WrapEqualAreaSquare`).
//!
//! The one parameterization of the sphere in the crate: visibility records, environment
//! maps and product distributions all use it, so a texel of a `res x res` grid is always the
//! solid angle `4π / res²`, and the quadtree nodes of a `2^L x 2^L` grid are contiguous
//! ranges in Morton (Z) order.
//!
//! Orientation: the square's centre is `+y`, its four corners are `-y`; `u` grows with `+x`
//! and `v` with `+z`. (pbrt's `z` is our `y`, pbrt's `y` our `z`.)

use glam::{DVec2, DVec3, UVec2, Vec2, Vec3};

/// Solid angle of one texel of a `res x res` octahedral grid, in steradians.
#[inline]
pub fn texel_solid_angle(res: u32) -> f64 {
    4.0 * std::f64::consts::PI / (res as f64 * res as f64)
}

/// One body for the map in `f32` and `f64`: the two precisions stay the same map.
macro_rules! square_to_sphere_in {
    ($(#[$doc:meta])* $name:ident, $vec2:ty, $vec3:ident, $float:ident) => {
        $(#[$doc])*
        #[inline]
        pub fn $name(p: $vec2) -> $vec3 {
            let u = 2.0 * p.x - 1.0;
            let v = 2.0 * p.y - 1.0;
            let (up, vp) = (u.abs(), v.abs());
            // Signed distance from the diagonal |u| + |v| = 1, which is the equator.
            let signed_distance = 1.0 - (up + vp);
            let r = 1.0 - signed_distance.abs();
            let phi = if r == 0.0 { 1.0 } else { (vp - up) / r + 1.0 }
                * std::$float::consts::FRAC_PI_4;
            let height = (1.0 - r * r).copysign(signed_distance);
            let (sin_phi, cos_phi) = phi.sin_cos();
            let radial = r * (2.0 - r * r).max(0.0).sqrt();
            $vec3::new(
                cos_phi.copysign(u) * radial,
                height,
                sin_phi.copysign(v) * radial,
            )
        }
    };
}

square_to_sphere_in!(
    /// Maps a point of `[0,1]^2` to a unit direction. Total and continuous on the closed
    /// square; the border folds onto itself (see [`wrap_texel`]).
    square_to_sphere, Vec2, Vec3, f32
);

square_to_sphere_in!(
    /// [`square_to_sphere`] in `f64`, unit length to `~1e-16`.
    square_to_sphere_f64, DVec2, DVec3, f64
);

/// `atan(b) · 2/π` on `[0, 1]`, the odd polynomial pbrt-v4 uses (max error ~1e-6).
#[inline]
fn atan_2_over_pi(b: f32) -> f32 {
    const T: [f32; 7] = [
        4.067_586e-6,
        0.636_226_5,
        0.615_720_2e-2,
        -0.247_333_73,
        0.881_770_7e-1,
        0.419_038_8e-1,
        -0.251_390_97e-1,
    ];
    let mut acc = T[6];
    for c in T[..6].iter().rev() {
        acc = acc * b + c;
    }
    acc
}

/// Maps a unit direction to `[0,1]^2`; the inverse of [`square_to_sphere`]. The input must
/// be normalised (to f32 precision).
#[inline]
pub fn sphere_to_square(d: Vec3) -> Vec2 {
    let (ax, ay, az) = (d.x.abs(), d.y.abs(), d.z.abs());
    // r = sqrt(1 - |y|); near the poles 1 - |y| cancels catastrophically in f32, so it is
    // taken from the other two components there: 1 - |y| = (x² + z²) / (1 + |y|).
    let one_minus_y = if ay > 0.5 {
        (ax * ax + az * az) / (1.0 + ay)
    } else {
        1.0 - ay
    };
    let r = one_minus_y.max(0.0).sqrt();
    let a = ax.max(az);
    let b = if a == 0.0 { 0.0 } else { ax.min(az) / a };
    let mut phi = atan_2_over_pi(b);
    if ax < az {
        phi = 1.0 - phi;
    }
    let mut v = phi * r;
    let mut u = r - v;
    if d.y < 0.0 {
        // Lower hemisphere: fold the triangle outwards, onto the square's corners.
        std::mem::swap(&mut u, &mut v);
        u = 1.0 - u;
        v = 1.0 - v;
    }
    let u = u.copysign(d.x);
    let v = v.copysign(d.z);
    Vec2::new(0.5 * (u + 1.0), 0.5 * (v + 1.0))
}

/// The texel of a `res x res` grid that contains direction `d` (`res >= 1`).
#[inline]
pub fn texel_of(d: Vec3, res: u32) -> UVec2 {
    texel_of_square(sphere_to_square(d), res)
}

/// The texel of a `res x res` grid containing point `p` of the square (clamped to it).
#[inline]
pub fn texel_of_square(p: Vec2, res: u32) -> UVec2 {
    let p = p * res as f32;
    let max = res - 1;
    UVec2::new(
        (p.x.max(0.0) as u32).min(max),
        (p.y.max(0.0) as u32).min(max),
    )
}

/// The direction through the centre of texel `(x, y)` of a `res x res` grid.
#[inline]
pub fn texel_center(texel: UVec2, res: u32) -> Vec3 {
    square_to_sphere((texel.as_vec2() + 0.5) / res as f32)
}

/// Brings a texel coordinate that lies up to one grid width outside `[0, res)` back into
/// the grid: the neighbour across a border of the square is its mirror image, because the
/// map folds each edge onto itself about the edge's midpoint. Corners fold to the opposite
/// corner (all four are `-y`).
#[inline]
pub fn wrap_texel(x: i64, y: i64, res: u32) -> UVec2 {
    let n = res as i64;
    let (mut x, mut y) = (x, y);
    if x < 0 {
        x = -x - 1;
        y = n - 1 - y;
    } else if x >= n {
        x = 2 * n - 1 - x;
        y = n - 1 - y;
    }
    if y < 0 {
        x = n - 1 - x;
        y = -y - 1;
    } else if y >= n {
        x = n - 1 - x;
        y = 2 * n - 1 - y;
    }
    debug_assert!((0..n).contains(&x) && (0..n).contains(&y));
    UVec2::new(x as u32, y as u32)
}

/// Largest supported grid side, per axis: Morton codes hold 16 bits of each coordinate.
pub const MAX_RESOLUTION: u32 = 1 << 16;

/// Spreads the low 16 bits of `v` to the even bit positions.
#[inline]
const fn part1by1(v: u32) -> u32 {
    let mut x = v & 0x0000_ffff;
    x = (x | (x << 8)) & 0x00ff_00ff;
    x = (x | (x << 4)) & 0x0f0f_0f0f;
    x = (x | (x << 2)) & 0x3333_3333;
    (x | (x << 1)) & 0x5555_5555
}

/// Gathers the even bits of `v` into the low 16 bits.
#[inline]
const fn compact1by1(v: u32) -> u32 {
    let mut x = v & 0x5555_5555;
    x = (x | (x >> 1)) & 0x3333_3333;
    x = (x | (x >> 2)) & 0x0f0f_0f0f;
    x = (x | (x >> 4)) & 0x00ff_00ff;
    (x | (x >> 8)) & 0x0000_ffff
}

/// Morton (Z-order) code of texel `(x, y)`, both `< 2^16`: `x` takes the even bits, `y` the
/// odd ones, so the four children of a quadtree node are `(0,0), (1,0), (0,1), (1,1)`.
#[inline]
pub const fn morton_encode(x: u32, y: u32) -> u32 {
    part1by1(x) | (part1by1(y) << 1)
}

/// The texel of a Morton code; the inverse of [`morton_encode`].
#[inline]
pub const fn morton_decode(code: u32) -> UVec2 {
    UVec2::new(compact1by1(code), compact1by1(code >> 1))
}

/// The Morton range `[start, end)` of texels of level `finest` (a `2^finest` grid) that the
/// quadtree node `node` of level `level <= finest` covers: a node of a coarser level is the
/// block of `4^(finest - level)` consecutive finer codes.
#[inline]
pub const fn quadtree_range(level: u32, node: u32, finest: u32) -> (u64, u64) {
    let shift = 2 * (finest - level);
    let start = (node as u64) << shift;
    (start, start + (1u64 << shift))
}

/// The node of level `level` that contains texel Morton code `code` of level `finest`.
#[inline]
pub const fn quadtree_node(code: u32, finest: u32, level: u32) -> u32 {
    ((code as u64) >> (2 * (finest - level))) as u32
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sampling::rng::{hash4, to_unit_f32};

    fn random_dir(i: u64) -> Vec3 {
        let u = to_unit_f32(hash4(7, i, 0, 0));
        let v = to_unit_f32(hash4(7, i, 0, 1));
        let y = 1.0 - 2.0 * u;
        let r = (1.0 - y * y).max(0.0).sqrt();
        let phi = 2.0 * std::f32::consts::PI * v;
        Vec3::new(r * phi.cos(), y, r * phi.sin())
    }

    fn special_dirs() -> Vec<Vec3> {
        let mut dirs = Vec::new();
        for &a in &[-1.0f32, -0.0, 0.0, 1.0] {
            for &b in &[-1.0f32, -0.0, 0.0, 1.0] {
                for &c in &[-1.0f32, -0.0, 0.0, 1.0] {
                    let d = Vec3::new(a, b, c);
                    if d.length() > 0.0 {
                        dirs.push(d.normalize());
                    }
                }
            }
        }
        // Octant seams and the equator, slightly off and exactly on.
        for i in 0..1000 {
            let t = i as f32 / 999.0 * std::f32::consts::TAU;
            dirs.push(Vec3::new(t.cos(), 0.0, t.sin()));
            dirs.push(Vec3::new(t.cos(), t.sin(), 0.0));
            dirs.push(Vec3::new(0.0, t.cos(), t.sin()));
            dirs.push(Vec3::new(t.cos(), 1e-7, t.sin()).normalize());
        }
        dirs
    }

    #[test]
    fn round_trip_over_a_million_directions_and_the_special_ones() {
        let mut worst = 0.0f32;
        let check = |d: Vec3, worst: &mut f32| {
            let p = sphere_to_square(d);
            assert!(
                (0.0..=1.0).contains(&p.x) && (0.0..=1.0).contains(&p.y),
                "{d} -> {p}"
            );
            let back = square_to_sphere(p);
            assert!((back.length() - 1.0).abs() < 1e-5, "{d} -> {back}");
            *worst = worst.max((back - d).length());
        };
        for i in 0..1_000_000 {
            check(random_dir(i), &mut worst);
        }
        for d in special_dirs() {
            check(d, &mut worst);
        }
        assert!(worst <= 1e-5, "worst round-trip error {worst}");
    }

    #[test]
    fn orientation_centre_is_up_corners_are_down() {
        assert!((square_to_sphere(Vec2::splat(0.5)) - Vec3::Y).length() < 1e-6);
        for c in [Vec2::ZERO, Vec2::X, Vec2::Y, Vec2::ONE] {
            assert!((square_to_sphere(c) + Vec3::Y).length() < 1e-6, "{c}");
        }
        assert!(square_to_sphere(Vec2::new(1.0, 0.5)).x > 0.99);
        assert!(square_to_sphere(Vec2::new(0.5, 1.0)).z > 0.99);
    }

    /// Solid angle of a texel as the spherical polygon its border maps to, summed as
    /// triangles fanned from the texel's centre (Van Oosterom & Strackee 1983).
    fn texel_polygon_solid_angle(texel: UVec2, res: u32, per_edge: u32) -> f64 {
        let corner = |i: u32| {
            let t = i as f32 / per_edge as f32;
            let p = match i / per_edge {
                0 => Vec2::new(t, 0.0),
                1 => Vec2::new(1.0, t - 1.0),
                2 => Vec2::new(3.0 - t, 1.0),
                _ => Vec2::new(0.0, 4.0 - t),
            };
            square_to_sphere((texel.as_vec2() + p) / res as f32).as_dvec3()
        };
        let c = texel_center(texel, res).as_dvec3();
        (0..4 * per_edge)
            .map(|i| {
                let (a, b) = (corner(i), corner((i + 1) % (4 * per_edge)));
                let numerator = c.dot(a.cross(b));
                let denominator = 1.0 + c.dot(a) + a.dot(b) + b.dot(c);
                2.0 * numerator.atan2(denominator)
            })
            .sum::<f64>()
            .abs()
    }

    #[test]
    fn every_texel_has_the_same_solid_angle() {
        let res = 64u32;
        let expected = texel_solid_angle(res);
        let mut total = 0.0;
        for y in 0..res {
            for x in 0..res {
                let omega = texel_polygon_solid_angle(UVec2::new(x, y), res, 16);
                total += omega;
                let rel = (omega - expected).abs() / expected;
                assert!(rel < 0.01, "texel ({x},{y}): {omega} vs {expected}");
            }
        }
        assert!((total - 4.0 * std::f64::consts::PI).abs() < 1e-3, "{total}");
    }

    #[test]
    fn uniform_directions_fill_the_texels_evenly() {
        // Monte Carlo: uniform sphere directions (drawn without the map) binned by texel
        // follow a uniform pdf in the chi-square sense.
        use crate::sampling::chi2::{chi2_sphere, Chi2Params};
        let params = Chi2Params::with_resolution(64).with_subdivisions(1);
        let uniform_pdf = |_: Vec3| 1.0 / (4.0 * std::f64::consts::PI);
        let outcome = chi2_sphere(
            (0..4_000_000).map(|i| Some(random_dir(i))),
            uniform_pdf,
            &params,
        );
        assert!(outcome.passed, "{outcome:?}");
        assert_eq!(outcome.dof, 4095);
    }

    #[test]
    fn wrapping_is_continuous_across_every_edge() {
        for res in [2u32, 3, 8, 64] {
            let spacing = (texel_solid_angle(res)).sqrt() as f32;
            let n = res as i64;
            for i in -1..=n {
                for (x, y, ix, iy) in [
                    (i, -1, i.clamp(0, n - 1), 0),
                    (i, n, i.clamp(0, n - 1), n - 1),
                    (-1, i, 0, i.clamp(0, n - 1)),
                    (n, i, n - 1, i.clamp(0, n - 1)),
                ] {
                    let outside = wrap_texel(x, y, res);
                    let inside = UVec2::new(ix as u32, iy as u32);
                    let d = texel_center(outside, res).distance(texel_center(inside, res));
                    // A grid neighbour (diagonal at a corner) is within ~2 texel spacings.
                    assert!(
                        d < 2.5 * spacing,
                        "res {res}: ({x},{y}) -> {outside} vs {inside}: {d}"
                    );
                    // The wrapped texel is a different texel except at corners of tiny grids.
                    assert!(outside.x < res && outside.y < res);
                }
            }
            // Inside the grid, wrapping is the identity.
            for x in 0..n {
                for y in 0..n {
                    assert_eq!(wrap_texel(x, y, res), UVec2::new(x as u32, y as u32));
                }
            }
        }
    }

    #[test]
    fn the_continuous_fold_matches_the_texel_wrap() {
        // A point just outside the left edge lies where its mirror image does.
        for i in 0..100 {
            let v = (i as f32 + 0.5) / 100.0;
            let p_in = Vec2::new(0.001, 1.0 - v);
            let p_edge = Vec2::new(0.0, v);
            let a = square_to_sphere(p_edge);
            let b = square_to_sphere(Vec2::new(0.0, 1.0 - v));
            assert!((a - b).length() < 1e-5, "edge folds onto itself at v = {v}");
            assert!((square_to_sphere(p_in) - a).length() < 0.01);
        }
    }

    #[test]
    fn morton_round_trip_and_quadtree_ranges() {
        for &(x, y) in &[
            (0u32, 0u32),
            (1, 0),
            (0, 1),
            (65535, 65535),
            (12345, 54321),
            (1, 65535),
        ] {
            assert_eq!(morton_decode(morton_encode(x, y)), UVec2::new(x, y));
        }
        for i in 0..100_000u32 {
            let code = hash4(1, i as u64, 0, 0) as u32;
            let t = morton_decode(code);
            assert_eq!(morton_encode(t.x, t.y), code);
        }
        assert_eq!(morton_encode(1, 0), 1);
        assert_eq!(morton_encode(0, 1), 2);
        assert_eq!(morton_encode(1, 1), 3);
        // Every texel of an 8x8 grid lies in the range of its ancestors.
        for x in 0..8 {
            for y in 0..8 {
                let code = morton_encode(x, y);
                for level in 0..=3 {
                    let node = quadtree_node(code, 3, level);
                    let (a, b) = quadtree_range(level, node, 3);
                    assert!((a..b).contains(&(code as u64)));
                    let coarse = morton_decode(node);
                    let shift = 3 - level;
                    assert_eq!(coarse, UVec2::new(x >> shift, y >> shift));
                }
            }
        }
        assert_eq!(quadtree_range(0, 0, 16), (0, 1 << 32));
    }
}
