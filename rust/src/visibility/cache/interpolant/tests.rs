use glam::{UVec2, Vec3};

use super::*;
use crate::bsdf::Material;
use crate::lights::envmap::chroma::tests::{close, test_sky};
use crate::lights::envmap::chroma::{MapChroma, MIN_PEAK_DEPTH};
use crate::sampling::octahedral::{morton_decode, texel_solid_angle};
use crate::sampling::rng::hash4;
use crate::visibility::cache::VisibilityCache;
use crate::visibility::params::CacheParams;
use crate::visibility::record::{Record, VisibilityBits};

pub(crate) fn frame() -> (Vec3, Vec3) {
    (
        Vec3::new(0.2, 0.9, -0.3).normalize(),
        Vec3::new(-0.5, 0.4, 0.6).normalize(),
    )
}

/// Random bits with some coherence: blocks of 4^k texels share a coin.
pub(crate) fn random_bits(m: u32, seed: u64) -> VisibilityBits {
    VisibilityBits::from_fn(m, |z| {
        let block = (seed % 3) as u32 * 2;
        let key = (z >> block.min(2 * m)) as u64;
        !hash4(seed, key, 0, 0).is_multiple_of(3)
    })
    .unwrap()
}

/// `(∫ κ L_lum B~ dω, ∫ L_lum B~ dω, ∫ κ L_lum B~ V dω)` as plain sums over the finest
/// grid of the three (texels of equal solid angle), `κ` the colour of each texel's
/// region of level `regions` under `chroma`, independent of pyramids and hierarchies.
fn brute_force(
    env: &EnvMap,
    chroma: &MapChroma,
    regions: u32,
    product: &ProductDistribution,
    bits: &VisibilityBits,
) -> ([f64; 3], f64, [f64; 3]) {
    let e = env.resolution().trailing_zeros();
    let (p, m) = (product.level(), bits.m());
    let f = e.max(p).max(m);
    let side = 1u32 << f;
    let omega = texel_solid_angle(side);
    let (mut total, mut lum, mut j) = ([0.0f64; 3], 0.0, [0.0f64; 3]);
    for code in 0..side * side {
        let t = morton_decode(code);
        let env_texel = UVec2::new(t.x >> (f - e), t.y >> (f - e));
        let l = env.texels()[(env_texel.y * env.resolution() + env_texel.x) as usize];
        let cell = morton_encode(t.x >> (f - p), t.y >> (f - p));
        let b = product.bsdf_cells()[cell as usize] as f64 * omega;
        let y = crate::lights::envmap::luminance(l) * b;
        let kappa = chroma.control_colour(code >> (2 * (f - e)), regions);
        let visible = bits.get(morton_encode(t.x >> (f - m), t.y >> (f - m)) as usize);
        for c in 0..3 {
            total[c] += kappa[c] * y;
            if visible {
                j[c] += kappa[c] * y;
            }
        }
        lum += y;
    }
    (total, lum, j)
}

