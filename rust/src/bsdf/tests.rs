#![allow(clippy::needless_range_loop)]

use super::cells::{angle_between, border_samples, fast_exp2, fast_log2};
use super::*;
use crate::sampling::chi2::{chi2_sphere, Chi2Params};
use crate::sampling::octahedral::{
    morton_decode, morton_encode, sphere_to_square, square_to_sphere, texel_of,
};
use crate::sampling::rng::{hash4, to_unit_f32};
use glam::UVec2;
use rayon::prelude::*;

#[test]
fn validation_names_the_parameter() {
    assert!(Material::lambert([0.5, 0.5, 0.5]).is_ok());
    let e = Material::lambert([1.5, 0.0, 0.0]).unwrap_err().to_string();
    assert!(e.starts_with("albedo"), "{e}");
    let e = Material::phong([0.6; 3], [0.6; 3], 10.0)
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("ks"), "{e}");
    let e = Material::phong([0.1; 3], [0.1; 3], 0.5)
        .unwrap_err()
        .to_string();
    assert!(e.starts_with("exponent"), "{e}");
    assert!(Material::phong([0.1; 3], [0.1; 3], f32::NAN).is_err());
    assert!(Material::phong([0.1; 3], [0.9; 3], 1e4).is_ok());
}

fn rand_dir(seed: u64, i: u64) -> Vec3 {
    let u = to_unit_f32(hash4(seed, i, 0, 0));
    let v = to_unit_f32(hash4(seed, i, 0, 1));
    square_to_sphere(Vec2::new(u, v)).normalize()
}

/// A unit vector at angle `theta` from `n` (radians), in an arbitrary azimuth.
fn at_angle(n: Vec3, theta: f32, azimuth: f32) -> Vec3 {
    let (t, b) = n.any_orthonormal_pair();
    (n * theta.cos() + (t * azimuth.cos() + b * azimuth.sin()) * theta.sin()).normalize()
}

/// A normal that is not ±y, so horizon discontinuities do not run along bin diagonals.
fn test_normal() -> Vec3 {
    Vec3::new(0.3, 0.8, -0.5).normalize()
}

fn phong(e: f32) -> Material {
    Material::phong([0.3, 0.2, 0.1], [0.5, 0.6, 0.7], e).unwrap()
}

