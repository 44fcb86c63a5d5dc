use super::schedule::{bundle_order, Chunk, OccludedChunk, TraceOrder, CHUNK, SPATIAL_ORDER_MIN};
use super::*;
use crate::geometry::bvh::BvhUpdate;
use crate::simd::SimdLevel;
use glam::Affine3A;

fn unit_quad() -> Scene {
    let mut s = Scene::new();
    let v = [
        [0.0, 0.0, 0.0],
        [1.0, 0.0, 0.0],
        [1.0, 1.0, 0.0],
        [0.0, 1.0, 0.0],
    ];
    s.add_indexed(&v, &[[0, 1, 2], [0, 2, 3]], Material::DEFAULT, None)
        .unwrap();
    s
}

#[test]
fn batch_validation_names_the_argument() {
    let s = unit_quad();
    let o = [[0.5, 0.5, 1.0]];
    let cases: [(RayBatch, &str); 5] = [
        (RayBatch::new(&o, &[[0.0, 0.0, 0.0]]), "directions"),
        (
            RayBatch::new(&[[f32::NAN, 0.0, 0.0]], &[[0.0, 0.0, -1.0]]),
            "origins",
        ),
        (RayBatch::new(&o, &[]), "directions"),
        (
            RayBatch {
                tmax: TMax::Scalar(-1.0),
                ..RayBatch::new(&o, &[[0.0, 0.0, -1.0]])
            },
            "tmax",
        ),
        (
            RayBatch {
                tmax: TMax::PerRay(&[]),
                ..RayBatch::new(&o, &[[0.0, 0.0, -1.0]])
            },
            "tmax",
        ),
    ];
    for (batch, name) in cases {
        let e = s.occluded(&batch, None).unwrap_err().to_string();
        assert!(e.starts_with(name), "{e}");
    }
    // Large batches, whose chunks validate their own rays while others trace theirs:
    // the first bad row of the first bad argument is named, on any thread count, and
    // the chunks traced before the error count nothing.
    let n = 5 * CHUNK + 17;
    let (mut o, mut d) = (vec![[0.5, 0.5, 1.0]; n], vec![[0.0, 0.0, -1.0]; n]);
    let mut tmax = vec![1.0; n];
    d[4 * CHUNK + 3] = [0.0; 3];
    d[CHUNK + 1] = [f32::INFINITY, 0.0, 1.0];
    tmax[7] = -2.0;
    let message = |o: &[[f32; 3]], d: &[[f32; 3]], threads| {
        let batch = RayBatch {
            tmax: TMax::PerRay(&tmax),
            ..RayBatch::new(o, d)
        };
        s.occluded(&batch, threads).unwrap_err().to_string()
    };
    for threads in [Some(1), Some(2)] {
        let e = message(&o, &d, threads);
        assert!(
            e.starts_with(&format!("directions: row {}", CHUNK + 1)),
            "{e}"
        );
    }
    o[3 * CHUNK + 5] = [0.0, f32::NAN, 0.0];
    o[n - 1] = [f32::NEG_INFINITY, 0.0, 0.0];
    for threads in [Some(1), Some(2)] {
        let e = message(&o, &d, threads);
        assert!(
            e.starts_with(&format!("origins: row {}", 3 * CHUNK + 5)),
            "{e}"
        );
    }
    let (o, d) = (vec![[0.5, 0.5, 1.0]; n], vec![[0.0, 0.0, -1.0]; n]);
    assert!(message(&o, &d, None).starts_with("tmax: value 7"));
    assert_eq!(
        s.counters(),
        TraversalCounters::default(),
        "failed calls count nothing"
    );
    assert_eq!(
        s.occluded(&RayBatch::new(&o, &d), Some(2)).unwrap(),
        vec![true; n]
    );
    assert_eq!(s.counters().rays, n as u64);
}

#[test]
fn batch_answers_and_counters() {
    let s = unit_quad();
    let o = [[0.5, 0.25, 1.0], [2.0, 2.0, 1.0], [0.25, 0.5, -1.0]];
    let d = [[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, 1.0]];
    let occ = s.occluded(&RayBatch::new(&o, &d), Some(2)).unwrap();
    assert_eq!(occ, vec![true, false, true]);
    let hits = s.intersect(&RayBatch::new(&o, &d), Some(1)).unwrap();
    assert_eq!(hits.prim[1], -1);
    assert!(hits.t[1].is_infinite() && hits.position[1][0].is_nan());
    assert_eq!(hits.t[0], 1.0);
    assert_eq!(hits.prim[0], 0);
    assert_eq!(hits.prim[2], 1);
    assert_eq!(hits.normal[0], [0.0, 0.0, 1.0]);
    assert_eq!(hits.position[2], [0.25, 0.5, 0.0]);
    assert_eq!(s.counters().rays, 6);
    s.reset_counters();
    s.set_counting(false);
    s.occluded(&RayBatch::new(&o, &d), None).unwrap();
    assert_eq!(s.counters(), TraversalCounters::default());
}

