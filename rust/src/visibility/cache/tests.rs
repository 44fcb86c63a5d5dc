//! The cache against brute force: lookups against a linear scan implementing §5.1 from the
//! formulas, concurrency under a read-write mix, deterministic builds, eviction, and the
//! file format under truncation and corruption.

use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use super::*;
use crate::camera::{Camera, GBuffer};
use crate::math::to_world;
use crate::sampling::octahedral::morton_decode;
use crate::sampling::rng::{hash4, to_unit_f32};
use crate::scenes;
use crate::testing::synthetic_record;

fn unit(seed: u64, k: u64) -> f32 {
    to_unit_f32(hash4(seed, k, 0, 7))
}

fn random_dir(seed: u64, k: u64) -> Vec3 {
    let z = 2.0 * unit(seed, 2 * k) - 1.0;
    let phi = std::f32::consts::TAU * unit(seed, 2 * k + 1);
    let r = (1.0 - z * z).max(0.0).sqrt();
    Vec3::new(r * phi.cos(), r * phi.sin(), z)
}

/// The m nearest records within `d_max` and `θ_max` of `(x, n)` by a linear scan, nearest
/// first (ties by id), as `(id, distance, θ, w)` with `w = w_g · ŵ` straight from the
/// formulas of §5.1 (eq. 9). Shared by the lookup and the AO tests.
pub(crate) fn brute_m_nearest(
    c: &VisibilityCache,
    x: Vec3,
    n: Vec3,
    d_max: f32,
) -> Vec<(u32, f32, f32, f32)> {
    let p = c.params();
    let s = c.read();
    let theta_max = p.theta_max_deg.to_radians();
    let angle = |id: u32| {
        n.as_dvec3()
            .angle_between(s.store().header(id as usize).normal().as_dvec3()) as f32
    };
    // Filter by distance and angle first, then the m nearest.
    let mut near: Vec<(f32, u32)> = (0..s.len())
        .map(|i| (s.store().header(i).position().distance_squared(x), i as u32))
        .filter(|&(d2, id)| d2 <= d_max * d_max && angle(id) < theta_max)
        .collect();
    near.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
    near.truncate(p.m_search as usize);
    let lam = p.lambda_falloff;
    let w = |x: f32, t: f32| (1.0 - t / std::f32::consts::PI) * (1.0 - x / (1.0 + lam * x));
    let w_lo = w(1.0, theta_max);
    near.iter()
        .map(|&(d2, id)| {
            let theta = angle(id);
            let d = d2.sqrt();
            let w_hat = ((w(d / d_max, theta) - w_lo) / (1.0 - w_lo)).clamp(0.0, 1.0);
            let v = s.store().header(id as usize).position() - x;
            let w_g = if d > 0.0 {
                (1.0 - (n.dot(v) / v.length()).abs().min(1.0)).sqrt()
            } else {
                1.0
            };
            (id, d, theta, w_g * w_hat)
        })
        .collect()
}

/// §5.1 by a linear scan over every record: the n heaviest of [`brute_m_nearest`] (ties:
/// nearer, then lower id) with their `β`.
fn brute_lookup(c: &VisibilityCache, x: Vec3, n: Vec3, d_max: f32) -> Vec<(u32, f32)> {
    let p = c.params();
    let mut scored: Vec<(f32, f32, u32)> = brute_m_nearest(c, x, n, d_max)
        .into_iter()
        .filter(|&(_, _, _, wi)| wi > 0.0)
        .map(|(id, d, _, wi)| (wi, d, id))
        .collect();
    scored.sort_by(|a, b| {
        b.0.total_cmp(&a.0)
            .then(a.1.total_cmp(&b.1))
            .then(a.2.cmp(&b.2))
    });
    scored.truncate(p.n_keep as usize);
    let total: f32 = scored.iter().map(|s| s.0).sum();
    scored.iter().map(|&(wi, _, id)| (id, wi / total)).collect()
}

/// `count` synthetic records on a 1 x 1 patch of the plane y = 0 with normals tilted up to
/// 40° from +y, some sharing positions (a grid of 0.05) as records on flat geometry do.
fn patch_cache(params: CacheParams, count: u64, seed: u64) -> VisibilityCache {
    let c = VisibilityCache::new(params).unwrap();
    for k in 0..count {
        let snap = |v: f32| (v * 20.0).round() / 20.0;
        let p = Vec3::new(snap(unit(seed, 3 * k)), 0.0, snap(unit(seed, 3 * k + 1)));
        let tilt = 40f32.to_radians() * unit(seed, 3 * k + 2);
        let n = to_world(Vec3::new(tilt.sin(), 0.0, tilt.cos()), Vec3::Y).normalize();
        let n = Quat::from_rotation_y(std::f32::consts::TAU * unit(seed ^ 1, k)) * n;
        let r = synthetic_record(params.log2_resolution, p, n, 0.7, seed + k);
        c.insert_record(&r).unwrap().unwrap();
    }
    c
}

use glam::Quat;

fn assert_matches_brute(c: &VisibilityCache, x: Vec3, n: Vec3, d_max: f32) {
    let got = c.lookup(x, n, d_max);
    let want = brute_lookup(c, x, n, d_max);
    let ids: Vec<u32> = got.neighbours().iter().map(|k| k.id).collect();
    let want_ids: Vec<u32> = want.iter().map(|w| w.0).collect();
    assert_eq!(ids, want_ids, "x {x} n {n} d_max {d_max}");
    for (k, w) in got.neighbours().iter().zip(&want) {
        assert!((k.beta - w.1).abs() < 1e-5, "{} vs {}", k.beta, w.1);
    }
    if !want.is_empty() {
        let sum: f32 = got.neighbours().iter().map(|k| k.beta).sum();
        assert!((sum - 1.0).abs() < 1e-5);
    }
}

