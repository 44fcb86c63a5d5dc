//! AO against known answers (open plane, closed box, the view factor of a wall) at several
//! scene scales and ray counts; cache AO and the §6.1 criterion against linear scans
//! written from the formulas; determinism over thread counts; extremes and bad input.

use super::*;
use crate::bsdf::Material;
use crate::scenes::shapes::{quad, BoxGrid, Tri};
use crate::visibility::cache::tests::brute_m_nearest;
use crate::visibility::cache::VisibilityCache;
use crate::visibility::params::CacheParams;

pub(crate) fn scene_of(tris: &[Tri]) -> Scene {
    let vertices: Vec<[f32; 3]> = tris.iter().flatten().map(|v| v.to_array()).collect();
    let faces: Vec<[i64; 3]> = (0..tris.len() as i64)
        .map(|i| [3 * i, 3 * i + 1, 3 * i + 2])
        .collect();
    let mut s = Scene::new();
    s.add_indexed(
        &vertices,
        &faces,
        Material::lambert([0.5; 3]).unwrap(),
        None,
    )
    .unwrap();
    s
}

/// A floor `y = 0` of half-size `10·scale` and, with `wall`, a wall `x = h` of height `H`
/// running `±100·h` along z (all lengths times `scale`).
pub(crate) fn floor_and_wall(scale: f32, h: f32, height: f32, wall: bool) -> Scene {
    let s = scale;
    let mut t = Vec::new();
    quad(
        &mut t,
        Vec3::new(-10.0, 0.0, -10.0) * s,
        Vec3::new(10.0, 0.0, -10.0) * s,
        Vec3::new(10.0, 0.0, 10.0) * s,
        Vec3::new(-10.0, 0.0, 10.0) * s,
    );
    if wall {
        let l = 100.0 * h;
        quad(
            &mut t,
            Vec3::new(h, 0.0, -l) * s,
            Vec3::new(h, 0.0, l) * s,
            Vec3::new(h, height, l) * s,
            Vec3::new(h, height, -l) * s,
        );
    }
    scene_of(&t)
}

/// Cosine-weighted visible fraction at distance `h` from an infinitely long wall of
/// height `H`: one minus the view factor `(1 − h/√(h² + H²))/2` (Nusselt's analogue in 2D).
pub(crate) fn wall_ao(h: f32, height: f32) -> f64 {
    let (h, height) = (h as f64, height as f64);
    0.5 * (1.0 + h / (h * h + height * height).sqrt())
}

pub(crate) fn no_progress() -> impl FnMut(usize, usize) -> bool + Send {
    |_, _| true
}

#[test]
fn reference_on_open_plane_is_one() {
    for scale in [1e-4f32, 1.0, 1e4] {
        let scene = floor_and_wall(scale, 1.0, 1.0, false);
        let pts: Vec<Vec3> = (0..20)
            .map(|i| Vec3::new(i as f32 * 0.3 - 3.0, 0.0, 0.5) * scale)
            .collect();
        let a = reference_ao_points(&scene, &pts, &vec![Vec3::Y; 20], 256, 1, None).unwrap();
        assert!(a.iter().all(|&v| v == 1.0), "scale {scale}: {a:?}");
    }
}

#[test]
fn reference_in_closed_box_is_zero() {
    for scale in [1e-4f32, 1.0, 1e4] {
        let mut t = Vec::new();
        BoxGrid::new(
            Vec3::splat(-1.0) * scale,
            Vec3::splat(1.0) * scale,
            0.5 * scale,
        )
        .closed(&mut t);
        let scene = scene_of(&t);
        let pts = [
            Vec3::new(0.0, -1.0, 0.0) * scale,
            Vec3::new(0.7, -1.0, -0.9) * scale,
        ];
        let a = reference_ao_points(&scene, &pts, &[Vec3::Y; 2], 1024, 3, None).unwrap();
        assert_eq!(a, vec![0.0, 0.0], "scale {scale}");
    }
}