/// Large batches of scattered rays in a tree larger than L2 are interleaved, and record
/// bundles traced in the Morton order of their points;
/// they answer as each ray traced alone, with counters that count the batch's rays,
/// the same on one and two threads. Batches that take that path and batches that do
/// not (too few rays, bundles already in order) are both covered.
#[test]
fn reordered_batches_answer_as_single_rays() {
    let scene = crate::scenes::load("garden", 0.25, 3).unwrap().scene;
    assert!(
        scene.bvh().outgrows_l2(),
        "the test needs a tree larger than L2"
    );
    let (o, d) = crate::testing::ground_hemisphere_rays(&scene, SPATIAL_ORDER_MIN + 77, 5);
    let rays = RayBatch::new(&o, &d);
    assert!(
        scene.trace_order(&rays) == TraceOrder::Interleaved,
        "this batch must be interleaved"
    );
    let (bo, bd) = crate::testing::record_bundle_rays(&scene, 70, 32, 5);
    let bundles = RayBatch::new(&bo, &bd);
    let TraceOrder::Runs(order) = scene.trace_order(&bundles) else {
        panic!("scattered bundles are reordered")
    };
    // Each bundle is traced whole, from its first ray to its last.
    assert_eq!(order.len(), 70);
    assert!(order.iter().all(|r| r.start % 1024 == 0 && r.len() == 1024));
    let sorted: Vec<u32> = order.iter().map(|r| r.start / 1024).collect();
    let (so, sd): (Vec<_>, Vec<_>) = sorted
        .iter()
        .flat_map(|&k| (k as usize * 1024..(k as usize + 1) * 1024).map(|i| (bo[i], bd[i])))
        .unzip();
    assert!(
        scene.trace_order(&RayBatch::new(&so, &sd)) == TraceOrder::Given,
        "bundles in order stay as given"
    );
    let few = RayBatch::new(&o[..1000], &d[..1000]);
    assert_eq!(scene.trace_order(&few), TraceOrder::Given);
    let cycled_tmax =
        |n: usize| -> Vec<f32> { (0..n).map(|i| [f32::INFINITY, 0.05, 0.3][i % 3]).collect() };
    let tmax = cycled_tmax(o.len());
    let limited = RayBatch {
        tmax: TMax::PerRay(&tmax),
        ..rays
    };
    let bundle_tmax = cycled_tmax(bo.len());
    let limited_bundles = RayBatch {
        tmax: TMax::PerRay(&bundle_tmax),
        ..bundles
    };
    for batch in [rays, limited, bundles, limited_bundles] {
        let alone: Vec<bool> = (0..batch.len())
            .map(|i| {
                let mut c = TraversalCounters::default();
                scene.occluded1(
                    Vec3::from(batch.origins[i]),
                    Vec3::from(batch.directions[i]),
                    batch.tmax_of(i),
                    &mut c,
                )
            })
            .collect();
        scene.set_counting(true);
        scene.reset_counters();
        let one = scene.occluded(&batch, Some(1)).unwrap();
        let counted_one = scene.counters();
        scene.reset_counters();
        let two = scene.occluded(&batch, Some(2)).unwrap();
        assert_eq!(one, alone);
        assert_eq!(two, alone);
        assert_eq!(counted_one, scene.counters());
        assert_eq!(counted_one.rays, batch.len() as u64);
        assert!(alone.iter().any(|&a| a) && alone.iter().any(|&a| !a));
    }
    scene.set_counting(false);
}

/// Batches that are reordered or interleaved check their rays as they trace them, with
/// no pass over the batch first, and still name the first bad row of the first bad
/// argument, as [`RayBatch::validate`] does, on any thread count; a failed call counts
/// nothing. Bundles of 64 rays go 16 to a work item in Morton order, so one item may
/// trace a bundle with a bad row before another bundle with a lower one.
#[test]
fn reordered_batches_name_the_first_bad_row() {
    let scene = crate::scenes::load("garden", 0.25, 3).unwrap().scene;
    let (mut bo, mut bd) = crate::testing::record_bundle_rays(&scene, 1100, 8, 5);
    let TraceOrder::Runs(order) = scene.trace_order(&RayBatch::new(&bo, &bd)) else {
        panic!("scattered bundles are reordered")
    };
    // Two bundles of the first work item, the one traced first starting at a higher row.
    let item = &order[..CHUNK / 64];
    let (first, second) = (1..item.len())
        .find_map(|b| {
            (0..b)
                .find(|&a| item[a].start > item[b].start)
                .map(|a| (a, b))
        })
        .expect("a work item whose bundles are out of the batch's order");
    bd[item[first].start as usize + 9] = [0.0; 3];
    bd[item[second].start as usize + 3] = [f32::NAN, 0.0, 1.0];
    let (so, sd) = crate::testing::ground_hemisphere_rays(&scene, SPATIAL_ORDER_MIN + 77, 5);
    let (mut so, mut sd) = (so.to_vec(), sd.to_vec());
    sd[SPATIAL_ORDER_MIN + 70] = [0.0; 3];
    sd[4 * CHUNK + 1] = [f32::INFINITY, 0.0, 0.0];
    let mut failures = vec![(bo.clone(), bd.clone()), (so.clone(), sd.clone())];
    // A bad origin, even at the last row, comes before any bad direction.
    let last = bo.len() - 1;
    bo[last] = [0.0, f32::NAN, 0.0];
    so[SPATIAL_ORDER_MIN + 76] = [f32::NEG_INFINITY, 0.0, 0.0];
    failures.extend([(bo, bd), (so, sd)]);
    let wanted = [
        format!("directions: row {}", item[second].start + 3),
        format!("directions: row {}", 4 * CHUNK + 1),
        format!("origins: row {last}"),
        format!("origins: row {}", SPATIAL_ORDER_MIN + 76),
    ];
    scene.set_counting(true);
    scene.reset_counters();
    for ((o, d), wanted) in failures.iter().zip(wanted) {
        let batch = RayBatch::new(o, d);
        assert_ne!(scene.trace_order(&batch), TraceOrder::Given);
        let message = batch.validate().unwrap_err().to_string();
        assert!(message.starts_with(&wanted), "{message}");
        for threads in [Some(1), Some(2)] {
            assert_eq!(
                scene.occluded(&batch, threads).unwrap_err().to_string(),
                message
            );
        }
    }
    assert_eq!(
        scene.counters(),
        TraversalCounters::default(),
        "failed calls count nothing"
    );
    scene.set_counting(false);
}

