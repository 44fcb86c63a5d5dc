//! The AO renderers: bad input, the cache's density by the wall, determinism over thread
//! counts, and stopping early (the per-point maths are tested in
//! `crate::estimators::ambient`).

use super::*;
use crate::error::Error;
use crate::estimators::ambient::tests::{floor_and_wall, no_progress};
use crate::estimators::ambient::{cache_ao_at, needs_ao_record};

#[test]
fn bad_input_names_the_argument() {
    let scene = floor_and_wall(1.0, 1.0, 1.0, false);
    let empty = Scene::new();
    let msg = |e: Error| e.to_string();
    let cam = Camera::look_at(Vec3::new(0.0, 3.0, 5.0), Vec3::ZERO, Vec3::Y, 45.0, 8, 6).unwrap();
    let cache = VisibilityCache::new(CacheParams::MEDIUM).unwrap();
    let e = render_cache_ao(
        &empty,
        &cam,
        &cache,
        &AoParams::default(),
        0,
        None,
        None,
        &mut no_progress(),
    )
    .unwrap_err();
    assert!(msg(e).starts_with("scene"));
    for (bad, name) in [
        (
            AoParams {
                sigma_scale: 0.0,
                ..AoParams::default()
            },
            "sigma_scale",
        ),
        (
            AoParams {
                sigma_scale: f32::NAN,
                ..AoParams::default()
            },
            "sigma_scale",
        ),
        (
            AoParams {
                min_radius_scale: -1.0,
                ..AoParams::default()
            },
            "min_radius_scale",
        ),
        (
            AoParams {
                w_min: 1.5,
                ..AoParams::default()
            },
            "w_min",
        ),
    ] {
        let e = render_cache_ao(
            &scene,
            &cam,
            &cache,
            &bad,
            0,
            None,
            None,
            &mut no_progress(),
        )
        .unwrap_err();
        assert!(msg(e).starts_with(name));
    }
    let e =
        render_reference_ao(&scene, &cam, 4, 0, None, Some(-1.0), &mut no_progress()).unwrap_err();
    assert!(msg(e).starts_with("time_budget"));
    let e = render_cache_ao(
        &scene,
        &cam,
        &cache,
        &AoParams::default(),
        0,
        Some(0),
        None,
        &mut no_progress(),
    )
    .unwrap_err();
    assert!(msg(e).starts_with("threads"));
    assert!(cache.is_empty(), "a failed call left records behind");
}

#[test]
fn nearest_hit_distance_makes_the_cache_denser_near_geometry() {
    // The floor by the wall, with R_i as the paper has it (r = 0) and with R_i switched off
    // (clamped to infinity): R_i must make the cache denser by the wall, and every covered
    // pixel of a complete build must satisfy the criterion it was built with.
    let cam = Camera::look_at(
        Vec3::new(-3.0, 2.0, 0.0),
        Vec3::new(0.0, 0.0, 0.0),
        Vec3::Y,
        60.0,
        48,
        32,
    )
    .unwrap();
    let scene = floor_and_wall(1.0, 1.0, 1.5, true);
    let count = |min_radius_scale: f32| {
        let ao = AoParams {
            min_radius_scale,
            ..AoParams::default()
        };
        let cache = VisibilityCache::new(CacheParams::MEDIUM.with_log2_resolution(3)).unwrap();
        let r =
            render_cache_ao(&scene, &cam, &cache, &ao, 0, None, None, &mut no_progress()).unwrap();
        // Every covered pixel of a complete build is covered by some record.
        assert!(r.stats.complete);
        assert_eq!(r.stats.resolved_pixels, r.stats.covered_pixels);
        let state = cache.read();
        let g = GBuffer::render(&scene, &cam, 0, false, None).unwrap();
        for i in 0..g.object.len() {
            if g.object[i] < 0 {
                assert!(r.ao[i].is_nan());
                continue;
            }
            let (x, n, f) = (
                Vec3::from(g.position[i]),
                Vec3::from(g.normal[i]),
                g.footprint[i],
            );
            let nearest = state.nearest(cache.params(), x, n, cache.params().d_max_scale * f);
            let r_min = ao.min_radius_scale * f;
            assert!(!needs_ao_record(&state, &ao, &nearest, r_min), "pixel {i}");
            assert!((0.0..=1.0).contains(&r.ao[i]));
        }
        r.stats.records_inserted
    };
    let (with_r, without_r) = (count(0.0), count(f32::INFINITY));
    assert!(
        with_r > without_r,
        "{with_r} records with R_i vs {without_r} without"
    );
}