#[test]
fn lookups_equal_a_linear_scan_of_eq9_with_the_geometric_term() {
    let c = patch_cache(CacheParams::MEDIUM, 3000, 11);
    let s = c.read();
    let mut queries = Vec::new();
    for k in 0..400u64 {
        let x = Vec3::new(
            unit(5, 3 * k),
            0.02 * (unit(5, 3 * k + 1) - 0.5),
            unit(5, 3 * k + 2),
        );
        let n = (Vec3::Y + 0.4 * random_dir(6, k)).normalize();
        queries.push((x, n, 0.01 + 0.2 * unit(8, k)));
    }
    // Records exactly at x, with their own normal (θ = 0) and with one just inside θ_max.
    for id in [0usize, 17, 1234] {
        let h = s.store().header(id);
        queries.push((h.position(), h.normal(), 0.1));
        let (t, _) = crate::math::orthonormal_basis(h.normal());
        let just_under = Quat::from_axis_angle(t, 29.9f32.to_radians()) * h.normal();
        queries.push((h.position(), just_under, 0.1));
    }
    drop(s);
    for (x, n, d) in queries {
        assert_matches_brute(&c, x, n, d);
    }
}

/// After an eviction the index is rebuilt (a balanced tree of the first record at each
/// position, the others chained): lookups still equal the linear scan, before and after
/// further insertions split its leaves.
#[test]
fn lookups_equal_a_linear_scan_after_eviction_rebuilds_the_index() {
    let c = patch_cache(CacheParams::MEDIUM, 3000, 21);
    // Every third record predicted all its samples wrongly: out at the end of the frame.
    let ids: Vec<u32> = (0..3000).step_by(3).collect();
    let ones = vec![1u32; ids.len()];
    c.record_misses(&ids, &ones, &ones).unwrap();
    assert_eq!(c.end_frame().unwrap().by_misses, 1000);
    assert_eq!(c.len(), 2000);
    let queries: Vec<(Vec3, Vec3, f32)> = (0..150u64)
        .map(|k| {
            let x = Vec3::new(unit(22, 2 * k), 0.0, unit(22, 2 * k + 1));
            (
                x,
                (Vec3::Y + 0.3 * random_dir(23, k)).normalize(),
                0.02 + 0.15 * unit(24, k),
            )
        })
        .collect();
    for &(x, n, d) in &queries {
        assert_matches_brute(&c, x, n, d);
    }
    for k in 0..500u64 {
        let p = Vec3::new(unit(25, 2 * k), 0.0, unit(25, 2 * k + 1));
        c.insert_record(&synthetic_record(5, p, Vec3::Y, 0.6, k))
            .unwrap();
    }
    for &(x, n, d) in &queries {
        assert_matches_brute(&c, x, n, d);
    }
}

/// Lookups through a [`LookupScratch`] in pixel order, in scattered order and across
/// insertions give exactly what single range queries give (a fresh scratch gathers exactly
/// the ball of `d_max`), and the coherent stretch reuses its gatherings.
#[test]
fn scratch_lookups_equal_plain_ones_and_follow_insertions() {
    let c = patch_cache(CacheParams::MEDIUM, 3000, 11);
    let params = *c.params();
    let mut scratch = LookupScratch::default();
    let row = |k: u64, d_max: f32| {
        let x = Vec3::new(
            0.005 * (k % 200) as f32,
            0.001 * unit(4, k),
            0.3 + 0.01 * (k / 200) as f32,
        );
        let n = (Vec3::Y + 0.3 * random_dir(6, k)).normalize();
        (x, n, d_max * (1.0 + 0.2 * unit(9, k)))
    };
    let check = |s: &CacheState, scratch: &mut LookupScratch, (x, n, d): (Vec3, Vec3, f32)| {
        let plain = s.lookup_near(&params, x, n, d, &mut LookupScratch::default());
        assert_eq!(
            s.lookup_near(&params, x, n, d, scratch),
            plain,
            "x {x} d {d}"
        );
        let nearest = s.nearest_near(&params, x, n, d, &mut LookupScratch::default());
        let near = s.nearest_near(&params, x, n, d, scratch);
        assert_eq!(format!("{near:?}"), format!("{nearest:?}"));
        !plain.neighbours().is_empty()
    };
    {
        let s = c.read();
        let mut found = 0;
        for k in 0..1000u64 {
            found += check(&s, &mut scratch, row(k, 0.05)) as usize;
        }
        assert!(found > 900, "the path runs over records ({found})");
        assert!(
            scratch.gathers < 250,
            "{} gatherings for 1000 lookups",
            scratch.gathers
        );
        // Scattered points, some radii far larger and smaller than the gathered ball.
        for k in 0..300u64 {
            let x = Vec3::new(unit(12, k), 0.0, unit(13, k));
            let d = [0.001, 0.05, 0.5][k as usize % 3];
            check(&s, &mut scratch, (x, Vec3::Y, d));
        }
        // Scattered lookups back off from trying wide gatherings; a coherent walk takes
        // them up again within one retry interval.
        for k in 0..300u64 {
            let x = Vec3::new(unit(14, k), 0.0, unit(15, k));
            s.lookup_near(&params, x, Vec3::Y, 0.05, &mut scratch);
        }
        let (first, most) = LookupScratch::WIDE_RETRY;
        assert_eq!(scratch.wide_interval, most);
        let before = scratch.gathers;
        for k in 0..1000u64 {
            check(&s, &mut scratch, row(2000 + k, 0.05));
        }
        assert_eq!(scratch.wide_interval, first);
        let walked = scratch.gathers - before;
        assert!(walked < 250 + most, "{walked} gatherings for 1000 lookups");
    }
    // Records inserted where the scratch last gathered must be found.
    let (x, n, d) = row(1000, 0.05);
    check(&c.read(), &mut scratch, (x, n, d));
    let fresh = synthetic_record(params.log2_resolution, x + Vec3::X * 1e-3, n, 0.7, 99);
    let id = c.insert_record(&fresh).unwrap().unwrap();
    let s = c.read();
    let got = s.lookup_near(&params, x, n, d, &mut scratch);
    assert!(
        got.neighbours().iter().any(|k| k.id == id),
        "the new record is seen"
    );
    let plain = s.lookup_near(&params, x, n, d, &mut LookupScratch::default());
    assert_eq!(got, plain);
}