/// Runs of rays from one origin stay whole and go in the order of their origins' keys
/// (ties in the given order); runs in that order already, or a single run, stay put.
#[test]
fn bundle_order_keeps_runs_whole() {
    let o = |x: f32| [x, 0.0, 0.0];
    // Runs: 3 at x=2, 1 at x=0, 2 at x=1, 2 at x=0 (a second run from that point).
    let origins = [o(2.), o(2.), o(2.), o(0.), o(1.), o(1.), o(0.), o(0.)];
    let key = |p: &[f32; 3]| p[0] as u64;
    assert_eq!(
        bundle_order(&origins, key),
        Some(vec![3..4, 6..8, 4..6, 0..3])
    );
    let in_order = [o(0.), o(0.), o(1.), o(2.), o(2.)];
    assert_eq!(bundle_order(&in_order, key), None);
    assert_eq!(bundle_order(&[o(5.); 4], key), None);
    assert_eq!(bundle_order(&[], key), None);
    // -0.0 and 0.0 start different runs (origins are compared bit for bit).
    let signed = [o(1.), [-0.0, 0.0, 0.0], o(0.)];
    assert_eq!(
        bundle_order(&signed, |p| p[0].abs() as u64),
        Some(vec![1..2, 2..3, 0..1])
    );
}

/// Bundles from one origin in pattern order (where the occluder hint is used) answer as
/// the same rays traced one at a time without hints, on a closed box and open ground.
#[test]
fn hinted_bundles_answer_as_single_rays() {
    use crate::sampling::pattern::default_pattern;
    use crate::testing::surface_points;
    let pattern = default_pattern(5).unwrap();
    for (name, ground) in [
        ("cornell", "floor"),
        ("garden", "ground"),
        ("garage", "floor"),
    ] {
        let s = crate::scenes::load(name, 1.0, 0).unwrap().scene;
        let (mut origins, mut dirs) = (Vec::new(), Vec::new());
        for (p, n) in surface_points(&s, Some(ground), 64, 3) {
            let o = s.offset_point(p, n).to_array();
            for d in pattern.iter().filter(|d| n.dot(**d) > -0.2) {
                origins.push(o);
                dirs.push(d.to_array());
            }
        }
        let bundled = s
            .occluded(&RayBatch::new(&origins, &dirs), Some(2))
            .unwrap();
        let mut c = TraversalCounters::default();
        let single: Vec<bool> = origins
            .iter()
            .zip(&dirs)
            .map(|(o, d)| s.occluded1(Vec3::from(*o), Vec3::from(*d), f32::INFINITY, &mut c))
            .collect();
        assert_eq!(bundled, single, "{name}");
        let occluded = single.iter().filter(|&&b| b).count();
        if name == "cornell" {
            assert_eq!(occluded, single.len(), "the closed box blocks every ray");
        } else {
            assert!(
                occluded > 0 && occluded < single.len(),
                "{name}: a mix of answers"
            );
        }
    }
}

