//! The control variate's per-point cost (CAM08 §5.5): the tables of `L B~` for one shading
//! point, `J = Σ β_i J_i` over a lookup's records, and both with the lookup, on garage's
//! own records and G-buffer points (pixel order), at record resolutions 32² and 64².
//! What a render adds per pixel to product sampling is `lookup + tables + J`.

use std::hint::black_box;

use criterion::{criterion_group, criterion_main, Criterion};
use glam::Vec3;

use _core::camera::GBuffer;
use _core::lights::envmap::chroma::MapChroma;
use _core::lights::envmap::product::ProductDistribution;
use _core::visibility::cache::interpolant::{ControlTables, Interpolant};
use _core::visibility::cache::VisibilityCache;
use _core::visibility::params::CacheParams;

fn control_variate(c: &mut Criterion) {
    let setup = _core::scenes::load("garage", 1.0, 0).unwrap();
    let camera = setup.camera.with_resolution(128, 96).unwrap();
    let env = &setup.envmap;
    let chroma = MapChroma::new(env);
    let g = GBuffer::render(&setup.scene, &camera, 0, false, None).unwrap();
    let objects = &setup.scene.mesh().objects;
    let points: Vec<usize> = (0..g.object.len()).filter(|&i| g.object[i] >= 0).collect();
    let mut group = c.benchmark_group("control_variate");
    for m in [5u32, 6] {
        let cache = VisibilityCache::new(CacheParams::MEDIUM.with_log2_resolution(m)).unwrap();
        cache
            .build(&setup.scene, &camera, 0, None, None, &mut |_, _| true)
            .unwrap();
        let state = cache.read();
        let params = cache.params();
        // Per point: product, lookup (radius from the footprint).
        let prepared: Vec<_> = points
            .iter()
            .map(|&i| {
                let n = Vec3::from(g.normal[i]);
                let wo = -Vec3::from(g.direction[i]);
                let mat = objects[g.object[i] as usize].material;
                let product =
                    ProductDistribution::new(env, &mat, n, wo, mat.product_level_hint()).unwrap();
                let x = Vec3::from(g.position[i]);
                let d_max = params.d_max_scale * g.footprint[i];
                (product, x, n, d_max)
            })
            .collect();
        let r = 1 << m;
        group.bench_function(format!("lookup/{r}x{r}"), |b| {
            let mut k = 0;
            b.iter(|| {
                let (_, x, n, d) = &prepared[k % prepared.len()];
                k += 1;
                black_box(state.lookup(params, *x, *n, *d))
            })
        });
        let lookups: Vec<_> = prepared
            .iter()
            .map(|(_, x, n, d)| state.lookup(params, *x, *n, *d))
            .collect();
        let mut tables = ControlTables::new(&prepared[0].0, &chroma, m);
        group.bench_function(format!("tables/{r}x{r}"), |b| {
            let mut k = 0;
            b.iter(|| {
                let (product, ..) = &prepared[k % prepared.len()];
                k += 1;
                tables.fill(product, &chroma, m);
                black_box(tables.total())
            })
        });
        group.bench_function(format!("tables_and_j/{r}x{r}"), |b| {
            let mut k = 0;
            b.iter(|| {
                let i = k % prepared.len();
                k += 1;
                tables.fill(&prepared[i].0, &chroma, m);
                let product = &prepared[i].0;
                black_box(Interpolant::new(&state, &lookups[i], Some((&tables, product, env))).j)
            })
        });
    }
    group.finish();
}

criterion_group!(benches, control_variate);
criterion_main!(benches);
