use super::*;
use crate::render::render;
use crate::scenes;

/// Without a cache, method "cv" renders as it would with a cache of the same parameters
/// built by hand at the same anchors — bit for bit — and reports that cache; the records
/// stay within the cap its samples repay.
#[test]
fn cv_without_a_cache_equals_the_cache_built_by_hand() {
    let setup = scenes::load("garage", 0.3, 0).unwrap();
    let camera = setup.camera.with_resolution(64, 48).unwrap();
    let params = RenderParams {
        jitter: false,
        ..RenderParams::with(Method::ControlVariate, 64)
    };
    let quiet = &mut |_: u64, _: u64| true;
    let own = render(
        &setup.scene,
        &setup.envmap,
        &camera,
        &params,
        None,
        Some(2),
        quiet,
    )
    .unwrap();
    let stats = own.stats.own_cache.expect("the render built a cache");
    let cap = record_cap(&CacheParams::AUTO, camera.num_pixels() as u64, 64);
    assert_eq!(stats.planned_spp, Some(64));
    assert!(stats.records > 0 && stats.records <= cap as usize);
    // By hand: the same G-buffer, parameters, plan and seed.
    let g = GBuffer::render(&setup.scene, &camera, 0, false, Some(2)).unwrap();
    let cache = VisibilityCache::new(CacheParams {
        nearest_hits: false,
        max_records: cap,
        ..CacheParams::AUTO
    })
    .unwrap();
    cache.plan_samples(Some(64));
    let report = cache
        .build_from(&setup.scene, &g, 0, Some(1), None, &mut |_, _| true)
        .unwrap();
    assert_eq!(report.records, stats.records);
    let quiet = &mut |_: u64, _: u64| true;
    let by_hand = super::super::render_from(
        &setup.scene,
        &setup.envmap,
        &g,
        &params,
        Some(&cache),
        Some(1),
        quiet,
    )
    .unwrap();
    assert_eq!(own.image, by_hand.image);
    assert_eq!(own.variance, by_hand.variance);
    assert_eq!(
        own.stats.primary_rays,
        by_hand.stats.primary_rays + camera.num_pixels() as u64
    );
    assert!(by_hand.stats.own_cache.is_none());
}

/// The cap: one record per [`SAMPLES_PER_RECORD`] samples, never below the bootstrap's nor
/// above the preset's most.
#[test]
fn the_record_cap_follows_the_samples() {
    let p = CacheParams::AUTO;
    assert_eq!(record_cap(&p, 1000, 1), p.n_startup);
    assert_eq!(record_cap(&p, 400_000, 100), 100_000.min(p.max_records));
    assert_eq!(record_cap(&p, u32::MAX as u64, 1 << 20), p.max_records);
}