/// Runs of 1 to 23 rays from one origin, in narrow cones (traced as packets) and in
/// scattered directions (one by one), with per-ray `tmax`, across chunk boundaries:
/// the answers are single rays' on 1 and 2 threads, and the counters count every ray.
#[test]
fn runs_of_any_length_answer_as_single_rays() {
    use crate::sampling::rng::{hash4, to_unit_f32};
    use crate::testing::surface_points;
    let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 17));
    let s = crate::scenes::load("garage", 1.0, 0).unwrap().scene;
    let (mut origins, mut dirs, mut tmax) = (Vec::new(), Vec::new(), Vec::new());
    for (k, (p, n)) in surface_points(&s, None, 400, 5).into_iter().enumerate() {
        let k = k as u64;
        let o = s.offset_point(p, n).to_array();
        let axis = (n + Vec3::new(unit(1, k), unit(2, k), unit(3, k)) - 0.5).normalize();
        let spread = [0.1, 0.4, 4.0][k as usize % 3];
        for l in 0..1 + (7 * k) % 23 {
            let r = 64 * k + l;
            let jitter = Vec3::new(unit(4, r), unit(5, r), unit(6, r)) - 0.5;
            origins.push(o);
            dirs.push((axis + jitter * spread).to_array());
            tmax.push([f32::INFINITY, 2.0, 0.5][(r % 3) as usize]);
        }
    }
    assert!(origins.len() > 2 * CHUNK);
    let rays = RayBatch {
        origins: &origins,
        directions: &dirs,
        tmax: TMax::PerRay(&tmax),
    };
    s.set_counting(true);
    s.reset_counters();
    let one = s.occluded(&rays, Some(1)).unwrap();
    assert_eq!(s.counters().rays, origins.len() as u64);
    s.set_counting(false);
    assert_eq!(s.occluded(&rays, Some(2)).unwrap(), one);
    let mut c = TraversalCounters::default();
    let single: Vec<bool> = (0..origins.len())
        .map(|i| s.occluded1(Vec3::from(origins[i]), Vec3::from(dirs[i]), tmax[i], &mut c))
        .collect();
    assert_eq!(one, single);
    let occluded = single.iter().filter(|&&b| b).count();
    assert!(
        occluded > 500 && occluded < single.len() - 500,
        "{occluded}"
    );
    // Every instruction set's chunk loop: the same answers and counts as the portable.
    let bvh = s.bvh();
    let chunk = |f: &dyn Fn(&mut [bool], &mut TraversalCounters)| {
        let (mut out, mut c) = (vec![false; origins.len()], TraversalCounters::default());
        f(&mut out, &mut c);
        (out, c)
    };
    let portable = chunk(&|out, c| {
        let kernel = OccludedChunk::<true> {
            bvh,
            rays: &rays,
            base: 0,
            out,
            counters: c,
            interleave: false,
        };
        crate::simd::run_at(SimdLevel::Portable, kernel).expect("any CPU")
    });
    assert_eq!(portable.0, one);
    for simd in [SimdLevel::Avx2, SimdLevel::Avx512] {
        let vector = chunk(&|out, c| {
            let kernel = OccludedChunk::<true> {
                bvh,
                rays: &rays,
                base: 0,
                out,
                counters: c,
                interleave: false,
            };
            // Nothing to compare on CPUs without `simd`.
            if crate::simd::run_at(simd, kernel).is_none() {
                out.copy_from_slice(&portable.0);
                *c = portable.1;
            }
        });
        assert_eq!(vector, portable, "{simd:?}");
    }
}

/// The rays `(origins, directions, tmax)` answered by the chunk kernel ([`Chunk`]) at
/// instruction set `simd`, with counters; None on a CPU without it.
fn chunk_at<T: Clone + Default>(
    bvh: &crate::geometry::bvh::Bvh,
    (origins, directions, tmax): (&[[f32; 3]], &[[f32; 3]], &[f32]),
    simd: SimdLevel,
    interleave: bool,
) -> Option<(Vec<T>, TraversalCounters)>
where
    for<'a> Chunk<'a, T, true>: crate::simd::Kernel<Output = ()>,
{
    let rays = RayBatch {
        origins,
        directions,
        tmax: TMax::PerRay(tmax),
    };
    let (mut out, mut counters) = (
        vec![T::default(); origins.len()],
        TraversalCounters::default(),
    );
    let kernel = Chunk::<T, true> {
        bvh,
        rays: &rays,
        base: 0,
        out: &mut out,
        counters: &mut counters,
        interleave,
    };
    crate::simd::run_at(simd, kernel).map(|()| (out, counters))
}