#[test]
fn reference_beside_a_wall_is_unbiased_for_any_ray_count() {
    // Stratification on a c x r grid must stay unbiased when N is not a square (c = 1
    // for a prime). Points spread along the wall share one expectation; the standard error
    // of their mean comes from their spread.
    let (h, height) = (1.0f32, 1.5f32);
    for scale in [1e-4f32, 1.0, 1e4] {
        let scene = floor_and_wall(scale, h, height, true);
        // Rays leave from the offset origin, which sees a wall lower by the offset (a few
        // 1e-4 of h here); the ends of the wall at ±100h take less than 1e-6 away.
        let lift = scene.ray_epsilon(Vec3::ZERO) / scale;
        let expected = wall_ao(h, height - lift);
        for rays in [7u32, 100, 1000, 1024] {
            let p = 400;
            let pts: Vec<Vec3> = (0..p)
                .map(|i| Vec3::new(0.0, 0.0, (i as f32 / p as f32 - 0.5) * 8.0) * scale)
                .collect();
            let a = reference_ao_points(&scene, &pts, &vec![Vec3::Y; p], rays, 11, None).unwrap();
            let mean = a.iter().map(|&v| v as f64).sum::<f64>() / p as f64;
            let var = a.iter().map(|&v| (v as f64 - mean).powi(2)).sum::<f64>() / (p - 1) as f64;
            let se = (var / p as f64).sqrt();
            assert!(se > 0.0, "scale {scale} rays {rays}: no spread");
            assert!(
                (mean - expected).abs() < 4.0 * se,
                "scale {scale} rays {rays}: mean {mean} vs {expected} (se {se})"
            );
        }
    }
}

#[test]
fn reference_of_a_single_triangle_above_a_point() {
    let scene = scene_of(&[[
        Vec3::new(-1.0, 1.0, -1.0),
        Vec3::new(1.0, 1.0, -1.0),
        Vec3::new(0.0, 1.0, 1.0),
    ]]);
    let a = reference_ao_points(
        &scene,
        &[Vec3::ZERO, Vec3::new(0.0, 2.0, 0.0)],
        &[Vec3::Y; 2],
        1024,
        0,
        None,
    )
    .unwrap();
    assert!(a[0] > 0.0 && a[0] < 1.0, "{a:?}");
    assert_eq!(a[1], 1.0);
}

#[test]
fn bad_input_names_the_argument() {
    let scene = floor_and_wall(1.0, 1.0, 1.0, false);
    let msg = |e: Error| e.to_string();
    for rays in [0, MAX_AO_RAYS + 1] {
        let e = reference_ao_points(&scene, &[Vec3::ZERO], &[Vec3::Y], rays, 0, None).unwrap_err();
        assert!(msg(e).starts_with("reference_rays"));
    }
    let e = reference_ao_points(&scene, &[Vec3::ZERO], &[], 4, 0, None).unwrap_err();
    assert!(msg(e).starts_with("normals"));
    let empty = Scene::new();
    let e = reference_ao_points(&empty, &[Vec3::ZERO], &[Vec3::Y], 4, 0, None).unwrap_err();
    assert!(msg(e).starts_with("scene"));
}

/// A cache with records traced at scattered points on the floor beside the wall (some
/// near its foot, so that `R_i` is finite and small).
pub(crate) fn wall_cache(params: CacheParams) -> (Scene, VisibilityCache) {
    let scene = floor_and_wall(1.0, 1.0, 1.5, true);
    let cache = VisibilityCache::new(params).unwrap();
    for i in 0..60u64 {
        let u = crate::scenes::shapes::uniform(5, i, 0, 0);
        let v = crate::scenes::shapes::uniform(5, i, 0, 1);
        let p = Vec3::new(-2.0 + 2.95 * u, 0.0, -1.5 + 3.0 * v);
        // Tilted normals exercise θ and w_g.
        let n = Vec3::new(0.2 * (u - 0.5), 1.0, 0.3 * (v - 0.5)).normalize();
        cache.insert(&scene, p, n).unwrap();
    }
    (scene, cache)
}