#[test]
fn lookup_extremes() {
    let empty = VisibilityCache::new(CacheParams::MEDIUM).unwrap();
    let l = empty.lookup(Vec3::ZERO, Vec3::Y, 1.0);
    assert!(l.neighbours().is_empty() && l.max_weight == 0.0);
    assert!(l.needs_record(empty.params()));

    let c = patch_cache(CacheParams::MEDIUM, 500, 3);
    let x = Vec3::new(0.5, 0.0, 0.5);
    // A tiny d_max finds at most the records exactly at x; a huge one the m nearest.
    assert!(c
        .lookup(x + Vec3::X * 1e-3, Vec3::Y, 1e-9)
        .neighbours()
        .is_empty());
    assert_matches_brute(&c, x, Vec3::Y, 1e-9);
    assert_matches_brute(&c, x, Vec3::Y, 1e9);
    // Zero, negative, NaN and infinite radii find nothing instead of failing.
    for d in [0.0, -1.0, f32::NAN, f32::INFINITY] {
        assert!(c.lookup(x, Vec3::Y, d).neighbours().is_empty());
    }
    // θ_max = 0 accepts nothing (θ_i < 0 never holds); 180° accepts all but antipodes.
    let narrow = VisibilityCache::new(CacheParams {
        theta_max_deg: 0.0,
        ..CacheParams::MEDIUM
    })
    .unwrap();
    narrow
        .insert_record(&synthetic_record(5, x, Vec3::Y, 0.5, 1))
        .unwrap();
    assert!(narrow.lookup(x, Vec3::Y, 1.0).neighbours().is_empty());
    let wide = VisibilityCache::new(CacheParams {
        theta_max_deg: 180.0,
        ..CacheParams::MEDIUM
    })
    .unwrap();
    for (k, n) in [Vec3::Y, Vec3::X, -Vec3::Y].into_iter().enumerate() {
        wide.insert_record(&synthetic_record(5, x, n, 0.5, k as u64))
            .unwrap();
    }
    let l = wide.lookup(x, Vec3::Y, 1.0);
    let ids: Vec<u32> = l.neighbours().iter().map(|k| k.id).collect();
    assert_eq!(ids, vec![0, 1]);
    // Same position, weights from θ alone: (1 − θ/π) normalised with w_lo = 0.
    assert!((l.neighbours()[1].weight - 0.5).abs() < 1e-5);
    assert_matches_brute(&wide, x, Vec3::Y, 1.0);
}

#[test]
fn many_records_at_one_position_with_different_normals() {
    // More coincident records than a kd-tree bucket holds: they share one tree item.
    let c = VisibilityCache::new(CacheParams {
        theta_max_deg: 180.0,
        ..CacheParams::MEDIUM
    })
    .unwrap();
    let x = Vec3::new(1.0, 2.0, 3.0);
    for k in 0..300u64 {
        c.insert_record(&synthetic_record(5, x, random_dir(2, k), 0.5, k))
            .unwrap();
    }
    assert_eq!(c.len(), 300);
    for k in 0..20u64 {
        let n = random_dir(9, k);
        assert_matches_brute(&c, x, n, 0.5);
        assert_matches_brute(&c, x + 0.1 * random_dir(10, k), n, 0.5);
    }
}

#[test]
fn kept_count_larger_than_found_and_beta_sum_to_one() {
    let params = CacheParams {
        n_keep: 16,
        ..CacheParams::MEDIUM
    };
    let c = VisibilityCache::new(params).unwrap();
    for k in 0..3 {
        let p = Vec3::new(0.01 * k as f32, 0.0, 0.0);
        c.insert_record(&synthetic_record(5, p, Vec3::Y, 0.5, k))
            .unwrap();
    }
    let l = c.lookup(Vec3::new(0.005, 0.0, 0.001), Vec3::Y, 1.0);
    assert_eq!(l.neighbours().len(), 3);
    let sum: f32 = l.neighbours().iter().map(|k| k.beta).sum();
    assert!((sum - 1.0).abs() < 1e-6);
}

#[test]
fn mean_difference_and_interpolation_from_the_bits() {
    let c = VisibilityCache::new(CacheParams::MEDIUM).unwrap();
    let recs: Vec<Record> = (0..3)
        .map(|k| synthetic_record(5, Vec3::new(0.01 * k as f32, 0.0, 0.0), Vec3::Y, 0.5, k))
        .collect();
    for r in &recs {
        c.insert_record(r).unwrap();
    }
    let l = c.lookup(Vec3::new(0.01, 0.0, 0.0), Vec3::Y, 1.0);
    assert_eq!(l.neighbours().len(), 3);
    let d = |a: usize, b: usize| {
        (0..1024)
            .filter(|&z| recs[a].bits.get(z) != recs[b].bits.get(z))
            .count() as f32
            / 1024.0
    };
    let want = (d(0, 1) + d(0, 2) + d(1, 2)) / 3.0;
    assert!((l.mean_difference - want).abs() < 1e-6);
    let mut map = vec![0.0; 1024];
    c.read().interpolate(&l, &mut map);
    for z in 0..1024usize {
        let t = morton_decode(z as u32);
        let want: f32 = l
            .neighbours()
            .iter()
            .map(|k| {
                if recs[k.id as usize].bits.get(z) {
                    k.beta
                } else {
                    0.0
                }
            })
            .sum();
        assert!((map[t.y as usize * 32 + t.x as usize] - want).abs() < 1e-6);
    }
}