#[test]
fn record_integrals_equal_the_brute_force_sum() {
    // (record M, product level, map resolution): records coarser, equal and finer than
    // the cells; cells capped by coarse maps; sub-word maps.
    let cases = [
        (1, 1, 2),
        (2, 3, 8),
        (3, 3, 64),
        (5, 5, 64),
        (5, 3, 64),
        (4, 5, 256),
        (6, 5, 32),
        (7, 4, 16),
    ];
    let materials = [
        Material::lambert([0.8, 0.5, 0.3]).unwrap(),
        Material::phong([0.2; 3], [0.7; 3], 40.0).unwrap(),
    ];
    for (k, &(m, level, res)) in cases.iter().enumerate() {
        let env = test_sky(res);
        let chroma = MapChroma::new(&env);
        // The sun's texels take their own colour from 128² maps on.
        assert_eq!(
            !chroma.peaks().is_empty(),
            res >= 1 << MIN_PEAK_DEPTH,
            "{res}"
        );
        for (i, mat) in materials.iter().enumerate() {
            let (n, wo) = frame();
            let product = ProductDistribution::new(&env, mat, n, wo, level).unwrap();
            let tables = ControlTables::new(&product, &chroma, m);
            for seed in 0..4u64 {
                let bits = random_bits(m, 100 * k as u64 + 10 * i as u64 + seed);
                let j = tables.record_integral(bits.view(), &product, &env);
                let r = tables.region_level();
                assert_eq!(r, region_level(m, level, res.trailing_zeros()));
                let (total, lum, expect) = brute_force(&env, &chroma, r, &product, &bits);
                assert!(close(tables.total(), total, 1e-9));
                assert!((tables.total_luminance() / lum - 1.0).abs() < 1e-9);
                assert!(
                    close(j, expect, 1e-9),
                    "M={m} P={level} res={res}: {j:?} vs {expect:?}"
                );
            }
            // Several records at once: shared, partial, full and empty words.
            let mut maps: Vec<VisibilityBits> = (0..3)
                .map(|s| random_bits(m, 1000 + 10 * k as u64 + s))
                .collect();
            maps.push(maps[0].clone());
            maps.push(VisibilityBits::from_fn(m, |_| true).unwrap());
            let beta = [0.3f32, 0.1, 0.25, 0.15, 0.2];
            let views: Vec<_> = maps.iter().map(|b| b.view()).collect();
            let together = tables.interpolated_integral(&views, &beta, &product, &env);
            let separate = maps.iter().zip(beta).fold([0.0; 3], |acc, (b, w)| {
                let j = tables.record_integral(b.view(), &product, &env);
                std::array::from_fn(|c| acc[c] + w as f64 * j[c])
            });
            assert!(
                close(together, separate, 1e-12),
                "{together:?} vs {separate:?}"
            );
            assert_eq!(
                tables.interpolated_integral(&[], &[], &product, &env),
                [0.0; 3]
            );
            let all = VisibilityBits::from_fn(m, |_| true).unwrap();
            let none = VisibilityBits::from_fn(m, |_| false).unwrap();
            assert!(close(
                tables.record_integral(all.view(), &product, &env),
                tables.total(),
                1e-12
            ));
            assert_eq!(
                tables.record_integral(none.view(), &product, &env),
                [0.0; 3]
            );
            // The whole-sphere integral of L B~ is L_ns in RGB: its luminance is the
            // product's normalisation times a texel's solid angle, and the regions'
            // colours keep it (each has luminance 1).
            let lum: f64 = tables
                .total()
                .iter()
                .zip(crate::lights::envmap::LUMINANCE)
                .map(|(a, b)| a * b)
                .sum();
            let l_ns = product.normalization() * texel_solid_angle(res);
            assert!((lum / l_ns - 1.0).abs() < 1e-9, "{lum} vs {l_ns}");
            assert!((tables.total_luminance() / l_ns - 1.0).abs() < 1e-9);
            // In RGB the total is the exact ∫ L_c B~ when the regions are no coarser
            // than the cells' colours vary: here, within 20% of it.
            let exact = exact_rgb(&env, &product);
            assert!(close(tables.total(), exact, 0.2), "{exact:?}");
        }
    }
}

/// `∫ L_c B~ dω` per channel over the product's cells and the map's texels.
fn exact_rgb(env: &EnvMap, product: &ProductDistribution) -> [f64; 3] {
    let e = env.resolution().trailing_zeros();
    let p = product.level();
    let f = e.max(p);
    let side = 1u32 << f;
    let omega = texel_solid_angle(side);
    let mut rgb = [0.0f64; 3];
    for code in 0..side * side {
        let t = morton_decode(code);
        let l = env.texels()[((t.y >> (f - e)) * env.resolution() + (t.x >> (f - e))) as usize];
        let cell = morton_encode(t.x >> (f - p), t.y >> (f - p));
        let b = product.bsdf_cells()[cell as usize] as f64 * omega;
        for c in 0..3 {
            rgb[c] += l[c] as f64 * b;
        }
    }
    rgb
}

