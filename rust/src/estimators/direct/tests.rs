use super::*;
use crate::lights::procedural::sky;
use crate::sampling::chi2::{chi2_sphere, Chi2Params};
use crate::sampling::octahedral::square_to_sphere;
use crate::sampling::octahedral::texel_solid_angle;

fn test_sky(resolution: u32) -> EnvMap {
    let sun = Vec3::new(0.4, 0.6, -0.5).normalize();
    sky(
        sun,
        [2e3; 3],
        4.0,
        [0.2, 0.3, 0.6],
        [0.8, 0.8, 0.9],
        resolution,
    )
    .unwrap()
}

fn frames() -> [(Vec3, Vec3); 3] {
    [
        (Vec3::Y, Vec3::new(0.3, 0.8, 0.2).normalize()),
        (
            Vec3::new(0.2, 0.9, -0.3).normalize(),
            Vec3::new(-0.5, 0.4, 0.6).normalize(),
        ),
        // Grazing view on a tilted surface.
        (
            Vec3::new(0.6, 0.8, 0.0),
            Vec3::new(-0.79, 0.6, 0.1).normalize(),
        ),
    ]
}

fn uniform(i: u64) -> DVec2 {
    let r = SampleRng::new(17, i, 0);
    DVec2::new(r.get(0) as f64, r.get(1) as f64)
}

#[test]
fn product_samples_follow_the_product_pdf() {
    let env = test_sky(64);
    let materials = [
        Material::lambert([0.8; 3]).unwrap(),
        Material::phong([0.2; 3], [0.7; 3], 30.0).unwrap(),
    ];
    for m in materials {
        for (n, wo) in frames() {
            let product = ProductDistribution::new(&env, &m, n, wo, 5).unwrap();
            let samples = (0..300_000).map(|i| {
                let (dir, texel, pdf) = product.sample(&env, uniform(i));
                assert_eq!(pdf, product.texel_pdf(&env, texel));
                assert!(pdf > 0.0);
                Some(dir)
            });
            // Bins are the map's texels, so the piecewise-constant pdf integrates exactly.
            let params = Chi2Params::with_resolution(64).with_subdivisions(1);
            let outcome = chi2_sphere(samples, |d| product.pdf(&env, d), &params);
            assert!(outcome.passed, "{m:?} {n} {wo}: {outcome:?}");
            assert!(
                (outcome.integral - 1.0).abs() < 1e-9,
                "{}",
                outcome.integral
            );
        }
    }
}

/// On a discrete domain with known densities, the weights learnt from draws of the
/// default mixture come within 10% of the least second moment `Σ f² / q_c` over a grid
/// of weights, far below the default's; zero shares stay zero and the floor holds;
/// draws that saw no light leave the weights as they were.
#[test]
fn learnt_weights_approach_the_least_second_moment() {
    let n = 64usize;
    // Product density peaked on a "sun" the surface cannot see (f = 0 there); the
    // light the surface gets is spread like the BSDF's density.
    let norm = |v: Vec<f64>| {
        let s: f64 = v.iter().sum();
        v.into_iter().map(|x| x / s).collect::<Vec<f64>>()
    };
    let p_prod = norm((0..n).map(|i| if i < 4 { 50.0 } else { 1.0 }).collect());
    let p_bsdf = norm((0..n).map(|i| 1.0 + (i % 8) as f64).collect());
    let p_env = norm(vec![1.0; n]);
    let f: Vec<f64> = (0..n)
        .map(|i| if i < 4 { 0.0 } else { p_bsdf[i] })
        .collect();
    let pdfs = |i: usize| [p_prod[i], 0.0, p_bsdf[i], p_env[i]];
    let second = |c: [f64; 4]| -> f64 {
        (0..n)
            .map(|i| {
                let q: f64 = c.iter().zip(pdfs(i)).map(|(c, p)| c * p).sum();
                if f[i] > 0.0 {
                    f[i] * f[i] / q
                } else {
                    0.0
                }
            })
            .sum()
    };
    let start = Techniques::PRODUCT;
    let c0 = start.probabilities(true, false, true);
    // Draws from the default mixture by inversion of its discrete cdf.
    let q0: Vec<f64> = (0..n)
        .map(|i| c0.iter().zip(pdfs(i)).map(|(c, p)| c * p).sum())
        .collect();
    let draws: Vec<(f64, f64, [f64; 4], f64)> = (0..20_000u64)
        .map(|k| {
            let u = SampleRng::new(5, k, 0).get(0) as f64;
            let mut acc = 0.0;
            let i = q0
                .iter()
                .position(|&q| {
                    acc += q;
                    u < acc
                })
                .unwrap_or(n - 1);
            (1.0, f[i], pdfs(i), q0[i])
        })
        .collect();
    let learnt = start.learnt(&draws);
    let c = learnt.probabilities(true, false, true);
    assert_eq!(c[1], 0.0);
    assert!(c
        .iter()
        .enumerate()
        .all(|(t, &x)| t == 1 || x >= LEARN_FLOOR - 1e-6));
    let mut best = f64::INFINITY;
    for a in 1..20 {
        for b in 1..(20 - a) {
            let (pa, pb) = (a as f64 / 20.0, b as f64 / 20.0);
            best = best.min(second([pa, 0.0, pb, 1.0 - pa - pb]));
        }
    }
    let (got, was) = (second(c), second(c0));
    assert!(
        got <= 1.1 * best,
        "learnt {c:?}: {got} against the best {best}"
    );
    assert!(got < 0.5 * was, "learnt {got}, default {was}");
    let dark: Vec<_> = draws.iter().map(|&(w, _, p, q)| (w, 0.0, p, q)).collect();
    assert_eq!(start.learnt(&dark), start);
}

