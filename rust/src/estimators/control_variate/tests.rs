use super::*;
use glam::Vec3;

use crate::bsdf::Material;
use crate::lights::envmap::chroma::tests::test_sky;
use crate::moments::Moments;
use crate::sampling::octahedral::{morton_encode, square_to_sphere};
use crate::sampling::rng::SampleRng;
use crate::visibility::cache::interpolant::tests::{cache_with, frame, random_bits};
use crate::visibility::cache::interpolant::ControlTables;

#[test]
fn the_control_variate_averages_to_j_under_the_mixture() {
    // E[g/p] = J for draws of the renderer's mixture (guided by these records, built
    // for the product's point but used at another: a jittered sample's hit). The
    // material is blue paint under a grey coat, so the lobes' part counts too: E[g_d/p]
    // = J_d and E[W] = 0 per channel, with the diffuse part's cells never above the
    // product's; lobes of nearly one colour are not told apart.
    use crate::estimators::direct::{Mixture, ShadingPoint, Techniques};
    // 256²: the sun's texels are peaks with their own colour.
    let env = test_sky(256);
    assert!(!MapChroma::new(&env).peaks().is_empty());
    let chroma = MapChroma::new(&env);
    let mat = Material::phong([0.05, 0.1, 0.45], [0.3; 3], 20.0).unwrap();
    for (kd, ks) in [([0.2; 3], [0.4; 3]), ([0.4, 0.4, 0.42], [0.45; 3])] {
        let near_grey = Material::phong(kd, ks, 30.0).unwrap();
        assert!(near_grey.lobe_channel_ratios().is_none());
    }
    let (n, wo) = frame();
    let bits: Vec<_> = (0..3).map(|i| random_bits(5, 17 + i)).collect();
    let (cache, lookup) = cache_with(&bits);
    let state = cache.read();
    let product = ProductDistribution::new(&env, &mat, n, wo, 5).unwrap();
    let part = product.lobe_part(&env, &mat.diffuse_lobe(), n, wo).unwrap();
    let cells = part.bsdf_cells().iter().zip(product.bsdf_cells());
    assert!(cells.into_iter().all(|(d, b)| d <= b));
    let tables = ControlTables::new(&product, &chroma, 5);
    let interp = Interpolant::new(&state, &lookup, Some((&tables, &product, &env)));
    let guided = product.guided(interp.cell_visibility(&state, 5)).unwrap();
    let anchor = ShadingPoint {
        origin: Vec3::ZERO,
        normal: n,
        wo,
        material: mat,
    };
    let lobes =
        LobeControl::new(&product, &anchor, (&state, &lookup), &chroma, &env, None).unwrap();
    let sp = ShadingPoint {
        normal: Vec3::new(0.3, 0.9, -0.2).normalize(),
        ..anchor
    };
    let mixture = Mixture::new(
        &env,
        &sp,
        Some(&product),
        Some(&guided),
        &Techniques::CONTROL_VARIATE,
    );
    let (mut sums, mut part_sums, mut w_sums) = <[[Moments; 3]; 3]>::default().into();
    for i in 0..300_000u64 {
        let rng = SampleRng::new(5, i, 0);
        let (g, gd) = match mixture.sample(rng.get2(0), rng.get(2)) {
            Some(d) => {
                let g = control_sample(&state, &interp, &chroma, d.square)
                    .value
                    .map(|v| v * d.product_pdf / d.pdf);
                (g, g.map(|v| v * lobes.share(d.square)))
            }
            None => ([0.0; 3], [0.0; 3]),
        };
        Moments::push_each(&mut sums, g);
        Moments::push_each(&mut part_sums, gd);
        Moments::push_each(&mut w_sums, lobes.w(g, gd, &interp.j));
    }
    assert_mean_within_4_se(&sums, interp.j, "g/p");
    assert_mean_within_4_se(&part_sums, lobes.j, "g_d/p");
    assert_mean_within_4_se(&w_sums, [0.0; 3], "W");
    assert!((0..3).all(|c| lobes.j[c] > 0.0 && lobes.j[c] < interp.j[c]));
}

/// The mean of the samples `sums` holds lies within 4 of their standard errors of
/// `want`, per channel.
fn assert_mean_within_4_se(sums: &[Moments; 3], want: [f64; 3], what: &str) {
    for (c, m) in sums.iter().enumerate() {
        let z = (m.mean - want[c]) / m.variance_of_mean().sqrt();
        assert!(
            z.abs() < 4.0,
            "{what}, channel {c}: {} vs {} ({z:.2} SE)",
            m.mean,
            want[c]
        );
    }
}

#[test]
fn the_control_variate_averages_to_j() {
    // E[g/p] = J: product samples of a sky against three random records. The mean of
    // g/p over N samples must lie within 4 standard errors (from the same samples).
    // 256²: the sun's texels are peaks with their own colour.
    let env = test_sky(256);
    let chroma = MapChroma::new(&env);
    let mat = Material::phong([0.3; 3], [0.5; 3], 20.0).unwrap();
    let (n, wo) = frame();
    for m in [3u32, 5, 6] {
        let bits: Vec<_> = (0..3).map(|i| random_bits(m, 7 + i)).collect();
        let (cache, lookup) = cache_with(&bits);
        let state = cache.read();
        let product = ProductDistribution::new(&env, &mat, n, wo, 5).unwrap();
        let tables = ControlTables::new(&product, &chroma, m);
        let interp = Interpolant::new(&state, &lookup, Some((&tables, &product, &env)));
        // g/p of 200k product samples of seed `seed`.
        let sample_sums = |interp: &Interpolant, seed: u64| {
            let mut sums = [Moments::default(); 3];
            for i in 0..200_000u64 {
                let rng = SampleRng::new(seed, i, 0);
                let u = DVec2::new(rng.get(0) as f64, rng.get(1) as f64);
                let s = product.sample_point(&env, u);
                let g = control_sample(&state, interp, &chroma, s.square);
                Moments::push_each(&mut sums, g.value);
            }
            sums
        };
        let sums = sample_sums(&interp, 3);
        assert_mean_within_4_se(&sums, interp.j, &format!("g/p at M = {m}"));
        // The same with the point's sun visibility on the peaks.
        for v_sun in [0.0, 1.0] {
            let sunny = interp.with_sun(&state, &tables, &product, v_sun);
            let what = format!("g/p at M = {m}, sun {v_sun}");
            assert_mean_within_4_se(&sample_sums(&sunny, 5), sunny.j, &what);
        }
        // Ṽ at a sample equals Σ β_i V_i of the records' bits at its texel.
        let p = DVec2::new(0.3, 0.7);
        let z = record_texel_code(p, m) as usize;
        let expect: f64 = interp
            .ids()
            .iter()
            .zip(interp.betas())
            .map(|(&id, &b)| {
                if state.store().bits(id as usize).get(z) {
                    b as f64
                } else {
                    0.0
                }
            })
            .sum();
        assert!((interp.eval(&state, p).0 - expect).abs() < 1e-12);
        // The texel of a square point is the texel of its direction.
        let d = square_to_sphere(p.as_vec2());
        let t = crate::sampling::octahedral::texel_of(d, 1 << m);
        assert_eq!(morton_encode(t.x, t.y) as usize, z);
    }
}