/// A cache with three records of chosen bits around the origin, and the lookup there.
pub(crate) fn cache_with(bits: &[VisibilityBits]) -> (VisibilityCache, Lookup) {
    let m = bits[0].m();
    let cache = VisibilityCache::new(CacheParams::MEDIUM.with_log2_resolution(m)).unwrap();
    for (i, b) in bits.iter().enumerate() {
        let record = Record {
            position: Vec3::new(0.01 * (i as f32 + 1.0), 0.0, 0.0),
            normal: Vec3::Y,
            bits: b.clone(),
            ambient_occlusion: 0.5,
            nearest_hit_distance: 1.0,
            misses: 0,
            uses: 0,
            last_frame: 0,
        };
        cache.insert_record(&record).unwrap();
    }
    let lookup = cache.lookup(Vec3::ZERO, Vec3::Y, 1.0);
    assert_eq!(lookup.neighbours().len(), bits.len());
    (cache, lookup)
}

#[test]
fn cell_visibility_is_the_weighted_share_of_visible_record_texels() {
    for m in [2u32, 3, 5, 6, 7] {
        let bits: Vec<_> = (0..3).map(|i| random_bits(m, 11 + i)).collect();
        let (cache, lookup) = cache_with(&bits);
        let state = cache.read();
        let interp = Interpolant::new(&state, &lookup, None);
        for level in [4u32, 5, 6] {
            let got = interp.cell_visibility(&state, level);
            for (c, &v) in got.iter().enumerate() {
                let mut want = 0.0f64;
                for (&id, &beta) in interp.ids().iter().zip(interp.betas()) {
                    let b = state.store().bits(id as usize);
                    let share = if m >= level {
                        let k = 1usize << (2 * (m - level));
                        (0..k).filter(|t| b.get(c * k + t)).count() as f64 / k as f64
                    } else {
                        b.get(c >> (2 * (level - m))) as u32 as f64
                    };
                    want += beta as f64 * share;
                }
                assert!(
                    (v as f64 - want.min(1.0)).abs() < 1e-5,
                    "m {m} level {level}"
                );
            }
        }
    }
}

#[test]
fn record_averages_are_each_records_weighted_share_and_blend_to_v_tilde() {
    // Scattered bits, and long runs (whole words visible or blocked, as real records
    // are) at odd offsets.
    let runs = |m: u32, seed: u64| {
        VisibilityBits::from_fn(m, move |z| {
            !((z as u64 + 37 * seed) / 150).is_multiple_of(3)
        })
        .unwrap()
    };
    for (m, scattered) in [(2u32, true), (3, true), (5, true), (6, true), (6, false)] {
        let bits: Vec<_> = (0..3)
            .map(|i| {
                if scattered {
                    random_bits(m, 21 + i)
                } else {
                    runs(m, i)
                }
            })
            .collect();
        let (cache, lookup) = cache_with(&bits);
        let state = cache.read();
        let interp = Interpolant::new(&state, &lookup, None);
        for level in [4u32, 5] {
            let cells = 1usize << (2 * level);
            let weights: Vec<f64> = (0..cells).map(|c| 1.0 + (c % 7) as f64).collect();
            let total: f64 = weights.iter().sum();
            let pyramid = QuadPyramid::from_morton_unchecked(weights.clone());
            let got = interp.record_averages(&state, &pyramid);
            assert_eq!(got.len(), interp.ids().len());
            let mut blended = 0.0;
            for ((&(beta, avg), &id), &b) in got.iter().zip(interp.ids()).zip(interp.betas()) {
                assert_eq!(beta, b);
                let rec = state.store().bits(id as usize);
                let want: f64 = (0..cells)
                    .map(|c| {
                        let share = if m >= level {
                            let k = 1usize << (2 * (m - level));
                            (0..k).filter(|t| rec.get(c * k + t)).count() as f64 / k as f64
                        } else {
                            rec.get(c >> (2 * (level - m))) as u32 as f64
                        };
                        weights[c] * share
                    })
                    .sum::<f64>()
                    / total;
                assert!(
                    (avg - want).abs() < 1e-6,
                    "m {m} level {level}: {avg} {want}"
                );
                blended += beta as f64 * avg;
            }
            // With β summing to one no cell is clamped: the records' blend is Ṽ's.
            let v: f64 = interp
                .cell_visibility(&state, level)
                .iter()
                .zip(&weights)
                .map(|(&v, &w)| w * v as f64)
                .sum::<f64>()
                / total;
            assert!(
                (blended - v).abs() < 1e-5,
                "m {m} level {level}: {blended} {v}"
            );
        }
    }
}