#[test]
fn concurrent_inserts_and_lookups_lose_nothing_and_see_whole_records() {
    // Every record's bits are a function of its position, so a reader can tell a torn or
    // mismatched record from a whole one.
    let params = CacheParams {
        max_records: 200_000,
        ..CacheParams::MEDIUM.with_log2_resolution(3)
    };
    let c = Arc::new(VisibilityCache::new(params).unwrap());
    const WRITERS: u64 = 2;
    const PER_WRITER: u64 = 50_000;
    let done = Arc::new(AtomicBool::new(false));
    let seed_of = |p: Vec3| (p.x.to_bits() as u64) << 32 | p.z.to_bits() as u64;
    std::thread::scope(|s| {
        let mut writers = Vec::new();
        for w in 0..WRITERS {
            let c = c.clone();
            writers.push(s.spawn(move || {
                for k in 0..PER_WRITER {
                    let i = w * PER_WRITER + k;
                    let p = Vec3::new(unit(21, 2 * i) * 10.0, 0.0, unit(21, 2 * i + 1) * 10.0);
                    let r = synthetic_record(3, p, Vec3::Y, 0.5, seed_of(p));
                    c.insert_record(&r).unwrap().unwrap();
                }
            }));
        }
        for t in 0..2u64 {
            let (c, done) = (c.clone(), done.clone());
            s.spawn(move || {
                let mut k = 0u64;
                while !done.load(Ordering::Relaxed) || k < 1000 {
                    let x = Vec3::new(
                        unit(30 + t, 2 * k) * 10.0,
                        0.0,
                        unit(30 + t, 2 * k + 1) * 10.0,
                    );
                    let state = c.read();
                    let l = state.lookup(c.params(), x, Vec3::Y, 0.3);
                    for n in l.neighbours() {
                        let h = state.store().header(n.id as usize);
                        let want =
                            synthetic_record(3, h.position(), Vec3::Y, 0.5, seed_of(h.position()));
                        assert_eq!(
                            state.store().bits(n.id as usize).words(),
                            want.bits.view().words()
                        );
                    }
                    k += 1;
                }
            });
        }
        // Flag the readers once the writers are done (or have failed).
        for w in writers {
            let finished = w.join();
            if finished.is_err() {
                done.store(true, Ordering::Relaxed);
                panic!("a writer failed");
            }
        }
        done.store(true, Ordering::Relaxed);
    });
    assert_eq!(c.len(), (WRITERS * PER_WRITER) as usize);
    assert_eq!(c.counters().inserted, WRITERS * PER_WRITER);
    // Every record is findable at its own position.
    let s = c.read();
    for i in (0..s.len()).step_by(97) {
        let h = s.store().header(i);
        let l = s.lookup(c.params(), h.position(), Vec3::Y, 1e-6);
        assert!(
            l.neighbours().iter().any(|n| n.id == i as u32),
            "record {i} lost"
        );
    }
}

fn small_cornell() -> (scenes::Setup, Camera) {
    let setup = scenes::load("cornell", 0.5, 0).unwrap();
    let cam = setup.camera.with_resolution(48, 36).unwrap();
    (setup, cam)
}

#[test]
fn builds_are_identical_for_any_thread_count() {
    let (setup, cam) = small_cornell();
    let params = CacheParams {
        n_startup: 100,
        ..CacheParams::MEDIUM
    };
    let build = |threads| {
        let c = VisibilityCache::new(params).unwrap();
        let r = c
            .build(&setup.scene, &cam, 3, Some(threads), None, &mut |_, _| true)
            .unwrap();
        (c.to_bytes(), r)
    };
    let (one, r1) = build(1);
    let (two, r2) = build(2);
    assert!(r1.records > r1.bootstrap_records && r1.complete);
    assert_eq!(r1.records, r2.records);
    assert_eq!(r1.shadow_rays, r2.shadow_rays);
    assert!(one == two, "caches differ");
    // Amortised cost is the record rays over the pixels.
    assert_eq!(
        r1.shadow_rays_per_pixel,
        r1.shadow_rays as f64 / (48.0 * 36.0)
    );
    // After a build, every covered pixel meets the criteria (the closed box's records are
    // all occluded, so they agree; elsewhere δ̄ can stay high where neighbours differ).
    let c = VisibilityCache::load_bytes_for_test(&one);
    let g = GBuffer::render(&setup.scene, &cam, 3, false, None).unwrap();
    for i in 0..g.object.len() {
        if g.object[i] >= 0 {
            let l = c.lookup(
                g.position[i].into(),
                g.normal[i].into(),
                12.0 * g.footprint[i],
            );
            assert!(!l.needs_record(c.params()), "pixel {i}");
        }
    }
}

#[test]
fn a_build_from_the_gbuffer_is_the_build_from_its_camera() {
    let (setup, cam) = small_cornell();
    let params = CacheParams {
        n_startup: 100,
        ..CacheParams::MEDIUM
    };
    let own = VisibilityCache::new(params).unwrap();
    let r1 = own
        .build(&setup.scene, &cam, 3, Some(2), None, &mut |_, _| true)
        .unwrap();
    let g = GBuffer::render(&setup.scene, &cam, 0, false, Some(2)).unwrap();
    let given = VisibilityCache::new(params).unwrap();
    let r2 = given
        .build_from(&setup.scene, &g, 3, Some(2), None, &mut |_, _| true)
        .unwrap();
    assert!(own.to_bytes() == given.to_bytes(), "caches differ");
    assert_eq!((r1.records, r1.shadow_rays), (r2.records, r2.shadow_rays));
    // A buffer of another scene is refused before anything changes.
    let other = scenes::load("garage", 0.5, 0).unwrap();
    let fresh = VisibilityCache::new(params).unwrap();
    let e = fresh
        .build_from(&other.scene, &g, 3, Some(2), None, &mut |_, _| true)
        .unwrap_err();
    assert!(e.to_string().starts_with("gbuffer"), "{e}");
    assert!(fresh.is_empty());
}

