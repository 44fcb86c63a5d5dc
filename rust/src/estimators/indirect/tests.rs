use super::*;
use crate::bsdf::Material;
use crate::estimators::direct::ProductLevel;
use crate::lights::envmap::EnvMap;
use crate::sampling::rng::SampleRng;

/// The furnace ([`crate::testing::furnace_sphere`]) of `material` under a black map:
/// direct light at any inner point is the directional albedo `ρ`, and each bounce
/// multiplies by `ρ` again.
fn furnace(material: Material) -> Scene {
    crate::testing::furnace_sphere(3, material)
}

/// The shading point where the ray from `origin` along `dir` first hits `scene`, and the
/// hit's position.
fn hit_point(scene: &Scene, origin: Vec3, dir: Vec3) -> (ShadingPoint, Vec3) {
    let mut bvh = TraversalCounters::default();
    let hit = scene
        .intersect1(origin, dir.normalize(), f32::INFINITY, &mut bvh)
        .expect("the ray hits the scene");
    (
        shading_point_at(scene, &hit, -dir.normalize()),
        hit.position,
    )
}

fn point_seen(scene: &Scene, origin: Vec3, dir: Vec3) -> ShadingPoint {
    hit_point(scene, origin, dir).0
}

/// Mean and standard error per channel of `n` indirect estimates at `sp`.
fn indirect_mean(
    scene: &Scene,
    env: &EnvMap,
    sp: &ShadingPoint,
    params: &PathParams,
    n: u64,
    seed: u64,
) -> ([f64; 3], [f64; 3], DirectCounters) {
    let lighting = Lighting {
        scene,
        env,
        product_level: ProductLevel::PerMaterial,
    };
    let (mut sum, mut sum2) = ([0.0f64; 3], [0.0f64; 3]);
    let mut counters = DirectCounters::default();
    let mut bvh = TraversalCounters::default();
    for s in 0..n {
        let rng = SampleRng::new(seed, 0, s);
        let l = estimate_indirect(&lighting, sp, params, &rng, &mut counters, &mut bvh);
        assert!(l.is_finite() && l.min_element() >= 0.0, "sample {s}: {l}");
        for c in 0..3 {
            sum[c] += l[c] as f64;
            sum2[c] += (l[c] as f64).powi(2);
        }
    }
    let nf = n as f64;
    let mean = sum.map(|s| s / nf);
    let se = std::array::from_fn(|c| ((sum2[c] / nf - mean[c] * mean[c]).max(0.0) / nf).sqrt());
    (mean, se, counters)
}

/// `|got - want| <= 4 SE`, plus float rounding (`1e-5` relative).
fn assert_within_4se(what: &str, got: [f64; 3], se: [f64; 3], want: [f64; 3]) {
    for c in 0..3 {
        let tol = 4.0 * se[c] + 1e-5 * want[c].abs();
        assert!(
            (got[c] - want[c]).abs() <= tol,
            "{what}, channel {c}: {} vs expected {} (4 SE = {})",
            got[c],
            want[c],
            4.0 * se[c]
        );
    }
}

#[test]
fn the_furnace_gives_the_geometric_series_of_the_albedo() {
    let albedo = [0.5f32, 0.3, 0.8];
    let scene = furnace(Material::lambert(albedo).unwrap());
    let env = EnvMap::constant([0.0; 3], 8).unwrap();
    let sp = point_seen(
        &scene,
        Vec3::new(0.1, -0.2, 0.05),
        Vec3::new(0.3, 1.0, -0.2),
    );
    for bounces in [1u32, 3] {
        let params = PathParams::new(bounces);
        let (mean, se, counters) = indirect_mean(&scene, &env, &sp, &params, 20_000, 7);
        // Σ_{j=1..k} a^j · a: the direct light a at the j-th vertex, carried back by a^j.
        let want = albedo.map(|a| (1..=bounces).map(|j| (a as f64).powi(j as i32 + 1)).sum());
        assert_within_4se(&format!("{bounces} bounces"), mean, se, want);
        assert!(
            counters.bounce_rays >= 20_000,
            "every path takes its first bounce"
        );
    }
}