#[test]
fn product_pdf_is_positive_wherever_the_integrand_is() {
    // Conservative B~ times a map that is positive everywhere: every direction where
    // f cos L > 0 has p > 0, including the grazing horizon and a 1e4 lobe.
    let env = test_sky(128);
    let m = Material::phong([0.0; 3], [1.0; 3], 1e4).unwrap();
    for (n, wo) in frames() {
        let product = ProductDistribution::new(&env, &m, n, wo, 5).unwrap();
        let res = 512;
        for y in 0..res {
            for x in 0..res {
                let d = square_to_sphere((Vec2::new(x as f32, y as f32) + 0.5) / res as f32);
                let integrand = m.eval(n, wo, d).x * n.dot(d).max(0.0);
                if integrand > 0.0 {
                    assert!(product.pdf(&env, d) > 0.0, "{n} {wo} {d}");
                }
            }
        }
    }
}

#[test]
fn a_products_cells_give_the_pdf_under_another_map() {
    let (env, other) = (test_sky(64), test_sky(64).rotated(70.0));
    let m = Material::phong([0.2; 3], [0.7; 3], 30.0).unwrap();
    for (n, wo) in frames() {
        let here = ProductDistribution::new(&env, &m, n, wo, 5).unwrap();
        let there = ProductDistribution::new(&other, &m, n, wo, 5).unwrap();
        for i in 0..10_000 {
            let d = square_to_sphere(uniform(i).as_vec2());
            let p = here.pdf_with_map(&other, there.normalization(), d);
            assert_eq!(p, there.pdf(&other, d), "{n} {wo} {d}");
        }
    }
}

#[test]
fn black_maps_and_black_materials_have_no_product() {
    let black = EnvMap::constant([0.0; 3], 32).unwrap();
    let m = Material::lambert([0.5; 3]).unwrap();
    assert!(ProductDistribution::new(&black, &m, Vec3::Y, Vec3::Y, 5).is_none());
    let env = test_sky(32);
    let dark = Material::lambert([0.0; 3]).unwrap();
    assert!(ProductDistribution::new(&env, &dark, Vec3::Y, Vec3::Y, 5).is_none());
    // Level capped by the map's depth: a 4x4 map has 16 cells at most.
    let tiny = test_sky(4);
    let p = ProductDistribution::new(&tiny, &m, Vec3::Y, Vec3::Y, 5).unwrap();
    let total: f64 = (0..16)
        .map(|i| p.texel_pdf(&tiny, UVec2::new(i % 4, i / 4)) * texel_solid_angle(4))
        .sum();
    assert!((total - 1.0).abs() < 1e-9);
}