/// Scattered rays traced [`crate::geometry::bvh::LANES`] at a time in turns (a tree larger
/// than L2, under every instruction set the CPU has): each answers as traced alone, with
/// per-ray `tmax` (some segments ending before any occluder), and the node and triangle
/// counts are the sum of the single rays'. Batches shorter than the lanes, and empty
/// ones, too; runs from one origin within them keep their packets and hints.
#[test]
fn interleaved_rays_answer_and_count_as_single_rays() {
    let s = crate::scenes::load("garden", 0.25, 3).unwrap().scene;
    let bvh = s.bvh();
    assert!(bvh.outgrows_l2(), "the test needs a tree larger than L2");
    let (mut origins, mut dirs) = crate::testing::ground_hemisphere_rays(&s, 3000, 9);
    let mut tmax: Vec<f32> = (0..origins.len())
        .map(|i| [f32::INFINITY, 0.05, 0.3, 2.0][i % 4])
        .collect();
    // A bundle of one origin among the scattered rays, traced as a packet either way.
    let (bo, bd) = crate::testing::record_bundle_rays(&s, 1, 8, 4);
    origins.splice(1500..1500, bo[..64].iter().copied());
    dirs.splice(1500..1500, bd[..64].iter().copied());
    tmax.splice(1500..1500, [f32::INFINITY; 64]);
    s.set_counting(true);
    // Each ray alone, and the counters of the first 1500 (scattered) ones.
    let mut counted = TraversalCounters::default();
    let single: Vec<bool> = (0..origins.len())
        .map(|i| {
            let (o, d) = (Vec3::from(origins[i]), Vec3::from(dirs[i]));
            let mut c = TraversalCounters::default();
            let occluded = s.occluded1(o, d, tmax[i], &mut c);
            if i < 1500 {
                counted += c;
            }
            occluded
        })
        .collect();
    let occluded = single.iter().filter(|&&b| b).count();
    assert!(occluded > 300 && occluded < 2700, "{occluded}");
    assert_eq!(counted.rays, 1500);
    let trace = |simd: SimdLevel, n: usize, interleave: bool| {
        chunk_at::<bool>(
            bvh,
            (&origins[..n], &dirs[..n], &tmax[..n]),
            simd,
            interleave,
        )
    };
    let mut levels = 0;
    for simd in [SimdLevel::Portable, SimdLevel::Avx2, SimdLevel::Avx512] {
        for n in [0, 3, origins.len()] {
            let Some(interleaved) = trace(simd, n, true) else {
                continue; // a CPU without `simd`
            };
            levels += 1;
            let given = trace(simd, n, false).unwrap();
            assert_eq!(interleaved, given, "{simd:?}, {n} rays");
        }
        let (answers, counters) = trace(simd, 1500, true).unwrap();
        assert_eq!(answers, single[..1500], "{simd:?}");
        assert_eq!(counters, counted, "{simd:?}");
        let (all, _) = trace(simd, origins.len(), true).unwrap();
        assert_eq!(all, single, "{simd:?}");
    }
    assert!(levels >= 3);
    s.set_counting(false);
}

/// Closest hits of scattered rays traced [`crate::geometry::bvh::LANES`] at a time in turns
/// (a tree larger than L2, every instruction set the CPU has): each hit (distance, triangle,
/// barycentrics) is the one the ray finds alone, with per-ray `tmax`, and the node and
/// triangle counts are the sum of the single rays'; also for fewer rays than lanes and
/// none. A batch large enough for [`Scene::intersect`] to interleave gives the single
/// rays' hits on one and two threads.
#[test]
fn interleaved_closest_hits_are_single_rays_hits() {
    let s = crate::scenes::load("garden", 0.25, 3).unwrap().scene;
    let bvh = s.bvh();
    assert!(bvh.outgrows_l2(), "the test needs a tree larger than L2");
    let (origins, dirs) = crate::testing::ground_hemisphere_rays(&s, SPATIAL_ORDER_MIN + 5, 7);
    let tmax: Vec<f32> = (0..origins.len())
        .map(|i| [f32::INFINITY, 0.05, 0.3, 2.0][i % 4])
        .collect();
    s.set_counting(true);
    let mut counted = TraversalCounters::default();
    let single: Vec<Option<crate::geometry::bvh::Hit>> = (0..1500)
        .map(|i| {
            let (o, d) = (Vec3A::from(origins[i]), Vec3A::from(dirs[i]));
            bvh.intersect::<true>(o, d, tmax[i], &mut counted)
        })
        .collect();
    let found = single.iter().filter(|h| h.is_some()).count();
    assert!(found > 300 && found < 1200, "{found}");
    let trace = |simd: SimdLevel, n: usize, interleave: bool| {
        let rays = (&origins[..n], &dirs[..n], &tmax[..n]);
        chunk_at::<Option<crate::geometry::bvh::Hit>>(bvh, rays, simd, interleave)
    };
    let mut levels = 0;
    for simd in [SimdLevel::Portable, SimdLevel::Avx2, SimdLevel::Avx512] {
        let Some((hits, counters)) = trace(simd, 1500, true) else {
            continue; // a CPU without `simd`
        };
        levels += 1;
        assert_eq!(hits, single, "{simd:?}");
        assert_eq!(counters, counted, "{simd:?}");
        for n in [0, 3] {
            assert_eq!(
                trace(simd, n, true),
                trace(simd, n, false),
                "{simd:?}, {n} rays"
            );
        }
    }
    assert!(levels >= 2);
    let rays = RayBatch {
        origins: &origins,
        directions: &dirs,
        tmax: TMax::PerRay(&tmax),
    };
    s.reset_counters();
    let one = s.intersect(&rays, Some(1)).unwrap();
    let counted_one = s.counters();
    s.reset_counters();
    let two = s.intersect(&rays, Some(2)).unwrap();
    assert_eq!(counted_one, s.counters());
    assert_eq!(counted_one.rays, origins.len() as u64);
    s.set_counting(false);
    for (i, h) in single.iter().enumerate() {
        let t = h.map_or(f32::INFINITY, |h| h.t);
        let prim = h.map_or(-1, |h| h.triangle as i32);
        assert_eq!((one.t[i], one.prim[i]), (t, prim), "ray {i}");
        assert_eq!((two.t[i], two.prim[i]), (t, prim), "ray {i}");
    }
}