#[test]
fn a_white_furnace_keeps_every_bounce_and_a_phong_one_loses_energy() {
    // Albedo 1: each bounce adds exactly 1, and roulette never cuts (throughput 1).
    let scene = furnace(Material::lambert([1.0; 3]).unwrap());
    let env = EnvMap::constant([0.0; 3], 8).unwrap();
    let sp = point_seen(&scene, Vec3::ZERO, Vec3::new(-0.4, 0.2, 1.0));
    let (mean, se, counters) = indirect_mean(&scene, &env, &sp, &PathParams::new(4), 4_000, 3);
    assert_within_4se("white furnace", mean, se, [4.0; 3]);
    assert_eq!(counters.bounce_rays, 4 * 4_000);
    // kd + ks = 1: the lobe clipped by the horizon reflects less than it receives, so k
    // bounces bring at most k.
    let phong = Material::phong([0.3; 3], [0.7; 3], 20.0).unwrap();
    let scene = furnace(phong);
    let sp = point_seen(&scene, Vec3::ZERO, Vec3::new(0.5, -0.3, 1.0));
    let (mean, se, _) = indirect_mean(&scene, &env, &sp, &PathParams::new(3), 20_000, 5);
    for c in 0..3 {
        assert!(
            mean[c] <= 3.0 + 4.0 * se[c],
            "Phong furnace gains energy: {mean:?}"
        );
        assert!(
            mean[c] > 1.0,
            "three bounces of albedo near 1 bring well over 1: {mean:?}"
        );
    }
}

/// A ground quad (albedo `a`), a wall (albedo `b`) at `x = 1` and an area light above,
/// under a black map.
struct Bounce {
    scene: Scene,
    a: f64,
    b: f64,
    light: [Vec3; 4],
    radiance: f64,
}

fn bounce_scene() -> Bounce {
    let (a, b, radiance) = (0.6, 0.7, 20.0);
    let mut scene = Scene::new();
    let ground = [
        [-1.0, 0.0, -1.0],
        [1.0, 0.0, -1.0],
        [1.0, 0.0, 1.0],
        [-1.0, 0.0, 1.0],
    ];
    let quad = [[0, 1, 2], [0, 2, 3]];
    scene
        .add_indexed(
            &ground,
            &quad,
            Material::lambert([a as f32; 3]).unwrap(),
            None,
        )
        .unwrap();
    let wall = [
        [1.0, 0.0, -0.5],
        [1.0, 1.0, -0.5],
        [1.0, 1.0, 0.5],
        [1.0, 0.0, 0.5],
    ];
    scene
        .add_indexed(
            &wall,
            &quad,
            Material::lambert([b as f32; 3]).unwrap(),
            None,
        )
        .unwrap();
    // Emits downwards: (v1 - v0) x (v2 - v0) = -y.
    let light = [
        [0.0, 2.0, -0.5],
        [1.0, 2.0, -0.5],
        [1.0, 2.0, 0.5],
        [0.0, 2.0, 0.5],
    ];
    scene
        .add_area_light(&light, [radiance as f32; 3], None)
        .unwrap();
    Bounce {
        scene,
        a,
        b,
        light: light.map(Vec3::from),
        radiance,
    }
}