#[test]
fn renders_are_identical_for_any_thread_count() {
    let setup = crate::scenes::load("cornell", 0.5, 0).unwrap();
    let cam = setup.camera.with_resolution(40, 30).unwrap();
    let run = |threads| {
        let cache = VisibilityCache::new(CacheParams::MEDIUM.with_log2_resolution(3)).unwrap();
        let r = render_cache_ao(
            &setup.scene,
            &cam,
            &cache,
            &AoParams::default(),
            0,
            Some(threads),
            None,
            &mut no_progress(),
        )
        .unwrap();
        let reference = render_reference_ao(
            &setup.scene,
            &cam,
            16,
            4,
            Some(threads),
            None,
            &mut no_progress(),
        )
        .unwrap();
        (r.ao, r.stats.records, r.stats.shadow_rays, reference.ao)
    };
    let (a, b) = (run(1), run(2));
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    assert_eq!(bits(&a.0), bits(&b.0));
    assert_eq!((a.1, a.2), (b.1, b.2));
    assert_eq!(bits(&a.3), bits(&b.3));
}

#[test]
fn stopping_early_reports_incomplete_and_no_records_give_nan() {
    let scene = floor_and_wall(1.0, 1.0, 1.5, true);
    let cam =
        Camera::look_at(Vec3::new(-3.0, 2.0, 0.0), Vec3::ZERO, Vec3::Y, 60.0, 32, 24).unwrap();
    let cache = VisibilityCache::new(CacheParams::MEDIUM.with_log2_resolution(3)).unwrap();
    let mut stop = |_: usize, _: usize| false;
    let r = render_cache_ao(
        &scene,
        &cam,
        &cache,
        &AoParams::default(),
        0,
        None,
        None,
        &mut stop,
    )
    .unwrap();
    assert!(!r.stats.complete);
    assert!(r.stats.records_inserted > 0);
    // No records within reach: the cache has nothing to say.
    let empty = VisibilityCache::new(CacheParams::MEDIUM).unwrap();
    let state = empty.read();
    assert_eq!(
        cache_ao_at(
            &state,
            empty.params(),
            &AoParams::default(),
            Vec3::ZERO,
            Vec3::Y,
            0.1
        ),
        None
    );
}

/// A reference stopped part-way (by progress, or by a budget spent before it starts)
/// leaves the pixels it did not reach NaN and the rest exactly as a complete render has
/// them: a pixel's rays are never cut short.
#[test]
fn a_stopped_reference_keeps_whole_pixels() {
    // Enough rays that one thread takes longer than the first report (about 0.1 s).
    const RAYS: u32 = 256;
    let scene = floor_and_wall(1.0, 1.0, 1.5, true);
    let cam =
        Camera::look_at(Vec3::new(-3.0, 2.0, 0.0), Vec3::ZERO, Vec3::Y, 60.0, 96, 64).unwrap();
    let full =
        render_reference_ao(&scene, &cam, RAYS, 3, Some(1), None, &mut no_progress()).unwrap();
    assert!(full.stats.complete);
    assert_eq!(full.stats.resolved_pixels, full.stats.covered_pixels);
    assert_eq!(
        full.stats.shadow_rays,
        RAYS as u64 * full.stats.covered_pixels as u64
    );
    let mut calls = 0;
    let mut stop_first = |_: usize, _: usize| {
        calls += 1;
        false
    };
    let budgeted = render_reference_ao(
        &scene,
        &cam,
        RAYS,
        3,
        Some(1),
        Some(1e-6),
        &mut no_progress(),
    )
    .unwrap();
    let stopped =
        render_reference_ao(&scene, &cam, RAYS, 3, Some(1), None, &mut stop_first).unwrap();
    assert!(calls >= 1);
    for r in [&budgeted, &stopped] {
        assert_eq!(
            r.stats.complete,
            r.stats.resolved_pixels == r.stats.covered_pixels
        );
        assert_eq!(
            r.stats.shadow_rays,
            RAYS as u64 * r.stats.resolved_pixels as u64
        );
        let mut resolved = 0;
        for (a, b) in r.ao.iter().zip(&full.ao) {
            if !a.is_nan() {
                assert_eq!(a.to_bits(), b.to_bits());
                resolved += 1;
            }
        }
        assert_eq!(resolved, r.stats.resolved_pixels);
    }
    // A budget of 1 µs is spent at the first report.
    assert!(!budgeted.stats.complete, "{:?}", budgeted.stats);
    assert!(!stopped.stats.complete, "{:?}", stopped.stats);
}