/// `n` rays from points uniform in `b` (grown by `margin`) in uniform directions, some
/// with a finite `tmax`.
fn random_rays(b: Bounds, margin: f32, n: usize, seed: u64) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    use crate::sampling::rng::SampleRng;
    use crate::scenes::shapes::sphere_dir;
    let (lo, hi) = (b.min - margin, b.max + margin);
    (0..n as u64)
        .map(|i| {
            let r = SampleRng::new(seed, i, 0);
            let [a, c] = r.get2(0);
            let p = lo + (hi - lo) * Vec3::new(a, c, r.get(2));
            let [u, v] = r.get2(3);
            (p.to_array(), sphere_dir(u, v).to_array())
        })
        .unzip()
}

/// Occluded answers (unbounded and with tmax 1) and closest hits of `s` on the rays.
fn answers(s: &Scene, o: &[[f32; 3]], d: &[[f32; 3]]) -> (Vec<bool>, Vec<bool>, Hits) {
    let rays = RayBatch::new(o, d);
    let short = RayBatch {
        tmax: TMax::Scalar(1.0),
        ..rays
    };
    (
        s.occluded(&rays, None).unwrap(),
        s.occluded(&short, None).unwrap(),
        s.intersect(&rays, None).unwrap(),
    )
}

/// Panics with the number of differing rays and the first, if the answers differ.
/// Shadow answers must agree exactly, and so must closest hits, except that trees of
/// other topologies may return different triangles where two lie at the same `t` up to
/// rounding (a box's bottom face on the ground, a shared edge): the traversal finds the
/// closest hit up to a few ulps, and which of such a pair it returns depends on the
/// order it visits them.
fn assert_same_answers(s: &Scene, t: &Scene, o: &[[f32; 3]], d: &[[f32; 3]], what: &str) {
    let (a, b) = (answers(s, o, d), answers(t, o, d));
    let differ: Vec<usize> = (0..o.len())
        .filter(|&i| {
            let (ta, tb) = (a.2.t[i], b.2.t[i]);
            let tie = (ta - tb).abs() <= 1e-6 * ta.max(tb);
            a.0[i] != b.0[i]
                || a.1[i] != b.1[i]
                || ((ta != tb || a.2.prim[i] != b.2.prim[i]) && !tie)
        })
        .collect();
    if let Some(&i) = differ.first() {
        panic!(
            "{what}: {} of {} rays differ; first {i}: ray {:?} {:?}: occluded {} {} / {} {}, hit t {} {}, prim {} {}",
            differ.len(),
            o.len(),
            o[i],
            d[i],
            a.0[i],
            b.0[i],
            a.1[i],
            b.1[i],
            a.2.t[i],
            b.2.t[i],
            a.2.prim[i],
            b.2.prim[i]
        );
    }
}

fn sphere_of_dynamics() -> (Scene, u32) {
    let s = crate::scenes::load("dynamics", 0.5, 0).unwrap().scene;
    let id = s.mesh().objects.iter().position(|o| o.name == "sphere");
    (s, id.unwrap() as u32)
}

fn some_motion(k: f32) -> Affine3A {
    Affine3A::from_rotation_translation(
        glam::Quat::from_euler(glam::EulerRot::XYZ, 0.3 * k, 1.1 * k, -0.2 * k),
        Vec3::new(-0.7 * k, 0.05 * k, 0.9 * k),
    )
}

#[test]
fn moving_an_object_answers_as_moving_its_vertices_and_rebuilding() {
    let (mut s, sphere) = sphere_of_dynamics();
    s.bvh();
    let range = s.mesh().objects[sphere as usize].triangle_range();
    let rest = s.mesh().clone();
    for (k, update) in [
        (1.0, BvhUpdate::Refit),
        (2.0, BvhUpdate::Rebuild),
        (-1.5, BvhUpdate::Refit),
    ] {
        let t = some_motion(k);
        s.set_object_transform_with(sphere, t, update).unwrap();
        assert_eq!(s.object_transform(sphere).unwrap(), t);
        let mut by_hand = rest.clone();
        for tri in &mut by_hand.triangles[range.clone()] {
            *tri = tri.map(|v| t.transform_point3(v));
        }
        assert_eq!(s.mesh().triangles, by_hand.triangles);
        let by_hand = Scene::from_mesh(by_hand);
        assert_eq!(s.bounds(), by_hand.bounds());
        let (o, d) = random_rays(
            s.object_bounds(sphere).unwrap(),
            1.0,
            4000,
            k.to_bits() as u64,
        );
        assert_same_answers(&s, &by_hand, &o, &d, &format!("{update:?} {k}"));
        let a = answers(&s, &o, &d);
        let hits = a.2.obj.iter().filter(|&&o| o == sphere as i32).count();
        assert!(
            hits > 200 && a.0.iter().any(|x| !x),
            "rays see the sphere: {hits}"
        );
    }
    // Back to the identity: the rest pose, bit for bit, after any number of poses.
    s.set_object_transform(sphere, Affine3A::IDENTITY).unwrap();
    let bits = |m: &Mesh| -> Vec<u32> {
        m.triangles
            .iter()
            .flatten()
            .flat_map(|v| v.to_array().map(f32::to_bits))
            .collect()
    };
    assert_eq!(bits(s.mesh()), bits(&rest));
}

