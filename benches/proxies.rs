//! Proxy builds (BLD §3, issue 66 §1; target: <= 2 s for a 1M-triangle scene on 2 cores):
//! each kind of `geometry::proxies::build` on the hairball at detail 0.66 (~1M triangles,
//! the tangle one object) and, for inside proxies, on the blob (one closed 330k-triangle
//! object).
//!
//! Run: `cargo bench --bench proxies`. Figures: benches/README.md.

use std::time::Duration;

use _core::geometry::proxies::{build, ProxyOptions};
use _core::parallel::with_threads;
use _core::scenes;
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};

fn proxies(c: &mut Criterion) {
    let mut g = c.benchmark_group("proxy_build");
    g.sample_size(10).measurement_time(Duration::from_secs(10));
    let d = ProxyOptions::DEFAULT;
    let hairball = scenes::load("hairball", 0.66, 0).unwrap().scene;
    let blob = scenes::load("blob", 1.0, 0).unwrap().scene;
    let cases = [
        ("hairball", &hairball, "outside", "box", d.clone()),
        (
            "hairball",
            &hairball,
            "outside",
            "hull",
            ProxyOptions {
                hull: true,
                ..d.clone()
            },
        ),
        (
            "hairball",
            &hairball,
            "outside",
            "hull32",
            ProxyOptions {
                hull: true,
                target: Some(32),
                ..d.clone()
            },
        ),
        ("hairball", &hairball, "general", "cell3%", d.clone()),
        (
            "hairball",
            &hairball,
            "general",
            "target512",
            ProxyOptions {
                target: Some(512),
                ..d.clone()
            },
        ),
        (
            "hairball",
            &hairball,
            "mixed",
            "hull",
            ProxyOptions {
                hull: true,
                ..d.clone()
            },
        ),
        (
            "blob",
            &blob,
            "inside",
            "40",
            ProxyOptions {
                objects: Some(vec![1]),
                ..d.clone()
            },
        ),
        ("blob", &blob, "general", "cell3%", d.clone()),
    ];
    for (name, scene, kind, label, options) in cases {
        let set = with_threads(Some(2), || build(scene, kind, &options))
            .unwrap()
            .unwrap();
        eprintln!(
            "{name} ({} triangles): {kind} {label}: {} proxy triangles",
            scene.num_triangles(),
            set.num_triangles()
        );
        g.bench_function(BenchmarkId::new(format!("{name}_{kind}"), label), |b| {
            b.iter(|| {
                with_threads(Some(2), || build(scene, kind, &options))
                    .unwrap()
                    .unwrap()
            })
        });
    }
    g.finish();
}

criterion_group!(benches, proxies);
criterion_main!(benches);