/// Midpoint-rule integral over the wall (`n²` cells) and, per wall cell, over the light
/// (`n²` cells) of one bounce's light at `x` on the ground (normal +y):
/// `(a/π) ∫_wall (b/π) E(y) cos θ_x cos θ_y / r² dA_y`, with the wall's irradiance
/// `E(y) = ∫_light L cos θ_y' cos θ_l / r'² dA_l`. Nothing occludes these pairs.
fn one_bounce_quadrature(s: &Bounce, x: Vec3, n: usize) -> f64 {
    let [l0, l1, _, l3] = s.light;
    let (lu, lv) = (l1 - l0, l3 - l0);
    let light_cell = lu.length() * lv.length() / (n * n) as f32;
    let (wall_normal, wall_cell) = (Vec3::NEG_X, 1.0 / (n * n) as f64);
    let mut total = 0.0f64;
    for i in 0..n {
        for j in 0..n {
            let y = Vec3::new(
                1.0,
                (i as f32 + 0.5) / n as f32,
                -0.5 + (j as f32 + 0.5) / n as f32,
            );
            let mut irradiance = 0.0f64;
            for p in 0..n {
                for q in 0..n {
                    let l = l0
                        + lu * ((p as f32 + 0.5) / n as f32)
                        + lv * ((q as f32 + 0.5) / n as f32);
                    let d = l - y;
                    let r2 = d.length_squared() as f64;
                    let w = d.normalize();
                    let (cy, cl) = (w.dot(wall_normal) as f64, (-w).dot(Vec3::NEG_Y) as f64);
                    if cy > 0.0 && cl > 0.0 {
                        irradiance += s.radiance * cy * cl / r2 * light_cell as f64;
                    }
                }
            }
            let d = y - x;
            let r2 = d.length_squared() as f64;
            let w = d.normalize();
            let (cx, cy) = (w.dot(Vec3::Y) as f64, (-w).dot(wall_normal) as f64);
            if cx > 0.0 && cy > 0.0 {
                let wall_radiance = s.b / std::f64::consts::PI * irradiance;
                total += wall_radiance * cx * cy / r2 * wall_cell;
            }
        }
    }
    s.a / std::f64::consts::PI * total
}

#[test]
fn one_bounce_equals_the_two_point_integral() {
    let s = bounce_scene();
    let env = EnvMap::constant([0.0; 3], 8).unwrap();
    let (sp, x) = hit_point(
        &s.scene,
        Vec3::new(0.2, 1.0, 0.1),
        Vec3::new(0.0, -1.0, 0.0),
    );
    let fine = one_bounce_quadrature(&s, x, 40);
    let coarse = one_bounce_quadrature(&s, x, 20);
    let (mean, se, _) = indirect_mean(&s.scene, &env, &sp, &PathParams::new(1), 200_000, 11);
    for c in 0..3 {
        let tol = 4.0 * se[c] + (fine - coarse).abs();
        assert!(
            (mean[c] - fine).abs() <= tol,
            "channel {c}: path {} vs quadrature {fine} (tolerance {tol})",
            mean[c]
        );
    }
    assert!(
        fine > 0.01,
        "the wall must light the ground noticeably: {fine}"
    );
}

#[test]
fn mis_and_bsdf_sampling_at_the_vertices_agree() {
    let s = bounce_scene();
    let env = EnvMap::constant([0.0; 3], 8).unwrap();
    let sp = point_seen(
        &s.scene,
        Vec3::new(-0.3, 1.0, 0.2),
        Vec3::new(0.1, -1.0, 0.0),
    );
    let mis = PathParams::new(2);
    let bsdf = PathParams {
        vertex_method: Method::Bsdf,
        ..mis
    };
    let (m1, se1, _) = indirect_mean(&s.scene, &env, &sp, &mis, 100_000, 1);
    let (m2, se2, _) = indirect_mean(&s.scene, &env, &sp, &bsdf, 100_000, 2);
    for c in 0..3 {
        let tol = 4.0 * (se1[c] * se1[c] + se2[c] * se2[c]).sqrt();
        assert!(
            (m1[c] - m2[c]).abs() <= tol,
            "channel {c}: MIS {} vs BSDF-only {} (4 SE = {tol})",
            m1[c],
            m2[c]
        );
        assert!(se1[c] < se2[c], "MIS should have the lower error here");
    }
}