#[test]
fn refit_traces_as_rebuild_and_keeps_the_topology() {
    let (mut refit, sphere) = sphere_of_dynamics();
    refit.bvh();
    assert!(!refit.is_posed(sphere));
    refit
        .set_object_transform(sphere, Affine3A::IDENTITY)
        .unwrap();
    assert!(
        refit.is_posed(sphere) && !refit.is_built(),
        "the first move drops the tree"
    );
    let nodes_before = refit.bvh().num_nodes();
    let mut rebuilt = refit.clone();
    for k in [0.25f32, 0.5, 1.0, 3.0] {
        refit.set_object_transform(sphere, some_motion(k)).unwrap();
        rebuilt
            .set_object_transform_with(sphere, some_motion(k), BvhUpdate::Rebuild)
            .unwrap();
        assert!(refit.is_built() && !rebuilt.is_built());
        assert_eq!(refit.bvh().num_nodes(), nodes_before, "topology kept");
        let (o, d) = random_rays(refit.bounds(), 0.0, 3000, 7);
        let (o2, d2) = random_rays(refit.object_bounds(sphere).unwrap(), 0.5, 3000, 8);
        for (o, d) in [(o, d), (o2, d2)] {
            assert_same_answers(&refit, &rebuilt, &o, &d, &format!("k = {k}"));
        }
    }
}

#[test]
fn bad_motion_arguments_leave_the_scene_unchanged() {
    let (mut s, sphere) = sphere_of_dynamics();
    s.set_object_transform(sphere, some_motion(0.5)).unwrap();
    s.bvh();
    let (tris, bounds) = (s.mesh().triangles.clone(), s.bounds());
    let cases = [
        (s.num_objects() as u32, Affine3A::IDENTITY, "object"),
        (u32::MAX, Affine3A::IDENTITY, "object"),
        (
            sphere,
            Affine3A::from_translation(Vec3::new(f32::NAN, 0.0, 0.0)),
            "transform",
        ),
        (
            sphere,
            Affine3A::from_scale(Vec3::splat(f32::INFINITY)),
            "transform",
        ),
        (sphere, Affine3A::from_scale(Vec3::splat(3e38)), "transform"),
    ];
    for (object, t, name) in cases {
        for update in [BvhUpdate::Refit, BvhUpdate::Rebuild] {
            let e = s
                .set_object_transform_with(object, t, update)
                .unwrap_err()
                .to_string();
            assert!(e.starts_with(name), "{e}");
            assert_eq!(s.mesh().triangles, tris);
            assert_eq!(s.bounds(), bounds);
            assert!(s.is_built());
            assert_eq!(s.object_transform(sphere).unwrap(), some_motion(0.5));
        }
    }
    assert!(s
        .object_transform(99)
        .unwrap_err()
        .to_string()
        .starts_with("object"));
    assert!(s
        .object_bounds(99)
        .unwrap_err()
        .to_string()
        .starts_with("object"));
}

#[test]
fn flattening_an_object_falls_back_to_a_rebuild() {
    // Scale 0 along y makes the pillar's side triangles degenerate (its top and bottom
    // stay non-degenerate): the refit must notice and rebuild, and the answers match a
    // scene built from the flattened triangles.
    let (mut s, _) = sphere_of_dynamics();
    let pillar = s
        .mesh()
        .objects
        .iter()
        .position(|o| o.name == "pillar")
        .unwrap() as u32;
    s.bvh();
    let flat = Affine3A::from_scale(Vec3::new(1.0, 0.0, 1.0));
    s.set_object_transform(pillar, flat).unwrap();
    let b = s.object_bounds(pillar).unwrap();
    assert_eq!((b.min.y, b.max.y), (0.0, 0.0));
    let by_hand = Scene::from_mesh(s.mesh().clone());
    let (o, d) = random_rays(b, 1.0, 3000, 3);
    assert_same_answers(&s, &by_hand, &o, &d, "flattened");
    // And back.
    s.set_object_transform(pillar, Affine3A::IDENTITY).unwrap();
    let b = s.object_bounds(pillar).unwrap();
    assert_eq!((b.min.y, b.max.y), (0.0, 2.5));
}

