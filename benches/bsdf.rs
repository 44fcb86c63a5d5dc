//! BSDF kernels: B~ over the 32² cells of octahedral level 5 (the per-shading-point cost of
//! product importance sampling; target ≤ 10 µs) and one `sample` + `pdf` pair.

use std::hint::black_box;

use _core::bsdf::Material;
use _core::sampling::rng::SampleRng;
use criterion::{criterion_group, criterion_main, Criterion};
use glam::{Vec2, Vec3};

fn bench_product_cells(c: &mut Criterion) {
    let n = Vec3::new(0.3, 0.8, -0.5).normalize();
    let wo = Vec3::new(0.7, 0.5, 0.1).normalize();
    let mats = [
        ("lambert", Material::lambert([0.8, 0.6, 0.4]).unwrap()),
        (
            "phong_e100",
            Material::phong([0.3; 3], [0.6; 3], 100.0).unwrap(),
        ),
        (
            "phong_e1e4",
            Material::phong([0.3; 3], [0.6; 3], 1e4).unwrap(),
        ),
    ];
    let mut out = vec![0.0f32; 1024];
    for (name, m) in mats {
        m.product_cells(n, wo, 5, &mut out); // builds the level-5 table outside the timing
        c.bench_function(&format!("product_cells_level5/{name}"), |b| {
            b.iter(|| m.product_cells(black_box(n), black_box(wo), 5, black_box(&mut out)))
        });
    }
}

fn bench_sample_pdf(c: &mut Criterion) {
    let n = Vec3::new(0.3, 0.8, -0.5).normalize();
    let wo = Vec3::new(0.7, 0.5, 0.1).normalize();
    for (name, m) in [
        ("lambert", Material::lambert([0.8, 0.6, 0.4]).unwrap()),
        (
            "phong_e100",
            Material::phong([0.3; 3], [0.6; 3], 100.0).unwrap(),
        ),
    ] {
        let mut i = 0u64;
        c.bench_function(&format!("sample_pdf/{name}"), |b| {
            b.iter(|| {
                i += 1;
                let rng = SampleRng::new(1, 0, i);
                let wi = m.sample(
                    black_box(n),
                    black_box(wo),
                    rng.get(0),
                    Vec2::from(rng.get2(1)),
                );
                wi.map(|wi| m.pdf(n, wo, wi))
            })
        });
    }
}

criterion_group!(benches, bench_product_cells, bench_sample_pdf);
criterion_main!(benches);
