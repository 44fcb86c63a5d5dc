//! The visibility cache (CAM08 §5.1–5.2): one lookup (`m = 16`, `n = 4`, eq. 9 weights,
//! `w_g`, β and `δ̄`; `_records`: without `δ̄`, as a renderer asks) among 1k, 10k, 100k and
//! 1M records (issue target <= 1 µs at 100k),
//! and insertion into the kd-tree amortised over 100k records (target <= 2 µs, rays
//! excluded: the records are made beforehand). Bytes per record are printed at start-up.
//!
//! Records lie on the unit square of the plane y = 0 (as on a floor; one coordinate shared
//! by all, the case kiddo's bucket size matters for) with normals tilted up to 20° from +y;
//! the search radius holds about 24 records, so `m = 16` candidates are nearly always found.
//! Queries come in two orders: random (each lookup misses the CPU caches: the records it
//! reads are scattered over up to 172 MB) and pixel order (consecutive queries one
//! footprint apart, as a renderer walking a G-buffer issues them).
//!
//! Run: `cargo bench --bench cache`.

use std::hint::black_box;
use std::time::{Duration, Instant};

use _core::sampling::rng::{hash4, to_unit_f32};
use _core::testing::synthetic_record;
use _core::visibility::{bytes_per_record, CacheParams, Record, VisibilityCache};
use criterion::{criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};
use glam::Vec3;

const DISTINCT_MAPS: usize = 1024;

fn unit(seed: u64, k: u64) -> f32 {
    to_unit_f32(hash4(seed, k, 0, 3))
}

fn point(seed: u64, k: u64) -> (Vec3, Vec3) {
    let p = Vec3::new(unit(seed, 4 * k), 0.0, unit(seed, 4 * k + 1));
    let tilt = 0.35 * unit(seed, 4 * k + 2);
    let phi = std::f32::consts::TAU * unit(seed, 4 * k + 3);
    let n = Vec3::new(tilt * phi.cos(), 1.0, tilt * phi.sin()).normalize();
    (p, n)
}

/// `count` records: positions and normals from [`point`], maps from a pool of 1024.
fn records(count: usize) -> Vec<Record> {
    let pool: Vec<Record> = (0..DISTINCT_MAPS as u64)
        .map(|k| synthetic_record(5, Vec3::ZERO, Vec3::Y, 0.6, k))
        .collect();
    (0..count)
        .map(|k| {
            let (p, n) = point(1, k as u64);
            let mut r = pool[k % DISTINCT_MAPS].clone();
            r.position = p;
            r.normal = n;
            r
        })
        .collect()
}

fn filled(count: usize) -> VisibilityCache {
    let c = VisibilityCache::new(CacheParams {
        max_records: 2_000_000,
        ..CacheParams::MEDIUM
    })
    .unwrap();
    for r in records(count) {
        c.insert_record(&r).unwrap();
    }
    c
}

fn lookup(c: &mut Criterion) {
    let mut g = c.benchmark_group("cache_lookup");
    g.measurement_time(Duration::from_secs(4));
    for count in [1_000usize, 10_000, 100_000, 1_000_000] {
        let cache = filled(count);
        // About 24 records within d_max (a build with w_min = 0.55 keeps 10–20).
        let d_max = (24.0 / (std::f32::consts::PI * count as f32)).sqrt();
        let queries: Vec<(Vec3, Vec3)> = (0..4096).map(|k| point(7, k)).collect();
        let state = cache.read();
        let params = *cache.params();
        let found: usize = queries
            .iter()
            .map(|&(x, n)| state.lookup(&params, x, n, d_max).neighbours().len())
            .sum();
        println!(
            "cache_lookup/{count}: d_max {d_max:.4}, mean kept {:.2}",
            found as f64 / queries.len() as f64
        );
        // Random points: every lookup starts with cold caches (the worst case). Pixel
        // order: rows of points one footprint (d_max / 12, the default k) apart, as a
        // renderer walks a G-buffer; consecutive lookups share most records, and the
        // thread's LookupScratch serves several of them from one range query.
        let step = d_max / 12.0;
        let per_row = (1.0 / step) as usize;
        let rows: Vec<(Vec3, Vec3)> = (0..64 * per_row)
            .map(|i| {
                let (r, c) = (i / per_row, i % per_row);
                let x = Vec3::new(c as f32 * step, 0.0, unit(9, r as u64));
                (x, point(11, i as u64).1)
            })
            .collect();
        // Full lookups (records, β and δ̄), and `_records`: the records and β alone, what a
        // renderer asks.
        for (order, points) in [("random", &queries), ("pixel_order", &rows)] {
            for records in [false, true] {
                let name = if records {
                    format!("m16_n4_records_{order}")
                } else {
                    format!("m16_n4_{order}")
                };
                let mut k = 0;
                g.bench_function(BenchmarkId::new(name, count), |b| {
                    b.iter(|| {
                        let (x, n) = points[k % points.len()];
                        k += 1;
                        let (x, n) = (black_box(x), black_box(n));
                        black_box(if records {
                            state.lookup_records(&params, x, n, d_max)
                        } else {
                            state.lookup(&params, x, n, d_max)
                        })
                    })
                });
            }
        }
    }
    g.finish();
}

fn insert(c: &mut Criterion) {
    const COUNT: usize = 100_000;
    let recs = records(COUNT);
    let mut g = c.benchmark_group("cache_insert");
    g.sample_size(10);
    g.throughput(Throughput::Elements(COUNT as u64));
    g.bench_function(BenchmarkId::new("amortised", COUNT), |b| {
        b.iter_custom(|iters| {
            let mut total = Duration::ZERO;
            for _ in 0..iters {
                let cache = VisibilityCache::new(CacheParams::MEDIUM).unwrap();
                let start = Instant::now();
                for r in &recs {
                    cache.insert_record(black_box(r)).unwrap();
                }
                total += start.elapsed();
                black_box(&cache);
            }
            total
        })
    });
    g.finish();
}

fn print_sizes(_: &mut Criterion) {
    for m in 1..=7u32 {
        println!(
            "bytes per record at {0}x{0}: {1}",
            1 << m,
            bytes_per_record(m)
        );
    }
}

criterion_group!(benches, print_sizes, lookup, insert);
criterion_main!(benches);
