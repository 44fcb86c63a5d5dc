//! The record index's reach query (`SpatialIndex::within_reach`, the irradiance cache's
//! lookup; issue target for lookup with interpolation <= 1 µs per point on 2 cores): every
//! record whose reach covers a point, sorted by id, among 100k records on the floor y = 0,
//! one per unit square of a 400 x 250 grid (jittered inside it, so the spacing is 1).
//!
//! Reaches are uniform in 1–30 units (the spread: a point is covered by about 920
//! records) and in 1–3 (about 14, nearer an irradiance cache, whose records lie a few
//! reaches apart). Queries come in pixel order (rows of points 0.25 apart, four pixels
//! per record spacing, rows at random heights) and at random over the floor.
//! `refresh_reach` over the 100k records is timed too.
//!
//! Run: `cargo bench --bench reach_query`.

use std::hint::black_box;
use std::time::Duration;

use _core::sampling::rng::{hash4, to_unit_f32};
use _core::spatial::{Records, SpatialIndex};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion};
use glam::Vec3;

const COLUMNS: usize = 400;
const ROWS: usize = 250;

fn unit(seed: u64, k: u64) -> f32 {
    to_unit_f32(hash4(seed, k, 0, 4))
}

/// Positions and reaches, by id.
struct Floor {
    position: Vec<Vec3>,
    radius: Vec<f32>,
}

impl Records for Floor {
    fn len(&self) -> usize {
        self.position.len()
    }

    fn site(&self, id: usize) -> (Vec3, Vec3) {
        (self.position[id], Vec3::Y)
    }

    fn radius(&self, id: usize) -> f32 {
        self.radius[id]
    }
}

/// The grid's records in a seeded order (as inserted in waves, not scanline by scanline),
/// reaches uniform in `[lo, hi]`, indexed one insertion at a time.
fn floor(lo: f32, hi: f32) -> SpatialIndex<Floor> {
    let count = COLUMNS * ROWS;
    let mut cells: Vec<(u64, usize)> = (0..count).map(|k| (hash4(1, k as u64, 0, 0), k)).collect();
    cells.sort_unstable();
    let mut index = SpatialIndex::new(Floor {
        position: Vec::new(),
        radius: Vec::new(),
    });
    for (id, &(_, cell)) in cells.iter().enumerate() {
        let (c, r) = ((cell % COLUMNS) as f32, (cell / COLUMNS) as f32);
        let k = id as u64;
        let p = Vec3::new(c + unit(2, 2 * k), 0.0, r + unit(2, 2 * k + 1));
        let reach = lo + (hi - lo) * unit(3, k);
        index
            .admit(|f| {
                f.position.push(p);
                f.radius.push(reach);
                Ok(f.position.len() - 1)
            })
            .unwrap();
    }
    index
}

fn within_reach(c: &mut Criterion) {
    let mut g = c.benchmark_group("reach_query");
    g.measurement_time(Duration::from_secs(4));
    let random: Vec<Vec3> = (0..4096)
        .map(|k| {
            Vec3::new(
                COLUMNS as f32 * unit(7, 2 * k),
                0.0,
                ROWS as f32 * unit(7, 2 * k + 1),
            )
        })
        .collect();
    let per_row = 4 * COLUMNS;
    let pixels: Vec<Vec3> = (0..16 * per_row)
        .map(|i| {
            let (r, c) = (i / per_row, i % per_row);
            Vec3::new(c as f32 * 0.25, 0.0, ROWS as f32 * unit(9, r as u64))
        })
        .collect();
    for (name, lo, hi) in [("reach_1_30", 1.0f32, 30.0f32), ("reach_1_3", 1.0, 3.0)] {
        let index = floor(lo, hi);
        let mut out = Vec::new();
        for (order, points) in [("random", &random), ("pixel_order", &pixels)] {
            let found: usize = points
                .iter()
                .map(|&x| {
                    out.clear();
                    index.within_reach(x, &mut out);
                    out.len()
                })
                .sum();
            println!(
                "reach_query/{name}/{order}: {:.1} records found per query, {} B index",
                found as f64 / points.len() as f64,
                index.memory_bytes()
            );
            let mut k = 0;
            g.bench_function(BenchmarkId::new(name, order), |b| {
                b.iter(|| {
                    let x = points[k % points.len()];
                    k += 1;
                    out.clear();
                    index.within_reach(black_box(x), &mut out);
                    black_box(out.len())
                })
            });
        }
        let mut index = index;
        g.bench_function(BenchmarkId::new("refresh_reach_100k", name), |b| {
            b.iter(|| index.refresh_reach())
        });
    }
    g.finish();
}

criterion_group!(benches, within_reach);
criterion_main!(benches);
