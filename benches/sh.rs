//! Spherical harmonics for the lighting preview: the projection of an octahedral map (the
//! cost of every lighting change), the cell-basis projection of one pixel's transfer (the
//! per-pixel cost of preparation) and the rotation matrices of a map turn.

use std::hint::black_box;

use _core::sampling::sh::{project_texels, CellBasis, Rotation};
use criterion::{criterion_group, criterion_main, Criterion};
use glam::{DMat3, DVec3};

fn bench_project_texels(c: &mut Criterion) {
    for res in [256u32, 512] {
        let tex: Vec<[f32; 3]> = (0..res * res)
            .map(|i| {
                let v = (i % 97) as f32 * 0.01;
                [v, 0.5 * v, 2.0 - v]
            })
            .collect();
        for order in [4u32, 8, 12] {
            c.bench_function(&format!("project_texels/res{res}/order{order}"), |b| {
                b.iter(|| project_texels(order, black_box(&tex), res))
            });
        }
    }
}

fn bench_cell_project(c: &mut Criterion) {
    for level in [4u32, 5] {
        let basis = CellBasis::new(8, level);
        // A transfer with a third of the cells occluded (zero), as visibility leaves it.
        let per_cell: Vec<f32> = (0..basis.cells())
            .map(|i| {
                if i % 3 == 0 {
                    0.0
                } else {
                    (i % 13) as f32 * 0.1
                }
            })
            .collect();
        let mut out = vec![0.0f32; 64];
        c.bench_function(&format!("cell_project/order8/level{level}"), |b| {
            b.iter(|| basis.project(black_box(&per_cell), black_box(&mut out)))
        });
    }
}

fn bench_rotation(c: &mut Criterion) {
    let r = DMat3::from_axis_angle(DVec3::new(0.3, 1.0, -0.2).normalize(), 0.8);
    for order in [8u32, 16] {
        c.bench_function(&format!("rotation_new/order{order}"), |b| {
            b.iter(|| Rotation::new(order, black_box(r)).unwrap())
        });
    }
}

criterion_group!(
    benches,
    bench_project_texels,
    bench_cell_project,
    bench_rotation
);
criterion_main!(benches);