#[test]
fn the_sun_replaces_the_records_on_the_peaks_exactly() {
    // J with the point's own sun visibility on the peaks against a plain sum over the
    // finest grid, each texel's Ṽ the sun's where it is a peak and the records' blend
    // elsewhere; records coarser and finer than the cells.
    let env = test_sky(256);
    let chroma = MapChroma::new(&env);
    let sun = chroma.sun().expect("the test sky's peaks are one sun");
    let sky_sun = Vec3::new(0.4, 0.6, -0.5).normalize();
    assert!(sun.dot(sky_sun) > 1f32.to_radians().cos(), "{sun}");
    let mat = Material::phong([0.3; 3], [0.5; 3], 20.0).unwrap();
    let (n, wo) = frame();
    let product = ProductDistribution::new(&env, &mat, n, wo, 5).unwrap();
    let e = env.resolution().trailing_zeros();
    for m in [3u32, 5, 6] {
        let bits: Vec<_> = (0..3).map(|i| random_bits(m, 31 + i)).collect();
        let (cache, lookup) = cache_with(&bits);
        let state = cache.read();
        let tables = ControlTables::new(&product, &chroma, m);
        let interp = Interpolant::new(&state, &lookup, Some((&tables, &product, &env)));
        assert_eq!(interp.sun, None);
        let p = product.level();
        let f = e.max(p).max(m);
        let side = 1u32 << f;
        let omega = texel_solid_angle(side);
        for v_sun in [0.0, 1.0] {
            let sunny = interp.with_sun(&state, &tables, &product, v_sun);
            assert_eq!(sunny.sun, Some(v_sun));
            let mut want = [0.0f64; 3];
            for code in 0..side * side {
                let t = morton_decode(code);
                let map_code = code >> (2 * (f - e));
                let l = env.texel(morton_decode(map_code));
                let cell = morton_encode(t.x >> (f - p), t.y >> (f - p));
                let b = product.bsdf_cells()[cell as usize] as f64 * omega;
                let y = crate::lights::envmap::luminance(l.into()) * b;
                let kappa = chroma.control_colour(map_code, interp.region_level);
                let z = morton_encode(t.x >> (f - m), t.y >> (f - m)) as usize;
                let v = match chroma.peak_index(map_code) {
                    Some(_) => v_sun,
                    None => interp
                        .ids()
                        .iter()
                        .zip(interp.betas())
                        .filter(|(&id, _)| state.store().bits(id as usize).get(z))
                        .map(|(_, &b)| b as f64)
                        .sum(),
                };
                want = std::array::from_fn(|c| want[c] + kappa[c] * y * v);
            }
            assert!(
                close(sunny.j, want, 1e-9),
                "M = {m}, sun {v_sun}: {:?} vs {want:?}",
                sunny.j
            );
        }
    }
    // Without records nothing changes: J stays 0 and the samples' Ṽ too.
    let empty = Interpolant::EMPTY;
    let state = cache_with(&[random_bits(5, 1)]).0;
    let tables = ControlTables::new(&product, &chroma, 5);
    let same = empty.with_sun(&state.read(), &tables, &product, 1.0);
    assert_eq!((same.j, same.sun), ([0.0; 3], None));
}