/// (name, wo) at normal, oblique (60°) and grazing (89°) incidence.
fn incidences(n: Vec3) -> [(&'static str, Vec3); 3] {
    [
        ("normal", n),
        ("oblique", at_angle(n, 60f32.to_radians(), 0.7)),
        ("grazing", at_angle(n, 89f32.to_radians(), 2.1)),
    ]
}

fn chi2_of(
    m: Material,
    n: Vec3,
    wo: Vec3,
    samples: u64,
    params: &Chi2Params,
) -> crate::sampling::chi2::Chi2Outcome {
    let draws = (0..samples).map(|i| {
        let rng = SampleRng::new(17, 3, i);
        m.sample(n, wo, rng.get(0), Vec2::from(rng.get2(1)))
    });
    chi2_sphere(draws, |wi| m.pdf(n, wo, wi), params)
}

#[test]
fn fast_exp2_and_log2_are_accurate() {
    for i in 0..10_000 {
        let x = -126.0 + 252.0 * i as f32 / 9999.0;
        let rel = (fast_exp2(x) as f64 / 2f64.powf(x as f64) - 1.0).abs();
        assert!(rel < 1e-6, "exp2({x}) rel error {rel}");
        let y = 1e-30f32 * 1.0173f32.powi(i % 4000);
        let abs = (fast_log2(y) as f64 - (y as f64).log2()).abs();
        assert!(
            abs < 2e-6 * (y as f64).log2().abs().max(1.0),
            "log2({y}) error {abs}"
        );
    }
}

#[test]
fn chi2_lambert_and_phong_low_exponents() {
    let n = test_normal();
    for m in [
        Material::lambert([0.8, 0.5, 0.2]).unwrap(),
        phong(1.0),
        phong(10.0),
    ] {
        for (name, wo) in incidences(n) {
            let out = chi2_of(m, n, wo, 200_000, &Chi2Params::with_resolution(32));
            assert!(out.passed, "{m:?} {name}: {out:?}");
        }
    }
}

#[test]
fn chi2_phong_100() {
    let n = test_normal();
    for (name, wo) in incidences(n) {
        let out = chi2_of(
            phong(100.0),
            n,
            wo,
            300_000,
            &Chi2Params::with_resolution(64),
        );
        assert!(out.passed, "{name}: {out:?}");
    }
}

/// The e = 1e4 lobe is ~0.01 rad wide, narrower than a bin of the default 32² grid
/// (0.11 rad): use 512² bins (0.007 rad) and a 12² midpoint grid per bin.
#[test]
fn chi2_phong_1e4() {
    let n = test_normal();
    let params = Chi2Params::with_resolution(512).with_subdivisions(12);
    for (name, wo) in incidences(n) {
        let out = chi2_of(phong(1e4), n, wo, 300_000, &params);
        assert!(out.passed, "{name}: {out:?}");
    }
}

#[test]
fn pure_specular_and_black_materials_are_consistent() {
    let n = test_normal();
    let (_, wo) = incidences(n)[1];
    let spec = Material::phong([0.0; 3], [1.0; 3], 30.0).unwrap();
    let out = chi2_of(spec, n, wo, 100_000, &Chi2Params::with_resolution(32));
    assert!(out.passed && out.rejected > 0, "{out:?}");
    let black = Material::phong([0.0; 3], [0.0; 3], 30.0).unwrap();
    let out = chi2_of(black, n, wo, 100_000, &Chi2Params::with_resolution(32));
    assert!(out.passed, "{out:?}");
    let mut cells = vec![1.0; 1024];
    black.product_cells(n, wo, 5, &mut cells);
    assert!(cells.iter().all(|&c| c == 0.0));
}

#[test]
fn below_the_surface_is_zero_and_nan_is_harmless() {
    let n = Vec3::Y;
    let up = Vec3::new(0.1, 0.9, 0.0).normalize();
    let down = Vec3::new(0.1, -0.9, 0.0).normalize();
    let tangent = Vec3::X;
    for m in [Material::DEFAULT, phong(50.0)] {
        for (wo, wi) in [
            (up, down),
            (down, up),
            (tangent, up),
            (up, tangent),
            (Vec3::NAN, up),
        ] {
            assert_eq!(m.eval(n, wo, wi), Vec3::ZERO);
            assert_eq!(m.pdf(n, wo, wi), 0.0);
        }
        assert_eq!(m.sample(n, down, 0.5, Vec2::splat(0.5)), None);
        assert_eq!(m.sample(n, Vec3::NAN, 0.5, Vec2::splat(0.5)), None);
        let mut cells = vec![1.0; 64];
        m.product_cells(n, down, 3, &mut cells);
        assert!(cells.iter().all(|&c| c == 0.0));
        m.product_cells(Vec3::NAN, up, 3, &mut cells);
        assert!(cells.iter().all(|&c| c == 0.0));
    }
    // Extreme sample coordinates stay finite.
    for u in [
        Vec2::ZERO,
        Vec2::new(0.0, 0.999_999_9),
        Vec2::splat(0.999_999_9),
    ] {
        for m in [Material::DEFAULT, phong(1e4)] {
            for uc in [0.0, 0.999_999_9] {
                if let Some(wi) = m.sample(n, up, uc, u) {
                    assert!(wi.is_finite() && (wi.length() - 1.0).abs() < 1e-5);
                }
            }
        }
    }
}

#[test]
fn reciprocity() {
    for m in [Material::DEFAULT, phong(1.0), phong(100.0), phong(1e4)] {
        for i in 0..10_000 {
            let n = rand_dir(1, i);
            let a = rand_dir(2, i);
            // Every tenth pair near the mirror configuration, where the lobe is large.
            let b = if i % 10 == 0 {
                let r = (2.0 * n.dot(a) * n - a).normalize();
                at_angle(r, 0.005, i as f32)
            } else {
                rand_dir(3, i)
            };
            let (fab, fba) = (m.eval(n, a, b), m.eval(n, b, a));
            // f32 inputs: cos α is known to ~1e-7, so the lobe to ~e · 1e-7 relative.
            let e = match m {
                Material::Phong { exponent, .. } => exponent,
                _ => 0.0,
            };
            let tol = (1e-5 + 2e-7 * e) * fab.max_element() + 1e-7;
            assert!(
                (fab - fba).abs().max_element() <= tol,
                "{m:?} {n} {a} {b}: {fab} vs {fba}"
            );
        }
    }
}

#[test]
fn energy_conservation_at_every_incidence() {
    let n = test_normal();
    let mats = [
        Material::lambert([1.0; 3]).unwrap(),
        Material::phong([0.5; 3], [0.5; 3], 1.0).unwrap(),
        Material::phong([0.0; 3], [1.0; 3], 1.0).unwrap(),
        Material::phong([0.2; 3], [0.8; 3], 10.0).unwrap(),
        Material::phong([0.0; 3], [1.0; 3], 100.0).unwrap(),
        Material::phong([0.1; 3], [0.9; 3], 1e4).unwrap(),
    ];
    for m in mats {
        for deg in [0.0f32, 30.0, 60.0, 80.0, 89.0, 89.9] {
            let wo = at_angle(n, deg.to_radians(), 0.3);
            let (mean, se) = m.directional_albedo(n, wo, 20_000, 5);
            for c in 0..3 {
                assert!(
                    mean[c] <= 1.0 + 4.0 * se[c] + 1e-9,
                    "{m:?} at {deg}°: {mean} ± {se}"
                );
            }
            if deg == 0.0 {
                // At normal incidence kd + ks = 1 reflects everything (the lobe lies above the surface).
                for c in 0..3 {
                    assert!(mean[c] > 0.99 - 4.0 * se[c], "{m:?}: {mean} ± {se}");
                }
            }
        }
    }
}

#[test]
fn lambert_albedo_is_the_albedo() {
    let m = Material::lambert([0.8, 0.5, 0.2]).unwrap();
    let n = test_normal();
    for (name, wo) in incidences(n) {
        // Importance sampling a Lambertian is exact (zero variance); also check uniform
        // hemisphere sampling, which has a proper standard error.
        let (mean, se) = m.directional_albedo(n, wo, 10_000, 9);
        assert!(
            (mean - DVec3::new(0.8, 0.5, 0.2)).abs().max_element() < 1e-5 + 4.0 * se.max_element(),
            "{name}: {mean}"
        );
        let k = 100_000u64;
        let (mut s, mut s2) = (0.0f64, 0.0f64);
        for i in 0..k {
            let d = rand_dir(21, i);
            let d = if d.dot(n) < 0.0 {
                d - 2.0 * d.dot(n) * n
            } else {
                d
            };
            let x = m.eval(n, wo, d).x as f64 * n.dot(d).max(0.0) as f64 * std::f64::consts::TAU;
            s += x;
            s2 += x * x;
        }
        let mean = s / k as f64;
        let se = ((s2 / k as f64 - mean * mean) / (k - 1) as f64).sqrt();
        assert!((mean - 0.8).abs() < 4.0 * se, "{name}: {mean} ± {se}");
    }
}

/// The cones contain their cells: a 4x denser border walk and a 64² interior grid of
/// every cell stay within the half-angle (which itself is within a few per cent of the
/// measured maximum, so it is not wastefully loose).
#[test]
fn cell_cones_contain_their_cells() {
    for level in [1, 3, 5, 7] {
        let t = CellCones::get(level);
        let res = 1u32 << level;
        let k = 4 * border_samples(level);
        let worst: Vec<(f64, f64)> = (0..res * res)
            .into_par_iter()
            .map(|code| {
                let cell = morton_decode(code);
                let c = DVec3::new(
                    t.cx[code as usize] as f64,
                    t.cy[code as usize] as f64,
                    t.cz[code as usize] as f64,
                );
                let a = t.half_angle[code as usize] as f64;
                let mut far = 0.0f64;
                let mut check = |p: Vec2| {
                    let d = square_to_sphere((cell.as_vec2() + p) / res as f32)
                        .as_dvec3()
                        .normalize();
                    far = far.max(angle_between(c, d));
                };
                for i in 0..=k {
                    let j = i as f32 / k as f32;
                    for p in [
                        Vec2::new(j, 0.0),
                        Vec2::new(1.0, j),
                        Vec2::new(j, 1.0),
                        Vec2::new(0.0, j),
                    ] {
                        check(p);
                    }
                }
                for i in 0..64 {
                    for j in 0..64 {
                        check((Vec2::new(i as f32, j as f32) + 0.5) / 64.0);
                    }
                }
                (far, a)
            })
            .collect();
        for (code, &(far, a)) in worst.iter().enumerate() {
            assert!(far <= a, "level {level} cell {code}: {far} > {a}");
            assert!(
                a <= far * 1.05 + 2e-5,
                "level {level} cell {code}: cone {a} loose vs {far}"
            );
        }
    }
}

fn lum_fcos(m: &Material, n: Vec3, wo: Vec3, wi: Vec3) -> f32 {
    let f = m.eval(n, wo, wi);
    luminance([f.x, f.y, f.z]) * n.dot(wi).max(0.0)
}

/// Points of cell `cell` of a `res` grid: a `sub²` interior grid and `sub` points per
/// edge (corners included).
fn cell_points(cell: UVec2, res: u32, sub: u32) -> impl Iterator<Item = Vec3> {
    let interior = (0..sub * sub)
        .map(move |i| (Vec2::new((i % sub) as f32, (i / sub) as f32) + 0.5) / sub as f32);
    let border = (0..=sub).flat_map(move |i| {
        let j = i as f32 / sub as f32;
        [
            Vec2::new(j, 0.0),
            Vec2::new(1.0, j),
            Vec2::new(j, 1.0),
            Vec2::new(0.0, j),
        ]
    });
    interior
        .chain(border)
        .map(move |p| square_to_sphere((cell.as_vec2() + p) / res as f32))
}

/// No cell where f cos θ > 0 anywhere gets B~ = 0: random normals, wo from normal to
/// 1e-3 above the horizon, Lambert and Phong up to e = 1e4, each cell sampled on a 16²
/// grid plus its border plus the exact mirror direction.
#[test]
fn product_cells_are_conservative() {
    let mats = [
        Material::lambert([0.5, 0.2, 0.9]).unwrap(),
        phong(10.0),
        Material::phong([0.0; 3], [1.0; 3], 100.0).unwrap(),
        Material::phong([0.0; 3], [1.0; 3], 1e4).unwrap(),
        phong(1e4),
    ];
    let cos_o = [1.0f32, 0.7, 0.2, 0.03, 1e-2, 1e-3];
    let cases: Vec<(usize, Vec3, Vec3, u32)> = (0..60u64)
        .map(|i| {
            let n = if i < 4 {
                [Vec3::Y, -Vec3::Y, Vec3::X, test_normal()][i as usize]
            } else {
                rand_dir(31, i)
            };
            let wo = at_angle(
                n,
                cos_o[(i % 6) as usize].acos(),
                6.0 * to_unit_f32(hash4(32, i, 0, 0)),
            );
            let level = [5, 5, 5, 3, 6][(i % 5) as usize];
            ((i % 5) as usize, n, wo, level)
        })
        .collect();
    let failures: Vec<String> = cases
        .par_iter()
        .flat_map_iter(|&(mi, n, wo, level)| {
            let m = mats[mi];
            let res = 1u32 << level;
            let mut cells = vec![0.0f32; 1 << (2 * level)];
            m.product_cells(n, wo, level, &mut cells);
            let mut bad = Vec::new();
            assert!(cells.iter().all(|c| c.is_finite() && *c >= 0.0));
            for code in 0..cells.len() as u32 {
                let cell = morton_decode(code);
                let positive = cell_points(cell, res, 16).any(|d| lum_fcos(&m, n, wo, d) > 0.0);
                if positive && cells[code as usize] <= 0.0 {
                    bad.push(format!("{m:?} n={n} wo={wo} level {level} cell {cell}"));
                }
            }
            let r = (2.0 * n.dot(wo) * n - wo).normalize();
            let rc = texel_of(r, res);
            if lum_fcos(&m, n, wo, r) > 0.0 && cells[morton_encode(rc.x, rc.y) as usize] <= 0.0 {
                bad.push(format!("mirror cell {rc} of {m:?} n={n} wo={wo}"));
            }
            bad
        })
        .collect();
    assert!(
        failures.is_empty(),
        "{} failures, e.g. {:?}",
        failures.len(),
        &failures[..failures.len().min(5)]
    );
}

/// B~ is zero for cells whose cone is below the horizon, and cells that lie entirely
/// below it (by dense sampling) but whose cone still reaches above get at most the
/// bound floor: together a negligible share of the total.
#[test]
fn product_cells_vanish_below_the_horizon() {
    for (i, m) in [Material::DEFAULT, phong(100.0), phong(1e4)]
        .into_iter()
        .enumerate()
    {
        for j in 0..10u64 {
            let n = rand_dir(41, j + 10 * i as u64);
            let wo = at_angle(n, [0.0f32, 1.0, 1.5, 1.569][(j % 4) as usize], j as f32);
            let t = CellCones::get(5);
            let mut cells = vec![0.0f32; 1024];
            m.product_cells(n, wo, 5, &mut cells);
            let total: f64 = cells.iter().map(|&c| c as f64).sum();
            let mut below_mass = 0.0f64;
            for k in 0..1024usize {
                let c = Vec3::new(t.cx[k], t.cy[k], t.cz[k]);
                let theta_c = n.dot(c).clamp(-1.0, 1.0).acos();
                if theta_c - t.half_angle[k] >= std::f32::consts::FRAC_PI_2 + 1e-4 {
                    assert_eq!(cells[k], 0.0, "cone below the horizon, cell {k}");
                }
                let all_below =
                    cell_points(morton_decode(k as u32), 32, 16).all(|d| n.dot(d) <= 0.0);
                if all_below {
                    below_mass += cells[k] as f64;
                }
            }
            assert!(
                below_mass <= 2e-3 * total,
                "{m:?}: {below_mass} of {total} below the horizon"
            );
        }
    }
}

/// Points that share a normal and a material whose product ignores the view share
/// their cells bit for bit (the renderer then reuses `J`); a specular lobe follows the
/// view.
#[test]
fn product_cells_ignore_the_view_unless_the_material_says_otherwise() {
    let diffuse_phong = Material::phong([0.5; 3], [0.0; 3], 50.0).unwrap();
    for (m, depends) in [
        (Material::DEFAULT, false),
        (diffuse_phong, false),
        (phong(100.0), true),
    ] {
        assert_eq!(m.product_depends_on_wo(), depends, "{m:?}");
        for j in 0..10u64 {
            let n = rand_dir(43, j);
            let cells = |angle: f32| {
                let mut out = vec![0.0f32; 1024];
                m.product_cells(n, at_angle(n, angle, j as f32), 5, &mut out);
                out
            };
            let (a, b) = (cells(0.2), cells(1.2));
            assert!(a.iter().any(|&c| c > 0.0));
            let same = a.iter().zip(&b).all(|(x, y)| x.to_bits() == y.to_bits());
            assert_eq!(same, !depends, "{m:?}, normal {n}");
        }
    }
}

/// Sampling efficiency `I² / E[(g/p)²]` (1 = perfect) of a piecewise-constant pdf with
/// the given per-cell weights, for the integrand `g = lum(f) cos` sampled on `sub²`
/// points per cell.
fn efficiency(weights: &[f32], g_mean: &[f64], g2_mean: &[f64], omega: f64) -> f64 {
    let wsum: f64 = weights.iter().map(|&w| w as f64).sum();
    let integral: f64 = g_mean.iter().sum::<f64>() * omega;
    let mut second = 0.0;
    for k in 0..weights.len() {
        if g2_mean[k] > 0.0 {
            let p = weights[k] as f64 / (wsum * omega);
            second += if p > 0.0 {
                g2_mean[k] * omega / p
            } else {
                f64::INFINITY
            };
        }
    }
    integral * integral / second
}

/// Quality of B~ against the best piecewise-constant approximation (exact cell means)
/// and against plain centre values; prints a table (run with --nocapture).
#[test]
fn product_cells_approximate_the_cell_means() {
    let n = test_normal();
    let t = CellCones::get(5);
    let omega = t.cell_solid_angle as f64;
    let mut worst = Vec::new();
    for m in [
        Material::DEFAULT,
        phong(10.0),
        phong(100.0),
        phong(1000.0),
        phong(1e4),
    ] {
        for (name, wo) in incidences(n) {
            let mut cells = vec![0.0f32; 1024];
            m.product_cells(n, wo, 5, &mut cells);
            let sub = 32;
            let (mut gm, mut g2m, mut centre) =
                (vec![0.0; 1024], vec![0.0; 1024], vec![0.0f32; 1024]);
            for k in 0..1024 {
                let cell = morton_decode(k as u32);
                let (mut s, mut s2) = (0.0f64, 0.0f64);
                for d in cell_points(cell, 32, sub).take((sub * sub) as usize) {
                    let g = lum_fcos(&m, n, wo, d) as f64;
                    s += g;
                    s2 += g * g;
                }
                gm[k] = s / (sub * sub) as f64;
                g2m[k] = s2 / (sub * sub) as f64;
                centre[k] = lum_fcos(&m, n, wo, Vec3::new(t.cx[k], t.cy[k], t.cz[k]));
            }
            let exact: Vec<f32> = gm.iter().map(|&g| g as f32).collect();
            let (eb, ee, ec) = (
                efficiency(&cells, &gm, &g2m, omega),
                efficiency(&exact, &gm, &g2m, omega),
                efficiency(&centre, &gm, &g2m, omega),
            );
            let sum_b: f64 = cells.iter().map(|&c| c as f64).sum::<f64>() * omega;
            let sum_e: f64 = gm.iter().sum::<f64>() * omega;
            println!("{:>28} {name:>8}: efficiency B~ {eb:.3}  exact means {ee:.3}  centres {ec:.3}  ∫B~/∫B {:.3}", format!("{m:?}").chars().take(28).collect::<String>(), sum_b / sum_e);
            if eb < 0.5 * ee {
                worst.push(format!("{m:?} {name}: {eb} vs {ee}"));
            }
        }
    }
    assert!(worst.is_empty(), "{worst:?}");
}

#[test]
fn sphere_to_square_is_the_cell_lookup() {
    // B~ cells are indexed by the same map the samplers use.
    let d = test_normal();
    let p = sphere_to_square(d) * 32.0;
    let c = texel_of(d, 32);
    assert_eq!(c, UVec2::new(p.x as u32, p.y as u32));
}