#[test]
fn moving_an_emitter_moves_its_light_and_an_empty_object_is_fine() {
    let mut s = unit_quad();
    let quad = [
        [0.0, 0.0, 2.0],
        [1.0, 0.0, 2.0],
        [1.0, 1.0, 2.0],
        [0.0, 1.0, 2.0],
    ];
    let light = s.add_area_light(&quad, [1.0, 2.0, 3.0], None).unwrap();
    let empty = s.add_indexed(&[], &[], Material::DEFAULT, None).unwrap();
    s.set_object_transform(empty, some_motion(1.0)).unwrap();
    let t = Affine3A::from_translation(Vec3::new(0.0, 0.0, 3.0));
    s.set_object_transform(light, t).unwrap();
    let l = s.emitter(light).unwrap();
    assert_eq!(l.radiance(), Vec3::new(1.0, 2.0, 3.0));
    assert_eq!(s.object_bounds(light).unwrap().min.z, 5.0);
    assert_eq!(s.bounds().max.z, 5.0);
    // Scale 0 leaves the light without area: an error, nothing changes.
    let e = s
        .set_object_transform(light, Affine3A::from_scale(Vec3::ZERO))
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("transform"), "{e}");
    assert_eq!(s.object_bounds(light).unwrap().min.z, 5.0);
    // Bounds stay those of all vertices with several moved objects and later additions.
    let far = [[0.0, 0.0, -7.0], [1.0, 0.0, -7.0], [0.0, 1.0, -7.0]];
    let added = s
        .add_indexed(&far, &[[0, 1, 2]], Material::DEFAULT, None)
        .unwrap();
    assert_eq!(s.bounds(), s.mesh().bounds());
    for (object, z) in [(0, -9.0), (added, 4.0), (light, -1.0), (added, 0.0)] {
        let t = Affine3A::from_translation(Vec3::new(0.0, 0.0, z));
        s.set_object_transform(object, t).unwrap();
        assert_eq!(s.bounds(), s.mesh().bounds(), "object {object} to {z}");
    }
    assert_eq!(s.bounds().min.z, -9.0);
}

/// Camera rays (runs of one origin, traced as packets) mixed with scattered rays, short
/// runs and a run too wide for a packet: [`Scene::intersect`] gives each ray the distance
/// it finds alone, bit for bit, and the same hits on one and two threads; a packet may name
/// the other triangle only where two are hit at exactly that distance.
#[test]
fn camera_rays_in_a_batch_find_the_single_rays_hits() {
    use crate::sampling::rng::{hash4, to_unit_f32};
    let setup = crate::scenes::load("garden", 0.25, 3).unwrap();
    let (s, cam) = (&setup.scene, setup.camera.with_resolution(64, 48).unwrap());
    let unit = |a: u64, b: u64| to_unit_f32(hash4(a, b, 0, 29));
    let (mut origins, mut dirs) = (Vec::new(), Vec::new());
    for py in 0..48 {
        for px in 0..64 {
            let k = (py * 64 + px) as u64;
            let (o, d) = cam.pixel_ray(px, py, [unit(1, k), unit(2, k)]);
            origins.push(o.to_array());
            dirs.push(d.to_array());
        }
    }
    let camera_rays = origins.len();
    let (so, sd) = crate::testing::ground_hemisphere_rays(s, 1000, 5);
    // Scattered rays, runs of 2 and 3 from one point, and a run of 20 over a hemisphere.
    origins.extend(&so);
    dirs.extend(&sd);
    for (k, run) in [(0usize, 2usize), (1, 3), (2, 20)] {
        for l in 0..run {
            origins.push(so[k]);
            dirs.push(sd[(k + 7 * l) % sd.len()]);
        }
    }
    let tmax: Vec<f32> = (0..origins.len())
        .map(|i| [f32::INFINITY, f32::INFINITY, 0.3, 5.0][i % 4])
        .collect();
    let rays = RayBatch {
        origins: &origins,
        directions: &dirs,
        tmax: TMax::PerRay(&tmax),
    };
    let one = s.intersect(&rays, Some(1)).unwrap();
    let two = s.intersect(&rays, Some(2)).unwrap();
    assert_eq!((&one.t, &one.prim), (&two.t, &two.prim));
    let (mut found, mut ties) = (0, 0);
    let mut c = TraversalCounters::default();
    for i in 0..origins.len() {
        let (o, d) = (Vec3::from(origins[i]), Vec3::from(dirs[i]));
        let alone = s.intersect1(o, d, tmax[i], &mut c);
        let t = alone.map_or(f32::INFINITY, |h| h.t);
        assert_eq!(one.t[i].to_bits(), t.to_bits(), "ray {i}");
        if let Some(h) = alone {
            found += (i < camera_rays) as usize;
            ties += (one.prim[i] != h.prim as i32) as usize;
        }
    }
    assert!(found > camera_rays / 2, "{found}");
    assert!(ties * 100 < found, "{ties} ties");
}

/// Ray chunks poll the current stop: a set one fails the batch with `Interrupted` (on one
/// thread and on a pool), counting nothing; outside its scope the same rays are answered.
#[test]
fn a_set_stop_interrupts_ray_batches() {
    let s = unit_quad();
    let (o, d) = random_rays(s.bounds(), 1.0, 3 * CHUNK + 5, 3);
    let batch = RayBatch::new(&o, &d);
    let stop = crate::stop::Stop::new();
    stop.set();
    for threads in [Some(1), Some(2)] {
        let before = s.counters();
        let e = stop.scope(|| s.intersect(&batch, threads)).unwrap_err();
        assert!(matches!(e, crate::Error::Interrupted { .. }), "{e}");
        let e = stop.scope(|| s.occluded(&batch, threads)).unwrap_err();
        assert!(matches!(e, crate::Error::Interrupted { .. }), "{e}");
        assert_eq!(s.counters().rays, before.rays);
    }
    assert_eq!(s.occluded(&batch, Some(2)).unwrap().len(), o.len());
}