#[test]
fn build_stops_on_request_and_reports_incomplete() {
    let (setup, cam) = small_cornell();
    let c = VisibilityCache::new(CacheParams {
        n_startup: 10,
        ..CacheParams::MEDIUM
    })
    .unwrap();
    let mut calls = 0;
    let r = c
        .build(&setup.scene, &cam, 0, Some(2), None, &mut |_, _| {
            calls += 1;
            false
        })
        .unwrap();
    assert_eq!(calls, 1);
    assert!(!r.complete);
    assert!(c
        .build(&setup.scene, &cam, 0, None, Some(-1.0), &mut |_, _| true)
        .is_err());
    assert!(c
        .build(
            &crate::geometry::Scene::new(),
            &cam,
            0,
            None,
            None,
            &mut |_, _| true
        )
        .is_err());
}

#[test]
fn coarse_to_fine_visits_every_pixel_once() {
    for (w, h) in [(1, 1), (48, 36), (100, 7), (64, 64)] {
        let mut o: Vec<u32> = coarse_to_fine_levels(w, h).concat();
        assert_eq!(o[0], 0);
        o.sort_unstable();
        assert_eq!(o, (0..w * h).collect::<Vec<_>>());
    }
}

#[test]
fn eviction_by_miss_rate_by_rank_and_by_age() {
    let c = patch_cache(CacheParams::MEDIUM, 50, 4);
    let before: Vec<[f32; 3]> = (0..50)
        .map(|i| c.read().store().header(i).position)
        .collect();
    // Record 7 disagrees on 1 sample in 10 (> 5%), record 8 on 1 in 100 (kept).
    c.record_misses(&[7, 8, 9], &[1, 1, 0], &[10, 100, 5])
        .unwrap();
    assert!(c.record_misses(&[50], &[0], &[1]).is_err());
    assert!(c.record_misses(&[1], &[2], &[1]).is_err());
    assert!(c.record_misses(&[1, 2], &[0], &[1]).is_err());
    let r = c.end_frame().unwrap();
    assert_eq!((r.frame, r.by_misses, r.unused, r.remaining), (0, 1, 0, 49));
    let after: Vec<[f32; 3]> = (0..49)
        .map(|i| c.read().store().header(i).position)
        .collect();
    let mut expect = before.clone();
    expect.remove(7);
    assert_eq!(after, expect, "kept records keep their order");
    assert_eq!(
        c.read().store().header(7).uses,
        0,
        "counters restart each frame"
    );
    // The k worst instead of a threshold.
    let worst = VisibilityCache::new(CacheParams {
        evict_worst: 2,
        ..CacheParams::MEDIUM
    })
    .unwrap();
    for k in 0..5 {
        worst
            .insert_record(&synthetic_record(5, Vec3::X * k as f32, Vec3::Y, 0.5, k))
            .unwrap();
    }
    worst
        .record_misses(&[0, 1, 2, 3], &[1, 3, 2, 0], &[100, 100, 100, 100])
        .unwrap();
    assert_eq!(worst.end_frame().unwrap().by_misses, 2);
    let xs: Vec<f32> = (0..3)
        .map(|i| worst.read().store().header(i).position[0])
        .collect();
    assert_eq!(xs, vec![0.0, 3.0, 4.0]);
    // Unused records age out after F frames; a used one stays.
    let aging = VisibilityCache::new(CacheParams {
        unused_frames: 3,
        ..CacheParams::MEDIUM
    })
    .unwrap();
    for k in 0..2 {
        aging
            .insert_record(&synthetic_record(5, Vec3::X * k as f32, Vec3::Y, 0.5, k))
            .unwrap();
    }
    let mut unused = 0;
    for _ in 0..3 {
        aging.record_misses(&[1], &[0], &[1]).unwrap();
        unused += aging.end_frame().unwrap().unused;
    }
    assert_eq!((unused, aging.len()), (0, 2));
    aging.record_misses(&[1], &[0], &[1]).unwrap();
    assert_eq!(aging.end_frame().unwrap().unused, 1);
    assert_eq!(aging.read().store().header(0).position[0], 1.0);
    // Lookups still work after compaction.
    assert_matches_brute(&c, Vec3::new(0.5, 0.0, 0.5), Vec3::Y, 0.3);
}

#[test]
fn max_records_refuses_insertions() {
    let c = VisibilityCache::new(CacheParams {
        max_records: 3,
        ..CacheParams::MEDIUM
    })
    .unwrap();
    for k in 0..5u64 {
        let got = c
            .insert_record(&synthetic_record(5, Vec3::X * k as f32, Vec3::Y, 0.5, k))
            .unwrap();
        assert_eq!(got.is_some(), k < 3);
    }
    assert_eq!((c.len(), c.counters().refused_full), (3, 2));
}

#[test]
fn files_round_trip_and_reject_truncation_and_corruption() {
    let c = patch_cache(
        CacheParams {
            n_keep: 3,
            ..CacheParams::HIGH
        },
        40,
        9,
    );
    c.record_misses(&[3], &[1], &[4]).unwrap();
    let bytes = c.to_bytes();
    let back = VisibilityCache::from_bytes(&bytes, Path::new("mem")).unwrap();
    assert_eq!(back.params(), c.params());
    assert!(back.to_bytes() == bytes);
    assert_matches_brute(&back, Vec3::new(0.5, 0.0, 0.5), Vec3::Y, 0.3);
    for cut in [0, 5, 8, 12, 40, 100, bytes.len() / 2, bytes.len() - 1] {
        let e = VisibilityCache::from_bytes(&bytes[..cut], Path::new("cut.vc")).unwrap_err();
        assert!(e.to_string().starts_with("cut.vc"), "{e}");
    }
    for at in (0..bytes.len()).step_by(37) {
        let mut bad = bytes.clone();
        bad[at] ^= 0x10;
        assert!(
            VisibilityCache::from_bytes(&bad, Path::new("flip")).is_err(),
            "byte {at}"
        );
    }
    let mut longer = bytes.clone();
    longer.push(0);
    assert!(VisibilityCache::from_bytes(&longer, Path::new("long")).is_err());
    // Inconsistent hierarchy codes with a valid checksum are still refused.
    let mut forged = bytes[..bytes.len() - 8].to_vec();
    let last_word = forged.len() - 8;
    forged[last_word] ^= 0b11;
    let sum = super::io::checksum(&forged);
    forged.extend(sum.to_le_bytes());
    let e = VisibilityCache::from_bytes(&forged, Path::new("forged")).unwrap_err();
    assert!(e.to_string().contains("hierarchy"), "{e}");
}

