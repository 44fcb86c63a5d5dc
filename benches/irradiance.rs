//! The irradiance cache's lookup with interpolation (Survey eq. 3.7–3.8, issue target
//! <= 1 µs per point on 2 cores): records placed on the unit square of the floor y = 0 as a
//! build places them (a record wherever none is usable, over a grid of query points coarse
//! to fine), with radii varying smoothly over the floor, then `interpolate` at random points
//! and in pixel order, one thread, and `interpolate_batch` over 100k points on 2 threads.
//! Bytes per record and records per lookup are printed at start-up.
//!
//! Run: `cargo bench --bench irradiance`.

use std::hint::black_box;

use _core::estimators::irradiance::cache::{IrradianceCache, IrradianceParams};
use _core::estimators::irradiance::record::IrradianceRecord;
use _core::sampling::rng::{hash4, to_unit_f32};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::Vec3;

fn unit(seed: u64, k: u64) -> f32 {
    to_unit_f32(hash4(seed, k, 0, 5))
}

/// `R` over the floor: between `0.25·scale` and `scale`, smooth.
fn radius_at(p: Vec3, scale: f32) -> f32 {
    scale * (0.625 + 0.375 * (7.0 * p.x).sin() * (5.0 * p.z).cos())
}

/// A cache grown over a `side x side` grid of points (coarse to fine, as a G-buffer's
/// pixels), `R` about 16 grid steps, the default `a`.
fn grown(side: u32) -> IrradianceCache {
    let cache = IrradianceCache::new(IrradianceParams::DEFAULT).unwrap();
    let step = 1.0 / side as f32;
    let mut scratch = Vec::new();
    let mut spacing = 32u32;
    loop {
        for y in (0..side).step_by(spacing as usize) {
            for x in (0..side).step_by(spacing as usize) {
                let p = Vec3::new(x as f32 * step, 0.0, y as f32 * step);
                if cache.read().covers(p, Vec3::Y, &mut scratch) {
                    continue;
                }
                let k = (y * side + x) as u64;
                let record = IrradianceRecord {
                    position: p,
                    normal: Vec3::Y,
                    irradiance: [1.0 + unit(1, k), 0.5, 0.25],
                    radius: radius_at(p, 16.0 * step),
                    rotation: [Vec3::new(0.1, 0.0, -0.2); 3],
                    translation: [Vec3::new(2.0 * unit(2, k), 0.0, 1.0); 3],
                };
                cache.insert_record(record).unwrap();
            }
        }
        if spacing == 1 {
            return cache;
        }
        spacing /= 2;
    }
}

fn lookups(c: &mut Criterion) {
    let mut group = c.benchmark_group("irradiance_lookup");
    for side in [256u32, 1024] {
        let cache = grown(side);
        let n = 100_000usize;
        let random: Vec<Vec3> = (0..n as u64)
            .map(|k| Vec3::new(unit(3, 2 * k), 0.0, unit(3, 2 * k + 1)))
            .collect();
        let step = 1.0 / side as f32;
        let ordered: Vec<Vec3> = (0..n as u32)
            .map(|k| {
                Vec3::new(
                    (k % side) as f32 * step,
                    0.0,
                    (k / side % side) as f32 * step,
                )
            })
            .collect();
        let state = cache.read();
        let used: u64 = random
            .iter()
            .filter_map(|&p| state.interpolate(p, Vec3::Y, &mut Vec::new()))
            .map(|f| f.records as u64)
            .sum();
        println!(
            "{side}x{side} points: {} records, {} B each, {:.2} records per lookup",
            cache.len(),
            IrradianceCache::record_bytes(),
            used as f64 / n as f64
        );
        drop(state);
        group.throughput(Throughput::Elements(1));
        for (order, points) in [("random", &random), ("pixel_order", &ordered)] {
            group.bench_with_input(
                BenchmarkId::new(format!("{order}_1_thread"), cache.len()),
                points,
                |b, points| {
                    let state = cache.read();
                    let mut scratch = Vec::new();
                    let mut i = 0;
                    b.iter(|| {
                        i = (i + 1) % points.len();
                        black_box(state.interpolate(points[i], Vec3::Y, &mut scratch))
                    })
                },
            );
        }
        let normals = vec![Vec3::Y; n];
        group.throughput(Throughput::Elements(n as u64));
        group.sample_size(10);
        group.bench_with_input(
            BenchmarkId::new("pixel_order_batch_2_threads", cache.len()),
            &ordered,
            |b, points| b.iter(|| black_box(cache.interpolate_batch(points, &normals, Some(2)))),
        );
        group.sample_size(100);
    }
    group.finish();
}

criterion_group!(benches, lookups);
criterion_main!(benches);
