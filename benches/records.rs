//! Visibility records (CAM08 §5.5): the xor-popcount difference of two maps (eq. 11; issue
//! target <= 5 ns at 32²), record creation on garden and cornell ground points (throughput in
//! shadow rays; the closest-hit rays for `R_i` are extra work inside the same time, and a
//! second variant skips them as `nearest_hits = false` caches do), the
//! same shadow rays through `Scene::occluded` in record order and shuffled (incoherent), and
//! building the coverage hierarchy.
//!
//! Run: `cargo bench --bench records`.

use std::hint::black_box;
use std::time::Duration;

use _core::geometry::{RayBatch, Scene};
use _core::sampling::pattern::default_pattern;
use _core::sampling::rng::hash4;
use _core::scenes;
use _core::testing::surface_points;
use _core::visibility::{Record, VisibilityBits};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::Vec3;

/// Two random-looking maps of resolution `m`.
fn random_pair(m: u32) -> (VisibilityBits, VisibilityBits) {
    let f = |s: u64| {
        VisibilityBits::from_fn(m, |z| hash4(s, z as u64, 0, 0) & 1 == 1).expect("valid m")
    };
    (f(1), f(2))
}

fn difference(c: &mut Criterion) {
    let mut g = c.benchmark_group("record_difference");
    for m in [5u32, 7] {
        let (a, b) = random_pair(m);
        let side = 1 << m;
        g.bench_function(
            BenchmarkId::new("xor_popcount", format!("{side}x{side}")),
            |bch| bch.iter(|| black_box(&a).difference(black_box(&b))),
        );
    }
    g.finish();
}

fn hierarchy(c: &mut Criterion) {
    let mut g = c.benchmark_group("record_hierarchy");
    for m in [5u32, 7] {
        let (a, _) = random_pair(m);
        let words = a.view().bit_words().to_vec();
        let side = 1 << m;
        g.bench_function(BenchmarkId::new("build", format!("{side}x{side}")), |bch| {
            bch.iter(|| VisibilityBits::from_bit_words(m, black_box(&words)).unwrap())
        });
        g.bench_function(
            BenchmarkId::new("node_walk", format!("{side}x{side}")),
            |bch| bch.iter(|| black_box(&a).view().nodes().count()),
        );
    }
    g.finish();
}

/// Ground points of a scene and the shadow rays their 32 x 32 records trace.
fn record_rays(
    scene: &Scene,
    points: &[(Vec3, Vec3)],
    pattern: &[Vec3],
) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    let mut origins = Vec::new();
    let mut dirs = Vec::new();
    for &(p, n) in points {
        let o = scene.offset_point(p, n);
        for d in pattern.iter().filter(|d| n.dot(**d) > 0.0) {
            origins.push(o.to_array());
            dirs.push(d.to_array());
        }
    }
    (origins, dirs)
}

fn creation(c: &mut Criterion) {
    let pattern = default_pattern(5).unwrap();
    for (name, ground) in [("garden", "ground"), ("cornell", "floor")] {
        let scene = scenes::load(name, 1.0, 0).unwrap().scene;
        scene.bvh();
        scene.set_counting(false);
        let points = surface_points(&scene, Some(ground), 256, 1);
        let (origins, dirs) = record_rays(&scene, &points, pattern);
        // A fixed shuffle of the same rays: incoherent order.
        let mut order: Vec<usize> = (0..dirs.len()).collect();
        order.sort_by_key(|&i| hash4(9, i as u64, 0, 0));
        let shuffled_o: Vec<[f32; 3]> = order.iter().map(|&i| origins[i]).collect();
        let shuffled_d: Vec<[f32; 3]> = order.iter().map(|&i| dirs[i]).collect();

        let mut g = c.benchmark_group(format!("record_create_{name}"));
        g.sample_size(10).measurement_time(Duration::from_secs(5));
        g.throughput(Throughput::Elements(dirs.len() as u64));
        g.bench_function("record_trace_32x32", |b| {
            b.iter(|| {
                let _ = _core::parallel::with_threads(Some(1), || {
                    for &(p, n) in &points {
                        black_box(Record::trace(&scene, p, n, pattern, 0).unwrap());
                    }
                });
            })
        });
        g.bench_function("record_trace_32x32_without_nearest", |b| {
            b.iter(|| {
                let _ = _core::parallel::with_threads(Some(1), || {
                    for &(p, n) in &points {
                        let traced = Record::trace_with(&scene, p, n, pattern, 0, false);
                        black_box(traced.unwrap());
                    }
                });
            })
        });
        g.bench_function("occluded_record_order", |b| {
            b.iter(|| {
                scene
                    .occluded(&RayBatch::new(&origins, &dirs), Some(1))
                    .unwrap()
            })
        });
        g.bench_function("occluded_shuffled", |b| {
            b.iter(|| {
                scene
                    .occluded(&RayBatch::new(&shuffled_o, &shuffled_d), Some(1))
                    .unwrap()
            })
        });
        g.finish();
    }
}

criterion_group!(benches, difference, hierarchy, creation);
criterion_main!(benches);
