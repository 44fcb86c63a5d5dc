//! The build over a G-buffer: determinism over thread counts, coverage, scale invariance,
//! `a → 0`, a dark scene and a budget.

use std::time::Instant;

use glam::Vec3;

use super::*;
use crate::camera::Camera;
use crate::estimators::ambient::tests::floor_and_wall;
use crate::estimators::irradiance::cache::{IrradianceCache, IrradianceParams};
use crate::lights::envmap::EnvMap;

/// Small strata: these tests are about placement, not accuracy.
const FAST: IrradianceParams = IrradianceParams {
    strata: (4, 12),
    ..IrradianceParams::DEFAULT
};

fn cornell(width: u32, height: u32) -> (crate::scenes::Setup, Camera) {
    let setup = crate::scenes::load("cornell", 1.0, 0).unwrap();
    let camera = setup.camera.with_resolution(width, height).unwrap();
    (setup, camera)
}

fn build(
    cache: &IrradianceCache,
    scene: &crate::geometry::Scene,
    env: &EnvMap,
    g: &GBuffer,
    threads: Option<usize>,
    budget: Option<f64>,
) -> IrradianceBuildReport {
    let lighting = Lighting {
        scene,
        env,
        product_level: crate::estimators::direct::ProductLevel::PerMaterial,
    };
    cache
        .build_from(
            &lighting,
            g,
            7,
            threads,
            Instant::now(),
            budget,
            &mut |_, _| true,
        )
        .unwrap()
}

#[test]
fn builds_are_the_same_for_any_thread_count_and_cover_every_diffuse_pixel() {
    let (setup, camera) = cornell(48, 36);
    let g = GBuffer::render(&setup.scene, &camera, 0, false, None).unwrap();
    let one = IrradianceCache::new(FAST).unwrap();
    let two = IrradianceCache::new(FAST).unwrap();
    let r1 = build(&one, &setup.scene, &setup.envmap, &g, Some(1), None);
    let r2 = build(&two, &setup.scene, &setup.envmap, &g, Some(2), None);
    assert!(r1.complete && r1.records > 10, "{r1:?}");
    assert_eq!(r1.records, r2.records);
    assert_eq!(one.read().records(), two.read().records());
    assert_eq!(r1.hemisphere_rays, r2.hemisphere_rays);
    // Sparse even at 48 x 36, where R_i is a few footprints: about one record per four
    // points (395 of 1728 when written).
    assert!(r1.records * 3 < r1.points, "{r1:?}");
    let state = one.read();
    let mut scratch = Vec::new();
    for i in 0..g.object.len() {
        if g.object[i] >= 0 {
            let (x, n) = (Vec3::from(g.position[i]), Vec3::from(g.normal[i]));
            assert!(state.covers(x, n, &mut scratch), "pixel {i} uncovered");
        }
    }
    // A second build of the same view adds nothing.
    drop(state);
    let again = build(&one, &setup.scene, &setup.envmap, &g, None, None);
    assert_eq!(again.inserted, 0);
}

#[test]
fn tiny_a_gives_every_pixel_its_own_record_and_its_estimate() {
    let (setup, camera) = cornell(12, 9);
    let g = GBuffer::render(&setup.scene, &camera, 0, false, None).unwrap();
    let cache = IrradianceCache::new(IrradianceParams { a: 1e-3, ..FAST }).unwrap();
    let report = build(&cache, &setup.scene, &setup.envmap, &g, None, None);
    assert_eq!(report.records, report.points);
    let lighting = Lighting {
        scene: &setup.scene,
        env: &setup.envmap,
        product_level: crate::estimators::direct::ProductLevel::PerMaterial,
    };
    let state = cache.read();
    let mut scratch = Vec::new();
    for i in 0..g.object.len() {
        if g.object[i] < 0 {
            continue;
        }
        let point = (
            Vec3::from(g.position[i]),
            Vec3::from(g.normal[i]),
            g.footprint[i],
        );
        let own = cache.trace(&lighting, point, 7, i as u64).0;
        let got = state.interpolate(point.0, point.1, &mut scratch).unwrap();
        assert_eq!(got.irradiance, own.irradiance, "pixel {i}");
    }
}

#[test]
fn record_placement_does_not_depend_on_the_scene_scale() {
    let env = EnvMap::constant([1.0, 0.8, 0.6], 8).unwrap();
    let mut placements = Vec::new();
    for scale in [1e-4f32, 1.0, 1e4] {
        let scene = floor_and_wall(scale, 1.0, 1.5, true);
        let camera = Camera::look_at(
            Vec3::new(-2.0, 1.5, 0.0) * scale,
            Vec3::new(1.0, 0.0, 0.0) * scale,
            Vec3::Y,
            60.0,
            32,
            24,
        )
        .unwrap();
        let g = GBuffer::render(&scene, &camera, 0, false, None).unwrap();
        let cache = IrradianceCache::new(FAST).unwrap();
        let report = build(&cache, &scene, &env, &g, None, None);
        let state = cache.read();
        let records: Vec<(Vec3, f32, [f32; 3])> = state
            .records()
            .iter()
            .map(|r| (r.position / scale, r.radius / scale, r.irradiance))
            .collect();
        placements.push((report.records, records));
    }
    let (count, base) = &placements[1];
    assert!(*count > 3);
    for (n, records) in &placements {
        assert_eq!(n, count);
        for ((p, r, e), (p0, r0, e0)) in records.iter().zip(base) {
            assert!((*p - *p0).length() < 1e-3, "{p} vs {p0}");
            assert!((r / r0 - 1.0).abs() < 1e-3, "{r} vs {r0}");
            for c in 0..3 {
                assert!(
                    (e[c] - e0[c]).abs() <= 1e-3 * e0[c].max(1e-3),
                    "{e:?} vs {e0:?}"
                );
            }
        }
    }
}

#[test]
fn a_dark_scene_gives_zero_and_no_nan() {
    // No area lights, a black sky.
    let scene = floor_and_wall(1.0, 1.0, 1.5, true);
    let camera =
        Camera::look_at(Vec3::new(-2.0, 1.5, 0.0), Vec3::X, Vec3::Y, 60.0, 24, 18).unwrap();
    let env = EnvMap::constant([0.0; 3], 8).unwrap();
    let g = GBuffer::render(&scene, &camera, 0, false, None).unwrap();
    let cache = IrradianceCache::new(FAST).unwrap();
    build(&cache, &scene, &env, &g, None, None);
    for r in cache.read().records() {
        assert_eq!(r.irradiance, [0.0; 3]);
        assert!(r.radius.is_finite() && r.radius > 0.0);
        assert!(r
            .rotation
            .iter()
            .chain(&r.translation)
            .all(|v| *v == Vec3::ZERO));
    }
}

#[test]
fn a_spent_budget_stops_between_waves_and_keeps_the_records() {
    let (setup, camera) = cornell(64, 48);
    let g = GBuffer::render(&setup.scene, &camera, 0, false, None).unwrap();
    let cache = IrradianceCache::new(FAST).unwrap();
    let report = build(&cache, &setup.scene, &setup.envmap, &g, None, Some(1e-9));
    assert!(!report.complete);
    assert_eq!(report.records, cache.len());
    assert!(report.records > 0);
}
