//! Ray tracing kernels: BVH build (100k and 1M triangles), `occluded` on incoherent rays and
//! on record-building bundles, `intersect`, and the cost of the traversal counters.
//!
//! Run: `cargo bench --bench tracing`. Figures and the Embree comparison: benches/README.md.

use std::hint::black_box;
use std::time::Duration;

use _core::geometry::{BuildQuality, Bvh, Mesh, RayBatch, Scene};
use _core::parallel::with_threads;
use _core::scenes;
use _core::testing::{ground_hemisphere_rays, record_bundle_rays};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

/// The first `n` triangles of a built-in scene (whole objects where possible).
fn mesh_with(name: &str, detail: f32, n: usize) -> Mesh {
    let full = scenes::load(name, detail, 0).unwrap().scene.mesh().clone();
    assert!(
        full.num_triangles() >= n,
        "{name} has only {} triangles",
        full.num_triangles()
    );
    let mut m = full.clone();
    m.triangles.truncate(n);
    m.object_ids.truncate(n);
    m
}

fn build(c: &mut Criterion) {
    let mut g = c.benchmark_group("bvh_build");
    g.sample_size(10).measurement_time(Duration::from_secs(8));
    for (label, mesh) in [
        ("100k", mesh_with("garden", 0.3, 100_000)),
        ("1M", mesh_with("hairball", 1.0, 1_000_000)),
    ] {
        for q in [
            BuildQuality::Auto,
            BuildQuality::Sah,
            BuildQuality::Fastest,
            BuildQuality::Fast,
            BuildQuality::Medium,
        ] {
            g.throughput(Throughput::Elements(mesh.num_triangles() as u64));
            g.bench_with_input(BenchmarkId::new(q.name(), label), &mesh, |b, m| {
                b.iter(|| with_threads(Some(2), || Bvh::build(m, q)).unwrap())
            });
        }
    }
    g.finish();
}

fn traversal(c: &mut Criterion) {
    let n = 1 << 20;
    for name in ["garden", "cornell"] {
        let scene = scenes::load(name, 1.0, 0).unwrap().scene;
        scene.bvh();
        let (o, d) = ground_hemisphere_rays(&scene, n, 1);
        let (bo, bd) = record_bundle_rays(&scene, 1000, 32, 1);
        let mut g = c.benchmark_group(format!("trace_{name}"));
        g.sample_size(10).measurement_time(Duration::from_secs(6));
        g.throughput(Throughput::Elements(n as u64));
        for threads in [1, 2] {
            let rays = RayBatch::new(&o, &d);
            scene.set_counting(false);
            g.bench_function(BenchmarkId::new("occluded_incoherent", threads), |b| {
                b.iter(|| black_box(scene.occluded(&rays, Some(threads)).unwrap()))
            });
            scene.set_counting(true);
            g.bench_function(
                BenchmarkId::new("occluded_incoherent_counted", threads),
                |b| b.iter(|| black_box(scene.occluded(&rays, Some(threads)).unwrap())),
            );
            scene.set_counting(false);
            g.bench_function(BenchmarkId::new("intersect_incoherent", threads), |b| {
                b.iter(|| black_box(scene.intersect(&rays, Some(threads)).unwrap()))
            });
        }
        g.throughput(Throughput::Elements(bo.len() as u64));
        let bundles = RayBatch::new(&bo, &bd);
        for threads in [1, 2] {
            g.bench_function(BenchmarkId::new("occluded_bundles", threads), |b| {
                b.iter(|| black_box(scene.occluded(&bundles, Some(threads)).unwrap()))
            });
        }
        g.finish();
    }
}

fn counting_overhead(c: &mut Criterion) {
    // Same rays with counters on and off, single thread, so the ratio isolates the adds.
    let scene = scenes::load("garden", 1.0, 0).unwrap().scene;
    let (o, d) = ground_hemisphere_rays(&scene, 1 << 18, 2);
    let rays = RayBatch::new(&o, &d);
    let mut g = c.benchmark_group("counters");
    g.sample_size(20)
        .throughput(Throughput::Elements(o.len() as u64));
    for on in [false, true] {
        scene.set_counting(on);
        g.bench_function(if on { "on" } else { "off" }, |b| {
            b.iter(|| black_box(scene.occluded(&rays, Some(1)).unwrap()))
        });
    }
    g.finish();
    let _ = Scene::new();
}

criterion_group!(benches, build, traversal, counting_overhead);
criterion_main!(benches);
