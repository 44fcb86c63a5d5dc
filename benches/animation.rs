//! Animated scenes: updating the BVH after the `dynamics` sphere moves, by refit and by
//! rebuild, and tracing speed with each tree over the frames.
//!
//! Run: `cargo bench --bench animation`. Figures: benches/README.md.

use std::hint::black_box;
use std::time::Duration;

use _core::camera::Camera;
use _core::geometry::{Bvh, BvhUpdate, Scene, TraversalCounters};
use _core::math::{to_world, uniform_hemisphere};
use _core::parallel::with_threads;
use _core::sampling::rng::SampleRng;
use _core::scenes::{self, Animation};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::Vec3A;

/// The animated `dynamics` scene at `detail`, with its BVH built at the rest pose, and its
/// camera.
fn animated(detail: f32) -> (Scene, Animation, Camera) {
    let s = scenes::load_animated("dynamics", detail, 0).unwrap();
    s.scene.bvh();
    (s.scene, s.animation.unwrap(), s.camera)
}

type Rays = (Vec<[f32; 3]>, Vec<[f32; 3]>);

/// What a renderer traces: primary rays through the pixel centres of `cam`, and from each
/// hit one shadow ray uniform on the hemisphere about the normal facing the camera.
fn camera_workload(scene: &Scene, cam: &Camera) -> (Rays, Rays) {
    let mut c = TraversalCounters::default();
    let (mut primary, mut shadow): (Rays, Rays) = Default::default();
    for y in 0..cam.height {
        for x in 0..cam.width {
            let d = cam.direction(x as f32 + 0.5, y as f32 + 0.5);
            primary.0.push(cam.eye.to_array());
            primary.1.push(d.to_array());
            if let Some(h) = scene.intersect1(cam.eye, d, f32::INFINITY, &mut c) {
                let n = if h.normal.dot(d) > 0.0 {
                    -h.normal
                } else {
                    h.normal
                };
                let u = SampleRng::new(3, (y * cam.width + x) as u64, 0).get2(0);
                shadow.0.push(scene.offset_point(h.position, n).to_array());
                shadow.1.push(to_world(uniform_hemisphere(u), n).to_array());
            }
        }
    }
    (primary, shadow)
}

/// Moving the sphere to the next frame (cycling through a period) and updating the BVH:
/// refit (one thread: it is serial), or rebuild (the `medium` preset on 2 threads).
fn update(c: &mut Criterion) {
    for detail in [1.0, 16.0] {
        let (scene, anim, _) = animated(detail);
        let mut g = c.benchmark_group(format!("animation_update_{}", scene.num_triangles()));
        g.sample_size(20).measurement_time(Duration::from_secs(4));
        for update in [BvhUpdate::Refit, BvhUpdate::Rebuild] {
            let mut s = scene.clone();
            let mut frame = 0;
            let name = format!("{update:?}").to_lowercase();
            g.bench_function(name, |b| {
                b.iter(|| {
                    frame = (frame + 1) % anim.period();
                    s.set_object_transform_with(anim.object, anim.transform(frame), update)
                        .unwrap();
                    if update == BvhUpdate::Rebuild {
                        with_threads(Some(2), || black_box(s.bvh())).unwrap();
                    }
                })
            });
        }
        g.finish();
    }
}

/// Traces `rays` one after the other: closest hits (`primary`) or shadow queries.
/// Returns the number of hits.
fn trace<const COUNT: bool>(
    bvh: &Bvh,
    rays: &[(Vec3A, Vec3A)],
    primary: bool,
    k: &mut TraversalCounters,
) -> u32 {
    let mut n = 0;
    for &(o, d) in rays {
        n += if primary {
            bvh.intersect::<COUNT>(o, d, f32::INFINITY, k).is_some()
        } else {
            bvh.occluded::<COUNT>(o, d, f32::INFINITY, k)
        } as u32;
    }
    n
}

/// Tracing after moving the sphere, through four trees: the scene's (built at the rest
/// pose with the sphere in a subtree of its own, then refit: what `at_frame` does), the
/// same built at the frame (`BvhUpdate::Rebuild`), a whole-scene build at the frame (the
/// best tree the builder makes), and a whole-scene build at the rest pose refit to the
/// frame (a refit without the separate subtree). Workload: the camera's primary rays
/// (`intersect`) and one hemisphere shadow ray per hit (`occluded`) at 256 x 192, on one
/// thread.
fn trace_after(c: &mut Criterion) {
    let (rest, anim, cam) = animated(1.0);
    let range = {
        let o = &rest.mesh().objects[anim.object as usize];
        o.first_triangle as usize..(o.first_triangle + o.num_triangles) as usize
    };
    let quality = rest.bvh().quality();
    let whole_rest = Bvh::build(rest.mesh(), quality);
    let mut g = c.benchmark_group("animation_trace");
    g.sample_size(10).measurement_time(Duration::from_secs(3));
    for frame in [0, 15, 30] {
        let mut scene = rest.clone();
        scene
            .set_object_transform(anim.object, anim.transform(frame))
            .unwrap();
        let mesh = scene.mesh();
        let mut whole_refit = whole_rest.clone();
        assert!(whole_refit.refit(mesh, range.clone()));
        let trees = [
            ("refit", scene.bvh().clone()),
            (
                "rebuilt",
                Bvh::build_grouped(mesh, quality, std::slice::from_ref(&range)),
            ),
            ("whole", Bvh::build(mesh, quality)),
            ("whole_refit", whole_refit),
        ];
        let (primary, shadow) = camera_workload(&scene, &cam);
        for (kind, (o, d)) in [("primary", &primary), ("shadow", &shadow)] {
            let rays: Vec<(Vec3A, Vec3A)> = o
                .iter()
                .zip(d)
                .map(|(o, d)| (Vec3A::from(*o), Vec3A::from(*d)))
                .collect();
            let primary = kind == "primary";
            for (tree, bvh) in &trees {
                let mut k = TraversalCounters::default();
                trace::<true>(bvh, &rays, primary, &mut k);
                eprintln!(
                    "frame {frame} {kind} {tree}: {:.2} nodes, {:.2} triangles per ray",
                    k.nodes as f64 / k.rays as f64,
                    k.triangles as f64 / k.rays as f64
                );
                g.throughput(Throughput::Elements(rays.len() as u64));
                g.bench_function(BenchmarkId::new(format!("{kind}_{tree}"), frame), |b| {
                    b.iter(|| {
                        let mut k = TraversalCounters::default();
                        black_box(trace::<false>(bvh, &rays, primary, &mut k))
                    })
                });
            }
        }
    }
    g.finish();
}

criterion_group!(benches, update, trace_after);
criterion_main!(benches);