fn point(normal: Vec3, wo: Vec3, material: Material) -> ShadingPoint {
    ShadingPoint {
        origin: Vec3::ZERO,
        normal,
        wo,
        material,
    }
}

/// A visibility estimate per level-5 cell: the cells whose centre lies on the sun's
/// side of a plane see, the others do not (a record that calls half the sky occluded).
fn half_visible() -> Vec<f32> {
    (0..1024u32)
        .map(|c| {
            let t = crate::sampling::octahedral::morton_decode(c);
            let d = square_to_sphere((t.as_vec2() + 0.5) / 32.0);
            if d.dot(Vec3::new(0.4, 0.6, -0.5)) > 0.2 {
                1.0
            } else {
                0.0
            }
        })
        .collect()
}

#[test]
fn mixture_samples_follow_the_mixture_pdf() {
    // The product is built at one point and the mixture used at another (a jittered
    // sample's hit), for every combination of techniques.
    let env = test_sky(64);
    let materials = [
        Material::lambert([0.8; 3]).unwrap(),
        Material::phong([0.2; 3], [0.7; 3], 30.0).unwrap(),
    ];
    let weights = [
        Techniques::PRODUCT,
        Techniques::CONTROL_VARIATE,
        Techniques::new(0.0, 1.0, 0.0, 0.0),
        Techniques::new(0.0, 0.0, 1.0, 1.0),
        Techniques::new(0.2, 0.2, 0.3, 0.3),
    ];
    let [(n0, wo0), (n1, wo1), _] = frames();
    for m in materials {
        let product = ProductDistribution::new(&env, &m, n0, wo0, 5).unwrap();
        let guided = product.guided(half_visible()).unwrap();
        let sp = point(n1, wo1, m);
        for t in weights {
            let mix = Mixture::new(&env, &sp, Some(&product), Some(&guided), &t);
            // A direction's own texel gives the draw's density but where the f32 round
            // trip square -> sphere -> square put it across a texel border (about one
            // draw in ten thousand; the estimators read the drawn texel, not this).
            let mut crossed = 0;
            let samples: Vec<Option<Vec3>> = (0..300_000)
                .map(|i| {
                    let r = SampleRng::new(23, i, 0);
                    mix.sample(r.get2(0), r.get(2)).map(|d| {
                        crossed += ((d.pdf - mix.pdf(d.direction)).abs() > 1e-9 * d.pdf) as u32;
                        d.direction
                    })
                })
                .collect();
            assert!(
                crossed < 300,
                "{m:?} {t:?}: {crossed} draws across a border"
            );
            // The BSDF's density varies inside a bin: integrate it on a fine sub-grid.
            let params = Chi2Params::with_resolution(64).with_subdivisions(8);
            let outcome = chi2_sphere(samples, |d| mix.pdf(d), &params);
            assert!(outcome.passed, "{m:?} {t:?}: {outcome:?}");
        }
    }
}

#[test]
fn the_mixture_estimates_the_unoccluded_integral_without_bias() {
    // E[f L cos / p] over the mixture equals ∫ f L cos dω (dense quadrature over the
    // map's texels), for a product built at another point and records that call most
    // of the sky occluded, and for weights without a product.
    let env = test_sky(64);
    let m = Material::phong([0.3; 3], [0.5; 3], 20.0).unwrap();
    let [(n0, wo0), (n1, wo1), _] = frames();
    let product = ProductDistribution::new(&env, &m, n0, wo0, 5).unwrap();
    let guided = product.guided(half_visible()).unwrap();
    let sp = point(n1, wo1, m);
    let res = 512u32;
    let omega = texel_solid_angle(res);
    let mut exact = 0.0f64;
    for y in 0..res {
        for x in 0..res {
            let d = square_to_sphere((Vec2::new(x as f32, y as f32) + 0.5) / res as f32);
            let cos = n1.dot(d).max(0.0) as f64;
            exact += (m.eval(n1, wo1, d) * env.eval(d)).x as f64 * cos * omega;
        }
    }
    for t in [
        Techniques::CONTROL_VARIATE,
        Techniques::new(0.0, 0.0, 1.0, 1.0),
    ] {
        let mix = Mixture::new(&env, &sp, Some(&product), Some(&guided), &t);
        let n = 400_000u64;
        let (mut sum, mut sum2) = (0.0f64, 0.0f64);
        for i in 0..n {
            let r = SampleRng::new(29, i, 0);
            if let Some(d) = mix.sample(r.get2(0), r.get(2)) {
                let cos = n1.dot(d.direction).max(0.0) as f64;
                let f = m.eval(n1, wo1, d.direction).x as f64;
                let v = f * env.texel(d.texel).x as f64 * cos / d.pdf;
                sum += v;
                sum2 += v * v;
            }
        }
        let mean = sum / n as f64;
        let se = ((sum2 / n as f64 - mean * mean) / (n - 1) as f64).sqrt();
        // The quadrature's own error (texels at 4x the map's resolution) is far smaller.
        assert!(
            (mean - exact).abs() < 4.0 * se,
            "{t:?}: {mean} vs {exact} (SE {se})"
        );
    }
}

