//! Product importance sampling (CAM08 §5.5): the cost of building the product of B~ and the
//! environment's cells for one shading point, and of one sample with its pdf (no shadow
//! ray). Targets: ≤ 20 µs per shading point at 32² cells, ≤ 0.3 µs per sample. `sample`
//! returns the pdf with the direction; `sample_and_pdf` adds the separate `pdf(dir)` that
//! MIS needs.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::{DVec2, Vec3};

use _core::bsdf::Material;
use _core::lights::envmap::product::ProductDistribution;
use _core::lights::envmap::EnvMap;
use _core::sampling::rng::{hash4, to_unit_f64};

fn sky() -> EnvMap {
    _core::scenes::load("garden", 0.01, 0).unwrap().envmap
}

fn frames(n: usize) -> Vec<(Vec3, Vec3)> {
    (0..n as u64)
        .map(|i| {
            let a = to_unit_f64(hash4(1, i, 0, 0)) as f32 * std::f32::consts::TAU;
            let b = to_unit_f64(hash4(1, i, 0, 1)) as f32;
            let normal = Vec3::new(0.3 * a.cos(), 1.0, 0.3 * a.sin()).normalize();
            let wo = Vec3::new(b - 0.5, 0.6, 0.8).normalize();
            (normal, wo)
        })
        .collect()
}

fn uniform(i: u64) -> DVec2 {
    DVec2::new(
        to_unit_f64(hash4(2, i, 0, 0)),
        to_unit_f64(hash4(2, i, 0, 1)),
    )
}

fn product(c: &mut Criterion) {
    let env = sky();
    let points = frames(256);
    let materials = [
        ("lambert", Material::lambert([0.8; 3]).unwrap()),
        (
            "phong_e100",
            Material::phong([0.3; 3], [0.6; 3], 100.0).unwrap(),
        ),
        (
            "phong_e1e4",
            Material::phong([0.0; 3], [1.0; 3], 1e4).unwrap(),
        ),
    ];
    let mut g = c.benchmark_group("product");
    for (name, m) in materials {
        g.bench_function(format!("build_32x32/{name}"), |b| {
            let mut i = 0;
            b.iter(|| {
                let (n, wo) = points[i % points.len()];
                i += 1;
                black_box(ProductDistribution::new(&env, &m, n, wo, 5))
            })
        });
        let (n, wo) = points[0];
        let dist = ProductDistribution::new(&env, &m, n, wo, 5).unwrap();
        g.bench_function(format!("sample/{name}"), |b| {
            let mut i = 0u64;
            b.iter(|| {
                i += 1;
                let u = uniform(i);
                black_box(dist.sample(&env, u))
            })
        });
        g.bench_function(format!("sample_and_pdf/{name}"), |b| {
            let mut i = 0u64;
            b.iter(|| {
                i += 1;
                let u = uniform(i);
                let (dir, _, pdf) = dist.sample(&env, u);
                black_box((dir, pdf, dist.pdf(&env, dir)))
            })
        });
    }
    g.finish();
}

criterion_group!(benches, product);
criterion_main!(benches);
