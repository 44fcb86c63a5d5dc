//! Row B's bound against the geometry term at random points of random regions (Fig. 6.5),
//! its tightness at a region of one point, and the unbounded light inside the ball.

use super::*;
use crate::sampling::rng::{hash4, to_unit_f64};

fn unit(seed: u64, k: u64) -> f64 {
    to_unit_f64(hash4(seed, k, 0, 19))
}

fn random_dir(seed: u64, k: u64) -> Vec3 {
    let z = 2.0 * unit(seed, 2 * k) - 1.0;
    let phi = std::f64::consts::TAU * unit(seed, 2 * k + 1);
    let r = (1.0 - z * z).max(0.0).sqrt();
    DVec3::new(r * phi.cos(), r * phi.sin(), z).as_vec3()
}

/// A unit vector within `cone` of the unit `n` (uniform in the cap's solid angle).
fn within_cone(n: Vec3, cone: f32, seed: u64, k: u64) -> Vec3 {
    let cos_max = (cone as f64).cos();
    let z = 1.0 - unit(seed, 2 * k) * (1.0 - cos_max);
    let phi = std::f64::consts::TAU * unit(seed, 2 * k + 1);
    let r = (1.0 - z * z).max(0.0).sqrt();
    let (t, b) = n.any_orthonormal_pair();
    (t * (r * phi.cos()) as f32 + b * (r * phi.sin()) as f32 + n * z as f32).normalize()
}

/// A point in the ball of `radius` about `p` (uniform in volume).
fn within_ball(p: Vec3, radius: f32, seed: u64, k: u64) -> Vec3 {
    let d = random_dir(seed, 3 * k);
    p + d * (radius * unit(seed, 3 * k + 2).cbrt() as f32)
}

/// 200 random regions (radius 0 to 0.5, cones 0 to 60°) and lights (distance 0.6 to 3,
/// any normal), 50 points and normals of each region apiece (1e4 in all, point and
/// directional): `G <= G_max` everywhere; and `G_max` is not loose everywhere (over the
/// regions the largest `G` found is within a factor 3 of `G_max` for most).
#[test]
fn b_bounds_u_at_random_points_of_each_region() {
    let mut close = 0;
    let mut positive = 0;
    for case in 0..200u64 {
        let region = Region {
            position: Vec3::new(unit(1, case) as f32, 0.0, unit(2, case) as f32),
            normal: random_dir(3, case),
            radius: 0.5 * unit(4, case) as f32,
            cone: (60.0f64.to_radians() * unit(5, case)) as f32,
        };
        let dist = 0.6 + 2.4 * unit(6, case);
        let v = region.position + random_dir(7, case) * dist as f32;
        let m = random_dir(8, case);
        let w = random_dir(9, case);
        let (g_max, d_max) = (point_bound(&region, v, m), directional_bound(&region, w));
        assert!(g_max.is_finite() && d_max.is_finite());
        let mut best = 0.0f64;
        for k in 0..50u64 {
            let x = within_ball(region.position, region.radius, 10 + case, k);
            let n = within_cone(region.normal, region.cone, 20 + case, k);
            let g = point_g(x, n, v, m);
            assert!(g <= g_max * (1.0 + 1e-6), "case {case}: G {g} > {g_max}");
            best = best.max(g);
            let c = n.as_dvec3().dot(w.as_dvec3()).max(0.0);
            assert!(
                c <= d_max * (1.0 + 1e-6) + 1e-12,
                "case {case}: cos {c} > {d_max}"
            );
        }
        if best > 0.0 {
            positive += 1;
            close += (best * 3.0 >= g_max) as u32;
        }
    }
    assert!(
        positive > 50 && close * 2 > positive,
        "{close} of {positive}"
    );
}

/// A region of one point and one normal: the bound is `G` itself (to the slack), for a
/// light in front, grazing and behind.
#[test]
fn a_point_region_bounds_exactly() {
    let region = Region {
        position: Vec3::new(0.2, 0.0, -0.1),
        normal: Vec3::Y,
        radius: 0.0,
        cone: 0.0,
    };
    for (v, m) in [
        (
            Vec3::new(0.5, 1.0, 0.3),
            Vec3::new(0.1, -1.0, 0.0).normalize(),
        ),
        (Vec3::new(1.5, 0.01, 0.3), -Vec3::X),
        (Vec3::new(0.5, -1.0, 0.3), Vec3::Y),
    ] {
        let g = point_g(region.position, region.normal, v, m);
        let b = point_bound(&region, v, m);
        // The slack (1e-6 rad per angle) is the whole gap: relative 1e-4 at grazing.
        assert!(b >= g && b <= g * (1.0 + 1e-3) + 1e-9, "{v}: {b} vs {g}");
    }
    let w = Vec3::new(0.3, 0.8, 0.1).normalize();
    let b = directional_bound(&region, w);
    assert!((b - w.y as f64).abs() < 1e-5, "{b}");
    // Behind the record, but within its cone of normals: B keeps the light.
    let wide = Region {
        cone: 0.5,
        radius: 0.2,
        ..region
    };
    let below = Vec3::new(1.0, -0.2, 0.0).normalize();
    assert_eq!(directional_bound(&region, below), 0.0);
    assert!(directional_bound(&wide, below) > 0.0);
    let (v, m) = (Vec3::new(1.2, -0.05, -0.1), -Vec3::X);
    assert_eq!(point_g(region.position, region.normal, v, m), 0.0);
    assert!(point_bound(&wide, v, m) > 0.0);
}

/// A light within the ball is unbounded; one just outside is finite.
#[test]
fn a_light_within_the_ball_is_unbounded() {
    let region = Region {
        position: Vec3::ZERO,
        normal: Vec3::Y,
        radius: 0.1,
        cone: 0.2,
    };
    assert_eq!(
        point_bound(&region, Vec3::new(0.05, 0.05, 0.0), -Vec3::Y),
        f64::INFINITY
    );
    assert!(point_bound(&region, Vec3::new(0.0, 0.1001, 0.0), -Vec3::Y).is_finite());
}