pub(crate) fn query_points() -> Vec<(Vec3, Vec3)> {
    (0..200u64)
        .map(|i| {
            let u = crate::scenes::shapes::uniform(9, i, 0, 0);
            let v = crate::scenes::shapes::uniform(9, i, 0, 1);
            let n = Vec3::new(0.4 * (u - 0.5), 1.0, -0.2 * (v - 0.5)).normalize();
            (Vec3::new(-2.5 + 3.4 * u, 0.0, -2.0 + 4.0 * v), n)
        })
        .collect()
}

#[test]
fn nearest_equals_a_linear_scan_and_agrees_with_lookup() {
    let params = CacheParams {
        m_search: 8,
        ..CacheParams::MEDIUM
    };
    let (_, cache) = wall_cache(params);
    let state = cache.read();
    let mut found = 0;
    for (x, n) in query_points() {
        let d_max = 0.9;
        let got = state.nearest(&params, x, n, d_max);
        let want = brute_m_nearest(&cache, x, n, d_max);
        assert_eq!(got.candidates().len(), want.len());
        for (g, w) in got.candidates().iter().zip(&want) {
            assert_eq!(g.id, w.0);
            assert!((g.distance - w.1).abs() < 1e-5 && (g.theta - w.2).abs() < 1e-3);
            assert!((g.weight - w.3).abs() < 2e-3, "{} vs {}", g.weight, w.3);
        }
        // The §5.1 lookup keeps the n heaviest of the same candidates with the same weights.
        let lookup = state.lookup(&params, x, n, d_max);
        for k in lookup.neighbours() {
            let c = got.candidates().iter().find(|c| c.id == k.id).unwrap();
            assert_eq!(c.weight, k.weight);
        }
        let best = got
            .candidates()
            .iter()
            .map(|c| c.weight)
            .fold(0.0, f32::max);
        assert_eq!(best, lookup.max_weight);
        found += got.candidates().len();
    }
    assert!(found > 200, "queries found too few records ({found})");
}

#[test]
fn cache_ao_is_the_gaussian_average_and_the_criterion_its_formula() {
    let params = CacheParams::MEDIUM;
    let (_, cache) = wall_cache(params);
    let ao = AoParams::default();
    let state = cache.read();
    let mut finite_radii = 0;
    for (x, n) in query_points() {
        let footprint = 0.05;
        let d_max = params.d_max_scale * footprint;
        let want = brute_m_nearest(&cache, x, n, d_max);
        let sigma = (ao.sigma_scale * footprint) as f64;
        let (mut sum, mut total) = (0.0f64, 0.0f64);
        let mut cover = 0.0f32;
        for &(id, d, theta, w) in &want {
            let h = state.store().header(id as usize);
            let v = h.position() - x;
            let w_g = if d > 0.0 {
                (1.0 - (n.dot(v) / v.length()).abs().min(1.0) as f64).sqrt()
            } else {
                1.0
            };
            let g = (-(d as f64).powi(2) / (2.0 * sigma * sigma)).exp()
                * (1.0 - theta as f64 / std::f64::consts::PI)
                * w_g;
            sum += g * h.ambient_occlusion() as f64;
            total += g;
            let r = h.nearest_hit_distance.max(ao.min_radius_scale * footprint);
            finite_radii += r.is_finite() as usize;
            let factor = if r.is_finite() {
                (1.0 - d / r).max(0.0)
            } else {
                1.0
            };
            cover = cover.max(w * factor);
        }
        let got = cache_ao_at(&state, &params, &ao, x, n, footprint);
        match got {
            None => assert!(want.is_empty() || total == 0.0),
            Some(a) => assert!(
                (a as f64 - sum / total).abs() < 1e-4,
                "{a} vs {}",
                sum / total
            ),
        }
        let nearest = state.nearest(&params, x, n, d_max);
        let r_min = ao.min_radius_scale * footprint;
        assert!((coverage(&state, &nearest, r_min) - cover).abs() < 2e-3);
        assert_eq!(
            needs_ao_record(&state, &ao, &nearest, r_min),
            coverage(&state, &nearest, r_min) < ao.w_min
        );
    }
    assert!(finite_radii > 0, "no record saw the wall");
}