#[test]
fn guided_sampling_prefers_what_the_records_see() {
    let env = test_sky(64);
    let m = Material::lambert([0.8; 3]).unwrap();
    let (n, wo) = frames()[0];
    let product = ProductDistribution::new(&env, &m, n, wo, 5).unwrap();
    let vis = half_visible();
    let guided = product.guided(vis.clone()).unwrap();
    for i in 0..10_000 {
        let s = guided.sample_point(&product, &env, uniform(i));
        assert_eq!(vis[product.cell_of(&env, s.texel)], 1.0);
        let ratio = guided.ratio(product.cell_of(&env, s.texel));
        assert!((s.pdf - product.texel_pdf(&env, s.texel) * ratio).abs() <= 1e-12 * s.pdf);
    }
    // Records that see nothing guide nothing.
    assert!(product.guided(vec![0.0; 1024]).is_none());
}

#[test]
fn techniques_are_picked_by_interval_and_rescaled() {
    let c = [0.5, 0.0, 0.25, 0.25];
    assert_eq!(pick_technique(0.0, &c), (0, 0.0));
    assert_eq!(pick_technique(0.25, &c), (0, 0.5));
    assert_eq!(pick_technique(0.5, &c), (2, 0.0));
    assert_eq!(pick_technique(0.875, &c), (3, 0.5));
    // Past the end by rounding: the last technique with a share.
    let (t, u) = pick_technique(1.0, &[0.3, 0.0, 0.7, 0.0]);
    assert!(t == 2 && u < 1.0);
    // The guided share falls to the product without records; weights are checked.
    let p = Techniques::CONTROL_VARIATE.probabilities(true, false, true);
    assert_eq!(p, Techniques::PRODUCT.probabilities(true, false, true));
    assert_eq!(
        Techniques::PRODUCT.probabilities(false, false, false),
        [0.0, 0.0, 1.0, 0.0]
    );
    assert!(Techniques::PRODUCT.validate(true).is_ok());
    assert!(Techniques::PRODUCT_ONLY.validate(false).is_ok());
    assert!(Techniques::PRODUCT_ONLY.validate(true).is_err());
    assert!(Techniques::new(-1.0, 0.0, 1.0, 0.0)
        .validate(false)
        .is_err());
    assert!(Techniques::new(f32::NAN, 0.0, 1.0, 0.0)
        .validate(false)
        .is_err());
    assert!(Techniques::new(0.0, 0.0, 0.0, 0.0).validate(false).is_err());
    let w = Techniques::CONTROL_VARIATE.without_product();
    assert_eq!((w.product, w.guided), (0.0, 0.0));
    assert!((w.bsdf + w.env - 1.0).abs() < 1e-6);
}

#[test]
fn power_heuristic_handles_zero_and_infinite_densities() {
    assert_eq!(power_heuristic(0.0, 0.0), 0.0);
    assert_eq!(power_heuristic(f64::INFINITY, 1.0), 1.0);
    assert_eq!(power_heuristic(1.0, 1.0), 0.5);
    assert_eq!(power_heuristic(1.0, 0.0), 1.0);
}