/// A file whose checksum is right but one of whose fields is out of range is refused with
/// an error naming that field (never "truncated", never a cache that misbehaves later).
#[test]
fn files_with_a_field_out_of_range_name_the_field() {
    let c = patch_cache(CacheParams::MEDIUM, 20, 4);
    c.record_misses(&[1], &[1], &[2]).unwrap();
    let bytes = c.to_bytes();
    let n = c.len() as u64;
    // Offsets of the version-4 format (io.rs): parameters from 12, flags at 72, frame at
    // 76, fingerprint at 80, radius at 88, the record count at 92, headers from 100.
    let forge = |at: usize, value: &[u8]| {
        let mut v = bytes[..bytes.len() - 8].to_vec();
        v[at..at + value.len()].copy_from_slice(value);
        let sum = io::checksum(&v);
        v.extend(sum.to_le_bytes());
        VisibilityCache::from_bytes(&v, Path::new("forged.vc"))
            .map(|_| ())
            .unwrap_err()
            .to_string()
    };
    let u = |v: u32| v.to_le_bytes().to_vec();
    let f = |v: f32| v.to_le_bytes().to_vec();
    let record = 100;
    let cases: Vec<(usize, Vec<u8>, &str)> = vec![
        (12, u(9), "log2_resolution"),
        (20, f(f32::INFINITY), "d_max_scale"),
        (24, f(200.0), "theta_max_deg"),
        (28, f(-1.0), "lambda_falloff"),
        (32, u(0), "m_search"),
        (36, u(99), "n_keep"),
        (40, f(2.0), "w_min"),
        (44, f(f32::NAN), "delta_max"),
        (48, f(-0.5), "epsilon_max"),
        (56, u(0), "unused_frames"),
        (60, u(0), "max_records"),
        (72, u(255), "flags: 0xff"),
        (72, u(16), "flags: 0x10"),
        (76, u(u32::MAX), "frame: 4294967295 is out of range"),
        (88, f(-1.0), "default radius"),
        (92, (1u64 << 40).to_le_bytes().to_vec(), "record count"),
        (92, (n + 1).to_le_bytes().to_vec(), "do not hold the"),
        (record, f(f32::NAN), "record 0: position"),
        (record + 16, f(-2.0), "record 0: nearest-hit distance"),
        (
            record + 36 + 20,
            u(3),
            "record 1: misses (3) exceed uses (2)",
        ),
        (
            record + 28,
            u(1),
            "record 0: last frame (1) is after the cache's frame (0)",
        ),
        (
            record + 34,
            7u16.to_le_bytes().to_vec(),
            "record 0: reserved",
        ),
    ];
    for (at, value, expect) in cases {
        let e = forge(at, &value);
        assert!(
            e.starts_with("forged.vc") && e.contains(expect),
            "byte {at}: {e}"
        );
        assert!(!e.contains("truncated"), "{e}");
    }
}

/// `end_frame` stops at [`LAST_FRAME`] with an error instead of wrapping to frame 0 (which
/// would evict every record as unused), and changes nothing when it refuses.
#[test]
fn end_frame_never_wraps() {
    let c = patch_cache(CacheParams::MEDIUM, 10, 2);
    let mut v = c.to_bytes();
    v.truncate(v.len() - 8);
    v[76..80].copy_from_slice(&(LAST_FRAME - 1).to_le_bytes());
    // Records last used at the frame before, so none is evicted as unused.
    for i in 0..c.len() {
        let at = 100 + 36 * i + 28;
        v[at..at + 4].copy_from_slice(&(LAST_FRAME - 2).to_le_bytes());
    }
    let sum = io::checksum(&v);
    v.extend(sum.to_le_bytes());
    let late = VisibilityCache::from_bytes(&v, Path::new("late.vc")).unwrap();
    let r = late.end_frame().unwrap();
    assert_eq!((r.frame, r.remaining), (LAST_FRAME - 1, c.len()));
    let before = late.to_bytes();
    let e = late.end_frame().unwrap_err().to_string();
    assert!(e.starts_with("frame:") && e.contains("last frame"), "{e}");
    assert!(late.to_bytes() == before);
    assert_eq!(late.read().frame(), LAST_FRAME);
}

use std::path::Path;

impl VisibilityCache {
    fn load_bytes_for_test(bytes: &[u8]) -> Self {
        Self::from_bytes(bytes, Path::new("test")).unwrap()
    }
}

#[test]
fn records_without_nearest_hits_have_the_same_bits_and_version_one_files_load() {
    let setup = scenes::load("garage", 0.3, 0).unwrap();
    let cam = setup.camera.with_resolution(24, 18).unwrap();
    let build = |nearest_hits: bool| {
        let c = VisibilityCache::new(CacheParams {
            nearest_hits,
            n_startup: 20,
            ..CacheParams::MEDIUM
        })
        .unwrap();
        c.build(&setup.scene, &cam, 0, Some(1), None, &mut |_, _| true)
            .unwrap();
        c
    };
    let (with, without) = (build(true), build(false));
    assert_eq!(with.len(), without.len());
    assert!(with.counters().nearest_rays > 0);
    assert_eq!(without.counters().nearest_rays, 0);
    assert_eq!(with.counters().shadow_rays, without.counters().shadow_rays);
    let (a, b) = (with.read(), without.read());
    for i in 0..a.len() {
        assert_eq!(a.store().bits(i), b.store().bits(i));
        assert!(b.store().header(i).nearest_hit_distance.is_infinite());
    }
    drop((a, b));
    // Version 2 keeps the flag; a version-1 stream (no flags word) reads with it on.
    let bytes = without.to_bytes();
    assert!(
        !VisibilityCache::from_bytes(&bytes, Path::new("v2"))
            .unwrap()
            .params()
            .nearest_hits
    );
    // Version 3 keeps the scene the cache was built for.
    let fingerprint = setup.scene.geometry_fingerprint();
    assert_eq!(without.scene_fingerprint(), Some(fingerprint));
    let again = VisibilityCache::from_bytes(&bytes, Path::new("v4")).unwrap();
    assert_eq!(again.scene_fingerprint(), Some(fingerprint));
    // Version 4 keeps the default radius of the build.
    let radius = without.default_radius();
    assert!(radius.is_some_and(|r| r > 0.0));
    assert_eq!(again.default_radius(), radius);
    // Older streams: version 3 has no default radius (loads without one), version 2 no
    // fingerprint either (loads unbound), version 1 no flags word either (loads with
    // nearest hits on).
    let flags_at = 8 + 4 + 60;
    let frame_at = flags_at + 4;
    let radius_at = frame_at + 4 + 8;
    let records_at = radius_at + 4;
    let mut v3 = bytes[..radius_at].to_vec();
    v3.extend_from_slice(&bytes[records_at..bytes.len() - 8]);
    v3[8..12].copy_from_slice(&3u32.to_le_bytes());
    let sum = io::checksum(&v3);
    v3.extend(sum.to_le_bytes());
    let v3 = VisibilityCache::from_bytes(&v3, Path::new("v3")).unwrap();
    assert_eq!(v3.default_radius(), None);
    assert_eq!(
        (v3.len(), v3.scene_fingerprint()),
        (without.len(), Some(fingerprint))
    );
    let older = |version: u32, flags: bool| {
        let mut v = bytes[..flags_at].to_vec();
        if flags {
            v.extend((bytes[flags_at] as u32 & 3).to_le_bytes());
        }
        v.extend_from_slice(&bytes[frame_at..frame_at + 4]);
        v.extend_from_slice(&bytes[records_at..bytes.len() - 8]);
        v[8..12].copy_from_slice(&version.to_le_bytes());
        let sum = io::checksum(&v);
        v.extend(sum.to_le_bytes());
        VisibilityCache::from_bytes(&v, Path::new("old")).unwrap()
    };
    let v2 = older(2, true);
    assert!(!v2.params().nearest_hits);
    assert_eq!((v2.len(), v2.scene_fingerprint()), (without.len(), None));
    let v1 = older(1, false);
    assert!(v1.params().nearest_hits);
    assert_eq!((v1.len(), v1.scene_fingerprint()), (without.len(), None));
    // An unbound cache with records binds to the first scene it is used with.
    v2.bind_scene(&setup.scene).unwrap();
    assert_eq!(v2.scene_fingerprint(), Some(fingerprint));
}

/// The default radius of a build survives saving and loading; a cache without one saves
/// and loads without one; a stored radius that is negative or infinite is refused.
#[test]
fn saving_and_loading_keeps_the_default_radius() {
    let setup = scenes::load("cornell", 0.3, 0).unwrap();
    let cam = setup.camera.with_resolution(16, 12).unwrap();
    let c = VisibilityCache::new(CacheParams::MEDIUM).unwrap();
    assert_eq!(c.default_radius(), None);
    let empty = VisibilityCache::load_bytes_for_test(&c.to_bytes());
    assert_eq!(empty.default_radius(), None);
    let report = c
        .build(&setup.scene, &cam, 0, Some(1), None, &mut |_, _| true)
        .unwrap();
    let expect = report.median_footprint.unwrap() * c.params().d_max_scale;
    assert_eq!(c.default_radius(), Some(expect));
    let dir = std::env::temp_dir().join(format!("viscache-radius-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("radius.vc");
    c.save(&path).unwrap();
    let back = VisibilityCache::load(&path).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    assert_eq!(back.default_radius(), Some(expect));
    assert!(back.to_bytes() == c.to_bytes());
    let radius_at = 8 + 4 + 60 + 4 + 4 + 8;
    for bad in [-1.0f32, f32::INFINITY] {
        let mut v = c.to_bytes();
        v.truncate(v.len() - 8);
        v[radius_at..radius_at + 4].copy_from_slice(&bad.to_le_bytes());
        let sum = io::checksum(&v);
        v.extend(sum.to_le_bytes());
        let e = VisibilityCache::from_bytes(&v, Path::new("radius.vc")).unwrap_err();
        assert!(e.to_string().contains("default radius"), "{e}");
    }
}

/// A cache bound to a scene (by its first build) refuses a scene of other geometry, says
/// so, and stays as it was; so does an empty one bound explicitly.
#[test]
fn caches_refuse_other_scenes() {
    let garage = scenes::load("garage", 0.3, 0).unwrap();
    let cornell = scenes::load("cornell", 0.3, 0).unwrap();
    let cam = garage.camera.with_resolution(16, 12).unwrap();
    let c = VisibilityCache::new(CacheParams::MEDIUM).unwrap();
    assert_eq!(c.scene_fingerprint(), None);
    c.build(&garage.scene, &cam, 0, Some(1), None, &mut |_, _| true)
        .unwrap();
    let n = c.len();
    assert!(n > 0);
    let e = c.bind_scene(&cornell.scene).unwrap_err();
    assert!(
        e.to_string()
            .starts_with("cache: was built for another scene"),
        "{e}"
    );
    let cam_c = cornell.camera.with_resolution(16, 12).unwrap();
    assert!(c
        .build(&cornell.scene, &cam_c, 0, Some(1), None, &mut |_, _| true)
        .is_err());
    assert_eq!(c.len(), n);
    assert_eq!(
        c.scene_fingerprint(),
        Some(garage.scene.geometry_fingerprint())
    );
    let empty = VisibilityCache::new(CacheParams::MEDIUM).unwrap();
    empty.bind_scene(&cornell.scene).unwrap();
    assert!(empty.bind_scene(&garage.scene).is_err());
    assert!(empty.bind_scene(&cornell.scene).is_ok());
    assert_ne!(
        garage.scene.geometry_fingerprint(),
        scenes::load("garage", 0.5, 0)
            .unwrap()
            .scene
            .geometry_fingerprint()
    );
    assert_eq!(
        garage.scene.geometry_fingerprint(),
        scenes::load("garage", 0.3, 0)
            .unwrap()
            .scene
            .geometry_fingerprint()
    );
}

/// A lookup for its records alone keeps the same records with the same weights and `β` bit
/// for bit, and leaves `δ̄` out.
#[test]
fn lookups_for_records_alone_equal_full_lookups_without_the_difference() {
    let c = patch_cache(CacheParams::MEDIUM, 2000, 31);
    let s = c.read();
    let p = *c.params();
    for k in 0..300u64 {
        let x = Vec3::new(unit(32, 2 * k), 0.0, unit(32, 2 * k + 1));
        let n = (Vec3::Y + 0.3 * random_dir(33, k)).normalize();
        let d = 0.02 + 0.1 * unit(34, k);
        let full = s.lookup(&p, x, n, d);
        let records = s.lookup_records(&p, x, n, d);
        assert_eq!(records.neighbours(), full.neighbours(), "query {k}");
        assert_eq!(records.max_weight.to_bits(), full.max_weight.to_bits());
        assert!(records.mean_difference.is_nan());
        assert!(!full.mean_difference.is_nan());
        assert_eq!(records.needs_record(&p), full.max_weight < p.w_min);
    }
}

/// Bounded fuzzing of the cache reader: 4000 damaged streams (cut, flipped, inserted,
/// duplicated, fields zeroed or maxed) never panic, and every changed one is refused
/// (the checksum covers all of it).
#[test]
fn damaged_cache_streams_are_refused_without_panics() {
    let setup = scenes::load("cornell", 0.3, 0).unwrap();
    let c = VisibilityCache::new(CacheParams {
        log2_resolution: 3,
        ..CacheParams::MEDIUM
    })
    .unwrap();
    let cam = setup.camera.with_resolution(12, 9).unwrap();
    c.build(&setup.scene, &cam, 0, Some(1), None, &mut |_, _| true)
        .unwrap();
    let good = c.to_bytes();
    let mut changed = 0;
    for k in 0..4000 {
        let bad = crate::testing::damaged(&good, k, 1);
        let read = VisibilityCache::from_bytes(&bad, Path::new("fuzz"));
        if bad != good {
            changed += 1;
            assert!(read.is_err(), "damage {k} was accepted");
        }
    }
    assert!(changed > 3800, "{changed}");
}

/// A stop requested during a build drops the wave being traced, returns `Interrupted`
/// and keeps the records of the waves before; the next build runs to the end.
#[test]
fn request_stop_interrupts_a_build_between_records() {
    let setup = scenes::load("garage", 0.3, 0).unwrap();
    let cam = setup.camera.with_resolution(64, 48).unwrap();
    let c = VisibilityCache::new(CacheParams::MEDIUM).unwrap();
    let mut waves = 0;
    let mut after_two = 0;
    let r = c.build(&setup.scene, &cam, 0, Some(2), None, &mut |_, _| {
        waves += 1;
        if waves == 2 {
            after_two = c.len();
            c.request_stop();
        }
        true
    });
    let e = r.unwrap_err();
    assert!(matches!(e, Error::Interrupted { .. }), "{e}");
    assert_eq!(waves, 2);
    assert!(after_two > 0);
    assert_eq!(c.len(), after_two);
    let done = c
        .build(&setup.scene, &cam, 0, Some(2), None, &mut |_, _| true)
        .unwrap();
    assert!(done.complete && c.len() > after_two);
}

/// The calling thread's current stop (Ctrl-C) reaches every phase of a build: set before
/// it, the build fails with `Interrupted` and the cache stays empty; set by a progress
/// report after the first wave, the records of the waves before are kept. A later build
/// outside the scope runs to the end.
#[test]
fn the_current_stop_interrupts_a_build() {
    let setup = scenes::load("garage", 0.3, 0).unwrap();
    let cam = setup.camera.with_resolution(64, 48).unwrap();
    let c = VisibilityCache::new(CacheParams::MEDIUM).unwrap();
    let stop = crate::stop::Stop::new();
    stop.set();
    let e = stop
        .scope(|| c.build(&setup.scene, &cam, 0, Some(2), None, &mut |_, _| true))
        .unwrap_err();
    assert!(matches!(e, Error::Interrupted { .. }), "{e}");
    assert_eq!(c.len(), 0);
    let stop = crate::stop::Stop::new();
    let mut kept = 0;
    let e = stop
        .scope(|| {
            c.build(&setup.scene, &cam, 0, Some(2), None, &mut |_, _| {
                kept = c.len();
                stop.set();
                true
            })
        })
        .unwrap_err();
    assert!(matches!(e, Error::Interrupted { .. }), "{e}");
    assert!(kept > 0 && c.len() == kept);
    let done = c
        .build(&setup.scene, &cam, 0, Some(2), None, &mut |_, _| true)
        .unwrap();
    assert!(done.complete && c.len() > kept);
}
